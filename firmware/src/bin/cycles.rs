//! Per-sample cost of the on-chip sample path, in instructions, on the Cortex-M4F under QEMU.
//!
//! Run with `-icount shift=0` (one instruction = 1 ns of virtual time, so SysTick readings are
//! deterministic) — `scripts/fw-cycles.sh` does it. The program
//!
//! 1. calibrates SysTick against a loop of known length (`subs` + `bne`, two instructions per
//!    iteration; two lengths, so the loop's entry/exit cost cancels): SysTick ticks per instruction;
//! 2. times [`ITERATIONS`] samples of exactly the firmware's sample path — `Sampler::sample` (two
//!    `Encoder<32>::update`, `Kernel::distance_mm`, status bits, the sample pushed into the batch)
//!    and, for every full batch, `protocol::encode` of the `DeviceMsg::Batch` frame — on raw counts
//!    of the default simulated circular test (precomputed, so the simulation is not timed);
//! 3. times `CircularTest::counts_at` alone (the QEMU build's simulated encoders, not part of the
//!    on-chip path) for information;
//!
//! and prints, on semihosting stdout (this program does not use defmt):
//!
//! ```text
//! systick ticks per instruction: 0.168000
//! sample path: N instructions/sample (over 16384 samples; counts -> D -> batch -> frame bytes)
//! simulated encoders (qemu only, not on chip): N instructions/sample
//! ```
//!
//! Exit code 0, or 1 if the calibration is inconsistent. The interrupt entry/exit of the sample
//! task (~12 cycles each way on the M4) and the queue hand-off are not included.
#![no_std]
#![no_main]

use core::arch::asm;
use core::hint::black_box;

use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use jdbb_core::protocol::{self, DeviceMsg, MAX_FRAME_LEN};
use jdbb_core::sampler::{SampleClock, Sampler};
use jdbb_core::sim::CircularTest;
use stm32f4xx_hal as _; // the device's interrupt vector table

/// Samples timed.
const ITERATIONS: u32 = 16_384;
/// Distinct raw-count pairs cycled through (1 ms apart on the default circular test).
const TABLE_LEN: usize = 256;

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

/// Exactly `2 n` instructions in the loop body (n ≥ 1).
#[inline(always)]
fn spin(n: u32) {
    unsafe {
        asm!("2:", "subs {0}, {0}, #1", "bne 2b", inout(reg) n => _, options(nomem, nostack));
    }
}

/// SysTick ticks taken by `f` (the counter counts down from 2^24 − 1; one measurement must stay
/// below 2^24 ticks ≈ 100 M instructions).
#[inline(always)]
fn ticks(f: impl FnOnce()) -> u32 {
    let start = SYST::get_current();
    f();
    let end = SYST::get_current();
    start.wrapping_sub(end) & 0x00ff_ffff
}

#[entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().unwrap();
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(0x00ff_ffff);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();

    // 1. Calibration: 2·(N2 − N1) instructions.
    const N1: u32 = 1_000_000;
    const N2: u32 = 5_000_000;
    let t1 = ticks(|| spin(N1));
    let t2 = ticks(|| spin(N2));
    if t2 <= t1 {
        hprintln!("calibration failed: {} then {} ticks", t1, t2);
        debug::exit(debug::EXIT_FAILURE);
    }
    let ticks_per_instr = (t2 - t1) as f32 / (2 * (N2 - N1)) as f32;
    hprintln!("systick ticks per instruction: {}", ticks_per_instr);

    // 2. The sample path on realistic counts.
    let test = CircularTest::DEFAULT;
    let mut table = [[0u32; 2]; TABLE_LEN];
    for (i, raw) in table.iter_mut().enumerate() {
        let (c1, c2) = test.counts_at(i as u64 * 1000).unwrap_or((0, 0));
        *raw = [c1 as u32, c2 as u32];
    }
    let mut sampler = Sampler::new([0, 0], &test.cal, SampleClock::new(10_000, 10), true);
    let mut frame = [0u8; MAX_FRAME_LEN];
    let mut frame_bytes = 0usize;
    let table = black_box(&table);
    let t_path = ticks(|| {
        for i in 0..ITERATIONS {
            let raw = table[i as usize % TABLE_LEN];
            if let Some(batch) = sampler.sample(raw) {
                let msg = DeviceMsg::Batch(batch);
                if let Ok(bytes) = protocol::encode(&msg, &mut frame) {
                    frame_bytes += black_box(bytes).len();
                }
            }
        }
    });
    let per_sample = t_path as f32 / ticks_per_instr / ITERATIONS as f32;
    hprintln!(
        "sample path: {} instructions/sample (over {} samples; counts -> D -> batch -> frame bytes, {} frame bytes/sample)",
        per_sample as u32,
        ITERATIONS,
        frame_bytes as u32 / ITERATIONS
    );

    // Parts of the path, for information.
    let kernel = jdbb_core::geometry::Kernel::new(&test.cal);
    let mut acc = 0.0f64;
    let t_kernel = ticks(|| {
        for i in 0..ITERATIONS {
            let raw = table[i as usize % TABLE_LEN];
            acc += kernel.distance_mm(raw[0] as i32 as i64, raw[1] as i32 as i64);
        }
    });
    black_box(acc);
    let mut last = None;
    for &raw in table.iter().take(16) {
        if let Some(b) = sampler.sample(raw) {
            last = Some(DeviceMsg::Batch(b));
        }
    }
    let msg = last.unwrap_or(DeviceMsg::Pong(0));
    const ENC_N: u32 = 256;
    let t_encode = ticks(|| {
        for _ in 0..ENC_N {
            if let Ok(bytes) = protocol::encode(black_box(&msg), &mut frame) {
                black_box(bytes);
            }
        }
    });
    hprintln!(
        "  of which Kernel::distance_mm: {} instructions, frame encoding: {} instructions/sample",
        (t_kernel as f32 / ticks_per_instr / ITERATIONS as f32) as u32,
        (t_encode as f32 / ticks_per_instr / (ENC_N * 16) as f32) as u32
    );

    // 3. The simulation alone (QEMU build only).
    const SIM_N: u32 = 256;
    let mut sink = 0i64;
    let t_sim = ticks(|| {
        for i in 0..SIM_N {
            let (a, b) = test.counts_at(black_box(i as u64 * 1000)).unwrap_or((0, 0));
            sink = sink.wrapping_add(a ^ b);
        }
    });
    black_box(sink);
    hprintln!(
        "simulated encoders (qemu only, not on chip): {} instructions/sample",
        (t_sim as f32 / ticks_per_instr / SIM_N as f32) as u32
    );
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
