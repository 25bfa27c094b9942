//! LinuxCNC 2.9 (trivkins): `[JOINT_n] BACKLASH` in the INI, a screw-compensation
//! `COMP_FILE` where the error depends on position, `matrixkins` for squareness (2.10/master).
//!
//! Semantics (sources as in `shared/notes/controllers.md`; checked in LinuxCNC's
//! `src/emc/motion/control.c`, `usrmotintf.cc`, `command.c`):
//! - `BACKLASH` is the **full** lost motion in machine units; `compute_screw_comp()` sets
//!   `backlash_corr = +0.5·backlash` while the joint's commanded velocity is > 0 and `−0.5·backlash`
//!   while it is < 0, ramps it (`backlash_filt`) and adds it to the motor command
//!   (`motor_pos_cmd = pos_cmd + backlash_filt + motor_offset`). No sign check: a negative value is
//!   applied as it is.
//! - `COMP_FILE` holds `nominal a b` triplets, one per line, nominal strictly increasing, at most
//!   256 per joint, linearly interpolated, the end values held beyond the table; loading stops at
//!   the first line that is not three numbers (so the file has no comments). `COMP_FILE_TYPE = 0`:
//!   a, b are the *actual* positions reached moving + and −; the loader stores `nominal − a` and
//!   `nominal − b`. Type 1: a, b are the trims themselves. The trim for the direction of motion
//!   replaces `±0.5·BACKLASH`: **`BACKLASH` is ignored when `COMP_FILE` is set**, so the table
//!   written here carries the backlash in its forward − reverse difference.
//! - Squareness: trivkins has none. `matrixkins` (LinuxCNC 2.10 / master only, not 2.9) maps
//!   `X_joint = C_xx·X + C_xy·Y + C_xz·Z` (and Y, Z alike) with HAL parameters
//!   `matrixkins.C_ij`; δ_i = s·j is cancelled by C_ij = −s·10⁻⁶.
//!
//! Tables written here span `--travel`, else the tested circle round `--table-ball` (machine
//! coordinates of the table ball; the diagnosis' positions are relative to it). Entries are
//! every 1/16 of the pitch where there is a cyclic error (down to 1/8 to stay within 256), else
//! 65 over the span; the cyclic part of each entry is divided by sinc²(step/pitch), the share of
//! a sine at the pitch that linear interpolation between entries keeps, so the table LinuxCNC
//! interpolates has the measured amplitude.
//!
//! Joints: X, Y, Z are joints 0, 1, 2 (trivkins `coordinates=XYZ`); a gantry's second joint of an
//! axis takes the same values.
//!
//! Units: machine units, `[TRAJ] LINEAR_UNITS` (`mm`/`metric` or `inch`/`in`/`imperial`) as the
//! `--current` file says; without it mm is assumed and the title says so. `BACKLASH`, `COMP_FILE`
//! positions and trims, and the values in force are all in machine units; `--table-ball` and
//! `--travel` stay in mm.
//!
//! A `COMP_FILE` in force (named in `--current`) makes LinuxCNC ignore `BACKLASH`: the `BACKLASH`
//! in force is then not counted, and every change of that joint goes into a table **merged** with
//! the one in force (read next to the `--current` file, its `COMP_FILE_TYPE` as given there,
//! default 0): the trims in force, interpolated as LinuxCNC does, plus the change, on the union of
//! both tables' positions. If that table cannot be read, `compensate` refuses rather than replace
//! it.
//!
//! # `--current` format
//! The INI sections and keys in force, and HAL `setp` lines, e.g.
//! ```text
//! [JOINT_0]
//! BACKLASH = 0.004
//! [JOINT_1]
//! BACKLASH = 0.0
//! setp matrixkins.C_xy 0.0
//! ```
//! `[AXIS_n]` (LinuxCNC 2.7) counts as `[JOINT_n]`; `COMP_FILE` and `COMP_FILE_TYPE` in a section
//! are read, as is `[TRAJ] LINEAR_UNITS`; other sections, keys and lines are ignored.
use std::path::{Path, PathBuf};

