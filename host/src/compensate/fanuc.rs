//! Fanuc Series 0i-F / 30i: backlash (Nos. 1851/1852) and pitch-error compensation (Nos.
//! 3620–3624 and the table of points), in the axis' detection unit; squareness only through the
//! straightness compensation option, else mechanically.
//!
//! Semantics (sources in `docs/controllers.md`; parameter manuals B-64120 (0i-C), B-63090 (21i),
//! B-63980 (0i-PB), technical report A-77810E (bidirectional pitch error compensation)):
//! - **1851** backlash compensating value, word axis, **detection unit**, −9999…+9999; the control
//!   outputs the whole value at each reversal, "the positive or negative direction for
//!   compensating values is the direction of movement", so the setting that cancels a lost
//!   motion b is **B = b** (as for the open controllers). **1852** (rapid traverse) is used only
//!   when bit RBK (No. 1800#4) is 1; a ball bar test runs at cutting feed and does not measure it.
//!   Both take effect after the first reference position return after power-on.
//! - Detection unit: the least command increment of the increment system divided by the command
//!   multiplier CMR (No. 1820: 2·CMR for CMR 1…48): IS-B 0.001 mm / 0.0001 inch, IS-C 0.0001 mm /
//!   0.00001 inch (No. 1013#1 ISC per axis; No. 1001#0 INM for an inch machine). Without them in
//!   `--current`, IS-B, mm and CMR 1 are assumed and the title says so.
//! - Pitch error compensation: points numbered along the axis, No. 3620 the point of the
//!   reference position, 3621/3622 the most distant points on the − and + sides, 3623 the
//!   magnification (the values are in detection unit × magnification), 3624 the interval (in the
//!   least input increment). The value of point n is the **increment** of the compensation over
//!   the section ending at point n (from point n−1 to n, counted in machine coordinates from the
//!   reference position, point 3620 at machine 0): the compensation at point n is the sum of the
//!   values of the points between the reference point and n (negative side: minus the sum of the
//!   points above n up to the reference point). The value is added in the direction of its sign,
//!   so it is −δ. The table counts from the reference position (machine 0 here: No. 1240 = 0
//!   assumed), so it spans the tested travel and the reference position. At most 128 points
//!   between the extremes (service literature); each value −7…+7 (Series 16i/0i literature; not
//!   confirmed for 0i-F/30i), so the magnification is raised until they fit. Takes effect after
//!   power off/on and a reference position return. Between points the value of a section is
//!   output at its point ("the compensation value is output at the compensation position No.
//!   corresponding to each section", B-63980EN p. 100, whose figure of the compensation amount
//!   is a staircase): the compensation is held between points, so up to the largest step between
//!   neighbouring points is left there; the output says how much, and which interval would
//!   leave under 2 % (interpolation between points is a separate option, not assumed).
//! - Not confirmed and said so in the output: the input format of the table (`N10000+point P…`,
//!   as in a parameter backup), inclination compensation (Nos. 5861–5874) and the straightness
//!   compensation option's parameters.
//!
//! # `--current` format
//! A parameter backup (`CNC-PARA.TXT`, as punched out): `N<number>` followed by `A<axis>P<value>`
//! words (or one `P<value>` for a non-axis parameter), `Q…` words and `%` ignored; axes 1, 2, 3
//! are X, Y, Z; bit parameters as eight digits #7…#0; pitch error data as `N1xxxx P…` (point
//! xxxx). A value that is not a number is an error at its line and column.
use std::fmt::Write;
use std::path::Path;

use super::current::Current;
use super::{
    defaults_note, table_change, table_span_mm, Block, Cannot, MachineErrors, Placement, Plan,
};
use crate::model::{Axis, Pair};
use crate::{Error, Result};

