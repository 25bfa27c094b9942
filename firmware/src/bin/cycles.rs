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
//!    of the default simulated circular test (precomputed, so the simulation is not timed), once
//!    with the default instrument and once with `INSTRUMENT_WITH_ERRORS` (every term of the
//!    extended model non-zero);
//! 3. times, one call at a time, the sample task's worst tick (`Sampler::sample_at_tick`, with a
//!    batch sealed; and an overrun tick) and every section in which another task holds the
//!    sampler's lock and so delays the sample task (`restart` for `Start`, `take_batch` for
//!    `Stop`, `set_kernel` for `SetCalibration`, the `DeviceInfo` fields, `on_index_edge` of the
//!    index tasks) — the software part of the sample task's latency;
//! 4. times `CircularTest::counts_at` alone (the QEMU build's simulated encoders, not part of the
//!    on-chip path) for information;
//!
//! and prints, on semihosting stdout (this program does not use defmt):
//!
//! ```text
//! systick ticks per instruction: 0.168000
//! sample path, default instrument: N instructions/sample (over 16384 samples; …)
//!   of which Kernel::distance_mm: N instructions, frame encoding: N instructions/sample
//! sample path, instrument with every error term: N instructions/sample (…)
//!   of which Kernel::distance_mm: N instructions, frame encoding: N instructions/sample
//! worst sample path: N instructions/sample (budget 2000)
//! sample task, worst single tick: N instructions (batch sealed); overrun tick: N
//! sections holding off the sample task: Start N, Stop N, SetCalibration N, Info N, index edge N
//!   (Kernel::new for SetCalibration, outside the lock: N)
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
use jdbb_core::geometry::Kernel;
use jdbb_core::protocol::{self, DeviceMsg, MAX_FRAME_LEN};
use jdbb_core::quadrature::IndexEdge;
use jdbb_core::sampler::{SampleClock, Sampler};
use jdbb_core::sim::CircularTest;
use jdbb_core::Calibration;
use jdbb_firmware::INSTRUMENT_WITH_ERRORS;
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

/// Instructions per sample of the whole sample path (`Sampler::sample` + frame encoding) on the
/// raw counts of `test`, of `Kernel::distance_mm` alone, and of the frame encoding per sample; and
/// the frame bytes per sample.
fn time_sample_path(test: &CircularTest, ticks_per_instr: f32) -> (u32, u32, u32, u32) {
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

    // Parts of the path, for information. The kernel's result is folded in with an integer xor
    // (2 instructions), not an f64 sum, so the figure is the kernel's own.
    let kernel = jdbb_core::geometry::Kernel::new(&test.cal);
    let mut acc = 0u64;
    let t_kernel = ticks(|| {
        for i in 0..ITERATIONS {
            let raw = table[i as usize % TABLE_LEN];
            acc ^= kernel
                .distance_mm(raw[0] as i32 as i64, raw[1] as i32 as i64)
                .to_bits();
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
    (
        per_sample as u32,
        (t_kernel as f32 / ticks_per_instr / ITERATIONS as f32) as u32,
        (t_encode as f32 / ticks_per_instr / (ENC_N * 16) as f32) as u32,
        frame_bytes as u32 / ITERATIONS,
    )
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

    // 2. The sample path on realistic counts, for the default instrument and for one with every
    //    error term of the extended model (the kernel does the same work for both; the counts'
    //    sizes, hence the frame bytes, differ slightly).
    let mut worst = 0u32;
    for (name, cal) in [
        ("default instrument", Calibration::DEFAULT),
        ("instrument with every error term", INSTRUMENT_WITH_ERRORS),
    ] {
        let test = CircularTest {
            cal,
            ..CircularTest::DEFAULT
        };
        let (per_sample, kernel, encode, bytes) = time_sample_path(&test, ticks_per_instr);
        worst = worst.max(per_sample);
        hprintln!(
            "sample path, {}: {} instructions/sample (over {} samples; counts -> D -> batch -> frame bytes, {} frame bytes/sample)",
            name,
            per_sample,
            ITERATIONS,
            bytes
        );
        hprintln!(
            "  of which Kernel::distance_mm: {} instructions, frame encoding: {} instructions/sample",
            kernel,
            encode
        );
    }
    hprintln!(
        "worst sample path: {} instructions/sample (budget 2000)",
        worst
    );

    let test = CircularTest::DEFAULT;
    let mut table = [[0u32; 2]; TABLE_LEN];
    for (i, raw) in table.iter_mut().enumerate() {
        let (c1, c2) = test.counts_at(i as u64 * 1000).unwrap_or((0, 0));
        *raw = [c1 as u32, c2 as u32];
    }
    let table = black_box(&table);

    // 3. The sample task's latency, software part: its own worst tick, and the longest section
    // another task runs with the sampler locked.
    let instr = |t: u32| (t as f32 / ticks_per_instr) as u32;
    let mut s2 = Sampler::new([0, 0], &test.cal, SampleClock::new(10_000, 10), true);
    let mut worst_tick = 0u32;
    const TICKS_N: u32 = 4096;
    for tick in 1..=TICKS_N {
        let raw = table[tick as usize % TABLE_LEN];
        let t = ticks(|| {
            black_box(s2.sample_at_tick(tick, |_| raw));
        });
        worst_tick = worst_tick.max(t);
    }
    let t_overrun = ticks(|| {
        black_box(s2.sample_at_tick(TICKS_N + 3, |_| table[3]));
    });
    hprintln!(
        "sample task, worst single tick: {} instructions (batch sealed); overrun tick: {}",
        instr(worst_tick),
        instr(t_overrun)
    );
    for tick in 1..=5u32 {
        black_box(s2.sample_at_tick(TICKS_N + 3 + tick, |_| table[0]));
    }
    let t_stop = ticks(|| {
        black_box(s2.take_batch());
    });
    let kernel = ticks(|| {
        black_box(Kernel::new(black_box(&test.cal)));
    });
    let k = Kernel::new(&test.cal);
    let t_cal = ticks(|| s2.set_kernel(black_box(k)));
    let t_info = ticks(|| {
        black_box((s2.index_status(), s2.overruns()));
    });
    let t_index = ticks(|| {
        black_box(s2.on_index_edge(0, 100, 101, IndexEdge::Rising));
    });
    let t_start = ticks(|| s2.restart());
    hprintln!(
        "sections holding off the sample task: Start {}, Stop {}, SetCalibration {}, Info {}, index edge {}",
        instr(t_start),
        instr(t_stop),
        instr(t_cal),
        instr(t_info),
        instr(t_index)
    );
    hprintln!(
        "  (Kernel::new for SetCalibration, outside the lock: {})",
        instr(kernel)
    );

    // 4. The simulation alone (QEMU build only).
    for (name, cal) in [
        ("default instrument", Calibration::DEFAULT),
        ("with errors", INSTRUMENT_WITH_ERRORS),
    ] {
        let test = CircularTest {
            cal,
            ..CircularTest::DEFAULT
        };
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
            "simulated encoders, {} (qemu only, not on chip): {} instructions/sample",
            name,
            (t_sim as f32 / ticks_per_instr / SIM_N as f32) as u32
        );
    }
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
