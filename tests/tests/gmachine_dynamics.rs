//! The G-code machine moves like a machine (`jdbb_tests::gmachine::dynamics`): known answers for
//! its position loops (the closed loop's transfer function, the circle's shrink v²/(2R·Kv²)),
//! stick-slip at reversals, a structural mode ringing at its frequency, thermal growth, and the
//! coloured noise's correlation. These check the simulator against the physics it is written from;
//! what the diagnosis makes of such machines is measured elsewhere.
use std::f64::consts::PI;

use jdbb_tests::gmachine::{
    Axis, ColouredNoise, Dialect, Friction, MachineErrors, Recording, SegmentKind, ServoLoop,
    SimConfig, Simulation, SpindleGrowth, StructuralMode, ThermalGrowth, TruthSample,
};

const BALL: [f64; 3] = [150.0, 100.0, -50.0];
const R: f64 = 90.0;
/// R 90 mm in XY about BALL at F1000: lead-in 90°, 360° ccw, overshoot, the same cw.
const LINUXCNC: &str = include_str!("../data/gmachine/ballbar.ngc");

fn run(text: &str, cfg: SimConfig) -> (Simulation, Recording) {
    let sim = Simulation::new(text, cfg).unwrap_or_else(|e| panic!("{e}"));
    let rec = sim.run().unwrap_or_else(|e| panic!("{e}"));
    (sim, rec)
}

/// Samples on the two 360° data arcs, with +1 (ccw) or −1 (cw).
fn data_samples(rec: &Recording) -> Vec<(&TruthSample, f64)> {
    let a: Vec<usize> = (0..rec.truth.blocks.len())
        .filter(|&i| matches!(rec.truth.blocks[i].kind, SegmentKind::Arc { .. }))
        .collect();
    assert_eq!(a.len(), 8);
    rec.truth
        .samples
        .iter()
        .filter_map(|s| match s.block? {
            b if b == a[1] || b == a[2] => Some((s, 1.0)),
            b if b == a[5] || b == a[6] => Some((s, -1.0)),
            _ => None,
        })
        .collect()
}

fn config(errors: MachineErrors) -> SimConfig {
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, BALL);
    cfg.errors = errors;
    cfg
}

fn loops(l: ServoLoop) -> MachineErrors {
    let mut e = MachineErrors::default();
    e.dynamics.servo = [Some(l), Some(l), Some(l)];
    e
}

/// The loop's H(jω) for a fast velocity loop is the textbook first-order lag: amplitude
/// 1 − (ω/Kv)²/2, phase −ω/Kv; full feed-forward follows exactly.
#[test]
fn the_closed_loop_is_a_first_order_lag_without_feed_forward() {
    let mut l = ServoLoop::new(30.0);
    l.velocity_bandwidth_hz = 1000.0;
    let w = 1000.0 / 60.0 / R;
    let (re, im) = l.response(w);
    let amp = (re * re + im * im).sqrt();
    let want = 1.0 - (w / 30.0f64).powi(2) / 2.0;
    assert!(
        ((1.0 - amp) / (1.0 - want) - 1.0).abs() < 0.01,
        "{amp} vs {want}"
    );
    let phase = im.atan2(re);
    assert!((phase / (-w / 30.0) - 1.0).abs() < 0.01, "{phase}");
    l.ff_velocity = 1.0;
    l.ff_acceleration = 1.0;
    for w in [0.1, 1.0, 10.0, 100.0] {
        let (re, im) = l.response(w);
        assert!(
            (re - 1.0).abs() < 1e-12 && im.abs() < 1e-12,
            "{w}: {re} {im}"
        );
    }
}

