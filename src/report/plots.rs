//! PNG plots of the reports, drawn with plotters on a [`Canvas`] (embedded font, atomic
//! write): log-log panels (error against Δt with order guide lines, error against wall time)
//! and the stability map.
use std::path::Path;

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;

use crate::plot::{Canvas, FONT_FAMILY, PlotError, font_size_for, format_number};

/// Distinguishable line colours (Okabe–Ito, colour-blind safe), used in order.
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(120, 120, 120),
    RGBColor(0, 0, 0),
];

/// One line with markers.
#[derive(Clone, Debug)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// Colour.
    pub colour: RGBColor,
    /// Points (x, y), drawn in the given order; non-positive values are skipped.
    pub points: Vec<(f64, f64)>,
    /// Dashed line and hollow markers (secondary data, e.g. errors against the exact solution).
    pub dashed: bool,
}

/// One log-log panel.
#[derive(Clone, Debug, Default)]
pub struct Panel {
    /// Panel title.
    pub title: String,
    /// x axis description.
    pub x_label: String,
    /// y axis description.
    pub y_label: String,
    /// The data.
    pub series: Vec<Series>,
    /// Orders p of guide lines y ∝ x^p (e.g. 1 and 2), drawn in grey from a common point a
    /// factor 3 below the lowest point at the smallest x.
    pub guides: Vec<f64>,
}

fn log_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let mut r: Option<(f64, f64)> = None;
    for v in values.filter(|v| *v > 0.0 && v.is_finite()) {
        r = Some(match r {
            None => (v, v),
            Some((a, b)) => (a.min(v), b.max(v)),
        });
    }
    // Pad by a factor on each side (and open up a single value).
    r.map(|(a, b)| {
        let pad = ((b / a).powf(0.06)).max(1.5);
        (a / pad, b * pad)
    })
}

/// A log-axis tick label at 1, 2 and 5 × 10ᵏ only (empty elsewhere, so labels never crowd):
/// plain decimals from 0.01 to 1000, `2e-3` style outside.
fn log_tick(v: f64) -> String {
    if v <= 0.0 || !v.is_finite() {
        return String::new();
    }
    let e = v.log10().floor();
    let m = v / 10f64.powf(e);
    let Some(mant) = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .find(|c| (m - c).abs() < 1e-6 * c)
    else {
        return String::new();
    };
    let (mant, e) = if mant == 10.0 {
        (1.0, e + 1.0)
    } else {
        (mant, e)
    };
    if (-2.0..=3.0).contains(&e) {
        format_number(mant * 10f64.powf(e))
    } else {
        format!("{mant}e{e}")
    }
}

/// Draws `panels` side by side into a `width × height` PNG at `path`, under `title`.
pub fn draw_log_log(
    path: &Path,
    title: &str,
    panels: &[Panel],
    width: u32,
    height: u32,
) -> Result<(), PlotError> {
    draw_panels(path, title, panels, (width, height), |area, panel, font| {
        draw_panel(area, panel, font)
    })
}

