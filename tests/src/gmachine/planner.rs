//! The motion planner: program blocks → a timed trajectory p(t) of the commanded position.
//!
//! # What it does
//!
//! 1. **Limits per move.** Straight moves (G0, G1) accelerate along the path at
//!    a = min_k a_k / |u_k| (u the unit direction, a_k the axis limits), so that no axis exceeds
//!    its limit. Arcs reserve the in-plane budget a_p = min(a_a, a_b): the centripetal
//!    acceleration v²/R may use [`ARC_NORMAL_SHARE`]·a_p (the speed on the arc is capped at
//!    √(share·a_p·R), below the feed for small R or large feeds) and the tangential acceleration
//!    [`ARC_TANGENTIAL_SHARE`]·a_p; the shares satisfy ½² + (√3/2)² = 1, so the in-plane
//!    acceleration vector never exceeds a_p (a helix also respects the normal axis' limit).
//! 2. **Junctions.** Consecutive moves whose tangents agree within
//!    [`MachineConfig::blend_angle_deg`] (an arc split into 180° pieces, a line meeting an arc
//!    tangentially) are run without stopping: the junction speed is the smaller of the two moves'
//!    speed limits. At a corner, a reversal, a dwell (`G4`, even `G4 P0`), a program stop, in
//!    exact-stop mode (`G61`) and at the program end the speed is zero. Zero-length moves are
//!    transparent.
//! 3. **Lookahead.** The whole program is known, so the classic two passes over the moves give
//!    each move's entry and exit speed: backwards, the exit speed is lowered so the move can still
//!    stop (or reach the next entry speed) within its length; forwards, the entry speed is limited by
//!    what the previous move could reach.
//! 4. **Profile.** Each move runs a trapezoidal (acceleration-limited, jerk-unlimited) speed profile
//!    along its path: accelerate from the entry speed to the peak, cruise, decelerate to the exit
//!    speed — a triangle when the move is too short to reach its speed limit. Positions and times
//!    are analytic in each phase; no time stepping.
//! 5. **Axis directions.** For backlash and reversal spikes, the time at which each axis starts
//!    moving in a new direction is found analytically: on a line from the sign of the axis'
//!    travel, on an arc where the axis passes an extreme of the circle (θ = kπ for the first plane
//!    axis, π/2 + kπ for the second). A direction holds through standstill.
//!
//! Times here are *program time*: seconds since the first block started.
//!
//! Rapid moves (G0) run at [`MachineConfig::rapid_mm_min`] along the path, unaffected by the feed
//! override. The spiral arcs the program may contain (start and end radius differing by the
//! printing's rounding, ≤ 2 µm) change radius linearly with angle; their length is taken as
//! r_mean·|sweep| and their reversal angles are those of the circle.

use super::program::{Action, ArcMove, Program};
use super::SimError;

/// Fraction of the in-plane acceleration limit the centripetal acceleration may use on an arc.
pub const ARC_NORMAL_SHARE: f64 = 0.866_025_403_784_438_6; // √3/2
/// Fraction of the in-plane acceleration limit used to speed up or slow down along an arc.
pub const ARC_TANGENTIAL_SHARE: f64 = 0.5;

/// How the machine moves (everything except its errors).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MachineConfig {
    /// Speed of rapid moves (G0) along the path (mm/min).
    pub rapid_mm_min: f64,
    /// Acceleration limit of each axis x, y, z (mm/s²).
    pub accel_mm_s2: [f64; 3],
    /// Feed override (%): 100 runs the programmed feeds. Applies to G1/G2/G3, not to G0.
    pub feed_override_pct: f64,
    /// Junctions whose tangents differ by at most this angle (deg) are run without stopping.
    pub blend_angle_deg: f64,
    /// Corners sharper than that: 0 stops at each (LinuxCNC `G64 P0.001`, exact stop); a
    /// positive junction deviation δ (mm) passes them at grbl's and Marlin's junction speed
    /// v² = a·δ·sin(θ/2)/(1 − sin(θ/2)), θ the angle between the entry move's direction reversed
    /// and the exit move's (180° straight on, 90° at a right-angle corner, 0 at a reversal, which
    /// stops), a the smaller of their acceleration limits (grbl's default δ is 0.01 mm, Marlin's
    /// 0.013 mm).
    pub junction_deviation_mm: f64,
    /// How long the operator takes to press cycle start at a program stop (M0, M1) other than the
    /// first (s). The first stop is where the instrument is mounted; see
    /// [`InstrumentConfig::start_delay_s`](super::InstrumentConfig::start_delay_s).
    pub stop_wait_s: f64,
    /// The optional-stop switch: whether M1 stops.
    pub optional_stop: bool,
    /// Where the machine is when the program starts (mm, program coordinates).
    pub initial_position_mm: [f64; 3],
    /// Direction each axis last moved in before the program (+1 or −1), for backlash.
    pub initial_direction: [i8; 3],
}

