//! A diagnosis as settings of a CNC controller: what to change, where, in the controller's own
//! syntax and units, and what no setting can fix (with what to do instead).
//!
//! | effect (jdbb) | LinuxCNC 2.9 | grblHAL | Marlin | Klipper |
//! |---|---|---|---|---|
//! | `backlash_k` | `[JOINT_n] BACKLASH` (or in the `COMP_FILE`) | `$160`–`$162` | `M425` | no (not in mainline) |
//! | `squareness_ij` | no (`matrixkins` on 2.10/master) | no | `M852 I J K` | `SET_SKEW` |
//! | `scale_k`, `scale_mismatch_ij` | `COMP_FILE` | `$100`–`$102` steps/mm | `M92` steps/mm | `rotation_distance` |
//! | `scale2_k`, `cyclic_k` | `COMP_FILE` | no | no | no |
//! | `servo_mismatch_ij`, `interference_k`, `reversal_spike_k`, `drift` | tuning / repair / warm-up, not a setting | | | |
//!
//! Each controller's module quotes its semantics with the source named in the project's
//! `shared/notes/controllers.md`; [`MachineErrors`] is the common model they all start from.
//!
//! # Conventions (from [`crate::model`])
//!
//! The diagnosis reports errors δ added to the commanded position (the actual position is
//! command + δ), with positions k in mm relative to the table ball:
//! - `backlash_k` b (µm), the trade's sign: **b > 0 is lost motion (play)**, the axis lags its
//!   command by b/2 in the direction of motion, δ_k = −(b/2)·(direction of motion), taken up as a
//!   dead band after each reversal; b < 0 means it runs ahead (typically a backlash compensation
//!   already in force that is too large). When the two ends of the travel differ
//!   (`pos_um`/`neg_um`), a single setting takes their mean and the difference is noted.
//! - straightness (a bowed axis) is no setting: it is listed with what to do instead.
//! - `squareness_ij` s (µm/m): δ_i = s·j (i moves by s per metre of j).
//! - `scale_k` a (µm/m): δ_k = a·k; `scale_mismatch_ij` a: δ_i = +(a/2)·i, δ_j = −(a/2)·j (one
//!   radius cannot separate the common scale from the bar length; the split is the model's own).
//! - `scale2_k` b (µm/m²): δ_k = b·k²; `cyclic_k`: δ_k = sin_um·sin(2πk/p) + cos_um·cos(2πk/p).
//!
//! A controller correction c added to the motor command cancels an error when c = −δ. Every
//! controller here that compensates backlash adds, at each reversal, a motion of the full
//! setting in the new direction (LinuxCNC as ±half about the centre, Marlin and grblHAL as the
//! whole step); either way the correction is +(B/2)·direction up to a constant offset, so the
//! setting that cancels δ_k = −(b/2)·direction is **B = b** (the full lost motion). A skew
//! correction x' = x − xy·y (Marlin, Klipper) cancels δ_x = xy·y, so **xy = s·10⁻⁶**.
//!
//! The values in force during the test were already acting on the machine, so what the test shows
//! is what remains: the new setting is the value in force plus the change (`--current FILE`;
//! without it the controller's default, usually 0, is assumed and said).
//!
//! Effects are acted on only when at least 3 standard errors from zero; others are listed as left
//! alone.
use std::fmt::Write;

use crate::model::{Axis, Effect, Pair};
use crate::report::document::DiagnosisDoc;
use crate::units::{format_estimate, human};
use crate::{Error, Result};

pub mod current;
pub mod fanuc;
pub mod grblhal;
pub mod heidenhain;
pub mod klipper;
pub mod linuxcnc;
pub mod marlin;
pub mod plausible;
pub mod sinumerik;

/// What a controller can set, defined with the effects (the diagnosis's what-if G uses it too).
pub use crate::model::settable::{is_setting, Controller, SIGNIFICANT_SIGMAS};
pub use current::Current;

impl Current {
    /// Read `path` (`--current`) in the format of `controller`; a file with nothing of this
    /// controller's in it is an input error that names the controller it reads as, if any.
    pub fn read(path: &std::path::Path, controller: Controller) -> Result<Current> {
        let text = crate::table::read_text(path)?;
        let mut c = parse_current(path, &text, controller)?;
        if !c.has_values() && has_content(&text) {
            // Nothing of this controller's in a file with something in it: another format.
            let other = Controller::ALL.iter().copied().find(|&o| {
                o != controller && parse_current(path, &text, o).is_ok_and(|c| c.has_values())
            });
            return Err(Error::input(
                path,
                1,
                0,
                format!(
                    "no {} setting in this file{}; give --current the values in force in the format of --controller {}",
                    controller.name(),
                    other.map_or(String::new(), |o| format!(
                        " (it reads as a {} file: is --controller {} meant?)",
                        o.name(),
                        o.name()
                    )),
                    controller.name()
                ),
            ));
        }
        c.source = Some(path.to_path_buf());
        Ok(c)
    }
}

/// `text` read in the `--current` format of `controller`.
fn parse_current(path: &std::path::Path, text: &str, controller: Controller) -> Result<Current> {
    match controller {
        Controller::LinuxCnc => linuxcnc::parse_current(path, text),
        Controller::GrblHal => grblhal::parse_current(path, text),
        Controller::Marlin => marlin::parse_current(path, text),
        Controller::Klipper => klipper::parse_current(path, text),
        Controller::Fanuc => fanuc::parse_current(path, text),
        Controller::Sinumerik => sinumerik::parse_current(path, text),
        Controller::Heidenhain => heidenhain::parse_current(path, text),
    }
}

/// Whether `text` has a line that is neither blank nor a comment (`#`, `;`).
fn has_content(text: &str) -> bool {
    text.lines().any(|l| {
        let t = l.trim();
        !t.is_empty() && !t.starts_with('#') && !t.starts_with(';')
    })
}

