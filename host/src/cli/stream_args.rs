//! Options shared by the commands that stream from a device (`live`, `record`), and what they
//! send to it at the start and the end of a session.
use std::io::{Read, Write};
use std::time::{Duration, Instant};

use jdbb_core::protocol::{self, Command};

use crate::link::stream::Stream;
use crate::live_web::feed::LiveFeed;
use crate::{Error, Result};

/// How long a session waits for the device to answer before it starts anyway.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);

/// Say a warning of a streaming session (`live`, `record`): on a line of its own on the
/// terminal (`terminal`: standard error, or `live`'s standard output between its status lines)
/// and, with `--web`, on the live page with its next publication, which is due at once. Every
/// warning these commands show goes through here, so the page shows what the terminal shows.
pub fn warn(terminal: &mut dyn Write, page: Option<&mut LiveFeed>, text: &str) {
    // A failing terminal (a closed pipe) must not end the session.
    let _ = writeln!(terminal, "{text}");
    let _ = terminal.flush();
    if let Some(f) = page {
        f.warn(text);
    }
}

/// Options shared by the commands that stream from a device (`live`, `record`).
#[derive(Debug, Clone, clap::Args)]
pub struct StreamArgs {
    /// Serial port: a USB CDC device (e.g. /dev/ttyACM0) or QEMU's pty (/dev/pts/N).
    #[arg(long, value_name = "PORT")]
    pub port: String,
    /// Stop after this many seconds, at most a year (default: until Ctrl-C or the device goes
    /// away).
    #[arg(long, value_name = "N", value_parser = super::args::seconds)]
    pub seconds: Option<f64>,
    /// Set the device's sample clock (Hz) before starting: at most the rate the board is known
    /// to sustain (10 kHz, README "Throughput budget") unless `--unsustained-rate`.
    #[arg(long, value_name = "HZ")]
    pub rate: Option<u32>,
    /// Accept a `--rate` above the sustained rate, up to the device's 20 kHz (the first-flash
    /// check of the tick chain): samples may be dropped (counted).
    #[arg(long)]
    pub unsustained_rate: bool,
    /// Listen only: send no Start (and no Stop at the end) to a device that is already streaming.
    #[arg(long)]
    pub no_start: bool,
    /// Serve a live page of the session (D, rate, losses; with `record --plan`, the progress and
    /// the current circle's trace) at ADDR, 127.0.0.1:8765 if no ADDR is given (port 0: any free
    /// port). Another address than localhost needs the token printed with the URL. Read-only.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = crate::live_web::server::DEFAULT_ADDR)]
    pub web: Option<std::net::SocketAddr>,
}

impl StreamArgs {
    /// Start the live page's server when `--web` asks for it, and say its URL (stderr).
    pub fn web_server(
        &self,
        board: &crate::live_web::feed::Board,
    ) -> Result<Option<crate::live_web::server::LiveServer>> {
        let Some(addr) = self.web else {
            return Ok(None);
        };
        let server = crate::live_web::server::LiveServer::start(addr, board.clone())?;
        super::output::note(&format!("live page: {}", server.url()));
        if let Some(n) = server.url_note() {
            super::output::note(&n);
        }
        if server.token().is_some() {
            super::output::note(
                "the page is reachable from other computers; only with this URL's token",
            );
        }
        Ok(Some(server))
    }

    /// Check the values before anything is opened.
    pub fn validate(&self) -> Result<()> {
        if let Some(hz) = self.rate {
            if !(1..=protocol::MAX_SAMPLE_RATE_HZ).contains(&hz) {
                return Err(Error::Usage(format!(
                    "--rate {hz}: the device samples at 1 to {} Hz",
                    protocol::MAX_SAMPLE_RATE_HZ
                )));
            }
            if hz > protocol::SUSTAINED_SAMPLE_RATE_HZ && !self.unsustained_rate {
                return Err(Error::Usage(format!(
                    "--rate {hz}: above {} Hz, the rate the board is known to sustain end to end. \
                     Each sample is ~23 bytes on the link and up to ~1 800 instructions on the chip: \
                     {hz} Hz needs {} kB/s over USB full speed with one packet in flight and most of \
                     the CPU, which no board has shown; samples would be dropped (README, \
                     \"Throughput budget\"). To check the tick chain anyway, add \
                     --unsustained-rate",
                    protocol::SUSTAINED_SAMPLE_RATE_HZ,
                    hz as u64 * 23 / 1000
                )));
            }
        }
        Ok(())
    }

    /// The deadline given by `--seconds`, counted from `t0` (`--seconds` is at most a year, so
    /// the sum cannot overflow; None also if it would).
    pub fn deadline(&self, t0: Instant) -> Option<Instant> {
        self.seconds
            .and_then(|s| Duration::try_from_secs_f64(s).ok())
            .and_then(|d| t0.checked_add(d))
    }

    /// Ask the device to describe itself, then configure and start it as asked (`--rate`,
    /// unless `--no-start`); a warning (the device did not answer) goes to `warn` ([`warn`]).
    pub fn start<P: Read + Write>(
        &self,
        stream: &mut Stream<P>,
        warn: &mut dyn FnMut(&str),
    ) -> Result<()> {
        if self.no_start {
            // Listen only: every sample counts from the first byte, so no handshake.
            return stream.send(&Command::GetInfo);
        }
        if !stream.handshake(HANDSHAKE_TIMEOUT)? {
            warn(&format!(
                "warning: {} did not answer a ping within {} s; starting anyway",
                stream.name(),
                HANDSHAKE_TIMEOUT.as_secs()
            ));
        }
        stream.send(&Command::GetInfo)?;
        if let Some(hz) = self.rate {
            stream.send(&Command::SetSampleRate(hz))?;
        }
        stream.send(&Command::Start)
    }

    /// Stop the device at the end of a session (unless `--no-start`). Errors are ignored: the
    /// device may be gone, which was reported already.
    pub fn stop<P: Write>(&self, stream: &mut Stream<P>) {
        if !self.no_start {
            let _ = stream.send(&Command::Stop);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::stream::Stats;
    use crate::live_web::feed::new_board;

    /// A device that says nothing: its port reads as closed and takes every write.
    struct Silent;

    impl Read for Silent {
        fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
            Ok(0)
        }
    }

    impl Write for Silent {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn the_handshake_warning_is_on_the_page_as_on_the_terminal() {
        let args = StreamArgs {
            port: "/dev/ttyFAKE".into(),
            seconds: None,
            rate: None,
            unsustained_rate: false,
            no_start: false,
            web: None,
        };
        let board = new_board();
        let mut feed = Some(LiveFeed::new(board.clone(), None, None));
        let mut terminal = vec![];
        let mut stream = Stream::new(Silent, "/dev/ttyFAKE");
        args.start(&mut stream, &mut |w| warn(&mut terminal, feed.as_mut(), w))
            .unwrap();
        let said = String::from_utf8(terminal).unwrap();
        assert!(
            said.starts_with("warning: /dev/ttyFAKE did not answer a ping"),
            "{said}"
        );
        feed.as_mut()
            .unwrap()
            .publish_if_due(&Stats::default(), Instant::now());
        let json = board.lock().unwrap().json.clone();
        let state: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(
            state["warnings"],
            serde_json::json!([said.trim_end()]),
            "{state}"
        );
    }
}
