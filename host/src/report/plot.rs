//! `--report DIR`: a ballbar-style polar plot (SVG and PNG) with the set-up removed, as ballbar
//! software does: the measured deviation D − (|p − t| + e) with the fitted table-ball offset t
//! and length offset e (the one centre of every output: `setup_offset`, `length_offset`), the
//! ideal machine (the zero-deviation circle) and
//! the extended model's prediction after the same removal (its machine effects), with the one
//! circular deviation G per circle and direction (ISO 230-4, minimum-zone centre, as the text and
//! the JSON) and hysteresis H; plus the JSON of the diagnosis. Figures are shown to the digits
//! the test's noise supports ([`crate::report`], *Digits*).
//!
//! Each run (one circle, one direction, no jump; [`crate::diagnose::runs::split_runs`]) is its own
//! polyline, so no chord crosses the plot; several circles get one colour each (ccw dark, cw
//! light) on one deviation scale, as the caption says.
//!
//! The plane is drawn in its physical orientation ([`Orientation`]): XY seen from above (+X right,
//! +Y up), ZX seen from the front of the machine (+X right, +Z up), YZ seen from its +X side (+Y
//! right, +Z up); the spokes carry the plane's angle (from its first axis towards its second, as
//! the text and the JSON give angles) and the axis each main spoke points along. A trace of many
//! samples is drawn through the least and the largest deviation of each bin of consecutive
//! samples ([`decimate`]), so the extremes stay on the plot whatever the record's length, and a
//! plot (and `report.html`) stays small.
//!
//! plotters has no polar axes: rings and spokes are drawn here. Text uses DejaVu Sans embedded in
//! the binary (host/assets, Bitstream Vera licence, see DejaVuSans.LICENSE.txt), so no
//! fontconfig is needed.
use std::path::Path as FsPath;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::diagnose::Diagnosis;
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
/// Free space kept at the left and right edge of every text line (pixels).
const TEXT_MARGIN: u32 = 10;
/// Title font size (pixels), reduced until the title fits the width.
const TITLE_PX: u32 = 20;
const LEGEND_PX: u32 = 13;
const CAPTION_PX: u32 = 11;
/// Most points a view's traces are drawn with per kind (measured, model): a longer trace is drawn
/// through the extremes of bins of consecutive samples ([`decimate`]).
pub const MAX_TRACE_POINTS: usize = 6000;
const LEGEND_ROW_H: u32 = 20;
const CAPTION_ROW_H: u32 = 18;

/// Width (pixels) of `text` in the embedded font at `size_px`.
fn text_width_px(text: &str, size_px: u32) -> u32 {
    ("sans-serif", size_px)
        .into_font()
        .box_size(text)
        .map_or(size_px * text.chars().count() as u32, |(w, _)| w)
}

/// The largest font size up to `size_px` at which `text` fits `width_px` (at least 8 px).
fn fitting_size(text: &str, size_px: u32, width_px: u32) -> u32 {
    (8..=size_px)
        .rev()
        .find(|&s| text_width_px(text, s) <= width_px)
        .unwrap_or(8)
}

/// `text` cut into lines at spaces so that each fits `width_px` at `size_px` (a word longer than
/// the width is a line of its own).
fn wrap(text: &str, size_px: u32, width_px: u32) -> Vec<String> {
    let mut lines: Vec<String> = vec![];
    let mut line = String::new();
    for word in text.split(' ') {
        let candidate = if line.is_empty() {
            word.to_string()
        } else {
            format!("{line} {word}")
        };
        if !line.is_empty() && text_width_px(&candidate, size_px) > width_px {
            lines.push(std::mem::replace(&mut line, word.to_string()));
        } else {
            line = candidate;
        }
    }
    lines.push(line);
    lines
}

/// How the plane of a test is drawn: in its physical orientation, a vertical plane as seen from
/// the machine with +Z up (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Orientation {
    /// The plane's second axis is drawn to the right and its first up (ZX: the angle runs from +Z
    /// towards +X, drawn with +X right and +Z up, a mirror of the plane's own sense).
    swap: bool,
    /// The axis drawn to the right and the one drawn up (0 = X, 1 = Y, 2 = Z).
    pub right: usize,
    pub up: usize,
    /// Where the plane is seen from, in words.
    pub seen_from: &'static str,
}

