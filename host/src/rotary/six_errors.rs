//! Six geometric errors of a rotary axis from DBB runs (seed 002: Ni et al., Strojniški vestnik
//! 64 (2018) 5, §1.2, eq. 6-9 and the three installation combinations).
//!
//! **Model** (eq. 9, first order): at axis angle γ the ball P(γ) on the rotating part is displaced
//! by ΔP = δ + ε × P(γ), with δ = (δx, δy, δz) and ε = (εx, εy, εz) the six errors at γ. A bar
//! installed radially, tangentially or axially reads the component of ΔP along its direction.
//! - C turntable: P(γ) = (L cos γ, L sin γ, H); radial (cos γ, sin γ, 0), tangential
//!   (−sin γ, cos γ, 0), axial (0, 0, 1) at L = 0 (eq. 11). This reproduces eq. (9) term by term.
//! - B swinging head (about Y): the printed eq. (25) is garbled (P = (0 0 −L) becomes
//!   (L sin β, 0, L cos β)) and eq. (26)-(33) are missing from the text, so it is derived again:
//!   P(β) = R_y(β)(0, H, −L) = (−L sin β, H, −L cos β); radial (sin β, 0, cos β), tangential
//!   (−cos β, 0, sin β), axial (0, 1, 0).
//!
//! **Which way a run reads.** A bar reads its length change, + when it extends. A run's direction
//! n above is the one along which a displacement of P extends the bar: the other ball sits at
//! P − ℓ·n. C: the spindle ball inward of the table ball (radial), behind it in the sense of
//! rotation (tangential); the axial run follows the paper's eq. (14), ΔZ = Δla (the spindle ball
//! above the table ball would read −ΔZ). B: the table ball on the tool's axis beyond the spindle
//! ball (the only place it can be: on the pivot side it would be inside the head), so a ball
//! displaced along the tool toward the table shortens the bar and radial reads −ΔP·(−sin β, 0,
//! −cos β); tangential with the table ball on the head's +X side at B = 0, axial on the spindle
//! ball's −Y side. Until issue 21 the B radial direction was (−sin β, 0, −cos β), which a
//! physical head's data cannot fit (`tests/tests/rotary_truth.rs`).
//!
//! **Runs**: C: combination 1 at (L1, H1) radial, tangential and axial; 2 at (L2, H1); 3 at
//! (L1, H3). B: combination 1 at (L1, H1), 2 at (L2, H1), each radial, tangential, axial.
//!
//! **What the runs determine.** For C, eq. (9) gives per angle
//! r_j = cos γ (δx + H_j εy) + sin γ (δy − H_j εx) (no L: radial runs at L1 and L2 must agree),
//! t_j = L_j εz + cos γ (δy − H_j εx) − sin γ (δx + H_j εy), a = δz. Hence without numbers for
//! L and H only δz(γ), (L2 − L1)·εz(γ) = t2 − t1 and (H3 − H1)·(εx, εy)(γ) (from r3 − r1,
//! t3 − t1) are identifiable; δx, δy need H1 and εz needs L2 − L1. For B (H = 0):
//! r = sin β δx + cos β δz, t_j = L_j εy + sin β δz − cos β δx, a_j = δy + L_j(εx cos β − εz sin β):
//! per angle εx and εz enter only as εx cos β − εz sin β, so the paper's per-angle solution for B
//! is rank-deficient; a Fourier fit over the swing range separates them in part. A δ or ε that
//! turns with the head (δ = R_y(β)·v, v in the XZ plane) moves both balls the same in the head's
//! frame and only shifts each run's zero: the Fourier fit reports those harmonic pairs as
//! undetermined. An axis line offset by o (or tilted by t) gives δ = (I − R_y(β))·o: its
//! constant term o is what the runs determine.
//!
//! **Setup terms.** Every re-installation of the bar has its own zero (a constant per run), and
//! the centre of the circle the spindle ball describes is never exactly on the axis: a constant
//! (δx, δy) offset, which produces a once-per-revolution term of the same amplitude in the
//! radial and tangential runs, 90° apart. [`harmonics`] measures it; the least-squares fits carry
//! one offset per run and report what stays undetermined.
use std::path::{Path, PathBuf};

use serde_json::{json, Value};

use crate::numerics::lsq::{least_squares, LsqFit, LsqOptions, Problem};
use crate::{Error, Result};

/// The error names, in parameter order; δ in mm, ε in rad.
pub const ERROR_NAMES: [&str; 6] = ["dx", "dy", "dz", "ex", "ey", "ez"];

/// Which rotary axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Axis {
    /// C turntable (about Z).
    C,
    /// B swinging head (about Y).
    B,
}

/// Direction in which the bar was installed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    Radial,
    Tangential,
    Axial,
}

