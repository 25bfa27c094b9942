//! The calibration fit: which instrument effects the calibrator's samples show, how large they
//! are and how sure we are; the same engine and report shape as `diagnose`
//! ([`crate::diagnose`]).
//!
//! Pipeline ([`calibrate`]):
//! 1. Baseline: the nominal instrument's D at each sample's counts against the reference,
//!    r = d_ref − D (µm): RMS and peak-to-valley.
//! 2. Design: one pass over the samples with the core model
//!    ([`jdbb_core::geometry::Model::distance_and_gradient`], analytic partial derivatives)
//!    accumulates the Gram matrix of every candidate effect's columns (µm of D per µm or arcsec
//!    of the effect, [`super::effects`]) and of y = r + J·v, the data relative to the nominal
//!    instrument linearised at the current estimate v. With equal nominal bars the columns of L1
//!    and L2 are identical (D is symmetric in them): the rank test names them confounded and the
//!    search fits `length_sum` instead.
//! 3. Selection by extended BIC ([`crate::numerics::select::forward_select`], γ = ½, stepwise)
//!    with a floor: an effect that changes D by less than [`MIN_EFFECT_UM`] anywhere on the
//!    samples is not named (listed below the floor).
//! 4. Gauss–Newton on the selection: the selected effects' least-squares coefficients are the
//!    Gauss–Newton step of the exact model, so the estimate moves there and steps 2–3 are
//!    repeated, linearised at the new estimate, until the same effects are chosen and the step is
//!    below a tenth of each standard error (two or three passes: instrument errors are small). A
//!    term that only stood in for the model's curvature at the nominal point leaves on the way.
//!    These rounds are the exact non-linear refit of the chosen effects on the core model.
//! 5. Statistics: one more pass through the shared engine
//!    ([`crate::numerics::lsq::least_squares`], no step) at the estimate gives the standard errors
//!    and the final RMS of the exact model; if the rounds did not settle, Levenberg–Marquardt
//!    continues from there instead. The fitted calibration is the nominal one plus the chosen
//!    effects.
use jdbb_core::calib::{Calibration, N_PARAMS};
use jdbb_core::geometry::Model;
use nalgebra::DMatrix;

use super::effects::Effect;
use super::samples::CalSamples;
use crate::numerics::lsq::{least_squares, GramAccumulator, LsqOptions, Problem};
use crate::numerics::select::{
    confounded_names, forward_select, null_space, sub, Group, SelectOptions,
};
use crate::{Error, Result};

/// The reporting floor (µm): an instrument effect that changes D by less than this anywhere on
/// the samples is not named. The size of a good calibrator's noise and under half the 0.05 µm a
/// calibration must predict to, so what is left out cannot spoil a prediction.
pub const MIN_EFFECT_UM: f64 = 0.02;

/// Most Gauss–Newton rounds of selection and linearisation (module docs, step 4).
const MAX_ROUNDS: usize = 8;

/// The rounds have settled when the same effects are chosen and every parameter's step is below
/// this many of its standard errors: Gauss–Newton converges quadratically on these small
/// errors, so what the next step would add is far smaller still.
const STEP_SIGMAS: f64 = 0.1;

/// Knobs of the calibration.
#[derive(Debug, Clone)]
pub struct Options {
    /// Also search the frames' pivot geometry: tilt_k, offset_normal_k, offset_axial_k.
    pub extended: bool,
    /// The forward selection's limits, BIC penalty and floor.
    pub select: SelectOptions,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            extended: false,
            select: SelectOptions {
                max_effects: 16,
                gamma: 0.5,
                min_peak: MIN_EFFECT_UM,
                ..SelectOptions::default()
            },
        }
    }
}

