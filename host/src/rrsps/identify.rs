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
    /// Iterations of the engine (LM, or minimax outer iterations).
    pub iterations: usize,
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
        return Err(Error::Usage("identify needs at least one samples file".into()));
    }
    if samples.len() == 1 && !free.is_empty() {
        return Err(Error::Usage(
            "--free only makes sense with several --samples files (one test per file)".into(),
        ));
    }
    let problem = JointProblem::new(samples, free);
    let x0 = problem.start(start);
    let lsq = least_squares(&problem, &x0, &LsqOptions::default())?;
    let (x, iterations) = match method {
        Method::Lsq => (lsq.params.clone(), lsq.iterations),
        Method::Minimax => {
            let mm = minimax(&problem, &lsq.params, &MinimaxOptions::default())?;
            (mm.params, mm.iterations)
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
    let undetermined: Vec<Vec<String>> = lsq
        .undetermined
        .iter()
        .map(|g| g.iter().map(|&j| name_of(j)).collect())
        .collect();
    // Per-test statistics.
    let mut tests = Vec::new();
    let (mut all_max, mut all_ss, mut all_n) = (0.0f64, 0.0, 0usize);
    for (t, s) in samples.iter().enumerate() {
        let p = problem.params_of(&x, t);
        let prep = Prepared::new(&p);
        let (mut mx, mut ss) = (0.0f64, 0.0);
        for ((&a, &c), &d) in s.theta_a_rad.iter().zip(&s.theta_c_rad).zip(&s.d_mm) {
            let r = prep.bar_length(SinCos::of(a), SinCos::of(c)) - d;
            mx = mx.max(r.abs());
            ss += r * r;
        }
        all_max = all_max.max(mx);
        all_ss += ss;
        all_n += s.d_mm.len();
        tests.push(TestFit {
            params: p,
            n_samples: s.d_mm.len(),
            max_abs_residual_um: mx * 1e3,
            rms_residual_um: (ss / s.d_mm.len() as f64).sqrt() * 1e3,
        });
    }
    // Changes of free parameters relative to test 1, with σ from the joint covariance.
    let mut changes = Vec::new();
    let ns = 8 - problem.free.len();
    for t in 1..samples.len() {
        for (j, &k) in problem.free.iter().enumerate() {
            let i1 = ns + j;
            let it = ns + t * problem.free.len() + j;
            let determined = lsq.sigma[i1].is_some() && lsq.sigma[it].is_some();
            let cov = &lsq.covariance;
            let var = cov[(i1, i1)] + cov[(it, it)] - 2.0 * cov[(i1, it)];
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
