//! `report.html`: the report a person reads, files or shows. One self-contained page: inline
//! CSS, the polar plots as inline SVG, nothing fetched.
//!
//! What it says, in order: the verdict against the tolerance; the test conditions (machine,
//! date, plane, circles with radius, height and feed, instrument calibration, and the ISO 230-4
//! items: operator, instrument serial, machine and instrument temperatures, the table ball in
//! machine coordinates, the compensation in force, each "not given" when absent; the plan as a
//! table); the machine
//! effects ranked by their share of the error, each with value ± standard error and its cause
//! in the trade's words ([`crate::model::words`]); G and H of every circle per ISO 230-4 with the
//! minimum-zone centre ([`crate::diagnose::zone`]); the polar plot of every circle.
//!
//! Definitions the page states too:
//! - *share of the error* of an effect: the mean square of the radial deviation that effect
//!   alone makes (after the same set-up removal as the plot), over the sum of that of every
//!   machine effect and the residual's (JSON `effects[].share`, `residual_share`): the shares
//!   add up to 100 %, shown as whole percentages rounded by largest remainder;
//! - *G*: one per circle and direction, the minimum zone's (the same figure as the text and the
//!   plots); figures without a ± of their own are shown to the digits the test's noise supports;
//! - *F*: ISO 230-4 radial deviation, max and min per circle and direction
//!   ([`crate::report::radial_deviation_f`]);
//! - *pass*: every circle's G (each direction, minimum-zone centre) is at most the tolerance.
//!
//! The page is built from the diagnosis JSON read back as a [`DiagnosisDoc`] (so it shows what
//! the file says) and from the [`Diagnosis`] for the plotted traces.
use std::fmt::Write;

use crate::diagnose::Diagnosis;
use crate::model::words::cause;
use crate::report::document::{CircleDoc, DiagnosisDoc, ZoneDoc};
use crate::report::plot::{polar_svg, View};
use crate::report::split_percentages;
use crate::units::{format_estimate, format_to, human};
use crate::Result;

/// `text` with the five HTML special characters escaped.
pub fn escape(text: &str) -> String {
    let mut s = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => s.push_str("&amp;"),
            '<' => s.push_str("&lt;"),
            '>' => s.push_str("&gt;"),
            '"' => s.push_str("&quot;"),
            '\'' => s.push_str("&#39;"),
            c => s.push(c),
        }
    }
    s
}

/// The verdict of a diagnosis file against its tolerance: Some(pass) if a tolerance was given.
pub fn verdict(doc: &DiagnosisDoc) -> Option<bool> {
    doc.tolerance.as_ref().map(|t| t.pass)
}

