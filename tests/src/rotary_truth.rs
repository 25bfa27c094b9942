//! Closed-form physical truth for the rotary-axis tests (issue 21): a swinging head ([`BHead`])
//! or a turntable ([`CTable`]) whose axis line is offset and tilted, a ball on the spindle and a
//! ball on the table, and the ball bar's length between them. Written from the physics with its
//! own rotations (Rodrigues' formula); it shares no code and no equation with the host's `rotary`
//! model, whose six-error sensitivities it is meant to check.
//!
//! The rest of this doc is the head's; the turntable's is at [`CTable`].
//!
//! **Frame and senses** (ISO 841): machine axes X, Y, Z right-handed; B turns about +Y by the
//! right-hand rule, so a positive B swings the downward tool (−Z) toward −X. The head's pivot is
//! the origin when the machine stands at the nominal head position; the linear axes carry the
//! whole head (pivot, bearing, spindle) and follow the *nominal* kinematics, so any translation
//! they add cancels between the actual and the nominal ball.
//!
//! **The head as built**: its real axis line passes through `offset_mm` = (ox, 0, oz) (a point
//! of the line, measured from the nominal pivot, off the nominal axis in X and Z) and points
//! along (−tilt_z, 1, tilt_x) normalised: `tilt_x_rad` turns +Y about +X (toward +Z),
//! `tilt_z_rad` turns +Y about +Z (toward −X), both right-handed. The head was set up (tool
//! length, ball centre) at B = 0, so at B = 0 the ball is where the controller thinks it is; the
//! error grows as B moves away from 0: at angle β the ball, at P0 when β = 0, is at
//! o + Rot(axis, β)(P0 − o) instead of Rot(Y, β)·P0.
//!
//! **The ball bar**: the table ball is fixed; the linear axes put the nominal spindle ball at a
//! bar length ℓ from it in a direction fixed to the head (so the bar turns with the head): the
//! reading is the change of the distance between the two balls, positive when the bar extends,
//! as a ball bar reads. Where the table ball sits, per installation ([`Install`]):
//! - radial: on the tool's axis, *beyond* the spindle ball (toward the table): the bar lies
//!   along the tool, the only place a table ball can be (on the pivot side it would be inside
//!   the head). A ball displaced along the tool toward the table shortens the bar.
//! - tangential: beside the spindle ball on the head's +X side at B = 0 (the side B's positive
//!   turn moves away from): a ball displaced toward −X at B = 0 extends the bar.
//! - axial: beside the spindle ball on its −Y side: a ball displaced toward +Y extends the bar.

/// A swinging head about Y with its axis line off where the controller thinks it is.
#[derive(Debug, Clone, Copy)]
pub struct BHead {
    /// A point of the real axis line (mm): (ox, 0, oz) from the nominal pivot.
    pub offset_mm: [f64; 3],
    /// Tilt of the real axis about +X (rad): +Y leans toward +Z.
    pub tilt_x_rad: f64,
    /// Tilt of the real axis about +Z (rad): +Y leans toward −X.
    pub tilt_z_rad: f64,
}

/// How the bar is installed (where the other ball sits: [`BHead`] in the module doc, [`CTable`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Install {
    /// Along the radius from the axis to the moving ball.
    Radial,
    /// In the plane of rotation, square to the radius.
    Tangential,
    /// Along the axis of rotation.
    Axial,
}

/// A ball on the spindle: `l_mm` below the pivot along the tool (at B = 0, along −Z), `h_mm`
/// along +Y from the pivot.
#[derive(Debug, Clone, Copy)]
pub struct SpindleBall {
    pub l_mm: f64,
    pub h_mm: f64,
}

/// Rotation of `v` by `angle` about the unit vector `k` (Rodrigues' formula,
/// v cos θ + (k × v) sin θ + k (k·v)(1 − cos θ)): right-handed about `k`.
pub fn rotate(k: [f64; 3], angle: f64, v: [f64; 3]) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let kxv = cross(k, v);
    let kv = dot(k, v);
    [0, 1, 2].map(|i| v[i] * c + kxv[i] * s + k[i] * kv * (1.0 - c))
}

pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
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

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

const Y: [f64; 3] = [0.0, 1.0, 0.0];

impl BHead {
    /// The real axis's direction (unit).
    pub fn axis(&self) -> [f64; 3] {
        let a = [-self.tilt_z_rad, 1.0, self.tilt_x_rad];
        scale(1.0 / norm(a), a)
    }

    /// Where the spindle ball is at B = `beta_rad`, as built and as the controller thinks
    /// (mm, relative to the pivot the linear axes carry): (actual, nominal).
    pub fn ball(&self, ball: SpindleBall, beta_rad: f64) -> ([f64; 3], [f64; 3]) {
        let p0 = [0.0, ball.h_mm, -ball.l_mm];
        let o = self.offset_mm;
        let actual = add(o, rotate(self.axis(), beta_rad, sub(p0, o)));
        (actual, rotate(Y, beta_rad, p0))
    }

    /// The unit vector from the spindle ball to the table ball, fixed to the head, at B.
    pub fn bar_direction(install: Install, beta_rad: f64) -> [f64; 3] {
        let at_zero = match install {
            Install::Radial => [0.0, 0.0, -1.0],
            Install::Tangential => [1.0, 0.0, 0.0],
            Install::Axial => [0.0, -1.0, 0.0],
        };
        rotate(Y, beta_rad, at_zero)
    }

