//! A circular test (ISO 230-4 style: each circle counter-clockwise, then
//! clockwise) on a machine with chosen errors, written as the `t_s,x_mm,y_mm,z_mm,d_mm` CSV that
//! `jdbb diagnose` reads. For users (what does backlash look like?) and for the tests.
//!
//! The machine errors come from `jdbb_core::machine` (the shared seed 000 models); set-up
//! offset, length offset and servo mismatch are added here. D is the exact distance
//! |p + δ + c| + e, then noise and reading resolution are applied.
//!
//! The folder `simulate/`: this module simulates a test on a machine with chosen errors;
//! [`machine`] (the machine TOML) and [`record_sim`]: a plan's program run on a machine and
//! recorded as `jdbb record` records it; [`progress`]: where a recording stands against its
//! plan while it is made. May use: [`crate::model`], [`crate::plan`], [`crate::sync`];
//! nothing of `diagnose` or `report`.
// Index loops over the axes (k in 0..3) and samples mirror the equations; keep them.
#![allow(clippy::needless_range_loop)]
pub mod machine;
pub mod progress;
pub mod record_sim;
use std::io::Write;

use jdbb_core::machine::{AxisErrors, MachineErrors};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use crate::model::{Effect, EffectSet, Path};
use crate::{Error, Result};

/// One effect with its parameters (in the effect's parameter units, see
/// [`Effect::param_names`]).
#[derive(Debug, Clone, PartialEq)]
pub struct EffectValue {
    pub effect: Effect,
    pub params: Vec<f64>,
}

/// Parse `name=value[@phase_deg]` or `name=v1,v2,..` (all parameters, e.g. `setup_offset=5,-3,0`;
/// `backlash_x=10,5` is lost motion of 10 µm at the positive end and 5 µm at the negative).
pub fn parse_effect(s: &str) -> Result<EffectValue> {
    let (name, val) = s.split_once('=').ok_or_else(|| {
        Error::Usage(format!(
            "--effect `{s}`: expected name=value, e.g. scale_x=20 or cyclic_x=3@45"
        ))
    })?;
    let effect = Effect::parse(&name.trim().to_ascii_lowercase()).ok_or_else(|| {
        let names: Vec<String> = Effect::all().iter().map(|e| e.name()).collect();
        Error::Usage(format!(
            "--effect: unknown effect `{name}`; known: {}",
            names.join(", ")
        ))
    })?;
    let num = |t: &str| -> Result<f64> {
        t.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| Error::Usage(format!("--effect {name}: `{t}` is not a number")))
    };
    let (vals, phase) = match val.split_once('@') {
        Some((v, ph)) => (v, Some(num(ph)?.to_radians())),
        None => (val, None),
    };
    let list: Vec<f64> = vals.split(',').map(num).collect::<Result<_>>()?;
    // `backlash_x=pos,neg`: lost motion at the positive and the negative end of the travel.
    let effect = match (effect, list.len()) {
        (Effect::Backlash(a), 2) => Effect::BacklashEnds(a),
        (e, _) => e,
    };
    let from_value = if list.len() == 1 {
        effect.params_from_value(list[0], phase.unwrap_or(0.0))
    } else {
        None
    };
    let params = if list.len() == effect.n_params() && phase.is_none() && list.len() > 1 {
        list
    } else if let Some(p) = from_value {
        p
    } else {
        return Err(Error::Usage(format!(
            "--effect {name}: give {}all {} parameters ({})",
            match (effect.params_from_value(1.0, 0.0), effect.periodic_axis()) {
                (None, _) => "",
                (Some(_), Some(_)) => "one value, optionally @phase_deg, or ",
                (Some(_), None) => "one value or ",
            },
            effect.n_params(),
            effect.param_names().join(",")
        )));
    };
    Ok(EffectValue { effect, params })
}

/// The path of a test: circles of the given radii at the given heights in a plane.
#[derive(Debug, Clone)]
pub struct PathSpec {
    pub radii_mm: Vec<f64>,
    pub heights_mm: Vec<f64>,
    /// Plane axes (i, j) and normal axis n, e.g. (0, 1, 2) for xy.
    pub plane: (usize, usize, usize),
    pub feed_mm_min: f64,
    pub rate_hz: f64,
}

/// Largest number of samples [`nominal_path`] makes: `simulate` holds the whole path (time,
/// position, velocity, acceleration, direction and pitch phase, with D: about 140 bytes per
/// sample), so this bounds it to about 700 MB. Ten minutes at 5 kHz is 3 M samples.
pub const MAX_SAMPLES: usize = 5_000_000;

