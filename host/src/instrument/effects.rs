//! The instrument effects a calibration can name, in the units it reports them (µm for lengths,
//! arcsec for angles), and how each one's parameters map onto the continuous parameters of
//! `jdbb_core::calib::Calibration` ([`Param`], mm and rad).
//!
//! Every fit parameter is a *change from the nominal calibration*: the fit starts at the nominal
//! instrument, and an effect that is not named leaves its parameters there.
use jdbb_core::calib::Param;

use super::ARCSEC_RAD;

/// One named instrument effect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Effect {
    /// L1 + L2 (µm), each bar changed by half: with equal nominal bars D is symmetric in L1 and
    /// L2 and only the sum is identifiable.
    LengthSum,
    /// L1 (µm), when the nominal bars differ.
    LengthL1,
    /// L2 (µm), when the nominal bars differ.
    LengthL2,
    /// Encoder 1's fine zero ζ₁ (arcsec).
    Zero1,
    /// Encoder 2's fine zero ζ₂ (arcsec).
    Zero2,
    /// Skew γ of the pivot axes: their angle minus 90° (arcsec).
    AxesSkew,
    /// Encoder 1's once-per-turn error (arcsec amplitude; components and phase in its params).
    Eccentricity1,
    /// Encoder 2's once-per-turn error.
    Eccentricity2,
    /// Tilt τ₁ of frame 1's pivot axis (arcsec; `--extended`).
    Tilt1,
    /// Tilt τ₂ of frame 2's pivot axis (arcsec; `--extended`).
    Tilt2,
    /// Frame 1's pivot offset along its slot normal, ν₁ (arcsec: offset over grip radius).
    OffsetNormal1,
    /// Frame 2's pivot offset along its slot normal, ν₂.
    OffsetNormal2,
    /// Frame 1's pivot offset along the bar, μ₁.
    OffsetAxial1,
    /// Frame 2's pivot offset along the bar, μ₂.
    OffsetAxial2,
}

impl Effect {
    /// The effects a calibration always searches (one of the length forms, see
    /// [`Self::lengths`]).
    pub const BASIC: [Effect; 5] = [
        Effect::Zero1,
        Effect::Zero2,
        Effect::AxesSkew,
        Effect::Eccentricity1,
        Effect::Eccentricity2,
    ];

    /// The frames' pivot geometry, searched with `--extended`.
    pub const EXTENDED: [Effect; 6] = [
        Effect::Tilt1,
        Effect::Tilt2,
        Effect::OffsetNormal1,
        Effect::OffsetNormal2,
        Effect::OffsetAxial1,
        Effect::OffsetAxial2,
    ];

    /// The length effects: the sum when the bars cannot be told apart, else each bar.
    pub fn lengths(bars_confounded: bool) -> Vec<Effect> {
        if bars_confounded {
            vec![Effect::LengthSum]
        } else {
            vec![Effect::LengthL1, Effect::LengthL2]
        }
    }

