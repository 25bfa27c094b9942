//! Forward selection of model terms by BIC on a Gram matrix, and the rank tests it rests on: which
//! candidate columns the data support, which the data cannot tell apart. Shared by the circular
//! diagnosis (`diagnose`) and the angle-indexed rotary runs (`rotary::run_diagnosis`);
//! it sees only numbers and column names, never the physics.
//!
//! Selection: starting from the `base` columns, repeatedly add the candidate group that lowers
//! the extended BIC (Chen & Chen 2008)
//!
//! ```text
//! EBIC = m·ln(SSR/m) + penalty·k·ln m + 2γ·ln C(N, s)
//! ```
//!
//! most, while it lowers it; k counts the parameters, s the groups chosen out of N candidate
//! families. With γ = 0 this is plain BIC: one added parameter is a likelihood-ratio test at
//! χ²₁ > ln m, a false-alarm rate of P(χ²₁ > ln m) per candidate (0.16 % at m = 20 000). With
//! many candidates those rates add up; γ > 0 raises the bar of the first choice by 2γ·ln N (and
//! of later ones by 2γ·ln((N − s)/(s + 1))), keeping the chance of naming any effect in data
//! that have none small: with γ = ½ and N = 15, the first choice needs χ²₁ > ln m + ln 15,
//! P ≈ 5e-4 per candidate at m = 20 000. After each addition, a group chosen earlier that no
//! longer lowers EBIC is removed (stepwise selection): greedy forward selection can take a term
//! that only stood in for two that came later.
//!
//! Rank: columns that are linear combinations of others (singular values of the column-scaled
//! Gram block below [`RANK_TOLERANCE`] of the largest) are never fitted against each other; they
//! are named as confounded instead.
use nalgebra::{DMatrix, DVector, SymmetricEigen};

use crate::{Error, Result};

/// Singular values of the column-scaled design below this fraction of the largest count as zero
/// (the same rule as [`crate::numerics::lsq`]).
pub const RANK_TOLERANCE: f64 = 1e-7;

/// Knobs of [`forward_select`].
#[derive(Debug, Clone)]
pub struct SelectOptions {
    /// At most this many groups are selected.
    pub max_effects: usize,
    /// BIC penalty multiplier: a group with k parameters must lower m·ln(SSR/m) by more than
    /// `penalty · k · ln m`. 1.0 is plain BIC.
    pub penalty: f64,
    /// γ of the extended BIC (module docs): 0 is plain BIC; ½ controls the false alarms of a
    /// search over many candidates.
    pub gamma: f64,
    /// The floor (units of y): a group whose fitted columns reach less than this anywhere
    /// (Σ_c |β_c|·[`Group::peak`]_c, an upper bound of its largest contribution) is not chosen,
    /// however significant — it is below what the measurement can claim, and data of many
    /// samples make a model's smallest misfits significant. 0 turns it off.
    pub min_peak: f64,
}

impl Default for SelectOptions {
    fn default() -> Self {
        SelectOptions {
            max_effects: 8,
            penalty: 1.0,
            gamma: 0.0,
            min_peak: 0.0,
        }
    }
}

/// Column-scaled eigen-structure of a Gram block: (rank, unit null vectors in the block's index).
pub fn null_space(g: &DMatrix<f64>) -> (usize, Vec<DVector<f64>>) {
    let n = g.nrows();
    if n == 0 {
        return (0, vec![]);
    }
    // Dead columns (norm below 1e-10 of the largest) count as exactly zero, as in numerics::lsq.
    let norms: Vec<f64> = (0..n).map(|k| g[(k, k)].max(0.0).sqrt()).collect();
    let dmax = norms.iter().cloned().fold(0.0, f64::max);
    let dead: Vec<bool> = norms.iter().map(|&d| d <= 1e-10 * dmax).collect();
    let a = DMatrix::from_fn(n, n, |i, j| {
        if dead[i] || dead[j] {
            0.0
        } else {
            g[(i, j)] / (norms[i] * norms[j])
        }
    });
    let eig = SymmetricEigen::new(a);
    let emax = eig.eigenvalues.iter().cloned().fold(0.0f64, f64::max);
    let thr = RANK_TOLERANCE * RANK_TOLERANCE * emax;
    let mut nulls = vec![];
    let mut rank = 0;
    for (c, &e) in eig.eigenvalues.iter().enumerate() {
        if e > thr && emax > 0.0 {
            rank += 1;
        } else {
            nulls.push(eig.eigenvectors.column(c).into_owned());
        }
    }
    (rank, nulls)
}

