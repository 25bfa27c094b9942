//! `jdbb recompute`: arguments and glue to [`crate::instrument::recompute`].
use std::path::PathBuf;

use super::output::emit;
use crate::instrument::file::read_calibration;
use crate::instrument::recompute::recompute;
use crate::Result;

/// Arguments of `jdbb recompute`.
#[derive(Debug, clap::Args)]
pub struct RecomputeArgs {
    /// A `jdbb record` file (`seq,t_us,enc1,enc2,d_mm`).
    #[arg(long, value_name = "REC.csv")]
    pub record: PathBuf,
    /// The calibration to evaluate it with (TOML, e.g. from `jdbb calibrate -o`).
    #[arg(long, value_name = "CAL.toml")]
    pub calibration: PathBuf,
    /// The new record: the same file with `d_mm` recomputed (must not be the record itself).
    #[arg(short = 'o', long = "out", value_name = "OUT.csv")]
    pub out: PathBuf,
    /// Replace --out if it exists (a regular file only; never a link or a device).
    #[arg(long)]
    pub force: bool,
}

/// Run `jdbb recompute`.
pub fn run(args: &RecomputeArgs) -> Result<()> {
    crate::fsio::check_not_input(&args.out, &[("--calibration", args.calibration.as_path())])?;
    let cal = read_calibration(&args.calibration)?;
    let rows = recompute(&args.record, &cal, &args.out, args.force)?;
    emit(&format!(
        "{rows} samples: d_mm recomputed with {}, written to {}",
        args.calibration.display(),
        args.out.display()
    ))
}
