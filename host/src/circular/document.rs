//! A diagnosis as a file: the JSON that `jdbb diagnose --json` prints and `--report DIR` writes
//! (documented in [`super::report`]), read back into types. It is the input contract of
//! `jdbb compensate` and `jdbb history`: they never rerun a diagnosis.
//!
//! Every field added after the first version is optional here, so an older file still reads;
//! fields this reader does not know are ignored, so a newer file does too. A malformed file is
//! an input error at `file:line:column` (serde_json's position).
use std::collections::BTreeMap;
use std::path::Path as FsPath;

use serde::Deserialize;

use super::model::{Axis, Effect};
use crate::{Error, Result};

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
}

impl EffectDoc {
    /// The effect this entry names, if it is one this version knows.
    pub fn effect(&self) -> Option<Effect> {
        Effect::parse(&self.name)
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

/// A diagnosis file (see the module docs and [`super::report`] for the fields).
#[derive(Debug, Clone, Deserialize)]
pub struct DiagnosisDoc {
    pub samples: usize,
    #[serde(default)]
    pub baseline: Figures,
    pub effects: Vec<EffectDoc>,
    #[serde(default)]
    pub confounded: Vec<Vec<String>>,
    #[serde(rename = "final", default)]
    pub final_fit: Figures,
    pub gain: Option<f64>,
    pub circular_deviation_g_um: Option<f64>,
    pub hysteresis_h_um: Option<f64>,
    #[serde(default)]
    pub plane: Option<String>,
    #[serde(default)]
    pub pitch_mm: BTreeMap<String, Option<f64>>,
    #[serde(default)]
    pub circles: Vec<CircleDoc>,
    #[serde(default)]
    pub minimum_zone: Option<Figures>,
    #[serde(default)]
    pub machine: Option<String>,
    #[serde(default)]
    pub date_utc: Option<String>,
    #[serde(default)]
    pub tolerance: Option<ToleranceDoc>,
    /// The instrument calibration, kept as given (compared as a whole between runs).
    #[serde(default)]
    pub calibration: Option<serde_json::Value>,
    /// The test plan, kept as given (compared as a whole between runs).
    #[serde(default)]
    pub plan: Option<serde_json::Value>,
}

impl DiagnosisDoc {
    /// Read a diagnosis file; a missing file or malformed JSON is an input error (exit 2), with
    /// `file:line:column` for the latter.
    pub fn read(path: &FsPath) -> Result<(DiagnosisDoc, String)> {
        let text = crate::table::read_text(path)?;
        let doc = Self::parse(path, &text)?;
        Ok((doc, text))
    }

    /// Parse the text of a diagnosis file named `path` (for messages).
    pub fn parse(path: &FsPath, text: &str) -> Result<DiagnosisDoc> {
        let doc: DiagnosisDoc = serde_json::from_str(text).map_err(|e| {
            Error::input(
                path,
                e.line(),
                e.column(),
                format!(
                    "not a jdbb diagnosis ({e}); give the diagnosis.json of `jdbb diagnose --report DIR` or the output of `jdbb diagnose --json`"
                ),
            )
        })?;
        for (k, e) in doc.effects.iter().enumerate() {
            if e.effect().is_none() {
                return Err(Error::Input {
                    location: path.display().to_string(),
                    message: format!(
                        "effects[{k}]: unknown effect `{}`; was the file written by a newer jdbb?",
                        e.name
                    ),
                });
            }
        }
        Ok(doc)
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
        assert_eq!(eff[0].1, Effect::Backlash(Axis::X));
        assert_eq!(eff[0].0.param_values(eff[0].1), vec![-6.0]);
        assert!(eff[0].0.significant(3.0));
        assert!(d.circles.is_empty() && d.machine.is_none() && d.g_um().is_none());

        let bad = "{\"samples\": 100,\n  \"effects\": [1, }";
        let e = DiagnosisDoc::parse(FsPath::new("d.json"), bad).unwrap_err();
        assert!(e.to_string().starts_with("d.json:2:"), "{e}");
        assert_eq!(e.exit_code(), 2);
        let unknown = r#"{"samples": 1, "effects": [{"name": "warp_x", "value": 1, "sigma": 1}]}"#;
        let e = DiagnosisDoc::parse(FsPath::new("d.json"), unknown).unwrap_err();
        assert!(e.to_string().contains("unknown effect `warp_x`"), "{e}");
    }
}
