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

use nalgebra::DMatrix;

use super::lsq::Problem;

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

/// Fewest blocks [`block_jackknife_variance`] uses: its longest blocks, an eighth of the record,
/// see a slow wander that [`integrated_time`]'s thirtieths do not.
pub const MIN_JACKKNIFE_BLOCKS: usize = 8;

/// The variance of each fitted parameter of `problem` at `p` when the noise is correlated over
/// times up to an eighth of the record: the delete-a-block jackknife of the fit, linearised. For
/// G blocks g of consecutive residuals, leaving g out moves the parameters by
/// δ_g = (JᵀJ − J_gᵀJ_g)⁺·J_gᵀr_g (exact for a linear model), and the variance is
/// (G − 1)/G·Σ_g δ_g².
///
/// Why per parameter and not one τ_int: a parameter's error is Σ_i w_i·ε_i with its own weights.
/// A lateral play or a drift weighs whole runs of the test alike, so a wander of seconds moves it
/// by its whole power; a cyclic error of a 5 mm pitch weighs the samples with alternating signs,
/// and the same wander cancels in it. Why the jackknife and not the plain block-score sandwich
/// A·Σ_g(J_gᵀr_g)(J_gᵀr_g)ᵀ·A: with a few long blocks, the fit's own slow parameters (length
/// offset, drift, lateral play) have taken out of the residual most of the very wander that moves
/// them, and the sandwich sees too little; leaving a block out refits without it and sees it.
/// Taken as the largest over block lengths from 1/512 of the record to the longest leaving
/// [`MIN_JACKKNIFE_BLOCKS`] blocks (each level the previous one's pairs), so a correlation of any
/// length up to that is not missed. Directions the data do not determine (singular values below
/// 1e-9 of the largest, column-scaled) are left out of each solve.
pub fn block_jackknife_variance(problem: &dyn Problem, p: &[f64]) -> Vec<f64> {
    let n = p.len();
    let m = problem.n_residuals();
    let mut best = vec![0.0; n];
    if n == 0 || m < 2 * MIN_JACKKNIFE_BLOCKS {
        return best;
    }
    let finest = (m / 512).max(1);
    let nb = m.div_ceil(finest);
    let mut scores = DMatrix::<f64>::zeros(n, nb);
    let mut grams: Vec<DMatrix<f64>> = vec![DMatrix::zeros(n, n); nb];
    problem.eval(p, &mut |i, r, g| {
        let b = (i / finest).min(nb - 1);
        for k in 0..n {
            scores[(k, b)] += g[k] * r;
        }
        let gb = &mut grams[b];
        for k in 0..n {
            if g[k] != 0.0 {
                for l in 0..n {
                    gb[(k, l)] += g[k] * g[l];
                }
            }
        }
    });
    let total: DMatrix<f64> = grams.iter().fold(DMatrix::zeros(n, n), |a, g| a + g);
    let d: Vec<f64> = (0..n)
        .map(|k| {
            let v = total[(k, k)].sqrt();
            if v > 0.0 && v.is_finite() {
                v
            } else {
                1.0
            }
        })
        .collect();
    while scores.ncols() >= MIN_JACKKNIFE_BLOCKS {
        let g_count = scores.ncols();
        let mut v = vec![0.0; n];
        let mut ok = true;
        for g in 0..g_count {
            let scaled = DMatrix::from_fn(n, n, |k, l| {
                (total[(k, l)] - grams[g][(k, l)]) / (d[k] * d[l])
            });
            let eps = 1e-9 * scaled.norm();
            let Ok(pinv) = scaled.pseudo_inverse(eps) else {
                ok = false;
                break;
            };
            let s = DMatrix::from_fn(n, 1, |k, _| scores[(k, g)] / d[k]);
            let delta = pinv * s;
            for k in 0..n {
                v[k] += (delta[(k, 0)] / d[k]).powi(2);
            }
        }
        if ok {
            let gf = g_count as f64;
            for k in 0..n {
                best[k] = f64::max(best[k], v[k] * (gf - 1.0) / gf);
            }
        }
        // Pairs; an odd last block joins the last pair.
        let next = g_count / 2;
        let join = |c: usize| -> Vec<usize> {
            if c + 1 == next && g_count % 2 == 1 {
                vec![2 * c, 2 * c + 1, g_count - 1]
            } else {
                vec![2 * c, 2 * c + 1]
            }
        };
        scores = DMatrix::from_fn(n, next, |k, c| {
            join(c).iter().map(|&b| scores[(k, b)]).sum()
        });
        grams = (0..next)
            .map(|c| {
                join(c)
                    .iter()
                    .fold(DMatrix::zeros(n, n), |a, &b| a + &grams[b])
            })
            .collect();
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
