//! QEMU `netduinoplus2` (an STM32F405 machine running this F411 binary; same peripheral addresses
//! and interrupt numbers for everything used here).
//!
//! What QEMU 7.2 models and what it does not decides this seam:
//!
//! - RCC, GPIO and USB OTG are not modelled: HSI only (the HAL would wait for HSE/PLL ready bits
//!   forever) and USART2 instead of USB.
//! - TIM2–5 have no encoder mode (16-bit counters clocked at 1 GHz whatever RCC says), so the
//!   encoders are simulated: a circular test from [`jdbb_core::sim`], or a scenario file named on
//!   the semihosting command line ([`crate::scenario`], `scripts/qemu-run.sh --scenario`), gives
//!   the extended counts at each sample time, presented as 32-bit raw counter values and fed
//!   through the same `Encoder<32>` path as TIM2/TIM5 on the real board.
//! - TIM3's update interrupt is not periodic there. Measured with SysTick under `-icount`: the
//!   first period is right (1 ms = 168 012 SysTick ticks), but re-armed by an update event each
//!   following period doubles, and left alone the interrupt fires back to back. So the sample clock
//!   is paced in software: [`SampleTimer`] here only holds the period (whole µs), and the
//!   application's `pace` task, woken every 1 ms by the SysTick monotonic, pends the TIM3
//!   interrupt once for every period elapsed on TIM2's count ([`pace_clock_raw_us`]), counting
//!   each tick ([`count_ticks`], the tick count the real board keeps in TIM4 and TIM1) — the very
//!   same sample task then runs. QEMU computes TIM2's count from its virtual clock, so no period is
//!   lost when QEMU delivers SysTick interrupts late or merged (it does on a loaded host: a 10 kHz
//!   monotonic alone ran at ~60 % of real time). When more periods elapsed than a burst catches
//!   up (the emulated CPU stalled, e.g. in a [`RamFlash`] erase, or the host starved QEMU), the
//!   rest are counted as ticks without a sample, so the sample task sees overruns exactly as on
//!   the board.
//! - Cost: the simulation (the default instrument, `Calibration::DEFAULT`: 2²³ counts/rev) runs in
//!   software f64 on the emulated M4F, ~36 000 instructions per sample (`scripts/fw-cycles.sh`;
//!   ~94 000 for an instrument with eccentric encoders, whose inverse iterates), so on QEMU's
//!   real-time clock rates above ~2 kHz overload the
//!   emulated CPU and samples are dropped (counted); under `-icount shift=0,sleep=off` nothing is
//!   dropped at any rate (see `scripts/qemu-run.sh`).
//! - SysTick runs at the machine's 168 MHz CPU clock (measured, see above).

use core::sync::atomic::{AtomicU32, Ordering};

use super::Parts;
use jdbb_core::protocol::{Board, CalKept, ResetCause, SampleBatch};
use jdbb_core::sampler::Sampler;
use jdbb_core::scenario::raw_of;
use jdbb_core::sim::CircularTest;
use jdbb_core::store::{CalStore, ClearedFlags};
use stm32f4xx_hal::{pac, prelude::*};

use crate::scenario::Scenario;
use crate::usart2::Usart2;

/// Reported in `DeviceInfo`.
pub const BOARD: Board = Board::QemuNetduinoPlus2;
/// Samples carry `Status::SIMULATED`.
pub const SIMULATED: bool = true;
/// Clock of the sample period: TIM2 counts µs ([`pace_clock_raw_us`]).
pub const PACE_HZ: u32 = 1_000_000;
/// SysTick's clock on netduinoplus2 (the machine's fixed 168 MHz system clock).
pub const SYSTICK_HZ: u32 = 168_000_000;
/// The QEMU build starts sampling at boot, so a host sees data without sending `Start`.
pub const AUTO_START: bool = true;
/// A UART has no connection state: a host may listen from power-up.
pub const LINK_UP_AT_START: bool = true;