/// The block of `g` on the rows and columns `idx`.
pub fn sub(g: &DMatrix<f64>, idx: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(idx.len(), idx.len(), |i, j| g[(idx[i], idx[j])])
}

/// Solve the normal equations on columns `idx` of the Gram `g` (whose last row/column is y):
/// returns (coefficients, SSR, (GᵀG)⁻¹ on idx). None if the block is rank deficient.
pub fn solve(
    g: &DMatrix<f64>,
    idx: &[usize],
    yy: f64,
    ycol: usize,
) -> Option<(Vec<f64>, f64, DMatrix<f64>)> {
    let a = sub(g, idx);
    let b = DVector::from_iterator(idx.len(), idx.iter().map(|&i| g[(i, ycol)]));
    let (rank, _) = null_space(&a);
    if rank < idx.len() {
        return None;
    }
    let s: Vec<f64> = (0..idx.len()).map(|k| a[(k, k)].sqrt()).collect();
    let scaled = DMatrix::from_fn(idx.len(), idx.len(), |i, j| a[(i, j)] / (s[i] * s[j]));
    let chol = scaled.cholesky()?;
    let inv_scaled = chol.inverse();
    let inv = DMatrix::from_fn(idx.len(), idx.len(), |i, j| {
        inv_scaled[(i, j)] / (s[i] * s[j])
    });
    let x = &inv * &b;
    let ssr = (yy - x.dot(&b)).max(0.0);
    Some((x.iter().cloned().collect(), ssr, inv))
}

/// A candidate group of columns for [`forward_select`].
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    /// Columns, most important first: a group that is not independent of the current model is
    /// tried with those of its leading columns that are (the others held at zero and reported as
    /// confounded).
    pub cols: Vec<usize>,
    /// Parameters the group costs in BIC: at least its columns (a nonlinear parameter that the
    /// search holds at a trial value, like a spike's decay time, still costs one).
    pub cost: usize,
    /// Groups of one family are alternatives (one effect at several trial values): once one of
    /// them is chosen, the others leave the search.
    pub family: usize,
    /// Largest |value| of each column over the samples, for [`SelectOptions::min_peak`]; empty
    /// for a group the floor does not apply to.
    pub peak: Vec<f64>,
}

impl Group {
    /// A group costing one parameter per column, alone in its family, without a floor.
    pub fn simple(cols: Vec<usize>, family: usize) -> Group {
        Group {
            cost: cols.len(),
            cols,
            family,
            peak: vec![],
        }
    }

    /// The most the group's columns with coefficients `coef` (of its columns `cols`, a leading
    /// part of its own) can contribute anywhere; None without peaks.
    fn bound(&self, cols: &[usize], coef: &[f64]) -> Option<f64> {
        (self.peak.len() == self.cols.len()).then(|| {
            cols.iter()
                .zip(coef)
                .map(|(c, b)| {
                    let k = self.cols.iter().position(|x| x == c).unwrap_or(0);
                    b.abs() * self.peak[k]
                })
                .sum()
        })
    }
}

/// One step of [`forward_select`].
#[derive(Debug, Clone)]
pub struct SelectionStep {
    /// Index into the candidate groups.
    pub group: usize,
    /// The group's columns that were added (all of them, or its leading independent ones).
    pub cols: Vec<usize>,
    /// RMS of the residual after this step (units of y).
    pub rms_after: f64,
    /// RMS before / after.
    pub rms_ratio: f64,
    /// BIC change (negative = better).
    pub delta_bic: f64,
}

/// The outcome of [`forward_select`].
#[derive(Debug, Clone)]
pub struct Selection {
    /// SSR of the base model.
    pub base_ssr: f64,
    pub steps: Vec<SelectionStep>,
    /// Columns of the final model: base, then the chosen groups' columns in order.
    pub current: Vec<usize>,
    /// Coefficients of `current` (linear least squares) and their covariance s²(XᵀX)⁻¹.
    pub coef: Vec<f64>,
    pub covariance: DMatrix<f64>,
    pub ssr: f64,
    /// Names of candidate columns found to lie in the span of the model, with what they are
    /// confounded with.
    pub confounded: Vec<Vec<String>>,
    /// Groups that would have lowered the BIC but stayed below [`SelectOptions::min_peak`] when
    /// last tried: (group, the bound of their contribution). One per family.
    pub below_floor: Vec<(usize, f64)>,
}

