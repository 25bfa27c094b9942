//! Lines a recording up with its plan from D alone: where the cycle started, where each circle is,
//! how fast the machine really went, and which samples lie on the data arcs — so a real test needs
//! no hand-entered offsets (`jdbb diagnose --record REC.csv --plan plan.json`).
//!
//! # What D shows
//! The plan's circles are constant-D plateaus: on its arcs the ball distance changes only by the
//! machine's errors (µm). Each circle is entered and left by a radial line, the feed-in and the
//! feed-out, which move D by about the feed-in length (mm), and between motions the machine
//! dwells. So D alone shows, per circle: a dwell at D_in (the feed-in start), a ramp to D_c (the
//! circle), a long plateau at D_c (the arcs, both senses), a ramp back to D_in, a dwell.
//!
//! # How
//! 1. **Find each circle, in plan order.** The feed-in is the first crossing of the midpoint
//!    (D_in + D_c)/2 towards D_c after the previous circle that starts from a standstill at D_in
//!    and arrives at D_c; the feed-out is the next crossing back. Levels match within
//!    [`LEVEL_TOLERANCE_MM`] (set-up and instrument errors are µm). A circle that cannot be found
//!    so — another radius, an aborted run, a missing circle — is an error that names the circle
//!    and what the record does instead; nothing is guessed.
//! 2. **Time the ramps.** D along a line is known geometry, so each ramp gives the path length
//!    s(t) along its line (normalised to the plateaus next to it, which takes out set-up and
//!    instrument offsets); a trapezoidal speed profile — accelerate at a, cruise at v, decelerate
//!    at a — is fitted to it by least squares ([`Profile`]): start, speed and acceleration.
//! 3. **Time the arcs.** The arcs run at the lines' feed. Every timing fact the record holds
//!    estimates it, each with a bound on what the machine's errors can do to it
//!    ([`FeedFact`], `feed_facts`, `combine`; docs/synchronisation.md): the feed-in's cruise (the
//!    feed-out only where the feed-in cannot: the reversal before it biases it), a ruler of
//!    about 2 mm with the errors of its axis printed on it (a cyclic error stretches it by
//!    10⁻³; [`Ruler`] reads it through the errors a diagnosis found, `crate::diagnose::planned`), and the
//!    arcs' durations of circles of different lengths at one feed, solved together for the
//!    speed and the arcs' acceleration. Facts that disagree beyond their bounds are said
//!    ([`Sync::feed_note`]). Between the feed-in's end and the feed-out's start the machine runs
//!    the circle's arcs: runs of tangent arcs of one sense, each from rest to rest (the corner
//!    after the feed-in, the reversal, the corner before the feed-out), and the plan's dwells. With
//!    that speed v, the time the runs took fixes the acceleration at their ends:
//!    Σ_runs (S_r/v + v/a) + Σ dwells = T. Each data arc's samples then get their nominal position
//!    from the run's trapezoidal profile. The speed's standard error moves the data arcs' ends by
//!    the *timing σ* (reported; a reversal spike's height carries it). Where the feed-in's speed
//!    gives no plausible acceleration (the arcs ran at another speed, or the feed-in was too short
//!    to reach the feed: at 2000–4000 mm/min it never cruises), v is searched in the data, around
//!    the feed-in's speed if the arcs' time allows it, else around the speed the feed-in's
//!    acceleration gives.
//! 4. **Report** the cycle start on the record's clock (the first feed-in's start minus the dwell
//!    and the take-up line before it), the measured feed against the programmed one (%, on the record's clock: the
//!    feed override, the controller's timing and the instrument clock's error together), the
//!    clock scale where two circles give a measurable dwell (dwell durations do not follow the
//!    feed override), the acceleration, and the data arcs used with their sample counts.
//!
//! Only the data arcs go to the diagnosis; the lead-in and overshoot arcs, the ramps and the
//! dwells are left out. A partial arc (`jdbb plan --arc-deg`) is the same to all of this: its
//! runs are the arc counter-clockwise and the same arc back clockwise, each from rest to rest,
//! with the reversal dwell between them, and its data arcs the part of each between the lead-in
//! and the overshoot (`tests/tests/arc_hidden.rs` runs the 220° test). The axis reversals of the whole motion (including those in the lead-in,
//! overshoot and at the sense reversal) are handed to the path, for the reversal spike.
//!
//! May use: [`crate::plan`], [`crate::model::path`], [`crate::numerics::lsq`], [`crate::table`].
//!
//! The folder `sync/`: this module lines a recording up with its plan from D alone, its
//! glitches set aside first ([`glitch`]); the record as read (`record`), a ramp's motion
//! profile fitted (`ramp`), the arcs' timing facts (`feed`), a record made while the machine
//! already runs (`running`), the data arcs handed to the diagnosis (`data`), and a ramp read
//! through a position loop's lag ([`loop_lag`], built, not used yet). May use: [`crate::model`], [`crate::plan`],
//! [`crate::numerics`], [`crate::table`]; nothing of `simulate`, `diagnose` or `report`.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
pub mod glitch;
pub mod loop_lag;
mod record;
pub use record::*;
mod running;
pub use running::*;
mod feed;
pub use feed::*;
mod ramp;
pub use ramp::*;
mod data;
pub use data::*;
use std::path::{Path as FsPath, PathBuf};