/// One named effect: its fitted parameters (exact refit) and the selection step that added it.
#[derive(Debug, Clone)]
pub struct Found {
    pub effect: Effect,
    /// Values of [`Effect::param_names`] (µm, arcsec, degrees): change from the nominal.
    pub params: Vec<f64>,
    /// Their standard errors; None for a parameter the samples do not determine (held at 0).
    pub params_sigma: Vec<Option<f64>>,
    /// The effect's size: the change of the length or angle, or the eccentricity's amplitude.
    pub value: f64,
    /// Standard error of `value`; None if undetermined.
    pub sigma: Option<f64>,
    /// RMS (µm) of the residual after the selection step that added it.
    pub rms_after_um: f64,
    /// RMS before / after that step.
    pub rms_ratio: f64,
    /// BIC change of that step (negative = better).
    pub delta_bic: f64,
}

/// The result of [`calibrate`].
#[derive(Debug, Clone)]
pub struct Calibrated {
    pub samples: usize,
    /// RMS and peak-to-valley (µm) of d_ref − D with the nominal instrument.
    pub baseline_rms_um: f64,
    pub baseline_pv_um: f64,
    /// Named effects in the order the selection added them.
    pub effects: Vec<Found>,
    /// Groups of names the samples cannot tell apart.
    pub confounded: Vec<Vec<String>>,
    /// The effects searched.
    pub candidates: Vec<String>,
    /// Effects the data support but that stay under the floor: name and the bound (µm) of their
    /// largest contribution to D.
    pub below_floor: Vec<(String, f64)>,
    /// The floor applied (µm).
    pub floor_um: f64,
    /// RMS (µm) of d_ref − D with the fitted calibration.
    pub final_rms_um: f64,
    /// baseline RMS / final RMS.
    pub gain: f64,
    /// Gauss–Newton rounds of selection (module docs, step 4).
    pub rounds: usize,
    /// The calibration the fit started from.
    pub nominal: Calibration,
    /// The nominal calibration with the named effects applied.
    pub calibration: Calibration,
    /// Without a calibrator (samples with positions): the table ball's set-up offset fitted
    /// alongside, per axis (µm) with its standard error.
    pub setup_um: Option<[(f64, Option<f64>); 3]>,
    /// Without a calibrator: how each searched instrument effect stands against the machine's
    /// linear errors and the set-up offset on these samples ([`machine_separation`]).
    pub machine: Vec<Separation>,
}

/// The machine's linear geometric errors a run of spheres also measures, as columns of D (µm
/// per ppm of scale or µrad of squareness): `scale_x/y/z` (δD = p_k²/|p|) and `squareness_xy/yz/zx`
/// (δD = p_i p_j/|p|).
pub const MACHINE_NAMES: [&str; 6] = [
    "scale_x",
    "scale_y",
    "scale_z",
    "squareness_xy",
    "squareness_yz",
    "squareness_zx",
];

/// One instrument effect against the machine's errors and the set-up offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Separation {
    /// The instrument effect.
    pub effect: String,
    /// The share of its columns' effect on D (smallest over its columns, 0–1) that no
    /// combination of machine errors and set-up offset reproduces: 0 = cannot be told apart.
    pub separable: f64,
    /// When it is not separable: the machine and set-up terms that reproduce it (each carrying
    /// at least a tenth of the combination that does).
    pub confounded_with: Vec<String>,
}

/// A share below this is a confounding (the rank test's tolerance, as a share of the column).
const SEPARABLE_MIN: f64 = 1e-4;

