//! `jdbb record` / `jdbb live` / `jdbb devices` from the outside: bad ports and outputs give a
//! clear error and a nonzero exit, and a fake device on a pty (the same kind of port QEMU gives)
//! streams into a CSV that survives Ctrl-C, SIGKILL and an unplug.
#![cfg(unix)]

use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsRawFd, FromRawFd};
use std::path::Path;
use std::process::{Child, Command as Proc, Stdio};
use std::time::{Duration, Instant};

use jdbb_core::protocol::{
    self, Board, Command, Decoder, DeviceInfo, DeviceMsg, IndexStatus, Reference, ResetCause,
    Sample, SampleBatch, Status, BATCH_LEN, MAX_FRAME_LEN,
};
mod common;
use common::{jdbb, stderr};

const JDBB: &str = env!("CARGO_BIN_EXE_jdbb");

/// A pseudo-terminal pair: the test plays the device on the master side, jdbb opens the slave
/// path like QEMU's /dev/pts/N.
struct Pty {
    master: File,
    slave_path: String,
    /// Answer commands other than Ping (as the firmware does); false plays a device that does not.
    answers: bool,
}

impl Pty {
    fn new() -> Pty {
        // SAFETY: plain libc calls on a descriptor we own; every result is checked.
        unsafe {
            // O_CLOEXEC: no jdbb spawned by a test running in parallel may inherit the master,
            // or closing it here would not hang up the slave.
            let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC);
            assert!(fd >= 0, "posix_openpt");
            assert_eq!(libc::grantpt(fd), 0, "grantpt");
            assert_eq!(libc::unlockpt(fd), 0, "unlockpt");
            let mut name = [0 as libc::c_char; 128];
            assert_eq!(libc::ptsname_r(fd, name.as_mut_ptr(), name.len()), 0);
            let slave_path = std::ffi::CStr::from_ptr(name.as_ptr())
                .to_string_lossy()
                .into_owned();
            // Raw mode from the start, so no byte written before jdbb opens the slave is cooked.
            let mut t: libc::termios = std::mem::zeroed();
            assert_eq!(libc::tcgetattr(fd, &mut t), 0);
            libc::cfmakeraw(&mut t);
            assert_eq!(libc::tcsetattr(fd, libc::TCSANOW, &t), 0);
            Pty {
                master: File::from_raw_fd(fd),
                slave_path,
                answers: true,
            }
        }
    }

    /// Read what jdbb sent until `want` arrives, answering each command as the firmware does
    /// (Pong to a Ping, Info to the rest); panic after `timeout`.
    /// Returns every command seen up to and including `want`.
    fn expect_command(&mut self, want: Command, timeout: Duration) -> Vec<Result<Command, ()>> {
        self.expect_command_after(want, timeout, &[])
    }

    /// [`Pty::expect_command`], sending `before_answer` (batches of the run going on) just
    /// before the answer to `want`.
    fn expect_command_after(
        &mut self,
        want: Command,
        timeout: Duration,
        before_answer: &[u8],
    ) -> Vec<Result<Command, ()>> {
        let t0 = Instant::now();
        let mut dec = Decoder::<MAX_FRAME_LEN>::new();
        let mut seen = Vec::new();
        while t0.elapsed() < timeout {
            let mut pfd = libc::pollfd {
                fd: self.master.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            // SAFETY: one valid pollfd.
            if unsafe { libc::poll(&mut pfd, 1, 50) } <= 0 {
                continue;
            }
            let mut buf = [0u8; 256];
            let n = self.master.read(&mut buf).expect("read pty master");
            let mut new = Vec::new();
            dec.feed::<Command>(&buf[..n], |c| new.push(c));
            for c in new {
                if c == Ok(want) {
                    self.send(before_answer);
                }
                match c {
                    Ok(Command::Ping(token)) => self.send(&encode(&DeviceMsg::Pong(token))),
                    _ if self.answers => self.send(&encode(&DeviceMsg::Info(info()))),
                    _ => {}
                }
                seen.push(c.map_err(|_| ()));
            }
            if seen.contains(&Ok(want)) {
                return seen;
            }
        }
        panic!("jdbb did not send {want:?} within {timeout:?}; got {seen:?}");
    }

    /// Every command jdbb sends until it closes the port (its exit), answering as the firmware
    /// does; panics after `timeout`.
    fn commands_until_closed(&mut self, timeout: Duration) -> Vec<Result<Command, ()>> {
        let t0 = Instant::now();
        let mut dec = Decoder::<MAX_FRAME_LEN>::new();
        let mut seen = Vec::new();
        while t0.elapsed() < timeout {
            let mut pfd = libc::pollfd {
                fd: self.master.as_raw_fd(),
                events: libc::POLLIN,
                revents: 0,
            };
            // SAFETY: one valid pollfd.
            if unsafe { libc::poll(&mut pfd, 1, 50) } <= 0 {
                continue;
            }
            if pfd.revents & libc::POLLIN == 0 {
                return seen; // hung up: the slave side is closed
            }
            let mut buf = [0u8; 256];
            let n = match self.master.read(&mut buf) {
                Ok(0) | Err(_) => return seen,
                Ok(n) => n,
            };
            let mut new = Vec::new();
            dec.feed::<Command>(&buf[..n], |c| new.push(c));
            for c in new {
                if let Ok(Command::Ping(token)) = c {
                    self.send(&encode(&DeviceMsg::Pong(token)));
                }
                seen.push(c.map_err(|_| ()));
            }
        }
        panic!("jdbb did not close the port within {timeout:?}; sent {seen:?}");
    }

    fn send(&mut self, bytes: &[u8]) {
        self.master.write_all(bytes).expect("write pty master");
        self.master.flush().unwrap();
    }
}

