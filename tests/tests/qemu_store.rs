//! Issue 19 §2 on the QEMU firmware: the calibration store's erase is kept out of the streaming
//! path, and an erase that still happens while sampling never passes unseen.
//!
//! The QEMU build keeps the calibration in the board's store (`jdbb_core::store`) over a RAM flash
//! of two 1 KiB blocks (4 records each) whose erase holds the emulated CPU with every interrupt
//! masked for `ERASE_STALL_US` = 200 ms, as the F411's flash stalls every fetch for a sector
//! erase. At 5 kHz that is 1 000 sample periods.
//!
//! 1. Stores 1–8 while sampling: the log fills block 0, then moves to block 1, blank since power-up:
//!    no erase, not one sample lost.
//! 2. Store 9 finds block 1 full and block 0 (the spare) not erased: it erases in the command
//!    path. The stall shows in the stream: one sequence gap, equal to what the device reports it
//!    dropped and to `DeviceInfo.overruns`, with the time stamps skipping exactly gap × period.
//! 3. `Stop` erases the spare (block 1) ahead; after `Start`, stores 10–13 (the 13th moves to
//!    block 1) lose nothing.
//!
//! Issue 32 §1, with the RAM flash failing as the semihosting command line says
//! (`flash-fault=...`, the firmware's `FlashFault`): a store that fails is in the reply, and the
//! host says "stored" only for a record the device read back equal.
//!
//! - `protected`: every program sets WRPERR: `jdbb calibration send` fails, naming the reason;
//!   the calibration is in force (until the next power cycle), `DeviceInfo` says `WriteFailed`.
//! - `deaf`: programming reports success and changes nothing: only the device's read-back finds
//!   it (`ReadBackDiffers`), and the host reports it.
//! - `leftover`: an error flag set at power-up (as the ROM bootloader can leave it before a DFU
//!   `:leave`): the firmware clears the flags before every program, so the store succeeds.
mod common;

use common::collect_run;
use std::time::{Duration, Instant};

use jdbb::link::calibration::{connect, read_calibration, send_calibration};
use jdbb::link::stream::{Poll, SeqSample, Stream};
use jdbb::Error;
use jdbb_core::protocol::{CalKept, Command};
use jdbb_core::Calibration;
use jdbb_tests::{jdbb_bin, qemu_available, qemu_elf, Qemu};

const RATE_HZ: u32 = 5_000;
const PERIOD_US: u64 = 1_000_000 / RATE_HZ as u64;

fn cal(k: u32) -> Calibration {
    let mut c = Calibration::DEFAULT;
    c.l1_mm += 1e-3 * f64::from(k);
    c
}

/// Send `SetCalibration(cal(k))` and keep every sample until the device's Info reports it, then
/// 500 samples more (the stream after the store).
fn store<P: std::io::Read + std::io::Write>(
    stream: &mut Stream<P>,
    k: u32,
    got: &mut Vec<SeqSample>,
) {
    stream.send(&Command::SetCalibration(cal(k))).unwrap();
    let t0 = Instant::now();
    while stream.info().map(|i| i.calibration) != Some(cal(k)) {
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no Info after store {k}"
        );
        if stream.poll(|b| got.extend_from_slice(b)).unwrap() == Poll::Closed {
            panic!("QEMU closed the pty");
        }
    }
    got.extend(stream.collect(500, Duration::from_secs(60)).unwrap());
}

/// The sequence gaps in `got`: (index, samples skipped).
fn gaps(got: &[SeqSample]) -> Vec<(usize, u64)> {
    got.windows(2)
        .enumerate()
        .filter(|(_, w)| w[1].seq != w[0].seq + 1)
        .map(|(i, w)| (i, w[1].seq - w[0].seq - 1))
        .collect()
}