impl Default for MachineConfig {
    /// A small vertical mill: 5 m/min rapids, 500 mm/s² on x and y, 300 on z, 0.5° blending,
    /// 5 s at each later program stop, at the program origin with every axis last moved in +.
    fn default() -> Self {
        MachineConfig {
            rapid_mm_min: 5000.0,
            accel_mm_s2: [500.0, 500.0, 300.0],
            feed_override_pct: 100.0,
            blend_angle_deg: 0.5,
            junction_deviation_mm: 0.0,
            stop_wait_s: 5.0,
            optional_stop: true,
            initial_position_mm: [0.0; 3],
            initial_direction: [1; 3],
        }
    }
}

impl MachineConfig {
    fn validate(&self) -> Result<(), SimError> {
        let bad = |what: &str| Err(SimError::Config(what.to_string()));
        if !(self.rapid_mm_min > 0.0 && self.rapid_mm_min.is_finite()) {
            return bad("rapid_mm_min must be a positive number (mm/min)");
        }
        if !self.accel_mm_s2.iter().all(|a| *a > 0.0 && a.is_finite()) {
            return bad("accel_mm_s2 must be positive numbers (mm/s²) for x, y and z");
        }
        if !(self.feed_override_pct > 0.0 && self.feed_override_pct.is_finite()) {
            return bad("feed_override_pct must be a positive number (%)");
        }
        if !(0.0..90.0).contains(&self.blend_angle_deg) {
            return bad("blend_angle_deg must be in 0..90 degrees");
        }
        if !(self.junction_deviation_mm >= 0.0 && self.junction_deviation_mm.is_finite()) {
            return bad("junction_deviation_mm must be a number ≥ 0 (mm)");
        }
        if !(self.stop_wait_s >= 0.0 && self.stop_wait_s.is_finite()) {
            return bad("stop_wait_s must be ≥ 0 (s)");
        }
        if !self.initial_direction.iter().all(|d| *d == 1 || *d == -1) {
            return bad("initial_direction must be +1 or -1 per axis");
        }
        if !self.initial_position_mm.iter().all(|p| p.is_finite()) {
            return bad("initial_position_mm must be finite");
        }
        Ok(())
    }
}

/// The geometry of one segment, parametrised by the distance s travelled along it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Path {
    /// Standing still.
    Hold {
        /// Position (mm).
        at: [f64; 3],
    },
    /// Straight line.
    Line {
        /// Start (mm).
        from: [f64; 3],
        /// End (mm).
        to: [f64; 3],
        /// Length (mm).
        len: f64,
    },
    /// Circular or helical arc.
    Arc {
        /// The arc as programmed.
        arc: ArcMove,
        /// Path length (mm).
        len: f64,
    },
}

impl Path {
    /// Length (mm).
    pub fn len(&self) -> f64 {
        match *self {
            Path::Hold { .. } => 0.0,
            Path::Line { len, .. } | Path::Arc { len, .. } => len,
        }
    }

    /// Position (mm) after travelling `s` mm.
    pub fn at(&self, s: f64) -> [f64; 3] {
        match *self {
            Path::Hold { at } => at,
            Path::Line { from, to, len } => {
                if s >= len {
                    return to;
                }
                let u = s / len;
                [0, 1, 2].map(|k| from[k] + (to[k] - from[k]) * u)
            }
            Path::Arc { arc, len } => {
                if s >= len {
                    return arc.to;
                }
                let u = s / len;
                let (a, b, n) = arc.plane.axes();
                let th = arc.theta0_rad + arc.sweep_rad * u;
                let r = arc.radius_mm[0] + (arc.radius_mm[1] - arc.radius_mm[0]) * u;
                let (sn, cs) = th.sin_cos();
                let mut p = arc.centre;
                p[a] += r * cs;
                p[b] += r * sn;
                p[n] = arc.from[n] + (arc.to[n] - arc.from[n]) * u;
                p
            }
        }
    }

    /// Unit tangent at fraction `u` ∈ [0, 1] of the path (zero for a hold).
    pub fn tangent(&self, u: f64) -> [f64; 3] {
        let d = match *self {
            Path::Hold { .. } => return [0.0; 3],
            Path::Line { from, to, .. } => [0, 1, 2].map(|k| to[k] - from[k]),
            Path::Arc { arc, .. } => {
                let (a, b, n) = arc.plane.axes();
                let th = arc.theta0_rad + arc.sweep_rad * u;
                let dr = arc.radius_mm[1] - arc.radius_mm[0];
                let r = arc.radius_mm[0] + dr * u;
                let (sn, cs) = th.sin_cos();
                let mut d = [0.0; 3];
                d[a] = dr * cs - r * sn * arc.sweep_rad;
                d[b] = dr * sn + r * cs * arc.sweep_rad;
                d[n] = arc.to[n] - arc.from[n];
                d
            }
        };
        let m = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if m > 0.0 {
            d.map(|x| x / m)
        } else {
            [0.0; 3]
        }
    }

