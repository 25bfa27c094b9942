//! STM32F411CEU6 "Black Pill" (25 MHz crystal, or another: see [`HSE_HZ`]).
//!
//! | signal              | pin  | peripheral            |
//! |---------------------|------|-----------------------|
//! | encoder 1 A / B     | PA15 / PB3 | TIM2 CH1/CH2 (AF1), quadrature ×4 |
//! | encoder 1 index (Z) | PB10 | TIM2 CH3 input capture, both edges (AF1) |
//! | encoder 2 A / B     | PA0 / PA1  | TIM5 CH1/CH2 (AF2), quadrature ×4 |
//! | encoder 2 index (Z) | PA2  | TIM5 CH3 input capture, both edges (AF2) |
//! | USB FS D− / D+      | PA11 / PA12 | OTG_FS, CDC-ACM |
//!
//! All encoder inputs get the internal pull-ups and a digital input filter of 8 timer clocks
//! (83 ns at 96 MHz). Counts are latched in hardware twice:
//!
//! - at every sample-clock tick, into CCR4 of TIM2 and TIM5 (channel 4 captures on TRC, the
//!   internal trigger = TIM3's update event: ITR2 for TIM2, ITR1 for TIM5), so both encoders are
//!   sampled at the same instant whatever the interrupt latency; TIM4 counts the ticks (see
//!   `crate::sample_timer`);
//! - at every index edge, into CCR3, so index referencing is exact however late its interrupt runs.
//!
//! The calibration is kept in flash sectors 6 and 7 (offsets 256–512 KiB, 2 × 128 KiB, the HAL's
//! erase size) with [`jdbb_core::store`]: `memory.x` gives the program the first 256 KiB only.
//! Writing one record stalls the CPU's instruction fetch for ~2 ms (about 110 bytes programmed one
//! at a time, 16 µs each, as the HAL programs). Every 512th store needs a 128 KiB sector erased,
//! 2 s typical, 4 s max (DS10314, x8 parallelism as the HAL erases), during which the single-bank
//! flash stalls every instruction fetch, so no task runs whatever its priority: the spare sector is
//! therefore erased *ahead*, at power-up and whenever sampling stops (`jdbb_core::store`,
//! `CalStore::erase_spare`), never in the store itself unless 512 stores came without a stop. A
//! stall is never silent: the sample clock's 32-bit tick count keeps counting (see
//! `crate::sample_timer`), so the missed ticks show as overruns and drops with their sequence
//! numbers and time skipped. An F411xC (256 KiB) has no
//! sectors 6 and 7: there the calibration is not kept (logged at start-up).
//!
//! Clocks: HSE 25 MHz ([`HSE_HZ`], other crystals by cargo feature) → PLL → SYSCLK 96 MHz (48 MHz
//! for USB), APB1 48 MHz, timer clock 96 MHz, with the regulator in voltage scale 1 (needed above
//! 84 MHz). `init` first returns the clocks to their reset state (HSI, PLL off: the ROM DFU
//! bootloader leaves its PLL running), then starts the crystal and locks the PLL once itself, every
//! wait bounded, before the HAL (whose waits are not) programs them; the crystal is measured
//! against HSI first (`crystal_measure`, `jdbb_core::clock`): only a reading that is another
//! supported crystal rejects it (the log names the build to use), a reading that is no supported
//! crystal is treated like none. No crystal, or another supported one: the firmware runs on HSI
//! (±4 % over temperature: USB, which needs ±0.25 %, does not run on it), `DeviceInfo.clock` says `Internal` and the LED flashes twice every 2 s; a PLL that does not lock: nothing runs, the LED
//! flashes three times. The independent watchdog (started first, fed from the idle loop) resets a
//! firmware that hangs, after 5.6–15.4 s; `DeviceInfo.reset_cause` then says `WATCHDOG`.

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};

use super::Parts;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use jdbb_core::clock::{crystal_hz, crystal_verdict, crystal_verdict_too_fast, CrystalVerdict};
use jdbb_core::indicator::{ClockFault, Indicator, LedCode};
use jdbb_core::protocol::{Board, CalKept, ClockSource, ResetCause, SampleBatch};
use jdbb_core::quadrature::IndexCapture;
use jdbb_core::reset;
use jdbb_core::sampler::Sampler;
use jdbb_core::store::{CalStore, ClearedFlags, StickyErrors};
use jdbb_core::Calibration;
use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
use stm32f4xx_hal::otg_fs::{UsbBus, UsbBusType, USB};
use stm32f4xx_hal::qei::{Qei, QeiExt};
use stm32f4xx_hal::{pac, prelude::*};
use usb_device::bus::UsbBusAllocator;
use usb_device::class::UsbClass;
use usb_device::prelude::*;
use usbd_serial::SerialPort;

use crate::sample_timer::tick_count;
pub use crate::sample_timer::SampleTimer;

/// Reported in `DeviceInfo`.
pub const BOARD: Board = Board::BlackPillF411;
/// Counts come from hardware.
pub const SIMULATED: bool = false;
/// The real board also streams from power-up (the host may `Stop`/`Start`); samples are dropped,
/// and counted, while no host reads the port.
pub const AUTO_START: bool = true;
/// USB: nobody listens before the host has configured the device.
pub const LINK_UP_AT_START: bool = false;

/// USB vendor and product ID: pid.codes' test PID (1209:0001). It is for development and
/// in-house testing only, not for instruments that are distributed: request a PID for the project
/// from pid.codes (free for open-source hardware) and put it here. See README, "Real board".
pub const USB_VID_PID: (u16, u16) = (0x1209, 0x0001);

const CCMR1_IC1F_IC2F_N8: u32 = (0b0011 << 4) | (0b0011 << 12);
/// CC3: input on TI3 (the index pin), filter N = 8; CC4: input on TRC (the internal trigger).
const CCMR2_CC3_TI3_N8_CC4_TRC: u32 = 0b01 | (0b0011 << 4) | (0b11 << 8);
/// CC3 enabled on both edges (CC3P = CC3NP = 1); CC4 enabled (rising edge of the trigger).
const CCER_CC3_BOTH_CC4: u32 = (1 << 8) | (1 << 9) | (1 << 11) | (1 << 12);
const SMCR_SMS_ENCODER3: u32 = 0b011;
/// `SMCR.TS`: ITR2 (TIM2's input from TIM3's TRGO).
const SMCR_TS_ITR2: u32 = 0b010 << 4;
/// `SMCR.TS`: ITR1 (TIM5's input from TIM3's TRGO).
const SMCR_TS_ITR1: u32 = 0b001 << 4;
const CR1_CEN: u32 = 1;
const DIER_CC3IE: u32 = 1 << 3;
const SR_CC3IF: u32 = 1 << 3;
const SR_CC3OF: u32 = 1 << 11;
/// Chip unique ID (RM0383 §24.2).
const UID_ADDR: usize = 0x1fff_7a10;

