//! The joint diagnosis of a volumetric record (`jdbb diagnose --record R --plan P` on a plan of
//! `jdbb plan --volumetric`): one record, synchronised across all elements, diagnosed as one
//! test, with each plane's own view beside it.
//!
//! # Synchronisation
//!
//! Every element of the plan (an xy cone at its height, a zx or yz arc in its plane) is one of
//! the plan's circles, entered by its own radial feed-in from a dwell and left by its feed-out,
//! and the moves along the shell between elements keep D away from the next element's level
//! until its feed-in. So the plane test's synchronisation ([`crate::sync`]) finds
//! each element in turn from D alone, as it finds the circles of a plane test: the plan's
//! segments carry each element's heights and plane (3-D start and end points of its lines and
//! arcs), which give the levels of D to look for and the nominal position of every sample.
//! [`elements`] states what it found per element: where it started on the record's clock and
//! the feed it ran at.
//!
//! # Diagnosis
//!
//! The data arcs of all elements form one path in space; the plane diagnosis's effect model
//! ([`crate::model`]) is written in three dimensions (each effect's δ acts on the
//! nominal position, D = |p + δ − c| + e), so the one selection ([`crate::diagnose`])
//! runs over all elements at once: backlash per axis and per end, scales, squarenesses XY, YZ
//! and ZX, servo mismatch per pair, bows, cyclic error per axis (with `--pitch`), reversal
//! spikes, with σ and shares, under the same names and JSON schema as a plane test (so
//! `compensate` and `history add` take it unchanged). Added here:
//!
//! - **the scales with the calibration as the length reference**: on one ball distance the mean
//!   of the three scales moves D as the instrument's length does (a length offset e, or the
//!   bar-length sum off), so the diagnosis names the scale differences; the mean is
//!   s̄ = e/D, true as far as the instrument's calibration is ([`Scales`]);
//! - **the identifiability** of the plan ([`super::ident`]) beside the numerical rank of the
//!   linear model's design matrix at the record's own data samples ([`super::fit`]);
//! - **each plane's view**: per element and direction the ISO 230-4 G and H of the plane report
//!   ([`crate::diagnose::zone`]), from the joint diagnosis's deviations with its set-up removed.
//!
//! May use: [`crate::sync`], [`crate::diagnose`] (planned, runs, zone) by import, and
//! this module's siblings.
use crate::diagnose::planned::{diagnose_record as planned_record, Planned};
use crate::diagnose::runs::{angles, split_runs_at, MAX_RUN_STEP_RAD};
use crate::diagnose::zone::{circle_zones, CircleZone};
use crate::diagnose::Diagnosis;
use crate::model::{Effect, Pair, Path};
use crate::plan::{Plan, Plane, Purpose};
use crate::sync::{Record, Sync};
use crate::Result;

use super::ident::{identifiability, Identifiability};
use super::plan::{data_points_mm, element_kind};

/// One element of a volumetric record as the synchronisation found it.
#[derive(Debug, Clone, PartialEq)]
pub struct Element {
    /// The plan's circle (0-based).
    pub circle: usize,
    /// `xy cone`, `zx arc`, … ([`element_kind`]).
    pub kind: String,
    pub plane: Plane,
    /// Along the plane's normal from the table ball (mm).
    pub height_mm: f64,
    pub radius_mm: f64,
    /// The feed-in's start on the record's clock (s).
    pub start_s: f64,
    /// The feed the element ran at (mm/min, on the record's clock) and as programmed.
    pub feed_mm_min: f64,
    pub programmed_feed_mm_min: f64,
    /// Data-arc samples of the element.
    pub samples: usize,
}

/// Each element of `plan` in the record as `sync` found it, in program order.
pub fn elements(plan: &Plan, sync: &Sync) -> Vec<Element> {
    sync.circles
        .iter()
        .map(|c| {
            let pc = &plan.circles[c.circle];
            Element {
                circle: c.circle,
                kind: element_kind(plan, c.circle),
                plane: pc.plane,
                height_mm: pc.height_mm,
                radius_mm: pc.radius_mm,
                start_s: c.feed_in.profile.t0_s,
                feed_mm_min: 60.0 * c.speed_mm_s,
                programmed_feed_mm_min: pc.feed_mm_min,
                samples: c.data.iter().map(|a| a.samples).sum(),
            }
        })
        .collect()
}

