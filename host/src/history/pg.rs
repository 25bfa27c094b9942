//! The history on a PostgreSQL server (`--db postgres://…`): a plant's machines in one database
//! that several stations add to at once.
//!
//! - The same tables as the SQLite file ([`super::schema`] at its latest version) in the
//!   database's search path, plus `jdbb_schema` (jdbb's application id and the schema version):
//!   a database holding other tables but not that one is another program's and is refused
//!   untouched, one of a newer jdbb's version too.
//! - The schema is created once, under a transaction-scoped advisory lock, so stations that
//!   first open a new database at once do not race.
//! - Idempotence is the database's: `UNIQUE (machine_id, digest)` and `ON CONFLICT DO NOTHING`,
//!   each add in one transaction. A connection lost mid-add leaves nothing (the server rolls the
//!   open transaction back) and the error says so; a commit whose answer was lost is said to be
//!   unknown, and adding again files the run once.
//! - TLS as the URL asks (`sslmode=disable|prefer|require`; `prefer` is the default), through
//!   the system's TLS library with its certificate check.
//! - The URL's password never prints: every message names the history by [`redact`].
//!
//! May use: postgres, postgres-native-tls.
use postgres::{Client, Config, Row};

use super::{
    find_run, schema, unknown_machine, Added, CompensationEvent, Conditions, EffectRow, Export,
    NewRun, Run, Store,
};
use crate::{Error, Result};

/// Whether `db` (a `--db` or `JDBB_HISTORY_DB` value) names a PostgreSQL server.
pub fn is_url(db: &str) -> bool {
    db.starts_with("postgres://") || db.starts_with("postgresql://")
}

/// `url` with its password (in the user part, or a `password=` parameter) shown as `***`: the
/// only way a history URL is printed.
pub fn redact(url: &str) -> String {
    let (scheme, rest) = url.split_once("://").unwrap_or(("", url));
    let (body, query) = match rest.split_once('?') {
        Some((b, q)) => (b, Some(q)),
        None => (rest, None),
    };
    let body = match body.rsplit_once('@') {
        Some((user, host)) => match user.split_once(':') {
            Some((name, _)) => format!("{name}:***@{host}"),
            None => format!("{user}@{host}"),
        },
        None => body.to_string(),
    };
    let query = query.map(|q| {
        q.split('&')
            .map(|kv| match kv.split_once('=') {
                Some((k, _)) if k.to_ascii_lowercase().contains("password") => format!("{k}=***"),
                _ => kv.to_string(),
            })
            .collect::<Vec<_>>()
            .join("&")
    });
    let mut out = if scheme.is_empty() {
        body
    } else {
        format!("{scheme}://{body}")
    };
    if let Some(q) = query {
        out.push('?');
        out.push_str(&q);
    }
    out
}

/// The tables of a new jdbb history on a server (schema version 4, the first on a server),
/// brought up to date by [`MIGRATIONS`].
const SCHEMA: &str = "
CREATE TABLE jdbb_schema (application_id BIGINT NOT NULL, version BIGINT NOT NULL);
CREATE TABLE machines (
    id BIGSERIAL PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    created_utc TEXT NOT NULL
);
CREATE TABLE runs (
    id BIGSERIAL PRIMARY KEY,
    machine_id BIGINT NOT NULL REFERENCES machines(id),
    date_utc TEXT NOT NULL,
    added_utc TEXT NOT NULL,
    source TEXT NOT NULL,
    digest TEXT NOT NULL,
    samples BIGINT NOT NULL,
    conditions TEXT NOT NULL,
    g_um DOUBLE PRECISION,
    h_um DOUBLE PRECISION,
    final_rms_um DOUBLE PRECISION,
    tolerance_um DOUBLE PRECISION,
    pass BOOLEAN,
    diagnosis TEXT NOT NULL,
    jdbb_version TEXT,
    compensation TEXT,
    UNIQUE (machine_id, digest)
);
CREATE INDEX runs_by_machine_date ON runs (machine_id, date_utc);
CREATE TABLE effects (
    run_id BIGINT NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
    position INTEGER NOT NULL,
    name TEXT NOT NULL,
    value DOUBLE PRECISION,
    sigma DOUBLE PRECISION,
    unit TEXT NOT NULL,
    PRIMARY KEY (run_id, name)
);
CREATE TABLE compensations (
    id BIGSERIAL PRIMARY KEY,
    machine_id BIGINT NOT NULL REFERENCES machines(id),
    date_utc TEXT NOT NULL,
    added_utc TEXT NOT NULL,
    text TEXT NOT NULL,
    source TEXT
);
CREATE INDEX compensations_by_machine_date ON compensations (machine_id, date_utc);
";