impl Kind {
    fn parse(s: &str) -> Option<Kind> {
        match s {
            "radial" => Some(Kind::Radial),
            "tangential" => Some(Kind::Tangential),
            "axial" => Some(Kind::Axial),
            _ => None,
        }
    }
}

/// Installation geometry of a run: distance L (mm) of the ball from the axis and its height H
/// (mm) along the axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub l_mm: f64,
    pub h_mm: f64,
}

/// The DBB length change (mm) for errors e = (δx, δy, δz mm; εx, εy, εz rad) at angle
/// `angle_rad`, bar installed as `kind` at `place` (eq. 9 for C; derived for B, see module doc).
pub fn length_change(
    axis: Axis,
    e: &[f64; 6],
    angle_rad: f64,
    kind: Kind,
    place: Placement,
) -> f64 {
    sensitivity(axis, angle_rad, kind, place)
        .iter()
        .zip(e)
        .map(|(a, b)| a * b)
        .sum()
}

/// d(length change)/d(error) for each of the six errors: the model is linear in them.
pub fn sensitivity(axis: Axis, angle_rad: f64, kind: Kind, place: Placement) -> [f64; 6] {
    let (s, c) = angle_rad.sin_cos();
    let (l, h) = (place.l_mm, place.h_mm);
    let (p, dir) = match axis {
        Axis::C => {
            let p = [l * c, l * s, h];
            let dir = match kind {
                Kind::Radial => [c, s, 0.0],
                Kind::Tangential => [-s, c, 0.0],
                Kind::Axial => [0.0, 0.0, 1.0],
            };
            (p, dir)
        }
        Axis::B => {
            let p = [-l * s, h, -l * c];
            let dir = match kind {
                Kind::Radial => [s, 0.0, c],
                Kind::Tangential => [-c, 0.0, s],
                Kind::Axial => [0.0, 1.0, 0.0],
            };
            (p, dir)
        }
    };
    // ΔP·n = δ·n + (ε × P)·n = δ·n + ε·(P × n).
    let pxn = [
        p[1] * dir[2] - p[2] * dir[1],
        p[2] * dir[0] - p[0] * dir[2],
        p[0] * dir[1] - p[1] * dir[0],
    ];
    [dir[0], dir[1], dir[2], pxn[0], pxn[1], pxn[2]]
}

/// One measured run: a column of the table.
#[derive(Debug, Clone)]
pub struct Run {
    pub column: String,
    pub combination: usize,
    pub kind: Kind,
    pub values_mm: Vec<f64>,
}

/// A table of runs: `angle_deg` then columns `dl<combination>_<radial|tangential|axial>_mm`.
#[derive(Debug, Clone)]
pub struct Table {
    pub path: PathBuf,
    pub angles_deg: Vec<f64>,
    pub runs: Vec<Run>,
}

/// Read a runs table (see [`Table`]). A last row repeating the first angle plus 360° (the C
/// table's 360° line) is kept as data.
pub fn read_table(path: &Path) -> Result<Table> {
    runs_table(crate::table::Table::open_with(
        path,
        crate::fsio::Limit::Table,
    )?)
}

/// [`read_table`] on text already read.
pub fn parse_table(path: &Path, text: &str) -> Result<Table> {
    runs_table(crate::table::Table::from_text(path, text)?)
}

fn runs_table(mut t: crate::table::Table) -> Result<Table> {
    let path = t.path().to_path_buf();
    let names: Vec<String> = t.names().to_vec();
    if names.first().map(String::as_str) != Some("angle_deg") {
        let first = t.optional(&names[0]).expect("a name of the header");
        return Err(t.header_error(
            Some(&first),
            format!(
                "first column must be `angle_deg`, found `{}`",
                crate::table::shown(&names[0])
            ),
        ));
    }
    let mut runs = Vec::new();
    let mut cols = vec![];
    for name in names.iter().skip(1) {
        let col = t.optional(name).expect("a name of the header");
        let parsed = name
            .strip_prefix("dl")
            .and_then(|r| r.strip_suffix("_mm"))
            .and_then(|r| r.split_once('_'))
            .and_then(|(c, k)| Some((c.parse::<usize>().ok()?, Kind::parse(k)?)));
        let Some((combination, kind)) = parsed else {
            return Err(t.header_error(
                Some(&col),
                format!(
                    "column `{}` is not `dl<combination>_<radial|tangential|axial>_mm`",
                    crate::table::shown(name)
                ),
            ));
        };
        cols.push(col);
        runs.push(Run {
            column: name.to_string(),
            combination,
            kind,
            values_mm: Vec::new(),
        });
    }
    if runs.is_empty() {
        return Err(t.header_error(None, "no run columns after angle_deg"));
    }
    let angle_col = t.optional("angle_deg").expect("checked above");
    let mut angles = Vec::new();
    while let Some(row) = t.next_row()? {
        angles.push(row.number(&angle_col)?);
        for (run, c) in runs.iter_mut().zip(&cols) {
            run.values_mm.push(row.number(c)?);
        }
    }
    let distinct = distinct_angles(&angles);
    if distinct < 5 {
        return Err(t.header_error(
            Some(&angle_col),
            format!(
                "only {distinct} distinct angles: the per-angle and Fourier identifications need at least 5 (the paper uses 18-21)"
            ),
        ));
    }
    Ok(Table {
        path,
        angles_deg: angles,
        runs,
    })
}

