//! Charts of `psao bench` (plotters, PNG): PSNR against client time for
//! every method, and PSNR against bit rate for PSAO.
//!
//! The x axes are logarithmic, with labelled ticks at decades, at 1-2-5
//! steps or finer, whichever gives 3 to 10 of them, and light lines at the
//! next finer steps ([`log_ticks`]). Each point's label goes where it
//! overlaps no other label, no marker and not the frame, near its point
//! or, failing that, farther off with a leader line ([`place_labels`]).
//! The legend is a row under the title, off the data.

use std::path::Path;

use anyhow::Context as _;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::images::register_fonts;
use super::model::{Method, Row, SceneResult};

/// Chart size, pixels.
const SIZE: (u32, u32) = (900, 600);

/// Height of the title and legend above the plot, pixels.
const HEADER: u32 = 62;

/// Radius of a point's marker, pixels.
const MARKER: i32 = 5;

/// Most labelled ticks on a log axis (unless fewer than 3 would be left:
/// then up to 13, tenths over a factor of 2.25).
const MAX_TICKS: usize = 10;

/// Colour of the points' labels.
const LABEL: RGBColor = RGBColor(40, 40, 40);

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
                .filter(|row| matches!(row.method, Method::Psao { rate, budget: false, .. } if Some(rate) == first_rate(r)))
                .collect(),
        ),
        (
            "PSAO (lower server rates)",
            RGBColor(86, 180, 233),
            finite
                .iter()
                .copied()
                .filter(|row| matches!(row.method, Method::Psao { rate, budget: false, .. } if Some(rate) != first_rate(r)))
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

/// One group of points: its legend name, colour and (x, PSNR, label)s.
struct Series<'a> {
    name: &'a str,
    color: RGBColor,
    points: Vec<(f64, f64, String)>,
}

