//! Issue 16, finding by finding: what a careless or hostile user met, as tests that failed
//! before the fix. One writer (no link, no device, whole files, sets, `--force` everywhere), one
//! reader discipline (limits, unknown keys, plausible numbers), never a panic.
#![cfg(unix)]

use std::fs;
use std::os::unix::fs::FileTypeExt;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};
mod common;
use common::{command, jdbb_in, ok_in, stderr};

/// `args` (run in `dir`) exit `code` with `want` in stderr and no panic.
fn fails_in(dir: &Path, args: &[&str], code: i32, want: &str) -> String {
    let o = jdbb_in(dir, args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(code), "{args:?}: {e}");
    assert!(e.contains(want), "{args:?}: wanted `{want}` in `{e}`");
    assert!(!e.contains("panicked"), "{args:?}: {e}");
    e
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(name)
}

fn mkfifo(p: &Path) {
    let c = std::ffi::CString::new(p.to_str().unwrap()).unwrap();
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
}

/// Every name in `dir`, sorted.
fn ls(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// No temporary file or directory of the writer is left in `dir`.
fn no_temporaries(dir: &Path) {
    let left: Vec<String> = ls(dir)
        .into_iter()
        .filter(|n| n.contains(".jdbb-") || n.ends_with(".tmp") || n.contains(".tmp-"))
        .collect();
    assert!(
        left.is_empty(),
        "temporaries left in {}: {left:?}",
        dir.display()
    );
}

/// A small simulated circular test `s.csv` in `dir` (diagnose accepts it, with `--pitch x=10`).
fn samples(dir: &Path) -> &'static str {
    ok_in(
        dir,
        &[
            "simulate",
            "--radius",
            "40",
            "--radius",
            "70",
            "--rate",
            "50",
            "--effect",
            "scale_x=30",
            "--effect",
            "cyclic_x=2@40",
            "--effect",
            "backlash_x=-6",
            "--pitch",
            "x=10",
            "-o",
            "s.csv",
        ],
    );
    "s.csv"
}

/// `diag.json` in `dir`, diagnosed from [`samples`].
fn diagnosis(dir: &Path) -> &'static str {
    samples(dir);
    let json = ok_in(
        dir,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--pitch",
            "x=10",
            "--json",
            "--machine",
            "m1",
        ],
    );
    fs::write(dir.join("diag.json"), json).unwrap();
    "diag.json"
}

/// A record `rec.csv` and the default calibration `cal.toml` in `dir` (recompute accepts them).
fn record_and_calibration(dir: &Path) {
    fs::write(
        dir.join("rec.csv"),
        "seq,t_us,enc1,enc2,d_mm\n0,0,1000,-2000,99.9\n1,100,1001,-2001,99.9\n",
    )
    .unwrap();
    fs::write(dir.join("cal.toml"), CAL_TOML).unwrap();
}

const CAL_TOML: &str = "l1_mm = 50.0\nl2_mm = 50.0\n[enc1]\ncounts_per_rev = 8388608\nzero_count = 0\ndirection = \"Positive\"\n[enc2]\ncounts_per_rev = 8388608\nzero_count = 0\ndirection = \"Positive\"\n";

/// Calibrator samples `cal.csv` of the default instrument over its range (calibrate accepts them).
fn calibrator_samples(dir: &Path) -> &'static str {
    let cal = jdbb_core::calib::Calibration::DEFAULT;
    let mut s = String::from("enc1,enc2,d_ref_mm\n");
    for i in -6..=6 {
        for j in -6..=6 {
            let (e1, e2) = (i * 180_000i64, j * 170_000i64);
            s += &format!(
                "{e1},{e2},{}\n",
                jdbb_core::geometry::distance_mm(&cal, e1, e2)
            );
        }
    }
    fs::write(dir.join("cal.csv"), s).unwrap();
    "cal.csv"
}

/// A history `h.sqlite` in `dir` with one run of machine m1 (after [`diagnosis`]).
fn history(dir: &Path) {
    ok_in(
        dir,
        &[
            "history",
            "--db",
            "h.sqlite",
            "add",
            "--machine",
            "m1",
            "--diagnosis",
            "diag.json",
        ],
    );
}

// ---------------------------------------------------------------------------------------------
// Outputs replace what they point at.

#[test]
fn an_output_that_is_a_pipe_or_socket_is_refused_and_left_as_it_is() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    record_and_calibration(d);
    calibrator_samples(d);
    mkfifo(&d.join("fifo"));
    let sock = std::os::unix::net::UnixListener::bind(d.join("sock")).unwrap();
    for out in ["fifo", "sock"] {
        for force in [false, true] {
            let mut cases: Vec<Vec<&str>> = vec![
                vec![
                    "recompute",
                    "--record",
                    "rec.csv",
                    "--calibration",
                    "cal.toml",
                    "-o",
                    out,
                ],
                vec!["calibrate", "--samples", "cal.csv", "-o", out],
                vec!["simulate", "--rate", "20", "-o", out],
            ];
            for c in &mut cases {
                if force {
                    c.push("--force");
                }
                fails_in(d, c, 2, "device, pipe or socket");
            }
        }
    }
    assert!(fs::symlink_metadata(d.join("fifo"))
        .unwrap()
        .file_type()
        .is_fifo());
    assert!(fs::symlink_metadata(d.join("sock"))
        .unwrap()
        .file_type()
        .is_socket());
    drop(sock);
    no_temporaries(d);
}

