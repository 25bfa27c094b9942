//! `jdbb live`: the latest D (mm, to 0.1 µm), the measured sample rate and the loss counters,
//! redrawn on one terminal line a few times per second — or, when stdout is not a terminal (a
//! log, a CI job), printed as one line per second. A device restart is reported on a line of its
//! own (what showed it, the last sample before it), and counted in `resets`.
use std::io::{IsTerminal, Write};
use std::sync::atomic::Ordering;
use std::time::Instant;

use super::output::emit;
use super::stream_args::{warn, StreamArgs};
use crate::link::live::{status_line, RateMeter, REDRAW};
use crate::link::record::{port_lost, summary, End};
use crate::link::stream::{describe_info, interrupt_flag, Poll, Stream};
use crate::live_web::feed::{new_board, LiveFeed};
use crate::live_web::server::LAST_STATE_GRACE;
use crate::Result;

/// Arguments of `jdbb live`.
#[derive(Debug, Clone, clap::Args)]
pub struct LiveArgs {
    #[command(flatten)]
    pub stream: StreamArgs,
}

/// `jdbb live`: show the stream from `--port` until `--seconds`, Ctrl-C or the device goes away,
/// then print a summary. Losing the device is an error (nonzero exit).
pub fn run(args: &LiveArgs) -> Result<()> {
    let a = &args.stream;
    a.validate()?;
    let board = new_board();
    // Before the port: an address in use touches no device.
    let server = a.web_server(&board)?;
    let mut feed = server.as_ref().map(|_| LiveFeed::new(board, None, None));
    let mut stream = Stream::open(&a.port)?;
    let interrupted = interrupt_flag();
    a.start(&mut stream, &mut |w| {
        warn(&mut std::io::stderr(), feed.as_mut(), w)
    })?;
    let tty = std::io::stdout().is_terminal();
    let t0 = Instant::now();
    let deadline = a.deadline(t0);
    let mut rate = RateMeter::new(t0);
    let mut last_draw = t0;
    let mut info_shown = false;
    let mut resets_shown = 0;
    let mut out = std::io::stdout().lock();
    let end = loop {
        if interrupted.load(Ordering::SeqCst) {
            break End::Interrupted;
        }
        let now = Instant::now();
        if deadline.is_some_and(|d| now >= d) {
            break End::Time;
        }
        let polled = stream.poll(|batch| {
            if let Some(f) = feed.as_mut() {
                f.samples(batch);
            }
        });
        if let Some(f) = feed.as_mut() {
            f.publish_if_due(stream.stats(), Instant::now());
        }
        if stream.stats().resets > resets_shown {
            // Said on a line of its own, so that it stays visible above the redrawn status.
            resets_shown = stream.stats().resets;
            if let Some(r) = stream.last_restart() {
                let text = format!("warning: {r}; the counts go on with its new run");
                let _ = write!(out, "{}", if tty { "\r\x1b[2K" } else { "" });
                warn(&mut out, feed.as_mut(), &text);
            }
        }
        if let Err(e) = stream.check_start() {
            break End::NotStarted(e);
        }
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
            Ok(Poll::Closed) => break End::Lost(port_lost(&a.port)),
            Err(e) => break End::Lost(e),
            Ok(_) => {}
        }
    };
    let seconds = t0.elapsed().as_secs_f64();
    a.stop(&mut stream);
    if let Some(f) = feed.as_mut() {
        f.finish(stream.stats(), &end.describe());
        // Let the open pages receive the last state before the server stops.
        std::thread::sleep(LAST_STATE_GRACE);
    }
    drop(server);
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
    drop(out);
    emit(&format!(
        "live ({}): {}",
        end.describe(),
        summary(stream.stats(), seconds)
    ))?;
    match end {
        End::Lost(e) | End::NotStarted(e) | End::Write(e) => Err(e),
        End::Restarted(_) | End::Time | End::ProgramEnded | End::Interrupted => Ok(()),
    }
}
