//! Klipper: skew `[skew_correction]` / `SET_SKEW`, scale `rotation_distance`; no backlash.
//!
//! Semantics (Klipper3d/klipper `klippy/extras/skew_correction.py`, docs Skew_Correction.md and
//! G-Codes.md; as in `shared/notes/controllers.md`):
//! - An empty `[skew_correction]` section enables it. `SET_SKEW XY=<ac>,<bd>,<ad>` (likewise XZ,
//!   YZ; lengths in mm, no spaces) sets a plane's factor with `calc_skew_factor(ac, bd, ad)`, a
//!   port of Marlin's: side `ab = √(2ac² + 2bd² − 4ad²)/2`,
//!   `factor = tan(π/2 − acos((ac² − ab² − ad²)/(2·ab·ad)))`. Moves go to
//!   `x' = x − y·xy − z·(xz − xy·yz)`, `y' = y − z·yz`, so xy cancels δ_x = xy·y.
//!   `SKEW_PROFILE SAVE=<name>` then `SAVE_CONFIG` stores the factors as `xy_skew`, `xz_skew`,
//!   `yz_skew` in a `[skew_correction <name>]` section; a profile is not loaded at start-up by
//!   itself (`SKEW_PROFILE LOAD=<name>` in a start macro).
//! - The lengths written here are of a rhombus with sides `ad` = [`SIDE_MM`] whose angle DAB gives
//!   the factor: cos DAB = k/√(1 + k²), ac = ad·√(2 + 2·cos DAB), bd = ad·√(2 − 2·cos DAB).
//! - Backlash: not in mainline (feature request #2040 closed; PRs #7157, #7259 open).
//!
//! # `--current` format
//! The printer.cfg parts in force (the `#*# ` prefix of SAVE_CONFIG's block is fine):
//! ```text
//! [skew_correction default]
//! xy_skew = 0.0001
//! [stepper_x]
//! rotation_distance: 40
//! ```
//! Several `[skew_correction <name>]` profiles: the one a `SKEW_PROFILE LOAD=<name>` line in the
//! file names (e.g. the start macro's) is the one in force; with no such line (or lines naming
//! different profiles) `compensate` refuses to guess when a skew is to change, listing the
//! profiles. A single profile is taken as in force, and said.
use std::path::Path;

use super::current::{key_value, number, Current};
use super::{
    change, defaults_note, scale_epsilon, skew_factors, Block, Cannot, Change, MachineErrors, Plan,
};
use crate::model::Axis;
use crate::{Error, Result};

/// Side AD of the rhombus `SET_SKEW` is given, mm.
pub const SIDE_MM: f64 = 100.0;

/// The profile name `jdbb compensate` saves.
pub const PROFILE: &str = "jdbb";

