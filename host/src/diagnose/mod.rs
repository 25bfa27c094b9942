//! What the ideal-machine simulation gets wrong in a circular test, which machine
//! errors explain it, how large they are and how sure we are.
//!
//! Pipeline (see [`diagnose`]):
//! 1. Baseline: the ideal machine predicts D = |p_nominal|; report RMS and peak-to-valley (µm).
//! 2. Set-up: fit the table-ball offset c and the length offset e with the exact geometry
//!    D = |p − c| + e. Set-up parameters the path cannot determine (c_z on a flat circle) are
//!    held at zero and reported as confounded.
//! 3. Candidate search: every candidate effect of [`crate::model`] becomes columns of a linear
//!    model, linearised at the nominal path (seed 000 eq. 1: ΔR = u·δ, u = p/|p|), against the
//!    residual of step 2. One pass over the samples accumulates the Gram matrix of all columns; the
//!    forward selection then works on that small matrix only, which is why the whole search costs
//!    one pass (O(m·n²)) plus O(n³) per trial.
//! 4. Selection by extended BIC ([`crate::numerics::select`], γ = ½ in `Options::default()`) =
//!    m·ln(SSR/m) + k·ln(m) + 2γ·ln C(N, s): an effect is added while it lowers it. For the first
//!    of N candidate families with one parameter this is a likelihood-ratio test at
//!    χ²₁ > ln m + ln N, so the chance that data without any effect name one is at most
//!    N·P(χ²₁ > ln(m·N)) (≈ 0.6 % at m = 17 000, N = 15; the derivation and its test are in
//!    `docs/tests.md`).
//!    An effect must also reach [`MIN_EFFECT_UM`] on D somewhere on the test (the bound
//!    Σ|β_c|·max|column_c|): with tens of thousands of samples, misfits of a few nanometres —
//!    a backlash that is a dead zone rather than a step, a sample's timing off by a millisecond —
//!    are significant, and would be named as a squareness of 0.1 µm/m. They are listed as below
//!    the floor instead ([`Diagnosis::below_floor`]). The floor is checked again on each effect
//!    alone with its refitted parameters (step 6): where the exact model ties search columns
//!    together (a servo mismatch's lag difference and common lag) the bound can pass while the
//!    effect named does not.
//! 5. Identifiability: columns that are linear combinations of others (rank test on the
//!    column-scaled Gram matrix, singular values below 1e-7 of the largest) are never fitted
//!    against each other. If the isotropic scale is confounded with the length offset (one radius),
//!    the scale candidates become `scale_mismatch_ij` = scale_i − scale_j and the confounded group
//!    is named; a candidate that lies in the span of the current model is skipped and named with
//!    what it is confounded with. On a partial arc (the samples of a circle leave a gap, e.g. the
//!    220° vertical-plane test) a candidate the arc barely tells from the set-up and the scale
//!    ([`PARTIAL_ARC_MIN_FREE`]) is named with them in [`Diagnosis::weak_on_arc`], and one it
//!    cannot tell at all ([`PARTIAL_ARC_NONE`]) is not tried and named as confounded.
//! 6. The selected effects are refitted with the exact geometry ([`crate::model::ExactModel`]),
//!    giving the reported values ± standard errors, then the residual's harmonics against angle.
//!
//! The inputs are read by [`crate::diagnose::input`]; the report (text, JSON, plots) is [`crate::report`]
//! and [`crate::report::plot`].
//!
//! The folder `diagnose/`: [`input`] reads a test (`t_s,x_mm,y_mm,z_mm,d_mm`, or a record with
//! its path); [`runs`]: the circles as drawn (plane, angles, runs, G and H, harmonics);
//! [`zone`]: per circle, ISO 230-4 G and H with the minimum-zone centre; this module: baseline,
//! set-up, candidate search and selection, exact refit; [`pitch_hint`]: the pitch of a cyclic
//! error; [`planned`]: a planned test's diagnosis, the ramps read again through the errors it
//! finds. May use: [`crate::model`], [`crate::plan`], [`crate::sync`], [`crate::simulate`]
//! (`planned` follows a recording with [`crate::simulate::progress`]), [`crate::numerics`],
//! [`crate::table`]; nothing of `report`.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
mod diagnosis;
pub mod input;
pub mod pitch_hint;
pub mod planned;
pub mod reversal;
pub mod runs;
pub mod zone;
pub use diagnosis::*;
mod design;
pub use design::*;
mod refit;
use nalgebra::DMatrix;
pub use refit::*;

