//! The fleet view (`jdbb history fleet`): every machine × quantity (each machine effect, and
//! the circular deviation G) with its latest value, its slope per 30 days, its tolerance, the
//! machine's last compensation change, and a drift alarm; as text, CSV and an HTML page.
//!
//! # Drift alarm: a CUSUM on the effect's σ, reset at a compensation change
//! Over the comparable runs since the last compensation change (the runs the slope is fitted
//! over), the first is the reference x₀; each later run i is scored
//! z_i = (x_i − x₀)/√(σ_i² + σ₀²), its departure in units of the two runs' σ (G, which has no
//! σ, in units of the runs' noise, their residual RMS). A two-sided tabular CUSUM accumulates
//! them, S⁺_i = max(0, S⁺_{i−1} + z_i − k) and S⁻_i = max(0, S⁻_{i−1} − z_i − k), with the
//! usual k = ½ (tuned to a shift of one σ) and h = 5 ([`CUSUM_H`]): an in-control effect raises
//! a false alarm about once in 465 runs, and a shift of one σ is flagged after about 10 runs,
//! of 3 σ after about 2. The alarm names the runs of the excursion: from the first run after
//! the sum last stood at 0 to the last run over h.
//!
//! Why CUSUM rather than EWMA: a machine's effect drifts by wear, a slow steady change, or steps
//! by a crash or a repair; CUSUM is the optimal detector of a sustained shift of a given size
//! and points at where it began (the runs it names), while an EWMA smooths that start away and
//! needs its weight chosen per test interval. Both need a reference: the run after the last
//! compensation change is the machine as it was set, so the sums restart there (a new
//! compensation is a deliberate shift, not drift).
use std::fmt::Write;

use super::trend::{self, EffectTrend, Figure, Mark};
use super::{printable, Run};
use crate::units::{format_estimate, format_to, human};

/// The CUSUM's allowance k, in σ (module docs).
pub const CUSUM_K: f64 = 0.5;
/// The CUSUM's decision limit h, in σ (module docs).
pub const CUSUM_H: f64 = 5.0;

/// A drift alarm: the runs that show it, and its direction.
#[derive(Debug, Clone, PartialEq)]
pub struct Drift {
    pub run_ids: Vec<i64>,
    /// True: the value grows against the reference run; false: it shrinks.
    pub up: bool,
}

/// The drift alarm of `t` (module docs), over the runs since the last of `marks`.
pub fn drift(t: &EffectTrend, marks: &[Mark]) -> Option<Drift> {
    let pts = t.fitted(marks);
    let (first, rest) = pts.split_first()?;
    let scale = |p: &trend::Point| p.sigma.or(p.noise).filter(|s| *s > 0.0);
    let (x0, s0) = (first.value?, scale(first)?);
    let (mut up, mut down) = (0.0f64, 0.0f64);
    let (mut up_from, mut down_from) = (0usize, 0usize);
    let mut alarm: Option<Drift> = None;
    for (k, p) in rest.iter().enumerate() {
        let (Some(x), Some(s)) = (p.value, scale(p)) else {
            continue;
        };
        let z = (x - x0) / (s * s + s0 * s0).sqrt();
        if up == 0.0 {
            up_from = k;
        }
        if down == 0.0 {
            down_from = k;
        }
        up = (up + z - CUSUM_K).max(0.0);
        down = (down - z - CUSUM_K).max(0.0);
        for (sum, from, is_up) in [(up, up_from, true), (down, down_from, false)] {
            if sum > CUSUM_H {
                let ids = rest[from..=k].iter().map(|p| p.run_id).collect();
                match &mut alarm {
                    Some(a) if a.up == is_up => a.run_ids = ids,
                    _ => {
                        alarm = Some(Drift {
                            run_ids: ids,
                            up: is_up,
                        })
                    }
                }
            }
        }
    }
    alarm
}

/// One machine × quantity of the fleet view.
#[derive(Debug, Clone)]
pub struct Row {
    pub machine: String,
    pub trend: EffectTrend,
    /// The tolerance the latest run was judged by (G only: µm).
    pub tolerance_um: Option<f64>,
    pub slope: Option<trend::Slope>,
    pub last_compensation: Option<Mark>,
    pub drift: Option<Drift>,
}

impl Row {
    /// The latest run that found the quantity.
    pub fn latest(&self) -> Option<&trend::Point> {
        self.trend.points.iter().rev().find(|p| p.value.is_some())
    }
}