    /// Stable snake_case name (reports, JSON).
    pub fn name(self) -> &'static str {
        match self {
            Effect::LengthSum => "length_sum",
            Effect::LengthL1 => "length_l1",
            Effect::LengthL2 => "length_l2",
            Effect::Zero1 => "zero_1",
            Effect::Zero2 => "zero_2",
            Effect::AxesSkew => "axes_skew",
            Effect::Eccentricity1 => "eccentricity_1",
            Effect::Eccentricity2 => "eccentricity_2",
            Effect::Tilt1 => "tilt_1",
            Effect::Tilt2 => "tilt_2",
            Effect::OffsetNormal1 => "offset_normal_1",
            Effect::OffsetNormal2 => "offset_normal_2",
            Effect::OffsetAxial1 => "offset_axial_1",
            Effect::OffsetAxial2 => "offset_axial_2",
        }
    }

    /// ASCII unit of the value (`um` or `arcsec`).
    pub fn unit(self) -> &'static str {
        if self.is_length() {
            "um"
        } else {
            "arcsec"
        }
    }

    /// Whether the effect is a bar length (µm) rather than an angle (arcsec).
    pub fn is_length(self) -> bool {
        matches!(
            self,
            Effect::LengthSum | Effect::LengthL1 | Effect::LengthL2
        )
    }

    /// Number of fit parameters (columns of the linear search).
    pub fn n_cols(self) -> usize {
        match self {
            Effect::Eccentricity1 | Effect::Eccentricity2 => 2,
            _ => 1,
        }
    }

    /// Names of the reported parameters: the fit parameters, then (eccentricity) the phase.
    pub fn param_names(self) -> &'static [&'static str] {
        match self {
            Effect::Eccentricity1 | Effect::Eccentricity2 => {
                &["sin_arcsec", "cos_arcsec", "phase_deg"]
            }
            e if e.is_length() => &["delta_um"],
            _ => &["delta_arcsec"],
        }
    }

    /// How fit parameter `k` of the effect changes the core parameters: (parameter, its change
    /// in mm or rad per µm or arcsec of the fit parameter).
    pub fn targets(self, k: usize) -> &'static [(Param, f64)] {
        const UM: f64 = 1e-3;
        const AS: f64 = ARCSEC_RAD;
        match (self, k) {
            (Effect::LengthSum, _) => &[(Param::L1, 0.5 * UM), (Param::L2, 0.5 * UM)],
            (Effect::LengthL1, _) => &[(Param::L1, UM)],
            (Effect::LengthL2, _) => &[(Param::L2, UM)],
            (Effect::Zero1, _) => &[(Param::Zero1, AS)],
            (Effect::Zero2, _) => &[(Param::Zero2, AS)],
            (Effect::AxesSkew, _) => &[(Param::AxesSkew, AS)],
            (Effect::Eccentricity1, 0) => &[(Param::Ecc1Sin, AS)],
            (Effect::Eccentricity1, _) => &[(Param::Ecc1Cos, AS)],
            (Effect::Eccentricity2, 0) => &[(Param::Ecc2Sin, AS)],
            (Effect::Eccentricity2, _) => &[(Param::Ecc2Cos, AS)],
            (Effect::Tilt1, _) => &[(Param::Tilt1, AS)],
            (Effect::Tilt2, _) => &[(Param::Tilt2, AS)],
            (Effect::OffsetNormal1, _) => &[(Param::OffsetNormal1, AS)],
            (Effect::OffsetNormal2, _) => &[(Param::OffsetNormal2, AS)],
            (Effect::OffsetAxial1, _) => &[(Param::OffsetAxial1, AS)],
            (Effect::OffsetAxial2, _) => &[(Param::OffsetAxial2, AS)],
        }
    }

    /// The reported value and its standard error (delta method) from the fit parameters and
    /// their covariance: the parameter itself, or for an eccentricity the amplitude √(a² + b²).
    pub fn value(self, params: &[f64], cov: &[[f64; 2]; 2]) -> (f64, f64) {
        if self.n_cols() == 2 {
            let (a, b) = (params[0], params[1]);
            let e = a.hypot(b);
            let g = if e > 0.0 { [a / e, b / e] } else { [1.0, 0.0] };
            (e, quad(&g, cov).sqrt())
        } else {
            (params[0], cov[0][0].max(0.0).sqrt())
        }
    }

    /// The eccentricity's phase φₑ (degrees) and its standard error, for
    /// e·sin(ψ + φₑ) = a·sin ψ + b·cos ψ: φₑ = atan2(b, a).
    pub fn phase_deg(params: &[f64], cov: &[[f64; 2]; 2]) -> (f64, f64) {
        let (a, b) = (params[0], params[1]);
        let e2 = a * a + b * b;
        let g = if e2 > 0.0 {
            [-b / e2, a / e2]
        } else {
            [0.0, 0.0]
        };
        (b.atan2(a).to_degrees(), quad(&g, cov).sqrt().to_degrees())
    }

    /// The physical cause in words (for reports).
    pub fn cause(self) -> &'static str {
        match self {
            Effect::LengthSum => "bar lengths L1 + L2 differ from the nominal (only their sum acts on D with equal bars)",
            Effect::LengthL1 => "bar 1 (table ball to joint centre) differs from its nominal length",
            Effect::LengthL2 => "bar 2 (joint centre to spindle ball) differs from its nominal length",
            Effect::Zero1 => "encoder 1 does not read zero with the bars collinear (fine zero)",
            Effect::Zero2 => "encoder 2 does not read zero with the bars collinear (fine zero)",
            Effect::AxesSkew => "the frames' pivot axes are not perpendicular (angle between them minus 90°)",
            Effect::Eccentricity1 => "encoder 1's disc is off centre on its axis: a once-per-turn reading error",
            Effect::Eccentricity2 => "encoder 2's disc is off centre on its axis: a once-per-turn reading error",
            Effect::Tilt1 => "frame 1's pivot axis tilts out of the plane normal to bar 1",
            Effect::Tilt2 => "frame 2's pivot axis tilts out of the plane normal to bar 1",
            Effect::OffsetNormal1 => "frame 1's pivot axis misses the joint centre along the slot normal",
            Effect::OffsetNormal2 => "frame 2's pivot axis misses the joint centre along the slot normal",
            Effect::OffsetAxial1 => "frame 1's pivot axis passes above or below the joint centre along bar 1",
            Effect::OffsetAxial2 => "frame 2's pivot axis passes above or below the joint centre along bar 1",
        }
    }
}

/// gᵀ C g for a 2-vector.
fn quad(g: &[f64; 2], c: &[[f64; 2]; 2]) -> f64 {
    (g[0] * g[0] * c[0][0] + 2.0 * g[0] * g[1] * c[0][1] + g[1] * g[1] * c[1][1]).max(0.0)
}
