//! A diagnosis as a file: the JSON that `jdbb diagnose --json` prints and `--report DIR` writes
//! (documented in [`crate::report`]), read back into types. It is the input contract of
//! `jdbb compensate` and `jdbb history`: they never rerun a diagnosis.
//!
//! Every field added after the first version is optional here, so an older file still reads;
//! fields this reader does not know are ignored, so a newer file does too. A malformed file is
//! an input error at `file:line:column` (serde_json's position).
//!
//! A file of an older `format` (absent = 1) is upgraded to this version's conventions as it is
//! read ([`upgrade`]), so an old run keeps its meaning: format 1 wrote backlash with the
//! opposite sign (positive = the axis runs ahead) and the set-up offset as the centring c of
//! D = |p + c| (the table ball at −c), took the circular deviation G about the least-squares
//! centre, and had shares that did not add up to 1.
use std::collections::BTreeMap;
use std::path::Path as FsPath;

use serde::Deserialize;

use crate::model::words;
use crate::model::{Axis, Effect};
use crate::{Error, Result};

/// The `format` of the diagnosis JSON this version writes and reads: 2 = backlash positive is
/// lost motion, the set-up offset is where the table ball is, G is the minimum zone's, shares
/// add up to 1 (see [`crate::report`]). Older files are upgraded as they are read ([`upgrade`]).
pub const FORMAT: u32 = 2;

/// One effect of the file.
#[derive(Debug, Clone, Deserialize)]
pub struct EffectDoc {
    pub name: String,
    pub value: Option<f64>,
    #[serde(default)]
    pub unit: String,
    pub sigma: Option<f64>,
    #[serde(default)]
    pub params: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub params_sigma: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub setup: bool,
    #[serde(default)]
    pub cause: String,
    #[serde(default)]
    pub contribution_rms_um: Option<f64>,
    #[serde(default)]
    pub share: Option<f64>,
    /// The effect's share of G (absent in files written before it; see the report's docs).
    #[serde(default)]
    pub g_share: Option<f64>,
    /// The test's G without this effect, µm.
    #[serde(default)]
    pub g_without_um: Option<f64>,
}

impl EffectDoc {
    /// The effect this entry names, if it is one this version knows.
    pub fn effect(&self) -> Option<Effect> {
        match Effect::parse(&self.name)? {
            // A backlash whose two ends differ carries `pos_um`/`neg_um`.
            Effect::Backlash(a) if self.params.contains_key("pos_um") => {
                Some(Effect::BacklashEnds(a))
            }
            e => Some(e),
        }
    }

    /// The effect's parameters in [`Effect::param_names`] order (a missing or null one is 0).
    pub fn param_values(&self, effect: Effect) -> Vec<f64> {
        effect
            .param_names()
            .iter()
            .map(|n| self.params.get(*n).copied().flatten().unwrap_or(0.0))
            .collect()
    }

    /// Whether the value is at least `k` standard errors from zero (false if σ is unknown).
    pub fn significant(&self, k: f64) -> bool {
        match (self.value, self.sigma) {
            (Some(v), Some(s)) if s > 0.0 => v.abs() >= k * s,
            _ => false,
        }
    }
}

/// One direction's (or both directions') minimum zone of a circle.
#[derive(Debug, Clone, Deserialize)]
pub struct ZoneDoc {
    pub g_um: Option<f64>,
    #[serde(default)]
    pub centre: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub radius_offset_um: Option<f64>,
}

/// One circle of the test: conditions and minimum-zone G and H.
#[derive(Debug, Clone, Deserialize)]
pub struct CircleDoc {
    pub radius_mm: f64,
    #[serde(default)]
    pub height_mm: f64,
    pub feed_mm_min: Option<f64>,
    #[serde(default)]
    pub samples: usize,
    pub g_um: Option<f64>,
    pub h_um: Option<f64>,
    pub ccw: Option<ZoneDoc>,
    pub cw: Option<ZoneDoc>,
    pub bidirectional: Option<ZoneDoc>,
    /// ISO 230-4 radial deviation F per direction (absent in files written before it).
    #[serde(default)]
    pub radial_deviation_f: Option<RadialDeviationDoc>,
    /// G per direction of the trace low-passed at `filter_upr` (absent in files before it).
    #[serde(default)]
    pub g_filtered_um: Option<DirectionsDoc>,
}

