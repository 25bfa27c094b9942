//! Data the instrument as built ([`crate::mechanism`]) would give, for testing the calibration
//! (issue 9 §6): a calibrator with CMM-measured lengths while the knee is swung through its range
//! ([`swing`], [`calibrator_samples`]), held-out poses as an ordinary record ([`pose_record`]), and
//! a circular test of a perfect machine recorded by that instrument ([`circular_record`]).
//!
//! Counts always come from the mechanism's inverse with its hidden errors, rounded to integers;
//! the reference distance is the pose's true D. The `d_mm` column of a record is what the
//! instrument would have written with its *nominal* calibration: `jdbb_core::geometry::distance_mm`,
//! the model under test.
use std::fmt::Write as _;

use jdbb_core::calib::Calibration;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use crate::mechanism::{add, cross, dot, norm, rotate, scale, sub, unit, Mechanism, PoseError, V3};

/// A pose of the knee: ball distance and lean azimuth of bar 2 in bar 1's frame (from +x
/// towards +y).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Ball distance D (mm).
    pub d_mm: f64,
    /// Lean azimuth (rad).
    pub azimuth_rad: f64,
}

/// The knee swung all round at each distance: `per_turn` azimuths equally spaced from
/// `phase_rad`. Poses the frames cannot reach are left for [`calibrator_samples`] to drop.
pub fn swing(distances_mm: &[f64], per_turn: usize, phase_rad: f64) -> Vec<Pose> {
    let mut poses = Vec::with_capacity(distances_mm.len() * per_turn);
    for &d_mm in distances_mm {
        for i in 0..per_turn {
            let azimuth_rad = phase_rad + std::f64::consts::TAU * i as f64 / per_turn as f64;
            poses.push(Pose { d_mm, azimuth_rad });
        }
    }
    poses
}

/// `n` distances equally spaced from `from_mm` to `to_mm` inclusive.
pub fn distances_mm(from_mm: f64, to_mm: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| from_mm + (to_mm - from_mm) * i as f64 / (n.max(2) - 1) as f64)
        .collect()
}

/// One row of a calibration file `enc1,enc2,d_ref_mm`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalSample {
    /// Encoder 1's extended count.
    pub enc1: i64,
    /// Encoder 2's extended count.
    pub enc2: i64,
    /// The calibrator's reference distance (mm): true D plus its own noise.
    pub d_ref_mm: f64,
    /// The true D (mm), without the calibrator's noise (not written to the file).
    pub d_true_mm: f64,
}

/// What the calibrator records at each pose the frames can reach: the instrument's counts and
/// the reference length with Gaussian noise of `noise_um` (µm, one sigma) from `seed`.
pub fn calibrator_samples(
    m: &Mechanism,
    poses: &[Pose],
    noise_um: f64,
    seed: u64,
) -> Vec<CalSample> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, noise_um * 1e-3).expect("finite noise");
    poses
        .iter()
        .filter_map(|p| match m.counts_for_pose(p.d_mm, p.azimuth_rad) {
            Ok([enc1, enc2]) => Some(CalSample {
                enc1,
                enc2,
                d_ref_mm: p.d_mm + noise.sample(&mut rng),
                d_true_mm: p.d_mm,
            }),
            Err(PoseError::OutOfRange) => None,
            Err(e) => panic!("pose {p:?}: {e:?}"),
        })
        .collect()
}

/// The calibration file `enc1,enc2,d_ref_mm` of `jdbb calibrate --samples`.
pub fn samples_csv(samples: &[CalSample]) -> String {
    let mut s = String::from("enc1,enc2,d_ref_mm\n");
    for r in samples {
        writeln!(s, "{},{},{}", r.enc1, r.enc2, r.d_ref_mm).unwrap();
    }
    s
}

/// One row of a `jdbb record` file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordRow {
    /// Sample sequence number.
    pub seq: u64,
    /// Device time (µs).
    pub t_us: u64,
    /// Encoder 1's extended count.
    pub enc1: i64,
    /// Encoder 2's extended count.
    pub enc2: i64,
    /// D the instrument wrote with its nominal calibration (mm).
    pub d_mm: f64,
}

/// A record file `seq,t_us,enc1,enc2,d_mm`.
pub fn record_csv(rows: &[RecordRow]) -> String {
    let mut s = String::from("seq,t_us,enc1,enc2,d_mm\n");
    for r in rows {
        writeln!(s, "{},{},{},{},{}", r.seq, r.t_us, r.enc1, r.enc2, r.d_mm).unwrap();
    }
    s
}

/// Held-out poses as a record (one sample per pose every 10 ms, `d_mm` from the nominal
/// calibration) and the true D of each row. Poses the frames cannot reach are dropped.
pub fn pose_record(
    m: &Mechanism,
    nominal: &Calibration,
    poses: &[Pose],
) -> (Vec<RecordRow>, Vec<f64>) {
    let samples = calibrator_samples(m, poses, 0.0, 0);
    let rows = samples
        .iter()
        .enumerate()
        .map(|(i, s)| RecordRow {
            seq: i as u64,
            t_us: 10_000 * i as u64,
            enc1: s.enc1,
            enc2: s.enc2,
            d_mm: jdbb_core::geometry::distance_mm(nominal, s.enc1, s.enc2),
        })
        .collect();
    (rows, samples.iter().map(|s| s.d_true_mm).collect())
}

