//! The trend of a machine's effects over its runs: each effect's value ± σ per run, whether the
//! run is comparable with the latest (and what differs if not), the change between the first and
//! the last comparable run since the last compensation change, the slope per 30 days with its σ;
//! and the same as an SVG plot and a CSV file. Instead of the effects, the circular deviation G
//! or the hysteresis H of each run ([`Figure`]), which have no σ of their own.
//!
//! A run in which an effect was not selected has no value for it: the effect was below what that
//! test could detect (shown as `not found`), which is not the same as zero.
//!
//! # Compensation changes
//! A change of the machine's compensation changes what the test sees, so the trend marks it
//! ([`Mark`]): where a `jdbb history comp` event was filed, and between two runs whose
//! diagnoses state different compensations in force (`jdbb diagnose --compensation`). The slope
//! and the change are taken over the comparable runs **since the last mark** only (the text names
//! those runs and their dates, and the runs before the mark it leaves out); the text, the plot (a
//! dashed vertical line, named in the legend) and the CSV (`compensation_changed`) show the marks.
//!
//! # Slope
//! Least squares of value against time, in the trend's unit per 30 days ([`SLOPE_DAYS`]; the
//! same unit in the text and the plot's legend, which draws the fitted line over its runs), over
//! the comparable runs that found the effect since the last mark, weighted by 1/σ² where every
//! run has a σ. Its σ is the fit's, scaled up by √(χ²/(n − 2)) when the runs scatter more than
//! their σ say (n ≥ 3); without σ per run (G, H) it is the residual scatter's, which needs 3 runs.
use std::fmt::Write;
use std::path::Path;

use plotters::prelude::*;
use time::format_description::well_known::Rfc3339;
use time::OffsetDateTime;

use super::{printable, CompensationEvent, Run};
use crate::units::{format_estimate, format_to, human};
use crate::{Error, Result};

/// One run of one effect.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    pub run_id: i64,
    pub date_utc: String,
    pub value: Option<f64>,
    pub sigma: Option<f64>,
    /// Where the value has no σ of its own (G, H): the run's noise (its residual RMS, µm), the
    /// digits it is shown to.
    pub noise: Option<f64>,
    /// What differs from the latest run (empty: comparable).
    pub differences: Vec<String>,
}

impl Point {
    /// `value ± σ`, or the value to its noise's digits, or `not found`.
    fn text(&self) -> String {
        match (self.value, self.sigma, self.noise) {
            (None, _, _) => "not found".into(),
            (Some(v), None, Some(n)) => format_to(v, n),
            (Some(v), s, _) => format_estimate(v, s),
        }
    }
}

/// One effect over the runs.
#[derive(Debug, Clone, PartialEq)]
pub struct EffectTrend {
    pub name: String,
    pub unit: String,
    pub points: Vec<Point>,
}

/// The change of a trend between the first and the last of the runs its slope is fitted over.
#[derive(Debug, Clone, PartialEq)]
pub struct Change {
    /// Last minus first, in the trend's unit.
    pub value: f64,
    pub sigma: Option<f64>,
    /// Days between the two runs.
    pub days: f64,
    /// The first and the last run (id, date).
    pub from: (i64, String),
    pub to: (i64, String),
}

impl EffectTrend {
    /// The runs a change and a slope are taken over: comparable with the latest, found, and
    /// not before the last of `marks` (module docs).
    pub fn fitted(&self, marks: &[Mark]) -> Vec<&Point> {
        let since = marks.last().map(|m| m.date_utc.as_str());
        self.points
            .iter()
            .filter(|p| p.differences.is_empty() && p.value.is_some())
            .filter(|p| since.is_none_or(|s| p.date_utc.as_str() >= s))
            .filter(|p| days(&p.date_utc).is_some())
            .collect()
    }

    /// The comparable runs that found the effect but lie before the last of `marks`: left out
    /// of the change and the slope.
    pub fn before_last_mark(&self, marks: &[Mark]) -> Vec<i64> {
        let Some(since) = marks.last().map(|m| m.date_utc.as_str()) else {
            return vec![];
        };
        self.points
            .iter()
            .filter(|p| p.differences.is_empty() && p.value.is_some())
            .filter(|p| p.date_utc.as_str() < since)
            .map(|p| p.run_id)
            .collect()
    }

    /// Last minus first of the runs the slope is fitted over (comparable, since the last of
    /// `marks`), never across a compensation change.
    pub fn change(&self, marks: &[Mark]) -> Option<Change> {
        let found = self.fitted(marks);
        let (a, b) = (found.first()?, found.last()?);
        if a.run_id == b.run_id {
            return None;
        }
        let sigma = match (a.sigma, b.sigma) {
            (Some(x), Some(y)) => Some(x.hypot(y)),
            _ => None,
        };
        Some(Change {
            value: b.value? - a.value?,
            sigma,
            days: days(&b.date_utc)? - days(&a.date_utc)?,
            from: (a.run_id, a.date_utc.clone()),
            to: (b.run_id, b.date_utc.clone()),
        })
    }
}

