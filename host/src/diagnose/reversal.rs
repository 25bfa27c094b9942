//! Reversals as the trade reads them: at each end of each axis that reverses, the peak of the
//! excursion a person sees in the trace right after the reversal, and how long it lasts.
//!
//! A ballbar plot shows a reversal spike as a point of the trace standing out of the circle
//! where an axis reverses; the trade reads its height (µm, outward positive) per axis and per
//! end (the axis's positive and negative reversal), and ISO 230-4 / the ballbar makers' reports
//! list it that way. What stands out is whatever the static effects (backlash, scale,
//! squareness, …) do not explain: the residual of the diagnosis **plus** what a named reversal
//! spike of that axis takes out of it. Measured, not fitted to a shape, the peak is the same
//! number for a spike that jumps and decays (the model's `reversal_spike_k`), for stick-slip (the
//! error grows while the axis sticks, then releases) and for a ring, so a person can compare it
//! with the trace; the fitted spike's h is the same number only where the shape is the model's.
//!
//! # The measurement ([`reversal_peaks`])
//! For each reversal of axis k (time t_r, the end it reverses at), the samples from
//! [`BEFORE_MS`] before to [`AFTER_MS`] after it (and before the next reversal of any axis) are
//! pooled with those of the other reversals at the same end, by time since the reversal. The
//! pooled trace is smoothed by a running mean over n samples (n reversals at that end: about
//! one sample period of each); its largest |value| is the peak (signed as the radial
//! deviation: positive outward). Its σ is the residual's rms away from every reversal over
//! √(samples averaged) — the noise of the mean at the peak. The duration is the width of the
//! pooled trace at half its peak (FWHM, ms): τ·ln 2 for a spike that decays as e^(−Δt/τ).
use crate::model::{Axis, Effect, EffectSet, Path};

/// The pooled trace starts this long (ms) before the commanded reversal: an axis that lags its
/// command (a servo delay of a few ms, a loop's 1/Kv of 15–35 ms) reverses later, not earlier.
pub const BEFORE_MS: f64 = 5.0;

/// The pooled trace ends this long (ms) after the reversal: stick-slip releases within 25–95 ms
/// and a lightly damped mode of 18–40 Hz has decayed by e^(−ζωt) ≈ 1/e after 0.2–0.5 s.
pub const AFTER_MS: f64 = 400.0;

/// Which end of its travel an axis reverses at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum End {
    /// The axis reverses at the high end of its travel (moving + before, − after).
    Pos,
    /// The axis reverses at the low end.
    Neg,
}

impl End {
    /// The trade's word for the end: `pos` / `neg` (JSON, text).
    pub fn word(self) -> &'static str {
        match self {
            End::Pos => "pos",
            End::Neg => "neg",
        }
    }
}

/// What the trace after an axis's reversals looks like, named as the trade names it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// It stands out at the reversal and decays: a reversal spike (the axis lags at the
    /// reversal and catches up). Peaks within [`STICK_MS`] of the reversal.
    Spike,
    /// It grows after the reversal while the axis sticks and is released when it breaks free:
    /// stick-slip. Peaks later than [`STICK_MS`] after the reversal (25–95 ms inside a loop).
    StickSlip,
    /// It rings: at least [`RING_LOBES`] lobes of alternating sign above the noise after the
    /// peak, a structural mode kicked by the reversal.
    Vibration {
        /// Frequency of the ring (Hz), from the spacing of its lobes.
        frequency_hz: f64,
        /// Damping ratio ζ, from the decay of its lobes (e^(−ζ·2πf·t)).
        damping: f64,
        /// Amplitude (µm): the largest lobe.
        amplitude_um: f64,
    },
}

impl Shape {
    /// The trade's word: `spike`, `stick_slip`, `vibration` (JSON, text).
    pub fn word(&self) -> &'static str {
        match self {
            Shape::Spike => "spike",
            Shape::StickSlip => "stick_slip",
            Shape::Vibration { .. } => "vibration",
        }
    }
}

/// A trace that peaks later than this after the reversal (ms) grew there: stick-slip. A spike
/// peaks at its axis's own reversal, a servo delay (1–6 ms) after its command's.
pub const STICK_MS: f64 = 15.0;

