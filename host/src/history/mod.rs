//! A machine's history: its diagnoses over time in one SQLite file, and the trend of each effect.
//!
//! - One file (default `history.sqlite` in the user's data directory, e.g.
//!   `~/.local/share/jdbb/` on Linux; `--db PATH` chooses another), schema versioned by
//!   `PRAGMA user_version` with migrations in [`schema`].
//! - jdbb's file only: `PRAGMA application_id` [`schema::APPLICATION_ID`], checked before
//!   anything is written ([`schema::owner`]); another program's SQLite file (a mistyped `--db`)
//!   is refused as it is, and a `--db` that is a symbolic link is refused like any output
//!   ([`crate::fsio::check_destination`]).
//! - Bounded: `add` refuses values and σ that are not finite or beyond [`MAX_VALUE`], and machine
//!   names with control characters; names and texts print through [`printable`].
//! - Safe with two writers at once: write-ahead logging (`journal_mode = WAL`), a busy timeout
//!   (a writer waits up to [`BUSY_TIMEOUT`] for the other), and every write in one
//!   `BEGIN IMMEDIATE` transaction (the write lock is taken up front, so two writers never
//!   deadlock upgrading read locks).
//! - A run is one diagnosis file, kept whole, with its effects and conditions in columns. Adding
//!   the same file twice adds nothing (a 64-bit FNV-1a digest of its text per machine). A file
//!   of an older diagnosis format is kept upgraded to the current one
//!   ([`crate::report::document::upgrade`]), as are the runs of an older history file
//!   (migration 3 of [`schema`]): an old run keeps its meaning under today's signs.
//! - Runs are comparable when their conditions match: plane, circles (radius and height within
//!   0.5 mm), feed (within 2 %), test plan and instrument calibration (equal as JSON). The trend
//!   ([`trend`]) compares every run with the latest and says what differs.
//! - The compensation in force: a run keeps what its diagnosis states (`jdbb diagnose
//!   --compensation`, column `runs.compensation`), and `jdbb history comp` files a change on its
//!   own (table `compensations`: date, text, source; migration 4). The trend marks both
//!   ([`trend::compensation_marks`]) and fits its slope only after the last mark.
//! - Raw records kept with their runs (`history add --keep-record`, table `kept_files`, migration
//!   5): gzip-compressed and checksummed ([`keep`]), restored and re-diagnosed by `history rerun`.
//!
//! May use: [`crate::report::document`] (the diagnosis file), rusqlite, plotters.
use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{params, Connection, OptionalExtension, TransactionBehavior};
use serde::{Deserialize, Serialize};

use crate::report::document::{upgraded_text, DiagnosisDoc};
use crate::{Error, Result};

pub mod fleet;
pub mod keep;
pub mod pg;
pub mod schema;
pub mod trend;

/// How long a writer waits for another one before giving up.
pub const BUSY_TIMEOUT: Duration = Duration::from_secs(30);

/// The default history file: `history.sqlite` in the user's data directory.
pub fn default_path() -> Result<PathBuf> {
    dirs::data_dir()
        .map(|d| d.join("jdbb").join("history.sqlite"))
        .ok_or_else(|| {
            Error::Usage(
                "no user data directory is known here (HOME unset?): give --db PATH".into(),
            )
        })
}

/// The conditions of a run, which decide whether two runs can be compared.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Conditions {
    pub plane: Option<String>,
    /// (radius, height, feed) per circle, mm and mm/min.
    pub circles: Vec<(f64, f64, Option<f64>)>,
    pub plan: Option<serde_json::Value>,
    pub calibration: Option<serde_json::Value>,
}

impl Conditions {
    /// The conditions of a diagnosis file.
    pub fn of(doc: &DiagnosisDoc) -> Conditions {
        Conditions {
            plane: doc.plane.clone(),
            circles: doc
                .circles
                .iter()
                .map(|c| (c.radius_mm, c.height_mm, c.feed_mm_min))
                .collect(),
            plan: doc.plan.clone(),
            calibration: doc.calibration.clone(),
        }
    }