/// The time unit of a slope: per 30 days (said so wherever a slope is shown).
pub const SLOPE_DAYS: f64 = 30.0;

/// A figure of the whole run to trend instead of the effects (`--figure`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Figure {
    /// The circular deviation G (the largest minimum-zone G of a circle and direction).
    G,
    /// The hysteresis H (the largest of a circle).
    H,
}

impl Figure {
    /// `g` or `h`, any case; the error says what to give.
    pub fn parse(s: &str) -> Result<Figure> {
        match s.trim().to_ascii_lowercase().as_str() {
            "g" => Ok(Figure::G),
            "h" => Ok(Figure::H),
            _ => Err(Error::Usage(format!(
                "--figure {s}: give g (circular deviation G) or h (hysteresis H)"
            ))),
        }
    }

    /// The name a trend of it carries (the diagnosis JSON's, without the unit).
    pub fn name(self) -> &'static str {
        match self {
            Figure::G => "circular_deviation_g",
            Figure::H => "hysteresis_h",
        }
    }
}

/// The trend of G or H over `runs` (oldest first): σ per run is not known (its digits are the
/// run's noise).
pub fn figure_trend(runs: &[Run], figure: Figure) -> Vec<EffectTrend> {
    let Some(latest) = runs.last() else {
        return vec![];
    };
    vec![EffectTrend {
        name: figure.name().into(),
        unit: "um".into(),
        points: runs
            .iter()
            .map(|r| Point {
                run_id: r.id,
                date_utc: r.date_utc.clone(),
                value: match figure {
                    Figure::G => r.g_um,
                    Figure::H => r.h_um,
                },
                sigma: None,
                noise: r.final_rms_um,
                differences: r.conditions.differences(&latest.conditions),
            })
            .collect(),
    }]
}

/// A change of the compensation in force (module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Mark {
    pub date_utc: String,
    /// What is in force from then on (the first line, for people).
    pub text: String,
    /// Where the mark comes from, in words.
    pub why: String,
}

/// The compensation changes of a machine: its `history comp` events and the runs whose stated
/// compensation differs from the run before (when both state one and no event lies between),
/// by date.
pub fn compensation_marks(runs: &[Run], events: &[CompensationEvent]) -> Vec<Mark> {
    let first_line = |t: &str| {
        let l = t
            .lines()
            .find(|l| !l.trim().is_empty())
            .unwrap_or("")
            .trim();
        let more = t.lines().filter(|l| !l.trim().is_empty()).count() > 1;
        format!("{l}{}", if more { " …" } else { "" })
    };
    let mut marks: Vec<Mark> = events
        .iter()
        .map(|e| Mark {
            date_utc: e.date_utc.clone(),
            text: first_line(&e.text),
            why: format!("history comp {}", e.id),
        })
        .collect();
    for w in runs.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        let (Some(ca), Some(cb)) = (&a.compensation, &b.compensation) else {
            continue;
        };
        let between = events
            .iter()
            .any(|e| e.date_utc > a.date_utc && e.date_utc <= b.date_utc);
        if ca.trim() != cb.trim() && !between {
            marks.push(Mark {
                date_utc: b.date_utc.clone(),
                text: first_line(cb),
                why: format!("run {} states another compensation than run {}", b.id, a.id),
            });
        }
    }
    marks.sort_by(|x, y| x.date_utc.cmp(&y.date_utc));
    marks
}

