//! The minimum-zone circle (MZC) of a nearly circular trace: the two concentric circles, closest
//! together, that enclose every point. Their radial separation is the roundness of the trace;
//! ISO 230-4's circular deviation G is that separation for one circle in one direction.
//!
//! Method: a ballbar trace deviates from its nominal circle by micrometres at a radius of tens of
//! millimetres, so moving the centre by (a, b) changes the radial deviation at angle θ by
//! −(a·cos θ + b·sin θ) to first order (the limaçon linearisation; the neglected term is
//! (a² + b²)/(2R), below 1e-5 µm for a 3 µm shift at R = 50 mm). With a mean radius offset r₀
//! the zone is then a Chebyshev (L∞) fit, a linear program:
//!
//! ```text
//!   minimise t  subject to  |dev_i − r₀ − a·cos θ_i − b·sin θ_i| ≤ t  (all i);   width = 2t
//! ```
//!
//! solved by the project's minimax engine ([`super::minimax`], an exchange active set with an
//! LP step via clarabel), which lands on the exact Chebyshev solution of a linear problem. At
//! the optimum at least four points touch the two circles, alternating outer and inner around
//! the circle (the classical optimality condition; checked in the tests together with known
//! answers and a brute-force search).
use super::lsq::Problem;
use super::minimax::{minimax, MinimaxOptions};
use crate::{Error, Result};

/// The minimum zone of a trace given as radial deviations (µm) at angles (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MinimumZone {
    /// Centre of the zone relative to the centre the deviations were measured from, µm, along
    /// the plane's first and second axis (θ = 0 and θ = 90°).
    pub centre_um: [f64; 2],
    /// Mean radius of the two circles minus the reference radius, µm.
    pub radius_offset_um: f64,
    /// Radial separation of the two circles, µm: the roundness (G of ISO 230-4 for one run).
    pub width_um: f64,
}

/// The limaçon residuals dev_i − r₀ − a·cos θ_i − b·sin θ_i as a [`Problem`] in (r₀, a, b).
struct Limacon<'a> {
    trig: Vec<(f64, f64)>,
    dev_um: &'a [f64],
}

impl Problem for Limacon<'_> {
    fn n_params(&self) -> usize {
        3
    }
    fn n_residuals(&self) -> usize {
        self.dev_um.len()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        for (i, (&(s, c), &d)) in self.trig.iter().zip(self.dev_um).enumerate() {
            visit(i, d - p[0] - p[1] * c - p[2] * s, &[-1.0, -c, -s]);
        }
    }
}

