//! G-code text → the list of things the machine does ([`Block`]s: rapid, feed line, arc, dwell,
//! program stop), with the source line of each. Words come from the `gcode` crate's tokenizer; the
//! meaning (modal state, dialect rules) is ours, written from the controllers' documented
//! behaviour — see the [module docs](super) for the table of what each dialect means.
//!
//! Numbers are read in full (f64) precision, not as the parser's f32 (see `words.rs`).

use super::words::{read_blocks, RawBlock, Word};

/// Which controller's G-code the program is written for. It decides the units of `G4` and
/// whether `O` program numbers and Fanuc's decimal-point rule apply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Dialect {
    /// LinuxCNC (RS274/NGC): `G4 P` seconds.
    LinuxCnc,
    /// grbl / grblHAL: `G4 P` seconds.
    Grbl,
    /// Fanuc (and look-alikes): `G4 X` seconds (`X` without a decimal point: ms) or `G4 P` ms;
    /// `O` program numbers and `%` lines; lengths without a decimal point in 0.001 mm unless
    /// [`FanucInput::Calculator`].
    Fanuc,
    /// Marlin: `G4 P` milliseconds or `G4 S` seconds.
    Marlin,
}

impl Dialect {
    /// All dialects, for tests that run over each.
    pub const ALL: [Dialect; 4] = [
        Dialect::LinuxCnc,
        Dialect::Grbl,
        Dialect::Fanuc,
        Dialect::Marlin,
    ];

    /// The name used on the command line and in plan.json (`linuxcnc`, `grbl`, `fanuc`, `marlin`).
    pub fn name(self) -> &'static str {
        match self {
            Dialect::LinuxCnc => "linuxcnc",
            Dialect::Grbl => "grbl",
            Dialect::Fanuc => "fanuc",
            Dialect::Marlin => "marlin",
        }
    }
}

impl std::str::FromStr for Dialect {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Dialect::ALL
            .into_iter()
            .find(|d| d.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("unknown dialect {s:?}: use linuxcnc, grbl, fanuc or marlin"))
    }
}

/// How a Fanuc control reads a length written without a decimal point (parameter "decimal
/// point input", DPI): `X100` is 0.1 mm on a factory-set control, 100 mm with calculator input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FanucInput {
    /// Least input increment, 0.001 mm (and 0.001 s for `G4 X`): the factory setting.
    #[default]
    LeastIncrement,
    /// Calculator-type input: `X100` = 100 mm, `G4 X2` = 2 s.
    Calculator,
}

/// How to read a program.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProgramOptions {
    /// The controller the program is written for.
    pub dialect: Dialect,
    /// Fanuc only: lengths without a decimal point.
    pub fanuc_input: FanucInput,
}

impl ProgramOptions {
    /// Options for `dialect` with the controller's factory settings.
    pub fn new(dialect: Dialect) -> Self {
        ProgramOptions {
            dialect,
            fanuc_input: FanucInput::default(),
        }
    }
}

/// Working plane of `G2`/`G3` (`G17`, `G18`, `G19`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    /// G17: plane axes X, Y; normal +Z.
    Xy,
    /// G18: plane axes Z, X; normal +Y (Z × X = Y).
    Zx,
    /// G19: plane axes Y, Z; normal +X.
    Yz,
}

impl Plane {
    /// Machine axes (a, b, n) with a × b = n: the arc angle θ = atan2(b − b_c, a − a_c) grows
    /// counter-clockwise seen from +n, which is `G3`.
    pub fn axes(self) -> (usize, usize, usize) {
        match self {
            Plane::Xy => (0, 1, 2),
            Plane::Zx => (2, 0, 1),
            Plane::Yz => (1, 2, 0),
        }
    }
}

/// A circular (or helical) move, geometry resolved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcMove {
    /// Start point (mm, program coordinates).
    pub from: [f64; 3],
    /// End point (mm).
    pub to: [f64; 3],
    /// Centre (mm); its normal-axis coordinate is the start's.
    pub centre: [f64; 3],
    /// Plane of the arc.
    pub plane: Plane,
    /// Radius at the start and at the end (mm); they differ by at most
    /// [`ARC_RADIUS_TOLERANCE_MM`], the radius changing linearly with angle in between.
    pub radius_mm: [f64; 2],
    /// Angle of the start point, atan2(b, a) about the centre (rad).
    pub theta0_rad: f64,
    /// Signed sweep (rad): positive = counter-clockwise seen from +n (`G3`), |sweep| ≤ 2π.
    pub sweep_rad: f64,
    /// Programmed feed (mm/min).
    pub feed_mm_min: f64,
}

