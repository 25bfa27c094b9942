//! The host's error type. Each message says what went wrong *and what to do about it*; the
//! binary prints it with its causes and exits nonzero.
use std::path::PathBuf;

/// Everything the `jdbb` commands can fail with.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A serial port could not be opened.
    #[error("cannot open serial port {port}: {source}. Check the name with `jdbb devices`, that the device is plugged in, and that you may read it (group dialout)")]
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
    /// A file could not be created, written or read.
    #[error("{action} {path}: {source}")]
    File {
        action: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Input data is malformed; `location` is `file:line:column` when known.
    #[error("{location}: {message}")]
    Input { location: String, message: String },
    /// The command line asks for something that cannot be done.
    #[error("{0}")]
    Usage(String),
    /// A fit or computation could not produce a trustworthy answer.
    #[error("{0}")]
    Numerics(String),
}

impl Error {
    /// Process exit code: 2 for bad input or usage, 1 for everything else.
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Input { .. } | Error::Usage(_) => 2,
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

/// Parse one numeric field of an input file: a finite f64, or an input error at
/// `path:line:column` that names the column and shows what was there. Every CSV reader of the
/// host uses it, so bad numbers read the same whatever the command.
pub fn parse_number(
    path: &std::path::Path,
    line: usize,
    column: usize,
    name: &str,
    raw: &str,
) -> Result<f64> {
    let raw = raw.trim();
    match raw.parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        Ok(_) => Err(Error::input(
            path,
            line,
            column,
            format!("{name} is {raw}; every value must be finite"),
        )),
        Err(_) => Err(Error::input(
            path,
            line,
            column,
            format!("{name}: `{raw}` is not a number"),
        )),
    }
}

/// Result with the host's [`Error`].
pub type Result<T> = std::result::Result<T, Error>;
