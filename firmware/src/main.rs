//! The J-DBB firmware: an RTIC 2 application, the same on the real STM32F411 board and on QEMU's
//! netduinoplus2 (`--no-default-features --features qemu`); only [`jdbb_firmware::board`] differs.
//!
//! Tasks, highest priority first:
//!
//! | task      | priority | trigger                    | does |
//! |-----------|----------|----------------------------|------|
//! | `sample`  | 3        | TIM3 update (sample clock) | 32-bit tick count + counts latched at the tick; a pending rate change written (before D is computed); → `Sampler` (overruns counted as drops, counts → D → batch); a full batch goes to the queue with `try_send`, or is dropped and counted |
//! | `pace`    | 3        | SysTick monotonic (qemu only) | pends TIM3 once per sample period and counts the tick: QEMU's TIM3 is not periodic |
//! | `index1/2`| 4        | TIM2/TIM5 CC3 (board only) | index edge latched in hardware, read before the pulse's other edge can overwrite it → a queue, `index_apply` pended |
//! | `index_apply` | 3    | SPI4 vector, pended by `index1/2` (board only) | the queued index edges → `Encoder::on_index_edge` |
//! | `usb_rx` / `uart_rx` | 2 | OTG_FS (board) / USART2 (qemu) | services the link, greets a host that configured the device, decodes commands, replies through the queue |
//! | `writer`  | 1        | queue (async)              | frames each message and writes it to the link without blocking the others; discards (and counts) while no host reads |
//! | `upkeep`  | 1        | spawned by `Stop`          | erases the calibration store's spare block ahead while not sampling, once every reply has left and the host has been quiet for `UPKEEP_QUIET_MS` |
//! | idle      | 0        | —                          | feeds the watchdog, sets the status LED, sleeps (`wfi`) |
//! | SysTick   | 1 (board) / 3 (qemu) | monotonic tick | time base of the writer's waits (and of the qemu pacer); below the sample task on the board |
//!
//! The queue holds [`QUEUE_LEN`] messages, of which sample batches may take [`BATCH_QUOTA`], so a
//! reply always finds room. The writer waits for a link that is momentarily full (USB packets
//! not yet read by the host) for up to [`LINK_TIMEOUT_US`] per frame; then it drops the frame,
//! takes the host for absent (`jdbb_core::link::Presence`), throws away what the link still
//! buffers, and discards every message until the host is back (a command, the link coming up, or
//! probe bytes read), counting their samples as dropped. The sample task never waits, allocates or
//! panics.
//!
//! Sampling starts at power-up at [`DEFAULT_RATE_HZ`] (both boards, see `board::AUTO_START`); the
//! device sends `DeviceMsg::Hello` first: at power-up on the UART, when the host has configured
//! the device on USB.
#![no_std]
#![no_main]

#[cfg(feature = "board-f411")]
use defmt_rtt as _;
#[cfg(feature = "qemu")]
use defmt_semihosting as _;
// The real board's panic handler (log, mark, reset) is in `board::f411`.
#[cfg(feature = "qemu")]
use panic_probe as _;

use jdbb_core::link::BatchQuota;
use rtic_monotonics::systick::prelude::*;

// Real board: 10 kHz, the writer's polling granularity while USB is momentarily full (at 10 kHz
// sampling the link needs a refill every few hundred µs). QEMU: 1 kHz, the sample pacer's wake-up
// rate — every SysTick interrupt costs the emulator real time (under `-icount` each idle wake-up
// overshoots by the host's timer slack: at 10 kHz emulated time ran at 40 % of real time).
#[cfg(feature = "board-f411")]
const MONO_HZ: u32 = 10_000;
#[cfg(feature = "qemu")]
const MONO_HZ: u32 = 1_000;
systick_monotonic!(Mono, MONO_HZ);

