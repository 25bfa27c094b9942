//! The shared least-squares engine: Levenberg–Marquardt on accumulated normal equations.
//!
//! A [`Problem`] hands the engine one residual and its gradient at a time, so the engine builds
//! JᵀJ (n×n) and Jᵀr (n) without ever storing the m×n Jacobian: a million samples cost O(n²)
//! memory and one pass per iteration. Every fit of the crate goes through [`least_squares`]
//! (the diagnosis, the rotary-axis errors, the RRSPS identification and synthesis).
//!
//! **Scaling and damping.** Columns are scaled to unit norm, D = diag(√(JᵀJ)ₖₖ), and the engine
//! works with A = D⁻¹JᵀJD⁻¹ (unit diagonal) and g = D⁻¹Jᵀr. A step solves (A + λI) z = −g, h = D⁻¹z,
//! which is Marquardt's (JᵀJ + λ·diag JᵀJ) h = −Jᵀr: the damping is relative to each parameter's
//! own curvature, whatever its unit. λ starts at `initial_lambda` × the smallest *determined*
//! eigenvalue of A (the unit diagonal is the largest scale of A, so on a well-conditioned
//! problem this is Nielsen's τ·max diag A; on one with a weakly determined direction it does
//! not freeze that direction under a damping a million times its curvature) and follows
//! Nielsen's gain-ratio rule (Madsen, Nielsen & Tingleff, *Methods for non-linear least squares
//! problems*, 2004, eq. 3.15 ff.): with ρ = actual / predicted reduction of the sum of squares,
//! an accepted step sets λ ← λ·max(1/3, 1 − (2ρ − 1)³), ν ← 2; a rejected one λ ← λν, ν ← 2ν.
//! A rejected step is first given a second chance (a watchdog, Chamberlain et al. 1982): in a
//! curved valley the step goes the right way along the valley but leaves its floor, so the
//! trial point's own Gauss-Newton step, which puts the determined combinations back on the
//! floor, is added, and the pair is accepted if together they lower the sum of squares (one
//! more pass, counted as an iteration).
//!
//! **Rank.** A = Σ e_c v_c v_cᵀ (eigen-decomposition); √e_c are the singular values of the
//! column-scaled Jacobian. A direction with √e_c ≤ τ·√e_max, τ = [`LsqOptions::rank_tolerance`],
//! is *undetermined*: the data do not fix that combination of parameters. The default τ = 1e-7 is
//! the numerical floor of the normal equations: JᵀJ and its computed eigenvalues carry absolute
//! errors of a few ε·e_max (ε = 2.2e-16), so singular values below √(few ε) ≈ 1e-7 of the largest
//! are round-off, not information. A problem that knows a weak combination is meaningless to
//! it — a standard error along it far beyond any useful size, a valley too curved to linearise —
//! raises τ and says why (the RRSPS identification does). Steps are taken only in the
//! determined subspace, so an undetermined combination stays where `p0` put it (the minimum-norm
//! step) instead of the damped iteration creeping along a flat, curved valley; the covariance is
//! s²(JᵀJ)⁺ on that subspace (s² = ssr / dof).
//!
//! **Null loading.** A parameter is undetermined as soon as a null direction moves it
//! appreciably, even if that direction is mostly made of other parameters. For parameter k let
//! σ_det,k = s·√(Σ_determined v_kc²/e_c)/d_k be its standard error from the determined directions.
//! A null direction c has √e_c ≤ τ√e_max, so it adds at least s·|v_kc|/(τ√e_max)/d_k: a lower
//! bound of what the data leave open. Parameter k is undetermined — `sigma` None, and listed in
//! the group of that direction — when √(Σ_null v_kc²)/(τ√e_max) > `null_loading` × √(Σ_det v_kc²/e_c),
//! i.e. when what is left open is at least `null_loading` (default 1) times what is determined.
//! A parameter below that still gets the open part added to its standard error, so its σ never
//! claims more than the data give: σ_k² = σ_det,k² + s²·Σ_null v_kc²/(τ²e_max d_k²).
//! Round-off alone cannot trigger it: an eigenvector error mixes a null direction with a
//! determined one r by at most ε·e_max/e_r, which gives a ratio of at most ε/τ² ≈ 0.02 at τ = 1e-7.
//! A column that is (numerically) zero — the parameter acts on no residual — is a group of its own.
use nalgebra::{DMatrix, DVector, SymmetricEigen};

use crate::{Error, Result};

/// A least-squares problem: m residuals in n parameters.
pub trait Problem {
    fn n_params(&self) -> usize;
    fn n_residuals(&self) -> usize;
    /// Call `visit(i, r_i, grad_i)` for every residual i, where grad_i[k] = d r_i / d p_k.
    /// Lets the engine accumulate JᵀJ and Jᵀr without storing J (1e6 samples fit in O(n²) memory).
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64]));
}

