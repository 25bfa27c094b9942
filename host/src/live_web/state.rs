//! What the live page shows, as the JSON of one server-sent event ([`LiveState`]), and where the
//! machine is in the plan, followed from D as the samples arrive ([`Tracker`]).
//!
//! # Progress from D
//! Each circle of the plan is entered by a feed-in that moves D from the feed-in start's level
//! `D_in` to the circle's `D_c`, and left by a feed-out back to `D_in` — the levels the
//! synchronisation ([`crate::sync`]) looks for. The tracker follows them sample by
//! sample: *waiting* for circle k's feed-in (D crosses (D_in + D_c)/2 towards D_c), *feed-in*
//! (until D is within [`LEVEL_TOLERANCE_MM`] of D_c), *circle* (the arcs, until D crosses the
//! midpoint back), *feed-out* (until D is back within the tolerance of D_in), then circle k + 1.
//! On the circle, the time since its plateau began is laid along the plan's arcs and dwells at
//! the **programmed** feed (no acceleration, no override): it gives the sense (ccw/cw), the
//! percentage and the angle of each trace point. That is a live estimate, good to a few degrees;
//! the report's angles come from the full synchronisation of the finished record
//! (`jdbb diagnose --record --plan`).
use serde::Serialize;

use crate::plan::{ArcRole, LineRole, Plan, Segment, Sense};
use crate::sync::LEVEL_TOLERANCE_MM;

/// Most trace points kept (and pushed) for the current circle: beyond it every other point is
/// dropped and only every 2nd (4th, …) sample taken from then on.
pub const MAX_TRACE_POINTS: usize = 2000;

/// Loss and corruption counters of the stream, as the terminal's status line shows them.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Counts {
    /// Samples received.
    pub samples: u64,
    /// Samples lost on the link (gaps in `seq`).
    pub lost: u64,
    /// Samples the device dropped (its queue was full).
    pub dropped: u64,
    /// Corrupt frames.
    pub corrupt: u64,
    /// Device restarts seen.
    pub resets: u64,
}

/// Where the machine is in the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Before circle k's feed-in: the operator's stop, the dwell, the move to its start.
    Dwell,
    /// On circle k's feed-in (D ramps from D_in to D_c).
    FeedIn,
    /// On circle k's arcs.
    Circle,
    /// On circle k's feed-out (D ramps back to D_in).
    FeedOut,
    /// Every circle of the plan has been run.
    Done,
}

/// Progress in the plan.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Progress {
    pub phase: Phase,
    /// The circle (1-based), n when done.
    pub circle: usize,
    /// Circles in the plan.
    pub circles: usize,
    /// The sense of the arc being run, on a circle; None elsewhere.
    pub sense: Option<&'static str>,
    /// Whether the arc being run is a data arc (not a lead-in or overshoot).
    pub on_data_arc: bool,
    /// Of the whole plan's circles (each circle's arcs at the programmed feed), %.
    pub percent: f64,
}

/// One point of the current circle's polar trace.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TracePoint {
    /// Angle in the plan's plane (degrees from its first axis towards its second), estimated at
    /// the programmed feed (module docs).
    pub angle_deg: f64,
    /// D minus the mean D of the circle's data-arc points so far (µm).
    pub dev_um: f64,
    /// `ccw` or `cw`.
    pub sense: &'static str,
}

/// The current circle's trace.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Trace {
    /// The circle (1-based).
    pub circle: usize,
    /// Its nominal radius (mm).
    pub radius_mm: f64,
    /// Samples per point (1, 2, 4, …: the decimation).
    pub stride: usize,
    pub points: Vec<TracePoint>,
}

