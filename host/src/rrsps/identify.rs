//! Identification of the eight RRSPS parameters from measured bar lengths (seed 004 §4, eq. 26).
//!
//! One or several tests are fitted at once. All tests share the eight parameters except the
//! `free` ones, which get one value per test (the paper's cases M2/M3 moved s0 with the X axis).
//! The residual of sample i is d(eq. 26; p, θA_i, θC_i) − d*_i.
//!
//! Least squares ([`crate::fit`]) gives standard errors, singular values and the undetermined
//! combinations; minimax ([`crate::minimax`], the paper's saddle programme) starts from the
//! least-squares answer and minimises the largest residual. The standard errors reported with a
//! minimax fit are those of the least-squares fit of the same data (a minimax estimate has no
//! simple covariance; the two estimates differ by far less than those errors at Gaussian noise).
use super::io::Samples;
use super::{Params, Prepared, SinCos, IS_ANGLE, PARAM_NAMES};
use crate::fit::{least_squares, LsqOptions, Problem};
use crate::minimax::{minimax, MinimaxOptions};
use crate::{Error, Result};

/// Fitting criterion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    /// Minimise the largest |residual| (the paper's eq. 26).
    Minimax,
    /// Minimise the sum of squared residuals.
    Lsq,
}

/// One test prepared for repeated evaluation (sin/cos of its angles computed once).
struct Test {
    a: Vec<SinCos>,
    c: Vec<SinCos>,
    d_mm: Vec<f64>,
}

/// Several tests sharing the parameters except `free` ones. The fit vector is the shared
/// parameters (in [`PARAM_NAMES`] order, skipping free ones) followed by, for each test, its free
/// parameters.
pub struct JointProblem {
    tests: Vec<Test>,
    free: Vec<usize>,
    shared: Vec<usize>,
    n_residuals: usize,
}

impl JointProblem {
    /// `free`: indices into [`PARAM_NAMES`] of the parameters that differ between tests.
    pub fn new(samples: &[Samples], free: &[usize]) -> Self {
        let tests: Vec<Test> = samples
            .iter()
            .map(|s| Test {
                a: s.theta_a_rad.iter().map(|&x| SinCos::of(x)).collect(),
                c: s.theta_c_rad.iter().map(|&x| SinCos::of(x)).collect(),
                d_mm: s.d_mm.clone(),
            })
            .collect();
        let mut free = free.to_vec();
        free.sort_unstable();
        free.dedup();
        let shared = (0..8).filter(|k| !free.contains(k)).collect();
        let n_residuals = tests.iter().map(|t| t.d_mm.len()).sum();
        JointProblem {
            tests,
            free,
            shared,
            n_residuals,
        }
    }

    /// The full parameter set of test `t` from a fit vector.
    pub fn params_of(&self, x: &[f64], t: usize) -> Params {
        let mut p = [0.0; 8];
        for (j, &k) in self.shared.iter().enumerate() {
            p[k] = x[j];
        }
        let base = self.shared.len() + t * self.free.len();
        for (j, &k) in self.free.iter().enumerate() {
            p[k] = x[base + j];
        }
        Params::from_array(&p)
    }

    /// A fit vector with every test at `p`.
    pub fn start(&self, p: &Params) -> Vec<f64> {
        let a = p.to_array();
        let mut x: Vec<f64> = self.shared.iter().map(|&k| a[k]).collect();
        for _ in 0..self.tests.len() {
            x.extend(self.free.iter().map(|&k| a[k]));
        }
        x
    }

    /// (parameter index in PARAM_NAMES, test index or None if shared) of each fit-vector entry.
    pub fn layout(&self) -> Vec<(usize, Option<usize>)> {
        let mut v: Vec<(usize, Option<usize>)> = self.shared.iter().map(|&k| (k, None)).collect();
        for t in 0..self.tests.len() {
            v.extend(self.free.iter().map(|&k| (k, Some(t))));
        }
        v
    }
}

