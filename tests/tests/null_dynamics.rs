//! Perfect machines that move like machines (issue 26): no geometric error at all, but axes driven
//! by real position loops (Kv 30–60 s⁻¹, velocity loops of 50–200 Hz, feed-forward none or
//! 0.9–1.0, held on 0.1–1 µm counts) and coloured noise (AR(1) up to ρ 0.8 per sample, 1/f
//! wander, vibration). A diagnosis must name nothing a technician would act on: the loop's own
//! following error is the servo's, not a scale, a squareness or a spike.
//!
//! Seeded draws over planes (XY circles of one or two radii, ZX and YZ 220° arcs), feeds
//! (500–3000 mm/min) and sample rates; each draw is a plan from `jdbb plan`, run on the
//! independent G-code machine, read back through a CSV file, synchronised and diagnosed as
//! `jdbb diagnose --record --plan` does.
//!
//! The sweep is a measurement, run by hand (`JDBB_NULL_SEEDS=A..B`, default 0..200; `JDBB_WHITE=1`
//! counts every sample as independent, as the diagnosis did before issue 26):
//! `cargo test --profile sweep -p jdbb-tests --test null_dynamics -- --ignored --nocapture`.
//! Its counts are in `docs/mechanisms.md`. It is not a CI test yet: the false-alarm rate it
//! measures is above what issue 26 asks (2 %), and a test that fails on main cannot land.
mod planned;

use planned::{machine_names, read_back};

