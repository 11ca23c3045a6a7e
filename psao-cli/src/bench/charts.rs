//! Charts of `psao bench` (plotters, PNG): PSNR against client time for
//! every method, and PSNR against bit rate for PSAO.

use std::path::Path;

use anyhow::Context as _;
use plotters::prelude::*;

use super::images::register_fonts;
use super::model::{Method, Row, SceneResult};

/// Chart size, pixels.
const SIZE: (u32, u32) = (900, 560);

/// Writes `<scene>-time-error.png` and `<scene>-bitrate-error.png`.
pub fn write_charts(out: &Path, r: &SceneResult) -> anyhow::Result<()> {
    register_fonts()?;
    let finite: Vec<&Row> = r.rows.iter().filter(|row| row.psnr.is_finite()).collect();
    let groups: Vec<(&str, RGBColor, Vec<&Row>)> = vec![
        (
            "PSAO (density sweep)",
            RGBColor(0, 114, 178),
            finite
                .iter()
                .copied()
                .filter(|row| matches!(row.method, Method::Psao { rate, .. } if Some(rate) == first_rate(r)))
                .collect(),
        ),
        (
            "PSAO (lower server rates)",
            RGBColor(86, 180, 233),
            finite
                .iter()
                .copied()
                .filter(|row| matches!(row.method, Method::Psao { rate, .. } if Some(rate) != first_rate(r)))
                .collect(),
        ),
        (
            "RTAO-k",
            RGBColor(213, 94, 0),
            finite
                .iter()
                .copied()
                .filter(|row| matches!(row.method, Method::Rtao { .. }))
                .collect(),
        ),
        (
            "SAO",
            RGBColor(0, 158, 115),
            finite
                .iter()
                .copied()
                .filter(|row| row.method == Method::Sao)
                .collect(),
        ),
    ];
    scatter(
        &out.join(format!("{}-time-error.png", r.name)),
        &format!("{}: PSNR against client AO time per frame", r.name),
        "client ms per frame (log scale)",
        &groups,
        |row| Some(row.client_ms),
    )?;
    let psao: Vec<_> = groups.into_iter().take(2).collect();
    scatter(
        &out.join(format!("{}-bitrate-error.png", r.name)),
        &format!("{}: PSNR against PSAO bit rate", r.name),
        "Mbit/s at the server rate (log scale)",
        &psao,
        |row| row.mbit_s,
    )
}

/// The rate of the density sweep: the first PSAO row's.
fn first_rate(r: &SceneResult) -> Option<u16> {
    r.rows.iter().find_map(|row| match row.method {
        Method::Psao { rate, .. } => Some(rate),
        _ => None,
    })
}

/// A labelled scatter chart of PSNR (y) against `x` on a log axis.
fn scatter(
    path: &Path,
    title: &str,
    x_label: &str,
    groups: &[(&str, RGBColor, Vec<&Row>)],
    x: impl Fn(&Row) -> Option<f64>,
) -> anyhow::Result<()> {
    let points: Vec<(f64, f64)> = groups
        .iter()
        .flat_map(|(_, _, rows)| rows.iter().filter_map(|r| x(r).map(|v| (v, r.psnr))))
        .filter(|(v, _)| *v > 0.0 && v.is_finite())
        .collect();
    let mut buf = vec![255u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (mut x0, mut x1) = points.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
            (lo.min(p.0), hi.max(p.0))
        });
        let (mut y0, mut y1) = points.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| {
            (lo.min(p.1), hi.max(p.1))
        });
        if points.is_empty() {
            (x0, x1, y0, y1) = (0.1, 10.0, 0.0, 40.0);
        }
        let (x0, x1) = (x0 / 1.5, x1 * 1.5);
        let (y0, y1) = ((y0 - 1.5).floor(), (y1 + 1.5).ceil());
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc("PSNR against the reference, dB")
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(draw_err)?;
        for (name, color, rows) in groups {
            let pts: Vec<(f64, f64, String)> = rows
                .iter()
                .filter_map(|r| x(r).map(|v| (v, r.psnr, r.method.label())))
                .filter(|(v, _, _)| *v > 0.0 && v.is_finite())
                .collect();
            let color = *color;
            chart
                .draw_series(pts.iter().map(|(px, py, label)| {
                    EmptyElement::at((*px, *py))
                        + Circle::new((0, 0), 5, color.filled())
                        + Text::new(label.clone(), (7, -12), ("sans-serif", 11).into_font())
                }))
                .map_err(draw_err)?
                .label(*name)
                .legend(move |(lx, ly)| Circle::new((lx + 8, ly), 5, color.filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .label_font(("sans-serif", 13))
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    image::RgbImage::from_raw(SIZE.0, SIZE.1, buf)
        .context("chart buffer has the wrong size")?
        .save(path)
        .with_context(|| path.display().to_string())
}

/// A drawing error, as plotters says it.
fn draw_err<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> anyhow::Error {
    anyhow::anyhow!("drawing: {e}")
}
