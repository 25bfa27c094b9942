//! The inputs of a circular-test diagnosis, read into a [`Path`] and the measured D.
//!
//! - [`read_samples`]: CSV `t_s,x_mm,y_mm,z_mm,d_mm` (any column order, extra columns ignored):
//!   time, the nominal (commanded) spindle-ball centre relative to the table ball in machine axes,
//!   and the measured ball distance D. `jdbb simulate` writes this.
//! - [`read_record_with_path`]: a `jdbb record` file (`seq,t_us,enc1,enc2,d_mm`) and the nominal
//!   path as CSV `t_s,x_mm,y_mm,z_mm`, whose t_s = 0 lies `offset_s` seconds after the record's
//!   first sample. The path is interpolated linearly at each record time. Record samples outside
//!   the path's span, or inside a gap of the path (two path points further apart in time than 5
//!   median path intervals: the path does not say where the machine was), are left out.
//!
//! Every file goes through [`crate::table`]; errors name `file:line:column`. What a diagnosis
//! cannot use is refused here, as bad input: a D that is not positive, a position at the table
//! ball, a path that does not move, or one that draws no arc of at least
//! [`MIN_ARC_DEG`] about the table ball.
use std::path::Path as FsPath;

use crate::diagnose::runs::{main_plane, split_runs, MAX_RUN_STEP_RAD};
use crate::model::{Axis, Path};
use crate::sync::{Record, Sync, MAX_DATA_SAMPLES};
use crate::table::Table;
use crate::{Error, Result};

/// Fewer samples than this cannot support a candidate search.
pub const MIN_SAMPLES: usize = 32;

/// A circular test needs at least one arc (one circle, one direction, no jump) of this many
/// degrees about the table ball: ISO 230-4's partial arcs are 180° or more.
pub const MIN_ARC_DEG: f64 = 180.0;

/// Positions closer than this to the table ball (mm) cannot be a ball bar's: the bar has a length.
const MIN_RADIUS_MM: f64 = 1.0;

/// Largest |D − nominal distance| (mm) of a sample: a ball bar measures machine errors of µm to
/// a few hundred µm; a D 5 mm off the nominal path is a wrong column, a glitch or another test,
/// and would swamp the diagnosis (one D of 1e6 mm gave G = 1e9 µm).
pub const MAX_DEVIATION_MM: f64 = 5.0;

/// The value of a `# key: value` comment line before a file's first data line (above or below
/// its header: `jdbb record` writes `# instrument_serial: …` right after the header, when the
/// device has described itself), if there is one: [`Table::header_comment`] once the first row
/// is read.
pub fn record_header_value(file: &FsPath, key: &str) -> Result<Option<String>> {
    let mut t = Table::open(file)?;
    t.next_row()?;
    Ok(t.header_comment(key)
        .filter(|v| !v.is_empty())
        .map(str::to_string))
}

/// Read `t_s,x_mm,y_mm,z_mm,d_mm`. Returns the path (with `pitch_mm` applied) and D.
pub fn read_samples(file: &FsPath, pitch_mm: [Option<f64>; 3]) -> Result<(Path, Vec<f64>)> {
    samples_from(Table::open(file)?, pitch_mm)
}

/// [`read_samples`] on text already in memory; `file` names it in errors.
pub fn parse_samples(
    file: &FsPath,
    text: &str,
    pitch_mm: [Option<f64>; 3],
) -> Result<(Path, Vec<f64>)> {
    samples_from(Table::from_text(file, text)?, pitch_mm)
}

fn samples_from(table: Table, pitch_mm: [Option<f64>; 3]) -> Result<(Path, Vec<f64>)> {
    samples_binned(table, pitch_mm, MAX_DATA_SAMPLES)
}

