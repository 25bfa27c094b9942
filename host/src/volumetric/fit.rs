//! The linear volumetric model fitted to changes of D at known positions about the table ball:
//! the nine terms of [`super::ident`] with the instrument's calibration as the length reference
//! (the instrument's scale fixed at 0), through the crate's least-squares engine
//! ([`crate::numerics::lsq`]), with σ and the groups the data leave undetermined.
//!
//! This is the core of the joint diagnosis, not the whole of it: the positions come from the
//! plan, not yet from a synchronised record, and backlash, servo and cyclic terms are not in
//! the model yet.
use super::ident::Term;
use crate::numerics::lsq::{least_squares, LsqOptions, Problem};
use crate::{Error, Result};

/// The terms the fit estimates: [`Term::ALL`] without the instrument's scale.
pub fn fitted_terms() -> &'static [Term] {
    &Term::ALL[..Term::ALL.len() - 1]
}

/// ΔD = Σ term·∂D/∂term at each point, against the measured ΔD.
struct Linear<'a> {
    points_mm: &'a [[f64; 3]],
    dd_um: &'a [f64],
}

impl Problem for Linear<'_> {
    fn n_params(&self) -> usize {
        fitted_terms().len()
    }

    fn n_residuals(&self) -> usize {
        self.points_mm.len()
    }

    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let mut grad = vec![0.0; p.len()];
        for (i, (q, dd)) in self.points_mm.iter().zip(self.dd_um).enumerate() {
            for (g, t) in grad.iter_mut().zip(fitted_terms()) {
                *g = t.partial_um(*q);
            }
            let model: f64 = grad.iter().zip(p).map(|(g, x)| g * x).sum();
            visit(i, model - dd, &grad);
        }
    }
}

/// One fitted term: its value and standard error in its unit ([`Term::unit`]); `sigma` is
/// `None` where the data do not determine it.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    pub term: Term,
    pub value: f64,
    pub sigma: Option<f64>,
}

/// The fit of the linear model.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearFit {
    pub estimates: Vec<Estimate>,
    /// Rank of the fit's own (column-scaled) design matrix.
    pub rank: usize,
    /// Groups of terms the data do not determine.
    pub undetermined: Vec<Vec<Term>>,
    /// Root mean square of the residual (µm).
    pub rms_um: f64,
}

/// Fit the nine terms to the changes of D `dd_um` (µm) measured at `points_mm` (mm, relative
/// to the table ball). Refused (bad input) when the two lengths differ or no point is given.
pub fn fit_linear(points_mm: &[[f64; 3]], dd_um: &[f64]) -> Result<LinearFit> {
    if points_mm.is_empty() || points_mm.len() != dd_um.len() {
        return Err(Error::Usage(format!(
            "a volumetric fit needs one change of D per point: {} points, {} values",
            points_mm.len(),
            dd_um.len()
        )));
    }
    let problem = Linear { points_mm, dd_um };
    let n = fitted_terms().len();
    let fit = least_squares(&problem, &vec![0.0; n], &LsqOptions::default())?;
    Ok(LinearFit {
        estimates: fitted_terms()
            .iter()
            .enumerate()
            .map(|(k, t)| Estimate {
                term: *t,
                value: fit.params[k],
                sigma: fit.sigma[k],
            })
            .collect(),
        rank: fit.rank,
        undetermined: fit
            .undetermined
            .iter()
            .map(|g| g.iter().map(|&k| fitted_terms()[k]).collect())
            .collect(),
        rms_um: fit.rms,
    })
}
