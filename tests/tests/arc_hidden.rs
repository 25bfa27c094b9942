//! Hidden effects on partial arcs (issue 15 §4–5): the vertical-plane test, 220° from −20°
//! (`jdbb plan --plane zx|yz --arc-deg 220 --start-deg -20`), run as G-code on the tests'
//! independent G-code machine (`jdbb_tests::gmachine`: its own parser and planner, feed override,
//! unknown start, a clock off by tens of ppm, noise) with one hidden effect, synchronised from D
//! alone and diagnosed on the data arcs (0° to 180°, both senses), as `jdbb diagnose --record
//! --plan` does. Each hidden effect must be named by the one tolerance rule
//! (`planned::assert_unbiased`: within 5 % and within 1 % + 3σ, σ under 10 %) and nothing else, a
//! perfect machine nothing; what the arc cannot separate is said.
mod planned;

use planned::{machine_names, read_back};

use jdbb::diagnose::{diagnose, Diagnosis, Options};
use jdbb::plan::{plan, write_program, Dialect as PlanDialect, Plan, PlanSpec, Plane};
use jdbb::report::summary;
use jdbb::sync::{data_path, synchronise};
use jdbb_core::Calibration;
use jdbb_tests::gmachine::{
    Axis, BacklashEnds, Bow, Cyclic, Dialect, LateralPlay, MachineErrors, Recording, SimConfig,
    Simulation, Squareness,
};

const CENTRE: [f64; 3] = [100.0, 50.0, -20.0];
const AXES: [Axis; 3] = [Axis::X, Axis::Y, Axis::Z];

/// The vertical-plane test: one circle of 90 mm in `plane`, 220° from −20°, at 1000 mm/min.
fn arc_plan(plane: Plane) -> Plan {
    let spec = PlanSpec::machine_test(
        &[90.0],
        &[0.0],
        plane,
        1000.0,
        CENTRE,
        PlanDialect::Linuxcnc,
    )
    .with_arc(220.0);
    let spec = PlanSpec {
        start_deg: -20.0,
        ..spec
    };
    let p = plan(&spec, &Calibration::DEFAULT).unwrap();
    assert_eq!((p.arc.data_start_deg, p.arc.data_sweep_deg), (0.0, 180.0));
    p
}

/// Run the plan's program on a machine with `errors`, feed override, unknown start, a clock off
/// by tens of ppm, 0.2 µm noise, at 1 kHz.
fn record(plan: &Plan, errors: MachineErrors, seed: u64) -> Recording {
    let text = write_program(plan, PlanDialect::Linuxcnc);
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, CENTRE);
    cfg.errors = errors;
    cfg.machine.feed_override_pct = 96.0 + (seed % 9) as f64;
    cfg.machine.accel_mm_s2 = [400.0 + 100.0 * (seed % 3) as f64, 600.0, 300.0];
    cfg.instrument.clock_ppm = if seed.is_multiple_of(2) { 37.0 } else { -52.0 };
    cfg.instrument.start_delay_s = 2.0 + (seed % 5) as f64;
    cfg.instrument.t0_us = 1_000_000 * seed;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.seed = seed;
    Simulation::new(&text, cfg).unwrap().run().unwrap()
}

