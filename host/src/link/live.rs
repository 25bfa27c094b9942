//! The live readout (`jdbb live`): the latest D (mm, 4 decimals = 0.1 µm), the measured sample rate and the loss
//! counters, redrawn on one terminal line a few times per second — or, when stdout is not a
//! terminal (a log, a CI job), printed as one line per second.
use std::time::{Duration, Instant};

use super::stream::Stats;

/// Terminal redraw interval.
pub const REDRAW: Duration = Duration::from_millis(250);
/// Window over which the sample rate is measured, and the line interval when not a terminal.
pub const RATE_WINDOW: Duration = Duration::from_secs(1);

/// Received-sample rate over consecutive windows of [`RATE_WINDOW`] (host clock).
#[derive(Debug)]
pub struct RateMeter {
    start: Instant,
    start_samples: u64,
    /// The rate (Hz) over the last full window, None before the first.
    pub hz: Option<f64>,
}

impl RateMeter {
    /// A meter whose first window starts at `now`.
    pub fn new(now: Instant) -> Self {
        RateMeter {
            start: now,
            start_samples: 0,
            hz: None,
        }
    }

    /// Close the window if it is full; returns whether it was.
    pub fn update(&mut self, now: Instant, samples: u64) -> bool {
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
pub fn status_line(d_mm: Option<f64>, hz: Option<f64>, st: &Stats) -> String {
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
