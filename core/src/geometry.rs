//! The instrument model: encoder counts → frame angles → direction of bar 2 → joint deflection φ →
//! ball distance D; its inverse for simulation; the sensitivity of D to one count and to every
//! instrument parameter; and the on-chip evaluation ([`Kernel`]).
//!
//! # Conventions
//!
//! Bar-1 frame: origin at the joint centre J, +z along bar 1 *away from* the table ball, so the
//! table ball B1 is at −L1·ẑ. x̂ is the direction of frame 1's pivot axis projected on the plane
//! normal to bar 1, ŷ = ẑ × x̂. Each mechanical decoupling frame (MDF) pivots about its axis a_k
//! and holds bar 2 in its slot plane, which contains a_k; the two slots cross in the square hole
//! through which bar 2 passes. Frame angles θ₁ (= α, encoder 1) and θ₂ (= β, encoder 2) are
//! right-handed rotations about a₁ ≈ +x̂ and a₂ ≈ +ŷ: positive α turns bar 2 towards −y, positive
//! β towards +x. A frame is at zero when its slot plane is parallel to bar 1; for a perfect
//! instrument both are at zero when bar 2 continues bar 1 straight. The lean azimuth ψ of bar 2
//! is measured in bar 1's frame from +x towards +y.
//!
//! # The perfect instrument (seed 000, section 2; derived here because the paper gives no formula)
//!
//! Frame 1 turned by α holds bar 2 in the plane spanned by x̂ and (0, −sin α, cos α); frame 2
//! turned by β in the plane spanned by ŷ and (sin β, 0, cos β). Their intersection is bar 2:
//!
//! ```text
//!   u = (tan β, −tan α, 1) / n,   n = √(1 + tan²α + tan²β),   cos φ = u_z              (G1)
//!   D² = |L2·u + L1·ẑ|² = L1² + L2² + 2·L1·L2·cos φ                                    (G2)
//! ```
//!
//! (φ = 0: bars collinear, D = L1 + L2.) Near φ = 0, `1 − cos φ` cancels catastrophically, so it
//! is never formed by subtraction: with S = L1 + L2, K = 2·L1·L2 and q = 1 − cos φ ≥ 0 computed
//! from small quantities ((G8)),
//!
//! ```text
//!   D = S − Δ,   Δ = K·q / (S + √(S² − K·q))                                             (G3)
//! ```
//!
//! # The instrument as built
//!
//! Parameters: [`Calibration`] (field docs say each one's sign). s_k, c_k are sin θ_k, cos θ_k.
//!
//! **Pivot axes** (skew γ between them in the plane normal to bar 1, frame 2's axis rotated about
//! bar 1 so that the angle between the axes is 90° + γ; tilt τ_k of each axis out of that plane,
//! towards +z):
//!
//! ```text
//!   a₁ = (cos τ₁, 0, sin τ₁),   a₂ = (−sin γ·cos τ₂, cos γ·cos τ₂, sin τ₂)                 (G4)
//! ```
//!
//! **Slot planes.** The plane of frame k contains a_k; at θ_k = 0 it also contains ẑ, so its unit
//! normal is n₁⁰ = ẑ × a₁/|·| = ŷ, n₂⁰ = a₂ × ẑ/|·| = (cos γ, sin γ, 0). Turning the frame by θ_k
//! turns the normal about a_k (Rodrigues, n_k⁰ ⊥ a_k): n_k = cos θ_k·n_k⁰ + sin θ_k·m_k⁰ with
//! m_k⁰ = a_k × n_k⁰, i.e.
//!
//! ```text
//!   n₁ = (−s₁·sin τ₁,  c₁,  s₁·cos τ₁)
//!   n₂ = (c₂·cos γ − s₂·sin τ₂·sin γ,  c₂·sin γ + s₂·sin τ₂·cos γ,  −s₂·cos τ₂)            (G5)
//! ```
//!
//! **Grip of bar 2.** Bar 2's axis passes through J (the spherical joint) and crosses frame k's
//! slot plane at distance r_k from J, where the frame grips it. If the pivot axis passes at p_k
//! from J instead of through it, the slot plane misses J by p_k·n_k, so the grip point r_k·u lies
//! on it when
//!
//! ```text
//!   u·n_k = ρ_k(θ_k) = p_k·n_k(θ_k)/r_k = ν_k·cos θ_k + μ_k·sin θ_k                         (G6)
//! ```
//!
//! with ν_k = p_k·n_k⁰/r_k, μ_k = p_k·m_k⁰/r_k (the offset's component along a_k has no effect).
//!
//! **Direction of bar 2.** The solution of u·n₁ = ρ₁, u·n₂ = ρ₂, |u| = 1 on the side of
//! w = n₂ × n₁ (u_z > 0 over the working range), with g = n₁·n₂ and |w|² = 1 − g²:
//!
//! ```text
//!   λ₁ = (ρ₁ − g·ρ₂)/|w|²,  λ₂ = (ρ₂ − g·ρ₁)/|w|²,  η = √(1 − λ₁ρ₁ − λ₂ρ₂)
//!   u = λ₁·n₁ + λ₂·n₂ + η·w/|w|                                                            (G7)
//! ```
//!
//! For γ = τ = ν = μ = 0, w = (s₂c₁, −s₁c₂, c₁c₂) = c₁c₂·(tan β, −tan α, 1): (G7) is (G1).
//!
//! **Deflection without cancellation.** u_x, u_y are sums of products that vanish with the frame
//! angles (no large terms cancel), so
//!
//! ```text
//!   q = 1 − cos φ = 1 − u_z = (u_x² + u_y²)/(1 + u_z)                                       (G8)
//! ```
//!
//! and (G3) gives D.
//!
//! **Encoders** (eq. (G9), see [`EncoderCal`]): the true frame angle
//! from an extended count c, with the disc's own angle ψ = 2π·(c mod N)/N,
//!
//! ```text
//!   θ = s·(c − z)·2π/N − ζ + e·sin(ψ + φₑ)                                                (G9)
//! ```
//!
//! **Inverse** (simulation, D and lean azimuth ψ → counts): (G2) gives φ, hence
//! u = (sin φ cos ψ, sin φ sin ψ, cos φ); (G6) with (G5) is linear in (cos θ_k, sin θ_k):
//!
//! ```text
//!   (u·n_k⁰ − ν_k)·cos θ_k + (u·m_k⁰ − μ_k)·sin θ_k = 0
//!   θ_k = atan(−(u·n_k⁰ − ν_k)/(u·m_k⁰ − μ_k))   (the root with |θ_k| < 90°)                 (G10)
//! ```
//!
//! and (G9) is solved for c by fixed-point iteration.
//!
//! **Partial derivatives** (for the host's least-squares fit): implicit differentiation of (G6)
//! with |u| = 1 gives, for any parameter p of (G4)–(G6), with h the solution of
//! h₁·n₁ + h₂·n₂ + h₃·u = ẑ,
//!
//! ```text
//!   ∂u_z/∂p = −h₁·(u·∂n₁/∂p − ∂ρ₁/∂p) − h₂·(u·∂n₂/∂p − ∂ρ₂/∂p)
//!   ∂D/∂p = (L1·L2/D)·∂u_z/∂p,  ∂D/∂L1 = (L1 + L2·u_z)/D,  ∂D/∂L2 = (L2 + L1·u_z)/D          (G11)
//! ```
//!
//! and the encoder parameters act through θ_k: ∂θ/∂ζ = −1, ∂θ/∂a = sin ψ, ∂θ/∂b = cos ψ for
//! e·sin(ψ + φₑ) = a·sin ψ + b·cos ψ.
//!
//! # What the model leaves out, and why
//!
//! - **Bar lengths**: with L1 = L2, D is symmetric in L1 ↔ L2 (only the sum is identifiable from
//!   D); both are parameters so unequal bars can be fitted.
//! - **Play of bar 2 in the square hole**: a clearance c at grip radius r lets bar 2 lag by up to
//!   ±c/(2r) in the direction of motion (2 µm at r = 20 mm: ±10″, ±1 µm in D at mid-range). It is
//!   hysteresis, not a function of the counts, so no static calibration can hold it; it appears at
//!   reversals like machine backlash. The hole must be preloaded (zero clearance).
//! - **Ball 2 off the bar axis**: bar 2 is free to spin about its own axis in a round-section
//!   design and the spin is not measured, so an offset o of the ball from the axis moves D by up
//!   to o·L1·sin φ/D depending on an unmeasured angle. It must be kept small by construction.
//! - **Encoder interpolation (sub-divisional) error**: periodic with the encoder's signal period
//!   (40″ for 2¹⁵ lines), a few tens of nm in D for a good interpolator; an encoder property far
//!   above the frequencies a static calibration resolves.
//! - **Higher harmonics of the disc error** (twice per turn: disc tilt, ellipticity): an order of
//!   magnitude below eccentricity on a properly mounted disc; would enter (G9) like e.
//! - **Nearly confounded terms**: ν_k acts like the zero ζ_k and the cosine part of the
//!   eccentricity, μ_k like its sine part, differing only by the factor 1/cos χ (χ: bar 2's angle
//!   within the slot); a fit needs the knee swung over a wide range of both frames to tell them.
//!
//! # On-chip arithmetic and error budget
//!
//! The Cortex-M4F has a single-precision FPU and f64 is emulated in software (hundreds of cycles per
//! operation), while the budget is 2 000 instructions per sample. f32 alone cannot meet 10 nm: at
//! the corner of the working range Δ ≈ 23 mm, where one f32 ulp is 1.9 nm, and a dozen chained f32
//! roundings reach 5–10 nm. So [`Kernel`] splits the work by size:
//!
//! - **Large quantities in Q30 fixed point** (i32, 1 = 2³⁰, absolute resolution 9.3e-10): the frame
//!   angle `steps × rad_per_count` as an exact 32×32→64-bit product; its sin and cos from a table
//!   at 1/16 rad rotated by the remainder; the products s₂c₁, s₁c₂, c₁c₂ of (G7); N = w_x² + w_y²
//!   and M = |w|² exactly in 64 bits; q_w as the root of R(q) = q(2 − q)·M − N (f32 seed, one
//!   Newton step on the exact residual: a small correction, never 1 − cos φ by subtraction); and
//!   D = S·√y, y = 1 − (K/S²)·q (√ seeded by the FPU, refined on the exact residual y − t₀²).
//!   Fixed-point subtraction is exact, so D carries only √y's absolute error (≈ 2e-9, 0.2 nm at
//!   S = 100 mm) however small the deflection: nothing cancels.
//! - **Small corrections in f32** (|·| ≲ 0.05, so f32's relative 6e-8 is ≲ 3e-9 absolute): the
//!   rotation from the table angle by the remainder, the zero and the eccentricity; the skew/tilt
//!   terms of w; and the pivot-offset terms (q = q_w + (1 − η)(1 − q_w) − ε, ε = λ₁n₁z + λ₂n₂z,
//!   from (G7)).
//! - **One f64 at the end**: D·2⁴⁸ as a 64-bit integer (S·2⁴⁸ × t), whose bits become the f64.
//!
//! Cost ≈ 450 instructions per sample whatever the calibration (`scripts/fw-cycles.sh`), about as
//! much as the f32 kernel of the perfect-instrument model took.
//!
//! The budget is checked, not assumed: `tests/tests/qemu_accuracy.rs` runs [`Kernel`] on the
//! Cortex-M4F in QEMU over grids covering [`FRAME_RANGE_RAD`] for the default instrument, for one
//! with every error term non-zero and for the 20 000-count instrument, and compares with
//! [`distance_mm`] (worst 0.25 nm).