/// Mark the panic and hard-fault handlers leave for the next start (see [`jdbb_core::reset`]);
/// in `.uninit`, so the start-up code does not clear it.
#[link_section = ".uninit.jdbb_crash_mark"]
static mut CRASH_MARK: MaybeUninit<u32> = MaybeUninit::uninit();

/// Why the chip started: `RCC_CSR`'s reset flags and the crash mark, both cleared for next time;
/// and the interrupt without a handler that caused it, if one did.
fn take_reset_cause(rcc: &pac::RCC) -> (ResetCause, Option<i16>) {
    let csr = rcc.csr().read().bits();
    rcc.csr().modify(|_, w| w.rmvf().set_bit());
    // SAFETY: single-threaded start-up; the word is plain RAM (random after power-on, which
    // `reset::from_stm32f4` does not trust).
    let mark = unsafe {
        let p = core::ptr::addr_of_mut!(CRASH_MARK) as *mut u32;
        let mark = core::ptr::read_volatile(p);
        core::ptr::write_volatile(p, reset::MARK_NONE);
        mark
    };
    (
        reset::from_stm32f4(csr, mark),
        reset::unhandled_irq(csr, mark),
    )
}

/// Leave `mark` for the next start and reset the chip.
fn crash_reset(mark: u32) -> ! {
    // SAFETY: interrupts are off; nothing else writes the mark.
    unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(CRASH_MARK) as *mut u32, mark) };
    cortex_m::peripheral::SCB::sys_reset()
}

/// A field instrument must not hang: log the panic (non-blocking RTT; nothing waits for a probe),
/// leave the mark and reset. The next `DeviceInfo` reports `ResetCause::PANIC`.
///
/// A panic during start-up (before [`init_done`]) would do the same again after every reset, with
/// the LED dark: there the firmware stops and flickers the LED instead (5 Hz, see
/// `jdbb_core::clock::panic_blink`), feeding the watchdog, until the board is power-cycled.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    if !PANICKED.swap(true, Ordering::Relaxed) {
        defmt::error!("panic: {}", defmt::Display2Format(info));
    }
    if !INIT_DONE.load(Ordering::Relaxed) {
        defmt::error!("the panic was during start-up: LED flickers, power-cycle after fixing");
        init_panic_blink();
    }
    // No `defmt::flush`: it waits for the probe whenever probe-rs left the channel in blocking
    // mode, even after the probe is gone.
    crash_reset(reset::MARK_PANIC)
}

/// A hard fault (escalated bus, memory or usage fault) resets too, and is reported as
/// `ResetCause::FAULT`.
#[cortex_m_rt::exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    crash_reset(reset::MARK_FAULT)
}

/// An interrupt or exception that has no handler (a peripheral left enabled, a wrong vector):
/// reset at once rather than spin until the watchdog bites, and leave its number for the next
/// start (`ResetCause::FAULT` with `DeviceInfo.unhandled_irq`).
#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    cortex_m::interrupt::disable();
    crash_reset(reset::mark_unhandled_irq(irqn))
}

/// Set once start-up is over ([`init_done`]): a panic then resets the chip.
static INIT_DONE: AtomicBool = AtomicBool::new(false);

/// Start-up is over: from now a panic resets the chip (`ResetCause::PANIC`).
pub fn init_done() {
    INIT_DONE.store(true, Ordering::Relaxed);
}

/// The LED code of a panic during start-up, forever (interrupts are off). The LED's GPIO is set
/// up again (the panic may have come before `led_init`); the clock may be HSI (16 MHz) or the PLL
/// (96 MHz): counting at 16 MHz, the flicker is 5 Hz on HSI and 30 Hz at most otherwise, both
/// unlike any other code (steady 2 s patterns).
fn init_panic_blink() -> ! {
    // SAFETY: RCC's AHB1ENR GPIOC bit; interrupts are off and nothing else runs.
    led_init(unsafe { &*pac::RCC::ptr() });
    play_forever(LedCode::InitPanic)
}

/// Play `code` on the LED forever, the watchdog fed every millisecond (no reset loop), timed by
/// [`SpinDelay`] at the 16 MHz HSI (≥ 1 ms per step).
fn play_forever(code: LedCode) -> ! {
    let mut delay = SpinDelay { cpu_hz: HSI_HZ };
    let (mut led, mut t_ms) = (led(), 0);
    loop {
        t_ms = led.play(&mut delay, code, t_ms, 1000, feed_watchdog);
    }
}

/// A delay that spins the CPU (`cortex_m::asm::delay`) for a clock of `cpu_hz`: at least the time
/// asked for at that clock or a slower one. For the LED loops that run with interrupts off.
struct SpinDelay {
    cpu_hz: u32,
}

impl embedded_hal::delay::DelayNs for SpinDelay {
    fn delay_ns(&mut self, ns: u32) {
        let cycles = u64::from(ns) * u64::from(self.cpu_hz) / 1_000_000_000;
        cortex_m::asm::delay(u32::try_from(cycles).unwrap_or(u32::MAX).max(1));
    }
}

/// The chip's unique ID, as it lies in memory.
fn chip_id() -> [u8; 12] {
    let mut id = [0u8; 12];
    for (i, word) in id.chunks_exact_mut(4).enumerate() {
        // SAFETY: the 96-bit unique ID is read-only system memory present on every F411.
        let w = unsafe { core::ptr::read_volatile((UID_ADDR + 4 * i) as *const u32) };
        word.copy_from_slice(&w.to_le_bytes());
    }
    id
}

