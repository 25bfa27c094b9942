//! `jdbb record`: stream one run from a device into a CSV file until `--seconds`, Ctrl-C (or
//! SIGTERM, SIGHUP), the device goes away or restarts, or the file cannot be written; then a
//! summary. The port is opened first, the samples go to `OUT.partial`, renamed to `OUT` at the
//! end (see [`crate::link::record`]). Every end but time and interruption is an error (nonzero
//! exit), reported after the file is complete and in place.
use std::path::PathBuf;
use std::time::Instant;

use super::output::{emit, note, print};
use super::stream_args::StreamArgs;
use crate::link::record::{
    check_output, create_partial, finish_output, header, partial_path, record_watched, summary,
    CsvOut, End,
};
use crate::link::stream::{describe_info, interrupt_flag, Stream};
use crate::link::stream::{SeqSample, Stats};
use crate::live_web::end::diagnose_record;
use crate::live_web::feed::{new_board, LiveFeed, PUBLISH_INTERVAL};
use crate::live_web::server::LAST_STATE_GRACE;
use crate::plan::{Plan, PLAN_ID_KEY};
use crate::simulate::progress::Tracker;
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
    /// The plan.json of the program the machine runs: its id goes into the record (`# plan_id:`
    /// line), so `jdbb diagnose --record --plan` can tell a record of another plan; a progress
    /// line shows the circle being run; a missed cycle start is said at once; and the record
    /// stops by itself after the program's end.
    /// With --web the page also shows where the machine is in the plan and the current
    /// circle's trace, and at the end the record is diagnosed as `jdbb diagnose --record OUT
    /// --plan plan.json` does, printed and shown.
    #[arg(long, value_name = "PLAN_JSON")]
    pub plan: Option<PathBuf>,
    /// With --plan and --web: tolerance on the circular deviation G (µm) for the end-of-test
    /// verdict, as `jdbb diagnose --tolerance-um`.
    #[arg(long, requires = "plan", value_parser = super::args::positive)]
    pub tolerance_um: Option<f64>,
}

/// What `jdbb record --plan` shows while it records: a progress line every
/// [`PROGRESS_EVERY`], a message when cycle start was missed, and the end of the program.
struct Watch {
    tracker: Tracker,
    last_line: Option<Instant>,
    missed_told: bool,
    stop_at_end: bool,
}

/// How often the progress line is printed.
const PROGRESS_EVERY: std::time::Duration = std::time::Duration::from_secs(2);

impl Watch {
    fn new(plan: &Plan, listen_only: bool) -> Watch {
        Watch {
            tracker: Tracker::new(plan),
            last_line: None,
            missed_told: false,
            // Listening to a run someone else started: the program may be anywhere.
            stop_at_end: !listen_only,
        }
    }

    /// Take the samples of one read: whether the program has ended, and the warning said now (for
    /// the live page too).
    fn see(&mut self, samples: &[SeqSample], stats: &Stats) -> (bool, Option<String>) {
        for s in samples {
            self.tracker
                .push(s.sample.t_us as f64 * 1e-6, s.sample.d_mm);
        }
        let mut warning = None;
        if let (Some(m), false) = (&self.tracker.missed_start, self.missed_told) {
            self.missed_told = true;
            let text = format!(
                "warning: {m}. This record cannot be synchronised with the plan: stop (Ctrl-C), run the machine back to the plan's start point, start `jdbb record --plan` first, then press cycle start"
            );
            note(&text);
            warning = Some(text);
        }
        let now = Instant::now();
        if self.last_line.is_none_or(|t| now - t >= PROGRESS_EVERY) {
            // A read may bring no samples (the live page sees every read): the line waits for one.
            if let (Some(last), Some(first)) = (samples.last(), self.tracker.first_t_s()) {
                self.last_line = Some(now);
                note(&format!(
                    "t {:.1} s, {} samples, D {:.4} mm, lost {}, {}",
                    last.sample.t_us as f64 * 1e-6 - first,
                    stats.samples,
                    last.sample.d_mm,
                    stats.lost,
                    self.tracker.status()
                ));
            }
        }
        (self.stop_at_end && self.tracker.ended(), warning)
    }
}

/// Run `jdbb record`.
pub fn run(args: &RecordArgs) -> Result<()> {
    args.stream.validate()?;
    check_output(&args.out, args.force)?;
    if let Some(plan) = &args.plan {
        crate::fsio::check_not_input(&args.out, &[("--plan", plan.as_path())])?;
    }
    let plan = args.plan.as_deref().map(Plan::read).transpose()?;
    let head = header(&match &plan {
        Some(p) => vec![(PLAN_ID_KEY, p.id())],
        None => vec![],
    });
    let board = new_board();
    // Before the port and the file: an address in use leaves nothing behind.
    let server = args.stream.web_server(&board)?;
    let mut feed = server
        .as_ref()
        .map(|_| LiveFeed::new(board, plan.as_ref(), args.tolerance_um));
    // The port first: a mistyped port leaves no file behind and touches none.
    let mut stream = Stream::open(&args.stream.port)?;
    let partial = partial_path(&args.out);
    let file = create_partial(&partial, &head)?;
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
    let mut out = CsvOut::new(file, head.len() as u64);
    if let Some(p) = &plan {
        let (lo, hi) = p.mounted_d_range_mm();
        out.check.set_plan_range(lo, hi);
    }
    let mut watch = plan.as_ref().map(|p| Watch::new(p, args.stream.no_start));
    let end = record_watched(
        &mut stream,
        &mut out,
        &args.out,
        args.stream.deadline(t0),
        &interrupted,
        &mut |info| note(&format!("device: {}", describe_info(info))),
        &mut |samples, stats| {
            let (ended, warning) = watch
                .as_mut()
                .map_or((false, None), |w| w.see(samples, stats));
            if let Some(f) = feed.as_mut() {
                f.samples(samples);
                if let Some(w) = &warning {
                    f.warn(w);
                }
                f.publish_if_due(stats, Instant::now());
            }
            ended
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
        // The end-of-test diagnosis in its own thread, while circles the worker diagnoses in
        // the meantime still reach the page.
        let result = std::thread::scope(|scope| {
            let job = scope.spawn(|| diagnose_record(plan, &args.out, args.tolerance_um));
            while !job.is_finished() {
                f.publish_new_diagnoses(stream.stats());
                std::thread::sleep(PUBLISH_INTERVAL);
            }
            job.join()
        })
        .unwrap_or_else(|_| {
            Err(Error::Usage(
                "the end-of-test diagnosis failed unexpectedly (a bug: please report it)".into(),
            ))
        });
        match result {
            Ok((text, verdict)) => {
                print(&text)?;
                f.diagnosis(stream.stats(), &text, verdict);
            }
            // The record is complete and in place; only its diagnosis failed: say why.
            Err(e) => {
                let text = format!("no end-of-test diagnosis: {e}");
                note(&text);
                f.diagnosis(stream.stats(), &text, None);
            }
        }
    }
    if let Some(s) = &server {
        // A record that ended by itself (the plan's program over, --seconds) leaves the page up
        // with its final state and diagnosis until the user has read it: Ctrl-C ends the page.
        if !interrupted.load(std::sync::atomic::Ordering::SeqCst) {
            note(&format!(
                "the record is complete and in place; the live page {} keeps its final state: Ctrl-C to close it",
                s.url()
            ));
            while !interrupted.load(std::sync::atomic::Ordering::SeqCst) {
                if let Some(f) = feed.as_mut() {
                    f.publish_new_diagnoses(stream.stats());
                }
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
        }
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
        End::Time | End::ProgramEnded | End::Interrupted => None,
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
