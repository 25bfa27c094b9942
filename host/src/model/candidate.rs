//! An effect as columns of the linear search (Candidate), a set of effects with values (EffectSet), and the exact model of D.
use super::*;

/// How the linear candidate search sees an effect: columns linear in the search parameters at
/// the nominal path, and the start of the exact refit from their coefficients. For a linear
/// effect the search parameters are the effect's own; a reversal spike is searched at a trial
/// decay time with h alone; a servo delay by its mismatch Δτ and the cross term q = τ̄·Δτ (ms²),
/// whose column is (a_i, −a_j)/2 (the first-order lag column, −τ̄·v, is dead on a circle).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub effect: Effect,
    /// The trial decay time of a reversal spike (ms); 0 for other effects.
    pub tau_ms: f64,
    /// The trial gap of a backlash (µm) whose dead band shapes its search column (the column
    /// is the dead band of this gap per µm); 0 searches a step.
    pub gap_um: f64,
}

impl Candidate {
    /// The search form of `effect` (a spike at 10 ms: use [`Candidate::spike`] for others).
    pub fn of(effect: Effect) -> Candidate {
        Candidate {
            effect,
            tau_ms: if matches!(effect, Effect::ReversalSpike(_)) {
                10.0
            } else {
                0.0
            },
            gap_um: 0.0,
        }
    }

    /// A backlash of axis `a` (uniform, or differing between the ends) searched with the dead
    /// band of a trial gap `gap_um` (a step if it is not positive).
    pub fn backlash(a: Axis, ends: bool, gap_um: f64) -> Candidate {
        Candidate {
            effect: if ends {
                Effect::BacklashEnds(a)
            } else {
                Effect::Backlash(a)
            },
            tau_ms: 0.0,
            gap_um: gap_um.max(0.0),
        }
    }

    /// A reversal spike of axis `a` at the trial decay time `tau_ms`.
    pub fn spike(a: Axis, tau_ms: f64) -> Candidate {
        Candidate {
            effect: Effect::ReversalSpike(a),
            tau_ms,
            gap_um: 0.0,
        }
    }

    /// Number of search columns.
    pub fn n_cols(&self) -> usize {
        match self.effect {
            Effect::ReversalSpike(_) | Effect::BacklashEnds(_) => 1,
            e => e.n_params(),
        }
    }

    /// The exact model's parameters from the search coefficients `coef` (length `n_cols`; a
    /// column the data could not determine is given as 0).
    pub fn start(&self, coef: &[f64]) -> Vec<f64> {
        match self.effect {
            Effect::ReversalSpike(_) => vec![coef[0], self.tau_ms],
            // Searched by the difference pos − neg alone (the mean is `Backlash`'s; the
            // diagnosis merges the two): exact (pos, neg) = (±difference/2).
            Effect::BacklashEnds(_) => vec![0.5 * coef[0], -0.5 * coef[0]],
            Effect::ServoMismatch(_) => {
                let lag = if coef[0].abs() > 1e-6 {
                    (coef[1] / coef[0]).clamp(-50.0, 50.0)
                } else {
                    0.0
                };
                vec![coef[0], lag]
            }
            _ => coef.to_vec(),
        }
    }

