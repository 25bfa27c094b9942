//! `jdbb::rrsps` (seed 004's A/C table as an RRSPS linkage) against a physical table (issue 21):
//! the bar lengths come from `jdbb_tests::rrsps_truth`, two axis lines and two balls turned by
//! rigid rotations, written without the host's eq. (8). The parameters' meaning on the table as
//! built (which foot, which direction, which zero) is stated in
//! `TrunnionTable::linkage_parameters`.
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use jdbb::rrsps::design::{theta_a_for, Branch};
use jdbb::rrsps::identify::{identify, Method};
use jdbb::rrsps::io::{read_params, Samples};
use jdbb::rrsps::{Params, PARAM_NAMES};
use jdbb_tests::rrsps_truth::TrunnionTable;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

#[allow(dead_code)]
mod planned;

const D_MM: f64 = 300.0;
/// The paper's residual level (Table 4: largest deviation ~1.6 µm).
const NOISE_MM: f64 = 0.45e-3;

fn design() -> Params {
    let f = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/rrsps_parameters_table2_3.csv");
    read_params(&f, Some("design_range_neg")).unwrap()
}

/// The paper's Table 2 design (A −110..0°) as a physical table, written out from the numbers'
/// meaning: A axis along +X and C axis along +Z crossing at the origin; the spindle ball
/// 96.310 mm along +X, 352.114 mm from the A axis at 35° from +Y toward +Z (θA0 = −55° is that
/// angle minus 90°); the table ball 80 mm up the C axis, 30 mm from it at −161.592° from +Y,
/// right-handed about +Z (toward −X for a positive angle).
fn nominal() -> TrunnionTable {
    let psi = 35f64.to_radians();
    let tc0 = (-161.592f64).to_radians();
    TrunnionTable {
        a_point: [0.0; 3],
        a_dir: [1.0, 0.0, 0.0],
        c_point: [0.0; 3],
        c_dir: [0.0, 0.0, 1.0],
        table_ball: [-30.0 * tc0.sin(), 30.0 * tc0.cos(), 80.0],
        spindle_ball: [96.310, 352.114 * psi.cos(), 352.114 * psi.sin()],
    }
}

/// A test on the physical table: the motion designed for the paper's table at d = 300 mm
/// (`points` C positions per branch, both branches), the bar lengths the table as built gives,
/// and noise.
fn measured(table: &TrunnionTable, points: usize, seed: u64) -> Samples {
    let design = design();
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, NOISE_MM).unwrap();
    let (mut ta, mut tc, mut d) = (vec![], vec![], vec![]);
    for b in Branch::BOTH {
        for k in 0..points {
            let c = (k as f64 * 360.0 / points as f64).to_radians();
            if let Some(a) = theta_a_for(&design, D_MM, c, b) {
                ta.push(a);
                tc.push(c);
                d.push(table.bar_mm(a, c) + noise.sample(&mut rng));
            }
        }
    }
    Samples {
        path: PathBuf::from(format!("physical{seed}.csv")),
        theta_a_rad: ta,
        theta_c_rad: tc,
        d_mm: d,
    }
}

/// The host's bar length (eq. 8) for the nominal table's parameters is the physical table's
/// bar length at every A, C: A and C turn the way the model says, their zeros and the
/// parameters' meanings agree. A sense of A or C flipped, an angle measured from the other side,
/// or E's angle taken from +Y instead of +Z (θA0 off by 90°) moves the bar by tens of mm.
#[test]
fn the_paper_design_as_a_physical_table_gives_eq8s_bar_lengths() {
    let table = nominal();
    let p = table.linkage_parameters();
    let design = design().to_array();
    for (k, name) in PARAM_NAMES.iter().enumerate() {
        let d = if k == 5 || k == 2 || k == 7 {
            (p[k] - design[k] + PI).rem_euclid(2.0 * PI) - PI
        } else {
            p[k] - design[k]
        };
        assert!(d.abs() < 1e-9, "{name}: {} vs design {}", p[k], design[k]);
    }
    let host = Params::from_array(&p);
    let mut worst = 0.0f64;
    for i in 0..40 {
        let a = (-120.0 + 3.3 * i as f64).to_radians();
        let c = (17.0 + 37.0 * i as f64).to_radians();
        let diff = jdbb::rrsps::bar_length(&host, a, c) - table.bar_mm(a, c);
        worst = worst.max(diff.abs());
    }
    assert!(
        worst < 1e-9,
        "eq. 8 and the physical table differ by {worst} mm"
    );
}