/// The rows of one machine: each effect, then G.
pub fn rows(machine: &str, runs: &[Run], marks: &[Mark]) -> Vec<Row> {
    let mut trends = trend::trend(runs, None).unwrap_or_default();
    trends.extend(trend::figure_trend(runs, Figure::G));
    trends
        .into_iter()
        .map(|t| Row {
            machine: machine.to_string(),
            tolerance_um: (t.name == Figure::G.name())
                .then(|| runs.last().and_then(|r| r.tolerance_um))
                .flatten(),
            slope: t.slope(marks),
            last_compensation: marks.last().cloned(),
            drift: drift(&t, marks),
            trend: t,
        })
        .collect()
}

/// A value of `row`'s latest run, with its σ, in words.
fn latest_text(row: &Row) -> String {
    match row.latest() {
        Some(p) => match (p.value, p.sigma, p.noise) {
            (Some(v), None, Some(n)) => format_to(v, n),
            (Some(v), s, _) => format_estimate(v, s),
            _ => "-".into(),
        },
        None => "-".into(),
    }
}

fn slope_text(row: &Row) -> String {
    row.slope
        .as_ref()
        .map_or("-".into(), |s| format_estimate(s.per_30_days, s.sigma))
}

fn drift_text(row: &Row) -> String {
    row.drift.as_ref().map_or("-".into(), |d| {
        format!(
            "DRIFT {} in runs {}",
            if d.up { "up" } else { "down" },
            d.run_ids
                .iter()
                .map(i64::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        )
    })
}

fn compensation_text(row: &Row) -> String {
    row.last_compensation.as_ref().map_or("-".into(), |m| {
        format!("{} {}", &m.date_utc[..10.min(m.date_utc.len())], m.text)
    })
}

/// The fleet view as text: one line per machine × quantity, the drift alarms counted first.
pub fn render(rows: &[Row]) -> String {
    let mut s = String::new();
    let alarms = rows.iter().filter(|r| r.drift.is_some()).count();
    let machines = {
        let mut m: Vec<&str> = rows.iter().map(|r| r.machine.as_str()).collect();
        m.dedup();
        m.len()
    };
    let _ = writeln!(
        s,
        "machines: {machines}, quantities: {}; drift alarms: {alarms} (CUSUM k = {CUSUM_K} σ, h = {CUSUM_H} σ since the last compensation change)",
        rows.len()
    );
    let _ = writeln!(
        s,
        "{:<12} {:<24} {:<6} {:<4} {:<10} {:<18} {:<20} {:<9} {:<28} drift",
        "machine",
        "quantity",
        "unit",
        "run",
        "date",
        "latest",
        "slope per 30 days",
        "tolerance",
        "last compensation"
    );
    for r in rows {
        let latest = r.latest();
        let _ = writeln!(
            s,
            "{:<12} {:<24} {:<6} {:<4} {:<10} {:<18} {:<20} {:<9} {:<28} {}",
            printable(&r.machine),
            printable(&r.trend.name),
            human(&r.trend.unit),
            latest.map_or("-".into(), |p| p.run_id.to_string()),
            latest.map_or("-", |p| &p.date_utc[..10.min(p.date_utc.len())]),
            latest_text(r),
            slope_text(r),
            r.tolerance_um.map_or("-".into(), |t| format!("{t}")),
            printable(&compensation_text(r)),
            drift_text(r)
        );
    }
    s
}

/// The fleet view as CSV, one row per machine × quantity.
pub fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "machine,quantity,unit,latest_run,latest_date_utc,latest_value,latest_sigma,slope_per_30_days,slope_sigma,tolerance_um,last_compensation_date_utc,last_compensation,drift,drift_runs\n",
    );
    let num = |x: Option<f64>| x.map_or(String::new(), |v| v.to_string());
    for r in rows {
        let p = r.latest();
        let fields = [
            r.machine.clone(),
            r.trend.name.clone(),
            r.trend.unit.clone(),
            p.map_or(String::new(), |p| p.run_id.to_string()),
            p.map_or(String::new(), |p| p.date_utc.clone()),
            num(p.and_then(|p| p.value)),
            num(p.and_then(|p| p.sigma)),
            num(r.slope.as_ref().map(|s| s.per_30_days)),
            num(r.slope.as_ref().and_then(|s| s.sigma)),
            num(r.tolerance_um),
            r.last_compensation
                .as_ref()
                .map_or(String::new(), |m| m.date_utc.clone()),
            r.last_compensation
                .as_ref()
                .map_or(String::new(), |m| m.text.clone()),
            r.drift
                .as_ref()
                .map_or(String::new(), |d| if d.up { "up" } else { "down" }.into()),
            r.drift.as_ref().map_or(String::new(), |d| {
                d.run_ids
                    .iter()
                    .map(i64::to_string)
                    .collect::<Vec<_>>()
                    .join(" ")
            }),
        ];
        let line: Vec<String> = fields.iter().map(|f| trend::csv_field(f)).collect();
        let _ = writeln!(s, "{}", line.join(","));
    }
    s
}

