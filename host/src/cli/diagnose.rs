//! `jdbb diagnose`: arguments and glue to [`crate::diagnose`] and [`crate::report`].
use std::path::PathBuf;

use super::output::{emit, json_text, print};
use crate::diagnose::input::{read_record_with_path, read_samples};
use crate::diagnose::planned::diagnose_record;
use crate::diagnose::{diagnose, Options};
use crate::fsio::{check_dir_destination, write_dir};
use crate::model::parse_pitch;
use crate::plan::Plan;
use crate::report::document::DiagnosisDoc;
use crate::report::html::report_html;
use crate::report::plot::write_report;
use crate::report::{details, plan_json, summary, sync_details, sync_json, sync_summary, to_json};
use crate::sync::Record;
use crate::{Error, Result};

/// Arguments of `jdbb diagnose`.
#[derive(Debug, Clone, clap::Args)]
pub struct DiagnoseArgs {
    /// CSV `t_s,x_mm,y_mm,z_mm,d_mm` (nominal path and measured D), e.g. from `jdbb simulate`.
    #[arg(long, required_unless_present = "record", conflicts_with = "record")]
    pub samples: Option<PathBuf>,
    /// A `jdbb record` file (`seq,t_us,enc1,enc2,d_mm`), diagnosed together with `--plan` (or a
    /// hand-made `--path`).
    #[arg(long)]
    pub record: Option<PathBuf>,
    /// The plan.json that `jdbb plan` wrote for the program the machine ran: the record is
    /// synchronised with it from D alone (cycle start, circles, feed) and only its data arcs are
    /// diagnosed.
    #[arg(long, requires = "record", conflicts_with_all = ["path", "path_offset_s"])]
    pub plan: Option<PathBuf>,
    /// The nominal path of a `--record` file: CSV `t_s,x_mm,y_mm,z_mm` (the commanded ball
    /// centre relative to the table ball), interpolated linearly at the record's times.
    #[arg(long, requires = "record")]
    pub path: Option<PathBuf>,
    /// With `--path`: time of the path's t_s = 0 on the record's clock, in s after the record's
    /// first sample.
    #[arg(long, allow_negative_numbers = true, value_parser = super::args::finite)]
    pub path_offset_s: Option<f64>,
    /// Ball-screw or scale pitch per axis in mm, e.g. `x=10,y=10,z=5`; enables cyclic_k and
    /// interference_k for those axes.
    #[arg(long)]
    pub pitch: Option<String>,
    /// Print the documented JSON instead of the human summary.
    #[arg(long)]
    pub json: bool,
    /// Add the details to the human summary: the ideal machine, each selection step's RMS and
    /// gain, every group the test cannot tell apart, what was tried and not named, the other
    /// centres (least-squares, minimum zone), residual harmonics, the clock and the arcs used.
    #[arg(long, short = 'v', conflicts_with = "json")]
    pub verbose: bool,
    /// Write polar plots (SVG and PNG), the JSON and report.html to this directory, as a whole:
    /// built beside it and swapped in, never a mix of new and stale files.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// With --report: also report.pdf, the report printed (A4; page one: machine, test, verdict,
    /// polar plot, ranked effects) by headless Chromium, which must be installed (Debian: `apt
    /// install chromium`; JDBB_CHROMIUM names another binary).
    #[arg(long, requires = "report")]
    pub pdf: bool,
    /// Replace the --report directory if it exists (only one jdbb wrote, holding nothing else; never a link).
    #[arg(long, requires = "report")]
    pub force: bool,
    /// The machine's name, for the report and the history (`jdbb history add`).
    #[arg(long)]
    pub machine: Option<String>,
    /// The machine profile, a FILE or a machine's NAME (`crate::profile`): its name, pitches (of
    /// the axes that move), tolerance and table ball stand where `--machine`, `--pitch`,
    /// `--tolerance-um`, `--table-ball` are not given.
    #[arg(long, value_name = "FILE|NAME")]
    pub machine_profile: Option<PathBuf>,
    /// Tolerance on the circular deviation G (µm): the run passes if every circle's G (each
    /// direction, minimum-zone centre) is at most this.
    #[arg(long, value_parser = super::args::positive)]
    pub tolerance_um: Option<f64>,
    /// Date of the test, YYYY-MM-DD or RFC 3339 (default: now), for the report and the history.
    #[arg(long, value_parser = crate::dates::parse_date)]
    pub date: Option<String>,
    /// The instrument calibration in force (the TOML `jdbb calibrate -o` writes; JSON with
    /// l1_mm, l2_mm, enc1 and enc2 is read too), for the report and the history.
    #[arg(long, value_name = "FILE")]
    pub calibration: Option<PathBuf>,
    /// Who ran the test, for the report (ISO 230-4).
    #[arg(long)]
    pub operator: Option<String>,
    /// The machine's temperature during the test (°C), for the report (ISO 230-4).
    #[arg(long, value_name = "°C", allow_negative_numbers = true, value_parser = super::args::finite)]
    pub machine_temperature_c: Option<f64>,
    /// The instrument's temperature during the test (°C), for the report (ISO 230-4).
    #[arg(long, value_name = "°C", allow_negative_numbers = true, value_parser = super::args::finite)]
    pub instrument_temperature_c: Option<f64>,
    /// Machine coordinates (G53) of the table ball during the test, e.g. `x=250,y=150,z=-300`
    /// (mm), for the report (as `jdbb compensate --table-ball`).
    #[arg(long, value_name = "x=..,y=..,z=..")]
    pub table_ball: Option<String>,
    /// The compensation in force during the test, in words (e.g. `BACKLASH X 0.010 mm, no
    /// COMP_FILE`), for the report and the history.
    #[arg(long, value_name = "TEXT", conflicts_with = "compensation_file")]
    pub compensation: Option<String>,
    /// The compensation in force during the test as a file (e.g. the INI section or the `M503`
    /// output; its text goes into the report and the history).
    #[arg(long, value_name = "FILE")]
    pub compensation_file: Option<PathBuf>,
}