/// Logical priority of the SysTick exception (the monotonic). It is 0, above every task, unless
/// set: on the board it goes below the sample and USB tasks, to the writer's level (the only task
/// that waits on it); in QEMU it paces the samples, at the sample task's level.
#[cfg(feature = "board-f411")]
const SYSTICK_PRIO: u8 = 1;
#[cfg(feature = "qemu")]
const SYSTICK_PRIO: u8 = 3;

/// Messages the queue between the tasks and the writer holds.
pub const QUEUE_LEN: usize = 16;
/// Places of the queue sample batches may take; the rest are kept for replies.
pub const BATCH_QUOTA: usize = QUEUE_LEN - 4;
/// Sample clock at power-up (Hz).
pub const DEFAULT_RATE_HZ: u32 = 1_000;
/// How long the writer waits for a full link before it drops a frame and takes the host for
/// absent (µs).
pub const LINK_TIMEOUT_US: u32 = 20_000;
const LINK_POLL_US: u32 = 250;

/// How long the link must have been quiet (no command, nothing left to send) before `upkeep`
/// erases (ms): the erase stalls the whole CPU, so it waits until the host is not waiting.
pub const UPKEEP_QUIET_MS: u32 = 300;
/// Monotonic tick of the last command frame received (for `upkeep`).
static LAST_COMMAND: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// Batches in the queue (taken by the sample task, given back by the writer).
static BATCHES: BatchQuota = BatchQuota::new(BATCH_QUOTA);

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true, dispatchers = [SPI2, SPI3])]
mod app {
    use super::{
        Mono, BATCHES, DEFAULT_RATE_HZ, LINK_POLL_US, LINK_TIMEOUT_US, QUEUE_LEN, SYSTICK_PRIO,
    };
    use cortex_m::peripheral::scb::SystemHandler;
    use jdbb_core::geometry::Kernel;
    use jdbb_core::link::{Outgoing, Presence, ProbeStep};
    use jdbb_core::protocol::{
        self, CalKept, ClockSource, Command, CommandError, Decoder, DeviceInfo, DeviceMsg,
        FrameError, Hello, ResetCause, SampleBatch, MAX_FRAME_LEN, MAX_SAMPLE_RATE_HZ,
        PROTOCOL_VERSION,
    };
    use jdbb_core::quadrature::IndexEdge;
    use jdbb_core::sampler::{SampleClock, Sampler};
    use jdbb_core::Calibration;
    use jdbb_firmware::board::{self, SampleTimer};
    use jdbb_firmware::FIRMWARE_VERSION;
    use rtic_monotonics::systick::prelude::*;
    use rtic_sync::channel::{Receiver, Sender, TrySendError};
    use rtic_sync::make_channel;

    type Tx = Sender<'static, Outgoing, QUEUE_LEN>;
    type Rx = Receiver<'static, Outgoing, QUEUE_LEN>;
    /// Index edges captured (count at the edge, count after, which way), one queue per encoder.
    const INDEX_QUEUE: usize = 8;
    type IndexQueue = heapless::spsc::Queue<(u32, u32, IndexEdge), INDEX_QUEUE>;
    type IndexTx = heapless::spsc::Producer<'static, (u32, u32, IndexEdge)>;
    type IndexRx = heapless::spsc::Consumer<'static, (u32, u32, IndexEdge)>;

    #[shared]
    struct Shared {
        sampler: Sampler,
        timer: SampleTimer,
        link: board::Link,
        presence: Presence,
        control: Control,
    }

    #[local]
    struct Local {
        encoders: board::Encoders,
        batch_tx: Tx,
        rx: Rx,
        index_tx1: IndexTx,
        index_tx2: IndexTx,
        index_rx1: IndexRx,
        index_rx2: IndexRx,
    }

    /// State of the command handler.
    pub struct Control {
        decoder: Decoder<MAX_FRAME_LEN>,
        state: State,
    }

