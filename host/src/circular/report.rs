//! What a diagnosis says, for people and for programs: the text summary and the documented JSON.
//! (The polar plot is [`super::plot`].)
//!
//! # JSON (`--json`, and `diagnosis.json` in `--report DIR`)
//! ```text
//! samples                  number of samples used
//! baseline.rms_um          RMS of D − |p| (ideal machine), µm
//! baseline.pv_um           peak-to-valley of D − |p|, µm
//! effects[]                set-up first (setup_offset, length_offset), then machine effects in
//!                          the order the selection added them
//!   .name                  effect name (setup_offset, length_offset, scale_k, scale2_k,
//!                          backlash_k, cyclic_k, interference_k, squareness_ij,
//!                          servo_mismatch_ij, or the identifiable scale_mismatch_ij)
//!   .value                 |c| for setup_offset, amplitude for cyclic/interference, else the
//!                          single parameter; from the exact-geometry refit
//!   .unit                  um, um/m, um/m^2, um/(mm/s) or ms
//!   .sigma                 standard error of value (delta method), null if undetermined
//!   .params                {parameter: value}: setup_offset {x_um,y_um,z_um}, length_offset
//!                          {e_um}, scale/scale_mismatch {a_um_per_m}, scale2 {b_um_per_m2},
//!                          backlash {f_um}, cyclic {sin_um,cos_um} (A·sin(w+φ) = sin_um·sin w +
//!                          cos_um·cos w, w = 2πk/pitch), interference {sin_um_per_mm_s,
//!                          cos_um_per_mm_s}, squareness {s_um_per_m}, servo_mismatch {dtau_ms}
//!   .params_sigma          {parameter: standard error or null (undetermined, held at 0)}
//!   .rms_after_um          RMS of the residual after the step that added this effect (linear
//!                          search); for the set-up, after the set-up fit
//!   .rms_ratio             RMS before / after that step
//!   .delta_bic             BIC change of that step (null for the set-up)
//!   .setup                 true for setup_offset and length_offset
//!   .cause                 the physical cause in words
//! confounded[][]           groups of names the test cannot tell apart (effects, or set-up
//!                          components setup_offset.x/.y/.z); a group of one is a parameter the
//!                          path does not excite at all
//! floor_um                 the reporting floor: an effect that changes D by less than this
//!                          anywhere is not named (µm)
//! below_floor[]            {name, peak_um}: effects the data support but that stay under the
//!                          floor (peak_um bounds their largest contribution to D)
//! not_significant[]        {name, value, sigma, unit, params}: effects the selection chose whose value
//!                          is within 2σ of zero once σ counts the timing uncertainty (not named)
//! final.rms_um             RMS of the residual of the exact refit, µm
//! gain                     baseline.rms_um / final.rms_um
//! harmonics_um[]           amplitude of residual harmonics 1..8 against the angle in the plane
//!                          of the two axes with the largest travel, µm
//! lsq_setup                {x_um, y_um, z_um, e_um}: least-squares centre and length offset of
//!                          all samples (D ≈ |p + c| + e), the set-up removed before G, H and
//!                          the polar plot
//! circular_deviation_g_um  ISO 230-4 style G of D − (|p + c| + e) with lsq_setup: largest
//!                          peak-to-valley of one circle in one direction, µm
//! hysteresis_h_um          ISO 230-4 style H: largest ccw − cw difference of one circle in a
//!                          1° bin, µm
//! candidates[]             the candidate effects that were tried
//! arcs[]                   per circle (as `circles`): {start_deg, sweep_deg, partial}, the arc
//!                          its samples cover in the plane, degrees from the plane's first axis
//!                          (360 a full circle); on a partial arc `harmonics_um` is empty and
//!                          the candidates the arc cannot tell from the set-up and the scale are
//!                          in `confounded` and not tried
//! ```
//!
//! Added for acting on a diagnosis (issue 10); every field is optional to a reader, so a file
//! written before them still reads ([`super::document`]):
//!
//! ```text
//! effects[].contribution_rms_um  RMS of the radial deviation the effect alone makes, with the
//!                          plotted curve's set-up removal, µm (null for the set-up)
//! effects[].share          contribution_rms_um² / (RMS of the plotted measured deviation)²: the
//!                          effect's share of the error (null for the set-up; shares of
//!                          correlated effects need not add up to 1)
//! plane                    xy, yz or zx: the plane of the two axes with the largest travel; the
//!                          polar angle is measured from the first axis towards the second
//! pitch_mm                 {x, y, z}: the pitch per axis the diagnosis was given, mm or null
//! circles[]                per circle (radius, height) of the path:
//!   .radius_mm, .height_mm nominal radius in the plane and height along its normal, mm
//!   .feed_mm_min           median speed of the nominal path over the circle, mm/min
//!   .samples               samples of the circle (both directions)
//!   .g_um                  ISO 230-4 circular deviation G with the minimum-zone centre: the
//!                          larger of .ccw.g_um and .cw.g_um, µm
//!   .h_um                  hysteresis H: largest ccw − cw difference in a 1° bin, µm
//!   .ccw, .cw, .bidirectional  the minimum zone of that trace (null if not run): {g_um (zone
//!                          width), centre {<axis>_um, <axis>_um} (zone centre relative to the
//!                          least-squares set-up centre, along the plane's axes), radius_offset_um}
//! minimum_zone             {g_um, h_um}: the largest G and H over the circles
//!
//! Written by `jdbb diagnose` from its options, when given:
//! machine                  --machine NAME
//! date_utc                 --date, else the time of the diagnosis (RFC 3339, UTC)
//! tolerance                {g_um, pass}: --tolerance-um and whether every circle's G is within it
//! calibration              --calibration FILE: the instrument calibration (jdbb-core Calibration)
//! plan                     the test plan, when the diagnosis was given one (read as an opaque
//!                          object by the report and the history)
//! ```
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
use super::diagnose::Diagnosis;
use super::plan::{Plan, Sense};
use super::sync::Sync;
use super::zone::CircleZone;
use crate::numerics::mzc::MinimumZone;