use crate::model::path::{median_interval, Path, Reversal};
use crate::numerics::lsq::{least_squares, LsqOptions, Problem};
use crate::plan::{ArcRole, LineRole, Plan, Segment, Sense};
use crate::sync::glitch::Glitch;
use crate::table::Table;
use crate::{Error, Result};

/// D on a plateau of the record matches a level of the plan within this (mm): set-up offsets and
/// instrument errors are µm, another radius is mm.
pub const LEVEL_TOLERANCE_MM: f64 = 0.1;

/// Most data-arc samples handed to the diagnosis; a longer record is averaged over consecutive
/// samples of one arc (bins of k samples, k as small as keeps it under this), which bounds memory
/// and time whatever the record's length. 500 000 keeps the diagnosis of a 4.4 M-sample record
/// (three circles at 10 kHz) at 167 MB peak (216 MB at 1 M, 273 MB at 2 M: issue 31's 200 MB);
/// a bin of k samples averages the noise over k/f_s (0.7 ms at k = 7, 10 kHz), far inside the
/// 50-undulation filter, so the effects are unchanged (backlash 5.99946 ± 0.00039 µm at both
/// 1 M and 0.5 M for 6) but the raw G of such a record is that of the record averaged over k.
pub const MAX_DATA_SAMPLES: usize = 500_000;

/// Samples closer than this to an axis reversal of the nominal motion are left out of the data
/// (s), at least 1.5 sample intervals: the step of a backlash (and the start of a reversal spike)
/// happens at the reversal, which the synchronisation places to a fraction of a millisecond — a
/// backlash of f µm at the ramps' ends shifts them by about f/(2v) — so the one or two samples
/// straddling it cannot be told from a mistimed step.
pub const REVERSAL_GUARD_S: f64 = 1e-3;

/// Most samples a record is read with ([`Record::read`]): the record is held whole (time, D and
/// line: 20 bytes a sample) while it is synchronised, so this bounds the memory a diagnosis or a
/// calibration of any record takes (the data arcs binned to [`MAX_DATA_SAMPLES`]: 9.8 million
/// samples were diagnosed in 580 MB; a calibration holds the counts too, about 1 GB). 10
/// million samples is 33 min at 5 kHz, 2.8 h at 1 kHz: a ballbar test lasts minutes.
pub const MAX_RECORD_SAMPLES: usize = 10_000_000;

/// A record with more than one glitch in this many samples is refused: not glitches but a
/// faulty instrument or cable.
pub const MAX_GLITCH_SHARE: usize = 100;

/// Feed factors (measured over programmed) outside this range are not a machine running the
/// plan: the record belongs to another program or the run was disturbed.
pub const FEED_RANGE: (f64, f64) = (0.05, 3.0);

/// The fastest a ballbar test's arcs are taken to run (% of the plan's feed): controllers allow
/// overrides of 120–200 %, but a test run faster than this is taken as a record of another
/// program (or of edited F words), which it far more often is than a knob left at 150–200 %.
pub const MAX_OVERRIDE_PERCENT: f64 = 150.0;

/// The least feed (% of the programmed) the arcs of the synchronised circles ran at, on the
/// record's clock, from times alone: each circle's arcs (length S) and dwells (D) took the time
/// T between its feed-in's end and its feed-out's start, so they ran at least at S / (T − D)
/// (acceleration only adds time). The mean over the circles; None without a circle. Unlike the
/// fitted speed, this does not depend on a feed-in that cruises.
pub fn least_feed_percent(plan: &Plan, sync: &Sync) -> Option<f64> {
    let mut v = vec![];
    for c in &sync.circles {
        let seg_of = |role: LineRole| {
            plan.segments.iter().position(|s| {
                matches!(s, Segment::Line { role: r, circle, .. } if *r == role && *circle == c.circle)
            })
        };
        let (Some(a), Some(b)) = (seg_of(LineRole::FeedIn), seg_of(LineRole::FeedOut)) else {
            continue;
        };
        let (mut length, mut dwell) = (0.0, 0.0);
        for s in plan.segments.get(a + 1..b).unwrap_or_default() {
            match s {
                Segment::Arc { .. } => length += s.length_mm(),
                Segment::Dwell { seconds } => dwell += seconds,
                _ => {}
            }
        }
        let moving_s = c.feed_out.profile.t0_s - c.feed_in.profile.end_s() - dwell;
        // Each circle against its own feed (a feed sweep runs circles at several).
        let feed_mm_s = plan.circles[c.circle].feed_mm_min / 60.0;
        if moving_s > 0.0 && length > 0.0 && feed_mm_s > 0.0 {
            v.push(length / moving_s / feed_mm_s);
        }
    }
    (!v.is_empty()).then(|| 100.0 * v.iter().sum::<f64>() / v.len() as f64)
}

