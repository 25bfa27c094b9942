//! The shared minimax (Chebyshev, L∞) engine: parameters that make the largest absolute residual
//! as small as possible — the "saddle point programming" of seed 004 (eq. 18, 19, 26).
//!
//! Works on the same [`Problem`] as the least-squares engine in [`super::lsq`].
//!
//! Method: sequential linear programming with a trust region. At p the residuals are linearised,
//! r_i(p + δ) ≈ r_i + g_i·δ, and the linear program
//!
//! ```text
//!   minimise t  subject to  −t ≤ r_i + g_i·δ ≤ t  (all i),   |δ_k|·s_k ≤ Δ  (all k)
//! ```
//!
//! is solved with clarabel (s_k is the RMS of column k, so the trust region Δ is in residual
//! units). The LP is not built on all residuals: an exchange loop solves it on an active set
//! (the worst residuals), checks the linearised residuals of all points, adds the violators and
//! solves again, until no point exceeds t. The step is accepted when the true maximum falls by a
//! fair share of the predicted fall; Δ grows after good steps and shrinks after bad ones. The
//! iteration stops when the LP predicts a relative improvement below `tolerance`.
//!
//! For a problem linear in p one LP step lands on the exact Chebyshev solution (tested against
//! the classical best uniform approximations); for a nonlinear one the steps converge to a local
//! minimax point, at which the LP on the linearisation predicts no improvement (a first-order
//! optimality condition), which is checked at every stop.
use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus,
};

use super::lsq::Problem;
use crate::{Error, Result};

/// Knobs of [`minimax`].
#[derive(Debug, Clone)]
pub struct MinimaxOptions {
    /// Outer (linearisation) iterations.
    pub max_iterations: usize,
    /// Stop when the LP predicts a fall of the maximum below `tolerance` × the maximum.
    pub tolerance: f64,
    /// Size of the initial active set per outer iteration (the worst residuals); at least
    /// 4 × (parameters + 1) are used.
    pub active_set: usize,
    /// Most linear programs solved in all (bounds the time on any input: each outer iteration
    /// may exchange up to 50 times); reaching it stops the fit ([`MinimaxFit::exhausted`]).
    pub max_lp_solves: usize,
}

impl Default for MinimaxOptions {
    fn default() -> Self {
        MinimaxOptions {
            max_iterations: 100,
            tolerance: 1e-10,
            active_set: 64,
            max_lp_solves: 600,
        }
    }
}

/// The result of a minimax fit.
#[derive(Debug, Clone)]
pub struct MinimaxFit {
    pub params: Vec<f64>,
    /// max_i |r_i| at `params`.
    pub max_abs_residual: f64,
    /// √(Σ r_i² / m) at `params`.
    pub rms_residual: f64,
    /// Outer iterations used.
    pub iterations: usize,
    /// Linear programs solved (outer iterations × exchange rounds).
    pub lp_solves: usize,
    /// Residuals within 1e-6 relative of the maximum: the points that define the fit.
    pub extremal: Vec<usize>,
    /// LP-predicted relative improvement at the stop (≤ tolerance when converged).
    pub predicted_improvement: f64,
    /// Whether the fit stopped at [`MinimaxOptions::max_lp_solves`].
    pub exhausted: bool,
}

struct Linearised {
    r: Vec<f64>,
    /// Row-major m × n gradients.
    g: Vec<f64>,
    max: f64,
    ssr: f64,
}

fn linearise(problem: &dyn Problem, p: &[f64]) -> Result<Linearised> {
    let n = problem.n_params();
    let m = problem.n_residuals();
    let mut r = vec![0.0; m];
    let mut g = vec![0.0; m * n];
    let mut bad = false;
    problem.eval(p, &mut |i, ri, gi| {
        if i >= m || !ri.is_finite() {
            bad = true;
            return;
        }
        r[i] = ri;
        g[i * n..(i + 1) * n].copy_from_slice(&gi[..n]);
    });
    if bad {
        return Err(Error::Numerics(
            "the model produced a non-finite residual; check the input for NaN or absurd values"
                .into(),
        ));
    }
    let max = r.iter().fold(0.0f64, |a, x| a.max(x.abs()));
    let ssr = r.iter().map(|x| x * x).sum();
    Ok(Linearised { r, g, max, ssr })
}

