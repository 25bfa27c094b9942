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
    let problem = Limacon {
        trig: angle_rad.iter().map(|a| a.sin_cos()).collect(),
        dev_um,
    };
    let lo = dev_um.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = dev_um.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let opts = MinimaxOptions {
        tolerance: 1e-12,
        ..Default::default()
    };
    let fit = minimax(&problem, &[0.5 * (lo + hi), 0.0, 0.0], &opts)?;
    Ok(MinimumZone {
        centre_um: [fit.params[1], fit.params[2]],
        radius_offset_um: fit.params[0],
        width_um: 2.0 * fit.max_abs_residual,
    })
}

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
    fn too_few_points_are_refused() {
        assert!(minimum_zone(&[0.0, 1.0, 2.0], &[0.0, 0.1, 0.2]).is_err());
        assert!(minimum_zone(&[0.0, 1.0, 2.0, 3.0], &[0.0, f64::NAN, 0.2, 0.1]).is_err());
    }
}