/// The schema version [`SCHEMA`] creates.
const SCHEMA_VERSION: i64 = 4;

/// The server's migrations after [`SCHEMA_VERSION`]: `(k, sql)` takes the version from k − 1 to
/// k, as migration k of [`schema::MIGRATIONS`] does on a file. Never edit a released one: add one.
const MIGRATIONS: &[(i64, &str)] = &[(
    5,
    "CREATE TABLE kept_files (
        run_id BIGINT NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
        role TEXT NOT NULL,
        name TEXT NOT NULL,
        size_bytes BIGINT NOT NULL,
        sha256 TEXT NOT NULL,
        gzip BYTEA NOT NULL,
        PRIMARY KEY (run_id, role)
    );",
)];

/// Bring the history of `tx` (the advisory lock held) from `version` to [`schema::latest`].
fn upgrade(
    tx: &mut postgres::Transaction,
    version: i64,
) -> std::result::Result<(), postgres::Error> {
    for (k, sql) in MIGRATIONS.iter().filter(|(k, _)| *k > version) {
        tx.batch_execute(sql)?;
        tx.execute("UPDATE jdbb_schema SET version = $1", &[k])?;
    }
    Ok(())
}

/// A history on a PostgreSQL server.
pub struct PgHistory {
    client: Client,
    /// The URL, redacted ([`redact`]).
    location: String,
}

impl PgHistory {
    /// Connect to the server of `url` and check that its database is a jdbb history, creating
    /// the schema in an empty one unless `existing` (reading commands: a mistyped URL is an
    /// error, not a new history).
    pub fn open(url: &str, existing: bool) -> Result<PgHistory> {
        let location = redact(url);
        let config: Config = url.parse().map_err(|e| Error::Usage(format!(
            "--db {location}: not a PostgreSQL URL ({e}); give postgres://USER:PASSWORD@HOST:PORT/DATABASE"
        )))?;
        let tls = native_tls::TlsConnector::new().map_err(|e| Error::Server {
            location: location.clone(),
            message: format!("cannot set up TLS: {e}"),
        })?;
        let client = config
            .connect(postgres_native_tls::MakeTlsConnector::new(tls))
            .map_err(|e| Error::Server {
                location: location.clone(),
                message: format!(
                    "cannot connect: {}; check the host, port, user, password and database of the URL (and sslmode)",
                    text(&e)
                ),
            })?;
        let mut h = PgHistory { client, location };
        h.check_schema(existing)?;
        Ok(h)
    }

