//! Calibration parameters of one J-DBB: bar lengths; per encoder its resolution, zero, direction
//! and once-per-turn (eccentricity) error; the frames' geometry (skew between the pivot axes, tilt
//! of each axis, offset of each axis from the joint centre). One serde struct (the error terms
//! default to zero when a file leaves them out, so a calibration file may give only the nominal
//! fields); the device reports
//! the calibration in force in its [`DeviceInfo`](crate::protocol::DeviceInfo) and the host replaces
//! it with [`Command::SetCalibration`](crate::protocol::Command::SetCalibration).
//!
//! What each parameter means geometrically, and the equations that use it, are in
//! [`crate::geometry`] ((G4)–(G9)). Every angle here is in radians; the error angles are small
//! (|·| ≤ [`MAX_ERROR_RAD`]), as instrument errors are: the on-chip arithmetic relies on it.
//!
//! For a least-squares fit of the instrument, [`Param`] names each continuous parameter and
//! [`Calibration::param`] / [`Calibration::set_param`] read and write it;
//! [`crate::geometry::distance_and_gradient`] gives D with its analytic partial derivatives.

use serde::{Deserialize, Serialize};

/// Largest magnitude (rad, ≈ 34′) accepted for each error angle: the fine zero, the eccentricity,
/// the skew, the tilts and the pivot offsets. Real instruments are 10–100× inside it; beyond it a
/// frame is misassembled, not miscalibrated, and the small-angle steps of the on-chip kernel would
/// no longer meet the accuracy budget.
pub const MAX_ERROR_RAD: f64 = 0.01;

/// Shortest bar (mm) a calibration may give: a ball bar's bars are centimetres long, so below
/// 1 mm is a typing or unit error (`1e-300`), not an instrument.
pub const MIN_BAR_MM: f64 = 1.0;

/// A bar length (mm) must be below this: 10 m, longer than any machine tool.
pub const MAX_BAR_MM: f64 = 10_000.0;

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

/// Calibration of one rotary encoder on a decoupling frame: counts → frame angle, eq. (G9) of
/// [`crate::geometry`]:
///
/// ```text
///   θ = s·(c − z)·δ − ζ + e·sin(ψ + φₑ),   δ = 2π/N,   ψ = 2π·(c mod N)/N
/// ```
///
/// c: extended count (referenced to the index, or the absolute encoder's zero); N:
/// [`counts_per_rev`](Self::counts_per_rev); z: [`zero_count`](Self::zero_count); s:
/// [`direction`](Self::direction); ζ: [`zero_offset_rad`](Self::zero_offset_rad); e, φₑ:
/// [`eccentricity_rad`](Self::eccentricity_rad), [`eccentricity_phase_rad`](Self::eccentricity_phase_rad);
/// ψ: the disc's own angle (count 0 at ψ = 0).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
// A misspelled key in a calibration file is an error, not a term silently left at zero.
#[serde(deny_unknown_fields)]
pub struct EncoderCal {
    /// Counts per revolution after decoding (×4 quadrature of an interpolated signal, or the
    /// absolute encoder's resolution), N.
    pub counts_per_rev: u32,
    /// Whole count z at which the frame angle is zero, apart from [`Self::zero_offset_rad`].
    pub zero_count: i64,
    /// Sign s relating count to frame angle.
    pub direction: Direction,
    /// Fine zero ζ (rad): the angle, measured from `zero_count`, that the encoder reads when the
    /// frame is at zero (its slot plane parallel to bar 1). The integer `zero_count` keeps the
    /// large part exact; ζ is the small continuous rest a calibration fits.
    #[serde(default)]
    pub zero_offset_rad: f64,
    /// Amplitude e ≥ 0 (rad) of the once-per-turn error of the reading (disc eccentric to the
    /// frame's pivot: a disc offset ε from the axis at graduation radius R gives e = ε/R).
    #[serde(default)]
    pub eccentricity_rad: f64,
    /// Phase φₑ (rad, within ±2π) of the once-per-turn error, relative to the disc angle ψ.
    #[serde(default)]
    pub eccentricity_phase_rad: f64,
}

impl EncoderCal {
    /// An ideal encoder: `counts_per_rev`, zero at count 0, positive direction, no errors.
    pub const fn ideal(counts_per_rev: u32) -> Self {
        EncoderCal {
            counts_per_rev,
            zero_count: 0,
            direction: Direction::Positive,
            zero_offset_rad: 0.0,
            eccentricity_rad: 0.0,
            eccentricity_phase_rad: 0.0,
        }
    }