/// A `width × height` PNG at `path`: `title` over `panels` side by side, each drawn by `draw`
/// (given its area, the panel and the font size).
fn draw_panels(
    path: &Path,
    title: &str,
    panels: &[Panel],
    (width, height): (u32, u32),
    draw: impl Fn(&DrawingArea<BitMapBackend<'_>, Shift>, &Panel, f64) -> Result<(), PlotError>,
) -> Result<(), PlotError> {
    let mut canvas = Canvas::new(width, height)?;
    {
        let root = canvas.area()?;
        root.fill(&WHITE)?;
        let font = font_size_for(height);
        let root = root.titled(title, (FONT_FAMILY, 1.2 * font))?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        for (panel, area) in panels.iter().zip(&areas) {
            draw(area, panel, font)?;
        }
        root.present()?;
    }
    canvas.write_png(path)
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    font: f64,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    // Legend strip under the chart: one entry per guide and series, in columns.
    let area = &split_legend(area, panel, font)?;
    let all = || panel.series.iter().flat_map(|s| s.points.iter().copied());
    let (Some((x0, x1)), Some((mut y0, mut y1))) =
        (log_range(all().map(|p| p.0)), log_range(all().map(|p| p.1)))
    else {
        area.draw_text(
            &format!("{}: no data", panel.title),
            &(FONT_FAMILY, font).into_font().color(&BLACK),
            (20, 40),
        )?;
        return Ok(());
    };
    // Guide lines from a common point a factor 3 below the lowest point at the smallest x.
    let anchor = panel
        .series
        .iter()
        .filter_map(|s| {
            s.points
                .iter()
                .filter(|p| p.0 > 0.0 && p.1 > 0.0)
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .copied()
        })
        .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let guides: Vec<(f64, Vec<(f64, f64)>)> = match anchor {
        Some((xa, ya)) => panel
            .guides
            .iter()
            .map(|&p| {
                let y = |x: f64| ya / 3.0 * (x / xa).powf(p);
                (p, vec![(xa, y(xa)), (x1, y(x1))])
            })
            .collect(),
        None => Vec::new(),
    };
    if let Some(lowest) = guides.iter().map(|g| g.1[0].1).reduce(f64::min) {
        y0 = y0.min(lowest / 1.5);
    }
    // Keep guides inside the data range (they are clipped, not allowed to stretch it).
    if guides.is_empty() {
        y0 = y0.min(y1 / 10.0);
        y1 = y1.max(y0 * 10.0);
    }
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, (FONT_FAMILY, 1.05 * font))
        .margin((0.8 * font) as u32)
        .x_label_area_size((3.2 * font) as u32)
        .y_label_area_size((5.0 * font) as u32)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())?;
    chart
        .configure_mesh()
        .x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .x_labels(12)
        .y_labels(12)
        .x_label_formatter(&|v| log_tick(*v))
        .y_label_formatter(&|v| log_tick(*v))
        .label_style((FONT_FAMILY, 0.85 * font))
        .axis_desc_style((FONT_FAMILY, font))
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(242, 242, 242))
        .draw()?;
    let grey = RGBColor(110, 110, 110);
    for (p, pts) in guides {
        let style = ShapeStyle::from(grey).stroke_width(1);
        chart.draw_series(std::iter::once(DashedPathElement::new(
            clip_to(&pts, y0, y1),
            guide_dash(p),
            4,
            style,
        )))?;
    }
    draw_series(&mut chart, &panel.series, font, |p| p.0 > 0.0 && p.1 > 0.0)
}

/// Draws `series` (lines with markers) into `chart`, skipping non-finite points and those
/// `keep` rejects (non-positive values on log axes).
fn draw_series<DB, X, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<X, Y>>,
    series: &[Series],
    font: f64,
    keep: impl Fn(&(f64, f64)) -> bool,
) -> Result<(), PlotError>
where
    DB: DrawingBackend,
    DB::ErrorType: 'static,
    X: Ranged<ValueType = f64>,
    Y: Ranged<ValueType = f64>,
{
    for s in series {
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .copied()
            .filter(|p| p.0.is_finite() && p.1.is_finite() && keep(p))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let c = s.colour;
        // Markers only where they stay apart (a time series of many frames is a plain line).
        let r = if pts.len() <= 60 {
            (0.32 * font).max(3.0) as u32
        } else {
            0
        };
        let (width, dash) = if s.dashed { (1, true) } else { (2, false) };
        let line = ShapeStyle::from(c).stroke_width(width);
        if dash {
            chart.draw_series(std::iter::once(DashedPathElement::new(
                pts.clone(),
                6,
                4,
                line,
            )))?;
        } else {
            chart.draw_series(std::iter::once(PathElement::new(pts.clone(), line)))?;
        }
        if r > 0 {
            let marker = if dash { c.stroke_width(1) } else { c.filled() };
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, r, marker)))?;
        }
    }
    Ok(())
}

/// Draws `panels` side by side into a `width × height` PNG at `path`, under `title`, with
/// linear axes (a logarithmic y axis with `log_y`; non-positive values are then skipped).
/// Panels' guide lines are not drawn.
pub fn draw_lines(
    path: &Path,
    title: &str,
    panels: &[Panel],
    size: (u32, u32),
    log_y: bool,
) -> Result<(), PlotError> {
    draw_panels(path, title, panels, size, |area, panel, font| {
        let panel = Panel {
            guides: Vec::new(),
            ..panel.clone()
        };
        draw_linear_panel(area, &panel, font, log_y)
    })
}

/// The range of `values` (finite, and positive when `positive`), padded by 4 % of its span.
fn linear_range(values: impl Iterator<Item = f64>, positive: bool) -> Option<(f64, f64)> {
    let (mut a, mut b) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite() && (!positive || *v > 0.0)) {
        a = a.min(v);
        b = b.max(v);
    }
    if a > b {
        return None;
    }
    if positive {
        // Whole decades, so that the log axis has 1-2-5 key points to label.
        let lo = 10f64.powf(a.log10().floor());
        let hi = 10f64.powf(b.log10().ceil()).max(10.0 * lo);
        return Some((lo, hi));
    }
    let pad = if b > a {
        0.04 * (b - a)
    } else {
        0.5 * a.abs().max(1e-12)
    };
    Some((a - pad, b + pad))
}

