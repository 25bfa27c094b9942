use super::*;
use jdbb_core::machine::{AxisErrors, MachineErrors};

/// A ccw circle of radius r in xy at 0.5 rad/s, 100 Hz, pitch 5 mm on x and y.
fn circle(r: f64, n: usize) -> Path {
    let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
    let p = t
        .iter()
        .map(|&t| {
            let th = t * 0.5;
            [r * th.cos(), r * th.sin(), 0.0]
        })
        .collect();
    Path::new(t, p, [Some(5.0), Some(5.0), None])
}

/// Every effect, including the derived scale mismatches.
fn every_effect() -> Vec<Effect> {
    let mut v = Effect::all();
    v.extend(Pair::ALL.map(Effect::ScaleMismatch));
    v.extend(Axis::ALL.map(Effect::BacklashEnds));
    v
}

/// Some parameters for `e` (a spike's τ positive).
fn some_params(e: Effect) -> Vec<f64> {
    match e {
        Effect::ReversalSpike(_) => vec![2.5, 12.0],
        Effect::ServoMismatch(_) => vec![1.5, 3.0],
        _ => (0..e.n_params()).map(|k| 3.0 - 2.5 * k as f64).collect(),
    }
}

#[test]
fn names_round_trip() {
    for e in every_effect() {
        assert_eq!(e.param_names().len(), e.n_params());
        if let Effect::BacklashEnds(a) = e {
            // One name for a backlash, whether its ends differ or not.
            assert_eq!(Effect::parse(&e.name()), Some(Effect::Backlash(a)));
            continue;
        }
        assert_eq!(Effect::parse(&e.name()), Some(e));
    }
    assert_eq!(Effect::parse("scale_w"), None);
    assert_eq!(Effect::parse("backlash"), None);
    assert_eq!(Effect::parse("straightness_x_x"), None);
    assert_eq!(
        Effect::parse("straightness_x_y"),
        Some(Effect::Straightness(Axis::X, Axis::Y))
    );
    assert_eq!(
        Effect::all().len(),
        2 + 5 * 3 + 2 * 3 + 3 + 6 + 6 + 1 + 2 * 3 + 1
    );
}

#[test]
fn deltas_match_the_core_machine_models() {
    // Each effect's δ must reproduce jdbb_core::machine's δ (µm) at a few samples, which
    // checks units and sign conventions against the shared models.
    let path = circle(40.0, 700);
    let ax = AxisErrors {
        scale_um_per_m: 30.0,
        scale2_um_per_m2: 700.0,
        cyclic_um: 2.0,
        cyclic_phase_rad: 0.7,
        interference_um_per_mm_s: 0.3,
        interference_phase_rad: -0.4,
        pitch_mm: 5.0,
        backlash_um: 6.0,
    };
    let m = MachineErrors {
        axes: [ax, AxisErrors::default(), AxisErrors::default()],
        squareness_um_per_m: [12.0, 0.0, 0.0],
    };
    let set = EffectSet::new(vec![
        Effect::Scale(Axis::X),
        Effect::Scale2(Axis::X),
        Effect::Cyclic(Axis::X),
        Effect::Interference(Axis::X),
        Effect::Backlash(Axis::X),
        Effect::Squareness(Pair::Xy),
    ]);
    let mut theta = vec![30.0, 700.0];
    theta.extend(Effect::Cyclic(Axis::X).params_from_value(2.0, 0.7).unwrap());
    theta.extend(
        Effect::Interference(Axis::X)
            .params_from_value(0.3, -0.4)
            .unwrap(),
    );
    theta.extend([6.0, 12.0]);
    for i in [3usize, 250, 400, 650] {
        let expect = m.error_um(path.p_mm[i], path.v_mm_s[i], path.dir[i]);
        let (q, dd) = set.displaced(&path, i, &theta);
        assert_eq!(dd, 0.0);
        for k in 0..3 {
            let got = 1e3 * (q[k] - path.p_mm[i][k]);
            assert!(
                (got - expect[k]).abs() < 1e-9,
                "sample {i} axis {k}: {got} vs {expect:?}"
            );
        }
    }
}

