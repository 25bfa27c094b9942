//! The machine of `jdbb simulate --plan plan.json --machine MACHINE.toml`: a small TOML file that
//! says how the machine runs a plan's program (feed override, acceleration, rapid speed,
//! controller), which errors it has (the effects of the diagnosis, by the same names, parameters
//! and units), where the table ball really is, and how the instrument records it (sample rate,
//! clock error, start delay, noise, lean, seed, calibration). [`EXAMPLE`] is the documented
//! example (`jdbb simulate --machine` prints it); `docs/simulate.md` describes every key.
//!
//! Errors name `file:line:column` (the TOML's spans) and say what the key must hold.
use std::collections::BTreeMap;
use std::path::{Path as FsPath, PathBuf};

use jdbb_core::calib::Calibration;
use serde::Deserialize;

use crate::model::path::{Axis, Pair};
use crate::model::Effect;
use crate::plan::Dialect;
use crate::simulate::{parse_effect, EffectValue};
use crate::{Error, Result};

/// The commented example machine (`jdbb simulate --machine` with no file prints it).
pub const EXAMPLE: &str = r#"# A machine for `jdbb simulate --plan plan.json --machine machine.toml -o rec.csv`.
# Every key is optional; the values shown are the defaults unless marked "example".
# See docs/simulate.md for what each key does.

name = "example mill"          # example: for the messages only
# controller = "linuxcnc"      # linuxcnc, grbl, fanuc or marlin (default: the plan's dialect);
                               # marlin draws arcs as chords of arc_segment_mm
arc_segment_mm = 1.0           # marlin's MM_PER_ARC_SEGMENT
feed_override_pct = 98.0       # example (default 100): the feed override knob, % (not dwells)
accel_mm_s2 = 500.0            # acceleration at every start and stop, mm/s² (trapezoidal moves)
rapid_mm_min = 5000.0          # speed of a G0, mm/min
operator_stop_s = 5.0          # how long each M0 after the first lasts (the operator), s
# table_ball_mm = [100.0, 50.0, -20.0]   # where the table ball really is, machine mm
                               # (default: the plan's centre_mm; a difference is a set-up offset)
# pitch_mm = { x = 10.0, y = 10.0 }      # ball-screw pitch, mm: needed by cyclic_k, interference_k

[instrument]
sample_rate_hz = 1000.0        # the device's sample clock, Hz
clock_ppm = 37.0               # example (default 0): the device's clock runs fast by this, ppm
start_delay_s = 3.0            # the recording starts this long before cycle start, s
tail_s = 2.0                   # and goes on this long after the program ends, s
noise_um = 0.2                 # example (default 0): Gaussian noise on D, µm (1 sigma)
lean_deg = 17.0                # the bars' lean about the ball-to-ball line, deg
t0_us = 0                      # the device's t_us at the first sample
seed = 1                       # seed of the noise
serial = "000000000000000000000000"   # the serial the device reports (24 hex digits: its
                                    # chip ID), written on the record's # instrument_serial: line
# calibration = "instrument.toml"   # the calibration in force (default: the nominal J-DBB);
                                    # a path relative to this file

[effects]                      # names, parameters and units as in `jdbb diagnose --json`
backlash_x = 8.0               # example: lost motion on X, µm
squareness_xy = 30.0           # example: X and Y out of square, µm/m
# backlash_y = [6.0, 4.0]      # at the positive and the negative end of the travel, µm
# cyclic_x = "3@45"            # amplitude µm @ phase deg (needs pitch_mm)
# setup_offset = [5.0, -3.0, 0.0]   # all parameters as an array, in the effect's units
"#;