/// Location errors hidden in a physical table and found by the joint identification of three
/// tests (the spindle moved +0.2 and −0.2 mm along X between them, as the paper's M1–M3):
/// the A axis 30 µm below where it should be and turned 0.3 mrad toward +Y, the C axis 25 µm to
/// +Y of the A axis, leaning 0.05° toward +X and 0.03° toward −Y (which turns the common normal
/// and with it the zeros of θA0 and θC0), the table ball and the spindle ball set up a few
/// tenths of a mm off. The
/// deviations from the design of a1 (+25 µm), α12 (+0.05°), θA0 and θC0 must come back unbiased
/// (1 % of the deviation or 0.5 µm / 0.0005°, plus 3σ, and σ under 10 % of it), the spindle's
/// moves as s0 changes of +0.2 and −0.2 mm the same way; the ball distances within 3σ.
///
/// What a flipped sign would do: a1 taken along −x1 reads −25 µm for +25 µm (the C axis on the
/// wrong side of the A axis); α12 taken about −x1 reads 269.95° for 270.05°; s0 taken along −X
/// makes the +0.2 mm move −0.2 mm. Each fails by twice the error against a bound of a few µm.
#[test]
fn location_errors_of_an_ac_table_are_found_with_their_signs() {
    let design = design();
    let lean = 0.05f64.to_radians();
    let mut built = nominal();
    let lean_y = 0.03f64.to_radians();
    built.a_point = [0.0, 0.0, -0.030];
    built.a_dir = [1.0, 0.0003, 0.0];
    built.c_point = [0.0, 0.025, 0.0];
    built.c_dir = [lean.sin(), -lean_y.sin(), lean.cos() * lean_y.cos()];
    built.table_ball = [
        built.table_ball[0] + 0.3,
        built.table_ball[1] - 0.2,
        built.table_ball[2] + 0.15,
    ];
    built.spindle_ball = [
        built.spindle_ball[0] + 0.1,
        built.spindle_ball[1] - 0.25,
        built.spindle_ball[2] + 0.2,
    ];
    let moved = |dx: f64| {
        let mut t = built;
        t.spindle_ball[0] += dx;
        t
    };
    let tables = [built, moved(0.2), moved(-0.2)];
    let samples: Vec<Samples> = tables
        .iter()
        .zip(1..)
        .map(|(t, seed)| measured(t, 900, seed))
        .collect();
    let id = identify(&samples, &design, &[0], Method::Lsq).unwrap();
    let truth: Vec<[f64; 8]> = tables
        .iter()
        .map(|t| Params::from_array(&t.linkage_parameters()).to_named_units())
        .collect();
    let design_named = design.to_named_units();
    let context = format!(
        "{:#?}\nundetermined {:?}\nrms {} µm",
        id.estimates, id.undetermined, id.rms_residual_um
    );
    assert!(id.undetermined.is_empty(), "{context}");
    // The ball distances (s0, a0, s2, a2) stay a weak combination even with the spindle
    // moved (σ 10-50 µm, the weak valley of `hidden_parameters_recovered_within_3_sigma`): they
    // are checked within 3σ, not for their sign; the moves themselves are checked as changes.
    let weak = ["s0_mm", "a0_mm", "s2_mm", "a2_mm"];
    let mut strong = 0;
    for e in &id.estimates {
        // `test` is the 0-based index of the test of a per-test (free) parameter.
        let t = e.test.unwrap_or(0);
        let want = truth[t][e.param] - design_named[e.param];
        let got = e.value - design_named[e.param];
        let sigma = e
            .sigma
            .unwrap_or_else(|| panic!("{}: no σ\n{context}", e.name));
        eprintln!("{}: {got:+.5} ± {sigma:.5} (truth {want:+.5})", e.name);
        if weak.contains(&PARAM_NAMES[e.param]) {
            assert!(
                (got - want).abs() <= 3.0 * sigma + 5e-4,
                "{}: {got} ± {sigma} vs {want}\n{context}",
                e.name
            );
        } else {
            strong += 1;
            // 0.5 µm or 0.0005° (about 3 µm at the balls' 350 mm): the noise's floor.
            planned::assert_unbiased(&e.name, got, sigma, want, 5e-4, &context);
        }
    }
    assert_eq!(strong, 4, "{context}");
    for (name, t, change, sigma) in &id.changes {
        // Test t (1-based) moved the spindle +0.2 (t = 2) or −0.2 mm (t = 3) along X: along the
        // A axis, turned 0.3 mrad from X, that is s0 ± 0.2·cos(0.3 mrad).
        let want = truth[t - 1][0] - truth[0][0];
        assert!((want - if *t == 2 { 0.2 } else { -0.2 }).abs() < 1e-6);
        eprintln!("{name} change in test {t}: {change:+.5} ± {sigma:?} (truth {want:+.5})");
        planned::assert_unbiased(name, *change, sigma.unwrap(), want, 5e-4, &context);
    }
    assert!(
        (0.8..1.2).contains(&(id.rms_residual_um / (NOISE_MM * 1e3))),
        "{context}"
    );
}
