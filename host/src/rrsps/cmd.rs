//! `jdbb rrsps design|simulate|identify`: the command-line side of [`crate::rrsps`].
use std::io::Write;
use std::path::PathBuf;

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use serde_json::{json, Map, Value};

use super::design::{design, theta_a_for, Branch, Design};
use super::identify::{format_estimate, identify, param_index, Identification, Method};
use super::io::{read_params, read_samples, samples_csv};
use super::saddle::{saddle_synthesize, Limits, SaddleOptions, CONSTRAINTS};
use super::{Params, Prepared, SinCos, PARAM_NAMES};
use crate::{Error, Result};

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
    #[arg(long, value_enum, default_value_t = SynthMethod::Saddle)]
    pub method: SynthMethod,
    /// Bar length d (mm). Required by dead-point; for saddle it replaces the series (g13).
    #[arg(long = "d", value_name = "MM")]
    pub d_mm: Option<f64>,
    /// Required A range (degrees), e.g. --require-a=-110,0.
    #[arg(
        long,
        value_name = "MIN,MAX",
        value_delimiter = ',',
        allow_hyphen_values = true,
        required = true
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
    #[arg(long, value_name = "MM,..", value_delimiter = ',', default_values_t = [100.0, 150.0, 300.0])]
    pub bar_series: Vec<f64>,
    /// g1: largest bar angle to the spindle axis (deg) [assumed].
    #[arg(long, default_value_t = 75.0)]
    pub spindle_cup_deg: f64,
    /// g2: largest bar angle to the table normal (deg) [assumed].
    #[arg(long, default_value_t = 75.0)]
    pub table_cup_deg: f64,
    /// g3, g10: table radius (mm) [paper: Φ650].
    #[arg(long, default_value_t = 325.0)]
    pub table_radius_mm: f64,
    /// g3: table top height along C above the A axis (mm) [assumed].
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub table_top_mm: f64,
    /// g3: least bar-to-table clearance (mm) [assumed].
    #[arg(long, default_value_t = 10.0)]
    pub clearance_mm: f64,
    /// g4, g5: spindle ball X range (mm) [paper: 650 travel; assumed centred].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [-325.0, 325.0])]
    pub spindle_x_mm: Vec<f64>,
    /// g6, g7: spindle ball Y range (mm) [paper: 650 travel; assumed centred].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [-325.0, 325.0])]
    pub spindle_y_mm: Vec<f64>,
    /// g8, g9: spindle ball height above the table top at A = 0 (mm) [paper: 90~540].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [90.0, 540.0])]
    pub spindle_height_mm: Vec<f64>,
    /// Largest table-ball radius a2 accepted (mm), e.g. a fixture's reach (default: only g10).
    #[arg(long)]
    pub a2_max_mm: Option<f64>,
    /// g11, g12: table ball height s2 (mm) [assumed].
    #[arg(long, value_name = "MIN,MAX", value_delimiter = ',', allow_hyphen_values = true, default_values_t = [40.0, 200.0])]
    pub ball_height_mm: Vec<f64>,
}

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
    #[arg(long = "d", value_name = "MM")]
    pub d_mm: f64,
    /// Required A range (degrees) to check the motion against, e.g. --require-a=-110,0.
    #[arg(
        long,
        value_name = "MIN,MAX",
        value_delimiter = ',',
        allow_hyphen_values = true
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
    #[arg(long = "d", value_name = "MM")]
    pub d_mm: f64,
    /// Number of C positions per branch, evenly spaced over 0..360°.
    #[arg(long, default_value_t = 1800)]
    pub points: usize,
    /// Branches to run (plus, minus, or both one after the other).
    #[arg(long, value_enum, default_value_t = BranchChoice::Both)]
    pub branch: BranchChoice,
    /// Standard deviation of Gaussian noise added to d (µm).
    #[arg(long, default_value_t = 0.0)]
    pub noise_um: f64,
    /// Random seed of the noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output CSV (default: standard output).
    #[arg(long, short)]
    pub output: Option<PathBuf>,
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
    #[arg(long, value_enum, default_value_t = Method::Minimax)]
    pub method: Method,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

