//! The one module through which the core does floating-point transcendental math, so that the host
//! and the Cortex-M4F compute *the same* numbers from the same code.
//!
//! Implementation: the [`libm`] crate (a port of musl's libm) on every target — its functions are
//! accurate to about 1 ulp — except the two f32 functions of the on-chip D ([`tan_f32`],
//! [`sqrt_f32`]), which avoid libm's hidden f64 work (see each). We deliberately
//! do **not** use `micromath`: its `sin(0.7)` is off by 5.6e-4 and its `sqrt` by ~5 %, i.e. tens of
//! µm in D at L = 50 mm, far outside the 10 nm on-chip budget (see [`crate::geometry`]). Nothing in
//! the D path would fit micromath's error, so there is no place where it is used.
//!
//! On the host, `f64::sqrt` would resolve to std and on the chip to something else; routing every
//! call through here removes that difference.

/// tan(x) in single precision, evaluated in f32 only: ≤ 2.5 ulp for |x| ≤ 1.5 rad (checked against
/// f64 `tan` in the tests), libm `tanf` beyond (outside the frames' range, rare).
///
/// Why not libm `tanf` everywhere: musl's `tanf` works in f64 inside, which the Cortex-M4F emulates
/// in software — measured under QEMU, two `tanf` made the on-chip D cost ~3 800 instructions, far
/// over the 2 000 per-sample budget. Here: |x| ≤ π/4: tan x = x + x³·P(x²) with Cephes' `tanf`
/// minimax coefficients; π/4 < |x| ≤ 1.5: tan x = −1/tan(x − π/2), where |x| − π/2 is formed with
/// π/2 split in three f32 words (the first subtraction is exact by Sterbenz's lemma). The f32 error
/// moves D by a few nm at most over the working range (budget: [`crate::geometry`]).
#[inline]
pub fn tan_f32(x: f32) -> f32 {
    const PIO4: f32 = core::f32::consts::FRAC_PI_4;
    const PIO2_HI: f32 = core::f32::consts::FRAC_PI_2; // f32 nearest π/2
    const PIO2_MID: f32 = -4.371_139e-8; // π/2 − PIO2_HI, rounded to f32
    const PIO2_LO: f32 = -1.715_124_5e-15; // the rest
    #[inline(always)]
    fn kernel(x: f32) -> f32 {
        let z = x * x;
        let p = ((((9.385_402e-3 * z + 3.119_922_3e-3) * z + 2.443_013_5e-2) * z + 5.341_128e-2)
            * z
            + 1.333_879_9e-1)
            * z
            + 3.333_315_7e-1;
        p * z * x + x
    }
    let ax = f32::from_bits(x.to_bits() & 0x7fff_ffff);
    if ax <= PIO4 {
        kernel(x)
    } else if ax <= 1.5 {
        let y = ((ax - PIO2_HI) - PIO2_MID) - PIO2_LO;
        let t = -1.0 / kernel(y);
        if x < 0.0 {
            -t
        } else {
            t
        }
    } else {
        libm::tanf(x)
    }
}

