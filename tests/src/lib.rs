//! Helpers for the integration tests in `tests/`: finding the firmware images and running them in
//! QEMU's `netduinoplus2` (STM32F405 model; the F411 image runs there, see the README);
//! [`gmachine`], an independent simulator of a CNC machine running a ballbar G-code program with
//! the J-DBB recording it; an independent model of the instrument as built ([`mechanism`]) and
//! the data it gives ([`calibration_data`]); closed-form physical rotary axes ([`rotary_truth`])
//! and A/C tables ([`rrsps_truth`]); the `jdbb` binary ([`jdbb_bin`]).
pub mod gmachine;

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub mod calibration_data;
pub mod mechanism;
pub mod rotary_truth;
pub mod rrsps_truth;
pub mod tolerance;

/// Root of the repository.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// Path of a QEMU-build firmware binary (`scripts/fw-build.sh` puts them in `target/qemu`).
pub fn qemu_elf(name: &str) -> PathBuf {
    repo_root()
        .join("target/qemu/thumbv7em-none-eabihf/release")
        .join(name)
}

/// Whether QEMU tests must run (`JDBB_REQUIRE_QEMU=1`, set by `scripts/test.sh` and CI). When not
/// required and the firmware or QEMU is missing, a test prints why and returns early, so that a
/// plain `cargo test` on a machine without the thumb toolchain still tests the host crates.
pub fn qemu_available(elf: &Path) -> bool {
    let required = std::env::var("JDBB_REQUIRE_QEMU").is_ok_and(|v| v == "1");
    let have_qemu = Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    let have_elf = elf.exists();
    if have_qemu && have_elf {
        return true;
    }
    let why = format!(
        "QEMU test not run: qemu-system-arm {}, {} {} (build it with scripts/fw-build.sh)",
        if have_qemu { "found" } else { "missing" },
        elf.display(),
        if have_elf { "found" } else { "missing" },
    );
    assert!(!required, "{why}; JDBB_REQUIRE_QEMU=1 demands it");
    eprintln!("{why}");
    false
}

/// A QEMU process, killed when dropped.
pub struct Qemu {
    child: Child,
}

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn base_command(elf: &Path, icount: bool) -> Command {
    base_command_with(elf, icount, None)
}

/// The QEMU command for `elf`; with `scenario`, the semihosting command line names it, as
/// `scripts/qemu-run.sh --scenario` does (commas doubled for QEMU's option syntax).
fn base_command_with(elf: &Path, icount: bool, scenario: Option<&Path>) -> Command {
    let arg = scenario.map(|file| {
        let abs = std::fs::canonicalize(file).expect("the scenario file exists");
        abs.to_str().expect("a UTF-8 path").to_string()
    });
    base_command_arg(elf, icount, arg.as_deref())
}

/// The QEMU command for `elf`; with `arg`, the semihosting command line is `jdbb-firmware ARG`
/// (commas doubled for QEMU's option syntax).
fn base_command_arg(elf: &Path, icount: bool, arg: Option<&str>) -> Command {
    let mut semihosting = String::from("enable=on,target=native");
    if let Some(arg) = arg {
        let arg = arg.replace(',', ",,");
        semihosting.push_str(&format!(",arg=jdbb-firmware,arg={arg}"));
    }
    let mut c = Command::new("qemu-system-arm");
    c.args([
        "-machine",
        "netduinoplus2",
        "-nographic",
        "-monitor",
        "none",
    ])
    .args(["-semihosting-config", &semihosting]);
    if icount {
        // One instruction per ns of emulated time, idle time skipped: the emulated CPU can never
        // overrun its sample clock however busy the host is, so a run is lossless and repeatable.
        c.args(["-icount", "shift=0,sleep=off"]);
    }
    c.arg("-kernel").arg(elf);
    c
}