use crate::calib::{Calibration, EncoderCal, N_PARAMS};
use crate::math;

/// Mechanical range of each decoupling frame, ±75° (rad). Beyond it the frames' slots foul the bar;
/// the accuracy budget is proven over this range.
pub const FRAME_RANGE_RAD: f64 = 75.0 * core::f64::consts::PI / 180.0;

/// Largest |frame angle| (rad, 86°) the on-chip [`Kernel`] evaluates; beyond it (where no real frame
/// can be) it returns NaN.
pub const KERNEL_RANGE_RAD: f64 = 1.5;

type V3 = [f64; 3];

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// 1 − cos x without cancellation.
fn one_minus_cos(x: f64) -> f64 {
    let h = math::sin(0.5 * x);
    2.0 * h * h
}

/// The extended instrument model in f64 with its constants ((G4)–(G6), (G9)) prepared once for one
/// calibration: the host's reference. Build one per calibration and evaluate many samples with it
/// (a least-squares fit, recomputing a record); the free functions of this module are shorthands
/// that build one per call.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Model {
    cal: Calibration,
    /// sin, cos of τ₁, τ₂, γ.
    st: [f64; 2],
    ct: [f64; 2],
    sg: f64,
    cg: f64,
    /// Eccentricity components (a, b) per encoder: e·sin(ψ + φₑ) = a·sin ψ + b·cos ψ.
    ecc: [(f64, f64); 2],
}

/// The slot planes at one pair of frame angles: (G5) and (G6).
struct Planes {
    s: [f64; 2],
    c: [f64; 2],
    n1: V3,
    n2: V3,
    rho: [f64; 2],
}

/// Bar 2's direction from the two slot planes and grip offsets, eq. (G7).
fn direction(p: &Planes) -> V3 {
    let w = cross(p.n2, p.n1);
    let w2 = dot(w, w);
    let wn = math::sqrt(w2);
    let [r1, r2] = p.rho;
    if r1 == 0.0 && r2 == 0.0 {
        return [w[0] / wn, w[1] / wn, w[2] / wn];
    }
    let g = dot(p.n1, p.n2);
    let l1 = (r1 - g * r2) / w2;
    let l2 = (r2 - g * r1) / w2;
    let eta = math::sqrt(1.0 - l1 * r1 - l2 * r2);
    core::array::from_fn(|i| l1 * p.n1[i] + l2 * p.n2[i] + eta * w[i] / wn)
}

/// 1 − cos φ for a unit direction u of bar 2, eq. (G8): no cancellation near φ = 0.
pub fn one_minus_cos_deflection(u: [f64; 3]) -> f64 {
    (u[0] * u[0] + u[1] * u[1]) / (1.0 + u[2])
}

/// Ball distance D (mm) from q = 1 − cos φ, eq. (G3).
pub fn distance_from_one_minus_cos_mm(l1_mm: f64, l2_mm: f64, q: f64) -> f64 {
    let s = l1_mm + l2_mm;
    let k = 2.0 * l1_mm * l2_mm * q;
    s - k / (s + math::sqrt(s * s - k))
}

/// Ball distance D (mm) from the deflection φ, eq. (G2) in the cancellation-free form of (G3):
/// 1 − cos φ = 2 sin²(φ/2).
pub fn distance_from_deflection_mm(l1_mm: f64, l2_mm: f64, phi_rad: f64) -> f64 {
    distance_from_one_minus_cos_mm(l1_mm, l2_mm, one_minus_cos(phi_rad))
}

impl Model {
    /// Prepare the model for `cal`.
    pub fn new(cal: &Calibration) -> Self {
        let (st1, ct1) = math::sin_cos(cal.frame1.tilt_rad);
        let (st2, ct2) = math::sin_cos(cal.frame2.tilt_rad);
        let (sg, cg) = math::sin_cos(cal.axes_skew_rad);
        Model {
            cal: *cal,
            st: [st1, st2],
            ct: [ct1, ct2],
            sg,
            cg,
            ecc: [
                cal.enc1.eccentricity_components(),
                cal.enc2.eccentricity_components(),
            ],
        }
    }

    /// The calibration this model evaluates.
    pub fn calibration(&self) -> &Calibration {
        &self.cal
    }

    /// True frame angle θ_k (rad) of encoder k (0 or 1) at an extended count, eq. (G9), with
    /// (sin ψ, cos ψ) of the disc angle (for the gradient).
    fn angle_and_disc(&self, k: usize, count: i64) -> (f64, (f64, f64)) {
        let e = if k == 0 {
            &self.cal.enc1
        } else {
            &self.cal.enc2
        };
        let steps = count.wrapping_sub(e.zero_count) * e.direction.sign();
        let theta = steps as f64 * e.rad_per_count() - e.zero_offset_rad;
        let (a, b) = self.ecc[k];
        if a == 0.0 && b == 0.0 {
            return (theta, (0.0, 1.0));
        }
        let (sp, cp) = math::sin_cos(e.disc_angle_rad(count));
        (theta + a * sp + b * cp, (sp, cp))
    }

    /// True frame angles (θ₁, θ₂) = (α, β) in rad for two extended counts, eq. (G9).
    pub fn frame_angles_rad(&self, enc1: i64, enc2: i64) -> (f64, f64) {
        (
            self.angle_and_disc(0, enc1).0,
            self.angle_and_disc(1, enc2).0,
        )
    }

    fn planes(&self, theta1: f64, theta2: f64) -> Planes {
        let (s1, c1) = math::sin_cos(theta1);
        let (s2, c2) = math::sin_cos(theta2);
        let [st1, st2] = self.st;
        let [ct1, ct2] = self.ct;
        let (sg, cg) = (self.sg, self.cg);
        let f1 = &self.cal.frame1;
        let f2 = &self.cal.frame2;
        Planes {
            s: [s1, s2],
            c: [c1, c2],
            n1: [-s1 * st1, c1, s1 * ct1],
            n2: [c2 * cg - s2 * st2 * sg, c2 * sg + s2 * st2 * cg, -s2 * ct2],
            rho: [
                f1.offset_normal_rad * c1 + f1.offset_axial_rad * s1,
                f2.offset_normal_rad * c2 + f2.offset_axial_rad * s2,
            ],
        }
    }

    /// Unit direction of bar 2 in bar 1's frame at true frame angles θ₁, θ₂ (rad), (G4)–(G7).
    pub fn bar2_direction(&self, theta1_rad: f64, theta2_rad: f64) -> [f64; 3] {
        direction(&self.planes(theta1_rad, theta2_rad))
    }

    /// Ball distance D (mm) at true frame angles θ₁, θ₂ (rad): (G4)–(G8), (G3).
    pub fn distance_from_angles_mm(&self, theta1_rad: f64, theta2_rad: f64) -> f64 {
        let u = self.bar2_direction(theta1_rad, theta2_rad);
        distance_from_one_minus_cos_mm(self.cal.l1_mm, self.cal.l2_mm, one_minus_cos_deflection(u))
    }

    /// Ball distance D (mm) for two extended encoder counts.
    pub fn distance_mm(&self, enc1: i64, enc2: i64) -> f64 {
        let (t1, t2) = self.frame_angles_rad(enc1, enc2);
        self.distance_from_angles_mm(t1, t2)
    }

