//! A machine profile (`--machine-profile FILE`): what a machine's ball bar test needs, written
//! once in a commented TOML file, so that nothing is typed again at every test. `compensate` and
//! `diagnose` take its values where their own flags are not given (an explicit flag overrides the
//! profile); `plan` and `history` accept the flag.
//!
//! ```toml
#![doc = include_str!("profile_example.toml")]
//! ```
use std::collections::BTreeMap;
use std::path::Path;

use serde::Deserialize;

use crate::{Error, Result};

/// The example profile (the README shows it).
pub const EXAMPLE: &str = include_str!("profile_example.toml");

/// One machine's test set-up.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineProfile {
    /// The machine's name (as `history --machine` and `diagnose --machine` give it).
    pub machine: Option<String>,
    /// The controller, as `compensate --controller` names it.
    pub controller: Option<String>,
    /// The controller's version, for people (e.g. `0i-F`, `840D sl SW 4.95`, `iTNC 530`).
    pub controller_version: Option<String>,
    /// The control's machine units: `mm` or `inch`.
    pub units: Option<String>,
    /// Fanuc's increment system: `IS-B` or `IS-C`.
    pub increment_system: Option<String>,
    /// Screw (or scale) pitch per axis, mm.
    #[serde(default)]
    pub pitch_mm: BTreeMap<String, f64>,
    /// The table ball's machine coordinates (G53), mm.
    #[serde(default)]
    pub table_ball_mm: BTreeMap<String, f64>,
    /// Each axis' travel `[min, max]`, machine coordinates, mm.
    #[serde(default)]
    pub travel_mm: BTreeMap<String, [f64; 2]>,
    /// The circular-deviation tolerance G, µm.
    pub tolerance_um: Option<f64>,
    /// The test feeds, mm/min.
    #[serde(default)]
    pub feeds_mm_min: Vec<f64>,
}

impl MachineProfile {
    /// Read a profile; a field that is not one, or a value of the wrong kind, is an error at its
    /// line and column.
    pub fn read(path: &Path) -> Result<MachineProfile> {
        let text = crate::table::read_text(path)?;
        MachineProfile::parse(path, &text)
    }

    /// [`MachineProfile::read`] on text in memory; `path` names it in errors.
    pub fn parse(path: &Path, text: &str) -> Result<MachineProfile> {
        let p: MachineProfile = toml::from_str(text).map_err(|e| {
            let (line, col) = e
                .span()
                .map_or((1, 0), |s| crate::table::line_col(text, s.start));
            Error::input(
                path,
                line,
                col,
                format!(
                    "{}; a machine profile is TOML with the fields of the README's example (section 5)",
                    e.message().trim_end()
                ),
            )
        })?;
        let bad = |what: String| Error::input(path, 1, 0, what);
        for (k, v) in p.pitch_mm.iter().chain(&p.table_ball_mm) {
            if !matches!(k.as_str(), "x" | "y" | "z") || !v.is_finite() {
                return Err(bad(format!(
                    "`{k} = {v}`: axes are x, y, z with a finite value in mm"
                )));
            }
        }
        for (k, [lo, hi]) in &p.travel_mm {
            if !matches!(k.as_str(), "x" | "y" | "z")
                || lo.partial_cmp(hi) != Some(std::cmp::Ordering::Less)
            {
                return Err(bad(format!(
                    "travel_mm.{k} = [{lo}, {hi}]: an axis x, y, z with [min, max], min < max (mm)"
                )));
            }
        }
        if let Some(u) = &p.units {
            if u != "mm" && u != "inch" {
                return Err(bad(format!("units = \"{u}\": mm or inch")));
            }
        }
        if let Some(i) = &p.increment_system {
            if i != "IS-B" && i != "IS-C" {
                return Err(bad(format!("increment_system = \"{i}\": IS-B or IS-C")));
            }
        }
        Ok(p)
    }

    /// A per-axis map as the command line writes it (`x=10,y=5`), if any.
    fn per_axis_text(map: &BTreeMap<String, f64>) -> Option<String> {
        (!map.is_empty()).then(|| {
            map.iter()
                .map(|(k, v)| format!("{k}={v}"))
                .collect::<Vec<_>>()
                .join(",")
        })
    }

    /// `--pitch` as the profile gives it.
    pub fn pitch_arg(&self) -> Option<String> {
        Self::per_axis_text(&self.pitch_mm)
    }

    /// `--table-ball` as the profile gives it.
    pub fn table_ball_arg(&self) -> Option<String> {
        Self::per_axis_text(&self.table_ball_mm)
    }

    /// `--travel` as the profile gives it.
    pub fn travel_arg(&self) -> Option<String> {
        (!self.travel_mm.is_empty()).then(|| {
            self.travel_mm
                .iter()
                .map(|(k, [lo, hi])| format!("{k}={lo}:{hi}"))
                .collect::<Vec<_>>()
                .join(",")
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_example_reads_and_becomes_the_flags() {
        let p = MachineProfile::parse(Path::new("m.toml"), EXAMPLE).unwrap();
        assert_eq!(p.controller.as_deref(), Some("fanuc"));
        assert_eq!(p.pitch_arg().as_deref(), Some("x=10,y=10,z=5"));
        assert_eq!(p.table_ball_arg().as_deref(), Some("x=250,y=120,z=-300"));
        assert_eq!(p.travel_arg().as_deref(), Some("x=0:600,y=0:400"));
        assert_eq!(p.tolerance_um, Some(10.0));
        let e = MachineProfile::parse(Path::new("m.toml"), "machine = \"a\"\ntolerence_um = 3\n")
            .unwrap_err();
        assert!(e.to_string().starts_with("m.toml:2:1:"), "{e}");
        assert_eq!(e.exit_code(), 2);
        let e = MachineProfile::parse(Path::new("m.toml"), "units = \"furlong\"\n").unwrap_err();
        assert!(e.to_string().contains("mm or inch"), "{e}");
    }
}
