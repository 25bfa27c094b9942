//! Saddle (min-max) synthesis of the RRSS test linkage with the constraints g1–g13 (seed 004,
//! §3.2, eq. 18-23), the method behind Table 2.
//!
//! # The programme as printed, and why it is re-derived here
//!
//! Eq. (18), the *first saddle programme*: for given positions (θ1⁽ⁱ⁾, θ2⁽ⁱ⁾) of the table, the
//! table point F traces points F⁽ⁱ⁾ in the frame; the saddle sphere is the sphere (centre E,
//! radius d) that minimises max_i |‖E − F⁽ⁱ⁾‖ − d| (error Δ_ss). Eq. (19), the *second saddle
//! programme*: choose the table point Z = F_m minimising Δ_ss(Z), subject to g_j ≤ 0. The paper
//! does not print the positions it fed in, and the two programmes as printed cannot by themselves
//! produce Table 2: with positions of a prescribed motion law, Δ_ss → 0 is reached by putting F on
//! the A/C intersection (a ball that does not move, a useless test), and the motion the test
//! finally runs is not the prescribed one but the RRSS's own (eq. 10), on which the bar length is
//! constant, so Δ_ss = 0 for *every* RRSS. The content of the synthesis is therefore in what the
//! paper says its result is (§3.2, §5.1): "two extreme positions and constraint conditions" — the
//! rocker's dead points at the ends of the required A range, C turning fully, every g_j ≤ 0.
//!
//! Here the two levels are kept, with each level's task stated exactly:
//!
//! 1. *First level (the role of eq. 18)*: for a table point Z = (s2, a2) and a bar length d, the
//!    frame point E = (s0, a0, θA0) and the C origin θC0 are fixed by the extreme positions:
//!    dead points (eq. 13-15) at A_min and A_max, the branches of eq. (9) just meeting so that C
//!    turns fully over the whole range, the lower dead point at C = 0 ([`first_level`]; on its own
//!    it is the dead-point synthesis of [`super::synth`]). The sphere about E of radius d then
//!    carries F's whole trajectory: Δ_ss = 0 (checked by running eq. 18 itself, minimax, on the
//!    trajectory: [`sphere_fit`]). Eq. (25), which turns (E, F_m) into the named parameters,
//!    swaps θA0 and θC0 against eq. (7); eq. (7) is followed here (θC0 is F's angle on the table).
//! 2. *Second level (the role of eq. 19)*: choose Z minimising, over the motion, the largest
//!    utilisation of the ball cups — the saddle (min over design, max over motion) of
//!    max(g1, g2), the bar's angle to each cup axis beyond its limit (eq. 20) —
//!    subject to g3–g12 ≤ 0 (collision with the table, spindle travel, table radius, ball
//!    height) and g13 (d from the bar series, each length solved in turn, the best kept).
//!
//! Solver: the second level has two unknowns, the table-ball height s2 (box g11, g12) and the
//! spindle ball's offset s0 along A (box g4, g5); the first level gives a2, a0, θA0, θC0 for
//! each. (In the chart (s2, a2) the realisable set ends at a fold where the mirror solutions ±s0
//! merge, and a pattern search stalls on that curved edge; in (s2, s0) the same point is
//! interior.) A coarse scan of the box, warm-started along a serpentine path, finds the best
//! feasible cell; a generalised pattern search (8 directions, step halved on failure, infeasible
//! points rejected — the "extreme barrier") refines it to `tolerance_mm`. Every point it returns
//! satisfies every g; local optimality is checked by the tests against random feasible
//! perturbations, and the result does not depend on the assumed cup limits unless they make a
//! design infeasible (the objective is max(g1, g2) with equal limits).
//!
//! What comes out (default limits, A −110..0°): d = 300 mm (100 mm breaks the cup limits, 150 mm
//! is feasible with worse cup angles), the table ball at its lowest allowed height (g11 active)
//! and the spindle ball in the plane of the C axis (s0 = 0). That symmetric design has a closed
//! form, which the tests check the search against: with a1 = 0, α12 = 270°, s0 = 0 the bar
//! length is constant when F·x0 = s2 (the branches meeting), the A range is then 4·atan(a2/s2)
//! and d² = a0² + s2² + a2² − 2·a0·s2, so a2 = s2·tan(ΔA/4), a0 = s2 + √(d² − a2²) and θA0 is
//! the middle of the range. Table 2's table ball (s2 = 80, a2 = 30 < 80·tan 27.5° = 41.6) is
//! too close to the C axis for the symmetric design, so its spindle ball must move along A
//! (s0 = 96.31) to reach the range — at the price of larger cup angles (66.0° against 63.0° for
//! the symmetric design at the same height).
//!
//! Constraint conventions (all ≤ 0 when met; angles in degrees, lengths in mm):
//! - g1: angle between the bar E→F and the spindle axis (machine −Z), minus the spindle cup's
//!   limit (eq. 20: the paper's −x0 is machine −Z by eq. 24).
//! - g2: angle between the bar F→E and the table normal z2, minus the table cup's limit (eq. 20
//!   prints R_EF·z2; with the table ball on top of the table the bar leaves it along F→E).
//! - g3: the bar must stay outside the table (eq. 21). The paper intersects the bar with the
//!   table disc; here the table is a solid cylinder of radius r_t below its top face at height
//!   `table_top_mm` along C, and g3 = clearance − min over the bar of max(height above the top,
//!   distance outside the rim), which is continuous and also keeps the bar out of the table body.
//! - g4–g9: spindle ball E within the travel (eq. 22): X = s0, Y = −a0 sin θA0 (eq. 7), height
//!   above the table top at A = 0 within the spindle-to-table distance.
//! - g10: a2 ≤ r_t; g11, g12: s2 within the ball-height limits; g13: d in the bar series.
use super::design::{design_with_grid, eq9, theta_a_for, Branch};
use super::Params;
use crate::numerics::lsq::Problem;
use crate::numerics::minimax::{minimax, MinimaxOptions};
use crate::{Error, Result};