/// Lobes of alternating sign (each beyond [`LOBE_SIGMAS`] σ) that make a trace a ring: a
/// stick-slip that overshoots once has two, a spike one.
pub const RING_LOBES: usize = 4;

/// A lobe counts where the trace goes this many σ (of a smoothed point) beyond zero.
pub const LOBE_SIGMAS: f64 = 4.0;

/// The peak a person sees in the trace after an axis's reversals at one end.
#[derive(Debug, Clone, PartialEq)]
pub struct ReversalPeak {
    /// The axis that reverses.
    pub axis: Axis,
    /// The end it reverses at.
    pub end: End,
    /// How many reversals at that end the record holds (pooled).
    pub reversals: usize,
    /// The peak of the pooled trace (µm, radial: positive outward).
    pub peak_um: f64,
    /// Its standard uncertainty from the noise (µm).
    pub peak_sigma_um: f64,
    /// Time from the reversal to the peak (ms).
    pub at_ms: f64,
    /// Width of the pooled trace at half its peak (ms): the peak's duration.
    pub duration_ms: f64,
    /// What it looks like: spike, stick-slip or vibration.
    pub shape: Shape,
}

/// The reversal peaks of every axis that reverses in `path`, per end, from the diagnosis's
/// residual `resid_um` (D − model, µm, one per sample) and its named effects `set` at `theta`:
/// the named reversal spikes' own deviation is added back, so the peak is what the trace shows
/// whether or not a spike was named (module docs).
pub fn reversal_peaks(
    path: &Path,
    resid_um: &[f64],
    set: &EffectSet,
    theta: &[f64],
) -> Vec<ReversalPeak> {
    let m = path.len().min(resid_um.len());
    if m == 0 {
        return vec![];
    }
    // The trace the reversals stand out of: residual + what the named spikes move D by.
    let mut trace: Vec<f64> = resid_um[..m].to_vec();
    let mut without = theta.to_vec();
    let mut any = false;
    for (e, &o) in set.effects.iter().zip(&set.offsets) {
        if let Effect::ReversalSpike(_) = e {
            without[o] = 0.0;
            any = true;
        }
    }
    if any {
        let with_mm = set.distances_mm(path, theta);
        let without_mm = set.distances_mm(path, &without);
        for ((t, a), b) in trace.iter_mut().zip(&with_mm).zip(&without_mm) {
            *t += 1e3 * (a - b);
        }
    }
    // Every reversal of any axis, in time: a window ends at the next one.
    let mut all_t: Vec<f64> = path.reversals.iter().flatten().map(|r| r.t_s).collect();
    all_t.sort_by(f64::total_cmp);
    // The noise away from every reversal's window.
    let near = |t: f64| {
        let i = all_t.partition_point(|&r| r <= t + 1e-3 * BEFORE_MS);
        i > 0 && t - all_t[i - 1] < 1e-3 * AFTER_MS
    };
    let quiet: Vec<f64> = (0..m)
        .filter(|&i| !near(path.t_s[i]))
        .map(|i| resid_um[i])
        .collect();
    let noise_um = if quiet.len() > 10 {
        (quiet.iter().map(|v| v * v).sum::<f64>() / quiet.len() as f64).sqrt()
    } else {
        (resid_um[..m].iter().map(|v| v * v).sum::<f64>() / m as f64).sqrt()
    };
    let mut out = vec![];
    for a in Axis::ALL {
        let k = a.index();
        for end in [End::Pos, End::Neg] {
            // At the high end the axis turns to −, at the low end to +.
            let want_dir: i8 = if end == End::Pos { -1 } else { 1 };
            let revs: Vec<f64> = path.reversals[k]
                .iter()
                .filter(|r| r.new_dir == want_dir)
                .map(|r| r.t_s)
                .collect();
            if revs.is_empty() {
                continue;
            }
            let mut pooled: Vec<(f64, f64)> = vec![];
            for &t_r in &revs {
                let next = all_t
                    .iter()
                    .copied()
                    .find(|&t| t > t_r + 1e-6)
                    .unwrap_or(f64::INFINITY);
                let lo = t_r - 1e-3 * BEFORE_MS;
                let hi = (t_r + 1e-3 * AFTER_MS).min(next - 1e-3 * BEFORE_MS);
                let i0 = path.t_s[..m].partition_point(|&t| t < lo);
                let i1 = path.t_s[..m].partition_point(|&t| t <= hi);
                pooled.extend((i0..i1).map(|i| (1e3 * (path.t_s[i] - t_r), trace[i])));
            }
            if let Some(p) = peak_of(&mut pooled, revs.len(), noise_um) {
                out.push(ReversalPeak {
                    axis: a,
                    end,
                    reversals: revs.len(),
                    ..p
                });
            }
        }
    }
    out
}