    fn err(&self) -> impl Fn(postgres::Error) -> Error + '_ {
        move |e| Error::Server {
            location: self.location.clone(),
            message: text(&e),
        }
    }

    /// Whose the database is, and its schema created if it is new and may be (module docs).
    fn check_schema(&mut self, existing: bool) -> Result<()> {
        let location = self.location.clone();
        let err = |e: postgres::Error| Error::Server {
            location: location.clone(),
            message: text(&e),
        };
        let mut tx = self.client.transaction().map_err(err)?;
        tx.execute(
            "SELECT pg_advisory_xact_lock($1)",
            &[&schema::APPLICATION_ID],
        )
        .map_err(err)?;
        let ours = tx
            .query_one("SELECT to_regclass('jdbb_schema') IS NOT NULL", &[])
            .map_err(err)?
            .get::<_, bool>(0);
        if ours {
            let row = tx
                .query_opt("SELECT application_id, version FROM jdbb_schema", &[])
                .map_err(err)?;
            let (id, version): (i64, i64) = row.map_or((0, 0), |r| (r.get(0), r.get(1)));
            if id != schema::APPLICATION_ID {
                return Err(Error::Usage(format!(
                    "{location} is not a jdbb history database (its jdbb_schema holds application id {id:#010x}): left as it was; check --db"
                )));
            }
            if version > schema::latest() {
                return Err(Error::Usage(format!(
                    "history database {location}: schema version {version} was written by a newer jdbb (this one knows {}); update jdbb",
                    schema::latest()
                )));
            }
            upgrade(&mut tx, version).map_err(err)?;
            return tx.commit().map_err(err);
        }
        let tables: Vec<String> = tx
            .query(
                // pg_tables lists every table, also those this role may not read (which
                // information_schema hides).
                "SELECT tablename::text FROM pg_catalog.pg_tables
                 WHERE schemaname = current_schema() ORDER BY tablename",
                &[],
            )
            .map_err(err)?
            .iter()
            .map(|r| r.get(0))
            .collect();
        if !tables.is_empty() {
            return Err(Error::Usage(format!(
                "{location} is not a jdbb history database (it holds the tables {} and no jdbb_schema): it is another program's, left as it was; check --db",
                tables.join(", ")
            )));
        }
        if existing {
            return Err(Error::Usage(format!(
                "no history in the database {location}: check --db (`jdbb history add` creates one)"
            )));
        }
        tx.batch_execute(SCHEMA).map_err(err)?;
        tx.execute(
            "INSERT INTO jdbb_schema (application_id, version) VALUES ($1, $2)",
            &[&schema::APPLICATION_ID, &SCHEMA_VERSION],
        )
        .map_err(err)?;
        upgrade(&mut tx, SCHEMA_VERSION).map_err(err)?;
        tx.commit().map_err(err)
    }

    /// The files run `run_id` keeps, the record first.
    fn kept_files(&mut self, run_id: i64) -> Result<Vec<super::keep::KeptFile>> {
        Ok(self
            .client
            .query(
                "SELECT role, name, size_bytes, sha256, gzip FROM kept_files WHERE run_id = $1
                 ORDER BY role = 'plan', role",
                &[&run_id],
            )
            .map_err(self.err())?
            .iter()
            .map(|r| super::keep::KeptFile {
                role: r.get(0),
                name: r.get(1),
                size_bytes: r.get(2),
                sha256: r.get(3),
                gzip: r.get(4),
            })
            .collect())
    }

    /// The id of `machine`; an unknown machine is a usage error naming the known ones.
    fn machine_id(&mut self, machine: &str) -> Result<i64> {
        let row = self
            .client
            .query_opt("SELECT id FROM machines WHERE name = $1", &[&machine])
            .map_err(self.err())?;
        match row {
            Some(r) => Ok(r.get(0)),
            None => {
                let known = self.machines()?;
                Err(unknown_machine(machine, &self.location, &known))
            }
        }
    }
}

/// A server error in words: the server's own message where it sent one.
fn text(e: &postgres::Error) -> String {
    match e.as_db_error() {
        Some(db) => format!("{}: {}", db.severity(), db.message()),
        None => e.to_string(),
    }
}

/// Whether `e` ended the connection (closed, broken, or ended by the server: a FATAL error)
/// rather than refused one statement.
fn connection_lost(e: &postgres::Error) -> bool {
    e.is_closed()
        || e.as_db_error()
            .is_none_or(|d| matches!(d.severity(), "FATAL" | "PANIC"))
}

/// Keep `files` with run `run_id` in `tx`, but not a role the run already keeps; returns how
/// many were kept.
fn keep_files(
    tx: &mut postgres::Transaction,
    run_id: i64,
    files: &[super::keep::KeptFile],
) -> std::result::Result<usize, postgres::Error> {
    let mut n = 0;
    for f in files {
        n += tx.execute(
            "INSERT INTO kept_files (run_id, role, name, size_bytes, sha256, gzip)
             VALUES ($1, $2, $3, $4, $5, $6) ON CONFLICT (run_id, role) DO NOTHING",
            &[&run_id, &f.role, &f.name, &f.size_bytes, &f.sha256, &f.gzip],
        )? as usize;
    }
    Ok(n)
}

