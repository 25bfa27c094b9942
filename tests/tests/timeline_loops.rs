//! The timeline under real position loops (issue 26): how far the synchronisation's timeline is
//! off the machine's real motion when every axis follows its command through a loop (no
//! feed-forward at Kv 30 and 60 s⁻¹, 90 % and full velocity feed-forward) at 500–3000 mm/min.
//!
//! What is measured, against the independent G-code machine's truth: the feed error (the
//! synchronised speed over the true one on the record's clock, ppm) and the start error (how far,
//! in time along the path, the nominal position the timeline gives each data sample lies from
//! where the axes really were, ms: the mean over the data arcs, the largest at any sample, and
//! the spread between the circle's first and last tenth). The loop's pure delay τ = (1 − k_v)/Kv
//! belongs to the timeline (a common delay is a time shift of the whole motion; the servo
//! mismatch is the difference between axes), so the truth is the actual position, not the command.
//!
//! The table in docs/synchronisation.md comes from
//! `cargo test --profile sweep -p jdbb-tests --test timeline_loops -- --ignored --nocapture`.
mod planned;

use planned::read_back;

use jdbb::plan::{plan, write_program, Dialect as PlanDialect, Plan, PlanSpec, Plane};
use jdbb::sync::{data_path, synchronise};
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{Dialect, MachineErrors, ServoLoop, SimConfig, Simulation};

const CENTRE: [f64; 3] = [100.0, 50.0, -20.0];
const CLOCK_PPM: f64 = 23.0;

/// The feed error a synchronisation under a loop must stay within (ppm): the ramp's ruler bound
/// (2·10⁻⁴ on a 2 mm feed-in, docs/synchronisation.md) with room for the arcs' search where the
/// feed-in does not cruise.
const FEED_BOUND_PPM: f64 = 500.0;

/// The mean offset of the timeline from the machine's motion it must stay within (ms): a tenth of
/// the lag of a loop of Kv 30 s⁻¹ without feed-forward (33 ms), which the old timeline was bent by.
const START_BOUND_MS: f64 = 3.0;

/// The loop kinds the timeline's accuracy is stated for.
fn loops() -> Vec<(&'static str, ServoLoop)> {
    let ff = |k: f64| ServoLoop {
        ff_velocity: k,
        ..ServoLoop::new(30.0)
    };
    vec![
        ("no FF, Kv 30", ServoLoop::new(30.0)),
        ("no FF, Kv 60", ServoLoop::new(60.0)),
        ("FF 0.9, Kv 30", ff(0.9)),
        ("FF 1.0, Kv 30", ff(1.0)),
    ]
}

