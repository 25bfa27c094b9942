//! A plan's program run on a [`Machine`] and recorded by a J-DBB, sample by sample, as `jdbb
//! record` would record it (`jdbb simulate --plan plan.json --machine MACHINE.toml`).
//!
//! # The motion
//! The program is the plan's segments after its first stop (M0: the operator mounts the
//! instrument, then presses cycle start). Each motion runs from rest to rest with a trapezoidal
//! speed profile ([`Profile`]: accelerate at `accel_mm_s2`, cruise, decelerate), except that tangent
//! arcs of one circle and one sense run as one move (the controller blends them, as the plan's
//! synchronisation expects). Lines and arcs run at their feed × `feed_override_pct`, a G0 at
//! `rapid_mm_min`; dwells last their seconds (they do not follow the override); every later M0
//! lasts `operator_stop_s`. A Marlin controller draws arcs as chords of `arc_segment_mm`.
//!
//! # The machine and the instrument
//! The commanded positions, relative to the plan's table ball, become a [`Path`] on true time; the
//! machine's errors (the diagnosis's effects, [`distances_mm`]) and the true table ball position
//! (a set-up offset) give the true D. The instrument adds Gaussian noise, turns D into encoder
//! counts through its calibration for the bars' lean (`jdbb_core::geometry`), and computes D from
//! the counts with the firmware's kernel. Its clock runs `clock_ppm` fast; the recording starts
//! `start_delay_s` before cycle start and ends `tail_s` after the program's end.
//!
//! The host's own models are used here (not the tests' G-code machine, which is the independent
//! check of all this).
use jdbb_core::geometry::{self, Kernel};
use jdbb_core::protocol::{Sample, Status};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use crate::model::path::Path;
use crate::model::Effect;
use crate::plan::{Dialect, Plan, Segment};
use crate::simulate::machine::Machine;
use crate::simulate::{distances_mm, EffectValue, MAX_SAMPLES};
use crate::sync::Profile;
use crate::{Error, Result};

/// One piece of the program's timeline (program time, s from cycle start).
#[derive(Debug, Clone)]
enum Piece {
    /// Standing still at a position (a dwell, a stop).
    Hold { t1_s: f64, p_mm: [f64; 3] },
    /// A move from rest to rest over one or more segments: (segment, its start along the move,
    /// its length).
    Move {
        profile: Profile,
        segments: Vec<(usize, f64, f64)>,
    },
}

impl Piece {
    fn end_s(&self) -> f64 {
        match self {
            Piece::Hold { t1_s, .. } => *t1_s,
            Piece::Move { profile, .. } => profile.end_s(),
        }
    }
}

/// The timed program: where the commanded spindle ball is at every program time.
#[derive(Debug, Clone)]
pub struct Timeline {
    pieces: Vec<Piece>,
    start_mm: [f64; 3],
    end_mm: [f64; 3],
    chord_mm: Option<f64>,
}

/// Whether two consecutive segments run as one move: arcs of the same circle, sense and feed,
/// the second starting where the first ends.
fn blends(a: &Segment, b: &Segment) -> bool {
    match (a, b) {
        (
            Segment::Arc {
                circle: c1,
                sense: s1,
                feed_mm_min: f1,
                to_mm,
                ..
            },
            Segment::Arc {
                circle: c2,
                sense: s2,
                feed_mm_min: f2,
                from_mm,
                ..
            },
        ) => c1 == c2 && s1 == s2 && f1 == f2 && crate::plan::dist(to_mm, from_mm) < 1e-3,
        _ => false,
    }
}

