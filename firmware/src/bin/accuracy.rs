//! On-chip accuracy of D: evaluates `Kernel::distance_mm` on the Cortex-M4F (QEMU netduinoplus2)
//! over a grid of count pairs and streams the results as ordinary protocol frames on USART2 (the
//! *second* `-serial`), then exits through semihosting with code 0. The host compares every D with
//! its f64 reference `geometry::distance_mm` against `geometry::accuracy_budget_mm`.
//!
//! Run: `scripts/fw-accuracy.sh OUT.bin` (writes the raw USART2 bytes to OUT.bin), i.e.
//! `qemu-system-arm -machine netduinoplus2 -nographic -monitor none -serial null
//! -serial file:OUT.bin -semihosting-config enable=on,target=native -kernel <accuracy ELF>`.
//!
//! # Frame stream
//!
//! For each of the [`calibrations`] in order (three sections):
//!
//! 1. one `DeviceMsg::Info` whose `calibration` is the one every following D was computed with
//!    (`sample_rate_hz = 0`, `sampling = false`, `board = QemuNetduinoPlus2`);
//! 2. `DeviceMsg::Batch` frames of up to `BATCH_LEN` samples; `seq` counts the section's points
//!    from 0, `dropped = 0`, each sample has `t_us` = its index in the section, `status` = 0,
//!    `enc1`/`enc2` the extended counts and `d_mm` the chip's D.
//!
//! Points of a section, in order: with c = ⌊FRAME_RANGE_RAD / rad_per_count⌋ count steps (the
//! whole ±75° working range; computed per encoder), a coarse grid of [`COARSE`]² points, steps
//! i·2c/(COARSE−1) − c for i, j in 0..COARSE (enc1 outer, enc2 inner), then a fine grid around zero
//! deflection, steps −[`FINE`]..=[`FINE`] on both (enc1 outer); a step s is the count
//! `zero_count + direction·s`. So each section holds COARSE² + (2·FINE+1)² = 6 850 points, 20 550
//! in all, sent as 429 batch frames per section.
#![no_std]
#![no_main]

use cortex_m_semihosting::debug;
use jdbb_core::calib::{Calibration, EncoderCal};
use jdbb_core::geometry::{Kernel, FRAME_RANGE_RAD};
use jdbb_core::protocol::{
    self, Board, DeviceInfo, DeviceMsg, ResetCause, Sample, SampleBatch, Status, MAX_FRAME_LEN,
    PROTOCOL_VERSION,
};
use jdbb_core::quadrature::Encoder;
use jdbb_firmware::usart2::Usart2;
use jdbb_firmware::INSTRUMENT_WITH_ERRORS;
use stm32f4xx_hal::{pac, prelude::*};

/// Points per axis of the coarse grid.
pub const COARSE: i64 = 81;
/// Half-width (count steps) of the fine grid around zero.
pub const FINE: i64 = 8;

/// The calibrations checked: the default instrument (L1 = L2 = 50 mm, 2²³ counts/rev, no errors);
/// [`INSTRUMENT_WITH_ERRORS`] (every term of the extended model non-zero, unequal bars, non-zero
/// zero counts, a reversed encoder, 2²³ counts/rev); and seed 000's coarse instrument (20 000
/// counts/rev), where the budget is 1 % of a count's step rather than 10 nm.
pub fn calibrations() -> [Calibration; 3] {
    [
        Calibration::DEFAULT,
        INSTRUMENT_WITH_ERRORS,
        Calibration::SEED_000,
    ]
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

struct Out {
    uart: Usart2,
    frame: [u8; MAX_FRAME_LEN],
}

impl Out {
    fn send(&mut self, msg: &DeviceMsg) {
        match protocol::encode(msg, &mut self.frame) {
            Ok(bytes) => self.uart.write_all(bytes),
            Err(_) => debug::exit(debug::EXIT_FAILURE),
        }
    }
}

fn count(enc: &EncoderCal, step: i64) -> i64 {
    enc.zero_count + enc.direction.sign() * step
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let dp = pac::Peripherals::take().unwrap();
    let clocks = dp.RCC.constrain().cfgr.freeze();
    let gpioa = dp.GPIOA.split();
    let _tx = gpioa.pa2.into_alternate::<7>();
    let _rx = gpioa.pa3.into_alternate::<7>();
    let mut out = Out {
        uart: Usart2::new(dp.USART2, clocks.pclk1().raw()),
        frame: [0; MAX_FRAME_LEN],
    };

    for cal in calibrations() {
        out.send(&DeviceMsg::Info(DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: jdbb_firmware::FIRMWARE_VERSION,
            board: Board::QemuNetduinoPlus2,
            sample_rate_hz: 0,
            sampling: false,
            calibration: cal,
            chip_id: [0; 12],
            reset_cause: ResetCause::default(),
            index: [Encoder::<32>::new(0).index_status(); 2],
            overruns: 0,
            clock: jdbb_core::protocol::ClockSource::Emulated,
            calibration_kept: jdbb_core::protocol::CalKept::NotSent,
            unhandled_irq: None,
            index_disabled: [false; 2],
        }));
        let kernel = Kernel::new(&cal);
        let c1 = (FRAME_RANGE_RAD / cal.enc1.rad_per_count()) as i64;
        let c2 = (FRAME_RANGE_RAD / cal.enc2.rad_per_count()) as i64;
        let coarse = (0..COARSE).flat_map(|i| {
            (0..COARSE).map(move |j| {
                (
                    i * 2 * c1 / (COARSE - 1) - c1,
                    j * 2 * c2 / (COARSE - 1) - c2,
                )
            })
        });
        let fine = (-FINE..=FINE).flat_map(|i| (-FINE..=FINE).map(move |j| (i, j)));
        let mut batch = SampleBatch {
            seq: 0,
            dropped: 0,
            samples: heapless::Vec::new(),
        };
        for (n, (s1, s2)) in coarse.chain(fine).enumerate() {
            let (enc1, enc2) = (count(&cal.enc1, s1), count(&cal.enc2, s2));
            if batch.samples.is_empty() {
                batch.seq = n as u32;
            }
            let _ = batch.samples.push(Sample {
                t_us: n as u64,
                enc1,
                enc2,
                d_mm: kernel.distance_mm(enc1, enc2),
                status: Status(0),
            });
            if batch.samples.is_full() {
                out.send(&DeviceMsg::Batch(batch.clone()));
                batch.samples.clear();
            }
        }
        if !batch.samples.is_empty() {
            out.send(&DeviceMsg::Batch(batch));
        }
    }
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
