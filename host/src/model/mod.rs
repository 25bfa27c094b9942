//! Candidate effects of a circular test: parametric models of the error δ added to the nominal
//! spindle-ball position, and the exact ball-distance model D = |p + δ + c| + e built from them.
//!
//! Most effects are *linear in their parameters* given the nominal path: a periodic term
//! A·sin(2πk/p + φ) is fitted as A_s·sin(2πk/p) + A_c·cos(2πk/p), so a fit never has to search a
//! phase. Two are not: the reversal spike's decay time τ and the servo delay's common lag. The
//! exact geometry and those two are handled by [`ExactModel`] with the least-squares engine in
//! [`crate::numerics::lsq`] ([`Effect::add_delta_block`], [`Effect::gradient_block`]).
//! Linearised at the nominal path (seed 000 eq. 1, ΔR = u·δ with u = p/|p|), each parameter of
//! a [`Candidate`] is one column of a linear model, which the diagnosis uses for a fast search
//! ([`Candidate::columns_block`]): a spike at a trial τ, a servo delay by its mismatch and the
//! cross term of mismatch and lag (see [`Effect::ServoMismatch`]).
//!
//! Conventions (the same as `jdbb_core::machine`): positions in mm relative to the table ball,
//! velocities mm/s, δ positive lengthens the axis. Parameters are in their reporting units (µm,
//! µm/m, µm/m², µm per mm/s, ms, µm/min) so the fit's column scaling is well conditioned.
//!
//! The folder `model/`: what a test's path and a machine's errors are, in the trade's words.
//! - [`path`]: the nominal path (positions, velocity, direction, pitch phase).
//! - this module: the candidate machine effects (seed 000) and the exact distance
//!   D = |p + δ + c| + e built from them.
//! - [`words`]: what each effect means in the trade's words (the causes every output shows).
//! - [`settable`]: which effects a controller setting can remove ("compensable"), and the
//!   controllers `jdbb compensate` knows.
//!
//! May use: [`crate::numerics`], `jdbb_core::machine`. The lowest of the test folders:
//! `model` ← `plan`, `sync`, `simulate`, `diagnose`, `report`; it uses none of them.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
mod candidate;
pub mod path;
pub mod settable;
pub mod words;
pub use candidate::*;
use std::fmt;

pub use crate::model::path::{parse_pitch, Axis, Pair, Path};

