//! Angle-indexed runs of a rotary axis (`jdbb diagnose-rotary`): the same selection engine on angle-indexed DBB data of a rotary axis
//! (seed 002: the bar length while the C turntable turns, spindle ball following).
//!
//! The ideal rotary table predicts no change of bar length, ΔL = 0. The candidate effects are
//! functions of the axis angle θ, each linear in its parameters (a harmonic A·cos(kθ − φ) is
//! fitted as a·cos kθ + b·sin kθ):
//!
//! | name            | columns            | cause (radial / tangential bar)                       |
//! |-----------------|--------------------|-------------------------------------------------------|
//! | `length_offset` | 1                  | constant: bar length / zero of the reading; axial: δz |
//! | `once_per_rev`  | cos θ, sin θ       | eccentricity: the ball orbits off the C axis (axis location error or set-up offset of the table ball); axial bar: tilt of the C axis |
//! | `twice_per_rev` | cos 2θ, sin 2θ     | ellipticity: scale mismatch/squareness of the following X, Y axes, or C-axis wobble |
//! | `three_per_rev`, `four_per_rev` | cos kθ, sin kθ | higher-order run-out of the C bearing |
//! | `linear_drift`  | θ / 2π             | drift during the run (thermal); tangential bar: angular positioning scale error of C |
//!
//! Each run (column) is diagnosed alone by [`crate::numerics::select::forward_select`].
use std::path::Path as FsPath;

use nalgebra::DMatrix;

use crate::numerics::select::{forward_select, Group, SelectOptions};
use crate::table::{Column, Table};
use crate::units::format_estimate;
use crate::{Error, Result};

/// The candidate effects of angle-indexed data, in the order of the table above.
pub const CANDIDATES: [&str; 6] = [
    "length_offset",
    "once_per_rev",
    "twice_per_rev",
    "three_per_rev",
    "four_per_rev",
    "linear_drift",
];

/// Columns (values per unit parameter) of candidate `c` at angle θ.
fn columns(c: usize, theta: f64) -> Vec<f64> {
    match c {
        0 => vec![1.0],
        1..=4 => {
            let k = c as f64;
            vec![(k * theta).cos(), (k * theta).sin()]
        }
        _ => vec![theta / std::f64::consts::TAU],
    }
}

/// What the installation of the bar is (from the column name).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Installation {
    Radial,
    Tangential,
    Axial,
    Unknown,
}

impl Installation {
    fn from_name(name: &str) -> Installation {
        if name.contains("radial") {
            Installation::Radial
        } else if name.contains("tangential") {
            Installation::Tangential
        } else if name.contains("axial") {
            Installation::Axial
        } else {
            Installation::Unknown
        }
    }
}

/// The physical cause of a candidate for a bar installation, in words.
pub fn cause(candidate: &str, inst: Installation) -> &'static str {
    use Installation::*;
    match (candidate, inst) {
        ("length_offset", Axial) => {
            "constant axial offset: axial displacement error of the C axis (δz) or the reading's zero"
        }
        ("length_offset", Tangential) => {
            "constant: with the reading zeroed at the start, an eccentric orbit reads e·(1 − cos(θ − φ)), so the constant ≈ the once-per-rev amplitude; else bar length"
        }
        ("length_offset", _) => {
            "constant: the reading is zeroed at the start angle (the constant cancels the other terms there) or the bar length is not as assumed"
        }
        ("once_per_rev", Axial) => {
            "tilt of the C axis against the XY plane: the table ball rises and falls once per turn"
        }
        ("once_per_rev", _) => {
            "eccentricity: the table ball orbits off-centre (C axis location error or set-up offset of the table ball relative to the C axis)"
        }
        ("twice_per_rev", Axial) => "axial wobble of the table twice per turn",
        ("twice_per_rev", _) => {
            "ellipticity: scale mismatch or squareness of the X, Y axes that follow the ball, or C-axis wobble"
        }
        ("three_per_rev", _) | ("four_per_rev", _) => "higher-order run-out of the C-axis bearing",
        ("linear_drift", Tangential) => {
            "angular positioning error of C growing with angle (scale error of the C encoder) or thermal drift"
        }
        ("linear_drift", _) => "drift during the run (thermal)",
        _ => "unknown",
    }
}

