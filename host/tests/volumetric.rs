//! `jdbb plan --volumetric`: the plan of a volumetric test, one program from one mount. The
//! geometry is checked on the plan's own segments, sampled every 0.1 mm: D in the instrument's
//! range everywhere after the stop, the spindle ball never lower than the vertical arcs' ends,
//! moves between elements never lower than the elements they join, the vertical arcs 220°.
//! (Every dialect's program parsed back by an independent reader: `tests/plan.rs`.)
use std::path::Path;

use jdbb::plan::{LineRole, Plan, Plane, Purpose, Segment, Sense, VOLUMETRIC_VERSION};
mod common;
use common::{jdbb, stderr, stdout};

/// `jdbb plan ARGS --feed 1000 --centre 100,50,-20 --out DIR` (the README's numbers).
fn plan_in(dir: &Path, args: &[&str]) -> std::process::Output {
    let mut all = vec!["plan"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--feed", "1000", "--centre", "100,50,-20"]);
    all.extend_from_slice(&["--out", dir.to_str().unwrap()]);
    jdbb(&all)
}

/// `jdbb plan --volumetric --distance 90 … --out DIR` with `extra` options.
fn plan_volumetric(dir: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec!["--volumetric", "--distance", "90"];
    args.extend_from_slice(extra);
    plan_in(dir, &args)
}

/// Points along segment `k`, every 0.1 mm (and both ends).
fn samples(plan: &Plan, k: usize) -> Vec<[f64; 3]> {
    let len = plan.length_mm(k);
    let n = (len / 0.1).ceil().max(1.0) as usize;
    (0..=n)
        .map(|m| plan.position_at(k, len * m as f64 / n as f64))
        .collect()
}

fn d(c: &[f64; 3], p: &[f64; 3]) -> f64 {
    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
}

#[test]
fn the_plan_stays_in_range_above_the_table_and_off_the_ball() {
    let dir = tempfile::tempdir().unwrap();
    let o = plan_volumetric(dir.path(), &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let plan = Plan::read(&dir.path().join("plan.json")).unwrap();
    assert_eq!(plan.purpose, Purpose::VolumetricTest);
    assert_eq!(plan.version, VOLUMETRIC_VERSION);
    let planes: Vec<(Plane, f64)> = plan
        .circles
        .iter()
        .map(|c| (c.plane, c.height_mm))
        .collect();
    assert_eq!(
        planes,
        [
            (Plane::Xy, 0.0),
            (Plane::Xy, 30.0),
            (Plane::Xy, 60.0),
            (Plane::Zx, 0.0),
            (Plane::Yz, 0.0)
        ]
    );
    let c = plan.centre_mm;
    let inst = plan.instrument;
    // The lowest point of the test: the vertical arcs' ends, 20° below the ball.
    let floor_z = c[2] - 90.0 * 20f64.to_radians().sin() - 1e-3;
    let mut mounted = false;
    for (k, s) in plan.segments.iter().enumerate() {
        if matches!(s, Segment::Stop) {
            mounted = true;
        }
        if s.to_mm().is_none() || !mounted {
            continue;
        }
        let pts = samples(&plan, k);
        for p in &pts {
            let dd = d(&c, p);
            assert!(
                dd >= inst.d_min_mm - 1e-6 && dd <= inst.d_max_mm + 1e-6,
                "segment {k}: D {dd} outside {}",
                inst.describe()
            );
            assert!(p[2] >= floor_z, "segment {k}: Z {} below {floor_z}", p[2]);
        }
    }
    // A move between two elements (consecutive `move` lines after the first circle) runs along
    // the shell: never lower than where it starts or where it ends.
    let mut k = 0;
    while k < plan.segments.len() {
        let is_move = |s: &Segment| {
            matches!(
                s,
                Segment::Line {
                    role: LineRole::Move,
                    ..
                }
            )
        };
        if !is_move(&plan.segments[k]) {
            k += 1;
            continue;
        }
        let first = k;
        while k < plan.segments.len() && is_move(&plan.segments[k]) {
            k += 1;
        }
        let (a, b) = (
            plan.segments[first].from_mm().unwrap(),
            plan.segments[k - 1].to_mm().unwrap(),
        );
        let low = a[2].min(b[2]);
        for m in first..k {
            for p in samples(&plan, m) {
                assert!(
                    p[2] >= low - 1e-3,
                    "the move of segments {first}..{k} dips to Z {} below its ends' {low}",
                    p[2]
                );
            }
        }
    }
    // The vertical arcs: 220° each way, never beyond their ends, from −110° of z (zx) and −20°
    // of y (yz): both 20° below the ball at their ends.
    for (circle, start) in [(3, -110.0), (4, -20.0)] {
        let arc = plan.circles[circle]
            .arc
            .expect("a volumetric circle has its arc");
        assert_eq!((arc.start_deg, arc.sweep_deg), (start, 220.0));
        assert_eq!(arc.data_sweep_deg, 180.0);
        let sweep = |sense: Sense| -> f64 {
            plan.segments
                .iter()
                .filter_map(|s| match s {
                    Segment::Arc {
                        circle: k,
                        sense: q,
                        sweep_deg,
                        ..
                    } if *k == circle && *q == sense => Some(*sweep_deg),
                    _ => None,
                })
                .sum()
        };
        assert!(
            (sweep(Sense::Ccw) - 220.0).abs() < 0.01,
            "{}",
            sweep(Sense::Ccw)
        );
        assert!(
            (sweep(Sense::Cw) + 220.0).abs() < 0.01,
            "{}",
            sweep(Sense::Cw)
        );
    }
}

#[test]
fn the_printout_says_where_what_and_what_it_determines() {
    let dir = tempfile::tempdir().unwrap();
    let o = plan_volumetric(dir.path(), &[]);
    let out = stdout(&o);
    assert!(o.status.success(), "{}", stderr(&o));
    for want in [
        "table ball centre:   X 100.000  Y 50.000  Z -20.000 mm",
        "5 element(s)",
        "zx arc",
        "yz arc",
        "xy cone",
        "spindle ball travel:",
        "ball distances used:",
        "estimated run time:",
        "determined:        scale_x, scale_y, scale_z, squareness_xy, squareness_yz, squareness_zx, setup_offset_x, setup_offset_y, setup_offset_z",
        "rank:              9 of 9 with the calibration (9 of 10 without",
        "confounded:        scale_x + scale_y + scale_z − instrument_scale",
        "a second lever arm",
    ] {
        assert!(out.contains(want), "wanted `{want}` in\n{out}");
    }
}

#[test]
fn travel_is_checked_naming_the_element_and_the_excess() {
    let dir = tempfile::tempdir().unwrap();
    // The plan fits a generous box…
    let o = plan_volumetric(
        &dir.path().join("fits"),
        &["--travel", "x=0:200,y=-50:150,z=-60:100"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let plan = Plan::read(&dir.path().join("fits").join("plan.json")).unwrap();
    // …and is refused by one whose floor is 5 mm above the zx arc's lowest point.
    let zx_low = (0..plan.segments.len())
        .filter(|&k| matches!(&plan.segments[k], Segment::Arc { circle: 3, .. }))
        .filter_map(|k| plan.segment_travel_mm(k))
        .map(|(lo, _)| lo[2])
        .fold(f64::INFINITY, f64::min);
    let floor = zx_low + 5.0;
    let travel = format!("x=0:200,z={floor}:100");
    let o = plan_volumetric(&dir.path().join("refused"), &["--travel", &travel]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    let want = format!(
        "element 4 (zx arc, R 90 mm, H 0 mm) reaches Z {zx_low:.3} mm, 5.000 mm below the travel's Z {floor}"
    );
    assert!(err.contains(&want), "wanted `{want}` in {err}");
    assert!(!dir.path().join("refused").join("plan.json").exists());
    // A box too narrow in x names the element that leaves it, beyond its end.
    let o = plan_volumetric(&dir.path().join("x"), &["--travel", "x=0:150"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("element 1 (xy circle, R 90 mm, H 0 mm) reaches X 190.000 mm, 40.000 mm beyond the travel's X 150"),
        "{err}"
    );
    // A malformed box is a usage error naming the form.
    let o = plan_volumetric(&dir.path().join("bad"), &["--travel", "x=200:0"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("x=MIN:MAX with MIN < MAX"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn plan_json_round_trips_and_a_plane_plan_is_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let o = plan_volumetric(dir.path(), &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let path = dir.path().join("plan.json");
    let text = std::fs::read_to_string(&path).unwrap();
    let plan = Plan::read(&path).unwrap();
    assert_eq!(plan.to_json(), text);
    assert_eq!(
        Plan::from_json(&path, &plan.to_json()).unwrap().id(),
        plan.id()
    );
    // A volumetric circle without its arc, or a plane plan claiming version 3, is refused.
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["circles"][3].as_object_mut().unwrap().remove("arc");
    let e = Plan::from_json(&path, &v.to_string())
        .unwrap_err()
        .to_string();
    assert!(e.contains("circle 3 does not agree with itself"), "{e}");
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["purpose"] = "machine-test".into();
    let e = Plan::from_json(&path, &v.to_string())
        .unwrap_err()
        .to_string();
    assert!(e.contains("does not go with version 3"), "{e}");
    // A plane test is still version 2, its circles without `arc`.
    let plane = dir.path().join("plane");
    let o = plan_in(&plane, &["--radius", "90"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(plane.join("plan.json")).unwrap();
    assert!(text.contains("\"version\": 2,"), "{text}");
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert!(v["circles"][0].get("arc").is_none(), "{text}");
}

#[test]
fn diagnosing_a_volumetric_record_says_it_is_not_built_yet() {
    let dir = tempfile::tempdir().unwrap();
    let o = plan_volumetric(dir.path(), &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let record = dir.path().join("rec.csv");
    std::fs::write(&record, "seq,t_us,enc1,enc2,d_mm\n").unwrap();
    let o = jdbb(&[
        "diagnose",
        "--record",
        record.to_str().unwrap(),
        "--plan",
        dir.path().join("plan.json").to_str().unwrap(),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("volumetric diagnosis is not built yet"),
        "{}",
        stderr(&o)
    );
}