use jdbb::diagnose::planned::diagnose_planned;
use jdbb::diagnose::{Diagnosis, Options};
use jdbb::plan::{plan, write_program, Dialect as PlanDialect, Plan, PlanSpec, Plane};
use jdbb::sync::synchronise;
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{
    ColouredNoise, Dialect, MachineErrors, Realistic, ServoLoop, SimConfig, Simulation, Tuning,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const CENTRE: [f64; 3] = [100.0, 50.0, -20.0];

/// One null machine and its test.
#[derive(Debug, Clone)]
struct Draw {
    plane: Plane,
    radii: Vec<f64>,
    feed_mm_min: f64,
    rate_hz: f64,
    loops: [ServoLoop; 3],
    noise: ColouredNoise,
    white_um: f64,
}

fn draw(seed: u64) -> Draw {
    let mut r = ChaCha8Rng::seed_from_u64(0x6e75_6c6c ^ seed);
    let (plane, radii) = match r.gen_range(0..4) {
        0 => (Plane::Xy, vec![90.0]),
        1 => (Plane::Xy, vec![95.0, 85.0]),
        2 => (Plane::Zx, vec![90.0]),
        _ => (Plane::Yz, vec![90.0]),
    };
    let feed_mm_min = [500.0, 1000.0, 2000.0, 3000.0][r.gen_range(0..4)];
    let rate_hz = [1000.0, 2000.0, 5000.0][r.gen_range(0..3)];
    // Axes tuned alike (unequal gains are a servo mismatch, a real effect to name); AR(1) with
    // ρ up to 0.8 between samples, 1/f wander and a vibration.
    let real = Realistic::draw_from(&mut r, rate_hz, Tuning::Either);
    Draw {
        plane,
        radii,
        feed_mm_min,
        rate_hz,
        loops: [real.servo; 3],
        noise: real.noise,
        white_um: real.white_um,
    }
}

fn make_plan(d: &Draw) -> Plan {
    let spec = PlanSpec::machine_test(
        &d.radii,
        &[0.0],
        d.plane,
        d.feed_mm_min,
        CENTRE,
        PlanDialect::Linuxcnc,
    );
    let spec = if d.plane == Plane::Xy {
        spec
    } else {
        // A partial arc is timed from its feed-in: at 2000 mm/min and more the default 2 mm does
        // not cruise, and `jdbb plan` says to lengthen it.
        PlanSpec {
            start_deg: -20.0,
            feed_in_mm: if d.feed_mm_min >= 2000.0 {
                4.0
            } else {
                spec.feed_in_mm
            },
            ..spec.with_arc(220.0)
        }
    };
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

/// The diagnosis of seed `seed`'s null machine (or why the record could not be synchronised and
/// diagnosed), and a line describing the draw.
fn run(seed: u64) -> (Result<Diagnosis, String>, String) {
    let d = draw(seed);
    let p = make_plan(&d);
    let text = write_program(&p, PlanDialect::Linuxcnc);
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, CENTRE);
    cfg.errors = MachineErrors {
        setup_offset_um: [12.0, -8.0, 5.0],
        ..MachineErrors::default()
    };
    cfg.errors.dynamics.servo = d.loops.map(Some);
    cfg.machine.accel_mm_s2 = [1500.0, 1500.0, 1000.0];
    cfg.machine.feed_override_pct = 100.0;
    cfg.instrument.clock_ppm = 23.0;
    cfg.instrument.start_delay_s = 2.0;
    cfg.instrument.noise_um = d.white_um;
    cfg.instrument.coloured_noise = d.noise;
    cfg.instrument.sample_rate_hz = d.rate_hz;
    cfg.instrument.seed = seed;
    let rec = Simulation::new(&text, cfg).unwrap().run().unwrap();
    let r = read_back(&rec);
    let diagnosis = synchronise(&p, &r)
        .and_then(|first| {
            let opts = Options {
                // JDBB_WHITE=1: every sample independent, as the diagnosis did before issue 26.
                correlated_noise: std::env::var("JDBB_WHITE").is_err(),
                ..Options::default()
            };
            diagnose_planned(&p, &r, first, [None; 3], &opts)
        })
        .map(|done| done.diagnosis)
        .map_err(|e| e.to_string());
    let l = &d.loops[0];
    let line = format!(
        "seed {seed}: {:?} R {:?} F{} {} Hz, Kv {:.0} vel-loop {:.0} Hz ff {:.2}/{:.2} count {} µm, \
         AR {:.2} µm τ {:.2} ms, wander {:.2}, vib {:.2} µm @ {:.0} Hz",
        d.plane,
        d.radii,
        d.feed_mm_min,
        d.rate_hz,
        l.kv_per_s,
        l.velocity_bandwidth_hz,
        l.ff_velocity,
        l.ff_acceleration,
        l.count_um,
        d.noise.ar1_um,
        d.noise.ar1_tau_ms,
        d.noise.wander_um,
        d.noise.vibration_um,
        d.noise.vibration_hz
    );
    (diagnosis, line)
}

/// Run `seeds`, print each false alarm and failure, and return (runs, runs naming something,
/// runs not diagnosed).
fn sweep(seeds: impl Iterator<Item = u64>) -> (usize, usize, usize) {
    let (mut n, mut alarms, mut failed) = (0, 0, 0);
    for seed in seeds {
        let (d, line) = run(seed);
        n += 1;
        let d = match d {
            Ok(d) => d,
            Err(e) => {
                failed += 1;
                println!("{line}\n    not diagnosed: {e}");
                continue;
            }
        };
        let names = machine_names(&d);
        if !names.is_empty() {
            alarms += 1;
            let named: Vec<String> = d
                .effects
                .iter()
                .filter(|f| !f.effect.is_setup())
                .map(|f| match f.sigma {
                    Some(s) => format!("{} = {:.4} ± {:.4}", f.effect.name(), f.value, s),
                    None => format!("{} = {:.4}", f.effect.name(), f.value),
                })
                .collect();
            println!("{line}\n    named: {}", named.join(", "));
        }
    }
    println!("{alarms} of {n} null machines named something, {failed} not diagnosed");
    (n, alarms, failed)
}

fn seeds_from_env(default: std::ops::Range<u64>) -> std::ops::Range<u64> {
    std::env::var("JDBB_NULL_SEEDS")
        .ok()
        .and_then(|s| {
            let (a, b) = s.split_once("..")?;
            Some(a.parse().ok()?..b.parse().ok()?)
        })
        .unwrap_or(default)
}

/// The full sweep, by hand (see the module docs): the false-alarm rate stated in
/// `docs/mechanisms.md`.
#[test]
#[ignore = "the full sweep: run by hand with --profile sweep (docs/mechanisms.md)"]
fn null_machines_with_loops_sweep() {
    let (n, alarms, failed) = sweep(seeds_from_env(0..200));
    println!(
        "false-alarm rate {:.1} %, not diagnosed {:.1} %",
        100.0 * alarms as f64 / n as f64,
        100.0 * failed as f64 / n as f64
    );
}