/// The USB serial number: the unique ID's 12 bytes as 24 upper-case hex digits.
fn serial_number(id: &[u8; 12]) -> &'static str {
    const HEX: &[u8; 16] = b"0123456789ABCDEF";
    let buf = cortex_m::singleton!(: [u8; 24] = [0; 24]).unwrap();
    for (i, b) in id.iter().enumerate() {
        buf[2 * i] = HEX[(b >> 4) as usize];
        buf[2 * i + 1] = HEX[(b & 0xf) as usize];
    }
    core::str::from_utf8(buf).unwrap_or("0")
}

/// Bring up the board: watchdog, regulator and clocks (every wait bounded), both encoder timers
/// with index and sample latches, the sample clock at `rate_hz`, the calibration store (its spare
/// block erased ahead), USB.
pub fn init(dp: pac::Peripherals, rate_hz: u32) -> Parts {
    let (reset_cause, unhandled_irq) = take_reset_cause(&dp.RCC);
    // First, so that every wait after it is bounded by it too.
    watchdog_start(&dp.IWDG, &dp.DBGMCU);
    led_init(&dp.RCC);
    // Started from the ROM DFU bootloader (`dfu-util ... :leave`) the PLL may still run, and then
    // VOS and PLLCFGR cannot be written (RM0383 §5.1.3, §6.3.2): back to the reset state first.
    if !clocks_to_reset_state(&dp.RCC) {
        defmt::error!(
            "clock start failed: HSI or the clock switch did not answer (LED: 4 flashes)"
        );
        clock_failure(ClockFault::HsiNoAnswer);
    }
    // Voltage scale 1 before the PLL starts (RM0383 §5.1.3): the reset value, scale 2, allows
    // HCLK ≤ 84 MHz only. VOS can be written only while the PLL is off and takes effect when it
    // locks.
    dp.RCC.apb1enr().modify(|_, w| w.pwren().set_bit());
    cortex_m::asm::dsb();
    dp.PWR.cr().modify(|_, w| w.vos().scale1());
    let mut crystal = hse_start(&dp.RCC);
    if crystal {
        // Only a crystal of the build's frequency may drive the PLL (see `jdbb_core::clock`).
        let verdict = match crystal_measure(&dp.RCC) {
            Reading::Hz(hz) => {
                let v = crystal_verdict(hz, HSE_HZ);
                if v == CrystalVerdict::Build {
                    defmt::info!("crystal measured at {=u32} Hz against HSI", hz);
                } else if v == CrystalVerdict::Nonsense {
                    defmt::warn!(
                        "crystal measured at {=u32} Hz: no supported crystal, the reading is not \
                         trusted; used as built ({=u32} Hz)",
                        hz,
                        HSE_HZ
                    );
                }
                v
            }
            Reading::TooFast => crystal_verdict_too_fast(HSE_HZ),
            Reading::NoEdges => {
                defmt::warn!("the crystal could not be measured: used as built");
                CrystalVerdict::Build
            }
        };
        if let CrystalVerdict::Other(hz, how) = verdict {
            // Only a reading that is another supported crystal rejects it (`jdbb_core::clock`).
            defmt::error!(
                "the crystal is a {=u32} Hz one, the build is for {=u32} Hz: not used; build \
                 with {=str}",
                hz,
                HSE_HZ,
                how
            );
        }
        crystal = verdict.uses_crystal();
        if !crystal {
            hse_stop(&dp.RCC);
        }
    }
    let pll_src_hz = if crystal { HSE_HZ } else { HSI_HZ };
    if !pll_locks(&dp.RCC, crystal, pll_src_hz) {
        defmt::error!("clock start failed: the PLL did not lock (LED: 3 flashes)");
        clock_failure(ClockFault::PllNoLock);
    }
    if !crystal {
        ON_HSI.store(true, Ordering::Relaxed);
    }
    // The HAL's own waits for HSERDY and PLLRDY are unbounded; they return at once now: the
    // crystal is running (or not asked for) and the PLL just locked from the same source.
    let rcc = dp.RCC.constrain();
    let cfgr = if crystal {
        rcc.cfgr.use_hse(HSE_HZ.Hz())
    } else {
        rcc.cfgr
    };
    let clocks = cfgr.sysclk(96.MHz()).require_pll48clk().freeze();
    if dp.PWR.csr().read().vosrdy().bit_is_clear() {
        defmt::warn!("regulator not ready in voltage scale 1");
    }
    if crystal {
        defmt::info!("clocks from the {=u32} Hz crystal", HSE_HZ);
    } else {
        defmt::error!(
            "not running from the {=u32} Hz crystal: on the internal oscillator (HSI: ±1 % at \
             25 °C, ±4 % over -10..85 °C; time stamps off by up to 4 %; USB needs ±0.25 % and \
             will not run on it; LED flashes twice)",
            HSE_HZ
        );
    }
    // The bootloader may have left the USB core running: reset it before the driver takes it.
    // SAFETY: a reset pulse on the OTG FS peripheral, before anything uses it.
    unsafe {
        let rcc = &*pac::RCC::ptr();
        rcc.ahb2rstr()
            .modify(|r, w| w.bits(r.bits() | AHB2RSTR_OTGFSRST));
        rcc.ahb2rstr()
            .modify(|r, w| w.bits(r.bits() & !AHB2RSTR_OTGFSRST));
    }
    let gpioa = dp.GPIOA.split();
    let gpiob = dp.GPIOB.split();

    // Encoders: the HAL sets encoder mode 3 (×4) with ARR = u32::MAX and starts them; we stop
    // them to add filters, the index capture (CH3) and the sample latch (CH4 on TRC).
    let enc1 = dp.TIM2.qei((
        gpioa.pa15.into_alternate::<1>().internal_pull_up(true),
        gpiob.pb3.into_alternate::<1>().internal_pull_up(true),
    ));
    let enc2 = dp.TIM5.qei((
        gpioa.pa0.internal_pull_up(true),
        gpioa.pa1.internal_pull_up(true),
    ));
    let _z1 = gpiob.pb10.internal_pull_up(true).into_alternate::<1>();
    let _z2 = gpioa.pa2.internal_pull_up(true).into_alternate::<2>();
    for (ch, ts) in [(0, SMCR_TS_ITR2), (1, SMCR_TS_ITR1)] {
        let t = encoder_timer(ch);
        // SAFETY: the encoder timers are owned by `Encoders`; configured once, here.
        unsafe {
            t.cr1().modify(|r, w| w.bits(r.bits() & !CR1_CEN));
            t.ccmr1_input()
                .modify(|r, w| w.bits(r.bits() | CCMR1_IC1F_IC2F_N8));
            t.ccmr2_input().write(|w| w.bits(CCMR2_CC3_TI3_N8_CC4_TRC));
            t.ccer().modify(|r, w| w.bits(r.bits() | CCER_CC3_BOTH_CC4));
            // The trigger selection only routes TIM3's TRGO to TRC; encoder mode ignores it.
            t.smcr().write(|w| w.bits(SMCR_SMS_ENCODER3 | ts));
            t.sr().write(|w| w.bits(0));
            t.dier().write(|w| w.bits(DIER_CC3IE));
            t.cr1().modify(|r, w| w.bits(r.bits() | CR1_CEN));
        }
    }
    let encoders = Encoders {
        _enc1: enc1,
        _enc2: enc2,
    };
    let initial_raw = [
        encoder_timer(0).cnt().read().bits(),
        encoder_timer(1).cnt().read().bits(),
    ];

    // The calibration store, its spare block erased now if it must be (up to 4 s, before USB
    // enumerates and with nothing sampling), so that no store while sampling has to erase.
    let mut cal_memory = CalMemory::open(dp.FLASH);
    cal_memory.erase_ahead();

    // USB FS CDC-ACM.
    let chip_id = chip_id();
    let usb = USB::new(
        (dp.OTG_FS_GLOBAL, dp.OTG_FS_DEVICE, dp.OTG_FS_PWRCLK),
        (gpioa.pa11, gpioa.pa12),
        &clocks,
    );
    let ep_memory = cortex_m::singleton!(: [u32; 1024] = [0; 1024]).unwrap();
    let bus: &'static UsbBusAllocator<UsbBusType> =
        cortex_m::singleton!(: UsbBusAllocator<UsbBusType> = UsbBus::new(usb, ep_memory)).unwrap();
    // A 1 KiB transmit buffer holds more than a full frame (`MAX_FRAME_LEN`), so the writer
    // hands over whole frames and the USB interrupt streams them out packet by packet.
    let serial = SerialPort::new_with_store(bus, [0u8; RX_BUF], [0u8; TX_BUF]);
    let dev = UsbDeviceBuilder::new(bus, UsbVidPid(USB_VID_PID.0, USB_VID_PID.1))
        .strings(&[StringDescriptors::default()
            .manufacturer("jdbb open double ball bar")
            .product("J-DBB double ball bar")
            .serial_number(serial_number(&chip_id))])
        .unwrap()
        .device_class(usbd_serial::USB_CLASS_CDC)
        .build();

    Parts {
        encoders,
        link: Link {
            dev,
            serial,
            configured: false,
        },
        timer: SampleTimer::new(dp.TIM3, dp.TIM4, dp.TIM1, clocks.timclk1().raw(), rate_hz),
        systick_hz: clocks.sysclk().raw(),
        initial_raw,
        index_raw: None,
        chip_id,
        reset_cause,
        unhandled_irq,
        cal_memory,
        clock: if crystal {
            ClockSource::Crystal
        } else {
            ClockSource::Internal
        },
    }
}