/// Read the `--current` format (module docs).
pub fn parse_current(path: &Path, text: &str) -> Result<Current> {
    let mut c = Current::none();
    let mut section = String::new();
    // Skew profiles by name (`[skew_correction <name>]`; "" for a bare section), in file order.
    let mut profiles: Vec<(String, Vec<(String, f64)>)> = vec![];
    let mut loaded: Vec<String> = vec![];
    for (n, raw) in text.lines().enumerate() {
        if let Some(i) = raw.find("SKEW_PROFILE") {
            let words = raw[i..].split_whitespace().skip(1);
            for w in words {
                if let Some(name) = w.strip_prefix("LOAD=").or_else(|| w.strip_prefix("load=")) {
                    if !loaded.iter().any(|l| l == name) {
                        loaded.push(name.to_string());
                    }
                }
            }
        }
        let (line, shift) = match raw.strip_prefix("#*#") {
            Some(rest) => (rest, 3),
            None => (raw, 0),
        };
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') || t.starts_with(';') {
            continue;
        }
        if t.starts_with('[') {
            section = t
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim()
                .to_string();
            continue;
        }
        let Some((key, value, col)) = key_value(line) else {
            continue;
        };
        let col = col + shift;
        if section.starts_with("skew_correction") && key.ends_with("_skew") {
            let v = number(path, n + 1, col, &value, &key)?;
            let name = section["skew_correction".len()..].trim().to_string();
            let at = match profiles.iter().position(|(p, _)| *p == name) {
                Some(i) => i,
                None => {
                    profiles.push((name, vec![]));
                    profiles.len() - 1
                }
            };
            profiles[at].1.push((key, v));
        } else if section.starts_with("stepper_") && key == "rotation_distance" {
            let v = number(path, n + 1, col, &value, &key)?;
            c.set(format!("{section}.rotation_distance"), v);
        }
    }
    let named = |p: &str| {
        if p.is_empty() {
            "[skew_correction]".to_string()
        } else {
            p.to_string()
        }
    };
    let chosen = match (&profiles[..], &loaded[..]) {
        ([], _) => None,
        ([one], []) => Some((one, format!("the only skew profile in --current, {}, is taken as in force (no SKEW_PROFILE LOAD= line says which is loaded)", named(&one.0)))),
        (_, [name]) => match profiles.iter().find(|(p, _)| p == name) {
            Some(p) => Some((p, format!("skew profile {name} is taken as in force (SKEW_PROFILE LOAD={name} in --current)"))),
            None => {
                c.set_text(SKEW_AMBIGUOUS, format!("SKEW_PROFILE LOAD={name} names no profile in the file, which has {}", profiles.iter().map(|(p, _)| named(p)).collect::<Vec<_>>().join(", ")));
                None
            }
        },
        _ => {
            c.set_text(
                SKEW_AMBIGUOUS,
                format!(
                    "the file has {} skew profiles ({}){}",
                    profiles.len(),
                    profiles.iter().map(|(p, _)| named(p)).collect::<Vec<_>>().join(", "),
                    if loaded.is_empty() {
                        String::new()
                    } else {
                        format!(" and loads {}", loaded.join(" and "))
                    }
                ),
            );
            None
        }
    };
    if let Some(((_, values), said)) = chosen {
        for (k, v) in values {
            c.set(k.clone(), *v);
        }
        c.set_text(SKEW_IN_FORCE, said);
    }
    Ok(c)
}

/// The [`Current`] text key saying which skew profile was taken as in force.
const SKEW_IN_FORCE: &str = "skew_correction.in_force";

/// The [`Current`] text key saying why no skew profile could be taken as in force.
const SKEW_AMBIGUOUS: &str = "skew_correction.ambiguous";

/// The `ac, bd, ad` lengths (mm) whose `calc_skew_factor` is `factor`.
pub fn skew_lengths(factor: f64) -> (f64, f64, f64) {
    let cos_dab = factor / (1.0 + factor * factor).sqrt();
    (
        SIDE_MM * (2.0 + 2.0 * cos_dab).sqrt(),
        SIDE_MM * (2.0 - 2.0 * cos_dab).sqrt(),
        SIDE_MM,
    )
}