/// Samples held, the running means of consecutive raw samples ([`Bins::halve`]).
struct Bins {
    t: Vec<f64>,
    p: Vec<[f64; 3]>,
    d: Vec<f64>,
    /// Mean distance |p| of each bin's raw samples: the bin's position is put at this distance
    /// (a mean of points on an arc lies inside it), so D − |p| is the mean of the raw ones.
    r: Vec<f64>,
    /// Raw samples in each.
    n: Vec<u32>,
    /// Whether a bin begins at a reversal of an axis (or a jump): never merged with the one
    /// before, so no bin averages across a backlash step.
    fence: Vec<bool>,
    /// The last raw position and the step that led to it.
    last: Option<([f64; 3], [f64; 3])>,
    /// Raw samples per bin for new rows (a power of two).
    width: u32,
}

impl Bins {
    /// Add one raw sample: into the last bin if it is not full, else a new one.
    fn push(&mut self, t: f64, p: [f64; 3], d: f64) {
        let r = crate::plan::dist(&p, &[0.0; 3]);
        // A reversal: an axis that moved one way now moves the other.
        let reversal = self.last.is_some_and(|(q, step)| {
            (0..3).any(|j| {
                let now = p[j] - q[j];
                now * step[j] < 0.0
            })
        });
        self.last = Some(match self.last {
            Some((q, step)) => {
                let now: [f64; 3] = std::array::from_fn(|j| p[j] - q[j]);
                // A standing axis keeps the direction it had.
                (
                    p,
                    std::array::from_fn(|j| if now[j] != 0.0 { now[j] } else { step[j] }),
                )
            }
            None => (p, [0.0; 3]),
        });
        if let Some(k) = self.n.len().checked_sub(1) {
            if !reversal && self.n[k] < self.width && self.joins(k, &p) {
                let (a, b) = (f64::from(self.n[k]), 1.0);
                let m = |x: f64, y: f64| (a * x + b * y) / (a + b);
                self.t[k] = m(self.t[k], t);
                self.p[k] = std::array::from_fn(|j| m(self.p[k][j], p[j]));
                self.d[k] = m(self.d[k], d);
                self.r[k] = m(self.r[k], r);
                self.n[k] += 1;
                return;
            }
        }
        let fence = reversal
            || self
                .n
                .last()
                .is_some_and(|_| !self.joins(self.n.len() - 1, &p));
        self.t.push(t);
        self.p.push(p);
        self.d.push(d);
        self.r.push(r);
        self.n.push(1);
        self.fence.push(fence);
    }

    /// The bins' times, positions (at their mean distance) and D.
    fn finish(self) -> (Vec<f64>, Vec<[f64; 3]>, Vec<f64>) {
        let p = self
            .p
            .iter()
            .zip(&self.r)
            .map(|(p, &r)| {
                let len = crate::plan::dist(p, &[0.0; 3]);
                if len > 0.0 {
                    std::array::from_fn(|j| p[j] * r / len)
                } else {
                    *p
                }
            })
            .collect();
        (self.t, p, self.d)
    }

    /// Whether `p` continues bin `k` (no jump: a step at most twice the one before it).
    fn joins(&self, k: usize, p: &[f64; 3]) -> bool {
        if k == 0 {
            return true;
        }
        let step = |a: &[f64; 3], b: &[f64; 3]| crate::plan::dist(a, b);
        let before = step(&self.p[k - 1], &self.p[k]) / f64::from(self.n[k - 1].max(1));
        step(&self.p[k], p) <= 2.0 * before * f64::from(self.width) + 1e-9
    }

    /// Merge neighbouring bins pairwise, doubling the width: not across a reversal or a jump,
    /// unless that would leave more than three quarters of them (noisy positions reverse at
    /// every sample): then all pairs, so memory stays bounded whatever the file.
    fn halve(&mut self) {
        let before = self.n.len();
        self.halve_pairs(false);
        if self.n.len() > before / 4 * 3 {
            self.halve_pairs(true);
        }
    }

