//! How fast the arcs ran, from the record itself: the feed facts of each circle's arcs, combined, and the timing residuals that set the data arcs' times.
use super::*;

/// How a circle's arcs ran: speed and its standard error, the acceleration at their starts and
/// stops, and how far the data arcs' times may be off for the speed's standard error.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct ArcTiming {
    pub(super) speed_mm_s: f64,
    pub(super) speed_sigma_mm_s: f64,
    pub(super) accel_mm_s2: f64,
    pub(super) timing_sigma_s: f64,
}

/// One circle as found in the record, before its arcs are timed: its ramps, what runs between
/// them and how long that took.
pub(super) struct Found {
    pub(super) circle: usize,
    pub(super) ramp_in: Ramp,
    pub(super) ramp_out: Ramp,
    /// The feed-in's end: where the arcs start (s).
    pub(super) t0_s: f64,
    pub(super) d_measured_mm: f64,
    pub(super) items: Vec<Item>,
    /// Path length of each run of arcs (mm).
    pub(super) lengths: Vec<f64>,
    /// Time between the feed-in's end and the feed-out's start, less the plan's dwells (s).
    pub(super) avail_s: f64,
    /// The arcs' programmed feed (mm/s).
    pub(super) programmed_mm_s: f64,
    pub(super) lines: LineSpeed,
    /// The ramps' acceleration (mm/s², mean of feed-in and feed-out).
    pub(super) accel_mm_s2: f64,
}

impl Found {
    /// The acceleration at the runs' starts and stops with which they take `avail_s` at speed
    /// `v`: Σ_r (S_r/v + v/a) = T gives a = n·v/(T − ΣS/v); None where no positive one does.
    pub(super) fn accel_for(&self, v: f64) -> Option<f64> {
        let total: f64 = self.lengths.iter().sum();
        let spare = self.avail_s - total / v;
        (spare > 0.0)
            .then(|| self.lengths.len() as f64 * v / spare)
            .filter(|a| a.is_finite() && *a > 0.0)
    }

    /// An acceleration on the arcs a machine whose lines accelerate at `accel_mm_s2` can have
    /// (1/25 … 10 times the lines': a controller shares its budget on an arc between the
    /// tangential and the centripetal part — LinuxCNC keeps half for the tangent — and takes
    /// the smaller of the plane's two axes, while the ramps measure the feed-in's axis alone,
    /// which may accelerate several times faster).
    pub(super) fn plausible(&self, a: f64) -> bool {
        (0.04 * self.accel_mm_s2..=10.0 * self.accel_mm_s2).contains(&a)
    }
}

/// Where an estimate of the feed comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeedSource {
    /// The cruise of a circle's feed-in (or, where the feed-in gives none, its feed-out): a ruler
    /// as long as the cruise with the machine's errors along its axis printed on it.
    Ramp,
    /// The arcs' durations between feed-in and feed-out of circles of different lengths at one
    /// programmed feed, solved together for the speed and the arcs' acceleration: a ruler as long
    /// as the difference of the circles' paths, read off the ramps' ends.
    ArcDurations,
}

impl FeedSource {
    /// The name in outputs (JSON `source`, the summary).
    pub fn name(self) -> &'static str {
        match self {
            FeedSource::Ramp => "ramp",
            FeedSource::ArcDurations => "arc_durations",
        }
    }
}

/// One estimate of the feed factor (measured over programmed feed, on the record's clock).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeedFact {
    pub source: FeedSource,
    /// The plan's circle it comes from (None: several circles together).
    pub circle: Option<usize>,
    /// Measured over programmed feed.
    pub factor: f64,
    /// Its standard error, including a bound on what the machine's errors can do to it.
    pub sigma: f64,
}

/// How far the machine's errors can bend a ramp that cruised (relative): a cyclic error of 5 µm
/// over a 3 mm pitch, 2πA/P = 10⁻². Where its speed leaves the arcs no plausible acceleration,
/// the arcs' speed is searched in their data within this of it (`arc_motion`).
pub const RULER_WINDOW: f64 = 0.01;