/// Bring up the board: HSI clocks, USART2, TIM3 as the sample clock at `rate_hz`.
pub fn init(dp: pac::Peripherals, rate_hz: u32) -> Parts {
    let rcc = dp.RCC.constrain();
    let clocks = rcc.cfgr.freeze(); // HSI 16 MHz, no PLL
    let gpioa = dp.GPIOA.split();
    // TIM3 itself stays unused (see the module docs); its interrupt vector runs the sample task.
    let _ = dp.TIM3;
    start_pace_clock(dp.TIM2);
    let _tx = gpioa.pa2.into_alternate::<7>();
    let _rx = gpioa.pa3.into_alternate::<7>();
    let encoders = Encoders::new();
    Parts {
        initial_raw: encoders.last,
        encoders,
        link: Link {
            uart: Usart2::new(dp.USART2, clocks.pclk1().raw()),
        },
        timer: SampleTimer::new(rate_hz),
        systick_hz: SYSTICK_HZ,
        index_raw: Some([0, 0]),
        // QEMU models no unique ID (reading its address would fault) and no reset flags.
        chip_id: [0; 12],
        reset_cause: ResetCause::default(),
        unhandled_irq: None,
        cal_memory: {
            let mut m = CalMemory::open();
            m.erase_ahead();
            m
        },
        clock: jdbb_core::protocol::ClockSource::Emulated,
    }
}

/// Start QEMU's TIM2 as a free-running 32-bit µs counter (QEMU derives the count from its virtual
/// clock, see the module docs). It is used for nothing else.
fn start_pace_clock(tim: pac::TIM2) {
    // QEMU clocks the timer at 1 GHz: prescaler 1000 → 1 µs per count. ARR stays 0 (no
    // interrupts); the count runs regardless.
    tim.psc().write(|w| unsafe { w.bits(999) });
    tim.egr().write(|w| unsafe { w.bits(1) });
    tim.cr1().write(|w| unsafe { w.bits(1) });
}

/// The pacer's time base: TIM2's raw count (µs, wraps every 71 minutes; extend it with
/// `CountExtender<32>`).
#[inline]
pub fn pace_clock_raw_us() -> u32 {
    // SAFETY: read-only access to a counter configured once in `init` and used nowhere else.
    unsafe { (*pac::TIM2::ptr()).cnt().read().bits() }
}

/// Simulated encoders: a scenario file if the semihosting command line names one
/// ([`crate::scenario`]), else [`CircularTest::DEFAULT`] (R = 90 mm, 1000 mm/min, ccw then cw).
pub struct Encoders {
    source: Source,
    last: [u32; 2],
}

// One instance, the sample task's local resource; no heap to box the block buffer into.
#[allow(clippy::large_enum_variant)]
enum Source {
    Circle(CircularTest),
    Scenario(Scenario),
}

impl Encoders {
    /// The encoders the command line asks for. A scenario that cannot be played stops QEMU with
    /// the reason on its stdout (a run must never silently fall back to the built-in circle).
    fn new() -> Self {
        let mut enc = match Scenario::from_command_line() {
            None => Encoders {
                source: Source::Circle(CircularTest::DEFAULT),
                last: [0, 0],
            },
            Some(Ok(s)) => {
                let h = s.header();
                defmt::info!("scenario: {} records every {} us", h.n_samples, h.period_us);
                cortex_m_semihosting::hprintln!(
                    "jdbb-firmware: playing a scenario of {} records every {} us",
                    h.n_samples,
                    h.period_us
                );
                Encoders {
                    source: Source::Scenario(s),
                    last: [0, 0],
                }
            }
            Some(Err(e)) => {
                defmt::error!("scenario: {}", e);
                cortex_m_semihosting::hprintln!(
                    "jdbb-firmware: scenario not played: {}",
                    e.describe()
                );
                cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
                unreachable!("QEMU exits");
            }
        };
        enc.last = enc.read(0);
        enc
    }

    /// First thing at a tick of the sample clock: the pacer's tick count (the simulated counters
    /// are computed for the tick's time by [`Self::sample`]).
    #[inline]
    pub fn latch(&mut self) -> Latch {
        Latch {
            tick: TICKS.load(Ordering::Relaxed),
        }
    }

    /// The latched tick's sample: the simulated counters at the tick's time, to the sampler.
    #[inline]
    pub fn sample(&mut self, latch: Latch, s: &mut Sampler) -> Option<SampleBatch> {
        s.sample_at_tick(latch.tick, |t_us| self.read(t_us))
    }

    /// The simulated counters' raw values for the sample taken at `t_us` (the extended counts
    /// truncated to 32 bits, as a 32-bit timer would hold them). Holds the last value if the
    /// test's radius were out of the instrument's reach.
    #[inline]
    fn read(&mut self, t_us: u64) -> [u32; 2] {
        match &mut self.source {
            Source::Circle(test) => {
                if let Some((c1, c2)) = test.counts_at(t_us) {
                    self.last = [raw_of(c1), raw_of(c2)];
                }
            }
            Source::Scenario(s) => self.last = s.raw_at(t_us),
        }
        self.last
    }
}