/// One candidate effect. Names (see [`Effect::name`]) are the issue's, used everywhere.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// c: where the table ball is relative to where it was assumed (µm per axis); the spindle
    /// ball is then at p + δ − c from it: D = |p + δ − c| + e. The same sign as `calibrate`'s
    /// table-ball offset.
    SetupOffset,
    /// e added to D (µm).
    LengthOffset,
    /// δ_k = a·k, a in µm/m (seed 000 eq. 2, first-order uniform contraction).
    Scale(Axis),
    /// δ_k = b·k², b in µm/m² (seed 000 eq. 5, second-order uniform contraction).
    Scale2(Axis),
    /// Lost motion of axis k, b in µm: **positive = play** (a nut clearance: the carriage lags
    /// its motor by b/2 in the direction of motion), negative = the axis runs ahead by |b|/2
    /// (over-compensation). Play is a *dead band* (a play operator between motor and carriage):
    /// after a reversal at x_r the carriage stands still until the motor has travelled b, so
    /// δ_k = −s·b/2 + s·max(0, b − s·(k − x_r)) with s the new direction; on a circle the gap is
    /// taken up over Δθ ≈ √(2b/R). A negative b is a step at the reversal (the controller's
    /// compensation jumps the motor through the gap), which is seed 000 eq. 14 with f = −b.
    Backlash(Axis),
    /// Lost motion that differs along the travel (a worn screw): the gap grows linearly from
    /// `neg_um` at the low end of the axis's travel to `pos_um` at the high end (the circle's
    /// ends, ±R about the table ball: [`travel_ends_mm`]), each taken up as a dead band as in
    /// [`Effect::Backlash`]; the ballbar's backlash at the negative and the positive reversal.
    /// Reported under the same name (`backlash_k`), value (pos + neg)/2: the gap at the ball.
    BacklashEnds(Axis),
    /// A bowed axis i (straightness): moving along i, axis j is displaced by
    /// δ_j = w·(1 − 4·((i − i_mid)/L)²), w in µm: the bow of the middle of the travel L of i
    /// between the circle's ends (±R about the table ball, [`travel_ends_mm`]; i_mid the ball)
    /// relative to the line through them, positive towards +j. On one circle, and on every arc of
    /// it, i² = R² − j², so it is the same data as `scale2_j` with a set-up offset.
    Straightness(Axis, Axis),
    /// Lateral play of axis i in direction j (a guideway clearance across its travel): when i
    /// reverses, friction turns and the carriage shifts across the clearance, so
    /// δ_j = (l/2)·s_i with s_i the direction of i, l in µm (positive: towards +j while i moves
    /// in +i). A step where i reverses, seen in j; on a circle ∓(l/2)·|u_j| by direction.
    LateralPlay(Axis, Axis),
    /// δ_k = A·sin(2πk/p + φ), A in µm (seed 000 eq. 8, periodic error).
    Cyclic(Axis),
    /// δ_k = b·v_k·sin(2πk/p + φ), b in µm per mm/s (seed 000 eq. 11, interference).
    Interference(Axis),
    /// δ_i = s·j, s in µm/m.
    Squareness(Pair),
    /// A true delay: axis i follows its command τ_i late, δ_i = p_i(t − τ_i) − p_i(t), and j by
    /// τ_j. Parameters: the mismatch Δτ = τ_i − τ_j (`dtau_ms`, the reported value) and the common
    /// lag τ̄ = (τ_i + τ_j)/2 (`lag_ms`). Evaluated to second order,
    /// δ_i = −τ_i·v_i + τ_i²·a_i/2 (the third-order term, R·ω³·τ³/6, is below 0.04 µm for
    /// τ ≤ 10 ms at ω ≤ 1.7 rad/s). To first order only Δτ is seen (the common lag moves the ball
    /// along the path); the cross term τ̄·Δτ·(a_i, −a_j)/2 looks like a scale mismatch on one
    /// circle at one speed and is told apart from one by a second radius or feed, where the
    /// angular speed ω differs (a_k = −ω²·p_k on a circle).
    ServoMismatch(Pair),
    /// Identifiable combination scale_i − scale_j (µm/m) when the isotropic scale is confounded
    /// with length_offset: δ_i = +(a/2)·i, δ_j = −(a/2)·j.
    ScaleMismatch(Pair),
    /// At each reversal of axis k (time t_r, new direction s): δ_k = −h·s·exp(−(t − t_r)/τ) for
    /// t ≥ t_r until the next reversal of k: the axis sticks, then catches up. h in µm, τ in ms.
    ReversalSpike(Axis),
    /// D changes linearly with time: +r·(t − t₀) with r in µm/min and t₀ the first sample.
    Drift,
    /// Thermal drift of scale: axis k's scale grows in time (heat in its screw),
    /// δ_k = ρ·((t − t₀)/60 s)·k with ρ in µm/m per minute, about the table ball (the growth about
    /// the screw's fixed bearing elsewhere adds a [`Effect::PositionDrift`] of k). Told from a
    /// static scale by a test that closes on itself in time (`jdbb plan --close`).
    ScaleDrift(Axis),
    /// Axis k's position drifts in time: δ_k = g·(t − t₀)/60 s, g in µm/min (a screw growing
    /// about a fixed bearing away from the table ball, a spindle growing towards the table).
    PositionDrift(Axis),
    /// The position loops' following error beyond their delay (issue 26): every axis is drawn
    /// δ_k = q·a_k off its command, a_k the command's acceleration, q in ms². A loop of gain Kv
    /// with velocity feed-forward k_v follows as H(s) = (Kv + k_v·s)/(s + Kv)
    /// = 1 − (1 − k_v)·s/Kv + (1 − k_v)·s²/Kv² − …: the s term is a delay along the path (the
    /// servo delay, absorbed by the timeline), the s² term this δ; with the delay's own
    /// second-order part a circle of radius R at speed v (ω = v/R) is drawn with amplitude
    /// |H(jω)| ≈ 1 − (1 − k_v²)·ω²/(2Kv²), i.e. smaller by the **radius loss**
    /// q·v²/R = q·ω²·R with q = (1 − k_v²)/(2Kv²) (no feed-forward: v²/(2R·Kv²)). The
    /// reported value is q (`q_ms2`); [`following_error_kv_per_s`] turns it into the loop gain
    /// of a loop without feed-forward that loses as much, and [`radius_loss_um`] into the radius
    /// lost at a circle's feed and radius. It grows with feed and falls with radius: a scale
    /// grows with radius and not with feed, so two feeds (or radii and feeds such that a·R,
    /// −q·v²/R and the length offset are not collinear) tell them apart.
    FollowingError,
}

