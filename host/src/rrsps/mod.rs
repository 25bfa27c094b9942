//! The DBB test of an A/C two-axis rotary table as a spatial five-bar linkage RRSPS (seed 004,
//! Liao, Tang & Wang, Machines 2023, 11, 919).
//!
//! The ball E sits on the spindle (fixed during the test), the ball F on the C table; the A axis
//! (link 1) carries the C axis (link 2). Eight parameters describe the linkage, named as in
//! `rrsps_parameters_table2_3.csv`:
//!
//! | name | meaning |
//! | --- | --- |
//! | `s0_mm`, `a0_mm`, `theta_a0_deg` | ball E in cylindrical coordinates about the A axis |
//! | `s2_mm`, `a2_mm`, `theta_c0_deg` | ball F in cylindrical coordinates about the C axis |
//! | `a1_mm`, `alpha12_deg` | common normal and twist between the A and C axes |
//!
//! The bar length is eq. (8)/(26) *as printed*, with the machine angles entering as
//! θ1 = θA − θA0 − 90° and θ2 = θC + θC0 (eq. 26; the inverse of eq. 11). Inside, angles are radians.
//!
//! - [`design`]: the RRSS motion (constant bar length, eq. 9-15): θA(θC) on each branch, dead
//!   points, whether C turns fully, the A range (Table 2).
//! - [`identify`]: the eight parameters from measured bar lengths, by least squares or minimax
//!   (eq. 26), one test or several tests sharing all but the parameters the user says changed.
//! - [`synth`]: ball positions that make the motion cover a required A range (Table 2).
//! - [`saddle`]: the saddle (min-max) synthesis with the constraints g1–g13 (eq. 18-23).
//! - [`io`]: parameter files (TOML or CSV) and sample files (`theta_a_deg,theta_c_deg,d_mm`).
//! - [`simulate`]: a simulated test (designed motion, true parameters, noise).
//! - [`report`]: text and JSON of designs, syntheses and identifications.
//!
//! The command line (`jdbb rrsps design|simulate|identify|synthesize`) is `crate::cli::rrsps`.
//! May use: [`crate::numerics`], [`crate::table`].
pub mod design;
pub mod identify;
pub mod io;
pub mod report;
pub mod saddle;
pub mod simulate;
pub mod synth;

use std::f64::consts::FRAC_PI_2;

/// The parameter names, in the order of [`Params::to_array`] (the order of Table 3).
pub const PARAM_NAMES: [&str; 8] = [
    "s0_mm",
    "a0_mm",
    "theta_a0_deg",
    "s2_mm",
    "a2_mm",
    "theta_c0_deg",
    "a1_mm",
    "alpha12_deg",
];

/// Which of the eight parameters are angles (stored in radians, shown in degrees).
pub const IS_ANGLE: [bool; 8] = [false, false, true, false, false, true, false, true];

/// The eight linkage parameters. Lengths in mm, angles in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Params {
    pub s0_mm: f64,
    pub a0_mm: f64,
    pub theta_a0_rad: f64,
    pub s2_mm: f64,
    pub a2_mm: f64,
    pub theta_c0_rad: f64,
    pub a1_mm: f64,
    pub alpha12_rad: f64,
}

impl Params {
    /// The parameters in [`PARAM_NAMES`] order, in internal units (mm, rad).
    pub fn to_array(&self) -> [f64; 8] {
        [
            self.s0_mm,
            self.a0_mm,
            self.theta_a0_rad,
            self.s2_mm,
            self.a2_mm,
            self.theta_c0_rad,
            self.a1_mm,
            self.alpha12_rad,
        ]
    }

    /// Inverse of [`Params::to_array`].
    pub fn from_array(p: &[f64; 8]) -> Self {
        Params {
            s0_mm: p[0],
            a0_mm: p[1],
            theta_a0_rad: p[2],
            s2_mm: p[3],
            a2_mm: p[4],
            theta_c0_rad: p[5],
            a1_mm: p[6],
            alpha12_rad: p[7],
        }
    }

    /// The parameters in the units of their names (mm, degrees), for files and reports.
    pub fn to_named_units(&self) -> [f64; 8] {
        let mut v = self.to_array();
        for (x, &angle) in v.iter_mut().zip(&IS_ANGLE) {
            if angle {
                *x = x.to_degrees();
            }
        }
        v
    }

    /// Inverse of [`Params::to_named_units`].
    pub fn from_named_units(v: &[f64; 8]) -> Self {
        let mut p = *v;
        for (x, &angle) in p.iter_mut().zip(&IS_ANGLE) {
            if angle {
                *x = x.to_radians();
            }
        }
        Params::from_array(&p)
    }