/// A run as the columns of `runs` give it (without its effects).
fn run_of_row(r: &Row) -> Run {
    let conditions: String = r.get(5);
    Run {
        id: r.get(0),
        date_utc: r.get(1),
        added_utc: r.get(2),
        source: r.get(3),
        samples: r.get(4),
        conditions: serde_json::from_str::<Conditions>(&conditions).unwrap_or_default(),
        g_um: r.get(6),
        h_um: r.get(7),
        final_rms_um: r.get(8),
        tolerance_um: r.get(9),
        pass: r.get(10),
        effects: vec![],
        compensation: r.get(11),
    }
}

impl Store for PgHistory {
    fn location(&self) -> String {
        self.location.clone()
    }

    fn store_run(&mut self, run: &NewRun) -> Result<Added> {
        let location = self.location.clone();
        let lost = |e: postgres::Error, committing: bool| Error::Server {
            location: location.clone(),
            message: if connection_lost(&e) {
                if committing {
                    format!("{}: the connection was lost while the run was committed, so whether it was filed is unknown; add it again (a run already filed is not filed twice)", text(&e))
                } else {
                    format!("{}: the connection was lost while adding; the server rolls the unfinished transaction back, so nothing of this run was written; add it again", text(&e))
                }
            } else {
                format!("{}; nothing of this run was written", text(&e))
            },
        };
        let now = crate::dates::now_utc();
        let mut tx = self.client.transaction().map_err(|e| lost(e, false))?;
        tx.execute(
            "INSERT INTO machines (name, created_utc) VALUES ($1, $2) ON CONFLICT (name) DO NOTHING",
            &[&run.machine, &now],
        )
        .map_err(|e| lost(e, false))?;
        let machine_id: i64 = tx
            .query_one("SELECT id FROM machines WHERE name = $1", &[&run.machine])
            .map_err(|e| lost(e, false))?
            .get(0);
        let filed = |tx: &mut postgres::Transaction| {
            tx.query_opt(
                "SELECT id, date_utc FROM runs WHERE machine_id = $1 AND digest = $2",
                &[&machine_id, &run.digest],
            )
        };
        // Filed before (by this station or another): checked first, so that a run filed again
        // takes no number from the sequence.
        let before = filed(&mut tx).map_err(|e| lost(e, false))?;
        let inserted = if before.is_some() {
            None
        } else {
            tx.query_opt(
                "INSERT INTO runs (machine_id, date_utc, added_utc, source, digest, samples, conditions,
                     g_um, h_um, final_rms_um, tolerance_um, pass, diagnosis, jdbb_version, compensation)
                 VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15)
                 ON CONFLICT (machine_id, digest) DO NOTHING RETURNING id",
                &[
                    &machine_id,
                    &run.date_utc,
                    &now,
                    &run.source,
                    &run.digest,
                    &run.samples,
                    &run.conditions,
                    &run.g_um,
                    &run.h_um,
                    &run.final_rms_um,
                    &run.tolerance_um,
                    &run.pass,
                    &run.diagnosis,
                    &run.jdbb_version,
                    &run.compensation,
                ],
            )
            .map_err(|e| lost(e, false))?
        };
        let Some(row) = inserted else {
            // Filed before, or by another station a moment ago (its transaction committed
            // meanwhile).
            let again = if before.is_some() {
                before
            } else {
                filed(&mut tx).map_err(|e| lost(e, false))?
            };
            let r = again.ok_or_else(|| Error::Server {
                location: location.clone(),
                message: "a run of the same digest was filed and removed at once; add it again"
                    .into(),
            })?;
            // Filed before: it keeps the files it has, and gains those it lacks.
            let kept = keep_files(&mut tx, r.get(0), &run.kept).map_err(|e| lost(e, false))?;
            tx.commit().map_err(|e| lost(e, false))?;
            return Ok(Added {
                run_id: r.get(0),
                new: false,
                date_utc: r.get(1),
                date_from_file: run.date_from_file,
                kept,
            });
        };
        let run_id: i64 = row.get(0);
        for (k, e) in run.effects.iter().enumerate() {
            tx.execute(
                "INSERT INTO effects (run_id, position, name, value, sigma, unit)
                 VALUES ($1, $2, $3, $4, $5, $6)",
                &[&run_id, &(k as i32), &e.name, &e.value, &e.sigma, &e.unit],
            )
            .map_err(|e| lost(e, false))?;
        }
        let kept = keep_files(&mut tx, run_id, &run.kept).map_err(|e| lost(e, false))?;
        tx.commit().map_err(|e| lost(e, true))?;
        Ok(Added {
            run_id,
            new: true,
            date_utc: run.date_utc.clone(),
            date_from_file: run.date_from_file,
            kept,
        })
    }

    fn machines(&mut self) -> Result<Vec<(String, i64)>> {
        let rows = self
            .client
            .query(
                "SELECT m.name, COUNT(r.id) FROM machines m LEFT JOIN runs r ON r.machine_id = m.id
                 GROUP BY m.id, m.name ORDER BY m.name",
                &[],
            )
            .map_err(self.err())?;
        Ok(rows.iter().map(|r| (r.get(0), r.get(1))).collect())
    }

    fn runs(&mut self, machine: &str) -> Result<Vec<Run>> {
        let machine_id = self.machine_id(machine)?;
        let mut runs: Vec<Run> = self
            .client
            .query(
                "SELECT id, date_utc, added_utc, source, samples, conditions, g_um, h_um,
                        final_rms_um, tolerance_um, pass, compensation
                 FROM runs WHERE machine_id = $1 ORDER BY date_utc, id",
                &[&machine_id],
            )
            .map_err(self.err())?
            .iter()
            .map(run_of_row)
            .collect();
        let effects = self
            .client
            .query(
                "SELECT e.run_id, e.name, e.value, e.sigma, e.unit FROM effects e
                 JOIN runs r ON r.id = e.run_id WHERE r.machine_id = $1
                 ORDER BY e.run_id, e.position",
                &[&machine_id],
            )
            .map_err(self.err())?;
        for e in effects {
            let run_id: i64 = e.get(0);
            if let Some(run) = runs.iter_mut().find(|r| r.id == run_id) {
                run.effects.push(EffectRow {
                    name: e.get(1),
                    value: e.get(2),
                    sigma: e.get(3),
                    unit: e.get(4),
                });
            }
        }
        Ok(runs)
    }

    fn compensations(&mut self, machine: &str) -> Result<Vec<CompensationEvent>> {
        let machine_id = self.machine_id(machine)?;
        let rows = self
            .client
            .query(
                "SELECT id, date_utc, text, source FROM compensations WHERE machine_id = $1
                 ORDER BY date_utc, id",
                &[&machine_id],
            )
            .map_err(self.err())?;
        Ok(rows
            .iter()
            .map(|r| CompensationEvent {
                id: r.get(0),
                date_utc: r.get(1),
                text: r.get(2),
                source: r.get(3),
            })
            .collect())
    }

    fn add_compensation(
        &mut self,
        machine: &str,
        date_utc: &str,
        text: &str,
        source: Option<&str>,
    ) -> Result<i64> {
        super::check_compensation_text(text)?;
        let machine_id = self.machine_id(machine)?;
        let row = self
            .client
            .query_one(
                "INSERT INTO compensations (machine_id, date_utc, added_utc, text, source)
                 VALUES ($1, $2, $3, $4, $5) RETURNING id",
                &[
                    &machine_id,
                    &date_utc,
                    &crate::dates::now_utc(),
                    &text,
                    &source,
                ],
            )
            .map_err(self.err())?;
        Ok(row.get(0))
    }

    fn remove_run(&mut self, machine: &str, run_id: i64) -> Result<Run> {
        let runs = self.runs(machine)?;
        let run = find_run(runs, machine, run_id, &self.location)?;
        let location = self.location.clone();
        let err = |e: postgres::Error| Error::Server {
            location: location.clone(),
            message: text(&e),
        };
        let mut tx = self.client.transaction().map_err(err)?;
        tx.execute("DELETE FROM effects WHERE run_id = $1", &[&run_id])
            .map_err(err)?;
        tx.execute("DELETE FROM kept_files WHERE run_id = $1", &[&run_id])
            .map_err(err)?;
        tx.execute("DELETE FROM runs WHERE id = $1", &[&run_id])
            .map_err(err)?;
        tx.commit().map_err(err)?;
        Ok(run)
    }

    fn set_date(&mut self, machine: &str, run_id: i64, date_utc: &str) -> Result<String> {
        let runs = self.runs(machine)?;
        let run = find_run(runs, machine, run_id, &self.location)?;
        self.client
            .execute(
                "UPDATE runs SET date_utc = $1 WHERE id = $2",
                &[&date_utc, &run_id],
            )
            .map_err(self.err())?;
        Ok(run.date_utc)
    }

    fn kept(&mut self, machine: &str, run_id: i64) -> Result<super::keep::Kept> {
        let runs = self.runs(machine)?;
        let run = find_run(runs, machine, run_id, &self.location)?;
        let diagnosis: String = self
            .client
            .query_one("SELECT diagnosis FROM runs WHERE id = $1", &[&run_id])
            .map_err(self.err())?
            .get(0);
        Ok(super::keep::Kept {
            run,
            diagnosis,
            files: self.kept_files(run_id)?,
        })
    }

    fn export(&mut self) -> Result<Export> {
        let mut out = Export::default();
        // Runs in the order they were filed (by id), so that a new history numbers them alike.
        let mut filed: Vec<(i64, NewRun)> = vec![];
        for (machine, _) in self.machines()? {
            let id = self.machine_id(&machine)?;
            let rows = self
                .client
                .query(
                    "SELECT id, date_utc, source, digest, samples, conditions, g_um, h_um,
                            final_rms_um, tolerance_um, pass, diagnosis, jdbb_version, compensation
                     FROM runs WHERE machine_id = $1 ORDER BY date_utc, id",
                    &[&id],
                )
                .map_err(self.err())?;
            let runs = self.runs(&machine)?;
            for r in rows {
                let run_id: i64 = r.get(0);
                let kept = self.kept_files(run_id)?;
                filed.push((
                    run_id,
                    NewRun {
                        machine: machine.clone(),
                        date_utc: r.get(1),
                        date_from_file: false,
                        source: r.get(2),
                        digest: r.get(3),
                        samples: r.get(4),
                        conditions: r.get(5),
                        g_um: r.get(6),
                        h_um: r.get(7),
                        final_rms_um: r.get(8),
                        tolerance_um: r.get(9),
                        pass: r.get(10),
                        diagnosis: r.get(11),
                        jdbb_version: r.get(12),
                        compensation: r.get(13),
                        effects: runs
                            .iter()
                            .find(|run| run.id == run_id)
                            .map(|run| run.effects.clone())
                            .unwrap_or_default(),
                        kept,
                    },
                ));
            }
            for c in self.compensations(&machine)? {
                out.compensations.push((machine.clone(), c));
            }
        }
        filed.sort_by_key(|(id, _)| *id);
        out.runs = filed.into_iter().map(|(_, r)| r).collect();
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passwords_never_print() {
        assert_eq!(
            redact("postgres://lab:s3cr%40t@db.plant:5432/jdbb?sslmode=require"),
            "postgres://lab:***@db.plant:5432/jdbb?sslmode=require"
        );
        assert_eq!(
            redact("postgresql://db/jdbb?user=lab&password=hunter2&sslmode=disable"),
            "postgresql://db/jdbb?user=lab&password=***&sslmode=disable"
        );
        assert_eq!(redact("postgres://lab@db/jdbb"), "postgres://lab@db/jdbb");
        assert!(is_url("postgresql://x") && !is_url("history.sqlite"));
    }
}
