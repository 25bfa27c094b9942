//! How a machine moves like a machine: per-axis position loops, friction inside those loops,
//! structural modes, thermal growth in time, and the coloured noise of a real trace. Written from
//! the physics (`docs/mechanisms.md`, "Machine dynamics"), apart from the host's fit: nothing here
//! knows what the diagnosis models.
//!
//! # The position loop ([`ServoLoop`])
//! Per axis, a cascade as a CNC drive runs it, integrated in time on a fixed grid
//! ([`DynamicState`]):
//!
//! ```text
//!   p(t) ─▶ e = p − x̂ ─▶ Kv·e + k_v·ṗ = v_c ─▶ PI(v_c − v) + k_a·p̈ = u ─▶ plant: v̇ = u − friction
//!               ▲                                                          │
//!               └──── x̂ = x held on whole encoder counts ◀──── ẋ = v ◀────┘
//! ```
//!
//! - position loop: proportional, gain Kv (s⁻¹), velocity feed-forward k_v (0..1);
//! - velocity loop: PI on the axis's inertia, Kp = 2ζω_v, Ki = ω_v² (ω_v = 2π × the velocity-loop
//!   bandwidth, ζ = 0.7), so that without friction the velocity follows v_c as
//!   V(s) = (Kp·s + Ki)/(s² + Kp·s + Ki); acceleration (torque) feed-forward k_a (0..1);
//! - u is the drive's force per moved mass (mm/s²); the plant integrates v̇ = u − F(v)/m;
//! - the feedback x̂ is the position rounded to whole encoder counts (`count_um`, 0: continuous):
//!   at rest the axis hunts within a count, as a real axis does.
//!
//! Without friction the axis follows its command through
//! H(s) = (V·Kv + V·k_v·s + W·k_a·s²) / (s + V·Kv), W(s) = s/(s² + Kp·s + Ki),
//! so a circle of radius R at speed v (ω = v/R) is drawn with amplitude |H(jω)|: without
//! feed-forward and a fast velocity loop ≈ 1 − (ω/Kv)²/2, i.e. the circle shrinks by
//! v²/(2R·Kv²) and each axis lags by 1/Kv. With k_v = k_a = 1, H = 1.
//!
//! # Friction ([`Friction`])
//! Coulomb + Stribeck + viscous, as an acceleration (force per moved mass):
//! F(v) = sign(v)·(F_c + (F_s − F_c)·exp(−(v/v_s)²)) + c·v. At v = 0 the axis sticks while
//! |u| ≤ F_s (Karnopp); when its velocity would change sign within a step it stops there. Inside
//! the loop this is stick-slip at a reversal: the axis stops, the position error and the velocity
//! loop's integrator grow until u passes F_s, then it breaks free (the friction falls to F_c) and
//! catches up, often overshooting. F_s and F_c may differ at the two ends of the travel
//! ([`Friction::pos_end_factor`]).
//!
//! # Structural modes ([`StructuralMode`])
//! A lightly damped mode between spindle and table along one axis, driven by the drive force u of
//! one axis: ÿ + 2ζω·ẏ + ω²·y = −ω²·c·u, so a steady force u deflects it by −c·u (c: compliance,
//! µm per m/s²) and a sudden change of u (a friction reversal) makes it ring at ω. A mode driven
//! by an axis without a loop is driven by that axis's commanded acceleration.
//!
//! # Heat ([`ThermalGrowth`], [`SpindleGrowth`])
//! From cycle start on, an axis's scale grows in time about its fixed bearing:
//! δ_k = g(t)·(p_k − bearing) with g(t) = rate·t (or rate·τ·(1 − e^(−t/τ)) with a thermal time
//! constant τ), and the spindle grows along Z towards the table: δ_z = −growth(t).
//!
//! # Coloured noise ([`ColouredNoise`])
//! Added to D on top of the white noise, from its own random stream (a seed's white noise and lean
//! do not change when it is switched on): an AR(1) process defined in time
//! (ρ = exp(−Δt/τ) per sample), a 1/f-like wander (three AR(1) of τ 0.1, 1 and 10 s of equal
//! variance), and narrow-band vibration (a complex AR(1) rotating at the vibration's frequency,
//! decaying at π × its bandwidth).

