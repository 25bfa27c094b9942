//! Issue 33 and issue 31's history items: every history command alike on a SQLite file and a
//! PostgreSQL server (a throwaway cluster, [`common::pg`]); stations adding at once, one killed
//! mid-add, lose nothing and file nothing twice; a connection lost mid-add leaves nothing and
//! says so; the URL's password never prints; `history remove` and `history edit --date`; one
//! effect order in `history list`.
#![cfg(unix)]

use std::path::Path;
use std::process::{Child, Output, Stdio};

mod common;
use common::{command, diagnosis, jdbb_in, pg, stderr, stdout};

/// `jdbb history --db DB ARGS` in `dir`, which must succeed; its standard output. The
/// password of the test role must not be in anything it prints.
fn ok_on(dir: &Path, db: &str, args: &[&str]) -> String {
    let o = on(dir, db, args);
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    stdout(&o)
}

/// `jdbb history --db DB ARGS` in `dir`; nothing it prints holds the password.
fn on(dir: &Path, db: &str, args: &[&str]) -> Output {
    let mut all = vec!["history", "--db", db];
    all.extend_from_slice(args);
    let o = jdbb_in(dir, &all);
    for text in [stdout(&o), stderr(&o)] {
        assert!(!text.contains(pg::PASSWORD), "the password printed: {text}");
        assert!(!text.contains("panicked"), "{text}");
    }
    o
}

