//! The device's calibration: send one ([`send_calibration`]) and read back what the device holds
//! ([`read_calibration`]), with a field-by-field comparison ([`differences`]).
//!
//! The calibration travels as postcard, which carries every `f64` as its 8 bytes, so what the
//! device reports must be *bit for bit* what was sent; anything else is a fault of the link or
//! of the firmware, not rounding.
use std::io::{Read, Write};
use std::time::Duration;

use jdbb_core::calib::{Calibration, EncoderCal, FrameCal};
use jdbb_core::protocol::{CalKept, Command, CommandError, DeviceInfo};

use super::stream::Stream;
use crate::instrument::file::why;
use crate::{Error, Result};

/// How long the device has to answer a ping before a calibration command (a QEMU pty drops
/// output until QEMU notices the open; a USB device may still be enumerating).
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(5);

/// How long the device has to answer `GetInfo`: a reply takes milliseconds, but a command that
/// arrives while the device erases its calibration store's spare block ahead (which it starts only
/// after the link has been quiet, and which stalls the CPU for up to 4 s, DS10314) is answered
/// after it. The wait covers that erase, so it delays a reply but never fails one.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

/// How long the device has to answer `SetCalibration`: [`REPLY_TIMEOUT`] (which covers an erase
/// ahead under way when the command came) plus the worst case of
/// keeping the calibration in flash, a 128 KiB sector erase of the STM32F411 (4 s max, DS10314's
/// "Flash memory programming" table at x8 parallelism, which the firmware uses) and one record
/// written (~110 bytes at 100 µs max each). The firmware erases ahead, so a store rarely erases;
/// when it does, the reply comes after the erase, and a shorter wait would report a failed send
/// of a calibration that was kept.
pub const STORE_REPLY_TIMEOUT: Duration = Duration::from_secs(10);

/// What the device said after [`send_calibration`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SendReport {
    /// The device's answer to `SetCalibration`.
    pub reply: DeviceInfo,
    /// Its answer to the `GetInfo` sent after: the calibration in force, read afresh.
    pub read_back: DeviceInfo,
}

/// Wait for the device to answer a ping; [`Error::NoReply`] if it does not within `timeout`.
pub fn connect<P: Read + Write>(stream: &mut Stream<P>, timeout: Duration) -> Result<()> {
    if stream.handshake(timeout)? {
        Ok(())
    } else {
        Err(Error::NoReply {
            port: stream.name().to_string(),
            command: "Ping",
            seconds: timeout.as_secs_f64(),
        })
    }
}

/// Send `cal` (checked with [`Calibration::validate`] first) and read it back: the device's
/// answer to `SetCalibration` and a fresh `GetInfo` must both report `cal` bit for bit, and the
/// answer must say the device stored it ([`CalKept::Stored`]: written to flash and read back
/// equal).
///
/// Errors: [`Error::CommandRefused`] naming the reason when the device refuses it,
/// [`Error::NoReply`] when it does not answer within `timeout`, [`Error::ReadBackMismatch`]
/// listing the fields that differ, [`Error::NotStored`] when the calibration is in force but was
/// not kept (with the device's reason). Call [`connect`] first.
pub fn send_calibration<P: Read + Write>(
    stream: &mut Stream<P>,
    cal: &Calibration,
    timeout: Duration,
) -> Result<SendReport> {
    cal.validate().map_err(|e| {
        Error::Usage(format!(
            "the calibration is not valid, so it was not sent: {}",
            why(e)
        ))
    })?;
    let reply = answer(stream, &Command::SetCalibration(*cal), timeout)?;
    check_same(stream, cal, &reply.calibration)?;
    if reply.calibration_kept != CalKept::Stored {
        return Err(Error::NotStored {
            port: stream.name().to_string(),
            reason: kept_reason(reply.calibration_kept).into(),
        });
    }
    let read_back = answer(stream, &Command::GetInfo, timeout)?;
    check_same(stream, cal, &read_back.calibration)?;
    Ok(SendReport { reply, read_back })
}

/// Words for what became of the last calibration sent ([`DeviceInfo::calibration_kept`]).
pub fn kept_reason(kept: CalKept) -> &'static str {
    match kept {
        CalKept::NotSent => "no calibration was sent since the device started",
        CalKept::Stored => "stored in flash and read back equal",
        CalKept::NoRoom => "the device has no room in flash for it (an STM32F411xC has no sectors 6 and 7)",
        CalKept::EraseFailed => "erasing the flash sector failed",
        CalKept::WriteFailed => {
            "programming the flash failed (the flash reported an error: write protection, or a programming error)"
        }
        CalKept::ReadBackDiffers => {
            "the flash was written without an error but reads back different (worn or failing flash)"
        }
    }
}

/// The device's description of itself, with the calibration in force. Call [`connect`] first.
pub fn read_calibration<P: Read + Write>(
    stream: &mut Stream<P>,
    timeout: Duration,
) -> Result<DeviceInfo> {
    answer(stream, &Command::GetInfo, timeout)
}