/// Most points between the extremes of one axis' pitch error table.
pub const MAX_POINTS: i64 = 128;
/// Largest value of one pitch error point (detection unit × magnification).
pub const MAX_POINT_VALUE: i64 = 7;
/// The first data number of the pitch error table in a parameter backup.
pub const PITCH_DATA_BASE: u32 = 10000;
/// The first point each axis' new table starts at (X, Y, Z) when none is in force.
const FIRST_POINT: [i64; 3] = [0, 200, 400];

/// The axis number (A1, A2, A3) of `a`.
fn axis_no(a: Axis) -> usize {
    a.index() + 1
}

/// The key of parameter `no` of axis `a` (or none) in [`Current`].
fn key(no: u32, a: Option<Axis>) -> String {
    match a {
        Some(a) => format!("{no}.{}", axis_no(a)),
        None => format!("{no}"),
    }
}

/// Bit `bit` of a bit parameter in force (eight digits #7…#0), if given.
fn bit(current: &Current, no: u32, a: Option<Axis>, bit: usize) -> Option<bool> {
    let t = current.text(&key(no, a))?;
    let digits: Vec<char> = t.chars().collect();
    (digits.len() == 8).then(|| digits[7 - bit] == '1')
}

/// The units of axis `a`: (detection unit in mm, least input increment in mm, the words for the
/// title, what was assumed for want of a parameter in `--current`).
fn detection_unit(current: &Current, a: Axis) -> (f64, f64, String, Option<String>) {
    let inch = bit(current, 1001, None, 0);
    let isc = bit(current, 1013, Some(a), 1);
    let cmr = current.get(&key(1820, Some(a))).and_then(|v| {
        if (2.0..=96.0).contains(&v) {
            Some(v / 2.0)
        } else if v > 100.0 {
            Some(1.0 / (v - 100.0))
        } else {
            None
        }
    });
    let least = match (inch == Some(true), isc == Some(true)) {
        (false, false) => 0.001,
        (false, true) => 0.0001,
        (true, false) => 0.0001 * 25.4,
        (true, true) => 0.00001 * 25.4,
    };
    let words = format!(
        "IS-{} {}",
        if isc == Some(true) { "C" } else { "B" },
        if inch == Some(true) { "inch" } else { "mm" }
    );
    let assumed: Vec<&str> = [
        (inch.is_none(), "mm (No. 1001#0)"),
        (isc.is_none(), "IS-B (No. 1013#1)"),
        (cmr.is_none(), "CMR 1 (No. 1820)"),
    ]
    .iter()
    .filter_map(|(a, w)| a.then_some(*w))
    .collect();
    (
        least / cmr.unwrap_or(1.0),
        least,
        words,
        (!assumed.is_empty()).then(|| assumed.join(", ")),
    )
}

/// Read the `--current` format (module docs).
pub fn parse_current(path: &Path, text: &str) -> Result<Current> {
    let mut c = Current::none();
    for (n, line) in text.lines().enumerate() {
        let body = line.split(';').next().unwrap_or("");
        let t = body.trim();
        if t.is_empty() || t.starts_with('%') || t.starts_with('#') {
            continue;
        }
        // Words: a letter and the text up to the next word's letter (spaces optional, as punched).
        let mut words: Vec<(char, String, usize)> = vec![];
        for (i, ch) in body.char_indices() {
            // The backup's words are N, A, P, Q; another letter is a typo inside a value.
            if "NAPQnapq".contains(ch) {
                words.push((ch.to_ascii_uppercase(), String::new(), i + 1));
            } else if !ch.is_whitespace() {
                match words.last_mut() {
                    Some(w) => w.1.push(ch),
                    None => {
                        return Err(Error::input(
                            path,
                            n + 1,
                            i + 1,
                            format!("`{}` is not a parameter line (N<number> A<axis> P<value>) of a Fanuc parameter backup", t),
                        ))
                    }
                }
            }
        }
        let Some((_, no, col)) = words.iter().find(|w| w.0 == 'N') else {
            continue;
        };
        let no: u32 = no.parse().map_err(|_| {
            Error::input(
                path,
                n + 1,
                *col,
                format!("N{no}: a parameter number is a whole number"),
            )
        })?;
        let mut axis: Option<usize> = None;
        for (letter, value, col) in &words {
            match letter {
                'A' => {
                    axis = Some(value.parse().map_err(|_| {
                        Error::input(
                            path,
                            n + 1,
                            *col,
                            format!("N{no}: A{value} is not an axis number"),
                        )
                    })?)
                }
                'P' => {
                    let k = if no >= PITCH_DATA_BASE {
                        format!("PITCH.{}", no - PITCH_DATA_BASE)
                    } else {
                        match axis {
                            Some(a) => format!("{no}.{a}"),
                            None => format!("{no}"),
                        }
                    };
                    let v = super::current::number(path, n + 1, col + 1, value, &format!("N{no}"))?;
                    if value.len() == 8 && value.chars().all(|ch| ch == '0' || ch == '1') {
                        c.set_text(k.clone(), value.clone());
                    }
                    c.set(k, v);
                }
                _ => {}
            }
        }
    }
    Ok(c)
}

