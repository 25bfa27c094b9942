//! grblHAL (core): backlash `$160`–`$162`, steps/mm `$100`–`$102`, in mm.
//!
//! Semantics (grblHAL/core `motion_control.c`, `settings.c`, `config.h`; snapshot as in
//! `shared/notes/controllers.md`):
//! - Backlash compensation is a **compile-time option**, `ENABLE_BACKLASH_COMPENSATION`, off by
//!   default in `config.h`: a default build has no `$160`. `Setting_AxisBacklash` is
//!   `$160` X, `$161` Y, `$162` Z ("-axis backlash compensation", mm).
//! - `mc_line()`: on each reversal of an axis it queues a separate move of the **full** backlash
//!   in the new direction before the commanded move; `mc_backlash_init()` rounds it to whole
//!   steps (`lroundf(backlash·steps_per_mm)`). The initial direction comes from the homing
//!   direction mask. The move only ever goes the new way, so the setting is ≥ 0.
//! - No skew (squareness) and no pitch-error compensation in core.
//!
//! # `--current` format
//! `$n=value` lines as `$$` prints them (other lines are ignored):
//! ```text
//! $100=800.000
//! $160=0.004
//! ```
use std::path::Path;

use super::current::{number, Current};
use super::{change, defaults_note, scale_epsilon, Block, Cannot, Change, MachineErrors, Plan};
use crate::model::{Axis, Pair};
use crate::Result;

/// Read the `--current` format (module docs).
pub fn parse_current(path: &Path, text: &str) -> Result<Current> {
    let mut c = Current::none();
    for (n, line) in text.lines().enumerate() {
        let t = line.trim();
        let Some(rest) = t.strip_prefix('$') else {
            continue;
        };
        let Some((key, value)) = rest.split_once('=') else {
            continue;
        };
        if key.trim().parse::<u32>().is_err() {
            continue;
        }
        let value = value.split(['(', ';']).next().unwrap_or("");
        let col = line.find('=').map_or(0, |i| i + 2);
        let key = format!("${}", key.trim());
        let v = number(path, n + 1, col, value, &key)?;
        c.set(key, v);
    }
    Ok(c)
}

/// What to change in grblHAL (module docs).
pub fn plan(m: &MachineErrors, current: &Current) -> Plan {
    let mut p = Plan {
        title: "grblHAL (core), settings in mm".into(),
        ..Default::default()
    };
    p.notes.extend(defaults_note(current));
    let mut lines = vec![];
    for axis in Axis::ALL {
        let k = axis.index();
        let Some(b) = &m.backlash_um[k] else { continue };
        let key = format!("${}", 160 + k);
        let c = change(
            b.text(),
            key.clone(),
            "mm",
            current.get(&key),
            0.0,
            1e-3 * b.value,
            6,
        );
        if c.new < 0.0 {
            p.cannot.push(Cannot {
                effect: b.text(),
                why: format!(
                    "{} runs ahead at reversal ({:.4} mm in total): grblHAL's backlash move only goes the new way, so {key} cannot be negative",
                    axis.letter().to_ascii_uppercase(),
                    -c.new
                ),
                instead: if c.current > 0.0 {
                    format!("lower {key} (now {:.6}) towards 0 and test again", c.current)
                } else {
                    "look for a compensation in force elsewhere (sender, post-processor, drive) and remove it".into()
                },
            });
            continue;
        }
        lines.push(format!("{key}={:.6}", c.new));
        p.changes.push(c);
    }
    if !lines.is_empty() {
        p.notes.push("backlash compensation needs a grblHAL build with ENABLE_BACKLASH_COMPENSATION (off by default in config.h): `$$` lists $160 if yours has it; it is applied as whole steps (up to half a step remains) and starts from the homing direction, so home before use".into());
    }
    for axis in Axis::ALL {
        let k = axis.index();
        let Some((eps, src)) = scale_epsilon(m, axis) else {
            continue;
        };
        let key = format!("${}", 100 + k);
        let factor = 1.0 / (1.0 + eps);
        match current.get(&key) {
            Some(cur) => {
                let c = change(src.text(), key.clone(), "steps/mm", Some(cur), 0.0, cur * (factor - 1.0), 6);
                lines.push(format!("{key}={:.6}", c.new));
                p.changes.push(c);
            }
            None => p.changes.push(Change {
                because: src.text(),
                setting: format!("{key} (steps/mm)"),
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
    if !lines.is_empty() {
        p.blocks.push(Block {
            label: "the console (grblHAL stores $ settings at once)".into(),
            lines,
        });
    }
    for pair in Pair::ALL {
        if let Some(s) = m.squareness(pair) {
            p.cannot.push(Cannot {
                effect: s.text(),
                why: "grblHAL core has no squareness (skew) compensation".into(),
                instead: format!("{}; a gantry driven by two motors with auto-squaring can be squared with its dual axis offset setting (offset = s × the distance between the two rails)", super::square_mechanically(pair)),
            });
        }
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
                why: "grblHAL core has no position-dependent (pitch error) compensation".into(),
                instead: "compensate it in the CAM post-processor, or on a controller with a screw-compensation table (LinuxCNC COMP_FILE)".into(),
            });
        }
    }
    p
}