/// A labelled scatter chart of PSNR (y) against `x` on a log axis.
fn scatter(
    path: &Path,
    title: &str,
    x_label: &str,
    groups: &[(&str, RGBColor, Vec<&Row>)],
    x: impl Fn(&Row) -> Option<f64>,
) -> anyhow::Result<()> {
    let series: Vec<Series> = groups
        .iter()
        .map(|(name, color, rows)| Series {
            name,
            color: *color,
            points: rows
                .iter()
                .filter_map(|r| x(r).map(|v| (v, r.psnr, r.method.label())))
                .filter(|(v, _, _)| *v > 0.0 && v.is_finite())
                .collect(),
        })
        .filter(|s| !s.points.is_empty())
        .collect();
    let points: Vec<&(f64, f64, String)> = series.iter().flat_map(|s| &s.points).collect();
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
    let ticks = log_ticks(x0, x1);
    let mut buf = vec![255u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (header, body) = root.split_vertically(HEADER);
        let centre = Pos::new(HPos::Center, VPos::Top);
        header
            .draw_text(
                title,
                &("sans-serif", 20).into_font().color(&BLACK).pos(centre),
                (SIZE.0 as i32 / 2, 8),
            )
            .map_err(draw_err)?;
        legend(&header, &series, 40)?;
        let mut chart = ChartBuilder::on(&body)
            .margin(12)
            .margin_right(24)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(
                (x0..x1)
                    .log_scale()
                    .with_key_points(ticks.major.clone())
                    .with_light_points(ticks.minor.clone()),
                y0..y1,
            )
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc("PSNR against the reference, dB")
            .label_style(("sans-serif", 13))
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .draw()
            .map_err(draw_err)?;
        for s in &series {
            let color = s.color;
            chart
                .draw_series(
                    s.points
                        .iter()
                        .map(|(px, py, _)| Circle::new((*px, *py), MARKER, color.filled())),
                )
                .map_err(draw_err)?;
        }
        let text = ("sans-serif", 11).into_font().color(&LABEL);
        let mut anchors = Vec::new();
        let mut sizes = Vec::new();
        for (px, py, label) in &points {
            anchors.push(chart.backend_coord(&(*px, *py)));
            let (w, h) = root.estimate_text_size(label, &text).map_err(draw_err)?;
            sizes.push((w as i32, h as i32));
        }
        let (xs, ys) = chart.plotting_area().get_pixel_range();
        let bounds = Rect {
            x0: xs.start + 2,
            y0: ys.start + 2,
            x1: xs.end - 2,
            y1: ys.end - 2,
        };
        for ((anchor, (_, _, label)), placed) in anchors
            .iter()
            .zip(&points)
            .zip(place_labels(&anchors, &sizes, bounds, MARKER))
        {
            if placed.leader {
                let end = placed.rect.nearest(*anchor);
                root.draw(&PathElement::new(
                    vec![*anchor, end],
                    RGBColor(150, 150, 150).stroke_width(1),
                ))
                .map_err(draw_err)?;
            }
            root.draw_text(label, &text, (placed.rect.x0, placed.rect.y0))
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    image::RgbImage::from_raw(SIZE.0, SIZE.1, buf)
        .context("chart buffer has the wrong size")?
        .save(path)
        .with_context(|| path.display().to_string())
}

/// The legend: one row, centred at height `y` of `area`, a marker and the
/// name of each series.
fn legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    series: &[Series],
    y: i32,
) -> anyhow::Result<()> {
    let style = ("sans-serif", 13)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    let (gap, swatch) = (28, 2 * MARKER + 6);
    let mut widths = Vec::new();
    for s in series {
        let (w, _) = area.estimate_text_size(s.name, &style).map_err(draw_err)?;
        widths.push(w as i32);
    }
    let total: i32 =
        widths.iter().map(|w| swatch + w).sum::<i32>() + gap * (widths.len() as i32 - 1).max(0);
    let width = area.dim_in_pixel().0 as i32;
    let mut x = (width - total) / 2;
    for (s, w) in series.iter().zip(widths) {
        area.draw(&Circle::new((x + MARKER, y), MARKER, s.color.filled()))
            .map_err(draw_err)?;
        area.draw_text(s.name, &style, (x + swatch, y))
            .map_err(draw_err)?;
        x += swatch + w + gap;
    }
    Ok(())
}

/// Ticks of a log axis: labelled (`major`) and light lines (`minor`).
#[derive(Debug, PartialEq)]
pub struct Ticks {
    /// Labelled tick values, ascending.
    pub major: Vec<f64>,
    /// Light grid values, ascending (the next finer steps).
    pub minor: Vec<f64>,
}

/// Mantissas of the tick levels, coarse to fine: decades; 1-2-5; every
/// digit; halves; tenths.
fn mantissas(level: usize) -> Vec<f64> {
    match level {
        0 => vec![1.0],
        1 => vec![1.0, 2.0, 5.0],
        2 => (1..10).map(f64::from).collect(),
        3 => (2..20).map(|m| f64::from(m) / 2.0).collect(),
        _ => (10..100).map(|m| f64::from(m) / 10.0).collect(),
    }
}

/// Number of tick levels ([`mantissas`]).
const LEVELS: usize = 5;

/// The values of tick level `level` in `[lo, hi]`, ascending.
fn level_values(level: usize, lo: f64, hi: f64) -> Vec<f64> {
    let (k0, k1) = (lo.log10().floor() as i32 - 1, hi.log10().ceil() as i32);
    let mut out = Vec::new();
    for k in k0..=k1 {
        for m in mantissas(level) {
            // Dividing by an exact power of ten keeps 0.3 as 0.3.
            let v = if k < 0 {
                m / 10f64.powi(-k)
            } else {
                m * 10f64.powi(k)
            };
            if v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                out.push(v);
            }
        }
    }
    out
}

/// Ticks of a log axis over `[lo, hi]` (0 < lo < hi): the coarsest level
/// of decades, 1-2-5, digits, halves and tenths that gives at least 4
/// labels, or the one before it when that gives more than [`MAX_TICKS`]
/// and the one before at least 3; light lines at the next finer level. A
/// range too narrow for 3 labels even at tenths also labels its ends. A
/// range that is not positive and finite gets no ticks.
pub fn log_ticks(lo: f64, hi: f64) -> Ticks {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return Ticks {
            major: Vec::new(),
            minor: Vec::new(),
        };
    }
    let counts: Vec<Vec<f64>> = (0..LEVELS).map(|l| level_values(l, lo, hi)).collect();
    let mut level = (0..LEVELS)
        .find(|&l| counts[l].len() >= 4)
        .unwrap_or(LEVELS - 1);
    if counts[level].len() > MAX_TICKS && level > 0 && counts[level - 1].len() >= 3 {
        level -= 1;
    }
    let mut major = counts[level].clone();
    if major.len() < 3 {
        major.insert(0, lo);
        major.push(hi);
        major.dedup_by(|a, b| (*a - *b).abs() <= 1e-9 * b.abs());
    }
    let minor = if level + 1 < LEVELS {
        counts[level + 1].clone()
    } else {
        Vec::new()
    };
    Ticks { major, minor }
}

