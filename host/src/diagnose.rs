//! `jdbb diagnose`: what the ideal-machine simulation gets wrong in a circular test, which machine
//! errors explain it, how large they are and how sure we are.
//!
//! Pipeline (see [`diagnose`]):
//! 1. Baseline: the ideal machine predicts D = |p_nominal|; report RMS and peak-to-valley (µm).
//! 2. Set-up: fit the table-ball offset c and the length offset e with the exact geometry
//!    D = |p + c| + e. Set-up parameters the path cannot determine (c_z on a flat circle) are
//!    held at zero and reported as confounded.
//! 3. Candidate search: every candidate effect of [`crate::model`] becomes columns of a linear
//!    model, linearised at the nominal path (seed 000 eq. 1: ΔR = u·δ, u = p/|p|), against the
//!    residual of step 2. One pass over the samples accumulates the Gram matrix of all columns; the
//!    forward selection then works on that small matrix only, which is why the whole search costs
//!    one pass (O(m·n²)) plus O(n³) per trial.
//! 4. Selection by BIC = m·ln(SSR/m) + k·ln(m): an effect is added while it lowers BIC. For one
//!    added parameter this is a likelihood-ratio test at χ²₁ > ln m, i.e. a false-alarm rate of
//!    P(χ²₁ > ln m) per candidate (0.16 % at m = 20 000; 2 parameters: P(χ²₂ > 2 ln m) = 5e-5).
//! 5. Identifiability: columns that are linear combinations of others (rank test on the
//!    column-scaled Gram matrix, singular values below 1e-7 of the largest) are never fitted
//!    against each other. If the isotropic scale is confounded with the length offset (one radius),
//!    the scale candidates become `scale_mismatch_ij` = scale_i − scale_j and the confounded group
//!    is named; a candidate that lies in the span of the current model is skipped and named with
//!    what it is confounded with.
//! 6. The selected effects are refitted with the exact geometry ([`crate::model::ExactModel`]),
//!    giving the reported values ± standard errors, then the residual's harmonics against angle.
//!
//! # Input
//! - `--samples FILE`: CSV with header `t_s,x_mm,y_mm,z_mm,d_mm` (any column order, extra
//!   columns ignored): time, the nominal (commanded) spindle-ball centre relative to the table ball
//!   in machine axes, and the measured ball distance D. `jdbb simulate` writes this.
//! - `--record FILE --path FILE [--path-offset-s S]`: a `jdbb record` file
//!   (`seq,t_us,enc1,enc2,d_mm`) and the nominal path as CSV `t_s,x_mm,y_mm,z_mm`, whose t_s = 0
//!   lies S seconds after the record's first sample. The path is interpolated linearly at each
//!   record time; record samples outside the path's span are left out.
//!
//! # JSON (`--json`, and `diagnosis.json` in `--report DIR`)
//! ```text
//! samples                  number of samples used
//! baseline.rms_um          RMS of D − |p| (ideal machine), µm
//! baseline.pv_um           peak-to-valley of D − |p|, µm
//! effects[]                set-up first (setup_offset, length_offset), then machine effects in
//!                          the order the selection added them
//!   .name                  effect name (setup_offset, length_offset, scale_k, scale2_k,
//!                          backlash_k, cyclic_k, interference_k, squareness_ij,
//!                          servo_mismatch_ij, or the identifiable scale_mismatch_ij)
//!   .value                 |c| for setup_offset, amplitude for cyclic/interference, else the
//!                          single parameter; from the exact-geometry refit
//!   .unit                  um, um/m, um/m^2, um/(mm/s) or ms
//!   .sigma                 standard error of value (delta method), null if undetermined
//!   .params                {parameter: value}: setup_offset {x_um,y_um,z_um}, length_offset
//!                          {e_um}, scale/scale_mismatch {a_um_per_m}, scale2 {b_um_per_m2},
//!                          backlash {f_um}, cyclic {sin_um,cos_um} (A·sin(w+φ) = sin_um·sin w +
//!                          cos_um·cos w, w = 2πk/pitch), interference {sin_um_per_mm_s,
//!                          cos_um_per_mm_s}, squareness {s_um_per_m}, servo_mismatch {dtau_ms}
//!   .params_sigma          {parameter: standard error or null (undetermined, held at 0)}
//!   .rms_after_um          RMS of the residual after the step that added this effect (linear
//!                          search); for the set-up, after the set-up fit
//!   .rms_ratio             RMS before / after that step
//!   .delta_bic             BIC change of that step (null for the set-up)
//!   .setup                 true for setup_offset and length_offset
//!   .cause                 the physical cause in words
//! confounded[][]           groups of names the test cannot tell apart (effects, or set-up
//!                          components setup_offset.x/.y/.z); a group of one is a parameter the
//!                          path does not excite at all
//! final.rms_um             RMS of the residual of the exact refit, µm
//! gain                     baseline.rms_um / final.rms_um
//! harmonics_um[]           amplitude of residual harmonics 1..8 against the angle in the plane
//!                          of the two axes with the largest travel, µm
//! lsq_setup                {x_um, y_um, z_um, e_um}: least-squares centre and length offset of
//!                          all samples (D ≈ |p + c| + e), the set-up removed before G, H and
//!                          the polar plot
//! circular_deviation_g_um  ISO 230-4 style G of D − (|p + c| + e) with lsq_setup: largest
//!                          peak-to-valley of one circle in one direction, µm
//! hysteresis_h_um          ISO 230-4 style H: largest ccw − cw difference of one circle in a
//!                          1° bin, µm
//! candidates[]             the candidate effects that were tried
//! ```
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
#[path = "diagnose/rotary.rs"]
pub mod rotary;

use std::path::{Path as FsPath, PathBuf};

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use crate::error::parse_number;
use crate::fit::{least_squares, GramAccumulator, LsqOptions};
use crate::model::{Axis, Effect, EffectSet, ExactModel, Pair, Path};
use crate::{Error, Result};

/// Singular values of the column-scaled design below this fraction of the largest count as zero
/// (the same rule as [`crate::fit`]).
pub const RANK_TOLERANCE: f64 = 1e-7;

/// Knobs of the diagnosis.
#[derive(Debug, Clone)]
pub struct Options {
    /// At most this many machine effects are selected.
    pub max_effects: usize,
    /// BIC penalty multiplier: an effect with k parameters must lower m·ln(SSR/m) by more than
    /// `penalty · k · ln m`. 1.0 is plain BIC.
    pub penalty: f64,
    /// Number of angle harmonics reported for the residual.
    pub harmonics: usize,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_effects: 8,
            penalty: 1.0,
            harmonics: 8,
        }
    }
}

/// One reported effect: its fitted parameters (exact geometry) and the selection step that added it.
#[derive(Debug, Clone)]
pub struct Found {
    pub effect: Effect,
    pub params: Vec<f64>,
    pub param_sigma: Vec<Option<f64>>,
    pub value: f64,
    pub sigma: Option<f64>,
    /// RMS (µm) of the residual after this step of the selection.
    pub rms_after_um: f64,
    /// RMS before / RMS after this step.
    pub rms_ratio: f64,
    /// Change of BIC by this step (negative = better).
    pub delta_bic: f64,
}

/// The result of [`diagnose`].
#[derive(Debug, Clone)]
pub struct Diagnosis {
    pub samples: usize,
    pub baseline_rms_um: f64,
    pub baseline_pv_um: f64,
    /// Set-up (setup_offset, length_offset) then machine effects, in the order selected.
    pub effects: Vec<Found>,
    /// Groups of names (effects, or effect components like `setup_offset.z`) the test cannot
    /// tell apart.
    pub confounded: Vec<Vec<String>>,
    pub final_rms_um: f64,
    /// baseline RMS / final RMS.
    pub gain: f64,
    /// Amplitude (µm) of residual harmonics 1..=n against the angle in the main plane.
    pub harmonics_um: Vec<f64>,
    /// Candidates that were tried (names).
    pub candidates: Vec<String>,
    /// Per sample: angle (rad) in the main plane; measured deviation with the least-squares
    /// set-up removed, D − (|p + c| + e) with c, e from [`Diagnosis::lsq_setup_um`] (µm); and the
    /// extended model's deviation after the same removal, i.e. its machine effects (µm).
    pub angle_rad: Vec<f64>,
    pub measured_dev_um: Vec<f64>,
    pub model_dev_um: Vec<f64>,
    /// The set-up removed from the plotted deviations: the least-squares centre and length of all
    /// samples, D ≈ |p + c| + e, as [c_x, c_y, c_z, e] in µm (a component the path cannot
    /// determine is held at 0).
    pub lsq_setup_um: [f64; 4],
    /// Main plane (axis indices) of the angle.
    pub plane: (usize, usize),
    /// The distinct circles (nominal radius and height) of the path.
    pub circles: Vec<Circle>,
    /// The samples cut into runs of one circle in one direction without gaps (see [`split_runs`]).
    pub runs: Vec<Run>,
    /// ISO 230-4 style circular deviation G and hysteresis H (µm) of the plotted measured
    /// deviation, see [`circularity`].
    pub circular_deviation_g_um: f64,
    pub hysteresis_h_um: f64,
}

