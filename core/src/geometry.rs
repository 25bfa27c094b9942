//! The instrument model: encoder counts → frame angles → direction of bar 2 → joint deflection φ →
//! ball distance D; its inverse for simulation; the sensitivity of D to one count.
//!
//! # Convention (seed 000, section 2; derived here because the paper gives no formula)
//!
//! Bar-1 frame: origin at the joint centre J, +z along bar 1 *away from* the table ball, so the
//! table ball B1 is at `−L1·ẑ`. The two mechanical decoupling frames (MDF) pivot about axes through
//! J: frame 1 about x (angle α, encoder 1), frame 2 about y (angle β, encoder 2), both zero when
//! bar 2 continues bar 1 straight. Frame 1 turned by α holds bar 2 in the plane spanned by x̂ and
//! R_x(α)ẑ = (0, −sin α, cos α); frame 2 turned by β holds it in the plane spanned by ŷ and
//! R_y(β)ẑ = (sin β, 0, cos β). The intersection of the two planes is the direction of bar 2:
//!
//! ```text
//!   u = (tan β, −tan α, 1) / n,   n = √(1 + tan²α + tan²β)                          (G1)
//! ```
//!
//! The joint deflection φ is the angle between bar 2 and the continuation of bar 1: cos φ = u_z = 1/n.
//! The spindle ball B2 = L2·u, so with B1 = −L1·ẑ,
//!
//! ```text
//!   D² = |L2·u + L1·ẑ|² = L1² + L2² + 2·L1·L2·cos φ                                   (G2)
//! ```
//!
//! (φ = 0: bars collinear, D = L1 + L2.) Near φ = 0, `1 − cos φ` cancels catastrophically, so we
//! never form cos φ. With S = L1 + L2 and q = 1 − cos φ = (n − 1)/n = t / (n (n + 1)), t = tan²α + tan²β
//! (a sum of squares, no cancellation):
//!
//! ```text
//!   D = S − Δ,   Δ = 2·L1·L2·q / (S + √(S² − 2·L1·L2·q))                            (G3)
//! ```
//!
//! Every term in (G3) is positive, so Δ carries only a few ulp of relative error at any φ.
//!
//! # On-chip error budget
//!
//! The Cortex-M4F has a single-precision FPU; f64 is software-emulated (hundreds of cycles per
//! operation) and a libm f64 `tan` alone would blow the 2 000-instruction per-sample budget. So the
//! chip evaluates (G1)–(G3) in f32 ([`Kernel`]) but keeps S in f64 and forms D = S − Δ in f64: the
//! f32 rounding then scales with Δ (≤ S − D_min ≈ 23 mm at L = 50 mm), not with D (100 mm). Estimate:
//! Δ with ~10 ulp of relative error (6e-7) is off by ≤ 14 nm at the extreme corner of the working
//! range, where one count moves D by ≈ 10 µm (budget there: 1 % of a step = 100 nm); near φ = 0, Δ
//! and its error vanish. The angle itself is `steps × rad_per_count` with `steps` exact in f32 up to
//! 2²⁴ counts. The budget is checked, not assumed: `tests/tests/qemu.rs` runs [`Kernel`] on the
//! Cortex-M4F in QEMU over a grid covering [`FRAME_RANGE_RAD`] and compares with [`distance_mm`].

use crate::calib::Calibration;
use crate::math;

/// Mechanical range of each decoupling frame, ±75° (rad). Beyond it the frames' slots foul the bar;
/// the accuracy budget is proven over this range.
pub const FRAME_RANGE_RAD: f64 = 75.0 * core::f64::consts::PI / 180.0;

/// On-chip accuracy budget for D (mm) at a pose: 10 nm, or 1 % of the larger change of D caused by
/// one count of either encoder, whichever is larger.
pub fn accuracy_budget_mm(cal: &Calibration, alpha_rad: f64, beta_rad: f64) -> f64 {
    let [s1, s2] = sensitivity_mm_per_count(cal, alpha_rad, beta_rad);
    f64::max(1e-5, 0.01 * f64::max(s1.abs(), s2.abs()))
}

/// Frame angles (α, β) in rad for two extended counts (host reference, f64).
pub fn frame_angles_rad(cal: &Calibration, enc1: i64, enc2: i64) -> (f64, f64) {
    (cal.enc1.angle_rad(enc1), cal.enc2.angle_rad(enc2))
}

