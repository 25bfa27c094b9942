//! The diagnosis while recording: a worker thread that keeps its own copy of the samples (time
//! and D, sent by the feed in batches over a channel that never blocks the sender) and diagnoses
//! each circle alone, with the same functions as `jdbb diagnose --record --plan`:
//! - **circle 1** when the tracker has seen its feed-out end and [`SETTLE_S`] more seconds of
//!   samples came: the samples so far are synchronised with the plan cut after it
//!   ([`synchronise`]). Nothing in the record fixes the feed before that feed-out.
//! - **circle k + 1** as soon as its last data arc is in the record: its feed-in is found in D
//!   and its arcs timed at the feed the k circles before it measured
//!   ([`synchronise_running`]), seconds before its feed-out (a full circle's 180° overshoot).
//!   After each feed-out the circles completed are synchronised again, for the next one.
//!
//! The results go back to the feed over another channel, which the feed reads without waiting.
use std::path::PathBuf;
use std::sync::mpsc::{channel, Receiver, Sender, TryRecvError};
use std::thread::JoinHandle;
use std::time::Instant;

use serde::Serialize;

use crate::diagnose::input::check_holes;
use crate::diagnose::{diagnose, Diagnosis, Options};
use crate::model::words::cause;
use crate::plan::{LineRole, Plan, Segment};
use crate::report::{share_percentages, summary, sync_summary, tolerance_verdict};
use crate::sync::{data_path, synchronise, synchronise_running, Record, Running, Sync};
use crate::units::{format_estimate, format_to, human};

/// Seconds of samples after a circle's feed-out is seen back at D_in before its diagnosis runs:
/// the synchronisation fits the feed-out's ramp up to 0.25 s into the dwell after it.
pub const SETTLE_S: f64 = 0.5;

/// One circle's diagnosis while recording, as the page shows it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CircleDiagnosis {
    /// The circle diagnosed (1-based), alone.
    pub circle: usize,
    /// The text `jdbb diagnose --record --plan` prints for it, or why there is none.
    pub text: String,
    /// The ranked effects (the set-up first), as the text lists them; empty without a diagnosis.
    pub effects: Vec<EffectRow>,
    /// Circular deviation G per direction (minimum zone, ISO 230-4), and hysteresis H.
    pub zones: Vec<ZoneRow>,
    /// Hysteresis H (µm, the digits the residual supports), None without both directions.
    pub h_um: Option<String>,
    /// Against `--tolerance-um`, when given and the diagnosis succeeded.
    pub pass: Option<bool>,
    /// How long the synchronisation and diagnosis took (ms).
    pub took_ms: f64,
}

/// One ranked effect of a circle's diagnosis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EffectRow {
    /// `set-up` or `step k`, as `jdbb diagnose` prints it.
    pub step: String,
    pub name: String,
    /// Value ± σ with the digits σ supports.
    pub value: String,
    pub unit: String,
    /// Whole percent of the error (the shares and the residual's add up to 100); None for the
    /// set-up.
    pub share_percent: Option<u32>,
    /// The cause in words.
    pub cause: String,
}

/// G of one direction of a circle.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ZoneRow {
    /// `ccw` or `cw`.
    pub direction: &'static str,
    /// Minimum-zone width (µm, the digits the residual supports).
    pub g_um: String,
}