/// One circle of the path: nominal radius in the main plane and height along its normal (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circle {
    pub radius_mm: f64,
    pub height_mm: f64,
}

/// Consecutive samples of one circle in one direction, with no jump in angle, time, radius or
/// height between neighbours: a polyline through them never draws a chord across a polar plot.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub range: std::ops::Range<usize>,
    /// Index into [`Diagnosis::circles`].
    pub circle: usize,
    /// Counter-clockwise (angle increasing) in the main plane.
    pub ccw: bool,
}

/// Largest angle step (rad) between neighbouring samples of one [`Run`].
pub const MAX_RUN_STEP_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// Cut the samples into [`Run`]s. A new run starts where neighbours differ in angle (in the plane
/// `plane`) by more than `max_step_rad`, in time by more than 5 median sampling intervals, in
/// radius or height by more than 0.01 mm + 1e-4 of the radius, or where the direction of rotation
/// changes (a standstill keeps the direction). Circles are the distinct (radius, height) pairs of
/// the runs' first samples, within 0.5 mm.
pub fn split_runs(
    t_s: &[f64],
    p_mm: &[[f64; 3]],
    plane: (usize, usize),
    max_step_rad: f64,
) -> (Vec<Circle>, Vec<Run>) {
    split_runs_at(t_s, p_mm, &angles(p_mm, plane), plane, max_step_rad)
}

/// The angle (rad) of every position in the plane `plane`: atan2(p[plane.1], p[plane.0]).
fn angles(p_mm: &[[f64; 3]], plane: (usize, usize)) -> Vec<f64> {
    p_mm.iter().map(|p| p[plane.1].atan2(p[plane.0])).collect()
}

/// [`split_runs`] with the angles of [`angles`] already computed (the diagnosis needs them for
/// the plot too); each sample's radius is computed once.
fn split_runs_at(
    t_s: &[f64],
    p_mm: &[[f64; 3]],
    angle_rad: &[f64],
    plane: (usize, usize),
    max_step_rad: f64,
) -> (Vec<Circle>, Vec<Run>) {
    let n = p_mm.len().min(t_s.len()).min(angle_rad.len());
    let normal = 3 - plane.0 - plane.1;
    // (angle, radius, height) of sample i.
    let polar = |i: usize| {
        let p = &p_mm[i];
        (angle_rad[i], p[plane.0].hypot(p[plane.1]), p[normal])
    };
    let mut dts: Vec<f64> = t_s[..n].windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_by(f64::total_cmp);
    let max_dt = dts.get(dts.len() / 2).map_or(f64::INFINITY, |m| 5.0 * m);
    let mut circles: Vec<Circle> = vec![];
    let mut runs: Vec<Run> = vec![];
    let mut start = 0;
    // Direction of the current run: None until it has moved.
    let mut dir: Option<bool> = None;
    let mut close = |start: usize, end: usize, dir: Option<bool>, runs: &mut Vec<Run>| {
        if end <= start {
            return;
        }
        let (_, r, h) = polar(start);
        let circle = match circles
            .iter()
            .position(|c| (c.radius_mm - r).abs() < 0.5 && (c.height_mm - h).abs() < 0.5)
        {
            Some(k) => k,
            None => {
                circles.push(Circle {
                    radius_mm: r,
                    height_mm: h,
                });
                circles.len() - 1
            }
        };
        runs.push(Run {
            range: start..end,
            circle,
            ccw: dir.unwrap_or(true),
        });
    };
    let mut prev = if n > 0 { polar(0) } else { (0.0, 0.0, 0.0) };
    for i in 1..n {
        let (a0, r0, h0) = prev;
        let (a1, r1, h1) = polar(i);
        prev = (a1, r1, h1);
        let da = wrap_pi(a1 - a0);
        let tol = 0.01 + 1e-4 * r0.max(r1);
        let step_dir = if da.abs() > 1e-12 {
            Some(da > 0.0)
        } else {
            None
        };
        let jump = da.abs() > max_step_rad
            || t_s[i] - t_s[i - 1] > max_dt
            || (r1 - r0).abs() > tol
            || (h1 - h0).abs() > tol;
        let turn = matches!((dir, step_dir), (Some(a), Some(b)) if a != b);
        if jump || turn {
            close(start, i, dir, &mut runs);
            start = i;
            dir = None;
        } else if dir.is_none() {
            dir = step_dir;
        }
    }
    close(start, n, dir, &mut runs);
    (circles, runs)
}

/// `a` wrapped into [−π, π].
fn wrap_pi(a: f64) -> f64 {
    let w = a.rem_euclid(std::f64::consts::TAU);
    if w > std::f64::consts::PI {
        w - std::f64::consts::TAU
    } else {
        w
    }
}

/// Read `t_s,x_mm,y_mm,z_mm,d_mm` (columns by name, any order, extra columns ignored).
/// Returns the path (with `pitch_mm` applied) and D. Errors name file, line and column.
pub fn read_samples(file: &FsPath, pitch_mm: [Option<f64>; 3]) -> Result<(Path, Vec<f64>)> {
    let text = std::fs::read_to_string(file).map_err(|source| Error::File {
        action: "cannot read",
        path: file.to_path_buf(),
        source,
    })?;
    parse_samples(file, &text, pitch_mm)
}

/// [`read_samples`] on text already in memory; `file` names it in errors.
pub fn parse_samples(
    file: &FsPath,
    text: &str,
    pitch_mm: [Option<f64>; 3],
) -> Result<(Path, Vec<f64>)> {
    const NAMES: [&str; 5] = ["t_s", "x_mm", "y_mm", "z_mm", "d_mm"];
    let mut lines = text.lines().enumerate();
    let (_, header) = lines
        .by_ref()
        .find(|(_, l)| !l.trim().is_empty())
        .ok_or_else(|| {
            Error::input(
                file,
                1,
                0,
                "empty file; expected header t_s,x_mm,y_mm,z_mm,d_mm",
            )
        })?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let mut idx = [0usize; 5];
    for (k, name) in NAMES.iter().enumerate() {
        idx[k] = cols.iter().position(|c| c == name).ok_or_else(|| {
            Error::input(
                file,
                1,
                0,
                format!(
                    "missing column `{name}`; the header is `{header}` but must name t_s,x_mm,y_mm,z_mm,d_mm"
                ),
            )
        })?;
    }
    let mut t = Vec::new();
    let mut p = Vec::new();
    let mut d = Vec::new();
    let mut last_line = 1;
    for (ln, line) in lines {
        let line_no = ln + 1;
        if line.trim().is_empty() || line.starts_with('#') {
            continue;
        }
        last_line = line_no;
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let mut v = [0.0f64; 5];
        for k in 0..5 {
            let col = idx[k] + 1;
            let f = fields.get(idx[k]).ok_or_else(|| {
                Error::input(
                    file,
                    line_no,
                    col,
                    format!(
                        "missing value for `{}` ({} fields on this line)",
                        NAMES[k],
                        fields.len()
                    ),
                )
            })?;
            v[k] = parse_number(file, line_no, col, NAMES[k], f)?;
        }
        if let Some(&prev) = t.last() {
            if v[0] <= prev {
                return Err(Error::input(
                    file,
                    line_no,
                    idx[0] + 1,
                    format!("time goes backwards or stands still ({} s after {prev} s); samples must be in time order", v[0]),
                ));
            }
        }
        t.push(v[0]);
        p.push([v[1], v[2], v[3]]);
        d.push(v[4]);
    }
    if t.len() < MIN_SAMPLES {
        return Err(Error::input(
            file,
            last_line,
            0,
            format!(
                "only {} samples; a diagnosis needs at least {MIN_SAMPLES} (a full circle each way)",
                t.len()
            ),
        ));
    }
    let path = Path::new(t, p, pitch_mm);
    for a in Axis::ALL {
        if pitch_mm[a.index()].is_some() && !path.moves(a) {
            return Err(Error::input(
                file,
                1,
                idx[1 + a.index()] + 1,
                format!(
                    "a pitch was given for axis {} but `{}` never changes; drop it from --pitch",
                    a.letter(),
                    NAMES[1 + a.index()]
                ),
            ));
        }
    }
    Ok((path, d))
}

