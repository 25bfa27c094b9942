//! An independent model of the J-DBB as built, for testing the project's instrument model
//! (`jdbb_core::geometry`) and its calibration (`jdbb calibrate`) against something that does not
//! share their derivation.
//!
//! It takes from `jdbb_core` only the *data* — [`Calibration`]'s fields and what each one means
//! physically (its field docs and the "Conventions" of `jdbb_core::geometry`) — and builds the
//! mechanism from parts:
//!
//! - **Bar 1's frame.** Joint centre J at the origin, ẑ along bar 1 away from the table ball B1 =
//!   −L1·ẑ; x̂ is frame 1's pivot axis projected on the plane normal to bar 1.
//! - **Pivot axes** as rotations of unit vectors: frame 1's axis is x̂, frame 2's is ŷ turned
//!   about ẑ by the skew γ (so the projected axes are 90° + γ apart); each then tilted by τ_k
//!   towards +z (a rotation about a_k × ẑ).
//! - **Frames as rigid bodies.** Frame k turns by θ_k right-handedly about the *line* through its
//!   pivot point p_k along a_k. Its slot plane contains that line; at θ_k = 0 it is parallel to
//!   bar 1. The pivot point is placed in space: p_k = r_k·(ν_k·n_k⁰ + μ_k·m_k⁰) + w_k·a_k, with
//!   n_k⁰ the slot normal at zero (n₁⁰ ∝ ẑ × a₁, n₂⁰ ∝ a₂ × ẑ), m_k⁰ = a_k × n_k⁰, r_k the
//!   distance from J at which the frame grips bar 2 and w_k a free slide along the axis (which
//!   must not matter).
//! - **Bar 2** is the line through J whose grip points r_k·u lie in both slot planes: found by
//!   Newton's method on the unit sphere (gnomonic coordinates u ∝ (x, y, 1)), not by a formula.
//! - **D = |L2·u − B1| = |L2·u + L1·ẑ|**, as a vector.
//! - **Inverse** (for generating data): the frame angle that puts the grip point of a given bar-2
//!   direction in frame k's slot plane, by bisection; the count at which the encoder reads that
//!   angle, eq. (G9) θ = s·(c − z)·2π/N − ζ + e·sin(ψ + φₑ) with ψ the disc angle, by Newton's
//!   method on the real count, then rounded: the instrument quantises.
//!
//! Nothing here calls `jdbb_core::geometry` or the encoder methods of `jdbb_core::calib`.
use jdbb_core::calib::{Calibration, EncoderCal};

/// A vector in bar 1's frame (mm or unitless).
pub type V3 = [f64; 3];

const Z: V3 = [0.0, 0.0, 1.0];

/// The frames' mechanical range: each frame turns at most ±75° from zero.
pub const FRAME_RANGE_RAD: f64 = 75.0 * std::f64::consts::PI / 180.0;

/// One arc second in radians.
pub const ARCSEC: f64 = std::f64::consts::PI / (180.0 * 3600.0);

/// Sum.
pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
/// Difference a − b.
pub fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
/// a·s.
pub fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
/// Scalar product.
pub fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
/// Vector product.
pub fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
/// Euclidean length.
pub fn norm(a: V3) -> f64 {
    dot(a, a).sqrt()
}
/// `a` scaled to unit length.
pub fn unit(a: V3) -> V3 {
    scale(a, 1.0 / norm(a))
}

/// `v` turned right-handedly by `angle_rad` about the unit vector `axis` (Rodrigues).
pub fn rotate(v: V3, axis: V3, angle_rad: f64) -> V3 {
    let (s, c) = angle_rad.sin_cos();
    let k_cross_v = cross(axis, v);
    let k_dot_v = dot(axis, v);
    add(
        add(scale(v, c), scale(k_cross_v, s)),
        scale(axis, k_dot_v * (1.0 - c)),
    )
}

/// A unit vector `h` normal to ẑ tilted by `tilt_rad` towards +z (a rotation about h × ẑ).
fn tilt_towards_z(h: V3, tilt_rad: f64) -> V3 {
    rotate(h, unit(cross(h, Z)), tilt_rad)
}

/// One mechanical decoupling frame as a rigid body turning about a line.
#[derive(Debug, Clone, Copy)]
pub struct Frame {
    /// Unit direction a_k of the pivot axis.
    pub axis: V3,
    /// A point of the pivot axis (mm): the axis passes there, not necessarily through J.
    pub pivot_mm: V3,
    /// Unit normal n_k⁰ of the slot plane at θ_k = 0.
    pub normal0: V3,
    /// Distance r_k from J at which the frame grips bar 2 (mm).
    pub grip_mm: f64,
}

