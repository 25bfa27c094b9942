//! Files of the RRSPS commands: parameter sets (TOML `name = value` or CSV with the eight names as
//! columns, like `rrsps_parameters_table2_3.csv`) and samples (CSV `theta_a_deg,theta_c_deg,d_mm`).
//! Every malformed input is reported as `file:line:column: what to do`.
use std::path::{Path, PathBuf};

use super::{Params, PARAM_NAMES};
use crate::table::{read_text, Table};
use crate::{Error, Result};

/// Read a parameter set. `.toml` files hold `s0_mm = 96.31` lines (all eight names, nothing
/// else); other files are CSV with a header naming the eight columns (extra columns such as
/// `case` and `note` are ignored). A CSV with several rows needs `case` to pick one by its
/// `case` column.
pub fn read_params(path: &Path, case: Option<&str>) -> Result<Params> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
    {
        parse_params_toml(path, &read_text(path)?)
    } else {
        params_from(Table::open_with(path, crate::fsio::Limit::Table)?, case)
    }
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ParamsToml {
    s0_mm: f64,
    a0_mm: f64,
    theta_a0_deg: f64,
    s2_mm: f64,
    a2_mm: f64,
    theta_c0_deg: f64,
    a1_mm: f64,
    alpha12_deg: f64,
}

fn parse_params_toml(path: &Path, text: &str) -> Result<Params> {
    let t: ParamsToml = toml::from_str(text).map_err(|e| {
        let (line, col) = e
            .span()
            .map_or((1, 0), |s| crate::table::line_col(text, s.start));
        Error::input(
            path,
            line,
            col,
            format!(
                "{}; a parameter file needs exactly these numbers: {}",
                e.message(),
                PARAM_NAMES.join(", ")
            ),
        )
    })?;
    let v = [
        t.s0_mm,
        t.a0_mm,
        t.theta_a0_deg,
        t.s2_mm,
        t.a2_mm,
        t.theta_c0_deg,
        t.a1_mm,
        t.alpha12_deg,
    ];
    if let Some(k) = v.iter().position(|x| !x.is_finite()) {
        return Err(Error::input(
            path,
            1,
            0,
            format!("{} is not a finite number", PARAM_NAMES[k]),
        ));
    }
    Ok(Params::from_named_units(&v))
}

#[cfg(test)]
fn parse_params_csv(path: &Path, text: &str, case: Option<&str>) -> Result<Params> {
    params_from(Table::from_text(path, text)?, case)
}

