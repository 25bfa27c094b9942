//! The timeline under a position loop (issue 26): a ramp of D read as the machine's *command*
//! passed through its loop, so that a loop that delays and rounds the feed-in cannot bend the
//! timeline ([`super`] uses it; docs/synchronisation.md, "Under a position loop").
//!
//! # The model
//! A position loop of gain Kv with velocity feed-forward k_v follows its command as
//! H(s) = k_v + (1 − k_v)/(1 + s/Kv): to first order a delay τ = (1 − k_v)/Kv, and without
//! feed-forward a first-order lag of that time constant. A trapezoidal move (accelerate at a for
//! t_a, cruise t_c, decelerate t_a; starting at t₀) is a sum of four parabolas,
//! s(t) = a·[g(t − t₀) − g(t − t₀ − t_a) − g(t − t₀ − t_a − t_c) + g(t − t₀ − T)], g(x) = x²/2 for
//! x > 0 (T = 2t_a + t_c). Through the lag 1/(1 + sτ) each parabola becomes
//! g_τ(x) = x²/2 − τx + τ²(1 − e^(−x/τ)) (x > 0): the command's start, speed, acceleration and
//! length are fitted together with τ. The command's speed is the feed (the lag does not change
//! the speed of a cruise, only when it is reached), its start and end are the program's, and
//! the arcs, which the loop delays by τ too, start τ after the command's end: the ramps and the
//! arcs between them are timed on one clock, the loop's lag a parameter of it rather than a bend.
use super::Profile;
use crate::numerics::lsq::{least_squares, LsqOptions, Problem};

/// A lag is taken as the loop's only where the fit fixes it to this many standard errors and it
/// is at least [`MIN_LAG_S`]: on a machine that follows its program (or within a sample of it)
/// the ramp's plain trapezoid stands.
pub const LAG_SIGMAS: f64 = 3.0;

/// The least lag (s) taken as a loop's: below a millisecond the plain trapezoid's start already
/// holds it as a delay.
pub const MIN_LAG_S: f64 = 1e-3;

/// Path length (mm) covered at time `t` by a move whose command is `p`, followed through a
/// first-order lag of time constant `lag_s` (the module docs' g_τ); `lag_s` 0 is the command.
pub fn lagged_s_at(p: &Profile, lag_s: f64, t: f64) -> f64 {
    if lag_s <= 1e-9 {
        return p.s_at(t);
    }
    let g = |x: f64| {
        if x <= 0.0 {
            0.0
        } else {
            0.5 * x * x - lag_s * x + lag_s * lag_s * (1.0 - (-x / lag_s).exp())
        }
    };
    let total = p.duration_s();
    let ta = p.accel_phase_s();
    let tau = t - p.t0_s;
    let a = p.accel_mm_s2;
    a * (g(tau) - g(tau - ta) - g(tau - (total - ta)) + g(tau - total))
}

/// A ramp's command fitted through the loop: the command's profile (its start not yet delayed),
/// the lag and its standard error (s), the speed's standard error (mm/s) and the fit's RMS (µm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaggedRamp {
    pub command: Profile,
    pub lag_s: f64,
    pub lag_sigma_s: f64,
    pub speed_sigma_mm_s: f64,
    pub rms_um: f64,
}

/// s(t) samples (s, mm) of one ramp against a lagged trapezoid: t₀, speed, acceleration, length
/// and the lag.
struct LaggedProblem<'a> {
    t: &'a [f64],
    s: &'a [f64],
}

impl LaggedProblem<'_> {
    fn profile(p: &[f64]) -> (Profile, f64) {
        (
            Profile {
                t0_s: p[0],
                length_mm: p[3].abs().max(1e-6),
                speed_mm_s: p[1].abs().max(1e-6),
                accel_mm_s2: p[2].abs().max(1e-3),
            },
            p[4].abs(),
        )
    }
}

impl Problem for LaggedProblem<'_> {
    fn n_params(&self) -> usize {
        5
    }
    fn n_residuals(&self) -> usize {
        self.t.len()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let steps = [
            1e-5,
            1e-6 * p[1].abs().max(1.0),
            1e-6 * p[2].abs().max(1.0),
            1e-7 * p[3].abs().max(1.0),
            1e-5,
        ];
        let (base, lag) = Self::profile(p);
        let shifted: Vec<((Profile, f64), (Profile, f64))> = (0..5)
            .map(|k| {
                let (mut up, mut down) = (p.to_vec(), p.to_vec());
                up[k] += steps[k];
                down[k] -= steps[k];
                (Self::profile(&up), Self::profile(&down))
            })
            .collect();
        let mut g = [0.0; 5];
        for (i, (&t, &s)) in self.t.iter().zip(self.s).enumerate() {
            for k in 0..5 {
                let ((u, lu), (d, ld)) = &shifted[k];
                g[k] = 1e3 * (lagged_s_at(u, *lu, t) - lagged_s_at(d, *ld, t)) / (2.0 * steps[k]);
            }
            visit(i, 1e3 * (lagged_s_at(&base, lag, t) - s), &g);
        }
    }
}