/// Crystal (HSE) frequency (Hz): 25 MHz (the WeAct Black Pill), or the cargo feature `hse-8mhz`,
/// `hse-12mhz`, `hse-16mhz` or `hse-24mhz`.
pub const HSE_HZ: u32 = if cfg!(feature = "hse-8mhz") {
    8_000_000
} else if cfg!(feature = "hse-12mhz") {
    12_000_000
} else if cfg!(feature = "hse-16mhz") {
    16_000_000
} else if cfg!(feature = "hse-24mhz") {
    24_000_000
} else {
    25_000_000
};
const HSI_HZ: u32 = 16_000_000;

// RCC_CR bits (RM0383 §6.3.1).
const CR_HSION: u32 = 1 << 0;
const CR_HSIRDY: u32 = 1 << 1;
const CR_HSEON: u32 = 1 << 16;
const CR_HSERDY: u32 = 1 << 17;
const CR_HSEBYP: u32 = 1 << 18;
const CR_PLLON: u32 = 1 << 24;
const CR_PLLRDY: u32 = 1 << 25;
const CR_PLLI2SON: u32 = 1 << 26;
const CR_PLLI2SRDY: u32 = 1 << 27;
/// RCC_CFGR.SWS (bits 3:2), 00 = HSI.
const CFGR_SWS: u32 = 0b11 << 2;
/// RCC_PLLCFGR's reserved bits, kept as they are.
const PLLCFGR_RESERVED: u32 = 0xf0bc_8000;
const AHB2RSTR_OTGFSRST: u32 = 1 << 7;

/// Bounds of the clock start-up waits, in polls of a register (each ≥ 4 cycles of the 16 MHz HSI,
/// so ≥ 250 ns): HSI and the clock switch 25 ms (they take a few µs); the crystal 100 ms (DS10314:
/// start-up 2 ms typical); the PLL 25 ms (lock time 100 µs typical, 200 µs max).
const WAIT_HSI: u32 = 100_000;
const WAIT_HSE: u32 = 400_000;
const WAIT_PLL: u32 = 100_000;

/// Poll `done` up to `polls` times; whether it came true.
fn wait(polls: u32, done: impl Fn() -> bool) -> bool {
    for _ in 0..polls {
        if done() {
            return true;
        }
    }
    done()
}

/// The clocks as after a reset, whoever ran before (the ROM bootloader): HSI on and selected as
/// SYSCLK, prescalers at 1, the PLLs and the crystal off. Whether every step finished in time.
fn clocks_to_reset_state(rcc: &pac::RCC) -> bool {
    let cr = || rcc.cr().read().bits();
    // SAFETY (all register writes below): bit patterns from RM0383 §6.3; nothing else uses the
    // clocks yet.
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() | CR_HSION) });
    let mut ok = wait(WAIT_HSI, || cr() & CR_HSIRDY != 0);
    // SW = HSI, AHB/APB prescalers 1, MCOs off.
    rcc.cfgr().write(|w| unsafe { w.bits(0) });
    ok &= wait(WAIT_HSI, || rcc.cfgr().read().bits() & CFGR_SWS == 0);
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !(CR_PLLON | CR_PLLI2SON)) });
    ok &= wait(WAIT_PLL, || cr() & (CR_PLLRDY | CR_PLLI2SRDY) == 0);
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !CR_HSEON) });
    ok &= wait(WAIT_HSE, || cr() & CR_HSERDY == 0);
    // HSEBYP is writable only with the crystal off.
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !CR_HSEBYP) });
    ok
}