/// One family of effects for [`effect_list`]: a representative (axis x, pair xy), and what it is
/// on the machine in a few words.
const FAMILIES: [(Effect, &str); 17] = [
    (
        Effect::SetupOffset,
        "the table ball is not where the plan says (set-up)",
    ),
    (
        Effect::LengthOffset,
        "the bar is longer than its calibrated length (set-up)",
    ),
    (Effect::Scale(Axis::X), "k's scale (pitch or thermal) error"),
    (
        Effect::Scale2(Axis::X),
        "k's second-order scale error (about the table ball)",
    ),
    (
        Effect::Backlash(Axis::X),
        "k's lost motion at reversal, a dead band; negative: over-compensated",
    ),
    (
        Effect::BacklashEnds(Axis::X),
        "k's lost motion, different at the two ends of the travel",
    ),
    (
        Effect::Cyclic(Axis::X),
        "k's ball-screw cyclic error, once per pitch (needs pitch_mm)",
    ),
    (
        Effect::Interference(Axis::X),
        "k's cyclic error growing with speed (needs pitch_mm)",
    ),
    (
        Effect::Squareness(Pair::Xy),
        "i moves by this per metre of j: i and j out of square",
    ),
    (
        Effect::ServoMismatch(Pair::Xy),
        "i follows its command later than j (servo mismatch)",
    ),
    (
        Effect::ReversalSpike(Axis::X),
        "k sticks at reversal and catches up (height, decay time)",
    ),
    (
        Effect::Straightness(Axis::X, Axis::Y),
        "k is bowed along j (bow at mid travel)",
    ),
    (
        Effect::LateralPlay(Axis::X, Axis::Y),
        "k steps sideways (along j) where k reverses",
    ),
    (Effect::Drift, "D drifts in time (thermal)"),
    (
        Effect::ScaleDrift(Axis::X),
        "k's scale grows in time (thermal drift of scale, per minute)",
    ),
    (
        Effect::PositionDrift(Axis::X),
        "k's position drifts in time (a screw growing about its bearing, spindle growth)",
    ),
    (
        Effect::FollowingError,
        "the position loops draw circles smaller by q·v²/R (following error)",
    ),
];

/// The name of `e`'s family: its axes as k (one axis), ij (a pair) or k_j (two axes).
fn family_name(e: &Effect) -> String {
    let name = e.name();
    let axes = |p: &str| !p.is_empty() && p.chars().all(|c| matches!(c, 'x' | 'y' | 'z'));
    let mut parts: Vec<&str> = name.split('_').collect();
    let tail = match parts.as_slice() {
        [.., a, b] if axes(a) && axes(b) && a.len() == 1 => "k_j",
        [.., a] if axes(a) && a.len() == 2 => "ij",
        [.., a] if axes(a) => "k",
        _ => return name,
    };
    parts.truncate(parts.len() - tail.split('_').count());
    format!("{}_{tail}", parts.join("_"))
}

/// The commented list of every effect the diagnosis knows, for the example machine: its name
/// (by family), its parameters with their units, and what one value stands for.
fn effect_list() -> String {
    let mut out = String::from(
        "\n# Every effect `jdbb diagnose` knows, by family (k: x, y or z; ij: xy, yz or zx; k_j: two\n\
         # different axes). Give one value (the effect's size, in its unit) or all parameters:\n",
    );
    for (e, words) in FAMILIES {
        let params = e.param_names();
        let given = match e {
            Effect::Cyclic(_) | Effect::Interference(_) => {
                format!("\"A@phase_deg\" or [{}]", params.join(", "))
            }
            Effect::BacklashEnds(_) => format!("[{}]", params.join(", ")),
            _ if params.len() == 1 => params[0].to_string(),
            _ if e.params_from_value(1.0, 0.0).is_some() => {
                format!("value or [{}]", params.join(", "))
            }
            _ => format!("[{}]", params.join(", ")),
        };
        out.push_str(&format!(
            "#   {:<20} = {:<38} {}, {}\n",
            family_name(&e),
            given,
            e.unit().replace("um", "µm").replace("^2", "²"),
            words
        ));
    }
    out
}

/// The commented example machine with the list of every effect (`jdbb simulate --machine`
/// prints it).
pub fn example() -> String {
    format!("{EXAMPLE}{}", effect_list())
}