/// What the machine's position errors along a ramp's axis that no diagnosis names may change
/// over the ramp's cruise (µm): a ramp's speed is read through D along a ruler as long as its
/// cruise, and carries this over that length as a bound (1.7·10⁻⁴ on the default 2 mm feed-in
/// at 1000 mm/min). The errors a diagnosis names (a cyclic error of a few µm over a pitch of a
/// few mm stretches a 2 mm feed-in by 10⁻³) are taken off the ruler ([`Ruler`]) before.
pub const RULER_ERROR_UM: f64 = 0.25;

/// The least relative bound on a ramp's ruler, whatever its length: errors that grow with the
/// travel (a scale error no diagnosis names, or one it names as a twin that agrees with it on
/// the circle and not along the radial ramp, e.g. a second-order scale for a bow) change over a
/// ruler in proportion to its length; 100 µm/m.
pub const RULER_SLOPE_BOUND: f64 = 1e-4;

/// How far the machine's errors may move the times at which a circle's ramps end and start
/// apart between circles (µm of path, over the speed): a backlash, a spike or a cyclic error
/// seen at another radius.
pub const RAMP_END_ERROR_UM: f64 = 3.0;

/// Every estimate of the feed factor the record holds: each circle's ramp cruise (where it
/// cruised and gives its arcs a plausible acceleration) and the arcs' durations of circles at
/// one feed solved together. (The arcs' data were tried as a third and are not one: fitting the
/// speed to them hides in the timeline whatever the fit does not model — a cyclic error on y
/// moved it by 5·10⁻³ — see docs/synchronisation.md.)
pub(super) fn feed_facts(rec: &Record, found: &[Found]) -> Vec<FeedFact> {
    let mut facts = vec![];
    for f in found {
        let l = f.lines;
        if l.sigma_mm_s.is_finite() && f.accel_for(l.speed_mm_s).is_some_and(|a| f.plausible(a)) {
            let ruler = l.speed_mm_s
                * (1e-3 * RULER_ERROR_UM / l.cruise_mm.max(1e-3)).hypot(RULER_SLOPE_BOUND);
            facts.push(FeedFact {
                source: FeedSource::Ramp,
                circle: Some(f.circle),
                factor: l.speed_mm_s / f.programmed_mm_s,
                sigma: l.sigma_mm_s.hypot(ruler) / f.programmed_mm_s,
            });
        }
    }
    let dt = median_interval(&rec.t_s);
    let mut covered = vec![false; found.len()];
    for (i, f) in found.iter().enumerate() {
        if covered[i] {
            continue;
        }
        let group: Vec<usize> = (i..found.len())
            .filter(|&j| (found[j].programmed_mm_s / f.programmed_mm_s - 1.0).abs() < 1e-9)
            .collect();
        if let Some(fact) = arc_durations(found, &group, dt) {
            for &j in &group {
                covered[j] = true;
            }
            facts.push(fact);
        }
    }
    facts
}

/// The feed factor from the arcs' durations of the circles `group` (one programmed feed): each
/// circle's time between its feed-in's end and its feed-out's start, less the dwells, is
/// ΣS/v + n·(v/a) — linear in 1/v and v/a — so circles of different path lengths give both,
/// whatever acceleration the controller uses on arcs (the same on every circle of the test). The
/// ramps' ends are timed to the sample interval and to what a few µm of the machine's errors
/// ([`RAMP_END_ERROR_UM`]) move them by; a constant shift, the same on every circle, goes into
/// v/a. None where the circles' lengths per run differ by less than 1 % or the solution is not
/// physical.
pub(super) fn arc_durations(found: &[Found], group: &[usize], dt: f64) -> Option<FeedFact> {
    if group.len() < 2 {
        return None;
    }
    let per_run: Vec<f64> = group
        .iter()
        .map(|&j| found[j].lengths.iter().sum::<f64>() / found[j].lengths.len() as f64)
        .collect();
    let (lo, hi) = per_run
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(l, h), &x| (l.min(x), h.max(x)));
    if hi < 1.01 * lo {
        return None;
    }
    // Weighted least squares for (x, y) = (1/v, v/a): rows (ΣS, n) → T.
    let (mut n11, mut n12, mut n22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut rows = vec![];
    for &j in group {
        let f = &found[j];
        let total: f64 = f.lengths.iter().sum();
        let n = f.lengths.len() as f64;
        let v = total / f.avail_s;
        let sigma_t = std::f64::consts::SQRT_2 * (0.5 * dt).hypot(1e-3 * RAMP_END_ERROR_UM / v);
        let w = 1.0 / (sigma_t * sigma_t);
        n11 += w * total * total;
        n12 += w * total * n;
        n22 += w * n * n;
        b1 += w * total * f.avail_s;
        b2 += w * n * f.avail_s;
        rows.push((total, n, f.avail_s, w));
    }
    let det = n11 * n22 - n12 * n12;
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let x = (n22 * b1 - n12 * b2) / det;
    let y = (n11 * b2 - n12 * b1) / det;
    if !(x > 0.0 && y > 0.0) {
        return None;
    }
    // With more than two circles, the scatter about the fit scales the standard error.
    let dof = rows.len() as f64 - 2.0;
    let chi2: f64 = rows
        .iter()
        .map(|&(s, n, t, w)| w * (t - s * x - n * y).powi(2))
        .sum();
    let scale = if dof > 0.0 {
        (chi2 / dof).max(1.0)
    } else {
        1.0
    };
    let sigma_x = (scale * n22 / det).sqrt();
    let programmed = found[group[0]].programmed_mm_s;
    let v = 1.0 / x;
    Some(FeedFact {
        source: FeedSource::ArcDurations,
        circle: None,
        factor: v / programmed,
        sigma: sigma_x / (x * x) / programmed,
    })
}