use super::errors::Axis;
use super::planner::Trajectory;

/// One axis's position loop (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoLoop {
    /// Position-loop gain Kv (s⁻¹); typical machining centres 30–60.
    pub kv_per_s: f64,
    /// Velocity-loop bandwidth (Hz); typical 50–200.
    pub velocity_bandwidth_hz: f64,
    /// Velocity feed-forward k_v (0..1).
    pub ff_velocity: f64,
    /// Acceleration (torque) feed-forward k_a (0..1).
    pub ff_acceleration: f64,
    /// Encoder count (µm) the loop holds the axis on; 0: continuous feedback.
    pub count_um: f64,
}

impl ServoLoop {
    /// A loop of gain `kv_per_s` with a 100 Hz velocity loop, no feed-forward, 0.1 µm counts.
    pub fn new(kv_per_s: f64) -> Self {
        ServoLoop {
            kv_per_s,
            velocity_bandwidth_hz: 100.0,
            ff_velocity: 0.0,
            ff_acceleration: 0.0,
            count_um: 0.1,
        }
    }

    /// Velocity-loop damping ratio ζ.
    pub const DAMPING: f64 = 0.7;

    /// The velocity loop's PI gains (Kp s⁻¹, Ki s⁻²).
    pub fn velocity_gains(&self) -> (f64, f64) {
        let w = std::f64::consts::TAU * self.velocity_bandwidth_hz;
        (2.0 * Self::DAMPING * w, w * w)
    }

    /// The closed loop's response H(jω) to its command (the module docs' H(s)), as (re, im):
    /// what a circle at angular rate ω (rad/s) is drawn with on this axis, without friction.
    pub fn response(&self, omega: f64) -> (f64, f64) {
        let (kp, ki) = self.velocity_gains();
        let s = C(0.0, omega);
        let den_v = s * s + C(kp, 0.0) * s + C(ki, 0.0);
        let v = (C(kp, 0.0) * s + C(ki, 0.0)) / den_v;
        let w = s / den_v;
        let kv = C(self.kv_per_s, 0.0);
        let num =
            v * kv + v * C(self.ff_velocity, 0.0) * s + w * C(self.ff_acceleration, 0.0) * s * s;
        let h = num / (s + v * kv);
        (h.0, h.1)
    }
}

/// A tiny complex number for [`ServoLoop::response`].
#[derive(Debug, Clone, Copy)]
struct C(f64, f64);
impl std::ops::Add for C {
    type Output = C;
    fn add(self, o: C) -> C {
        C(self.0 + o.0, self.1 + o.1)
    }
}
impl std::ops::Mul for C {
    type Output = C;
    fn mul(self, o: C) -> C {
        C(self.0 * o.0 - self.1 * o.1, self.0 * o.1 + self.1 * o.0)
    }
}
impl std::ops::Div for C {
    type Output = C;
    fn div(self, o: C) -> C {
        let n = o.0 * o.0 + o.1 * o.1;
        C(
            (self.0 * o.0 + self.1 * o.1) / n,
            (self.1 * o.0 - self.0 * o.1) / n,
        )
    }
}

/// Friction on one axis, as force per moved mass (mm/s²); acts only inside a [`ServoLoop`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Friction {
    /// Coulomb (sliding) friction F_c (mm/s²).
    pub coulomb_mm_s2: f64,
    /// Static (breakaway) friction F_s ≥ F_c (mm/s²).
    pub static_mm_s2: f64,
    /// Stribeck velocity v_s (mm/s): how fast the friction falls from F_s to F_c.
    pub stribeck_mm_s: f64,
    /// Viscous friction c (s⁻¹).
    pub viscous_per_s: f64,
    /// Friction differs along the travel: F_s and F_c scale linearly from 1 at `neg_end_mm` to
    /// `pos_end_factor` at `pos_end_mm` (clamped beyond). `pos_end_mm <= neg_end_mm`: uniform.
    pub neg_end_mm: f64,
    /// See `neg_end_mm`.
    pub pos_end_mm: f64,
    /// See `neg_end_mm`.
    pub pos_end_factor: f64,
}