/// Machine and instrument limits of g1–g13. The paper's Table 1 and §5 give the table radius
/// (Φ650 mm), the travel (650/650/450 mm), the spindle-to-table distance (90–540 mm) and the bar
/// (d = 300 mm nominal); the rest is not printed and is an explicit assumption (see
/// [`Limits::ASSUMED`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    /// g1: largest angle (deg) between the bar and the spindle axis the spindle cup allows.
    pub spindle_cup_deg: f64,
    /// g2: largest angle (deg) between the bar and the table normal the table cup allows.
    pub table_cup_deg: f64,
    /// g3, g10: table radius r_t (mm). Paper: Φ650 mm.
    pub table_radius_mm: f64,
    /// g3: height of the table's top face along C above the A/C common normal (mm).
    pub table_top_mm: f64,
    /// g3: least clearance between the bar axis and the table (mm).
    pub clearance_mm: f64,
    /// g4, g5: spindle ball X = s0 (mm). Paper: X travel 650 mm.
    pub spindle_x_mm: [f64; 2],
    /// g6, g7: spindle ball Y = −a0 sin θA0 (mm). Paper: Y travel 650 mm.
    pub spindle_y_mm: [f64; 2],
    /// g8, g9: spindle ball height above the table top at A = 0 (mm). Paper: spindle end face to
    /// table 90–540 mm.
    pub spindle_height_mm: [f64; 2],
    /// g11, g12: table ball height s2 along C (mm).
    pub ball_height_mm: [f64; 2],
    /// g13: the bar lengths available (mm).
    pub bar_series_mm: Vec<f64>,
}

impl Limits {
    /// Which fields are assumptions, not numbers from the paper, with the reason.
    pub const ASSUMED: [(&'static str, &'static str); 7] = [
        (
            "spindle_cup_deg",
            "not in the paper; 75° leaves the Table 2 design (max 66.0°) feasible",
        ),
        (
            "table_cup_deg",
            "not in the paper; 75° leaves the Table 2 design (max 66.0°) feasible",
        ),
        (
            "table_top_mm",
            "not in the paper; table top taken on the A axis (0 mm)",
        ),
        (
            "clearance_mm",
            "not in the paper; 10 mm between bar axis and table",
        ),
        (
            "spindle_x_mm/spindle_y_mm",
            "travel 650 mm from Table 1, assumed centred on the table: ±325 mm",
        ),
        (
            "ball_height_mm",
            "not in the paper; 40..200 mm above the A axis for the table ball (the optimum sits on the lower end, so the synthesized s2 is this assumption)",
        ),
        (
            "bar_series_mm",
            "the QC20-W series 100, 150, 300 mm (the paper names only d = 300 mm)",
        ),
    ];
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            spindle_cup_deg: 75.0,
            table_cup_deg: 75.0,
            table_radius_mm: 325.0,
            table_top_mm: 0.0,
            clearance_mm: 10.0,
            spindle_x_mm: [-325.0, 325.0],
            spindle_y_mm: [-325.0, 325.0],
            spindle_height_mm: [90.0, 540.0],
            ball_height_mm: [40.0, 200.0],
            bar_series_mm: vec![100.0, 150.0, 300.0],
        }
    }
}

/// Names of the constraints g1–g12 in the order of [`constraint_values`], with their meaning.
pub const CONSTRAINTS: [(&str, &str); 12] = [
    ("g1", "bar angle in the spindle cup (deg over limit)"),
    ("g2", "bar angle in the table cup (deg over limit)"),
    ("g3", "bar/table collision (mm inside the clearance)"),
    ("g4", "spindle X below travel"),
    ("g5", "spindle X above travel"),
    ("g6", "spindle Y below travel"),
    ("g7", "spindle Y above travel"),
    ("g8", "spindle too close to the table"),
    ("g9", "spindle too far from the table"),
    ("g10", "table ball outside the table radius"),
    ("g11", "table ball below its lowest height"),
    ("g12", "table ball above its highest height"),
];

/// θC positions per branch at which the motion is checked.
const MOTION_GRID: usize = 360;

