//! `jdbb diagnose-rotary`: arguments and glue to [`crate::rotary::run_diagnosis`].
use std::path::PathBuf;

use super::output::{emit, json_text, print};
use crate::numerics::select::SelectOptions;
use crate::rotary::run_diagnosis::{diagnose_run, read_runs, summary, to_json, RunDiagnosis};
use crate::Result;

/// Arguments of `jdbb diagnose-rotary`.
#[derive(Debug, clap::Args)]
pub struct DiagnoseRotaryArgs {
    /// CSV `angle_deg,<run>_mm,...`: bar-length change per run while the rotary axis turns
    /// (e.g. ../shared/data/dbb_c_turntable_table1.csv).
    #[arg(long)]
    pub samples: PathBuf,
    /// Print JSON instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// Run `jdbb diagnose-rotary`.
pub fn run(args: &DiagnoseRotaryArgs) -> Result<()> {
    let (theta, runs) = read_runs(&args.samples)?;
    let opts = SelectOptions::default();
    let out: Vec<RunDiagnosis> = runs
        .iter()
        .map(|(name, dl)| diagnose_run(name, &theta, dl, &opts))
        .collect::<Result<_>>()?;
    if args.json {
        emit(&json_text(&to_json(&out)))
    } else {
        print(&summary(&out))
    }
}
