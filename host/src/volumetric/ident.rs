//! What one table-ball position can identify: the design matrix of the linear volumetric model
//! over a test's data arcs, its numerical rank, singular values and condition number, and the
//! combinations of terms it cannot tell apart (its null space, named in effects).
//!
//! # The model
//!
//! The spindle ball's nominal position relative to the table ball is p (mm), D₀ = |p|, û = p/D₀.
//! A linear error field moves it by δ = E·p; the table ball sits c off its nominal place (the
//! set-up offset); the instrument reads lengths (1 + k) times too long when its bar-length sum
//! L1 + L2 is off by k (D of the two-bar linkage scales with L1 + L2). To first order
//!
//! ```text
//! D − D₀ = ûᵀ·E·p − ûᵀ·c + k·D₀,
//! ```
//!
//! and ûᵀ·E·p = pᵀ·E·p / D₀ sees only the symmetric part of E: a rotation (the antisymmetric
//! part) moves the ball across the bar, not along it. The symmetric part is the three scales
//! (E_xx, E_yy, E_zz: `scale_x`, …) and the three squarenesses; a squareness is written as the
//! plane diagnosis writes it ([`crate::model::Effect::Squareness`]): `squareness_xy` is
//! δx = s·y, so ∂D/∂s = u_x·p_y. Ten terms ([`Term::ALL`]): 3 scales, 3 squarenesses (µm/m),
//! the set-up offset in x, y, z (µm) and the instrument's scale (µm/m).
//!
//! The mean of the three scales moves D by s̄·D₀ everywhere, exactly as the instrument's scale
//! does: no test from one mount tells them apart. The instrument's calibration (its L1 + L2,
//! measured on a calibrator) is the length reference, so the fit fixes k = 0 and leaves nine
//! terms; [`Identifiability`] reports both the ten-term rank and the nine-term one.
//!
//! # Numbers
//!
//! Rows are the data arcs' points (one per mm of path, [`SAMPLE_STEP_MM`], as a record at a
//! constant feed and sample rate has them). Columns are scaled to
//! unit Euclidean norm before the singular value decomposition (nalgebra's SVD): each term in
//! the unit that moves D by one unit in the root-sum-square over the test, so that the condition
//! number does not depend on the units chosen (µm/m against µm). The rank counts singular values
//! above [`RANK_TOLERANCE`] times the largest; the condition number is the largest over the
//! smallest of those, of the nine terms with the calibration as the length reference.
use nalgebra::{DMatrix, SVD};

use crate::model::path::{Axis, Pair};

/// Relative size below which a singular value counts as zero (the rank's tolerance).
pub const RANK_TOLERANCE: f64 = 1e-9;
/// One row of the design matrix per this much path (mm) of each data arc: a record at a
/// constant feed and sample rate has as many samples per mm on every element.
pub const SAMPLE_STEP_MM: f64 = 1.0;
/// A coefficient of a named confounded combination smaller than this (relative to its largest)
/// is left out of its name.
const SHOW_COEFFICIENT: f64 = 1e-6;

/// A term of the linear volumetric model (see the module docs for each one's ∂D).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Term {
    /// E_aa, µm/m.
    Scale(Axis),
    /// δ_a = s·p_b for the pair (a, b), µm/m.
    Squareness(Pair),
    /// The table ball's set-up offset along an axis, µm.
    SetupOffset(Axis),
    /// The instrument's scale (its bar-length sum L1 + L2 off), µm/m: the length reference.
    InstrumentScale,
}

impl Term {
    /// The ten terms, in the design matrix's column order.
    pub const ALL: [Term; 10] = [
        Term::Scale(Axis::X),
        Term::Scale(Axis::Y),
        Term::Scale(Axis::Z),
        Term::Squareness(Pair::Xy),
        Term::Squareness(Pair::Yz),
        Term::Squareness(Pair::Zx),
        Term::SetupOffset(Axis::X),
        Term::SetupOffset(Axis::Y),
        Term::SetupOffset(Axis::Z),
        Term::InstrumentScale,
    ];

