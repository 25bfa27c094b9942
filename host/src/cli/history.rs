//! `jdbb history add|list|trend|comp|remove|edit`: a machine's diagnoses over time, on a file or
//! a server; glue to [`crate::history`], each command written once on its [`Store`].
use std::fmt::Write;
use std::path::PathBuf;

use super::output::print;
use crate::history::keep::{self, Kept, KeptFile};
use crate::history::{effect_order, printable, trend};
use crate::report::document::DiagnosisDoc;
use crate::units::{format_to, human};
use crate::Result;

/// Arguments of `jdbb history`.
#[derive(Debug, clap::Args)]
pub struct HistoryArgs {
    /// The history database: a file (default: $JDBB_HISTORY_DB, else history.sqlite in your
    /// data directory, e.g. ~/.local/share/jdbb/) or a server, postgres://USER:PASSWORD@HOST/DB.
    #[arg(long, global = true, value_name = "PATH|URL")]
    pub db: Option<PathBuf>,
    /// The machine profile, a FILE or a machine's NAME (`crate::profile`): its machine stands
    /// where --machine is not given, its tolerance where `trend --figure g` has no --tolerance-um.
    #[arg(long, global = true, value_name = "FILE|NAME")]
    pub machine_profile: Option<PathBuf>,
    #[command(subcommand)]
    pub command: HistoryCommand,
}

