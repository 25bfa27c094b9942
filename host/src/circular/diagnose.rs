//! What the ideal-machine simulation gets wrong in a circular test, which machine
//! errors explain it, how large they are and how sure we are.
//!
//! Pipeline (see [`diagnose`]):
//! 1. Baseline: the ideal machine predicts D = |p_nominal|; report RMS and peak-to-valley (µm).
//! 2. Set-up: fit the table-ball offset c and the length offset e with the exact geometry
//!    D = |p + c| + e. Set-up parameters the path cannot determine (c_z on a flat circle) are
//!    held at zero and reported as confounded.
//! 3. Candidate search: every candidate effect of [`super::model`] becomes columns of a linear
//!    model, linearised at the nominal path (seed 000 eq. 1: ΔR = u·δ, u = p/|p|), against the
//!    residual of step 2. One pass over the samples accumulates the Gram matrix of all columns; the
//!    forward selection then works on that small matrix only, which is why the whole search costs
//!    one pass (O(m·n²)) plus O(n³) per trial.
//! 4. Selection by BIC ([`crate::numerics::select`]) = m·ln(SSR/m) + k·ln(m): an effect is added while it lowers BIC. For one
//!    added parameter this is a likelihood-ratio test at χ²₁ > ln m, i.e. a false-alarm rate of
//!    P(χ²₁ > ln m) per candidate (0.16 % at m = 20 000; 2 parameters: P(χ²₂ > 2 ln m) = 5e-5).
//!    An effect must also reach [`MIN_EFFECT_UM`] on D somewhere on the test (the bound
//!    Σ|β_c|·max|column_c|): with tens of thousands of samples, misfits of a few nanometres —
//!    a backlash that is a dead zone rather than a step, a sample's timing off by a millisecond —
//!    are significant, and would be named as a squareness of 0.1 µm/m. They are listed as below
//!    the floor instead ([`Diagnosis::below_floor`]).
//! 5. Identifiability: columns that are linear combinations of others (rank test on the
//!    column-scaled Gram matrix, singular values below 1e-7 of the largest) are never fitted
//!    against each other. If the isotropic scale is confounded with the length offset (one radius),
//!    the scale candidates become `scale_mismatch_ij` = scale_i − scale_j and the confounded group
//!    is named; a candidate that lies in the span of the current model is skipped and named with
//!    what it is confounded with. On a partial arc (the samples of a circle leave a gap, e.g. the
//!    220° vertical-plane test) a candidate the arc cannot tell from the set-up and the scale
//!    ([`PARTIAL_ARC_MIN_FREE`]) is not tried and named as confounded with them.
//! 6. The selected effects are refitted with the exact geometry ([`super::model::ExactModel`]),
//!    giving the reported values ± standard errors, then the residual's harmonics against angle.
//!
//! The inputs are read by [`super::input`]; the report (text, JSON, plots) is [`super::report`]
//! and [`super::plot`].
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
use nalgebra::DMatrix;

use super::input::MIN_SAMPLES;
use super::model::{Axis, Candidate, Effect, EffectSet, ExactModel, Pair, Path, MIN_TAU_MS};
use super::runs::{
    angles, arc_cover, circularity, harmonics, main_plane, split_runs_at, ArcCover, Circle, Run,
    MAX_RUN_STEP_RAD,
};
use super::zone::{circle_zones, CircleZone};
use crate::numerics::lsq::{least_squares, GramAccumulator, LsqOptions, Problem, Subset};
use crate::numerics::select::{
    confounded_names, forward_select, null_space, solve, sub, Group, SelectOptions,
};
use crate::{Error, Result};

/// The reporting floor (µm): an effect that changes D by less than this everywhere on the test is
/// not named. A fifth of a typical J-DBB sample's noise (0.2 µm), half of the 0.1 µm resolution
/// commercial ballbars quote, and far below the machine errors a ballbar test is for (µm).
pub const MIN_EFFECT_UM: f64 = 0.05;

/// Knobs of the diagnosis.
#[derive(Debug, Clone)]
pub struct Options {
    /// The forward selection's limits and BIC penalty.
    pub select: SelectOptions,
    /// Number of angle harmonics reported for the residual.
    pub harmonics: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            select: SelectOptions {
                gamma: 0.5,
                min_peak: MIN_EFFECT_UM,
                ..SelectOptions::default()
            },
            harmonics: 8,
        }
    }
}