impl Orientation {
    /// The orientation of the plane `(first, second)` (axis indices, angle from first to second).
    pub fn of(plane: (usize, usize)) -> Orientation {
        match plane {
            (2, 0) => Orientation {
                swap: true,
                right: 0,
                up: 2,
                seen_from: "seen from the front of the machine (from −Y)",
            },
            (1, 2) => Orientation {
                swap: false,
                right: 1,
                up: 2,
                seen_from: "seen from the machine's +X side",
            },
            (a, b) => Orientation {
                swap: false,
                right: a,
                up: b,
                seen_from: "seen from above (from +Z)",
            },
        }
    }

    /// Screen position (right, up) of plot radius `r` at the plane's angle `a_rad`.
    pub fn at(&self, r: f64, a_rad: f64) -> (f64, f64) {
        let (s, c) = a_rad.sin_cos();
        if self.swap {
            (r * s, r * c)
        } else {
            (r * c, r * s)
        }
    }

    /// The axis (with its sign) a spoke at the plane's angle `deg` (0, 90, 180, 270) points along.
    fn axis_at(&self, plane: (usize, usize), deg: u32) -> String {
        let name = |k: usize| ['X', 'Y', 'Z'][k];
        match deg {
            0 => format!("+{}", name(plane.0)),
            90 => format!("+{}", name(plane.1)),
            180 => format!("−{}", name(plane.0)),
            _ => format!("−{}", name(plane.1)),
        }
    }

    /// The caption's line on the view: `ZX seen from …: +X right, +Z up`.
    fn words(&self) -> String {
        let name = |k: usize| ['X', 'Y', 'Z'][k];
        format!(
            "View: {}, +{} right, +{} up; angles in the plane from +{} towards +{}",
            self.seen_from,
            name(self.right),
            name(self.up),
            if self.swap {
                name(self.up)
            } else {
                name(self.right)
            },
            if self.swap {
                name(self.right)
            } else {
                name(self.up)
            }
        )
    }
}

/// The runs of `runs` (in sample order) where a pass of a circle in one direction starts: a run
/// that goes on from where the previous one ended (same circle and direction, its first angle
/// within [`crate::diagnose::runs::MAX_RUN_STEP_RAD`] of the previous run's last, ahead in its direction)
/// was cut from it by a gap in time only — the samples left out around an axis reversal, bins of
/// a long record — and is no new start.
pub fn pass_starts(runs: &[crate::diagnose::runs::Run], angle_rad: &[f64]) -> Vec<bool> {
    use crate::diagnose::runs::{wrap_pi, MAX_RUN_STEP_RAD};
    let mut out = Vec::with_capacity(runs.len());
    for (k, run) in runs.iter().enumerate() {
        let goes_on = k > 0 && {
            let prev = &runs[k - 1];
            let gap = wrap_pi(angle_rad[run.range.start] - angle_rad[prev.range.end - 1]);
            let ahead = if run.ccw { gap } else { -gap };
            prev.circle == run.circle
                && prev.ccw == run.ccw
                && prev.range.end == run.range.start
                && (-1e-9..=MAX_RUN_STEP_RAD).contains(&ahead)
        };
        out.push(!goes_on);
    }
    out
}

/// The sample indices a trace of `range` is drawn through: all of them when there are at most
/// 2 per `bin` samples, else, per bin of `bin` consecutive samples, the one of least and the one
/// of largest `dev` in their order (and the range's last sample), so the trace keeps its extremes.
pub fn decimate(range: std::ops::Range<usize>, dev: &[f64], bin: usize) -> Vec<usize> {
    if bin <= 2 {
        return range.collect();
    }
    let mut out = Vec::with_capacity(2 * range.len() / bin + 2);
    let mut i = range.start;
    while i < range.end {
        let j = (i + bin).min(range.end);
        let (mut lo, mut hi) = (i, i);
        for k in i..j {
            if dev[k] < dev[lo] {
                lo = k;
            }
            if dev[k] > dev[hi] {
                hi = k;
            }
        }
        out.push(lo.min(hi));
        if hi != lo {
            out.push(lo.max(hi));
        }
        i = j;
    }
    if out.last() != Some(&(range.end - 1)) && !range.is_empty() {
        out.push(range.end - 1);
    }
    out
}

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

