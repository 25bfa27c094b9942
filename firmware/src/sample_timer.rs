//! The real board's sample clock: TIM3 (16-bit) as a periodic update interrupt, register-level.
//! (QEMU's TIM3 model cannot do this; the `qemu` board paces the same interrupt from SysTick.)

use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Enable, Reset};

const CR1_CEN: u32 = 1 << 0;
const CR1_URS: u32 = 1 << 2;
const DIER_UIE: u32 = 1 << 0;
const EGR_UG: u32 = 1 << 0;

/// TIM3 driven by a `clock_hz` input clock.
pub struct SampleTimer {
    tim: pac::TIM3,
    clock_hz: u32,
    period_ticks: u32,
}

impl SampleTimer {
    /// Enable TIM3 with a `clock_hz` input clock and program `rate_hz`; the timer stays stopped
    /// until [`Self::start`].
    pub fn new(tim: pac::TIM3, clock_hz: u32, rate_hz: u32) -> Self {
        unsafe {
            pac::TIM3::enable_unchecked();
            pac::TIM3::reset_unchecked();
        }
        // Only counter overflow raises the update interrupt, not the UG we use to load PSC/ARR.
        tim.cr1().write(|w| unsafe { w.bits(CR1_URS) });
        let mut t = SampleTimer {
            tim,
            clock_hz,
            period_ticks: 0,
        };
        t.set_rate(rate_hz);
        t
    }

    /// Program the nearest period to `rate_hz` (≥ 1) the 16-bit prescaler and reload allow; returns
    /// the period in input-clock ticks, `(PSC + 1) · (ARR + 1)`, which is exact (see
    /// [`jdbb_core::sampler::SampleClock`]).
    pub fn set_rate(&mut self, rate_hz: u32) -> u32 {
        let total = (self.clock_hz / rate_hz.max(1)).max(2);
        let psc = (total - 1) / 65_536; // smallest prescaler that makes ARR fit 16 bits
        let arr = (total / (psc + 1)).clamp(2, 65_536) - 1;
        self.tim.psc().write(|w| unsafe { w.bits(psc) });
        self.tim.arr().write(|w| unsafe { w.bits(arr) });
        self.tim.egr().write(|w| unsafe { w.bits(EGR_UG) }); // load PSC now, restart the count
        self.period_ticks = (psc + 1) * (arr + 1);
        self.period_ticks
    }

    /// Input clock of the timer (Hz).
    pub fn clock_hz(&self) -> u32 {
        self.clock_hz
    }

    /// Current period in input-clock ticks.
    pub fn period_ticks(&self) -> u32 {
        self.period_ticks
    }

    /// Effective sample rate (Hz, rounded).
    pub fn rate_hz(&self) -> u32 {
        (self.clock_hz + self.period_ticks / 2) / self.period_ticks.max(1)
    }

    /// Start counting with the update interrupt enabled; the first sample comes one period later.
    pub fn start(&mut self) {
        self.tim.cnt().write(|w| unsafe { w.bits(0) });
        self.tim.sr().write(|w| unsafe { w.bits(0) });
        self.tim.dier().write(|w| unsafe { w.bits(DIER_UIE) });
        self.tim
            .cr1()
            .write(|w| unsafe { w.bits(CR1_URS | CR1_CEN) });
    }

    /// Stop counting and mask the interrupt.
    pub fn stop(&mut self) {
        self.tim.cr1().write(|w| unsafe { w.bits(CR1_URS) });
        self.tim.dier().write(|w| unsafe { w.bits(0) });
        self.tim.sr().write(|w| unsafe { w.bits(0) });
    }

    /// Whether the timer runs.
    pub fn is_running(&self) -> bool {
        self.tim.cr1().read().bits() & CR1_CEN != 0
    }

    /// Acknowledge the update interrupt (first thing in the sample task).
    #[inline]
    pub fn clear_update(&mut self) {
        self.tim.sr().write(|w| unsafe { w.bits(0) });
    }
}