type V3 = [f64; 3];

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn norm(a: V3) -> f64 {
    dot(a, a).sqrt()
}
fn angle_deg(a: V3, b: V3) -> f64 {
    (dot(a, b) / (norm(a) * norm(b)))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// One pose of the linkage in frame 0 of eq. (8) (z0 along A, E = (a0, 0, s0)).
struct Pose {
    e: V3,
    f: V3,
    /// Origin of the table frame: foot of the common normal on the C axis.
    o2: V3,
    /// Table normal (C axis) z2.
    z2: V3,
}

/// [M10]·v of eq. (7).
fn m10(theta1: f64, alpha: f64, v: V3) -> V3 {
    let (s1, c1) = theta1.sin_cos();
    let (sa, ca) = alpha.sin_cos();
    [
        c1 * v[0] - ca * s1 * v[1] + sa * s1 * v[2],
        s1 * v[0] + ca * c1 * v[1] - sa * c1 * v[2],
        sa * v[1] + ca * v[2],
    ]
}

fn pose(p: &Params, theta_a: f64, theta_c: f64) -> Pose {
    let (t1, t2) = p.link_angles(theta_a, theta_c);
    let a = p.alpha12_rad;
    let f = m10(
        t1,
        a,
        [p.a1_mm + p.a2_mm * t2.cos(), p.a2_mm * t2.sin(), p.s2_mm],
    );
    Pose {
        e: [p.a0_mm, 0.0, p.s0_mm],
        f,
        o2: m10(t1, a, [p.a1_mm, 0.0, 0.0]),
        z2: m10(t1, a, [0.0, 0.0, 1.0]),
    }
}

/// Machine "up" (+Z) in frame 0: the table normal at A = 0.
fn up(p: &Params) -> (V3, V3) {
    let q = pose(p, 0.0, 0.0);
    (q.z2, q.o2)
}

/// The poses of the designed motion (eq. 9-11) at bar length d, both branches.
pub fn motion(p: &Params, d_mm: f64, grid: usize) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(2 * grid);
    for b in Branch::BOTH {
        for k in 0..grid {
            let c = (k as f64 / grid as f64) * std::f64::consts::TAU;
            if let Some(a) = theta_a_for(p, d_mm, c, b) {
                out.push((a, c));
            }
        }
    }
    out
}

/// Least value along the bar E–F of max(height above the table top, distance outside the rim):
/// negative when the bar enters the table (a convex function of the position on the bar, so a
/// ternary search finds its minimum).
fn table_distance(q: &Pose, lim: &Limits) -> f64 {
    let local = |x: V3| {
        let r = sub(x, q.o2);
        let z = dot(r, q.z2);
        let perp = [r[0] - z * q.z2[0], r[1] - z * q.z2[1], r[2] - z * q.z2[2]];
        (z, norm(perp))
    };
    // ρ along the bar is not linear in t; evaluate it from the 3-D point.
    let at = |t: f64| {
        let x = [
            q.f[0] + t * (q.e[0] - q.f[0]),
            q.f[1] + t * (q.e[1] - q.f[1]),
            q.f[2] + t * (q.e[2] - q.f[2]),
        ];
        let (z, rho) = local(x);
        (z - lim.table_top_mm).max(rho - lim.table_radius_mm)
    };
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for _ in 0..40 {
        let m1 = lo + (hi - lo) / 3.0;
        let m2 = hi - (hi - lo) / 3.0;
        if at(m1) <= at(m2) {
            hi = m2;
        } else {
            lo = m1;
        }
    }
    at(0.5 * (lo + hi)).min(at(0.0)).min(at(1.0))
}

/// g1–g12 for parameters `p` and bar length d, each the worst over the designed motion (≤ 0
/// when met), in the order of [`CONSTRAINTS`]. None when the motion is empty.
pub fn constraint_values(p: &Params, d_mm: f64, lim: &Limits) -> Option<[f64; 12]> {
    constraint_values_on(p, &motion(p, d_mm, MOTION_GRID), lim)
}

fn constraint_values_on(p: &Params, poses: &[(f64, f64)], lim: &Limits) -> Option<[f64; 12]> {
    if poses.is_empty() {
        return None;
    }
    let (up, o2_at_zero) = up(p);
    let down = [-up[0], -up[1], -up[2]];
    let (mut g1, mut g2, mut clear) = (f64::NEG_INFINITY, f64::NEG_INFINITY, f64::INFINITY);
    for &(a, c) in poses {
        let q = pose(p, a, c);
        let bar = sub(q.f, q.e);
        g1 = g1.max(angle_deg(bar, down));
        g2 = g2.max(angle_deg([-bar[0], -bar[1], -bar[2]], q.z2));
        clear = clear.min(table_distance(&q, lim));
    }
    let x = p.s0_mm;
    let y = -p.a0_mm * p.theta_a0_rad.sin();
    let h = dot(sub([p.a0_mm, 0.0, p.s0_mm], o2_at_zero), up) - lim.table_top_mm;
    Some([
        g1 - lim.spindle_cup_deg,
        g2 - lim.table_cup_deg,
        lim.clearance_mm - clear,
        lim.spindle_x_mm[0] - x,
        x - lim.spindle_x_mm[1],
        lim.spindle_y_mm[0] - y,
        y - lim.spindle_y_mm[1],
        lim.spindle_height_mm[0] - h,
        h - lim.spindle_height_mm[1],
        p.a2_mm - lim.table_radius_mm,
        lim.ball_height_mm[0] - p.s2_mm,
        p.s2_mm - lim.ball_height_mm[1],
    ])
}