/// A tick value as text: up to 6 significant digits, no trailing zeros
/// (0.3, 2, 1000, 1.5).
pub fn tick_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let decimals = (5 - v.abs().log10().floor() as i32).clamp(0, 12) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// A pixel rectangle: `x0..x1` by `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    /// Left edge.
    pub x0: i32,
    /// Top edge.
    pub y0: i32,
    /// Right edge (exclusive).
    pub x1: i32,
    /// Bottom edge (exclusive).
    pub y1: i32,
}

impl Rect {
    /// A `w` by `h` rectangle with its top left corner at `(x, y)`.
    fn at(x: i32, y: i32, w: i32, h: i32) -> Rect {
        Rect {
            x0: x,
            y0: y,
            x1: x + w,
            y1: y + h,
        }
    }

    /// Pixels in it.
    fn area(&self) -> i64 {
        (self.x1 - self.x0).max(0) as i64 * (self.y1 - self.y0).max(0) as i64
    }

    /// Pixels it shares with `o`.
    pub fn overlap(&self, o: &Rect) -> i64 {
        let w = (self.x1.min(o.x1) - self.x0.max(o.x0)).max(0) as i64;
        let h = (self.y1.min(o.y1) - self.y0.max(o.y0)).max(0) as i64;
        w * h
    }

    /// The point of it nearest to `p`.
    fn nearest(&self, p: (i32, i32)) -> (i32, i32) {
        (
            p.0.clamp(self.x0, self.x1 - 1),
            p.1.clamp(self.y0, self.y1 - 1),
        )
    }
}

/// Where a point's label goes: its box and whether a leader line joins it
/// to its point (when placed off its point's ring).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Placed {
    /// The label's box (its top left corner is where the text starts).
    pub rect: Rect,
    /// Whether to draw a line from the point to the label.
    pub leader: bool,
}

/// Rings of candidate positions around a point (the first one touching
/// its marker, each next one this many pixels farther).
const RINGS: i32 = 8;
/// Pixels between rings.
const RING_STEP: i32 = 9;

/// Places a label of size `sizes[i]` next to each point `anchors[i]`
/// (pixels), greedily, most crowded point first: the first of eight
/// positions around the point (upper right first) on the nearest ring that
/// overlaps no placed label and no marker (of radius `marker`) and lies
/// within `bounds`; where none does, the position that overlaps least.
pub fn place_labels(
    anchors: &[(i32, i32)],
    sizes: &[(i32, i32)],
    bounds: Rect,
    marker: i32,
) -> Vec<Placed> {
    let markers: Vec<Rect> = anchors
        .iter()
        .map(|&(x, y)| Rect {
            x0: x - marker - 1,
            y0: y - marker - 1,
            x1: x + marker + 2,
            y1: y + marker + 2,
        })
        .collect();
    // Points with the most neighbours go first: they have the fewest
    // free places.
    let near = |i: usize| {
        anchors
            .iter()
            .filter(|a| (a.0 - anchors[i].0).abs() < 120 && (a.1 - anchors[i].1).abs() < 40)
            .count()
    };
    let mut order: Vec<usize> = (0..anchors.len().min(sizes.len())).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(near(i)));
    let mut placed: Vec<Option<Placed>> = vec![None; order.len()];
    let mut taken: Vec<Rect> = Vec::new();
    for i in order {
        let ((px, py), (w, h)) = (anchors[i], sizes[i]);
        let cost = |r: &Rect| -> i64 {
            let outside = r.area() - r.overlap(&bounds);
            let labels: i64 = taken.iter().map(|t| t.overlap(r)).sum();
            let dots: i64 = markers.iter().map(|m| m.overlap(r)).sum();
            outside * 100 + labels * 10 + dots * 10
        };
        let mut best: Option<(i64, Placed)> = None;
        'rings: for ring in 0..RINGS {
            let d = marker + 3 + ring * RING_STEP;
            let dd = d * 3 / 4;
            let candidates = [
                (px + dd, py - dd - h),
                (px + d, py - h / 2),
                (px + dd, py + dd),
                (px - dd - w, py - dd - h),
                (px - d - w, py - h / 2),
                (px - dd - w, py + dd),
                (px - w / 2, py - d - h),
                (px - w / 2, py + d),
            ];
            for (x, y) in candidates {
                let rect = Rect::at(x, y, w, h);
                let c = cost(&rect);
                let here = Placed {
                    rect,
                    leader: ring > 0,
                };
                if best.is_none_or(|(b, _)| c < b) {
                    best = Some((c, here));
                }
                if c == 0 {
                    break 'rings;
                }
            }
        }
        if let Some((_, p)) = best {
            taken.push(p.rect);
            placed[i] = Some(p);
        }
    }
    placed
        .into_iter()
        .map(|p| {
            p.unwrap_or(Placed {
                rect: Rect::at(0, 0, 0, 0),
                leader: false,
            })
        })
        .collect()
}