/// Forward selection by BIC on a Gram matrix whose last row/column is the data y: starting from
/// the `base` columns, repeatedly add the candidate group that lowers
/// BIC = m·ln(SSR/m) + penalty·k·ln m most (k: the parameters' cost), while it lowers it. A group
/// whose columns are (numerically) in the span of the current model is dropped, or cut to its
/// leading independent columns, and what is in the span is reported as confounded (names from
/// `col_name`). Used by `diagnose` and `diagnose-rotary`.
pub fn forward_select(
    gram: &DMatrix<f64>,
    m: usize,
    base: &[usize],
    groups: &[Group],
    opts: &SelectOptions,
    col_name: &dyn Fn(usize) -> String,
) -> Result<Selection> {
    let ycol = gram.nrows() - 1;
    let yy = gram[(ycol, ycol)];
    let mf = m as f64;
    let mut families: Vec<usize> = groups.iter().map(|g| g.family).collect();
    families.sort_unstable();
    families.dedup();
    let n_families = families.len();
    // ln C(N, s): the extended BIC's count of models with s of the N families.
    let ln_choose = |s: usize| -> f64 {
        (0..s.min(n_families))
            .map(|i| ((n_families - i) as f64 / (i + 1) as f64).ln())
            .sum()
    };
    let ebic = |ssr: f64, k: usize, s: usize| {
        mf * (ssr.max(1e-300) / mf).ln()
            + opts.penalty * k as f64 * mf.ln()
            + 2.0 * opts.gamma * ln_choose(s)
    };
    let mut current: Vec<usize> = base.to_vec();
    let mut cost = current.len();
    let base_ssr = if current.is_empty() {
        yy
    } else {
        solve(gram, &current, yy, ycol)
            .ok_or_else(|| Error::Numerics("the base model's columns are degenerate".into()))?
            .1
    };
    let mut ssr = base_ssr;
    let mut bic = ebic(ssr, cost, 0);
    let mut steps = vec![];
    let mut confounded: Vec<Vec<String>> = vec![];
    let note = |gs: Vec<Vec<String>>, confounded: &mut Vec<Vec<String>>| {
        for g in gs {
            if g.len() > 1 && !confounded.contains(&g) {
                confounded.push(g);
            }
        }
    };
    let mut remaining: Vec<usize> = (0..groups.len()).collect();
    let mut below_floor: Vec<(usize, f64)> = vec![];
    // Chosen groups in the order added: (group, its columns, its cost).
    let mut chosen: Vec<(usize, Vec<usize>, usize)> = vec![];
    let model_of = |chosen: &[(usize, Vec<usize>, usize)]| {
        let mut cols = base.to_vec();
        let mut k = base.len();
        for (_, c, kc) in chosen {
            cols.extend(c);
            k += kc;
        }
        (cols, k)
    };
    for _round in 0..4 * groups.len().max(1) {
        if chosen.len() >= opts.max_effects {
            break;
        }
        // (group, columns, cost, ssr, bic)
        let mut best: Option<(usize, Vec<usize>, usize, f64, f64)> = None;
        let mut skip = vec![];
        for &e in &remaining {
            let g = &groups[e];
            let mut trial = current.clone();
            trial.extend(&g.cols);
            let (cols, solved) = match solve(gram, &trial, yy, ycol) {
                Some(sol) => (g.cols.clone(), Some(sol)),
                None => {
                    note(confounded_names(gram, &trial, col_name), &mut confounded);
                    // The leading columns that are independent of the model, if any.
                    let mut kept = current.clone();
                    for &c in &g.cols {
                        kept.push(c);
                        if null_space(&sub(gram, &kept)).0 < kept.len() {
                            kept.pop();
                        }
                    }
                    let cols = kept[current.len()..].to_vec();
                    if cols.is_empty() {
                        (cols, None)
                    } else {
                        (cols, solve(gram, &kept, yy, ycol))
                    }
                }
            };
            let Some((coef, s, _)) = solved else {
                skip.push(e);
                continue;
            };
            let k = g.cost - (g.cols.len() - cols.len());
            let b = ebic(s, cost + k, chosen.len() + 1);
            let n_cur = coef.len() - cols.len();
            if let Some(bound) = g.bound(&cols, &coef[n_cur..]) {
                if bound < opts.min_peak {
                    if b < bic {
                        below_floor.retain(|(x, _)| groups[*x].family != g.family);
                        below_floor.push((e, bound));
                    }
                    continue;
                }
            }
            if best.as_ref().is_none_or(|bb| b < bb.4) {
                best = Some((e, cols, k, s, b));
            }
        }
        remaining.retain(|e| !skip.contains(e));
        let Some((e, cols, k, s, b)) = best else {
            break;
        };
        if b >= bic {
            break;
        }
        current.extend(&cols);
        cost += k;
        ssr = s;
        bic = b;
        chosen.push((e, cols, k));
        let family = groups[e].family;
        remaining.retain(|&x| groups[x].family != family);
        // Backward: a group chosen earlier that the model no longer needs (removing it lowers
        // BIC) leaves for good — greedy forward selection can take a term that only stood in
        // for two that came later.
        loop {
            let mut drop: Option<(usize, f64, f64)> = None;
            for idx in 0..chosen.len().saturating_sub(1) {
                let mut rest = chosen.clone();
                rest.remove(idx);
                let (cols, k) = model_of(&rest);
                if let Some((_, s, _)) = solve(gram, &cols, yy, ycol) {
                    let b = ebic(s, k, rest.len());
                    if b < bic && drop.is_none_or(|d| b < d.2) {
                        drop = Some((idx, s, b));
                    }
                }
            }
            let Some((idx, s, b)) = drop else { break };
            chosen.remove(idx);
            let (cols, k) = model_of(&chosen);
            current = cols;
            cost = k;
            ssr = s;
            bic = b;
        }
    }
    // The statistics of each step, replayed in the order the kept groups were added.
    let mut replay = base.to_vec();
    let mut k_replay = base.len();
    let mut ssr_before = base_ssr;
    let mut bic_before = ebic(base_ssr, k_replay, 0);
    for (n_sel, (e, cols, k)) in chosen.iter().enumerate() {
        replay.extend(cols);
        k_replay += k;
        let s = solve(gram, &replay, yy, ycol).map_or(ssr_before, |x| x.1);
        let b = ebic(s, k_replay, n_sel + 1);
        steps.push(SelectionStep {
            group: *e,
            cols: cols.clone(),
            rms_after: (s / mf).sqrt(),
            rms_ratio: (ssr_before / mf).sqrt() / (s / mf).sqrt().max(1e-300),
            delta_bic: b - bic_before,
        });
        ssr_before = s;
        bic_before = b;
    }
    let _ = ssr;
    let (coef, covariance) = match solve(gram, &current, yy, ycol) {
        Some((x, s, inv)) => {
            let dof = m.saturating_sub(current.len()).max(1);
            (x, inv * (s / dof as f64))
        }
        None => (vec![], DMatrix::zeros(0, 0)),
    };
    below_floor.retain(|(x, _)| {
        !chosen
            .iter()
            .any(|(c, _, _)| groups[*c].family == groups[*x].family)
    });
    Ok(Selection {
        base_ssr,
        steps,
        current,
        coef,
        covariance,
        ssr,
        confounded,
        below_floor,
    })
}