/// Synchronise and diagnose a recording through a CSV file, as `jdbb diagnose --record --plan`.
fn diagnose_record(plan: &Plan, rec: &Recording, pitch: [Option<f64>; 3]) -> Diagnosis {
    let r = read_back(rec);
    let sync = synchronise(plan, &r).unwrap();
    let t = &rec.truth;
    // The feed as the device's clock measures it: a clock fast by ppm sees the motion slower.
    let feed = 100.0 * t.feed_factor / (1.0 + 1e-6 * t.clock_ppm);
    assert!(
        (sync.feed_percent - feed).abs() < 0.05,
        "feed {} % vs {feed} %",
        sync.feed_percent
    );
    let start_us = sync.t0_us + 1e6 * sync.cycle_start_s;
    assert!(
        (start_us - t.cycle_start_us).abs() < 10_000.0,
        "cycle start {start_us} µs vs {} µs",
        t.cycle_start_us
    );
    // The diagnosis JSON's plan says which arc was run.
    let pj = jdbb::report::plan_json(std::path::Path::new("plan.json"), plan);
    assert_eq!(pj["arc"]["sweep_deg"], plan.arc.sweep_deg);
    assert_eq!(pj["arc"]["data_sweep_deg"], plan.arc.data_sweep_deg);
    // Every data arc of the plan found: the data arc ccw and back cw.
    let planned = plan
        .segments
        .iter()
        .filter(|s| {
            matches!(
                s,
                jdbb::plan::Segment::Arc {
                    role: jdbb::plan::ArcRole::Data,
                    ..
                }
            )
        })
        .count();
    assert_eq!(sync.circles[0].data.len(), planned);
    let (path, d) = data_path(plan, &r, &sync, pitch).unwrap();
    diagnose(&path, &d, &Options::default()).unwrap()
}

/// What a 220° test's diagnosis must say about the arc in `plane` (axes i, j): one circle
/// covering the data arc of 180° (0° to 180°, less the 1° bins the reversal guard may empty at
/// its ends); the bow of i towards j (`straightness_i_j`: on 0°..180° its shape u_j·sin²θ = sin³θ
/// is nearly set-up and scale mismatch, keeping 0.13 % of itself where a full circle keeps
/// 10 %) tried but named as weak on the arc, with the set-up and the scale mismatch it
/// resembles, and its one-circle twin, the second-order scale of j, as confounded with it; no
/// harmonics; the note in the summary, the JSON and report.html.
fn assert_partial_arc_reported(d: &Diagnosis, plane: Plane) {
    let text = format!("{}{}", summary(d), jdbb::report::details(d));
    assert_eq!(d.arcs.len(), 1, "{text}");
    let a = d.arcs[0];
    assert!(a.is_partial(), "{a:?}");
    assert!((178.0..=180.0).contains(&a.sweep_deg), "{a:?}");
    let (i, j, _) = plane.axes();
    let names = ["x", "y", "z"];
    let bow = format!("straightness_{}_{}", names[i], names[j]);
    let twin = format!("scale2_{}", names[j]);
    assert!(
        d.candidates.contains(&bow),
        "{bow} not tried: {:?}",
        d.candidates
    );
    assert!(
        !d.candidates.contains(&twin),
        "{twin} tried: {:?}",
        d.candidates
    );
    let weak = d
        .weak_on_arc
        .iter()
        .find(|w| w.names[0] == bow)
        .unwrap_or_else(|| panic!("{bow} not said to be weak on the arc\n{text}"));
    assert!(
        weak.names.iter().any(|n| n.starts_with("scale_mismatch"))
            && weak.names.iter().any(|n| n.starts_with("setup_offset")),
        "{weak:?}"
    );
    assert!((0.0005..0.003).contains(&weak.free_fraction), "{weak:?}");
    assert!(
        d.confounded
            .iter()
            .any(|g| g.contains(&twin) && g.contains(&bow)),
        "{text}"
    );
    assert!(
        text.contains("weak on this arc: only 0.1") && text.contains(&bow),
        "{text}"
    );
    assert!(d.harmonics_um.is_empty());
    let from = format!("from {} towards {}", names[i], names[j]);
    assert!(text.contains("partial arc: circle 1 covers"), "{text}");
    assert!(text.contains(&from), "{text}");
    // The JSON and report.html say it too.
    let json = jdbb::report::to_json(d);
    assert_eq!(json["arcs"][0]["partial"], true);
    assert_eq!(json["weak_on_arc"][0]["names"][0], bow.as_str());
    let doc: jdbb::report::document::DiagnosisDoc = serde_json::from_value(json).unwrap();
    let html = jdbb::report::html::report_html(d, &doc).unwrap();
    assert!(html.contains("Partial arc: circle 1 covers"), "{html}");
    assert!(html.contains("Weak on this arc"), "{html}");
}