impl Friction {
    /// Uniform friction: Coulomb `coulomb_mm_s2`, static `static_mm_s2`, Stribeck 1 mm/s, no
    /// viscous part.
    pub fn new(coulomb_mm_s2: f64, static_mm_s2: f64) -> Self {
        Friction {
            coulomb_mm_s2,
            static_mm_s2,
            stribeck_mm_s: 1.0,
            viscous_per_s: 0.0,
            neg_end_mm: 0.0,
            pos_end_mm: 0.0,
            pos_end_factor: 1.0,
        }
    }

    fn factor(&self, p_mm: f64) -> f64 {
        if self.pos_end_mm <= self.neg_end_mm {
            return 1.0;
        }
        let w = ((p_mm - self.neg_end_mm) / (self.pos_end_mm - self.neg_end_mm)).clamp(0.0, 1.0);
        1.0 + w * (self.pos_end_factor - 1.0)
    }

    /// The new velocity after a step `h` from `v` under drive `u` at position `p_mm`.
    fn step(&self, v: f64, u: f64, p_mm: f64, h: f64) -> f64 {
        let f = self.factor(p_mm);
        let (fs, fc) = (self.static_mm_s2 * f, self.coulomb_mm_s2 * f);
        if v == 0.0 {
            if u.abs() <= fs {
                return 0.0;
            }
            return (u - u.signum() * fs) * h;
        }
        let r = v / self.stribeck_mm_s.max(1e-12);
        let friction = v.signum() * (fc + (fs - fc) * (-r * r).exp()) + self.viscous_per_s * v;
        let v_new = v + (u - friction) * h;
        if v_new == 0.0 || v_new.signum() != v.signum() {
            0.0
        } else {
            v_new
        }
    }
}

/// A structural mode between spindle and table (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StructuralMode {
    /// The direction the spindle ball is displaced in.
    pub axis: Axis,
    /// The axis whose drive force excites it.
    pub driven_by: Axis,
    /// Natural frequency (Hz).
    pub frequency_hz: f64,
    /// Damping ratio ζ (lightly damped: 0.01–0.05).
    pub damping: f64,
    /// Static deflection per drive acceleration (µm per m/s²).
    pub compliance_um_per_m_s2: f64,
}

/// An axis's scale growing in time about its fixed bearing (heat), from cycle start on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ThermalGrowth {
    /// The axis that grows.
    pub axis: Axis,
    /// Initial rate of scale change (µm/m per minute).
    pub um_per_m_per_min: f64,
    /// Position of the screw's fixed bearing (mm, program coordinates): the point that does not
    /// move.
    pub fixed_bearing_mm: f64,
    /// Thermal time constant (min); 0: the scale grows linearly for the whole test.
    pub time_constant_min: f64,
}

/// The spindle growing along Z towards the table (heat), from cycle start on.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SpindleGrowth {
    /// Initial growth rate (µm/min); positive: the spindle ball moves towards −Z.
    pub um_per_min: f64,
    /// Thermal time constant (min); 0: linear.
    pub time_constant_min: f64,
}

/// Growth after `t_min` minutes at initial rate `rate` with time constant `tau_min` (0: linear).
fn growth(rate: f64, tau_min: f64, t_min: f64) -> f64 {
    if t_min <= 0.0 {
        0.0
    } else if tau_min > 0.0 {
        rate * tau_min * (1.0 - (-t_min / tau_min).exp())
    } else {
        rate * t_min
    }
}

impl ThermalGrowth {
    /// δ (µm) of the axis at `p_mm`, `t_min` minutes after cycle start.
    pub fn delta_um(&self, p_mm: f64, t_min: f64) -> f64 {
        growth(self.um_per_m_per_min, self.time_constant_min, t_min)
            * (p_mm - self.fixed_bearing_mm)
            * 1e-3
    }
}

impl SpindleGrowth {
    /// δ_z (µm) `t_min` minutes after cycle start.
    pub fn delta_z_um(&self, t_min: f64) -> f64 {
        -growth(self.um_per_min, self.time_constant_min, t_min)
    }
}

