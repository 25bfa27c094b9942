//! The words of the trade: what a diagnosed effect means to the person at the machine, in plain
//! language, and the labels of its parameters. This is the only place the user-facing cause
//! texts live (the text summary, `effects[].cause` of the JSON and `report.html` all take them
//! from here).
//!
//! The texts name the mechanism and where to look, not the paper a model comes from: the models
//! and their references (seed 000's equations) are documented in [`crate::model`].
//!
//! Signs, as ballbar users read them:
//! - `backlash_k` (µm): **positive = lost motion (play)** at reversal, negative = the axis runs
//!   ahead at reversal (a backlash compensation set too large: over-compensation);
//! - `scale_k` (µm/m): positive = the axis travels further than commanded;
//! - `servo_mismatch_ij` (ms): positive = i follows its command later than j;
//! - `reversal_spike_k` (µm): positive = the axis sticks at reversal and catches up;
//! - `setup_offset` (µm): where the table ball is relative to where it was assumed.
use crate::model::{Axis, Effect, Pair};

fn up(a: Axis) -> char {
    a.letter().to_ascii_uppercase()
}

fn pair_up(p: Pair) -> (char, char) {
    let (i, j) = p.axes();
    (up(i), up(j))
}

/// The cause of `effect` with value `value` (in the effect's unit) in words a machine-tool
/// technician uses: the mechanism, then after " — " what to check or set. The sign of the value
/// chooses the words where the trade has two (play vs over-compensation, long vs short travel).
pub fn cause(effect: Effect, value: f64) -> String {
    let neg = value < 0.0;
    match effect {
        Effect::SetupOffset => {
            "the table ball is not where it was assumed (centring) — set-up, not a machine error"
                .into()
        }
        Effect::LengthOffset => {
            "the bar is longer or shorter than its assumed length — bar calibration or ball seating; set-up, not a machine error".into()
        }
        Effect::Scale(a) => format!(
            "{}: travels {} than commanded (scale error) — steps/mm or pitch setting, or the screw or scale is warm",
            up(a),
            if neg { "less" } else { "further" }
        ),
        Effect::Scale2(a) => format!(
            "{}: travel error that grows with the square of the distance (second-order scale) — screw or scale fixed at both ends and warm; on one circle the same as a bowed (not straight) other axis",
            up(a)
        ),
        Effect::Backlash(a) => {
            if neg {
                format!(
                    "{}: axis runs ahead at reversal (over-compensation) — backlash compensation set too large",
                    up(a)
                )
            } else {
                format!(
                    "{}: lost motion (play) at reversal — backlash setting, or a worn nut or loose screw bearing",
                    up(a)
                )
            }
        }
        Effect::BacklashEnds(a) => format!(
            "{}: lost motion that differs between the two ends of the travel — a ball screw or nut worn more at one end; one backlash setting can only take the mean",
            up(a)
        ),
        Effect::Straightness(a, b) => format!(
            "{}: not straight, bows in {} (straightness) — guideway bent, worn or unevenly supported (level, foundation); on one circle the same as a second-order scale of {}",
            up(a),
            up(b),
            up(b)
        ),
        Effect::LateralPlay(a, b) => format!(
            "{}: its carriage shifts in {} each time it reverses (lateral play) — clearance across the guideway: gibs or roller preload loose or worn",
            up(a),
            up(b)
        ),
        Effect::Cyclic(a) => format!(
            "{}: error that repeats with every turn of the screw (cyclic error at the pitch) — screw runout, thrust bearing or coupling, or the scale's read head",
            up(a)
        ),
        Effect::Interference(a) => format!(
            "{}: cyclic reading error that grows with speed — the scale or encoder signal (read head alignment, gap, cabling)",
            up(a)
        ),
        Effect::Squareness(p) => {
            let (i, j) = pair_up(p);
            format!(
                "{i} and {j} are out of square: {i} moves by this much per metre of {j} travel — axis alignment (geometry), or the controller's skew setting"
            )
        }
        Effect::ServoMismatch(p) => {
            let (i, j) = pair_up(p);
            let (late, early) = if neg { (j, i) } else { (i, j) };
            format!(
                "{late} follows its command later than {early} (servo mismatch) — position-loop gain or feed-forward of the two axes differ: tuning, not a setting"
            )
        }
        Effect::ScaleMismatch(p) => {
            let (i, j) = pair_up(p);
            let (long, short) = if neg { (j, i) } else { (i, j) };
            format!(
                "{long} travels further than {short} for the same command (scale mismatch) — steps/mm or pitch settings, or a warm screw; one radius cannot show their common part"
            )
        }
        Effect::ReversalSpike(a) => {
            if neg {
                format!(
                    "{}: overshoots at reversal and settles (reversal spike) — servo tuning at reversal (friction feed-forward too large)",
                    up(a)
                )
            } else {
                format!(
                    "{}: sticks at reversal and then catches up (reversal spike) — friction in the ways or gibs (lubrication, preload), or a servo slow to take up the reversal",
                    up(a)
                )
            }
        }
        Effect::Drift => {
            "the ball distance drifts during the test — the machine or the instrument is warming up".into()
        }
        Effect::ScaleDrift(a) => format!(
            "{}: its scale grows during the test (thermal drift of scale) — the screw is warming up; warm the machine up, or check its thermal compensation",
            up(a)
        ),
        Effect::PositionDrift(a) => format!(
            "{}: its position drifts during the test — a screw growing about its fixed bearing, or the spindle growing; warm the machine up, or check its thermal compensation",
            up(a)
        ),
        Effect::FollowingError => {
            "the position loops draw each circle smaller the faster it runs (following error: radius loss q·v²/R) — position-loop gain (Kv) and velocity feed-forward: servo tuning, not geometry".into()
        }
    }
}

