//! The program of a [`Plan`] in one controller's G-code: one block per segment (G0, G1, G2/G3, G4,
//! M0), in order, between a header that sets the modes and a program end.
//!
//! What every dialect gets: absolute positions (G90) in mm (G21) on the plan's 1 µm grid, always
//! with a decimal point and all three axes; arc centres as I/J/K offsets from the arc's start
//! (incremental: the default of all four), only the two of the arc's plane; an F word on every
//! G1/G2/G3; G3 for a ccw arc and G2 for a cw one in every plane; no spindle, coolant or tool
//! commands.
//!
//! | | LinuxCNC (`ballbar.ngc`) | grbl 1.1 (`ballbar.nc`) | Fanuc (`O1000.nc`) | Marlin 2 (`ballbar.gcode`) |
//! |---|---|---|---|---|
//! | comments | `( )` (also `;`) | `( )` (also `;`) | `( )`, upper case | `;` (`( )` only with `PAREN_COMMENTS`) |
//! | start | — | — | `%`, `O1000` | — |
//! | modes | `G21 G90 G94 G17 G40 G91.1`, `G64 P0.001` | `G21 G90 G94 G17 G40 G91.1` | `G21 G90 G94 G17 G40` | `G21 G90 G17` |
//! | dwell | `G4 P` seconds | `G4 P` seconds | `G4 X` seconds (`P` would be ms, no decimal point) | `G4 P` milliseconds (`S` seconds) |
//! | stop | `M0` | `M0` | `M0` | `M0` (needs an LCD, `EMERGENCY_PARSER` or host prompt support to resume) |
//! | end | `M2` | `M2` | `M30`, `%` | `M400` (finish moves; Marlin has no M2, and its M30 deletes a file) |
//!
//! Plane selection G17/G18/G19 in all four (Marlin: only with `CNC_WORKSPACE_PLANES`; without it
//! G18/G19 are ignored and arcs run in XY — do not run a yz or zx plan on such a Marlin). In
//! G18 the plane's axes are (Z, X) and in G19 (Y, Z): G2 is clockwise seen from the positive end
//! of the normal (RS274/NGC, ISO 6983; LinuxCNC's, grbl's and Marlin's arc code all measure
//! the angle in that order), so the plan's ccw (θ = atan2(j, i) growing, a rotation about +n) is
//! G3 in every plane. Other notes:
//!
//! - LinuxCNC: `G91.1` in case a previous program left `G90.1` (absolute centres) in force;
//!   `G64 P0.001` blends within 1 µm, so the machine does not stop where an arc is split.
//! - grbl: no `%` (not supported); `G91.1` is its only arc mode, written for clarity.
//! - Fanuc: a number without a decimal point can be read in least input increments (`X100` =
//!   0.1 mm on IS-B), hence the decimal point everywhere; comments are upper case ASCII.
//! - Marlin: G0 moves at the last feed (or `G0_FEEDRATE`), not a separate rapid rate; arcs are
//!   drawn as chords (`MM_PER_ARC_SEGMENT`, 1 mm by default: a 1.4 µm sagitta at R 90 mm), which
//!   the ballbar sees; `ARC_SUPPORT` must be on (the default).
use std::fmt::Write;

use super::{Dialect, Plan, Plane, Segment, Sense};

/// Program number of the Fanuc program (`O1000`).
pub const FANUC_PROGRAM_NUMBER: u32 = 1000;

/// A number as the program writes it: 3 decimals (the 1 µm grid), trailing zeros dropped but
/// one kept after the point (`90.0`, `-12.345`), never `-0.0`.
pub fn number(x: f64) -> String {
    let s = format!("{x:.3}");
    let s = s.trim_end_matches('0');
    let s = if s.ends_with('.') {
        format!("{s}0")
    } else {
        s.to_string()
    };
    if s == "-0.0" {
        "0.0".into()
    } else {
        s
    }
}

fn xyz(p: &[f64; 3]) -> String {
    format!("X{} Y{} Z{}", number(p[0]), number(p[1]), number(p[2]))
}

fn plane_code(p: Plane) -> &'static str {
    match p {
        Plane::Xy => "G17",
        Plane::Zx => "G18",
        Plane::Yz => "G19",
    }
}

struct Out {
    dialect: Dialect,
    text: String,
}

impl Out {
    fn line(&mut self, s: &str) {
        self.text.push_str(s);
        self.text.push('\n');
    }

    /// A comment line in the dialect's syntax (ASCII; no parentheses inside; Fanuc upper case).
    fn comment(&mut self, s: &str) {
        let clean: String = s
            .chars()
            .map(|c| match c {
                '(' | ')' | ';' => ' ',
                c if c.is_ascii() && !c.is_ascii_control() => c,
                _ => ' ',
            })
            .collect();
        let text = match self.dialect {
            Dialect::Fanuc => format!("({})", clean.to_ascii_uppercase()),
            Dialect::Marlin => format!("; {clean}"),
            Dialect::Linuxcnc | Dialect::Grbl => format!("({clean})"),
        };
        self.line(&text);
    }
}