/// The saddle objective: max(g1, g2), the worse ball cup's angle beyond its limit (deg).
fn objective(g: &[f64; 12]) -> f64 {
    g[0].max(g[1])
}

/// Eq. (18), the first saddle programme, run as printed with d fixed by g13: the centre E of the
/// sphere of radius `d_mm` that minimises the largest normal distance of the points `pts`.
/// Returns (E, Δ_ss).
///
/// d must be given: when the A and C axes intersect (a1 = 0) every table point keeps its distance
/// to the intersection O, so F's trajectory on an RRSS lies on two spheres (about O and about E),
/// i.e. on a circle, and the spheres through it form a one-parameter family — with d free eq.
/// (18) has no unique solution (the test design's Jacobian has a zero singular value).
pub fn sphere_fit(pts: &[V3], e0: V3, d_mm: f64) -> Result<(V3, f64)> {
    struct Sphere<'a>(&'a [V3], f64);
    impl Problem for Sphere<'_> {
        fn n_params(&self) -> usize {
            3
        }
        fn n_residuals(&self) -> usize {
            self.0.len()
        }
        fn eval(&self, x: &[f64], visit: &mut dyn FnMut(usize, f64, &[f64])) {
            for (i, f) in self.0.iter().enumerate() {
                let r = sub([x[0], x[1], x[2]], *f);
                let n = norm(r);
                visit(i, n - self.1, &[r[0] / n, r[1] / n, r[2] / n]);
            }
        }
    }
    // On points that lie exactly on a sphere the error falls to rounding level, where the LP
    // can stall: fewer outer iterations then still give the converged sphere.
    let mut last = None;
    for iterations in [100, 30, 12, 6, 4, 3, 2] {
        match minimax(
            &Sphere(pts, d_mm),
            &e0,
            &MinimaxOptions {
                max_iterations: iterations,
                ..MinimaxOptions::default()
            },
        ) {
            Ok(fit) => {
                let x = &fit.params;
                return Ok(([x[0], x[1], x[2]], fit.max_abs_residual));
            }
            Err(e) => last = Some(e),
        }
    }
    Err(last.expect("at least one attempt"))
}

/// Options of [`saddle_synthesize`].
#[derive(Debug, Clone)]
pub struct SaddleOptions {
    /// Coarse scan of the (s2, s0) box: points per side.
    pub scan: usize,
    /// Largest table-ball radius a2 accepted (mm), on top of g10 (a2 ≤ r_t): to hold the
    /// ball within a fixture's reach.
    pub a2_max_mm: f64,
    /// Pattern search stops when its step in s2 and s0 is below this (mm).
    pub tolerance_mm: f64,
}

impl Default for SaddleOptions {
    fn default() -> Self {
        SaddleOptions {
            scan: 8,
            a2_max_mm: f64::INFINITY,
            tolerance_mm: 1e-3,
        }
    }
}

/// The synthesis for one bar length.
#[derive(Debug, Clone)]
pub struct SaddleAtLength {
    pub d_mm: f64,
    /// The best design, or why there is none.
    pub outcome: std::result::Result<SaddleDesign, String>,
}

/// A synthesized design and its constraint values.
#[derive(Debug, Clone)]
pub struct SaddleDesign {
    pub params: Params,
    /// The saddle objective max(g1, g2) (deg): the worst cup angle over the motion minus its
    /// limit. The worst cup angle itself is this plus the limit.
    pub objective_deg: f64,
    /// g1–g12 at the solution, [`CONSTRAINTS`] order.
    pub g: [f64; 12],
    /// Eq. (18) run on F's trajectory: the saddle sphere error (mm) — 0 up to the solver.
    pub sphere_error_mm: f64,
    /// Residual of the first-level (dead-point) conditions (mm).
    pub first_level_mm: f64,
    /// Objective evaluations (each one a first-level solve).
    pub evaluations: usize,
    /// True when a step of 10 × tolerance from the solution leaves the set of table-ball
    /// positions for which the first level has a solution: the required range can only just
    /// be covered there (an active constraint that is not one of g1–g13).
    pub at_coverage_limit: bool,
    /// True when a step of 10 × tolerance reaches a table-ball radius above `a2_max_mm`.
    pub at_a2_max: bool,
}

impl SaddleDesign {
    /// Constraints within `tol` of their bound, plus `coverage` or `a2_max` when the search
    /// stopped at the edge of the realisable set or at the a2 bound (g13, d from the series, is
    /// always active and not listed here).
    pub fn active(&self, tol: f64) -> Vec<&'static str> {
        let mut v: Vec<&'static str> = CONSTRAINTS
            .iter()
            .zip(&self.g)
            .filter(|(_, &g)| g > -tol)
            .map(|((n, _), _)| *n)
            .collect();
        if self.at_coverage_limit {
            v.push("coverage");
        }
        if self.at_a2_max {
            v.push("a2_max");
        }
        v
    }
}