impl Frame {
    /// Unit normal of the slot plane with the frame turned by `theta_rad` about its axis.
    pub fn normal(&self, theta_rad: f64) -> V3 {
        rotate(self.normal0, self.axis, theta_rad)
    }

    /// Signed distance (mm) of bar 2's grip point r_k·u from the slot plane at `theta_rad`:
    /// zero when the frame holds a bar in direction `u`.
    pub fn miss_mm(&self, u: V3, theta_rad: f64) -> f64 {
        dot(
            sub(scale(u, self.grip_mm), self.pivot_mm),
            self.normal(theta_rad),
        )
    }
}

/// Why a pose cannot be made or read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PoseError {
    /// D is outside L1 + L2 and |L1 − L2|.
    Unreachable,
    /// A frame would have to turn beyond [`FRAME_RANGE_RAD`].
    OutOfRange,
    /// The numerical solve did not converge.
    NoConvergence,
}

/// The instrument as built, from parts (see the module docs).
#[derive(Debug, Clone, Copy)]
pub struct Mechanism {
    /// Bar 1, table ball centre to joint centre (mm).
    pub l1_mm: f64,
    /// Bar 2, joint centre to spindle ball centre (mm).
    pub l2_mm: f64,
    /// The two encoders (their calibration data: resolution, zero, direction, errors).
    pub encoders: [EncoderCal; 2],
    /// The two frames.
    pub frames: [Frame; 2],
}

/// Where each frame grips bar 2 (mm from J) and how far its pivot point slides along its own
/// axis (mm). The calibration parameters only hold the ratios p/r, so neither may change D.
#[derive(Debug, Clone, Copy)]
pub struct Build {
    /// r_k (mm).
    pub grip_mm: [f64; 2],
    /// w_k (mm): the pivot point's component along a_k.
    pub axial_slide_mm: [f64; 2],
}

impl Default for Build {
    fn default() -> Self {
        Build {
            grip_mm: [25.0, 25.0],
            axial_slide_mm: [0.0, 0.0],
        }
    }
}

impl Mechanism {
    /// The mechanism a [`Calibration`] describes, with frames gripping bar 2 at 25 mm.
    pub fn new(cal: &Calibration) -> Self {
        Self::with_build(cal, &Build::default())
    }

    /// The mechanism a [`Calibration`] describes, with a chosen grip distance and axial slide of
    /// each pivot point.
    pub fn with_build(cal: &Calibration, build: &Build) -> Self {
        let horizontal = [
            [1.0, 0.0, 0.0],
            rotate([0.0, 1.0, 0.0], Z, cal.axes_skew_rad),
        ];
        let fc = [cal.frame1, cal.frame2];
        let frames = core::array::from_fn(|k| {
            let a = tilt_towards_z(horizontal[k], fc[k].tilt_rad);
            let n0 = if k == 0 {
                unit(cross(Z, a))
            } else {
                unit(cross(a, Z))
            };
            let m0 = cross(a, n0);
            let r = build.grip_mm[k];
            let p = add(
                scale(
                    add(
                        scale(n0, fc[k].offset_normal_rad),
                        scale(m0, fc[k].offset_axial_rad),
                    ),
                    r,
                ),
                scale(a, build.axial_slide_mm[k]),
            );
            Frame {
                axis: a,
                pivot_mm: p,
                normal0: n0,
                grip_mm: r,
            }
        });
        Mechanism {
            l1_mm: cal.l1_mm,
            l2_mm: cal.l2_mm,
            encoders: [cal.enc1, cal.enc2],
            frames,
        }
    }

    /// The frame angles (rad) the two encoders read at these counts, eq. (G9).
    pub fn frame_angles_rad(&self, counts: [i64; 2]) -> [f64; 2] {
        [
            encoder_angle_rad(&self.encoders[0], counts[0]),
            encoder_angle_rad(&self.encoders[1], counts[1]),
        ]
    }

