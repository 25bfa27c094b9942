//! The shared least-squares engine: Levenberg–Marquardt on accumulated normal equations.
//!
//! A [`Problem`] hands the engine one residual and its gradient at a time, so the engine builds
//! JᵀJ (n×n) and Jᵀr (n) without ever storing the m×n Jacobian: a million samples cost O(n²)
//! memory and one pass per iteration.
//!
//! Conditioning and rank. Columns are scaled to unit norm (D = diag(√(JᵀJ)ₖₖ)), and the scaled
//! normal matrix A = D⁻¹JᵀJD⁻¹ is eigen-decomposed. Its eigenvalues are the squared singular
//! values of the column-scaled Jacobian. A direction whose singular value is below
//! `rank_tolerance × s_max` (default 1e-7, i.e. condition number 1e7 of the scaled Jacobian, about
//! √ε of f64 so that the normal equations still carry ~8 good digits in what they keep) is
//! *undetermined*: the data does not fix that combination of parameters. Steps are taken only in
//! the determined subspace (so undetermined combinations stay where `p0` put them), the covariance
//! is s²(JᵀJ)⁺ on that subspace, and parameters touched by a null direction get no standard error.
//! A column that is exactly zero (the parameter does not influence any residual) is undetermined
//! on its own.
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
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the sum of squares by less than `tolerance` relative to
    /// it, or when the scaled step is shorter than `tolerance` (relative to the scaled parameters).
    pub tolerance: f64,
    /// Singular values of the column-scaled Jacobian below `rank_tolerance × s_max` count as zero.
    pub rank_tolerance: f64,
    /// Initial Marquardt damping, relative to the (unit) diagonal of the scaled normal matrix.
    pub initial_lambda: f64,
    /// A null direction names parameter k as undetermined when |v_k| ≥ this (v has unit norm).
    pub null_loading: f64,
}

impl Default for LsqOptions {
    fn default() -> Self {
        LsqOptions {
            max_iterations: 100,
            tolerance: 1e-12,
            rank_tolerance: 1e-7,
            initial_lambda: 1e-6,
            null_loading: 0.1,
        }
    }
}

