//! Plausibility of what `jdbb compensate` would have the user enter into a controller: each
//! setting within the range a working machine can have, with the reason. A value outside is not
//! printed as advice (`$160=1000`, `M92 X0`) but refused, naming the setting, the limit and where
//! the absurd number came from (the diagnosis or the values in force, `--current`). The values
//! in force are held to the same limits as the new ones: a typing error in `--current`
//! (`$100=0.000001`) would otherwise be carried into the new total.
//!
//! The limits, once (each a constant below, with its reason):
//!
//! | what | limit | why |
//! |---|---|---|
//! | a scale error (`scale_k`, half a `scale_mismatch_ij`) | ≤ 10 000 µm/m (1 %) | a larger one is a wrong pulley, microstep or pitch setting: to correct from the machine's data, not trimmed from a test |
//! | a backlash setting (in force or new) | ≤ 1 mm | beyond, a worn or loose screw or nut to repair |
//! | a trim of a LinuxCNC `COMP_FILE` (in force or new) | ≤ 2 mm | a positioning error larger than that is a setting or a repair |
//! | steps per mm (in force or new) | 1 to 10⁶ | a belt drive at full step has about 5; a 0.9° motor at 256 microsteps on a 0.5 mm screw 204 800 |
//! | a Klipper `rotation_distance` (in force or new) | 0.1 to 1000 mm per turn | a fine screw is 0.5 mm per turn, a belt pulley about 40 |
//! | a skew factor (in force or new) | ≤ 0.01 | 10 mm per m: a machine to square mechanically |
//! | Marlin's backlash correction `M425 F` (in force or new) | 0 to 1 | a fraction of the backlash |
use super::{Change, Current, MachineErrors, Plan};
use crate::{Error, Result};

/// Largest backlash (mm) a controller setting may take up: beyond 1 mm the screw or nut is worn
/// or loose, a repair, not a setting.
pub const MAX_BACKLASH_MM: f64 = 1.0;

/// Smallest steps per mm of an axis: a belt drive (40 mm per turn) at full step has 5; fewer
/// than 1 is a typing error.
pub const MIN_STEPS_PER_MM: f64 = 1.0;

/// Largest steps per mm of an axis: a 0.9° motor at 256 microsteps on a 0.5 mm pitch screw has
/// 204 800; more is a typing error.
pub const MAX_STEPS_PER_MM: f64 = 1e6;

/// Largest skew factor (tangent of the angle between two axes): 0.01, 10 mm per m; more is a
/// machine to square mechanically, or a wrong number.
pub const MAX_SKEW: f64 = 0.01;

/// Smallest Klipper `rotation_distance` (mm travelled per motor turn): 0.1 mm (a fine screw is
/// 0.5 mm per turn).
pub const MIN_ROTATION_DISTANCE_MM: f64 = 0.1;

/// Largest Klipper `rotation_distance` (mm travelled per motor turn): 1 m.
pub const MAX_ROTATION_DISTANCE_MM: f64 = 1000.0;

/// Largest scale error (µm/m) a setting may correct: 1 %. A ball bar test sees machine errors of
/// tens to hundreds of µm/m; a larger scale is a wrong drive setting (pulley, microsteps,
/// pitch), or a wrong number.
pub const MAX_SCALE_UM_PER_M: f64 = 10_000.0;

/// Largest trim (mm) of a LinuxCNC `COMP_FILE` entry: 2 mm.
pub const MAX_TRIM_MM: f64 = 2.0;

/// Why `v`, a value of the setting of `c` (`what`: "would be" for the new one, "in force ... is"
/// for the one in force), is not one a working machine can have, if it is not. A length in
/// inches (LinuxCNC in inch units) is held to the limit in mm.
fn out_of_range(c: &Change, v: f64, what: &str) -> Option<String> {
    let s = c.setting.as_str();
    if !v.is_finite() {
        return Some(format!("{s} {what} {v}, not a number"));
    }
    let mm_per_unit = if c.unit == "inch" { 25.4 } else { 1.0 };
    if s.contains("rotation_distance") {
        if !((MIN_ROTATION_DISTANCE_MM..=MAX_ROTATION_DISTANCE_MM).contains(&v)) {
            return Some(format!(
                "{s} {what} {v} mm; a rotation distance is {MIN_ROTATION_DISTANCE_MM} to {MAX_ROTATION_DISTANCE_MM} mm per turn"
            ));
        }
    } else if c.unit == "steps/mm" {
        if !((MIN_STEPS_PER_MM..=MAX_STEPS_PER_MM).contains(&v)) {
            return Some(format!(
                "{s} {what} {v} steps/mm; steps per mm are above 0, at least {MIN_STEPS_PER_MM} and at most {MAX_STEPS_PER_MM}"
            ));
        }
    } else if c.unit == "mm" || c.unit == "inch" {
        if (v * mm_per_unit).abs() > MAX_BACKLASH_MM {
            return Some(format!(
                "{s} {what} {v} {}; a backlash beyond {MAX_BACKLASH_MM} mm is a worn or loose screw or nut to repair, not a setting",
                c.unit
            ));
        }
    } else if s.starts_with("M425 F") {
        if !(0.0..=1.0).contains(&v) {
            return Some(format!(
                "{s} {what} {v}; Marlin's backlash correction fraction is 0 (none) to 1 (full)"
            ));
        }
    } else if (s.contains("skew") || s.contains("matrixkins")) && v.abs() > MAX_SKEW {
        return Some(format!(
            "{s} {what} {v}; a skew beyond {MAX_SKEW} (10 mm per m) is a machine to square mechanically, not a setting"
        ));
    }
    None
}