/// Send `command`; the device's Info, or [`Error::CommandRefused`] / [`Error::NoReply`].
fn answer<P: Read + Write>(
    stream: &mut Stream<P>,
    command: &Command,
    timeout: Duration,
) -> Result<DeviceInfo> {
    stream
        .request(command, timeout)?
        .map_err(|e| Error::CommandRefused {
            port: stream.name().to_string(),
            command: super::stream::command_name(command),
            reason: refusal(e),
        })
}

fn check_same<P>(stream: &Stream<P>, sent: &Calibration, got: &Calibration) -> Result<()> {
    let diff = differences(sent, got);
    if diff.is_empty() {
        Ok(())
    } else {
        Err(Error::ReadBackMismatch {
            port: stream.name().to_string(),
            differences: diff.join(", "),
        })
    }
}

/// Words for a refusal.
pub fn refusal(e: CommandError) -> String {
    match e {
        CommandError::BadCalibration(c) => format!("bad calibration: {}", why(c)),
        CommandError::SampleRateOutOfRange => "sample rate out of range".into(),
        CommandError::Malformed => {
            "the device could not decode the command (another protocol version?)".into()
        }
        other => format!("{other:?}"),
    }
}

/// The fields in which `got` differs from `sent`, each as `name: sent X, device Y`; empty when
/// they are identical (every `f64` compared bit for bit).
pub fn differences(sent: &Calibration, got: &Calibration) -> Vec<String> {
    let mut out = Vec::new();
    let mut f = |name: &str, a: f64, b: f64| {
        if a.to_bits() != b.to_bits() {
            out.push(format!("{name}: sent {a:e}, device {b:e}"));
        }
    };
    f("l1_mm", sent.l1_mm, got.l1_mm);
    f("l2_mm", sent.l2_mm, got.l2_mm);
    f("axes_skew_rad", sent.axes_skew_rad, got.axes_skew_rad);
    for (k, a, b) in [
        (1, &sent.frame1, &got.frame1),
        (2, &sent.frame2, &got.frame2),
    ] {
        let FrameCal {
            tilt_rad,
            offset_normal_rad,
            offset_axial_rad,
        } = *a;
        f(&format!("frame{k}.tilt_rad"), tilt_rad, b.tilt_rad);
        f(
            &format!("frame{k}.offset_normal_rad"),
            offset_normal_rad,
            b.offset_normal_rad,
        );
        f(
            &format!("frame{k}.offset_axial_rad"),
            offset_axial_rad,
            b.offset_axial_rad,
        );
    }
    for (k, a, b) in [(1, &sent.enc1, &got.enc1), (2, &sent.enc2, &got.enc2)] {
        let EncoderCal {
            counts_per_rev,
            zero_count,
            direction,
            zero_offset_rad,
            eccentricity_rad,
            eccentricity_phase_rad,
        } = *a;
        if counts_per_rev != b.counts_per_rev {
            out.push(format!(
                "enc{k}.counts_per_rev: sent {counts_per_rev}, device {}",
                b.counts_per_rev
            ));
        }
        if zero_count != b.zero_count {
            out.push(format!(
                "enc{k}.zero_count: sent {zero_count}, device {}",
                b.zero_count
            ));
        }
        if direction != b.direction {
            out.push(format!(
                "enc{k}.direction: sent {direction:?}, device {:?}",
                b.direction
            ));
        }
        let mut f = |name: &str, a: f64, b: f64| {
            if a.to_bits() != b.to_bits() {
                out.push(format!("enc{k}.{name}: sent {a:e}, device {b:e}"));
            }
        };
        f("zero_offset_rad", zero_offset_rad, b.zero_offset_rad);
        f("eccentricity_rad", eccentricity_rad, b.eccentricity_rad);
        f(
            "eccentricity_phase_rad",
            eccentricity_phase_rad,
            b.eccentricity_phase_rad,
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_field_is_compared() {
        let a = Calibration::DEFAULT;
        assert!(differences(&a, &a).is_empty());
        let mut b = a;
        b.l1_mm = f64::from_bits(a.l1_mm.to_bits() + 1); // one ulp
        b.enc2.zero_count = 7;
        b.enc1.eccentricity_phase_rad = 0.5;
        b.frame2.offset_axial_rad = 1e-5;
        b.axes_skew_rad = -0.0; // equal as a number, not the same bits
        let d = differences(&a, &b);
        let names: Vec<&str> = d.iter().map(|s| s.split(':').next().unwrap()).collect();
        assert_eq!(
            names,
            [
                "l1_mm",
                "axes_skew_rad",
                "frame2.offset_axial_rad",
                "enc1.eccentricity_phase_rad",
                "enc2.zero_count"
            ],
            "{d:?}"
        );
    }
}