#[test]
fn outputs_never_follow_a_symbolic_link() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let outside = tempfile::tempdir().unwrap();
    let victim = outside.path().join("victim");
    fs::write(&victim, "the user's file\n").unwrap();
    diagnosis(d);
    history(d);
    let link = |name: &str| {
        let p = d.join(name);
        std::os::unix::fs::symlink(&victim, &p).unwrap();
    };
    link("sim.csv");
    fails_in(
        d,
        &["simulate", "--rate", "20", "-o", "sim.csv", "--force"],
        2,
        "symbolic link",
    );
    link("trend.svg");
    fails_in(
        d,
        &[
            "history",
            "--db",
            "h.sqlite",
            "trend",
            "--machine",
            "m1",
            "--plot",
            "trend.svg",
            "--force",
        ],
        2,
        "symbolic link",
    );
    fs::create_dir(d.join("plan")).unwrap();
    std::os::unix::fs::symlink(&victim, d.join("plan/plan.json")).unwrap();
    fails_in(
        d,
        &[
            "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "plan",
            "--force",
        ],
        2,
        "symbolic link",
    );
    assert!(
        !d.join("plan/ballbar.ngc").exists(),
        "nothing of the set written"
    );
    fs::create_dir(d.join("comp")).unwrap();
    std::os::unix::fs::symlink(&victim, d.join("comp/x.comp")).unwrap();
    // A report directory that is a link to another directory.
    std::os::unix::fs::symlink(outside.path(), d.join("rep")).unwrap();
    fails_in(
        d,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--report",
            "rep",
            "--force",
        ],
        2,
        "symbolic link",
    );
    assert_eq!(ls(outside.path()), ["victim"]);
    assert_eq!(fs::read_to_string(&victim).unwrap(), "the user's file\n");
    no_temporaries(d);
}

#[test]
fn nothing_is_replaced_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d);
    history(d);
    record_and_calibration(d);
    calibrator_samples(d);
    fs::copy(data("rrsps_parameters_table2_3.csv"), d.join("p.csv")).unwrap();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["simulate", "--rate", "20", "-o", "out.csv"], "out.csv"),
        (
            vec![
                "recompute",
                "--record",
                "rec.csv",
                "--calibration",
                "cal.toml",
                "-o",
                "out.csv",
            ],
            "out.csv",
        ),
        (
            vec!["calibrate", "--samples", "cal.csv", "-o", "out.toml"],
            "out.toml",
        ),
        (
            vec![
                "history",
                "--db",
                "h.sqlite",
                "trend",
                "--machine",
                "m1",
                "--plot",
                "t.svg",
            ],
            "t.svg",
        ),
        (
            vec![
                "rrsps",
                "simulate",
                "--design",
                "p.csv",
                "--case",
                "design_range_neg",
                "--d",
                "300",
                "--points",
                "36",
                "-o",
                "r.csv",
            ],
            "r.csv",
        ),
    ];
    for (args, out) in &cases {
        let _ = fs::remove_file(d.join(out));
        fs::write(d.join(out), "hand-edited\n").unwrap();
        fails_in(d, args, 2, "--force");
        assert_eq!(
            fs::read_to_string(d.join(out)).unwrap(),
            "hand-edited\n",
            "{args:?}"
        );
        let mut forced = args.clone();
        forced.push("--force");
        ok_in(d, &forced);
        assert_ne!(
            fs::read_to_string(d.join(out)).unwrap(),
            "hand-edited\n",
            "{args:?}"
        );
    }
    // compensate --out run twice: the hand-edited table is kept.
    let comp = [
        "compensate",
        "--diagnosis",
        "diag.json",
        "--controller",
        "linuxcnc",
        "--table-ball",
        "x=250,y=150",
        "--travel",
        "x=0:500,y=0:400",
        "--out",
        "comp",
    ];
    ok_in(d, &comp);
    let tables = ls(&d.join("comp"));
    assert!(!tables.is_empty());
    let first = d.join("comp").join(&tables[0]);
    fs::write(&first, "# hand-edited\n").unwrap();
    fails_in(d, &comp, 2, "--force");
    assert_eq!(fs::read_to_string(&first).unwrap(), "# hand-edited\n");
    let mut forced = comp.to_vec();
    forced.push("--force");
    ok_in(d, &forced);
    assert_ne!(fs::read_to_string(&first).unwrap(), "# hand-edited\n");
    // A report directory: refused without --force, replaced whole with it.
    ok_in(d, &["diagnose", "--samples", "s.csv", "--report", "rep"]);
    fails_in(
        d,
        &["diagnose", "--samples", "s.csv", "--report", "rep"],
        2,
        "--force",
    );
    // A file an earlier report wrote (its mark lists it) that the new one does not write.
    fs::write(d.join("rep/stale.svg"), "stale").unwrap();
    let mark = d.join("rep/.jdbb-output");
    let listed = fs::read_to_string(&mark).unwrap() + "stale.svg\n";
    fs::write(&mark, listed).unwrap();
    ok_in(
        d,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--report",
            "rep",
            "--force",
        ],
    );
    assert!(
        !d.join("rep/stale.svg").exists(),
        "no stale file in a new report"
    );
    assert!(d.join("rep/report.html").exists() && d.join("rep/diagnosis.json").exists());
    // A directory of the user's is never replaced, even with --force.
    fs::create_dir(d.join("mine")).unwrap();
    fs::write(d.join("mine/notes.txt"), "mine").unwrap();
    fails_in(
        d,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--report",
            "mine",
            "--force",
        ],
        2,
        "not replaced",
    );
    assert_eq!(ls(&d.join("mine")), ["notes.txt"]);
    no_temporaries(d);
}

// ---------------------------------------------------------------------------------------------
// Torn outputs under their final names.

/// Run `args` in `dir` with files limited to `bytes` (RLIMIT_FSIZE, SIGXFSZ ignored): a write
/// beyond fails as on a full disk.
fn run_on_small_disk(dir: &Path, args: &[&str], bytes: u64) -> Output {
    let mut c = command();
    c.current_dir(dir).args(args);
    // SAFETY: async-signal-safe libc calls between fork and exec.
    unsafe {
        c.pre_exec(move || {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
            let l = libc::rlimit {
                rlim_cur: bytes,
                rlim_max: bytes,
            };
            libc::setrlimit(libc::RLIMIT_FSIZE, &l);
            Ok(())
        });
    }
    c.output().unwrap()
}