    /// Angle of one count step, δ = 2π/N (rad).
    pub fn rad_per_count(&self) -> f64 {
        core::f64::consts::TAU / self.counts_per_rev as f64
    }

    /// The disc's angle ψ ∈ [0, 2π) at an extended count (count 0 at ψ = 0), reduced exactly.
    pub fn disc_angle_rad(&self, count: i64) -> f64 {
        let n = self.counts_per_rev as i64;
        count.rem_euclid(n) as f64 * self.rad_per_count()
    }

    /// Eccentricity as the coefficients (a, b) of e·sin(ψ + φₑ) = a·sin ψ + b·cos ψ, i.e.
    /// a = e·cos φₑ, b = e·sin φₑ: the well-conditioned form for a fit.
    pub fn eccentricity_components(&self) -> (f64, f64) {
        let (s, c) = crate::math::sin_cos(self.eccentricity_phase_rad);
        (self.eccentricity_rad * c, self.eccentricity_rad * s)
    }

    /// Set the eccentricity from its components (a, b) (see [`Self::eccentricity_components`]).
    pub fn set_eccentricity_components(&mut self, a: f64, b: f64) {
        self.eccentricity_rad = libm::hypot(a, b);
        self.eccentricity_phase_rad = crate::math::atan2(b, a);
    }

    /// Frame angle θ (rad) for an extended count, eq. (G9), in f64: the host reference.
    pub fn angle_rad(&self, count: i64) -> f64 {
        let steps = count.wrapping_sub(self.zero_count) * self.direction.sign();
        let mut theta = steps as f64 * self.rad_per_count() - self.zero_offset_rad;
        if self.eccentricity_rad != 0.0 {
            theta += self.eccentricity_rad
                * crate::math::sin(self.disc_angle_rad(count) + self.eccentricity_phase_rad);
        }
        theta
    }

    /// dθ/dc (rad per count) at an extended count: s·δ + e·δ·cos(ψ + φₑ).
    pub fn angle_per_count_rad(&self, count: i64) -> f64 {
        let d = self.rad_per_count();
        let ecc = self.eccentricity_rad
            * crate::math::cos(self.disc_angle_rad(count) + self.eccentricity_phase_rad);
        self.direction.sign() as f64 * d + ecc * d
    }

    /// The real-valued count at which the encoder reads frame angle θ: (G9) solved for c. The
    /// once-per-turn term is resolved by fixed-point iteration, which contracts by e·δ/δ = e per
    /// step (≤ 0.01): five steps reach 1e-10 counts.
    pub fn count_real_for_angle(&self, angle_rad: f64) -> f64 {
        let z = self.zero_count as f64;
        let s = self.direction.sign() as f64;
        let d = self.rad_per_count();
        let base = angle_rad + self.zero_offset_rad;
        let mut c = z + s * base / d;
        if self.eccentricity_rad != 0.0 {
            let n = self.counts_per_rev as f64;
            for _ in 0..5 {
                let turns = c / n - libm::floor(c / n);
                let psi = core::f64::consts::TAU * turns;
                let ecc =
                    self.eccentricity_rad * crate::math::sin(psi + self.eccentricity_phase_rad);
                c = z + s * (base - ecc) / d;
            }
        }
        c
    }

    /// Nearest extended count for a frame angle (rad): the inverse of [`Self::angle_rad`] up to
    /// quantisation; used by simulation.
    pub fn count_for_angle(&self, angle_rad: f64) -> i64 {
        crate::math::round(self.count_real_for_angle(angle_rad)) as i64
    }

    fn validate(&self) -> Result<(), CalibrationError> {
        if self.counts_per_rev < 4 {
            return Err(CalibrationError::Resolution);
        }
        if !small(self.zero_offset_rad) {
            return Err(CalibrationError::ZeroOffset);
        }
        let e = self.eccentricity_rad;
        let phase_ok = libm::fabs(self.eccentricity_phase_rad) <= core::f64::consts::TAU;
        if !(small(e) && e >= 0.0 && phase_ok) {
            return Err(CalibrationError::Eccentricity);
        }
        // The on-chip kernel rotates the reading by ζ and the eccentricity together.
        if libm::fabs(self.zero_offset_rad) + e > MAX_ERROR_RAD {
            return Err(CalibrationError::ZeroOffset);
        }
        Ok(())
    }
}