/// The feed facts together: their weighted mean and its standard error, scaled up by their
/// scatter where it exceeds their standard errors; a note where a fact lies more than 3σ from
/// the others.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Feed {
    pub(super) factor: f64,
    pub(super) sigma: f64,
    pub(super) note: Option<String>,
}

/// Combine `facts` ([`Feed`]); None without any.
pub(super) fn combine(facts: &[FeedFact]) -> Option<Feed> {
    let usable: Vec<&FeedFact> = facts
        .iter()
        .filter(|f| f.factor.is_finite() && f.sigma.is_finite() && f.sigma > 0.0)
        .collect();
    if usable.is_empty() {
        return None;
    }
    let wsum: f64 = usable.iter().map(|f| f.sigma.powi(-2)).sum();
    let factor = usable
        .iter()
        .map(|f| f.factor * f.sigma.powi(-2))
        .sum::<f64>()
        / wsum;
    let mut sigma = wsum.powf(-0.5);
    let chi2: f64 = usable
        .iter()
        .map(|f| ((f.factor - factor) / f.sigma).powi(2))
        .sum();
    if usable.len() > 1 {
        sigma *= (chi2 / (usable.len() - 1) as f64).max(1.0).sqrt();
    }
    // A fact off the others' mean by more than 3σ (its own and theirs together).
    let outliers: Vec<String> = usable
        .iter()
        .filter_map(|f| {
            let rest: Vec<FeedFact> = usable
                .iter()
                .filter(|g| !std::ptr::eq(**g, *f))
                .map(|g| **g)
                .collect();
            let others = combine_plain(&rest)?;
            let z = (f.factor - others.0) / f.sigma.hypot(others.1);
            (z.abs() > 3.0).then(|| {
                format!(
                    "{}{} says {:.3} ± {:.3} %, the others {:.3} ± {:.3} %",
                    f.source.name(),
                    f.circle
                        .map(|c| format!(" of circle {}", c + 1))
                        .unwrap_or_default(),
                    100.0 * f.factor,
                    100.0 * f.sigma,
                    100.0 * others.0,
                    100.0 * others.1
                )
            })
        })
        .collect();
    let note = (!outliers.is_empty()).then(|| {
        format!(
            "the timing facts disagree beyond their standard errors ({}): the machine's errors bend one of them more than allowed for; the feed is their weighted mean with its standard error scaled by their scatter, and what depends on the timing carries it",
            outliers.join("; ")
        )
    });
    Some(Feed {
        factor,
        sigma,
        note,
    })
}

/// Weighted mean and standard error of `facts`, no scatter scaling (None without any).
pub(super) fn combine_plain(facts: &[FeedFact]) -> Option<(f64, f64)> {
    let wsum: f64 = facts.iter().map(|f| f.sigma.powi(-2)).sum();
    (wsum > 0.0 && wsum.is_finite()).then(|| {
        (
            facts
                .iter()
                .map(|f| f.factor * f.sigma.powi(-2))
                .sum::<f64>()
                / wsum,
            wsum.powf(-0.5),
        )
    })
}