/// The rank test of each instrument effect in `effects` against the machine's linear errors
/// ([`MACHINE_NAMES`]) and the set-up offset, on samples with positions at the instrument
/// `cal`: which instrument terms a run of spheres cannot tell from the machine.
pub fn machine_separation(
    samples: &CalSamples,
    cal: &Calibration,
    effects: &[Effect],
) -> Vec<Separation> {
    let Some(pos) = &samples.positions else {
        return vec![];
    };
    let design = Design::new(cal, effects);
    let n0 = design.cols.len();
    let n = n0 + 3 + MACHINE_NAMES.len();
    let model = Model::new(cal);
    let mut g = DMatrix::<f64>::zeros(n, n);
    let mut row = vec![0.0; n];
    for (i, &p) in pos.iter().enumerate() {
        let (_, grad) = model.distance_and_gradient(samples.enc1[i], samples.enc2[i]);
        let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        for (c, map) in design.maps.iter().enumerate() {
            row[c] = map.iter().map(|&(q, f)| f * grad[q]).sum();
        }
        for k in 0..3 {
            row[n0 + k] = p[k] / d;
            row[n0 + 3 + k] = 1e-3 * p[k] * p[k] / d;
            row[n0 + 6 + k] = 1e-3 * p[k] * p[(k + 1) % 3] / d;
        }
        for a in 0..n {
            for b in a..n {
                g[(a, b)] += row[a] * row[b];
            }
        }
    }
    for a in 0..n {
        for b in 0..a {
            g[(a, b)] = g[(b, a)];
        }
    }
    let name = |c: usize| {
        if c < n0 {
            design.name(c)
        } else if c < n0 + 3 {
            SETUP_NAMES[c - n0].to_string()
        } else {
            MACHINE_NAMES[c - n0 - 3].to_string()
        }
    };
    let others: Vec<usize> = (n0..n).collect();
    let a = sub(&g, &others);
    let a_pinv = a.clone().pseudo_inverse(1e-12 * a.norm()).unwrap_or(a);
    effects
        .iter()
        .map(|&e| {
            let cols = design.cols_of(e);
            let separable = cols
                .iter()
                .map(|&c| {
                    let b = nalgebra::DVector::from_fn(others.len(), |k, _| g[(others[k], c)]);
                    let explained = (b.transpose() * &a_pinv * &b)[(0, 0)];
                    let total = g[(c, c)];
                    if total > 0.0 {
                        ((total - explained).max(0.0) / total).sqrt()
                    } else {
                        0.0
                    }
                })
                .fold(1.0f64, f64::min);
            // The combination of machine and set-up columns that reproduces the first column.
            let c = cols[0];
            let b = nalgebra::DVector::from_fn(others.len(), |k, _| g[(others[k], c)]);
            let x = &a_pinv * &b;
            let parts: Vec<f64> = (0..others.len())
                .map(|k| x[k].abs() * g[(others[k], others[k])].max(0.0).sqrt())
                .collect();
            let big = parts.iter().cloned().fold(0.0, f64::max);
            let confounded_with = if separable < SEPARABLE_MIN {
                (0..others.len())
                    .filter(|&k| parts[k] >= 0.1 * big)
                    .map(|k| name(others[k]))
                    .collect()
            } else {
                vec![]
            };
            Separation {
                effect: e.name().to_string(),
                separable,
                confounded_with,
            }
        })
        .collect()
}

/// The search columns: every effect's fit parameters (both length forms, all candidates), with
/// the core parameters each one moves.
struct Design {
    /// The instrument's columns; with `setup`, three more follow: the table ball's set-up
    /// offset c (µm per axis, [`SETUP_NAMES`]).
    cols: Vec<(Effect, usize)>,
    setup: bool,
    /// Per column: (index into `Param::ALL`, µm of D per mm or rad of that parameter × its
    /// change per unit of the column).
    maps: Vec<Vec<(usize, f64)>>,
    nominal: Calibration,
}

/// What one pass over the samples gives.
struct Pass {
    /// Gram of [columns…, y] (µm², y = r + J·v).
    gram: DMatrix<f64>,
    /// Σ r² (µm²) and the extremes of r = d_ref − D (µm) at the current estimate.
    ssr: f64,
    min_um: f64,
    max_um: f64,
    /// Largest |column| over the samples (µm per unit).
    peak: Vec<f64>,
}

