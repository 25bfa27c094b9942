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
    let mut jtj = DMatrix::<f64>::zeros(n, n);
    let mut jtr = DVector::<f64>::zeros(n);
    let mut ssr = 0.0;
    let mut finite = true;
    {
        let a = jtj.as_mut_slice(); // column-major; we fill the upper triangle (row ≤ col)
        let b = jtr.as_mut_slice();
        problem.eval(p, &mut |_i, r, g| {
            if !r.is_finite() {
                finite = false;
                return;
            }
            ssr += r * r;
            if with_jacobian {
                for (k, &gk) in g.iter().enumerate().take(n) {
                    if gk == 0.0 {
                        continue;
                    }
                    b[k] += gk * r;
                    let col = &mut a[k * n..k * n + k + 1];
                    for (c, &gj) in col.iter_mut().zip(g.iter()) {
                        *c += gj * gk;
                    }
                }
            }
        });
    }
    if !finite {
        return Err(Error::Numerics(
            "the model produced a non-finite residual; check the input for NaN or absurd values"
                .into(),
        ));
    }
    if with_jacobian {
        for k in 0..n {
            for j in 0..k {
                jtj[(k, j)] = jtj[(j, k)];
            }
        }
    }
    Ok(Normal { jtj, jtr, ssr })
}

/// Scaled eigen-structure of JᵀJ: scale D, eigenvalues (descending) and vectors of D⁻¹JᵀJD⁻¹.
struct Spectrum {
    scale: Vec<f64>,
    values: Vec<f64>,
    vectors: DMatrix<f64>,
    rank: usize,
}

fn spectrum(jtj: &DMatrix<f64>, rank_tolerance: f64) -> Spectrum {
    let n = jtj.nrows();
    let scale: Vec<f64> = (0..n)
        .map(|k| {
            let d = jtj[(k, k)].max(0.0).sqrt();
            if d > 0.0 {
                d
            } else {
                1.0
            }
        })
        .collect();
    let mut a = jtj.clone();
    for i in 0..n {
        for j in 0..n {
            a[(i, j)] /= scale[i] * scale[j];
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
        if std::env::var("LMTRACE").is_ok() { eprintln!("it {iterations} lambda {lambda:e} ssr {} -> {} rank {} z {:e}", cur.ssr, next.ssr, sp.rank, z.norm()); }
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
    // Undetermined groups: parameters loaded by null directions, merged when directions share one.
    let mut in_null = vec![false; n];
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for c in sp.rank..n {
        let v = sp.vectors.column(c);
        let members: Vec<usize> = (0..n).filter(|&k| v[k].abs() >= opts.null_loading).collect();
        if members.is_empty() {
            continue;
        }
        for &k in &members {
            in_null[k] = true;
        }
        let overlapping: Vec<usize> = (0..groups.len())
            .filter(|&g| groups[g].iter().any(|k| members.contains(k)))
            .collect();
        let mut merged = members;
        for &g in overlapping.iter().rev() {
            merged.extend(groups.remove(g));
        }
        merged.sort_unstable();
        merged.dedup();
        groups.push(merged);
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