/// A linear-axis tick label for an axis over `[lo, hi]`: as many decimals as a tenth of the
/// span needs; with a common power of ten (`7.25e-4`) when the values are below 0.01 or from
/// 10⁵ on.
fn linear_tick(v: f64, lo: f64, hi: f64) -> String {
    let step = ((hi - lo) / 10.0).abs().max(f64::MIN_POSITIVE);
    let mag = lo.abs().max(hi.abs());
    let digits = |scale: f64| (-(step / scale).log10().floor()).clamp(0.0, 6.0) as usize;
    if (1e-2..1e5).contains(&mag) || mag == 0.0 {
        format!("{v:.*}", digits(1.0))
    } else {
        let e = mag.log10().floor();
        let scale = 10f64.powf(e);
        format!("{:.*}e{e}", digits(scale), v / scale)
    }
}

fn draw_linear_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    font: f64,
    log_y: bool,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let area = split_legend(area, panel, font)?;
    let all = || panel.series.iter().flat_map(|s| s.points.iter().copied());
    let (Some((x0, x1)), Some((y0, y1))) = (
        linear_range(all().map(|p| p.0), false),
        linear_range(all().map(|p| p.1), log_y),
    ) else {
        area.draw_text(
            &format!("{}: no data", panel.title),
            &(FONT_FAMILY, font).into_font().color(&BLACK),
            (20, 40),
        )?;
        return Ok(());
    };
    let mut builder = ChartBuilder::on(&area);
    builder
        .caption(&panel.title, (FONT_FAMILY, 1.05 * font))
        .margin((0.8 * font) as u32)
        .x_label_area_size((3.2 * font) as u32)
        .y_label_area_size((5.5 * font) as u32);
    let x_tick = |v: &f64| linear_tick(*v, x0, x1);
    let y_tick = |v: &f64| linear_tick(*v, y0, y1);
    if log_y {
        let mut chart = builder.build_cartesian_2d(x0..x1, (y0..y1).log_scale())?;
        chart
            .configure_mesh()
            .x_desc(panel.x_label.as_str())
            .y_desc(panel.y_label.as_str())
            .x_label_formatter(&x_tick)
            .y_label_formatter(&|v| log_tick(*v))
            .y_labels(12)
            .label_style((FONT_FAMILY, 0.85 * font))
            .axis_desc_style((FONT_FAMILY, font))
            .bold_line_style(RGBColor(215, 215, 215))
            .light_line_style(RGBColor(242, 242, 242))
            .draw()?;
        draw_series(&mut chart, &panel.series, font, |p| p.1 > 0.0)
    } else {
        let mut chart = builder.build_cartesian_2d(x0..x1, y0..y1)?;
        chart
            .configure_mesh()
            .x_desc(panel.x_label.as_str())
            .y_desc(panel.y_label.as_str())
            .x_label_formatter(&x_tick)
            .y_label_formatter(&y_tick)
            .label_style((FONT_FAMILY, 0.85 * font))
            .axis_desc_style((FONT_FAMILY, font))
            .bold_line_style(RGBColor(215, 215, 215))
            .light_line_style(RGBColor(242, 242, 242))
            .draw()?;
        draw_series(&mut chart, &panel.series, font, |_| true)
    }
}

/// Draws the panel's legend (one entry per guide and series, in up to three columns) in a
/// strip at the bottom of `area` and returns the area above it for the chart.
fn split_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    font: f64,
) -> Result<DrawingArea<DB, Shift>, PlotError>
where
    DB::ErrorType: 'static,
{
    let entries = panel.guides.len() + panel.series.len();
    let (w, h) = area.dim_in_pixel();
    let line_h = (1.45 * font).ceil() as u32;
    let col_w = (20.0 * font) as u32;
    let cols = (w / col_w).clamp(1, 3) as usize;
    let rows = entries.div_ceil(cols) as u32;
    let legend_h = rows * line_h + line_h / 2;
    let (chart, strip) = area.split_vertically(h.saturating_sub(legend_h));
    draw_legend(
        &strip,
        panel,
        font,
        cols,
        line_h,
        (w as usize / cols) as i32,
    )?;
    Ok(chart)
}

/// Dash length of the order-`p` guide line (order 1 short dashes, order 2 long).
fn guide_dash(p: f64) -> u32 {
    if p < 1.5 { 4 } else { 10 }
}