/// The history subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum HistoryCommand {
    /// File a diagnosis (diagnosis.json of `jdbb diagnose --report DIR`) under a machine.
    Add {
        /// The machine (default: the one the diagnosis names, `jdbb diagnose --machine`).
        #[arg(long)]
        machine: Option<String>,
        #[arg(long, value_name = "DIAG.json")]
        diagnosis: PathBuf,
        /// Date of the test (YYYY-MM-DD or RFC 3339), if not the one in the file.
        #[arg(long, value_parser = crate::dates::parse_date)]
        date: Option<String>,
        /// Keep the raw record the diagnosis was made from with the run (compressed,
        /// checksummed), so that `history rerun` can diagnose it again with a newer jdbb: the
        /// `jdbb record` file (with --plan), or the `--samples` CSV.
        #[arg(long, value_name = "REC.csv")]
        keep_record: Option<PathBuf>,
        /// With --keep-record: the plan.json the record was diagnosed with (`diagnose --record
        /// --plan`), kept too.
        #[arg(long, value_name = "PLAN.json", requires = "keep_record")]
        plan: Option<PathBuf>,
    },
    /// Diagnose a run's kept record (`add --keep-record`) again with this jdbb, its checksum
    /// checked first, and print each effect's stored value beside the new one (value, σ,
    /// difference in σ).
    Rerun {
        /// The run's machine (default: the one holding run --run).
        #[arg(long)]
        machine: Option<String>,
        /// The run's number, as `history list --machine NAME` shows it.
        #[arg(long)]
        run: i64,
    },
    /// The runs of a machine (or, without --machine, the machines).
    List {
        #[arg(long)]
        machine: Option<String>,
    },
    /// Each effect of a machine with its σ over time; runs not comparable with the latest are
    /// flagged with what differs (plane, circles, feed, plan, instrument calibration).
    Trend {
        /// The machine (default: the machine profile's).
        #[arg(long)]
        machine: Option<String>,
        /// Only this effect, e.g. backlash_x.
        #[arg(long, conflicts_with = "figure")]
        effect: Option<String>,
        /// Trend the circular deviation G (`g`) or the hysteresis H (`h`) of each run instead of
        /// the effects.
        #[arg(long, value_name = "g|h")]
        figure: Option<String>,
        /// A tolerance (µm) to hold G, H or an effect in µm against: a line on the plot, and the
        /// runs over it named.
        #[arg(long, value_parser = super::args::positive)]
        tolerance_um: Option<f64>,
        /// Also plot the trend to this SVG file.
        #[arg(long, visible_alias = "out", short = 'o', value_name = "OUT.svg")]
        plot: Option<PathBuf>,
        /// Also write the trend as CSV to this file (one row per run and quantity).
        #[arg(long, value_name = "OUT.csv")]
        csv: Option<PathBuf>,
        /// Replace --plot or --csv if it exists (a regular file only; never a link or a device).
        #[arg(long)]
        force: bool,
    },
    /// File a change of a machine's compensation (e.g. the settings `jdbb compensate` gave,
    /// once entered): `history trend` marks it and fits its slope only after it.
    Comp {
        /// The machine (default: the machine profile's).
        #[arg(long)]
        machine: Option<String>,
        /// When the change was made (YYYY-MM-DD or RFC 3339).
        #[arg(long, value_parser = crate::dates::parse_date)]
        date: String,
        /// What is in force from then on, in words.
        #[arg(long, conflicts_with = "file", required_unless_present = "file")]
        text: Option<String>,
        /// What is in force from then on, as a file (the INI section, the M503 output, ...).
        #[arg(long, value_name = "FILE")]
        file: Option<PathBuf>,
    },
    /// Every machine × effect (and G): latest value, slope per 30 days, tolerance, last
    /// compensation change, and drift alarms (a CUSUM since the last compensation change)
    /// naming the runs that show them.
    Fleet {
        /// Also write the view as CSV to this file.
        #[arg(long, value_name = "OUT.csv")]
        csv: Option<PathBuf>,
        /// Also write the view as an HTML page to this file.
        #[arg(long, value_name = "OUT.html")]
        html: Option<PathBuf>,
        /// Replace --csv or --html if it exists (a regular file only).
        #[arg(long)]
        force: bool,
    },
    /// Copy a station's history (a SQLite file) to another (a server): every run and
    /// compensation change, checked by counts and by each run's checksum; safe to run twice.
    Migrate {
        /// The history to copy, e.g. a station's history.sqlite.
        #[arg(long, value_name = "PATH|URL")]
        from: PathBuf,
        /// The history to copy to, e.g. postgres://USER:PASSWORD@HOST/DB.
        #[arg(long, value_name = "URL|PATH")]
        to: PathBuf,
    },
    /// Take a run out of the history (e.g. one filed under the wrong machine); it says what
    /// it removed, so that it can be added again from its file.
    Remove {
        /// The machine (default: the machine profile's).
        #[arg(long)]
        machine: Option<String>,
        /// The run's number, as `history list --machine NAME` shows it.
        #[arg(long)]
        run: i64,
    },
    /// Correct a run: file it under another date (one added with the wrong date).
    Edit {
        /// The machine (default: the machine profile's).
        #[arg(long)]
        machine: Option<String>,
        /// The run's number, as `history list --machine NAME` shows it.
        #[arg(long)]
        run: i64,
        /// The test's date (YYYY-MM-DD or RFC 3339).
        #[arg(long, value_parser = crate::dates::parse_date)]
        date: String,
    },
}

/// The machine holding run `run_id` of the history `h`; none is a usage error.
fn machine_of_run(h: &mut dyn crate::history::Store, run_id: i64) -> Result<String> {
    for (machine, _) in h.machines()? {
        if h.runs(&machine)?.iter().any(|r| r.id == run_id) {
            return Ok(machine);
        }
    }
    Err(crate::Error::Usage(format!(
        "no run {run_id} in the history {}: see `jdbb history list --machine NAME`",
        h.location()
    )))
}

