//! `jdbb simulate`: a circular test on a machine with chosen errors, written as the
//! `t_s,x_mm,y_mm,z_mm,d_mm` CSV that `jdbb diagnose --samples` reads; or, with `--plan` and
//! `--machine`, a plan's program run on a machine described in a TOML file and recorded as `jdbb
//! record` records it ([`crate::simulate::record_sim`]), for `jdbb diagnose --record --plan`.
use std::io::Write;
use std::path::PathBuf;

use super::output::{note, print, stdout_result};
use crate::fsio::{check_destination, Staged};
use crate::link::record::{header, write_csv_lines};
use crate::link::stream::SeqSample;
use crate::model::{parse_pitch, Path};
use crate::plan::{Plan, PLAN_ID_KEY};
use crate::simulate::machine::{example, Machine};
use crate::simulate::record_sim::record;
use crate::simulate::{
    distances_mm, measure, nominal_path, parse_effect, parse_plane, write_csv, EffectValue,
    PathSpec,
};
use crate::{Error, Result};

/// Arguments of `jdbb simulate`.
#[derive(Debug, clap::Args)]
pub struct SimulateArgs {
    /// Run this plan's program (the plan.json `jdbb plan` wrote) on the --machine and write what
    /// `jdbb record` would record (`seq,t_us,enc1,enc2,d_mm`), for `jdbb diagnose --record
    /// --plan`. The path options below are then not used.
    #[arg(long, value_name = "PLAN_JSON", requires = "machine", conflicts_with_all = ["radii_mm", "heights_mm", "plane", "feed", "rate", "effects", "pitch", "sigma_um", "resolution_um", "seed"])]
    pub plan: Option<PathBuf>,
    /// The machine of --plan: a TOML file (feed override, acceleration, controller, errors by
    /// the diagnosis's names, the instrument). Without a file: print a commented example.
    #[arg(long, value_name = "MACHINE_TOML", num_args = 0..=1)]
    pub machine: Option<Option<PathBuf>>,
    /// Circle radius in mm (repeat for several radii: the J-DBB's bar length is free).
    #[arg(long = "radius", default_value = "50", value_parser = super::args::positive)]
    pub radii_mm: Vec<f64>,
    /// Height of the circle's plane above the table ball, mm (repeat for several heights).
    #[arg(long = "height", default_value = "0", allow_negative_numbers = true, value_parser = super::args::finite)]
    pub heights_mm: Vec<f64>,
    /// Plane of the circles: xy, yz or zx.
    #[arg(long, default_value = "xy")]
    pub plane: String,
    /// Feed along the circle, mm/min.
    #[arg(long, default_value_t = 1000.0, value_parser = super::args::positive)]
    pub feed: f64,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 500.0, value_parser = super::args::positive)]
    pub rate: f64,
    /// A machine effect, `name=value[@phase_deg]` or `name=p1,p2,..`; repeat. Names as in
    /// `jdbb diagnose` (scale_x, backlash_y, cyclic_x, servo_mismatch_xy, setup_offset, ...).
    #[arg(long = "effect")]
    pub effects: Vec<String>,
    /// Pitch per axis in mm (x=10,y=10), needed by cyclic_k and interference_k.
    #[arg(long)]
    pub pitch: Option<String>,
    /// Gaussian reading noise, µm (1 σ).
    #[arg(long, default_value_t = 0.0, value_parser = super::args::non_negative)]
    pub sigma_um: f64,
    /// Reading resolution, µm (D is rounded to it; 0 = none).
    #[arg(long, default_value_t = 0.0, value_parser = super::args::non_negative)]
    pub resolution_um: f64,
    /// Seed of the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Output CSV (stdout if absent); written whole or not at all. Never replaces a file without
    /// --force.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// Replace --out if it exists (a regular file only; never a link or a device).
    #[arg(long, requires = "out")]
    pub force: bool,
}

