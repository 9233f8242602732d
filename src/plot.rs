//! PNG pictures drawn with [plotters](https://docs.rs/plotters/0.3) (cargo feature `plot`, on
//! by default).
//!
//! Generic building blocks shared by `treacle snapshot` ([`crate::snapshot`]) and other plots:
//!
//! * [`Canvas`]: an RGB pixel buffer to draw on with plotters' bitmap backend
//!   ([`Canvas::area`]), encoded as PNG and written atomically (temporary file + rename, via
//!   [`write_atomic_with`]) by [`Canvas::write_png`].
//! * [`register_fonts`]: text uses DejaVu Sans (`assets/fonts/`, Bitstream Vera licence in
//!   `assets/fonts/DejaVuSans-LICENSE.txt`) embedded in the binary and registered as plotters'
//!   `sans-serif` family ([`FONT_FAMILY`]), so no system font library or font file is needed at
//!   run time. [`Canvas::area`] registers it.
//! * [`ColourScale`] / [`viridis`]: a linear value → colour map with the viridis colours, and
//!   [`draw_colour_bar`], a vertical colour bar labelled with a title, its minimum and maximum.
//! * [`format_number`] (four significant digits), [`format_tick`], [`parse_image_size`]
//!   (`"1024x768"`), [`font_size_for`].
//!
//! Drawing errors from plotters convert into [`PlotError`] with `?`.
use std::io;
use std::path::Path;
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::colors::colormaps::ViridisRGB;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::output::{OutputError, write_atomic_with};

/// Font family name the embedded font is registered under (plotters' default family, so
/// chart labels use it without being told).
pub const FONT_FAMILY: &str = "sans-serif";

/// DejaVu Sans 2.37 (Debian package fonts-dejavu-core), Bitstream Vera licence.
static FONT_BYTES: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// Largest accepted image width or height \[px\].
pub const MAX_IMAGE_SIDE: u32 = 8192;

/// Errors of the plotting helpers.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// An image size is malformed or out of range.
    #[error("invalid image size {given:?}: {reason}")]
    InvalidSize {
        /// The size as given, e.g. `"0x768"`.
        given: String,
        /// What is wrong with it.
        reason: String,
    },
    /// plotters failed to draw (e.g. the area is too small for its labels).
    #[error("drawing failed: {0}")]
    Draw(String),
    /// The embedded font could not be registered.
    #[error("the embedded font could not be loaded")]
    Font,
    /// The PNG file could not be written (the error names the file).
    #[error(transparent)]
    Write(#[from] OutputError),
}

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for PlotError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        PlotError::Draw(e.to_string())
    }
}

/// Register the embedded DejaVu Sans as [`FONT_FAMILY`] (all styles fall back to it). Cheap
/// after the first call; [`Canvas::area`] calls it.
pub fn register_fonts() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT_FAMILY, FontStyle::Normal, FONT_BYTES).is_ok()
    });
    if ok { Ok(()) } else { Err(PlotError::Font) }
}

/// An RGB image (8 bits per channel, rows top to bottom) to draw on with plotters.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Canvas {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Canvas {
    /// A white `width × height` canvas; both sides must be in `1..=`[`MAX_IMAGE_SIDE`].
    pub fn new(width: u32, height: u32) -> Result<Self, PlotError> {
        check_side(width, height)?;
        Ok(Self {
            width,
            height,
            rgb: vec![255; 3 * width as usize * height as usize],
        })
    }

    /// Width \[px\].
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height \[px\].
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The pixels, `3 × width × height` bytes, row-major from the top-left corner.
    pub fn rgb(&self) -> &[u8] {
        &self.rgb
    }

    /// The colour of pixel `(x, y)` (`y` down from the top), `None` outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> Option<[u8; 3]> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let i = 3 * (y as usize * self.width as usize + x as usize);
        Some([self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]])
    }

    /// A plotters drawing area covering the whole canvas (registers the font first). Call
    /// `present()` on it, or drop it, before reading the pixels.
    pub fn area(&mut self) -> Result<DrawingArea<BitMapBackend<'_>, Shift>, PlotError> {
        register_fonts()?;
        let size = (self.width, self.height);
        Ok(BitMapBackend::with_buffer(&mut self.rgb, size).into_drawing_area())
    }

    /// Encode as an 8-bit RGB PNG.
    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.encode_png_to(&mut out)
            .expect("encoding a checked image into a Vec cannot fail");
        out
    }

    /// Atomically write the image to `path` as PNG (temporary file in the same directory,
    /// then rename; an existing file is replaced). The parent directory must exist.
    pub fn write_png(&self, path: &Path) -> Result<(), PlotError> {
        write_atomic_with(path, |w| self.encode_png_to(w))?;
        Ok(())
    }

    fn encode_png_to(&self, w: &mut dyn io::Write) -> io::Result<()> {
        let mut encoder = png::Encoder::new(w, self.width, self.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        let mut writer = encoder.write_header().map_err(io::Error::other)?;
        writer
            .write_image_data(&self.rgb)
            .map_err(io::Error::other)?;
        writer.finish().map_err(io::Error::other)
    }
}