impl Design {
    fn new(nominal: &Calibration, effects: &[Effect]) -> Design {
        let mut cols = vec![];
        for &e in effects {
            cols.extend((0..e.n_cols()).map(|k| (e, k)));
        }
        let maps = cols
            .iter()
            .map(|&(e, k)| {
                e.targets(k)
                    .iter()
                    .map(|&(p, f)| (p.index(), 1e3 * f))
                    .collect()
            })
            .collect();
        Design {
            cols,
            setup: false,
            maps,
            nominal: *nominal,
        }
    }

    /// Number of columns: the instrument's, then the set-up offset's.
    fn n(&self) -> usize {
        self.cols.len() + if self.setup { 3 } else { 0 }
    }

    /// The set-up offset (mm) in the values `v`.
    fn setup_mm(&self, v: &[f64]) -> [f64; 3] {
        let n0 = self.cols.len();
        if self.setup {
            [0, 1, 2].map(|k| 1e-3 * v[n0 + k])
        } else {
            [0.0; 3]
        }
    }

    fn col(&self, e: Effect) -> usize {
        self.cols
            .iter()
            .position(|c| c.0 == e)
            .expect("effect in the design")
    }

    fn cols_of(&self, e: Effect) -> Vec<usize> {
        (0..self.cols.len())
            .filter(|&c| self.cols[c].0 == e)
            .collect()
    }

    fn name(&self, c: usize) -> String {
        match self.cols.get(c) {
            Some(col) => col.0.name().to_string(),
            None => SETUP_NAMES[c - self.cols.len()].to_string(),
        }
    }

    /// The nominal calibration with the columns' values `v` applied.
    fn calibration(&self, v: &[f64]) -> Calibration {
        let mut p: [f64; N_PARAMS] = self.nominal.params();
        for (c, &x) in v.iter().enumerate().take(self.cols.len()) {
            if x != 0.0 {
                for &(q, f) in self.cols[c].0.targets(self.cols[c].1) {
                    p[q.index()] += f * x;
                }
            }
        }
        self.nominal.with_params(&p)
    }

    /// One pass: the Gram of the columns and of y = r + J·v at the estimate `v` (module docs).
    fn pass(&self, s: &CalSamples, v: &[f64]) -> Result<Pass> {
        let model = Model::new(&self.calibration(v));
        let setup = self.setup_mm(v);
        let n0 = self.cols.len();
        let n = self.n();
        let w = n + 1;
        let mut acc = GramAccumulator::new(w);
        let mut peak = vec![0.0f64; n];
        let (mut ssr, mut min_um, mut max_um) = (0.0, f64::INFINITY, f64::NEG_INFINITY);
        let m = s.len();
        let mut i0 = 0;
        while i0 < m {
            let len = GramAccumulator::ROWS.min(m - i0);
            let block = acc.rows(len);
            for j in 0..len {
                let i = i0 + j;
                let (d, g) = model.distance_and_gradient(s.enc1[i], s.enc2[i]);
                let (d_ref, u) = reference(s, i, setup);
                let r = 1e3 * (d_ref - d);
                if !r.is_finite() {
                    return Err(Error::input(
                        &s.path,
                        s.line[i],
                        0,
                        "the instrument model gives no distance at these counts; are they within the frames' ±75°?",
                    ));
                }
                let row = &mut block[j * w..(j + 1) * w];
                let mut y = r;
                for (c, map) in self.maps.iter().enumerate() {
                    let x: f64 = map.iter().map(|&(q, f)| f * g[q]).sum();
                    row[c] = x;
                    y += x * v[c];
                    peak[c] = peak[c].max(x.abs());
                }
                for k in 0..n - n0 {
                    // d_ref = |p − c| grows by u·δc: the column of r's model is −u.
                    let x = -u[k];
                    row[n0 + k] = x;
                    y += x * v[n0 + k];
                    peak[n0 + k] = peak[n0 + k].max(x.abs());
                }
                row[n] = y;
                ssr += r * r;
                min_um = min_um.min(r);
                max_um = max_um.max(r);
            }
            i0 += len;
        }
        Ok(Pass {
            gram: acc.finish(),
            ssr,
            min_um,
            max_um,
            peak,
        })
    }
}

