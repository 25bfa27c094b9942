//! `jdbb rrsps design|simulate|identify|synthesize`: arguments and glue to [`crate::rrsps`].
use std::path::PathBuf;

use crate::rrsps::design::{design, Branch};
use crate::rrsps::identify::{identify, param_index, Method};
use crate::rrsps::io::{read_params, read_samples, samples_csv};
use crate::rrsps::report::{
    dead_point_report, design_json, design_text, identification_json, identification_text,
    saddle_report,
};
use crate::rrsps::saddle::{Limits, SaddleOptions};
use crate::rrsps::simulate::simulate;
use crate::rrsps::Params;
use crate::{Error, Result};

use super::output::{emit, note};

/// `jdbb rrsps ...`
#[derive(Debug, clap::Args)]
pub struct RrspsArgs {
    #[command(subcommand)]
    pub command: RrspsCommand,
}

/// The RRSPS subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum RrspsCommand {
    /// Constant-bar-length motion (eq. 9-15): θA(θC) per branch, dead points, A range.
    Design(DesignArgs),
    /// Write a samples CSV for the designed motion, with bar lengths from (possibly other)
    /// true parameters plus Gaussian noise.
    Simulate(SimulateArgs),
    /// Identify the eight parameters from one or more samples files (eq. 26).
    Identify(IdentifyArgs),
    /// Place the balls for a required A range: saddle synthesis with the constraints g1-g13
    /// (eq. 18-23), or only its first level (dead points on the range) with --method dead-point.
    Synthesize(SynthesizeArgs),
}

#[derive(Debug, clap::Args)]
pub struct SynthesizeArgs {
    /// Start values and the machine: a1 and α12 are taken from here and held (the dead-point
    /// method also holds the table ball s2, a2 from here).
    #[command(flatten)]
    pub source: ParamsSource,
    /// Synthesis method: `saddle` (eq. 18-23: min-max of the ball-cup angles over the motion
    /// subject to g1-g13, table ball chosen) or `dead-point` (only the first level: the spindle
    /// ball for the table ball given in --params).
    #[arg(long, value_enum, ignore_case = true, default_value_t = SynthMethod::Saddle)]
    pub method: SynthMethod,
    /// Bar length d (mm). Required by dead-point; for saddle it replaces the series (g13).
    #[arg(long = "d", value_name = "MM", value_parser = super::args::finite)]
    pub d_mm: Option<f64>,
    /// Required A range (degrees), e.g. --require-a=-110,0.
    #[arg(
        long,
        value_name = "MIN,MAX",
        value_delimiter = ',',
        allow_hyphen_values = true,
        required = true,
        value_parser = super::args::finite
    )]
    pub require_a: Vec<f64>,
    /// Limits of the constraints g1-g13 (saddle method).
    #[command(flatten)]
    pub limits: LimitArgs,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

/// Which synthesis `jdbb rrsps synthesize` runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SynthMethod {
    Saddle,
    DeadPoint,
}

/// The limits of g1-g13 (see `jdbb::rrsps::saddle::Limits`; defaults: the paper's Table 1 where
/// it gives a number, stated assumptions elsewhere).
#[derive(Debug, clap::Args)]
pub struct LimitArgs {
    /// g13: bar lengths available (mm) [assumed: QC20-W series].
    #[arg(long, value_name = "MM,..", value_delimiter = ',', default_values_t = [100.0, 150.0, 300.0], value_parser = super::args::bar_mm)]
    pub bar_series: Vec<f64>,
    /// g1: largest bar angle to the spindle axis (deg) [assumed].
    #[arg(long, default_value_t = 75.0, value_parser = super::args::finite)]
    pub spindle_cup_deg: f64,
    /// g2: largest bar angle to the table normal (deg) [assumed].
    #[arg(long, default_value_t = 75.0, value_parser = super::args::finite)]
    pub table_cup_deg: f64,
    /// g3, g10: table radius (mm) [paper: Φ650].
    #[arg(long, default_value_t = 325.0, value_parser = super::args::finite)]
    pub table_radius_mm: f64,
    /// g3: table top height along C above the A axis (mm) [assumed].
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = super::args::finite)]
    pub table_top_mm: f64,
    /// g3: least bar-to-table clearance (mm) [assumed].
    #[arg(long, default_value_t = 10.0, value_parser = super::args::finite)]
    pub clearance_mm: f64,
    /// g4, g5: spindle ball X range (mm) [paper: 650 travel; assumed centred].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [-325.0, 325.0], value_parser = super::args::finite)]
    pub spindle_x_mm: Vec<f64>,
    /// g6, g7: spindle ball Y range (mm) [paper: 650 travel; assumed centred].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [-325.0, 325.0], value_parser = super::args::finite)]
    pub spindle_y_mm: Vec<f64>,
    /// g8, g9: spindle ball height above the table top at A = 0 (mm) [paper: 90~540].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [90.0, 540.0], value_parser = super::args::finite)]
    pub spindle_height_mm: Vec<f64>,
    /// Largest table-ball radius a2 accepted (mm), e.g. a fixture's reach (default: only g10).
    #[arg(long, value_parser = super::args::finite)]
    pub a2_max_mm: Option<f64>,
    /// g11, g12: table ball height s2 (mm) [assumed].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [40.0, 200.0], value_parser = super::args::finite)]
    pub ball_height_mm: Vec<f64>,
}