/// A circle drawn through identical loops is scaled by |H(jω)| and turned back by arg H(jω):
/// at F1000 on R 90 with Kv 30 and no feed-forward it shrinks by about v²/(2R·Kv²) = 1.71 µm.
#[test]
fn a_circle_through_position_loops_shrinks_and_lags_as_the_loop_says() {
    for (kv, ffv) in [(30.0, 0.0), (45.0, 0.0), (30.0, 0.5)] {
        let mut l = ServoLoop::new(kv);
        l.ff_velocity = ffv;
        l.count_um = 0.0;
        let (_, rec) = run(LINUXCNC, config(loops(l)));
        let w = 1000.0 / 60.0 / R;
        let (re, im) = l.response(w);
        let want_dr_um = R * ((re * re + im * im).sqrt() - 1.0) * 1e3;
        let want_phase = im.atan2(re);
        if ffv == 0.0 && kv == 30.0 {
            let textbook = -(1000.0f64 / 60.0).powi(2) / (2.0 * R * kv * kv) * 1e3;
            assert!(
                (want_dr_um / textbook - 1.0).abs() < 0.05,
                "{want_dr_um} vs {textbook}"
            );
        }
        let (mut n, mut dr, mut dphi) = (0, 0.0, 0.0);
        for (s, sense) in data_samples(&rec) {
            let c = [s.command_mm[0] - BALL[0], s.command_mm[1] - BALL[1]];
            let a = [s.actual_mm[0] - BALL[0], s.actual_mm[1] - BALL[1]];
            dr += (a[0].hypot(a[1]) - R) * 1e3;
            // Angle from command to actual, in the sense of motion.
            dphi += sense * (c[0] * a[1] - c[1] * a[0]).atan2(c[0] * a[0] + c[1] * a[1]);
            n += 1;
        }
        let (dr, dphi) = (dr / n as f64, dphi / n as f64);
        assert!(
            (dr - want_dr_um).abs() < 0.02 * want_dr_um.abs(),
            "Kv {kv}, ff {ffv}: ΔR {dr:.4} µm, H says {want_dr_um:.4}"
        );
        assert!(
            (dphi - want_phase).abs() < 0.01 * want_phase.abs(),
            "Kv {kv}, ff {ffv}: lag {dphi:.3e} rad, H says {want_phase:.3e}"
        );
    }
}

#[test]
fn full_feed_forward_follows_the_circle_within_10_nm() {
    let mut l = ServoLoop::new(40.0);
    l.ff_velocity = 1.0;
    l.ff_acceleration = 1.0;
    l.count_um = 0.0;
    let (_, rec) = run(LINUXCNC, config(loops(l)));
    let worst = data_samples(&rec)
        .iter()
        .map(|(s, _)| {
            (0..3)
                .map(|k| (s.actual_mm[k] - s.command_mm[k]).abs())
                .fold(0.0, f64::max)
        })
        .fold(0.0, f64::max);
    assert!(
        worst * 1e3 < 0.01,
        "worst following error {:.4} µm",
        worst * 1e3
    );
}

/// A reversal of X on a data arc: when (program s), the commanded X there (mm), and X's
/// following error around it (time since the reversal s, error µm).
type Reversal = (f64, f64, Vec<(f64, f64)>);

/// The X reversals on the data arcs, each with its following error.
fn around_x_reversals(sim: &Simulation, rec: &Recording) -> Vec<Reversal> {
    let data = data_samples(rec);
    // Reversals while a data arc runs (not at the stop between the directions).
    let on_data = |t: f64| {
        let i = data.partition_point(|(s, _)| s.t_program_s < t);
        i > 0 && i < data.len() && data[i].0.t_program_s - data[i - 1].0.t_program_s < 0.01
    };
    sim.trajectory().events[0]
        .iter()
        .filter(|e| on_data(e.t_s) && on_data(e.t_s + 1.0))
        .map(|e| {
            let x = sim.trajectory().position_at(e.t_s)[0];
            let w: Vec<(f64, f64)> = rec
                .truth
                .samples
                .iter()
                .filter(|s| s.t_program_s >= e.t_s - 0.1 && s.t_program_s <= e.t_s + 1.0)
                .map(|s| {
                    (
                        s.t_program_s - e.t_s,
                        (s.actual_mm[0] - s.command_mm[0]) * 1e3,
                    )
                })
                .collect();
            (e.t_s, x, w)
        })
        .collect()
}