/// A named reversal spike where the trace after its axis's reversals rings at every end
/// ([`Shape::Vibration`]) or grows and releases at every end ([`Shape::StickSlip`]): its index
/// in `set` and why it is not a spike, in words. A ring is a structural mode kicked by the
/// reversal, left in the residual with its frequency stated (issue 26); stick-slip is named as
/// such in `reversal_peaks` with its peak per end. Neither is named as a spike, whose fitted
/// height would be neither's peak (35–44 % of a stick-slip's).
pub fn ringing_spike(
    path: &Path,
    d_mm: &[f64],
    set: &EffectSet,
    theta: &[f64],
) -> Option<(usize, String)> {
    let spikes: Vec<(usize, Axis)> = set
        .effects
        .iter()
        .enumerate()
        .filter_map(|(i, e)| match e {
            Effect::ReversalSpike(a) => Some((i, *a)),
            _ => None,
        })
        .collect();
    if spikes.is_empty() {
        return None;
    }
    let model_mm = set.distances_mm(path, theta);
    let resid_um: Vec<f64> = d_mm
        .iter()
        .zip(&model_mm)
        .map(|(d, m)| 1e3 * (d - m))
        .collect();
    let peaks = reversal_peaks(path, &resid_um, set, theta);
    spikes.into_iter().find_map(|(i, a)| {
        let ends: Vec<&ReversalPeak> = peaks.iter().filter(|p| p.axis == a).collect();
        let letter = a.letter().to_ascii_uppercase();
        let rings: Vec<(f64, f64)> = ends
            .iter()
            .filter_map(|p| match p.shape {
                Shape::Vibration {
                    frequency_hz,
                    damping,
                    ..
                } => Some((frequency_hz, damping)),
                _ => None,
            })
            .collect();
        let sticks = ends.iter().filter(|p| p.shape == Shape::StickSlip).count();
        if ends.is_empty() {
            None
        } else if rings.len() == ends.len() {
            let (f, z) = rings[0];
            Some((
                i,
                format!(
                    "the trace after {letter}'s reversals rings ({f:.1} Hz, damping ratio {z:.3}): vibration, not a spike (reversal_peaks)"
                ),
            ))
        } else if sticks == ends.len() {
            Some((
                i,
                format!(
                    "the trace after {letter}'s reversals grows, then releases: stick-slip, not a spike (reversal_peaks)"
                ),
            ))
        } else {
            None
        }
    })
}

/// A peak this many σ from zero is printed in the report's text (the JSON has every end): the
/// largest |mean| of pure noise over the few hundred points of a window is about 3σ.
pub const SHOWN_SIGMAS: f64 = 5.0;

/// The report's lines for `peaks`: per axis, each end's peak (µm, outward positive) and its
/// width at half height, in the trade's words; one line saying so where none stands out.
pub fn peaks_text(peaks: &[ReversalPeak]) -> String {
    use std::fmt::Write;
    if peaks.is_empty() {
        return String::new();
    }
    let mut s = String::new();
    let shown: Vec<&ReversalPeak> = peaks
        .iter()
        .filter(|p| p.peak_um.abs() >= SHOWN_SIGMAS * p.peak_sigma_um)
        .collect();
    if shown.is_empty() {
        let _ = writeln!(s, "reversal peaks: none stands out of the noise");
        return s;
    }
    let _ = writeln!(
        s,
        "reversal peaks (the trace after an axis reverses, µm outward, width at half height):"
    );
    for p in shown {
        let what = match p.shape {
            Shape::Spike => "reversal spike".to_string(),
            Shape::StickSlip => "stick-slip (grows while the axis sticks, then releases)".into(),
            Shape::Vibration {
                frequency_hz,
                damping,
                amplitude_um,
            } => format!(
                "vibration {frequency_hz:.1} Hz, damping ratio {damping:.3}, amplitude \
                 {amplitude_um:.2} µm (a structural mode kicked by the reversal)"
            ),
        };
        let _ = writeln!(
            s,
            "  {} {} end: {what}: {} µm, peaks {:.0} ms after the reversal, lasts {:.0} ms ({} reversals)",
            p.axis.letter().to_ascii_uppercase(),
            p.end.word(),
            crate::units::format_estimate(p.peak_um, Some(p.peak_sigma_um)),
            p.at_ms,
            p.duration_ms,
            p.reversals
        );
    }
    s
}