fn params_from(mut t: Table, case: Option<&str>) -> Result<Params> {
    let path = t.path().to_path_buf();
    let cols = t.require(&PARAM_NAMES)?;
    let case_col = t.optional("case");
    if case.is_some() && case_col.is_none() {
        return Err(Error::Usage(format!(
            "{}: --case given but the file has no `case` column",
            path.display()
        )));
    }
    // Keep the rows' numbers (or their errors) with their case names; only the chosen row's
    // errors matter.
    let mut rows: Vec<(String, usize, Result<[f64; 8]>)> = vec![];
    while let Some(row) = t.next_row()? {
        let name = match &case_col {
            Some(c) => row.text(c).unwrap_or("").to_string(),
            None => String::new(),
        };
        let values = (|| {
            let mut v = [0.0; 8];
            for (k, c) in cols.iter().enumerate() {
                v[k] = row.number(c)?;
            }
            Ok(v)
        })();
        rows.push((name, row.line(), values));
    }
    let cases = || {
        rows.iter()
            .map(|r| r.0.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let chosen = match case {
        Some(name) => rows.iter().position(|r| r.0 == name).ok_or_else(|| {
            Error::Usage(format!(
                "{}: no case `{name}`; the file has: {}",
                path.display(),
                cases()
            ))
        })?,
        None if rows.len() == 1 => 0,
        None if !rows.is_empty() && case_col.is_some() => {
            return Err(Error::Usage(format!(
                "{} holds {} parameter sets; pick one with --case ({})",
                path.display(),
                rows.len(),
                cases()
            )))
        }
        None => {
            return Err(Error::input(
                &path,
                t.header_line() + 1,
                0,
                format!(
                    "expected exactly one row of parameters, found {}",
                    rows.len()
                ),
            ))
        }
    };
    let v = rows.swap_remove(chosen).2?;
    Ok(Params::from_named_units(&v))
}

/// Write a parameter set as TOML (the format [`read_params`] reads back).
pub fn params_toml(p: &Params) -> String {
    let v = p.to_named_units();
    PARAM_NAMES
        .iter()
        .zip(v)
        .map(|(n, x)| format!("{n} = {x}\n"))
        .collect()
}

/// One DBB test: machine angles and measured bar lengths.
#[derive(Debug, Clone)]
pub struct Samples {
    pub path: PathBuf,
    pub theta_a_rad: Vec<f64>,
    pub theta_c_rad: Vec<f64>,
    pub d_mm: Vec<f64>,
}

/// The columns of a samples file.
pub const SAMPLE_COLUMNS: [&str; 3] = ["theta_a_deg", "theta_c_deg", "d_mm"];

/// Read a samples CSV (`theta_a_deg,theta_c_deg,d_mm`, any column order, other columns ignored)
/// and check that it can identify `n_params` parameters: enough distinct positions, and both
/// axes moving. Bar lengths must be positive and below [`MAX_BAR_MM`].
pub fn read_samples(path: &Path, n_params: usize) -> Result<Samples> {
    samples_from(Table::open_with(path, crate::fsio::Limit::Table)?, n_params)
}

/// [`read_samples`] on text already read.
pub fn parse_samples(path: &Path, text: &str, n_params: usize) -> Result<Samples> {
    samples_from(Table::from_text(path, text)?, n_params)
}

/// Longest bar length (mm) a samples file may hold: ten metres, far beyond any ball bar.
pub const MAX_BAR_MM: f64 = 10_000.0;

fn samples_from(mut t: Table, n_params: usize) -> Result<Samples> {
    let path = t.path().to_path_buf();
    let cols = t.require(&SAMPLE_COLUMNS)?;
    let mut s = Samples {
        path: path.clone(),
        theta_a_rad: Vec::new(),
        theta_c_rad: Vec::new(),
        d_mm: Vec::new(),
    };
    while let Some(row) = t.next_row()? {
        let mut v = [0.0; 3];
        for (k, c) in cols.iter().enumerate() {
            v[k] = row.number(c)?;
        }
        if !(v[2] > 0.0 && v[2] < MAX_BAR_MM) {
            return Err(row.error(
                &cols[2],
                format!(
                    "d_mm = {} must be a bar length between 0 and {MAX_BAR_MM} mm",
                    v[2]
                ),
            ));
        }
        s.theta_a_rad.push(v[0].to_radians());
        s.theta_c_rad.push(v[1].to_radians());
        s.d_mm.push(v[2]);
    }
    // Distinct machine positions (to 1e-6°).
    let mut pos: Vec<(i64, i64)> = s
        .theta_a_rad
        .iter()
        .zip(&s.theta_c_rad)
        .map(|(a, c)| {
            (
                (a.to_degrees() * 1e6).round() as i64,
                (c.to_degrees() * 1e6).round() as i64,
            )
        })
        .collect();
    pos.sort_unstable();
    pos.dedup();
    if pos.len() <= n_params {
        return Err(t.header_error(
            None,
            format!(
                "{} samples at {} distinct (A, C) positions: identifying {} parameters needs more than {} positions; record a longer motion",
                s.d_mm.len(),
                pos.len(),
                n_params,
                n_params
            ),
        ));
    }
    for (k, angles) in [&s.theta_a_rad, &s.theta_c_rad].into_iter().enumerate() {
        let lo = angles.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = angles.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        if hi - lo < 1e-9 {
            return Err(t.header_error(
                Some(&cols[k]),
                format!(
                    "{} never changes (always {}°): the {} axis must move during the test, or the linkage parameters cannot be identified",
                    SAMPLE_COLUMNS[k],
                    lo.to_degrees(),
                    if k == 0 { "A" } else { "C" }
                ),
            ));
        }
    }
    Ok(s)
}

/// Write samples as CSV `theta_a_deg,theta_c_deg,d_mm` with round-trip precision.
pub fn samples_csv(theta_a_rad: &[f64], theta_c_rad: &[f64], d_mm: &[f64]) -> String {
    let mut out = String::from("theta_a_deg,theta_c_deg,d_mm\n");
    for ((a, c), d) in theta_a_rad.iter().zip(theta_c_rad).zip(d_mm) {
        out.push_str(&format!("{},{},{}\n", a.to_degrees(), c.to_degrees(), d));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_csv_picks_a_case() {
        let text =
            "case,s0_mm,a0_mm,theta_a0_deg,s2_mm,a2_mm,theta_c0_deg,a1_mm,alpha12_deg,note\n\
                    M1,96.865,351.891,-54.995,79.871,30.063,-161.531,-0.023,270.093,x\n\
                    M2,97.124,351.900,-54.996,79.904,30.080,-161.541,-0.021,270.102,y\n";
        let p = parse_params_csv(Path::new("t.csv"), text, Some("M2")).unwrap();
        assert_eq!(p.s0_mm, 97.124);
        assert!((p.alpha12_rad.to_degrees() - 270.102).abs() < 1e-12);
        let e = parse_params_csv(Path::new("t.csv"), text, None).unwrap_err();
        assert!(e.to_string().contains("--case"), "{e}");
    }

    #[test]
    fn toml_round_trips_and_reports_position() {
        let p = Params::from_named_units(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
        let back = parse_params_toml(Path::new("p.toml"), &params_toml(&p)).unwrap();
        for (a, b) in p.to_array().iter().zip(back.to_array()) {
            assert!((a - b).abs() < 1e-12);
        }
        let bad = "s0_mm = 1\na0_mm = x\n";
        let e = parse_params_toml(Path::new("p.toml"), bad).unwrap_err();
        assert!(e.to_string().starts_with("p.toml:2:"), "{e}");
    }

    #[test]
    fn samples_errors_point_at_the_field() {
        let e = parse_samples(
            Path::new("s.csv"),
            "theta_a_deg,theta_c_deg,d_mm\n1,2,3\n1,zz,3\n",
            0,
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "s.csv:3:3: theta_c_deg: `zz` is not a number"
        );
        let e = parse_samples(Path::new("s.csv"), "a,b,c\n1,2,3\n", 0).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("s.csv:1: missing column `theta_a_deg`"),
            "{e}"
        );
    }
}