/// Longest `--compensation-file` taken into the diagnosis (bytes).
const MAX_COMPENSATION_BYTES: usize = 64 * 1024;

/// The test's conditions from the options (ISO 230-4: operator, temperatures, table ball,
/// compensation in force) and the record's header (instrument serial), as fields of the
/// diagnosis JSON (documented in `report`); read before the work, so a bad option
/// costs nothing.
fn conditions(args: &DiagnoseArgs) -> Result<serde_json::Value> {
    use serde_json::json;
    let mut json = json!({});
    if let Some(o) = &args.operator {
        json["operator"] = json!(o);
    }
    if args.machine_temperature_c.is_some() || args.instrument_temperature_c.is_some() {
        json["temperature_c"] = json!({
            "machine": args.machine_temperature_c,
            "instrument": args.instrument_temperature_c,
        });
    }
    if let Some(s) = &args.table_ball {
        let [x, y, z] =
            super::args::per_axis("--table-ball", s, super::args::finite_value, "x=250 (mm)")?;
        json["table_ball_mm"] = json!({"x": x, "y": y, "z": z});
    }
    if let Some(t) = &args.compensation {
        json["compensation"] = json!({"text": t});
    }
    if let Some(f) = &args.compensation_file {
        let text = crate::table::read_text(f)?;
        if text.len() > MAX_COMPENSATION_BYTES {
            return Err(Error::input(
                f,
                1,
                0,
                format!(
                    "{} bytes: give the compensation in force, not a whole configuration (at most {} KiB; the relevant section or the M503 output)",
                    text.len(),
                    MAX_COMPENSATION_BYTES / 1024
                ),
            ));
        }
        json["compensation"] = json!({"file": f.display().to_string(), "text": text});
    }
    if let Some(record) = &args.record {
        if let Some(serial) =
            crate::diagnose::input::record_header_value(record, crate::table::INSTRUMENT_SERIAL)?
        {
            json["instrument"] = json!({"serial": serial});
        }
    }
    Ok(json)
}

