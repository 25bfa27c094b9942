//! What the tests of planned runs on the G-code machine share (`sync_hidden`, `arc_hidden`,
//! `mechanisms`, `sync_random`, `real_machine`, …): the recording read back as `jdbb diagnose
//! --record` reads it, the names a diagnosis gives, and the seeded suites' draws and checks. They
//! use the host's reader, which the library of this crate must not: its simulators are written
//! apart from the host.
use jdbb::diagnose::Diagnosis;
use jdbb::model::Path;
use jdbb::plan::{write_program, Dialect as PlanDialect, Plan};
use jdbb::sync::{data_path, synchronise, Record};
use jdbb_tests::gmachine::{Dialect, MachineErrors, Recording, SimConfig, Simulation};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The recording as `jdbb record` writes it (CSV in a temporary file) and `diagnose --record`
/// reads it back.
pub fn read_back(rec: &Recording) -> Record {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("rec.csv");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&file).unwrap());
    rec.write_csv(&mut f).unwrap();
    drop(f);
    Record::read(&file).unwrap()
}

/// The machine effects a diagnosis names (not the set-up), in the order selected.
#[allow(dead_code)]
pub fn machine_names(d: &Diagnosis) -> Vec<String> {
    d.effects
        .iter()
        .filter(|f| !f.effect.is_setup())
        .map(|f| f.effect.name())
        .collect()
}

/// The one tolerance rule (`jdbb_tests::tolerance`): within 5 % and within 1 % + 3σ, σ under a
/// stated fraction of the value (10 % unless a test says why more).
// Not every test file that shares this module checks a value.
#[allow(unused_imports)]
pub use jdbb_tests::tolerance::{assert_unbiased, assert_unbiased_sigma};

/// Run `plan`'s LinuxCNC program on the G-code machine as `cfg` sets it up, read the record back
/// (`read_back`), synchronise it from D and cut out the data arcs, as `jdbb diagnose --record
/// --plan` does: the recording (its truth), the data arcs' path and their D (mm).
// Not every test file that shares this module runs a plan this way.
#[allow(dead_code)]
pub fn data_arcs(plan: &Plan, cfg: SimConfig) -> (Recording, Path, Vec<f64>) {
    let rec = Simulation::new(&write_program(plan, PlanDialect::Linuxcnc), cfg)
        .unwrap()
        .run()
        .unwrap();
    let r = read_back(&rec);
    let sync = synchronise(plan, &r).unwrap();
    let (path, d) = data_path(plan, &r, &sync, [None; 3]).unwrap();
    (rec, path, d)
}

/// A value of random sign with magnitude in `lo..hi` (the seeded suites' draws).
#[allow(dead_code)]
pub fn signed(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let v = rng.gen_range(lo..hi);
    if rng.gen_bool(0.5) {
        v
    } else {
        -v
    }
}

/// How far `p_mm` is from the nearest whole multiple of `pitch_mm`, as a fraction of the pitch
/// (0 on a multiple, 0.5 halfway).
#[allow(dead_code)]
pub fn pitch_fraction(p_mm: f64, pitch_mm: f64) -> f64 {
    let f = (p_mm / pitch_mm).rem_euclid(1.0);
    f.min(1.0 - f)
}

/// The twin a diagnosis named in place of the expected `name` (one circle cannot tell a bow from
/// the second-order scale of the axis it bows in), if it was named and the pair said to be
/// confounded.
#[allow(dead_code)]
pub fn twin_stated<'a>(
    name: &str,
    twin: Option<&'a String>,
    named: &[String],
    d: &Diagnosis,
) -> Option<&'a String> {
    twin.filter(|t| {
        named.contains(t)
            && d.confounded
                .iter()
                .any(|g| g.contains(t) && g.iter().any(|n| n == name))
    })
}

/// Fail with every case of `seeds` that `check` finds wrong.
#[allow(dead_code)]
pub fn assert_cases(seeds: &[u64], check: impl Fn(u64) -> Result<(), String>) {
    let failures: Vec<String> = seeds.iter().filter_map(|&s| check(s).err()).collect();
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        seeds.len(),
        failures.join("\n\n")
    );
}

/// How a seeded case's machine runs and records, as the suite drew it.
#[allow(dead_code)]
pub struct Drawn {
    pub override_pct: f64,
    pub accel_mm_s2: [f64; 3],
    pub clock_ppm: f64,
    pub rate_hz: f64,
}

/// The G-code machine of seeded case `seed` (LinuxCNC, 0.2 µm of noise on D) with `errors`,
/// the program's test centre at `centre_mm`, as `drawn`; the start delay (1–5 s) and the device
/// clock's origin drawn from `rng`, in that order.
#[allow(dead_code)]
pub fn seeded_config(
    rng: &mut ChaCha8Rng,
    seed: u64,
    centre_mm: [f64; 3],
    errors: MachineErrors,
    drawn: Drawn,
) -> SimConfig {
    let mut config = SimConfig::new(Dialect::LinuxCnc, centre_mm);
    config.errors = errors;
    config.machine.feed_override_pct = drawn.override_pct;
    config.machine.accel_mm_s2 = drawn.accel_mm_s2;
    config.instrument.clock_ppm = drawn.clock_ppm;
    config.instrument.start_delay_s = rng.gen_range(1.0..5.0);
    config.instrument.t0_us = rng.gen_range(0..1_000_000_000);
    config.instrument.noise_um = 0.2;
    config.instrument.seed = seed;
    config.instrument.sample_rate_hz = drawn.rate_hz;
    config
}
