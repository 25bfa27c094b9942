//! What the host's integration tests share: running the `jdbb` binary they were built with.
// Each test file is its own crate and uses some of these.
#![allow(dead_code)]
use std::path::Path;
use std::process::{Command, Output};

/// The one tolerance rule for a recovered value: the file of `jdbb_tests::tolerance` (the host's
/// tests do not depend on the tests' crate), included, not copied.
#[path = "../../../tests/src/tolerance.rs"]
pub mod tolerance;

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
