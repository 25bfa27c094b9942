//! Placing the two balls so that the RRSS motion covers a required A range (seed 004 §3.2, §5.1).
//!
//! The paper's saddle programmes (eq. 18-19) fit a sphere, minimax, to the trajectory of a
//! table point over *given* positions (θ1⁽ⁱ⁾, θ2⁽ⁱ⁾), then move the point to make that error
//! smallest under constraints g1–g13. The positions it used are not printed, so that programme
//! cannot be re-run as such. What its result (Table 2) satisfies can be stated exactly, and this
//! module solves those conditions instead ("dead-point synthesis"):
//!
//! 1. the rocker's lower dead point (eq. 13-15) is at the required A minimum,
//! 2. its upper dead point is at the required A maximum,
//! 3. the lower dead point occurs at C = 0 (this fixes θC0, which does not change the A range),
//! 4. the bar length d is the shortest at which C still turns fully (the two branches touch; the
//!    discriminant of eq. 9 vanishes at one C angle, cf. eq. 12) — Table 2's parameters sit there
//!    to within the rounding of its printed digits.
//!
//! Unknowns are the spindle-ball position (s0, a0, θA0) and θC0; the table-ball position
//! (s2, a2) and the axes (a1, α12) are given (constraints g10-g12: the ball on the table within
//! its radius and height limits, which the user picks). d comes from the bar-length series (g13:
//! the user gives one of its lengths). Not implemented: g1-g3 (ball-joint angle limits and
//! bar/table collision) and g4-g9 (spindle travel), which need machine geometry the paper does not
//! give in numbers.
use super::design::design_with_grid;
use super::Params;
use crate::fit::{least_squares, LsqOptions, Problem};
use crate::{Error, Result};

/// Scan density for the synthesis (dead points are refined beyond it by bisection).
const GRID: usize = 3600;

/// The four conditions (see module doc) as residuals in mm-like units: angles × 100 mm.
struct DeadPointSynthesis {
    fixed: Params,
    d_mm: f64,
    a_min_rad: f64,
    a_max_rad: f64,
}

const LEVER_MM: f64 = 100.0;

impl DeadPointSynthesis {
    fn params(&self, x: &[f64]) -> Params {
        let mut p = self.fixed;
        p.s0_mm = x[0];
        p.a0_mm = x[1];
        p.theta_a0_rad = x[2];
        p.theta_c0_rad = x[3];
        p
    }

    fn residuals(&self, x: &[f64]) -> Option<[f64; 4]> {
        let p = self.params(x);
        let des = design_with_grid(&p, self.d_mm, GRID);
        let dead = des.branches.iter().flat_map(|b| b.dead_points.iter());
        let lo = dead
            .clone()
            .filter(|d| d.kind == "min")
            .min_by(|a, b| a.theta_a_deg.total_cmp(&b.theta_a_deg))?;
        let hi = dead
            .filter(|d| d.kind == "max")
            .max_by(|a, b| a.theta_a_deg.total_cmp(&b.theta_a_deg))?;
        let [d_lo, _] = des.d_full_turn_mm?;
        let c_at_lo = (lo.theta_c_deg + 180.0).rem_euclid(360.0) - 180.0;
        Some([
            (lo.theta_a_deg.to_radians() - self.a_min_rad) * LEVER_MM,
            (hi.theta_a_deg.to_radians() - self.a_max_rad) * LEVER_MM,
            c_at_lo.to_radians() * LEVER_MM,
            d_lo - self.d_mm,
        ])
    }
}

impl Problem for DeadPointSynthesis {
    fn n_params(&self) -> usize {
        4
    }
    fn n_residuals(&self) -> usize {
        4
    }
    fn eval(&self, x: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let Some(r0) = self.residuals(x) else {
            for i in 0..4 {
                visit(i, f64::NAN, &[0.0; 4]);
            }
            return;
        };
        // Central differences: each residual comes out of a scan and refinement, not a formula.
        let mut jac = [[0.0; 4]; 4];
        let steps = [1e-4, 1e-4, 1e-7, 1e-7];
        for k in 0..4 {
            let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
            xp[k] += steps[k];
            xm[k] -= steps[k];
            match (self.residuals(&xp), self.residuals(&xm)) {
                (Some(rp), Some(rm)) => {
                    for i in 0..4 {
                        jac[i][k] = (rp[i] - rm[i]) / (2.0 * steps[k]);
                    }
                }
                _ => {
                    for row in jac.iter_mut() {
                        row[k] = f64::NAN;
                    }
                }
            }
        }
        for i in 0..4 {
            visit(i, r0[i], &jac[i]);
        }
    }
}

/// Result of [`synthesize`].
#[derive(Debug, Clone)]
pub struct Synthesis {
    pub params: Params,
    /// Largest |residual| of the four conditions (mm; angles × 100 mm).
    pub max_condition_mm: f64,
    pub iterations: usize,
}

/// Find s0, a0, θA0, θC0 (starting from `start`; s2, a2, a1, α12 taken from it and held) so that
/// the motion at bar length `d_mm` has its dead points at `a_range_deg`, the lower one at C = 0,
/// and the branches just touching (see module doc).
pub fn synthesize(start: &Params, d_mm: f64, a_range_deg: [f64; 2]) -> Result<Synthesis> {
    let prob = DeadPointSynthesis {
        fixed: *start,
        d_mm,
        a_min_rad: a_range_deg[0].min(a_range_deg[1]).to_radians(),
        a_max_rad: a_range_deg[0].max(a_range_deg[1]).to_radians(),
    };
    let x0 = [
        start.s0_mm,
        start.a0_mm,
        start.theta_a0_rad,
        start.theta_c0_rad,
    ];
    if prob.residuals(&x0).is_none() {
        return Err(Error::Numerics(
            "the start parameters give no rocker dead points or no bar length at which C turns fully; start nearer a working design"
                .into(),
        ));
    }
    let fit = least_squares(
        &prob,
        &x0,
        &LsqOptions {
            max_iterations: 60,
            tolerance: 1e-14,
            ..LsqOptions::default()
        },
    )?;
    let r = prob.residuals(&fit.params).ok_or_else(|| {
        Error::Numerics("synthesis left the region where the motion has dead points".into())
    })?;
    let max = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if max > 1e-4 {
        return Err(Error::Numerics(format!(
            "dead-point synthesis did not converge (conditions off by {max:.2e} mm); try another start or A range"
        )));
    }
    Ok(Synthesis {
        params: prob.params(&fit.params),
        max_condition_mm: max,
        iterations: fit.iterations,
    })
}
