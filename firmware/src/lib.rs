//! J-DBB firmware support: the board seam. The RTIC application is
//! `src/main.rs`; all instrument logic (counts → D, batching, protocol) lives in `jdbb-core`.
//!
//! Exactly one board is compiled in: `board-f411` (default; STM32F411CEU6 "Black Pill", encoders on
//! TIM2/TIM5, USB FS CDC-ACM) or `qemu` (QEMU `netduinoplus2`: simulated encoders, USART2).
#![no_std]

#[cfg(all(feature = "board-f411", feature = "qemu"))]
compile_error!(
    "features `board-f411` and `qemu` are exclusive: use `--no-default-features --features qemu`"
);
#[cfg(any(
    all(
        feature = "hse-8mhz",
        any(feature = "hse-12mhz", feature = "hse-16mhz", feature = "hse-24mhz")
    ),
    all(
        feature = "hse-12mhz",
        any(feature = "hse-16mhz", feature = "hse-24mhz")
    ),
    all(feature = "hse-16mhz", feature = "hse-24mhz"),
))]
compile_error!(
    "select at most one crystal feature (`hse-8mhz`, `hse-12mhz`, `hse-16mhz`, `hse-24mhz`)"
);
#[cfg(not(any(feature = "board-f411", feature = "qemu")))]
compile_error!("select a board: feature `board-f411` (default) or `qemu`");

pub mod board;
#[cfg(feature = "board-f411")]
pub mod sample_timer;
#[cfg(feature = "qemu")]
pub mod scenario;
#[cfg(feature = "qemu")]
pub mod usart2;

/// Firmware version reported in `DeviceInfo` (from Cargo.toml).
pub const FIRMWARE_VERSION: [u8; 3] = [
    parse_u8(env!("CARGO_PKG_VERSION_MAJOR")),
    parse_u8(env!("CARGO_PKG_VERSION_MINOR")),
    parse_u8(env!("CARGO_PKG_VERSION_PATCH")),
];

const fn parse_u8(s: &str) -> u8 {
    let b = s.as_bytes();
    let mut i = 0;
    let mut v: u32 = 0;
    while i < b.len() {
        v = v * 10 + (b[i] - b'0') as u32;
        i += 1;
    }
    if v > 255 {
        255
    } else {
        v as u8
    }
}

/// One arcsecond (rad).
const ARCSEC: f64 = core::f64::consts::PI / 180.0 / 3600.0;

/// An instrument with every error term of the extended model non-zero, at realistic sizes: bars
/// 45 µm long and 38 µm short, fine zeros +100″ and −85″, eccentricities 60″ and 45″, axes skewed
/// by −100″, pivot axes tilted by 80″ and −60″, pivot offsets 40–70″ (at the grip radius); and
/// non-zero zero counts with encoder 2 reversed. Besides the default instrument, the worst case
/// the `accuracy` and `cycles` programs check.
pub const INSTRUMENT_WITH_ERRORS: jdbb_core::Calibration = {
    use jdbb_core::calib::{Calibration, Direction, EncoderCal, FrameCal};
    Calibration {
        l1_mm: 50.045,
        l2_mm: 49.962,
        enc1: EncoderCal {
            counts_per_rev: 1 << 23,
            zero_count: 1_234_567,
            direction: Direction::Positive,
            zero_offset_rad: 100.0 * ARCSEC,
            eccentricity_rad: 60.0 * ARCSEC,
            eccentricity_phase_rad: 0.9,
        },
        enc2: EncoderCal {
            counts_per_rev: 1 << 23,
            zero_count: -654_321,
            direction: Direction::Negative,
            zero_offset_rad: -85.0 * ARCSEC,
            eccentricity_rad: 45.0 * ARCSEC,
            eccentricity_phase_rad: -2.3,
        },
        axes_skew_rad: -100.0 * ARCSEC,
        frame1: FrameCal {
            tilt_rad: 80.0 * ARCSEC,
            offset_normal_rad: 50.0 * ARCSEC,
            offset_axial_rad: -40.0 * ARCSEC,
        },
        frame2: FrameCal {
            tilt_rad: -60.0 * ARCSEC,
            offset_normal_rad: 70.0 * ARCSEC,
            offset_axial_rad: -55.0 * ARCSEC,
        },
    }
};
