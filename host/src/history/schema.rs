//! The history database's schema and its versioned migrations.
//!
//! The version is SQLite's `PRAGMA user_version`: a new file is 0, and migration k (1-based)
//! takes it from k − 1 to k. Opening runs every migration the file lacks, each in the same
//! `BEGIN IMMEDIATE` transaction as the version bump, so two processes opening a new file at
//! once do not both migrate it (the second waits, then finds the version already up to date).
//! A file whose version is newer than this program's is refused rather than guessed at.
//!
//! A history file is jdbb's by its `PRAGMA application_id` ([`APPLICATION_ID`]), stamped in the
//! same transaction as the migrations. Before anything is written to a file, [`owner`] says
//! whose it is, reading only: jdbb's (stamped, or an older jdbb's file without the stamp whose
//! tables are exactly those of its `user_version`), a new empty database, or another program's,
//! which is refused untouched (never switched to WAL, never migrated, its `user_version` kept).
//!
//! Never edit a released migration: add one.
use rusqlite::{params, Connection, Transaction, TransactionBehavior};

/// jdbb's `PRAGMA application_id`: "JDBB" in ASCII.
pub const APPLICATION_ID: i64 = 0x4A44_4242;

/// Whose a SQLite file is (see the module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Owner {
    /// jdbb's history: stamped, or an older jdbb's by its schema.
    Jdbb,
    /// A new database: no application id, no version, nothing in it.
    Empty,
    /// Another program's: what shows it, in words.
    Other(String),
}

/// The tables (without SQLite's own) of a history file of schema version `version`.
fn tables_of(version: i64) -> &'static [&'static str] {
    if version >= 5 {
        &["compensations", "effects", "kept_files", "machines", "runs"]
    } else if version >= 4 {
        &["compensations", "effects", "machines", "runs"]
    } else {
        &["effects", "machines", "runs"]
    }
}

/// Whose the database of `conn` is, read without writing anything (in one read transaction:
/// another process may be creating the schema meanwhile).
pub fn owner(conn: &Connection) -> rusqlite::Result<Owner> {
    let tx = conn.unchecked_transaction()?;
    let conn: &Connection = &tx;
    let id: i64 = conn.query_row("PRAGMA application_id", [], |r| r.get(0))?;
    if id == APPLICATION_ID {
        return Ok(Owner::Jdbb);
    }
    if id != 0 {
        return Ok(Owner::Other(format!(
            "its application id is {id:#010x}, not jdbb's {APPLICATION_ID:#010x}"
        )));
    }
    let version: i64 = conn.query_row("PRAGMA user_version", [], |r| r.get(0))?;
    let objects: i64 = conn.query_row("SELECT COUNT(*) FROM sqlite_master", [], |r| r.get(0))?;
    if version == 0 && objects == 0 {
        return Ok(Owner::Empty);
    }
    let mut st = conn.prepare(
        "SELECT name FROM sqlite_master WHERE type = 'table' AND name NOT LIKE 'sqlite\\_%' ESCAPE '\\'
         ORDER BY name",
    )?;
    let tables = st
        .query_map([], |r| r.get::<_, String>(0))?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    let runs_columns = if tables.iter().any(|t| t == "runs") {
        let mut st = conn.prepare("SELECT name FROM pragma_table_info('runs')")?;
        let v = st
            .query_map([], |r| r.get::<_, String>(0))?
            .collect::<rusqlite::Result<Vec<_>>>()?;
        v
    } else {
        vec![]
    };
    let ours = (1..=latest()).contains(&version)
        && tables == tables_of(version)
        && ["digest", "diagnosis", "conditions", "machine_id"]
            .iter()
            .all(|c| runs_columns.iter().any(|r| r == c));
    Ok(if ours {
        Owner::Jdbb
    } else {
        Owner::Other(format!(
            "it holds {} (user_version {version}), not the tables of a jdbb history",
            if tables.is_empty() {
                "no table".to_string()
            } else {
                format!("the tables {}", tables.join(", "))
            }
        ))
    })
}