#[test]
fn a_full_disk_leaves_the_old_outputs_whole() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d);
    let plan = [
        "plan", "--radius", "90", "--radius", "85", "--feed", "1000", "--centre", "0,0,0", "--out",
        "plan",
    ];
    ok_in(d, &plan);
    let old_json = fs::read(d.join("plan/plan.json")).unwrap();
    let old_prog = fs::read(d.join("plan/ballbar.ngc")).unwrap();
    let sim = ["simulate", "--rate", "200", "-o", "sim.csv"];
    ok_in(d, &sim);
    let old_sim = fs::read(d.join("sim.csv")).unwrap();
    ok_in(d, &["diagnose", "--samples", "s.csv", "--report", "rep"]);
    let old_report = fs::read(d.join("rep/diagnosis.json")).unwrap();
    let old_ls = ls(&d.join("rep"));
    let room = 2000;
    let mut forced_plan = plan.to_vec();
    forced_plan.push("--force");
    forced_plan[2] = "95";
    let o = run_on_small_disk(d, &forced_plan, room);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(fs::read(d.join("plan/plan.json")).unwrap(), old_json);
    assert_eq!(fs::read(d.join("plan/ballbar.ngc")).unwrap(), old_prog);
    let mut forced_sim = sim.to_vec();
    forced_sim.extend(["--force", "--radius", "70"]);
    let o = run_on_small_disk(d, &forced_sim, room);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(fs::read(d.join("sim.csv")).unwrap(), old_sim);
    let o = run_on_small_disk(
        d,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--report",
            "rep",
            "--force",
            "--machine",
            "x",
        ],
        room,
    );
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(fs::read(d.join("rep/diagnosis.json")).unwrap(), old_report);
    assert_eq!(ls(&d.join("rep")), old_ls);
    let comp = [
        "compensate",
        "--diagnosis",
        "diag.json",
        "--controller",
        "linuxcnc",
        "--table-ball",
        "x=250,y=150",
        "--travel",
        "x=0:500,y=0:400",
        "--out",
        "comp",
        "--force",
    ];
    let o = run_on_small_disk(d, &comp, 300);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(
        !d.join("comp").exists() || ls(&d.join("comp")).is_empty(),
        "no torn table"
    );
    no_temporaries(d);
    no_temporaries(&d.join("plan"));
}

#[test]
fn a_plan_whose_program_cannot_be_written_keeps_the_old_set() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let plan = [
        "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "p",
    ];
    ok_in(d, &plan);
    let old_json = fs::read(d.join("p/plan.json")).unwrap();
    // The program's name is taken by a directory: the new plan.json must not go in beside it.
    fs::remove_file(d.join("p/ballbar.ngc")).unwrap();
    fs::create_dir(d.join("p/ballbar.ngc")).unwrap();
    let forced = [
        "plan", "--radius", "90", "--feed", "2000", "--centre", "0,0,0", "--out", "p", "--force",
    ];
    fails_in(d, &forced, 2, "a directory");
    assert_eq!(fs::read(d.join("p/plan.json")).unwrap(), old_json);
    no_temporaries(&d.join("p"));
}

// ---------------------------------------------------------------------------------------------
// A failing stderr panics; a panic is a bug report, exit 1.

#[test]
fn a_failing_standard_error_is_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let full = fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let o = command()
        .current_dir(d)
        .args(["diagnose", "--samples", "missing.csv"])
        .stderr(Stdio::from(full))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    // A closed pipe as standard error.
    let mut child = command()
        .current_dir(d)
        .args(["rotary", "--axis", "c", "--table", "missing.csv"])
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stderr.take());
    assert_eq!(child.wait().unwrap().code(), Some(2));
    // A note on standard error that cannot be written does not end the command.
    fs::copy(data("rrsps_parameters_table2_3.csv"), d.join("p.csv")).unwrap();
    let full = fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let o = command()
        .current_dir(d)
        .args([
            "rrsps",
            "simulate",
            "--design",
            "p.csv",
            "--case",
            "design_range_neg",
            "--d",
            "300",
            "--points",
            "36",
            "-o",
            "r.csv",
        ])
        .stderr(Stdio::from(full))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0));
}

#[test]
fn a_panic_is_exit_1_with_a_bug_report() {
    let o = command()
        .args(["devices"])
        .env("JDBB_PANIC_FOR_TEST", "1")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
    let e = stderr(&o);
    assert!(
        e.contains("internal error (a bug)") && e.contains("report it"),
        "{e}"
    );
    let full = fs::OpenOptions::new()
        .write(true)
        .open("/dev/full")
        .unwrap();
    let o = command()
        .args(["devices"])
        .env("JDBB_PANIC_FOR_TEST", "1")
        .stderr(Stdio::from(full))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1));
}

// ---------------------------------------------------------------------------------------------
// Unbounded.

/// Run `args` in `dir` with the address space limited to 1 GiB (a reader that reads an endless
/// input whole runs out of it and aborts).
fn run_bounded(dir: &Path, args: &[&str]) -> Output {
    let mut c = command();
    c.current_dir(dir).args(args);
    // SAFETY: an async-signal-safe libc call between fork and exec.
    unsafe {
        c.pre_exec(|| {
            let l = libc::rlimit {
                rlim_cur: 1 << 30,
                rlim_max: 1 << 30,
            };
            libc::setrlimit(libc::RLIMIT_AS, &l);
            Ok(())
        });
    }
    c.output().unwrap()
}