/// The calibration file of `--calibration` (TOML as `jdbb calibrate -o` writes it, or JSON),
/// checked against jdbb-core's Calibration, as a JSON value for the diagnosis.
fn read_calibration(file: &std::path::Path) -> Result<serde_json::Value> {
    let text = crate::table::read_text(file)?;
    if !text.trim_start().starts_with('{') {
        let cal = crate::instrument::file::parse_calibration(file, &text)?;
        return Ok(serde_json::to_value(cal).expect("a calibration is plain data"));
    }
    let cal: jdbb_core::calib::Calibration = serde_json::from_str(&text).map_err(|e| {
        Error::input(
            file,
            e.line(),
            e.column(),
            format!("not an instrument calibration ({e}); expected the TOML `jdbb calibrate -o` writes, or JSON with l1_mm, l2_mm, enc1 and enc2 ({{counts_per_rev, zero_count, direction: Positive|Negative}})"),
        )
    })?;
    cal.validate().map_err(|e| Error::Input {
        location: file.display().to_string(),
        message: format!("calibration rejected: {}", crate::instrument::file::why(e)),
    })?;
    Ok(serde_json::to_value(cal).expect("a calibration is plain data"))
}

/// The run's facts from the options (machine, date, tolerance and verdict, calibration) into
/// the diagnosis JSON (documented in `report`); returns the verdict line to print.
fn add_run_facts(
    json: &mut serde_json::Value,
    args: &DiagnoseArgs,
    diag: &crate::diagnose::Diagnosis,
) -> Result<Option<String>> {
    use serde_json::json;
    if let Some(m) = &args.machine {
        json["machine"] = json!(m);
    }
    json["date_utc"] = json!(args.date.clone().unwrap_or_else(crate::dates::now_utc));
    json["date_of"] = json!(if args.date.is_some() {
        "test"
    } else {
        "diagnosis"
    });
    if let Some(file) = &args.calibration {
        json["calibration"] = read_calibration(file)?;
        json["calibration_file"] = json!(file.display().to_string());
    }
    let Some(tol) = args.tolerance_um else {
        return Ok(None);
    };
    let (pass, line) = crate::report::tolerance_verdict(diag, tol);
    json["tolerance"] = json!({"g_um": tol, "pass": pass});
    Ok(Some(line))
}

/// Refuse a record made for another plan (its `# plan_id:` line names another id). A record
/// without the line (made by `jdbb record` without `--plan`, before plan ids, or by hand) is
/// taken as it is, with a warning: D alone cannot tell the plane, so a plan for another plane
/// would name the wrong axes unseen.
fn check_plan_id(rec: &Record, plan: &Plan, plan_file: &std::path::Path) -> Result<()> {
    if rec.plan_id.is_none() {
        super::output::note(&format!(
            "warning: {} has no `# plan_id:` line, so nothing ties it to {} (plane {}, plan_id {}): D alone cannot tell the plane, and a plan for another plane names the wrong axes (X play as Z play). Check that this is the plan the test ran; `jdbb record --plan` writes the line",
            rec.path.display(),
            plan_file.display(),
            plan.plane.name().to_ascii_uppercase(),
            plan.id()
        ));
    }
    match &rec.plan_id {
        Some(id) if *id != plan.id() => Err(Error::Input {
            location: rec.path.display().to_string(),
            message: format!(
                "this record was made for another plan (plan_id {id}), not for {} (plan_id {}): another plane, circle, feed or centre would make the diagnosis name the wrong axes. Give the plan.json the record was made with",
                plan_file.display(),
                plan.id()
            ),
        }),
        _ => Ok(()),
    }
}

/// The input files of `args`, each with the option that names it.
fn inputs(args: &DiagnoseArgs) -> Vec<(&'static str, &std::path::Path)> {
    [
        ("--samples", &args.samples),
        ("--record", &args.record),
        ("--plan", &args.plan),
        ("--path", &args.path),
        ("--calibration", &args.calibration),
        ("--compensation-file", &args.compensation_file),
    ]
    .into_iter()
    .filter_map(|(o, p)| p.as_deref().map(|p| (o, p)))
    .collect()
}

