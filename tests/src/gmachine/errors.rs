//! Machine errors: where the spindle ball and the table ball really are, given the commanded
//! trajectory. The models and their signs are the contract written in the [module docs](super);
//! every parameter zero is a perfect machine.

use super::dynamics::{DynOffsets, Dynamics, SpindleGrowth, ThermalGrowth};
use super::planner::Trajectory;

/// A machine axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Axis {
    /// x.
    X,
    /// y.
    Y,
    /// z.
    Z,
}

impl Axis {
    /// 0, 1, 2.
    pub fn index(self) -> usize {
        self as usize
    }
}

/// Periodic (pitch) error of one axis: δ = A·sin(2π·p/P + φ).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Cyclic {
    /// Amplitude A (µm).
    pub amplitude_um: f64,
    /// Pitch P (mm); 0 = none.
    pub pitch_mm: f64,
    /// Phase φ (rad).
    pub phase_rad: f64,
}

/// Second-order scale of one axis: the screw's pitch is not constant but grows (or shrinks)
/// linearly along the travel — a screw ground with a tapered lead, or warmed more at one end —
/// so the lead error accumulated from the point `origin_mm`, where the lead is right, grows with
/// the square of the distance: δ = b·(p − origin)², b in µm/m².
///
/// Sign: b > 0 means the lead is too long beyond `origin_mm` in + and too short below it, so the
/// carriage ends up displaced towards **+** on both sides of the origin (it overshoots going up
/// and falls short coming down from the origin). `origin_mm` is in program coordinates; a
/// second-order error about another origin than the table ball also carries a first-order part
/// 2·b·(ball − origin) (a scale) and a constant (a shift of the circle's centre): the physics,
/// not a convention.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Scale2 {
    /// b (µm per m²); 0 = none.
    pub um_per_m2: f64,
    /// Where the lead is right (mm, program coordinates).
    pub origin_mm: f64,
}

/// Interference of the detection device of one axis (seed 000 §3.3), written as the mechanism:
/// the read head of the axis' scale (or encoder) reports the position *late* by a latency that
/// varies over each signal period P of the scale — an interpolator whose two quadrature
/// channels are filtered unequally settles at a different delay at each point of the period:
/// τ(p) = τ_c·sin(2π·p/P + φ), p the axis' position from the program origin.
///
/// The servo holds the *reading* on the command: reading(t) = actual(t − τ) = command(t), so the
/// carriage runs **ahead** of its command by what the reading lags, actual(t) = command(t + τ),
/// i.e. δ ≈ +v·τ(p): an error at the signal period whose amplitude grows with the speed and
/// which changes sign with the direction of motion. In µm per mm/s the amplitude is τ_c in ms.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Interference {
    /// τ_c (ms): the latency's amplitude; 0 = none.
    pub latency_ms: f64,
    /// The signal period P (mm); 0 = none.
    pub pitch_mm: f64,
    /// Phase φ (rad) at the program origin.
    pub phase_rad: f64,
}

/// Stick at reversal of one axis: the axis lags its command by h right after it reverses and
/// catches up with time constant τ.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ReversalSpike {
    /// Height h (µm).
    pub height_um: f64,
    /// Decay time constant τ (ms); 0 = none.
    pub tau_ms: f64,
}

/// Out-of-squareness: axis `axis` is displaced in proportion to the position of axis `by`
/// relative to the table ball: δ_axis = s·(p_by − ball_by).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Squareness {
    /// The axis displaced (i).
    pub axis: Axis,
    /// The axis whose position causes it (j ≠ i).
    pub by: Axis,
    /// s (µm per m).
    pub um_per_m: f64,
}

/// A clearance (play) that varies along the axis: linear from `neg_um` at `neg_end_mm` to
/// `pos_um` at `pos_end_mm` (program coordinates), constant beyond the two.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BacklashEnds {
    /// Position of the negative end (mm).
    pub neg_end_mm: f64,
    /// Clearance there (µm).
    pub neg_um: f64,
    /// Position of the positive end (mm).
    pub pos_end_mm: f64,
    /// Clearance there (µm).
    pub pos_um: f64,
}

/// A bowed axis: moving along `axis`, axis `toward` is displaced by κ·(p_axis − vertex)².
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bow {
    /// The axis that is not straight (i).
    pub axis: Axis,
    /// The direction it bows in (j ≠ i).
    pub toward: Axis,
    /// Where on i the bow's vertex is (mm, program coordinates).
    pub vertex_mm: f64,
    /// κ (µm per m²).
    pub um_per_m2: f64,
}