/// One diagnosed effect as the source of a change: its name and value ± σ for people.
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    pub effect: Effect,
    pub value: f64,
    pub sigma: f64,
}

impl Measured {
    /// `backlash_x = -8.0012 ± 0.0046 µm`
    pub fn text(&self) -> String {
        format!(
            "{} = {} {}",
            self.effect.name(),
            format_estimate(self.value, Some(self.sigma)),
            human(self.effect.unit())
        )
    }
}

/// A periodic error of one axis: δ_k = sin_um·sin(2πk/p) + cos_um·cos(2πk/p).
#[derive(Debug, Clone, PartialEq)]
pub struct Cyclic {
    pub sin_um: f64,
    pub cos_um: f64,
    pub pitch_mm: f64,
    pub source: Measured,
}

/// What the diagnosis says the machine does, in the diagnosis' conventions (module docs), per
/// axis (index x, y, z) and pair (index xy, yz, zx): the input of every controller's plan.
#[derive(Debug, Clone, Default)]
pub struct MachineErrors {
    /// backlash_k b (µm, positive = play).
    pub backlash_um: [Option<Measured>; 3],
    /// Scale a (µm/m) per axis, with the effect it comes from (scale_k, or half a
    /// scale_mismatch_ij with its sign).
    pub scale_um_per_m: [Option<(f64, Measured)>; 3],
    /// scale2_k b (µm/m²).
    pub scale2_um_per_m2: [Option<Measured>; 3],
    pub cyclic: [Option<Cyclic>; 3],
    /// squareness_ij s (µm/m), by pair.
    pub squareness_um_per_m: [Option<Measured>; 3],
    /// Effects that are tuning, repair or warm-up, not a setting (servo_mismatch, interference,
    /// reversal_spike, drift, straightness).
    pub tuning: Vec<Measured>,
    /// Effects left alone and why (not significant, undetermined).
    pub left_alone: Vec<String>,
    /// How effects were mapped (e.g. the scale mismatch split).
    pub notes: Vec<String>,
    /// The largest circle radius of the test (mm), the span a position table can rest on.
    pub radius_mm: Option<f64>,
    /// reversal_spike_k as (h_um, tau_ms), for a control that compensates it (Heidenhain).
    pub reversal_spike: [Option<(f64, f64)>; 3],
}

fn pair_index(p: Pair) -> usize {
    match p {
        Pair::Xy => 0,
        Pair::Yz => 1,
        Pair::Zx => 2,
    }
}

impl MachineErrors {
    /// The machine errors of a diagnosis file (module docs: only effects ≥ 3σ from zero).
    pub fn from_doc(doc: &DiagnosisDoc) -> Result<MachineErrors> {
        let mut m = MachineErrors {
            radius_mm: doc.circles.iter().map(|c| c.radius_mm).reduce(f64::max),
            ..Default::default()
        };
        for (e, effect) in doc.machine_effects() {
            let (value, sigma) = match (e.value, e.sigma) {
                (Some(v), Some(s)) if v.is_finite() && s.is_finite() => (v, s),
                _ => {
                    m.left_alone
                        .push(format!("{}: undetermined by this test", effect.name()));
                    continue;
                }
            };
            let measured = Measured {
                effect,
                value,
                sigma,
            };
            if !e.significant(SIGNIFICANT_SIGMAS) {
                m.left_alone.push(format!(
                    "{}: less than {SIGNIFICANT_SIGMAS}σ from zero",
                    measured.text()
                ));
                continue;
            }
            let p = e.param_values(effect);
            match effect {
                Effect::SetupOffset | Effect::LengthOffset => {}
                _ if !is_setting(effect, None) => {
                    if let (Effect::ReversalSpike(a), [h_um, tau_ms]) = (effect, &p[..]) {
                        m.reversal_spike[a.index()] = Some((*h_um, *tau_ms));
                    }
                    m.tuning.push(measured)
                }
                Effect::Backlash(a) | Effect::BacklashEnds(a) => {
                    if let [pos, neg] = p[..] {
                        m.notes.push(format!(
                            "{}: lost motion differs along the travel ({pos:.1} µm at the positive end, {neg:.1} µm at the negative end): one backlash setting takes the mean; a worn screw or nut is the cause",
                            measured.text()
                        ));
                    }
                    m.backlash_um[a.index()] = Some(measured)
                }
                Effect::Scale(a) => m.scale_um_per_m[a.index()] = Some((p[0], measured)),
                Effect::ScaleMismatch(pair) => {
                    let (i, j) = pair.axes();
                    m.scale_um_per_m[i.index()] = Some((0.5 * p[0], measured.clone()));
                    m.scale_um_per_m[j.index()] = Some((-0.5 * p[0], measured.clone()));
                    m.notes.push(format!(
                        "{}: one radius shows only the difference of the two scales; it is split as +{:.3} µm/m on {} and {:.3} µm/m on {}, which removes the mismatch and leaves their common part (test a second radius, or use a calibrated bar length, to find it)",
                        measured.text(),
                        0.5 * p[0],
                        i.letter().to_ascii_uppercase(),
                        -0.5 * p[0],
                        j.letter().to_ascii_uppercase()
                    ));
                }
                Effect::Scale2(a) => m.scale2_um_per_m2[a.index()] = Some(measured),
                Effect::Cyclic(a) => match doc.pitch_mm(a) {
                    Some(pitch_mm) => {
                        m.cyclic[a.index()] = Some(Cyclic {
                            sin_um: p[0],
                            cos_um: p[1],
                            pitch_mm,
                            source: measured,
                        })
                    }
                    None => m.left_alone.push(format!(
                        "{}: the diagnosis file does not say the pitch (rerun jdbb diagnose with --pitch)",
                        measured.text()
                    )),
                },
                Effect::Squareness(pair) => {
                    m.squareness_um_per_m[pair_index(pair)] = Some(measured)
                }
                // Not a setting of every control (is_setting): tuning, repair or warm-up.
                _ => m.tuning.push(measured),
            }
        }
        Ok(m)
    }