    /// What differs from `reference`, in words (empty: comparable).
    pub fn differences(&self, reference: &Conditions) -> Vec<String> {
        let mut out = vec![];
        if self.plane != reference.plane {
            out.push(format!(
                "plane {} (latest {})",
                self.plane.as_deref().unwrap_or("?"),
                reference.plane.as_deref().unwrap_or("?")
            ));
        }
        let radii = |c: &Conditions| {
            c.circles
                .iter()
                .map(|(r, h, _)| format!("r {r:.1} mm at {h:.1} mm"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let same_circles = self.circles.len() == reference.circles.len()
            && self
                .circles
                .iter()
                .zip(&reference.circles)
                .all(|(a, b)| (a.0 - b.0).abs() <= 0.5 && (a.1 - b.1).abs() <= 0.5);
        if !same_circles {
            out.push(format!(
                "circles {} (latest {})",
                radii(self),
                radii(reference)
            ));
        } else {
            for (a, b) in self.circles.iter().zip(&reference.circles) {
                if let (Some(fa), Some(fb)) = (a.2, b.2) {
                    if (fa - fb).abs() > 0.02 * fb.abs() {
                        out.push(format!("feed {fa:.0} mm/min (latest {fb:.0})"));
                        break;
                    }
                }
            }
        }
        if self.plan != reference.plan {
            out.push(
                match (&self.plan, &reference.plan) {
                    (None, _) => "no plan recorded (the latest has one)",
                    (_, None) => "a plan recorded (the latest has none)",
                    _ => "another test plan",
                }
                .into(),
            );
        }
        if self.calibration != reference.calibration {
            out.push(
                match (&self.calibration, &reference.calibration) {
                    (None, _) => "no instrument calibration recorded (the latest has one)",
                    (_, None) => "an instrument calibration recorded (the latest has none)",
                    _ => "another instrument calibration",
                }
                .into(),
            );
        }
        out
    }
}

/// One effect of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct EffectRow {
    pub name: String,
    pub value: Option<f64>,
    pub sigma: Option<f64>,
    pub unit: String,
}

/// One run of a machine as the history holds it.
#[derive(Debug, Clone)]
pub struct Run {
    pub id: i64,
    pub date_utc: String,
    pub added_utc: String,
    pub source: String,
    pub samples: i64,
    pub conditions: Conditions,
    pub g_um: Option<f64>,
    pub h_um: Option<f64>,
    pub final_rms_um: Option<f64>,
    pub tolerance_um: Option<f64>,
    pub pass: Option<bool>,
    /// Machine effects (not the set-up), in the diagnosis' order.
    pub effects: Vec<EffectRow>,
    /// The compensation in force during the run, as the diagnosis says (`jdbb diagnose
    /// --compensation`); None if it does not.
    pub compensation: Option<String>,
}

/// A change of a machine's compensation filed with `jdbb history comp`: from `date_utc` on,
/// `text` is in force.
#[derive(Debug, Clone, PartialEq)]
pub struct CompensationEvent {
    pub id: i64,
    pub date_utc: String,
    pub text: String,
    /// The file the text came from, if any.
    pub source: Option<String>,
}

/// The outcome of [`History::add`].
#[derive(Debug, Clone, PartialEq)]
pub struct Added {
    pub run_id: i64,
    /// False if this diagnosis was already in the history (nothing was added).
    pub new: bool,
    /// The date the run is filed under.
    pub date_utc: String,
    /// Whether that date came from the file (false: the time of adding, or `--date`).
    pub date_from_file: bool,
    /// How many of the run's [`NewRun::kept`] files were kept now (a run already filed keeps
    /// the files it has).
    pub kept: usize,
}

/// A history back end (a SQLite file, a PostgreSQL server): what each `jdbb history` command
/// needs, so that each command is written once.
pub trait Store {
    /// Where the history is, for messages: a path, or a URL with its password redacted.
    fn location(&self) -> String;
    /// File `run` in one transaction; a run already filed (same machine, same digest) is not
    /// filed again.
    fn store_run(&mut self, run: &NewRun) -> Result<Added>;
    /// The machines and their number of runs, by name.
    fn machines(&mut self) -> Result<Vec<(String, i64)>>;
    /// The runs of `machine`, oldest first, each run's effects in its diagnosis' order; an
    /// unknown machine is a usage error naming the known ones.
    fn runs(&mut self, machine: &str) -> Result<Vec<Run>>;
    /// The compensation changes filed for `machine`, oldest first.
    fn compensations(&mut self, machine: &str) -> Result<Vec<CompensationEvent>>;
    /// File a compensation change of `machine`: from `date_utc` on, `text` (read from
    /// `source`, if a file) is in force. Returns the event's id.
    fn add_compensation(
        &mut self,
        machine: &str,
        date_utc: &str,
        text: &str,
        source: Option<&str>,
    ) -> Result<i64>;
    /// Take run `run_id` of `machine` out of the history, with its kept files; returns it as
    /// it was.
    fn remove_run(&mut self, machine: &str, run_id: i64) -> Result<Run>;
    /// File run `run_id` of `machine` under `date_utc` instead; returns the date it had.
    fn set_date(&mut self, machine: &str, run_id: i64, date_utc: &str) -> Result<String>;
    /// Run `run_id` of `machine` with its diagnosis file and kept files (none: it kept no
    /// record), for `history rerun`.
    fn kept(&mut self, machine: &str, run_id: i64) -> Result<keep::Kept>;

    /// Every run as filed (its digest, date and diagnosis as they are) and every compensation
    /// change with its machine's name: what `history migrate` copies and checks.
    fn export(&mut self) -> Result<Export>;

    /// File the diagnosis `doc` (whose file text is `text`, read from `source`) under
    /// `machine`, dated `date_utc` if given, else by the file's date, else now.
    fn add(
        &mut self,
        machine: &str,
        doc: &DiagnosisDoc,
        text: &str,
        source: &str,
        date_utc: Option<String>,
    ) -> Result<Added> {
        self.store_run(&NewRun::of(machine, doc, text, source, date_utc)?)
    }
}

/// A whole history as [`Store::export`] gives it.
#[derive(Debug, Clone, Default)]
pub struct Export {
    pub runs: Vec<NewRun>,
    /// (machine, change), oldest first per machine.
    pub compensations: Vec<(String, CompensationEvent)>,
}

/// The checksum of a filed run: a digest of everything the history holds of it (machine,
/// date, source, file digest, conditions, figures, the diagnosis file, the effects), compared
/// between two histories by `history migrate`.
pub fn checksum(run: &NewRun) -> String {
    digest(format!("{run:?}").as_bytes())
}

/// What [`migrate`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct Migrated {
    pub runs: usize,
    pub machines: usize,
    /// Runs the target did not hold before.
    pub new_runs: usize,
    pub compensations: usize,
    pub new_compensations: usize,
}

/// Copy every run and compensation change of `from` into `to` (runs already there, by machine
/// and file digest, and changes already there, by machine, date and text, are not copied
/// again: safe to run twice), then check that `to` holds every run of `from` with the same
/// checksum ([`checksum`]).
pub fn migrate(from: &mut dyn Store, to: &mut dyn Store) -> Result<Migrated> {
    let source = from.export()?;
    let mut new_runs = 0;
    for run in &source.runs {
        new_runs += usize::from(to.store_run(run)?.new);
    }
    let mut new_compensations = 0;
    for (machine, c) in &source.compensations {
        let there = to.compensations(machine)?;
        if !there
            .iter()
            .any(|t| t.date_utc == c.date_utc && t.text == c.text)
        {
            to.add_compensation(machine, &c.date_utc, &c.text, c.source.as_deref())?;
            new_compensations += 1;
        }
    }
    let target = to.export()?;
    let mut missing = vec![];
    for run in &source.runs {
        let same = target
            .runs
            .iter()
            .find(|t| t.machine == run.machine && t.digest == run.digest);
        match same {
            Some(t) if checksum(t) == checksum(run) => {}
            Some(_) => missing.push(format!(
                "{} {} ({}): differs",
                printable(&run.machine),
                run.date_utc,
                printable(&run.source)
            )),
            None => missing.push(format!(
                "{} {} ({}): missing",
                printable(&run.machine),
                run.date_utc,
                printable(&run.source)
            )),
        }
    }
    if !missing.is_empty() {
        return Err(Error::Usage(format!(
            "{} holds {} of the {} runs of {} unchanged; not so: {}. A run filed there before with another date or content keeps it: correct it with `history edit` or `history remove` there, then migrate again",
            to.location(),
            source.runs.len() - missing.len(),
            source.runs.len(),
            from.location(),
            missing.join("; ")
        )));
    }
    let mut machines: Vec<&str> = source.runs.iter().map(|r| r.machine.as_str()).collect();
    machines.sort_unstable();
    machines.dedup();
    Ok(Migrated {
        runs: source.runs.len(),
        machines: machines.len(),
        new_runs,
        compensations: source.compensations.len(),
        new_compensations,
    })
}

/// Refuse an empty compensation text.
fn check_compensation_text(text: &str) -> Result<()> {
    if text.trim().is_empty() {
        return Err(Error::Usage(
            "the compensation is empty: give what was set (--text TEXT or --file FILE)".into(),
        ));
    }
    Ok(())
}

/// Where the history is: `--db` if given, else `JDBB_HISTORY_DB`, else the default file.
/// A value starting `postgres://` or `postgresql://` is a server's URL, anything else a file.
pub fn location(db: Option<&std::ffi::OsStr>) -> Result<std::ffi::OsString> {
    match db
        .map(ToOwned::to_owned)
        .or_else(|| std::env::var_os("JDBB_HISTORY_DB"))
    {
        Some(v) if !v.is_empty() => Ok(v),
        _ => Ok(default_path()?.into_os_string()),
    }
}

/// Open the history at `db` ([`location`]): a server's database, or a file. `existing`: for
/// reading (it must exist, and a file the user may only read is opened read-only).
pub fn open(db: &std::ffi::OsStr, existing: bool) -> Result<Box<dyn Store>> {
    if let Some(url) = db.to_str().filter(|s| pg::is_url(s)) {
        return Ok(Box::new(pg::PgHistory::open(url, existing)?));
    }
    let path = Path::new(db);
    Ok(Box::new(if existing {
        History::open_existing(path)?
    } else {
        History::open(path)?
    }))
}

impl Store for History {
    fn location(&self) -> String {
        self.path.display().to_string()
    }
    fn store_run(&mut self, run: &NewRun) -> Result<Added> {
        self.file_run(run)
    }
    fn machines(&mut self) -> Result<Vec<(String, i64)>> {
        History::machines(self)
    }
    fn runs(&mut self, machine: &str) -> Result<Vec<Run>> {
        History::runs(self, machine)
    }
    fn compensations(&mut self, machine: &str) -> Result<Vec<CompensationEvent>> {
        History::compensations(self, machine)
    }
    fn add_compensation(
        &mut self,
        machine: &str,
        date_utc: &str,
        text: &str,
        source: Option<&str>,
    ) -> Result<i64> {
        History::add_compensation(self, machine, date_utc, text, source)
    }
    fn remove_run(&mut self, machine: &str, run_id: i64) -> Result<Run> {
        History::remove_run(self, machine, run_id)
    }
    fn set_date(&mut self, machine: &str, run_id: i64, date_utc: &str) -> Result<String> {
        History::set_date(self, machine, run_id, date_utc)
    }
    fn kept(&mut self, machine: &str, run_id: i64) -> Result<keep::Kept> {
        let run = self.run_of(machine, run_id)?;
        let diagnosis: String = self
            .conn
            .query_row(
                "SELECT diagnosis FROM runs WHERE id = ?1",
                params![run_id],
                |r| r.get(0),
            )
            .map_err(self.db())?;
        Ok(keep::Kept {
            run,
            diagnosis,
            files: self.kept_files(run_id)?,
        })
    }
    fn export(&mut self) -> Result<Export> {
        let mut out = Export::default();
        // Runs in the order they were filed (by id), so that a new history numbers them alike.
        let mut filed: Vec<(i64, NewRun)> = vec![];
        for (machine, _) in History::machines(self)? {
            let id = self.machine_id(&machine)?;
            let mut st = self
                .conn
                .prepare(
                    "SELECT id, date_utc, source, digest, samples, conditions, g_um, h_um,
                            final_rms_um, tolerance_um, pass, diagnosis, jdbb_version, compensation
                     FROM runs WHERE machine_id = ?1 ORDER BY date_utc, id",
                )
                .map_err(self.db())?;
            let rows = st
                .query_map(params![id], |r| {
                    Ok((
                        r.get::<_, i64>(0)?,
                        NewRun {
                            machine: machine.clone(),
                            date_utc: r.get(1)?,
                            date_from_file: false,
                            source: r.get(2)?,
                            digest: r.get(3)?,
                            samples: r.get(4)?,
                            conditions: r.get(5)?,
                            g_um: r.get(6)?,
                            h_um: r.get(7)?,
                            final_rms_um: r.get(8)?,
                            tolerance_um: r.get(9)?,
                            pass: r.get(10)?,
                            diagnosis: r.get(11)?,
                            jdbb_version: r.get(12)?,
                            compensation: r.get(13)?,
                            effects: vec![],
                            kept: vec![],
                        },
                    ))
                })
                .map_err(self.db())?
                .collect::<rusqlite::Result<Vec<_>>>()
                .map_err(self.db())?;
            let runs = History::runs(self, &machine)?;
            for (run_id, mut run) in rows {
                run.effects = runs
                    .iter()
                    .find(|r| r.id == run_id)
                    .map(|r| r.effects.clone())
                    .unwrap_or_default();
                run.kept = self.kept_files(run_id)?;
                filed.push((run_id, run));
            }
            for c in History::compensations(self, &machine)? {
                out.compensations.push((machine.clone(), c));
            }
        }
        filed.sort_by_key(|(id, _)| *id);
        out.runs = filed.into_iter().map(|(_, r)| r).collect();
        Ok(out)
    }
}

/// An open history file.
pub struct History {
    conn: Connection,
    path: PathBuf,
}

/// The SQLite URI of the file `path` (`file:` with `?`, `#`, `%` escaped), read-only, and
/// `immutable` if asked.
fn file_uri(path: &Path, immutable: bool) -> String {
    let mut uri = String::from("file:");
    for c in path.to_string_lossy().chars() {
        match c {
            '?' | '#' | '%' => uri.push_str(&format!("%{:02X}", c as u32)),
            c => uri.push(c),
        }
    }
    uri.push_str("?mode=ro");
    if immutable {
        uri.push_str("&immutable=1");
    }
    uri
}

/// Largest size of a value or σ filed in a history, in its own unit (µm, µm/m, µm/m², ms,
/// µm/min, µm/(mm/s)): 10⁶ is 1 m of error, a scale of 100 %, a lag of 1000 s, which no machine
/// has. A larger number is a damaged or hand-edited file, and would leave the trend nothing to
/// fit or plot.
pub const MAX_VALUE: f64 = 1e6;

/// Refuse a diagnosis with a value or σ that is not finite or beyond [`MAX_VALUE`] (`source`
/// names the file).
fn check_values(doc: &DiagnosisDoc, source: &str) -> Result<()> {
    let mut values: Vec<(String, Option<f64>, &str)> = vec![];
    for (e, _) in doc.machine_effects() {
        values.push((e.name.clone(), e.value, e.unit.as_str()));
        values.push((format!("the σ of {}", e.name), e.sigma, e.unit.as_str()));
    }
    values.push(("G".into(), doc.g_um(), "um"));
    values.push(("H".into(), doc.h_um(), "um"));
    values.push(("the residual RMS".into(), doc.final_fit.rms_um, "um"));
    values.push((
        "the tolerance".into(),
        doc.tolerance.as_ref().map(|t| t.g_um),
        "um",
    ));
    for (what, value, unit) in values {
        let Some(v) = value else { continue };
        if !(v.is_finite() && v.abs() <= MAX_VALUE) || (what.starts_with("the σ") && v < 0.0) {
            return Err(Error::Input {
                location: source.to_string(),
                message: format!(
                    "{} = {v:e} {}: a value filed in the history is finite and at most {MAX_VALUE:e} in size (a σ not negative); no machine has this, so the file is damaged or hand-edited: nothing was added",
                    printable(&what),
                    crate::units::human(unit)
                ),
            });
        }
    }
    Ok(())
}

/// `text` with its control characters (line breaks, tabs, escapes) shown escaped (`\n`,
/// `\u{1b}`), so that a name or a text from the history prints as one plain line.
pub fn printable(text: &str) -> std::borrow::Cow<'_, str> {
    if text.chars().any(char::is_control) {
        text.chars()
            .map(|c| {
                if c.is_control() {
                    c.escape_default().to_string()
                } else {
                    c.to_string()
                }
            })
            .collect::<String>()
            .into()
    } else {
        text.into()
    }
}

