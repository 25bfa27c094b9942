//! `jdbb rotary --axis b` against a physical swinging head (issue 21): the data come from
//! `jdbb_tests::rotary_truth`, a head whose axis line is offset and tilted, written from the
//! physics (Rodrigues rotations, the bar's real length between two balls) without the host's
//! six-error model. The host's Fourier fit (order 1) must find the location errors with their
//! signs, unbiased.
//!
//! **What a location error is in the six errors.** An axis line through o (off the nominal
//! pivot) turns the head about o instead of the pivot: the ball that was at P0 at B = 0 is at
//! o + R(β)(P0 − o) = R(β)P0 + (I − R(β))·o, a displacement δ(β) = (I − R(β))·o of the head's
//! origin. An axis leaning by the small rotation t = (tx, 0, tz) turns the head by
//! R_t R(β) R_tᵀ = (I + [(I − R(β))·t]×) R(β) to first order: a small rotation
//! ε(β) = (I − R(β))·t. With R(β)·v = cos β·v + sin β·(Y × v) for v ⊥ Y and Y × (vx, 0, vz) =
//! (vz, 0, −vx):
//!
//!   δx = ox − ox cos β − oz sin β,  δz = oz − oz cos β + ox sin β,  δy = 0,
//!   εx = tx − tx cos β − tz sin β,  εz = tz − tz cos β + tx sin β,  εy = 0.
//!
//! The harmonic part −R(β)·o turns with the head: it moves both balls alike in the head's frame
//! and only shifts each run's zero, so no run sees it (the fit must call those harmonics
//! undetermined). What the runs see is the constant: δ.const = o, ε.const = t, each location
//! error with its own sign.
use std::path::Path;

use jdbb_tests::rotary_truth::{BHead, CTable, Install, SpindleBall};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};

#[allow(dead_code)]
mod planned;

const BAR_MM: f64 = 150.0;
const L1_MM: f64 = 150.0;
const L2_MM: f64 = 250.0;
const H1_MM: f64 = 0.0;
/// The QC20's resolution, 0.1 µm: the scatter of runs averaged as the paper's.
const NOISE_MM: f64 = 0.1e-3;

/// The head as built: the axis 12 µm toward +X and 7 µm toward −Z of the nominal pivot, leaning
/// 30 µrad toward +Z (about +X) and 45 µrad toward +X (about +Z, negative).
const HEAD: BHead = BHead {
    offset_mm: [0.012, 0.0, -0.007],
    tilt_x_rad: 30e-6,
    tilt_z_rad: -45e-6,
};

/// Runs as the paper's B table: combination 1 at L1, combination 2 at L2, each radial,
/// tangential and axial; B from −120° to +30° (the machine's range) in 5° steps. Each run has its
/// own zero (a random offset) and noise.
fn table_text(head: &BHead, seed: u64, flip_radial: bool) -> String {
    let runs = [
        (1, L1_MM, Install::Radial, "radial"),
        (1, L1_MM, Install::Tangential, "tangential"),
        (1, L1_MM, Install::Axial, "axial"),
        (2, L2_MM, Install::Radial, "radial"),
        (2, L2_MM, Install::Tangential, "tangential"),
        (2, L2_MM, Install::Axial, "axial"),
    ];
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, NOISE_MM).unwrap();
    let zeros: Vec<f64> = runs.iter().map(|_| rng.gen_range(-0.02..0.02)).collect();
    let mut text = String::from("angle_deg");
    for (c, _, _, k) in &runs {
        text += &format!(",dl{c}_{k}_mm");
    }
    text += "\n";
    for i in 0..=30 {
        let b_deg = -120.0 + 5.0 * i as f64;
        text += &format!("{b_deg}");
        for ((_, l, install, _), zero) in runs.iter().zip(&zeros) {
            let ball = SpindleBall {
                l_mm: *l,
                h_mm: H1_MM,
            };
            let mut r = head.reading_mm(ball, *install, BAR_MM, b_deg.to_radians());
            if flip_radial && *install == Install::Radial {
                r = -r;
            }
            text += &format!(",{:.7}", r + zero + noise.sample(&mut rng));
        }
        text += "\n";
    }
    text
}

/// `jdbb rotary --axis b --order 1 --json` on the table: the Fourier coefficients by name, as
/// (value, σ) in the report's units (µm, 1e-5 rad).
fn fit(dir: &Path, text: &str) -> (Vec<(String, f64, Option<f64>)>, serde_json::Value) {
    let (coef, v) = rotary(
        dir,
        text,
        &[
            "--axis",
            "b",
            "--l1",
            &L1_MM.to_string(),
            "--l2",
            &L2_MM.to_string(),
            "--h1",
            &H1_MM.to_string(),
        ],
    );
    (coef, v["fourier"].clone())
}

