//! The diagnosis while recording: a worker thread that keeps its own copy of the samples (time
//! and D, sent by the feed in batches over a channel that never blocks the sender) and, when the
//! tracker sees a circle's feed-out end, waits for [`SETTLE_S`] more seconds of samples, then
//! synchronises the samples so far with the plan cut after that circle and diagnoses them — the
//! same functions as `jdbb diagnose --record --plan` on the circles completed so far. Its result
//! goes back to the feed over another channel, which the feed reads without waiting.
use std::path::PathBuf;
use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};
use std::thread::JoinHandle;
use std::time::Instant;

use serde::Serialize;

use crate::circular::diagnose::{diagnose, Options};
use crate::circular::input::check_holes;
use crate::circular::plan::{LineRole, Plan, Segment};
use crate::circular::report::{summary, sync_summary, tolerance_verdict};
use crate::circular::sync::{data_path, synchronise, Record};

/// Seconds of samples after a circle's feed-out is seen back at D_in before its diagnosis runs:
/// the synchronisation fits the feed-out's ramp up to 0.25 s into the dwell after it.
pub const SETTLE_S: f64 = 0.5;

/// The diagnosis of the circles completed so far.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SoFar {
    /// Circles completed and diagnosed (the first n of the plan).
    pub circles: usize,
    /// The text `jdbb diagnose --record --plan` prints for them, or why there is none.
    pub text: String,
    /// Against `--tolerance-um`, when given and the diagnosis succeeded.
    pub pass: Option<bool>,
    /// How long the synchronisation and diagnosis took (ms).
    pub took_ms: f64,
}

enum Msg {
    /// (t_s, d_mm) pairs, in order.
    Samples(Vec<(f64, f64)>),
    /// Circle n (1-based) ended at t_s.
    CircleDone { n: usize, t_s: f64 },
}

/// The feed's handle on the worker.
#[derive(Debug)]
pub struct Diagnoser {
    tx: Option<Sender<Msg>>,
    rx: Receiver<SoFar>,
    thread: Option<JoinHandle<()>>,
}

/// `plan` cut after the feed-out of its `n`-th circle (and the dwells after it).
pub fn plan_up_to(plan: &Plan, n: usize) -> Plan {
    let mut seen = 0;
    let mut end = plan.segments.len();
    for (i, s) in plan.segments.iter().enumerate() {
        if let Segment::Line {
            role: LineRole::FeedOut,
            ..
        } = s
        {
            seen += 1;
            if seen == n {
                end = i + 1;
                while matches!(plan.segments.get(end), Some(Segment::Dwell { .. })) {
                    end += 1;
                }
                break;
            }
        }
    }
    let mut cut = plan.clone();
    cut.segments.truncate(end);
    cut
}

impl Diagnoser {
    /// Start the worker for `plan`; `tolerance_um` for the verdict.
    pub fn start(plan: &Plan, tolerance_um: Option<f64>) -> Diagnoser {
        let (tx, rx_msg) = channel::<Msg>();
        let (tx_res, rx) = channel::<SoFar>();
        let plan = plan.clone();
        let thread = std::thread::Builder::new()
            .name("jdbb-live-diagnosis".into())
            .spawn(move || work(&plan, tolerance_um, &rx_msg, &tx_res))
            .ok();
        Diagnoser {
            tx: Some(tx),
            rx,
            thread,
        }
    }

    /// Hand over samples (never waits).
    pub fn samples(&self, batch: Vec<(f64, f64)>) {
        if let Some(tx) = &self.tx {
            let _ = tx.send(Msg::Samples(batch));
        }
    }

    /// Circle `n` (1-based) ended at `t_s` (never waits).
    pub fn circle_done(&self, n: usize, t_s: f64) {
        if let Some(tx) = &self.tx {
            let _ = tx.send(Msg::CircleDone { n, t_s });
        }
    }

    /// The latest result, if one came since the last call (never waits).
    pub fn result(&self) -> Option<SoFar> {
        let mut last = None;
        loop {
            match self.rx.try_recv() {
                Ok(r) => last = Some(r),
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return last,
            }
        }
    }
}