/// The loop gain Kv (s⁻¹) of a position loop without feed-forward whose following error is
/// `q_ms2` (q = 1/(2Kv²)): the equivalent loop gain a servo engineer compares with the drive's
/// setting; None where q is not positive (a loop with feed-forward above 1 draws circles larger).
pub fn following_error_kv_per_s(q_ms2: f64) -> Option<f64> {
    (q_ms2 > 0.0).then(|| 1.0 / (2.0 * q_ms2 * 1e-6).sqrt())
}

/// The radius (µm) a following error `q_ms2` takes off a circle of `radius_mm` run at
/// `feed_mm_min`: q·v²/R ([`Effect::FollowingError`]).
pub fn radius_loss_um(q_ms2: f64, feed_mm_min: f64, radius_mm: f64) -> f64 {
    let v_mm_s = feed_mm_min / 60.0;
    1e-3 * q_ms2 * v_mm_s * v_mm_s / radius_mm
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// Smallest spike decay time (ms) the model evaluates: a fit that steps τ below it sees a spike
/// that is gone after one sample.
pub(crate) const MIN_TAU_MS: f64 = 1e-3;

impl Effect {
    /// Every effect name the user may give, in the order (without the derived
    /// `scale_mismatch_*`, which the diagnosis introduces itself but which also parse).
    pub fn all() -> Vec<Effect> {
        let mut v = vec![Effect::SetupOffset, Effect::LengthOffset];
        for a in Axis::ALL {
            v.push(Effect::Scale(a));
        }
        for a in Axis::ALL {
            v.push(Effect::Scale2(a));
        }
        for a in Axis::ALL {
            v.push(Effect::Backlash(a));
        }
        for a in Axis::ALL {
            v.push(Effect::Cyclic(a));
        }
        for a in Axis::ALL {
            v.push(Effect::Interference(a));
        }
        for p in Pair::ALL {
            v.push(Effect::Squareness(p));
        }
        for p in Pair::ALL {
            v.push(Effect::ServoMismatch(p));
        }
        for a in Axis::ALL {
            v.push(Effect::ReversalSpike(a));
        }
        for a in Axis::ALL {
            for b in Axis::ALL {
                if a != b {
                    v.push(Effect::Straightness(a, b));
                }
            }
        }
        for a in Axis::ALL {
            for b in Axis::ALL {
                if a != b {
                    v.push(Effect::LateralPlay(a, b));
                }
            }
        }
        v.push(Effect::Drift);
        v.extend(Axis::ALL.map(Effect::ScaleDrift));
        v.extend(Axis::ALL.map(Effect::PositionDrift));
        v.push(Effect::FollowingError);
        v
    }

    /// The effect's name, e.g. `scale_x`, `servo_mismatch_xy`.
    pub fn name(&self) -> String {
        match *self {
            Effect::SetupOffset => "setup_offset".into(),
            Effect::LengthOffset => "length_offset".into(),
            Effect::Scale(a) => format!("scale_{}", a.letter()),
            Effect::Scale2(a) => format!("scale2_{}", a.letter()),
            Effect::Backlash(a) | Effect::BacklashEnds(a) => format!("backlash_{}", a.letter()),
            Effect::Straightness(a, b) => format!("straightness_{}_{}", a.letter(), b.letter()),
            Effect::LateralPlay(a, b) => format!("lateral_play_{}_{}", a.letter(), b.letter()),
            Effect::Cyclic(a) => format!("cyclic_{}", a.letter()),
            Effect::Interference(a) => format!("interference_{}", a.letter()),
            Effect::Squareness(p) => format!("squareness_{}", p.name()),
            Effect::ServoMismatch(p) => format!("servo_mismatch_{}", p.name()),
            Effect::ScaleMismatch(p) => format!("scale_mismatch_{}", p.name()),
            Effect::ReversalSpike(a) => format!("reversal_spike_{}", a.letter()),
            Effect::Drift => "drift".into(),
            Effect::ScaleDrift(a) => format!("scale_drift_{}", a.letter()),
            Effect::PositionDrift(a) => format!("position_drift_{}", a.letter()),
            Effect::FollowingError => "following_error".into(),
        }
    }

    /// Parse an effect name; None if unknown.
    pub fn parse(name: &str) -> Option<Effect> {
        match name {
            "setup_offset" => return Some(Effect::SetupOffset),
            "length_offset" => return Some(Effect::LengthOffset),
            "drift" => return Some(Effect::Drift),
            "following_error" => return Some(Effect::FollowingError),
            _ => {}
        }
        for (prefix, make) in [
            (
                "straightness_",
                Effect::Straightness as fn(Axis, Axis) -> Effect,
            ),
            ("lateral_play_", Effect::LateralPlay),
        ] {
            if let Some(rest) = name.strip_prefix(prefix) {
                let (a, b) = rest.split_once('_')?;
                let (a, b) = (Axis::parse(a)?, Axis::parse(b)?);
                return (a != b).then_some(make(a, b));
            }
        }
        let (head, tail) = name.rsplit_once('_')?;
        match head {
            "scale" => Axis::parse(tail).map(Effect::Scale),
            "scale2" => Axis::parse(tail).map(Effect::Scale2),
            "backlash" => Axis::parse(tail).map(Effect::Backlash),
            "cyclic" => Axis::parse(tail).map(Effect::Cyclic),
            "interference" => Axis::parse(tail).map(Effect::Interference),
            "squareness" => Pair::parse(tail).map(Effect::Squareness),
            "servo_mismatch" => Pair::parse(tail).map(Effect::ServoMismatch),
            "scale_mismatch" => Pair::parse(tail).map(Effect::ScaleMismatch),
            "reversal_spike" => Axis::parse(tail).map(Effect::ReversalSpike),
            "scale_drift" => Axis::parse(tail).map(Effect::ScaleDrift),
            "position_drift" => Axis::parse(tail).map(Effect::PositionDrift),
            _ => None,
        }
    }

    /// Growth in time (heat): a drift of an axis's scale or position, which only a test that
    /// closes on itself tells from a scale or from a difference between the directions.
    pub fn is_drift_in_time(&self) -> bool {
        matches!(self, Effect::ScaleDrift(_) | Effect::PositionDrift(_))
    }

    /// Setup (not a machine error): the ball positions of this particular set-up.
    pub fn is_setup(&self) -> bool {
        matches!(self, Effect::SetupOffset | Effect::LengthOffset)
    }

    /// Unit of the effect's value.
    pub fn unit(&self) -> &'static str {
        match self {
            Effect::SetupOffset | Effect::LengthOffset => "um",
            Effect::Scale(_) | Effect::Squareness(_) | Effect::ScaleMismatch(_) => "um/m",
            Effect::Scale2(_) => "um/m^2",
            Effect::Backlash(_)
            | Effect::BacklashEnds(_)
            | Effect::Cyclic(_)
            | Effect::ReversalSpike(_)
            | Effect::Straightness(..)
            | Effect::LateralPlay(..) => "um",
            Effect::Interference(_) => "um/(mm/s)",
            Effect::ServoMismatch(_) => "ms",
            Effect::Drift | Effect::PositionDrift(_) => "um/min",
            Effect::ScaleDrift(_) => "um/m/min",
            Effect::FollowingError => "ms^2",
        }
    }

    /// Names of the parameters (JSON keys).
    pub fn param_names(&self) -> &'static [&'static str] {
        match self {
            Effect::SetupOffset => &["x_um", "y_um", "z_um"],
            Effect::LengthOffset => &["e_um"],
            Effect::Scale(_) | Effect::ScaleMismatch(_) => &["a_um_per_m"],
            Effect::Scale2(_) => &["b_um_per_m2"],
            Effect::Backlash(_) => &["b_um"],
            Effect::BacklashEnds(_) => &["pos_um", "neg_um"],
            Effect::Straightness(..) => &["bow_um"],
            Effect::LateralPlay(..) => &["l_um"],
            Effect::Cyclic(_) => &["sin_um", "cos_um"],
            Effect::Interference(_) => &["sin_um_per_mm_s", "cos_um_per_mm_s"],
            Effect::Squareness(_) => &["s_um_per_m"],
            Effect::ServoMismatch(_) => &["dtau_ms", "lag_ms"],
            Effect::ReversalSpike(_) => &["h_um", "tau_ms"],
            Effect::Drift | Effect::PositionDrift(_) => &["rate_um_per_min"],
            Effect::ScaleDrift(_) => &["rate_um_per_m_per_min"],
            Effect::FollowingError => &["q_ms2"],
        }
    }

    pub fn n_params(&self) -> usize {
        self.param_names().len()
    }

    /// Whether the effect needs a pitch.
    pub fn periodic_axis(&self) -> Option<Axis> {
        match *self {
            Effect::Cyclic(a) | Effect::Interference(a) => Some(a),
            _ => None,
        }
    }

    /// Whether the model is linear in all the effect's parameters (given the nominal path).
    pub fn is_linear(&self) -> bool {
        !matches!(
            self,
            Effect::ServoMismatch(_)
                | Effect::ReversalSpike(_)
                | Effect::Backlash(_)
                | Effect::BacklashEnds(_)
        )
    }

    /// Add this effect's δ (mm) for parameters `theta` to `q[j]` and its direct change of D (mm)
    /// to `dd[j]` for samples i0 + j, j < q.len(). Effect by effect over a block of samples,
    /// because the exact fit evaluates every effect on every sample on every pass.
    pub fn add_delta_block(
        &self,
        path: &Path,
        i0: usize,
        theta: &[f64],
        q: &mut [[f64; 3]],
        dd: &mut [f64],
    ) {
        let n = q.len();
        let p = &path.p_mm[i0..i0 + n];
        let v = &path.v_mm_s[i0..i0 + n];
        let dd = &mut dd[..n];
        match *self {
            Effect::SetupOffset => {
                // The table ball moved by c: the spindle ball is at p + δ − c from it.
                let c = [1e-3 * theta[0], 1e-3 * theta[1], 1e-3 * theta[2]];
                for qj in q.iter_mut() {
                    for k in 0..3 {
                        qj[k] -= c[k];
                    }
                }
            }
            Effect::LengthOffset => {
                let e = 1e-3 * theta[0];
                for x in dd.iter_mut() {
                    *x += e;
                }
            }
            Effect::Drift => {
                let (t0, r) = (path.t0_s, 1e-3 * theta[0] / 60.0);
                for (x, t) in dd.iter_mut().zip(&path.t_s[i0..i0 + n]) {
                    *x += r * (t - t0);
                }
            }
            Effect::FollowingError => {
                // q in ms², a in mm/s²: δ = q·a·1e-6 mm.
                let q_s2 = 1e-6 * theta[0];
                for (qj, aj) in q.iter_mut().zip(&path.a_mm_s2[i0..i0 + n]) {
                    for k in 0..3 {
                        qj[k] += q_s2 * aj[k];
                    }
                }
            }
            Effect::Scale(a) => {
                let (k, s) = (a.index(), 1e-6 * theta[0]);
                for (qj, pj) in q.iter_mut().zip(p) {
                    qj[k] += s * pj[k];
                }
            }
            Effect::ScaleDrift(a) | Effect::PositionDrift(a) => {
                let k = a.index();
                let scale = matches!(self, Effect::ScaleDrift(_));
                for (j, qj) in q.iter_mut().enumerate() {
                    let minutes = elapsed_min(path, i0 + j);
                    qj[k] += if scale {
                        1e-6 * theta[0] * minutes * p[j][k]
                    } else {
                        1e-3 * theta[0] * minutes
                    };
                }
            }
            Effect::ScaleMismatch(pair) => {
                let (a, b) = pair.axes();
                let (a, b) = (a.index(), b.index());
                let s = 0.5e-6 * theta[0];
                for (qj, pj) in q.iter_mut().zip(p) {
                    qj[a] += s * pj[a];
                    qj[b] -= s * pj[b];
                }
            }
            Effect::Scale2(a) => {
                let (k, s) = (a.index(), 1e-9 * theta[0]);
                for (qj, pj) in q.iter_mut().zip(p) {
                    qj[k] += s * pj[k] * pj[k];
                }
            }
            Effect::Backlash(a) => {
                let k = a.index();
                for_each_dead_band(path, k, i0, n, theta[0], theta[0], |j, d_um, _, _| {
                    q[j][k] += 1e-3 * d_um;
                });
            }
            Effect::BacklashEnds(a) => {
                let k = a.index();
                for_each_dead_band(path, k, i0, n, theta[0], theta[1], |j, d_um, _, _| {
                    q[j][k] += 1e-3 * d_um;
                });
            }
            Effect::Straightness(a, b) => {
                let (i, j) = (a.index(), b.index());
                let w = 1e-3 * theta[0];
                let ends = travel_ends_mm(path, i);
                for (qk, pk) in q.iter_mut().zip(p) {
                    qk[j] += w * bow_shape(ends, pk[i]);
                }
            }
            Effect::LateralPlay(a, b) => {
                let (i, j) = (a.index(), b.index());
                let half = 0.5e-3 * theta[0];
                for (qk, dk) in q.iter_mut().zip(&path.dir[i0..i0 + n]) {
                    qk[j] += half * f64::from(dk[i]);
                }
            }
            Effect::Cyclic(a) => {
                let k = a.index();
                let phase = &path.phase[i0..i0 + n];
                for (qj, ph) in q.iter_mut().zip(phase) {
                    let (s, c) = ph[k];
                    qj[k] += 1e-3 * (theta[0] * s + theta[1] * c);
                }
            }
            Effect::Interference(a) => {
                let k = a.index();
                let phase = &path.phase[i0..i0 + n];
                for ((qj, ph), vj) in q.iter_mut().zip(phase).zip(v) {
                    let (s, c) = ph[k];
                    qj[k] += 1e-3 * vj[k] * (theta[0] * s + theta[1] * c);
                }
            }
            Effect::Squareness(pair) => {
                let (a, b) = pair.axes();
                let (a, b) = (a.index(), b.index());
                let s = 1e-6 * theta[0];
                for (qj, pj) in q.iter_mut().zip(p) {
                    qj[a] += s * pj[b];
                }
            }
            Effect::ServoMismatch(pair) => {
                let (a, b) = pair.axes();
                let acc = &path.a_mm_s2[i0..i0 + n];
                // Per-axis delays in s.
                let ta = 1e-3 * (theta[1] + 0.5 * theta[0]);
                let tb = 1e-3 * (theta[1] - 0.5 * theta[0]);
                for ((qj, vj), aj) in q.iter_mut().zip(v).zip(acc) {
                    for (k, t) in [(a.index(), ta), (b.index(), tb)] {
                        qj[k] += -t * vj[k] + 0.5 * t * t * aj[k];
                    }
                }
            }
            Effect::ReversalSpike(a) => {
                let k = a.index();
                let (h, tau) = (1e-3 * theta[0], theta[1].max(MIN_TAU_MS));
                for_each_spike(path, k, i0, n, |j, s, dt_ms| {
                    q[j][k] -= h * s * decay(dt_ms / tau);
                });
            }
        }
    }

    /// The exact gradient: for samples i0 + j, the change of D (µm) per unit of each parameter
    /// at `theta`, given u = the unit vector of the displaced position, written to
    /// `out[j·stride + offset + k]`. For an effect linear in its parameters this does not depend
    /// on `theta` and equals its [`Candidate::columns_block`].
    #[allow(clippy::too_many_arguments)]
    pub fn gradient_block(
        &self,
        path: &Path,
        i0: usize,
        theta: &[f64],
        u: &[[f64; 3]],
        out: &mut [f64],
        stride: usize,
        offset: usize,
    ) {
        let n = u.len();
        let rows = (0..n).map(|j| j * stride + offset);
        match *self {
            Effect::ServoMismatch(pair) => {
                let (a, b) = pair.axes();
                let (a, b) = (a.index(), b.index());
                let v = &path.v_mm_s[i0..i0 + n];
                let acc = &path.a_mm_s2[i0..i0 + n];
                let ta = 1e-3 * (theta[1] + 0.5 * theta[0]);
                let tb = 1e-3 * (theta[1] - 0.5 * theta[0]);
                for (j, o) in rows.enumerate() {
                    // dδ_k/dτ_k (mm per s) → µm of D per ms: ×1e3 (mm→µm) ×1e-3 (ms→s).
                    let ga = u[j][a] * (-v[j][a] + ta * acc[j][a]);
                    let gb = u[j][b] * (-v[j][b] + tb * acc[j][b]);
                    out[o] = 0.5 * (ga - gb);
                    out[o + 1] = ga + gb;
                }
            }
            Effect::ReversalSpike(ax) => {
                let k = ax.index();
                let (h, tau) = (theta[0], theta[1].max(MIN_TAU_MS));
                for o in rows.clone() {
                    out[o] = 0.0;
                    out[o + 1] = 0.0;
                }
                for_each_spike(path, k, i0, n, |j, s, dt_ms| {
                    let e = decay(dt_ms / tau);
                    let o = j * stride + offset;
                    out[o] = -u[j][k] * s * e;
                    out[o + 1] = -u[j][k] * h * s * e * dt_ms / (tau * tau);
                });
            }
            Effect::Backlash(ax) | Effect::BacklashEnds(ax) => {
                let k = ax.index();
                let ends = matches!(self, Effect::BacklashEnds(_));
                let (pos, neg) = if ends {
                    (theta[0], theta[1])
                } else {
                    (theta[0], theta[0])
                };
                for_each_dead_band(path, k, i0, n, pos, neg, |j, _, dpos, dneg| {
                    let o = j * stride + offset;
                    if ends {
                        out[o] = u[j][k] * dpos;
                        out[o + 1] = u[j][k] * dneg;
                    } else {
                        out[o] = u[j][k] * (dpos + dneg);
                    }
                });
            }
            _ => Candidate::of(*self).columns_block(path, i0, u, out, stride, offset),
        }
    }

    /// The effect's reported value and its standard error from its parameters and their
    /// covariance block (value = |c| for setup_offset, the amplitude for periodic effects, the
    /// first parameter otherwise; the delta method propagates the covariance).
    pub fn value(&self, params: &[f64], cov: &[Vec<f64>]) -> (f64, Option<f64>) {
        let norm = |ps: &[f64]| ps.iter().map(|x| x * x).sum::<f64>().sqrt();
        match self {
            Effect::SetupOffset | Effect::Cyclic(_) | Effect::Interference(_) => {
                let v = norm(params);
                if v == 0.0 {
                    return (0.0, None);
                }
                let g: Vec<f64> = params.iter().map(|x| x / v).collect();
                let mut var = 0.0;
                for i in 0..g.len() {
                    for j in 0..g.len() {
                        var += g[i] * g[j] * cov[i][j];
                    }
                }
                (v, var.is_finite().then(|| var.max(0.0).sqrt()))
            }
            Effect::BacklashEnds(_) => {
                let var = 0.25 * (cov[0][0] + cov[1][1] + 2.0 * cov[0][1]);
                (
                    0.5 * (params[0] + params[1]),
                    var.is_finite().then(|| var.max(0.0).sqrt()),
                )
            }
            _ => (params[0], Some(cov[0][0].max(0.0).sqrt())),
        }
    }

    /// Parameters from a value and an optional phase (rad), for simulation: periodic effects
    /// A·sin(w + φ) = A cos φ · sin w + A sin φ · cos w; a servo mismatch with no common lag;
    /// None for an effect that needs all its parameters (a spike's h and τ).
    pub fn params_from_value(&self, value: f64, phase_rad: f64) -> Option<Vec<f64>> {
        match self {
            Effect::Cyclic(_) | Effect::Interference(_) => {
                Some(vec![value * phase_rad.cos(), value * phase_rad.sin()])
            }
            Effect::ServoMismatch(_) => Some(vec![value, 0.0]),
            Effect::ReversalSpike(_) | Effect::SetupOffset | Effect::BacklashEnds(_) => None,
            _ => Some(vec![value; self.n_params()]),
        }
    }
}