    /// Whether axis `a` has an error that depends on position (scale, scale2, cyclic).
    pub fn position_dependent(&self, a: Axis) -> bool {
        let k = a.index();
        self.scale_um_per_m[k].is_some()
            || self.scale2_um_per_m2[k].is_some()
            || self.cyclic[k].is_some()
    }

    /// The position-dependent error δ of axis `a` (mm) at `k_mm` from the table ball (scale,
    /// scale2, cyclic; not backlash).
    pub fn position_error_mm(&self, a: Axis, k_mm: f64) -> f64 {
        let i = a.index();
        let mut d = 0.0;
        if let Some((s, _)) = &self.scale_um_per_m[i] {
            d += 1e-6 * s * k_mm;
        }
        if let Some(b) = &self.scale2_um_per_m2[i] {
            d += 1e-9 * b.value * k_mm * k_mm;
        }
        d + self.cyclic_error_mm(a, k_mm)
    }

    /// The cyclic part of [`MachineErrors::position_error_mm`] (mm).
    pub fn cyclic_error_mm(&self, a: Axis, k_mm: f64) -> f64 {
        match &self.cyclic[a.index()] {
            Some(c) => {
                let w = std::f64::consts::TAU * k_mm / c.pitch_mm;
                1e-3 * (c.sin_um * w.sin() + c.cos_um * w.cos())
            }
            None => 0.0,
        }
    }

    /// The effects behind axis `a`'s position-dependent error (scale, scale2, cyclic), as people
    /// read them: what a position table is "for".
    pub fn position_sources(&self, a: Axis) -> Vec<String> {
        let k = a.index();
        [
            self.scale_um_per_m[k].as_ref().map(|s| s.1.text()),
            self.scale2_um_per_m2[k].as_ref().map(|s| s.text()),
            self.cyclic[k].as_ref().map(|c| c.source.text()),
        ]
        .into_iter()
        .flatten()
        .collect()
    }

    /// The squareness of `pair`.
    pub fn squareness(&self, pair: Pair) -> Option<&Measured> {
        self.squareness_um_per_m[pair_index(pair)].as_ref()
    }
}

/// One setting to change.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    /// The effect(s) it acts on, as people read them.
    pub because: String,
    /// Where: `[JOINT_0] BACKLASH`, `$160`, `M425 X`, `xy_skew`.
    pub setting: String,
    pub unit: String,
    /// The value in force: from `--current`, or the controller's default (then `assumed`).
    pub current: f64,
    pub assumed: bool,
    pub new: f64,
    /// Decimals to print.
    pub decimals: usize,
    /// A setting that is not a number (a file to load): what it becomes, in words.
    pub text: Option<String>,
}

/// An effect this controller cannot take as a setting.
#[derive(Debug, Clone, PartialEq)]
pub struct Cannot {
    pub effect: String,
    pub why: String,
    pub instead: String,
}

/// Lines to enter somewhere, verbatim.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// Where they go, e.g. `the INI file` or `the console (then M500)`.
    pub label: String,
    pub lines: Vec<String>,
}

/// Everything `jdbb compensate` says for one controller.
#[derive(Debug, Clone, Default)]
pub struct Plan {
    pub title: String,
    pub changes: Vec<Change>,
    pub cannot: Vec<Cannot>,
    pub blocks: Vec<Block>,
    /// Files to write: (name, content).
    pub files: Vec<(String, String)>,
    pub left_alone: Vec<String>,
    pub notes: Vec<String>,
}

/// Where the machine is, for tables over machine positions (LinuxCNC's `COMP_FILE`).
#[derive(Debug, Clone, Default)]
pub struct Placement {
    /// Machine coordinates of the table ball during the test, mm (None = 0, said in a note).
    pub table_ball_mm: [Option<f64>; 3],
    /// Machine travel per axis to cover with a table, mm (None = the tested span).
    pub travel_mm: [Option<(f64, f64)>; 3],
}

/// Options of [`plan`].
#[derive(Debug, Clone)]
pub struct Options {
    pub controller: Controller,
    pub placement: Placement,
    /// LinuxCNC `COMP_FILE_TYPE` to write: 0 (actual positions) or 1 (corrections).
    pub comp_file_type: u8,
}

/// The plan for `opts.controller` from a diagnosis file and the values in force.
pub fn plan(doc: &DiagnosisDoc, current: &Current, opts: &Options) -> Result<Plan> {
    let m = MachineErrors::from_doc(doc)?;
    plausible::check_errors(&m)?;
    plausible::check_in_force(current)?;
    let mut p = match opts.controller {
        Controller::LinuxCnc => linuxcnc::plan(&m, current, opts)?,
        Controller::GrblHal => grblhal::plan(&m, current),
        Controller::Marlin => marlin::plan(&m, current),
        Controller::Klipper => klipper::plan(&m, current)?,
        Controller::Fanuc => fanuc::plan(&m, current, &opts.placement)?,
        Controller::Sinumerik => sinumerik::plan(&m, current, &opts.placement)?,
        Controller::Heidenhain => heidenhain::plan(&m, current, &opts.placement)?,
    };
    for t in &m.tuning {
        p.cannot.push(tuning_advice(t, opts.controller));
    }
    p.left_alone.extend(m.left_alone.iter().cloned());
    let mut notes = m.notes.clone();
    notes.append(&mut p.notes);
    p.notes = notes;
    plausible::check(&p)?;
    Ok(p)
}