/// The minimum-zone circle of the radial deviations `dev_um` (µm) at angles `angle_rad`
/// (see the module docs). Needs at least 4 points spread over more than a half circle's
/// worth of directions for a unique centre; fewer points are refused.
pub fn minimum_zone(angle_rad: &[f64], dev_um: &[f64]) -> Result<MinimumZone> {
    if angle_rad.len() != dev_um.len() || dev_um.len() < 4 {
        return Err(Error::Numerics(format!(
            "a minimum-zone circle needs at least 4 points with an angle each (got {} angles, {} deviations)",
            angle_rad.len(),
            dev_um.len()
        )));
    }
    if dev_um.iter().chain(angle_rad).any(|x| !x.is_finite()) {
        return Err(Error::Numerics(
            "a minimum-zone circle needs finite angles and deviations".into(),
        ));
    }
    // Only points at the edges of the trace can touch the zone: solve on the highest and lowest
    // point of each 1° of angle, then add every point the zone does not hold and solve again
    // until it holds them all (the answer is that of all points; the subset only saves time).
    let n = dev_um.len();
    let binned = n > 4 * EDGE_BINS;
    let width = std::f64::consts::TAU / EDGE_BINS as f64;
    let bin_of =
        |a: f64| ((a.rem_euclid(std::f64::consts::TAU) / width) as usize).min(EDGE_BINS - 1);
    let mut bins: Vec<u16> = vec![];
    let mut hi_of = vec![usize::MAX; EDGE_BINS];
    let mut lo_of = vec![usize::MAX; EDGE_BINS];
    let mut subset: Vec<usize> = if binned {
        bins.reserve_exact(n);
        for (i, (&a, &d)) in angle_rad.iter().zip(dev_um).enumerate() {
            let bin = bin_of(a);
            bins.push(bin as u16);
            if hi_of[bin] == usize::MAX || d > dev_um[hi_of[bin]] {
                hi_of[bin] = i;
            }
            if lo_of[bin] == usize::MAX || d < dev_um[lo_of[bin]] {
                lo_of[bin] = i;
            }
        }
        let mut v: Vec<usize> = hi_of
            .iter()
            .chain(&lo_of)
            .copied()
            .filter(|&i| i != usize::MAX)
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    } else {
        (0..n).collect()
    };
    // sin, cos of the points' angles, made when a point is first needed (NaN until then): on a
    // long trace most points lie in bins the zone holds whole and never need them.
    let mut trig: Vec<(f64, f64)> = vec![(f64::NAN, f64::NAN); n];
    for &i in &subset {
        trig[i] = angle_rad[i].sin_cos();
    }
    loop {
        let (p, t) = match exchange(angle_rad, &trig, dev_um, &subset) {
            Some(fit) => fit,
            None => chebyshev(&trig, dev_um, &subset)?,
        };
        let tol = t * (1.0 + 1e-9) + 1e-12;
        // A bin is held whole when its highest and lowest points are held with room for the
        // largest change of r₀ + a·cos θ + b·sin θ across the bin: |(a, b)|·(half a bin).
        let slack = p[1].hypot(p[2]) * 0.5 * width;
        let whole: Vec<bool> = (0..EDGE_BINS)
            .map(|b| {
                binned && hi_of[b] != usize::MAX && {
                    let (s, c) = ((b as f64 + 0.5) * width).sin_cos();
                    let m = p[0] + p[1] * c + p[2] * s;
                    dev_um[hi_of[b]] - m + slack <= tol && m - dev_um[lo_of[b]] + slack <= tol
                }
            })
            .collect();
        let mut outside: Vec<usize> = vec![];
        for i in 0..n {
            if binned && whole[bins[i] as usize] {
                continue;
            }
            if trig[i].0.is_nan() {
                trig[i] = angle_rad[i].sin_cos();
            }
            let (s, c) = trig[i];
            if (dev_um[i] - p[0] - p[1] * c - p[2] * s).abs() > tol {
                outside.push(i);
            }
        }
        if outside.is_empty() || subset.len() == n {
            return Ok(MinimumZone {
                centre_um: [p[1], p[2]],
                radius_offset_um: p[0],
                width_um: 2.0 * t,
            });
        }
        subset.extend(outside);
        subset.sort_unstable();
        subset.dedup();
    }
}