/// Friction inside the loop sticks the axis at its reversal: the following error grows for tens
/// of ms while the velocity loop winds up, then the axis breaks free and catches up. Twice the
/// friction at the + end gives a larger glitch there.
#[test]
fn friction_in_the_loop_sticks_at_reversals_and_releases_larger_where_it_is_larger() {
    let mut l = ServoLoop::new(30.0);
    l.ff_velocity = 0.9;
    l.count_um = 0.0;
    let plain = loops(l);
    let mut sticky = plain.clone();
    let mut f = Friction::new(300.0, 450.0);
    f.neg_end_mm = BALL[0] - R;
    f.pos_end_mm = BALL[0] + R;
    f.pos_end_factor = 2.0;
    sticky.dynamics.friction[0] = Some(f);
    let (sim0, rec0) = run(LINUXCNC, config(plain));
    let (sim1, rec1) = run(LINUXCNC, config(sticky));
    let r0 = around_x_reversals(&sim0, &rec0);
    let r1 = around_x_reversals(&sim1, &rec1);
    assert_eq!(r0.len(), 4, "two X reversals per direction");
    let mut peaks = vec![];
    for ((_, x, w0), (_, _, w1)) in r0.iter().zip(&r1) {
        // The glitch: the error with friction minus the loop's own error.
        let g: Vec<(f64, f64)> = w0.iter().zip(w1).map(|(a, b)| (a.0, b.1 - a.1)).collect();
        let (t_peak, peak) =
            g.iter().fold(
                (0.0, 0.0f64),
                |m, &(t, v)| if v.abs() > m.1.abs() { (t, v) } else { m },
            );
        let late = g
            .iter()
            .filter(|(t, _)| *t > 0.6)
            .map(|(_, v)| v.abs())
            .fold(0.0, f64::max);
        println!(
            "X {x:.0}: peak {peak:.3} µm at {:.1} ms, {late:.3} µm after 0.6 s",
            t_peak * 1e3
        );
        assert!(peak.abs() > 1.0, "at X {x:.0}: glitch {peak:.3} µm");
        assert!(
            t_peak > 0.01 && t_peak < 0.3,
            "at X {x:.0}: the glitch peaks {t_peak:.3} s after the reversal"
        );
        assert!(
            late < 0.1 * peak.abs(),
            "at X {x:.0}: {late:.3} µm left after 0.6 s"
        );
        peaks.push((*x, peak.abs()));
    }
    let at = |end: f64| {
        peaks
            .iter()
            .filter(|(x, _)| (x - end).abs() < 1.0)
            .map(|p| p.1)
            .fold(0.0, f64::max)
    };
    let (pos, neg) = (at(BALL[0] + R), at(BALL[0] - R));
    assert!(pos > 1.3 * neg, "+ end {pos:.3} µm, − end {neg:.3} µm");
}

/// A lightly damped mode driven by the X drive rings at its damped frequency after the friction
/// reverses at X's reversal.
#[test]
fn a_structural_mode_rings_at_its_frequency_after_a_reversal() {
    let mut l = ServoLoop::new(30.0);
    l.count_um = 0.0;
    let mut base = loops(l);
    base.dynamics.friction[0] = Some(Friction::new(20.0, 20.0));
    let mut ringing = base.clone();
    let (f_hz, zeta) = (25.0, 0.03);
    ringing.dynamics.modes.push(StructuralMode {
        axis: Axis::X,
        driven_by: Axis::X,
        frequency_hz: f_hz,
        damping: zeta,
        compliance_um_per_m_s2: 20.0,
    });
    let mut cfg0 = config(base);
    let mut cfg1 = config(ringing);
    cfg0.instrument.sample_rate_hz = 5000.0;
    cfg1.instrument.sample_rate_hz = 5000.0;
    let (sim0, rec0) = run(LINUXCNC, cfg0);
    let (_, rec1) = run(LINUXCNC, cfg1);
    let (_, _, w0) = &around_x_reversals(&sim0, &rec0)[0];
    let (_, _, w1) = &around_x_reversals(&sim0, &rec1)[0];
    // The structure's displacement alone (the mode does not act back on the loop).
    let y: Vec<(f64, f64)> = w0
        .iter()
        .zip(w1)
        .map(|(a, b)| (a.0, b.1 - a.1))
        .filter(|(t, _)| *t > 0.0 && *t < 0.6)
        .collect();
    let amp = y.iter().map(|p| p.1.abs()).fold(0.0, f64::max);
    assert!(amp > 0.2, "ring amplitude {amp:.3} µm");
    // Upward zero crossings of the ring about its running mean (its quasi-static part moves
    // slowly) give the period.
    let mean = |i: usize| {
        let lo = i.saturating_sub(100);
        let hi = (i + 100).min(y.len());
        y[lo..hi].iter().map(|p| p.1).sum::<f64>() / (hi - lo) as f64
    };
    let z: Vec<f64> = (1..y.len())
        .filter(|&i| y[i - 1].1 - mean(i - 1) < 0.0 && y[i].1 - mean(i) >= 0.0)
        .map(|i| y[i].0)
        .collect();
    assert!(z.len() >= 5, "{} crossings", z.len());
    let period = (z[z.len() - 1] - z[0]) / (z.len() - 1) as f64;
    let want = f_hz * (1.0 - zeta * zeta).sqrt();
    assert!(
        (1.0 / period / want - 1.0).abs() < 0.03,
        "rings at {:.2} Hz, mode {want:.2}",
        1.0 / period
    );
}

