//! Where a recording stands against its plan while it is made (`jdbb record --plan`): a cheap
//! tracker of D against the plan's levels, sample by sample, not the synchronisation.
//!
//! - **Cycle start**: D leaves the level it had when the record began by more than
//!   [`MOVE_MM`]. If the record's first sample is not at the start level (within
//!   [`crate::sync::LEVEL_TOLERANCE_MM`]), cycle start was missed: the program ran before the
//!   record began, and the record cannot be synchronised with the plan (said after [`FIRST_S`],
//!   with whether D was moving then).
//! - **Circle and arc**: once D has left the circle being run, the next circle is the first
//!   later one of the plan whose level D reaches (within [`crate::sync::LEVEL_TOLERANCE_MM`]); the arc's share is the time on that level over
//!   the circle's arcs at the programmed feed (an estimate: the override changes it).
//! - **End**: the program has ended when at least its duration at the programmed feed has passed
//!   since cycle start, the last circle was run and left, and D has stood still (within [`MOVE_MM`]) at
//!   the end point's level (within [`crate::sync::LEVEL_TOLERANCE_MM`]) for [`END_STILL_S`].
use crate::plan::{dist, Plan, Segment};
use crate::simulate::machine::Machine;
use crate::simulate::record_sim::Timeline;
use crate::sync::LEVEL_TOLERANCE_MM;

/// D moving by more than this (mm) from the start level is cycle start.
pub const MOVE_MM: f64 = 0.02;
/// The record's first this many seconds show whether cycle start was missed.
pub const FIRST_S: f64 = 0.5;
/// D standing at the end level this long (s) after the program's duration ends the record.
pub const END_STILL_S: f64 = 3.0;

/// The tracker (module docs).
#[derive(Debug, Clone)]
pub struct Tracker {
    start_level_mm: f64,
    end_level_mm: f64,
    /// Per circle: D (mm) and the arcs' duration at the programmed feed (s).
    circles: Vec<(f64, f64)>,
    nominal_s: f64,
    t0_s: Option<f64>,
    first: (f64, f64),
    first_d_mm: f64,
    start_checked: bool,
    /// What was found wrong with the start, once.
    pub missed_start: Option<String>,
    /// Cycle start (s on the record's clock), once seen.
    pub cycle_start_s: Option<f64>,
    /// Circle being run (index) and when D reached its level.
    circle: Option<(usize, f64)>,
    /// Whether D has left the circle being run (its feed-out).
    left: bool,
    /// Since when (s) D has stood at the end level, and where (mm).
    still_since: Option<(f64, f64)>,
    last: (f64, f64),
}

impl Tracker {
    /// A tracker for `plan`.
    pub fn new(plan: &Plan) -> Tracker {
        let level = |p: [f64; 3]| dist(&p, &plan.centre_mm);
        let timeline = Machine::parse(std::path::Path::new("default"), "")
            .ok()
            .and_then(|m| Timeline::new(plan, &m).ok());
        let end = plan
            .segments
            .iter()
            .rev()
            .find_map(Segment::to_mm)
            .unwrap_or(plan.start_mm);
        let circles = plan
            .circles
            .iter()
            .map(|c| {
                let arcs: f64 = plan
                    .segments
                    .iter()
                    .filter_map(|s| match s {
                        Segment::Arc {
                            circle,
                            feed_mm_min,
                            ..
                        } if *circle == c.index => Some(s.length_mm() / feed_mm_min * 60.0),
                        _ => None,
                    })
                    .sum();
                (c.d_mm, arcs)
            })
            .collect();
        Tracker {
            start_level_mm: level(plan.start_mm),
            end_level_mm: level(end),
            circles,
            nominal_s: timeline.map_or(plan.nominal_duration_s(), |t| t.end_s()),
            t0_s: None,
            first: (f64::INFINITY, f64::NEG_INFINITY),
            first_d_mm: f64::NAN,
            start_checked: false,
            missed_start: None,
            cycle_start_s: None,
            circle: None,
            left: false,
            still_since: None,
            last: (0.0, 0.0),
        }
    }

