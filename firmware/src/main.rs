//! The J-DBB firmware: an RTIC 2 application, the same on the real STM32F411 board and on QEMU's
//! netduinoplus2 (`--no-default-features --features qemu`); only [`jdbb_firmware::board`] differs.
//!
//! Tasks, highest priority first:
//!
//! | task      | priority | trigger                    | does |
//! |-----------|----------|----------------------------|------|
//! | `sample`  | 3        | TIM3 update (sample clock) | raw counts → `Sampler` (counts → D → batch); a full batch goes to the queue with `try_send`, or is dropped and counted |
//! | `pace`    | 3        | SysTick monotonic (qemu only) | pends TIM3 once per sample period: QEMU's TIM3 is not periodic |
//! | `index1/2`| 3        | TIM2/TIM5 CC3 (board only) | index pulse latched in hardware → `Encoder::on_index` |
//! | `usb_rx` / `uart_rx` | 2 | OTG_FS (board) / USART2 (qemu) | services the link, decodes commands, replies through the queue |
//! | `writer`  | 1        | queue (async)              | frames each message and writes it to the link without blocking the others |
//!
//! The queue holds [`QUEUE_LEN`] messages. The writer waits for a link that is momentarily full
//! (USB packets not yet read by the host) for up to [`LINK_TIMEOUT_US`] per frame, then drops the
//! frame and counts its samples; while it waits, the queue fills and the sample task drops whole
//! batches, counted too. The sample task never waits, allocates or panics.
//!
//! Sampling starts at power-up at [`DEFAULT_RATE_HZ`] (both boards, see `board::AUTO_START`); the
//! device sends `DeviceMsg::Info` first.
#![no_std]
#![no_main]

#[cfg(feature = "board-f411")]
use defmt_rtt as _;
#[cfg(feature = "qemu")]
use defmt_semihosting as _;
use panic_probe as _;

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

/// Messages the queue between the tasks and the writer holds.
pub const QUEUE_LEN: usize = 16;
/// Sample clock at power-up (Hz).
pub const DEFAULT_RATE_HZ: u32 = 1_000;
/// How long the writer waits for a full link before it drops a frame (µs).
pub const LINK_TIMEOUT_US: u32 = 20_000;
const LINK_POLL_US: u32 = 250;

#[rtic::app(device = stm32f4xx_hal::pac, peripherals = true, dispatchers = [SPI2, SPI3])]
mod app {
    use super::{Mono, DEFAULT_RATE_HZ, LINK_POLL_US, LINK_TIMEOUT_US, QUEUE_LEN};
    use jdbb_core::protocol::{
        self, Command, CommandError, Decoder, DeviceInfo, DeviceMsg, FrameError, MAX_FRAME_LEN,
        MAX_SAMPLE_RATE_HZ, PROTOCOL_VERSION,
    };
    use jdbb_core::sampler::{SampleClock, Sampler};
    use jdbb_core::Calibration;
    use jdbb_firmware::board::{self, SampleTimer};
    use jdbb_firmware::FIRMWARE_VERSION;
    use rtic_monotonics::systick::prelude::*;
    use rtic_sync::channel::{Receiver, Sender, TrySendError};
    use rtic_sync::make_channel;

    type Tx = Sender<'static, DeviceMsg, QUEUE_LEN>;
    type Rx = Receiver<'static, DeviceMsg, QUEUE_LEN>;

    #[shared]
    struct Shared {
        sampler: Sampler,
        timer: SampleTimer,
        link: board::Link,
        control: Control,
    }

    #[local]
    struct Local {
        encoders: board::Encoders,
        batch_tx: Tx,
        rx: Rx,
    }

    /// State of the command handler.
    pub struct Control {
        decoder: Decoder<MAX_FRAME_LEN>,
        cal: Calibration,
        reply_tx: Tx,
    }

