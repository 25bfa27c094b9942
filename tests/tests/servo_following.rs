//! The position loops' following error on the independent G-code machine (issue 26): a loop of
//! gain Kv draws a circle of radius R at speed v smaller by about (1 − k_v²)·v²/(2R·Kv²) (k_v the
//! velocity feed-forward), which the diagnosis names as `following_error` (q = radius loss ·
//! R/v², in ms²), never as a scale. On circles of two radii at one feed the isotropic scale
//! cannot be told from it (both, and the length offset, are constants per circle): the following
//! error is named and the scale listed as confounded with it. A feed sweep (`jdbb plan --feed F1
//! --feed F2`) tells them apart: a hidden scale is named beside the loop's following error.
//!
//! The truth is the machine's own loop, not the fit's model: q = (1 − |H(jω)|)/ω² with H the
//! closed loop of `gmachine::dynamics` (velocity loop, feed-forward) at each circle's ω = v/R.
mod planned;

use planned::{machine_names, read_back};

use jdbb::diagnose::{diagnose, Diagnosis, Found, Options};
use jdbb::plan::{plan, write_program, Dialect as PlanDialect, Plan, PlanSpec, Plane};
use jdbb::report::summary;
use jdbb::sync::{data_path, synchronise};
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{Dialect, MachineErrors, ServoLoop, SimConfig, Simulation};

const CENTRE: [f64; 3] = [100.0, 50.0, -20.0];

/// XY circles of `radii` at each of `feeds` (a feed sweep if more than one).
fn make_plan(radii: &[f64], feeds_mm_min: &[f64]) -> Plan {
    let spec = PlanSpec::machine_test(
        radii,
        &[0.0],
        Plane::Xy,
        feeds_mm_min[0],
        CENTRE,
        PlanDialect::Linuxcnc,
    )
    .feed_sweep(feeds_mm_min);
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

/// Identical loops `l` on every axis, with `errors`, at 1 kHz with 0.2 µm of white noise;
/// synchronised from D and diagnosed as `jdbb diagnose --record --plan` does.
fn run(p: &Plan, l: ServoLoop, mut errors: MachineErrors, seed: u64) -> Diagnosis {
    errors.dynamics.servo = [Some(l); 3];
    errors.setup_offset_um = [12.0, -8.0, 5.0];
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, CENTRE);
    cfg.errors = errors;
    cfg.machine.feed_override_pct = 100.0;
    cfg.instrument.clock_ppm = 23.0;
    cfg.instrument.start_delay_s = 2.0;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.seed = seed;
    cfg.instrument.sample_rate_hz = 1000.0;
    let rec = Simulation::new(&write_program(p, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    let sync = synchronise(p, &r).unwrap();
    let (path, d) = data_path(p, &r, &sync, [None; 3]).unwrap();
    diagnose(&path, &d, &Options::default()).unwrap()
}

/// The machine's q (ms²): (1 − |H(jω)|)/ω² of loop `l`, averaged over the plan's circles (it
/// barely depends on ω: the next term is of order (ω/Kv)² smaller).
fn true_q_ms2(l: &ServoLoop, p: &Plan) -> f64 {
    let qs: Vec<f64> = p
        .circles
        .iter()
        .map(|c| {
            let omega = c.feed_mm_min / 60.0 / c.radius_mm;
            let (re, im) = l.response(omega);
            1e6 * (1.0 - re.hypot(im)) / (omega * omega)
        })
        .collect();
    qs.iter().sum::<f64>() / qs.len() as f64
}

fn found<'a>(d: &'a Diagnosis, name: &str) -> &'a Found {
    d.effects
        .iter()
        .find(|f| f.effect.name() == name)
        .unwrap_or_else(|| panic!("{name} not named\n{}", summary(d)))
}

fn assert_following_error(d: &Diagnosis, truth_ms2: f64, what: &str) {
    let f = found(d, "following_error");
    println!(
        "{what}: following_error {} ± {} ms² for {truth_ms2} (confounded {:?})",
        f.value,
        f.sigma.unwrap_or(f64::NAN),
        d.confounded
    );
    planned::assert_unbiased(
        &format!("following_error q_ms2 ({what})"),
        f.value,
        f.sigma.unwrap(),
        truth_ms2,
        0.0,
        &summary(d),
    );
}