/// Geometry of one decoupling frame's pivot, see (G4)–(G6) of [`crate::geometry`].
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
// A misspelled key in a calibration file is an error, not a term silently left at zero.
#[serde(deny_unknown_fields)]
pub struct FrameCal {
    /// Tilt τ (rad) of the frame's pivot axis out of the plane normal to bar 1, positive towards
    /// +z (the side of bar 2). Equal tilts of both axes are bar 1 standing crooked in the joint
    /// body.
    #[serde(default)]
    pub tilt_rad: f64,
    /// ν = p·n⁰/r (rad): the pivot axis' offset p from the joint centre along n⁰, the normal of
    /// the frame's slot plane at zero, over the distance r from the joint centre at which the frame
    /// grips bar 2. At zero it moves the slot plane sideways off the joint centre.
    #[serde(default)]
    pub offset_normal_rad: f64,
    /// μ = p·m⁰/r (rad): the same offset along m⁰ = a × n⁰, the in-plane direction perpendicular
    /// to the pivot axis a (m⁰ ≈ +z for frame 1, ≈ −z for frame 2): the axis passes above or
    /// below the joint centre along bar 1.
    #[serde(default)]
    pub offset_axial_rad: f64,
}

impl FrameCal {
    /// A perfect frame.
    pub const IDEAL: FrameCal = FrameCal {
        tilt_rad: 0.0,
        offset_normal_rad: 0.0,
        offset_axial_rad: 0.0,
    };
}

/// Everything the instrument model needs to turn two counts into D.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
// A misspelled key in a calibration file is an error, not a term silently left at zero.
#[serde(deny_unknown_fields)]
pub struct Calibration {
    /// Bar 1: centre of the table ball to the centre of the spherical joint (mm).
    pub l1_mm: f64,
    /// Bar 2: centre of the spherical joint to the centre of the spindle ball (mm).
    pub l2_mm: f64,
    /// Encoder 1, on frame 1, whose pivot axis defines x of bar 1's frame (angle θ₁ = α).
    pub enc1: EncoderCal,
    /// Encoder 2, on frame 2, pivoting about (nearly) y (angle θ₂ = β).
    pub enc2: EncoderCal,
    /// Skew γ (rad): the angle between the two pivot axes, projected on the plane normal to bar 1,
    /// minus 90°. Frame 2's axis is the one rotated (about bar 1); positive γ opens the angle.
    #[serde(default)]
    pub axes_skew_rad: f64,
    /// Frame 1's pivot geometry.
    #[serde(default)]
    pub frame1: FrameCal,
    /// Frame 2's pivot geometry.
    #[serde(default)]
    pub frame2: FrameCal,
}

impl Calibration {
    /// A perfect instrument with bars `l1_mm`, `l2_mm` and two ideal encoders of
    /// `counts_per_rev` each (zero at count 0, positive direction).
    pub const fn nominal(l1_mm: f64, l2_mm: f64, counts_per_rev: u32) -> Self {
        Calibration {
            l1_mm,
            l2_mm,
            enc1: EncoderCal::ideal(counts_per_rev),
            enc2: EncoderCal::ideal(counts_per_rev),
            axes_skew_rad: 0.0,
            frame1: FrameCal::IDEAL,
            frame2: FrameCal::IDEAL,
        }
    }

    /// The default instrument: L1 = L2 = 50 mm (seed 000), two 2²³-count encoders (a 23-bit
    /// absolute encoder, or an interpolated incremental one, see `docs/instrument-model.md`),
    /// zero at count 0, positive direction, no errors. One count moves D by ≤ 0.023 µm over the
    /// working range.
    pub const DEFAULT: Calibration = Calibration::nominal(50.0, 50.0, 1 << 23);

    /// Seed 000's instrument as the paper has it: L = 50 mm bars and 5000-line encoders read ×4
    /// (20 000 counts/rev), zero at count 0. One count moves D by up to 9.6 µm over the working range.
    pub const SEED_000: Calibration = Calibration::nominal(50.0, 50.0, 20_000);

