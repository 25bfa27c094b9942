//! `jdbb simulate --plan --machine` (the host's own models: issue 17) against the independent
//! G-code machine of this crate, on the same program, machine and instrument: the two records
//! last as long, start alike, and `jdbb diagnose --record --plan` finds the same machine in both.
//! The host's simulator is a round trip through the host's models; this is its outside check.
use std::path::Path;
use std::process::Command;

use jdbb_tests::gmachine::{Axis, Dialect, MachineErrors, SimConfig, Simulation, Squareness};
use jdbb_tests::jdbb_bin;

fn jdbb(dir: &Path, args: &[&str]) -> String {
    let o = Command::new(jdbb_bin())
        .current_dir(dir)
        .args(args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

/// The machine effects a diagnosis (JSON) names: (name, value).
fn named(json: &str) -> Vec<(String, f64)> {
    let v: serde_json::Value = serde_json::from_str(json).unwrap();
    v["effects"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["setup"] == false)
        .map(|e| {
            (
                e["name"].as_str().unwrap().to_string(),
                e["value"].as_f64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn host_simulator_and_gcode_machine_agree() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    jdbb(
        d,
        &[
            "plan",
            "--radius",
            "90",
            "--feed",
            "2000",
            "--centre",
            "100,50,-20",
            "--out",
            "plan",
        ],
    );
    let rate = 250.0;
    // The independent machine.
    let program = std::fs::read_to_string(d.join("plan/ballbar.ngc")).unwrap();
    let mut cfg = SimConfig::new(Dialect::LinuxCnc, [100.0, 50.0, -20.0]);
    cfg.errors = MachineErrors {
        backlash_um: [8.0, 0.0, 0.0],
        squareness: vec![Squareness {
            axis: Axis::X,
            by: Axis::Y,
            um_per_m: 30.0,
        }],
        ..MachineErrors::default()
    };
    cfg.machine.feed_override_pct = 98.0;
    cfg.instrument.sample_rate_hz = rate;
    cfg.instrument.clock_ppm = 37.0;
    cfg.instrument.noise_um = 0.2;
    cfg.instrument.start_delay_s = 3.0;
    cfg.instrument.seed = 3;
    let sim = Simulation::new(&program, cfg).unwrap();
    let rec = sim.run().unwrap();
    let mut f = std::io::BufWriter::new(std::fs::File::create(d.join("gm.csv")).unwrap());
    rec.write_csv(&mut f).unwrap();
    drop(f);
    // The host's, from the same description.
    std::fs::write(
        d.join("m.toml"),
        format!(
            "feed_override_pct = 98\n[instrument]\nsample_rate_hz = {rate}\nclock_ppm = 37\nnoise_um = 0.2\nstart_delay_s = 3\n[effects]\nbacklash_x = 8\nsquareness_xy = 30\n"
        ),
    )
    .unwrap();
    jdbb(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "m.toml",
            "-o",
            "hm.csv",
        ],
    );
    let host_rows = std::fs::read_to_string(d.join("hm.csv"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .count()
        - 1;
    // The same run: as many samples within 0.5 s (the controllers' models differ in detail).
    let (a, b) = (rec.rows.len() as f64, host_rows as f64);
    assert!((a - b).abs() < 0.5 * rate, "{a} vs {b} samples");
    let diagnose = |file: &str| {
        let json = jdbb(
            d,
            &[
                "diagnose",
                "--record",
                file,
                "--plan",
                "plan/plan.json",
                "--json",
            ],
        );
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        (
            named(&json),
            v["sync"]["feed_percent"].as_f64().unwrap(),
            v["sync"]["cycle_start_device_us"].as_f64().unwrap(),
        )
    };
    let (gm, gm_feed, gm_start) = diagnose("gm.csv");
    let (hm, hm_feed, hm_start) = diagnose("hm.csv");
    let names = |v: &[(String, f64)]| v.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(names(&gm), ["backlash_x", "squareness_xy"], "{gm:?}");
    assert_eq!(names(&hm), names(&gm), "{hm:?} vs {gm:?}");
    for ((_, g), (_, h)) in gm.iter().zip(&hm) {
        assert!((g / h - 1.0).abs() < 0.03, "{gm:?} vs {hm:?}");
    }
    assert!((gm_feed - hm_feed).abs() < 0.3, "{gm_feed} vs {hm_feed}");
    assert!(
        (gm_start - hm_start).abs() < 5_000.0,
        "{gm_start} vs {hm_start}"
    );
    println!(
        "gmachine {gm:?} feed {gm_feed:.3} % start {gm_start:.0} µs; host {hm:?} feed {hm_feed:.3} % start {hm_start:.0} µs"
    );
}