/// `jdbb rotary <args> --order 1 --json` on the table `text`: the Fourier coefficients by name
/// as (value, σ) in the report's units (µm, 1e-5 rad), and the whole report.
fn rotary(
    dir: &Path,
    text: &str,
    args: &[&str],
) -> (Vec<(String, f64, Option<f64>)>, serde_json::Value) {
    let f = dir.join("runs.csv");
    std::fs::write(&f, text).unwrap();
    let out = std::process::Command::new(jdbb_tests::jdbb_bin())
        .arg("rotary")
        .args(args)
        .arg("--table")
        .arg(&f)
        .args(["--order", "1", "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let coef = v["fourier"]["coefficients"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["name"].as_str().unwrap().to_string(),
                c["value"].as_f64().unwrap(),
                c["sigma"].as_f64(),
            )
        })
        .collect();
    (coef, v)
}

/// The location errors of the axis line, with their signs, from a head built with them.
/// Truth (µm and 1e-5 rad, the report's units), from the physics in the module doc: the constant
/// terms are the offset and the lean themselves, δx.const = ox = +12, δz.const = oz = −7,
/// εx.const = tx = +3, εz.const = tz = −4.5; δy and εy have no harmonic. The harmonics of δx, δz,
/// εx, εz turn with the head and must be reported undetermined, not given a value.
///
/// What a flipped sign would do: an offset taken as the pivot's own displacement (δ = (R − I)·o)
/// or a tilt in the other sense flips the constant it shows as (−12 for +12: the check fails by
/// 24 µm against a bound of 0.3 µm + 3σ ≈ 0.5 µm); a radial bar read the other way (the table
/// ball on the pivot side) leaves no fit of the data at the noise
/// (`a_radial_bar_read_the_other_way_is_not_a_head`).
#[test]
fn b_head_axis_offset_and_tilt_are_found_with_their_signs() {
    let dir = tempfile::tempdir().unwrap();
    let (coef, fourier) = fit(dir.path(), &table_text(&HEAD, 3, false));
    let [ox, _, oz] = HEAD.offset_mm.map(|x| x * 1e3);
    let (tx, tz) = (HEAD.tilt_x_rad * 1e5, HEAD.tilt_z_rad * 1e5);
    let context = format!("{fourier:#}");
    let find = |name: &str| {
        coef.iter()
            .find(|(n, _, _)| n == name)
            .unwrap_or_else(|| panic!("no coefficient {name}: {context}"))
            .clone()
    };
    for (name, want) in [
        ("dx.const", ox),
        ("dz.const", oz),
        ("ex.const", tx),
        ("ez.const", tz),
        ("dy.cos1", 0.0),
        ("dy.sin1", 0.0),
        ("ey.cos1", 0.0),
        ("ey.sin1", 0.0),
    ] {
        let (_, got, sigma) = find(name);
        let sigma = sigma.unwrap_or_else(|| panic!("{name} not determined: {context}"));
        eprintln!("{name}: {got:.3} ± {sigma:.3} (truth {want})");
        // 0.3 µm / 0.3e-5 rad: the exact model's second-order terms and the noise's floor.
        planned::assert_unbiased(name, got, sigma, want, 0.3, &context);
    }
    for name in [
        "dx.cos1", "dx.sin1", "dz.cos1", "dz.sin1", "ex.cos1", "ex.sin1", "ez.cos1", "ez.sin1",
    ] {
        assert!(
            find(name).2.is_none(),
            "{name} turns with the head: {context}"
        );
    }
    let rms_um = fourier["rms_residual_um"].as_f64().unwrap();
    assert!(rms_um < 1.5 * NOISE_MM * 1e3, "RMS {rms_um} µm: {context}");
}

/// The same head with the radial runs read the other way round (what the host's model said
/// before issue 21, when a displacement toward the table extended a radial bar): no setting of
/// the six errors explains the data, the residual is many times the noise.
#[test]
fn a_radial_bar_read_the_other_way_is_not_a_head() {
    let dir = tempfile::tempdir().unwrap();
    let (_, fourier) = fit(dir.path(), &table_text(&HEAD, 3, true));
    let rms_um = fourier["rms_residual_um"].as_f64().unwrap();
    eprintln!("RMS with the radial runs flipped: {rms_um:.3} µm");
    assert!(rms_um > 5.0 * NOISE_MM * 1e3, "RMS {rms_um} µm");
}