fn sample(seq: u64) -> Sample {
    Sample {
        t_us: 100 * seq,
        enc1: 1000 - seq as i64,
        enc2: -(seq as i64) * 3,
        d_mm: 99.9 + 1e-6 * seq as f64 + 1.234_567e-8,
        status: Status(Status::SIMULATED),
    }
}

fn info() -> DeviceInfo {
    DeviceInfo {
        protocol_version: protocol::PROTOCOL_VERSION,
        firmware_version: [0, 1, 0],
        board: Board::QemuNetduinoPlus2,
        sample_rate_hz: 10_000,
        sampling: true,
        calibration: jdbb_core::Calibration::DEFAULT,
        chip_id: [0; 12],
        reset_cause: ResetCause(ResetCause::POWER),
        index: [IndexStatus {
            reference: Reference::None,
            armed: true,
            passes: 0,
            last_pass_count: 0,
        }; 2],
        overruns: 0,
        clock: jdbb_core::protocol::ClockSource::Emulated,
        calibration_kept: jdbb_core::protocol::CalKept::NotSent,
        unhandled_irq: None,
        index_disabled: [false; 2],
    }
}

fn encode(msg: &DeviceMsg) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    protocol::encode(msg, &mut buf).unwrap().to_vec()
}

/// The work file of a recording to `out`, where the samples are while it runs.
fn partial(out: &Path) -> std::path::PathBuf {
    let mut s = out.as_os_str().to_owned();
    s.push(".partial");
    s.into()
}

fn batch_frame(seq: u32) -> Vec<u8> {
    let mut samples = heapless::Vec::new();
    for i in 0..BATCH_LEN as u64 {
        samples.push(sample(u64::from(seq) + i)).unwrap();
    }
    let msg = DeviceMsg::Batch(SampleBatch {
        seq,
        dropped: 0,
        samples,
    });
    let mut buf = [0u8; MAX_FRAME_LEN];
    protocol::encode(&msg, &mut buf).unwrap().to_vec()
}

/// How long to wait for a command from `jdbb` before calling it a hang: generous, for a debug
/// build starting on busy cores; the wait ends as soon as the command arrives.
const WAIT: Duration = Duration::from_secs(60);

fn spawn(args: &[&str]) -> Child {
    Proc::new(JDBB)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn jdbb")
}