/// Speed and acceleration of a circle's arcs, and the timing's standard error.
///
/// The speed is the combined `feed` ([`feed_facts`], [`combine`]) times the circle's programmed
/// feed; what it cannot tell is the acceleration at the arcs' starts and stops, which a
/// controller may set apart from the lines' (it shares the acceleration between the tangential
/// and the centripetal part). For the speed v the runs' total time fixes it:
/// Σ_r (S_r/v + v/a) = T gives a = n·v/(T − ΣS/v). The speed's standard error then moves the
/// data arcs' times by up to a millisecond or two by the end of a run; that is the timing's
/// standard error, which the diagnosis adds to what depends on it (a reversal spike's height).
///
/// Where the feed gives this circle no acceleration within 1/25 … 10 of the lines' (its arcs
/// ran at another speed, or its ramp's ruler is bent), its speed is searched in its data
/// ([`speed_from_data`]): within [`RULER_WINDOW`] of a ramp that cruised, else over ±20 %; its
/// standard error is that minimum's distance from where the search started (at least 10⁻⁴).
pub(super) fn arc_motion(plan: &Plan, rec: &Record, f: &Found, feed: Option<&Feed>) -> ArcTiming {
    let v_accel = solve_speed(&f.lengths, f.accel_mm_s2, f.avail_s);
    let given = feed
        .map(|fd| (fd.factor * f.programmed_mm_s, fd.sigma * f.programmed_mm_s))
        .filter(|(v, _)| f.accel_for(*v).is_some_and(|a| f.plausible(a)));
    let search = |v0: f64, window: f64| {
        speed_from_data(
            plan,
            rec,
            &f.items,
            &f.lengths,
            f.t0_s,
            f.avail_s,
            v0,
            window,
            TIMING_SAMPLES,
        )
        .map(|(v, _)| (v, (1e-4 * v).max((v - v0).abs())))
    };
    // A ramp that cruised is off by no more than what the machine's errors bend its ruler by
    // ([`RULER_WINDOW`]): the plausible speed nearest to it, if that is within the window (the
    // arcs' time rules the ramp's own speed out, so the truth lies on the plausible side), else a
    // search in the data within the window. Else around the lines' speed if the arcs could have
    // run at it with a plausible acceleration, else around the speed at which the runs,
    // accelerating as the lines do, fill the arcs' time.
    let l = f.lines;
    let nearest = || {
        let (lo, hi) = (
            solve_speed(&f.lengths, 10.0 * f.accel_mm_s2, f.avail_s),
            solve_speed(&f.lengths, 0.04 * f.accel_mm_s2, f.avail_s),
        );
        let v = l.speed_mm_s.clamp(lo, hi.max(lo));
        ((v / l.speed_mm_s - 1.0).abs() <= RULER_WINDOW && f.accel_for(v).is_some())
            .then(|| (v, (1e-4 * v).max((v - l.speed_mm_s).abs())))
    };
    let (v, sigma_v) = match given {
        Some(x) => x,
        None => l
            .sigma_mm_s
            .is_finite()
            .then(|| nearest().or_else(|| search(l.speed_mm_s, RULER_WINDOW)))
            .flatten()
            .or_else(|| {
                let v0 = if f.accel_for(l.speed_mm_s).is_some_and(|a| f.plausible(a)) {
                    l.speed_mm_s
                } else {
                    v_accel
                };
                search(v0, 0.2)
            })
            .unwrap_or((v_accel, 1e-3 * v_accel)),
    };
    let Some(a) = f.accel_for(v) else {
        return ArcTiming {
            speed_mm_s: v_accel,
            speed_sigma_mm_s: f64::INFINITY,
            accel_mm_s2: f.accel_mm_s2,
            timing_sigma_s: f64::INFINITY,
        };
    };
    // The data arcs' ends at v + σ_v against v.
    let (_, at_v) = timeline(plan, rec, &f.items, f.t0_s, v, a);
    let timing_sigma_s = match f.accel_for(v + sigma_v) {
        Some(a1) => {
            let (_, at_v1) = timeline(plan, rec, &f.items, f.t0_s, v + sigma_v, a1);
            at_v.iter()
                .zip(&at_v1)
                .map(|(x, y)| {
                    (x.t_start_s - y.t_start_s)
                        .abs()
                        .max((x.t_end_s - y.t_end_s).abs())
                })
                .fold(0.0, f64::max)
        }
        None => f64::INFINITY,
    };
    ArcTiming {
        speed_mm_s: v,
        speed_sigma_mm_s: sigma_v,
        accel_mm_s2: a,
        timing_sigma_s,
    }
}