impl PathSpec {
    /// Check that the test can be meant and made: radii in (0, 10 000] mm, heights within
    /// ±10 000 mm, feed in [0.1, 100 000] mm/min, rate in (0, 1 MHz], and at most
    /// [`MAX_SAMPLES`] samples. The message names the limit.
    pub fn validate(&self) -> Result<()> {
        if self.radii_mm.is_empty() || self.heights_mm.is_empty() {
            return Err(Error::Usage(
                "give at least one --radius and one --height".into(),
            ));
        }
        if let Some(r) = self
            .radii_mm
            .iter()
            .find(|r| !(**r > 0.0 && **r <= 10_000.0))
        {
            return Err(Error::Usage(format!(
                "--radius {r}: a circle's radius is in (0, 10000] mm"
            )));
        }
        if let Some(h) = self
            .heights_mm
            .iter()
            .find(|h| !(h.is_finite() && h.abs() <= 10_000.0))
        {
            return Err(Error::Usage(format!(
                "--height {h}: a height is within ±10000 mm"
            )));
        }
        if !(0.1..=100_000.0).contains(&self.feed_mm_min) {
            return Err(Error::Usage(format!(
                "--feed {}: the feed is 0.1 to 100000 mm/min",
                self.feed_mm_min
            )));
        }
        if !(self.rate_hz > 0.0 && self.rate_hz <= 1e6) {
            return Err(Error::Usage(format!(
                "--rate {}: the sample rate is above 0 and at most 1000000 Hz",
                self.rate_hz
            )));
        }
        let n = self.sample_count();
        if n > MAX_SAMPLES as f64 {
            return Err(Error::Usage(format!(
                "this test would have {n:.3e} samples; simulate makes at most {MAX_SAMPLES}: lower --rate, raise --feed, or use fewer or smaller circles"
            )));
        }
        Ok(())
    }

    /// Number of samples [`nominal_path`] makes (as f64, so an absurd spec cannot overflow).
    pub fn sample_count(&self) -> f64 {
        let dt = 1.0 / self.rate_hz;
        let per_height: f64 = self
            .radii_mm
            .iter()
            .map(|&r| {
                let period = std::f64::consts::TAU * r / (self.feed_mm_min / 60.0);
                2.0 * (period / dt).round().max(8.0)
            })
            .sum();
        per_height * self.heights_mm.len() as f64
    }
}

/// Sample the nominal path: for every (radius, height) a full circle counter-clockwise from
/// angle 0, then clockwise back, with a 1 s pause between circles.
pub fn nominal_path(spec: &PathSpec) -> (Vec<f64>, Vec<[f64; 3]>) {
    let mut t = vec![];
    let mut p = vec![];
    let mut t0 = 0.0;
    let dt = 1.0 / spec.rate_hz;
    for &h in &spec.heights_mm {
        for &r in &spec.radii_mm {
            let omega = spec.feed_mm_min / 60.0 / r; // rad/s
            let period = std::f64::consts::TAU / omega;
            let n = (period / dt).round().max(8.0) as usize;
            for dirn in [1.0, -1.0] {
                for s in 0..n {
                    let frac = s as f64 / n as f64;
                    let th = if dirn > 0.0 {
                        std::f64::consts::TAU * frac
                    } else {
                        std::f64::consts::TAU * (1.0 - frac)
                    };
                    let mut q = [0.0; 3];
                    q[spec.plane.0] = r * th.cos();
                    q[spec.plane.1] = r * th.sin();
                    q[spec.plane.2] = h;
                    t.push(t0 + s as f64 * dt);
                    p.push(q);
                }
                t0 += n as f64 * dt;
            }
            t0 += 1.0;
        }
    }
    (t, p)
}

