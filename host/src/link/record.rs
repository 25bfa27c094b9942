//! Recording: samples from a device to a CSV file `seq,t_us,enc1,enc2,d_mm` (`jdbb record`).
//!
//! **One run per file.** A record holds exactly the run the recorder started: the stream
//! delivers nothing from before the device acknowledged the Start
//! ([`stream`](super::stream) module docs), so `seq` begins at 0 and `t_us` increases
//! strictly; a device restart during the record ends it with what it has ([`End::Restarted`]),
//! never stitching the next run on. Listening without Start (`--no-start`) records what comes,
//! one run too.
//!
//! **Files.** The port is opened first; the recording goes into `OUT.partial`, created new (never
//! an existing file), and is renamed to `OUT` at the end, whatever the end (time, Ctrl-C, SIGTERM,
//! SIGHUP, the device lost or restarted, a write error): nothing the recorder did not create is
//! removed or cut. An existing `OUT` is replaced only with `--force`, and a link or anything but a
//! regular file never ([`check_output`], [`finish_output`]).
//!
//! **Whole lines.** Lines are formatted into a memory buffer and handed to the file with one
//! `write` per read from the port (every batch that read completed, ≤ [`READ_TIMEOUT`] apart), so
//! the file grows by whole lines only and holds every sample received up to the latest read. A
//! write that fails (full disk) is cut back to the last whole line ([`CsvOut`]) and ends the
//! record. A killed process (SIGKILL) leaves `OUT.partial` as of its last write — a valid CSV. (A
//! kill *during* a multi-page `write` system call could in principle cut it at a page boundary;
//! the writes here are a few kB and last microseconds.)
//!
//! **The instrument.** When the device first describes itself, the record gets a comment line
//! `# instrument_serial: <24 hex digits>` ([`crate::table::INSTRUMENT_SERIAL`]): right after the
//! header as a device greets before it streams, so a report can name the instrument; readers skip
//! it as every comment line.
//!
//! [`READ_TIMEOUT`]: super::stream::READ_TIMEOUT
use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use jdbb_core::protocol::DeviceInfo;

use super::stream::{Poll, Restart, SeqSample, Stats, Stream};
use crate::{Error, Result};

/// First line of every recording.
pub const CSV_HEADER: &str = "seq,t_us,enc1,enc2,d_mm\n";

/// The text a record starts with: a `# key: value` comment line per entry of `comments` (e.g. the
/// plan's id, which readers find with `Table::header_comment`), then [`CSV_HEADER`].
pub fn header(comments: &[(&str, String)]) -> String {
    let mut s = String::new();
    for (k, v) in comments {
        s.push_str(&format!("# {k}: {v}\n"));
    }
    s.push_str(CSV_HEADER);
    s
}

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

/// Samples the recorder set aside, by reason ([`SampleCheck`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Suspects {
    /// D is NaN or infinite.
    pub d_not_finite: u64,
    /// D is outside the instrument's physical range for the device's calibration: below D at
    /// the frames' mechanical limit (±75°) or above l1 + l2 (a ball distance no instrument of
    /// these bars can show).
    pub d_impossible: u64,
    /// D is outside the range the plan's program moves the instrument through (with
    /// [`PLAN_RANGE_MARGIN_MM`]; `jdbb record --plan` only).
    pub d_off_plan: u64,
    /// An encoder's count is more than a turn from zero (the frames reach ±86°).
    pub counts_out_of_range: u64,
    /// `t_us` is before the previous sample's.
    pub time_back: u64,
    /// `t_us` jumps more than [`MAX_TIME_JUMP_US`] ahead of the previous sample's: a corrupted
    /// time (2⁶⁴ − 1), which would make every later sample seem to go back.
    pub time_ahead: u64,
    /// `t_us` equals the previous sample's.
    pub time_still: u64,
}

impl Suspects {
    /// All samples set aside.
    pub fn total(&self) -> u64 {
        self.d_not_finite
            + self.d_impossible
            + self.d_off_plan
            + self.counts_out_of_range
            + self.time_back
            + self.time_ahead
            + self.time_still
    }
}

impl std::fmt::Display for Suspects {
    /// `suspect samples N (D not finite a, D impossible b, D off the plan c, counts out of
    /// range d, time back e, time ahead f, time standing still g), kept as `# suspect` comment
    /// lines`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "suspect samples {} (D not finite {}, D impossible {}, D off the plan {}, counts out of range {}, time back {}, time ahead {}, time standing still {}), kept in the file as `{SUSPECT_PREFIX}` comment lines that readers skip",
            self.total(),
            self.d_not_finite,
            self.d_impossible,
            self.d_off_plan,
            self.counts_out_of_range,
            self.time_back,
            self.time_ahead,
            self.time_still
        )
    }
}