/// What the record set aside, as `sync.set_aside` of the diagnosis JSON: `glitches` (each
/// sample's `line`, `t_s` after the record's first sample and `d_mm`; at most
/// [`MAX_LISTED_GLITCHES`]), `glitch_count` (all of them) and `marked` (samples the recorder
/// marked as suspect, `# suspect:` lines).
fn set_aside_json(rec: &Record) -> serde_json::Value {
    serde_json::json!({
        "glitch_count": rec.glitches.len(),
        "glitches": rec.glitches.iter().take(MAX_LISTED_GLITCHES).map(|g| serde_json::json!({
            "line": g.line,
            "t_s": g.t_s,
            "d_mm": g.d_mm,
        })).collect::<Vec<_>>(),
        "marked": rec.marked,
    })
}

/// Most glitches listed one by one in the diagnosis JSON.
const MAX_LISTED_GLITCHES: usize = 1000;

/// The profile's pitches (`--pitch`) of the axes that move in the test: samples are read once to
/// see which axes move, a record's are the two of its plan's plane; a record with a hand-made
/// `--path` does not use them (give --pitch).
fn profile_pitch(
    args: &DiagnoseArgs,
    profile: &crate::profile::MachineProfile,
) -> Result<Option<String>> {
    let Some(all) = profile.pitch_arg() else {
        return Ok(None);
    };
    let moves: Box<dyn Fn(crate::model::Axis) -> bool> = match (&args.samples, &args.plan) {
        (Some(samples), _) => {
            let (path, _) = read_samples(samples, [None; 3])?;
            Box::new(move |a| path.moves(a))
        }
        (None, Some(plan_file)) => {
            let (i, j, _) = Plan::read(plan_file)?.plane.axes();
            Box::new(move |a| a.index() == i || a.index() == j)
        }
        (None, None) => return Ok(None),
    };
    let pitch = parse_pitch(&all)?;
    let moving: Vec<String> = crate::model::Axis::ALL
        .iter()
        .filter_map(|&a| {
            let p = pitch[a.index()]?;
            moves(a).then(|| format!("{}={p}", a.letter()))
        })
        .collect();
    Ok((!moving.is_empty()).then(|| moving.join(",")))
}

/// The diagnosis of a `--samples` file: the one path of `diagnose --samples` and `history rerun`.
pub fn diagnose_samples(
    samples: &std::path::Path,
    pitch: [Option<f64>; 3],
    opts: &Options,
) -> Result<crate::diagnose::Diagnosis> {
    let (path, d) = read_samples(samples, pitch)?;
    diagnose(&path, &d, opts)
}

/// The diagnosis of a `--record` file synchronised with its `--plan`: the one path of
/// `diagnose --record --plan` and `history rerun`.
pub fn diagnose_planned(
    record: &std::path::Path,
    plan_file: &std::path::Path,
    pitch: [Option<f64>; 3],
    opts: &Options,
) -> Result<(Plan, Record, crate::diagnose::planned::Planned)> {
    let plan = Plan::read(plan_file)?;
    crate::volumetric::refuse_diagnosis(&plan, plan_file)?;
    let rec = Record::read(record)?;
    check_plan_id(&rec, &plan, plan_file)?;
    let done = diagnose_record(&plan, &rec, pitch, opts)?;
    Ok((plan, rec, done))
}