    /// The name as in the diagnosis's JSON: `scale_x`, `squareness_xy`, `setup_offset_z`,
    /// `instrument_scale`.
    pub fn name(self) -> String {
        match self {
            Term::Scale(a) => format!("scale_{}", a.letter()),
            Term::Squareness(p) => format!("squareness_{}", p.name()),
            Term::SetupOffset(a) => format!("setup_offset_{}", a.letter()),
            Term::InstrumentScale => "instrument_scale".into(),
        }
    }

    /// The unit of the term's value: `um/m` or `um`.
    pub fn unit(self) -> &'static str {
        match self {
            Term::SetupOffset(_) => "um",
            _ => "um/m",
        }
    }

    /// ∂D/∂term (µm of D per unit of the term) at the nominal position `p_mm` of the spindle
    /// ball relative to the table ball.
    pub fn partial_um(self, p_mm: [f64; 3]) -> f64 {
        let d = (p_mm[0] * p_mm[0] + p_mm[1] * p_mm[1] + p_mm[2] * p_mm[2]).sqrt();
        let u = p_mm.map(|x| x / d);
        match self {
            // µm/m × mm = 1e-3 µm.
            Term::Scale(a) => 1e-3 * u[a.index()] * p_mm[a.index()],
            Term::Squareness(pair) => {
                let (a, b) = pair.axes();
                1e-3 * u[a.index()] * p_mm[b.index()]
            }
            Term::SetupOffset(a) => -u[a.index()],
            Term::InstrumentScale => 1e-3 * d,
        }
    }
}

/// The design matrix ∂D/∂(terms) at the given positions (mm, relative to the table ball): one
/// row per position, one column per [`Term::ALL`] entry, in µm per unit.
pub fn design_matrix(points_mm: &[[f64; 3]]) -> DMatrix<f64> {
    DMatrix::from_fn(points_mm.len(), Term::ALL.len(), |r, c| {
        Term::ALL[c].partial_um(points_mm[r])
    })
}

/// What a test determines of the linear volumetric model (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Identifiability {
    /// Rows of the design matrix (points of the data arcs).
    pub rows: usize,
    /// Rank of the ten-term design (instrument scale free).
    pub rank: usize,
    /// Its singular values, columns scaled to unit norm, largest first.
    pub singular_values: Vec<f64>,
    /// Rank of the nine-term design: the instrument's calibration as the length reference.
    pub rank_with_reference: usize,
    /// Condition number of the nine-term design (columns scaled to unit norm): largest over
    /// smallest non-zero singular value.
    pub condition: f64,
    /// Per term of [`Term::ALL`] (without the instrument's scale): whether the nine-term design
    /// determines it alone.
    pub determined: Vec<(Term, bool)>,
    /// The combinations the ten-term design cannot see: a basis of its null space in reduced row
    /// echelon form (each combination led by one term with coefficient 1), in the terms' units.
    pub confounded: Vec<Vec<(Term, f64)>>,
}

/// The identifiability of a test whose data arcs pass through `points_mm` (relative to the
/// table ball, mm). Refuses nothing: a test that sees nothing has rank 0.
pub fn identifiability(points_mm: &[[f64; 3]]) -> Identifiability {
    let a = design_matrix(points_mm);
    let (scaled, norms) = unit_columns(&a);
    let svd = SVD::new(scaled.clone(), false, true);
    let mut sv: Vec<f64> = svd.singular_values.iter().copied().collect();
    sv.sort_by(|x, y| y.total_cmp(x));
    let top = sv.first().copied().unwrap_or(0.0);
    let rank = sv.iter().filter(|s| **s > RANK_TOLERANCE * top).count();
    let confounded = null_space(&scaled, &norms);

    // The nine terms with the calibration as the length reference.
    let nine = a.columns(0, Term::ALL.len() - 1).into_owned();
    let (scaled9, norms9) = unit_columns(&nine);
    let mut sv9: Vec<f64> = SVD::new(scaled9.clone(), false, false)
        .singular_values
        .iter()
        .copied()
        .collect();
    sv9.sort_by(|x, y| y.total_cmp(x));
    let top9 = sv9.first().copied().unwrap_or(0.0);
    let kept: Vec<f64> = sv9
        .iter()
        .copied()
        .filter(|s| *s > RANK_TOLERANCE * top9)
        .collect();
    let rank_with_reference = kept.len();
    let condition = match kept.last() {
        Some(low) => top9 / low,
        None => f64::INFINITY,
    };
    let null9 = null_space(&scaled9, &norms9);
    let determined = Term::ALL[..Term::ALL.len() - 1]
        .iter()
        .enumerate()
        .map(|(k, t)| {
            let seen = null9
                .iter()
                .all(|v| v.iter().all(|(u, _)| *u != Term::ALL[k]));
            (*t, seen)
        })
        .collect();
    Identifiability {
        rows: points_mm.len(),
        rank,
        singular_values: sv,
        rank_with_reference,
        condition,
        determined,
        confounded,
    }
}

