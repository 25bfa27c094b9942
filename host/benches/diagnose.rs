//! Speed of `jdbb diagnose`'s whole candidate search (issue 3: 20,000 samples in ≤ 20 ms on one
//! core, linear growth to 10⁶). Plain `harness = false` main timed with `Instant`.
//!
//! `cargo bench -p jdbb --bench diagnose` times simulated tests of 20,000, 100,000 and 1,000,000
//! samples (one circle ccw + cw at R = 50 mm, set-up offset, scale_x, backlash_y, cyclic_x,
//! 0.3 µm noise, pitch x = y = 10 mm). `cargo bench -p jdbb --bench diagnose -- FILE [RUNS]`
//! times the diagnosis of FILE instead (`sim:N`: the simulated test of N samples), 51 runs unless RUNS says (bench/compare_diagnose.sh gives
//! the same file to bench/diagnose.py; one run under `valgrind --tool=callgrind` counts
//! instructions, which a loaded machine does not disturb).
//! Timed: everything from the samples in memory (nominal path + D) to the finished diagnosis —
//! velocity/direction derivation, baseline, set-up fit, the one-pass Gram of all candidates, the
//! forward selection, the exact refit, residual harmonics, G and H. CSV parsing is not timed.
use std::time::Instant;

use jdbb::diagnose::input::read_samples;
use jdbb::diagnose::{diagnose, Options};
use jdbb::model::parse_pitch;
use jdbb::model::Path;
use jdbb::simulate::{distances_mm, measure, nominal_path, parse_effect, PathSpec};

fn simulated(n: usize) -> (Path, Vec<f64>) {
    let period_s = std::f64::consts::TAU * 50.0 / (1000.0 / 60.0);
    let spec = PathSpec {
        radii_mm: vec![50.0],
        heights_mm: vec![0.0],
        plane: (0, 1, 2),
        feed_mm_min: 1000.0,
        rate_hz: (n / 2) as f64 / period_s,
    };
    let (t, p) = nominal_path(&spec);
    let pitch = parse_pitch("x=10,y=10").unwrap();
    let path = Path::new(t, p, pitch);
    let effects: Vec<_> = [
        "setup_offset=30,-20,0",
        "scale_x=20",
        "backlash_y=8",
        "cyclic_x=2@40",
    ]
    .iter()
    .map(|s| parse_effect(s).unwrap())
    .collect();
    let mut d = distances_mm(&path, &effects).unwrap();
    measure(&mut d, 0.3, 0.1, 1);
    (path, d)
}

/// Median and minimum of `reps` timed diagnoses (ms); the path is rebuilt from raw t, p each time
/// so velocity and direction derivation are included.
fn time(path: &Path, d: &[f64], reps: usize) -> (f64, f64, String) {
    let mut ms = vec![];
    let mut names = String::new();
    for _ in 0..reps {
        let (t, p) = (path.t_s.clone(), path.p_mm.clone());
        let t0 = Instant::now();
        let fresh = Path::new(t, p, path.pitch_mm);
        let r = diagnose(&fresh, d, &Options::default()).unwrap();
        ms.push(t0.elapsed().as_secs_f64() * 1e3);
        names = r
            .effects
            .iter()
            .map(|f| format!("{}={:.3}", f.effect.name(), f.value))
            .collect::<Vec<_>>()
            .join(" ");
    }
    ms.sort_by(f64::total_cmp);
    (ms[ms.len() / 2], ms[0], names)
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with("--"))
        .collect();
    if let Some(file) = args.first() {
        let (path, d) = match file.strip_prefix("sim:") {
            // `sim:N`: the simulated test of N samples (for one run under callgrind).
            Some(n) => simulated(n.parse().expect("sim:N, N samples")),
            None => {
                let pitch = parse_pitch("x=10,y=10").unwrap();
                read_samples(std::path::Path::new(file), pitch).expect("read samples")
            }
        };
        let reps = args.get(1).and_then(|r| r.parse().ok()).unwrap_or(51);
        let (med, min, names) = time(&path, &d, reps);
        println!(
            "diagnose {} samples: median {med:.3} ms, min {min:.3} ms ({reps} runs)",
            d.len()
        );
        println!("  found: {names}");
        return;
    }
    for (n, reps) in [(20_000usize, 51usize), (100_000, 11), (1_000_000, 3)] {
        let (path, d) = simulated(n);
        let (med, min, names) = time(&path, &d, reps);
        println!(
            "diagnose {} samples: median {med:.3} ms, min {min:.3} ms ({reps} runs), {:.1} ns/sample",
            d.len(),
            med * 1e6 / d.len() as f64
        );
        println!("  found: {names}");
    }
}
