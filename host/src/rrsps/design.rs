//! Motion design of the RRSS linkage (seed 004 §3, eq. 9-15): with the bar length held at d, the
//! A angle as a function of the C angle on each of the two branches, the dead points, whether C
//! turns fully, and the A range (Table 2).
//!
//! Eq. (9) is linear in sin θ1 and cos θ1: A sin θ1 + B cos θ1 + C = 0, so with
//! φ = atan2(A, B) and R = √(A² + B²), θ1 = φ ± arccos(−C/R). The sign picks the branch; where
//! |C| > R there is no position for that θ2 (C cannot pass), and where |C| = R the two branches
//! meet. Since C = K(θ2) − d², C turns fully on both branches exactly when
//! max(K − R) ≤ d² ≤ min(K + R) over θ2; [`Design::d_full_turn_mm`] reports that interval.
use std::f64::consts::{PI, TAU};

use super::Params;

/// Eq. (9): the coefficients (A, B, C) of A sin θ1 + B cos θ1 + C = 0 for link angle θ2.
pub fn eq9(p: &Params, d_mm: f64, theta2_rad: f64) -> (f64, f64, f64) {
    let (sa, ca) = p.alpha12_rad.sin_cos();
    let (s2, c2) = theta2_rad.sin_cos();
    let (a0, a1, a2, sz2) = (p.a0_mm, p.a1_mm, p.a2_mm, p.s2_mm);
    let a = 2.0 * a0 * a2 * ca * s2 - 2.0 * a0 * sz2 * sa;
    let b = -2.0 * a0 * a2 * c2 - 2.0 * a0 * a1;
    let c = k_of(p, theta2_rad) - d_mm * d_mm;
    (a, b, c)
}

/// C + d² of eq. (9): the part of C that does not depend on d.
fn k_of(p: &Params, theta2_rad: f64) -> f64 {
    let (sa, ca) = p.alpha12_rad.sin_cos();
    let (s2, c2) = theta2_rad.sin_cos();
    let (a0, a1, a2, s0, sz2) = (p.a0_mm, p.a1_mm, p.a2_mm, p.s0_mm, p.s2_mm);
    a0 * a0 + a1 * a1 + a2 * a2 + s0 * s0 + sz2 * sz2
        - 2.0 * s0 * sz2 * ca
        - 2.0 * a2 * s0 * sa * s2
        + 2.0 * a1 * a2 * c2
}

/// The branch of eq. (9): θ1 = φ + sign·arccos(−C/R).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Branch {
    Plus,
    Minus,
}

impl Branch {
    pub const BOTH: [Branch; 2] = [Branch::Plus, Branch::Minus];
    pub fn sign(self) -> f64 {
        match self {
            Branch::Plus => 1.0,
            Branch::Minus => -1.0,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Branch::Plus => "plus",
            Branch::Minus => "minus",
        }
    }
}

/// The machine A angle (rad) that keeps the bar at d for machine C angle θC on `branch`
/// (eq. 9 then eq. 11), or None where C cannot reach θC with this bar length.
pub fn theta_a_for(p: &Params, d_mm: f64, theta_c_rad: f64, branch: Branch) -> Option<f64> {
    let (_, theta2) = p.link_angles(0.0, theta_c_rad);
    let (a, b, c) = eq9(p, d_mm, theta2);
    let r = a.hypot(b);
    if r.is_nan() || r <= 0.0 || c.abs() > r {
        return None;
    }
    let theta1 = a.atan2(b) + branch.sign() * (-c / r).clamp(-1.0, 1.0).acos();
    let (theta_a, _) = p.machine_angles(theta1, theta2);
    Some(wrap_pi(theta_a))
}

/// Eq. (15): the triple product (z1, x2, R_EF), zero at a dead (extreme) position of the A rocker.
pub fn eq15(p: &Params, theta1_rad: f64, theta2_rad: f64) -> f64 {
    let (sa, ca) = p.alpha12_rad.sin_cos();
    let (s1, c1) = theta1_rad.sin_cos();
    let (s2, c2) = theta2_rad.sin_cos();
    p.a0_mm * c1 * s2 - p.a1_mm * s2 - p.s0_mm * sa * c2 + p.a0_mm * ca * s1 * c2
}

fn wrap_pi(x: f64) -> f64 {
    let y = (x + PI).rem_euclid(TAU) - PI;
    if y == -PI {
        PI
    } else {
        y
    }
}

/// An extreme position of the A rocker (eq. 13): dθA/dθC = 0.
#[derive(Debug, Clone, PartialEq)]
pub struct DeadPoint {
    pub theta_c_deg: f64,
    pub theta_a_deg: f64,
    /// "max" or "min" of θA.
    pub kind: &'static str,
    /// Eq. (15) at this point (mm): a check that the point found numerically is a dead point.
    pub eq15_mm: f64,
}

