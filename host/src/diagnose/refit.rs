//! After the selection: what an arc cannot carry, the set-up and the exact refit of the effects found, the following error's confounding.
use super::*;

/// On a partial arc, a candidate that keeps less than this fraction of its column's norm² once
/// the set-up's columns (table-ball offset, length offset) and, for all but the scales, the
/// scale candidates' columns are projected out is named in [`Diagnosis::weak_on_arc`] with what
/// it resembles. On a full circle every candidate keeps 10 % or more (a bowed axis, u_k·p_k² ∝
/// cos³θ, keeps its cos 3θ part, 10 %). On the 220° vertical-plane test's 180° of data (0° to
/// 180°), the bow of the first axis towards the second (`straightness_i_j`, u_j·sin²θ = sin³θ:
/// nearly 1, sin θ and cos 2θ, i.e. set-up and scale mismatch) keeps 0.13 %: its σ is some 28
/// times what a shape of its own would have, and on simulated records (0.2 µm noise) it is
/// still found (8.10 ± 0.01 µm for 8.1 µm), while leaving it out named the bow as a scale
/// mismatch of −147 µm/m and two reversal spikes. So it is tried and said. The scale mismatch
/// keeps 4.9 % (σ 4.5 times a full circle's per sample), squareness 28 %, backlash 100 %.
pub const PARTIAL_ARC_MIN_FREE: f64 = 0.01;

/// On a partial arc, a candidate that keeps less than this fraction (see
/// [`PARTIAL_ARC_MIN_FREE`]) is not tried, and is named as confounded with what it resembles:
/// numerically nothing of it is its own (or it does not move on the data at all).
pub const PARTIAL_ARC_NONE: f64 = 1e-6;

/// The candidates (of `candidates`, by index into `design.cands`; a spike's trial decay times
/// count as one) that a partial arc barely tells from the set-up (columns `setup`) and the
/// scale: those keeping less than [`PARTIAL_ARC_MIN_FREE`] of themselves, each with the group
/// to report — its name and the columns that carry it (each at least a tenth of the largest part
/// of the projection), or its name alone where it does not move on the data — and the fraction
/// it keeps.
pub(super) fn weak_on_arc(
    design: &Design,
    candidates: &[usize],
    setup: &[usize],
) -> Vec<(usize, Vec<String>, f64)> {
    let mut out: Vec<(usize, Vec<String>, f64)> = vec![];
    let is_scale = |c: usize| {
        matches!(
            design.cands[c].effect,
            Effect::Scale(_) | Effect::ScaleMismatch(_)
        )
    };
    let scale_cols: Vec<usize> = candidates
        .iter()
        .filter(|&&c| is_scale(c))
        .flat_map(|&c| design.cols_of(c))
        .collect();
    for &c in candidates {
        let effect = design.cands[c].effect;
        if out
            .iter()
            .any(|(k, _, _)| design.cands[*k].effect == effect)
        {
            continue;
        }
        let mut base = setup.to_vec();
        if !is_scale(c) {
            base.extend(&scale_cols);
        }
        let setup = &base[..];
        let mut worst: Option<(f64, Vec<String>)> = None;
        // The first column: the effect's own (a cyclic error's sine and cosine are alike; a
        // servo delay's second, the common lag, is held where one circle cannot carry it).
        for col in design.cols_of(c).into_iter().take(1) {
            let norm2 = design.gram[(col, col)];
            let (free, names) = if norm2 <= 0.0 {
                (0.0, vec![])
            } else {
                match solve(&design.gram, setup, norm2, col) {
                    Some((beta, ssr, _)) => {
                        let parts: Vec<f64> = setup
                            .iter()
                            .zip(&beta)
                            .map(|(&j, b)| (b * b * design.gram[(j, j)]).sqrt())
                            .collect();
                        let big = parts.iter().copied().fold(0.0, f64::max);
                        let names = setup
                            .iter()
                            .zip(&parts)
                            .filter(|(_, &p)| p >= 0.1 * big)
                            .map(|(&j, _)| design.col_name(j))
                            .collect();
                        ((ssr / norm2).max(0.0), names)
                    }
                    None => (1.0, vec![]),
                }
            };
            if worst.as_ref().is_none_or(|(w, _)| free < *w) {
                worst = Some((free, names));
            }
        }
        if let Some((free, names)) = worst {
            if free < PARTIAL_ARC_MIN_FREE {
                let mut group = vec![effect.name()];
                group.extend(names);
                out.push((c, group, free));
            }
        }
    }
    out
}