#[test]
fn every_input_read_from_an_endless_file_stops_at_its_limit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d);
    history(d);
    record_and_calibration(d);
    calibrator_samples(d);
    ok_in(
        d,
        &[
            "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "p",
        ],
    );
    // `calibrate --record --plan` takes a calibration-test plan only (issue 17).
    ok_in(
        d,
        &[
            "plan",
            "--calibration-test",
            "--feed",
            "1000",
            "--centre",
            "0,0,0",
            "--out",
            "cp",
        ],
    );
    fs::copy(data("rrsps_parameters_table2_3.csv"), d.join("p.csv")).unwrap();
    let z = "/dev/zero";
    let cases: Vec<Vec<&str>> = vec![
        vec!["diagnose", "--samples", z],
        vec!["diagnose", "--record", z, "--plan", "p/plan.json"],
        vec!["diagnose", "--record", "rec.csv", "--plan", z],
        vec!["diagnose", "--record", "rec.csv", "--path", z],
        vec!["diagnose", "--samples", "s.csv", "--calibration", z],
        vec!["compensate", "--diagnosis", z, "--controller", "linuxcnc"],
        vec![
            "compensate",
            "--diagnosis",
            "diag.json",
            "--controller",
            "grblhal",
            "--current",
            z,
        ],
        vec![
            "history",
            "--db",
            "h.sqlite",
            "add",
            "--machine",
            "m1",
            "--diagnosis",
            z,
        ],
        vec!["calibrate", "--samples", z],
        vec!["calibrate", "--samples", "cal.csv", "--nominal", z],
        vec!["calibrate", "--record", z, "--plan", "cp/plan.json"],
        vec![
            "recompute",
            "--record",
            z,
            "--calibration",
            "cal.toml",
            "-o",
            "o.csv",
        ],
        vec![
            "recompute",
            "--record",
            "rec.csv",
            "--calibration",
            z,
            "-o",
            "o.csv",
        ],
        vec!["rotary", "--axis", "c", "--table", z],
        vec!["rrsps", "simulate", "--design", z, "--d", "300"],
        vec![
            "rrsps",
            "identify",
            "--samples",
            z,
            "--design",
            "p.csv",
            "--case",
            "design_range_neg",
        ],
        vec![
            "plan",
            "--radius",
            "90",
            "--feed",
            "1000",
            "--centre",
            "0,0,0",
            "--out",
            "q",
            "--calibration",
            z,
        ],
    ];
    for args in &cases {
        let t0 = Instant::now();
        let o = run_bounded(d, args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        assert!(
            e.contains("MiB") || e.contains("GiB"),
            "{args:?}: the message names the limit: {e}"
        );
        // A hang, not a speed check: reading an endless input without its limit would run
        // until the 1 GiB address-space limit, far beyond this.
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "{args:?}: {:?}",
            t0.elapsed()
        );
    }
    assert!(!d.join("o.csv").exists() && !d.join("q").exists());
}

#[test]
fn rrsps_simulate_points_are_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fs::copy(data("rrsps_parameters_table2_3.csv"), d.join("p.csv")).unwrap();
    for n in ["1000000000", "18446744073709551615", "1"] {
        fails_in(
            d,
            &[
                "rrsps",
                "simulate",
                "--design",
                "p.csv",
                "--case",
                "design_range_neg",
                "--d",
                "300",
                "--points",
                n,
            ],
            2,
            "1000000",
        );
    }
}

/// How long a process may take to end after SIGINT before the test calls it a hang: generous, so
/// a debug build on busy cores cannot miss it; what is checked is that SIGINT is handled (exit
/// 130, nothing left behind), not how fast.
const HANG: Duration = Duration::from_secs(60);

/// Whether process `pid` catches SIGINT (its handler installed: `SigCgt` in /proc/PID/status).
fn catches_sigint(pid: u32) -> bool {
    fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("SigCgt:"))
                .and_then(|h| u64::from_str_radix(h.trim(), 16).ok())
        })
        .is_some_and(|mask| mask & (1 << (libc::SIGINT - 1)) != 0)
}

/// Start `args` in `dir`, send SIGINT once it catches it and `ready` (states, not times: its
/// handler is installed, it is still at work, and e.g. it is writing); the exit code (None: still
/// running after [`HANG`], then killed) and how long it took to end.
fn interrupt(dir: &Path, args: &[&str], ready: &dyn Fn() -> bool) -> (Option<i32>, Duration) {
    let mut child = command()
        .current_dir(dir)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    while !(catches_sigint(child.id()) && ready()) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "{args:?} ended before the interrupt"
        );
        if started.elapsed() > HANG {
            let _ = child.kill();
            panic!("{args:?}: not ready for the interrupt after {HANG:?}");
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(
        child.try_wait().unwrap().is_none(),
        "{args:?} ended before the interrupt"
    );
    // SAFETY: a signal to our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let t0 = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return (s.code(), t0.elapsed());
        }
        if t0.elapsed() > HANG {
            let _ = child.kill();
            let _ = child.wait();
            return (None, t0.elapsed());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
/// Ctrl-C handled: `simulate` and `diagnose` interrupted mid-run exit with 130 (the shell's code
/// for SIGINT) instead of running on or being killed, leave no partial output, and leave the
/// input they were reading byte for byte as it was.
fn ctrl_c_stops_simulate_and_diagnose_leaving_no_output_and_the_input_intact() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok_in(
        d,
        &[
            "simulate", "--radius", "90", "--rate", "20000", "-o", "big.csv",
        ],
    );
    let big = fs::read(d.join("big.csv")).unwrap();
    let (code, took) = interrupt(
        d,
        &[
            "simulate", "--radius", "90", "--rate", "60000", "-o", "sim.csv",
        ],
        // Mid-write: its temporary file is there.
        &|| ls(d).iter().any(|n| n.ends_with(".tmp")),
    );
    assert_eq!(code, Some(130), "ended after {took:?}");
    let (code, took) = interrupt(
        d,
        &["diagnose", "--samples", "big.csv", "--report", "rep"],
        &|| true,
    );
    assert_eq!(code, Some(130), "ended after {took:?}");
    assert_eq!(ls(d), ["big.csv"], "no partial output");
    assert!(
        fs::read(d.join("big.csv")).unwrap() == big,
        "the input is intact"
    );
}

