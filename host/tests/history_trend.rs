//! `jdbb history trend` over a machine that wears and is compensated: G with a tolerance, the
//! slope per 30 days with its σ and the change taken only since the compensation changed, the change marked
//! (filed with `history comp`, and stated by the diagnoses' `--compensation`), CSV export.
use std::path::{Path, PathBuf};
mod common;
use common::ok;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A diagnosis of a machine with `backlash_um` of play, tested on `date` under `compensation`.
fn run(dir: &Path, name: &str, backlash_um: f64, date: &str, compensation: &str) -> PathBuf {
    let csv = dir.join(format!("{name}.csv"));
    let rep = dir.join(name);
    let effect = format!("backlash_x={backlash_um}");
    ok(&[
        "simulate",
        "--radius",
        "60",
        "--rate",
        "100",
        "--effect",
        &effect,
        "--sigma-um",
        "0.2",
        "--seed",
        "5",
        "-o",
        s(&csv),
    ]);
    ok(&[
        "diagnose",
        "--samples",
        s(&csv),
        "--report",
        s(&rep),
        "--machine",
        "mill",
        "--date",
        date,
        "--compensation",
        compensation,
    ]);
    rep.join("diagnosis.json")
}

#[test]
fn trend_marks_compensation_changes_fits_the_slope_after_them_and_exports_csv() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("h.sqlite");
    // Wear of 1 µm a month, then the backlash compensated on 2026-04-10, then 0.5 µm a month.
    let runs = [
        (6.0, "2026-01-01", "BACKLASH = 0"),
        (7.0, "2026-02-01", "BACKLASH = 0"),
        (8.0, "2026-03-01", "BACKLASH = 0"),
        (1.0, "2026-05-01", "BACKLASH = 0.008"),
        (1.5, "2026-06-01", "BACKLASH = 0.008"),
        (2.0, "2026-07-01", "BACKLASH = 0.008"),
    ];
    for (k, (b, date, comp)) in runs.iter().enumerate() {
        let d = run(dir.path(), &format!("r{k}"), *b, date, comp);
        ok(&[
            "history",
            "add",
            "--db",
            s(&db),
            "--machine",
            "mill",
            "--diagnosis",
            s(&d),
        ]);
    }
    let out = ok(&[
        "history",
        "comp",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--date",
        "2026-04-10",
        "--text",
        "BACKLASH = 0.008 (jdbb compensate)",
    ]);
    assert!(
        out.starts_with("filed compensation change 1 of mill on 2026-04-10"),
        "{out}"
    );

    let csv = dir.path().join("trend.csv");
    let plot = dir.path().join("trend.svg");
    let out = ok(&[
        "history",
        "trend",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--effect",
        "backlash_x",
        "--csv",
        s(&csv),
        "--plot",
        s(&plot),
    ]);
    // One mark (the event; runs 3 and 4 state the same change, not marked twice), between them.
    let lines: Vec<&str> = out.lines().collect();
    let marks: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].contains("compensation changed"))
        .collect();
    assert_eq!(marks.len(), 1, "{out}");
    assert!(
        lines[marks[0] - 1].contains("run 3") && lines[marks[0] + 1].contains("run 4"),
        "{out}"
    );
    // The slope since the change: 0.5 µm over each of the months May–June (31 d) and June–July
    // (30 d), per 30 days, and the runs it is fitted over named with their dates.
    let slope_line = lines.iter().find(|l| l.contains("slope over the")).unwrap();
    assert!(
        slope_line.contains("3 comparable runs since the compensation change of 2026-04-10 (runs 4, 5, 6 from 2026-05-01 to 2026-07-01)")
            && slope_line.ends_with(" µm per 30 days"),
        "{out}"
    );
    let nums: Vec<f64> = slope_line
        .split(": ")
        .nth(1)
        .unwrap()
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    let (slope, sigma) = (nums[0], nums[1]);
    let want = 1.0 / (61.0 / 30.0);
    assert!(sigma > 0.0 && sigma < 0.1, "{slope_line}");
    assert!(
        (slope - want).abs() < 3.0 * sigma + 0.02,
        "{slope_line}: want {want}"
    );
    // The change is taken over the same runs, never across the compensation change (which
    // would give 2 − 6 = −4 µm), and says so; the runs before it are named as left out.
    let change_line = lines
        .iter()
        .find(|l| l.contains("change from run"))
        .unwrap();
    assert!(
        change_line.contains("change from run 4 (2026-05-01) to run 6 (2026-07-01), the first and the last comparable run since the compensation change of 2026-04-10: ")
            && change_line.ends_with(" µm in 61 days"),
        "{out}"
    );
    let change: f64 = change_line
        .rsplit(": ")
        .next()
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((change - 1.0).abs() < 0.1, "{change_line}");
    assert!(
        out.contains("  runs 1, 2, 3: before the compensation change of 2026-04-10, not compared across it\n"),
        "{out}"
    );
    // The CSV: one row per run, the change flagged at the first run after it.
    let text = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<Vec<&str>> = text
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    assert_eq!(text.lines().next().unwrap(), "machine,quantity,unit,run,date_utc,value,sigma,comparable,differences,compensation_changed,compensation");
    assert_eq!(rows.len(), 6);
    for (k, r) in rows.iter().enumerate() {
        let value: f64 = r[5].parse().unwrap();
        assert!((value - runs[k].0).abs() < 0.1, "{r:?}");
        assert_eq!(r[9], if k == 3 { "true" } else { "false" }, "{r:?}");
        assert_eq!(r[10], runs[k].2);
    }
    // The plot names what it draws: the mark, the fitted slope with its value and unit over its
    // runs (a line from the first to the last of them), the runs with their σ.
    let svg = std::fs::read_to_string(&plot).unwrap();
    assert!(
        svg.contains("compensation changed 2026-04-10: BACKLASH = 0.008 (jdbb compensate)"),
        "{svg}"
    );
    let fitted = svg
        .lines()
        .map(str::trim)
        .find(|t| t.starts_with("fitted slope "))
        .unwrap_or_else(|| panic!("no fitted slope in the legend: {svg}"));
    assert!(
        fitted.contains(" µm per 30 days (runs 4, 5, 6, 2026-05-01 to 2026-07-01)"),
        "{fitted}"
    );
    let legend_slope: f64 = fitted["fitted slope ".len()..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(legend_slope, slope, "one slope in the text and the plot");
    assert!(svg.contains("backlash_x (µm), value ± σ"), "{svg}");

    // G with a tolerance: the worn runs are over it, the compensated ones within.
    let out = ok(&[
        "history",
        "trend",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--figure",
        "G",
        "--tolerance-um",
        "4",
    ]);
    assert!(out.contains("circular_deviation_g (µm)"), "{out}");
    // G has no σ: the plot says none, and names the tolerance line.
    let g_plot = dir.path().join("g.svg");
    ok(&[
        "history",
        "trend",
        "--db",
        s(&db),
        "--machine",
        "mill",
        "--figure",
        "g",
        "--tolerance-um",
        "4",
        "--plot",
        s(&g_plot),
    ]);
    let svg = std::fs::read_to_string(&g_plot).unwrap();
    assert!(!svg.contains('σ'), "G has no σ: {svg}");
    assert!(svg.lines().any(|l| l.trim() == "tolerance 4 µm"), "{svg}");
    assert!(svg.contains("fitted slope "), "{svg}");
    assert!(
        out.contains("tolerance 4 µm: over it in run 1, 2, 3\n"),
        "{out}"
    );
    // Without the marks the slope over all six runs would be negative; the text says since when.
    assert!(
        out.contains("since the compensation change of 2026-04-10"),
        "{out}"
    );
}

#[test]
fn a_run_dated_by_its_diagnosis_is_filed_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("t.csv");
    let rep = dir.path().join("rep");
    let db = dir.path().join("h.sqlite");
    ok(&["simulate", "--radius", "60", "--rate", "100", "-o", s(&csv)]);
    // No --date: the diagnosis dates the file with the time it ran, and says so.
    ok(&[
        "diagnose",
        "--samples",
        s(&csv),
        "--report",
        s(&rep),
        "--machine",
        "mill",
    ]);
    let diag = rep.join("diagnosis.json");
    let out = ok(&["history", "add", "--db", s(&db), "--diagnosis", s(&diag)]);
    assert!(
        out.contains(
            ", the date of the diagnosis: the test's date was not given; give it with --date)"
        ),
        "{out}"
    );
    // The test's date given when filing: no warning.
    let db2 = dir.path().join("h2.sqlite");
    let out = ok(&[
        "history",
        "add",
        "--db",
        s(&db2),
        "--diagnosis",
        s(&diag),
        "--date",
        "2026-05-01",
    ]);
    assert!(
        out.starts_with("added run 1 of mill (2026-05-01T00:00:00Z) to "),
        "{out}"
    );
}