impl JointProblem {
    /// Per test: (max |residual|, sum of squares, samples), without gradients.
    pub fn residual_stats(&self, x: &[f64]) -> Vec<(f64, f64, usize)> {
        self.tests
            .iter()
            .enumerate()
            .map(|(t, test)| {
                let prep = Prepared::new(&self.params_of(x, t));
                let (mut mx, mut ss) = (0.0f64, 0.0);
                for ((&a, &c), &d) in test.a.iter().zip(&test.c).zip(&test.d_mm) {
                    let r = prep.bar_length(a, c) - d;
                    mx = mx.max(r.abs());
                    ss += r * r;
                }
                (mx, ss, test.d_mm.len())
            })
            .collect()
    }

    /// Sum of squared residuals, without gradients.
    pub fn ssr(&self, x: &[f64]) -> f64 {
        self.residual_stats(x).iter().map(|s| s.1).sum()
    }
}

/// JᵀJ (full, row-major n×n), Jᵀr and the sum of squares in one pass.
fn normal_equations(problem: &dyn Problem, x: &[f64]) -> (Vec<f64>, Vec<f64>, f64) {
    let n = x.len();
    let mut jtj = vec![0.0; n * n];
    let mut jtr = vec![0.0; n];
    let mut ssr = 0.0;
    problem.eval(x, &mut |_, r, g| {
        ssr += r * r;
        for (i, &gi) in g.iter().enumerate() {
            if gi != 0.0 {
                jtr[i] += gi * r;
                let row = &mut jtj[i * n..i * n + i + 1];
                for (a, &gj) in row.iter_mut().zip(g) {
                    *a += gi * gj;
                }
            }
        }
    });
    for i in 0..n {
        for j in i + 1..n {
            jtj[i * n + j] = jtj[j * n + i];
        }
    }
    (jtj, jtr, ssr)
}

impl Problem for JointProblem {
    fn n_params(&self) -> usize {
        self.shared.len() + self.free.len() * self.tests.len()
    }
    fn n_residuals(&self) -> usize {
        self.n_residuals
    }
    fn eval(&self, x: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let n = self.n_params();
        let mut grad = vec![0.0; n];
        let mut i = 0;
        let ns = self.shared.len();
        for (t, test) in self.tests.iter().enumerate() {
            let prep = Prepared::new(&self.params_of(x, t));
            let base = ns + t * self.free.len();
            grad.iter_mut().for_each(|g| *g = 0.0);
            for ((&a, &c), &d) in test.a.iter().zip(&test.c).zip(&test.d_mm) {
                let (model, g) = prep.bar_length_and_gradient(a, c);
                for (j, &k) in self.shared.iter().enumerate() {
                    grad[j] = g[k];
                }
                for (j, &k) in self.free.iter().enumerate() {
                    grad[base + j] = g[k];
                }
                visit(i, model - d, &grad);
                i += 1;
            }
        }
    }
}

/// Singular values of the column-scaled Jacobian below this fraction of the largest count as
/// undetermined. One constant-length test has one such direction at ~1e-6 (see [`gauss_newton`]):
/// moving it by a millimetre changes the bar lengths by ~0.005 µm, so the data cannot fix it, and
/// the linearised σ along it (mm) would be both meaningless and unreliable (the valley is curved
/// over that range).
pub const RANK_TOLERANCE: f64 = 1e-5;

