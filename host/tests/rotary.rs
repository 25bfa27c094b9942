//! Seed 002 (six errors of a rotary axis): the paper's C-table data, synthetic round trips with
//! hidden errors, and bad input through the CLI. The synthetic tests are round trips (the data
//! made by `length_change`, the model they fit): they check the fits, not a sign; the signs are
//! checked against a physical swinging head in `tests/tests/rotary_truth.rs` (issue 21).
use std::path::{Path, PathBuf};

use jdbb::rotary::six_errors::{
    length_change, per_angle, placement, read_table, Axis, FourierProblem, Geometry, Kind, Table,
};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
mod common;
use common::jdbb;

/// The paper's Table 1 (C turntable), as in ../shared/data/dbb_c_turntable_table1.csv: kept here
/// so the test runs from a fresh clone.
const C_TABLE1: &str = "angle_deg,dl1_radial_mm,dl1_tangential_mm,dl1_axial_mm,dl2_radial_mm,dl2_tangential_mm,dl3_radial_mm,dl3_tangential_mm
0,-0.0002,0.0082,0.0143,-0.0148,0.0040,0.0017,0.0061
20,0.0522,0.0032,0.0140,0.0379,0.0018,0.0530,0.0023
40,0.1005,0.0174,0.0140,0.0856,0.0179,0.1025,0.0163
60,0.1433,0.0485,0.0140,0.1271,0.0512,0.1427,0.0487
80,0.1698,0.0915,0.0142,0.1519,0.0953,0.1704,0.0922
100,0.1799,0.1411,0.0142,0.1599,0.1457,0.1804,0.1421
120,0.1741,0.1913,0.0143,0.1526,0.1957,0.1725,0.1921
140,0.1510,0.2378,0.0143,0.1275,0.2408,0.1492,0.2373
160,0.1134,0.2715,0.0144,0.0879,0.2732,0.1112,0.2708
180,0.0663,0.2910,0.0142,0.0403,0.2903,0.0647,0.2896
200,0.0180,0.2934,0.0142,-0.0086,0.2910,0.0154,0.2907
220,-0.0283,0.2783,0.0141,-0.0541,0.2732,-0.0310,0.2747
240,-0.0686,0.2482,0.0142,-0.0933,0.2417,-0.0702,0.2439
260,-0.0967,0.2069,0.0141,-0.1196,0.1992,-0.0982,0.2020
280,-0.1105,0.1604,0.0139,-0.1309,0.1515,-0.1110,0.1533
300,-0.1071,0.1105,0.0137,-0.1256,0.1026,-0.1073,0.1060
320,-0.0864,0.0654,0.0139,-0.1029,0.0578,-0.0844,0.0618
340,-0.0484,0.0295,0.0139,-0.0633,0.0236,-0.0468,0.0267
360,-0.0002,0.0080,0.0136,-0.0145,0.0037,0.0020,0.0061
";

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn json(out: &std::process::Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "jdbb failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Known answers from the paper's C-table data: the axial displacement error of Table 3
/// (max 14.4, min 13.6, avg 14.079 µm) is the axial run itself (eq. 14), and the ~0.15 mm
/// once-per-revolution term of every radial and tangential run is one constant centre offset.
#[test]
fn c_table_reproduces_table3_axial_and_explains_the_centring() {
    let dir = tempfile::tempdir().unwrap();
    let f = write(dir.path(), "c.csv", C_TABLE1);
    let v = json(&jdbb(&[
        "rotary",
        "--axis",
        "c",
        "--table",
        f.to_str().unwrap(),
        "--json",
    ]));
    let dz = v["scale_free"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["name"] == "dz_um")
        .unwrap();
    assert!((dz["max"].as_f64().unwrap() - 14.4).abs() < 1e-9);
    assert!((dz["min"].as_f64().unwrap() - 13.6).abs() < 1e-9);
    assert!((dz["avg"].as_f64().unwrap() - 14.079).abs() < 5e-4, "{dz}");
    let c = &v["centring"];
    let off = c["offset_um"].as_f64().unwrap();
    assert!((140.0..152.0).contains(&off), "{c}");
    // One offset explains all six first harmonics to a few µm, in one rotation sense only.
    assert!(c["misfit_um"].as_f64().unwrap() < 5.0, "{c}");
    assert!(c["other_sense_misfit_um"].as_f64().unwrap() > 100.0, "{c}");
    assert_eq!(c["sense"].as_f64().unwrap(), -1.0);
    // What is left after the per-run mean and first harmonic is a few µm, like the paper's errors.
    for h in v["harmonics"].as_array().unwrap() {
        assert!(h["rest_max_um"].as_f64().unwrap() < 4.0, "{h}");
    }
}

/// Six errors as low-order Fourier series: (constant, cos γ, sin γ, cos 2γ, sin 2γ) each.
fn hidden_errors(rng: &mut impl Rng) -> Vec<[f64; 5]> {
    (0..6)
        .map(|k| {
            let s = if k < 3 { 5e-3 } else { 5e-5 }; // 5 µm, 5e-5 rad
            [0.0; 5].map(|_| rng.gen_range(-s..s))
        })
        .collect()
}

fn eval(coef: &[[f64; 5]], gamma: f64) -> [f64; 6] {
    let mut e = [0.0; 6];
    for (k, c) in coef.iter().enumerate() {
        e[k] = c[0]
            + c[1] * gamma.cos()
            + c[2] * gamma.sin()
            + c[3] * (2.0 * gamma).cos()
            + c[4] * (2.0 * gamma).sin();
    }
    e
}

const GEOM: Geometry = Geometry {
    l1_mm: Some(150.0),
    l2_mm: Some(100.0),
    h1_mm: Some(60.0),
    h3_mm: Some(160.0),
    reversed: false,
};

/// A table like the paper's with hidden errors, per-run zero offsets and noise.
fn synthetic(axis: Axis, coef: &[[f64; 5]], offsets_mm: &[f64], noise_mm: f64, seed: u64) -> Table {
    let header = match axis {
        Axis::C => C_TABLE1.lines().next().unwrap().to_string(),
        Axis::B => "angle_deg,dl1_radial_mm,dl1_tangential_mm,dl1_axial_mm,dl2_radial_mm,dl2_tangential_mm,dl2_axial_mm".into(),
    };
    let angles: Vec<f64> = match axis {
        Axis::C => (0..18).map(|i| i as f64 * 20.0).collect(),
        Axis::B => (0..21).map(|i| -(i as f64) * 5.0).collect(),
    };
    let mut text = header + "\n";
    for &a in &angles {
        text += &format!("{a}");
        for _ in 0..offsets_mm.len() {
            text += ",0";
        }
        text += "\n";
    }
    let mut t = jdbb::rotary::six_errors::parse_table(Path::new("synthetic.csv"), &text).unwrap();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, noise_mm.max(1e-300)).unwrap();
    for (run, &off) in t.runs.iter_mut().zip(offsets_mm) {
        let pl = placement(axis, run, &GEOM).unwrap();
        for (y, &a) in run.values_mm.iter_mut().zip(&angles) {
            let g = a.to_radians();
            *y = length_change(axis, &eval(coef, g), g, run.kind, pl)
                + off
                + if noise_mm > 0.0 {
                    noise.sample(&mut rng)
                } else {
                    0.0
                };
        }
    }
    t
}