use super::current::{key_value, number, Current};
use super::{change, defaults_note, plausible, Block, Change, MachineErrors, Options, Plan};
use crate::model::{Axis, Pair};
use crate::{Error, Result};

/// Largest number of triplets LinuxCNC takes per joint.
pub const MAX_COMP_ENTRIES: usize = 256;

/// The [`Current`] key of `[TRAJ] LINEAR_UNITS` (text `mm` or `inch`).
pub const LINEAR_UNITS: &str = "TRAJ.LINEAR_UNITS";

/// The machine units of `current`: (name, mm per unit, decimals to print), and whether they
/// were given.
fn machine_units(current: &Current) -> (&'static str, f64, usize, bool) {
    match current.text(LINEAR_UNITS) {
        Some("inch") => ("inch", 25.4, 7, true),
        Some(_) => ("mm", 1.0, 6, true),
        None => ("mm", 1.0, 6, false),
    }
}

/// The COMP_FILE in force for joint `k`: its name as `--current` gives it and the file (next to
/// the `--current` file, as it sits next to the INI).
fn comp_file(current: &Current, k: usize) -> Option<(&str, PathBuf)> {
    let name = current.text(&format!("JOINT_{k}.COMP_FILE"))?;
    let dir = current
        .source
        .as_deref()
        .and_then(Path::parent)
        .unwrap_or(Path::new("."));
    Some((name, dir.join(name)))
}

/// Every COMP_FILE in force that `--current` names (inputs of `compensate`, never its outputs).
pub fn comp_files_in_force(current: &Current) -> Vec<PathBuf> {
    Axis::ALL
        .iter()
        .filter_map(|a| comp_file(current, a.index()).map(|(_, f)| f))
        .collect()
}

/// The comp table in force for joint `k` (named by `--current`, read next to it), as trims
/// (nominal, forward, reverse) in mm; None if none is in force.
fn table_in_force(
    current: &Current,
    k: usize,
    mm_per_unit: f64,
) -> Result<Option<(String, Vec<CompRow>)>> {
    let Some((name, file)) = comp_file(current, k) else {
        return Ok(None);
    };
    let refuse = |why: String| {
        Error::Usage(format!(
            "joint {k} has COMP_FILE = {name} in force (--current says so), and LinuxCNC ignores BACKLASH while it is set, so the change must be merged into that table: {why}; put a copy of {name} next to the --current file (as it sits next to the INI), or remove COMP_FILE from --current if it is no longer in force"
        ))
    };
    // Read as every input is (crate::fsio's limit, a pipe or device refused or bounded).
    let text = crate::table::read_text(&file).map_err(|e| refuse(e.to_string()))?;
    let kind = current
        .get(&format!("JOINT_{k}.COMP_FILE_TYPE"))
        .unwrap_or(0.0);
    let mut rows: Vec<CompRow> = vec![];
    // As LinuxCNC's loader: triplets until the first line that is not three numbers.
    for line in text.lines() {
        let v: Vec<f64> = line
            .split_whitespace()
            .map_while(|w| w.parse::<f64>().ok().filter(|x| x.is_finite()))
            .collect();
        if v.len() != 3 || line.split_whitespace().count() != 3 {
            break;
        }
        let (nominal, a, b) = (v[0], v[1], v[2]);
        let (fwd, rev) = if kind == 0.0 {
            (nominal - a, nominal - b)
        } else {
            (a, b)
        };
        if rows.last().is_some_and(|r| r.0 >= nominal * mm_per_unit) {
            return Err(refuse(format!(
                "{}: its positions are not increasing at {nominal}",
                file.display()
            )));
        }
        rows.push((nominal * mm_per_unit, fwd * mm_per_unit, rev * mm_per_unit));
    }
    if rows.is_empty() {
        return Err(refuse(format!(
            "{} has no `nominal a b` line",
            file.display()
        )));
    }
    Ok(Some((name.to_string(), rows)))
}