/// The state one server-sent event carries (its JSON is documented in `docs/live.md`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct LiveState {
    /// Increases with every publication.
    pub version: u64,
    /// Latest D (mm), None before the first sample.
    pub d_mm: Option<f64>,
    /// Received-sample rate over the last second (Hz), None before the first full second.
    pub rate_hz: Option<f64>,
    pub counts: Counts,
    /// Seconds since the session started (host clock).
    pub elapsed_s: f64,
    /// Progress in the plan, when a plan was given.
    pub progress: Option<Progress>,
    /// The current (or last) circle's trace, when a plan was given.
    pub trace: Option<Trace>,
    /// Each circle's diagnosis while recording, in the order they came ([`super::worker`]).
    pub circle_diagnoses: Vec<super::worker::CircleDiagnosis>,
    /// How the session ended, once it has (the summary's words).
    pub ended: Option<String>,
    /// The end-of-test diagnosis summary, once computed (the text `jdbb diagnose` prints).
    pub diagnosis: Option<String>,
    /// The end-of-test verdict against the tolerance (`record --plan --tolerance-um`), once
    /// computed; the page shows it large.
    pub verdict: Option<Verdict>,
    /// Every warning the terminal showed during the session, in the order it showed them, each
    /// once (the page shows them as they come).
    pub warnings: Vec<String>,
}

/// PASS or FAIL against the tolerance, and the line the terminal prints for it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Verdict {
    pub pass: bool,
    pub text: String,
}

impl LiveState {
    /// The JSON of one event (one line: no newline inside, as an SSE `data:` field needs).
    pub fn to_json(&self) -> String {
        // Serialising plain numbers, strings and options cannot fail; NaN becomes null.
        serde_json::to_string(self).unwrap_or_else(|_| "{}".into())
    }
}

/// One arc or dwell of a circle, timed at the programmed feed from the plateau's start.
#[derive(Debug, Clone, PartialEq)]
struct Piece {
    t0_s: f64,
    duration_s: f64,
    /// None for a dwell.
    arc: Option<PieceArc>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct PieceArc {
    start_deg: f64,
    /// Signed (+ ccw, − cw).
    sweep_deg: f64,
    sense: Sense,
    data: bool,
}

/// A circle of the plan as the tracker needs it.
#[derive(Debug, Clone, PartialEq)]
struct Level {
    d_in_mm: f64,
    d_c_mm: f64,
    tol_mm: f64,
    radius_mm: f64,
    pieces: Vec<Piece>,
    /// Sum of the pieces (s).
    arcs_s: f64,
}

impl Level {
    fn mid(&self) -> f64 {
        0.5 * (self.d_in_mm + self.d_c_mm)
    }

    /// +1 when the feed-in increases D.
    fn dir(&self) -> f64 {
        (self.d_c_mm - self.d_in_mm).signum()
    }

    /// The piece running `tau` s after the plateau began (the last one after the plan's time).
    fn piece_at(&self, tau: f64) -> Option<&Piece> {
        self.pieces
            .iter()
            .find(|p| tau < p.t0_s + p.duration_s)
            .or(self.pieces.last())
    }
}

fn sense_name(s: Sense) -> &'static str {
    match s {
        Sense::Ccw => "ccw",
        Sense::Cw => "cw",
    }
}