/// How the machine runs the program, its errors, and the instrument (module docs).
#[derive(Debug, Clone)]
pub struct Machine {
    /// For messages.
    pub name: Option<String>,
    /// The controller (None: the plan's dialect).
    pub controller: Option<Dialect>,
    /// Marlin's chord length on arcs (mm).
    pub arc_segment_mm: f64,
    /// Feed override (%): every G1/G2/G3 runs at feed × this / 100.
    pub feed_override_pct: f64,
    /// Acceleration at every start and stop (mm/s²).
    pub accel_mm_s2: f64,
    /// G0 speed (mm/min).
    pub rapid_mm_min: f64,
    /// Duration of each M0 after the first (s).
    pub operator_stop_s: f64,
    /// The table ball's true position (machine mm); None: the plan's centre.
    pub table_ball_mm: Option<[f64; 3]>,
    /// Pitch per axis (mm).
    pub pitch_mm: [Option<f64>; 3],
    pub instrument: RecordingInstrument,
    /// The machine's errors (diagnosis names, parameters and units).
    pub effects: Vec<EffectValue>,
}

/// The instrument as it records (module docs; `[instrument]` of the TOML).
#[derive(Debug, Clone)]
pub struct RecordingInstrument {
    pub sample_rate_hz: f64,
    pub clock_ppm: f64,
    pub start_delay_s: f64,
    pub tail_s: f64,
    pub noise_um: f64,
    /// Lean of the bars about the ball-to-ball line (rad).
    pub lean_rad: f64,
    pub t0_us: u64,
    pub seed: u64,
    /// The serial the simulated device reports (24 upper-case hex digits, as `jdbb record`
    /// writes a real one on the record's `# instrument_serial:` line).
    pub serial: String,
    /// The calibration in force (counts are made with it and D is computed with it): the
    /// nominal J-DBB unless the caller reads `calibration_file` into it.
    pub calibration: Calibration,
    /// `instrument.calibration` of the file, relative to the machine file's directory: a
    /// calibration TOML for the caller to read (`crate::instrument::file`, which this module may
    /// not use: it uses this one).
    pub calibration_file: Option<PathBuf>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct MachineToml {
    name: Option<String>,
    controller: Option<toml::Spanned<String>>,
    arc_segment_mm: Option<toml::Spanned<f64>>,
    feed_override_pct: Option<toml::Spanned<f64>>,
    accel_mm_s2: Option<toml::Spanned<f64>>,
    rapid_mm_min: Option<toml::Spanned<f64>>,
    operator_stop_s: Option<toml::Spanned<f64>>,
    table_ball_mm: Option<toml::Spanned<[f64; 3]>>,
    pitch_mm: Option<toml::Spanned<BTreeMap<String, f64>>>,
    instrument: Option<InstrumentToml>,
    effects: Option<BTreeMap<String, toml::Spanned<toml::Value>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct InstrumentToml {
    sample_rate_hz: Option<toml::Spanned<f64>>,
    clock_ppm: Option<toml::Spanned<f64>>,
    start_delay_s: Option<toml::Spanned<f64>>,
    tail_s: Option<toml::Spanned<f64>>,
    noise_um: Option<toml::Spanned<f64>>,
    lean_deg: Option<toml::Spanned<f64>>,
    t0_us: Option<u64>,
    seed: Option<u64>,
    serial: Option<toml::Spanned<String>>,
    calibration: Option<toml::Spanned<PathBuf>>,
}

impl Machine {
    /// Read and check a machine TOML (module docs).
    pub fn read(path: &FsPath) -> Result<Machine> {
        let text = crate::table::read_text(path)?;
        Machine::parse(path, &text)
    }

    /// [`Machine::read`] on text in memory; `path` names it in errors (and relative calibration
    /// paths are taken from its directory).
    pub fn parse(path: &FsPath, text: &str) -> Result<Machine> {
        let at = |span: std::ops::Range<usize>, message: String| {
            let (line, col) = crate::table::line_col(text, span.start);
            Error::input(path, line, col, message)
        };
        let m: MachineToml = toml::from_str(text).map_err(|e| {
            let (line, col) = e
                .span()
                .map_or((1, 0), |s| crate::table::line_col(text, s.start));
            Error::input(
                path,
                line,
                col,
                format!(
                    "{}; a machine file is TOML as `jdbb simulate --machine` prints it",
                    e.message().trim_end()
                ),
            )
        })?;
        // A number within [lo, hi], or the default.
        let num = |v: &Option<toml::Spanned<f64>>,
                   key: &str,
                   default: f64,
                   lo: f64,
                   hi: f64,
                   unit: &str|
         -> Result<f64> {
            match v {
                None => Ok(default),
                Some(s) if s.get_ref().is_finite() && (lo..=hi).contains(s.get_ref()) => {
                    Ok(*s.get_ref())
                }
                Some(s) => Err(at(
                    s.span(),
                    format!(
                        "{key} = {}: give a value from {lo} to {hi} {unit}",
                        s.get_ref()
                    ),
                )),
            }
        };
        let controller = match &m.controller {
            None => None,
            Some(s) => Some(
                Dialect::parse(&s.get_ref().to_ascii_lowercase()).ok_or_else(|| {
                    at(
                        s.span(),
                        format!(
                            "controller = \"{}\": use linuxcnc, grbl, fanuc or marlin",
                            s.get_ref()
                        ),
                    )
                })?,
            ),
        };
        let mut pitch_mm = [None; 3];
        if let Some(p) = &m.pitch_mm {
            for (k, v) in p.get_ref() {
                let Some(axis) = crate::model::path::Axis::parse(&k.to_ascii_lowercase()) else {
                    return Err(at(
                        p.span(),
                        format!("pitch_mm: `{k}` is not an axis; use x, y or z"),
                    ));
                };
                if !(v.is_finite() && *v > 0.0) {
                    return Err(at(
                        p.span(),
                        format!("pitch_mm.{k} = {v}: a pitch is a positive length in mm"),
                    ));
                }
                pitch_mm[axis.index()] = Some(*v);
            }
        }
        if let Some(b) = &m.table_ball_mm {
            if !b.get_ref().iter().all(|x| x.is_finite() && x.abs() <= 1e5) {
                return Err(at(
                    b.span(),
                    "table_ball_mm: three finite coordinates in mm, e.g. [100.0, 50.0, -20.0]"
                        .into(),
                ));
            }
        }
        let ins = m.instrument.as_ref();
        let g =
            |f: fn(&InstrumentToml) -> &Option<toml::Spanned<f64>>| -> Option<toml::Spanned<f64>> {
                ins.and_then(|i| f(i).clone())
            };
        let calibration_file = ins.and_then(|i| i.calibration.as_ref()).map(|c| {
            path.parent()
                .map_or_else(|| c.get_ref().clone(), |d| d.join(c.get_ref()))
        });
        let serial = match ins.and_then(|i| i.serial.as_ref()) {
            None => "0".repeat(24),
            Some(s) => {
                let v = s.get_ref();
                if v.len() != 24 || !v.chars().all(|c| c.is_ascii_hexdigit()) {
                    return Err(at(
                        s.span(),
                        format!("serial = \"{v}\": give 24 hex digits (the device's chip ID)"),
                    ));
                }
                v.to_ascii_uppercase()
            }
        };
        let instrument = RecordingInstrument {
            sample_rate_hz: num(
                &g(|i| &i.sample_rate_hz),
                "sample_rate_hz",
                1000.0,
                1.0,
                100_000.0,
                "Hz",
            )?,
            clock_ppm: num(
                &g(|i| &i.clock_ppm),
                "clock_ppm",
                0.0,
                -10_000.0,
                10_000.0,
                "ppm",
            )?,
            start_delay_s: num(
                &g(|i| &i.start_delay_s),
                "start_delay_s",
                3.0,
                0.0,
                3600.0,
                "s",
            )?,
            tail_s: num(&g(|i| &i.tail_s), "tail_s", 2.0, 0.0, 3600.0, "s")?,
            noise_um: num(&g(|i| &i.noise_um), "noise_um", 0.0, 0.0, 1000.0, "µm")?,
            lean_rad: num(&g(|i| &i.lean_deg), "lean_deg", 17.0, -90.0, 90.0, "deg")?.to_radians(),
            t0_us: ins.and_then(|i| i.t0_us).unwrap_or(0),
            seed: ins.and_then(|i| i.seed).unwrap_or(1),
            serial,
            calibration: Calibration::DEFAULT,
            calibration_file,
        };
        let mut effects = vec![];
        for (name, value) in m.effects.iter().flatten() {
            let v = match value.get_ref() {
                toml::Value::Integer(i) => i.to_string(),
                toml::Value::Float(f) => f.to_string(),
                toml::Value::String(s) => s.clone(),
                toml::Value::Array(a) => a
                    .iter()
                    .map(|x| match x {
                        toml::Value::Integer(i) => Some(i.to_string()),
                        toml::Value::Float(f) => Some(f.to_string()),
                        _ => None,
                    })
                    .collect::<Option<Vec<_>>>()
                    .map(|v| v.join(","))
                    .ok_or_else(|| {
                        at(value.span(), format!("effects.{name}: an array of numbers"))
                    })?,
                _ => {
                    return Err(at(
                        value.span(),
                        format!(
                            "effects.{name}: a number, an array of numbers or \"value@phase_deg\""
                        ),
                    ))
                }
            };
            let ev = parse_effect(&format!("{name}={v}")).map_err(|e| {
                let msg = e.to_string();
                let msg = msg
                    .strip_prefix("--effect")
                    .map_or(msg.as_str(), str::trim_start);
                at(
                    value.span(),
                    format!(
                        "effects.{name}: {}",
                        msg.trim_start_matches(':').trim_start()
                    ),
                )
            })?;
            effects.push(ev);
        }
        Ok(Machine {
            name: m.name,
            controller,
            arc_segment_mm: num(&m.arc_segment_mm, "arc_segment_mm", 1.0, 0.001, 100.0, "mm")?,
            feed_override_pct: num(
                &m.feed_override_pct,
                "feed_override_pct",
                100.0,
                1.0,
                300.0,
                "%",
            )?,
            accel_mm_s2: num(
                &m.accel_mm_s2,
                "accel_mm_s2",
                500.0,
                1.0,
                100_000.0,
                "mm/s²",
            )?,
            rapid_mm_min: num(
                &m.rapid_mm_min,
                "rapid_mm_min",
                5000.0,
                1.0,
                200_000.0,
                "mm/min",
            )?,
            operator_stop_s: num(&m.operator_stop_s, "operator_stop_s", 5.0, 0.0, 3600.0, "s")?,
            table_ball_mm: m.table_ball_mm.map(|b| b.into_inner()),
            pitch_mm,
            instrument,
            effects,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_example_lists_every_effect_the_diagnosis_knows() {
        let text = example();
        let families: Vec<String> = FAMILIES.iter().map(|(e, _)| family_name(e)).collect();
        for e in Effect::all() {
            let f = family_name(&e);
            assert!(families.contains(&f), "{} is not in the example", e.name());
            assert!(text.contains(&format!("#   {f} ")), "{f}");
            for p in e.param_names() {
                assert!(text.contains(p), "{p} of {}", e.name());
            }
        }
        // Still a machine file that reads, with the list as comments.
        Machine::parse(FsPath::new("example.toml"), &text).unwrap();
    }

    #[test]
    fn the_example_reads_with_its_values() {
        let m = Machine::parse(FsPath::new("example.toml"), EXAMPLE).unwrap();
        assert_eq!(m.controller, None);
        assert_eq!(m.feed_override_pct, 98.0);
        assert_eq!(m.instrument.clock_ppm, 37.0);
        assert_eq!(m.instrument.sample_rate_hz, 1000.0);
        let names: Vec<String> = m.effects.iter().map(|e| e.effect.name()).collect();
        assert_eq!(names, ["backlash_x", "squareness_xy"]);
        assert_eq!(m.effects[0].params, vec![8.0]);
    }

    #[test]
    fn bad_values_name_line_and_column() {
        let text = "feed_override_pct = 100.0\n[effects]\nbacklash_q = 3\n";
        let e = Machine::parse(FsPath::new("m.toml"), text)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.toml:3:"), "{e}");
        assert!(e.contains("unknown effect `backlash_q`"), "{e}");
        let text = "\n\naccel_mm_s2 = -5\n";
        let e = Machine::parse(FsPath::new("m.toml"), text)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("m.toml:3:"), "{e}");
        let text = "feed_overide_pct = 100\n";
        let e = Machine::parse(FsPath::new("m.toml"), text)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("m.toml:1:1") && e.contains("feed_overide_pct"),
            "{e}"
        );
    }
}