// ---------------------------------------------------------------------------------------------
// Panics on absurd numbers.

#[test]
fn absurd_rotary_lengths_are_refused_before_the_algebra() {
    let dir = tempfile::tempdir().unwrap();
    let table = data("dbb_c_turntable_table1.csv");
    let table = table.to_str().unwrap();
    for opt in ["--l1", "--l2", "--h1", "--h3"] {
        for v in ["1e300", "1e100", "-1e20"] {
            let arg = format!("{opt}={v}");
            fails_in(
                dir.path(),
                &["rotary", "--axis", "c", "--table", table, &arg],
                2,
                "10 m",
            );
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Garbage passed on.

#[test]
fn a_misspelled_calibration_key_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    record_and_calibration(d);
    calibrator_samples(d);
    let skewed = format!("axes_skew_rads = 1.5e-5\n{CAL_TOML}");
    fs::write(d.join("typo.toml"), &skewed).unwrap();
    let e = fails_in(
        d,
        &[
            "recompute",
            "--record",
            "rec.csv",
            "--calibration",
            "typo.toml",
            "-o",
            "o.csv",
        ],
        2,
        "typo.toml:1:1",
    );
    assert!(e.contains("axes_skew_rads"), "{e}");
    fails_in(
        d,
        &[
            "calibrate",
            "--samples",
            "cal.csv",
            "--nominal",
            "typo.toml",
        ],
        2,
        "axes_skew_rads",
    );
    let in_table = CAL_TOML.replace(
        "zero_count = 0\ndirection",
        "zero_count = 0\nzero_ofset_rad = 1e-4\ndirection",
    );
    fs::write(d.join("typo2.toml"), in_table).unwrap();
    fails_in(
        d,
        &[
            "calibrate",
            "--samples",
            "cal.csv",
            "--nominal",
            "typo2.toml",
        ],
        2,
        "zero_ofset_rad",
    );
    // The JSON calibration of `diagnose --calibration` too.
    samples(d);
    fs::write(
        d.join("cal.json"),
        r#"{"l1_mm":50,"l2_mm":50,"axes_skew":1e-5,"enc1":{"counts_per_rev":8388608,"zero_count":0,"direction":"Positive"},"enc2":{"counts_per_rev":8388608,"zero_count":0,"direction":"Positive"}}"#,
    )
    .unwrap();
    fails_in(
        d,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--calibration",
            "cal.json",
        ],
        2,
        "axes_skew",
    );
    assert!(!d.join("o.csv").exists());
}

#[test]
fn an_absurd_bar_length_is_refused_before_the_device() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for l in ["1e-300", "0.5", "20000.0"] {
        fs::write(
            d.join("bad.toml"),
            CAL_TOML.replace("l1_mm = 50.0", &format!("l1_mm = {l}")),
        )
        .unwrap();
        // The file is checked before the port: the error is the bar, not the missing port.
        fails_in(
            d,
            &[
                "calibration",
                "send",
                "--port",
                "/dev/ttyJDBB-none",
                "--file",
                "bad.toml",
            ],
            2,
            "between 1 mm and 10 m",
        );
    }
}

#[test]
fn compensate_refuses_absurd_settings_and_another_controllers_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d);
    // 1e6 µm of play in the diagnosis is not `$160=1000` (positive backlash is play, the sign
    // grblHAL takes).
    let mut doc: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(d.join("diag.json")).unwrap()).unwrap();
    for e in doc["effects"].as_array_mut().unwrap() {
        if e["name"] == "backlash_x" {
            e["value"] = serde_json::json!(1e6);
            for v in e["params"].as_object_mut().unwrap().values_mut() {
                *v = serde_json::json!(1e6);
            }
        }
    }
    fs::write(d.join("huge.json"), serde_json::to_string(&doc).unwrap()).unwrap();
    for c in ["grblhal", "linuxcnc", "marlin"] {
        let o = jdbb_in(
            d,
            &["compensate", "--diagnosis", "huge.json", "--controller", c],
        );
        let e = stderr(&o);
        assert_eq!(
            o.status.code(),
            Some(2),
            "{c}: {e} {}",
            String::from_utf8_lossy(&o.stdout)
        );
        assert!(e.contains("repair"), "{c}: {e}");
    }
    // Zero steps per mm in force is not `M92 X0`.
    fs::write(d.join("marlin.txt"), "M92 X0 Y80 Z400\n").unwrap();
    fails_in(
        d,
        &[
            "compensate",
            "--diagnosis",
            "diag.json",
            "--controller",
            "marlin",
            "--current",
            "marlin.txt",
        ],
        2,
        "steps per mm are above 0",
    );
    // Another controller's file as --current.
    fs::write(d.join("grbl.txt"), "$100=80.0\n$101=80.0\n$160=0.01\n").unwrap();
    fails_in(
        d,
        &[
            "compensate",
            "--diagnosis",
            "diag.json",
            "--controller",
            "linuxcnc",
            "--current",
            "grbl.txt",
        ],
        2,
        "--controller grblhal",
    );
}

