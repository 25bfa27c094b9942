//! A feed-in or feed-out ramp read from D: the trapezoidal motion profile fitted to the ramp's
//! samples (its start, speed, acceleration and length), from which the timeline starts.
#![allow(clippy::needless_range_loop)]
use super::*;

/// The machine's motion along one move from rest to rest: accelerate at `accel_mm_s2` up to
/// `speed_mm_s`, cruise, decelerate at the same rate, over `length_mm`; triangular (never
/// reaching the speed) when the move is too short.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    pub t0_s: f64,
    pub length_mm: f64,
    pub speed_mm_s: f64,
    pub accel_mm_s2: f64,
}

impl Profile {
    /// Peak speed and the duration of the acceleration phase.
    fn phases(&self) -> (f64, f64) {
        let (l, v, a) = (self.length_mm, self.speed_mm_s, self.accel_mm_s2);
        if v * v / a >= l {
            let vp = (a * l).sqrt();
            (vp, vp / a)
        } else {
            (v, v / a)
        }
    }

    /// Duration of the acceleration phase (s; as long as the deceleration's).
    pub fn accel_phase_s(&self) -> f64 {
        self.phases().1
    }

    /// Duration of the move (s).
    pub fn duration_s(&self) -> f64 {
        let (vp, ta) = self.phases();
        let cruise = (self.length_mm - vp * ta).max(0.0) / vp;
        2.0 * ta + cruise
    }

    /// When the move ends (s).
    pub fn end_s(&self) -> f64 {
        self.t0_s + self.duration_s()
    }

    /// Path length covered at time `t` (mm), 0 before the start and the length after the end.
    pub fn s_at(&self, t: f64) -> f64 {
        let (vp, ta) = self.phases();
        let a = self.accel_mm_s2;
        let l = self.length_mm;
        let tau = t - self.t0_s;
        let total = self.duration_s();
        if tau <= 0.0 {
            0.0
        } else if tau >= total {
            l
        } else if tau < ta {
            0.5 * a * tau * tau
        } else if tau > total - ta {
            let r = total - tau;
            l - 0.5 * a * r * r
        } else {
            0.5 * vp * ta + vp * (tau - ta)
        }
    }

    /// Time at which path length `s` is reached (the inverse of [`Profile::s_at`] on the move).
    pub fn t_at(&self, s: f64) -> f64 {
        let (vp, ta) = self.phases();
        let a = self.accel_mm_s2;
        let l = self.length_mm;
        let s = s.clamp(0.0, l);
        let total = self.duration_s();
        let sa = 0.5 * vp * ta;
        let tau = if s <= sa {
            (2.0 * s / a).sqrt()
        } else if s >= l - sa {
            total - (2.0 * (l - s) / a).sqrt()
        } else {
            ta + (s - sa) / vp
        };
        self.t0_s + tau
    }
}

/// A ramp of D fitted with a [`Profile`], and how well it fits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ramp {
    pub profile: Profile,
    /// Standard error of the fitted speed (mm/s).
    pub speed_sigma_mm_s: f64,
    /// RMS of the fit (µm of path length).
    pub rms_um: f64,
    /// Samples used.
    pub samples: usize,
    /// The position loop's lag the ramp was read through (s; 0 where none is determined): the
    /// profile is then the command delayed by it ([`loop_lag`]).
    pub lag_s: f64,
}

/// The trapezoidal profile fitted to s(t) samples of one ramp: start, speed, acceleration and the
/// length the data show (the plan's length give or take the µm that a backlash step or the
/// set-up put between the plateaus).
pub(super) struct RampProblem<'a> {
    t: &'a [f64],
    s: &'a [f64],
}

impl RampProblem<'_> {
    fn profile(p: &[f64]) -> Profile {
        Profile {
            t0_s: p[0],
            length_mm: p[3].abs().max(1e-6),
            speed_mm_s: p[1].abs().max(1e-6),
            accel_mm_s2: p[2].abs().max(1e-3),
        }
    }
}

