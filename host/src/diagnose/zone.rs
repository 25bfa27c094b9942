//! ISO 230-4 figures of each circle with the minimum-zone centre: circular deviation G per
//! direction (the radial width of the minimum zone of that trace), the bidirectional zone, and
//! hysteresis H; plus the test conditions a person compares runs by (radius, height, feed).
//!
//! ISO 230-4 lets the centre of G be the least-squares or the minimum-zone circle's; this module
//! uses the minimum zone ([`crate::numerics::mzc`]), which never gives a larger G. The traces are
//! the plotted measured deviations (the least-squares set-up of all samples removed), so the
//! zone centres are reported relative to that set-up centre. H is the largest difference of the
//! ccw and cw mean deviations in a 1° bin, as in [`crate::diagnose::runs::circle_g_h`]; a centre common to
//! both directions does not change it.
//!
//! # Filter
//! Beside G of the raw trace, G of the trace low-passed at [`FILTER_UPR`] = 50 undulations per
//! revolution ([`filtered_g_um`]): the instrument's noise is broadband, so on a raw trace of
//! thousands of samples its extremes add some six σ to G (a perfect machine with 0.5 µm noise:
//! G 3.75 µm), while the machine's geometry lives at a few undulations per revolution. 50 UPR is
//! the long-standing default cut-off of roundness measurement; the filter is the Gaussian
//! profile filter of ISO 16610-21. It also smooths what is faster than 1/50 of a turn — a
//! reversal spike of a few ms is mostly gone from the filtered G — so the raw G stays the test's
//! G (and the tolerance verdict's), the filtered G beside it.
use crate::diagnose::runs::{circle_g_h, Circle, Run};
use crate::model::Path;
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

/// The low-pass cut-off of the filtered G, undulations per revolution (UPR): 50 UPR, the
/// long-standing default of roundness measurement (see the module docs, *Filter*).
pub const FILTER_UPR: f64 = 50.0;

/// Angle bins per cut-off wavelength in [`lowpass_run`]: a bin is 1/20 of the shortest
/// undulation kept (0.36° at 50 UPR), fine enough that binning changes nothing the filter keeps.
const BINS_PER_CUTOFF: f64 = 20.0;

/// G (µm, minimum zone) of every circle's ccw and cw traces low-passed at `upr` undulations per
/// revolution ([`lowpass_run`] on each run), [ccw, cw] per circle of `0..circles`; None where the
/// circle was not run that way (or too little of it).
pub fn filtered_g_um(
    angle_rad: &[f64],
    dev_um: &[f64],
    runs: &[Run],
    circles: usize,
    upr: f64,
) -> Result<Vec<[Option<f64>; 2]>> {
    let mut out = vec![[None, None]; circles];
    for (c, slot) in out.iter_mut().enumerate() {
        for (k, ccw) in [true, false].into_iter().enumerate() {
            let (mut a, mut d) = (vec![], vec![]);
            for run in runs.iter().filter(|r| r.circle == c && r.ccw == ccw) {
                let (ra, rd) = lowpass_run(
                    &angle_rad[run.range.clone()],
                    &dev_um[run.range.clone()],
                    upr,
                );
                a.extend(ra);
                d.extend(rd);
            }
            if a.len() >= 16 {
                slot[k] = Some(minimum_zone(&a, &d)?.width_um);
            }
        }
    }
    Ok(out)
}

/// One run's trace (deviation µm against angle rad, in the run's order) low-passed at `upr`
/// undulations per revolution, as (angle, deviation) points: the samples are averaged in bins
/// of angle (the angle unwrapped along the run, so a run past 360° keeps both ends), and the bin
/// means are smoothed by the Gaussian profile filter of ISO 16610-21 with cut-off wavelength
/// λc = 2π/upr (weighting exp(−π(Δ/(αλc))²), α = √(ln 2/π): 50 % transmission at λc), the
/// weights renormalised where the run ends. Bins weigh the same whatever their samples, so a
/// standstill (a backlash's dead band) counts as one place on the circle, not as many.
fn lowpass_run(angle_rad: &[f64], dev_um: &[f64], upr: f64) -> (Vec<f64>, Vec<f64>) {
    use std::f64::consts::{PI, TAU};
    let Some(&first) = angle_rad.first() else {
        return (vec![], vec![]);
    };
    let lambda = TAU / upr;
    let width = lambda / BINS_PER_CUTOFF;
    let mut unwrapped = Vec::with_capacity(angle_rad.len());
    let mut acc = first;
    let mut prev = first;
    for &a in angle_rad {
        acc += (a - prev + PI).rem_euclid(TAU) - PI;
        prev = a;
        unwrapped.push(acc);
    }
    let lo = unwrapped.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = unwrapped.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let n = ((hi - lo) / width).floor() as usize + 1;
    let mut sum = vec![(0.0, 0.0, 0usize); n];
    for (&a, &d) in unwrapped.iter().zip(dev_um) {
        let bin = &mut sum[(((a - lo) / width) as usize).min(n - 1)];
        bin.0 += a;
        bin.1 += d;
        bin.2 += 1;
    }
    let bins: Vec<(f64, f64)> = sum
        .iter()
        .filter(|b| b.2 > 0)
        .map(|b| (b.0 / b.2 as f64, b.1 / b.2 as f64))
        .collect();
    let alpha_lambda = (2f64.ln() / PI).sqrt() * lambda;
    let reach = (BINS_PER_CUTOFF as usize) + 1;
    let mut out = (
        Vec::with_capacity(bins.len()),
        Vec::with_capacity(bins.len()),
    );
    for (i, &(a, _)) in bins.iter().enumerate() {
        let (mut w_sum, mut wd_sum) = (0.0, 0.0);
        for &(b, d) in &bins[i.saturating_sub(reach)..(i + reach + 1).min(bins.len())] {
            let w = (-PI * ((b - a) / alpha_lambda).powi(2)).exp();
            w_sum += w;
            wd_sum += w * d;
        }
        out.0.push(a);
        out.1.push(wd_sum / w_sum);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::runs::{angles, split_runs_at, MAX_RUN_STEP_RAD};
    use crate::simulate::{nominal_path, PathSpec};

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
