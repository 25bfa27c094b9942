//! `--report DIR`: a ballbar-style polar plot (SVG and PNG) with the set-up removed, as ballbar
//! software does: the measured deviation D − (|p − t| + e) with the fitted table-ball offset t
//! and length offset e (the one centre of every output: `setup_offset`, `length_offset`), the
//! ideal machine (the zero-deviation circle) and
//! the extended model's prediction after the same removal (its machine effects), with the one
//! circular deviation G per circle and direction (ISO 230-4, minimum-zone centre, as the text and
//! the JSON) and hysteresis H; plus the JSON of the diagnosis. Figures are shown to the digits
//! the test's noise supports ([`super::report`], *Digits*).
//!
//! Each run (one circle, one direction, no jump; [`super::runs::split_runs`]) is its own
//! polyline, so no chord crosses the plot; several circles get one colour each (ccw dark, cw
//! light) on one deviation scale, as the caption says.
//!
//! plotters has no polar axes: rings and spokes are drawn here. Text uses DejaVu Sans embedded in
//! the binary (host/assets, Bitstream Vera licence, see DejaVuSans.LICENSE.txt), so no
//! fontconfig is needed.
use std::path::Path as FsPath;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::diagnose::Diagnosis;
use crate::units::format_to;
use crate::{Error, Result};

static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Register the embedded DejaVu Sans as plotters' `sans-serif` (once).
pub(crate) fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The embedded font is known good; failure would only mean it was already registered.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

fn plot_err(e: impl std::fmt::Display) -> Error {
    Error::Numerics(format!("plotting failed: {e}"))
}

/// Canvas: title strip, square polar chart, legend and caption strip (pixels).
const WIDTH: u32 = 800;
const TITLE_H: u32 = 40;
const LEGEND_ROW_H: u32 = 20;
const CAPTION_ROW_H: u32 = 18;

/// Colours of the measured runs per circle (ccw); cw runs use a lighter shade. One circle uses
/// blue (ccw) and orange (cw) instead.
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
    RGBColor(188, 189, 34),
    RGBColor(127, 127, 127),
];
const IDEAL: RGBColor = RGBColor(0, 160, 0);
const MODEL: RGBColor = RGBColor(0, 0, 0);

/// What one polar plot shows: all circles overlaid (`polar.svg`), or one circle with its own
/// deviation scale (the HTML report's plot per circle), and its title.
#[derive(Debug, Clone)]
pub struct View {
    /// Only this circle (index into [`Diagnosis::circles`]); None = all.
    pub circle: Option<usize>,
    /// The title strip's text; None = the test's G (the largest minimum-zone G of a circle in
    /// one direction) and H.
    pub title: Option<String>,
}

impl View {
    /// All circles, the default title: what `polar.svg` and `polar.png` show.
    pub const ALL: View = View {
        circle: None,
        title: None,
    };

    fn shows(&self, circle: usize) -> bool {
        self.circle.is_none_or(|c| c == circle)
    }

    /// Number of circles drawn.
    fn n_circles(&self, d: &Diagnosis) -> usize {
        if self.circle.is_some() {
            1
        } else {
            d.circles.len()
        }
    }
}

/// Colour of the measured trace of `circle` in one direction.
fn run_colour(n_circles: usize, circle: usize, ccw: bool) -> RGBColor {
    if n_circles <= 1 {
        return if ccw { PALETTE[0] } else { PALETTE[1] };
    }
    let RGBColor(r, g, b) = PALETTE[circle % PALETTE.len()];
    if ccw {
        RGBColor(r, g, b)
    } else {
        let light = |c: u8| ((c as u16 + 255) / 2) as u8;
        RGBColor(light(r), light(g), light(b))
    }
}