/// Number of distinct angles (degrees, modulo 360°, to 1e-6°).
pub fn distinct_angles(angles_deg: &[f64]) -> usize {
    let mut distinct: Vec<i64> = angles_deg
        .iter()
        .map(|a| ((a.rem_euclid(360.0)) * 1e6).round() as i64 % 360_000_000)
        .collect();
    distinct.sort_unstable();
    distinct.dedup();
    distinct.len()
}

/// The highest Fourier order [`analyse`] accepts for a table: each error's series needs fewer
/// coefficients than there are distinct angles, 2·order + 1 ≤ distinct angles.
pub fn max_order(table: &Table) -> usize {
    (distinct_angles(&table.angles_deg).saturating_sub(1)) / 2
}

/// The placement of a run from the combination table of seed 002, or None if a needed number
/// was not given. Axial runs on C are at L = 0 (eq. 11).
pub fn placement(axis: Axis, run: &Run, g: &Geometry) -> Option<Placement> {
    let (l, h) = match (axis, run.combination) {
        (_, 1) => (g.l1_mm?, g.h1_mm?),
        (_, 2) => (g.l2_mm?, g.h1_mm?),
        (Axis::C, 3) => (g.l1_mm?, g.h3_mm?),
        _ => return None,
    };
    let l = if axis == Axis::C && run.kind == Kind::Axial {
        0.0
    } else {
        l
    };
    Some(Placement { l_mm: l, h_mm: h })
}

/// The installation distances, when known.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Geometry {
    pub l1_mm: Option<f64>,
    pub l2_mm: Option<f64>,
    pub h1_mm: Option<f64>,
    pub h3_mm: Option<f64>,
    /// The axis turns opposite to the paper's matrices (eq. 6): the model is evaluated at −angle.
    pub reversed: bool,
}

impl Geometry {
    fn model_angle(&self, angle_deg: f64) -> f64 {
        if self.reversed {
            -angle_deg.to_radians()
        } else {
            angle_deg.to_radians()
        }
    }
}

/// Mean and first harmonic of one run: y ≈ mean + cos_mm cos γ + sin_mm sin γ + rest.
#[derive(Debug, Clone, PartialEq)]
pub struct Harmonics {
    pub column: String,
    pub mean_mm: f64,
    pub cos_mm: f64,
    pub sin_mm: f64,
    /// Largest |rest| after removing mean and first harmonic (mm).
    pub rest_max_mm: f64,
}

/// Least-squares mean and first harmonic of every run (the 360° repeat row included as data).
pub fn harmonics(table: &Table) -> Vec<Harmonics> {
    table
        .runs
        .iter()
        .map(|run| {
            let rows: Vec<[f64; 3]> = table
                .angles_deg
                .iter()
                .map(|a| {
                    let (s, c) = a.to_radians().sin_cos();
                    [1.0, c, s]
                })
                .collect();
            let x = solve_small(&rows, &run.values_mm);
            let rest_max = rows
                .iter()
                .zip(&run.values_mm)
                .map(|(r, y)| (y - r[0] * x[0] - r[1] * x[1] - r[2] * x[2]).abs())
                .fold(0.0, f64::max);
            Harmonics {
                column: run.column.clone(),
                mean_mm: x[0],
                cos_mm: x[1],
                sin_mm: x[2],
                rest_max_mm: rest_max,
            }
        })
        .collect()
}

/// The table with each run's mean and first harmonic removed: what is left once the per-run
/// zero and the centring (set-up) terms are taken out, as DBB software does before analysis.
pub fn without_setup(table: &Table) -> Table {
    let h = harmonics(table);
    let mut t = table.clone();
    for (run, hh) in t.runs.iter_mut().zip(&h) {
        for (y, a) in run.values_mm.iter_mut().zip(&table.angles_deg) {
            let (s, c) = a.to_radians().sin_cos();
            *y -= hh.mean_mm + hh.cos_mm * c + hh.sin_mm * s;
        }
    }
    t
}