/// At most this many data samples of a circle enter the search of the arcs' speed where it is
/// the circle's only timing ([`speed_from_data`]); more are taken at an even stride.
pub(super) const TIMING_SAMPLES: usize = 30_000;

/// The data-arc samples of a circle on the timeline of `v0` with the runs unshifted, shrunk by
/// 1 % of each arc's time at both ends (so that nearby timelines have them on their runs too),
/// at most `max_samples` of them at an even stride.
pub(super) fn timing_samples(rec: &Record, data: &[DataArc], max_samples: usize) -> Vec<usize> {
    let mut idx: Vec<usize> = vec![];
    for a in data {
        let m = 0.01 * (a.t_end_s - a.t_start_s);
        let (i, j) = (rec.index_at(a.t_start_s + m), rec.index_at(a.t_end_s - m));
        idx.extend(i..j);
    }
    let stride = idx.len().div_ceil(max_samples).max(1);
    idx.into_iter().step_by(stride).collect()
}

/// Positions (relative to the table ball, mm) and unit tangents of the samples `idx` on the
/// timeline at speed `v`, acceleration `a`.
#[allow(clippy::too_many_arguments)]
pub(super) fn nominal_on_runs(
    plan: &Plan,
    rec: &Record,
    items: &[Item],
    idx: &[usize],
    t0: f64,
    v: f64,
    a: f64,
) -> Vec<([f64; 3], [f64; 3])> {
    let centre = plan.centre_mm;
    let (runs, _) = timeline(plan, rec, items, t0, v, a);
    idx.iter()
        .map(|&i| {
            let t = rec.t_s[i];
            let run = runs
                .iter()
                .rev()
                .find(|r| r.profile.t0_s <= t)
                .unwrap_or(&runs[0]);
            let s = run.profile.s_at(t);
            let (seg, at, _) = run
                .arcs
                .iter()
                .rev()
                .find(|x| x.1 <= s)
                .copied()
                .unwrap_or(run.arcs[0]);
            let q = plan.position_at(seg, s - at);
            let (q1, q2) = (
                plan.position_at(seg, s - at - 1e-3),
                plan.position_at(seg, s - at + 1e-3),
            );
            let d = [q2[0] - q1[0], q2[1] - q1[1], q2[2] - q1[2]];
            let n = dist(&q1, &q2).max(1e-12);
            (
                [q[0] - centre[0], q[1] - centre[1], q[2] - centre[2]],
                [d[0] / n, d[1] / n, d[2] / n],
            )
        })
        .collect()
}