/// Data lines of the CSV (header checked), once it holds `n` of them; panics after 60 s (a hang,
/// generous for a debug build on busy cores: it returns as soon as the lines are there).
fn wait_for_lines(path: &Path, n: usize) -> Vec<String> {
    let t0 = Instant::now();
    loop {
        let text = std::fs::read_to_string(path).unwrap_or_default();
        let lines: Vec<String> = text
            .lines()
            .skip(1)
            .filter(|l| !l.starts_with("# instrument_serial:"))
            .map(str::to_string)
            .collect();
        if lines.len() >= n {
            assert!(text.starts_with("seq,t_us,enc1,enc2,d_mm\n"), "{text:.80}");
            return lines;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "CSV has {} of {n} lines",
            lines.len()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// The CSV must be whole lines, each the sample with that sequence number, and nothing else.
fn check_csv(path: &Path, want_seqs: &[u64]) {
    let text = std::fs::read_to_string(path).unwrap();
    assert!(
        text.ends_with('\n'),
        "torn last line: {:?}",
        text.lines().last()
    );
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("seq,t_us,enc1,enc2,d_mm"));
    // The instrument's serial (the fake device's chip ID is all zero), once the device said it.
    let (serial, rows): (Vec<&str>, Vec<&str>) =
        lines.partition(|l| l.starts_with("# instrument_serial:"));
    assert!(
        serial.len() <= 1
            && serial
                .iter()
                .all(|l| *l == "# instrument_serial: 000000000000000000000000"),
        "{serial:?}"
    );
    assert_eq!(rows.len(), want_seqs.len());
    for (row, &seq) in rows.iter().zip(want_seqs) {
        let f: Vec<&str> = row.split(',').collect();
        assert_eq!(f.len(), 5, "{row}");
        let s = sample(seq);
        assert_eq!(f[0].parse::<u64>().unwrap(), seq, "{row}");
        assert_eq!(f[1].parse::<u64>().unwrap(), s.t_us, "{row}");
        assert_eq!(f[2].parse::<i64>().unwrap(), s.enc1, "{row}");
        assert_eq!(f[3].parse::<i64>().unwrap(), s.enc2, "{row}");
        // 7 decimals: within half of 0.1 nm of the value sent.
        let d: f64 = f[4].parse().unwrap();
        assert!((d - s.d_mm).abs() <= 0.5e-7 + 1e-12, "{row} vs {}", s.d_mm);
        assert_eq!(f[4].split('.').nth(1).map(str::len), Some(7), "{row}");
    }
}

#[test]
fn no_such_port_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.csv");
    let port = "/dev/ttyJDBB-does-not-exist";
    for args in [
        vec!["record", "--port", port, "--out", out.to_str().unwrap()],
        vec!["live", "--port", port, "--seconds", "1"],
    ] {
        let o = jdbb(&args);
        assert!(!o.status.success());
        let e = stderr(&o);
        assert!(e.contains(port) && e.contains("no such port"), "{e}");
        assert!(e.contains("jdbb devices"), "{e}");
        assert!(!e.contains("panicked"), "{e}");
    }
    assert!(!out.exists(), "no empty recording left behind");
}

#[test]
fn a_port_in_use_says_so_not_dialout() {
    let pty = Pty::new();
    // Another program holds the port (serialport opens it exclusively, as a terminal would).
    let held = serialport::new(&pty.slave_path, 115_200).open().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.csv");
    let o = jdbb(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("in use by another program"), "{e}");
    assert!(!e.contains("dialout") && !e.contains("panicked"), "{e}");
    assert!(!out.exists());
    drop(held);
}

#[test]
fn a_port_a_terminal_holds_without_the_exclusive_lock_is_refused() {
    let pty = Pty::new();
    // As minicom or screen hold it: opened plainly (they lock with UUCP lock files), so the
    // port's own exclusive open would succeed and both programs would read the device's bytes.
    let held = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&pty.slave_path)
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.csv");
    let o = jdbb(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--seconds",
        "2",
    ]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(
        e.contains(&format!("(PID {})", std::process::id())) && e.contains("in use by"),
        "{e}"
    );
    assert!(!out.exists());
    drop(held);
}

#[test]
fn port_that_is_not_a_device_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.csv");
    let dir_s = dir.path().to_str().unwrap().to_string();
    for (port, want) in [
        ("/etc/passwd", "regular file"),
        (dir_s.as_str(), "directory"),
        ("/dev/null", "not a serial device"),
    ] {
        for args in [
            vec!["record", "--port", port, "--out", out.to_str().unwrap()],
            vec!["live", "--port", port],
        ] {
            let o = jdbb(&args);
            assert!(!o.status.success(), "{args:?}");
            let e = stderr(&o);
            assert!(e.contains(port) && e.contains(want), "{args:?}: {e}");
            assert!(!e.contains("panicked"), "{e}");
        }
    }
}

#[test]
fn unwritable_output_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let pty = Pty::new();
    let missing = dir.path().join("no/such/dir/x.csv");
    let dir_s = dir.path().to_str().unwrap().to_string();
    for (out, want) in [
        (missing.to_str().unwrap(), "cannot create"),
        (dir_s.as_str(), "is a directory, not a regular file"),
    ] {
        let o = jdbb(&[
            "record",
            "--port",
            &pty.slave_path,
            "--out",
            out,
            "--seconds",
            "1",
        ]);
        assert!(!o.status.success());
        let e = stderr(&o);
        assert!(e.contains(want) && e.contains(out), "{e}");
    }
}

