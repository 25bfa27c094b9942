//! The board seam: everything that differs between the real STM32F411 and QEMU's netduinoplus2.
//! Both modules export the same names:
//!
//! - [`BOARD`], [`SIMULATED`]: what `DeviceInfo` and the status bits report;
//! - [`Parts`] / [`init`]: clocks, the raw-count source, the link, the sample timer;
//! - `Encoders::read(t_us) -> [u32; 2]`: the two counters' raw values at the sample taken at `t_us`;
//! - `Link::{poll, read, write}`: the byte link to the host (non-blocking).

#[cfg(feature = "board-f411")]
mod f411;
#[cfg(feature = "board-f411")]
pub use f411::*;

#[cfg(feature = "qemu")]
mod qemu;
#[cfg(feature = "qemu")]
pub use qemu::*;