fn max_abs(problem: &dyn Problem, p: &[f64]) -> Result<f64> {
    let mut max = 0.0f64;
    let mut finite = true;
    problem.eval(p, &mut |_, r, _| {
        finite &= r.is_finite();
        max = max.max(r.abs());
    });
    if finite {
        Ok(max)
    } else {
        Err(Error::Numerics(
            "non-finite residual in a minimax trial step".into(),
        ))
    }
}

/// Solve min t s.t. |b_i + a_i·y| ≤ t for i in `rows`, |y_k| ≤ bound_k. Returns (y, t).
fn lp(a: &[f64], b: &[f64], n: usize, rows: &[usize], bound: &[f64]) -> Result<(Vec<f64>, f64)> {
    // Variables x = (y_0..y_{n-1}, t). Constraints A x + s = h, s ≥ 0.
    let nv = n + 1;
    let mut ri = Vec::new();
    let mut ci = Vec::new();
    let mut v = Vec::new();
    let mut h = Vec::new();
    let mut row = 0;
    for &i in rows {
        // a_i·y − t ≤ −b_i  and  −a_i·y − t ≤ b_i
        for sgn in [1.0, -1.0] {
            for k in 0..n {
                let x = a[i * n + k];
                if x != 0.0 {
                    ri.push(row);
                    ci.push(k);
                    v.push(sgn * x);
                }
            }
            ri.push(row);
            ci.push(n);
            v.push(-1.0);
            h.push(-sgn * b[i]);
            row += 1;
        }
    }
    for (k, &bk) in bound.iter().enumerate() {
        for sgn in [1.0, -1.0] {
            ri.push(row);
            ci.push(k);
            v.push(sgn);
            h.push(bk);
            row += 1;
        }
    }
    let amat = CscMatrix::new_from_triplets(row, nv, ri, ci, v);
    let pmat = CscMatrix::<f64>::zeros((nv, nv));
    let mut q = vec![0.0; nv];
    q[n] = 1.0;
    let cones = [NonnegativeConeT(row)];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-11)
        .tol_gap_rel(1e-11)
        .tol_feas(1e-11)
        .build()
        .map_err(|e| Error::Numerics(format!("minimax LP settings: {e:?}")))?;
    let mut solver = DefaultSolver::new(&pmat, &q, &amat, &h, &cones, settings)
        .map_err(|e| Error::Numerics(format!("minimax LP setup: {e:?}")))?;
    solver.solve();
    match solver.solution.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => {
            let x = &solver.solution.x;
            Ok((x[..n].to_vec(), x[n]))
        }
        s => Err(Error::Numerics(format!(
            "the minimax linear program did not solve ({s:?}); try a start closer to the answer"
        ))),
    }
}

