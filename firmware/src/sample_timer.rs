//! The real board's sample clock, register-level: TIM3 (16-bit) makes one update event per sample
//! period, which
//!
//! - raises the sample task's interrupt (TIM3 update);
//! - is TIM3's trigger output (TRGO, `CR2.MMS = update`), on which TIM2 and TIM5 latch their
//!   counts into CCR4 (input capture on TRC; see `board::f411`), so both encoders are read at the
//!   same instant in hardware, however late the interrupt runs;
//! - clocks TIM4 (external clock mode 1 on ITR2 = TIM3's TRGO, RM0383 table "TIMx internal trigger
//!   connection"), the low 16 bits of the count of sample-clock ticks; TIM4's overflow is its own
//!   TRGO (`MMS = update`), which clocks TIM1 (external clock mode 1 on ITR3 = TIM4's TRGO), the
//!   high 16 bits. The sample task learns from the 32-bit count how many ticks passed since it last
//!   ran (overruns, see `jdbb_core::sampler`): 32 bits, so that even a stall as long as a 128 KiB
//!   flash erase (4 s, 80 000 periods at 20 kHz) is counted exactly instead of wrapping.
//!
//! A new rate is written by the sample task right after the tick it serves, *before* it computes
//! that tick's sample ([`SampleTimer::apply_pending_rate`]), into the preloaded PSC/ARR, so the
//! period running then completes with its old length and the new one starts at the next update
//! event: the sample clock never restarts mid-period. The write is made only with the tick count
//! unchanged since the tick and at least [`RATE_WRITE_MARGIN_US`] left in the period (interrupts
//! masked for the two stores), so it always lands before the next update event
//! (`jdbb_core::sampler::rate_write_lands`, host-tested against a model of the timer); checked
//! again after the write. Otherwise it waits for the next tick (one period later, and the sampler's clock
//! switches with it).
//! (QEMU's TIM3 model cannot do this; the `qemu` board paces the same interrupt from SysTick.)

use jdbb_core::sampler::rate_write_lands;
use stm32f4xx_hal::pac;
use stm32f4xx_hal::rcc::{Enable, Reset};

const CR1_CEN: u32 = 1 << 0;
const CR1_URS: u32 = 1 << 2;
const CR1_ARPE: u32 = 1 << 7;
const CR2_MMS_UPDATE: u32 = 0b010 << 4;
const DIER_UIE: u32 = 1 << 0;
const SR_UIF: u32 = 1 << 0;
const EGR_UG: u32 = 1 << 0;
/// TIM4 slave mode: external clock mode 1 (`SMS = 111`) from ITR2 (`TS = 010`) = TIM3's TRGO.
const TIM4_SMCR_ECM1_ITR2: u32 = 0b111 | (0b010 << 4);
/// TIM1 slave mode: external clock mode 1 (`SMS = 111`) from ITR3 (`TS = 011`) = TIM4's TRGO.
const TIM1_SMCR_ECM1_ITR3: u32 = 0b111 | (0b011 << 4);

/// Least time left in the period for the sample task to write a new PSC/ARR (µs): far more than
/// the two stores take, so the write cannot straddle the update event.
pub const RATE_WRITE_MARGIN_US: u32 = 2;

/// The sample task's view of the tick counter: TIM1:TIM4, the 32-bit count of TIM3 update events
/// (wraps after 2³² ticks, 2.5 days at 20 kHz), reset to 0 by [`SampleTimer::start`]. TIM1 counts
/// TIM4's overflow a few timer clocks late (its slave controller resynchronises the trigger):
/// [`jdbb_core::ticks::read_tick_count`] waits that out when TIM4 reads 0 (proved there against
/// a model of the two timers), so the count is never 65 536 low.
#[inline]
pub fn tick_count() -> u32 {
    // SAFETY: read-only access to counters configured in `SampleTimer::new` and written only by
    // `SampleTimer::start`.
    let (lo, hi) = unsafe { (&*pac::TIM4::ptr(), &*pac::TIM1::ptr()) };
    jdbb_core::ticks::read_tick_count(
        || lo.cnt().read().bits() as u16,
        || hi.cnt().read().bits() as u16,
        // ≥ 32 CPU cycles (timer clock = CPU clock): far more than the resynchronisation's 2–3
        // timer clocks, far less than a sample period (≥ 4 800 cycles at 20 kHz).
        || cortex_m::asm::delay(32),
    )
}