/// Exactly `name` was found, its value unbiased (`planned::assert_unbiased`: within 5 % and within
/// 1 % of the truth, or 0.1 in its unit, plus 3σ, and σ under 10 %).
fn assert_only(d: &Diagnosis, name: &str, truth: f64) -> f64 {
    assert_eq!(machine_names(d), vec![name.to_string()], "{}", summary(d));
    let f = d.effects.iter().find(|f| f.effect.name() == name).unwrap();
    planned::assert_unbiased(name, f.value, f.sigma.unwrap(), truth, 0.1, &summary(d));
    f.value
}

#[test]
fn a_perfect_machine_shows_nothing_on_220_degrees() {
    for (plane, seed) in [
        (Plane::Zx, 1),
        (Plane::Yz, 2),
        (Plane::Zx, 9),
        (Plane::Yz, 10),
    ] {
        let p = arc_plan(plane);
        let errors = MachineErrors {
            setup_offset_um: [35.0, -20.0, 15.0],
            length_offset_um: 12.0,
            ..MachineErrors::default()
        };
        let d = diagnose_record(&p, &record(&p, errors, seed), [None; 3]);
        assert!(machine_names(&d).is_empty(), "{plane:?}\n{}", summary(&d));
        assert_partial_arc_reported(&d, plane);
    }
}

#[test]
fn squareness_zx_on_220_degrees() {
    let p = arc_plan(Plane::Zx);
    let errors = MachineErrors {
        setup_offset_um: [-25.0, 0.0, 30.0],
        squareness: vec![Squareness {
            axis: Axis::Z,
            by: Axis::X,
            um_per_m: 20.0,
        }],
        ..MachineErrors::default()
    };
    for seed in [3, 11] {
        let d = diagnose_record(&p, &record(&p, errors.clone(), seed), [None; 3]);
        assert_only(&d, "squareness_zx", 20.0);
        assert_partial_arc_reported(&d, Plane::Zx);
    }
}

#[test]
fn cyclic_error_on_220_degrees() {
    let p = arc_plan(Plane::Yz);
    let mut errors = MachineErrors::default();
    errors.cyclic[2] = Cyclic {
        amplitude_um: 2.5,
        pitch_mm: 10.0,
        phase_rad: 0.4,
    };
    for seed in [4, 19] {
        let d = diagnose_record(
            &p,
            &record(&p, errors.clone(), seed),
            [None, Some(10.0), Some(10.0)],
        );
        assert_only(&d, "cyclic_z", 2.5);
        assert_partial_arc_reported(&d, Plane::Yz);
    }
}

#[test]
fn scale_on_220_degrees() {
    let p = arc_plan(Plane::Yz);
    let mut errors = MachineErrors::default();
    errors.scale_um_per_m[1] = 40.0;
    for seed in [5, 17] {
        let d = diagnose_record(&p, &record(&p, errors.clone(), seed), [None; 3]);
        // One radius: scale_y − scale_z, as on a full circle, with a larger σ (0.15 µm/m here,
        // 0.024 on the full circle of the same machine: 4.5 times per sample).
        assert_only(&d, "scale_mismatch_yz", 40.0);
        assert_partial_arc_reported(&d, Plane::Yz);
    }
}

#[test]
fn backlash_on_220_degrees() {
    // Today's step model of backlash (the gmachine's too). x reverses mid-arc (at 90°), z at
    // the data arc's ends (0° and 180°): each shows as the difference between the senses.
    let p = arc_plan(Plane::Zx);
    for (k, name, seed) in [(0, "backlash_x", 6), (2, "backlash_z", 7)] {
        let mut errors = MachineErrors::default();
        errors.backlash_um[k] = 6.0;
        let d = diagnose_record(&p, &record(&p, errors, seed), [None; 3]);
        assert_only(&d, name, 6.0);
    }
}