    /// Check the values make physical sense before they are used: lengths positive and finite
    /// below 10 m, at least 4 counts per revolution, every error angle finite and within
    /// ±[`MAX_ERROR_RAD`] (eccentricity amplitude ≥ 0, its phase within ±2π).
    pub fn validate(&self) -> Result<(), CalibrationError> {
        let ok_len = |l: f64| (MIN_BAR_MM..MAX_BAR_MM).contains(&l);
        if !ok_len(self.l1_mm) || !ok_len(self.l2_mm) {
            return Err(CalibrationError::BarLength);
        }
        self.enc1.validate()?;
        self.enc2.validate()?;
        if !small(self.axes_skew_rad) {
            return Err(CalibrationError::AxesSkew);
        }
        for f in [&self.frame1, &self.frame2] {
            if !small(f.tilt_rad) {
                return Err(CalibrationError::Tilt);
            }
            if !(small(f.offset_normal_rad) && small(f.offset_axial_rad)) {
                return Err(CalibrationError::PivotOffset);
            }
        }
        Ok(())
    }

    /// The value of one continuous parameter, in mm (lengths) or rad (angles).
    pub fn param(&self, p: Param) -> f64 {
        match p {
            Param::L1 => self.l1_mm,
            Param::L2 => self.l2_mm,
            Param::Zero1 => self.enc1.zero_offset_rad,
            Param::Zero2 => self.enc2.zero_offset_rad,
            Param::Ecc1Sin => self.enc1.eccentricity_components().0,
            Param::Ecc1Cos => self.enc1.eccentricity_components().1,
            Param::Ecc2Sin => self.enc2.eccentricity_components().0,
            Param::Ecc2Cos => self.enc2.eccentricity_components().1,
            Param::AxesSkew => self.axes_skew_rad,
            Param::Tilt1 => self.frame1.tilt_rad,
            Param::Tilt2 => self.frame2.tilt_rad,
            Param::OffsetNormal1 => self.frame1.offset_normal_rad,
            Param::OffsetAxial1 => self.frame1.offset_axial_rad,
            Param::OffsetNormal2 => self.frame2.offset_normal_rad,
            Param::OffsetAxial2 => self.frame2.offset_axial_rad,
        }
    }

    /// Set one continuous parameter (mm or rad). Eccentricity components are converted to the
    /// stored amplitude and phase.
    pub fn set_param(&mut self, p: Param, value: f64) {
        match p {
            Param::L1 => self.l1_mm = value,
            Param::L2 => self.l2_mm = value,
            Param::Zero1 => self.enc1.zero_offset_rad = value,
            Param::Zero2 => self.enc2.zero_offset_rad = value,
            Param::Ecc1Sin | Param::Ecc1Cos | Param::Ecc2Sin | Param::Ecc2Cos => {
                let enc = match p {
                    Param::Ecc1Sin | Param::Ecc1Cos => &mut self.enc1,
                    _ => &mut self.enc2,
                };
                let (mut a, mut b) = enc.eccentricity_components();
                if matches!(p, Param::Ecc1Sin | Param::Ecc2Sin) {
                    a = value;
                } else {
                    b = value;
                }
                enc.set_eccentricity_components(a, b);
            }
            Param::AxesSkew => self.axes_skew_rad = value,
            Param::Tilt1 => self.frame1.tilt_rad = value,
            Param::Tilt2 => self.frame2.tilt_rad = value,
            Param::OffsetNormal1 => self.frame1.offset_normal_rad = value,
            Param::OffsetAxial1 => self.frame1.offset_axial_rad = value,
            Param::OffsetNormal2 => self.frame2.offset_normal_rad = value,
            Param::OffsetAxial2 => self.frame2.offset_axial_rad = value,
        }
    }

    /// All continuous parameters in [`Param::ALL`] order.
    pub fn params(&self) -> [f64; N_PARAMS] {
        Param::ALL.map(|p| self.param(p))
    }

    /// A copy with all continuous parameters replaced (in [`Param::ALL`] order); the discrete
    /// fields (resolution, zero count, direction) are kept.
    pub fn with_params(&self, values: &[f64; N_PARAMS]) -> Calibration {
        let mut c = *self;
        for (p, v) in Param::ALL.iter().zip(values) {
            c.set_param(*p, *v);
        }
        c
    }
}

impl Default for Calibration {
    fn default() -> Self {
        Self::DEFAULT
    }
}

fn small(x: f64) -> bool {
    x.is_finite() && libm::fabs(x) <= MAX_ERROR_RAD
}

/// Number of continuous instrument parameters, [`Param::ALL`].
pub const N_PARAMS: usize = 15;