/// Gauss-Newton with backtracking along the step, on column-scaled normal equations solved by
/// eigen-decomposition (pseudo-inverse below 1e-13 of the largest eigenvalue).
///
/// Why not only [`crate::fit::least_squares`]: for a1 ≈ 0 (intersecting axes) the balls can move
/// radially from the axes' intersection, both at once, keeping the angle E-O-F and hence the
/// whole test path: a one-parameter family along which d barely changes (singular value ~1e-6
/// of the largest) and which is curved in (s0, a0, s2, a2). Levenberg-Marquardt damping is far
/// larger than that direction's eigenvalue, so LM creeps along the curved valley (100 iterations
/// without converging on a 900-point test), and so does a backtracked Gauss-Newton step that
/// includes it. Steps are therefore taken only in the determined subspace ([`RANK_TOLERANCE`]),
/// where Gauss-Newton converges in a few passes; the shared engine then starts at this optimum,
/// with the same rank rule, and supplies the statistics.
fn gauss_newton(problem: &JointProblem, x0: &[f64]) -> Result<GaussNewton> {
    use nalgebra::{DMatrix, DVector, SymmetricEigen};
    let n = x0.len();
    let mut x = x0.to_vec();
    let mut ssr = problem.ssr(&x);
    let mut passes = 0;
    while passes < 50 {
        passes += 1;
        let (jtj, jtr, _) = normal_equations(problem, &x);
        let d: Vec<f64> = (0..n)
            .map(|k| jtj[k * n + k].sqrt().max(f64::MIN_POSITIVE))
            .collect();
        let a = DMatrix::from_fn(n, n, |i, j| jtj[i * n + j] / (d[i] * d[j]));
        let eig = SymmetricEigen::new(a);
        let emax = eig.eigenvalues.iter().fold(0.0f64, |m, &e| m.max(e));
        let g = DVector::from_fn(n, |k, _| jtr[k] / d[k]);
        let mut z = DVector::<f64>::zeros(n);
        for c in 0..n {
            let e = eig.eigenvalues[c];
            if e > RANK_TOLERANCE * RANK_TOLERANCE * emax {
                let v = eig.eigenvectors.column(c);
                z -= v * (v.dot(&g) / e);
            }
        }
        let step: Vec<f64> = (0..n).map(|k| z[k] / d[k]).collect();
        let mut alpha = 1.0;
        let mut accepted = false;
        for _ in 0..40 {
            let trial: Vec<f64> = x.iter().zip(&step).map(|(a, b)| a + alpha * b).collect();
            let t = problem.ssr(&trial);
            if t.is_finite() && t < ssr {
                let gain = ssr - t;
                x = trial;
                ssr = t;
                accepted = true;
                if gain <= 1e-12 * ssr {
                    return Ok(GaussNewton {
                        x,
                        passes,
                        converged: true,
                    });
                }
                break;
            }
            alpha *= 0.5;
        }
        if !accepted {
            // No step along the Gauss-Newton direction lowers the sum: a minimum to rounding.
            return if ssr.is_finite() {
                Ok(GaussNewton {
                    x,
                    passes,
                    converged: true,
                })
            } else {
                Err(Error::Numerics(
                    "the model produced a non-finite residual; check the input for NaN or absurd values"
                        .into(),
                ))
            };
        }
    }
    Ok(GaussNewton {
        x,
        passes,
        converged: false,
    })
}

struct GaussNewton {
    x: Vec<f64>,
    passes: usize,
    converged: bool,
}

/// The determined directions of `problem` at `x` (eigenvectors of the column-scaled normal
/// matrix with eigenvalue above [`RANK_TOLERANCE`]² of the largest), as physical steps.
fn determined_basis(problem: &dyn Problem, x: &[f64]) -> Vec<Vec<f64>> {
    use nalgebra::{DMatrix, SymmetricEigen};
    let n = x.len();
    let (jtj, _, _) = normal_equations(problem, x);
    let d: Vec<f64> = (0..n)
        .map(|k| jtj[k * n + k].sqrt().max(f64::MIN_POSITIVE))
        .collect();
    let eig = SymmetricEigen::new(DMatrix::from_fn(n, n, |i, j| {
        jtj[i * n + j] / (d[i] * d[j])
    }));
    let emax = eig.eigenvalues.iter().fold(0.0f64, |m, &e| m.max(e));
    (0..n)
        .filter(|&c| eig.eigenvalues[c] > RANK_TOLERANCE * RANK_TOLERANCE * emax)
        .map(|c| (0..n).map(|k| eig.eigenvectors[(k, c)] / d[k]).collect())
        .collect()
}

/// `inner` restricted to x = x0 + Σ_c y_c b_c: the minimax fit moves only in the determined
/// subspace, leaving the undetermined combination where least squares left it.
struct Restricted<'a> {
    inner: &'a JointProblem,
    x0: Vec<f64>,
    basis: Vec<Vec<f64>>,
}

