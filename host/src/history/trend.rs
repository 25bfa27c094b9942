//! The trend of a machine's effects over its runs: each effect's value ± σ per run, whether the
//! run is comparable with the latest (and what differs if not), the change between the first and
//! the last comparable run; and the same as an SVG plot.
//!
//! A run in which an effect was not selected has no value for it: the effect was below what that
//! test could detect (shown as `not found`), which is not the same as zero.
use std::fmt::Write;
use std::path::Path;

use plotters::prelude::*;
use time::format_description::well_known::Rfc3339;
use time::OffsetDateTime;

use super::Run;
use crate::units::{format_estimate, format_to, human};
use crate::{Error, Result};

/// One run of one effect.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    pub run_id: i64,
    pub date_utc: String,
    pub value: Option<f64>,
    pub sigma: Option<f64>,
    /// What differs from the latest run (empty: comparable).
    pub differences: Vec<String>,
}

/// One effect over the runs.
#[derive(Debug, Clone, PartialEq)]
pub struct EffectTrend {
    pub name: String,
    pub unit: String,
    pub points: Vec<Point>,
}

impl EffectTrend {
    /// Last minus first comparable run that found the effect: (change, its σ, days between).
    pub fn change(&self) -> Option<(f64, Option<f64>, f64)> {
        let found: Vec<&Point> = self
            .points
            .iter()
            .filter(|p| p.differences.is_empty() && p.value.is_some())
            .collect();
        let (a, b) = (found.first()?, found.last()?);
        if a.run_id == b.run_id {
            return None;
        }
        let sigma = match (a.sigma, b.sigma) {
            (Some(x), Some(y)) => Some(x.hypot(y)),
            _ => None,
        };
        Some((
            b.value? - a.value?,
            sigma,
            days(&b.date_utc)? - days(&a.date_utc)?,
        ))
    }
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
    let mut names: Vec<(String, String)> = vec![];
    for r in runs {
        for e in &r.effects {
            if !names.iter().any(|(n, _)| *n == e.name) {
                names.push((e.name.clone(), e.unit.clone()));
            }
        }
    }
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
                        differences: r.conditions.differences(&latest.conditions),
                    }
                })
                .collect(),
            name,
            unit,
        })
        .collect())
}

/// The text of `jdbb history trend`.
pub fn render(machine: &str, runs: &[Run], trends: &[EffectTrend]) -> String {
    let mut s = String::new();
    let Some(latest) = runs.last() else {
        return format!("machine {machine}: no runs\n");
    };
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
    for t in trends {
        let _ = writeln!(s, "{} ({})", t.name, human(&t.unit));
        for p in &t.points {
            let v = match p.value {
                Some(v) => format_estimate(v, p.sigma),
                None => "not found".into(),
            };
            let flag = if p.differences.is_empty() {
                String::new()
            } else {
                format!("   not comparable: {}", p.differences.join("; "))
            };
            let _ = writeln!(s, "  {}  run {:<3} {v}{flag}", p.date_utc, p.run_id);
        }
        if let Some((d, sigma, dt)) = t.change() {
            let _ = writeln!(
                s,
                "  change over the comparable runs: {} {} in {dt:.0} days",
                format_estimate(d, sigma),
                human(&t.unit)
            );
        }
    }
    s
}

/// Plot the trends into an SVG file: one panel per effect, value ± σ against the date;
/// comparable runs filled, others hollow and grey.
pub fn plot_svg(file: &Path, machine: &str, trends: &[EffectTrend]) -> Result<()> {
    crate::circular::plot::register_font();
    let err = |e: &dyn std::fmt::Display| Error::Numerics(format!("plotting failed: {e}"));
    let panel_h = 260u32;
    let n = trends.len().max(1) as u32;
    let root = SVGBackend::new(file, (900, 40 + n * panel_h)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (title, body) = root.split_vertically(40);
    title
        .titled(
            &format!(
                "J-DBB history of {machine}: effects ± σ (filled: comparable with the latest run; hollow: not)"
            ),
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
    let first_date = trends
        .iter()
        .flat_map(|t| t.points.iter())
        .find(|p| days(&p.date_utc) == Some(d0))
        .map(|p| p.date_utc[..10.min(p.date_utc.len())].to_string())
        .unwrap_or_default();
    for (t, area) in trends.iter().zip(body.split_evenly((n as usize, 1))) {
        let pts: Vec<(f64, f64, f64, bool)> = t
            .points
            .iter()
            .filter_map(|p| {
                Some((
                    days(&p.date_utc)? - d0,
                    p.value?,
                    p.sigma.unwrap_or(0.0),
                    p.differences.is_empty(),
                ))
            })
            .collect();
        let lo = pts.iter().map(|p| p.1 - p.2).fold(f64::INFINITY, f64::min);
        let hi = pts
            .iter()
            .map(|p| p.1 + p.2)
            .fold(f64::NEG_INFINITY, f64::max);
        let (lo, hi) = if lo.is_finite() {
            let pad = ((hi - lo) * 0.15)
                .max(1e-3 * hi.abs().max(lo.abs()))
                .max(1e-6);
            (lo - pad, hi + pad)
        } else {
            (-1.0, 1.0)
        };
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
        let mut chart = ChartBuilder::on(&area)
            .caption(
                format!("{} ({})", t.name, human(&t.unit)),
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(32)
            .y_label_area_size(70)
            .build_cartesian_2d(x0..x1, lo..hi)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .light_line_style(WHITE.mix(0.0))
            .x_desc(format!("days since {first_date}"))
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format_to(*y, label_sigma))
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(|e| err(&e))?;
        if lo < 0.0 && hi > 0.0 {
            chart
                .draw_series(LineSeries::new([(x0, 0.0), (x1, 0.0)], BLACK.mix(0.3)))
                .map_err(|e| err(&e))?;
        }
        let blue = RGBColor(31, 119, 180);
        let grey = RGBColor(150, 150, 150);
        chart
            .draw_series(pts.iter().map(|&(x, v, s, ok)| {
                PathElement::new(
                    vec![(x, v - s), (x, v + s)],
                    if ok { blue } else { grey }.stroke_width(2),
                )
            }))
            .map_err(|e| err(&e))?;
        chart
            .draw_series(pts.iter().map(|&(x, v, _, ok)| {
                if ok {
                    Circle::new((x, v), 5, blue.filled())
                } else {
                    Circle::new((x, v), 5, grey.stroke_width(2))
                }
            }))
            .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