use crate::diagnose::input::MIN_SAMPLES;
use crate::diagnose::runs::{
    angles, arc_cover, harmonics, main_plane, split_runs_at, ArcCover, Circle, Run,
    MAX_RUN_STEP_RAD,
};
use crate::diagnose::zone::{circle_zones, filtered_g_um, CircleZone, FILTER_UPR};
use crate::model::path::median_interval;
use crate::model::{Axis, Candidate, Effect, EffectSet, ExactModel, Pair, Path, MIN_TAU_MS};
use crate::numerics::correlation;
use crate::numerics::lsq::{least_squares, GramAccumulator, LsqOptions, Subset};
use crate::numerics::select::{
    confounded_names, forward_select, null_space, solve, sub, Group, SelectOptions,
};
use crate::{Error, Result};

/// Diagnose a circular test: baseline, set-up, forward selection of machine effects, exact refit,
/// residual harmonics, G and H. See the module docs.
pub fn diagnose(path: &Path, d_mm: &[f64], opts: &Options) -> Result<Diagnosis> {
    let white = diagnose_counting(path, d_mm, opts, 1.0)?;
    if !opts.correlated_noise || white.noise_tau_int <= CORRELATED_TAU {
        return Ok(white);
    }
    // Correlated noise: select and state σ again as for m/τ independent samples.
    let tau = white.noise_tau_int;
    let mut d = diagnose_counting(path, d_mm, opts, tau)?;
    d.noise_tau_int = tau;
    Ok(d)
}

/// Whether the test comes back to a circle it has left in the same direction (`jdbb plan
/// --close`): then the change of that circle between its visits is growth in time, whatever the
/// radius and the direction. Circles run once each (ccw, then cw) tell growth in time from a
/// difference between the directions, or from a scale, only through the order they ran in.
fn closes_on_itself(runs: &[Run]) -> bool {
    let mut seen: Vec<(usize, bool)> = vec![];
    for (k, r) in runs.iter().enumerate() {
        let key = (r.circle, r.ccw);
        if k > 0 && (runs[k - 1].circle, runs[k - 1].ccw) == key {
            continue;
        }
        if seen.contains(&key) {
            return true;
        }
        seen.push(key);
    }
    false
}

/// On a test that does not close on itself: each axis whose scale is named, with its thermal
/// drift of scale, as a group the test cannot tell apart (heat growing a screw during the test
/// reads as scales there, docs/mechanisms.md).
fn drift_and_scale_confounded(found: &[Found]) -> Vec<Vec<String>> {
    let mut groups = vec![];
    for a in Axis::ALL {
        let named = found.iter().any(|f| f.effect == Effect::Scale(a));
        if named {
            groups.push(vec![Effect::ScaleDrift(a).name(), Effect::Scale(a).name()]);
        }
    }
    groups
}

/// Residuals whose integrated autocorrelation time (samples) is at most this count as white: the
/// batch-means estimate reads white noise at 1.0–1.8 ([`correlation::integrated_time`]).
pub const CORRELATED_TAU: f64 = 2.0;