/// Run ids as the text and the plot name them: `1, 2, 4`.
fn id_list(ids: &[i64]) -> String {
    ids.iter()
        .map(i64::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// A slope per 30 days and its σ (module docs, *Slope*).
#[derive(Debug, Clone, PartialEq)]
pub struct Slope {
    /// In the trend's unit per [`SLOPE_DAYS`] days.
    pub per_30_days: f64,
    pub sigma: Option<f64>,
    /// The runs it was fitted over, oldest first.
    pub run_ids: Vec<i64>,
    /// The first and the last of their dates.
    pub from_date: String,
    pub to_date: String,
    /// The mark it starts after, if any.
    pub since: Option<String>,
    /// The fitted line passes through (`mean_day`, `mean_value`): days since 1970 and the
    /// trend's unit (the weighted means).
    pub mean_day: f64,
    pub mean_value: f64,
}

impl Slope {
    /// The fitted line's value on `day` (days since 1970).
    pub fn at(&self, day: f64) -> f64 {
        self.mean_value + self.per_30_days * (day - self.mean_day) / SLOPE_DAYS
    }
}

impl EffectTrend {
    /// The slope over the comparable runs since the last of `marks` (module docs).
    pub fn slope(&self, marks: &[Mark]) -> Option<Slope> {
        let since = marks.last().map(|m| m.date_utc.clone());
        let fitted = self.fitted(marks);
        let pts: Vec<(f64, f64, Option<f64>)> = fitted
            .iter()
            .filter_map(|p| Some((days(&p.date_utc)? / SLOPE_DAYS, p.value?, p.sigma)))
            .collect();
        let n = pts.len();
        if n < 2 {
            return None;
        }
        let weighted = pts.iter().all(|p| p.2.is_some_and(|s| s > 0.0));
        let w = |p: &(f64, f64, Option<f64>)| {
            if weighted {
                p.2.map_or(1.0, |s| 1.0 / (s * s))
            } else {
                1.0
            }
        };
        let sw: f64 = pts.iter().map(w).sum();
        let mx = pts.iter().map(|p| w(p) * p.0).sum::<f64>() / sw;
        let my = pts.iter().map(|p| w(p) * p.1).sum::<f64>() / sw;
        let sxx: f64 = pts.iter().map(|p| w(p) * (p.0 - mx).powi(2)).sum();
        if sxx <= 0.0 {
            return None;
        }
        let slope = pts
            .iter()
            .map(|p| w(p) * (p.0 - mx) * (p.1 - my))
            .sum::<f64>()
            / sxx;
        let chi2: f64 = pts
            .iter()
            .map(|p| w(p) * (p.1 - my - slope * (p.0 - mx)).powi(2))
            .sum();
        let sigma = if weighted {
            let scale = if n >= 3 {
                (chi2 / (n - 2) as f64).max(1.0)
            } else {
                1.0
            };
            Some((scale / sxx).sqrt())
        } else if n >= 3 {
            Some((chi2 / (n - 2) as f64 / sxx).sqrt())
        } else {
            None
        };
        Some(Slope {
            per_30_days: slope,
            sigma,
            run_ids: fitted.iter().map(|p| p.run_id).collect(),
            from_date: fitted.first()?.date_utc.clone(),
            to_date: fitted.last()?.date_utc.clone(),
            since,
            mean_day: mx * SLOPE_DAYS,
            mean_value: my,
        })
    }
}

/// The day (YYYY-MM-DD) of an RFC 3339 date.
fn day(date: &str) -> &str {
    date.get(..10).unwrap_or(date)
}

/// Days since 1970 of an RFC 3339 date.
fn days(date: &str) -> Option<f64> {
    OffsetDateTime::parse(date, &Rfc3339)
        .ok()
        .map(|t| t.unix_timestamp() as f64 / 86_400.0)
}

/// The trend of every machine effect in `runs` (oldest first), or only of `effect`.
pub fn trend(runs: &[Run], effect: Option<&str>) -> Result<Vec<EffectTrend>> {
    let Some(latest) = runs.last() else {
        return Ok(vec![]);
    };
    let mut names = super::effect_order(runs);
    if let Some(want) = effect {
        if !names.iter().any(|(n, _)| n == want) {
            return Err(Error::Usage(format!(
                "--effect {want}: no run of this machine found it; found: {}",
                if names.is_empty() {
                    "no machine effect at all".to_string()
                } else {
                    names
                        .iter()
                        .map(|(n, _)| n.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            )));
        }
        names.retain(|(n, _)| n == want);
    }
    Ok(names
        .into_iter()
        .map(|(name, unit)| EffectTrend {
            points: runs
                .iter()
                .map(|r| {
                    let e = r.effects.iter().find(|e| e.name == name);
                    Point {
                        run_id: r.id,
                        date_utc: r.date_utc.clone(),
                        value: e.and_then(|e| e.value),
                        sigma: e.and_then(|e| e.sigma),
                        noise: None,
                        differences: r.conditions.differences(&latest.conditions),
                    }
                })
                .collect(),
            name,
            unit,
        })
        .collect())
}

/// The text of `jdbb history trend`: per trend its runs with the compensation marks among
/// them by date, the change and the slope over the comparable runs, and the runs over
/// `tolerance_um` (applied to values in µm, by magnitude).
pub fn render(
    machine: &str,
    runs: &[Run],
    trends: &[EffectTrend],
    marks: &[Mark],
    tolerance_um: Option<f64>,
) -> String {
    let mut s = String::new();
    let Some(latest) = runs.last() else {
        return format!("machine {}: no runs\n", printable(machine));
    };
    let machine = printable(machine);
    let _ = writeln!(
        s,
        "machine {machine}: {} runs; compared with the latest (run {}, {})",
        runs.len(),
        latest.id,
        latest.date_utc
    );
    if trends.is_empty() {
        let _ = writeln!(s, "no machine effect was found in any run");
    }
    let mark_line = |s: &mut String, m: &Mark| {
        let _ = writeln!(
            s,
            "  {}  -- compensation changed: {} ({})",
            m.date_utc,
            printable(&m.text),
            m.why
        );
    };
    for t in trends {
        let _ = writeln!(s, "{} ({})", printable(&t.name), human(&t.unit));
        let mut next_mark = 0;
        for p in &t.points {
            while let Some(m) = marks.get(next_mark).filter(|m| m.date_utc <= p.date_utc) {
                mark_line(&mut s, m);
                next_mark += 1;
            }
            let v = p.text();
            let flag = if p.differences.is_empty() {
                String::new()
            } else {
                format!("   not comparable: {}", p.differences.join("; "))
            };
            let _ = writeln!(s, "  {}  run {:<3} {v}{flag}", p.date_utc, p.run_id);
        }
        for m in &marks[next_mark.min(marks.len())..] {
            mark_line(&mut s, m);
        }
        // Without σ (G, H): the digits of the noisiest run.
        let noise = t.points.iter().filter_map(|p| p.noise).reduce(f64::max);
        let estimate = |x: f64, sigma: Option<f64>| match (sigma, noise) {
            (None, Some(n)) => format_to(x, n),
            _ => format_estimate(x, sigma),
        };
        let since = marks.last().map_or(String::new(), |m| {
            format!(" since the compensation change of {}", day(&m.date_utc))
        });
        if let Some(c) = t.change(marks) {
            let _ = writeln!(
                s,
                "  change from run {} ({}) to run {} ({}), the first and the last comparable run{since}: {} {} in {:.0} days",
                c.from.0,
                day(&c.from.1),
                c.to.0,
                day(&c.to.1),
                estimate(c.value, c.sigma),
                human(&t.unit),
                c.days
            );
        }
        match t.slope(marks) {
            Some(sl) => {
                let _ = writeln!(
                    s,
                    "  slope over the {} comparable runs{since} (runs {} from {} to {}): {} {} per {SLOPE_DAYS} days{}",
                    sl.run_ids.len(),
                    id_list(&sl.run_ids),
                    day(&sl.from_date),
                    day(&sl.to_date),
                    estimate(sl.per_30_days, sl.sigma),
                    human(&t.unit),
                    if sl.sigma.is_none() {
                        " (σ needs a third run)"
                    } else {
                        ""
                    }
                );
            }
            None if !marks.is_empty() => {
                let _ = writeln!(
                    s,
                    "  slope: fewer than 2 comparable runs since the last compensation change"
                );
            }
            None => {}
        }
        let before = t.before_last_mark(marks);
        if let (false, Some(m)) = (before.is_empty(), marks.last()) {
            let _ = writeln!(
                s,
                "  run{} {}: before the compensation change of {}, not compared across it",
                if before.len() > 1 { "s" } else { "" },
                id_list(&before),
                day(&m.date_utc)
            );
        }
        if let Some(tol) = tolerance_um {
            if t.unit != "um" {
                let _ = writeln!(
                    s,
                    "  tolerance {tol} µm: not applied ({} is in {})",
                    t.name,
                    human(&t.unit)
                );
                continue;
            }
            let over: Vec<String> = t
                .points
                .iter()
                .filter(|p| p.value.is_some_and(|v| v.abs() > tol))
                .map(|p| p.run_id.to_string())
                .collect();
            let _ = writeln!(
                s,
                "  tolerance {tol} µm: {}",
                if over.is_empty() {
                    "every run within it".to_string()
                } else {
                    format!("over it in run {}", over.join(", "))
                }
            );
        }
    }
    s
}

/// `text` as one CSV field: quoted (with `""` for a quote) where it holds a comma, a quote or a
/// line break.
pub fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_string()
    }
}

/// The trend as CSV (`--csv FILE`), one row per run and trend: `machine, quantity, unit, run,
/// date_utc, value, sigma, comparable` (with what differs if not), `compensation_changed` (a
/// mark lies after the previous run, up to this one) and `compensation` (in force, as the
/// run's diagnosis states it). Empty `value`: not found; empty `sigma`: not known.
pub fn csv(machine: &str, runs: &[Run], trends: &[EffectTrend], marks: &[Mark]) -> String {
    let mut s = String::from(
        "machine,quantity,unit,run,date_utc,value,sigma,comparable,differences,compensation_changed,compensation\n",
    );
    let num = |x: Option<f64>| x.map_or(String::new(), |v| format!("{v}"));
    for t in trends {
        let mut prev: Option<&str> = None;
        for p in &t.points {
            let changed = marks.iter().any(|m| {
                m.date_utc.as_str() <= p.date_utc.as_str()
                    && prev.is_none_or(|d| m.date_utc.as_str() > d)
            });
            let comp = runs
                .iter()
                .find(|r| r.id == p.run_id)
                .and_then(|r| r.compensation.as_deref())
                .unwrap_or("");
            let _ = writeln!(
                s,
                "{},{},{},{},{},{},{},{},{},{},{}",
                csv_field(machine),
                csv_field(&t.name),
                t.unit,
                p.run_id,
                p.date_utc,
                num(p.value),
                num(p.sigma),
                p.differences.is_empty(),
                csv_field(&p.differences.join("; ")),
                changed,
                csv_field(comp.trim_end())
            );
            prev = Some(&p.date_utc);
        }
    }
    s
}

/// The value axis of a panel whose data (with σ and tolerance lines) span `lo..hi` (infinite:
/// no data), padded a little. The axis' ticks are counted from its range: a range that is
/// finite, and wide against its values (a thousandth of their size at least), keeps that count
/// small and finite.
fn axis_range(lo: f64, hi: f64) -> (f64, f64) {
    let (lo, hi) = if lo.is_finite() && hi.is_finite() && lo <= hi {
        let pad = ((hi - lo) * 0.08)
            .max(1e-3 * hi.abs().max(lo.abs()))
            .max(1e-6);
        (lo - pad, hi + pad)
    } else {
        (-1.0, 1.0)
    };
    if (hi - lo).is_finite() && hi > lo {
        (lo, hi)
    } else {
        (-1.0, 1.0)
    }
}

/// How a run stands in a trend's plot: comparable and in the slope, comparable but before the
/// last compensation change (left out, as the text leaves it out), or not comparable.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Standing {
    Fitted,
    BeforeMark,
    NotComparable,
}

/// What a legend line shows beside its text.
#[derive(Clone, Copy)]
enum Symbol {
    Line(RGBColor),
    Dashed(RGBColor),
    Dot(RGBColor),
    Ring(RGBColor),
}

/// Height of one legend line under a panel, in pixels.
const LEGEND_LINE_PX: u32 = 16;

/// Draw `entries` (symbol, text) one per line in `area`, the legend under a panel's plot.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    entries: &[(Symbol, String)],
) -> std::result::Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let style = ("sans-serif", 12).into_font().color(&BLACK);
    for (k, (symbol, text)) in entries.iter().enumerate() {
        let y = 8 + k as i32 * LEGEND_LINE_PX as i32;
        let (x0, x1) = (80, 100);
        match *symbol {
            Symbol::Line(c) => {
                area.draw(&PathElement::new(vec![(x0, y), (x1, y)], c.stroke_width(2)))?
            }
            Symbol::Dashed(c) => {
                for x in [x0, x0 + 8, x0 + 16] {
                    area.draw(&PathElement::new(
                        vec![(x, y), (x + 4, y)],
                        c.stroke_width(2),
                    ))?;
                }
            }
            Symbol::Dot(c) => area.draw(&Circle::new((x0 + 10, y), 5, c.filled()))?,
            Symbol::Ring(c) => area.draw(&Circle::new((x0 + 10, y), 5, c.stroke_width(2)))?,
        }
        area.draw(&Text::new(text.clone(), (x1 + 8, y - 7), style.clone()))?;
    }
    Ok(())
}

