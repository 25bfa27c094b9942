//! A cyclic error the diagnosis was not told to look for: without `--pitch` the cyclic and
//! interference effects are not candidates, so a screw's once-per-turn error stays in the
//! residual. Where the residual is above its noise, its spectrum against the position along each
//! moving axis says which pitch to try: the residual is averaged in bins of [`BIN_MM`] of the
//! axis coordinate, and a sine and cosine (with a straight line) are fitted to the bins at every
//! candidate pitch from [`MIN_PITCH_MM`] to [`MAX_PITCH_MM`]; the strongest pitch is named when
//! its amplitude is at least [`CLEAR_RATIO`] times the strongest away from it.
use nalgebra::{Matrix4, Vector4};

use crate::model::{Axis, Path};

/// Shortest and longest pitch tried (mm): fine-pitch screws to long-lead ones.
pub const MIN_PITCH_MM: f64 = 1.0;
pub const MAX_PITCH_MM: f64 = 40.0;
/// Width of a bin of the axis coordinate (mm): a tenth of the shortest pitch.
pub const BIN_MM: f64 = 0.1;
/// How much the strongest pitch must exceed the strongest elsewhere to be named.
pub const CLEAR_RATIO: f64 = 2.0;
/// Relative distance in frequency within which the strongest pitch's own side lobes lie, not
/// counted as the rest it must stand out from.
pub const SIDE_LOBES: f64 = 0.3;
/// The residual is above its noise when its RMS exceeds this multiple of the sample-to-sample
/// noise (the RMS of successive differences over √2).
pub const ABOVE_NOISE: f64 = 1.3;

/// A pitch the residual suggests trying with `--pitch`.
#[derive(Debug, Clone, PartialEq)]
pub struct PitchHint {
    /// The axis whose position the residual's cyclic part follows.
    pub axis: Axis,
    /// The pitch (mm) of the strongest sine in the residual against that position.
    pub pitch_mm: f64,
    /// Its amplitude in the binned residual (µm).
    pub amplitude_um: f64,
    /// Its amplitude over the strongest at a pitch away from it.
    pub clearness: f64,
}

/// The pitch to try, from `resid_um` (per sample of `path`, measured minus model, µm), when no
/// pitch was given for any moving axis, the residual is above its noise and one pitch stands
/// out clearly; None otherwise.
pub fn pitch_hint(path: &Path, resid_um: &[f64]) -> Option<PitchHint> {
    let moving: Vec<Axis> = Axis::ALL.into_iter().filter(|&a| path.moves(a)).collect();
    if moving.iter().any(|a| path.pitch_mm[a.index()].is_some()) || resid_um.len() < 16 {
        return None;
    }
    let ms = resid_um.iter().map(|r| r * r).sum::<f64>() / resid_um.len() as f64;
    let diff_ms = resid_um
        .windows(2)
        .map(|w| (w[1] - w[0]).powi(2))
        .sum::<f64>()
        / (resid_um.len() - 1) as f64;
    let noise_um = (diff_ms / 2.0).sqrt();
    if ms.sqrt() <= ABOVE_NOISE * noise_um {
        return None;
    }
    moving
        .into_iter()
        .filter_map(|a| axis_peak(path, resid_um, a))
        .max_by(|x, y| x.amplitude_um.total_cmp(&y.amplitude_um))
        .filter(|h| h.clearness >= CLEAR_RATIO)
}