/// X grows about its fixed bearing at X 0 by 1.5 µm/m per minute and the spindle by 2 µm/min:
/// after two minutes the carriage at X 240 is 0.72 µm out and the ball 4 µm lower.
#[test]
fn heat_grows_an_axis_about_its_bearing_and_the_spindle_towards_the_table() {
    let text = "G21 G90 G94 G17\nG0 X240 Y100 Z-50\nM0\nG4 P120\nM2\n";
    let mut e = MachineErrors::default();
    e.thermal.push(ThermalGrowth {
        axis: Axis::X,
        um_per_m_per_min: 1.5,
        fixed_bearing_mm: 0.0,
        time_constant_min: 0.0,
    });
    e.spindle_growth = SpindleGrowth {
        um_per_min: 2.0,
        time_constant_min: 0.0,
    };
    let mut cfg = config(e);
    cfg.table_ball_mm = [150.0, 100.0, -50.0];
    let (sim, rec) = run(text, cfg);
    let cs = sim.trajectory().cycle_start_s;
    for s in rec.truth.samples.iter().step_by(997) {
        let t_min = ((s.t_program_s - cs) / 60.0).max(0.0);
        let dx = (s.actual_mm[0] - s.command_mm[0]) * 1e3;
        let dz = (s.actual_mm[2] - s.command_mm[2]) * 1e3;
        assert!(
            (dx - 1.5 * t_min * 0.240).abs() < 1e-9,
            "{t_min} min: δx {dx}"
        );
        assert!((dz + 2.0 * t_min).abs() < 1e-9, "{t_min} min: δz {dz}");
    }
}

/// A program that stands still for `secs` at R 90 from the ball: D is the noise.
fn standing(secs: f64) -> String {
    format!("G21 G90 G94 G17\nG0 X240 Y100 Z-50\nM0\nG4 P{secs}\nM2\n")
}

#[test]
fn ar1_noise_has_its_correlation_and_size_and_leaves_the_white_noise_and_lean_alone() {
    let text = standing(60.0);
    let mut cfg = config(MachineErrors::default());
    cfg.instrument.noise_um = 0.1;
    let (_, white) = run(&text, cfg.clone());
    cfg.instrument.coloured_noise = ColouredNoise {
        ar1_um: 0.5,
        ar1_tau_ms: 5.0,
        ..ColouredNoise::default()
    };
    let (_, coloured) = run(&text, cfg);
    let n: Vec<f64> = white
        .truth
        .samples
        .iter()
        .zip(&coloured.truth.samples)
        .map(|(w, c)| {
            assert_eq!(w.azimuth_rad, c.azimuth_rad);
            (c.d_mm_instrument - w.d_mm_instrument) * 1e3
        })
        .collect();
    let var = n.iter().map(|v| v * v).sum::<f64>() / n.len() as f64;
    let rho = n.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (n.len() - 1) as f64 / var;
    let want = (-1.0f64 / 5.0).exp();
    assert!(
        (var.sqrt() / 0.5 - 1.0).abs() < 0.05,
        "σ {:.4} µm",
        var.sqrt()
    );
    assert!(
        (rho - want).abs() < 0.02,
        "lag-1 correlation {rho:.4}, want {want:.4}"
    );
}

#[test]
fn vibration_noise_is_narrow_band_at_its_frequency() {
    let text = standing(20.0);
    let mut cfg = config(MachineErrors::default());
    cfg.instrument.coloured_noise = ColouredNoise {
        vibration_um: 0.3,
        vibration_hz: 30.0,
        vibration_bandwidth_hz: 1.0,
        ..ColouredNoise::default()
    };
    let (_, rec) = run(&text, cfg);
    let n: Vec<f64> = rec
        .truth
        .samples
        .iter()
        .map(|s| (s.d_mm_instrument - s.d_mm_true) * 1e3)
        .collect();
    let dt = 1e-3;
    let power = |f: f64| {
        let (mut c, mut s) = (0.0, 0.0);
        for (i, v) in n.iter().enumerate() {
            let (sn, cs) = (2.0 * PI * f * i as f64 * dt).sin_cos();
            c += v * cs;
            s += v * sn;
        }
        (c * c + s * s) / n.len() as f64
    };
    let (p30, p20, p45) = (power(30.0), power(20.0), power(45.0));
    assert!(
        p30 > 50.0 * p20 && p30 > 50.0 * p45,
        "{p30:.3} vs {p20:.3}, {p45:.3}"
    );
    let rms = (n.iter().map(|v| v * v).sum::<f64>() / n.len() as f64).sqrt();
    assert!((rms / 0.3 - 1.0).abs() < 0.25, "rms {rms:.3} µm");
}
