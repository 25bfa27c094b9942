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

/// Largest length of a machine or instrument, mm: 10 m. A machine tool, a ball bar and a
/// turntable's offsets are all smaller; a larger number is a typing error (`1e300`), and the
/// geometry would lose all its digits on it.
pub const MAX_LENGTH_MM: f64 = 10_000.0;

/// A length in mm for a geometric offset (may be negative): finite, at most [`MAX_LENGTH_MM`] in
/// size.
pub fn length_mm(s: &str) -> Result<f64, String> {
    let x = finite(s)?;
    if x.abs() <= MAX_LENGTH_MM {
        Ok(x)
    } else {
        Err(format!(
            "{s} mm is longer than any machine ({MAX_LENGTH_MM} mm = 10 m); give the length in mm"
        ))
    }
}

/// A bar length in mm: positive and at most [`MAX_LENGTH_MM`].
pub fn bar_mm(s: &str) -> Result<f64, String> {
    let x = length_mm(s)?;
    if x > 0.0 {
        Ok(x)
    } else {
        Err(format!("{s} mm: a bar length is positive"))
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

/// `x=1,y=2` into per-axis values with `parse` for each value.
pub fn per_axis<T>(
    option: &str,
    s: &str,
    parse: impl Fn(&str) -> Option<T>,
    form: &str,
) -> crate::Result<[Option<T>; 3]> {
    let mut out: [Option<T>; 3] = [None, None, None];
    for part in s.split(',').filter(|p| !p.trim().is_empty()) {
        let (k, v) = part.split_once('=').ok_or_else(|| {
            crate::Error::Usage(format!("{option}: `{part}` should look like {form}"))
        })?;
        let axis = match k.trim().to_ascii_lowercase().as_str() {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            other => {
                return Err(crate::Error::Usage(format!(
                    "{option}: unknown axis `{other}`; use x, y or z"
                )))
            }
        };
        if out[axis].is_some() {
            return Err(crate::Error::Usage(format!(
                "{option}: axis {} is given twice",
                k.trim()
            )));
        }
        out[axis] = Some(parse(v.trim()).ok_or_else(|| {
            crate::Error::Usage(format!("{option}: `{part}` should look like {form}"))
        })?);
    }
    Ok(out)
}

/// A machine's travel per axis, `x=0:500,y=0:400` (mm), for `option`: each axis given
/// (MIN, MAX) with MIN < MAX, the others `None`.
pub fn travel_mm(option: &str, s: &str) -> crate::Result<[Option<(f64, f64)>; 3]> {
    per_axis(
        option,
        s,
        |v| {
            let (a, b) = v.split_once(':')?;
            let (a, b) = (finite_value(a.trim())?, finite_value(b.trim())?);
            (a < b).then_some((a, b))
        },
        "x=MIN:MAX with MIN < MAX (mm)",
    )
}

/// `s` as a finite number, if it is one.
pub fn finite_value(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|x| x.is_finite())
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
        assert!(length_mm("1e300").unwrap_err().contains("10 m"));
        assert!(length_mm("1e100").is_err() && length_mm("-20000").is_err());
        assert_eq!(length_mm("-250"), Ok(-250.0));
        assert!(bar_mm("0").is_err() && bar_mm("1e-300").is_ok() && bar_mm("100").is_ok());
    }
}