/// The exact model restricted to the chosen columns, for the refit: r = D − d_ref (µm).
struct Refit<'a> {
    design: &'a Design,
    samples: &'a CalSamples,
    free: &'a [usize],
}

impl Problem for Refit<'_> {
    fn n_params(&self) -> usize {
        self.free.len()
    }
    fn n_residuals(&self) -> usize {
        self.samples.len()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let mut v = vec![0.0; self.design.n()];
        for (a, &c) in self.free.iter().enumerate() {
            v[c] = p[a];
        }
        let model = Model::new(&self.design.calibration(&v));
        let setup = self.design.setup_mm(&v);
        let n0 = self.design.cols.len();
        let s = self.samples;
        let mut grad = vec![0.0; self.free.len()];
        for i in 0..s.len() {
            let (d, g) = model.distance_and_gradient(s.enc1[i], s.enc2[i]);
            let (d_ref, u) = reference(s, i, setup);
            for (a, &c) in self.free.iter().enumerate() {
                grad[a] = if c < n0 {
                    self.design.maps[c].iter().map(|&(q, f)| f * g[q]).sum()
                } else {
                    -u[c - n0]
                };
            }
            visit(i, 1e3 * (d - d_ref), &grad);
        }
    }
}

/// Names of the set-up offset's columns (µm): where the table ball is, relative to where the
/// plan put it, when the samples come from a machine run (`--record` with `--plan`).
pub const SETUP_NAMES: [&str; 3] = ["setup_x", "setup_y", "setup_z"];

/// Sample `i`'s reference distance (mm) and u = ∂d_ref/∂c: a calibrator's d_ref (u = 0), or
/// |p − c| for a machine run's nominal position p (relative to where the plan put the table
/// ball) and the table ball's set-up offset c (mm): u = −(p − c)/|p − c|.
fn reference(s: &CalSamples, i: usize, setup_mm: [f64; 3]) -> (f64, [f64; 3]) {
    match &s.positions {
        None => (s.d_ref_mm[i], [0.0; 3]),
        Some(p) => {
            let q = [0, 1, 2].map(|k| p[i][k] - setup_mm[k]);
            let d = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
            (d, q.map(|x| -x / d))
        }
    }
}

