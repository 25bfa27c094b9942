//! Calibration parameters of one J-DBB: bar lengths and, per encoder, resolution, zero and
//! direction. One serde struct; the device reports the calibration in force in its
//! [`DeviceInfo`](crate::protocol::DeviceInfo) and the host can replace it with
//! [`Command::SetCalibration`](crate::protocol::Command::SetCalibration).

use serde::{Deserialize, Serialize};

/// Direction in which an encoder's count grows relative to the positive frame angle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Direction {
    /// Counts grow with the frame angle.
    Positive,
    /// Counts fall as the frame angle grows.
    Negative,
}

impl Direction {
    /// +1 or −1.
    pub fn sign(self) -> i64 {
        match self {
            Direction::Positive => 1,
            Direction::Negative => -1,
        }
    }
}

/// Calibration of one rotary encoder on a mechanical decoupling frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderCal {
    /// Counts per revolution after ×4 quadrature decoding (e.g. 4 × 5000 lines = 20 000).
    pub counts_per_rev: u32,
    /// Extended count at which the frame angle is zero (the bars are collinear).
    pub zero_count: i64,
    /// Sign relating count to frame angle.
    pub direction: Direction,
}

impl EncoderCal {
    /// Frame angle (rad) for an extended count, in f64 — the host reference.
    pub fn angle_rad(&self, count: i64) -> f64 {
        let steps = (count - self.zero_count) * self.direction.sign();
        steps as f64 * self.rad_per_count()
    }

    /// Angle of one count step (rad).
    pub fn rad_per_count(&self) -> f64 {
        core::f64::consts::TAU / self.counts_per_rev as f64
    }

    /// Nearest extended count for a frame angle (rad): the inverse of [`Self::angle_rad`] up to
    /// quantisation; used by simulation.
    pub fn count_for_angle(&self, angle_rad: f64) -> i64 {
        let steps = crate::math::round(angle_rad / self.rad_per_count()) as i64;
        self.zero_count + steps * self.direction.sign()
    }
}

/// Everything the instrument model needs to turn two counts into D.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Calibration {
    /// Bar 1: centre of the table ball to the centre of the spherical joint (mm).
    pub l1_mm: f64,
    /// Bar 2: centre of the spherical joint to the centre of the spindle ball (mm).
    pub l2_mm: f64,
    /// Encoder 1, on the frame that pivots about the x axis of bar 1's frame (angle α).
    pub enc1: EncoderCal,
    /// Encoder 2, on the frame that pivots about the y axis of bar 1's frame (angle β).
    pub enc2: EncoderCal,
}

impl Calibration {
    /// The default instrument: seed 000's L = 50 mm bars and 5000-line encoders read ×4
    /// (20 000 counts/rev), zero at count 0.
    pub const DEFAULT: Calibration = Calibration {
        l1_mm: 50.0,
        l2_mm: 50.0,
        enc1: EncoderCal {
            counts_per_rev: 20_000,
            zero_count: 0,
            direction: Direction::Positive,
        },
        enc2: EncoderCal {
            counts_per_rev: 20_000,
            zero_count: 0,
            direction: Direction::Positive,
        },
    };

    /// Check the values make physical sense before they are used (lengths positive and finite,
    /// resolution at least 4 counts per revolution).
    pub fn validate(&self) -> Result<(), CalibrationError> {
        let ok_len = |l: f64| l.is_finite() && l > 0.0 && l < 10_000.0;
        if !ok_len(self.l1_mm) || !ok_len(self.l2_mm) {
            return Err(CalibrationError::BarLength);
        }
        if self.enc1.counts_per_rev < 4 || self.enc2.counts_per_rev < 4 {
            return Err(CalibrationError::Resolution);
        }
        Ok(())
    }
}

impl Default for Calibration {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a [`Calibration`] was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CalibrationError {
    /// A bar length is not a finite positive number below 10 m.
    BarLength,
    /// An encoder has fewer than 4 counts per revolution.
    Resolution,
}