/// Lateral play: the carriage of `axis` sits in a guideway with a clearance across it; the
/// friction along `axis` turns it to one side, so it shifts by ±l/2 in `toward` with the
/// direction of `axis` (+l/2 while `axis` moves in +).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LateralPlay {
    /// The axis whose guideway has the clearance (i).
    pub axis: Axis,
    /// The direction the carriage shifts in (j ≠ i).
    pub toward: Axis,
    /// l (µm): the whole shift between the two directions.
    pub um: f64,
}

/// All machine errors; [`Default`] is a perfect machine.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MachineErrors {
    /// Set-up offset c (µm): the table ball sits at the nominal position + c.
    pub setup_offset_um: [f64; 3],
    /// Length offset e (µm) added to D (the instrument's length calibration error).
    pub length_offset_um: f64,
    /// Backlash per axis (µm): the clearance between motor and carriage (play); see the module
    /// docs. Negative: over-compensated (a step ahead).
    pub backlash_um: [f64; 3],
    /// A clearance that differs along the axis; replaces `backlash_um` of that axis when set.
    pub backlash_ends: [Option<BacklashEnds>; 3],
    /// Bowed axes.
    pub bows: Vec<Bow>,
    /// Guideway clearances across the travel.
    pub lateral_play: Vec<LateralPlay>,
    /// Scale error a per axis (µm/m): δ = a·p (p from the program origin).
    pub scale_um_per_m: [f64; 3],
    /// Squareness terms.
    pub squareness: Vec<Squareness>,
    /// Periodic errors per axis.
    pub cyclic: [Cyclic; 3],
    /// Servo delay τ per axis (ms): the axis is where its command was τ earlier.
    pub servo_delay_ms: [f64; 3],
    /// Reversal spikes per axis.
    pub reversal_spike: [ReversalSpike; 3],
    /// Drift of D (µm/min) from cycle start on (warm-up).
    pub drift_um_per_min: f64,
    /// Second-order scale (a lead that changes along the screw) per axis.
    pub scale2: [Scale2; 3],
    /// Interference of each axis' detection device (a reading latency that varies over the
    /// scale's signal period).
    pub interference: [Interference; 3],
    /// Position loops, friction inside them and structural modes ([`super::dynamics`]):
    /// integrated in time along the recording.
    pub dynamics: Dynamics,
    /// Axes whose scale grows in time (heat).
    pub thermal: Vec<ThermalGrowth>,
    /// The spindle growing towards the table (heat).
    pub spindle_growth: SpindleGrowth,
}

impl MachineErrors {
    /// Check the parameters are usable (finite, pitches and time constants non-negative, no
    /// squareness of an axis with itself).
    pub fn validate(&self) -> Result<(), String> {
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let mut all = vec![self.length_offset_um, self.drift_um_per_min];
        all.extend(self.setup_offset_um);
        all.extend(self.backlash_um);
        all.extend(self.scale_um_per_m);
        all.extend(self.servo_delay_ms);
        for c in &self.cyclic {
            all.extend([c.amplitude_um, c.pitch_mm, c.phase_rad]);
        }
        for s in &self.reversal_spike {
            all.extend([s.height_um, s.tau_ms]);
        }
        for s in &self.scale2 {
            all.extend([s.um_per_m2, s.origin_mm]);
        }
        for i in &self.interference {
            all.extend([i.latency_ms, i.pitch_mm, i.phase_rad]);
        }
        for s in &self.squareness {
            all.push(s.um_per_m);
        }
        for e in self.backlash_ends.iter().flatten() {
            all.extend([e.neg_end_mm, e.neg_um, e.pos_end_mm, e.pos_um]);
        }
        for b in &self.bows {
            all.extend([b.vertex_mm, b.um_per_m2]);
        }
        for l in &self.lateral_play {
            all.push(l.um);
        }
        if self.lateral_play.iter().any(|l| l.axis == l.toward) {
            return Err("lateral play shifts another axis than its own".into());
        }
        if self
            .backlash_ends
            .iter()
            .flatten()
            .any(|e| e.pos_end_mm <= e.neg_end_mm)
        {
            return Err("backlash_ends: pos_end_mm must lie above neg_end_mm".into());
        }
        if self.bows.iter().any(|b| b.axis == b.toward) {
            return Err("a bow displaces another axis than its own".into());
        }
        if !finite(&all) {
            return Err("machine errors must be finite numbers".into());
        }
        if self.cyclic.iter().any(|c| c.pitch_mm < 0.0) {
            return Err("cyclic pitch_mm must be ≥ 0 (0 = no cyclic error)".into());
        }
        if self.interference.iter().any(|i| i.pitch_mm < 0.0) {
            return Err("interference pitch_mm must be ≥ 0 (0 = no interference)".into());
        }
        if self
            .interference
            .iter()
            .any(|i| i.pitch_mm > 0.0 && i.latency_ms.abs() > 10.0)
        {
            return Err("interference latency_ms must be within ±10 ms".into());
        }
        if self.reversal_spike.iter().any(|s| s.tau_ms < 0.0) {
            return Err("reversal spike tau_ms must be ≥ 0 (0 = no spike)".into());
        }
        if self.servo_delay_ms.iter().any(|d| *d < 0.0) {
            return Err("servo_delay_ms must be ≥ 0".into());
        }
        if self.squareness.iter().any(|s| s.axis == s.by) {
            return Err("squareness needs two different axes".into());
        }
        self.dynamics.validate()?;
        let heat = self
            .thermal
            .iter()
            .flat_map(|g| [g.um_per_m_per_min, g.fixed_bearing_mm, g.time_constant_min]);
        let spindle = [
            self.spindle_growth.um_per_min,
            self.spindle_growth.time_constant_min,
        ];
        if !heat.chain(spindle).all(f64::is_finite)
            || self.thermal.iter().any(|g| g.time_constant_min < 0.0)
            || self.spindle_growth.time_constant_min < 0.0
        {
            return Err("thermal growth: finite values, time constants ≥ 0".into());
        }
        Ok(())
    }

