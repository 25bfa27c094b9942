//! The circles of a circular test as the path draws them: the plane of the test, each sample's
//! angle in it, the runs (one circle, one direction, no jump) that the polar plot draws and that
//! G and H are taken over, and the residual's harmonics against the angle.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
use crate::model::path::median_interval;
use crate::model::Path;
use crate::numerics::lsq::GramAccumulator;

/// One circle of the path: nominal radius in the main plane and height along its normal (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    pub radius_mm: f64,
    pub height_mm: f64,
}

/// Consecutive samples of one circle in one direction, with no jump in angle, time, radius or
/// height between neighbours: a polyline through them never draws a chord across a polar plot.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub range: std::ops::Range<usize>,
    /// Index into [`Diagnosis::circles`].
    pub circle: usize,
    /// Counter-clockwise (angle increasing) in the main plane.
    pub ccw: bool,
}

/// Largest angle step (rad) between neighbouring samples of one [`Run`].
pub const MAX_RUN_STEP_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// Cut the samples into [`Run`]s. A new run starts where neighbours differ in angle (in the plane
/// `plane`) by more than `max_step_rad`, in time by more than 5 median sampling intervals, in
/// radius or height by more than 0.01 mm + 1e-4 of the radius, or where the direction of rotation
/// changes (a standstill keeps the direction). Circles are the distinct (radius, height) pairs of
/// the runs' first samples, within 0.5 mm.
pub fn split_runs(
    t_s: &[f64],
    p_mm: &[[f64; 3]],
    plane: (usize, usize),
    max_step_rad: f64,
) -> (Vec<Circle>, Vec<Run>) {
    split_runs_at(t_s, p_mm, &angles(p_mm, plane), plane, max_step_rad)
}

/// The angle (rad) of every position in the plane `plane`: atan2(p[plane.1], p[plane.0]).
pub fn angles(p_mm: &[[f64; 3]], plane: (usize, usize)) -> Vec<f64> {
    p_mm.iter().map(|p| p[plane.1].atan2(p[plane.0])).collect()
}

/// [`split_runs`] with the angles of [`angles`] already computed (the diagnosis needs them for
/// the plot too); each sample's radius is computed once.
pub fn split_runs_at(
    t_s: &[f64],
    p_mm: &[[f64; 3]],
    angle_rad: &[f64],
    plane: (usize, usize),
    max_step_rad: f64,
) -> (Vec<Circle>, Vec<Run>) {
    let n = p_mm.len().min(t_s.len()).min(angle_rad.len());
    let normal = 3 - plane.0 - plane.1;
    // (angle, radius, height) of sample i.
    let polar = |i: usize| {
        let p = &p_mm[i];
        (angle_rad[i], p[plane.0].hypot(p[plane.1]), p[normal])
    };
    let max_dt = if n >= 2 {
        5.0 * median_interval(&t_s[..n])
    } else {
        f64::INFINITY
    };
    let mut circles: Vec<Circle> = vec![];
    let mut runs: Vec<Run> = vec![];
    let mut start = 0;
    // Direction of the current run: None until it has moved.
    let mut dir: Option<bool> = None;
    let mut close = |start: usize, end: usize, dir: Option<bool>, runs: &mut Vec<Run>| {
        if end <= start {
            return;
        }
        let (_, r, h) = polar(start);
        let circle = match circles
            .iter()
            .position(|c| (c.radius_mm - r).abs() < 0.5 && (c.height_mm - h).abs() < 0.5)
        {
            Some(k) => k,
            None => {
                circles.push(Circle {
                    radius_mm: r,
                    height_mm: h,
                });
                circles.len() - 1
            }
        };
        runs.push(Run {
            range: start..end,
            circle,
            ccw: dir.unwrap_or(true),
        });
    };
    let mut prev = if n > 0 { polar(0) } else { (0.0, 0.0, 0.0) };
    for i in 1..n {
        let (a0, r0, h0) = prev;
        let (a1, r1, h1) = polar(i);
        prev = (a1, r1, h1);
        let da = wrap_pi(a1 - a0);
        let tol = 0.01 + 1e-4 * r0.max(r1);
        let step_dir = if da.abs() > 1e-12 {
            Some(da > 0.0)
        } else {
            None
        };
        let jump = da.abs() > max_step_rad
            || t_s[i] - t_s[i - 1] > max_dt
            || (r1 - r0).abs() > tol
            || (h1 - h0).abs() > tol;
        let turn = matches!((dir, step_dir), (Some(a), Some(b)) if a != b);
        if jump || turn {
            close(start, i, dir, &mut runs);
            start = i;
            dir = None;
        } else if dir.is_none() {
            dir = step_dir;
        }
    }
    close(start, n, dir, &mut runs);
    (circles, runs)
}