/// Fit the ramp's samples (`t` s, `s` mm along its line) as a command through a loop, from the
/// plain trapezoid `plain` fitted to them (which, under a lag, starts late, accelerates too
/// gently and ends late). None where no lag is determined ([`LAG_SIGMAS`], [`MIN_LAG_S`]), the
/// fit does not converge, or its length is more than `tol_mm` off the line's `len_mm`.
pub fn fit_through_loop(
    t: &[f64],
    s: &[f64],
    plain: &Profile,
    len_mm: f64,
    tol_mm: f64,
) -> Option<LaggedRamp> {
    let prob = LaggedProblem { t, s };
    let opts = LsqOptions {
        max_iterations: 80,
        tolerance: 1e-10,
        initial_lambda: 1e-3,
        ..Default::default()
    };
    // Starts: the plain trapezoid moved earlier by a trial lag (a lag of τ delays the move by
    // about τ), with a steeper acceleration (the lag halves what a trapezoid fitted to a rounded
    // ramp reads at Kv 30 s⁻¹ and 2000 mm/min).
    [0.005, 0.015, 0.035]
        .iter()
        .filter_map(|&lag| {
            let p0 = [
                plain.t0_s - lag,
                plain.speed_mm_s,
                2.0 * plain.accel_mm_s2,
                plain.length_mm,
                lag,
            ];
            let fit = least_squares(&prob, &p0, &opts).ok()?;
            let (command, lag_s) = LaggedProblem::profile(&fit.params);
            let lag_sigma_s = fit.sigma[4]?;
            ((command.length_mm - len_mm).abs() <= tol_mm
                && lag_s >= MIN_LAG_S
                && lag_s > LAG_SIGMAS * lag_sigma_s)
                .then_some(LaggedRamp {
                    command,
                    lag_s,
                    lag_sigma_s,
                    speed_sigma_mm_s: fit.sigma[1].unwrap_or(f64::INFINITY),
                    rms_um: fit.rms,
                })
        })
        .min_by(|x, y| x.rms_um.total_cmp(&y.rms_um))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lagged_trapezoid_ends_where_the_command_does_and_lags_it_by_tau_in_its_cruise() {
        let p = Profile {
            t0_s: 1.0,
            length_mm: 4.0,
            speed_mm_s: 50.0,
            accel_mm_s2: 1500.0,
        };
        let lag = 1.0 / 30.0;
        // Long after the end: the whole length.
        assert!((lagged_s_at(&p, lag, p.end_s() + 1.0) - 4.0).abs() < 1e-9);
        // In the cruise, once the lag has settled, it is the command τ earlier.
        let t = p.t0_s + p.accel_phase_s() + 0.6 * (p.duration_s() - 2.0 * p.accel_phase_s());
        let late = lagged_s_at(&p, lag, t);
        let settled = p.s_at(t) - p.speed_mm_s * lag;
        assert!(late > settled - 0.2 && late < p.s_at(t), "{late} {settled}");
        // No lag: the command.
        assert_eq!(lagged_s_at(&p, 0.0, t), p.s_at(t));
        // The closed form against the lag's own equation, ds/dt = (s_cmd − s)/τ, integrated
        // (midpoint rule, 1 µs steps) through the whole move.
        let (mut s, mut time, h) = (0.0, p.t0_s, 1e-6);
        while time < p.end_s() + 0.1 {
            let mid = s + 0.5 * h * (p.s_at(time) - s) / lag;
            s += h * (p.s_at(time + 0.5 * h) - mid) / lag;
            time += h;
            if ((time - p.t0_s) / 0.01).fract() < h / 0.01 {
                assert!((lagged_s_at(&p, lag, time) - s).abs() < 1e-6, "{time}");
            }
        }
    }

    #[test]
    fn a_ramp_through_a_loop_gives_back_the_command_and_its_lag() {
        // A 4 mm feed-in at 3000 mm/min and 1500 mm/s² through a loop of Kv 30 s⁻¹ without
        // feed-forward (τ 33 ms, as long as the move's acceleration), sampled at 1 kHz: the plain
        // trapezoid reads the speed, start and end off; through the loop they are the command's.
        let cmd = Profile {
            t0_s: 0.2,
            length_mm: 4.0,
            speed_mm_s: 50.0,
            accel_mm_s2: 1500.0,
        };
        let lag = 1.0 / 30.0;
        let t: Vec<f64> = (0..500).map(|i| i as f64 * 1e-3).collect();
        let s: Vec<f64> = t.iter().map(|&x| lagged_s_at(&cmd, lag, x)).collect();
        let plain = Profile {
            t0_s: cmd.t0_s + lag,
            accel_mm_s2: 0.5 * cmd.accel_mm_s2,
            ..cmd
        };
        let fit = fit_through_loop(&t, &s, &plain, 4.0, 0.1).unwrap();
        assert!((fit.lag_s - lag).abs() < 1e-5, "{fit:?}");
        assert!((fit.command.t0_s - cmd.t0_s).abs() < 1e-5, "{fit:?}");
        assert!(
            (fit.command.speed_mm_s / 50.0 - 1.0).abs() < 1e-5,
            "{fit:?}"
        );
        // A machine that follows its program exactly has no lag to take.
        let s0: Vec<f64> = t.iter().map(|&x| cmd.s_at(x)).collect();
        let noisy: Vec<f64> = s0
            .iter()
            .enumerate()
            .map(|(i, x)| x + 2e-4 * ((i * 7919 % 1000) as f64 / 1000.0 - 0.5))
            .collect();
        assert!(fit_through_loop(&t, &noisy, &cmd, 4.0, 0.1).is_none());
    }
}
