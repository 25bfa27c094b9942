//! Glitches: single samples (or a few in a row) of a record whose D lies far off the samples
//! around them — a loose cable, an encoder miscount, a corrupted value the device did not
//! catch. A glitch is data, not a crash: [`find`] names them, [`crate::sync::Record::read`]
//! sets them aside before anything else sees D, and [`describe`] says how many and where.
//!
//! # The test
//! For sample i, the medians of the [`SIDE`] samples before it and of the [`SIDE`] after it
//! (at a record's ends, the samples on the side that has them). Sample i is a glitch when it
//! lies beyond **both** medians on the same side, by more than the threshold each:
//!
//! threshold = max([`FLOOR_MM`], [`NOISE_FACTOR`]·σ, [`STEP_FACTOR`]·s)
//!
//! with σ the record's noise (1.4826 · the median |ΔD| between consecutive samples, / √2) and
//! s the median |ΔD| between consecutive samples around i (how fast D moves there: on a ramp a
//! sample lies up to a step from its neighbours). A real effect is never set aside:
//! - a step (a backlash, a spike's rise) puts each sample level with one side: no glitch;
//! - a reversal spike of several µm lasting ms is tens of samples at 1–5 kHz: the medians of
//!   its own samples follow it, and it is far below the floor besides;
//! - a ramp moves D by s per sample: a sample stands out of a smooth ramp by a fraction of s.
//!
//! A run of up to `SIDE / 2 - 1` glitches in a row is found whole (each side's median has a
//! majority of good samples); a longer excursion is not a glitch but an event of the test.
use std::fmt::Write;

/// Samples on each side of a sample that it is compared with.
pub const SIDE: usize = 8;

/// Least distance (mm) from its neighbours that makes a sample a glitch: 20 µm in one sample,
/// and back, is no machine's motion at 1–5 kHz (a reversal spike of several µm lasts ms).
pub const FLOOR_MM: f64 = 0.02;

/// Threshold in units of the record's noise σ.
pub const NOISE_FACTOR: f64 = 50.0;

/// Threshold in units of the local step of D between samples (ramps).
pub const STEP_FACTOR: f64 = 10.0;

/// Most samples the noise is estimated on (evenly spread): bounded time for any record.
const NOISE_SAMPLES: usize = 1 << 20;

/// Median of `v` (reordered); 0 for an empty slice.
fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    v.sort_unstable_by(f64::total_cmp);
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The record's noise σ (mm) from consecutive differences (robust: glitches and ramps are a
/// minority of them).
fn noise_mm(d: &[f64]) -> f64 {
    if d.len() < 2 {
        return 0.0;
    }
    let stride = (d.len() / NOISE_SAMPLES).max(1);
    let mut diffs: Vec<f64> = (1..d.len())
        .step_by(stride)
        .map(|i| (d[i] - d[i - 1]).abs())
        .collect();
    1.4826 * median(&mut diffs) / std::f64::consts::SQRT_2
}

/// Indices (ascending) of the glitches of `d_mm`, D in time order (module docs). Too few
/// samples to compare (fewer than 2·[`SIDE`] + 1): none.
pub fn find(d_mm: &[f64]) -> Vec<usize> {
    let n = d_mm.len();
    if n < 2 * SIDE + 1 {
        return vec![];
    }
    let sigma = noise_mm(d_mm);
    let base = FLOOR_MM.max(NOISE_FACTOR * sigma);
    let mut out = vec![];
    let (mut left, mut right, mut steps) = (
        Vec::with_capacity(SIDE),
        Vec::with_capacity(SIDE),
        Vec::with_capacity(2 * SIDE),
    );
    for i in 0..n {
        // The window of 2·SIDE + 1 samples around i, shifted inside the record at its ends.
        let start = i.saturating_sub(SIDE).min(n - 1 - 2 * SIDE);
        let window = &d_mm[start..=start + 2 * SIDE];
        left.clear();
        right.clear();
        for (k, &x) in window.iter().enumerate() {
            match (start + k).cmp(&i) {
                std::cmp::Ordering::Less => left.push(x),
                std::cmp::Ordering::Greater => right.push(x),
                std::cmp::Ordering::Equal => {}
            }
        }
        let x = d_mm[i];
        // Cheap first: a side's median lies within its range, so a sample within the base
        // threshold of a side's range (both ways) is no glitch of that side.
        let near = |s: &[f64]| {
            let (lo, hi) = s
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            !s.is_empty() && x <= lo + base && x >= hi - base
        };
        if near(&left) || near(&right) {
            continue;
        }
        let sides: Vec<f64> = [&mut left, &mut right]
            .into_iter()
            .filter(|s| !s.is_empty())
            .map(|s| x - median(s))
            .collect();
        // A sample within the base threshold of either side's median is no glitch.
        let lo = sides.iter().fold(f64::INFINITY, |m, v| m.min(v.abs()));
        let same_sign = sides.iter().all(|v| v > &0.0) || sides.iter().all(|v| v < &0.0);
        if lo <= base || !same_sign {
            continue;
        }
        steps.clear();
        steps.extend(window.windows(2).map(|w| (w[1] - w[0]).abs()));
        let step = median(&mut steps);
        if lo > STEP_FACTOR * step {
            out.push(i);
        }
    }
    out
}

