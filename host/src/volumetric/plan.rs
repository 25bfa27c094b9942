//! The plan of a volumetric test: one program, one plan.json, one mount.
//!
//! # The elements, in program order
//!
//! 1. **xy cones**: on each ball distance D (`--distance`, in order), circles at each height H
//!    (`--height`; default 0, D/3 and 2D/3) of radius R = √(D² − H²), heights upwards on the
//!    first distance, downwards on the next, and so on, each run as a plane test's circle
//!    (full circle from 0°, ccw then cw, [`crate::plan`]);
//! 2. **a zx arc** through the ball on each distance: 220° from −110° of z (−20° to 200° of x,
//!    the ballbar's vertical test), ccw then back cw, lead-in and overshoot 20° from inside;
//! 3. **a yz arc** the same, 220° from −20° of y.
//!
//! Each element is planned as a plane test ([`crate::plan::build::plan`]) and keeps
//! that plan's path: take-up, dwells, feed-in, arcs, feed-out, and moves between its own circles.
//! Between two elements the spindle ball moves **along the shell**: up its meridian to the
//! higher of the two elevations, along that latitude to the next element's azimuth (the
//! shorter way), and down that meridian to the next element's take-up point, D changing evenly
//! along the way, in lines of at most 5° (shorter where a chord would leave the instrument's
//! range). So it never passes through or under the table ball, never goes lower than the two
//! elements it joins, and the instrument stays in range; the whole plan is checked for that.
//!
//! What it determines of the linear error field: [`super::ident`] over [`data_points_mm`].
use crate::plan::build::{self, check_range, q, CircleSpec, PlanSpec};
use crate::plan::{
    dist, instrument, line_d_range, Circle, Instrument, LineRole, Plan, Plane, Purpose, Segment,
    VOLUMETRIC_VERSION,
};
use crate::{Error, Result};
use jdbb_core::calib::Calibration;

/// The arc of the vertical elements (degrees): the ballbar's 220° test.
pub const VERTICAL_ARC_DEG: f64 = 220.0;
/// Where the zx arc starts (degrees from z towards x): −110°, so that it runs from 20° below
/// the ball on −x over the top to 20° below it on +x.
pub const ZX_START_DEG: f64 = -110.0;
/// Where the yz arc starts (degrees from y towards z): −20°.
pub const YZ_START_DEG: f64 = -20.0;
/// Longest line of a move along the shell (degrees of the shell).
pub const SHELL_STEP_DEG: f64 = 5.0;

/// What `jdbb plan --volumetric` is asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct VolumetricSpec {
    /// Ball distances D of the elements (mm), in order.
    pub distances_mm: Vec<f64>,
    /// Heights of the xy cones above the table ball (mm); empty: 0, D/3 and 2D/3 on each D.
    pub heights_mm: Vec<f64>,
    /// Feed, centre, dialect, feed-in and dwells as a plane test takes them (its `circles`,
    /// `plane`, `purpose` and arc are set per element).
    pub base: PlanSpec,
}

/// The default ball distance: the middle of the instrument's range, to 1 mm.
pub fn default_distance_mm(inst: &Instrument) -> f64 {
    ((inst.d_min_mm + inst.d_max_mm) / 2.0).round()
}

/// The plane-test specs of the three elements (xy cones, zx arcs, yz arcs), in program order.
fn elements(spec: &VolumetricSpec) -> Vec<PlanSpec> {
    let mut cones = vec![];
    for (k, &d) in spec.distances_mm.iter().enumerate() {
        let mut heights = if spec.heights_mm.is_empty() {
            vec![0.0, q(d / 3.0), q(2.0 * d / 3.0)]
        } else {
            spec.heights_mm.clone()
        };
        if k % 2 == 1 {
            heights.reverse();
        }
        cones.extend(heights.into_iter().map(|h| CircleSpec {
            radius_mm: (d * d - h * h).max(0.0).sqrt(),
            height_mm: h,
            feed_mm_min: None,
        }));
    }
    let arcs: Vec<CircleSpec> = spec
        .distances_mm
        .iter()
        .map(|&d| CircleSpec {
            radius_mm: d,
            height_mm: 0.0,
            feed_mm_min: None,
        })
        .collect();
    let base = PlanSpec {
        purpose: Purpose::MachineTest,
        ..spec.base.clone()
    };
    let vertical = |plane: Plane, start_deg: f64| {
        PlanSpec {
            circles: arcs.clone(),
            plane,
            start_deg,
            ..base.clone()
        }
        .with_arc(VERTICAL_ARC_DEG)
    };
    vec![
        PlanSpec {
            circles: cones,
            plane: Plane::Xy,
            start_deg: 0.0,
            ..base.clone()
        }
        .with_arc(360.0),
        vertical(Plane::Zx, ZX_START_DEG),
        vertical(Plane::Yz, YZ_START_DEG),
    ]
}