/// One reported effect: its fitted parameters (exact geometry) and the selection step that added it.
#[derive(Debug, Clone)]
pub struct Found {
    pub effect: Effect,
    pub params: Vec<f64>,
    pub param_sigma: Vec<Option<f64>>,
    pub value: f64,
    pub sigma: Option<f64>,
    /// RMS (µm) of the residual after this step of the selection.
    pub rms_after_um: f64,
    /// RMS before / RMS after this step.
    pub rms_ratio: f64,
    /// Change of BIC by this step (negative = better).
    pub delta_bic: f64,
    /// RMS (µm) of the radial deviation this effect alone makes along the path, after the same
    /// set-up removal as the plotted curve; NaN for the set-up itself.
    pub contribution_rms_um: f64,
    /// This effect's share of the error: contribution_rms_um² / (RMS of the plotted measured
    /// deviation)². Shares of correlated effects need not add up to 1; NaN for the set-up.
    pub share: f64,
}

/// An effect the selection chose but whose value its σ does not tell from zero.
#[derive(Debug, Clone, PartialEq)]
pub struct NotSignificant {
    /// Effect name, as in [`Found`].
    pub name: String,
    /// Unit of `value`.
    pub unit: &'static str,
    /// Its value in the exact refit.
    pub value: f64,
    /// Its standard uncertainty, timing included.
    pub sigma_value: f64,
    /// Its parameters in the exact refit, by name (a spike's decay shows why its height is
    /// undetermined: τ far below the sample period).
    pub params: Vec<(&'static str, f64)>,
}

/// The result of [`diagnose`].
#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub samples: usize,
    pub baseline_rms_um: f64,
    pub baseline_pv_um: f64,
    /// Set-up (setup_offset, length_offset) then machine effects, in the order selected.
    pub effects: Vec<Found>,
    /// Groups of names (effects, or effect components like `setup_offset.z`) the test cannot
    /// tell apart.
    pub confounded: Vec<Vec<String>>,
    pub final_rms_um: f64,
    /// baseline RMS / final RMS.
    pub gain: f64,
    /// Amplitude (µm) of residual harmonics 1..=n against the angle in the main plane.
    pub harmonics_um: Vec<f64>,
    /// Candidates that were tried (names).
    pub candidates: Vec<String>,
    /// Effects that would have lowered the BIC but reach less than the floor
    /// ([`SelectOptions::min_peak`], µm) anywhere on D: name and that bound (µm).
    pub below_floor: Vec<(String, f64)>,
    /// The floor applied (µm).
    pub floor_um: f64,
    /// Effects the selection chose whose final value is within 2σ of zero, once σ counts the
    /// uncertainty of the timing (a reversal spike's height against the synchronisation's
    /// timing σ); not named, and the rest refitted without them.
    pub not_significant: Vec<NotSignificant>,
    /// Per sample: angle (rad) in the main plane; measured deviation with the least-squares
    /// set-up removed, D − (|p + c| + e) with c, e from [`Diagnosis::lsq_setup_um`] (µm); and the
    /// extended model's deviation after the same removal, i.e. its machine effects (µm).
    pub angle_rad: Vec<f64>,
    pub measured_dev_um: Vec<f64>,
    pub model_dev_um: Vec<f64>,
    /// The set-up removed from the plotted deviations: the least-squares centre and length of all
    /// samples, D ≈ |p + c| + e, as [c_x, c_y, c_z, e] in µm (a component the path cannot
    /// determine is held at 0).
    pub lsq_setup_um: [f64; 4],
    /// Main plane (axis indices) of the angle.
    pub plane: (usize, usize),
    /// The distinct circles (nominal radius and height) of the path.
    pub circles: Vec<Circle>,
    /// The samples cut into runs of one circle in one direction without gaps (see [`split_runs`]).
    pub runs: Vec<Run>,
    /// ISO 230-4 style circular deviation G and hysteresis H (µm) of the plotted measured
    /// deviation, see [`circularity`].
    pub circular_deviation_g_um: f64,
    pub hysteresis_h_um: f64,
    /// Per circle: conditions (radius, height, feed) and ISO 230-4 G and H with the
    /// minimum-zone centre ([`super::zone`]).
    pub circle_zones: Vec<CircleZone>,
    /// The pitch per axis the diagnosis was given (mm), which the periodic effects refer to.
    pub pitch_mm: [Option<f64>; 3],
    /// The arc each circle's samples cover (in `circles`' order): 360° on a full circle. On a
    /// partial arc the candidates it cannot tell from the set-up are not tried and named in
    /// `confounded` ([`PARTIAL_ARC_MIN_FREE`]), and `harmonics_um` is empty.
    pub arcs: Vec<ArcCover>,
}