/// The date (YYYY-MM-DD, UTC) `day` days after the day `d0` (days since 1970).
fn date_of_day(d0: f64, day: f64) -> String {
    OffsetDateTime::from_unix_timestamp(((d0 + day) * 86_400.0).round() as i64)
        .map(|t| t.date().to_string())
        .unwrap_or_default()
}

/// Plot the trends into an SVG file: one panel per effect, value (± σ where it has one) against
/// the date; runs in the slope filled, those before the last compensation change hollow blue and
/// those not comparable hollow grey (both left out of the slope, as the text leaves them out);
/// the fitted slope as a line over the runs it was fitted on; compensation marks as dashed
/// vertical lines, the tolerance (on values in µm) as red lines at ± it (+ only for G and H);
/// each named in the legend under the panel's plot, outside the data.
pub fn plot_svg(
    file: &Path,
    machine: &str,
    trends: &[EffectTrend],
    marks: &[Mark],
    tolerance_um: Option<f64>,
) -> Result<()> {
    crate::report::plot::register_font();
    let err = |e: &dyn std::fmt::Display| Error::Numerics(format!("plotting failed: {e}"));
    // The plot, and under it room for the most legend lines a panel can have: the tolerance,
    // the marks, the slope and three kinds of run.
    let plot_h = 300u32;
    let panel_h = plot_h + LEGEND_LINE_PX * (marks.len() as u32 + 5) + 10;
    let n = trends.len().max(1) as u32;
    let root = SVGBackend::new(file, (900, 40 + n * panel_h)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (title, body) = root.split_vertically(40);
    title
        .titled(
            &format!("J-DBB history of {}", printable(machine)),
            ("sans-serif", 17),
        )
        .map_err(|e| err(&e))?;
    let all_days: Vec<f64> = trends
        .iter()
        .flat_map(|t| t.points.iter().filter_map(|p| days(&p.date_utc)))
        .collect();
    let d0 = all_days.iter().cloned().fold(f64::INFINITY, f64::min);
    let d1 = all_days.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    let (x0, x1) = if d0.is_finite() {
        let pad = ((d1 - d0) * 0.08).max(1.0);
        (-pad, d1 - d0 + pad)
    } else {
        (-1.0, 1.0)
    };
    for (t, panel) in trends.iter().zip(body.split_evenly((n as usize, 1))) {
        let (area, legend_area) = panel.split_vertically(plot_h);
        let mut legend: Vec<(Symbol, String)> = vec![];
        // Only values a history can hold (a run filed before `history add` bounded them may
        // hold ±1e308, which would leave the axis no finite range): the others are not drawn,
        // and said so in the panel's caption.
        let plottable = |x: f64| x.is_finite() && x.abs() <= super::MAX_VALUE;
        let before = t.before_last_mark(marks);
        let pts: Vec<(f64, f64, f64, Standing)> = t
            .points
            .iter()
            .filter_map(|p| {
                Some((
                    days(&p.date_utc)? - d0,
                    p.value.filter(|v| plottable(*v))?,
                    p.sigma.filter(|s| plottable(*s)).unwrap_or(0.0).abs(),
                    if !p.differences.is_empty() {
                        Standing::NotComparable
                    } else if before.contains(&p.run_id) {
                        Standing::BeforeMark
                    } else {
                        Standing::Fitted
                    },
                ))
            })
            .collect();
        let not_drawn = t
            .points
            .iter()
            .filter(|p| p.value.is_some_and(|v| !plottable(v)))
            .count();
        let tol = tolerance_um.filter(|_| t.unit == "um");
        let figure = t.name == Figure::G.name() || t.name == Figure::H.name();
        let tol_lines: Vec<f64> = match tol {
            Some(v) if figure => vec![v],
            Some(v) => vec![v, -v],
            None => vec![],
        };
        let lo = pts
            .iter()
            .map(|p| p.1 - p.2)
            .chain(tol_lines.iter().copied())
            .fold(f64::INFINITY, f64::min);
        let hi = pts
            .iter()
            .map(|p| p.1 + p.2)
            .chain(tol_lines.iter().copied())
            .fold(f64::NEG_INFINITY, f64::max);
        let (lo, hi) = axis_range(lo, hi);
        // Axis labels to the digits of the panel's smallest σ, or of its tick spacing where that
        // is coarser (about a tenth of the range).
        let smallest_sigma = pts
            .iter()
            .map(|p| p.2)
            .filter(|s| *s > 0.0)
            .fold(f64::INFINITY, f64::min);
        let tick = (hi - lo) / 20.0;
        let label_sigma = if smallest_sigma.is_finite() {
            smallest_sigma.max(tick)
        } else {
            tick
        };
        let has_sigma = pts.iter().any(|p| p.2 > 0.0);
        let unit = human(&t.unit);
        let slope = t.slope(marks);
        let fitted_line: Vec<(f64, f64)> = slope
            .as_ref()
            .and_then(|sl| {
                let a = days(&sl.from_date)?;
                let b = days(&sl.to_date)?;
                let line = vec![(a - d0, sl.at(a)), (b - d0, sl.at(b))];
                line.iter().all(|p| plottable(p.1)).then_some(line)
            })
            .unwrap_or_default();
        let mut chart = ChartBuilder::on(&area)
            .caption(
                format!(
                    "{} ({unit}){}{}",
                    printable(&t.name),
                    if has_sigma { ", value ± σ" } else { "" },
                    if not_drawn > 0 {
                        format!(
                            ", {not_drawn} run(s) beyond ±{:e} not drawn",
                            super::MAX_VALUE
                        )
                    } else {
                        String::new()
                    }
                ),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(32)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, lo..hi)
            .map_err(|e| err(&e))?;
        let date_label = |x: &f64| date_of_day(d0, *x);
        chart
            .configure_mesh()
            .light_line_style(WHITE.mix(0.0))
            .x_desc("date (UTC)")
            .x_labels(6)
            .x_label_formatter(&date_label)
            .y_label_formatter(&|y| format_to(*y, label_sigma))
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(|e| err(&e))?;
        if lo < 0.0 && hi > 0.0 {
            chart
                .draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], BLACK.mix(0.3)))
                .map_err(|e| err(&e))?;
        }
        let red = RGBColor(200, 30, 30);
        for v in &tol_lines {
            chart
                .draw_series(LineSeries::new([(x0, *v), (x1, *v)], red.stroke_width(2)))
                .map_err(|e| err(&e))?;
        }
        if let Some(v) = tol_lines.first() {
            legend.push((
                Symbol::Line(red),
                format!(
                    "tolerance {}{} µm",
                    if tol_lines.len() > 1 { "±" } else { "" },
                    v.abs()
                ),
            ));
        }
        let orange = RGBColor(230, 120, 0);
        for m in marks {
            let Some(x) = days(&m.date_utc).map(|d| d - d0) else {
                continue;
            };
            // Dashed: short segments up the panel.
            let n = 24;
            chart
                .draw_series((0..n).step_by(2).map(|k| {
                    let y = |k: usize| lo + (hi - lo) * k as f64 / n as f64;
                    PathElement::new(vec![(x, y(k)), (x, y(k + 1))], orange.stroke_width(2))
                }))
                .map_err(|e| err(&e))?;
            legend.push((
                Symbol::Dashed(orange),
                format!(
                    "compensation changed {}: {}",
                    day(&m.date_utc),
                    printable(&m.text)
                ),
            ));
        }
        let green = RGBColor(20, 140, 60);
        if let (Some(sl), false) = (&slope, fitted_line.is_empty()) {
            let noise = t.points.iter().filter_map(|p| p.noise).reduce(f64::max);
            let value = match (sl.sigma, noise) {
                (None, Some(n)) => format_to(sl.per_30_days, n),
                _ => format_estimate(sl.per_30_days, sl.sigma),
            };
            chart
                .draw_series(LineSeries::new(fitted_line, green.stroke_width(2)))
                .map_err(|e| err(&e))?;
            legend.push((
                Symbol::Line(green),
                format!(
                    "fitted slope {value} {unit} per {SLOPE_DAYS} days (runs {}, {} to {})",
                    id_list(&sl.run_ids),
                    day(&sl.from_date),
                    day(&sl.to_date)
                ),
            ));
        }
        let blue = RGBColor(31, 119, 180);
        let grey = RGBColor(150, 150, 150);
        let colour = |s: Standing| {
            if s == Standing::NotComparable {
                grey
            } else {
                blue
            }
        };
        chart
            .draw_series(pts.iter().map(|&(x, v, s, standing)| {
                PathElement::new(
                    vec![(x, v - s), (x, v + s)],
                    colour(standing).stroke_width(2),
                )
            }))
            .map_err(|e| err(&e))?;
        let what = if has_sigma { "run, value ± σ" } else { "run" };
        for (standing, symbol, words) in [
            (
                Standing::Fitted,
                Symbol::Dot(blue),
                "comparable with the latest",
            ),
            (
                Standing::BeforeMark,
                Symbol::Ring(blue),
                "before the last compensation change (left out of the slope)",
            ),
            (
                Standing::NotComparable,
                Symbol::Ring(grey),
                "not comparable (left out of the slope)",
            ),
        ] {
            let these: Vec<(f64, f64)> = pts
                .iter()
                .filter(|p| p.3 == standing)
                .map(|p| (p.0, p.1))
                .collect();
            if these.is_empty() && standing != Standing::Fitted {
                continue;
            }
            chart
                .draw_series(these.iter().map(|&(x, v)| match symbol {
                    Symbol::Dot(c) => Circle::new((x, v), 5, c.filled()),
                    _ => Circle::new((x, v), 5, colour(standing).stroke_width(2)),
                }))
                .map_err(|e| err(&e))?;
            legend.push((symbol, format!("{what}, {words}")));
        }
        draw_legend(&legend_area, &legend).map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trend(points: &[(&str, f64, Option<f64>)]) -> EffectTrend {
        EffectTrend {
            name: "circular_deviation_g".into(),
            unit: "um".into(),
            points: points
                .iter()
                .enumerate()
                .map(|(k, (d, v, s))| Point {
                    run_id: k as i64 + 1,
                    date_utc: format!("{d}T00:00:00Z"),
                    value: Some(*v),
                    sigma: *s,
                    noise: None,
                    differences: vec![],
                })
                .collect(),
        }
    }

    /// The numbers of attribute `name` of every `<tag` element in `svg`.
    fn attr(svg: &str, tag: &str, name: &str) -> Vec<(f64, String)> {
        svg.split(&format!("<{tag} "))
            .skip(1)
            .filter_map(|el| {
                let v = el.split(&format!("{name}=\"")).nth(1)?.split('"').next()?;
                Some((v.parse().ok()?, el.to_string()))
            })
            .collect()
    }

    #[test]
    fn the_plot_dates_its_axis_keeps_its_legend_off_the_data_and_draws_runs_left_out_hollow() {
        // Four runs, the compensation changed between the second and the third: the first two
        // are left out of the slope (as the text leaves them out) and drawn so.
        let t = trend(&[
            ("2026-09-01", 9.0, Some(0.1)),
            ("2026-10-01", 10.0, Some(0.1)),
            ("2026-11-01", 2.0, Some(0.1)),
            ("2026-12-01", 2.5, Some(0.1)),
        ]);
        let mark = Mark {
            date_utc: "2026-10-15T00:00:00Z".into(),
            text: "BACKLASH 0.01".into(),
            why: "test".into(),
        };
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("t.svg");
        plot_svg(&file, "mill", &[t], std::slice::from_ref(&mark), Some(4.0)).unwrap();
        let svg = std::fs::read_to_string(&file).unwrap();
        assert!(!svg.contains("days since"), "dates, not days since");
        assert!(svg.contains("\n2026-10-"), "ticks as dates: {svg}");
        assert!(svg.contains("date (UTC)"));
        // The legend is drawn after the data, its first line the tolerance: every run's marker
        // lies above every legend line, so the legend covers no data.
        let (data, legend) = svg.split_at(svg.find("\ntolerance 4 µm").unwrap());
        let runs = attr(data, "circle", "cy");
        assert_eq!(runs.len(), 4, "{svg}");
        let lowest_run = runs.iter().map(|c| c.0).fold(f64::MIN, f64::max);
        let first_legend_line = attr(&svg, "text", "y")
            .into_iter()
            .filter(|(_, el)| el.contains("\ntolerance 4 µm") || el.contains("\nfitted slope"))
            .map(|(y, _)| y)
            .fold(f64::MAX, f64::min);
        assert!(
            first_legend_line > lowest_run + 5.0,
            "legend from {first_legend_line}, runs down to {lowest_run}"
        );
        assert!(legend.contains("\nfitted slope"));
        // Filled: the two runs of the slope; hollow: the two before the change.
        let hollow = runs
            .iter()
            .filter(|c| c.1.contains("fill=\"none\""))
            .count();
        assert_eq!(hollow, 2, "{svg}");
        let hollow_dates: Vec<f64> = runs
            .iter()
            .filter(|c| c.1.contains("fill=\"none\""))
            .filter_map(|c| c.1.split("cx=\"").nth(1)?.split('"').next()?.parse().ok())
            .collect();
        let filled_dates: Vec<f64> = runs
            .iter()
            .filter(|c| !c.1.contains("fill=\"none\""))
            .filter_map(|c| c.1.split("cx=\"").nth(1)?.split('"').next()?.parse().ok())
            .collect();
        assert!(
            hollow_dates
                .iter()
                .all(|h| filled_dates.iter().all(|f| h < f)),
            "the hollow runs are the earlier ones: {svg}"
        );
        assert!(svg.contains("before the last compensation change (left out of the slope)"));
    }

    #[test]
    fn slope_per_30_days_and_its_sigma() {
        // 2 µm in 30 days, two runs without σ per run: the slope, no σ.
        let t = trend(&[("2026-01-01", 1.0, None), ("2026-01-31", 3.0, None)]);
        let s = t.slope(&[]).unwrap();
        assert!((s.per_30_days - 2.0).abs() < 1e-9, "{s:?}");
        assert_eq!(s.sigma, None, "two runs without σ: no σ");
        // Scatter about a line: σ from the residuals, √(RSS/(n−2)/Sxx).
        let t = trend(&[
            ("2026-01-01", 0.0, None),
            ("2026-01-31", 1.0, None),
            ("2026-03-02", 1.0, None),
        ]);
        let s = t.slope(&[]).unwrap();
        let x: Vec<f64> = [0.0, 30.0, 60.0].iter().map(|d| d / 30.0).collect();
        let sxx: f64 = x.iter().map(|v| (v - x[1]).powi(2)).sum();
        let slope = (x[2] - x[1]) / sxx;
        let res: Vec<f64> = [0.0, 1.0, 1.0]
            .iter()
            .zip(&x)
            .map(|(y, xi)| y - (2.0 / 3.0) - slope * (xi - x[1]))
            .collect();
        let want = (res.iter().map(|r| r * r).sum::<f64>() / sxx).sqrt();
        assert!((s.per_30_days - slope).abs() < 1e-9 && (s.sigma.unwrap() - want).abs() < 1e-9);
        // Weighted: runs with σ that agree with the line keep the fit's σ, √(1/Σw(x−x̄)²).
        let t = trend(&[
            ("2026-01-01", 0.0, Some(0.1)),
            ("2026-01-31", 1.0, Some(0.1)),
            ("2026-03-02", 2.0, Some(0.1)),
        ]);
        let s = t.slope(&[]).unwrap();
        assert!((s.per_30_days - 1.0).abs() < 1e-9);
        assert!(
            (s.sigma.unwrap() - (0.01 / sxx).sqrt()).abs() < 1e-12,
            "{s:?}"
        );
        // Only since the last mark.
        let mark = Mark {
            date_utc: "2026-01-15T00:00:00Z".into(),
            text: "x".into(),
            why: "test".into(),
        };
        assert_eq!(
            t.slope(std::slice::from_ref(&mark)).unwrap().run_ids.len(),
            2
        );
        // The fitted line (drawn on the plot) passes through the runs that lie on it.
        let d0 = days("2026-01-01T00:00:00Z").unwrap();
        assert!(
            s.at(d0).abs() < 1e-9 && (s.at(d0 + 60.0) - 2.0).abs() < 1e-9,
            "{s:?}"
        );
        // The change over the whole trend, then only since the mark (never across it).
        let c = t.change(&[]).unwrap();
        assert_eq!((c.from.0, c.to.0, c.value, c.days), (1, 3, 2.0, 60.0));
        let c = t.change(std::slice::from_ref(&mark)).unwrap();
        assert_eq!((c.from.0, c.to.0, c.value, c.days), (2, 3, 1.0, 30.0));
        assert_eq!(t.before_last_mark(&[mark]), vec![1]);
    }
}