/// Noise on D beyond white noise (see the module docs); [`Default`]: none.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ColouredNoise {
    /// Standard deviation of the AR(1) part (µm).
    pub ar1_um: f64,
    /// Its correlation time τ (ms): ρ = exp(−Δt/τ) between samples Δt apart.
    pub ar1_tau_ms: f64,
    /// Standard deviation of the 1/f-like wander (µm).
    pub wander_um: f64,
    /// RMS of the narrow-band vibration (µm).
    pub vibration_um: f64,
    /// Its centre frequency (Hz).
    pub vibration_hz: f64,
    /// Its bandwidth (Hz).
    pub vibration_bandwidth_hz: f64,
}

/// Time constants of the wander's three AR(1) parts (s).
const WANDER_TAU_S: [f64; 3] = [0.1, 1.0, 10.0];

impl ColouredNoise {
    /// Whether any part is on.
    pub fn is_on(&self) -> bool {
        self.ar1_um > 0.0 || self.wander_um > 0.0 || self.vibration_um > 0.0
    }

    pub(super) fn validate(&self) -> Result<(), String> {
        let v = [
            self.ar1_um,
            self.ar1_tau_ms,
            self.wander_um,
            self.vibration_um,
            self.vibration_hz,
            self.vibration_bandwidth_hz,
        ];
        if !v.iter().all(|x| x.is_finite() && *x >= 0.0) {
            return Err("coloured noise: every value must be finite and ≥ 0".into());
        }
        if self.ar1_um > 0.0 && self.ar1_tau_ms <= 0.0 {
            return Err("coloured noise: ar1_tau_ms must be > 0".into());
        }
        if self.vibration_um > 0.0
            && (self.vibration_hz <= 0.0 || self.vibration_bandwidth_hz <= 0.0)
        {
            return Err(
                "coloured noise: vibration_hz and vibration_bandwidth_hz must be > 0".into(),
            );
        }
        Ok(())
    }
}

/// The state of [`ColouredNoise`] along a recording; `next` takes standard normal draws.
#[derive(Debug, Clone, Default)]
pub struct NoiseState {
    ar1: f64,
    wander: [f64; 3],
    vib: (f64, f64),
    started: bool,
}

impl NoiseState {
    /// The next noise value (µm) `dt_s` after the previous one; `normal` draws N(0, 1).
    pub fn next(&mut self, c: &ColouredNoise, dt_s: f64, mut normal: impl FnMut() -> f64) -> f64 {
        // AR(1) of standard deviation σ and correlation time τ: stationary from the first sample.
        let ar = |x: &mut f64, sigma: f64, tau_s: f64, first: bool, z: f64| {
            if first {
                *x = sigma * z;
            } else {
                let rho = (-dt_s / tau_s).exp();
                *x = rho * *x + sigma * (1.0 - rho * rho).sqrt() * z;
            }
        };
        let first = !self.started;
        self.started = true;
        let mut out = 0.0;
        if c.ar1_um > 0.0 {
            ar(
                &mut self.ar1,
                c.ar1_um,
                c.ar1_tau_ms * 1e-3,
                first,
                normal(),
            );
            out += self.ar1;
        }
        if c.wander_um > 0.0 {
            let s = c.wander_um / 3f64.sqrt();
            for (x, tau) in self.wander.iter_mut().zip(WANDER_TAU_S) {
                ar(x, s, tau, first, normal());
                out += *x;
            }
        }
        if c.vibration_um > 0.0 {
            // A complex AR(1) rotating at the centre frequency: its real part is a narrow-band
            // process of variance vibration_um² centred there, of −3 dB bandwidth
            // vibration_bandwidth_hz.
            let (z1, z2) = (normal(), normal());
            let (re, im) = self.vib;
            if first {
                self.vib = (c.vibration_um * z1, c.vibration_um * z2);
            } else {
                let rho = (-std::f64::consts::PI * c.vibration_bandwidth_hz * dt_s).exp();
                let (sn, cs) = (std::f64::consts::TAU * c.vibration_hz * dt_s).sin_cos();
                let g = c.vibration_um * (1.0 - rho * rho).sqrt();
                self.vib = (
                    rho * (re * cs - im * sn) + g * z1,
                    rho * (re * sn + im * cs) + g * z2,
                );
            }
            out += self.vib.0;
        }
        out
    }
}