    /// D and its partial derivatives with respect to θ₁, θ₂ and the geometric parameters, (G11).
    fn angle_partials(&self, theta1: f64, theta2: f64) -> AnglePartials {
        let p = self.planes(theta1, theta2);
        let u = direction(&p);
        let (l1, l2) = (self.cal.l1_mm, self.cal.l2_mm);
        let d = distance_from_one_minus_cos_mm(l1, l2, one_minus_cos_deflection(u));
        let [s1, s2] = p.s;
        let [c1, c2] = p.c;
        let [st1, st2] = self.st;
        let [ct1, ct2] = self.ct;
        let (sg, cg) = (self.sg, self.cg);
        let f1 = &self.cal.frame1;
        let f2 = &self.cal.frame2;
        // h₁n₁ + h₂n₂ + h₃u = ẑ by Cramer's rule.
        let n2xu = cross(p.n2, u);
        let det = dot(p.n1, n2xu);
        let h1 = n2xu[2] / det;
        let h2 = cross(u, p.n1)[2] / det;
        // ∂D for a change of plane k's normal by dn and of its offset by drho.
        let k = l1 * l2 / d;
        let dd1 = |dn: V3, drho: f64| -k * h1 * (dot(u, dn) - drho);
        let dd2 = |dn: V3, drho: f64| -k * h2 * (dot(u, dn) - drho);
        let dn1_dt1 = [-c1 * st1, -s1, c1 * ct1];
        let dn2_dt2 = [
            -s2 * cg - c2 * st2 * sg,
            -s2 * sg + c2 * st2 * cg,
            -c2 * ct2,
        ];
        let dn2_dg = [-c2 * sg - s2 * st2 * cg, c2 * cg - s2 * st2 * sg, 0.0];
        let dn1_dtau1 = [-s1 * ct1, 0.0, -s1 * st1];
        let dn2_dtau2 = [-s2 * ct2 * sg, s2 * ct2 * cg, s2 * st2];
        let drho1 = -f1.offset_normal_rad * s1 + f1.offset_axial_rad * c1;
        let drho2 = -f2.offset_normal_rad * s2 + f2.offset_axial_rad * c2;
        let z = [0.0; 3];
        AnglePartials {
            d_mm: d,
            d_theta: [dd1(dn1_dt1, drho1), dd2(dn2_dt2, drho2)],
            d_geom: [
                (l1 + l2 * u[2]) / d,
                (l2 + l1 * u[2]) / d,
                dd2(dn2_dg, 0.0),
                dd1(dn1_dtau1, 0.0),
                dd2(dn2_dtau2, 0.0),
                dd1(z, c1),
                dd1(z, s1),
                dd2(z, c2),
                dd2(z, s2),
            ],
        }
    }

    /// D (mm) and its analytic partial derivatives with respect to every continuous instrument
    /// parameter, in [`Param::ALL`](crate::calib::Param::ALL) order (mm/mm for lengths, mm/rad
    /// for angles), at two extended counts: (G11) with (G9). The Jacobian row of a least-squares
    /// fit of the instrument to samples (enc1, enc2, d_ref_mm).
    pub fn distance_and_gradient(&self, enc1: i64, enc2: i64) -> (f64, [f64; N_PARAMS]) {
        let (t1, (sp1, cp1)) = self.angle_and_disc(0, enc1);
        let (t2, (sp2, cp2)) = self.angle_and_disc(1, enc2);
        // The components' derivatives need the disc angle even where the eccentricity is zero.
        let disc = |k: usize, count: i64, sc: (f64, f64)| {
            if self.ecc[k] == (0.0, 0.0) {
                let e = if k == 0 {
                    &self.cal.enc1
                } else {
                    &self.cal.enc2
                };
                math::sin_cos(e.disc_angle_rad(count))
            } else {
                sc
            }
        };
        let (sp1, cp1) = disc(0, enc1, (sp1, cp1));
        let (sp2, cp2) = disc(1, enc2, (sp2, cp2));
        let ap = self.angle_partials(t1, t2);
        let [dt1, dt2] = ap.d_theta;
        let g = ap.d_geom;
        (
            ap.d_mm,
            [
                g[0],
                g[1],
                -dt1,
                -dt2,
                dt1 * sp1,
                dt1 * cp1,
                dt2 * sp2,
                dt2 * cp2,
                g[2],
                g[3],
                g[4],
                g[5],
                g[6],
                g[7],
                g[8],
            ],
        )
    }

    /// ∂D/∂θ₁ and ∂D/∂θ₂ (mm/rad) at true frame angles, (G11).
    pub fn distance_per_angle_mm_per_rad(&self, theta1_rad: f64, theta2_rad: f64) -> [f64; 2] {
        self.angle_partials(theta1_rad, theta2_rad).d_theta
    }

    /// Sensitivity of D to one count of each encoder, [dD/dcount1, dD/dcount2] in mm per count,
    /// at two extended counts: ∂D/∂θ_k (G11) times dθ_k/dc (G9).
    pub fn sensitivity_mm_per_count(&self, enc1: i64, enc2: i64) -> [f64; 2] {
        let (t1, t2) = self.frame_angles_rad(enc1, enc2);
        let [d1, d2] = self.distance_per_angle_mm_per_rad(t1, t2);
        [
            d1 * self.cal.enc1.angle_per_count_rad(enc1),
            d2 * self.cal.enc2.angle_per_count_rad(enc2),
        ]
    }

    /// True frame angles (θ₁, θ₂) that hold bar 2 along the unit direction u, eq. (G10): the
    /// inverse of [`Self::bar2_direction`] (frame angles within ±90°).
    pub fn frame_angles_for_direction(&self, u: [f64; 3]) -> (f64, f64) {
        let [st1, st2] = self.st;
        let [ct1, ct2] = self.ct;
        let (sg, cg) = (self.sg, self.cg);
        let solve = |n0: V3, m0: V3, nu: f64, mu: f64| {
            let a = dot(u, n0) - nu;
            let b = dot(u, m0) - mu;
            // A cos θ + B sin θ = 0, the root with |θ| < π/2.
            math::atan2(if b < 0.0 { a } else { -a }, b.abs())
        };
        let f1 = &self.cal.frame1;
        let f2 = &self.cal.frame2;
        (
            solve(
                [0.0, 1.0, 0.0],
                [-st1, 0.0, ct1],
                f1.offset_normal_rad,
                f1.offset_axial_rad,
            ),
            solve(
                [cg, sg, 0.0],
                [-st2 * sg, st2 * cg, -ct2],
                f2.offset_normal_rad,
                f2.offset_axial_rad,
            ),
        )
    }

    /// Extended counts (enc1, enc2) that put the balls `d_mm` apart with bar 2 leaning towards
    /// azimuth ψ: D → φ (G2) → u → (θ₁, θ₂) (G10) → counts (G9). `None` if `d_mm` is out of reach
    /// or the frames would leave [`FRAME_RANGE_RAD`].
    pub fn counts_for_distance(&self, d_mm: f64, psi_rad: f64) -> Option<(i64, i64)> {
        let cal = &self.cal;
        let phi = deflection_for_distance_rad(cal.l1_mm, cal.l2_mm, d_mm)?;
        if phi >= core::f64::consts::FRAC_PI_2 {
            return None;
        }
        let (t1, t2) = self.frame_angles_for_direction(direction_for_deflection(phi, psi_rad));
        if t1.abs() > FRAME_RANGE_RAD || t2.abs() > FRAME_RANGE_RAD {
            return None;
        }
        Some((cal.enc1.count_for_angle(t1), cal.enc2.count_for_angle(t2)))
    }
}

/// D and its partial derivatives with respect to the true frame angles and the geometric
/// parameters, eq. (G11).
struct AnglePartials {
    d_mm: f64,
    /// ∂D/∂θ₁, ∂D/∂θ₂ (mm/rad).
    d_theta: [f64; 2],
    /// ∂D/∂L1, ∂D/∂L2, ∂D/∂γ, ∂D/∂τ₁, ∂D/∂τ₂, ∂D/∂ν₁, ∂D/∂μ₁, ∂D/∂ν₂, ∂D/∂μ₂.
    d_geom: [f64; 9],
}

/// On-chip accuracy budget for D (mm) at a pair of counts: 10 nm, or 1 % of the larger change of D
/// caused by one count of either encoder, whichever is larger.
pub fn accuracy_budget_mm(cal: &Calibration, enc1: i64, enc2: i64) -> f64 {
    let [s1, s2] = sensitivity_mm_per_count(cal, enc1, enc2);
    f64::max(1e-5, 0.01 * f64::max(s1.abs(), s2.abs()))
}

/// True frame angles (θ₁, θ₂) = (α, β) in rad for two extended counts, eq. (G9) (host reference).
pub fn frame_angles_rad(cal: &Calibration, enc1: i64, enc2: i64) -> (f64, f64) {
    Model::new(cal).frame_angles_rad(enc1, enc2)
}

/// Unit direction of bar 2 in bar 1's frame at true frame angles θ₁, θ₂ (rad), eq. (G4)–(G7).
pub fn bar2_direction(cal: &Calibration, theta1_rad: f64, theta2_rad: f64) -> [f64; 3] {
    Model::new(cal).bar2_direction(theta1_rad, theta2_rad)
}

/// Joint deflection φ (rad) at true frame angles θ₁, θ₂: the angle between bar 2 and the
/// continuation of bar 1, accurate near zero.
pub fn deflection_rad(cal: &Calibration, theta1_rad: f64, theta2_rad: f64) -> f64 {
    let u = bar2_direction(cal, theta1_rad, theta2_rad);
    math::atan2(math::sqrt(u[0] * u[0] + u[1] * u[1]), u[2])
}

/// Ball distance D (mm) at true frame angles θ₁, θ₂ (rad): (G4)–(G8), (G3).
pub fn distance_from_angles_mm(cal: &Calibration, theta1_rad: f64, theta2_rad: f64) -> f64 {
    Model::new(cal).distance_from_angles_mm(theta1_rad, theta2_rad)
}

/// Ball distance D (mm) for two extended encoder counts: the host's f64 reference of the extended
/// model, (G9) then (G4)–(G8), (G3). Computed a different way from [`Kernel`] (the explicit
/// vector u of (G7) here; fixed-point q_w plus small corrections there), so the on-chip check
/// compares two independent evaluations. For many samples, build a [`Model`] once.
pub fn distance_mm(cal: &Calibration, enc1: i64, enc2: i64) -> f64 {
    Model::new(cal).distance_mm(enc1, enc2)
}

/// D (mm) and its analytic partial derivatives with respect to every continuous instrument
/// parameter at two extended counts: [`Model::distance_and_gradient`].
pub fn distance_and_gradient(cal: &Calibration, enc1: i64, enc2: i64) -> (f64, [f64; N_PARAMS]) {
    Model::new(cal).distance_and_gradient(enc1, enc2)
}

/// ∂D/∂θ₁ and ∂D/∂θ₂ (mm/rad) at true frame angles, (G11).
pub fn distance_per_angle_mm_per_rad(
    cal: &Calibration,
    theta1_rad: f64,
    theta2_rad: f64,
) -> [f64; 2] {
    Model::new(cal).distance_per_angle_mm_per_rad(theta1_rad, theta2_rad)
}