/// What one program line makes the machine do.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Action {
    /// `G0`: straight line at the rapid rate.
    Rapid {
        /// Start (mm).
        from: [f64; 3],
        /// End (mm).
        to: [f64; 3],
    },
    /// `G1`: straight line at the programmed feed.
    Line {
        /// Start (mm).
        from: [f64; 3],
        /// End (mm).
        to: [f64; 3],
        /// Feed (mm/min).
        feed_mm_min: f64,
    },
    /// `G2`/`G3`.
    Arc(ArcMove),
    /// `G4`: stand still.
    Dwell {
        /// Duration (s), converted from the dialect's units.
        seconds: f64,
    },
    /// `M0`, or `M1` (`optional`): wait for the operator's cycle start.
    Stop {
        /// `M1`.
        optional: bool,
    },
}

/// One executed program line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Block {
    /// Source line, 1-based.
    pub line: usize,
    /// `N` number, if written.
    pub n: Option<u32>,
    /// What it does.
    pub action: Action,
    /// Exact-stop mode (`G61`) was in force: the machine stops at the end of this move.
    pub exact_stop: bool,
}

/// A parsed program: the actions in order, up to the program end (`M2`/`M30`, or the last line).
#[derive(Debug, Clone, PartialEq)]
pub struct Program {
    /// How it was read.
    pub options: ProgramOptions,
    /// Where the machine was when the program started (mm).
    pub initial_mm: [f64; 3],
    /// The actions.
    pub blocks: Vec<Block>,
    /// Line of `M2`/`M30`, if the program ended with one.
    pub end_line: Option<usize>,
}

/// Start and end radius of an arc may differ by this much (mm): the rounding of coordinates
/// printed with 4 decimals is < 1e-4 mm; anything larger is a wrong centre, and we refuse it.
pub const ARC_RADIUS_TOLERANCE_MM: f64 = 0.002;

/// Why a program was refused; the message names the line and what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct ProgramError {
    /// Source line, 1-based.
    pub line: usize,
    /// What is wrong and what to do.
    pub message: String,
}

fn err<T>(line: usize, message: impl Into<String>) -> Result<T, ProgramError> {
    Err(ProgramError {
        line,
        message: message.into(),
    })
}

// ---------------------------------------------------------------------------------------------
// Raw blocks → actions.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Motion {
    Rapid,
    Line,
    Cw,
    Ccw,
}

struct Interpreter {
    opts: ProgramOptions,
    pos: [f64; 3],
    motion: Option<Motion>,
    plane: Plane,
    incremental: bool,
    feed_mm_min: Option<f64>,
    exact_stop: bool,
}

/// Read a program: the actions the machine performs, starting at `initial_mm`. Anything the
/// simulator does not implement is refused with its line number rather than guessed.
pub fn parse_program(
    text: &str,
    opts: ProgramOptions,
    initial_mm: [f64; 3],
) -> Result<Program, ProgramError> {
    let raw_blocks = read_blocks(text)?;
    let mut it = Interpreter {
        opts,
        pos: initial_mm,
        motion: None,
        plane: Plane::Xy,
        incremental: false,
        feed_mm_min: None,
        exact_stop: false,
    };
    let mut blocks = Vec::new();
    let mut end_line = None;
    for raw in &raw_blocks {
        if it.block(raw, &mut blocks)? {
            end_line = Some(raw.line);
            break;
        }
    }
    Ok(Program {
        options: opts,
        initial_mm,
        blocks,
        end_line,
    })
}

fn axis_index(letter: char) -> Option<usize> {
    match letter {
        'X' => Some(0),
        'Y' => Some(1),
        'Z' => Some(2),
        _ => None,
    }
}

impl Interpreter {
    /// A length word in mm (Fanuc: integers may be least increments).
    fn length(&self, w: &Word) -> f64 {
        if self.opts.dialect == Dialect::Fanuc
            && !w.point
            && self.opts.fanuc_input == FanucInput::LeastIncrement
        {
            w.value / 1000.0
        } else {
            w.value
        }
    }