/// Refuse a record whose arcs ran faster than [`MAX_OVERRIDE_PERCENT`] of the plan's feed, by
/// [`least_feed_percent`] (a bound that holds where the fitted feed is uncertain): the machine
/// did not run this plan's program as written.
pub fn check_feed(plan: &Plan, sync: &Sync, rec: &Record) -> Result<()> {
    match least_feed_percent(plan, sync) {
        Some(pct) if pct > MAX_OVERRIDE_PERCENT => Err(Error::Input {
            location: rec.path.display().to_string(),
            message: format!(
                "the arcs ran at {pct:.0} % of the plan's feed {} mm/min or faster, more than a ballbar test is run at ({MAX_OVERRIDE_PERCENT:.0} %): the machine ran another program, its F words were edited, or the override knob was far up. Record the plan's own program at an override of at most {MAX_OVERRIDE_PERCENT:.0} %, or give the plan.json of the program that ran",
                sync.programmed_feed_mm_min
            ),
        }),
        _ => Ok(()),
    }
}

/// One data arc as found in the record.
#[derive(Debug, Clone, PartialEq)]
pub struct DataArc {
    /// Index of the arc in the plan's segments.
    pub segment: usize,
    pub sense: Sense,
    pub t_start_s: f64,
    pub t_end_s: f64,
    /// Record samples on it.
    pub samples: usize,
}

/// A run of tangent arcs of one sense, from rest to rest, as timed in the record.
#[derive(Debug, Clone, PartialEq)]
struct Run {
    profile: Profile,
    /// (plan segment, path length where it starts in the run, its length).
    arcs: Vec<(usize, f64, f64)>,
}

/// One circle as found in the record.
#[derive(Debug, Clone, PartialEq)]
pub struct CircleSync {
    /// Index into the plan's circles.
    pub circle: usize,
    pub feed_in: Ramp,
    pub feed_out: Ramp,
    /// Speed on the arcs (mm/s on the record's clock).
    pub speed_mm_s: f64,
    /// Its standard error (mm/s).
    pub speed_sigma_mm_s: f64,
    /// Acceleration at the arcs' starts and stops (mm/s²): the ramps' unless the data say
    /// otherwise (see the module docs).
    pub arc_accel_mm_s2: f64,
    /// How far the data arcs' times may be off for the speed's standard error (s; see
    /// `arc_motion`).
    pub timing_sigma_s: f64,
    /// D measured on the arcs' plateau (median, mm).
    pub d_measured_mm: f64,
    pub data: Vec<DataArc>,
    runs: Vec<Run>,
}

/// The synchronisation of a record with its plan.
#[derive(Debug, Clone, PartialEq)]
pub struct Sync {
    /// The cycle start (after the program stop) in s after the record's first sample.
    pub cycle_start_s: f64,
    /// The record's first `t_us` (so the cycle start on the device clock is
    /// `t0_us + 1e6·cycle_start_s`).
    pub t0_us: f64,
    /// Programmed feed on the arcs (mm/min).
    pub programmed_feed_mm_min: f64,
    /// Measured over programmed feed on the arcs, %, and its spread over the circles (standard
    /// deviation, %; 0 with one circle).
    pub feed_percent: f64,
    pub feed_spread_percent: f64,
    /// Standard error of the feed (%): what the timing facts leave, each weighed by what the
    /// machine's errors can do to it (see [`FeedFact`]).
    pub feed_sigma_percent: f64,
    /// Every estimate of the feed the record gave, before they were combined.
    pub feed_facts: Vec<FeedFact>,
    /// Where the facts disagree beyond their standard errors: which, by how much, and which were
    /// used (for the user; None when they agree).
    pub feed_note: Option<String>,
    /// Measured dwell over programmed dwell, where two circles give one (dwell times do not
    /// follow the feed override: this is the controller's and the instrument's clocks).
    pub clock_scale: Option<f64>,
    /// Acceleration fitted on the ramps (mm/s², mean).
    pub accel_mm_s2: f64,
    pub circles: Vec<CircleSync>,
}