/// Sensitivity of D to one count of each encoder, [dD/dcount1, dD/dcount2] in mm per count, at
/// two extended counts: [`Model::sensitivity_mm_per_count`].
pub fn sensitivity_mm_per_count(cal: &Calibration, enc1: i64, enc2: i64) -> [f64; 2] {
    Model::new(cal).sensitivity_mm_per_count(enc1, enc2)
}

/// Inverse of (G2): the deflection φ (rad) at which the balls are `d_mm` apart, or `None` if no
/// pose of the bars gives that distance (outside |L1 − L2| ..= L1 + L2). Uses
/// 1 − cos φ = (S − D)(S + D) / (2 L1 L2) to stay accurate near φ = 0.
pub fn deflection_for_distance_rad(l1_mm: f64, l2_mm: f64, d_mm: f64) -> Option<f64> {
    let s = l1_mm + l2_mm;
    if !(d_mm.is_finite() && ((l1_mm - l2_mm).abs()..=s).contains(&d_mm)) {
        return None;
    }
    let q = (s - d_mm) * (s + d_mm) / (2.0 * l1_mm * l2_mm); // 1 − cos φ ∈ [0, 2]
    let half_sin = math::sqrt(0.5 * q).min(1.0); // sin(φ/2)
    Some(2.0 * libm::asin(half_sin))
}

/// Unit direction of bar 2 deflected by φ towards lean azimuth ψ (rad, from +x towards +y in bar
/// 1's frame): (sin φ cos ψ, sin φ sin ψ, cos φ).
pub fn direction_for_deflection(phi_rad: f64, psi_rad: f64) -> [f64; 3] {
    let (sp, cp) = math::sin_cos(phi_rad);
    let (ss, cs) = math::sin_cos(psi_rad);
    [sp * cs, sp * ss, cp]
}

/// True frame angles (θ₁, θ₂) that hold bar 2 along the unit direction u, eq. (G10):
/// [`Model::frame_angles_for_direction`].
pub fn frame_angles_for_direction(cal: &Calibration, u: [f64; 3]) -> (f64, f64) {
    Model::new(cal).frame_angles_for_direction(u)
}

/// Extended counts (enc1, enc2) that put the balls `d_mm` apart with bar 2 leaning towards azimuth
/// ψ: the simulation path, [`Model::counts_for_distance`].
pub fn counts_for_distance(cal: &Calibration, d_mm: f64, psi_rad: f64) -> Option<(i64, i64)> {
    Model::new(cal).counts_for_distance(d_mm, psi_rad)
}

// ---------------------------------------------------------------------------------------------
// On-chip kernel
// ---------------------------------------------------------------------------------------------

/// Q30 fixed point: 1.0 = 2³⁰.
const ONE: i32 = 1 << 30;
const ONE_F: f32 = ONE as f32;
const INV_ONE_F: f32 = 1.0 / ONE_F;

/// sin and cos of j/16 rad, j = 0..=25, in Q30 (rounded; checked against libm in the tests).
#[rustfmt::skip]
const SIN_COS_Q30: [(i32, i32); 26] = [
    (0, 1073741824), (67065182, 1071645355), (133868476, 1065364133), (200149016, 1054922687),
    (265647978, 1040361791), (330109591, 1021738304), (393282133, 999124951),
    (454918917, 972610037), (514779252, 942297101), (572629385, 908304515),
    (628243413, 870765019), (681404164, 829825205), (731904045, 785644941),
    (779545858, 738396750), (824143560, 688265136), (865522999, 635445861),
    (903522590, 580145183), (937993944, 522579052), (968802452, 462972260),
    (995827807, 401557571), (1018964476, 338574809), (1038122110, 274269919),
    (1053225900, 208894011), (1064216865, 142702376), (1071052086, 75953492),
    (1073704872, 8908011),
];

/// One table row: the Q30 values and the same as f32 (for the small corrections).
#[derive(Clone, Copy)]
struct TableRow {
    s: i32,
    c: i32,
    sf: f32,
    cf: f32,
}

const SIN_COS_TABLE: [TableRow; 26] = {
    let mut t = [TableRow {
        s: 0,
        c: 0,
        sf: 0.0,
        cf: 0.0,
    }; 26];
    let mut i = 0;
    while i < t.len() {
        let (s, c) = SIN_COS_Q30[i];
        t[i] = TableRow {
            s,
            c,
            sf: s as f32 * INV_ONE_F,
            cf: c as f32 * INV_ONE_F,
        };
        i += 1;
    }
    t
};

/// a·b in Q30 (truncated).
#[inline(always)]
fn qmul(a: i32, b: i32) -> i32 {
    ((a as i64 * b as i64) >> 30) as i32
}

#[inline(always)]
fn q2f(a: i32) -> f32 {
    a as f32 * INV_ONE_F
}

/// A small f32 (|x| < 2) in Q30 (truncated; `as` saturates, so nothing can panic).
#[inline(always)]
fn f2q(x: f32) -> i32 {
    (x * ONE_F) as i32
}

/// One encoder's constants for the kernel.
#[derive(Debug, Clone, Copy, PartialEq)]
struct EncKernel {
    zero: i64,
    /// ±1: the encoder's direction.
    sign: i32,
    /// Largest |count − zero| inside [`KERNEL_RANGE_RAD`].
    max_steps: u64,
    /// rad_per_count = mant·2^−(30+shift), mant ∈ [2³⁰, 2³¹), shift ≤ 31.
    mant: i32,
    shift: u32,
    rad_per_count: f32,
    zeta: f32,
    /// The eccentricity e·sin(ψ + φₑ) as ecc_sin·sin m + ecc_cos·cos m of the measured angle m.
    ecc_sin: f32,
    ecc_cos: f32,
}

/// sin and cos of one true frame angle: Q30 for the large path, f32 for the corrections.
#[derive(Clone, Copy)]
struct Trig {
    s: i32,
    c: i32,
    sf: f32,
    cf: f32,
}

impl EncKernel {
    fn new(e: &EncoderCal) -> Self {
        let rpc = e.rad_per_count();
        let mut shift = 0u32;
        while rpc * ((1u64 << (30 + shift)) as f64) < (1u64 << 30) as f64 && shift < 31 {
            shift += 1;
        }
        let mant = math::round(rpc * (1u64 << (30 + shift)) as f64).min(i32::MAX as f64) as i32;
        let s = e.direction.sign() as f64;
        // ψ = ψ_z + s·m with ψ_z the disc angle at the zero count (G9), so with Φ = ψ_z + φₑ:
        // e·sin(ψ + φₑ) = s·e·cos Φ·sin m + e·sin Φ·cos m.
        let (sp, cp) =
            math::sin_cos_poly(e.disc_angle_rad(e.zero_count) + e.eccentricity_phase_rad);
        EncKernel {
            zero: e.zero_count,
            sign: e.direction.sign() as i32,
            max_steps: (KERNEL_RANGE_RAD / rpc) as u64,
            mant,
            shift,
            rad_per_count: rpc as f32,
            zeta: e.zero_offset_rad as f32,
            ecc_sin: (s * e.eccentricity_rad * cp) as f32,
            ecc_cos: (e.eccentricity_rad * sp) as f32,
        }
    }

    /// Steps from the zero count in the frame's positive sense, if inside the kernel's range.
    #[inline(always)]
    fn steps(&self, count: i64) -> Option<i32> {
        let d = count.wrapping_sub(self.zero);
        // |d| ≤ max ⇔ d + max ∈ [0, 2·max] (unsigned).
        if (d as u64).wrapping_add(self.max_steps) > 2 * self.max_steps {
            return None;
        }
        Some((d as i32).wrapping_mul(self.sign))
    }

    /// sin and cos of the true angle θ = m + δ (G9) for one count, m = steps·δc the measured angle
    /// and δ = −ζ + eccentricity. With a = |m| = θ_j + r (θ_j = j/16 the nearest table angle,
    /// |r| ≤ 1/32) and ρ = r ± δ the whole rotation from the table angle:
    ///
    /// sin(θ_j + ρ) = s_j + c_j·r + [c_j·(ρ − r) + c_j·(sin ρ − ρ) − s_j·(1 − cos ρ)]
    ///
    /// c_j·r exactly in Q30; the bracket (|·| ≤ 0.03) in f32, absolute error ≲ 2e-9.
    #[inline(always)]
    fn trig(&self, count: i64) -> Option<Trig> {
        let steps = self.steps(count)?;
        // m in Q30: exact 64-bit product, one truncation.
        let m = ((steps as i64 * self.mant as i64) >> (self.shift & 31)) as i32;
        let a = m.unsigned_abs();
        let j = (a + (1 << 25)) >> 26;
        let r = a.wrapping_sub(j << 26) as i32; // |r| ≤ 2²⁵, i.e. 1/32 rad
        let t = SIN_COS_TABLE[(j as usize).min(SIN_COS_TABLE.len() - 1)];
        let rf = q2f(r);
        let r2 = rf * rf;
        // sin a, cos a to ~1e-8 (r⁴/24 dropped) for the eccentricity term only.
        let sr = rf - rf * r2 * (1.0 / 6.0);
        let sa = t.sf + t.cf * sr - t.sf * (0.5 * r2);
        let ca = t.cf - t.sf * sr - t.cf * (0.5 * r2);
        let neg = m < 0;
        // δ = −ζ + a_e·sin m + b_e·cos m, and its sign in the |m| domain.
        let ecc_sa = if neg { -self.ecc_sin } else { self.ecc_sin } * sa;
        let delta = ecc_sa + self.ecc_cos * ca - self.zeta;
        let d = if neg { -delta } else { delta };
        let rho = rf + d;
        let p2 = rho * rho;
        let sin_rho_m = rho * p2 * (p2 * (1.0 / 120.0) - 1.0 / 6.0); // sin ρ − ρ
        let omc_rho = p2 * (0.5 - p2 * (1.0 / 24.0)); // 1 − cos ρ
        let lin = d + sin_rho_m;
        let s_small = t.cf * lin - t.sf * omc_rho;
        let c_small = -(t.sf * lin + t.cf * omc_rho);
        let s = t.s.wrapping_add(qmul(t.c, r)).wrapping_add(f2q(s_small));
        let c = t.c.wrapping_sub(qmul(t.s, r)).wrapping_add(f2q(c_small));
        let sf = t.sf + t.cf * rf + s_small;
        let cf = t.cf - t.sf * rf + c_small;
        Some(if neg {
            Trig {
                s: s.wrapping_neg(),
                c,
                sf: -sf,
                cf,
            }
        } else {
            Trig { s, c, sf, cf }
        })
    }
}

