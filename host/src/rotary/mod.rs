//! Rotary axes measured with a ball bar (seed 002).
//!
//! - [`six_errors`]: the six geometric errors of a C turntable or B swinging head (δx, δy, δz,
//!   εx, εy, εz) from radial, tangential and axial runs: forward model, the paper's per-angle least
//!   squares, a joint Fourier fit, what the installations can determine (`jdbb rotary`).
//! - [`run_diagnosis`]: each angle-indexed run on its own through the circular tests' selection
//!   engine: which harmonics, constants and drifts the data support (`jdbb diagnose-rotary`).
//!
//! May use: [`crate::numerics`], [`crate::table`].
pub mod run_diagnosis;
pub mod six_errors;
