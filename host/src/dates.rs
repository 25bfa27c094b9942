//! Dates as the reports and the history write them: RFC 3339 in UTC to the second
//! (`2026-11-23T14:05:00Z`), which also sorts as text.
use time::format_description::well_known::Rfc3339;
use time::{OffsetDateTime, UtcOffset};

/// Now, in UTC, to the second.
pub fn now_utc() -> String {
    format_utc(OffsetDateTime::now_utc())
}

fn format_utc(t: OffsetDateTime) -> String {
    t.to_offset(UtcOffset::UTC)
        .replace_nanosecond(0)
        .expect("0 ns is valid")
        .format(&Rfc3339)
        .expect("a UTC date formats as RFC 3339")
}

/// A date given by a person: `YYYY-MM-DD` (midnight UTC) or RFC 3339 with any offset; returned
/// in UTC as [`now_utc`] writes it. The error says what is accepted.
pub fn parse_date(s: &str) -> Result<String, String> {
    let t = s.trim();
    let full = if t.len() == 10 {
        format!("{t}T00:00:00Z")
    } else {
        t.to_string()
    };
    OffsetDateTime::parse(&full, &Rfc3339)
        .map(format_utc)
        .map_err(|e| {
            format!(
                "`{s}` is not a date ({e}); give YYYY-MM-DD or RFC 3339 like 2026-11-23T14:05:00Z"
            )
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_normalise_to_utc_seconds() {
        assert_eq!(parse_date("2026-10-01").unwrap(), "2026-10-01T00:00:00Z");
        assert_eq!(
            parse_date("2026-10-01T12:30:15.25+02:00").unwrap(),
            "2026-10-01T10:30:15Z"
        );
        assert!(parse_date("2026-13-01").is_err());
        assert!(parse_date("yesterday").unwrap_err().contains("YYYY-MM-DD"));
        let now = now_utc();
        assert_eq!(now.len(), 20, "{now}");
        assert_eq!(parse_date(&now).unwrap(), now);
    }
}