fn check_side(width: u32, height: u32) -> Result<(), PlotError> {
    if (1..=MAX_IMAGE_SIDE).contains(&width) && (1..=MAX_IMAGE_SIDE).contains(&height) {
        Ok(())
    } else {
        Err(PlotError::InvalidSize {
            given: format!("{width}x{height}"),
            reason: format!("width and height must be between 1 and {MAX_IMAGE_SIDE} pixels"),
        })
    }
}

/// Parse `"WIDTHxHEIGHT"` (e.g. `"1024x768"`; `X` and `×` also separate), each side in
/// `1..=`[`MAX_IMAGE_SIDE`].
pub fn parse_image_size(s: &str) -> Result<(u32, u32), PlotError> {
    let bad = |reason: &str| PlotError::InvalidSize {
        given: s.to_owned(),
        reason: reason.to_owned(),
    };
    let Some((w, h)) = s.trim().split_once(['x', 'X', '×']) else {
        return Err(bad("expected WIDTHxHEIGHT, e.g. 1024x768"));
    };
    let (Ok(w), Ok(h)) = (w.trim().parse::<u32>(), h.trim().parse::<u32>()) else {
        return Err(bad(
            "expected WIDTHxHEIGHT with whole numbers of pixels, e.g. 1024x768",
        ));
    };
    check_side(w, h).map_err(|_| {
        bad(&format!(
            "width and height must be between 1 and {MAX_IMAGE_SIDE} pixels"
        ))
    })?;
    Ok((w, h))
}

/// The viridis colour map at `t ∈ [0, 1]` (dark purple at 0, yellow at 1); `t` is clamped and
/// NaN maps to 0.
pub fn viridis(t: f64) -> RGBColor {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    ViridisRGB.get_color_normalized(t, 0.0, 1.0)
}

/// A linear colour scale: `min` ↦ [`viridis`]`(0)`, `max` ↦ [`viridis`]`(1)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ColourScale {
    /// Value at the bottom of the scale.
    pub min: f64,
    /// Value at the top of the scale.
    pub max: f64,
}

impl ColourScale {
    /// The scale spanning the finite values of `values`; `None` if there are none.
    pub fn from_values(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let mut range: Option<(f64, f64)> = None;
        for v in values.into_iter().filter(|v| v.is_finite()) {
            range = Some(match range {
                None => (v, v),
                Some((lo, hi)) => (lo.min(v), hi.max(v)),
            });
        }
        range.map(|(min, max)| Self { min, max })
    }

    /// Where `v` lies on the scale, clamped to `[0, 1]`; `0.5` for a scale with `min == max`.
    pub fn position(&self, v: f64) -> f64 {
        if self.max > self.min {
            ((v - self.min) / (self.max - self.min)).clamp(0.0, 1.0)
        } else {
            0.5
        }
    }

    /// The colour of `v`.
    pub fn colour(&self, v: f64) -> RGBColor {
        viridis(self.position(v))
    }

    /// The value range a colour bar shows: `[min, max]`, widened around the value when
    /// `min == max` so the axis has a non-empty range.
    pub fn axis_range(&self) -> (f64, f64) {
        if self.max > self.min {
            (self.min, self.max)
        } else {
            let d = if self.min == 0.0 {
                1.0
            } else {
                0.01 * self.min.abs()
            };
            (self.min - d, self.max + d)
        }
    }
}

/// `v` with four significant digits: `0`, `1.25`, `-0.003125`, `998.5`, `1.235e6`; trailing
/// zeros after the decimal point are dropped. Exponent form outside `[1e-3, 1e5)`.
pub fn format_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v == 0.0 { "0".into() } else { v.to_string() };
    }
    let a = v.abs();
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.3e}");
    }
    let decimals = (3 - a.log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        &s
    };
    if s == "-0" { "0".into() } else { s.into() }
}

/// A tick label on an axis spanning `span`: [`format_number`], with values below `1e-9 × span`
/// shown as `0` (tick positions computed in floating point miss zero by rounding errors).
pub fn format_tick(v: f64, span: f64) -> String {
    if v.abs() <= 1e-9 * span.abs() {
        "0".into()
    } else {
        format_number(v)
    }
}

/// Font size for an image `height` pixels tall: 16 px at 768 px, scaled, at least 10 px.
pub fn font_size_for(height: u32) -> f64 {
    (16.0 * height as f64 / 768.0).clamp(10.0, 64.0)
}