    /// Interpret one line; `Ok(true)` at the program end.
    fn block(&mut self, raw: &RawBlock, out: &mut Vec<Block>) -> Result<bool, ProgramError> {
        let line = raw.line;
        let dialect = self.opts.dialect;
        if raw.o.is_some() && dialect != Dialect::Fanuc {
            return err(
                line,
                format!(
                    "O words (subroutines, program numbers) are not supported in {}; remove the line",
                    dialect.name()
                ),
            );
        }
        if raw.t {
            return err(line, "tool changes (T) are not supported: remove them");
        }
        // Words by letter, each at most once.
        let mut words: [Option<Word>; 26] = [None; 26];
        for w in &raw.words {
            let Some(i) = (w.letter as u32)
                .checked_sub('A' as u32)
                .filter(|&i| i < 26)
            else {
                return err(line, format!("unknown word {:?}", w.letter));
            };
            if words[i as usize].is_some() {
                return err(line, format!("{} appears twice in one line", w.letter));
            }
            words[i as usize] = Some(*w);
        }
        let mut take = |c: char| words[(c as u8 - b'A') as usize].take();

        // G codes by modal group.
        // Some(None) = G80 (motion mode off).
        let mut motion: Option<Option<Motion>> = None;
        let mut plane = None;
        let mut distance = None;
        let mut dwell = false;
        let mut path_mode = None;
        for &(g, minor) in &raw.g {
            let name = if minor == 0 {
                format!("G{g}")
            } else {
                format!("G{g}.{minor}")
            };
            let clash = |set: bool| -> Result<(), ProgramError> {
                if set {
                    err(
                        line,
                        format!("{name} conflicts with another G code of its group in this line"),
                    )
                } else {
                    Ok(())
                }
            };
            match (g, minor) {
                (0, 0) | (1, 0) | (2, 0) | (3, 0) | (80, 0) => {
                    clash(motion.is_some())?;
                    motion = Some(match g {
                        0 => Some(Motion::Rapid),
                        1 => Some(Motion::Line),
                        2 => Some(Motion::Cw),
                        3 => Some(Motion::Ccw),
                        _ => None,
                    });
                }
                (4, 0) => {
                    clash(dwell)?;
                    dwell = true;
                }
                (17, 0) | (18, 0) | (19, 0) => {
                    clash(plane.is_some())?;
                    plane = Some(match g {
                        17 => Plane::Xy,
                        18 => Plane::Zx,
                        _ => Plane::Yz,
                    });
                }
                (20, 0) => {
                    return err(
                        line,
                        "G20 (inches) is not supported: write the program in millimetres (G21)",
                    )
                }
                (21, 0) | (94, 0) | (91, 1) | (40, 0) | (49, 0) | (54, 0) => {}
                (90, 0) | (91, 0) => {
                    clash(distance.is_some())?;
                    distance = Some(g == 91);
                }
                (61, 0) | (64, 0) => {
                    clash(path_mode.is_some())?;
                    path_mode = Some(g == 61);
                }
                (90, 1) => return err(
                    line,
                    "G90.1 (absolute arc centres) is not supported: use incremental I/J/K (G91.1)",
                ),
                (93, 0) | (95, 0) => {
                    return err(
                        line,
                        format!(
                        "{name} (feed per time/revolution) is not supported: use G94, F in mm/min"
                    ),
                    )
                }
                _ => return err(line, format!("{name} is not supported by the simulator")),
            }
        }

        // M codes.
        let mut stop = None;
        let mut end = false;
        for &(m, minor) in &raw.m {
            match (m, minor) {
                (0, 0) | (1, 0) => {
                    if stop.is_some() || end {
                        return err(line, "more than one program stop/end in one line");
                    }
                    stop = Some(m == 1);
                }
                (2, 0) | (30, 0) => {
                    if stop.is_some() || end {
                        return err(line, "more than one program stop/end in one line");
                    }
                    end = true;
                }
                (3, 0) | (4, 0) | (5, 0) => {} // spindle: the instrument is in the spindle; ignored
                // Marlin's M400 waits until the planned moves are done: the simulator's moves
                // are always done in order, so there is nothing to wait for.
                (400, 0) if self.opts.dialect == Dialect::Marlin => {}
                _ => {
                    let name = if minor == 0 {
                        format!("M{m}")
                    } else {
                        format!("M{m}.{minor}")
                    };
                    return err(line, format!("{name} is not supported by the simulator"));
                }
            }
        }

        // Modal settings, in RS274/NGC order: feed, plane, distance mode, path mode.
        if let Some(f) = take('F') {
            if f.value.is_nan() || f.value <= 0.0 {
                return err(line, format!("feed F{} must be positive (mm/min)", f.value));
            }
            self.feed_mm_min = Some(f.value);
        }
        if let Some(p) = plane {
            self.plane = p;
        }
        if let Some(inc) = distance {
            self.incremental = inc;
        }
        if let Some(es) = path_mode {
            self.exact_stop = es;
            if !es {
                // G64 P/Q (blending tolerance): our planner only blends tangent junctions,
                // which keeps the path within any tolerance; the values are not needed.
                take('P');
                take('Q');
            }
        }
        if let Some(m) = motion {
            self.motion = m;
        }

        // Dwell.
        if dwell {
            let seconds = self.dwell_seconds(line, &mut take)?;
            out.push(Block {
                line,
                n: raw.n,
                action: Action::Dwell { seconds },
                exact_stop: true,
            });
        }
        // Spindle speed: harmless with M3/M4 or alone.
        take('S');

        // Motion.
        let axes: Vec<(usize, Word)> = ['X', 'Y', 'Z']
            .into_iter()
            .filter_map(|c| take(c).map(|w| (axis_index(c).unwrap_or(0), w)))
            .collect();
        let offsets = [take('I'), take('J'), take('K')];
        let r_word = take('R');
        if dwell && !axes.is_empty() {
            return err(line, "axis words in a G4 (dwell) line");
        }
        if let Some((i, _)) = words.iter().enumerate().find(|(_, w)| w.is_some()) {
            let c = (b'A' + i as u8) as char;
            return err(
                line,
                format!(
                    "word {c} is not supported here (this simulator reads X Y Z I J K R F P S)"
                ),
            );
        }
        let is_arc = matches!(self.motion, Some(Motion::Cw | Motion::Ccw));
        if (offsets.iter().any(Option::is_some) || r_word.is_some()) && (!is_arc || axes.is_empty())
        {
            return err(
                line,
                "I/J/K/R without an arc move (G2/G3 with an end point)",
            );
        }
        if !axes.is_empty() {
            let Some(mode) = self.motion else {
                return err(line, "axis words but no motion mode (G0/G1/G2/G3) in force");
            };
            let mut to = self.pos;
            for (k, w) in &axes {
                let v = self.length(w);
                to[*k] = if self.incremental {
                    self.pos[*k] + v
                } else {
                    v
                };
            }
            let from = self.pos;
            let action = match mode {
                Motion::Rapid => Action::Rapid { from, to },
                Motion::Line => Action::Line {
                    from,
                    to,
                    feed_mm_min: self.feed(line)?,
                },
                Motion::Cw | Motion::Ccw => {
                    let feed = self.feed(line)?;
                    let ccw = mode == Motion::Ccw;
                    Action::Arc(self.arc(line, from, to, ccw, offsets, r_word, feed)?)
                }
            };
            out.push(Block {
                line,
                n: raw.n,
                action,
                exact_stop: self.exact_stop,
            });
            self.pos = to;
        } else if matches!(motion, Some(Some(Motion::Cw | Motion::Ccw))) {
            return err(
                line,
                "G2/G3 without an end point (X/Y/Z): write the end point",
            );
        }

        if let Some(optional) = stop {
            out.push(Block {
                line,
                n: raw.n,
                action: Action::Stop { optional },
                exact_stop: true,
            });
        }
        Ok(end)
    }

