//! What the host's integration tests share: running the `jdbb` binary they were built with.
// Each test file is its own crate and uses some of these.
#![allow(dead_code)]
use std::path::Path;
use std::process::{Command, Output};

/// The one tolerance rule for a recovered value: the file of `jdbb_tests::tolerance` (the host's
/// tests do not depend on the tests' crate), included, not copied.
#[path = "../../../tests/src/tolerance.rs"]
pub mod tolerance;

pub mod pg;

/// A diagnosis file `name` in `dir` of a machine with `backlash_um` of play (σ `sigma_um`),
/// tested on `date`: what the history tests file.
pub fn diagnosis(dir: &Path, name: &str, backlash_um: f64, sigma_um: f64, date: &str) {
    let text = serde_json::json!({
        "format": 2,
        "samples": 1000,
        "effects": [
            {"name": "setup_offset", "value": 1.0, "unit": "um", "sigma": 0.1, "setup": true,
             "params": {"x_um": 1.0, "y_um": 0.0, "z_um": 0.0}},
            {"name": "backlash_x", "value": backlash_um, "unit": "um", "sigma": sigma_um,
             "params": {"b_um": backlash_um}}
        ],
        "final": {"rms_um": 0.3},
        "plane": "xy",
        "circles": [{"radius_mm": 50.0, "height_mm": 0.0, "feed_mm_min": 1000.0, "samples": 500,
                     "g_um": 5.0, "h_um": 3.0}],
        "date_utc": date,
    });
    std::fs::write(dir.join(name), serde_json::to_string_pretty(&text).unwrap()).unwrap();
}

/// The `jdbb` binary of this build, to be given arguments.
pub fn command() -> Command {
    Command::new(env!("CARGO_BIN_EXE_jdbb"))
}

/// `jdbb ARGS` in the current directory.
pub fn jdbb(args: &[&str]) -> Output {
    command().args(args).output().expect("run jdbb")
}

/// `jdbb ARGS` in `dir`.
pub fn jdbb_in(dir: &Path, args: &[&str]) -> Output {
    command()
        .current_dir(dir)
        .args(args)
        .output()
        .expect("run jdbb")
}

/// Its standard error, as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Its standard output, as text.
pub fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// `jdbb ARGS`, which must succeed: its standard output.
pub fn ok(args: &[&str]) -> String {
    let o = jdbb(args);
    assert!(o.status.success(), "jdbb {args:?}: {}", stderr(&o));
    stdout(&o)
}

/// `jdbb ARGS` in `dir`, which must succeed: its standard output.
pub fn ok_in(dir: &Path, args: &[&str]) -> String {
    let o = jdbb_in(dir, args);
    assert!(o.status.success(), "jdbb {args:?}: {}", stderr(&o));
    stdout(&o)
}

/// The machine effects `diagnose --json` names (set-up excluded): (name, value).
pub fn named(json: &str) -> Vec<(String, f64)> {
    let v: serde_json::Value = serde_json::from_str(json).unwrap();
    v["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["setup"] == false)
        .map(|e| {
            (
                e["name"].as_str().unwrap().to_string(),
                e["value"].as_f64().unwrap(),
            )
        })
        .collect()
}
