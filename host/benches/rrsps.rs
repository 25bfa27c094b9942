//! Benchmark: identify the eight RRSPS parameters (seed 004, eq. 26) from 100,000 samples.
//!
//! `cargo bench -p jdbb --bench rrsps [-- SAMPLES.csv]`: with a file (as `bench/compare_rrsps.sh`
//! passes, so that Python fits the very same data) it fits that file; without one it simulates
//! the Table 2 design motion with the paper's M1 parameters as truth and 0.45 µm noise.
//! Prints the median wall time of the least-squares identification over several runs, and the
//! time of one minimax identification.
use std::path::PathBuf;
use std::time::Instant;

use jdbb::rrsps::design::Branch;
use jdbb::rrsps::identify::{identify, Method};
use jdbb::rrsps::io::{read_samples, Samples};
use jdbb::rrsps::simulate::simulate;
use jdbb::rrsps::Params;

fn design() -> Params {
    Params::from_named_units(&[96.310, 352.114, -55.0, 80.0, 30.0, -161.592, 0.0, 270.0])
}

fn main() {
    let file = std::env::args().skip(1).find(|a| a.ends_with(".csv"));
    let samples = match &file {
        Some(f) => read_samples(&PathBuf::from(f), 8).expect("samples file"),
        None => {
            let truth = Params::from_named_units(&[
                96.865, 351.891, -54.995, 79.871, 30.063, -161.531, -0.023, 270.093,
            ]);
            let (ta, tc, d, _) = simulate(&design(), &truth, 300.0, 50_000, &Branch::BOTH, 0.45, 1)
                .expect("simulate");
            Samples {
                path: "simulated".into(),
                theta_a_rad: ta,
                theta_c_rad: tc,
                d_mm: d,
            }
        }
    };
    let n = samples.d_mm.len();
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..7 {
        let t0 = Instant::now();
        let id =
            identify(std::slice::from_ref(&samples), &design(), &[], Method::Lsq).expect("fit");
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        last = Some(id);
    }
    times.sort_by(f64::total_cmp);
    let id = last.unwrap();
    println!(
        "rrsps lsq: {n} samples, median {:.1} ms (min {:.1}, max {:.1}) over {} runs, {} LM iterations, rms {:.3} um",
        times[times.len() / 2],
        times[0],
        times[times.len() - 1],
        times.len(),
        id.iterations,
        id.rms_residual_um
    );
    println!(
        "rrsps lsq params: {}",
        id.estimates
            .iter()
            .map(|e| format!("{}={:.6}", e.name, e.value))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let t0 = Instant::now();
    let mm = identify(
        std::slice::from_ref(&samples),
        &design(),
        &[],
        Method::Minimax,
    )
    .expect("minimax");
    println!(
        "rrsps minimax: {n} samples, {:.1} ms (one run, includes the least-squares start), max |r| {:.3} um",
        t0.elapsed().as_secs_f64() * 1e3,
        mm.max_abs_residual_um
    );
}