/// What to do about an effect that is tuning or repair.
fn tuning_advice(t: &Measured, c: Controller) -> Cannot {
    match t.effect {
        Effect::ServoMismatch(pair) => {
            let (i, j) = pair.axes();
            let (lag, lead) = if t.value >= 0.0 { (i, j) } else { (j, i) };
            let (lag, lead) = (
                lag.letter().to_ascii_uppercase(),
                lead.letter().to_ascii_uppercase(),
            );
            let how = match c {
                Controller::Fanuc | Controller::Sinumerik | Controller::Heidenhain => format!(
                    "match the position loops of {lag} and {lead}: the same position-loop gain (kv) and feed-forward on both (Fanuc: servo loop gain No. 1825 and feed-forward; SINUMERIK: MD32200 POSCTRL_GAIN and MD32620 FFW_MODE; Heidenhain: the kv factors), or raise {lag}'s, until a new test shows the mismatch within its standard error"
                ),
                Controller::LinuxCnc => format!(
                    "match the position loops: raise FF1 (velocity feed-forward, towards 1) or P of the PID of the joint of {lag}, or lower {lead}'s, until a new test shows the mismatch within its standard error"
                ),
                _ => format!(
                    "stepper drives without feedback have no position loop to tune: check the drives of {lag} and {lead} (closed-loop or servo drives: match their gains), and that their acceleration and jerk settings are equal"
                ),
            };
            Cannot {
                effect: t.text(),
                why: format!(
                    "{lag} lags {lead} by {:.3} ms: a servo time-constant mismatch is tuning, not a compensation setting",
                    t.value.abs()
                ),
                instead: how,
            }
        }
        Effect::ReversalSpike(a) => {
            let axis = a.letter().to_ascii_uppercase();
            Cannot {
                effect: t.text(),
                why: format!(
                    "{axis} sticks at each reversal and catches up: friction (stick-slip) or a servo that takes up lost motion slowly; {} has no setting for it",
                    c.name()
                ),
                instead: match c {
                    Controller::Heidenhain => format!(
                        "the reversal-spike compensation written below (iTNC 530 MP711/MP712), then check {axis}'s ways and gibs (lubrication, preload): a spike is friction, the setting only hides it"
                    ),
                    Controller::Fanuc | Controller::Sinumerik => format!(
                        "check {axis}'s ways and gibs (lubrication, preload); then the control's quadrant-error (friction) compensation, set with the machine builder (Fanuc: backlash acceleration in the servo parameters; SINUMERIK: friction compensation, MD32500 FRICT_COMP_ENABLE)"
                    ),
                    Controller::LinuxCnc => format!(
                        "check {axis}'s ways and gibs (lubrication, preload); on a servo axis raise the PID's I or add friction feed-forward (a bias of BIAS/FF0 by direction) until a new test no longer shows the spike"
                    ),
                    _ => format!(
                        "check {axis}'s ways and gibs (lubrication, preload) and the drive's current at low speed; a stepper axis that stalls at reversal needs more torque or less acceleration"
                    ),
                },
            }
        }
        Effect::Straightness(a, b) => {
            let (a, b) = (a.letter().to_ascii_uppercase(), b.letter().to_ascii_uppercase());
            Cannot {
                effect: t.text(),
                why: format!(
                    "{a} bows in {b} by {:.1} µm over the tested travel: a guideway that is bent, worn or unevenly supported; {} has no setting for it",
                    t.value,
                    c.name()
                ),
                instead: format!(
                    "check {a}'s guideway straightness (level, foundation bolts, a straightedge along its travel) and realign or regrind it; a second radius about the same table ball confirms it against a second-order scale of {b}"
                ),
            }
        }
        Effect::LateralPlay(a, b) => {
            let (a, b) = (a.letter().to_ascii_uppercase(), b.letter().to_ascii_uppercase());
            Cannot {
                effect: t.text(),
                why: format!(
                    "{a}'s carriage shifts {:.1} µm in {b} each time {a} reverses: clearance across its guideway; {} has no setting for it",
                    t.value.abs(),
                    c.name()
                ),
                instead: format!("adjust {a}'s gibs or roller preload, or renew worn guideway pads, and test again"),
            }
        }
        Effect::ScaleDrift(_) | Effect::PositionDrift(_) => Cannot {
            effect: t.text(),
            why: "the axis grew during the test (heat in its screw or spindle): a state of the machine, not a setting of the axis".into(),
            instead: "warm the machine up (run the spindle and axes for 15–30 min) and test again; if it persists, the machine's thermal compensation is the place for it".into(),
        },
        Effect::Drift => Cannot {
            effect: t.text(),
            why: "D drifted during the test: the machine (or the instrument) was warming up; it is a state, not an error of an axis".into(),
            instead: "warm the machine up (run the spindle and axes for 15–30 min) and the instrument mounted for a few minutes, then test again; if it persists, the machine's thermal compensation is the place for it".into(),
        },
        Effect::FollowingError => Cannot {
            effect: t.text(),
            why: format!(
                "the position loops draw circles smaller the faster they run (following error, q = {:.1} ms²): servo tuning, not a compensation setting of {}",
                t.value,
                c.name()
            ),
            instead: "raise the position-loop gain (Kv) or the velocity feed-forward towards 100 % in the drive, as far as the axes stay stable; a scale compensation would be wrong at every other feed".into(),
        },
        _ => Cannot {
            effect: t.text(),
            why: "a reading error that grows with speed is a fault of the scale or encoder signal, not of the axis position".into(),
            instead: "check the scale or encoder read head (alignment, gap, cabling, interpolation settings); no controller setting compensates it".into(),
        },
    }
}