/// The arcs' speed from the data of one circle alone: the v within `v0`·(1 ± `window`) — each
/// with the acceleration the runs' total time then implies — whose timeline leaves the least
/// residual after [`timing_residuals`]' fit (golden section, on at most `max_samples` samples),
/// and its standard error from the residual's curvature there. None where the data do not
/// determine it (the least residual at the window's edge), or no acceleration is physical.
#[allow(clippy::too_many_arguments)]
pub(super) fn speed_from_data(
    plan: &Plan,
    rec: &Record,
    items: &[Item],
    lengths: &[f64],
    t0: f64,
    avail: f64,
    v0: f64,
    window: f64,
    max_samples: usize,
) -> Option<(f64, f64)> {
    let n_runs = lengths.len();
    let total: f64 = lengths.iter().sum();
    let accel_for = |v: f64| {
        let spare = avail - total / v;
        (spare > 0.0)
            .then(|| n_runs as f64 * v / spare)
            .filter(|a| a.is_finite() && *a > 0.0)
    };
    // The samples: on the data arcs of a timeline within the window that the arcs' time allows.
    let (vs, a0) = [v0, v0 * (1.0 + 0.5 * window), v0 * (1.0 + window)]
        .into_iter()
        .find_map(|v| accel_for(v).map(|a| (v, a)))?;
    let (_, data0) = timeline(plan, rec, items, t0, vs, a0);
    let idx = timing_samples(rec, &data0, max_samples);
    if idx.len() < 64 {
        return None;
    }
    let ssr = |v: f64| -> f64 {
        let Some(a) = accel_for(v) else {
            return f64::INFINITY;
        };
        let nominal = nominal_on_runs(plan, rec, items, &idx, t0, v, a);
        timing_residuals(&nominal, v, idx.iter().map(|&i| (rec.t_s[i], rec.d_mm[i])))
            .iter()
            .map(|x| x * x)
            .sum()
    };
    let (lo0, hi0) = (v0 * (1.0 - window), v0 * (1.0 + window));
    let (mut lo, mut hi) = (lo0, hi0);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (ssr(x1), ssr(x2));
    for _ in 0..40 {
        if f1 < f2 {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - g * (hi - lo);
            f1 = ssr(x1);
        } else {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + g * (hi - lo);
            f2 = ssr(x2);
        }
    }
    let (v, f) = if f1 < f2 { (x1, f1) } else { (x2, f2) };
    let interior = (v - lo0).min(hi0 - v) >= 0.05 * (hi0 - lo0);
    if !(f.is_finite() && interior) {
        return None;
    }
    // Its standard error from the residual's curvature there: SSR(v) ≈ SSR_min + k·(v − v̂)²,
    // σ² = s²/k with s² = SSR_min/(N − columns).
    let h = 1e-4 * v;
    let k = (ssr(v + h) + ssr(v - h) - 2.0 * f) / (2.0 * h * h);
    let s2 = f / (idx.len() as f64 - TIMING_COLUMNS as f64).max(1.0);
    let sigma = if k > 0.0 && k.is_finite() {
        (s2 / k).sqrt()
    } else {
        window * v
    };
    Some((v, sigma))
}

/// Columns of [`timing_design`]: u (3), 1, backlash (3), reversal spike at two τ (6), drift,
/// servo delay per axis (3), linear distortion p_i·p_j/|p| (6).
pub(super) const TIMING_COLUMNS: usize = 3 + 1 + 3 + 6 + 1 + 3 + 6;