/// The motion on one branch.
#[derive(Debug, Clone, PartialEq)]
pub struct BranchMotion {
    pub branch: Branch,
    /// True when every θC in 0..360° has a position on this branch.
    pub c_full_turn: bool,
    /// θC intervals (degrees, machine C) with no position: C stops at their ends, where the two
    /// branches meet (|C| = R in eq. 9).
    pub c_blocked_deg: Vec<[f64; 2]>,
    /// A range reached on this branch (machine A, degrees), None if the branch is empty.
    pub a_range_deg: Option<[f64; 2]>,
    /// Smooth extremes of θA(θC) (eq. 13-15), not counting the ends at blocked intervals.
    pub dead_points: Vec<DeadPoint>,
}

/// The motion design for one parameter set and bar length.
#[derive(Debug, Clone, PartialEq)]
pub struct Design {
    pub d_mm: f64,
    pub branches: Vec<BranchMotion>,
    /// Union of the branches' A ranges (degrees).
    pub a_range_deg: Option<[f64; 2]>,
    /// The bar lengths for which C turns fully on both branches, if any.
    pub d_full_turn_mm: Option<[f64; 2]>,
}

/// Grid step for scanning θC: 0.01°.
const GRID: usize = 36_000;

/// Design the constant-length motion (eq. 9-15) for parameters `p` and bar length `d_mm`.
pub fn design(p: &Params, d_mm: f64) -> Design {
    design_with_grid(p, d_mm, GRID)
}

/// [`design`] scanning θC on `grid` points (dead points and limits are refined beyond the grid).
pub fn design_with_grid(p: &Params, d_mm: f64, grid: usize) -> Design {
    let grid = grid.max(360);
    let step = TAU / grid as f64;
    let branches: Vec<BranchMotion> = Branch::BOTH
        .iter()
        .map(|&b| branch_motion(p, d_mm, b, step, grid))
        .collect();
    let a_range_deg = branches
        .iter()
        .filter_map(|b| b.a_range_deg)
        .reduce(|x, y| [x[0].min(y[0]), x[1].max(y[1])]);
    Design {
        d_mm,
        branches,
        a_range_deg,
        d_full_turn_mm: d_full_turn(p, step, grid),
    }
}

fn branch_motion(p: &Params, d: f64, branch: Branch, step: f64, grid: usize) -> BranchMotion {
    let at = |k: usize| theta_a_for(p, d, k as f64 * step, branch);
    let vals: Vec<Option<f64>> = (0..grid).map(at).collect();
    // Unwrap θA along the grid so a range across ±180° stays contiguous.
    let mut unwrapped: Vec<Option<f64>> = Vec::with_capacity(grid);
    let mut prev: Option<f64> = None;
    for v in &vals {
        let u = v.map(|x| match prev {
            Some(q) => q + wrap_pi(x - q),
            None => x,
        });
        if u.is_some() {
            prev = u;
        }
        unwrapped.push(u);
    }
    let a_range_deg = unwrapped
        .iter()
        .flatten()
        .fold(None, |acc: Option<[f64; 2]>, &x| {
            Some(match acc {
                Some([lo, hi]) => [lo.min(x), hi.max(x)],
                None => [x, x],
            })
        })
        .map(|[lo, hi]| [lo.to_degrees(), hi.to_degrees()]);

    // Blocked θC intervals: runs of None, edges refined by bisection on R² − C².
    let open = |theta_c: f64| {
        let (_, t2) = p.link_angles(0.0, theta_c);
        let (a, b, c) = eq9(p, d, t2);
        a * a + b * b - c * c
    };
    let mut c_blocked_deg = Vec::new();
    let n_blocked = vals.iter().filter(|v| v.is_none()).count();
    if n_blocked == grid {
        c_blocked_deg.push([0.0, 360.0]);
    } else if n_blocked > 0 {
        // Start scanning at a valid point so runs do not wrap around the array end.
        let start = vals.iter().position(|v| v.is_some()).unwrap_or(0);
        let mut k = 0;
        while k < grid {
            let i = (start + k) % grid;
            if vals[i].is_none() {
                let first = k;
                while k < grid && vals[(start + k) % grid].is_none() {
                    k += 1;
                }
                let lo_c = ((start + first) as f64 - 1.0) * step;
                let hi_c = ((start + k) as f64) * step;
                let lo = bisect(open, lo_c, lo_c + step);
                let hi = bisect(open, hi_c - step, hi_c);
                c_blocked_deg.push([
                    lo.to_degrees().rem_euclid(360.0),
                    hi.to_degrees().rem_euclid(360.0),
                ]);
            }
            k += 1;
        }
    }

    // Dead points: interior local extremes of θA(θC), refined by golden section.
    let mut dead_points = Vec::new();
    for k in 0..grid {
        let (Some(a), Some(b), Some(c)) = (
            unwrapped[(k + grid - 1) % grid],
            unwrapped[k],
            unwrapped[(k + 1) % grid],
        ) else {
            continue;
        };
        // Compare through wrap_pi so the seam at k = 0 does not fake an extreme.
        let (db_a, dc_b) = (wrap_pi(b - a), wrap_pi(c - b));
        let is_max = db_a > 0.0 && dc_b <= 0.0;
        let is_min = db_a < 0.0 && dc_b >= 0.0;
        if !(is_max || is_min) {
            continue;
        }
        // Refine on eq. (15), which changes sign at the extreme (it is ∝ dθ1/dθ2, eq. 13).
        let f = |tc: f64| {
            theta_a_for(p, d, tc, branch).map_or(0.0, |ta| {
                let (t1, t2) = p.link_angles(ta, tc);
                eq15(p, t1, t2)
            })
        };
        let tc = bisect(f, (k as f64 - 1.0) * step, (k as f64 + 1.0) * step);
        let Some(ta) = theta_a_for(p, d, tc, branch) else {
            continue;
        };
        let (t1, t2) = p.link_angles(ta, tc);
        dead_points.push(DeadPoint {
            theta_c_deg: tc.to_degrees().rem_euclid(360.0),
            theta_a_deg: ta.to_degrees(),
            kind: if is_max { "max" } else { "min" },
            eq15_mm: eq15(p, t1, t2),
        });
    }
    BranchMotion {
        branch,
        c_full_turn: n_blocked == 0,
        c_blocked_deg,
        a_range_deg,
        dead_points,
    }
}