/// Read the named numeric columns of a CSV with a header; rows as (line number, values).
/// Errors name file, line and column.
fn read_table(file: &FsPath, names: &[&str]) -> Result<Vec<(usize, Vec<f64>)>> {
    let text = std::fs::read_to_string(file).map_err(|source| Error::File {
        action: "cannot read",
        path: file.to_path_buf(),
        source,
    })?;
    let mut lines = text.lines().enumerate();
    let (_, header) = lines
        .by_ref()
        .find(|(_, l)| !l.trim().is_empty())
        .ok_or_else(|| {
            Error::input(
                file,
                1,
                0,
                format!("empty file; expected header {}", names.join(",")),
            )
        })?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let idx: Vec<usize> = names
        .iter()
        .map(|n| {
            cols.iter().position(|c| c == n).ok_or_else(|| {
                Error::input(
                    file,
                    1,
                    0,
                    format!(
                        "missing column `{n}`; the header is `{header}` but must name {}",
                        names.join(",")
                    ),
                )
            })
        })
        .collect::<Result<_>>()?;
    let mut rows = vec![];
    for (ln, line) in lines {
        if line.trim().is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let mut v = Vec::with_capacity(names.len());
        for (k, &c) in idx.iter().enumerate() {
            let f = fields.get(c).ok_or_else(|| {
                Error::input(
                    file,
                    ln + 1,
                    c + 1,
                    format!("missing value for `{}`", names[k]),
                )
            })?;
            v.push(parse_number(file, ln + 1, c + 1, names[k], f)?);
        }
        if let Some((_, prev)) = rows.last() {
            let prev: &Vec<f64> = prev;
            if v[0] <= prev[0] {
                return Err(Error::input(
                    file,
                    ln + 1,
                    idx[0] + 1,
                    format!(
                        "time goes backwards or stands still ({} after {})",
                        v[0], prev[0]
                    ),
                ));
            }
        }
        rows.push((ln + 1, v));
    }
    Ok(rows)
}