/// Most bar lengths `--bar-series` takes: a ball bar's extension set has a handful; each length
/// is a synthesis of its own, so an endless list would be an endless run.
pub const MAX_BAR_SERIES: usize = 32;

impl LimitArgs {
    /// The limits, with every pair checked.
    pub fn limits(&self) -> Result<Limits> {
        let pair = |v: &[f64], flag: &str| -> Result<[f64; 2]> {
            match v {
                &[a, b] if a.is_finite() && b.is_finite() && a <= b => Ok([a, b]),
                _ => Err(Error::Usage(format!(
                    "--{flag} takes two numbers MIN,MAX with MIN <= MAX"
                ))),
            }
        };
        for (x, flag) in [
            (self.spindle_cup_deg, "spindle-cup-deg"),
            (self.table_cup_deg, "table-cup-deg"),
            (self.table_radius_mm, "table-radius-mm"),
        ] {
            if !(x.is_finite() && x > 0.0) {
                return Err(Error::Usage(format!("--{flag} must be a positive number")));
            }
        }
        if self.bar_series.iter().any(|d| !(d.is_finite() && *d > 0.0)) {
            return Err(Error::Usage(
                "--bar-series takes positive bar lengths in mm, e.g. 100,150,300".into(),
            ));
        }
        if self.bar_series.len() > MAX_BAR_SERIES {
            return Err(Error::Usage(format!(
                "--bar-series has {} bar lengths; a bar set has at most {MAX_BAR_SERIES} (each is a synthesis of its own): give the lengths you have, e.g. 100,150,300",
                self.bar_series.len()
            )));
        }
        Ok(Limits {
            spindle_cup_deg: self.spindle_cup_deg,
            table_cup_deg: self.table_cup_deg,
            table_radius_mm: self.table_radius_mm,
            table_top_mm: self.table_top_mm,
            clearance_mm: self.clearance_mm,
            spindle_x_mm: pair(&self.spindle_x_mm, "spindle-x-mm")?,
            spindle_y_mm: pair(&self.spindle_y_mm, "spindle-y-mm")?,
            spindle_height_mm: pair(&self.spindle_height_mm, "spindle-height-mm")?,
            ball_height_mm: pair(&self.ball_height_mm, "ball-height-mm")?,
            bar_series_mm: self.bar_series.clone(),
        })
    }
}

/// Parameter file and, for CSV tables with several rows, the row.
#[derive(Debug, clap::Args)]
pub struct ParamsSource {
    /// Parameter set: TOML (`s0_mm = ...`) or CSV with the eight names as columns.
    #[arg(long, value_name = "FILE")]
    pub params: PathBuf,
    /// Row of a CSV table to use (its `case` column), e.g. design_range_neg.
    #[arg(long)]
    pub case: Option<String>,
}

