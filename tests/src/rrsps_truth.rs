//! Closed-form physical truth for the RRSPS tests (issue 21): an A/C tilting-rotary table as
//! built — two axis lines anywhere in space, a ball on the C table, a ball on the spindle — and
//! the ball bar's length between the balls. Written from the physics (rigid rotations about
//! lines, [`crate::rotary_truth::rotate`]); it shares no code and no equation with the host's
//! `rrsps` model (eq. 8 of seed 004), whose parameters it is meant to check.
//!
//! **Senses** (ISO 841): A turns the cradle right-handed about the A axis's direction (+X on a
//! nominal machine), C turns the table right-handed about the C axis's direction (+Z at A = 0),
//! and the C axis rides on the cradle. Everything is described at A = 0, C = 0; at (A, C) the
//! table ball is first turned by C about the C line (as it lies at A = 0), then the whole cradle
//! by A about the A line. The spindle ball stays where it is during a test.
use crate::rotary_truth::{cross, dot, rotate};

/// An A/C table as built, at A = 0 and C = 0 (mm; directions need not be unit).
#[derive(Debug, Clone, Copy)]
pub struct TrunnionTable {
    /// A point of the A axis line.
    pub a_point: [f64; 3],
    /// The A axis's direction: A turns the cradle right-handed about it.
    pub a_dir: [f64; 3],
    /// A point of the C axis line (at A = 0).
    pub c_point: [f64; 3],
    /// The C axis's direction (at A = 0): C turns the table right-handed about it.
    pub c_dir: [f64; 3],
    /// The table ball's centre at A = 0, C = 0.
    pub table_ball: [f64; 3],
    /// The spindle ball's centre.
    pub spindle_ball: [f64; 3],
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(s: f64, a: [f64; 3]) -> [f64; 3] {
    [s * a[0], s * a[1], s * a[2]]
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    scale(1.0 / dot(a, a).sqrt(), a)
}

/// `v` turned by `angle` right-handed about the line through `point` along `dir`.
fn rotate_about_line(point: [f64; 3], dir: [f64; 3], angle: f64, v: [f64; 3]) -> [f64; 3] {
    add(point, rotate(unit(dir), angle, sub(v, point)))
}

/// The signed angle from `from` to `to` (both square to `axis`), right-handed about `axis`.
fn angle_about(axis: [f64; 3], from: [f64; 3], to: [f64; 3]) -> f64 {
    let k = unit(axis);
    dot(cross(from, to), k).atan2(dot(from, to))
}

impl TrunnionTable {
    /// The table ball's centre at machine angles A, C (rad).
    pub fn table_ball_at(&self, a_rad: f64, c_rad: f64) -> [f64; 3] {
        let on_c = rotate_about_line(self.c_point, self.c_dir, c_rad, self.table_ball);
        rotate_about_line(self.a_point, self.a_dir, a_rad, on_c)
    }

    /// The bar's length (mm) at machine angles A, C (rad): the distance between the balls.
    pub fn bar_mm(&self, a_rad: f64, c_rad: f64) -> f64 {
        let r = sub(self.table_ball_at(a_rad, c_rad), self.spindle_ball);
        dot(r, r).sqrt()
    }