/// A `jdbb record` file (`seq,t_us,enc1,enc2,d_mm`) with its nominal path (`t_s,x_mm,y_mm,z_mm`,
/// t_s = 0 at `offset_s` after the record's first sample). The path is interpolated linearly at
/// each record time; record samples outside the path's time span are left out.
pub fn read_record_with_path(
    record: &FsPath,
    nominal: &FsPath,
    offset_s: f64,
    pitch_mm: [Option<f64>; 3],
) -> Result<(Path, Vec<f64>)> {
    let rec = read_table(record, &["t_us", "d_mm"])?;
    let nom = read_table(nominal, &["t_s", "x_mm", "y_mm", "z_mm"])?;
    if nom.len() < 2 {
        return Err(Error::input(
            nominal,
            nom.last().map_or(1, |r| r.0),
            0,
            "the path needs at least 2 points",
        ));
    }
    let t0 = rec.first().map_or(0.0, |r| r.1[0]);
    let mut t = vec![];
    let mut p = vec![];
    let mut d = vec![];
    let mut j = 0;
    for (_, r) in &rec {
        let ts = (r[0] - t0) * 1e-6 - offset_s;
        if ts < nom[0].1[0] || ts > nom[nom.len() - 1].1[0] {
            continue;
        }
        while j + 2 < nom.len() && nom[j + 1].1[0] < ts {
            j += 1;
        }
        let (a, b) = (&nom[j].1, &nom[j + 1].1);
        let f = ((ts - a[0]) / (b[0] - a[0])).clamp(0.0, 1.0);
        p.push([
            a[1] + f * (b[1] - a[1]),
            a[2] + f * (b[2] - a[2]),
            a[3] + f * (b[3] - a[3]),
        ]);
        t.push(ts);
        d.push(r[1]);
    }
    if t.len() < MIN_SAMPLES {
        return Err(Error::input(
            record,
            rec.last().map_or(1, |r| r.0),
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
            return Err(Error::input(
                nominal,
                1,
                2 + a.index(),
                format!("a pitch was given for axis {} but the path never moves it; drop it from --pitch", a.letter()),
            ));
        }
    }
    Ok((path, d))
}

/// Fewer samples than this cannot support a candidate search.
pub const MIN_SAMPLES: usize = 32;

/// Column-scaled eigen-structure of a Gram block: (rank, unit null vectors in the block's index).
fn null_space(g: &DMatrix<f64>) -> (usize, Vec<DVector<f64>>) {
    let n = g.nrows();
    if n == 0 {
        return (0, vec![]);
    }
    // Dead columns (norm below 1e-10 of the largest) count as exactly zero, as in crate::fit.
    let norms: Vec<f64> = (0..n).map(|k| g[(k, k)].max(0.0).sqrt()).collect();
    let dmax = norms.iter().cloned().fold(0.0, f64::max);
    let dead: Vec<bool> = norms.iter().map(|&d| d <= 1e-10 * dmax).collect();
    let a = DMatrix::from_fn(n, n, |i, j| {
        if dead[i] || dead[j] {
            0.0
        } else {
            g[(i, j)] / (norms[i] * norms[j])
        }
    });
    let eig = SymmetricEigen::new(a);
    let emax = eig.eigenvalues.iter().cloned().fold(0.0f64, f64::max);
    let thr = RANK_TOLERANCE * RANK_TOLERANCE * emax;
    let mut nulls = vec![];
    let mut rank = 0;
    for (c, &e) in eig.eigenvalues.iter().enumerate() {
        if e > thr && emax > 0.0 {
            rank += 1;
        } else {
            nulls.push(eig.eigenvectors.column(c).into_owned());
        }
    }
    (rank, nulls)
}

fn sub(g: &DMatrix<f64>, idx: &[usize]) -> DMatrix<f64> {
    DMatrix::from_fn(idx.len(), idx.len(), |i, j| g[(idx[i], idx[j])])
}

/// Solve the normal equations on columns `idx` of the Gram `g` (whose last row/column is y):
/// returns (coefficients, SSR, (GᵀG)⁻¹ on idx). None if the block is rank deficient.
fn solve(
    g: &DMatrix<f64>,
    idx: &[usize],
    yy: f64,
    ycol: usize,
) -> Option<(Vec<f64>, f64, DMatrix<f64>)> {
    let a = sub(g, idx);
    let b = DVector::from_iterator(idx.len(), idx.iter().map(|&i| g[(i, ycol)]));
    let (rank, _) = null_space(&a);
    if rank < idx.len() {
        return None;
    }
    let s: Vec<f64> = (0..idx.len()).map(|k| a[(k, k)].sqrt()).collect();
    let scaled = DMatrix::from_fn(idx.len(), idx.len(), |i, j| a[(i, j)] / (s[i] * s[j]));
    let chol = scaled.cholesky()?;
    let inv_scaled = chol.inverse();
    let inv = DMatrix::from_fn(idx.len(), idx.len(), |i, j| {
        inv_scaled[(i, j)] / (s[i] * s[j])
    });
    let x = &inv * &b;
    let ssr = (yy - x.dot(&b)).max(0.0);
    Some((x.iter().cloned().collect(), ssr, inv))
}

/// A parameter column: which effect, which of its parameters.
#[derive(Debug, Clone, Copy)]
struct ParamRef {
    effect: usize,
    k: usize,
}

/// The linearised design: all candidate effects' columns at the nominal u, with y last.
struct Design {
    effects: Vec<Effect>,
    set: EffectSet,
    params: Vec<ParamRef>,
    gram: DMatrix<f64>,
    yy: f64,
}

impl Design {
    /// One pass: accumulate the Gram matrix of u·dp + dd (µm per unit parameter) and y (µm).
    fn build(path: &Path, y_um: &[f64], effects: Vec<Effect>) -> Design {
        let set = EffectSet::new(effects.clone());
        let n = set.n_params;
        let mut params = Vec::with_capacity(n);
        for (e, eff) in effects.iter().enumerate() {
            for k in 0..eff.n_params() {
                params.push(ParamRef { effect: e, k });
            }
        }
        let w = n + 1;
        let mut acc = GramAccumulator::new(w);
        let mut u = Vec::with_capacity(GramAccumulator::ROWS);
        let mut i0 = 0;
        while i0 < y_um.len() {
            let len = GramAccumulator::ROWS.min(y_um.len() - i0);
            u.clear();
            u.extend(path.p_mm[i0..i0 + len].iter().map(|p| {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                [p[0] / r, p[1] / r, p[2] / r]
            }));
            let block = acc.rows(len);
            for (e, &o) in set.effects.iter().zip(&set.offsets) {
                e.radial_block(path, i0, &u, block, w, o);
            }
            for j in 0..len {
                block[j * w + n] = y_um[i0 + j];
            }
            i0 += len;
        }
        let gram = acc.finish();
        let yy = gram[(n, n)];
        Design {
            effects,
            set,
            params,
            gram,
            yy,
        }
    }

    fn ycol(&self) -> usize {
        self.set.n_params
    }

    fn cols_of(&self, e: usize) -> Vec<usize> {
        let o = self.set.offsets[e];
        (o..o + self.effects[e].n_params()).collect()
    }

    /// Name of parameter column i for confounding reports: the effect, or `effect.component`
    /// for multi-parameter set-up.
    fn param_name(&self, i: usize) -> String {
        let pr = self.params[i];
        let eff = self.effects[pr.effect];
        match eff {
            Effect::SetupOffset => format!("setup_offset.{}", ['x', 'y', 'z'][pr.k]),
            _ => eff.name(),
        }
    }

    /// Names of the columns (among `idx`) loaded by the null vectors of the block `idx`.
    fn confounded_names(&self, idx: &[usize]) -> Vec<Vec<String>> {
        confounded_names(&self.gram, idx, &|i| self.param_name(i))
    }

    /// Greedy: keep columns of `order` that raise the rank of what is kept.
    fn independent(&self, order: &[usize]) -> Vec<usize> {
        let mut kept: Vec<usize> = vec![];
        for &c in order {
            let mut trial = kept.clone();
            trial.push(c);
            let (rank, _) = null_space(&sub(&self.gram, &trial));
            if rank == trial.len() {
                kept = trial;
            }
        }
        kept
    }
}

/// The candidate machine effects the path can show: axes that move, pairs that both move,
/// periodic effects only where a pitch is known.
pub fn candidate_effects(path: &Path) -> Vec<Effect> {
    let mut v = vec![];
    let moving: Vec<Axis> = Axis::ALL.into_iter().filter(|&a| path.moves(a)).collect();
    for &a in &moving {
        v.push(Effect::Scale(a));
    }
    for &a in &moving {
        v.push(Effect::Scale2(a));
        v.push(Effect::Backlash(a));
        if path.pitch_mm[a.index()].is_some() {
            v.push(Effect::Cyclic(a));
            v.push(Effect::Interference(a));
        }
    }
    for pair in Pair::ALL {
        let (i, j) = pair.axes();
        if path.moves(i) && path.moves(j) {
            v.push(Effect::Squareness(pair));
            v.push(Effect::ServoMismatch(pair));
        }
    }
    v
}

/// One step of [`forward_select`].
#[derive(Debug, Clone)]
pub struct SelectionStep {
    /// Index into the candidate groups.
    pub group: usize,
    /// RMS of the residual after this step (units of y).
    pub rms_after: f64,
    /// RMS before / after.
    pub rms_ratio: f64,
    /// BIC change (negative = better).
    pub delta_bic: f64,
}

/// The outcome of [`forward_select`].
#[derive(Debug, Clone)]
pub struct Selection {
    /// SSR of the base model.
    pub base_ssr: f64,
    pub steps: Vec<SelectionStep>,
    /// Columns of the final model: base, then the chosen groups' columns in order.
    pub current: Vec<usize>,
    /// Coefficients of `current` (linear least squares) and their covariance s²(XᵀX)⁻¹.
    pub coef: Vec<f64>,
    pub covariance: DMatrix<f64>,
    pub ssr: f64,
    /// Names of candidate columns found to lie in the span of the model, with what they are
    /// confounded with.
    pub confounded: Vec<Vec<String>>,
}

/// Forward selection by BIC on a Gram matrix whose last row/column is the data y: starting from
/// the `base` columns, repeatedly add the candidate group that lowers
/// BIC = m·ln(SSR/m) + penalty·k·ln m most, while it lowers it. A group whose columns are
/// (numerically) in the span of the current model is dropped and reported as confounded (names
/// from `col_name`). Used by `diagnose` and `diagnose-rotary`.
pub fn forward_select(
    gram: &DMatrix<f64>,
    m: usize,
    base: &[usize],
    groups: &[Vec<usize>],
    opts: &Options,
    col_name: &dyn Fn(usize) -> String,
) -> Result<Selection> {
    let ycol = gram.nrows() - 1;
    let yy = gram[(ycol, ycol)];
    let mf = m as f64;
    let bic_of =
        |ssr: f64, k: usize| mf * (ssr.max(1e-300) / mf).ln() + opts.penalty * k as f64 * mf.ln();
    let mut current: Vec<usize> = base.to_vec();
    let base_ssr = if current.is_empty() {
        yy
    } else {
        solve(gram, &current, yy, ycol)
            .ok_or_else(|| Error::Numerics("the base model's columns are degenerate".into()))?
            .1
    };
    let mut ssr = base_ssr;
    let mut bic = bic_of(ssr, current.len());
    let mut steps = vec![];
    let mut confounded: Vec<Vec<String>> = vec![];
    let mut remaining: Vec<usize> = (0..groups.len()).collect();
    while steps.len() < opts.max_effects {
        let mut best: Option<(usize, f64, f64)> = None; // (group, ssr, bic)
        let mut skip = vec![];
        for &e in &remaining {
            let mut trial = current.clone();
            trial.extend(&groups[e]);
            match solve(gram, &trial, yy, ycol) {
                None => {
                    for g in confounded_names(gram, &trial, col_name) {
                        if g.len() > 1 && !confounded.contains(&g) {
                            confounded.push(g);
                        }
                    }
                    skip.push(e);
                }
                Some((_, s, _)) => {
                    let b = bic_of(s, trial.len());
                    if best.is_none_or(|(_, _, bb)| b < bb) {
                        best = Some((e, s, b));
                    }
                }
            }
        }
        remaining.retain(|e| !skip.contains(e));
        let Some((e, s, b)) = best else { break };
        if b >= bic {
            break;
        }
        let before = (ssr / mf).sqrt();
        let after = (s / mf).sqrt();
        current.extend(&groups[e]);
        steps.push(SelectionStep {
            group: e,
            rms_after: after,
            rms_ratio: before / after.max(1e-300),
            delta_bic: b - bic,
        });
        ssr = s;
        bic = b;
        remaining.retain(|&x| x != e);
    }
    let (coef, covariance) = match solve(gram, &current, yy, ycol) {
        Some((x, s, inv)) => {
            let dof = m.saturating_sub(current.len()).max(1);
            (x, inv * (s / dof as f64))
        }
        None => (vec![], DMatrix::zeros(0, 0)),
    };
    Ok(Selection {
        base_ssr,
        steps,
        current,
        coef,
        covariance,
        ssr,
        confounded,
    })
}

/// Names of the columns (among `idx`) loaded by the null vectors of the Gram block `idx`.
fn confounded_names(
    gram: &DMatrix<f64>,
    idx: &[usize],
    col_name: &dyn Fn(usize) -> String,
) -> Vec<Vec<String>> {
    // Dead columns (no effect on the data) are named alone; the rest from the null space of the
    // live columns, so a degenerate null space cannot tie a dead column to an unrelated group.
    let norms: Vec<f64> = idx.iter().map(|&i| gram[(i, i)].max(0.0).sqrt()).collect();
    let dmax = norms.iter().cloned().fold(0.0, f64::max);
    let mut out: Vec<Vec<String>> = vec![];
    let mut live = vec![];
    for (k, &i) in idx.iter().enumerate() {
        if norms[k] <= 1e-10 * dmax {
            let g = vec![col_name(i)];
            if !out.contains(&g) {
                out.push(g);
            }
        } else {
            live.push(i);
        }
    }
    let (_, nulls) = null_space(&sub(gram, &live));
    for v in nulls {
        let mut names: Vec<String> = (0..live.len())
            .filter(|&k| v[k].abs() >= 0.1)
            .map(|k| col_name(live[k]))
            .collect();
        names.dedup();
        if !names.is_empty() && !out.contains(&names) {
            out.push(names);
        }
    }
    out
}

/// Diagnose a circular test: baseline, set-up, forward selection of machine effects, exact refit,
/// residual harmonics, G and H. See the module docs.
pub fn diagnose(path: &Path, d_mm: &[f64], opts: &Options) -> Result<Diagnosis> {
    let m = d_mm.len();
    if m != path.len() || m < MIN_SAMPLES {
        return Err(Error::Numerics(format!(
            "diagnose needs at least {MIN_SAMPLES} samples with a path each (got {m})"
        )));
    }
    // 1. Baseline.
    let base: Vec<f64> = path
        .p_mm
        .iter()
        .zip(d_mm)
        .map(|(p, d)| 1e3 * (d - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()))
        .collect();
    let baseline_rms_um = rms(&base);
    let baseline_pv_um = pv(&base);

    // 2. Which set-up parameters the path determines (nominal linearisation: columns u_x, u_y,
    // u_z for c and 1 for e), keeping e first, then c_x, c_y, c_z.
    let setup = [Effect::SetupOffset, Effect::LengthOffset];
    let setup_probe = Design::build(path, &base, setup.to_vec());
    let setup_free = setup_probe.independent(&[3, 0, 1, 2]);
    let mut confounded: Vec<Vec<String>> = setup_probe.confounded_names(&[0, 1, 2, 3]);

    // 3. Exact set-up fit D = |p + c| + e on the determined set-up parameters.
    // Start from the linearised solution (one Gauss–Newton step done already).
    let mut setup_start = [0.0; 4];
    if let Some((x, _, _)) = solve(
        &setup_probe.gram,
        &setup_free,
        setup_probe.yy,
        setup_probe.ycol(),
    ) {
        for (&i, v) in setup_free.iter().zip(x) {
            setup_start[i] = v;
        }
    }
    let setup_theta = fit_setup(path, d_mm, &setup_free, &setup_start)?;
    let c_mm = [
        setup_theta[0] * 1e-3,
        setup_theta[1] * 1e-3,
        setup_theta[2] * 1e-3,
    ];
    let y: Vec<f64> = (0..m)
        .map(|i| {
            let p = path.p_mm[i];
            let q = [p[0] + c_mm[0], p[1] + c_mm[1], p[2] + c_mm[2]];
            let dist = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + setup_theta[3] * 1e-3;
            1e3 * (d_mm[i] - dist)
        })
        .collect();

    // 4. One pass: Gram of [set-up, scale_k, scale_mismatch_ij, other candidates, y].
    let others = candidate_effects(path);
    let mut effects = setup.to_vec();
    effects.extend(others.iter().filter(|e| matches!(e, Effect::Scale(_))));
    for pair in Pair::ALL {
        let (i, j) = pair.axes();
        if path.moves(i) && path.moves(j) {
            effects.push(Effect::ScaleMismatch(pair));
        }
    }
    effects.extend(others.iter().filter(|e| !matches!(e, Effect::Scale(_))));
    let design = Design::build(path, &y, effects);
    // If the isotropic scale is confounded with the set-up (one radius), the identifiable
    // candidates are the scale mismatches; otherwise the per-axis scales.
    let scale_effects: Vec<usize> = (0..design.effects.len())
        .filter(|&e| matches!(design.effects[e], Effect::Scale(_)))
        .collect();
    let scale_cols: Vec<usize> = scale_effects
        .iter()
        .map(|&e| design.cols_of(e)[0])
        .collect();
    let mut block: Vec<usize> = setup_free.clone();
    block.extend(&scale_cols);
    let isotropic_confounded = design.independent(&block).len() < block.len();
    if isotropic_confounded {
        let mut with_all_setup = vec![0, 1, 2, 3];
        with_all_setup.extend(&scale_cols);
        for g in design.confounded_names(&with_all_setup) {
            if g.iter().any(|n| n.starts_with("scale_")) && !confounded.contains(&g) {
                confounded.push(g);
            }
        }
    }
    confounded.retain(|g| !g.is_empty());
    let candidates: Vec<usize> = (2..design.effects.len())
        .filter(|&e| match design.effects[e] {
            Effect::Scale(_) => !isotropic_confounded,
            Effect::ScaleMismatch(_) => isotropic_confounded,
            _ => true,
        })
        .collect();

    // 5. Linear forward selection on the Gram.
    let free_setup = setup_free.clone();
    let groups: Vec<Vec<usize>> = candidates.iter().map(|&e| design.cols_of(e)).collect();
    let sel = forward_select(&design.gram, m, &free_setup, &groups, opts, &|i| {
        design.param_name(i)
    })?;
    for g in sel.confounded {
        if !confounded.contains(&g) {
            confounded.push(g);
        }
    }
    let setup_rms = (sel.base_ssr / m as f64).sqrt();
    // (effect idx, rms after, ratio, dbic)
    let chosen: Vec<(usize, f64, f64, f64)> = sel
        .steps
        .iter()
        .map(|st| {
            (
                candidates[st.group],
                st.rms_after,
                st.rms_ratio,
                st.delta_bic,
            )
        })
        .collect();
    let current = &sel.current;

    // 6. Exact refit of set-up + chosen effects.
    let mut final_effects = setup.to_vec();
    final_effects.extend(chosen.iter().map(|c| design.effects[c.0]));
    let final_set = EffectSet::new(final_effects.clone());
    let mut free = free_setup.clone();
    let mut start = setup_theta.clone();
    // Start from the linear solution for the chosen parameters (set-up from its exact fit plus
    // its linear correction). `current` = free set-up columns, then the chosen effects' columns.
    let x = &sel.coef;
    for (k, &col) in current.iter().enumerate() {
        if col < 4 {
            start[col] += x[k];
        }
    }
    let mut at = free_setup.len();
    for c in &chosen {
        let n = design.effects[c.0].n_params();
        start.extend(&x[at..at + n]);
        at += n;
    }
    for i in 4..final_set.n_params {
        free.push(i);
    }
    let (theta, sig, cov, final_ssr) = fit_exact(path, d_mm, &final_set, &free, &start, 1e-6)?;
    let final_rms_um = (final_ssr / m as f64).sqrt();

    // Report.
    let mut found = vec![];
    for (ei, eff) in final_effects.iter().enumerate() {
        let o = final_set.offsets[ei];
        let n = eff.n_params();
        let params = theta[o..o + n].to_vec();
        let psig: Vec<Option<f64>> = sig[o..o + n].to_vec();
        let block: Vec<Vec<f64>> = (0..n)
            .map(|i| (0..n).map(|j| cov[(o + i, o + j)]).collect())
            .collect();
        let (value, mut sigma) = eff.value(&params, &block);
        if psig.iter().all(|s| s.is_none()) {
            sigma = None;
        }
        let (rms_after_um, rms_ratio, delta_bic) = if ei < 2 {
            (setup_rms, baseline_rms_um / setup_rms.max(1e-300), f64::NAN)
        } else {
            let c = chosen[ei - 2];
            (c.1, c.2, c.3)
        };
        found.push(Found {
            effect: *eff,
            params,
            param_sigma: psig,
            value,
            sigma,
            rms_after_um,
            rms_ratio,
            delta_bic,
        });
    }

    // Residual structure, G and H. The plotted deviations have the least-squares set-up of step 3
    // removed (the ballbar convention: centring and bar length are set-up, not machine); the
    // model's prediction gets the same treatment, so both curves show the same quantity.
    let plane = main_plane(path);
    let full_mm = final_set.distances_mm(path, &theta);
    let model_setup = fit_setup(
        path,
        &full_mm,
        &setup_free,
        &[
            setup_theta[0],
            setup_theta[1],
            setup_theta[2],
            setup_theta[3],
        ],
    )?;
    let lsq_setup_um = [
        setup_theta[0],
        setup_theta[1],
        setup_theta[2],
        setup_theta[3],
    ];
    let angle = angles(&path.p_mm, plane);
    let mut meas = Vec::with_capacity(m);
    let mut model = Vec::with_capacity(m);
    let mut resid = Vec::with_capacity(m);
    for i in 0..m {
        let p = path.p_mm[i];
        meas.push(1e3 * (d_mm[i] - setup_distance_mm(p, &lsq_setup_um)));
        model.push(1e3 * (full_mm[i] - setup_distance_mm(p, &model_setup)));
        resid.push(1e3 * (d_mm[i] - full_mm[i]));
    }
    let harmonics_um = harmonics(&angle, &resid, opts.harmonics);
    let (circles, runs) = split_runs_at(&path.t_s, &path.p_mm, &angle, plane, MAX_RUN_STEP_RAD);
    let (g, h) = circularity(&angle, &meas, &runs);
    Ok(Diagnosis {
        samples: m,
        baseline_rms_um,
        baseline_pv_um,
        effects: found,
        confounded,
        final_rms_um,
        gain: baseline_rms_um / final_rms_um.max(1e-300),
        harmonics_um,
        candidates: candidates
            .iter()
            .map(|&e| design.effects[e].name())
            .collect(),
        angle_rad: angle,
        measured_dev_um: meas,
        model_dev_um: model,
        lsq_setup_um,
        plane,
        circles,
        runs,
        circular_deviation_g_um: g,
        hysteresis_h_um: h,
    })
}

/// The set-up's distance |p + c| + e (mm) for `setup_um` = [c_x, c_y, c_z, e] in µm.
fn setup_distance_mm(p: [f64; 3], setup_um: &[f64]) -> f64 {
    let q = [
        p[0] + 1e-3 * setup_um[0],
        p[1] + 1e-3 * setup_um[1],
        p[2] + 1e-3 * setup_um[2],
    ];
    (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + 1e-3 * setup_um[3]
}

/// D = |p + c| + e with only the set-up parameters `free` (indices into c_x, c_y, c_z, e)
/// varying, from `start`; returns [c_x, c_y, c_z, e] in µm.
fn fit_setup(path: &Path, d_mm: &[f64], free: &[usize], start: &[f64; 4]) -> Result<Vec<f64>> {
    struct Setup<'a> {
        path: &'a Path,
        d_mm: &'a [f64],
        free: &'a [usize],
    }
    impl crate::fit::Problem for Setup<'_> {
        fn n_params(&self) -> usize {
            self.free.len()
        }
        fn n_residuals(&self) -> usize {
            self.d_mm.len()
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            let mut full = [0.0; 4];
            for (a, &i) in self.free.iter().enumerate() {
                full[i] = p[a];
            }
            let mut g = [0.0; 4];
            for (i, (q0, d)) in self.path.p_mm.iter().zip(self.d_mm).enumerate() {
                let q = [
                    q0[0] + 1e-3 * full[0],
                    q0[1] + 1e-3 * full[1],
                    q0[2] + 1e-3 * full[2],
                ];
                let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
                let all = [q[0] / r, q[1] / r, q[2] / r, 1.0];
                for (a, &k) in self.free.iter().enumerate() {
                    g[a] = all[k];
                }
                visit(i, 1e3 * (r - d) + full[3], &g[..self.free.len()]);
            }
        }
    }
    let opts = LsqOptions {
        max_iterations: 50,
        // The final refit frees the set-up again: this fit only has to be good enough to
        // linearise the candidates around.
        tolerance: 1e-6,
        ..Default::default()
    };
    let prob = Setup { path, d_mm, free };
    let p0: Vec<f64> = free.iter().map(|&i| start[i]).collect();
    let fit = least_squares(&prob, &p0, &opts)?;
    let mut full = vec![0.0; 4];
    for (a, &i) in free.iter().enumerate() {
        full[i] = fit.params[a];
    }
    Ok(full)
}