/// Calibrate the instrument: which effects the samples show against `nominal`, their sizes, and
/// the fitted calibration. See the module docs. The samples should have passed
/// [`CalSamples::check_against`] for `nominal`.
pub fn calibrate(
    samples: &CalSamples,
    nominal: &Calibration,
    opts: &Options,
) -> Result<Calibrated> {
    let m = samples.len();
    if m < super::samples::MIN_SAMPLES {
        return Err(Error::Numerics(format!(
            "a calibration needs at least {} samples (got {m})",
            super::samples::MIN_SAMPLES
        )));
    }
    let mut all = vec![Effect::LengthSum, Effect::LengthL1, Effect::LengthL2];
    all.extend(Effect::BASIC);
    if opts.extended {
        all.extend(Effect::EXTENDED);
    }
    let mut design = Design::new(nominal, &all);
    design.setup = samples.positions.is_some();
    let base: Vec<usize> = (design.cols.len()..design.n()).collect();
    let name = |c: usize| design.name(c);
    let mut v = vec![0.0; design.n()];

    // Round 0 at the nominal instrument: the baseline, and whether the bars can be told apart.
    let first = design.pass(samples, &v)?;
    let baseline_rms_um = (first.ssr / m as f64).sqrt();
    let baseline_pv_um = first.max_um - first.min_um;
    let bars = [design.col(Effect::LengthL1), design.col(Effect::LengthL2)];
    let bars_confounded = null_space(&sub(&first.gram, &bars)).0 < 2;
    let mut confounded: Vec<Vec<String>> = if bars_confounded {
        confounded_names(&first.gram, &bars, &name)
    } else {
        vec![]
    };
    let mut candidates = Effect::lengths(bars_confounded);
    candidates.extend(Effect::BASIC);
    if opts.extended {
        candidates.extend(Effect::EXTENDED);
    }

    let baseline_ssr = first.ssr;
    let mut pass = first;
    let mut converged = false;
    let mut prev: Option<Vec<usize>> = None;
    let mut rounds = 0;
    let sel = loop {
        rounds += 1;
        let groups: Vec<Group> = candidates
            .iter()
            .enumerate()
            .map(|(family, &e)| {
                let cols = design.cols_of(e);
                Group {
                    peak: cols.iter().map(|&c| pass.peak[c]).collect(),
                    cost: cols.len(),
                    cols,
                    family,
                }
            })
            .collect();
        let sel = forward_select(&pass.gram, m, &base, &groups, &opts.select, &name)?;
        let mut v_new = vec![0.0; v.len()];
        for (k, &c) in sel.current.iter().enumerate() {
            v_new[c] = sel.coef[k];
        }
        let mut set = sel.current.clone();
        set.sort_unstable();
        let small_step = sel.current.iter().enumerate().all(|(k, &c)| {
            let sigma = sel.covariance[(k, k)].max(0.0).sqrt();
            (v_new[c] - v[c]).abs() <= STEP_SIGMAS * sigma
        });
        let same = prev.as_ref() == Some(&set);
        v = v_new;
        if same && small_step {
            converged = true;
            break sel;
        }
        if rounds == MAX_ROUNDS {
            break sel;
        }
        prev = Some(set);
        pass = design.pass(samples, &v)?;
    };
    for g in sel.confounded.iter() {
        let mut g = g.clone();
        g.dedup();
        if !confounded.contains(&g) {
            confounded.push(g);
        }
    }
    let group_effect = |g: usize| candidates[g];
    let below_floor: Vec<(String, f64)> = sel
        .below_floor
        .iter()
        .map(|&(g, bound)| (group_effect(g).name().to_string(), bound))
        .collect();

    // 5. The statistics of the exact model at the Gauss–Newton estimate (one pass), or, if the
    // rounds did not settle, Levenberg–Marquardt from there.
    let free: Vec<usize> = sel.current.clone();
    let (final_ssr, sigma, cov) = if free.is_empty() {
        (baseline_ssr, vec![], DMatrix::zeros(0, 0))
    } else {
        let prob = Refit {
            design: &design,
            samples,
            free: &free,
        };
        let p0: Vec<f64> = free.iter().map(|&c| v[c]).collect();
        let lsq = LsqOptions {
            max_iterations: if converged { 0 } else { 50 },
            tolerance: 1e-10,
            ..LsqOptions::default()
        };
        let fit = least_squares(&prob, &p0, &lsq)?;
        if !converged && !fit.converged {
            return Err(Error::Numerics(format!(
                "the calibration fit did not converge in {} iterations; check that the samples come from one instrument and one reference",
                fit.iterations
            )));
        }
        for (a, &c) in free.iter().enumerate() {
            v[c] = fit.params[a];
        }
        (fit.ssr, fit.sigma, fit.covariance)
    };
    let calibration = design.calibration(&v);
    calibration.validate().map_err(|e| {
        Error::Numerics(format!(
            "the fitted calibration is no plausible instrument ({e:?}: an error angle beyond 0.01 rad or a bar length out of range); check the samples and --nominal"
        ))
    })?;
    let final_rms_um = (final_ssr / m as f64).sqrt();
    let setup_um = design.setup.then(|| {
        [0, 1, 2].map(|k| {
            let c = design.cols.len() + k;
            (
                v[c],
                free.iter().position(|&x| x == c).and_then(|a| sigma[a]),
            )
        })
    });
    let machine = machine_separation(samples, &calibration, &candidates);

    // Report, in the order the selection added the effects.
    let at = |c: usize| free.iter().position(|&x| x == c);
    let effects: Vec<Found> = sel
        .steps
        .iter()
        .map(|st| {
            let effect = group_effect(st.group);
            let cols = design.cols_of(effect);
            let vals: Vec<f64> = cols.iter().map(|&c| v[c]).collect();
            let sig: Vec<Option<f64>> =
                cols.iter().map(|&c| at(c).and_then(|a| sigma[a])).collect();
            let mut c2 = [[0.0; 2]; 2];
            for (i, &ci) in cols.iter().enumerate() {
                for (j, &cj) in cols.iter().enumerate() {
                    if let (Some(a), Some(b)) = (at(ci), at(cj)) {
                        c2[i][j] = cov[(a, b)];
                    }
                }
            }
            let determined = sig.iter().all(|s| s.is_some());
            let (value, s) = effect.value(&vals, &c2);
            let mut params = vals.clone();
            let mut params_sigma = sig.clone();
            if effect.n_cols() == 2 {
                let (ph, ps) = Effect::phase_deg(&vals, &c2);
                params.push(ph);
                params_sigma.push(determined.then_some(ps));
            }
            Found {
                effect,
                params,
                params_sigma,
                value,
                sigma: determined.then_some(s),
                rms_after_um: st.rms_after,
                rms_ratio: st.rms_ratio,
                delta_bic: st.delta_bic,
            }
        })
        .collect();
    Ok(Calibrated {
        samples: m,
        baseline_rms_um,
        baseline_pv_um,
        effects,
        confounded,
        candidates: candidates.iter().map(|e| e.name().to_string()).collect(),
        below_floor,
        floor_um: opts.select.min_peak,
        final_rms_um,
        gain: baseline_rms_um / final_rms_um.max(1e-300),
        rounds,
        nominal: *nominal,
        calibration,
        setup_um,
        machine,
    })
}

