//! The independent model of the instrument as built (`jdbb_tests::mechanism`) against known
//! answers, its own invariants, the issue's table of hidden-error effects (issue 9), and — as the
//! thing under test — the project's closed-form model `jdbb_core::geometry::distance_mm`.
use jdbb_core::calib::{Calibration, Direction};
use jdbb_tests::calibration_data::{calibrator_samples, distances_mm, swing};
use jdbb_tests::mechanism::{
    dot, encoder_angle_rad, encoder_count_real, Build, Mechanism, PoseError, ARCSEC,
    FRAME_RANGE_RAD,
};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// Every error term of the extended model non-zero, at magnitudes a real frame might have, and
/// a non-trivial encoder set-up (zero counts away from 0, encoder 2 counting backwards).
fn every_error(base: Calibration) -> Calibration {
    let mut c = base;
    c.l1_mm += 0.023;
    c.l2_mm -= 0.011;
    c.enc1.zero_count = 1234;
    c.enc2.zero_count = -5678;
    c.enc2.direction = Direction::Negative;
    c.enc1.zero_offset_rad = 35.0 * ARCSEC;
    c.enc2.zero_offset_rad = -60.0 * ARCSEC;
    c.enc1.eccentricity_rad = 40.0 * ARCSEC;
    c.enc1.eccentricity_phase_rad = 0.7;
    c.enc2.eccentricity_rad = 25.0 * ARCSEC;
    c.enc2.eccentricity_phase_rad = -2.1;
    c.axes_skew_rad = 90.0 * ARCSEC;
    c.frame1.tilt_rad = 50.0 * ARCSEC;
    c.frame2.tilt_rad = -30.0 * ARCSEC;
    c.frame1.offset_normal_rad = 40.0 * ARCSEC;
    c.frame1.offset_axial_rad = -70.0 * ARCSEC;
    c.frame2.offset_normal_rad = -45.0 * ARCSEC;
    c.frame2.offset_axial_rad = 60.0 * ARCSEC;
    c
}

fn law_of_cosines_mm(l1: f64, l2: f64, phi: f64) -> f64 {
    (l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * phi.cos()).sqrt()
}

#[test]
fn perfect_instrument_gives_the_law_of_cosines() {
    for (l1, l2) in [(50.0, 50.0), (40.0, 65.0)] {
        let cal = Calibration::nominal(l1, l2, 1 << 23);
        let m = Mechanism::new(&cal);
        let step = std::f64::consts::TAU / (1u64 << 23) as f64;
        for deg in [-74.0, -40.0, -3.0, 0.0, 0.5, 20.0, 60.0, 74.9] {
            let c = (deg * DEG / step).round() as i64;
            let phi = c as f64 * step;
            let expect = law_of_cosines_mm(l1, l2, phi);
            // The whole deflection on frame 1, then on frame 2.
            for counts in [[c, 0], [0, c]] {
                let d = m.distance_mm(counts).unwrap();
                assert!((d - expect).abs() < 1e-12, "{counts:?}: {d} vs {expect}");
            }
        }
        // Both frames turned: bar 2 lies in both slot planes, u ∝ (tan β, −tan α, 1), and the
        // deflection is the angle between u and bar 1.
        for (a, b) in [(30.0, -20.0), (-60.0, 45.0), (5.0, 70.0), (-70.0, -70.0)] {
            let (a, b) = (a * DEG, b * DEG);
            let u = m.bar2_direction([a, b]).unwrap();
            let w = [b.tan(), -a.tan(), 1.0];
            let wn = dot(w, w).sqrt();
            for k in 0..3 {
                assert!((u[k] - w[k] / wn).abs() < 1e-14, "{u:?}");
            }
            let phi = u[2].acos();
            let d = m.distance_for_direction_mm(u);
            assert!((d - law_of_cosines_mm(l1, l2, phi)).abs() < 1e-12);
        }
    }
}