#[test]
fn gradients_are_the_derivatives_of_the_exact_model() {
    // Finite differences of D (µm) against gradient_block, for every effect, at parameters
    // away from zero, on a circle with reversals and a pitch.
    let path = circle(40.0, 1300);
    assert!(!path.reversals[0].is_empty() && !path.reversals[1].is_empty());
    for e in every_effect() {
        let set = EffectSet::new(vec![e]);
        let theta = some_params(e);
        let n = e.n_params();
        let (i0, len) = (1000, 120);
        let mut q = vec![[0.0; 3]; len];
        let mut dd = vec![0.0; len];
        set.displaced_block(&path, i0, &theta, &mut q, &mut dd);
        let u: Vec<[f64; 3]> = q
            .iter()
            .map(|q| {
                let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
                [q[0] / r, q[1] / r, q[2] / r]
            })
            .collect();
        let mut grad = vec![f64::NAN; len * n];
        e.gradient_block(&path, i0, &theta, &u, &mut grad, n, 0);
        for k in 0..n {
            let h = 1e-4 * theta[k].abs().max(1.0);
            let mut up = theta.clone();
            let mut down = theta.clone();
            up[k] += h;
            down[k] -= h;
            for j in (0..len).step_by(7) {
                let d = |th: &[f64]| 1e3 * set.distance_mm(&path, i0 + j, th);
                let fd = (d(&up) - d(&down)) / (2.0 * h);
                let g = grad[j * n + k];
                assert!(
                    (fd - g).abs() < 1e-5 * (1.0 + g.abs()),
                    "{e} param {k} sample {}: fd {fd} vs {g}",
                    i0 + j
                );
            }
        }
        if e.is_linear() {
            // The search columns are the gradient, whatever θ.
            let mut cols = vec![f64::NAN; len * n];
            Candidate::of(e).columns_block(&path, i0, &u, &mut cols, n, 0);
            assert_eq!(cols, grad, "{e}");
        }
    }
}

#[test]
fn a_block_of_any_length_is_the_same_as_one_sample_at_a_time() {
    // Blocks start anywhere (the spike finds its reversal by search): the exact fit's blocks
    // must give the per-sample model exactly, so that speed never changes a result.
    let path = circle(40.0, 1300);
    let set = EffectSet::new(every_effect());
    let theta: Vec<f64> = set.effects.iter().flat_map(|&e| some_params(e)).collect();
    let (i0, len) = (297, 700);
    let mut q = vec![[f64::NAN; 3]; len];
    let mut dd = vec![f64::NAN; len];
    set.displaced_block(&path, i0, &theta, &mut q, &mut dd);
    let all = set.distances_mm(&path, &theta);
    assert_eq!(all.len(), path.len());
    for j in 0..len {
        let (want, want_d) = set.displaced(&path, i0 + j, &theta);
        assert_eq!(q[j], want, "sample {}", i0 + j);
        assert_eq!(dd[j].to_bits(), want_d.to_bits());
    }
    for (i, d) in all.iter().enumerate() {
        assert_eq!(d.to_bits(), set.distance_mm(&path, i, &theta).to_bits());
    }
}

#[test]
fn direction_holds_and_reversals_are_found_where_the_velocity_crosses_zero() {
    let path = circle(40.0, 1300); // θ = 0.5 t: x reverses at θ = π (t = 2π s)
    let r = path.reversals[0][0];
    assert!((r.t_s - std::f64::consts::TAU).abs() < 1e-4, "{r:?}");
    assert_eq!(r.new_dir, 1); // past θ = π, x increases again
    let ry = path.reversals[1][0];
    assert!((ry.t_s - std::f64::consts::PI).abs() < 1e-4, "{ry:?}");
    assert_eq!(ry.new_dir, -1);
    assert_eq!(path.last_reversal(0, 1.0), None);
    assert_eq!(path.last_reversal(0, 7.0), Some(r));
}

#[test]
fn servo_mismatch_is_a_true_delay_to_second_order() {
    // On a circle at ω, axis k delayed by τ_k is at R·cos(ω(t − τ_x)), R·sin(ω(t − τ_y)).
    let (r, omega) = (50.0, 0.5);
    let path = circle(r, 1300);
    let e = Effect::ServoMismatch(Pair::Xy);
    let (dtau, lag) = (4.0, 6.0); // τ_x = 8 ms, τ_y = 4 ms
    let set = EffectSet::new(vec![e]);
    for i in [300usize, 640, 1100] {
        let t = path.t_s[i];
        let (tx, ty) = (1e-3 * (lag + dtau / 2.0), 1e-3 * (lag - dtau / 2.0));
        let exact = [r * (omega * (t - tx)).cos(), r * (omega * (t - ty)).sin()];
        let (q, _) = set.displaced(&path, i, &[dtau, lag]);
        for k in 0..2 {
            // Third order R·ω³·τ³/6 ≈ 1.3e-6 mm; finite-difference v, a add ~1e-6 mm.
            assert!(
                (q[k] - exact[k]).abs() < 5e-6,
                "sample {i} axis {k}: {} vs {}",
                q[k],
                exact[k]
            );
        }
    }
    // To first order the mismatch is seen with opposite sign in the two directions:
    // δ·u = −(Δτ/2)(u_x v_x − u_y v_y) = (Δτ/2)·R·ω·sin 2θ (ms → s) on this ccw circle.
    let mut c = [0.0; 2];
    let i = 40;
    let p = path.p_mm[i];
    let u = [p[0] / r, p[1] / r, 0.0];
    Candidate::of(e).columns_block(&path, i, &[u], &mut c, 2, 0);
    let th = p[1].atan2(p[0]);
    let expect = 0.5e-3 * r * omega * (2.0 * th).sin() * 1e3;
    assert!((c[0] - expect).abs() < 1e-4, "{} {expect}", c[0]);
}