/// Minutes from the path's first sample to sample i: the time of a drift in time.
fn elapsed_min(path: &Path, i: usize) -> f64 {
    (path.t_s[i] - path.t0_s) / 60.0
}

/// Beyond this many decay times a spike is taken as gone: e^(−37) ≈ 8.5·10⁻¹⁷ is under half an
/// ulp of 1.0, below the last bit of the spike's height.
const DECAY_CUTOFF: f64 = 37.0;

/// e^(−x) for x ≥ 0, exactly 0 beyond x = [`DECAY_CUTOFF`]: a spike's decay after its reversal.
/// A spike column then costs an `exp` only over its first 37 τ after each reversal, not over the
/// whole circle (that was 3 % of a diagnosis of 20 000 samples), and libm's slow underflow path
/// is never taken.
fn decay(x: f64) -> f64 {
    if x < DECAY_CUTOFF {
        (-x).exp()
    } else {
        0.0
    }
}

/// The ends of axis k's travel that the bow and the lost motion per end refer to (mm, relative
/// to the table ball): ±h with h the farthest the path goes from the table ball along k, the
/// points where a whole circle about the ball reverses k. On a full circle they are the path's
/// lowest and highest positions. On a partial arc they are not where the data end: a 220° arc
/// in yz records z from 0 to R only, and a bow or a gap referred to the data's own travel (mid
/// R/2) would differ from a full circle's by a linear part, i.e. a squareness, or by an arc
/// end's reversal outside the data (z = R·sin(−20°)) held at the end's gap. Referred to ±h, a
/// bow of k is the same data as the other axis's second-order scale on every arc of the circle
/// (k² = R² − j², the constant a set-up offset), as on a full circle, and the gaps are the ones
/// at the reversals of a full circle about the same ball (docs/mechanisms.md).
pub(crate) fn travel_ends_mm(path: &Path, k: usize) -> (f64, f64) {
    let h = path.lo_mm[k].abs().max(path.hi_mm[k].abs());
    if path.range_mm[k] > 0.0 {
        (-h, h)
    } else {
        (0.0, 0.0)
    }
}

