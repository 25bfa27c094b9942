//! Command-line interface. Each subcommand's arguments and `run` live in the module of its concern;
//! this file only lists them.
use clap::{Parser, Subcommand};

use crate::Result;

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
    /// List serial ports (USB CDC devices, and ptys such as QEMU's when given explicitly).
    Devices,
    /// Show live D (mm, to 0.1 µm), sample rate and dropped/corrupt frame counts.
    Live(crate::live::LiveArgs),
    /// Record samples to CSV `seq,t_us,enc1,enc2,d_mm`, flushed as it goes.
    Record(crate::record::RecordArgs),
    /// A/C two-axis table as an RRSPS linkage (seed 004): motion design, simulation, identification.
    Rrsps(crate::rrsps::cmd::RrspsArgs),
    /// Six geometric errors of a C turntable or B swinging head from DBB runs (seed 002).
    Rotary(crate::rotary::RotaryArgs),
    /// Simulate a circular test (ccw then cw circles) on a machine with chosen errors → CSV.
    Simulate(crate::simulate::SimulateArgs),
    /// Diagnose a circular test: which machine errors, how large, how sure; polar plot report.
    Diagnose(crate::diagnose::DiagnoseArgs),
    /// Diagnose angle-indexed DBB runs of a rotary axis (ideal table: ΔL = 0), e.g. seed 002 data.
    DiagnoseRotary(crate::diagnose::rotary::DiagnoseRotaryArgs),
}

/// Run one parsed command line.
pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Devices => crate::stream::devices(),
        Command::Live(args) => crate::live::live(&args),
        Command::Record(args) => crate::record::record(&args),
        Command::Rrsps(args) => crate::rrsps::cmd::run(&args),
        Command::Rotary(args) => crate::rotary::run(&args),
        Command::Simulate(args) => crate::simulate::run(&args),
        Command::Diagnose(args) => crate::diagnose::run(&args),
        Command::DiagnoseRotary(args) => crate::diagnose::rotary::run(&args),
    }
}
