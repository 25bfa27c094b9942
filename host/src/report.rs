//! `--report DIR`: a ballbar-style polar plot (SVG and PNG) of the measured deviation, the ideal
//! machine ("simulated", the set-up-corrected circle) and the extended model, with ISO 230-4
//! circular deviation G and hysteresis H; plus the JSON of the diagnosis.
//!
//! plotters has no polar axes: rings and spokes are drawn here. Text uses DejaVu Sans embedded in
//! the binary (host/assets, Bitstream Vera licence, see DejaVuSans.LICENSE.txt), so no
//! fontconfig is needed.
use std::path::Path as FsPath;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::diagnose::Diagnosis;
use crate::{Error, Result};

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The embedded font is known good; failure would only mean it was already registered.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

fn plot_err(e: impl std::fmt::Display) -> Error {
    Error::Numerics(format!("plotting failed: {e}"))
}

/// Draw the polar plot on any plotters backend.
fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    d: &Diagnosis,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(plot_err)?;
    let maxdev = d
        .measured_dev_um
        .iter()
        .chain(&d.model_dev_um)
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
    let title = format!(
        "J-DBB circular test: G = {:.2} µm, H = {:.2} µm, {} µm/div",
        d.circular_deviation_g_um, d.hysteresis_h_um, step
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
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
                (1.1 * a.cos() - 0.04, 1.1 * a.sin() + 0.02),
                ("sans-serif", 12),
            )))
            .map_err(plot_err)?;
    }
    let pts = |dev: &[f64]| -> Vec<(f64, f64)> {
        d.angle_rad
            .iter()
            .zip(dev)
            .map(|(&a, &v)| (rad(v) * a.cos(), rad(v) * a.sin()))
            .collect()
    };
    chart
        .draw_series(LineSeries::new(circle(rad(0.0)), GREEN.stroke_width(2)))
        .map_err(plot_err)?
        .label("simulated (ideal machine)")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], GREEN));
    chart
        .draw_series(LineSeries::new(pts(&d.measured_dev_um), BLUE))
        .map_err(plot_err)?
        .label("measured")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLUE));
    chart
        .draw_series(LineSeries::new(pts(&d.model_dev_um), RED))
        .map_err(plot_err)?
        .label("extended model")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(plot_err)?;
    root.present().map_err(plot_err)?;
    Ok(())
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
    draw(SVGBackend::new(&svg, (800, 800)).into_drawing_area(), d)?;
    let png = dir.join("polar.png");
    draw(BitMapBackend::new(&png, (800, 800)).into_drawing_area(), d)?;
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