/// The strongest pitch of the residual binned along axis `a`, with its clearness.
fn axis_peak(path: &Path, resid_um: &[f64], a: Axis) -> Option<PitchHint> {
    let k = a.index();
    let (lo, hi) = path
        .p_mm
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p[k]), hi.max(p[k]))
        });
    let span_mm = hi - lo;
    if span_mm.is_nan() || span_mm <= 2.0 * MIN_PITCH_MM {
        return None;
    }
    let n = (span_mm / BIN_MM).ceil() as usize + 1;
    // Per bin: the sums of the residual and of the axis' direction cosine along the bar (how
    // much of an error of the axis D sees), and the count.
    let mut sum = vec![(0.0, 0.0, 0usize); n];
    for (p, r) in path.p_mm.iter().zip(resid_um) {
        let b = (((p[k] - lo) / BIN_MM) as usize).min(n - 1);
        let len_mm = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        sum[b].0 += r;
        sum[b].1 += p[k] / len_mm.max(1e-9);
        sum[b].2 += 1;
    }
    let bins: Vec<Bin> = sum
        .iter()
        .enumerate()
        .filter(|(_, s)| s.2 > 0)
        .map(|(b, &(r, u, c))| Bin {
            x_mm: lo + (b as f64 + 0.5) * BIN_MM,
            resid_um: r / c as f64,
            u: u / c as f64,
        })
        .collect();
    // Frequencies (1/mm) on a grid a tenth of the span's resolution, then refined about the peak.
    let df = 0.1 / span_mm;
    let (f_lo, f_hi) = (1.0 / MAX_PITCH_MM, 1.0 / MIN_PITCH_MM);
    let steps = ((f_hi - f_lo) / df).ceil() as usize;
    let scan: Vec<(f64, f64)> = (0..=steps)
        .map(|i| {
            let f = f_lo + i as f64 * df;
            (f, amplitude_um(&bins, f))
        })
        .collect();
    let &(f_peak, _) = scan.iter().max_by(|x, y| x.1.total_cmp(&y.1))?;
    let (f_best, a_best) = (-10..=10)
        .map(|j| {
            let f = f_peak + j as f64 * df / 10.0;
            (f, amplitude_um(&bins, f))
        })
        .max_by(|x, y| x.1.total_cmp(&y.1))?;
    // Away from the peak: beyond its side lobes, which the direction cosine's weighting (D sees
    // an axis' error most at the ends of its travel on the circle) makes strong within some
    // 25 % of its frequency.
    let rest = scan
        .iter()
        .filter(|(f, _)| (f / f_best - 1.0).abs() > SIDE_LOBES)
        .map(|s| s.1)
        .fold(0.0, f64::max);
    Some(PitchHint {
        axis: a,
        pitch_mm: 1.0 / f_best,
        amplitude_um: a_best,
        clearness: a_best / rest.max(1e-300),
    })
}

/// The residual's mean over samples whose axis coordinate falls in one bin.
struct Bin {
    /// The bin's centre, mm.
    x_mm: f64,
    /// The mean residual, µm.
    resid_um: f64,
    /// The mean direction cosine of the axis along the bar: D sees u·δ of an axis error δ.
    u: f64,
}

/// Amplitude (µm, of the axis' error) of the sine of frequency `f` (1/mm) along the axis,
/// as D sees it (times the direction cosine), fitted with a straight line to `bins`.
fn amplitude_um(bins: &[Bin], f: f64) -> f64 {
    let mut ata = Matrix4::<f64>::zeros();
    let mut atb = Vector4::<f64>::zeros();
    let x0 = bins[0].x_mm;
    for b in bins {
        let ph = std::f64::consts::TAU * f * b.x_mm;
        let row = Vector4::new(b.u * ph.sin(), b.u * ph.cos(), 1.0, b.x_mm - x0);
        ata += row * row.transpose();
        atb += row * b.resid_um;
    }
    ata.cholesky().map_or(0.0, |c| {
        let s = c.solve(&atb);
        s[0].hypot(s[1])
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::{diagnose, Options};
    use crate::model::Effect;
    use crate::simulate::{distances_mm, measure, nominal_path, EffectValue, PathSpec};

    /// A circle of r 60 mm in XY with backlash and, optionally, a cyclic error of X at
    /// `cyclic_pitch_mm`; diagnosed without `--pitch`.
    fn diagnosed(cyclic_pitch_mm: Option<f64>) -> Option<PitchHint> {
        let spec = PathSpec {
            radii_mm: vec![60.0],
            heights_mm: vec![0.0],
            plane: (0, 1, 2),
            feed_mm_min: 1000.0,
            rate_hz: 100.0,
        };
        let (t, p) = nominal_path(&spec);
        let mut effects = vec![EffectValue {
            effect: Effect::Backlash(Axis::X),
            params: vec![5.0],
        }];
        let mut pitch = [None; 3];
        if let Some(p) = cyclic_pitch_mm {
            pitch[0] = Some(p);
            effects.push(EffectValue {
                effect: Effect::Cyclic(Axis::X),
                params: vec![1.5, 0.8],
            });
        }
        let simulated = Path::new(t.clone(), p.clone(), pitch);
        let mut d = distances_mm(&simulated, &effects).unwrap();
        measure(&mut d, 0.3, 0.1, 5);
        let d = diagnose(&Path::new(t, p, [None; 3]), &d, &Options::default()).unwrap();
        d.pitch_hint
    }

    #[test]
    fn a_hidden_cyclic_error_names_its_pitch_and_a_clean_record_names_none() {
        let h = diagnosed(Some(8.0)).expect("a hint for the 8 mm cyclic error");
        assert_eq!(h.axis, Axis::X, "{h:?}");
        assert!((h.pitch_mm - 8.0).abs() < 0.1, "{h:?}");
        assert_eq!(diagnosed(None), None);
    }
}
