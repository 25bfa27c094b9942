//! The values in force (`jdbb compensate --current FILE`), in each controller's own format; the
//! formats are documented with each controller ([`super::linuxcnc`], [`super::grblhal`],
//! [`super::marlin`], [`super::klipper`]). Read into one map from a setting's key (as those
//! modules name it, e.g. `JOINT_0.BACKLASH`, `$160`, `M425.X`, `xy_skew`) to its value.
//! Lines a format does not use are ignored; a value that is not a number is an input error at
//! `file:line:column`. Reading a file in a controller's format ([`Current::read`]) is in the parent module:
//! the parsers live with each controller, and this module depends on none of them.
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::{Error, Result};

/// Values in force, by key.
#[derive(Debug, Clone, Default)]
pub struct Current {
    values: BTreeMap<String, f64>,
    /// Text settings (e.g. a LinuxCNC `COMP_FILE` name), by key.
    texts: BTreeMap<String, String>,
    /// Decimals each value was written with, by key (where the format rounds, e.g. Marlin's
    /// `M503`).
    decimals: BTreeMap<String, usize>,
    pub source: Option<PathBuf>,
}

impl Current {
    /// Nothing in force given.
    pub fn none() -> Current {
        Current::default()
    }

    pub fn get(&self, key: &str) -> Option<f64> {
        self.values.get(key).copied()
    }

    pub fn text(&self, key: &str) -> Option<&str> {
        self.texts.get(key).map(|s| s.as_str())
    }

    pub fn set(&mut self, key: impl Into<String>, value: f64) {
        self.values.insert(key.into(), value);
    }

    /// Record that the value of `key` was written with `decimals` decimals.
    pub fn set_decimals(&mut self, key: impl Into<String>, decimals: usize) {
        self.decimals.insert(key.into(), decimals);
    }

    /// The decimals the value of `key` was written with, where recorded.
    pub fn decimals(&self, key: &str) -> Option<usize> {
        self.decimals.get(key).copied()
    }

    /// Whether anything (a number or a text) was read.
    pub fn has_values(&self) -> bool {
        !self.values.is_empty() || !self.texts.is_empty()
    }

    pub fn set_text(&mut self, key: impl Into<String>, value: impl Into<String>) {
        self.texts.insert(key.into(), value.into());
    }

    /// Whether nothing was given.
    pub fn is_empty(&self) -> bool {
        self.values.is_empty() && self.texts.is_empty() && self.source.is_none()
    }
}

/// A number at `path:line:col` (1-based), or an input error naming `what`.
pub(crate) fn number(path: &Path, line: usize, col: usize, text: &str, what: &str) -> Result<f64> {
    text.trim()
        .parse::<f64>()
        .ok()
        .filter(|x| x.is_finite())
        .ok_or_else(|| {
            Error::input(
                path,
                line,
                col,
                format!("{what}: `{}` is not a number", text.trim()),
            )
        })
}

/// The words of a G-code line as (letter, value text, 1-based column of the letter): `M425 F1
/// X0.02` → (M, 425), (F, 1), (X, 0.02). Words are separated by white space (as `M503` prints
/// them), so a typo such as `X0.0o2` stays one word and fails as a number rather than being
/// read as `X0.0`. Comments after `;` and in `( )` are dropped; a leading `echo:` (Marlin's
/// `M503` output) is skipped.
pub(crate) fn gcode_words(line: &str) -> Vec<(char, String, usize)> {
    let mut body = line;
    if let Some(i) = body.find(';') {
        body = &body[..i];
    }
    // Blank out parenthesised comments, keeping columns.
    let mut clean = String::with_capacity(body.len());
    let mut depth = 0;
    for c in body.chars() {
        match c {
            '(' => {
                depth += 1;
                clean.push(' ');
            }
            ')' if depth > 0 => {
                depth -= 1;
                clean.push(' ');
            }
            _ if depth > 0 => clean.push(' '),
            _ => clean.push(c),
        }
    }
    let start = clean.len() - clean.trim_start().len();
    let mut from = start;
    if clean[start..].starts_with("echo:") {
        from = start + 5;
    }
    let mut words = vec![];
    let mut i = from;
    let bytes = clean.as_bytes();
    while i < clean.len() {
        if bytes[i].is_ascii_whitespace() {
            i += 1;
            continue;
        }
        let end = clean[i..]
            .find(|c: char| c.is_ascii_whitespace())
            .map_or(clean.len(), |k| i + k);
        let token = &clean[i..end];
        let mut chars = token.chars();
        if let Some(letter) = chars.next().filter(|c| c.is_ascii_alphabetic()) {
            words.push((
                letter.to_ascii_uppercase(),
                chars.as_str().to_string(),
                i + 1,
            ));
        }
        i = end;
    }
    words
}

/// `key = value` or `key: value` of an INI-like line (LinuxCNC INI, Klipper config), with the
/// 1-based column of the value; comments after `#` or `;` dropped.
pub(crate) fn key_value(line: &str) -> Option<(String, String, usize)> {
    let body = match line.find(['#', ';']) {
        Some(i) => &line[..i],
        None => line,
    };
    let sep = body.find(['=', ':'])?;
    let key = body[..sep].trim();
    if key.is_empty() {
        return None;
    }
    let raw = &body[sep + 1..];
    let lead = raw.len() - raw.trim_start().len();
    Some((key.to_string(), raw.trim().to_string(), sep + 2 + lead))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gcode_words_split_with_columns() {
        let w = gcode_words("echo:  M425 F1.00 S0.00 X0.02 Y-0.01 ; comment X9");
        let got: Vec<(char, &str)> = w.iter().map(|(c, v, _)| (*c, v.as_str())).collect();
        assert_eq!(
            got,
            vec![
                ('M', "425"),
                ('F', "1.00"),
                ('S', "0.00"),
                ('X', "0.02"),
                ('Y', "-0.01")
            ]
        );
        assert_eq!(w[3].2, 25);
        let w = gcode_words("M852 I2.5e-05 (skew) J0");
        assert_eq!(w[1].1, "2.5e-05");
        assert_eq!(w[2], ('J', "0".to_string(), 22));
        // A typo stays in its word (and then fails as a number).
        let w = gcode_words("M425 X0.0o2");
        assert_eq!(w[1], ('X', "0.0o2".to_string(), 6));
    }

    #[test]
    fn key_values_with_column() {
        assert_eq!(
            key_value("BACKLASH = 0.012  # x"),
            Some(("BACKLASH".into(), "0.012".into(), 12))
        );
        assert_eq!(
            key_value("xy_skew: 0.001"),
            Some(("xy_skew".into(), "0.001".into(), 10))
        );
        assert_eq!(key_value("[JOINT_0]"), None);
        let e = number(Path::new("c.ini"), 3, 12, "0.0x1", "BACKLASH").unwrap_err();
        assert_eq!(
            e.to_string(),
            "c.ini:3:12: BACKLASH: `0.0x1` is not a number"
        );
    }
}