impl Sync {
    /// The synchronisation of its last circle alone (the live page diagnoses each circle as it
    /// ends): the feed and clock as all the circles measured them.
    pub fn last_circle(&self) -> Sync {
        Sync {
            circles: self.circles.last().cloned().into_iter().collect(),
            ..self.clone()
        }
    }

    /// Number of data-arc samples.
    pub fn data_samples(&self) -> usize {
        self.circles
            .iter()
            .flat_map(|c| &c.data)
            .map(|a| a.samples)
            .sum()
    }
}

/// The plan's segments of one circle: its feed-in, feed-out and what lies between.
struct CirclePlan {
    circle: usize,
    feed_in: usize,
    feed_out: usize,
    /// Dwells between the previous motion and the feed-in (seconds).
    dwell_before_s: f64,
}

/// A circle's feed-in and feed-out as the synchronisation reads them: their ends relative to the
/// table ball (mm), their feeds (mm/min), D's levels at the feed-in start and on the circle, the
/// direction and midpoint of the feed-in's crossing, and how far D may stray from a level (mm).
struct Lines {
    a_in: [f64; 3],
    b_in: [f64; 3],
    a_out: [f64; 3],
    b_out: [f64; 3],
    fi_feed: f64,
    fo_feed: f64,
    d_in: f64,
    d_c: f64,
    dir: f64,
    mid: f64,
    tol: f64,
}

