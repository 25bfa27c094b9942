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
/// `jdbb diagnose`: baseline, candidate-effect selection, identifiability, residual harmonics.
pub mod diagnose;
pub mod error;
/// Least-squares engine (Levenberg–Marquardt on accumulated normal equations, rank and covariance).
pub mod fit;
/// `jdbb live`: the latest D, sample rate and loss counters on one terminal line.
pub mod live;
/// Minimax (Chebyshev) engine on the same problems: sequential LP with an exchange active set.
pub mod minimax;
/// Candidate machine effects of a circular test and the exact model D = |p + δ + c| + e.
pub mod model;
pub mod record;
/// Ballbar-style polar plot (SVG, PNG) of a diagnosis.
pub mod report;
/// Seed 002: six geometric errors of a rotary axis (C turntable, B head) from DBB runs.
pub mod rotary;
/// Seed 004: the DBB test of an A/C table as an RRSPS linkage: motion design and identification.
pub mod rrsps;
/// `jdbb simulate`: circular tests on a machine with chosen errors, as diagnosis CSV.
pub mod simulate;
pub mod stream;

pub use error::{Error, Result};