/// Caption lines under the legend: the view, the set-up removed, what G and H are, the overlay.
fn caption(d: &Diagnosis, view: &View) -> Vec<String> {
    let s = d.fitted_setup_um();
    let um = |x: f64| format_to(x, d.final_rms_um);
    let mut out = vec![
        Orientation::of(d.plane).words(),
        "Rings: radial deviation from the ideal machine (the green circle, 0 µm), outward positive".to_string(),
        format!(
            "Set-up removed (fitted): table ball at x = {} µm, y = {} µm, z = {} µm from where assumed; length offset e = {} µm",
            um(s[0]), um(s[1]), um(s[2]), um(s[3])
        ),
        "G: radial width of the minimum zone of one circle in one direction (ISO 230-4, minimum-zone centre); H: largest ccw − cw difference in a 1° bin".to_string(),
        "Ringed dot: where a pass (one direction of a circle) starts; arrow outside the rings: from its start angle, the direction it runs".to_string(),
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

/// The deviation scale of a view: ring step (µm, a 1-2-5 sequence with about 4 rings out to the
/// largest deviation), rings each side of zero, and the outer ring's deviation (µm).
fn scale(d: &Diagnosis, view: &View) -> (f64, i32, f64) {
    let maxdev = d
        .runs
        .iter()
        .filter(|r| view.shows(r.circle))
        .flat_map(|r| r.range.clone())
        .flat_map(|i| [d.measured_dev_um[i], d.model_dev_um[i]])
        .fold(0.0f64, |m, x| m.max(x.abs()))
        .max(1e-3);
    let raw = maxdev / 4.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|k| k * mag)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * mag);
    let rings = (maxdev / step).ceil().max(1.0) as i32;
    (step, rings, rings as f64 * step)
}

/// Everything of a view's canvas that has a size: the title at the size that fits, the legend's
/// columns and the caption cut into lines that fit (nothing is clipped at the canvas' edges).
struct Layout {
    title: String,
    title_px: u32,
    legend: Vec<(Vec<RGBColor>, String)>,
    /// Legend rows (entries fill the first column, then the second).
    legend_rows: usize,
    caption: Vec<String>,
}

/// Horizontal space of a legend entry before its text (the line samples), pixels.
const LEGEND_SAMPLE_W: u32 = 38;

impl Layout {
    fn new(d: &Diagnosis, view: &View) -> Layout {
        let (step, _, _) = scale(d, view);
        let title = match &view.title {
            Some(t) => format!("{t}, {step} µm/div"),
            None => format!(
                "J-DBB circular test, set-up removed: G = {} µm (largest), H = {} µm, {} µm/div",
                format_to(d.circular_deviation_g_um, d.final_rms_um),
                format_to(d.hysteresis_h_um, d.final_rms_um),
                step
            ),
        };
        let usable = WIDTH - 2 * TEXT_MARGIN;
        let title_px = fitting_size(&title, TITLE_PX, usable);
        let legend = legend(d, view);
        // Two columns when every entry fits half the width, else one.
        let column = usable / 2 - LEGEND_SAMPLE_W;
        let two = legend
            .iter()
            .all(|(_, t)| text_width_px(t, LEGEND_PX) <= column);
        let legend_rows = if two {
            legend.len().div_ceil(2)
        } else {
            legend.len()
        };
        let caption = caption(d, view)
            .iter()
            .flat_map(|l| wrap(l, CAPTION_PX, usable))
            .collect();
        Layout {
            title,
            title_px,
            legend,
            legend_rows,
            caption,
        }
    }

