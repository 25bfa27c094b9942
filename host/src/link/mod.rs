//! The link to the instrument: frames from a serial port (USB CDC or QEMU's pty) decoded into
//! samples with loss, corruption and reset accounting ([`stream`]); the recording CSV and the
//! loop that writes it ([`record`]); the live readout's rate and status line ([`live`]); sending
//! a calibration to the device and reading it back ([`calibration`]).
//!
//! May use: `jdbb_core::protocol` (the one definition of every message), serialport, and
//! `crate::instrument::file::why` (the words for a refused calibration). Knows
//! nothing of what the samples are used for.
pub mod calibration;
pub mod live;
pub mod record;
pub mod stream;
