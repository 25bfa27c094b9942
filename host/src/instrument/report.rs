//! What a calibration says, for people and for programs: the text summary and the documented
//! JSON (`jdbb calibrate --json`).
//!
//! # JSON
//! ```text
//! samples                number of calibration samples used
//! baseline.rms_um        RMS of d_ref − D with the nominal instrument, µm
//! baseline.pv_um         peak-to-valley of d_ref − D with the nominal instrument, µm
//! effects[]              the named instrument effects, in the order the selection added them
//!   .name                length_sum, length_l1, length_l2, zero_1, zero_2, axes_skew,
//!                        eccentricity_1, eccentricity_2; with --extended also tilt_k,
//!                        offset_normal_k, offset_axial_k
//!   .value               change from the nominal calibration (eccentricity: amplitude of the
//!                        change), exact refit
//!   .unit                um (lengths) or arcsec (angles)
//!   .sigma               standard error of value (delta method), null if undetermined
//!   .params              {parameter: value}: lengths {delta_um}, angles {delta_arcsec},
//!                        eccentricity {sin_arcsec, cos_arcsec, phase_deg} with
//!                        e·sin(ψ + φₑ) = sin_arcsec·sin ψ + cos_arcsec·cos ψ, ψ the disc angle
//!   .params_sigma        {parameter: standard error or null (undetermined, held at 0)}
//!   .rms_after_um        RMS of the residual after the step that added the effect (linear search)
//!   .rms_ratio           RMS before / after that step
//!   .delta_bic           BIC change of that step
//!   .cause               the physical cause in words
//! confounded[][]         groups of names the samples cannot tell apart (with equal nominal bars
//!                        always [length_l1, length_l2]: only length_sum is fitted)
//! floor_um               an effect that changes D by less than this anywhere is not named, µm
//! below_floor[]          {name, peak_um}: effects the data support that stay under the floor
//! final.rms_um           RMS of d_ref − D with the fitted calibration, µm
//! gain                   baseline.rms_um / final.rms_um
//! candidates[]           the effects searched
//! rounds                 Gauss–Newton rounds of selection and linearisation
//! setup                  with --record/--plan: the table ball's set-up offset fitted alongside,
//!                        {x_um, y_um, z_um, x_sigma_um, …}; null with --samples
//! machine[]              with --record/--plan: each searched instrument effect against the
//!                        machine's linear errors (scale_x/y/z, squareness_xy/yz/zx) and the
//!                        set-up offset: {name, separable (share of its effect on D no machine
//!                        error reproduces, 0–1), confounded_with[] (rank test; empty if separable)}
//! nominal                the calibration the fit started from (jdbb-core Calibration)
//! calibration            the fitted calibration: nominal plus the named effects (what -o writes)
//! ```
use std::fmt::Write as _;

use super::fit::Calibrated;
use crate::units::{format_estimate, human};

/// Human summary of a calibration, units on every number.
pub fn summary(c: &Calibrated) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{} calibration samples", c.samples);
    let _ = writeln!(
        s,
        "nominal instrument: RMS {:.3} µm, peak-to-valley {:.3} µm (d_ref − D)",
        c.baseline_rms_um, c.baseline_pv_um
    );
    for (i, f) in c.effects.iter().enumerate() {
        let unit = human(f.effect.unit());
        let _ = writeln!(
            s,
            "step {}: {} = {} {unit} — {}",
            i + 1,
            f.effect.name(),
            format_estimate(f.value, f.sigma),
            f.effect.cause()
        );
        if f.effect.n_cols() == 2 {
            let p = |k: usize| format_estimate(f.params[k], f.params_sigma[k]);
            let _ = writeln!(
                s,
                "    sin part {} arcsec, cos part {} arcsec, phase {} °",
                p(0),
                p(1),
                p(2)
            );
        }
        let _ = writeln!(
            s,
            "    RMS after {:.4} µm, gain ×{:.2}",
            f.rms_after_um, f.rms_ratio
        );
    }
    if c.effects.is_empty() {
        let _ = writeln!(
            s,
            "no instrument effect is supported by the samples: the nominal calibration stands"
        );
    }
    for g in &c.confounded {
        let why = if g == &["length_l1", "length_l2"] {
            " (equal nominal bars: only their sum acts on D, fitted as length_sum)"
        } else {
            ""
        };
        let _ = writeln!(
            s,
            "confounded (these samples cannot tell apart): {}{why}",
            g.join(", ")
        );
    }
    if let Some(su) = &c.setup_um {
        let axes = ["x", "y", "z"]
            .iter()
            .zip(su)
            .map(|(a, (v, sg))| format!("{a} {}", format_estimate(*v, *sg)))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            s,
            "set-up offset of the table ball (fitted alongside): {axes} µm"
        );
    }
    for m in &c.machine {
        if m.separable >= 1e-4 {
            let _ = writeln!(
                s,
                "machine run: {} is told from the machine's linear errors and the set-up ({:.1} % of its effect on D is its own)",
                m.effect,
                100.0 * m.separable
            );
        } else {
            let _ = writeln!(
                s,
                "machine run: {} cannot be told from machine errors: confounded with {} — its value is only as good as the machine",
                m.effect,
                m.confounded_with.join(", ")
            );
        }
    }
    for (name, peak) in &c.below_floor {
        let _ = writeln!(
            s,
            "below the floor (significant, but at most {peak:.4} µm on D, under {:.3} µm): {name} — not named",
            c.floor_um
        );
    }
    let _ = writeln!(
        s,
        "final: RMS {:.4} µm, gain ×{:.1} over the nominal instrument",
        c.final_rms_um, c.gain
    );
    s
}