/// The peak, its σ, its time and its width at half height of `pooled` ((ms since the
/// reversal, µm) from `n` reversals), each point the mean of n consecutive pooled samples (about
/// one sample of each reversal: a wider mean would cut the top off a spike that jumps).
fn peak_of(pooled: &mut [(f64, f64)], n: usize, noise_um: f64) -> Option<ReversalPeak> {
    pooled.sort_by(|a, b| a.0.total_cmp(&b.0));
    let w = n.max(1);
    if pooled.len() < w + 2 {
        return None;
    }
    let smooth: Vec<(f64, f64)> = pooled
        .windows(w)
        .map(|win| {
            let t: f64 = win.iter().map(|p| p.0).sum();
            let v: f64 = win.iter().map(|p| p.1).sum();
            (t / w as f64, v / w as f64)
        })
        .collect();
    let (ip, &(at_ms, peak_um)) = smooth
        .iter()
        .enumerate()
        .max_by(|a, b| a.1 .1.abs().total_cmp(&b.1 .1.abs()))?;
    // Width at half height: from the peak outwards to where the trace first falls under half.
    let above = |v: f64| v * peak_um.signum() >= 0.5 * peak_um.abs();
    let mut lo = ip;
    while lo > 0 && above(smooth[lo - 1].1) {
        lo -= 1;
    }
    let mut hi = ip;
    while hi + 1 < smooth.len() && above(smooth[hi + 1].1) {
        hi += 1;
    }
    // Interpolated crossings (the edges of the band above half height).
    let cross = |i: usize, j: usize| -> f64 {
        let (ti, vi) = smooth[i];
        let (tj, vj) = smooth[j];
        let target = 0.5 * peak_um;
        if (vj - vi).abs() > 0.0 {
            ti + (target - vi) / (vj - vi) * (tj - ti)
        } else {
            ti
        }
    };
    let t_lo = if lo > 0 {
        cross(lo - 1, lo)
    } else {
        smooth[lo].0
    };
    let t_hi = if hi + 1 < smooth.len() {
        cross(hi, hi + 1)
    } else {
        smooth[hi].0
    };
    let point_sigma_um = noise_um / (w as f64).sqrt();
    let shape = match ring(&smooth[ip..], LOBE_SIGMAS * point_sigma_um) {
        Some(v) => v,
        None if at_ms > STICK_MS => Shape::StickSlip,
        None => Shape::Spike,
    };
    Some(ReversalPeak {
        axis: Axis::X,
        end: End::Pos,
        reversals: n,
        peak_um,
        peak_sigma_um: point_sigma_um,
        at_ms,
        duration_ms: (t_hi - t_lo).max(0.0),
        shape,
    })
}