    /// What commands act on and replies report, besides the sampler and the timer.
    pub struct State {
        cal: Calibration,
        /// Where the calibration is kept across power cycles.
        cal_memory: board::CalMemory,
        reply_tx: Tx,
        chip_id: [u8; 12],
        reset_cause: ResetCause,
        unhandled_irq: Option<i16>,
        clock: ClockSource,
        /// What became of the last calibration sent (reported in every `DeviceInfo`).
        kept: CalKept,
    }

    #[init(local = [index_q1: IndexQueue = IndexQueue::new(), index_q2: IndexQueue = IndexQueue::new()])]
    fn init(mut cx: init::Context) -> (Shared, Local) {
        let parts = board::init(cx.device, DEFAULT_RATE_HZ);
        Mono::start(cx.core.SYST, parts.systick_hz);
        // SAFETY: set once, before any task runs; RTIC does not manage SysTick's priority.
        unsafe {
            let bits = stm32f4xx_hal::pac::NVIC_PRIO_BITS;
            let hw = ((1u8 << bits) - SYSTICK_PRIO) << (8 - bits);
            cx.core.SCB.set_priority(SystemHandler::SysTick, hw);
        }
        let mut timer = parts.timer;
        // The calibration kept from before the last power cycle, else the default instrument.
        let kept = parts.cal_memory.load();
        let cal = kept.unwrap_or(Calibration::DEFAULT);
        let clock = SampleClock::new(timer.clock_hz(), timer.period_ticks());
        let mut sampler = Sampler::new(parts.initial_raw, &cal, clock, board::SIMULATED);
        if let Some(index) = parts.index_raw {
            sampler.on_index(0, index[0]);
            sampler.on_index(1, index[1]);
        }

        let (mut reply_tx, rx) = make_channel!(Outgoing, QUEUE_LEN);
        let batch_tx = reply_tx.clone();
        if board::AUTO_START {
            timer.start();
        }
        let control = Control {
            decoder: Decoder::new(),
            state: State {
                cal,
                cal_memory: parts.cal_memory,
                reply_tx: reply_tx.clone(),
                chip_id: parts.chip_id,
                reset_cause: parts.reset_cause,
                unhandled_irq: parts.unhandled_irq,
                clock: parts.clock,
                kept: CalKept::NotSent,
            },
        };
        if board::LINK_UP_AT_START {
            // The queue is empty: the greeting always fits.
            let greeting = Hello::of(&info(&timer, &sampler, &control.state));
            let _ = reply_tx.try_send(reply(DeviceMsg::Hello(greeting)));
        }
        writer::spawn().ok();
        #[cfg(feature = "qemu")]
        pace::spawn().ok();
        // (Unused in the QEMU build, which has no index interrupts.)
        let (index_tx1, index_rx1) = cx.local.index_q1.split();
        let (index_tx2, index_rx2) = cx.local.index_q2.split();
        defmt::info!(
            "jdbb firmware {}: {} Hz, sampling {}, reset cause {=u8:#x}",
            board::BOARD,
            timer.rate_hz(),
            timer.is_running(),
            parts.reset_cause.0
        );
        if kept.is_some() {
            defmt::info!("calibration kept from before the last power-up in force");
        }
        // From here a panic resets the chip (reported as PANIC); before, it shows on the LED.
        board::init_done();
        (
            Shared {
                sampler,
                timer,
                link: parts.link,
                presence: Presence::new(board::LINK_UP_AT_START),
                control,
            },
            Local {
                encoders: parts.encoders,
                batch_tx,
                rx,
                index_tx1,
                index_tx2,
                index_rx1,
                index_rx2,
            },
        )
    }