/// Print a report on standard output; a closed pipe (`| head`) is not an error.
pub fn emit(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}").and_then(|_| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(Error::File {
            action: "cannot write",
            path: "<stdout>".into(),
            source: e,
        }),
        _ => Ok(()),
    }
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

/// Tolerance (degrees) for "fits the required range".
const FIT_TOL_DEG: f64 = 0.01;

/// (within, covers) of the union A range against the required one.
fn check_required(des: &Design, req: [f64; 2]) -> (bool, bool) {
    match des.a_range_deg {
        Some([lo, hi]) => (
            lo >= req[0] - FIT_TOL_DEG && hi <= req[1] + FIT_TOL_DEG,
            lo <= req[0] + FIT_TOL_DEG && hi >= req[1] - FIT_TOL_DEG,
        ),
        None => (false, false),
    }
}

/// The JSON form of a design (see README).
pub fn design_json(des: &Design, required: Option<[f64; 2]>) -> Value {
    let branches: Vec<Value> = des
        .branches
        .iter()
        .map(|b| {
            json!({
                "branch": b.branch.name(),
                "c_full_turn": b.c_full_turn,
                "c_blocked_deg": b.c_blocked_deg,
                "a_range_deg": b.a_range_deg,
                "dead_points": b.dead_points.iter().map(|dp| json!({
                    "theta_c_deg": dp.theta_c_deg,
                    "theta_a_deg": dp.theta_a_deg,
                    "kind": dp.kind,
                    "eq15_mm": dp.eq15_mm,
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    let mut v = json!({
        "d_mm": des.d_mm,
        "a_range_deg": des.a_range_deg,
        "d_full_turn_mm": des.d_full_turn_mm,
        "branches": branches,
    });
    if let Some(req) = required {
        let (within, covers) = check_required(des, req);
        v["required_a_deg"] = json!(req);
        v["within_required"] = json!(within);
        v["covers_required"] = json!(covers);
    }
    v
}

fn design_text(des: &Design, required: Option<[f64; 2]>) -> String {
    let mut s = format!("RRSS motion for d = {} mm (eq. 9-15)\n", des.d_mm);
    for b in &des.branches {
        s += &format!("branch {}:\n", b.branch.name());
        match b.a_range_deg {
            Some([lo, hi]) => s += &format!("  A range {lo:.3}° .. {hi:.3}°\n"),
            None => s += "  no position at any C angle\n",
        }
        if b.c_full_turn {
            s += "  C turns fully\n";
        } else {
            for [lo, hi] in &b.c_blocked_deg {
                s += &format!(
                    "  C cannot pass {lo:.3}° .. {hi:.3}° (the branches meet at the ends)\n"
                );
            }
        }
        for dp in &b.dead_points {
            s += &format!(
                "  dead point ({}): C = {:.3}°, A = {:.4}° (eq. 15 residual {:.1e} mm)\n",
                dp.kind, dp.theta_c_deg, dp.theta_a_deg, dp.eq15_mm
            );
        }
    }
    if let Some([lo, hi]) = des.a_range_deg {
        s += &format!("both branches: A {lo:.3}° .. {hi:.3}°\n");
    }
    match des.d_full_turn_mm {
        Some([lo, hi]) => {
            s += &format!("C turns fully on both branches for {lo:.4} mm <= d <= {hi:.4} mm\n")
        }
        None => s += "C turns fully for no bar length\n",
    }
    if let Some(req) = required {
        let (within, covers) = check_required(des, req);
        s += &format!(
            "required A {}° .. {}°: {} and {}\n",
            req[0],
            req[1],
            if within { "within it" } else { "NOT within it" },
            if covers {
                "covers it"
            } else {
                "does NOT cover it"
            }
        );
    }
    s.trim_end().to_string()
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

fn named_params(p: &Params) -> Map<String, Value> {
    PARAM_NAMES
        .iter()
        .zip(p.to_named_units())
        .map(|(n, x)| (n.to_string(), json!(x)))
        .collect()
}

/// Tolerance for "active" constraints: within this of the bound (deg or mm).
const ACTIVE_TOL: f64 = 1e-3;

/// Run the saddle synthesis and format its report (text or JSON). Also evaluates the
/// constraints for the `--params` set itself at the chosen length, as a reference (with
/// Table 2's row: the paper's design under the same limits).
pub fn saddle_report(
    start: &Params,
    range: [f64; 2],
    lim: &Limits,
    opts: &SaddleOptions,
    json_out: bool,
) -> Result<String> {
    let syn = saddle_synthesize(start, range, lim, opts)?;
    let lengths: Vec<Value> = syn
        .per_length
        .iter()
        .map(|l| match &l.outcome {
            Ok(d) => json!({"d_mm": l.d_mm, "feasible": true, "objective_deg": d.objective_deg}),
            Err(e) => json!({"d_mm": l.d_mm, "feasible": false, "reason": e}),
        })
        .collect();
    let assumed: Map<String, Value> = Limits::ASSUMED
        .iter()
        .map(|(k, why)| (k.to_string(), json!(why)))
        .collect();
    let limits = json!({
        "spindle_cup_deg": lim.spindle_cup_deg,
        "table_cup_deg": lim.table_cup_deg,
        "table_radius_mm": lim.table_radius_mm,
        "table_top_mm": lim.table_top_mm,
        "clearance_mm": lim.clearance_mm,
        "spindle_x_mm": lim.spindle_x_mm,
        "spindle_y_mm": lim.spindle_y_mm,
        "spindle_height_mm": lim.spindle_height_mm,
        "ball_height_mm": lim.ball_height_mm,
        "bar_series_mm": lim.bar_series_mm,
    });
    let Some(best) = syn.best else {
        let why: Vec<String> = syn
            .per_length
            .iter()
            .filter_map(|l| {
                l.outcome
                    .as_ref()
                    .err()
                    .map(|e| format!("d = {} mm: {e}", l.d_mm))
            })
            .collect();
        return Err(Error::Numerics(format!(
            "no bar length of the series gives a feasible design for A {}..{}°; {}. Relax the limits (see --help) or change the range",
            range[0],
            range[1],
            why.join("; ")
        )));
    };
    let d_mm = syn.per_length[best].d_mm;
    let sol = syn.per_length[best]
        .outcome
        .as_ref()
        .expect("best is feasible");
    let mut active: Vec<&str> = sol.active(ACTIVE_TOL);
    active.push("g13");
    let reference = super::saddle::evaluate(start, d_mm, lim);
    let des = design(&sol.params, d_mm);
    let cup = sol.objective_deg + lim.spindle_cup_deg.min(lim.table_cup_deg);
    let constraints_json = |g: &[f64; 12]| -> Map<String, Value> {
        CONSTRAINTS
            .iter()
            .zip(g)
            .map(|((n, m), v)| {
                (
                    n.to_string(),
                    json!({"value": v, "active": *v > -ACTIVE_TOL, "meaning": m}),
                )
            })
            .collect()
    };
    if json_out {
        let mut v = json!({
            "method": "saddle",
            "required_a_deg": range,
            "d_mm": d_mm,
            "params": named_params(&sol.params),
            "objective_deg": sol.objective_deg,
            "objective": "max over the motion of max(g1, g2): worst ball-cup angle minus its limit",
            "constraints": constraints_json(&sol.g),
            "active": active,
            "sphere_error_mm": sol.sphere_error_mm,
            "first_level_residual_mm": sol.first_level_mm,
            "evaluations": sol.evaluations,
            "lengths": lengths,
            "limits": limits,
            "assumed": assumed,
            "motion": motion_json(&des, range),
        });
        if let Some((obj, g)) = reference {
            v["reference"] = json!({
                "params": named_params(start),
                "objective_deg": obj,
                "constraints": constraints_json(&g),
            });
        }
        return Ok(serde_json::to_string_pretty(&v).expect("JSON of numbers"));
    }
    let mut s = format!(
        "saddle synthesis (eq. 18-23) for A {}..{}°: min over the table ball of the max over the motion of the ball-cup angles, s.t. g1-g13\n",
        range[0], range[1]
    );
    for l in &syn.per_length {
        match &l.outcome {
            Ok(d) => {
                s += &format!(
                    "  d = {} mm: feasible, worst cup angle {:.3}°\n",
                    l.d_mm,
                    d.objective_deg + lim.spindle_cup_deg.min(lim.table_cup_deg)
                )
            }
            Err(e) => s += &format!("  d = {} mm: {e}\n", l.d_mm),
        }
    }
    s += &format!(
        "best: d = {d_mm} mm (g13), worst cup angle {cup:.4}° (objective max(g1, g2) = {:.4}°)\n",
        sol.objective_deg
    );
    for (n, x) in PARAM_NAMES.iter().zip(sol.params.to_named_units()) {
        s += &format!("  {n:<14} {x:.4}\n");
    }
    s += "constraints (<= 0 met; worst over the motion):\n";
    for ((n, m), v) in CONSTRAINTS.iter().zip(sol.g) {
        let flag = if v > -ACTIVE_TOL { "  ACTIVE" } else { "" };
        s += &format!("  {n:<4} {v:>10.4}  {m}{flag}\n");
    }
    s += &format!("active: {}\n", active.join(", "));
    s += &format!(
        "eq. 18 on the table ball's trajectory: saddle sphere error {:.1e} mm (the sphere of radius d about the spindle ball)\n",
        sol.sphere_error_mm
    );
    if let Some((obj, g)) = reference {
        s += &format!(
            "reference (--params set at d = {d_mm} mm): worst cup angle {:.4}°, {}\n",
            obj + lim.spindle_cup_deg.min(lim.table_cup_deg),
            if g.iter().all(|&x| x <= 0.0) {
                "meets g1-g12".to_string()
            } else {
                let bad: Vec<&str> = CONSTRAINTS
                    .iter()
                    .zip(g)
                    .filter(|(_, v)| *v > 0.0)
                    .map(|((n, _), _)| *n)
                    .collect();
                format!("violates {}", bad.join(", "))
            }
        );
    }
    s += &format!(
        "limits used: cups {}°/{}°, table radius {} mm, table top {} mm, clearance {} mm, spindle X {:?} Y {:?} height {:?} mm, ball height {:?} mm, bars {:?} mm\n",
        lim.spindle_cup_deg,
        lim.table_cup_deg,
        lim.table_radius_mm,
        lim.table_top_mm,
        lim.clearance_mm,
        lim.spindle_x_mm,
        lim.spindle_y_mm,
        lim.spindle_height_mm,
        lim.ball_height_mm,
        lim.bar_series_mm
    );
    s += "defaults assumed (not printed in the paper):\n";
    for (k, why) in Limits::ASSUMED {
        s += &format!("  {k}: {why}\n");
    }
    Ok(s + &motion_text(&des, range))
}

/// The designed motion in brief: A range and C blocking per branch, the full-turn bar lengths.
/// (Dead points are left out: at a synthesized design the branches meet at d exactly, where
/// θA(θC) has a corner and the grid scan of [`design`] can report rounding-level extremes.)
fn motion_json(des: &Design, range: [f64; 2]) -> Value {
    let (within, covers) = check_required(des, range);
    json!({
        "d_mm": des.d_mm,
        "a_range_deg": des.a_range_deg,
        "d_full_turn_mm": des.d_full_turn_mm,
        "branches": des.branches.iter().map(|b| json!({
            "branch": b.branch.name(),
            "a_range_deg": b.a_range_deg,
            "c_blocked_deg": b.c_blocked_deg,
        })).collect::<Vec<_>>(),
        "within_required": within,
        "covers_required": covers,
    })
}

fn motion_text(des: &Design, range: [f64; 2]) -> String {
    let mut s = format!("motion at d = {} mm (eq. 9-11):\n", des.d_mm);
    for b in &des.branches {
        if let Some([lo, hi]) = b.a_range_deg {
            s += &format!("  branch {}: A {lo:.4}° .. {hi:.4}°", b.branch.name());
        }
        for [lo, hi] in &b.c_blocked_deg {
            s += &format!(", meets the other branch at C {lo:.3}°..{hi:.3}°");
        }
        s += "\n";
    }
    if let Some([lo, hi]) = des.d_full_turn_mm {
        s += &format!("  C turns fully for {lo:.4} mm <= d <= {hi:.4} mm\n");
    }
    let (within, covers) = check_required(des, range);
    s += &format!(
        "  required A {}..{}°: {}, {}",
        range[0],
        range[1],
        if within { "within it" } else { "NOT within it" },
        if covers {
            "covers it"
        } else {
            "does NOT cover it"
        }
    );
    s
}

fn run_dead_point(start: &Params, d_mm: f64, range: [f64; 2], json_out: bool) -> Result<()> {
    let syn = super::synth::synthesize(start, d_mm, range)?;
    let des = design(&syn.params, d_mm);
    let out = if json_out {
        serde_json::to_string_pretty(&json!({
            "method": "dead-point",
            "params": named_params(&syn.params),
            "max_condition_mm": syn.max_condition_mm,
            "design": design_json(&des, Some(range)),
        }))
        .expect("JSON of numbers")
    } else {
        let mut s = format!(
            "dead-point synthesis for d = {} mm, A {}..{}° (conditions met to {:.1e} mm):\n",
            d_mm, range[0], range[1], syn.max_condition_mm
        );
        for (n, x) in PARAM_NAMES.iter().zip(syn.params.to_named_units()) {
            s += &format!("  {n:<14} {x:.4}\n");
        }
        s + &design_text(&des, Some(range))
    };
    emit(&out)
}

fn run_simulate(args: &SimulateArgs) -> Result<()> {
    check_d(args.d_mm)?;
    if args.points < 2 {
        return Err(Error::Usage("--points must be at least 2".into()));
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
        eprintln!(
            "note: {skipped} C positions have no A position at d = {} mm (C blocked there) and were left out",
            args.d_mm
        );
    }
    let text = samples_csv(&ta, &tc, &d);
    match &args.output {
        Some(path) => std::fs::write(path, text).map_err(|source| Error::File {
            action: "cannot write",
            path: path.clone(),
            source,
        })?,
        None => emit(text.trim_end())?,
    }
    Ok(())
}

/// Simulate a DBB test: the motion designed with `design` at bar length `d_mm`
/// (`points` C positions per branch over 0..360°), bar lengths from `truth` plus Gaussian noise
/// of `noise_um`. Returns (θA rad, θC rad, d mm, number of C positions left out).
#[allow(clippy::type_complexity)]
pub fn simulate(
    design: &Params,
    truth: &Params,
    d_mm: f64,
    points: usize,
    branches: &[Branch],
    noise_um: f64,
    seed: u64,
) -> Result<(Vec<f64>, Vec<f64>, Vec<f64>, usize)> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise =
        Normal::new(0.0, noise_um * 1e-3).map_err(|e| Error::Usage(format!("noise: {e}")))?;
    let prep = Prepared::new(truth);
    let (mut ta, mut tc, mut d) = (Vec::new(), Vec::new(), Vec::new());
    let mut skipped = 0;
    for &b in branches {
        for k in 0..points {
            let c = (k as f64 * 360.0 / points as f64).to_radians();
            match theta_a_for(design, d_mm, c, b) {
                Some(a) => {
                    ta.push(a);
                    tc.push(c);
                    d.push(prep.bar_length(SinCos::of(a), SinCos::of(c)) + noise.sample(&mut rng));
                }
                None => skipped += 1,
            }
        }
    }
    Ok((ta, tc, d, skipped))
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

/// The JSON form of an identification (see README): `params`, `sigma` (null when undetermined),
/// `undetermined`, residuals in µm, and with several tests `tests[].params` of the free ones.
pub fn identification_json(id: &Identification) -> Value {
    let single = id.tests.len() == 1;
    let mut params = Map::new();
    let mut sigma = Map::new();
    for e in id.estimates.iter().filter(|e| e.test.is_none()) {
        params.insert(PARAM_NAMES[e.param].into(), json!(e.value));
        sigma.insert(PARAM_NAMES[e.param].into(), json!(e.sigma));
    }
    let mut v = json!({
        "method": match id.method { Method::Minimax => "minimax", Method::Lsq => "lsq" },
        "params": params,
        "sigma": sigma,
        // The standard errors always come from the least-squares fit of the same data.
        "sigma_method": "lsq",
        "undetermined": id.undetermined,
        "max_abs_residual_um": id.max_abs_residual_um,
        "rms_residual_um": id.rms_residual_um,
        "singular_values": id.singular_values,
        "n_samples": id.tests.iter().map(|t| t.n_samples).sum::<usize>(),
        "iterations": id.iterations,
        "weakest": {
            "relative_singular_value": id.weakest.relative_singular_value,
            "direction": id.weakest.components.iter().map(|(n, v)| (n.clone(), json!(v))).collect::<Map<_, _>>(),
            "max_change_um_per_unit": id.weakest.max_change_um,
        },
    });
    if id.method == Method::Minimax {
        // The standard errors are those of the least-squares fit: show its values beside them.
        v["lsq_params"] = id
            .estimates
            .iter()
            .zip(&id.lsq_values)
            .map(|(e, &x)| (e.name.clone(), json!(x)))
            .collect::<Map<_, _>>()
            .into();
    }
    if !single {
        let tests: Vec<Value> = id
            .tests
            .iter()
            .enumerate()
            .map(|(t, tf)| {
                let mut p = Map::new();
                let mut s = Map::new();
                let mut ch = Map::new();
                for e in id.estimates.iter().filter(|e| e.test == Some(t)) {
                    p.insert(PARAM_NAMES[e.param].into(), json!(e.value));
                    s.insert(PARAM_NAMES[e.param].into(), json!(e.sigma));
                }
                for (name, test, value, sig) in &id.changes {
                    if *test == t + 1 {
                        ch.insert(name.clone(), json!({"value": value, "sigma": sig}));
                    }
                }
                json!({
                    "params": p,
                    "sigma": s,
                    "change_from_test_1": ch,
                    "n_samples": tf.n_samples,
                    "max_abs_residual_um": tf.max_abs_residual_um,
                    "rms_residual_um": tf.rms_residual_um,
                })
            })
            .collect();
        v["tests"] = json!(tests);
    }
    v
}

fn identification_text(id: &Identification) -> String {
    let mut s = format!(
        "{} identification from {} samples in {} test(s) (eq. 26)\n",
        match id.method {
            Method::Minimax => "minimax",
            Method::Lsq => "least-squares",
        },
        id.tests.iter().map(|t| t.n_samples).sum::<usize>(),
        id.tests.len()
    );
    for e in &id.estimates {
        s += &format!("  {:<18} {}\n", e.name, format_estimate(e.value, e.sigma));
    }
    for (name, t, value, sig) in &id.changes {
        s += &format!(
            "  change of {name} from test 1 to test {t}: {}\n",
            format_estimate(*value, *sig)
        );
    }
    for g in &id.undetermined {
        s += &format!(
            "  undetermined by this data: a combination of {} (values kept near the design)\n",
            g.join(", ")
        );
    }
    let w = &id.weakest;
    s += &format!(
        "  weakest combination (singular value {:.1e} of the largest): {}\n    one unit along it changes d by at most {:.3} µm\n",
        w.relative_singular_value,
        w.components
            .iter()
            .filter(|(_, v)| v.abs() >= 0.01)
            .map(|(n, v)| format!("{v:+.2} {n}"))
            .collect::<Vec<_>>()
            .join(", "),
        w.max_change_um
    );
    if id.method == Method::Minimax {
        s += &format!(
            "  least-squares values: {}\n",
            id.estimates
                .iter()
                .zip(&id.lsq_values)
                .map(|(e, &x)| format!("{} {}", e.name, format_estimate(x, e.sigma)))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    s += &format!(
        "  singular values (column-scaled): {}\n",
        id.singular_values
            .iter()
            .map(|x| format!("{x:.2e}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    for (t, tf) in id.tests.iter().enumerate() {
        s += &format!(
            "  test {}: {} samples, max |residual| {:.3} µm, RMS {:.3} µm\n",
            t + 1,
            tf.n_samples,
            tf.max_abs_residual_um,
            tf.rms_residual_um
        );
    }
    s += "  (± are standard errors of the least-squares fit, digits beyond them not shown; a minimax\n   estimate scatters more than that along weak combinations)";
    s
}
