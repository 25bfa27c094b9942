//! Calibration files: TOML with the fields of `jdbb_core::calib::Calibration` (`l1_mm`, `l2_mm`,
//! `axes_skew_rad`, tables `[enc1]`, `[enc2]`, `[frame1]`, `[frame2]`; the error terms default to
//! zero, so a nominal file may give only lengths and encoders). Read checked; written by
//! [`crate::fsio`] (whole, or not at all).
use std::path::Path;

use jdbb_core::calib::{Calibration, CalibrationError};

use crate::{Error, Result};

/// Read and check a calibration TOML file. Errors name `file:line:column` and say what the file
/// must hold.
pub fn read_calibration(path: &Path) -> Result<Calibration> {
    let text = crate::table::read_text(path)?;
    parse_calibration(path, &text)
}

/// [`read_calibration`] on text in memory; `path` names it in errors.
pub fn parse_calibration(path: &Path, text: &str) -> Result<Calibration> {
    let cal = toml::from_str::<Calibration>(text).map_err(|e| {
        let (line, col) = e.span().map_or((1, 0), |s| crate::table::line_col(text, s.start));
        Error::input(
            path,
            line,
            col,
            format!(
                "{}; a calibration file holds l1_mm, l2_mm and tables [enc1], [enc2] with counts_per_rev, zero_count and direction (Positive or Negative), e.g. as `jdbb calibrate -o` writes it",
                e.message().trim_end()
            ),
        )
    })?;
    cal.validate().map_err(|e| Error::Input {
        location: path.display().to_string(),
        message: format!("calibration rejected: {}", why(e)),
    })?;
    Ok(cal)
}

/// Words for a [`CalibrationError`].
pub fn why(e: CalibrationError) -> &'static str {
    match e {
        CalibrationError::BarLength => "a bar length is not between 1 mm and 10 m (a bar is centimetres long: a smaller or larger number is a typing or unit error)",
        CalibrationError::Resolution => "an encoder has fewer than 4 counts per revolution",
        CalibrationError::ZeroOffset => "a fine zero (zero_offset_rad), with the eccentricity, is beyond 0.01 rad: set zero_count instead",
        CalibrationError::Eccentricity => "an eccentricity is negative or beyond 0.01 rad, or its phase beyond ±2π",
        CalibrationError::AxesSkew => "axes_skew_rad is beyond 0.01 rad",
        CalibrationError::Tilt => "a pivot tilt is beyond 0.01 rad",
        CalibrationError::PivotOffset => "a pivot offset is beyond 0.01 rad",
        _ => "a value is out of range",
    }
}

/// The TOML text of a calibration, after comment lines `header` (each prefixed with `# `).
pub fn calibration_toml(cal: &Calibration, header: &[String]) -> String {
    let mut s = String::new();
    for h in header {
        s.push_str("# ");
        s.push_str(h);
        s.push('\n');
    }
    s.push_str(&toml::to_string(cal).expect("a calibration is plain data"));
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_errors() {
        let mut c = Calibration::nominal(40.0, 60.0, 1 << 20);
        c.enc1.set_eccentricity_components(1e-4, -2e-5);
        c.axes_skew_rad = 3e-4;
        let text = calibration_toml(&c, &["written by a test".into()]);
        assert!(text.starts_with("# written by a test\n"));
        assert_eq!(parse_calibration(Path::new("c.toml"), &text).unwrap(), c);
        // Only the nominal fields: the error terms default to zero.
        let short = "l1_mm = 50.0\nl2_mm = 50.0\n[enc1]\ncounts_per_rev = 8388608\nzero_count = 0\ndirection = \"Positive\"\n[enc2]\ncounts_per_rev = 8388608\nzero_count = 0\ndirection = \"Positive\"\n";
        assert_eq!(
            parse_calibration(Path::new("c.toml"), short).unwrap(),
            Calibration::DEFAULT
        );
        let e =
            parse_calibration(Path::new("c.toml"), "l1_mm = 50.0\nl2_mm = \"x\"\n").unwrap_err();
        assert!(e.to_string().starts_with("c.toml:2:9: "), "{e}");
        assert_eq!(e.exit_code(), 2);
        let bad = short.replace("l1_mm = 50.0", "l1_mm = -5.0");
        let e = parse_calibration(Path::new("c.toml"), &bad).unwrap_err();
        assert!(e.to_string().contains("bar length"), "{e}");
    }
}