impl Problem for RampProblem<'_> {
    fn n_params(&self) -> usize {
        4
    }
    fn n_residuals(&self) -> usize {
        self.t.len()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        // Central differences: the profile is piecewise quadratic in its parameters.
        let steps = [
            1e-5,
            1e-6 * p[1].abs().max(1.0),
            1e-6 * p[2].abs().max(1.0),
            1e-7 * p[3].abs().max(1.0),
        ];
        let base = Self::profile(p);
        let shifted: Vec<(Profile, Profile)> = (0..4)
            .map(|k| {
                let (mut up, mut down) = (p.to_vec(), p.to_vec());
                up[k] += steps[k];
                down[k] -= steps[k];
                (Self::profile(&up), Self::profile(&down))
            })
            .collect();
        let mut g = [0.0; 4];
        for (i, (&t, &s)) in self.t.iter().zip(self.s).enumerate() {
            for k in 0..4 {
                let (u, d) = &shifted[k];
                g[k] = 1e3 * (u.s_at(t) - d.s_at(t)) / (2.0 * steps[k]);
            }
            visit(i, 1e3 * (base.s_at(t) - s), &g);
        }
    }
}

/// Fit the ramp of a line crossing the midpoint at record index `cross`, the line running from
/// `from` to `to` (relative to the table ball, mm); `d_from`/`d_to` are the plan's D at its ends.
/// D is put on the line's path length with the line's geometry, offset to the plateau before
/// the ramp (not scaled to the one after it). The fit takes `before_s` of standstill before the
/// ramp and `after_s` after it: a dwell's worth on the side of a dwell, a few ms on the side of
/// an arc, where the arc's first µm (a backlash step, a reversal spike, the set-up's
/// once-per-revolution term) already show.
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_ramp(
    rec: &Record,
    cross: usize,
    from: [f64; 3],
    to: [f64; 3],
    d_from: f64,
    d_to: f64,
    feed_mm_s: f64,
    before_s: f64,
    after_s: f64,
    ruler: Option<&Ruler>,
) -> Option<Ramp> {
    let len = dist(&from, &to);
    let tol = LEVEL_TOLERANCE_MM.min(0.25 * (d_to - d_from).abs());
    // Ramp extent: from the last sample near D_from's level before the crossing to the first
    // sample near D_to's level after it (2 % of the ramp). The levels are measured, not the
    // plan's: a set-up offset or an instrument error moves them by tens of µm, as much as 2 % of
    // a 2 mm ramp. First the samples within `tol` of the plan's levels, then the standstills just
    // beyond them give the levels.
    let near = 0.02 * (d_to - d_from).abs();
    let mut a = cross;
    while a > 0 && (rec.d_mm[a] - d_from).abs() > tol {
        a -= 1;
    }
    let mut b = cross;
    while b + 1 < rec.len() && (rec.d_mm[b] - d_to).abs() > tol {
        b += 1;
    }
    let level_from = rec
        .median(rec.t_s[a] - 0.15, rec.t_s[a] - 0.05)
        .unwrap_or(d_from);
    let level_to = rec
        .median(rec.t_s[b] + 0.05, rec.t_s[b] + 0.15)
        .unwrap_or(d_to);
    let mut a = cross;
    while a > 0 && (rec.d_mm[a] - level_from).abs() > near {
        a -= 1;
    }
    let mut b = cross;
    while b + 1 < rec.len() && (rec.d_mm[b] - level_to).abs() > near {
        b += 1;
    }
    // The 2 % points lie up to LEAD_S inside the motion (at 100 mm/s², 28 ms after the start):
    // the standstill before the ramp ends LEAD_S before the first one, and the one after it
    // begins LEAD_S after the second. The plateaus' levels are taken there; the fit runs from
    // `before_s` before the motion to `after_s` after it — on the side of an arc, from the 2 %
    // point itself, so that none of the arc gets in.
    const LEAD_S: f64 = 0.03;
    let (ta, tb) = (rec.t_s[a], rec.t_s[b]);
    let d0 = rec.median(ta - LEAD_S - before_s.max(0.005), ta - LEAD_S)?;
    let d1 = rec.median(tb + LEAD_S, tb + LEAD_S + 0.25)?;
    if (d0 - d_from).abs() > tol || (d1 - d_to).abs() > tol {
        return None;
    }
    let fit_from = if before_s > 0.01 {
        ta - LEAD_S - before_s
    } else {
        ta - before_s
    };
    let fit_to = if after_s > 0.01 {
        tb + LEAD_S + after_s
    } else {
        tb + after_s
    };
    let (i, j) = (rec.index_at(fit_from), rec.index_at(fit_to));
    // s from D: |from + s·e| = D on the line, D offset to the plateau before the ramp.
    let e = [
        (to[0] - from[0]) / len,
        (to[1] - from[1]) / len,
        (to[2] - from[2]) / len,
    ];
    let bb = e[0] * from[0] + e[1] * from[1] + e[2] * from[2];
    let cc = from[0] * from[0] + from[1] * from[1] + from[2] * from[2];
    let along = |dn: f64| {
        let disc = (bb * bb - cc + dn * dn).max(0.0).sqrt();
        let r1 = -bb + disc;
        let r2 = -bb - disc;
        let pick = if (r1 - len / 2.0).abs() < (r2 - len / 2.0).abs() {
            r1
        } else {
            r2
        };
        pick.clamp(-0.1 * len, 1.1 * len)
    };
    let t: Vec<f64> = rec.t_s[i..j].to_vec();
    let mut s: Vec<f64> = rec.d_mm[i..j]
        .iter()
        .map(|&d| along(d_from + (d - d0)))
        .collect();
    // D is read through the machine's errors at each point of the line, as far as the diagnosis
    // knows them: take them off, relative to the line's start where the plateau `d0` was taken.
    if let Some(r) = ruler {
        let at = |x: f64| {
            [
                from[0] + x.clamp(0.0, len) * e[0],
                from[1] + x.clamp(0.0, len) * e[1],
                from[2] + x.clamp(0.0, len) * e[2],
            ]
        };
        let mut points: Vec<[f64; 3]> = s.iter().map(|&x| at(x)).collect();
        points.push(from);
        let err = (r.error_mm)(&points);
        let err0 = err[err.len() - 1];
        for (k, x) in s.iter_mut().enumerate() {
            *x = along(d_from + (rec.d_mm[i + k] - d0) - (err[k] - err0));
        }
    }
    // Start: the speed through the midpoint (slope over ±5 ms) and the acceleration that reaches
    // it between leaving D_from and the midpoint.
    let slope = {
        let (p, q) = (
            rec.index_at(rec.t_s[cross] - 0.005),
            rec.index_at(rec.t_s[cross] + 0.005),
        );
        let q = q.min(rec.len() - 1);
        if q > p {
            ((rec.d_mm[q] - rec.d_mm[p]) / (rec.t_s[q] - rec.t_s[p])).abs()
        } else {
            feed_mm_s
        }
    };
    let v0 = if slope.is_finite() && slope > 0.0 {
        slope.min(5.0 * feed_mm_s.max(1e-3))
    } else {
        feed_mm_s.max(1e-3)
    };
    let to_mid = (rec.t_s[cross] - ta).max(1e-3);
    let a0 = (v0 / to_mid).max(1.0) * 2.0;
    // A second start for a fast machine: the ramp cruises at about the feed (along the line: D
    // moves slower than s where the line is not radial) and the time it takes beyond len/v is
    // v/a. The fit keeps whichever start ends with the smaller residual.
    let v1 = {
        let ratio = len / (d_to - d_from).abs().max(1e-9);
        let v = slope * ratio;
        if v.is_finite() && v > 0.0 {
            v.min(5.0 * feed_mm_s.max(1e-3))
        } else {
            feed_mm_s.max(1e-3)
        }
    };
    let spare = (tb - ta) - len / v1;
    let a1 = (v1 / spare.max(1e-3)).clamp(1.0, 1e5);
    let prob = RampProblem { t: &t, s: &s };
    let starts = [
        [ta - 0.5 * v0 / a0, v0, a0, len],
        [ta - 0.5 * v1 / a1, v1, a1, len],
    ];
    let (fit, profile) = starts
        .iter()
        .filter_map(|p0| {
            let fit = least_squares(
                &prob,
                p0,
                &LsqOptions {
                    max_iterations: 80,
                    tolerance: 1e-10,
                    initial_lambda: 1e-3,
                    ..Default::default()
                },
            )
            .ok()?;
            let profile = RampProblem::profile(&fit.params);
            ((profile.length_mm - len).abs() <= tol).then_some((fit, profile))
        })
        .min_by(|x, y| x.0.rms.total_cmp(&y.0.rms))?;
    let plain = Ramp {
        profile,
        speed_sigma_mm_s: fit.sigma[1].unwrap_or(f64::INFINITY),
        rms_um: fit.rms,
        samples: t.len(),
        lag_s: 0.0,
    };
    // The ramp read as the command through a position loop's lag ([`loop_lag::fit_through_loop`])
    // is built but not used: on the tests' feed sweep under Kv 40 loops without feed-forward it
    // moved the timeline so that a false 0.74 ± 0.21 µm reversal spike of Y was named, and it has
    // not been measured on the null sweep (issue 26, docs/synchronisation.md).
    Some(plain)
}