/// Least squares for a 3-column linear design (mean, cos, sin), by the shared engine: a couple
/// of Levenberg-Marquardt steps solve it to rounding, and a design the angles cannot resolve
/// (too few distinct angles) gets the minimum-norm answer instead of a failed solve.
fn solve_small(rows: &[[f64; 3]], y: &[f64]) -> [f64; 3] {
    struct Linear<'a> {
        rows: &'a [[f64; 3]],
        y: &'a [f64],
    }
    impl Problem for Linear<'_> {
        fn n_params(&self) -> usize {
            3
        }
        fn n_residuals(&self) -> usize {
            self.rows.len()
        }
        fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for (i, (r, &yi)) in self.rows.iter().zip(self.y).enumerate() {
                visit(i, r[0] * p[0] + r[1] * p[1] + r[2] * p[2] - yi, r);
            }
        }
    }
    // parse_table admits only finite values, so the engine cannot fail on non-finite residuals;
    // an empty run (no rows) has no harmonics: NaN says so rather than a made-up zero.
    match least_squares(&Linear { rows, y }, &[0.0; 3], &LsqOptions::default()) {
        Ok(fit) => [fit.params[0], fit.params[1], fit.params[2]],
        Err(_) => [f64::NAN; 3],
    }
}

/// A constant centre offset (δx, δy) fitted to the first harmonics of all radial and tangential
/// runs of a C table: the once-per-revolution term explained as a setup/axis-location offset.
#[derive(Debug, Clone, PartialEq)]
pub struct Centring {
    /// +1 if the data follow eq. (9) with γ as printed, −1 if with −γ (C turning the other way).
    pub sense: f64,
    pub dx_mm: f64,
    pub dy_mm: f64,
    /// Largest misfit of the predicted first-harmonic coefficients (mm).
    pub misfit_mm: f64,
    /// The same misfit for the other sense, for comparison.
    pub other_sense_misfit_mm: f64,
}

/// Fit [`Centring`] for a C table: with sense σ, a constant (δx, δy) gives radial
/// cos δx + σ sin δy ... i.e. r = δx cos γ + σ δy sin γ and t = δy cos γ − σ δx sin γ.
pub fn centring(h: &[Harmonics], table: &Table) -> Option<Centring> {
    let fit = |sense: f64| {
        // Unknowns δx, δy; each radial run gives (cos: δx, sin: σδy), tangential (cos: δy, sin: −σδx).
        let (mut sx, mut nx, mut sy, mut ny) = (0.0, 0, 0.0, 0);
        for (hh, run) in h.iter().zip(&table.runs) {
            match run.kind {
                Kind::Radial => {
                    sx += hh.cos_mm;
                    nx += 1;
                    sy += sense * hh.sin_mm;
                    ny += 1;
                }
                Kind::Tangential => {
                    sy += hh.cos_mm;
                    ny += 1;
                    sx += -sense * hh.sin_mm;
                    nx += 1;
                }
                Kind::Axial => {}
            }
        }
        if nx == 0 || ny == 0 {
            return None;
        }
        let (dx, dy) = (sx / nx as f64, sy / ny as f64);
        let mut misfit = 0.0f64;
        for (hh, run) in h.iter().zip(&table.runs) {
            let (pc, ps) = match run.kind {
                Kind::Radial => (dx, sense * dy),
                Kind::Tangential => (dy, -sense * dx),
                Kind::Axial => continue,
            };
            misfit = misfit
                .max((hh.cos_mm - pc).abs())
                .max((hh.sin_mm - ps).abs());
        }
        Some((dx, dy, misfit))
    };
    let (a, b) = (fit(1.0)?, fit(-1.0)?);
    let (sense, best, other) = if a.2 <= b.2 {
        (1.0, a, b)
    } else {
        (-1.0, b, a)
    };
    Some(Centring {
        sense,
        dx_mm: best.0,
        dy_mm: best.1,
        misfit_mm: best.2,
        other_sense_misfit_mm: other.2,
    })
}

/// Max, min and mean of a series (the paper's Table 3/4 rows).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Summary {
    pub max: f64,
    pub min: f64,
    pub avg: f64,
}

fn summary(v: &[f64]) -> Summary {
    Summary {
        max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        min: v.iter().copied().fold(f64::INFINITY, f64::min),
        avg: v.iter().sum::<f64>() / v.len() as f64,
    }
}

/// A quantity identifiable without numeric L and H (see module doc), one value per table row,
/// its unit in the name: e.g. "dz_um" (C: the axial run) or "(L2-L1)*ez_um" (C: t2 − t1).
#[derive(Debug, Clone)]
pub struct Combination {
    pub name: String,
    /// Formula in terms of the runs.
    pub formula: String,
    pub values_um: Vec<f64>,
}

