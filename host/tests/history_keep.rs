//! Issue 33 item 4: `jdbb history add --keep-record REC.csv --plan PLAN.json` keeps the raw
//! record with its run (gzip, SHA-256, table `kept_files`), `jdbb history rerun` diagnoses it
//! again and prints the stored values beside the new ones; a damaged blob is refused; an old
//! history gains the table; `history remove` takes the kept record too. On a SQLite file and on
//! a PostgreSQL server ([`common::pg`]).
#![cfg(unix)]

use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
use common::{jdbb_in, ok_in, pg, stderr, stdout};

/// Where a test's history is, and how the test looks inside it.
enum Backend {
    File(PathBuf),
    Server {
        cluster: &'static pg::Cluster,
        name: String,
        url: String,
    },
}

impl Backend {
    /// The `--db` value.
    fn db(&self) -> String {
        match self {
            Backend::File(p) => p.display().to_string(),
            Backend::Server { url, .. } => url.clone(),
        }
    }

    /// `sql` (one number) on the history, as its owner.
    fn count(&self, sql: &str) -> i64 {
        match self {
            Backend::File(p) => rusqlite::Connection::open(p)
                .unwrap()
                .query_row(sql, [], |r| r.get(0))
                .unwrap(),
            Backend::Server { cluster, name, .. } => cluster.psql_in(name, sql).parse().unwrap(),
        }
    }

    /// Flip one bit of the kept record's compressed bytes, in the middle of the blob.
    fn damage_record(&self) {
        match self {
            Backend::File(p) => {
                let c = rusqlite::Connection::open(p).unwrap();
                let mut blob: Vec<u8> = c
                    .query_row(
                        "SELECT gzip FROM kept_files WHERE role = 'record'",
                        [],
                        |r| r.get(0),
                    )
                    .unwrap();
                let at = blob.len() / 2;
                blob[at] ^= 0x10;
                c.execute(
                    "UPDATE kept_files SET gzip = ?1 WHERE role = 'record'",
                    [blob],
                )
                .unwrap();
            }
            Backend::Server { cluster, name, .. } => {
                cluster.psql_in(
                    name,
                    "UPDATE kept_files SET gzip = set_byte(gzip, length(gzip) / 2,
                         get_byte(gzip, length(gzip) / 2) # 16) WHERE role = 'record'",
                );
            }
        }
    }
}

/// `jdbb history --db DB ARGS` in `dir`.
fn history(dir: &Path, b: &Backend, args: &[&str]) -> Output {
    let db = b.db();
    let mut all = vec!["history", "--db", db.as_str()];
    all.extend_from_slice(args);
    let o = jdbb_in(dir, &all);
    for text in [stdout(&o), stderr(&o)] {
        assert!(!text.contains("panicked"), "{text}");
        assert!(!text.contains(pg::PASSWORD), "the password printed: {text}");
    }
    o
}

/// `jdbb history --db DB ARGS` in `dir`, which must succeed: its output.
fn ok(dir: &Path, b: &Backend, args: &[&str]) -> String {
    let o = history(dir, b, args);
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    stdout(&o)
}