/// The scale of each axis (µm/m) with the instrument's calibration as the length reference.
#[derive(Debug, Clone, PartialEq)]
pub struct Scales {
    /// Mean of the three scales, s̄ = e/D̄ (µm/m), with its σ: the length offset the
    /// diagnosis found, read as the machine's (the instrument's calibration taken as true).
    pub mean_um_per_m: f64,
    pub mean_sigma_um_per_m: Option<f64>,
    /// Each axis's scale relative to the mean (µm/m, summing to 0), from the named scale
    /// differences; 0 where none is named.
    pub relative_um_per_m: [f64; 3],
    /// Whether the test told the mean from the length offset by itself (several ball
    /// distances): then the diagnosis's own `scale_k` are the scales and e is the instrument's.
    pub mean_from_distances: bool,
}

impl Scales {
    /// Each axis's scale, mean plus relative (µm/m).
    pub fn per_axis_um_per_m(&self) -> [f64; 3] {
        self.relative_um_per_m.map(|r| r + self.mean_um_per_m)
    }
}

/// What is true of the mean scale, in the output's words.
pub const MEAN_SCALE_NOTE: &str = "one mount cannot tell the mean of the three scales from the instrument's length: the mean is taken with the instrument's calibration as the length reference (its error enters the mean, not the differences)";

/// The scales of diagnosis `d` of a test on ball distances `d_mm` (see [`Scales`]).
pub fn scales(d: &Diagnosis, d_mm: &[f64]) -> Scales {
    let mean_d = d_mm.iter().sum::<f64>() / d_mm.len().max(1) as f64;
    let named = |e: Effect| d.effects.iter().find(|f| f.effect == e);
    let own: Vec<_> = crate::model::Axis::ALL
        .iter()
        .map(|&a| named(Effect::Scale(a)).map(|f| f.value))
        .collect();
    if own.iter().any(Option::is_some) {
        let s: Vec<f64> = own.iter().map(|v| v.unwrap_or(0.0)).collect();
        let mean = s.iter().sum::<f64>() / 3.0;
        return Scales {
            mean_um_per_m: mean,
            mean_sigma_um_per_m: None,
            relative_um_per_m: [s[0] - mean, s[1] - mean, s[2] - mean],
            mean_from_distances: true,
        };
    }
    // ScaleMismatch(ij) of value a: δ_i = +a/2·i, δ_j = −a/2·j.
    let mut rel = [0.0; 3];
    for pair in Pair::ALL {
        if let Some(f) = named(Effect::ScaleMismatch(pair)) {
            let (i, j) = pair.axes();
            rel[i.index()] += f.value / 2.0;
            rel[j.index()] -= f.value / 2.0;
        }
    }
    let e = named(Effect::LengthOffset);
    // µm over mm → 1e3 µm/m.
    Scales {
        mean_um_per_m: e.map_or(0.0, |f| 1e3 * f.value / mean_d),
        mean_sigma_um_per_m: e.and_then(|f| f.sigma).map(|s| 1e3 * s / mean_d),
        relative_um_per_m: rel,
        mean_from_distances: false,
    }
}

/// One element's view as a plane test reports it: its G and H per direction.
#[derive(Debug, Clone)]
pub struct PlaneView {
    pub element: Element,
    pub zone: CircleZone,
}

/// The joint diagnosis of a volumetric record.
#[derive(Debug, Clone)]
pub struct Volumetric {
    /// The synchronisation, the data and the joint diagnosis.
    pub planned: Planned,
    pub elements: Vec<Element>,
    pub scales: Scales,
    /// What the plan determines of the linear error field ([`super::ident`]).
    pub identifiability: Identifiability,
    /// Rank of the linear model's nine-term design matrix (calibration as length reference) at
    /// the record's own data samples ([`super::fit`]): equal to the plan's rank when the
    /// record holds what the plan promised.
    pub fit_rank: usize,
    /// Per element, in program order.
    pub planes: Vec<PlaneView>,
}

/// Diagnose `rec`, a record of the volumetric `plan`, as one test (module docs): synchronise
/// and diagnose as [`crate::diagnose::planned::diagnose_record`] does, then the scales, the
/// identifiability and each plane's view.
pub fn diagnose_record(
    plan: &Plan,
    rec: &Record,
    pitch_mm: [Option<f64>; 3],
    opts: &crate::diagnose::Options,
) -> Result<Volumetric> {
    let planned = planned_record(plan, rec, pitch_mm, opts)?;
    views(plan, planned)
}

