//! The board seam: everything that differs between the real STM32F411 and QEMU's netduinoplus2.
//! Both modules export the same names:
//!
//! - [`BOARD`], [`SIMULATED`]: what `DeviceInfo` and the status bits report;
//! - `init`: clocks, the raw-count source, the link, the sample timer, returned as [`Parts`];
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

/// Everything the application needs from the board, as `init` returns it.
pub struct Parts {
    /// Raw-count source.
    pub encoders: Encoders,
    /// Byte link to the host.
    pub link: Link,
    /// Sample clock (stopped).
    pub timer: SampleTimer,
    /// SysTick input clock for the monotonic (Hz).
    pub systick_hz: u32,
    /// Raw counter values at power-up.
    pub initial_raw: [u32; 2],
    /// Raw values at which the encoders' index pulses were seen during `init`, if any (the real
    /// board reports later pulses through its index tasks; the simulated encoders have their index
    /// at raw 0, where the simulated counter was reset).
    pub index_raw: Option<[u32; 2]>,
}