#[test]
fn on_a_partial_arc_the_feed_in_must_cruise() {
    // At 2000 mm/min a 2 mm feed-in never reaches the feed (the machine needs 3–4 mm to get
    // there), and a 220° arc's short runs cannot tell the arcs' speed from their acceleration
    // (a search in the data came out 1 % off and named a 0.08 µm backlash_z that is not there):
    // the synchronisation refuses, naming the feed-in length that would do. With it, the test
    // runs and finds the hidden backlash alone.
    let spec = |feed_in_mm: f64| {
        let s = PlanSpec::machine_test(
            &[90.0],
            &[0.0],
            Plane::Zx,
            2000.0,
            CENTRE,
            PlanDialect::Linuxcnc,
        )
        .with_arc(220.0);
        PlanSpec {
            start_deg: -20.0,
            feed_in_mm,
            ..s
        }
    };
    let mut errors = MachineErrors::default();
    errors.backlash_um[0] = 6.0;
    let p = plan(&spec(2.0), &Calibration::DEFAULT).unwrap();
    let rec = record(&p, errors.clone(), 31);
    let e = synchronise(&p, &read_back(&rec)).unwrap_err();
    let m = e.to_string();
    assert_eq!(e.exit_code(), 2, "{m}");
    assert!(
        m.contains("never reached the feed") && m.contains("--feed-in-mm 4.5 or more"),
        "{m}"
    );
    let p = plan(&spec(4.5), &Calibration::DEFAULT).unwrap();
    let d = diagnose_record(&p, &record(&p, errors, 31), [None; 3]);
    assert_only(&d, "backlash_x", 6.0);
}

#[test]
fn a_bowed_axis_on_220_degrees_is_found_and_said_to_be_weak() {
    // Z bows in X, κ = −1000 µm/m² about the table ball: over the data arc's Z travel (ball
    // ± 90 mm) the middle stands 8.1 µm off the line through the ends. On 0°..180° the bow's
    // shape is 99.87 % set-up and scale mismatch: it is found on its 0.13 % (left out, it came
    // out as a scale mismatch of −147 µm/m and two reversal spikes), and said to be weak.
    let p = arc_plan(Plane::Zx);
    let errors = MachineErrors {
        bows: vec![Bow {
            axis: Axis::Z,
            toward: Axis::X,
            vertex_mm: CENTRE[2],
            um_per_m2: -1000.0,
        }],
        ..MachineErrors::default()
    };
    let d = diagnose_record(&p, &record(&p, errors, 43), [None; 3]);
    assert_only(&d, "straightness_z_x", 1000.0 * 0.09 * 0.09);
    assert_partial_arc_reported(&d, Plane::Zx);
}

#[test]
fn lost_motion_per_end_on_220_degrees() {
    // Z reverses at both ends of its travel inside the data arc (0° and 180°): 10 µm at the
    // top, 5 µm at the bottom, the dead band growing linearly between.
    let p = arc_plan(Plane::Zx);
    let mut errors = MachineErrors::default();
    errors.backlash_ends[2] = Some(BacklashEnds {
        neg_end_mm: CENTRE[2] - 90.0,
        neg_um: 5.0,
        pos_end_mm: CENTRE[2] + 90.0,
        pos_um: 10.0,
    });
    let d = diagnose_record(&p, &record(&p, errors, 41), [None; 3]);
    assert_only(&d, "backlash_z", 7.5);
    let f = d
        .effects
        .iter()
        .find(|f| f.effect.name() == "backlash_z")
        .unwrap();
    assert_eq!(f.effect.param_names(), &["pos_um", "neg_um"]);
    for (k, truth) in [(0, 10.0), (1, 5.0)] {
        let (v, s) = (f.params[k], f.param_sigma[k].unwrap());
        planned::assert_unbiased(f.effect.param_names()[k], v, s, truth, 0.1, &summary(&d));
    }
}

#[test]
fn lateral_play_on_220_degrees() {
    // Each axis's carriage shifts 6 µm across to the other with its direction: Z's reverses at
    // the data arc's ends, X's mid-arc; each is named alone.
    let p = arc_plan(Plane::Zx);
    for (axis, toward, name, seed) in [
        (Axis::Z, Axis::X, "lateral_play_z_x", 51),
        (Axis::X, Axis::Z, "lateral_play_x_z", 52),
    ] {
        let errors = MachineErrors {
            lateral_play: vec![LateralPlay {
                axis,
                toward,
                um: 6.0,
            }],
            ..MachineErrors::default()
        };
        let d = diagnose_record(&p, &record(&p, errors, seed), [None; 3]);
        assert_only(&d, name, 6.0);
    }
}