    #[init]
    fn init(cx: init::Context) -> (Shared, Local) {
        let parts = board::init(cx.device, DEFAULT_RATE_HZ);
        Mono::start(cx.core.SYST, parts.systick_hz);
        let mut timer = parts.timer;
        let cal = Calibration::DEFAULT;
        let clock = SampleClock::new(timer.clock_hz(), timer.period_ticks());
        let mut sampler = Sampler::new(parts.initial_raw, &cal, clock, board::SIMULATED);
        if let Some(index) = parts.index_raw {
            sampler.on_index(0, index[0]);
            sampler.on_index(1, index[1]);
        }

        let (mut reply_tx, rx) = make_channel!(DeviceMsg, QUEUE_LEN);
        let batch_tx = reply_tx.clone();
        if board::AUTO_START {
            timer.start();
        }
        // The queue is empty: the greeting always fits.
        let _ = reply_tx.try_send(DeviceMsg::Info(info(&timer, &cal)));
        writer::spawn().ok();
        #[cfg(feature = "qemu")]
        pace::spawn().ok();
        defmt::info!(
            "jdbb firmware {}: {} Hz, sampling {}",
            board::BOARD,
            timer.rate_hz(),
            timer.is_running()
        );
        (
            Shared {
                sampler,
                timer,
                link: parts.link,
                control: Control {
                    decoder: Decoder::new(),
                    cal,
                    reply_tx,
                },
            },
            Local {
                encoders: parts.encoders,
                batch_tx,
                rx,
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// One tick of the sample clock: the whole on-chip sample path.
    #[task(binds = TIM3, priority = 3, shared = [sampler, timer], local = [encoders, batch_tx])]
    fn sample(cx: sample::Context) {
        let sample::SharedResources {
            mut sampler,
            mut timer,
            ..
        } = cx.shared;
        let encoders = cx.local.encoders;
        let tx = cx.local.batch_tx;
        timer.lock(|t| t.clear_update());
        sampler.lock(|s| {
            let raw = encoders.read(s.next_t_us());
            if let Some(batch) = s.sample(raw) {
                if let Err(TrySendError::Full(msg) | TrySendError::NoReceiver(msg)) =
                    tx.try_send(DeviceMsg::Batch(batch))
                {
                    s.count_dropped(samples_in(&msg));
                }
            }
        });
    }

    /// QEMU only: the sample clock (see `board::qemu`). Woken by every monotonic tick, pends the
    /// sample task's interrupt once for every period elapsed on the lossless TIM2 µs count (up to
    /// [`PACE_BURST`] per wake-up, yielding in between so each pend runs the sample task), so the
    /// samples keep their rate on average even though QEMU delivers SysTick ticks irregularly.
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
            while now_us() >= next_us && burst < PACE_BURST {
                next_us += period_us;
                rtic::pend(stm32f4xx_hal::pac::Interrupt::TIM3);
                yield_now().await;
                burst += 1;
            }
            // After a stall of the emulator (host busy) longer than a burst, resume from now: the
            // skipped periods are simply not sampled (sequence numbers stay contiguous; only the
            // simulated time runs slower than the host's clock) instead of flooding the queue.
            next_us = next_us.max(now_us().saturating_sub(PACE_BURST as u64 * period_us));
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

    /// Encoder 1's index pulse (board only).
    #[cfg(feature = "board-f411")]
    #[task(binds = TIM2, priority = 3, shared = [sampler])]
    fn index1(mut cx: index1::Context) {
        if let Some(raw) = board::take_index(0) {
            cx.shared.sampler.lock(|s| s.on_index(0, raw));
        }
    }

    /// Encoder 2's index pulse (board only).
    #[cfg(feature = "board-f411")]
    #[task(binds = TIM5, priority = 3, shared = [sampler])]
    fn index2(mut cx: index2::Context) {
        if let Some(raw) = board::take_index(1) {
            cx.shared.sampler.lock(|s| s.on_index(1, raw));
        }
    }

    /// USB interrupt: service the stack, then read commands.
    #[cfg(feature = "board-f411")]
    #[task(binds = OTG_FS, priority = 2, shared = [link, sampler, timer, control])]
    fn usb_rx(cx: usb_rx::Context) {
        let usb_rx::SharedResources {
            link,
            sampler,
            timer,
            mut control,
            ..
        } = cx.shared;
        control.lock(|c| receive(link, sampler, timer, c));
    }

    /// USART2 receive interrupt: read commands.
    #[cfg(feature = "qemu")]
    #[task(binds = USART2, priority = 2, shared = [link, sampler, timer, control])]
    fn uart_rx(cx: uart_rx::Context) {
        let uart_rx::SharedResources {
            link,
            sampler,
            timer,
            mut control,
            ..
        } = cx.shared;
        control.lock(|c| receive(link, sampler, timer, c));
    }

    /// Frame every queued message and write it to the link.
    #[task(priority = 1, shared = [link, sampler], local = [rx, frame: [u8; MAX_FRAME_LEN] = [0; MAX_FRAME_LEN], cut: bool = false])]
    async fn writer(cx: writer::Context) {
        let writer::SharedResources {
            mut link,
            mut sampler,
            ..
        } = cx.shared;
        let writer::LocalResources { rx, frame, cut, .. } = cx.local;
        while let Ok(msg) = rx.recv().await {
            let n = samples_in(&msg);
            // A frame abandoned half-way is closed with a delimiter first: the host then loses
            // (and counts as corrupt) that frame only.
            if *cut {
                if send(&mut link, &[0]).await == 1 {
                    *cut = false;
                } else {
                    sampler.lock(|s| s.count_dropped(n));
                    continue;
                }
            }
            let Ok(bytes) = protocol::encode(&msg, frame) else {
                // Cannot happen: MAX_FRAME_LEN bounds every message (tested in the core).
                sampler.lock(|s| s.count_dropped(n));
                continue;
            };
            let len = bytes.len();
            let written = send(&mut link, bytes).await;
            if written < len {
                sampler.lock(|s| s.count_dropped(n));
                *cut = written > 0;
                defmt::warn!("link full: frame dropped ({} samples)", n);
            }
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

    fn samples_in(msg: &DeviceMsg) -> u32 {
        match msg {
            DeviceMsg::Batch(b) => b.samples.len() as u32,
            _ => 0,
        }
    }

    fn info(timer: &SampleTimer, cal: &Calibration) -> DeviceInfo {
        DeviceInfo {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: FIRMWARE_VERSION,
            board: board::BOARD,
            sample_rate_hz: timer.rate_hz(),
            sampling: timer.is_running(),
            calibration: *cal,
        }
    }

    /// Drain the link's receiver and act on every complete command frame.
    fn receive(
        mut link: impl rtic::Mutex<T = board::Link>,
        mut sampler: impl rtic::Mutex<T = Sampler>,
        mut timer: impl rtic::Mutex<T = SampleTimer>,
        control: &mut Control,
    ) {
        let mut buf = [0u8; 64];
        loop {
            let n = link.lock(|l| if l.poll() { l.read(&mut buf) } else { 0 });
            if n == 0 {
                break;
            }
            let Control {
                decoder,
                cal,
                reply_tx,
            } = control;
            decoder.feed::<Command>(&buf[..n], |cmd| {
                let reply = execute(cmd, &mut sampler, &mut timer, cal, reply_tx);
                if reply_tx.try_send(reply).is_err() {
                    defmt::warn!("queue full: reply dropped");
                }
            });
        }
    }

    /// Carry out one command; returns the reply.
    fn execute(
        cmd: Result<Command, FrameError>,
        sampler: &mut impl rtic::Mutex<T = Sampler>,
        timer: &mut impl rtic::Mutex<T = SampleTimer>,
        cal: &mut Calibration,
        tx: &mut Tx,
    ) -> DeviceMsg {
        let cmd = match cmd {
            Ok(c) => c,
            Err(e) => {
                defmt::warn!("bad command frame: {}", e);
                return DeviceMsg::Rejected(CommandError::Malformed);
            }
        };
        defmt::info!("command {}", cmd);
        match cmd {
            Command::Start => {
                timer.lock(|t| {
                    t.stop();
                    sampler.lock(|s| s.restart());
                    t.start();
                });
            }
            Command::Stop => {
                timer.lock(|t| t.stop());
                if let Some(rest) = sampler.lock(|s| s.take_batch()) {
                    if let Err(TrySendError::Full(m) | TrySendError::NoReceiver(m)) =
                        tx.try_send(DeviceMsg::Batch(rest))
                    {
                        let n = samples_in(&m);
                        sampler.lock(|s| s.count_dropped(n));
                    }
                }
            }
            Command::SetSampleRate(hz) => {
                if !(1..=MAX_SAMPLE_RATE_HZ).contains(&hz) {
                    return DeviceMsg::Rejected(CommandError::SampleRateOutOfRange);
                }
                timer.lock(|t| {
                    let ticks = t.set_rate(hz);
                    let clock_hz = t.clock_hz();
                    sampler.lock(|s| s.set_period(clock_hz, ticks));
                });
            }
            Command::SetCalibration(new) => {
                if let Err(e) = new.validate() {
                    return DeviceMsg::Rejected(CommandError::BadCalibration(e));
                }
                *cal = new;
                sampler.lock(|s| s.set_calibration(&new));
            }
            Command::Zero => sampler.lock(|s| s.zero_here()),
            Command::Ping(token) => return DeviceMsg::Pong(token),
            Command::GetInfo => {}
        }
        DeviceMsg::Info(timer.lock(|t| info(t, cal)))
    }
}