    /// The search columns at samples i0 + j for unit vectors `u[j]`: the change of D (µm) per
    /// unit of each search parameter (seed 000 eq. 1), written to `out[j·stride + offset + k]`.
    pub fn columns_block(
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
        match self.effect {
            Effect::SetupOffset => {
                for (j, o) in rows.enumerate() {
                    out[o..o + 3].copy_from_slice(&u[j].map(|x| -x));
                }
            }
            Effect::LengthOffset => {
                for o in rows {
                    out[o] = 1.0;
                }
            }
            Effect::Drift => {
                let t0 = path.t_s.first().copied().unwrap_or(0.0);
                let t = &path.t_s[i0..i0 + n];
                for (j, o) in rows.enumerate() {
                    out[o] = (t[j] - t0) / 60.0;
                }
            }
            Effect::FollowingError => {
                // Per ms²: δ = a·1e-6 mm = a·1e-3 µm along u.
                let acc = &path.a_mm_s2[i0..i0 + n];
                for (j, o) in rows.enumerate() {
                    out[o] =
                        1e-3 * (u[j][0] * acc[j][0] + u[j][1] * acc[j][1] + u[j][2] * acc[j][2]);
                }
            }
            Effect::Scale(a) => {
                let k = a.index();
                for (j, o) in rows.enumerate() {
                    out[o] = 1e-3 * u[j][k] * p[j][k];
                }
            }
            Effect::ScaleDrift(a) | Effect::PositionDrift(a) => {
                let k = a.index();
                let scale = matches!(self.effect, Effect::ScaleDrift(_));
                for (j, o) in rows.enumerate() {
                    let minutes = elapsed_min(path, i0 + j);
                    out[o] = u[j][k] * minutes * if scale { 1e-3 * p[j][k] } else { 1.0 };
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
            Effect::Backlash(a) | Effect::BacklashEnds(a) => {
                // Per µm of gap: the dead band of the trial gap scaled to it, or the step
                // ∂δ/∂b = −s/2; the ends' column is ∂δ/∂(pos − neg) at the trial gap.
                let k = a.index();
                let g = self.gap_um;
                let ends = matches!(self.effect, Effect::BacklashEnds(_));
                for_each_dead_band(path, k, i0, n, g, g, |j, d, dpos, dneg| {
                    out[j * stride + offset] = u[j][k]
                        * if ends {
                            0.5 * (dpos - dneg)
                        } else if g > 0.0 {
                            d / g
                        } else {
                            dpos + dneg
                        };
                });
            }
            Effect::Straightness(a, b) => {
                let (i, jx) = (a.index(), b.index());
                let ends = travel_ends_mm(path, i);
                for (j, o) in rows.enumerate() {
                    out[o] = u[j][jx] * bow_shape(ends, p[j][i]);
                }
            }
            Effect::LateralPlay(a, b) => {
                let (i, jx) = (a.index(), b.index());
                let dir = &path.dir[i0..i0 + n];
                for (j, o) in rows.enumerate() {
                    out[o] = 0.5 * u[j][jx] * f64::from(dir[j][i]);
                }
            }
            Effect::Cyclic(a) | Effect::Interference(a) => {
                let k = a.index();
                let cyclic = matches!(self.effect, Effect::Cyclic(_));
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
                let acc = &path.a_mm_s2[i0..i0 + n];
                for (j, o) in rows.enumerate() {
                    out[o] = 0.5 * (u[j][b] * v[j][b] - u[j][a] * v[j][a]);
                    // q = τ̄·Δτ in ms²: δ = ±(q/2)·a·1e-6 mm = ±(q/2)·a·1e-3 µm.
                    out[o + 1] = 0.5e-3 * (u[j][a] * acc[j][a] - u[j][b] * acc[j][b]);
                }
            }
            Effect::ReversalSpike(ax) => {
                let k = ax.index();
                let tau = self.tau_ms.max(MIN_TAU_MS);
                for o in rows {
                    out[o] = 0.0;
                }
                for_each_spike(path, k, i0, n, |j, s, dt_ms| {
                    out[j * stride + offset] = -u[j][k] * s * decay(dt_ms / tau);
                });
            }
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
}

impl EffectSet {
    pub fn new(effects: Vec<Effect>) -> EffectSet {
        let mut offsets = Vec::with_capacity(effects.len());
        let mut n = 0;
        for e in &effects {
            offsets.push(n);
            n += e.n_params();
        }
        EffectSet {
            effects,
            offsets,
            n_params: n,
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
        let mut q = [[0.0; 3]];
        let mut d = [0.0];
        self.displaced_block(path, i, theta, &mut q, &mut d);
        (q[0], d[0])
    }

    /// [`EffectSet::displaced`] for samples i0..i0 + q.len() at once: writes p + δ + c (mm) to
    /// `q[j]` and e (mm) to `dd[j]` for sample i0 + j.
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

impl crate::numerics::lsq::Problem for ExactModel<'_> {
    fn n_params(&self) -> usize {
        self.set.n_params
    }
    fn n_residuals(&self) -> usize {
        self.d_mm.len()
    }
    fn eval(&self, theta: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        // The gradient of |q| with respect to a parameter is u·∂δ/∂θ with u = q/|q|, evaluated
        // at the displaced position a block of samples at a time.
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
                e.gradient_block(
                    self.path,
                    i0,
                    &theta[o..o + e.n_params()],
                    &u,
                    &mut grads,
                    n,
                    o,
                );
            }
            for j in 0..len {
                visit(i0 + j, res[j], &grads[j * n..(j + 1) * n]);
            }
            i0 += len;
        }
    }
}
