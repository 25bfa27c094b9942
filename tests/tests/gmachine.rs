//! The G-code machine simulator (`jdbb_tests::gmachine`) end to end, on hand-made ballbar programs
//! in each dialect (`tests/data/gmachine/`): known answers for the instrument reading, the
//! machine errors' effect on D, the clocks and the recording format.
//!
//! Every program: table ball at (150, 100, −50), R = 90 mm, F1000, start angle 0; rapid to the
//! feed-in point 2 mm inside the circle, M0 (mount), dwell 1 s, feed-in, 90° lead-in, 360° ccw in
//! two 180° arcs, 90° overshoot, dwell 1 s (reversal), the same cw, feed-out, dwell 1 s.
use std::f64::consts::PI;

use jdbb_core::geometry;
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{
    simulate, Axis, Cyclic, Dialect, MachineErrors, Recording, ReversalSpike, SegmentKind,
    SimConfig, SimError, Simulation, Squareness, TruthSample,
};

const BALL: [f64; 3] = [150.0, 100.0, -50.0];
const R: f64 = 90.0;
const V_MM_S: f64 = 1000.0 / 60.0;

const LINUXCNC: &str = include_str!("../data/gmachine/ballbar.ngc");
const GRBL: &str = include_str!("../data/gmachine/ballbar_grbl.nc");
const FANUC: &str = include_str!("../data/gmachine/O1000.nc");
const MARLIN: &str = include_str!("../data/gmachine/ballbar.gcode");
const ZX: &str = include_str!("../data/gmachine/ballbar_zx.ngc");

/// Program text and height H of the circle above the ball (along the plane normal).
fn program(d: Dialect) -> (&'static str, f64) {
    match d {
        Dialect::LinuxCnc => (LINUXCNC, 0.0),
        Dialect::Grbl => (GRBL, 0.0),
        Dialect::Fanuc => (FANUC, 0.0),
        Dialect::Marlin => (MARLIN, 20.0),
    }
}

fn run(text: &str, cfg: SimConfig) -> Recording {
    simulate(text, cfg).unwrap_or_else(|e| panic!("{e}"))
}

/// Block indices of the arcs: [lead-in, data, data, overshoot] ccw then the same cw.
fn arcs(rec: &Recording) -> Vec<usize> {
    let a: Vec<usize> = (0..rec.truth.blocks.len())
        .filter(|&i| matches!(rec.truth.blocks[i].kind, SegmentKind::Arc { .. }))
        .collect();
    assert_eq!(a.len(), 8, "{:?}", rec.truth.blocks);
    a
}

/// Samples on the data arcs (360° ccw and 360° cw), with +1 (ccw) or −1 (cw).
fn data_samples(rec: &Recording) -> Vec<(&TruthSample, f64)> {
    let a = arcs(rec);
    rec.truth
        .samples
        .iter()
        .filter_map(|s| {
            let b = s.block?;
            if b == a[1] || b == a[2] {
                Some((s, 1.0))
            } else if b == a[5] || b == a[6] {
                Some((s, -1.0))
            } else {
                None
            }
        })
        .collect()
}

/// Angle of the commanded position about the ball in the xy plane.
fn theta(s: &TruthSample) -> f64 {
    (s.command_mm[1] - BALL[1]).atan2(s.command_mm[0] - BALL[0])
}

/// A calibration fine enough (2²² counts/rev: D to ≈ 35 nm) that µm effects show in the counts.
fn fine() -> Calibration {
    let mut c = Calibration::DEFAULT;
    c.enc1.counts_per_rev = 1 << 22;
    c.enc2.counts_per_rev = 1 << 22;
    c
}