/// A search column: which candidate, which of its search parameters.
#[derive(Debug, Clone, Copy)]
struct ColRef {
    cand: usize,
    k: usize,
}

/// The linearised design: all candidates' search columns at the nominal u, with y last.
struct Design {
    cands: Vec<Candidate>,
    /// First column of each candidate.
    offsets: Vec<usize>,
    cols: Vec<ColRef>,
    gram: DMatrix<f64>,
    yy: f64,
    /// Largest |value| of each search column over the samples (µm per unit parameter).
    peak: Vec<f64>,
}

impl Design {
    /// One pass: accumulate the Gram matrix of the search columns (µm per unit parameter) and y
    /// (µm).
    fn build(path: &Path, y_um: &[f64], cands: Vec<Candidate>) -> Design {
        let mut offsets = Vec::with_capacity(cands.len());
        let mut cols = vec![];
        for (c, cand) in cands.iter().enumerate() {
            offsets.push(cols.len());
            cols.extend((0..cand.n_cols()).map(|k| ColRef { cand: c, k }));
        }
        let n = cols.len();
        let w = n + 1;
        let mut acc = GramAccumulator::new(w);
        let mut peak = vec![0.0f64; n];
        let mut u = Vec::with_capacity(GramAccumulator::ROWS);
        let mut i0 = 0;
        while i0 < y_um.len() {
            let len = GramAccumulator::ROWS.min(y_um.len() - i0);
            u.clear();
            u.extend(path.p_mm[i0..i0 + len].iter().map(|p| {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                [p[0] / r, p[1] / r, p[2] / r]
            }));
            let block = acc.rows(len);
            for (cand, &o) in cands.iter().zip(&offsets) {
                cand.columns_block(path, i0, &u, block, w, o);
            }
            for j in 0..len {
                block[j * w + n] = y_um[i0 + j];
                for (c, pk) in peak.iter_mut().enumerate() {
                    *pk = pk.max(block[j * w + c].abs());
                }
            }
            i0 += len;
        }
        let gram = acc.finish();
        let yy = gram[(n, n)];
        Design {
            cands,
            offsets,
            cols,
            gram,
            yy,
            peak,
        }
    }

    fn ycol(&self) -> usize {
        self.cols.len()
    }

    fn cols_of(&self, c: usize) -> Vec<usize> {
        let o = self.offsets[c];
        (o..o + self.cands[c].n_cols()).collect()
    }

    /// Name of column i for confounding reports: the effect, or `effect.component` for the
    /// set-up's components and the servo delay's common lag.
    fn col_name(&self, i: usize) -> String {
        let cr = self.cols[i];
        let eff = self.cands[cr.cand].effect;
        match (eff, cr.k) {
            (Effect::SetupOffset, k) => format!("setup_offset.{}", ['x', 'y', 'z'][k]),
            (Effect::ServoMismatch(_), 1) => format!("{}.lag", eff.name()),
            _ => eff.name(),
        }
    }

    /// Names of the columns (among `idx`) loaded by the null vectors of the block `idx`.
    fn confounded_names(&self, idx: &[usize]) -> Vec<Vec<String>> {
        let mut out = confounded_names(&self.gram, idx, &|i| self.col_name(i));
        for g in &mut out {
            g.dedup();
        }
        out
    }

    /// Greedy: keep columns of `order` that raise the rank of what is kept.
    fn independent(&self, order: &[usize]) -> Vec<usize> {
        let mut kept: Vec<usize> = vec![];
        for &c in order {
            let mut trial = kept.clone();
            trial.push(c);
            let (rank, _) = null_space(&sub(&self.gram, &trial));
            if rank == trial.len() {
                kept = trial;
            }
        }
        kept
    }
}

/// Trial decay times (ms) of the reversal-spike candidates: the search tries each, the exact
/// refit frees τ from the best.
pub const SPIKE_TRIAL_TAU_MS: [f64; 4] = [3.0, 10.0, 30.0, 100.0];

/// The candidate machine effects the path can show: axes that move, pairs that both move,
/// periodic effects only where a pitch is known, reversal spikes of axes that reverse, drift.
pub fn candidate_effects(path: &Path) -> Vec<Effect> {
    let mut v = vec![];
    let moving: Vec<Axis> = Axis::ALL.into_iter().filter(|&a| path.moves(a)).collect();
    for &a in &moving {
        v.push(Effect::Scale(a));
    }
    for &a in &moving {
        v.push(Effect::Scale2(a));
        v.push(Effect::Backlash(a));
        if path.pitch_mm[a.index()].is_some() {
            v.push(Effect::Cyclic(a));
            v.push(Effect::Interference(a));
        }
    }
    for pair in Pair::ALL {
        let (i, j) = pair.axes();
        if path.moves(i) && path.moves(j) {
            v.push(Effect::Squareness(pair));
            v.push(Effect::ServoMismatch(pair));
        }
    }
    for &a in &moving {
        if !path.reversals[a.index()].is_empty() {
            v.push(Effect::ReversalSpike(a));
        }
    }
    v.push(Effect::Drift);
    v
}