/// Names of the columns (among `idx`) loaded by the null vectors of the Gram block `idx`.
pub fn confounded_names(
    gram: &DMatrix<f64>,
    idx: &[usize],
    col_name: &dyn Fn(usize) -> String,
) -> Vec<Vec<String>> {
    // Dead columns (no effect on the data) are named alone; the rest from the null space of the
    // live columns, so a degenerate null space cannot tie a dead column to an unrelated group.
    let norms: Vec<f64> = idx.iter().map(|&i| gram[(i, i)].max(0.0).sqrt()).collect();
    let dmax = norms.iter().cloned().fold(0.0, f64::max);
    let mut out: Vec<Vec<String>> = vec![];
    let mut live = vec![];
    for (k, &i) in idx.iter().enumerate() {
        if norms[k] <= 1e-10 * dmax {
            let g = vec![col_name(i)];
            if !out.contains(&g) {
                out.push(g);
            }
        } else {
            live.push(i);
        }
    }
    let (_, nulls) = null_space(&sub(gram, &live));
    for v in nulls {
        let mut names: Vec<String> = (0..live.len())
            .filter(|&k| v[k].abs() >= 0.1)
            .map(|k| col_name(live[k]))
            .collect();
        names.dedup();
        if !names.is_empty() && !out.contains(&names) {
            out.push(names);
        }
    }
    out
}