/// |device D − expected| within half a count on each encoder plus the chip's f32 budget.
fn assert_within_quantisation(cal: &Calibration, enc1: i64, enc2: i64, d_mm: f64, expect_mm: f64) {
    let s = geometry::sensitivity_mm_per_count(cal, enc1, enc2);
    let tol =
        0.5 * (s[0].abs() + s[1].abs()) * 1.01 + geometry::accuracy_budget_mm(cal, enc1, enc2);
    assert!(
        (d_mm - expect_mm).abs() <= tol,
        "D {d_mm} vs {expect_mm}: off by {:e} > {tol:e}",
        d_mm - expect_mm
    );
}

/// Run the LinuxCNC program with `errors` and compare ΔD (µm) on the data arcs with `expect`
/// (sample, sense ±1 → µm) within `tol_um`.
fn check_effect(
    errors: MachineErrors,
    expect: impl Fn(&TruthSample, f64) -> f64,
    tol_um: f64,
) -> Recording {
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    cfg.errors = errors;
    cfg.instrument.calibration = fine();
    let rec = run(LINUXCNC, cfg.clone());
    let data = data_samples(&rec);
    assert!(data.len() > 60_000, "{}", data.len());
    let mut worst = 0.0f64;
    for (s, sense) in &data {
        let got = (s.d_mm_true - R) * 1e3;
        let want = expect(s, *sense);
        worst = worst.max((got - want).abs());
        assert!(
            (got - want).abs() <= tol_um,
            "θ {:.1}°, sense {sense}: ΔD {got:.6} µm, expected {want:.6}",
            theta(s).to_degrees()
        );
        // ... and the device sees it, to its quantisation.
        let row = &rec.rows[s.seq as usize];
        assert_within_quantisation(
            &cfg.instrument.calibration,
            row.enc1,
            row.enc2,
            row.d_mm,
            s.d_mm_true,
        );
    }
    println!("worst model deviation {worst:.2e} µm");
    rec
}

#[test]
fn ideal_machine_reads_sqrt_r2_h2_in_every_dialect() {
    let reference = run(LINUXCNC, SimConfig::new(Dialect::LinuxCnc, BALL));
    for d in Dialect::ALL {
        let (text, h) = program(d);
        let cfg = SimConfig::new(d, BALL);
        let rec = run(text, cfg.clone());
        let expect = (R * R + h * h).sqrt();
        let a = arcs(&rec);
        let mut n = 0;
        for s in &rec.truth.samples {
            if !s.block.is_some_and(|b| a.contains(&b)) {
                continue;
            }
            n += 1;
            assert!(
                (s.d_mm_true - expect).abs() < 1e-9,
                "{d:?}: {}",
                s.d_mm_true
            );
            let row = &rec.rows[s.seq as usize];
            assert_within_quantisation(
                &cfg.instrument.calibration,
                row.enc1,
                row.enc2,
                row.d_mm,
                expect,
            );
        }
        // Both directions of 360° + 2·90° at 1000 mm/min from rest to rest (tangential
        // acceleration ½·500 mm/s²: each run takes L/v + v/a), at 1 kHz.
        let arcs_s = 2.0 * (1.5 * 2.0 * PI * R / V_MM_S + V_MM_S / 250.0);
        assert!(
            (n as f64 - 1000.0 * arcs_s).abs() < 3.0,
            "{d:?}: {n} samples on arcs"
        );

        // Same blocks, same timing from the program stop on (dwells of 1 s in each dialect's units).
        let kinds: Vec<_> = rec.truth.blocks.iter().map(|b| b.kind).collect();
        let ref_kinds: Vec<_> = reference.truth.blocks.iter().map(|b| b.kind).collect();
        assert_eq!(kinds, ref_kinds, "{d:?}");
        for (b, r) in rec.truth.blocks.iter().zip(&reference.truth.blocks).skip(1) {
            assert!(
                (b.start_s - r.start_s).abs() < 1e-9,
                "{d:?} line {}",
                b.line
            );
            assert!((b.end_s - r.end_s).abs() < 1e-9, "{d:?} line {}", b.line);
            if b.kind == SegmentKind::Dwell {
                assert!(
                    (b.end_s - b.start_s - 1.0).abs() < 1e-12,
                    "{d:?} line {}",
                    b.line
                );
            }
        }
        // The recording starts at the program stop; cycle start 3 s later.
        assert_eq!(
            rec.truth.blocks[1].kind,
            SegmentKind::Stop { skipped: false }
        );
        assert!(rec.truth.blocks[1].start_s.abs() < 1e-12);
        assert!((rec.truth.cycle_start_us - 3e6).abs() < 1e-6);
        // Arcs end where programmed.
        for &i in &a {
            let b = &rec.truth.blocks[i];
            let r = [0, 1, 2].map(|k| b.to_mm[k] - BALL[k]);
            let r_plane = (r[0] * r[0] + r[1] * r[1]).sqrt();
            assert!(
                (r_plane - R).abs() < 1e-12 && (r[2] - h).abs() < 1e-12,
                "{d:?}: {b:?}"
            );
        }
    }
}

