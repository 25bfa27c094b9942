//! The one tolerance rule for a value recovered from data against the truth that was hidden in
//! them (issue 27), shared by every test that checks one: `jdbb_tests::tolerance` here, and the
//! host's tests include this very file (`host/tests/common/mod.rs`), which cannot depend on this
//! crate's simulators. It takes nothing from the project.
//!
//! `got ± σ` is `truth` when, with t = |truth| and `abs` a small absolute floor (quantisation, the
//! synchronisation's timing, a value near zero; stated by the caller):
//! - the error is within 5 % of t (or `abs`, where larger): no bias of more than 5 % passes,
//!   whatever σ is;
//! - the error is within 1 % of t (or `abs`) **plus** 3σ: a bias of a few per cent fails when σ
//!   says the value is known better than that;
//! - σ itself is under `sigma_fraction` of t (or `abs`): a vague value does not pass on a large
//!   σ. [`SIGMA_FRACTION`] (10 %) unless the caller states why its σ is larger (e.g. a spike's σ
//!   carries the synchronisation's timing).
//!
//! "Within 5 % or 3σ" passed a 4 µm spike reported as 9.9 ± 1.99 µm; "1 % + 3σ" alone passed
//! about 31 % with σ at 10 %.

/// The σ bound unless a test states a larger one, as a fraction of |truth|.
pub const SIGMA_FRACTION: f64 = 0.1;

/// `Ok` when `got ± sigma` is `truth` by the rule above, else why not (with `what`).
pub fn check_unbiased(
    what: &str,
    got: f64,
    sigma: f64,
    truth: f64,
    abs: f64,
    sigma_fraction: f64,
) -> Result<(), String> {
    let t = truth.abs();
    let err = (got - truth).abs();
    let most = (0.05 * t).max(abs);
    let bias = (0.01 * t).max(abs);
    let sigma_most = (sigma_fraction * t).max(abs);
    if !(err.is_finite() && sigma.is_finite()) {
        Err(format!(
            "{what}: {got} ± {sigma} vs truth {truth}: not finite"
        ))
    } else if err > most {
        Err(format!(
            "{what}: {got} ± {sigma} vs truth {truth}: off by {err}, more than 5 % ({most})"
        ))
    } else if err > bias + 3.0 * sigma {
        Err(format!(
            "{what}: {got} ± {sigma} vs truth {truth}: off by {err}, more than {bias} + 3σ"
        ))
    } else if sigma > sigma_most {
        Err(format!(
            "{what}: σ {sigma} of truth {truth} is over {sigma_most} ({} %): too large to check \
             the value",
            100.0 * sigma_fraction
        ))
    } else {
        Ok(())
    }
}

/// Panics (printing `context`, e.g. the diagnosis summary) unless `got ± sigma` is `truth` by
/// the rule, σ under [`SIGMA_FRACTION`] of |truth| (or `abs`).
pub fn assert_unbiased(what: &str, got: f64, sigma: f64, truth: f64, abs: f64, context: &str) {
    assert_unbiased_sigma(what, got, sigma, truth, abs, SIGMA_FRACTION, context);
}

/// [`assert_unbiased`] with σ allowed up to `sigma_fraction` of |truth|, for a value whose σ is
/// larger for a stated physical reason.
pub fn assert_unbiased_sigma(
    what: &str,
    got: f64,
    sigma: f64,
    truth: f64,
    abs: f64,
    sigma_fraction: f64,
    context: &str,
) {
    if let Err(e) = check_unbiased(what, got, sigma, truth, abs, sigma_fraction) {
        panic!("{e}\n{context}");
    }
}