/// The legend strip of a log-log panel: guides, then series, filled row by row.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    font: f64,
    cols: usize,
    line_h: u32,
    col_w: i32,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let text = (FONT_FAMILY, 0.8 * font).into_font().color(&BLACK);
    let r = (0.32 * font).max(3.0) as i32;
    let mut k = 0usize;
    let mut slot = || {
        let (col, row) = (k % cols, k / cols);
        k += 1;
        (
            12 + col as i32 * col_w,
            (line_h / 4) as i32 + row as i32 * line_h as i32 + line_h as i32 / 2,
        )
    };
    let grey = RGBColor(110, 110, 110);
    for &p in &panel.guides {
        let (x, y) = slot();
        area.draw(&DashedPathElement::new(
            vec![(x, y), (x + 30, y)],
            guide_dash(p),
            4,
            ShapeStyle::from(grey).stroke_width(1),
        ))?;
        area.draw_text(
            &format!("order {}", format_number(p)),
            &text,
            (x + 38, y - (0.45 * font) as i32),
        )?;
    }
    for s in &panel.series {
        let (x, y) = slot();
        if s.dashed {
            area.draw(&DashedPathElement::new(
                vec![(x, y), (x + 30, y)],
                6,
                4,
                ShapeStyle::from(s.colour).stroke_width(1),
            ))?;
            area.draw(&Circle::new((x + 15, y), r, s.colour.stroke_width(1)))?;
        } else {
            area.draw(&PathElement::new(
                vec![(x, y), (x + 30, y)],
                ShapeStyle::from(s.colour).stroke_width(2),
            ))?;
            area.draw(&Circle::new((x + 15, y), r, s.colour.filled()))?;
        }
        area.draw_text(&s.label, &text, (x + 38, y - (0.45 * font) as i32))?;
    }
    Ok(())
}

/// The part of the straight (log-log) segment `pts[0]–pts[1]` with y in `[y0, y1]`.
fn clip_to(pts: &[(f64, f64)], y0: f64, y1: f64) -> Vec<(f64, f64)> {
    let ((xa, ya), (xb, yb)) = (pts[0], pts[1]);
    let (lxa, lya, lxb, lyb) = (xa.ln(), ya.ln(), xb.ln(), yb.ln());
    let at = |ly: f64| (lxa + (ly - lya) / (lyb - lya) * (lxb - lxa)).exp();
    let clamp = |(x, y): (f64, f64)| -> (f64, f64) {
        if y < y0 {
            (at(y0.ln()), y0)
        } else if y > y1 {
            (at(y1.ln()), y1)
        } else {
            (x, y)
        }
    };
    if (ya < y0 && yb < y0) || (ya > y1 && yb > y1) || lyb == lya {
        return Vec::new();
    }
    vec![clamp((xa, ya)), clamp((xb, yb))]
}

/// How a stability case ended, for the map's markers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapMark {
    /// Finished with bounded energy.
    Finished,
    /// Stopped by the failure monitor with a diagnostic.
    Stopped,
    /// Finished (or ran out of steps) with unbounded energy or speed: not detected.
    SilentBlowUp,
    /// Step budget exhausted or panicked.
    Other,
}

/// One panel of the stability map.
#[derive(Clone, Debug, Default)]
pub struct MapPanel {
    /// Family name.
    pub title: String,
    /// The stiffness parameter.
    pub x_label: String,
    /// (stiffness, Δt / predicted limit, outcome, adaptive?).
    pub points: Vec<(f64, f64, MapMark, bool)>,
}

/// Draws the stability map: one panel per family, x = stiffness parameter (log), y = Δt over
/// the predicted limit of ALGORITHM §7.2 (log), one marker per case.
pub fn draw_stability_map(path: &Path, title: &str, panels: &[MapPanel]) -> Result<(), PlotError> {
    let cols = panels.len().clamp(1, 3);
    let rows = panels.len().max(1).div_ceil(cols);
    let (width, height) = (560 * cols as u32, 430 * rows as u32 + 90);
    let mut canvas = Canvas::new(width, height)?;
    {
        let root = canvas.area()?;
        root.fill(&WHITE)?;
        let font = 15.0;
        let (main, foot) = root.split_vertically(height - 42);
        let main = main.titled(title, (FONT_FAMILY, 1.2 * font))?;
        let areas = main.split_evenly((rows, cols));
        for (panel, area) in panels.iter().zip(&areas) {
            draw_map_panel(area, panel, font)?;
        }
        draw_map_legend(&foot, font)?;
        root.present()?;
    }
    canvas.write_png(path)
}

fn mark_style(m: MapMark) -> (RGBColor, &'static str) {
    match m {
        MapMark::Finished => (RGBColor(0, 158, 115), "finished"),
        MapMark::Stopped => (RGBColor(230, 159, 0), "stopped with diagnostic"),
        MapMark::SilentBlowUp => (RGBColor(213, 0, 0), "silent blow-up"),
        MapMark::Other => (RGBColor(90, 90, 90), "budget / panic"),
    }
}