/// The limaçon's Chebyshev fit on the points `subset` by Stiefel's exchange (the discrete Remez
/// algorithm): {1, cos θ, sin θ} is a Haar system on the circle, so the best fit is the one
/// whose residuals reach ±t, alternating in sign, at four points in angular order. Start from
/// four points spread over the angles, solve r_j = ±h exactly on them, bring in the point with
/// the largest residual in place of the neighbour (cyclically, in angle) whose residual has the
/// same sign, until no point exceeds |h|. |h| grows at every exchange. None if a reference is
/// singular or it does not settle (the LP engine then answers).
fn exchange(
    angle_rad: &[f64],
    trig: &[(f64, f64)],
    dev_um: &[f64],
    subset: &[usize],
) -> Option<([f64; 3], f64)> {
    use nalgebra::{Matrix4, Vector4};
    let mut order: Vec<usize> = subset.to_vec();
    let angle = |i: usize| angle_rad[i].rem_euclid(std::f64::consts::TAU);
    order.sort_by(|&a, &b| angle(a).total_cmp(&angle(b)));
    let n = order.len();
    if n < 4 {
        return None;
    }
    // Reference as positions in `order` (sorted), signs alternating from +.
    let mut refs = [0, n / 4, n / 2, 3 * n / 4];
    for _ in 0..500 {
        let m = Matrix4::from_fn(|j, k| {
            let (s, c) = trig[order[refs[j]]];
            match k {
                0 => 1.0,
                1 => c,
                2 => s,
                _ => {
                    if j.is_multiple_of(2) {
                        1.0
                    } else {
                        -1.0
                    }
                }
            }
        });
        let rhs = Vector4::from_fn(|j, _| dev_um[order[refs[j]]]);
        let x = m.lu().solve(&rhs)?;
        let (p, h) = ([x[0], x[1], x[2]], x[3]);
        if !(p.iter().all(|v| v.is_finite()) && h.is_finite()) {
            return None;
        }
        let res = |pos: usize| {
            let i = order[pos];
            let (s, c) = trig[i];
            dev_um[i] - p[0] - p[1] * c - p[2] * s
        };
        let (worst, r) = (0..n)
            .map(|pos| (pos, res(pos)))
            .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))?;
        let t = r.abs();
        if t <= h.abs() * (1.0 + 1e-12) + 1e-13 {
            return Some((p, h.abs().max(t)));
        }
        if refs.contains(&worst) {
            return None;
        }
        // The references stay in cyclic angular order (a rotation of the sorted order), so the
        // pattern +h, −h, +h, −h by index alternates around the circle. The new point takes the
        // place of the neighbour whose residual has its sign: the order and the alternation stay.
        let sign_at = |j: usize| if j.is_multiple_of(2) { h } else { -h }.signum();
        let after = (0..4)
            .filter(|&j| refs[j] > worst)
            .min_by_key(|&j| refs[j])
            .or_else(|| (0..4).min_by_key(|&j| refs[j]))?;
        let before = (after + 3) % 4;
        let replace = if sign_at(before) == r.signum() {
            before
        } else {
            after
        };
        refs[replace] = worst;
    }
    None
}

/// The limaçon's Chebyshev fit on the points `subset`: ((r₀, a, b), the largest |residual|).
fn chebyshev(trig: &[(f64, f64)], dev_um: &[f64], subset: &[usize]) -> Result<([f64; 3], f64)> {
    let dev: Vec<f64> = subset.iter().map(|&i| dev_um[i]).collect();
    let problem = Limacon {
        trig: subset.iter().map(|&i| trig[i]).collect(),
        dev_um: &dev,
    };
    let lo = dev.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = dev.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let opts = MinimaxOptions {
        tolerance: 1e-12,
        ..Default::default()
    };
    let fit = minimax(&problem, &[0.5 * (lo + hi), 0.0, 0.0], &opts)?;
    Ok((
        [fit.params[0], fit.params[1], fit.params[2]],
        fit.max_abs_residual,
    ))
}

/// Bins of angle (1° each) whose highest and lowest points start [`minimum_zone`]'s search on a
/// long trace.
const EDGE_BINS: usize = 360;