/// `text` escaped for HTML.
fn html_escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The fleet view as one self-contained HTML page: a table, the drift alarms in red.
pub fn html(rows: &[Row], title: &str) -> String {
    let mut s = String::new();
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>\
         body{{font-family:sans-serif;margin:1.5em;color:#222}}\
         table{{border-collapse:collapse;font-size:14px}}\
         th,td{{border-bottom:1px solid #ccc;padding:4px 10px;text-align:left}}\
         th{{background:#eef}} td.num{{text-align:right;font-variant-numeric:tabular-nums}}\
         tr.drift td{{background:#fde8e8}} td.alarm{{color:#b00;font-weight:bold}}\
         tr.first td{{border-top:2px solid #888}}\
         </style></head><body>\n<h1>{t}</h1>\n<p>Drift alarm: CUSUM of each run's departure from the first run since the last compensation change, in σ (k = {CUSUM_K}, h = {CUSUM_H}).</p>\n<table>\n<tr><th>machine</th><th>quantity</th><th>unit</th><th>latest run</th><th>date</th><th>latest</th><th>slope per 30 days</th><th>tolerance µm</th><th>last compensation</th><th>drift</th></tr>\n",
        t = html_escape(title)
    );
    let mut previous = "";
    for r in rows {
        let p = r.latest();
        let mut class = vec![];
        if r.drift.is_some() {
            class.push("drift");
        }
        if r.machine != previous {
            class.push("first");
        }
        previous = &r.machine;
        let _ = writeln!(
            s,
            "<tr class=\"{}\"><td>{}</td><td>{}</td><td>{}</td><td class=\"num\">{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td class=\"{}\">{}</td></tr>",
            class.join(" "),
            html_escape(&r.machine),
            html_escape(&r.trend.name),
            html_escape(&human(&r.trend.unit)),
            p.map_or("-".into(), |p| p.run_id.to_string()),
            p.map_or("-", |p| &p.date_utc[..10.min(p.date_utc.len())]),
            html_escape(&latest_text(r)),
            html_escape(&slope_text(r)),
            r.tolerance_um.map_or("-".into(), |t| format!("{t}")),
            html_escape(&compensation_text(r)),
            if r.drift.is_some() { "alarm" } else { "" },
            html_escape(&drift_text(r)),
        );
    }
    s.push_str("</table>\n</body></html>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points(values: &[f64], sigma: f64) -> EffectTrend {
        EffectTrend {
            name: "backlash_x".into(),
            unit: "um".into(),
            points: values
                .iter()
                .enumerate()
                .map(|(k, v)| trend::Point {
                    run_id: k as i64 + 1,
                    date_utc: format!("2026-{:02}-01T00:00:00Z", k + 1),
                    value: Some(*v),
                    sigma: Some(sigma),
                    noise: None,
                    differences: vec![],
                })
                .collect(),
        }
    }

    #[test]
    fn cusum_flags_a_drift_names_its_runs_and_restarts_at_a_compensation() {
        // Steady within σ: no alarm, even over twelve runs.
        let calm = points(
            &[
                8.0, 8.1, 7.9, 8.05, 7.95, 8.1, 7.9, 8.0, 8.1, 7.95, 8.0, 8.05,
            ],
            0.1,
        );
        assert_eq!(drift(&calm, &[]), None);
        // From run 5 on the play grows by 0.2 µm a run (2 σ of a difference of two runs ≈ 1.4):
        // the alarm names the runs of the excursion, from run 5 on.
        let worn = points(&[8.0, 8.05, 7.95, 8.0, 8.2, 8.4, 8.6, 8.8, 9.0], 0.1);
        let d = drift(&worn, &[]).unwrap();
        assert!(d.up, "{d:?}");
        assert_eq!(d.run_ids.first(), Some(&5), "{d:?}");
        assert_eq!(d.run_ids.last(), Some(&9), "{d:?}");
        // Shrinking: flagged down.
        let down = points(&[8.0, 7.5, 7.0, 6.5], 0.1);
        assert!(!drift(&down, &[]).unwrap().up);
        // A compensation after run 6 restarts the sums: the runs after it are steady.
        let mark = Mark {
            date_utc: "2026-06-15T00:00:00Z".into(),
            text: "BACKLASH".into(),
            why: "test".into(),
        };
        let comp = points(&[8.0, 8.4, 8.8, 9.2, 9.6, 10.0, 2.0, 2.05, 1.95, 2.0], 0.1);
        assert!(drift(&comp, &[]).is_some());
        assert_eq!(drift(&comp, &[mark]), None);
    }
}