/// One selected effect of one run.
#[derive(Debug, Clone)]
pub struct RunEffect {
    pub name: &'static str,
    /// Amplitude (µm): |a| for offset and drift, √(a² + b²) for harmonics.
    pub value_um: f64,
    pub sigma_um: f64,
    /// Phase φ (deg) of A·cos(kθ − φ) for harmonics; None otherwise.
    pub phase_deg: Option<f64>,
    pub rms_after_um: f64,
    pub rms_ratio: f64,
    pub delta_bic: f64,
    pub cause: &'static str,
}

/// The diagnosis of one run.
#[derive(Debug, Clone)]
pub struct RunDiagnosis {
    pub run: String,
    pub samples: usize,
    pub baseline_rms_um: f64,
    pub baseline_pv_um: f64,
    pub effects: Vec<RunEffect>,
    pub final_rms_um: f64,
    pub gain: f64,
    pub confounded: Vec<Vec<String>>,
}

/// Angles (rad) and, per run, its name and ΔL (µm).
pub type Runs = (Vec<f64>, Vec<(String, Vec<f64>)>);

/// Read `angle_deg,<run>_mm,...` (one run per column, ΔL in mm; angles in increasing order, at
/// least [`MIN_ANGLES`] distinct).
pub fn read_runs(file: &FsPath) -> Result<Runs> {
    runs_from(Table::open_with(file, crate::fsio::Limit::Table)?)
}

/// [`read_runs`] on text in memory.
pub fn parse_runs(file: &FsPath, text: &str) -> Result<Runs> {
    runs_from(Table::from_text(file, text)?)
}

/// Fewer distinct angles than this cannot tell the harmonics apart.
pub const MIN_ANGLES: usize = 8;

fn runs_from(mut t: Table) -> Result<Runs> {
    let names: Vec<String> = t.names().to_vec();
    if names.first().map(String::as_str) != Some("angle_deg") {
        let first = t.optional(&names[0]).expect("a name of the header");
        return Err(t.header_error(
            Some(&first),
            format!(
                "first column must be `angle_deg`, found `{}`",
                crate::table::shown(&names[0])
            ),
        ));
    }
    if names.len() < 2 {
        return Err(t.header_error(None, "no run columns after angle_deg"));
    }
    let cols: Vec<Column> = names
        .iter()
        .map(|n| t.optional(n).expect("a name of the header"))
        .collect();
    if let Some(c) = cols.iter().skip(1).find(|c| !c.name.ends_with("_mm")) {
        return Err(t.header_error(
            Some(c),
            format!(
                "column `{}` must be a bar-length change in mm (name ending in _mm)",
                crate::table::shown(&c.name)
            ),
        ));
    }
    let mut angle: Vec<f64> = vec![];
    let mut runs: Vec<(String, Vec<f64>)> =
        names[1..].iter().map(|c| (c.to_string(), vec![])).collect();
    let mut last_line = t.header_line();
    while let Some(row) = t.next_row()? {
        last_line = row.line();
        let x = row.number(&cols[0])?;
        if angle.last().is_some_and(|&a| x.to_radians() < a) {
            return Err(row.error(
                &cols[0],
                "angle goes backwards; rows must be in angle order",
            ));
        }
        angle.push(x.to_radians());
        for (run, c) in runs.iter_mut().zip(&cols[1..]) {
            run.1.push(row.number(c)? * 1e3);
        }
    }
    let mut distinct: Vec<f64> = angle.clone();
    distinct.dedup();
    if distinct.len() < MIN_ANGLES {
        return Err(Error::input(
            t.path(),
            last_line,
            0,
            format!(
                "only {} distinct angles; need at least {MIN_ANGLES} to tell harmonics apart",
                distinct.len()
            ),
        ));
    }
    Ok((angle, runs))
}