/// Result of [`saddle_synthesize`]: every bar length tried, and the best.
#[derive(Debug, Clone)]
pub struct Saddle {
    pub per_length: Vec<SaddleAtLength>,
    /// Index into `per_length` of the best feasible length, if any.
    pub best: Option<usize>,
}

struct Level2<'a> {
    start: Params,
    d_mm: f64,
    a_range_deg: [f64; 2],
    lim: &'a Limits,
    a2_max_mm: f64,
    evaluations: usize,
}

/// One evaluation of the second level at (s2, a2): first level from `warm`, then g1–g12.
struct Eval {
    params: Params,
    g: [f64; 12],
    first_level_mm: f64,
}

/// Why a second-level point has no design.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Reject {
    /// The first level has no solution: the range cannot be covered from here.
    Coverage,
    /// The table-ball radius exceeds `a2_max_mm`.
    A2Max,
}

impl Level2<'_> {
    /// The design with table-ball height s2 and spindle-ball offset s0 along A (the second
    /// level's chart; a2, a0, θA0, θC0 from the first level).
    fn eval(&mut self, s2: f64, s0: f64, warm: &Params) -> Option<Eval> {
        self.try_eval(s2, s0, warm).ok()
    }

    fn try_eval(&mut self, s2: f64, s0: f64, warm: &Params) -> std::result::Result<Eval, Reject> {
        self.evaluations += 1;
        let mut start = *warm;
        start.s2_mm = s2;
        start.s0_mm = s0;
        start.a1_mm = self.start.a1_mm;
        start.alpha12_rad = self.start.alpha12_rad;
        let (params, first_level_mm) =
            first_level_for_a2(&start, self.d_mm, self.a_range_deg).ok_or(Reject::Coverage)?;
        if params.a2_mm.is_nan() || params.a2_mm <= 0.0 {
            return Err(Reject::Coverage);
        }
        if params.a2_mm > self.a2_max_mm {
            return Err(Reject::A2Max);
        }
        let g = constraint_values(&params, self.d_mm, self.lim).ok_or(Reject::Coverage)?;
        Ok(Eval {
            params,
            g,
            first_level_mm,
        })
    }
}

/// Eq. (10): the coefficients (L, M, N) of L sin θ2 + M cos θ2 + N = 0 at link angle θ1.
pub fn eq10(p: &Params, d_mm: f64, theta1_rad: f64) -> (f64, f64, f64) {
    let (sa, ca) = p.alpha12_rad.sin_cos();
    let (s1, c1) = theta1_rad.sin_cos();
    let (a0, a1, a2, s0, s2) = (p.a0_mm, p.a1_mm, p.a2_mm, p.s0_mm, p.s2_mm);
    let l = 2.0 * a0 * a2 * ca * s1 - 2.0 * a2 * s0 * sa;
    let m = 2.0 * a1 * a2 - 2.0 * a0 * a2 * c1;
    let n = a0 * a0 + a1 * a1 + a2 * a2 + s0 * s0 + s2 * s2
        - d_mm * d_mm
        - 2.0 * a0 * a1 * c1
        - 2.0 * a0 * s2 * sa * s1
        - 2.0 * s0 * s2 * ca;
    (l, m, n)
}

/// Scan density of the first level's search for the shortest full-turn bar.
const FULL_TURN_GRID: usize = 180;

/// The shortest bar length at which C turns fully: √max over θ2 of (K − R) of eq. (9), where
/// K − R is the least d² reachable at that θ2 (a max-min of the bar length over the motion).
fn shortest_full_turn_mm(p: &Params) -> f64 {
    let f = |t2: f64| {
        let (a, b, k) = eq9(p, 0.0, t2);
        k - a.hypot(b)
    };
    let step = std::f64::consts::TAU / FULL_TURN_GRID as f64;
    let k = (0..FULL_TURN_GRID)
        .map(|i| (i, f(i as f64 * step)))
        .max_by(|x, y| x.1.total_cmp(&y.1))
        .map_or(0, |(i, _)| i);
    // Golden section on the bracketing cells.
    let (mut lo, mut hi) = ((k as f64 - 1.0) * step, (k as f64 + 1.0) * step);
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let (mut x1, mut x2) = (hi - g * (hi - lo), lo + g * (hi - lo));
    let (mut f1, mut f2) = (f(x1), f(x2));
    for _ in 0..60 {
        if f1 < f2 {
            lo = x1;
            (x1, f1) = (x2, f2);
            x2 = lo + g * (hi - lo);
            f2 = f(x2);
        } else {
            hi = x2;
            (x2, f2) = (x1, f1);
            x1 = hi - g * (hi - lo);
            f1 = f(x1);
        }
    }
    f(0.5 * (lo + hi)).max(0.0).sqrt()
}

