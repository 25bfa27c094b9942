//! The synchronisation's text and JSON, and the plan's JSON, in the report of a planned test.
use super::*;

/// How far (%) the measured feed may be from the programmed before the summary warns: a
/// controller's feed runs within a few % of F at 100 % override (its clock and acceleration
/// limits), while an override knob left at 80 % or 130 % changes every servo effect.
pub const FEED_OVERRIDE_WARN_PERCENT: f64 = 5.0;

/// Human summary of a synchronisation: cycle start, feed and acceleration, and what the timing
/// warns of ([`sync_details`] has the clock and the arcs used).
pub fn sync_summary(_plan: &Plan, s: &Sync) -> String {
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
    if let Some(note) = &s.feed_note {
        let _ = writeln!(out, "timing: {note}");
    }
    if (s.feed_percent - 100.0).abs() > FEED_OVERRIDE_WARN_PERCENT {
        let _ = writeln!(
            out,
            "warning: the arcs ran at {:.0} % of the programmed feed (feed override not at 100 %?): servo effects (mismatch, reversal spikes) change with feed, so compare this test only with tests run at the same feed; run it at 100 % override",
            s.feed_percent
        );
    }
    out
}

/// The synchronisation's details behind `--verbose`: the clock scale and, per circle, the
/// radius, height, D measured, feed, acceleration, timing σ and the data arcs' times.
pub fn sync_details(plan: &Plan, s: &Sync) -> String {
    use std::fmt::Write;
    let mut out = String::new();
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
        "feed_sigma_percent": s.feed_sigma_percent,
        "feed_facts": s.feed_facts.iter().map(|f| json!({
            "source": f.source.name(),
            "circle": f.circle,
            "feed_percent": 100.0 * f.factor,
            "sigma_percent": 100.0 * f.sigma,
        })).collect::<Vec<_>>(),
        "feed_note": s.feed_note,
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

/// What the diagnosis JSON says of the plan (`plan`): the file, dialect, feed, the arc every
/// circle runs (plan.json's `arc`: a full circle or a partial arc) and the circles, so a report
/// and the machine's history can tell which test this was.
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
        "arc": plan.arc,
        "circles": plan.circles.iter().map(|c| json!({
            "radius_mm": c.radius_mm, "height_mm": c.height_mm, "d_mm": c.d_mm,
            "plane": c.plane.name(), "feed_mm_min": c.feed_mm_min,
        })).collect::<Vec<_>>(),
    })
}
