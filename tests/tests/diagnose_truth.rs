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

use jdbb::diagnose::planned::diagnose_planned;
use jdbb::diagnose::{Diagnosis, Found, Options};
use jdbb::plan::{plan, write_program, Dialect as PlanDialect, Plan, PlanSpec, Plane};
use jdbb::report::summary;
use jdbb::sync::synchronise;
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{
    Axis, BacklashEnds, Cyclic, Dialect, Interference, MachineErrors, ReversalSpike, Scale2,
    SimConfig, Simulation, Squareness,
};
use rand::{Rng, SeedableRng};

/// The table ball (program = machine coordinates): off a whole pitch of 4 and 5 mm on X and Y.
const BALL: [f64; 3] = [253.7, 61.3, -20.0];

fn make_plan(radii: &[f64], heights: &[f64], plane: Plane) -> Plan {
    let spec = PlanSpec::machine_test(radii, heights, plane, 1000.0, BALL, PlanDialect::Linuxcnc);
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

/// Run `plan` on the G-code machine with `errors` (feed override, unknown start, clock off by
/// tens of ppm, 0.2 µm noise, 250 Hz), synchronise from D and diagnose with `pitch`.
fn run(plan: &Plan, errors: MachineErrors, seed: u64, pitch: [Option<f64>; 3]) -> Diagnosis {
    run_noise(plan, errors, seed, pitch, 0.2)
}

/// [`run`] with a noise of `noise_um` (σ on D).
fn run_noise(
    plan: &Plan,
    errors: MachineErrors,
    seed: u64,
    pitch: [Option<f64>; 3],
    noise_um: f64,
) -> Diagnosis {
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    cfg.errors = errors;
    cfg.machine.feed_override_pct = 97.0 + (seed % 5) as f64;
    cfg.instrument.clock_ppm = if seed.is_multiple_of(2) { 41.0 } else { -33.0 };
    cfg.instrument.start_delay_s = 2.0 + (seed % 3) as f64;
    cfg.instrument.noise_um = noise_um;
    cfg.instrument.seed = seed;
    cfg.instrument.sample_rate_hz = 250.0;
    let rec = Simulation::new(&write_program(plan, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    // As `jdbb diagnose --record --plan` does: the ramps read again through the errors found.
    let sync = synchronise(plan, &r).unwrap();
    diagnose_planned(plan, &r, sync, pitch, &Options::default())
        .unwrap()
        .diagnosis
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
    // The height's σ carries the synchronisation's timing σ: a quarter of the value allowed.
    planned::assert_unbiased_sigma("reversal_spike_x h", h, sh, 4.0, 0.1, 0.25, &s);
    let (tau, st) = param(f, 1);
    // τ is measured through the sampling at 4 ms and the synchronisation's timing: its σ, as
    // the height's, up to a quarter of the value.
    planned::assert_unbiased_sigma("reversal_spike_x tau_ms", tau, st, 25.0, 0.0, 0.25, &s);
}

/// The cyclic phase's origin: Y's screw has a 2.5 µm error at its 5 mm pitch,
/// δ = A·sin(2π·y/P + φ) in machine coordinates. The diagnosis gives sin and cos components
/// against the position *relative to the table ball* k = y − 61.3, so its truth is
/// A·sin(2π·k/P + ψ) with ψ = φ + 2π·61.3/P: sin_um = A·cos ψ, cos_um = A·sin ψ. A phase taken
/// from the wrong origin turns (sin, cos) by 2π·0.26 (94°) and fails; so does a flipped sign.
/// (On Y: the plan's feed-ins run along X, see
/// [`a_cyclic_error_along_the_feed_in_does_not_bias_the_synchronised_feed`].)
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

/// A cyclic error of the axis the feed-ins run along (X) changes D's slope along the feed-in by
/// 2π·A/P (0.3 % for 2.5 µm at 5 mm). Read as feed, it had given 98.13 % for a true 98.00 % with
/// the ball on a whole pitch and 113.5 % with the ball at X 253.7, after which the diagnosis
/// found 0.5 µm of a 2.5 µm error. The timeline now weighs every timing fact by what the
/// machine's errors can do to it and reads the ramps again through the errors found (issue 20,
/// `diagnose::planned`): the cyclic error is named alone, unbiased, with its phase.
#[test]
fn a_cyclic_error_along_the_feed_in_does_not_bias_the_synchronised_feed() {
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

/// The cyclic phase on Z in a vertical plane (YZ, the 220° test from −20°): Z's screw has a
/// 2 µm error at an 8 mm pitch, δ = A·sin(2π·z/P + φ) in machine coordinates, and the table ball
/// stands at Z −20 (2.5 pitches: half a pitch off), so the truth against the position relative to
/// the ball is turned by ψ = φ + 2π·(−20)/8. A phase from the program origin is off by π and
/// flips both components; so does a flipped sign.
#[test]
fn the_cyclic_phase_on_z_in_a_vertical_plane_is_measured_from_the_table_ball() {
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
    let (a, pitch, phi) = (2.0, 8.0, 1.1);
    let mut errors = MachineErrors::default();
    errors.cyclic[2] = Cyclic {
        amplitude_um: a,
        pitch_mm: pitch,
        phase_rad: phi,
    };
    let d = run(&p, errors, 31, [None, None, Some(pitch)]);
    let f = only(&d, "cyclic_z");
    let s = summary(&d);
    let psi = phi + std::f64::consts::TAU * BALL[2] / pitch;
    let tol = 0.01 * a + 0.02;
    let (sn, ss) = param(f, 0);
    let (cs, sc) = param(f, 1);
    assert_unbiased("cyclic_z sin_um", sn, ss, a * psi.cos(), tol, &s);
    assert_unbiased("cyclic_z cos_um", cs, sc, a * psi.sin(), tol, &s);
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
    // Two feeds: two radii at one feed do not tell the isotropic scale from the loops' following
    // error.
    let spec = PlanSpec::machine_test(
        &[95.0, 85.0],
        &[0.0],
        Plane::Xy,
        1000.0,
        BALL,
        PlanDialect::Linuxcnc,
    )
    .feed_sweep(&[1000.0, 2000.0]);
    let p = plan(&spec, &Calibration::DEFAULT).unwrap();
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

/// The vertical plane's 220° test (YZ, from −20°) of `radii` about the table ball.
fn yz_arc_plan(radii: &[f64]) -> Plan {
    let spec = PlanSpec::machine_test(
        radii,
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
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

/// Interference on Z in a vertical plane (YZ, the 220° test from −20°): Z's read head reports
/// late by τ(z) = 0.15 ms·sin(2π·z/6 mm + 0.7), so Z runs ahead of its command by v·τ(z) and
/// `interference_z` is 0.15 µm per mm/s. The table ball stands at Z −20, a third of a pitch off
/// (−20/6 = −3.33 pitches), so the truth against the position relative to the ball is turned by
/// ψ = φ + 2π·(−20)/6. A reading taken as leading (the sign flipped) turns both components by
/// π; a phase from the program origin instead of the ball turns them by 2π/3 (120°); either
/// fails by more than the amplitude.
#[test]
fn interference_on_z_in_a_vertical_plane_keeps_its_sign_and_phase() {
    let p = yz_arc_plan(&[90.0]);
    let (b, pitch, phi) = (0.15, 6.0, 0.7);
    let mut errors = MachineErrors::default();
    errors.interference[2] = Interference {
        latency_ms: b,
        pitch_mm: pitch,
        phase_rad: phi,
    };
    let d = run(&p, errors, 35, [None, None, Some(pitch)]);
    let f = only(&d, "interference_z");
    let s = summary(&d);
    let psi = phi + std::f64::consts::TAU * BALL[2] / pitch;
    let tol = 0.01 * b + 0.002;
    let (sn, ss) = param(f, 0);
    let (cs, sc) = param(f, 1);
    assert_unbiased("interference_z sin", sn, ss, b * psi.cos(), tol, &s);
    assert_unbiased("interference_z cos", cs, sc, b * psi.sin(), tol, &s);
}

/// A second-order scale on Z in a vertical plane (YZ, the 220° test from −20°, two radii about
/// the table ball): Z's lead grows along its screw, δ_z = b·(z − o)² with b = −2000 µm/m² and
/// the lead right at the ball's height (o = −20), so `scale2_z` = −2000 µm/m² is named alone.
/// A flipped sign of b reports +2000; a second-order scale taken about the program origin
/// instead of the ball would add a first-order scale of 2·b·20 mm = −80 µm/m, named with it.
#[test]
fn a_lead_growing_along_z_is_second_order_scale_in_a_vertical_plane() {
    let p = yz_arc_plan(&[95.0, 85.0]);
    let b = -2000.0;
    let mut errors = MachineErrors::default();
    errors.scale2[2] = Scale2 {
        um_per_m2: b,
        origin_mm: BALL[2],
    };
    let d = run(&p, errors, 36, [None; 3]);
    let f = only(&d, "scale2_z");
    assert_unbiased("scale2_z", f.value, f.sigma.unwrap(), b, 5.0, &summary(&d));
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

/// A random set-up: the table ball up to ±60 µm off in x and y, the bar up to ±20 µm long.
fn random_setup(rng: &mut impl Rng) -> MachineErrors {
    MachineErrors {
        setup_offset_um: [rng.gen_range(-60.0..60.0), rng.gen_range(-60.0..60.0), 0.0],
        length_offset_um: rng.gen_range(-20.0..20.0),
        ..MachineErrors::default()
    }
}

/// Hidden effects drawn at random (issue 3's test, its truth now the G-code machine's
/// mechanisms): a random set-up, one effect among scale, second-order scale, play, cyclic,
/// interference, squareness, servo delay and scale mismatch, a random radius and noise; the
/// diagnosis must name that effect alone, its value unbiased (1 % or a small absolute term
/// plus 3σ, σ under 10 %), and the set-up where the ball is. Cyclic and interference are drawn on
/// Y only (on X, where the feed-ins run, see
/// [`a_cyclic_error_along_the_feed_in_does_not_bias_the_synchronised_feed`]). Seeded: every run
/// draws the same cases.
#[test]
fn a_hidden_random_mechanism_is_named_alone_with_its_value() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(2026);
    let pitch_y = 8.0;
    for case in 0..16u64 {
        let axis = if rng.gen_bool(0.5) { 0 } else { 1 };
        let other = 1 - axis;
        let letter = ["x", "y"];
        let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        let phase: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
        let radius: f64 = rng.gen_range(84.0..96.0);
        let mut e = random_setup(&mut rng);
        let setup = e.setup_offset_um;
        // (reported name, its truth, absolute term of the bias bound)
        let (name, truth, abs) = match case % 8 {
            0 => {
                // One radius: only scale_x − scale_y shows.
                let a = sign * rng.gen_range(10.0..40.0);
                e.scale_um_per_m[axis] = a;
                let truth = if axis == 0 { a } else { -a };
                ("scale_mismatch_xy".to_string(), truth, 0.3)
            }
            1 => {
                // One radius: b·j² of axis j is the same data as a bow of the other axis towards
                // j; the bow is named, w = b·R².
                let b = sign * rng.gen_range(400.0..1500.0);
                e.scale2[axis] = Scale2 {
                    um_per_m2: b,
                    origin_mm: BALL[axis],
                };
                let name = format!("straightness_{}_{}", letter[other], letter[axis]);
                (name, b * (radius * 1e-3).powi(2), 0.05)
            }
            2 => {
                let b = rng.gen_range(2.0..10.0);
                e.backlash_um[axis] = b;
                (format!("backlash_{}", letter[axis]), b, 0.05)
            }
            3 => {
                let a = rng.gen_range(1.0..4.0);
                e.cyclic[1] = Cyclic {
                    amplitude_um: a,
                    pitch_mm: pitch_y,
                    phase_rad: phase,
                };
                ("cyclic_y".to_string(), a, 0.03)
            }
            4 => {
                let b = rng.gen_range(0.06..0.2);
                e.interference[1] = Interference {
                    latency_ms: b,
                    pitch_mm: pitch_y,
                    phase_rad: phase,
                };
                ("interference_y".to_string(), b, 0.003)
            }
            5 => {
                let s = sign * rng.gen_range(20.0..60.0);
                e.squareness = vec![Squareness {
                    axis: Axis::X,
                    by: Axis::Y,
                    um_per_m: s,
                }];
                ("squareness_xy".to_string(), s, 0.3)
            }
            6 => {
                // X later than Y by Δτ: servo_mismatch_xy = τ_x − τ_y.
                let t = rng.gen_range(0.1..0.6);
                e.servo_delay_ms[axis] = t;
                let truth = if axis == 0 { t } else { -t };
                ("servo_mismatch_xy".to_string(), truth, 0.01)
            }
            _ => {
                let a = sign * rng.gen_range(10.0..40.0);
                e.scale_um_per_m = [0.5 * a, -0.5 * a, 0.0];
                ("scale_mismatch_xy".to_string(), a, 0.3)
            }
        };
        let sigma = rng.gen_range(0.1..0.5);
        let seed = rng.gen();
        let p = make_plan(&[radius], &[0.0], Plane::Xy);
        let d = run_noise(&p, e.clone(), seed, [None, Some(pitch_y), None], sigma);
        let context = format!(
            "case {case}: hidden {name} (R {radius:.1} mm, σ {sigma:.2} µm)\n{}",
            summary(&d)
        );
        assert_eq!(machine_names(&d), vec![name.clone()], "{context}");
        let f = d.effects.iter().find(|f| f.effect.name() == name).unwrap();
        assert_unbiased(&name, f.value, f.sigma.unwrap(), truth, abs, &context);
        // The set-up is where the ball is (a scale counted from the program origin moves the
        // circle's centre by a·ball, which the set-up takes).
        let c_truth = setup[0] - e.scale_um_per_m[0] * BALL[0] * 1e-3;
        let (c, sc) = param(&d.effects[0], 0);
        assert_unbiased("setup_offset.x", c, sc, c_truth, 0.5, &context);
        assert!(
            d.final_rms_um < 1.3 * sigma.max(0.1),
            "rms {}\n{context}",
            d.final_rms_um
        );
    }
}

/// Two mechanisms at once, play on X and a slide leaning towards −X, are both named with their
/// values. Anything else named must be at the reporting floor (under 0.05 µm RMS on D): with
/// this seed a 0.06 ± 0.013 µm straightness of X is named besides (seeds 1–7 name nothing
/// else), a systematic of the G-code machine against the fit at that level, reported with
/// issue 21.
#[test]
fn two_mechanisms_at_once_are_both_named() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let mut e = random_setup(&mut rand::rngs::StdRng::seed_from_u64(5));
    e.backlash_um[0] = 6.0;
    e.squareness = vec![Squareness {
        axis: Axis::X,
        by: Axis::Y,
        um_per_m: -40.0,
    }];
    let d = run_noise(&p, e, 9, [None; 3], 0.3);
    let s = summary(&d);
    let get = |n: &str| {
        d.effects
            .iter()
            .find(|f| f.effect.name() == n)
            .unwrap_or_else(|| panic!("{n} not named\n{s}"))
    };
    let f = get("backlash_x");
    assert_unbiased("backlash_x", f.value, f.sigma.unwrap(), 6.0, 0.05, &s);
    let f = get("squareness_xy");
    assert_unbiased("squareness_xy", f.value, f.sigma.unwrap(), -40.0, 0.3, &s);
    for f in d.effects.iter().filter(|f| !f.effect.is_setup()) {
        let n = f.effect.name();
        assert!(
            n == "backlash_x" || n == "squareness_xy" || f.contribution_rms_um < 0.05,
            "{n} named besides, {} µm RMS on D\n{s}",
            f.contribution_rms_um
        );
    }
}

/// Near the noise floor: 0.2 µm of play on X under 0.5 µm of noise (its σ is about
/// σ_D/√(m/8) ≈ 0.01 µm with m ≈ 17 000 samples; 0.1 µm on D at most, twice the 0.05 µm
/// floor) is found with its value; 0.02 µm (about 2σ, under the floor) is not named.
#[test]
fn a_small_play_near_the_noise_floor() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let with = |b: f64| {
        let mut e = MachineErrors {
            setup_offset_um: [12.0, -7.0, 0.0],
            length_offset_um: 3.0,
            ..MachineErrors::default()
        };
        e.backlash_um[0] = b;
        e
    };
    let d = run_noise(&p, with(0.2), 11, [None; 3], 0.5);
    let f = only(&d, "backlash_x");
    let s = f.sigma.unwrap();
    assert!(s > 0.005 && s < 0.025, "σ {s}\n{}", summary(&d));
    assert_unbiased("backlash_x", f.value, s, 0.2, 0.01, &summary(&d));
    let d = run_noise(&p, with(0.02), 12, [None; 3], 0.5);
    assert!(machine_names(&d).is_empty(), "{}", summary(&d));
}

/// One radius: an isotropic scale (both axes +30 µm/m) looks exactly like a longer bar, so
/// nothing is named, the group is said, and e takes a·R (4 + 30·0.09 = 6.7 µm).
#[test]
fn one_radius_confounds_isotropic_scale_with_the_bar_length() {
    let e = MachineErrors {
        setup_offset_um: [20.0, 10.0, 0.0],
        length_offset_um: 4.0,
        scale_um_per_m: [30.0, 30.0, 0.0],
        ..MachineErrors::default()
    };
    let d = run(&make_plan(&[90.0], &[0.0], Plane::Xy), e, 3, [None; 3]);
    let s = summary(&d);
    assert!(machine_names(&d).is_empty(), "{s}");
    assert!(
        d.confounded
            .iter()
            .any(|g| g.contains(&"length_offset".to_string()) && g.contains(&"scale_x".to_string())),
        "{s}"
    );
    let f = &d.effects[1];
    assert_unbiased(
        "e (one radius)",
        f.value,
        f.sigma.unwrap(),
        4.0 + 30.0 * 0.09,
        0.05,
        &s,
    );
}

/// Two radii about the same ball separate the isotropic scale (`scale_x`, `scale_y` = +30 µm/m,
/// e = 4 µm) from the bar length, even within the default J-DBB's reach (D 79.8..99.5 mm): the
/// radii differ by 13.5 mm, the per-circle length change a·ΔR is 0.4 µm. Neither axis's scale
/// alone shows that (each adds a 2θ term the data do not hold), so the search offers the pair
/// as one group; one at a time it had named a drift (−0.17 µm/min: the circles run one after
/// the other) and two lateral plays instead, for every seed tried (1–7).
/// At one feed two radii do not separate it from the position loops' following error (−q·v²/R
/// per circle: with a·R and e, three per-circle constants on two circles): there the scale is
/// listed as confounded with `following_error` (issue 26) and no scale is named; the same two
/// radii at two feeds (a feed sweep) name the scale.
#[test]
fn two_radii_separate_the_isotropic_scale() {
    let e = MachineErrors {
        setup_offset_um: [20.0, 10.0, 0.0],
        length_offset_um: 4.0,
        scale_um_per_m: [30.0, 30.0, 0.0],
        ..MachineErrors::default()
    };
    let one_feed = run(
        &make_plan(&[96.5, 83.0], &[0.0], Plane::Xy),
        e.clone(),
        4,
        [None; 3],
    );
    let s = summary(&one_feed);
    assert!(
        machine_names(&one_feed)
            .iter()
            .all(|n| !n.starts_with("scale_")),
        "{s}"
    );
    assert!(
        one_feed.confounded.iter().any(|g| {
            g.contains(&"following_error".to_string()) && g.contains(&"scale_x".to_string())
        }),
        "{s}"
    );
    let spec = PlanSpec::machine_test(
        &[96.5, 83.0],
        &[0.0],
        Plane::Xy,
        1000.0,
        BALL,
        PlanDialect::Linuxcnc,
    )
    .feed_sweep(&[1000.0, 2000.0]);
    let d = run(
        &plan(&spec, &Calibration::DEFAULT).unwrap(),
        e,
        4,
        [None; 3],
    );
    let s = summary(&d);
    let mut n = machine_names(&d);
    n.sort();
    assert_eq!(n, vec!["scale_x", "scale_y"], "{s}");
    for name in ["scale_x", "scale_y"] {
        let f = d.effects.iter().find(|f| f.effect.name() == name).unwrap();
        assert_unbiased(name, f.value, f.sigma.unwrap(), 30.0, 0.3, &s);
    }
    let f = &d.effects[1];
    assert_unbiased("e (two radii)", f.value, f.sigma.unwrap(), 4.0, 0.1, &s);
}

/// A circle above the table ball cannot tell c_z from the bar length; a circle through the
/// ball's height does not see c_z at all. Both are said as confounded, nothing is named.
#[test]
fn a_circle_above_the_table_ball_confounds_c_z_with_the_bar_length() {
    let e = MachineErrors {
        setup_offset_um: [5.0, 5.0, 8.0],
        length_offset_um: 2.0,
        ..MachineErrors::default()
    };
    let d = run(
        &make_plan(&[85.0], &[30.0], Plane::Xy),
        e.clone(),
        8,
        [None; 3],
    );
    assert!(machine_names(&d).is_empty(), "{}", summary(&d));
    assert!(
        d.confounded.contains(&vec![
            "setup_offset.z".to_string(),
            "length_offset".to_string()
        ]),
        "{:?}",
        d.confounded
    );
    let d = run(&make_plan(&[85.0], &[0.0], Plane::Xy), e, 8, [None; 3]);
    assert!(machine_names(&d).is_empty(), "{}", summary(&d));
    assert!(
        d.confounded.contains(&vec!["setup_offset.z".to_string()]),
        "{:?}",
        d.confounded
    );
}

/// 24 noise draws (and clock, feed and start) of the same machine: the z-scores
/// (value − truth)/σ of 4 µm of play on Y scatter with a standard deviation near 1 (with 24
/// draws, 0.7..1.35 covers > 95 %) and a mean near 0; a σ off by the set-up's coupling, by the
/// timing σ or by a wrong dof fails, and so does a bias of more than about 0.5σ.
#[test]
fn standard_errors_match_the_scatter_over_seeds() {
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let mut z = vec![];
    for seed in 0..24u64 {
        let mut e = MachineErrors {
            setup_offset_um: [40.0, -25.0, 0.0],
            length_offset_um: 2.0,
            ..MachineErrors::default()
        };
        e.backlash_um[1] = 4.0;
        let d = run_noise(&p, e, 1000 + seed, [None; 3], 0.4);
        let f = only(&d, "backlash_y");
        z.push((f.value - 4.0) / f.sigma.unwrap());
    }
    let mean = z.iter().sum::<f64>() / z.len() as f64;
    let sd = (z.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (z.len() - 1) as f64).sqrt();
    eprintln!("z-scores: mean {mean:.3}, sd {sd:.3}");
    assert!(mean.abs() < 0.6, "mean z {mean}: {z:?}");
    assert!(sd > 0.7 && sd < 1.35, "sd of z {sd}: {z:?}");
}

/// erfc(x) for x ≥ 0 (Abramowitz & Stegun 7.1.26, error under 1.5·10⁻⁷).
fn erfc(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    poly * (-x * x).exp()
}

/// The false-alarm bound per run of the selection rule `diagnose` uses (docs/tests.md): extended
/// BIC with γ = ½, so the first effect chosen among N candidate families on m samples must
/// lower m·ln(SSR/m) by more than k·ln m + 2γ·ln N = k·ln m + ln N. Under no effect that drop is
/// χ²_k, and a k-parameter family's rate P(χ²_k > k·ln m + ln N) is at most the 1-parameter
/// one, so P(any) ≤ N·P(χ²₁ > ln(m·N)) = N·erfc(√(ln(m·N)/2)). The 0.05 µm floor only removes
/// alarms, so this is an upper bound.
fn false_alarm_bound(m: usize, n: usize) -> f64 {
    let x = ((m * n) as f64).ln();
    n as f64 * erfc((0.5 * x).sqrt())
}

/// The smallest k with P(Poisson(λ) > k) < 1 %.
fn poisson_upper(lambda: f64) -> usize {
    let (mut k, mut term, mut cdf) = (0usize, (-lambda).exp(), (-lambda).exp());
    while 1.0 - cdf >= 0.01 {
        k += 1;
        term *= lambda / k as f64;
        cdf += term;
    }
    k
}

/// A machine without errors (random set-ups and noise, 40 runs) names a machine effect no more
/// often than the selection rule allows: the count of runs with an alarm must stay within the
/// 99 % Poisson bound of the per-run bounds of [`false_alarm_bound`] summed over the runs
/// (about 0.6 % per run at m ≈ 17 000 samples and N ≈ 15 candidates: λ ≈ 0.23, at most 2
/// alarms). A rule 20 times laxer fails nine seeds in ten; plain BIC (≈ 3 % per run) one in ten
/// (docs/tests.md).
#[test]
fn null_data_report_no_machine_effect_at_the_stated_false_alarm_rate() {
    // The helpers against known values: erfc(1), P(χ²₁ > 3.841) = 5 %, Poisson(0.23) > 2 < 1 %.
    assert!((erfc(1.0) - 0.157_299_207).abs() < 1e-6);
    assert!((erfc((0.5f64 * 3.841).sqrt()) - 0.05).abs() < 1e-4);
    assert_eq!(poisson_upper(0.23), 2);
    let p = make_plan(&[90.0], &[0.0], Plane::Xy);
    let mut rng = rand::rngs::StdRng::seed_from_u64(77);
    let (runs, mut alarms, mut bound_sum) = (40, 0, 0.0);
    let mut named = vec![];
    for _ in 0..runs {
        let e = random_setup(&mut rng);
        let sigma = rng.gen_range(0.1..0.8);
        let d = run_noise(&p, e, rng.gen(), [None; 3], sigma);
        bound_sum += false_alarm_bound(d.samples, d.candidates.len());
        let n = machine_names(&d);
        if !n.is_empty() {
            alarms += 1;
            named.push(n);
        }
    }
    let allowed = poisson_upper(bound_sum);
    eprintln!(
        "{alarms} false alarms in {runs} runs, expected at most {bound_sum:.2}, allowed {allowed}"
    );
    assert!(
        alarms <= allowed,
        "{alarms} false alarms in {runs} null runs ({named:?}); the rule allows {allowed} (λ {bound_sum:.2})"
    );
}

/// The floor holds for the value named, not only for the search's: a servo mismatch that the
/// search let in above the floor (its second column, the lag difference times the common lag,
/// is free there and took up 0.054 µm of a misfit shaped like a scale mismatch, cos 2θ·v²/R on a
/// circle) came out of the exact refit, which ties that column to the lag difference, as
/// −0.00071 ± 0.00022 ms: 0.016 µm on D, under the 0.05 µm floor, and was named beside the two
/// real effects (seed 5023 of sync_random: lost motion per end of Y, 7.5 and 10.9 µm, and a
/// 3.8 µm cyclic error of X at 11.5 mm, 2360 mm/min, 515 Hz). It is listed below the floor.
#[test]
fn an_effect_the_refit_leaves_below_the_floor_is_not_named() {
    let centre = [132.62, 33.59, -36.36];
    let spec = PlanSpec {
        feed_in_mm: 2.0,
        ..PlanSpec::machine_test(
            &[95.838],
            &[0.0],
            Plane::Xy,
            2360.0,
            centre,
            PlanDialect::Linuxcnc,
        )
    };
    let p = plan(&spec, &Calibration::DEFAULT).unwrap();
    let mut errors = MachineErrors {
        setup_offset_um: [-36.93, 1.08, 19.82],
        ..MachineErrors::default()
    };
    errors.backlash_ends[1] = Some(BacklashEnds {
        neg_end_mm: centre[1] - 95.838,
        neg_um: 7.505,
        pos_end_mm: centre[1] + 95.838,
        pos_um: 10.853,
    });
    errors.cyclic[0] = Cyclic {
        amplitude_um: 3.836,
        pitch_mm: 11.5235,
        phase_rad: 1.0586,
    };
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, centre);
    cfg.errors = errors;
    cfg.machine.feed_override_pct = 95.2426;
    cfg.machine.accel_mm_s2 = [1828.8, 563.9, 1714.6];
    cfg.instrument.clock_ppm = 54.99;
    cfg.instrument.start_delay_s = 3.89;
    cfg.instrument.t0_us = 681_677_719;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.seed = 5023;
    cfg.instrument.sample_rate_hz = 515.21;
    let rec = Simulation::new(&write_program(&p, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    let sync = synchronise(&p, &r).unwrap();
    let pitch = [Some(11.5235), Some(10.0), None];
    let d = diagnose_planned(&p, &r, sync, pitch, &Options::default())
        .unwrap()
        .diagnosis;
    let text = summary(&d);
    assert_eq!(machine_names(&d), ["backlash_y", "cyclic_x"], "{text}");
    let value = |name: &str| {
        let f = d.effects.iter().find(|f| f.effect.name() == name).unwrap();
        (f.value, f.sigma.unwrap())
    };
    let (b, s) = value("backlash_y");
    assert_unbiased("backlash_y", b, s, 0.5 * (7.505 + 10.853), 0.05, &text);
    let (c, s) = value("cyclic_x");
    assert_unbiased("cyclic_x", c, s, 3.836, 0.05, &text);
    let (_, peak) = d
        .below_floor
        .iter()
        .find(|(name, _)| name == "servo_mismatch_xy")
        .unwrap_or_else(|| panic!("the servo mismatch is not listed below the floor\n{text}"));
    assert!(*peak < d.floor_um, "{peak} µm\n{text}");
}

/// A cyclic error of an axis that lags its command (servo delays X 4 ms, Y 1 ms): the machine's
/// cyclic error lies where the delayed axis is, A·sin(w·(p − v·τ)), whose speed-dependent part
/// has the shape of an interference of (w·τ·A_c, −w·τ·A_s). It is one cyclic error, named with
/// the servo mismatch and nothing else; the speed-dependent part is listed as not named with
/// the lag as its reason (it was named as `interference_y`, issue 20's seed 9005). A real
/// read-head interference beside them is still named.
#[test]
fn a_cyclic_error_of_a_lagging_axis_is_one_cyclic_error() {
    let p = make_plan(&[95.0, 86.0], &[0.0], Plane::Xy);
    let pitch = 6.0;
    let mut errors = MachineErrors::default();
    errors.cyclic[1] = Cyclic {
        amplitude_um: 2.5,
        pitch_mm: pitch,
        phase_rad: 0.7,
    };
    errors.servo_delay_ms = [4.0, 1.0, 0.0];
    let d = run(&p, errors.clone(), 71, [None, Some(pitch), None]);
    let s = summary(&d);
    assert_eq!(
        machine_names(&d),
        vec!["servo_mismatch_xy".to_string(), "cyclic_y".to_string()],
        "{s}"
    );
    let lag = d
        .not_significant
        .iter()
        .find(|w| w.name == "interference_y")
        .unwrap_or_else(|| panic!("the lag's part is not said: {s}"));
    assert!(lag.reason.contains("lags its command"), "{s}");
    let f = d
        .effects
        .iter()
        .find(|f| f.effect.name() == "cyclic_y")
        .unwrap();
    assert!((f.value - 2.5).abs() < 0.05, "{s}");
    // With a read head reporting late by 0.1 ms·sin(…) on Y as well, the interference is named.
    errors.interference[1] = Interference {
        latency_ms: 0.1,
        pitch_mm: pitch,
        phase_rad: 0.2,
    };
    let d = run(&p, errors, 72, [None, Some(pitch), None]);
    let names = machine_names(&d);
    assert!(
        names.contains(&"interference_y".to_string()),
        "{}",
        summary(&d)
    );
}