/// Restore the kept files of `kept` (run of `machine` in the history at `location`) to a
/// temporary directory, checked; diagnose them again as `jdbb diagnose` would (`--record
/// --plan`, or `--samples`) with the pitches the run was diagnosed with; and say each effect's
/// stored value beside the new one.
fn rerun(kept: &Kept, machine: &str, location: &str) -> Result<String> {
    let id = kept.run.id;
    let Some(record) = kept.files.iter().find(|f| f.role == keep::RECORD) else {
        return Err(crate::Error::Usage(format!(
            "run {id} of {} kept no record: nothing to diagnose again (`jdbb history add --keep-record REC.csv` keeps one)",
            printable(machine)
        )));
    };
    let plan = kept.files.iter().find(|f| f.role == keep::PLAN);
    let dir = tempfile::Builder::new()
        .prefix("jdbb-rerun-")
        .tempdir()
        .map_err(|source| crate::Error::File {
            action: "cannot create a temporary directory for",
            path: std::env::temp_dir(),
            source,
        })?;
    let restore = |f: &KeptFile, sub: &str| -> Result<PathBuf> {
        let bytes = f.unpack(id, location)?;
        let sub = dir.path().join(sub);
        std::fs::create_dir_all(&sub).map_err(|source| crate::Error::File {
            action: "cannot create",
            path: sub.clone(),
            source,
        })?;
        let path = sub.join(f.base_name());
        crate::fsio::write_file(&path, &bytes, false)?;
        Ok(path)
    };
    let record_path = restore(record, "record")?;
    let plan_path = plan.map(|p| restore(p, "plan")).transpose()?;
    let stored = DiagnosisDoc::parse(std::path::Path::new(location), &kept.diagnosis)?;
    let pitch = crate::model::Axis::ALL.map(|a| stored.pitch_mm(a));
    let diag = match &plan_path {
        Some(p) => {
            super::diagnose::diagnose_planned(&record_path, p, pitch, &Default::default())?
                .2
                .diagnosis
        }
        None => super::diagnose::diagnose_samples(&record_path, pitch, &Default::default())?,
    };
    let now: DiagnosisDoc = serde_json::from_value(crate::report::to_json(&diag))
        .map_err(|e| {
            crate::Error::Numerics(format!(
                "the new diagnosis does not read back as a document ({e}); this is a bug, please report it"
            ))
        })?;
    let mut s = format!(
        "run {id} of {} ({}) diagnosed again with jdbb {} from its kept {}{} (SHA-256 checked)\n",
        printable(machine),
        kept.run.date_utc,
        env!("CARGO_PKG_VERSION"),
        printable(&record.name),
        plan.map(|p| format!(" and {}", printable(&p.name)))
            .unwrap_or_default()
    );
    s.push_str(&keep::compare(
        &kept.run.effects,
        &crate::history::effect_rows(&now),
    ));
    Ok(s)
}

/// The machine a subcommand is about: its --machine, else the machine profile's.
fn machine_or_profile(
    machine: &Option<String>,
    profile: &crate::profile::MachineProfile,
) -> Result<String> {
    machine
        .clone()
        .or_else(|| profile.machine.clone())
        .ok_or_else(|| {
            crate::Error::Usage(
                "give --machine NAME, or a --machine-profile with `machine = \"NAME\"`".into(),
            )
        })
}