/// The combinations of the six errors that the runs determine without numeric L and H.
pub fn scale_free_combinations(axis: Axis, table: &Table) -> Vec<Combination> {
    let col = |c: usize, k: Kind| {
        table
            .runs
            .iter()
            .find(|r| r.combination == c && r.kind == k)
            .map(|r| &r.values_mm)
    };
    let ang: Vec<(f64, f64)> = table
        .angles_deg
        .iter()
        .map(|a| a.to_radians().sin_cos())
        .collect();
    let mut out = Vec::new();
    let mut push = |name: &str, formula: &str, v: Vec<f64>| {
        out.push(Combination {
            name: name.into(),
            formula: formula.into(),
            values_um: v.iter().map(|x| x * 1e3).collect(),
        })
    };
    match axis {
        Axis::C => {
            if let Some(a1) = col(1, Kind::Axial) {
                push("dz_um", "axial run 1 (eq. 14: ΔZ1 = Δla1)", a1.clone());
            }
            if let (Some(t1), Some(t2)) = (col(1, Kind::Tangential), col(2, Kind::Tangential)) {
                push(
                    "(L2-L1)*ez_um",
                    "t2 − t1",
                    t2.iter().zip(t1).map(|(a, b)| a - b).collect(),
                );
            }
            if let (Some(r1), Some(r2)) = (col(1, Kind::Radial), col(2, Kind::Radial)) {
                push(
                    "r2-r1_um (model: 0)",
                    "r2 − r1: radial runs do not depend on L, so this is setup",
                    r2.iter().zip(r1).map(|(a, b)| a - b).collect(),
                );
            }
            if let (Some(r1), Some(t1), Some(r3), Some(t3)) = (
                col(1, Kind::Radial),
                col(1, Kind::Tangential),
                col(3, Kind::Radial),
                col(3, Kind::Tangential),
            ) {
                let dr: Vec<f64> = r3.iter().zip(r1).map(|(a, b)| a - b).collect();
                let dt: Vec<f64> = t3.iter().zip(t1).map(|(a, b)| a - b).collect();
                push(
                    "(H3-H1)*ex_um",
                    "−(sin γ (r3 − r1) + cos γ (t3 − t1))",
                    ang.iter()
                        .zip(dr.iter().zip(&dt))
                        .map(|(&(s, c), (r, t))| -(s * r + c * t))
                        .collect(),
                );
                push(
                    "(H3-H1)*ey_um",
                    "cos γ (r3 − r1) − sin γ (t3 − t1)",
                    ang.iter()
                        .zip(dr.iter().zip(&dt))
                        .map(|(&(s, c), (r, t))| c * r - s * t)
                        .collect(),
                );
            }
        }
        Axis::B => {
            if let (Some(t1), Some(t2)) = (col(1, Kind::Tangential), col(2, Kind::Tangential)) {
                push(
                    "(L2-L1)*ey_um",
                    "t2 − t1",
                    t2.iter().zip(t1).map(|(a, b)| a - b).collect(),
                );
            }
            if let (Some(a1), Some(a2)) = (col(1, Kind::Axial), col(2, Kind::Axial)) {
                push(
                    "(L2-L1)*(ex*cos(b)-ez*sin(b))_um",
                    "a2 − a1",
                    a2.iter().zip(a1).map(|(a, b)| a - b).collect(),
                );
            }
            if let (Some(r1), Some(r2)) = (col(1, Kind::Radial), col(2, Kind::Radial)) {
                push(
                    "r2-r1_um (model: 0)",
                    "r2 − r1: radial runs do not depend on L, so this is setup",
                    r2.iter().zip(r1).map(|(a, b)| a - b).collect(),
                );
            }
        }
    }
    out
}

/// The paper's method: the six errors at each angle by least squares over all runs (eq. 14, 19,
/// 24 stacked), needing numeric L and H. Returns per angle the fit (errors in mm and rad).
pub fn per_angle(axis: Axis, table: &Table, g: &Geometry) -> Result<Vec<LsqFit>> {
    let places = placements(axis, table, g)?;
    (0..table.angles_deg.len())
        .map(|i| {
            let gamma = g.model_angle(table.angles_deg[i]);
            let prob = PerAngle {
                rows: table
                    .runs
                    .iter()
                    .zip(&places)
                    .map(|(run, &pl)| (sensitivity(axis, gamma, run.kind, pl), run.values_mm[i]))
                    .collect(),
            };
            least_squares(&prob, &[0.0; 6], &LsqOptions::default())
        })
        .collect()
}

fn placements(axis: Axis, table: &Table, g: &Geometry) -> Result<Vec<Placement>> {
    table
        .runs
        .iter()
        .map(|run| {
            placement(axis, run, g).ok_or_else(|| {
                Error::Usage(format!(
                    "run {} needs numeric distances: give --l1, --l2{} (mm)",
                    run.column,
                    if axis == Axis::C { ", --h1, --h3" } else { "" }
                ))
            })
        })
        .collect()
}

struct PerAngle {
    rows: Vec<([f64; 6], f64)>,
}