#[test]
fn following_error_draws_a_circle_smaller_by_q_v2_over_r() {
    // δ = q·a with a = −ω²·p on a circle: D = R·(1 − q·ω²), the radius loss q·v²/R.
    let (r, omega, q_ms2) = (40.0, 0.5, 500.0);
    let path = circle(r, 1300);
    let set = EffectSet::new(vec![Effect::FollowingError]);
    let loss_um = 1e-3 * q_ms2 * (omega * r) * (omega * r) / r;
    for i in [5usize, 640, 1294] {
        let d_um = 1e3 * set.distance_mm(&path, i, &[q_ms2]);
        assert!(
            (1e3 * r - d_um - loss_um).abs() < 1e-3 * loss_um,
            "sample {i}: {d_um} µm for R {r} mm less {loss_um} µm"
        );
    }
    // The same through the reporting helpers: Kv 30 s⁻¹ without feed-forward is
    // q = 1/(2·Kv²) = 555.6 ms², 15.43 µm off R 90 mm at 3000 mm/min.
    let q = 1e6 / (2.0 * 30.0 * 30.0);
    assert!((following_error_kv_per_s(q).unwrap() - 30.0).abs() < 1e-9);
    assert!((radius_loss_um(q, 3000.0, 90.0) - 15.432).abs() < 1e-3);
    assert_eq!(following_error_kv_per_s(-1.0), None);
}

#[test]
fn acceleration_is_not_differenced_across_the_gap_between_two_circles() {
    // Two circles (R 40 and 30 mm at 0.5 rad/s) 5 s apart: every sample's acceleration is its
    // own circle's −ω²·p near the gap, not a difference across the jump between them.
    let (omega, n) = (0.5, 400);
    let mut t = vec![];
    let mut p = vec![];
    for (k, r) in [40.0, 30.0].into_iter().enumerate() {
        for i in 0..n {
            let ti = i as f64 * 0.01 + k as f64 * (n as f64 * 0.01 + 5.0);
            let th = omega * ti;
            t.push(ti);
            p.push([r * th.cos(), r * th.sin(), 0.0]);
        }
    }
    let path = Path::new(t, p.clone(), [None; 3]);
    // Next to the gap the differences are one-sided within each circle: the second sample
    // from each circle's end reads about three quarters of ω²·R (the velocity at the end is
    // a half step back), where differences across the gap read nothing of the circle.
    for i in [n - 3, n - 2, n + 1, n + 2] {
        let a = path.a_mm_s2[i];
        let r = (p[i][0] * p[i][0] + p[i][1] * p[i][1]).sqrt();
        let radial = -(a[0] * p[i][0] + a[1] * p[i][1]) / r;
        assert!(
            (radial - omega * omega * r).abs() < 0.3 * omega * omega * r,
            "sample {i}: radial acceleration {radial} for {}",
            omega * omega * r
        );
    }
}

#[test]
fn spike_and_drift_follow_their_definitions() {
    let path = circle(40.0, 1300);
    let rev = path.reversals[0][0];
    let i = path.t_s.partition_point(|&t| t < rev.t_s + 0.012);
    let dt_ms = 1e3 * (path.t_s[i] - rev.t_s);
    let set = EffectSet::new(vec![Effect::ReversalSpike(Axis::X)]);
    let (q, _) = set.displaced(&path, i, &[3.0, 12.0]);
    let want = -3e-3 * f64::from(rev.new_dir) * (-dt_ms / 12.0).exp();
    assert!((q[0] - path.p_mm[i][0] - want).abs() < 1e-12);
    // No spike before the first reversal.
    let (q, _) = set.displaced(&path, 10, &[3.0, 12.0]);
    assert_eq!(q[0], path.p_mm[10][0]);
    let drift = EffectSet::new(vec![Effect::Drift]);
    let (_, dd) = drift.displaced(&path, 600, &[2.0]);
    assert!((dd - 2e-3 * path.t_s[600] / 60.0).abs() < 1e-15);
}
