//! Where a plan's elements are in time: how long the machine stays on each circle (an xy cone, a
//! zx or yz arc), so that a record can be cut into its elements and checked against the plan.
use crate::plan::{Plan, Segment};

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
