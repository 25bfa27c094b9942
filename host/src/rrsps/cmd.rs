//! `jdbb rrsps design|simulate|identify`: the command-line side of [`crate::rrsps`].
use std::io::Write;
use std::path::PathBuf;

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use serde_json::{json, Map, Value};

use super::design::{design, theta_a_for, Branch, Design};
use super::identify::{format_estimate, identify, param_index, Identification, Method};
use super::io::{read_params, read_samples, samples_csv};
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
    /// Place the balls (s0, a0, θA0, θC0) so the motion's dead points fall on a required A range.
    Synthesize(SynthesizeArgs),
}

#[derive(Debug, clap::Args)]
pub struct SynthesizeArgs {
    /// Start values; s2, a2 (the table ball), a1 and α12 are taken from here and held.
    #[command(flatten)]
    pub source: ParamsSource,
    /// Bar length d (mm), one of the bar-length series.
    #[arg(long = "d", value_name = "MM")]
    pub d_mm: f64,
    /// Required A range (degrees), e.g. --require-a=-110,0.
    #[arg(
        long,
        value_name = "MIN,MAX",
        value_delimiter = ',',
        allow_hyphen_values = true,
        required = true
    )]
    pub require_a: Vec<f64>,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
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
    check_d(args.d_mm)?;
    let [a, b] = args.require_a[..] else {
        return Err(Error::Usage(
            "--require-a takes two angles in degrees, e.g. --require-a=-110,0".into(),
        ));
    };
    let start = read_params(&args.source.params, args.source.case.as_deref())?;
    let syn = super::synth::synthesize(&start, args.d_mm, [a, b])?;
    let v = syn.params.to_named_units();
    let des = design(&syn.params, args.d_mm);
    let out = if args.json {
        let params: Map<String, Value> = PARAM_NAMES
            .iter()
            .zip(v)
            .map(|(n, x)| (n.to_string(), json!(x)))
            .collect();
        serde_json::to_string_pretty(&json!({
            "params": params,
            "max_condition_mm": syn.max_condition_mm,
            "design": design_json(&des, Some([a.min(b), a.max(b)])),
        }))
        .expect("JSON of numbers")
    } else {
        let mut s = format!(
            "dead-point synthesis for d = {} mm, A {}..{}° (conditions met to {:.1e} mm):\n",
            args.d_mm,
            a.min(b),
            a.max(b),
            syn.max_condition_mm
        );
        for (n, x) in PARAM_NAMES.iter().zip(v) {
            s += &format!("  {n:<14} {x:.4}\n");
        }
        s + &design_text(&des, Some([a.min(b), a.max(b)]))
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