impl Restricted<'_> {
    fn full(&self, y: &[f64]) -> Vec<f64> {
        let mut x = self.x0.clone();
        for (b, &yc) in self.basis.iter().zip(y) {
            for (xi, bi) in x.iter_mut().zip(b) {
                *xi += yc * bi;
            }
        }
        x
    }
}

impl Problem for Restricted<'_> {
    fn n_params(&self) -> usize {
        self.basis.len()
    }
    fn n_residuals(&self) -> usize {
        self.inner.n_residuals()
    }
    fn eval(&self, y: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let x = self.full(y);
        let mut gy = vec![0.0; self.basis.len()];
        self.inner.eval(&x, &mut |i, r, g| {
            for (o, b) in gy.iter_mut().zip(&self.basis) {
                *o = b.iter().zip(g).map(|(p, q)| p * q).sum();
            }
            visit(i, r, &gy);
        });
    }
}

/// Residual statistics of one test.
#[derive(Debug, Clone, PartialEq)]
pub struct TestFit {
    pub params: Params,
    pub n_samples: usize,
    pub max_abs_residual_um: f64,
    pub rms_residual_um: f64,
}

/// A value in the units of its name (mm or degrees) with its standard error, if determined.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// Parameter name, with `[t]` (1-based test number) for per-test free parameters.
    pub name: String,
    pub param: usize,
    pub test: Option<usize>,
    pub value: f64,
    pub sigma: Option<f64>,
}

/// The result of an identification.
#[derive(Debug, Clone)]
pub struct Identification {
    pub method: Method,
    pub estimates: Vec<Estimate>,
    pub tests: Vec<TestFit>,
    /// Groups of fit-vector names the data does not determine (in `estimates` naming).
    pub undetermined: Vec<Vec<String>>,
    /// Singular values of the column-scaled Jacobian, descending.
    pub singular_values: Vec<f64>,
    pub max_abs_residual_um: f64,
    pub rms_residual_um: f64,
    /// Change of each free parameter from test 1 to test t (t ≥ 2), with its standard error
    /// from the joint covariance: (name, test, change, sigma).
    pub changes: Vec<(String, usize, f64, Option<f64>)>,
    /// Iterations: Gauss-Newton passes plus the engine's LM iterations (least squares), or the
    /// minimax engine's outer iterations.
    pub iterations: usize,
    /// The least-squares values (units of the names), same order as `estimates`; for a minimax
    /// fit they show how far the minimax answer moved along weakly determined combinations.
    pub lsq_values: Vec<f64>,
    /// The least well determined combination of the parameters.
    pub weakest: WeakDirection,
}

/// The direction in parameter space the data determines least (smallest singular value of the
/// column-scaled Jacobian): moving all parameters together along it changes the bar lengths least.
#[derive(Debug, Clone)]
pub struct WeakDirection {
    /// Smallest over largest singular value.
    pub relative_singular_value: f64,
    /// (name, component) in units of the names, scaled so the largest |component| is 1.
    pub components: Vec<(String, f64)>,
    /// Largest change of any modelled bar length (µm) for one unit step along the direction.
    pub max_change_um: f64,
}