/// The on-chip evaluation of counts → D of the extended model (see the module's error budget):
/// Q30 fixed point for the large terms, f32 for the small corrections, one f64 at the end. Built
/// once from a [`Calibration`]; the host runs the same code and gets the chip's numbers bit for
/// bit (integer arithmetic, IEEE f32 without fused operations, correctly rounded √).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kernel {
    enc: [EncKernel; 2],
    /// Small parts of w = n₂ × n₁ beyond (s₂c₁, −s₁c₂, c₁c₂), as coefficients of the products
    /// (c₁s₂, s₁c₂, s₁s₂) for x, (s₁s₂, s₁c₂) for y, (c₁c₂, c₁s₂, s₁c₂, s₁s₂) for z.
    dwx: [f32; 3],
    dwy: [f32; 2],
    dwz: [f32; 4],
    /// g = n₁·n₂ as coefficients of (c₁c₂, c₁s₂, s₁c₂, s₁s₂).
    g: [f32; 4],
    /// n₁z = s₁·nz[0], n₂z = s₂·nz[1].
    nz: [f32; 2],
    nu: [f32; 2],
    mu: [f32; 2],
    /// K/S² in Q30.
    k_over_s2: i32,
    /// S·2⁴⁸.
    s_fixed: u64,
}

/// Fraction bits of [`Kernel`]'s S.
const S_BITS: u32 = 48;

impl Kernel {
    /// Precompute the constants from a calibration (call it with a validated one).
    pub fn new(cal: &Calibration) -> Self {
        // libm-free trigonometry (see `math::sin_cos_poly`): the firmware calls this.
        let sc = math::sin_cos_poly;
        // cos x − 1 = −2 sin²(x/2), without cancellation.
        let cm1 = |x: f64| {
            let h = sc(0.5 * x).0;
            -2.0 * h * h
        };
        let (st1, ct1) = sc(cal.frame1.tilt_rad);
        let (st2, ct2) = sc(cal.frame2.tilt_rad);
        let (sg, cg) = sc(cal.axes_skew_rad);
        let ct1m = cm1(cal.frame1.tilt_rad);
        let ct2m = cm1(cal.frame2.tilt_rad);
        let cgm = cm1(cal.axes_skew_rad);
        let ct1cg_m = ct1m * cg + cgm; // cos τ₁·cos γ − 1
        let s = cal.l1_mm + cal.l2_mm;
        let f = |x: f64| x as f32;
        Kernel {
            enc: [EncKernel::new(&cal.enc1), EncKernel::new(&cal.enc2)],
            dwx: [f(ct2m), f(ct1 * sg), f(ct1 * st2 * cg)],
            dwy: [f(ct2 * st1 + ct1 * st2 * sg), f(-ct1cg_m)],
            dwz: [f(cgm), f(-st2 * sg), f(st1 * sg), f(st1 * st2 * cg)],
            g: [
                f(sg),
                f(st2 * cg),
                f(-st1 * cg),
                f(st1 * st2 * sg - ct1 * ct2),
            ],
            nz: [f(ct1), f(-ct2)],
            nu: [
                f(cal.frame1.offset_normal_rad),
                f(cal.frame2.offset_normal_rad),
            ],
            mu: [
                f(cal.frame1.offset_axial_rad),
                f(cal.frame2.offset_axial_rad),
            ],
            k_over_s2: math::round(2.0 * cal.l1_mm * cal.l2_mm / (s * s) * ONE as f64) as i32,
            s_fixed: math::round(s * (1u64 << S_BITS) as f64) as u64,
        }
    }

    /// Frame angles (θ₁, θ₂) in rad, single precision, with the fine zeros but without the
    /// eccentricity (≤ its amplitude off): for range checks. +∞ outside the kernel's range.
    #[inline]
    pub fn frame_angles_rad(&self, enc1: i64, enc2: i64) -> (f32, f32) {
        let angle = |e: &EncKernel, count: i64| match e.steps(count) {
            Some(steps) => steps as f32 * e.rad_per_count - e.zeta,
            None => f32::INFINITY,
        };
        (angle(&self.enc[0], enc1), angle(&self.enc[1], enc2))
    }

    /// D (mm) for two extended counts; NaN if a frame angle is beyond [`KERNEL_RANGE_RAD`].
    #[inline]
    pub fn distance_mm(&self, enc1: i64, enc2: i64) -> f64 {
        let (Some(t1), Some(t2)) = (self.enc[0].trig(enc1), self.enc[1].trig(enc2)) else {
            return f64::NAN;
        };
        // w = n₂ × n₁ (G7): large products in Q30, the skew/tilt terms in f32.
        let (pss, psc, pcs, pcc) = (t1.sf * t2.sf, t1.sf * t2.cf, t1.cf * t2.sf, t1.cf * t2.cf);
        let [x0, x1, x2] = self.dwx;
        let [y0, y1] = self.dwy;
        let [z0, z1, z2, z3] = self.dwz;
        let dwx = x0 * pcs + x1 * psc + x2 * pss;
        let dwy = y0 * pss + y1 * psc;
        let dwz = z0 * pcc + z1 * pcs + z2 * psc + z3 * pss;
        let wx = qmul(t2.s, t1.c).wrapping_add(f2q(dwx));
        let wy = f2q(dwy).wrapping_sub(qmul(t1.s, t2.c));
        let wz = qmul(t1.c, t2.c).wrapping_add(f2q(dwz));
        // q_w = 1 − w_z/|w| solves R(q) = q(2 − q)·M − N = 0 with N = w_x² + w_y², M = |w|²
        // (G8 for ρ = 0). Seed N/(M + w_z·√M) in f32, then one Newton step on R: N, M and
        // q(2 − q)·M exactly in Q60 (i64), q(2 − q) = q + q(1 − q) ≤ 1 in Q30. Near the corners of
        // the range |w|² ≈ 0.13 and the step divides by 2(1 − q)M ≈ 0.05, so anything truncated
        // here would be amplified 20×; nothing cancels, 1 − cos φ is never subtracted.
        let n60 = wx as i64 * wx as i64 + wy as i64 * wy as i64;
        let m60 = n60 + wz as i64 * wz as i64;
        let (m_hi, m_lo) = ((m60 >> 30) as i32, (m60 & (ONE as i64 - 1)) as i32);
        let (nf, mf) = ((n60 >> 30) as i32 as f32 * INV_ONE_F, q2f(m_hi));
        let q0f = nf / (mf + q2f(wz) * math::sqrt_f32(mf));
        let q0 = f2q(q0f);
        let q2q = q0.wrapping_add(qmul(q0, ONE.wrapping_sub(q0))) as i64;
        let r60 = n60 - q2q * m_hi as i64 - ((q2q * m_lo as i64) >> 30);
        let r40 = (r60 >> 20) as i32; // |R| ≪ 2⁻⁹: fits, resolution 2⁻⁴⁰
        let qw = q0.wrapping_add(
            (r40 as f32 * (1.0 / (1u64 << 10) as f32) / (2.0 * (1.0 - q0f) * mf)) as i32,
        );
        // Pivot offsets (G6), (G7): q = q_w + (1 − η)(1 − q_w) − (λ₁n₁z + λ₂n₂z).
        let [g0, g1, g2, g3] = self.g;
        let g = g0 * pcc + g1 * pcs + g2 * psc + g3 * pss;
        let rho1 = self.nu[0] * t1.cf + self.mu[0] * t1.sf;
        let rho2 = self.nu[1] * t2.cf + self.mu[1] * t2.sf;
        let inv = 1.0 / (1.0 - g * g);
        let l1 = (rho1 - g * rho2) * inv;
        let l2 = (rho2 - g * rho1) * inv;
        let x = l1 * rho1 + l2 * rho2;
        let one_minus_eta = x / (1.0 + math::sqrt_f32(1.0 - x));
        let eps = l1 * self.nz[0] * t1.sf + l2 * self.nz[1] * t2.sf;
        let q = qw.wrapping_add(f2q(one_minus_eta * (1.0 - q0f) - eps));
        // D = √(S² − K·q) = S·√y, y = 1 − (K/S²)·q: an exact fixed-point subtraction (nothing
        // cancels), then √y seeded in f32 and refined on the exact residual y − t₀².
        let y = ONE.wrapping_sub(qmul(self.k_over_s2, q));
        if y <= 0 {
            return f64::NAN;
        }
        let t0f = math::sqrt_f32(q2f(y));
        let t0 = f2q(t0f);
        let res = ((((y as i64) << 30) - t0 as i64 * t0 as i64) >> 30) as i32;
        let t = t0.wrapping_add(f2q(q2f(res) / (2.0 * t0f))) as u32 as u64;
        // S·t·2⁴⁸ from S·2⁴⁸ = hi·2³² + lo.
        let hi = self.s_fixed >> 32;
        let lo = self.s_fixed & 0xffff_ffff;
        let d_fixed = ((hi * t) << 2).wrapping_add((lo * t) >> 30);
        fixed_to_f64(d_fixed)
    }
}