    /// The direction of bar 2 (unit, in bar 1's frame) held by the frames at these angles: the
    /// u with both grip points in their slot planes, by Newton's method on the sphere.
    pub fn bar2_direction(&self, theta_rad: [f64; 2]) -> Result<V3, PoseError> {
        // Gnomonic coordinates: u = (x, y, 1)/|(x, y, 1)| covers the half sphere u_z > 0.
        let direction = |x: f64, y: f64| unit([x, y, 1.0]);
        let normals = [
            self.frames[0].normal(theta_rad[0]),
            self.frames[1].normal(theta_rad[1]),
        ];
        let residual = |u: V3| -> [f64; 2] {
            core::array::from_fn(|k| self.frames[k].miss_mm(u, theta_rad[k]))
        };
        let (mut x, mut y) = (0.0, 0.0);
        for _ in 0..60 {
            let v = [x, y, 1.0];
            let len = norm(v);
            let u = scale(v, 1.0 / len);
            let f = residual(u);
            // ∂u/∂x = (e_x − u·u_x)/|v|, ∂u/∂y = (e_y − u·u_y)/|v|; ∂miss_k/∂u = r_k·n_k.
            let dux = scale(sub([1.0, 0.0, 0.0], scale(u, u[0])), 1.0 / len);
            let duy = scale(sub([0.0, 1.0, 0.0], scale(u, u[1])), 1.0 / len);
            let j: [[f64; 2]; 2] = core::array::from_fn(|k| {
                let g = scale(normals[k], self.frames[k].grip_mm);
                [dot(g, dux), dot(g, duy)]
            });
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det.abs() < 1e-300 {
                return Err(PoseError::NoConvergence);
            }
            let dx = (f[0] * j[1][1] - f[1] * j[0][1]) / det;
            let dy = (j[0][0] * f[1] - j[1][0] * f[0]) / det;
            x -= dx;
            y -= dy;
            if dx.abs().max(dy.abs()) < 1e-14 * (1.0 + x.abs().max(y.abs())) {
                break;
            }
        }
        let u = direction(x, y);
        let miss = residual(u);
        let worst_mm = miss[0].abs().max(miss[1].abs());
        if worst_mm.is_nan() || worst_mm >= 1e-12 {
            return Err(PoseError::NoConvergence);
        }
        Ok(u)
    }

    /// Ball distance (mm) for a bar-2 direction: |L2·u + L1·ẑ|.
    pub fn distance_for_direction_mm(&self, u: V3) -> f64 {
        norm(add(scale(u, self.l2_mm), scale(Z, self.l1_mm)))
    }

    /// Ball distance (mm) the instrument as built has when its encoders read these counts.
    pub fn distance_mm(&self, counts: [i64; 2]) -> Result<f64, PoseError> {
        let u = self.bar2_direction(self.frame_angles_rad(counts))?;
        Ok(self.distance_for_direction_mm(u))
    }

    /// The bar-2 direction for ball distance `d_mm` and lean azimuth `azimuth_rad` (in bar 1's
    /// frame, from +x towards +y): the deflection φ from the triangle B1–J–B2 (law of cosines).
    /// Bar 2 stays on the spindle side of the joint (φ < 90°, the half sphere
    /// [`Self::bar2_direction`] covers): a slot plane holds the whole line through J, but the
    /// bar cannot fold back past perpendicular to bar 1, so a smaller D is unreachable.
    pub fn direction_for_pose(&self, d_mm: f64, azimuth_rad: f64) -> Result<V3, PoseError> {
        let (l1, l2) = (self.l1_mm, self.l2_mm);
        let cos_phi = (d_mm * d_mm - l1 * l1 - l2 * l2) / (2.0 * l1 * l2);
        if !(cos_phi > 0.0 && cos_phi <= 1.0) {
            return Err(PoseError::Unreachable);
        }
        let sin_phi = (1.0 - cos_phi * cos_phi).sqrt();
        let (s, c) = azimuth_rad.sin_cos();
        Ok([sin_phi * c, sin_phi * s, cos_phi])
    }

    /// The angle (rad) frame `k` must turn to so that it holds bar 2 in direction `u`: the root
    /// of the grip point's miss in (−90°, 90°), by Newton's method kept inside a bisection
    /// bracket (the miss's derivative is the grip point against the turning normal,
    /// d n/dθ = a × n). Err if it is beyond the range.
    pub fn frame_angle_for_direction_rad(&self, k: usize, u: V3) -> Result<f64, PoseError> {
        let frame = &self.frames[k];
        let f = |t: f64| frame.miss_mm(u, t);
        let half = std::f64::consts::FRAC_PI_2 - 1e-9;
        let (mut lo, mut hi) = (-half, half);
        let (f_lo, f_hi) = (f(lo), f(hi));
        if f_lo.signum() == f_hi.signum() {
            return Err(PoseError::NoConvergence);
        }
        let rising = f_hi > f_lo;
        let grip = sub(scale(u, frame.grip_mm), frame.pivot_mm);
        let mut theta = 0.0;
        for _ in 0..200 {
            let n = frame.normal(theta);
            let value = dot(grip, n);
            if value == 0.0 {
                break;
            }
            // Keep the bracket: the root lies on the side where the miss changes sign.
            if (value > 0.0) == rising {
                hi = theta;
            } else {
                lo = theta;
            }
            let slope = dot(grip, cross(frame.axis, n));
            let newton = theta - value / slope;
            let next = if slope != 0.0 && newton > lo && newton < hi {
                newton
            } else {
                0.5 * (lo + hi)
            };
            if (next - theta).abs() < 1e-15 {
                theta = next;
                break;
            }
            theta = next;
        }
        if theta.abs() > FRAME_RANGE_RAD {
            return Err(PoseError::OutOfRange);
        }
        Ok(theta)
    }

