//! The nominal path of a test, with what the effects need of it: time, the commanded spindle-ball
//! centre relative to the table ball, velocity, the held direction of motion per axis, and the
//! pitch phase of each axis that has a pitch. Also the axis and axis-pair names.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
use crate::{Error, Result};

/// A machine axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Axis {
    X = 0,
    Y = 1,
    Z = 2,
}

impl Axis {
    pub const ALL: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];
    pub fn index(self) -> usize {
        self as usize
    }
    pub fn letter(self) -> char {
        ['x', 'y', 'z'][self as usize]
    }
    /// The axis called `x`, `y` or `z`.
    pub fn parse(c: &str) -> Option<Axis> {
        match c {
            "x" => Some(Axis::X),
            "y" => Some(Axis::Y),
            "z" => Some(Axis::Z),
            _ => None,
        }
    }
}

/// An ordered axis pair ij ∈ {xy, yz, zx}.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Pair {
    Xy,
    Yz,
    Zx,
}

impl Pair {
    pub const ALL: [Pair; 3] = [Pair::Xy, Pair::Yz, Pair::Zx];
    /// (i, j) of the pair.
    pub fn axes(self) -> (Axis, Axis) {
        match self {
            Pair::Xy => (Axis::X, Axis::Y),
            Pair::Yz => (Axis::Y, Axis::Z),
            Pair::Zx => (Axis::Z, Axis::X),
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Pair::Xy => "xy",
            Pair::Yz => "yz",
            Pair::Zx => "zx",
        }
    }
    /// The pair called `xy`, `yz` or `zx`.
    pub fn parse(s: &str) -> Option<Pair> {
        match s {
            "xy" => Some(Pair::Xy),
            "yz" => Some(Pair::Yz),
            "zx" => Some(Pair::Zx),
            _ => None,
        }
    }
}

/// Parse a pitch per axis, `x=10,y=10,z=5` (mm), as `--pitch` takes it: each axis at most once,
/// each pitch positive.
pub fn parse_pitch(s: &str) -> Result<[Option<f64>; 3]> {
    let mut out = [None; 3];
    for part in s.split(',').filter(|p| !p.trim().is_empty()) {
        let (k, v) = part.split_once('=').ok_or_else(|| {
            Error::Usage(format!(
                "--pitch: `{part}` should look like x=10 (axis=pitch in mm)"
            ))
        })?;
        let axis = match k.trim().to_ascii_lowercase().as_str() {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            other => {
                return Err(Error::Usage(format!(
                    "--pitch: unknown axis `{other}`; use x, y or z"
                )))
            }
        };
        let p: f64 = v
            .trim()
            .parse()
            .ok()
            .filter(|p: &f64| p.is_finite() && *p > 0.0)
            .ok_or_else(|| Error::Usage(format!("--pitch: `{v}` is not a positive pitch in mm")))?;
        if out[axis].is_some() {
            return Err(Error::Usage(format!(
                "--pitch: axis {} is given twice; give each axis once",
                k.trim()
            )));
        }
        out[axis] = Some(p);
    }
    Ok(out)
}

/// Central differences of `x` against `t`, one-sided at the ends and at a gap in time (a step
/// over [`GAP_STEPS`] median sample periods: the path holds the data arcs of several circles, and
/// a difference across the jump between two of them is no velocity of either); zero where time
/// stands still or a run has a single sample.
fn derivative(t_s: &[f64], x: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let n = x.len();
    let gap_s = GAP_STEPS * median_interval(t_s);
    let joined = |i: usize| gap_s <= 0.0 || t_s[i + 1] - t_s[i] <= gap_s;
    let mut d = vec![[0.0; 3]; n];
    for i in 0..n {
        let back = i > 0 && joined(i - 1);
        let ahead = i + 1 < n && joined(i);
        let (a, b) = match (back, ahead) {
            (true, true) => (i - 1, i + 1),
            (true, false) => (i - 1, i),
            (false, true) => (i, i + 1),
            (false, false) => continue,
        };
        let dt = t_s[b] - t_s[a];
        if dt > 0.0 {
            for k in 0..3 {
                d[i][k] = (x[b][k] - x[a][k]) / dt;
            }
        }
    }
    d
}

/// A step in time of more than this many median sample periods is a gap between runs of samples
/// ([`derivative`] does not difference across it). Glitches set aside leave gaps of a few
/// samples, across which the motion is still smooth; between circles there are seconds.
const GAP_STEPS: f64 = 20.0;