/// A figure of one circle per direction, µm (null: not run that way).
#[derive(Debug, Clone, Copy, Default, Deserialize)]
pub struct DirectionsDoc {
    pub ccw: Option<f64>,
    pub cw: Option<f64>,
}

/// F of one circle per direction (`circles[].radial_deviation_f`).
#[derive(Debug, Clone, Default, Deserialize)]
pub struct RadialDeviationDoc {
    pub ccw: Option<RangeDoc>,
    pub cw: Option<RangeDoc>,
}

/// The largest and smallest radial deviation F of one trace, µm.
#[derive(Debug, Clone, Copy, Deserialize)]
pub struct RangeDoc {
    pub max_um: Option<f64>,
    pub min_um: Option<f64>,
}

/// The temperatures during the test (`temperature_c`), °C.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct TemperatureDoc {
    pub machine: Option<f64>,
    pub instrument: Option<f64>,
}

/// The compensation in force during the test (`compensation`).
#[derive(Debug, Clone, Default, Deserialize, PartialEq)]
pub struct CompensationDoc {
    #[serde(default)]
    pub text: String,
    pub file: Option<String>,
}

/// What the instrument said of itself (`instrument`).
#[derive(Debug, Clone, Default, Deserialize)]
pub struct InstrumentDoc {
    pub serial: Option<String>,
}

/// The arc one circle's samples cover (`arcs[]`: degrees from the plane's first axis).
#[derive(Debug, Clone, Deserialize)]
pub struct ArcDoc {
    pub start_deg: f64,
    pub sweep_deg: f64,
    /// Whether it is a partial arc (the diagnosis' own verdict).
    #[serde(default)]
    pub partial: bool,
}

/// A candidate a partial arc barely tells from others: `names` (it first), `free_fraction`.
#[derive(Debug, Clone, Deserialize)]
pub struct WeakOnArcDoc {
    pub names: Vec<String>,
    pub free_fraction: f64,
}

/// An effect the data support that stays under the reporting floor: `name`, `peak_um` (its
/// largest contribution to D).
#[derive(Debug, Clone, Deserialize)]
pub struct BelowFloorDoc {
    pub name: String,
    pub peak_um: Option<f64>,
}

/// An effect the selection chose that the data cannot carry: `name`, `value` ± `sigma` in
/// `unit`, and why it is not named.
#[derive(Debug, Clone, Deserialize)]
pub struct NotSignificantDoc {
    pub name: String,
    pub value: Option<f64>,
    pub sigma: Option<f64>,
    pub unit: String,
    pub reason: String,
}

/// `tolerance` of the file: the limit on G and the verdict.
#[derive(Debug, Clone, Deserialize)]
pub struct ToleranceDoc {
    pub g_um: f64,
    pub pass: bool,
}

/// Two numbers of the file that come as an object `{rms_um}` or `{g_um, h_um}`.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct Figures {
    pub rms_um: Option<f64>,
    pub pv_um: Option<f64>,
    pub g_um: Option<f64>,
    pub h_um: Option<f64>,
}