    fn halve_pairs(&mut self, all: bool) {
        let len = self.n.len();
        let (mut t, mut p, mut d, mut r, mut n, mut fence) = (
            Vec::with_capacity(len / 2 + 1),
            Vec::with_capacity(len / 2 + 1),
            Vec::with_capacity(len / 2 + 1),
            Vec::with_capacity(len / 2 + 1),
            Vec::with_capacity(len / 2 + 1),
            Vec::with_capacity(len / 2 + 1),
        );
        let mut k = 0;
        while k < len {
            let pair = k + 1 < len && (all || !self.fence[k + 1]) && {
                let step = crate::plan::dist(&self.p[k], &self.p[k + 1]);
                let near = |i: usize, j: usize| crate::plan::dist(&self.p[i], &self.p[j]);
                let before = if k > 0 { near(k - 1, k) } else { step };
                let after = if k + 2 < len {
                    near(k + 1, k + 2)
                } else {
                    step
                };
                all || step <= 2.0 * before.max(after) + 1e-9
            };
            if pair {
                let (a, b) = (f64::from(self.n[k]), f64::from(self.n[k + 1]));
                let m = |x: f64, y: f64| (a * x + b * y) / (a + b);
                t.push(m(self.t[k], self.t[k + 1]));
                p.push(std::array::from_fn(|j| m(self.p[k][j], self.p[k + 1][j])));
                d.push(m(self.d[k], self.d[k + 1]));
                r.push(m(self.r[k], self.r[k + 1]));
                n.push(self.n[k] + self.n[k + 1]);
                fence.push(self.fence[k]);
                k += 2;
            } else {
                t.push(self.t[k]);
                p.push(self.p[k]);
                d.push(self.d[k]);
                r.push(self.r[k]);
                n.push(self.n[k]);
                fence.push(self.fence[k]);
                k += 1;
            }
        }
        (self.t, self.p, self.d, self.r, self.n, self.fence) = (t, p, d, r, n, fence);
        self.width *= 2;
    }
}

/// [`samples_from`] holding at most about `max` samples: beyond, consecutive samples are
/// averaged in bins (never across a jump in position), as `diagnose --record --plan` bins the
/// data arcs ([`MAX_DATA_SAMPLES`]), so a file of any length is diagnosed in bounded memory.
fn samples_binned(
    mut table: Table,
    pitch_mm: [Option<f64>; 3],
    max: usize,
) -> Result<(Path, Vec<f64>)> {
    const NAMES: [&str; 5] = ["t_s", "x_mm", "y_mm", "z_mm", "d_mm"];
    let cols = table.require(&NAMES)?;
    let mut bins = Bins {
        t: Vec::new(),
        p: Vec::new(),
        d: Vec::new(),
        r: Vec::new(),
        n: Vec::new(),
        fence: Vec::new(),
        last: None,
        width: 1,
    };
    let mut prev_t: Option<f64> = None;
    let mut raw = 0usize;
    let mut last_line = table.header_line();
    while let Some(row) = table.next_row()? {
        last_line = row.line();
        let mut v = [0.0f64; 5];
        for (k, c) in cols.iter().enumerate() {
            v[k] = row.number(c)?;
        }
        if let Some(prev) = prev_t {
            if v[0] <= prev {
                return Err(row.error(
                    &cols[0],
                    format!(
                        "time goes backwards or stands still ({} s after {prev} s); samples must be in time order",
                        v[0]
                    ),
                ));
            }
        }
        if v[4] <= 0.0 {
            return Err(row.error(
                &cols[4],
                format!("d_mm is {}; a ball distance is positive", v[4]),
            ));
        }
        let nominal_mm = (v[1] * v[1] + v[2] * v[2] + v[3] * v[3]).sqrt();
        if nominal_mm < MIN_RADIUS_MM {
            return Err(row.error(
                &cols[1],
                format!(
                    "the position ({}, {}, {}) mm is at the table ball; positions are the spindle ball's, relative to the table ball",
                    v[1], v[2], v[3]
                ),
            ));
        }
        if (v[4] - nominal_mm).abs() > MAX_DEVIATION_MM {
            return Err(row.error(
                &cols[4],
                format!(
                    "d_mm is {} but the nominal distance is {nominal_mm:.3} mm; more than {MAX_DEVIATION_MM} mm apart is not a machine's error (a wrong column, a glitch, another test)",
                    v[4]
                ),
            ));
        }
        prev_t = Some(v[0]);
        raw += 1;
        bins.push(v[0], [v[1], v[2], v[3]], v[4]);
        if bins.n.len() >= 2 * max.max(MIN_SAMPLES) {
            bins.halve();
        }
    }
    if bins.n.len() > max.max(MIN_SAMPLES) {
        bins.halve();
    }
    let (t, p, d) = bins.finish();
    let file = table.path().to_path_buf();
    if raw < MIN_SAMPLES {
        return Err(Error::input(
            &file,
            last_line,
            0,
            format!(
                "only {raw} samples; a diagnosis needs at least {MIN_SAMPLES} (a full circle each way)"
            ),
        ));
    }
    let path = Path::new(t, p, pitch_mm);
    for a in Axis::ALL {
        if pitch_mm[a.index()].is_some() && !path.moves(a) {
            return Err(table.header_error(
                Some(&cols[1 + a.index()]),
                format!(
                    "a pitch was given for axis {} but `{}` never changes; drop it from --pitch",
                    a.letter(),
                    NAMES[1 + a.index()]
                ),
            ));
        }
    }
    // What the whole file shows is reported at its end, as the count of samples is.
    check_circular(&path).map_err(|m| Error::input(&file, last_line, 0, m))?;
    Ok((path, d))
}