/// Human summary of a diagnosis.
pub fn summary(d: &Diagnosis) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "{} samples", d.samples);
    let _ = writeln!(
        s,
        "ideal machine (D = |p|): RMS {:.3} µm, peak-to-valley {:.3} µm",
        d.baseline_rms_um, d.baseline_pv_um
    );
    for (i, f) in d.effects.iter().enumerate() {
        let step = if i < 2 {
            "set-up".to_string()
        } else {
            format!("step {}", i - 1)
        };
        let sig = f
            .sigma
            .map(|s| format!(" ± {s:.4}"))
            .unwrap_or_else(|| " (undetermined)".into());
        let _ = writeln!(
            s,
            "{step}: {} = {:.4}{sig} {} — {}",
            f.effect.name(),
            f.value,
            crate::units::human(f.effect.unit()),
            f.effect.cause()
        );
        let params: Vec<String> = f
            .effect
            .param_names()
            .iter()
            .zip(&f.params)
            .zip(&f.param_sigma)
            .map(|((n, v), s)| match s {
                Some(s) => format!("{n} = {v:.4} ± {s:.4}"),
                None => format!("{n} = {v:.4} (undetermined, held)"),
            })
            .collect();
        let _ = writeln!(s, "    {}", params.join(", "));
        if i >= 2 || i == 1 {
            let _ = writeln!(
                s,
                "    RMS after {:.3} µm, gain ×{:.2}{}",
                f.rms_after_um,
                f.rms_ratio,
                if f.delta_bic.is_finite() {
                    format!(", ΔBIC {:.1}", f.delta_bic)
                } else {
                    String::new()
                }
            );
        }
    }
    if d.effects.len() <= 2 {
        let _ = writeln!(s, "no machine effect is supported by the data");
    }
    for g in &d.confounded {
        let _ = writeln!(
            s,
            "confounded (this test cannot tell apart): {}",
            g.join(", ")
        );
    }
    for (name, peak) in &d.below_floor {
        let _ = writeln!(
            s,
            "below the floor (significant, but at most {peak:.3} µm on D, under {:.3} µm): {name} — not named",
            d.floor_um
        );
    }
    for w in &d.not_significant {
        let params: Vec<String> = w
            .params
            .iter()
            .map(|(n, v)| format!("{n} = {v:.4}"))
            .collect();
        let _ = writeln!(
            s,
            "not significant (|value| < 2σ, σ with the timing uncertainty): {} = {:.3} ± {:.3} {} ({}) — not named",
            w.name,
            w.value,
            w.sigma_value,
            crate::units::human(w.unit),
            params.join(", ")
        );
    }
    let _ = writeln!(
        s,
        "final: RMS {:.3} µm, gain ×{:.2} over the ideal machine",
        d.final_rms_um, d.gain
    );
    let _ = writeln!(
        s,
        "circular deviation G {:.3} µm, hysteresis H {:.3} µm (ISO 230-4 style, least-squares centre and length removed)",
        d.circular_deviation_g_um, d.hysteresis_h_um
    );
    let partial: Vec<String> = d
        .arcs
        .iter()
        .enumerate()
        .filter(|(_, a)| a.is_partial())
        .map(|(k, a)| {
            // From −180° up, so an arc across the first axis reads −20° to 200°.
            let start = if a.start_deg > 180.0 {
                a.start_deg - 360.0
            } else {
                a.start_deg
            };
            format!(
                "circle {} covers {:.0}° ({:.0}° to {:.0}° from {} towards {})",
                k + 1,
                a.sweep_deg,
                start,
                start + a.sweep_deg,
                ["x", "y", "z"][d.plane.0],
                ["x", "y", "z"][d.plane.1]
            )
        })
        .collect();
    if partial.is_empty() {
        let h: Vec<String> = d
            .harmonics_um
            .iter()
            .enumerate()
            .map(|(k, a)| format!("{}:{:.3}", k + 1, a))
            .collect();
        let _ = writeln!(s, "residual harmonics vs angle (order:µm): {}", h.join(" "));
    } else {
        let _ = writeln!(
            s,
            "partial arc: {}; what it cannot tell from the set-up and the scale is listed as confounded and not tried, the set-up and scale are less sure than on a full circle (their σ says by how much), and residual harmonics are not shown (they need the whole circle)",
            partial.join(", ")
        );
    }
    s
}