/// Median time between samples (s), the sample period of a record or path; 0 for fewer than
/// two.
pub(crate) fn median_interval(t: &[f64]) -> f64 {
    // At most about a million intervals, evenly spread: bounded memory for any record.
    const MOST: usize = 1 << 20;
    let stride = (t.len() / MOST).max(1);
    let mut dts: Vec<f64> = (1..t.len())
        .step_by(stride)
        .map(|i| t[i] - t[i - 1])
        .collect();
    if dts.is_empty() {
        return 0.0;
    }
    let mid = dts.len() / 2;
    *dts.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// A reversal of one axis: the time (s) its commanded velocity crossed zero, the sign of the
/// new direction, and where the axis turned (mm, in the path's frame: relative to the table
/// ball). A dead band (backlash) is taken up over the first `b` of travel from there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reversal {
    pub t_s: f64,
    pub new_dir: i8,
    pub p_mm: f64,
}

/// The nominal path with the derived motion: velocity, acceleration, held direction and the
/// reversals per axis.
#[derive(Debug, Clone)]
pub struct Path {
    pub t_s: Vec<f64>,
    pub p_mm: Vec<[f64; 3]>,
    /// Velocity from the nominal path and time (central differences).
    pub v_mm_s: Vec<[f64; 3]>,
    /// Acceleration: central differences of the velocity (the servo delay's second-order term).
    pub a_mm_s2: Vec<[f64; 3]>,
    /// Reversals per axis in time order (see [`Path::set_reversals`]): where the held direction
    /// changes sign, at the zero crossing of the velocity.
    pub reversals: [Vec<Reversal>; 3],
    /// Direction of motion per axis, +1/−1, holding its sign through a standstill; 0 for an axis
    /// that never moves.
    pub dir: Vec<[i8; 3]>,
    /// Ball-screw or scale pitch per axis (mm), needed by the periodic effects.
    pub pitch_mm: [Option<f64>; 3],
    /// Travel range (max − min) per axis, mm.
    pub range_mm: [f64; 3],
    /// Lowest and highest position per axis on the path (mm, relative to the table ball); the
    /// ends that a bow and the lost motion per end refer to are derived from them
    /// (`model::travel_ends_mm`).
    pub lo_mm: [f64; 3],
    pub hi_mm: [f64; 3],
    /// See [`Path::pitch_phase`].
    pub(crate) phase: Vec<[(f64, f64); 3]>,
    /// Standard error of the samples' times against the machine's motion (s): 0 where the path
    /// comes with its times (a nominal path file, a simulation); the synchronisation's where the
    /// times were found from D ([`crate::sync`]). What depends on the time of a reversal (a
    /// reversal spike's height) carries it into its standard error.
    pub timing_sigma_s: f64,
}

