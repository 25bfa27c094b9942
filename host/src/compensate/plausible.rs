//! Plausibility of what `jdbb compensate` would have the user enter into a controller: each
//! setting within the range a working machine can have, with the reason. A value outside is not
//! printed as advice (`$160=1000`, `M92 X0`) but refused, naming the setting and where the
//! absurd number came from (the diagnosis or the values in force, `--current`).
use super::{Change, Plan};
use crate::{Error, Result};

/// Largest backlash (mm) a controller setting may take up: beyond 1 mm the screw or nut is worn
/// or loose, a repair, not a setting.
pub const MAX_BACKLASH_MM: f64 = 1.0;

/// Largest steps per mm of an axis: a 0.9° motor at 256 microsteps on a 0.5 mm pitch screw has
/// 204 800; more is a typing error.
pub const MAX_STEPS_PER_MM: f64 = 1e6;

/// Largest skew factor (tangent of the angle between two axes): 0.01, 10 mm per m; more is a
/// machine to square mechanically, or a wrong number.
pub const MAX_SKEW: f64 = 0.01;

/// Largest Klipper `rotation_distance` (mm travelled per motor turn): 1 m.
pub const MAX_ROTATION_DISTANCE_MM: f64 = 1000.0;

/// Why the new value of `c` is not one a working machine can have, if it is not.
fn implausible(c: &Change) -> Option<String> {
    if c.text.is_some() {
        return None;
    }
    let v = c.new;
    let s = c.setting.as_str();
    if !v.is_finite() {
        return Some(format!("{s} would be {v}, not a number"));
    }
    if s.contains("rotation_distance") {
        if !(v > 0.0 && v <= MAX_ROTATION_DISTANCE_MM) {
            return Some(format!(
                "{s} would be {v} mm; a rotation distance is above 0 and at most {MAX_ROTATION_DISTANCE_MM} mm per turn"
            ));
        }
    } else if c.unit == "steps/mm" {
        if !(c.current > 0.0 && v > 0.0 && v <= MAX_STEPS_PER_MM) {
            return Some(format!(
                "{s} would be {v} steps/mm (from {} in force); steps per mm are above 0 and at most {MAX_STEPS_PER_MM}",
                c.current
            ));
        }
    } else if c.unit == "mm" {
        if v.abs() > MAX_BACKLASH_MM {
            return Some(format!(
                "{s} would be {v} mm; a backlash beyond {MAX_BACKLASH_MM} mm is a worn or loose screw or nut to repair, not a setting"
            ));
        }
    } else if (s.contains("skew") || s.contains("matrixkins")) && v.abs() > MAX_SKEW {
        return Some(format!(
            "{s} would be {v}; a skew beyond {MAX_SKEW} (10 mm per m) is a machine to square mechanically, not a setting"
        ));
    }
    None
}

/// Refuse a plan with a setting no working machine can have (see the module docs).
pub fn check(p: &Plan) -> Result<()> {
    for c in &p.changes {
        if let Some(why) = implausible(c) {
            return Err(Error::Usage(format!(
                "{why} (for {}). Check the diagnosis and the values in force (--current): one of them holds an absurd number",
                c.because
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(setting: &str, unit: &str, current: f64, new: f64) -> Change {
        Change {
            because: "test".into(),
            setting: setting.into(),
            unit: unit.into(),
            current,
            assumed: false,
            new,
            decimals: 3,
            text: None,
        }
    }

    #[test]
    fn absurd_settings_are_refused_with_the_reason() {
        assert!(implausible(&c("$160", "mm", 0.0, 0.02)).is_none());
        assert!(implausible(&c("$160", "mm", 0.0, 1000.0))
            .unwrap()
            .contains("repair"));
        assert!(implausible(&c("M92 X", "steps/mm", 80.0, 80.01)).is_none());
        assert!(implausible(&c("M92 X", "steps/mm", 0.0, 0.0))
            .unwrap()
            .contains("above 0"));
        assert!(implausible(&c("[stepper_x] rotation_distance", "mm", 40.0, 40.01)).is_none());
        assert!(implausible(&c("[stepper_x] rotation_distance", "mm", 0.0, -1.0)).is_some());
        assert!(implausible(&c("M852 I (xy skew factor)", "", 0.0, 2e-5)).is_none());
        assert!(implausible(&c("M852 I (xy skew factor)", "", 0.0, 0.5)).is_some());
        assert!(implausible(&c("M425 F", "", 0.0, 1.0)).is_none());
    }
}