const STYLE: &str = "
body { font-family: 'DejaVu Sans', Arial, sans-serif; margin: 24px auto; max-width: 1100px;
       color: #222; line-height: 1.35; }
h1 { font-size: 24px; margin-bottom: 4px; }
h2 { font-size: 18px; margin-top: 28px; border-bottom: 1px solid #ccc; padding-bottom: 3px; }
.sub { color: #555; margin-top: 0; }
.verdict { font-size: 20px; font-weight: bold; padding: 10px 14px; border-radius: 6px;
           margin: 14px 0; }
.pass { background: #d9f2dc; color: #155d22; border: 1px solid #7cc488; }
.fail { background: #fbdcdc; color: #8a1414; border: 1px solid #e08787; }
.none { background: #eee; color: #444; border: 1px solid #bbb; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: top; }
th { background: #f3f3f3; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.share { white-space: nowrap; }
.bar { display: inline-block; height: 10px; background: #4a7bb7; vertical-align: middle; }
.note { color: #555; font-size: 13px; }
.plots { display: flex; flex-wrap: wrap; gap: 16px; }
.plot { flex: 1 1 520px; max-width: 800px; }
.plot svg { width: 100%; height: auto; border: 1px solid #ddd; }
pre.comp { margin: 4px 0; font-size: 12px; white-space: pre-wrap; }
.overview { max-width: 800px; margin: 0 auto; }
.overview svg { width: 100%; height: auto; }
@page { size: A4; margin: 12mm; }
@media print {
  body { margin: 0; max-width: none; font-size: 9pt; line-height: 1.25; }
  h1 { font-size: 15pt; margin: 0; }
  .sub, .test { margin: 2px 0; }
  .verdict { font-size: 12pt; padding: 5px 8px; margin: 6px 0; }
  .overview { width: 118mm; }
  .overview svg { border: none; }
  .first h2 { margin-top: 4px; }
  h2.details { break-before: page; }
  table { font-size: 8pt; }
  th, td { padding: 2px 4px; }
  .plot { break-inside: avoid; }
  .bar { print-color-adjust: exact; -webkit-print-color-adjust: exact; }
  .verdict { print-color-adjust: exact; -webkit-print-color-adjust: exact; }
}
";

fn fmt_opt(x: Option<f64>, decimals: usize) -> String {
    match x {
        Some(v) if v.is_finite() => format!("{v:.decimals$}"),
        _ => "–".into(),
    }
}

/// Write a JSON value of the plan or calibration as `key: value` rows.
fn object_rows(v: &serde_json::Value, prefix: &str, out: &mut Vec<(String, String)>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                match x {
                    serde_json::Value::Object(_) if out.len() < 40 => object_rows(x, &key, out),
                    _ => out.push((key, compact(x))),
                }
            }
        }
        other => out.push((prefix.to_string(), compact(other))),
    }
}

fn compact(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// `x` (µm) to the digits the test's noise `noise_um` supports, or a dash.
fn um(x: Option<f64>, noise_um: f64) -> String {
    match x {
        Some(v) if v.is_finite() => format_to(v, noise_um),
        _ => "–".into(),
    }
}

fn zone_cell(z: &Option<ZoneDoc>, tol: Option<f64>, noise_um: f64) -> String {
    match z.as_ref().and_then(|z| z.g_um) {
        Some(g) => {
            let mark = match tol {
                Some(t) if g > t => " <b>✗</b>",
                Some(_) => " ✓",
                None => "",
            };
            format!("{}{mark}", format_to(g, noise_um))
        }
        None => "–".into(),
    }
}

fn centre_text(z: &Option<ZoneDoc>, noise_um: f64) -> String {
    match z {
        Some(z) if !z.centre.is_empty() => z
            .centre
            .iter()
            .map(|(k, v)| format!("{} {}", k.trim_end_matches("_um"), um(*v, noise_um)))
            .collect::<Vec<_>>()
            .join(", "),
        _ => "–".into(),
    }
}

fn circle_label(c: &CircleDoc, normal: char) -> String {
    format!(
        "r = {:.1} mm, {normal} = {:.1} mm",
        c.radius_mm, c.height_mm
    )
}

/// The ISO 230-4 conditions the user states (operator, temperatures, table ball) and the
/// instrument's serial, each "not given" with the option that gives it when absent.
fn iso_rows(doc: &DiagnosisDoc) -> Vec<(String, String)> {
    let temp = |t: Option<f64>, option: &str| match t {
        Some(t) => format!("{t} °C"),
        None => format!("not given (--{option})"),
    };
    let t = doc.temperature_c.clone().unwrap_or_default();
    vec![
        (
            "Operator".into(),
            doc.operator
                .clone()
                .unwrap_or_else(|| "not given (--operator)".into()),
        ),
        (
            "Instrument".into(),
            match doc.instrument.as_ref().and_then(|i| i.serial.as_deref()) {
                Some(s) => format!("J-DBB, serial {s}"),
                None => {
                    "J-DBB, serial not reported (a `jdbb record` file carries it; this input has none)".into()
                }
            },
        ),
        (
            "Machine temperature".into(),
            temp(t.machine, "machine-temperature-c"),
        ),
        (
            "Instrument temperature".into(),
            temp(t.instrument, "instrument-temperature-c"),
        ),
        (
            "Table ball, machine coordinates (G53)".into(),
            match &doc.table_ball_mm {
                Some(p) => {
                    let given: Vec<String> = p
                        .iter()
                        .filter_map(|(k, v)| v.map(|v| format!("{k} = {v:.3} mm")))
                        .collect();
                    given.join(", ")
                }
                None => "not given (--table-ball x=..,y=..,z=..)".into(),
            },
        ),
    ]
}

/// Where a plan's circles run, in degrees from the plane's first axis (the plan's `arc`): the
/// feed-in at the start angle, the lead-in, the data arc ccw (the samples the diagnosis uses)
/// and the overshoot, then back cw over the same data arc.
fn arc_text(start: f64, sweep: f64, lead_in: f64, overshoot: f64, data0: f64, data: f64) -> String {
    let end = data0 + data;
    if sweep >= 360.0 {
        format!(
            "full circles: feed-in at {start:.0}°, lead-in {lead_in:.0}°, data {data0:.0}°→{end:.0}° ccw (one turn) then {end:.0}°→{data0:.0}° cw, overshoot {overshoot:.0}° each way"
        )
    } else {
        format!(
            "partial arcs of {sweep:.0}° from {start:.0}° to {:.0}°: feed-in at {start:.0}°, lead-in {lead_in:.0}°, data {data0:.0}°→{end:.0}° ccw then {end:.0}°→{data0:.0}° cw, overshoot {overshoot:.0}° each way",
            start + sweep
        )
    }
}

/// The instrument calibration (`calibration` of the diagnosis, a jdbb-core `Calibration`) as a
/// person reads it: the file it came from, the bar lengths in mm, the encoders and the angles
/// in degrees; every value (radians also in degrees) under a `<details>` element. HTML.
fn calibration_html(cal: &serde_json::Value, file: Option<&str>) -> String {
    let num = |path: &[&str]| {
        path.iter()
            .try_fold(cal, |v, k| v.get(*k))
            .and_then(|v| v.as_f64())
    };
    let mm = |path: &[&str]| num(path).map_or("?".into(), |v| format!("{v:.4} mm"));
    let deg = |path: &[&str]| num(path).map_or("?".into(), |v| format!("{:.4}°", v.to_degrees()));
    let mut out = String::new();
    let _ = write!(
        out,
        "{}bars L1 {}, L2 {}",
        file.map_or(String::new(), |f| format!("from <b>{}</b>: ", escape(f))),
        mm(&["l1_mm"]),
        mm(&["l2_mm"])
    );
    for enc in ["enc1", "enc2"] {
        let counts = num(&[enc, "counts_per_rev"]);
        let zero = num(&[enc, "zero_count"]);
        let dir = cal
            .get(enc)
            .and_then(|e| e.get("direction"))
            .and_then(|d| d.as_str())
            .unwrap_or("?");
        let _ = write!(
            out,
            "; encoder {}: {} counts/rev, zero at count {}, direction {}, fine zero {}, eccentricity {} at {}",
            &enc[3..],
            counts.map_or("?".into(), |c| format!("{c:.0}")),
            zero.map_or("?".into(), |z| format!("{z:.0}")),
            escape(&dir.to_lowercase()),
            deg(&[enc, "zero_offset_rad"]),
            deg(&[enc, "eccentricity_rad"]),
            deg(&[enc, "eccentricity_phase_rad"])
        );
    }
    let _ = write!(out, "; axes skew {}", deg(&["axes_skew_rad"]));
    for frame in ["frame1", "frame2"] {
        let _ = write!(
            out,
            "; frame {}: tilt {}, pivot offset {} normal, {} axial (× grip radius)",
            &frame[5..],
            deg(&[frame, "tilt_rad"]),
            deg(&[frame, "offset_normal_rad"]),
            deg(&[frame, "offset_axial_rad"])
        );
    }
    let mut r = vec![];
    object_rows(cal, "", &mut r);
    let _ = write!(
        out,
        "<details><summary>all {} values of the file</summary><table>",
        r.len()
    );
    for (k, v) in r {
        let shown = match (k.ends_with("_rad"), v.parse::<f64>()) {
            (true, Ok(x)) => format!("{v} ({:.6}°)", x.to_degrees()),
            _ => v,
        };
        let _ = write!(
            out,
            "<tr><td>{}</td><td class=\"num\">{}</td></tr>",
            escape(&k),
            escape(&shown)
        );
    }
    out.push_str("</table></details>");
    out
}

/// The plan (`plan` of the diagnosis) as a sentence and a table of its circles.
fn plan_html(plan: Option<&serde_json::Value>) -> String {
    let Some(p) = plan else {
        return "not given (jdbb diagnose --record FILE --plan plan.json)".into();
    };
    let text = |k: &str| p.get(k).and_then(|v| v.as_str()).map(escape);
    let num = |v: Option<&serde_json::Value>| v.and_then(|v| v.as_f64());
    let mut parts: Vec<String> = vec![];
    if let Some(f) = text("file") {
        parts.push(format!("<b>{f}</b>"));
    }
    if let Some(x) = text("purpose") {
        parts.push(format!("purpose {x}"));
    }
    if let Some(x) = text("program") {
        parts.push(format!("program {x}"));
    }
    if let Some(x) = text("dialect") {
        parts.push(format!("G-code dialect {x}"));
    }
    if let Some(x) = text("plane") {
        parts.push(format!("plane {x}"));
    }
    if let Some(f) = num(p.get("feed_mm_min")) {
        parts.push(format!("programmed feed {f:.0} mm/min"));
    }
    if let Some(c) = p.get("centre_mm").and_then(|v| v.as_array()) {
        let c: Vec<String> = c
            .iter()
            .map(|x| x.as_f64().map_or("?".into(), |x| format!("{x:.3}")))
            .collect();
        parts.push(format!(
            "centre (program coordinates) ({}) mm",
            c.join(", ")
        ));
    }
    if let Some(a) = p.get("arc") {
        let g = |k: &str| num(a.get(k)).unwrap_or(f64::NAN);
        parts.push(arc_text(
            g("start_deg"),
            g("sweep_deg"),
            g("lead_in_deg"),
            g("overshoot_deg"),
            g("data_start_deg"),
            g("data_sweep_deg"),
        ));
    }
    let mut out = parts.join(", ");
    if let Some(circles) = p.get("circles").and_then(|v| v.as_array()) {
        out.push_str("<table><tr><th>circle</th><th>radius mm</th><th>height mm</th><th>bar length D mm</th><th>plane</th><th>programmed feed mm/min</th></tr>");
        for (k, c) in circles.iter().enumerate() {
            let f = |key: &str, d: usize| fmt_opt(num(c.get(key)), d);
            let _ = write!(
                out,
                "<tr><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td class=\"num\">{}</td></tr>",
                k + 1,
                f("radius_mm", 3),
                f("height_mm", 3),
                f("d_mm", 3),
                c.get("plane").and_then(|v| v.as_str()).map_or("–".into(), escape),
                f("feed_mm_min", 0)
            );
        }
        out.push_str("</table>");
    }
    out
}

/// The feed of circle `k` as the record shows it (`measured_mm_min`), and beside it, where the
/// diagnosis was lined up with a plan, the programmed feed and the override the record shows
/// (the measured over the programmed feed: override, controller timing and clock together).
fn feed_text(doc: &DiagnosisDoc, k: usize, measured_mm_min: Option<f64>) -> String {
    let sync = doc.sync.as_ref();
    let programmed = sync
        .and_then(|s| s.get("programmed_feed_mm_min"))
        .and_then(|v| v.as_f64());
    let percent = sync
        .and_then(|s| s.get("circles"))
        .and_then(|c| c.get(k))
        .and_then(|c| c.get("feed_percent"))
        .and_then(|v| v.as_f64())
        .or_else(|| {
            sync.and_then(|s| s.get("feed_percent"))
                .and_then(|v| v.as_f64())
        });
    let measured = format!("measured feed {} mm/min", fmt_opt(measured_mm_min, 0));
    match (programmed, percent) {
        (Some(p), Some(pc)) => {
            format!("{measured} (programmed {p:.0} mm/min, override {pc:.2} % as measured)")
        }
        _ => format!("{measured} (programmed feed and override: not known without a plan)"),
    }
}

/// F max / min of one trace (µm) to the noise's digits, or a dash.
fn f_cell(r: Option<&crate::report::document::RangeDoc>, noise_um: f64) -> String {
    match r {
        Some(r) => format!("{} / {}", um(r.max_um, noise_um), um(r.min_um, noise_um)),
        None => "–".into(),
    }
}

/// The test in one line, for page one: plane, circles and their feed.
fn test_line(doc: &DiagnosisDoc, plane: &str, normal: char) -> String {
    let circles: Vec<String> = doc
        .circles
        .iter()
        .map(|c| {
            format!(
                "{} at {} mm/min",
                circle_label(c, normal),
                fmt_opt(c.feed_mm_min, 0)
            )
        })
        .collect();
    format!(
        "Test: plane {}, {} circle{} ({}), ccw and cw",
        plane.to_ascii_uppercase(),
        circles.len(),
        if circles.len() == 1 { "" } else { "s" },
        circles.join("; ")
    )
}

/// The whole page (see the module docs).
pub fn report_html(d: &Diagnosis, doc: &DiagnosisDoc) -> Result<String> {
    let mut h = String::new();
    let machine = doc
        .machine
        .as_deref()
        .unwrap_or("(machine not named: --machine NAME)");
    let tol = doc.tolerance.as_ref().map(|t| t.g_um);
    // The test's noise: the digits of every figure without a ± of its own.
    let noise = doc.final_fit.rms_um.unwrap_or(f64::NAN);
    let plane = doc.plane.clone().unwrap_or_else(|| "?".into());
    let normal = match plane.as_str() {
        "xy" => 'z',
        "yz" => 'x',
        "zx" => 'y',
        _ => '?',
    };
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>Circular test: {}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n",
        escape(machine)
    );
    // What the date is the date of: the test's (--date) or the diagnosis' (when it ran).
    let (date_label, date_word, date_note) = match doc.date_of.as_deref() {
        Some("test") => ("Date of the test (UTC, --date)", "test of", ""),
        Some("diagnosis") => (
            "Date of the diagnosis (UTC)",
            "diagnosed",
            " (when jdbb diagnose ran; the test's date was not given: --date)",
        ),
        _ => ("Date (UTC)", "dated", ""),
    };
    let _ = writeln!(
        h,
        "<h1>Circular test report: {}</h1>\n<p class=\"sub\">J-DBB double ball bar, {} samples, {}</p>",
        escape(machine),
        doc.samples,
        escape(&doc.date_utc.as_deref().map_or("date not recorded".to_string(), |d| format!("{date_word} {d}")))
    );

    // Verdict.
    let g_max = doc.g_um();
    match (&doc.tolerance, g_max) {
        (Some(t), Some(g)) => {
            let _ = writeln!(
                h,
                "<div class=\"verdict {}\">{}: largest circular deviation G = {} µm (minimum zone, per circle and direction) {} tolerance {} µm</div>",
                if t.pass { "pass" } else { "fail" },
                if t.pass { "PASS" } else { "FAIL" },
                format_to(g, noise),
                if t.pass { "≤" } else { ">" },
                t.g_um
            );
        }
        _ => {
            let _ = writeln!(
                h,
                "<div class=\"verdict none\">No tolerance given (jdbb diagnose --tolerance-um): largest circular deviation G = {} µm (minimum zone, per circle and direction)</div>",
                um(g_max, noise)
            );
        }
    }

    if let (Some(w), Some(g)) = (doc.g_if_compensated_um, g_max) {
        if w != g {
            let _ = writeln!(
                h,
                "<p class=\"what-if\">G with the compensable settings entered (<code>jdbb compensate</code>: backlash, scale, squareness, cyclic error): <b>{} µm</b> (measured {} µm)</p>",
                format_to(w, noise),
                format_to(g, noise)
            );
        }
    }

    // Page one (also printed, `--pdf`): the test in a line, the polar plot of all circles, then
    // the effects ranked by share.
    let _ = writeln!(
        h,
        "<p class=\"test\">{}</p>",
        escape(&test_line(doc, &plane, normal))
    );
    let svg = polar_svg(d, &View::ALL)?;
    let _ = writeln!(h, "<div class=\"plot overview\">{svg}</div>");
    // Effects ranked by share.
    let _ = writeln!(h, "<h2>What the errors are, largest share first</h2>");
    // Whole percentages adding up to 100, over the file's effects in its order, then ranked.
    let named: Vec<_> = doc.machine_effects().collect();
    let pct = split_percentages(
        &named
            .iter()
            .map(|(e, _)| Some(e.share.unwrap_or(f64::NAN)))
            .collect::<Vec<_>>(),
        doc.residual_share.unwrap_or(f64::NAN),
    );
    // Ranked as the text ranks them: by share of G, then by mean-square share.
    let keys: Vec<_> = named
        .iter()
        .map(|(e, _)| Some((e.g_share.unwrap_or(f64::NAN), e.share.unwrap_or(f64::NAN))))
        .collect();
    let effects: Vec<_> = crate::report::rank_order(&keys)
        .into_iter()
        .map(|i| (named[i], pct.effects[i]))
        .collect();
    if effects.is_empty() {
        let _ = writeln!(
            h,
            "<p>No machine effect is supported by the data: what remains is noise.</p>"
        );
    } else {
        let _ = writeln!(
            h,
            "<table>\n<tr><th>#</th><th>effect</th><th>value ± σ</th><th>share of G</th><th>share of the mean square</th><th>RMS alone</th><th>cause</th></tr>"
        );
        for (k, ((e, effect), pct)) in effects.iter().enumerate() {
            let bar = match pct {
                Some(p) => format!(
                    "<span class=\"bar\" style=\"width:{:.0}px\"></span> ",
                    (1.2 * f64::from(*p)).max(1.0)
                ),
                None => String::new(),
            };
            let _ = writeln!(
                h,
                "<tr><td class=\"num\">{}</td><td>{}</td><td class=\"num\">{} {}</td><td class=\"num\">{}</td><td class=\"share\">{bar}{}</td><td class=\"num\">{} µm</td><td>{}</td></tr>",
                k + 1,
                escape(&e.name),
                escape(&format_estimate(e.value.unwrap_or(f64::NAN), e.sigma)),
                escape(&human(&e.unit)),
                e.g_share
                    .filter(|g| g.is_finite())
                    .map_or("–".to_string(), |g| format!("{:.0} %", 100.0 * g)),
                match pct {
                    Some(p) => format!("{p} %"),
                    None => "–".into(),
                },
                um(e.contribution_rms_um, noise),
                escape(&cause(*effect, e.value.unwrap_or(0.0)))
            );
        }
        let _ = writeln!(
            h,
            "<tr><td></td><td>residual</td><td class=\"num\">RMS {} µm</td><td></td><td class=\"share\">{}</td><td class=\"num\">{} µm</td><td>noise and what no effect explains</td></tr>\n</table>",
            um(doc.final_fit.rms_um, noise),
            pct.residual.map_or("–".to_string(), |p| format!("{p} %")),
            um(doc.final_fit.rms_um, noise),
        );
    }
    let setup: Vec<String> = doc
        .effects
        .iter()
        .filter(|e| e.setup)
        .map(|e| {
            let params: Vec<String> = e
                .params
                .iter()
                .filter_map(|(k, v)| {
                    let v = (*v)?;
                    let s = e.params_sigma.get(k).copied().flatten();
                    Some(crate::model::words::param_text(
                        k,
                        v,
                        s,
                        "undetermined, held",
                    ))
                })
                .collect();
            format!(
                "{} = {} {}{}",
                e.name,
                format_estimate(e.value.unwrap_or(f64::NAN), e.sigma),
                human(&e.unit),
                if params.len() > 1 {
                    format!(" ({})", params.join(", "))
                } else {
                    String::new()
                }
            )
        })
        .collect();
    let _ = writeln!(
        h,
        "<p class=\"note\">Share of G: how much of the test's G the effect makes, (G − G without it) / G. Share of the mean square: the mean square of the radial deviation an effect alone makes (set-up removed), over the sum of that of every effect and the residual's mean square; the shares add up to 100 % (whole percentages, rounded by largest remainder). ± is one standard error; every figure is shown to the digits its σ supports (G, H and RMS: the test's noise, the residual RMS). Set-up, removed before everything here (the table ball relative to where it was assumed): {}.</p>",
        escape(&setup.join("; "))
    );
    for g in &doc.confounded {
        let _ = writeln!(
            h,
            "<p class=\"note\">This test cannot tell apart: {}.</p>",
            escape(&g.join(", "))
        );
    }
    // What the selection tried and did not name, and why: a reader checking a cause that is
    // absent from the table finds it here.
    for w in &doc.not_significant {
        let _ = writeln!(
            h,
            "<p class=\"note\">Not named: {} = {} {} — {}.</p>",
            escape(&w.name),
            format_estimate(w.value.unwrap_or(f64::NAN), w.sigma),
            human(&w.unit),
            escape(&w.reason)
        );
    }
    for b in &doc.below_floor {
        let _ = writeln!(
            h,
            "<p class=\"note\">Not named, below the reporting floor: {} is supported by the data but changes D by at most {} µm, under the floor of {} µm.</p>",
            escape(&b.name),
            b.peak_um.map_or("–".to_string(), |p| format!("{p:.3}")),
            doc.floor_um.map_or("–".to_string(), |f| format!("{f:.3}"))
        );
    }
    for (k, a) in doc.arcs.iter().enumerate().filter(|(_, a)| a.partial) {
        let start = if a.start_deg > 180.0 {
            a.start_deg - 360.0
        } else {
            a.start_deg
        };
        let _ = writeln!(
            h,
            "<p class=\"note\">Partial arc: circle {} covers {:.0}° ({:.0}° to {:.0}°). The set-up and the scale are less sure than on a full circle (their ± says by how much).</p>",
            k + 1,
            a.sweep_deg,
            start,
            start + a.sweep_deg
        );
    }
    for w in &doc.weak_on_arc {
        let _ = writeln!(
            h,
            "<p class=\"note\">Weak on this arc: only {:.2} % of {}'s shape is its own beside {}; where one of them is named, the others are its alternative.</p>",
            100.0 * w.free_fraction,
            escape(&w.names[0]),
            escape(&w.names[1..].join(", "))
        );
    }

    // Conditions.

    let _ = writeln!(h, "<h2 class=\"details\">Test conditions</h2>\n<table>");
    let mut rows: Vec<(String, String)> = vec![
        ("Machine".into(), machine.to_string()),
        (
            date_label.into(),
            doc.date_utc
                .as_ref()
                .map_or("not recorded".into(), |d| format!("{d}{date_note}")),
        ),
        (
            "Plane".into(),
            format!("{plane} (angle measured from the first axis towards the second)"),
        ),
    ];
    for (k, c) in doc.circles.iter().enumerate() {
        rows.push((
            format!("Circle {}", k + 1),
            format!(
                "{}, {}, {} samples (ccw and cw)",
                circle_label(c, normal),
                feed_text(doc, k, c.feed_mm_min),
                c.samples
            ),
        ));
    }
    let pitch: Vec<String> = doc
        .pitch_mm
        .iter()
        .filter_map(|(k, v)| v.map(|p| format!("{k} {p} mm")))
        .collect();
    if !pitch.is_empty() {
        rows.push(("Screw/scale pitch".into(), pitch.join(", ")));
    }
    for (k, v) in rows.drain(..) {
        let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", escape(&k), escape(&v));
    }
    let _ = writeln!(
        h,
        "<tr><th>Instrument calibration</th><td>{}</td></tr>",
        match &doc.calibration {
            Some(c) => calibration_html(c, doc.calibration_file.as_deref()),
            None => "not given (jdbb diagnose --calibration FILE)".into(),
        }
    );
    rows.push((
        "Tolerance on G".into(),
        tol.map_or("not given".into(), |t| format!("{t} µm")),
    ));
    rows.push((
        "Fit".into(),
        format!(
            "RMS {} µm before (ideal machine), {} µm after the model (gain ×{})",
            um(doc.baseline.rms_um, noise),
            um(doc.final_fit.rms_um, noise),
            fmt_opt(doc.gain, 1)
        ),
    ));
    rows.extend(iso_rows(doc));
    for (k, v) in rows {
        let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", escape(&k), escape(&v));
    }
    let _ = writeln!(
        h,
        "<tr><th>Compensation in force during the test</th><td>{}</td></tr>",
        match &doc.compensation {
            Some(c) => format!(
                "{}<pre class=\"comp\">{}</pre>",
                c.file
                    .as_deref()
                    .map_or(String::new(), |f| format!("from {}:", escape(f))),
                escape(c.text.trim_end())
            ),
            None =>
                "not given (jdbb diagnose --compensation TEXT or --compensation-file FILE)".into(),
        }
    );
    let _ = writeln!(
        h,
        "<tr><th>Plan</th><td>{}</td></tr>",
        plan_html(doc.plan.as_ref())
    );
    let _ = writeln!(h, "</table>");

    // G and H.
    let _ = writeln!(
        h,
        "<h2>Circular deviation G and hysteresis H (ISO 230-4, minimum-zone centre)</h2>\n<table>\n<tr><th>circle</th><th>measured feed mm/min</th><th>G ccw µm</th><th>G cw µm</th><th>G both directions µm</th><th>H µm</th><th>F max / min ccw µm</th><th>F max / min cw µm</th><th>minimum-zone centre (ccw): table ball at, µm</th><th>verdict</th></tr>"
    );
    for c in &doc.circles {
        let verdict = match (tol, c.g_um) {
            (Some(t), Some(g)) if g <= t => "pass",
            (Some(_), Some(_)) => "fail",
            _ => "–",
        };
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td>{verdict}</td></tr>",
            escape(&circle_label(c, normal)),
            fmt_opt(c.feed_mm_min, 0),
            zone_cell(&c.ccw, tol, noise),
            zone_cell(&c.cw, tol, noise),
            zone_cell(&c.bidirectional, None, noise),
            um(c.h_um, noise),
            f_cell(c.radial_deviation_f.as_ref().and_then(|f| f.ccw.as_ref()), noise),
            f_cell(c.radial_deviation_f.as_ref().and_then(|f| f.cw.as_ref()), noise),
            escape(&centre_text(&c.ccw, noise)),
        );
    }
    let _ = writeln!(
        h,
        "</table>\n<p class=\"note\">G: the radial width of the minimum zone (two concentric circles, closest together, enclosing the trace) of one circle in one direction; its centre is given as where it puts the table ball, relative to where the ball was assumed (as the set-up offset). H: the largest difference between the ccw and cw traces in a 1° bin. F (radial deviation, ISO 230-4): the largest (max) and smallest (min) deviation of the trace from the nominal circle, about the centre of the least-squares circle of all samples, with the radius as the calibrated bar measures it (so F includes the bar's length error, which its calibration bounds). Pass: every circle's G in each direction is at most the tolerance.</p>"
    );

    // Plots of each circle on its own scale (one circle: the plot above is its own).
    if doc.circles.len() > 1 {
        let _ = writeln!(
            h,
            "<h2>Polar plots, one circle each</h2>\n<div class=\"plots\">"
        );
        for (k, c) in doc.circles.iter().enumerate().take(d.circles.len()) {
            let view = View {
                circle: Some(k),
                title: Some(format!(
                    "{}: G ccw {} µm, cw {} µm, H {} µm",
                    circle_label(c, normal),
                    um(c.ccw.as_ref().and_then(|z| z.g_um), noise),
                    um(c.cw.as_ref().and_then(|z| z.g_um), noise),
                    um(c.h_um, noise)
                )),
            };
            let svg = polar_svg(d, &view)?;
            let _ = writeln!(h, "<div class=\"plot\">{svg}</div>");
        }
        let _ = writeln!(h, "</div>");
    }
    let _ = writeln!(
        h,
        "</div>\n<p class=\"note\">Polar plots: the measured deviation with the fitted set-up removed (one circle: ccw blue, cw orange), the ideal machine (green, zero deviation) and the model's machine effects (black); a long record is drawn through the least and largest deviation of each bin of consecutive samples, so every extreme is on the plot.</p>\n<p class=\"note\">jdbb {}</p>\n</body>\n</html>",
        env!("CARGO_PKG_VERSION")
    );
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_is_a_sentence_and_a_table_not_json() {
        let plan = serde_json::json!({
            "file": "plan.json", "purpose": "machine-test", "dialect": "linuxcnc",
            "program": "test.ngc", "plane": "xy", "feed_mm_min": 1000.0,
            "centre_mm": [100.0, 50.0, -20.0],
            "arc": {"start_deg": 0.0, "sweep_deg": 360.0, "lead_in_deg": 10.0,
                    "overshoot_deg": 10.0, "data_start_deg": 10.0, "data_sweep_deg": 360.0},
            "circles": [{"radius_mm": 50.0, "height_mm": 0.0, "d_mm": 100.0, "plane": "xy",
                         "feed_mm_min": 1000.0}]
        });
        let h = plan_html(Some(&plan));
        assert!(h.starts_with("<b>plan.json</b>, purpose machine-test, program test.ngc, G-code dialect linuxcnc, plane xy, programmed feed 1000 mm/min, centre (program coordinates) (100.000, 50.000, -20.000) mm, full circles: feed-in at 0°, lead-in 10°, data 10°→370° ccw (one turn) then 370°→10° cw, overshoot 10° each way"), "{h}");
        assert!(h.contains("<td class=\"num\">50.000</td><td class=\"num\">0.000</td><td class=\"num\">100.000</td><td>xy</td>"), "{h}");
        // No raw JSON left.
        assert!(!h.contains("{\"") && !h.contains("\":"), "{h}");
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(
            escape("<b>&\"x\"'</b>"),
            "&lt;b&gt;&amp;&quot;x&quot;&#39;&lt;/b&gt;"
        );
    }
}
