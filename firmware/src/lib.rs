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
#[cfg(not(any(feature = "board-f411", feature = "qemu")))]
compile_error!("select a board: feature `board-f411` (default) or `qemu`");

pub mod board;
#[cfg(feature = "board-f411")]
pub mod sample_timer;
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