/// The forward and reverse trims of `table` at `x`, as LinuxCNC interpolates them (linearly,
/// end values held beyond the table).
fn trims_at(table: &[CompRow], x: f64) -> (f64, f64) {
    let (first, last) = (table[0], table[table.len() - 1]);
    if x <= first.0 {
        return (first.1, first.2);
    }
    if x >= last.0 {
        return (last.1, last.2);
    }
    let i = table.partition_point(|r| r.0 <= x);
    let (a, b) = (table[i - 1], table[i]);
    let t = (x - a.0) / (b.0 - a.0);
    (a.1 + t * (b.1 - a.1), a.2 + t * (b.2 - a.2))
}

/// Read the `--current` format (module docs).
pub fn parse_current(path: &Path, text: &str) -> Result<Current> {
    let mut c = Current::none();
    let mut joint: Option<usize> = None;
    let mut traj = false;
    for (n, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.is_empty() || t.starts_with('#') || t.starts_with(';') {
            continue;
        }
        if t.starts_with('[') {
            let name = t.trim_start_matches('[').split(']').next().unwrap_or("");
            traj = name.trim() == "TRAJ";
            joint = name
                .strip_prefix("JOINT_")
                .or_else(|| name.strip_prefix("AXIS_"))
                .and_then(|k| k.trim().parse().ok());
            continue;
        }
        if let Some(rest) = t.strip_prefix("setp") {
            let parts: Vec<&str> = rest
                .split(|ch: char| ch.is_whitespace() || ch == '=')
                .filter(|p| !p.is_empty())
                .collect();
            if let [name, value] = parts[..] {
                if name.starts_with("matrixkins.C_") {
                    let col = line.find(value).map_or(0, |i| i + 1);
                    c.set(name, number(path, n + 1, col, value, name)?);
                }
            }
            continue;
        }
        if traj {
            if let Some((key, value, col)) = key_value(line) {
                if key == "LINEAR_UNITS" {
                    let unit = match value.to_ascii_lowercase().as_str() {
                        "mm" | "metric" => "mm",
                        "inch" | "in" | "imperial" => "inch",
                        _ => {
                            return Err(Error::input(
                                path,
                                n + 1,
                                col,
                                format!("LINEAR_UNITS: `{value}` is not a unit LinuxCNC knows; use mm or inch as in the machine's INI"),
                            ))
                        }
                    };
                    c.set_text(LINEAR_UNITS, unit);
                }
            }
            continue;
        }
        let (Some(j), Some((key, value, col))) = (joint, key_value(line)) else {
            continue;
        };
        match key.as_str() {
            "BACKLASH" => {
                let v = number(path, n + 1, col, &value, "BACKLASH")?;
                c.set(format!("JOINT_{j}.BACKLASH"), v);
            }
            "COMP_FILE" => c.set_text(format!("JOINT_{j}.COMP_FILE"), value),
            "COMP_FILE_TYPE" => {
                let v = number(path, n + 1, col, &value, "COMP_FILE_TYPE")?;
                if v != 0.0 && v != 1.0 {
                    return Err(Error::input(
                        path,
                        n + 1,
                        col,
                        format!("COMP_FILE_TYPE: `{value}` should be 0 or 1"),
                    ));
                }
                c.set(format!("JOINT_{j}.COMP_FILE_TYPE"), v);
            }
            _ => {}
        }
    }
    Ok(c)
}

/// One comp table row: (nominal machine position, forward trim, reverse trim), mm.
type CompRow = (f64, f64, f64);