/// What to change in Klipper (module docs).
pub fn plan(m: &MachineErrors, current: &Current) -> Result<Plan> {
    let mut p = Plan {
        title: "Klipper (mainline), mm".into(),
        ..Default::default()
    };
    p.notes.extend(defaults_note(current));
    let mut set = vec![];
    let planes = [("XY", "xy_skew"), ("XZ", "xz_skew"), ("YZ", "yz_skew")];
    if skew_factors(m).iter().any(Option::is_some) {
        if let Some(why) = current.text(SKEW_AMBIGUOUS) {
            return Err(Error::Usage(format!(
                "--current: which skew profile is in force? {why}; keep only that profile in the --current file, or add the SKEW_PROFILE LOAD=<name> line of your start macro to it"
            )));
        }
        p.notes
            .extend(current.text(SKEW_IN_FORCE).map(str::to_string));
    }
    for ((plane, key), factor) in planes.into_iter().zip(skew_factors(m)) {
        let Some((k, src)) = factor else { continue };
        let c = change(
            src.text(),
            format!("{key} ({plane} skew factor)"),
            "",
            current.get(key),
            0.0,
            k,
            9,
        );
        let (ac, bd, ad) = skew_lengths(c.new);
        set.push(format!("{plane}={ac:.6},{bd:.6},{ad:.6}"));
        p.changes.push(c);
    }
    let mut cfg = vec![];
    if !set.is_empty() {
        p.blocks.push(Block {
            label: "the console (with an empty [skew_correction] section in printer.cfg)".into(),
            lines: vec![
                format!("SET_SKEW {}", set.join(" ")),
                format!("SKEW_PROFILE SAVE={PROFILE}"),
                "SAVE_CONFIG".into(),
            ],
        });
        p.notes.push(format!(
            "SET_SKEW takes the diagonals AC, BD and side AD (mm) of a square printed without correction; these are of a {SIDE_MM} mm rhombus with the measured angle. Klipper does not load a profile at start: add SKEW_PROFILE LOAD={PROFILE} to your start macro"
        ));
    }
    for axis in Axis::ALL {
        let Some((eps, src)) = scale_epsilon(m, axis) else {
            continue;
        };
        let section = format!("stepper_{}", axis.letter());
        let factor = 1.0 + eps;
        match current.get(&format!("{section}.rotation_distance")) {
            Some(cur) => {
                let c = change(
                    src.text(),
                    format!("[{section}] rotation_distance"),
                    "mm",
                    Some(cur),
                    0.0,
                    cur * eps,
                    6,
                );
                cfg.push(format!("[{section}]"));
                cfg.push(format!("rotation_distance: {:.6}", c.new));
                p.changes.push(c);
            }
            None => p.changes.push(Change {
                because: src.text(),
                setting: format!("[{section}] rotation_distance"),
                unit: String::new(),
                current: 0.0,
                assumed: true,
                new: 0.0,
                decimals: 0,
                text: Some(format!(
                    "multiply the value in force by {factor:.8} (give it with --current for the new value)"
                )),
            }),
        }
    }
    if !cfg.is_empty() {
        p.blocks.push(Block {
            label: "printer.cfg (then RESTART)".into(),
            lines: cfg,
        });
    }
    for axis in Axis::ALL {
        let k = axis.index();
        if let Some(b) = &m.backlash_um[k] {
            p.cannot.push(Cannot {
                effect: b.text(),
                why: "mainline Klipper has no backlash compensation (request #2040 closed; PRs #7157 and #7259 not merged)".into(),
                instead: "take the play out mechanically: preload or replace the nut, tension the belt, check the pulley grub screws".into(),
            });
        }
        for src in [
            m.scale2_um_per_m2[k].as_ref(),
            m.cyclic[k].as_ref().map(|c| &c.source),
        ]
        .into_iter()
        .flatten()
        {
            p.cannot.push(Cannot {
                effect: src.text(),
                why: "Klipper has no position-dependent (pitch error) compensation of an axis"
                    .into(),
                instead: "replace or re-tension the screw/belt".into(),
            });
        }
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Klipper's calc_skew_factor, transcribed from skew_correction.py.
    fn calc_skew_factor(ac: f64, bd: f64, ad: f64) -> f64 {
        let side = (2.0 * ac * ac + 2.0 * bd * bd - 4.0 * ad * ad).sqrt() / 2.0;
        (std::f64::consts::FRAC_PI_2
            - ((ac * ac - side * side - ad * ad) / (2.0 * side * ad)).acos())
        .tan()
    }

    #[test]
    fn skew_lengths_round_trip_through_klippers_formula() {
        for k in [0.0, 2.5e-5, -4e-4, 0.01] {
            let (ac, bd, ad) = skew_lengths(k);
            assert!((calc_skew_factor(ac, bd, ad) - k).abs() < 1e-12, "{k}");
        }
        // Positive when AC > BD (Marlin's sign).
        let (ac, bd, _) = skew_lengths(1e-3);
        assert!(ac > bd);
    }
}