    /// Pixel height of the canvas.
    fn height(&self) -> u32 {
        TITLE_H
            + WIDTH
            + self.legend_rows as u32 * LEGEND_ROW_H
            + self.caption.len() as u32 * CAPTION_ROW_H
            + 20
    }
}

/// The measured runs as polylines: one series per [`crate::diagnose::runs::Run`], so no chord joins the
/// end of one run (another direction, circle or a jump) to the start of the next; each drawn
/// through the samples [`decimate`] keeps, bins of `bin` samples.
fn run_points<'a>(
    d: &'a Diagnosis,
    view: &'a View,
    dev: &'a [f64],
    bin: usize,
    at: impl Fn(f64, f64) -> (f64, f64) + 'a,
) -> impl Iterator<Item = (&'a crate::diagnose::runs::Run, Vec<(f64, f64)>)> + 'a {
    d.runs
        .iter()
        .filter(|r| view.shows(r.circle))
        .map(move |run| {
            let pts = decimate(run.range.clone(), dev, bin)
                .into_iter()
                .map(|i| at(dev[i], d.angle_rad[i]))
                .collect();
            (run, pts)
        })
}

/// A text of the canvas: its size, whether it is centred on `at` (else it starts there, centred
/// vertically), and `at` in pixels of the whole canvas.
struct Label {
    text: String,
    size_px: u32,
    centred: bool,
    at: (i32, i32),
}

/// Draw `label` on `root`. With `glyphs` (the PNG) each glyph is rasterised here from the
/// embedded font at its own bearing and baseline: plotters' bitmap text drops both (a hyphen
/// over the J of "J-DBB", a comma or a decimal point raised to mid-height: "50·0 mm"). Without
/// (the SVG) the text goes as a text element, for the viewer's renderer to set.
fn put_text<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    label: &Label,
    glyphs: bool,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    if !glyphs {
        let h = if label.centred {
            HPos::Center
        } else {
            HPos::Left
        };
        return root
            .draw_text(
                &label.text,
                &TextStyle::from(("sans-serif", label.size_px).into_font())
                    .pos(Pos::new(h, VPos::Center)),
                label.at,
            )
            .map_err(plot_err);
    }
    use ab_glyph::{Font, FontRef, PxScale, ScaleFont};
    let font = FontRef::try_from_slice(FONT).map_err(plot_err)?;
    // The scale plotters sets text at, so that the sizes (and [`text_width_px`]) agree.
    let scaled = font.as_scaled(PxScale::from(label.size_px as f32));
    let mut width = 0.0f32;
    let mut prev = None;
    for c in label.text.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = prev {
            width += scaled.kern(p, id);
        }
        width += scaled.h_advance(id);
        prev = Some(id);
    }
    let x0 = label.at.0 as f32 - if label.centred { width / 2.0 } else { 0.0 };
    // The baseline puts the middle of the ascent-descent box on `at`'s row.
    let baseline = label.at.1 as f32 + (scaled.ascent() + scaled.descent()) / 2.0;
    let mut pen = x0;
    let mut prev = None;
    for c in label.text.chars() {
        let id = scaled.glyph_id(c);
        if let Some(p) = prev {
            pen += scaled.kern(p, id);
        }
        prev = Some(id);
        let glyph = id.with_scale_and_position(scaled.scale(), ab_glyph::point(pen, baseline));
        pen += scaled.h_advance(id);
        let Some(outline) = font.outline_glyph(glyph) else {
            continue;
        };
        let b = outline.px_bounds();
        let mut result = Ok(());
        outline.draw(|gx, gy, coverage| {
            if coverage > 0.0 && result.is_ok() {
                let p = (b.min.x as i32 + gx as i32, b.min.y as i32 + gy as i32);
                result = root.draw_pixel(p, &BLACK.mix(f64::from(coverage.min(1.0))));
            }
        });
        result.map_err(plot_err)?;
    }
    Ok(())
}

