//! `jdbb simulate --plan plan.json --machine MACHINE.toml -o REC.csv` (issue 17, item 1): a
//! record as `jdbb record` writes it, of a plan's program on a machine with hidden errors, which
//! `jdbb diagnose --record --plan` then names; and the mistakes around it.
use std::fs;
use std::path::Path;
mod common;
use common::{jdbb_in, named, ok_in};

/// `args` exit 2 with `want` in stderr, no panic; stderr.
fn refused(dir: &Path, args: &[&str], want: &str) -> String {
    let o = jdbb_in(dir, args);
    let e = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
    assert!(e.contains(want), "{args:?}: wanted `{want}` in `{e}`");
    assert!(!e.contains("panicked"), "{e}");
    e
}

/// A plan of two radii at 1500 mm/min, in `dir/plan`.
fn plan(dir: &Path) {
    ok_in(
        dir,
        &[
            "plan",
            "--radius",
            "90",
            "--radius",
            "85",
            "--feed",
            "1500",
            "--centre",
            "100,50,-20",
            "--out",
            "plan",
        ],
    );
}

const INSTRUMENT: &str = "[instrument]\nsample_rate_hz = 250\nclock_ppm = 60\nstart_delay_s = 4.2\nnoise_um = 0.3\nt0_us = 123456\nseed = 7\n";

#[test]
fn hidden_play_and_squareness_are_named_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    plan(d);
    fs::write(
        d.join("mill.toml"),
        format!(
            "name = \"mill 3\"\nfeed_override_pct = 97\naccel_mm_s2 = 400\n{INSTRUMENT}[effects]\nbacklash_x = 8\nsquareness_xy = 40\n"
        ),
    )
    .unwrap();
    ok_in(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "mill.toml",
            "-o",
            "rec.csv",
        ],
    );
    let rec = fs::read_to_string(d.join("rec.csv")).unwrap();
    let mut lines = rec.lines();
    assert!(lines.next().unwrap().starts_with("# plan_id: "));
    assert_eq!(lines.next().unwrap(), "seq,t_us,enc1,enc2,d_mm");
    assert!(lines.next().unwrap().starts_with("# instrument_serial: "));
    assert!(lines.next().unwrap().starts_with("0,123456,"));
    let json = ok_in(
        d,
        &[
            "diagnose",
            "--record",
            "rec.csv",
            "--plan",
            "plan/plan.json",
            "--json",
        ],
    );
    let found = named(&json);
    let names: Vec<&str> = found.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["backlash_x", "squareness_xy"], "{found:?}");
    for ((_, v), truth) in found.iter().zip([8.0, 40.0]) {
        assert!((v / truth - 1.0).abs() < 0.05, "{found:?}");
    }
    // The feed the synchronisation measured: the override over the clock's 60 ppm.
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let pct = v["sync"]["feed_percent"].as_f64().unwrap();
    assert!((pct - 97.0 / 1.00006).abs() < 0.05, "{pct}");
}

#[test]
fn a_perfect_machine_names_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    plan(d);
    fs::write(d.join("perfect.toml"), INSTRUMENT).unwrap();
    ok_in(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "perfect.toml",
            "-o",
            "rec.csv",
        ],
    );
    let json = ok_in(
        d,
        &[
            "diagnose",
            "--record",
            "rec.csv",
            "--plan",
            "plan/plan.json",
            "--json",
        ],
    );
    assert_eq!(named(&json), [], "a perfect machine");
}