/// Start of the comment line a suspect sample is written as: `# suspect: seq,t_us,enc1,enc2,d_mm:
/// reason`. The readers skip comment lines, so the file stays valid, the sample stays visible,
/// and the gap in `seq` shows where it was.
pub const SUSPECT_PREFIX: &str = "# suspect:";

/// What the recorder checks of each sample before it becomes a data line: D finite and inside
/// the instrument's physical range (and the plan's, with `--plan`), counts within a turn, time
/// strictly increasing and not ahead of the host's clock. A sample that fails is counted
/// ([`Suspects`]) and written as a [`SUSPECT_PREFIX`] comment line, never silently; the samples
/// after it are checked against the last time that held, so one bad time costs one sample.
#[derive(Debug, Clone)]
pub struct SampleCheck {
    d_min_mm: f64,
    d_max_mm: f64,
    /// The plan's range of D, widened by [`PLAN_RANGE_MARGIN_MM`] (`--plan` only).
    plan_mm: Option<(f64, f64)>,
    counts_max: i64,
    /// The last `t_us` that held (not back, still or ahead), whatever that sample's D.
    last_t_us: Option<u64>,
    /// The time of the last sample, if it was set aside for jumping ahead: a next sample that
    /// goes on from it shows the jump was real.
    ahead_t_us: Option<u64>,
    /// The samples set aside so far.
    pub suspects: Suspects,
}

/// Slack (mm) below the instrument's D at the frames' mechanical limit before a D is called
/// impossible: the calibration's bar lengths are known to µm, this is far beyond.
pub const RANGE_SLACK_MM: f64 = 0.1;

/// How far (mm) D may leave the range the plan's program moves the instrument through before a
/// sample is called off the plan: set-up errors (the table ball's placement) are far smaller.
pub const PLAN_RANGE_MARGIN_MM: f64 = 1.0;

/// The longest step (µs) of `t_us` from one sample to the next taken as it is: 10 s. A longer
/// one is a corrupted time unless the next sample goes on from it (samples the device dropped
/// over a long stall of the link), which then costs that one sample, marked.
pub const MAX_TIME_JUMP_US: u64 = 10_000_000;

impl Default for SampleCheck {
    fn default() -> Self {
        let mut c = SampleCheck {
            d_min_mm: 0.0,
            d_max_mm: 0.0,
            plan_mm: None,
            counts_max: 0,
            last_t_us: None,
            ahead_t_us: None,
            suspects: Suspects::default(),
        };
        c.set_calibration(&jdbb_core::calib::Calibration::DEFAULT);
        c
    }
}

impl SampleCheck {
    /// Check against the bars and encoders of `cal` (the device's, once it describes itself):
    /// D from the frames' mechanical limit ([`FRAME_RANGE_RAD`], less [`RANGE_SLACK_MM`]) to
    /// l1 + l2.
    ///
    /// [`FRAME_RANGE_RAD`]: jdbb_core::geometry::FRAME_RANGE_RAD
    pub fn set_calibration(&mut self, cal: &jdbb_core::calib::Calibration) {
        use jdbb_core::geometry::{distance_from_deflection_mm, FRAME_RANGE_RAD};
        self.d_max_mm = cal.l1_mm + cal.l2_mm;
        self.d_min_mm = (distance_from_deflection_mm(cal.l1_mm, cal.l2_mm, FRAME_RANGE_RAD)
            - RANGE_SLACK_MM)
            .max(0.0);
        self.counts_max = i64::from(cal.enc1.counts_per_rev.max(cal.enc2.counts_per_rev));
    }

    /// Check D against the range the plan's program moves the instrument through, `lo..hi`
    /// (mm; [`crate::plan::Plan::mounted_d_range_mm`]: the segments after the stop),
    /// widened by [`PLAN_RANGE_MARGIN_MM`].
    pub fn set_plan_range(&mut self, lo: f64, hi: f64) {
        self.plan_mm = Some((lo - PLAN_RANGE_MARGIN_MM, hi + PLAN_RANGE_MARGIN_MM));
    }

