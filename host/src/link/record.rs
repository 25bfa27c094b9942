//! Recording: samples from a device to a CSV file `seq,t_us,enc1,enc2,d_mm` (`jdbb record`).
//!
//! Crash safety: lines are formatted into a memory buffer and handed to the file with one
//! `write` per read from the port (every batch that read completed, ≤ [`READ_TIMEOUT`] apart), so
//! the file grows by whole lines only and holds every sample received up to the latest read.
//! Ctrl-C stops cleanly (flush, sync, summary); a killed process (SIGKILL) leaves the file as of
//! its last write — a valid CSV. (A kill *during* a multi-page `write` system call could in
//! principle cut it at a page boundary; the writes here are a few kB and last microseconds.)
//!
//! [`READ_TIMEOUT`]: super::stream::READ_TIMEOUT
use std::fs::File;
use std::io::{Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use jdbb_core::protocol::DeviceInfo;

use super::stream::{Poll, SeqSample, Stats, Stream};
use crate::{Error, Result};

/// First line of every recording.
pub const CSV_HEADER: &str = "seq,t_us,enc1,enc2,d_mm\n";

/// Append one CSV line per sample to `out`: `seq,t_us,enc1,enc2,d_mm`, D with 7 decimals
/// (0.1 nm; the on-chip D is good to ~10 nm).
pub fn write_csv_lines(out: &mut Vec<u8>, samples: &[SeqSample]) {
    for s in samples {
        let x = &s.sample;
        // Writing to a Vec cannot fail.
        let _ = writeln!(
            out,
            "{},{},{},{},{:.7}",
            s.seq, x.t_us, x.enc1, x.enc2, x.d_mm
        );
    }
}

/// How a streaming session ended.
#[derive(Debug)]
pub enum End {
    /// `--seconds` elapsed.
    Time,
    /// Ctrl-C.
    Interrupted,
    /// The source ended (EOF) or failed (unplugged): the error to report.
    Lost(Error),
}

impl End {
    /// Words for the summary.
    pub fn describe(&self) -> String {
        match self {
            End::Time => "time limit reached".into(),
            End::Interrupted => "interrupted".into(),
            End::Lost(e) => format!("device lost: {e}"),
        }
    }
}

/// One line summing up a session: counts, duration and mean rate.
pub fn summary(stats: &Stats, seconds: f64) -> String {
    let rate = if seconds > 0.0 {
        stats.samples as f64 / seconds
    } else {
        0.0
    };
    format!("{stats}; {seconds:.2} s, {rate:.1} samples/s")
}

/// The error for a device that closed the connection.
pub fn port_lost(port: &str) -> Error {
    Error::PortRead {
        port: port.to_string(),
        source: std::io::Error::new(
            std::io::ErrorKind::UnexpectedEof,
            "the device closed the connection",
        ),
    }
}

/// Create the output file with its header. Done before the port is opened, so an unwritable path
/// fails before anything is sent to the device.
pub fn create_output(path: &Path) -> Result<File> {
    let file_err = |action, source| Error::File {
        action,
        path: path.to_path_buf(),
        source,
    };
    let mut file = File::create(path).map_err(|e| file_err("cannot create", e))?;
    file.write_all(CSV_HEADER.as_bytes())
        .map_err(|e| file_err("cannot write", e))?;
    Ok(file)
}

/// Stream from `stream` into `file` (named `path` in errors) until `deadline`, `interrupted` or the
/// device goes away; `on_info` is called once, when the device first describes itself. Whatever
/// was decoded is written before anything else happens (module docs). Returns how it ended.
pub fn record_to<P: Read + Write>(
    stream: &mut Stream<P>,
    file: &mut File,
    path: &Path,
    deadline: Option<Instant>,
    interrupted: &AtomicBool,
    on_info: &mut dyn FnMut(&DeviceInfo),
) -> Result<End> {
    let write_err = |source| Error::File {
        action: "cannot write",
        path: path.to_path_buf(),
        source,
    };
    let mut lines = Vec::with_capacity(1 << 16);
    let mut info_shown = false;
    let port = stream.name().to_string();
    let end = loop {
        if interrupted.load(Ordering::SeqCst) {
            break End::Interrupted;
        }
        if deadline.is_some_and(|d| Instant::now() >= d) {
            break End::Time;
        }
        let polled = stream.poll(|batch| write_csv_lines(&mut lines, batch));
        if !lines.is_empty() {
            file.write_all(&lines).map_err(write_err)?;
            lines.clear();
        }
        if !info_shown {
            if let Some(info) = stream.info() {
                on_info(info);
                info_shown = true;
            }
        }
        match polled {
            Ok(Poll::Closed) => break End::Lost(port_lost(&port)),
            Err(e) => break End::Lost(e),
            Ok(_) => {}
        }
    };
    Ok(end)
}

#[cfg(test)]
mod tests {
    use super::*;
    use jdbb_core::protocol::{Sample, Status};

    #[test]
    fn csv_lines_are_whole_and_exact() {
        let s = |seq, d_mm| SeqSample {
            seq,
            sample: Sample {
                t_us: 1_000 * seq,
                enc1: -7,
                enc2: 123_456,
                d_mm,
                status: Status(0),
            },
        };
        let mut out = Vec::new();
        write_csv_lines(&mut out, &[s(0, 100.0), s(1, 99.999_987_654_321)]);
        assert_eq!(
            String::from_utf8(out).unwrap(),
            "0,0,-7,123456,100.0000000\n1,1000,-7,123456,99.9999877\n"
        );
    }

    #[test]
    fn summary_gives_rate() {
        let st = Stats {
            samples: 2000,
            ..Stats::default()
        };
        let line = summary(&st, 2.0);
        assert!(line.contains("samples 2000"), "{line}");
        assert!(line.contains("1000.0 samples/s"), "{line}");
    }

    #[test]
    fn unwritable_output_fails_before_the_port() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("no/such/dir/x.csv");
        let e = create_output(&out).unwrap_err();
        assert!(e.to_string().contains("cannot create"), "{e}");
    }
}
