//! Units and numbers as people read them. JSON keys, JSON unit strings and file columns stay ASCII (`um`,
//! `um/m`, `d_mm`); text for people uses the symbols (`µm`, `µm/m`). One function does the
//! translation, so every human report reads the same.

/// The human form of an ASCII unit: `um` → `µm`, `um/m^2` → `µm/m²`, `1e-5rad` → `1e-5 rad`.
pub fn human(ascii: &str) -> String {
    let mut s = String::with_capacity(ascii.len() + 2);
    let mut rest = ascii;
    while !rest.is_empty() {
        // `um` as a whole unit token (not inside a word such as `sum`).
        let at_token = s.chars().last().is_none_or(|c| !c.is_ascii_alphabetic());
        if at_token
            && rest.starts_with("um")
            && !rest[2..].starts_with(|c: char| c.is_ascii_alphabetic())
        {
            s.push('µ');
            s.push('m');
            rest = &rest[2..];
        } else if let Some(r) = rest.strip_prefix("^2") {
            s.push('²');
            rest = r;
        } else {
            let c = rest.chars().next().expect("not empty");
            s.push(c);
            rest = &rest[c.len_utf8()..];
        }
    }
    s.replace("1e-5rad", "1e-5 rad")
}

/// Format `value ± sigma` with the digits the standard error supports (two significant digits
/// of sigma); an undetermined value is shown to 3 decimals and flagged.
pub fn format_estimate(value: f64, sigma: Option<f64>) -> String {
    match sigma {
        Some(s) if s > 0.0 && s.is_finite() => {
            let decimals = (1 - s.log10().floor() as i32).clamp(0, 12) as usize;
            format!("{value:.decimals$} ± {s:.decimals$}")
        }
        Some(_) => format!("{value} ± 0"),
        None => format!("{value:.3} (undetermined)"),
    }
}

#[cfg(test)]
mod tests {
    use super::{format_estimate, human};

    #[test]
    fn ascii_units_become_symbols() {
        assert_eq!(human("um"), "µm");
        assert_eq!(human("um/m"), "µm/m");
        assert_eq!(human("um/m^2"), "µm/m²");
        assert_eq!(human("um/(mm/s)"), "µm/(mm/s)");
        assert_eq!(human("ms"), "ms");
        assert_eq!(human("1e-5rad"), "1e-5 rad");
        assert_eq!(human("drum"), "drum");
    }

    #[test]
    fn estimates_show_the_digits_sigma_supports() {
        assert_eq!(format_estimate(1.234_567, Some(0.0123)), "1.235 ± 0.012");
        assert_eq!(format_estimate(250.0, Some(31.0)), "250 ± 31");
        assert_eq!(format_estimate(1.0, None), "1.000 (undetermined)");
    }
}