impl Problem for PerAngle {
    fn n_params(&self) -> usize {
        6
    }
    fn n_residuals(&self) -> usize {
        self.rows.len()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        for (i, (a, y)) in self.rows.iter().enumerate() {
            let m: f64 = a.iter().zip(p).map(|(x, q)| x * q).sum();
            visit(i, m - y, a);
        }
    }
}

/// All runs at once: each error a Fourier series of order `order` in the angle, plus one zero
/// offset per run (every installation has its own zero). Parameter layout: error k, coefficient
/// j (0: constant, 2h−1: cos hγ, 2h: sin hγ) at k·(2·order+1) + j, then the run offsets.
pub struct FourierProblem {
    order: usize,
    /// (run index, angle rad, sensitivity, value mm)
    rows: Vec<(usize, f64, [f64; 6], f64)>,
    n_runs: usize,
    run_offsets: bool,
}

impl FourierProblem {
    pub fn new(
        axis: Axis,
        table: &Table,
        g: &Geometry,
        order: usize,
        run_offsets: bool,
    ) -> Result<Self> {
        let places = placements(axis, table, g)?;
        let mut rows = Vec::new();
        for (j, (run, &pl)) in table.runs.iter().zip(&places).enumerate() {
            for (i, &a) in table.angles_deg.iter().enumerate() {
                let gamma = g.model_angle(a);
                rows.push((
                    j,
                    gamma,
                    sensitivity(axis, gamma, run.kind, pl),
                    run.values_mm[i],
                ));
            }
        }
        Ok(FourierProblem {
            order,
            rows,
            n_runs: table.runs.len(),
            run_offsets,
        })
    }

    fn per_error(&self) -> usize {
        2 * self.order + 1
    }

    fn basis(&self, gamma: f64, out: &mut [f64]) {
        out[0] = 1.0;
        for h in 1..=self.order {
            let (s, c) = (h as f64 * gamma).sin_cos();
            out[2 * h - 1] = c;
            out[2 * h] = s;
        }
    }

    /// The six errors at angle γ from fitted coefficients.
    pub fn errors_at(&self, p: &[f64], gamma: f64) -> [f64; 6] {
        let m = self.per_error();
        let mut b = vec![0.0; m];
        self.basis(gamma, &mut b);
        let mut e = [0.0; 6];
        for (k, ek) in e.iter_mut().enumerate() {
            *ek = (0..m).map(|j| p[k * m + j] * b[j]).sum();
        }
        e
    }

    /// Name of parameter `i`, e.g. `ez.cos2`, `offset.dl1_axial_mm`.
    pub fn param_name(&self, i: usize, table: &Table) -> String {
        let m = self.per_error();
        if i < 6 * m {
            let (k, j) = (i / m, i % m);
            let coef = match j {
                0 => "const".to_string(),
                j if j % 2 == 1 => format!("cos{}", j.div_ceil(2)),
                j => format!("sin{}", j / 2),
            };
            format!("{}.{}", ERROR_NAMES[k], coef)
        } else {
            format!("offset.{}", table.runs[i - 6 * m].column)
        }
    }
}

impl Problem for FourierProblem {
    fn n_params(&self) -> usize {
        6 * self.per_error() + if self.run_offsets { self.n_runs } else { 0 }
    }
    fn n_residuals(&self) -> usize {
        self.rows.len()
    }
    fn eval(&self, p: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
        let m = self.per_error();
        let n = self.n_params();
        let mut g = vec![0.0; n];
        let mut b = vec![0.0; m];
        for (i, &(run, gamma, sens, y)) in self.rows.iter().enumerate() {
            self.basis(gamma, &mut b);
            g.iter_mut().for_each(|x| *x = 0.0);
            let mut model = 0.0;
            for k in 0..6 {
                for j in 0..m {
                    let d = sens[k] * b[j];
                    g[k * m + j] = d;
                    model += d * p[k * m + j];
                }
            }
            if self.run_offsets {
                g[6 * m + run] = 1.0;
                model += p[6 * m + run];
            }
            visit(i, model - y, &g);
        }
    }
}

const SCALE: [f64; 6] = [1e3, 1e3, 1e3, 1e5, 1e5, 1e5];
const UNIT: [&str; 6] = ["um", "um", "um", "1e-5rad", "1e-5rad", "1e-5rad"];