/// x·2⁻⁴⁸ as f64 for 0 < x < 2⁶³, built from the bits (truncated to 53 significant bits, ≤ 1.1e-16
/// relative): cheaper than the soft-float conversion on the M4F, the same on every target.
#[inline(always)]
fn fixed_to_f64(x: u64) -> f64 {
    if x == 0 {
        return 0.0;
    }
    let lz = x.leading_zeros() as u64;
    let mant = (x << lz) >> 11; // leading one at bit 52
                                // value = mant·2^(11 − lz − 48) = (mant/2⁵²)·2^(63 − lz − 48); the implicit one in mant adds
                                // one to the biased exponent field.
    let biased = 1023 + 63 - S_BITS as u64 - lz;
    f64::from_bits(((biased - 1) << 52) + mant)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{Direction, FrameCal, Param};
    use proptest::prelude::*;

    const DEG: f64 = core::f64::consts::PI / 180.0;
    const ARCSEC: f64 = DEG / 3600.0;

    fn cal(l1: f64, l2: f64, cpr: u32) -> Calibration {
        let mut c = Calibration::nominal(l1, l2, cpr);
        c.enc1.zero_count = 123;
        c.enc2.zero_count = -77;
        c.enc2.direction = Direction::Negative;
        c
    }

    /// Every error term non-zero, at realistic sizes.
    fn all_errors(cpr: u32) -> Calibration {
        let mut c = cal(50.03, 49.96, cpr);
        c.enc1.zero_count = 1_234_567;
        c.enc2.zero_count = -7_654_321;
        c.enc1.zero_offset_rad = 80.0 * ARCSEC;
        c.enc2.zero_offset_rad = -95.0 * ARCSEC;
        c.enc1.eccentricity_rad = 55.0 * ARCSEC;
        c.enc1.eccentricity_phase_rad = 0.9;
        c.enc2.eccentricity_rad = 40.0 * ARCSEC;
        c.enc2.eccentricity_phase_rad = -2.3;
        c.axes_skew_rad = 90.0 * ARCSEC;
        c.frame1 = FrameCal {
            tilt_rad: -70.0 * ARCSEC,
            offset_normal_rad: 50.0 * ARCSEC,
            offset_axial_rad: -60.0 * ARCSEC,
        };
        c.frame2 = FrameCal {
            tilt_rad: 100.0 * ARCSEC,
            offset_normal_rad: -45.0 * ARCSEC,
            offset_axial_rad: 75.0 * ARCSEC,
        };
        c.validate().unwrap();
        c
    }

    /// The perfect instrument's D, (G1)–(G3), as the seed-000 model had it.
    fn nominal_distance(l1: f64, l2: f64, alpha: f64, beta: f64) -> f64 {
        let a = math::tan(beta);
        let b = math::tan(alpha);
        let t = a * a + b * b;
        let n = math::sqrt(1.0 + t);
        distance_from_one_minus_cos_mm(l1, l2, t / (n * (n + 1.0)))
    }

    // -- An instrument model written apart from (G4)–(G8): physical pivot axes and slot planes,
    // -- rotated with Rodrigues' formula, the grip points solved by Newton's method.

    fn rotate(v: V3, axis: V3, angle: f64) -> V3 {
        let (s, c) = math::sin_cos(angle);
        let kxv = cross(axis, v);
        let kv = dot(axis, v);
        core::array::from_fn(|i| v[i] * c + kxv[i] * s + axis[i] * kv * (1.0 - c))
    }

    fn unit(v: V3) -> V3 {
        let n = math::sqrt(dot(v, v));
        [v[0] / n, v[1] / n, v[2] / n]
    }

    /// A J-DBB built from parts: pivot axis k through point p_k (mm) with direction a_k, slot plane
    /// through the axis, gripping bar 2 at r_k (mm) from J.
    struct Mechanism {
        axis: [V3; 2],
        point: [V3; 2],
        grip_mm: [f64; 2],
        l1: f64,
        l2: f64,
    }

    impl Mechanism {
        fn from_cal(c: &Calibration, grip_mm: [f64; 2]) -> Self {
            let z = [0.0, 0.0, 1.0];
            // Frame 1's axis: x̂ tilted towards +z; frame 2's: ŷ turned by γ about z, tilted.
            let a1 = rotate([1.0, 0.0, 0.0], [0.0, -1.0, 0.0], c.frame1.tilt_rad);
            let a2h = rotate([0.0, 1.0, 0.0], z, c.axes_skew_rad);
            let a2 = unit([
                a2h[0] * math::cos(c.frame2.tilt_rad),
                a2h[1] * math::cos(c.frame2.tilt_rad),
                math::sin(c.frame2.tilt_rad),
            ]);
            // Offsets: physical points on the axes from ν, μ and the grip radius.
            let n10 = unit(cross(z, a1));
            let n20 = unit(cross(a2, z));
            let p = |n0: V3, a: V3, f: &FrameCal, r: f64| -> V3 {
                let m0 = cross(a, n0);
                core::array::from_fn(|i| {
                    r * (f.offset_normal_rad * n0[i] + f.offset_axial_rad * m0[i])
                })
            };
            Mechanism {
                axis: [a1, a2],
                point: [
                    p(n10, a1, &c.frame1, grip_mm[0]),
                    p(n20, a2, &c.frame2, grip_mm[1]),
                ],
                grip_mm,
                l1: c.l1_mm,
                l2: c.l2_mm,
            }
        }

        /// Slot plane normal of frame k at angle θ: zero when the plane contains bar 1 (z).
        fn normal(&self, k: usize, theta: f64) -> V3 {
            let z = [0.0, 0.0, 1.0];
            let n0 = if k == 0 {
                unit(cross(z, self.axis[0]))
            } else {
                unit(cross(self.axis[1], z))
            };
            rotate(n0, self.axis[k], theta)
        }

        /// Ball distance: Newton on (r_k·u − p_k)·n_k = 0 for both frames and |u| = 1.
        fn distance(&self, theta: [f64; 2]) -> f64 {
            let n = [self.normal(0, theta[0]), self.normal(1, theta[1])];
            let mut u = unit(cross(n[1], n[0]));
            for _ in 0..20 {
                let f = [
                    dot(u, n[0]) - dot(self.point[0], n[0]) / self.grip_mm[0],
                    dot(u, n[1]) - dot(self.point[1], n[1]) / self.grip_mm[1],
                    0.5 * (dot(u, u) - 1.0),
                ];
                // J = [n1ᵀ; n2ᵀ; uᵀ]; solve J du = −f by Cramer.
                let rows = [n[0], n[1], u];
                let det = dot(rows[0], cross(rows[1], rows[2]));
                let col = |i: usize| [rows[0][i], rows[1][i], rows[2][i]];
                let b = [-f[0], -f[1], -f[2]];
                let du: V3 = core::array::from_fn(|i| {
                    let mut m = [col(0), col(1), col(2)];
                    m[i] = b;
                    dot(m[0], cross(m[1], m[2])) / det
                });
                u = core::array::from_fn(|i| u[i] + du[i]);
            }
            let b2 = [self.l2 * u[0], self.l2 * u[1], self.l2 * u[2] + self.l1];
            math::sqrt(dot(b2, b2))
        }
    }

    #[test]
    fn straight_bars_give_sum_of_lengths() {
        let c = cal(50.0, 60.0, 20_000);
        assert_eq!(distance_mm(&c, 123, -77), 110.0);
        assert_eq!(Kernel::new(&c).distance_mm(123, -77), 110.0);
        let c = cal(50.0, 50.0, 1 << 23);
        assert_eq!(distance_mm(&c, 123, -77), 100.0);
        assert_eq!(Kernel::new(&c).distance_mm(123, -77), 100.0);
    }

    #[test]
    fn one_frame_alone_is_the_law_of_cosines() {
        // Only frame 2 turned by β: bar 2 in the xz plane, φ = β exactly.
        let c = cal(50.0, 50.0, 20_000);
        for deg in [1.0, 10.0, 30.0, 60.0, 75.0] {
            let phi = deg * DEG;
            let expect = (2.0 * 2500.0 + 2.0 * 2500.0 * phi.cos()).sqrt();
            assert!((distance_from_angles_mm(&c, 0.0, phi) - expect).abs() < 1e-12);
            assert!((distance_from_deflection_mm(50.0, 50.0, phi) - expect).abs() < 1e-12);
            assert!((deflection_rad(&c, 0.0, phi) - phi).abs() < 1e-14);
        }
    }

    #[test]
    fn paper_configuration_distance() {
        // Seed 000 §4 uses L = 50 mm bars. Law of cosines: φ = 60° gives
        // D² = 2500 + 2500 + 2·2500·½, D = √7500 = 86.6025 mm.
        let d = distance_from_deflection_mm(50.0, 50.0, 60.0 * DEG);
        assert!((d - 7500f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn reduces_to_the_perfect_instrument_model_when_errors_vanish() {
        for c in [cal(50.0, 50.0, 1 << 23), cal(40.0, 70.0, 20_000)] {
            let mut worst = 0.0f64;
            for i in -30..=30 {
                for j in -30..=30 {
                    let (a, b) = (i as f64 * 2.5 * DEG, j as f64 * 2.5 * DEG);
                    let d = distance_from_angles_mm(&c, a, b);
                    worst = worst.max((d - nominal_distance(c.l1_mm, c.l2_mm, a, b)).abs());
                }
            }
            assert!(worst <= 1e-12, "worst {worst:e} mm");
        }
    }

    #[test]
    fn closed_form_matches_a_mechanism_built_from_parts() {
        // (G4)–(G8) against the Rodrigues/Newton mechanism, each error alone and all together.
        let full = all_errors(1 << 23);
        let mut cases = std::vec![full];
        for p in Param::ALL.iter().skip(2) {
            let mut c = Calibration::nominal(50.0, 50.0, 1 << 23);
            c.set_param(*p, full.param(*p));
            // Encoder parameters don't enter angles → D; skip them here.
            if matches!(
                p,
                Param::Zero1
                    | Param::Zero2
                    | Param::Ecc1Sin
                    | Param::Ecc1Cos
                    | Param::Ecc2Sin
                    | Param::Ecc2Cos
            ) {
                continue;
            }
            cases.push(c);
        }
        for c in &cases {
            for grip in [[18.0, 22.0], [30.0, 30.0]] {
                let mech = Mechanism::from_cal(c, grip);
                for (a, b) in [
                    (0.0, 0.0),
                    (10.0, -20.0),
                    (-45.0, 30.0),
                    (70.0, 70.0),
                    (-75.0, 5.0),
                    (1e-4, 3e-5),
                ] {
                    let (a, b) = (a * DEG, b * DEG);
                    let got = distance_from_angles_mm(c, a, b);
                    let want = mech.distance([a, b]);
                    assert!(
                        (got - want).abs() < 1e-11,
                        "{c:?} ({a}, {b}): {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn vector_length_agrees_with_cancellation_free_form() {
        // |L2·u + L1·ẑ| (G2) against (G8)+(G3) for the full model.
        let c = all_errors(1 << 23);
        for (a, b) in [(0.0, 0.0), (0.3, -0.2), (-1.2, 1.1), (1e-7, -2e-7)] {
            let u = bar2_direction(&c, a, b);
            let v = [c.l2_mm * u[0], c.l2_mm * u[1], c.l2_mm * u[2] + c.l1_mm];
            let direct = math::sqrt(dot(v, v));
            assert!((direct - distance_from_angles_mm(&c, a, b)).abs() < 1e-12);
            assert!((dot(u, u) - 1.0).abs() < 1e-15);
        }
    }

    #[test]
    fn near_zero_deflection_keeps_precision() {
        // φ = 1 µrad: D = S − L1·L2·φ²/(2S) (series), i.e. 100 mm − 1.25e-11 mm, right to the last
        // ulp of 100 (1.4e-14) in the f64 reference; the chip resolves D absolutely to < 1 nm.
        let phi = 1e-6;
        let d = distance_from_deflection_mm(50.0, 50.0, phi);
        assert!(((100.0 - d) - 1.25e-11).abs() < 3e-14, "{:e}", 100.0 - d);
        let c = cal(50.0, 50.0, 1 << 30); // one count = 5.9 nrad
        let c1 = c.enc1.zero_count + 170;
        let c2 = c.enc2.zero_count;
        let (a, b) = frame_angles_rad(&c, c1, c2);
        let phi = deflection_rad(&c, a, b);
        let expect = 2500.0 * phi * phi / 200.0;
        assert!(((100.0 - distance_mm(&c, c1, c2)) - expect).abs() < 1e-9 * expect + 3e-14);
        assert!((Kernel::new(&c).distance_mm(c1, c2) - distance_mm(&c, c1, c2)).abs() < 1e-6);
    }

    #[test]
    fn symmetric_in_the_bar_lengths() {
        // D² = L1² + L2² + 2 L1 L2 cos φ: swapping the bars leaves D unchanged (equal bars: only
        // their sum is identifiable).
        let mut c = all_errors(1 << 23);
        for (a, b) in [(0.2, 0.3), (-1.0, 0.7), (1.2, -1.25)] {
            let d = distance_from_angles_mm(&c, a, b);
            core::mem::swap(&mut c.l1_mm, &mut c.l2_mm);
            assert!((distance_from_angles_mm(&c, a, b) - d).abs() < 1e-12);
        }
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let c = all_errors(1 << 23);
        let k = (FRAME_RANGE_RAD / c.enc1.rad_per_count()) as i64;
        for (f1, f2) in [
            (0.1, 0.2),
            (-0.6, 0.05),
            (0.95, -0.9),
            (0.0, 0.0),
            (-0.3, -0.99),
        ] {
            let e1 = c.enc1.zero_count + (f1 * k as f64) as i64;
            let e2 = c.enc2.zero_count - (f2 * k as f64) as i64;
            let (d, grad) = distance_and_gradient(&c, e1, e2);
            assert_eq!(d, distance_mm(&c, e1, e2));
            for p in Param::ALL {
                let h = if p.is_length() { 1e-4 } else { 1e-6 };
                let at = |v: f64| {
                    let mut q = c;
                    q.set_param(p, c.param(p) + v);
                    distance_mm(&q, e1, e2)
                };
                let fd = (at(h) - at(-h)) / (2.0 * h);
                let g = grad[p.index()];
                assert!(
                    (g - fd).abs() < 2e-7 * (1.0 + fd.abs()),
                    "{p:?} at ({e1}, {e2}): {g} vs {fd}"
                );
            }
        }
    }

    #[test]
    fn sensitivity_matches_finite_difference() {
        for c in [all_errors(1 << 23), cal(50.0, 50.0, 20_000)] {
            let k = (FRAME_RANGE_RAD / c.enc1.rad_per_count()) as i64;
            for (f1, f2) in [(0.1, 0.2), (-0.5, 0.05), (0.9, -0.9), (0.004, 0.0)] {
                let e1 = c.enc1.zero_count + (f1 * k as f64) as i64;
                let e2 = c.enc2.zero_count + (f2 * k as f64) as i64;
                let s = sensitivity_mm_per_count(&c, e1, e2);
                // Central difference over ±1 count (the curvature term is 1e-6 of a step).
                let fd1 = (distance_mm(&c, e1 + 1, e2) - distance_mm(&c, e1 - 1, e2)) / 2.0;
                let fd2 = (distance_mm(&c, e1, e2 + 1) - distance_mm(&c, e1, e2 - 1)) / 2.0;
                let tol = 1e-5 * s[0].abs().max(s[1].abs()) + 1e-13;
                assert!((s[0] - fd1).abs() < tol, "{s:?} {fd1}");
                assert!((s[1] - fd2).abs() < tol, "{s:?} {fd2}");
            }
        }
    }

    #[test]
    fn default_instrument_steps_d_by_at_most_a_tenth_of_a_micrometre() {
        // Issue: D's step ≤ 0.1 µm over the working range. Dense grid over ±75° × ±75°, plus
        // actual one-count steps.
        let c = Calibration::DEFAULT;
        assert_eq!(c.enc1.counts_per_rev, 1 << 23);
        let k = (FRAME_RANGE_RAD / c.enc1.rad_per_count()) as i64;
        let mut worst = 0.0f64;
        for i in -100..=100 {
            for j in -100..=100 {
                let (e1, e2) = (k * i / 100, k * j / 100);
                let [s1, s2] = sensitivity_mm_per_count(&c, e1, e2);
                worst = worst.max(s1.abs()).max(s2.abs());
                let d = distance_mm(&c, e1, e2);
                assert!((distance_mm(&c, e1 + 1, e2) - d).abs() <= 1e-4);
                assert!((distance_mm(&c, e1, e2 + 1) - d).abs() <= 1e-4);
            }
        }
        assert!(worst <= 1e-4 && worst > 2e-5, "largest step {worst:e} mm");
        std::println!(
            "2^23 counts: largest step of D over ±75° × ±75°: {:.4} µm",
            worst * 1e3
        );
        // The seed-000 instrument (20 000 counts) steps by up to 9.5 µm.
        let c = Calibration::SEED_000;
        let k = (FRAME_RANGE_RAD / c.enc1.rad_per_count()) as i64;
        let s = sensitivity_mm_per_count(&c, 0, k);
        assert!(s[1].abs() > 9e-3, "{s:?}");
    }

    /// RMS of the error in D that the nominal instrument makes when the built one has `hidden`,
    /// over ball distances 79–99 mm with bar 2 leaning all round (the knee swung through its
    /// range), both at 2²³ counts.
    fn rms_error_um(hidden: &Calibration) -> f64 {
        let nominal = Calibration::DEFAULT;
        let (mut sum, mut n) = (0.0, 0);
        for i in 0..=20 {
            let d = 79.0 + i as f64;
            for j in 0..72 {
                let psi = j as f64 * 5.0 * DEG;
                let Some((c1, c2)) = counts_for_distance(hidden, d, psi) else {
                    continue;
                };
                let err = distance_mm(&nominal, c1, c2) - d;
                sum += err * err;
                n += 1;
            }
        }
        assert!(n > 1400, "{n}");
        (sum / n as f64).sqrt() * 1e3
    }

    #[test]
    fn hidden_instrument_errors_match_the_issue_table() {
        // Issue 9's table, measured with an instrument model written apart from this project:
        // L1 23 µm long → 20.5 µm, encoder 2 zero 60″ off → 3.6 µm, axes 90″ from perpendicular →
        // 1.4 µm, encoder 1 eccentric 40″ → 2.1 µm (RMS of D). The same sizes hidden here.
        let base = Calibration::DEFAULT;
        let mut l1 = base;
        l1.l1_mm += 0.023;
        let mut zero2 = base;
        zero2.enc2.zero_offset_rad = 60.0 * ARCSEC;
        let mut skew = base;
        skew.axes_skew_rad = 90.0 * ARCSEC;
        let got = [rms_error_um(&l1), rms_error_um(&zero2), rms_error_um(&skew)];
        let table = [20.5, 3.6, 1.4];
        for (g, t) in got.iter().zip(table) {
            assert!((g / t - 1.0).abs() < 0.15, "{got:?} vs {table:?}");
        }
        // Eccentricity: the RMS depends on the phase; the table's value lies within the range.
        let mut lo = f64::MAX;
        let mut hi = 0.0f64;
        for k in 0..8 {
            let mut e = base;
            e.enc1.eccentricity_rad = 40.0 * ARCSEC;
            e.enc1.eccentricity_phase_rad = k as f64 * 45.0 * DEG;
            let r = rms_error_um(&e);
            lo = lo.min(r);
            hi = hi.max(r);
        }
        assert!(
            lo < 2.1 * 1.15 && 2.1 / 1.15 < hi,
            "eccentricity {lo}..{hi} µm"
        );
        std::println!(
            "RMS errors (µm): L1 {:.2}, zero2 {:.2}, skew {:.2}, ecc1 {lo:.2}..{hi:.2}",
            got[0],
            got[1],
            got[2]
        );
        // Nothing hidden: no error at all beyond count quantisation (< 0.02 µm).
        assert!(rms_error_um(&base) < 0.02);
    }

    /// Correlation matrix of the least-squares estimates of `params` from the calibration design
    /// (D 79–99 mm, bar 2 leaning all round), i.e. the normalised inverse of JᵀJ.
    fn design_correlations(c: &Calibration, params: &[Param]) -> std::vec::Vec<std::vec::Vec<f64>> {
        let n = params.len();
        let mut a = std::vec![std::vec![0.0f64; n]; n];
        for i in 0..=40 {
            let d = 79.0 + 0.5 * i as f64;
            for j in 0..72 {
                let Some((c1, c2)) = counts_for_distance(c, d, j as f64 * 5.0 * DEG) else {
                    continue;
                };
                let (_, g) = distance_and_gradient(c, c1, c2);
                for r in 0..n {
                    for k in 0..n {
                        a[r][k] += g[params[r].index()] * g[params[k].index()];
                    }
                }
            }
        }
        // Gauss–Jordan inverse.
        let mut inv: std::vec::Vec<std::vec::Vec<f64>> = (0..n)
            .map(|i| (0..n).map(|k| if i == k { 1.0 } else { 0.0 }).collect())
            .collect();
        for col in 0..n {
            let piv = (col..n)
                .max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))
                .unwrap();
            a.swap(col, piv);
            inv.swap(col, piv);
            let p = a[col][col];
            for k in 0..n {
                a[col][k] /= p;
                inv[col][k] /= p;
            }
            for r in 0..n {
                if r != col {
                    let f = a[r][col];
                    for k in 0..n {
                        a[r][k] -= f * a[col][k];
                        inv[r][k] -= f * inv[col][k];
                    }
                }
            }
        }
        (0..n)
            .map(|i| {
                (0..n)
                    .map(|k| inv[i][k] / (inv[i][i] * inv[k][k]).sqrt())
                    .collect()
            })
            .collect()
    }

    #[test]
    fn calibration_design_separates_every_parameter_but_the_bar_split() {
        // With equal bars only L1 + L2 is identifiable (D symmetric in L1 ↔ L2); fit the sum (here
        // L1 alone). Every other parameter is separable from samples over D 79–99 mm with the knee
        // swung all round, though some pairs are strongly correlated (printed for the host's fit).
        let c = all_errors(1 << 23);
        let params: std::vec::Vec<Param> = Param::ALL
            .iter()
            .copied()
            .filter(|p| *p != Param::L2)
            .collect();
        let r = design_correlations(&c, &params);
        let mut worst = 0.0f64;
        for i in 0..params.len() {
            for k in 0..i {
                if r[i][k].abs() > 0.9 {
                    std::println!(
                        "correlation {:?}–{:?}: {:.4}",
                        params[i],
                        params[k],
                        r[i][k]
                    );
                }
                worst = worst.max(r[i][k].abs());
            }
        }
        std::println!("largest |correlation| {worst:.5}");
        assert!(worst < 0.9999, "{worst}");
    }

    #[test]
    fn sin_cos_table_is_correctly_rounded() {
        for (j, &(s, c)) in SIN_COS_Q30.iter().enumerate() {
            let x = j as f64 / 16.0;
            assert!((s as f64 - libm::sin(x) * ONE as f64).abs() <= 0.5, "{j}");
            assert!((c as f64 - libm::cos(x) * ONE as f64).abs() <= 0.5, "{j}");
        }
    }

    #[test]
    fn kernel_sin_cos_within_a_few_lsb() {
        // Every count of a 2²⁰ encoder over the kernel's range, with a fine zero and eccentricity.
        let mut e = EncoderCal::ideal(1 << 20);
        e.zero_count = 77_777;
        e.direction = Direction::Negative;
        e.zero_offset_rad = 90.0 * ARCSEC;
        e.eccentricity_rad = 60.0 * ARCSEC;
        e.eccentricity_phase_rad = 2.0;
        let k = EncKernel::new(&e);
        let max = (KERNEL_RANGE_RAD / e.rad_per_count()) as i64 - 1;
        let mut worst = 0.0f64;
        for steps in -max..=max {
            let count = e.zero_count - steps;
            let t = k.trig(count).unwrap();
            let theta = e.angle_rad(count);
            let (s, c) = math::sin_cos(theta);
            worst = worst
                .max((t.s as f64 / ONE as f64 - s).abs())
                .max((t.c as f64 / ONE as f64 - c).abs());
            assert!((t.sf as f64 - s).abs() < 3e-7 && (t.cf as f64 - c).abs() < 3e-7);
        }
        assert!(worst < 8e-9, "{worst:e}");
        assert!(k.trig(e.zero_count + max + 2).is_none());
    }

    #[test]
    fn fixed_to_f64_is_exact_scaling() {
        for x in [
            1u64,
            3,
            1 << 47,
            (100u64 << 48) + 12345,
            (1 << 62) + 1,
            0x7fff_ffff_ffff_ffff,
        ] {
            let want = x as f64 / (1u64 << 48) as f64;
            let got = fixed_to_f64(x);
            assert!((got - want).abs() <= want * 1.2e-16, "{x}: {got} vs {want}");
            assert!(got <= want);
        }
        assert_eq!(fixed_to_f64(0), 0.0);
        assert_eq!(fixed_to_f64(100 << 48), 100.0);
    }

    fn kernel_worst_error_nm(c: &Calibration, n: i64) -> f64 {
        let k = Kernel::new(c);
        let m1 = (FRAME_RANGE_RAD / c.enc1.rad_per_count()) as i64;
        let m2 = (FRAME_RANGE_RAD / c.enc2.rad_per_count()) as i64;
        let mut worst = 0.0f64;
        for i in -n..=n {
            for j in -n..=n {
                let e1 = c.enc1.zero_count + c.enc1.direction.sign() * (m1 * i / n);
                let e2 = c.enc2.zero_count + c.enc2.direction.sign() * (m2 * j / n);
                let err = (k.distance_mm(e1, e2) - distance_mm(c, e1, e2)).abs();
                let budget = accuracy_budget_mm(c, e1, e2);
                assert!(err <= budget, "({e1},{e2}): err {err:e} > {budget:e}");
                worst = worst.max(err * 1e6);
            }
        }
        worst
    }

    #[test]
    fn kernel_meets_budget_on_host_over_working_range() {
        // The same code as on chip (integer and IEEE f32 arithmetic are bit-identical across
        // targets); the QEMU test repeats this on the Cortex-M4F.
        let default = kernel_worst_error_nm(&Calibration::DEFAULT, 60);
        let full = kernel_worst_error_nm(&all_errors(1 << 23), 60);
        let coarse = kernel_worst_error_nm(&Calibration::SEED_000, 60);
        let unequal = kernel_worst_error_nm(&all_errors(1 << 24), 40);
        std::println!("kernel worst error (nm): default {default:.3}, all errors {full:.3}, 20k {coarse:.3}, 2^24 {unequal:.3}");
        for w in [default, full, coarse, unequal] {
            assert!(w < 2.0, "{w} nm");
        }
    }

    #[test]
    fn kernel_out_of_range_is_nan_not_a_panic() {
        let c = all_errors(1 << 23);
        let k = Kernel::new(&c);
        let far = (1.6 / c.enc1.rad_per_count()) as i64;
        assert!(k
            .distance_mm(c.enc1.zero_count + far, c.enc2.zero_count)
            .is_nan());
        assert!(k.distance_mm(i64::MIN, i64::MAX).is_nan());
        let (a, b) = k.frame_angles_rad(i64::MAX, c.enc2.zero_count);
        assert!(a.is_infinite() && b.abs() < 1e-3);
    }

    proptest! {
        // A fixed seed: the same cases on every run, so a failure is reproducible and CI cannot
        // flake on a rare draw (a failing case found later is kept as its own test).
        #![proptest_config(ProptestConfig {
            rng_seed: proptest::test_runner::RngSeed::Fixed(15561),
            failure_persistence: None,
            ..ProptestConfig::default()
        })]
        #[test]
        fn distance_to_counts_round_trip(d in 80.0f64..100.0, psi in -3.2f64..3.2, cpr in 4_000u32..20_000_000, errors in any::<bool>()) {
            let mut c = cal(50.0, 50.0, cpr);
            if errors {
                let full = all_errors(cpr);
                c = full;
            }
            if let Some((c1, c2)) = counts_for_distance(&c, d, psi) {
                // Quantisation to whole counts moves D by at most half a count on each encoder.
                let s = sensitivity_mm_per_count(&c, c1, c2);
                let tol = 0.5 * (s[0].abs() + s[1].abs()) * 1.01 + 1e-9;
                prop_assert!((distance_mm(&c, c1, c2) - d).abs() <= tol);
            }
        }

        #[test]
        fn direction_to_angles_round_trip(a in -1.3f64..1.3, b in -1.3f64..1.3) {
            let c = all_errors(1 << 23);
            let u = bar2_direction(&c, a, b);
            let (a2, b2) = frame_angles_for_direction(&c, u);
            prop_assert!((a2 - a).abs() < 1e-12 && (b2 - b).abs() < 1e-12, "({a}, {b}) → ({a2}, {b2})");
        }

        #[test]
        fn deflection_round_trip(l1 in 10.0f64..200.0, l2 in 10.0f64..200.0, phi in 0.0f64..3.1) {
            let d = distance_from_deflection_mm(l1, l2, phi);
            let back = deflection_for_distance_rad(l1, l2, d).unwrap();
            prop_assert!((back - phi).abs() < 1e-6, "{phi} -> {d} -> {back}");
        }

        #[test]
        fn distance_bounded_by_triangle(a in -1.3f64..1.3, b in -1.3f64..1.3) {
            let c = cal(50.0, 70.0, 20_000);
            let d = distance_from_angles_mm(&c, a, b);
            prop_assert!((20.0..=120.0 + 1e-12).contains(&d));
            let phi = deflection_rad(&c, a, b);
            prop_assert!((distance_from_deflection_mm(50.0, 70.0, phi) - d).abs() < 1e-11);
        }
    }
}