/// [`diagnose`] with the samples worth `tau_int` each: the selection counts m/τ_int independent
/// samples and the standard errors grow by √τ_int (`numerics::correlation`).
fn diagnose_counting(path: &Path, d_mm: &[f64], opts: &Options, tau_int: f64) -> Result<Diagnosis> {
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

    // 3. Exact set-up fit D = |p − c| + e on the determined set-up parameters.
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
            let q = [p[0] - c_mm[0], p[1] - c_mm[1], p[2] - c_mm[2]];
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
    // Growth in time is told from what differs between the directions (play, lost motion per
    // end) and from a scale only where a circle is met again in the same direction: a test run
    // once (ccw early, cw late) reads a drift as a hysteresis (docs/mechanisms.md).
    let closed = closes_on_itself(&runs);
    let mut others = candidate_effects(path);
    others.retain(|e| closed || !e.is_drift_in_time());
    let mut effects = setup.to_vec();
    effects.extend(others.iter().filter(|e| matches!(e, Effect::Scale(_))));
    for pair in Pair::ALL {
        let (i, j) = pair.axes();
        if path.moves(i) && path.moves(j) {
            effects.push(Effect::ScaleMismatch(pair));
        }
    }
    effects.extend(others.iter().filter(|e| !matches!(e, Effect::Scale(_))));
    // The search, made again at the gaps it finds: a dead band's column depends on its gap, and
    // the first estimate (a step fitted alone) is pulled by whatever else the data hold.
    let confounded_before = confounded.clone();
    let mut gaps_um = trial_gaps_um(path, &y);
    let mut pass = 0;
    let mut weak: Vec<WeakOnArc> = vec![];
    let mut previous: Option<Design> = None;
    let (design, group_cands, sel) = loop {
        confounded = confounded_before.clone();
        weak.clear();
        let cands: Vec<Candidate> = effects
            .iter()
            .flat_map(|&e| search_forms(e, &gaps_um))
            .collect();
        let design = match previous.take() {
            Some(before) => before.with_forms(path, &y, cands),
            None => Design::build(path, &y, cands),
        };
        // If the isotropic scale is confounded with the set-up (one radius), the identifiable
        // candidates are the scale mismatches; otherwise the per-axis scales.
        let scale_cols: Vec<usize> = (0..design.cands.len())
            .filter(|&c| matches!(design.cands[c].effect, Effect::Scale(_)))
            .map(|c| design.offsets[c])
            .collect();
        let mut block: Vec<usize> = setup_free.clone();
        block.extend(&scale_cols);
        let scale_with_setup = design.independent(&block).len() < block.len();
        if scale_with_setup {
            let mut with_all_setup = vec![0, 1, 2, 3];
            with_all_setup.extend(&scale_cols);
            for g in design.confounded_names(&with_all_setup) {
                if g.iter().any(|n| n.starts_with("scale_")) && !confounded.contains(&g) {
                    confounded.push(g);
                }
            }
        }
        let following = following_error_confounding(&design, path, &runs, &scale_cols);
        for g in &following.groups {
            if !confounded.contains(g) {
                confounded.push(g.clone());
            }
        }
        // The isotropic scale is searched only where the test tells it from the set-up and
        // from the loops' following error; otherwise the scale mismatches are.
        let isotropic_confounded = scale_with_setup || following.hides_scale;
        confounded.retain(|g| !g.is_empty());
        // A second-order scale of j that a bow of another axis towards j already explains (one
        // circle: i² = R² − j²) is not searched; the bow is named, with the pair said.
        let mut twin_of_bow = vec![false; design.cands.len()];
        for (c2, cand2) in design.cands.iter().enumerate() {
            let Effect::Scale2(j) = cand2.effect else {
                continue;
            };
            for (cs, cands) in design.cands.iter().enumerate() {
                if !matches!(cands.effect, Effect::Straightness(_, b) if b == j) {
                    continue;
                }
                // Each alone adds to the set-up; together they do not.
                let with = |cols: &[usize]| {
                    let mut block = setup_free.clone();
                    block.extend(cols);
                    design.independent(&block).len() == block.len()
                };
                let (cols_s, cols_2) = (design.cols_of(cs), design.cols_of(c2));
                let both: Vec<usize> = cols_s.iter().chain(&cols_2).copied().collect();
                if with(&cols_s) && with(&cols_2) && !with(&both) {
                    twin_of_bow[c2] = true;
                    let g = vec![cands.effect.name(), cand2.effect.name()];
                    if !confounded.contains(&g) {
                        confounded.push(g);
                    }
                }
            }
        }
        let mut candidates: Vec<usize> = (2..design.cands.len())
            .filter(|&c| match design.cands[c].effect {
                Effect::FollowingError => following.searched,
                Effect::Scale(_) => !isotropic_confounded,
                Effect::ScaleMismatch(_) => isotropic_confounded,
                Effect::Scale2(_) => !twin_of_bow[c],
                _ => true,
            })
            .collect();
        if partial {
            for (c, group, free) in weak_on_arc(&design, &candidates, &setup_free) {
                if free < PARTIAL_ARC_NONE {
                    candidates.retain(|&k| design.cands[k].effect != design.cands[c].effect);
                    if !confounded.contains(&group) {
                        confounded.push(group);
                    }
                } else {
                    weak.push(WeakOnArc {
                        names: group,
                        free_fraction: free,
                    });
                }
            }
        }

        // 5. Linear forward selection on the Gram; a spike's trial decay times are one family.
        // Where the radii separate the isotropic scale, the plane's two scales are also offered
        // together (one group, two parameters): an isotropic scale moves each circle's radius
        // by s·R and neither axis's column alone shows that (each adds a 2θ term the data do
        // not hold), so one at a time the search would explain it with a drift and plays. The
        // two alone and the pair are one family: x, y or both.
        let group_cands: Vec<Vec<usize>> = {
            let scales: Vec<usize> = candidates
                .iter()
                .copied()
                .filter(|&c| matches!(design.cands[c].effect, Effect::Scale(_)))
                .collect();
            let mut g: Vec<Vec<usize>> = candidates.iter().map(|&c| vec![c]).collect();
            if scales.len() == 2 {
                g.push(scales);
            }
            g
        };
        let joint_scales = group_cands.len() > candidates.len();
        let key_of = |cs: &[usize]| -> String {
            let cand = &design.cands[cs[0]];
            if joint_scales && matches!(cand.effect, Effect::Scale(_)) {
                "scale".into()
            } else {
                family_key(cand)
            }
        };
        let families: Vec<String> = {
            let mut f: Vec<String> = vec![];
            for cs in &group_cands {
                let key = key_of(cs);
                if !f.contains(&key) {
                    f.push(key);
                }
            }
            f
        };
        let groups: Vec<Group> = group_cands
            .iter()
            .map(|cs| {
                let cols: Vec<usize> = cs.iter().flat_map(|&c| design.cols_of(c)).collect();
                let key = key_of(cs);
                Group {
                    peak: cols.iter().map(|&i| design.peak[i]).collect(),
                    // A spike's decay time costs a parameter although the search holds it.
                    cost: cs
                        .iter()
                        .map(|&c| match design.cands[c].effect {
                            Effect::BacklashEnds(_) => 1,
                            e => e.n_params(),
                        })
                        .sum(),
                    cols,
                    family: families.iter().position(|f| *f == key).unwrap_or(0),
                }
            })
            .collect();
        let m_independent = ((m as f64 / tau_int).round() as usize).clamp(2, m);
        let sel = forward_select(
            &design.gram,
            m_independent,
            &setup_free,
            &groups,
            &opts.select,
            &|i| design.col_name(i),
        )?;
        for mut g in sel.confounded.clone() {
            g.dedup();
            if !confounded.contains(&g) {
                confounded.push(g);
            }
        }
        pass += 1;
        let mut found = gaps_um;
        for st in &sel.steps {
            for &c in &group_cands[st.group] {
                if let Effect::Backlash(a) = design.cands[c].effect {
                    let col = design.offsets[c];
                    if let Some(k) = sel.current.iter().position(|&x| x == col) {
                        found[a.index()] = sel.coef[k].max(0.0);
                    }
                }
            }
        }
        let close = (0..3).all(|k| (found[k] - gaps_um[k]).abs() <= 0.05 * found[k] + 0.02);
        if close || pass == 3 {
            break (design, group_cands, sel);
        }
        gaps_um = found;
        previous = Some(design);
    };
    let mut below_floor: Vec<(String, f64)> = sel
        .below_floor
        .iter()
        .map(|&(g, bound)| {
            let names: Vec<String> = group_cands[g]
                .iter()
                .map(|&c| family_key(&design.cands[c]))
                .collect();
            (names.join("+"), bound)
        })
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
    // dropped and the rest refitted; so is one that, alone with its refitted parameters, moves D
    // by less than the floor (listed below it).
    let mut not_significant: Vec<NotSignificant> = vec![];
    let period_s = median_interval(&path.t_s);
    // Effects taken out after the refit (not significant, or under the floor): one effect, not
    // its whole step (the plane's two scales are one step where the radii separate them).
    let mut left_out: Vec<Effect> = vec![];
    let (final_set, theta, final_ssr, mut found, alone) = loop {
        // The selection's steps (less what was left out) as effects with their start parameters;
        // a backlash's uniform gap and the difference of its ends (two steps) become one
        // `BacklashEnds`.
        let mut chosen: Vec<Chosen> = vec![];
        for st in &sel.steps {
            for &c in &group_cands[st.group] {
                let cand = design.cands[c];
                if left_out.iter().any(|&e| same_effect(e, cand.effect)) {
                    continue;
                }
                let coef: Vec<f64> = design.cols_of(c).into_iter().map(coef_of).collect();
                let start = cand.start(&coef);
                let held_lag = matches!(cand.effect, Effect::ServoMismatch(_)) && st.cols.len() < 2;
                let twin = backlash_axis(cand.effect).and_then(|a| {
                    chosen
                        .iter()
                        .position(|ch| backlash_axis(ch.effect) == Some(a))
                });
                match twin {
                    Some(i) => {
                        let ch = &mut chosen[i];
                        // One is the uniform gap b, the other the ends' difference d = pos − neg.
                        let (b, d) = if let Effect::Backlash(_) = ch.effect {
                            (ch.start[0], start[0] - start[1])
                        } else {
                            (start[0], ch.start[0] - ch.start[1])
                        };
                        if let Some(a) = backlash_axis(cand.effect) {
                            ch.effect = Effect::BacklashEnds(a);
                        }
                        ch.start = vec![b + 0.5 * d, b - 0.5 * d];
                        ch.rms_after = st.rms_after;
                        ch.rms_ratio *= st.rms_ratio;
                        ch.delta_bic += st.delta_bic;
                    }
                    None => chosen.push(Chosen {
                        effect: cand.effect,
                        start,
                        held_lag,
                        rms_after: st.rms_after,
                        rms_ratio: st.rms_ratio,
                        delta_bic: st.delta_bic,
                    }),
                }
            }
        }
        let mut final_effects = setup.to_vec();
        let mut start = setup_theta.clone();
        for (k, &col) in current.iter().enumerate() {
            if col < 4 {
                start[col] += sel.coef[k];
            }
        }
        let mut free = setup_free.clone();
        for ch in &chosen {
            let first = start.len();
            final_effects.push(ch.effect);
            start.extend(&ch.start);
            for k in 0..ch.effect.n_params() {
                if !(ch.held_lag && k == 1) {
                    free.push(first + k);
                }
            }
        }
        let final_set = EffectSet::new(final_effects.clone());
        let (mut theta, mut sig, mut cov, mut final_ssr) =
            fit_exact(path, d_mm, &final_set, &free, &start, 1e-6)?;
        // A spike's refit can step out of its valley to a decay under a sample period (even
        // below zero, where the model holds τ at its least and the height has no gradient):
        // then the spike is not named and what it leaves is (issue 20's held-out seed 7245, a
        // 7.4 µm spike decaying over ten sample periods, refitted at τ = −0.83 ms). Started
        // again from each longer trial decay, the best fit whose spikes all decay over a sample
        // period or more is kept if it fits better.
        let spike_taus: Vec<usize> = final_effects
            .iter()
            .enumerate()
            .filter(|(_, e)| matches!(e, Effect::ReversalSpike(_)))
            .map(|(ei, _)| final_set.offsets[ei] + 1)
            .collect();
        let resolved = |th: &[f64]| spike_taus.iter().all(|&t| 1e-3 * th[t] >= period_s);
        if !resolved(&theta) {
            let stuck: Vec<usize> = spike_taus
                .iter()
                .copied()
                .filter(|&t| 1e-3 * theta[t] < period_s)
                .collect();
            for t in stuck {
                for &tau in SPIKE_TRIAL_TAU_MS
                    .iter()
                    .filter(|&&tau| 1e-3 * tau >= period_s)
                {
                    let mut again = start.clone();
                    again[t] = tau;
                    if let Ok(fit) = fit_exact(path, d_mm, &final_set, &free, &again, 1e-6) {
                        if fit.3 < final_ssr && resolved(&fit.0) {
                            (theta, sig, cov, final_ssr) = fit;
                        }
                    }
                }
            }
        }
        // Correlated noise: each σ also as the delete-a-block jackknife sees it (a wander of seconds
        // moves a lateral play or a drift by its whole power, a short-pitch cyclic error hardly),
        // whichever is larger than √τ_int times the white σ.
        let factor = if tau_int > 1.0 {
            robust_factors(
                path, d_mm, &final_set, &free, &theta, &cov, final_ssr, tau_int,
            )
        } else {
            vec![1.0; theta.len()]
        };
        for i in 0..theta.len() {
            sig[i] = sig[i].map(|s| s * factor[i]);
            for j in 0..theta.len() {
                cov[(i, j)] *= factor[i] * factor[j];
            }
        }
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
            // And a dead band on the same axis, taken up over Δθ ≈ √(2b/R) after the reversal,
            // ends when the axis moves at v·√(2b/R): mistimed by δt, it leaves a misfit of about
            // v·√(2b/R)·δt in the window, which is where the spike lives.
            if let (Effect::ReversalSpike(a), true) = (eff, path.timing_sigma_s > 0.0) {
                let mut extra = params[0] * 1e3 * path.timing_sigma_s / params[1].max(MIN_TAU_MS);
                let k = a.index();
                let gap_um = final_effects
                    .iter()
                    .zip(&final_set.offsets)
                    .filter(|(e, _)| backlash_axis(**e) == Some(*a))
                    .map(|(e, &o)| {
                        theta[o..o + e.n_params()]
                            .iter()
                            .cloned()
                            .fold(0.0, f64::max)
                    })
                    .fold(0.0, f64::max);
                let radius_mm = 0.5 * path.range_mm[k];
                if gap_um > 0.0 && radius_mm > 0.0 {
                    let v_mm_s = path.v_mm_s.iter().map(|v| v[k].abs()).fold(0.0, f64::max);
                    let window = v_mm_s * (2e-3 * gap_um / radius_mm).sqrt();
                    extra = extra.hypot(1e3 * window * path.timing_sigma_s);
                }
                let add = |s: Option<f64>| s.map(|s| s.hypot(extra));
                psig[0] = add(psig[0]);
                sigma = add(sigma);
            }
            let (rms_after_um, rms_ratio, delta_bic) = if ei < 2 {
                (setup_rms, baseline_rms_um / setup_rms.max(1e-300), f64::NAN)
            } else {
                let ch = &chosen[ei - 2];
                (ch.rms_after, ch.rms_ratio, ch.delta_bic)
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
                g_without_um: f64::NAN,
            });
        }
        // What the data cannot carry is not named: first an effect whose parameters the data do
        // not determine or whose decay is shorter than a sample period, then the one whose value
        // its σ tells least from zero (|value| < 2σ, possible only where σ counts more than the
        // fit's noise: a spike's height with the timing uncertainty).
        let weak = found
            .iter()
            .enumerate()
            .skip(2)
            .find_map(|(ei, f)| cannot_carry(f, period_s).map(|r| (ei, r)))
            .or_else(|| {
                found
                    .iter()
                    .enumerate()
                    .skip(2)
                    .filter(|(_, f)| f.sigma.is_some_and(|s| f.value.abs() < 2.0 * s))
                    .min_by(|a, b| {
                        let z = |f: &Found| f.value.abs() / f.sigma.unwrap_or(f64::INFINITY);
                        z(a.1).total_cmp(&z(b.1))
                    })
                    .map(|(ei, _)| {
                        let reason =
                            "its value is within 2σ of zero (σ with the timing uncertainty)";
                        (ei, reason.to_string())
                    })
            })
            .map(|(ei, reason)| (ei, NotSignificant::of(&found[ei], reason)));
        if let Some((ei, weak)) = weak {
            not_significant.push(weak);
            left_out.push(found[ei].effect);
            continue;
        }
        // A ring after the reversals is vibration, never a reversal spike (issue 26).
        if let Some((ei, reason)) = reversal::ringing_spike(path, d_mm, &final_set, &theta) {
            not_significant.push(NotSignificant::of(&found[ei], reason));
            left_out.push(found[ei].effect);
            continue;
        }
        // Each machine effect alone with its refitted parameters: its peak on D for the floor
        // here, its set-up projection for its share below (one pass each, nothing kept).
        let alone: Vec<Option<Alone>> = found
            .iter()
            .map(|f| (!f.effect.is_setup()).then(|| Alone::of(path, f, &setup_free)))
            .collect();
        // The floor again, on the refitted value: the search's bound is that of its linear
        // columns, and where the exact model ties them (a servo mismatch's second column, the
        // lag difference times the common lag, is free in the search and takes up a
        // scale-mismatch-shaped misfit there: cos 2θ·v²/R on a circle) the named effect can
        // move D by less than the floor.
        let peak_um = |ei: usize| alone[ei].as_ref().map_or(f64::INFINITY, |a| a.peak_um);
        let low = (2..found.len())
            .map(|ei| (ei, peak_um(ei)))
            .filter(|&(_, peak)| peak < opts.select.min_peak)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((ei, peak)) = low {
            let name = found[ei].effect.name();
            below_floor.retain(|(n, _)| *n != name);
            below_floor.push((name, peak));
            left_out.push(found[ei].effect);
            continue;
        }
        break (final_set, theta, final_ssr, found, alone);
    };
    let final_rms_um = (final_ssr / m as f64).sqrt();
    let candidates_tried: Vec<String> = {
        let mut names: Vec<String> = vec![];
        for &c in group_cands.iter().flatten() {
            let name = design.cands[c].effect.name();
            if !names.contains(&name) {
                names.push(name);
            }
        }
        names
    };

    // Residual structure, G and H. The plotted deviations have the fitted set-up removed (the
    // one centre of every output, issue 31: centring and bar length are set-up, not machine);
    // the model's prediction gets the same treatment, so both curves show the same quantity:
    // the model's curve is its machine effects alone.
    let full_mm = final_set.distances_mm(path, &theta);
    let fitted_setup_um = fitted_setup_um(&found);
    // fit_setup's t is where the table ball is: D = |p − t| + e.
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
        meas.push(1e3 * (d_mm[i] - setup_distance_mm(p, &fitted_setup_um)));
        model.push(1e3 * (full_mm[i] - setup_distance_mm(p, &fitted_setup_um)));
        resid.push(1e3 * (d_mm[i] - full_mm[i]));
    }
    // Harmonics against the angle need the whole circle: on part of one they are not
    // orthogonal, and a fit of eight of them to half a circle blows up.
    let harmonics_um = if partial {
        vec![]
    } else {
        harmonics(&angle, &resid, opts.harmonics)
    };
    let pitch_hint = crate::diagnose::pitch_hint::pitch_hint(path, &resid);
    let zones = circle_zones(path, &angle, &meas, &circles, &runs)?;
    let filtered_g_um = filtered_g_um(&angle, &meas, &runs, circles.len(), FILTER_UPR)?;
    // Blocks up to the longest the estimate allows: the effects live at the circle's low
    // harmonics and a drift over the whole test, where a slow wander competes with them.
    let noise_tau_int = correlation::integrated_time(&resid, m);
    let g = zones.iter().map(CircleZone::g_um).fold(0.0, f64::max);
    let h = zones.iter().map(|z| z.h_um).fold(0.0, f64::max);
    // Each machine effect alone, with the plotted curve's set-up removal: its share of the error.
    // An effect alone moves the ball by micrometres, where the set-up fit is linear: its set-up
    // is the projection on the set-up probe's columns (−u, 1), and what is left has the mean
    // square (rᵀr − rᵀJ·θ)/m, one pass per effect.
    let setup_normal = setup_probe
        .gram
        .select_rows(&setup_free)
        .select_columns(&setup_free);
    let setup_chol = setup_normal.cholesky().ok_or_else(|| {
        Error::Numerics("the set-up fit is singular: the path does not determine it".into())
    })?;
    for (f, a) in found.iter_mut().zip(&alone) {
        let Some(Alone { rr, jtr, .. }) = a else {
            continue;
        };
        let its_setup = setup_chol.solve(jtr);
        let ms = (rr - jtr.dot(&its_setup)).max(0.0) / m as f64;
        f.contribution_rms_um = ms.sqrt();
    }
    let residual_ms = final_rms_um * final_rms_um;
    let total_ms = residual_ms
        + found
            .iter()
            .filter(|f| !f.effect.is_setup())
            .map(|f| f.contribution_rms_um.powi(2))
            .sum::<f64>();
    let share = |ms: f64| {
        if total_ms > 0.0 {
            ms / total_ms
        } else {
            f64::NAN
        }
    };
    for f in found.iter_mut().filter(|f| !f.effect.is_setup()) {
        f.share = share(f.contribution_rms_um.powi(2));
    }
    // A speed-dependent cyclic term that is the cyclic error read where a lagging axis is: kept
    // in the model (D holds it), named as part of the cyclic error, not as an effect of its own.
    let explained = lag_explained(&found, path);
    // What G would be without each machine effect (with the interference named as part of it).
    let traces = Traces {
        path,
        angle: &angle,
        meas: &meas,
        circles: &circles,
        runs: &runs,
    };
    for k in (2..found.len()).filter(|k| !explained.iter().any(|e| e.0 == *k)) {
        let mut group = vec![k];
        group.extend(explained.iter().filter(|e| e.1 == k).map(|e| e.0));
        found[k].g_without_um = traces.g_without_um(&found, &group)?;
    }
    // What G would be with the compensable effects entered as settings (each with the
    // interference named as part of it).
    let mut compensable: Vec<usize> = (2..found.len())
        .filter(|&k| {
            let f = &found[k];
            crate::model::settable::is_setting(f.effect, opts.controller)
                && f.sigma.is_some_and(|s| {
                    f.value.abs() >= crate::model::settable::SIGNIFICANT_SIGMAS * s
                })
                && !explained.iter().any(|e| e.0 == k)
        })
        .collect();
    let parts: Vec<usize> = explained
        .iter()
        .filter(|e| compensable.contains(&e.1))
        .map(|e| e.0)
        .collect();
    compensable.extend(parts);
    let g_if_compensated_um = if compensable.is_empty() {
        g
    } else {
        traces.g_without_um(&found, &compensable)?
    };
    for &(ii, ci, _) in &explained {
        let (rms, sh) = (found[ii].contribution_rms_um, found[ii].share);
        found[ci].contribution_rms_um = found[ci].contribution_rms_um.hypot(rms);
        found[ci].share += sh;
    }
    for (ii, _, reason) in explained.into_iter().rev() {
        let f = found.remove(ii);
        not_significant.push(NotSignificant::of(&f, reason));
    }
    if !closed {
        for g in drift_and_scale_confounded(&found) {
            if !confounded.contains(&g) {
                confounded.push(g);
            }
        }
    }
    let radius_loss = radius_losses(path, &found, &runs, &circles);
    let reversal_peaks = reversal::reversal_peaks(path, &resid, &final_set, &theta);
    Ok(Diagnosis {
        samples: m,
        baseline_rms_um,
        baseline_pv_um,
        effects: found,
        confounded,
        final_rms_um,
        residual_share: share(residual_ms),
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
        g_if_compensated_um,
        hysteresis_h_um: h,
        pitch_hint,
        circle_zones: zones,
        filtered_g_um,
        filter_upr: FILTER_UPR,
        pitch_mm: path.pitch_mm,
        arcs,
        weak_on_arc: weak,
        noise_tau_int,
        radius_loss,
        reversal_peaks,
    })
}