/// Exact-geometry fit of `set` with only parameters `free` varying (others held at `start`).
/// Returns (θ, σ, covariance, SSR in µm²).
#[allow(clippy::type_complexity)]
fn fit_exact(
    path: &Path,
    d_mm: &[f64],
    set: &EffectSet,
    free: &[usize],
    start: &[f64],
    tolerance: f64,
) -> Result<(Vec<f64>, Vec<Option<f64>>, DMatrix<f64>, f64)> {
    let model = ExactModel { path, d_mm, set };
    let restricted = Restricted {
        inner: &model,
        free,
        base: start,
    };
    let p0: Vec<f64> = free.iter().map(|&i| start[i]).collect();
    let opts = LsqOptions {
        max_iterations: 50,
        tolerance,
        ..Default::default()
    };
    let fit = least_squares(&restricted, &p0, &opts)?;
    let n = set.n_params;
    let mut theta = start.to_vec();
    let mut sig = vec![None; n];
    let mut cov = DMatrix::zeros(n, n);
    for (a, &i) in free.iter().enumerate() {
        theta[i] = fit.params[a];
        sig[i] = fit.sigma[a];
        for (b, &j) in free.iter().enumerate() {
            cov[(i, j)] = fit.covariance[(a, b)];
        }
    }
    Ok((theta, sig, cov, fit.ssr))
}