/// Longest interval between two record samples on a data arc, in median sample intervals: a
/// longer one is a hole (samples lost: a cable pulled, a full queue), and the arc would be
/// diagnosed as if whole.
pub const MAX_HOLE_INTERVALS: f64 = 20.0;

/// Shortest interval (s) called a hole whatever the sample rate: 50 ms.
pub const MIN_HOLE_S: f64 = 0.05;

/// Refuse a record with a hole inside one of the plan's data arcs as synchronised (`sync`): a
/// gap between samples (or between an arc's start or end and its nearest sample) longer than
/// [`MAX_HOLE_INTERVALS`] median intervals and [`MIN_HOLE_S`]. The error names the line after
/// the hole and its length.
pub fn check_holes(rec: &Record, sync: &Sync) -> Result<()> {
    let t = &rec.t_s;
    // The median of up to 10 000 intervals: the sample interval.
    let mut dts: Vec<f64> = t.windows(2).take(10_000).map(|w| w[1] - w[0]).collect();
    if dts.is_empty() {
        return Ok(());
    }
    dts.sort_by(f64::total_cmp);
    let limit = (MAX_HOLE_INTERVALS * dts[dts.len() / 2]).max(MIN_HOLE_S);
    for (k, c) in sync.circles.iter().enumerate() {
        for a in &c.data {
            let i0 = t.partition_point(|&x| x < a.t_start_s);
            let i1 = t.partition_point(|&x| x <= a.t_end_s);
            let mut prev = (a.t_start_s, i0);
            let ends = (i0..i1)
                .map(|i| (t[i], i))
                .chain(std::iter::once((a.t_end_s, i1)));
            for (x, i) in ends {
                let gap = x - prev.0;
                if gap > limit {
                    let line = rec.line_of(i.min(t.len().saturating_sub(1)));
                    return Err(Error::input(
                        &rec.path,
                        line,
                        0,
                        format!(
                            "the record has a hole of {gap:.3} s ({:.3}..{:.3} s after its first sample) inside circle {}'s {} data arc ({:.3}..{:.3} s): samples were lost there, and the arc cannot be diagnosed as if whole; record the test again (a hole is more than {MAX_HOLE_INTERVALS} sample intervals and {MIN_HOLE_S} s)",
                            prev.0,
                            x,
                            k + 1,
                            match a.sense {
                                crate::plan::Sense::Ccw => "ccw",
                                crate::plan::Sense::Cw => "cw",
                            },
                            a.t_start_s,
                            a.t_end_s
                        ),
                    ));
                }
                prev = (x, i);
            }
        }
    }
    Ok(())
}

