//! `jdbb calibrate`: arguments and glue to [`crate::instrument`].
use std::path::PathBuf;

use jdbb_core::calib::Calibration;

use super::output::{emit, json_text, print};
use crate::instrument::file::{calibration_toml, read_calibration};
use crate::instrument::fit::{calibrate, Options};
use crate::instrument::report::{summary, to_json};
use crate::instrument::run::calibrate_run_noted;
use crate::instrument::samples::read_samples;
use crate::plan::{Plan, Purpose};
use crate::{Error, Result};

/// Arguments of `jdbb calibrate`.
#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// CSV `enc1,enc2,d_ref_mm`: the encoders' extended counts and the calibrator's reference
    /// ball distance (mm) at each pose.
    #[arg(
        long,
        value_name = "CAL.csv",
        required_unless_present = "record",
        conflicts_with = "record"
    )]
    pub samples: Option<PathBuf>,
    /// Without a calibrator: a `jdbb record` file of the machine running the program of
    /// `--plan` (best `jdbb plan --calibration-test`); the table ball's set-up offset is fitted
    /// alongside and the report says which instrument terms the machine's errors could mimic.
    #[arg(long, value_name = "REC.csv", requires = "plan")]
    pub record: Option<PathBuf>,
    /// The plan.json of the program the machine ran for `--record`.
    #[arg(long, value_name = "PLAN.json", requires = "record")]
    pub plan: Option<PathBuf>,
    /// The nominal calibration (TOML: l1_mm, l2_mm, [enc1], [enc2], …) the fit starts from and
    /// whose discrete fields it keeps; default: the default instrument (50 + 50 mm, 2²³ counts/rev).
    #[arg(long, value_name = "CAL.toml")]
    pub nominal: Option<PathBuf>,
    /// Also search the frames' pivot geometry (tilt_k, offset_normal_k, offset_axial_k); needs
    /// samples over a wide range of both frames.
    #[arg(long)]
    pub extended: bool,
    /// Print the documented JSON instead of the human summary.
    #[arg(long)]
    pub json: bool,
    /// Write the fitted calibration (the nominal fields plus what was fitted) as TOML.
    #[arg(short = 'o', long = "out", value_name = "OUT.toml")]
    pub out: Option<PathBuf>,
    /// Replace --out if it exists (a regular file only; never a link or a device).
    #[arg(long, requires = "out")]
    pub force: bool,
}

/// Run `jdbb calibrate`.
pub fn run(args: &CalibrateArgs) -> Result<()> {
    let nominal = match &args.nominal {
        Some(file) => read_calibration(file)?,
        None => Calibration::DEFAULT,
    };
    let input = match (&args.samples, &args.record) {
        (Some(s), None) => s,
        (None, Some(r)) => r,
        _ => {
            return Err(Error::Usage(
                "give --samples CAL.csv, or --record REC.csv with --plan PLAN.json".into(),
            ))
        }
    };
    if let Some(out) = &args.out {
        let inputs: Vec<(&str, &std::path::Path)> = [
            ("--samples", &args.samples),
            ("--record", &args.record),
            ("--plan", &args.plan),
            ("--nominal", &args.nominal),
        ]
        .into_iter()
        .filter_map(|(o, p)| p.as_deref().map(|p| (o, p)))
        .collect();
        crate::fsio::check_not_input(out, &inputs)?;
        crate::fsio::check_destination(out, args.force)?;
    }
    let opts = Options {
        extended: args.extended,
        ..Options::default()
    };
    let cal = match (&args.record, &args.plan) {
        (Some(rec), Some(plan_file)) => {
            let plan = Plan::read(plan_file)?;
            if plan.purpose != Purpose::CalibrationTest {
                return Err(Error::Usage(format!(
                    "{} is a {} plan: its circles at one ball distance cannot calibrate the instrument, which needs spheres at several distances. Make a calibration test with `jdbb plan --calibration-test ...`, run and record it, then calibrate with that record and plan",
                    plan_file.display(),
                    plan.purpose.name()
                )));
            }
            let (cal, note) = calibrate_run_noted(&plan, rec, &nominal, &opts)?;
            if let Some(n) = note {
                super::output::note(&n);
            }
            cal
        }
        _ => {
            let samples = read_samples(input)?;
            samples.check_against(&nominal)?;
            calibrate(&samples, &nominal, &opts)?
        }
    };
    if let Some(out) = &args.out {
        let header = vec![
            format!(
                "J-DBB calibration fitted by `jdbb calibrate` from {} ({} samples)",
                input.display(),
                cal.samples
            ),
            format!(
                "RMS of d_ref - D: nominal {:.4} um, calibrated {:.4} um; effects: {}",
                cal.baseline_rms_um,
                cal.final_rms_um,
                if cal.effects.is_empty() {
                    "none".to_string()
                } else {
                    cal.effects
                        .iter()
                        .map(|f| f.effect.name())
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ),
        ];
        crate::fsio::write_file(
            out,
            calibration_toml(&cal.calibration, &header).as_bytes(),
            args.force,
        )?;
    }
    if args.json {
        emit(&json_text(&to_json(&cal)))?;
    } else {
        print(&summary(&cal))?;
        if let Some(out) = &args.out {
            emit(&format!("calibration written to {}", out.display()))?;
        }
    }
    Ok(())
}
