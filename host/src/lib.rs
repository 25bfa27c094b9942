//! `jdbb`, the host side of the J-DBB double ball bar.
//!
//! One module per concern:
//! - [`stream`]: frames from a serial port (USB CDC or a QEMU pty) → decoded samples, with loss,
//!   corruption and device-reset accounting.
//! - [`record`]: the `seq,t_us,enc1,enc2,d_mm` CSV, written so a killed process leaves a valid file.
//! - [`cli`]: the command line (`jdbb live`, `jdbb record`, `jdbb devices`, ...).
//!
//! The instrument model, wire protocol and machine error models live in `jdbb-core` and are shared
//! with the firmware.
pub mod cli;
pub mod error;
/// Least-squares engine (Levenberg–Marquardt on accumulated normal equations, rank and covariance).
pub mod fit;
/// Minimax (Chebyshev) engine on the same problems: sequential LP with an exchange active set.
pub mod minimax;
pub mod record;
/// Seed 002: six geometric errors of a rotary axis (C turntable, B head) from DBB runs.
pub mod rotary;
/// Seed 004: the DBB test of an A/C table as an RRSPS linkage: motion design and identification.
pub mod rrsps;
pub mod stream;

pub use error::{Error, Result};