/// Follows the plan's progress and the current circle's trace from D (module docs).
#[derive(Debug, Clone)]
pub struct Tracker {
    levels: Vec<Level>,
    /// The circle being waited for or run (0-based).
    k: usize,
    phase: Phase,
    plateau_t0_s: f64,
    last_tau_s: f64,
    last_d_mm: Option<f64>,
    /// (angle, D mm, sense) of the current circle's data arcs, decimated.
    points: Vec<(f64, f64, &'static str)>,
    stride: usize,
    skip: usize,
    /// The circle whose trace `points` holds.
    trace_circle: Option<usize>,
}

impl Tracker {
    /// A tracker for `plan`'s circles, waiting for the first feed-in.
    pub fn new(plan: &Plan) -> Tracker {
        let c = plan.centre_mm;
        let d = |p: &[f64; 3]| {
            ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
        };
        let mut levels = vec![];
        let mut open: Option<Level> = None;
        for s in &plan.segments {
            match s {
                Segment::Line {
                    role: LineRole::FeedIn,
                    from_mm,
                    to_mm,
                    ..
                } => {
                    let (d_in_mm, d_c_mm) = (d(from_mm), d(to_mm));
                    open = Some(Level {
                        d_in_mm,
                        d_c_mm,
                        tol_mm: LEVEL_TOLERANCE_MM.min(0.25 * (d_c_mm - d_in_mm).abs()),
                        radius_mm: 0.0,
                        pieces: vec![],
                        arcs_s: 0.0,
                    });
                }
                Segment::Line {
                    role: LineRole::FeedOut,
                    ..
                } => {
                    if let Some(l) = open.take() {
                        levels.push(l);
                    }
                }
                Segment::Arc {
                    radius_mm,
                    sense,
                    start_deg,
                    sweep_deg,
                    role,
                    ..
                } => {
                    if let Some(l) = open.as_mut() {
                        let duration_s = s.nominal_duration_s().unwrap_or(0.0);
                        l.radius_mm = *radius_mm;
                        l.pieces.push(Piece {
                            t0_s: l.arcs_s,
                            duration_s,
                            arc: Some(PieceArc {
                                start_deg: *start_deg,
                                sweep_deg: *sweep_deg,
                                sense: *sense,
                                data: *role == ArcRole::Data,
                            }),
                        });
                        l.arcs_s += duration_s;
                    }
                }
                Segment::Dwell { seconds } => {
                    if let Some(l) = open.as_mut() {
                        l.pieces.push(Piece {
                            t0_s: l.arcs_s,
                            duration_s: *seconds,
                            arc: None,
                        });
                        l.arcs_s += seconds;
                    }
                }
                _ => {}
            }
        }
        Tracker {
            levels,
            k: 0,
            phase: Phase::Dwell,
            plateau_t0_s: 0.0,
            last_tau_s: 0.0,
            last_d_mm: None,
            points: vec![],
            stride: 1,
            skip: 0,
            trace_circle: None,
        }
    }

    /// Take one sample: `t_s` on any clock that increases (s), D (mm).
    pub fn push(&mut self, t_s: f64, d_mm: f64) {
        let prev = self.last_d_mm.replace(d_mm);
        let Some(l) = self.levels.get(self.k) else {
            self.phase = Phase::Done;
            return;
        };
        let (mid, dir) = (l.mid(), l.dir());
        let crossed_in = prev.is_some_and(|p| (p - mid) * dir < 0.0 && (d_mm - mid) * dir >= 0.0);
        let crossed_out = prev.is_some_and(|p| (p - mid) * dir >= 0.0 && (d_mm - mid) * dir < 0.0);
        match self.phase {
            Phase::Dwell => {
                if crossed_in {
                    self.phase = Phase::FeedIn;
                }
            }
            Phase::FeedIn => {
                if (d_mm - l.d_c_mm).abs() <= l.tol_mm {
                    self.phase = Phase::Circle;
                    self.plateau_t0_s = t_s;
                    self.last_tau_s = 0.0;
                    self.points.clear();
                    self.stride = 1;
                    self.skip = 0;
                    self.trace_circle = Some(self.k);
                } else if crossed_out {
                    // Back below the midpoint before reaching the circle: not its feed-in.
                    self.phase = Phase::Dwell;
                }
            }
            Phase::Circle => {
                if crossed_out {
                    self.phase = Phase::FeedOut;
                    return;
                }
                let tau = t_s - self.plateau_t0_s;
                self.last_tau_s = tau;
                let Some(Piece {
                    t0_s,
                    duration_s,
                    arc: Some(a),
                }) = l.piece_at(tau)
                else {
                    return;
                };
                if !a.data {
                    return;
                }
                self.skip += 1;
                if self.skip < self.stride {
                    return;
                }
                self.skip = 0;
                let f = ((tau - t0_s) / duration_s.max(1e-9)).clamp(0.0, 1.0);
                let angle = (a.start_deg + f * a.sweep_deg).rem_euclid(360.0);
                self.points.push((angle, d_mm, sense_name(a.sense)));
                if self.points.len() >= MAX_TRACE_POINTS {
                    let kept: Vec<_> = self.points.iter().copied().step_by(2).collect();
                    self.points = kept;
                    self.stride *= 2;
                }
            }
            Phase::FeedOut => {
                if (d_mm - l.d_in_mm).abs() <= l.tol_mm {
                    self.k += 1;
                    self.phase = if self.k < self.levels.len() {
                        Phase::Dwell
                    } else {
                        Phase::Done
                    };
                }
            }
            Phase::Done => {}
        }
    }

