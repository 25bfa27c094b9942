//! The candidate search: the candidate effects of a path and the design matrix of their columns.
use super::*;

/// A parameter that gives an effect's size is determined when its σ is below this fraction of
/// it (`cannot_carry`; the 2σ rule on the value is the same bound).
pub const POORLY_DETERMINED: f64 = 0.5;

/// A search column: which candidate, which of its search parameters.
#[derive(Debug, Clone, Copy)]
pub(super) struct ColRef {
    pub(super) cand: usize,
    pub(super) k: usize,
}

/// The linearised design: all candidates' search columns at the nominal u, with y last.
pub(super) struct Design {
    pub(super) cands: Vec<Candidate>,
    /// First column of each candidate.
    pub(super) offsets: Vec<usize>,
    pub(super) cols: Vec<ColRef>,
    pub(super) gram: DMatrix<f64>,
    pub(super) yy: f64,
    /// Largest |value| of each search column over the samples (µm per unit parameter).
    pub(super) peak: Vec<f64>,
}

impl Design {
    /// One pass: accumulate the Gram matrix of the search columns (µm per unit parameter) and y
    /// (µm).
    pub(super) fn build(path: &Path, y_um: &[f64], cands: Vec<Candidate>) -> Design {
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

    /// The same search with some candidates' trial forms changed (the backlash columns at new
    /// trial gaps, the search's second pass): only the rows where a changed column differs by
    /// more than rounding (a dead band's take-up window after each reversal, a few per cent of
    /// a circle) are taken out of the Gram matrix and put back, so the pass costs a fraction of
    /// [`Design::build`]. Falls back to it when the candidates are not the same effects.
    pub(super) fn with_forms(self, path: &Path, y_um: &[f64], cands: Vec<Candidate>) -> Design {
        let same_shape = cands.len() == self.cands.len()
            && cands
                .iter()
                .zip(&self.cands)
                .all(|(a, b)| a.effect == b.effect);
        if !same_shape {
            return Design::build(path, y_um, cands);
        }
        let changed: Vec<usize> = (0..cands.len())
            .filter(|&c| cands[c] != self.cands[c])
            .collect();
        let m = y_um.len();
        let unit = |p: &[f64; 3]| {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            [p[0] / r, p[1] / r, p[2] / r]
        };
        let u: Vec<[f64; 3]> = path.p_mm.iter().map(unit).collect();
        let mut peak = self.peak.clone();
        let mut differs = vec![false; m];
        for &c in &changed {
            let nc = cands[c].n_cols();
            let mut old = vec![0.0; m * nc];
            let mut new = vec![0.0; m * nc];
            self.cands[c].columns_block(path, 0, &u, &mut old, nc, 0);
            cands[c].columns_block(path, 0, &u, &mut new, nc, 0);
            for (j, flag) in differs.iter_mut().enumerate() {
                for k in 0..nc {
                    let (a, b) = (old[j * nc + k], new[j * nc + k]);
                    if (a - b).abs() > 1e-12 * a.abs().max(b.abs()) {
                        *flag = true;
                    }
                }
            }
            let o = self.offsets[c];
            for (k, pk) in peak[o..o + nc].iter_mut().enumerate() {
                *pk = (0..m).map(|j| new[j * nc + k].abs()).fold(0.0, f64::max);
            }
        }
        let n = self.cols.len();
        let w = n + 1;
        let mut take_out = GramAccumulator::new(w);
        let mut put_back = GramAccumulator::new(w);
        let mut i0 = 0;
        while i0 < m {
            if !differs[i0] {
                i0 += 1;
                continue;
            }
            let mut len = 1;
            while i0 + len < m && len < GramAccumulator::ROWS && differs[i0 + len] {
                len += 1;
            }
            for (acc, forms) in [(&mut take_out, &self.cands), (&mut put_back, &cands)] {
                let block = acc.rows(len);
                for (cand, &o) in forms.iter().zip(&self.offsets) {
                    cand.columns_block(path, i0, &u[i0..i0 + len], block, w, o);
                }
                for j in 0..len {
                    block[j * w + n] = y_um[i0 + j];
                }
            }
            i0 += len;
        }
        let gram = self.gram - take_out.finish() + put_back.finish();
        Design {
            cands,
            gram,
            peak,
            ..self
        }
    }

    pub(super) fn ycol(&self) -> usize {
        self.cols.len()
    }

    pub(super) fn cols_of(&self, c: usize) -> Vec<usize> {
        let o = self.offsets[c];
        (o..o + self.cands[c].n_cols()).collect()
    }

    /// Name of column i for confounding reports: the effect, or `effect.component` for the
    /// set-up's components and the servo delay's common lag.
    pub(super) fn col_name(&self, i: usize) -> String {
        let cr = self.cols[i];
        let eff = self.cands[cr.cand].effect;
        match (eff, cr.k) {
            (Effect::SetupOffset, k) => format!("setup_offset.{}", ['x', 'y', 'z'][k]),
            (Effect::BacklashEnds(_), _) => format!("{}.ends", eff.name()),
            (Effect::ServoMismatch(_), 1) => format!("{}.lag", eff.name()),
            _ => eff.name(),
        }
    }

    /// Names of the columns (among `idx`) loaded by the null vectors of the block `idx`.
    pub(super) fn confounded_names(&self, idx: &[usize]) -> Vec<Vec<String>> {
        let mut out = confounded_names(&self.gram, idx, &|i| self.col_name(i));
        for g in &mut out {
            g.dedup();
        }
        out
    }

    /// Greedy: keep columns of `order` that raise the rank of what is kept.
    pub(super) fn independent(&self, order: &[usize]) -> Vec<usize> {
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
    // A bowed axis before the other axis's second-order scale: on one circle they are the same
    // data, and a bow is the common cause; the selection names the other as confounded.
    for &a in &moving {
        for &b in &moving {
            if a != b {
                v.push(Effect::Straightness(a, b));
            }
        }
    }
    for &a in &moving {
        if path.reversals[a.index()].is_empty() {
            continue;
        }
        for &b in &moving {
            if a != b {
                v.push(Effect::LateralPlay(a, b));
            }
        }
    }
    for &a in &moving {
        v.push(Effect::Scale2(a));
        v.push(Effect::Backlash(a));
        if !path.reversals[a.index()].is_empty() {
            v.push(Effect::BacklashEnds(a));
        }
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
    // Heat in time: an axis's scale and position growing during the test.
    for &a in &moving {
        v.push(Effect::ScaleDrift(a));
        v.push(Effect::PositionDrift(a));
    }
    if moving.len() >= 2 {
        v.push(Effect::FollowingError);
    }
    v
}

/// Whether search candidate `b` is (part of) the named effect `a`: itself, or a backlash of the
/// same axis (a uniform gap and the difference of its ends are named as one).
pub(super) fn same_effect(a: Effect, b: Effect) -> bool {
    a == b || backlash_axis(a).is_some_and(|k| backlash_axis(b) == Some(k))
}

/// The search forms of `effect`: one, a spike at each trial decay time, or a backlash with the
/// dead band of its axis's trial gap (`gaps_um`, see [`trial_gaps_um`]).
pub(super) fn search_forms(effect: Effect, gaps_um: &[f64; 3]) -> Vec<Candidate> {
    match effect {
        Effect::ReversalSpike(a) => SPIKE_TRIAL_TAU_MS
            .iter()
            .map(|&t| Candidate::spike(a, t))
            .collect(),
        Effect::Backlash(a) => vec![Candidate::backlash(a, false, gaps_um[a.index()])],
        Effect::BacklashEnds(a) => vec![Candidate::backlash(a, true, gaps_um[a.index()])],
        e => vec![Candidate::of(e)],
    }
}

/// The family a search form belongs to (forms of one family are alternatives): the effect's
/// name, and for the ends' difference of a backlash its own (it adds to the backlash).
pub(super) fn family_key(c: &Candidate) -> String {
    match c.effect {
        Effect::BacklashEnds(_) => format!("{}.ends", c.effect.name()),
        e => e.name(),
    }
}

/// Each axis's gap (µm) whose dead band shapes its backlash search column: the least-squares
/// backlash of the set-up residual `y_um` alone, with the column made again at the estimate a few
/// times (a fixed point; the dead band's window is a few per cent of a circle, so it converges
/// in two or three passes). A step (0) where the estimate is not positive.
pub(super) fn trial_gaps_um(path: &Path, y_um: &[f64]) -> [f64; 3] {
    let m = path.len();
    let u: Vec<[f64; 3]> = path
        .p_mm
        .iter()
        .map(|p| {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            [p[0] / r, p[1] / r, p[2] / r]
        })
        .collect();
    let mut gaps = [0.0; 3];
    let mut col = vec![0.0; m];
    for a in Axis::ALL {
        if !path.moves(a) || path.reversals[a.index()].is_empty() {
            continue;
        }
        let mut g = 0.0;
        for _ in 0..4 {
            Candidate::backlash(a, false, g).columns_block(path, 0, &u, &mut col, 1, 0);
            let cc: f64 = col.iter().map(|c| c * c).sum();
            if cc <= 0.0 {
                break;
            }
            let b = col.iter().zip(y_um).map(|(c, y)| c * y).sum::<f64>() / cc;
            if !(b.is_finite() && b > 0.0) {
                g = 0.0;
                break;
            }
            if (b - g).abs() < 0.01 * b {
                g = b;
                break;
            }
            g = b;
        }
        gaps[a.index()] = g;
    }
    gaps
}
