//! Issue 9 §3, without a calibrator: `jdbb plan --calibration-test` (spheres at several
//! distances) run by the independent G-code machine simulator (`jdbb_tests::gmachine`: a perfect
//! machine, a set-up offset, noise, the lean of the bars wandering) with a J-DBB whose counts
//! come from an instrument with hidden errors while the device computes D with the nominal
//! calibration (`InstrumentConfig::true_calibration`); `jdbb calibrate --record --plan`'s library
//! path (`instrument::run::run_samples`, then `instrument::fit::calibrate`) must name exactly the
//! hidden effects, each and the set-up offset by the one tolerance rule (`jdbb_tests::tolerance`:
//! within 5 % and within 1 % + 3σ, σ under 10 %), and name nothing for a perfect instrument. It also records which instrument terms the rank test finds confounded with the
//! machine's linear errors on these spheres.
use std::path::Path;

use jdbb::instrument::fit::{Calibrated, Options};
use jdbb::instrument::run::calibrate_run;
use jdbb::plan::{
    calibration_circles, default_calibration_distances, instrument, plan, write_program,
    Dialect as PlanDialect, Plan, PlanSpec, Plane, Purpose,
};
use jdbb_core::geometry::Model;
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{Dialect, MachineErrors, Recording, SimConfig, Simulation};
use jdbb_tests::mechanism::ARCSEC;
use jdbb_tests::tolerance::assert_unbiased;

const CENTRE: [f64; 3] = [120.0, 40.0, -30.0];
const SETUP_UM: [f64; 3] = [12.0, -8.0, 5.0];

fn calibration_plan() -> Plan {
    let cal = Calibration::DEFAULT;
    let mut spec = PlanSpec::machine_test(
        &[50.0],
        &[0.0],
        Plane::Xy,
        1000.0,
        CENTRE,
        PlanDialect::Linuxcnc,
    );
    let d = default_calibration_distances(&instrument(&cal).unwrap(), spec.feed_in_mm);
    spec.purpose = Purpose::CalibrationTest;
    spec.circles = calibration_circles(&d);
    plan(&spec, &cal).unwrap()
}

/// Run the plan on a perfect machine with a set-up offset; counts from `truth`, D from the
/// nominal calibration; then calibrate from the record file as the CLI does.
fn run_and_calibrate(plan: &Plan, truth: Option<Calibration>, seed: u64) -> Calibrated {
    run_and_calibrate_with(plan, truth, seed, SETUP_UM, None)
}

/// [`run_and_calibrate`] with the table ball `setup_um` off, and the machine's axes accelerating
/// at `accel_mm_s2` (default: the simulator's).
fn run_and_calibrate_with(
    plan: &Plan,
    truth: Option<Calibration>,
    seed: u64,
    setup_um: [f64; 3],
    accel_mm_s2: Option<[f64; 3]>,
) -> Calibrated {
    let rec = record(plan, truth, seed, setup_um, accel_mm_s2, 0.1);
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("rec.csv");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&file).unwrap());
    rec.write_csv(&mut f).unwrap();
    drop(f);
    calibrate_run(
        plan,
        Path::new(&file),
        &Calibration::DEFAULT,
        &Options::default(),
    )
    .unwrap()
}

/// The plan run on a perfect machine with the table ball `setup_um` off, its axes accelerating
/// at `accel_mm_s2` (default: the simulator's), the counts from `truth` with `noise_um` on D.
fn record(
    plan: &Plan,
    truth: Option<Calibration>,
    seed: u64,
    setup_um: [f64; 3],
    accel_mm_s2: Option<[f64; 3]>,
    noise_um: f64,
) -> Recording {
    let text = write_program(plan, PlanDialect::Linuxcnc);
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, CENTRE);
    cfg.errors = MachineErrors {
        setup_offset_um: setup_um,
        ..MachineErrors::default()
    };
    cfg.instrument.true_calibration = truth;
    if let Some(a) = accel_mm_s2 {
        cfg.machine.accel_mm_s2 = a;
    }
    cfg.instrument.noise_um = noise_um;
    cfg.instrument.seed = seed;
    cfg.instrument.sample_rate_hz = 1000.0;
    cfg.instrument.clock_ppm = 37.0;
    Simulation::new(&text, cfg).unwrap().run().unwrap()
}