/// Draw the polar plot on any plotters backend.
fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    d: &Diagnosis,
    view: &View,
    layout: &Layout,
    glyphs: bool,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let (_, rest) = root.split_vertically(TITLE_H);
    let (chart_area, bottom) = rest.split_vertically(WIDTH);
    let (step, rings, outer) = scale(d, view);
    // Plot radius: deviation −outer..+outer maps to 0.2..1.0 around the zero ring at 0.6.
    let rad = |dev: f64| 0.6 + 0.4 * dev / outer;
    let orient = Orientation::of(d.plane);
    let at = |dev: f64, a: f64| orient.at(rad(dev), a);
    // Every text, placed in pixels of the whole canvas, drawn last ([`put_text`]).
    let mut labels: Vec<Label> = vec![Label {
        text: layout.title.clone(),
        size_px: layout.title_px,
        centred: true,
        at: (WIDTH as i32 / 2, TITLE_H as i32 / 2),
    }];
    // A square area with equal margins keeps circles round; room outside the spokes for their
    // labels.
    let mut chart = ChartBuilder::on(&chart_area)
        .margin(10)
        .build_cartesian_2d::<RangedCoordf64, RangedCoordf64>(
            (-1.25f64..1.25).into(),
            (-1.25f64..1.25).into(),
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
    for s in 0..12u32 {
        let a = (f64::from(s) * 30.0).to_radians();
        chart
            .draw_series(LineSeries::new(
                [orient.at(0.2, a), orient.at(1.05, a)],
                BLACK.mix(0.15),
            ))
            .map_err(plot_err)?;
        let deg = s * 30;
        // The main spokes name the axis they point along: a polar plot's axis labels.
        let (label, r, px) = if deg % 90 == 0 {
            (format!("{deg}° {}", orient.axis_at(d.plane, deg)), 1.16, 13)
        } else {
            (format!("{deg}°"), 1.12, 12)
        };
        labels.push(Label {
            text: label,
            size_px: px,
            centred: true,
            at: chart.backend_coord(&orient.at(r, a)),
        });
    }
    chart
        .draw_series(LineSeries::new(circle(rad(0.0)), IDEAL.stroke_width(2)))
        .map_err(plot_err)?;
    let n_circles = view.n_circles(d);
    // Bins of consecutive samples so that each kind of trace has at most MAX_TRACE_POINTS.
    let shown: usize = d
        .runs
        .iter()
        .filter(|r| view.shows(r.circle))
        .map(|r| r.range.len())
        .sum();
    let bin = (2 * shown).div_ceil(MAX_TRACE_POINTS).max(1);
    for (run, pts) in run_points(d, view, &d.measured_dev_um, bin, at) {
        let colour = run_colour(n_circles, run.circle, run.ccw);
        chart
            .draw_series(LineSeries::new(pts, colour))
            .map_err(plot_err)?;
    }
    for (_, pts) in run_points(d, view, &d.model_dev_um, bin, at) {
        chart
            .draw_series(LineSeries::new(pts, MODEL.stroke_width(2)))
            .map_err(plot_err)?;
    }
    // On top of everything: where each pass starts (a white dot ringed in its colour, on the
    // trace) and which way it runs (an arrow outside the rings, from the start angle 15° along
    // the pass' direction). Drawn under the traces they were lost in a noisy trace.
    let starts = pass_starts(&d.runs, &d.angle_rad);
    for (run, _) in d
        .runs
        .iter()
        .zip(&starts)
        .filter(|(r, start)| **start && view.shows(r.circle) && !r.range.is_empty())
    {
        let colour = run_colour(n_circles, run.circle, run.ccw);
        let first = at(
            d.measured_dev_um[run.range.start],
            d.angle_rad[run.range.start],
        );
        let a0 = d.angle_rad[run.range.start];
        let turn = if run.ccw { 1.0 } else { -1.0 };
        let r_arrow = 1.03;
        let sweep = 15f64.to_radians();
        let arc: Vec<(f64, f64)> = (0..=12)
            .map(|k| orient.at(r_arrow, a0 + turn * sweep * f64::from(k) / 12.0))
            .collect();
        chart
            .draw_series(LineSeries::new(arc, colour.stroke_width(3)))
            .map_err(plot_err)?;
        let a1 = a0 + turn * sweep;
        // Unit tangent the way it runs and outward normal, on the screen (a mirrored view
        // turns the other way round).
        let base = orient.at(r_arrow, a1);
        let ahead = orient.at(r_arrow, a1 + turn * 1e-3);
        let len = (ahead.0 - base.0).hypot(ahead.1 - base.1);
        let (tx, ty) = ((ahead.0 - base.0) / len, (ahead.1 - base.1) / len);
        let (nx, ny) = (base.0 / r_arrow, base.1 / r_arrow);
        let (s, w) = (0.045, 0.025);
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
    // On top of the traces: deviation labels of the inner, zero and outer rings, between spokes
    // (at 105° of the screen, whatever the plane).
    let la = 105f64.to_radians();
    for v in [-outer, 0.0, outer] {
        labels.push(Label {
            text: if v == 0.0 {
                "0 µm".to_string()
            } else {
                format!("{v:+} µm")
            },
            size_px: 11,
            centred: true,
            at: chart.backend_coord(&(rad(v) * la.cos(), rad(v) * la.sin())),
        });
    }
    // Legend in two columns (one if an entry is too wide), then the caption, under the chart.
    let rows = layout.legend_rows;
    let top = (TITLE_H + WIDTH) as i32;
    for (k, (colours, text)) in layout.legend.iter().enumerate() {
        let x = (2 * TEXT_MARGIN) as i32 + (k / rows) as i32 * (WIDTH as i32 / 2);
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
        labels.push(Label {
            text: text.clone(),
            size_px: LEGEND_PX,
            centred: false,
            at: (x + LEGEND_SAMPLE_W as i32, top + y),
        });
    }
    for (k, line) in layout.caption.iter().enumerate() {
        let y = (rows as u32 * LEGEND_ROW_H + 10 + k as u32 * CAPTION_ROW_H) as i32;
        labels.push(Label {
            text: line.clone(),
            size_px: CAPTION_PX,
            centred: false,
            at: (TEXT_MARGIN as i32, top + y),
        });
    }
    for l in &labels {
        put_text(&root, l, glyphs)?;
    }
    root.present().map_err(plot_err)?;
    Ok(())
}

/// The polar plot of `view` as SVG text (for pages that embed it, such as `report.html`).
pub fn polar_svg(d: &Diagnosis, view: &View) -> Result<String> {
    register_font();
    let mut svg = String::new();
    let layout = Layout::new(d, view);
    {
        let size = (WIDTH, layout.height());
        draw(
            SVGBackend::with_string(&mut svg, size).into_drawing_area(),
            d,
            view,
            &layout,
            false,
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
    let layout = Layout::new(d, &View::ALL);
    let size = (WIDTH, layout.height());
    draw(
        SVGBackend::new(&svg, size).into_drawing_area(),
        d,
        &View::ALL,
        &layout,
        false,
    )?;
    let png = dir.join("polar.png");
    draw(
        BitMapBackend::new(&png, size).into_drawing_area(),
        d,
        &View::ALL,
        &layout,
        true,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::runs::{split_runs, MAX_RUN_STEP_RAD};

    #[test]
    fn a_vertical_plane_is_drawn_from_the_front_with_z_up() {
        // ZX: the angle runs from +Z towards +X. Seen from the front, +X is to the right and +Z
        // up; drawn as XY is (angle 0 to the right), +Z would lie to the right.
        let zx = Orientation::of((2, 0));
        let (r, u) = zx.at(1.0, 0.0); // +Z
        assert!(
            r.abs() < 1e-12 && (u - 1.0).abs() < 1e-12,
            "+Z at ({r}, {u})"
        );
        let (r, u) = zx.at(1.0, 90f64.to_radians()); // +X
        assert!(
            (r - 1.0).abs() < 1e-12 && u.abs() < 1e-12,
            "+X at ({r}, {u})"
        );
        assert_eq!((zx.right, zx.up), (0, 2));
        assert_eq!(zx.axis_at((2, 0), 90), "+X");
        // YZ from its +X side: +Y right, +Z up; XY from above: +X right, +Y up.
        let yz = Orientation::of((1, 2));
        assert_eq!((yz.right, yz.up), (1, 2));
        let (r, u) = yz.at(1.0, 90f64.to_radians()); // +Z
        assert!(r.abs() < 1e-12 && (u - 1.0).abs() < 1e-12);
        let xy = Orientation::of((0, 1));
        assert_eq!((xy.right, xy.up), (0, 1));
        assert!(xy.words().contains("+X right, +Y up"));
    }

    #[test]
    fn a_pass_cut_by_gaps_at_the_reversals_starts_once() {
        // One circle ccw then cw, sampled every 1 ms, with 9 ms left out around each axis
        // reversal (0°, 90°, 180°, 270°) as the synchronisation does: the runs split there, but
        // each direction starts once (the binned record's plot put a start at every reversal).
        let (mut t, mut p) = (vec![], vec![]);
        let n = 3600;
        for (k, sense) in [1.0f64, -1.0].into_iter().enumerate() {
            for i in 0..n {
                let a = sense * (i as f64 / n as f64) * std::f64::consts::TAU;
                let quarter = (i as f64 * 4.0 / n as f64).fract();
                if i > 0 && !(0.005..=0.995).contains(&quarter) {
                    continue;
                }
                t.push(k as f64 * 10.0 + i as f64 * 1e-3);
                p.push([50.0 * a.cos(), 50.0 * a.sin(), 0.0]);
            }
        }
        let (_, runs) = split_runs(&t, &p, (0, 1), MAX_RUN_STEP_RAD);
        assert!(runs.len() > 4, "the gaps split the runs: {}", runs.len());
        let angle: Vec<f64> = p.iter().map(|q| q[1].atan2(q[0])).collect();
        let starts = pass_starts(&runs, &angle);
        let started: Vec<(bool, usize)> = runs
            .iter()
            .zip(&starts)
            .filter(|(_, s)| **s)
            .map(|(r, _)| (r.ccw, r.range.start))
            .collect();
        assert_eq!(started.len(), 2, "{started:?}");
        assert!(started[0].0 && !started[1].0, "{started:?}");
    }

    #[test]
    fn a_decimated_trace_keeps_every_bins_extremes() {
        let dev: Vec<f64> = (0..10_000)
            .map(|i| (i as f64 * 0.37).sin() + if i == 4321 { 9.0 } else { 0.0 })
            .collect();
        let kept = decimate(0..dev.len(), &dev, 100);
        assert!(kept.len() <= 2 * 100 + 1, "{}", kept.len());
        assert!(kept.windows(2).all(|w| w[0] < w[1]), "in sample order");
        assert!(kept.contains(&4321), "the spike");
        for b in 0..100 {
            let bin = &dev[b * 100..(b + 1) * 100];
            let lo = bin.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = bin.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            assert!(kept.iter().any(|&i| dev[i] == lo) && kept.iter().any(|&i| dev[i] == hi));
        }
        assert_eq!(decimate(5..9, &dev, 1), vec![5, 6, 7, 8]);
    }

    /// The lowest inked row of `text` drawn at (20, 20) in a 60 × 40 PNG canvas.
    fn lowest_ink_row(text: &str, glyphs: bool) -> usize {
        let (w, h) = (60usize, 40usize);
        let mut buf = vec![255u8; w * h * 3];
        {
            let root =
                BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
            let label = Label {
                text: text.into(),
                size_px: 13,
                centred: false,
                at: (20, 20),
            };
            put_text(&root, &label, glyphs).unwrap();
            root.present().unwrap();
        }
        (0..h)
            .filter(|y| (0..w).any(|x| buf[(y * w + x) * 3] < 128))
            .max()
            .unwrap()
    }

    #[test]
    fn a_decimal_point_and_a_comma_sit_on_the_baseline_of_the_png() {
        // plotters' bitmap text put them at mid-height ("50·0 mm").
        register_font();
        let digit = lowest_ink_row("5", true);
        assert_eq!(lowest_ink_row(".", true), digit, "the point");
        assert!(
            lowest_ink_row(",", true) >= digit,
            "the comma reaches the baseline"
        );
    }
}
