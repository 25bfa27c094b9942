//! The J-DBB and `jdbb record`: true D → noise → counts (for a wandering lean of the bars) → the
//! device's D from those counts, stamped by the device's clock; rows written exactly as
//! `jdbb record` writes them; and the truth behind every row.

use std::io::{self, Write};

use jdbb_core::geometry::Kernel;
use jdbb_core::Calibration;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::mechanism::Mechanism;

use super::dynamics::{ColouredNoise, DynamicState, NoiseState};
use super::planner::SegmentKind;
use super::{SimError, Simulation};

/// First line of a recording (the same as `jdbb record`'s).
pub const CSV_HEADER: &str = "seq,t_us,enc1,enc2,d_mm\n";

/// How the bars lean: the azimuth ψ of bar 2 about bar 1 (the rotation of the whole instrument
/// about the line between the balls is free, so it drifts). A reflected random walk.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AzimuthWalk {
    /// ψ at the first sample (rad).
    pub start_rad: f64,
    /// Random-walk intensity (rad/√s): the standard deviation of the change over 1 s.
    pub rate_rad_per_sqrt_s: f64,
    /// ψ stays within `start_rad` ± this (rad), reflected at the bounds.
    pub half_range_rad: f64,
}

impl Default for AzimuthWalk {
    /// Starts at 0.3 rad, wanders by 0.02 rad/√s (≈ 0.5 rad over 10 min), within ±0.6 rad.
    fn default() -> Self {
        AzimuthWalk {
            start_rad: 0.3,
            rate_rad_per_sqrt_s: 0.02,
            half_range_rad: 0.6,
        }
    }
}

/// The instrument and the recording.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstrumentConfig {
    /// The calibration in force: the counts are made with it and the device computes D with it.
    pub calibration: Calibration,
    /// The instrument as built, when it differs from the calibration in force (calibration
    /// tests): the counts are made with this one while the device computes D with
    /// `calibration`, as a J-DBB with unknown errors running a nominal calibration does. None:
    /// the instrument is exactly `calibration`. Either way the counts come from the independent
    /// model of the instrument as built ([`crate::mechanism`]), not from the core model.
    pub true_calibration: Option<Calibration>,
    /// Sample rate on the device's clock (Hz).
    pub sample_rate_hz: f64,
    /// The device's clock runs at (1 + ppm·1e-6) × true time.
    pub clock_ppm: f64,
    /// Device time of the first sample (µs).
    pub t0_us: u64,
    /// The recording starts this long (true s) before cycle start: the operator starts `jdbb
    /// record`, then presses cycle start.
    pub start_delay_s: f64,
    /// The recording goes on this long (true s) after the program ends.
    pub tail_s: f64,
    /// Gaussian noise on D, standard deviation (µm), added before quantisation.
    pub noise_um: f64,
    /// Correlated noise on D besides the white noise (its own random stream).
    pub coloured_noise: ColouredNoise,
    /// Lean of the bars.
    pub azimuth: AzimuthWalk,
    /// Seed of the noise and the azimuth walk.
    pub seed: u64,
}

impl Default for InstrumentConfig {
    /// The default J-DBB (`Calibration::DEFAULT`) at 1 kHz on a perfect clock starting at 0,
    /// 3 s before cycle start, 2 s after the end, no noise.
    fn default() -> Self {
        InstrumentConfig {
            calibration: Calibration::DEFAULT,
            true_calibration: None,
            sample_rate_hz: 1000.0,
            clock_ppm: 0.0,
            t0_us: 0,
            start_delay_s: 3.0,
            tail_s: 2.0,
            noise_um: 0.0,
            coloured_noise: ColouredNoise::default(),
            azimuth: AzimuthWalk::default(),
            seed: 1,
        }
    }
}

impl InstrumentConfig {
    pub(super) fn validate(&self) -> Result<(), String> {
        self.calibration
            .validate()
            .map_err(|e| format!("calibration rejected: {e:?}"))?;
        if let Some(t) = &self.true_calibration {
            t.validate()
                .map_err(|e| format!("true_calibration rejected: {e:?}"))?;
        }
        let pos = |v: f64| v > 0.0 && v.is_finite();
        let nonneg = |v: f64| v >= 0.0 && v.is_finite();
        if !(pos(self.sample_rate_hz) && self.sample_rate_hz <= 1e6) {
            return Err("sample_rate_hz must be in (0, 1e6] Hz".into());
        }
        if self.clock_ppm.is_nan() || self.clock_ppm.abs() >= 1e5 {
            return Err("clock_ppm must be within ±1e5".into());
        }
        if !(nonneg(self.start_delay_s) && nonneg(self.tail_s) && nonneg(self.noise_um)) {
            return Err("start_delay_s, tail_s and noise_um must be ≥ 0".into());
        }
        self.coloured_noise.validate()?;
        let a = &self.azimuth;
        if !(a.start_rad.is_finite() && nonneg(a.rate_rad_per_sqrt_s) && nonneg(a.half_range_rad)) {
            return Err("azimuth: start finite, rate and half range ≥ 0".into());
        }
        Ok(())
    }
}