/// The shape of a bow (see [`Effect::Straightness`]) at the bowed axis's position `x_mm`:
/// 1 − 4·((x − mid)/L)² over its travel between its ends `(lo, hi)` ([`travel_ends_mm`]); 0 for
/// an axis that does not move.
fn bow_shape((lo, hi): (f64, f64), x_mm: f64) -> f64 {
    let len = hi - lo;
    if len <= 0.0 {
        return 0.0;
    }
    let z = (x_mm - 0.5 * (hi + lo)) / len;
    1.0 - 4.0 * z * z
}

/// A dead band (play operator) between motor and carriage of axis k, evaluated from the nominal
/// (motor) position: for each sample i0 + j, `f(j, δ_um, ∂δ/∂pos, ∂δ/∂neg)` with the gap g(x)
/// growing linearly from `neg_um` at the low end of k's travel ([`travel_ends_mm`]) to `pos_um`
/// at the high end (equal for a uniform backlash). With s the direction since the last reversal
/// (at x_r, gap g_r there) and u = s·(x − x_r) ≥ 0 the motor's travel since: the carriage stood
/// where the old direction left it, x_r + s·g_r/2, until the motor took the gap up, so
/// δ = −s·g(x)/2 + s·max(0, g_r − u) for g_r > 0; a negative gap is a step (over-compensation).
/// Before the first reversal the held direction of the path is used, the gap taken up.
pub(crate) fn for_each_dead_band(
    path: &Path,
    k: usize,
    i0: usize,
    n: usize,
    pos_um: f64,
    neg_um: f64,
    mut f: impl FnMut(usize, f64, f64, f64),
) {
    let (lo, hi) = travel_ends_mm(path, k);
    let weight_pos = |x: f64| {
        if hi > lo {
            ((x - lo) / (hi - lo)).clamp(0.0, 1.0)
        } else {
            0.5
        }
    };
    for_each_last_reversal(path, k, i0, n, |j, last| {
        let x = path.p_mm[i0 + j][k];
        let wp = weight_pos(x);
        let gap = pos_um * wp + neg_um * (1.0 - wp);
        let (s, taken) = match last {
            Some(r) => {
                let s = f64::from(r.new_dir);
                let wr = weight_pos(r.p_mm);
                let gap_r = pos_um * wr + neg_um * (1.0 - wr);
                let travel_um = (1e3 * s * (x - r.p_mm)).max(0.0);
                (s, (gap_r > travel_um).then_some((gap_r - travel_um, wr)))
            }
            None => (f64::from(path.dir[i0 + j][k]), None),
        };
        let mut d = -0.5 * s * gap;
        let mut dpos = -0.5 * s * wp;
        let mut dneg = -0.5 * s * (1.0 - wp);
        if let Some((left, wr)) = taken {
            d += s * left;
            dpos += s * wr;
            dneg += s * (1.0 - wr);
        }
        f(j, d, dpos, dneg);
    });
}

