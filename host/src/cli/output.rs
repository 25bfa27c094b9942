//! Writing what a command produces on standard output and standard error (files are written by
//! [`crate::fsio`]).
//!
//! A reader that goes away (`jdbb diagnose ... | head -1`, `| true`) ends the printing quietly —
//! the command still finishes its other work (files) and exits 0 — while a real write failure
//! (`> /dev/full`) is an error that names standard output (exit 1). Nothing here panics, unlike
//! `println!`.
use std::io::Write;

use crate::{Error, Result};

/// Write `text` and a newline to standard output (see the module docs).
pub fn emit(text: &str) -> Result<()> {
    print(&format!("{text}\n"))
}

/// Write `text` as it is to standard output (see the module docs).
pub fn print(text: &str) -> Result<()> {
    write_stdout(text.as_bytes())
}

/// Write bytes to standard output and flush (see the module docs).
pub fn write_stdout(bytes: &[u8]) -> Result<()> {
    let mut out = std::io::stdout().lock();
    stdout_result(out.write_all(bytes).and_then(|_| out.flush()))
}

/// The outcome of writing to standard output: a closed pipe is not an error, any other failure
/// is (see the module docs).
pub fn stdout_result(r: std::io::Result<()>) -> Result<()> {
    match r {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        Err(source) => Err(Error::Stdout { source }),
        Ok(()) => Ok(()),
    }
}

/// Write `text` and a newline to standard error, ignoring a failure: a note or a progress line
/// must not end a command (`2>/dev/full`, a closed pipe), unlike `eprintln!`, which panics.
pub fn note(text: &str) {
    let mut err = std::io::stderr().lock();
    let _ = err.write_all(text.as_bytes());
    let _ = err.write_all(b"\n");
    let _ = err.flush();
}

/// Pretty JSON of a value made of numbers and strings (cannot fail).
pub fn json_text(v: &serde_json::Value) -> String {
    serde_json::to_string_pretty(v).expect("JSON of plain values")
}
