//! The data arcs of a synchronised record as the diagnosis takes them: each sample's nominal
//! position and D (binned beyond [`MAX_DATA_SAMPLES`]), and the nominal motion's axis reversals.
#![allow(clippy::needless_range_loop)]
use super::*;

/// The data arcs' samples with their nominal positions (relative to the table ball, mm): the
/// path and D the diagnosis takes. A record with more than [`MAX_DATA_SAMPLES`] data samples is
/// averaged in bins of consecutive samples of one arc. The axis reversals of the whole nominal
/// motion (ramps, lead-in and overshoot arcs, sense reversals) are set on the path.
pub fn data_path(
    plan: &Plan,
    rec: &Record,
    sync: &Sync,
    pitch_mm: [Option<f64>; 3],
) -> Result<(Path, Vec<f64>)> {
    data_path_within(plan, rec, sync, pitch_mm, MAX_DATA_SAMPLES)
}

/// [`data_path`] with at most `max_samples` data samples (bins beyond that): the calibration
/// takes each sample's counts as they are and sets its own bound.
pub fn data_path_within(
    plan: &Plan,
    rec: &Record,
    sync: &Sync,
    pitch_mm: [Option<f64>; 3],
    max_samples: usize,
) -> Result<(Path, Vec<f64>)> {
    let centre = plan.centre_mm;
    let total = sync.data_samples();
    let bin = total.div_ceil(max_samples).max(1);
    let mut t = Vec::with_capacity(total / bin + 16);
    let mut p = Vec::with_capacity(total / bin + 16);
    let mut d = Vec::with_capacity(total / bin + 16);
    let reversals = nominal_reversals(plan, sync);
    let dt = median_interval(&rec.t_s);
    let guard = REVERSAL_GUARD_S.max(1.5 * dt * bin as f64);
    // Reversal times of the axes that move on the data arcs, sorted.
    let mut marks: Vec<f64> = reversals.iter().flatten().map(|r| r.t_s).collect();
    marks.sort_by(f64::total_cmp);
    let near_reversal = |time: f64| {
        let k = marks.partition_point(|&m| m < time - guard);
        k < marks.len() && marks[k] <= time + guard
    };
    let position = |run: &Run, seg: usize, start: f64, time: f64| {
        let s = run.profile.s_at(time) - start;
        let q = plan.position_at(seg, s);
        [q[0] - centre[0], q[1] - centre[1], q[2] - centre[2]]
    };
    for c in &sync.circles {
        for run in &c.runs {
            for &(seg, start, _) in &run.arcs {
                let Some(arc) = c.data.iter().find(|a| a.segment == seg) else {
                    continue;
                };
                let (i0, i1) = (rec.index_at(arc.t_start_s), rec.index_at(arc.t_end_s));
                let mut i = i0;
                while i < i1 {
                    let j = (i + bin).min(i1);
                    let n = (j - i) as f64;
                    let tm = rec.t_s[i..j].iter().sum::<f64>() / n;
                    let dm = rec.d_mm[i..j].iter().sum::<f64>() / n;
                    if !near_reversal(tm) {
                        t.push(tm);
                        p.push(position(run, seg, start, tm));
                        d.push(dm);
                    }
                    i = j;
                }
            }
        }
    }
    if t.len() < 32 {
        return Err(Error::Input {
            location: rec.path.display().to_string(),
            message: format!(
                "only {} samples lie on the plan's data arcs; a diagnosis needs at least 32",
                t.len()
            ),
        });
    }
    let mut path = Path::new(t, p, pitch_mm);
    path.set_reversals(reversals);
    path.timing_sigma_s = sync
        .circles
        .iter()
        .map(|c| c.timing_sigma_s)
        .fold(0.0, f64::max);
    Ok((path, d))
}

/// The axis reversals of the nominal motion of every circle: its feed-in, arcs and feed-out, on
/// the record's clock, found on a 1 ms grid (velocity zero crossings interpolated).
pub(super) fn nominal_reversals(plan: &Plan, sync: &Sync) -> [Vec<Reversal>; 3] {
    let mut out: [Vec<Reversal>; 3] = Default::default();
    for c in &sync.circles {
        let (t_a, t_b) = (c.feed_in.profile.t0_s, c.feed_out.profile.end_s());
        let n = ((t_b - t_a) / 1e-3).ceil().max(2.0) as usize;
        let pos = |time: f64| -> [f64; 3] { nominal_position(plan, c, time) };
        let mut prev_p = pos(t_a);
        let mut prev_v = [0.0f64; 3];
        let mut dir = [0i8; 3];
        for step in 1..=n {
            let time = t_a + (t_b - t_a) * step as f64 / n as f64;
            let q = pos(time);
            let dt = (t_b - t_a) / n as f64;
            for k in 0..3 {
                let v = (q[k] - prev_p[k]) / dt;
                let s = if v > 1e-9 {
                    1
                } else if v < -1e-9 {
                    -1
                } else {
                    0
                };
                if s != 0 && dir[k] != 0 && s != dir[k] {
                    let f = if prev_v[k] != v {
                        prev_v[k] / (prev_v[k] - v)
                    } else {
                        0.0
                    };
                    // Where the axis turned: the extreme of the two grid points around it.
                    let ext = if s > 0 {
                        prev_p[k].min(q[k])
                    } else {
                        prev_p[k].max(q[k])
                    };
                    out[k].push(Reversal {
                        t_s: time - dt + f.clamp(0.0, 1.0) * dt - 0.5 * dt,
                        new_dir: s,
                        p_mm: ext - plan.centre_mm[k],
                    });
                }
                if s != 0 {
                    dir[k] = s;
                }
                prev_v[k] = v;
            }
            prev_p = q;
        }
    }
    for r in &mut out {
        r.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    }
    out
}

/// The nominal position (program coordinates) of circle `c`'s motion at record time `t`.
pub(super) fn nominal_position(plan: &Plan, c: &CircleSync, t: f64) -> [f64; 3] {
    let line = |seg: usize, prof: &Profile| plan.position_at(seg, prof.s_at(t));
    let (fi_seg, fo_seg) = feed_segments(plan, c.circle);
    if t <= c.feed_in.profile.end_s() {
        return line(fi_seg, &c.feed_in.profile);
    }
    if t >= c.feed_out.profile.t0_s {
        return line(fo_seg, &c.feed_out.profile);
    }
    // The run in force (or the last one that ended: a dwell holds its end).
    let mut cur = &c.runs[0];
    for run in &c.runs {
        if run.profile.t0_s <= t {
            cur = run;
        }
    }
    let s = cur.profile.s_at(t);
    let mut last = cur.arcs[0];
    for &a in &cur.arcs {
        if a.1 <= s {
            last = a;
        }
    }
    plan.position_at(last.0, s - last.1)
}

/// The feed-in and feed-out segments of circle `k`.
pub(super) fn feed_segments(plan: &Plan, k: usize) -> (usize, usize) {
    let find = |role: LineRole| {
        plan.segments
            .iter()
            .position(|s| matches!(s, Segment::Line { role: r, circle, .. } if *r == role && *circle == k))
            .unwrap_or(0)
    };
    (find(LineRole::FeedIn), find(LineRole::FeedOut))
}
