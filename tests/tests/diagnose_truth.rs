//! Signs and values of `jdbb diagnose` against an independent truth (issue 21): `jdbb plan`'s
//! program runs on the tests' G-code machine (`jdbb_tests::gmachine`: its own parser, planner,
//! machine errors written from the mechanisms, and the instrument from the independent
//! mechanism model), the record is synchronised from D alone and diagnosed as `jdbb diagnose
//! --record --plan` does. Nothing here shares a model with the fit, so a flipped sign or a phase
//! measured from the wrong origin in the fit fails here.
//!
//! The table ball sits at X 253.7, Y 61.3 — off a whole pitch of every pitch used (4, 5 mm) —
//! so a cyclic or interference phase taken from the program origin instead of the table ball (or
//! the other way round) shows. Every value is checked with [`planned::assert_unbiased`]: 1 % (or
//! a small absolute term) plus 3σ, and σ under 10 % of the value. Records are at 250 Hz to keep
//! CI short.
mod planned;

use planned::{assert_unbiased, machine_names, read_back};

use jdbb::circular::diagnose::{diagnose, Diagnosis, Found, Options};
use jdbb::circular::plan::{plan, write_program, Dialect as PlanDialect, Plan, PlanSpec, Plane};
use jdbb::circular::report::summary;
use jdbb::circular::sync::{data_path, synchronise};
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{
    Axis, Cyclic, Dialect, Interference, MachineErrors, ReversalSpike, Scale2, SimConfig,
    Simulation, Squareness,
};

/// The table ball (program = machine coordinates): off a whole pitch of 4 and 5 mm on X and Y.
const BALL: [f64; 3] = [253.7, 61.3, -20.0];

fn make_plan(radii: &[f64], heights: &[f64], plane: Plane) -> Plan {
    let spec = PlanSpec::machine_test(radii, heights, plane, 1000.0, BALL, PlanDialect::Linuxcnc);
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

/// Run `plan` on the G-code machine with `errors` (feed override, unknown start, clock off by
/// tens of ppm, 0.2 µm noise, 250 Hz), synchronise from D and diagnose with `pitch`.
fn run(plan: &Plan, errors: MachineErrors, seed: u64, pitch: [Option<f64>; 3]) -> Diagnosis {
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    cfg.errors = errors;
    cfg.machine.feed_override_pct = 97.0 + (seed % 5) as f64;
    cfg.instrument.clock_ppm = if seed.is_multiple_of(2) { 41.0 } else { -33.0 };
    cfg.instrument.start_delay_s = 2.0 + (seed % 3) as f64;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.seed = seed;
    cfg.instrument.sample_rate_hz = 250.0;
    let rec = Simulation::new(&write_program(plan, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    let sync = synchronise(plan, &r).unwrap();
    let (path, d) = data_path(plan, &r, &sync, pitch).unwrap();
    diagnose(&path, &d, &Options::default()).unwrap()
}

/// Exactly `name` was named (besides the set-up); returns it.
fn only<'a>(d: &'a Diagnosis, name: &str) -> &'a Found {
    assert_eq!(machine_names(d), vec![name.to_string()], "{}", summary(d));
    d.effects.iter().find(|f| f.effect.name() == name).unwrap()
}

/// Parameter `k` of `f` and its σ.
fn param(f: &Found, k: usize) -> (f64, f64) {
    (
        f.params[k],
        f.param_sigma[k].expect("a determined parameter"),
    )
}

/// The set-up offset is where the table ball really is relative to where the program assumed
/// it: the machine's `setup_offset_um` c puts the ball at nominal + c, and the diagnosis must
/// report +c (the same sign as `calibrate`'s table-ball offset). Flipping the sign in the fit
/// reports −c and fails by 2|c|. A perfect machine names nothing.
#[test]
fn the_setup_offset_is_where_the_table_ball_is() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let errors = MachineErrors {
        setup_offset_um: [35.0, -20.0, 0.0],
        length_offset_um: 4.0,
        ..MachineErrors::default()
    };
    let d = run(&p, errors, 21, [None; 3]);
    assert!(machine_names(&d).is_empty(), "{}", summary(&d));
    let c = &d.effects[0];
    assert_eq!(c.effect.name(), "setup_offset");
    let s = summary(&d);
    for (k, truth) in [(0, 35.0), (1, -20.0)] {
        let (v, sig) = param(c, k);
        assert_unbiased(&format!("setup_offset[{k}]"), v, sig, truth, 0.3, &s);
    }
    let e = &d.effects[1];
    assert_eq!(e.effect.name(), "length_offset");
    assert_unbiased("length_offset", e.value, e.sigma.unwrap(), 4.0, 0.3, &s);
}