impl Qemu {
    /// Run `elf` to completion (semihosting exit) with USART2 written to `usart2_out`; returns the
    /// exit status. Fails after `timeout`.
    pub fn run_to_exit(
        elf: &Path,
        usart2_out: &Path,
        timeout: Duration,
    ) -> std::process::ExitStatus {
        let mut c = base_command(elf, false);
        c.args(["-serial", "null", "-serial"])
            .arg(format!("file:{}", usart2_out.display()))
            .stdout(Stdio::null())
            .stderr(Stdio::inherit());
        let mut child = c.spawn().expect("start qemu-system-arm");
        let start = Instant::now();
        loop {
            if let Some(status) = child.try_wait().expect("wait for qemu") {
                return status;
            }
            if start.elapsed() > timeout {
                let _ = child.kill();
                panic!("{} did not exit within {timeout:?}", elf.display());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Start `elf` with USART2 on a pseudo-terminal, under `-icount shift=0,sleep=off`; returns
    /// the process and the pty path.
    pub fn start_with_pty(elf: &Path) -> (Qemu, PathBuf) {
        Self::start_pty(base_command(elf, true))
    }

    /// [`Self::start_with_pty`], the encoders playing `scenario` (`jdbb_core::scenario`).
    pub fn start_with_scenario(elf: &Path, scenario: &Path) -> (Qemu, PathBuf) {
        Self::start_pty(base_command_with(elf, true, Some(scenario)))
    }

    /// [`Self::start_with_pty`], the calibration flash failing as `mode` says (`leftover`,
    /// `protected` or `deaf`: see `FlashFault` in the firmware's `board::qemu`).
    pub fn start_with_flash_fault(elf: &Path, mode: &str) -> (Qemu, PathBuf) {
        let arg = format!("flash-fault={mode}");
        Self::start_pty(base_command_arg(elf, true, Some(&arg)))
    }

    fn start_pty(mut c: Command) -> (Qemu, PathBuf) {
        c.args(["-serial", "null", "-serial", "pty"])
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        let mut child = c.spawn().expect("start qemu-system-arm");
        let stdout = child.stdout.take().expect("piped stdout");
        let mut reader = BufReader::new(stdout);
        // QEMU prints "char device redirected to /dev/pts/N (label serial1)" on stdout; after it,
        // stdout carries the firmware's binary defmt log (semihosting), so read raw lines.
        let pty = loop {
            let mut line = Vec::new();
            let n = reader
                .read_until(b'\n', &mut line)
                .expect("read QEMU stdout");
            assert!(n > 0, "QEMU exited before announcing its pty");
            let line = String::from_utf8_lossy(&line);
            if let Some(rest) = line.split("redirected to ").nth(1) {
                if line.contains("serial1") {
                    break PathBuf::from(rest.split_whitespace().next().unwrap());
                }
            }
        };
        // Keep draining stdout so QEMU never blocks on it.
        std::thread::spawn(move || {
            let mut sink = [0u8; 4096];
            while matches!(reader.read(&mut sink), Ok(n) if n > 0) {}
        });
        (Qemu { child }, pty)
    }
}

/// How far an on-chip D is from the host's independent f64 reference for the same counts, and
/// the budget it must meet there (`geometry::accuracy_budget_mm`): `(error_mm, budget_mm)`.
pub fn chip_error_mm(
    cal: &jdbb_core::Calibration,
    sample: &jdbb_core::protocol::Sample,
) -> (f64, f64) {
    use jdbb_core::geometry;
    let reference = geometry::distance_mm(cal, sample.enc1, sample.enc2);
    (
        (sample.d_mm - reference).abs(),
        geometry::accuracy_budget_mm(cal, sample.enc1, sample.enc2),
    )
}

/// A `jdbb record --plan` file read back against the scenario QEMU played (`expected`, the
/// scenario's rows): the plan id, the column header and the instrument serial first (`serial`,
/// or any); then every sample in order at `period_us`, with the scenario's counts (held after
/// its last row) and D within the chip's accuracy budget of the host's f64 model, plus 0.05 nm
/// (the CSV keeps 7 decimals). Returns each sample's D (mm) and the largest |D_chip − D_host|
/// (nm).
pub fn check_record_is_scenario(
    text: &str,
    expected: &[gmachine::Row],
    period_us: u64,
    serial: Option<&str>,
) -> (Vec<f64>, f64) {
    use jdbb_core::geometry;
    let cal = jdbb_core::Calibration::DEFAULT;
    let mut lines = text.lines();
    assert!(lines.next().is_some_and(|l| l.starts_with("# plan_id: ")));
    assert_eq!(lines.next(), Some("seq,t_us,enc1,enc2,d_mm"));
    let serial_line = lines.next().unwrap_or("");
    match serial {
        Some(s) => assert_eq!(serial_line, format!("# instrument_serial: {s}")),
        None => assert!(
            serial_line.starts_with("# instrument_serial: "),
            "{serial_line}"
        ),
    }
    let (mut d_mm, mut worst_nm) = (vec![], 0.0f64);
    for (i, line) in lines.enumerate() {
        let v: Vec<&str> = line.split(',').collect();
        let (seq, t_us): (u64, u64) = (v[0].parse().unwrap(), v[1].parse().unwrap());
        let (enc1, enc2): (i64, i64) = (v[2].parse().unwrap(), v[3].parse().unwrap());
        let d: f64 = v[4].parse().unwrap();
        assert_eq!(seq, i as u64, "sequence gap at line {}", i + 4);
        assert_eq!(t_us, period_us * seq, "t_us at seq {seq}");
        let e = &expected[i.min(expected.len() - 1)];
        assert_eq!((enc1, enc2), (e.enc1, e.enc2), "counts at seq {seq}");
        let reference = geometry::distance_mm(&cal, enc1, enc2);
        let err = (d - reference).abs();
        let budget = geometry::accuracy_budget_mm(&cal, enc1, enc2) + 0.5e-7;
        assert!(
            err <= budget,
            "seq {seq}: D chip {d} mm vs host {reference} mm"
        );
        worst_nm = worst_nm.max(err * 1e6);
        d_mm.push(d);
    }
    (d_mm, worst_nm)
}

/// The `jdbb` binary built in this workspace (`target/<profile>/jdbb`, beside this test's
/// `deps/` folder), or `$JDBB_BIN`. `cargo test` at the root builds it for the host crate's
/// tests; alone, `cargo build -p jdbb` first.
pub fn jdbb_bin() -> PathBuf {
    if let Some(bin) = std::env::var_os("JDBB_BIN") {
        return PathBuf::from(bin);
    }
    let exe = std::env::current_exe().expect("the test executable's path");
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("a test executable lives in target/<profile>/deps");
    let bin = profile_dir.join(format!("jdbb{}", std::env::consts::EXE_SUFFIX));
    assert!(
        bin.exists(),
        "{} missing: run `cargo build -p jdbb` (or set JDBB_BIN)",
        bin.display()
    );
    bin
}

// The rule is tested here, not in `tolerance.rs`, which the host's tests include too.
#[cfg(test)]
mod tolerance_rule {
    use crate::tolerance::check_unbiased;

    #[test]
    fn the_rule_fails_a_bias_with_any_sigma_and_a_vague_value() {
        // Unbiased within its σ.
        assert!(check_unbiased("v", 10.2, 0.1, 10.0, 0.0, 0.1).is_ok());
        // The spike: 9.9 ± 1.99 for 4 (the OR form passed it).
        assert!(check_unbiased("v", 9.9, 1.99, 4.0, 0.0, 0.5).is_err());
        // 4 % off with a tiny σ.
        assert!(check_unbiased("v", 10.4, 0.01, 10.0, 0.0, 0.1).is_err());
        // 6 % off with σ at the bound: 1 % + 3σ would pass it.
        assert!(check_unbiased("v", 10.6, 0.9, 10.0, 0.0, 0.1).is_err());
        // Right, but σ too large to tell.
        assert!(check_unbiased("v", 10.0, 1.5, 10.0, 0.0, 0.1).is_err());
        // The floor: 0.08 off a 0.2 truth within an absolute 0.1.
        assert!(check_unbiased("v", 0.28, 0.01, 0.2, 0.1, 0.1).is_ok());
        // Sign flipped, and NaN.
        assert!(check_unbiased("v", -10.0, 0.1, 10.0, 0.0, 0.1).is_err());
        assert!(check_unbiased("v", f64::NAN, 0.1, 10.0, 0.0, 0.1).is_err());
    }
}
