//! Issue 28, the history's findings as tests that failed before the fix: a mistyped `--db` that
//! names another program's SQLite file (finding 4), values of ±1e308 that made `history trend
//! --plot` spin for ever (finding 5), a `--db` symbolic link, and machine names with line
//! breaks or terminal escapes.
#![cfg(unix)]

use std::fs;
use std::path::Path;
use std::process::Output;
use std::time::{Duration, Instant};

use rusqlite::Connection;
mod common;
use common::{command, diagnosis, jdbb_in, ok_in, stderr, stdout};

/// `args` (run in `dir`) exit `code` with `want` in stderr and no panic.
fn fails_in(dir: &Path, args: &[&str], code: i32, want: &str) -> String {
    let o = jdbb_in(dir, args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(code), "{args:?}: {e}");
    assert!(e.contains(want), "{args:?}: wanted `{want}` in `{e}`");
    assert!(!e.contains("panicked"), "{args:?}: {e}");
    e
}

/// `history --db h.sqlite add` of `file` under machine `machine`, which must succeed.
fn add(dir: &Path, machine: &str, file: &str) {
    ok_in(
        dir,
        &[
            "history",
            "--db",
            "h.sqlite",
            "add",
            "--machine",
            machine,
            "--diagnosis",
            file,
        ],
    );
}

/// `args` in `dir`, killed if it runs longer than a minute (None then).
fn run_bounded(dir: &Path, args: &[&str]) -> Option<Output> {
    let mut child = command()
        .current_dir(dir)
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(60) {
        if child.try_wait().unwrap().is_some() {
            return Some(child.wait_with_output().unwrap());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    None
}

#[test]
fn a_mistyped_db_leaves_another_programs_sqlite_file_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d, "diag.json", 8.0, 0.01, "2026-09-01");
    // Another program's database: a `runs` table of its own, its own user_version; and one
    // that says whose it is with an application id.
    for (name, app_id) in [("other.sqlite", 0), ("stamped.sqlite", 0x1234_5678)] {
        let path = d.join(name);
        {
            let c = Connection::open(&path).unwrap();
            c.execute_batch(
                "CREATE TABLE runs (lap INTEGER, seconds REAL);
                 INSERT INTO runs VALUES (1, 61.5);
                 PRAGMA user_version = 7;",
            )
            .unwrap();
            c.pragma_update(None, "application_id", app_id).unwrap();
        }
        let before = fs::read(&path).unwrap();
        for args in [
            vec!["add", "--machine", "m", "--diagnosis", "diag.json"],
            vec!["list"],
            vec!["trend", "--machine", "m"],
            vec![
                "comp",
                "--machine",
                "m",
                "--date",
                "2026-10-01",
                "--text",
                "x",
            ],
        ] {
            let mut all = vec!["history", "--db", name];
            all.extend(args);
            fails_in(d, &all, 2, "not a jdbb history database");
        }
        assert_eq!(fs::read(&path).unwrap(), before, "{name} was changed");
        assert!(!d.join(format!("{name}-wal")).exists(), "{name}: WAL left");
        let c = Connection::open(&path).unwrap();
        let mode: String = c
            .query_row("PRAGMA journal_mode", [], |r| r.get(0))
            .unwrap();
        assert_eq!(mode, "delete", "{name}");
    }
    // A new file and an empty one become histories, stamped as jdbb's.
    fs::write(d.join("empty.sqlite"), b"").unwrap();
    for name in ["new.sqlite", "empty.sqlite"] {
        ok_in(
            d,
            &[
                "history",
                "--db",
                name,
                "add",
                "--machine",
                "m",
                "--diagnosis",
                "diag.json",
            ],
        );
        let c = Connection::open(d.join(name)).unwrap();
        let id: i64 = c
            .query_row("PRAGMA application_id", [], |r| r.get(0))
            .unwrap();
        assert_eq!(id, jdbb::history::schema::APPLICATION_ID, "{name}");
    }
}

#[test]
fn a_db_that_is_a_symbolic_link_is_refused_and_its_target_left_alone() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d, "diag.json", 8.0, 0.01, "2026-09-01");
    fs::write(d.join("empty"), b"").unwrap();
    std::os::unix::fs::symlink("empty", d.join("h.sqlite")).unwrap();
    for args in [
        vec!["add", "--machine", "m", "--diagnosis", "diag.json"],
        vec!["list"],
    ] {
        let mut all = vec!["history", "--db", "h.sqlite"];
        all.extend(args);
        fails_in(d, &all, 2, "symbolic link");
    }
    assert_eq!(fs::read(d.join("empty")).unwrap(), b"");
}