/// Everything `jdbb rotary` reports, as JSON (see README): harmonics per run, the centring
/// offset (C), the scale-free combinations with Table 3/4-style max/min/avg, and with numeric
/// distances the paper's per-angle solution and the Fourier fit.
pub fn analyse(axis: Axis, table: &Table, g: &Geometry, order: usize) -> Result<Value> {
    let h = harmonics(table);
    let mut v = json!({
        "axis": match axis { Axis::C => "c", Axis::B => "b" },
        "model_angle_reversed": g.reversed,
        "n_angles": table.angles_deg.len(),
        "harmonics": h.iter().map(|x| json!({
            "run": x.column,
            "mean_um": x.mean_mm * 1e3,
            "cos1_um": x.cos_mm * 1e3,
            "sin1_um": x.sin_mm * 1e3,
            "amplitude1_um": x.cos_mm.hypot(x.sin_mm) * 1e3,
            "rest_max_um": x.rest_max_mm * 1e3,
        })).collect::<Vec<_>>(),
        "scale_free": scale_free_combinations(axis, table).iter().map(|c| {
            let s = summary(&c.values_um);
            json!({"name": c.name, "formula": c.formula, "max": s.max, "min": s.min, "avg": s.avg, "values": c.values_um})
        }).collect::<Vec<_>>(),
    });
    if axis == Axis::C {
        if let Some(c) = centring(&h, table) {
            v["centring"] = json!({
                "sense": c.sense,
                "dx_um": c.dx_mm * 1e3,
                "dy_um": c.dy_mm * 1e3,
                "offset_um": c.dx_mm.hypot(c.dy_mm) * 1e3,
                "misfit_um": c.misfit_mm * 1e3,
                "other_sense_misfit_um": c.other_sense_misfit_mm * 1e3,
            });
        }
    }
    let known = placements(axis, table, g).is_ok();
    if known {
        let fits = per_angle(axis, table, g)?;
        let mut rows = Vec::new();
        for k in 0..6 {
            let vals: Vec<f64> = fits.iter().map(|f| f.params[k] * SCALE[k]).collect();
            let s = summary(&vals);
            let undetermined = fits.iter().filter(|f| f.sigma[k].is_none()).count();
            rows.push(json!({"error": ERROR_NAMES[k], "unit": UNIT[k], "max": s.max, "min": s.min, "avg": s.avg,
                "undetermined_at_angles": undetermined}));
        }
        // Per angle, the norm of the residuals of all runs (the runs over-determine the errors).
        let worst = fits.iter().map(|f| f.ssr.sqrt()).fold(0.0, f64::max);
        v["per_angle"] = json!({"summary": rows, "max_residual_norm_um": worst * 1e3});
        let prob = FourierProblem::new(axis, table, g, order, true)?;
        let n = prob.n_params();
        let fit = least_squares(&prob, &vec![0.0; n], &LsqOptions::default())?;
        let mut rows = Vec::new();
        let per: Vec<[f64; 6]> = table
            .angles_deg
            .iter()
            .map(|&a| prob.errors_at(&fit.params, g.model_angle(a)))
            .collect();
        let m = prob.per_error();
        for k in 0..6 {
            let vals: Vec<f64> = per.iter().map(|e| e[k] * SCALE[k]).collect();
            let s = summary(&vals);
            let undetermined: Vec<String> = (k * m..(k + 1) * m)
                .filter(|&i| fit.sigma[i].is_none())
                .map(|i| prob.param_name(i, table))
                .collect();
            rows.push(json!({"error": ERROR_NAMES[k], "unit": UNIT[k], "max": s.max, "min": s.min, "avg": s.avg,
                "undetermined_coefficients": undetermined}));
        }
        let coef: Vec<Value> = (0..n)
            .map(|i| {
                let k = i / prob.per_error();
                let sc = if k < 6 { SCALE[k] } else { 1e3 };
                json!({"name": prob.param_name(i, table), "value": fit.params[i] * sc,
                    "sigma": fit.sigma[i].map(|s| s * sc), "unit": if k < 6 { UNIT[k] } else { "um" }})
            })
            .collect();
        v["fourier"] = json!({
            "order": order,
            "summary": rows,
            "coefficients": coef,
            "undetermined": fit.undetermined.iter().map(|grp| grp.iter().map(|&i| prob.param_name(i, table)).collect::<Vec<_>>()).collect::<Vec<_>>(),
            "rms_residual_um": fit.rms * 1e3,
            "dof": fit.dof,
            "singular_values": fit.singular_values,
        });
    }
    Ok(v)
}