/// The search forms of `effect`: one, or a spike at each trial decay time.
fn search_forms(effect: Effect) -> Vec<Candidate> {
    match effect {
        Effect::ReversalSpike(a) => SPIKE_TRIAL_TAU_MS
            .iter()
            .map(|&t| Candidate::spike(a, t))
            .collect(),
        e => vec![Candidate::of(e)],
    }
}

/// Diagnose a circular test: baseline, set-up, forward selection of machine effects, exact refit,
/// residual harmonics, G and H. See the module docs.
pub fn diagnose(path: &Path, d_mm: &[f64], opts: &Options) -> Result<Diagnosis> {
    let m = d_mm.len();
    if m != path.len() || m < MIN_SAMPLES {
        return Err(Error::Numerics(format!(
            "diagnose needs at least {MIN_SAMPLES} samples with a path each (got {m})"
        )));
    }
    // 1. Baseline.
    let base: Vec<f64> = path
        .p_mm
        .iter()
        .zip(d_mm)
        .map(|(p, d)| 1e3 * (d - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()))
        .collect();
    let baseline_rms_um = rms(&base);
    let baseline_pv_um = pv(&base);

    // 2. Which set-up parameters the path determines (nominal linearisation: columns u_x, u_y,
    // u_z for c and 1 for e), keeping e first, then c_x, c_y, c_z.
    let setup = [Effect::SetupOffset, Effect::LengthOffset];
    let setup_probe = Design::build(path, &base, setup.map(Candidate::of).to_vec());
    let setup_free = setup_probe.independent(&[3, 0, 1, 2]);
    let mut confounded: Vec<Vec<String>> = setup_probe.confounded_names(&[0, 1, 2, 3]);

    // 3. Exact set-up fit D = |p + c| + e on the determined set-up parameters.
    // Start from the linearised solution (one Gauss–Newton step done already).
    let mut setup_start = [0.0; 4];
    if let Some((x, _, _)) = solve(
        &setup_probe.gram,
        &setup_free,
        setup_probe.yy,
        setup_probe.ycol(),
    ) {
        for (&i, v) in setup_free.iter().zip(x) {
            setup_start[i] = v;
        }
    }
    let setup_theta = fit_setup(path, d_mm, &setup_free, &setup_start)?;
    let c_mm = [
        setup_theta[0] * 1e-3,
        setup_theta[1] * 1e-3,
        setup_theta[2] * 1e-3,
    ];
    let y: Vec<f64> = (0..m)
        .map(|i| {
            let p = path.p_mm[i];
            let q = [p[0] + c_mm[0], p[1] + c_mm[1], p[2] + c_mm[2]];
            let dist = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + setup_theta[3] * 1e-3;
            1e3 * (d_mm[i] - dist)
        })
        .collect();

    // The circles and the arc each covers: a partial arc limits what can be told apart.
    let plane = main_plane(path);
    let angle = angles(&path.p_mm, plane);
    let (circles, runs) = split_runs_at(&path.t_s, &path.p_mm, &angle, plane, MAX_RUN_STEP_RAD);
    let arcs = arc_cover(&angle, &runs, circles.len());
    let partial = arcs.iter().any(ArcCover::is_partial);

    // 4. One pass: Gram of [set-up, scale_k, scale_mismatch_ij, other candidates, y].
    let others = candidate_effects(path);
    let mut effects = setup.to_vec();
    effects.extend(others.iter().filter(|e| matches!(e, Effect::Scale(_))));
    for pair in Pair::ALL {
        let (i, j) = pair.axes();
        if path.moves(i) && path.moves(j) {
            effects.push(Effect::ScaleMismatch(pair));
        }
    }
    effects.extend(others.iter().filter(|e| !matches!(e, Effect::Scale(_))));
    let cands: Vec<Candidate> = effects.iter().flat_map(|&e| search_forms(e)).collect();
    let design = Design::build(path, &y, cands);
    // If the isotropic scale is confounded with the set-up (one radius), the identifiable
    // candidates are the scale mismatches; otherwise the per-axis scales.
    let scale_cols: Vec<usize> = (0..design.cands.len())
        .filter(|&c| matches!(design.cands[c].effect, Effect::Scale(_)))
        .map(|c| design.offsets[c])
        .collect();
    let mut block: Vec<usize> = setup_free.clone();
    block.extend(&scale_cols);
    let isotropic_confounded = design.independent(&block).len() < block.len();
    if isotropic_confounded {
        let mut with_all_setup = vec![0, 1, 2, 3];
        with_all_setup.extend(&scale_cols);
        for g in design.confounded_names(&with_all_setup) {
            if g.iter().any(|n| n.starts_with("scale_")) && !confounded.contains(&g) {
                confounded.push(g);
            }
        }
    }
    confounded.retain(|g| !g.is_empty());
    let mut candidates: Vec<usize> = (2..design.cands.len())
        .filter(|&c| match design.cands[c].effect {
            Effect::Scale(_) => !isotropic_confounded,
            Effect::ScaleMismatch(_) => isotropic_confounded,
            _ => true,
        })
        .collect();
    if partial {
        for (c, group) in undetermined_on_arc(&design, &candidates, &setup_free) {
            candidates.retain(|&k| design.cands[k].effect != design.cands[c].effect);
            if !confounded.contains(&group) {
                confounded.push(group);
            }
        }
    }

    // 5. Linear forward selection on the Gram; a spike's trial decay times are one family.
    let free_setup = setup_free.clone();
    let families: Vec<Effect> = {
        let mut f: Vec<Effect> = candidates.iter().map(|&c| design.cands[c].effect).collect();
        f.dedup();
        f
    };
    let groups: Vec<Group> = candidates
        .iter()
        .map(|&c| {
            let effect = design.cands[c].effect;
            let cols = design.cols_of(c);
            Group {
                peak: cols.iter().map(|&i| design.peak[i]).collect(),
                cols,
                cost: effect.n_params(),
                family: families.iter().position(|&f| f == effect).unwrap_or(0),
            }
        })
        .collect();
    let sel = forward_select(&design.gram, m, &free_setup, &groups, &opts.select, &|i| {
        design.col_name(i)
    })?;
    for mut g in sel.confounded {
        g.dedup();
        if !confounded.contains(&g) {
            confounded.push(g);
        }
    }
    let below_floor: Vec<(String, f64)> = sel
        .below_floor
        .iter()
        .map(|&(g, bound)| (design.cands[candidates[g]].effect.name(), bound))
        .collect();
    let setup_rms = (sel.base_ssr / m as f64).sqrt();
    let current = &sel.current;
    let coef_of = |col: usize| {
        current
            .iter()
            .position(|&c| c == col)
            .map_or(0.0, |k| sel.coef[k])
    };

    // 6. Exact refit of set-up + chosen effects, from the linear solution (set-up from its exact
    // fit plus its linear correction). A search column dropped as confounded holds its exact
    // parameter (the servo delay's lag) at zero.
    // An effect whose value its own σ does not tell from zero (|value| < 2σ, possible only
    // where σ counts more than the fit's noise: a spike's height with the timing uncertainty) is
    // dropped and the rest refitted.
    let mut kept: Vec<usize> = (0..sel.steps.len()).collect();
    let mut not_significant: Vec<NotSignificant> = vec![];
    let (final_set, theta, final_ssr, mut found) = loop {
        let mut final_effects = setup.to_vec();
        let mut start = setup_theta.clone();
        for (k, &col) in current.iter().enumerate() {
            if col < 4 {
                start[col] += sel.coef[k];
            }
        }
        let mut free = free_setup.clone();
        for st in kept.iter().map(|&k| &sel.steps[k]) {
            let c = candidates[st.group];
            let cand = design.cands[c];
            let coef: Vec<f64> = design.cols_of(c).into_iter().map(coef_of).collect();
            let first = start.len();
            final_effects.push(cand.effect);
            start.extend(cand.start(&coef));
            let held_lag = matches!(cand.effect, Effect::ServoMismatch(_)) && st.cols.len() < 2;
            for k in 0..cand.effect.n_params() {
                if !(held_lag && k == 1) {
                    free.push(first + k);
                }
            }
        }
        let final_set = EffectSet::new(final_effects.clone());
        let (theta, sig, cov, final_ssr) = fit_exact(path, d_mm, &final_set, &free, &start, 1e-6)?;
        let chosen: Vec<(f64, f64, f64)> = kept
            .iter()
            .map(|&k| &sel.steps[k])
            .map(|st| (st.rms_after, st.rms_ratio, st.delta_bic))
            .collect();
        // Report.
        let mut found = vec![];
        for (ei, eff) in final_effects.iter().enumerate() {
            let o = final_set.offsets[ei];
            let n = eff.n_params();
            let params = theta[o..o + n].to_vec();
            let mut psig: Vec<Option<f64>> = sig[o..o + n].to_vec();
            let block: Vec<Vec<f64>> = (0..n)
                .map(|i| (0..n).map(|j| cov[(o + i, o + j)]).collect())
                .collect();
            let (value, mut sigma) = eff.value(&params, &block);
            if psig.iter().all(|s| s.is_none()) {
                sigma = None;
            }
            // A spike's height h·e^(−δt/τ) moves by h·δt/τ when the reversal's time is off by δt.
            if let (Effect::ReversalSpike(_), true) = (eff, path.timing_sigma_s > 0.0) {
                let extra = params[0] * 1e3 * path.timing_sigma_s / params[1].max(MIN_TAU_MS);
                let add = |s: Option<f64>| s.map(|s| s.hypot(extra));
                psig[0] = add(psig[0]);
                sigma = add(sigma);
            }
            let (rms_after_um, rms_ratio, delta_bic) = if ei < 2 {
                (setup_rms, baseline_rms_um / setup_rms.max(1e-300), f64::NAN)
            } else {
                chosen[ei - 2]
            };
            found.push(Found {
                effect: *eff,
                params,
                param_sigma: psig,
                value,
                sigma,
                rms_after_um,
                rms_ratio,
                delta_bic,
                contribution_rms_um: f64::NAN,
                share: f64::NAN,
            });
        }
        let weak = found
            .iter()
            .enumerate()
            .skip(2)
            .filter(|(_, f)| f.sigma.is_some_and(|s| f.value.abs() < 2.0 * s))
            .min_by(|a, b| {
                let z = |f: &Found| f.value.abs() / f.sigma.unwrap_or(f64::INFINITY);
                z(a.1).total_cmp(&z(b.1))
            })
            .map(|(ei, f)| {
                let weak = NotSignificant {
                    name: f.effect.name(),
                    unit: f.effect.unit(),
                    value: f.value,
                    sigma_value: f.sigma.unwrap_or(f64::NAN),
                    params: f
                        .effect
                        .param_names()
                        .iter()
                        .copied()
                        .zip(f.params.iter().copied())
                        .collect(),
                };
                (ei, weak)
            });
        match weak {
            Some((ei, weak)) => {
                not_significant.push(weak);
                kept.remove(ei - 2);
            }
            None => break (final_set, theta, final_ssr, found),
        }
    };
    let final_rms_um = (final_ssr / m as f64).sqrt();
    let candidates_tried: Vec<String> = {
        let mut names: Vec<String> = candidates
            .iter()
            .map(|&c| design.cands[c].effect.name())
            .collect();
        names.dedup();
        names
    };

    // Residual structure, G and H. The plotted deviations have the least-squares set-up of step 3
    // removed (the ballbar convention: centring and bar length are set-up, not machine); the
    // model's prediction gets the same treatment, so both curves show the same quantity.
    let full_mm = final_set.distances_mm(path, &theta);
    let model_setup = fit_setup(
        path,
        &full_mm,
        &setup_free,
        &[
            setup_theta[0],
            setup_theta[1],
            setup_theta[2],
            setup_theta[3],
        ],
    )?;
    let lsq_setup_um = [
        setup_theta[0],
        setup_theta[1],
        setup_theta[2],
        setup_theta[3],
    ];
    let mut meas = Vec::with_capacity(m);
    let mut model = Vec::with_capacity(m);
    let mut resid = Vec::with_capacity(m);
    for i in 0..m {
        let p = path.p_mm[i];
        meas.push(1e3 * (d_mm[i] - setup_distance_mm(p, &lsq_setup_um)));
        model.push(1e3 * (full_mm[i] - setup_distance_mm(p, &model_setup)));
        resid.push(1e3 * (d_mm[i] - full_mm[i]));
    }
    // Harmonics against the angle need the whole circle: on part of one they are not
    // orthogonal, and a fit of eight of them to half a circle blows up.
    let harmonics_um = if partial {
        vec![]
    } else {
        harmonics(&angle, &resid, opts.harmonics)
    };
    let (g, h) = circularity(&angle, &meas, &runs);
    let zones = circle_zones(path, &angle, &meas, &circles, &runs)?;
    // Each machine effect alone, with the plotted curve's set-up removal: its share of the error.
    let meas_ms = meas.iter().map(|x| x * x).sum::<f64>() / m as f64;
    for f in found.iter_mut().filter(|f| !f.effect.is_setup()) {
        let alone = EffectSet::new(vec![f.effect]).distances_mm(path, &f.params);
        let its_setup = fit_setup(path, &alone, &setup_free, &[0.0; 4])?;
        let ms = path
            .p_mm
            .iter()
            .zip(&alone)
            .map(|(p, d)| (1e3 * (d - setup_distance_mm(*p, &its_setup))).powi(2))
            .sum::<f64>()
            / m as f64;
        f.contribution_rms_um = ms.sqrt();
        f.share = if meas_ms > 0.0 {
            ms / meas_ms
        } else {
            f64::NAN
        };
    }
    Ok(Diagnosis {
        samples: m,
        baseline_rms_um,
        baseline_pv_um,
        effects: found,
        confounded,
        final_rms_um,
        gain: baseline_rms_um / final_rms_um.max(1e-300),
        harmonics_um,
        candidates: candidates_tried,
        below_floor,
        floor_um: opts.select.min_peak,
        not_significant,
        angle_rad: angle,
        measured_dev_um: meas,
        model_dev_um: model,
        lsq_setup_um,
        plane,
        circles,
        runs,
        circular_deviation_g_um: g,
        hysteresis_h_um: h,
        circle_zones: zones,
        pitch_mm: path.pitch_mm,
        arcs,
    })
}