/// The first level: for the table ball (s2, a2) and the machine (a1, α12) of `start`, the
/// spindle ball (s0, a0, θA0) and θC0 such that the rocker has dead points at both ends of the
/// A range (eq. 12 at θ1 = A_min − θA0 − 90° and at A_max), C turns fully with the branches just
/// meeting (d = the shortest full-turn bar), and the lower dead point is at C = 0 (its θ2 is the
/// double root of eq. 10). Newton's method from `start`; the result is checked against the
/// designed motion (eq. 9-15). Returns the parameters and the largest condition residual (mm),
/// or None when there is no such linkage near `start`.
pub fn first_level(start: &Params, d_mm: f64, a_range_deg: [f64; 2]) -> Option<(Params, f64)> {
    solve_conditions(start, d_mm, a_range_deg, [0, 1, 2])
}

/// The same conditions solved for a2 instead of s0 (s0 and s2 given): the chart the second level
/// searches in. In (s2, a2) the realisable set ends where the two mirror solutions ±s0 merge
/// (s0 = 0, a fold with an infinite slope); in (s2, s0) that edge is an ordinary interior point.
pub fn first_level_for_a2(
    start: &Params,
    d_mm: f64,
    a_range_deg: [f64; 2],
) -> Option<(Params, f64)> {
    solve_conditions(start, d_mm, a_range_deg, [4, 1, 2])
}

/// Solve the first-level conditions for the three parameters `unknowns` ([`super::PARAM_NAMES`]
/// indices; the others come from `start`), then set θC0.
fn solve_conditions(
    start: &Params,
    d_mm: f64,
    a_range_deg: [f64; 2],
    unknowns: [usize; 3],
) -> Option<(Params, f64)> {
    let a_min = a_range_deg[0].min(a_range_deg[1]).to_radians();
    let a_max = a_range_deg[0].max(a_range_deg[1]).to_radians();
    let with = |x: &[f64; 3]| {
        let mut v = start.to_array();
        for (k, &i) in unknowns.iter().enumerate() {
            v[i] = x[k];
        }
        Params::from_array(&v)
    };
    // Conditions in mm: eq. (12) divided by 2·(2 a0 a2)·... so that each is a length.
    let res = |x: &[f64; 3]| -> [f64; 3] {
        let p = with(x);
        let scale = 2.0 * p.a0_mm.abs().max(1.0) * p.a2_mm.abs().max(1e-3);
        let e12 = |a: f64| {
            let (l, m, n) = eq10(&p, d_mm, a - p.theta_a0_rad - std::f64::consts::FRAC_PI_2);
            (l * l + m * m - n * n) / (scale * scale) * d_mm
        };
        [e12(a_min), e12(a_max), shortest_full_turn_mm(&p) - d_mm]
    };
    let norm_inf = |r: &[f64; 3]| r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let v0 = start.to_array();
    let mut x = unknowns.map(|i| v0[i]);
    let mut r = res(&x);
    let steps = unknowns.map(|i| if super::IS_ANGLE[i] { 1e-9 } else { 1e-6 });
    for _ in 0..60 {
        if !norm_inf(&r).is_finite() {
            return None;
        }
        if norm_inf(&r) < 1e-10 {
            break;
        }
        let mut jac = nalgebra::Matrix3::<f64>::zeros();
        for k in 0..3 {
            let mut xp = x;
            let mut xm = x;
            xp[k] += steps[k];
            xm[k] -= steps[k];
            let (rp, rm) = (res(&xp), res(&xm));
            for i in 0..3 {
                jac[(i, k)] = (rp[i] - rm[i]) / (2.0 * steps[k]);
            }
        }
        let dx = jac
            .lu()
            .solve(&nalgebra::Vector3::new(-r[0], -r[1], -r[2]))?;
        // Damped step: halve until the residual falls.
        let mut t = 1.0;
        loop {
            let xt = [x[0] + t * dx[0], x[1] + t * dx[1], x[2] + t * dx[2]];
            let rt = res(&xt);
            if norm_inf(&rt) < norm_inf(&r) {
                (x, r) = (xt, rt);
                break;
            }
            t *= 0.5;
            if t < 1e-6 {
                return None;
            }
        }
    }
    let mut p = with(&x);
    let err = norm_inf(&r);
    if err > 1e-7 {
        return None;
    }
    // θC0: the double root θ2 of eq. (10) at A_min sits at C = 0.
    let (l, m, n) = eq10(
        &p,
        d_mm,
        a_min - p.theta_a0_rad - std::f64::consts::FRAC_PI_2,
    );
    p.theta_c0_rad = (-n * l).atan2(-n * m);
    // The conditions have other roots (a tangency inside the range, a range on the wrong
    // side): accept only a motion whose dead points are the required extremes.
    let des = design_with_grid(&p, d_mm, 720);
    let dead = des.branches.iter().flat_map(|b| b.dead_points.iter());
    let lo = dead
        .clone()
        .map(|d| d.theta_a_deg)
        .fold(f64::INFINITY, f64::min);
    let hi = dead
        .map(|d| d.theta_a_deg)
        .fold(f64::NEG_INFINITY, f64::max);
    let [r_lo, r_hi] = des.a_range_deg?;
    let tol = 1e-6;
    let ok = (lo - a_min.to_degrees()).abs() < tol
        && (hi - a_max.to_degrees()).abs() < tol
        && r_lo > a_min.to_degrees() - 1e-3
        && r_hi < a_max.to_degrees() + 1e-3;
    ok.then_some((p, err))
}

