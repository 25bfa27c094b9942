//! Identification of the eight RRSPS parameters from measured bar lengths (seed 004 §4, eq. 26).
//!
//! One or several tests are fitted at once. All tests share the eight parameters except the
//! `free` ones, which get one value per test (the paper's cases M2/M3 moved s0 with the X axis).
//! The residual of sample i is d(eq. 26; p, θA_i, θC_i) − d*_i.
//!
//! Least squares ([`crate::numerics::lsq`]) gives standard errors, singular values and the undetermined
//! combinations; minimax ([`crate::numerics::minimax`], the paper's saddle programme) starts from the
//! least-squares answer and minimises the largest residual. The standard errors reported with a
//! minimax fit are those of the least-squares fit of the same data (a minimax estimate has no
//! simple covariance; the two estimates differ by far less than those errors at Gaussian noise).
use super::io::Samples;
use super::{Params, Prepared, SinCos, IS_ANGLE, PARAM_NAMES};
use crate::numerics::lsq::{least_squares, LsqFit, LsqOptions, Problem};
use crate::numerics::minimax::{minimax, MinimaxOptions};
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

/// τ for this problem ([`LsqOptions::rank_tolerance`]): singular values of the column-scaled
/// Jacobian at or below this fraction of the largest count as undetermined, instead of the
/// engine's numerical floor 1e-7. For a1 ≈ 0 (intersecting axes) the balls can move radially
/// from the axes' intersection, both at once, keeping the angle E-O-F and hence the whole test
/// path: a one-parameter family in (s0, a0, s2, a2) with a singular value ~1e-6 of the largest.
/// Moving along it by a millimetre changes the bar lengths by ~0.005 µm, so at the paper's
/// noise (~0.5 µm) its standard error is of the order of millimetres: the data cannot fix it, and
/// the valley is curved over that range, so a linearised σ along it would be meaningless and
/// Levenberg-Marquardt steps along it only creep (100 iterations without converging on a
/// 900-point test). With τ = 1e-5 the engine steps in the determined subspace, converges in a
/// few passes and names the combination. The next singular value of a designed single test is
/// ~1e-2 of the largest; a joint fit of cases like M1-M3 has its weakest at ~6e-5, determined.
pub const RANK_TOLERANCE: f64 = 1e-5;

/// [`LsqOptions::null_loading`] for this problem: a parameter is undetermined when the weak
/// combination leaves open at least ten times its determined standard error (at the threshold
/// [`RANK_TOLERANCE`]; the engine then adds that open part to the σ of the others). On a
/// designed single test the four ball distances s0, a0, s2, a2 exceed this ratio by far (≈ 90
/// to 3500), while the angles θA0, θC0, α12 and a1 load on the combination only at ratios of
/// 0.3 to 5: they keep a standard error, inflated by the open part, instead of being declared
/// unknown for a share of the weak combination below their own noise level.
pub const NULL_LOADING: f64 = 10.0;

/// The engine's options for this problem.
fn options() -> LsqOptions {
    LsqOptions {
        rank_tolerance: RANK_TOLERANCE,
        null_loading: NULL_LOADING,
        ..LsqOptions::default()
    }
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
    /// Iterations: the engine's Levenberg-Marquardt iterations (least squares), or the minimax
    /// engine's outer iterations.
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

/// The weakest direction of `problem` (see [`WeakDirection`]): the last direction of the
/// least-squares fit `lsq` (smallest singular value of the column-scaled Jacobian, the engine's
/// rank test), with the largest change of a bar length along it evaluated at `x`.
fn weakest_direction(
    problem: &JointProblem,
    lsq: &LsqFit,
    x: &[f64],
    names: &[String],
) -> WeakDirection {
    let n = x.len();
    let sv = &lsq.singular_values;
    let imin = n - 1;
    let layout = problem.layout();
    // Step in internal units, then in the units of the names.
    let step: Vec<f64> = (0..n).map(|k| lsq.directions[(k, imin)]).collect();
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
        relative_singular_value: if sv[0] > 0.0 { sv[imin] / sv[0] } else { 0.0 },
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
    let lsq = least_squares(&problem, &x0, &options())?;
    if !lsq.converged {
        return Err(Error::Numerics(format!(
            "least squares did not converge in {} iterations; check that the design parameters \
             are near the machine's and the samples belong to this test",
            lsq.iterations
        )));
    }
    let (x, iterations) = match method {
        Method::Lsq => (lsq.params.clone(), lsq.iterations),
        Method::Minimax => {
            // Minimax moves only in the determined subspace of the least-squares fit.
            let restricted = Restricted {
                inner: &problem,
                basis: (0..lsq.rank)
                    .map(|c| lsq.directions.column(c).iter().copied().collect())
                    .collect(),
                x0: lsq.params.clone(),
            };
            let y0 = vec![0.0; restricted.basis.len()];
            let opts = MinimaxOptions::default();
            let mm = minimax(&restricted, &y0, &opts)?;
            if mm.exhausted && mm.predicted_improvement > opts.tolerance {
                return Err(Error::Numerics(format!(
                    "the minimax fit did not settle within {} linear programs (max |residual| {:.3} µm, still falling): these samples do not pin a minimax solution down; use --method lsq",
                    opts.max_lp_solves,
                    mm.max_abs_residual * 1e3
                )));
            }
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
    let weakest = weakest_direction(&problem, &lsq, &x, &names);
    let undetermined_idx = &lsq.undetermined;
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
            sigma: lsq.sigma[j].map(|s| unit(k, s)),
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