/// 64-bit FNV-1a of `bytes`, as 16 hex digits: the identity of a diagnosis file's text.
pub fn digest(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= u64::from(*b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// A diagnosis checked and made ready to file: what every back end stores for one run.
#[derive(Debug, Clone, PartialEq)]
pub struct NewRun {
    pub machine: String,
    pub date_utc: String,
    /// Whether `date_utc` came from the file (false: the time of adding, or `--date`).
    pub date_from_file: bool,
    pub source: String,
    /// [`digest`] of the file's text as it was added: the run's identity per machine.
    pub digest: String,
    pub samples: i64,
    /// [`Conditions`] as JSON.
    pub conditions: String,
    pub g_um: Option<f64>,
    pub h_um: Option<f64>,
    pub final_rms_um: Option<f64>,
    pub tolerance_um: Option<f64>,
    pub pass: Option<bool>,
    /// The diagnosis file's text, upgraded to the current format.
    pub diagnosis: String,
    /// The jdbb that filed it (none: a run of the first history files).
    pub jdbb_version: Option<String>,
    pub compensation: Option<String>,
    pub effects: Vec<EffectRow>,
    /// Files kept with the run (`history add --keep-record`): the record, and its plan.
    pub kept: Vec<keep::KeptFile>,
}

impl NewRun {
    /// The run of the diagnosis `doc` (whose file text is `text`, read from `source`) under
    /// `machine`, dated `date_utc` if given, else by the file's date, else now; a machine name
    /// that is empty or has control characters, and a value no machine has, are refused.
    pub fn of(
        machine: &str,
        doc: &DiagnosisDoc,
        text: &str,
        source: &str,
        date_utc: Option<String>,
    ) -> Result<NewRun> {
        let machine = machine.trim();
        if machine.is_empty() {
            return Err(Error::Usage("--machine: give the machine a name".into()));
        }
        if machine.chars().any(char::is_control) {
            return Err(Error::Usage(format!(
                "--machine `{}`: a machine name is one line of text, without control characters (line breaks, tabs, escapes)",
                printable(machine)
            )));
        }
        check_values(doc, source)?;
        let (date, from_file) = match (date_utc, &doc.date_utc) {
            (Some(d), _) => (d, false),
            (None, Some(d)) => (
                crate::dates::parse_date(d).map_err(|e| Error::Input {
                    location: source.to_string(),
                    message: format!("date_utc: {e}"),
                })?,
                true,
            ),
            (None, None) => (crate::dates::now_utc(), false),
        };
        Ok(NewRun {
            machine: machine.to_string(),
            date_utc: date,
            date_from_file: from_file,
            source: source.to_string(),
            digest: digest(text.as_bytes()),
            samples: doc.samples as i64,
            conditions: serde_json::to_string(&Conditions::of(doc))
                .expect("conditions are plain data"),
            g_um: doc.g_um(),
            h_um: doc.h_um(),
            final_rms_um: doc.final_fit.rms_um,
            tolerance_um: doc.tolerance.as_ref().map(|t| t.g_um),
            pass: doc.tolerance.as_ref().map(|t| t.pass),
            diagnosis: upgraded_text(text).unwrap_or_else(|| text.to_string()),
            jdbb_version: Some(env!("CARGO_PKG_VERSION").to_string()),
            compensation: doc.compensation.as_ref().map(|c| c.text.clone()),
            effects: effect_rows(doc),
            kept: vec![],
        })
    }
}

/// The machine effects of `doc` as the history files them, in the diagnosis' order.
pub fn effect_rows(doc: &DiagnosisDoc) -> Vec<EffectRow> {
    doc.machine_effects()
        .map(|(e, _)| EffectRow {
            name: e.name.clone(),
            value: e.value,
            sigma: e.sigma,
            unit: e.unit.clone(),
        })
        .collect()
}

/// The error for a machine the history at `location` does not hold, naming the `known` ones.
pub fn unknown_machine(machine: &str, location: &str, known: &[(String, i64)]) -> Error {
    let known: Vec<String> = known
        .iter()
        .map(|(n, _)| printable(n).into_owned())
        .collect();
    Error::Usage(format!(
        "no machine `{}` in the history {location}; {}",
        printable(machine),
        if known.is_empty() {
            "it is empty: add a diagnosis with `jdbb history add --machine NAME --diagnosis DIAG.json`".to_string()
        } else {
            format!("known: {}", known.join(", "))
        }
    ))
}

/// Run `run_id` among `runs` (those of `machine` in the history at `location`); another id is
/// a usage error naming the machine's runs.
pub fn find_run(runs: Vec<Run>, machine: &str, run_id: i64, location: &str) -> Result<Run> {
    let ids: Vec<String> = runs.iter().map(|r| r.id.to_string()).collect();
    runs.into_iter().find(|r| r.id == run_id).ok_or_else(|| {
        Error::Usage(format!(
            "no run {run_id} of machine `{}` in the history {location}; its runs: {} (see `jdbb history list --machine NAME`)",
            printable(machine),
            if ids.is_empty() { "none".to_string() } else { ids.join(", ") }
        ))
    })
}

/// Every machine effect of `runs` (name, unit) in the one order the list, the trend and the
/// fleet use: by first appearance, oldest run first, each run in its diagnosis' order.
pub fn effect_order(runs: &[Run]) -> Vec<(String, String)> {
    let mut names: Vec<(String, String)> = vec![];
    for r in runs {
        for e in &r.effects {
            if !names.iter().any(|(n, _)| *n == e.name) {
                names.push((e.name.clone(), e.unit.clone()));
            }
        }
    }
    names
}

impl History {
    /// Open (or create) the history at `path`, creating its directory, and bring its schema up
    /// to date (see the module docs).
    pub fn open(path: &Path) -> Result<History> {
        Self::open_at(path, schema::latest())
    }

    /// Open the history at `path` for reading (`history list`, `trend`): it must exist (a
    /// mistyped `--db` is an error, not a new empty history), and a file the user may only read
    /// is opened read-only. A file of an older schema is brought up to date if it may be
    /// written.
    pub fn open_existing(path: &Path) -> Result<History> {
        crate::fsio::check_destination(path, true)?;
        match std::fs::metadata(path) {
            Ok(m) if m.is_file() => {}
            Ok(_) => {
                return Err(Error::Usage(format!(
                    "history database {} is not a file: check --db",
                    path.display()
                )))
            }
            Err(_) => {
                return Err(Error::Usage(format!(
                    "no history database at {}: check --db (`jdbb history add` creates one)",
                    path.display()
                )))
            }
        }
        let db = |source| Error::Database {
            path: path.to_path_buf(),
            source,
        };
        let read_only = |immutable: bool| -> rusqlite::Result<(Connection, i64)> {
            use rusqlite::OpenFlags as F;
            let flags = F::SQLITE_OPEN_READ_ONLY | F::SQLITE_OPEN_NO_MUTEX | F::SQLITE_OPEN_URI;
            let conn = Connection::open_with_flags(file_uri(path, immutable), flags)?;
            conn.busy_timeout(BUSY_TIMEOUT)?;
            let version: i64 = conn.query_row("PRAGMA user_version", [], |r| r.get(0))?;
            Ok((conn, version))
        };
        // A WAL file in a directory the user may not write has no shared-memory file to read
        // through: then it is read as immutable (nobody who may write it is this user).
        let (conn, version) = read_only(false).or_else(|_| read_only(true)).map_err(db)?;
        Self::check_owner(&conn, path)?;
        if version == schema::latest() {
            return Ok(History {
                conn,
                path: path.to_path_buf(),
            });
        }
        drop(conn);
        Self::open(path)
    }

    /// [`History::open`] migrating only to version `target` (for the migration tests).
    pub fn open_at(path: &Path, target: i64) -> Result<History> {
        // A history is a file jdbb writes: like every output, never through a symbolic link
        // (which would make a database of whatever it points at), never a device.
        crate::fsio::check_destination(path, true)?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| Error::File {
                action: "cannot create the directory of",
                path: path.to_path_buf(),
                source,
            })?;
        }
        let db = |source| Error::Database {
            path: path.to_path_buf(),
            source,
        };
        let mut conn = Connection::open(path).map_err(db)?;
        conn.busy_timeout(BUSY_TIMEOUT).map_err(db)?;
        // Whose the file is, before anything is written to it (WAL, migrations, the stamp).
        Self::check_owner(&conn, path)?;
        // journal_mode returns the mode in force; anything but wal means the file system
        // cannot share memory between processes (then SQLite's default locking still serialises).
        // Switching a new file to WAL while another process does the same can be refused as busy
        // without the busy handler being asked: retry, within the same timeout.
        let started = std::time::Instant::now();
        let _mode: String = loop {
            match conn.query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0)) {
                Err(rusqlite::Error::SqliteFailure(e, _))
                    if e.code == rusqlite::ErrorCode::DatabaseBusy
                        && started.elapsed() < BUSY_TIMEOUT =>
                {
                    std::thread::sleep(Duration::from_millis(5));
                }
                other => break other.map_err(db)?,
            }
        };
        conn.pragma_update(None, "foreign_keys", true).map_err(db)?;
        match schema::migrate_to(&mut conn, target) {
            Ok(_) => {}
            Err(schema::MigrateError::Sql(e)) => return Err(db(e)),
            Err(schema::MigrateError::Newer(v)) => {
                return Err(Error::Usage(format!(
                    "history database {}: schema version {v} was written by a newer jdbb (this one knows {}); update jdbb",
                    path.display(),
                    schema::latest()
                )))
            }
        }
        Ok(History {
            conn,
            path: path.to_path_buf(),
        })
    }

    /// Refuse the file of `conn` (at `path`) unless it is jdbb's history or a new empty
    /// database ([`schema::owner`]).
    fn check_owner(conn: &Connection, path: &Path) -> Result<()> {
        match schema::owner(conn).map_err(|source| Error::Database {
            path: path.to_path_buf(),
            source,
        })? {
            schema::Owner::Jdbb | schema::Owner::Empty => Ok(()),
            schema::Owner::Other(why) => Err(Error::Usage(format!(
                "{} is not a jdbb history database ({why}): it is another program's file, left as it was; check --db",
                path.display()
            ))),
        }
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn db(&self) -> impl Fn(rusqlite::Error) -> Error + '_ {
        move |source| Error::Database {
            path: self.path.clone(),
            source,
        }
    }

    /// The schema version of the open file.
    pub fn version(&self) -> Result<i64> {
        self.conn
            .query_row("PRAGMA user_version", [], |r| r.get(0))
            .map_err(self.db())
    }

    /// File `run` (checked by [`NewRun::of`]) in one transaction; a run already filed (same
    /// machine, same digest) is not filed again.
    fn file_run(&mut self, run: &NewRun) -> Result<Added> {
        let path = self.path.clone();
        let db = move |source| Error::Database {
            path: path.clone(),
            source,
        };
        let now = crate::dates::now_utc();
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(&db)?;
        tx.execute(
            "INSERT OR IGNORE INTO machines (name, created_utc) VALUES (?1, ?2)",
            params![run.machine, now],
        )
        .map_err(&db)?;
        let machine_id: i64 = tx
            .query_row(
                "SELECT id FROM machines WHERE name = ?1",
                params![run.machine],
                |r| r.get(0),
            )
            .map_err(&db)?;
        if let Some((id, d)) = tx
            .query_row(
                "SELECT id, date_utc FROM runs WHERE machine_id = ?1 AND digest = ?2",
                params![machine_id, run.digest],
                |r| Ok((r.get::<_, i64>(0)?, r.get::<_, String>(1)?)),
            )
            .optional()
            .map_err(&db)?
        {
            // Filed before: it keeps the files it has, and gains those it lacks.
            let kept = Self::keep_files(&tx, id, &run.kept).map_err(&db)?;
            tx.commit().map_err(&db)?;
            return Ok(Added {
                run_id: id,
                new: false,
                date_utc: d,
                date_from_file: run.date_from_file,
                kept,
            });
        }
        tx.execute(
            "INSERT INTO runs (machine_id, date_utc, added_utc, source, digest, samples, conditions,
                 g_um, h_um, final_rms_um, tolerance_um, pass, diagnosis, jdbb_version, compensation)
             VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15)",
            params![
                machine_id,
                run.date_utc,
                now,
                run.source,
                run.digest,
                run.samples,
                run.conditions,
                run.g_um,
                run.h_um,
                run.final_rms_um,
                run.tolerance_um,
                run.pass,
                run.diagnosis,
                run.jdbb_version,
                run.compensation,
            ],
        )
        .map_err(&db)?;
        let run_id = tx.last_insert_rowid();
        for e in &run.effects {
            tx.execute(
                "INSERT INTO effects (run_id, name, value, sigma, unit) VALUES (?1, ?2, ?3, ?4, ?5)",
                params![run_id, e.name, e.value, e.sigma, e.unit],
            )
            .map_err(&db)?;
        }
        let kept = Self::keep_files(&tx, run_id, &run.kept).map_err(&db)?;
        tx.commit().map_err(&db)?;
        Ok(Added {
            run_id,
            new: true,
            date_utc: run.date_utc.clone(),
            date_from_file: run.date_from_file,
            kept,
        })
    }

    /// Keep `files` with run `run_id` in `tx`, but not a role the run already keeps; returns
    /// how many were kept.
    fn keep_files(
        tx: &rusqlite::Transaction,
        run_id: i64,
        files: &[keep::KeptFile],
    ) -> rusqlite::Result<usize> {
        let mut n = 0;
        for f in files {
            n += tx.execute(
                "INSERT OR IGNORE INTO kept_files (run_id, role, name, size_bytes, sha256, gzip)
                 VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
                params![run_id, f.role, f.name, f.size_bytes, f.sha256, f.gzip],
            )?;
        }
        Ok(n)
    }

    /// Take run `run_id` of `machine` out of the history (with its effects); returns it as it
    /// was, so that what was removed can be said (and added again from its source file).
    pub fn remove_run(&mut self, machine: &str, run_id: i64) -> Result<Run> {
        let run = self.run_of(machine, run_id)?;
        let path = self.path.clone();
        let db = move |source| Error::Database {
            path: path.clone(),
            source,
        };
        let tx = self
            .conn
            .transaction_with_behavior(TransactionBehavior::Immediate)
            .map_err(&db)?;
        tx.execute("DELETE FROM effects WHERE run_id = ?1", params![run_id])
            .map_err(&db)?;
        tx.execute("DELETE FROM kept_files WHERE run_id = ?1", params![run_id])
            .map_err(&db)?;
        tx.execute("DELETE FROM runs WHERE id = ?1", params![run_id])
            .map_err(&db)?;
        tx.commit().map_err(&db)?;
        Ok(run)
    }

    /// File run `run_id` of `machine` under `date_utc` instead (a run added with the wrong
    /// date); returns the date it had.
    pub fn set_date(&mut self, machine: &str, run_id: i64, date_utc: &str) -> Result<String> {
        let run = self.run_of(machine, run_id)?;
        self.conn
            .execute(
                "UPDATE runs SET date_utc = ?1 WHERE id = ?2",
                params![date_utc, run_id],
            )
            .map_err(self.db())?;
        Ok(run.date_utc)
    }

    /// The files run `run_id` keeps, the record first.
    fn kept_files(&self, run_id: i64) -> Result<Vec<keep::KeptFile>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT role, name, size_bytes, sha256, gzip FROM kept_files WHERE run_id = ?1
                 ORDER BY role = 'plan', role",
            )
            .map_err(self.db())?;
        let files = st
            .query_map(params![run_id], |r| {
                Ok(keep::KeptFile {
                    role: r.get(0)?,
                    name: r.get(1)?,
                    size_bytes: r.get(2)?,
                    sha256: r.get(3)?,
                    gzip: r.get(4)?,
                })
            })
            .map_err(self.db())?
            .collect::<rusqlite::Result<Vec<_>>>()
            .map_err(self.db())?;
        Ok(files)
    }

    /// Run `run_id` of `machine`; a run of another machine or none is a usage error.
    fn run_of(&self, machine: &str, run_id: i64) -> Result<Run> {
        let runs = self.runs(machine)?;
        find_run(runs, machine, run_id, &self.path.display().to_string())
    }

    /// The machines and their number of runs, by name.
    pub fn machines(&self) -> Result<Vec<(String, i64)>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT m.name, COUNT(r.id) FROM machines m LEFT JOIN runs r ON r.machine_id = m.id
                 GROUP BY m.id ORDER BY m.name",
            )
            .map_err(self.db())?;
        let rows = st
            .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
            .map_err(self.db())?;
        rows.collect::<rusqlite::Result<Vec<_>>>()
            .map_err(self.db())
    }

    /// The runs of `machine`, oldest first; an unknown machine is a usage error naming the
    /// known ones.
    pub fn runs(&self, machine: &str) -> Result<Vec<Run>> {
        let machine_id = self.machine_id(machine)?;
        self.runs_of(machine_id)
    }

    /// The id of `machine`; an unknown machine is a usage error naming the known ones.
    fn machine_id(&self, machine: &str) -> Result<i64> {
        let id: Option<i64> = self
            .conn
            .query_row(
                "SELECT id FROM machines WHERE name = ?1",
                params![machine],
                |r| r.get(0),
            )
            .optional()
            .map_err(self.db())?;
        let Some(machine_id) = id else {
            return Err(unknown_machine(
                machine,
                &self.path.display().to_string(),
                &self.machines()?,
            ));
        };
        Ok(machine_id)
    }

    /// File a compensation change of `machine` (which must have runs): from `date_utc` on,
    /// `text` (read from `source`, if a file) is in force. Returns the event's id.
    pub fn add_compensation(
        &mut self,
        machine: &str,
        date_utc: &str,
        text: &str,
        source: Option<&str>,
    ) -> Result<i64> {
        check_compensation_text(text)?;
        let machine_id = self.machine_id(machine)?;
        self.conn
            .execute(
                "INSERT INTO compensations (machine_id, date_utc, added_utc, text, source)
                 VALUES (?1, ?2, ?3, ?4, ?5)",
                params![machine_id, date_utc, crate::dates::now_utc(), text, source],
            )
            .map_err(self.db())?;
        Ok(self.conn.last_insert_rowid())
    }

    /// The compensation changes filed for `machine`, oldest first.
    pub fn compensations(&self, machine: &str) -> Result<Vec<CompensationEvent>> {
        let machine_id = self.machine_id(machine)?;
        let mut st = self
            .conn
            .prepare(
                "SELECT id, date_utc, text, source FROM compensations WHERE machine_id = ?1
                 ORDER BY date_utc, id",
            )
            .map_err(self.db())?;
        let rows = st
            .query_map(params![machine_id], |r| {
                Ok(CompensationEvent {
                    id: r.get(0)?,
                    date_utc: r.get(1)?,
                    text: r.get(2)?,
                    source: r.get(3)?,
                })
            })
            .map_err(self.db())?;
        rows.collect::<rusqlite::Result<Vec<_>>>()
            .map_err(self.db())
    }

    /// The runs of the machine `machine_id`, oldest first.
    fn runs_of(&self, machine_id: i64) -> Result<Vec<Run>> {
        let mut st = self
            .conn
            .prepare(
                "SELECT id, date_utc, added_utc, source, samples, conditions, g_um, h_um,
                        final_rms_um, tolerance_um, pass, compensation
                 FROM runs WHERE machine_id = ?1 ORDER BY date_utc, id",
            )
            .map_err(self.db())?;
        let rows = st
            .query_map(params![machine_id], |r| {
                let conditions: String = r.get(5)?;
                Ok(Run {
                    id: r.get(0)?,
                    date_utc: r.get(1)?,
                    added_utc: r.get(2)?,
                    source: r.get(3)?,
                    samples: r.get(4)?,
                    conditions: serde_json::from_str(&conditions).unwrap_or_default(),
                    g_um: r.get(6)?,
                    h_um: r.get(7)?,
                    final_rms_um: r.get(8)?,
                    tolerance_um: r.get(9)?,
                    pass: r.get(10)?,
                    effects: vec![],
                    compensation: r.get(11)?,
                })
            })
            .map_err(self.db())?;
        let mut runs = rows
            .collect::<rusqlite::Result<Vec<_>>>()
            .map_err(self.db())?;
        let mut st = self
            .conn
            .prepare(
                "SELECT name, value, sigma, unit FROM effects WHERE run_id = ?1 ORDER BY rowid",
            )
            .map_err(self.db())?;
        for run in &mut runs {
            let rows = st
                .query_map(params![run.id], |r| {
                    Ok(EffectRow {
                        name: r.get(0)?,
                        value: r.get(1)?,
                        sigma: r.get(2)?,
                        unit: r.get(3)?,
                    })
                })
                .map_err(self.db())?;
            run.effects = rows
                .collect::<rusqlite::Result<Vec<_>>>()
                .map_err(self.db())?;
        }
        Ok(runs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc(
        effect_value: f64,
        radius: f64,
        feed: f64,
        date: Option<&str>,
    ) -> (DiagnosisDoc, String) {
        let text = serde_json::json!({
            "samples": 1000,
            "format": 2,
            "effects": [
                {"name": "setup_offset", "value": 1.0, "unit": "um", "sigma": 0.1, "setup": true,
                 "params": {"x_um": 1.0, "y_um": 0.0, "z_um": 0.0}},
                {"name": "backlash_x", "value": effect_value, "unit": "um", "sigma": 0.01,
                 "params": {"b_um": effect_value}}
            ],
            "final": {"rms_um": 0.3},
            "plane": "xy",
            "circles": [{"radius_mm": radius, "height_mm": 0.0, "feed_mm_min": feed, "samples": 500,
                          "g_um": 5.0, "h_um": 3.0}],
            "date_utc": date,
        })
        .to_string();
        (
            DiagnosisDoc::parse(Path::new("t.json"), &text).unwrap(),
            text,
        )
    }

    #[test]
    fn add_list_dedupe_and_unknown_machine() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/h.sqlite");
        let mut h = History::open(&path).unwrap();
        assert_eq!(h.version().unwrap(), schema::latest());
        let (d1, t1) = doc(-8.0, 50.0, 1000.0, Some("2026-09-01"));
        let a = h.add("mill", &d1, &t1, "a.json", None).unwrap();
        assert!(a.new && a.date_from_file && a.date_utc == "2026-09-01T00:00:00Z");
        let again = h.add("mill", &d1, &t1, "a.json", None).unwrap();
        assert_eq!((again.run_id, again.new), (a.run_id, false));
        let (d2, t2) = doc(-9.0, 50.0, 1000.0, None);
        let b = h
            .add(
                "mill",
                &d2,
                &t2,
                "b.json",
                Some("2026-10-01T00:00:00Z".into()),
            )
            .unwrap();
        assert!(b.new && !b.date_from_file);
        let runs = h.runs("mill").unwrap();
        assert_eq!(runs.len(), 2);
        assert_eq!(runs[1].effects[0].name, "backlash_x");
        assert_eq!(runs[1].effects[0].value, Some(-9.0));
        assert_eq!(runs[0].conditions.circles, vec![(50.0, 0.0, Some(1000.0))]);
        let e = h.runs("lathe").unwrap_err();
        assert!(e.to_string().contains("known: mill"), "{e}");
        assert_eq!(e.exit_code(), 2);
        assert_eq!(h.machines().unwrap(), vec![("mill".to_string(), 2)]);
    }

    #[test]
    fn an_old_schema_is_migrated_and_a_newer_one_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.sqlite");
        {
            let h = History::open_at(&path, 1).unwrap();
            assert_eq!(h.version().unwrap(), 1);
            // A version-1 file holds runs without jdbb_version: add one by hand.
            let (d, t) = doc(-8.0, 50.0, 1000.0, Some("2026-09-01"));
            h.conn
                .execute(
                    "INSERT INTO machines (name, created_utc) VALUES ('m', 'x')",
                    [],
                )
                .unwrap();
            h.conn
                .execute(
                    "INSERT INTO runs (machine_id, date_utc, added_utc, source, digest, samples, conditions, diagnosis)
                     VALUES (1, '2026-09-01T00:00:00Z', 'x', 's', 'd', 1000, ?1, ?2)",
                    params![serde_json::to_string(&Conditions::of(&d)).unwrap(), t],
                )
                .unwrap();
        }
        let h = History::open(&path).unwrap();
        assert_eq!(h.version().unwrap(), schema::latest());
        assert_eq!(
            h.runs("m").unwrap().len(),
            1,
            "the run survives the migration"
        );
        let idx: i64 = h
            .conn
            .query_row(
                "SELECT COUNT(*) FROM sqlite_master WHERE name = 'runs_by_machine_date'",
                [],
                |r| r.get(0),
            )
            .unwrap();
        assert_eq!(idx, 1);
        drop(h);
        let conn = Connection::open(&path).unwrap();
        conn.pragma_update(None, "user_version", 99).unwrap();
        drop(conn);
        let e = History::open(&path).err().unwrap();
        assert!(e.to_string().contains("newer jdbb"), "{e}");
    }

    #[test]
    fn runs_stored_before_the_signs_of_the_trade_keep_their_meaning() {
        // A version-2 history as the previous jdbb wrote it: a format-1 diagnosis whose
        // backlash_x −8 µm was lost motion (the axis lagging) and whose centring c = (12, −7)
        // put the table ball at (−12, 7); plus a squareness, which has no changed sign.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.sqlite");
        let old_text = serde_json::json!({
            "samples": 1000,
            "effects": [
                {"name": "setup_offset", "value": 13.9, "unit": "um", "sigma": 0.1, "setup": true,
                 "params": {"x_um": 12.0, "y_um": -7.0, "z_um": 0.0}},
                {"name": "backlash_x", "value": -8.0, "unit": "um", "sigma": 0.01,
                 "params": {"f_um": -8.0}},
                {"name": "squareness_xy", "value": 25.0, "unit": "um/m", "sigma": 0.05,
                 "params": {"s_um_per_m": 25.0}}
            ],
            "final": {"rms_um": 0.3},
            "lsq_setup": {"x_um": 12.0, "y_um": -7.0, "z_um": 0.0, "e_um": 0.0},
            "plane": "xy",
            "circles": [{"radius_mm": 90.0, "height_mm": 0.0, "feed_mm_min": 1000.0,
                         "samples": 500, "g_um": 14.1, "h_um": 10.3}],
            "minimum_zone": {"g_um": 14.1, "h_um": 10.3},
        })
        .to_string();
        {
            let h = History::open_at(&path, 2).unwrap();
            h.conn
                .execute(
                    "INSERT INTO machines (name, created_utc) VALUES ('mill', 'x')",
                    [],
                )
                .unwrap();
            h.conn
                .execute(
                    "INSERT INTO runs (machine_id, date_utc, added_utc, source, digest, samples,
                         conditions, g_um, h_um, final_rms_um, diagnosis, jdbb_version)
                     VALUES (1, '2026-09-01T00:00:00Z', 'x', 'sep.json', ?1, 1000, '{}', 14.1,
                         10.3, 0.3, ?2, '0.1.0')",
                    params![digest(old_text.as_bytes()), old_text],
                )
                .unwrap();
            for (name, value, unit) in [("backlash_x", -8.0, "um"), ("squareness_xy", 25.0, "um/m")]
            {
                h.conn
                    .execute(
                        "INSERT INTO effects (run_id, name, value, sigma, unit) VALUES (1, ?1, ?2, 0.01, ?3)",
                        params![name, value, unit],
                    )
                    .unwrap();
            }
        }
        let h = History::open(&path).unwrap();
        assert_eq!(h.version().unwrap(), schema::latest());
        let runs = h.runs("mill").unwrap();
        let value = |n: &str| runs[0].effects.iter().find(|e| e.name == n).unwrap().value;
        assert_eq!(
            value("backlash_x"),
            Some(8.0),
            "lost motion is positive now"
        );
        assert_eq!(value("squareness_xy"), Some(25.0));
        assert_eq!(runs[0].g_um, Some(14.1));
        // The stored file reads as today's: backlash +8 as b_um, the table ball at (−12, 7).
        let stored: String = h
            .conn
            .query_row("SELECT diagnosis FROM runs WHERE id = 1", [], |r| r.get(0))
            .unwrap();
        let doc = DiagnosisDoc::parse(Path::new("stored"), &stored).unwrap();
        let v: serde_json::Value = serde_json::from_str(&stored).unwrap();
        assert_eq!(v["format"], crate::report::document::FORMAT);
        assert_eq!(v["effects"][1]["params"]["b_um"].as_f64(), Some(8.0));
        assert_eq!(doc.effects[0].params.get("x_um"), Some(&Some(-12.0)));
        assert_eq!(v["lsq_setup"]["y_um"].as_f64(), Some(7.0));
        // Migrated once: opening again changes nothing.
        drop(h);
        let mut h = History::open(&path).unwrap();
        assert_eq!(h.runs("mill").unwrap()[0].effects[0].value, Some(8.0));
        // The same old file added again is the run already there (its digest is the file's);
        // a new old-format file is stored upgraded, its backlash +8 too.
        let d = DiagnosisDoc::parse(Path::new("sep.json"), &old_text).unwrap();
        let again = h.add("mill", &d, &old_text, "sep.json", None).unwrap();
        assert_eq!((again.run_id, again.new), (1, false));
        let other = old_text.replace("\"samples\":1000", "\"samples\":1001");
        let d = DiagnosisDoc::parse(Path::new("oct.json"), &other).unwrap();
        let added = h
            .add(
                "mill",
                &d,
                &other,
                "oct.json",
                Some("2026-10-01T00:00:00Z".into()),
            )
            .unwrap();
        assert!(added.new);
        let runs = h.runs("mill").unwrap();
        assert_eq!(runs[1].effects[0].value, Some(8.0));
        let stored: String = h
            .conn
            .query_row(
                "SELECT diagnosis FROM runs WHERE id = ?1",
                [added.run_id],
                |r| r.get(0),
            )
            .unwrap();
        assert!(stored.contains("\"format\": 2"), "{stored}");
    }

    #[test]
    fn many_first_opens_of_a_new_file_at_once_all_succeed() {
        // Six connections open the same new file at once, sixty times over: each must get it
        // (switching a new file to WAL can be refused as busy without the busy handler).
        let dir = tempfile::tempdir().unwrap();
        for round in 0..60 {
            let path = dir.path().join(format!("h{round}.sqlite"));
            let start = std::sync::Arc::new(std::sync::Barrier::new(6));
            let handles: Vec<_> = (0..6)
                .map(|_| {
                    let (path, start) = (path.clone(), start.clone());
                    std::thread::spawn(move || {
                        start.wait();
                        History::open(&path).map(|h| h.version().unwrap())
                    })
                })
                .collect();
            for h in handles {
                let v = h.join().unwrap();
                assert_eq!(v.ok(), Some(schema::latest()), "round {round}");
            }
        }
    }

    #[test]
    fn two_writers_at_once_lose_nothing() {
        // Two threads, each with its own connection, add 40 runs each at the same time.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.sqlite");
        History::open(&path).unwrap();
        let handles: Vec<_> = (0..2)
            .map(|w| {
                let path = path.clone();
                std::thread::spawn(move || {
                    let mut h = History::open(&path).unwrap();
                    for k in 0..40 {
                        let (d, t) = doc(-(w * 100 + k) as f64, 50.0, 1000.0, Some("2026-09-01"));
                        h.add("mill", &d, &t, "x.json", None).unwrap();
                    }
                })
            })
            .collect();
        for j in handles {
            j.join().unwrap();
        }
        let h = History::open(&path).unwrap();
        assert_eq!(h.runs("mill").unwrap().len(), 80);
    }

    #[test]
    fn an_older_jdbb_history_without_the_stamp_opens_and_is_stamped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("h.sqlite");
        for version in 1..=schema::latest() {
            let _ = std::fs::remove_file(&path);
            drop(History::open_at(&path, version).unwrap());
            // As a jdbb before the application id left it.
            let conn = Connection::open(&path).unwrap();
            conn.pragma_update(None, "application_id", 0).unwrap();
            assert_eq!(schema::owner(&conn).unwrap(), schema::Owner::Jdbb);
            // Another table beside jdbb's is not jdbb's schema.
            conn.execute_batch("CREATE TABLE laps (t REAL)").unwrap();
            assert!(matches!(
                schema::owner(&conn).unwrap(),
                schema::Owner::Other(_)
            ));
            conn.execute_batch("DROP TABLE laps").unwrap();
            drop(conn);
            if version == schema::latest() {
                // Read as it is (list, trend), then stamped when opened to write.
                let h = History::open_existing(&path).unwrap();
                assert!(h.machines().unwrap().is_empty());
            }
            let h = History::open(&path).unwrap();
            assert_eq!(h.version().unwrap(), schema::latest(), "from {version}");
            let id: i64 = h
                .conn
                .query_row("PRAGMA application_id", [], |r| r.get(0))
                .unwrap();
            assert_eq!(id, schema::APPLICATION_ID, "from {version}");
        }
    }

    #[test]
    fn control_characters_print_escaped() {
        assert_eq!(printable("mill-1 ä"), "mill-1 ä");
        assert_eq!(printable("a\nb\u{1b}[2J\t"), "a\\nb\\u{1b}[2J\\t");
    }

    #[test]
    fn conditions_name_what_differs() {
        let (a, _) = doc(-8.0, 50.0, 1000.0, None);
        let (b, _) = doc(-8.0, 90.0, 1000.0, None);
        let (c, _) = doc(-8.0, 50.3, 1500.0, None);
        let ca = Conditions::of(&a);
        assert!(ca.differences(&ca).is_empty());
        let d = Conditions::of(&b).differences(&ca);
        assert!(d[0].starts_with("circles r 90.0 mm"), "{d:?}");
        let d = Conditions::of(&c).differences(&ca);
        assert_eq!(d, vec!["feed 1500 mm/min (latest 1000)".to_string()]);
        let mut cal = Conditions::of(&a);
        cal.calibration = Some(serde_json::json!({"l1_mm": 50}));
        assert_eq!(
            cal.differences(&ca),
            vec!["an instrument calibration recorded (the latest has none)".to_string()]
        );
        assert_eq!(digest(b""), "cbf29ce484222325");
        assert_eq!(digest(b"a"), "af63dc4c8601ec8c");
    }
}