    /// Take one sample: time (s, the record's clock) and D (mm).
    pub fn push(&mut self, t_s: f64, d_mm: f64) {
        let t0 = *self.t0_s.get_or_insert(t_s);
        if t_s == t0 {
            self.first_d_mm = d_mm;
        }
        self.last = (t_s, d_mm);
        if t_s - t0 <= FIRST_S {
            self.first = (self.first.0.min(d_mm), self.first.1.max(d_mm));
        } else if !self.start_checked {
            self.start_checked = true;
            let (lo, hi) = self.first;
            let d0 = self.first_d_mm;
            if (d0 - self.start_level_mm).abs() > LEVEL_TOLERANCE_MM {
                self.missed_start = Some(if hi - lo > MOVE_MM {
                    format!(
                        "cycle start was missed: D was already moving when the record began ({d0:.3} mm, {lo:.3} to {hi:.3} mm in its first {FIRST_S} s), away from the plan's start level {:.3} mm",
                        self.start_level_mm
                    )
                } else {
                    format!(
                        "cycle start was missed: D was {d0:.3} mm when the record began, not the plan's start level {:.3} mm",
                        self.start_level_mm
                    )
                });
            }
        }
        // From where D stood when the record began: set-up offsets move the levels by µm.
        if self.cycle_start_s.is_none() && (d_mm - self.first_d_mm).abs() > MOVE_MM {
            self.cycle_start_s = Some(t_s);
        }
        let Some(start) = self.cycle_start_s else {
            return;
        };
        // The circle being run is left when D leaves its level; only then is the next entered:
        // the first later circle whose level D reaches (consecutive circles of one sphere share
        // a level).
        if let Some((c, _)) = self.circle {
            if (d_mm - self.circles[c].0).abs() > LEVEL_TOLERANCE_MM {
                self.left = true;
            }
        }
        if self.circle.is_none() || self.left {
            let next = self.circle.map_or(0, |(k, _)| k + 1);
            if let Some(k) = (next..self.circles.len())
                .find(|&k| (d_mm - self.circles[k].0).abs() < 0.5 * LEVEL_TOLERANCE_MM)
            {
                self.circle = Some((k, t_s));
                self.left = false;
            }
        }
        let at_end = (d_mm - self.end_level_mm).abs() < LEVEL_TOLERANCE_MM;
        let last_seen = self.left
            && self
                .circle
                .is_some_and(|(k, _)| k + 1 == self.circles.len());
        let still = self
            .still_since
            .is_none_or(|(_, d0)| (d_mm - d0).abs() < MOVE_MM);
        if at_end && still && last_seen && t_s - start >= self.nominal_s - END_STILL_S {
            self.still_since.get_or_insert((t_s, d_mm));
        } else {
            self.still_since = None;
        }
    }

    /// The first sample's time (s), once there is one.
    pub fn first_t_s(&self) -> Option<f64> {
        self.t0_s
    }

    /// Whether the program has ended (module docs).
    pub fn ended(&self) -> bool {
        match (self.cycle_start_s, self.still_since) {
            (Some(start), Some((still, _))) => {
                self.last.0 - still >= END_STILL_S && self.last.0 - start >= self.nominal_s
            }
            _ => false,
        }
    }