impl Timeline {
    /// Time the plan's program on the machine (module docs).
    pub fn new(plan: &Plan, machine: &Machine) -> Result<Timeline> {
        let first_stop = plan
            .segments
            .iter()
            .position(|s| matches!(s, Segment::Stop))
            .ok_or_else(|| {
                Error::Usage(
                    "the plan has no program stop (M0) to start from; make it with `jdbb plan`"
                        .into(),
                )
            })?;
        let dialect = machine.controller.unwrap_or(plan.dialect);
        let chord_mm = (dialect == Dialect::Marlin).then_some(machine.arc_segment_mm);
        let over = machine.feed_override_pct / 100.0;
        let a = machine.accel_mm_s2;
        let mut pieces = vec![];
        let mut t = 0.0;
        let mut here = plan.position_at(first_stop, 0.0);
        let start_mm = here;
        let mut i = first_stop + 1;
        while i < plan.segments.len() {
            let seg = &plan.segments[i];
            match seg {
                Segment::Stop | Segment::Dwell { .. } => {
                    let d = match seg {
                        Segment::Dwell { seconds } => *seconds,
                        _ => machine.operator_stop_s,
                    };
                    pieces.push(Piece::Hold {
                        t1_s: t + d,
                        p_mm: here,
                    });
                    t += d;
                    i += 1;
                }
                Segment::Rapid { .. } | Segment::Line { .. } | Segment::Arc { .. } => {
                    let speed = match seg {
                        Segment::Line { feed_mm_min, .. } | Segment::Arc { feed_mm_min, .. } => {
                            feed_mm_min / 60.0 * over
                        }
                        _ => machine.rapid_mm_min / 60.0,
                    };
                    let mut segments = vec![(i, 0.0, seg.length_mm())];
                    let mut length = seg.length_mm();
                    while i + 1 < plan.segments.len()
                        && blends(&plan.segments[i], &plan.segments[i + 1])
                    {
                        i += 1;
                        let l = plan.segments[i].length_mm();
                        segments.push((i, length, l));
                        length += l;
                    }
                    if length > 0.0 {
                        let profile = Profile {
                            t0_s: t,
                            length_mm: length,
                            speed_mm_s: speed,
                            accel_mm_s2: a,
                        };
                        t = profile.end_s();
                        pieces.push(Piece::Move { profile, segments });
                    }
                    here = plan.position_at(i, f64::INFINITY);
                    i += 1;
                }
            }
        }
        Ok(Timeline {
            pieces,
            start_mm,
            end_mm: here,
            chord_mm,
        })
    }

    /// When the program ends (s after cycle start).
    pub fn end_s(&self) -> f64 {
        self.pieces.last().map_or(0.0, Piece::end_s)
    }

    /// The commanded position (program mm) at program time `t` (s after cycle start; before it
    /// the start point, after the end the last point).
    pub fn position_at(&self, plan: &Plan, t: f64) -> [f64; 3] {
        if t <= 0.0 || self.pieces.is_empty() {
            return self.start_mm;
        }
        let k = self.pieces.partition_point(|p| p.end_s() < t);
        let Some(piece) = self.pieces.get(k) else {
            return self.end_mm;
        };
        match piece {
            Piece::Hold { p_mm, .. } => *p_mm,
            Piece::Move { profile, segments } => {
                let s = profile.s_at(t);
                let j = segments
                    .partition_point(|&(_, s0, _)| s0 <= s)
                    .saturating_sub(1);
                let (seg, s0, len) = segments[j];
                let local = (s - s0).clamp(0.0, len);
                match (self.chord_mm, &plan.segments[seg]) {
                    (Some(chord), Segment::Arc { .. }) if len > 0.0 => {
                        // Marlin: straight chords between points of the arc.
                        let n = (len / chord).ceil().max(1.0);
                        let step = len / n;
                        let c = (local / step).floor().min(n - 1.0);
                        let (a, b) = (
                            plan.position_at(seg, c * step),
                            plan.position_at(seg, (c + 1.0) * step),
                        );
                        let f = (local - c * step) / step;
                        std::array::from_fn(|k| a[k] + f * (b[k] - a[k]))
                    }
                    _ => plan.position_at(seg, local),
                }
            }
        }
    }
}

/// What a simulated recording knows of itself (the truth, for the messages and the tests).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Truth {
    /// Cycle start on the device's clock (µs).
    pub cycle_start_t_us: f64,
    /// The program's duration (true s).
    pub program_s: f64,
    /// Measured over programmed feed on the device's clock (the override and the clock error).
    pub feed_factor: f64,
}