/// Run `jdbb diagnose`.
pub fn run(args: &DiagnoseArgs) -> Result<()> {
    let filled;
    // The profile's controller: which settings the what-if G assumes entered.
    let mut opts = Options::default();
    let args = match &args.machine_profile {
        Some(f) => {
            let p = crate::profile::MachineProfile::find(f)?;
            opts.controller = p
                .controller
                .as_deref()
                .map(crate::compensate::Controller::parse)
                .transpose()?;
            let mut a = args.clone();
            a.machine = a.machine.or(p.machine.clone());
            if a.pitch.is_none() {
                a.pitch = profile_pitch(&a, &p)?;
            }
            a.tolerance_um = a.tolerance_um.or(p.tolerance_um);
            a.table_ball = a.table_ball.or(p.table_ball_arg());
            filled = a;
            &filled
        }
        None => args,
    };
    if let Some(dir) = &args.report {
        // Before the work: a report directory that will be refused is refused at once.
        check_dir_destination(dir, args.force)?;
        crate::fsio::check_not_input(dir, &inputs(args))?;
    }
    // Before the work too: a --pdf that cannot be printed costs nothing.
    let chromium = args
        .pdf
        .then(crate::report::pdf::find_chromium)
        .transpose()?;
    let pitch = match &args.pitch {
        Some(s) => parse_pitch(s)?,
        None => [None; 3],
    };
    let conditions = conditions(args)?;
    let mut synced = None;
    // What `--record --path` set aside (glitches), said before the diagnosis.
    let mut path_note: Option<String> = None;
    let diag = match (&args.samples, &args.record, &args.path, &args.plan) {
        (Some(samples), _, _, _) => diagnose_samples(samples, pitch, &opts)?,
        (None, Some(record), None, Some(plan_file)) => {
            let (plan, rec, done) = diagnose_planned(record, plan_file, pitch, &opts)?;
            let set_aside = (rec.set_aside_note(Some(&done.sync)), set_aside_json(&rec));
            synced = Some((plan_file, plan, done.sync, set_aside));
            done.diagnosis
        }
        (None, Some(record), Some(nominal), None) => {
            let (path, d, glitches) =
                read_record_with_path(record, nominal, args.path_offset_s.unwrap_or(0.0), pitch)?;
            if let Some(n) = crate::sync::glitch::describe(&glitches, &|_| None) {
                path_note = Some(n);
            }
            diagnose(&path, &d, &opts)?
        }
        _ => {
            return Err(Error::Usage(
                "give --samples FILE, or --record FILE with --plan plan.json (or with a hand-made --path FILE)".into(),
            ))
        }
    };
    let mut json = to_json(&diag);
    if let Some((file, plan, sync, (_, set_aside))) = &synced {
        json["plan"] = plan_json(file, plan);
        json["sync"] = sync_json(plan, sync);
        json["sync"]["set_aside"] = set_aside.clone();
    }
    let verdict = add_run_facts(&mut json, args, &diag)?;
    if let serde_json::Value::Object(m) = conditions {
        for (k, v) in m {
            json[k] = v;
        }
    }
    if args.json {
        emit(&json_text(&json))?;
    } else {
        if let Some((_, plan, sync, (note, _))) = &synced {
            print(&sync_summary(plan, sync))?;
            if args.verbose {
                print(&sync_details(plan, sync))?;
            }
            if let Some(n) = note {
                emit(n)?;
            }
        }
        if let Some(n) = &path_note {
            emit(n)?;
        }
        print(&summary(&diag))?;
        if args.verbose {
            print(&details(&diag))?;
        }
        if let Some(v) = &verdict {
            emit(v)?;
        }
    }
    if let Some(dir) = &args.report {
        let doc: DiagnosisDoc = serde_json::from_value(json.clone()).map_err(|e| {
            Error::Numerics(format!(
                "the diagnosis does not read back as a document ({e}); this is a bug, please report it"
            ))
        })?;
        let html = report_html(&diag, &doc)?;
        write_dir(dir, args.force, |stage| {
            write_report(stage, &diag, &json)?;
            let page = stage.join("report.html");
            crate::fsio::write_file(&page, html.as_bytes(), false)?;
            match &chromium {
                Some(c) => crate::report::pdf::print_to_pdf(
                    c,
                    &page,
                    &stage.join("report.pdf"),
                    &stage.join(".chromium-profile"),
                ),
                None => Ok(()),
            }
        })?;
        if !args.json {
            emit(&format!("report written to {}", dir.display()))?;
        }
    }
    Ok(())
}