    /// Where the run stands, in words: waiting for cycle start, or circle k of n and the arc's
    /// share.
    pub fn status(&self) -> String {
        match (self.cycle_start_s, self.circle) {
            (None, _) => "waiting for cycle start".into(),
            (Some(_), None) => {
                "feeding in to circle 1".to_string() + &format!("/{}", self.circles.len())
            }
            (Some(_), Some((k, since))) => {
                let pct = if self.circles[k].1 > 0.0 {
                    (100.0 * (self.last.0 - since) / self.circles[k].1).min(100.0)
                } else {
                    100.0
                };
                format!("circle {}/{}, arcs {pct:.0} %", k + 1, self.circles.len())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::build::{plan as make_plan, PlanSpec};
    use crate::plan::{Dialect, Plane};
    use crate::simulate::record_sim::record;
    use jdbb_core::calib::Calibration;

    fn plan() -> Plan {
        let spec = PlanSpec::machine_test(
            &[90.0, 85.0],
            &[0.0],
            Plane::Xy,
            1500.0,
            [100.0, 50.0, -20.0],
            Dialect::Linuxcnc,
        );
        make_plan(&spec, &Calibration::DEFAULT).unwrap()
    }

    /// The simulated record of `plan` on a machine (TOML), as (t_s, d_mm).
    fn samples(plan: &Plan, machine: &str) -> (Vec<(f64, f64)>, f64, f64) {
        let m = Machine::parse(std::path::Path::new("m.toml"), machine).unwrap();
        let (s, truth) = record(plan, &m).unwrap();
        let t0 = s[0].t_us as f64;
        let v = s
            .iter()
            .map(|x| ((x.t_us as f64 - t0) * 1e-6, x.d_mm))
            .collect();
        (v, (truth.cycle_start_t_us - t0) * 1e-6, truth.program_s)
    }

    #[test]
    fn the_start_the_circles_and_the_end_are_seen() {
        let plan = plan();
        let (v, start, program) = samples(
            &plan,
            "feed_override_pct = 90\ntable_ball_mm = [100.03, 49.98, -20.0]\n[instrument]\nsample_rate_hz = 200\nnoise_um = 0.5\ntail_s = 30\nstart_delay_s = 4\n",
        );
        let mut tr = Tracker::new(&plan);
        let mut ended_at = None;
        let mut circles_seen = vec![];
        for &(t, d) in &v {
            tr.push(t, d);
            let s = tr.status();
            if s.starts_with("circle") && circles_seen.last() != Some(&s[..10].to_string()) {
                circles_seen.push(s[..10].to_string());
            }
            if ended_at.is_none() && tr.ended() {
                ended_at = Some(t);
            }
        }
        assert!(tr.missed_start.is_none(), "{:?}", tr.missed_start);
        // The move to the feed-in start leaves the start level within a few ms of cycle start.
        let seen = tr.cycle_start_s.unwrap();
        assert!(seen > start && seen - start < 0.2, "{seen} {start}");
        assert_eq!(circles_seen, ["circle 1/2", "circle 2/2"]);
        // Ended after the program (at 90 %: longer than nominal) plus the still time, not before.
        let end = ended_at.unwrap();
        assert!(
            end > start + program && end < start + program + END_STILL_S + 1.0,
            "{end} {}",
            start + program
        );
    }

    #[test]
    fn a_record_begun_after_cycle_start_is_flagged() {
        let plan = plan();
        let (v, start, _) = samples(&plan, "[instrument]\nsample_rate_hz = 200\n");
        let mut tr = Tracker::new(&plan);
        // The operator pressed cycle start 10 s before starting the record.
        for &(t, d) in v.iter().filter(|(t, _)| *t > start + 10.0) {
            tr.push(t, d);
        }
        let m = tr.missed_start.clone().unwrap();
        assert!(m.contains("cycle start was missed"), "{m}");
        // A record begun in time is not flagged, and waits.
        let mut tr = Tracker::new(&plan);
        for &(t, d) in v.iter().filter(|(t, _)| *t < start) {
            tr.push(t, d);
        }
        assert!(tr.missed_start.is_none());
        assert_eq!(tr.status(), "waiting for cycle start");
    }

    #[test]
    fn a_calibration_test_is_followed_circle_by_circle_to_its_end() {
        // Spheres of three circles each at one D: equal levels one after another.
        let spec = PlanSpec {
            purpose: crate::plan::Purpose::CalibrationTest,
            circles: crate::plan::build::calibration_circles(&[85.0, 95.0]),
            ..PlanSpec::machine_test(
                &[90.0],
                &[0.0],
                Plane::Xy,
                3000.0,
                [100.0, 50.0, -20.0],
                Dialect::Linuxcnc,
            )
        };
        let plan = make_plan(&spec, &Calibration::DEFAULT).unwrap();
        assert_eq!(plan.circles.len(), 6);
        // At 80 % the run lasts well beyond its nominal duration: no stop before its end.
        let (v, start, program) = samples(
            &plan,
            "feed_override_pct = 80\n[instrument]\nsample_rate_hz = 50\nnoise_um = 0.3\ntail_s = 20\n",
        );
        let mut tr = Tracker::new(&plan);
        let mut seen: Vec<String> = vec![];
        let mut entered = vec![];
        let mut ended_at = None;
        for &(t, d) in &v {
            tr.push(t, d);
            let s = tr.status();
            if let Some(c) = s.strip_prefix("circle ").and_then(|r| r.split(',').next()) {
                if seen.last().map(String::as_str) != Some(c) {
                    seen.push(c.to_string());
                    entered.push(t);
                }
            }
            if ended_at.is_none() && tr.ended() {
                ended_at = Some(t);
            }
        }
        assert_eq!(seen, ["1/6", "2/6", "3/6", "4/6", "5/6", "6/6"]);
        // Each circle is entered after the one before has run its arcs (at least their time at
        // the programmed feed), not as soon as D shows the same level.
        for (k, w) in entered.windows(2).enumerate() {
            assert!(
                w[1] - w[0] > tr.circles[k].1,
                "circle {}: {entered:?}",
                k + 2
            );
        }
        let end = ended_at.unwrap();
        assert!(
            end > start + program && end < start + program + END_STILL_S + 1.0,
            "{end} {}",
            start + program
        );
    }
}
