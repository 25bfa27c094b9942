//! Value parsers shared by the subcommands' arguments: numbers are finite, and limits are stated
//! in the messages (clap prints them as usage errors, exit 2).

/// A finite number (refuses `nan`, `inf`).
pub fn finite(s: &str) -> Result<f64, String> {
    let x: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    if x.is_finite() {
        Ok(x)
    } else {
        Err(format!("{s} is not a finite number"))
    }
}

/// A finite number ≥ 0.
pub fn non_negative(s: &str) -> Result<f64, String> {
    let x = finite(s)?;
    if x >= 0.0 {
        Ok(x)
    } else {
        Err(format!("{s} is negative; give a number >= 0"))
    }
}

/// A finite number > 0.
pub fn positive(s: &str) -> Result<f64, String> {
    let x = finite(s)?;
    if x > 0.0 {
        Ok(x)
    } else {
        Err(format!("{s} is not positive"))
    }
}

/// Largest `--seconds` of a streaming session: one year.
pub const MAX_SECONDS: f64 = 365.0 * 24.0 * 3600.0;

/// A duration in seconds for `--seconds`: positive, at most [`MAX_SECONDS`].
pub fn seconds(s: &str) -> Result<f64, String> {
    let x = positive(s)?;
    if x <= MAX_SECONDS {
        Ok(x)
    } else {
        Err(format!(
            "{s} s is more than a year ({MAX_SECONDS} s); leave --seconds out to run until Ctrl-C"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_finite_and_in_range() {
        assert_eq!(finite("-2.5"), Ok(-2.5));
        assert!(finite("nan").is_err() && finite("inf").is_err() && finite("x").is_err());
        assert!(non_negative("0").is_ok() && non_negative("-1").is_err());
        assert!(positive("0").is_err() && positive("1e-3").is_ok());
        assert!(seconds("1e300").unwrap_err().contains("more than a year"));
        assert!(seconds("1e19").is_err() && seconds("-1").is_err());
        assert_eq!(seconds("60"), Ok(60.0));
    }
}