fn feasible(g: &[f64; 12]) -> bool {
    g.iter().all(|&x| x <= 0.0)
}

/// The saddle synthesis (see the module doc) for the required A range, every bar length of the
/// series. `start` supplies a1, α12 (the machine) and the start of the first level.
pub fn saddle_synthesize(
    start: &Params,
    a_range_deg: [f64; 2],
    lim: &Limits,
    opts: &SaddleOptions,
) -> Result<Saddle> {
    if lim.bar_series_mm.is_empty() {
        return Err(Error::Usage("the bar series is empty (g13)".into()));
    }
    let mut per_length = Vec::new();
    for &d in &lim.bar_series_mm {
        per_length.push(SaddleAtLength {
            d_mm: d,
            outcome: at_length(start, d, a_range_deg, lim, opts),
        });
    }
    let best = per_length
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.outcome.as_ref().ok().map(|o| (i, o.objective_deg)))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i);
    Ok(Saddle { per_length, best })
}

fn at_length(
    start: &Params,
    d_mm: f64,
    a_range_deg: [f64; 2],
    lim: &Limits,
    opts: &SaddleOptions,
) -> std::result::Result<SaddleDesign, String> {
    let mut l2 = Level2 {
        start: *start,
        d_mm,
        a_range_deg,
        lim,
        a2_max_mm: opts.a2_max_mm,
        evaluations: 0,
    };
    // Box of the second level: g11, g12 for s2; g4, g5 for s0 (the spindle's X travel).
    let [h_lo, h_hi] = lim.ball_height_mm;
    let [x_lo, x_hi] = lim.spindle_x_mm;
    let n = opts.scan.max(2);
    let grid = |k: usize, lo: f64, hi: f64| lo + (hi - lo) * k as f64 / (n - 1) as f64;
    let inside = |s2: f64, s0: f64| (h_lo..=h_hi).contains(&s2) && (x_lo..=x_hi).contains(&s0);
    // Serpentine scan, warm-starting each first-level solve from the last success.
    let mut warm = *start;
    let mut best: Option<(f64, f64, Eval)> = None;
    let mut any_first_level = false;
    let mut least_violated: Option<(f64, [f64; 12])> = None;
    for i in 0..n {
        for jj in 0..n {
            let j = if i % 2 == 0 { jj } else { n - 1 - jj };
            let (s2, s0) = (grid(i, h_lo, h_hi), grid(j, x_lo, x_hi));
            let Some(ev) = l2.eval(s2, s0, &warm).or_else(|| l2.eval(s2, s0, start)) else {
                continue;
            };
            any_first_level = true;
            warm = ev.params;
            let worst = ev.g.iter().fold(f64::NEG_INFINITY, |m, &x| m.max(x));
            if least_violated.as_ref().is_none_or(|(w, _)| worst < *w) {
                least_violated = Some((worst, ev.g));
            }
            if feasible(&ev.g)
                && best
                    .as_ref()
                    .is_none_or(|b| objective(&ev.g) < objective(&b.2.g))
            {
                best = Some((s2, s0, ev));
            }
        }
    }
    let Some((mut s2, mut s0, mut cur)) = best else {
        return Err(
            if let (true, Some((_, g))) = (any_first_level, least_violated) {
                let names: Vec<String> = CONSTRAINTS
                    .iter()
                    .zip(g)
                    .filter(|(_, v)| *v > 0.0)
                    .map(|((n, m), v)| format!("{n} {m} by {v:.3}"))
                    .collect();
                format!(
                    "no point of the scan meets every constraint; the nearest violates {}",
                    names.join(", ")
                )
            } else {
                "no table-ball position in the box gives dead points on the required A range at this bar length".into()
            },
        );
    };
    // Generalised pattern search, extreme barrier.
    let mut step = [
        (h_hi - h_lo) / (n - 1) as f64 / 2.0,
        (x_hi - x_lo) / (n - 1) as f64 / 2.0,
    ];
    let dirs = [
        (1.0, 0.0),
        (-1.0, 0.0),
        (0.0, 1.0),
        (0.0, -1.0),
        (1.0, 1.0),
        (-1.0, -1.0),
        (1.0, -1.0),
        (-1.0, 1.0),
    ];
    while step[0].max(step[1]) > opts.tolerance_mm {
        let mut improved = false;
        for &(ds, dx) in &dirs {
            let (ts, tx) = (s2 + ds * step[0], s0 + dx * step[1]);
            if !inside(ts, tx) {
                continue;
            }
            if let Some(ev) = l2.eval(ts, tx, &cur.params) {
                if feasible(&ev.g) && objective(&ev.g) < objective(&cur.g) - 1e-12 {
                    (s2, s0, cur) = (ts, tx, ev);
                    improved = true;
                    break;
                }
            }
        }
        if !improved {
            step = [step[0] / 2.0, step[1] / 2.0];
        }
    }
    // Is the solution on the edge of the realisable set (first level without solution nearby)?
    let probe = 10.0 * opts.tolerance_mm;
    let (mut at_coverage_limit, mut at_a2_max) = (false, false);
    for &(ds, dx) in &dirs {
        let (ts, tx) = (s2 + ds * probe, s0 + dx * probe);
        if inside(ts, tx) {
            match l2.try_eval(ts, tx, &cur.params) {
                Err(Reject::Coverage) => at_coverage_limit = true,
                Err(Reject::A2Max) => at_a2_max = true,
                Ok(_) => {}
            }
        }
    }
    // Eq. (18) on F's trajectory over the designed motion: the saddle sphere.
    let p = cur.params;
    let pts: Vec<V3> = motion(&p, d_mm, 90)
        .into_iter()
        .map(|(a, c)| pose(&p, a, c).f)
        .collect();
    let sphere_error_mm = match sphere_fit(&pts, [p.a0_mm + 1.0, 0.5, p.s0_mm - 1.0], d_mm) {
        Ok((_, err)) => err,
        Err(e) => return Err(format!("eq. 18 on the synthesized trajectory failed: {e}")),
    };
    Ok(SaddleDesign {
        params: p,
        objective_deg: objective(&cur.g),
        g: cur.g,
        sphere_error_mm,
        first_level_mm: cur.first_level_mm,
        evaluations: l2.evaluations,
        at_coverage_limit,
        at_a2_max,
    })
}