/// `jdbb simulate --plan --machine`: the record of the plan's program run on the machine.
fn run_plan(
    args: &SimulateArgs,
    plan_file: &std::path::Path,
    machine_file: &std::path::Path,
) -> Result<()> {
    let plan = Plan::read(plan_file)?;
    let mut machine = Machine::read(machine_file)?;
    if let Some(cal) = &machine.instrument.calibration_file {
        if let Some(out) = &args.out {
            crate::fsio::check_not_input(out, &[("the machine's calibration file", cal)])?;
        }
        machine.instrument.calibration = crate::instrument::file::read_calibration(cal)?;
    }
    if let Some(c) = machine.controller.filter(|c| *c != plan.dialect) {
        note(&format!(
            "warning: the plan's program is written for {}, and {} says its controller is {}: it is run as {} would run it (check the plan's --dialect)",
            plan.dialect.name(),
            machine_file.display(),
            c.name(),
            c.name()
        ));
    }
    let (samples, truth) = record(&plan, &machine)?;
    let mut text = header(&[(PLAN_ID_KEY, plan.id())]).into_bytes();
    // As `jdbb record` writes it: the serial the device reported, before the samples.
    text.extend_from_slice(
        format!(
            "# {}: {}\n",
            crate::table::INSTRUMENT_SERIAL,
            machine.instrument.serial
        )
        .as_bytes(),
    );
    let seq: Vec<SeqSample> = samples
        .iter()
        .enumerate()
        .map(|(k, s)| SeqSample {
            seq: k as u64,
            sample: *s,
        })
        .collect();
    write_csv_lines(&mut text, &seq);
    match &args.out {
        Some(file) => {
            crate::fsio::write_file(file, &text, args.force)?;
            let rate = machine.instrument.sample_rate_hz;
            note(&format!(
                "wrote {}: {} samples at {rate} Hz ({:.1} s) of plan {} on {}; truth: cycle start at t_us {:.0}, program {:.1} s, feed factor {:.6}",
                file.display(),
                samples.len(),
                samples.len() as f64 / rate,
                plan.id(),
                machine.name.as_deref().unwrap_or("the machine"),
                truth.cycle_start_t_us,
                truth.program_s,
                truth.feed_factor
            ));
            Ok(())
        }
        None => super::output::write_stdout(&text),
    }
}

/// Run `jdbb simulate`.
pub fn run(args: &SimulateArgs) -> Result<()> {
    if let Some(file) = &args.out {
        // Before the work: a destination that will be refused is refused at once.
        check_destination(file, args.force)?;
        let mut inputs = vec![];
        inputs.extend(args.plan.iter().map(|p| ("--plan", p.as_path())));
        inputs.extend(
            args.machine
                .iter()
                .flatten()
                .map(|m| ("--machine", m.as_path())),
        );
        crate::fsio::check_not_input(file, &inputs)?;
    }
    match (&args.plan, &args.machine) {
        (_, Some(None)) => return print(&example()),
        (Some(plan), Some(Some(machine))) => return run_plan(args, plan, machine),
        (None, Some(Some(_))) => {
            return Err(Error::Usage(
                "--machine FILE runs a plan: give --plan plan.json too (or --machine alone for an example file)".into(),
            ))
        }
        _ => {}
    }
    let spec = PathSpec {
        radii_mm: args.radii_mm.clone(),
        heights_mm: args.heights_mm.clone(),
        plane: parse_plane(&args.plane)?,
        feed_mm_min: args.feed,
        rate_hz: args.rate,
    };
    spec.validate()?;
    let pitch = match &args.pitch {
        Some(s) => parse_pitch(s)?,
        None => [None; 3],
    };
    let effects: Vec<EffectValue> = args
        .effects
        .iter()
        .map(|s| parse_effect(s))
        .collect::<Result<_>>()?;
    let (t, p) = nominal_path(&spec);
    let path = Path::new(t, p, pitch);
    let mut d = distances_mm(&path, &effects)?;
    measure(&mut d, args.sigma_um, args.resolution_um, args.seed);
    match &args.out {
        Some(file) => {
            let mut w = Staged::create(file, args.force)?;
            write_csv(&mut w, &path, &d).map_err(|source| Error::File {
                action: "cannot write",
                path: file.clone(),
                source,
            })?;
            w.commit()
        }
        None => {
            let mut w = std::io::BufWriter::new(std::io::stdout().lock());
            stdout_result(write_csv(&mut w, &path, &d).and_then(|_| w.flush()))
        }
    }
}