#[derive(Debug, clap::Args)]
pub struct DesignArgs {
    #[command(flatten)]
    pub source: ParamsSource,
    /// Bar length d (mm).
    #[arg(long = "d", value_name = "MM", value_parser = super::args::finite)]
    pub d_mm: f64,
    /// Required A range (degrees) to check the motion against, e.g. --require-a=-110,0.
    #[arg(
        long,
        value_name = "MIN,MAX",
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_parser = super::args::finite
    )]
    pub require_a: Option<Vec<f64>>,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Design parameters: the motion θA(θC) is computed from these (TOML or CSV).
    #[arg(long, value_name = "FILE")]
    pub design: PathBuf,
    /// Row of the design CSV.
    #[arg(long)]
    pub case: Option<String>,
    /// The machine's true parameters that produce the bar lengths (default: the design).
    #[arg(long, value_name = "FILE")]
    pub truth: Option<PathBuf>,
    /// Row of the truth CSV.
    #[arg(long)]
    pub truth_case: Option<String>,
    /// Bar length d (mm) of the design.
    #[arg(long = "d", value_name = "MM", value_parser = super::args::finite)]
    pub d_mm: f64,
    /// Number of C positions per branch, evenly spaced over 0..360° (2 to 1 000 000).
    #[arg(long, default_value_t = 1800, value_parser = parse_points)]
    pub points: usize,
    /// Branches to run (plus, minus, or both one after the other).
    #[arg(long, value_enum, ignore_case = true, default_value_t = BranchChoice::Both)]
    pub branch: BranchChoice,
    /// Standard deviation of Gaussian noise added to d (µm).
    #[arg(long, default_value_t = 0.0, value_parser = super::args::finite)]
    pub noise_um: f64,
    /// Random seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output CSV (default: standard output); written whole or not at all.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Replace --out if it exists (a regular file only; never a link or a device).
    #[arg(long, requires = "out")]
    pub force: bool,
}

/// Most C positions per branch of `rrsps simulate`: one per 0.00036°, 1 000 000 rows (about
/// 50 MB of CSV) per branch; a finer sampling tells nothing more about the linkage.
pub const MAX_POINTS: usize = 1_000_000;