fn draw_marker<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    at: (i32, i32),
    m: MapMark,
    adaptive: bool,
    r: i32,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let (c, _) = mark_style(m);
    let style = c.filled();
    if adaptive {
        area.draw(&Circle::new(at, r + 4, BLACK.stroke_width(1)))?;
    }
    match m {
        MapMark::Finished => area.draw(&Circle::new(at, r, style))?,
        MapMark::Stopped => area.draw(&TriangleMarker::new(at, r + 2, style))?,
        MapMark::SilentBlowUp => area.draw(&Cross::new(at, r + 1, c.stroke_width(3)))?,
        MapMark::Other => area.draw(&Rectangle::new(
            [(at.0 - r, at.1 - r), (at.0 + r, at.1 + r)],
            style,
        ))?,
    }
    Ok(())
}

fn draw_map_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    font: f64,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let style = (FONT_FAMILY, 0.9 * font).into_font().color(&BLACK);
    let mut x = 20;
    let y = 20;
    for m in [
        MapMark::Finished,
        MapMark::Stopped,
        MapMark::SilentBlowUp,
        MapMark::Other,
    ] {
        draw_marker(area, (x, y), m, false, 6)?;
        let (_, name) = mark_style(m);
        area.draw_text(name, &style, (x + 14, y - 8))?;
        x += 30 + (name.len() as f64 * 0.55 * 0.9 * font) as i32;
    }
    draw_marker(area, (x, y), MapMark::Finished, true, 6)?;
    area.draw_text(
        "ringed: adaptive Δt (at max Δt / initial limit)",
        &style,
        (x + 14, y - 8),
    )?;
    Ok(())
}

fn draw_map_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &MapPanel,
    font: f64,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    // Whole decades on x, labelled at the powers of ten.
    let (lo, hi) = log_range(panel.points.iter().map(|p| p.0)).unwrap_or((0.1, 10.0));
    let (mut e0, mut e1) = (lo.log10().floor(), hi.log10().ceil());
    if e1 - e0 < 2.0 {
        e0 -= 1.0;
        e1 += 1.0;
    }
    let (x0, x1) = (10f64.powf(e0), 10f64.powf(e1));
    let x_keys: Vec<f64> = (e0 as i32..=e1 as i32).map(|e| 10f64.powi(e)).collect();
    // Δt ratios: the tested factors are powers of two.
    let (y0, y1) =
        log_range(panel.points.iter().map(|p| p.1).chain([0.25, 8.0])).unwrap_or((0.2, 10.0));
    let y_keys: Vec<f64> = (-6..=6)
        .map(|e| 2f64.powi(e))
        .filter(|v| (y0..=y1).contains(v))
        .collect();
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, (FONT_FAMILY, 1.05 * font))
        .margin((0.8 * font) as u32)
        .x_label_area_size((3.2 * font) as u32)
        .y_label_area_size((4.2 * font) as u32)
        .build_cartesian_2d(
            (x0..x1).log_scale().with_key_points(x_keys),
            (y0..y1).log_scale().with_key_points(y_keys),
        )?;
    chart
        .configure_mesh()
        .x_desc(panel.x_label.as_str())
        .y_desc("Δt / predicted limit")
        .x_label_formatter(&|v| log_tick(*v))
        .y_label_formatter(&|v| format_number(*v))
        .label_style((FONT_FAMILY, 0.85 * font))
        .axis_desc_style((FONT_FAMILY, 0.95 * font))
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(242, 242, 242))
        .draw()?;
    chart.draw_series(std::iter::once(DashedPathElement::new(
        vec![(x0, 1.0), (x1, 1.0)],
        8,
        5,
        ShapeStyle::from(RGBColor(110, 110, 110)).stroke_width(1),
    )))?;
    let plot = chart.plotting_area().strip_coord_spec();
    // Markers in pixel coordinates so every shape has the same size; cases that share a
    // point are spread horizontally.
    let mut placed: Vec<(i32, i32)> = Vec::new();
    for &(x, y, m, adaptive) in &panel.points {
        let (mut px, py) = chart.backend_coord(&(x, y));
        let (ox, oy) = plot.get_base_pixel();
        while placed.iter().any(|&(a, b)| (a - px).abs() < 10 && b == py) {
            px += 11;
        }
        placed.push((px, py));
        draw_marker(&plot, (px - ox, py - oy), m, adaptive, 5)?;
    }
    Ok(())
}