#[test]
fn a_bad_port_leaves_an_existing_file_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("precious.csv");
    std::fs::write(&out, "precious data\n").unwrap();
    let port = "/dev/ttyJDBB-mistyped";
    for force in [false, true] {
        let mut args = vec!["record", "--port", port, "--out", out.to_str().unwrap()];
        if force {
            args.push("--force");
        }
        let o = jdbb(&args);
        assert!(!o.status.success(), "{args:?}");
        let e = stderr(&o);
        if force {
            // The port is opened before anything is written.
            assert!(e.contains(port) && e.contains("no such port"), "{e}");
        } else {
            assert!(e.contains("exists") && e.contains("--force"), "{e}");
            assert_eq!(o.status.code(), Some(2));
        }
        assert_eq!(
            std::fs::read_to_string(&out).unwrap(),
            "precious data\n",
            "{args:?}"
        );
        assert!(!partial(&out).exists(), "no work file left");
    }
}

#[test]
fn links_and_devices_are_never_written_through() {
    let dir = tempfile::tempdir().unwrap();
    let target = dir.path().join("target.csv");
    std::fs::write(&target, "theirs\n").unwrap();
    let link = dir.path().join("link.csv");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let pty = Pty::new();
    for (out, want) in [
        (link.to_str().unwrap(), "symbolic link"),
        ("/dev/null", "not a regular file"),
    ] {
        for port in ["/dev/ttyJDBB-mistyped", pty.slave_path.as_str()] {
            let o = jdbb(&["record", "--port", port, "--out", out, "--force"]);
            assert!(!o.status.success());
            let e = stderr(&o);
            assert!(e.contains(want) && e.contains(out), "{e}");
        }
    }
    assert!(link.symlink_metadata().unwrap().file_type().is_symlink());
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "theirs\n");
}

#[test]
fn bad_option_values_are_refused() {
    let o = jdbb(&["live", "--port", "/dev/null", "--seconds=-1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--seconds"), "{}", stderr(&o));
    let o = jdbb(&["live", "--port", "/dev/null", "--rate", "0"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--rate"), "{}", stderr(&o));
    // Issue 32 §3: above the sustained rate, refused with the reason (the port is not opened).
    let o = jdbb(&[
        "record",
        "--port",
        "/dev/null",
        "--out",
        "x.csv",
        "--rate",
        "20000",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("known to sustain"), "{}", stderr(&o));
    assert!(stderr(&o).contains("kB/s"), "{}", stderr(&o));
    let o = jdbb(&["live", "--port", "/dev/null", "--rate", "10001"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

#[test]
fn record_survives_sigkill_with_every_flushed_sample() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let mut child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
    ]);
    pty.expect_command(Command::Start, WAIT);
    // 20 batches in pieces of odd sizes, as a USB link would deliver them.
    let bytes: Vec<u8> = (0..20).flat_map(|k| batch_frame(16 * k)).collect();
    for chunk in bytes.chunks(333) {
        pty.send(chunk);
    }
    // Every sample reaches the file while the recorder is still running (flushed as it goes)...
    wait_for_lines(&partial(&out), 320);
    // ...and half a frame more is on the wire when the process is killed.
    let next = batch_frame(320);
    pty.send(&next[..next.len() / 2]);
    std::thread::sleep(Duration::from_millis(200));
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    // Killed, it could not rename: the work file holds everything, in whole lines.
    check_csv(&partial(&out), &(0..320).collect::<Vec<_>>());
    assert!(!out.exists());
}

#[test]
fn record_ctrl_c_flushes_and_summarises() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
    ]);
    pty.expect_command(Command::Start, WAIT);
    // Batches 0, 16, a corrupted copy of 32, then 48 and 64: 16 samples lost, 1 corrupt frame.
    let mut bytes = batch_frame(0);
    bytes.extend(batch_frame(16));
    let mut bad = batch_frame(32);
    bad[10] = if bad[10] == 0x42 { 0x43 } else { 0x42 };
    bytes.extend(bad);
    bytes.extend(batch_frame(48));
    bytes.extend(batch_frame(64));
    pty.send(&bytes);
    wait_for_lines(&partial(&out), 64);
    // SAFETY: signalling our own child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    // The recorder tells the device to stop before it exits.
    pty.expect_command(Command::Stop, WAIT);
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", stderr(&o));
    assert!(stdout.contains("interrupted"), "{stdout}");
    assert!(stdout.contains("samples 64, lost 16"), "{stdout}");
    assert!(stdout.contains("corrupt frames 1"), "{stdout}");
    let want: Vec<u64> = (0..32).chain(48..80).collect();
    check_csv(&out, &want);
    assert!(!partial(&out).exists(), "renamed into place");
}