#[test]
fn a_bow_of_an_axis_the_arc_sees_one_side_of_is_named_with_its_twin() {
    // The second axis of the plane (X in zx, Z in yz) runs from the table ball to +90 mm only
    // on the data arc (0° to 180°). Its bow about the ball, κ·x², is the other axis's
    // second-order scale on every arc of the circle (x² = R² − z²), as on a full circle; referred
    // to the data's own travel (middle at 45 mm) the bow had a linear part, a squareness, and
    // bow, scale2 and squareness were one group of three from which the selection picked two
    // silently (seed 1023 of sync_random: scale2_y and a bow of −0.91 µm for a bow of 8.97 µm
    // and a squareness of −38.6 µm/m). Now the bow is named, over the circle's diameter as on a
    // full circle, its twin said, and a squareness beside it keeps its own value.
    for (plane, axis, toward, seed) in [
        (Plane::Zx, Axis::X, Axis::Z, 61),
        (Plane::Yz, Axis::Z, Axis::Y, 62),
    ] {
        let (i, j, _) = plane.axes();
        let letters = ["x", "y", "z"];
        let bow = format!(
            "straightness_{}_{}",
            letters[axis as usize], letters[toward as usize]
        );
        let twin = format!("scale2_{}", letters[toward as usize]);
        let square = format!("squareness_{}{}", letters[i], letters[j]);
        let bowed = Bow {
            axis,
            toward,
            vertex_mm: CENTRE[axis as usize],
            um_per_m2: -1000.0,
        };
        let p = arc_plan(plane);
        // The bow alone, then with a squareness (the first of the pair displaced by the second).
        for with_squareness in [false, true] {
            let errors = MachineErrors {
                setup_offset_um: [12.0, -30.0, 25.0],
                bows: vec![bowed],
                squareness: if with_squareness {
                    vec![Squareness {
                        axis: AXES[i],
                        by: AXES[j],
                        um_per_m: -35.0,
                    }]
                } else {
                    vec![]
                },
                ..MachineErrors::default()
            };
            let d = diagnose_record(&p, &record(&p, errors, seed), [None; 3]);
            let text = summary(&d);
            let mut want = vec![bow.clone()];
            if with_squareness {
                want.push(square.clone());
            }
            let mut named = machine_names(&d);
            named.sort();
            want.sort();
            assert_eq!(named, want, "{plane:?}\n{text}");
            let value = |name: &str| {
                let f = d.effects.iter().find(|f| f.effect.name() == name).unwrap();
                (f.value, f.sigma.unwrap())
            };
            // The middle of the diameter stands −κ·R² off the line through its ends.
            let (w, s) = value(&bow);
            planned::assert_unbiased(&bow, w, s, 1000.0 * 0.09 * 0.09, 0.1, &text);
            if with_squareness {
                let (v, s) = value(&square);
                planned::assert_unbiased(&square, v, s, -35.0, 0.5, &text);
            }
            // The twin is said; no group ties the bow to the squareness.
            assert!(
                d.confounded
                    .iter()
                    .any(|g| g.len() == 2 && g.contains(&bow) && g.contains(&twin)),
                "{text}"
            );
            assert!(
                !d.confounded
                    .iter()
                    .any(|g| g.contains(&bow) && g.contains(&square)),
                "{text}"
            );
        }
    }
}