    /// Why `s` is suspect, if it is (and count it).
    fn verdict(&mut self, s: &SeqSample) -> Option<&'static str> {
        let x = &s.sample;
        let last = self.last_t_us;
        let ahead = last.is_some_and(|l| x.t_us > l.saturating_add(MAX_TIME_JUMP_US))
            && !self
                .ahead_t_us
                .is_some_and(|a| x.t_us > a && x.t_us - a <= MAX_TIME_JUMP_US);
        // The next sample's time is checked against this one's if this one's time holds,
        // whatever its D: a corrupted time costs one sample, not every one after it.
        if ahead {
            self.ahead_t_us = Some(x.t_us);
        } else if last.is_none_or(|l| x.t_us > l) {
            self.last_t_us = Some(x.t_us);
            self.ahead_t_us = None;
        }
        let why = if !x.d_mm.is_finite() {
            self.suspects.d_not_finite += 1;
            "D is not finite"
        } else if !(x.d_mm > 0.0 && x.d_mm >= self.d_min_mm && x.d_mm <= self.d_max_mm) {
            self.suspects.d_impossible += 1;
            "D is outside the instrument's range (frames' limit to l1 + l2 of the device's bars)"
        } else if self
            .plan_mm
            .is_some_and(|(lo, hi)| x.d_mm < lo || x.d_mm > hi)
        {
            self.suspects.d_off_plan += 1;
            "D is outside the range the plan's program moves the instrument through"
        } else if x.enc1.abs() > self.counts_max || x.enc2.abs() > self.counts_max {
            self.suspects.counts_out_of_range += 1;
            "an encoder count is more than a turn from zero"
        } else if last.is_some_and(|l| x.t_us < l) {
            self.suspects.time_back += 1;
            "t_us goes back"
        } else if last == Some(x.t_us) {
            self.suspects.time_still += 1;
            "t_us stands still"
        } else if ahead {
            self.suspects.time_ahead += 1;
            "t_us jumps ahead by more than 10 s"
        } else {
            return None;
        };
        Some(why)
    }

    /// Append the lines of `samples` to `lines` (data lines, or suspect comment lines) and the
    /// samples that became data lines to `good`.
    pub fn lines(&mut self, lines: &mut Vec<u8>, good: &mut Vec<SeqSample>, samples: &[SeqSample]) {
        for s in samples {
            match self.verdict(s) {
                None => {
                    write_csv_lines(lines, std::slice::from_ref(s));
                    good.push(*s);
                }
                Some(why) => {
                    let x = &s.sample;
                    // Writing to a Vec cannot fail.
                    let _ = writeln!(
                        lines,
                        "{SUSPECT_PREFIX} {},{},{},{},{}: {why}",
                        s.seq, x.t_us, x.enc1, x.enc2, x.d_mm
                    );
                }
            }
        }
    }
}

/// How a streaming session ended.
#[derive(Debug)]
pub enum End {
    /// `--seconds` elapsed.
    Time,
    /// The plan's program ended (`jdbb record --plan`).
    ProgramEnded,
    /// Ctrl-C, SIGTERM or SIGHUP.
    Interrupted,
    /// The source ended (EOF) or failed (unplugged): the error to report.
    Lost(Error),
    /// The device restarted (one-run mode): the run ends with the last sample before it.
    Restarted(Restart),
    /// The device refused or never acknowledged the Start.
    NotStarted(Error),
    /// The output could not be written (full disk): the error to report. The file ends with
    /// the last whole line written.
    Write(Error),
}