/// The text `jdbb compensate` prints.
pub fn render(p: &Plan, files_written_to: Option<&std::path::Path>) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", p.title);
    if p.changes.is_empty() {
        let _ = writeln!(s, "nothing to change in this controller's settings");
    } else {
        let _ = writeln!(s, "change:");
        for c in &p.changes {
            if let Some(t) = &c.text {
                let _ = writeln!(s, "  {}: {t} for {}", c.setting, c.because);
                continue;
            }
            let d = c.decimals;
            let unit = if c.unit.is_empty() {
                String::new()
            } else {
                format!(" {}", c.unit)
            };
            let _ = writeln!(
                s,
                "  {}: {:.d$}{} -> {:.d$}{unit} ({:+.d$}) for {}",
                c.setting,
                c.current,
                if c.assumed { " (default)" } else { "" },
                c.new,
                c.new - c.current,
                c.because
            );
        }
    }
    if !p.cannot.is_empty() {
        let _ = writeln!(s, "cannot compensate here:");
        for c in &p.cannot {
            let _ = writeln!(s, "  {}: {}", c.effect, c.why);
            let _ = writeln!(s, "    instead: {}", c.instead);
        }
    }
    if !p.left_alone.is_empty() {
        let _ = writeln!(s, "left alone:");
        for l in &p.left_alone {
            let _ = writeln!(s, "  {l}");
        }
    }
    for b in &p.blocks {
        let _ = writeln!(s, "enter in {}:", b.label);
        for l in &b.lines {
            let _ = writeln!(s, "{l}");
        }
    }
    for (name, content) in &p.files {
        match files_written_to {
            Some(dir) => {
                let _ = writeln!(
                    s,
                    "file {} written ({} lines)",
                    dir.join(name).display(),
                    content.lines().count()
                );
            }
            None => {
                let _ = writeln!(
                    s,
                    "file {name} ({} lines; --out DIR writes it):",
                    content.lines().count()
                );
                s.push_str(content);
            }
        }
    }
    if !p.notes.is_empty() {
        let _ = writeln!(s, "notes:");
        for n in &p.notes {
            let _ = writeln!(s, "  - {n}");
        }
    }
    s
}

/// A change of a setting that is `current` (or the default `default` if not in force) by
/// `delta`, with `decimals` printed.
#[allow(clippy::too_many_arguments)]
pub(crate) fn change(
    because: String,
    setting: String,
    unit: &str,
    current: Option<f64>,
    default: f64,
    delta: f64,
    decimals: usize,
) -> Change {
    let (cur, assumed) = match current {
        Some(v) => (v, false),
        None => (default, true),
    };
    Change {
        because,
        setting,
        unit: unit.into(),
        current: cur,
        assumed,
        new: cur + delta,
        decimals,
        text: None,
    }
}

/// A change that is a table or file to load rather than a number: `text` says what it becomes;
/// `in_force` whether it builds on one in force.
pub(crate) fn table_change(
    because: String,
    setting: String,
    in_force: bool,
    text: String,
) -> Change {
    Change {
        because,
        setting,
        unit: String::new(),
        current: 0.0,
        assumed: !in_force,
        new: 0.0,
        decimals: 0,
        text: Some(text),
    }
}

/// The note said when `--current` was not given.
pub(crate) fn defaults_note(current: &Current) -> Option<String> {
    current.is_empty().then(|| {
        "no --current FILE: the values in force are taken as the controller's defaults (0, no compensation); if anything was set during the test, give it with --current so the new values are totals".to_string()
    })
}

/// Scale of an axis as a factor: the axis moves (1 + ε) times the command.
pub(crate) fn scale_epsilon(m: &MachineErrors, a: Axis) -> Option<(f64, &Measured)> {
    m.scale_um_per_m[a.index()]
        .as_ref()
        .map(|(s, src)| (1e-6 * s, src))
}

/// The Marlin/Klipper skew factor (tan of the deviation from 90°, x' = x − xy·y) of each of
/// their planes xy, xz, yz from the diagnosis: xy from squareness_xy (δ_x = s·y), yz from
/// squareness_yz (δ_y = s·z), xz from squareness_zx (δ_z = s·x, which differs from δ_x = s·z
/// only by a rotation about y the ball bar cannot see and a part does not mind).
pub(crate) fn skew_factors(m: &MachineErrors) -> [Option<(f64, &Measured)>; 3] {
    let f = |p: Pair| m.squareness(p).map(|s| (1e-6 * s.value, s));
    [f(Pair::Xy), f(Pair::Zx), f(Pair::Yz)]
}

/// What to do about `pair`'s squareness where a controller has no setting for it: square its two
/// axes by hand, naming them (`square X and Y mechanically`).
pub(crate) fn square_mechanically(pair: Pair) -> String {
    let (i, j) = pair.axes();
    format!(
        "square {} and {} mechanically",
        i.letter().to_ascii_uppercase(),
        j.letter().to_ascii_uppercase()
    )
}

/// The span (machine coordinates, mm) a position table of axis `a` covers: `--travel`, else the
/// tested circle about the table ball; widened to take in `reference` (a control whose table is
/// counted from its reference point, Fanuc's, needs the points between it and the tested span).
pub(crate) fn table_span_mm(
    m: &MachineErrors,
    a: Axis,
    placement: &Placement,
    reference: Option<f64>,
) -> Result<(f64, f64)> {
    let k = a.index();
    let k0 = placement.table_ball_mm[k].unwrap_or(0.0);
    let (lo, hi) = match (placement.travel_mm[k], m.radius_mm) {
        (Some(t), _) => t,
        (None, Some(r)) => (k0 - r, k0 + r),
        (None, None) => {
            return Err(Error::Usage(format!(
                "the diagnosis file does not say the circles' radius (written by an older jdbb): give --travel {}=MIN:MAX for the table",
                a.letter()
            )))
        }
    };
    Ok(match reference {
        Some(r) => (lo.min(r), hi.max(r)),
        None => (lo, hi),
    })
}

/// The position-dependent error δ (mm, the diagnosis' sign: actual − command) of axis `a` at
/// machine position `x_mm`, counted from its value at machine position `reference_mm` (a table
/// that is zero at the control's reference point does not shift the machine's zero).
pub(crate) fn error_from_mm(
    m: &MachineErrors,
    a: Axis,
    placement: &Placement,
    x_mm: f64,
    reference_mm: f64,
) -> f64 {
    let k0 = placement.table_ball_mm[a.index()].unwrap_or(0.0);
    m.position_error_mm(a, x_mm - k0) - m.position_error_mm(a, reference_mm - k0)
}