/// The volumetric plan for `spec` on the instrument `cal` (see the module docs): refused (usage
/// error, exit 2) if a distance or height leaves no element in the instrument's range.
pub fn plan(spec: &VolumetricSpec, cal: &Calibration) -> Result<Plan> {
    let inst = instrument(cal)?;
    if spec.distances_mm.is_empty() {
        return Err(Error::Usage("give at least one --distance".into()));
    }
    for &d in &spec.distances_mm {
        if !inst.contains(d) {
            return Err(Error::Usage(format!(
                "--distance {d}: the ball distance of a volumetric test is inside the instrument's range {}",
                inst.describe()
            )));
        }
        if let Some(h) = spec.heights_mm.iter().find(|h| h.abs() >= d) {
            return Err(Error::Usage(format!(
                "--height {h}: a cone's height is below its ball distance D = {d} mm (R = √(D² − H²))"
            )));
        }
    }
    let parts = elements(spec)
        .iter()
        .map(|e| {
            build::plan(e, cal).map_err(|err| match err {
                Error::Usage(m) => Error::Usage(format!("the {} element: {m}", e.plane.name())),
                other => other,
            })
        })
        .collect::<Result<Vec<Plan>>>()?;
    let first = &parts[0];
    let mut circles: Vec<Circle> = vec![];
    let mut segments: Vec<Segment> = vec![];
    for part in &parts {
        let offset = circles.len();
        let body = if segments.is_empty() {
            &part.segments[..]
        } else {
            // The instrument is mounted: no rapid and no stop, a move along the shell instead.
            let from = segments
                .iter()
                .rev()
                .find_map(Segment::to_mm)
                .expect("the first element has motions");
            let to = part.segments[0]
                .to_mm()
                .expect("an element starts with its rapid");
            let way = shell_move(&inst, &first.centre_mm, from, to).ok_or_else(|| {
                Error::Usage(format!(
                    "cannot move along the shell to the {} element keeping D within {}; give other distances",
                    part.plane.name(),
                    inst.describe()
                ))
            })?;
            let mut a = from;
            for b in way {
                segments.push(Segment::Line {
                    from_mm: a,
                    to_mm: b,
                    feed_mm_min: part.feed_mm_min,
                    role: LineRole::Move,
                    circle: offset,
                });
                a = b;
            }
            &part.segments[2..]
        };
        segments.extend(body.iter().cloned().map(|mut s| {
            if let Segment::Line { circle, .. } | Segment::Arc { circle, .. } = &mut s {
                *circle += offset;
            }
            s
        }));
        circles.extend(part.circles.iter().map(|c| Circle {
            index: c.index + offset,
            arc: Some(part.arc),
            ..c.clone()
        }));
    }
    let plan = Plan {
        version: VOLUMETRIC_VERSION,
        purpose: Purpose::VolumetricTest,
        circles,
        segments,
        ..first.clone()
    };
    check_range(&plan)?;
    Ok(plan)
}