    fn feed(&self, line: usize) -> Result<f64, ProgramError> {
        match self.feed_mm_min {
            Some(f) => Ok(f),
            None => err(line, "feed move before any F word: set the feed (mm/min)"),
        }
    }

    fn dwell_seconds(
        &self,
        line: usize,
        take: &mut impl FnMut(char) -> Option<Word>,
    ) -> Result<f64, ProgramError> {
        let p = take('P');
        let s = match self.opts.dialect {
            Dialect::Marlin => take('S'),
            _ => None, // S is the spindle speed there
        };
        let x = match self.opts.dialect {
            Dialect::Fanuc => take('X'),
            _ => None,
        };
        let seconds = match self.opts.dialect {
            Dialect::LinuxCnc | Dialect::Grbl => match (p, s) {
                (Some(p), None) => p.value,
                _ => return err(line, "G4 needs P (seconds) and nothing else"),
            },
            Dialect::Marlin => match (p, s) {
                (Some(p), None) => p.value / 1000.0,
                (None, Some(s)) => s.value,
                _ => return err(line, "G4 needs one of P (milliseconds) or S (seconds)"),
            },
            Dialect::Fanuc => match (x, p, s) {
                (Some(x), None, None) => {
                    if x.point || self.opts.fanuc_input == FanucInput::Calculator {
                        x.value
                    } else {
                        x.value / 1000.0
                    }
                }
                (None, Some(p), None) => {
                    if p.point {
                        return err(
                            line,
                            "G4 P takes whole milliseconds (no decimal point) on Fanuc",
                        );
                    }
                    p.value / 1000.0
                }
                _ => return err(line, "G4 needs one of X (seconds) or P (milliseconds)"),
            },
        };
        if seconds.is_nan() || seconds < 0.0 {
            return err(line, "negative dwell");
        }
        Ok(seconds)
    }