/// Legend entries: colours of the line sample (one or two) and text.
fn legend(d: &Diagnosis, view: &View) -> Vec<(Vec<RGBColor>, String)> {
    let n = view.n_circles(d);
    let mut out = vec![(vec![IDEAL], "ideal machine (zero deviation)".to_string())];
    if n <= 1 {
        out.push((
            vec![run_colour(1, 0, true)],
            "measured − set-up, ccw".to_string(),
        ));
        out.push((
            vec![run_colour(1, 0, false)],
            "measured − set-up, cw".to_string(),
        ));
    } else {
        let normal = ['x', 'y', 'z'][3 - d.plane.0 - d.plane.1];
        for (k, c) in d.circles.iter().enumerate() {
            out.push((
                vec![run_colour(n, k, true), run_colour(n, k, false)],
                format!(
                    "measured − set-up, r = {:.1} mm, {normal} = {:.1} mm",
                    c.radius_mm, c.height_mm
                ),
            ));
        }
    }
    out.push((
        vec![MODEL],
        "extended model (machine effects, set-up removed)".to_string(),
    ));
    out
}

/// Caption lines under the legend: the set-up removed, what G and H are, the overlay.
fn caption(d: &Diagnosis, view: &View) -> Vec<String> {
    let s = d.fitted_setup_um();
    let um = |x: f64| format_to(x, d.final_rms_um);
    let mut out = vec![
        format!(
            "Set-up removed (fitted): table ball at x = {} µm, y = {} µm, z = {} µm from where assumed; length offset e = {} µm",
            um(s[0]), um(s[1]), um(s[2]), um(s[3])
        ),
        "G: radial width of the minimum zone of one circle in one direction (ISO 230-4, minimum-zone centre); H: largest ccw − cw difference in a 1° bin".to_string(),
        "Ringed dot: where a run (one direction of a circle) starts; arrow outside the rings: from its start angle, the direction it runs".to_string(),
    ];
    if view.circle.is_none() {
        let normal = ['x', 'y', 'z'][3 - d.plane.0 - d.plane.1];
        for c in &d.circle_zones {
            let g = |z: &Option<crate::numerics::mzc::MinimumZone>| {
                z.map_or("not run".to_string(), |z| format!("{} µm", um(z.width_um)))
            };
            out.push(format!(
                "r = {:.1} mm, {normal} = {:.1} mm: G ccw {}, cw {}; H {} µm",
                c.radius_mm,
                c.height_mm,
                g(&c.ccw),
                g(&c.cw),
                um(c.h_um)
            ));
        }
    }
    if view.n_circles(d) > 1 {
        out.push(format!(
            "{} circles (radius, height) overlaid on one deviation scale; dark = ccw, light = cw",
            d.circles.len()
        ));
    }
    out
}

/// Pixel height of the canvas for `d`.
fn height(d: &Diagnosis, view: &View) -> u32 {
    let rows = legend(d, view).len().div_ceil(2) as u32;
    TITLE_H + WIDTH + rows * LEGEND_ROW_H + caption(d, view).len() as u32 * CAPTION_ROW_H + 20
}

