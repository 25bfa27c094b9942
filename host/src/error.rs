//! The host's error type. Each message says what went wrong *and what to do about it*; the
//! binary prints it with its causes and exits nonzero.
use std::path::PathBuf;

/// Everything the `jdbb` commands can fail with.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A serial port could not be opened.
    #[error("cannot open serial port {port}: {source}. {}", port_hint(source))]
    PortOpen {
        port: String,
        #[source]
        source: serialport::Error,
    },
    /// Reading from an open port failed (e.g. the device was unplugged).
    #[error("reading {port} failed: {source}. Was the device unplugged or reset?")]
    PortRead {
        port: String,
        #[source]
        source: std::io::Error,
    },
    /// Sending a command to an open port failed.
    #[error("writing to {port} failed: {source}. Was the device unplugged or reset?")]
    PortWrite {
        port: String,
        #[source]
        source: std::io::Error,
    },
    /// The device did not answer `Start`.
    #[error("{port} did not acknowledge Start within {seconds} s, so no sample could be told apart from the run before it; nothing was recorded. Check that the device is a J-DBB with this protocol (`jdbb live --port {port}` shows it) and try again")]
    StartNotAcknowledged { port: String, seconds: u64 },
    /// The device refused `Start`.
    #[error("{port} refused Start ({reason}); nothing was recorded. Try again; if it persists, reset the device")]
    StartRefused { port: String, reason: String },
    /// The device restarted during a recording: the file holds the run up to the restart.
    #[error("{restart}. {path} holds the run up to there and nothing after (no run is stitched to another). Check the device's power and cable, then record again")]
    DeviceRestarted {
        restart: crate::link::stream::Restart,
        path: PathBuf,
    },
    /// The device did not answer a command in time.
    #[error("{port} did not answer {command} within {seconds} s. Check that the device is a J-DBB with this protocol (`jdbb live --port {port}` shows it), that nothing else holds the port, and try again")]
    NoReply {
        port: String,
        command: &'static str,
        seconds: f64,
    },
    /// The device refused a command.
    #[error("{port} refused {command}: {reason}")]
    CommandRefused {
        port: String,
        command: &'static str,
        reason: String,
    },
    /// What the device reports holding differs from what was sent to it.
    #[error("{port} accepted the calibration but reports holding another one: {differences}. Send it again; if it persists, the firmware does not keep what it is sent")]
    ReadBackMismatch { port: String, differences: String },
    /// The device put the calibration in force but did not keep it across power cycles.
    #[error("{port} put the calibration in force but did NOT store it: {reason}. It is lost at the next power cycle. Send it again; if it persists, power-cycle the device (a flash error left by the bootloader is cleared at every store, a persistent one is a fault of the board's flash)")]
    NotStored { port: String, reason: String },
    /// Writing the recording failed (e.g. a full disk); the file was cut back to whole lines.
    #[error("cannot write {path}: {source}. The file ends with whole lines ({position}); free some space or choose another --out, then record again")]
    RecordWrite {
        path: PathBuf,
        position: String,
        #[source]
        source: std::io::Error,
    },
    /// An output names a file that exists, and `--force` was not given.
    #[error("{path} exists; choose another output, or add --force to replace it")]
    OutputExists { path: PathBuf },
    /// An output names something that is not a regular file (a link, a device, a directory).
    #[error("{path} is {what}, not a regular file; jdbb writes regular files only (never through a link, never over a device, even with --force): choose another output")]
    OutputNotAFile { path: PathBuf, what: &'static str },
    /// The recording's work file exists already.
    #[error("{path} exists, left by a record that did not finish: it is a valid CSV of what that record got; rename or remove it, then record again")]
    PartialExists { path: PathBuf },
    /// The finished recording could not be put in place because `--out` appeared meanwhile.
    #[error("{out} appeared while recording, so it was left alone; the recording is in {partial}: rename it yourself")]
    OutputAppeared { out: PathBuf, partial: PathBuf },
    /// An input file could not be read (missing, unreadable, a directory): bad input, exit 2.
    #[error("cannot read {path}: {source}")]
    InputFile {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// An output file could not be created or written.
    #[error("{action} {path}: {source}")]
    File {
        action: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Standard output could not be written (a full disk; a closed pipe is not an error).
    #[error("cannot write to standard output: {source}")]
    Stdout {
        #[source]
        source: std::io::Error,
    },
    /// Input data is malformed; `location` is `file:line:column` when known.
    #[error("{location}: {message}")]
    Input { location: String, message: String },
    /// The command line asks for something that cannot be done.
    #[error("{0}")]
    Usage(String),
    /// The live page's server could not listen on its address (`--web ADDR`).
    #[error("cannot serve the live page on {addr}: {message}. Is another jdbb (or another program) using it? Give another --web ADDR, e.g. 127.0.0.1:8766")]
    WebServer { addr: String, message: String },
    /// A fit or computation could not produce a trustworthy answer.
    #[error("{0}")]
    Numerics(String),
    /// A program an option runs is not installed, or failed.
    #[error("{option} needs {program}: {message}")]
    Program {
        option: &'static str,
        program: &'static str,
        message: String,
    },
    /// The history database could not be opened, read or written.
    #[error("history database {path}: {source}. Is it a jdbb history file, on a disk you may write? (--db PATH chooses another)")]
    Database {
        path: PathBuf,
        #[source]
        source: rusqlite::Error,
    },
    /// The history server (`--db postgres://…`, named with its password redacted) could not be
    /// reached, read or written.
    #[error("history database {location}: {message}")]
    Server { location: String, message: String },
}

impl Error {
    /// Process exit code: 2 for bad input (a file missing, unreadable or malformed, a history
    /// file that is not a database) or usage (an `--out` that exists or is not a file), 1 for everything else (a device, an output, a
    /// computation that failed).
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Input { .. }
            | Error::InputFile { .. }
            | Error::Usage(_)
            | Error::OutputExists { .. }
            | Error::OutputNotAFile { .. } => 2,
            // A --db that is not a database is bad input too.
            Error::Database {
                source: rusqlite::Error::SqliteFailure(e, _),
                ..
            } if e.code == rusqlite::ErrorCode::NotADatabase => 2,
            // A port another program holds: the user's to free, like bad input.
            Error::PortOpen { source, .. } if port_busy(source) => 2,
            _ => 1,
        }
    }

    /// Shorthand for an input error at `file:line:column` (line and column 1-based; column 0
    /// means "the whole line").
    pub fn input(
        path: &std::path::Path,
        line: usize,
        column: usize,
        message: impl Into<String>,
    ) -> Self {
        let location = if column > 0 {
            format!("{}:{}:{}", path.display(), line, column)
        } else {
            format!("{}:{}", path.display(), line)
        };
        Error::Input {
            location,
            message: message.into(),
        }
    }
}

/// Whether a port would not open because another program holds it (EBUSY, or the exclusive lock
/// serial ports take).
fn port_busy(e: &serialport::Error) -> bool {
    let d = e.description.to_lowercase();
    d.contains("busy") || d.contains("in use") || d.contains("lock")
}

/// What to do about a port that would not open: a port in use is another program's (the
/// exclusive lock of a serial port), a refused one is the user's permissions, anything else the
/// name or the cable.
fn port_hint(e: &serialport::Error) -> &'static str {
    let d = e.description.to_lowercase();
    if port_busy(e) {
        "The port is in use by another program (another jdbb, a serial terminal, a slicer or ModemManager): close it, then try again"
    } else if d.contains("permission") || d.contains("access is denied") {
        "You may not open it: add yourself to the group that owns it (dialout on Debian and Ubuntu, uucp on Arch) and log in again"
    } else {
        "Check the name with `jdbb devices` and that the device is plugged in"
    }
}

/// Result with the host's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