/// A table of equal steps over `lo..hi` (mm) for a control that interpolates linearly between
/// its points (SINUMERIK's `$AA_ENC_COMP`, Heidenhain's `*.COM`): (position, δ from
/// `reference_mm`), at most `max_points`; 16 points per pitch of a cyclic error where they fit,
/// else 65 over the span. The cyclic part of each point is divided by sinc²(step/pitch), the share
/// of a sine that linear interpolation between the points keeps (as for LinuxCNC's COMP_FILE).
pub(crate) fn linear_table(
    m: &MachineErrors,
    a: Axis,
    placement: &Placement,
    (lo, hi): (f64, f64),
    max_points: usize,
    reference_mm: f64,
) -> Vec<(f64, f64)> {
    let k0 = placement.table_ball_mm[a.index()].unwrap_or(0.0);
    let (n, attenuation) = match &m.cyclic[a.index()] {
        Some(c) => {
            let n = (((hi - lo) / (c.pitch_mm / 16.0)).ceil() as usize).clamp(1, max_points - 1);
            let x = std::f64::consts::PI * (hi - lo) / n as f64 / c.pitch_mm;
            (n, (x.sin() / x).powi(2))
        }
        None => (64.min(max_points - 1), 1.0),
    };
    (0..=n)
        .map(|i| {
            let x = lo + (hi - lo) * i as f64 / n as f64;
            let cyclic = m.cyclic_error_mm(a, x - k0) - m.cyclic_error_mm(a, reference_mm - k0);
            let e = error_from_mm(m, a, placement, x, reference_mm) - cyclic + cyclic / attenuation;
            (x, e)
        })
        .collect()
}

