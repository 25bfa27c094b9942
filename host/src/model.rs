//! Candidate effects of a circular test: parametric models of the error δ added to the nominal
//! spindle-ball position, and the exact ball-distance model D = |p + δ + c| + e built from them.
//!
//! Every effect here is *linear in its parameters* given the nominal path: a periodic term
//! A·sin(2πk/p + φ) is fitted as A_s·sin(2πk/p) + A_c·cos(2πk/p), so a fit never has to search a
//! phase. The only nonlinearity is the norm |·| of the exact geometry, handled by
//! [`ExactModel`] with the least-squares engine in [`crate::fit`]. Linearised at the nominal path
//! (seed 000 eq. 1, ΔR = u·C with u = p/|p|), each parameter is one column of a linear model,
//! which the diagnosis uses for a fast candidate search.
//!
//! Conventions (the same as `jdbb_core::machine`): positions in mm relative to the table ball,
//! velocities mm/s, δ positive lengthens the axis. Parameters are in their reporting units (µm,
//! µm/m, µm/m², µm per mm/s, ms) so the fit's column scaling is well conditioned.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
use std::fmt;

/// A machine axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Axis {
    X = 0,
    Y = 1,
    Z = 2,
}

impl Axis {
    pub const ALL: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];
    pub fn index(self) -> usize {
        self as usize
    }
    pub fn letter(self) -> char {
        ['x', 'y', 'z'][self as usize]
    }
    fn parse(c: &str) -> Option<Axis> {
        match c {
            "x" => Some(Axis::X),
            "y" => Some(Axis::Y),
            "z" => Some(Axis::Z),
            _ => None,
        }
    }
}

/// An ordered axis pair ij ∈ {xy, yz, zx}.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Pair {
    Xy,
    Yz,
    Zx,
}

impl Pair {
    pub const ALL: [Pair; 3] = [Pair::Xy, Pair::Yz, Pair::Zx];
    /// (i, j) of the pair.
    pub fn axes(self) -> (Axis, Axis) {
        match self {
            Pair::Xy => (Axis::X, Axis::Y),
            Pair::Yz => (Axis::Y, Axis::Z),
            Pair::Zx => (Axis::Z, Axis::X),
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Pair::Xy => "xy",
            Pair::Yz => "yz",
            Pair::Zx => "zx",
        }
    }
    fn parse(s: &str) -> Option<Pair> {
        match s {
            "xy" => Some(Pair::Xy),
            "yz" => Some(Pair::Yz),
            "zx" => Some(Pair::Zx),
            _ => None,
        }
    }
}

/// One candidate effect. Names (see [`Effect::name`]) are the issue's, used everywhere.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// c: the table ball is not where assumed (µm per axis); D = |p + δ + c| + e.
    SetupOffset,
    /// e added to D (µm).
    LengthOffset,
    /// δ_k = a·k, a in µm/m (seed 000 eq. 2, first-order uniform contraction).
    Scale(Axis),
    /// δ_k = b·k², b in µm/m² (seed 000 eq. 5, second-order uniform contraction).
    Scale2(Axis),
    /// δ_k = ±f/2 moving ±k, f in µm (seed 000 eq. 14, opposite clearance).
    Backlash(Axis),
    /// δ_k = A·sin(2πk/p + φ), A in µm (seed 000 eq. 8, periodic error).
    Cyclic(Axis),
    /// δ_k = b·v_k·sin(2πk/p + φ), b in µm per mm/s (seed 000 eq. 11, interference).
    Interference(Axis),
    /// δ_i = s·j, s in µm/m.
    Squareness(Pair),
    /// δ_k = −τ_k·v_k with τ_i − τ_j = Δτ (ms): δ_i = −(Δτ/2)·v_i, δ_j = +(Δτ/2)·v_j. The common
    /// lag moves the ball along the path and is invisible to first order, so only Δτ is a parameter.
    ServoMismatch(Pair),
    /// Identifiable combination scale_i − scale_j (µm/m) when the isotropic scale is confounded
    /// with length_offset: δ_i = +(a/2)·i, δ_j = −(a/2)·j.
    ScaleMismatch(Pair),
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name())
    }
}

/// What an effect contributes per unit of one parameter at one sample: a position change (mm)
/// and a direct change of D (mm).
#[derive(Debug, Clone, Copy, Default)]
pub struct Column {
    pub dp_mm: [f64; 3],
    pub dd_mm: f64,
}

