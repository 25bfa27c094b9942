//! `jdbb live`: the latest D (mm, 4 decimals = 0.1 µm), the measured sample rate and the loss
//! counters, redrawn on one terminal line a few times per second — or, when stdout is not a
//! terminal (a log, a CI job), printed as one line per second.
use std::io::{IsTerminal, Write};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use crate::record::{describe_info, summary, End};
use crate::stream::{self, Poll, Stats, Stream, StreamArgs};
use crate::Result;

/// Arguments of `jdbb live`.
#[derive(Debug, Clone, clap::Args)]
pub struct LiveArgs {
    #[command(flatten)]
    pub stream: StreamArgs,
}

/// Terminal redraw interval.
const REDRAW: Duration = Duration::from_millis(250);
/// Window over which the sample rate is measured, and the line interval when not a terminal.
const RATE_WINDOW: Duration = Duration::from_secs(1);

/// Received-sample rate over consecutive windows of [`RATE_WINDOW`] (host clock).
#[derive(Debug)]
struct RateMeter {
    start: Instant,
    start_samples: u64,
    hz: Option<f64>,
}

impl RateMeter {
    fn new(now: Instant) -> Self {
        RateMeter {
            start: now,
            start_samples: 0,
            hz: None,
        }
    }

    /// Close the window if it is full; returns whether it was.
    fn update(&mut self, now: Instant, samples: u64) -> bool {
        let dt = now.duration_since(self.start);
        if dt < RATE_WINDOW {
            return false;
        }
        self.hz = Some((samples - self.start_samples) as f64 / dt.as_secs_f64());
        self.start = now;
        self.start_samples = samples;
        true
    }
}

/// The status line: D, rate and counters.
fn status_line(d_mm: Option<f64>, hz: Option<f64>, st: &Stats) -> String {
    let d = d_mm.map_or_else(|| "-".repeat(8), |d| format!("{d:.4}"));
    let hz = hz.map_or_else(|| "-".into(), |h| format!("{h:.1}"));
    format!(
        "D {d} mm | {hz} Hz | samples {} | lost {} | dropped {} | corrupt {} | resets {}",
        st.samples,
        st.lost,
        st.device_dropped,
        st.corrupt.total(),
        st.resets
    )
}

/// `jdbb live`: show the stream from `--port` until `--seconds`, Ctrl-C or the device goes away,
/// then print a summary. Losing the device is an error (nonzero exit).
pub fn live(args: &LiveArgs) -> Result<()> {
    let a = &args.stream;
    a.validate()?;
    let mut stream = Stream::open(&a.port)?;
    let interrupted = stream::interrupt_flag();
    a.start(&mut stream)?;
    let tty = std::io::stdout().is_terminal();
    let t0 = Instant::now();
    let deadline = a.deadline(t0);
    let mut rate = RateMeter::new(t0);
    let mut last_draw = t0;
    let mut info_shown = false;
    let mut out = std::io::stdout().lock();
    let end = loop {
        if interrupted.load(Ordering::SeqCst) {
            break End::Interrupted;
        }
        let now = Instant::now();
        if deadline.is_some_and(|d| now >= d) {
            break End::Time;
        }
        let polled = stream.poll(|_| {});
        let now = Instant::now();
        let window_closed = rate.update(now, stream.stats().samples);
        if !info_shown {
            if let Some(info) = stream.info() {
                let _ = write!(out, "{}", if tty { "\r\x1b[2K" } else { "" });
                let _ = writeln!(out, "device: {}", describe_info(info));
                info_shown = true;
            }
        }
        let draw = if tty {
            now.duration_since(last_draw) >= REDRAW
        } else {
            window_closed
        };
        if draw {
            last_draw = now;
            let line = status_line(
                stream.last_sample().map(|s| s.sample.d_mm),
                rate.hz,
                stream.stats(),
            );
            // Output errors (a closed pipe) must not stop the stream: ignore them.
            let _ = if tty {
                write!(out, "\r\x1b[2K{line}")
            } else {
                writeln!(out, "{line}")
            };
            let _ = out.flush();
        }
        match polled {
            Ok(Poll::Closed) => {
                break End::Lost(crate::Error::PortRead {
                    port: a.port.clone(),
                    source: std::io::Error::new(
                        std::io::ErrorKind::UnexpectedEof,
                        "the device closed the connection",
                    ),
                })
            }
            Err(e) => break End::Lost(e),
            Ok(_) => {}
        }
    };
    let seconds = t0.elapsed().as_secs_f64();
    a.stop(&mut stream);
    let last = status_line(
        stream.last_sample().map(|s| s.sample.d_mm),
        rate.hz,
        stream.stats(),
    );
    let _ = if tty {
        writeln!(out, "\r\x1b[2K{last}")
    } else {
        writeln!(out, "{last}")
    };
    let _ = writeln!(
        out,
        "live ({}): {}",
        end.describe(),
        summary(stream.stats(), seconds)
    );
    match end {
        End::Lost(e) => Err(e),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_line_shows_d_to_a_tenth_of_a_micrometre() {
        let st = Stats {
            samples: 10,
            lost: 2,
            device_dropped: 1,
            resets: 1,
            ..Stats::default()
        };
        let l = status_line(Some(99.987_654), Some(1000.04), &st);
        assert!(
            l.starts_with("D 99.9877 mm | 1000.0 Hz | samples 10 | lost 2 | dropped 1"),
            "{l}"
        );
        assert!(status_line(None, None, &st).starts_with("D -------- mm | - Hz"));
    }

    #[test]
    fn rate_meter_measures_over_a_window() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(t0);
        assert!(!m.update(t0 + Duration::from_millis(500), 500));
        assert!(m.hz.is_none());
        assert!(m.update(t0 + Duration::from_millis(2000), 2000));
        assert!((m.hz.unwrap() - 1000.0).abs() < 1e-9);
    }
}