/// `a` with every column scaled to unit norm, and the norms (a zero column stays zero, norm 1).
fn unit_columns(a: &DMatrix<f64>) -> (DMatrix<f64>, Vec<f64>) {
    let norms: Vec<f64> = a
        .column_iter()
        .map(|c| {
            let n = c.norm();
            if n > 0.0 {
                n
            } else {
                1.0
            }
        })
        .collect();
    let mut s = a.clone();
    for (k, mut c) in s.column_iter_mut().enumerate() {
        c /= norms[k];
    }
    (s, norms)
}

/// A basis of the null space of `scaled` (columns scaled by `norms`), in the original units,
/// in reduced row echelon form, each vector as (term, coefficient) pairs without the negligible
/// ones. The terms are the first `scaled.ncols()` of [`Term::ALL`].
fn null_space(scaled: &DMatrix<f64>, norms: &[f64]) -> Vec<Vec<(Term, f64)>> {
    let n = scaled.ncols();
    // Zero rows up to a square matrix, so that the SVD gives all n right singular vectors.
    let rows = scaled.nrows().max(n);
    let a = DMatrix::from_fn(rows, n, |r, c| {
        if r < scaled.nrows() {
            scaled[(r, c)]
        } else {
            0.0
        }
    });
    let svd = SVD::new(a, false, true);
    let v_t = svd.v_t.expect("asked for V");
    let top = svd.singular_values.max();
    let basis: Vec<Vec<f64>> = (0..n)
        .filter(|&k| svd.singular_values[k] <= RANK_TOLERANCE * top)
        .map(|k| (0..n).map(|c| v_t[(k, c)] / norms[c]).collect())
        .collect();
    rref(basis)
        .into_iter()
        .map(|v| {
            let big = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            v.iter()
                .enumerate()
                .filter(|(_, x)| x.abs() > SHOW_COEFFICIENT * big)
                .map(|(c, x)| (Term::ALL[c], *x))
                .collect()
        })
        .collect()
}

/// Reduced row echelon form of the rows (partial pivoting), each row's leading entry 1.
fn rref(mut rows: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    let m = rows.len();
    let n = rows.first().map_or(0, Vec::len);
    let mut r = 0;
    for c in 0..n {
        if r == m {
            break;
        }
        let (p, best) = (r..m)
            .map(|k| (k, rows[k][c].abs()))
            .fold((r, -1.0), |a, b| if b.1 > a.1 { b } else { a });
        if best < 1e-9 {
            continue;
        }
        rows.swap(r, p);
        let lead = rows[r][c];
        for x in rows[r].iter_mut() {
            *x /= lead;
        }
        for k in 0..m {
            if k != r {
                let f = rows[k][c];
                if f != 0.0 {
                    let pivot = rows[r].clone();
                    for (x, y) in rows[k].iter_mut().zip(&pivot) {
                        *x -= f * y;
                    }
                }
            }
        }
        r += 1;
    }
    for row in rows.iter_mut() {
        for x in row.iter_mut() {
            if x.abs() < 1e-9 {
                *x = 0.0;
            }
        }
    }
    rows
}