/// Unit direction of bar 2 in bar 1's frame for frame angles α (about x) and β (about y), eq. (G1).
pub fn bar2_direction(alpha_rad: f64, beta_rad: f64) -> [f64; 3] {
    let a = math::tan(beta_rad);
    let b = -math::tan(alpha_rad);
    let n = math::sqrt(1.0 + a * a + b * b);
    [a / n, b / n, 1.0 / n]
}

/// Joint deflection φ (rad, in [0, π/2)) for frame angles α, β: cos φ = 1/n from (G1), computed as
/// φ = atan(√(tan²α + tan²β)) so it stays accurate near zero.
pub fn deflection_rad(alpha_rad: f64, beta_rad: f64) -> f64 {
    let a = math::tan(beta_rad);
    let b = math::tan(alpha_rad);
    math::atan(math::sqrt(a * a + b * b))
}

/// Ball distance D (mm) from the deflection φ, eq. (G2) in the cancellation-free form of (G3):
/// 1 − cos φ = 2 sin²(φ/2).
pub fn distance_from_deflection_mm(l1_mm: f64, l2_mm: f64, phi_rad: f64) -> f64 {
    let s = l1_mm + l2_mm;
    let h = math::sin(0.5 * phi_rad);
    let q = 2.0 * h * h;
    let k = 2.0 * l1_mm * l2_mm * q;
    s - k / (s + math::sqrt(s * s - k))
}

/// Ball distance D (mm) for frame angles α, β (rad): the host's f64 reference. Deliberately computed
/// a different way from [`Kernel`] — as the length of the vector B2 − B1 — so the on-chip check
/// compares two independent formulas.
pub fn distance_from_angles_mm(cal: &Calibration, alpha_rad: f64, beta_rad: f64) -> f64 {
    let u = bar2_direction(alpha_rad, beta_rad);
    let v = [
        cal.l2_mm * u[0],
        cal.l2_mm * u[1],
        cal.l2_mm * u[2] + cal.l1_mm,
    ];
    math::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
}

/// Ball distance D (mm) for two extended encoder counts: the host's f64 reference.
pub fn distance_mm(cal: &Calibration, enc1: i64, enc2: i64) -> f64 {
    let (alpha, beta) = frame_angles_rad(cal, enc1, enc2);
    distance_from_angles_mm(cal, alpha, beta)
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

/// Split a deflection φ into the two frame angles, for a bar 2 leaning towards azimuth ψ (rad,
/// measured from +x towards +y in bar 1's frame): u = (sin φ cos ψ, sin φ sin ψ, cos φ), then
/// β = atan2(u_x, u_z), α = atan2(−u_y, u_z) from (G1). Valid for φ < π/2.
pub fn frame_angles_for_deflection(phi_rad: f64, psi_rad: f64) -> (f64, f64) {
    let (sp, cp) = math::sin_cos(phi_rad);
    let (ss, cs) = math::sin_cos(psi_rad);
    let alpha = math::atan2(-sp * ss, cp);
    let beta = math::atan2(sp * cs, cp);
    (alpha, beta)
}

/// Sensitivity of D to one count of each encoder, [dD/dcount1, dD/dcount2] in mm per count,
/// at frame angles α, β. From (G1)–(G2): ∂D/∂tanβ = −L1·L2·tanβ / (D·n³) and d tanβ/dβ = 1 + tan²β
/// (likewise for α); times the angle of one count and the encoder's direction.
pub fn sensitivity_mm_per_count(cal: &Calibration, alpha_rad: f64, beta_rad: f64) -> [f64; 2] {
    let a = math::tan(beta_rad);
    let b = math::tan(alpha_rad);
    let n = math::sqrt(1.0 + a * a + b * b);
    let d = distance_from_angles_mm(cal, alpha_rad, beta_rad);
    let k = -cal.l1_mm * cal.l2_mm / (d * n * n * n);
    let dd_dalpha = k * b * (1.0 + b * b);
    let dd_dbeta = k * a * (1.0 + a * a);
    [
        dd_dalpha * cal.enc1.rad_per_count() * cal.enc1.direction.sign() as f64,
        dd_dbeta * cal.enc2.rad_per_count() * cal.enc2.direction.sign() as f64,
    ]
}

/// Extended counts (enc1, enc2) that put the balls `d_mm` apart with bar 2 leaning towards azimuth
/// ψ: the simulation path D → φ → (α, β) → counts. `None` if `d_mm` is out of reach or the frames
/// would leave [`FRAME_RANGE_RAD`].
pub fn counts_for_distance(cal: &Calibration, d_mm: f64, psi_rad: f64) -> Option<(i64, i64)> {
    let phi = deflection_for_distance_rad(cal.l1_mm, cal.l2_mm, d_mm)?;
    if phi >= core::f64::consts::FRAC_PI_2 {
        return None;
    }
    let (alpha, beta) = frame_angles_for_deflection(phi, psi_rad);
    if alpha.abs() > FRAME_RANGE_RAD || beta.abs() > FRAME_RANGE_RAD {
        return None;
    }
    Some((
        cal.enc1.count_for_angle(alpha),
        cal.enc2.count_for_angle(beta),
    ))
}

/// The on-chip evaluation of counts → D: (G1)–(G3) in f32 with S and the final subtraction in f64
/// (see the module's error budget). Built once from a [`Calibration`]; the host uses the same code
/// to reproduce the chip's numbers bit for bit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kernel {
    zero: [i64; 2],
    sign: [i64; 2],
    rad_per_count: [f32; 2],
    s_mm: f64,
    s_f32: f32,
    two_l1l2: f32,
}