/// Everything of the dynamics that is stateful in time, per machine.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Dynamics {
    /// Position loop per axis (x, y, z); None: the axis follows its command exactly (apart from
    /// [`super::MachineErrors::servo_delay_ms`]).
    pub servo: [Option<ServoLoop>; 3],
    /// Friction per axis; needs that axis's loop.
    pub friction: [Option<Friction>; 3],
    /// Structural modes.
    pub modes: Vec<StructuralMode>,
}

impl Dynamics {
    /// Whether anything here needs integrating in time.
    pub fn is_on(&self) -> bool {
        self.servo.iter().any(Option::is_some) || !self.modes.is_empty()
    }

    pub(super) fn validate(&self) -> Result<(), String> {
        let ok = |v: f64| v.is_finite() && v >= 0.0;
        for s in self.servo.iter().flatten() {
            let good = s.kv_per_s > 0.0
                && s.kv_per_s.is_finite()
                && s.velocity_bandwidth_hz > 0.0
                && s.velocity_bandwidth_hz <= 2000.0
                && ok(s.ff_velocity)
                && s.ff_velocity <= 1.5
                && ok(s.ff_acceleration)
                && s.ff_acceleration <= 1.5
                && ok(s.count_um);
            if !good {
                return Err(
                    "servo loop: Kv > 0, velocity bandwidth in (0, 2000] Hz, feed-forwards \
                     in [0, 1.5], count ≥ 0"
                        .into(),
                );
            }
        }
        for (k, f) in self.friction.iter().enumerate() {
            let Some(f) = f else { continue };
            if self.servo[k].is_none() {
                return Err(
                    "friction acts inside a position loop: give that axis a servo loop".into(),
                );
            }
            if !(ok(f.coulomb_mm_s2)
                && ok(f.static_mm_s2)
                && f.static_mm_s2 >= f.coulomb_mm_s2
                && f.stribeck_mm_s > 0.0
                && ok(f.viscous_per_s)
                && ok(f.pos_end_factor)
                && f.neg_end_mm.is_finite()
                && f.pos_end_mm.is_finite())
            {
                return Err("friction: values ≥ 0, static ≥ Coulomb, Stribeck velocity > 0".into());
            }
        }
        for m in &self.modes {
            if !(m.frequency_hz > 0.0
                && m.frequency_hz <= 1000.0
                && m.damping > 0.0
                && m.damping < 1.0
                && m.compliance_um_per_m_s2.is_finite())
            {
                return Err("structural mode: frequency in (0, 1000] Hz, damping in (0, 1)".into());
            }
        }
        Ok(())
    }

    /// The integration step (s): fine against the fastest pole.
    fn step_s(&self) -> f64 {
        let mut w_max: f64 = 0.0;
        for s in self.servo.iter().flatten() {
            w_max = w_max
                .max(std::f64::consts::TAU * s.velocity_bandwidth_hz)
                .max(s.kv_per_s);
        }
        for m in &self.modes {
            w_max = w_max.max(std::f64::consts::TAU * m.frequency_hz);
        }
        (0.02 / w_max.max(1.0)).min(50e-6)
    }
}

/// What the dynamics add at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DynOffsets {
    /// Position of each axis's carriage minus its command (mm): the loop's following error with
    /// its sign (negative: behind a positive command velocity).
    pub follow_mm: [f64; 3],
    /// Displacement of the spindle ball by the structural modes (µm).
    pub structure_um: [f64; 3],
}

#[derive(Debug, Clone, Copy, Default)]
struct AxisState {
    x: f64,
    v: f64,
    integral: f64,
    /// Drive force per mass of the last step (mm/s²).
    u: f64,
}

#[derive(Debug, Clone, Copy, Default)]
struct ModeState {
    y_um: f64,
    dy: f64,
}