/// A problem with some parameters held fixed.
struct Restricted<'a> {
    inner: &'a dyn crate::fit::Problem,
    free: &'a [usize],
    base: &'a [f64],
}

impl crate::fit::Problem for Restricted<'_> {
    fn n_params(&self) -> usize {
        self.free.len()
    }
    fn n_residuals(&self) -> usize {
        self.inner.n_residuals()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let mut full = self.base.to_vec();
        for (a, &i) in self.free.iter().enumerate() {
            full[i] = p[a];
        }
        let mut g = vec![0.0; self.free.len()];
        self.inner.eval(&full, &mut |i, r, grad| {
            for (a, &k) in self.free.iter().enumerate() {
                g[a] = grad[k];
            }
            visit(i, r, &g);
        });
    }
}

/// The two axes with the largest travel (the plane of the circle).
pub fn main_plane(path: &Path) -> (usize, usize) {
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| path.range_mm[b].total_cmp(&path.range_mm[a]));
    let (a, b) = (idx[0].min(idx[1]), idx[0].max(idx[1]));
    // Keep a right-handed order: (x,y), (y,z), (z,x).
    match (a, b) {
        (0, 2) => (2, 0),
        ab => ab,
    }
}

/// Amplitudes (µm) of harmonics 1..=n of `r` against `angle` (least squares with a constant).
pub fn harmonics(angle: &[f64], r: &[f64], n: usize) -> Vec<f64> {
    let w = 2 * n + 2;
    let mut acc = GramAccumulator::new(w);
    for (&a, &y) in angle.iter().zip(r) {
        // Row [1, cos θ, sin θ, …, cos nθ, sin nθ, y], cut into its parts up front so the
        // per-sample loop runs without bounds checks.
        let (one, rest) = acc.row().split_at_mut(1);
        let (trig, last) = rest.split_at_mut(2 * n);
        one[0] = 1.0;
        // cos kθ, sin kθ by rotation from one sin_cos (error ~k·ε, fine for k ≤ 100).
        let (s1, c1) = a.sin_cos();
        let (mut c, mut s) = (1.0f64, 0.0f64);
        for cs in trig.chunks_exact_mut(2) {
            (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
            cs[0] = c;
            cs[1] = s;
        }
        last[0] = y;
    }
    let full = acc.finish();
    let g = full.view((0, 0), (w - 1, w - 1)).into_owned();
    let b = full.view((0, w - 1), (w - 1, 1)).column(0).into_owned();
    let coef = match g.clone().cholesky() {
        Some(ch) => ch.solve(&b),
        None => return vec![0.0; n],
    };
    (1..=n)
        .map(|k| coef[2 * k - 1].hypot(coef[2 * k]))
        .collect()
}

/// ISO 230-4 style circular deviation G and hysteresis H (µm) of `dev`, the deviation (µm) from
/// the circle of the least-squares set-up (one centre and length for all samples, not the minimum
/// zone) — the measured curve of the polar plot. Each circle of `runs` is evaluated on its own:
/// G is the largest peak-to-valley of one circle in one direction, H the largest difference
/// between a circle's ccw and cw mean deviation in the same 1° angle bin.
pub fn circularity(angle: &[f64], dev: &[f64], runs: &[Run]) -> (f64, f64) {
    let n_circles = runs.iter().map(|r| r.circle + 1).max().unwrap_or(0);
    let mut g = 0.0f64;
    let mut h = 0.0f64;
    for c in 0..n_circles {
        let mut bins = [vec![(0.0f64, 0usize); 360], vec![(0.0f64, 0usize); 360]];
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for run in runs.iter().filter(|r| r.circle == c) {
            let d = usize::from(!run.ccw);
            for i in run.range.clone() {
                lo[d] = lo[d].min(dev[i]);
                hi[d] = hi[d].max(dev[i]);
                let deg = angle[i].to_degrees().rem_euclid(360.0);
                let k = (deg as usize).min(359);
                bins[d][k].0 += dev[i];
                bins[d][k].1 += 1;
            }
        }
        for d in 0..2 {
            if hi[d] >= lo[d] {
                g = g.max(hi[d] - lo[d]);
            }
        }
        for k in 0..360 {
            let (a, b) = (bins[0][k], bins[1][k]);
            if a.1 > 0 && b.1 > 0 {
                h = h.max((a.0 / a.1 as f64 - b.0 / b.1 as f64).abs());
            }
        }
    }
    (g, h)
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

fn pv(v: &[f64]) -> f64 {
    let lo = v.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    hi - lo
}

/// Human summary of a diagnosis.
pub fn summary(d: &Diagnosis) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "{} samples", d.samples);
    let _ = writeln!(
        s,
        "ideal machine (D = |p|): RMS {:.3} µm, peak-to-valley {:.3} µm",
        d.baseline_rms_um, d.baseline_pv_um
    );
    for (i, f) in d.effects.iter().enumerate() {
        let step = if i < 2 {
            "set-up".to_string()
        } else {
            format!("step {}", i - 1)
        };
        let sig = f
            .sigma
            .map(|s| format!(" ± {s:.4}"))
            .unwrap_or_else(|| " (undetermined)".into());
        let _ = writeln!(
            s,
            "{step}: {} = {:.4}{sig} {} — {}",
            f.effect.name(),
            f.value,
            f.effect.unit(),
            f.effect.cause()
        );
        let params: Vec<String> = f
            .effect
            .param_names()
            .iter()
            .zip(&f.params)
            .zip(&f.param_sigma)
            .map(|((n, v), s)| match s {
                Some(s) => format!("{n} = {v:.4} ± {s:.4}"),
                None => format!("{n} = {v:.4} (undetermined, held)"),
            })
            .collect();
        let _ = writeln!(s, "    {}", params.join(", "));
        if i >= 2 || i == 1 {
            let _ = writeln!(
                s,
                "    RMS after {:.3} µm, gain ×{:.2}{}",
                f.rms_after_um,
                f.rms_ratio,
                if f.delta_bic.is_finite() {
                    format!(", ΔBIC {:.1}", f.delta_bic)
                } else {
                    String::new()
                }
            );
        }
    }
    if d.effects.len() <= 2 {
        let _ = writeln!(s, "no machine effect is supported by the data");
    }
    for g in &d.confounded {
        let _ = writeln!(
            s,
            "confounded (this test cannot tell apart): {}",
            g.join(", ")
        );
    }
    let _ = writeln!(
        s,
        "final: RMS {:.3} µm, gain ×{:.2} over the ideal machine",
        d.final_rms_um, d.gain
    );
    let _ = writeln!(
        s,
        "circular deviation G {:.3} µm, hysteresis H {:.3} µm (ISO 230-4 style, least-squares centre and length removed)",
        d.circular_deviation_g_um, d.hysteresis_h_um
    );
    let h: Vec<String> = d
        .harmonics_um
        .iter()
        .enumerate()
        .map(|(k, a)| format!("{}:{:.3}", k + 1, a))
        .collect();
    let _ = writeln!(s, "residual harmonics vs angle (order:µm): {}", h.join(" "));
    s
}

