//! `diagnose --report DIR --pdf`: `report.pdf`, the printable report — `report.html` printed by
//! headless Chromium (`--print-to-pdf`) through the page's print stylesheet ([`crate::report::html`]):
//! A4, page one the machine, the test, the verdict, the polar plot and the ranked effects; the
//! conditions, G and H and the per-circle plots on the pages after.
//!
//! Why Chromium and not a PDF crate: the PDF is the page a person already reads, laid out once —
//! the polar plot stays the same vector SVG, the text stays text (searchable, copyable), and a
//! change to the report changes both. A PDF crate (printpdf, genpdf) would need the report laid
//! out a second time by hand, tables and SVG included, and kept in step with the page. The cost
//! is a program to install for `--pdf` only (Debian: `apt install chromium`); it is looked for
//! before any work, and its absence is said with what to install.
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::{Error, Result};

/// The option that needs Chromium, for messages.
const OPTION: &str = "--pdf";

/// Longest a print may take before Chromium is stopped.
const PRINT_TIMEOUT: Duration = Duration::from_secs(120);

/// The Chromium binary to print with: `JDBB_CHROMIUM` if set, else the first of `chromium`,
/// `chromium-browser`, `chromium-headless-shell`, `google-chrome` on `PATH`. Err says what to
/// install.
pub fn find_chromium() -> Result<PathBuf> {
    if let Some(p) = std::env::var_os("JDBB_CHROMIUM") {
        let p = PathBuf::from(p);
        return if p.is_file() {
            Ok(p)
        } else {
            Err(Error::Program {
                option: OPTION,
                program: "Chromium",
                message: format!(
                    "JDBB_CHROMIUM names {}, which is not a file; name the chromium binary, or unset it to use the one on PATH",
                    p.display()
                ),
            })
        };
    }
    let path = std::env::var_os("PATH").unwrap_or_default();
    for name in [
        "chromium",
        "chromium-browser",
        "chromium-headless-shell",
        "google-chrome",
    ] {
        for dir in std::env::split_paths(&path) {
            let p = dir.join(name);
            if p.is_file() {
                return Ok(p);
            }
        }
    }
    Err(Error::Program {
        option: OPTION,
        program: "Chromium",
        message: "no chromium, chromium-browser, chromium-headless-shell or google-chrome on PATH. Install it (Debian and Ubuntu: `sudo apt install chromium`), or name the binary in JDBB_CHROMIUM; or leave out --pdf and print report.html from a browser".into(),
    })
}

/// Print `html` (a file) to `pdf` with `chromium`, its profile in `scratch` (a directory this
/// creates and removes). A failed or hung print is an error saying so; `pdf` is then absent or
/// incomplete, which the caller's staging discards.
pub fn print_to_pdf(chromium: &Path, html: &Path, pdf: &Path, scratch: &Path) -> Result<()> {
    let failed = |message: String| Error::Program {
        option: OPTION,
        program: "Chromium",
        message,
    };
    let url = format!(
        "file://{}",
        std::path::absolute(html)
            .map_err(|e| failed(format!("cannot name {}: {e}", html.display())))?
            .display()
    );
    let mut child = Command::new(chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-pdf-header-footer",
            &format!("--user-data-dir={}", scratch.display()),
            &format!("--print-to-pdf={}", pdf.display()),
            &url,
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| failed(format!("{} would not start: {e}", chromium.display())))?;
    let t0 = Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break Ok(s),
            Ok(None) if t0.elapsed() > PRINT_TIMEOUT => {
                let _ = child.kill();
                let _ = child.wait();
                break Err(failed(format!(
                    "{} did not print report.html within {} s; try again, or print report.html from a browser",
                    chromium.display(),
                    PRINT_TIMEOUT.as_secs()
                )));
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(50)),
            Err(e) => break Err(failed(format!("waiting for {}: {e}", chromium.display()))),
        }
    };
    let _ = std::fs::remove_dir_all(scratch);
    let status = status?;
    let printed = std::fs::read(pdf)
        .map(|b| b.starts_with(b"%PDF"))
        .unwrap_or(false);
    if !status.success() || !printed {
        return Err(failed(format!(
            "{} exited with {status} without printing report.html to a PDF; check that it runs (`{} --headless --version`), or print report.html from a browser",
            chromium.display(),
            chromium.display()
        )));
    }
    Ok(())
}