/// On a partial arc, a candidate keeps at least this fraction of its column's norm² once the
/// set-up's columns (table-ball offset, length offset) and, for all but the scales, the scale
/// candidates' columns are projected out, or it is not tried: the arc cannot tell it from the
/// set-up and the scale. On a full circle every candidate keeps 10 % or more (a bowed axis,
/// u_k·p_k² ∝ cos³θ, keeps its cos 3θ part, 10 %). On the 220° vertical-plane test's 180° of
/// data (0° to 180°), the bow of the axis that reverses mid-arc keeps 0.13 % (sin³θ there is
/// nearly 1, sin θ and cos 2θ: set-up and scale mismatch), so it is not tried; the bow of the
/// axis that reverses at the data arc's ends keeps its 10 %, the scale mismatch 4.9 % (its σ
/// 4.5 times a full circle's per sample), squareness 28 %, backlash 100 %.
pub const PARTIAL_ARC_MIN_FREE: f64 = 0.01;

/// The candidates (of `candidates`, by index into `design.cands`; a spike's trial decay times
/// count as one) that a partial arc cannot tell from the set-up (columns `setup`) and the
/// scale ([`PARTIAL_ARC_MIN_FREE`]), each with the confounded group to report: its name and
/// the columns that carry it (each at least a tenth of the largest part of the projection), or
/// its name alone where it does not move on the data.
fn undetermined_on_arc(
    design: &Design,
    candidates: &[usize],
    setup: &[usize],
) -> Vec<(usize, Vec<String>)> {
    let mut out: Vec<(usize, Vec<String>)> = vec![];
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
        if out.iter().any(|(k, _)| design.cands[*k].effect == effect) {
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
                out.push((c, group));
            }
        }
    }
    out
}