/// Whether `path` is a circular test the diagnosis can work on: it moves, and draws at least one
/// arc of [`MIN_ARC_DEG`] about the table ball. The message says what is wrong.
pub fn check_circular(path: &Path) -> std::result::Result<(), String> {
    let moving = Axis::ALL.iter().filter(|&&a| path.moves(a)).count();
    if moving < 2 {
        return Err(format!(
            "the path moves {} axis; a circular test moves two axes around the table ball",
            if moving == 0 { "no" } else { "only one" }
        ));
    }
    let plane = main_plane(path);
    let (_, runs) = split_runs(&path.t_s, &path.p_mm, plane, MAX_RUN_STEP_RAD);
    let sweep_deg = runs
        .iter()
        .map(|r| {
            let a = crate::diagnose::runs::angles(&path.p_mm[r.range.clone()], plane);
            a.windows(2)
                .map(|w| crate::diagnose::runs::wrap_pi(w[1] - w[0]).abs())
                .sum::<f64>()
                .to_degrees()
        })
        .fold(0.0, f64::max);
    if sweep_deg < MIN_ARC_DEG {
        return Err(format!(
            "the longest arc about the table ball spans {sweep_deg:.1}°; a circular test needs arcs of at least {MIN_ARC_DEG}° (is this a circle centred on the table ball?)"
        ));
    }
    Ok(())
}

