//! `jdbb simulate --plan VOL.json --machine M.toml -o rec.csv` on a volumetric plan (issue 29):
//! the whole program (every cone and arc, the moves along the shell between them) run on a
//! machine with errors on all three axes and recorded as `jdbb record` records it.
//!
//! What is checked is the record alone, against the plan and the physics, not against the
//! simulator's own timeline: every sample within the instrument's range; one stretch of D at
//! the elements' ball distance per element, in the plan's order, each as long as the plan's arcs
//! and dwells on that element take at the programmed feed; and a hidden squareness of YZ
//! (δ_y = s·z) seen as the first-order change of D, ΔD = (p·δ)/D = s·y·z/D: zero on the zx
//! arc and the cone at height 0, ±s·R·H/D on a cone at height H (first +, as y = R·sin φ
//! rises from 0°), ±s·D/2 on the yz arc (first +, at 45° of its ccw run from −20°).
use std::fs;
use std::path::Path;

use jdbb::plan::{Plan, Plane};
use jdbb::volumetric::elements::on_circle_s;
mod common;
use common::ok_in;

/// Programmed feed of the plan (mm/min).
const FEED_MM_MIN: f64 = 3000.0;
/// The machine's acceleration (mm/s²) and the instrument, in every machine file here.
const MACHINE: &str =
    "accel_mm_s2 = 2000\n[instrument]\nsample_rate_hz = 200\nstart_delay_s = 2\ntail_s = 1\n";

/// `jdbb plan --volumetric --distance 90` in `dir/plan`, read back.
fn volumetric_plan(dir: &Path) -> Plan {
    ok_in(
        dir,
        &[
            "plan",
            "--volumetric",
            "--distance",
            "90",
            "--feed",
            &FEED_MM_MIN.to_string(),
            "--centre",
            "100,50,-20",
            "--out",
            "plan",
        ],
    );
    Plan::read(&dir.join("plan/plan.json")).unwrap()
}

/// `jdbb simulate --plan plan/plan.json` on a machine with `effects` (the `[effects]` lines) and
/// `noise_um`: the record's (t_us, d_mm), read from the CSV `jdbb record` writes.
fn simulated(dir: &Path, name: &str, noise_um: f64, effects: &str) -> Vec<(u64, f64)> {
    let machine = format!("{name}.toml");
    let rec = format!("{name}.csv");
    fs::write(
        dir.join(&machine),
        format!("{MACHINE}noise_um = {noise_um}\n[effects]\n{effects}"),
    )
    .unwrap();
    ok_in(
        dir,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            &machine,
            "-o",
            &rec,
        ],
    );
    let text = fs::read_to_string(dir.join(&rec)).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    assert_eq!(lines.next(), Some("seq,t_us,enc1,enc2,d_mm"));
    lines
        .map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            (v[1].parse().unwrap(), v[4].parse().unwrap())
        })
        .collect()
}

/// The stretches (first, last sample) where D stays within `tol_mm` of `d_mm` for at least
/// `min_s`, in record order.
fn stretches_at(rec: &[(u64, f64)], d_mm: f64, tol_mm: f64, min_s: f64) -> Vec<(usize, usize)> {
    let mut out = vec![];
    let mut start = None;
    for (i, &(_, d)) in rec.iter().enumerate() {
        match ((d - d_mm).abs() < tol_mm, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push((s, i - 1));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, rec.len() - 1));
    }
    out.retain(|&(a, b)| (rec[b].0 - rec[a].0) as f64 * 1e-6 >= min_s);
    out
}

