//! `jdbb record`: stream one run from a device into a CSV file until `--seconds`, Ctrl-C (or
//! SIGTERM, SIGHUP), the device goes away or restarts, or the file cannot be written; then a
//! summary. The port is opened first, the samples go to `OUT.partial`, renamed to `OUT` at the
//! end (see [`crate::link::record`]). Every end but time and interruption is an error (nonzero
//! exit), reported after the file is complete and in place.
use std::path::PathBuf;
use std::time::Instant;

use super::output::{emit, note, print};
use super::stream_args::StreamArgs;
use crate::circular::plan::Plan;
use crate::link::record::{
    check_output, create_partial, finish_output, partial_path, record_observed, summary, CsvOut,
    End, CSV_HEADER,
};
use crate::link::stream::{describe_info, interrupt_flag, Stream};
use crate::live_web::end::diagnose_record;
use crate::live_web::feed::{new_board, LiveFeed};
use crate::live_web::server::LAST_STATE_GRACE;
use crate::{Error, Result};

/// Arguments of `jdbb record`.
#[derive(Debug, Clone, clap::Args)]
pub struct RecordArgs {
    #[command(flatten)]
    pub stream: StreamArgs,
    /// Output CSV file. Must not exist (unless --force); written as FILE.partial and renamed to
    /// FILE at the end.
    #[arg(long, short, value_name = "FILE")]
    pub out: PathBuf,
    /// Replace --out if it exists (a regular file only; never a link or a device).
    #[arg(long)]
    pub force: bool,
    /// With --web: the plan.json of the program the machine runs (`jdbb plan`). The page shows
    /// where the machine is in it and the current circle's trace; at the end the record is
    /// diagnosed as `jdbb diagnose --record OUT --plan plan.json` does, printed and shown.
    #[arg(long, value_name = "FILE", requires = "web")]
    pub plan: Option<PathBuf>,
    /// With --plan: tolerance on the circular deviation G (µm) for the end-of-test verdict, as
    /// `jdbb diagnose --tolerance-um`.
    #[arg(long, requires = "plan", value_parser = super::args::positive)]
    pub tolerance_um: Option<f64>,
}

/// Run `jdbb record`.
pub fn run(args: &RecordArgs) -> Result<()> {
    args.stream.validate()?;
    check_output(&args.out, args.force)?;
    let plan = args.plan.as_deref().map(Plan::read).transpose()?;
    let board = new_board();
    // Before the port and the file: an address in use leaves nothing behind.
    let server = args.stream.web_server(&board)?;
    let mut feed = server
        .as_ref()
        .map(|_| LiveFeed::new(board, plan.as_ref(), args.tolerance_um));
    // The port first: a mistyped port leaves no file behind and touches none.
    let mut stream = Stream::open(&args.stream.port)?;
    let partial = partial_path(&args.out);
    let file = create_partial(&partial)?;
    let interrupted = interrupt_flag();
    if let Err(e) = args.stream.start(&mut stream) {
        // Nothing recorded: remove the work file this run created (it holds the header only).
        drop(file);
        let _ = std::fs::remove_file(&partial);
        return Err(e);
    }
    note(&format!(
        "recording {} to {} ({})",
        args.stream.port,
        args.out.display(),
        match args.stream.seconds {
            Some(s) => format!("{s} s, Ctrl-C to stop early"),
            None => "Ctrl-C to stop".into(),
        }
    ));
    let t0 = Instant::now();
    let mut out = CsvOut::new(file, CSV_HEADER.len() as u64);
    let end = record_observed(
        &mut stream,
        &mut out,
        &args.out,
        args.stream.deadline(t0),
        &interrupted,
        &mut |info| note(&format!("device: {}", describe_info(info))),
        &mut |batch, stats| {
            if let Some(f) = feed.as_mut() {
                f.samples(batch);
                f.publish_if_due(stats, Instant::now());
            }
        },
    );
    let seconds = t0.elapsed().as_secs_f64();
    args.stream.stop(&mut stream);
    // What was recorded is kept, however the record ended.
    let synced = out.file.sync_data().map_err(|source| Error::File {
        action: "cannot write",
        path: partial.clone(),
        source,
    });
    drop(out.file);
    let placed = if matches!(end, End::NotStarted(_)) {
        // No run began, so nothing was recorded: remove the header-only work file this record
        // created, and leave --out as it was.
        std::fs::remove_file(&partial).map_err(|source| Error::File {
            action: "cannot remove",
            path: partial.clone(),
            source,
        })
    } else {
        finish_output(&partial, &args.out, args.force)
    };
    if let Some(f) = feed.as_mut() {
        f.finish(stream.stats(), &end.describe());
    }
    let suspects = out.check.suspects;
    emit(&format!(
        "recorded {} ({}): {}{}",
        args.out.display(),
        end.describe(),
        summary(stream.stats(), seconds),
        if suspects.total() > 0 {
            format!("; {suspects}")
        } else {
            String::new()
        }
    ))?;
    if let (Some(plan), Some(f), Ok(()), false) = (
        &plan,
        feed.as_mut(),
        &placed,
        matches!(end, End::NotStarted(_)),
    ) {
        match diagnose_record(plan, &args.out, args.tolerance_um) {
            Ok(text) => {
                print(&text)?;
                f.diagnosis(stream.stats(), &text);
            }
            // The record is complete and in place; only its diagnosis failed: say why.
            Err(e) => {
                let text = format!("no end-of-test diagnosis: {e}");
                note(&text);
                f.diagnosis(stream.stats(), &text);
            }
        }
    }
    if server.is_some() {
        // Let the open pages receive the last state before the server stops; they keep showing it.
        std::thread::sleep(LAST_STATE_GRACE);
    }
    drop(server);
    let failed = match end {
        End::Lost(e) | End::NotStarted(e) | End::Write(e) => Some(e),
        End::Restarted(restart) => Some(Error::DeviceRestarted {
            restart,
            path: args.out.clone(),
        }),
        End::Time | End::Interrupted => None,
    };
    match (failed, placed) {
        (Some(e), Err(p)) => {
            note(&format!("error: {p}"));
            Err(e)
        }
        (Some(e), Ok(())) => Err(e),
        (None, placed) => synced.and(placed),
    }
}