/// The arc a circle's samples cover in the main plane: where it starts and how far it goes
/// (degrees, ccw). 360° for a full circle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcCover {
    /// Start of the arc, degrees in [0, 360) from the plane's first axis towards its second.
    pub start_deg: f64,
    /// Its length (degrees): 360 minus the largest gap the samples leave.
    pub sweep_deg: f64,
}

impl ArcCover {
    /// Whether the samples leave a gap of more than [`PARTIAL_ARC_GAP_DEG`]: a partial arc.
    pub fn is_partial(&self) -> bool {
        self.sweep_deg < 360.0 - PARTIAL_ARC_GAP_DEG
    }
}

/// A circle whose samples leave an angular gap wider than this (degrees) is a partial arc (the
/// synchronisation's gaps at axis reversals are a few hundredths of a degree).
pub const PARTIAL_ARC_GAP_DEG: f64 = 10.0;

/// The arc each circle's samples cover ([`ArcCover`], in `circles`' order), on 1° bins: the
/// largest run of empty bins, around the circle, is the gap.
pub fn arc_cover(angle: &[f64], runs: &[Run], n_circles: usize) -> Vec<ArcCover> {
    (0..n_circles)
        .map(|c| {
            let mut filled = [false; 360];
            for run in runs.iter().filter(|r| r.circle == c) {
                for i in run.range.clone() {
                    let deg = angle[i].to_degrees().rem_euclid(360.0);
                    filled[(deg as usize).min(359)] = true;
                }
            }
            if filled.iter().all(|&f| f) || !filled.iter().any(|&f| f) {
                return ArcCover {
                    start_deg: 0.0,
                    sweep_deg: if filled[0] { 360.0 } else { 0.0 },
                };
            }
            // Largest circular run of empty bins; the arc starts after it.
            let (mut best, mut best_end, mut run) = (0usize, 0usize, 0usize);
            for k in 0..720 {
                if filled[k % 360] {
                    run = 0;
                } else {
                    run += 1;
                    if run > best {
                        best = run.min(360);
                        best_end = k % 360;
                    }
                }
            }
            ArcCover {
                start_deg: ((best_end + 1) % 360) as f64,
                sweep_deg: (360 - best) as f64,
            }
        })
        .collect()
}

/// `a` wrapped into [−π, π].
pub fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI {
        w - std::f64::consts::TAU
    } else {
        w
    }
}

/// The two axes with the largest travel (the plane of the circle).
pub fn main_plane(path: &Path) -> (usize, usize) {
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| path.range_mm[b].total_cmp(&path.range_mm[a]));
    let (a, b) = (idx[0].min(idx[1]), idx[0].max(idx[1]));
    // Keep a right-handed order: (x,y), (y,z), (z,x).
    match (a, b) {
        (0, 2) => (2, 0),
        ab => ab,
    }
}