/// In `dir`: a plan (plan/plan.json), a record of it on a machine with 8 µm of X play and
/// 40 µrad of XY squareness (rec.csv), and its diagnosis (diag.json, machine `mill`).
fn recorded_test(dir: &Path) {
    ok_in(
        dir,
        &[
            "plan",
            "--radius",
            "90",
            "--feed",
            "1500",
            "--centre",
            "100,50,-20",
            "--out",
            "plan",
        ],
    );
    std::fs::write(
        dir.join("mill.toml"),
        "name = \"mill\"\n[instrument]\nnoise_um = 0.3\nseed = 7\n[effects]\nbacklash_x = 8\nsquareness_xy = 40\n",
    )
    .unwrap();
    ok_in(
        dir,
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
    let json = ok_in(
        dir,
        &[
            "diagnose",
            "--record",
            "rec.csv",
            "--plan",
            "plan/plan.json",
            "--machine",
            "mill",
            "--date",
            "2026-09-01",
            "--json",
        ],
    );
    std::fs::write(dir.join("diag.json"), json).unwrap();
}

/// `history add` of [`recorded_test`]'s diagnosis, keeping its record and plan.
const KEEP: &[&str] = &[
    "add",
    "--diagnosis",
    "diag.json",
    "--keep-record",
    "rec.csv",
    "--plan",
    "plan/plan.json",
];

/// The rows of `history rerun`'s table (after its heading): (effect, difference).
fn differences(out: &str) -> Vec<(String, String)> {
    out.lines()
        .skip_while(|l| !l.starts_with("effect "))
        .skip(1)
        .map(|l| {
            let name = l.split_whitespace().next().unwrap().to_string();
            let words: Vec<&str> = l.split_whitespace().collect();
            let diff = words[words.len().saturating_sub(2)..].join(" ");
            (name, diff)
        })
        .collect()
}

/// Keep → rerun reproduces the stored values; a flipped byte is refused; remove takes the
/// kept record with the run.
fn keep_rerun_damage_remove(b: &Backend) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    recorded_test(d);
    let added = ok(d, b, KEEP);
    assert!(added.contains("kept with run 1: rec.csv ("), "{added}");
    assert_eq!(
        b.count("SELECT COUNT(*) FROM kept_files WHERE run_id = 1"),
        2
    );
    let rec = std::fs::read(d.join("rec.csv")).unwrap();
    assert!(
        b.count("SELECT length(gzip) FROM kept_files WHERE role = 'record'") * 3 < rec.len() as i64,
        "the record is kept compressed"
    );

    // The same jdbb: every effect the same, to the digits printed.
    let out = ok(d, b, &["rerun", "--run", "1"]);
    assert!(
        out.contains("from its kept rec.csv and plan/plan.json (SHA-256 checked)"),
        "{out}"
    );
    let rows = differences(&out);
    assert!(
        rows.iter().any(|(n, _)| n == "backlash_x")
            && rows.iter().any(|(n, _)| n == "squareness_xy"),
        "{out}"
    );
    for (name, diff) in &rows {
        assert_eq!(diff, "+0.00 σ", "{name} differs on the same jdbb:\n{out}");
    }

    // A flipped bit in the stored blob: refused, saying what.
    b.damage_record();
    let o = history(d, b, &["rerun", "--machine", "mill", "--run", "1"]);
    assert_eq!(o.status.code(), Some(2), "{}", stdout(&o));
    let e = stderr(&o);
    assert!(e.contains("the kept record (rec.csv) is damaged"), "{e}");
    assert!(
        stdout(&o).is_empty(),
        "nothing diagnosed from a damaged record"
    );

    // Removing the run removes what it kept.
    ok(d, b, &["remove", "--machine", "mill", "--run", "1"]);
    assert_eq!(b.count("SELECT COUNT(*) FROM kept_files"), 0);
}

#[test]
fn a_kept_record_reruns_to_the_stored_values_is_checked_and_leaves_with_its_run() {
    let dir = tempfile::tempdir().unwrap();
    keep_rerun_damage_remove(&Backend::File(dir.path().join("h.sqlite")));
    let Some(cluster) = pg::cluster() else { return };
    let (name, url) = cluster.database();
    keep_rerun_damage_remove(&Backend::Server { cluster, name, url });
}