impl CirclePlan {
    fn lines(&self, plan: &Plan) -> Lines {
        let (
            Segment::Line {
                from_mm: fi_from,
                to_mm: fi_to,
                feed_mm_min: fi_feed,
                ..
            },
            Segment::Line {
                from_mm: fo_from,
                to_mm: fo_to,
                feed_mm_min: fo_feed,
                ..
            },
        ) = (&plan.segments[self.feed_in], &plan.segments[self.feed_out])
        else {
            unreachable!("circle_plans returns lines");
        };
        let c = plan.centre_mm;
        let rel = |p: &[f64; 3]| [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        let (a_in, b_in) = (rel(fi_from), rel(fi_to));
        let (d_in, d_c) = (dist(&a_in, &[0.0; 3]), dist(&b_in, &[0.0; 3]));
        Lines {
            a_in,
            b_in,
            a_out: rel(fo_from),
            b_out: rel(fo_to),
            fi_feed: *fi_feed,
            fo_feed: *fo_feed,
            d_in,
            d_c,
            dir: (d_c - d_in).signum(),
            mid: 0.5 * (d_in + d_c),
            tol: LEVEL_TOLERANCE_MM.min(0.25 * (d_c - d_in).abs()),
        }
    }
}

fn circle_plans(plan: &Plan) -> Result<Vec<CirclePlan>> {
    let mut out: Vec<CirclePlan> = vec![];
    let mut dwell = 0.0;
    let mut open: Option<(usize, usize, f64)> = None;
    for (i, s) in plan.segments.iter().enumerate() {
        match s {
            Segment::Dwell { seconds } => dwell += seconds,
            Segment::Line {
                role: LineRole::FeedIn,
                circle,
                ..
            } => {
                open = Some((*circle, i, dwell));
                dwell = 0.0;
            }
            Segment::Line {
                role: LineRole::FeedOut,
                circle,
                ..
            } => {
                let (c, fi, before) = open.take().filter(|o| o.0 == *circle).ok_or_else(|| {
                    Error::Usage(format!(
                        "the plan's feed-out of circle {circle} has no feed-in before it: not a plan `jdbb plan` wrote"
                    ))
                })?;
                out.push(CirclePlan {
                    circle: c,
                    feed_in: fi,
                    feed_out: i,
                    dwell_before_s: before,
                });
                dwell = 0.0;
            }
            _ => dwell = 0.0,
        }
    }
    if out.is_empty() {
        return Err(Error::Usage(
            "the plan has no circle with a feed-in and a feed-out to synchronise on".into(),
        ));
    }
    Ok(out)
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Words for circle k of the plan in errors.
fn describe_circle(plan: &Plan, k: usize) -> String {
    let c = &plan.circles[k];
    format!(
        "circle {} (R {:.3} mm at height {:.3} mm, D {:.3} mm)",
        k + 1,
        c.radius_mm,
        c.height_mm,
        c.d_mm
    )
}

/// Find the first crossing of `mid` in direction `dir` (+1 up, −1 down) at or after index `from`.
fn crossing(rec: &Record, from: usize, mid: f64, dir: f64) -> Option<usize> {
    (from.max(1)..rec.len())
        .find(|&i| (rec.d_mm[i - 1] - mid) * dir < 0.0 && (rec.d_mm[i] - mid) * dir >= 0.0)
}

/// Synchronise `rec` with `plan` (module docs).
pub fn synchronise(plan: &Plan, rec: &Record) -> Result<Sync> {
    synchronise_with(plan, rec, None)
}

/// What the machine's errors do to D at a point of the plan's lines, as a diagnosis of the
/// same record found them: the ramps are read through it ([`synchronise_with`]).
pub struct Ruler<'a> {
    /// D's error (mm) at each of the positions (relative to the table ball, mm).
    pub error_mm: &'a dyn Fn(&[[f64; 3]]) -> Vec<f64>,
}

/// [`synchronise`], with the ramps read through `ruler` (the machine's errors along the feed-in
/// a diagnosis found: a cyclic or scale error of its axis is printed on its ruler).
pub fn synchronise_with(plan: &Plan, rec: &Record, ruler: Option<&Ruler>) -> Result<Sync> {
    let err = |i: usize, msg: String| Error::Input {
        location: rec.location(i.min(rec.len().saturating_sub(1))),
        message: msg,
    };
    let mut found: Vec<Found> = vec![];
    let mut cursor = 0usize;
    let mut cycle_start = f64::NAN;
    let mut dwell_ratios = vec![];
    let mut last_feed_out_end: Option<(f64, f64)> = None; // (time, dwell after it)
    for cp in circle_plans(plan)? {
        let k = cp.circle;
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
        if (d_c - d_in).abs() < 0.05 {
            return Err(Error::Usage(format!(
                "{what}: its feed-in changes D by only {:.3} mm; the synchronisation needs a feed-in that moves D (plan with a longer --feed-in-mm)",
                (d_c - d_in).abs()
            )));
        }
        // 1. The feed-in: a crossing from a standstill at D_in to a plateau at D_c.
        let mut search = cursor;
        let (cross_in, ramp_in) = loop {
            let Some(i) = crossing(rec, search, mid, dir) else {
                let (lo, hi) = rec.d_mm[cursor.min(rec.len() - 1)..]
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &d| {
                        (l.min(d), h.max(d))
                    });
                return Err(err(
                    rec.len() - 1,
                    format!(
                        "{what}: no feed-in from D = {d_in:.3} mm to {d_c:.3} mm (± {tol:.3} mm) after {:.3} s of the record; D there spans {lo:.3} to {hi:.3} mm (another radius, a missing circle, or a record of another plan?)",
                        rec.t_s[cursor.min(rec.len() - 1)]
                    ),
                ));
            };
            let ramp = fit_ramp(
                rec,
                i,
                a_in,
                b_in,
                d_in,
                d_c,
                fi_feed / 60.0,
                cp.dwell_before_s.clamp(0.005, 0.25),
                0.005,
                ruler,
            );
            match ramp {
                Some(r) => break (i, r),
                None => search = i + 1,
            }
        };
        // 2. The feed-out: the next crossing back; D stays on the plateau in between.
        let Some(cross_out) = crossing(rec, cross_in + 1, mid, -dir) else {
            return Err(err(
                rec.len() - 1,
                format!(
                    "{what}: the record ends {:.3} s after its feed-in, during its arcs (an aborted run?)",
                    rec.t_s[rec.len() - 1] - rec.t_s[cross_in]
                ),
            ));
        };
        let ramp_out = fit_ramp(
            rec,
            cross_out,
            a_out,
            b_out,
            d_c,
            d_in,
            fo_feed / 60.0,
            0.005,
            dwell_after(plan, cp.feed_out).clamp(0.005, 0.25),
            ruler,
        )
        .ok_or_else(|| {
            err(
                cross_out,
                format!(
                    "{what}: D leaves the circle's {d_c:.3} mm at {:.3} s but does not come back to the feed-in start's {d_in:.3} mm: not the plan's feed-out (an aborted run?)",
                    rec.t_s[cross_out]
                ),
            )
        })?;
        let t_arcs = (ramp_in.profile.end_s(), ramp_out.profile.t0_s);
        // The plateau: D within the tolerance of D_c, once a loop's lag has settled after the
        // feed-in (e^-4 of the lag left) and before the feed-out starts to pull it away.
        let (pi, pj) = (
            rec.index_at(t_arcs.0 + 4.0 * ramp_in.lag_s),
            rec.index_at(t_arcs.1 - 4.0 * ramp_out.lag_s),
        );
        let d_measured = rec.median(t_arcs.0, t_arcs.1).unwrap_or(f64::NAN);
        if let Some(off) = (pi..pj).find(|&i| (rec.d_mm[i] - d_c).abs() > tol) {
            return Err(err(
                off,
                format!(
                    "{what}: during its arcs D is {:.4} mm at {:.3} s, off the circle's {d_c:.3} mm by more than {tol:.3} mm (another radius, or the instrument moved?)",
                    rec.d_mm[off], rec.t_s[off]
                ),
            ));
        }
        // 3. The arcs between the ramps: runs of one sense from rest to rest, and dwells.
        let items = circle_items(plan, &cp)?;
        let accel = 0.5 * (ramp_in.profile.accel_mm_s2 + ramp_out.profile.accel_mm_s2);
        let lengths: Vec<f64> = items
            .iter()
            .filter_map(|it| match it {
                Item::Run(_, arcs) => Some(arcs.iter().map(|a| a.1).sum::<f64>()),
                Item::Dwell(_) => None,
            })
            .collect();
        let dwells: f64 = items
            .iter()
            .map(|it| match it {
                Item::Dwell(s) => *s,
                Item::Run(..) => 0.0,
            })
            .sum();
        let avail = t_arcs.1 - t_arcs.0 - dwells;
        let speed0 = solve_speed(&lengths, accel, avail);
        let programmed = arc_feed(plan, cp.feed_in, cp.feed_out) / 60.0;
        let factor = speed0 / programmed;
        if !(speed0.is_finite() && (FEED_RANGE.0..=FEED_RANGE.1).contains(&factor)) {
            return Err(err(
                pj,
                format!(
                    "{what}: its arcs took {:.3} s; at the programmed {:.1} mm/min they take {:.3} s — a feed of {:.0} % of the programmed one, outside {:.0}–{:.0} % (a record of another plan, or a disturbed run?)",
                    t_arcs.1 - t_arcs.0,
                    programmed * 60.0,
                    lengths.iter().sum::<f64>() / programmed + dwells,
                    100.0 * factor,
                    100.0 * FEED_RANGE.0,
                    100.0 * FEED_RANGE.1
                ),
            ));
        }
        // On a partial arc the runs are short: their time fixes only a combination of the arcs'
        // speed and acceleration, so the speed must come from a feed-in that cruised.
        let lines = line_speed(&ramp_in, &ramp_out);
        if plan.arc.is_partial() && !lines.sigma_mm_s.is_finite() {
            let a = ramp_in.profile.accel_mm_s2;
            let need = (speed0 * speed0 / a / (1.0 - MIN_CRUISE_FRACTION) * 2.0).ceil() / 2.0;
            return Err(err(
                cross_in,
                format!(
                    "{what}: its feed-in of {:.3} mm never reached the feed (the machine accelerated at {a:.0} mm/s² towards {:.1} mm/s), so the feed is not measured, and on a partial arc the arcs' time cannot tell their speed from their acceleration; plan the test again with --feed-in-mm {need} or more (keeping the feed-in start in the instrument's range), or a lower --feed",
                    ramp_in.profile.length_mm,
                    speed0
                ),
            ));
        }
        if found.is_empty() {
            // Cycle start: the end of the program stop; from there the dwells and lines (the
            // take-up) before the feed-in ran, the lines at the feed-in's speed and acceleration.
            let stop = plan.segments[..cp.feed_in]
                .iter()
                .rposition(|s| matches!(s, Segment::Stop))
                .map_or(0, |i| i + 1);
            let before: f64 = plan.segments[stop..cp.feed_in]
                .iter()
                .map(|s| match s {
                    Segment::Dwell { seconds } => *seconds,
                    Segment::Line { .. } => Profile {
                        length_mm: s.length_mm(),
                        ..ramp_in.profile
                    }
                    .duration_s(),
                    _ => 0.0,
                })
                .sum();
            cycle_start = ramp_in.profile.t0_s - ramp_in.lag_s - before;
        }
        if let Some((t_end, dwell_after)) = last_feed_out_end {
            // Between the previous feed-out and this feed-in: dwells and moves. Where D stands
            // still over the whole gap (no visible move), it is all dwell.
            let gap = ramp_in.profile.t0_s - t_end;
            let planned = dwell_after + cp.dwell_before_s;
            let still = rec
                .median(t_end, ramp_in.profile.t0_s)
                .is_some_and(|m| (m - d_in).abs() < tol)
                && moves_between(plan, cp.feed_in).abs() < 1e-9;
            if still && planned > 0.0 {
                dwell_ratios.push(gap / planned);
            }
        }
        last_feed_out_end = Some((ramp_out.profile.end_s(), dwell_after(plan, cp.feed_out)));
        cursor = rec.index_at(ramp_out.profile.end_s());
        found.push(Found {
            circle: k,
            ramp_in,
            ramp_out,
            t0_s: t_arcs.0,
            d_measured_mm: d_measured,
            items,
            lengths,
            avail_s: avail,
            programmed_mm_s: programmed,
            lines,
            accel_mm_s2: accel,
        });
    }
    // 4. The feed from every timing fact the record holds, each weighed by what the machine's
    // errors can do to it (`feed_facts`), and each circle's timeline at that feed.
    let facts = feed_facts(rec, &found);
    let feed = combine(&facts);
    let feed_note = feed.as_ref().and_then(|f| f.note.clone());
    let mut circles = Vec::with_capacity(found.len());
    for f in found {
        let timing = arc_motion(plan, rec, &f, feed.as_ref());
        let (runs, data) = timeline(
            plan,
            rec,
            &f.items,
            f.t0_s,
            timing.speed_mm_s,
            timing.accel_mm_s2,
        );
        circles.push(CircleSync {
            circle: f.circle,
            feed_in: f.ramp_in,
            feed_out: f.ramp_out,
            speed_mm_s: timing.speed_mm_s,
            speed_sigma_mm_s: timing.speed_sigma_mm_s,
            arc_accel_mm_s2: timing.accel_mm_s2,
            timing_sigma_s: timing.timing_sigma_s,
            d_measured_mm: f.d_measured_mm,
            data,
            runs,
        });
    }
    let factors: Vec<f64> = circles
        .iter()
        .map(|c| {
            let cp = &plan.circles[c.circle];
            c.speed_mm_s / (cp.feed_mm_min / 60.0)
        })
        .collect();
    let mean = factors.iter().sum::<f64>() / factors.len() as f64;
    let feed_sigma = circles
        .iter()
        .map(|c| c.speed_sigma_mm_s / (plan.circles[c.circle].feed_mm_min / 60.0))
        .fold(0.0, f64::max);
    let spread = if factors.len() > 1 {
        (factors.iter().map(|f| (f - mean).powi(2)).sum::<f64>() / (factors.len() - 1) as f64)
            .sqrt()
    } else {
        0.0
    };
    let accel = circles
        .iter()
        .map(|c| 0.5 * (c.feed_in.profile.accel_mm_s2 + c.feed_out.profile.accel_mm_s2))
        .sum::<f64>()
        / circles.len() as f64;
    let clock_scale = (!dwell_ratios.is_empty())
        .then(|| dwell_ratios.iter().sum::<f64>() / dwell_ratios.len() as f64);
    Ok(Sync {
        cycle_start_s: cycle_start,
        t0_us: rec.t0_us,
        programmed_feed_mm_min: plan.feed_mm_min,
        feed_percent: 100.0 * mean,
        feed_spread_percent: 100.0 * spread,
        feed_sigma_percent: 100.0 * feed_sigma,
        feed_facts: facts,
        feed_note,
        clock_scale,
        accel_mm_s2: accel,
        circles,
    })
}