#[test]
fn sign_conventions_of_the_definitions() {
    let m = Mechanism::new(&Calibration::DEFAULT);
    // Positive α turns bar 2 towards −y, positive β towards +x.
    let u = m.bar2_direction([0.3, 0.0]).unwrap();
    assert!(u[1] < -0.29 && u[0].abs() < 1e-15);
    let u = m.bar2_direction([0.0, 0.3]).unwrap();
    assert!(u[0] > 0.29 && u[1].abs() < 1e-15);
    // Positive skew opens the angle between the pivot axes; positive tilt lifts an axis to +z.
    let mut cal = Calibration::DEFAULT;
    cal.axes_skew_rad = 1e-3;
    cal.frame1.tilt_rad = 2e-3;
    cal.frame2.tilt_rad = -3e-3;
    let m = Mechanism::new(&cal);
    let [f1, f2] = m.frames;
    let proj = |a: [f64; 3]| [a[0], a[1], 0.0];
    let (p1, p2) = (proj(f1.axis), proj(f2.axis));
    let angle = (dot(p1, p2) / (dot(p1, p1) * dot(p2, p2)).sqrt()).acos();
    assert!((angle - (90.0 * DEG + 1e-3)).abs() < 1e-12, "{angle}");
    assert!((f1.axis[2] - 2e-3f64.sin()).abs() < 1e-15);
    assert!((f2.axis[2] + 3e-3f64.sin()).abs() < 1e-15);
    // The slot normals at zero: n₁⁰ ≈ +y, n₂⁰ ≈ +x; m⁰ = a × n⁰ ≈ +z for frame 1, −z for frame 2.
    assert!(f1.normal0[1] > 0.999 && f2.normal0[0] > 0.999);
}

#[test]
fn bars_swap_without_changing_d() {
    // D² = L1² + L2² + 2·L1·L2·u_z: symmetric in the bars whatever the frames do.
    let a = every_error(Calibration::nominal(43.0, 57.0, 1 << 23));
    let mut b = a;
    (b.l1_mm, b.l2_mm) = (a.l2_mm, a.l1_mm);
    let (ma, mb) = (Mechanism::new(&a), Mechanism::new(&b));
    for counts in [
        [0, 0],
        [900_000, -400_000],
        [-1_500_000, 1_200_000],
        [17, 1_700_000],
    ] {
        let (da, db) = (
            ma.distance_mm(counts).unwrap(),
            mb.distance_mm(counts).unwrap(),
        );
        assert!((da - db).abs() < 1e-12, "{counts:?}: {da} vs {db}");
    }
}

#[test]
fn inverse_and_forward_round_trip_with_every_error() {
    let cal = every_error(Calibration::DEFAULT);
    let m = Mechanism::new(&cal);
    let mut worst_quantised_um: f64 = 0.0;
    for pose in swing(&distances_mm(79.0, 99.5, 6), 24, 0.1) {
        let u = m.direction_for_pose(pose.d_mm, pose.azimuth_rad).unwrap();
        let theta = match m.frame_angles_for_direction_rad(u) {
            Ok(t) => t,
            Err(PoseError::OutOfRange) => continue,
            Err(e) => panic!("{e:?}"),
        };
        // Angles → direction → D is exact.
        let back = m.bar2_direction(theta).unwrap();
        let d = m.distance_for_direction_mm(back);
        assert!((d - pose.d_mm).abs() < 1e-11, "{pose:?}: {d}");
        // Each encoder reads back the angle at its real count (G9 and its inverse).
        for (enc, &theta_k) in m.encoders.iter().zip(&theta) {
            let c = encoder_count_real(enc, theta_k);
            let lo = encoder_angle_rad(enc, c.floor() as i64);
            let hi = encoder_angle_rad(enc, c.floor() as i64 + 1);
            let frac = c - c.floor();
            let interpolated = lo + (hi - lo) * frac;
            assert!(
                (interpolated - theta_k).abs() < 1e-12,
                "{interpolated} {}",
                theta_k
            );
        }
        // Rounded counts: D within what half a count can move it (≤ 0.023 µm per count).
        let counts = m.counts_for_pose(pose.d_mm, pose.azimuth_rad).unwrap();
        let err_um = (m.distance_mm(counts).unwrap() - pose.d_mm).abs() * 1e3;
        worst_quantised_um = worst_quantised_um.max(err_um);
    }
    assert!(worst_quantised_um < 0.025, "{worst_quantised_um}");
    assert!(worst_quantised_um > 1e-4, "quantisation must show");
}