/// The paper's per-angle least squares recovers the six C errors exactly from noise-free runs
/// (no offsets), and finds the B head's per-angle problem rank-deficient at every angle (εx and
/// εz enter only as εx cos β − εz sin β, and with δx, δz through H).
#[test]
fn per_angle_recovers_c_errors_and_flags_b_rank_deficiency() {
    let mut rng = rand::rngs::StdRng::seed_from_u64(5);
    let coef = hidden_errors(&mut rng);
    let t = synthetic(Axis::C, &coef, &[0.0; 7], 0.0, 1);
    let fits = per_angle(Axis::C, &t, &GEOM).unwrap();
    for (f, &a) in fits.iter().zip(&t.angles_deg) {
        let truth = eval(&coef, a.to_radians());
        for (k, (got, want)) in f.params.iter().zip(truth).enumerate() {
            let tol = if k < 3 { 1e-9 } else { 1e-11 };
            assert!((got - want).abs() < tol, "angle {a} error {k}");
        }
        assert!(f.undetermined.is_empty());
    }
    let tb = synthetic(Axis::B, &coef, &[0.0; 6], 0.0, 1);
    let fits = per_angle(Axis::B, &tb, &GEOM).unwrap();
    for (f, &a) in fits.iter().zip(&tb.angles_deg) {
        // Rank 5 of 6 at every angle: one null direction, which involves εx or εz (both in
        // general; at β = −90° only εx with δz, at β = 0 only εz with δx, through H).
        assert_eq!(f.undetermined.len(), 1, "angle {a}");
        let g = &f.undetermined[0];
        assert!(g.contains(&3) || g.contains(&5), "angle {a}: {g:?}");
        if a % 90.0 != 0.0 {
            assert!(g.contains(&3) && g.contains(&5), "angle {a}: {g:?}");
        }
    }
}