/// Start the crystal; whether it was ready within [`WAIT_HSE`] (if not, it is switched off again).
fn hse_start(rcc: &pac::RCC) -> bool {
    // SAFETY: HSEON, RM0383 §6.3.1.
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() | CR_HSEON) });
    if wait(WAIT_HSE, || rcc.cr().read().bits() & CR_HSERDY != 0) {
        return true;
    }
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !CR_HSEON) });
    false
}

/// Switch the crystal off (it is not the build's).
fn hse_stop(rcc: &pac::RCC) {
    // SAFETY: HSEON, RM0383 §6.3.1; nothing runs from HSE.
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !CR_HSEON) });
    wait(WAIT_HSE, || rcc.cr().read().bits() & CR_HSERDY == 0);
}

/// The crystal measured against HSI.
enum Reading {
    /// Its frequency (Hz).
    Hz(u32),
    /// Its divided edges came faster than they could be read: far above the build's frequency.
    TooFast,
    /// No edge within the bound: not measured.
    NoEdges,
}

/// Edges of `HSE_RTC` per TIM11 capture (input prescaler /8), and captures measured.
const EDGES_PER_CAPTURE: u32 = 8;
const CAPTURES: u32 = 64;

/// Measure the running crystal against HSI (SYSCLK = HSI, prescalers 1: TIM11 counts at 16 MHz):
/// TIM11 CH1 captures every 8th edge of `HSE_RTC` (the crystal divided by RTCPRE, set for 1 MHz
/// from the build's crystal: RM0383 TIM11_OR `TI1_RMP = 10`, "for measurement purposes") 64
/// times, 512 µs with the right crystal. TIM11 and RTCPRE are left as at reset.
fn crystal_measure(rcc: &pac::RCC) -> Reading {
    const RTCPRE: u32 = 0x1f << 16;
    const APB2ENR_TIM11EN: u32 = 1 << 18;
    const SR_CC1IF: u32 = 1 << 1;
    const SR_CC1OF: u32 = 1 << 9;
    let divider = HSE_HZ / 1_000_000;
    // SAFETY (all writes below): RCC_CFGR.RTCPRE and TIM11's registers, RM0383 §6.3.3 and §14.5;
    // TIM11 is used for nothing else.
    rcc.cfgr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !RTCPRE | (divider << 16)) });
    rcc.apb2enr()
        .modify(|r, w| unsafe { w.bits(r.bits() | APB2ENR_TIM11EN) });
    cortex_m::asm::dsb();
    let t = unsafe { &*pac::TIM11::ptr() };
    unsafe {
        t.or().write(|w| w.bits(0b10)); // TI1 = HSE_RTC
        t.psc().write(|w| w.bits(0));
        t.arr().write(|w| w.bits(0xffff));
        t.ccmr1_input().write(|w| w.bits(0b01 | (0b11 << 2))); // IC1 on TI1, every 8th edge
        t.ccer().write(|w| w.bits(1)); // CC1E, rising edges
        t.sr().write(|w| w.bits(0));
        t.cr1().write(|w| w.bits(1));
    }
    let capture = || -> Option<u16> {
        wait(WAIT_PLL, || t.sr().read().bits() & SR_CC1IF != 0)
            .then(|| t.ccr1().read().bits() as u16) // reading CCR1 clears CC1IF
    };
    let mut reading = Reading::NoEdges;
    if let Some(mut prev) = capture() {
        let mut cycles: u32 = 0;
        let mut complete = true;
        for _ in 0..CAPTURES {
            let Some(c) = capture() else {
                complete = false;
                break;
            };
            cycles += u32::from(c.wrapping_sub(prev));
            prev = c;
        }
        reading = if t.sr().read().bits() & SR_CC1OF != 0 {
            Reading::TooFast
        } else if !complete {
            Reading::NoEdges
        } else {
            crystal_hz(cycles, CAPTURES * EDGES_PER_CAPTURE, divider, HSI_HZ)
                .map_or(Reading::TooFast, Reading::Hz)
        };
    }
    unsafe {
        t.cr1().write(|w| w.bits(0));
        t.ccer().write(|w| w.bits(0));
        t.or().write(|w| w.bits(0));
    }
    rcc.apb2enr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !APB2ENR_TIM11EN) });
    rcc.cfgr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !RTCPRE) });
    reading
}

/// Lock the PLL once from the crystal (`hse`) or HSI at `src_hz` (a whole number of MHz) with the
/// firmware's VCO (1 MHz in, 192 MHz, /2 = 96 MHz, /4 = 48 MHz), then switch it off again for the
/// HAL to program (PLLCFGR may be written only while it is off). Whether it locked, and stopped,
/// within [`WAIT_PLL`].
fn pll_locks(rcc: &pac::RCC, hse: bool, src_hz: u32) -> bool {
    let m = src_hz / 1_000_000;
    let fields = m | (192 << 6) | (u32::from(hse) << 22) | (4 << 24); // PLLP = 00: /2
                                                                      // SAFETY: RM0383 §6.3.2, with the PLL off (`clocks_to_reset_state`).
    rcc.pllcfgr()
        .modify(|r, w| unsafe { w.bits(r.bits() & PLLCFGR_RESERVED | fields) });
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() | CR_PLLON) });
    let locked = wait(WAIT_PLL, || rcc.cr().read().bits() & CR_PLLRDY != 0);
    rcc.cr()
        .modify(|r, w| unsafe { w.bits(r.bits() & !CR_PLLON) });
    let stopped = wait(WAIT_PLL, || rcc.cr().read().bits() & CR_PLLRDY == 0);
    locked && stopped
}

/// The clocks cannot run USB (the caller logged why): the LED shows the fault's code (its flashes
/// every 2 s), forever (the watchdog fed: no reset loop). Nothing else runs; power-cycle after
/// fixing the board.
fn clock_failure(fault: ClockFault) -> ! {
    play_forever(LedCode::Clock(fault))
}