impl End {
    /// Words for the summary.
    pub fn describe(&self) -> String {
        match self {
            End::Time => "time limit reached".into(),
            End::ProgramEnded => "the plan's program ended".into(),
            End::Interrupted => "interrupted".into(),
            End::Lost(e) => format!("device lost: {e}"),
            End::Restarted(r) => format!("stopped: {r}"),
            End::NotStarted(_) => "not started".into(),
            End::Write(_) => "stopped: write error".into(),
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

/// The work file a recording to `out` is written in: `OUT.partial`.
pub fn partial_path(out: &Path) -> PathBuf {
    let mut s = OsString::from(out.as_os_str());
    s.push(".partial");
    PathBuf::from(s)
}

/// Check that a recording may be put at `out`: nothing there, or (with `force`) a regular file
/// to be replaced. A symbolic link, a directory, a device (`/dev/null`), a pipe or a socket is
/// refused whatever `force` says. Touches nothing.
pub fn check_output(out: &Path, force: bool) -> Result<()> {
    crate::fsio::check_destination(out, force)
}

/// Create the work file `partial` (it must not exist: never an existing file, never through a
/// link) and write `header` (see [`header`]).
pub fn create_partial(partial: &Path, header: &str) -> Result<File> {
    let mut file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(partial)
        .map_err(|source| {
            if source.kind() == io::ErrorKind::AlreadyExists {
                Error::PartialExists {
                    path: partial.to_path_buf(),
                }
            } else {
                Error::File {
                    action: "cannot create",
                    path: partial.to_path_buf(),
                    source,
                }
            }
        })?;
    file.write_all(header.as_bytes())
        .map_err(|source| Error::File {
            action: "cannot write",
            path: partial.to_path_buf(),
            source,
        })?;
    Ok(file)
}

/// Put the finished work file `partial` in place as `out`. Without `force`, never over a file
/// that appeared meanwhile (a hard link fails if `out` exists; where the file system has none,
/// `out` is checked just before the rename). With `force`, `out` is replaced (a link itself, not
/// its target).
pub fn finish_output(partial: &Path, out: &Path, force: bool) -> Result<()> {
    let appeared = || Error::OutputAppeared {
        out: out.to_path_buf(),
        partial: partial.to_path_buf(),
    };
    let rename = || {
        fs::rename(partial, out).map_err(|source| Error::File {
            action: "cannot rename the recording to",
            path: out.to_path_buf(),
            source,
        })
    };
    if force {
        // What is at `out` now may have changed while recording: a link or a device node that
        // appeared meanwhile is left alone (the recording stays in `partial`).
        return match crate::fsio::check_destination(out, true) {
            Ok(()) => rename(),
            Err(_) => Err(appeared()),
        };
    }
    match fs::hard_link(partial, out) {
        Ok(()) => fs::remove_file(partial).map_err(|source| Error::File {
            action: "cannot remove",
            path: partial.to_path_buf(),
            source,
        }),
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => Err(appeared()),
        Err(_) => match fs::symlink_metadata(out) {
            Err(e) if e.kind() == io::ErrorKind::NotFound => rename(),
            _ => Err(appeared()),
        },
    }
}

/// A file that can be cut back to a length after a failed write.
pub trait Truncate {
    /// Make the file `len` bytes long and continue writing there.
    fn truncate_to(&mut self, len: u64) -> io::Result<()>;
}

impl Truncate for File {
    fn truncate_to(&mut self, len: u64) -> io::Result<()> {
        self.set_len(len)?;
        self.seek(SeekFrom::Start(len))?;
        Ok(())
    }
}

/// The CSV being written: whole lines only. `committed` bytes (header included) are whole lines;
/// a write that fails is cut back to them.
pub struct CsvOut<W> {
    /// The file.
    pub file: W,
    /// Bytes of whole lines in the file.
    pub committed: u64,
    /// The last sample whose line is in the file.
    pub last: Option<SeqSample>,
    /// Data lines in the file.
    pub lines: u64,
    /// What is checked of each sample, and the suspects so far.
    pub check: SampleCheck,
}

impl<W: Write + Truncate> CsvOut<W> {
    /// A CSV whose first `committed` bytes (the header) are written.
    pub fn new(file: W, committed: u64) -> Self {
        CsvOut {
            file,
            committed,
            last: None,
            lines: 0,
            check: SampleCheck::default(),
        }
    }

    /// Append `bytes` (whole lines for `samples`). On failure the file is cut back to its last
    /// whole line and the write error returned (with the cut's error, if that failed too).
    pub fn append(&mut self, bytes: &[u8], samples: &[SeqSample]) -> io::Result<()> {
        if bytes.is_empty() {
            return Ok(());
        }
        if let Err(e) = self.file.write_all(bytes).and_then(|()| self.file.flush()) {
            return Err(match self.file.truncate_to(self.committed) {
                Ok(()) => e,
                Err(cut) => io::Error::new(
                    e.kind(),
                    format!("{e}; cutting back to the last whole line failed too: {cut}"),
                ),
            });
        }
        self.committed += bytes.len() as u64;
        self.lines += samples.len() as u64;
        if let Some(s) = samples.last() {
            self.last = Some(*s);
        }
        Ok(())
    }
}

/// Where a recording stands: the last line in the file, for messages.
pub fn position(lines: u64, last: Option<&SeqSample>) -> String {
    match last {
        Some(s) => format!(
            "{lines} samples, the last seq {}, t_us {}",
            s.seq, s.sample.t_us
        ),
        None => "no sample".into(),
    }
}

/// Stream from `stream` into `out` (named `path` in errors) until `deadline`, `interrupted`, the
/// device goes away or restarts, the Start is not acknowledged, or a write fails; `on_info` is
/// called once, when the device first describes itself. Whatever was decoded is written before
/// anything else happens (module docs). The stream is put in one-run mode. Returns how it ended.
pub fn record_to<P: Read + Write, W: Write + Truncate>(
    stream: &mut Stream<P>,
    out: &mut CsvOut<W>,
    path: &Path,
    deadline: Option<Instant>,
    interrupted: &AtomicBool,
    on_info: &mut dyn FnMut(&DeviceInfo),
) -> End {
    record_watched(
        stream,
        out,
        path,
        deadline,
        interrupted,
        on_info,
        &mut |_, _| false,
    )
}

/// [`record_to`], with `watch` shown the samples of every read once they are in the file
/// (possibly none), with the stream's counts so far — after they are in the file, so an
/// observer (the live page) sees nothing the file does not hold and cannot delay a write; it
/// must not block. It returns true to end the record ([`End::ProgramEnded`]: `jdbb record
/// --plan` stops after the program's end).
pub fn record_watched<P: Read + Write, W: Write + Truncate>(
    stream: &mut Stream<P>,
    out: &mut CsvOut<W>,
    path: &Path,
    deadline: Option<Instant>,
    interrupted: &AtomicBool,
    on_info: &mut dyn FnMut(&DeviceInfo),
    watch: &mut dyn FnMut(&[SeqSample], &Stats) -> bool,
) -> End {
    stream.set_one_run(true);
    let mut lines = Vec::with_capacity(1 << 16);
    let mut batch = Vec::new();
    let mut info_shown = false;
    let port = stream.name().to_string();
    loop {
        if interrupted.load(Ordering::SeqCst) {
            return End::Interrupted;
        }
        if deadline.is_some_and(|d| Instant::now() >= d) {
            return End::Time;
        }
        let check = &mut out.check;
        let polled = stream.poll(|b| check.lines(&mut lines, &mut batch, b));
        // The device's description first: its serial line goes before the samples of the read
        // that brought it.
        if !info_shown {
            if let Some(info) = stream.info() {
                out.check.set_calibration(&info.calibration);
                let serial = format!(
                    "# {}: {}\n",
                    crate::table::INSTRUMENT_SERIAL,
                    super::stream::serial_number(info)
                );
                if let Err(source) = out.append(serial.as_bytes(), &[]) {
                    return End::Write(Error::RecordWrite {
                        path: path.to_path_buf(),
                        position: position(out.lines, out.last.as_ref()),
                        source,
                    });
                }
                on_info(info);
                info_shown = true;
            }
        }
        let written = out.append(&lines, &batch);
        lines.clear();
        if let Err(source) = written {
            return End::Write(Error::RecordWrite {
                path: path.to_path_buf(),
                position: position(out.lines, out.last.as_ref()),
                source,
            });
        }
        let ended = watch(&batch, stream.stats()) && !batch.is_empty();
        batch.clear();
        if ended {
            return End::ProgramEnded;
        }
        if let Some(r) = stream.run_ended() {
            return End::Restarted(*r);
        }
        if let Err(e) = stream.check_start() {
            return End::NotStarted(e);
        }
        match polled {
            Ok(Poll::Closed) => return End::Lost(port_lost(&port)),
            Err(e) => return End::Lost(e),
            Ok(_) => {}
        }
    }
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
    fn suspect_samples_are_counted_and_kept_as_comments() {
        let s = |seq: u64, t_us, enc1, d_mm| SeqSample {
            seq,
            sample: Sample {
                t_us,
                enc1,
                enc2: 5,
                d_mm,
                status: Status(0),
            },
        };
        let mut check = SampleCheck::default();
        let (mut lines, mut good) = (Vec::new(), Vec::new());
        let samples = [
            s(0, 100, 0, 100.0),
            s(1, 200, 0, f64::NAN),
            s(2, 300, 0, f64::INFINITY),
            s(3, 400, 0, -1.0),
            s(4, 500, 0, 1e6),
            // Inside (0, l1 + l2] but beyond the frames' ±75°: no instrument of these bars.
            s(5, 510, 0, 50.0),
            s(6, 600, 1 << 30, 100.0),
            s(7, 90, 0, 100.0),
            s(8, 600, 0, 100.0),
            s(9, 700, 0, 90.0),
            // A corrupted time mid-batch: set aside, and the next samples are data.
            s(10, u64::MAX, 0, 90.0),
            s(11, 800, 0, 90.0),
            s(12, 800 + MAX_TIME_JUMP_US + 1, 0, 90.0),
            s(13, 900, 0, 90.0),
            // A real jump (a long stall of the link): the sample after it goes on from it.
            s(14, 900 + 2 * MAX_TIME_JUMP_US, 0, 90.0),
            s(15, 1900 + 2 * MAX_TIME_JUMP_US, 0, 90.0),
        ];
        check.lines(&mut lines, &mut good, &samples);
        let text = String::from_utf8(lines).unwrap();
        assert_eq!(
            good.iter().map(|g| g.seq).collect::<Vec<_>>(),
            [0, 9, 11, 13, 15],
            "{text}"
        );
        let n = check.suspects;
        assert_eq!(
            (
                n.d_not_finite,
                n.d_impossible,
                n.counts_out_of_range,
                n.time_back,
                n.time_still,
                n.time_ahead
            ),
            (2, 3, 1, 1, 1, 3)
        );
        assert_eq!(
            text.lines()
                .filter(|l| l.starts_with(SUSPECT_PREFIX))
                .count(),
            11
        );
        assert!(
            text.contains("# suspect: 1,200,0,5,NaN: D is not finite"),
            "{text}"
        );
        assert!(
            text.contains("# suspect: 10,18446744073709551615,0,5,90: t_us jumps ahead"),
            "{text}"
        );
        assert!(n.to_string().starts_with("suspect samples 11 "), "{n}");
        // With a plan: D outside its range (and the margin) is marked too.
        let mut check = SampleCheck::default();
        check.set_plan_range(89.0, 91.0);
        let (mut plan_lines, mut plan_good) = (Vec::new(), Vec::new());
        check.lines(
            &mut plan_lines,
            &mut plan_good,
            &[s(0, 0, 0, 90.0), s(1, 1000, 0, 85.0), s(2, 2000, 0, 91.9)],
        );
        assert_eq!(plan_good.iter().map(|g| g.seq).collect::<Vec<_>>(), [0, 2]);
        assert_eq!(check.suspects.d_off_plan, 1);
        // The file stays readable by the one CSV reader: the suspects are skipped.
        let csv = format!("{CSV_HEADER}{text}");
        let mut t = crate::table::Table::from_text(Path::new("r.csv"), &csv).unwrap();
        let c = t.require(&["seq", "d_mm"]).unwrap();
        let mut seqs = vec![];
        while let Some(r) = t.next_row().unwrap() {
            seqs.push(r.integer(&c[0]).unwrap());
            assert!(r.number(&c[1]).unwrap() > 0.0);
        }
        assert_eq!(seqs, [0, 9, 11, 13, 15]);
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
    fn unwritable_output_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("no/such/dir/x.csv");
        let e = create_partial(&partial_path(&out), CSV_HEADER).unwrap_err();
        assert!(e.to_string().contains("cannot create"), "{e}");
    }

    use crate::link::stream::tests::{batch, frame, info, run, Duplex};
    use jdbb_core::protocol::{Command, DeviceMsg};
    use std::io::Cursor;

    impl Truncate for Cursor<Vec<u8>> {
        fn truncate_to(&mut self, len: u64) -> io::Result<()> {
            self.get_mut().truncate(len as usize);
            self.set_position(len);
            Ok(())
        }
    }

    /// A file on a disk that fills up after `room` bytes: the write that does not fit puts what
    /// fits, then fails (ENOSPC).
    struct SmallDisk {
        data: Vec<u8>,
        room: usize,
    }

    impl Write for SmallDisk {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            let n = buf.len().min(self.room - self.data.len());
            if n == 0 {
                return Err(io::Error::from_raw_os_error(28)); // ENOSPC
            }
            self.data.extend_from_slice(&buf[..n]);
            Ok(n)
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl Truncate for SmallDisk {
        fn truncate_to(&mut self, len: u64) -> io::Result<()> {
            self.data.truncate(len as usize);
            Ok(())
        }
    }

    /// Record everything `input` holds (after sending Start) into memory: how it ended, the CSV.
    fn record_bytes<W: Write + Truncate>(input: Vec<u8>, file: W) -> (End, CsvOut<W>, Stats) {
        let mut stream = Stream::new(Duplex::new(input), "mem");
        stream.send(&Command::Start).unwrap();
        let mut out = CsvOut::new(file, 0);
        let end = record_to(
            &mut stream,
            &mut out,
            Path::new("rec.csv"),
            None,
            &AtomicBool::new(false),
            &mut |_| {},
        );
        (end, out, *stream.stats())
    }

    /// The data lines of a CSV (not the serial's comment line), checked whole, as (seq, t_us).
    fn rows(csv: &[u8]) -> Vec<(u64, u64)> {
        let text = std::str::from_utf8(csv).unwrap();
        assert!(text.is_empty() || text.ends_with('\n'), "torn: {text:?}");
        text.lines()
            // The serial the device reported (written when it describes itself).
            .filter(|l| !l.starts_with("# instrument_serial: "))
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                assert_eq!(f.len(), 5, "{l}");
                (f[0].parse().unwrap(), f[1].parse().unwrap())
            })
            .collect()
    }

    /// seq from 0 and consecutive, t_us strictly increasing.
    fn assert_one_run(rows: &[(u64, u64)]) {
        for (i, w) in rows.iter().enumerate() {
            assert_eq!(w.0, i as u64, "seq");
        }
        for w in rows.windows(2) {
            assert!(w[1].1 > w[0].1, "t_us {} then {}", w[0].1, w[1].1);
        }
    }

    #[test]
    fn pre_start_samples_are_discarded() {
        // The running session (at 7000, then a restart of its own at 0), the answer to Start,
        // then the new run.
        let mut input = run(7000, 2);
        input.extend(run(0, 2));
        input.extend(frame(&info()));
        input.extend(run(0, 5));
        let (end, out, st) = record_bytes(input, Cursor::new(Vec::new()));
        assert!(matches!(end, End::Lost(_)), "{end:?}");
        let rows = rows(out.file.get_ref());
        assert_eq!(rows.len(), 80);
        assert_one_run(&rows);
        assert_eq!((st.before_start, st.resets, st.lost), (64, 0, 0));
    }

    #[test]
    fn a_corrupted_time_mid_batch_is_marked_and_the_record_reads_back() {
        // Issue 28 (10): t_us = 2⁶⁴ − 1 on one sample with a valid D, mid-batch.
        let mut input = frame(&info());
        input.extend(frame(&batch(0, 0, 16, 0)));
        let DeviceMsg::Batch(mut b) = batch(16, 0, 16, 16_000) else {
            unreachable!()
        };
        b.samples[5].t_us = u64::MAX;
        input.extend(frame(&DeviceMsg::Batch(b)));
        input.extend(frame(&batch(32, 0, 16, 32_000)));
        let (end, out, _) = record_bytes(input, Cursor::new(Vec::new()));
        assert!(matches!(end, End::Lost(_)), "{end:?}");
        assert_eq!(out.check.suspects.time_ahead, 1);
        assert_eq!(out.check.suspects.total(), 1);
        assert_eq!(out.lines, 47);
        let text = String::from_utf8(out.file.get_ref().clone()).unwrap();
        assert!(
            text.contains("# suspect: 21,18446744073709551615,"),
            "{text}"
        );
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("rec.csv");
        std::fs::write(&f, format!("{CSV_HEADER}{text}")).unwrap();
        let rec = crate::sync::Record::read(&f).unwrap();
        assert_eq!(rec.t_s.len(), 47);
        assert_eq!(rec.marked, 1);
    }

    #[test]
    fn a_corrupted_time_as_a_batchs_last_sample_does_not_end_the_record() {
        // The stream took the next batch's first time, below 2⁶⁴ − 1, for a restart.
        let mut input = frame(&info());
        let DeviceMsg::Batch(mut b) = batch(0, 0, 16, 0) else {
            unreachable!()
        };
        b.samples[15].t_us = u64::MAX;
        input.extend(frame(&DeviceMsg::Batch(b)));
        input.extend(frame(&batch(16, 0, 16, 16_000)));
        let (end, out, st) = record_bytes(input, Cursor::new(Vec::new()));
        assert!(matches!(end, End::Lost(_)), "{end:?}");
        assert_eq!(st.resets, 0);
        assert_eq!(out.lines, 31);
        assert_eq!(out.check.suspects.time_ahead, 1);
    }

    #[test]
    fn restart_mid_record_stops_with_whole_lines() {
        let mut input = frame(&info());
        input.extend(run(0, 4));
        input.extend(run(0, 3)); // the device restarted
        let (end, out, st) = record_bytes(input, Cursor::new(Vec::new()));
        let End::Restarted(r) = end else {
            panic!("{end:?}")
        };
        let rows = rows(out.file.get_ref());
        assert_eq!(rows.len(), 64);
        assert_one_run(&rows);
        assert_eq!(st.resets, 1);
        let e = Error::DeviceRestarted {
            restart: r,
            path: "rec.csv".into(),
        }
        .to_string();
        assert!(
            e.contains("after seq 63, t_us 63000") && e.contains("rec.csv holds the run up to"),
            "{e}"
        );
    }

    #[test]
    fn a_failed_write_is_cut_back_to_the_last_whole_line() {
        let mut input = frame(&info());
        input.extend(run(0, 10));
        // One read takes all ten batches: 160 lines, more than the disk holds.
        let disk = SmallDisk {
            data: Vec::new(),
            room: 1000,
        };
        let (end, out, _) = record_bytes(input, disk);
        let End::Write(e) = end else {
            panic!("{end:?}")
        };
        assert!(e.to_string().contains("whole lines"), "{e}");
        // Nothing fit whole in one write of 160 lines: cut back to the serial's line before them,
        // not a torn line.
        assert!(rows(&out.file.data).is_empty());
        let serial = "# instrument_serial: 000000000000000000000000\n";
        assert_eq!(out.file.data, serial.as_bytes());
        assert_eq!(out.committed, serial.len() as u64);

        // Two writes fit, the third does not: the file keeps the first two reads' lines.
        let mut disk = CsvOut::new(
            SmallDisk {
                data: Vec::new(),
                room: 1500,
            },
            0,
        );
        let samples: Vec<SeqSample> = {
            let mut s = Stream::new(&[0u8; 0][..], "x");
            let mut v = Vec::new();
            s.feed(&run(0, 10), |b| v.extend_from_slice(b));
            v
        };
        let mut wrote = 0;
        let err = loop {
            let chunk = &samples[wrote..wrote + 16];
            let mut lines = Vec::new();
            write_csv_lines(&mut lines, chunk);
            if let Err(e) = disk.append(&lines, chunk) {
                break e;
            }
            wrote += 16;
        };
        assert_eq!(err.raw_os_error(), Some(28));
        let rows = rows(&disk.file.data);
        assert_eq!(rows.len() as u64, disk.lines);
        assert_eq!(rows.len(), wrote);
        assert!(wrote > 0 && wrote < 160);
        assert_eq!(disk.last.unwrap().seq, wrote as u64 - 1);
        assert_eq!(disk.committed, disk.file.data.len() as u64);
    }

    #[test]
    fn existing_outputs_are_refused_unless_force_and_never_links_or_devices() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("precious.csv");
        assert!(check_output(&out, false).is_ok(), "nothing there");
        std::fs::write(&out, "keep me\n").unwrap();
        let e = check_output(&out, false).unwrap_err().to_string();
        assert!(e.contains("exists") && e.contains("--force"), "{e}");
        assert!(check_output(&out, true).is_ok());
        #[cfg(unix)]
        {
            let link = dir.path().join("link.csv");
            std::os::unix::fs::symlink(&out, &link).unwrap();
            for force in [false, true] {
                let e = check_output(&link, force).unwrap_err().to_string();
                assert!(e.contains("symbolic link"), "{e}");
                let e = check_output(Path::new("/dev/null"), force)
                    .unwrap_err()
                    .to_string();
                assert!(e.contains("not a regular file"), "{e}");
            }
        }
        let e = check_output(dir.path(), true).unwrap_err().to_string();
        assert!(e.contains("a directory"), "{e}");
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "keep me\n");
    }