/// Per parameter of a refit, what its white-noise σ is multiplied by when the samples are
/// correlated: √τ_int, or more where the delete-a-block jackknife
/// ([`correlation::block_jackknife_variance`]) says the parameter's own weights see more of the
/// noise (1 for parameters held).
#[allow(clippy::too_many_arguments)]
fn robust_factors(
    path: &Path,
    d_mm: &[f64],
    set: &EffectSet,
    free: &[usize],
    theta: &[f64],
    cov: &DMatrix<f64>,
    ssr: f64,
    tau_int: f64,
) -> Vec<f64> {
    let n = theta.len();
    let mut factor = vec![1.0; n];
    if !(ssr > 0.0 && ssr.is_finite()) {
        return factor;
    }
    let model = ExactModel { path, d_mm, set };
    let restricted = Subset {
        inner: &model,
        free,
        base: theta,
    };
    let p: Vec<f64> = free.iter().map(|&i| theta[i]).collect();
    let v = correlation::block_jackknife_variance(&restricted, &p);
    for (k, &i) in free.iter().enumerate() {
        let white = cov[(i, i)];
        factor[i] = if white > 0.0 && v[k].is_finite() {
            tau_int.sqrt().max((v[k] / white).sqrt())
        } else {
            tau_int.sqrt()
        };
    }
    factor
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
mod tests;
