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

/// The decimals that show two significant digits of `sigma` (the digits a value with that
/// standard uncertainty supports): 0.0123 → 4, 0.2 → 2, 31 → 0. Three for an unknown σ.
pub fn decimals_for(sigma: f64) -> usize {
    if sigma > 0.0 && sigma.is_finite() {
        (1 - sigma.log10().floor() as i32).clamp(0, 12) as usize
    } else {
        3
    }
}

/// `value` rounded to the decimal place of two significant digits of `sigma` (see
/// [`decimals_for`]): the form of every printed figure that has no ± of its own (G, H, RMS,
/// with the noise σ of the test).
pub fn format_to(value: f64, sigma: f64) -> String {
    let d = decimals_for(sigma);
    no_negative_zero(format!("{value:.d$}"))
}

/// `-0.00` (a small negative value rounded away) as `0.00`.
fn no_negative_zero(text: String) -> String {
    match text.strip_prefix('-') {
        Some(rest) if rest.chars().all(|c| c == '0' || c == '.') => rest.to_string(),
        _ => text,
    }
}

/// Whole percentages of `shares` (fractions of one whole, NaN counting as 0) that add up to
/// exactly 100: each gets the floor of its percentage, and the points still missing go to the
/// largest remainders (ties to the earlier one). All zero if the shares sum to nothing.
pub fn percentages(shares: &[f64]) -> Vec<u32> {
    let clean: Vec<f64> = shares
        .iter()
        .map(|s| if s.is_finite() { s.max(0.0) } else { 0.0 })
        .collect();
    let total: f64 = clean.iter().sum();
    if total <= 0.0 {
        return vec![0; shares.len()];
    }
    let exact: Vec<f64> = clean.iter().map(|s| 100.0 * s / total).collect();
    let mut out: Vec<u32> = exact.iter().map(|e| e.floor() as u32).collect();
    let missing = 100 - out.iter().sum::<u32>().min(100);
    let mut order: Vec<usize> = (0..exact.len()).collect();
    order.sort_by(|&a, &b| {
        let ra = exact[a] - exact[a].floor();
        let rb = exact[b] - exact[b].floor();
        rb.total_cmp(&ra).then(a.cmp(&b))
    });
    for &k in order.iter().take(missing as usize) {
        out[k] += 1;
    }
    out
}

/// Format `value ± sigma` with the digits the standard error supports (two significant digits
/// of sigma); an undetermined value is shown to 3 decimals and flagged.
pub fn format_estimate(value: f64, sigma: Option<f64>) -> String {
    match sigma {
        Some(s) if s > 0.0 && s.is_finite() => {
            let decimals = decimals_for(s);
            let v = no_negative_zero(format!("{value:.decimals$}"));
            format!("{v} ± {s:.decimals$}")
        }
        Some(_) => format!("{value} ± 0"),
        None => format!("{value:.3} (undetermined)"),
    }
}

#[cfg(test)]
mod tests {
    use super::{decimals_for, format_estimate, format_to, human, percentages};

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
        // No nanometres that σ does not support.
        assert_eq!(decimals_for(0.201), 2);
        assert_eq!(format_to(7.2951, 0.201), "7.30");
        assert_eq!(format_to(7.2951, 0.0034), "7.2951");
        assert_eq!(format_to(1234.4, 31.0), "1234");
        assert_eq!(format_to(-0.000_04, 0.2), "0.00");
        assert_eq!(format_estimate(-0.000_04, Some(0.2)), "0.00 ± 0.20");
    }

    #[test]
    fn percentages_add_up_to_100_by_largest_remainder() {
        // 1/3 each: 33.33 % thrice; the missing point goes to the first.
        assert_eq!(percentages(&[1.0, 1.0, 1.0]), vec![34, 33, 33]);
        // 97.6 / 1.7 / 0.7: floors 97 + 1 + 0 = 98; the two largest remainders (0.7, 0.7) get
        // the two points, not the 0.6 of the largest share.
        assert_eq!(percentages(&[0.976, 0.017, 0.007]), vec![97, 2, 1]);
        // Shares that do not add to one are taken relative to their sum; NaN counts as 0.
        let p = percentages(&[0.5, f64::NAN, 0.25, 0.05]);
        assert_eq!(p.iter().sum::<u32>(), 100);
        assert_eq!(p, vec![63, 0, 31, 6]);
        assert_eq!(percentages(&[0.0, 0.0]), vec![0, 0]);
    }
}
