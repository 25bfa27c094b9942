//! A volumetric record synchronised across all its elements: each element of the plan (an xy
//! cone at its height, a zx or yz arc in its plane) found in one record from D alone, with its
//! start and its feed; and where the plan puts each element in time ([`on_circle_s`]), to cut a
//! record into its elements and check them against the plan.
//!
//! Every element is one of the plan's circles, entered by its own radial feed-in from a dwell and
//! left by its feed-out, and the moves along the shell between elements keep D away from the
//! next element's level until its feed-in. So the plane test's synchronisation
//! ([`crate::sync::synchronise`]) finds each element in turn, as it finds the circles of a plane
//! test: the plan's 3-D segments carry each cone's height and each arc's plane, which give the
//! levels of D to look for and the nominal position of every data sample
//! ([`crate::sync::data_path`]). [`elements`] states what it found per element.
//!
//! Not built yet: the joint diagnosis. The plane diagnosis's selection run over all elements'
//! data at once is wrong (measured on the G-code machine with errors on all three axes: its
//! angles, runs and partial-arc rules are those of one main plane, so the arcs fall into hundreds
//! of "circles" and most effects go unnamed), so `jdbb diagnose` still refuses a volumetric plan.
//!
//! May use: [`crate::sync`], [`crate::plan`] and this module's siblings.
use crate::plan::{Plan, Plane, Segment};
use crate::sync::Sync;

use super::plan::element_kind;

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

/// The time the machine spends on circle `k` of `plan` at the programmed feed, as (moving s,
/// standing s): its arcs, and the dwells from the corner at its feed-in to the corner before its
/// feed-out (the corner dwells, the reversal dwell). A feed override of f stretches the moving
/// part by 1/f; the dwells do not follow it. None if the plan has no arc of circle `k`.
pub fn on_circle_s(plan: &Plan, k: usize) -> Option<(f64, f64)> {
    let of_k = |s: &Segment| matches!(s, Segment::Arc { circle, .. } if *circle == k);
    let dwell = |i: usize| matches!(plan.segments.get(i), Some(Segment::Dwell { .. }));
    let mut first = plan.segments.iter().position(of_k)?;
    let mut last = plan.segments.iter().rposition(of_k)?;
    if first > 0 && dwell(first - 1) {
        first -= 1;
    }
    if dwell(last + 1) {
        last += 1;
    }
    let (mut moving_s, mut standing_s) = (0.0, 0.0);
    for s in &plan.segments[first..=last] {
        match s {
            Segment::Dwell { seconds } => standing_s += seconds,
            _ => moving_s += s.nominal_duration_s().unwrap_or(0.0),
        }
    }
    Some((moving_s, standing_s))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::build::{plan as make_plan, PlanSpec};
    use crate::plan::{Dialect, Plane};
    use jdbb_core::calib::Calibration;

    #[test]
    fn a_circle_is_its_two_senses_at_the_feed_and_its_three_dwells() {
        let spec = PlanSpec::machine_test(
            &[90.0],
            &[0.0],
            Plane::Xy,
            1200.0,
            [100.0, 50.0, -20.0],
            Dialect::Linuxcnc,
        );
        let plan = make_plan(&spec, &Calibration::DEFAULT).unwrap();
        let (moving_s, standing_s) = on_circle_s(&plan, 0).unwrap();
        // Lead-in, 360° and overshoot of 180° each way: 2 × 720° of R 90 at 20 mm/s.
        let expect = 2.0 * 4.0 * std::f64::consts::PI * 90.0 / 20.0;
        assert!((moving_s - expect).abs() < 1e-6, "{moving_s} {expect}");
        let dwells: Vec<f64> = plan
            .segments
            .iter()
            .filter_map(|s| match s {
                Segment::Dwell { seconds } => Some(*seconds),
                _ => None,
            })
            .collect();
        // Before the feed-in, the corner, the reversal, the corner, after the feed-out: the
        // middle three are on the circle.
        assert_eq!(dwells.len(), 5, "{dwells:?}");
        let on: f64 = dwells[1..4].iter().sum();
        assert!((standing_s - on).abs() < 1e-12, "{standing_s} {on}");
        assert!(on_circle_s(&plan, 1).is_none());
    }
}
