//! `jdbb rotary`: seed 002's six geometric errors of a rotary axis; arguments and glue to
//! [`crate::rotary::six_errors`].
use std::path::PathBuf;

use serde_json::json;

use super::output::{emit, json_text};
use crate::rotary::six_errors::{
    analyse, centring, harmonics, max_order, read_table, report_text, without_setup, Axis, Geometry,
};
use crate::{Error, Result};

/// `jdbb rotary` arguments.
#[derive(Debug, clap::Args)]
pub struct RotaryArgs {
    /// Which axis the table measures.
    #[arg(long, value_enum, ignore_case = true)]
    pub axis: Axis,
    /// Runs table: `angle_deg,dl1_radial_mm,...` (e.g. dbb_c_turntable_table1.csv).
    #[arg(long, value_name = "FILE")]
    pub table: PathBuf,
    /// Distance L1 (mm) of the ball from the axis in combination 1 (and 3).
    #[arg(long = "l1", value_name = "MM", value_parser = super::args::length_mm)]
    pub l1_mm: Option<f64>,
    /// Distance L2 (mm) in combination 2.
    #[arg(long = "l2", value_name = "MM", value_parser = super::args::length_mm)]
    pub l2_mm: Option<f64>,
    /// Height H1 (mm) of the ball along the axis in combinations 1 and 2 (B default: 0).
    #[arg(long = "h1", value_name = "MM", value_parser = super::args::length_mm)]
    pub h1_mm: Option<f64>,
    /// Height H3 (mm) in combination 3 (C only).
    #[arg(long = "h3", value_name = "MM", value_parser = super::args::length_mm)]
    pub h3_mm: Option<f64>,
    /// Sense of rotation of the data relative to eq. (6): `auto` picks, for C, the sense in which
    /// one centre offset explains the once-per-revolution terms of all runs.
    #[arg(long, value_enum, ignore_case = true, default_value_t = Sense::Auto)]
    pub sense: Sense,
    /// Remove each run's mean and once-per-revolution term (set-up: bar zero and centring) before
    /// identifying, as the paper's few-µm results imply was done (meant for full-turn C data).
    #[arg(long)]
    pub remove_setup: bool,
    /// Order of the Fourier series of each error in the all-runs fit.
    #[arg(long, default_value_t = 2)]
    pub order: usize,
    /// Machine-readable output.
    #[arg(long)]
    pub json: bool,
}

/// Sense of rotation of the table's angles relative to the paper's matrices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Sense {
    Auto,
    AsPrinted,
    Reversed,
}

/// Run `jdbb rotary`.
pub fn run(args: &RotaryArgs) -> Result<()> {
    let table = read_table(&args.table)?;
    if args.order > max_order(&table) {
        return Err(Error::Usage(format!(
            "--order {}: {} has {} distinct angles, which determine a Fourier series up to order {} (2·order + 1 coefficients per error)",
            args.order,
            args.table.display(),
            crate::rotary::six_errors::distinct_angles(&table.angles_deg),
            max_order(&table)
        )));
    }
    let reversed = match args.sense {
        Sense::AsPrinted => false,
        Sense::Reversed => true,
        Sense::Auto => {
            args.axis == Axis::C
                && centring(&harmonics(&table), &table).is_some_and(|c| c.sense < 0.0)
        }
    };
    let g = Geometry {
        l1_mm: args.l1_mm,
        l2_mm: args.l2_mm,
        // The paper's B model has the ball on the spindle axis (H = 0) unless told otherwise.
        h1_mm: args.h1_mm.or(if args.axis == Axis::B {
            Some(0.0)
        } else {
            None
        }),
        h3_mm: args.h3_mm,
        reversed,
    };
    let mut report = if args.remove_setup {
        analyse(args.axis, &without_setup(&table), &g, args.order)?
    } else {
        analyse(args.axis, &table, &g, args.order)?
    };
    report["setup_removed"] = json!(args.remove_setup);
    if args.remove_setup {
        // Harmonics and centring describe the data as measured.
        let raw = analyse(args.axis, &table, &Geometry::default(), args.order)?;
        report["harmonics"] = raw["harmonics"].clone();
        if let Some(c) = raw.get("centring") {
            report["centring"] = c.clone();
        }
    }
    let text = if args.json {
        json_text(&report)
    } else {
        report_text(&report)
    };
    emit(&text)
}