/// The comp table of one axis and a note if the table had to be shortened.
fn comp_table(
    m: &MachineErrors,
    axis: Axis,
    backlash_mm: f64,
    opts: &Options,
) -> Result<(Vec<CompRow>, Option<String>)> {
    let k = axis.index();
    let k0 = opts.placement.table_ball_mm[k].unwrap_or(0.0);
    let (mut lo, mut hi) = match (opts.placement.travel_mm[k], m.radius_mm) {
        (Some(t), _) => t,
        (None, Some(r)) => (k0 - r, k0 + r),
        (None, None) => {
            return Err(Error::Usage(format!(
                "the diagnosis file does not say the circles' radius (written by an older jdbb): give --travel {}=MIN:MAX for the comp table",
                axis.letter()
            )))
        }
    };
    // A table over a cyclic error needs several entries per pitch: 16 if they fit in 256, else
    // as many as fit down to 8; beyond that the table is shortened round the table ball.
    let (step, attenuation) = match &m.cyclic[k] {
        Some(c) => {
            let step = (c.pitch_mm / 16.0)
                .max((hi - lo) / (MAX_COMP_ENTRIES - 1) as f64)
                .min(c.pitch_mm / 8.0);
            // LinuxCNC interpolates linearly between entries; that keeps only sinc²(step/pitch)
            // of a sine at the pitch (the hat function's transform), so the cyclic part of each
            // entry is divided by it and the interpolated table has the right amplitude.
            let x = std::f64::consts::PI * step / c.pitch_mm;
            (step, (x.sin() / x).powi(2))
        }
        None => ((hi - lo) / 64.0, 1.0),
    };
    let mut note = None;
    let max_span = step * (MAX_COMP_ENTRIES - 1) as f64;
    if hi - lo > max_span * (1.0 + 1e-9) {
        let (want_lo, want_hi) = (lo, hi);
        let centre = k0.clamp(lo + 0.5 * max_span, hi - 0.5 * max_span);
        lo = centre - 0.5 * max_span;
        hi = centre + 0.5 * max_span;
        note = Some(format!(
            "{}: a table of at most {MAX_COMP_ENTRIES} entries at {step:.4} mm (1/8 of the pitch) covers {lo:.3}..{hi:.3} mm, not all of {want_lo:.3}..{want_hi:.3} mm; LinuxCNC holds the end values beyond it",
            axis.letter().to_ascii_uppercase()
        ));
    }
    let n = (((hi - lo) / step).round() as usize).clamp(1, MAX_COMP_ENTRIES - 1);
    let rows = (0..=n)
        .map(|i| {
            let nominal = lo + (hi - lo) * i as f64 / n as f64;
            let kk = nominal - k0;
            let cyclic = m.cyclic_error_mm(axis, kk);
            let e = m.position_error_mm(axis, kk) - cyclic + cyclic / attenuation;
            (nominal, -e + 0.5 * backlash_mm, -e - 0.5 * backlash_mm)
        })
        .collect();
    Ok((rows, note))
}