/// A drawing error, as plotters says it.
fn draw_err<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> anyhow::Error {
    anyhow::anyhow!("drawing: {e}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_axes_get_three_to_ten_labelled_ticks() {
        // Ranges as the charts pad them (a factor 2.25 at least), narrow
        // to wide, at every position in a decade.
        for lo in [
            0.011, 0.09, 0.13, 0.5, 0.99, 1.01, 2.1, 4.4, 7.7, 9.9, 130.0,
        ] {
            for factor in [2.25, 3.0, 7.0, 12.0, 40.0, 300.0, 1e4, 1e7] {
                let t = log_ticks(lo, lo * factor);
                let n = t.major.len();
                assert!((3..=15).contains(&n), "{lo} x{factor}: {:?}", t.major);
                assert!(t.major.windows(2).all(|w| w[0] < w[1]), "{:?}", t.major);
                assert!(
                    t.major
                        .iter()
                        .all(|&v| v >= lo * 0.999 && v <= lo * factor * 1.001)
                );
            }
        }
    }

    #[test]
    fn log_ticks_prefer_decades_then_one_two_five() {
        let t = log_ticks(0.05, 2e5);
        assert_eq!(t.major, vec![0.1, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5]);
        assert!(t.minor.contains(&0.2) && t.minor.contains(&5e4));
        let t = log_ticks(0.3, 40.0);
        assert_eq!(t.major, vec![0.5, 1.0, 2.0, 5.0, 10.0, 20.0]);
        // The ranges of the issue: one or two decade ticks before.
        assert_eq!(
            log_ticks(0.5, 22.0).major,
            vec![0.5, 1.0, 2.0, 5.0, 10.0, 20.0]
        );
        assert!(log_ticks(0.3, 1.6).major.len() >= 3);
        assert_eq!(log_ticks(0.0, 1.0).major, Vec::<f64>::new());
    }

    #[test]
    fn tick_labels_are_short() {
        let labels: Vec<String> = [0.3, 0.1 * 3.0, 2.0, 1000.0, 1.5, 0.05, 12.5]
            .into_iter()
            .map(tick_label)
            .collect();
        assert_eq!(labels, ["0.3", "0.3", "2", "1000", "1.5", "0.05", "12.5"]);
    }

    #[test]
    fn labels_of_a_cluster_do_not_overlap() {
        // Seven points within a few pixels, room around them.
        let anchors: Vec<(i32, i32)> = (0..7).map(|k| (400 + 3 * k, 300 + 2 * k)).collect();
        let sizes = vec![(90, 14); anchors.len()];
        let bounds = Rect {
            x0: 0,
            y0: 0,
            x1: 800,
            y1: 600,
        };
        let placed = place_labels(&anchors, &sizes, bounds, MARKER);
        assert_eq!(placed.len(), anchors.len());
        for (i, a) in placed.iter().enumerate() {
            assert_eq!(a.rect.overlap(&bounds), 90 * 14, "{a:?} leaves the plot");
            for b in &placed[i + 1..] {
                assert_eq!(a.rect.overlap(&b.rect), 0, "{a:?} and {b:?}");
            }
            for &(x, y) in &anchors {
                let dot = Rect::at(x - MARKER, y - MARKER, 2 * MARKER, 2 * MARKER);
                assert_eq!(a.rect.overlap(&dot), 0, "{a:?} covers the point at {x},{y}");
            }
        }
    }

    #[test]
    fn a_lone_label_sits_up_and_right_without_a_leader() {
        let bounds = Rect {
            x0: 0,
            y0: 0,
            x1: 800,
            y1: 600,
        };
        let p = place_labels(&[(100, 100)], &[(60, 12)], bounds, MARKER);
        assert!(!p[0].leader);
        assert!(p[0].rect.x0 > 100 && p[0].rect.y1 < 100, "{:?}", p[0]);
        // At the right edge it moves to the left of its point.
        let p = place_labels(&[(790, 100)], &[(60, 12)], bounds, MARKER);
        assert!(p[0].rect.x1 <= 790, "{:?}", p[0]);
    }
}