/// Why the value in force or the new value of `c` is not one a working machine can have, if
/// either is not.
fn implausible(c: &Change) -> Option<String> {
    if c.text.is_some() {
        return None;
    }
    if !c.assumed {
        if let Some(why) = out_of_range(c, c.current, "in force (--current) is") {
            return Some(why);
        }
    }
    out_of_range(c, c.new, "would be")
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

/// Refuse a diagnosis whose scale errors no setting should correct ([`MAX_SCALE_UM_PER_M`]),
/// before any controller's plan is made of them.
pub fn check_errors(m: &MachineErrors) -> Result<()> {
    for (s, src) in m.scale_um_per_m.iter().flatten() {
        if !(s.is_finite() && s.abs() <= MAX_SCALE_UM_PER_M) {
            return Err(Error::Usage(format!(
                "{}: a scale error of {s} µm/m is beyond {MAX_SCALE_UM_PER_M} µm/m (1 %), which no setting should trim: a wrong drive setting (pulley, microsteps, screw pitch) to correct from the machine's data, or an absurd number in the diagnosis; nothing was written",
                src.text()
            )));
        }
    }
    Ok(())
}

/// Refuse a value in force that a plan builds on without changing it, if absurd: Marlin's
/// `M425 F` (the others in force are a change's current value, checked with it by [`check`]).
pub fn check_in_force(current: &Current) -> Result<()> {
    if let Some(f) = current.get("M425.F") {
        if !(0.0..=1.0).contains(&f) {
            return Err(Error::Usage(format!(
                "M425 F in force (--current) is {f}; Marlin's backlash correction fraction is 0 (none) to 1 (full): check the values in force"
            )));
        }
    }
    Ok(())
}

/// Refuse a LinuxCNC comp table trim (forward or reverse, mm) beyond [`MAX_TRIM_MM`] at
/// `position_mm` of `table` (the file's name; `whose`: the new table or the one in force).
pub fn check_trim(table: &str, whose: &str, position_mm: f64, trim_mm: f64) -> Result<()> {
    if trim_mm.is_finite() && trim_mm.abs() <= MAX_TRIM_MM {
        return Ok(());
    }
    Err(Error::Usage(format!(
        "{table} ({whose}) has a trim of {trim_mm} mm at {position_mm} mm; a trim beyond {MAX_TRIM_MM} mm is a wrong setting or a repair, not a compensation. Check the diagnosis, --travel and the values in force (--current): one of them holds an absurd number"
    )))
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

    #[test]
    fn values_in_force_are_held_to_the_same_limits_as_new_ones() {
        // Issue 28, finding 9: `$100=0.000001` in force, a rotation distance of 0.00004 mm,
        // a backlash of 2 mm in force (in inches on LinuxCNC).
        let e = implausible(&c("$100", "steps/mm", 0.000001, 0.000001)).unwrap();
        assert!(
            e.contains("in force (--current) is 0.000001") && e.contains("at least 1"),
            "{e}"
        );
        let e = implausible(&c("[stepper_x] rotation_distance", "mm", 40.0, 0.00004)).unwrap();
        assert!(
            e.contains("would be 0.00004") && e.contains("0.1 to 1000"),
            "{e}"
        );
        assert!(implausible(&c("[JOINT_0] BACKLASH", "inch", 0.08, 0.0801)).is_some());
        assert!(implausible(&c("[JOINT_0] BACKLASH", "inch", 0.0004, 0.0005)).is_none());
        let mut m = Current::none();
        m.set("M425.F", 1000.0);
        assert!(check_in_force(&m).is_err());
        m.set("M425.F", 0.5);
        assert!(check_in_force(&m).is_ok());
        assert!(implausible(&c("M425 F", "", 1000.0, 1000.0))
            .unwrap()
            .contains("0 (none) to 1 (full)"));
        // An assumed default (0 steps/mm where none was given) is not checked.
        let mut d = c("$100", "steps/mm", 0.0, 80.0);
        d.assumed = true;
        assert!(implausible(&d).is_none());
        assert!(check_trim("x.comp", "new", 10.0, 1.5).is_ok());
        let e = check_trim("x.comp", "new", 10.0, 90_000.0).unwrap_err();
        assert!(e.to_string().contains("beyond 2 mm"), "{e}");
        assert_eq!(e.exit_code(), 2);
    }
}