/// The weakest direction of `problem` at `x` (see [`WeakDirection`]), from the eigenvectors of
/// the column-scaled normal matrix, the same scaling as [`crate::fit`] uses for its rank test.
fn weakest_direction(problem: &JointProblem, x: &[f64], names: &[String]) -> WeakDirection {
    use nalgebra::{DMatrix, SymmetricEigen};
    let n = x.len();
    let (jtj, _, _) = normal_equations(problem, x);
    let jtj = DMatrix::from_row_slice(n, n, &jtj);
    let d: Vec<f64> = (0..n)
        .map(|k| {
            let v = jtj[(k, k)].sqrt();
            if v > 0.0 {
                v
            } else {
                1.0
            }
        })
        .collect();
    let a = DMatrix::from_fn(n, n, |i, j| jtj[(i, j)] / (d[i] * d[j]));
    let eig = SymmetricEigen::new(a);
    let (mut imin, mut imax) = (0, 0);
    for i in 0..n {
        if eig.eigenvalues[i] < eig.eigenvalues[imin] {
            imin = i;
        }
        if eig.eigenvalues[i] > eig.eigenvalues[imax] {
            imax = i;
        }
    }
    let layout = problem.layout();
    // Step in internal units, then in the units of the names.
    let step: Vec<f64> = (0..n).map(|k| eig.eigenvectors[(k, imin)] / d[k]).collect();
    let shown: Vec<f64> = (0..n).map(|j| unit(layout[j].0, step[j])).collect();
    let big = shown
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    let sign = if shown
        .iter()
        .cloned()
        .fold(0.0, |m: f64, v| if v.abs() > m.abs() { v } else { m })
        < 0.0
    {
        -1.0
    } else {
        1.0
    };
    let mut max_change = 0.0f64;
    problem.eval(x, &mut |_, _, g| {
        let dr: f64 = g.iter().zip(&step).map(|(a, b)| a * b).sum();
        max_change = max_change.max(dr.abs());
    });
    WeakDirection {
        relative_singular_value: (eig.eigenvalues[imin].max(0.0) / eig.eigenvalues[imax]).sqrt(),
        components: names
            .iter()
            .zip(&shown)
            .map(|(nm, v)| (nm.clone(), sign * v / big))
            .collect(),
        max_change_um: max_change / big * 1e3,
    }
}

fn unit(k: usize, x: f64) -> f64 {
    if IS_ANGLE[k] {
        x.to_degrees()
    } else {
        x
    }
}

/// Index in [`PARAM_NAMES`] of a parameter name (as given to `--free`).
pub fn param_index(name: &str) -> Result<usize> {
    PARAM_NAMES.iter().position(|&n| n == name).ok_or_else(|| {
        Error::Usage(format!(
            "unknown parameter `{name}`; the parameters are {}",
            PARAM_NAMES.join(", ")
        ))
    })
}