/// A `jdbb record` file (`seq,t_us,enc1,enc2,d_mm`) with its nominal path (`t_s,x_mm,y_mm,z_mm`,
/// t_s = 0 at `offset_s` after the record's first sample). See the module docs. The record is read
/// by [`Record::read`], which sets glitch samples aside; they are returned with their line (their
/// `t_s` from the record's first sample).
pub fn read_record_with_path(
    record: &FsPath,
    nominal: &FsPath,
    offset_s: f64,
    pitch_mm: [Option<f64>; 3],
) -> Result<(Path, Vec<f64>, Vec<crate::sync::glitch::Glitch>)> {
    // The path: t_s strictly increasing.
    let mut nt = Table::open_with(nominal, crate::fsio::Limit::Table)?;
    let ncols = nt.require(&["t_s", "x_mm", "y_mm", "z_mm"])?;
    let mut nom: Vec<[f64; 4]> = vec![];
    let mut nom_last = nt.header_line();
    while let Some(row) = nt.next_row()? {
        let mut v = [0.0; 4];
        for (k, c) in ncols.iter().enumerate() {
            v[k] = row.number(c)?;
        }
        if nom.last().is_some_and(|p| v[0] <= p[0]) {
            return Err(row.error(
                &ncols[0],
                format!(
                    "time goes backwards or stands still ({} after {})",
                    v[0],
                    nom.last().map_or(0.0, |p| p[0])
                ),
            ));
        }
        nom_last = row.line();
        nom.push(v);
    }
    if nom.len() < 2 {
        return Err(Error::input(
            nominal,
            nom_last,
            0,
            "the path needs at least 2 points",
        ));
    }
    let mut gaps: Vec<f64> = nom.windows(2).map(|w| w[1][0] - w[0][0]).collect();
    gaps.sort_by(f64::total_cmp);
    let max_gap_s = 5.0 * gaps[gaps.len() / 2];

    // The record as every command reads it: time increasing, D positive, glitches set aside.
    let rec = Record::read(record)?;
    let mut t = vec![];
    let mut p = vec![];
    let mut d = vec![];
    let mut j = 0;
    let (first_s, last_s) = (nom[0][0], nom[nom.len() - 1][0]);
    for (&t_rec, &d_mm) in rec.t_s.iter().zip(&rec.d_mm) {
        let ts = t_rec - offset_s;
        if ts < first_s || ts > last_s {
            continue;
        }
        while j + 2 < nom.len() && nom[j + 1][0] < ts {
            j += 1;
        }
        let (a, b) = (&nom[j], &nom[j + 1]);
        if b[0] - a[0] > max_gap_s {
            continue;
        }
        let f = ((ts - a[0]) / (b[0] - a[0])).clamp(0.0, 1.0);
        p.push([
            a[1] + f * (b[1] - a[1]),
            a[2] + f * (b[2] - a[2]),
            a[3] + f * (b[3] - a[3]),
        ]);
        t.push(ts);
        d.push(d_mm);
    }
    let rec_last = rec.line_of(rec.t_s.len().saturating_sub(1));
    if t.len() < MIN_SAMPLES {
        return Err(Error::input(
            record,
            rec_last,
            0,
            format!(
                "only {} record samples fall inside the path's time span; check --path-offset-s (need {MIN_SAMPLES})",
                t.len()
            ),
        ));
    }
    let path = Path::new(t, p, pitch_mm);
    for a in Axis::ALL {
        if pitch_mm[a.index()].is_some() && !path.moves(a) {
            return Err(nt.header_error(
                Some(&ncols[1 + a.index()]),
                format!("a pitch was given for axis {} but the path never moves it; drop it from --pitch", a.letter()),
            ));
        }
    }
    check_circular(&path).map_err(|m| Error::Input {
        location: nominal.display().to_string(),
        message: m,
    })?;
    Ok((path, d, rec.glitches))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 180-sample ccw circle of radius 50 mm (2° steps), columns in another order.
    fn circle_text() -> String {
        let mut text = String::from("d_mm,t_s,x_mm,y_mm,z_mm\n");
        for i in 0..180 {
            let a = (i as f64 * 2.0).to_radians();
            text.push_str(&format!("50,{i},{},{},0\n", 50.0 * a.cos(), 50.0 * a.sin()));
        }
        text
    }

    #[test]
    fn long_sample_files_are_binned_in_bounded_memory_never_across_a_jump() {
        // Two circles (R 50 then R 60, a jump between them), ccw then cw, 4 000 samples each
        // way, D = R + 2 µm·cos 3θ.
        let mut text = String::from("t_s,x_mm,y_mm,z_mm,d_mm\n");
        let mut i = 0;
        for r in [50.0, 60.0] {
            for k in (0..4000).chain((0..4000).rev()) {
                let a = (k as f64 * 0.09).to_radians();
                let d = r + 0.002 * (3.0 * a).cos();
                text += &format!(
                    "{},{},{},0,{d}\n",
                    i as f64 * 1e-3,
                    r * a.cos(),
                    r * a.sin()
                );
                i += 1;
            }
        }
        // Bins of 16 samples (1.44°), far below a run's largest step.
        let table = Table::from_text(FsPath::new("s.csv"), &text).unwrap();
        let (path, d) = samples_binned(table, [None; 3], 1000).unwrap();
        assert!(
            d.len() <= 1000 && d.len() >= 500,
            "{} samples held",
            d.len()
        );
        for (p, d) in path.p_mm.iter().zip(&d) {
            let r = (p[0] * p[0] + p[1] * p[1]).sqrt();
            // A bin's mean lies on its circle (to the chord of a few samples) and D follows it.
            assert!(
                (r - 50.0).abs() < 1e-3 || (r - 60.0).abs() < 1e-3,
                "a bin across the jump: r = {r}"
            );
            let a = p[1].atan2(p[0]);
            let want = r.round() + 0.002 * (3.0 * a).cos();
            assert!((d - want).abs() < 2e-4, "D {d} vs {want}");
        }
        // Positions with noise reverse at every sample: memory stays bounded all the same.
        let noisy: String = text
            .lines()
            .enumerate()
            .map(|(i, l)| {
                if i == 0 {
                    return format!("{l}\n");
                }
                let mut f: Vec<String> = l.split(',').map(str::to_string).collect();
                let x: f64 = f[1].parse().unwrap();
                f[1] = format!("{}", x + if i % 2 == 0 { 1e-4 } else { -1e-4 });
                format!("{}\n", f.join(","))
            })
            .collect();
        let table = Table::from_text(FsPath::new("s.csv"), &noisy).unwrap();
        let (_, d) = samples_binned(table, [None; 3], 1000).unwrap();
        assert!(d.len() <= 1000, "{} samples held", d.len());
        // Below the bound nothing is binned.
        let table = Table::from_text(FsPath::new("s.csv"), &text).unwrap();
        let (_, all) = samples_binned(table, [None; 3], 20_000).unwrap();
        assert_eq!(all.len(), 16_000);
    }

    #[test]
    fn csv_errors_name_line_and_column() {
        let f = FsPath::new("s.csv");
        let e = parse_samples(f, "t_s,x_mm,y_mm,z_mm\n0,1,2,3\n", [None; 3]).unwrap_err();
        assert!(
            e.to_string().starts_with("s.csv:1: missing column `d_mm`"),
            "{e}"
        );
        let e = parse_samples(
            f,
            "t_s,x_mm,y_mm,z_mm,d_mm\n0,1,2,3,4\n1,1,NaN,3,4\n",
            [None; 3],
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("s.csv:3:5: y_mm is NaN"), "{e}");
        let e = parse_samples(
            f,
            "t_s,x_mm,y_mm,z_mm,d_mm\n0,1,2,3,4\n0,1,2,3,4\n",
            [None; 3],
        )
        .unwrap_err();
        assert!(
            e.to_string().starts_with("s.csv:3:1: time goes backwards"),
            "{e}"
        );
        let e = parse_samples(f, "t_s,x_mm,y_mm,z_mm,d_mm\n0,1,2,3,4\n", [None; 3]).unwrap_err();
        assert!(e.to_string().contains("only 1 samples"), "{e}");
        let text = circle_text();
        let (p, d) = parse_samples(f, &text, [None; 3]).unwrap();
        assert_eq!(d.len(), 180);
        assert!(p.moves(Axis::X) && !p.moves(Axis::Z));
        let e = parse_samples(f, &text, [None, None, Some(5.0)]).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("s.csv:1:20: a pitch was given for axis z"),
            "{e}"
        );
    }

    #[test]
    fn what_a_diagnosis_cannot_use_is_refused() {
        let f = FsPath::new("s.csv");
        let text = circle_text();
        // Negative D.
        let bad = text.replacen("\n50,3,", "\n-50,3,", 1);
        let e = parse_samples(f, &bad, [None; 3]).unwrap_err();
        assert!(e.to_string().starts_with("s.csv:5:1: d_mm is -50"), "{e}");
        // All zero positions.
        let mut zeros = String::from("t_s,x_mm,y_mm,z_mm,d_mm\n");
        for i in 0..40 {
            zeros.push_str(&format!("{i},0,0,0,50\n"));
        }
        let e = parse_samples(f, &zeros, [None; 3]).unwrap_err();
        assert!(e.to_string().contains("is at the table ball"), "{e}");
        // Stationary.
        let still: String = std::iter::once("t_s,x_mm,y_mm,z_mm,d_mm\n".to_string())
            .chain((0..40).map(|i| format!("{i},50,0,0,50\n")))
            .collect();
        let e = parse_samples(f, &still, [None; 3]).unwrap_err();
        assert!(e.to_string().contains("moves no axis"), "{e}");
        // A straight line past the table ball.
        let line: String = std::iter::once("t_s,x_mm,y_mm,z_mm,d_mm\n".to_string())
            .chain((0..40).map(|i| {
                let (x, y) = (i as f64 - 20.0, 30.0 + 0.5 * i as f64);
                format!("{i},{x},{y},0,{}\n", x.hypot(y))
            }))
            .collect();
        let e = parse_samples(f, &line, [None; 3]).unwrap_err();
        assert!(e.to_string().contains("needs arcs of at least 180°"), "{e}");
        assert_eq!(e.exit_code(), 2);
    }

    /// A path file's text: a ccw circle of 50 mm over 0..10 s, 101 points.
    fn ccw_circle_path() -> String {
        let mut path = String::from("t_s,x_mm,y_mm,z_mm\n");
        for k in 0..=100 {
            let a = (k as f64 * 3.6).to_radians();
            path.push_str(&format!(
                "{},{},{},0\n",
                0.1 * k as f64,
                50.0 * a.cos(),
                50.0 * a.sin()
            ));
        }
        path
    }

    #[test]
    fn a_glitch_in_a_record_with_a_path_is_set_aside_with_its_line() {
        // A ccw circle of 50 mm over 10 s, the record at 100 Hz with D 50 mm and one sample at
        // 30 mm (a loose cable): it is set aside, named by its line, and the rest is kept.
        let dir = tempfile::tempdir().unwrap();
        let path_file = dir.path().join("path.csv");
        let rec_file = dir.path().join("rec.csv");
        let path = ccw_circle_path();
        std::fs::write(&path_file, &path).unwrap();
        let mut rec = String::from("seq,t_us,enc1,enc2,d_mm\n");
        for i in 0..=1000 {
            let d = if i == 500 { 30.0 } else { 50.0 };
            rec.push_str(&format!("{i},{},0,0,{d}\n", i * 10_000));
        }
        std::fs::write(&rec_file, rec).unwrap();
        let (p, d, glitches) =
            read_record_with_path(&rec_file, &path_file, 0.0, [None; 3]).unwrap();
        assert_eq!(glitches.len(), 1, "{glitches:?}");
        assert_eq!((glitches[0].line, glitches[0].d_mm), (502, 30.0));
        assert_eq!((d.len(), p.len()), (1000, 1000));
        assert!(d.iter().all(|&v| v == 50.0));
    }

    #[test]
    fn record_samples_in_a_gap_of_the_path_are_left_out() {
        // Path: a ccw circle 0..10 s, nothing between 10 and 20 s, a cw circle 20..30 s. Record
        // samples every 0.01 s from 0 to 30 s.
        let dir = tempfile::tempdir().unwrap();
        let path_file = dir.path().join("path.csv");
        let rec_file = dir.path().join("rec.csv");
        let mut path = ccw_circle_path();
        for k in 0..=100 {
            let a = (-(k as f64) * 3.6).to_radians();
            let t = 20.0 + 0.1 * k as f64;
            path.push_str(&format!("{t},{},{},0\n", 50.0 * a.cos(), 50.0 * a.sin()));
        }
        std::fs::write(&path_file, path).unwrap();
        let mut rec = String::from("seq,t_us,enc1,enc2,d_mm\n");
        for i in 0..=3000 {
            rec.push_str(&format!("{i},{},0,0,50\n", i * 10_000));
        }
        std::fs::write(&rec_file, rec).unwrap();
        let (p, d, _) = read_record_with_path(&rec_file, &path_file, 0.0, [None; 3]).unwrap();
        assert_eq!(d.len(), p.len());
        assert!(
            p.t_s.iter().all(|&t| t <= 10.0 + 1e-6 || t >= 20.0 - 1e-6),
            "a sample inside the gap was kept"
        );
        assert!((1999..=2002).contains(&p.len()), "{} samples", p.len());
    }
}