#[test]
fn one_sample_far_off_the_path_is_refused_not_diagnosed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    samples(d);
    let text = fs::read_to_string(d.join("s.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    let mut f: Vec<String> = lines[10].split(',').map(str::to_string).collect();
    f[4] = "1000000".into();
    lines[10] = f.join(",");
    fs::write(d.join("glitch.csv"), lines.join("\n")).unwrap();
    fails_in(
        d,
        &["diagnose", "--samples", "glitch.csv"],
        2,
        "glitch.csv:11:",
    );
}

#[test]
fn plan_json_circles_units_and_keys_are_checked_against_the_segments() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok_in(
        d,
        &[
            "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "p",
        ],
    );
    fs::write(
        d.join("rec.csv"),
        "seq,t_us,enc1,enc2,d_mm\n0,0,0,0,90\n1,100,0,0,90\n",
    )
    .unwrap();
    let plan: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(d.join("p/plan.json")).unwrap()).unwrap();
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "units",
            Box::new(|p| p["units"] = "in".into()),
            "`units` is \"in\"",
        ),
        (
            "radius",
            Box::new(|p| p["circles"][0]["radius_mm"] = 45.0.into()),
            "circle 0",
        ),
        (
            "d",
            Box::new(|p| p["circles"][0]["d_mm"] = 91.0.into()),
            "circle 0",
        ),
        (
            "key",
            Box::new(|p| p["feed_mm_minute"] = 1000.into()),
            "feed_mm_minute",
        ),
    ];
    for (name, edit, want) in cases {
        let mut p = plan.clone();
        edit(&mut p);
        let f = format!("{name}.json");
        fs::write(d.join(&f), serde_json::to_string_pretty(&p).unwrap()).unwrap();
        fails_in(
            d,
            &["diagnose", "--record", "rec.csv", "--plan", &f],
            2,
            want,
        );
    }
}

/// Run `args` in `dir` as user and group nobody (65534).
fn run_as_nobody(dir: &Path, args: &[&str]) -> Output {
    let mut c = command();
    c.current_dir(dir).args(args);
    // SAFETY: async-signal-safe libc calls between fork and exec.
    unsafe {
        c.pre_exec(|| {
            if libc::setgroups(0, std::ptr::null()) != 0
                || libc::setgid(65534) != 0
                || libc::setuid(65534) != 0
            {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    c.output().unwrap()
}

#[test]
fn history_reads_a_read_only_database_and_never_creates_one_by_mistake() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d);
    history(d);
    // A mistyped --db: an error, and no empty database made.
    for cmd in [
        vec!["list"],
        vec!["list", "--machine", "m1"],
        vec!["trend", "--machine", "m1"],
    ] {
        let mut args = vec!["history", "--db", "hh.sqlite"];
        args.extend(cmd);
        fails_in(d, &args, 2, "check --db");
    }
    assert!(!d.join("hh.sqlite").exists());
    // A database the user may only read (another user's, in a directory not theirs).
    // SAFETY: getuid has no preconditions.
    if unsafe { libc::getuid() } != 0 {
        eprintln!("not root: cannot play another user; the read-only case is not run");
        return;
    }
    use std::os::unix::fs::PermissionsExt;
    fs::set_permissions(d, fs::Permissions::from_mode(0o755)).unwrap();
    fs::set_permissions(d.join("h.sqlite"), fs::Permissions::from_mode(0o644)).unwrap();
    let before = fs::read(d.join("h.sqlite")).unwrap();
    for cmd in [
        vec!["list"],
        vec!["list", "--machine", "m1"],
        vec!["trend", "--machine", "m1"],
    ] {
        let mut args = vec!["history", "--db", "h.sqlite"];
        args.extend(cmd.iter().copied());
        let o = run_as_nobody(d, &args);
        assert!(o.status.success(), "{cmd:?}: {}", stderr(&o));
        assert!(String::from_utf8_lossy(&o.stdout).contains("m1"));
    }
    assert_eq!(fs::read(d.join("h.sqlite")).unwrap(), before);
}

#[test]
fn a_record_with_a_hole_inside_the_data_arcs_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok_in(
        d,
        &[
            "plan",
            "--radius",
            "90",
            "--feed",
            "2000",
            "--centre",
            "100,50,-20",
            "--out",
            "p",
        ],
    );
    let text = fs::read_to_string(data("examples/ballbar-backlash.csv")).unwrap();
    // Rows with t_us in [from, to) removed: a hole in the record.
    let cut = |from: u64, to: u64| -> String {
        text.lines()
            .enumerate()
            .filter(|(_, l)| {
                l.starts_with('#') || l.starts_with("seq,") || {
                    let t: u64 = l.split(',').nth(1).unwrap().parse().unwrap();
                    t < from || t >= to
                }
            })
            .map(|(_, l)| format!("{l}\n"))
            .collect()
    };
    // The data arcs of this record are at 14.0–31.3 s and 49.8–67.1 s.
    fs::write(d.join("hole.csv"), cut(18_000_000, 26_000_000)).unwrap();
    let e = fails_in(
        d,
        &["diagnose", "--record", "hole.csv", "--plan", "p/plan.json"],
        2,
        "hole.csv:",
    );
    assert!(e.contains("a hole of") && e.contains("ccw data arc"), "{e}");
    // A hole outside the data arcs (between the directions) is no harm.
    fs::write(d.join("between.csv"), cut(40_000_000, 45_000_000)).unwrap();
    ok_in(
        d,
        &[
            "diagnose",
            "--record",
            "between.csv",
            "--plan",
            "p/plan.json",
        ],
    );
}

// ---------------------------------------------------------------------------------------------
// Issue 28: files and inputs. `--force` replaces only what jdbb wrote, never an input; a set is
// old or new after any interruption; every input read with the limits and no wait at open.

#[test]
/// Finding 2: a report folder jdbb wrote, into which the user copied the record and notes, is
/// not replaced by `--force`: the command refuses, naming the files, and they are kept.
fn force_never_deletes_the_users_files_in_a_report_folder() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    samples(d);
    let diag = [
        "diagnose",
        "--samples",
        "s.csv",
        "--pitch",
        "x=10",
        "--report",
        "rep",
    ];
    ok_in(d, &diag);
    let report = ls(&d.join("rep"));
    fs::copy(d.join("s.csv"), d.join("rep/rec.csv")).unwrap();
    fs::write(d.join("rep/notes.txt"), "spindle warm\n").unwrap();
    let mut forced = diag.to_vec();
    forced.push("--force");
    let e = fails_in(d, &forced, 2, "notes.txt");
    assert!(e.contains("rec.csv"), "{e}");
    // The input itself in the folder: refused too.
    forced[2] = "rep/rec.csv";
    fails_in(d, &forced, 2, "rep");
    assert_eq!(
        fs::read_to_string(d.join("rep/notes.txt")).unwrap(),
        "spindle warm\n"
    );
    assert_eq!(
        fs::read(d.join("rep/rec.csv")).unwrap(),
        fs::read(d.join("s.csv")).unwrap()
    );
    // What jdbb wrote alone is replaced with --force, as before.
    fs::remove_file(d.join("rep/notes.txt")).unwrap();
    fs::remove_file(d.join("rep/rec.csv")).unwrap();
    forced[2] = "s.csv";
    ok_in(d, &forced);
    assert_eq!(ls(&d.join("rep")), report);
    no_temporaries(d);
}