/// TIM3 as the sample clock, TIM4 counting its ticks, both from a `clock_hz` timer clock.
pub struct SampleTimer {
    tim: pac::TIM3,
    clock_hz: u32,
    period_ticks: u32,
    pending: Option<(u32, u32)>,
}

impl SampleTimer {
    /// Enable TIM3 and TIM4 with a `clock_hz` input clock and program `rate_hz`; the sample clock
    /// stays stopped until [`Self::start`].
    pub fn new(
        tim: pac::TIM3,
        tim4: pac::TIM4,
        tim1: pac::TIM1,
        clock_hz: u32,
        rate_hz: u32,
    ) -> Self {
        unsafe {
            pac::TIM3::enable_unchecked();
            pac::TIM3::reset_unchecked();
            pac::TIM4::enable_unchecked();
            pac::TIM4::reset_unchecked();
            pac::TIM1::enable_unchecked();
            pac::TIM1::reset_unchecked();
        }
        // Only counter overflow raises the update interrupt, not the UG we use to load PSC/ARR;
        // ARR is preloaded so a new period starts cleanly at an update event.
        tim.cr1().write(|w| unsafe { w.bits(CR1_URS | CR1_ARPE) });
        tim.cr2().write(|w| unsafe { w.bits(CR2_MMS_UPDATE) });
        tim4.arr().write(|w| unsafe { w.bits(0xffff) });
        tim4.smcr()
            .write(|w| unsafe { w.bits(TIM4_SMCR_ECM1_ITR2) });
        // TIM4's overflow (its update event) is its TRGO, TIM1's clock: the count's high half.
        tim4.cr2().write(|w| unsafe { w.bits(CR2_MMS_UPDATE) });
        tim4.cr1().write(|w| unsafe { w.bits(CR1_CEN) });
        tim1.arr().write(|w| unsafe { w.bits(0xffff) });
        tim1.smcr()
            .write(|w| unsafe { w.bits(TIM1_SMCR_ECM1_ITR3) });
        tim1.cr1().write(|w| unsafe { w.bits(CR1_CEN) });
        let mut t = SampleTimer {
            tim,
            clock_hz,
            period_ticks: 0,
            pending: None,
        };
        let (psc, arr) = t.divide(rate_hz);
        t.write(psc, arr); // loaded by the UG in `start`
        t
    }

    /// Prescaler and reload for the nearest period to `rate_hz` (≥ 1) the 16-bit registers allow.
    fn divide(&self, rate_hz: u32) -> (u32, u32) {
        let total = (self.clock_hz / rate_hz.max(1)).max(2);
        let psc = (total - 1) / 65_536; // smallest prescaler that makes ARR fit 16 bits
        let arr = (total / (psc + 1)).clamp(2, 65_536) - 1;
        (psc, arr)
    }

    /// Write PSC/ARR (both preloaded: they take effect at the next update event, or at the UG in
    /// [`Self::start`]).
    fn write(&mut self, psc: u32, arr: u32) -> u32 {
        self.tim.psc().write(|w| unsafe { w.bits(psc) });
        self.tim.arr().write(|w| unsafe { w.bits(arr) });
        self.period_ticks = (psc + 1) * (arr + 1);
        self.period_ticks
    }

    /// Program the nearest period to `rate_hz`; returns it in input-clock ticks,
    /// `(PSC + 1) · (ARR + 1)`, which is exact (see [`jdbb_core::sampler::SampleClock`]). While
    /// the clock runs, the change waits for the sample task ([`Self::apply_pending_rate`]) and the
    /// caller must not change the sampler's period itself.
    pub fn set_rate(&mut self, rate_hz: u32) -> u32 {
        let (psc, arr) = self.divide(rate_hz);
        if self.is_running() {
            self.pending = Some((psc, arr));
            (psc + 1) * (arr + 1)
        } else {
            self.pending = None;
            self.write(psc, arr)
        }
    }