/// The program of `plan` in `dialect` (see the module docs).
pub fn write_program(plan: &Plan, dialect: Dialect) -> String {
    let mut o = Out {
        dialect,
        text: String::new(),
    };
    if dialect == Dialect::Fanuc {
        o.line("%");
        o.line(&format!("O{FANUC_PROGRAM_NUMBER} (JDBB BALLBAR)"));
    }
    let c = &plan.centre_mm;
    let arc = if plan.arc.is_partial() {
        format!(
            "each a {}-degree arc from {} degrees, ccw then back cw",
            number(plan.arc.sweep_deg),
            number(plan.arc.start_deg)
        )
    } else {
        "each ccw then cw".to_string()
    };
    let what = if plan.purpose == super::Purpose::VolumetricTest {
        format!(
            "{} circles and arcs: xy circles at several heights, then zx and yz arcs, each ccw then cw",
            plan.circles.len()
        )
    } else {
        format!(
            "{} circles in plane {}, {arc}",
            plan.circles.len(),
            plan.plane.name()
        )
    };
    let feeds: Vec<String> = plan.feeds_mm_min().into_iter().map(number).collect();
    o.comment(&format!(
        "jdbb plan, {}: {what}, feed {} mm/min",
        plan.purpose.name(),
        feeds.join(", ")
    ));
    o.comment(&format!(
        "table ball centre {} mm in these coordinates",
        xyz(c)
    ));
    o.comment(&format!(
        "the program stops M0 at {}: mount the J-DBB there, then cycle start",
        xyz(&plan.start_mm)
    ));
    o.comment(&format!(
        "ball distance D stays within {}..{} mm, plan.json describes every block",
        number(plan.instrument.d_min_mm),
        number(plan.instrument.d_max_mm)
    ));
    let plane = plane_code(plan.plane);
    match dialect {
        Dialect::Linuxcnc => {
            o.line(&format!("G21 G90 G94 {plane} G40 G91.1"));
            o.line("G64 P0.001");
        }
        Dialect::Grbl => o.line(&format!("G21 G90 G94 {plane} G40 G91.1")),
        Dialect::Fanuc => o.line(&format!("G21 G90 G94 {plane} G40")),
        Dialect::Marlin => o.line(&format!("G21 G90 {plane}")),
    }
    let mut current_plane = plan.plane;
    let mut circle_announced = None;
    for s in &plan.segments {
        match s {
            Segment::Rapid { to_mm, .. } => o.line(&format!("G0 {}", xyz(to_mm))),
            Segment::Stop => o.line("M0"),
            Segment::Dwell { seconds } => {
                let block = match dialect {
                    Dialect::Linuxcnc | Dialect::Grbl => format!("G4 P{}", number(*seconds)),
                    Dialect::Fanuc => format!("G4 X{}", number(*seconds)),
                    Dialect::Marlin => format!("G4 P{}", (seconds * 1000.0).round() as u64),
                };
                o.line(&block);
            }
            Segment::Line {
                to_mm,
                feed_mm_min,
                circle,
                ..
            } => {
                if circle_announced != Some(*circle) {
                    let ci = &plan.circles[*circle];
                    o.comment(&format!(
                        "circle {} of {}: radius {} mm, height {} mm, D {} mm",
                        circle + 1,
                        plan.circles.len(),
                        number(ci.radius_mm),
                        number(ci.height_mm),
                        number(ci.d_mm)
                    ));
                    circle_announced = Some(*circle);
                }
                o.line(&format!("G1 {} F{}", xyz(to_mm), number(*feed_mm_min)));
            }
            Segment::Arc {
                centre_mm,
                plane,
                sense,
                feed_mm_min,
                from_mm,
                to_mm,
                ..
            } => {
                if *plane != current_plane {
                    o.line(plane_code(*plane));
                    current_plane = *plane;
                }
                let g = match sense {
                    Sense::Ccw => "G3",
                    Sense::Cw => "G2",
                };
                let off = |k: usize| number(centre_mm[k] - from_mm[k]);
                let ijk = match plane {
                    Plane::Xy => format!("I{} J{}", off(0), off(1)),
                    Plane::Yz => format!("J{} K{}", off(1), off(2)),
                    Plane::Zx => format!("I{} K{}", off(0), off(2)),
                };
                let mut line = String::new();
                let _ = write!(line, "{g} {} {ijk} F{}", xyz(to_mm), number(*feed_mm_min));
                o.line(&line);
            }
        }
    }
    match dialect {
        Dialect::Linuxcnc | Dialect::Grbl => o.line("M2"),
        Dialect::Fanuc => {
            o.line("M30");
            o.line("%");
        }
        Dialect::Marlin => {
            o.comment(
                "end: wait for the moves to finish. Marlin has no M2, and its M30 deletes a file",
            );
            o.line("M400");
        }
    }
    o.text
}

#[cfg(test)]
mod tests {
    use super::number;

    #[test]
    fn numbers_keep_a_decimal_point_and_the_grid() {
        assert_eq!(number(90.0), "90.0");
        assert_eq!(number(-12.345), "-12.345");
        assert_eq!(number(0.1), "0.1");
        assert_eq!(number(-0.0), "0.0");
        assert_eq!(number(-0.0001), "0.0");
        assert_eq!(number(188.0004), "188.0");
        assert_eq!(number(1000.0), "1000.0");
    }
}
