//! End to end: the QEMU build of the firmware (simulated circular test, same sample path as the
//! real board) streams over USART2 → QEMU pty → the host's `jdbb::link::stream` decoder. At least 10 000
//! consecutive samples must arrive with zero loss and no corrupt frame, and every D computed on the
//! chip must agree with the host's f64 reference for the same counts within the on-chip budget.
mod common;

use common::collect_run;
use std::time::Duration;

use jdbb::link::stream::Stream;
use jdbb_core::protocol::{Command, Status};
use jdbb_tests::{chip_error_mm, qemu_available, qemu_elf, Qemu};

const N: usize = 10_000;

#[test]
fn qemu_firmware_streams_10000_samples_without_loss_and_chip_d_matches_host() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let (_qemu, pty) = Qemu::start_with_pty(&elf);
    let mut stream = Stream::open(pty.to_str().unwrap()).expect("open QEMU pty");
    // Until QEMU notices the pty was opened, what the firmware writes is dropped.
    assert!(
        stream.handshake(Duration::from_secs(30)).unwrap(),
        "the firmware never answered a ping"
    );
    // Restart sampling so the sequence starts at 0 from our point of view, at 5 kHz so the test
    // takes about two seconds of emulated time.
    stream.send(&Command::SetSampleRate(5_000)).unwrap();
    stream.send(&Command::Start).unwrap();
    let got = collect_run(&mut stream, N, Duration::from_secs(120));
    let stats = *stream.stats();
    println!("end to end: {stats}");
    assert!(
        got.len() >= N,
        "only {} samples arrived: {stats}",
        got.len()
    );
    assert_eq!(stats.corrupt.total(), 0, "corrupt frames: {stats}");
    assert_eq!(stats.lost, 0, "samples lost: {stats}");
    assert_eq!(stats.device_dropped, 0, "device dropped samples: {stats}");
    assert_eq!(stats.resets, 0, "device reset: {stats}");

    let info = stream.info().expect("the device announced itself");
    assert_eq!(info.protocol_version, jdbb_core::protocol::PROTOCOL_VERSION);
    let cal = info.calibration;
    let mut worst_nm = 0.0f64;
    for pair in got.windows(2) {
        assert_eq!(pair[1].seq, pair[0].seq + 1, "sequence gap");
        // 5 kHz asked for while running, applied by Start: 200 µs apart from the first sample.
        assert_eq!(
            pair[1].sample.t_us - pair[0].sample.t_us,
            200,
            "seq {}: samples not 200 µs apart",
            pair[1].seq
        );
    }
    for s in &got {
        let smp = &s.sample;
        assert!(smp.status.has(Status::SIMULATED));
        let (err, budget) = chip_error_mm(&cal, smp);
        assert!(
            err <= budget,
            "seq {}: chip {} mm, error {:.2} nm > budget {:.2} nm",
            s.seq,
            smp.d_mm,
            err * 1e6,
            budget * 1e6
        );
        worst_nm = worst_nm.max(err * 1e6);
        // The simulated test is an ideal 90 mm circle: D within one count's step of it.
        assert!(
            (smp.d_mm - 90.0).abs() < 0.05,
            "seq {}: D = {} mm",
            s.seq,
            smp.d_mm
        );
    }
    println!(
        "end to end: {} samples, max |D_chip − D_host| = {worst_nm:.2} nm",
        got.len()
    );
}