fn make_plan(plane: Plane, radii: &[f64], feed_mm_min: f64) -> Plan {
    let spec = PlanSpec::machine_test(
        radii,
        &[0.0],
        plane,
        feed_mm_min,
        CENTRE,
        PlanDialect::Linuxcnc,
    );
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

/// How far the synchronised timeline lies from the machine's real motion.
#[derive(Debug, Clone, Copy)]
struct Accuracy {
    /// Synchronised feed over the true one on the record's clock, − 1 (ppm).
    feed_ppm: f64,
    /// Mean time offset along the path of the nominal positions from the actual ones (ms;
    /// positive: the timeline is late).
    start_ms: f64,
    /// The largest offset at any data sample (ms).
    max_ms: f64,
}

/// Run `p` on a machine with loop `l` on every axis (no geometric error; a set-up offset, 0.2 µm
/// white noise, 1 kHz, clock +23 ppm), synchronise it from D, and measure the timeline against
/// the machine's truth; Err with the synchronisation's message where it fails.
fn measure(p: &Plan, l: ServoLoop, seed: u64) -> Result<Accuracy, String> {
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, CENTRE);
    cfg.errors = MachineErrors {
        setup_offset_um: [12.0, -8.0, 5.0],
        ..MachineErrors::default()
    };
    cfg.errors.dynamics.servo = [Some(l); 3];
    cfg.machine.accel_mm_s2 = [1500.0, 1500.0, 1000.0];
    cfg.machine.feed_override_pct = 100.0;
    cfg.instrument.clock_ppm = CLOCK_PPM;
    cfg.instrument.start_delay_s = 2.0;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.sample_rate_hz = 1000.0;
    cfg.instrument.seed = seed;
    let rec = Simulation::new(&write_program(p, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    let sync = synchronise(p, &r).map_err(|e| e.to_string())?;
    let truth_factor = 1.0 / (1.0 + CLOCK_PPM * 1e-6);
    let feed_ppm = sync
        .circles
        .iter()
        .map(|c| {
            let programmed = p.circles[c.circle].feed_mm_min / 60.0;
            1e6 * (c.speed_mm_s / programmed / truth_factor - 1.0)
        })
        .fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
    let (path, _) = data_path(p, &r, &sync, [None; 3]).map_err(|e| e.to_string())?;
    let truth = &rec.truth.samples;
    let device: Vec<f64> = truth.iter().map(|s| s.t_device_us as f64).collect();
    let (mut sum, mut n, mut max) = (0.0, 0.0, 0.0f64);
    for (i, (&t, q)) in path.t_s.iter().zip(&path.p_mm).enumerate() {
        let v = path.v_mm_s[i];
        let speed = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if speed < 1e-3 {
            continue;
        }
        let at = r.t0_us + 1e6 * t;
        let k = device.partition_point(|&x| x < at - 0.5);
        let Some(s) = truth.get(k) else { continue };
        let a = s.actual_mm;
        // Along the path: (nominal − actual)·tangent / speed is how late the actual is behind
        // the timeline's position, i.e. how early the timeline is; its negative is the offset.
        let along: f64 = (0..3)
            .map(|j| (q[j] - (a[j] - CENTRE[j])) * v[j] / speed)
            .sum();
        let dt_ms = 1e3 * along / speed;
        sum += dt_ms;
        n += 1.0;
        max = max.max(dt_ms.abs());
    }
    Ok(Accuracy {
        feed_ppm,
        start_ms: sum / n,
        max_ms: max,
    })
}

/// The table of docs/synchronisation.md: every loop kind at 500, 1000, 2000 and 3000 mm/min on
/// XY circles of one and of two radii.
#[test]
#[ignore = "a measurement: run by hand with --profile sweep (docs/synchronisation.md)"]
fn timeline_accuracy_table() {
    println!("| loop | test | F mm/min | feed error ppm | mean offset ms | largest offset ms |");
    println!("|---|---|---|---|---|---|");
    for (name, l) in loops() {
        for radii in [vec![90.0], vec![95.0, 85.0]] {
            for feed in [500.0, 1000.0, 2000.0, 3000.0] {
                let p = make_plan(Plane::Xy, &radii, feed);
                let cell = match measure(&p, l, 7) {
                    Ok(a) => format!("{:+.0} | {:+.2} | {:.2}", a.feed_ppm, a.start_ms, a.max_ms),
                    Err(e) => format!("not synchronised: {e} | | "),
                };
                println!("| {name} | R {radii:?} | {feed} | {cell} |");
            }
        }
    }
}

/// Issue 26's failure: a loop without feed-forward at 2000–3000 mm/min delays and rounds the
/// feed-in by as much as the move lasts (τ = 33 ms at Kv 30 s⁻¹); read as a plain trapezoid, its
/// end left D 0.1–0.6 mm short of the circle and the record was not synchronised. Read as the
/// command through the loop, the timeline holds: the feed and the arcs' timing within the bounds
/// docs/synchronisation.md states for this loop.
#[test]
#[ignore = "issue 26: written with the lagged-ramp timeline but not yet run (the shared build did not finish before the deadline); run by hand and un-ignore when it passes"]
fn a_loop_without_feed_forward_cannot_bend_the_timeline() {
    for (radii, feed, seed) in [(vec![95.0, 85.0], 3000.0, 3), (vec![90.0], 2000.0, 5)] {
        let p = make_plan(Plane::Xy, &radii, feed);
        let a = measure(&p, ServoLoop::new(30.0), seed)
            .unwrap_or_else(|e| panic!("R {radii:?} F{feed}: {e}"));
        println!("R {radii:?} F{feed}: {a:?}");
        assert!(
            a.feed_ppm.abs() < FEED_BOUND_PPM,
            "R {radii:?} F{feed}: {a:?}"
        );
        assert!(
            a.start_ms.abs() < START_BOUND_MS,
            "R {radii:?} F{feed}: {a:?}"
        );
    }
}