/// Whether the clocks run on HSI (no crystal, or not the build's): the LED's code while running
/// is then [`ClockFault::NoCrystal`] (2 flashes), else [`LedCode::Running`] (1 flash).
static ON_HSI: AtomicBool = AtomicBool::new(false);

/// The status LED: PC13, lit when low (a zero-sized handle: every copy writes PC13's BSRR).
const fn led() -> Indicator<Led> {
    Indicator::new(Led, true)
}

/// The Black Pill's LED: PC13, lit when low.
fn led_init(rcc: &pac::rcc::RegisterBlock) {
    rcc.ahb1enr().modify(|_, w| w.gpiocen().set_bit());
    cortex_m::asm::dsb();
    led().set(false);
    // SAFETY: PC13 as a push-pull output (MODER13 = 01); PC13 is used for nothing else.
    unsafe {
        let c = &*pac::GPIOC::ptr();
        c.moder()
            .modify(|r, w| w.bits(r.bits() & !(0b11 << 26) | (0b01 << 26)));
    }
}

/// The Black Pill's LED pin, PC13, as an embedded-hal `OutputPin` (high = dark). Written through
/// BSRR directly rather than the HAL's `PC13<Output>`: the start-up panic's code must drive it
/// from the panic handler, whatever happened to the HAL's pin before (BSRR writes are atomic, so
/// the copies cannot disturb each other).
#[derive(Clone, Copy)]
pub struct Led;

impl embedded_hal::digital::ErrorType for Led {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::OutputPin for Led {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        // SAFETY: BSRR resets PC13 only.
        unsafe {
            (*pac::GPIOC::ptr())
                .bsrr()
                .write(|w| w.bits(1 << (13 + 16)))
        };
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Self::Error> {
        // SAFETY: BSRR sets PC13 only.
        unsafe { (*pac::GPIOC::ptr()).bsrr().write(|w| w.bits(1 << 13)) };
        Ok(())
    }
}

/// The status LED at `t_ms` (called from the idle loop): see [`ON_HSI`].
pub fn indicate(t_ms: u32) {
    led().show(LedCode::running(!ON_HSI.load(Ordering::Relaxed)), t_ms);
}

/// IWDG prescaler /64 (`PR = 4`) and reload 4095: the watchdog resets the chip after
/// 4096 · 64 / f_LSI = 5.6 s at the fastest LSI (47 kHz), 8.2 s typical (32 kHz), 15.4 s at the
/// slowest (17 kHz; DS10314's LSI range): longer than the longest stall of the firmware, a 128 KiB
/// sector erase (4 s max, DS10314 at x8 parallelism, as the HAL erases).
const IWDG_PR_DIV64: u32 = 4;
const IWDG_RELOAD: u32 = 4095;

/// Start the independent watchdog (it cannot be stopped again until reset); it stops while a
/// debugger halts the core. Fed from the idle loop ([`feed_watchdog`]).
fn watchdog_start(iwdg: &pac::IWDG, dbg: &pac::DBGMCU) {
    // SAFETY: key and register values from RM0383 §16.4; DBG_IWDG_STOP is bit 12 of
    // DBGMCU_APB1_FZ.
    unsafe {
        dbg.apb1_fz().modify(|r, w| w.bits(r.bits() | (1 << 12)));
        iwdg.kr().write(|w| w.bits(0xcccc));
        iwdg.kr().write(|w| w.bits(0x5555));
        iwdg.pr().write(|w| w.bits(IWDG_PR_DIV64));
        iwdg.rlr().write(|w| w.bits(IWDG_RELOAD));
    }
    // PVU/RVU: the values reach the LSI domain within a few LSI periods (≤ 5 at /64: ~2 ms).
    wait(WAIT_PLL, || iwdg.sr().read().bits() == 0);
    feed_watchdog();
}

/// Reload the independent watchdog.
#[inline]
pub fn feed_watchdog() {
    // SAFETY: the reload key, RM0383 §16.4.
    unsafe { (*pac::IWDG::ptr()).kr().write(|w| w.bits(0xaaaa)) };
}

/// Offset (from the start of flash) of the calibration store: sector 6.
const CAL_BASE: u32 = 0x4_0000;
/// One block of the store: a 128 KiB sector (sectors 6 and 7).
const CAL_BLOCK: u32 = 0x2_0000;

/// `FLASH_SR`'s error flags (RM0383 §3.8.4: OPERR, WRPERR, PGAERR, PGPERR, PGSERR), cleared by
/// writing 1.
const FLASH_SR_ERRORS: u32 = (1 << 1) | (1 << 4) | (1 << 5) | (1 << 6) | (1 << 7);
/// `FLASH_CR.LOCK`.
const FLASH_CR_LOCK: u32 = 1 << 31;

/// The flash, unlocked only for the length of each erase or write; the store uses it through
/// `ClearedFlags`, which clears leftover error flags before each.
pub struct BoardFlash(LockedFlash);

impl StickyErrors for BoardFlash {
    /// Before every erase or program (`jdbb_core::store::ClearedFlags`): the flash as the HAL
    /// expects it. The error flags stay set
    /// until cleared, and the HAL neither clears them nor tells a leftover flag from a new one:
    /// one left set (by the ROM bootloader before a DFU `:leave`, which is not a reset, or by an
    /// earlier failure) would fail every later store. And the HAL writes the unlock keys without
    /// checking the lock: on a flash left unlocked that is a wrong key sequence (bus error, and
    /// the HAL's assertion panics), so an unlocked flash is locked first.
    fn clear_errors(&mut self) {
        // SAFETY: FLASH_CR's LOCK bit and FLASH_SR's write-1-to-clear error flags only; the
        // flash is used by this driver alone, with no operation in progress between calls.
        unsafe {
            let f = &*pac::FLASH::ptr();
            if f.cr().read().bits() & FLASH_CR_LOCK == 0 {
                f.cr().modify(|r, w| w.bits(r.bits() | FLASH_CR_LOCK));
            }
            f.sr().write(|w| w.bits(FLASH_SR_ERRORS));
        }
    }
}

impl ErrorType for BoardFlash {
    type Error = stm32f4xx_hal::flash::Error;
}

impl ReadNorFlash for BoardFlash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        ReadNorFlash::read(&mut self.0, offset, bytes)
    }

    fn capacity(&self) -> usize {
        ReadNorFlash::capacity(&self.0)
    }
}