#[test]
fn record_reports_unplug_and_keeps_the_data() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--seconds",
        "30",
    ]);
    pty.expect_command(Command::Start, WAIT);
    let bytes: Vec<u8> = (0..3).flat_map(|k| batch_frame(16 * k)).collect();
    pty.send(&bytes);
    wait_for_lines(&partial(&out), 48);
    drop(pty); // the device goes away: the master side closes
               // The exit itself is the check (a hang would never return); no speed bound.
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("unplugged"), "{e}");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("device lost") && stdout.contains("samples 48"),
        "{stdout}"
    );
    check_csv(&out, &(0..48).collect::<Vec<_>>());
    // The device described itself before its first batch: its serial follows the header.
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(
        text.lines().nth(1),
        Some("# instrument_serial: 000000000000000000000000")
    );
}

#[test]
fn live_prints_lines_and_stops_by_itself() {
    let mut pty = Pty::new();
    let child = spawn(&["live", "--port", &pty.slave_path, "--seconds", "1.5"]);
    pty.expect_command(Command::Start, WAIT);
    let bytes: Vec<u8> = (0..4).flat_map(|k| batch_frame(16 * k)).collect();
    pty.send(&bytes);
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", stderr(&o));
    // Not a terminal: plain lines, no redraw codes; the last D shown to 4 decimals.
    assert!(!stdout.contains('\r'), "{stdout:?}");
    let d_last = format!("D {:.4} mm", sample(63).d_mm);
    assert!(stdout.contains(&d_last), "{stdout}");
    assert!(stdout.contains("samples 64 | lost 0"), "{stdout}");
    assert!(stdout.contains("time limit reached"), "{stdout}");
}

#[test]
fn devices_lists_ports_and_explains_ptys() {
    let o = jdbb(&["devices"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("/dev/pts/N"), "{stdout}");
}

#[test]
fn record_stops_by_itself_after_seconds() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--seconds",
        "1",
    ]);
    pty.expect_command(Command::Start, WAIT);
    let bytes: Vec<u8> = (0..2).flat_map(|k| batch_frame(16 * k)).collect();
    pty.send(&bytes);
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", stderr(&o));
    assert!(
        stdout.contains("time limit reached") && stdout.contains("samples 32, lost 0"),
        "{stdout}"
    );
    pty.expect_command(Command::Stop, WAIT);
    check_csv(&out, &(0..32).collect::<Vec<_>>());
}

#[test]
fn sigterm_and_sighup_end_a_record_like_ctrl_c() {
    for signal in [libc::SIGTERM, libc::SIGHUP] {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("rec.csv");
        let mut pty = Pty::new();
        let child = spawn(&[
            "record",
            "--port",
            &pty.slave_path,
            "--out",
            out.to_str().unwrap(),
        ]);
        pty.expect_command(Command::Start, WAIT);
        let bytes: Vec<u8> = (0..3).flat_map(|k| batch_frame(16 * k)).collect();
        pty.send(&bytes);
        wait_for_lines(&partial(&out), 48);
        // SAFETY: signalling our own child.
        assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
        pty.expect_command(Command::Stop, WAIT);
        let o = child.wait_with_output().unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "signal {signal}: {stdout}{}",
            stderr(&o)
        );
        assert!(
            stdout.contains("interrupted") && stdout.contains("samples 48"),
            "{stdout}"
        );
        check_csv(&out, &(0..48).collect::<Vec<_>>());
    }
}

#[test]
fn record_discards_the_run_before_its_start_and_stops_at_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--seconds",
        "30",
    ]);
    // The device was running (and had just restarted: small sequence numbers) when Start came.
    let old_run: Vec<u8> = [5000, 5016, 0, 16]
        .into_iter()
        .flat_map(batch_frame)
        .collect();
    pty.expect_command_after(Command::Start, WAIT, &old_run);
    let run: Vec<u8> = (0..4).flat_map(|k| batch_frame(16 * k)).collect();
    pty.send(&run);
    wait_for_lines(&partial(&out), 64);
    // The device restarts by itself: the record ends with the run it had.
    let again: Vec<u8> = (0..2).flat_map(|k| batch_frame(16 * k)).collect();
    pty.send(&again);
    pty.expect_command(Command::Stop, WAIT);
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{stdout}{e}");
    assert!(
        e.contains("restarted") && e.contains("after seq 63, t_us 6300"),
        "{e}"
    );
    assert!(e.contains("rec.csv holds the run up to there"), "{e}");
    assert!(
        stdout.contains("samples 64, lost 0") && stdout.contains("discarded before start 64"),
        "{stdout}"
    );
    check_csv(&out, &(0..64).collect::<Vec<_>>());
}

#[test]
fn force_replaces_an_existing_recording() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    std::fs::write(&out, "old\n").unwrap();
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--seconds",
        "1",
        "--force",
    ]);
    pty.expect_command(Command::Start, WAIT);
    pty.send(&batch_frame(0));
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    check_csv(&out, &(0..16).collect::<Vec<_>>());
}