fn parse_points(s: &str) -> std::result::Result<usize, String> {
    let n: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a whole number"))?;
    if (2..=MAX_POINTS).contains(&n) {
        Ok(n)
    } else {
        Err(format!(
            "{n} C positions: give 2 to {MAX_POINTS} (more is not a finer test, only a larger file)"
        ))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BranchChoice {
    Plus,
    Minus,
    Both,
}

#[derive(Debug, clap::Args)]
pub struct IdentifyArgs {
    /// Samples CSV `theta_a_deg,theta_c_deg,d_mm`; repeat for several tests fitted jointly.
    #[arg(long, value_name = "FILE", required = true)]
    pub samples: Vec<PathBuf>,
    /// Parameter that differs between tests (repeatable), e.g. --free s0_mm.
    #[arg(long, value_name = "NAME")]
    pub free: Vec<String>,
    /// Design parameters, the start of the fit (TOML or CSV).
    #[arg(long, value_name = "FILE")]
    pub design: PathBuf,
    /// Row of the design CSV.
    #[arg(long)]
    pub case: Option<String>,
    /// Fitting criterion.
    #[arg(long, value_enum, ignore_case = true, default_value_t = Method::Minimax)]
    pub method: Method,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

/// Run `jdbb rrsps ...`.
pub fn run(args: &RrspsArgs) -> Result<()> {
    match &args.command {
        RrspsCommand::Design(a) => run_design(a),
        RrspsCommand::Simulate(a) => run_simulate(a),
        RrspsCommand::Identify(a) => run_identify(a),
        RrspsCommand::Synthesize(a) => run_synthesize(a),
    }
}

fn check_d(d_mm: f64) -> Result<()> {
    if d_mm.is_finite() && d_mm > 0.0 {
        Ok(())
    } else {
        Err(Error::Usage(format!(
            "--d {d_mm}: the bar length must be a positive number of mm"
        )))
    }
}

fn run_design(args: &DesignArgs) -> Result<()> {
    check_d(args.d_mm)?;
    let p = read_params(&args.source.params, args.source.case.as_deref())?;
    let des = design(&p, args.d_mm);
    let required = match args.require_a.as_deref() {
        None => None,
        Some(&[a, b]) => Some([a.min(b), a.max(b)]),
        Some(_) => {
            return Err(Error::Usage(
                "--require-a takes two angles in degrees, e.g. --require-a=-110,0".into(),
            ))
        }
    };
    let out = if args.json {
        serde_json::to_string_pretty(&design_json(&des, required)).expect("JSON of numbers")
    } else {
        design_text(&des, required)
    };
    emit(&out)
}

fn run_synthesize(args: &SynthesizeArgs) -> Result<()> {
    let [a, b] = args.require_a[..] else {
        return Err(Error::Usage(
            "--require-a takes two angles in degrees, e.g. --require-a=-110,0".into(),
        ));
    };
    let range = [a.min(b), a.max(b)];
    let start = read_params(&args.source.params, args.source.case.as_deref())?;
    match args.method {
        SynthMethod::DeadPoint => {
            let d_mm = args.d_mm.ok_or_else(|| {
                Error::Usage("--method dead-point needs the bar length --d MM".into())
            })?;
            check_d(d_mm)?;
            run_dead_point(&start, d_mm, range, args.json)
        }
        SynthMethod::Saddle => {
            let mut lim = args.limits.limits()?;
            if let Some(d) = args.d_mm {
                check_d(d)?;
                lim.bar_series_mm = vec![d];
            }
            let opts = SaddleOptions {
                a2_max_mm: args.limits.a2_max_mm.unwrap_or(f64::INFINITY),
                ..SaddleOptions::default()
            };
            let out = saddle_report(&start, range, &lim, &opts, args.json)?;
            emit(&out)
        }
    }
}

fn run_dead_point(start: &Params, d_mm: f64, range: [f64; 2], json_out: bool) -> Result<()> {
    let syn = crate::rrsps::synth::synthesize(start, d_mm, range)?;
    emit(&dead_point_report(&syn, d_mm, range, json_out))
}

fn run_simulate(args: &SimulateArgs) -> Result<()> {
    check_d(args.d_mm)?;
    if let Some(path) = &args.out {
        crate::fsio::check_destination(path, args.force)?;
        let mut inputs = vec![("--design", args.design.as_path())];
        inputs.extend(args.truth.iter().map(|t| ("--truth", t.as_path())));
        crate::fsio::check_not_input(path, &inputs)?;
    }
    if !(args.noise_um >= 0.0 && args.noise_um.is_finite()) {
        return Err(Error::Usage(
            "--noise-um must be a non-negative number".into(),
        ));
    }
    let des = read_params(&args.design, args.case.as_deref())?;
    let truth = match &args.truth {
        Some(f) => read_params(f, args.truth_case.as_deref())?,
        None => des,
    };
    let branches: &[Branch] = match args.branch {
        BranchChoice::Plus => &[Branch::Plus],
        BranchChoice::Minus => &[Branch::Minus],
        BranchChoice::Both => &Branch::BOTH,
    };
    let (ta, tc, d, skipped) = simulate(
        &des,
        &truth,
        args.d_mm,
        args.points,
        branches,
        args.noise_um,
        args.seed,
    )?;
    if skipped > 0 {
        note(&format!(
            "note: {skipped} C positions have no A position at d = {} mm (C blocked there) and were left out",
            args.d_mm
        ));
    }
    let text = samples_csv(&ta, &tc, &d);
    match &args.out {
        Some(path) => crate::fsio::write_file(path, text.as_bytes(), args.force),
        None => emit(text.trim_end()),
    }
}

fn run_identify(args: &IdentifyArgs) -> Result<()> {
    let start = read_params(&args.design, args.case.as_deref())?;
    let free: Vec<usize> = args
        .free
        .iter()
        .map(|n| param_index(n))
        .collect::<Result<_>>()?;
    // Every test must determine the linkage on its own terms: more than eight positions.
    let samples = args
        .samples
        .iter()
        .map(|p| read_samples(p, 8))
        .collect::<Result<Vec<_>>>()?;
    let id = identify(&samples, &start, &free, args.method)?;
    let out = if args.json {
        serde_json::to_string_pretty(&identification_json(&id)).expect("JSON of numbers")
    } else {
        identification_text(&id)
    };
    emit(&out)
}