    #[test]
    fn the_work_file_is_new_and_renamed_into_place() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("rec.csv");
        let partial = partial_path(&out);
        assert_eq!(partial, dir.path().join("rec.csv.partial"));
        drop(create_partial(&partial, CSV_HEADER).unwrap());
        // A second recorder may not take over the work file.
        let e = create_partial(&partial, CSV_HEADER)
            .unwrap_err()
            .to_string();
        assert!(e.contains("did not finish"), "{e}");
        finish_output(&partial, &out, false).unwrap();
        assert!(!partial.exists());
        assert_eq!(std::fs::read_to_string(&out).unwrap(), CSV_HEADER);
        // Without --force, a file that appeared meanwhile is left alone.
        drop(create_partial(&partial, CSV_HEADER).unwrap());
        std::fs::write(&out, "theirs\n").unwrap();
        let e = finish_output(&partial, &out, false)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("appeared") && e.contains("rec.csv.partial"),
            "{e}"
        );
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "theirs\n");
        assert!(partial.exists());
        // With --force it is replaced.
        finish_output(&partial, &out, true).unwrap();
        assert_eq!(std::fs::read_to_string(&out).unwrap(), CSV_HEADER);
        // Even with --force, a link that took its place while recording is left alone (issue 28).
        #[cfg(unix)]
        {
            std::fs::write(dir.path().join("theirs.csv"), "theirs\n").unwrap();
            std::fs::remove_file(&out).unwrap();
            std::os::unix::fs::symlink("theirs.csv", &out).unwrap();
            drop(create_partial(&partial, CSV_HEADER).unwrap());
            let e = finish_output(&partial, &out, true).unwrap_err().to_string();
            assert!(e.contains("rec.csv.partial"), "{e}");
            assert!(std::fs::symlink_metadata(&out).unwrap().is_symlink());
            assert!(partial.exists());
        }
    }

    #[test]
    fn record_to_stops_on_interrupt_and_deadline() {
        let mut input = frame(&DeviceMsg::Pong(1));
        input.extend(run(0, 1));
        let mut stream = Stream::new(Duplex::new(input), "mem");
        let mut out = CsvOut::new(Cursor::new(Vec::new()), 0);
        let end = record_to(
            &mut stream,
            &mut out,
            Path::new("x"),
            None,
            &AtomicBool::new(true),
            &mut |_| {},
        );
        assert!(matches!(end, End::Interrupted));
        let end = record_to(
            &mut stream,
            &mut out,
            Path::new("x"),
            Some(Instant::now()),
            &AtomicBool::new(false),
            &mut |_| {},
        );
        assert!(matches!(end, End::Time));
    }
}