    /// Intervals of constant, non-zero direction of `axis` along the path: (start fraction u,
    /// direction ±1), in order. Empty if the axis does not move.
    fn directions(&self, axis: usize) -> Vec<(f64, i8)> {
        let sign = |x: f64| if x > 0.0 { 1 } else { -1 };
        match *self {
            Path::Hold { .. } => vec![],
            Path::Line { from, to, .. } => {
                let d = to[axis] - from[axis];
                if d == 0.0 {
                    vec![]
                } else {
                    vec![(0.0, sign(d))]
                }
            }
            Path::Arc { arc, .. } => {
                let (a, _, n) = arc.plane.axes();
                if axis == n {
                    let d = arc.to[n] - arc.from[n];
                    return if d == 0.0 {
                        vec![]
                    } else {
                        vec![(0.0, sign(d))]
                    };
                }
                // Velocity of the axis ∝ −sin θ·sweep (a) or cos θ·sweep (b): zero at θ = kπ (a)
                // or π/2 + kπ (b).
                let offset = if axis == a {
                    0.0
                } else {
                    std::f64::consts::FRAC_PI_2
                };
                let (t0, sw) = (arc.theta0_rad, arc.sweep_rad);
                let (lo, hi) = if sw > 0.0 {
                    (t0, t0 + sw)
                } else {
                    (t0 + sw, t0)
                };
                let pi = std::f64::consts::PI;
                let mut cuts = vec![0.0];
                let mut k = ((lo - offset) / pi).floor();
                loop {
                    let th = offset + k * pi;
                    if th >= hi {
                        break;
                    }
                    let u = (th - t0) / sw;
                    if u > 1e-12 && u < 1.0 - 1e-12 {
                        cuts.push(u);
                    }
                    k += 1.0;
                }
                cuts.sort_by(f64::total_cmp);
                cuts.push(1.0);
                let vel = |u: f64| {
                    let th = t0 + sw * u;
                    if axis == a {
                        -th.sin() * sw
                    } else {
                        th.cos() * sw
                    }
                };
                cuts.windows(2)
                    .map(|w| (w[0], sign(vel(0.5 * (w[0] + w[1])))))
                    .collect()
            }
        }
    }
}

/// A trapezoidal speed profile along a path of length `len`: accelerate at `a` from `v0` to `vp`,
/// cruise, decelerate to `v1`. A hold is a profile of length 0 lasting `t_total`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    /// Path length (mm).
    pub len: f64,
    /// Entry speed (mm/s).
    pub v0: f64,
    /// Peak (cruise) speed (mm/s).
    pub vp: f64,
    /// Exit speed (mm/s).
    pub v1: f64,
    /// Acceleration and deceleration along the path (mm/s²).
    pub a: f64,
    /// End of the acceleration phase (s).
    pub t1: f64,
    /// Start of the deceleration phase (s).
    pub t2: f64,
    /// Duration (s).
    pub t_total: f64,
    /// Distance at `t1` (mm).
    pub s1: f64,
    /// Distance at `t2` (mm).
    pub s2: f64,
}

impl Profile {
    /// Standing still for `seconds`.
    pub fn hold(seconds: f64) -> Self {
        Profile {
            len: 0.0,
            v0: 0.0,
            vp: 0.0,
            v1: 0.0,
            a: 1.0,
            t1: 0.0,
            t2: seconds,
            t_total: seconds,
            s1: 0.0,
            s2: 0.0,
        }
    }

    /// The fastest profile over `len` from `v0` to `v1` with speed ≤ `vmax` and acceleration ≤ `a`.
    /// The caller guarantees |v1² − v0²| ≤ 2·a·len (the lookahead passes do).
    pub fn new(len: f64, v0: f64, v1: f64, vmax: f64, a: f64) -> Self {
        if len <= 0.0 {
            return Profile::hold(0.0);
        }
        let vp = vmax
            .min((a * len + 0.5 * (v0 * v0 + v1 * v1)).sqrt())
            .max(v0)
            .max(v1);
        let s1 = (vp * vp - v0 * v0) / (2.0 * a);
        let s3 = (vp * vp - v1 * v1) / (2.0 * a);
        let sc = (len - s1 - s3).max(0.0);
        let t1 = (vp - v0) / a;
        let t2 = t1 + sc / vp;
        let t_total = t2 + (vp - v1) / a;
        Profile {
            len,
            v0,
            vp,
            v1,
            a,
            t1,
            t2,
            t_total,
            s1,
            s2: (s1 + sc).min(len),
        }
    }