#[test]
fn zx_plane_program_circles_the_ball() {
    let cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    let rec = run(ZX, cfg.clone());
    let a = arcs(&rec);
    let mut n = 0;
    for s in &rec.truth.samples {
        let Some(b) = s.block.filter(|b| a.contains(b)) else {
            continue;
        };
        n += 1;
        assert!((s.d_mm_true - R).abs() < 1e-9);
        assert!(
            (s.command_mm[1] - BALL[1]).abs() < 1e-12,
            "stays in the ZX plane"
        );
        // G3 (ccw seen from +Y) turns from +Z towards +X: angular velocity r × v along +y.
        let ccw = rec.truth.blocks[b].kind == SegmentKind::Arc { ccw: true };
        let next = &rec.truth.samples[s.seq as usize + 1];
        let r = [0, 1, 2].map(|k| s.command_mm[k] - BALL[k]);
        let v = [0, 1, 2].map(|k| next.command_mm[k] - s.command_mm[k]);
        let w_y = r[2] * v[0] - r[0] * v[2];
        if v.iter().map(|x| x.abs()).sum::<f64>() > 1e-4 {
            assert_eq!(w_y > 0.0, ccw, "{s:?}");
        }
    }
    assert!(n > 90_000);
}

#[test]
fn without_a_program_stop_cycle_start_is_the_program_start() {
    // The operator jogged to the feed-in point, started the recording, then the program.
    let text: String = GRBL
        .lines()
        .filter(|l| !l.starts_with("M0"))
        .collect::<Vec<_>>()
        .join("\n");
    let mut cfg = SimConfig::new(Dialect::Grbl, BALL);
    cfg.machine.initial_position_mm = [238.0, 100.0, -50.0];
    cfg.instrument.start_delay_s = 2.5;
    let rec = run(&text, cfg);
    assert!((rec.truth.cycle_start_us - 2.5e6).abs() < 1e-6);
    assert!((rec.truth.recording_start_program_s + 2.5).abs() < 1e-12);
    // The rapid to where the machine already is takes no time; the dwell starts at cycle start.
    assert_eq!(rec.truth.blocks[0].kind, SegmentKind::Rapid);
    assert_eq!(rec.truth.blocks[0].end_s, 2.5);
    assert_eq!(rec.truth.blocks[1].kind, SegmentKind::Dwell);
    assert!((rec.truth.blocks[1].start_s - 2.5).abs() < 1e-12);
    for s in &rec.truth.samples[..3500] {
        assert!((s.d_mm_true - 88.0).abs() < 1e-12);
    }
}