/// A confounded combination as a person reads it: `scale_x + scale_y + scale_z +
/// 3·instrument_scale` stays unseen (coefficients to two decimals, in the terms' units).
pub fn combination_text(v: &[(Term, f64)]) -> String {
    let mut s = String::new();
    for (k, (t, x)) in v.iter().enumerate() {
        let sign = if *x < 0.0 { "−" } else { "+" };
        let a = x.abs();
        let coef = if (a - 1.0).abs() < 5e-3 {
            String::new()
        } else {
            format!("{}·", trim(a))
        };
        if k == 0 {
            if *x < 0.0 {
                s.push('−');
            }
        } else {
            s.push_str(&format!(" {sign} "));
        }
        s.push_str(&format!("{coef}{}", t.name()));
    }
    s
}

/// A coefficient to two decimals without trailing zeros.
fn trim(x: f64) -> String {
    let s = format!("{x:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// What would separate a confounded combination: the instrument's calibration for the mean
/// scale, circles at more heights (cones) or vertical arcs for terms along z.
pub fn separation_text(v: &[(Term, f64)]) -> &'static str {
    let has = |f: &dyn Fn(Term) -> bool| v.iter().any(|(t, _)| f(*t));
    if has(&|t| t == Term::InstrumentScale)
        && v.len() > 1
        && !has(&|t| matches!(t, Term::SetupOffset(_) | Term::Squareness(_)))
    {
        "the instrument's calibration (L1 + L2) as the length reference"
    } else if has(&|t| matches!(t, Term::Squareness(Pair::Yz) | Term::Squareness(Pair::Zx)))
        || has(&|t| matches!(t, Term::SetupOffset(Axis::Z) | Term::Scale(Axis::Z)))
    {
        "circles at more heights (cones about the ball), or zx and yz arcs"
    } else {
        "more elements about the ball (other heights, radii or planes)"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points of an xy circle of ball distance `d` at height `h`, one per degree.
    fn cone(d: f64, h: f64) -> Vec<[f64; 3]> {
        let r = (d * d - h * h).sqrt();
        (0..360)
            .map(|k| {
                let a = (k as f64).to_radians();
                [r * a.cos(), r * a.sin(), h]
            })
            .collect()
    }

    #[test]
    fn the_partials_are_those_of_the_exact_distance() {
        // Each column against a finite difference of |p + E·p − c|·(1 + k).
        let p: [f64; 3] = [40.0, -55.0, 30.0];
        let d0 = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        for t in Term::ALL {
            let eps = 1e-3; // of the term's unit
            let mut q = p;
            let mut scale = 1.0;
            match t {
                Term::Scale(a) => q[a.index()] += eps * 1e-6 * p[a.index()],
                Term::Squareness(pair) => {
                    let (a, b) = pair.axes();
                    q[a.index()] += eps * 1e-6 * p[b.index()];
                }
                Term::SetupOffset(a) => q[a.index()] -= eps * 1e-3,
                Term::InstrumentScale => scale += eps * 1e-6,
            }
            let d = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() * scale;
            let fd_um = (d - d0) * 1e3 / eps;
            let an = t.partial_um(p);
            assert!(
                (fd_um - an).abs() < 1e-6 * an.abs().max(1e-3),
                "{t:?}: {fd_um} vs {an}"
            );
        }
    }

    #[test]
    fn one_height_sees_five_terms_and_the_mean_scale_never_separates() {
        let id = identifiability(&cone(90.0, 0.0));
        assert_eq!(id.rank, 5);
        assert_eq!(id.confounded.len(), 5);
        // scale_x + scale_y against the instrument's scale is one of the unseen combinations.
        let mean = id
            .confounded
            .iter()
            .find(|v| v.iter().any(|(t, _)| *t == Term::InstrumentScale))
            .expect("the instrument's scale is confounded");
        let coef = |t: Term| mean.iter().find(|(u, _)| *u == t).map_or(0.0, |(_, x)| *x);
        assert!((coef(Term::Scale(Axis::X)) - coef(Term::Scale(Axis::Y))).abs() < 1e-9);
        assert!((coef(Term::Scale(Axis::X)) + coef(Term::InstrumentScale)).abs() < 1e-9);
    }
}