#[test]
fn stores_erase_ahead_and_an_erase_while_sampling_shows_as_an_exact_gap() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let (_qemu, pty) = Qemu::start_with_pty(&elf);
    let mut stream = Stream::open(pty.to_str().unwrap()).expect("open QEMU pty");
    assert!(
        stream.handshake(Duration::from_secs(30)).unwrap(),
        "the firmware never answered a ping"
    );
    stream.send(&Command::SetSampleRate(RATE_HZ)).unwrap();
    stream.send(&Command::Start).unwrap();
    let mut got = collect_run(&mut stream, 1_000, Duration::from_secs(60));

    // 1. Eight stores, no erase.
    for k in 1..=8 {
        store(&mut stream, k, &mut got);
    }
    let stats = *stream.stats();
    assert!(gaps(&got).is_empty(), "{:?}: {stats}", gaps(&got));
    assert_eq!((stats.lost, stats.device_dropped), (0, 0), "{stats}");
    assert_eq!(stream.info().unwrap().overruns, 0);

    // 2. The ninth erases block 0 in the command path: a stall, counted to the tick.
    let from = got.len();
    store(&mut stream, 9, &mut got);
    stream.send(&Command::GetInfo).unwrap();
    let t0 = Instant::now();
    while stream.info().is_none_or(|i| i.overruns == 0) {
        assert!(t0.elapsed() < Duration::from_secs(30), "no Info");
        stream.poll(|b| got.extend_from_slice(b)).unwrap();
    }
    let info = *stream.info().unwrap();
    let stats = *stream.stats();
    let g = gaps(&got[from..]);
    assert_eq!(g.len(), 1, "one stall, one gap: {g:?}");
    let (at, skipped) = (from + g[0].0, g[0].1);
    // 200 ms of stall at 5 kHz: 1 000 periods, less the pacer's catch-up burst (32 samples taken
    // late but at their own ticks' times).
    assert!(
        (900..=1_000).contains(&skipped),
        "the stall skipped {skipped} samples"
    );
    assert_eq!(
        got[at + 1].sample.t_us - got[at].sample.t_us,
        (skipped + 1) * PERIOD_US,
        "time skips exactly the missed periods"
    );
    assert_eq!(
        stats.device_dropped, skipped,
        "the device reports the gap: {stats}"
    );
    assert_eq!(stats.lost, skipped, "{stats}");
    assert_eq!(u64::from(info.overruns), skipped, "DeviceInfo.overruns");
    println!(
        "erase while sampling: {skipped} samples skipped at seq {}, t_us {} → {}, dropped {}, overruns {}",
        got[at].seq,
        got[at].sample.t_us,
        got[at + 1].sample.t_us,
        stats.device_dropped,
        info.overruns
    );

    // 3. Stop erases block 1 ahead; then four stores (the last moves to block 1) lose nothing.
    stream
        .request(&Command::Stop, Duration::from_secs(10))
        .unwrap()
        .unwrap();
    // The erase runs after the reply (the upkeep task), once the link has been quiet for 300 ms
    // (emulated; idle time is skipped under `-icount sleep=off`); a ping answered after that
    // means it is over.
    std::thread::sleep(Duration::from_secs(2));
    assert!(stream.handshake(Duration::from_secs(30)).unwrap());
    stream.send(&Command::Start).unwrap();
    let mut run = collect_run(&mut stream, 500, Duration::from_secs(60));
    let dropped_before = stream.stats().device_dropped;
    for k in 10..=13 {
        store(&mut stream, k, &mut run);
    }
    assert!(gaps(&run).is_empty(), "{:?}", gaps(&run));
    assert_eq!(
        stream.stats().device_dropped,
        dropped_before,
        "{}",
        stream.stats()
    );
    assert_eq!(run[0].seq, 0, "a new run");
    println!(
        "after Stop (spare erased ahead): stores 10–13, {} samples, no gap",
        run.len()
    );
}

#[test]
fn a_store_that_fails_is_reported_and_never_called_stored() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let t = Duration::from_secs(10);

    // Write-protected: the command line reports the failure and its reason, not "stored".
    let (qemu, pty) = Qemu::start_with_flash_fault(&elf, "protected");
    let port = pty.to_str().unwrap().to_string();
    {
        let mut stream = Stream::open(&port).expect("open QEMU pty");
        connect(&mut stream, Duration::from_secs(30)).expect("the firmware answers a ping");
        assert_eq!(
            read_calibration(&mut stream, t).unwrap().calibration_kept,
            CalKept::NotSent
        );
    }
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cal.toml");
    std::fs::write(
        &file,
        jdbb::instrument::file::calibration_toml(&cal(1), &[]),
    )
    .unwrap();
    let o = std::process::Command::new(jdbb_bin())
        .args(["calibration", "send", "--port", &port, "--file"])
        .arg(&file)
        .output()
        .expect("run jdbb");
    let (out, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    assert_eq!(o.status.code(), Some(1), "{out}\n{err}");
    assert!(err.contains("did NOT store it"), "{err}");
    assert!(err.contains("programming the flash failed"), "{err}");
    assert!(!out.contains("stored"), "{out}");
    // In force, not kept: the device says so to anyone who asks.
    let mut stream = Stream::open(&port).expect("open QEMU pty");
    connect(&mut stream, Duration::from_secs(30)).unwrap();
    let info = read_calibration(&mut stream, t).unwrap();
    assert_eq!(info.calibration, cal(1));
    assert_eq!(info.calibration_kept, CalKept::WriteFailed);
    println!("write-protected flash: {}", err.trim());
    drop((stream, qemu));

    // Programming that silently does nothing: only the read-back finds it.
    let (qemu, pty) = Qemu::start_with_flash_fault(&elf, "deaf");
    let mut stream = Stream::open(pty.to_str().unwrap()).expect("open QEMU pty");
    connect(&mut stream, Duration::from_secs(30)).unwrap();
    match send_calibration(&mut stream, &cal(2), t) {
        Err(e @ Error::NotStored { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("reads back different"), "{msg}");
        }
        other => panic!("a store that did not take was reported as {other:?}"),
    }
    drop((stream, qemu));

    // An error flag left set from before the firmware started: cleared before the program, so
    // the store succeeds (and is read back equal).
    let (_qemu, pty) = Qemu::start_with_flash_fault(&elf, "leftover");
    let mut stream = Stream::open(pty.to_str().unwrap()).expect("open QEMU pty");
    connect(&mut stream, Duration::from_secs(30)).unwrap();
    let report =
        send_calibration(&mut stream, &cal(3), t).expect("stored despite the leftover flag");
    assert_eq!(report.reply.calibration_kept, CalKept::Stored);
    assert_eq!(report.read_back.calibration_kept, CalKept::Stored);
}