/// Draw a vertical colour bar filling `area`: `title` (e.g. `"speed [m/s]"`) and the maximum
/// on top, the bar with tick labels on its right, the minimum below. Text is `font_px` high.
pub fn draw_colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    scale: &ColourScale,
    title: &str,
    font_px: f64,
) -> Result<(), PlotError>
where
    DB::ErrorType: 'static,
{
    let (w, h) = area.dim_in_pixel();
    let line = (1.4 * font_px).ceil() as i32;
    let centre = w as i32 / 2;
    let top = TextStyle::from((FONT_FAMILY, font_px).into_font())
        .color(&BLACK)
        .pos(Pos::new(HPos::Center, VPos::Top));
    let pad = (0.6 * font_px) as i32;
    area.draw_text(title, &top, (centre, pad))?;
    area.draw_text(
        &format!("max {}", format_number(scale.max)),
        &top,
        (centre, pad + line),
    )?;
    area.draw_text(
        &format!("min {}", format_number(scale.min)),
        &top,
        (centre, h as i32 - pad - line),
    )?;

    let (lo, hi) = scale.axis_range();
    let bar_px = (1.8 * font_px).round() as u32;
    let labels_px = (4.8 * font_px).round() as u32;
    let side = (w.saturating_sub(bar_px + labels_px) / 2) as i32;
    let mut chart = ChartBuilder::on(area)
        .margin_top(pad + 2 * line + pad)
        .margin_bottom(2 * pad + line)
        .margin_left(side)
        .margin_right(side)
        .right_y_label_area_size(labels_px)
        .build_cartesian_2d(0.0..1.0, lo..hi)?;
    // One rectangle per pixel row, coloured by the value at its centre.
    let rows = chart.plotting_area().dim_in_pixel().1.max(1);
    let step = (hi - lo) / rows as f64;
    chart.draw_series((0..rows).map(|k| {
        let v0 = lo + step * k as f64;
        Rectangle::new(
            [(0.0, v0), (1.0, v0 + step)],
            scale.colour(v0 + 0.5 * step).filled(),
        )
    }))?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .axis_style(BLACK)
        .set_all_tick_mark_size((0.4 * font_px).round() as u32)
        .y_labels(6)
        .y_label_formatter(&|v| format_tick(*v, hi - lo))
        .label_style((FONT_FAMILY, font_px))
        .draw()?;
    chart.draw_series(std::iter::once(Rectangle::new(
        [(0.0, lo), (1.0, hi)],
        BLACK.stroke_width(1),
    )))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_have_four_significant_digits() {
        assert_eq!(format_number(0.0), "0");
        assert_eq!(format_number(1.0), "1");
        assert_eq!(format_number(1.23456), "1.235");
        assert_eq!(format_number(-0.0031254), "-0.003125");
        assert_eq!(format_number(998.5), "998.5");
        assert_eq!(format_number(12345.6), "12346");
        assert_eq!(format_number(1234567.0), "1.235e6");
        assert_eq!(format_number(2.5e-5), "2.500e-5");
        assert_eq!(format_tick(6.9e-18, 0.1), "0");
        assert_eq!(format_tick(0.02, 0.1), "0.02");
    }

    #[test]
    fn sizes() {
        assert_eq!(parse_image_size("1024x768").unwrap(), (1024, 768));
        assert_eq!(parse_image_size(" 640 X 480 ").unwrap(), (640, 480));
        for bad in ["1024", "0x768", "axb", "1024x99999", "-1x5", ""] {
            let e = parse_image_size(bad).unwrap_err();
            assert!(e.to_string().contains(&format!("{bad:?}")), "{e}");
        }
        assert!(Canvas::new(0, 1).is_err());
    }

    #[test]
    fn colour_scale() {
        let s = ColourScale::from_values([2.0, f64::NAN, -1.0, 5.0]).unwrap();
        assert_eq!((s.min, s.max), (-1.0, 5.0));
        assert_eq!(s.position(2.0), 0.5);
        assert_eq!(s.position(99.0), 1.0);
        // The end points of viridis: dark purple and yellow.
        assert_eq!(s.colour(-1.0), RGBColor(68, 1, 84));
        assert_eq!(s.colour(5.0), RGBColor(254, 232, 37));
        let flat = ColourScale { min: 0.0, max: 0.0 };
        assert_eq!(flat.position(0.0), 0.5);
        assert_eq!(flat.axis_range(), (-1.0, 1.0));
        assert!(ColourScale::from_values([f64::NAN]).is_none());
    }

    #[test]
    fn font_loads_and_text_draws() {
        let mut c = Canvas::new(120, 40).unwrap();
        {
            let area = c.area().unwrap();
            area.draw_text("Ag", &(FONT_FAMILY, 24).into_font().color(&BLACK), (5, 5))
                .unwrap();
            area.present().unwrap();
        }
        let dark = c.rgb().chunks(3).filter(|p| p[0] < 128).count();
        assert!(dark > 20, "{dark} dark pixels");
    }

    #[test]
    fn png_header_and_size() {
        let c = Canvas::new(7, 3).unwrap();
        let png = c.encode_png();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        let decoder = png::Decoder::new(std::io::Cursor::new(png));
        let reader = decoder.read_info().unwrap();
        assert_eq!((reader.info().width, reader.info().height), (7, 3));
    }
}