/// Diagnose one run: ΔL (µm) against angle θ (rad).
pub fn diagnose_run(
    run: &str,
    theta: &[f64],
    dl_um: &[f64],
    opts: &SelectOptions,
) -> Result<RunDiagnosis> {
    let m = theta.len();
    let inst = Installation::from_name(run);
    let mut groups = vec![];
    let mut n = 0;
    for c in 0..CANDIDATES.len() {
        let k = columns(c, 0.0).len();
        groups.push((n..n + k).collect::<Vec<usize>>());
        n += k;
    }
    let w = n + 1;
    let mut g = DMatrix::<f64>::zeros(w, w);
    for (&t, &y) in theta.iter().zip(dl_um) {
        let mut x: Vec<f64> = (0..CANDIDATES.len()).flat_map(|c| columns(c, t)).collect();
        x.push(y);
        for i in 0..w {
            for j in 0..w {
                g[(i, j)] += x[i] * x[j];
            }
        }
    }
    let col_name = |i: usize| {
        let c = groups.iter().position(|gr| gr.contains(&i)).unwrap_or(0);
        CANDIDATES[c].to_string()
    };
    let candidate_groups: Vec<Group> = groups
        .iter()
        .enumerate()
        .map(|(f, cols)| Group::simple(cols.clone(), f))
        .collect();
    let sel = forward_select(&g, m, &[], &candidate_groups, opts, &col_name)?;
    let baseline_rms_um = (dl_um.iter().map(|x| x * x).sum::<f64>() / m as f64).sqrt();
    let lo = dl_um.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = dl_um.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let mut effects = vec![];
    let mut at = 0;
    for st in &sel.steps {
        let name = CANDIDATES[st.group];
        let k = groups[st.group].len();
        let a = &sel.coef[at..at + k];
        let cov = |i: usize, j: usize| sel.covariance[(at + i, at + j)];
        let (value, sigma, phase) = if k == 2 {
            let amp = a[0].hypot(a[1]);
            let var = if amp > 0.0 {
                (a[0] * a[0] * cov(0, 0) + a[1] * a[1] * cov(1, 1) + 2.0 * a[0] * a[1] * cov(0, 1))
                    / (amp * amp)
            } else {
                cov(0, 0)
            };
            (
                amp,
                var.max(0.0).sqrt(),
                Some(a[1].atan2(a[0]).to_degrees()),
            )
        } else {
            (a[0], cov(0, 0).max(0.0).sqrt(), None)
        };
        effects.push(RunEffect {
            name,
            value_um: value,
            sigma_um: sigma,
            phase_deg: phase,
            rms_after_um: st.rms_after,
            rms_ratio: st.rms_ratio,
            delta_bic: st.delta_bic,
            cause: cause(name, inst),
        });
        at += k;
    }
    let final_rms_um = (sel.ssr / m as f64).sqrt();
    Ok(RunDiagnosis {
        run: run.to_string(),
        samples: m,
        baseline_rms_um,
        baseline_pv_um: hi - lo,
        effects,
        final_rms_um,
        gain: baseline_rms_um / final_rms_um.max(1e-12),
        confounded: sel.confounded,
    })
}

/// Human table of all runs.
pub fn summary(runs: &[RunDiagnosis]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "ideal rotary table: ΔL = 0. Per run: how wrong that is, the effects the data supports (BIC), and the gain."
    );
    for r in runs {
        let _ = writeln!(
            s,
            "\n{} ({} angles): ideal-table RMS {:.2} µm, PV {:.2} µm",
            r.run, r.samples, r.baseline_rms_um, r.baseline_pv_um
        );
        for (i, e) in r.effects.iter().enumerate() {
            let phase = e
                .phase_deg
                .map(|p| format!(" at {p:.1}°"))
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "  step {}: {} = {} µm{phase} — {}\n          RMS after {:.2} µm, ×{:.2}",
                i + 1,
                e.name,
                format_estimate(e.value_um, Some(e.sigma_um)),
                e.cause,
                e.rms_after_um,
                e.rms_ratio,
            );
        }
        for g in &r.confounded {
            let _ = writeln!(s, "  confounded: {}", g.join(", "));
        }
        let _ = writeln!(
            s,
            "  final RMS {:.2} µm, gain ×{:.1} over the ideal table",
            r.final_rms_um, r.gain
        );
    }
    s
}