/// g1–g12 and the objective for given parameters (for checks and reports), or None when the
/// motion at d is empty.
pub fn evaluate(p: &Params, d_mm: f64, lim: &Limits) -> Option<(f64, [f64; 12])> {
    constraint_values(p, d_mm, lim).map(|g| (objective(&g), g))
}

/// The motion grid used for the constraints (θC points per branch), for reports.
pub const fn motion_grid() -> usize {
    MOTION_GRID
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table2() -> Params {
        Params::from_named_units(&[96.310, 352.114, -55.0, 80.0, 30.0, -161.592, 0.0, 270.0])
    }

    #[test]
    fn table2_design_meets_the_default_limits() {
        let (obj, g) = evaluate(&table2(), 300.0, &Limits::default()).unwrap();
        assert!(feasible(&g), "{g:?}");
        // Both cups see the bar at up to 66.0° (half the A range, 55°, plus the ball offsets).
        assert!((obj + 75.0 - 66.01).abs() < 0.01, "{obj}");
    }

    /// Eq. (10) as printed must vanish on every pose of eq. (8) at its own bar length.
    #[test]
    fn eq10_matches_eq8() {
        let p = Params::from_named_units(&[96.9, 351.9, -54.99, 79.9, 30.06, -161.5, -0.02, 270.1]);
        for &(ta, tc) in &[(-30.0f64, 10.0f64), (-100.0, 250.0), (-5.0, 123.0)] {
            let (ta, tc) = (ta.to_radians(), tc.to_radians());
            let d = crate::rrsps::bar_length(&p, ta, tc);
            let (t1, t2) = p.link_angles(ta, tc);
            let (l, m, n) = eq10(&p, d, t1);
            let v = l * t2.sin() + m * t2.cos() + n;
            assert!(v.abs() < 1e-7 * d * d, "{v}");
        }
    }

    /// The first level with Table 2's table ball and d = 300 mm gives Table 2's spindle ball.
    #[test]
    fn first_level_gives_table2_spindle_ball() {
        let start = Params::from_named_units(&[90.0, 345.0, -58.0, 80.0, 30.0, 0.0, 0.0, 270.0]);
        let (p, err) = first_level(&start, 300.0, [-110.0, 0.0]).unwrap();
        let v = p.to_named_units();
        assert!(err < 1e-9);
        assert!((v[0] - 96.310).abs() < 0.0015, "s0 {}", v[0]);
        assert!((v[1] - 352.114).abs() < 0.0015, "a0 {}", v[1]);
        assert!((v[2] + 55.0).abs() < 0.0015, "θA0 {}", v[2]);
        assert!((v[5] + 161.592).abs() < 0.07, "θC0 {}", v[5]);
    }

    #[test]
    fn eq18_recovers_a_known_sphere() {
        let p = table2();
        let pts: Vec<V3> = motion(&p, 300.0, 90)
            .into_iter()
            .map(|(a, c)| pose(&p, a, c).f)
            .collect();
        let (e, err) = sphere_fit(&pts, [p.a0_mm + 3.0, -2.0, p.s0_mm + 2.0], 300.0)
            .map_err(|e| format!("{e}"))
            .unwrap();
        assert!(err < 1e-7, "{err}");
        assert!((e[0] - p.a0_mm).abs() < 1e-5 && e[1].abs() < 1e-5);
        assert!((e[2] - p.s0_mm).abs() < 1e-5);
    }
}
