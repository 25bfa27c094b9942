//! `jdbb calibration send|show`: arguments and glue to [`crate::link::calibration`].
use std::path::PathBuf;

use jdbb_core::calib::{Calibration, EncoderCal};

use super::output::emit;
use crate::instrument::file::read_calibration;
use crate::instrument::ARCSEC_RAD;
use crate::link::calibration::{self, HANDSHAKE_TIMEOUT, REPLY_TIMEOUT, STORE_REPLY_TIMEOUT};
use crate::link::stream::{describe_info, Stream};
use crate::Result;

/// Arguments of `jdbb calibration`.
#[derive(Debug, clap::Args)]
pub struct CalibrationArgs {
    #[command(subcommand)]
    pub action: Action,
}

/// What to do with the device's calibration.
#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// Write a calibration file to the device and read it back: the device then computes D with
    /// it. Exit 1 if the device refuses it, does not answer, or reports holding anything else.
    Send(SendArgs),
    /// Print the calibration the device computes D with.
    Show(ShowArgs),
}

/// Arguments of `jdbb calibration send`.
#[derive(Debug, clap::Args)]
pub struct SendArgs {
    /// Serial port: a USB CDC device (e.g. /dev/ttyACM0) or QEMU's pty (/dev/pts/N).
    #[arg(long, value_name = "PORT")]
    pub port: String,
    /// The calibration (TOML, as `jdbb calibrate -o` writes it).
    #[arg(long, value_name = "CAL.toml")]
    pub file: PathBuf,
}

/// Arguments of `jdbb calibration show`.
#[derive(Debug, clap::Args)]
pub struct ShowArgs {
    /// Serial port: a USB CDC device (e.g. /dev/ttyACM0) or QEMU's pty (/dev/pts/N).
    #[arg(long, value_name = "PORT")]
    pub port: String,
}

/// Run `jdbb calibration`.
pub fn run(args: &CalibrationArgs) -> Result<()> {
    match &args.action {
        Action::Send(a) => send(a),
        Action::Show(a) => show(a),
    }
}

fn send(args: &SendArgs) -> Result<()> {
    // The file is checked before the port is touched.
    let cal = read_calibration(&args.file)?;
    let mut stream = Stream::open(&args.port)?;
    calibration::connect(&mut stream, HANDSHAKE_TIMEOUT)?;
    let report = calibration::send_calibration(&mut stream, &cal, STORE_REPLY_TIMEOUT)?;
    let mut text = format!(
        "sent {} to {}\ndevice: {}\n",
        args.file.display(),
        args.port,
        describe_info(&report.read_back)
    );
    text.push_str(&describe(&report.read_back.calibration));
    text.push_str("read back: identical\nstored: written to flash and read back equal (kept across power cycles)");
    emit(&text)
}

fn show(args: &ShowArgs) -> Result<()> {
    let mut stream = Stream::open(&args.port)?;
    calibration::connect(&mut stream, HANDSHAKE_TIMEOUT)?;
    let info = calibration::read_calibration(&mut stream, REPLY_TIMEOUT)?;
    let mut text = format!("device: {}\n", describe_info(&info));
    text.push_str(&describe(&info.calibration));
    emit(text.trim_end())
}

/// The calibration, one quantity a line: bars in mm, angles in arcsec (phases in degrees).
pub fn describe(cal: &Calibration) -> String {
    let asec = |rad: f64| rad / ARCSEC_RAD;
    let mut s = format!(
        "L1 {:.6} mm, L2 {:.6} mm\naxes skew {:.3}″\n",
        cal.l1_mm,
        cal.l2_mm,
        asec(cal.axes_skew_rad)
    );
    for (k, e) in [(1, &cal.enc1), (2, &cal.enc2)] {
        let EncoderCal {
            counts_per_rev,
            zero_count,
            direction,
            zero_offset_rad,
            eccentricity_rad,
            eccentricity_phase_rad,
        } = *e;
        s.push_str(&format!(
            "encoder {k}: {counts_per_rev} counts/rev, {direction:?}, zero at count {zero_count} {:+.3}″, eccentricity {:.3}″ at {:.2}°\n",
            asec(zero_offset_rad),
            asec(eccentricity_rad),
            eccentricity_phase_rad.to_degrees()
        ));
    }
    for (k, f) in [(1, &cal.frame1), (2, &cal.frame2)] {
        s.push_str(&format!(
            "frame {k}: tilt {:.3}″, pivot offset normal {:.3}″, axial {:.3}″\n",
            asec(f.tilt_rad),
            asec(f.offset_normal_rad),
            asec(f.offset_axial_rad)
        ));
    }
    s
}
