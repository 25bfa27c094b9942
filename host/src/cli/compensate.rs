//! `jdbb compensate`: a diagnosis as the settings of a CNC controller; glue to
//! [`crate::compensate`].
use std::path::PathBuf;

use super::args::{finite_value as finite, per_axis};
use super::output::print;
use crate::compensate::{plan, render, Controller, Current, Options, Placement};
use crate::fsio::FileSet;
use crate::profile::MachineProfile;
use crate::report::document::DiagnosisDoc;
use crate::Result;

/// The profile's units and increment system, where the values in force do not give them: the
/// parameters of a Fanuc backup (Nos. 1001#0, 1013#1 as eight-digit bit strings) and SINUMERIK's
/// `$MN_SCALING_SYSTEM_IS_METRIC`.
fn profile_units(profile: &MachineProfile, controller: Controller, current: &mut Current) {
    let inch = profile.units.as_deref().map(|u| u == "inch");
    match controller {
        Controller::Fanuc => {
            if let (Some(inch), None) = (inch, current.text("1001")) {
                current.set_text("1001", if inch { "00000001" } else { "00000000" });
            }
            if let Some(is) = profile.increment_system.as_deref() {
                for k in 1..=3 {
                    let key = format!("1013.{k}");
                    if current.text(&key).is_none() {
                        current.set_text(key, if is == "IS-C" { "00000010" } else { "00000000" });
                    }
                }
            }
        }
        Controller::Sinumerik => {
            if let (Some(inch), None) = (inch, current.get("METRIC")) {
                current.set("METRIC", if inch { 0.0 } else { 1.0 });
            }
        }
        _ => {}
    }
}

/// Arguments of `jdbb compensate`.
#[derive(Debug, clap::Args)]
pub struct CompensateArgs {
    /// The diagnosis: diagnosis.json of `jdbb diagnose --report DIR`, or its `--json` output.
    #[arg(long, value_name = "DIAG.json")]
    pub diagnosis: PathBuf,
    /// The controller: linuxcnc, grblhal, marlin, klipper, fanuc (0i-F/30i), sinumerik (840D sl /
    /// ONE) or heidenhain (iTNC 530 / TNC 640).
    /// (Or the machine profile's `controller`.)
    #[arg(long, required_unless_present = "machine_profile")]
    pub controller: Option<String>,
    /// The values in force, in the controller's format (LinuxCNC INI lines with `[TRAJ]
    /// LINEAR_UNITS`, a `COMP_FILE` in force read beside this file; grblHAL `$n=v` lines; Marlin
    /// M425/M852/M92 lines; Klipper printer.cfg sections with the `SKEW_PROFILE LOAD=` line of
    /// the start macro; a Fanuc parameter backup CNC-PARA.TXT; SINUMERIK machine-data lines
    /// `$MA_…=`; Heidenhain `MPxxx.x:` lines); the output gives new totals in the controller's
    /// units.
    #[arg(long, value_name = "FILE")]
    pub current: Option<PathBuf>,
    /// Machine coordinates of the table ball during the test, e.g. `x=250,y=150,z=-300` (mm),
    /// where a table over machine positions is written (LinuxCNC COMP_FILE, Fanuc pitch error
    /// table, SINUMERIK EEC, Heidenhain *.COM).
    #[arg(long, value_name = "x=..,y=..,z=..")]
    pub table_ball: Option<String>,
    /// Machine travel to cover with a position table, e.g. `x=0:500,y=0:400` (mm).
    #[arg(long, value_name = "x=MIN:MAX,..")]
    pub travel: Option<String>,
    /// LinuxCNC COMP_FILE_TYPE to write: 1 (corrections) or 0 (actual positions).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(0..=1))]
    pub comp_file_type: u8,
    /// Write the files (LinuxCNC comp tables, Fanuc pitch.txt, SINUMERIK AX_EEC_INI.SPF,
    /// Heidenhain *.COM and CONFIG.CMA) into this directory instead of printing them; they
    /// are written as a set (all new, or all as they were).
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Replace files already in --out (a hand-edited table is not replaced without it).
    #[arg(long, requires = "out")]
    pub force: bool,
    /// The machine profile (a commented TOML: controller, units and increment system, table
    /// ball, travel; `crate::profile`): its values stand where a flag is not given, a flag
    /// overrides it. A FILE, or a machine's NAME found in the machines directory.
    #[arg(long, value_name = "FILE|NAME")]
    pub machine_profile: Option<PathBuf>,
}

/// Run `jdbb compensate`.
pub fn run(args: &CompensateArgs) -> Result<()> {
    let profile = match &args.machine_profile {
        Some(f) => MachineProfile::find(f)?,
        None => MachineProfile::default(),
    };
    let controller = match args.controller.as_ref().or(profile.controller.as_ref()) {
        Some(name) => Controller::parse(name)?,
        None => {
            return Err(crate::Error::Usage(
                "give --controller, or a machine profile with `controller = \"…\"`".into(),
            ))
        }
    };
    let (doc, _) = DiagnosisDoc::read(&args.diagnosis)?;
    let mut current = match &args.current {
        Some(f) => Current::read(f, controller)?,
        None => Current::none(),
    };
    profile_units(&profile, controller, &mut current);
    let mut placement = Placement::default();
    if let Some(s) = args.table_ball.clone().or(profile.table_ball_arg()) {
        placement.table_ball_mm = per_axis("--table-ball", &s, finite, "x=250 (mm)")?;
    }
    if let Some(s) = args.travel.clone().or(profile.travel_arg()) {
        placement.travel_mm = super::args::travel_mm("--travel", &s)?;
    }
    let opts = Options {
        controller,
        placement,
        comp_file_type: args.comp_file_type,
    };
    let p = plan(&doc, &current, &opts)?;
    if let Some(dir) = &args.out {
        let mut set = FileSet::new(dir, args.force)?;
        let names: Vec<&str> = p.files.iter().map(|(n, _)| n.as_str()).collect();
        let mut inputs = vec![("--diagnosis", args.diagnosis.as_path())];
        inputs.extend(args.current.iter().map(|c| ("--current", c.as_path())));
        let comp_files = crate::compensate::linuxcnc::comp_files_in_force(&current);
        inputs.extend(comp_files.iter().map(|c| ("COMP_FILE", c.as_path())));
        set.check(&names, &inputs)?;
        for (name, content) in &p.files {
            set.add(name, content.as_bytes())?;
        }
        set.commit()?;
    }
    let mut text = format!("from {}\n", args.diagnosis.display());
    text.push_str(&render(&p, args.out.as_deref()));
    print(&text)
}
