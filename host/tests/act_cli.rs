//! Acting on a diagnosis from the command line (issue 10): `jdbb compensate` and
//! `jdbb history`, their bad inputs (exit 2 with `file:line:column` where it applies), and two
//! `jdbb history add` processes writing one database at once.
use std::path::{Path, PathBuf};
mod common;
use common::{jdbb, ok};

/// `args` exit 2 with `want` in stderr and no panic.
fn bad(args: &[&str], want: &str) -> String {
    let o = jdbb(args);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    assert!(err.contains(want), "{args:?}: wanted `{want}` in `{err}`");
    assert!(!err.contains("panicked"), "{err}");
    err
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A diagnosis file of a simulated machine with X backlash and squareness.
fn diagnosis(dir: &Path, name: &str, extra: &[&str]) -> PathBuf {
    let csv = dir.join(format!("{name}.csv"));
    let rep = dir.join(name);
    let mut sim = vec![
        "simulate",
        "--radius",
        "60",
        "--rate",
        "100",
        "--effect",
        "backlash_x=8",
        "--effect",
        "squareness_xy=30",
        "--sigma-um",
        "0.3",
        "-o",
        s(&csv),
    ];
    sim.extend_from_slice(extra);
    ok(&sim);
    ok(&[
        "diagnose",
        "--samples",
        s(&csv),
        "--report",
        s(&rep),
        "--machine",
        "mill",
        "--date",
        "2026-10-01",
    ]);
    rep.join("diagnosis.json")
}

#[test]
fn compensate_prints_each_controllers_syntax_and_new_totals() {
    let dir = tempfile::tempdir().unwrap();
    let diag = diagnosis(dir.path(), "a", &[]);
    let out = ok(&[
        "compensate",
        "--diagnosis",
        s(&diag),
        "--controller",
        "marlin",
    ]);
    assert!(out.contains("M425 F1 X0.00"), "{out}");
    assert!(out.contains("M852 I0.0000"), "{out}");
    let out = ok(&[
        "compensate",
        "--diagnosis",
        s(&diag),
        "--controller",
        "klipper",
    ]);
    assert!(out.contains("SET_SKEW XY="), "{out}");
    assert!(
        out.contains("mainline Klipper has no backlash compensation"),
        "{out}"
    );
    let out = ok(&[
        "compensate",
        "--diagnosis",
        s(&diag),
        "--controller",
        "grblhal",
    ]);
    assert!(out.contains("$160=0.00"), "{out}");
    assert!(out.contains("grblHAL core has no squareness"), "{out}");
    // With 5 µm in force the new BACKLASH is the total (about 13 µm).
    let cur = dir.path().join("cur.ini");
    std::fs::write(&cur, "[JOINT_0]\nBACKLASH = 0.005\n").unwrap();
    let out = ok(&[
        "compensate",
        "--diagnosis",
        s(&diag),
        "--controller",
        "linuxcnc",
        "--current",
        s(&cur),
    ]);
    let line = out
        .lines()
        .find(|l| l.starts_with("BACKLASH = "))
        .unwrap_or_else(|| panic!("{out}"));
    let v: f64 = line["BACKLASH = ".len()..].parse().unwrap();
    assert!((v - 0.013).abs() < 2e-4, "{line}");
    assert!(out.contains("setp matrixkins.C_xy -0.0000"), "{out}");
}

#[test]
fn compensate_writes_comp_files_with_out() {
    let dir = tempfile::tempdir().unwrap();
    // Writes c.csv (its diagnosis has no pitch, so no cyclic_x): diagnose again with --pitch.
    diagnosis(
        dir.path(),
        "c",
        &["--effect", "cyclic_x=2@30", "--pitch", "x=10"],
    );
    let csv = dir.path().join("c.csv");
    let rep = dir.path().join("cp");
    ok(&[
        "diagnose",
        "--samples",
        s(&csv),
        "--pitch",
        "x=10",
        "--report",
        s(&rep),
    ]);
    let out_dir = dir.path().join("comp");
    let out = ok(&[
        "compensate",
        "--diagnosis",
        s(&rep.join("diagnosis.json")),
        "--controller",
        "linuxcnc",
        "--table-ball",
        "x=200,y=100",
        "--out",
        s(&out_dir),
    ]);
    assert!(out.contains("COMP_FILE = x.comp"), "{out}");
    let table = std::fs::read_to_string(out_dir.join("x.comp")).unwrap();
    let rows: Vec<Vec<f64>> = table
        .lines()
        .map(|l| l.split_whitespace().map(|x| x.parse().unwrap()).collect())
        .collect();
    assert!(rows.len() > 100 && rows.len() <= 256, "{}", rows.len());
    assert!(rows.iter().all(|r| r.len() == 3));
    assert!((rows[0][0] - 140.0).abs() < 1e-6 && (rows[rows.len() - 1][0] - 260.0).abs() < 1e-6);
    // The backlash (8 µm) is the forward − reverse difference of every row.
    assert!(rows.iter().all(|r| (r[1] - r[2] - 0.008).abs() < 1e-4));
}

#[test]
fn compensate_bad_input_exits_2_with_the_place() {
    let dir = tempfile::tempdir().unwrap();
    let broken = dir.path().join("broken.json");
    std::fs::write(&broken, "{\"samples\": 10,\n  \"effects\": [,]}").unwrap();
    bad(
        &[
            "compensate",
            "--diagnosis",
            s(&broken),
            "--controller",
            "marlin",
        ],
        &format!("{}:2:", broken.display()),
    );
    bad(
        &[
            "compensate",
            "--diagnosis",
            "/nonexistent/d.json",
            "--controller",
            "marlin",
        ],
        "cannot read /nonexistent/d.json",
    );
    let diag = diagnosis(dir.path(), "b", &[]);
    bad(
        &[
            "compensate",
            "--diagnosis",
            s(&diag),
            "--controller",
            "okuma",
        ],
        "use one of linuxcnc, grblhal, marlin, klipper",
    );
    let cur = dir.path().join("cur.txt");
    std::fs::write(&cur, "M92 X80\nM425 F1 X0.0o2\n").unwrap();
    bad(
        &[
            "compensate",
            "--diagnosis",
            s(&diag),
            "--controller",
            "marlin",
            "--current",
            s(&cur),
        ],
        &format!("{}:2:9: M425.X", cur.display()),
    );
    bad(
        &[
            "compensate",
            "--diagnosis",
            s(&diag),
            "--controller",
            "linuxcnc",
            "--travel",
            "x=5:1",
        ],
        "MIN < MAX",
    );
    let cal = dir.path().join("cal.json");
    std::fs::write(&cal, "{\"l1_mm\": 50,\n \"l2_mm\": }").unwrap();
    bad(
        &[
            "diagnose",
            "--samples",
            s(&dir.path().join("b.csv")),
            "--calibration",
            s(&cal),
        ],
        &format!("{}:2:", cal.display()),
    );
}

#[test]
fn history_add_list_trend_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("h.sqlite");
    let d1 = diagnosis(dir.path(), "r1", &["--seed", "1"]);
    let d2 = diagnosis(dir.path(), "r2", &["--seed", "2", "--feed", "2000"]);
    let d3 = diagnosis(dir.path(), "r3", &["--seed", "3"]);
    let out = ok(&[
        "history",
        "add",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--diagnosis",
        s(&d1),
    ]);
    assert!(
        out.starts_with("added run 1 of mill (2026-10-01T00:00:00Z)"),
        "{out}"
    );
    let out = ok(&[
        "history",
        "add",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--diagnosis",
        s(&d1),
    ]);
    assert!(out.starts_with("already in"), "{out}");
    ok(&[
        "history",
        "add",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--diagnosis",
        s(&d2),
        "--date",
        "2026-10-15",
    ]);
    ok(&[
        "history",
        "add",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--diagnosis",
        s(&d3),
        "--date",
        "2026-11-01",
    ]);
    let list = ok(&["history", "list", "--db", s(&db), "--machine", "mill"]);
    assert!(list.starts_with("machine mill: 3 runs"), "{list}");
    assert!(list.contains("backlash_x 8.0"), "{list}");
    let machines = ok(&["history", "list", "--db", s(&db)]);
    assert_eq!(machines, "mill: 3 runs\n");
    let plot = dir.path().join("trend.svg");
    let trend = ok(&[
        "history",
        "trend",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--effect",
        "backlash_x",
        "--plot",
        s(&plot),
    ]);
    assert!(trend.contains("backlash_x (µm)"), "{trend}");
    // Run 2 ran at another feed: flagged, and left out of the change.
    let run2 = trend.lines().find(|l| l.contains("run 2")).unwrap();
    assert!(
        run2.contains("not comparable: feed 2000 mm/min (latest 1000)"),
        "{trend}"
    );
    assert!(
        trend.contains("the first and the last comparable run:"),
        "{trend}"
    );
    assert!(trend.contains("in 31 days"), "{trend}");
    let svg = std::fs::read_to_string(&plot).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("backlash_x"));

    bad(
        &["history", "list", "--db", s(&db), "--machine", "lathe"],
        "no machine `lathe` in the history",
    );
    bad(
        &[
            "history",
            "trend",
            "--db",
            s(&db),
            "--machine",
            "mill",
            "--effect",
            "cyclic_q",
        ],
        "no run of this machine found it",
    );
    bad(
        &[
            "history",
            "add",
            "--db",
            s(&db),
            "--machine",
            "lathe",
            "--diagnosis",
            s(&d1),
        ],
        "is of machine `mill`, not `lathe`",
    );
    let broken = dir.path().join("broken.json");
    std::fs::write(&broken, "{\n\n  \"samples\": x}").unwrap();
    bad(
        &[
            "history",
            "add",
            "--db",
            s(&db),
            "--machine",
            "mill",
            "--diagnosis",
            s(&broken),
        ],
        &format!("{}:3:14", broken.display()),
    );
    let not_db = dir.path().join("not.sqlite");
    std::fs::write(&not_db, "this is not a database").unwrap();
    bad(
        &["history", "list", "--db", s(&not_db)],
        "is not a database",
    );
}