#[test]
fn live_reports_a_device_restart() {
    let mut pty = Pty::new();
    let child = spawn(&["live", "--port", &pty.slave_path, "--seconds", "1.5"]);
    pty.expect_command(Command::Start, WAIT);
    let mut bytes: Vec<u8> = (0..4).flat_map(|k| batch_frame(16 * k)).collect();
    bytes.extend(batch_frame(0));
    pty.send(&bytes);
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", stderr(&o));
    assert!(
        stdout.contains(
            "warning: the device restarted (sequence went back: 64 was due, 0 came) after seq 63"
        ),
        "{stdout}"
    );
    assert!(stdout.contains("resets 1"), "{stdout}");
}

#[test]
fn an_unacknowledged_start_records_nothing_and_leaves_the_output_alone() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("precious.csv");
    std::fs::write(&out, "precious data\n").unwrap();
    let mut pty = Pty::new();
    pty.answers = false;
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--force",
    ]);
    pty.expect_command(Command::Start, WAIT);
    // Batches without the answer to Start: another run's, never recorded.
    pty.send(&batch_frame(0));
    let o = child.wait_with_output().unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("did not acknowledge Start"), "{e}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "precious data\n");
    assert!(!partial(&out).exists());
}

/// Issue 16: a failing standard error (`2>/dev/full`) once panicked `record` right after it
/// created its work file, leaving a header-only `.partial` that blocked the next record. Now the
/// progress lines are dropped and the record runs as ever.
#[test]
fn record_with_a_failing_standard_error_records_as_ever() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let full = std::fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let child = Proc::new(JDBB)
        .args([
            "record",
            "--port",
            &pty.slave_path,
            "--out",
            out.to_str().unwrap(),
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::from(full))
        .spawn()
        .unwrap();
    pty.expect_command(Command::Start, WAIT);
    let mut bytes = batch_frame(0);
    bytes.extend(batch_frame(16));
    pty.send(&bytes);
    wait_for_lines(&partial(&out), 32);
    // SAFETY: signalling our own child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    pty.expect_command(Command::Stop, WAIT);
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success(), "{:?}", o.status);
    check_csv(&out, &(0..32).collect::<Vec<_>>());
    assert!(
        !partial(&out).exists(),
        "no work file left to block the next record"
    );
}

/// Issue 16: samples a device sends that no instrument can give (D NaN, infinite, negative or
/// beyond the bars, time going back or standing still) are counted, summarised and kept as
/// `# suspect` comment lines; the file reads back.
#[test]
fn record_sets_suspect_samples_aside_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
    ]);
    pty.expect_command(Command::Start, WAIT);
    let mut samples = heapless::Vec::new();
    for i in 0..BATCH_LEN as u64 {
        let mut s = sample(i);
        match i {
            1 => s.d_mm = f64::NAN,
            2 => s.d_mm = f64::INFINITY,
            3 => s.d_mm = -1.0,
            4 => s.d_mm = 1e6,
            5 => s.t_us = sample(4).t_us,
            6 => s.t_us = sample(4).t_us - 50,
            7 => s.enc1 = 1 << 40,
            _ => {}
        }
        samples.push(s).unwrap();
    }
    let msg = DeviceMsg::Batch(SampleBatch {
        seq: 0,
        dropped: 0,
        samples,
    });
    pty.send(&encode(&msg));
    wait_for_lines(&partial(&out), BATCH_LEN);
    // SAFETY: signalling our own child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    pty.expect_command(Command::Stop, WAIT);
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", stderr(&o));
    assert!(
        stdout.contains("suspect samples 7 (D not finite 2, D impossible 2, D off the plan 0, counts out of range 1, time back 1, time ahead 0, time standing still 1)"),
        "{stdout}"
    );
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(
        text.lines().filter(|l| l.starts_with("# suspect:")).count(),
        7,
        "{text}"
    );
    let data: Vec<u64> = text
        .lines()
        .skip(1)
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(data, [0, 8, 9, 10, 11, 12, 13, 14, 15]);
}

/// `record --no-start` listens to a device that is already streaming: it sends no Ping, no
/// Start and no Stop (only GetInfo, which changes nothing), skips the tail of the frame it
/// joined in the middle of, and records from the first complete batch on — its sequence numbers
/// as they come (48.., not renumbered from 0).
#[test]
fn record_no_start_only_listens_and_keeps_the_runs_numbers() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--seconds",
        "1",
        "--no-start",
    ]);
    let mut sent = pty.expect_command(Command::GetInfo, WAIT);
    // The run was going on: the second half of batch 32's frame, then whole batches.
    let joined = batch_frame(32);
    let mut bytes = joined[joined.len() / 2..].to_vec();
    bytes.extend((3..5).flat_map(|k| batch_frame(16 * k)));
    pty.send(&bytes);
    sent.extend(pty.commands_until_closed(WAIT));
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{stdout}{}", stderr(&o));
    assert!(
        sent.iter().all(|c| !matches!(
            c,
            Ok(Command::Start) | Ok(Command::Stop) | Ok(Command::Ping(_))
        )),
        "a listener must not drive the device: {sent:?}"
    );
    check_csv(&out, &(48..80).collect::<Vec<_>>());
}