/// A nice interval (mm) of at least `min_mm`: 1, 2, 2.5 or 5 times a power of ten.
fn nice_interval(min_mm: f64) -> f64 {
    let p = 10f64.powf(min_mm.log10().floor());
    [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|f| f * p)
        .find(|v| *v >= min_mm * (1.0 - 1e-12))
        .unwrap_or(10.0 * p)
}

/// The pitch error table of one axis (module docs).
struct PitchTable {
    reference_point: i64,
    first_point: i64,
    last_point: i64,
    interval_mm: f64,
    magnification: i64,
    /// (point, value in detection unit × magnification), the new totals.
    values: Vec<(i64, i64)>,
    /// Whether a table was in force (its numbers kept, its values added to).
    in_force: bool,
}

/// The pitch error table of `a` (None if the axis has no position-dependent error or the
/// cyclic error cannot be followed, with the reason in `p`).
fn pitch_table(
    m: &MachineErrors,
    a: Axis,
    current: &Current,
    placement: &Placement,
    unit_mm: f64,
    least_input_mm: f64,
    p: &mut Plan,
) -> Result<Option<PitchTable>> {
    let (lo, hi) = table_span_mm(m, a, placement, Some(0.0))?;
    let g = |no: u32| current.get(&key(no, Some(a)));
    let letter = a.letter().to_ascii_uppercase();
    let in_force = match (g(3620), g(3621), g(3622), g(3624)) {
        (Some(r), Some(f), Some(l), Some(i)) if i > 0.0 => Some((r, f, l, i)),
        _ => None,
    };
    let (reference_point, first_point, last_point, interval_mm) = match in_force {
        Some((r, f, l, i)) => (r as i64, f as i64, l as i64, i * least_input_mm),
        None => {
            let mut interval = nice_interval(((hi - lo) / (MAX_POINTS - 1) as f64).max(10.0));
            if let Some(c) = &m.cyclic[a.index()] {
                let fine = c.pitch_mm / 8.0;
                if (hi - lo) / fine <= (MAX_POINTS - 1) as f64 {
                    interval = fine;
                } else {
                    p.cannot.push(Cannot {
                        effect: c.source.text(),
                        why: format!(
                            "{letter}: a cyclic error of {:.3} mm pitch needs pitch error points every {:.3} mm, {} of them over {lo:.1}..{hi:.1} mm (with the reference position), more than the {MAX_POINTS} a Fanuc axis has",
                            c.pitch_mm,
                            fine,
                            ((hi - lo) / fine).ceil()
                        ),
                        instead: "the table below takes the scale only; a cyclic error at the screw's pitch is a screw, nut or support bearing running out: check them (or test a shorter travel with --travel)".into(),
                    });
                }
            }
            let below = ((-lo) / interval).ceil().max(0.0) as i64;
            let above = (hi / interval).ceil().max(0.0) as i64;
            let first = FIRST_POINT[a.index()];
            (first + below, first, first + below + above, interval)
        }
    };
    let follows_cyclic = m.cyclic[a.index()]
        .as_ref()
        .is_some_and(|c| interval_mm <= c.pitch_mm / 8.0 + 1e-9);
    // The correction at each point, counted from the reference position, in detection units.
    let correction_units = |n: i64| -> f64 {
        let x = (n - reference_point) as f64 * interval_mm;
        let k0 = placement.table_ball_mm[a.index()].unwrap_or(0.0);
        let mut e = m.position_error_mm(a, x - k0) - m.position_error_mm(a, -k0);
        if !follows_cyclic {
            e -= m.cyclic_error_mm(a, x - k0) - m.cyclic_error_mm(a, -k0);
        }
        -e / unit_mm
    };
    let old = |n: i64| current.get(&format!("PITCH.{n}")).unwrap_or(0.0) as i64;
    let old_magnification = g(3623).filter(|v| *v >= 1.0).unwrap_or(1.0) as i64;
    let mut magnification = if in_force.is_some() {
        old_magnification
    } else {
        1
    };
    loop {
        let mut values = vec![];
        let mut prev = (correction_units(first_point) / magnification as f64).round() as i64;
        values.push((first_point, old(first_point)));
        for n in first_point + 1..=last_point {
            let now = (correction_units(n) / magnification as f64).round() as i64;
            values.push((n, old(n) + now - prev));
            prev = now;
        }
        let worst = values.iter().map(|v| v.1.abs()).max().unwrap_or(0);
        if worst <= MAX_POINT_VALUE || in_force.is_some() {
            if worst > MAX_POINT_VALUE {
                p.notes.push(format!(
                    "{letter}: a pitch error value reaches {worst} at magnification {magnification} (No. 3623 in force); the Series 16i/0i literature allows −7…+7: raise No. 3623 and halve the table in force, or check the control's range"
                ));
            }
            if (last_point - first_point) > MAX_POINTS {
                p.notes.push(format!("{letter}: the table in force has {} points between its extremes; the service literature gives at most {MAX_POINTS}", last_point - first_point));
            }
            p.notes.extend(between_points_note(
                letter,
                table_span_mm(m, a, placement, None)?,
                |n| (n - reference_point) as f64 * interval_mm,
                |n| correction_units(n) * unit_mm * 1e3,
                (first_point, last_point),
                interval_mm,
            ));
            return Ok(Some(PitchTable {
                reference_point,
                first_point,
                last_point,
                interval_mm,
                magnification,
                values,
                in_force: in_force.is_some(),
            }));
        }
        magnification += 1;
    }
}