    /// The clearance (µm) of axis `k` at its position `p_mm`.
    fn clearance_um(&self, k: usize, p_mm: f64) -> f64 {
        match self.backlash_ends[k] {
            Some(e) => {
                let w = ((p_mm - e.neg_end_mm) / (e.pos_end_mm - e.neg_end_mm)).clamp(0.0, 1.0);
                e.neg_um + w * (e.pos_um - e.neg_um)
            }
            None => self.backlash_um[k],
        }
    }

    /// Where the carriage of axis `k` is (mm) when its motor is at `motor_mm` at program time `t`:
    /// the play operator over the motor's motion since its last reversal.
    fn carriage_mm(&self, k: usize, motor_mm: f64, traj: &Trajectory, t: f64) -> f64 {
        let half = 0.5e-3 * self.clearance_um(k, motor_mm);
        let (dir, last) = traj.direction_at(k, t);
        let s = if dir < 0 { -1.0 } else { 1.0 };
        if half <= 0.0 {
            // Over-compensated (or none): the controller's jump leaves the carriage ahead.
            return motor_mm - s * half;
        }
        // The flank that pushes: behind the motor in the direction of motion.
        let pushed = motor_mm - s * half;
        match last {
            None => pushed,
            Some(t_rev) => {
                // At the reversal the old direction's flank had left the carriage behind the
                // motor's turning point; it stays there until the other flank arrives.
                let turn_mm = traj.position_at(t_rev)[k];
                let left_at = turn_mm + s * 0.5e-3 * self.clearance_um(k, turn_mm);
                if s > 0.0 {
                    pushed.max(left_at.min(motor_mm + half))
                } else {
                    pushed.min(left_at.max(motor_mm - half))
                }
            }
        }
    }

    /// Error δ_k (µm) of axis `k` alone (scale, cyclic, backlash, reversal spike) at its own
    /// commanded coordinate `p_k` (mm), for the direction state of the axis at program time `t`.
    fn axis_error_um(&self, k: usize, p_k: f64, traj: &Trajectory, t: f64) -> f64 {
        let mut d = self.scale_um_per_m[k] * p_k * 1e-3;
        let q = &self.scale2[k];
        if q.um_per_m2 != 0.0 {
            let from_origin_m = (p_k - q.origin_mm) * 1e-3;
            d += q.um_per_m2 * from_origin_m * from_origin_m;
        }
        let c = &self.cyclic[k];
        if c.pitch_mm > 0.0 && c.amplitude_um != 0.0 {
            d += c.amplitude_um * (std::f64::consts::TAU * p_k / c.pitch_mm + c.phase_rad).sin();
        }
        if self.backlash_um[k] != 0.0 || self.backlash_ends[k].is_some() {
            d += 1e3 * (self.carriage_mm(k, p_k, traj, t) - p_k);
        }
        let sp = &self.reversal_spike[k];
        if sp.height_um != 0.0 && sp.tau_ms > 0.0 {
            let (dir, last) = traj.direction_at(k, t);
            let s = dir as f64;
            if let Some(t_rev) = last {
                if sp.tau_ms > 0.0 && sp.height_um != 0.0 {
                    d -= sp.height_um * s * (-(t - t_rev) * 1e3 / sp.tau_ms).exp();
                }
            }
        }
        d
    }