    /// Called by the sample task right after tick `tick` (the tick count it read), before it
    /// computes that tick's sample: write a rate change asked for while running, so that it
    /// starts with the period after the current one; returns the new period (ticks) for the
    /// sampler's clock, to be set after tick `tick`'s sample. `None` (the change stays pending,
    /// for the next tick) when the tick count moved on already or less than
    /// [`RATE_WRITE_MARGIN_US`] is left in the period; see the module docs.
    #[inline]
    pub fn apply_pending_rate(&mut self, tick: u32) -> Option<u32> {
        let (psc, arr) = self.pending?;
        let margin = self.clock_hz / 1_000_000 * RATE_WRITE_MARGIN_US;
        let written = cortex_m::interrupt::free(|_| {
            let left = {
                let r = self.tim.arr().read().bits() + 1 - self.tim.cnt().read().bits();
                r * (self.tim.psc().read().bits() + 1)
            };
            if !rate_write_lands(tick, tick_count(), left, margin) {
                return None;
            }
            let ticks = self.write(psc, arr);
            // The write is before the update event that ends this period: the count is still
            // `tick` (checked, not assumed).
            (tick_count() == tick).then_some(ticks)
        });
        if written.is_some() {
            self.pending = None;
        }
        written
    }

    /// Input clock of the timer (Hz).
    pub fn clock_hz(&self) -> u32 {
        self.clock_hz
    }

    /// Current period in input-clock ticks.
    pub fn period_ticks(&self) -> u32 {
        self.period_ticks
    }

    /// Sample rate (Hz, rounded), including a change that waits for the next period.
    pub fn rate_hz(&self) -> u32 {
        let ticks = match self.pending {
            Some((psc, arr)) => (psc + 1) * (arr + 1),
            None => self.period_ticks,
        };
        (self.clock_hz + ticks / 2) / ticks.max(1)
    }

    /// Start counting with the update interrupt enabled; the first tick (tick count 1) comes one
    /// full period later. The tick count restarts at 0 (with `Sampler::restart`).
    pub fn start(&mut self) {
        if let Some((psc, arr)) = self.pending.take() {
            self.write(psc, arr);
        }
        // UG restarts the counter and the prescaler and loads PSC/ARR. It is also a TRGO pulse
        // (one tick for TIM4, one capture), so TIM4 is cleared after it — after a pause much longer
        // than the few timer clocks TIM4's slave controller takes to count it.
        self.tim.egr().write(|w| unsafe { w.bits(EGR_UG) });
        cortex_m::asm::delay(64);
        // SAFETY: TIM4 and TIM1 are the tick counter, configured in `new`; only this function
        // writes them.
        unsafe {
            (*pac::TIM4::ptr()).cnt().write(|w| w.bits(0));
            (*pac::TIM1::ptr()).cnt().write(|w| w.bits(0));
        }
        self.tim.sr().write(|w| unsafe { w.bits(0) });
        self.tim.dier().write(|w| unsafe { w.bits(DIER_UIE) });
        self.tim
            .cr1()
            .write(|w| unsafe { w.bits(CR1_URS | CR1_ARPE | CR1_CEN) });
    }

    /// Stop counting and mask the interrupt.
    pub fn stop(&mut self) {
        self.tim
            .cr1()
            .write(|w| unsafe { w.bits(CR1_URS | CR1_ARPE) });
        self.tim.dier().write(|w| unsafe { w.bits(0) });
        self.tim.sr().write(|w| unsafe { w.bits(0) });
    }

    /// Whether the timer runs.
    pub fn is_running(&self) -> bool {
        self.tim.cr1().read().bits() & CR1_CEN != 0
    }

    /// Acknowledge the update interrupt (first thing in the sample task). Clears UIF only
    /// (the status bits are cleared by writing 0, so every other bit is written 1). A tick that
    /// came while UIF was still set is not lost: TIM4 counted it.
    #[inline]
    pub fn clear_update(&mut self) {
        self.tim.sr().write(|w| unsafe { w.bits(!SR_UIF) });
    }
}
