//! Which effects a controller setting can remove, and the controllers `jdbb compensate` knows:
//! the one definition of "compensable". It sits with the effects, below both its users, the
//! compensation plans (`crate::compensate`) and the diagnosis's what-if G, so that neither
//! depends on the other.
use super::Effect;
use crate::{Error, Result};

/// A controller `jdbb compensate` knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Controller {
    LinuxCnc,
    GrblHal,
    Marlin,
    Klipper,
    /// Fanuc Series 0i-F / 30i.
    Fanuc,
    /// Siemens SINUMERIK 840D sl / ONE.
    Sinumerik,
    /// Heidenhain iTNC 530 / TNC 640.
    Heidenhain,
}

impl Controller {
    pub const ALL: [Controller; 7] = [
        Controller::LinuxCnc,
        Controller::GrblHal,
        Controller::Marlin,
        Controller::Klipper,
        Controller::Fanuc,
        Controller::Sinumerik,
        Controller::Heidenhain,
    ];

    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Controller::LinuxCnc => "linuxcnc",
            Controller::GrblHal => "grblhal",
            Controller::Marlin => "marlin",
            Controller::Klipper => "klipper",
            Controller::Fanuc => "fanuc",
            Controller::Sinumerik => "sinumerik",
            Controller::Heidenhain => "heidenhain",
        }
    }

    /// The controller called `name`; the error lists the known ones.
    pub fn parse(name: &str) -> Result<Controller> {
        Controller::ALL
            .into_iter()
            .find(|c| c.name() == name.trim().to_ascii_lowercase())
            .ok_or_else(|| {
                Error::Usage(format!(
                    "--controller `{name}`: use one of linuxcnc, grblhal, marlin, klipper, fanuc, sinumerik, heidenhain"
                ))
            })
    }
}

/// The standard-error multiple below which an effect is left alone.
pub const SIGNIFICANT_SIGMAS: f64 = 3.0;

/// Whether a controller setting removes `effect` (backlash, scale, squareness, cyclic/pitch
/// error: what [`MachineErrors`] maps to settings), as opposed to tuning, repair or warm-up
/// (`MachineErrors::tuning`). A reversal spike is a setting only of a controller that
/// compensates it (`controller` Heidenhain); None stands for the settings every control has.
/// The one definition of "compensable": the compensation plans and the diagnosis' what-if G
/// (`crate::diagnose::Diagnosis::g_if_compensated_um`) both use it.
pub fn is_setting(effect: Effect, controller: Option<Controller>) -> bool {
    match effect {
        Effect::Backlash(_)
        | Effect::BacklashEnds(_)
        | Effect::Scale(_)
        | Effect::ScaleMismatch(_)
        | Effect::Scale2(_)
        | Effect::Cyclic(_)
        | Effect::Squareness(_) => true,
        Effect::ReversalSpike(_) => controller == Some(Controller::Heidenhain),
        Effect::Straightness(..)
        | Effect::LateralPlay(..)
        | Effect::ServoMismatch(_)
        | Effect::Interference(_)
        | Effect::Drift
        | Effect::ScaleDrift(_)
        | Effect::PositionDrift(_)
        | Effect::FollowingError
        | Effect::SetupOffset
        | Effect::LengthOffset => false,
    }
}