/// The fitted set-up [t_x, t_y, t_z, e] (µm) of `found`: its `setup_offset` (where the table
/// ball is relative to where it was assumed) and `length_offset`; 0 for one not there.
pub(super) fn fitted_setup_um(found: &[Found]) -> [f64; 4] {
    let mut s = [0.0; 4];
    for f in found {
        match f.effect {
            Effect::SetupOffset => s[..3].copy_from_slice(&f.params[..3]),
            Effect::LengthOffset => s[3] = f.params[0],
            _ => {}
        }
    }
    s
}

impl Diagnosis {
    /// The fitted set-up [t_x, t_y, t_z, e] (µm): where the table ball is relative to where it
    /// was assumed, and the bar's length offset. The one centre of every output: removed from
    /// the plotted deviations, said in the text as the move that centres the ball.
    pub fn fitted_setup_um(&self) -> [f64; 4] {
        fitted_setup_um(&self.effects)
    }
}

/// The measured traces of a diagnosis, to take an effect out of.
pub(super) struct Traces<'a> {
    pub(super) path: &'a Path,
    pub(super) angle: &'a [f64],
    pub(super) meas: &'a [f64],
    pub(super) circles: &'a [Circle],
    pub(super) runs: &'a [Run],
}

impl Traces<'_> {
    /// The test's G (µm: the largest minimum-zone G over circles and directions) of the measured
    /// traces with the radial deviation the effects `group` of `found` make alone taken out:
    /// what G would be without them.
    pub(super) fn g_without_um(&self, found: &[Found], group: &[usize]) -> Result<f64> {
        let mut dev = self.meas.to_vec();
        for f in group.iter().map(|&k| &found[k]) {
            let d = EffectSet::new(vec![f.effect]).distances_mm(self.path, &f.params);
            for ((v, p), d) in dev.iter_mut().zip(&self.path.p_mm).zip(&d) {
                *v -= 1e3 * (d - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt());
            }
        }
        let zones = circle_zones(self.path, self.angle, &dev, self.circles, self.runs)?;
        Ok(zones.iter().map(CircleZone::g_um).fold(0.0, f64::max))
    }
}

/// What the test tells of the position loops' following error ([`Effect::FollowingError`]): its
/// column −q·v²/R per circle against the set-up's length offset (one circle at one feed cannot
/// tell them: not searched) and against the isotropic scale a·R (on circles of two radii at one
/// feed, or of any radii at one angular speed, the three are collinear). Where the scale cannot
/// be told from it, the following error is searched and the scale is not (a loop is always
/// there at feed, a scale error may not be; the pair is named as confounded), so identical loops
/// on two radii are not read as a scale. A feed sweep separates them.
pub(super) struct FollowingConfounding {
    /// Whether the following error is a search candidate.
    pub(super) searched: bool,
    /// Whether it hides the isotropic scale (search the scale mismatches instead).
    pub(super) hides_scale: bool,
    /// The groups to name as confounded.
    pub(super) groups: Vec<Vec<String>>,
}