/// The same commands on `db` (a file or a URL), printed with the history's name as `DB`.
fn session(dir: &Path, db: &str, shown: &str) -> String {
    diagnosis(dir, "sep.json", 8.0, 0.1, "2026-09-01");
    diagnosis(dir, "oct.json", 9.0, 0.1, "2026-10-01");
    diagnosis(dir, "nov.json", 9.5, 0.1, "2026-11-01");
    let mut out = String::new();
    for args in [
        &["add", "--machine", "mill", "--diagnosis", "sep.json"][..],
        &["add", "--machine", "mill", "--diagnosis", "oct.json"],
        &["add", "--machine", "mill", "--diagnosis", "sep.json"],
        // November's test filed as December's by mistake, then corrected.
        &[
            "add",
            "--machine",
            "mill",
            "--diagnosis",
            "nov.json",
            "--date",
            "2026-12-01",
        ],
        &[
            "edit",
            "--machine",
            "mill",
            "--run",
            "3",
            "--date",
            "2026-11-01",
        ],
        &["remove", "--machine", "mill", "--run", "2"],
        &[
            "comp",
            "--machine",
            "mill",
            "--date",
            "2026-10-15",
            "--text",
            "BACKLASH 0.008",
        ],
        &["list"],
        &["list", "--machine", "mill"],
        &["trend", "--machine", "mill"],
    ] {
        out.push_str(&ok_on(dir, db, args).replace(shown, "DB"));
    }
    // A run of another machine, or none, is refused with the runs there are.
    let o = on(dir, db, &["remove", "--machine", "mill", "--run", "7"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    out.push_str(&stderr(&o).replace(shown, "DB"));
    out
}

#[test]
fn every_command_reads_alike_on_a_file_and_a_server() {
    let dir = tempfile::tempdir().unwrap();
    let file = session(dir.path(), "h.sqlite", "h.sqlite");
    for want in [
        "added run 3 of mill (2026-12-01T00:00:00Z) to DB",
        "already in DB: run 1 of mill (2026-09-01T00:00:00Z); nothing added",
        "run 3 of mill now filed on 2026-11-01T00:00:00Z (was 2026-12-01T00:00:00Z) in DB",
        "removed run 2 of mill (2026-10-01T00:00:00Z, from oct.json) from DB",
        "mill: 2 runs",
        "no run 7 of machine `mill` in the history DB; its runs: 1, 3",
    ] {
        assert!(file.contains(want), "wanted `{want}` in:\n{file}");
    }
    let rows: Vec<&str> = file
        .lines()
        .filter(|l| l.starts_with("1 ") || l.starts_with("3 "))
        .collect();
    assert!(
        rows[0].contains("2026-09-01") && rows[1].contains("2026-11-01"),
        "{rows:?}"
    );
    let Some(cluster) = pg::cluster() else { return };
    let (_, url) = cluster.database();
    let dir = tempfile::tempdir().unwrap();
    let shown = url.replace(pg::PASSWORD, "***");
    let server = session(dir.path(), &url, &shown);
    assert_eq!(server, file, "the server's history reads as the file's");
    // The history named by JDBB_HISTORY_DB when no --db is given.
    let o = command()
        .current_dir(dir.path())
        .env("JDBB_HISTORY_DB", &url)
        .args(["history", "list"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(stdout(&o), "mill: 2 runs\n");
}

#[test]
fn one_effect_order_in_every_row_of_the_list() {
    // Two diagnoses naming the same effects in another order: the list shows them in one.
    let dir = tempfile::tempdir().unwrap();
    let effects = |names: [&str; 2]| {
        names
            .iter()
            .map(|n| {
                serde_json::json!({"name": n, "value": 4.0, "unit": "um", "sigma": 0.1,
                    "params": {"b_um": 4.0}})
            })
            .collect::<Vec<_>>()
    };
    for (file, names, date) in [
        ("a.json", ["backlash_x", "backlash_y"], "2026-09-01"),
        ("b.json", ["backlash_y", "backlash_x"], "2026-10-01"),
    ] {
        let text = serde_json::json!({
            "format": 2, "samples": 1000, "effects": effects(names),
            "final": {"rms_um": 0.3}, "plane": "xy",
            "circles": [{"radius_mm": 50.0, "height_mm": 0.0, "feed_mm_min": 1000.0,
                         "samples": 500, "g_um": 5.0, "h_um": 3.0}],
            "date_utc": date,
        });
        std::fs::write(dir.path().join(file), text.to_string()).unwrap();
        ok_on(
            dir.path(),
            "h.sqlite",
            &["add", "--machine", "m", "--diagnosis", file],
        );
    }
    let list = ok_on(dir.path(), "h.sqlite", &["list", "--machine", "m"]);
    let rows: Vec<&str> = list.lines().skip(2).collect();
    assert_eq!(rows.len(), 2, "{list}");
    for row in rows {
        let x = row.find("backlash_x").unwrap();
        let y = row.find("backlash_y").unwrap();
        assert!(x < y, "every row in the one order: {list}");
    }
}

/// A client of the test database as the superuser.
fn superuser(cluster: &pg::Cluster, db: &str) -> postgres::Client {
    postgres::Client::connect(
        &format!(
            "host=127.0.0.1 port={} user=postgres password={} dbname={db}",
            cluster.port,
            pg::PASSWORD
        ),
        postgres::NoTls,
    )
    .unwrap()
}

/// `jdbb history --db URL add --machine mill --diagnosis FILE` started in `dir`.
fn spawn_add(dir: &Path, url: &str, file: &str) -> Child {
    command()
        .current_dir(dir)
        .args(["history", "--db", url, "add", "--machine", "mill"])
        .args(["--diagnosis", file])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Wait until `n` sessions of database `db` wait for a lock (bounded: 60 s of polling).
fn wait_for_waiters(client: &mut postgres::Client, db: &str, n: i64) {
    for _ in 0..1200 {
        let waiting: i64 = client
            .query_one(
                "SELECT COUNT(*) FROM pg_stat_activity WHERE datname = $1 AND wait_event_type = 'Lock'",
                &[&db],
            )
            .unwrap()
            .get(0);
        if waiting >= n {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    panic!("fewer than {n} adds reached the lock");
}

/// The runs of database `db`: (digest, effects filed with it), by id.
fn stored(client: &mut postgres::Client) -> Vec<(String, i64)> {
    client
        .query(
            "SELECT r.digest, (SELECT COUNT(*) FROM effects e WHERE e.run_id = r.id) FROM runs r ORDER BY r.id",
            &[],
        )
        .unwrap()
        .iter()
        .map(|r| (r.get(0), r.get(1)))
        .collect()
}

#[test]
fn stations_adding_at_once_one_killed_mid_add_lose_nothing_and_file_nothing_twice() {
    let Some(cluster) = pg::cluster() else { return };
    let (db, url) = cluster.database();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d, "first.json", 1.0, 0.1, "2026-01-01");
    diagnosis(d, "shared.json", 2.0, 0.1, "2026-02-01");
    diagnosis(d, "victim.json", 3.0, 0.1, "2026-03-01");
    for k in 0..5 {
        diagnosis(
            d,
            &format!("own{k}.json"),
            10.0 + k as f64,
            0.1,
            "2026-04-01",
        );
    }
    ok_on(
        d,
        &url,
        &["add", "--machine", "mill", "--diagnosis", "first.json"],
    );
    // Hold every add inside its transaction: the effects table locked by another session.
    let mut watch = superuser(cluster, &db);
    let mut blocker = superuser(cluster, &db);
    let mut tx = blocker.transaction().unwrap();
    tx.batch_execute("LOCK TABLE effects IN EXCLUSIVE MODE")
        .unwrap();
    let shared: Vec<Child> = (0..5).map(|_| spawn_add(d, &url, "shared.json")).collect();
    let own: Vec<Child> = (0..5)
        .map(|k| spawn_add(d, &url, &format!("own{k}.json")))
        .collect();
    let mut victim = spawn_add(d, &url, "victim.json");
    // 1 + 5 + 1 at the effects lock, 4 waiting for the first shared add's transaction.
    wait_for_waiters(&mut watch, &db, 11);
    victim.kill().unwrap();
    victim.wait().unwrap();
    tx.rollback().unwrap();
    let mut added = 0;
    for c in shared {
        let o = c.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        let text = stdout(&o);
        assert!(!text.contains(pg::PASSWORD));
        added += usize::from(text.starts_with("added run"));
        assert!(
            text.starts_with("added run") || text.starts_with("already in"),
            "{text}"
        );
    }
    assert_eq!(added, 1, "the shared diagnosis filed once");
    for c in own {
        let o = c.wait_with_output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let runs = stored(&mut watch);
    assert_eq!(runs.len(), 7, "first, shared, five own: {runs:?}");
    assert!(
        runs.iter().all(|r| r.1 == 1),
        "every run with its effect: {runs:?}"
    );
    let mut digests: Vec<&String> = runs.iter().map(|r| &r.0).collect();
    digests.sort();
    digests.dedup();
    assert_eq!(digests.len(), 7, "none twice");
    // The killed station's run left nothing; adding it again files it once.
    ok_on(
        d,
        &url,
        &["add", "--machine", "mill", "--diagnosis", "victim.json"],
    );
    assert_eq!(stored(&mut watch).len(), 8);
}

#[test]
fn a_connection_lost_mid_add_leaves_nothing_and_says_so() {
    let Some(cluster) = pg::cluster() else { return };
    let (db, url) = cluster.database();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    diagnosis(d, "first.json", 1.0, 0.1, "2026-01-01");
    diagnosis(d, "second.json", 2.0, 0.1, "2026-02-01");
    ok_on(
        d,
        &url,
        &["add", "--machine", "mill", "--diagnosis", "first.json"],
    );
    let mut watch = superuser(cluster, &db);
    let mut blocker = superuser(cluster, &db);
    let mut tx = blocker.transaction().unwrap();
    tx.batch_execute("LOCK TABLE effects IN EXCLUSIVE MODE")
        .unwrap();
    let add = spawn_add(d, &url, "second.json");
    wait_for_waiters(&mut watch, &db, 1);
    // The server ends the station's connection while its run is half-written.
    watch
        .batch_execute(&format!(
            "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE datname = '{db}' AND wait_event_type = 'Lock'"
        ))
        .unwrap();
    let o = add.wait_with_output().unwrap();
    tx.rollback().unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("the connection was lost while adding"), "{e}");
    assert!(
        e.contains("nothing of this run was written; add it again"),
        "{e}"
    );
    assert!(
        !e.contains(pg::PASSWORD) && e.contains(":***@127.0.0.1"),
        "{e}"
    );
    assert_eq!(stored(&mut watch).len(), 1, "nothing half-written");
}

#[test]
fn tls_asked_for_is_required_and_a_server_history_must_exist_to_be_read() {
    let Some(cluster) = pg::cluster() else { return };
    let (_, url) = cluster.database();
    let dir = tempfile::tempdir().unwrap();
    // This server has no TLS: asked for, the connection is refused rather than made in clear.
    let o = on(dir.path(), &format!("{url}?sslmode=require"), &["list"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("TLS"), "{}", stderr(&o));
    // A mistyped database is an error for a reader, and no history is created by reading.
    let o = on(dir.path(), &url, &["list"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(
        stderr(&o).contains("no history in the database"),
        "{}",
        stderr(&o)
    );
    // Another program's database is left as it was.
    let (name, url) = cluster.database();
    cluster.psql_in(&name, "CREATE TABLE laps (t REAL)");
    diagnosis(dir.path(), "a.json", 1.0, 0.1, "2026-01-01");
    let o = on(
        dir.path(),
        &url,
        &["add", "--machine", "m", "--diagnosis", "a.json"],
    );
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("another program's"), "{}", stderr(&o));
    assert_eq!(
        cluster.psql_in(&name, "SELECT string_agg(table_name, ',') FROM information_schema.tables WHERE table_schema = 'public'"),
        "laps"
    );
}

#[test]
fn a_stations_file_migrates_to_the_server_checked_and_safe_to_run_twice() {
    let Some(cluster) = pg::cluster() else { return };
    let (_, url) = cluster.database();
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (k, date) in ["2026-09-01", "2026-10-01", "2026-11-01"]
        .iter()
        .enumerate()
    {
        let name = format!("r{k}.json");
        diagnosis(d, &name, 8.0 + k as f64, 0.1, date);
        ok_on(
            d,
            "h.sqlite",
            &["add", "--machine", "mill", "--diagnosis", &name],
        );
        ok_on(
            d,
            "h.sqlite",
            &["add", "--machine", "lathe", "--diagnosis", &name],
        );
    }
    ok_on(
        d,
        "h.sqlite",
        &[
            "comp",
            "--machine",
            "mill",
            "--date",
            "2026-10-15",
            "--text",
            "BACKLASH 0.009",
        ],
    );
    let shown = url.replace(pg::PASSWORD, "***");
    let first = ok_on(d, &url, &["migrate", "--from", "h.sqlite", "--to", &url]);
    assert_eq!(
        first,
        format!("migrated h.sqlite to {shown}: 6 runs of 2 machines (6 new there), 1 compensation changes (1 new there); checked: every run there with the same checksum\n")
    );
    let again = ok_on(d, &url, &["migrate", "--from", "h.sqlite", "--to", &url]);
    assert!(
        again.contains("(0 new there), 1 compensation changes (0 new there)"),
        "{again}"
    );
    for args in [
        &["list"][..],
        &["list", "--machine", "mill"],
        &["trend", "--machine", "mill"],
        &["trend", "--machine", "lathe", "--figure", "g"],
    ] {
        assert_eq!(
            ok_on(d, &url, args).replace(&shown, "DB"),
            ok_on(d, "h.sqlite", args).replace("h.sqlite", "DB"),
            "{args:?}"
        );
    }
}

/// A fleet of two machines in `db`: mill's X play grows from its fifth run, lathe's stays.
fn fleet_session(dir: &Path, db: &str, shown: &str) -> String {
    let mill = [8.0, 8.05, 7.95, 8.0, 8.3, 8.6, 8.9];
    let lathe = [5.0, 5.05, 4.95, 5.0, 5.05, 4.95, 5.0];
    for (machine, values) in [("mill", mill), ("lathe", lathe)] {
        for (k, v) in values.iter().enumerate() {
            let name = format!("{machine}{k}.json");
            diagnosis(dir, &name, *v, 0.1, &format!("2026-{:02}-01", k + 1));
            ok_on(
                dir,
                db,
                &["add", "--machine", machine, "--diagnosis", &name],
            );
        }
    }
    let mut out = ok_on(
        dir,
        db,
        &[
            "fleet",
            "--csv",
            "fleet.csv",
            "--html",
            "fleet.html",
            "--force",
        ],
    );
    // The nut is replaced and the compensation set anew: the alarm restarts from there.
    ok_on(
        dir,
        db,
        &[
            "comp",
            "--machine",
            "mill",
            "--date",
            "2026-07-15",
            "--text",
            "new nut",
        ],
    );
    for (k, v) in [2.0, 2.05, 1.95].iter().enumerate() {
        let name = format!("after{k}.json");
        diagnosis(dir, &name, *v, 0.1, &format!("2026-{:02}-01", k + 8));
        ok_on(dir, db, &["add", "--machine", "mill", "--diagnosis", &name]);
    }
    out.push_str(&ok_on(dir, db, &["fleet"]));
    out.replace(shown, "DB")
}

#[test]
fn the_fleet_view_flags_a_drift_with_its_runs_and_restarts_after_a_compensation() {
    let dir = tempfile::tempdir().unwrap();
    let file = fleet_session(dir.path(), "h.sqlite", "h.sqlite");
    let row = |text: &str, machine: &str, nth: usize| {
        text.split("drift alarms:")
            .nth(nth)
            .unwrap()
            .lines()
            .find(|l| l.starts_with(machine) && l.contains("backlash_x"))
            .unwrap()
            .to_string()
    };
    let mill = row(&file, "mill ", 1);
    assert!(mill.ends_with("DRIFT up in runs 5, 6, 7"), "{file}");
    assert!(mill.contains(" 8.9"), "latest value: {mill}");
    assert!(row(&file, "lathe", 1).ends_with(" -"), "{file}");
    let after = row(&file, "mill ", 2);
    assert!(
        after.ends_with(" -") && after.contains("2026-07-15 new nut"),
        "{file}"
    );
    let csv = std::fs::read_to_string(dir.path().join("fleet.csv")).unwrap();
    assert!(
        csv.lines()
            .any(|l| l.starts_with("mill,backlash_x,um,7,") && l.ends_with(",up,5 6 7")),
        "{csv}"
    );
    let html = std::fs::read_to_string(dir.path().join("fleet.html")).unwrap();
    assert!(
        html.contains("<td class=\"alarm\">DRIFT up in runs 5, 6, 7</td>"),
        "{html}"
    );
    let Some(cluster) = pg::cluster() else { return };
    let (_, url) = cluster.database();
    let dir = tempfile::tempdir().unwrap();
    let shown = url.replace(pg::PASSWORD, "***");
    assert_eq!(fleet_session(dir.path(), &url, &shown), file);
}