#[test]
fn absurd_values_are_refused_on_add() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d, "huge.json", 1e308, 0.01, "2026-09-01");
    diagnosis(d, "wide.json", 8.0, 1e308, "2026-09-01");
    diagnosis(d, "neg.json", -1e7, 0.01, "2026-09-01");
    for (file, want) in [
        ("huge.json", "backlash_x = 1e308"),
        ("wide.json", "the σ of backlash_x = 1e308"),
        ("neg.json", "backlash_x = -1e7"),
    ] {
        let e = fails_in(
            d,
            &[
                "history",
                "--db",
                "h.sqlite",
                "add",
                "--machine",
                "m",
                "--diagnosis",
                file,
            ],
            2,
            want,
        );
        assert!(e.contains("nothing was added"), "{e}");
    }
    assert!(
        !d.join("h.sqlite").exists() || {
            let c = Connection::open(d.join("h.sqlite")).unwrap();
            c.query_row("SELECT COUNT(*) FROM runs", [], |r| r.get::<_, i64>(0))
                .unwrap()
                == 0
        }
    );
}

#[test]
fn a_trend_of_runs_of_plus_or_minus_1e308_plots_and_ends() {
    // A history filed before `add` bounded the values holds such runs: the trend and its plot
    // still end (a σ of 1e308 spun at 100 % CPU for ever, values of ±1e308 panicked in the
    // plot's axis), the runs beyond the bound named as not drawn.
    for (updates, not_drawn) in [
        (
            &["UPDATE effects SET sigma = 1e308 WHERE run_id = 1"][..],
            None,
        ),
        (
            &[
                "UPDATE effects SET value = 1e308 WHERE run_id = 1",
                "UPDATE effects SET value = -1e308, sigma = 1e308 WHERE run_id = 2",
            ][..],
            Some("2 run(s) beyond ±1e6 not drawn"),
        ),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for (k, date) in ["2026-09-01", "2026-10-01", "2026-11-01"]
            .iter()
            .enumerate()
        {
            diagnosis(d, &format!("r{k}.json"), 8.0 + k as f64, 0.01, date);
            add(d, "m", &format!("r{k}.json"));
        }
        let c = Connection::open(d.join("h.sqlite")).unwrap();
        for u in updates {
            c.execute(u, []).unwrap();
        }
        drop(c);
        let o = run_bounded(
            d,
            &[
                "history",
                "--db",
                "h.sqlite",
                "trend",
                "--machine",
                "m",
                "--plot",
                "t.svg",
            ],
        )
        .unwrap_or_else(|| {
            panic!("{updates:?}: history trend --plot still running after a minute")
        });
        assert_eq!(o.status.code(), Some(0), "{updates:?}: {}", stderr(&o));
        let svg = fs::read_to_string(d.join("t.svg")).unwrap();
        if let Some(want) = not_drawn {
            assert!(svg.contains(want), "{svg}");
        }
    }
}

#[test]
fn machine_names_with_line_breaks_or_escapes_are_refused_and_printed_escaped() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d, "diag.json", 8.0, 0.01, "2026-09-01");
    for name in ["mill\nfake: 99 runs", "mill\u{1b}[2J", "a\tb"] {
        let e = fails_in(
            d,
            &[
                "history",
                "--db",
                "h.sqlite",
                "add",
                "--machine",
                name,
                "--diagnosis",
                "diag.json",
            ],
            2,
            "without control characters",
        );
        assert!(!e.contains('\u{1b}'), "{e:?}");
    }
    // A history an older jdbb filed such a name in: printed escaped, on one line.
    add(d, "m", "diag.json");
    let c = Connection::open(d.join("h.sqlite")).unwrap();
    c.execute(
        "UPDATE machines SET name = 'mill\u{1b}[2J' || char(10) || 'fake: 99 runs'",
        [],
    )
    .unwrap();
    drop(c);
    let out = ok_in(d, &["history", "--db", "h.sqlite", "list"]);
    assert_eq!(out, "mill\\u{1b}[2J\\nfake: 99 runs: 1 runs\n");
    let e = fails_in(
        d,
        &["history", "--db", "h.sqlite", "list", "--machine", "m"],
        2,
        "known: mill\\u{1b}[2J\\nfake",
    );
    assert!(!e.contains('\u{1b}'), "{e:?}");
    let o = jdbb_in(
        d,
        &[
            "history",
            "--db",
            "h.sqlite",
            "comp",
            "--machine",
            "mill\u{1b}[2J\nfake: 99 runs",
            "--date",
            "2026-10-01",
            "--text",
            "BACKLASH\u{1b}[31m = 0.008",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&jdbb_in(
        d,
        &[
            "history",
            "--db",
            "h.sqlite",
            "trend",
            "--machine",
            "mill\u{1b}[2J\nfake: 99 runs",
        ],
    ));
    assert!(!out.contains('\u{1b}'), "{out:?}");
    assert!(
        out.starts_with("machine mill\\u{1b}[2J\\nfake: 99 runs: 1 runs")
            && out.contains("BACKLASH\\u{1b}[31m = 0.008"),
        "{out}"
    );
}