/// What is left between the points of a table at `interval_mm` over the tested travel
/// `tested_mm`: the control holds a section's compensation between its points (a staircase,
/// module docs), so up to the largest step between neighbouring points (µm) of the correction
/// `correction_um` at point n (machine position `at_mm(n)`) is left; said with the interval that
/// would leave under 2 % of the correction's range, if the table's leaves more.
fn between_points_note(
    letter: char,
    tested_mm: (f64, f64),
    at_mm: impl Fn(i64) -> f64,
    correction_um: impl Fn(i64) -> f64,
    (first_point, last_point): (i64, i64),
    interval_mm: f64,
) -> Option<String> {
    let inside =
        |n: i64| (tested_mm.0 - interval_mm..=tested_mm.1 + interval_mm).contains(&at_mm(n));
    let points: Vec<i64> = (first_point..=last_point).filter(|&n| inside(n)).collect();
    let c: Vec<f64> = points.iter().map(|&n| correction_um(n)).collect();
    let range_um =
        c.iter().cloned().fold(f64::MIN, f64::max) - c.iter().cloned().fold(f64::MAX, f64::min);
    let step_um = c
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0.0, f64::max);
    if range_um.is_nan() || range_um <= 0.0 || step_um <= 0.02 * range_um {
        return None;
    }
    // 1.5 % between points: room for what is left at the points (the integers, the fit).
    let need_mm = interval_mm * 0.015 * range_um / step_um;
    let count = ((tested_mm.1.max(0.0) - tested_mm.0.min(0.0)) / need_mm).ceil();
    Some(format!(
        "{letter}: between its points the control holds each section's compensation (a staircase, B-63980EN p. 100), so up to {step_um:.2} µm of the {range_um:.2} µm corrected over the tested travel is left between the points every {interval_mm} mm ({:.1} %); under 2 % with what is left at the points needs an interval No. 3624 of {need_mm:.2} mm or less ({count} points from the reference position{}), or the interpolation-type pitch error compensation option",
        100.0 * step_um / range_um,
        if count > MAX_POINTS as f64 { format!(", more than the {MAX_POINTS} of the service literature") } else { String::new() }
    ))
}