/// The volumetric views of `planned` where `plan` is a volumetric test; None for a plane test.
pub fn of_plan(plan: &Plan, planned: &Planned) -> Result<Option<Volumetric>> {
    if plan.purpose != Purpose::VolumetricTest {
        return Ok(None);
    }
    views(plan, planned.clone()).map(Some)
}

/// The volumetric views of `planned`, a record of the volumetric `plan` synchronised and
/// diagnosed as one test.
pub fn views(plan: &Plan, planned: Planned) -> Result<Volumetric> {
    let elements = elements(plan, &planned.sync);
    let mut ds: Vec<f64> = plan.circles.iter().map(|c| c.d_mm).collect();
    ds.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    let scales = scales(&planned.diagnosis, &ds);
    let identifiability = identifiability(&data_points_mm(plan));
    let fit_rank = identifiability_of_samples(&planned.path);
    let planes = plane_views(&planned, &elements)?;
    Ok(Volumetric {
        planned,
        elements,
        scales,
        identifiability,
        fit_rank,
        planes,
    })
}

/// Most samples the record's own rank is taken over: every k-th data sample, so that a long
/// record at 5 kHz costs a 20 000 × 10 decomposition, not a matrix of millions of rows.
pub const RANK_SAMPLES: usize = 20_000;

/// The nine-term rank of the linear model at the path's samples (every k-th, at most
/// [`RANK_SAMPLES`]).
fn identifiability_of_samples(path: &Path) -> usize {
    let step = path.len().div_ceil(RANK_SAMPLES).max(1);
    let points: Vec<[f64; 3]> = path.p_mm.iter().step_by(step).copied().collect();
    identifiability(&points).rank_with_reference
}

/// G and H of every element in its own plane, from the joint diagnosis's measured deviation
/// (set-up removed), each element's samples being those inside its feed-in and feed-out.
fn plane_views(planned: &Planned, elements: &[Element]) -> Result<Vec<PlaneView>> {
    let path = &planned.path;
    let dev = &planned.diagnosis.measured_dev_um;
    let mut out = vec![];
    for (e, c) in elements.iter().zip(&planned.sync.circles) {
        let (t_a, t_b) = (c.feed_in.profile.t0_s, c.feed_out.profile.end_s());
        let idx: Vec<usize> = (0..path.len())
            .filter(|&i| path.t_s[i] >= t_a && path.t_s[i] <= t_b)
            .collect();
        if idx.is_empty() {
            continue;
        }
        let (i, j, _) = e.plane.axes();
        let t: Vec<f64> = idx.iter().map(|&k| path.t_s[k]).collect();
        let p: Vec<[f64; 3]> = idx.iter().map(|&k| path.p_mm[k]).collect();
        let d: Vec<f64> = idx.iter().map(|&k| dev[k]).collect();
        let sub = Path::new(t, p, path.pitch_mm);
        let angle = angles(&sub.p_mm, (i, j));
        let (circles, runs) = split_runs_at(&sub.t_s, &sub.p_mm, &angle, (i, j), MAX_RUN_STEP_RAD);
        let zones = circle_zones(&sub, &angle, &d, &circles, &runs)?;
        if let Some(zone) = zones.into_iter().max_by_key(|z| z.samples) {
            out.push(PlaneView {
                element: e.clone(),
                zone,
            });
        }
    }
    Ok(out)
}