    /// Both frame angles (rad) holding bar 2 in direction `u`.
    pub fn frame_angles_for_direction_rad(&self, u: V3) -> Result<[f64; 2], PoseError> {
        Ok([
            self.frame_angle_for_direction_rad(0, u)?,
            self.frame_angle_for_direction_rad(1, u)?,
        ])
    }

    /// The real-valued counts at which the encoders read these frame angles (not yet quantised).
    pub fn counts_real_for_angles(&self, theta_rad: [f64; 2]) -> [f64; 2] {
        [
            encoder_count_real(&self.encoders[0], theta_rad[0]),
            encoder_count_real(&self.encoders[1], theta_rad[1]),
        ]
    }

    /// The counts the instrument shows at ball distance `d_mm` and lean azimuth `azimuth_rad`:
    /// exact frame angles, then each encoder's count rounded to the nearest integer.
    pub fn counts_for_pose(&self, d_mm: f64, azimuth_rad: f64) -> Result<[i64; 2], PoseError> {
        let u = self.direction_for_pose(d_mm, azimuth_rad)?;
        self.counts_for_direction(u)
    }

    /// The (rounded) counts the instrument shows with bar 2 in direction `u`.
    pub fn counts_for_direction(&self, u: V3) -> Result<[i64; 2], PoseError> {
        let theta = self.frame_angles_for_direction_rad(u)?;
        Ok(self.counts_real_for_angles(theta).map(|c| c.round() as i64))
    }
}

/// The disc angle ψ ∈ [0, 2π) of a (real) count: count 0 at ψ = 0, N counts per turn.
fn disc_angle_rad(enc: &EncoderCal, count: f64) -> f64 {
    let turns = count / enc.counts_per_rev as f64;
    std::f64::consts::TAU * (turns - turns.floor())
}

/// Eq. (G9): the frame angle (rad) encoder `enc` reads at an extended count.
pub fn encoder_angle_rad(enc: &EncoderCal, count: i64) -> f64 {
    let step_rad = std::f64::consts::TAU / enc.counts_per_rev as f64;
    let sign = match enc.direction {
        jdbb_core::calib::Direction::Positive => 1.0,
        jdbb_core::calib::Direction::Negative => -1.0,
    };
    // The disc angle of an integer count is reduced exactly in integers.
    let n = enc.counts_per_rev as i64;
    let psi = (count.rem_euclid(n)) as f64 * step_rad;
    sign * (count - enc.zero_count) as f64 * step_rad - enc.zero_offset_rad
        + enc.eccentricity_rad * (psi + enc.eccentricity_phase_rad).sin()
}

/// The real count at which `enc` reads `theta_rad`: (G9) solved by Newton's method (the reading
/// grows strictly with the count for e < 1).
pub fn encoder_count_real(enc: &EncoderCal, theta_rad: f64) -> f64 {
    let step_rad = std::f64::consts::TAU / enc.counts_per_rev as f64;
    let sign = match enc.direction {
        jdbb_core::calib::Direction::Positive => 1.0,
        jdbb_core::calib::Direction::Negative => -1.0,
    };
    let z = enc.zero_count as f64;
    let (e, ph) = (enc.eccentricity_rad, enc.eccentricity_phase_rad);
    let reading = |c: f64| {
        sign * (c - z) * step_rad - enc.zero_offset_rad + e * (disc_angle_rad(enc, c) + ph).sin()
    };
    let mut c = z + sign * (theta_rad + enc.zero_offset_rad) / step_rad;
    for _ in 0..50 {
        let slope = step_rad * (sign + e * (disc_angle_rad(enc, c) + ph).cos());
        let dc = (reading(c) - theta_rad) / slope;
        c -= dc;
        if dc.abs() < 1e-9 {
            break;
        }
    }
    c
}