/// Run `jdbb history`.
pub fn run(args: &HistoryArgs) -> Result<()> {
    let profile = match &args.machine_profile {
        Some(f) => crate::profile::MachineProfile::find(f)?,
        None => crate::profile::MachineProfile::default(),
    };
    let db = crate::history::location(args.db.as_deref().map(|p| p.as_os_str()))?;
    // A file's path, to keep the outputs off it; none for a server.
    let path = PathBuf::from(&db);
    let path = (!db.to_str().is_some_and(crate::history::pg::is_url)).then_some(path);
    match &args.command {
        HistoryCommand::Add {
            machine,
            diagnosis,
            date,
            keep_record,
            plan,
        } => {
            let (doc, text) = DiagnosisDoc::read(diagnosis)?;
            // Read (and packed) before anything is filed: a record that cannot be read files
            // nothing.
            let mut kept = vec![];
            if let Some(f) = keep_record {
                kept.push(KeptFile::read(keep::RECORD, f)?);
            }
            if let Some(f) = plan {
                kept.push(KeptFile::read(keep::PLAN, f)?);
            }
            let machine = match (
                machine.as_ref().or(profile.machine.as_ref()),
                doc.machine.as_deref(),
            ) {
                (Some(m), _) => m.clone(),
                (None, Some(named)) => named.to_string(),
                (None, None) => {
                    return Err(crate::Error::Usage(format!(
                    "{} names no machine: give --machine NAME (or diagnose with --machine NAME)",
                    diagnosis.display()
                )))
                }
            };
            let machine = &machine;
            if let Some(named) = doc.machine.as_deref().filter(|m| *m != machine.trim()) {
                return Err(crate::Error::Usage(format!(
                    "{} is of machine `{named}`, not `{machine}`: give --machine {named}, or diagnose again with --machine {machine}",
                    diagnosis.display()
                )));
            }
            let mut h = crate::history::open(&db, false)?;
            let mut run = crate::history::NewRun::of(
                machine,
                &doc,
                &text,
                &diagnosis.display().to_string(),
                date.clone(),
            )?;
            run.kept = kept;
            let added = h.store_run(&run)?;
            let mut text = if added.new {
                format!(
                    "added run {} of {machine} ({}{}) to {}\n",
                    added.run_id,
                    added.date_utc,
                    match (added.date_from_file, date.is_some(), doc.date_of.as_deref()) {
                        (_, true, _) => "",
                        (true, _, Some("diagnosis")) => {
                            ", the date of the diagnosis: the test's date was not given; give it with --date"
                        }
                        (true, _, _) => "",
                        (false, _, _) => ", the time of adding: the file has no date",
                    },
                    h.location()
                )
            } else {
                format!(
                    "already in {}: run {} of {machine} ({}); nothing added\n",
                    h.location(),
                    added.run_id,
                    added.date_utc
                )
            };
            if !run.kept.is_empty() {
                let files: Vec<String> = run
                    .kept
                    .iter()
                    .map(|f| {
                        format!(
                            "{} ({} bytes, {} gzip)",
                            printable(&f.name),
                            f.size_bytes,
                            f.gzip.len()
                        )
                    })
                    .collect();
                let _ = writeln!(
                    text,
                    "{} with run {}: {}",
                    if added.kept == run.kept.len() {
                        "kept"
                    } else if added.kept == 0 {
                        "already kept (the files it has stay; nothing kept)"
                    } else {
                        "kept what it lacked"
                    },
                    added.run_id,
                    files.join(", ")
                );
            }
            print(&text)
        }
        HistoryCommand::Rerun { machine, run } => {
            let mut h = crate::history::open(&db, true)?;
            let machine = match machine.as_ref().or(profile.machine.as_ref()) {
                Some(m) => m.clone(),
                None => machine_of_run(h.as_mut(), *run)?,
            };
            let kept = h.kept(&machine, *run)?;
            print(&rerun(&kept, &machine, &h.location())?)
        }
        HistoryCommand::List { machine: None } if profile.machine.is_none() => {
            let mut h = crate::history::open(&db, true)?;
            let mut s = String::new();
            let machines = h.machines()?;
            if machines.is_empty() {
                let _ = writeln!(s, "{}: no machines yet", h.location());
            }
            for (name, n) in machines {
                let _ = writeln!(s, "{}: {n} runs", printable(&name));
            }
            print(&s)
        }
        HistoryCommand::List { machine } => {
            let machine = &machine_or_profile(machine, &profile)?;
            let mut h = crate::history::open(&db, true)?;
            let runs = h.runs(machine)?;
            // One effect order in every row: the trend's.
            let order = effect_order(&runs);
            let rank = |name: &str| order.iter().position(|(n, _)| n == name);
            let mut s = String::new();
            let _ = writeln!(s, "machine {}: {} runs", printable(machine), runs.len());
            let _ = writeln!(
                s,
                "run  date                  G µm    H µm    RMS µm  verdict  effects"
            );
            for r in &runs {
                // G, H and RMS to the digits the run's noise (its residual RMS) supports.
                let noise = r.final_rms_um.unwrap_or(f64::NAN);
                let num = |x: Option<f64>| x.map_or("-".to_string(), |v| format_to(v, noise));
                let verdict = match (r.pass, r.tolerance_um) {
                    (Some(true), Some(t)) => format!("pass {t}"),
                    (Some(false), Some(t)) => format!("FAIL {t}"),
                    _ => "-".into(),
                };
                let mut sorted: Vec<_> = r.effects.iter().collect();
                sorted.sort_by_key(|e| rank(&e.name));
                let effects: Vec<String> = sorted
                    .into_iter()
                    .map(|e| {
                        format!(
                            "{} {} {}",
                            printable(&e.name),
                            match (e.value, e.sigma) {
                                (Some(v), Some(s)) => format_to(v, s),
                                (Some(v), None) => format!("{v:.3}"),
                                (None, _) => "-".into(),
                            },
                            human(&e.unit)
                        )
                    })
                    .collect();
                let _ = writeln!(
                    s,
                    "{:<4} {:<21} {:<7} {:<7} {:<7} {:<8} {}",
                    r.id,
                    r.date_utc,
                    num(r.g_um),
                    num(r.h_um),
                    num(r.final_rms_um),
                    verdict,
                    if effects.is_empty() {
                        "none".to_string()
                    } else {
                        effects.join(", ")
                    }
                );
            }
            print(&s)
        }
        HistoryCommand::Trend {
            machine,
            effect,
            figure,
            tolerance_um,
            plot,
            csv,
            force,
        } => {
            if *force && plot.is_none() && csv.is_none() {
                return Err(crate::Error::Usage(
                    "--force replaces the --plot or --csv file: give one of them".into(),
                ));
            }
            for file in [plot, csv].into_iter().flatten() {
                crate::fsio::check_destination(file, *force)?;
                if let Some(path) = &path {
                    crate::fsio::check_not_input(file, &[("--db", path.as_path())])?;
                }
            }
            if let (Some(p), Some(c)) = (plot, csv) {
                if crate::fsio::same_file(p, c) {
                    return Err(crate::Error::Usage(format!(
                        "--plot and --csv are both {}: give each its own file",
                        p.display()
                    )));
                }
            }
            let figure = figure.as_deref().map(trend::Figure::parse).transpose()?;
            let machine = &machine_or_profile(machine, &profile)?;
            // The profile's tolerance is on G: it holds the trend of G, not of H or an effect.
            let tolerance_um = &tolerance_um.or(profile
                .tolerance_um
                .filter(|_| figure == Some(trend::Figure::G)));
            let mut h = crate::history::open(&db, true)?;
            let runs = h.runs(machine)?;
            let marks = trend::compensation_marks(&runs, &h.compensations(machine)?);
            let trends = match figure {
                Some(f) => trend::figure_trend(&runs, f),
                // Effect names are lower case (`backlash_x`), whatever case they are typed in.
                None => trend::trend(
                    &runs,
                    effect.as_deref().map(str::to_ascii_lowercase).as_deref(),
                )?,
            };
            let mut s = trend::render(machine, &runs, &trends, &marks, *tolerance_um);
            if let Some(file) = plot {
                crate::fsio::write_via(file, *force, |tmp| {
                    trend::plot_svg(tmp, machine, &trends, &marks, *tolerance_um)
                })?;
                let _ = writeln!(s, "plot written to {}", file.display());
            }
            if let Some(file) = csv {
                let text = trend::csv(machine, &runs, &trends, &marks);
                crate::fsio::write_file(file, text.as_bytes(), *force)?;
                let _ = writeln!(s, "CSV written to {}", file.display());
            }
            print(&s)
        }
        HistoryCommand::Comp {
            machine,
            date,
            text,
            file,
        } => {
            let (text, source) = match (text, file) {
                (Some(t), _) => (t.clone(), None),
                (None, Some(f)) => (crate::table::read_text(f)?, Some(f.display().to_string())),
                (None, None) => {
                    return Err(crate::Error::Usage(
                        "give what is in force from --date on: --text TEXT or --file FILE".into(),
                    ))
                }
            };
            let machine = &machine_or_profile(machine, &profile)?;
            // An existing history only (a mistyped --db is an error), opened to write.
            drop(crate::history::open(&db, true)?);
            let mut h = crate::history::open(&db, false)?;
            let id = h.add_compensation(machine, date, &text, source.as_deref())?;
            print(&format!(
                "filed compensation change {id} of {} on {date} in {}\n",
                printable(machine),
                h.location()
            ))
        }
        HistoryCommand::Fleet { csv, html, force } => {
            for file in [csv, html].into_iter().flatten() {
                crate::fsio::check_destination(file, *force)?;
                if let Some(path) = &path {
                    crate::fsio::check_not_input(file, &[("--db", path.as_path())])?;
                }
            }
            let mut h = crate::history::open(&db, true)?;
            let mut rows = vec![];
            for (machine, _) in h.machines()? {
                let runs = h.runs(&machine)?;
                let marks = trend::compensation_marks(&runs, &h.compensations(&machine)?);
                rows.extend(crate::history::fleet::rows(&machine, &runs, &marks));
            }
            let mut s = crate::history::fleet::render(&rows);
            if let Some(file) = csv {
                let text = crate::history::fleet::csv(&rows);
                crate::fsio::write_file(file, text.as_bytes(), *force)?;
                let _ = writeln!(s, "CSV written to {}", file.display());
            }
            if let Some(file) = html {
                let title = format!("J-DBB fleet: {}", h.location());
                let text = crate::history::fleet::html(&rows, &title);
                crate::fsio::write_file(file, text.as_bytes(), *force)?;
                let _ = writeln!(s, "page written to {}", file.display());
            }
            print(&s)
        }
        HistoryCommand::Migrate { from, to } => {
            let mut source = crate::history::open(from.as_os_str(), true)?;
            let mut target = crate::history::open(to.as_os_str(), false)?;
            if source.location() == target.location() {
                return Err(crate::Error::Usage(format!(
                    "--from and --to are both {}: give the history to copy to",
                    source.location()
                )));
            }
            let m = crate::history::migrate(source.as_mut(), target.as_mut())?;
            print(&format!(
                "migrated {} to {}: {} runs of {} machines ({} new there), {} compensation changes ({} new there); checked: every run there with the same checksum\n",
                source.location(),
                target.location(),
                m.runs,
                m.machines,
                m.new_runs,
                m.compensations,
                m.new_compensations
            ))
        }
        HistoryCommand::Remove { machine, run } => {
            let machine = &machine_or_profile(machine, &profile)?;
            drop(crate::history::open(&db, true)?);
            let mut h = crate::history::open(&db, false)?;
            let r = h.remove_run(machine, *run)?;
            print(&format!(
                "removed run {} of {} ({}, from {}) from {}; `jdbb history add --machine {} --diagnosis {}` (same --db) files it again\n",
                r.id,
                printable(machine),
                r.date_utc,
                printable(&r.source),
                h.location(),
                printable(machine),
                printable(&r.source)
            ))
        }
        HistoryCommand::Edit { machine, run, date } => {
            let machine = &machine_or_profile(machine, &profile)?;
            drop(crate::history::open(&db, true)?);
            let mut h = crate::history::open(&db, false)?;
            let was = h.set_date(machine, *run, date)?;
            print(&format!(
                "run {run} of {} now filed on {date} (was {was}) in {}\n",
                printable(machine),
                h.location()
            ))
        }
    }
}