/// Frames of the samples, BATCH_LEN to a batch, numbered from 0.
fn frames_of(samples: &[Sample]) -> Vec<u8> {
    let mut out = Vec::new();
    for (k, chunk) in samples.chunks(BATCH_LEN).enumerate() {
        let mut v = heapless::Vec::new();
        for s in chunk {
            v.push(*s).unwrap();
        }
        out.extend(encode(&DeviceMsg::Batch(SampleBatch {
            seq: (k * BATCH_LEN) as u32,
            dropped: 0,
            samples: v,
        })));
    }
    out
}

/// A plan made by `jdbb plan` in `dir/plan`, and its program run on a machine (`jdbb simulate
/// --plan`'s model) as the device's samples; the truth's cycle start (s after the first sample)
/// and program duration (s).
fn planned_run(dir: &Path, machine: &str) -> (String, Vec<Sample>, f64, f64) {
    let o = jdbb(&[
        "plan",
        "--radius",
        "90",
        "--feed",
        "2000",
        "--centre",
        "100,50,-20",
        "--out",
        dir.join("plan").to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let plan_file = dir.join("plan/plan.json");
    let plan = jdbb::plan::Plan::read(&plan_file).unwrap();
    let m = jdbb::simulate::machine::Machine::parse(Path::new("m.toml"), machine).unwrap();
    let (samples, truth) = jdbb::simulate::record_sim::record(&plan, &m).unwrap();
    let t0 = samples[0].t_us as f64;
    (
        plan_file.to_str().unwrap().to_string(),
        samples,
        (truth.cycle_start_t_us - t0) * 1e-6,
        truth.program_s,
    )
}

#[test]
fn record_with_a_plan_shows_progress_and_stops_after_the_program() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let (plan, samples, start, program) = planned_run(
        dir.path(),
        "[instrument]\nsample_rate_hz = 100\nnoise_um = 0.3\ntail_s = 10\n",
    );
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--plan",
        &plan,
        "--seconds",
        "120",
    ]);
    pty.expect_command(Command::Start, Duration::from_secs(10));
    // The device streams the whole run (and more) as fast as the pty takes it; jdbb stops by
    // itself after the program's end, whatever is still coming.
    let mut master = pty.master.try_clone().unwrap();
    let bytes = frames_of(&samples);
    std::thread::spawn(move || {
        let _ = master.write_all(&bytes);
    });
    let o = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    let err = stderr(&o);
    assert!(o.status.success(), "{stdout}{err}");
    assert!(stdout.contains("the plan's program ended"), "{stdout}");
    // The first progress line comes with the first read that brings samples; when the pty has
    // filled before jdbb reads (a loaded machine), that read is already on the circle, so the
    // line's status is whichever the data reached (the tracker's states are tested in
    // `simulate::progress`).
    assert!(
        err.contains(" samples, D 8")
            && (err.contains("lost 0, waiting for cycle start")
                || err.contains("lost 0, circle 1/1")),
        "a progress line: {err}"
    );
    assert!(!err.contains("cycle start was missed"), "{err}");
    let text = std::fs::read_to_string(&out).unwrap();
    let mut lines = text.lines();
    assert!(lines.next().unwrap().starts_with("# plan_id: "));
    assert_eq!(lines.next(), Some("seq,t_us,enc1,enc2,d_mm"));
    // It stopped after the program's end, within the 3 s D must stand still at the end level (the
    // last dwell counts) and a read's worth of samples, long before the samples' end.
    let n = lines.count() as f64;
    let end_s = n / 100.0;
    assert!(
        end_s > start + program && end_s < start + program + 4.0,
        "{end_s} {}",
        start + program
    );
    // And the record is the plan's: diagnose takes it.
    let o = jdbb(&[
        "diagnose",
        "--record",
        out.to_str().unwrap(),
        "--plan",
        &plan,
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn record_with_a_plan_says_when_cycle_start_was_missed() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let (plan, samples, start, _) = planned_run(dir.path(), "[instrument]\nsample_rate_hz = 100\n");
    // The operator pressed cycle start 10 s before starting the record.
    let late: Vec<Sample> = samples
        .iter()
        .skip(((start + 10.0) * 100.0) as usize)
        .take(300)
        .copied()
        .collect();
    let mut pty = Pty::new();
    let child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--plan",
        &plan,
        "--seconds",
        "3",
    ]);
    pty.expect_command(Command::Start, Duration::from_secs(10));
    pty.send(&frames_of(&late));
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        err.contains("cycle start was missed") && err.contains("start `jdbb record --plan` first"),
        "{err}"
    );
}