/// One stretch per element, in the plan's order, each the element's time on its circle; every
/// sample within the instrument's range.
#[test]
fn every_element_is_recorded_where_the_plan_puts_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let plan = volumetric_plan(d);
    let rec = simulated(
        d,
        "mill",
        0.2,
        "scale_x = 30\nscale_y = -20\nscale_z = 25\nsquareness_xy = 40\nsquareness_yz = -60\nsquareness_zx = 45\nbacklash_x = 8\nbacklash_y = [6.0, 4.0]\nbacklash_z = 5\n",
    );
    let inst = plan.instrument;
    for (i, &(t_us, d_mm)) in rec.iter().enumerate() {
        assert!(
            (inst.d_min_mm..=inst.d_max_mm).contains(&d_mm),
            "sample {i} (t_us {t_us}): D {d_mm} mm outside the instrument's {}..{} mm",
            inst.d_min_mm,
            inst.d_max_mm
        );
    }
    // The errors move D by a few µm: 20 µm takes each element's stretch at its D.
    let planes: Vec<Plane> = plan.circles.iter().map(|c| c.plane).collect();
    assert_eq!(
        planes,
        [Plane::Xy, Plane::Xy, Plane::Xy, Plane::Zx, Plane::Yz]
    );
    let d_mm = plan.circles[0].d_mm;
    assert!(plan.circles.iter().all(|c| (c.d_mm - d_mm).abs() < 1e-3));
    let runs = stretches_at(&rec, d_mm, 0.02, 1.0);
    assert_eq!(runs.len(), plan.circles.len(), "stretches at D: {runs:?}");
    for (k, &(a, b)) in runs.iter().enumerate() {
        let seen_s = (rec[b].0 - rec[a].0) as f64 * 1e-6;
        let (moving_s, standing_s) = on_circle_s(&plan, k).unwrap();
        let planned_s = moving_s + standing_s;
        // Each of its moves from rest (ccw, cw) takes v/a longer than at full feed.
        let v = FEED_MM_MIN / 60.0;
        let moves_s = 2.0 * v / 2000.0;
        assert!(
            (seen_s - planned_s - moves_s).abs() < 0.02 * planned_s,
            "element {k} ({:?}): {seen_s:.2} s at D, the plan {planned_s:.2} s + {moves_s:.2} s",
            plan.circles[k].plane
        );
    }
}

/// The hidden YZ squareness in the change of D, element by element (module docs).
#[test]
fn a_hidden_yz_squareness_shows_in_the_yz_arc_as_the_physics_says() {
    const S_UM_PER_M: f64 = 80.0;
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let plan = volumetric_plan(d);
    let perfect = simulated(d, "perfect", 0.0, "");
    let leaning = simulated(
        d,
        "leaning",
        0.0,
        &format!("squareness_yz = {S_UM_PER_M}\n"),
    );
    assert_eq!(perfect.len(), leaning.len());
    let d_mm = plan.circles[0].d_mm;
    let runs = stretches_at(&perfect, d_mm, 0.002, 1.0);
    assert_eq!(runs.len(), plan.circles.len(), "stretches at D: {runs:?}");
    for (k, &(a, b)) in runs.iter().enumerate() {
        let c = &plan.circles[k];
        let amplitude_um = match c.plane {
            Plane::Xy => 1e-3 * S_UM_PER_M * c.radius_mm * c.height_mm / c.d_mm,
            Plane::Zx => 0.0,
            Plane::Yz => 1e-3 * S_UM_PER_M * c.d_mm / 2.0,
        };
        let change_um: Vec<f64> = (a..=b)
            .map(|i| 1e3 * (leaning[i].1 - perfect[i].1))
            .collect();
        let hi = change_um.iter().copied().fold(f64::MIN, f64::max);
        let lo = change_um.iter().copied().fold(f64::MAX, f64::min);
        // The kernel's single precision and the counts: a few nm.
        let tol_um = 0.02 * amplitude_um + 0.02;
        assert!(
            (hi - amplitude_um).abs() < tol_um && (lo + amplitude_um).abs() < tol_um,
            "element {k} ({:?}, H {} mm): ΔD {lo:.4}..{hi:.4} µm, the physics ±{amplitude_um:.4} µm",
            c.plane,
            c.height_mm
        );
        if amplitude_um > 1.0 {
            // The ccw run comes first: y·z turns positive first (cones from 0°, the yz arc from
            // −20°: the largest |ΔD| is first reached at 90° and at 45°).
            let first = change_um
                .iter()
                .find(|v| v.abs() > 0.9 * amplitude_um)
                .unwrap();
            assert!(
                *first > 0.0,
                "element {k} ({:?}): ΔD first reaches {first:.3} µm, the physics +{amplitude_um:.3}",
                c.plane
            );
        }
    }
}