/// The documented JSON (see the README): samples, baseline, effects, confounded, final, gain.
pub fn to_json(d: &Diagnosis) -> serde_json::Value {
    use serde_json::{json, Map, Value};
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    let effects: Vec<Value> = d
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
                .zip(&f.param_sigma)
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
                "setup": f.effect.is_setup(),
                "cause": f.effect.cause(),
            })
        })
        .collect();
    let mut v = json!({
        "samples": d.samples,
        "baseline": {"rms_um": num(d.baseline_rms_um), "pv_um": num(d.baseline_pv_um)},
        "effects": effects,
        "confounded": d.confounded,
        "floor_um": num(d.floor_um),
        "below_floor": d.below_floor.iter().map(|(n, p)| json!({"name": n, "peak_um": num(*p)})).collect::<Vec<_>>(),
        "not_significant": d.not_significant.iter().map(|w| json!({
            "name": w.name, "value": num(w.value), "sigma": num(w.sigma_value), "unit": w.unit,
            "params": w.params.iter().map(|(n, v)| (n.to_string(), num(*v))).collect::<serde_json::Map<_, _>>(),
        })).collect::<Vec<_>>(),
        "final": {"rms_um": num(d.final_rms_um)},
        "gain": num(d.gain),
        "harmonics_um": d.harmonics_um,
        "lsq_setup": {
            "x_um": num(d.lsq_setup_um[0]),
            "y_um": num(d.lsq_setup_um[1]),
            "z_um": num(d.lsq_setup_um[2]),
            "e_um": num(d.lsq_setup_um[3]),
        },
        "circular_deviation_g_um": num(d.circular_deviation_g_um),
        "hysteresis_h_um": num(d.hysteresis_h_um),
        "candidates": d.candidates,
        "arcs": d.arcs.iter().map(|a| json!({
            "start_deg": num(a.start_deg), "sweep_deg": num(a.sweep_deg), "partial": a.is_partial(),
        })).collect::<Vec<_>>(),
    });
    add_zones_and_shares(&mut v, d);
    v
}