/// What to change in LinuxCNC (module docs).
pub fn plan(m: &MachineErrors, current: &Current, opts: &Options) -> Result<Plan> {
    let (unit, u, decimals, units_given) = machine_units(current);
    let mut p = Plan {
        title: format!(
            "LinuxCNC 2.9 (trivkins), joints X=0 Y=1 Z=2, machine units {unit}{}",
            if units_given {
                ""
            } else {
                " (assumed: give [TRAJ] LINEAR_UNITS in --current)"
            }
        ),
        ..Default::default()
    };
    p.notes.extend(defaults_note(current));
    let mut ini: Vec<String> = vec![];
    for axis in Axis::ALL {
        let k = axis.index();
        let key = format!("JOINT_{k}.BACKLASH");
        let old_table = table_in_force(current, k, u)?;
        if let Some((old_name, old)) = &old_table {
            for r in old {
                plausible::check_trim(old_name, "in force", r.0, r.1)?;
                plausible::check_trim(old_name, "in force", r.0, r.2)?;
            }
        }
        let cur_backlash = current.get(&key);
        if let (Some((name, _)), Some(b)) = (&old_table, cur_backlash) {
            p.notes.push(format!(
                "joint {k}: BACKLASH = {b} in force is ignored by LinuxCNC while COMP_FILE = {name} is set, so it is not counted"
            ));
        }
        // The backlash in force (mm): BACKLASH, or the table's forward − reverse trim.
        let (cur_mu, b0_mm) = match &old_table {
            Some((_, rows)) => {
                let mean = rows.iter().map(|r| r.1 - r.2).sum::<f64>() / rows.len() as f64;
                (Some(mean / u), mean)
            }
            None => (cur_backlash, cur_backlash.unwrap_or(0.0) * u),
        };
        let delta_mm = m.backlash_um[k].as_ref().map_or(0.0, |b| 1e-3 * b.value);
        let because_backlash = m.backlash_um[k].as_ref().map(|b| b.text());
        let to_change = m.position_dependent(axis) || because_backlash.is_some();
        if m.position_dependent(axis) || (old_table.is_some() && to_change) {
            let name = format!("{}.comp", axis.letter());
            let rows: Vec<CompRow>;
            let note;
            match &old_table {
                Some((old_name, old)) => {
                    // The trims in force plus the change, on the union of both tables' positions.
                    let (ours, n) = if m.position_dependent(axis) {
                        comp_table(m, axis, delta_mm, opts)?
                    } else {
                        (vec![(0.0, 0.5 * delta_mm, -0.5 * delta_mm)], None)
                    };
                    note = n;
                    let mut xs: Vec<f64> = old.iter().map(|r| r.0).collect();
                    if m.position_dependent(axis) {
                        xs.extend(ours.iter().map(|r| r.0));
                    }
                    xs.sort_by(f64::total_cmp);
                    xs.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
                    if xs.len() > MAX_COMP_ENTRIES {
                        return Err(Error::Usage(format!(
                            "joint {k}: merging {old_name} ({} entries) with the new trims needs {} entries, more than LinuxCNC's {MAX_COMP_ENTRIES}: give --travel {}=MIN:MAX within {old_name}'s span, or thin {old_name}",
                            old.len(),
                            xs.len(),
                            axis.letter()
                        )));
                    }
                    rows = xs
                        .into_iter()
                        .map(|x| {
                            let (f0, r0) = trims_at(old, x);
                            let (f1, r1) = trims_at(&ours, x);
                            (x, f0 + f1, r0 + r1)
                        })
                        .collect();
                    p.notes.push(format!(
                        "joint {k}: {name} is {old_name} in force ({} entries) with the change added at the same positions, not a replacement of it (LinuxCNC ignores BACKLASH while a COMP_FILE is set)",
                        old.len()
                    ));
                }
                None => {
                    let (r, n) = comp_table(m, axis, b0_mm + delta_mm, opts)?;
                    rows = r;
                    note = n;
                }
            }
            for r in &rows {
                plausible::check_trim(&name, "new", r.0, r.1)?;
                plausible::check_trim(&name, "new", r.0, r.2)?;
            }
            let mut text = String::new();
            for row in &rows {
                let (nominal, fwd, rev) = (row.0 / u, row.1 / u, row.2 / u);
                let line = match opts.comp_file_type {
                    0 => format!(
                        "{nominal:.6} {:.d$} {:.d$}\n",
                        nominal - fwd,
                        nominal - rev,
                        d = decimals + 1
                    ),
                    _ => format!("{nominal:.6} {fwd:.d$} {rev:.d$}\n", d = decimals + 1),
                };
                text.push_str(&line);
            }
            let mut sources: Vec<String> = vec![];
            if let Some((_, s)) = &m.scale_um_per_m[k] {
                sources.push(s.text());
            }
            if let Some(s) = &m.scale2_um_per_m2[k] {
                sources.push(s.text());
            }
            if let Some(c) = &m.cyclic[k] {
                sources.push(c.source.text());
            }
            sources.extend(because_backlash.clone());
            p.changes.push(Change {
                because: sources.join(", "),
                setting: format!("[JOINT_{k}] COMP_FILE"),
                unit: String::new(),
                current: 0.0,
                assumed: true,
                new: 0.0,
                decimals: 0,
                text: Some(format!(
                    "{name} ({} entries, COMP_FILE_TYPE = {})",
                    rows.len(),
                    opts.comp_file_type
                )),
            });
            if let Some(because) = because_backlash.clone().or_else(|| {
                (old_table.is_none() && b0_mm != 0.0)
                    .then(|| "the BACKLASH in force, which COMP_FILE overrides".into())
            }) {
                p.changes.push(change(
                    because,
                    format!("[JOINT_{k}] backlash in {name} (forward − reverse trim)"),
                    unit,
                    cur_mu,
                    0.0,
                    delta_mm / u,
                    decimals,
                ));
            }
            ini.push(format!("[JOINT_{k}]"));
            ini.push(format!("COMP_FILE = {name}"));
            ini.push(format!("COMP_FILE_TYPE = {}", opts.comp_file_type));
            p.files.push((name.clone(), text));
            if old_table.is_none() {
                p.notes.push(format!(
                    "joint {k}: BACKLASH is ignored while COMP_FILE is set, so {name}'s forward − reverse difference is the backlash compensation ({:.d$} {unit}; give a BACKLASH in force with --current to keep it); the file has no comments because LinuxCNC stops reading at the first line that is not three numbers",
                    (b0_mm + delta_mm) / u,
                    d = decimals
                ));
            }
            if m.position_dependent(axis) && opts.placement.table_ball_mm[k].is_none() {
                p.notes.push(format!(
                    "{name}: positions assume the table ball at machine {} = 0; give --table-ball {}=POSITION (its machine coordinate, G53) so the table sits where the errors were measured",
                    axis.letter().to_ascii_uppercase(),
                    axis.letter()
                ));
            }
            if m.position_dependent(axis) && opts.placement.travel_mm[k].is_none() {
                p.notes.push(format!(
                    "{name} spans the tested circle only; a scale error is linear, so --travel {}=MIN:MAX extends it over the axis",
                    axis.letter()
                ));
            }
            p.notes.extend(note);
        } else if let Some(b) = &m.backlash_um[k] {
            let c = change(
                b.text(),
                format!("[JOINT_{k}] BACKLASH"),
                unit,
                cur_mu,
                0.0,
                delta_mm / u,
                decimals,
            );
            if c.new < 0.0 {
                p.notes.push(format!(
                    "joint {k}: the total BACKLASH is negative: the axis runs ahead at reversal, so a compensation in force is too large; LinuxCNC applies the negative value as it is (±half), or lower the one in force to 0 and re-test"
                ));
            }
            ini.push(format!("[JOINT_{k}]"));
            ini.push(format!("BACKLASH = {:.d$}", c.new, d = decimals));
            p.changes.push(c);
        }
    }
    if !ini.is_empty() {
        p.blocks.push(Block {
            label: "the INI file (LinuxCNC 2.9; [AXIS_n] on 2.7)".into(),
            lines: ini,
        });
    }
    let mut hal = vec![];
    let mut by_hand = vec![];
    for pair in Pair::ALL {
        if let Some(s) = m.squareness(pair) {
            by_hand.push(super::square_mechanically(pair));
            let (i, j) = pair.axes();
            let key = format!("matrixkins.C_{}{}", i.letter(), j.letter());
            let c = change(
                s.text(),
                format!("HAL {key} (LinuxCNC 2.10/master only)"),
                "",
                current.get(&key),
                0.0,
                -1e-6 * s.value,
                10,
            );
            hal.push(format!("setp {key} {:.10}", c.new));
            p.changes.push(c);
        }
    }
    if !hal.is_empty() {
        p.blocks.push(Block {
            label: "a HAL file, LinuxCNC 2.10 (master) with [KINS] KINEMATICS = matrixkins".into(),
            lines: hal,
        });
        p.notes.push(format!("squareness: LinuxCNC 2.9 (trivkins) has no squareness compensation; the matrixkins lines need LinuxCNC 2.10/master (loadrt matrixkins, [KINS] KINEMATICS = matrixkins). On 2.9, {}", by_hand.join(", ")));
    }
    Ok(p)
}