#[test]
fn two_processes_add_at_once() {
    // Two threads each run 12 `jdbb history add` processes one after another: at any moment
    // two processes may be writing the same file. Every run must arrive.
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("h.sqlite");
    let base = std::fs::read_to_string(diagnosis(dir.path(), "base", &[])).unwrap();
    let mut files = vec![];
    for k in 0..24 {
        // Distinct files: another date in each.
        let text = base.replace(
            "2026-10-01T00:00:00Z",
            &format!("2026-10-{:02}T00:00:00Z", k + 1),
        );
        assert_ne!(text, base.replace("2026-10-01", "x"));
        let f = dir.path().join(format!("d{k}.json"));
        std::fs::write(&f, text).unwrap();
        files.push(f);
    }
    let handles: Vec<_> = files
        .chunks(12)
        .map(|chunk| {
            let chunk = chunk.to_vec();
            let db = db.clone();
            std::thread::spawn(move || {
                for f in chunk {
                    let o = jdbb(&[
                        "history",
                        "add",
                        "--db",
                        s(&db),
                        "--machine",
                        "mill",
                        "--diagnosis",
                        s(&f),
                    ]);
                    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
                }
            })
        })
        .collect();
    for h in handles {
        h.join().unwrap();
    }
    let list = ok(&["history", "list", "--db", s(&db)]);
    assert_eq!(list, "mill: 24 runs\n");
}
