//! The recorder's side of the live page: it takes every batch of samples, follows the plan
//! ([`Tracker`]) and, at most every [`PUBLISH_INTERVAL`], publishes the state as one JSON text
//! into a [`Board`]. Publishing never waits: if a page's thread holds the board at that moment
//! (for the microseconds it takes to clone an `Arc`), this publication is skipped and the next
//! one goes through. So a slow, stalled or closed page costs the recorder no sample.
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::state::{Counts, LiveState, Tracker, Verdict};
use super::worker::Diagnoser;
use crate::link::live::RateMeter;
use crate::link::stream::{SeqSample, Stats};
use crate::plan::Plan;

/// Least time between two publications (25 Hz at most, so that the page, which looks every
/// [`super::server::EVENT_INTERVAL`], gets well over 10 a second).
pub const PUBLISH_INTERVAL: Duration = Duration::from_millis(40);

/// The latest published state: its version and JSON. Shared by the recorder (writer) and the
/// page's threads (readers).
#[derive(Debug, Default)]
pub struct Published {
    pub version: u64,
    pub json: Arc<String>,
}

/// Where the latest state is published.
pub type Board = Arc<Mutex<Published>>;

/// A new, empty board (version 0, the JSON of an empty state).
pub fn new_board() -> Board {
    Arc::new(Mutex::new(Published {
        version: 0,
        json: Arc::new(LiveState::default().to_json()),
    }))
}

/// The recorder's side of the live page (module docs).
#[derive(Debug)]
pub struct LiveFeed {
    board: Board,
    tracker: Option<Tracker>,
    state: LiveState,
    rate: RateMeter,
    t0: Instant,
    last_publish: Option<Instant>,
    /// The first sample's `t_us` (the tracker's time origin).
    t0_us: Option<u64>,
    /// The diagnosis while recording, with a plan.
    diagnoser: Option<Diagnoser>,
    circles_done: usize,
    /// Publications skipped because a page held the board.
    pub skipped: u64,
}

impl LiveFeed {
    /// A feed publishing into `board`, following `plan` when one is given (and diagnosing each
    /// circle as it completes, against `tolerance_um`); its clock starts now.
    pub fn new(board: Board, plan: Option<&Plan>, tolerance_um: Option<f64>) -> LiveFeed {
        let t0 = Instant::now();
        LiveFeed {
            board,
            tracker: plan.map(Tracker::new),
            state: LiveState::default(),
            rate: RateMeter::new(t0),
            t0,
            last_publish: None,
            t0_us: None,
            diagnoser: plan.map(|p| Diagnoser::start(p, tolerance_um)),
            circles_done: 0,
            skipped: 0,
        }
    }

    /// Take a batch of samples (the ones written to the record, in order).
    pub fn samples(&mut self, batch: &[SeqSample]) {
        let Some(last) = batch.last() else {
            return;
        };
        self.state.d_mm = Some(last.sample.d_mm);
        let t0_us = *self.t0_us.get_or_insert(batch[0].sample.t_us);
        if let Some(t) = self.tracker.as_mut() {
            let mut pairs = Vec::with_capacity(batch.len());
            for s in batch {
                let t_s = s.sample.t_us.saturating_sub(t0_us) as f64 * 1e-6;
                t.push(t_s, s.sample.d_mm);
                pairs.push((t_s, s.sample.d_mm));
                if t.circles_done() > self.circles_done {
                    self.circles_done = t.circles_done();
                    if let Some(w) = &self.diagnoser {
                        w.circle_done(self.circles_done, t_s);
                    }
                }
            }
            if let Some(w) = &self.diagnoser {
                w.samples(pairs);
            }
        }
    }

    /// Each circle's diagnosis while recording, as last published.
    pub fn circle_diagnoses(&self) -> &[super::worker::CircleDiagnosis] {
        &self.state.circle_diagnoses
    }

    /// Publish the state if [`PUBLISH_INTERVAL`] has passed since the last publication.
    pub fn publish_if_due(&mut self, stats: &Stats, now: Instant) {
        self.rate.update(now, stats.samples);
        if self
            .last_publish
            .is_some_and(|l| now.duration_since(l) < PUBLISH_INTERVAL)
        {
            return;
        }
        self.last_publish = Some(now);
        self.publish(stats, now);
    }

    /// The session ended (`words`: how, as the summary says): publish at once, whatever the
    /// interval, waiting for the board if need be (the recording is over).
    pub fn finish(&mut self, stats: &Stats, words: &str) {
        self.state.ended = Some(words.to_string());
        self.publish_now(stats, Instant::now());
    }

    /// After the recording: publish at once if the worker has diagnosed another circle since the
    /// last publication (a debug build, or a long last circle, can take longer than the record).
    pub fn publish_new_diagnoses(&mut self, stats: &Stats) {
        let new = self
            .diagnoser
            .as_ref()
            .map(Diagnoser::results)
            .unwrap_or_default();
        if !new.is_empty() {
            self.state.circle_diagnoses.extend(new);
            self.publish_now(stats, Instant::now());
        }
    }

    /// Publish the end-of-test diagnosis summary and its verdict, if a tolerance was given
    /// (waits for the board: the recording is over).
    pub fn diagnosis(&mut self, stats: &Stats, text: &str, verdict: Option<Verdict>) {
        self.state.diagnosis = Some(text.to_string());
        self.state.verdict = verdict;
        self.publish_now(stats, Instant::now());
    }

    /// A warning the terminal shows (its whole text): on the page with the next publication,
    /// which is due at once. The same text twice is shown once.
    pub fn warn(&mut self, text: &str) {
        if !self.state.warnings.iter().any(|w| w == text) {
            self.state.warnings.push(text.to_string());
            self.last_publish = None;
        }
    }

    fn fill(&mut self, stats: &Stats, now: Instant) {
        self.state.version += 1;
        self.state.rate_hz = self.rate.hz;
        self.state.counts = Counts {
            samples: stats.samples,
            lost: stats.lost,
            dropped: stats.device_dropped,
            corrupt: stats.corrupt.total(),
            resets: stats.resets,
        };
        self.state.elapsed_s = now.duration_since(self.t0).as_secs_f64();
        if let Some(t) = &self.tracker {
            self.state.progress = Some(t.progress());
            self.state.trace = t.trace();
        }
        if let Some(w) = &self.diagnoser {
            self.state.circle_diagnoses.extend(w.results());
        }
    }

    fn publish(&mut self, stats: &Stats, now: Instant) {
        self.fill(stats, now);
        let json = Arc::new(self.state.to_json());
        // Never wait: a page that holds the board costs this publication, not a sample.
        let Ok(mut board) = self.board.try_lock() else {
            self.skipped += 1;
            return;
        };
        board.version = self.state.version;
        board.json = json;
    }

    fn publish_now(&mut self, stats: &Stats, now: Instant) {
        self.fill(stats, now);
        let json = Arc::new(self.state.to_json());
        let mut board = self.board.lock().unwrap_or_else(|p| p.into_inner());
        board.version = self.state.version;
        board.json = json;
    }
}