impl Drop for Diagnoser {
    fn drop(&mut self) {
        // Closing the channel ends the worker after what it is doing.
        self.tx.take();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn work(plan: &Plan, tolerance_um: Option<f64>, rx: &Receiver<Msg>, tx: &Sender<SoFar>) {
    let (mut t, mut d) = (Vec::<f64>::new(), Vec::<f64>::new());
    let mut pending: Option<(usize, f64)> = None;
    while let Ok(msg) = rx.recv() {
        match msg {
            Msg::Samples(b) => {
                for (ts, dm) in b {
                    t.push(ts);
                    d.push(dm);
                }
            }
            Msg::CircleDone { n, t_s } => pending = Some((n, t_s)),
        }
        let Some((n, t_end)) = pending else {
            continue;
        };
        if t.last().is_none_or(|&last| last < t_end + SETTLE_S) {
            continue;
        }
        pending = None;
        let t0 = Instant::now();
        let cut = plan_up_to(plan, n);
        let rec = Record::from_samples(&PathBuf::from("(samples so far)"), t.clone(), d.clone());
        // One pass (the ramps not read again through the errors found, as `diagnose_planned`
        // does at the end): a circle's preview must come while the next one runs.
        let result = synchronise(&cut, &rec).and_then(|sync| {
            check_holes(&rec, &sync)?;
            let (path, dd) = data_path(&cut, &rec, &sync, [None; 3])?;
            let diag = diagnose(&path, &dd, &Options::default())?;
            let mut text = format!("{}{}", sync_summary(&cut, &sync), summary(&diag));
            let mut pass = None;
            if let Some(tol) = tolerance_um {
                let (p, line) = tolerance_verdict(&diag, tol);
                text.push_str(&line);
                text.push('\n');
                pass = Some(p);
            }
            Ok((text, pass))
        });
        let (text, pass) = result.unwrap_or_else(|e| (format!("no diagnosis yet: {e}"), None));
        let so_far = SoFar {
            circles: n,
            text,
            pass,
            took_ms: t0.elapsed().as_secs_f64() * 1e3,
        };
        if tx.send(so_far).is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::circular::plan::build::{plan, PlanSpec};
    use crate::circular::plan::{Dialect, Plane};

    fn two_circles() -> Plan {
        let spec = PlanSpec::machine_test(
            &[85.0, 95.0],
            &[0.0],
            Plane::Xy,
            2000.0,
            [0.0, 0.0, 0.0],
            Dialect::Linuxcnc,
        );
        plan(&spec, &jdbb_core::calib::Calibration::DEFAULT).unwrap()
    }

    fn feed_outs(p: &Plan) -> usize {
        p.segments
            .iter()
            .filter(|s| {
                matches!(
                    s,
                    Segment::Line {
                        role: LineRole::FeedOut,
                        ..
                    }
                )
            })
            .count()
    }

    #[test]
    fn the_plan_is_cut_after_the_nth_circle_and_its_dwells() {
        let p = two_circles();
        assert_eq!(feed_outs(&p), 2);
        let one = plan_up_to(&p, 1);
        assert_eq!(feed_outs(&one), 1);
        assert!(one.segments.len() < p.segments.len());
        assert_eq!(one.segments[..], p.segments[..one.segments.len()]);
        // Ends with the feed-out or the dwells after it, never a motion of circle 2.
        let last_motion = one
            .segments
            .iter()
            .rev()
            .find(|s| !matches!(s, Segment::Dwell { .. }))
            .unwrap();
        assert!(matches!(
            last_motion,
            Segment::Line {
                role: LineRole::FeedOut,
                ..
            }
        ));
        assert_eq!(plan_up_to(&p, 2).segments, p.segments);
    }

    #[test]
    fn a_circle_is_diagnosed_only_once_its_samples_have_settled_and_says_why_not() {
        let p = two_circles();
        let w = Diagnoser::start(&p, Some(20.0));
        // Circle 1 "ended" at 1 s: nothing until samples reach 1.5 s.
        w.circle_done(1, 1.0);
        w.samples((0..1400).map(|i| (i as f64 * 1e-3, 85.0)).collect());
        std::thread::sleep(std::time::Duration::from_millis(200));
        assert!(w.result().is_none());
        w.samples((1400..1600).map(|i| (i as f64 * 1e-3, 85.0)).collect());
        let t0 = Instant::now();
        let r = loop {
            if let Some(r) = w.result() {
                break r;
            }
            assert!(t0.elapsed().as_secs() < 30, "no result");
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        // D never moved: no feed-in to find, and the text says so.
        assert_eq!(r.circles, 1);
        assert_eq!(r.pass, None);
        assert!(r.text.starts_with("no diagnosis yet: "), "{}", r.text);
        assert!(r.text.contains("no feed-in"), "{}", r.text);
    }
}