/// One row of the recording, as `jdbb record` writes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// Sequence number from 0.
    pub seq: u64,
    /// Device time (µs).
    pub t_us: u64,
    /// Extended count of encoder 1.
    pub enc1: i64,
    /// Extended count of encoder 2.
    pub enc2: i64,
    /// D computed by the device from the counts (mm).
    pub d_mm: f64,
}

impl Row {
    /// Append the CSV line `seq,t_us,enc1,enc2,d_mm` (D with 7 decimals, newline-terminated).
    pub fn write_csv_line(&self, out: &mut impl Write) -> io::Result<()> {
        writeln!(
            out,
            "{},{},{},{},{:.7}",
            self.seq, self.t_us, self.enc1, self.enc2, self.d_mm
        )
    }
}

/// Write a whole recording: header and one line per row.
pub fn write_csv<'a>(
    out: &mut impl Write,
    rows: impl IntoIterator<Item = &'a Row>,
) -> io::Result<()> {
    out.write_all(CSV_HEADER.as_bytes())?;
    for r in rows {
        r.write_csv_line(out)?;
    }
    Ok(())
}

/// What really happened at one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthSample {
    /// Sequence number (as the row's).
    pub seq: u64,
    /// True time since the recording started (s).
    pub t_s: f64,
    /// Device time (µs), as the row's `t_us`.
    pub t_device_us: u64,
    /// Program time (s since the first block started).
    pub t_program_s: f64,
    /// Index of the block running (`None` before the program starts or after it ends).
    pub block: Option<usize>,
    /// Commanded spindle-ball position (mm).
    pub command_mm: [f64; 3],
    /// Actual spindle-ball position (mm).
    pub actual_mm: [f64; 3],
    /// True D (mm): actual positions, set-up, length offset and drift, no noise.
    pub d_mm_true: f64,
    /// The D the frames were set to: true D + noise, before quantisation (mm).
    pub d_mm_instrument: f64,
    /// Lean azimuth ψ (rad).
    pub azimuth_rad: f64,
    /// Counts of encoder 1 (as in the row).
    pub enc1: i64,
    /// Counts of encoder 2.
    pub enc2: i64,
}

/// When one block ran, on both clocks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlockTiming {
    /// Source line (1-based).
    pub line: usize,
    /// `N` number.
    pub n: Option<u32>,
    /// What it was.
    pub kind: SegmentKind,
    /// Start, true s since the recording started (negative: before it).
    pub start_s: f64,
    /// End, true s since the recording started.
    pub end_s: f64,
    /// Start on the device clock (µs, unrounded).
    pub start_us: f64,
    /// End on the device clock (µs, unrounded).
    pub end_us: f64,
    /// Commanded position at the start (mm).
    pub from_mm: [f64; 3],
    /// Commanded position at the end (mm).
    pub to_mm: [f64; 3],
}

/// Everything the tests may compare a synchronisation or diagnosis with.
#[derive(Debug, Clone, PartialEq)]
pub struct Truth {
    /// Cycle start (the operator's press ending the first program stop) on the device clock (µs).
    pub cycle_start_us: f64,
    /// The feed factor the machine really ran at (feed override / 100).
    pub feed_factor: f64,
    /// Device clock error (ppm).
    pub clock_ppm: f64,
    /// Program time of the first sample (s).
    pub recording_start_program_s: f64,
    /// Every executed block.
    pub blocks: Vec<BlockTiming>,
    /// Every sample.
    pub samples: Vec<TruthSample>,
}

/// A simulated recording: the rows `jdbb record` would write, and the truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The CSV rows.
    pub rows: Vec<Row>,
    /// What happened.
    pub truth: Truth,
}

impl Recording {
    /// Write the rows as `jdbb record` does.
    pub fn write_csv(&self, out: &mut impl Write) -> io::Result<()> {
        write_csv(out, &self.rows)
    }
}

/// One sample: the row and its truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// What the device reports.
    pub row: Row,
    /// What happened.
    pub truth: TruthSample,
}

/// The samples of a [`Simulation`], computed one at a time (memory independent of length).
#[derive(Debug)]
pub struct Samples<'a> {
    sim: &'a Simulation,
    k: u64,
    /// Two streams, so that switching the noise on does not change the lean's path.
    rng_psi: ChaCha8Rng,
    rng_noise: ChaCha8Rng,
    /// A third stream for the coloured noise.
    rng_coloured: ChaCha8Rng,
    coloured: NoiseState,
    /// The machine's dynamics along the recording (None: nothing to integrate).
    dynamic: Option<DynamicState<'a>>,
    psi: f64,
    kernel: Kernel,
    /// The instrument as built: `true_calibration`, else the calibration in force, built from
    /// parts by the independent mechanism model.
    mechanism: Mechanism,
    failed: bool,
}

