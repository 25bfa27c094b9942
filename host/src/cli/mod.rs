//! The command line: one file per subcommand with its clap arguments and the glue from them to
//! the library, which takes typed input and returns typed results. Only this folder prints.
//!
//! - [`devices`], [`live`], [`record`]: the instrument link ([`crate::link`]);
//! - [`plan`], [`simulate`], [`diagnose`]: circular tests ([`crate::plan`], [`crate::simulate`], [`crate::diagnose`]);
//! - [`compensate`], [`history`]: acting on a diagnosis ([`crate::compensate`],
//!   [`crate::history`]);
//! - [`rotary`], [`diagnose_rotary`]: rotary axes ([`crate::rotary`]);
//! - [`rrsps`]: the A/C table as an RRSPS linkage ([`crate::rrsps`]);
//! - [`calibrate`], [`recompute`]: the instrument's own calibration ([`crate::instrument`]);
//!   [`calibration`]: the calibration on the device ([`crate::link::calibration`]);
//! - [`volumetric`]: the printout of `jdbb plan --volumetric` ([`crate::volumetric`]);
//! - [`args`], [`output`], [`stream_args`]: what the subcommands share.
use clap::{Parser, Subcommand};

use crate::Result;

pub mod args;
pub mod calibrate;
pub mod calibration;
pub mod compensate;
pub mod devices;
pub mod diagnose;
pub mod diagnose_rotary;
pub mod history;
pub mod live;
pub mod output;
pub mod plan;
pub mod recompute;
pub mod record;
pub mod rotary;
pub mod rrsps;
pub mod simulate;
pub mod stream_args;
pub mod volumetric;

/// J-DBB double ball bar: live readout, recording, simulation and diagnosis of machine-tool errors.
#[derive(Debug, Parser)]
#[command(name = "jdbb", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// List the serial ports the system knows (USB CDC devices; ptys such as QEMU's are not
    /// listed: pass them to --port).
    Devices,
    /// Show live D (mm, to 0.1 µm), sample rate and dropped/corrupt frame counts.
    Live(live::LiveArgs),
    /// Record samples to CSV `seq,t_us,enc1,enc2,d_mm`, flushed as it goes.
    Record(record::RecordArgs),
    /// A/C two-axis table as an RRSPS linkage (seed 004): motion design, simulation, identification.
    Rrsps(rrsps::RrspsArgs),
    /// Six geometric errors of a C turntable or B swinging head from DBB runs (seed 002).
    Rotary(rotary::RotaryArgs),
    /// Write the program a ballbar test runs (G-code for linuxcnc, grbl, fanuc or marlin) and
    /// its plan.json; print where to put the table ball and mount the instrument.
    Plan(plan::PlanArgs),
    /// Simulate a circular test (ccw then cw circles) on a machine with chosen errors → CSV; or,
    /// with --plan and --machine, the record of a plan's program on a machine.
    Simulate(simulate::SimulateArgs),
    /// Diagnose a circular test: which machine errors, how large, how sure; polar plot report.
    Diagnose(diagnose::DiagnoseArgs),
    /// Diagnose angle-indexed DBB runs of a rotary axis (ideal table: ΔL = 0), e.g. seed 002 data.
    DiagnoseRotary(diagnose_rotary::DiagnoseRotaryArgs),
    /// What to enter into a CNC controller (LinuxCNC, grblHAL, Marlin, Klipper) for a diagnosis.
    Compensate(compensate::CompensateArgs),
    /// A machine's diagnoses over time: add, list, trend (one SQLite file).
    History(history::HistoryArgs),
    /// Calibrate the instrument from a calibrator's samples `enc1,enc2,d_ref_mm`: which of its
    /// own errors (bar lengths, encoder zeros, axes skew, disc eccentricity) and how large.
    Calibrate(calibrate::CalibrateArgs),
    /// A record with d_mm recomputed from enc1, enc2 with another calibration.
    Recompute(recompute::RecomputeArgs),
    /// The calibration on the device: send a calibration file and read it back, or show it.
    Calibration(calibration::CalibrationArgs),
}

/// Run one parsed command line (see the Ctrl-C note in its body).
pub fn run(cli: Cli) -> Result<()> {
    // A write past `ulimit -f` is an error (the output as it was), not a silent SIGXFSZ death.
    crate::fsio::fail_writes_past_size_limit();
    // Ctrl-C (SIGTERM, SIGHUP) ends every command that computes or writes files at once, with
    // nothing half-written left; the commands that talk to a device end their session cleanly
    // with their own handler instead (a summary, Stop sent).
    if !matches!(
        cli.command,
        Command::Live(_) | Command::Record(_) | Command::Calibration(_)
    ) {
        crate::fsio::exit_on_interrupt();
    }
    match cli.command {
        Command::Devices => devices::run(),
        Command::Live(args) => live::run(&args),
        Command::Record(args) => record::run(&args),
        Command::Rrsps(args) => rrsps::run(&args),
        Command::Rotary(args) => rotary::run(&args),
        Command::Plan(args) => plan::run(&args),
        Command::Simulate(args) => simulate::run(&args),
        Command::Diagnose(args) => diagnose::run(&args),
        Command::DiagnoseRotary(args) => diagnose_rotary::run(&args),
        Command::Compensate(args) => compensate::run(&args),
        Command::History(args) => history::run(&args),
        Command::Calibrate(args) => calibrate::run(&args),
        Command::Recompute(args) => recompute::run(&args),
        Command::Calibration(args) => calibration::run(&args),
    }
}