#[test]
/// Finding 12: an output is never one of the command's inputs, by any name (a hard link), even
/// with `--force`.
fn an_output_is_never_one_of_the_commands_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d);
    history(d);
    let db = fs::read(d.join("h.sqlite")).unwrap();
    let trend = [
        "history",
        "--db",
        "h.sqlite",
        "trend",
        "--machine",
        "m1",
        "--csv",
        "h.sqlite",
        "--force",
    ];
    fails_in(d, &trend, 2, "input");
    fs::hard_link(d.join("h.sqlite"), d.join("alias.csv")).unwrap();
    let mut other_name = trend.to_vec();
    other_name[7] = "alias.csv";
    fails_in(d, &other_name, 2, "input");
    other_name[6] = "--plot";
    fails_in(d, &other_name, 2, "input");
    assert_eq!(fs::read(d.join("h.sqlite")).unwrap(), db);
    // simulate -o over its machine file or its plan.
    ok_in(
        d,
        &[
            "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "p",
        ],
    );
    fs::write(d.join("m.toml"), ok_in(d, &["simulate", "--machine"])).unwrap();
    let machine = fs::read(d.join("m.toml")).unwrap();
    for out in ["m.toml", "p/plan.json"] {
        fails_in(
            d,
            &[
                "simulate",
                "--plan",
                "p/plan.json",
                "--machine",
                "m.toml",
                "-o",
                out,
                "--force",
            ],
            2,
            "input",
        );
    }
    assert_eq!(fs::read(d.join("m.toml")).unwrap(), machine);
    // record -o over its plan: refused before the port is opened.
    let plan = fs::read(d.join("p/plan.json")).unwrap();
    fails_in(
        d,
        &[
            "record",
            "--port",
            "/dev/nonexistent",
            "--plan",
            "p/plan.json",
            "-o",
            "p/plan.json",
            "--force",
        ],
        2,
        "input",
    );
    assert_eq!(fs::read(d.join("p/plan.json")).unwrap(), plan);
    // compensate --out over the COMP_FILE in force (the table it merges into).
    fs::write(
        d.join("x.comp"),
        "100 0.001 -0.001\n200 0.002 -0.002\n300 0.001 -0.001\n",
    )
    .unwrap();
    fs::write(
        d.join("cur.ini"),
        "[JOINT_0]\nCOMP_FILE = x.comp\nCOMP_FILE_TYPE = 1\n",
    )
    .unwrap();
    let comp = fs::read(d.join("x.comp")).unwrap();
    fails_in(
        d,
        &[
            "compensate",
            "--diagnosis",
            "diag.json",
            "--controller",
            "linuxcnc",
            "--current",
            "cur.ini",
            "--table-ball",
            "x=200,y=100",
            "--out",
            ".",
            "--force",
        ],
        2,
        "COMP_FILE x.comp",
    );
    assert_eq!(fs::read(d.join("x.comp")).unwrap(), comp);
    no_temporaries(d);
}

/// Start `args` in `dir`, send SIGINT after `after` (if it still runs); its exit code and
/// standard error.
fn interrupt_capturing(dir: &Path, args: &[&str], after: Duration) -> (Option<i32>, String) {
    let child = command()
        .current_dir(dir)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(after);
    // SAFETY: a signal to our own child (not yet waited for, so its id is still its own).
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let o = child.wait_with_output().unwrap();
    (o.status.code(), stderr(&o))
}

#[test]
/// Finding 3: `plan --force` (a set: plan.json and its program) interrupted by Ctrl-C at any
/// moment leaves the old set or the new set, never a mix, says truly which, and leaves no
/// temporary or backup file.
fn ctrl_c_during_a_set_leaves_the_old_set_or_the_new_one() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let plan = |r: &'static str, out: &'static str| {
        [
            "plan", "--radius", r, "--feed", "1000", "--centre", "0,0,0", "--out", out, "--force",
        ]
    };
    let set = |p: &Path| {
        (
            fs::read(p.join("plan.json")).unwrap(),
            fs::read(p.join("ballbar.ngc")).unwrap(),
        )
    };
    ok_in(d, &plan("85", "a"));
    ok_in(d, &plan("90", "b"));
    let sets = [set(&d.join("a")), set(&d.join("b"))];
    assert_ne!(sets[0], sets[1]);
    ok_in(d, &plan("85", "p"));
    // How long one run takes here: the interrupts are spread over it.
    let t0 = Instant::now();
    ok_in(d, &plan("90", "p"));
    let run = t0.elapsed();
    let mut current = 1;
    let mut interrupted = 0;
    for k in 0..120u32 {
        let next = 1 - current;
        let (code, e) = interrupt_capturing(d, &plan(["85", "90"][next], "p"), run * (k % 40) / 30);
        assert!(!e.contains("panicked"), "{e}");
        let now = set(&d.join("p"));
        let which = sets.iter().position(|s| *s == now);
        assert!(which.is_some(), "run {k}: a mixed set ({code:?}: {e})");
        let which = which.unwrap();
        if e.contains("no output was written") {
            assert_eq!(
                which, current,
                "run {k}: the message says nothing was written: {e}"
            );
        }
        if code == Some(0) {
            assert_eq!(which, next, "run {k}");
        }
        interrupted += usize::from(code == Some(130));
        current = which;
        let left: Vec<String> = ls(&d.join("p"))
            .into_iter()
            .filter(|n| n != "plan.json" && n != "ballbar.ngc")
            .collect();
        assert!(left.is_empty(), "run {k}: left {left:?} ({code:?}: {e})");
    }
    assert!(
        interrupted > 0,
        "no run was interrupted: the test tested nothing"
    );
}