    /// The machine's state at program time `t`: commanded and actual spindle-ball position.
    /// `ball_mm` is the nominal table-ball position (for squareness).
    pub fn actual(&self, traj: &Trajectory, t: f64, ball_mm: [f64; 3]) -> Pose {
        self.actual_moving(traj, t, ball_mm, &DynOffsets::default())
    }

    /// [`Self::actual`] with what the machine's dynamics add at `t` (from a
    /// [`DynamicState`](super::dynamics::DynamicState)
    /// integrated along the same trajectory): each axis's carriage is its following error away
    /// from the (delayed) command, and its own errors are evaluated there; the structure's
    /// displacement and the thermal growth are added to δ.
    pub fn actual_moving(
        &self,
        traj: &Trajectory,
        t: f64,
        ball_mm: [f64; 3],
        dynamic: &DynOffsets,
    ) -> Pose {
        let command = traj.position_at(t);
        // Each axis lags by its own delay; its position-dependent errors go with it.
        let mut lagged = command;
        let mut t_axis = [t; 3];
        for k in 0..3 {
            if self.servo_delay_ms[k] != 0.0 {
                t_axis[k] = t - self.servo_delay_ms[k] * 1e-3;
                lagged[k] = traj.position_at(t_axis[k])[k];
            }
            // Interference: the reading lags by τ(p), so the axis is where its command will be
            // τ(p) later (τ < 0: earlier).
            let i = &self.interference[k];
            if i.pitch_mm > 0.0 && i.latency_ms != 0.0 {
                let w = std::f64::consts::TAU * lagged[k] / i.pitch_mm + i.phase_rad;
                t_axis[k] += i.latency_ms * 1e-3 * w.sin();
                lagged[k] = traj.position_at(t_axis[k])[k];
            }
        }
        for (l, f) in lagged.iter_mut().zip(dynamic.follow_mm) {
            *l += f;
        }
        let mut delta_um = dynamic.structure_um;
        let t_min = (t - traj.cycle_start_s) / 60.0;
        for k in 0..3 {
            delta_um[k] += self.axis_error_um(k, lagged[k], traj, t_axis[k]);
        }
        for g in &self.thermal {
            let k = g.axis.index();
            delta_um[k] += g.delta_um(lagged[k], t_min);
        }
        delta_um[2] += self.spindle_growth.delta_z_um(t_min);
        for s in &self.squareness {
            let (i, j) = (s.axis.index(), s.by.index());
            delta_um[i] += s.um_per_m * (lagged[j] - ball_mm[j]) * 1e-3;
        }
        for b in &self.bows {
            let x_m = (lagged[b.axis.index()] - b.vertex_mm) * 1e-3;
            delta_um[b.toward.index()] += b.um_per_m2 * x_m * x_m;
        }
        for l in &self.lateral_play {
            let i = l.axis.index();
            let (dir, _) = traj.direction_at(i, t_axis[i]);
            delta_um[l.toward.index()] += 0.5 * l.um * if dir < 0 { -1.0 } else { 1.0 };
        }
        Pose {
            command_mm: command,
            actual_mm: [0, 1, 2].map(|k| lagged[k] + delta_um[k] * 1e-3),
        }
    }

    /// Where the table ball really is (mm).
    pub fn table_ball_mm(&self, nominal_mm: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| nominal_mm[k] + self.setup_offset_um[k] * 1e-3)
    }

    /// True ball distance D (mm) for a spindle ball at `actual_mm`, at program time `t` with
    /// cycle start at `cycle_start_s` (drift runs from there).
    pub fn distance_mm(
        &self,
        actual_mm: [f64; 3],
        ball_nominal_mm: [f64; 3],
        t: f64,
        cycle_start_s: f64,
    ) -> f64 {
        let b = self.table_ball_mm(ball_nominal_mm);
        let d = [0, 1, 2].map(|k| actual_mm[k] - b[k]);
        let drift_um = self.drift_um_per_min * ((t - cycle_start_s).max(0.0) / 60.0);
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() + (self.length_offset_um + drift_um) * 1e-3
    }
}