/// What the board latched at a tick of the sample clock: here only the tick count.
#[derive(Clone, Copy)]
pub struct Latch {
    tick: u32,
}

impl Latch {
    /// The tick count.
    #[inline]
    pub fn tick(&self) -> u32 {
        self.tick
    }
}

/// USART2 as the host link.
pub struct Link {
    uart: Usart2,
}

impl Link {
    /// Service the link (nothing to do for a UART); true if bytes may have arrived.
    #[inline]
    pub fn poll(&mut self) -> bool {
        true
    }

    /// Received bytes into `buf`; how many.
    #[inline]
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        self.uart.read(buf)
    }

    /// Queue bytes for sending without waiting; how many were taken (0 = would block).
    #[inline]
    pub fn write(&mut self, bytes: &[u8]) -> usize {
        self.uart.write(bytes)
    }

    /// A UART never comes up or goes down.
    pub fn take_change(&mut self) -> Option<bool> {
        None
    }

    /// Nothing is buffered beyond the transmit register.
    pub fn drained(&mut self) -> bool {
        true
    }

    /// Nothing to discard.
    pub fn discard_pending(&mut self) {}
}

/// Ticks of the sample clock pended by the pacer since sampling started (the real board's TIM4).
static TICKS: AtomicU32 = AtomicU32::new(0);

/// The pacer counts `n` more ticks of the sample clock (more than one: ticks the emulated CPU
/// missed, as the board's TIM4 counts them while its CPU stalls).
#[inline]
pub fn count_ticks(n: u32) {
    TICKS.fetch_add(n, Ordering::Relaxed);
}

/// Period of the running sample clock in µs, 0 when stopped; read by the pacer.
static PACE_PERIOD: AtomicU32 = AtomicU32::new(0);

/// The period the application's pacer must wait before pending the sample interrupt again (µs);
/// 0 while sampling is stopped.
pub fn pace_period_us() -> u32 {
    PACE_PERIOD.load(Ordering::Relaxed)
}

/// The sample clock of the QEMU build: the same interface as the real board's TIM3 driver, paced
/// by the application from SysTick (see the module docs).
pub struct SampleTimer {
    period_ticks: u32,
    pending: Option<u32>,
    running: bool,
}

impl SampleTimer {
    /// A stopped clock at `rate_hz`.
    pub fn new(rate_hz: u32) -> Self {
        let mut t = SampleTimer {
            period_ticks: 1,
            pending: None,
            running: false,
        };
        t.set_rate(rate_hz);
        t
    }

    fn period_for(rate_hz: u32) -> u32 {
        let hz = rate_hz.max(1);
        ((PACE_HZ + hz / 2) / hz).max(1)
    }

    /// The nearest whole-µs period to `rate_hz`; returns it in ticks of [`Self::clock_hz`] (µs).
    /// While running, the change waits for the sample task ([`Self::apply_pending_rate`]), as on
    /// the real board.
    pub fn set_rate(&mut self, rate_hz: u32) -> u32 {
        let ticks = Self::period_for(rate_hz);
        if self.running {
            self.pending = Some(ticks);
        } else {
            self.pending = None;
            self.period_ticks = ticks;
        }
        ticks
    }

    /// Called by the sample task right after tick `tick`, before it computes that tick's sample:
    /// apply a rate change asked for while running from the next period on; returns the new
    /// period for the sampler's clock, to be set after tick `tick`'s sample. The pacer runs at the
    /// sample task's priority, so the tick count cannot move meanwhile (checked all the same).
    #[inline]
    pub fn apply_pending_rate(&mut self, tick: u32) -> Option<u32> {
        if TICKS.load(Ordering::Relaxed) != tick {
            return None;
        }
        let ticks = self.pending.take()?;
        self.period_ticks = ticks;
        PACE_PERIOD.store(ticks, Ordering::Relaxed);
        Some(ticks)
    }

    /// Clock of the period (Hz).
    pub fn clock_hz(&self) -> u32 {
        PACE_HZ
    }

    /// Current period in ticks.
    pub fn period_ticks(&self) -> u32 {
        self.period_ticks
    }

    /// Sample rate (Hz, rounded), including a change that waits for the next period.
    pub fn rate_hz(&self) -> u32 {
        let ticks = self.pending.unwrap_or(self.period_ticks);
        (PACE_HZ + ticks / 2) / ticks
    }