/// The JSON of the volumetric views (the diagnosis JSON's `volumetric` object; the rest of the
/// JSON is a plane diagnosis's, so `compensate` and `history add` read it unchanged).
pub fn to_json(v: &Volumetric) -> serde_json::Value {
    use serde_json::{json, Value};
    let num = |x: f64| if x.is_finite() { json!(x) } else { Value::Null };
    let id = &v.identifiability;
    let zone = |z: Option<crate::numerics::mzc::MinimumZone>| z.map(|z| num(z.width_um));
    json!({
        "elements": v.elements.iter().map(|e| json!({
            "circle": e.circle,
            "kind": e.kind,
            "plane": e.plane.name(),
            "height_mm": num(e.height_mm),
            "radius_mm": num(e.radius_mm),
            "start_s": num(e.start_s),
            "feed_mm_min": num(e.feed_mm_min),
            "programmed_feed_mm_min": num(e.programmed_feed_mm_min),
            "samples": e.samples,
        })).collect::<Vec<_>>(),
        "scales": {
            "x_um_per_m": num(v.scales.per_axis_um_per_m()[0]),
            "y_um_per_m": num(v.scales.per_axis_um_per_m()[1]),
            "z_um_per_m": num(v.scales.per_axis_um_per_m()[2]),
            "mean_um_per_m": num(v.scales.mean_um_per_m),
            "mean_sigma_um_per_m": v.scales.mean_sigma_um_per_m.map(num),
            "relative_um_per_m": v.scales.relative_um_per_m.map(num),
            "mean_from_distances": v.scales.mean_from_distances,
            "note": MEAN_SCALE_NOTE,
        },
        "identifiability": {
            "rank": id.rank_with_reference,
            "terms": id.determined.len(),
            "rank_of_record": v.fit_rank,
            "condition": num(id.condition),
            "determined": id.determined.iter().filter(|(_, d)| *d).map(|(t, _)| t.name()).collect::<Vec<_>>(),
            "not_determined": id.determined.iter().filter(|(_, d)| !*d).map(|(t, _)| t.name()).collect::<Vec<_>>(),
            "confounded": id.confounded.iter().map(|c| super::ident::combination_text(c)).collect::<Vec<_>>(),
            "second_setup": SECOND_SETUP,
        },
        "planes": v.planes.iter().map(|p| json!({
            "circle": p.element.circle,
            "kind": p.element.kind,
            "plane": p.element.plane.name(),
            "g_ccw_um": zone(p.zone.ccw),
            "g_cw_um": zone(p.zone.cw),
            "g_um": num(p.zone.g_um()),
            "h_um": num(p.zone.h_um),
            "samples": p.zone.samples,
        })).collect::<Vec<_>>(),
    })
}

/// What a second set-up would add, in the output's words.
pub const SECOND_SETUP: &str = "angular errors (pitch, yaw, roll) through the fixed lever arm read as these scales and squarenesses; a second lever arm (another stem length or table ball position) separates them";

/// The text of the volumetric views, after the plane diagnosis's summary.
pub fn text(v: &Volumetric) -> String {
    let mut t = format!(
        "volumetric test: {} elements found on one record\n  {:>2}  {:<9} {:>9} {:>10} {:>14} {:>8}\n",
        v.elements.len(),
        "#",
        "element",
        "H mm",
        "start s",
        "feed mm/min",
        "samples"
    );
    for e in &v.elements {
        t += &format!(
            "  {:>2}  {:<9} {:>9.3} {:>10.3} {:>14.1} {:>8}\n",
            e.circle + 1,
            e.kind,
            e.height_mm,
            e.start_s,
            e.feed_mm_min,
            e.samples
        );
    }
    let s = &v.scales;
    let [x, y, z] = s.per_axis_um_per_m();
    t += &format!(
        "scales: x {x:+.2}  y {y:+.2}  z {z:+.2} µm/m (mean {:+.2}",
        s.mean_um_per_m
    );
    if let Some(sig) = s.mean_sigma_um_per_m {
        t += &format!(" ± {sig:.2}");
    }
    t += " µm/m)\n";
    if !s.mean_from_distances {
        t += &format!("  note: {MEAN_SCALE_NOTE}\n");
    }
    let id = &v.identifiability;
    t += &format!(
        "linear terms determined: {} of {} (condition number {:.1}); the record's own samples: rank {}\n",
        id.rank_with_reference,
        id.determined.len(),
        id.condition,
        v.fit_rank
    );
    for c in &id.confounded {
        t += &format!("  confounded: {}\n", super::ident::combination_text(c));
    }
    t += &format!("  a second set-up would add: {SECOND_SETUP}\n");
    t += "each plane's view (ISO 230-4, minimum zone), µm:\n";
    t += &format!(
        "  {:>2}  {:<9} {:>5} {:>8} {:>8} {:>8}\n",
        "#", "element", "plane", "G ccw", "G cw", "H"
    );
    let g = |z: Option<crate::numerics::mzc::MinimumZone>| {
        z.map_or("-".to_string(), |z| format!("{:.2}", z.width_um))
    };
    for p in &v.planes {
        t += &format!(
            "  {:>2}  {:<9} {:>5} {:>8} {:>8} {:>8.2}\n",
            p.element.circle + 1,
            p.element.kind,
            p.element.plane.name(),
            g(p.zone.ccw),
            g(p.zone.cw),
            p.zone.h_um
        );
    }
    t
}
