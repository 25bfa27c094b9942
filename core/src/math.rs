//! The one module through which the core does floating-point transcendental math, so that the host
//! and the Cortex-M4F compute *the same* numbers from the same code.
//!
//! Implementation: the [`libm`] crate (a port of musl's libm) on every target. Its `f32` functions
//! are accurate to about 1 ulp, `f64` ones likewise; `sqrtf` is correctly rounded. We deliberately
//! do **not** use `micromath`: its `sin(0.7)` is off by 5.6e-4 and its `sqrt` by ~5 %, i.e. tens of
//! µm in D at L = 50 mm, far outside the 10 nm on-chip budget (see [`crate::geometry`]). Nothing in
//! the D path would fit micromath's error, so there is no place where it is used.
//!
//! On the host, `f64::sqrt` would resolve to std and on the chip to something else; routing every
//! call through here removes that difference.

/// tan(x) in single precision (libm `tanf`, ≤ 1 ulp).
#[inline]
pub fn tan_f32(x: f32) -> f32 {
    libm::tanf(x)
}

/// √x in single precision (libm `sqrtf`, correctly rounded).
#[inline]
pub fn sqrt_f32(x: f32) -> f32 {
    libm::sqrtf(x)
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
