//! Marlin: backlash `M425`, skew `M852`, steps/mm `M92`; mm, saved with `M500`.
//!
//! Semantics (MarlinFirmware/Marlin `gcode/calibrate/M425.cpp`, `M852.cpp`,
//! `feature/backlash.cpp`, `Configuration.h`; docs marlinfw.org/docs/gcode/M425.html, M852.html;
//! as in `shared/notes/controllers.md`):
//! - `M425 [F<fraction>] [S<smoothing mm>] [X<mm>] [Y<mm>] [Z<mm>]`, needs `BACKLASH_COMPENSATION`
//!   and `BACKLASH_GCODE`. On every direction change `Backlash::add_correction_steps()` adds
//!   `F × distance_mm × steps/mm` to the residual and takes it up as extra steps in the **new**
//!   direction: the **full** distance (times F), not halves. A correction against the motion is
//!   clamped away (`LIMIT(error_correction, 0, dist)`), so the effective distance F·X is ≥ 0.
//!   S > 0 spreads it over S mm of travel.
//! - `M852 I<xy> J<xz> K<yz>` (`S` = I), needs `SKEW_CORRECTION` + `SKEW_CORRECTION_GCODE`, J and
//!   K also `SKEW_CORRECTION_FOR_Z`. A factor is the tangent of the deviation from 90° of the
//!   angle DAB of a printed square (A origin, D on +X, B on +Y), positive when the diagonal AC >
//!   BD. The planner moves to `x' = x − y·xy − z·(xz − xy·yz)`, `y' = y − z·yz`, so xy cancels
//!   δ_x = xy·y. M852 reads the factors as linear units: send it in G21 (mm) mode.
//!
//! # `--current` format
//! The `M425`, `M852` and `M92` lines in force, as `M503` prints them (`echo:` prefixes and
//! comments are fine). `M503` prints two decimals (`M852` six): a value in force rounded so
//! makes the new total wrong by up to half its last digit (±5 µm of `M425` backlash, ±62.5 µm/m
//! of scale through `M92 X80.00`), which the output says with where to read the exact values
//! (what was sent with `M92`/`M425`/`M852` before `M500`, else `Configuration.h` /
//! `Configuration_adv.h`: Marlin has no command that prints the EEPROM with more digits). E.g.
//! ```text
//! echo:  M92 X80.00 Y80.00 Z400.00 E93.00
//! echo:  M425 F1.00 S0.00 X0.01 Y0.01 Z0.00
//! M852 I0.0001
//! ```
use std::path::Path;

use super::current::{gcode_words, number, Current};
use super::{
    change, defaults_note, scale_epsilon, skew_factors, Block, Cannot, Change, MachineErrors, Plan,
};
use crate::model::Axis;
use crate::Result;

/// Read the `--current` format (module docs).
pub fn parse_current(path: &Path, text: &str) -> Result<Current> {
    let mut c = Current::none();
    for (n, line) in text.lines().enumerate() {
        let words = gcode_words(line);
        let Some((cmd, rest)) = words.split_first() else {
            continue;
        };
        let code = match (cmd.0, cmd.1.as_str()) {
            ('M', "425") => "M425",
            ('M', "852") => "M852",
            ('M', "92") => "M92",
            _ => continue,
        };
        for (letter, value, col) in rest {
            let letter = if code == "M852" && *letter == 'S' {
                'I'
            } else {
                *letter
            };
            let key = format!("{code}.{letter}");
            let v = number(path, n + 1, *col, value, &key)?;
            let decimals = value.trim().split_once('.').map_or(0, |(_, f)| {
                f.chars().take_while(char::is_ascii_digit).count()
            });
            if !value.contains(['e', 'E']) {
                c.set_decimals(key.clone(), decimals);
            }
            c.set(key, v);
        }
    }
    Ok(c)
}

/// How far a value in force may be from what Marlin holds, given the decimals it was written
/// with (`M503` rounds): half its last digit, as the error it makes in the new total, in µm
/// (`M425` distances) or µm/m (`M852` factors, `M92` steps/mm); None when it is written exactly
/// enough (within 1 µm or µm/m) or its decimals are not known.
fn rounding(current: &Current, key: &str) -> Option<String> {
    let d = current.decimals(key)?;
    let v = current.get(key)?;
    let half = 0.5 * 10f64.powi(-(d as i32));
    let (err, unit) = match key.split('.').next()? {
        "M425" if key == "M425.F" => return None,
        "M425" => (
            1e3 * half * current.get("M425.F").unwrap_or(1.0).abs().min(1.0),
            "µm",
        ),
        "M852" => (1e6 * half, "µm/m"),
        "M92" if v != 0.0 => (1e6 * half / v.abs(), "µm/m"),
        _ => return None,
    };
    (err >= 1.0).then(|| {
        let (code, letter) = key.split_once('.').unwrap_or((key, ""));
        format!("{code} {letter}{v:.d$} (±{half} → ±{err:.1} {unit})")
    })
}