/// Backlash: a nut clearance of 6 µm on Y (the carriage trails its motor by 3 µm in the
/// direction of motion) is **positive** `backlash_y`. A flipped sign (a step ahead of the motor
/// read as play) reports −6 and fails.
#[test]
fn play_is_positive_backlash() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let mut errors = MachineErrors::default();
    errors.backlash_um[1] = 6.0;
    let d = run(&p, errors, 22, [None; 3]);
    let f = only(&d, "backlash_y");
    assert_unbiased(
        "backlash_y",
        f.value,
        f.sigma.unwrap(),
        6.0,
        0.1,
        &summary(&d),
    );
}

/// Squareness, as a tilted slide: Y's guideway leans towards +X by 40 µm per m, so moving Y by
/// Δy moves the spindle 40 µm/m·Δy in +X, which the diagnosis names `squareness_xy` = +40 µm/m
/// (δ_x = s·y). On an XY circle displacing X by s·y or Y by s·x gives the same ΔD = s·x·y/R,
/// so this catches the sign, not which axis carries it; a flipped sign reports −40.
#[test]
fn a_slide_leaning_towards_plus_x_is_positive_squareness_xy() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let errors = MachineErrors {
        squareness: vec![Squareness {
            axis: Axis::X,
            by: Axis::Y,
            um_per_m: 40.0,
        }],
        ..MachineErrors::default()
    };
    let d = run(&p, errors, 23, [None; 3]);
    let f = only(&d, "squareness_xy");
    assert_unbiased(
        "squareness_xy",
        f.value,
        f.sigma.unwrap(),
        40.0,
        0.3,
        &summary(&d),
    );
}

/// A vertical plane (YZ, the 220° test from −20°): Y's position depends on Z's (the column
/// leans towards +Y: δ_y = s·(z − z_ball)), named `squareness_yz` = +s. Flipping the sign, or
/// the plane's axis order (G19's y, z), reports −s.
#[test]
fn squareness_in_a_vertical_plane_keeps_its_sign() {
    let spec = PlanSpec::machine_test(
        &[90.0],
        &[0.0],
        Plane::Yz,
        1000.0,
        BALL,
        PlanDialect::Linuxcnc,
    )
    .with_arc(220.0);
    let spec = PlanSpec {
        start_deg: -20.0,
        ..spec
    };
    let p = plan(&spec, &Calibration::DEFAULT).unwrap();
    let errors = MachineErrors {
        squareness: vec![Squareness {
            axis: Axis::Y,
            by: Axis::Z,
            um_per_m: -50.0,
        }],
        ..MachineErrors::default()
    };
    let d = run(&p, errors, 24, [None; 3]);
    let f = only(&d, "squareness_yz");
    assert_unbiased(
        "squareness_yz",
        f.value,
        f.sigma.unwrap(),
        -50.0,
        0.5,
        &summary(&d),
    );
}

/// A reversal spike: X sticks at each reversal and catches up (h = 4 µm behind the new
/// direction, τ = 25 ms) — positive `reversal_spike_x` h. A flipped sign (the axis jumping
/// ahead) reports −4.
#[test]
fn an_axis_that_sticks_at_reversal_is_a_positive_spike() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let mut errors = MachineErrors::default();
    errors.reversal_spike[0] = ReversalSpike {
        height_um: 4.0,
        tau_ms: 25.0,
    };
    let d = run(&p, errors, 25, [None; 3]);
    let f = only(&d, "reversal_spike_x");
    let s = summary(&d);
    let (h, sh) = param(f, 0);
    assert_unbiased("reversal_spike_x h", h, sh, 4.0, 0.1, &s);
    let (tau, st) = param(f, 1);
    // τ is measured through the sampling at 4 ms and the synchronisation's timing.
    assert!(
        tau > 0.0 && (tau - 25.0).abs() <= 0.1 * 25.0 + 3.0 * st,
        "τ {tau} ± {st}\n{s}"
    );
}