/// Knobs of [`least_squares`].
#[derive(Debug, Clone)]
pub struct LsqOptions {
    /// Give up after this many accepted-or-rejected LM iterations (each is one pass over the data).
    /// 0 evaluates the statistics at `p0` without stepping.
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the sum of squares by less than `tolerance` relative to
    /// it, or when the scaled step is shorter than `tolerance` (relative to the scaled parameters).
    pub tolerance: f64,
    /// τ: singular values of the column-scaled Jacobian at or below τ × the largest count as zero
    /// (module docs, **Rank**). Default 1e-7, the numerical floor of the normal equations.
    pub rank_tolerance: f64,
    /// Initial damping λ₀ relative to the smallest determined eigenvalue of the scaled normal
    /// matrix (module docs, **Scaling and damping**; 1e-6 for a start near the answer, larger
    /// for a far one).
    pub initial_lambda: f64,
    /// A parameter is undetermined when the lower bound of its standard error from null
    /// directions exceeds `null_loading` × its standard error from determined ones (module docs,
    /// **Null loading**). Default 1.
    pub null_loading: f64,
}

impl Default for LsqOptions {
    fn default() -> Self {
        LsqOptions {
            max_iterations: 100,
            tolerance: 1e-12,
            rank_tolerance: 1e-7,
            initial_lambda: 1e-6,
            null_loading: 1.0,
        }
    }
}

/// The result of a fit, with the statistics needed to judge it.
#[derive(Debug, Clone)]
pub struct LsqFit {
    pub params: Vec<f64>,
    /// Standard errors: √(covariance_kk + s²·Σ_undetermined u_kc²/(τ²e_max)), the determined part
    /// plus the least the undetermined directions leave open (module docs, **Null loading**);
    /// None for parameters that load on an undetermined direction.
    pub sigma: Vec<Option<f64>>,
    /// s² (JᵀJ)⁺ on the determined subspace, s² = ssr / dof.
    pub covariance: DMatrix<f64>,
    /// Sum of squared residuals at `params`.
    pub ssr: f64,
    /// √(ssr / m).
    pub rms: f64,
    /// m − rank.
    pub dof: usize,
    pub n_residuals: usize,
    /// LM iterations used (each one pass over the data with gradients).
    pub iterations: usize,
    /// The stopping rule was met (false: `max_iterations` ran out, or no step could lower the
    /// sum of squares even at the largest damping).
    pub converged: bool,
    /// Of the column-scaled Jacobian, descending.
    pub singular_values: Vec<f64>,
    /// Number of determined directions (singular values above the rank threshold).
    pub rank: usize,
    /// Column c: the parameter-space direction of `singular_values[c]` in the parameters' own
    /// units (D⁻¹v_c). Columns `rank..` span the undetermined combinations.
    pub directions: DMatrix<f64>,
    /// Groups of parameter indices whose combinations the data does not determine.
    pub undetermined: Vec<Vec<usize>>,
}

/// `inner` with only the parameters `free` varying and the others held at their values in
/// `base`: for fitting a subset of a model's parameters (the diagnosis' set-up and refit).
pub struct Subset<'a> {
    /// The full problem.
    pub inner: &'a dyn Problem,
    /// Indices of the parameters that vary, in the order of the subset's parameters.
    pub free: &'a [usize],
    /// Values of all parameters; those not in `free` are held there.
    pub base: &'a [f64],
}

impl Problem for Subset<'_> {
    fn n_params(&self) -> usize {
        self.free.len()
    }
    fn n_residuals(&self) -> usize {
        self.inner.n_residuals()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let mut full = self.base.to_vec();
        for (a, &i) in self.free.iter().enumerate() {
            full[i] = p[a];
        }
        let mut g = vec![0.0; self.free.len()];
        self.inner.eval(&full, &mut |i, r, grad| {
            for (a, &k) in self.free.iter().enumerate() {
                g[a] = grad[k];
            }
            visit(i, r, &g);
        });
    }
}

/// Normal equations accumulated in one pass.
struct Normal {
    jtj: DMatrix<f64>,
    jtr: DVector<f64>,
    ssr: f64,
}

fn accumulate(problem: &dyn Problem, p: &[f64], with_jacobian: bool) -> Result<Normal> {
    let n = p.len();
    // Rows [g, r] go through the blocked Gram accumulator: [JᵀJ Jᵀr; rᵀJ rᵀr].
    let mut acc = GramAccumulator::new(n + 1);
    let mut ssr = 0.0;
    let mut finite = true;
    problem.eval(p, &mut |_i, r, g| {
        if !r.is_finite() {
            finite = false;
            return;
        }
        if with_jacobian {
            let row = acc.row();
            // Element by element in pairs: a slice copy of a few numbers would be a libc
            // memcpy call per residual, a measurable share of a pass. Both sides are cut to n
            // first so the loop runs without bounds checks.
            let (dst, src) = (&mut row[..n], &g[..n]);
            let mut k = 0;
            while k + 1 < n {
                dst[k] = src[k];
                dst[k + 1] = src[k + 1];
                k += 2;
            }
            if k < n {
                dst[k] = src[k];
            }
            row[n] = r;
        } else {
            ssr += r * r;
        }
    });
    if !finite {
        return Err(Error::Numerics(
            "the model produced a non-finite residual; check the input for NaN or absurd values"
                .into(),
        ));
    }
    if !with_jacobian {
        return Ok(Normal {
            jtj: DMatrix::zeros(n, n),
            jtr: DVector::zeros(n),
            ssr,
        });
    }
    let g = acc.finish();
    if g.iter().any(|x| !x.is_finite()) {
        // A derivative that overflowed (an absurd input far from the model's range): its
        // normal equations mean nothing, and every column would count as dead.
        return Err(Error::Numerics(
            "the model's derivatives are not finite; check the input for absurd values".into(),
        ));
    }
    Ok(Normal {
        jtj: g.view((0, 0), (n, n)).into_owned(),
        jtr: g.view((0, n), (n, 1)).column(0).into_owned(),
        ssr: g[(n, n)],
    })
}