impl NorFlash for BoardFlash {
    const WRITE_SIZE: usize = 1;
    const ERASE_SIZE: usize = 128 * 1024;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        NorFlash::erase(&mut self.0.unlocked(), from, to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        NorFlash::write(&mut self.0.unlocked(), offset, bytes)
    }
}

/// The calibration kept across power cycles, in flash (see the module docs); None where the
/// flash has no room for the store.
pub struct CalMemory(Option<CalStore<ClearedFlags<BoardFlash>>>);

impl CalMemory {
    fn open(flash: pac::FLASH) -> Self {
        let store = CalStore::open(
            ClearedFlags(BoardFlash(LockedFlash::new(flash))),
            CAL_BASE,
            CAL_BLOCK,
        );
        if store.is_err() {
            defmt::warn!(
                "no room in flash for the calibration: it is not kept across power cycles"
            );
        }
        CalMemory(store.ok())
    }

    /// The calibration stored last, if any.
    pub fn load(&self) -> Option<Calibration> {
        self.0.as_ref().and_then(CalStore::load)
    }

    /// Keep `cal` in flash and read it back; what became of it (the reply reports it). Writes
    /// one record (~2 ms); erases a sector first (2–4 s, the whole CPU stalled) only if the spare
    /// was not erased ahead.
    pub fn store(&mut self, cal: &Calibration) -> CalKept {
        let Some(s) = self.0.as_mut() else {
            return CalKept::NoRoom;
        };
        if s.store_would_erase().unwrap_or(false) {
            defmt::warn!("this store erases a flash sector: the CPU stalls for 2-4 s");
        }
        feed_watchdog();
        let r = s.store(cal);
        if let Err(
            jdbb_core::store::StoreError::Flash(e) | jdbb_core::store::StoreError::Erase(e),
        ) = r
        {
            defmt::warn!("calibration store: flash error {}", defmt::Debug2Format(&e));
        }
        jdbb_core::store::kept(&r)
    }

    /// Erase the store's spare sector if it is not erased yet (2–4 s, the whole CPU stalled:
    /// call it only while not sampling); whether it erased.
    pub fn erase_ahead(&mut self) -> bool {
        let Some(s) = self.0.as_mut() else {
            return false;
        };
        feed_watchdog();
        match s.erase_spare() {
            Ok(erased) => {
                if erased {
                    defmt::info!("calibration store: spare sector erased ahead");
                }
                erased
            }
            Err(_) => {
                defmt::warn!("calibration store: erasing the spare sector failed");
                false
            }
        }
    }
}

/// Encoder timer `ch` (0: TIM2, 1: TIM5).
fn encoder_timer(ch: usize) -> &'static pac::tim2::RegisterBlock {
    // SAFETY: callers only touch the registers this module configured for them (CNT, CCR3/4,
    // SR/DIER at init and in `IndexTimer`); TIM5's register block has TIM2's layout.
    unsafe {
        match ch {
            0 => &*pac::TIM2::ptr(),
            _ => &*(pac::TIM5::ptr() as *const pac::tim2::RegisterBlock),
        }
    }
}

/// TIM2 (encoder 1) and TIM5 (encoder 2) in quadrature mode.
pub struct Encoders {
    _enc1: Qei<pac::TIM2>,
    _enc2: Qei<pac::TIM5>,
}

impl Encoders {
    /// The tick count and the two counters latched at that tick. Retried if a tick comes while
    /// reading, so the three values always belong together.
    #[inline]
    fn latched(&self) -> (u32, [u32; 2]) {
        let mut tick = tick_count();
        for _ in 0..3 {
            let raw = [
                encoder_timer(0).ccr4().read().bits(),
                encoder_timer(1).ccr4().read().bits(),
            ];
            let again = tick_count();
            if again == tick {
                return (tick, raw);
            }
            tick = again;
        }
        // Three ticks within a few reads cannot happen (a period is ≥ 50 µs); keep the types total.
        (
            tick,
            [
                encoder_timer(0).ccr4().read().bits(),
                encoder_timer(1).ccr4().read().bits(),
            ],
        )
    }

    /// First thing at a tick of the sample clock: the tick count and the counts latched at it.
    #[inline]
    pub fn latch(&mut self) -> Latch {
        let (tick, raw) = self.latched();
        Latch { tick, raw }
    }

    /// The latched tick's sample, to the sampler.
    #[inline]
    pub fn sample(&mut self, latch: Latch, s: &mut Sampler) -> Option<SampleBatch> {
        s.sample_at_tick(latch.tick, |_| latch.raw)
    }
}

/// What the hardware latched at a tick of the sample clock.
#[derive(Clone, Copy)]
pub struct Latch {
    tick: u32,
    raw: [u32; 2],
}

impl Latch {
    /// The tick count (see [`crate::sample_timer`]).
    #[inline]
    pub fn tick(&self) -> u32 {
        self.tick
    }
}

/// Encoder `ch`'s index capture (0: TIM2, 1: TIM5; CH3 latches the counter at both edges of the
/// index pin), for [`jdbb_core::quadrature::service_index`] from the timer's interrupt.
pub struct IndexTimer(pub usize);

impl IndexCapture for IndexTimer {
    #[inline]
    fn take(&mut self) -> Option<u32> {
        let tim = encoder_timer(self.0);
        if tim.sr().read().bits() & SR_CC3IF == 0 {
            return None;
        }
        Some(tim.ccr3().read().bits()) // clears CC3IF
    }

    #[inline]
    fn counter(&mut self) -> u32 {
        encoder_timer(self.0).cnt().read().bits()
    }

    #[inline]
    fn again(&mut self) -> bool {
        let tim = encoder_timer(self.0);
        // Clear an overcapture (written 0; the other flags are written 1, which leaves them).
        tim.sr().write(|w| unsafe { w.bits(!SR_CC3OF) });
        tim.sr().read().bits() & SR_CC3IF != 0
    }