    /// The RRSS/RRSPS input angles (θ1, θ2) of eq. (26) for machine angles (θA, θC).
    pub fn link_angles(&self, theta_a_rad: f64, theta_c_rad: f64) -> (f64, f64) {
        (
            theta_a_rad - self.theta_a0_rad - FRAC_PI_2,
            theta_c_rad + self.theta_c0_rad,
        )
    }

    /// The machine angles (θA, θC) for link angles (θ1, θ2): eq. (11).
    pub fn machine_angles(&self, theta1_rad: f64, theta2_rad: f64) -> (f64, f64) {
        (
            theta1_rad + self.theta_a0_rad + FRAC_PI_2,
            theta2_rad - self.theta_c0_rad,
        )
    }
}

/// sin and cos of one angle, computed once per sample and reused every fit iteration.
#[derive(Debug, Clone, Copy)]
pub struct SinCos {
    pub sin: f64,
    pub cos: f64,
}

impl SinCos {
    pub fn of(angle_rad: f64) -> Self {
        let (sin, cos) = angle_rad.sin_cos();
        SinCos { sin, cos }
    }
}

/// Trigonometric constants of one parameter set, so that a sample costs no trig calls.
#[derive(Debug, Clone, Copy)]
pub struct Prepared {
    p: Params,
    /// φ = θA0 + 90°: θ1 = θA − φ.
    phi: SinCos,
    c0: SinCos,
    alpha: SinCos,
}

impl Prepared {
    pub fn new(p: &Params) -> Self {
        Prepared {
            p: *p,
            phi: SinCos::of(p.theta_a0_rad + FRAC_PI_2),
            c0: SinCos::of(p.theta_c0_rad),
            alpha: SinCos::of(p.alpha12_rad),
        }
    }

    /// The vector (u, v, w) of eq. (8) for machine angles given by their sin/cos.
    #[inline]
    fn uvw(&self, a: SinCos, c: SinCos) -> ([f64; 3], [f64; 4]) {
        let p = &self.p;
        // θ1 = θA − φ, θ2 = θC + θC0 by angle addition.
        let s1 = a.sin * self.phi.cos - a.cos * self.phi.sin;
        let c1 = a.cos * self.phi.cos + a.sin * self.phi.sin;
        let s2 = c.sin * self.c0.cos + c.cos * self.c0.sin;
        let c2 = c.cos * self.c0.cos - c.sin * self.c0.sin;
        let (sa, ca) = (self.alpha.sin, self.alpha.cos);
        let u =
            p.a1_mm * c1 + p.s2_mm * sa * s1 + p.a2_mm * c1 * c2 - p.a2_mm * ca * s1 * s2 - p.a0_mm;
        let v = p.a1_mm * s1 - p.s2_mm * sa * c1 + p.a2_mm * s1 * c2 + p.a2_mm * ca * c1 * s2;
        let w = -p.s0_mm + p.s2_mm * ca + p.a2_mm * sa * s2;
        ([u, v, w], [s1, c1, s2, c2])
    }

    /// Bar length d (mm) of eq. (8) at machine angles (θA, θC).
    pub fn bar_length(&self, a: SinCos, c: SinCos) -> f64 {
        let ([u, v, w], _) = self.uvw(a, c);
        (u * u + v * v + w * w).sqrt()
    }

    /// Bar length and its gradient with respect to the eight parameters in internal units
    /// (mm and rad, [`PARAM_NAMES`] order), differentiated from eq. (8) by hand.
    #[inline]
    pub fn bar_length_and_gradient(&self, a: SinCos, c: SinCos) -> (f64, [f64; 8]) {
        let p = &self.p;
        let ([u, v, w], [s1, c1, s2, c2]) = self.uvw(a, c);
        let d = (u * u + v * v + w * w).sqrt();
        let (sa, ca) = (self.alpha.sin, self.alpha.cos);
        let inv = 1.0 / d;
        // d/dθ1 of (u, v, w) is (−v, u + a0, 0); θ1 = θA − θA0 − 90° so d/dθA0 = −d/dθ1.
        let dd_dtheta1 = (u * (-v) + v * (u + p.a0_mm)) * inv;
        // d/dθ2 of (u, v, w); θ2 = θC + θC0 so d/dθC0 = d/dθ2.
        let du2 = -p.a2_mm * c1 * s2 - p.a2_mm * ca * s1 * c2;
        let dv2 = -p.a2_mm * s1 * s2 + p.a2_mm * ca * c1 * c2;
        let dw2 = p.a2_mm * sa * c2;
        let g = [
            // s0
            -w * inv,
            // a0
            -u * inv,
            // θA0
            -dd_dtheta1,
            // s2
            (u * sa * s1 - v * sa * c1 + w * ca) * inv,
            // a2
            (u * (c1 * c2 - ca * s1 * s2) + v * (s1 * c2 + ca * c1 * s2) + w * sa * s2) * inv,
            // θC0
            (u * du2 + v * dv2 + w * dw2) * inv,
            // a1
            (u * c1 + v * s1) * inv,
            // α12
            (u * (p.s2_mm * ca * s1 + p.a2_mm * sa * s1 * s2)
                + v * (-p.s2_mm * ca * c1 - p.a2_mm * sa * c1 * s2)
                + w * (-p.s2_mm * sa + p.a2_mm * ca * s2))
                * inv,
        ];
        (d, g)
    }
}

