//! Round trip of the project's own simulator (issue 3, issue 21): data made by
//! `jdbb::simulate` — which evaluates the same effect models (`model`, core's
//! machine) on the same `Path` the fit uses — with effects drawn at random; the diagnosis runs
//! without being told and must name the effect, its value unbiased, and nothing else. Because
//! generator and fit share every convention (signs, pairings, phase origins), this checks the
//! statistics and the selection only, and that `jdbb simulate` and `jdbb diagnose` agree. The
//! truth for signs and conventions is the independent G-code machine:
//! `tests/tests/diagnose_truth.rs` (and `docs/tests.md`). Seeded, so every run draws the same
//! cases.
mod common;

use jdbb::diagnose::{diagnose, Diagnosis, Options};
use jdbb::model::{Axis, Effect, Pair, Path};
use jdbb::simulate::{distances_mm, measure, nominal_path, EffectValue, PathSpec};
use rand::{Rng, SeedableRng};

/// A circular test: ccw then cw circles at the radii, 200 Hz, 1000 mm/min, xy plane at height h.
fn run(
    radii: &[f64],
    h: f64,
    pitch: [Option<f64>; 3],
    effects: &[EffectValue],
    sigma_um: f64,
    seed: u64,
) -> Diagnosis {
    let spec = PathSpec {
        radii_mm: radii.to_vec(),
        heights_mm: vec![h],
        plane: (0, 1, 2),
        feed_mm_min: 1000.0,
        rate_hz: 200.0,
    };
    let (t, p) = nominal_path(&spec);
    let path = Path::new(t, p, pitch);
    let mut d = distances_mm(&path, effects).unwrap();
    measure(&mut d, sigma_um, 0.1, seed);
    diagnose(&path, &d, &Options::default()).unwrap()
}

fn ev(effect: Effect, params: Vec<f64>) -> EffectValue {
    EffectValue { effect, params }
}

/// Random set-up: table ball off by up to ±60 µm in x, y, bar length off by up to ±20 µm.
fn setup(rng: &mut impl Rng) -> Vec<EffectValue> {
    vec![
        ev(
            Effect::SetupOffset,
            vec![rng.gen_range(-60.0..60.0), rng.gen_range(-60.0..60.0), 0.0],
        ),
        ev(Effect::LengthOffset, vec![rng.gen_range(-20.0..20.0)]),
    ]
}

/// Machine effects found (set-up excluded).
fn machine(d: &Diagnosis) -> Vec<&jdbb::diagnose::Found> {
    d.effects.iter().filter(|f| !f.effect.is_setup()).collect()
}

/// The value of `name` is `truth` by the one tolerance rule (`common::tolerance`): within 5 % and
/// within 1 % + 3σ of |truth| (or `abs`, where larger), σ under 10 % of |truth| (or `abs`).
fn assert_value(d: &Diagnosis, name: &str, truth: f64, abs: f64) {
    let f = machine(d)
        .into_iter()
        .find(|f| f.effect.name() == name)
        .unwrap_or_else(|| panic!("{name} not found in {:?}", names(d)));
    let sigma = f.sigma.expect("a determined effect has a standard error");
    common::tolerance::assert_unbiased(name, f.value, sigma, truth, abs, "");
}

fn names(d: &Diagnosis) -> Vec<String> {
    machine(d).iter().map(|f| f.effect.name()).collect()
}

/// Round trip of `simulate` → `diagnose` (shares the fit's models; see the module docs).
#[test]
fn round_trip_of_simulate_names_a_hidden_random_effect_alone() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(2026);
    let pitch = [Some(10.0), Some(8.0), None];
    for case in 0..27 {
        let axis = if rng.gen_bool(0.5) { Axis::X } else { Axis::Y };
        let phase: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
        let sign = if rng.gen_bool(0.5) { 1.0 } else { -1.0 };
        // (hidden effect, its simulation parameters, reported name, reported value)
        let (effect, params, name, truth) = match case % 9 {
            0 => {
                // One radius: only scale_x − scale_y is identifiable.
                let a = sign * rng.gen_range(10.0..40.0);
                let (name, truth) = match axis {
                    Axis::X => ("scale_mismatch_xy", a),
                    _ => ("scale_mismatch_xy", -a),
                };
                (Effect::Scale(axis), vec![a], name.to_string(), truth)
            }
            1 => {
                // One radius: b·j² of axis j is the same data as a bow of the other axis i
                // towards j (i² = R² − j²); the bow is named, w = b·R², and the pair said.
                let b = sign * rng.gen_range(400.0..1500.0);
                let e = Effect::Scale2(axis);
                let other = if axis == Axis::X { Axis::Y } else { Axis::X };
                let name = Effect::Straightness(other, axis).name();
                (e, vec![b], name, f64::NAN)
            }
            2 => {
                let f = rng.gen_range(2.0..10.0);
                let e = Effect::Backlash(axis);
                (e, vec![f], e.name(), f)
            }
            3 => {
                let a = rng.gen_range(1.0..4.0);
                let e = Effect::Cyclic(axis);
                (e, e.params_from_value(a, phase).unwrap(), e.name(), a)
            }
            4 => {
                let b = rng.gen_range(0.06..0.2);
                let e = Effect::Interference(axis);
                (e, e.params_from_value(b, phase).unwrap(), e.name(), b)
            }
            5 => {
                let s = sign * rng.gen_range(20.0..60.0);
                let e = Effect::Squareness(Pair::Xy);
                (e, vec![s], e.name(), s)
            }
            6 => {
                let t = sign * rng.gen_range(0.1..0.6);
                let e = Effect::ServoMismatch(Pair::Xy);
                (e, vec![t, 0.0], e.name(), t)
            }
            7 => {
                let a = sign * rng.gen_range(10.0..40.0);
                let e = Effect::ScaleMismatch(Pair::Xy);
                (e, vec![a], e.name(), a)
            }
            _ => {
                let f = rng.gen_range(2.0..6.0);
                let e = Effect::Backlash(axis);
                (e, vec![f], e.name(), f)
            }
        };
        let mut effects = setup(&mut rng);
        effects.push(ev(effect, params));
        let radius = rng.gen_range(40.0..90.0);
        let sigma = rng.gen_range(0.1..0.5);
        let seed = rng.gen();
        let truth = if truth.is_nan() {
            effects.last().unwrap().params[0] * radius * radius * 1e-6
        } else {
            truth
        };
        let d = run(&[radius], 0.0, pitch, &effects, sigma, seed);
        assert_eq!(
            names(&d),
            vec![name.clone()],
            "case {case}: hidden {} (R {radius:.1} mm, σ {sigma:.2} µm)\n{}",
            effect.name(),
            jdbb::report::summary(&d)
        );
        // The absolute part of the bias bound, in the effect's unit.
        let abs = match effect {
            Effect::Interference(_) => 0.002,
            Effect::ServoMismatch(_) => 0.005,
            _ => 0.05,
        };
        assert_value(&d, &name, truth, abs);
        if let Effect::Scale2(j) = effect {
            assert!(
                d.confounded
                    .iter()
                    .any(|g| g.contains(&name) && g.contains(&Effect::Scale2(j).name())),
                "case {case}: the one-circle twin of {name} is not said: {:?}",
                d.confounded
            );
        }
        // The set-up is recovered too, and the fit leaves white noise.
        let c = &d.effects[0].params;
        assert!((c[0] - effects[0].params[0]).abs() < 0.5, "c_x {c:?}");
        assert!(
            d.final_rms_um < 1.3 * sigma.max(0.1),
            "rms {}",
            d.final_rms_um
        );
    }
}