#[test]
fn grip_distance_and_axial_slide_of_the_pivots_do_not_change_d() {
    // The calibration holds only p·n⁰/r and p·m⁰/r: the mechanism built with other grip
    // distances and pivot points slid along their axes must give the same D.
    let cal = every_error(Calibration::DEFAULT);
    let base = Mechanism::new(&cal);
    let other = Mechanism::with_build(
        &cal,
        &Build {
            grip_mm: [18.0, 31.0],
            axial_slide_mm: [7.0, -4.0],
        },
    );
    for counts in [[0, 0], [1_000_000, -700_000], [-1_600_000, 1_500_000]] {
        let (a, b) = (
            base.distance_mm(counts).unwrap(),
            other.distance_mm(counts).unwrap(),
        );
        assert!((a - b).abs() < 1e-12, "{counts:?}: {a} vs {b}");
    }
}

/// RMS (µm) of D_nominal(counts) − D_true over D 79–99 mm with the knee swung all round
/// (poses the frames reach), counts made by the instrument with `hidden`.
fn rms_effect_um(hidden: &Calibration) -> f64 {
    let truth = Mechanism::new(hidden);
    let nominal = Mechanism::new(&Calibration::DEFAULT);
    let poses = swing(&distances_mm(79.0, 99.0, 21), 72, 0.0);
    let samples = calibrator_samples(&truth, &poses, 0.0, 0);
    let ss: f64 = samples
        .iter()
        .map(|s| {
            let d = nominal.distance_mm([s.enc1, s.enc2]).unwrap();
            (d - s.d_true_mm).powi(2)
        })
        .sum();
    1e3 * (ss / samples.len() as f64).sqrt()
}

#[test]
fn hidden_errors_move_d_as_the_issue_table_says() {
    let base = Calibration::DEFAULT;
    let quantisation_um = rms_effect_um(&base);
    let mut l1 = base;
    l1.l1_mm += 0.023;
    let mut zero2 = base;
    zero2.enc2.zero_offset_rad = 60.0 * ARCSEC;
    let mut skew = base;
    skew.axes_skew_rad = 90.0 * ARCSEC;
    let ecc = |phase_deg: f64| {
        let mut c = base;
        c.enc1.eccentricity_rad = 40.0 * ARCSEC;
        c.enc1.eccentricity_phase_rad = phase_deg * DEG;
        rms_effect_um(&c)
    };
    let ecc_over_phase: Vec<f64> = (0..12).map(|i| ecc(30.0 * i as f64)).collect();
    let ecc_min = ecc_over_phase.iter().cloned().fold(f64::INFINITY, f64::min);
    let ecc_max = ecc_over_phase.iter().cloned().fold(0.0, f64::max);
    let rows = [
        ("L1 23 um long", rms_effect_um(&l1), 20.5),
        ("encoder 2 zero 60\" off", rms_effect_um(&zero2), 3.6),
        ("axes 90\" from perpendicular", rms_effect_um(&skew), 1.4),
        ("encoder 1 eccentric 40\" (largest phase)", ecc_max, 2.1),
    ];
    println!("quantisation alone: {quantisation_um:.4} um RMS");
    for (what, got, table) in rows {
        println!("{what}: {got:.3} um RMS (issue's table {table})");
    }
    println!("encoder 1 eccentric 40\", over phase: {ecc_min:.3}-{ecc_max:.3} um");
    assert!(quantisation_um < 0.02, "{quantisation_um}");
    for (what, got, table) in rows {
        // The issue's figures are rounded and came from another sweep of the knee: agree within
        // 15 %.
        assert!(
            (got / table - 1.0).abs() < 0.15,
            "{what}: {got:.3} um vs the table's {table}"
        );
    }
}