    /// Start pacing; the tick count restarts at 0 (with `Sampler::restart`).
    pub fn start(&mut self) {
        if let Some(ticks) = self.pending.take() {
            self.period_ticks = ticks;
        }
        TICKS.store(0, Ordering::Relaxed);
        self.running = true;
        PACE_PERIOD.store(self.period_ticks, Ordering::Relaxed);
    }

    /// Stop pacing.
    pub fn stop(&mut self) {
        self.running = false;
        PACE_PERIOD.store(0, Ordering::Relaxed);
    }

    /// Whether samples are being paced.
    pub fn is_running(&self) -> bool {
        self.running
    }

    /// Nothing to acknowledge: the interrupt was pended by software.
    #[inline]
    pub fn clear_update(&mut self) {}
}

/// Erase block of the RAM flash (and block of the calibration store: 4 records).
const RAM_FLASH_BLOCK: u32 = 1024;
/// How long an erase of the RAM flash holds the emulated CPU (µs of emulated time), with every
/// interrupt masked: the board's single-bank flash stalls every instruction fetch for a 128 KiB
/// erase (2–4 s); shorter here so that tests stay quick, and long enough (1 000 periods at 5 kHz)
/// to see a stall in the stream.
pub const ERASE_STALL_US: u32 = 200_000;

/// `FLASH_SR`'s error flags as the board's flash has them (RM0383 §3.8.4): OPERR, WRPERR,
/// PGAERR, PGPERR, PGSERR; set by a failed operation, kept until cleared.
const SR_ERRORS: u32 = (1 << 1) | (1 << 4) | (1 << 5) | (1 << 6) | (1 << 7);
/// `FLASH_SR.WRPERR`: programming or erasing a write-protected sector.
const SR_WRPERR: u32 = 1 << 4;
/// `FLASH_SR.PGSERR`: a programming sequence error, the flag a DFU `:leave` can leave set.
const SR_PGSERR: u32 = 1 << 7;

/// How the QEMU build's calibration flash misbehaves: the semihosting command line's
/// `flash-fault=MODE` (`tests/tests/qemu_store.rs`); none by default.
#[derive(Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum FlashFault {
    /// A working flash.
    None,
    /// An error flag (PGSERR) is set at power-up, as the ROM bootloader can leave it before a
    /// DFU `:leave` jump: every store fails unless the driver clears the flags first.
    Leftover,
    /// The store's sectors are write-protected: every program and erase sets WRPERR and changes
    /// nothing.
    Protected,
    /// Programming reports success but changes nothing (only reading back finds it out).
    Deaf,
}

impl FlashFault {
    fn from_command_line() -> Self {
        let mut buf = [0u8; 32];
        match crate::scenario::flash_fault_arg(&mut buf) {
            Some(b"leftover") => FlashFault::Leftover,
            Some(b"protected") => FlashFault::Protected,
            Some(b"deaf") => FlashFault::Deaf,
            _ => FlashFault::None,
        }
    }
}

/// NOR flash in RAM for the calibration store, with the NOR rules that matter (erased = 0xFF,
/// whole-block erases), an erase that stalls the CPU like the board's ([`ERASE_STALL_US`]), and
/// the board's error flags: an operation fails when any flag is set after it, a leftover one
/// included, as the HAL checks them; `ClearedFlags` clears them before every operation, as on
/// the board ([`FlashFault`] injects the failures).
pub struct RamFlash {
    mem: &'static mut [u8; 2 * RAM_FLASH_BLOCK as usize],
    /// The modelled `FLASH_SR`.
    sr: u32,
    fault: FlashFault,
}

impl jdbb_core::store::StickyErrors for RamFlash {
    /// Before every erase or program, as on the board (`jdbb_core::store::ClearedFlags`): clear
    /// the error flags.
    fn clear_errors(&mut self) {
        self.sr &= !SR_ERRORS;
    }
}

impl RamFlash {
    /// After an operation, as the HAL: any error flag fails it.
    fn status(&self) -> Result<(), embedded_storage::nor_flash::NorFlashErrorKind> {
        if self.sr & SR_ERRORS != 0 {
            Err(embedded_storage::nor_flash::NorFlashErrorKind::Other)
        } else {
            Ok(())
        }
    }
}

impl embedded_storage::nor_flash::ErrorType for RamFlash {
    type Error = embedded_storage::nor_flash::NorFlashErrorKind;
}