    /// Distance travelled (mm) at time `t` (s) into the profile.
    pub fn s_at(&self, t: f64) -> f64 {
        let s = if t <= 0.0 || self.len == 0.0 {
            0.0
        } else if t < self.t1 {
            t * (self.v0 + 0.5 * self.a * t)
        } else if t < self.t2 {
            self.s1 + self.vp * (t - self.t1)
        } else if t < self.t_total {
            let r = t - self.t2;
            self.s2 + r * (self.vp - 0.5 * self.a * r)
        } else {
            self.len
        };
        s.min(self.len)
    }

    /// Speed along the path (mm/s) at time `t` into the profile.
    pub fn v_at(&self, t: f64) -> f64 {
        if self.len == 0.0 || t < 0.0 || t > self.t_total {
            0.0
        } else if t < self.t1 {
            self.v0 + self.a * t
        } else if t < self.t2 {
            self.vp
        } else {
            (self.vp - self.a * (t - self.t2)).max(0.0)
        }
    }

    /// Time (s) into the profile at which `s` mm have been travelled: the inverse of
    /// [`Self::s_at`], in the cancellation-free form of the quadratic's root.
    pub fn t_at(&self, s: f64) -> f64 {
        if s <= 0.0 {
            0.0
        } else if s < self.s1 {
            2.0 * s / (self.v0 + (self.v0 * self.v0 + 2.0 * self.a * s).sqrt())
        } else if s < self.s2 {
            self.t1 + (s - self.s1) / self.vp
        } else if s < self.len {
            let r = s - self.s2;
            let disc = (self.vp * self.vp - 2.0 * self.a * r).max(0.0);
            self.t2 + 2.0 * r / (self.vp + disc.sqrt())
        } else {
            self.t_total
        }
    }
}

/// What a segment is, for reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SegmentKind {
    /// G0.
    Rapid,
    /// G1.
    Line,
    /// G2 (`ccw` false) or G3.
    Arc {
        /// G3.
        ccw: bool,
    },
    /// G4.
    Dwell,
    /// M0/M1; `skipped` for an M1 with the optional-stop switch off.
    Stop {
        /// M1 not honoured.
        skipped: bool,
    },
}

/// One program block on the time axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Index of the block in [`Program::blocks`]; segments and blocks correspond one to one.
    pub block: usize,
    /// Source line (1-based).
    pub line: usize,
    /// What it is.
    pub kind: SegmentKind,
    /// Program time at which it starts (s).
    pub t_start_s: f64,
    /// Where it goes.
    pub path: Path,
    /// How fast.
    pub profile: Profile,
}

impl Segment {
    /// Program time at which it ends (s).
    pub fn t_end_s(&self) -> f64 {
        self.t_start_s + self.profile.t_total
    }

    /// Commanded position (mm) at program time `t` (clamped to the segment).
    pub fn position_at(&self, t: f64) -> [f64; 3] {
        self.path.at(self.profile.s_at(t - self.t_start_s))
    }
}

/// The moment an axis starts moving in direction `dir` (after moving the other way before).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DirEvent {
    /// Program time (s).
    pub t_s: f64,
    /// New direction, ±1.
    pub dir: i8,
}

/// The planned motion of a whole program.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// One per program block, in time order, end to end.
    pub segments: Vec<Segment>,
    /// Position before the program starts (mm).
    pub initial_mm: [f64; 3],
    /// Position after it ends (mm).
    pub final_mm: [f64; 3],
    /// Direction of each axis before its first move.
    pub initial_direction: [i8; 3],
    /// Direction changes of each axis (x, y, z), in time order.
    pub events: [Vec<DirEvent>; 3],
    /// Index of the first program stop that was honoured, if any.
    pub first_stop: Option<usize>,
    /// Cycle start: the end of the first program stop, or 0 if there is none (s).
    pub cycle_start_s: f64,
    /// Program end (s).
    pub end_s: f64,
}

impl Trajectory {
    /// Index of the segment running at program time `t`: the last one that has started (for
    /// t < 0, the first).
    pub fn segment_at(&self, t: f64) -> usize {
        self.segments
            .partition_point(|s| s.t_start_s <= t)
            .saturating_sub(1)
    }

    /// Commanded position (mm) at program time `t` (before the start: the initial position).
    pub fn position_at(&self, t: f64) -> [f64; 3] {
        if t <= 0.0 || self.segments.is_empty() {
            return self.initial_mm;
        }
        if t >= self.end_s {
            return self.final_mm;
        }
        self.segments[self.segment_at(t)].position_at(t)
    }

    /// Direction in which `axis` last moved at program time `t`, and when it last changed (the
    /// latest reversal), if it has.
    pub fn direction_at(&self, axis: usize, t: f64) -> (i8, Option<f64>) {
        let ev = &self.events[axis];
        let i = ev.partition_point(|e| e.t_s <= t);
        if i == 0 {
            (self.initial_direction[axis], None)
        } else {
            (ev[i - 1].dir, Some(ev[i - 1].t_s))
        }
    }
}