#[test]
fn matches_the_core_model_for_a_perfect_instrument() {
    for cal in [
        Calibration::DEFAULT,
        Calibration::nominal(40.0, 65.0, 1 << 23),
        Calibration::SEED_000,
    ] {
        let m = Mechanism::new(&cal);
        let n = cal.enc1.counts_per_rev as f64;
        let mut worst_mm: f64 = 0.0;
        for i in -8..=8 {
            for j in -8..=8 {
                let c1 = (n * (i as f64 / 8.0) * 74.0 / 360.0).round() as i64;
                let c2 = (n * (j as f64 / 8.0) * 74.0 / 360.0 + 0.37).round() as i64;
                let mine = m.distance_mm([c1, c2]).unwrap();
                let core = jdbb_core::geometry::distance_mm(&cal, c1, c2);
                worst_mm = worst_mm.max((mine - core).abs());
            }
        }
        assert!(worst_mm < 1e-11, "{cal:?}: {worst_mm} mm");
    }
}

#[test]
fn matches_the_core_model_with_each_error_and_all_together() {
    // The project's closed form against the mechanism built from the same definitions: one term
    // at a time (so a disagreement names the term), then all of them.
    let base = Calibration::DEFAULT;
    let e = 100.0 * ARCSEC;
    let mut cases: Vec<(&str, Calibration)> = vec![];
    let mut push = |name: &'static str, f: &dyn Fn(&mut Calibration)| {
        let mut c = base;
        f(&mut c);
        cases.push((name, c));
    };
    push("l1", &|c| c.l1_mm += 0.05);
    push("l2", &|c| c.l2_mm -= 0.05);
    push("zero_1", &|c| c.enc1.zero_offset_rad = e);
    push("zero_2", &|c| c.enc2.zero_offset_rad = -e);
    push("eccentricity_1", &|c| {
        c.enc1.eccentricity_rad = e;
        c.enc1.eccentricity_phase_rad = 1.0;
    });
    push("eccentricity_2", &|c| {
        c.enc2.eccentricity_rad = e;
        c.enc2.eccentricity_phase_rad = -2.5;
    });
    push("zero_count_direction", &|c| {
        c.enc1.zero_count = 4321;
        c.enc2.zero_count = -98_765;
        c.enc2.direction = Direction::Negative;
    });
    push("axes_skew", &|c| c.axes_skew_rad = e);
    push("tilt_1", &|c| c.frame1.tilt_rad = e);
    push("tilt_2", &|c| c.frame2.tilt_rad = -e);
    push("offset_normal_1", &|c| c.frame1.offset_normal_rad = e);
    push("offset_axial_1", &|c| c.frame1.offset_axial_rad = -e);
    push("offset_normal_2", &|c| c.frame2.offset_normal_rad = e);
    push("offset_axial_2", &|c| c.frame2.offset_axial_rad = e);
    cases.push(("every error", every_error(base)));
    let mut failures = vec![];
    for (name, cal) in &cases {
        let m = Mechanism::new(cal);
        let mut worst_mm: f64 = 0.0;
        for pose in swing(&distances_mm(79.0, 99.5, 5), 36, 0.05) {
            let counts = match m.counts_for_pose(pose.d_mm, pose.azimuth_rad) {
                Ok(c) => c,
                Err(PoseError::OutOfRange) => continue,
                Err(e) => panic!("{e:?}"),
            };
            let mine = m.distance_mm(counts).unwrap();
            let core = jdbb_core::geometry::distance_mm(cal, counts[0], counts[1]);
            worst_mm = worst_mm.max((mine - core).abs());
        }
        println!(
            "{name}: worst |mechanism − core| = {:.3e} um",
            worst_mm * 1e3
        );
        if worst_mm >= 1e-10 {
            failures.push(format!("{name}: {:.3e} um", worst_mm * 1e3));
        }
    }
    assert!(failures.is_empty(), "disagree: {failures:?}");
}