/// A diagnosis file (see the module docs and [`crate::report`] for the fields).
#[derive(Debug, Clone, Deserialize)]
pub struct DiagnosisDoc {
    /// The conventions the file was written in; after [`DiagnosisDoc::parse`], always
    /// [`FORMAT`].
    #[serde(default)]
    pub format: Option<u32>,
    pub samples: usize,
    #[serde(default)]
    pub baseline: Figures,
    pub effects: Vec<EffectDoc>,
    #[serde(default)]
    pub confounded: Vec<Vec<String>>,
    /// The reporting floor (µm on D).
    #[serde(default)]
    pub floor_um: Option<f64>,
    #[serde(default)]
    pub below_floor: Vec<BelowFloorDoc>,
    #[serde(default)]
    pub not_significant: Vec<NotSignificantDoc>,
    #[serde(rename = "final", default)]
    pub final_fit: Figures,
    /// The residual's share of the error (shares and it add up to 1).
    #[serde(default)]
    pub residual_share: Option<f64>,
    pub gain: Option<f64>,
    pub circular_deviation_g_um: Option<f64>,
    pub hysteresis_h_um: Option<f64>,
    /// What-if: the test's G with the compensable settings entered (absent in files before
    /// it), µm ([`crate::diagnose::Diagnosis::g_if_compensated_um`]).
    #[serde(default)]
    pub g_if_compensated_um: Option<f64>,
    /// The test's G of the traces low-passed at `filter_upr` (absent in files before it), µm.
    #[serde(default)]
    pub circular_deviation_g_filtered_um: Option<f64>,
    /// The low-pass cut-off of the filtered G, undulations per revolution.
    #[serde(default)]
    pub filter_upr: Option<f64>,
    #[serde(default)]
    pub plane: Option<String>,
    #[serde(default)]
    pub pitch_mm: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub circles: Vec<CircleDoc>,
    /// Per circle, the arc its samples cover (absent before partial arcs: full circles).
    #[serde(default)]
    pub arcs: Vec<ArcDoc>,
    /// On a partial arc, the candidates it barely tells from others (see the report's docs).
    #[serde(default)]
    pub weak_on_arc: Vec<WeakOnArcDoc>,
    #[serde(default)]
    pub minimum_zone: Option<Figures>,
    #[serde(default)]
    pub machine: Option<String>,
    #[serde(default)]
    pub date_utc: Option<String>,
    /// What `date_utc` is the date of: `test` (given with `--date`) or `diagnosis` (when
    /// `diagnose` ran); absent in files written before it was said.
    #[serde(default)]
    pub date_of: Option<String>,
    #[serde(default)]
    pub tolerance: Option<ToleranceDoc>,
    /// The instrument calibration, kept as given (compared as a whole between runs).
    #[serde(default)]
    pub calibration: Option<serde_json::Value>,
    /// The name of the file the calibration was read from, as given.
    #[serde(default)]
    pub calibration_file: Option<String>,
    /// The test plan, kept as given (compared as a whole between runs).
    #[serde(default)]
    pub plan: Option<serde_json::Value>,
    /// How the record was lined up with the plan (measured feed, override), kept as given.
    #[serde(default)]
    pub sync: Option<serde_json::Value>,
    #[serde(default)]
    pub operator: Option<String>,
    #[serde(default)]
    pub temperature_c: Option<TemperatureDoc>,
    #[serde(default)]
    pub table_ball_mm: Option<BTreeMap<String, Option<f64>>>,
    #[serde(default)]
    pub compensation: Option<CompensationDoc>,
    #[serde(default)]
    pub instrument: Option<InstrumentDoc>,
}

impl DiagnosisDoc {
    /// Read a diagnosis file; a missing file or malformed JSON is an input error (exit 2), with
    /// `file:line:column` for the latter.
    pub fn read(path: &FsPath) -> Result<(DiagnosisDoc, String)> {
        let text = crate::table::read_text(path)?;
        let doc = Self::parse(path, &text)?;
        Ok((doc, text))
    }

    /// Parse the text of a diagnosis file named `path` (for messages), upgraded to this
    /// version's conventions ([`upgrade`]).
    pub fn parse(path: &FsPath, text: &str) -> Result<DiagnosisDoc> {
        let not_a_diagnosis = |e: serde_json::Error| {
            Error::input(
                path,
                e.line(),
                e.column(),
                format!(
                    "not a jdbb diagnosis ({e}); give the diagnosis.json of `jdbb diagnose --report DIR` or the output of `jdbb diagnose --json`"
                ),
            )
        };
        let mut value: serde_json::Value = serde_json::from_str(text).map_err(not_a_diagnosis)?;
        let format = value.get("format").and_then(|f| f.as_u64()).unwrap_or(1);
        if format > u64::from(FORMAT) {
            return Err(Error::Input {
                location: path.display().to_string(),
                message: format!(
                    "format {format}: written by a newer jdbb (this one reads up to {FORMAT}); update jdbb"
                ),
            });
        }
        if format == u64::from(FORMAT) {
            // A file of this format has only the keys this version writes: a misspelled or
            // foreign key is an error naming it, never silently ignored. (An older file is
            // upgraded instead, whatever else it carried.)
            if let Err((place, key)) = known_keys(&value) {
                let (line, column) = position_of_key(text, &key);
                return Err(Error::input(
                    path,
                    line,
                    column,
                    format!(
                        "{place}: unknown key `{key}` in a format {FORMAT} diagnosis; give the file as `jdbb diagnose` wrote it"
                    ),
                ));
            }
        }
        upgrade(&mut value);
        // Positions are lost once parsed into a value: parse the text again for them.
        let doc: DiagnosisDoc = serde_json::from_value(value)
            .map_err(|_| serde_json::from_str::<DiagnosisDoc>(text).err())
            .map_err(|e| match e {
                Some(e) => not_a_diagnosis(e),
                None => Error::Input {
                    location: path.display().to_string(),
                    message: "not a jdbb diagnosis after its upgrade to the current format".into(),
                },
            })?;
        for (k, e) in doc.effects.iter().enumerate() {
            if e.effect().is_none() {
                // The name as the file spells it (JSON escapes included) places the error.
                let spelled = serde_json::to_string(&e.name).expect("JSON of a string");
                let (line, column) = position_of_text(text, &spelled);
                return Err(Error::input(
                    path,
                    line,
                    column,
                    format!(
                        "effects[{k}]: unknown effect `{}`; was the file written by a newer jdbb?",
                        e.name
                    ),
                ));
            }
        }
        Ok(doc)
    }