/// JSON of all runs.
pub fn to_json(runs: &[RunDiagnosis]) -> serde_json::Value {
    use serde_json::json;
    json!(runs
        .iter()
        .map(|r| json!({
            "run": r.run,
            "samples": r.samples,
            "baseline": {"rms_um": r.baseline_rms_um, "pv_um": r.baseline_pv_um},
            "effects": r.effects.iter().map(|e| json!({
                "name": e.name,
                "value": e.value_um,
                "unit": "um",
                "sigma": e.sigma_um,
                "phase_deg": e.phase_deg,
                "rms_after_um": e.rms_after_um,
                "rms_ratio": e.rms_ratio,
                "delta_bic": e.delta_bic,
                "cause": e.cause,
            })).collect::<Vec<_>>(),
            "confounded": r.confounded,
            "final": {"rms_um": r.final_rms_um},
            "gain": r.gain,
        }))
        .collect::<Vec<_>>())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_hidden_eccentricity_and_offset() {
        // ΔL = 3 + 100·cos(θ − 40°) µm plus a 0.01 µm ripple at 7/rev (not a candidate), on the
        // seed 002 grid of 20° steps: the two terms must come first, with their values.
        let theta: Vec<f64> = (0..=18).map(|i| (20.0 * i as f64).to_radians()).collect();
        let dl: Vec<f64> = theta
            .iter()
            .map(|t| 3.0 + 100.0 * (t - 40f64.to_radians()).cos() + 0.01 * (7.0 * t).sin())
            .collect();
        let r = diagnose_run("dl_radial_mm", &theta, &dl, &SelectOptions::default()).unwrap();
        let names: Vec<&str> = r.effects.iter().map(|e| e.name).collect();
        assert_eq!(&names[..2], &["once_per_rev", "length_offset"], "{names:?}");
        assert!((r.effects[0].value_um - 100.0).abs() < 0.1);
        assert!((r.effects[0].phase_deg.unwrap() - 40.0).abs() < 0.1);
        assert!((r.effects[1].value_um - 3.0).abs() < 0.1);
        assert!(r.gain > 100.0);
    }

    #[test]
    fn bad_rotary_files_name_line_and_column() {
        let f = FsPath::new("r.csv");
        let e = parse_runs(f, "deg,a_mm\n0,1\n").unwrap_err();
        assert!(e.to_string().starts_with("r.csv:1:1:"), "{e}");
        let e = parse_runs(f, "angle_deg,a\n0,1\n").unwrap_err();
        assert!(e.to_string().starts_with("r.csv:1:11:"), "{e}");
        let e = parse_runs(f, "angle_deg,a_mm\n0,1\n20,x\n").unwrap_err();
        assert!(e.to_string().starts_with("r.csv:3:4:"), "{e}");
        let e = parse_runs(f, "angle_deg,a_mm\n0,1\n20,2\n").unwrap_err();
        assert!(e.to_string().contains("only 2 distinct angles"), "{e}");
        // Twenty rows at one angle are one angle, as `jdbb rotary` says too.
        let same: String = std::iter::once("angle_deg,a_mm\n".to_string())
            .chain((0..20).map(|i| format!("10,{i}\n")))
            .collect();
        let e = parse_runs(f, &same).unwrap_err();
        assert!(e.to_string().contains("only 1 distinct angles"), "{e}");
        assert_eq!(e.exit_code(), 2);
    }
}