/// The measured runs as polylines: one series per [`super::runs::Run`], so no chord joins
/// the end of one run (another direction, circle or a jump) to the start of the next.
fn run_points<'a>(
    d: &'a Diagnosis,
    view: &'a View,
    dev: &'a [f64],
    rad: impl Fn(f64) -> f64 + 'a,
) -> impl Iterator<Item = (&'a super::runs::Run, Vec<(f64, f64)>)> + 'a {
    d.runs
        .iter()
        .filter(|r| view.shows(r.circle))
        .map(move |run| {
            let pts = run
                .range
                .clone()
                .map(|i| {
                    let (a, v) = (d.angle_rad[i], dev[i]);
                    (rad(v) * a.cos(), rad(v) * a.sin())
                })
                .collect();
            (run, pts)
        })
}

/// Draw the polar plot on any plotters backend.
fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    d: &Diagnosis,
    view: &View,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    root.fill(&WHITE).map_err(plot_err)?;
    let (title_area, rest) = root.split_vertically(TITLE_H);
    let (chart_area, bottom) = rest.split_vertically(WIDTH);
    let maxdev = d
        .runs
        .iter()
        .filter(|r| view.shows(r.circle))
        .flat_map(|r| r.range.clone())
        .flat_map(|i| [d.measured_dev_um[i], d.model_dev_um[i]])
        .fold(0.0f64, |m, x| m.max(x.abs()))
        .max(1e-3);
    // Ring step: 1-2-5 sequence with about 4 rings out to maxdev.
    let raw = maxdev / 4.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|k| k * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let rings = (maxdev / step).ceil().max(1.0) as i32;
    let outer = rings as f64 * step;
    // Plot radius: deviation −outer..+outer maps to 0.2..1.0 around the zero ring at 0.6.
    let rad = |dev: f64| 0.6 + 0.4 * dev / outer;
    let title = match &view.title {
        Some(t) => format!("{t}, {step} µm/div"),
        None => format!(
            "J-DBB circular test, set-up removed: G = {} µm (largest), H = {} µm, {} µm/div",
            format_to(d.circular_deviation_g_um, d.final_rms_um),
            format_to(d.hysteresis_h_um, d.final_rms_um),
            step
        ),
    };
    let centred = Pos::new(HPos::Center, VPos::Center);
    title_area
        .draw_text(
            &title,
            &TextStyle::from(("sans-serif", 20).into_font()).pos(centred),
            (WIDTH as i32 / 2, TITLE_H as i32 / 2),
        )
        .map_err(plot_err)?;
    // A square area with equal margins keeps circles round.
    let mut chart = ChartBuilder::on(&chart_area)
        .margin(10)
        .build_cartesian_2d::<RangedCoordf64, RangedCoordf64>(
            (-1.15f64..1.15).into(),
            (-1.15f64..1.15).into(),
        )
        .map_err(plot_err)?;
    let circle = |r: f64| {
        (0..=360).map(move |k| {
            let a = (k as f64).to_radians();
            (r * a.cos(), r * a.sin())
        })
    };
    for k in -rings..=rings {
        let r = rad(k as f64 * step);
        let style = if k == 0 {
            BLACK.mix(0.5)
        } else {
            BLACK.mix(0.15)
        };
        chart
            .draw_series(LineSeries::new(circle(r), style))
            .map_err(plot_err)?;
    }
    for s in 0..12 {
        let a = (s as f64 * 30.0).to_radians();
        chart
            .draw_series(LineSeries::new(
                [
                    (0.2 * a.cos(), 0.2 * a.sin()),
                    (1.05 * a.cos(), 1.05 * a.sin()),
                ],
                BLACK.mix(0.15),
            ))
            .map_err(plot_err)?;
        chart
            .draw_series(std::iter::once(Text::new(
                format!("{}°", s * 30),
                (1.1 * a.cos(), 1.1 * a.sin()),
                TextStyle::from(("sans-serif", 12).into_font()).pos(centred),
            )))
            .map_err(plot_err)?;
    }
    chart
        .draw_series(LineSeries::new(circle(rad(0.0)), IDEAL.stroke_width(2)))
        .map_err(plot_err)?;
    let n_circles = view.n_circles(d);
    for (run, pts) in run_points(d, view, &d.measured_dev_um, rad) {
        let colour = run_colour(n_circles, run.circle, run.ccw);
        chart
            .draw_series(LineSeries::new(pts, colour))
            .map_err(plot_err)?;
    }
    for (_, pts) in run_points(d, view, &d.model_dev_um, rad) {
        chart
            .draw_series(LineSeries::new(pts, MODEL.stroke_width(2)))
            .map_err(plot_err)?;
    }
    // On top of everything: where each run starts (a white dot ringed in its colour, on the
    // trace) and which way it runs (an arrow outside the rings, from the start angle 15° along
    // the run's direction). Drawn under the traces they were lost in a noisy trace.
    for (run, pts) in run_points(d, view, &d.measured_dev_um, rad) {
        let Some(&first) = pts.first() else { continue };
        let colour = run_colour(n_circles, run.circle, run.ccw);
        let a0 = d.angle_rad[run.range.start];
        let turn = if run.ccw { 1.0 } else { -1.0 };
        let r_arrow = 1.03;
        let sweep = 15f64.to_radians();
        let arc: Vec<(f64, f64)> = (0..=12)
            .map(|k| {
                let a = a0 + turn * sweep * k as f64 / 12.0;
                (r_arrow * a.cos(), r_arrow * a.sin())
            })
            .collect();
        chart
            .draw_series(LineSeries::new(arc, colour.stroke_width(3)))
            .map_err(plot_err)?;
        let a1 = a0 + turn * sweep;
        let (tx, ty) = (-a1.sin() * turn, a1.cos() * turn); // unit tangent, the way it runs
        let (nx, ny) = (a1.cos(), a1.sin()); // outward normal
        let (s, w) = (0.045, 0.025);
        let base = (r_arrow * nx, r_arrow * ny);
        let head = vec![
            (base.0 + tx * s, base.1 + ty * s),
            (base.0 + nx * w, base.1 + ny * w),
            (base.0 - nx * w, base.1 - ny * w),
        ];
        chart
            .draw_series(std::iter::once(Polygon::new(head, colour.filled())))
            .map_err(plot_err)?;
        chart
            .draw_series(std::iter::once(Circle::new(first, 6, WHITE.filled())))
            .map_err(plot_err)?;
        chart
            .draw_series(std::iter::once(Circle::new(
                first,
                6,
                colour.stroke_width(3),
            )))
            .map_err(plot_err)?;
    }
    // On top of the traces: deviation labels of the inner, zero and outer rings along the 105° direction (between spokes).
    let la = 105f64.to_radians();
    for v in [-outer, 0.0, outer] {
        chart
            .draw_series(std::iter::once(Text::new(
                if v == 0.0 {
                    "0 µm".to_string()
                } else {
                    format!("{v:+} µm")
                },
                (rad(v) * la.cos(), rad(v) * la.sin()),
                TextStyle::from(("sans-serif", 11).into_font()).pos(centred),
            )))
            .map_err(plot_err)?;
    }
    // Legend in two columns, then the caption, under the chart.
    let entries = legend(d, view);
    let rows = entries.len().div_ceil(2);
    let font = ("sans-serif", 13).into_font();
    for (k, (colours, text)) in entries.iter().enumerate() {
        let x = 20 + (k / rows) as i32 * (WIDTH as i32 / 2);
        let y = (k % rows) as i32 * LEGEND_ROW_H as i32 + 10;
        for (j, c) in colours.iter().enumerate() {
            let x0 = x + j as i32 * 15;
            bottom
                .draw(&PathElement::new(
                    vec![(x0, y), (x0 + 15, y)],
                    c.stroke_width(3),
                ))
                .map_err(plot_err)?;
        }
        bottom
            .draw_text(
                text,
                &TextStyle::from(font.clone()).pos(Pos::new(HPos::Left, VPos::Center)),
                (x + 38, y),
            )
            .map_err(plot_err)?;
    }
    let small = ("sans-serif", 11).into_font();
    for (k, line) in caption(d, view).iter().enumerate() {
        let y = (rows as u32 * LEGEND_ROW_H + 10 + k as u32 * CAPTION_ROW_H) as i32;
        bottom
            .draw_text(
                line,
                &TextStyle::from(small.clone()).pos(Pos::new(HPos::Left, VPos::Center)),
                (10, y),
            )
            .map_err(plot_err)?;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}

/// The polar plot of `view` as SVG text (for pages that embed it, such as `report.html`).
pub fn polar_svg(d: &Diagnosis, view: &View) -> Result<String> {
    register_font();
    let mut svg = String::new();
    {
        let size = (WIDTH, height(d, view));
        draw(
            SVGBackend::with_string(&mut svg, size).into_drawing_area(),
            d,
            view,
        )?;
    }
    Ok(svg)
}

/// Write `polar.svg`, `polar.png` and `diagnosis.json` into `dir` (created if missing).
pub fn write_report(dir: &FsPath, d: &Diagnosis, json: &serde_json::Value) -> Result<()> {
    register_font();
    std::fs::create_dir_all(dir).map_err(|source| Error::File {
        action: "cannot create report directory",
        path: dir.to_path_buf(),
        source,
    })?;
    let svg = dir.join("polar.svg");
    let size = (WIDTH, height(d, &View::ALL));
    draw(
        SVGBackend::new(&svg, size).into_drawing_area(),
        d,
        &View::ALL,
    )?;
    let png = dir.join("polar.png");
    draw(
        BitMapBackend::new(&png, size).into_drawing_area(),
        d,
        &View::ALL,
    )?;
    let jp = dir.join("diagnosis.json");
    std::fs::write(
        &jp,
        serde_json::to_string_pretty(json).expect("JSON of plain values"),
    )
    .map_err(|source| Error::File {
        action: "cannot write",
        path: jp,
        source,
    })
}