/// The result of a fit, with the statistics needed to judge it.
#[derive(Debug, Clone)]
pub struct LsqFit {
    pub params: Vec<f64>,
    /// Standard errors; None for parameters in the undetermined null space.
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
    /// LM iterations used (passes over the data beyond the first, minus the final covariance pass).
    pub iterations: usize,
    /// Of the column-scaled Jacobian, descending.
    pub singular_values: Vec<f64>,
    /// Groups of parameter indices whose combinations the data does not determine.
    pub undetermined: Vec<Vec<usize>>,
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
            // memcpy call per residual, a measurable share of a pass.
            let mut k = 0;
            while k + 1 < n {
                row[k] = g[k];
                row[k + 1] = g[k + 1];
                k += 2;
            }
            if k < n {
                row[k] = g[k];
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
struct Spectrum {
    dead: Vec<bool>,
    scale: Vec<f64>,
    values: Vec<f64>,
    vectors: DMatrix<f64>,
    rank: usize,
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
    let mut a = jtj.clone();
    for i in 0..n {
        for j in 0..n {
            a[(i, j)] = if dead[i] || dead[j] {
                0.0
            } else {
                a[(i, j)] / (scale[i] * scale[j])
            };
        }
    }
    let eig = SymmetricEigen::new(a);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| eig.eigenvalues[j].total_cmp(&eig.eigenvalues[i]));
    let values: Vec<f64> = order.iter().map(|&i| eig.eigenvalues[i].max(0.0)).collect();
    let mut vectors = DMatrix::<f64>::zeros(n, n);
    for (c, &i) in order.iter().enumerate() {
        vectors.set_column(c, &eig.eigenvectors.column(i));
    }
    let smax = values.first().copied().unwrap_or(0.0).sqrt();
    let rank = values
        .iter()
        .filter(|&&v| smax > 0.0 && v.sqrt() > rank_tolerance * smax)
        .count();
    Spectrum {
        dead,
        scale,
        values,
        vectors,
        rank,
    }
}

/// Minimise Σ r_i(p)² from `p0` by Levenberg–Marquardt and report parameters, standard errors,
/// covariance, rank and the undetermined parameter groups. See the module docs for the rank rule.
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
    let mut lambda = opts.initial_lambda;
    let mut iterations = 0;
    while iterations < opts.max_iterations && n > 0 {
        iterations += 1;
        let sp = spectrum(&cur.jtj, opts.rank_tolerance);
        // Scaled gradient g = D⁻¹Jᵀr; step z = −Σ v (vᵀg)/(e + λ) over determined directions.
        let g: DVector<f64> = DVector::from_iterator(n, (0..n).map(|k| cur.jtr[k] / sp.scale[k]));
        let mut z = DVector::<f64>::zeros(n);
        for c in 0..sp.rank {
            let v = sp.vectors.column(c);
            let coef = v.dot(&g) / (sp.values[c] + lambda);
            z -= v * coef;
        }
        let step: Vec<f64> = (0..n).map(|k| z[k] / sp.scale[k]).collect();
        let trial: Vec<f64> = p.iter().zip(&step).map(|(a, b)| a + b).collect();
        let scaled_p_norm = (0..n)
            .map(|k| (p[k] * sp.scale[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        let small_step = z.norm() <= opts.tolerance * (scaled_p_norm + opts.tolerance);
        let next = accumulate(problem, &trial, true)?;
        if next.ssr <= cur.ssr {
            let reduction = cur.ssr - next.ssr;
            p = trial;
            cur = next;
            lambda = (lambda * 0.1).max(1e-15);
            if reduction <= opts.tolerance * cur.ssr || small_step || cur.ssr == 0.0 {
                break;
            }
        } else {
            if small_step {
                break;
            }
            lambda *= 10.0;
            if lambda > 1e16 {
                break;
            }
        }
    }
    finish(problem, p, cur, m, iterations, opts)
}

fn finish(
    _problem: &dyn Problem,
    p: Vec<f64>,
    cur: Normal,
    m: usize,
    iterations: usize,
    opts: &LsqOptions,
) -> Result<LsqFit> {
    let n = p.len();
    let sp = spectrum(&cur.jtj, opts.rank_tolerance);
    let dof = m.saturating_sub(sp.rank);
    let s2 = if dof > 0 { cur.ssr / dof as f64 } else { 0.0 };
    // (JᵀJ)⁺ = D⁻¹ (Σ_determined v vᵀ / e) D⁻¹.
    let mut cov = DMatrix::<f64>::zeros(n, n);
    for c in 0..sp.rank {
        let v = sp.vectors.column(c);
        let w = s2 / sp.values[c];
        for i in 0..n {
            for j in 0..n {
                cov[(i, j)] += w * v[i] * v[j];
            }
        }
    }
    for i in 0..n {
        for j in 0..n {
            cov[(i, j)] /= sp.scale[i] * sp.scale[j];
        }
    }
    // Undetermined groups. A dead column is a group of its own; the other groups come from the
    // null space of the live columns alone (a degenerate null space mixes its vectors
    // arbitrarily, which would otherwise tie a dead column to an unrelated group). Null
    // directions sharing a parameter are merged.
    let mut in_null = sp.dead.clone();
    let mut groups: Vec<Vec<usize>> = (0..n).filter(|&k| sp.dead[k]).map(|k| vec![k]).collect();
    let live: Vec<usize> = (0..n).filter(|&k| !sp.dead[k]).collect();
    if sp.rank < live.len() {
        let a = DMatrix::from_fn(live.len(), live.len(), |i, j| {
            cur.jtj[(live[i], live[j])] / (sp.scale[live[i]] * sp.scale[live[j]])
        });
        let eig = SymmetricEigen::new(a);
        let emax = eig.eigenvalues.iter().cloned().fold(0.0, f64::max);
        let thr = opts.rank_tolerance * opts.rank_tolerance * emax;
        let mut live_groups: Vec<Vec<usize>> = Vec::new();
        for (c, &e) in eig.eigenvalues.iter().enumerate() {
            if e > thr {
                continue;
            }
            let v = eig.eigenvectors.column(c);
            let members: Vec<usize> = (0..live.len())
                .filter(|&k| v[k].abs() >= opts.null_loading)
                .map(|k| live[k])
                .collect();
            if members.is_empty() {
                continue;
            }
            for &k in &members {
                in_null[k] = true;
            }
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
    }
    groups.sort();
    let sigma = (0..n)
        .map(|k| {
            if in_null[k] {
                None
            } else {
                Some(cov[(k, k)].max(0.0).sqrt())
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
        singular_values: sp.values.iter().map(|v| v.sqrt()).collect(),
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
}