pub fn report_text(v: &Value) -> String {
    let f = |x: &Value| x.as_f64().unwrap_or(f64::NAN);
    let mut s = format!(
        "{} axis, {} angles\nper run: mean and once-per-revolution term (µm)\n",
        v["axis"].as_str().unwrap_or("?").to_uppercase(),
        v["n_angles"]
    );
    for h in v["harmonics"].as_array().into_iter().flatten() {
        s += &format!(
            "  {:<20} mean {:8.2}  1st harmonic {:8.2} (cos {:8.2}, sin {:8.2})  rest max {:6.2}\n",
            h["run"].as_str().unwrap_or(""),
            f(&h["mean_um"]),
            f(&h["amplitude1_um"]),
            f(&h["cos1_um"]),
            f(&h["sin1_um"]),
            f(&h["rest_max_um"])
        );
    }
    if let Some(c) = v.get("centring") {
        s += &format!(
            "centring: a constant centre offset (dx, dy) = ({:.1}, {:.1}) µm, |offset| {:.1} µm, explains every radial and\n  tangential first harmonic to {:.1} µm with C turning {} eq. (9) (the other sense misfits by {:.1} µm)\n",
            f(&c["dx_um"]),
            f(&c["dy_um"]),
            f(&c["offset_um"]),
            f(&c["misfit_um"]),
            if f(&c["sense"]) > 0.0 { "as in" } else { "opposite to" },
            f(&c["other_sense_misfit_um"])
        );
    }
    s += "identifiable without numeric L, H (max / min / avg, µm):\n";
    for c in v["scale_free"].as_array().into_iter().flatten() {
        s += &format!(
            "  {:<34} {:8.3} {:8.3} {:8.3}   = {}\n",
            c["name"].as_str().unwrap_or(""),
            f(&c["max"]),
            f(&c["min"]),
            f(&c["avg"]),
            c["formula"].as_str().unwrap_or("")
        );
    }
    for (key, title) in [
        ("per_angle", "paper's per-angle least squares"),
        ("fourier", "Fourier fit of all runs"),
    ] {
        if let Some(p) = v.get(key) {
            s += &format!("{title} (max / min / avg):\n");
            for r in p["summary"].as_array().into_iter().flatten() {
                s += &format!(
                    "  {:<3} {:9.3} {:9.3} {:9.3} {}{}\n",
                    r["error"].as_str().unwrap_or(""),
                    f(&r["max"]),
                    f(&r["min"]),
                    f(&r["avg"]),
                    crate::units::human(r["unit"].as_str().unwrap_or("")),
                    match (
                        r.get("undetermined_at_angles").and_then(Value::as_u64),
                        r.get("undetermined_coefficients").and_then(Value::as_array),
                    ) {
                        (Some(n), _) if n > 0 => format!("  (undetermined at {n} angles)"),
                        (_, Some(c)) if !c.is_empty() => format!(
                            "  (not determined: {}; shown is one of many fits)",
                            c.iter()
                                .filter_map(Value::as_str)
                                .collect::<Vec<_>>()
                                .join(" ")
                        ),
                        _ => String::new(),
                    }
                );
            }
            if let Some(r) = p.get("rms_residual_um").and_then(Value::as_f64) {
                s += &format!("  RMS residual {r:.2} µm\n");
            }
            if let Some(c) = p.get("coefficients").and_then(Value::as_array) {
                let det: Vec<String> = c
                    .iter()
                    .filter(|x| x["sigma"].is_f64())
                    .map(|x| {
                        format!(
                            "{} {} {}",
                            x["name"].as_str().unwrap_or(""),
                            crate::units::format_estimate(f(&x["value"]), x["sigma"].as_f64()),
                            crate::units::human(x["unit"].as_str().unwrap_or(""))
                        )
                    })
                    .collect();
                s += &format!("  determined coefficients: {}\n", det.join(", "));
                s += &format!(
                    "  {} of {} coefficients are undetermined (a per-run zero offset, ε·H and δ terms trade off)\n",
                    c.len() - det.len(),
                    c.len()
                );
            }
        }
    }
    if v.get("per_angle").is_none() {
        s += "give --l1 --l2 --h1 (and --h3 for C) in mm for the six errors themselves\n";
    }
    s.trim_end().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Eq. (9) of the paper, term by term, against the general δ + ε × P model.
    #[test]
    fn c_model_is_eq9() {
        let e = [1e-3, -2e-3, 3e-3, 2e-5, -3e-5, 4e-5];
        let (l, h) = (150.0, 80.0);
        for k in 0..12 {
            let g = (k as f64 * 30.0).to_radians();
            let (s, c) = g.sin_cos();
            let dx = -l * s * e[5] + h * e[4] + e[0];
            let dy = l * c * e[5] - h * e[3] + e[1];
            let dz = l * (-e[4] * c + e[3] * s) + e[2];
            let pl = Placement { l_mm: l, h_mm: h };
            let r = length_change(Axis::C, &e, g, Kind::Radial, pl);
            let t = length_change(Axis::C, &e, g, Kind::Tangential, pl);
            let a = length_change(Axis::C, &e, g, Kind::Axial, pl);
            // Eq. (13): ΔX = Δlr cos γ − Δlt sin γ, ΔY = Δlr sin γ + Δlt cos γ.
            assert!((r * c - t * s - dx).abs() < 1e-15);
            assert!((r * s + t * c - dy).abs() < 1e-15);
            assert!((a - dz).abs() < 1e-15);
        }
    }
}