    /// The ball bar's reading (mm): the distance between the table ball and the real spindle
    /// ball minus the bar length `bar_mm` (the distance to the nominal one), exact (no small-angle
    /// approximation).
    pub fn reading_mm(&self, ball: SpindleBall, install: Install, bar_mm: f64, beta: f64) -> f64 {
        let (actual, nominal) = self.ball(ball, beta);
        let table = add(nominal, scale(bar_mm, Self::bar_direction(install, beta)));
        norm(sub(table, actual)) - bar_mm
    }
}

/// A turntable about Z with its axis line off where the controller thinks it is (seed 002's
/// C table), for [`CTable::reading_mm`].
///
/// **Frame and senses**: C turns the table right-handed about +Z (ISO 841); the origin is where
/// the nominal axis meets the table's surface. The real axis passes through (ox, oy, 0) and
/// points along (tilt_y, −tilt_x, 1) normalised: `tilt_x_rad` turns +Z about +X (toward −Y),
/// `tilt_y_rad` about +Y (toward +X). The table ball, at P0 = (L, 0, H) at C = 0 (L from the
/// axis, H above the surface), is at o + Rot(axis, γ)(P0 − o) instead of Rot(Z, γ)·P0; the
/// set-up was made at C = 0.
///
/// **The ball bar**: the linear axes put the spindle ball at a bar length ℓ from the nominal
/// table ball in a direction fixed to the table: radial with the spindle ball *inward* (toward
/// the axis), tangential with it *behind* the table ball (on the side C's positive turn moves
/// away from), axial with it *above* the table ball (the spindle comes from above). The reading
/// is the change of the distance between the balls, + when the bar extends: a table ball
/// displaced outward, forward or *down* extends the bar.
#[derive(Debug, Clone, Copy)]
pub struct CTable {
    /// A point of the real axis line (mm): (ox, oy, 0).
    pub offset_mm: [f64; 3],
    /// Tilt of the real axis about +X (rad): +Z leans toward −Y.
    pub tilt_x_rad: f64,
    /// Tilt of the real axis about +Y (rad): +Z leans toward +X.
    pub tilt_y_rad: f64,
}

const Z: [f64; 3] = [0.0, 0.0, 1.0];

impl CTable {
    /// The real axis's direction (unit).
    pub fn axis(&self) -> [f64; 3] {
        let a = [self.tilt_y_rad, -self.tilt_x_rad, 1.0];
        scale(1.0 / norm(a), a)
    }

    /// The table ball `l_mm` from the axis and `h_mm` above the surface (at C = 0 on +X) at C =
    /// `gamma_rad`: (actual, nominal).
    pub fn ball(&self, l_mm: f64, h_mm: f64, gamma_rad: f64) -> ([f64; 3], [f64; 3]) {
        let p0 = [l_mm, 0.0, h_mm];
        let o = self.offset_mm;
        let actual = add(o, rotate(self.axis(), gamma_rad, sub(p0, o)));
        (actual, rotate(Z, gamma_rad, p0))
    }

    /// The unit vector from the table ball to the spindle ball, fixed to the table, at C.
    pub fn bar_direction(install: Install, gamma_rad: f64) -> [f64; 3] {
        match install {
            Install::Radial => rotate(Z, gamma_rad, [-1.0, 0.0, 0.0]),
            Install::Tangential => rotate(Z, gamma_rad, [0.0, -1.0, 0.0]),
            Install::Axial => Z,
        }
    }

    /// The bar's reading (mm), exact: the distance between the spindle ball and the real table
    /// ball minus the bar length `bar_mm`.
    pub fn reading_mm(
        &self,
        l_mm: f64,
        h_mm: f64,
        install: Install,
        bar_mm: f64,
        gamma: f64,
    ) -> f64 {
        let (actual, nominal) = self.ball(l_mm, h_mm, gamma);
        let spindle = add(nominal, scale(bar_mm, Self::bar_direction(install, gamma)));
        norm(sub(spindle, actual)) - bar_mm
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hand-computed: a quarter turn about +Y takes +Z to +X and the tool (−Z) to −X.
    #[test]
    fn rotation_is_right_handed() {
        let v = rotate(Y, std::f64::consts::FRAC_PI_2, [0.0, 0.0, -1.0]);
        assert!((v[0] + 1.0).abs() < 1e-15 && v[1].abs() < 1e-15 && v[2].abs() < 1e-15);
    }

    /// An axis line 10 µm off in +X: after a half turn the ball has moved 20 µm in +X (it turned
    /// about a point 10 µm to its +X side); a radial bar (tool pointing up at B = 180°, table ball
    /// above) sees it only to second order, a tangential one (table ball on −X at 180°) reads +20 µm.
    #[test]
    fn offset_moves_the_ball_twice_the_offset_at_a_half_turn() {
        let head = BHead {
            offset_mm: [0.01, 0.0, 0.0],
            tilt_x_rad: 0.0,
            tilt_z_rad: 0.0,
        };
        let ball = SpindleBall {
            l_mm: 200.0,
            h_mm: 0.0,
        };
        let pi = std::f64::consts::PI;
        let (a, n) = head.ball(ball, pi);
        assert!((a[0] - n[0] - 0.02).abs() < 1e-12, "{a:?} {n:?}");
        // Square to the bar: only the second-order 0.02² / (2·150) mm = 1.3 nm.
        let r = head.reading_mm(ball, Install::Radial, 150.0, pi);
        assert!((r - 0.02f64.powi(2) / 300.0).abs() < 1e-9, "{r}");
        let t = head.reading_mm(ball, Install::Tangential, 150.0, pi);
        assert!((t - 0.02).abs() < 1e-12, "{t}");
        // At B = 0 nothing has moved.
        for i in [Install::Radial, Install::Tangential, Install::Axial] {
            assert!(head.reading_mm(ball, i, 150.0, 0.0).abs() < 1e-12);
        }
    }
}