/// The arcs of circle `cp` between its feed-in and feed-out: runs of one sense from rest to rest,
/// and dwells.
fn circle_items(plan: &Plan, cp: &CirclePlan) -> Result<Vec<Item>> {
    let mut items: Vec<Item> = vec![];
    for seg in cp.feed_in + 1..cp.feed_out {
        match &plan.segments[seg] {
                Segment::Dwell { seconds } => items.push(Item::Dwell(*seconds)),
                Segment::Arc { sense, .. } => {
                    let len = plan.length_mm(seg);
                    match items.last_mut() {
                        Some(Item::Run(s, arcs)) if *s == *sense => arcs.push((seg, len)),
                        _ => items.push(Item::Run(*sense, vec![(seg, len)])),
                    }
                }
                other => {
                    return Err(Error::Usage(format!(
                        "the plan has a {:?} between the feed-in and the feed-out of circle {}: not a plan `jdbb plan` wrote",
                        kind(other),
                        cp.circle + 1
                    )))
                }
            }
    }
    Ok(items)
}

/// A run of arcs of one sense (its arcs: plan segment, length), or a dwell (s).
enum Item {
    Run(Sense, Vec<(usize, f64)>),
    Dwell(f64),
}

fn kind(s: &Segment) -> &'static str {
    match s {
        Segment::Rapid { .. } => "rapid",
        Segment::Stop => "program stop",
        Segment::Dwell { .. } => "dwell",
        Segment::Line { .. } => "line",
        Segment::Arc { .. } => "arc",
    }
}