/// The set-up's distance |p + c| + e (mm) for `setup_um` = [c_x, c_y, c_z, e] in µm.
fn setup_distance_mm(p: [f64; 3], setup_um: &[f64]) -> f64 {
    let q = [
        p[0] + 1e-3 * setup_um[0],
        p[1] + 1e-3 * setup_um[1],
        p[2] + 1e-3 * setup_um[2],
    ];
    (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + 1e-3 * setup_um[3]
}

/// D = |p + c| + e with only the set-up parameters `free` (indices into c_x, c_y, c_z, e)
/// varying, from `start`; returns [c_x, c_y, c_z, e] in µm.
fn fit_setup(path: &Path, d_mm: &[f64], free: &[usize], start: &[f64; 4]) -> Result<Vec<f64>> {
    struct Setup<'a> {
        path: &'a Path,
        d_mm: &'a [f64],
        free: &'a [usize],
    }
    impl Problem for Setup<'_> {
        fn n_params(&self) -> usize {
            self.free.len()
        }
        fn n_residuals(&self) -> usize {
            self.d_mm.len()
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            let mut full = [0.0; 4];
            for (a, &i) in self.free.iter().enumerate() {
                full[i] = p[a];
            }
            let mut g = [0.0; 4];
            for (i, (q0, d)) in self.path.p_mm.iter().zip(self.d_mm).enumerate() {
                let q = [
                    q0[0] + 1e-3 * full[0],
                    q0[1] + 1e-3 * full[1],
                    q0[2] + 1e-3 * full[2],
                ];
                let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
                let all = [q[0] / r, q[1] / r, q[2] / r, 1.0];
                for (a, &k) in self.free.iter().enumerate() {
                    g[a] = all[k];
                }
                visit(i, 1e3 * (r - d) + full[3], &g[..self.free.len()]);
            }
        }
    }
    let opts = LsqOptions {
        max_iterations: 50,
        // The final refit frees the set-up again: this fit only has to be good enough to
        // linearise the candidates around.
        tolerance: 1e-6,
        ..Default::default()
    };
    let prob = Setup { path, d_mm, free };
    let p0: Vec<f64> = free.iter().map(|&i| start[i]).collect();
    let fit = least_squares(&prob, &p0, &opts)?;
    let mut full = vec![0.0; 4];
    for (a, &i) in free.iter().enumerate() {
        full[i] = fit.params[a];
    }
    Ok(full)
}