/// The label of a parameter (its JSON key) for people, e.g. `dtau_ms` → `lag difference`;
/// an unknown key is shown as it is.
pub fn param_label(key: &str) -> &str {
    match key {
        "x_um" => "x",
        "y_um" => "y",
        "z_um" => "z",
        "e_um" => "length",
        "a_um_per_m" => "scale",
        "b_um_per_m2" => "second-order scale",
        "f_um" | "b_um" => "lost motion",
        "pos_um" => "at the + end",
        "neg_um" => "at the − end",
        "sin_um" | "sin_um_per_mm_s" => "sine part",
        "cos_um" | "cos_um_per_mm_s" => "cosine part",
        "s_um_per_m" => "squareness",
        "dtau_ms" => "lag difference",
        "lag_ms" => "common lag",
        "h_um" => "height",
        "bow_um" => "bow",
        "l_um" => "shift",
        "tau_ms" => "decay time",
        "rate_um_per_min" | "rate_um_per_m_per_min" => "rate",
        "q_ms2" => "radius loss per v²/R",
        other => other,
    }
}

/// The unit of a parameter for people, from its JSON key's suffix (`tau_ms` → `ms`, `h_um` →
/// `µm`, `a_um_per_m` → `µm/m`); empty for a key without one.
pub fn param_unit(key: &str) -> &'static str {
    const SUFFIXES: [(&str, &str); 8] = [
        ("_um_per_m_per_min", "µm/m per min"),
        ("_um_per_mm_s", "µm/(mm/s)"),
        ("_um_per_m2", "µm/m²"),
        ("_um_per_min", "µm/min"),
        ("_um_per_m", "µm/m"),
        ("_um", "µm"),
        ("_ms", "ms"),
        ("_ms2", "ms²"),
    ];
    SUFFIXES
        .iter()
        .find(|(suffix, _)| key.ends_with(suffix))
        .map_or("", |(_, unit)| unit)
}

/// A parameter for people: its label, its value to the digits its σ supports (± σ) and its
/// unit, e.g. `decay time 20 ± 15 ms`; without a σ (not determined) the value to 3 decimals and
/// `undetermined` in brackets after the unit.
pub fn param_text(key: &str, value: f64, sigma: Option<f64>, undetermined: &str) -> String {
    let unit = param_unit(key);
    let sep = if unit.is_empty() { "" } else { " " };
    match sigma.filter(|s| s.is_finite() && *s > 0.0) {
        Some(s) => format!(
            "{} {}{sep}{unit}",
            param_label(key),
            crate::units::format_estimate(value, Some(s))
        ),
        None => format!(
            "{} {value:.3}{sep}{unit} ({undetermined})",
            param_label(key)
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backlash_reads_as_play_or_over_compensation_by_its_sign() {
        let play = cause(Effect::Backlash(Axis::X), 6.0);
        assert!(
            play.starts_with("X: lost motion (play) at reversal — backlash setting"),
            "{play}"
        );
        let over = cause(Effect::Backlash(Axis::Y), -3.0);
        assert!(
            over.starts_with("Y: axis runs ahead at reversal (over-compensation)"),
            "{over}"
        );
        assert!(cause(Effect::ServoMismatch(Pair::Xy), 0.4).starts_with("X follows"));
        assert!(cause(Effect::ServoMismatch(Pair::Xy), -0.4).starts_with("Y follows"));
        assert!(cause(Effect::Scale(Axis::Z), -10.0).contains("travels less"));
    }

    #[test]
    fn a_parameter_reads_with_its_unit_and_the_digits_of_its_sigma() {
        // A reversal spike's height is in µm and its decay time in ms (model.rs: h·1e-3 mm,
        // τ in ms).
        assert_eq!(
            param_text("h_um", 0.0812, Some(7.93), "undetermined"),
            "height 0.1 ± 7.9 µm"
        );
        assert_eq!(
            param_text("tau_ms", 83.479, Some(12.4), "undetermined"),
            "decay time 83 ± 12 ms"
        );
        assert_eq!(
            param_text("z_um", 0.0, None, "undetermined, held"),
            "z 0.000 µm (undetermined, held)"
        );
        assert_eq!(param_unit("a_um_per_m"), "µm/m");
        assert_eq!(param_unit("b_um_per_m2"), "µm/m²");
        assert_eq!(param_unit("sin_um_per_mm_s"), "µm/(mm/s)");
        assert_eq!(param_unit("rate_um_per_m_per_min"), "µm/m per min");
    }

    #[test]
    fn no_paper_references_or_symbols_in_the_words() {
        let mut all: Vec<Effect> = Effect::all();
        all.extend(Pair::ALL.map(Effect::ScaleMismatch));
        for e in all {
            for v in [-1.0, 1.0] {
                let c = cause(e, v);
                for bad in ["seed", "eq.", "dtau", "BIC", "tau", "δ"] {
                    assert!(!c.contains(bad), "{e}: `{bad}` in `{c}`");
                }
                assert!(c.contains(" — "), "{c}");
            }
            for k in e.param_names() {
                let l = param_label(k);
                assert!(!l.contains('_'), "{e}: parameter {k} has no label");
                assert!(!param_unit(k).is_empty(), "{e}: parameter {k} has no unit");
            }
        }
    }
}
