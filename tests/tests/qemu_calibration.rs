//! Issue 9 §5 on the QEMU firmware: `jdbb calibration send` writes a non-trivial calibration (the
//! issue's example instrument: L1 23 µm long, encoder 2's zero 60″ off, axes 90″ skewed, encoder
//! 1's disc 40″ eccentric) over the pty, the device's Info reads it back bit for bit, and every D
//! computed on the chip afterwards is the host's f64 reference of *that* calibration within the
//! on-chip budget (and not the nominal instrument's D).
mod common;

use common::collect_run;
use std::process::Command as Proc;
use std::time::Duration;

use jdbb::instrument::file::calibration_toml;
use jdbb::instrument::ARCSEC_RAD;
use jdbb::link::calibration::{connect, differences, read_calibration, send_calibration};
use jdbb::link::stream::Stream;
use jdbb_core::protocol::Command;
use jdbb_core::{geometry, Calibration};
use jdbb_tests::{chip_error_mm, jdbb_bin, qemu_available, qemu_elf, Qemu};

fn example() -> Calibration {
    let mut c = Calibration::DEFAULT;
    c.l1_mm += 0.023;
    c.enc2.zero_offset_rad = 60.0 * ARCSEC_RAD;
    c.axes_skew_rad = 90.0 * ARCSEC_RAD;
    c.enc1.eccentricity_rad = 40.0 * ARCSEC_RAD;
    c.enc1.eccentricity_phase_rad = 0.7;
    c
}

#[test]
fn a_sent_calibration_is_read_back_and_applied_to_every_sample() {
    let elf = qemu_elf("jdbb-firmware");
    if !qemu_available(&elf) {
        return;
    }
    let (_qemu, pty) = Qemu::start_with_pty(&elf);
    let port = pty.to_str().unwrap();
    let cal = example();
    let mut stream = Stream::open(port).expect("open QEMU pty");
    // Until QEMU notices the pty was opened, what the firmware writes is dropped.
    connect(&mut stream, Duration::from_secs(30)).expect("the firmware answers a ping");
    let before = read_calibration(&mut stream, Duration::from_secs(10)).unwrap();
    assert_eq!(before.calibration, Calibration::DEFAULT);

    // The library call: SetCalibration's Info and a fresh GetInfo both report it bit for bit.
    let report = send_calibration(&mut stream, &cal, Duration::from_secs(10)).unwrap();
    assert!(differences(&cal, &report.reply.calibration).is_empty());
    assert!(differences(&cal, &report.read_back.calibration).is_empty());

    // Every on-chip D is the calibrated D.
    stream.send(&Command::SetSampleRate(5_000)).unwrap();
    stream.send(&Command::Start).unwrap();
    let got = collect_run(&mut stream, 5_000, Duration::from_secs(120));
    let stats = *stream.stats();
    assert!(got.len() >= 5_000, "only {} samples: {stats}", got.len());
    assert_eq!((stats.lost, stats.resets), (0, 0), "{stats}");
    let (mut worst_nm, mut least_shift_um) = (0.0f64, f64::INFINITY);
    for s in &got {
        let (err, budget) = chip_error_mm(&cal, &s.sample);
        assert!(
            err <= budget,
            "seq {}: chip {} mm, error {:.2} nm > budget {:.2} nm",
            s.seq,
            s.sample.d_mm,
            err * 1e6,
            budget * 1e6
        );
        worst_nm = worst_nm.max(err * 1e6);
        let nominal = geometry::distance_mm(&Calibration::DEFAULT, s.sample.enc1, s.sample.enc2);
        least_shift_um = least_shift_um.min((s.sample.d_mm - nominal).abs() * 1e3);
    }
    // L1 alone moves D by 23 µm × (L1 + L2 cos φ)/D ≥ ~12 µm over the working range.
    assert!(
        least_shift_um > 5.0,
        "D is the nominal one: {least_shift_um} µm"
    );
    stream.send(&Command::Stop).unwrap();
    drop(stream);
    println!(
        "calibrated on chip: {} samples, max |D_chip − D_host| = {worst_nm:.3} nm, D moved ≥ {least_shift_um:.1} µm from the nominal",
        got.len()
    );

    // The command line, on the same device: send the file (back to the default), read back.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("cal.toml");
    std::fs::write(&file, calibration_toml(&Calibration::DEFAULT, &[])).unwrap();
    let o = Proc::new(jdbb_bin())
        .args(["calibration", "send", "--port", port, "--file"])
        .arg(&file)
        .output()
        .expect("run jdbb");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("read back: identical"), "{out}");
    println!("{out}");
}