/// √x in single precision, correctly rounded: the FPU's `vsqrt.f32` on hard-float ARM (libm's
/// `sqrtf` is a software loop there), libm `sqrtf` elsewhere. Both round correctly, so the chip
/// and the host get the same bits.
#[inline]
pub fn sqrt_f32(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        // Rust exposes no FPU register class for single-precision-only FPUs (`sreg` needs the
        // `vfp2` feature, which implies f64 hardware the M4F lacks), but an explicit register can
        // be named and clobbered: the value goes through s15 (caller-saved, so nothing to
        // restore) from and to an integer register.
        let bits: u32;
        // SAFETY: only s15 is written, and it is declared clobbered.
        unsafe {
            core::arch::asm!(
                "vmov s15, {x}",
                "vsqrt.f32 s15, s15",
                "vmov {r}, s15",
                x = in(reg) x.to_bits(),
                r = lateout(reg) bits,
                out("s15") _,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        f32::from_bits(bits)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

/// (sin x, cos x) in f64 by Taylor polynomials after reduction by π/2, for |x| ≤ 1e4: ≲ 1e-15
/// absolute. Plain IEEE arithmetic and no tables: libm's `sin`/`sincos` bring its argument
/// reduction (about 8 KiB of flash on the M4F), which the firmware does not need for the one-off
/// constants of the on-chip kernel; and the host computes the same bits.
pub fn sin_cos_poly(x: f64) -> (f64, f64) {
    const PIO2_HI: f64 = core::f64::consts::FRAC_PI_2; // f64 nearest π/2
    const PIO2_LO: f64 = 6.123_233_995_736_766e-17; // π/2 − PIO2_HI
    let k = round(x * core::f64::consts::FRAC_2_PI);
    let r = (x - k * PIO2_HI) - k * PIO2_LO; // |r| ≤ π/4
    let r2 = r * r;
    // Nested Taylor series: the first dropped terms are r¹⁷/17! and r¹⁸/18! (< 2e-17).
    let mut s = 1.0;
    let mut c = 1.0;
    for n in (1..=8).rev() {
        let n = n as f64;
        s = 1.0 - r2 / ((2.0 * n) * (2.0 * n + 1.0)) * s;
        c = 1.0 - r2 / ((2.0 * n - 1.0) * (2.0 * n)) * c;
    }
    let s = r * s;
    match (k as i64).rem_euclid(4) {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// tan(x) in double precision.
#[inline]
pub fn tan(x: f64) -> f64 {
    libm::tan(x)
}

/// atan(x) in double precision.
#[inline]
pub fn atan(x: f64) -> f64 {
    libm::atan(x)
}

/// atan2(y, x) in double precision.
#[inline]
pub fn atan2(y: f64, x: f64) -> f64 {
    libm::atan2(y, x)
}

/// √x in double precision.
#[inline]
pub fn sqrt(x: f64) -> f64 {
    libm::sqrt(x)
}

/// sin(x) in double precision.
#[inline]
pub fn sin(x: f64) -> f64 {
    libm::sin(x)
}

/// cos(x) in double precision.
#[inline]
pub fn cos(x: f64) -> f64 {
    libm::cos(x)
}

/// (sin x, cos x) in double precision.
#[inline]
pub fn sin_cos(x: f64) -> (f64, f64) {
    libm::sincos(x)
}

/// Round half away from zero to the nearest integer, as f64.
#[inline]
pub fn round(x: f64) -> f64 {
    libm::round(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ulps(got: f32, exact: f64) -> f64 {
        let spacing = {
            let a = (exact.abs() as f32).max(f32::MIN_POSITIVE);
            (f32::from_bits(a.to_bits() + 1) - a) as f64
        };
        (got as f64 - exact).abs() / spacing
    }

    #[test]
    fn tan_f32_within_2_5_ulp_over_working_range_and_beyond() {
        let mut worst = 0.0f64;
        let n = 300_000;
        for i in 0..=n {
            let x = -1.5 + 3.0 * i as f32 / n as f32;
            let e = ulps(tan_f32(x), libm::tan(x as f64));
            assert!(e <= 2.5, "tan_f32({x}) off by {e} ulp");
            worst = worst.max(e);
        }
        assert!(worst > 0.5, "suspiciously exact: {worst}");
        // Exact at 0, odd, finite far out.
        assert_eq!(tan_f32(0.0), 0.0);
        assert_eq!(tan_f32(-0.3), -tan_f32(0.3));
        assert!(ulps(tan_f32(3.0), libm::tan(3.0)) <= 1.0);
    }

    #[test]
    fn sin_cos_poly_matches_libm() {
        let mut worst = 0.0f64;
        for i in -20_000..=20_000 {
            let x = i as f64 * 0.000_731 + 1e-3 * (i % 7) as f64;
            let (s, c) = sin_cos_poly(x);
            worst = worst
                .max((s - libm::sin(x)).abs())
                .max((c - libm::cos(x)).abs());
        }
        assert!(worst < 2e-15, "{worst:e}");
        assert_eq!(sin_cos_poly(0.0), (0.0, 1.0));
        let (s, _) = sin_cos_poly(1e-9);
        assert_eq!(s, 1e-9);
    }
}