impl<'a> Samples<'a> {
    pub(super) fn new(sim: &'a Simulation) -> Self {
        let ins = &sim.config.instrument;
        Samples {
            sim,
            k: 0,
            rng_psi: ChaCha8Rng::seed_from_u64(ins.seed),
            rng_noise: {
                let mut r = ChaCha8Rng::seed_from_u64(ins.seed);
                r.set_stream(1);
                r
            },
            rng_coloured: {
                let mut r = ChaCha8Rng::seed_from_u64(ins.seed);
                r.set_stream(2);
                r
            },
            coloured: NoiseState::default(),
            dynamic: sim.config.errors.dynamics.is_on().then(|| {
                DynamicState::new(
                    &sim.config.errors.dynamics,
                    &sim.trajectory,
                    sim.recording_start_s,
                )
            }),
            psi: ins.azimuth.start_rad,
            kernel: Kernel::new(&ins.calibration),
            mechanism: Mechanism::new(ins.true_calibration.as_ref().unwrap_or(&ins.calibration)),
            failed: false,
        }
    }

    fn step_azimuth(&mut self, dt: f64) {
        let a = &self.sim.config.instrument.azimuth;
        if a.rate_rad_per_sqrt_s > 0.0 {
            let z: f64 = self.rng_psi.sample(StandardNormal);
            self.psi += a.rate_rad_per_sqrt_s * dt.sqrt() * z;
            let (lo, hi) = (
                a.start_rad - a.half_range_rad,
                a.start_rad + a.half_range_rad,
            );
            // Reflect into [lo, hi] (a span of 0 pins ψ).
            if hi <= lo {
                self.psi = a.start_rad;
            } else {
                let w = hi - lo;
                let x = (self.psi - lo).rem_euclid(2.0 * w);
                self.psi = lo + if x > w { 2.0 * w - x } else { x };
            }
        }
    }
}

impl Iterator for Samples<'_> {
    type Item = Result<Sample, SimError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.failed || self.k >= self.sim.n_samples {
            return None;
        }
        let sim = self.sim;
        let ins = &sim.config.instrument;
        let k = self.k;
        self.k += 1;
        let scale = 1.0 + ins.clock_ppm * 1e-6;
        let t_dev_s = k as f64 / ins.sample_rate_hz;
        let t_us = ins.t0_us + (k as f64 * 1e6 / ins.sample_rate_hz).round() as u64;
        let t_s = t_dev_s / scale;
        let t_p = sim.recording_start_s + t_s;
        if k > 0 {
            self.step_azimuth(1.0 / (ins.sample_rate_hz * scale));
        }
        let traj = &sim.trajectory;
        let errors = &sim.config.errors;
        let ball = sim.config.table_ball_mm;
        let pose = match &mut self.dynamic {
            Some(dynamic) => errors.actual_moving(traj, t_p, ball, &dynamic.at(traj, t_p)),
            None => errors.actual(traj, t_p, ball),
        };
        let d_true = errors.distance_mm(pose.actual_mm, ball, t_p, traj.cycle_start_s);
        let mut d_ins = if ins.noise_um > 0.0 {
            let z: f64 = self.rng_noise.sample(StandardNormal);
            d_true + ins.noise_um * 1e-3 * z
        } else {
            d_true
        };
        if ins.coloured_noise.is_on() {
            let dt = 1.0 / (ins.sample_rate_hz * scale);
            let rng = &mut self.rng_coloured;
            let n = self
                .coloured
                .next(&ins.coloured_noise, dt, || rng.sample(StandardNormal));
            d_ins += n * 1e-3;
        }
        let block = (t_p >= 0.0 && t_p < traj.end_s).then(|| traj.segment_at(t_p));
        // The counts: the independent model of the instrument as built, not the core's inverse.
        let counts = self
            .mechanism
            .counts_for_pose(d_ins, self.psi)
            .ok()
            .map(|[a, b]| (a, b));
        let Some((enc1, enc2)) = counts else {
            self.failed = true;
            return Some(Err(SimError::OutOfReach {
                t_s,
                line: block.map(|b| traj.segments[b].line),
                d_mm: d_ins,
                azimuth_rad: self.psi,
            }));
        };
        // The device: the production kernel the firmware's sampler runs on these counts.
        let d_mm = self.kernel.distance_mm(enc1, enc2);
        let row = Row {
            seq: k,
            t_us,
            enc1,
            enc2,
            d_mm,
        };
        Some(Ok(Sample {
            row,
            truth: TruthSample {
                seq: k,
                t_s,
                t_device_us: t_us,
                t_program_s: t_p,
                block,
                command_mm: pose.command_mm,
                actual_mm: pose.actual_mm,
                d_mm_true: d_true,
                d_mm_instrument: d_ins,
                azimuth_rad: self.psi,
                enc1,
                enc2,
            },
        }))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = (self.sim.n_samples - self.k) as usize;
        (0, Some(n))
    }
}