/// The device's samples of `plan` run on `machine` (module docs), with the truth.
pub fn record(plan: &Plan, machine: &Machine) -> Result<(Vec<Sample>, Truth)> {
    let timeline = Timeline::new(plan, machine)?;
    let ins = &machine.instrument;
    let scale = 1.0 + ins.clock_ppm * 1e-6;
    let total_s = ins.start_delay_s + timeline.end_s() + ins.tail_s;
    let n_f = (total_s * scale * ins.sample_rate_hz).floor() + 1.0;
    if n_f > MAX_SAMPLES as f64 {
        return Err(Error::Usage(format!(
            "this recording would have {n_f:.3e} samples; simulate makes at most {MAX_SAMPLES}: lower the machine's instrument.sample_rate_hz"
        )));
    }
    let n = n_f as usize;
    let mut t_s = Vec::with_capacity(n);
    let mut p_mm = Vec::with_capacity(n);
    for k in 0..n {
        let t = k as f64 / ins.sample_rate_hz / scale; // true s since the recording started
        let q = timeline.position_at(plan, t - ins.start_delay_s);
        t_s.push(t);
        p_mm.push(std::array::from_fn(|a| q[a] - plan.centre_mm[a]));
    }
    let path = Path::new(t_s, p_mm, machine.pitch_mm);
    let mut effects = machine.effects.clone();
    if let Some(ball) = machine.table_ball_mm {
        // The table ball at centre + c: a set-up offset c (µm), added to one given.
        let c: Vec<f64> = (0..3)
            .map(|k| 1e3 * (ball[k] - plan.centre_mm[k]))
            .collect();
        match effects.iter_mut().find(|e| e.effect == Effect::SetupOffset) {
            Some(e) => e.params.iter_mut().zip(&c).for_each(|(p, c)| *p += c),
            None => effects.push(EffectValue {
                effect: Effect::SetupOffset,
                params: c,
            }),
        }
    }
    let d_true = distances_mm(&path, &effects)?;
    let mut rng = rand::rngs::StdRng::seed_from_u64(ins.seed);
    let normal = Normal::new(0.0, ins.noise_um * 1e-3)
        .map_err(|e| Error::Usage(format!("noise_um {}: {e}", ins.noise_um)))?;
    let kernel = Kernel::new(&ins.calibration);
    let mut samples = Vec::with_capacity(n);
    for (k, d) in d_true.iter().enumerate() {
        let d_ins = if ins.noise_um > 0.0 {
            d + normal.sample(&mut rng)
        } else {
            *d
        };
        let Some((enc1, enc2)) =
            geometry::counts_for_distance(&ins.calibration, d_ins, ins.lean_rad)
        else {
            return Err(Error::Usage(format!(
                "at {:.3} s of the recording D is {d_ins:.3} mm, out of the instrument's reach (L1 {} mm, L2 {} mm): the machine's errors or the table ball position are too large for this plan",
                path.t_s[k], ins.calibration.l1_mm, ins.calibration.l2_mm
            )));
        };
        let t_us = ins.t0_us + (k as f64 * 1e6 / ins.sample_rate_hz).round() as u64;
        samples.push(Sample {
            t_us,
            enc1,
            enc2,
            d_mm: kernel.distance_mm(enc1, enc2),
            status: Status(0),
        });
    }
    let truth = Truth {
        cycle_start_t_us: ins.t0_us as f64 + ins.start_delay_s * scale * 1e6,
        program_s: timeline.end_s(),
        feed_factor: machine.feed_override_pct / 100.0 / scale,
    };
    Ok((samples, truth))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::build::{plan as make_plan, PlanSpec};
    use crate::plan::Plane;
    use jdbb_core::calib::Calibration;

    fn machine(text: &str) -> Machine {
        Machine::parse(std::path::Path::new("m.toml"), text).unwrap()
    }

    fn plan(dialect: Dialect) -> Plan {
        let spec = PlanSpec::machine_test(
            &[90.0],
            &[0.0],
            Plane::Xy,
            1200.0,
            [100.0, 50.0, -20.0],
            dialect,
        );
        make_plan(&spec, &Calibration::DEFAULT).unwrap()
    }

    #[test]
    fn timeline_lasts_the_moves_at_the_overridden_feed_and_the_dwells() {
        let plan = plan(Dialect::Linuxcnc);
        for (pct, a) in [(100.0, 500.0), (80.0, 200.0)] {
            let m = machine(&format!("feed_override_pct = {pct}\naccel_mm_s2 = {a}\n"));
            let tl = Timeline::new(&plan, &m).unwrap();
            // Per move from rest to rest: L/v + v/a, or 2√(L/a) where it never cruises; dwells
            // as programmed.
            let v = 1200.0 / 60.0 * pct / 100.0;
            let moves = tl
                .pieces
                .iter()
                .filter(|p| matches!(p, Piece::Move { .. }))
                .count() as f64;
            let mut runs = vec![];
            let mut dwell = 0.0;
            for (i, s) in plan.segments.iter().enumerate().skip(2) {
                match s {
                    Segment::Dwell { seconds } => dwell += seconds,
                    _ if blends(&plan.segments[i - 1], s) => {
                        *runs.last_mut().unwrap() += s.length_mm()
                    }
                    _ => runs.push(s.length_mm()),
                }
            }
            let moving: f64 = runs
                .iter()
                .map(|&l| {
                    if v * v / a >= l {
                        2.0 * (l / a).sqrt()
                    } else {
                        l / v + v / a
                    }
                })
                .sum();
            let expect = moving + dwell;
            assert!(
                (tl.end_s() - expect).abs() < 1e-9,
                "{} {expect}",
                tl.end_s()
            );
            // Lines, and the four runs of blended arcs (ccw lead-in..overshoot, then cw): the
            // move to the start, feed-in, two runs, feed-out.
            assert_eq!(moves, 5.0);
            // Before cycle start at the start point, and back at the feed-in start at the end.
            assert_eq!(tl.position_at(&plan, -1.0), plan.start_mm);
            let end = tl.position_at(&plan, tl.end_s() + 1.0);
            assert!(crate::plan::dist(&end, &[188.0, 50.0, -20.0]) < 1e-9);
        }
    }

    #[test]
    fn marlin_draws_arcs_as_chords() {
        let plan = plan(Dialect::Marlin);
        let m = machine("arc_segment_mm = 5.0\n");
        let tl = Timeline::new(&plan, &m).unwrap();
        let c = plan.centre_mm;
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for piece in &tl.pieces {
            let Piece::Move { profile, segments } = piece else {
                continue;
            };
            if !matches!(plan.segments[segments[0].0], Segment::Arc { .. }) {
                continue;
            }
            for k in 0..=5000 {
                let t = profile.t0_s + k as f64 * profile.duration_s() / 5000.0;
                let r = crate::plan::dist(&tl.position_at(&plan, t), &c);
                lo = lo.min(r);
                hi = hi.max(r);
            }
        }
        // Sagitta of a 5 mm chord at R 90: 90 − √(90² − 2.5²) = 34.7 µm.
        let sag = 90.0 - (90.0f64 * 90.0 - 2.5 * 2.5).sqrt();
        assert!((hi - 90.0).abs() < 1e-6, "{hi}");
        assert!((90.0 - lo - sag).abs() < 2e-3, "{lo} {sag}");
    }

    #[test]
    fn a_perfect_machine_records_the_plan_levels_through_the_counts() {
        let plan = plan(Dialect::Linuxcnc);
        let m = machine("[instrument]\nsample_rate_hz = 200\nclock_ppm = 50\nt0_us = 1000\n");
        let (samples, truth) = record(&plan, &m).unwrap();
        assert_eq!(samples[0].t_us, 1000);
        assert_eq!(samples[1].t_us, 6000);
        // Before cycle start D is the start point's, on the arcs the circle's (the counts'
        // quantisation and the kernel's single precision: well under 1 µm).
        assert!((samples[0].d_mm - 87.5).abs() < 1e-3, "{}", samples[0].d_mm);
        let on_circle = samples
            .iter()
            .filter(|s| (s.d_mm - 90.0).abs() < 1e-3)
            .count();
        assert!(
            on_circle as f64 > 0.8 * truth.program_s * 200.0 * 0.9,
            "{on_circle}"
        );
        assert!((truth.feed_factor - 1.0 / 1.00005).abs() < 1e-12);
        assert!((truth.cycle_start_t_us - (1000.0 + 3e6 * 1.00005)).abs() < 1e-6);
    }
}