/// An old history (without `kept_files`) opens, gains the table, and its run then keeps a
/// record; a run that kept none says so on rerun.
fn old_history_gains_the_table(dir: &Path, b: &Backend) {
    assert_eq!(
        b.count("SELECT COUNT(*) FROM runs"),
        1,
        "the old history holds its run"
    );
    let list = ok(dir, b, &["list", "--machine", "mill"]);
    assert!(list.contains("machine mill: 1 runs"), "{list}");
    let o = history(dir, b, &["rerun", "--run", "1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("run 1 of mill kept no record"),
        "{}",
        stderr(&o)
    );
    let added = ok(dir, b, KEEP);
    assert!(added.contains("nothing added"), "{added}");
    assert!(added.contains("kept with run 1"), "{added}");
    let out = ok(dir, b, &["rerun", "--run", "1"]);
    assert!(
        differences(&out).iter().all(|(_, d)| d == "+0.00 σ"),
        "{out}"
    );
}

#[test]
fn an_old_history_without_kept_records_opens_and_gains_them() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    recorded_test(d);
    // A file of schema version 4 (before kept records), holding one run.
    let path = d.join("old.sqlite");
    {
        use jdbb::history::Store;
        let mut h = jdbb::history::History::open_at(&path, 4).unwrap();
        let (doc, text) = jdbb::report::document::DiagnosisDoc::read(&d.join("diag.json")).unwrap();
        h.add("mill", &doc, &text, "diag.json", None).unwrap();
        assert_eq!(h.version().unwrap(), 4);
    }
    let file = Backend::File(path.clone());
    assert_eq!(
        file.count("SELECT COUNT(*) FROM sqlite_master WHERE name = 'kept_files'"),
        0
    );
    old_history_gains_the_table(d, &file);
    assert_eq!(file.count("PRAGMA user_version"), 5);

    let Some(cluster) = pg::cluster() else { return };
    let (name, url) = cluster.database();
    let server = Backend::Server { cluster, name, url };
    ok(d, &server, &["add", "--diagnosis", "diag.json"]);
    // As a server history of version 4 was: no kept_files.
    if let Backend::Server { cluster, name, .. } = &server {
        cluster.psql_in(
            name,
            "DROP TABLE kept_files; UPDATE jdbb_schema SET version = 4",
        );
    }
    old_history_gains_the_table(d, &server);
    assert_eq!(server.count("SELECT version FROM jdbb_schema"), 5);
}

#[test]
fn a_station_migrated_to_the_server_brings_its_kept_records() {
    let Some(cluster) = pg::cluster() else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    recorded_test(d);
    let file = Backend::File(d.join("station.sqlite"));
    ok(d, &file, KEEP);
    let (name, url) = cluster.database();
    let server = Backend::Server { cluster, name, url };
    let o = jdbb_in(
        d,
        &[
            "history",
            "migrate",
            "--from",
            "station.sqlite",
            "--to",
            &server.db(),
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(server.count("SELECT COUNT(*) FROM kept_files"), 2);
    let out = ok(d, &server, &["rerun", "--run", "1"]);
    let rows = differences(&out);
    assert!(
        !rows.is_empty() && rows.iter().all(|(_, d)| d == "+0.00 σ"),
        "{out}"
    );
}

#[test]
fn a_kept_samples_file_without_a_plan_reruns_as_diagnose_samples() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let simulated = [
        "simulate",
        "--radius",
        "60",
        "--rate",
        "100",
        "--seed",
        "5",
        "--pitch",
        "x=10",
        "--effect",
        "backlash_x=6",
        "--effect",
        "cyclic_x=1.5,0",
        "-o",
        "s.csv",
    ];
    ok_in(d, &simulated);
    let json = ok_in(
        d,
        &[
            "diagnose",
            "--samples",
            "s.csv",
            "--pitch",
            "x=10",
            "--machine",
            "lathe",
            "--json",
        ],
    );
    std::fs::write(d.join("s.json"), json).unwrap();
    let file = Backend::File(d.join("h.sqlite"));
    let added = ok(
        d,
        &file,
        &["add", "--diagnosis", "s.json", "--keep-record", "s.csv"],
    );
    assert!(added.contains("kept with run 1: s.csv ("), "{added}");
    let out = ok(d, &file, &["rerun", "--run", "1"]);
    assert!(
        out.contains("from its kept s.csv (SHA-256 checked)"),
        "{out}"
    );
    let rows = differences(&out);
    // The pitch the run was diagnosed with is the re-run's: the cyclic error is named again.
    assert!(rows.iter().any(|(n, _)| n == "cyclic_x"), "{out}");
    assert!(rows.iter().all(|(_, d)| d == "+0.00 σ"), "{out}");
}