/// Minimise max_i |r_i(p)| from `p0`. See the module docs for the method.
pub fn minimax(problem: &dyn Problem, p0: &[f64], opts: &MinimaxOptions) -> Result<MinimaxFit> {
    let n = problem.n_params();
    let m = problem.n_residuals();
    if p0.len() != n || m == 0 {
        return Err(Error::Numerics(format!(
            "minimax: {} start values for {n} parameters and {m} residuals",
            p0.len()
        )));
    }
    let mut p = p0.to_vec();
    let mut lin = linearise(problem, &p)?;
    let mut delta = f64::NAN;
    let mut active: Vec<usize> = Vec::new();
    let mut lp_solves = 0;
    let mut iterations = 0;
    let mut predicted = f64::INFINITY;
    while iterations < opts.max_iterations && lin.max > 0.0 && lp_solves < opts.max_lp_solves {
        iterations += 1;
        // Column scales: RMS gradient, so |y_k| = |δ_k| s_k is in residual units.
        let mut scale = vec![0.0; n];
        for row in lin.g.chunks_exact(n) {
            for (s, g) in scale.iter_mut().zip(row) {
                *s += g * g;
            }
        }
        for s in &mut scale {
            *s = (*s / m as f64).sqrt();
        }
        // Normalise residuals by the current maximum so the LP works near unit size: with
        // y_k = δ_k s_k / max, the linearised residual / max is b_i + Σ_k a_ik y_k where
        // a_ik = g_ik / s_k and b_i = r_i / max.
        let norm = lin.max;
        let a: Vec<f64> = (0..m * n)
            .map(|j| {
                let s = scale[j % n];
                if s > 0.0 {
                    lin.g[j] / s
                } else {
                    0.0
                }
            })
            .collect();
        let b: Vec<f64> = lin.r.iter().map(|x| x / norm).collect();
        if delta.is_nan() {
            delta = 1.0;
        }
        let bound: Vec<f64> = scale
            .iter()
            .map(|&s| if s > 0.0 { delta } else { 0.0 })
            .collect();
        // Active set: previous active points plus the worst residuals.
        let want = opts.active_set.max(4 * (n + 1)).min(m);
        let mut order: Vec<usize> = (0..m).collect();
        order.select_nth_unstable_by(want - 1, |&i, &j| b[j].abs().total_cmp(&b[i].abs()));
        let mut set: Vec<usize> = order[..want].to_vec();
        set.extend(active.iter().copied());
        set.sort_unstable();
        set.dedup();
        let mut in_set = vec![false; m];
        for &i in &set {
            in_set[i] = true;
        }
        let mut rounds = 0;
        let (y, t) = loop {
            let (y, t) = lp(&a, &b, n, &set, &bound)?;
            lp_solves += 1;
            rounds += 1;
            // Linearised residuals of every point at this step; points outside the set that
            // exceed t join it. Points already in the set are satisfied up to the LP tolerance.
            let rho: Vec<f64> = a
                .chunks_exact(n)
                .zip(&b)
                .map(|(ai, bi)| (bi + ai.iter().zip(&y).map(|(x, z)| x * z).sum::<f64>()).abs())
                .collect();
            let lin_max = rho.iter().fold(t, |acc, &x| acc.max(x));
            let mut viol: Vec<(f64, usize)> = rho
                .iter()
                .enumerate()
                .filter(|&(i, &r)| !in_set[i] && r > t + 1e-9)
                .map(|(i, &r)| (r, i))
                .collect();
            if viol.is_empty() || rounds >= 50 || lp_solves >= opts.max_lp_solves {
                // lin_max is the true linearised maximum at y, a valid prediction either way.
                break (y, lin_max);
            }
            viol.sort_by(|x, z| z.0.total_cmp(&x.0));
            for &(_, i) in viol.iter().take(want) {
                in_set[i] = true;
                set.push(i);
            }
        };
        predicted = 1.0 - t;
        if predicted <= opts.tolerance {
            break;
        }
        let trial: Vec<f64> = (0..n)
            .map(|k| {
                if scale[k] > 0.0 {
                    p[k] + y[k] / scale[k] * norm
                } else {
                    p[k]
                }
            })
            .collect();
        let actual = 1.0 - max_abs(problem, &trial)? / norm;
        let rho = actual / predicted;
        let step = y.iter().fold(0.0f64, |a, x| a.max(x.abs()));
        if rho > 0.01 {
            p = trial;
            lin = linearise(problem, &p)?;
            active = (0..m)
                .filter(|&i| lin.r[i].abs() >= (1.0 - 1e-3) * lin.max)
                .collect();
            // Δ is relative to the maximum, which just changed.
            delta *= norm / lin.max.max(f64::MIN_POSITIVE);
            if rho > 0.75 && step >= 0.99 * delta {
                delta *= 2.0;
            }
        } else {
            delta = 0.25 * step.min(delta);
            if delta < 1e-14 {
                break;
            }
        }
    }
    let extremal = (0..m)
        .filter(|&i| lin.r[i].abs() >= (1.0 - 1e-6) * lin.max)
        .collect();
    Ok(MinimaxFit {
        params: p,
        max_abs_residual: lin.max,
        rms_residual: (lin.ssr / m as f64).sqrt(),
        iterations,
        lp_solves,
        extremal,
        predicted_improvement: predicted,
        exhausted: lp_solves >= opts.max_lp_solves,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fit c_0 + c_1 x + ... to f on a grid.
    struct Poly {
        x: Vec<f64>,
        y: Vec<f64>,
        degree: usize,
    }
    impl Problem for Poly {
        fn n_params(&self) -> usize {
            self.degree + 1
        }
        fn n_residuals(&self) -> usize {
            self.x.len()
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            let mut g = vec![0.0; self.degree + 1];
            for (i, (&x, &y)) in self.x.iter().zip(&self.y).enumerate() {
                let mut xk = 1.0;
                let mut v = 0.0;
                for (k, gk) in g.iter_mut().enumerate() {
                    *gk = xk;
                    v += p[k] * xk;
                    xk *= x;
                }
                visit(i, v - y, &g);
            }
        }
    }

    #[test]
    fn best_line_to_a_parabola_is_the_classical_one() {
        // Best uniform approximation of x² on [0, 1] by a line: x − 1/8, error 1/8 at 0, ½, 1.
        let x: Vec<f64> = (0..=1000).map(|i| i as f64 / 1000.0).collect();
        let y = x.iter().map(|x| x * x).collect();
        let fit = minimax(
            &Poly { x, y, degree: 1 },
            &[0.0, 0.0],
            &MinimaxOptions::default(),
        )
        .unwrap();
        assert!((fit.max_abs_residual - 0.125).abs() < 1e-9, "{fit:?}");
        assert!((fit.params[0] + 0.125).abs() < 1e-8 && (fit.params[1] - 1.0).abs() < 1e-8);
        assert_eq!(fit.extremal, vec![0, 500, 1000]);
        assert!(!fit.exhausted && fit.lp_solves < MinimaxOptions::default().max_lp_solves);
    }

    #[test]
    fn the_work_is_bounded_by_the_lp_budget() {
        let x: Vec<f64> = (0..=1000).map(|i| i as f64 / 1000.0).collect();
        let y = x.iter().map(|x| x * x).collect();
        let opts = MinimaxOptions {
            max_lp_solves: 2,
            ..MinimaxOptions::default()
        };
        let fit = minimax(&Poly { x, y, degree: 1 }, &[0.0, 0.0], &opts).unwrap();
        assert_eq!(fit.lp_solves, 2);
        assert!(fit.exhausted, "{fit:?}");
    }

    #[test]
    fn chebyshev_equioscillation_for_a_cubic() {
        // Best quadratic to x³ on [−1, 1]: x³ − T3(x)/4 = (3/4)x, error 1/4 at 4 alternating points.
        let x: Vec<f64> = (0..=2000).map(|i| -1.0 + i as f64 / 1000.0).collect();
        let y = x.iter().map(|x| x * x * x).collect();
        let fit = minimax(
            &Poly { x, y, degree: 2 },
            &[1.0, -1.0, 2.0],
            &MinimaxOptions::default(),
        )
        .unwrap();
        assert!((fit.max_abs_residual - 0.25).abs() < 1e-9, "{fit:?}");
        assert!(fit.params[0].abs() < 1e-8 && (fit.params[1] - 0.75).abs() < 1e-8);
        assert!(fit.params[2].abs() < 1e-8);
        // Extremal points of T3 on [−1, 1]: ±1, ±½.
        assert_eq!(fit.extremal, vec![0, 500, 1500, 2000]);
    }

    /// Circle through noisy points: nonlinear minimax must beat least squares on the maximum
    /// and show at least n + 1 = 4 extremal points (the Chebyshev alternation count).
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
    fn nonlinear_circle_minimax_beats_least_squares_maximum() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let q: Vec<(f64, f64)> = (0..500)
            .map(|i| {
                let t = i as f64 * 0.0126;
                let e = rng.gen_range(-0.01..0.01);
                (1.0 + (20.0 + e) * t.cos(), -3.0 + (20.0 + e) * t.sin())
            })
            .collect();
        let prob = Circle { q };
        let lsq = super::super::lsq::least_squares(&prob, &[0.0, 0.0, 15.0], &Default::default())
            .unwrap();
        let lsq_max = max_abs(&prob, &lsq.params).unwrap();
        let mm = minimax(&prob, &[0.0, 0.0, 15.0], &MinimaxOptions::default()).unwrap();
        assert!(
            mm.max_abs_residual <= lsq_max + 1e-12,
            "{} vs {lsq_max}: {mm:?}",
            mm.max_abs_residual
        );
        assert!(mm.max_abs_residual < 0.0101, "{mm:?}");
        assert!(mm.extremal.len() >= 4, "{:?}", mm.extremal);
        assert!(mm.predicted_improvement <= 1e-10);
        // Local optimality: no small random perturbation lowers the maximum.
        for j in 0..50 {
            let dp: Vec<f64> = (0..3).map(|_| rng.gen_range(-1e-4..1e-4)).collect();
            let p: Vec<f64> = mm.params.iter().zip(&dp).map(|(a, b)| a + b).collect();
            assert!(
                max_abs(&prob, &p).unwrap() >= mm.max_abs_residual - 1e-12,
                "trial {j}"
            );
        }
    }
}