/// Exact distances (mm) of a machine with `effects` along `path` (velocity and direction from the
/// path), before noise. The servo delay is a true delay: axis k is where the nominal path was
/// τ_k earlier (linear interpolation between path samples; the path's velocity and acceleration
/// where t − τ_k falls outside the samples around it).
pub fn distances_mm(path: &Path, effects: &[EffectValue]) -> Result<Vec<f64>> {
    let mut m = MachineErrors::default();
    let mut c_um = [0.0; 3];
    let mut e_um = 0.0;
    let mut drift_um_per_min = 0.0;
    let mut delay_ms = [0.0f64; 3]; // per-axis delay τ_k (ms)
    let mut spikes: Vec<(usize, f64, f64)> = vec![]; // (axis, h µm, τ ms)
    let mut path_effects: Vec<EffectValue> = vec![];
    for ev in effects {
        let p = &ev.params;
        let pitch = |k: usize| {
            path.pitch_mm[k].ok_or_else(|| {
                Error::Usage(format!(
                    "{} needs the pitch of axis {}: add --pitch {}=..",
                    ev.effect.name(),
                    ['x', 'y', 'z'][k],
                    ['x', 'y', 'z'][k]
                ))
            })
        };
        match ev.effect {
            Effect::SetupOffset => c_um = [p[0], p[1], p[2]],
            Effect::LengthOffset => e_um += p[0],
            Effect::Drift => drift_um_per_min += p[0],
            Effect::Scale(a) => m.axes[a.index()].scale_um_per_m += p[0],
            Effect::ScaleMismatch(pair) => {
                let (i, j) = pair.axes();
                m.axes[i.index()].scale_um_per_m += 0.5 * p[0];
                m.axes[j.index()].scale_um_per_m -= 0.5 * p[0];
            }
            Effect::Scale2(a) => m.axes[a.index()].scale2_um_per_m2 += p[0],
            // Dead bands and bows need the path's reversals and travel: the model's own
            // evaluation (a round trip with the fit, not an independent truth).
            Effect::Backlash(_)
            | Effect::BacklashEnds(_)
            | Effect::Straightness(..)
            | Effect::LateralPlay(..)
            | Effect::ScaleDrift(_)
            | Effect::PositionDrift(_)
            | Effect::FollowingError => path_effects.push(ev.clone()),
            Effect::Cyclic(a) => {
                let ax: &mut AxisErrors = &mut m.axes[a.index()];
                ax.pitch_mm = pitch(a.index())?;
                ax.cyclic_um = p[0].hypot(p[1]);
                ax.cyclic_phase_rad = p[1].atan2(p[0]);
            }
            Effect::Interference(a) => {
                let ax: &mut AxisErrors = &mut m.axes[a.index()];
                ax.pitch_mm = pitch(a.index())?;
                ax.interference_um_per_mm_s = p[0].hypot(p[1]);
                ax.interference_phase_rad = p[1].atan2(p[0]);
            }
            Effect::Squareness(pair) => {
                let k = match pair {
                    crate::model::Pair::Xy => 0,
                    crate::model::Pair::Yz => 1,
                    crate::model::Pair::Zx => 2,
                };
                m.squareness_um_per_m[k] += p[0];
            }
            Effect::ServoMismatch(pair) => {
                let (i, j) = pair.axes();
                delay_ms[i.index()] += p[1] + 0.5 * p[0];
                delay_ms[j.index()] += p[1] - 0.5 * p[0];
            }
            Effect::ReversalSpike(a) => {
                if p[1].is_nan() || p[1] <= 0.0 {
                    return Err(Error::Usage(format!(
                        "{}: the decay time tau_ms must be positive",
                        ev.effect.name()
                    )));
                }
                spikes.push((a.index(), p[0], p[1]));
            }
        }
    }
    let t0 = path.t_s.first().copied().unwrap_or(0.0);
    let along_path = EffectSet::new(path_effects.iter().map(|e| e.effect).collect());
    let along_theta: Vec<f64> = path_effects.iter().flat_map(|e| e.params.clone()).collect();
    Ok((0..path.len())
        .map(|i| {
            let v = path.v_mm_s[i];
            let dir = path.dir[i];
            let d = m.error_um(path.p_mm[i], v, dir);
            let mut q = path.p_mm[i];
            if !path_effects.is_empty() {
                q = along_path.displaced(path, i, &along_theta).0;
            }
            for k in 0..3 {
                // The table ball sits at +c: the spindle ball is at p + δ − c from it.
                q[k] += (d[k] - c_um[k]) * 1e-3;
                if delay_ms[k] != 0.0 {
                    q[k] += delayed_mm(path, i, k, 1e-3 * delay_ms[k]) - path.p_mm[i][k];
                }
            }
            for &(k, h, tau) in &spikes {
                if let Some(r) = path.last_reversal(k, path.t_s[i]) {
                    let dt_ms = 1e3 * (path.t_s[i] - r.t_s);
                    q[k] -= 1e-3 * h * f64::from(r.new_dir) * (-dt_ms / tau).exp();
                }
            }
            let drift_mm = 1e-3 * drift_um_per_min * (path.t_s[i] - t0) / 60.0;
            (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() + e_um * 1e-3 + drift_mm
        })
        .collect())
}

/// Axis `k` of the nominal path at t_i − τ (τ in s, either sign): interpolated between the two
/// samples around that time when they are neighbours of sample i, else extrapolated from sample i
/// with its velocity and acceleration.
fn delayed_mm(path: &Path, i: usize, k: usize, tau_s: f64) -> f64 {
    let t = path.t_s[i] - tau_s;
    let n = path.len();
    let b = path.t_s.partition_point(|&x| x < t).clamp(1, n.max(2) - 1);
    let a = b - 1;
    let near = a + 3 >= i && b <= i + 3;
    if n >= 2 && near && path.t_s[a] <= t && t <= path.t_s[b] {
        let f = (t - path.t_s[a]) / (path.t_s[b] - path.t_s[a]);
        path.p_mm[a][k] + f * (path.p_mm[b][k] - path.p_mm[a][k])
    } else {
        path.p_mm[i][k] - tau_s * path.v_mm_s[i][k] + 0.5 * tau_s * tau_s * path.a_mm_s2[i][k]
    }
}

/// Add Gaussian noise (σ µm, finite; negative counts as 0) and round to the reading resolution
/// (µm, 0 = none).
pub fn measure(d_mm: &mut [f64], sigma_um: f64, resolution_um: f64, seed: u64) {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let sigma = if sigma_um.is_finite() {
        sigma_um.max(0.0)
    } else {
        0.0
    };
    let normal = Normal::new(0.0, sigma).expect("finite sigma");
    for d in d_mm.iter_mut() {
        if sigma_um > 0.0 {
            *d += normal.sample(&mut rng) * 1e-3;
        }
        if resolution_um > 0.0 {
            let q = resolution_um * 1e-3;
            *d = (*d / q).round() * q;
        }
    }
}

/// Write the diagnosis CSV.
pub fn write_csv(out: &mut dyn Write, path: &Path, d_mm: &[f64]) -> std::io::Result<()> {
    writeln!(out, "t_s,x_mm,y_mm,z_mm,d_mm")?;
    for i in 0..path.len() {
        let p = path.p_mm[i];
        writeln!(
            out,
            "{:.6},{:.7},{:.7},{:.7},{:.8}",
            path.t_s[i], p[0], p[1], p[2], d_mm[i]
        )?;
    }
    Ok(())
}

/// Parse `xy`, `yz`, `zx` into (i, j, normal).
pub fn parse_plane(s: &str) -> Result<(usize, usize, usize)> {
    match s.to_ascii_lowercase().as_str() {
        "xy" => Ok((0, 1, 2)),
        "yz" => Ok((1, 2, 0)),
        "zx" => Ok((2, 0, 1)),
        _ => Err(Error::Usage(format!("--plane `{s}`: use xy, yz or zx"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effect_arguments_parse() {
        let e = parse_effect("scale_x=20").unwrap();
        assert_eq!(e.params, vec![20.0]);
        let e = parse_effect("cyclic_y=2@90").unwrap();
        assert!(e.params[0].abs() < 1e-12 && (e.params[1] - 2.0).abs() < 1e-12);
        let e = parse_effect("setup_offset=5,-3,1").unwrap();
        assert_eq!(e.params, vec![5.0, -3.0, 1.0]);
        assert!(parse_effect("scale_w=1")
            .unwrap_err()
            .to_string()
            .contains("unknown effect"));
        assert!(parse_effect("setup_offset=5").is_err());
        assert!(parse_effect("scale_x").is_err());
    }

    #[test]
    fn ideal_machine_on_a_circle_gives_the_radius() {
        let spec = PathSpec {
            radii_mm: vec![50.0],
            heights_mm: vec![0.0],
            plane: (0, 1, 2),
            feed_mm_min: 1000.0,
            rate_hz: 100.0,
        };
        let (t, p) = nominal_path(&spec);
        // One circle each way: 2π·50 mm at 1000/60 mm/s, 100 Hz.
        let n = (std::f64::consts::TAU * 50.0 / (1000.0 / 60.0) * 100.0).round() as usize;
        assert_eq!(t.len(), 2 * n);
        let path = Path::new(t, p, [None; 3]);
        let d = distances_mm(&path, &[]).unwrap();
        assert!(d.iter().all(|d| (d - 50.0).abs() < 1e-12));
        // Play b on x: the axis lags its motion by b/2, D changes by ∓(b/2)·cos θ (seed 000
        // eq. 16 with f = −b).
        let ev = parse_effect("backlash_x=10").unwrap();
        let d = distances_mm(&path, &[ev]).unwrap();
        let i = n / 8 + 3; // ccw, θ ≈ 45°: moving −x → δx = +b/2 → +(b/2)·cos θ
        let th = path.p_mm[i][1].atan2(path.p_mm[i][0]);
        assert!(((d[i] - 50.0) * 1e3 - 5.0 * th.cos()).abs() < 1e-3);
    }
}