/// Accumulates the Gram matrix XᵀX of rows pushed one at a time, in blocks of rows multiplied
/// with nalgebra's matrix product (cache-blocked, vectorised): O(w²) memory for any number of
/// rows. Shared by the fit and the diagnosis' candidate search.
pub struct GramAccumulator {
    w: usize,
    block: DMatrix<f64>,
    filled: usize,
    gram: DMatrix<f64>,
}

impl GramAccumulator {
    /// Rows per block (and the most [`GramAccumulator::rows`] hands out at once).
    pub const ROWS: usize = 1024;

    /// An accumulator for rows of width `w`.
    pub fn new(w: usize) -> GramAccumulator {
        GramAccumulator {
            w,
            block: DMatrix::zeros(w, Self::ROWS),
            filled: 0,
            gram: DMatrix::zeros(w, w),
        }
    }

    /// The next row to fill (all `w` entries must be written).
    pub fn row(&mut self) -> &mut [f64] {
        if self.filled == Self::ROWS {
            self.flush();
        }
        let w = self.w;
        let start = self.filled * w;
        self.filled += 1;
        &mut self.block.as_mut_slice()[start..start + w]
    }

    /// The next `n` rows (n ≤ [`GramAccumulator::ROWS`]) to fill, row j at `[j·w, (j+1)·w)`;
    /// every entry must be written.
    pub fn rows(&mut self, n: usize) -> &mut [f64] {
        assert!(n <= Self::ROWS, "at most ROWS rows at once");
        if self.filled + n > Self::ROWS {
            self.flush();
        }
        let w = self.w;
        let start = self.filled * w;
        self.filled += n;
        &mut self.block.as_mut_slice()[start..start + n * w]
    }

    fn flush(&mut self) {
        if self.filled == 0 {
            return;
        }
        // The block stores rows as columns (w × ROWS, column-major): G += B·Bᵀ, with Bᵀ the
        // same buffer read with swapped strides (no copy).
        let w = self.w;
        let k = self.filled;
        let b = self.block.as_slice().as_ptr();
        let c = self.gram.as_mut_slice().as_mut_ptr();
        // SAFETY: B is w×k with row stride 1 and column stride w inside `block` (k ≤ ROWS);
        // Bᵀ is k×w over the same memory (row stride w, column stride 1), read only; C is the
        // w×w `gram`, column-major (row stride 1, column stride w), and does not alias `block`.
        unsafe {
            matrixmultiply::dgemm(
                w, k, w, 1.0, b, 1, w as isize, b, w as isize, 1, 1.0, c, 1, w as isize,
            );
        }
        self.filled = 0;
    }

    /// XᵀX of all rows pushed.
    pub fn finish(mut self) -> DMatrix<f64> {
        self.flush();
        self.gram
    }
}

/// Scaled eigen-structure of JᵀJ: scale D, eigenvalues (descending) and vectors of D⁻¹JᵀJD⁻¹.
/// Live columns are decomposed together; each dead column gets its own unit vector with
/// eigenvalue 0 at the end (a degenerate null space would otherwise mix a dead parameter into an
/// unrelated group).
struct Spectrum {
    dead: Vec<bool>,
    scale: Vec<f64>,
    values: Vec<f64>,
    vectors: DMatrix<f64>,
    rank: usize,
    /// Number of live columns (directions `n_live..` are the dead columns).
    n_live: usize,
}

fn spectrum(jtj: &DMatrix<f64>, rank_tolerance: f64) -> Spectrum {
    let n = jtj.nrows();
    // A column whose norm is below DEAD_COLUMN × the largest is treated as exactly zero: the
    // parameter does not act on the data (e.g. c_z on a flat circle, whose column is only
    // round-off once c_x, c_y have moved), and scaling it up to unit norm would amplify noise.
    const DEAD_COLUMN: f64 = 1e-10;
    let norms: Vec<f64> = (0..n).map(|k| jtj[(k, k)].max(0.0).sqrt()).collect();
    let dmax = norms.iter().cloned().fold(0.0, f64::max);
    let dead: Vec<bool> = norms.iter().map(|&d| d <= DEAD_COLUMN * dmax).collect();
    let scale: Vec<f64> = (0..n)
        .map(|k| if dead[k] { 1.0 } else { norms[k] })
        .collect();
    let live: Vec<usize> = (0..n).filter(|&k| !dead[k]).collect();
    let nl = live.len();
    let mut values = vec![0.0; n];
    let mut vectors = DMatrix::<f64>::zeros(n, n);
    // No live column (every parameter dead): nothing to decompose, and nalgebra's eigen
    // decomposition panics on an empty matrix.
    if nl > 0 {
        let a = DMatrix::from_fn(nl, nl, |i, j| {
            jtj[(live[i], live[j])] / (scale[live[i]] * scale[live[j]])
        });
        let eig = SymmetricEigen::new(a);
        let mut order: Vec<usize> = (0..nl).collect();
        order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
        for (c, &i) in order.iter().enumerate() {
            values[c] = eig.eigenvalues[i].max(0.0);
            for (r, &k) in live.iter().enumerate() {
                vectors[(k, c)] = eig.eigenvectors[(r, i)];
            }
        }
    }
    for (c, k) in (0..n).filter(|&k| dead[k]).enumerate() {
        vectors[(k, nl + c)] = 1.0;
    }
    let smax = values.first().copied().unwrap_or(0.0).sqrt();
    let rank = values[..nl]
        .iter()
        .filter(|&&v| smax > 0.0 && v.sqrt() > rank_tolerance * smax)
        .count();
    Spectrum {
        dead,
        scale,
        values,
        vectors,
        rank,
        n_live: nl,
    }
}