/// One migration: SQL, or code for what SQL cannot do (rewrite the stored diagnosis files).
pub enum Migration {
    Sql(&'static str),
    Code(fn(&Transaction) -> rusqlite::Result<()>),
}

/// The migrations, in order; `MIGRATIONS[k]` takes `user_version` from k to k + 1.
pub const MIGRATIONS: &[Migration] = &[
    // 1: machines, their runs (one diagnosis each, kept whole), the runs' effects.
    Migration::Sql(
        "CREATE TABLE machines (
        id INTEGER PRIMARY KEY,
        name TEXT NOT NULL UNIQUE,
        created_utc TEXT NOT NULL
    );
    CREATE TABLE runs (
        id INTEGER PRIMARY KEY,
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        date_utc TEXT NOT NULL,
        added_utc TEXT NOT NULL,
        source TEXT NOT NULL,
        digest TEXT NOT NULL,
        samples INTEGER NOT NULL,
        conditions TEXT NOT NULL,
        g_um REAL,
        h_um REAL,
        final_rms_um REAL,
        tolerance_um REAL,
        pass INTEGER,
        diagnosis TEXT NOT NULL,
        UNIQUE (machine_id, digest)
    );
    CREATE TABLE effects (
        run_id INTEGER NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
        name TEXT NOT NULL,
        value REAL,
        sigma REAL,
        unit TEXT NOT NULL,
        PRIMARY KEY (run_id, name)
    );",
    ),
    // 2: the per-machine listing by date; which jdbb added a run.
    Migration::Sql(
        "CREATE INDEX runs_by_machine_date ON runs (machine_id, date_utc);
    ALTER TABLE runs ADD COLUMN jdbb_version TEXT;",
    ),
    // 3: the signs of the trade (diagnosis format 2): see [`to_format_2`].
    Migration::Code(to_format_2),
    // 4: the compensation in force during a run (the diagnosis' `compensation.text`), and
    // compensation changes filed on their own (`jdbb history comp`).
    Migration::Sql(
        "ALTER TABLE runs ADD COLUMN compensation TEXT;
    CREATE TABLE compensations (
        id INTEGER PRIMARY KEY,
        machine_id INTEGER NOT NULL REFERENCES machines(id),
        date_utc TEXT NOT NULL,
        added_utc TEXT NOT NULL,
        text TEXT NOT NULL,
        source TEXT
    );
    CREATE INDEX compensations_by_machine_date ON compensations (machine_id, date_utc);",
    ),
    // 5: files kept with a run (`history add --keep-record`: the record and its plan),
    // gzip-compressed with their size and SHA-256 ([`crate::history::keep`]).
    Migration::Sql(
        "CREATE TABLE kept_files (
        run_id INTEGER NOT NULL REFERENCES runs(id) ON DELETE CASCADE,
        role TEXT NOT NULL,
        name TEXT NOT NULL,
        size_bytes INTEGER NOT NULL,
        sha256 TEXT NOT NULL,
        gzip BLOB NOT NULL,
        PRIMARY KEY (run_id, role)
    );",
    ),
];

/// Migration 3: runs stored before diagnosis format 2 keep their meaning under its signs.
/// - `effects`: the value of every `backlash_k` is negated (positive is now lost motion);
/// - `runs.diagnosis`: the stored file is upgraded as [`crate::report::document::upgrade`]
///   does when such a file is read (backlash and set-up offset signs, zone centres, the one G,
///   shares adding up to 1). `runs.digest` stays that of the file as it was added, so adding
///   the same old file again still adds nothing. A stored text that is not JSON is left as is.
///
/// Nothing else stored has a sign or a meaning that changed: G and H in `runs` were already
/// the minimum zone's, and σ, units and conditions have no sign.
fn to_format_2(tx: &Transaction) -> rusqlite::Result<()> {
    tx.execute(
        "UPDATE effects SET value = -value WHERE name LIKE 'backlash\\_%' ESCAPE '\\'",
        [],
    )?;
    let mut read = tx.prepare("SELECT id, diagnosis FROM runs")?;
    let rows = read
        .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?)))?
        .collect::<rusqlite::Result<Vec<_>>>()?;
    for (id, text) in rows {
        if let Some(new) = crate::report::document::upgraded_text(&text) {
            tx.execute(
                "UPDATE runs SET diagnosis = ?1 WHERE id = ?2",
                params![new, id],
            )?;
        }
    }
    Ok(())
}

/// The schema version this program writes.
pub fn latest() -> i64 {
    MIGRATIONS.len() as i64
}

/// Why a database cannot be brought to [`latest`].
#[derive(Debug)]
pub enum MigrateError {
    /// SQLite failed.
    Sql(rusqlite::Error),
    /// The file was written by a newer jdbb (its version is given).
    Newer(i64),
}

impl From<rusqlite::Error> for MigrateError {
    fn from(e: rusqlite::Error) -> Self {
        MigrateError::Sql(e)
    }
}

/// Bring `conn` to version `target` (≤ [`latest`]) with the missing migrations; returns the
/// version found before.
pub fn migrate_to(conn: &mut Connection, target: i64) -> Result<i64, MigrateError> {
    let tx = conn.transaction_with_behavior(TransactionBehavior::Immediate)?;
    let found: i64 = tx.query_row("PRAGMA user_version", [], |r| r.get(0))?;
    if found > latest() {
        return Err(MigrateError::Newer(found));
    }
    let id: i64 = tx.query_row("PRAGMA application_id", [], |r| r.get(0))?;
    if id != APPLICATION_ID {
        tx.pragma_update(None, "application_id", APPLICATION_ID)?;
    }
    for (k, migration) in MIGRATIONS
        .iter()
        .enumerate()
        .take(target as usize)
        .skip(found as usize)
    {
        match migration {
            Migration::Sql(sql) => tx.execute_batch(sql)?,
            Migration::Code(run) => run(&tx)?,
        }
        tx.pragma_update(None, "user_version", (k + 1) as i64)?;
    }
    tx.commit()?;
    Ok(found)
}