impl embedded_storage::nor_flash::ReadNorFlash for RamFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let o = offset as usize;
        let src = self
            .mem
            .get(o..o + bytes.len())
            .ok_or(Self::Error::OutOfBounds)?;
        bytes.copy_from_slice(src);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl embedded_storage::nor_flash::NorFlash for RamFlash {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = RAM_FLASH_BLOCK as usize;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let range = self
            .mem
            .get_mut(from as usize..to as usize)
            .ok_or(Self::Error::OutOfBounds)?;
        if self.fault == FlashFault::Protected {
            self.sr |= SR_WRPERR;
        } else {
            range.fill(0xff);
            cortex_m::interrupt::free(|_| {
                let t0 = pace_clock_raw_us();
                while pace_clock_raw_us().wrapping_sub(t0) < ERASE_STALL_US {
                    cortex_m::asm::delay(10_000);
                }
            });
        }
        self.status()
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let o = offset as usize;
        let dst = self
            .mem
            .get_mut(o..o + bytes.len())
            .ok_or(Self::Error::OutOfBounds)?;
        match self.fault {
            FlashFault::Protected => self.sr |= SR_WRPERR,
            FlashFault::Deaf => {}
            // NOR programming only clears bits.
            _ => dst.iter_mut().zip(bytes).for_each(|(d, b)| *d &= *b),
        }
        self.status()
    }
}

/// The calibration kept across resets: the board's store (`jdbb_core::store`) over a RAM flash
/// ([`RamFlash`]: QEMU does not emulate flash writes), so it lasts until QEMU is restarted, and
/// its erases stall the CPU as the board's do.
pub struct CalMemory(Option<CalStore<ClearedFlags<RamFlash>>>);

impl CalMemory {
    fn open() -> Self {
        let fault = FlashFault::from_command_line();
        if fault != FlashFault::None {
            defmt::warn!("calibration flash fault injected: {}", fault);
        }
        let mem = cortex_m::singleton!(: [u8; 2 * RAM_FLASH_BLOCK as usize] =
            [0xff; 2 * RAM_FLASH_BLOCK as usize]);
        CalMemory(mem.and_then(|mem| {
            let flash = RamFlash {
                mem,
                sr: if fault == FlashFault::Leftover {
                    SR_PGSERR
                } else {
                    0
                },
                fault,
            };
            CalStore::open(ClearedFlags(flash), 0, RAM_FLASH_BLOCK).ok()
        }))
    }

    /// The calibration stored last, if any.
    pub fn load(&self) -> Option<jdbb_core::Calibration> {
        self.0.as_ref().and_then(CalStore::load)
    }

    /// Keep `cal` and read it back; what became of it (the reply reports it). Erases a block
    /// first (a stall of [`ERASE_STALL_US`]) only if the spare was not erased ahead.
    pub fn store(&mut self, cal: &jdbb_core::Calibration) -> CalKept {
        let Some(s) = self.0.as_mut() else {
            return CalKept::NoRoom;
        };
        if s.store_would_erase().unwrap_or(false) {
            defmt::warn!("this store erases a block: the CPU stalls");
        }
        jdbb_core::store::kept(&s.store(cal))
    }

    /// Erase the store's spare block if it is not erased yet (call it only while not sampling);
    /// whether it erased.
    pub fn erase_ahead(&mut self) -> bool {
        self.0
            .as_mut()
            .is_some_and(|s| s.erase_spare().unwrap_or(false))
    }
}

/// No index interrupts in the QEMU build: never switched off.
pub fn index_disabled() -> [bool; 2] {
    [false; 2]
}

/// No LED in QEMU's model (its panic handler, panic-probe, exits QEMU).
pub fn init_done() {}

/// No watchdog in QEMU's model: nothing to feed.
#[inline]
pub fn feed_watchdog() {}

/// The status LED's pin: QEMU's netduinoplus2 models no GPIO, so driving it does nothing; the
/// code is still played through [`jdbb_core::indicator`] as on the board.
#[derive(Clone, Copy)]
pub struct Led;

impl embedded_hal::digital::ErrorType for Led {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::OutputPin for Led {
    #[inline]
    fn set_low(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }

    #[inline]
    fn set_high(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

/// The status LED at `t_ms`: always running here (QEMU's clocks cannot fail).
#[inline]
pub fn indicate(t_ms: u32) {
    jdbb_core::indicator::Indicator::new(Led, false)
        .show(jdbb_core::indicator::LedCode::Running, t_ms);
}