#[test]
fn calibrator_poses_stay_within_the_frames_range() {
    let m = Mechanism::new(&every_error(Calibration::DEFAULT));
    let poses = swing(&distances_mm(79.0, 99.0, 5), 72, 0.0);
    let samples = calibrator_samples(&m, &poses, 0.02, 7);
    // At 79 mm some azimuths need a frame beyond 75° and are dropped; at 99 mm none are.
    assert!(samples.len() < poses.len() && samples.len() > poses.len() * 3 / 4);
    assert_eq!(
        samples.iter().filter(|s| s.d_true_mm == 99.0).count(),
        72,
        "every azimuth is reachable at 99 mm"
    );
    for s in &samples {
        let theta = m.frame_angles_rad([s.enc1, s.enc2]);
        assert!(theta.iter().all(|t| t.abs() <= FRAME_RANGE_RAD + 1e-6));
        let noise_um = (s.d_ref_mm - s.d_true_mm) * 1e3;
        assert!(noise_um.abs() < 0.02 * 6.0, "{noise_um}");
    }
    let rms_noise_um = 1e3
        * (samples
            .iter()
            .map(|s| (s.d_ref_mm - s.d_true_mm).powi(2))
            .sum::<f64>()
            / samples.len() as f64)
            .sqrt();
    assert!((rms_noise_um / 0.02 - 1.0).abs() < 0.15, "{rms_noise_um}");
}

#[test]
fn circular_test_record_of_a_perfect_machine() {
    use jdbb_tests::calibration_data::{circular_record, CircularTest};
    let cal = every_error(Calibration::DEFAULT);
    let m = Mechanism::new(&cal);
    let test = CircularTest {
        radius_mm: 90.0,
        height_mm: 0.0,
        speed_mm_s: 20.0,
        rate_hz: 50.0,
        start_spin_rad: 0.4,
    };
    let rec = circular_record(&m, &Calibration::DEFAULT, &test).unwrap();
    let n = rec.rows.len();
    assert_eq!(n % 2, 1);
    // The instrument as built reads the perfect machine's D = R to within quantisation.
    for r in &rec.rows {
        let d = m.distance_mm([r.enc1, r.enc2]).unwrap();
        assert!((d - 90.0).abs() < 0.03e-3, "{r:?}: {d}");
    }
    // Bar 1 carried without spin round a cone: the knee's azimuth in bar 1's frame turns by the
    // cone's solid angle, 2π(1 + sin δ) ≡ 2π·sin δ per circle, δ = bar 1's dip below level
    // (sin δ = ρ/L1, ρ the height of the knee below the ball-to-ball line), and back on the
    // clockwise circle.
    let (l1, l2, d) = (cal.l1_mm, cal.l2_mm, 90.0f64);
    let along = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d);
    let sin_dip = (l1 * l1 - along * along).sqrt() / l1;
    let turn = |a: &[f64]| {
        a.windows(2)
            .map(|w| {
                (w[1] - w[0] + 3.0 * std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI
            })
            .sum::<f64>()
    };
    let half = n / 2;
    let ccw = turn(&rec.azimuth_rad[..=half]);
    let cw = turn(&rec.azimuth_rad[half..]);
    println!(
        "knee azimuth: {:.2} deg on the ccw circle, {:.2} deg on the cw",
        ccw / DEG,
        cw / DEG
    );
    assert!(
        (ccw.abs() - std::f64::consts::TAU * sin_dip).abs() < 1e-3,
        "{ccw} vs {sin_dip}"
    );
    assert!((ccw + cw).abs() < 1e-9);
    // With its hidden errors the nominal instrument reads microns off, varying along the path.
    let nominal_err_um: Vec<f64> = rec.rows.iter().map(|r| (r.d_mm - 90.0) * 1e3).collect();
    let spread = nominal_err_um.iter().cloned().fold(f64::MIN, f64::max)
        - nominal_err_um.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread > 1.0, "{spread}");
    assert_eq!(rec.path.len(), n);
    assert!(rec.path.windows(2).all(|w| w[1][0] > w[0][0]));
}