    /// The one centre of the diagnosis: where the fitted set-up puts the table ball relative to
    /// where it was assumed, {x, y, z} µm (`setup_offset`'s parameters; None if the file has
    /// none). What the text says to move, what the plot removes.
    pub fn setup_um(&self) -> Option<[Option<f64>; 3]> {
        let e = self.effects.iter().find(|e| e.name == "setup_offset")?;
        let p = |k: &str| e.params.get(k).copied().flatten();
        Some([p("x_um"), p("y_um"), p("z_um")])
    }

    /// The machine effects in the order every output lists them: by share of G, then by
    /// mean-square share ([`crate::report::rank_order`]).
    pub fn ranked_machine_effects(&self) -> Vec<(&EffectDoc, Effect)> {
        let all: Vec<(&EffectDoc, Effect)> = self.machine_effects().collect();
        let keys: Vec<Option<(f64, f64)>> = all
            .iter()
            .map(|(e, _)| Some((e.g_share.unwrap_or(f64::NAN), e.share.unwrap_or(f64::NAN))))
            .collect();
        crate::report::rank_order(&keys)
            .into_iter()
            .map(|i| all[i])
            .collect()
    }

    /// The machine effects (not the set-up), in the file's order.
    pub fn machine_effects(&self) -> impl Iterator<Item = (&EffectDoc, Effect)> {
        self.effects
            .iter()
            .filter_map(|e| e.effect().map(|f| (e, f)))
            .filter(|(_, f)| !f.is_setup())
    }

    /// The pitch of `axis` the diagnosis was given, mm.
    pub fn pitch_mm(&self, axis: Axis) -> Option<f64> {
        self.pitch_mm
            .get(&axis.letter().to_string())
            .copied()
            .flatten()
    }

    /// The plane's axes (first, second) from `plane`, if known.
    pub fn plane_axes(&self) -> Option<(Axis, Axis)> {
        let p = self.plane.as_deref()?;
        let mut c = p.chars();
        let a = Axis::parse(&c.next()?.to_string())?;
        let b = Axis::parse(&c.next()?.to_string())?;
        Some((a, b))
    }

    /// The largest minimum-zone G of the file (its circles'), µm.
    pub fn g_um(&self) -> Option<f64> {
        self.minimum_zone
            .as_ref()
            .and_then(|z| z.g_um)
            .or_else(|| self.circles.iter().filter_map(|c| c.g_um).reduce(f64::max))
    }

    /// The largest H of the file, µm.
    pub fn h_um(&self) -> Option<f64> {
        self.minimum_zone
            .as_ref()
            .and_then(|z| z.h_um)
            .or(self.hysteresis_h_um)
    }
}