/// The plane's name (`xy`, `yz`, `zx`) for the axis pair `plane`.
pub fn plane_name(plane: (usize, usize)) -> String {
    let l = ['x', 'y', 'z'];
    format!("{}{}", l[plane.0], l[plane.1])
}

/// The issue 10 fields of the JSON (see the module docs): effect shares, plane, pitch, circles
/// with their conditions and minimum-zone G and H.
fn add_zones_and_shares(v: &mut serde_json::Value, d: &Diagnosis) {
    use serde_json::{json, Value};
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    if let Some(effects) = v["effects"].as_array_mut() {
        for (e, f) in effects.iter_mut().zip(&d.effects) {
            e["contribution_rms_um"] = num(f.contribution_rms_um);
            e["share"] = num(f.share);
        }
    }
    let axes = ['x', 'y', 'z'];
    let zone = |z: &Option<MinimumZone>| match z {
        None => Value::Null,
        Some(z) => {
            let mut centre = serde_json::Map::new();
            centre.insert(format!("{}_um", axes[d.plane.0]), num(z.centre_um[0]));
            centre.insert(format!("{}_um", axes[d.plane.1]), num(z.centre_um[1]));
            json!({"g_um": num(z.width_um), "centre": centre, "radius_offset_um": num(z.radius_offset_um)})
        }
    };
    let circles: Vec<Value> = d
        .circle_zones
        .iter()
        .map(|c: &CircleZone| {
            json!({
                "radius_mm": num(c.radius_mm),
                "height_mm": num(c.height_mm),
                "feed_mm_min": num(c.feed_mm_min),
                "samples": c.samples,
                "g_um": num(c.g_um()),
                "h_um": num(c.h_um),
                "ccw": zone(&c.ccw),
                "cw": zone(&c.cw),
                "bidirectional": zone(&c.both),
            })
        })
        .collect();
    let g = d.circle_zones.iter().map(|c| c.g_um()).fold(0.0, f64::max);
    let h = d.circle_zones.iter().map(|c| c.h_um).fold(0.0, f64::max);
    v["plane"] = json!(plane_name(d.plane));
    v["pitch_mm"] = json!({"x": d.pitch_mm[0], "y": d.pitch_mm[1], "z": d.pitch_mm[2]});
    v["circles"] = Value::Array(circles);
    v["minimum_zone"] = json!({"g_um": num(g), "h_um": num(h)});
}

/// Human summary of a synchronisation: cycle start, feed, clock, acceleration, the arcs used.
pub fn sync_summary(plan: &Plan, s: &Sync) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "synchronised with the plan: cycle start {:.3} s after the record's first sample (device clock {:.0} µs)",
        s.cycle_start_s,
        s.t0_us + 1e6 * s.cycle_start_s
    );
    let _ = writeln!(
        out,
        "feed on the arcs {:.2} % of the programmed {:.1} mm/min{} (on the record's clock); acceleration {:.0} mm/s²",
        s.feed_percent,
        s.programmed_feed_mm_min,
        if s.circles.len() > 1 {
            format!(", spread {:.2} % over the circles", s.feed_spread_percent)
        } else {
            String::new()
        },
        s.accel_mm_s2
    );
    let _ = writeln!(
        out,
        "clock scale {}",
        match s.clock_scale {
            Some(c) => format!(
                "{:.5} (measured dwell / programmed dwell; {:+.0} ppm)",
                c,
                (c - 1.0) * 1e6
            ),
            None =>
                "not measurable (needs two circles with a dwell between them that no move hides)"
                    .to_string(),
        }
    );
    for c in &s.circles {
        let pc = &plan.circles[c.circle];
        let arcs: Vec<String> = c
            .data
            .iter()
            .map(|a| {
                format!(
                    "{} {:.3}–{:.3} s ({} samples)",
                    match a.sense {
                        Sense::Ccw => "ccw",
                        Sense::Cw => "cw",
                    },
                    a.t_start_s,
                    a.t_end_s,
                    a.samples
                )
            })
            .collect();
        let _ = writeln!(
            out,
            "circle {}: R {:.3} mm, height {:.3} mm, D measured {:.4} mm; feed {:.2} %, acceleration on the arcs {:.0} mm/s², timing ± {:.2} ms; data arcs {}",
            c.circle + 1,
            pc.radius_mm,
            pc.height_mm,
            c.d_measured_mm,
            100.0 * c.speed_mm_s / (pc.feed_mm_min / 60.0),
            c.arc_accel_mm_s2,
            1e3 * c.timing_sigma_s,
            arcs.join(", ")
        );
    }
    out
}