/// One continuous parameter of the instrument model, as a least-squares fit addresses it. Values
/// are in mm (lengths) and rad (angles); partial derivatives of D from
/// [`crate::geometry::distance_and_gradient`] are in mm per mm and mm per rad, in [`Param::ALL`]
/// order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Param {
    /// L1 (mm).
    L1,
    /// L2 (mm).
    L2,
    /// Encoder 1's fine zero ζ₁ (rad).
    Zero1,
    /// Encoder 2's fine zero ζ₂ (rad).
    Zero2,
    /// Encoder 1's eccentricity, coefficient a₁ = e₁·cos φ₁ of sin ψ₁ (rad).
    Ecc1Sin,
    /// Encoder 1's eccentricity, coefficient b₁ = e₁·sin φ₁ of cos ψ₁ (rad).
    Ecc1Cos,
    /// Encoder 2's eccentricity, coefficient of sin ψ₂ (rad).
    Ecc2Sin,
    /// Encoder 2's eccentricity, coefficient of cos ψ₂ (rad).
    Ecc2Cos,
    /// Skew γ of the pivot axes (rad).
    AxesSkew,
    /// Tilt τ₁ of frame 1's pivot axis (rad).
    Tilt1,
    /// Tilt τ₂ of frame 2's pivot axis (rad).
    Tilt2,
    /// Frame 1's pivot offset along its slot normal, ν₁ (rad).
    OffsetNormal1,
    /// Frame 1's pivot offset along m₁⁰, μ₁ (rad).
    OffsetAxial1,
    /// Frame 2's pivot offset along its slot normal, ν₂ (rad).
    OffsetNormal2,
    /// Frame 2's pivot offset along m₂⁰, μ₂ (rad).
    OffsetAxial2,
}

impl Param {
    /// Every parameter, in the order of gradients and parameter vectors.
    pub const ALL: [Param; N_PARAMS] = [
        Param::L1,
        Param::L2,
        Param::Zero1,
        Param::Zero2,
        Param::Ecc1Sin,
        Param::Ecc1Cos,
        Param::Ecc2Sin,
        Param::Ecc2Cos,
        Param::AxesSkew,
        Param::Tilt1,
        Param::Tilt2,
        Param::OffsetNormal1,
        Param::OffsetAxial1,
        Param::OffsetNormal2,
        Param::OffsetAxial2,
    ];

    /// Position in [`Param::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// Stable snake_case name (for reports and files).
    pub fn name(self) -> &'static str {
        match self {
            Param::L1 => "l1",
            Param::L2 => "l2",
            Param::Zero1 => "zero_1",
            Param::Zero2 => "zero_2",
            Param::Ecc1Sin => "eccentricity_1_sin",
            Param::Ecc1Cos => "eccentricity_1_cos",
            Param::Ecc2Sin => "eccentricity_2_sin",
            Param::Ecc2Cos => "eccentricity_2_cos",
            Param::AxesSkew => "axes_skew",
            Param::Tilt1 => "tilt_1",
            Param::Tilt2 => "tilt_2",
            Param::OffsetNormal1 => "offset_normal_1",
            Param::OffsetAxial1 => "offset_axial_1",
            Param::OffsetNormal2 => "offset_normal_2",
            Param::OffsetAxial2 => "offset_axial_2",
        }
    }

    /// Whether the parameter is a length (mm) rather than an angle (rad).
    pub fn is_length(self) -> bool {
        matches!(self, Param::L1 | Param::L2)
    }
}