impl Path {
    /// Derive velocity and direction from the nominal positions and times (times strictly
    /// increasing; the caller checks).
    pub fn new(t_s: Vec<f64>, p_mm: Vec<[f64; 3]>, pitch_mm: [Option<f64>; 3]) -> Path {
        let n = p_mm.len();
        let v = derivative(&t_s, &p_mm);
        let a = derivative(&t_s, &v);
        let mut range = [0.0; 3];
        let mut lo_mm = [0.0; 3];
        let mut hi_mm = [0.0; 3];
        for k in 0..3 {
            let (lo, hi) = p_mm
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    (lo.min(p[k]), hi.max(p[k]))
                });
            range[k] = if n > 0 { hi - lo } else { 0.0 };
            if n > 0 {
                (lo_mm[k], hi_mm[k]) = (lo, hi);
            }
        }
        // Direction with hold: a speed below 1e-9 of the fastest axis speed is a standstill.
        let vmax = v
            .iter()
            .flat_map(|x| x.iter())
            .fold(0.0f64, |m, &x| m.max(x.abs()));
        let eps = vmax * 1e-9;
        let mut dir = vec![[0i8; 3]; n];
        for k in 0..3 {
            let first = v.iter().map(|x| x[k]).find(|x| x.abs() > eps);
            let mut held: i8 = match first {
                Some(x) if x > 0.0 => 1,
                Some(_) => -1,
                None => 0,
            };
            for i in 0..n {
                if v[i][k] > eps {
                    held = 1;
                } else if v[i][k] < -eps {
                    held = -1;
                }
                dir[i][k] = held;
            }
        }
        let mut reversals: [Vec<Reversal>; 3] = Default::default();
        for k in 0..3 {
            for i in 1..n {
                let (d0, d1) = (dir[i - 1][k], dir[i][k]);
                if d0 != 0 && d1 != 0 && d0 != d1 {
                    // Zero crossing of v between i−1 and i (at i−1 if it stood still there).
                    let (v0, v1) = (v[i - 1][k], v[i][k]);
                    let f = if (v0 > eps && v1 < -eps) || (v0 < -eps && v1 > eps) {
                        v0 / (v0 - v1)
                    } else {
                        0.0
                    };
                    // The turning point: the extreme of the samples around the crossing.
                    let ext = if d0 > 0 {
                        p_mm[i - 1][k].max(p_mm[i][k])
                    } else {
                        p_mm[i - 1][k].min(p_mm[i][k])
                    };
                    reversals[k].push(Reversal {
                        t_s: t_s[i - 1] + f * (t_s[i] - t_s[i - 1]),
                        new_dir: d1,
                        p_mm: ext,
                    });
                }
            }
        }
        let phase = p_mm
            .iter()
            .map(|p| {
                let mut out = [(0.0, 0.0); 3];
                for (k, o) in out.iter_mut().enumerate() {
                    if let Some(pitch) = pitch_mm[k] {
                        *o = (std::f64::consts::TAU * p[k] / pitch).sin_cos();
                    }
                }
                out
            })
            .collect();
        Path {
            t_s,
            p_mm,
            v_mm_s: v,
            a_mm_s2: a,
            reversals,
            dir,
            pitch_mm,
            range_mm: range,
            lo_mm,
            hi_mm,
            phase,
            timing_sigma_s: 0.0,
        }
    }

    /// Replace the reversals found in the samples by those of the whole nominal motion, e.g. when
    /// the path holds only the data arcs of a plan and an axis reversed between them.
    pub fn set_reversals(&mut self, reversals: [Vec<Reversal>; 3]) {
        self.reversals = reversals;
    }

    /// The last reversal of axis `k` at or before `t_s`, if any.
    pub fn last_reversal(&self, k: usize, t_s: f64) -> Option<Reversal> {
        let r = &self.reversals[k];
        let n = r.partition_point(|x| x.t_s <= t_s);
        n.checked_sub(1).map(|i| r[i])
    }

    pub fn len(&self) -> usize {
        self.p_mm.len()
    }

    pub fn is_empty(&self) -> bool {
        self.p_mm.is_empty()
    }

    /// (sin, cos) of 2π·k/pitch_k per axis at sample i; (0, 0) for an axis without a pitch.
    /// Computed once in [`Path::new`]: every periodic column needs it on every pass.
    pub fn pitch_phase(&self, i: usize) -> [(f64, f64); 3] {
        self.phase[i]
    }

    /// Whether axis k moves at all.
    pub fn moves(&self, k: Axis) -> bool {
        self.range_mm[k.index()] > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pitch_parses_and_rejects() {
        assert_eq!(
            parse_pitch("x=10,z=5").unwrap(),
            [Some(10.0), None, Some(5.0)]
        );
        assert!(parse_pitch("w=1").is_err());
        assert!(parse_pitch("x=-1").is_err());
        assert!(parse_pitch("x").is_err());
        assert!(parse_pitch("x=10,x=20")
            .unwrap_err()
            .to_string()
            .contains("given twice"));
    }

    #[test]
    fn direction_holds_through_a_standstill() {
        // x goes 0 → 1, stops, then 1 → 2: direction stays +1 during the stop.
        let t: Vec<f64> = (0..30).map(|i| i as f64).collect();
        let p: Vec<[f64; 3]> = (0..30)
            .map(|i| {
                let x = if i < 10 {
                    i as f64 * 0.1
                } else if i < 20 {
                    1.0
                } else {
                    1.0 + (i - 19) as f64 * 0.1
                };
                [x, 0.0, 0.0]
            })
            .collect();
        let path = Path::new(t, p, [None; 3]);
        assert!(path.dir.iter().all(|d| d[0] == 1), "{:?}", path.dir);
        assert!(path.dir.iter().all(|d| d[1] == 0));
        assert!(path.moves(Axis::X) && !path.moves(Axis::Y));
    }
}
