//! What `jdbb rrsps` reports, for people (text) and programs (JSON): designs, syntheses and
//! identifications. Functions return strings and JSON values; the command line prints them.
use serde_json::{json, Map, Value};

use super::design::{design, Design};
use super::identify::{Identification, Method};
use super::saddle::{saddle_synthesize, Limits, SaddleOptions, CONSTRAINTS};
use super::synth::Synthesis;
use super::{Params, PARAM_NAMES};
use crate::units::format_estimate;
use crate::{Error, Result};

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

pub fn design_text(des: &Design, required: Option<[f64; 2]>) -> String {
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

pub fn identification_text(id: &Identification) -> String {
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

/// The report of a dead-point synthesis (first level only) at bar length `d_mm` for the required
/// A range `range` (degrees).
pub fn dead_point_report(syn: &Synthesis, d_mm: f64, range: [f64; 2], json_out: bool) -> String {
    let des = design(&syn.params, d_mm);
    if json_out {
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
    }
}