/// Amplitudes (µm) of harmonics 1..=n of `r` against `angle` (least squares with a constant).
pub fn harmonics(angle: &[f64], r: &[f64], n: usize) -> Vec<f64> {
    let w = 2 * n + 2;
    let mut acc = GramAccumulator::new(w);
    for (&a, &y) in angle.iter().zip(r) {
        // Row [1, cos θ, sin θ, …, cos nθ, sin nθ, y], cut into its parts up front so the
        // per-sample loop runs without bounds checks.
        let (one, rest) = acc.row().split_at_mut(1);
        let (trig, last) = rest.split_at_mut(2 * n);
        one[0] = 1.0;
        // cos kθ, sin kθ by rotation from one sin_cos (error ~k·ε, fine for k ≤ 100).
        let (s1, c1) = a.sin_cos();
        let (mut c, mut s) = (1.0f64, 0.0f64);
        for cs in trig.chunks_exact_mut(2) {
            (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
            cs[0] = c;
            cs[1] = s;
        }
        last[0] = y;
    }
    let full = acc.finish();
    let g = full.view((0, 0), (w - 1, w - 1)).into_owned();
    let b = full.view((0, w - 1), (w - 1, 1)).column(0).into_owned();
    let coef = match g.clone().cholesky() {
        Some(ch) => ch.solve(&b),
        None => return vec![0.0; n],
    };
    (1..=n)
        .map(|k| coef[2 * k - 1].hypot(coef[2 * k]))
        .collect()
}

/// ISO 230-4 style circular deviation G and hysteresis H (µm) of `dev`, the deviation (µm) from
/// the circle of the least-squares set-up (one centre and length for all samples, not the minimum
/// zone) — the measured curve of the polar plot. Each circle of `runs` is evaluated on its own
/// ([`circle_g_h`]): G is the largest peak-to-valley of one circle in one direction, H the
/// largest difference between a circle's ccw and cw mean deviation in the same 1° angle bin.
pub fn circularity(angle: &[f64], dev: &[f64], runs: &[Run]) -> (f64, f64) {
    let n_circles = runs.iter().map(|r| r.circle + 1).max().unwrap_or(0);
    (0..n_circles)
        .map(|c| circle_g_h(angle, dev, runs, c))
        .fold((0.0f64, 0.0f64), |(g, h), (gc, hc)| (g.max(gc), h.max(hc)))
}

/// [`circularity`] of circle `circle` alone: (largest peak-to-valley of one direction, largest
/// ccw − cw difference of the mean deviation in a 1° bin), µm. H does not depend on a centre
/// shift common to both directions (to first order it moves both traces alike in each bin).
pub fn circle_g_h(angle: &[f64], dev: &[f64], runs: &[Run], circle: usize) -> (f64, f64) {
    let mut g = 0.0f64;
    let mut h = 0.0f64;
    let mut bins = [vec![(0.0f64, 0usize); 360], vec![(0.0f64, 0usize); 360]];
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for run in runs.iter().filter(|r| r.circle == circle) {
        let d = usize::from(!run.ccw);
        for i in run.range.clone() {
            lo[d] = lo[d].min(dev[i]);
            hi[d] = hi[d].max(dev[i]);
            let deg = angle[i].to_degrees().rem_euclid(360.0);
            let k = (deg as usize).min(359);
            bins[d][k].0 += dev[i];
            bins[d][k].1 += 1;
        }
    }
    for d in 0..2 {
        if hi[d] >= lo[d] {
            g = g.max(hi[d] - lo[d]);
        }
    }
    for k in 0..360 {
        let (a, b) = (bins[0][k], bins[1][k]);
        if a.1 > 0 && b.1 > 0 {
            h = h.max((a.0 / a.1 as f64 - b.0 / b.1 as f64).abs());
        }
    }
    (g, h)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A circle of radius `r_mm` at height `h_mm` in xy from angle `a0_deg`, `n` steps of
    /// `step_deg` (negative = cw), sampled every 0.01 s from `t0_s`.
    fn arc(
        r_mm: f64,
        h_mm: f64,
        a0_deg: f64,
        step_deg: f64,
        n: usize,
        t0_s: f64,
    ) -> (Vec<f64>, Vec<[f64; 3]>) {
        (0..n)
            .map(|k| {
                let a = (a0_deg + step_deg * k as f64).to_radians();
                (
                    t0_s + 0.01 * k as f64,
                    [r_mm * a.cos(), r_mm * a.sin(), h_mm],
                )
            })
            .unzip()
    }

    #[test]
    fn split_runs_leaves_no_chord_across_the_polar_plot() {
        // ccw circle, cw circle starting at 180° (a 180° jump), a standstill, then after a 1 s
        // pause a second radius at another height, and a 90° jump inside one ccw pass.
        let mut t = vec![];
        let mut p = vec![];
        let mut add = |(tt, pp): (Vec<f64>, Vec<[f64; 3]>)| {
            t.extend(tt);
            p.extend(pp);
        };
        add(arc(50.0, 0.0, 0.0, 1.0, 360, 0.0));
        add(arc(50.0, 0.0, 180.0, -1.0, 360, 3.6));
        add(arc(50.0, 0.0, 181.0, 0.0, 20, 7.2));
        add(arc(80.0, 10.0, 0.0, 0.5, 200, 8.4));
        add(arc(80.0, 10.0, 190.0, 0.5, 520, 10.4));
        let (circles, runs) = split_runs(&t, &p, (0, 1), MAX_RUN_STEP_RAD);
        assert_eq!(circles.len(), 2, "{circles:?}");
        assert!((circles[1].radius_mm - 80.0).abs() < 1e-9 && circles[1].height_mm == 10.0);
        // Runs tile the samples in order.
        assert_eq!(runs[0].range.start, 0);
        assert_eq!(runs.last().unwrap().range.end, t.len());
        for w in runs.windows(2) {
            assert_eq!(w[0].range.end, w[1].range.start);
        }
        // ccw, cw (+ standstill), ccw radius 80, ccw radius 80 after the 90° jump.
        let kinds: Vec<(usize, bool)> = runs.iter().map(|r| (r.circle, r.ccw)).collect();
        assert_eq!(kinds, vec![(0, true), (0, false), (1, true), (1, true)]);
        for run in &runs {
            let c = circles[run.circle];
            for i in run.range.clone() {
                let r = p[i][0].hypot(p[i][1]);
                assert!((r - c.radius_mm).abs() < 1e-6 && p[i][2] == c.height_mm);
            }
            for i in run.range.clone().skip(1) {
                let da = wrap_pi(p[i][1].atan2(p[i][0]) - p[i - 1][1].atan2(p[i - 1][0]));
                assert!(
                    da.abs() <= MAX_RUN_STEP_RAD,
                    "segment {i} spans {:.1}°",
                    da.to_degrees()
                );
                assert!(
                    da == 0.0 || (da > 0.0) == run.ccw,
                    "direction change in a run"
                );
            }
        }
    }

    #[test]
    fn arc_cover_finds_the_arc_a_circle_covers() {
        // A full circle both ways; a 180° arc from 0° both ways; an arc across 0°, from 300°
        // over 120°, with a 0.5° gap (a reversal guard) inside it.
        let mut t = vec![];
        let mut p = vec![];
        let mut add = |(tt, pp): (Vec<f64>, Vec<[f64; 3]>)| {
            t.extend(tt);
            p.extend(pp);
        };
        add(arc(50.0, 0.0, 0.0, 0.5, 720, 0.0));
        add(arc(60.0, 0.0, 0.25, 0.5, 360, 8.0));
        add(arc(60.0, 0.0, 179.75, -0.5, 360, 12.0));
        add(arc(70.0, 0.0, 300.25, 0.5, 120, 20.0));
        add(arc(70.0, 0.0, 0.75, 0.5, 120, 21.2));
        let (circles, runs) = split_runs(&t, &p, (0, 1), MAX_RUN_STEP_RAD);
        let a = arc_cover(&angles(&p, (0, 1)), &runs, circles.len());
        assert_eq!(a.len(), 3);
        assert_eq!((a[0].start_deg, a[0].sweep_deg), (0.0, 360.0));
        assert!(!a[0].is_partial());
        assert_eq!((a[1].start_deg, a[1].sweep_deg), (0.0, 180.0));
        assert!(a[1].is_partial());
        assert_eq!((a[2].start_deg, a[2].sweep_deg), (300.0, 121.0));
    }

    #[test]
    fn harmonics_recover_amplitudes() {
        let a: Vec<f64> = (0..720).map(|i| (i as f64).to_radians() * 0.5).collect();
        let r: Vec<f64> = a
            .iter()
            .map(|&t| 0.3 + 2.0 * (t + 0.4).cos() + 0.5 * (3.0 * t).sin())
            .collect();
        let h = harmonics(&a, &r, 4);
        assert!((h[0] - 2.0).abs() < 1e-9 && h[1].abs() < 1e-9);
        assert!((h[2] - 0.5).abs() < 1e-9 && h[3].abs() < 1e-9);
    }
}