/// Call `f(j, s, Δt_ms)` for each sample i0 + j (j < n) after a reversal of axis k: s the new
/// direction, Δt the time since the reversal (ms). Samples before the first reversal are skipped.
fn for_each_spike(path: &Path, k: usize, i0: usize, n: usize, mut f: impl FnMut(usize, f64, f64)) {
    if path.reversals[k].is_empty() {
        return;
    }
    for_each_last_reversal(path, k, i0, n, |j, last| {
        if let Some(r) = last {
            f(j, f64::from(r.new_dir), 1e3 * (path.t_s[i0 + j] - r.t_s));
        }
    });
}

/// Call `f(j, last)` for each sample i0 + j (j < n) with the last reversal of axis k at or
/// before it (None before the first): one walk through the reversals for a block of samples.
fn for_each_last_reversal(
    path: &Path,
    k: usize,
    i0: usize,
    n: usize,
    mut f: impl FnMut(usize, Option<crate::model::path::Reversal>),
) {
    let revs = &path.reversals[k];
    let t = &path.t_s[i0..i0 + n];
    // Index of the first reversal after t[0]; the one before it is in force.
    let mut next = revs.partition_point(|r| r.t_s <= t[0]);
    for (j, &tj) in t.iter().enumerate() {
        while next < revs.len() && revs[next].t_s <= tj {
            next += 1;
        }
        f(j, next.checked_sub(1).map(|i| revs[i]));
    }
}

#[cfg(test)]
mod tests;