/// A sample set aside as a glitch: its line in the file, its time (s after the record's first
/// sample) and its D (mm).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Glitch {
    pub line: usize,
    pub t_s: f64,
    pub d_mm: f64,
}

/// Most glitches a message lists one by one (the count is always whole).
pub const LISTED: usize = 5;

/// `set aside 2 glitch samples (D far off the samples around it: a loose cable, an encoder
/// miscount): line 1234 at 12.345 s (circle 1) D 50.000 mm, …`; `circle_of` names the circle a
/// time falls in (None: outside every circle). None without glitches.
pub fn describe(glitches: &[Glitch], circle_of: &dyn Fn(f64) -> Option<usize>) -> Option<String> {
    if glitches.is_empty() {
        return None;
    }
    let mut s = format!(
        "set aside {} glitch sample{} (D far off the samples around {}: a loose cable, an encoder miscount; the rest is used): ",
        glitches.len(),
        if glitches.len() == 1 { "" } else { "s" },
        if glitches.len() == 1 { "it" } else { "them" }
    );
    for (k, g) in glitches.iter().take(LISTED).enumerate() {
        if k > 0 {
            s.push_str(", ");
        }
        let _ = write!(s, "line {} at {:.3} s", g.line, g.t_s);
        match circle_of(g.t_s) {
            Some(c) => {
                let _ = write!(s, " (circle {})", c + 1);
            }
            None => s.push_str(" (outside the circles)"),
        }
        let _ = write!(s, " D {:.4} mm", g.d_mm);
    }
    if glitches.len() > LISTED {
        let _ = write!(s, " and {} more", glitches.len() - LISTED);
    }
    Some(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// D of a test at 1 kHz: a dwell at 90 mm, a ramp to 80 mm at 16.7 mm/s, a plateau with
    /// 0.2 µm noise, a reversal spike of 8 µm decaying over 5 ms and a backlash step of 30 µm.
    fn test_d() -> Vec<f64> {
        let mut d = vec![];
        let mut noise = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            noise ^= noise << 13;
            noise ^= noise >> 7;
            noise ^= noise << 17;
            (noise as f64 / u64::MAX as f64 - 0.5) * 0.0007
        };
        for _ in 0..500 {
            d.push(90.0 + rnd());
        }
        for k in 0..600 {
            d.push(90.0 - 0.0167 * k as f64 + rnd());
        }
        let level = *d.last().unwrap();
        for k in 0..3000 {
            let mut x = level + rnd();
            if k >= 1000 {
                x += 0.008 * (-((k - 1000) as f64) / 5.0).exp();
            }
            if k >= 2000 {
                x += 0.030;
            }
            d.push(x);
        }
        d
    }

    #[test]
    fn real_motion_is_never_a_glitch() {
        assert_eq!(find(&test_d()), Vec::<usize>::new());
    }

    #[test]
    fn single_glitches_and_short_runs_are_found() {
        let mut d = test_d();
        // One at 50 mm on the plateau, one on the ramp, a run of three, the first and last.
        for i in [2500, 800, 3300, 3301, 3302, 0, d.len() - 1] {
            d[i] = 50.0;
        }
        d[1600] += 0.1; // 100 µm for one sample
        let mut want = vec![0, 800, 1600, 2500, 3300, 3301, 3302, d.len() - 1];
        want.sort();
        assert_eq!(find(&d), want);
    }

    #[test]
    fn the_message_counts_and_places_them() {
        let g = |line, t_s| Glitch {
            line,
            t_s,
            d_mm: 50.0,
        };
        let all: Vec<Glitch> = (0..7).map(|k| g(10 + k, k as f64)).collect();
        let s = describe(&all, &|t| (t < 3.0).then_some(0)).unwrap();
        assert!(s.starts_with("set aside 7 glitch samples"), "{s}");
        assert!(
            s.contains("line 10 at 0.000 s (circle 1) D 50.0000 mm"),
            "{s}"
        );
        assert!(
            s.contains("line 13 at 3.000 s (outside the circles)"),
            "{s}"
        );
        assert!(s.ends_with("and 2 more"), "{s}");
        assert_eq!(describe(&[], &|_| None), None);
    }
}
