//! `--machine-profile FILE|NAME`: `plan` and `history` take their values from the profile
//! (issue 30), a flag overrides it, and a machine's NAME is found in `$JDBB_MACHINES`.
use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
use common::{command, stderr};

/// A fresh directory for one test.
fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("jdbb-profile-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The profile of mill-1: a Fanuc whose table ball stands at machine X 250 Y 120 Z −300 and whose
/// test program runs in a work coordinate system with its zero at machine X 200 Y 100 Z −320.
const MILL_1: &str = r#"
machine = "mill-1"
controller = "fanuc"
tolerance_um = 4.0
feeds_mm_min = [800.0, 1600.0]
[table_ball_mm]
x = 250.0
y = 120.0
z = -300.0
[work_offset_mm]
x = 200.0
y = 100.0
z = -320.0
[travel_mm]
x = [0.0, 600.0]
y = [0.0, 400.0]
"#;

/// `jdbb ARGS` with `machines` as `$JDBB_MACHINES`.
fn jdbb(machines: &Path, args: &[&str]) -> Output {
    command()
        .env("JDBB_MACHINES", machines)
        .args(args)
        .output()
        .expect("run jdbb")
}

/// `jdbb ARGS` (as [`jdbb`]), which must succeed.
fn ok(machines: &Path, args: &[&str]) -> Output {
    let o = jdbb(machines, args);
    assert!(o.status.success(), "{}", stderr(&o));
    o
}

fn plan_json(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("plan.json")).unwrap()).unwrap()
}

#[test]
fn plan_takes_dialect_feeds_table_ball_and_travel_from_the_profile_found_by_name() {
    let d = dir("plan");
    std::fs::write(d.join("mill-1.toml"), MILL_1).unwrap();
    let out = d.join("p");
    let o = ok(
        &d,
        &[
            "plan",
            "--machine-profile",
            "mill-1",
            "--radius",
            "90",
            "--out",
            out.to_str().unwrap(),
        ],
    );
    let p = plan_json(&out);
    assert_eq!(p["dialect"], "fanuc", "{p}");
    assert!(out.join("O1000.nc").is_file());
    // Machine (G53) 250, 120, −300 less the work offset 200, 100, −320.
    let c: Vec<f64> = serde_json::from_value(p["centre_mm"].clone()).unwrap();
    assert_eq!(c, vec![50.0, 20.0, 20.0], "{p}");
    let feeds: Vec<f64> = p["circles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["feed_mm_min"].as_f64().unwrap())
        .collect();
    assert_eq!(feeds, vec![800.0, 1600.0], "{p}");
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("work offset"), "{text}");

    // A flag overrides the profile.
    ok(
        &d,
        &[
            "plan",
            "--machine-profile",
            "mill-1",
            "--radius",
            "90",
            "--centre",
            "10,20,30",
            "--dialect",
            "linuxcnc",
            "--feed",
            "500",
            "--out",
            out.to_str().unwrap(),
            "--force",
        ],
    );
    let p = plan_json(&out);
    assert_eq!(p["dialect"], "linuxcnc");
    assert_eq!(p["centre_mm"], serde_json::json!([10.0, 20.0, 30.0]));
    assert_eq!(p["feed_mm_min"], 500.0);

    // The profile's machine travel, moved into the program's coordinates by the work offset:
    // X 230..600 machine is 30..400 in the program, which a circle of R 90 about program X 50
    // leaves (it reaches X −40 or less); the message names the program's X 30.
    std::fs::write(
        d.join("mill-2.toml"),
        MILL_1.replace("x = [0.0, 600.0]", "x = [230.0, 600.0]"),
    )
    .unwrap();
    let o = jdbb(
        &d,
        &[
            "plan",
            "--machine-profile",
            "mill-2",
            "--radius",
            "90",
            "--out",
            d.join("q").to_str().unwrap(),
        ],
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("below the travel's X 30"), "{e}");
    assert!(!d.join("q").join("plan.json").exists());
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_machine_name_that_is_not_there_says_where_it_looked_and_which_are() {
    let d = dir("missing");
    std::fs::write(d.join("mill-1.toml"), MILL_1).unwrap();
    std::fs::write(d.join("lathe-2.toml"), "machine = \"lathe-2\"\n").unwrap();
    let o = jdbb(
        &d,
        &[
            "plan",
            "--machine-profile",
            "mill-7",
            "--radius",
            "90",
            "--out",
            "x",
        ],
    );
    assert_eq!(o.status.code(), Some(2));
    let e = stderr(&o);
    assert!(e.contains(&d.display().to_string()), "{e}");
    assert!(e.contains("lathe-2, mill-1"), "{e}");
    assert!(!e.contains("panicked"), "{e}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn history_takes_the_machine_and_the_g_tolerance_from_the_profile() {
    let d = dir("history");
    std::fs::write(d.join("mill-1.toml"), MILL_1).unwrap();
    // The diagnosis names no machine: the profile's is the one it is filed under.
    common::diagnosis(&d, "diag.json", 6.0, 0.2, "2026-09-01T00:00:00Z");
    let db = d.join("h.sqlite");
    let db = db.to_str().unwrap();
    let diag = d.join("diag.json");
    let o = jdbb(
        &d,
        &[
            "history",
            "--db",
            db,
            "--machine-profile",
            "mill-1",
            "add",
            "--diagnosis",
            diag.to_str().unwrap(),
        ],
    );
    assert!(String::from_utf8_lossy(&o.stdout).contains("of mill-1"));
    let o = ok(
        &d,
        &["history", "--db", db, "--machine-profile", "mill-1", "list"],
    );
    assert!(
        String::from_utf8_lossy(&o.stdout).starts_with("machine mill-1: 1 runs"),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    // G 5 µm against the profile's 4 µm.
    let o = ok(
        &d,
        &[
            "history",
            "--db",
            db,
            "--machine-profile",
            "mill-1",
            "trend",
            "--figure",
            "g",
        ],
    );
    let t = String::from_utf8_lossy(&o.stdout);
    assert!(t.contains("tolerance 4 µm: over it in run 1"), "{t}");
    // Not held against an effect: the tolerance is on G.
    let o = ok(
        &d,
        &[
            "history",
            "--db",
            db,
            "--machine-profile",
            "mill-1",
            "trend",
        ],
    );
    assert!(!String::from_utf8_lossy(&o.stdout).contains("tolerance"));
    std::fs::remove_dir_all(&d).unwrap();
}