/// The documented JSON (module docs).
pub fn to_json(c: &Calibrated) -> serde_json::Value {
    use serde_json::{json, Map, Value};
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    let effects: Vec<Value> = c
        .effects
        .iter()
        .map(|f| {
            let mut params = Map::new();
            let mut psig = Map::new();
            for ((n, v), s) in f
                .effect
                .param_names()
                .iter()
                .zip(&f.params)
                .zip(&f.params_sigma)
            {
                params.insert((*n).into(), num(*v));
                psig.insert((*n).into(), s.map(num).unwrap_or(Value::Null));
            }
            json!({
                "name": f.effect.name(),
                "value": num(f.value),
                "unit": f.effect.unit(),
                "sigma": f.sigma.map(num).unwrap_or(Value::Null),
                "params": params,
                "params_sigma": psig,
                "rms_after_um": num(f.rms_after_um),
                "rms_ratio": num(f.rms_ratio),
                "delta_bic": num(f.delta_bic),
                "cause": f.effect.cause(),
            })
        })
        .collect();
    json!({
        "samples": c.samples,
        "baseline": {"rms_um": num(c.baseline_rms_um), "pv_um": num(c.baseline_pv_um)},
        "effects": effects,
        "confounded": c.confounded,
        "floor_um": num(c.floor_um),
        "below_floor": c.below_floor.iter().map(|(n, p)| json!({"name": n, "peak_um": num(*p)})).collect::<Vec<_>>(),
        "final": {"rms_um": num(c.final_rms_um)},
        "gain": num(c.gain),
        "candidates": c.candidates,
        "rounds": c.rounds,
        "setup": c.setup_um.map(|su| json!({
            "x_um": num(su[0].0), "y_um": num(su[1].0), "z_um": num(su[2].0),
            "x_sigma_um": su[0].1.map(num), "y_sigma_um": su[1].1.map(num), "z_sigma_um": su[2].1.map(num),
        })),
        "machine": c.machine.iter().map(|m| json!({
            "name": m.effect, "separable": num(m.separable), "confounded_with": m.confounded_with,
        })).collect::<Vec<_>>(),
        "nominal": serde_json::to_value(c.nominal).expect("a calibration is plain data"),
        "calibration": serde_json::to_value(c.calibration).expect("a calibration is plain data"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::instrument::fit::{calibrate, simulated_samples, Options};
    use crate::instrument::ARCSEC_RAD;
    use jdbb_core::calib::Calibration;

    #[test]
    fn text_and_json_say_the_same() {
        let mut hidden = Calibration::DEFAULT;
        hidden.l1_mm += 0.01;
        hidden
            .enc1
            .set_eccentricity_components(30.0 * ARCSEC_RAD, 10.0 * ARCSEC_RAD);
        let s = simulated_samples(&hidden, (79.0, 99.0, 5), 72, 0.02, 5);
        let c = calibrate(&s, &Calibration::DEFAULT, &Options::default()).unwrap();
        let text = summary(&c);
        println!("{text}");
        assert!(text.contains("step 1: length_sum = 9.99"), "{text}");
        assert!(text.contains("eccentricity_1 = 31.5"), "{text}");
        assert!(text.contains("phase 18.4"), "{text}");
        assert!(text.contains("confounded (these samples cannot tell apart): length_l1, length_l2 (equal nominal bars"), "{text}");
        let v = to_json(&c);
        assert_eq!(v["samples"], c.samples);
        let e = &v["effects"][1];
        assert_eq!(e["name"], "eccentricity_1");
        assert_eq!(e["unit"], "arcsec");
        for k in ["sin_arcsec", "cos_arcsec", "phase_deg"] {
            assert!(
                e["params"][k].is_f64() && e["params_sigma"][k].is_f64(),
                "{e}"
            );
        }
        assert_eq!(
            v["confounded"],
            serde_json::json!([["length_l1", "length_l2"]])
        );
        let back: Calibration = serde_json::from_value(v["calibration"].clone()).unwrap();
        assert_eq!(back, c.calibration);
        assert!(v["final"]["rms_um"].as_f64().unwrap() < 0.03);
    }
}
