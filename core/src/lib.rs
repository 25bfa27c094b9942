//! `jdbb-core`: everything about the J-DBB that both the firmware and the host must agree on.
//!
//! - [`geometry`]: encoder counts → decoupling-frame angles → joint deflection φ → ball distance D,
//!   for the extended instrument model; its inverse for simulation; the sensitivity dD per count
//!   and the partial derivatives a calibration fit needs; the on-chip kernel.
//! - [`calib`]: the calibration parameters in force (one serde struct, sent on the wire): bar
//!   lengths, encoders (resolution, zero, direction, eccentricity), frame geometry (skew, tilts,
//!   pivot offsets); [`Param`] addresses each continuous one for a fit.
//! - [`quadrature`]: extending a wrapping hardware counter to a continuous `i64`, index referencing.
//! - [`machine`]: seed 000's error equation (1) and its positioning-error models.
//! - [`protocol`]: every message between device and host, and their framing (postcard, CRC-32, COBS).
//! - [`sim`]: a simulated circular test producing encoder counts (QEMU build, tests).
//! - [`scenario`]: the file of encoder counts a QEMU run plays instead (a machine run simulated
//!   on the host).
//! - [`sampler`]: the device's sample path (counts → D → batches, counted drops and overruns),
//!   hardware-free.
//! - [`link`]: the device's writer policy: an absent host, the queue's room for replies, runs.
//! - [`reset`]: why the device last started (reset flags, a recorded panic or fault).
//! - [`store`]: the calibration kept in NOR flash (a versioned, CRC-checked append log over two
//!   erase blocks, safe against power loss, wear-aware).
//! - [`clock`], [`indicator`]: the board's clock start without hardware (the crystal's verdict)
//!   and the status LED's codes over embedded-hal's `OutputPin` and `DelayNs`.
//! - [`math`]: the one place that names which floating-point implementation is used.
//!
//! `no_std`, no allocation. The `std` feature only adds conveniences for the host.
#![cfg_attr(not(any(test, feature = "std")), no_std)]
#![deny(missing_docs)]

pub mod calib;
pub mod clock;
pub mod geometry;
pub mod indicator;
pub mod link;
pub mod machine;
pub mod math;
pub mod protocol;
pub mod quadrature;
pub mod reset;
pub mod sampler;
pub mod scenario;
pub mod sim;
pub mod store;
pub mod ticks;

pub use calib::{Calibration, EncoderCal, FrameCal, Param};