/// The ring in `trace` ((ms, µm) from the peak on), if it has [`RING_LOBES`] lobes or more of
/// alternating sign beyond `threshold_um` (a lobe ends where the trace passes the threshold on
/// the other side: noise about zero does not split one): its frequency from the mean spacing
/// of the lobes' extremes (half a period each), its damping from the straight line through
/// ln |extreme| against time (slope −ζ·2πf), its amplitude the largest lobe.
fn ring(trace: &[(f64, f64)], threshold_um: f64) -> Option<Shape> {
    let mut lobes: Vec<(f64, f64)> = vec![];
    let mut sign = 0.0;
    for &(t, v) in trace {
        if v.abs() >= threshold_um && v.signum() != sign {
            sign = v.signum();
            lobes.push((t, v));
        } else if v.signum() == sign && v.abs() > lobes.last().map_or(0.0, |l| l.1.abs()) {
            if let Some(l) = lobes.last_mut() {
                *l = (t, v);
            }
        }
    }
    if lobes.len() < RING_LOBES {
        return None;
    }
    // The ring's regular part: up to the first spacing 30 % off the median (a lobe lost in the
    // noise merges two and doubles a spacing).
    let gaps: Vec<f64> = lobes.windows(2).map(|w| w[1].0 - w[0].0).collect();
    let regular = {
        let mut g = gaps.clone();
        g.sort_by(f64::total_cmp);
        let median = g[g.len() / 2];
        gaps.iter()
            .take_while(|&&d| (d / median - 1.0).abs() <= 0.3)
            .count()
    };
    lobes.truncate(regular + 1);
    if lobes.len() < RING_LOBES {
        return None;
    }
    let half_period_ms = (lobes[lobes.len() - 1].0 - lobes[0].0) / (lobes.len() - 1) as f64;
    if half_period_ms <= 0.0 {
        return None;
    }
    let frequency_hz = 1e3 / (2.0 * half_period_ms);
    // Least-squares slope of ln|A| against t (1/ms).
    let n = lobes.len() as f64;
    let (mt, ml) = lobes.iter().fold((0.0, 0.0), |(a, b), l| {
        (a + l.0 / n, b + l.1.abs().ln() / n)
    });
    let (sxy, sxx) = lobes.iter().fold((0.0, 0.0), |(a, b), l| {
        let dt = l.0 - mt;
        (a + dt * (l.1.abs().ln() - ml), b + dt * dt)
    });
    let slope_per_ms = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let damping = (-slope_per_ms * 1e3 / (std::f64::consts::TAU * frequency_hz)).max(0.0);
    let amplitude_um = lobes.iter().map(|l| l.1.abs()).fold(0.0, f64::max);
    Some(Shape::Vibration {
        frequency_hz,
        damping,
        amplitude_um,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A circle of radius 100 mm in XY at 1000 mm/min, both ways, sampled at 1 kHz, about the
    /// table ball.
    fn circle_both_ways() -> Path {
        let r = 100.0;
        let w = 1000.0 / 60.0 / r;
        let n = (std::f64::consts::TAU / w * 1000.0) as usize;
        let mut t = vec![];
        let mut p = vec![];
        for i in 0..2 * n {
            let ts = i as f64 * 1e-3;
            let th = if i < n {
                w * ts
            } else {
                w * (2.0 * n as f64 * 1e-3 - ts)
            };
            t.push(ts);
            p.push([r * th.cos(), r * th.sin(), 0.0]);
        }
        Path::new(t, p, [None; 3])
    }

    /// The radial trace of `glitch(end_is_pos, Δt_ms)` (µm, outward) after every reversal of X
    /// (until the next reversal of any axis).
    fn trace_of(path: &Path, glitch: impl Fn(bool, f64) -> f64) -> Vec<f64> {
        let mut all: Vec<f64> = path.reversals.iter().flatten().map(|r| r.t_s).collect();
        all.sort_by(f64::total_cmp);
        let mut resid = vec![0.0; path.len()];
        for r in &path.reversals[0] {
            let next = all
                .iter()
                .copied()
                .find(|&t| t > r.t_s)
                .unwrap_or(f64::INFINITY);
            for (i, v) in resid.iter_mut().enumerate() {
                let dt_ms = 1e3 * (path.t_s[i] - r.t_s);
                if dt_ms >= 0.0 && path.t_s[i] < next {
                    *v += glitch(r.new_dir < 0, dt_ms);
                }
            }
        }
        resid
    }

    fn x_at(peaks: &[ReversalPeak], end: End) -> &ReversalPeak {
        peaks
            .iter()
            .find(|p| p.axis == Axis::X && p.end == end)
            .unwrap_or_else(|| panic!("no X {end:?} peak in {peaks:?}"))
    }

    fn peaks_of(path: &Path, resid: &[f64]) -> Vec<ReversalPeak> {
        reversal_peaks(path, resid, &EffectSet::new(vec![]), &[])
    }

    /// A spike of the model's shape with different heights at the two ends of X: each end's
    /// peak is its height (radial, outward for an axis that sticks), its duration τ·ln 2, its
    /// shape a spike.
    #[test]
    fn a_decaying_spike_reads_as_its_height_per_end_lasting_tau_ln2() {
        let path = circle_both_ways();
        let (pos_um, neg_um, tau_ms) = (6.0, 3.0, 20.0);
        let resid = trace_of(&path, |pos, dt_ms| {
            (if pos { pos_um } else { neg_um }) * (-dt_ms / tau_ms).exp()
        });
        let peaks = peaks_of(&path, &resid);
        for (end, h) in [(End::Pos, pos_um), (End::Neg, neg_um)] {
            let p = x_at(&peaks, end);
            // The first sample after a reversal is up to 1 ms late: up to 5 % under h at τ 20 ms.
            assert!(
                (p.peak_um / h - 1.0).abs() < 0.05,
                "{end:?}: peak {:.3} µm, truth {h}",
                p.peak_um
            );
            let want = tau_ms * std::f64::consts::LN_2;
            assert!(
                (p.duration_ms / want - 1.0).abs() < 0.1,
                "{end:?}: lasts {:.2} ms, τ·ln 2 = {want:.2}",
                p.duration_ms
            );
            assert_eq!(p.shape, Shape::Spike, "{p:?}");
        }
    }

    /// Stick-slip: the error grows as the command leaves the stuck axis (quadratically, from a
    /// reversal at rest along the axis) for 40 ms, then releases over 10 ms: named stick-slip,
    /// its peak the trace's.
    #[test]
    fn a_growing_error_released_after_the_stick_is_stick_slip() {
        let path = circle_both_ways();
        let (peak_um, stick_ms) = (4.0, 40.0);
        let resid = trace_of(&path, |_, dt_ms| {
            if dt_ms < stick_ms {
                peak_um * (dt_ms / stick_ms).powi(2)
            } else {
                peak_um * (-(dt_ms - stick_ms) / 10.0).exp()
            }
        });
        let peaks = peaks_of(&path, &resid);
        for end in [End::Pos, End::Neg] {
            let p = x_at(&peaks, end);
            assert_eq!(p.shape, Shape::StickSlip, "{p:?}");
            // The trace is sampled at 1 kHz: the largest sample a person sees lies up to half a
            // sample period before the true top, where the rise is at 4·(39.5/40)² = 3.90 µm.
            let lowest_top_um = peak_um * ((stick_ms - 0.5) / stick_ms).powi(2);
            assert!(
                p.peak_um > 0.99 * lowest_top_um && p.peak_um < 1.01 * peak_um,
                "{p:?}"
            );
            assert!((p.at_ms - stick_ms).abs() < 2.0, "{p:?}");
        }
    }

    /// A ring of 25 Hz, ζ 0.03, 1.5 µm kicked at each reversal: vibration with its frequency
    /// within 3 %, its damping within 20 % and its amplitude within 5 %.
    #[test]
    fn a_ring_after_the_reversal_is_vibration_with_its_frequency_and_damping() {
        let path = circle_both_ways();
        let (f_hz, zeta, amp_um) = (25.0, 0.03, 1.5);
        let w = std::f64::consts::TAU * f_hz;
        let resid = trace_of(&path, |_, dt_ms| {
            let t = 1e-3 * dt_ms;
            amp_um * (-zeta * w * t).exp() * (w * t).cos()
        });
        let peaks = peaks_of(&path, &resid);
        let p = x_at(&peaks, End::Pos);
        let Shape::Vibration {
            frequency_hz,
            damping,
            amplitude_um,
        } = p.shape
        else {
            panic!("not named vibration: {p:?}");
        };
        assert!((frequency_hz / f_hz - 1.0).abs() < 0.03, "{p:?}");
        assert!((damping / zeta - 1.0).abs() < 0.2, "{p:?}");
        assert!((amplitude_um / amp_um - 1.0).abs() < 0.05, "{p:?}");
    }
}
