//! A machine profile (`--machine-profile FILE|NAME`): what a machine's ball bar test needs,
//! written once in a commented TOML file, so that nothing is typed again at every test. `plan`,
//! `diagnose`, `compensate` and `history` take its values where their own flags are not given (an
//! explicit flag overrides the profile). A NAME (no `/`, no `.toml`) is the file `NAME.toml` in
//! the machines directory ([`machines_dirs`]).
//!
//! The table ball's position is in machine coordinates (G53): it stays true whatever work offset
//! a job leaves in force, and the travel is in machine coordinates too. A circle cannot be
//! programmed in G53 (it is one-shot, for straight moves only, on Fanuc, SINUMERIK and LinuxCNC),
//! so the test program runs in a work coordinate system; `work_offset_mm` is the machine position
//! of that system's zero (the G54…G59 the shop keeps for the test, default 0: program coordinates
//! are machine coordinates). `plan` puts the table ball at `table_ball_mm − work_offset_mm` in the
//! program's coordinates and checks the plan against `travel_mm − work_offset_mm`
//! (`docs/controllers.md`, "The machine profile").
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
    /// The machine coordinates (G53) of the zero of the work coordinate system the test program
    /// runs in, mm (an axis not given: 0).
    #[serde(default)]
    pub work_offset_mm: BTreeMap<String, f64>,
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
        for (k, v) in p
            .pitch_mm
            .iter()
            .chain(&p.table_ball_mm)
            .chain(&p.work_offset_mm)
        {
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
        if let Some(f) = p
            .feeds_mm_min
            .iter()
            .find(|f| !(f.is_finite() && **f > 0.0))
        {
            return Err(bad(format!(
                "feeds_mm_min: {f} is not a feed; give feeds > 0 in mm/min"
            )));
        }
        if let Some(t) = p.tolerance_um.filter(|t| !(t.is_finite() && *t > 0.0)) {
            return Err(bad(format!(
                "tolerance_um = {t}: give a tolerance > 0 in µm"
            )));
        }
        Ok(p)
    }

    /// The profile `arg` of `--machine-profile` names: a file if one is there, else a NAME
    /// (no `/`, no `.toml`) found as `NAME.toml` in the machines directory; what is neither is a
    /// usage error that says where it looked and which names are there.
    pub fn find(arg: &Path) -> Result<MachineProfile> {
        MachineProfile::read(&find_in(arg, &machines_dirs())?)
    }

    /// The work coordinate system's zero on axis `a` (0 x, 1 y, 2 z), machine coordinates, mm.
    pub fn work_offset(&self, a: usize) -> f64 {
        self.work_offset_mm.get(AXES[a]).copied().unwrap_or(0.0)
    }

    /// The table ball's centre in the program's coordinates (`plan --centre`), mm: the machine
    /// position less the work offset; `None` when the profile gives no table ball, an error when
    /// it gives only some axes.
    pub fn centre_mm(&self) -> Result<Option<[f64; 3]>> {
        if self.table_ball_mm.is_empty() {
            return Ok(None);
        }
        let mut c = [0.0; 3];
        for (a, c) in c.iter_mut().enumerate() {
            let m = self.table_ball_mm.get(AXES[a]).ok_or_else(|| {
                Error::Usage(format!(
                    "the machine profile's table_ball_mm has no {}: give x, y and z there, or --centre X,Y,Z",
                    AXES[a]
                ))
            })?;
            *c = m - self.work_offset(a);
        }
        Ok(Some(c))
    }

    /// The travel in the program's coordinates (`plan --travel`): machine travel less the work
    /// offset, per axis, mm.
    pub fn travel_program_mm(&self) -> [Option<(f64, f64)>; 3] {
        std::array::from_fn(|a| {
            self.travel_mm
                .get(AXES[a])
                .map(|[lo, hi]| (lo - self.work_offset(a), hi - self.work_offset(a)))
        })
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

/// The profiles' axis names, in the order of the axis indices.
const AXES: [&str; 3] = ["x", "y", "z"];

/// Where a profile NAME is looked for: `$JDBB_MACHINES` if set, else `jdbb/machines` in the
/// configuration directory (`$XDG_CONFIG_HOME`, else `~/.config`, on Linux).
pub fn machines_dirs() -> Vec<std::path::PathBuf> {
    match std::env::var_os("JDBB_MACHINES") {
        Some(d) => vec![d.into()],
        None => dirs::config_dir()
            .map(|c| c.join("jdbb").join("machines"))
            .into_iter()
            .collect(),
    }
}

/// The file `arg` names: itself if it is a file or looks like a path; else `NAME.toml` in the
/// first of `dirs` that holds it.
fn find_in(arg: &Path, dirs: &[std::path::PathBuf]) -> Result<std::path::PathBuf> {
    let text = arg.to_string_lossy();
    let is_name = !arg.is_file()
        && !text.is_empty()
        && !text.contains(['/', std::path::MAIN_SEPARATOR])
        && arg.extension().is_none_or(|e| e != "toml");
    if !is_name {
        return Ok(arg.to_path_buf());
    }
    let file = format!("{text}.toml");
    if let Some(found) = dirs.iter().map(|d| d.join(&file)).find(|p| p.is_file()) {
        return Ok(found);
    }
    let mut names: Vec<String> = dirs
        .iter()
        .filter_map(|d| std::fs::read_dir(d).ok())
        .flatten()
        .filter_map(|e| {
            let p = e.ok()?.path();
            if p.extension()? != "toml" {
                return None;
            }
            Some(p.file_stem()?.to_string_lossy().into_owned())
        })
        .collect();
    names.sort();
    let looked: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
    Err(Error::Usage(format!(
        "--machine-profile `{text}`: no file {text} here and no {file} in {} ($JDBB_MACHINES, else jdbb/machines in the configuration directory); {}",
        if looked.is_empty() { "a machines directory (none found)".to_string() } else { looked.join(", ") },
        if names.is_empty() {
            "no machine profiles are there: write one (README, \"A machine profile\") or give its file".to_string()
        } else {
            format!("the machines there are: {}", names.join(", "))
        }
    )))
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

    #[test]
    fn the_table_ball_and_travel_move_into_the_programs_coordinates_by_the_work_offset() {
        let mut p = MachineProfile::parse(Path::new("m.toml"), EXAMPLE).unwrap();
        assert_eq!(p.centre_mm().unwrap(), Some([250.0, 120.0, -300.0]));
        p.work_offset_mm = [("x".into(), 200.0), ("z".into(), -350.0)].into();
        assert_eq!(p.centre_mm().unwrap(), Some([50.0, 120.0, 50.0]));
        assert_eq!(
            p.travel_program_mm(),
            [Some((-200.0, 400.0)), Some((0.0, 400.0)), None]
        );
        p.table_ball_mm.remove("z");
        let e = p.centre_mm().unwrap_err();
        assert!(e.to_string().contains("no z"), "{e}");
    }

    #[test]
    fn a_name_is_found_in_the_machines_directory_and_a_missing_one_lists_what_is_there() {
        let dir = std::env::temp_dir().join(format!("jdbb-machines-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("mill-1.toml"), EXAMPLE).unwrap();
        std::fs::write(dir.join("lathe.toml"), "machine = \"lathe\"\n").unwrap();
        let dirs = [dir.clone()];
        assert_eq!(
            find_in(Path::new("mill-1"), &dirs).unwrap(),
            dir.join("mill-1.toml")
        );
        // A path is a path, never looked up.
        assert_eq!(
            find_in(Path::new("./mill-1"), &dirs).unwrap(),
            Path::new("./mill-1")
        );
        assert_eq!(
            find_in(Path::new("mill-1.toml"), &dirs).unwrap(),
            Path::new("mill-1.toml")
        );
        let e = find_in(Path::new("mill-2"), &dirs).unwrap_err().to_string();
        assert!(e.contains(&dir.display().to_string()), "{e}");
        assert!(e.contains("lathe, mill-1"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