/// The synchronisation as JSON (`sync` in the diagnosis JSON; see the module docs).
pub fn sync_json(plan: &Plan, s: &Sync) -> serde_json::Value {
    use serde_json::json;
    json!({
        "cycle_start_s": s.cycle_start_s,
        "cycle_start_device_us": s.t0_us + 1e6 * s.cycle_start_s,
        "programmed_feed_mm_min": s.programmed_feed_mm_min,
        "feed_percent": s.feed_percent,
        "feed_spread_percent": s.feed_spread_percent,
        "clock_scale": s.clock_scale,
        "accel_mm_s2": s.accel_mm_s2,
        "data_samples": s.data_samples(),
        "circles": s.circles.iter().map(|c| {
            let pc = &plan.circles[c.circle];
            json!({
                "circle": c.circle,
                "radius_mm": pc.radius_mm,
                "height_mm": pc.height_mm,
                "d_plan_mm": pc.d_mm,
                "d_measured_mm": c.d_measured_mm,
                "feed_percent": 100.0 * c.speed_mm_s / (pc.feed_mm_min / 60.0),
                "arc_accel_mm_s2": c.arc_accel_mm_s2,
                "timing_sigma_ms": 1e3 * c.timing_sigma_s,
                "feed_in": {"start_s": c.feed_in.profile.t0_s, "end_s": c.feed_in.profile.end_s(),
                            "speed_mm_s": c.feed_in.profile.speed_mm_s, "accel_mm_s2": c.feed_in.profile.accel_mm_s2,
                            "fit_rms_um": c.feed_in.rms_um},
                "feed_out": {"start_s": c.feed_out.profile.t0_s, "end_s": c.feed_out.profile.end_s(),
                             "speed_mm_s": c.feed_out.profile.speed_mm_s, "accel_mm_s2": c.feed_out.profile.accel_mm_s2,
                             "fit_rms_um": c.feed_out.rms_um},
                "data_arcs": c.data.iter().map(|a| json!({
                    "segment": a.segment,
                    "sense": match a.sense { Sense::Ccw => "ccw", Sense::Cw => "cw" },
                    "start_s": a.t_start_s,
                    "end_s": a.t_end_s,
                    "samples": a.samples,
                })).collect::<Vec<_>>(),
            })
        }).collect::<Vec<_>>(),
    })
}

/// What the diagnosis JSON says of the plan (`plan`): the file, dialect, feed and circles, so a
/// report and the machine's history can tell which test this was.
pub fn plan_json(file: &std::path::Path, plan: &Plan) -> serde_json::Value {
    use serde_json::json;
    json!({
        "file": file.display().to_string(),
        "purpose": plan.purpose.name(),
        "dialect": plan.dialect.name(),
        "program": plan.program,
        "plane": plan.plane.name(),
        "feed_mm_min": plan.feed_mm_min,
        "centre_mm": plan.centre_mm,
        "circles": plan.circles.iter().map(|c| json!({
            "radius_mm": c.radius_mm, "height_mm": c.height_mm, "d_mm": c.d_mm,
            "plane": c.plane.name(), "feed_mm_min": c.feed_mm_min,
        })).collect::<Vec<_>>(),
    })
}