/// The keys a diagnosis of [`FORMAT`] has, object by object (`jdbb diagnose --json`); maps whose
/// keys are names (parameters, pitches, centres) and the kept `calibration`, `plan` and `sync`
/// are not checked inside. Err((where, key)) for the first key that does not belong.
fn known_keys(v: &serde_json::Value) -> std::result::Result<(), (String, String)> {
    use serde_json::Value;
    const TOP: &[&str] = &[
        "format",
        "samples",
        "baseline",
        "effects",
        "confounded",
        "floor_um",
        "below_floor",
        "not_significant",
        "final",
        "residual_share",
        "gain",
        "noise_tau_int",
        "radius_loss",
        "harmonics_um",
        "lsq_setup",
        "circular_deviation_g_um",
        "hysteresis_h_um",
        "g_if_compensated_um",
        "pitch_hint",
        "minimum_zone",
        "plane",
        "pitch_mm",
        "circles",
        "arcs",
        "weak_on_arc",
        "candidates",
        "machine",
        "date_utc",
        "date_of",
        "tolerance",
        "calibration",
        "calibration_file",
        "plan",
        "sync",
        "lsq_circular_deviation_g_um",
        "circular_deviation_g_filtered_um",
        "filter_upr",
        // The test's conditions (ISO 230-4) from `jdbb diagnose`'s options.
        "operator",
        "temperature_c",
        "table_ball_mm",
        "compensation",
        "instrument",
    ];
    const EFFECT: &[&str] = &[
        "name",
        "value",
        "unit",
        "sigma",
        "params",
        "params_sigma",
        "setup",
        "cause",
        "rms_after_um",
        "rms_ratio",
        "delta_bic",
        "contribution_rms_um",
        "share",
        "g_share",
        "g_without_um",
    ];
    const NOT_SIGNIFICANT: &[&str] = &["name", "value", "sigma", "unit", "params", "reason"];
    const FIGURES: &[&str] = &["rms_um", "pv_um", "g_um", "h_um"];
    const LSQ_SETUP: &[&str] = &["x_um", "y_um", "z_um", "e_um"];
    const CIRCLE: &[&str] = &[
        "radius_mm",
        "height_mm",
        "feed_mm_min",
        "samples",
        "g_um",
        "h_um",
        "ccw",
        "cw",
        "bidirectional",
        "radial_deviation_f",
        "g_filtered_um",
    ];
    const ZONE: &[&str] = &["g_um", "centre", "radius_offset_um"];
    const ARC: &[&str] = &["start_deg", "sweep_deg", "partial"];
    const WEAK: &[&str] = &["names", "free_fraction"];
    const TOLERANCE: &[&str] = &["g_um", "pass"];
    const DIRECTIONS: &[&str] = &["ccw", "cw"];
    const RANGE: &[&str] = &["max_um", "min_um"];
    fn keys(v: &Value, allowed: &[&str], place: &str) -> std::result::Result<(), (String, String)> {
        if let Value::Object(m) = v {
            if let Some(k) = m.keys().find(|k| !allowed.contains(&k.as_str())) {
                return Err((place.to_string(), k.clone()));
            }
        }
        Ok(())
    }
    let each = |name: &str, allowed: &[&str]| -> std::result::Result<(), (String, String)> {
        if let Some(Value::Array(items)) = v.get(name) {
            for (k, item) in items.iter().enumerate() {
                keys(item, allowed, &format!("{name}[{k}]"))?;
            }
        }
        Ok(())
    };
    keys(v, TOP, "the file")?;
    each("effects", EFFECT)?;
    each("not_significant", NOT_SIGNIFICANT)?;
    each("circles", CIRCLE)?;
    each("arcs", ARC)?;
    each("weak_on_arc", WEAK)?;
    for name in ["baseline", "final", "minimum_zone"] {
        if let Some(x) = v.get(name) {
            keys(x, FIGURES, name)?;
        }
    }
    if let Some(x) = v.get("lsq_setup") {
        keys(x, LSQ_SETUP, "lsq_setup")?;
    }
    if let Some(x) = v.get("tolerance") {
        keys(x, TOLERANCE, "tolerance")?;
    }
    for (name, allowed) in [
        ("temperature_c", &["machine", "instrument"][..]),
        ("table_ball_mm", &["x", "y", "z"][..]),
        ("compensation", &["text", "file"][..]),
        ("instrument", &["serial"][..]),
    ] {
        if let Some(x) = v.get(name) {
            keys(x, allowed, name)?;
        }
    }
    if let Some(Value::Array(circles)) = v.get("circles") {
        for (k, c) in circles.iter().enumerate() {
            for sense in ["ccw", "cw", "bidirectional"] {
                if let Some(z) = c.get(sense) {
                    keys(z, ZONE, &format!("circles[{k}].{sense}"))?;
                }
            }
            if let Some(g) = c.get("g_filtered_um") {
                keys(g, DIRECTIONS, &format!("circles[{k}].g_filtered_um"))?;
            }
            if let Some(f) = c.get("radial_deviation_f") {
                let place = format!("circles[{k}].radial_deviation_f");
                keys(f, DIRECTIONS, &place)?;
                for sense in DIRECTIONS {
                    if let Some(r) = f.get(sense) {
                        keys(r, RANGE, &format!("{place}.{sense}"))?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// Line and column (1-based) of the first `"key"` in `text`; (1, 1) if not found.
fn position_of_key(text: &str, key: &str) -> (usize, usize) {
    position_of_text(text, &format!("\"{key}\""))
}

/// Line and column (1-based) of the first `needle` in `text`; (1, 1) if it is not there.
fn position_of_text(text: &str, needle: &str) -> (usize, usize) {
    match text.find(needle) {
        Some(at) => {
            let before = &text[..at];
            let line = before.matches('\n').count() + 1;
            let column = at - before.rfind('\n').map_or(0, |n| n + 1) + 1;
            (line, column)
        }
        None => (1, 1),
    }
}

/// The text of a diagnosis file brought to [`FORMAT`] ([`upgrade`], pretty-printed as
/// `jdbb diagnose` writes it); None if it is already current or is not JSON.
pub fn upgraded_text(text: &str) -> Option<String> {
    let mut v: serde_json::Value = serde_json::from_str(text).ok()?;
    upgrade(&mut v).then(|| serde_json::to_string_pretty(&v).expect("JSON of plain values"))
}

/// Bring the JSON of a diagnosis file to [`FORMAT`] in place (see the module docs); returns
/// whether it changed. A file of the current format is left as it is. From format 1:
/// - `backlash_k`: value and parameter negated (positive = lost motion), `f_um` renamed `b_um`;
/// - `setup_offset` parameters and `lsq_setup` x, y, z negated (where the table ball is), and each
///   zone centre made the table-ball position of that zone (−(c + zone centre));
/// - `circular_deviation_g_um` becomes the minimum zone's (`minimum_zone.g_um`, null without
///   it), the least-squares G kept as `lsq_circular_deviation_g_um`; `hysteresis_h_um` the
///   minimum zone's where the file has it;
/// - shares recomputed from `contribution_rms_um` and `final.rms_um` so they add up to 1;
/// - causes rewritten in the current words ([`words::cause`]).
pub fn upgrade(v: &mut serde_json::Value) -> bool {
    use serde_json::{json, Value};
    let format = v.get("format").and_then(Value::as_u64).unwrap_or(1);
    if format >= u64::from(FORMAT) || !v.is_object() {
        return false;
    }
    let neg = |x: &mut Value| {
        if let Some(f) = x.as_f64() {
            *x = json!(-f);
        }
    };
    let old_lsq: Vec<Option<f64>> = ["x_um", "y_um", "z_um"]
        .iter()
        .map(|k| v["lsq_setup"].get(*k).and_then(Value::as_f64))
        .collect();
    if let Some(effects) = v.get_mut("effects").and_then(Value::as_array_mut) {
        for e in effects.iter_mut() {
            let Some(effect) = e
                .get("name")
                .and_then(Value::as_str)
                .and_then(Effect::parse)
            else {
                continue;
            };
            match effect {
                Effect::Backlash(_) => {
                    neg(&mut e["value"]);
                    for key in ["params", "params_sigma"] {
                        if let Some(m) = e.get_mut(key).and_then(Value::as_object_mut) {
                            if let Some(mut f) = m.remove("f_um") {
                                if key == "params" {
                                    neg(&mut f);
                                }
                                m.insert("b_um".into(), f);
                            }
                        }
                    }
                }
                Effect::SetupOffset => {
                    if let Some(m) = e.get_mut("params").and_then(Value::as_object_mut) {
                        for k in ["x_um", "y_um", "z_um"] {
                            if let Some(x) = m.get_mut(k) {
                                neg(x);
                            }
                        }
                    }
                }
                _ => {}
            }
            if e.get("cause").is_some() {
                let value = e["value"].as_f64().unwrap_or(0.0);
                e["cause"] = json!(words::cause(effect, value));
            }
        }
    }
    if let Some(m) = v.get_mut("lsq_setup").and_then(Value::as_object_mut) {
        for k in ["x_um", "y_um", "z_um"] {
            if let Some(x) = m.get_mut(k) {
                neg(x);
            }
        }
    }
    if let Some(circles) = v.get_mut("circles").and_then(Value::as_array_mut) {
        for c in circles.iter_mut() {
            for dir in ["ccw", "cw", "bidirectional"] {
                if let Some(centre) = c
                    .get_mut(dir)
                    .and_then(|z| z.get_mut("centre"))
                    .and_then(Value::as_object_mut)
                {
                    for (k, x) in centre.iter_mut() {
                        let axis = ["x_um", "y_um", "z_um"].iter().position(|a| a == k);
                        let c0 = axis.and_then(|a| old_lsq[a]).unwrap_or(0.0);
                        if let Some(z) = x.as_f64() {
                            *x = json!(-(c0 + z));
                        }
                    }
                }
            }
        }
    }
    // Format 1's G was taken about the least-squares centre: kept under its own name, and the
    // test's G is the minimum zone's (null where the file has none). H did not depend on the
    // centre (the same 1° bins), so it stays unless the file has the minimum zone's.
    if let Some(g) = v.get("circular_deviation_g_um").cloned() {
        if !g.is_null() {
            v["lsq_circular_deviation_g_um"] = g;
        }
        v["circular_deviation_g_um"] = v["minimum_zone"]["g_um"].clone();
    }
    if let Some(h) = v.get("minimum_zone").and_then(|z| z.get("h_um")).cloned() {
        v["hysteresis_h_um"] = h;
    }
    let rms = v["final"]["rms_um"].as_f64();
    if let (Some(rms), Some(effects)) = (rms, v.get_mut("effects").and_then(Value::as_array_mut)) {
        let contrib: Vec<Option<f64>> = effects
            .iter()
            .map(|e| e.get("contribution_rms_um").and_then(Value::as_f64))
            .collect();
        if contrib.iter().any(Option::is_some) {
            let total = rms * rms + contrib.iter().flatten().map(|c| c * c).sum::<f64>();
            if total > 0.0 {
                for (e, c) in effects.iter_mut().zip(&contrib) {
                    if let Some(c) = c {
                        e["share"] = json!(c * c / total);
                    }
                }
                v["residual_share"] = json!(rms * rms / total);
            }
        }
    }
    v["format"] = json!(FORMAT);
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_first_version_file_reads_and_bad_json_names_line_and_column() {
        // The shape of issue 3's JSON, without any issue 10 field.
        let old = r#"{"samples": 100, "baseline": {"rms_um": 1, "pv_um": 2},
          "effects": [{"name": "setup_offset", "value": 1, "unit": "um", "sigma": 0.1,
             "params": {"x_um": 1, "y_um": 0, "z_um": null}, "setup": true},
            {"name": "backlash_x", "value": -6, "unit": "um", "sigma": 0.01,
             "params": {"f_um": -6}}],
          "confounded": [], "final": {"rms_um": 0.3}, "gain": 3}"#;
        let d = DiagnosisDoc::parse(FsPath::new("d.json"), old).unwrap();
        let eff: Vec<_> = d.machine_effects().collect();
        assert_eq!(eff.len(), 1);
        // Version 1 signs: f = −6 µm was lost motion; today that is b = +6 µm (play).
        assert_eq!(eff[0].1, Effect::Backlash(Axis::X));
        // Format 1's −6 (the axis lagging: lost motion) is +6 in today's sign.
        assert_eq!(eff[0].0.value, Some(6.0));
        assert_eq!(eff[0].0.params.get("b_um"), Some(&Some(6.0)));
        assert!(eff[0].0.significant(3.0));
        assert_eq!(d.format, Some(FORMAT));
        assert_eq!(d.effects[0].params.get("x_um"), Some(&Some(-1.0)));
        assert!(d.circles.is_empty() && d.machine.is_none() && d.g_um().is_none());

        // A misspelled key in a file of this format is named, with its place.
        let typo = format!(
            "{{\"format\": {FORMAT}, \"samples\": 100,\n  \"effects\": [{{\"name\": \"drift\", \"vaule\": 1}}]}}"
        );
        let e = DiagnosisDoc::parse(FsPath::new("d.json"), &typo).unwrap_err();
        assert!(
            e.to_string().starts_with("d.json:2:")
                && e.to_string().contains("effects[0]: unknown key `vaule`"),
            "{e}"
        );
        assert_eq!(e.exit_code(), 2);

        let bad = "{\"samples\": 100,\n  \"effects\": [1, }";
        let e = DiagnosisDoc::parse(FsPath::new("d.json"), bad).unwrap_err();
        assert!(e.to_string().starts_with("d.json:2:"), "{e}");
        assert_eq!(e.exit_code(), 2);
        let newer = r#"{"format": 99, "samples": 1, "effects": []}"#;
        let e = DiagnosisDoc::parse(FsPath::new("d.json"), newer).unwrap_err();
        assert!(e.to_string().contains("newer jdbb"), "{e}");
        let unknown = r#"{"samples": 1, "effects": [{"name": "warp_x", "value": 1, "sigma": 1}]}"#;
        let e = DiagnosisDoc::parse(FsPath::new("d.json"), unknown).unwrap_err();
        assert!(e.to_string().contains("unknown effect `warp_x`"), "{e}");
    }

    #[test]
    fn a_format_1_file_keeps_its_meaning_and_a_current_one_is_left_alone() {
        // Format 1 (issue 10): backlash_x −8 (lost motion then), centring c = (12, −7) so the
        // table ball at (−12, 7); the ccw zone centre 0.5 µm along x from the least-squares
        // centre in the plot; G about the least-squares centre 9.1 µm, minimum zone 8.8 µm;
        // shares 0.8 and 0.3 (adding to 1.1).
        let old = serde_json::json!({
            "samples": 100,
            "effects": [
                {"name": "setup_offset", "value": 13.9, "sigma": 0.01, "setup": true,
                 "params": {"x_um": 12.0, "y_um": -7.0, "z_um": 0.0}, "cause": "seed 000"},
                {"name": "backlash_x", "value": -8.0, "sigma": 0.01, "unit": "um",
                 "params": {"f_um": -8.0}, "params_sigma": {"f_um": 0.01},
                 "cause": "X axis backlash (opposite clearance): lost motion at reversal (seed 000 eq. 14)",
                 "contribution_rms_um": 4.0, "share": 0.8},
                {"name": "squareness_xy", "value": 25.0, "sigma": 0.05, "unit": "um/m",
                 "params": {"s_um_per_m": 25.0}, "contribution_rms_um": 2.0, "share": 0.3}
            ],
            "final": {"rms_um": 1.0},
            "lsq_setup": {"x_um": 12.0, "y_um": -7.0, "z_um": 0.0, "e_um": 0.1},
            "circular_deviation_g_um": 9.1, "hysteresis_h_um": 6.0,
            "plane": "xy",
            "circles": [{"radius_mm": 90.0, "g_um": 8.8, "h_um": 6.0,
                "ccw": {"g_um": 8.8, "centre": {"x_um": 0.5, "y_um": 0.0}}, "cw": null}],
            "minimum_zone": {"g_um": 8.8, "h_um": 6.0}
        });
        let mut v = old.clone();
        assert!(upgrade(&mut v));
        assert_eq!(v["format"], FORMAT);
        let b = &v["effects"][1];
        assert_eq!(
            (b["value"].as_f64(), b["params"]["b_um"].as_f64()),
            (Some(8.0), Some(8.0))
        );
        assert!(b["params"].get("f_um").is_none());
        assert_eq!(b["params_sigma"]["b_um"].as_f64(), Some(0.01));
        assert!(b["cause"]
            .as_str()
            .unwrap()
            .starts_with("X: lost motion (play)"));
        assert!(!v["effects"][0]["cause"].as_str().unwrap().contains("seed"));
        let s = &v["effects"][0]["params"];
        assert_eq!(
            (s["x_um"].as_f64(), s["y_um"].as_f64()),
            (Some(-12.0), Some(7.0))
        );
        assert_eq!(v["lsq_setup"]["x_um"].as_f64(), Some(-12.0));
        assert_eq!(v["lsq_setup"]["e_um"].as_f64(), Some(0.1));
        // The zone's table-ball position: −(12 + 0.5) along x, −(−7 + 0) along y.
        let c = &v["circles"][0]["ccw"]["centre"];
        assert_eq!(
            (c["x_um"].as_f64(), c["y_um"].as_f64()),
            (Some(-12.5), Some(7.0))
        );
        assert_eq!(v["circular_deviation_g_um"].as_f64(), Some(8.8));
        assert_eq!(v["lsq_circular_deviation_g_um"].as_f64(), Some(9.1));
        // Shares: 16 and 4 of 16 + 4 + 1 µm².
        let share = |k: usize| v["effects"][k]["share"].as_f64().unwrap();
        assert!((share(1) - 16.0 / 21.0).abs() < 1e-12);
        assert!((share(2) - 4.0 / 21.0).abs() < 1e-12);
        assert!((share(1) + share(2) + v["residual_share"].as_f64().unwrap() - 1.0).abs() < 1e-12);
        // Once upgraded, nothing changes again.
        let again = v.clone();
        assert!(!upgrade(&mut v));
        assert_eq!(v, again);
        // What the reader makes of the old text is the upgraded file.
        let d = DiagnosisDoc::parse(FsPath::new("d.json"), &old.to_string()).unwrap();
        assert_eq!(d.effects[1].value, Some(8.0));
        assert_eq!(d.g_um(), Some(8.8));
    }
}