#[test]
/// Low: `plan --force` with another dialect replaces the old program (no stale program beside
/// the new plan.json); the user's own files in the folder are kept.
fn plan_force_with_another_dialect_leaves_one_program() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let plan = [
        "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "p",
    ];
    ok_in(d, &plan);
    fs::write(d.join("p/notes.txt"), "mine").unwrap();
    let mut grbl = plan.to_vec();
    grbl.extend(["--dialect", "grbl", "--force"]);
    ok_in(d, &grbl);
    assert_eq!(ls(&d.join("p")), ["ballbar.nc", "notes.txt", "plan.json"]);
}

#[test]
/// Low: `--out link/` (a trailing slash) names the link, which is refused, not the directory it
/// points at.
fn an_output_folder_named_with_a_trailing_slash_is_not_followed() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    fs::create_dir(d.join("real")).unwrap();
    std::os::unix::fs::symlink("real", d.join("link")).unwrap();
    fails_in(
        d,
        &[
            "plan", "--radius", "90", "--feed", "1000", "--centre", "0,0,0", "--out", "link/",
        ],
        2,
        "symbolic link",
    );
    samples(d);
    fails_in(
        d,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--pitch",
            "x=10",
            "--report",
            "link/",
        ],
        2,
        "symbolic link",
    );
    assert!(ls(&d.join("real")).is_empty());
}

#[test]
/// Finding 7: the COMP_FILE named in `compensate --current` is read with the 16 MiB limit of
/// every document.
fn the_comp_file_in_force_is_read_within_the_limit() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d);
    let big = fs::File::create(d.join("x.comp")).unwrap();
    big.set_len(17 << 20).unwrap();
    fs::write(d.join("cur.ini"), "[JOINT_0]\nCOMP_FILE = x.comp\n").unwrap();
    fails_in(
        d,
        &[
            "compensate",
            "--diagnosis",
            "diag.json",
            "--controller",
            "linuxcnc",
            "--current",
            "cur.ini",
            "--table-ball",
            "x=200,y=100",
        ],
        2,
        "16 MiB",
    );
}

#[test]
/// Low: an input that is a named pipe nobody writes to does not block at its opening: it reads
/// as empty (exit 2). A pipe with a writer is read as before.
fn a_named_pipe_input_without_a_writer_does_not_wait() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    mkfifo(&d.join("fifo.csv"));
    let mut child = command()
        .current_dir(d)
        .args(["diagnose", "--samples", "fifo.csv"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let code = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s.code();
        }
        if t0.elapsed() > HANG {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    assert_eq!(code, Some(2), "blocked at the opening of the pipe");
}

#[test]
/// Finding 11: a CSV header of 205 000 names is read in linear time by every table reader: the
/// error comes within a CPU-time limit (RLIMIT_CPU) the quadratic check of names went far beyond.
fn a_header_of_200_000_names_is_read_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Three characters each: 800 kB, under the 1 MiB a line may have.
    let alphabet: Vec<char> = ('a'..='z').chain('A'..='Z').chain('0'..='9').collect();
    let names: Vec<String> = (0..205_000)
        .map(|k| {
            [k / 3844, k / 62 % 62, k % 62]
                .map(|i| alphabet[i])
                .iter()
                .collect()
        })
        .collect();
    fs::write(d.join("wide.csv"), names.join(",") + "\n").unwrap();
    for args in [
        ["diagnose", "--samples", "wide.csv"].as_slice(),
        ["diagnose-rotary", "--samples", "wide.csv"].as_slice(),
    ] {
        let mut c = command();
        c.current_dir(d).args(args);
        // SAFETY: an async-signal-safe libc call between fork and exec.
        unsafe {
            c.pre_exec(|| {
                let l = libc::rlimit {
                    rlim_cur: 10,
                    rlim_max: 10,
                };
                libc::setrlimit(libc::RLIMIT_CPU, &l);
                Ok(())
            });
        }
        let o = c.output().unwrap();
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        assert!(e.contains("wide.csv:1"), "{args:?}: {e}");
    }
}

#[test]
/// Low: a write past `ulimit -f` fails with an error and the old output kept (no silent death
/// by SIGXFSZ, no temporary file left); a temporary file of a killed jdbb is removed by the next
/// write beside it, not left to pile up.
fn a_file_size_limit_is_an_error_and_a_killed_runs_temporaries_are_cleared() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let sim = ["simulate", "--rate", "200", "-o", "sim.csv", "--force"];
    ok_in(d, &sim);
    let old = fs::read(d.join("sim.csv")).unwrap();
    let mut c = command();
    c.current_dir(d).args(sim).args(["--radius", "70"]);
    // SAFETY: an async-signal-safe libc call between fork and exec (SIGXFSZ left at its default).
    unsafe {
        c.pre_exec(|| {
            let l = libc::rlimit {
                rlim_cur: 2000,
                rlim_max: 2000,
            };
            libc::setrlimit(libc::RLIMIT_FSIZE, &l);
            Ok(())
        });
    }
    let o = c.output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("sim.csv"), "{}", stderr(&o));
    assert_eq!(fs::read(d.join("sim.csv")).unwrap(), old);
    no_temporaries(d);
    // A process that has ended (as one killed by SIGKILL) left its temporary file.
    let mut gone = command().arg("--version").spawn().unwrap();
    let pid = gone.id();
    gone.wait().unwrap();
    fs::write(d.join(format!(".sim.csv.jdbb-{pid}-0.tmp")), "half").unwrap();
    ok_in(d, &sim);
    no_temporaries(d);
}