    #[allow(clippy::too_many_arguments)]
    fn arc(
        &self,
        line: usize,
        from: [f64; 3],
        to: [f64; 3],
        ccw: bool,
        offsets: [Option<Word>; 3],
        r_word: Option<Word>,
        feed_mm_min: f64,
    ) -> Result<ArcMove, ProgramError> {
        let (a, b, n) = self.plane.axes();
        if offsets[n].is_some() {
            let c = ['I', 'J', 'K'][n];
            return err(line, format!("{c} is not an offset in the selected plane"));
        }
        let (sa, sb, ea, eb) = (from[a], from[b], to[a], to[b]);
        let chord = ((ea - sa).powi(2) + (eb - sb).powi(2)).sqrt();
        let (ca, cb) = match (offsets[a].is_some() || offsets[b].is_some(), r_word) {
            (true, Some(_)) => return err(line, "arc with both R and I/J/K: use one"),
            (false, None) => return err(line, "arc without a centre (I/J/K) or radius (R)"),
            (true, None) => {
                let oa = offsets[a].map_or(0.0, |w| self.length(&w));
                let ob = offsets[b].map_or(0.0, |w| self.length(&w));
                (sa + oa, sb + ob)
            }
            (false, Some(r)) => {
                let r = self.length(&r);
                if chord < 1e-9 {
                    return err(line, "a full circle cannot be given with R: use I/J/K");
                }
                let h2 = r * r - 0.25 * chord * chord;
                if h2 < -(ARC_RADIUS_TOLERANCE_MM * r.abs()) {
                    return err(
                        line,
                        format!("R{r} is shorter than half the chord {:.4} mm", chord / 2.0),
                    );
                }
                let h = h2.max(0.0).sqrt();
                // Left of the chord for a ccw arc ≤ 180°; right for cw; R < 0 swaps.
                let side = if ccw == (r > 0.0) { 1.0 } else { -1.0 };
                let (pa, pb) = (-(eb - sb) / chord, (ea - sa) / chord);
                (
                    0.5 * (sa + ea) + side * h * pa,
                    0.5 * (sb + eb) + side * h * pb,
                )
            }
        };
        let r0 = ((sa - ca).powi(2) + (sb - cb).powi(2)).sqrt();
        let r1 = ((ea - ca).powi(2) + (eb - cb).powi(2)).sqrt();
        if r0 < 1e-6 {
            return err(line, "arc centre at its start point");
        }
        if (r1 - r0).abs() > ARC_RADIUS_TOLERANCE_MM {
            return err(
                line,
                format!(
                    "arc end is not on the circle: radius {r0:.4} mm at the start, {r1:.4} mm at the end (tolerance {ARC_RADIUS_TOLERANCE_MM} mm)"
                ),
            );
        }
        let theta0 = (sb - cb).atan2(sa - ca);
        let theta1 = (eb - cb).atan2(ea - ca);
        let tau = std::f64::consts::TAU;
        let sweep = if chord < 1e-9 {
            if ccw {
                tau
            } else {
                -tau
            }
        } else if ccw {
            let s = (theta1 - theta0).rem_euclid(tau);
            if s == 0.0 {
                tau
            } else {
                s
            }
        } else {
            let s = (theta0 - theta1).rem_euclid(tau);
            -(if s == 0.0 { tau } else { s })
        };
        let mut centre = from;
        centre[a] = ca;
        centre[b] = cb;
        Ok(ArcMove {
            from,
            to,
            centre,
            plane: self.plane,
            radius_mm: [r0, r1],
            theta0_rad: theta0,
            sweep_rad: sweep,
            feed_mm_min,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn parse(text: &str, d: Dialect) -> Result<Program, ProgramError> {
        parse_program(text, ProgramOptions::new(d), [0.0; 3])
    }

    fn dwell(text: &str, d: Dialect) -> f64 {
        let p = parse(text, d).unwrap();
        match p.blocks[0].action {
            Action::Dwell { seconds } => seconds,
            a => panic!("{a:?}"),
        }
    }

    #[test]
    fn dwell_units_per_dialect() {
        assert_eq!(dwell("G4 P1.5", Dialect::LinuxCnc), 1.5);
        assert_eq!(dwell("G4 P1.5", Dialect::Grbl), 1.5);
        assert_eq!(dwell("G4 P1500", Dialect::Marlin), 1.5);
        assert_eq!(dwell("G4 S2", Dialect::Marlin), 2.0);
        assert_eq!(dwell("G4 X1.5", Dialect::Fanuc), 1.5);
        assert_eq!(dwell("G04 P1500", Dialect::Fanuc), 1.5);
        // Fanuc X without a decimal point: least increments (ms) on a factory-set control.
        assert_eq!(dwell("G4 X2", Dialect::Fanuc), 0.002);
        let calc = ProgramOptions {
            dialect: Dialect::Fanuc,
            fanuc_input: FanucInput::Calculator,
        };
        match parse_program("G4 X2", calc, [0.0; 3]).unwrap().blocks[0].action {
            Action::Dwell { seconds } => assert_eq!(seconds, 2.0),
            a => panic!("{a:?}"),
        }
        for (text, d) in [
            ("G4 X1", Dialect::LinuxCnc),
            ("G4 Q1", Dialect::Grbl),
            ("G4 P1 S1", Dialect::Marlin),
            ("G4 P1.5", Dialect::Fanuc),
            ("G4", Dialect::LinuxCnc),
        ] {
            let e = parse(text, d).unwrap_err();
            assert_eq!(e.line, 1, "{text}: {e}");
        }
    }

    #[test]
    fn unsupported_words_fail_with_their_line() {
        let cases = [
            ("G21 G90\nG1 X1 F100\nG41 X2\n", 3, "G41"),
            ("G21\n\n(comment)\nM8\n", 4, "M8"),
            ("G21\nT1 M6\n", 2, "tool"),
            ("G21\nG1 X1 Q3 F100\n", 2, "Q"),
            ("G20\n", 1, "G20"),
            ("G21\nG1 X#1 F100\n", 2, "unexpected"),
            ("G21\nG1.23 X1 F100\n", 2, "G1.23"),
            ("G21 G90\nO100 sub\n", 2, ""),
            ("G21\nX10\n", 2, "motion mode"),
            ("G21 G0 X1\nG1 X2\n", 2, "F word"),
            ("G21\nG1 E3 X1 F1\n", 2, "E"),
        ];
        for (text, line, what) in cases {
            let e = parse(text, Dialect::LinuxCnc).unwrap_err();
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(e.to_string().contains(what), "{text:?}: {e}");
            assert!(e.to_string().starts_with(&format!("line {line}: ")));
        }
        // O numbers are Fanuc only.
        assert_eq!(
            parse("%\nO1000\nG21\n%\n", Dialect::Grbl).unwrap_err().line,
            2
        );
        assert!(parse("%\nO1000\nG21\n%\n", Dialect::Fanuc).is_ok());
    }

    #[test]
    fn numbers_are_read_in_full_precision() {
        let p = parse("G21 G90 G0 X238.1237 Y-100.0001 Z.5\n", Dialect::LinuxCnc).unwrap();
        match p.blocks[0].action {
            // f32 would give 238.12370300..., 100.00009918...
            Action::Rapid { to, .. } => assert_eq!(to, [238.1237, -100.0001, 0.5]),
            a => panic!("{a:?}"),
        }
    }

    #[test]
    fn fanuc_integers_are_least_increments() {
        let p = parse("G21 G90 G0 X238 Y10. Z-5\n", Dialect::Fanuc).unwrap();
        match p.blocks[0].action {
            Action::Rapid { to, .. } => assert_eq!(to, [0.238, 10.0, -0.005]),
            a => panic!("{a:?}"),
        }
    }

    #[test]
    fn modal_state_and_incremental() {
        let p = parse(
            "G21 G91 G1 X10 F600\nY5\nG90 X0\nN40 M0\nG0 Z3 M30\nG1 X100\n",
            Dialect::LinuxCnc,
        )
        .unwrap();
        assert_eq!(p.end_line, Some(5));
        let ends: Vec<_> = p
            .blocks
            .iter()
            .filter_map(|b| match b.action {
                Action::Line { to, .. } | Action::Rapid { to, .. } => Some(to),
                _ => None,
            })
            .collect();
        assert_eq!(
            ends,
            [
                [10.0, 0.0, 0.0],
                [10.0, 5.0, 0.0],
                [0.0, 5.0, 0.0],
                [0.0, 5.0, 3.0]
            ]
        );
        assert_eq!(p.blocks[3].action, Action::Stop { optional: false });
        assert_eq!(p.blocks[3].n, Some(40));
        assert_eq!(p.blocks[3].line, 4);
    }

    fn arc_of(text: &str) -> ArcMove {
        let p = parse_program(text, ProgramOptions::new(Dialect::LinuxCnc), [0.0; 3]).unwrap();
        match p.blocks.last().unwrap().action {
            Action::Arc(a) => a,
            a => panic!("{a:?}"),
        }
    }

    #[test]
    fn arc_sense_per_plane() {
        // G17 G3 from (10,0) to (0,10) about the origin: +90°.
        let a = arc_of("G21 G17 G0 X10 Y0\nG3 X0 Y10 I-10 J0 F100\n");
        assert!((a.sweep_rad - PI / 2.0).abs() < 1e-12, "{a:?}");
        let a = arc_of("G21 G17 G0 X10 Y0\nG2 X0 Y10 I-10 J0 F100\n");
        assert!((a.sweep_rad + 3.0 * PI / 2.0).abs() < 1e-12, "{a:?}");
        // G18: plane axes (Z, X), normal +Y. G3 from +Z to +X about the origin is +90° seen from +Y.
        let a = arc_of("G21 G18 G0 Z10 X0\nG3 Z0 X10 K-10 I0 F100\n");
        assert_eq!(a.plane.axes(), (2, 0, 1));
        assert!((a.sweep_rad - PI / 2.0).abs() < 1e-12, "{a:?}");
        // G19: (Y, Z), normal +X.
        let a = arc_of("G21 G19 G0 Y10 Z0\nG2 Y0 Z-10 J-10 K0 F100\n");
        assert!((a.sweep_rad + PI / 2.0).abs() < 1e-12, "{a:?}");
        // Full circle: start = end.
        let a = arc_of("G21 G0 X10 Y0\nG2 X10 Y0 I-10 J0 F100\n");
        assert!((a.sweep_rad + 2.0 * PI).abs() < 1e-12);
    }

    #[test]
    fn r_form_arcs() {
        // G3 R10 from (10,0) to (0,10): the short (90°) arc about the origin.
        let a = arc_of("G21 G0 X10 Y0\nG3 X0 Y10 R10 F100\n");
        assert!(
            a.centre[0].abs() < 1e-12 && a.centre[1].abs() < 1e-12,
            "{a:?}"
        );
        assert!((a.sweep_rad - PI / 2.0).abs() < 1e-12);
        // R < 0: the long way, centre at (10, 10).
        let a = arc_of("G21 G0 X10 Y0\nG3 X0 Y10 R-10 F100\n");
        assert!((a.centre[0] - 10.0).abs() < 1e-12 && (a.centre[1] - 10.0).abs() < 1e-12);
        assert!((a.sweep_rad - 3.0 * PI / 2.0).abs() < 1e-12);
        // G2 R10: centre (10, 10) too, 90° clockwise.
        let a = arc_of("G21 G0 X10 Y0\nG2 X0 Y10 R10 F100\n");
        assert!((a.centre[0] - 10.0).abs() < 1e-12 && (a.centre[1] - 10.0).abs() < 1e-12);
        assert!((a.sweep_rad + PI / 2.0).abs() < 1e-12);
    }

    #[test]
    fn arc_off_its_circle_is_refused() {
        let e = parse(
            "G21 G0 X10 Y0\nG3 X0 Y10.01 I-10 J0 F100\n",
            Dialect::LinuxCnc,
        )
        .unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.message.contains("not on the circle"), "{e}");
    }
}