/// Why a [`Calibration`] was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum CalibrationError {
    /// A bar length is not between [`MIN_BAR_MM`] (1 mm) and [`MAX_BAR_MM`] (10 m).
    BarLength,
    /// An encoder has fewer than 4 counts per revolution.
    Resolution,
    /// A fine zero is not finite, or it and the eccentricity together exceed [`MAX_ERROR_RAD`].
    ZeroOffset,
    /// An eccentricity amplitude is negative, not finite or above [`MAX_ERROR_RAD`], or its phase
    /// is not a finite angle within ±2π.
    Eccentricity,
    /// The skew of the pivot axes is not finite or above [`MAX_ERROR_RAD`].
    AxesSkew,
    /// A pivot axis tilt is not finite or above [`MAX_ERROR_RAD`].
    Tilt,
    /// A pivot offset is not finite or above [`MAX_ERROR_RAD`].
    PivotOffset,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_round_trip_and_eccentricity_components() {
        let mut c = Calibration::DEFAULT;
        let values: [f64; N_PARAMS] = core::array::from_fn(|i| {
            if i < 2 {
                40.0 + i as f64
            } else {
                1e-4 * (i as f64 - 7.5)
            }
        });
        c = c.with_params(&values);
        for (p, v) in Param::ALL.iter().zip(values) {
            assert!((c.param(*p) - v).abs() < 1e-18, "{p:?}");
            assert_eq!(p.index(), Param::ALL.iter().position(|q| q == p).unwrap());
        }
        // a sin ψ + b cos ψ = e sin(ψ + φ).
        let (a, b) = c.enc2.eccentricity_components();
        for psi in [0.0, 0.7, 2.0, -1.3] {
            let lhs = a * libm::sin(psi) + b * libm::cos(psi);
            let e = &c.enc2;
            let rhs = e.eccentricity_rad * libm::sin(psi + e.eccentricity_phase_rad);
            assert!((lhs - rhs).abs() < 1e-18);
        }
        assert!(c.enc2.eccentricity_rad > 0.0);
        assert_eq!(c.validate(), Ok(()));
    }

    #[test]
    fn validation_rejects_gross_errors() {
        let ok = Calibration::DEFAULT;
        assert_eq!(ok.validate(), Ok(()));
        let mut c = ok;
        c.l2_mm = -1.0;
        assert_eq!(c.validate(), Err(CalibrationError::BarLength));
        for l in [1e-300, 0.5, 1e4, f64::NAN] {
            let mut c = ok;
            c.l1_mm = l;
            assert_eq!(c.validate(), Err(CalibrationError::BarLength), "{l}");
        }
        let mut c = ok;
        c.enc1.counts_per_rev = 3;
        assert_eq!(c.validate(), Err(CalibrationError::Resolution));
        let mut c = ok;
        c.enc2.zero_offset_rad = f64::NAN;
        assert_eq!(c.validate(), Err(CalibrationError::ZeroOffset));
        let mut c = ok;
        c.enc2.zero_offset_rad = 0.006;
        c.enc2.eccentricity_rad = 0.006;
        assert_eq!(c.validate(), Err(CalibrationError::ZeroOffset));
        let mut c = ok;
        c.enc1.eccentricity_rad = -1e-5;
        assert_eq!(c.validate(), Err(CalibrationError::Eccentricity));
        let mut c = ok;
        c.enc1.eccentricity_phase_rad = 7.0;
        assert_eq!(c.validate(), Err(CalibrationError::Eccentricity));
        let mut c = ok;
        c.axes_skew_rad = 0.02;
        assert_eq!(c.validate(), Err(CalibrationError::AxesSkew));
        let mut c = ok;
        c.frame2.tilt_rad = f64::INFINITY;
        assert_eq!(c.validate(), Err(CalibrationError::Tilt));
        let mut c = ok;
        c.frame1.offset_axial_rad = -0.011;
        assert_eq!(c.validate(), Err(CalibrationError::PivotOffset));
    }

    #[test]
    fn encoder_angle_and_its_inverse() {
        let mut e = EncoderCal::ideal(1 << 23);
        e.zero_count = 5_000_123;
        e.direction = Direction::Negative;
        e.zero_offset_rad = 3e-4;
        e.eccentricity_rad = 2e-4;
        e.eccentricity_phase_rad = 1.1;
        for c in [5_000_123i64, 4_000_000, 6_500_000, -3, 9_000_000] {
            let theta = e.angle_rad(c);
            let back = e.count_real_for_angle(theta);
            assert!((back - c as f64).abs() < 1e-6, "{c}: {back}");
            assert_eq!(e.count_for_angle(theta), c);
            // The derivative matches a central difference over ±1000 counts.
            let fd = (e.angle_rad(c + 1000) - e.angle_rad(c - 1000)) / 2000.0;
            assert!(
                (e.angle_per_count_rad(c) - fd).abs()
                    < 1e-12 * e.rad_per_count().max(fd.abs()) + 1e-15
            );
        }
        // At the zero count the reading is −ζ plus the eccentricity at the disc angle there.
        let psi = e.disc_angle_rad(e.zero_count);
        let expect = -3e-4 + 2e-4 * libm::sin(psi + 1.1);
        assert!((e.angle_rad(e.zero_count) - expect).abs() < 1e-18);
    }
}