    /// Circles whose feed-out has ended (the first n of the plan).
    pub fn circles_done(&self) -> usize {
        self.k
    }

    /// Where the machine is.
    pub fn progress(&self) -> Progress {
        let n = self.levels.len();
        let total: f64 = self.levels.iter().map(|l| l.arcs_s).sum();
        let done: f64 = self.levels.iter().take(self.k).map(|l| l.arcs_s).sum();
        let (mut sense, mut on_data_arc, mut current) = (None, false, 0.0);
        if let (Phase::Circle, Some(l)) = (self.phase, self.levels.get(self.k)) {
            current = self.last_tau_s.min(l.arcs_s);
            if let Some(Piece { arc: Some(a), .. }) = l.piece_at(self.last_tau_s) {
                sense = Some(sense_name(a.sense));
                on_data_arc = a.data;
            }
        } else if matches!(self.phase, Phase::FeedOut) {
            current = self.levels.get(self.k).map_or(0.0, |l| l.arcs_s);
        }
        let percent = if total > 0.0 {
            (100.0 * (done + current) / total).min(100.0)
        } else {
            0.0
        };
        Progress {
            phase: self.phase,
            circle: (self.k + 1).min(n.max(1)),
            circles: n,
            sense,
            on_data_arc,
            percent,
        }
    }