/// What to change on a Fanuc control (module docs).
pub fn plan(m: &MachineErrors, current: &Current, placement: &Placement) -> Result<Plan> {
    let (_, _, words, assumed) = detection_unit(current, Axis::X);
    let mut p = Plan {
        title: format!(
            "Fanuc Series 0i-F / 30i, axes X=1 Y=2 Z=3, {words}{}",
            match assumed {
                Some(a) => format!(" (assumed: {a}; give them in --current CNC-PARA.TXT)"),
                None => String::new(),
            }
        ),
        ..Default::default()
    };
    p.notes.extend(defaults_note(current));
    let mut params: Vec<String> = vec![];
    let mut table_text = String::new();
    for a in Axis::ALL {
        let (unit_mm, least_input_mm, _, _) = detection_unit(current, a);
        let letter = a.letter().to_ascii_uppercase();
        if let Some(b) = &m.backlash_um[a.index()] {
            let k = key(1851, Some(a));
            let cur = current.get(&k);
            let delta = (1e-3 * b.value / unit_mm).round();
            let c = super::change(
                b.text(),
                format!("No. 1851 (backlash, cutting feed) {letter}"),
                &format!("× {} µm (detection unit)", fmt_um(unit_mm)),
                cur,
                0.0,
                delta,
                0,
            );
            if c.new.abs() > 9999.0 || (c.new * unit_mm).abs() > super::plausible::MAX_BACKLASH_MM {
                return Err(Error::Usage(format!(
                    "No. 1851 {letter} would be {} detection units ({:.4} mm): beyond −9999…+9999 or {} mm, a worn or loose screw or nut to repair, not a setting. Check the diagnosis and the values in force (--current)",
                    c.new,
                    c.new * unit_mm,
                    super::plausible::MAX_BACKLASH_MM
                )));
            }
            params.push(format!("N1851 A{} P{:.0}", axis_no(a), c.new));
            p.changes.push(c);
        }
        if !m.position_dependent(a) {
            continue;
        }
        let Some(t) = pitch_table(m, a, current, placement, unit_mm, least_input_mm, &mut p)?
        else {
            continue;
        };
        let because = m.position_sources(a);
        p.changes.push(table_change(
            because.join(", "),
            format!("pitch error compensation {letter}"),
            t.in_force,
            format!(
                "points {}..{} every {:.4} mm, reference position at point {}, magnification {}{}",
                t.first_point,
                t.last_point,
                t.interval_mm,
                t.reference_point,
                t.magnification,
                if t.in_force {
                    " (the table in force, values added to)"
                } else {
                    ""
                }
            ),
        ));
        if !t.in_force {
            let n = axis_no(a);
            params.push(format!("N3620 A{n} P{}", t.reference_point));
            params.push(format!("N3621 A{n} P{}", t.first_point));
            params.push(format!("N3622 A{n} P{}", t.last_point));
            params.push(format!("N3623 A{n} P{}", t.magnification));
            params.push(format!("N3624 A{n} P{:.0}", t.interval_mm / least_input_mm));
            p.notes.push(format!(
                "{letter}: points {}..{} are jdbb's choice; if the machine builder's table uses other numbers, keep theirs and give the backup with --current so the values are added to it. The interval must be at least the rapid traverse rate / 7500 (mm/min → mm; service literature, not confirmed for 0i-F/30i)",
                t.first_point, t.last_point
            ));
        }
        let _ = writeln!(
            table_text,
            "({letter}: point, value in {} µm × {})",
            fmt_um(unit_mm),
            t.magnification
        );
        for (n, v) in &t.values {
            let _ = writeln!(table_text, "N{} P{v}", PITCH_DATA_BASE as i64 + n);
        }
    }
    if !params.is_empty() {
        p.blocks.push(Block {
            label:
                "the parameter screen (PWE = 1; then power off/on and a reference position return)"
                    .into(),
            lines: params,
        });
    }
    if !table_text.is_empty() {
        p.files.push(("pitch.txt".into(), table_text));
        p.notes.push("pitch.txt: the values on the pitch error compensation screen, one per point, as increments from the point below; N10000+point is the data number of a parameter backup (service literature, not confirmed from B-64490/B-64610). Power off/on and a reference position return after entering them; inclination compensation (Nos. 5861–5874, an option) could take a scale alone, but its semantics were not confirmed, so jdbb writes the pitch table".into());
    }
    if m.backlash_um.iter().any(|b| b.is_some()) {
        p.notes.push("No. 1852 (backlash at rapid traverse) is used only with No. 1800#4 RBK = 1; this test ran at cutting feed and does not measure it: leave it, or set it from a test at rapid traverse".into());
    }
    for pair in Pair::ALL {
        if let Some(s) = m.squareness(pair) {
            let (i, j) = pair.axes();
            p.cannot.push(Cannot {
                effect: s.text(),
                why: format!(
                    "a Fanuc control has no squareness setting; {} leaning on {} can be taken only by the straightness compensation option (its parameters are not confirmed here)",
                    i.letter().to_ascii_uppercase(),
                    j.letter().to_ascii_uppercase()
                ),
                instead: format!("{} (shim or scrape the column/saddle); if the machine has the straightness compensation option, ask the builder to enter it", super::square_mechanically(pair)),
            });
        }
    }
    Ok(p)
}