/// The cyclic phase's origin: Y's screw has a 2.5 µm error at its 5 mm pitch,
/// δ = A·sin(2π·y/P + φ) in machine coordinates. The diagnosis gives sin and cos components
/// against the position *relative to the table ball* k = y − 61.3, so its truth is
/// A·sin(2π·k/P + ψ) with ψ = φ + 2π·61.3/P: sin_um = A·cos ψ, cos_um = A·sin ψ. A phase taken
/// from the wrong origin turns (sin, cos) by 2π·0.26 (94°) and fails; so does a flipped sign.
/// (On Y: the plan's feed-ins run along X, see
/// [`a_cyclic_error_along_the_feed_in_biases_the_synchronised_feed`].)
#[test]
fn the_cyclic_phase_is_measured_from_the_table_ball() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let (a, pitch, phi) = (2.5, 5.0, 0.4);
    let mut errors = MachineErrors::default();
    errors.cyclic[1] = Cyclic {
        amplitude_um: a,
        pitch_mm: pitch,
        phase_rad: phi,
    };
    let d = run(&p, errors, 26, [None, Some(pitch), None]);
    let f = only(&d, "cyclic_y");
    let s = summary(&d);
    let psi = phi + std::f64::consts::TAU * BALL[1] / pitch;
    let (sn, ss) = param(f, 0);
    let (cs, sc) = param(f, 1);
    let tol = 0.01 * a + 0.02;
    assert_unbiased("cyclic_y sin_um", sn, ss, a * psi.cos(), tol, &s);
    assert_unbiased("cyclic_y cos_um", cs, sc, a * psi.sin(), tol, &s);
    assert_unbiased("cyclic_y amplitude", f.value, f.sigma.unwrap(), a, tol, &s);
}

/// Known failure (found by this file, reported to the lead): a cyclic error of the axis the
/// feed-ins run along (X) changes D's slope along the feed-in by 2π·A/P (0.3 % for 2.5 µm at
/// 5 mm), which the synchronisation reads as feed: 98.13 % for a true 98.00 % with the ball on a
/// whole pitch, and 113.5 % with the ball at X 253.7 (the fallback search then locks on the
/// wrong speed), after which the diagnosis finds 0.5 µm of a 2.5 µm error. This test states
/// the contract the synchronisation must meet.
#[test]
#[ignore = "the synchronisation's feed is biased by a cyclic error along the feed-in (issue 21 report)"]
fn a_cyclic_error_along_the_feed_in_biases_the_synchronised_feed() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let (a, pitch, phi) = (2.5, 5.0, 0.4);
    let mut errors = MachineErrors::default();
    errors.cyclic[0] = Cyclic {
        amplitude_um: a,
        pitch_mm: pitch,
        phase_rad: phi,
    };
    let d = run(&p, errors, 26, [Some(pitch), None, None]);
    let f = only(&d, "cyclic_x");
    let psi = phi + std::f64::consts::TAU * BALL[0] / pitch;
    let (s, tol) = (summary(&d), 0.01 * a + 0.02);
    let (sn, ss) = param(f, 0);
    let (cs, sc) = param(f, 1);
    assert_unbiased("cyclic_x sin_um", sn, ss, a * psi.cos(), tol, &s);
    assert_unbiased("cyclic_x cos_um", cs, sc, a * psi.sin(), tol, &s);
}

/// Interference: Y's read head reports late by τ(y) = 0.15 ms·sin(2π·y/4 mm + 1.0), so the
/// axis runs ahead by v·τ(y): `interference_y` of 0.15 µm per mm/s, its (sin, cos) components
/// against the position relative to the table ball turned by 2π·61.3/4 like the cyclic error's.
/// A sign flipped (a reading that leads) or a phase from the wrong origin fails.
#[test]
fn interference_is_named_with_its_phase_from_the_table_ball() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let (b, pitch, phi) = (0.15, 4.0, 1.0);
    let mut errors = MachineErrors::default();
    errors.interference[1] = Interference {
        latency_ms: b,
        pitch_mm: pitch,
        phase_rad: phi,
    };
    let d = run(&p, errors, 27, [None, Some(pitch), None]);
    let f = only(&d, "interference_y");
    let s = summary(&d);
    let psi = phi + std::f64::consts::TAU * BALL[1] / pitch;
    let tol = 0.01 * b + 0.002;
    let (sn, ss) = param(f, 0);
    let (cs, sc) = param(f, 1);
    assert_unbiased("interference_y sin", sn, ss, b * psi.cos(), tol, &s);
    assert_unbiased("interference_y cos", cs, sc, b * psi.sin(), tol, &s);
}