#[test]
fn the_example_machine_is_printed_and_reads() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let example = ok_in(d, &["simulate", "--machine"]);
    assert!(example.contains("[effects]") && example.contains("backlash_x"));
    fs::write(d.join("m.toml"), &example).unwrap();
    plan(d);
    // Written to stdout when there is no -o, header first.
    let rec = ok_in(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "m.toml",
        ],
    );
    assert!(rec.starts_with("# plan_id: "));
    // The serial line `jdbb record` writes after the header, before the samples; the report
    // names it as the instrument.
    let lines: Vec<&str> = rec.lines().take(3).collect();
    assert_eq!(lines[1], "seq,t_us,enc1,enc2,d_mm");
    assert_eq!(lines[2], "# instrument_serial: 000000000000000000000000");
    fs::write(
        d.join("s.toml"),
        "[instrument]\nserial = \"0a1b2c3d4e5f60718293a4b5\"\n",
    )
    .unwrap();
    let args = [
        "simulate",
        "--plan",
        "plan/plan.json",
        "--machine",
        "s.toml",
        "-o",
        "rec.csv",
    ];
    ok_in(d, &args);
    ok_in(
        d,
        &[
            "diagnose",
            "--record",
            "rec.csv",
            "--plan",
            "plan/plan.json",
            "--report",
            "rep",
        ],
    );
    let page = fs::read_to_string(d.join("rep/report.html")).unwrap();
    assert!(
        page.contains("0A1B2C3D4E5F60718293A4B5"),
        "serial not in the report"
    );
    // A machine whose controller is not the plan's dialect runs it, and says so.
    fs::write(d.join("g.toml"), "controller = \"GRBL\"\n").unwrap();
    let o = jdbb_in(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "g.toml",
        ],
    );
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("written for linuxcnc") && e.contains("its controller is grbl"),
        "{e}"
    );
    let o = jdbb_in(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "m.toml",
        ],
    );
    assert!(!String::from_utf8_lossy(&o.stderr).contains("warning"));
}

#[test]
fn bad_machine_files_name_file_line_and_column() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    plan(d);
    let args = [
        "simulate",
        "--plan",
        "plan/plan.json",
        "--machine",
        "m.toml",
        "-o",
        "rec.csv",
    ];
    for (text, want) in [
        (
            "feed_override_pct = 100\n[effects]\nbacklash_w = 3\n",
            "m.toml:3:",
        ),
        ("\naccel_mm_s2 = \"fast\"\n", "m.toml:2:"),
        ("\n\n[instrument]\nnoise_um = -1\n", "m.toml:4:"),
        ("controler = \"grbl\"\n", "m.toml:1:1"),
        ("[effects]\ncyclic_x = 3\n", "needs the pitch"),
        ("[effects\n", "m.toml:1:"),
        ("[instrument]\nserial = \"12zz\"\n", "m.toml:2:"),
    ] {
        fs::write(d.join("m.toml"), text).unwrap();
        refused(d, &args, want);
        assert!(!d.join("rec.csv").exists());
    }
}

#[test]
fn an_existing_record_is_kept_without_force() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    plan(d);
    fs::write(d.join("m.toml"), INSTRUMENT).unwrap();
    fs::write(d.join("rec.csv"), "precious\n").unwrap();
    let args = [
        "simulate",
        "--plan",
        "plan/plan.json",
        "--machine",
        "m.toml",
        "-o",
        "rec.csv",
    ];
    refused(d, &args, "--force");
    assert_eq!(fs::read_to_string(d.join("rec.csv")).unwrap(), "precious\n");
    let mut forced = args.to_vec();
    forced.push("--force");
    ok_in(d, &forced);
    assert!(fs::read_to_string(d.join("rec.csv"))
        .unwrap()
        .starts_with("# plan_id: "));
}

#[test]
fn a_record_of_another_plan_is_refused_by_diagnose() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    plan(d);
    ok_in(
        d,
        &[
            "plan",
            "--radius",
            "90",
            "--feed",
            "1500",
            "--centre",
            "100,50,-20",
            "--out",
            "other",
        ],
    );
    fs::write(d.join("m.toml"), INSTRUMENT).unwrap();
    ok_in(
        d,
        &[
            "simulate",
            "--plan",
            "other/plan.json",
            "--machine",
            "m.toml",
            "-o",
            "rec.csv",
        ],
    );
    let e = refused(
        d,
        &[
            "diagnose",
            "--record",
            "rec.csv",
            "--plan",
            "plan/plan.json",
        ],
        "made for another plan",
    );
    assert!(e.contains("rec.csv") && e.contains("plan/plan.json"), "{e}");
}

