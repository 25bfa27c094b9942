//! Synchronising a recording while it is made: one more circle against the synchronisation so far.
use super::*;

/// What [`synchronise_running`] found for the circle that runs.
#[derive(Debug, Clone, PartialEq)]
pub enum Running {
    /// Its data arcs are all in the record: the synchronisation of that circle alone, its
    /// feed-out placed where the feed puts it (not yet in the record).
    Ready(Sync),
    /// Its feed-in is not in the record yet, or its data arcs end after the record's last
    /// sample: ask again once the record reaches this time (s).
    Wait { until_s: f64 },
}

/// How long [`synchronise_running`] asks to wait when the running circle's feed-in is not in the
/// record yet (s of record time).
pub const RUNNING_RETRY_S: f64 = 0.05;

/// The synchronisation of circle `k` (index into the plan's circles) while it runs, for the live
/// page, which diagnoses a circle as soon as its last data arc ends. [`synchronise`] times a
/// circle between its feed-in and its feed-out, and on a full circle the feed-out comes a 180°
/// overshoot later (4 s at 4000 mm/min on R 90 mm). Here the circle's feed-in is found in D
/// after the circles of `before` (the ones completed, from [`synchronise`]) and its arcs are
/// timed from the end of the feed-in at `before`'s feed (the same override percentage) and the
/// arcs' acceleration `before` measured; the timing σ is what `before`'s feed σ makes of the data
/// arcs' ends. The first circle has nothing before it, and its feed is only known at its feed-out:
/// [`synchronise`] it then.
pub fn synchronise_running(plan: &Plan, rec: &Record, k: usize, before: &Sync) -> Result<Running> {
    let Some(cp) = circle_plans(plan)?.into_iter().find(|c| c.circle == k) else {
        return Err(Error::Usage(format!("the plan has no circle {}", k + 1)));
    };
    let Some(last) = before.circles.last() else {
        return Err(Error::Usage(format!(
            "circle {}: no circle synchronised before it gives the feed",
            k + 1
        )));
    };
    let what = describe_circle(plan, k);
    let Lines {
        a_in,
        b_in,
        a_out,
        b_out,
        fi_feed,
        fo_feed,
        d_in,
        d_c,
        dir,
        mid,
        tol,
    } = cp.lines(plan);
    let Some(&t_last) = rec.t_s.last() else {
        return Ok(Running::Wait {
            until_s: RUNNING_RETRY_S,
        });
    };
    // The feed-in: as in `synchronise`, once the record holds the whole ramp (at half the
    // programmed feed) and a little of the plateau after it.
    let factor = before.feed_percent / 100.0;
    let ramp_s = dist(&a_in, &b_in) / (0.5 * fi_feed / 60.0) + 0.05;
    let mut search = rec.index_at(last.feed_out.profile.end_s());
    let ramp_in = loop {
        let Some(i) = crossing(rec, search, mid, dir) else {
            return Ok(Running::Wait {
                until_s: t_last + RUNNING_RETRY_S,
            });
        };
        if t_last < rec.t_s[i] + ramp_s {
            return Ok(Running::Wait {
                until_s: rec.t_s[i] + ramp_s,
            });
        }
        match fit_ramp(
            rec,
            i,
            a_in,
            b_in,
            d_in,
            d_c,
            fi_feed / 60.0,
            cp.dwell_before_s.clamp(0.005, 0.25),
            0.005,
            None,
        ) {
            Some(r) => break r,
            None => search = i + 1,
        }
    };
    let items = circle_items(plan, &cp)?;
    let programmed = arc_feed(plan, cp.feed_in, cp.feed_out) / 60.0;
    let speed = factor * programmed;
    let sigma = before.feed_sigma_percent / 100.0 * programmed;
    let accel = before
        .circles
        .iter()
        .map(|c| c.arc_accel_mm_s2)
        .sum::<f64>()
        / before.circles.len() as f64;
    let t0 = ramp_in.profile.end_s();
    let (runs, data) = timeline(plan, rec, &items, t0, speed, accel);
    let (_, data_v1) = timeline(plan, rec, &items, t0, speed + sigma, accel);
    let timing_sigma_s = data
        .iter()
        .zip(&data_v1)
        .map(|(x, y)| {
            (x.t_start_s - y.t_start_s)
                .abs()
                .max((x.t_end_s - y.t_end_s).abs())
        })
        .fold(0.0, f64::max);
    let data_end = data.iter().map(|a| a.t_end_s).fold(t0, f64::max);
    let need = data_end + 3.0 * timing_sigma_s + 2.0 * median_interval(&rec.t_s);
    if !need.is_finite() {
        return Err(Error::Usage(format!(
            "{what}: the feed of the circles before it ({:.2} ± {:.2} %) does not time its arcs",
            before.feed_percent, before.feed_sigma_percent
        )));
    }
    if t_last < need {
        return Ok(Running::Wait { until_s: need });
    }
    let (pi, pj) = (
        rec.index_at(t0 + 4.0 * ramp_in.lag_s),
        rec.index_at(data_end),
    );
    if let Some(off) = (pi..pj).find(|&i| (rec.d_mm[i] - d_c).abs() > tol) {
        return Err(Error::Input {
            location: rec.location(off),
            message: format!(
                "{what}: during its arcs D is {:.4} mm at {:.3} s, off the circle's {d_c:.3} mm by more than {tol:.3} mm (another radius, or the instrument moved?)",
                rec.d_mm[off], rec.t_s[off]
            ),
        });
    }
    // Where the feed-out will start: after the last run and the dwells that follow it.
    let mut t_end = t0;
    let mut run = runs.iter();
    for it in &items {
        match it {
            Item::Dwell(s) => t_end += s,
            Item::Run(..) => t_end = run.next().map_or(t_end, |r| r.profile.end_s()),
        }
    }
    let feed_out = Ramp {
        profile: Profile {
            t0_s: t_end,
            length_mm: dist(&a_out, &b_out),
            speed_mm_s: factor * fo_feed / 60.0,
            accel_mm_s2: ramp_in.profile.accel_mm_s2,
        },
        speed_sigma_mm_s: f64::INFINITY,
        rms_um: f64::NAN,
        samples: 0,
        lag_s: ramp_in.lag_s,
    };
    let circle = CircleSync {
        circle: k,
        feed_in: ramp_in,
        feed_out,
        speed_mm_s: speed,
        speed_sigma_mm_s: sigma,
        arc_accel_mm_s2: accel,
        timing_sigma_s,
        d_measured_mm: rec.median(t0, data_end).unwrap_or(f64::NAN),
        data,
        runs,
    };
    Ok(Running::Ready(Sync {
        cycle_start_s: before.cycle_start_s,
        t0_us: rec.t0_us,
        programmed_feed_mm_min: plan.feed_mm_min,
        feed_percent: before.feed_percent,
        feed_spread_percent: 0.0,
        feed_sigma_percent: before.feed_sigma_percent,
        feed_facts: vec![],
        feed_note: Some(format!(
            "circle {} timed from its feed-in at the feed of the circle{} before it, before its own feed-out",
            k + 1,
            if before.circles.len() > 1 { "s" } else { "" }
        )),
        clock_scale: before.clock_scale,
        accel_mm_s2: accel,
        circles: vec![circle],
    }))
}