/// Identify the parameters of `samples` (one or more tests) starting from `start` (the design
/// values, as in the paper), with `free` parameters per test.
pub fn identify(
    samples: &[Samples],
    start: &Params,
    free: &[usize],
    method: Method,
) -> Result<Identification> {
    if samples.is_empty() {
        return Err(Error::Usage(
            "identify needs at least one samples file".into(),
        ));
    }
    if samples.len() == 1 && !free.is_empty() {
        return Err(Error::Usage(
            "--free only makes sense with several --samples files (one test per file)".into(),
        ));
    }
    let problem = JointProblem::new(samples, free);
    let x0 = problem.start(start);
    // Start undamped (Gauss-Newton): the weakest combination has a scaled eigenvalue near 1e-12,
    // which the default damping (1e-6) would shrink a million-fold, so LM would creep along it.
    let gn = gauss_newton(&problem, &x0)?;
    if !gn.converged {
        return Err(Error::Numerics(format!(
            "least squares did not converge in {} Gauss-Newton passes; check that the design \
             parameters are near the machine's and the samples belong to this test",
            gn.passes
        )));
    }
    // The engine supplies the statistics at the optimum (no further steps) with its default
    // rank rule, so the covariance includes the weakly determined direction: a parameter that
    // co-varies with it gets the standard error it really has.
    let lsq = least_squares(
        &problem,
        &gn.x,
        &LsqOptions {
            max_iterations: 0,
            ..LsqOptions::default()
        },
    )?;
    let (x, iterations) = match method {
        Method::Lsq => (gn.x.clone(), gn.passes),
        Method::Minimax => {
            let restricted = Restricted {
                inner: &problem,
                basis: determined_basis(&problem, &gn.x),
                x0: gn.x.clone(),
            };
            let y0 = vec![0.0; restricted.basis.len()];
            let mm = minimax(&restricted, &y0, &MinimaxOptions::default())?;
            (restricted.full(&mm.params), mm.iterations)
        }
    };
    let layout = problem.layout();
    let name_of = |j: usize| {
        let (k, t) = layout[j];
        match t {
            Some(t) => format!("{}[{}]", PARAM_NAMES[k], t + 1),
            None => PARAM_NAMES[k].to_string(),
        }
    };
    let names: Vec<String> = (0..layout.len()).map(name_of).collect();
    let weakest = weakest_direction(&problem, &x, &names);
    let mut undetermined_idx: Vec<Vec<usize>> = lsq.undetermined.clone();
    if weakest.relative_singular_value < RANK_TOLERANCE {
        // Parameters that move by at least 5 % of the largest mover along the weak direction.
        let group: Vec<usize> = (0..names.len())
            .filter(|&j| weakest.components[j].1.abs() >= 0.05)
            .collect();
        if !undetermined_idx
            .iter()
            .any(|g| group.iter().all(|j| g.contains(j)))
        {
            undetermined_idx.push(group);
        }
    }
    let in_group = |j: usize| undetermined_idx.iter().any(|g| g.contains(&j));
    let undetermined: Vec<Vec<String>> = undetermined_idx
        .iter()
        .map(|g| g.iter().map(|&j| name_of(j)).collect())
        .collect();
    let estimates: Vec<Estimate> = layout
        .iter()
        .enumerate()
        .map(|(j, &(k, t))| Estimate {
            name: name_of(j),
            param: k,
            test: t,
            value: unit(k, x[j]),
            sigma: if in_group(j) {
                None
            } else {
                lsq.sigma[j].map(|s| unit(k, s))
            },
        })
        .collect();
    // Per-test statistics.
    let mut tests = Vec::new();
    let (mut all_max, mut all_ss, mut all_n) = (0.0f64, 0.0, 0usize);
    for (t, (mx, ss, n)) in problem.residual_stats(&x).into_iter().enumerate() {
        all_max = all_max.max(mx);
        all_ss += ss;
        all_n += n;
        tests.push(TestFit {
            params: problem.params_of(&x, t),
            n_samples: n,
            max_abs_residual_um: mx * 1e3,
            rms_residual_um: (ss / n as f64).sqrt() * 1e3,
        });
    }
    // Changes of free parameters relative to test 1, with σ from the joint covariance.
    let mut changes = Vec::new();
    let ns = 8 - problem.free.len();
    for t in 1..samples.len() {
        for (j, &k) in problem.free.iter().enumerate() {
            let i1 = ns + j;
            let it = ns + t * problem.free.len() + j;
            // The change is determined even when each value is not: the undetermined combination
            // moves every test's value alike, so the contrast is orthogonal to it and
            // s²(JᵀJ)⁺ gives its variance. It is undetermined only if the covariance is zero.
            let cov = &lsq.covariance;
            let var = cov[(i1, i1)] + cov[(it, it)] - 2.0 * cov[(i1, it)];
            let determined = var > 0.0;
            changes.push((
                PARAM_NAMES[k].to_string(),
                t + 1,
                unit(k, x[it] - x[i1]),
                determined.then(|| unit(k, var.max(0.0).sqrt())),
            ));
        }
    }
    Ok(Identification {
        method,
        estimates,
        tests,
        undetermined,
        singular_values: lsq.singular_values.clone(),
        max_abs_residual_um: all_max * 1e3,
        rms_residual_um: (all_ss / all_n as f64).sqrt() * 1e3,
        changes,
        iterations,
        lsq_values: layout
            .iter()
            .enumerate()
            .map(|(j, &(k, _))| unit(k, lsq.params[j]))
            .collect(),
        weakest,
    })
}

/// Format `value ± sigma` with the digits the standard error supports (two significant digits
/// of sigma); an undetermined value is shown to 3 decimals and flagged.
pub fn format_estimate(value: f64, sigma: Option<f64>) -> String {
    match sigma {
        Some(s) if s > 0.0 && s.is_finite() => {
            let decimals = (1 - s.log10().floor() as i32).clamp(0, 12) as usize;
            format!("{value:.decimals$} ± {s:.decimals$}")
        }
        Some(_) => format!("{value} ± 0"),
        None => format!("{value:.3} (undetermined)"),
    }
}