/// What to change in Marlin (module docs).
pub fn plan(m: &MachineErrors, current: &Current) -> Plan {
    let mut p = Plan {
        title: "Marlin (G21, mm; M500 saves to EEPROM)".into(),
        ..Default::default()
    };
    p.notes.extend(defaults_note(current));
    let mut lines = vec![];
    // Values in force a change is built on, for the rounding note.
    let mut used: Vec<String> = vec![];

    // Backlash: the effective distance is F·X.
    let f_cur = current.get("M425.F");
    let keep_f = f_cur.filter(|f| *f > 0.0);
    let f = keep_f.unwrap_or(1.0);
    let mut words = vec![];
    for axis in Axis::ALL {
        let k = axis.index();
        let Some(b) = &m.backlash_um[k] else { continue };
        let l = axis.letter().to_ascii_uppercase();
        let key = format!("M425.{l}");
        let x_cur = current.get(&key);
        let eff_cur = f_cur.unwrap_or(0.0) * x_cur.unwrap_or(0.0);
        let eff_new = eff_cur + 1e-3 * b.value;
        if eff_new < 0.0 {
            p.cannot.push(Cannot {
                effect: b.text(),
                why: format!(
                    "{l} runs ahead at reversal ({:.4} mm in total): Marlin only adds steps in the new direction, so F·{l} cannot be negative",
                    -eff_new
                ),
                instead: if eff_cur > 0.0 {
                    format!("lower M425 {l} (F·{l} = {eff_cur:.6} mm now) towards 0 and test again")
                } else {
                    "look for a compensation in force elsewhere (slicer, post-processor) and remove it".into()
                },
            });
            continue;
        }
        used.push(key.clone());
        let c = change(
            b.text(),
            format!("M425 {l}"),
            "mm",
            x_cur,
            0.0,
            eff_new / f - x_cur.unwrap_or(0.0),
            6,
        );
        words.push(format!("{l}{:.6}", c.new));
        p.changes.push(c);
    }
    if !words.is_empty() {
        if keep_f.is_none() {
            p.changes.push(change(
                "the correction fraction: full".into(),
                "M425 F".into(),
                "",
                f_cur,
                0.0,
                1.0 - f_cur.unwrap_or(0.0),
                2,
            ));
        }
        lines.push(format!("M425 F{f} {}", words.join(" ")));
        p.notes.push("M425 needs BACKLASH_COMPENSATION and BACKLASH_GCODE; the correction is taken up in whole steps right after each reversal (S0), or spread over S mm with M425 S; on CoreXY machines Marlin applies it per motor (CORE_BACKLASH)".into());
    }

    // Skew.
    let planes = [
        ("I", "XY", "M852.I"),
        ("J", "XZ", "M852.J"),
        ("K", "YZ", "M852.K"),
    ];
    let mut skew = vec![];
    for ((word, plane, key), factor) in planes.into_iter().zip(skew_factors(m)) {
        let Some((k, src)) = factor else { continue };
        used.push(key.to_string());
        let c = change(
            src.text(),
            format!("M852 {word} ({plane} skew factor)"),
            "",
            current.get(key),
            0.0,
            k,
            9,
        );
        skew.push(format!("{word}{:.9}", c.new));
        p.changes.push(c);
    }
    if !skew.is_empty() {
        lines.push(format!("M852 {}", skew.join(" ")));
        p.notes.push("M852 needs SKEW_CORRECTION and SKEW_CORRECTION_GCODE (J and K also SKEW_CORRECTION_FOR_Z); send it in G21 (mm) mode, M852 reads the factors as linear units".into());
    }

    // Scale: steps/mm.
    let mut steps = vec![];
    for axis in Axis::ALL {
        let Some((eps, src)) = scale_epsilon(m, axis) else {
            continue;
        };
        let l = axis.letter().to_ascii_uppercase();
        let factor = 1.0 / (1.0 + eps);
        match current.get(&format!("M92.{l}")) {
            Some(cur) => {
                used.push(format!("M92.{l}"));
                let c = change(src.text(), format!("M92 {l}"), "steps/mm", Some(cur), 0.0, cur * (factor - 1.0), 6);
                steps.push(format!("{l}{:.6}", c.new));
                p.changes.push(c);
            }
            None => p.changes.push(Change {
                because: src.text(),
                setting: format!("M92 {l} (steps/mm)"),
                unit: String::new(),
                current: 0.0,
                assumed: true,
                new: 0.0,
                decimals: 0,
                text: Some(format!(
                    "multiply the value in force by {factor:.8} (give M92 with --current for the new value)"
                )),
            }),
        }
    }
    if !steps.is_empty() {
        lines.push(format!("M92 {}", steps.join(" ")));
    }
    let rough: Vec<String> = used.iter().filter_map(|k| rounding(current, k)).collect();
    if !rough.is_empty() {
        p.notes.push(format!(
            "the values in force are rounded as M503 prints them: {}; the new totals may be wrong by as much. Marlin has no command that prints them with more digits (the EEPROM holds them exactly): give --current the values as last sent with M92/M425/M852 before M500, or, if never changed, as in Configuration.h (DEFAULT_AXIS_STEPS_PER_UNIT) and Configuration_adv.h (BACKLASH_DISTANCE_MM, BACKLASH_CORRECTION)",
            rough.join(", ")
        ));
    }
    if !lines.is_empty() {
        lines.push("M500".into());
        p.blocks.push(Block {
            label: "the console or a start G-code (M500 saves them)".into(),
            lines,
        });
    }
    for axis in Axis::ALL {
        let k = axis.index();
        for src in [
            m.scale2_um_per_m2[k].as_ref(),
            m.cyclic[k].as_ref().map(|c| &c.source),
        ]
        .into_iter()
        .flatten()
        {
            p.cannot.push(Cannot {
                effect: src.text(),
                why: "Marlin has no position-dependent (pitch error) compensation of an axis".into(),
                instead: "replace or re-tension the screw/belt, or compensate in the slicer's post-processing".into(),
            });
        }
    }
    p
}