pub(super) fn following_error_confounding(
    design: &Design,
    path: &Path,
    runs: &[Run],
    scale_cols: &[usize],
) -> FollowingConfounding {
    let none = FollowingConfounding {
        searched: false,
        hides_scale: false,
        groups: vec![],
    };
    if !design
        .cands
        .iter()
        .any(|c| c.effect == Effect::FollowingError)
    {
        return none;
    }
    let scale_axes: Vec<usize> = design
        .cands
        .iter()
        .filter_map(|c| match c.effect {
            Effect::Scale(a) => Some(a.index()),
            _ => None,
        })
        .collect();
    let (free_setup, free_scale) = following_free_by_runs(path, runs, &scale_axes);
    // One circle at one feed (every run one radius and one speed): the following error is a
    // length offset there, which the set-up's bar length takes (not named as a group: the
    // isotropic scale's group with the length offset already says what one circle cannot tell).
    if free_setup < FOLLOWING_MIN_FREE {
        return none;
    }
    if scale_cols.is_empty() {
        return FollowingConfounding {
            searched: true,
            ..none
        };
    }
    let hides_scale = free_scale < FOLLOWING_MIN_FREE;
    let mut group = vec![design.col_name(3)]; // the length offset
    group.extend(scale_cols.iter().map(|&i| design.col_name(i)));
    group.push(Effect::FollowingError.name());
    FollowingConfounding {
        searched: true,
        hides_scale,
        groups: if hides_scale { vec![group] } else { vec![] },
    }
}

/// How much of the following error the runs of the test tell from the length offset and from
/// the isotropic scale: per run (one circle, one direction, one speed) the mean of the following
/// error's column (−u·a = v²/R on a circle, taken from the speed) and of the isotropic scale's (Σ u_k·p_k over
/// `scale_axes`, R on a circle), weighted by the run's samples; returns the fraction of the
/// following error's sum of squares left once a constant is fitted, and once a constant and the
/// scale are. Run means, not samples: within a run both are constants of the circle, and what
/// varies there (the timeline's numerics, ramps at the ends of a run) is no evidence of a radius
/// or a feed.
pub(super) fn following_free_by_runs(
    path: &Path,
    runs: &[Run],
    scale_axes: &[usize],
) -> (f64, f64) {
    let mut rows: Vec<(f64, f64, f64)> = vec![]; // (weight, scale, following)
    for run in runs {
        let n = run.range.len();
        if n == 0 {
            continue;
        }
        let (mut fe, mut sc) = (0.0, 0.0);
        for i in run.range.clone() {
            let p = path.p_mm[i];
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            if r <= 0.0 {
                continue;
            }
            // −u·a on a circle, from the speed: v²/D (v²/R in the ball's plane). A hand-made
            // path that turns from ccw to cw within one sample has an acceleration of v/dt
            // there, which would move a run's mean u·a by a sixth.
            let v = path.v_mm_s[i];
            fe += (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) / r;
            sc += scale_axes.iter().map(|&k| p[k] * p[k]).sum::<f64>() / r;
        }
        rows.push((n as f64, sc / n as f64, fe / n as f64));
    }
    let w: f64 = rows.iter().map(|r| r.0).sum();
    let yy: f64 = rows.iter().map(|r| r.0 * r.2 * r.2).sum();
    if w <= 0.0 || yy <= 0.0 {
        return (0.0, 0.0);
    }
    let mean =
        |f: &dyn Fn(&(f64, f64, f64)) -> f64| rows.iter().map(|r| r.0 * f(r)).sum::<f64>() / w;
    let (mx, my) = (mean(&|r| r.1), mean(&|r| r.2));
    let sxx = mean(&|r| (r.1 - mx) * (r.1 - mx)) * w;
    let sxy = mean(&|r| (r.1 - mx) * (r.2 - my)) * w;
    let syy = mean(&|r| (r.2 - my) * (r.2 - my)) * w;
    let left = if sxx > 1e-12 * mx * mx * w {
        syy - sxy * sxy / sxx
    } else {
        syy
    };
    ((syy / yy).max(0.0), (left / yy).max(0.0))
}

/// The following error is taken as confounded where the runs leave less than this fraction of
/// its sum of squares unexplained ([`following_free_by_runs`]): circles of two radii at one feed
/// left 10⁻¹⁵ and below in the tests (only the feed read per circle differs), a feed sweep of
/// two radii at 1000 and 3000 mm/min 0.33.
pub(super) const FOLLOWING_MIN_FREE: f64 = 1e-6;