/// The feed of the arcs between two segments (mm/min): the first arc's.
fn arc_feed(plan: &Plan, from: usize, to: usize) -> f64 {
    plan.segments[from..to]
        .iter()
        .find_map(|s| match s {
            Segment::Arc { feed_mm_min, .. } => Some(*feed_mm_min),
            _ => None,
        })
        .unwrap_or(plan.feed_mm_min)
}

/// Dwell time right after segment `seg` (s).
fn dwell_after(plan: &Plan, seg: usize) -> f64 {
    plan.segments[seg + 1..]
        .iter()
        .map_while(|s| match s {
            Segment::Dwell { seconds } => Some(*seconds),
            _ => None,
        })
        .sum()
}

/// Total length of the moves right before the feed-in `seg` (back to the previous feed-out).
fn moves_between(plan: &Plan, seg: usize) -> f64 {
    plan.segments[..seg]
        .iter()
        .rev()
        .take_while(|s| {
            !matches!(
                s,
                Segment::Line {
                    role: LineRole::FeedOut,
                    ..
                }
            )
        })
        .filter(|s| {
            matches!(
                s,
                Segment::Line {
                    role: LineRole::Move,
                    ..
                }
            )
        })
        .map(Segment::length_mm)
        .sum()
}

/// The runs of one circle on the record's clock from `t0` (the feed-in's end) at `speed` with
/// `accel` at every start and stop, and the data arcs on them.
fn timeline(
    plan: &Plan,
    rec: &Record,
    items: &[Item],
    t0: f64,
    speed: f64,
    accel: f64,
) -> (Vec<Run>, Vec<DataArc>) {
    let mut runs = vec![];
    let mut data = vec![];
    let mut t = t0;
    for it in items {
        match it {
            Item::Dwell(s) => t += s,
            Item::Run(sense, arcs) => {
                let total: f64 = arcs.iter().map(|a| a.1).sum();
                let profile = Profile {
                    t0_s: t,
                    length_mm: total,
                    speed_mm_s: speed,
                    accel_mm_s2: accel,
                };
                let mut at = 0.0;
                let mut placed = vec![];
                for &(seg, len) in arcs {
                    placed.push((seg, at, len));
                    if let Segment::Arc {
                        role: ArcRole::Data,
                        ..
                    } = plan.segments[seg]
                    {
                        let (t1, t2) = (profile.t_at(at), profile.t_at(at + len));
                        let samples = rec.index_at(t2) - rec.index_at(t1);
                        data.push(DataArc {
                            segment: seg,
                            sense: *sense,
                            t_start_s: t1,
                            t_end_s: t2,
                            samples,
                        });
                    }
                    at += len;
                }
                t = profile.end_s();
                runs.push(Run {
                    profile,
                    arcs: placed,
                });
            }
        }
    }
    (runs, data)
}