    /// Switch the index interrupt off (until the next power-up): its line interrupts faster than
    /// an index can (`jdbb_core::quadrature::IndexRateLimit`); reported by [`index_disabled`].
    fn disable(&mut self) {
        let tim = encoder_timer(self.0);
        // SAFETY: clears CC3IE only (DIER holds nothing else this firmware sets on these timers),
        // then the pending flags, from the index task that owns them.
        tim.dier()
            .modify(|r, w| unsafe { w.bits(r.bits() & !DIER_CC3IE) });
        tim.sr()
            .write(|w| unsafe { w.bits(!(SR_CC3IF | SR_CC3OF)) });
        INDEX_OFF[self.0].store(true, Ordering::Relaxed);
    }
}

/// Index lines switched off for interrupting too fast.
static INDEX_OFF: [AtomicBool; 2] = [AtomicBool::new(false), AtomicBool::new(false)];

/// Which index lines were switched off ([`IndexTimer::disable`]); reported in `DeviceInfo`.
pub fn index_disabled() -> [bool; 2] {
    [
        INDEX_OFF[0].load(Ordering::Relaxed),
        INDEX_OFF[1].load(Ordering::Relaxed),
    ]
}

/// Encoder `ch`'s index pin (PB10, PA2) as an embedded-hal `InputPin`. Read from IDR directly:
/// the HAL's pin is in alternate-function mode (the timer's CH3), for which it implements no
/// `InputPin`, and the IDR shows the level in every mode.
pub struct ZPin(pub usize);

impl embedded_hal::digital::ErrorType for ZPin {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::InputPin for ZPin {
    #[inline]
    fn is_high(&mut self) -> Result<bool, Self::Error> {
        // SAFETY: read-only access to the input data registers.
        Ok(unsafe {
            match self.0 {
                0 => (*pac::GPIOB::ptr()).idr().read().bits() & (1 << 10) != 0,
                _ => (*pac::GPIOA::ptr()).idr().read().bits() & (1 << 2) != 0,
            }
        })
    }

    #[inline]
    fn is_low(&mut self) -> Result<bool, Self::Error> {
        self.is_high().map(|h| !h)
    }
}

const RX_BUF: usize = 128;
const TX_BUF: usize = 1024;

/// USB FS CDC-ACM as the host link.
pub struct Link {
    dev: UsbDevice<'static, UsbBusType>,
    serial: SerialPort<'static, UsbBusType, [u8; RX_BUF], [u8; TX_BUF]>,
    configured: bool,
}

impl Link {
    /// Service the USB stack (from the OTG_FS interrupt); true if the serial class may have data.
    #[inline]
    pub fn poll(&mut self) -> bool {
        self.dev.poll(&mut [&mut self.serial])
    }

    /// `Some(true)` once when the host has configured the device, `Some(false)` once when it is
    /// no longer configured (reset, unplugged); a suspend keeps the state. Nothing is written to
    /// the endpoints before the host configured the device.
    pub fn take_change(&mut self) -> Option<bool> {
        let now = match self.dev.state() {
            UsbDeviceState::Configured => true,
            UsbDeviceState::Suspend => self.configured,
            _ => false,
        };
        if now == self.configured {
            return None;
        }
        self.configured = now;
        if now {
            release_in_endpoints();
        }
        Some(now)
    }

    /// Received bytes into `buf`; how many.
    #[inline]
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        self.serial.read(buf).unwrap_or(0)
    }

    /// Queue bytes for sending without waiting; how many were taken (0 = would block: the host is
    /// not reading or has not configured the device; the caller counts and drops).
    #[inline]
    pub fn write(&mut self, bytes: &[u8]) -> usize {
        if !self.configured {
            return 0;
        }
        self.serial.write(bytes).unwrap_or(0)
    }

    /// Whether everything written has left the class's buffer for the endpoint.
    pub fn drained(&mut self) -> bool {
        self.configured && self.serial.flush().is_ok()
    }

    /// Throw away what the class still buffers for sending (stale data for an absent host).
    pub fn discard_pending(&mut self) {
        // The class's reset clears both buffers (the receive buffer is always empty here: the
        // USB task drains it) and the line state, which this firmware does not use.
        UsbClass::reset(&mut self.serial);
    }
}

/// At every (re)configuration: an IN endpoint whose transfer was cut by a bus reset can stay
/// enabled (the driver's reset sets EPDIS without the NAK sequence of RM0383 §22.17.6, "IN
/// endpoint disable"), and every later write would return WouldBlock. Nothing has been written
/// since the configuration, so an enabled endpoint is such a leftover: disable it the documented
/// way and flush its transmit FIFO. Bounded waits: a stuck core cannot hang the USB task.
fn release_in_endpoints() {
    const EPENA: u32 = 1 << 31;
    const EPDIS: u32 = 1 << 30;
    const SNAK: u32 = 1 << 27;
    const INT_EPDISD: u32 = 1 << 1;
    const INT_INEPNE: u32 = 1 << 6;
    const GRSTCTL_TXFFLSH: u32 = 1 << 5;
    const GRSTCTL_AHBIDL: u32 = 1 << 31;
    const SPIN: u32 = 10_000;
    let wait = |done: &dyn Fn() -> bool| {
        for _ in 0..SPIN {
            if done() {
                break;
            }
        }
    };
    // SAFETY: called from the USB task with the link locked, between two polls of the driver;
    // touches only IN endpoints 1..=3's control/interrupt registers and the FIFO flush.
    let (dev, global) = unsafe { (&*pac::OTG_FS_DEVICE::ptr(), &*pac::OTG_FS_GLOBAL::ptr()) };
    for i in 0..3 {
        let ep = dev.diep(i);
        if ep.ctl().read().bits() & EPENA != 0 {
            ep.ctl().modify(|r, w| unsafe { w.bits(r.bits() | SNAK) });
            wait(&|| ep.int().read().bits() & INT_INEPNE != 0);
            ep.ctl()
                .modify(|r, w| unsafe { w.bits(r.bits() | SNAK | EPDIS) });
            wait(&|| ep.int().read().bits() & INT_EPDISD != 0);
            ep.int()
                .write(|w| unsafe { w.bits(INT_EPDISD | INT_INEPNE) });
        }
        wait(&|| global.grstctl().read().bits() & GRSTCTL_AHBIDL != 0);
        let txfnum = (i as u32 + 1) << 6;
        global
            .grstctl()
            .write(|w| unsafe { w.bits(txfnum | GRSTCTL_TXFFLSH) });
        wait(&|| global.grstctl().read().bits() & GRSTCTL_TXFFLSH == 0);
    }
}
