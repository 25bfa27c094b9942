//! How many independent samples a residual is worth: the integrated autocorrelation time of a
//! series, by batch means.
//!
//! A least-squares fit takes its samples as independent. When the noise is correlated (a machine's
//! vibration, an AR(1) process, a slow wander), m samples carry the information of about
//! m/τ_int independent ones, with
//!
//! ```text
//! τ_int = 1 + 2·Σ_{k≥1} ρ_k = S(0)/σ²
//! ```
//!
//! (ρ_k the autocorrelation at lag k, S(0) the spectral density at zero frequency in units of the
//! sample rate). A white-noise fit then states its standard errors √τ_int too small, and a
//! selection criterion that counts m samples names noise. Batch means estimate τ_int without a
//! spectrum: cut the series into blocks of b samples; for independent samples the block means
//! have variance σ²/b, for correlated ones about τ_int·σ²/b once b is long against the
//! correlation, so τ(b) = b·Var(block means)/σ² rises to τ_int as b grows (Flyvbjerg & Petersen,
//! J. Chem. Phys. 91, 461 (1989)).
//!
//! The estimate here is the largest τ(b) over block lengths b = 2, 4, 8, … up to `max_block`,
//! keeping at least [`MIN_BLOCKS`] blocks (each τ(b) is then known to about 26 %, the longest
//! blocks the least well). Taking the largest is conservative: white noise reads about 1.0–1.8,
//! not less; a slow wander, whose correlation only the longest blocks see, is not missed.

/// Fewest blocks a block length must leave for its τ(b) to count (the relative standard error
/// of a variance from n blocks is about √(2/n): 26 % at 30).
pub const MIN_BLOCKS: usize = 30;

/// The integrated autocorrelation time τ_int (≥ 1) of `x` in samples, from block lengths up to
/// `max_block` samples (module docs). A series too short for two block lengths, or constant,
/// gives 1.
pub fn integrated_time(x: &[f64], max_block: usize) -> f64 {
    let n = x.len();
    if n < 2 * MIN_BLOCKS {
        return 1.0;
    }
    let mean = x.iter().sum::<f64>() / n as f64;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n as f64;
    if var.is_nan() || var <= 0.0 || !var.is_finite() {
        return 1.0;
    }
    let mut best: f64 = 1.0;
    let mut b = 2;
    while b <= max_block && n / b >= MIN_BLOCKS {
        let blocks = n / b;
        let means: Vec<f64> = (0..blocks)
            .map(|i| x[i * b..(i + 1) * b].iter().sum::<f64>() / b as f64)
            .collect();
        let bm = means.iter().sum::<f64>() / blocks as f64;
        let vb = means.iter().map(|v| (v - bm) * (v - bm)).sum::<f64>() / (blocks - 1) as f64;
        best = best.max(b as f64 * vb / var);
        b *= 2;
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reproducible standard normal sequence (Box–Muller on a 64-bit LCG).
    fn normals(n: usize, seed: u64) -> Vec<f64> {
        let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let (u, v) = (next(), next());
                (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
            })
            .collect()
    }

    #[test]
    fn white_noise_is_worth_its_samples() {
        for seed in 0..5 {
            let tau = integrated_time(&normals(50_000, seed), 256);
            assert!((1.0..1.8).contains(&tau), "seed {seed}: τ {tau}");
        }
    }

    /// AR(1) of coefficient ρ: τ_int = (1 + ρ)/(1 − ρ), 9 at ρ = 0.8, 3 at ρ = 0.5.
    #[test]
    fn ar1_noise_is_worth_a_fraction_of_its_samples() {
        for (rho, seed) in [(0.8, 1), (0.5, 2), (0.9, 3)] {
            let z = normals(200_000, seed);
            let mut x = vec![0.0; z.len()];
            for i in 1..x.len() {
                x[i] = rho * x[i - 1] + z[i];
            }
            let want = (1.0 + rho) / (1.0 - rho);
            let tau = integrated_time(&x, 1024);
            assert!(
                (tau / want - 1.0).abs() < 0.35,
                "ρ {rho}: τ {tau:.2}, want {want:.2}"
            );
        }
    }

    #[test]
    fn short_or_constant_series_count_as_independent() {
        assert_eq!(integrated_time(&[1.0; 10], 8), 1.0);
        assert_eq!(integrated_time(&[2.5; 10_000], 64), 1.0);
    }
}