/// Commanded and actual spindle-ball position at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Where the program puts it (mm).
    pub command_mm: [f64; 3],
    /// Where it is (mm): command (per-axis delayed) + δ.
    pub actual_mm: [f64; 3],
}

#[cfg(test)]
mod tests {
    use super::super::planner::{plan, MachineConfig};
    use super::super::program::{parse_program, Dialect, ProgramOptions};
    use super::*;

    fn traj(text: &str) -> Trajectory {
        let m = MachineConfig::default();
        let p = parse_program(text, ProgramOptions::new(Dialect::LinuxCnc), [0.0; 3]).unwrap();
        plan(&p, &m, 1.0).unwrap()
    }

    #[test]
    fn backlash_is_play_that_lags_the_motion_and_is_taken_up_after_a_reversal() {
        // +x, dwell, −x, dwell.
        let t = traj("G21 G90 G1 X10 F600\nG4 P1\nX5\nG4 P1\n");
        let e = MachineErrors {
            backlash_um: [8.0, 0.0, 0.0],
            ..Default::default()
        };
        let b = [0.0; 3];
        let mid_plus = 0.5 * t.segments[0].t_end_s();
        let dwell1 = t.segments[1].t_start_s + 0.5;
        let mid_minus = 0.5 * (t.segments[2].t_start_s + t.segments[2].t_end_s());
        let dwell2 = t.segments[3].t_start_s + 0.5;
        let dx = |tt: f64| {
            let p = e.actual(&t, tt, b);
            (p.actual_mm[0] - p.command_mm[0]) * 1e3
        };
        // The carriage trails the motor by half the 8 µm clearance in the direction of motion.
        assert!((dx(mid_plus) + 4.0).abs() < 1e-9);
        assert!((dx(dwell1) + 4.0).abs() < 1e-9, "holds through standstill");
        assert!((dx(mid_minus) - 4.0).abs() < 1e-9);
        assert!((dx(dwell2) - 4.0).abs() < 1e-9);
        // Right after the reversal at X10 the carriage stands still until the motor has
        // travelled the 8 µm clearance back: it stays at 10 − 0.004 mm.
        let t_rev = t.segments[2].t_start_s;
        for dt in [1e-4, 1e-3, 5e-3] {
            let p = e.actual(&t, t_rev + dt, b);
            let motor = p.command_mm[0];
            let travelled_um = (10.0 - motor) * 1e3;
            if travelled_um < 8.0 {
                assert!(
                    (p.actual_mm[0] - (10.0 - 0.004)).abs() < 1e-12,
                    "{dt}: {p:?}"
                );
            } else {
                assert!(
                    (p.actual_mm[0] - (motor + 0.004)).abs() < 1e-12,
                    "{dt}: {p:?}"
                );
            }
        }
        // y did not move: its clearance stays closed in its initial direction (+): −b/2.
        let e = MachineErrors {
            backlash_um: [0.0, 6.0, 0.0],
            ..Default::default()
        };
        let p = e.actual(&t, dwell2, b);
        assert!(((p.actual_mm[1] - p.command_mm[1]) * 1e3 + 3.0).abs() < 1e-9);
    }

    #[test]
    fn scale_cyclic_and_squareness_values() {
        let t = traj("G21 G90 G0 X100 Y-50 Z20\n");
        let e = MachineErrors {
            scale_um_per_m: [10.0, 0.0, 0.0],
            cyclic: [
                Cyclic::default(),
                Cyclic {
                    amplitude_um: 2.0,
                    pitch_mm: 20.0,
                    phase_rad: 0.5,
                },
                Cyclic::default(),
            ],
            squareness: vec![Squareness {
                axis: Axis::Z,
                by: Axis::X,
                um_per_m: 30.0,
            }],
            ..Default::default()
        };
        let ball = [40.0, 0.0, 0.0];
        let p = e.actual(&t, t.end_s + 1.0, ball);
        let d = [0, 1, 2].map(|k| (p.actual_mm[k] - p.command_mm[k]) * 1e3);
        assert!((d[0] - 1.0).abs() < 1e-9, "scale: 10 µm/m · 0.1 m");
        let cyc = 2.0 * (std::f64::consts::TAU * -50.0 / 20.0 + 0.5).sin();
        assert!((d[1] - cyc).abs() < 1e-9);
        assert!(
            (d[2] - 30.0 * 60.0e-3).abs() < 1e-9,
            "squareness from the ball's x"
        );
    }