/// Samples a calibrator gives of the instrument `hidden` (core model): D `from..to` mm in `n_d`
/// steps, `per_turn` azimuths, reference with `noise_um` Gaussian noise (for the tests).
#[cfg(test)]
pub(crate) fn simulated_samples(
    hidden: &Calibration,
    d_mm: (f64, f64, usize),
    per_turn: usize,
    noise_um: f64,
    seed: u64,
) -> CalSamples {
    tests::samples(hidden, d_mm, per_turn, noise_um, seed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::instrument::ARCSEC_RAD;
    use jdbb_core::geometry::distance_mm;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    use std::path::Path;

    /// See [`super::simulated_samples`].
    pub(super) fn samples(
        hidden: &Calibration,
        d_mm: (f64, f64, usize),
        per_turn: usize,
        noise_um: f64,
        seed: u64,
    ) -> CalSamples {
        let model = Model::new(hidden);
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let noise = Normal::new(0.0, noise_um * 1e-3).unwrap();
        let (mut e1, mut e2, mut d) = (vec![], vec![], vec![]);
        for i in 0..d_mm.2 {
            let dist = d_mm.0 + (d_mm.1 - d_mm.0) * i as f64 / (d_mm.2 - 1) as f64;
            for k in 0..per_turn {
                let psi = std::f64::consts::TAU * k as f64 / per_turn as f64;
                if let Some((c1, c2)) = model.counts_for_distance(dist, psi) {
                    e1.push(c1);
                    e2.push(c2);
                    d.push(distance_mm(hidden, c1, c2) + noise.sample(&mut rng));
                }
            }
        }
        CalSamples::from_vecs(Path::new("cal.csv"), e1, e2, d)
    }

    fn names(c: &Calibrated) -> Vec<&'static str> {
        let mut n: Vec<_> = c.effects.iter().map(|f| f.effect.name()).collect();
        n.sort_unstable();
        n
    }

    #[test]
    fn recovers_a_known_calibration_made_with_the_core_model() {
        let mut hidden = Calibration::DEFAULT;
        hidden.l2_mm -= 0.012;
        hidden.enc1.zero_offset_rad = -35.0 * ARCSEC_RAD;
        hidden.axes_skew_rad = 50.0 * ARCSEC_RAD;
        hidden
            .enc2
            .set_eccentricity_components(20.0 * ARCSEC_RAD, -25.0 * ARCSEC_RAD);
        let s = samples(&hidden, (79.0, 99.0, 6), 72, 0.02, 7);
        s.check_against(&Calibration::DEFAULT).unwrap();
        let c = calibrate(&s, &Calibration::DEFAULT, &Options::default()).unwrap();
        assert_eq!(
            names(&c),
            ["axes_skew", "eccentricity_2", "length_sum", "zero_1"],
            "{c:?}"
        );
        assert_eq!(
            c.confounded,
            vec![vec!["length_l1".to_string(), "length_l2".to_string()]]
        );
        let f = |n: &str| c.effects.iter().find(|f| f.effect.name() == n).unwrap();
        for (n, truth) in [
            ("length_sum", -12.0),
            ("zero_1", -35.0),
            ("axes_skew", 50.0),
        ] {
            let e = f(n);
            assert!(
                (e.value - truth).abs() < 4.0 * e.sigma.unwrap(),
                "{n}: {} ± {:?}",
                e.value,
                e.sigma
            );
        }
        let e = f("eccentricity_2");
        assert!((e.params[0] - 20.0).abs() < 4.0 * e.params_sigma[0].unwrap());
        assert!((e.params[1] + 25.0).abs() < 4.0 * e.params_sigma[1].unwrap());
        assert!(
            (e.params[2] - (-25f64).atan2(20.0).to_degrees()).abs()
                < 4.0 * e.params_sigma[2].unwrap()
        );
        assert!(
            c.baseline_rms_um > 5.0 && c.final_rms_um < 0.025,
            "{} → {}",
            c.baseline_rms_um,
            c.final_rms_um
        );
        // The fitted calibration predicts D at other poses to the noise.
        let held = samples(&hidden, (80.5, 97.5, 4), 50, 0.0, 0);
        let model = Model::new(&c.calibration);
        let ms: f64 = (0..held.len())
            .map(|i| {
                (1e3 * (model.distance_mm(held.enc1[i], held.enc2[i]) - held.d_ref_mm[i])).powi(2)
            })
            .sum::<f64>()
            / held.len() as f64;
        assert!(ms.sqrt() < 0.01, "held-out RMS {} µm", ms.sqrt());
    }

    #[test]
    fn unequal_bars_are_fitted_each() {
        let nominal = Calibration::nominal(40.0, 60.0, 1 << 23);
        let mut hidden = nominal;
        hidden.l1_mm += 0.015;
        hidden.l2_mm -= 0.010;
        let s = samples(&hidden, (77.0, 99.5, 6), 72, 0.02, 3);
        let c = calibrate(&s, &nominal, &Options::default()).unwrap();
        assert_eq!(names(&c), ["length_l1", "length_l2"], "{c:?}");
        assert!(c.confounded.is_empty());
        assert!((c.calibration.l1_mm - hidden.l1_mm).abs() < 1e-3);
        assert!((c.calibration.l2_mm - hidden.l2_mm).abs() < 1e-3);
        assert_eq!(c.calibration.enc1, nominal.enc1);
    }

    #[test]
    fn a_perfect_instrument_names_nothing() {
        for seed in [1, 2, 3] {
            let s = samples(&Calibration::DEFAULT, (79.0, 99.0, 5), 72, 0.02, seed);
            let c = calibrate(&s, &Calibration::DEFAULT, &Options::default()).unwrap();
            assert!(c.effects.is_empty(), "seed {seed}: {:?}", c.effects);
            assert_eq!(c.calibration, Calibration::DEFAULT);
            assert!(c.final_rms_um < 0.025);
        }
    }
}