#[test]
fn later_stops_wait_for_the_operator_and_m1_follows_its_switch() {
    let text = LINUXCNC
        .replace("G4 P1\nG2", "M1\nG2")
        .replace("M2", "M0\nM2");
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    cfg.machine.stop_wait_s = 7.0;
    let rec = run(&text, cfg.clone());
    let stops: Vec<f64> = rec
        .truth
        .blocks
        .iter()
        .filter(|b| b.kind == SegmentKind::Stop { skipped: false })
        .map(|b| b.end_s - b.start_s)
        .collect();
    assert_eq!(stops, [3.0, 7.0, 7.0]);
    cfg.machine.optional_stop = false;
    let rec = run(&text, cfg);
    let kinds: Vec<_> = rec.truth.blocks.iter().map(|b| b.kind).collect();
    assert!(kinds.contains(&SegmentKind::Stop { skipped: true }));
    let skipped = rec
        .truth
        .blocks
        .iter()
        .find(|b| b.kind == SegmentKind::Stop { skipped: true })
        .unwrap();
    assert_eq!(skipped.start_s, skipped.end_s);
}

#[test]
fn unsupported_word_fails_with_its_line() {
    let mut lines: Vec<&str> = LINUXCNC.lines().collect();
    lines.insert(6, "M8 (coolant)");
    let text = lines.join("\n");
    match Simulation::new(&text, SimConfig::new(Dialect::LinuxCnc, BALL)) {
        Err(SimError::Program(e)) => {
            assert_eq!(e.line, 7);
            assert!(
                e.to_string().contains("line 7") && e.to_string().contains("M8"),
                "{e}"
            );
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn misplaced_table_ball_is_out_of_reach() {
    let cfg = SimConfig::new(Dialect::LinuxCnc, [180.0, 100.0, -50.0]);
    match simulate(LINUXCNC, cfg) {
        Err(e @ SimError::OutOfReach { .. }) => {
            let SimError::OutOfReach {
                t_s, line, d_mm, ..
            } = e
            else {
                unreachable!()
            };
            assert_eq!(t_s, 0.0);
            assert_eq!(line, Some(6)); // waiting at M0 when the recording starts
            assert!((d_mm - 58.0).abs() < 1e-9);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn backlash_on_a_circle_is_seed_000_eq_16_with_its_dead_band() {
    // Play b: the carriage trails the motor by b/2 in the direction of x's motion, δx = −s·b/2,
    // so ΔD = δx·cos θ = ∓(b/2)·cos θ (seed 000 eq. 16 with f = −b). On a ccw circle x moves −x
    // for θ in (0, π), +x in (π, 2π); cw the opposite. Right after x turns at x_r = ±R it stands
    // still until the motor has come back b: δx = x_r + s·b/2 − x there (the dead band).
    let b = 12.0;
    check_effect(
        MachineErrors {
            backlash_um: [b, 0.0, 0.0],
            ..Default::default()
        },
        |s, sense| {
            let th = theta(s);
            let vx = -sense * th.sin();
            if vx.abs() < 1e-6 {
                return 0.0;
            }
            let dir = vx.signum();
            let x = s.command_mm[0] - BALL[0];
            // Travel since the last turn (at −R before moving +, at +R before moving −), µm.
            let travel_um = 1e3 * (x + dir * R) * dir;
            let dx = -0.5 * b * dir + dir * (b - travel_um).max(0.0);
            dx * th.cos()
        },
        1e-3,
    );
}

#[test]
fn squareness_on_a_circle_is_s_x_y_over_r() {
    let s_um_per_m = 40.0;
    check_effect(
        MachineErrors {
            squareness: vec![Squareness {
                axis: Axis::X,
                by: Axis::Y,
                um_per_m: s_um_per_m,
            }],
            ..Default::default()
        },
        |s, _| {
            let (x, y) = (s.command_mm[0] - BALL[0], s.command_mm[1] - BALL[1]);
            s_um_per_m * 1e-3 * x * y / R
        },
        1e-4,
    );
}

#[test]
fn scale_is_measured_from_the_program_origin() {
    // δx = a·x with x from the program origin (x = 150 + R cos θ): ΔD = δx·cos θ.
    let a = 30.0;
    check_effect(
        MachineErrors {
            scale_um_per_m: [a, 0.0, 0.0],
            ..Default::default()
        },
        |s, _| a * 1e-3 * s.command_mm[0] * theta(s).cos(),
        1e-3, // second order: δ²/(2R) ≈ 1e-4 µm at δ = 4.5 µm
    );
}

#[test]
fn cyclic_error_on_a_circle() {
    let c = Cyclic {
        amplitude_um: 3.0,
        pitch_mm: 5.0,
        phase_rad: 0.7,
    };
    check_effect(
        MachineErrors {
            cyclic: [Cyclic::default(), c, Cyclic::default()],
            ..Default::default()
        },
        |s, _| {
            let dy = c.amplitude_um * (2.0 * PI * s.command_mm[1] / c.pitch_mm + c.phase_rad).sin();
            dy * theta(s).sin()
        },
        1e-3,
    );
}

#[test]
fn setup_offset_length_offset_and_drift() {
    let (c, e, drift) = ([10.0, -6.0, 4.0], 3.0, 2.0);
    check_effect(
        MachineErrors {
            setup_offset_um: c,
            length_offset_um: e,
            drift_um_per_min: drift,
            ..Default::default()
        },
        |s, _| {
            let th = theta(s);
            // Cycle start is 3 s into the recording (start_delay_s).
            -(c[0] * th.cos() + c[1] * th.sin()) + e + drift * (s.t_s - 3.0) / 60.0
        },
        2e-3, // second order: |c|²/(2R) ≈ 1e-3 µm
    );
}

#[test]
fn servo_delay_is_second_order_when_equal_and_an_ellipse_when_not() {
    // Equal delays on a circle run at constant speed: the delayed point is on the circle, ΔD = 0
    // exactly — not even the τ²v²/(2R) of the first-order −τ·v model.
    let tau = 5.0;
    let rec = check_effect(
        MachineErrors {
            servo_delay_ms: [tau, tau, 0.0],
            ..Default::default()
        },
        |_, _| 0.0,
        1e-6,
    );
    let model = (tau * 1e-3 * V_MM_S).powi(2) / (2.0 * R) * 1e3;
    assert!(model > 1e-2, "the −τ·v model would show {model} µm");
    // The lag itself: the actual point is the command τ earlier, i.e. v·τ behind along the path.
    let (s, _) = data_samples(&rec)[1000];
    let lag = s
        .command_mm
        .iter()
        .zip(&s.actual_mm)
        .map(|(c, a)| (c - a).powi(2))
        .sum::<f64>();
    assert!((lag.sqrt() - V_MM_S * tau * 1e-3).abs() < 1e-6);

    // Mismatch: x late by τx, y by τy: D ≈ R + R·ω·(τx − τy)/2·sin 2θ, ω = dθ/dt (signed).
    let (tx, ty) = (3.0e-3, 1.0e-3);
    check_effect(
        MachineErrors {
            servo_delay_ms: [tx * 1e3, ty * 1e3, 0.0],
            ..Default::default()
        },
        |s, sense| {
            let w = sense * V_MM_S / R;
            R * w * (tx - ty) / 2.0 * (2.0 * theta(s)).sin() * 1e3
        },
        0.02, // second order: R(ωΔτ)² ≈ 1e-2 µm
    );
}

#[test]
fn reversal_spike_decays_with_tau() {
    // y reverses (+ → −) at θ = 90° ccw, where the lead-in ends: δy = −h·(−1)·e^{−Δt/τ} and
    // ΔD = δy·sin θ.
    let (h, tau_ms) = (4.0, 20.0);
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    cfg.errors.reversal_spike[1] = ReversalSpike {
        height_um: h,
        tau_ms,
    };
    let rec = run(LINUXCNC, cfg);
    let a = arcs(&rec);
    let t_rev = rec.truth.blocks[a[1]].start_s;
    let mut checked = 0;
    for s in &rec.truth.samples {
        let dd = (s.d_mm_true - R) * 1e3;
        if s.block == Some(a[0]) {
            assert!(dd.abs() < 1e-9, "no spike before the reversal: {dd}");
        } else if s.t_s >= t_rev && s.t_s < t_rev + 0.2 {
            let want = h * (-(s.t_s - t_rev) * 1e3 / tau_ms).exp() * theta(s).sin();
            assert!(
                (dd - want).abs() < 1e-3,
                "Δt {:.4}: {dd} vs {want}",
                s.t_s - t_rev
            );
            checked += 1;
        }
    }
    assert!(checked >= 199, "{checked}");
}

#[test]
fn clock_ppm_scales_device_time() {
    let ppm = 5000.0;
    let t0 = 123_456;
    let mut cfg = SimConfig::new(Dialect::Grbl, BALL);
    let ideal = run(GRBL, cfg.clone());
    cfg.instrument.clock_ppm = ppm;
    cfg.instrument.t0_us = t0;
    let rec = run(GRBL, cfg);
    let k = 1.0 + ppm * 1e-6;
    // Nominal rate on the device clock: t_us = t0 + 1000·seq; the true time between samples is shorter.
    for (i, r) in rec.rows.iter().enumerate().step_by(997) {
        assert_eq!(r.seq, i as u64);
        assert_eq!(r.t_us, t0 + 1000 * i as u64);
        assert!((rec.truth.samples[i].t_s - i as f64 * 1e-3 / k).abs() < 1e-12);
    }
    assert!((rec.truth.cycle_start_us - (t0 as f64 + 3e6 * k)).abs() < 1e-6);
    // Block times: the same true times, device times stretched.
    for (b, r) in rec.truth.blocks.iter().zip(&ideal.truth.blocks) {
        assert!((b.start_s - r.start_s).abs() < 1e-12);
        assert!((b.start_us - (t0 as f64 + r.start_us * k)).abs() < 1e-6);
    }
    let ratio = rec.rows.len() as f64 / ideal.rows.len() as f64;
    assert!((ratio - k).abs() < 1e-4, "{ratio}");
    // In the data alone: the feed-in starts 4 s (true) after the recording, D reaches 88.05 mm
    // √(2·0.05/500) s later; on the device clock both are stretched by k.
    let first = |rec: &Recording| rec.rows.iter().find(|r| r.d_mm > 88.05).unwrap().t_us;
    let t_true = 4.0 + (2.0 * 0.05 / 500.0f64).sqrt();
    assert!(
        (first(&ideal) as f64 - t_true * 1e6).abs() <= 2000.0,
        "{}",
        first(&ideal)
    );
    assert!(
        (first(&rec) as f64 - (t0 as f64 + t_true * k * 1e6)).abs() <= 2000.0,
        "{}",
        first(&rec)
    );
}

#[test]
fn feed_override_scales_the_arcs() {
    let mut cfg = SimConfig::new(Dialect::Fanuc, BALL);
    cfg.machine.feed_override_pct = 120.0;
    let rec = run(FANUC, cfg);
    assert_eq!(rec.truth.feed_factor, 1.2);
    let a = arcs(&rec);
    let data_s = rec.truth.blocks[a[2]].end_s - rec.truth.blocks[a[1]].start_s;
    assert!(
        (data_s - 2.0 * PI * R / (1.2 * V_MM_S)).abs() < 1e-9,
        "{data_s}"
    );
}

#[test]
fn noise_has_the_configured_sigma() {
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    cfg.instrument.noise_um = 2.0;
    cfg.instrument.calibration = fine();
    let rec = run(LINUXCNC, cfg.clone());
    // The lean's path does not depend on the noise (separate random streams, same seed).
    cfg.instrument.noise_um = 0.0;
    let quiet = run(LINUXCNC, cfg);
    assert!(rec
        .truth
        .samples
        .iter()
        .zip(&quiet.truth.samples)
        .all(|(a, b)| a.azimuth_rad == b.azimuth_rad));
    let n: Vec<f64> = rec
        .truth
        .samples
        .iter()
        .map(|s| (s.d_mm_instrument - s.d_mm_true) * 1e3)
        .collect();
    let mean = n.iter().sum::<f64>() / n.len() as f64;
    let sd = (n.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n.len() as f64).sqrt();
    assert!(
        mean.abs() < 0.05 && (sd - 2.0).abs() < 0.05,
        "mean {mean}, sd {sd}"
    );
    // Azimuth wanders, within its band.
    let psi: Vec<f64> = rec.truth.samples.iter().map(|s| s.azimuth_rad).collect();
    let (lo, hi) = psi
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), p| (l.min(*p), h.max(*p)));
    assert!(
        hi - lo > 0.05 && lo >= 0.3 - 0.6 - 1e-12 && hi <= 0.3 + 0.6 + 1e-12,
        "{lo} {hi}"
    );
}

#[test]
fn csv_is_what_jdbb_record_writes() {
    use jdbb::link::record::{write_csv_lines, CSV_HEADER};
    use jdbb::link::stream::SeqSample;
    use jdbb_core::protocol::{Sample, Status};
    let rec = run(MARLIN, SimConfig::new(Dialect::Marlin, BALL));
    let mut ours = Vec::new();
    rec.write_csv(&mut ours).unwrap();
    let mut theirs = CSV_HEADER.as_bytes().to_vec();
    let seq: Vec<SeqSample> = rec
        .rows
        .iter()
        .map(|r| SeqSample {
            seq: r.seq,
            sample: Sample {
                t_us: r.t_us,
                enc1: r.enc1,
                enc2: r.enc2,
                d_mm: r.d_mm,
                status: Status(0),
            },
        })
        .collect();
    write_csv_lines(&mut theirs, &seq);
    assert!(ours == theirs, "CSV differs from jdbb record's");
    let text = String::from_utf8(ours).unwrap();
    let second = text.lines().nth(1).unwrap();
    assert!(second.starts_with("0,0,"), "{second}");
    assert_eq!(
        second
            .rsplit(',')
            .next()
            .unwrap()
            .split('.')
            .nth(1)
            .unwrap()
            .len(),
        7
    );
}

#[test]
fn streaming_equals_the_collected_recording() {
    let sim = Simulation::new(LINUXCNC, SimConfig::new(Dialect::LinuxCnc, BALL)).unwrap();
    let rec = sim.run().unwrap();
    assert_eq!(sim.len(), rec.rows.len());
    for (i, s) in sim.samples().enumerate().step_by(1013) {
        let s = s.unwrap();
        assert_eq!(s.row, rec.rows[i]);
        assert_eq!(s.truth, rec.truth.samples[i]);
    }
}

/// 10 minutes of ballbar circles at 1 kHz (600 000 samples). Timing is only meaningful in release:
/// `cargo test --release -p jdbb-tests --test gmachine -- --ignored --nocapture`.
#[test]
#[ignore]
fn ten_minutes_at_one_khz() {
    let lines: Vec<&str> = LINUXCNC.lines().collect();
    let body = lines[6..19].join("\n"); // G4 … G4 after the stop: one ccw + cw test
    let mut text = lines[..6].join("\n");
    for _ in 0..6 {
        text.push('\n');
        text.push_str(&body);
    }
    text.push_str("\nM2\n");
    let t = std::time::Instant::now();
    let sim = Simulation::new(&text, SimConfig::new(Dialect::LinuxCnc, BALL)).unwrap();
    let rec = sim.run().unwrap();
    let el = t.elapsed();
    println!(
        "{} samples ({:.0} s recorded) in {el:?}",
        rec.rows.len(),
        rec.rows.len() as f64 / 1e3
    );
    assert!(rec.rows.len() >= 600_000);
    if !cfg!(debug_assertions) {
        assert!(el.as_secs_f64() < 3.0, "{el:?}");
    }
}