/// Fourier fit of all runs at once: with hidden errors, unknown per-run zero offsets and 0.5 µm
/// noise, every coefficient the fit calls determined is within 3σ of the truth.
#[test]
fn fourier_fit_recovers_determined_coefficients_within_3_sigma() {
    use jdbb::numerics::lsq::{least_squares, LsqOptions};
    for (axis, n_runs) in [(Axis::C, 7), (Axis::B, 6)] {
        let mut rng = rand::rngs::StdRng::seed_from_u64(42);
        let coef = hidden_errors(&mut rng);
        let offsets: Vec<f64> = (0..n_runs).map(|_| rng.gen_range(-0.05..0.05)).collect();
        let t = synthetic(axis, &coef, &offsets, 0.5e-3, 9);
        let prob = FourierProblem::new(axis, &t, &GEOM, 2, true).unwrap();
        let n = jdbb::numerics::lsq::Problem::n_params(&prob);
        let fit = least_squares(&prob, &vec![0.0; n], &LsqOptions::default()).unwrap();
        assert!(
            (fit.rms - 0.5e-3).abs() < 0.25e-3,
            "{axis:?} rms {}",
            fit.rms
        );
        let mut determined = 0;
        for i in 0..30 {
            let truth = coef[i / 5][i % 5];
            if let Some(s) = fit.sigma[i] {
                determined += 1;
                assert!(
                    (fit.params[i] - truth).abs() <= 3.0 * s,
                    "{axis:?} {}: {} vs {} (σ {s})",
                    prob.param_name(i, &t),
                    fit.params[i],
                    truth
                );
            }
        }
        // The C runs determine most of the 30 coefficients; setup offsets cost a few.
        assert!(
            determined >= if axis == Axis::C { 18 } else { 6 },
            "{axis:?}: {determined}"
        );
        assert!(!fit.undetermined.is_empty());
    }
}

fn fails_with(args: &[&str], want: &str) {
    let out = jdbb(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains(want), "stderr: {err}\nwanted: {want}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn bad_tables_give_located_errors_and_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let run = |name: &str, text: &str, want: &str| {
        let f = write(dir.path(), name, text);
        fails_with(
            &["rotary", "--axis", "c", "--table", f.to_str().unwrap()],
            want,
        );
    };
    run(
        "h.csv",
        "angle,dl1_radial_mm\n0,1\n",
        "h.csv:1:1: first column must be `angle_deg`",
    );
    run(
        "k.csv",
        "angle_deg,dl1_radial_mm,dl1_sideways_mm\n0,1,2\n",
        "k.csv:1:25: column `dl1_sideways_mm` is not",
    );
    let mut few = String::from("angle_deg,dl1_radial_mm\n");
    for a in [0, 90, 180, 270] {
        few += &format!("{a},0.001\n");
    }
    run("few.csv", &few, "only 4 distinct angles");
    run(
        "n.csv",
        "angle_deg,dl1_radial_mm\n0,0.1\n20,x\n",
        "n.csv:3:4: dl1_radial_mm: `x` is not a number",
    );
    // The table from the paper reads fine with its own path.
    let f = write(dir.path(), "c.csv", C_TABLE1);
    let t = read_table(&f).unwrap();
    assert_eq!(t.runs.len(), 7);
    assert_eq!(t.runs[2].kind, Kind::Axial);
}