/// RMS (µm) of D recomputed from `rec`'s counts with `cal` (the core's f64 model, as `jdbb
/// recompute` does) against the true D the instrument was set to.
fn recomputed_rms_um(rec: &Recording, cal: &Calibration) -> f64 {
    let m = Model::new(cal);
    let s = &rec.truth.samples;
    let ss: f64 = s
        .iter()
        .map(|t| (m.distance_mm(t.enc1, t.enc2) - t.d_mm_true).powi(2))
        .sum();
    1e3 * (ss / s.len() as f64).sqrt()
}

/// The instrument the tests hide: zero_2 60″, axes skew 90″, eccentricity_1 40″.
fn hidden_instrument() -> Calibration {
    let mut truth = Calibration::DEFAULT;
    truth.enc2.zero_offset_rad = 60.0 * ARCSEC;
    truth.axes_skew_rad = 90.0 * ARCSEC;
    truth.enc1.set_eccentricity_components(40.0 * ARCSEC, 0.0);
    truth
}

fn names(c: &Calibrated) -> Vec<&'static str> {
    let mut n: Vec<_> = c.effects.iter().map(|f| f.effect.name()).collect();
    n.sort_unstable();
    n
}

/// `value ± σ` is `truth` by the one rule (`jdbb_tests::tolerance`: within 5 % and within
/// 1 % + 3σ, σ under 10 %); a value without a σ is held to 1 %.
fn assert_within(what: &str, value: f64, sigma: Option<f64>, truth: f64) {
    assert_unbiased(what, value, sigma.unwrap_or(0.0), truth, 0.0, "");
}

fn check_setup(c: &Calibrated) {
    check_setup_is(c, SETUP_UM);
}

fn check_setup_is(c: &Calibrated, truth: [f64; 3]) {
    let su = c.setup_um.expect("set-up offset fitted");
    for k in 0..3 {
        assert_within(&format!("setup {k}"), su[k].0, su[k].1, truth[k]);
    }
}

#[test]
fn a_calibration_test_run_finds_hidden_instrument_errors_and_the_set_up() {
    let plan = calibration_plan();
    let truth = hidden_instrument();
    let c = run_and_calibrate(&plan, Some(truth), 3);
    println!("{}", jdbb::instrument::report::summary(&c));
    assert_held_out(&c, SETUP_UM);
    assert_eq!(
        names(&c),
        ["axes_skew", "eccentricity_1", "zero_2"],
        "{}",
        jdbb::instrument::report::summary(&c)
    );
    let f = |n: &str| c.effects.iter().find(|f| f.effect.name() == n).unwrap();
    for (n, v) in [
        ("zero_2", 60.0),
        ("axes_skew", 90.0),
        ("eccentricity_1", 40.0),
    ] {
        let e = f(n);
        assert_within(n, e.value, e.sigma, v);
    }
    check_setup(&c);
    // The rank test against the machine's linear errors: the bars' length is an isotropic scale.
    let m = |n: &str| c.machine.iter().find(|s| s.effect == n).unwrap();
    assert!(m("length_sum").separable < 1e-4, "{:?}", c.machine);
    assert!(m("length_sum")
        .confounded_with
        .contains(&"scale_x".to_string()));
}

#[test]
fn a_perfect_instrument_names_nothing_on_a_calibration_test_run() {
    let plan = calibration_plan();
    for seed in [1, 2] {
        let c = run_and_calibrate(&plan, None, seed);
        println!("{}", jdbb::instrument::report::summary(&c));
        assert!(
            c.effects.is_empty(),
            "seed {seed}: {}",
            jdbb::instrument::report::summary(&c)
        );
        check_setup(&c);
    }
}