/// A second-order scale: X's lead grows along the screw, δ = b·(x − o)² with b = 1500 µm/m².
/// With the lead right at the table ball (o = 253.7) two radii about the ball name `scale2_x`
/// = b alone; with o 50 mm below the ball the same screw is also a first-order scale
/// 2·b·(ball − o) = +150 µm/m at the ball (the slope of the error there), which must be named
/// with it. A flipped sign of b, or of the slope's lever (ball − o), fails.
#[test]
fn a_lead_growing_along_the_screw_is_second_order_scale() {
    let p = make_plan(&[95.0, 85.0], &[0.0], Plane::Xy);
    let b = 1500.0;
    let with_origin = |origin_mm| {
        let mut e = MachineErrors::default();
        e.scale2[0] = Scale2 {
            um_per_m2: b,
            origin_mm,
        };
        e
    };
    let d = run(&p, with_origin(BALL[0]), 28, [None; 3]);
    let f = only(&d, "scale2_x");
    assert_unbiased("scale2_x", f.value, f.sigma.unwrap(), b, 5.0, &summary(&d));

    let d = run(&p, with_origin(BALL[0] - 50.0), 29, [None; 3]);
    let mut names = machine_names(&d);
    names.sort();
    assert_eq!(names, vec!["scale2_x", "scale_x"], "{}", summary(&d));
    let get = |n: &str| d.effects.iter().find(|f| f.effect.name() == n).unwrap();
    let s = summary(&d);
    let f = get("scale2_x");
    assert_unbiased(
        "scale2_x (o off the ball)",
        f.value,
        f.sigma.unwrap(),
        b,
        5.0,
        &s,
    );
    let f = get("scale_x");
    let slope = 2.0 * b * 0.05;
    assert_unbiased(
        "scale_x (o off the ball)",
        f.value,
        f.sigma.unwrap(),
        slope,
        0.5,
        &s,
    );
}

/// Z effects through several heights: XY circles of 84 and 92 mm at z = −30, 0, +30 mm about the
/// table ball (the J-DBB's free bar length), Z's scale +30 µm/m and a column leaning towards
/// +Z with X (δ_z = 40 µm/m·(x − x_ball)): `scale_z` = +30 and `squareness_zx` = +40, and the
/// set-up's c_z, now determined by the heights, is the ball's real height offset (+5 µm) plus
/// what Z's scale has moved the spindle at the ball's height.
#[test]
fn z_effects_over_several_heights() {
    let p = make_plan(&[84.0, 92.0], &[-30.0, 0.0, 30.0], Plane::Xy);
    let errors = MachineErrors {
        setup_offset_um: [10.0, -5.0, 5.0],
        scale_um_per_m: [0.0, 0.0, 30.0],
        squareness: vec![Squareness {
            axis: Axis::Z,
            by: Axis::X,
            um_per_m: 40.0,
        }],
        ..MachineErrors::default()
    };
    let d = run(&p, errors, 30, [None; 3]);
    let mut names = machine_names(&d);
    names.sort();
    assert_eq!(names, vec!["scale_z", "squareness_zx"], "{}", summary(&d));
    let s = summary(&d);
    let get = |n: &str| d.effects.iter().find(|f| f.effect.name() == n).unwrap();
    let f = get("scale_z");
    assert_unbiased("scale_z", f.value, f.sigma.unwrap(), 30.0, 0.5, &s);
    let f = get("squareness_zx");
    assert_unbiased("squareness_zx", f.value, f.sigma.unwrap(), 40.0, 0.5, &s);
    // Z's scale counts from the program origin: at the ball's height (z −20 mm) it has already
    // moved the spindle by 30 µm/m·(−20 mm) = −0.6 µm, which D cannot tell from the ball
    // standing 0.6 µm higher.
    let cz_truth = 5.0 - 30.0 * BALL[2] * 1e-3;
    let (cz, sz) = param(&d.effects[0], 2);
    assert_unbiased("setup_offset.z", cz, sz, cz_truth, 0.1, &s);
}