/// The dynamics integrated along a trajectory on a fixed time grid; asked for increasing times.
#[derive(Debug, Clone)]
pub struct DynamicState<'a> {
    dynamics: &'a Dynamics,
    h: f64,
    /// Grid time of `cur`.
    t: f64,
    /// Commanded positions at t − h, t, t + h.
    p: [[f64; 3]; 3],
    axes: [AxisState; 3],
    modes: Vec<ModeState>,
    prev: DynOffsets,
    cur: DynOffsets,
}

impl<'a> DynamicState<'a> {
    /// Start at program time `t0_s` with the machine at rest at its command.
    pub fn new(dynamics: &'a Dynamics, traj: &Trajectory, t0_s: f64) -> Self {
        let h = dynamics.step_s();
        let p0 = traj.position_at(t0_s);
        let axes = [0, 1, 2].map(|k| AxisState {
            x: p0[k],
            ..AxisState::default()
        });
        DynamicState {
            dynamics,
            h,
            t: t0_s,
            p: [traj.position_at(t0_s - h), p0, traj.position_at(t0_s + h)],
            axes,
            modes: vec![ModeState::default(); dynamics.modes.len()],
            prev: DynOffsets::default(),
            cur: DynOffsets::default(),
        }
    }

    /// The offsets at program time `t_s` (≥ the previous call's), integrating up to it.
    pub fn at(&mut self, traj: &Trajectory, t_s: f64) -> DynOffsets {
        while self.t < t_s {
            self.prev = self.cur;
            self.step(traj);
        }
        // Linear between the grid points around t_s.
        let w = if self.h > 0.0 {
            (1.0 - (self.t - t_s) / self.h).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let lerp = |a: f64, b: f64| a + w * (b - a);
        DynOffsets {
            follow_mm: [0, 1, 2].map(|k| lerp(self.prev.follow_mm[k], self.cur.follow_mm[k])),
            structure_um: [0, 1, 2]
                .map(|k| lerp(self.prev.structure_um[k], self.cur.structure_um[k])),
        }
    }

    fn step(&mut self, traj: &Trajectory) {
        let h = self.h;
        let [pm, p0, pp] = self.p;
        for k in 0..3 {
            let pv = (pp[k] - pm[k]) / (2.0 * h);
            let pa = (pp[k] - 2.0 * p0[k] + pm[k]) / (h * h);
            let a = &mut self.axes[k];
            let Some(s) = self.dynamics.servo[k] else {
                a.x = pp[k];
                a.u = pa;
                continue;
            };
            let q = s.count_um * 1e-3;
            let x_fb = if q > 0.0 { (a.x / q).round() * q } else { a.x };
            let (kp, ki) = s.velocity_gains();
            let v_c = s.kv_per_s * (p0[k] - x_fb) + s.ff_velocity * pv;
            let ev = v_c - a.v;
            a.integral += ki * ev * h;
            let u = kp * ev + a.integral + s.ff_acceleration * pa;
            a.u = u;
            a.v = match &self.dynamics.friction[k] {
                Some(f) => f.step(a.v, u, a.x, h),
                None => a.v + u * h,
            };
            a.x += a.v * h;
        }
        for (m, st) in self.dynamics.modes.iter().zip(self.modes.iter_mut()) {
            let w = std::f64::consts::TAU * m.frequency_hz;
            // u in mm/s² = 1e-3 m/s²; compliance in µm per m/s².
            let force = m.compliance_um_per_m_s2 * self.axes[m.driven_by.index()].u * 1e-3;
            let acc = -2.0 * m.damping * w * st.dy - w * w * (st.y_um + force);
            st.dy += acc * h;
            st.y_um += st.dy * h;
        }
        self.t += h;
        self.p = [p0, pp, traj.position_at(self.t + h)];
        let mut structure_um = [0.0; 3];
        for (m, st) in self.dynamics.modes.iter().zip(&self.modes) {
            structure_um[m.axis.index()] += st.y_um;
        }
        self.cur = DynOffsets {
            follow_mm: [0, 1, 2].map(|k| self.axes[k].x - pp[k]),
            structure_um,
        };
    }
}