/// The way-points (after `from`, ending at `to`) of a move along the shell about the table ball
/// at `c` (see the module docs): `None` if lines of 5° down to 0.3° all leave the range.
fn shell_move(
    inst: &Instrument,
    c: &[f64; 3],
    from: [f64; 3],
    to: [f64; 3],
) -> Option<Vec<[f64; 3]>> {
    // (D, azimuth, elevation) of a point about the ball.
    let polar = |p: &[f64; 3]| {
        let v = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        let d = dist(p, c);
        (d, v[1].atan2(v[0]), (v[2] / d).clamp(-1.0, 1.0).asin())
    };
    let ((d0, az0, el0), (d1, az1, el1)) = (polar(&from), polar(&to));
    let top = el0.max(el1);
    let turn =
        (az1 - az0 + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    // The three legs as (elevation, azimuth, D) at their ends and their lengths on the unit
    // sphere. D changes on the latitude only: up and down the meridians at a constant D, z
    // changes one way, so no point is lower than both ends.
    let legs = [
        ((el0, az0, d0), (top, az0, d0), (top - el0).abs()),
        (
            (top, az0, d0),
            (top, az0 + turn, d1),
            turn.abs() * top.cos(),
        ),
        (
            (top, az0 + turn, d1),
            (el1, az0 + turn, d1),
            (top - el1).abs(),
        ),
    ];
    let in_range = |a: &[f64; 3], b: &[f64; 3]| {
        let (lo, hi) = line_d_range(c, a, b);
        inst.contains(lo) && inst.contains(hi)
    };
    let mut step = SHELL_STEP_DEG.to_radians();
    for _ in 0..5 {
        let mut pts = vec![];
        for (k, &((e0, a0, r0), (e1, a1, r1), len)) in legs.iter().enumerate() {
            // The latitude has at least one piece: a radial line where D changes alone.
            let n = ((len / step).ceil() as usize).max(usize::from(k == 1));
            for s in 1..=n {
                let t = s as f64 / n as f64;
                let (e, a, d) = (e0 + t * (e1 - e0), a0 + t * (a1 - a0), r0 + t * (r1 - r0));
                pts.push([
                    q(c[0] + d * e.cos() * a.cos()),
                    q(c[1] + d * e.cos() * a.sin()),
                    q(c[2] + d * e.sin()),
                ]);
            }
        }
        match pts.last_mut() {
            Some(last) => *last = to,
            None => pts.push(to),
        }
        pts.dedup();
        let mut prev = from;
        if pts.iter().all(|p| {
            let ok = in_range(&prev, p);
            prev = *p;
            ok
        }) {
            return Some(pts);
        }
        step /= 2.0;
    }
    None
}

/// The points (mm, relative to the table ball) of every circle's data arc, one per
/// [`super::ident::SAMPLE_STEP_MM`] of path: the rows of the test's design matrix, weighted as a
/// record at a constant feed and sample rate weights them. A plane test's circles run the
/// plan's arc; a volumetric plan's each its own.
pub fn data_points_mm(plan: &Plan) -> Vec<[f64; 3]> {
    let mut out = vec![];
    for c in &plan.circles {
        let arc = c.arc.unwrap_or(plan.arc);
        let (i, j, _) = c.plane.axes();
        let length_mm = c.radius_mm * arc.data_sweep_deg.to_radians();
        let n = (length_mm / super::ident::SAMPLE_STEP_MM).round().max(1.0) as usize;
        // A full circle's last point is its first.
        let last = if arc.data_sweep_deg >= 360.0 {
            n
        } else {
            n + 1
        };
        for k in 0..last {
            let th = (arc.data_start_deg + arc.data_sweep_deg * k as f64 / n as f64).to_radians();
            let mut p: [f64; 3] = std::array::from_fn(|a| c.centre_mm[a] - plan.centre_mm[a]);
            p[i] += c.radius_mm * th.cos();
            p[j] += c.radius_mm * th.sin();
            out.push(p);
        }
    }
    out
}

/// A machine's travel (program coordinates, mm): per axis (x, y, z) its (min, max), or `None`
/// where not given.
pub type Travel = [Option<(f64, f64)>; 3];

/// What circle `k` of `plan` is: `xy cone` (an xy circle off the ball's height), `xy circle`,
/// `zx arc` (a partial arc), …
pub fn element_kind(plan: &Plan, k: usize) -> String {
    let c = &plan.circles[k];
    match (c.plane, c.arc.unwrap_or(plan.arc).is_partial()) {
        (Plane::Xy, false) if c.height_mm != 0.0 => "xy cone".into(),
        (p, false) => format!("{} circle", p.name()),
        (p, true) => format!("{} arc", p.name()),
    }
}

/// Circle `k` of `plan` as a message names it: `element 4 (zx arc, R 90 mm, H 0 mm)`.
pub fn element_name(plan: &Plan, k: usize) -> String {
    let c = &plan.circles[k];
    format!(
        "element {} ({}, R {} mm, H {} mm)",
        k + 1,
        element_kind(plan, k),
        c.radius_mm,
        c.height_mm
    )
}

/// Refuse a plan that leaves the machine's `travel` (usage error, exit 2): the message names
/// each element (or the move to it) that leaves it, the axis and by how much.
pub fn check_travel(plan: &Plan, travel: &Travel) -> Result<()> {
    // (what, axis, below) → the worst excess (mm) and where it reaches.
    let mut worst: Vec<(String, usize, bool, f64, f64)> = vec![];
    for k in 0..plan.segments.len() {
        let Some((lo, hi)) = plan.segment_travel_mm(k) else {
            continue;
        };
        let what = match &plan.segments[k] {
            Segment::Line {
                role: LineRole::Move,
                circle,
                ..
            } => format!("the move to {}", element_name(plan, *circle)),
            Segment::Line { circle, .. } | Segment::Arc { circle, .. } => {
                element_name(plan, *circle)
            }
            _ => "the start point".to_string(),
        };
        for (a, limits) in travel.iter().enumerate() {
            let Some((min, max)) = *limits else { continue };
            for (below, excess, at) in [(true, min - lo[a], lo[a]), (false, hi[a] - max, hi[a])] {
                if excess <= 1e-9 {
                    continue;
                }
                match worst
                    .iter_mut()
                    .find(|w| w.0 == what && w.1 == a && w.2 == below)
                {
                    Some(w) if w.3 < excess => (w.3, w.4) = (excess, at),
                    Some(_) => {}
                    None => worst.push((what.clone(), a, below, excess, at)),
                }
            }
        }
    }
    if worst.is_empty() {
        return Ok(());
    }
    let text: Vec<String> = worst
        .iter()
        .map(|(what, a, below, excess, at)| {
            let axis = ["X", "Y", "Z"][*a];
            let (min, max) = travel[*a].expect("an axis with an excess has limits");
            if *below {
                format!("{what} reaches {axis} {at:.3} mm, {excess:.3} mm below the travel's {axis} {min}")
            } else {
                format!("{what} reaches {axis} {at:.3} mm, {excess:.3} mm beyond the travel's {axis} {max}")
            }
        })
        .collect();
    Err(Error::Usage(format!(
        "the plan leaves the machine's travel (--travel): {}; move the table ball (--centre) or give smaller distances",
        text.join("; ")
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::Dialect;

    fn spec(dialect: Dialect) -> VolumetricSpec {
        VolumetricSpec {
            distances_mm: vec![90.0],
            heights_mm: vec![],
            base: PlanSpec::machine_test(
                &[1.0],
                &[0.0],
                Plane::Xy,
                1000.0,
                [100.0, 50.0, -20.0],
                dialect,
            ),
        }
    }

    /// The identifiability of a plane plan's circles (xy, about the ball at D 90 mm).
    fn cones(heights: &[f64]) -> super::super::ident::Identifiability {
        super::super::ident::identifiability(&cone_points(heights))
    }

    /// The data arcs' points of a plane plan's circles (xy, about the ball at D 90 mm).
    fn cone_points(heights: &[f64]) -> Vec<[f64; 3]> {
        let mut s = PlanSpec::machine_test(
            &[1.0],
            &[0.0],
            Plane::Xy,
            1000.0,
            [0.0; 3],
            Dialect::Linuxcnc,
        );
        s.circles = heights
            .iter()
            .map(|&h| CircleSpec {
                radius_mm: (90.0f64 * 90.0 - h * h).sqrt(),
                height_mm: h,
                feed_mm_min: None,
            })
            .collect();
        let p = build::plan(&s, &Calibration::DEFAULT).unwrap();
        data_points_mm(&p)
    }

    /// ΔD (µm) at `points` (mm) of a machine whose axes move by δx = s_x·x + q_xy·y,
    /// δy = s_y·y + q_yz·z, δz = s_z·z + q_zx·x (µm/m) with the table ball `c_um` off its place:
    /// the exact distance, not the model's partials.
    fn exact_dd_um(points: &[[f64; 3]], s: [f64; 3], q: [f64; 3], c_um: [f64; 3]) -> Vec<f64> {
        points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let e = 1e-6;
                let moved = [
                    p[0] + e * (s[0] * p[0] + q[0] * p[1]) - 1e-3 * c_um[0],
                    p[1] + e * (s[1] * p[1] + q[1] * p[2]) - 1e-3 * c_um[1],
                    p[2] + e * (s[2] * p[2] + q[2] * p[0]) - 1e-3 * c_um[2],
                ];
                let norm = |v: &[f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                // ±0.2 µm of noise, a fixed pattern (no generator shared with the fit).
                let noise = 0.2 * ((i as f64 * 0.618_034).fract() * 2.0 - 1.0);
                (norm(&moved) - norm(p)) * 1e3 + noise
            })
            .collect()
    }

    #[test]
    fn the_fit_recovers_three_squarenesses_and_two_scale_differences() {
        let p = plan(&spec(Dialect::Linuxcnc), &Calibration::DEFAULT).unwrap();
        let points = data_points_mm(&p);
        // Scales 40 and −25 µm/m of X and Y against Z (the calibration the length reference),
        // squarenesses 30, −20, 15 µm/m, the ball 5, −3, 8 µm off.
        let (s, q, c) = ([40.0, -25.0, 0.0], [30.0, -20.0, 15.0], [5.0, -3.0, 8.0]);
        let fit = super::super::fit::fit_linear(&points, &exact_dd_um(&points, s, q, c)).unwrap();
        assert_eq!(fit.rank, 9);
        assert!(fit.undetermined.is_empty());
        let truth = [s[0], s[1], s[2], q[0], q[1], q[2], c[0], c[1], c[2]];
        for (e, want) in fit.estimates.iter().zip(truth) {
            let sigma = e.sigma.expect("every term determined");
            let err = (e.value - want).abs();
            assert!(
                err <= 0.05 * want.abs().max(1.0) && err <= 4.0 * sigma + 0.05,
                "{}: {} ± {sigma} for {want}",
                e.term.name(),
                e.value
            );
        }
        assert!(fit.rms_um < 0.2, "{}", fit.rms_um);
    }

    #[test]
    fn the_identifiability_table_is_the_fits_own_rank() {
        // Two SVDs of two codes: `ident` (nalgebra's SVD of the scaled design) and the fit's
        // engine (eigen-decomposition of its normal equations), on each plan family.
        let full = data_points_mm(&plan(&spec(Dialect::Linuxcnc), &Calibration::DEFAULT).unwrap());
        for points in [
            cone_points(&[0.0]),
            cone_points(&[30.0, 60.0]),
            cone_points(&[0.0, 30.0, 60.0]),
            full,
        ] {
            let id = super::super::ident::identifiability(&points);
            let dd = exact_dd_um(&points, [10.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0; 3]);
            let fit = super::super::fit::fit_linear(&points, &dd).unwrap();
            assert_eq!(fit.rank, id.rank_with_reference);
            let mut unseen: Vec<String> = fit
                .undetermined
                .iter()
                .flatten()
                .map(|t| t.name())
                .collect();
            unseen.sort();
            let mut not: Vec<String> = id
                .determined
                .iter()
                .filter(|(_, d)| !d)
                .map(|(t, _)| t.name())
                .collect();
            not.sort();
            assert_eq!(unseen, not);
        }
    }

    #[test]
    fn what_each_plan_family_determines() {
        // Rows one per mm of the data arcs, columns scaled to unit norm (see `ident`).
        // One height: 5 of the 10 terms, and the instrument's calibration adds nothing.
        let one = cones(&[0.0]);
        assert_eq!((one.rank, one.rank_with_reference), (5, 5));
        assert!(
            (one.condition - 2f64.sqrt()).abs() < 1e-9,
            "{}",
            one.condition
        );
        // Cones at two non-zero heights: 8, and still 8 with the calibration (the scale of Z and
        // the set-up along z are one combination of the two heights' radial terms).
        let two = cones(&[30.0, 60.0]);
        assert_eq!((two.rank, two.rank_with_reference), (8, 8));
        // Three heights 0, 30, 60 mm at D 90 mm: 9 of 10; all nine with the calibration as the
        // length reference, the mean scale against the instrument's scale left.
        let three = cones(&[0.0, 30.0, 60.0]);
        assert_eq!((three.rank, three.rank_with_reference), (9, 9));
        assert!(
            (11.0..11.7).contains(&three.condition),
            "{}",
            three.condition
        );
        assert_eq!(three.confounded.len(), 1);
        let names: Vec<String> = three.confounded[0].iter().map(|(t, _)| t.name()).collect();
        assert_eq!(names, ["scale_x", "scale_y", "scale_z", "instrument_scale"]);
        // With the zx and yz 220° arcs (their 180° data arcs): still 9, better conditioned.
        let p = plan(&spec(Dialect::Linuxcnc), &Calibration::DEFAULT).unwrap();
        let all = super::super::ident::identifiability(&data_points_mm(&p));
        assert_eq!((all.rank, all.rank_with_reference), (9, 9));
        assert!((10.2..10.8).contains(&all.condition), "{}", all.condition);
        assert!(all.determined.iter().all(|(_, d)| *d));
    }

    #[test]
    fn the_default_cones_are_at_a_third_and_two_thirds_of_d() {
        let p = plan(&spec(Dialect::Linuxcnc), &Calibration::DEFAULT).unwrap();
        let hs: Vec<(Plane, f64, f64)> = p
            .circles
            .iter()
            .map(|c| (c.plane, c.height_mm, c.d_mm))
            .collect();
        assert_eq!(hs.len(), 5);
        assert_eq!(
            &hs[..3].iter().map(|h| h.1).collect::<Vec<_>>(),
            &[0.0, 30.0, 60.0]
        );
        assert_eq!((hs[3].0, hs[4].0), (Plane::Zx, Plane::Yz));
        for (_, _, d) in hs {
            assert!((d - 90.0).abs() < 1e-3, "{d}");
        }
    }
}