/// Bar lengths for which every θC has a position: √max(K − R) ≤ d ≤ √min(K + R).
fn d_full_turn(p: &Params, step: f64, grid: usize) -> Option<[f64; 2]> {
    let kr = |tc: f64, s: f64| {
        let (_, t2) = p.link_angles(0.0, tc);
        let (a, b, _) = eq9(p, 0.0, t2);
        k_of(p, t2) + s * a.hypot(b)
    };
    let argmax = |f: &dyn Fn(f64) -> f64| {
        let k = (0..grid)
            .max_by(|&i, &j| f(i as f64 * step).total_cmp(&f(j as f64 * step)))
            .unwrap_or(0);
        let t = golden_max(f, (k as f64 - 1.0) * step, (k as f64 + 1.0) * step);
        f(t)
    };
    let lo = argmax(&|t| kr(t, -1.0));
    let hi = -argmax(&|t| -kr(t, 1.0));
    (lo <= hi && hi > 0.0).then(|| [lo.max(0.0).sqrt(), hi.sqrt()])
}

/// Root of f in [a, b] where f changes sign (or the end nearer to a sign change).
fn bisect(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64) -> f64 {
    let mut fa = f(a);
    for _ in 0..60 {
        let m = 0.5 * (a + b);
        let fm = f(m);
        if (fm >= 0.0) == (fa >= 0.0) {
            a = m;
            fa = fm;
        } else {
            b = m;
        }
    }
    0.5 * (a + b)
}

/// Maximiser of a unimodal f on [a, b] by golden-section search.
fn golden_max(f: impl Fn(f64) -> f64, mut a: f64, mut b: f64) -> f64 {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let mut x1 = b - g * (b - a);
    let mut x2 = a + g * (b - a);
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..80 {
        if f1 < f2 {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + g * (b - a);
            f2 = f(x2);
        } else {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - g * (b - a);
            f1 = f(x1);
        }
    }
    0.5 * (a + b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rrsps::bar_length;

    fn table2(theta_a0_deg: f64) -> Params {
        Params::from_named_units(&[
            96.310,
            352.114,
            theta_a0_deg,
            80.0,
            30.0,
            -161.592,
            0.0,
            270.0,
        ])
    }

    #[test]
    fn motion_keeps_the_bar_length() {
        let p = table2(-55.0);
        for b in Branch::BOTH {
            for k in 0..36 {
                let tc = (k as f64 * 10.0).to_radians();
                if let Some(ta) = theta_a_for(&p, 300.0, tc, b) {
                    assert!((bar_length(&p, ta, tc) - 300.0).abs() < 1e-9);
                }
            }
        }
    }
}