    /// The idle loop feeds the watchdog: a task that never lets the CPU idle (a hang, a spin that
    /// does not end) resets the chip (board; see `board::f411`), and sets the status LED.
    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            board::feed_watchdog();
            let now_ms = Mono::now().ticks() as u64 * 1_000 / super::MONO_HZ as u64;
            board::indicate(now_ms as u32);
            cortex_m::asm::wfi();
        }
    }

    /// While not sampling: erase the calibration store's spare block ahead (on the board up to
    /// 4 s with the whole CPU stalled, USB included), so that no store while sampling has to.
    /// Spawned by `Stop`. The erase never holds up a reply the host waits for: it waits until
    /// every queued message has left the link and no command came for [`super::UPKEEP_QUIET_MS`]
    /// (the Stop reply, and whatever the host asks right after it, are answered first).
    #[task(priority = 1, shared = [timer, control, link])]
    async fn upkeep(cx: upkeep::Context) {
        let upkeep::SharedResources {
            mut timer,
            mut control,
            mut link,
            ..
        } = cx.shared;
        loop {
            Mono::delay(super::UPKEEP_QUIET_MS.millis()).await;
            let since_ms = Mono::now()
                .ticks()
                .wrapping_sub(super::LAST_COMMAND.load(core::sync::atomic::Ordering::Relaxed))
                as u64
                * 1_000
                / super::MONO_HZ as u64;
            let idle = since_ms >= super::UPKEEP_QUIET_MS as u64
                && control.lock(|c| c.state.reply_tx.is_empty())
                && link.lock(|l| l.drained());
            if idle {
                break;
            }
        }
        // Under the control lock no command (a Start) can come between the check and the erase.
        control.lock(|c| {
            if !timer.lock(|t| t.is_running()) {
                c.state.cal_memory.erase_ahead();
            }
        });
    }

    /// One tick of the sample clock: the whole on-chip sample path.
    #[task(binds = TIM3, priority = 3, shared = [sampler, timer], local = [encoders, batch_tx])]
    fn sample(cx: sample::Context) {
        let sample::SharedResources { sampler, timer, .. } = cx.shared;
        let encoders = cx.local.encoders;
        let tx = cx.local.batch_tx;
        (timer, sampler).lock(|t, s| {
            t.clear_update();
            let latch = encoders.latch();
            // A pending rate change is written first, before this tick's sample is computed, so
            // that it always lands in the period that just began (see `SampleTimer`).
            let new_period = t.apply_pending_rate(latch.tick());
            let batch = encoders.sample(latch, s);
            if let Some(ticks) = new_period {
                // After this tick's sample: the period now running keeps its old length.
                s.set_period(t.clock_hz(), ticks);
            }
            if let Some(batch) = batch {
                queue_batch(tx, s, batch);
            }
        });
    }

    /// Queue a sealed batch for the writer, or count it dropped (quota or queue full).
    fn queue_batch(tx: &mut Tx, s: &mut Sampler, batch: SampleBatch) {
        let n = batch.samples.len() as u32;
        if !BATCHES.try_take() {
            s.count_dropped(n);
            return;
        }
        let out = Outgoing {
            run: s.run(),
            msg: DeviceMsg::Batch(batch),
        };
        if let Err(TrySendError::Full(_) | TrySendError::NoReceiver(_)) = tx.try_send(out) {
            BATCHES.release();
            s.count_dropped(n);
        }
    }

    /// QEMU only: the sample clock (see `board::qemu`). Woken by every monotonic tick, pends the
    /// sample task's interrupt once for every period elapsed on the lossless TIM2 µs count (up to
    /// [`PACE_BURST`] per wake-up, yielding in between so each pend runs the sample task), so the
    /// samples keep their rate on average even though QEMU delivers SysTick ticks irregularly.
    /// Every elapsed period is counted (`board::count_ticks`), as TIM4 and TIM1 count them on the
    /// board; those beyond a burst are overruns.
    #[cfg(feature = "qemu")]
    #[task(priority = 3)]
    async fn pace(_: pace::Context) {
        let mut clock =
            jdbb_core::quadrature::CountExtender::<32>::new(board::pace_clock_raw_us(), 0);
        let mut now_us = move || clock.update(board::pace_clock_raw_us()) as u64;
        let mut next_us = now_us();
        loop {
            Mono::delay(<Mono as Monotonic>::Duration::from_ticks(1)).await;
            let period_us = board::pace_period_us() as u64;
            if period_us == 0 {
                next_us = now_us();
                continue;
            }
            let mut burst = 0;
            while now_us() >= next_us {
                if burst == PACE_BURST {
                    // More periods elapsed than a burst catches up: the emulated CPU stalled (a
                    // flash erase, or QEMU starved by its host). Count them all, as the board's
                    // tick counter counts ticks while its CPU stalls, and sample once: the sample
                    // task sees the overrun, the stream the gap.
                    let missed = (now_us() - next_us) / period_us + 1;
                    next_us += missed * period_us;
                    board::count_ticks(missed as u32);
                    rtic::pend(stm32f4xx_hal::pac::Interrupt::TIM3);
                    yield_now().await;
                    break;
                }
                next_us += period_us;
                board::count_ticks(1);
                rtic::pend(stm32f4xx_hal::pac::Interrupt::TIM3);
                yield_now().await;
                burst += 1;
            }
        }
    }

    /// Most samples the QEMU pacer catches up per wake-up (1 ms): up to 32 kHz.
    #[cfg(feature = "qemu")]
    const PACE_BURST: u32 = 32;

    /// Let every pending task of this priority run once (the sample task pended just before: it
    /// has the lower interrupt number, so it runs before this task's dispatcher).
    #[cfg(feature = "qemu")]
    async fn yield_now() {
        let mut yielded = false;
        core::future::poll_fn(|cx| {
            if yielded {
                core::task::Poll::Ready(())
            } else {
                yielded = true;
                cx.waker().wake_by_ref();
                core::task::Poll::Pending
            }
        })
        .await
    }

    /// Encoder 1's index edges (board only), at the highest priority, above the sample task: the
    /// edge's count is read from CCR3 before the pulse's other edge can overwrite it, and handed
    /// to `index_apply` (see README, "Index pulses").
    /// An index line that interrupts faster than an index can (`IndexRateLimit`) is switched
    /// off and reported (`DeviceInfo.index_disabled`), instead of starving every task below it
    /// until the watchdog resets the chip, over and over.
    #[cfg(feature = "board-f411")]
    #[task(binds = TIM2, priority = 4, local = [index_tx1, limit: jdbb_core::quadrature::IndexRateLimit = jdbb_core::quadrature::IndexRateLimit::new()])]
    fn index1(cx: index1::Context) {
        let tx = cx.local.index_tx1;
        let r = jdbb_core::quadrature::service_index(
            &mut board::IndexTimer(0),
            &mut board::ZPin(0),
            cx.local.limit,
            now_ms,
            |edge| hand_over(tx, 0, edge),
        );
        if r == jdbb_core::quadrature::IndexService::Disabled {
            defmt::error!("index of encoder 1 interrupts too fast: switched off");
        }
    }

    /// Encoder 2's index edges (board only); as `index1`.
    #[cfg(feature = "board-f411")]
    #[task(binds = TIM5, priority = 4, local = [index_tx2, limit: jdbb_core::quadrature::IndexRateLimit = jdbb_core::quadrature::IndexRateLimit::new()])]
    fn index2(cx: index2::Context) {
        let tx = cx.local.index_tx2;
        let r = jdbb_core::quadrature::service_index(
            &mut board::IndexTimer(1),
            &mut board::ZPin(1),
            cx.local.limit,
            now_ms,
            |edge| hand_over(tx, 1, edge),
        );
        if r == jdbb_core::quadrature::IndexService::Disabled {
            defmt::error!("index of encoder 2 interrupts too fast: switched off");
        }
    }

    /// Milliseconds of the monotonic (wrapping).
    #[cfg(feature = "board-f411")]
    fn now_ms() -> u32 {
        (Mono::now().ticks() as u64 * 1_000 / super::MONO_HZ as u64) as u32
    }

    /// An index edge captured on encoder `ch` goes to `index_apply` (pended); one that finds the
    /// queue full (more than [`INDEX_QUEUE`] − 1 edges before the sample task's priority could
    /// run) is lost and logged.
    #[cfg(feature = "board-f411")]
    #[inline]
    fn hand_over(tx: &mut IndexTx, ch: usize, (at, now, edge): (u32, u32, IndexEdge)) {
        if tx.enqueue((at, now, edge)).is_err() {
            defmt::warn!("index edge of encoder {} lost: queue full", ch + 1);
        }
        rtic::pend(stm32f4xx_hal::pac::Interrupt::SPI4);
    }

    /// The index edges to the sampler, at the sample task's priority (an unused interrupt vector,
    /// pended by `index1/2`).
    #[cfg(feature = "board-f411")]
    #[task(binds = SPI4, priority = 3, shared = [sampler], local = [index_rx1, index_rx2])]
    fn index_apply(mut cx: index_apply::Context) {
        for (ch, rx) in [&mut *cx.local.index_rx1, &mut *cx.local.index_rx2]
            .into_iter()
            .enumerate()
        {
            while let Some((at, now, edge)) = rx.dequeue() {
                cx.shared
                    .sampler
                    .lock(|s| s.on_index_edge(ch, at, now, edge));
            }
        }
    }

    /// USB interrupt: service the stack, greet a host that configured the device, read commands.
    #[cfg(feature = "board-f411")]
    #[task(binds = OTG_FS, priority = 2, shared = [link, sampler, timer, presence, control])]
    fn usb_rx(cx: usb_rx::Context) {
        let usb_rx::SharedResources {
            link,
            sampler,
            timer,
            presence,
            mut control,
            ..
        } = cx.shared;
        control.lock(|c| receive(link, sampler, timer, presence, c));
    }

    /// USART2 receive interrupt: read commands.
    #[cfg(feature = "qemu")]
    #[task(binds = USART2, priority = 2, shared = [link, sampler, timer, presence, control])]
    fn uart_rx(cx: uart_rx::Context) {
        let uart_rx::SharedResources {
            link,
            sampler,
            timer,
            presence,
            mut control,
            ..
        } = cx.shared;
        control.lock(|c| receive(link, sampler, timer, presence, c));
    }

    /// Frame every queued message and write it to the link; while no host reads, discard and count.
    #[task(priority = 1, shared = [link, sampler, presence], local = [rx, frame: [u8; MAX_FRAME_LEN] = [0; MAX_FRAME_LEN], cut: bool = false])]
    async fn writer(cx: writer::Context) {
        let writer::SharedResources {
            mut link,
            mut sampler,
            mut presence,
            ..
        } = cx.shared;
        let writer::LocalResources { rx, frame, cut, .. } = cx.local;
        while let Ok(out) = rx.recv().await {
            if out.is_batch() {
                BATCHES.release();
            }
            let n = out.samples();
            if !presence.lock(|p| p.is_present()) {
                sampler.lock(|s| s.count_dropped_in(out.run, n));
                probe(&mut link, &mut presence);
                continue;
            }
            // A frame abandoned half-way is closed with a delimiter first: the host then loses
            // (and counts as corrupt) that frame only.
            if *cut {
                if send(&mut link, &[0]).await == 1 {
                    *cut = false;
                } else {
                    sampler.lock(|s| s.count_dropped_in(out.run, n));
                    host_gone(&mut link, &mut presence, cut);
                    continue;
                }
            }
            let Ok(bytes) = protocol::encode(&out.msg, frame) else {
                // Cannot happen: MAX_FRAME_LEN bounds every message (tested in the core).
                sampler.lock(|s| s.count_dropped_in(out.run, n));
                continue;
            };
            let len = bytes.len();
            let written = send(&mut link, bytes).await;
            if written < len {
                sampler.lock(|s| s.count_dropped_in(out.run, n));
                *cut = written > 0;
                host_gone(&mut link, &mut presence, cut);
            }
        }
    }

    /// The link made no progress for the timeout: the host is absent. Throw away what the link
    /// still buffers (it would reach a later host stale) and close the frame cut there.
    fn host_gone(
        link: &mut impl rtic::Mutex<T = board::Link>,
        presence: &mut impl rtic::Mutex<T = Presence>,
        cut: &mut bool,
    ) {
        if presence.lock(|p| p.on_timeout()) {
            link.lock(|l| l.discard_pending());
            *cut = true;
            defmt::warn!("host not reading: discarding until it is back");
        }
    }

    /// While the host is absent: one step of the probe that finds it back (see
    /// `jdbb_core::link::Presence`).
    fn probe(
        link: &mut impl rtic::Mutex<T = board::Link>,
        presence: &mut impl rtic::Mutex<T = Presence>,
    ) {
        let drained = link.lock(|l| l.drained());
        if presence.lock(|p| p.probe_step(drained)) == ProbeStep::Send
            && link.lock(|l| l.write(&[0])) == 1
        {
            presence.lock(|p| p.probe_sent());
        }
    }

    /// Write `bytes` to the link, waiting (not spinning) while it is full, up to the timeout
    /// without progress; returns how many were written.
    async fn send(link: &mut impl rtic::Mutex<T = board::Link>, bytes: &[u8]) -> usize {
        let mut off = 0;
        let mut idle_us = 0;
        while off < bytes.len() {
            let n = link.lock(|l| l.write(&bytes[off..]));
            off += n;
            if off == bytes.len() {
                break;
            }
            idle_us = if n == 0 { idle_us + LINK_POLL_US } else { 0 };
            if idle_us > LINK_TIMEOUT_US {
                break;
            }
            Mono::delay(LINK_POLL_US.micros_at_least()).await; // ≥ 1 tick
        }
        off
    }

    /// A reply (not a batch: it does not take a place of the batch quota).
    fn reply(msg: DeviceMsg) -> Outgoing {
        Outgoing { run: 0, msg }
    }

    fn info(timer: &SampleTimer, sampler: &Sampler, control: &State) -> DeviceInfo {
        DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: FIRMWARE_VERSION,
            board: board::BOARD,
            sample_rate_hz: timer.rate_hz(),
            sampling: timer.is_running(),
            calibration: control.cal,
            chip_id: control.chip_id,
            reset_cause: control.reset_cause,
            index: sampler.index_status(),
            overruns: sampler.overruns(),
            clock: control.clock,
            calibration_kept: control.kept,
            unhandled_irq: control.unhandled_irq,
            index_disabled: board::index_disabled(),
        }
    }

    /// Service the link: greet a host that just configured the device, then drain the receiver and
    /// act on every complete command frame.
    fn receive(
        mut link: impl rtic::Mutex<T = board::Link>,
        mut sampler: impl rtic::Mutex<T = Sampler>,
        mut timer: impl rtic::Mutex<T = SampleTimer>,
        mut presence: impl rtic::Mutex<T = Presence>,
        control: &mut Control,
    ) {
        let mut buf = [0u8; 64];
        loop {
            let (n, change) = link.lock(|l| {
                let n = if l.poll() { l.read(&mut buf) } else { 0 };
                (n, l.take_change())
            });
            let Control { decoder, state } = &mut *control;
            match change {
                Some(true) => {
                    presence.lock(|p| p.on_host_activity());
                    let greeting =
                        DeviceMsg::Hello(Hello::of(&current_info(&mut timer, &mut sampler, state)));
                    if state.reply_tx.try_send(reply(greeting)).is_err() {
                        defmt::warn!("queue full: greeting dropped");
                    }
                }
                Some(false) => {
                    presence.lock(|p| p.on_timeout());
                }
                None => {}
            }
            if n == 0 {
                break;
            }
            presence.lock(|p| p.on_host_activity());
            super::LAST_COMMAND.store(Mono::now().ticks(), core::sync::atomic::Ordering::Relaxed);
            decoder.feed::<Command>(&buf[..n], |cmd| {
                let reply_msg = execute(cmd, &mut sampler, &mut timer, state);
                if state.reply_tx.try_send(reply(reply_msg)).is_err() {
                    defmt::warn!("queue full: reply dropped");
                }
            });
        }
    }

    fn current_info(
        timer: &mut impl rtic::Mutex<T = SampleTimer>,
        sampler: &mut impl rtic::Mutex<T = Sampler>,
        control: &State,
    ) -> DeviceInfo {
        timer.lock(|t| sampler.lock(|s| info(t, s, control)))
    }

    /// Carry out one command; returns the reply.
    fn execute(
        cmd: Result<Command, FrameError>,
        sampler: &mut impl rtic::Mutex<T = Sampler>,
        timer: &mut impl rtic::Mutex<T = SampleTimer>,
        control: &mut State,
    ) -> DeviceMsg {
        let cmd = match cmd {
            Ok(c) => c,
            Err(e) => {
                defmt::warn!("bad command frame: {}", e);
                return DeviceMsg::Rejected(CommandError::Malformed);
            }
        };
        defmt::debug!("command {}", cmd);
        match cmd {
            Command::Start => {
                timer.lock(|t| {
                    t.stop();
                    // Starting applies a rate change that was waiting for the next period: the
                    // sampler's clock must take the period the timer now runs at (else the
                    // samples' t_us would step by the old period).
                    t.start();
                    let (clock_hz, ticks) = (t.clock_hz(), t.period_ticks());
                    sampler.lock(|s| {
                        s.restart();
                        s.set_period(clock_hz, ticks);
                    });
                });
            }
            Command::Stop => {
                timer.lock(|t| t.stop());
                // Not sampling: the time to erase the calibration store's spare block, if due.
                upkeep::spawn().ok();
                let rest = sampler.lock(|s| s.take_batch().map(|b| (s.run(), b)));
                if let Some((run, rest)) = rest {
                    let n = rest.samples.len() as u32;
                    let queued = BATCHES.try_take()
                        && match control.reply_tx.try_send(Outgoing {
                            run,
                            msg: DeviceMsg::Batch(rest),
                        }) {
                            Ok(()) => true,
                            Err(_) => {
                                BATCHES.release();
                                false
                            }
                        };
                    if !queued {
                        sampler.lock(|s| s.count_dropped_in(run, n));
                    }
                }
            }
            Command::SetSampleRate(hz) => {
                if !(1..=MAX_SAMPLE_RATE_HZ).contains(&hz) {
                    return DeviceMsg::Rejected(CommandError::SampleRateOutOfRange);
                }
                timer.lock(|t| {
                    let ticks = t.set_rate(hz);
                    if !t.is_running() {
                        // Running, the sample task applies it at the next period boundary.
                        let clock_hz = t.clock_hz();
                        sampler.lock(|s| s.set_period(clock_hz, ticks));
                    }
                });
            }
            Command::SetCalibration(new) => {
                if let Err(e) = new.validate() {
                    return DeviceMsg::Rejected(CommandError::BadCalibration(e));
                }
                control.cal = new;
                // The trigonometry runs here, at the command's priority; the sample task waits
                // only for the copy.
                let kernel = Kernel::new(&new);
                sampler.lock(|s| s.set_kernel(kernel));
                // Kept for the next power-up (board: flash; QEMU: RAM), read back; the reply says
                // whether it was (the host reports "stored" only for `CalKept::Stored`).
                control.kept = control.cal_memory.store(&new);
                if control.kept != CalKept::Stored {
                    defmt::warn!(
                        "the calibration is in force but was not kept in flash: {}",
                        control.kept
                    );
                }
            }
            Command::Zero => sampler.lock(|s| s.zero_here()),
            Command::ArmIndex => sampler.lock(|s| s.arm_index()),
            Command::Ping(token) => return DeviceMsg::Pong(token),
            Command::GetInfo => {}
        }
        DeviceMsg::Info(current_info(timer, sampler, control))
    }
}