enum Spec {
    Move {
        path: Path,
        vmax: f64,
        a: f64,
        exact_stop: bool,
    },
    Hold(f64),
    /// Takes no time and does not stop the motion (zero-length move, skipped M1).
    Transparent([f64; 3]),
}

/// Plan `program` on `machine`. The first honoured program stop lasts `first_stop_s` (the
/// instrument is mounted there and the recording runs), later ones
/// [`MachineConfig::stop_wait_s`].
pub fn plan(
    program: &Program,
    machine: &MachineConfig,
    first_stop_s: f64,
) -> Result<Trajectory, SimError> {
    machine.validate()?;
    let acc = machine.accel_mm_s2;
    let ovr = machine.feed_override_pct / 100.0;
    let line_accel = |from: [f64; 3], to: [f64; 3], len: f64| {
        (0..3)
            .filter(|&k| (to[k] - from[k]).abs() > 1e-12 * len)
            .map(|k| acc[k] * len / (to[k] - from[k]).abs())
            .fold(f64::INFINITY, f64::min)
    };
    let mut kinds = Vec::with_capacity(program.blocks.len());
    let mut specs = Vec::with_capacity(program.blocks.len());
    let mut first_stop = None;
    let mut pos = program.initial_mm;
    for (i, b) in program.blocks.iter().enumerate() {
        let (kind, spec) = match b.action {
            Action::Rapid { from, to } | Action::Line { from, to, .. } => {
                let len = dist(from, to);
                let (kind, v) = match b.action {
                    Action::Line { feed_mm_min, .. } => {
                        (SegmentKind::Line, feed_mm_min / 60.0 * ovr)
                    }
                    _ => (SegmentKind::Rapid, machine.rapid_mm_min / 60.0),
                };
                pos = to;
                if len < 1e-9 {
                    (kind, Spec::Transparent(to))
                } else {
                    (
                        kind,
                        Spec::Move {
                            path: Path::Line { from, to, len },
                            vmax: v,
                            a: line_accel(from, to, len),
                            exact_stop: b.exact_stop,
                        },
                    )
                }
            }
            Action::Arc(arc) => {
                let (pa, pb, n) = arc.plane.axes();
                let r_mean = 0.5 * (arc.radius_mm[0] + arc.radius_mm[1]);
                let h = arc.to[n] - arc.from[n];
                let len = (r_mean * arc.sweep_rad).hypot(h);
                let a_plane = acc[pa].min(acc[pb]);
                let mut a = ARC_TANGENTIAL_SHARE * a_plane;
                if h != 0.0 {
                    a = a.min(acc[n] * len / h.abs());
                }
                let r_min = arc.radius_mm[0].min(arc.radius_mm[1]);
                let vmax =
                    (arc.feed_mm_min / 60.0 * ovr).min((ARC_NORMAL_SHARE * a_plane * r_min).sqrt());
                pos = arc.to;
                (
                    SegmentKind::Arc {
                        ccw: arc.sweep_rad > 0.0,
                    },
                    Spec::Move {
                        path: Path::Arc { arc, len },
                        vmax,
                        a,
                        exact_stop: b.exact_stop,
                    },
                )
            }
            Action::Dwell { seconds } => (SegmentKind::Dwell, Spec::Hold(seconds)),
            Action::Stop { optional } => {
                if optional && !machine.optional_stop {
                    (SegmentKind::Stop { skipped: true }, Spec::Transparent(pos))
                } else {
                    let d = if first_stop.is_none() {
                        first_stop = Some(i);
                        first_stop_s
                    } else {
                        machine.stop_wait_s
                    };
                    (SegmentKind::Stop { skipped: false }, Spec::Hold(d))
                }
            }
        };
        kinds.push(kind);
        specs.push(spec);
    }

    // Junction speed caps between consecutive moves; 0 where anything stops the machine.
    let moves: Vec<usize> = (0..specs.len())
        .filter(|&i| matches!(specs[i], Spec::Move { .. }))
        .collect();
    let cos_blend = machine.blend_angle_deg.to_radians().cos();
    let mut cap = vec![0.0; moves.len() + 1]; // cap[k]: entry of moves[k]; cap[len] = program end
    for k in 1..moves.len() {
        let (i, j) = (moves[k - 1], moves[k]);
        let holds_between = specs[i + 1..j].iter().any(|s| matches!(s, Spec::Hold(_)));
        let (
            Spec::Move {
                path: p,
                vmax: vi,
                exact_stop,
                a: ai,
                ..
            },
            Spec::Move {
                path: q,
                vmax: vj,
                a: aj,
                ..
            },
        ) = (&specs[i], &specs[j])
        else {
            unreachable!()
        };
        if holds_between || *exact_stop {
            continue;
        }
        let (ti, tj) = (p.tangent(1.0), q.tangent(0.0));
        let dot = ti[0] * tj[0] + ti[1] * tj[1] + ti[2] * tj[2];
        if dot >= cos_blend {
            cap[k] = vi.min(*vj);
        } else if machine.junction_deviation_mm > 0.0 {
            // θ between the lines: sin(θ/2) = √((1 + t_i·t_j)/2); a reversal (θ = 0) stops.
            let sin_half = (0.5 * (1.0 + dot)).max(0.0).sqrt().min(1.0 - 1e-12);
            let v2 = ai.min(*aj) * machine.junction_deviation_mm * sin_half / (1.0 - sin_half);
            cap[k] = vi.min(*vj).min(v2.sqrt());
        }
    }
    // Lookahead: backward then forward.
    let lim = |k: usize| match &specs[moves[k]] {
        Spec::Move { path, vmax, a, .. } => (path.len(), *vmax, *a),
        _ => unreachable!(),
    };
    let nm = moves.len();
    let mut entry = vec![0.0; nm];
    let mut exit = vec![0.0; nm];
    let mut next_entry = 0.0;
    for k in (0..nm).rev() {
        let (len, vmax, a) = lim(k);
        exit[k] = cap[k + 1].min(next_entry);
        if k + 1 == nm {
            exit[k] = 0.0;
        }
        entry[k] = cap[k]
            .min(vmax)
            .min((exit[k] * exit[k] + 2.0 * a * len).sqrt());
        next_entry = entry[k];
    }
    let mut prev_exit = 0.0;
    for k in 0..nm {
        let (len, _, a) = lim(k);
        entry[k] = entry[k].min(prev_exit);
        exit[k] = exit[k].min((entry[k] * entry[k] + 2.0 * a * len).sqrt());
        prev_exit = exit[k];
    }

    // Times.
    let mut segments = Vec::with_capacity(specs.len());
    let mut t = 0.0;
    let mut k = 0;
    let mut here = program.initial_mm;
    for (i, spec) in specs.iter().enumerate() {
        let (path, profile) = match spec {
            Spec::Move { path, vmax, a, .. } => {
                let p = Profile::new(path.len(), entry[k], exit[k], *vmax, *a);
                k += 1;
                here = path.at(path.len());
                (*path, p)
            }
            Spec::Hold(d) => (Path::Hold { at: here }, Profile::hold(*d)),
            Spec::Transparent(at) => {
                here = *at;
                (Path::Hold { at: here }, Profile::hold(0.0))
            }
        };
        segments.push(Segment {
            block: i,
            line: program.blocks[i].line,
            kind: kinds[i],
            t_start_s: t,
            path,
            profile,
        });
        t += profile.t_total;
    }

    // Direction changes per axis.
    let mut events: [Vec<DirEvent>; 3] = Default::default();
    for (axis, ev) in events.iter_mut().enumerate() {
        let mut cur = machine.initial_direction[axis];
        for s in &segments {
            for (u, dir) in s.path.directions(axis) {
                if dir != cur {
                    let t_s = s.t_start_s + s.profile.t_at(u * s.path.len());
                    ev.push(DirEvent { t_s, dir });
                    cur = dir;
                }
            }
        }
    }
    let cycle_start_s = first_stop.map_or(0.0, |i: usize| segments[i].t_end_s());
    Ok(Trajectory {
        initial_mm: program.initial_mm,
        final_mm: here,
        initial_direction: machine.initial_direction,
        events,
        first_stop,
        cycle_start_s,
        end_s: t,
        segments,
    })
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::super::program::{parse_program, Dialect, ProgramOptions};
    use super::*;

    fn traj(text: &str, m: &MachineConfig) -> Trajectory {
        let p = parse_program(
            text,
            ProgramOptions::new(Dialect::LinuxCnc),
            m.initial_position_mm,
        )
        .unwrap();
        plan(&p, m, 2.0).unwrap()
    }

    /// Rest-to-rest move of length L at speed limit v and acceleration a.
    fn analytic(l: f64, v: f64, a: f64) -> f64 {
        if l >= v * v / a {
            l / v + v / a
        } else {
            2.0 * (l / a).sqrt()
        }
    }

    #[test]
    fn g1_duration_matches_the_trapezoid_formula() {
        let m = MachineConfig {
            accel_mm_s2: [500.0, 250.0, 100.0],
            ..MachineConfig::default()
        };
        // Long x move: trapezoid; F1200 = 20 mm/s, a = 500.
        let t = traj("G21 G90 G1 X100 F1200\n", &m);
        assert!(
            (t.end_s - analytic(100.0, 20.0, 500.0)).abs() < 1e-12,
            "{}",
            t.end_s
        );
        assert!((t.end_s - (5.0 + 0.04)).abs() < 1e-12);
        // Short move: triangle, peak √(aL) = 7.07 mm/s < 20.
        let t = traj("G21 G90 G1 X0.1 F1200\n", &m);
        assert!((t.end_s - 2.0 * (0.1f64 / 500.0).sqrt()).abs() < 1e-12);
        // Diagonal (3, 4, 0)·5: a = min(500/0.6, 250/0.8) = 312.5 mm/s².
        let t = traj("G21 G90 G1 X15 Y20 F1200\n", &m);
        assert!((t.end_s - analytic(25.0, 20.0, 312.5)).abs() < 1e-12);
        // Feed override 50 %: 10 mm/s.
        let m50 = MachineConfig {
            feed_override_pct: 50.0,
            ..m
        };
        let t = traj("G21 G90 G1 X100 F1200\n", &m50);
        assert!((t.end_s - analytic(100.0, 10.0, 500.0)).abs() < 1e-12);
        // Rapid: not overridden, 5000 mm/min.
        let t = traj("G21 G90 G0 X100\n", &m50);
        assert!((t.end_s - analytic(100.0, 5000.0 / 60.0, 500.0)).abs() < 1e-12);
    }

    #[test]
    fn profile_inverse_and_continuity() {
        let p = Profile::new(10.0, 3.0, 1.0, 8.0, 20.0);
        for i in 0..=1000 {
            let s = 10.0 * i as f64 / 1000.0;
            let t = p.t_at(s);
            assert!((p.s_at(t) - s).abs() < 1e-9, "{s} {t}");
        }
        assert!((p.s_at(p.t_total) - 10.0).abs() < 1e-12);
        assert!((p.v_at(0.0) - 3.0).abs() < 1e-12 && (p.v_at(p.t_total) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn junction_deviation_passes_a_corner_at_grbls_speed() {
        // δ 0.01 mm, a 500 mm/s², 90°: v² = 500·0.01·√½/(1 − √½) → v = 3.474 mm/s; two 100 mm
        // moves at 20 mm/s through it take the time of their two profiles with that junction.
        let m = MachineConfig {
            junction_deviation_mm: 0.01,
            ..MachineConfig::default()
        };
        let s = 0.5f64.sqrt();
        let v = (500.0 * 0.01 * s / (1.0 - s)).sqrt();
        assert!((v - 3.474).abs() < 1e-3);
        let t = traj("G21 G90 G1 X100 F1200\nY100\n", &m);
        let leg = |v0: f64, v1: f64| Profile::new(100.0, v0, v1, 20.0, 500.0).t_total;
        assert!((t.end_s - (leg(0.0, v) + leg(v, 0.0))).abs() < 1e-9);
        // A reversal still stops.
        let t = traj("G21 G90 G1 X100 F1200\nX0\n", &m);
        assert!((t.end_s - 2.0 * analytic(100.0, 20.0, 500.0)).abs() < 1e-9);
    }

    #[test]
    fn tangent_junctions_blend_corners_stop() {
        let m = MachineConfig::default();
        // Two collinear lines: one rest-to-rest move of 200 mm.
        let t = traj("G21 G90 G1 X100 F1200\nX200\n", &m);
        assert!((t.end_s - analytic(200.0, 20.0, 500.0)).abs() < 1e-9);
        // A right-angle corner: two rest-to-rest moves.
        let t = traj("G21 G90 G1 X100 F1200\nY100\n", &m);
        assert!((t.end_s - 2.0 * analytic(100.0, 20.0, 500.0)).abs() < 1e-9);
        // A full circle as two 180° arcs at 1000 mm/min, R 90: one move of length 2πR.
        let t = traj(
            "G21 G90 G0 X90 Y0\nG3 X-90 Y0 I-90 J0 F1000\nG3 X90 Y0 I90 J0\n",
            &m,
        );
        let arcs = t.end_s - t.segments[1].t_start_s;
        let l = std::f64::consts::TAU * 90.0;
        assert!(
            (arcs - analytic(l, 1000.0 / 60.0, 250.0)).abs() < 1e-9,
            "{arcs}"
        );
        // Exact stop mode stops between them.
        let t = traj(
            "G21 G90 G61 G0 X90 Y0\nG3 X-90 Y0 I-90 J0 F1000\nG3 X90 Y0 I90 J0\n",
            &m,
        );
        let arcs = t.end_s - t.segments[1].t_start_s;
        assert!(
            (arcs - 2.0 * analytic(l / 2.0, 1000.0 / 60.0, 250.0)).abs() < 1e-9,
            "{arcs}"
        );
    }

    #[test]
    fn centripetal_limit_slows_small_arcs() {
        let m = MachineConfig {
            accel_mm_s2: [100.0, 100.0, 100.0],
            ..MachineConfig::default()
        };
        // R 1 mm at 3000 mm/min = 50 mm/s: v²/R would be 2500 mm/s²; capped at √(0.866·100·1).
        let t = traj("G21 G90 G0 X1 Y0\nG3 X1 Y0 I-1 J0 F3000\n", &m);
        let s = &t.segments[1];
        let v = (ARC_NORMAL_SHARE * 100.0).sqrt();
        assert!((s.profile.vp - v).abs() < 1e-12);
        assert!(s.profile.vp * s.profile.vp / 1.0 <= ARC_NORMAL_SHARE * 100.0 + 1e-9);
    }

    #[test]
    fn arcs_end_where_programmed_and_turn_the_right_way() {
        let m = MachineConfig::default();
        // Angular velocity vector r × v: along +n for G3, −n for G2, in each plane.
        let cases = [
            (
                "G17",
                "G3 X0 Y10 I-10 J0",
                [10.0, 0.0, 0.0],
                [0.0, 10.0, 0.0],
                [0.0, 0.0, 1.0],
            ),
            (
                "G17",
                "G2 X0 Y-10 I-10 J0",
                [10.0, 0.0, 0.0],
                [0.0, -10.0, 0.0],
                [0.0, 0.0, -1.0],
            ),
            (
                "G18",
                "G3 X10 Z0 I0 K-10",
                [0.0, 0.0, 10.0],
                [10.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
            ),
            (
                "G18",
                "G2 X-10 Z0 I0 K-10",
                [0.0, 0.0, 10.0],
                [-10.0, 0.0, 0.0],
                [0.0, -1.0, 0.0],
            ),
            (
                "G19",
                "G3 Y0 Z10 J-10 K0",
                [0.0, 10.0, 0.0],
                [0.0, 0.0, 10.0],
                [1.0, 0.0, 0.0],
            ),
            (
                "G19",
                "G2 Y0 Z-10 J-10 K0",
                [0.0, 10.0, 0.0],
                [0.0, 0.0, -10.0],
                [-1.0, 0.0, 0.0],
            ),
        ];
        for (plane, arc, start, end, axis) in cases {
            let text = format!(
                "G21 G90 {plane} G0 X{} Y{} Z{}\n{arc} F600\n",
                start[0], start[1], start[2]
            );
            let t = traj(&text, &m);
            let s = &t.segments[1];
            let e = s.position_at(s.t_end_s());
            assert!(dist(e, end) < 1e-12, "{plane} {arc}: ends at {e:?}");
            // Mid-arc: r × v from two nearby positions (centre at the origin).
            let tm = 0.5 * (s.t_start_s + s.t_end_s());
            let p = s.position_at(tm);
            let q = s.position_at(tm + 1e-3);
            let v = [0, 1, 2].map(|k| q[k] - p[k]);
            let w = [
                p[1] * v[2] - p[2] * v[1],
                p[2] * v[0] - p[0] * v[2],
                p[0] * v[1] - p[1] * v[0],
            ];
            let wn = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            for k in 0..3 {
                assert!(
                    (w[k] / wn - axis[k]).abs() < 1e-6,
                    "{plane} {arc}: r×v {w:?}"
                );
            }
            // Radius 10 throughout.
            assert!((dist(p, [0.0; 3]) - 10.0).abs() < 1e-9);
        }
    }

    #[test]
    fn direction_events_on_a_circle() {
        let m = MachineConfig {
            initial_direction: [1, 1, 1],
            ..MachineConfig::default()
        };
        // ccw full circle from θ = 45°: x reverses at 180° (to +), y at 90° (to −) and 270° (to +);
        // x at 360° (to −) after the +x of 180..360.
        let r = 50.0;
        let (c, s) = (r * 0.5f64.sqrt(), r * 0.5f64.sqrt());
        let text = format!("G21 G90 G0 X{c} Y{s}\nG3 X{c} Y{s} I{} J{} F600\n", -c, -s);
        let t = traj(&text, &m);
        // G0 from the origin moved +x +y: no event yet.
        let arc = &t.segments[1];
        let at_angle = |deg: f64| {
            let frac = (deg - 45.0) / 360.0;
            arc.t_start_s + arc.profile.t_at(frac * arc.path.len())
        };
        let x: Vec<_> = t.events[0].iter().map(|e| (e.t_s, e.dir)).collect();
        let y: Vec<_> = t.events[1].iter().map(|e| (e.t_s, e.dir)).collect();
        assert_eq!(x.len(), 3, "{x:?}"); // −x at 45°, + at 180°, − at 360°
        assert_eq!(x[0].1, -1);
        assert!((x[0].0 - arc.t_start_s).abs() < 1e-12);
        assert!((x[1].0 - at_angle(180.0)).abs() < 1e-9 && x[1].1 == 1);
        assert!((x[2].0 - at_angle(360.0)).abs() < 1e-9 && x[2].1 == -1);
        assert_eq!(y.len(), 2, "{y:?}");
        assert!((y[0].0 - at_angle(90.0)).abs() < 1e-9 && y[0].1 == -1);
        assert!((y[1].0 - at_angle(270.0)).abs() < 1e-9 && y[1].1 == 1);
        assert_eq!(t.direction_at(1, at_angle(100.0)), (-1, Some(y[0].0)));
    }
}
