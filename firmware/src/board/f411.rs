//! STM32F411CEU6 "Black Pill" (25 MHz crystal).
//!
//! | signal              | pin  | peripheral            |
//! |---------------------|------|-----------------------|
//! | encoder 1 A / B     | PA15 / PB3 | TIM2 CH1/CH2 (AF1), quadrature ×4 |
//! | encoder 1 index (Z) | PB10 | TIM2 CH3 input capture (AF1) |
//! | encoder 2 A / B     | PA0 / PA1  | TIM5 CH1/CH2 (AF2), quadrature ×4 |
//! | encoder 2 index (Z) | PA2  | TIM5 CH3 input capture (AF2) |
//! | USB FS D− / D+      | PA11 / PA12 | OTG_FS, CDC-ACM |
//!
//! All encoder inputs get the internal pull-ups (open-collector encoder outputs) and a digital
//! input filter of 8 timer clocks (83 ns at 96 MHz). The index pulse latches the count in CCR3 in
//! hardware, so referencing is exact however late the interrupt runs. Clocks: HSE 25 MHz → PLL →
//! SYSCLK 96 MHz (48 MHz for USB), APB1 48 MHz, timer clock 96 MHz.

use super::Parts;
use jdbb_core::protocol::Board;
use stm32f4xx_hal::otg_fs::{UsbBus, UsbBusType, USB};
use stm32f4xx_hal::qei::{Qei, QeiExt};
use stm32f4xx_hal::{pac, prelude::*};
use usb_device::bus::UsbBusAllocator;
use usb_device::prelude::*;
use usbd_serial::SerialPort;

pub use crate::sample_timer::SampleTimer;

/// Reported in `DeviceInfo`.
pub const BOARD: Board = Board::BlackPillF411;
/// Counts come from hardware.
pub const SIMULATED: bool = false;
/// The real board also streams from power-up (the host may `Stop`/`Start`); samples are dropped,
/// and counted, while no host reads the port.
pub const AUTO_START: bool = true;

const CCMR1_IC1F_IC2F_N8: u32 = (0b0011 << 4) | (0b0011 << 12);
const CCMR2_CC3S_TI3_IC3F_N8: u32 = 0b01 | (0b0011 << 4);
const CCER_CC3E: u32 = 1 << 8;
const DIER_CC3IE: u32 = 1 << 3;
const SR_CC3IF: u32 = 1 << 3;

/// Bring up the board: clocks, both encoder timers with index capture, USB, TIM3 at `rate_hz`.
pub fn init(dp: pac::Peripherals, rate_hz: u32) -> Parts {
    let rcc = dp.RCC.constrain();
    let clocks = rcc
        .cfgr
        .use_hse(25.MHz())
        .sysclk(96.MHz())
        .require_pll48clk()
        .freeze();
    let gpioa = dp.GPIOA.split();
    let gpiob = dp.GPIOB.split();

    // Encoders: the HAL sets encoder mode 3 (×4) with ARR = u32::MAX; we add pull-ups and filters.
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
    unsafe {
        let t2 = &*pac::TIM2::ptr();
        t2.ccmr1_input()
            .modify(|r, w| w.bits(r.bits() | CCMR1_IC1F_IC2F_N8));
        t2.ccmr2_input().write(|w| w.bits(CCMR2_CC3S_TI3_IC3F_N8));
        t2.ccer().modify(|r, w| w.bits(r.bits() | CCER_CC3E));
        t2.sr().write(|w| w.bits(0));
        t2.dier().write(|w| w.bits(DIER_CC3IE));
        let t5 = &*pac::TIM5::ptr();
        t5.ccmr1_input()
            .modify(|r, w| w.bits(r.bits() | CCMR1_IC1F_IC2F_N8));
        t5.ccmr2_input().write(|w| w.bits(CCMR2_CC3S_TI3_IC3F_N8));
        t5.ccer().modify(|r, w| w.bits(r.bits() | CCER_CC3E));
        t5.sr().write(|w| w.bits(0));
        t5.dier().write(|w| w.bits(DIER_CC3IE));
    }
    let encoders = Encoders {
        _enc1: enc1,
        _enc2: enc2,
    };
    let initial_raw = encoders.raw();

    // USB FS CDC-ACM.
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
    let dev = UsbDeviceBuilder::new(bus, UsbVidPid(0x16c0, 0x27dd))
        .strings(&[StringDescriptors::default()
            .manufacturer("jdbb")
            .product("J-DBB double ball bar")
            .serial_number("JDBB-F411")])
        .unwrap()
        .device_class(usbd_serial::USB_CLASS_CDC)
        .build();

    Parts {
        encoders,
        link: Link { dev, serial },
        timer: SampleTimer::new(dp.TIM3, clocks.timclk1().raw(), rate_hz),
        systick_hz: clocks.sysclk().raw(),
        initial_raw,
        index_raw: None,
    }
}

/// TIM2 (encoder 1) and TIM5 (encoder 2) in quadrature mode.
pub struct Encoders {
    _enc1: Qei<pac::TIM2>,
    _enc2: Qei<pac::TIM5>,
}

impl Encoders {
    fn raw(&self) -> [u32; 2] {
        // SAFETY: read-only access to the counters of timers this struct owns.
        unsafe {
            [
                (*pac::TIM2::ptr()).cnt().read().bits(),
                (*pac::TIM5::ptr()).cnt().read().bits(),
            ]
        }
    }

    /// The two counters' raw values now (`_t_us` is for the simulated encoders).
    #[inline]
    pub fn read(&mut self, _t_us: u64) -> [u32; 2] {
        self.raw()
    }
}

/// Encoder `ch`'s index capture (0: TIM2, 1: TIM5): the counter value latched at the index pulse,
/// if one arrived. Called from the timer's interrupt; the first index references the encoder and
/// disarms the interrupt (later passes need no action).
pub fn take_index(ch: usize) -> Option<u32> {
    // SAFETY: SR/CCR3/DIER of the encoder timers are touched only here after init; the count
    // register read by `Encoders::read` is not affected.
    let tim = unsafe {
        match ch {
            0 => &*pac::TIM2::ptr(),
            // TIM5's register block has the same layout as TIM2's.
            _ => &*(pac::TIM5::ptr() as *const pac::tim2::RegisterBlock),
        }
    };
    if tim.sr().read().bits() & SR_CC3IF == 0 {
        return None;
    }
    let raw = tim.ccr3().read().bits(); // reading CCR3 clears CC3IF
    tim.dier()
        .modify(|r, w| unsafe { w.bits(r.bits() & !DIER_CC3IE) });
    Some(raw)
}

const RX_BUF: usize = 128;
const TX_BUF: usize = 1024;

/// USB FS CDC-ACM as the host link.
pub struct Link {
    dev: UsbDevice<'static, UsbBusType>,
    serial: SerialPort<'static, UsbBusType, [u8; RX_BUF], [u8; TX_BUF]>,
}

impl Link {
    /// Service the USB stack (from the OTG_FS interrupt); true if the serial class may have data.
    #[inline]
    pub fn poll(&mut self) -> bool {
        self.dev.poll(&mut [&mut self.serial])
    }

    /// Received bytes into `buf`; how many.
    #[inline]
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        self.serial.read(buf).unwrap_or(0)
    }

    /// Queue bytes for sending without waiting; how many were taken (0 = would block: the host is
    /// not reading, the caller counts and drops).
    #[inline]
    pub fn write(&mut self, bytes: &[u8]) -> usize {
        self.serial.write(bytes).unwrap_or(0)
    }
}