    /// The linkage's eight parameters as seed 004 names them (`s0_mm, a0_mm, theta_a0, s2_mm,
    /// a2_mm, theta_c0, a1_mm, alpha12`; mm and rad), each measured on the table as built:
    ///
    /// - the common normal of the two axis lines runs from its foot on the A axis, **O_A**, to
    ///   its foot on the C axis, **O_C**, along **x1** = unit(c × a) (a, c the axes' directions):
    ///   on a nominal table (a = +X, c = +Z) x1 = +Y. `a1` is O_C − O_A along x1 (+ when the C
    ///   axis passes on the +Y side of the A axis); `alpha12` is the angle from a to c,
    ///   right-handed about x1, in 0..360° (270° nominal; more when the C axis leans toward +a,
    ///   i.e. toward +X on a nominal table).
    /// - the spindle ball E in cylinder coordinates about the A axis from O_A: `s0` along a,
    ///   `a0` its distance from the axis, and its angle ψ from x1 right-handed about a gives
    ///   `theta_a0` = ψ − 90° (seed 004 measures E's angle from the direction a × x1, which is
    ///   +Z on a nominal table).
    /// - the table ball F in cylinder coordinates about the C axis from O_C: `s2` along c,
    ///   `a2` its distance from the axis, `theta_c0` its angle from x1 right-handed about c
    ///   (at A = 0, C = 0).
    pub fn linkage_parameters(&self) -> [f64; 8] {
        let a = unit(self.a_dir);
        let c = unit(self.c_dir);
        // Feet of the common normal: O_A = pa + s·a, O_C = pc + t·c with (O_C − O_A) ⊥ a, c.
        let w = sub(self.a_point, self.c_point);
        let (b, d, e) = (dot(a, c), dot(a, w), dot(c, w));
        let den = 1.0 - b * b;
        let s = (b * e - d) / den;
        let t = (e - b * d) / den;
        let o_a = add(self.a_point, scale(s, a));
        let o_c = add(self.c_point, scale(t, c));
        let x1 = unit(cross(c, a));
        let a1 = dot(sub(o_c, o_a), x1);
        let alpha12 = angle_about(x1, a, c).rem_euclid(std::f64::consts::TAU);
        let re = sub(self.spindle_ball, o_a);
        let s0 = dot(re, a);
        let re_radial = sub(re, scale(s0, a));
        let a0 = dot(re_radial, re_radial).sqrt();
        let theta_a0 = angle_about(a, x1, re_radial) - std::f64::consts::FRAC_PI_2;
        let rf = sub(self.table_ball, o_c);
        let s2 = dot(rf, c);
        let rf_radial = sub(rf, scale(s2, c));
        let a2 = dot(rf_radial, rf_radial).sqrt();
        let theta_c0 = angle_about(c, x1, rf_radial);
        [s0, a0, theta_a0, s2, a2, theta_c0, a1, alpha12]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand-computed: a table ball 30 mm along +Y of the C axis, 80 mm up. C = 90° takes it to
    /// −X (right-handed about +Z); A = 90° (right-handed about +X) takes +Y to +Z and +Z to −Y.
    #[test]
    fn senses_are_right_handed() {
        let t = TrunnionTable {
            a_point: [0.0; 3],
            a_dir: [1.0, 0.0, 0.0],
            c_point: [0.0; 3],
            c_dir: [0.0, 0.0, 1.0],
            table_ball: [0.0, 30.0, 80.0],
            spindle_ball: [0.0, 0.0, 380.0],
        };
        let h = std::f64::consts::FRAC_PI_2;
        let f = t.table_ball_at(0.0, h);
        assert!((f[0] + 30.0).abs() < 1e-12 && f[1].abs() < 1e-12 && (f[2] - 80.0).abs() < 1e-12);
        let f = t.table_ball_at(h, 0.0);
        assert!(f[0].abs() < 1e-12 && (f[1] + 80.0).abs() < 1e-12 && (f[2] - 30.0).abs() < 1e-12);
        assert!((t.bar_mm(0.0, 0.0) - (30.0f64.powi(2) + 300.0f64.powi(2)).sqrt()).abs() < 1e-12);
        // The parameters of this table: E 380 mm along +Z is at ψ = 90° from x1 = +Y about +X.
        let p = t.linkage_parameters();
        let want = [
            0.0,
            380.0,
            0.0,
            80.0,
            30.0,
            0.0,
            0.0,
            1.5 * std::f64::consts::PI,
        ];
        for (g, w) in p.iter().zip(want) {
            assert!((g - w).abs() < 1e-12, "{p:?}");
        }
    }
}