/// The value of an equal-step table (`min_mm`, `step_mm`, values) at `x_mm`: linear between its
/// points, the end values held beyond it (SINUMERIK's and Heidenhain's tables in force).
pub(crate) fn table_at(min_mm: f64, step_mm: f64, values: &[f64], x_mm: f64) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let u = (x_mm - min_mm) / step_mm;
    if u <= 0.0 || step_mm <= 0.0 {
        return values[0];
    }
    let i = u.floor() as usize;
    if i + 1 >= values.len() {
        return values[values.len() - 1];
    }
    let t = u - i as f64;
    values[i] + t * (values[i + 1] - values[i])
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// A test effect: name, value, σ, parameters.
    type TestEffect<'a> = (&'a str, f64, f64, &'a [(&'a str, f64)]);

    /// A diagnosis file with these machine effects.
    fn doc(effects: &[TestEffect]) -> DiagnosisDoc {
        let effects: Vec<serde_json::Value> = effects
            .iter()
            .map(|(n, v, s, p)| {
                let params: serde_json::Map<String, serde_json::Value> = p
                    .iter()
                    .map(|(k, x)| (k.to_string(), serde_json::json!(x)))
                    .collect();
                serde_json::json!({"name": n, "value": v, "sigma": s, "unit": "um", "params": params})
            })
            .collect();
        // Format 2: the values as given (an older file would be upgraded as it is read).
        let text = serde_json::json!({"format": 2, "samples": 1000, "effects": effects,
            "circles": [{"radius_mm": 50.0, "height_mm": 0.0, "feed_mm_min": 1000.0}]})
        .to_string();
        DiagnosisDoc::parse(Path::new("d.json"), &text).unwrap()
    }

    fn current(c: Controller, text: &str) -> Current {
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("cur");
        std::fs::write(&f, text).unwrap();
        Current::read(&f, c).unwrap()
    }

    fn opts(c: Controller) -> Options {
        Options {
            controller: c,
            placement: Placement::default(),
            comp_file_type: 1,
        }
    }

    #[test]
    fn an_axis_that_runs_ahead_lowers_the_setting_in_force_or_cannot() {
        // b = −3 µm: the axis runs ahead by 1.5 µm each way (too much compensation in force).
        let d = doc(&[("backlash_x", -3.0, 0.01, &[("b_um", -3.0)])]);
        for c in [Controller::GrblHal, Controller::Marlin] {
            let p = plan(&d, &Current::none(), &opts(c)).unwrap();
            assert!(p.changes.is_empty() && p.cannot.len() == 1, "{c:?}: {p:?}");
            assert!(p.cannot[0].why.contains("runs ahead"), "{:?}", p.cannot[0]);
        }
        let p = plan(
            &d,
            &current(Controller::GrblHal, "$160=0.010\n"),
            &opts(Controller::GrblHal),
        )
        .unwrap();
        assert!(
            (p.changes[0].new - 0.007).abs() < 1e-12,
            "{:?}",
            p.changes[0]
        );
        let p = plan(
            &d,
            &current(Controller::Marlin, "M425 F0.5 X0.010\n"),
            &opts(Controller::Marlin),
        )
        .unwrap();
        // Effective 5 µm in force − 3 µm = 2 µm, at F0.5: X 0.004.
        assert!(
            (p.changes[0].new - 0.004).abs() < 1e-12,
            "{:?}",
            p.changes[0]
        );
        assert_eq!(p.blocks[0].lines[0], "M425 F0.5 X0.004000");
        // LinuxCNC applies a negative BACKLASH as it is, and says what it means.
        let p = plan(&d, &Current::none(), &opts(Controller::LinuxCnc)).unwrap();
        assert!((p.changes[0].new + 0.003).abs() < 1e-12);
        assert!(p.notes.iter().any(|n| n.contains("runs ahead")));
    }

    #[test]
    fn effects_below_3_sigma_are_left_alone() {
        let d = doc(&[
            ("backlash_x", 0.02, 0.01, &[("b_um", 0.02)]),
            ("squareness_xy", 12.0, 0.05, &[("s_um_per_m", 12.0)]),
        ]);
        let p = plan(&d, &Current::none(), &opts(Controller::Marlin)).unwrap();
        assert_eq!(p.changes.len(), 1);
        assert!(
            p.left_alone[0].starts_with("backlash_x"),
            "{:?}",
            p.left_alone
        );
    }

    #[test]
    fn current_files_read_in_each_format_and_say_where_they_are_wrong() {
        let c = current(
            Controller::LinuxCnc,
            "# mill\n[AXIS_1]\nBACKLASH = 0.004\n[JOINT_0]\nBACKLASH=0.002 ; x\nCOMP_FILE = x.comp\nsetp matrixkins.C_xy 0.0001\n",
        );
        assert_eq!(c.get("JOINT_1.BACKLASH"), Some(0.004));
        assert_eq!(c.get("JOINT_0.BACKLASH"), Some(0.002));
        assert_eq!(c.text("JOINT_0.COMP_FILE"), Some("x.comp"));
        assert_eq!(c.get("matrixkins.C_xy"), Some(0.0001));
        let c = current(Controller::GrblHal, "$100=800.000\nok\n$160=0.004\n");
        assert_eq!((c.get("$100"), c.get("$160")), (Some(800.0), Some(0.004)));
        let c = current(
            Controller::Klipper,
            "[stepper_x]\nrotation_distance: 40\n#*# [skew_correction jdbb]\n#*# xy_skew = 0.0002\n",
        );
        assert_eq!(c.get("stepper_x.rotation_distance"), Some(40.0));
        assert_eq!(c.get("xy_skew"), Some(0.0002));
        let c = current(Controller::Marlin, "M852 S0.0003\n");
        assert_eq!(c.get("M852.I"), Some(0.0003));

        let dir = tempfile::tempdir().unwrap();
        for (ctl, text, want) in [
            (
                Controller::LinuxCnc,
                "[JOINT_0]\nBACKLASH = 0,004\n",
                ":2:12: BACKLASH",
            ),
            (Controller::GrblHal, "$160=0.0o4\n", ":1:6: $160"),
            (
                Controller::Klipper,
                "#*# [skew_correction a]\n#*# xy_skew = x\n",
                ":2:15: xy_skew",
            ),
        ] {
            let f = dir.path().join("bad");
            std::fs::write(&f, text).unwrap();
            let e = Current::read(&f, ctl).unwrap_err();
            assert!(e.to_string().contains(want), "{ctl:?}: {e}");
            assert_eq!(e.exit_code(), 2);
        }
    }

    #[test]
    fn linuxcnc_in_inches_reads_and_writes_inches() {
        let d = doc(&[
            ("backlash_y", 8.0, 0.01, &[("b_um", 8.0)]),
            ("scale_x", 100.0, 0.1, &[("a_um_per_m", 100.0)]),
        ]);
        let inch = current(
            Controller::LinuxCnc,
            "[TRAJ]\nLINEAR_UNITS = inch\n[JOINT_1]\nBACKLASH = 0.0001\n",
        );
        let mut o = opts(Controller::LinuxCnc);
        o.placement.table_ball_mm = [Some(254.0), Some(0.0), None];
        let p = plan(&d, &inch, &o).unwrap();
        assert!(p.title.contains("machine units inch"), "{}", p.title);
        // 0.0001 in in force (2.54 µm) + 8 µm = 0.0001 + 0.000314961 in.
        let c = p
            .changes
            .iter()
            .find(|c| c.setting == "[JOINT_1] BACKLASH")
            .unwrap();
        assert_eq!((c.unit.as_str(), c.current), ("inch", 0.0001));
        assert!((c.new - (0.0001 + 0.008 / 25.4)).abs() < 1e-12, "{c:?}");
        assert!(p.blocks[0]
            .lines
            .contains(&"BACKLASH = 0.0004150".to_string()));
        // The comp table: positions and trims in inches; the table ball at 10 in.
        let (_, table) = &p.files[0];
        let first: Vec<f64> = table
            .lines()
            .next()
            .unwrap()
            .split(' ')
            .map(|w| w.parse().unwrap())
            .collect();
        let x_mm = first[0] * 25.4;
        assert!((x_mm - 204.0).abs() < 1e-4, "{first:?}");
        let want_in = -1e-4 * (x_mm - 254.0) / 25.4;
        assert!(
            (first[1] - want_in).abs() < 1e-7 && (first[2] - want_in).abs() < 1e-7,
            "{first:?}"
        );
        // Without LINEAR_UNITS: mm, and the title says it is assumed.
        let p = plan(&d, &Current::none(), &o).unwrap();
        assert!(p.title.contains("machine units mm (assumed"), "{}", p.title);
        let bad = tempfile::tempdir().unwrap();
        let f = bad.path().join("c.ini");
        std::fs::write(&f, "[TRAJ]\nLINEAR_UNITS = furlong\n").unwrap();
        let e = Current::read(&f, Controller::LinuxCnc).unwrap_err();
        assert!(e.to_string().contains(":2:16: LINEAR_UNITS"), "{e}");
    }

    #[test]
    fn linuxcnc_comp_file_in_force_is_merged_and_its_backlash_setting_not_counted() {
        let d = doc(&[("backlash_x", 4.0, 0.01, &[("b_um", 4.0)])]);
        let dir = tempfile::tempdir().unwrap();
        let ini = dir.path().join("mill.ini");
        std::fs::write(
            &ini,
            "[JOINT_0]\nBACKLASH = 0.010\nCOMP_FILE = old.comp\nCOMP_FILE_TYPE = 1\n",
        )
        .unwrap();
        let o = opts(Controller::LinuxCnc);
        // The table missing: refuse, never replace it unseen.
        let e = plan(&d, &Current::read(&ini, Controller::LinuxCnc).unwrap(), &o).unwrap_err();
        assert!(e.to_string().contains("merged into that table"), "{e}");
        assert_eq!(e.exit_code(), 2);
        // 2 µm of backlash in force through the table, and a trim that grows with X.
        std::fs::write(
            dir.path().join("old.comp"),
            "-100 0.001 -0.001\n100 0.003 0.001\n",
        )
        .unwrap();
        let p = plan(&d, &Current::read(&ini, Controller::LinuxCnc).unwrap(), &o).unwrap();
        assert!(
            p.blocks
                .iter()
                .all(|b| b.lines.iter().all(|l| !l.starts_with("BACKLASH"))),
            "{:?}",
            p.blocks
        );
        let (name, table) = &p.files[0];
        assert_eq!(name, "x.comp");
        let rows: Vec<Vec<f64>> = table
            .lines()
            .map(|l| l.split(' ').map(|w| w.parse().unwrap()).collect())
            .collect();
        let want = [[-100.0, 0.003, -0.003], [100.0, 0.005, -0.001]];
        assert_eq!(rows.len(), 2, "{table}");
        for (r, w) in rows.iter().zip(want) {
            for (a, b) in r.iter().zip(w) {
                assert!((a - b).abs() < 1e-9, "{table}");
            }
        }
        let c = p
            .changes
            .iter()
            .find(|c| c.setting.contains("backlash in x.comp"))
            .unwrap();
        assert!(
            (c.current - 0.002).abs() < 1e-12 && (c.new - 0.006).abs() < 1e-12,
            "{c:?}"
        );
        assert!(p
            .notes
            .iter()
            .any(|n| n.contains("BACKLASH = 0.01 in force is ignored")));
        assert!(p.notes.iter().any(|n| n.contains("not a replacement")));
    }

    #[test]
    fn marlin_values_rounded_by_m503_are_warned_with_their_error_and_where_to_read_them() {
        let d = doc(&[
            ("backlash_x", 8.0, 0.01, &[("b_um", 8.0)]),
            ("scale_x", 100.0, 0.1, &[("a_um_per_m", 100.0)]),
        ]);
        let m503 = current(
            Controller::Marlin,
            "echo:  M92 X80.00 Y80.00 Z400.00 E93.00\necho:  M425 F1.00 S0.00 X0.01 Y0.01 Z0.00\n",
        );
        let p = plan(&d, &m503, &opts(Controller::Marlin)).unwrap();
        let note = p
            .notes
            .iter()
            .find(|n| n.contains("rounded as M503 prints them"))
            .unwrap_or_else(|| panic!("{:?}", p.notes));
        // X0.01: ±0.005 mm = ±5 µm; X80.00 steps/mm: ±0.005/80 = ±62.5 µm/m.
        assert!(note.contains("M425 X0.01 (±0.005 → ±5.0 µm)"), "{note}");
        assert!(note.contains("M92 X80.00 (±0.005 → ±62.5 µm/m)"), "{note}");
        assert!(
            !note.contains("Y80") && !note.contains("M425 Y"),
            "only values used: {note}"
        );
        assert!(
            note.contains("Configuration.h") && note.contains("EEPROM"),
            "{note}"
        );
        // Exact values given: no warning.
        let exact = current(Controller::Marlin, "M92 X80.0125\nM425 F1 X0.0104\n");
        let p = plan(&d, &exact, &opts(Controller::Marlin)).unwrap();
        assert!(p.notes.iter().all(|n| !n.contains("M503")), "{:?}", p.notes);
    }

    #[test]
    fn klipper_of_several_skew_profiles_takes_the_loaded_one_or_asks() {
        let d = doc(&[("squareness_xy", 20.0, 0.05, &[("s_um_per_m", 20.0)])]);
        let profiles = "#*# [skew_correction cold]\n#*# xy_skew = 0.0001\n#*# [skew_correction hot]\n#*# xy_skew = 0.0003\n";
        // No LOAD line: refuse, listing the profiles.
        let c = current(Controller::Klipper, profiles);
        let e = plan(&d, &c, &opts(Controller::Klipper)).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("2 skew profiles (cold, hot)") && msg.contains("SKEW_PROFILE LOAD="),
            "{msg}"
        );
        assert_eq!(e.exit_code(), 2);
        // The start macro loads the first one: it is in force, not the last.
        let c = current(
            Controller::Klipper,
            &format!("[gcode_macro START_PRINT]\ngcode:\n  SKEW_PROFILE LOAD=cold\n{profiles}"),
        );
        let p = plan(&d, &c, &opts(Controller::Klipper)).unwrap();
        assert_eq!(p.changes[0].current, 0.0001);
        assert!(
            (p.changes[0].new - (0.0001 + 20e-6)).abs() < 1e-15,
            "{:?}",
            p.changes[0]
        );
        assert!(
            p.notes
                .iter()
                .any(|n| n.contains("cold is taken as in force")),
            "{:?}",
            p.notes
        );
        // A LOAD of a profile the file does not have: refuse.
        let c = current(
            Controller::Klipper,
            &format!("SKEW_PROFILE LOAD=warm\n{profiles}"),
        );
        let e = plan(&d, &c, &opts(Controller::Klipper)).unwrap_err();
        assert!(e.to_string().contains("LOAD=warm names no profile"), "{e}");
    }

    #[test]
    fn controller_names_parse() {
        for c in Controller::ALL {
            assert_eq!(Controller::parse(c.name()).unwrap(), c);
        }
        assert_eq!(Controller::parse("LinuxCNC").unwrap(), Controller::LinuxCnc);
        let e = Controller::parse("okuma").unwrap_err();
        assert!(e
            .to_string()
            .contains("linuxcnc, grblhal, marlin, klipper, fanuc, sinumerik, heidenhain"));
        assert_eq!(e.exit_code(), 2);
    }
}
