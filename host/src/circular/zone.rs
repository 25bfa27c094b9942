//! ISO 230-4 figures of each circle with the minimum-zone centre: circular deviation G per
//! direction (the radial width of the minimum zone of that trace), the bidirectional zone, and
//! hysteresis H; plus the test conditions a person compares runs by (radius, height, feed).
//!
//! ISO 230-4 lets the centre of G be the least-squares or the minimum-zone circle's; this module
//! uses the minimum zone ([`crate::numerics::mzc`]), which never gives a larger G. The traces are
//! the plotted measured deviations (the least-squares set-up of all samples removed), so the
//! zone centres are reported relative to that set-up centre. H is the largest difference of the
//! ccw and cw mean deviations in a 1° bin, as in [`super::runs::circle_g_h`]; a centre common to
//! both directions does not change it.
use super::model::Path;
use super::runs::{circle_g_h, Circle, Run};
use crate::numerics::mzc::{minimum_zone, MinimumZone};
use crate::Result;

/// One circle of the test with its conditions and its minimum-zone G and H.
#[derive(Debug, Clone, PartialEq)]
pub struct CircleZone {
    pub radius_mm: f64,
    pub height_mm: f64,
    /// Median speed of the nominal path over the circle's samples, mm/min (the feed as run).
    pub feed_mm_min: f64,
    pub samples: usize,
    /// Minimum zone of the counter-clockwise trace; None if the circle was not run that way.
    pub ccw: Option<MinimumZone>,
    /// Minimum zone of the clockwise trace.
    pub cw: Option<MinimumZone>,
    /// Minimum zone of both traces together (bidirectional circular deviation).
    pub both: Option<MinimumZone>,
    /// Hysteresis H, µm.
    pub h_um: f64,
}

impl CircleZone {
    /// G of this circle: the larger of the two directions' minimum-zone widths, µm.
    pub fn g_um(&self) -> f64 {
        [self.ccw, self.cw]
            .iter()
            .flatten()
            .map(|z| z.width_um)
            .fold(0.0, f64::max)
    }
}

/// The [`CircleZone`] of every circle of `runs`, from the plotted deviations `dev_um` at
/// `angle_rad` (see the module docs).
pub fn circle_zones(
    path: &Path,
    angle_rad: &[f64],
    dev_um: &[f64],
    circles: &[Circle],
    runs: &[Run],
) -> Result<Vec<CircleZone>> {
    let mut out = Vec::with_capacity(circles.len());
    for (c, circle) in circles.iter().enumerate() {
        let pick = |want: Option<bool>| -> (Vec<f64>, Vec<f64>) {
            let mut a = vec![];
            let mut d = vec![];
            for run in runs
                .iter()
                .filter(|r| r.circle == c && want.is_none_or(|w| r.ccw == w))
            {
                a.extend_from_slice(&angle_rad[run.range.clone()]);
                d.extend_from_slice(&dev_um[run.range.clone()]);
            }
            (a, d)
        };
        let zone = |(a, d): (Vec<f64>, Vec<f64>)| -> Result<Option<MinimumZone>> {
            // A zone needs directions spread round the circle; a stub of a run has none.
            if a.len() < 16 {
                return Ok(None);
            }
            minimum_zone(&a, &d).map(Some)
        };
        let ccw = zone(pick(Some(true)))?;
        let cw = zone(pick(Some(false)))?;
        let both = zone(pick(None))?;
        let mut speeds: Vec<f64> = runs
            .iter()
            .filter(|r| r.circle == c)
            .flat_map(|r| r.range.clone())
            .map(|i| {
                let v = path.v_mm_s[i];
                (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
            })
            .collect();
        let samples = speeds.len();
        let feed_mm_min = if samples > 0 {
            60.0 * *speeds.select_nth_unstable_by(samples / 2, f64::total_cmp).1
        } else {
            f64::NAN
        };
        let (_, h_um) = circle_g_h(angle_rad, dev_um, runs, c);
        out.push(CircleZone {
            radius_mm: circle.radius_mm,
            height_mm: circle.height_mm,
            feed_mm_min,
            samples,
            ccw,
            cw,
            both,
            h_um,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::runs::{angles, split_runs_at, MAX_RUN_STEP_RAD};
    use super::super::simulate::{nominal_path, PathSpec};
    use super::*;

    #[test]
    fn zones_of_an_offset_trace_remove_the_offset_and_keep_the_shape() {
        // Two radii, ccw then cw; the deviation is a 3 µm eccentricity (which the minimum zone
        // removes) plus a 2 µm 3-lobe shape (peak-to-valley 4 µm) and, on cw only, 1 µm more.
        let spec = PathSpec {
            radii_mm: vec![40.0, 80.0],
            heights_mm: vec![0.0],
            plane: (0, 1, 2),
            feed_mm_min: 1200.0,
            rate_hz: 200.0,
        };
        let (t, p) = nominal_path(&spec);
        let path = Path::new(t, p, [None; 3]);
        let angle = angles(&path.p_mm, (0, 1));
        let (circles, runs) =
            split_runs_at(&path.t_s, &path.p_mm, &angle, (0, 1), MAX_RUN_STEP_RAD);
        let mut dev = vec![0.0; path.len()];
        for run in &runs {
            for i in run.range.clone() {
                let a = angle[i];
                dev[i] = 3.0 * a.cos() + 2.0 * (3.0 * a).sin() + if run.ccw { 0.0 } else { 1.0 };
            }
        }
        let zones = circle_zones(&path, &angle, &dev, &circles, &runs).unwrap();
        assert_eq!(zones.len(), 2);
        for z in &zones {
            assert!((z.feed_mm_min - 1200.0).abs() < 1.0, "{}", z.feed_mm_min);
            let ccw = z.ccw.unwrap();
            let cw = z.cw.unwrap();
            assert!((ccw.width_um - 4.0).abs() < 1e-3, "{ccw:?}");
            assert!((cw.width_um - 4.0).abs() < 1e-3);
            assert!((ccw.centre_um[0] - 3.0).abs() < 1e-3 && ccw.centre_um[1].abs() < 1e-3);
            assert!((cw.radius_offset_um - ccw.radius_offset_um - 1.0).abs() < 1e-3);
            assert!((z.both.unwrap().width_um - 5.0).abs() < 1e-3);
            // H bins by 1°: where a bin's ccw and cw samples differ, the 3-lobe shape's slope
            // (0.1 µm/°) moves the bin means a little.
            assert!((z.h_um - 1.0).abs() < 0.02, "{}", z.h_um);
            assert!((z.g_um() - 4.0).abs() < 1e-3);
        }
    }
}
