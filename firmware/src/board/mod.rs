//! The board seam: everything that differs between the real STM32F411 and QEMU's netduinoplus2.
//! Both modules export the same names:
//!
//! - [`BOARD`], [`SIMULATED`]: what `DeviceInfo` and the status bits report;
//! - `init`: clocks, the raw-count source, the link, the sample timer, returned as [`Parts`];
//! - `Encoders::latch() -> Latch` then `Encoders::sample(Latch, &mut Sampler) ->
//!   Option<SampleBatch>`: one tick of the sample clock — the hardware's 32-bit tick count (and,
//!   on the board, the two counters latched at that tick), then the tick's sample through
//!   `Sampler::sample_at_tick`;
//! - `SampleTimer`: the sample clock (`set_rate` deferred to a period boundary while running,
//!   `apply_pending_rate(tick)` from the sample task between the two calls above, `start`/`stop`,
//!   `clear_update`);
//! - `feed_watchdog`, `indicate(t_ms)`: the idle loop's duties (the board's watchdog and status
//!   LED; nothing on QEMU); `Led`: the LED as an embedded-hal `OutputPin`, whose codes
//!   [`jdbb_core::indicator`] plays (QEMU's drives nothing: no GPIO there);
//! - `IndexTimer(ch)` (a `jdbb_core::quadrature::IndexCapture`) and `ZPin(ch)` (the
//!   index line as an embedded-hal `InputPin`) for `jdbb_core::quadrature::service_index`, and
//!   `index_disabled()` (QEMU: no index interrupts, only `index_disabled()`, all false);
//! - `Link::{poll, take_change, read, write, drained, discard_pending}`: the byte link to the host
//!   (non-blocking), whether it came up or went down, and its transmit buffer;
//! - [`LINK_UP_AT_START`]: whether a host may be listening at power-up (UART) or only once the
//!   link reports it came up (USB).
//! - `CalMemory::{load, store, erase_ahead}` (`store` returns the `CalKept` the reply reports): where the calibration is kept across power cycles —
//!   [`jdbb_core::store`] over flash sectors 6 and 7 on the board, over a RAM "flash" whose erase
//!   stalls the CPU on QEMU, which does not emulate flash writes (so there it lasts until QEMU is
//!   restarted); `erase_ahead` erases the spare block while not sampling.

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
    /// The chip's unique ID (zeros where there is none).
    pub chip_id: [u8; 12],
    /// Why the device started.
    pub reset_cause: jdbb_core::protocol::ResetCause,
    /// The interrupt without a handler that reset the device, if that is why it started.
    pub unhandled_irq: Option<i16>,
    /// The calibration kept across power cycles.
    pub cal_memory: CalMemory,
    /// What the clocks run from (the crystal, or the internal oscillator when it did not start).
    pub clock: jdbb_core::protocol::ClockSource,
}
