//! Memory of the long-record paths, checked without timing anything: `jdbb simulate --plan` and
//! `jdbb diagnose --record --plan` of a record of more than a million samples run with their
//! address space limited (RLIMIT_AS), and must finish and agree with the machine. Before issue 31
//! `simulate --plan` held every sample several times over (the path with its derived motion,
//! the samples, their lines: 734 MB for 4.16 M samples) and `diagnose` held two passes' data at
//! once; either runs out of this limit on this record and aborts.
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::Output;

mod common;
use common::command;

/// The address-space limit: the program, its libraries and everything it allocates.
const LIMIT_BYTES: u64 = 200 << 20;

/// Run `args` in `dir` with the address space limited to [`LIMIT_BYTES`].
fn run_limited(dir: &Path, args: &[&str]) -> Output {
    let mut c = command();
    c.current_dir(dir).args(args);
    // SAFETY: an async-signal-safe libc call between fork and exec.
    unsafe {
        c.pre_exec(|| {
            let l = libc::rlimit {
                rlim_cur: LIMIT_BYTES,
                rlim_max: LIMIT_BYTES,
            };
            libc::setrlimit(libc::RLIMIT_AS, &l);
            Ok(())
        });
    }
    c.output().unwrap()
}

#[test]
fn a_record_of_over_a_million_samples_is_simulated_and_diagnosed_in_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let o = command()
        .current_dir(d)
        .args([
            "plan",
            "--radius",
            "90",
            "--feed",
            "1000",
            "--centre",
            "100,50,-20",
            "--out",
            "p",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    std::fs::write(
        d.join("m.toml"),
        "[instrument]\nsample_rate_hz = 10000\nnoise_um = 0.2\n[effects]\nbacklash_x = 6.0\n",
    )
    .unwrap();
    let o = run_limited(
        d,
        &[
            "simulate",
            "--plan",
            "p/plan.json",
            "--machine",
            "m.toml",
            "-o",
            "rec.csv",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let samples = std::fs::read_to_string(d.join("rec.csv"))
        .unwrap()
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .count();
    assert!(samples > 1_000_000, "{samples}");
    assert!(
        err.contains(&format!("{samples} samples at 10000 Hz")),
        "{err}"
    );
    let o = run_limited(
        d,
        &[
            "diagnose",
            "--record",
            "rec.csv",
            "--plan",
            "p/plan.json",
            "--json",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let backlash = json["effects"]
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["name"] == "backlash_x")
        .unwrap_or_else(|| panic!("backlash_x not named: {json}"));
    let v = backlash["value"].as_f64().unwrap();
    assert!((v - 6.0).abs() < 0.05, "{v}");
}