/// The paper's C installations (combination 1 at L1 = 100, H1 = 50 radial, tangential, axial;
/// 2 at L2 = 150 radial, tangential; 3 at H3 = 100 radial, tangential), C from 0 to 350° in 10°
/// steps, each run with its own zero and 0.1 µm noise.
fn c_table_text(table: &CTable, seed: u64) -> String {
    let runs = [
        (1, 100.0, 50.0, Install::Radial, "radial"),
        (1, 100.0, 50.0, Install::Tangential, "tangential"),
        (1, 0.0, 50.0, Install::Axial, "axial"),
        (2, 150.0, 50.0, Install::Radial, "radial"),
        (2, 150.0, 50.0, Install::Tangential, "tangential"),
        (3, 100.0, 100.0, Install::Radial, "radial"),
        (3, 100.0, 100.0, Install::Tangential, "tangential"),
    ];
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, NOISE_MM).unwrap();
    let zeros: Vec<f64> = runs.iter().map(|_| rng.gen_range(-0.02..0.02)).collect();
    let mut text = String::from("angle_deg");
    for (c, _, _, _, k) in &runs {
        text += &format!(",dl{c}_{k}_mm");
    }
    text += "\n";
    for i in 0..36 {
        let g_deg = 10.0 * i as f64;
        text += &format!("{g_deg}");
        for ((_, l, h, install, _), zero) in runs.iter().zip(&zeros) {
            let r = table.reading_mm(*l, *h, *install, BAR_MM, g_deg.to_radians());
            text += &format!(",{:.7}", r + zero + noise.sample(&mut rng));
        }
        text += "\n";
    }
    text
}

/// A C turntable whose axis line stands 9 µm toward −X and 14 µm toward +Y of where the
/// controller thinks, leaning −25 µrad about X (toward +Y) and +35 µrad about Y (toward +X):
/// `jdbb rotary --axis c` keeps the rotation sense as printed (the table turns right-handed
/// about +Z, as eq. 6), and the Fourier fit's constants are the location errors with their
/// signs, δx.const = −9, δy.const = +14 µm, εx.const = −2.5, εy.const = +3.5 (1e-5 rad), as for
/// the head (δ = (I − R(γ))·o, ε = (I − R(γ))·t). The centring (the runs' common first
/// harmonic) is the offset plus the runs' mean height times the lean, (−6.67, +15.67) µm.
///
/// What a flipped sign would do: C taken as turning the other way (`--sense reversed`) reads
/// the offset's y as −18.7 µm for +14 and leaves 3 µm RMS on 0.1 µm noise (measured); an offset taken as the table's own
/// displacement flips every constant; the tilt's sign flipped fails by 5–7e-5 rad. The axial
/// run cannot tell which way it reads here: an offset or tilt of the axis does not move a ball
/// on the axis along it.
#[test]
fn c_table_axis_offset_and_tilt_are_found_with_their_signs() {
    let table = CTable {
        offset_mm: [-0.009, 0.014, 0.0],
        tilt_x_rad: -25e-6,
        tilt_y_rad: 35e-6,
    };
    let dir = tempfile::tempdir().unwrap();
    let (coef, v) = rotary(
        dir.path(),
        &c_table_text(&table, 5),
        &[
            "--axis", "c", "--l1", "100", "--l2", "150", "--h1", "50", "--h3", "100",
        ],
    );
    let context = format!("{:#}", v["fourier"]);
    assert_eq!(v["model_angle_reversed"], false, "{:#}", v["centring"]);
    assert_eq!(
        v["centring"]["sense"].as_f64(),
        Some(1.0),
        "{:#}",
        v["centring"]
    );
    // Each radial or tangential run's first harmonic is (δx + H·εy, δy − H·εx): the centring,
    // their plain mean, is the offset plus the mean height (66.7 mm) times the lean.
    let h_mean = (4.0 * 50.0 + 2.0 * 100.0) / 6.0;
    for (key, want) in [
        ("dx_um", -9.0 + h_mean * 35e-6 * 1e3),
        ("dy_um", 14.0 + h_mean * 25e-6 * 1e3),
    ] {
        let got = v["centring"][key].as_f64().unwrap();
        eprintln!("centring {key}: {got:.3} (truth {want:.3})");
        assert!(
            (got - want).abs() < 0.2,
            "centring {key} {got}, want {want}: {:#}",
            v["centring"]
        );
    }
    for (name, want) in [
        ("dx.const", -9.0),
        ("dy.const", 14.0),
        ("ex.const", -2.5),
        ("ey.const", 3.5),
    ] {
        let (_, got, sigma) = coef
            .iter()
            .find(|(n, _, _)| n == name)
            .unwrap_or_else(|| panic!("no {name}: {context}"))
            .clone();
        let sigma = sigma.unwrap_or_else(|| panic!("{name} not determined: {context}"));
        eprintln!("{name}: {got:.3} ± {sigma:.3} (truth {want})");
        planned::assert_unbiased(name, got, sigma, want, 0.3, &context);
    }
    let rms_um = v["fourier"]["rms_residual_um"].as_f64().unwrap();
    assert!(rms_um < 1.5 * NOISE_MM * 1e3, "RMS {rms_um} µm: {context}");
}