/// The residual (µm) of D − |p| after a linear least-squares fit of what ties D to the angle and
/// the time of a sample, over samples in time order with nominal positions and tangents
/// (`nominal`, relative to the table ball) at speed `v`, and (t, D): the set-up (u·c + e); every
/// moving axis's backlash step (f_k/2)·dir_k·u_k and reversal spike −h_k·dir_k·u_k·e^(−Δt/τ)
/// ([`Effect::ReversalSpike`], linear in h at τ 10 and 30 ms) from the axis's reversal (the
/// vertex of a parabola through the samples around it, so that it moves smoothly with the
/// timeline), its direction held through standstills and gaps; a drift (t); each axis's servo
/// delay u_k·v_k; and the linear distortions (scale, squareness) p_i·p_j/|p|. A fit without one
/// of these would move the timeline to hide it. Columns that do not move drop out (a small
/// ridge).
///
/// [`Effect::ReversalSpike`]: crate::model::Effect::ReversalSpike
pub(super) fn timing_residuals(
    nominal: &[([f64; 3], [f64; 3])],
    v: f64,
    samples: impl Iterator<Item = (f64, f64)>,
) -> Vec<f64> {
    use nalgebra::{DMatrix, DVector};
    const TAU_S: [f64; 2] = [0.010, 0.030];
    const W: usize = TIMING_COLUMNS;
    let mut rows: Vec<[f64; W]> = Vec::with_capacity(nominal.len());
    let mut y: Vec<f64> = Vec::with_capacity(nominal.len());
    let mut dir = [0.0f64; 3];
    let mut t_rev = [f64::NEG_INFINITY; 3];
    let mut hist: Vec<([f64; 3], f64)> = Vec::with_capacity(2);
    for ((p, tangent), (t, d)) in nominal.iter().zip(samples) {
        if let Some(&(q, tq)) = hist.last() {
            for k in 0..3 {
                let dp = p[k] - q[k];
                if dp.abs() > 1e-9 {
                    let new = dp.signum();
                    if dir[k] != 0.0 && new != dir[k] {
                        t_rev[k] = match hist.first() {
                            Some(&(q0, t0)) if hist.len() == 2 => {
                                vertex([t0, tq, t], [q0[k], q[k], p[k]]).unwrap_or(0.5 * (t + tq))
                            }
                            _ => 0.5 * (t + tq),
                        };
                    }
                    dir[k] = new;
                }
            }
        }
        if hist.len() == 2 {
            hist.remove(0);
        }
        hist.push((*p, t));
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        let u = [p[0] / r, p[1] / r, p[2] / r];
        let mut row = [0.0f64; W];
        row[..3].copy_from_slice(&u);
        row[3] = 1.0;
        for k in 0..3 {
            row[4 + k] = 0.5 * dir[k] * u[k];
            for (m, tau) in TAU_S.iter().enumerate() {
                row[7 + 3 * m + k] = -dir[k] * u[k] * (-(t - t_rev[k]) / tau).exp();
            }
            row[14 + k] = u[k] * v * tangent[k];
        }
        row[13] = t;
        let mut c = 17;
        for i in 0..3 {
            for j in i..3 {
                row[c] = p[i] * p[j] / r;
                c += 1;
            }
        }
        rows.push(row);
        y.push(1e3 * (d - r));
    }
    let mut g = DMatrix::<f64>::zeros(W, W);
    let mut b = DVector::<f64>::zeros(W);
    for (row, yi) in rows.iter().zip(&y) {
        for i in 0..W {
            b[i] += row[i] * yi;
            for j in i..W {
                g[(i, j)] += row[i] * row[j];
            }
        }
    }
    // Scale the columns to unit norm, then a ridge of 10⁻¹⁰ for the ones that do not move or
    // repeat another (an axis at rest, a spike never seen, u_x·p_y = u_y·p_x).
    let scale: Vec<f64> = (0..W)
        .map(|i| {
            let n = g[(i, i)].sqrt();
            if n > 0.0 {
                n
            } else {
                1.0
            }
        })
        .collect();
    let gs = DMatrix::from_fn(W, W, |i, j| {
        let x = if i <= j { g[(i, j)] } else { g[(j, i)] };
        x / (scale[i] * scale[j]) + if i == j { 1e-10 } else { 0.0 }
    });
    let bs = DVector::from_fn(W, |i, _| b[i] / scale[i]);
    let beta = match gs.cholesky() {
        Some(ch) => ch.solve(&bs),
        None => DVector::zeros(W),
    };
    rows.iter()
        .zip(&y)
        .map(|(row, yi)| yi - (0..W).map(|i| row[i] * beta[i] / scale[i]).sum::<f64>())
        .collect()
}

/// Time of the extremum of the parabola through three points (t, x), within their span.
pub(super) fn vertex(t: [f64; 3], x: [f64; 3]) -> Option<f64> {
    let d1 = (x[1] - x[0]) / (t[1] - t[0]);
    let d2 = (x[2] - x[1]) / (t[2] - t[1]);
    let a = (d2 - d1) / (t[2] - t[0]);
    if !(a.is_finite() && a != 0.0) {
        return None;
    }
    let b = d1 - a * (t[0] + t[1]);
    let tv = -b / (2.0 * a);
    (tv.is_finite() && tv >= t[0] && tv <= t[2]).then_some(tv)
}

/// The speed v that runs of `lengths` (each from rest to rest with acceleration `accel`) take
/// exactly `time` s to cover: Σ (S_r/v + v/a) = T, the smaller root of n·v²/a − T·v + ΣS = 0
/// (the other is faster than the runs allow). Falls back to ΣS/T if no root exists.
pub(super) fn solve_speed(lengths: &[f64], accel: f64, time: f64) -> f64 {
    let n = lengths.len() as f64;
    let total: f64 = lengths.iter().sum();
    let disc = time * time - 4.0 * n * total / accel;
    if accel > 0.0 && disc >= 0.0 {
        (time - disc.sqrt()) * accel / (2.0 * n)
    } else {
        total / time
    }
}