/// A detection unit in µm for people: 1, 0.1, 2.54, 0.254.
fn fmt_um(unit_mm: f64) -> String {
    let um = unit_mm * 1e3;
    let s = format!("{um:.5}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parameter_backup_is_read_with_its_units_and_bad_values_located() {
        let text = "%\nN01001P00000001\nN01013A1P00000010A2P00000010A3P00000000\nN01851 A1 P12 A2 P-3\nN10005P-2\n%\n";
        let c = parse_current(Path::new("CNC-PARA.TXT"), text).unwrap();
        assert_eq!(c.get("1851.1"), Some(12.0));
        assert_eq!(c.get("1851.2"), Some(-3.0));
        assert_eq!(c.get("PITCH.5"), Some(-2.0));
        // Inch machine, IS-C on X: 0.00001 inch.
        let (u, _, words, _) = detection_unit(&c, Axis::X);
        assert!((u - 0.000254).abs() < 1e-12, "{u}");
        assert_eq!(words, "IS-C inch");
        let (u, _, _, _) = detection_unit(&c, Axis::Z);
        assert!((u - 0.00254).abs() < 1e-12, "{u}");
        let e = parse_current(Path::new("p.txt"), "N1851 A1 P1O\n").unwrap_err();
        assert!(e.to_string().contains("p.txt:1:11: N1851"), "{e}");
        assert_eq!(e.exit_code(), 2);
    }

    #[test]
    fn nice_intervals() {
        assert_eq!(nice_interval(10.0), 10.0);
        assert_eq!(nice_interval(11.0), 20.0);
        assert_eq!(nice_interval(2.1), 2.5);
    }
}