#[test]
fn lost_motion_per_end_of_an_axis_the_arc_sees_one_side_of() {
    // X in zx (Z in yz) reverses at the top of the arc (+90 mm from the ball) and where the
    // test turns back at the arc's ends (R·sin(−20°) = −31 mm), outside the data arc (0 to
    // +90 mm). The ends were those of the data's travel: the turn-back's gap was held at the
    // gap at the ball, and the mean reported was the gap at +45 mm, 12–18 % off the mean of the
    // ends (seeds 1033, 5010, 5016 of sync_random). Now the ends are the circle's, ±R about the
    // table ball, where a full circle reverses the axis.
    for (plane, k, name, neg, pos, seed) in [
        (Plane::Zx, 0, "backlash_x", 5.0, 10.0, 63),
        (Plane::Yz, 2, "backlash_z", 9.0, 4.5, 64),
    ] {
        let p = arc_plan(plane);
        let mut errors = MachineErrors::default();
        errors.backlash_ends[k] = Some(BacklashEnds {
            neg_end_mm: CENTRE[k] - 90.0,
            neg_um: neg,
            pos_end_mm: CENTRE[k] + 90.0,
            pos_um: pos,
        });
        let d = diagnose_record(&p, &record(&p, errors, seed), [None; 3]);
        assert_only(&d, name, 0.5 * (neg + pos));
        let f = d.effects.iter().find(|f| f.effect.name() == name).unwrap();
        assert_eq!(f.effect.param_names(), &["pos_um", "neg_um"]);
        for (i, truth) in [(0, pos), (1, neg)] {
            let (v, s) = (f.params[i], f.param_sigma[i].unwrap());
            planned::assert_unbiased(f.effect.param_names()[i], v, s, truth, 0.1, &summary(&d));
        }
    }
}

/// Exploration, run by hand (`cargo test -p jdbb-tests --test arc_hidden -- --ignored
/// explore_arcs --nocapture`): partial arcs of other sweeps and starts than the standard 220°
/// from −20° (in zx the arc above the table starts at −110°), each effect hidden alone; prints
/// what is named. Not an assertion: a table to read.
#[test]
#[ignore]
fn explore_arcs() {
    let cases: Vec<(Plane, f64, f64)> = vec![
        (Plane::Zx, -110.0, 220.0),
        (Plane::Zx, -110.0, 180.0),
        (Plane::Zx, -130.0, 260.0),
        (Plane::Yz, -20.0, 180.0),
        (Plane::Yz, -40.0, 260.0),
        (Plane::Yz, 0.0, 220.0),
    ];
    for (plane, start, sweep) in cases {
        let p = arc_plan_at(plane, start, sweep);
        let (i, j) = match plane {
            Plane::Zx => (Axis::Z, Axis::X),
            Plane::Yz => (Axis::Y, Axis::Z),
            _ => unreachable!(),
        };
        let (ki, kj) = (axis_index(i), axis_index(j));
        let mut hidden: Vec<(String, MachineErrors)> = vec![];
        hidden.push(("perfect".into(), MachineErrors::default()));
        for (k, a) in [(ki, i), (kj, j)] {
            let mut e = MachineErrors::default();
            e.backlash_um[k] = 6.0;
            hidden.push((format!("backlash {a:?} 6"), e));
            let mut e = MachineErrors::default();
            e.backlash_ends[k] = Some(BacklashEnds {
                neg_end_mm: CENTRE[k] - 90.0,
                neg_um: 5.0,
                pos_end_mm: CENTRE[k] + 90.0,
                pos_um: 10.0,
            });
            hidden.push((format!("ends {a:?} +10/-5"), e));
        }
        for (a, b) in [(i, j), (j, i)] {
            hidden.push((
                format!("lateral {a:?}->{b:?} 6"),
                MachineErrors {
                    lateral_play: vec![LateralPlay {
                        axis: a,
                        toward: b,
                        um: 6.0,
                    }],
                    ..MachineErrors::default()
                },
            ));
            hidden.push((
                format!("bow {a:?} in {b:?} -1000/m2 (8.1 um)"),
                MachineErrors {
                    bows: vec![Bow {
                        axis: a,
                        toward: b,
                        vertex_mm: CENTRE[axis_index(a)],
                        um_per_m2: -1000.0,
                    }],
                    ..MachineErrors::default()
                },
            ));
        }
        hidden.push((
            format!("squareness {i:?} by {j:?} 20"),
            MachineErrors {
                squareness: vec![Squareness {
                    axis: i,
                    by: j,
                    um_per_m: 20.0,
                }],
                ..MachineErrors::default()
            },
        ));
        for (seed, (what, errors)) in hidden.into_iter().enumerate() {
            let rec = record(&p, errors, 100 + seed as u64);
            let r = read_back(&rec);
            let line = match synchronise(&p, &r) {
                Err(e) => format!("sync failed: {e}"),
                Ok(sync) => match data_path(&p, &r, &sync, [None; 3]) {
                    Err(e) => format!("data failed: {e}"),
                    Ok((path, d)) => match diagnose(&path, &d, &Options::default()) {
                        Err(e) => format!("diagnose failed: {e}"),
                        Ok(d) => d
                            .effects
                            .iter()
                            .filter(|f| !f.effect.is_setup())
                            .map(|f| {
                                format!(
                                    "{} {:.3}±{:.3} {:?}",
                                    f.effect.name(),
                                    f.value,
                                    f.sigma.unwrap_or(f64::NAN),
                                    f.params
                                )
                            })
                            .collect::<Vec<_>>()
                            .join("; "),
                    },
                },
            };
            println!(
                "{plane:?} {start:>5}° {sweep:>4}° data {:.0}..{:.0}° | {what:<32} | {line}",
                p.arc.data_start_deg,
                p.arc.data_start_deg + p.arc.data_sweep_deg
            );
        }
    }
}