/// A circular test of a perfect machine: the spindle ball circles the table ball (at the
/// origin) in a plane parallel to machine xy, counter-clockwise once, then clockwise once.
#[derive(Debug, Clone, Copy)]
pub struct CircularTest {
    /// Circle radius (mm).
    pub radius_mm: f64,
    /// Height of the circle's plane above the table ball (mm, machine z).
    pub height_mm: f64,
    /// Path speed (mm/s).
    pub speed_mm_s: f64,
    /// Sample rate (Hz).
    pub rate_hz: f64,
    /// Bar 1's spin about its own axis at the start (rad): where frame 1's axis points.
    pub start_spin_rad: f64,
}

/// A circular-test record made by the instrument as built.
#[derive(Debug, Clone)]
pub struct CircularRecord {
    /// The record (`d_mm` from the nominal calibration).
    pub rows: Vec<RecordRow>,
    /// The nominal path `t_s,x_mm,y_mm,z_mm` relative to the table ball, at the record's times.
    pub path: Vec<[f64; 4]>,
    /// The knee's lean azimuth (rad) in bar 1's frame at each sample.
    pub azimuth_rad: Vec<f64>,
}

/// The nominal path file `t_s,x_mm,y_mm,z_mm` of `jdbb diagnose --record --path`.
pub fn path_csv(path: &[[f64; 4]]) -> String {
    let mut s = String::from("t_s,x_mm,y_mm,z_mm\n");
    for p in path {
        writeln!(s, "{},{},{},{}", p[0], p[1], p[2], p[3]).unwrap();
    }
    s
}

/// Record a circular test of a perfect machine with the instrument as built.
///
/// How the knee sits is physics the plan cannot set, so it is modelled: the joint hangs at the
/// lowest point its bars allow (gravity, machine −z), and bar 1 does not spin in its cup — from
/// sample to sample its frame is carried by the smallest rotation that turns its old direction
/// into its new one. The knee's lean azimuth in bar 1's frame then drifts as the machine circles
/// (by the solid angle bar 1 sweeps), so instrument errors that depend on the azimuth enter the
/// record as functions of the path.
pub fn circular_record(
    m: &Mechanism,
    nominal: &Calibration,
    test: &CircularTest,
) -> Result<CircularRecord, PoseError> {
    let (l1, l2) = (m.l1_mm, m.l2_mm);
    let circle_s = std::f64::consts::TAU * test.radius_mm / test.speed_mm_s;
    let per_circle = (circle_s * test.rate_hz).round() as usize;
    let omega = std::f64::consts::TAU / per_circle as f64;
    let down: V3 = [0.0, 0.0, -1.0];
    let mut rows = Vec::with_capacity(2 * per_circle + 1);
    let mut path = Vec::with_capacity(2 * per_circle + 1);
    let mut azimuth_rad = Vec::with_capacity(2 * per_circle + 1);
    // Bar 1's frame (x̂, ẑ) in machine coordinates; set at the first sample.
    let mut frame: Option<(V3, V3)> = None;
    for i in 0..=2 * per_circle {
        let angle = if i <= per_circle {
            omega * i as f64
        } else {
            omega * (2 * per_circle - i) as f64
        };
        let p: V3 = [
            test.radius_mm * angle.cos(),
            test.radius_mm * angle.sin(),
            test.height_mm,
        ];
        let d = norm(p);
        // The joint: on the circle of points L1 from B1 and L2 from B2, at its lowest point.
        let axis = unit(p);
        let along = (l1 * l1 - l2 * l2 + d * d) / (2.0 * d);
        let rho = (l1 * l1 - along * along).sqrt();
        let hang = unit(sub(down, scale(axis, dot(down, axis))));
        let joint = add(scale(axis, along), scale(hang, rho));
        let z1 = unit(joint);
        let (x1, z1) = match frame {
            None => {
                let x0 = unit(cross([0.0, 0.0, 1.0], z1));
                (rotate(x0, z1, test.start_spin_rad), z1)
            }
            Some((x_old, z_old)) => {
                let k = cross(z_old, z1);
                let x = if norm(k) > 0.0 {
                    rotate(x_old, unit(k), dot(z_old, z1).clamp(-1.0, 1.0).acos())
                } else {
                    x_old
                };
                // Keep x̂ exactly normal to bar 1.
                (unit(sub(x, scale(z1, dot(x, z1)))), z1)
            }
        };
        frame = Some((x1, z1));
        let y1 = cross(z1, x1);
        let u_world = scale(sub(p, joint), 1.0 / l2);
        let u = [dot(u_world, x1), dot(u_world, y1), dot(u_world, z1)];
        let [enc1, enc2] = m.counts_for_direction(u)?;
        let t_us = (i as f64 * 1e6 / test.rate_hz).round() as u64;
        rows.push(RecordRow {
            seq: i as u64,
            t_us,
            enc1,
            enc2,
            d_mm: jdbb_core::geometry::distance_mm(nominal, enc1, enc2),
        });
        path.push([t_us as f64 * 1e-6, p[0], p[1], p[2]]);
        azimuth_rad.push(u[1].atan2(u[0]));
    }
    Ok(CircularRecord {
        rows,
        path,
        azimuth_rad,
    })
}