/// The documented JSON (see the README): samples, baseline, effects, confounded, final, gain.
pub fn to_json(d: &Diagnosis) -> serde_json::Value {
    use serde_json::{json, Map, Value};
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    let effects: Vec<Value> = d
        .effects
        .iter()
        .map(|f| {
            let mut params = Map::new();
            let mut psig = Map::new();
            for ((n, v), s) in f
                .effect
                .param_names()
                .iter()
                .zip(&f.params)
                .zip(&f.param_sigma)
            {
                params.insert((*n).into(), num(*v));
                psig.insert((*n).into(), s.map(num).unwrap_or(Value::Null));
            }
            json!({
                "name": f.effect.name(),
                "value": num(f.value),
                "unit": f.effect.unit(),
                "sigma": f.sigma.map(num).unwrap_or(Value::Null),
                "params": params,
                "params_sigma": psig,
                "rms_after_um": num(f.rms_after_um),
                "rms_ratio": num(f.rms_ratio),
                "delta_bic": num(f.delta_bic),
                "setup": f.effect.is_setup(),
                "cause": f.effect.cause(),
            })
        })
        .collect();
    json!({
        "samples": d.samples,
        "baseline": {"rms_um": num(d.baseline_rms_um), "pv_um": num(d.baseline_pv_um)},
        "effects": effects,
        "confounded": d.confounded,
        "final": {"rms_um": num(d.final_rms_um)},
        "gain": num(d.gain),
        "harmonics_um": d.harmonics_um,
        "lsq_setup": {
            "x_um": num(d.lsq_setup_um[0]),
            "y_um": num(d.lsq_setup_um[1]),
            "z_um": num(d.lsq_setup_um[2]),
            "e_um": num(d.lsq_setup_um[3]),
        },
        "circular_deviation_g_um": num(d.circular_deviation_g_um),
        "hysteresis_h_um": num(d.hysteresis_h_um),
        "candidates": d.candidates,
    })
}

/// Arguments of `jdbb diagnose`.
#[derive(Debug, clap::Args)]
pub struct DiagnoseArgs {
    /// CSV `t_s,x_mm,y_mm,z_mm,d_mm` (nominal path and measured D), e.g. from `jdbb simulate`.
    #[arg(long, required_unless_present = "record", conflicts_with = "record")]
    pub samples: Option<PathBuf>,
    /// A `jdbb record` file (`seq,t_us,enc1,enc2,d_mm`), diagnosed together with `--path`.
    #[arg(long, requires = "path")]
    pub record: Option<PathBuf>,
    /// The nominal path of a `--record` file: CSV `t_s,x_mm,y_mm,z_mm` (the commanded ball
    /// centre relative to the table ball), interpolated linearly at the record's times.
    #[arg(long, requires = "record")]
    pub path: Option<PathBuf>,
    /// Time of the path's t_s = 0 on the record's clock, in s after the record's first sample.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub path_offset_s: f64,
    /// Ball-screw or scale pitch per axis in mm, e.g. `x=10,y=10,z=5`; enables cyclic_k and
    /// interference_k for those axes.
    #[arg(long)]
    pub pitch: Option<String>,
    /// Print the documented JSON instead of the human summary.
    #[arg(long)]
    pub json: bool,
    /// Write polar plots (SVG and PNG) and the JSON to this directory.
    #[arg(long)]
    pub report: Option<PathBuf>,
}