fn axis_index(a: Axis) -> usize {
    AXES.iter().position(|b| *b == a).unwrap()
}

/// One circle of 90 mm in `plane`, `sweep_deg` from `start_deg`, at 1000 mm/min.
fn arc_plan_at(plane: Plane, start_deg: f64, sweep_deg: f64) -> Plan {
    let spec = PlanSpec::machine_test(
        &[90.0],
        &[0.0],
        plane,
        1000.0,
        CENTRE,
        PlanDialect::Linuxcnc,
    )
    .with_arc(sweep_deg);
    let spec = PlanSpec { start_deg, ..spec };
    plan(&spec, &Calibration::DEFAULT).unwrap()
}

#[test]
fn arcs_whose_ends_are_off_the_axes_name_only_what_is_hidden() {
    // Data arcs that end off the axes (−110°..110° in zx, 0°..140° in yz) and the zx arc that
    // stays above the table (from −110°). Their ends were rounded to the grid up to 0.25 µm
    // inside the circle, and the machine drew a spiral from there: a perfect machine showed a
    // bow of 0.07 µm (12σ) with a scale mismatch of 1.2 µm/m. The ends are grid points on the
    // circle now (`plan::build::on_circle`).
    let perfect = arc_plan_at(Plane::Zx, -130.0, 260.0);
    for seed in [61, 62] {
        let d = diagnose_record(
            &perfect,
            &record(&perfect, MachineErrors::default(), seed),
            [None; 3],
        );
        assert!(machine_names(&d).is_empty(), "{}", summary(&d));
    }
    let p = arc_plan_at(Plane::Yz, -40.0, 260.0);
    let errors = MachineErrors {
        lateral_play: vec![LateralPlay {
            axis: Axis::Y,
            toward: Axis::Z,
            um: 6.0,
        }],
        ..MachineErrors::default()
    };
    assert_only(
        &diagnose_record(&p, &record(&p, errors, 63), [None; 3]),
        "lateral_play_y_z",
        6.0,
    );
    let p = arc_plan_at(Plane::Zx, -110.0, 220.0);
    let errors = MachineErrors {
        bows: vec![Bow {
            axis: Axis::X,
            toward: Axis::Z,
            vertex_mm: CENTRE[0],
            um_per_m2: -1000.0,
        }],
        ..MachineErrors::default()
    };
    let d = diagnose_record(&p, &record(&p, errors, 64), [None; 3]);
    assert_only(&d, "straightness_x_z", 1000.0 * 0.09 * 0.09);
    let p = arc_plan_at(Plane::Yz, -20.0, 180.0);
    let errors = MachineErrors {
        squareness: vec![Squareness {
            axis: Axis::Y,
            by: Axis::Z,
            um_per_m: 20.0,
        }],
        ..MachineErrors::default()
    };
    assert_only(
        &diagnose_record(&p, &record(&p, errors, 65), [None; 3]),
        "squareness_yz",
        20.0,
    );
}