/// The lines' speed from a circle's ramps and its standard error (mm/s). The plan approaches
/// each feed-in start along the feed-in's own direction, so the feed-in starts without a
/// reversal and its trapezoid is the whole motion; the feed-out always starts with one, and
/// carries that axis's backlash step and reversal spike, which bias its speed by far more than
/// its σ says (a 4 µm spike of 25 ms moved it by 6·10⁻⁴). So the feed-in's speed is taken, and
/// the feed-out's only when the feed-in's fit gave no standard error. A ramp that cruises over
/// less than [`MIN_CRUISE_FRACTION`] of its length has not measured the feed (its "speed" is
/// the peak of a near-triangle, a percent off at 2000 mm/min on a 2 mm feed-in): its speed
/// comes with no standard error, and the arcs' speed is then searched in their data. The
/// acceleration check in [`arc_motion`] cannot be relied on to catch it: a partial arc's runs
/// are short, and a speed 1 % off still leaves them a plausible acceleration.
fn line_speed(feed_in: &Ramp, feed_out: &Ramp) -> LineSpeed {
    let usable = |r: &Ramp| {
        let s = r.speed_sigma_mm_s;
        let p = &r.profile;
        let cruise = p.length_mm - p.speed_mm_s * p.speed_mm_s / p.accel_mm_s2;
        (s.is_finite() && s > 0.0 && cruise >= MIN_CRUISE_FRACTION * p.length_mm).then_some(
            LineSpeed {
                speed_mm_s: p.speed_mm_s,
                sigma_mm_s: s,
                cruise_mm: cruise,
            },
        )
    };
    usable(feed_in)
        .or_else(|| usable(feed_out))
        .unwrap_or(LineSpeed {
            speed_mm_s: 0.5 * (feed_in.profile.speed_mm_s + feed_out.profile.speed_mm_s),
            sigma_mm_s: f64::INFINITY,
            cruise_mm: 0.0,
        })
}

/// A circle's lines' speed ([`line_speed`]): the speed (mm/s), its standard error from the ramp's
/// fit (infinite where no ramp cruised) and the length of the cruise that measured it (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
struct LineSpeed {
    speed_mm_s: f64,
    sigma_mm_s: f64,
    cruise_mm: f64,
}

/// Least part of a ramp's length spent at its cruising speed for its fitted speed to count as
/// the feed (`line_speed`).
pub const MIN_CRUISE_FRACTION: f64 = 0.2;

#[cfg(test)]
mod tests;