/// The nominal path with the derived motion: velocity and held direction per axis.
#[derive(Debug, Clone)]
pub struct Path {
    pub t_s: Vec<f64>,
    pub p_mm: Vec<[f64; 3]>,
    /// Velocity from the nominal path and time (central differences).
    pub v_mm_s: Vec<[f64; 3]>,
    /// Direction of motion per axis, +1/−1, holding its sign through a standstill; 0 for an axis
    /// that never moves.
    pub dir: Vec<[i8; 3]>,
    /// Ball-screw or scale pitch per axis (mm), needed by the periodic effects.
    pub pitch_mm: [Option<f64>; 3],
    /// Travel range (max − min) per axis, mm.
    pub range_mm: [f64; 3],
    /// See [`Path::pitch_phase`].
    pub(crate) phase: Vec<[(f64, f64); 3]>,
}

impl Path {
    /// Derive velocity and direction from the nominal positions and times (times strictly
    /// increasing; the caller checks).
    pub fn new(t_s: Vec<f64>, p_mm: Vec<[f64; 3]>, pitch_mm: [Option<f64>; 3]) -> Path {
        let n = p_mm.len();
        let mut v = vec![[0.0; 3]; n];
        for i in 0..n {
            let (a, b) = if n < 2 {
                (0, 0)
            } else if i == 0 {
                (0, 1)
            } else if i == n - 1 {
                (n - 2, n - 1)
            } else {
                (i - 1, i + 1)
            };
            let dt = t_s[b] - t_s[a];
            if dt > 0.0 {
                for k in 0..3 {
                    v[i][k] = (p_mm[b][k] - p_mm[a][k]) / dt;
                }
            }
        }
        let mut range = [0.0; 3];
        for k in 0..3 {
            let (lo, hi) = p_mm
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p[k]), hi.max(p[k]))
                });
            range[k] = if n > 0 { hi - lo } else { 0.0 };
        }
        // Direction with hold: a speed below 1e-9 of the fastest axis speed is a standstill.
        let vmax = v
            .iter()
            .flat_map(|x| x.iter())
            .fold(0.0f64, |m, &x| m.max(x.abs()));
        let eps = vmax * 1e-9;
        let mut dir = vec![[0i8; 3]; n];
        for k in 0..3 {
            let first = v.iter().map(|x| x[k]).find(|x| x.abs() > eps);
            let mut held: i8 = match first {
                Some(x) if x > 0.0 => 1,
                Some(_) => -1,
                None => 0,
            };
            for i in 0..n {
                if v[i][k] > eps {
                    held = 1;
                } else if v[i][k] < -eps {
                    held = -1;
                }
                dir[i][k] = held;
            }
        }
        let phase = p_mm
            .iter()
            .map(|p| {
                let mut out = [(0.0, 0.0); 3];
                for (k, o) in out.iter_mut().enumerate() {
                    if let Some(pitch) = pitch_mm[k] {
                        *o = (std::f64::consts::TAU * p[k] / pitch).sin_cos();
                    }
                }
                out
            })
            .collect();
        Path {
            t_s,
            p_mm,
            v_mm_s: v,
            dir,
            pitch_mm,
            range_mm: range,
            phase,
        }
    }

    pub fn len(&self) -> usize {
        self.p_mm.len()
    }

    pub fn is_empty(&self) -> bool {
        self.p_mm.is_empty()
    }

    /// (sin, cos) of 2π·k/pitch_k per axis at sample i; (0, 0) for an axis without a pitch.
    /// Computed once in [`Path::new`]: every periodic column needs it on every pass.
    pub fn pitch_phase(&self, i: usize) -> [(f64, f64); 3] {
        self.phase[i]
    }

    /// Whether axis k moves at all.
    pub fn moves(&self, k: Axis) -> bool {
        self.range_mm[k.index()] > 0.0
    }
}

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
        v
    }

    /// The effect's name, e.g. `scale_x`, `servo_mismatch_xy`.
    pub fn name(&self) -> String {
        match *self {
            Effect::SetupOffset => "setup_offset".into(),
            Effect::LengthOffset => "length_offset".into(),
            Effect::Scale(a) => format!("scale_{}", a.letter()),
            Effect::Scale2(a) => format!("scale2_{}", a.letter()),
            Effect::Backlash(a) => format!("backlash_{}", a.letter()),
            Effect::Cyclic(a) => format!("cyclic_{}", a.letter()),
            Effect::Interference(a) => format!("interference_{}", a.letter()),
            Effect::Squareness(p) => format!("squareness_{}", p.name()),
            Effect::ServoMismatch(p) => format!("servo_mismatch_{}", p.name()),
            Effect::ScaleMismatch(p) => format!("scale_mismatch_{}", p.name()),
        }
    }

    /// Parse an effect name; None if unknown.
    pub fn parse(name: &str) -> Option<Effect> {
        match name {
            "setup_offset" => return Some(Effect::SetupOffset),
            "length_offset" => return Some(Effect::LengthOffset),
            _ => {}
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
            _ => None,
        }
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
            Effect::Backlash(_) | Effect::Cyclic(_) => "um",
            Effect::Interference(_) => "um/(mm/s)",
            Effect::ServoMismatch(_) => "ms",
        }
    }

    /// Names of the parameters (JSON keys).
    pub fn param_names(&self) -> &'static [&'static str] {
        match self {
            Effect::SetupOffset => &["x_um", "y_um", "z_um"],
            Effect::LengthOffset => &["e_um"],
            Effect::Scale(_) | Effect::ScaleMismatch(_) => &["a_um_per_m"],
            Effect::Scale2(_) => &["b_um_per_m2"],
            Effect::Backlash(_) => &["f_um"],
            Effect::Cyclic(_) => &["sin_um", "cos_um"],
            Effect::Interference(_) => &["sin_um_per_mm_s", "cos_um_per_mm_s"],
            Effect::Squareness(_) => &["s_um_per_m"],
            Effect::ServoMismatch(_) => &["dtau_ms"],
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

    /// The physical cause, in words.
    pub fn cause(&self) -> String {
        match *self {
            Effect::SetupOffset => "the table ball is not where assumed (set-up offset)".into(),
            Effect::LengthOffset => "the bar length differs from its assumed value".into(),
            Effect::Scale(a) => format!(
                "{} axis scale error: uniform contraction/expansion of its ball screw or scale, usually thermal (seed 000 eq. 2)",
                a.letter().to_ascii_uppercase()
            ),
            Effect::Scale2(a) => format!(
                "{} axis second-order contraction: screw or scale fixed at both ends and heated (seed 000 eq. 5)",
                a.letter().to_ascii_uppercase()
            ),
            Effect::Backlash(a) => format!(
                "{} axis backlash (opposite clearance): lost motion at reversal (seed 000 eq. 14)",
                a.letter().to_ascii_uppercase()
            ),
            Effect::Cyclic(a) => format!(
                "{} axis periodic error of the ball screw or scale at its pitch (seed 000 eq. 8)",
                a.letter().to_ascii_uppercase()
            ),
            Effect::Interference(a) => format!(
                "{} axis interference of the detection device: periodic error growing with speed (seed 000 eq. 11)",
                a.letter().to_ascii_uppercase()
            ),
            Effect::Squareness(p) => {
                let (i, j) = p.axes();
                format!(
                    "squareness error between {} and {}: {} moves by s per metre of {}",
                    i.letter().to_ascii_uppercase(),
                    j.letter().to_ascii_uppercase(),
                    i.letter().to_ascii_uppercase(),
                    j.letter().to_ascii_uppercase()
                )
            }
            Effect::ServoMismatch(p) => {
                let (i, j) = p.axes();
                format!(
                    "servo gain mismatch: {} lags {} by dtau (position-loop time constants differ)",
                    i.letter().to_ascii_uppercase(),
                    j.letter().to_ascii_uppercase()
                )
            }
            Effect::ScaleMismatch(p) => {
                let (i, j) = p.axes();
                format!(
                    "scale mismatch between {} and {} (scale_{} − scale_{}); their common part cannot be told from length_offset at one radius",
                    i.letter().to_ascii_uppercase(),
                    j.letter().to_ascii_uppercase(),
                    i.letter(),
                    j.letter()
                )
            }
        }
    }

    /// Write the per-unit-parameter columns at sample `i` into `out` (length `n_params()`).
    /// `trig` is [`Path::pitch_phase`] at sample i.
    pub fn columns(&self, path: &Path, i: usize, trig: &[(f64, f64); 3], out: &mut [Column]) {
        let p = path.p_mm[i];
        let v = path.v_mm_s[i];
        for c in out.iter_mut() {
            *c = Column::default();
        }
        match *self {
            Effect::SetupOffset => {
                for k in 0..3 {
                    out[k].dp_mm[k] = 1e-3;
                }
            }
            Effect::LengthOffset => out[0].dd_mm = 1e-3,
            Effect::Scale(a) => {
                let k = a.index();
                out[0].dp_mm[k] = 1e-6 * p[k];
            }
            Effect::ScaleMismatch(pair) => {
                let (a, b) = pair.axes();
                out[0].dp_mm[a.index()] = 0.5e-6 * p[a.index()];
                out[0].dp_mm[b.index()] = -0.5e-6 * p[b.index()];
            }
            Effect::Scale2(a) => {
                let k = a.index();
                // b µm/m² · (k mm · 1e-3 m/mm)² · 1e-3 mm/µm
                out[0].dp_mm[k] = 1e-9 * p[k] * p[k];
            }
            Effect::Backlash(a) => {
                let k = a.index();
                out[0].dp_mm[k] = 0.5e-3 * f64::from(path.dir[i][k]);
            }
            Effect::Cyclic(a) | Effect::Interference(a) => {
                let k = a.index();
                let (s, c) = trig[k];
                let g = if matches!(self, Effect::Cyclic(_)) {
                    1e-3
                } else {
                    1e-3 * v[k]
                };
                out[0].dp_mm[k] = g * s;
                out[1].dp_mm[k] = g * c;
            }
            Effect::Squareness(pair) => {
                let (a, b) = pair.axes();
                out[0].dp_mm[a.index()] = 1e-6 * p[b.index()];
            }
            Effect::ServoMismatch(pair) => {
                let (a, b) = pair.axes();
                // ms → s: 1e-3; δ in mm directly (v in mm/s).
                out[0].dp_mm[a.index()] = -0.5e-3 * v[a.index()];
                out[0].dp_mm[b.index()] = 0.5e-3 * v[b.index()];
            }
        }
    }

    /// The linearised columns at sample `i`: 1e3·(u·dp + dd), i.e. the change of D in µm per unit
    /// of each parameter for a unit vector `u` (seed 000 eq. 1). The same numbers as
    /// [`Effect::columns`] projected on u. One sample of [`Effect::radial_block`].
    pub fn radial_columns(&self, path: &Path, i: usize, u: [f64; 3], out: &mut [f64]) {
        self.radial_block(path, i, &[u], out, self.n_params(), 0);
    }

    /// [`Effect::radial_columns`] for samples i0..i0 + u.len() at once: sample j's parameter k
    /// goes to `out[j·stride + offset + k]`. Effect by effect over a block of samples, because
    /// the candidate search and the exact fit evaluate every column on every sample.
    pub fn radial_block(
        &self,
        path: &Path,
        i0: usize,
        u: &[[f64; 3]],
        out: &mut [f64],
        stride: usize,
        offset: usize,
    ) {
        let n = u.len();
        let p = &path.p_mm[i0..i0 + n];
        let v = &path.v_mm_s[i0..i0 + n];
        let rows = (0..n).map(|j| j * stride + offset);
        match *self {
            Effect::SetupOffset => {
                for (j, o) in rows.enumerate() {
                    out[o..o + 3].copy_from_slice(&u[j]);
                }
            }
            Effect::LengthOffset => {
                for o in rows {
                    out[o] = 1.0;
                }
            }
            Effect::Scale(a) => {
                let k = a.index();
                for (j, o) in rows.enumerate() {
                    out[o] = 1e-3 * u[j][k] * p[j][k];
                }
            }
            Effect::ScaleMismatch(pair) => {
                let (a, b) = pair.axes();
                let (a, b) = (a.index(), b.index());
                for (j, o) in rows.enumerate() {
                    out[o] = 0.5e-3 * (u[j][a] * p[j][a] - u[j][b] * p[j][b]);
                }
            }
            Effect::Scale2(a) => {
                let k = a.index();
                for (j, o) in rows.enumerate() {
                    out[o] = 1e-6 * u[j][k] * p[j][k] * p[j][k];
                }
            }
            Effect::Backlash(a) => {
                let k = a.index();
                let dir = &path.dir[i0..i0 + n];
                for (j, o) in rows.enumerate() {
                    out[o] = 0.5 * u[j][k] * f64::from(dir[j][k]);
                }
            }
            Effect::Cyclic(a) | Effect::Interference(a) => {
                let k = a.index();
                let cyclic = matches!(self, Effect::Cyclic(_));
                for (j, o) in rows.enumerate() {
                    let (s, c) = path.phase[i0 + j][k];
                    let g = if cyclic { u[j][k] } else { u[j][k] * v[j][k] };
                    out[o] = g * s;
                    out[o + 1] = g * c;
                }
            }
            Effect::Squareness(pair) => {
                let (a, b) = pair.axes();
                let (a, b) = (a.index(), b.index());
                for (j, o) in rows.enumerate() {
                    out[o] = 1e-3 * u[j][a] * p[j][b];
                }
            }
            Effect::ServoMismatch(pair) => {
                let (a, b) = pair.axes();
                let (a, b) = (a.index(), b.index());
                for (j, o) in rows.enumerate() {
                    out[o] = 0.5 * (u[j][b] * v[j][b] - u[j][a] * v[j][a]);
                }
            }
        }
    }

    /// Add this effect's δ (mm) for parameters `theta` to the position `q`, and its direct
    /// change of D (mm) to `dd`: Σ θ_k·[`Effect::columns`]_k, written out because the exact fit
    /// evaluates it on every pass.
    pub fn add_delta(
        &self,
        path: &Path,
        i: usize,
        trig: &[(f64, f64); 3],
        theta: &[f64],
        q: &mut [f64; 3],
        dd: &mut f64,
    ) {
        let p = path.p_mm[i];
        let v = path.v_mm_s[i];
        match *self {
            Effect::SetupOffset => {
                for k in 0..3 {
                    q[k] += 1e-3 * theta[k];
                }
            }
            Effect::LengthOffset => *dd += 1e-3 * theta[0],
            Effect::Scale(a) => q[a.index()] += 1e-6 * theta[0] * p[a.index()],
            Effect::ScaleMismatch(pair) => {
                let (a, b) = pair.axes();
                q[a.index()] += 0.5e-6 * theta[0] * p[a.index()];
                q[b.index()] -= 0.5e-6 * theta[0] * p[b.index()];
            }
            Effect::Scale2(a) => {
                let k = a.index();
                q[k] += 1e-9 * theta[0] * p[k] * p[k];
            }
            Effect::Backlash(a) => {
                let k = a.index();
                q[k] += 0.5e-3 * theta[0] * f64::from(path.dir[i][k]);
            }
            Effect::Cyclic(a) | Effect::Interference(a) => {
                let k = a.index();
                let (s, c) = trig[k];
                let g = if matches!(self, Effect::Cyclic(_)) {
                    1e-3
                } else {
                    1e-3 * v[k]
                };
                q[k] += g * (theta[0] * s + theta[1] * c);
            }
            Effect::Squareness(pair) => {
                let (a, b) = pair.axes();
                q[a.index()] += 1e-6 * theta[0] * p[b.index()];
            }
            Effect::ServoMismatch(pair) => {
                let (a, b) = pair.axes();
                q[a.index()] -= 0.5e-3 * theta[0] * v[a.index()];
                q[b.index()] += 0.5e-3 * theta[0] * v[b.index()];
            }
        }
    }

    /// [`Effect::add_delta`] for samples i0..i0 + q.len() at once: adds this effect's δ (mm) to
    /// `q[j]` and its direct change of D (mm) to `dd[j]` for sample i0 + j. The same arithmetic
    /// as [`Effect::add_delta`] (bit for bit), effect by effect over a block of samples, because
    /// the exact fit evaluates every effect on every sample on every pass and a per-sample
    /// dispatch over the effects costs more than the arithmetic.
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
                let c = [1e-3 * theta[0], 1e-3 * theta[1], 1e-3 * theta[2]];
                for qj in q.iter_mut() {
                    for k in 0..3 {
                        qj[k] += c[k];
                    }
                }
            }
            Effect::LengthOffset => {
                let e = 1e-3 * theta[0];
                for x in dd.iter_mut() {
                    *x += e;
                }
            }
            Effect::Scale(a) => {
                let (k, s) = (a.index(), 1e-6 * theta[0]);
                for (qj, pj) in q.iter_mut().zip(p) {
                    qj[k] += s * pj[k];
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
                let (k, s) = (a.index(), 0.5e-3 * theta[0]);
                let dir = &path.dir[i0..i0 + n];
                for (qj, dj) in q.iter_mut().zip(dir) {
                    qj[k] += s * f64::from(dj[k]);
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
                let (a, b) = (a.index(), b.index());
                let s = 0.5e-3 * theta[0];
                for (qj, vj) in q.iter_mut().zip(v) {
                    qj[a] -= s * vj[a];
                    qj[b] += s * vj[b];
                }
            }
        }
    }

    /// The effect's reported value and its standard error from its parameters and their
    /// covariance block (value = |c| for setup_offset, the amplitude for periodic effects; the
    /// delta method propagates the covariance).
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
            _ => (params[0], Some(cov[0][0].max(0.0).sqrt())),
        }
    }

    /// Parameters from a value and an optional phase (rad), for simulation: periodic effects
    /// A·sin(w + φ) = A cos φ · sin w + A sin φ · cos w.
    pub fn params_from_value(&self, value: f64, phase_rad: f64) -> Vec<f64> {
        match self {
            Effect::Cyclic(_) | Effect::Interference(_) => {
                vec![value * phase_rad.cos(), value * phase_rad.sin()]
            }
            _ => vec![value; self.n_params()],
        }
    }
}