/// The set-up's distance |p − c| + e (mm) for `setup_um` = [c_x, c_y, c_z, e] in µm (c: where
/// the table ball is relative to where it was assumed).
pub(super) fn setup_distance_mm(p: [f64; 3], setup_um: &[f64]) -> f64 {
    let q = [
        p[0] - 1e-3 * setup_um[0],
        p[1] - 1e-3 * setup_um[1],
        p[2] - 1e-3 * setup_um[2],
    ];
    (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + 1e-3 * setup_um[3]
}

/// D = |p − c| + e with only the set-up parameters `free` (indices into c_x, c_y, c_z, e)
/// varying, from `start` (the others held at 0); returns [c_x, c_y, c_z, e] in µm. Gauss–Newton
/// on the normal equations (at most four parameters, one pass over the samples each step): the
/// problem is linear but for the sphere's curvature over micrometres, so it converges in two or
/// three steps.
pub(super) fn fit_setup(
    path: &Path,
    d_mm: &[f64],
    free: &[usize],
    start: &[f64; 4],
) -> Result<Vec<f64>> {
    let k = free.len();
    let mut full = [0.0; 4];
    for &i in free {
        full[i] = start[i];
    }
    if k == 0 {
        return Ok(full.to_vec());
    }
    for _ in 0..30 {
        let mut jtj = DMatrix::<f64>::zeros(k, k);
        let mut jtr = nalgebra::DVector::<f64>::zeros(k);
        let mut g = [0.0; 4];
        for (q0, d) in path.p_mm.iter().zip(d_mm) {
            let q = [
                q0[0] - 1e-3 * full[0],
                q0[1] - 1e-3 * full[1],
                q0[2] - 1e-3 * full[2],
            ];
            let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
            let all = [-q[0] / r, -q[1] / r, -q[2] / r, 1.0];
            for (a, &c) in free.iter().enumerate() {
                g[a] = all[c];
            }
            let res = 1e3 * (r - d) + full[3];
            for a in 0..k {
                jtr[a] += g[a] * res;
                for b in 0..=a {
                    jtj[(a, b)] += g[a] * g[b];
                }
            }
        }
        for a in 0..k {
            for b in 0..a {
                jtj[(b, a)] = jtj[(a, b)];
            }
        }
        let step = jtj.cholesky().map(|c| c.solve(&jtr)).ok_or_else(|| {
            Error::Numerics("the set-up fit is singular: the path does not determine it".into())
        })?;
        let mut largest = 0.0f64;
        for (a, &c) in free.iter().enumerate() {
            full[c] -= step[a];
            largest = largest.max(step[a].abs());
        }
        if !largest.is_finite() {
            return Err(Error::Numerics("the set-up fit did not converge".into()));
        }
        // Gauss–Newton here converges linearly at the rate residual/radius (µm over tens of
        // mm, 10⁻³ at most): after a step under 1 nm the next would be under 10⁻⁶ µm.
        if largest < 1e-3 {
            break;
        }
    }
    Ok(full.to_vec())
}

/// Exact-geometry fit of `set` with only parameters `free` varying (others held at `start`).
/// Returns (θ, σ, covariance, SSR in µm²).
#[allow(clippy::type_complexity)]
pub(super) fn fit_exact(
    path: &Path,
    d_mm: &[f64],
    set: &EffectSet,
    free: &[usize],
    start: &[f64],
    tolerance: f64,
) -> Result<(Vec<f64>, Vec<Option<f64>>, DMatrix<f64>, f64)> {
    let model = ExactModel { path, d_mm, set };
    let restricted = Subset {
        inner: &model,
        free,
        base: start,
    };
    let p0: Vec<f64> = free.iter().map(|&i| start[i]).collect();
    let opts = LsqOptions {
        max_iterations: 50,
        tolerance,
        ..Default::default()
    };
    let fit = least_squares(&restricted, &p0, &opts)?;
    let n = set.n_params;
    let mut theta = start.to_vec();
    let mut sig = vec![None; n];
    let mut cov = DMatrix::zeros(n, n);
    for (a, &i) in free.iter().enumerate() {
        theta[i] = fit.params[a];
        sig[i] = fit.sigma[a];
        for (b, &j) in free.iter().enumerate() {
            cov[(i, j)] = fit.covariance[(a, b)];
        }
    }
    Ok((theta, sig, cov, fit.ssr))
}