    #[test]
    fn servo_delay_is_a_true_delay() {
        let t = traj("G21 G90 G1 X100 F600\n");
        let e = MachineErrors {
            servo_delay_ms: [20.0, 0.0, 0.0],
            ..Default::default()
        };
        for tt in [0.01, 0.5, 3.0, 10.0, 10.05] {
            let p = e.actual(&t, tt, [0.0; 3]);
            assert_eq!(p.actual_mm[0], t.position_at(tt - 0.02)[0]);
        }
    }

    #[test]
    fn reversal_spike_decays() {
        let t = traj("G21 G90 G1 X10 F600\nX0\n");
        let e = MachineErrors {
            reversal_spike: [
                ReversalSpike {
                    height_um: 5.0,
                    tau_ms: 30.0,
                },
                ReversalSpike::default(),
                ReversalSpike::default(),
            ],
            ..Default::default()
        };
        let t_rev = t.segments[1].t_start_s;
        assert_eq!(t.events[0].last().map(|e| e.t_s), Some(t_rev));
        for dt_ms in [0.0, 10.0, 30.0, 90.0] {
            let p = e.actual(&t, t_rev + dt_ms * 1e-3, [0.0; 3]);
            let d = (p.actual_mm[0] - p.command_mm[0]) * 1e3;
            // New direction −x: δ = −h·(−1)·e^{−Δt/τ} = +h·e^{−Δt/τ}.
            let expect = 5.0 * (-dt_ms / 30.0).exp();
            assert!((d - expect).abs() < 1e-9, "{dt_ms} ms: {d} vs {expect}");
        }
        // Before the reversal: the move from the initial + state to +x is no reversal.
        let p = e.actual(&t, 0.5 * t_rev, [0.0; 3]);
        assert_eq!(p.actual_mm[0], p.command_mm[0]);
    }
    #[test]
    fn scale2_is_quadratic_about_its_origin_and_positive_on_both_sides() {
        let e = MachineErrors {
            scale2: [
                Scale2 {
                    um_per_m2: 800.0,
                    origin_mm: 100.0,
                },
                Scale2::default(),
                Scale2::default(),
            ],
            ..Default::default()
        };
        for (x, expect_um) in [(100.0, 0.0), (150.0, 2.0), (50.0, 2.0), (0.0, 8.0)] {
            let t = traj(&format!("G21 G90 G0 X{x}\n"));
            let p = e.actual(&t, t.end_s + 1.0, [0.0; 3]);
            let d = (p.actual_mm[0] - p.command_mm[0]) * 1e3;
            assert!((d - expect_um).abs() < 1e-9, "x {x}: {d} µm vs {expect_um}");
        }
    }

    #[test]
    fn interference_runs_the_axis_ahead_by_speed_times_the_reading_latency() {
        // +x at 600 mm/min = 10 mm/s, then back at the same feed.
        let t = traj("G21 G90 G1 X40 F600\nX0\n");
        let i = Interference {
            latency_ms: 0.2,
            pitch_mm: 4.0,
            phase_rad: 0.3,
        };
        let e = MachineErrors {
            interference: [i, Interference::default(), Interference::default()],
            ..Default::default()
        };
        let check = |tt: f64, v_mm_s: f64| {
            let p = e.actual(&t, tt, [0.0; 3]);
            let x = p.command_mm[0];
            let tau_s = 0.2e-3 * (std::f64::consts::TAU * x / 4.0 + 0.3).sin();
            let d_um = (p.actual_mm[0] - x) * 1e3;
            // δ = +v·τ(p) (to first order in τ at constant speed).
            let expect = 1e3 * v_mm_s * tau_s;
            assert!((d_um - expect).abs() < 1e-3, "t {tt}: {d_um} vs {expect}");
            d_um
        };
        let mid_up = 0.5 * t.segments[0].t_end_s();
        let mid_down = 0.5 * (t.segments[1].t_start_s + t.segments[1].t_end_s());
        let a = check(mid_up, 10.0);
        let b = check(mid_down, -10.0);
        assert!(a.abs() > 0.2 && b.abs() > 0.2, "{a} {b}");
        // Standing still: no error.
        let p = e.actual(&t, t.end_s + 1.0, [0.0; 3]);
        assert_eq!(p.actual_mm[0], p.command_mm[0]);
    }
}