/// Parse `x=10,y=10,z=5`.
pub fn parse_pitch(s: &str) -> Result<[Option<f64>; 3]> {
    let mut out = [None; 3];
    for part in s.split(',').filter(|p| !p.trim().is_empty()) {
        let (k, v) = part.split_once('=').ok_or_else(|| {
            Error::Usage(format!(
                "--pitch: `{part}` should look like x=10 (axis=pitch in mm)"
            ))
        })?;
        let axis = match k.trim() {
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
        out[axis] = Some(p);
    }
    Ok(out)
}

/// Run `jdbb diagnose`.
pub fn run(args: &DiagnoseArgs) -> Result<()> {
    let pitch = match &args.pitch {
        Some(s) => parse_pitch(s)?,
        None => [None; 3],
    };
    let (path, d) = match (&args.samples, &args.record, &args.path) {
        (Some(samples), _, _) => read_samples(samples, pitch)?,
        (None, Some(record), Some(nominal)) => {
            read_record_with_path(record, nominal, args.path_offset_s, pitch)?
        }
        _ => {
            return Err(Error::Usage(
                "give --samples FILE, or --record FILE with --path FILE".into(),
            ))
        }
    };
    let diag = diagnose(&path, &d, &Options::default())?;
    let json = to_json(&diag);
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&json).expect("JSON of plain values")
        );
    } else {
        print!("{}", summary(&diag));
    }
    if let Some(dir) = &args.report {
        crate::report::write_report(dir, &diag, &json)?;
        if !args.json {
            println!("report written to {}", dir.display());
        }
    }
    Ok(())
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
        assert!(e.to_string().starts_with("s.csv:3:3:"), "{e}");
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
        let mut text = String::from("d_mm,t_s,x_mm,y_mm,z_mm\n");
        for i in 0..40 {
            text.push_str(&format!(
                "50,{i},{},{},0\n",
                (i as f64).cos(),
                (i as f64).sin()
            ));
        }
        let (p, d) = parse_samples(f, &text, [None; 3]).unwrap();
        assert_eq!(d.len(), 40);
        assert!(p.moves(Axis::X) && !p.moves(Axis::Z));
        let e = parse_samples(f, &text, [None, None, Some(5.0)]).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("s.csv:1:5: a pitch was given for axis z"),
            "{e}"
        );
    }

    /// A circle of radius `r_mm` at height `h_mm` in xy from angle `a0_deg`, `n` steps of
    /// `step_deg` (negative = cw), sampled every 0.01 s from `t0_s`.
    fn arc(
        r_mm: f64,
        h_mm: f64,
        a0_deg: f64,
        step_deg: f64,
        n: usize,
        t0_s: f64,
    ) -> (Vec<f64>, Vec<[f64; 3]>) {
        (0..n)
            .map(|k| {
                let a = (a0_deg + step_deg * k as f64).to_radians();
                (
                    t0_s + 0.01 * k as f64,
                    [r_mm * a.cos(), r_mm * a.sin(), h_mm],
                )
            })
            .unzip()
    }

    #[test]
    fn split_runs_leaves_no_chord_across_the_polar_plot() {
        // ccw circle, cw circle starting at 180° (a 180° jump), a standstill, then after a 1 s
        // pause a second radius at another height, and a 90° jump inside one ccw pass.
        let mut t = vec![];
        let mut p = vec![];
        let mut add = |(tt, pp): (Vec<f64>, Vec<[f64; 3]>)| {
            t.extend(tt);
            p.extend(pp);
        };
        add(arc(50.0, 0.0, 0.0, 1.0, 360, 0.0));
        add(arc(50.0, 0.0, 180.0, -1.0, 360, 3.6));
        add(arc(50.0, 0.0, 181.0, 0.0, 20, 7.2));
        add(arc(80.0, 10.0, 0.0, 0.5, 200, 8.4));
        add(arc(80.0, 10.0, 190.0, 0.5, 520, 10.4));
        let (circles, runs) = split_runs(&t, &p, (0, 1), MAX_RUN_STEP_RAD);
        assert_eq!(circles.len(), 2, "{circles:?}");
        assert!((circles[1].radius_mm - 80.0).abs() < 1e-9 && circles[1].height_mm == 10.0);
        // Runs tile the samples in order.
        assert_eq!(runs[0].range.start, 0);
        assert_eq!(runs.last().unwrap().range.end, t.len());
        for w in runs.windows(2) {
            assert_eq!(w[0].range.end, w[1].range.start);
        }
        // ccw, cw (+ standstill), ccw radius 80, ccw radius 80 after the 90° jump.
        let kinds: Vec<(usize, bool)> = runs.iter().map(|r| (r.circle, r.ccw)).collect();
        assert_eq!(kinds, vec![(0, true), (0, false), (1, true), (1, true)]);
        for run in &runs {
            let c = circles[run.circle];
            for i in run.range.clone() {
                let r = p[i][0].hypot(p[i][1]);
                assert!((r - c.radius_mm).abs() < 1e-6 && p[i][2] == c.height_mm);
            }
            for i in run.range.clone().skip(1) {
                let da = wrap_pi(p[i][1].atan2(p[i][0]) - p[i - 1][1].atan2(p[i - 1][0]));
                assert!(
                    da.abs() <= MAX_RUN_STEP_RAD,
                    "segment {i} spans {:.1}°",
                    da.to_degrees()
                );
                assert!(
                    da == 0.0 || (da > 0.0) == run.ccw,
                    "direction change in a run"
                );
            }
        }
    }

    /// Simulated circular test, r = 50 mm, 100 Hz, 0.3 µm noise, 0.1 µm resolution.
    fn simulated(effects: &[crate::simulate::EffectValue]) -> (Path, Vec<f64>) {
        use crate::simulate::{distances_mm, measure, nominal_path, PathSpec};
        let spec = PathSpec {
            radii_mm: vec![50.0],
            heights_mm: vec![0.0],
            plane: (0, 1, 2),
            feed_mm_min: 1000.0,
            rate_hz: 100.0,
        };
        let (t, p) = nominal_path(&spec);
        let path = Path::new(t, p, [None; 3]);
        let mut d = distances_mm(&path, effects).unwrap();
        measure(&mut d, 0.3, 0.1, 11);
        (path, d)
    }

    fn ev(effect: Effect, params: Vec<f64>) -> crate::simulate::EffectValue {
        crate::simulate::EffectValue { effect, params }
    }

    #[test]
    fn plotted_deviation_has_the_setup_removed() {
        // Only set-up (centring 40, −25 µm; bar 15 µm long) and noise: the plotted measured
        // deviation is noise around zero, not the 47 µm eccentricity.
        let setup = [
            ev(Effect::SetupOffset, vec![40.0, -25.0, 0.0]),
            ev(Effect::LengthOffset, vec![15.0]),
        ];
        let (path, d) = simulated(&setup);
        let diag = diagnose(&path, &d, &Options::default()).unwrap();
        let meas = &diag.measured_dev_um;
        let mean = meas.iter().sum::<f64>() / meas.len() as f64;
        assert!(mean.abs() < 0.02, "mean radial deviation {mean} µm");
        let h1 = harmonics(&diag.angle_rad, meas, 1)[0];
        assert!(h1 < 0.05, "first harmonic (eccentricity) {h1} µm");
        assert!(rms(meas) < 0.4, "RMS {} µm", rms(meas));
        for (k, truth) in [40.0, -25.0, 0.0, 15.0].into_iter().enumerate() {
            assert!(
                (diag.lsq_setup_um[k] - truth).abs() < 0.1,
                "{:?}",
                diag.lsq_setup_um
            );
        }
        // No machine effect: the model's curve is the zero circle; G is the noise band only.
        assert!(diag.model_dev_um.iter().all(|v| v.abs() < 0.01));
        assert!(
            diag.circular_deviation_g_um < 3.0,
            "G {}",
            diag.circular_deviation_g_um
        );
        assert_eq!(diag.runs.len(), 2);

        // With a machine effect the model's curve follows the measured one to the noise.
        let mut with_backlash = setup.to_vec();
        with_backlash.push(ev(Effect::Backlash(Axis::X), vec![6.0]));
        let (path, d) = simulated(&with_backlash);
        let diag = diagnose(&path, &d, &Options::default()).unwrap();
        let diff: Vec<f64> = diag
            .measured_dev_um
            .iter()
            .zip(&diag.model_dev_um)
            .map(|(a, b)| a - b)
            .collect();
        assert!(rms(&diff) < 0.4, "measured − model RMS {}", rms(&diff));
        assert!(diag.circular_deviation_g_um > 5.0);
    }

    #[test]
    fn harmonics_recover_amplitudes() {
        let a: Vec<f64> = (0..720).map(|i| (i as f64).to_radians() * 0.5).collect();
        let r: Vec<f64> = a
            .iter()
            .map(|&t| 0.3 + 2.0 * (t + 0.4).cos() + 0.5 * (3.0 * t).sin())
            .collect();
        let h = harmonics(&a, &r, 4);
        assert!((h[0] - 2.0).abs() < 1e-9 && h[1].abs() < 1e-9);
        assert!((h[2] - 0.5).abs() < 1e-9 && h[3].abs() < 1e-9);
    }
}
