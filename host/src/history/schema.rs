//! The history database's schema and its versioned migrations.
//!
//! The version is SQLite's `PRAGMA user_version`: a new file is 0, and migration k (1-based)
//! takes it from k − 1 to k. Opening runs every migration the file lacks, each in the same
//! `BEGIN IMMEDIATE` transaction as the version bump, so two processes opening a new file at
//! once do not both migrate it (the second waits, then finds the version already up to date).
//! A file whose version is newer than this program's is refused rather than guessed at.
//!
//! Never edit a released migration: add one.
use rusqlite::{Connection, TransactionBehavior};

/// The migrations, in order; `MIGRATIONS[k]` takes `user_version` from k to k + 1.
pub const MIGRATIONS: &[&str] = &[
    // 1: machines, their runs (one diagnosis each, kept whole), the runs' effects.
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
    // 2: the per-machine listing by date; which jdbb added a run.
    "CREATE INDEX runs_by_machine_date ON runs (machine_id, date_utc);
    ALTER TABLE runs ADD COLUMN jdbb_version TEXT;",
];

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
    for (k, sql) in MIGRATIONS
        .iter()
        .enumerate()
        .take(target as usize)
        .skip(found as usize)
    {
        tx.execute_batch(sql)?;
        tx.pragma_update(None, "user_version", (k + 1) as i64)?;
    }
    tx.commit()?;
    Ok(found)
}
