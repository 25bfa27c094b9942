//! What the tests of planned runs on the G-code machine share (`sync_hidden`, `arc_hidden`,
//! `mechanisms`): the recording read back as `jdbb diagnose --record` reads it, and the names a
//! diagnosis gives. They use the host's reader, which the library of this crate must not: its
//! simulators are written apart from the host.
use jdbb::circular::diagnose::Diagnosis;
use jdbb::circular::sync::Record;
use jdbb_tests::gmachine::Recording;

/// The recording as `jdbb record` writes it (CSV in a temporary file) and `diagnose --record`
/// reads it back.
pub fn read_back(rec: &Recording) -> Record {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("rec.csv");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&file).unwrap());
    rec.write_csv(&mut f).unwrap();
    drop(f);
    Record::read(&file).unwrap()
}

/// The machine effects a diagnosis names (not the set-up), in the order selected.
pub fn machine_names(d: &Diagnosis) -> Vec<String> {
    d.effects
        .iter()
        .filter(|f| !f.effect.is_setup())
        .map(|f| f.effect.name())
        .collect()
}

/// `got ± sigma` is `truth`, without a bias a small σ would hide: the error is within the bias
/// bound (1 % of |truth|, or `abs` where that is larger: the quantisation, the synchronisation's
/// timing) plus 3σ, *and* σ itself is under 10 % of |truth| (or `abs`), so neither a biased
/// estimate with a tiny σ nor a vague one with a large σ passes. `context` is printed on failure
/// (e.g. the diagnosis summary).
// Not every test file that shares this module checks a value.
#[allow(dead_code)]
pub fn assert_unbiased(what: &str, got: f64, sigma: f64, truth: f64, abs: f64, context: &str) {
    assert_unbiased_sigma(what, got, sigma, truth, abs, 0.1, context);
}

/// [`assert_unbiased`] with σ allowed up to `sigma_fraction` of |truth|: for a value whose σ
/// carries the synchronisation's timing (a reversal spike lives in the milliseconds after a
/// reversal, and one circle times its feed to about 2·10⁻⁴: docs/synchronisation.md).
#[allow(dead_code)]
pub fn assert_unbiased_sigma(
    what: &str,
    got: f64,
    sigma: f64,
    truth: f64,
    abs: f64,
    sigma_fraction: f64,
    context: &str,
) {
    let bias = (0.01 * truth.abs()).max(abs);
    let err = (got - truth).abs();
    assert!(
        err <= bias + 3.0 * sigma,
        "{what}: {got} ± {sigma} vs truth {truth}: off by {err}, more than {bias} + 3σ\n{context}"
    );
    assert!(
        sigma <= (sigma_fraction * truth.abs()).max(abs),
        "{what}: σ {sigma} of truth {truth} is too large to check the value\n{context}"
    );
}