/// The rows of `diag` for the page.
fn rows(diag: &Diagnosis) -> (Vec<EffectRow>, Vec<ZoneRow>, Option<String>) {
    let shares = share_percentages(diag);
    let effects = diag
        .effects
        .iter()
        .enumerate()
        .map(|(i, f)| EffectRow {
            step: if i < 2 {
                "set-up".into()
            } else {
                format!("step {}", i - 1)
            },
            name: f.effect.name(),
            value: format_estimate(f.value, f.sigma),
            unit: human(f.effect.unit()),
            share_percent: shares.effects.get(i).copied().flatten(),
            cause: cause(f.effect, f.value),
        })
        .collect();
    let noise = diag.final_rms_um;
    let mut zones = vec![];
    let mut h_um = None;
    for z in &diag.circle_zones {
        for (direction, mz) in [("ccw", z.ccw), ("cw", z.cw)] {
            if let Some(mz) = mz {
                zones.push(ZoneRow {
                    direction,
                    g_um: format_to(mz.width_um, noise),
                });
            }
        }
        if z.ccw.is_some() && z.cw.is_some() {
            h_um = Some(format_to(z.h_um, noise));
        }
    }
    (effects, zones, h_um)
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
    rx: Receiver<CircleDiagnosis>,
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
        let (tx_res, rx) = channel::<CircleDiagnosis>();
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

    /// The circles diagnosed since the last call, in order (never waits).
    pub fn results(&self) -> Vec<CircleDiagnosis> {
        let mut out = vec![];
        loop {
            match self.rx.try_recv() {
                Ok(r) => out.push(r),
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return out,
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

fn work(plan: &Plan, tolerance_um: Option<f64>, rx: &Receiver<Msg>, tx: &Sender<CircleDiagnosis>) {
    let mut w = Work {
        plan,
        tolerance_um,
        t: vec![],
        d: vec![],
        completed: None,
        previewed: 0,
        retry_at_s: f64::NEG_INFINITY,
        pending: None,
    };
    while let Ok(msg) = rx.recv() {
        match msg {
            Msg::Samples(b) => {
                for (ts, dm) in b {
                    w.t.push(ts);
                    w.d.push(dm);
                }
            }
            Msg::CircleDone { n, t_s } => w.pending = Some((n, t_s)),
        }
        for diagnosis in w.step() {
            if tx.send(diagnosis).is_err() {
                return;
            }
        }
    }
}

/// The worker's state (module docs).
struct Work<'a> {
    plan: &'a Plan,
    tolerance_um: Option<f64>,
    t: Vec<f64>,
    d: Vec<f64>,
    /// The synchronisation of the first n circles, made after circle n's feed-out.
    completed: Option<(usize, Sync)>,
    /// Circles whose diagnosis was sent.
    previewed: usize,
    /// When (record time, s) to try the running circle again.
    retry_at_s: f64,
    /// A circle whose feed-out ended (n, at t_s), not yet synchronised.
    pending: Option<(usize, f64)>,
}

impl Work<'_> {
    fn record(&self) -> Record {
        Record::from_samples(
            &PathBuf::from("(samples so far)"),
            self.t.clone(),
            self.d.clone(),
        )
    }

    /// What is due with the samples so far: the running circle's diagnosis when its data arcs
    /// are in, and after a feed-out the synchronisation of the circles completed (with the
    /// circle's diagnosis, if it could not be made before).
    fn step(&mut self) -> Vec<CircleDiagnosis> {
        let mut out = vec![];
        let Some(&t_last) = self.t.last() else {
            return out;
        };
        if let Some((n, t_end)) = self.pending {
            if t_last >= t_end + SETTLE_S {
                self.pending = None;
                let t0 = Instant::now();
                let cut = plan_up_to(self.plan, n);
                let rec = self.record();
                match synchronise(&cut, &rec) {
                    Ok(sync) => {
                        if self.previewed < n {
                            out.push(self.diagnosis(n, &cut, &rec, Ok(sync.last_circle()), t0));
                            self.previewed = n;
                        }
                        self.completed = Some((n, sync));
                    }
                    Err(e) => {
                        if self.previewed < n {
                            out.push(self.diagnosis(n, &cut, &rec, Err(e), t0));
                            self.previewed = n;
                        }
                        self.completed = None;
                    }
                }
                self.retry_at_s = f64::NEG_INFINITY;
            }
        }
        // The running circle (index k = n completed), timed at the feed of the ones before it.
        let Some((n, before)) = &self.completed else {
            return out;
        };
        let k = *n;
        if self.previewed != k || k >= self.plan.circles.len() || t_last < self.retry_at_s {
            return out;
        }
        let t0 = Instant::now();
        let rec = self.record();
        match synchronise_running(self.plan, &rec, k, before) {
            Ok(Running::Wait { until_s }) => self.retry_at_s = until_s,
            Ok(Running::Ready(sync)) => {
                out.push(self.diagnosis(k + 1, self.plan, &rec, Ok(sync), t0));
                self.previewed = k + 1;
            }
            // Not timed before its feed-out: that synchronisation says why.
            Err(_) => self.retry_at_s = f64::INFINITY,
        }
        out
    }

    /// Circle `n`'s diagnosis from its synchronisation.
    fn diagnosis(
        &self,
        n: usize,
        plan: &Plan,
        rec: &Record,
        sync: crate::Result<Sync>,
        t0: Instant,
    ) -> CircleDiagnosis {
        let result = sync.and_then(|sync| {
            check_holes(rec, &sync)?;
            let (path, dd) = data_path(plan, rec, &sync, [None; 3])?;
            let diag = diagnose(&path, &dd, &Options::default())?;
            let mut text = format!("{}{}", sync_summary(plan, &sync), summary(&diag));
            let mut pass = None;
            if let Some(tol) = self.tolerance_um {
                let (p, line) = tolerance_verdict(&diag, tol);
                text.push_str(&line);
                text.push('\n');
                pass = Some(p);
            }
            Ok((text, pass, rows(&diag)))
        });
        let (text, pass, (effects, zones, h_um)) = result.unwrap_or_else(|e| {
            (
                format!("no diagnosis yet: {e}"),
                None,
                (vec![], vec![], None),
            )
        });
        CircleDiagnosis {
            circle: n,
            text,
            effects,
            zones,
            h_um,
            pass,
            took_ms: t0.elapsed().as_secs_f64() * 1e3,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::build::{plan, PlanSpec};
    use crate::plan::{Dialect, Plane};

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
        assert!(w.results().is_empty());
        w.samples((1400..1600).map(|i| (i as f64 * 1e-3, 85.0)).collect());
        let t0 = Instant::now();
        let r = loop {
            if let Some(r) = w.results().pop() {
                break r;
            }
            assert!(t0.elapsed().as_secs() < 30, "no result");
            std::thread::sleep(std::time::Duration::from_millis(20));
        };
        // D never moved: no feed-in to find, and the text says so.
        assert_eq!(r.circle, 1);
        assert_eq!(r.pass, None);
        assert!(r.effects.is_empty() && r.zones.is_empty());
        assert!(r.text.starts_with("no diagnosis yet: "), "{}", r.text);
        assert!(r.text.contains("no feed-in"), "{}", r.text);
    }
}