#[test]
fn a_plan_for_another_plane_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (plane, out) in [("xy", "xy"), ("zx", "zx")] {
        ok_in(
            d,
            &[
                "plan",
                "--radius",
                "90",
                "--feed",
                "1500",
                "--plane",
                plane,
                "--centre",
                "100,50,-20",
                "--out",
                out,
            ],
        );
    }
    fs::write(
        d.join("m.toml"),
        format!("{INSTRUMENT}[effects]\nbacklash_x = 8\n"),
    )
    .unwrap();
    ok_in(
        d,
        &[
            "simulate",
            "--plan",
            "xy/plan.json",
            "--machine",
            "m.toml",
            "-o",
            "rec.csv",
        ],
    );
    // The same circles in zx have the same D levels; the record says which plan it is of.
    let e = refused(
        d,
        &["diagnose", "--record", "rec.csv", "--plan", "zx/plan.json"],
        "made for another plan",
    );
    assert!(e.contains("wrong axes"), "{e}");
    // A record without its plan_id line (`jdbb record` without --plan, or older) cannot be
    // checked: it is diagnosed, with a warning that says so and names the plan's plane, and a
    // record that has the line gets no such warning.
    let rec = fs::read_to_string(d.join("rec.csv")).unwrap();
    let bare: String = rec
        .lines()
        .filter(|l| !l.starts_with("# plan_id:"))
        .map(|l| format!("{l}\n"))
        .collect();
    fs::write(d.join("bare.csv"), bare).unwrap();
    let o = jdbb_in(
        d,
        &["diagnose", "--record", "bare.csv", "--plan", "zx/plan.json"],
    );
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{e}");
    assert!(
        e.contains("has no `# plan_id:` line") && e.contains("plane ZX"),
        "{e}"
    );
    let o = jdbb_in(
        d,
        &["diagnose", "--record", "rec.csv", "--plan", "xy/plan.json"],
    );
    assert!(o.status.success());
    assert!(!String::from_utf8_lossy(&o.stderr).contains("plan_id"));
}

#[test]
fn the_machine_files_calibration_makes_the_counts() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    plan(d);
    let mut cal = jdbb_core::calib::Calibration::DEFAULT;
    cal.enc1.zero_count += 1000;
    fs::create_dir(d.join("ins")).unwrap();
    fs::write(
        d.join("ins/cal.toml"),
        jdbb::instrument::file::calibration_toml(&cal, &[]),
    )
    .unwrap();
    // The calibration's path is relative to the machine file.
    fs::write(d.join("ins/nominal.toml"), INSTRUMENT).unwrap();
    fs::write(
        d.join("ins/own.toml"),
        format!("{INSTRUMENT}calibration = \"cal.toml\"\n"),
    )
    .unwrap();
    let rows = |machine: &str| -> Vec<(i64, f64)> {
        let text = ok_in(
            d,
            &["simulate", "--plan", "plan/plan.json", "--machine", machine],
        );
        text.lines()
            .filter(|l| !l.starts_with('#'))
            .skip(1)
            .map(|l| {
                let f: Vec<&str> = l.split(',').collect();
                (f[2].parse().unwrap(), f[4].parse().unwrap())
            })
            .collect()
    };
    let (nominal, own) = (rows("ins/nominal.toml"), rows("ins/own.toml"));
    assert_eq!(nominal.len(), own.len());
    for (a, b) in nominal.iter().zip(&own).step_by(97) {
        // Encoder 1 reads 1000 counts more for the same angle; the device's D is the same.
        assert_eq!(b.0 - a.0, 1000 * cal.enc1.direction.sign());
        assert!((a.1 - b.1).abs() < 2e-6, "{a:?} {b:?}");
    }
    fs::write(
        d.join("ins/bad.toml"),
        "[instrument]\ncalibration = \"nope.toml\"\n",
    )
    .unwrap();
    refused(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "ins/bad.toml",
        ],
        "nope.toml",
    );
}

#[test]
fn a_record_begun_after_cycle_start_is_said_to_be_late() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    plan(d);
    fs::write(d.join("m.toml"), INSTRUMENT).unwrap();
    ok_in(
        d,
        &[
            "simulate",
            "--plan",
            "plan/plan.json",
            "--machine",
            "m.toml",
            "-o",
            "rec.csv",
        ],
    );
    // The same run, the record started 10 s after cycle start (4.2 s into the record).
    let text = fs::read_to_string(d.join("rec.csv")).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines.drain(2..2 + (14.2 * 250.0) as usize);
    fs::write(d.join("late.csv"), lines.join("\n") + "\n").unwrap();
    let e = refused(
        d,
        &[
            "diagnose",
            "--record",
            "late.csv",
            "--plan",
            "plan/plan.json",
        ],
        "cycle start was missed",
    );
    assert!(
        e.contains("late.csv") && e.contains("start `jdbb record --plan` first"),
        "{e}"
    );
}