/// Minimise Σ r_i(p)² from `p0` by Levenberg–Marquardt in the determined subspace and report
/// parameters, standard errors, covariance, rank and the undetermined parameter groups. See the
/// module docs for the damping, the rank rule and the null-loading rule.
pub fn least_squares(problem: &dyn Problem, p0: &[f64], opts: &LsqOptions) -> Result<LsqFit> {
    let n = problem.n_params();
    let m = problem.n_residuals();
    if p0.len() != n {
        return Err(Error::Numerics(format!(
            "least_squares: {} start values for {} parameters",
            p0.len(),
            n
        )));
    }
    if m == 0 {
        return Err(Error::Numerics("least_squares: no residuals".into()));
    }
    let mut p = p0.to_vec();
    let mut cur = accumulate(problem, &p, true)?;
    let mut sp = spectrum(&cur.jtj, opts.rank_tolerance);
    // λ₀ relative to the smallest determined eigenvalue of A (the unit diagonal of A is its
    // largest scale): a damping that swamps no determined direction at the start, so a weakly
    // determined combination is not frozen by a λ a million times its curvature.
    let mut lambda = if sp.rank > 0 {
        opts.initial_lambda * sp.values[sp.rank - 1]
    } else {
        0.0
    };
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut converged = n == 0 || sp.rank == 0 || cur.ssr == 0.0;
    while !converged && iterations < opts.max_iterations {
        iterations += 1;
        let (z, step, predicted) = damped_step(&cur, &sp, lambda);
        if predicted <= f64::EPSILON * cur.ssr {
            // The gradient has no determined component left: a stationary point to rounding.
            converged = true;
            break;
        }
        let trial: Vec<f64> = p.iter().zip(&step).map(|(a, b)| a + b).collect();
        let scaled_p_norm = (0..n)
            .map(|k| (p[k] * sp.scale[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        let small_step = z.norm() <= opts.tolerance * (scaled_p_norm + opts.tolerance);
        let next = accumulate(problem, &trial, true)?;
        if next.ssr <= cur.ssr {
            let reduction = cur.ssr - next.ssr;
            let rho = reduction / predicted;
            p = trial;
            cur = next;
            sp = spectrum(&cur.jtj, opts.rank_tolerance);
            lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
            nu = 2.0;
            if reduction <= opts.tolerance * cur.ssr || small_step || cur.ssr == 0.0 {
                converged = true;
            }
        } else {
            if small_step {
                // Rounding decides between the current point and a step this short.
                converged = true;
                break;
            }
            // Curved valley: the step went the right way along a weakly determined, curved
            // combination but left the valley floor, so the sum of squares rose. The trial's own
            // Gauss-Newton step (undamped, in its determined subspace) brings the determined
            // combinations back onto the floor; accept the pair if together they go downhill
            // (a watchdog step, Chamberlain et al. 1982).
            if iterations < opts.max_iterations && next.ssr.is_finite() {
                iterations += 1;
                let sp_t = spectrum(&next.jtj, opts.rank_tolerance);
                let (_, back, _) = damped_step(&next, &sp_t, 0.0);
                let pair: Vec<f64> = trial.iter().zip(&back).map(|(a, b)| a + b).collect();
                let after = accumulate(problem, &pair, true)?;
                if after.ssr < cur.ssr {
                    let reduction = cur.ssr - after.ssr;
                    p = pair;
                    cur = after;
                    sp = spectrum(&cur.jtj, opts.rank_tolerance);
                    lambda /= 3.0;
                    if reduction <= opts.tolerance * cur.ssr || cur.ssr == 0.0 {
                        converged = true;
                    }
                    continue;
                }
            }
            lambda = lambda.max(f64::MIN_POSITIVE) * nu;
            nu *= 2.0;
            if lambda > 1e16 {
                break;
            }
        }
    }
    finish(p, cur, sp, m, iterations, converged, opts)
}

/// The damped step at the point of `cur`: scaled z, physical h = D⁻¹z, and the reduction of
/// the sum of squares the linear model predicts for it.
fn damped_step(cur: &Normal, sp: &Spectrum, lambda: f64) -> (DVector<f64>, Vec<f64>, f64) {
    let n = sp.scale.len();
    // Scaled gradient g = D⁻¹Jᵀr; in the eigenbasis its components are γ_c = v_cᵀg, the step
    // z = −Σ_determined v_c γ_c/(e_c + λ), and the predicted reduction of the sum of squares
    // −(2gᵀz + zᵀAz) = Σ γ_c² (e_c + 2λ)/(e_c + λ)².
    let g: DVector<f64> = DVector::from_iterator(n, (0..n).map(|k| cur.jtr[k] / sp.scale[k]));
    let mut z = DVector::<f64>::zeros(n);
    let mut predicted = 0.0;
    for c in 0..sp.rank {
        let v = sp.vectors.column(c);
        let gamma = v.dot(&g);
        let e = sp.values[c];
        z -= v * (gamma / (e + lambda));
        predicted += gamma * gamma * (e + 2.0 * lambda) / ((e + lambda) * (e + lambda));
    }
    let step = (0..n).map(|k| z[k] / sp.scale[k]).collect();
    (z, step, predicted)
}

fn finish(
    p: Vec<f64>,
    cur: Normal,
    sp: Spectrum,
    m: usize,
    iterations: usize,
    converged: bool,
    opts: &LsqOptions,
) -> Result<LsqFit> {
    let n = p.len();
    let dof = m.saturating_sub(sp.rank);
    let s2 = if dof > 0 { cur.ssr / dof as f64 } else { 0.0 };
    // Physical directions u_c = D⁻¹v_c; (JᵀJ)⁺ = Σ_determined u_c u_cᵀ / e_c.
    let directions = DMatrix::from_fn(n, n, |k, c| sp.vectors[(k, c)] / sp.scale[k]);
    let mut cov = DMatrix::<f64>::zeros(n, n);
    for c in 0..sp.rank {
        let u = directions.column(c);
        cov.ger(s2 / sp.values[c], &u, &u, 1.0);
    }
    // Null loading (module docs): scaled standard error from determined directions, squared,
    // against the lower bound of the null directions' share, 1/(τ²e_max) per unit loading².
    let floor =
        opts.rank_tolerance * opts.rank_tolerance * sp.values.first().copied().unwrap_or(0.0);
    let nl2 = opts.null_loading * opts.null_loading;
    let det2: Vec<f64> = (0..n)
        .map(|k| {
            (0..sp.rank)
                .map(|c| sp.vectors[(k, c)].powi(2) / sp.values[c])
                .sum()
        })
        .collect();
    let loads = |k: usize, c: usize| {
        let v2 = sp.vectors[(k, c)].powi(2);
        v2 > 0.0 && (floor <= 0.0 || v2 / floor > nl2 * det2[k])
    };
    let mut in_null = sp.dead.clone();
    let mut groups: Vec<Vec<usize>> = (0..n).filter(|&k| sp.dead[k]).map(|k| vec![k]).collect();
    let mut live_groups: Vec<Vec<usize>> = Vec::new();
    let null_dirs = sp.rank..sp.n_live;
    // Per parameter: the null directions' total share, and the direction it loads on most.
    for k in (0..n).filter(|&k| !sp.dead[k]) {
        let total: f64 = null_dirs.clone().map(|c| sp.vectors[(k, c)].powi(2)).sum();
        if total > 0.0 && (floor <= 0.0 || total / floor > nl2 * det2[k]) {
            in_null[k] = true;
        }
    }
    for c in null_dirs.clone() {
        let mut members: Vec<usize> = (0..n)
            .filter(|&k| !sp.dead[k] && in_null[k] && loads(k, c))
            .collect();
        // A parameter undetermined only through several null directions together joins the
        // group of the one it loads on most.
        for k in (0..n).filter(|&k| !sp.dead[k] && in_null[k] && !loads(k, c)) {
            let best = null_dirs
                .clone()
                .max_by(|&a, &b| {
                    sp.vectors[(k, a)]
                        .abs()
                        .total_cmp(&sp.vectors[(k, b)].abs())
                })
                .unwrap_or(c);
            if best == c && !null_dirs.clone().any(|d| loads(k, d)) {
                members.push(k);
            }
        }
        if members.is_empty() {
            continue;
        }
        // Null directions sharing a parameter are one group (a degenerate null space mixes its
        // vectors arbitrarily).
        let overlapping: Vec<usize> = (0..live_groups.len())
            .filter(|&g| live_groups[g].iter().any(|k| members.contains(k)))
            .collect();
        let mut merged = members;
        for &g in overlapping.iter().rev() {
            merged.extend(live_groups.remove(g));
        }
        merged.sort_unstable();
        merged.dedup();
        live_groups.push(merged);
    }
    groups.extend(live_groups);
    groups.sort();
    // A determined parameter still carries the least the null directions leave open.
    let sigma = (0..n)
        .map(|k| {
            if in_null[k] {
                None
            } else {
                let open: f64 = if floor > 0.0 {
                    null_dirs
                        .clone()
                        .map(|c| sp.vectors[(k, c)].powi(2))
                        .sum::<f64>()
                        / floor
                } else {
                    0.0
                };
                let var = cov[(k, k)] + s2 * open / (sp.scale[k] * sp.scale[k]);
                Some(var.max(0.0).sqrt())
            }
        })
        .collect();
    Ok(LsqFit {
        params: p,
        sigma,
        covariance: cov,
        ssr: cur.ssr,
        rms: (cur.ssr / m as f64).sqrt(),
        dof,
        n_residuals: m,
        iterations,
        converged,
        singular_values: sp.values.iter().map(|v| v.sqrt()).collect(),
        rank: sp.rank,
        directions,
        undetermined: groups,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocked_gram_equals_the_plain_sum() {
        let mut acc = GramAccumulator::new(3);
        let mut plain = DMatrix::<f64>::zeros(3, 3);
        // More rows than one block, and a partial last block.
        for i in 0..2 * GramAccumulator::ROWS + 77 {
            let x = [1.0, i as f64 * 0.01, (i as f64).sin()];
            acc.row().copy_from_slice(&x);
            for a in 0..3 {
                for b in 0..3 {
                    plain[(a, b)] += x[a] * x[b];
                }
            }
        }
        let g = acc.finish();
        assert!((&g - &plain).abs().max() <= 1e-12 * plain.abs().max());
    }

    /// Straight line y = a + b·x sampled at given x with given y.
    struct Line {
        x: Vec<f64>,
        y: Vec<f64>,
    }
    impl Problem for Line {
        fn n_params(&self) -> usize {
            2
        }
        fn n_residuals(&self) -> usize {
            self.x.len()
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for (i, (&x, &y)) in self.x.iter().zip(&self.y).enumerate() {
                visit(i, p[0] + p[1] * x - y, &[1.0, x]);
            }
        }
    }

    #[test]
    fn linear_fit_matches_closed_form_and_covariance() {
        // x = 0..4, y = 1, 3, 2, 5, 4: closed form b = Sxy/Sxx = 8/10, a = ȳ − b x̄ = 3 − 1.6.
        let prob = Line {
            x: vec![0.0, 1.0, 2.0, 3.0, 4.0],
            y: vec![1.0, 3.0, 2.0, 5.0, 4.0],
        };
        let fit = least_squares(&prob, &[0.0, 0.0], &LsqOptions::default()).unwrap();
        assert!((fit.params[0] - 1.4).abs() < 1e-10, "{:?}", fit.params);
        assert!((fit.params[1] - 0.8).abs() < 1e-10);
        // Residuals −0.4, 0.8, −1.0, 1.2, −0.6 → ssr 3.6, dof 3, s² 1.2.
        assert!((fit.ssr - 3.6).abs() < 1e-10);
        assert_eq!(fit.dof, 3);
        // Var(b) = s²/Sxx = 0.12, Var(a) = s²(1/n + x̄²/Sxx) = 1.2·0.6 = 0.72, Cov = −s² x̄/Sxx.
        assert!((fit.covariance[(1, 1)] - 0.12).abs() < 1e-10);
        assert!((fit.covariance[(0, 0)] - 0.72).abs() < 1e-10);
        assert!((fit.covariance[(0, 1)] + 0.24).abs() < 1e-10);
        assert!((fit.sigma[1].unwrap() - 0.12f64.sqrt()).abs() < 1e-10);
        assert!(fit.undetermined.is_empty());
    }

    /// Circle fit in the plane: r_i = |q_i − (cx, cy)| − R.
    struct Circle {
        q: Vec<(f64, f64)>,
    }
    impl Problem for Circle {
        fn n_params(&self) -> usize {
            3
        }
        fn n_residuals(&self) -> usize {
            self.q.len()
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for (i, &(x, y)) in self.q.iter().enumerate() {
                let (dx, dy) = (x - p[0], y - p[1]);
                let d = (dx * dx + dy * dy).sqrt();
                visit(i, d - p[2], &[-dx / d, -dy / d, -1.0]);
            }
        }
    }

    #[test]
    fn circle_fit_recovers_truth_from_a_far_start() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let (cx, cy, r) = (3.0, -2.0, 50.0);
        let q: Vec<(f64, f64)> = (0..400)
            .map(|i| {
                let t = i as f64 * 0.0157;
                let e = rng.gen_range(-1e-3..1e-3);
                (cx + (r + e) * t.cos(), cy + (r + e) * t.sin())
            })
            .collect();
        let fit = least_squares(&Circle { q }, &[0.0, 0.0, 40.0], &LsqOptions::default()).unwrap();
        assert!((fit.params[0] - cx).abs() < 1e-3, "{:?}", fit.params);
        assert!((fit.params[1] - cy).abs() < 1e-3);
        assert!((fit.params[2] - r).abs() < 1e-3);
        // Uniform noise on ±1e-3 has σ = 1e-3/√3; the fit's rms must be near that.
        let s = 1e-3 / 3f64.sqrt();
        assert!(fit.rms > 0.8 * s && fit.rms < 1.2 * s, "rms {}", fit.rms);
        assert!(fit.sigma.iter().all(|s| s.is_some()));
    }

    /// y = a + (b + c)·x + d·x²: only b + c is determined.
    struct Redundant;
    impl Problem for Redundant {
        fn n_params(&self) -> usize {
            4
        }
        fn n_residuals(&self) -> usize {
            20
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for i in 0..20 {
                let x = i as f64 / 4.0;
                let y = 1.0 + 2.0 * x - 0.5 * x * x;
                visit(
                    i,
                    p[0] + (p[1] + p[2]) * x + p[3] * x * x - y,
                    &[1.0, x, x, x * x],
                );
            }
        }
    }

    /// y = a + (b + c)·x with a fourth parameter that acts on nothing.
    struct RedundantAndDead;
    impl Problem for RedundantAndDead {
        fn n_params(&self) -> usize {
            4
        }
        fn n_residuals(&self) -> usize {
            20
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for i in 0..20 {
                let x = i as f64 / 4.0;
                visit(
                    i,
                    p[0] + (p[1] + p[2]) * x - (1.0 + 2.0 * x),
                    &[1.0, x, x, 0.0],
                );
            }
        }
    }

    #[test]
    fn a_dead_parameter_is_its_own_group_beside_a_confounded_pair() {
        let fit = least_squares(&RedundantAndDead, &[0.0; 4], &LsqOptions::default()).unwrap();
        assert_eq!(fit.undetermined, vec![vec![1, 2], vec![3]]);
        assert!(fit.sigma[0].is_some() && fit.sigma[3].is_none());
        assert_eq!(fit.params[3], 0.0);
    }

    #[test]
    fn rank_deficiency_names_the_undetermined_group() {
        let fit = least_squares(&Redundant, &[0.0; 4], &LsqOptions::default()).unwrap();
        assert_eq!(fit.undetermined, vec![vec![1, 2]]);
        assert!(fit.sigma[1].is_none() && fit.sigma[2].is_none());
        assert!(fit.sigma[0].is_some() && fit.sigma[3].is_some());
        // The determined combination and the other parameters are exact.
        assert!((fit.params[1] + fit.params[2] - 2.0).abs() < 1e-9);
        assert!((fit.params[0] - 1.0).abs() < 1e-9);
        assert!((fit.params[3] + 0.5).abs() < 1e-9);
        // Minimum-norm step from zero splits the sum evenly.
        assert!((fit.params[1] - fit.params[2]).abs() < 1e-9);
        assert_eq!(fit.singular_values.len(), 4);
        assert!(fit.singular_values[3] < 1e-7 * fit.singular_values[0]);
        assert!(fit.ssr < 1e-18);
    }

    /// A curved valley with a weakly determined direction, the shape of the RRSPS identification:
    /// y(t) = (p1 − p0²)·sin t + p2·cos t + δ·p0·t². The data fix A = p1 − p0² and p2 strongly,
    /// and p0 only through the small term δ·p0·t², so the valley p1 = p0² + A is a parabola along
    /// which the sum of squares changes by a relative singular value of order δ. The model is
    /// linear in (A, p2, C = δ·p0), so its global minimum is a linear least-squares problem.
    struct Valley {
        t: Vec<f64>,
        y: Vec<f64>,
        delta: f64,
    }
    impl Valley {
        fn new(delta: f64) -> Valley {
            use rand::{Rng, SeedableRng};
            let mut rng = rand::rngs::StdRng::seed_from_u64(11);
            let t: Vec<f64> = (0..400)
                .map(|i| i as f64 * std::f64::consts::TAU / 400.0)
                .collect();
            // Truth A = 2, B = −1, p0 = 3 (C = 3δ), noise ±0.01.
            let y = t
                .iter()
                .map(|&t| {
                    2.0 * t.sin() - t.cos() + 3.0 * delta * t * t + rng.gen_range(-0.01..0.01)
                })
                .collect();
            Valley { t, y, delta }
        }
        /// The global minimum of the sum of squares, from the linear problem in (A, B, C).
        fn min_ssr(&self) -> f64 {
            let x = DMatrix::from_fn(self.t.len(), 3, |i, j| {
                let t = self.t[i];
                [t.sin(), t.cos(), t * t][j]
            });
            let y = DVector::from_column_slice(&self.y);
            let c = x.clone().svd(true, true).solve(&y, 0.0).unwrap();
            (&x * c - y).norm_squared()
        }
    }
    impl Problem for Valley {
        fn n_params(&self) -> usize {
            3
        }
        fn n_residuals(&self) -> usize {
            self.t.len()
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for (i, (&t, &y)) in self.t.iter().zip(&self.y).enumerate() {
                let (s, c) = t.sin_cos();
                let m = (p[1] - p[0] * p[0]) * s + p[2] * c + self.delta * p[0] * t * t;
                visit(i, m - y, &[-2.0 * p[0] * s + self.delta * t * t, s, c]);
            }
        }
    }

    #[test]
    fn curved_valley_with_a_near_null_direction_converges_to_the_global_minimum() {
        // δ = 1e-6 gives a weak singular value ~5e-6 of the largest (the RRSPS case: ~1e-6), still
        // above the default rank threshold, so the engine must walk the parabola to its end; the
        // minimum lies far along it (p0 ≈ −35), where only the noise puts it.
        for delta in [1e-4, 1e-6] {
            let v = Valley::new(delta);
            let fit = least_squares(&v, &[1.0, 0.0, 0.0], &LsqOptions::default()).unwrap();
            let min = v.min_ssr();
            let weak = fit.singular_values[2] / fit.singular_values[0];
            assert!(weak < 1e-3 && weak > 1e-7, "δ {delta}: weak {weak:e}");
            assert!(
                fit.converged && fit.iterations <= 10,
                "δ {delta}: {} iterations",
                fit.iterations
            );
            assert!(
                (fit.ssr - min).abs() <= 1e-9 * min,
                "δ {delta}: ssr {} vs {min}",
                fit.ssr
            );
            // Determined, so every parameter has a standard error, and A = p1 − p0² is the truth.
            assert!(fit.undetermined.is_empty() && fit.sigma.iter().all(|s| s.is_some()));
            let a = fit.params[1] - fit.params[0] * fit.params[0];
            assert!((a - 2.0).abs() < 3e-3, "δ {delta}: A {a}");
        }
    }

    #[test]
    fn a_weak_direction_below_the_rank_tolerance_is_not_walked_and_has_no_sigma() {
        // The RRSPS configuration: τ = 1e-5 above the weak singular value. The fit stops on the
        // valley floor next to the start in a few iterations, names {p0, p1} undetermined and
        // leaves p2 (orthogonal to the valley) determined; the sum of squares is the global
        // minimum but for the noise along the one direction it did not fit.
        let v = Valley::new(1e-6);
        let opts = LsqOptions {
            rank_tolerance: 1e-5,
            ..LsqOptions::default()
        };
        let fit = least_squares(&v, &[1.0, 0.0, 0.0], &opts).unwrap();
        assert!(
            fit.converged && fit.iterations <= 10,
            "{} iterations",
            fit.iterations
        );
        assert_eq!(fit.rank, 2);
        assert_eq!(fit.undetermined, vec![vec![0, 1]]);
        assert!(fit.sigma[0].is_none() && fit.sigma[1].is_none() && fit.sigma[2].is_some());
        let min = v.min_ssr();
        assert!(
            fit.ssr >= min && fit.ssr <= 1.01 * min,
            "ssr {} vs {min}",
            fit.ssr
        );
        let a = fit.params[1] - fit.params[0] * fit.params[0];
        assert!((a - 2.0).abs() < 3e-3, "A {a}");
        // The undetermined direction is the valley's tangent (1, 2·p0, 0) in physical units.
        let u = fit.directions.column(2);
        assert!((u[1] / u[0] - 2.0 * fit.params[0]).abs() < 1e-3 * u[1].abs().max(1.0));
    }

    /// y = a + b·x + c·x² + d·(x + 0.03·x²): the exact null direction is d − b − 0.03·c, in
    /// which c takes a small share (scaled component ≈ 0.07, below the old fixed loading cut of
    /// 0.1) but enough to leave c without any determined value.
    struct SmallLoading;
    impl Problem for SmallLoading {
        fn n_params(&self) -> usize {
            4
        }
        fn n_residuals(&self) -> usize {
            30
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for i in 0..30 {
                let x = i as f64 / 7.0;
                let cols = [1.0, x, x * x, x + 0.03 * x * x];
                let y = 1.0 - x + 0.2 * x * x + 0.01 * (i as f64 * 1.7).sin();
                let m: f64 = cols.iter().zip(p).map(|(c, q)| c * q).sum();
                visit(i, m - y, &cols);
            }
        }
    }

    #[test]
    fn a_small_but_real_null_loading_takes_the_sigma_away() {
        let fit = least_squares(&SmallLoading, &[0.0; 4], &LsqOptions::default()).unwrap();
        assert_eq!(fit.rank, 3);
        // Along the null direction c moves 0.03 as much as b: a small but real share.
        let u = fit.directions.column(3);
        let ratio = (u[2] / u[1]).abs();
        assert!(
            (ratio - 0.03).abs() < 1e-6,
            "c/b along the null direction {ratio}"
        );
        assert_eq!(fit.undetermined, vec![vec![1, 2, 3]]);
        assert!(
            fit.sigma[2].is_none(),
            "c loads on the null direction: {:?}",
            fit.sigma
        );
        // The intercept does not load on it: its σ is finite and its value exact.
        assert!(fit.sigma[0].is_some());
        // With the loading rule switched off (an absurdly high ratio), c would get a σ: the
        // rule, not the rank, is what takes it away.
        let lax = LsqOptions {
            null_loading: 1e12,
            ..LsqOptions::default()
        };
        let fit = least_squares(&SmallLoading, &[0.0; 4], &lax).unwrap();
        assert!(fit.sigma[2].is_some());
    }

    /// Residuals whose derivatives are all `g` (the same for every parameter).
    struct Flat(f64);
    impl Problem for Flat {
        fn n_params(&self) -> usize {
            2
        }
        fn n_residuals(&self) -> usize {
            4
        }
        fn eval(&self, _p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for i in 0..4 {
                visit(i, 1.0, &[self.0, self.0]);
            }
        }
    }

    #[test]
    fn no_live_parameter_and_overflowed_derivatives_are_not_a_panic() {
        // Every column dead: nothing to decompose (nalgebra panics on an empty matrix).
        let fit = least_squares(&Flat(0.0), &[0.0; 2], &LsqOptions::default()).unwrap();
        assert_eq!(fit.rank, 0);
        assert!(fit.sigma.iter().all(Option::is_none));
        // A derivative that overflowed (an absurd input): an error that says so.
        let e = least_squares(&Flat(f64::INFINITY), &[0.0; 2], &LsqOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("not finite"), "{e}");
    }
}