    /// The current (or last run) circle's trace, decimated to at most [`MAX_TRACE_POINTS`].
    pub fn trace(&self) -> Option<Trace> {
        let k = self.trace_circle?;
        let mean = if self.points.is_empty() {
            0.0
        } else {
            self.points.iter().map(|p| p.1).sum::<f64>() / self.points.len() as f64
        };
        Some(Trace {
            circle: k + 1,
            radius_mm: self.levels[k].radius_mm,
            stride: self.stride,
            points: self
                .points
                .iter()
                .map(|&(angle_deg, d, sense)| TracePoint {
                    angle_deg,
                    dev_um: (d - mean) * 1e3,
                    sense,
                })
                .collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::build::{plan, PlanSpec};
    use crate::plan::{Dialect, Plane};

    /// A two-radius plan and D along it at the programmed feed, 1 kHz, with a 5 µm
    /// once-per-revolution wobble on the arcs.
    pub(crate) fn test_plan() -> Plan {
        let spec = PlanSpec::machine_test(
            &[85.0, 95.0],
            &[0.0],
            Plane::Xy,
            2000.0,
            [0.0, 0.0, 0.0],
            Dialect::Linuxcnc,
        );
        plan(&spec, &jdbb_core::calib::Calibration::DEFAULT).unwrap()
    }

    #[test]
    fn the_plan_gives_one_level_per_circle_with_its_arcs_timed() {
        let p = test_plan();
        let t = Tracker::new(&p);
        assert_eq!(t.levels.len(), p.circles.len());
        for l in &t.levels {
            assert!(l.arcs_s > 0.0);
            assert!((l.d_c_mm - l.d_in_mm).abs() > 0.05);
            let data: f64 = l
                .pieces
                .iter()
                .filter_map(|p| p.arc.filter(|a| a.data).map(|a| a.sweep_deg.abs()))
                .sum();
            assert!((data - 720.0).abs() < 1e-6, "ccw and cw data arcs: {data}");
        }
    }

    #[test]
    fn phases_follow_d_through_a_circle() {
        let p = test_plan();
        let mut t = Tracker::new(&p);
        let l = t.levels[0].clone();
        let mut time = 0.0;
        let mut push = |t: &mut Tracker, d: f64| {
            time += 0.001;
            t.push(time, d);
        };
        for _ in 0..10 {
            push(&mut t, l.d_in_mm);
        }
        assert_eq!(t.progress().phase, Phase::Dwell);
        push(&mut t, l.mid() + 0.01 * l.dir());
        assert_eq!(t.progress().phase, Phase::FeedIn);
        push(&mut t, l.d_c_mm);
        assert_eq!(t.progress().phase, Phase::Circle);
        // 30 % through the circle's time (its ccw arcs): its share of the whole plan's circles,
        // and a sense.
        let n = (l.arcs_s * 0.3 / 0.001) as usize;
        for _ in 0..n {
            push(&mut t, l.d_c_mm);
        }
        let pr = t.progress();
        assert_eq!((pr.circle, pr.circles), (1, 2));
        assert_eq!(pr.sense, Some("ccw"));
        let total: f64 = t.levels.iter().map(|l| l.arcs_s).sum();
        let want = 100.0 * 0.3 * l.arcs_s / total;
        assert!((pr.percent - want).abs() < 0.5, "{} vs {want}", pr.percent);
        push(&mut t, l.mid() - 0.01 * l.dir());
        assert_eq!(t.progress().phase, Phase::FeedOut);
        push(&mut t, l.d_in_mm);
        let pr = t.progress();
        assert_eq!((pr.phase, pr.circle), (Phase::Dwell, 2));
        assert!(t.trace().is_some_and(|tr| tr.circle == 1));
    }

    #[test]
    fn the_trace_is_decimated_and_shows_the_deviation_in_micrometres() {
        let p = test_plan();
        let mut t = Tracker::new(&p);
        let l = t.levels[0].clone();
        t.push(0.0, l.d_in_mm);
        t.push(0.001, l.d_c_mm);
        t.push(0.002, l.d_c_mm);
        // 10 kHz over the whole circle: far more samples than points.
        let n = (l.arcs_s / 1e-4) as usize;
        for i in 0..n {
            let tau = i as f64 * 1e-4;
            // +3 µm on the first half of the time, −3 µm on the second.
            let d = l.d_c_mm + if tau < 0.5 * l.arcs_s { 3e-3 } else { -3e-3 };
            t.push(0.002 + tau, d);
        }
        let tr = t.trace().unwrap();
        assert!(tr.points.len() <= MAX_TRACE_POINTS && tr.points.len() > MAX_TRACE_POINTS / 4);
        assert!(tr.stride > 1);
        let max = tr.points.iter().map(|p| p.dev_um).fold(f64::MIN, f64::max);
        let min = tr.points.iter().map(|p| p.dev_um).fold(f64::MAX, f64::min);
        assert!((max - min - 6.0).abs() < 0.01, "{min}..{max} µm");
        assert!(tr.points.iter().any(|p| p.sense == "ccw"));
        assert!(tr.points.iter().any(|p| p.sense == "cw"));
        assert!(tr
            .points
            .iter()
            .all(|p| (0.0..360.0).contains(&p.angle_deg)));
    }

    #[test]
    fn state_json_is_one_line_with_units_in_the_names() {
        let s = LiveState {
            version: 3,
            d_mm: Some(100.0),
            rate_hz: Some(1000.0),
            counts: Counts {
                samples: 5,
                lost: 1,
                ..Counts::default()
            },
            progress: Some(Progress {
                phase: Phase::Circle,
                circle: 1,
                circles: 4,
                sense: Some("ccw"),
                on_data_arc: true,
                percent: 12.5,
            }),
            ..LiveState::default()
        };
        let j = s.to_json();
        assert!(!j.contains('\n'));
        let v: serde_json::Value = serde_json::from_str(&j).unwrap();
        assert_eq!(v["d_mm"], 100.0);
        assert_eq!(v["rate_hz"], 1000.0);
        assert_eq!(v["counts"]["lost"], 1);
        assert_eq!(v["progress"]["phase"], "circle");
        assert_eq!(v["progress"]["sense"], "ccw");
        assert_eq!(v["progress"]["percent"], 12.5);
        assert!(v["trace"].is_null());
    }
}