#[test]
fn a_larger_set_up_offset_and_a_fast_machine_still_synchronise_and_the_set_up_is_found() {
    // (35, −20, 5) µm moved the ramps' end levels by up to 2 % of the 2 mm feed-out on the
    // smallest sphere, and the synchronisation used the plan's levels to find the ramp's ends:
    // "does not come back to the feed-in start". It now measures the levels. At 5000 mm/s² the
    // ramp fit started from an acceleration 20 times too small and stopped at a 2.5 mm ramp for a
    // 2 mm line: "no feed-in" on the third sphere; it now also starts from the feed. The
    // instrument's terms with this offset were once biased by 2–7 % with two small terms added;
    // they are now unbiased, and the calibration gives the true D on a held-out record.
    let plan = calibration_plan();
    let truth = hidden_instrument();
    for (setup, accel) in [
        ([35.0, -20.0, 5.0], None),
        (SETUP_UM, Some([5000.0, 5000.0, 3000.0])),
    ] {
        let c = run_and_calibrate_with(&plan, Some(truth), 3, setup, accel);
        println!("{}", jdbb::instrument::report::summary(&c));
        check_setup_is(&c, setup);
        if accel.is_none() {
            // The realistic set-up: the instrument's terms unbiased and nothing else named, and
            // the calibration gives the true D on another record.
            assert_held_out(&c, setup);
            let report = jdbb::instrument::report::summary(&c);
            assert_eq!(
                names(&c),
                ["axes_skew", "eccentricity_1", "zero_2"],
                "{report}"
            );
            for (n, v) in [
                ("zero_2", 60.0),
                ("axes_skew", 90.0),
                ("eccentricity_1", 40.0),
            ] {
                let e = c.effects.iter().find(|f| f.effect.name() == n).unwrap();
                assert_within(n, e.value, e.sigma, v);
            }
        }
        // The noise is 0.1 µm.
        assert!(c.final_rms_um < 0.105, "final RMS {} µm", c.final_rms_um);
    }
}

/// The record the held-out check recomputes: the same hidden instrument on a new lean path and
/// a new set-up, no noise on D, so what is left is the calibration's error and the counts'
/// quantisation. Made once for the whole binary.
fn held_out() -> &'static Recording {
    static HELD_OUT: std::sync::OnceLock<Recording> = std::sync::OnceLock::new();
    HELD_OUT.get_or_init(|| {
        record(
            &calibration_plan(),
            Some(hidden_instrument()),
            11,
            [-18.0, 27.0, -4.0],
            None,
            0.0,
        )
    })
}

/// Held out (issue 27 §6): the calibration `calibrate --record` found from one record must give
/// the true D on another record of the same hidden instrument: RMS(D − D_true) < 0.05 µm. Run
/// on the calibrations of the (12, −8, 5) µm set-up (the first test) and of the realistic
/// (35, −20, 5) µm one (the larger set-up test); measured 0.0037 µm for both, the quantisation's
/// own. [`the_held_out_check_has_power`] shows that the check can fail.
fn assert_held_out(c: &Calibrated, setup: [f64; 3]) {
    let rms = recomputed_rms_um(held_out(), &c.calibration);
    println!("set-up {setup:?}: held-out RMS {rms:.4} µm");
    assert!(
        rms < 0.05,
        "set-up {setup:?}: held-out RMS(D − D_true) {rms:.4} µm\n{}",
        jdbb::instrument::report::summary(c)
    );
}

/// The held-out record recomputed with the true instrument leaves only the quantisation; the
/// nominal instrument leaves 5.7 µm, and the true one with zero_2 5 % off more than 0.05 µm: the
/// held-out check of the calibration tests has power.
#[test]
fn the_held_out_check_has_power() {
    let truth = hidden_instrument();
    let floor = recomputed_rms_um(held_out(), &truth);
    let nominal = recomputed_rms_um(held_out(), &Calibration::DEFAULT);
    assert!(floor < 0.01, "quantisation alone leaves {floor} µm");
    assert!(
        nominal > 0.5,
        "the nominal instrument leaves only {nominal} µm"
    );
    let mut off = truth;
    off.enc2.zero_offset_rad *= 1.05;
    let off_rms = recomputed_rms_um(held_out(), &off);
    println!("zero_2 5 % off: held-out RMS {off_rms:.4} µm");
    assert!(off_rms > 0.05, "zero_2 5 % off leaves only {off_rms} µm");
}