impl Kernel {
    /// Precompute the constants of the f32 path from a calibration.
    pub fn new(cal: &Calibration) -> Self {
        let s = cal.l1_mm + cal.l2_mm;
        Kernel {
            zero: [cal.enc1.zero_count, cal.enc2.zero_count],
            sign: [cal.enc1.direction.sign(), cal.enc2.direction.sign()],
            rad_per_count: [
                cal.enc1.rad_per_count() as f32,
                cal.enc2.rad_per_count() as f32,
            ],
            s_mm: s,
            s_f32: s as f32,
            two_l1l2: (2.0 * cal.l1_mm * cal.l2_mm) as f32,
        }
    }

    /// Frame angles (α, β) in rad, single precision.
    #[inline]
    pub fn frame_angles_rad(&self, enc1: i64, enc2: i64) -> (f32, f32) {
        let s1 = ((enc1 - self.zero[0]) * self.sign[0]) as f32;
        let s2 = ((enc2 - self.zero[1]) * self.sign[1]) as f32;
        (s1 * self.rad_per_count[0], s2 * self.rad_per_count[1])
    }

    /// D (mm) for two extended counts, eq. (G3).
    #[inline]
    pub fn distance_mm(&self, enc1: i64, enc2: i64) -> f64 {
        let (alpha, beta) = self.frame_angles_rad(enc1, enc2);
        let a = math::tan_f32(beta);
        let b = math::tan_f32(alpha);
        let t = a * a + b * b;
        let n = math::sqrt_f32(1.0 + t);
        let q = t / (n * (n + 1.0));
        let k = self.two_l1l2 * q;
        let delta = k / (self.s_f32 + math::sqrt_f32(self.s_f32 * self.s_f32 - k));
        self.s_mm - delta as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::{Direction, EncoderCal};
    use proptest::prelude::*;

    const DEG: f64 = core::f64::consts::PI / 180.0;

    fn cal(l1: f64, l2: f64, cpr: u32) -> Calibration {
        Calibration {
            l1_mm: l1,
            l2_mm: l2,
            enc1: EncoderCal {
                counts_per_rev: cpr,
                zero_count: 123,
                direction: Direction::Positive,
            },
            enc2: EncoderCal {
                counts_per_rev: cpr,
                zero_count: -77,
                direction: Direction::Negative,
            },
        }
    }

    #[test]
    fn straight_bars_give_sum_of_lengths() {
        let c = cal(50.0, 60.0, 20_000);
        assert_eq!(distance_mm(&c, 123, -77), 110.0);
        assert_eq!(Kernel::new(&c).distance_mm(123, -77), 110.0);
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
            assert!((deflection_rad(0.0, phi) - phi).abs() < 1e-14);
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
    fn near_zero_deflection_keeps_precision() {
        // φ = 1 µrad: D = S − L1·L2·φ²/(2S) (series), i.e. 100 mm − 1.25e-11 mm, right to the last
        // ulp of 100 (1.4e-14), in both the f64 reference and the chip's f32 kernel.
        let phi = 1e-6;
        let d = distance_from_deflection_mm(50.0, 50.0, phi);
        assert!(((100.0 - d) - 1.25e-11).abs() < 3e-14, "{:e}", 100.0 - d);
        let c = cal(50.0, 50.0, 1 << 30); // one count = 5.9 nrad
        let (c1, c2) = (c.enc1.zero_count + 170, c.enc2.zero_count);
        let (a, b) = frame_angles_rad(&c, c1, c2);
        let phi = deflection_rad(a, b);
        let expect = 2500.0 * phi * phi / 200.0;
        let chip = 100.0 - Kernel::new(&c).distance_mm(c1, c2);
        assert!(
            (chip - expect).abs() < 1e-6 * expect + 3e-14,
            "{chip:e} vs {expect:e}"
        );
    }

    #[test]
    fn sensitivity_matches_finite_difference() {
        let c = cal(50.0, 50.0, 20_000);
        for (a, b) in [(10.0, 20.0), (-40.0, 5.0), (60.0, -60.0), (0.5, 0.0)] {
            let (a, b) = (a * DEG, b * DEG);
            let s = sensitivity_mm_per_count(&c, a, b);
            let h1 = c.enc1.rad_per_count();
            let h2 = c.enc2.rad_per_count() * c.enc2.direction.sign() as f64;
            let fd1 = (distance_from_angles_mm(&c, a + 0.5 * h1, b)
                - distance_from_angles_mm(&c, a - 0.5 * h1, b))
                / 1.0;
            let fd2 = (distance_from_angles_mm(&c, a, b + 0.5 * h2)
                - distance_from_angles_mm(&c, a, b - 0.5 * h2))
                / 1.0;
            assert!((s[0] - fd1).abs() < 1e-9 * (1.0 + fd1.abs()), "{s:?} {fd1}");
            assert!((s[1] - fd2).abs() < 1e-9 * (1.0 + fd2.abs()), "{s:?} {fd2}");
        }
    }

    #[test]
    fn kernel_meets_budget_on_host_over_working_range() {
        // The same f32 code as on chip (libm is bit-identical across targets); the QEMU test repeats
        // this on the Cortex-M4F.
        let c = Calibration::DEFAULT;
        let k = Kernel::new(&c);
        let max = (FRAME_RANGE_RAD / c.enc1.rad_per_count()) as i64;
        let mut worst = 0.0f64;
        for i in -40..=40 {
            for j in -40..=40 {
                let (c1, c2) = (max * i / 40, max * j / 40);
                let (a, b) = frame_angles_rad(&c, c1, c2);
                let err = (k.distance_mm(c1, c2) - distance_mm(&c, c1, c2)).abs();
                let budget = accuracy_budget_mm(&c, a, b);
                assert!(err <= budget, "({c1},{c2}): err {err:e} > {budget:e}");
                worst = worst.max(err);
            }
        }
        assert!(worst < 2e-5, "worst {worst:e} mm");
    }

    proptest! {
        #[test]
        fn distance_to_counts_round_trip(d in 80.0f64..100.0, psi in -3.2f64..3.2, cpr in 4_000u32..2_000_000) {
            let c = cal(50.0, 50.0, cpr);
            if let Some((c1, c2)) = counts_for_distance(&c, d, psi) {
                // Quantisation to whole counts moves D by at most half a count on each encoder.
                let (a, b) = frame_angles_rad(&c, c1, c2);
                let s = sensitivity_mm_per_count(&c, a, b);
                let tol = 0.5 * (s[0].abs() + s[1].abs()) * 1.01 + 1e-9;
                prop_assert!((distance_mm(&c, c1, c2) - d).abs() <= tol);
            }
        }

        #[test]
        fn deflection_round_trip(l1 in 10.0f64..200.0, l2 in 10.0f64..200.0, phi in 0.0f64..3.1) {
            let d = distance_from_deflection_mm(l1, l2, phi);
            let back = deflection_for_distance_rad(l1, l2, d).unwrap();
            prop_assert!((back - phi).abs() < 1e-6, "{phi} -> {d} -> {back}");
        }

        #[test]
        fn split_reproduces_deflection(phi in 0.0f64..1.5, psi in -3.2f64..3.2) {
            let (alpha, beta) = frame_angles_for_deflection(phi, psi);
            prop_assert!((deflection_rad(alpha, beta) - phi).abs() < 1e-12);
        }

        #[test]
        fn distance_bounded_by_triangle(a in -1.3f64..1.3, b in -1.3f64..1.3) {
            let c = cal(50.0, 70.0, 20_000);
            let d = distance_from_angles_mm(&c, a, b);
            prop_assert!((20.0..=120.0 + 1e-12).contains(&d));
            let phi = deflection_rad(a, b);
            prop_assert!((distance_from_deflection_mm(50.0, 70.0, phi) - d).abs() < 1e-11);
        }
    }
}