/// Peak-to-valley (µm) of the deviations about a given centre shift (a, b) µm: the zone width
/// that centre gives. The minimum zone minimises this over (a, b).
pub fn zone_width_about(angle_rad: &[f64], dev_um: &[f64], centre_um: [f64; 2]) -> f64 {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for (&a, &d) in angle_rad.iter().zip(dev_um) {
        let (s, c) = a.sin_cos();
        let r = d - centre_um[0] * c - centre_um[1] * s;
        lo = lo.min(r);
        hi = hi.max(r);
    }
    hi - lo
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Points alternately on two concentric circles of radius offsets r1 < r2 (µm) about the
    /// centre (cx, cy) µm, seen from the origin, at R = 50 mm, exactly (no linearisation):
    /// the radial deviation from the nominal 50 mm circle about the origin.
    fn two_circles(n: usize, r1: f64, r2: f64, cx: f64, cy: f64) -> (Vec<f64>, Vec<f64>) {
        let big_r = 50_000.0; // µm
        let mut ang = vec![];
        let mut dev = vec![];
        for k in 0..n {
            let phi = std::f64::consts::TAU * (k as f64 + 0.37) / n as f64;
            let r = big_r + if k % 2 == 0 { r1 } else { r2 };
            let (x, y) = (cx + r * phi.cos(), cy + r * phi.sin());
            ang.push(y.atan2(x));
            dev.push(x.hypot(y) - big_r);
        }
        (ang, dev)
    }

    #[test]
    fn concentric_circles_give_their_separation_and_centre() {
        // Known answer: every point lies on one of two concentric circles 3 µm apart, centre
        // off by (4, −2.5) µm. The zone is exactly those circles.
        let (ang, dev) = two_circles(720, -1.0, 2.0, 4.0, -2.5);
        let z = minimum_zone(&ang, &dev).unwrap();
        // Tolerance: the limaçon's neglected term |c|²/(2R) = 2.2e-4 µm here.
        assert!((z.width_um - 3.0).abs() < 1e-3, "{z:?}");
        assert!((z.centre_um[0] - 4.0).abs() < 1e-3 && (z.centre_um[1] + 2.5).abs() < 1e-3);
        assert!((z.radius_offset_um - 0.5).abs() < 1e-3);
        // A least-squares centre of the same points is the same here (symmetric); the width
        // about the origin is much larger (the eccentricity is not removed).
        assert!(zone_width_about(&ang, &dev, [0.0, 0.0]) > 10.0);
    }

    #[test]
    fn minimum_zone_is_narrower_than_least_squares_and_beats_brute_force() {
        // A lobed trace with a flat: the least-squares and minimum-zone centres differ.
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let n = 2000;
        let ang: Vec<f64> = (0..n)
            .map(|k| std::f64::consts::TAU * k as f64 / n as f64)
            .collect();
        let dev: Vec<f64> = ang
            .iter()
            .map(|&a| {
                2.0 * (3.0 * a + 0.4).sin()
                    + 1.5 * (2.0 * a).cos()
                    + if a.cos() > 0.9 { -3.0 } else { 0.0 }
                    + 0.8 * a.cos()
                    + rng.gen_range(-0.2..0.2)
            })
            .collect();
        let z = minimum_zone(&ang, &dev).unwrap();
        assert!(
            (zone_width_about(&ang, &dev, z.centre_um) - z.width_um).abs() < 1e-8,
            "the reported width is the peak-to-valley about the reported centre"
        );
        // Brute force: a grid over centres ±4 µm, then a finer grid around the best.
        let mut best = (f64::INFINITY, [0.0, 0.0]);
        let mut span = 4.0;
        let mut at = [0.0, 0.0];
        for _ in 0..6 {
            for i in -40..=40 {
                for j in -40..=40 {
                    let c = [
                        at[0] + span * i as f64 / 40.0,
                        at[1] + span * j as f64 / 40.0,
                    ];
                    let w = zone_width_about(&ang, &dev, c);
                    if w < best.0 {
                        best = (w, c);
                    }
                }
            }
            at = best.1;
            span /= 10.0;
        }
        assert!(
            z.width_um <= best.0 + 1e-7,
            "LP {} vs brute force {}",
            z.width_um,
            best.0
        );
        assert!(best.0 - z.width_um < 1e-6, "brute force reaches it too");
        // Optimality: ≥ 4 contact points alternating outer/inner around the circle.
        let r: Vec<f64> = ang
            .iter()
            .zip(&dev)
            .map(|(&a, &d)| d - z.centre_um[0] * a.cos() - z.centre_um[1] * a.sin())
            .collect();
        let hi = r.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let lo = r.iter().cloned().fold(f64::INFINITY, f64::min);
        let contacts: Vec<bool> = r
            .iter()
            .filter_map(|&x| {
                if hi - x < 1e-6 {
                    Some(true)
                } else if x - lo < 1e-6 {
                    Some(false)
                } else {
                    None
                }
            })
            .collect();
        let mut changes = 0;
        for k in 0..contacts.len() {
            if contacts[k] != contacts[(k + 1) % contacts.len()] {
                changes += 1;
            }
        }
        assert!(changes >= 4, "contacts {contacts:?}");
    }

    #[test]
    fn a_long_trace_gives_the_zone_of_all_its_points() {
        // 20 000 points (the edges-first search): the same zone as the fit on every point, and
        // every point inside it.
        let mut rng = rand::rngs::StdRng::seed_from_u64(9);
        let n = 20_000;
        let angle: Vec<f64> = (0..n)
            .map(|i| std::f64::consts::TAU * i as f64 / n as f64)
            .collect();
        let dev: Vec<f64> = angle
            .iter()
            .map(|&a| {
                3.0 * (2.0 * a).cos() + 1.5 * a.cos() - 0.7 * a.sin()
                    + 0.4 * rng.gen_range(-1.0..1.0)
            })
            .collect();
        let z = minimum_zone(&angle, &dev).unwrap();
        let trig: Vec<(f64, f64)> = angle.iter().map(|a| a.sin_cos()).collect();
        let all: Vec<usize> = (0..n).collect();
        let (p, t) = chebyshev(&trig, &dev, &all).unwrap();
        assert!(
            (z.width_um - 2.0 * t).abs() < 1e-9,
            "{} vs {}",
            z.width_um,
            2.0 * t
        );
        assert!((z.centre_um[0] - p[1]).abs() < 1e-6 && (z.centre_um[1] - p[2]).abs() < 1e-6);
        let w = zone_width_about(&angle, &dev, z.centre_um);
        assert!((w - z.width_um).abs() < 1e-9, "{w} vs {}", z.width_um);
    }

    #[test]
    fn the_exchange_lands_on_the_linear_programs_answer() {
        // Random traces on full circles and on a 220° arc: Stiefel's exchange must find the
        // zone itself (not fall back to the LP) and agree with the LP engine.
        let mut rng = rand::rngs::StdRng::seed_from_u64(21);
        for case in 0..40 {
            let n = 300 + 37 * case;
            let (lo, span) = if case % 2 == 0 {
                (0.0, std::f64::consts::TAU)
            } else {
                ((-20.0f64).to_radians(), 220.0f64.to_radians())
            };
            let angle: Vec<f64> = (0..n).map(|_| lo + span * rng.gen::<f64>()).collect();
            let (a2, e) = (rng.gen_range(-3.0..3.0), rng.gen_range(-2.0..2.0));
            let dev: Vec<f64> = angle
                .iter()
                .map(|&a| a2 * (2.0 * a).cos() + e * a.sin() + rng.gen_range(-0.5..0.5))
                .collect();
            let trig: Vec<(f64, f64)> = angle.iter().map(|a| a.sin_cos()).collect();
            let all: Vec<usize> = (0..n).collect();
            let (p, t) = exchange(&angle, &trig, &dev, &all).expect("the exchange settles");
            let (q, u) = chebyshev(&trig, &dev, &all).unwrap();
            assert!((t - u).abs() < 1e-9 * (1.0 + u), "case {case}: {t} vs {u}");
            for k in 0..3 {
                assert!((p[k] - q[k]).abs() < 1e-6, "case {case}: {p:?} vs {q:?}");
            }
        }
    }

    #[test]
    fn too_few_points_are_refused() {
        assert!(minimum_zone(&[0.0, 1.0, 2.0], &[0.0, 0.1, 0.2]).is_err());
        assert!(minimum_zone(&[0.0, 1.0, 2.0, 3.0], &[0.0, f64::NAN, 0.2, 0.1]).is_err());
    }
}