/// Bar length d (mm) of eq. (8)/(26) for machine angles θA, θC (radians).
pub fn bar_length(p: &Params, theta_a_rad: f64, theta_c_rad: f64) -> f64 {
    Prepared::new(p).bar_length(SinCos::of(theta_a_rad), SinCos::of(theta_c_rad))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table2_neg() -> Params {
        Params::from_named_units(&[96.310, 352.114, -55.0, 80.0, 30.0, -161.592, 0.0, 270.0])
    }

    /// Eq. (8) must agree with the closed loop of eq. (6)/(7)/(17): F carried by [M10][M21]
    /// (with the −a0 column of eq. 17 and the a1 offset) minus E = (0, 0, s0) in frame 0.
    #[test]
    fn eq8_matches_the_transformation_chain() {
        let p = Params::from_named_units(&[96.9, 351.9, -54.99, 79.9, 30.06, -161.5, -0.02, 270.1]);
        for &(ta, tc) in &[(-30.0f64, 10.0f64), (-100.0, 250.0), (-5.0, 123.0)] {
            let (t1, t2) = p.link_angles(ta.to_radians(), tc.to_radians());
            let (sa, ca) = p.alpha12_rad.sin_cos();
            let m10 = [
                [t1.cos(), -ca * t1.sin(), sa * t1.sin()],
                [t1.sin(), ca * t1.cos(), -sa * t1.cos()],
                [0.0, sa, ca],
            ];
            // F in link-2 frame: (a2 cos θ2, a2 sin θ2, s2) after [M21]; plus a1 along x1.
            let f2 = [p.a2_mm * t2.cos() + p.a1_mm, p.a2_mm * t2.sin(), p.s2_mm];
            let mut f0 = [0.0; 3];
            for i in 0..3 {
                for j in 0..3 {
                    f0[i] += m10[i][j] * f2[j];
                }
            }
            let r = [f0[0] - p.a0_mm, f0[1], f0[2] - p.s0_mm];
            let d_chain = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
            let d8 = bar_length(&p, ta.to_radians(), tc.to_radians());
            assert!((d8 - d_chain).abs() < 1e-9, "{d8} vs {d_chain}");
        }
    }

    #[test]
    fn gradient_matches_central_differences() {
        let p = Params::from_named_units(&[96.9, 351.9, -54.99, 79.9, 30.06, -161.5, -0.02, 270.1]);
        let a = SinCos::of((-70.0f64).to_radians());
        let c = SinCos::of(200.0f64.to_radians());
        let (_, g) = Prepared::new(&p).bar_length_and_gradient(a, c);
        for k in 0..8 {
            let h = 1e-6;
            let mut hi = p.to_array();
            let mut lo = p.to_array();
            hi[k] += h;
            lo[k] -= h;
            let num = (Prepared::new(&Params::from_array(&hi)).bar_length(a, c)
                - Prepared::new(&Params::from_array(&lo)).bar_length(a, c))
                / (2.0 * h);
            assert!(
                (num - g[k]).abs() < 1e-6 * (1.0 + num.abs()),
                "{}: analytic {} numeric {}",
                PARAM_NAMES[k],
                g[k],
                num
            );
        }
    }

    #[test]
    fn unit_conversions_round_trip() {
        let p = table2_neg();
        let back = Params::from_named_units(&p.to_named_units());
        for (a, b) in p.to_array().iter().zip(back.to_array()) {
            assert!((a - b).abs() < 1e-12);
        }
        let (t1, t2) = p.link_angles(0.3, 1.1);
        let (a, c) = p.machine_angles(t1, t2);
        assert!((a - 0.3).abs() < 1e-15 && (c - 1.1).abs() < 1e-15);
    }
}