/// Whether `d` lists a confounded group holding both the following error and a scale.
fn scale_confounded_with_following_error(d: &Diagnosis) -> bool {
    d.confounded.iter().any(|g| {
        g.iter().any(|n| n == "following_error") && g.iter().any(|n| n.starts_with("scale_"))
    })
}

#[test]
fn identical_loops_on_two_radii_are_a_following_error_not_a_scale() {
    // The null failure: Kv 30 s⁻¹ without feed-forward read as isotropic scale
    // +14.9 µm/m on R 95 and 85 mm. Without feed-forward at 2000 and 3000 mm/min the loop's lag
    // bends the start of the arcs by 0.11 mm and the record is not synchronised (a timeline from
    // the arcs' own timing is not built yet), so the loops run at 1000 mm/min.
    for (seed, kv, ff, feed) in [(1, 30.0, 0.0, 1000.0), (3, 40.0, 0.0, 1000.0)] {
        let p = make_plan(&[95.0, 85.0], &[feed]);
        let l = ServoLoop {
            ff_velocity: ff,
            ..ServoLoop::new(kv)
        };
        let d = run(&p, l, MachineErrors::default(), seed);
        let names = machine_names(&d);
        assert!(
            names.iter().all(|n| !n.starts_with("scale")),
            "Kv {kv} ff {ff}: a scale named\n{}",
            summary(&d)
        );
        assert_eq!(names, vec!["following_error"], "{}", summary(&d));
        assert_following_error(&d, true_q_ms2(&l, &p), &format!("Kv {kv} ff {ff}"));
        assert!(
            scale_confounded_with_following_error(&d),
            "Kv {kv} ff {ff}: confounded {:?}",
            d.confounded
        );
    }
}

#[test]
fn a_feed_sweep_names_a_hidden_scale_beside_the_loops_following_error() {
    // The same two radii at 1000 and 3000 mm/min: the scale (a·R, the same at both feeds) and
    // the following error (q·v²/R, nine times larger at the higher feed) are no longer collinear.
    let p = make_plan(&[95.0, 85.0], &[1000.0, 3000.0]);
    assert_eq!(p.circles.len(), 4);
    assert_eq!(p.feeds_mm_min(), vec![1000.0, 3000.0]);
    let l = ServoLoop::new(40.0);
    let errors = MachineErrors {
        scale_um_per_m: [20.0, 20.0, 0.0],
        ..MachineErrors::default()
    };
    let d = run(&p, l, errors, 11);
    let mut names = machine_names(&d);
    names.sort();
    assert_eq!(
        names,
        vec!["following_error", "scale_x", "scale_y"],
        "{}",
        summary(&d)
    );
    assert!(
        !scale_confounded_with_following_error(&d),
        "{:?}",
        d.confounded
    );
    assert_following_error(&d, true_q_ms2(&l, &p), "feed sweep");
    for name in ["scale_x", "scale_y"] {
        let f = found(&d, name);
        planned::assert_unbiased(name, f.value, f.sigma.unwrap(), 20.0, 0.0, &summary(&d));
    }
}

#[test]
#[ignore = "issue 26: written with the lagged-ramp timeline but not yet run (the shared build did not finish before the deadline); run by hand and un-ignore when it passes"]
fn ninety_percent_feed_forward_at_3000_mm_min_is_a_following_error() {
    // The issue: Kv 30 s⁻¹ with 90 % velocity feed-forward at 3000 mm/min on R 95 and 85 mm read
    // as isotropic scale 16.5 µm/m, later as a drift and lateral plays of ±0.12 µm. The loop
    // delays the feed-in by τ = 3.3 ms and rounds it; read as the command through the loop
    // (docs/synchronisation.md) the timeline holds, and the loop is its following error alone.
    let p = make_plan(&[95.0, 85.0], &[3000.0]);
    let l = ServoLoop {
        ff_velocity: 0.9,
        ..ServoLoop::new(30.0)
    };
    let d = run(&p, l, MachineErrors::default(), 5);
    assert_eq!(
        machine_names(&d),
        vec!["following_error"],
        "{}",
        summary(&d)
    );
    assert_following_error(&d, true_q_ms2(&l, &p), "Kv 30 ff 0.9 F3000");
}