/// Exact-geometry fit of `set` with only parameters `free` varying (others held at `start`).
/// Returns (θ, σ, covariance, SSR in µm²).
#[allow(clippy::type_complexity)]
fn fit_exact(
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

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

fn pv(v: &[f64]) -> f64 {
    let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    hi - lo
}

#[cfg(test)]
mod tests {
    use super::*;
    /// Simulated circular test, r = 50 mm, 100 Hz, 0.3 µm noise, 0.1 µm resolution.
    fn simulated(effects: &[super::super::simulate::EffectValue]) -> (Path, Vec<f64>) {
        use super::super::simulate::{distances_mm, measure, nominal_path, PathSpec};
        let spec = PathSpec {
            radii_mm: vec![50.0],
            heights_mm: vec![0.0],
            plane: (0, 1, 2),
            feed_mm_min: 1000.0,
            rate_hz: 100.0,
        };
        let (t, p) = nominal_path(&spec);
        let path = Path::new(t, p, [None; 3]);
        let mut d = distances_mm(&path, effects).unwrap();
        measure(&mut d, 0.3, 0.1, 11);
        (path, d)
    }

    fn ev(effect: Effect, params: Vec<f64>) -> super::super::simulate::EffectValue {
        super::super::simulate::EffectValue { effect, params }
    }

    #[test]
    fn plotted_deviation_has_the_setup_removed() {
        // Only set-up (centring 40, −25 µm; bar 15 µm long) and noise: the plotted measured
        // deviation is noise around zero, not the 47 µm eccentricity.
        let setup = [
            ev(Effect::SetupOffset, vec![40.0, -25.0, 0.0]),
            ev(Effect::LengthOffset, vec![15.0]),
        ];
        let (path, d) = simulated(&setup);
        let diag = diagnose(&path, &d, &Options::default()).unwrap();
        let meas = &diag.measured_dev_um;
        let mean = meas.iter().sum::<f64>() / meas.len() as f64;
        assert!(mean.abs() < 0.02, "mean radial deviation {mean} µm");
        let h1 = harmonics(&diag.angle_rad, meas, 1)[0];
        assert!(h1 < 0.05, "first harmonic (eccentricity) {h1} µm");
        assert!(rms(meas) < 0.4, "RMS {} µm", rms(meas));
        for (k, truth) in [40.0, -25.0, 0.0, 15.0].into_iter().enumerate() {
            assert!(
                (diag.lsq_setup_um[k] - truth).abs() < 0.1,
                "{:?}",
                diag.lsq_setup_um
            );
        }
        // No machine effect: the model's curve is the zero circle; G is the noise band only.
        assert!(diag.model_dev_um.iter().all(|v| v.abs() < 0.01));
        assert!(
            diag.circular_deviation_g_um < 3.0,
            "G {}",
            diag.circular_deviation_g_um
        );
        assert_eq!(diag.runs.len(), 2);

        // With a machine effect the model's curve follows the measured one to the noise.
        let mut with_backlash = setup.to_vec();
        with_backlash.push(ev(Effect::Backlash(Axis::X), vec![6.0]));
        let (path, d) = simulated(&with_backlash);
        let diag = diagnose(&path, &d, &Options::default()).unwrap();
        let diff: Vec<f64> = diag
            .measured_dev_um
            .iter()
            .zip(&diag.model_dev_um)
            .map(|(a, b)| a - b)
            .collect();
        assert!(rms(&diff) < 0.4, "measured − model RMS {}", rms(&diff));
        assert!(diag.circular_deviation_g_um > 5.0);
    }
}