/// A set of effects with their parameters laid out one after another.
#[derive(Debug, Clone)]
pub struct EffectSet {
    pub effects: Vec<Effect>,
    /// Index of each effect's first parameter.
    pub offsets: Vec<usize>,
    pub n_params: usize,
    /// Whether any effect needs the pitch phase.
    periodic: bool,
}

impl EffectSet {
    pub fn new(effects: Vec<Effect>) -> EffectSet {
        let mut offsets = Vec::with_capacity(effects.len());
        let mut n = 0;
        for e in &effects {
            offsets.push(n);
            n += e.n_params();
        }
        let periodic = effects.iter().any(|e| e.periodic_axis().is_some());
        EffectSet {
            effects,
            offsets,
            n_params: n,
            periodic,
        }
    }

    /// All per-unit-parameter columns at sample i, in parameter order.
    pub fn columns(&self, path: &Path, i: usize, out: &mut [Column]) {
        let trig = if self.periodic {
            path.pitch_phase(i)
        } else {
            [(0.0, 0.0); 3]
        };
        for (e, &o) in self.effects.iter().zip(&self.offsets) {
            e.columns(path, i, &trig, &mut out[o..o + e.n_params()]);
        }
    }

    /// Exact model distance (mm) at sample i for parameters `theta`: |p + δ + c| + e.
    pub fn distance_mm(&self, path: &Path, i: usize, theta: &[f64]) -> f64 {
        let (q, d) = self.displaced(path, i, theta);
        (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + d
    }

    /// The displaced spindle-ball position p + δ + c (mm) and the length offset e (mm) at sample
    /// i for parameters `theta`.
    pub fn displaced(&self, path: &Path, i: usize, theta: &[f64]) -> ([f64; 3], f64) {
        let trig = path.pitch_phase(i);
        let mut q = path.p_mm[i];
        let mut d = 0.0;
        for (e, &o) in self.effects.iter().zip(&self.offsets) {
            e.add_delta(path, i, &trig, &theta[o..o + e.n_params()], &mut q, &mut d);
        }
        (q, d)
    }

    /// [`EffectSet::displaced`] for samples i0..i0 + q.len() at once (bit for bit the same):
    /// writes p + δ + c (mm) to `q[j]` and e (mm) to `dd[j]` for sample i0 + j.
    pub fn displaced_block(
        &self,
        path: &Path,
        i0: usize,
        theta: &[f64],
        q: &mut [[f64; 3]],
        dd: &mut [f64],
    ) {
        let n = q.len();
        q.copy_from_slice(&path.p_mm[i0..i0 + n]);
        dd[..n].fill(0.0);
        for (e, &o) in self.effects.iter().zip(&self.offsets) {
            e.add_delta_block(path, i0, &theta[o..o + e.n_params()], q, dd);
        }
    }

    /// [`EffectSet::distance_mm`] of every sample of the path (bit for bit the same), a block
    /// of samples at a time.
    pub fn distances_mm(&self, path: &Path, theta: &[f64]) -> Vec<f64> {
        const BLOCK: usize = 256;
        let m = path.len();
        let mut out = Vec::with_capacity(m);
        let mut q = [[0.0; 3]; BLOCK];
        let mut dd = [0.0; BLOCK];
        let mut i0 = 0;
        while i0 < m {
            let len = BLOCK.min(m - i0);
            self.displaced_block(path, i0, theta, &mut q[..len], &mut dd[..len]);
            out.extend(
                q[..len]
                    .iter()
                    .zip(&dd[..len])
                    .map(|(q, d)| (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + d),
            );
            i0 += len;
        }
        out
    }
}

/// The exact geometry D = |p + δ(θ) + c| + e as a least-squares problem; residuals in µm.
pub struct ExactModel<'a> {
    pub path: &'a Path,
    pub d_mm: &'a [f64],
    pub set: &'a EffectSet,
}

impl crate::fit::Problem for ExactModel<'_> {
    fn n_params(&self) -> usize {
        self.set.n_params
    }
    fn n_residuals(&self) -> usize {
        self.d_mm.len()
    }
    fn eval(&self, theta: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        // The gradient of |q| with respect to a parameter is u·dp with u = q/|q|: the radial
        // columns evaluated at the displaced position, computed a block of samples at a time.
        const BLOCK: usize = 256;
        let n = self.set.n_params;
        let m = self.d_mm.len();
        let mut grads = vec![0.0; BLOCK * n];
        let mut q = [[0.0; 3]; BLOCK];
        let mut dd = [0.0; BLOCK];
        let mut u = Vec::with_capacity(BLOCK);
        let mut res = Vec::with_capacity(BLOCK);
        let mut i0 = 0;
        while i0 < m {
            let len = BLOCK.min(m - i0);
            u.clear();
            res.clear();
            self.set
                .displaced_block(self.path, i0, theta, &mut q[..len], &mut dd[..len]);
            for (j, (q, d)) in q[..len].iter().zip(&dd[..len]).enumerate() {
                let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
                u.push([q[0] / r, q[1] / r, q[2] / r]);
                res.push(1e3 * (r + d - self.d_mm[i0 + j]));
            }
            for (e, &o) in self.set.effects.iter().zip(&self.set.offsets) {
                e.radial_block(self.path, i0, &u, &mut grads, n, o);
            }
            for j in 0..len {
                visit(i0 + j, res[j], &grads[j * n..(j + 1) * n]);
            }
            i0 += len;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jdbb_core::machine::{AxisErrors, MachineErrors};

    fn circle(r: f64, n: usize) -> Path {
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
        let p = t
            .iter()
            .map(|&t| {
                let th = t * 0.5;
                [r * th.cos(), r * th.sin(), 0.0]
            })
            .collect();
        Path::new(t, p, [Some(5.0), Some(5.0), None])
    }

    #[test]
    fn names_round_trip() {
        for e in Effect::all() {
            assert_eq!(Effect::parse(&e.name()), Some(e));
        }
        assert_eq!(Effect::parse("scale_w"), None);
        assert_eq!(Effect::parse("backlash"), None);
        assert_eq!(Effect::all().len(), 2 + 5 * 3 + 2 * 3);
    }

    #[test]
    fn columns_match_the_core_machine_models() {
        // Each effect's column × parameter must reproduce jdbb_core::machine's δ (µm) at a few
        // samples, which checks units and sign conventions against the shared models.
        let path = circle(40.0, 700);
        for i in [3usize, 250, 400, 650] {
            let p = path.p_mm[i];
            let v = path.v_mm_s[i];
            let dir = path.dir[i];
            let ax = AxisErrors {
                scale_um_per_m: 30.0,
                scale2_um_per_m2: 700.0,
                cyclic_um: 2.0,
                cyclic_phase_rad: 0.7,
                interference_um_per_mm_s: 0.3,
                interference_phase_rad: -0.4,
                pitch_mm: 5.0,
                backlash_um: 6.0,
            };
            let m = MachineErrors {
                axes: [ax, AxisErrors::default(), AxisErrors::default()],
                squareness_um_per_m: [12.0, 0.0, 0.0],
            };
            let expect = m.error_um(p, v, dir);
            let set = EffectSet::new(vec![
                Effect::Scale(Axis::X),
                Effect::Scale2(Axis::X),
                Effect::Cyclic(Axis::X),
                Effect::Interference(Axis::X),
                Effect::Backlash(Axis::X),
                Effect::Squareness(Pair::Xy),
            ]);
            let mut theta = vec![30.0, 700.0];
            theta.extend(Effect::Cyclic(Axis::X).params_from_value(2.0, 0.7));
            theta.extend(Effect::Interference(Axis::X).params_from_value(0.3, -0.4));
            theta.extend([6.0, 12.0]);
            let mut cols = vec![Column::default(); set.n_params];
            set.columns(&path, i, &mut cols);
            let mut got = [0.0; 3];
            for (c, t) in cols.iter().zip(&theta) {
                for k in 0..3 {
                    got[k] += 1e3 * t * c.dp_mm[k];
                }
            }
            for k in 0..3 {
                assert!(
                    (got[k] - expect[k]).abs() < 1e-9,
                    "sample {i} axis {k}: {got:?} vs {expect:?}"
                );
            }
        }
    }

    #[test]
    fn radial_columns_are_the_projected_columns() {
        let path = circle(40.0, 700);
        for e in Effect::all()
            .into_iter()
            .chain(Pair::ALL.map(Effect::ScaleMismatch))
        {
            let n = e.n_params();
            for i in [5usize, 333, 600] {
                let p = path.p_mm[i];
                let u = [p[0] / 40.0, p[1] / 40.0, 0.3];
                let mut cols = vec![Column::default(); n];
                e.columns(&path, i, &path.pitch_phase(i), &mut cols);
                let mut fast = vec![f64::NAN; n];
                e.radial_columns(&path, i, u, &mut fast);
                for k in 0..n {
                    let c = cols[k];
                    let slow =
                        1e3 * (u[0] * c.dp_mm[0] + u[1] * c.dp_mm[1] + u[2] * c.dp_mm[2] + c.dd_mm);
                    assert!(
                        (slow - fast[k]).abs() < 1e-12,
                        "{e} {i} {k}: {slow} {}",
                        fast[k]
                    );
                }
            }
        }
    }

    #[test]
    fn add_delta_is_the_sum_of_the_columns() {
        let path = circle(40.0, 700);
        for e in Effect::all()
            .into_iter()
            .chain(Pair::ALL.map(Effect::ScaleMismatch))
        {
            let n = e.n_params();
            let theta: Vec<f64> = (0..n).map(|k| 3.0 - 2.5 * k as f64).collect();
            for i in [5usize, 333, 600] {
                let trig = path.pitch_phase(i);
                let mut cols = vec![Column::default(); n];
                e.columns(&path, i, &trig, &mut cols);
                let mut q = path.p_mm[i];
                let mut dd = 0.0;
                e.add_delta(&path, i, &trig, &theta, &mut q, &mut dd);
                let mut want = path.p_mm[i];
                let mut want_dd = 0.0;
                for (c, t) in cols.iter().zip(&theta) {
                    for k in 0..3 {
                        want[k] += t * c.dp_mm[k];
                    }
                    want_dd += t * c.dd_mm;
                }
                for k in 0..3 {
                    assert!((q[k] - want[k]).abs() < 1e-12, "{e} {i} {k}");
                }
                assert!((dd - want_dd).abs() < 1e-15, "{e}");
            }
        }
    }

    #[test]
    fn block_displacement_is_the_per_sample_one_bit_for_bit() {
        // The exact fit uses the block form; it must be the per-sample model exactly, so that
        // speed never changes a result.
        let path = circle(40.0, 700);
        let mut effects = Effect::all();
        effects.extend(Pair::ALL.map(Effect::ScaleMismatch));
        let set = EffectSet::new(effects);
        let theta: Vec<f64> = (0..set.n_params)
            .map(|k| 0.7 * k as f64 - 3.1 + (k as f64).sin())
            .collect();
        let (i0, len) = (97, 300);
        let mut q = vec![[f64::NAN; 3]; len];
        let mut dd = vec![f64::NAN; len];
        set.displaced_block(&path, i0, &theta, &mut q, &mut dd);
        let all = set.distances_mm(&path, &theta);
        assert_eq!(all.len(), path.len());
        for j in 0..len {
            let (want, want_d) = set.displaced(&path, i0 + j, &theta);
            assert_eq!(q[j], want, "sample {}", i0 + j);
            assert_eq!(dd[j].to_bits(), want_d.to_bits());
        }
        for (i, d) in all.iter().enumerate() {
            assert_eq!(d.to_bits(), set.distance_mm(&path, i, &theta).to_bits());
        }
    }

    #[test]
    fn direction_holds_through_a_standstill() {
        // x goes 0 → 1, stops, then 1 → 2: direction stays +1 during the stop.
        let t: Vec<f64> = (0..30).map(|i| i as f64).collect();
        let p: Vec<[f64; 3]> = (0..30)
            .map(|i| {
                let x = if i < 10 {
                    i as f64 * 0.1
                } else if i < 20 {
                    1.0
                } else {
                    1.0 + (i - 19) as f64 * 0.1
                };
                [x, 0.0, 0.0]
            })
            .collect();
        let path = Path::new(t, p, [None; 3]);
        assert!(path.dir.iter().all(|d| d[0] == 1), "{:?}", path.dir);
        assert!(path.dir.iter().all(|d| d[1] == 0));
        assert!(path.moves(Axis::X) && !path.moves(Axis::Y));
    }

    #[test]
    fn servo_mismatch_is_seen_with_opposite_sign_in_the_two_directions() {
        // On a circle δ·u from servo mismatch is −(Δτ/2)(u_x v_x − u_y v_y): reverses with direction.
        let path = circle(50.0, 100);
        let e = Effect::ServoMismatch(Pair::Xy);
        let mut c = [Column::default()];
        e.columns(&path, 40, &path.pitch_phase(40), &mut c);
        let p = path.p_mm[40];
        let u = [p[0] / 50.0, p[1] / 50.0, 0.0];
        let fwd = u[0] * c[0].dp_mm[0] + u[1] * c[0].dp_mm[1];
        let v = path.v_mm_s[40];
        let th = (p[1]).atan2(p[0]);
        // Expected: −(1/2)·1e-3·(u_x v_x − u_y v_y) = (1e-3/2)·R·ω·sin 2θ with ω = 0.5 rad/s.
        let expect = 0.5e-3 * 50.0 * 0.5 * (2.0 * th).sin();
        assert!((fwd - expect).abs() < 1e-6, "{fwd} {expect} {v:?}");
    }
}