/// The lines a child writes to `stream`, as they come.
fn lines_as_they_come(stream: impl Read + Send + 'static) -> std::sync::mpsc::Receiver<String> {
    use std::io::BufRead;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stream)
            .lines()
            .map_while(|l| l.ok())
        {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// The first line from `rx` that `pick` takes (panics after [`WAIT`]: a hang).
fn line_where(rx: &std::sync::mpsc::Receiver<String>, pick: impl Fn(&str) -> bool) -> String {
    let t0 = Instant::now();
    while t0.elapsed() < WAIT {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(l) if pick(&l) => return l,
            _ => {}
        }
    }
    panic!("no such line within {WAIT:?}");
}

/// The live page's `/state` at the `host:port` of the URL `jdbb` printed, once `pick` takes it
/// (panics after [`WAIT`]).
fn state_where(url_line: &str, pick: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let host = url_line
        .split("http://")
        .nth(1)
        .and_then(|u| u.split('/').next())
        .unwrap_or_else(|| panic!("no URL in {url_line}"))
        .to_string();
    let t0 = Instant::now();
    let mut last = serde_json::Value::Null;
    while t0.elapsed() < WAIT {
        // HTTP/1.0: the body as it is, never chunked.
        let mut s = std::net::TcpStream::connect(&host).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        write!(s, "GET /state HTTP/1.0\r\nHost: {host}\r\n\r\n").unwrap();
        let mut answer = String::new();
        let _ = s.read_to_string(&mut answer);
        if let Some((_, body)) = answer.split_once("\r\n\r\n") {
            last = serde_json::from_str(body).unwrap_or(serde_json::Value::Null);
            if pick(&last) {
                return last;
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("/state never showed it: {last}");
}

#[test]
fn record_web_shows_the_missed_cycle_start_warning_the_terminal_shows() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("rec.csv");
    let (plan, samples, start, _) = planned_run(dir.path(), "[instrument]\nsample_rate_hz = 100\n");
    let late: Vec<Sample> = samples
        .iter()
        .skip(((start + 10.0) * 100.0) as usize)
        .take(300)
        .copied()
        .collect();
    let mut pty = Pty::new();
    let mut child = spawn(&[
        "record",
        "--port",
        &pty.slave_path,
        "--out",
        out.to_str().unwrap(),
        "--plan",
        &plan,
        "--seconds",
        "3",
        "--web",
        "127.0.0.1:0",
    ]);
    let err = lines_as_they_come(child.stderr.take().unwrap());
    let url = line_where(&err, |l| l.starts_with("live page: "));
    pty.expect_command(Command::Start, WAIT);
    pty.send(&frames_of(&late));
    let warning = line_where(&err, |l| l.contains("cycle start was missed"));
    assert!(warning.starts_with("warning: "), "{warning}");
    let st = state_where(&url, |s| {
        s["warnings"].as_array().is_some_and(|w| !w.is_empty())
    });
    // Word for word what the terminal said, and nothing else.
    assert_eq!(st["warnings"], serde_json::json!([warning]), "{st}");
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    child.wait().unwrap();
}

#[test]
fn live_web_shows_the_restart_warning_the_terminal_shows() {
    let mut pty = Pty::new();
    let mut child = spawn(&["live", "--port", &pty.slave_path, "--web", "127.0.0.1:0"]);
    let err = lines_as_they_come(child.stderr.take().unwrap());
    let out = lines_as_they_come(child.stdout.take().unwrap());
    let url = line_where(&err, |l| l.starts_with("live page: "));
    pty.expect_command(Command::Start, WAIT);
    let mut bytes: Vec<u8> = (0..4).flat_map(|k| batch_frame(16 * k)).collect();
    bytes.extend(batch_frame(0));
    pty.send(&bytes);
    let warning = line_where(&out, |l| l.contains("the device restarted"));
    let warning = warning.trim_start_matches("\r\x1b[2K").to_string();
    assert!(warning.starts_with("warning: "), "{warning}");
    let st = state_where(&url, |s| {
        s["warnings"].as_array().is_some_and(|w| !w.is_empty())
    });
    assert_eq!(st["warnings"], serde_json::json!([warning]), "{st}");
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    child.wait().unwrap();
}
