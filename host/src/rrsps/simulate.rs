//! Simulated DBB tests of the A/C table: the designed motion, bar lengths from (possibly other)
//! true parameters, Gaussian noise.
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use super::design::{theta_a_for, Branch};
use super::{Params, Prepared, SinCos};
use crate::{Error, Result};

/// Simulate a DBB test: the motion designed with `design` at bar length `d_mm`
/// (`points` C positions per branch over 0..360°), bar lengths from `truth` plus Gaussian noise
/// of `noise_um`. Returns (θA rad, θC rad, d mm, number of C positions left out).
#[allow(clippy::type_complexity)]
pub fn simulate(
    design: &Params,
    truth: &Params,
    d_mm: f64,
    points: usize,
    branches: &[Branch],
    noise_um: f64,
    seed: u64,
) -> Result<(Vec<f64>, Vec<f64>, Vec<f64>, usize)> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise =
        Normal::new(0.0, noise_um * 1e-3).map_err(|e| Error::Usage(format!("noise: {e}")))?;
    let prep = Prepared::new(truth);
    let (mut ta, mut tc, mut d) = (Vec::new(), Vec::new(), Vec::new());
    let mut skipped = 0;
    for &b in branches {
        for k in 0..points {
            let c = (k as f64 * 360.0 / points as f64).to_radians();
            match theta_a_for(design, d_mm, c, b) {
                Some(a) => {
                    ta.push(a);
                    tc.push(c);
                    d.push(prep.bar_length(SinCos::of(a), SinCos::of(c)) + noise.sample(&mut rng));
                }
                None => skipped += 1,
            }
        }
    }
    Ok((ta, tc, d, skipped))
}
