//! `treacle snapshot`: one particle frame drawn as a PNG picture, for a quick look at output
//! without other tools (cargo feature `plot`).
//!
//! The frame ([`ParticleFrame`], read with [`read_frame`] from the PLY or VTK files of
//! `treacle run`) is projected orthographically along a [`View`]; every particle is drawn as a
//! filled circle coloured by a field on the viridis scale, back to front (painter's order by
//! depth), with a radius of 0.55 particle spacings (the median nearest-neighbour distance,
//! [`particle_spacing`]) so a lattice of particles reads as a closed body. The axes have equal
//! scales, span the particles' projected bounding box plus a margin and are labelled in metres;
//! a vertical colour bar on the right shows the field's name, unit, minimum and maximum.
//!
//! Fields ([`available_fields`]): `speed` = |velocity| (the default), the velocity components
//! `vx`, `vy`, `vz`, the coordinates `x`, `y`, `z`, and every scalar field stored in the file
//! (`density`, `pressure`, `material`, … as chosen by the scene's `output.fields`).
//!
//! ```no_run
//! use std::path::Path;
//! use treacle::snapshot::{SnapshotOptions, View, snapshot_file};
//!
//! let opts = SnapshotOptions { field: "pressure".into(), view: View::Iso, ..Default::default() };
//! snapshot_file(Path::new("out/droplet/frame_00010.ply"), Path::new("f10.png"), &opts)?;
//! # Ok::<(), treacle::snapshot::SnapshotError>(())
//! ```
use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use plotters::prelude::*;

use crate::output::{OutputError, ParticleFrame, read_frame};
use crate::plot::{
    Canvas, ColourScale, FONT_FAMILY, PlotError, draw_colour_bar, font_size_for, format_number,
    format_tick,
};

/// Smallest image the snapshot layout (title, axis labels, colour bar) fits in \[px\].
pub const MIN_SNAPSHOT_SIZE: (u32, u32) = (320, 240);

/// Fields computed from positions and velocities, available in every frame.
pub const DERIVED_FIELDS: [&str; 7] = ["speed", "vx", "vy", "vz", "x", "y", "z"];

/// Circle radius in particle spacings: slightly more than half, so neighbours overlap.
const RADIUS_PER_SPACING: f64 = 0.55;

/// Direction the picture is taken from. Scenes have y up (gravity along −y), so [`View::Z`]
/// and [`View::X`] are side views and [`View::Y`] is the top view.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum View {
    /// Side view looking along +x (from the −x side): right = +z, up = +y.
    X,
    /// Top view looking down along −y: right = +x, up = −z (z grows downwards in the picture,
    /// as on a map seen from above).
    Y,
    /// Side view looking along −z (from the +z side): right = +x, up = +y. The default.
    #[default]
    Z,
    /// Isometric view from the (+x, +y, +z) octant: right = (x − z)/√2, up = (2y − x − z)/√6,
    /// y up.
    Iso,
}

/// The orthonormal basis of a [`View`]: a point `p` is drawn at `(p·right, p·up)`; larger
/// `p·forward` is farther from the viewer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewBasis {
    /// Screen right.
    pub right: [f64; 3],
    /// Screen up.
    pub up: [f64; 3],
    /// Viewing direction (away from the viewer).
    pub forward: [f64; 3],
}

impl View {
    /// All views, in the order of their names `x`, `y`, `z`, `iso`.
    pub const ALL: [View; 4] = [View::X, View::Y, View::Z, View::Iso];

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            View::X => "x",
            View::Y => "y",
            View::Z => "z",
            View::Iso => "iso",
        }
    }

    /// Screen axes and viewing direction.
    pub fn basis(self) -> ViewBasis {
        let s2 = std::f64::consts::FRAC_1_SQRT_2;
        let s3 = 1.0 / 3f64.sqrt();
        let s6 = 1.0 / 6f64.sqrt();
        let (right, up, forward) = match self {
            View::X => ([0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]),
            View::Y => ([1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]),
            View::Z => ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]),
            View::Iso => ([s2, 0.0, -s2], [-s6, 2.0 * s6, -s6], [-s3, -s3, -s3]),
        };
        ViewBasis { right, up, forward }
    }

    /// Axis titles (horizontal, vertical).
    fn axis_titles(self) -> (&'static str, &'static str) {
        match self {
            View::X => ("z [m]", "y [m]"),
            View::Y => ("x [m]", "z [m]"),
            View::Z => ("x [m]", "y [m]"),
            View::Iso => ("(x − z)/√2 [m]", "(2y − x − z)/√6 [m]"),
        }
    }

    /// What the picture shows, for its title.
    fn description(self) -> &'static str {
        match self {
            View::X => "side view along +x",
            View::Y => "top view along −y",
            View::Z => "side view along −z",
            View::Iso => "isometric view",
        }
    }
}

impl fmt::Display for View {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for View {
    type Err = SnapshotError;

    /// `x`, `y`, `z` or `iso`, case-insensitive.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        View::ALL
            .into_iter()
            .find(|v| v.name().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| SnapshotError::UnknownView { name: s.to_owned() })
    }
}

/// What to draw.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SnapshotOptions {
    /// Field the particles are coloured by (see [`available_fields`]). Default `speed`.
    pub field: String,
    /// Projection. Default [`View::Z`] (side view for a scene with gravity along −y).
    pub view: View,
    /// Image width \[px\], at least `MIN_SNAPSHOT_SIZE.0`. Default 1024.
    pub width: u32,
    /// Image height \[px\], at least `MIN_SNAPSHOT_SIZE.1`. Default 768.
    pub height: u32,
}

impl Default for SnapshotOptions {
    fn default() -> Self {
        Self {
            field: "speed".into(),
            view: View::Z,
            width: 1024,
            height: 768,
        }
    }
}

/// Errors of [`render_snapshot`] and [`snapshot_file`]. Errors about a frame name its file
/// when it came from one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SnapshotError {
    /// The frame file could not be read or parsed (the error names the file).
    #[error(transparent)]
    Frame(#[from] OutputError),
    /// The requested field is neither derived nor stored in the frame.
    #[error(
        "unknown field {field:?}{} (available: {})",
        in_file(frame),
        available.join(", ")
    )]
    UnknownField {
        /// The frame file, if any.
        frame: Option<PathBuf>,
        /// The requested name.
        field: String,
        /// The names that would have worked.
        available: Vec<String>,
    },
    /// A view name other than `x`, `y`, `z`, `iso`.
    #[error("unknown view {name:?} (expected x, y, z or iso)")]
    UnknownView {
        /// The rejected name.
        name: String,
    },
    /// The frame has no particles.
    #[error("no particles to draw{}", in_file(frame))]
    EmptyFrame {
        /// The frame file, if any.
        frame: Option<PathBuf>,
    },
    /// The image is smaller than [`MIN_SNAPSHOT_SIZE`].
    #[error(
        "image size {width}x{height} is too small for a snapshot (at least {}x{})",
        MIN_SNAPSHOT_SIZE.0,
        MIN_SNAPSHOT_SIZE.1
    )]
    TooSmall {
        /// Requested width \[px\].
        width: u32,
        /// Requested height \[px\].
        height: u32,
    },
    /// Drawing or writing the PNG failed.
    #[error(transparent)]
    Plot(#[from] PlotError),
}

fn in_file(frame: &Option<PathBuf>) -> String {
    match frame {
        Some(p) => format!(" in {}", p.display()),
        None => String::new(),
    }
}

impl SnapshotError {
    /// Attach the frame file to errors about the frame's content that do not name it yet.
    fn in_frame(mut self, path: &Path) -> Self {
        if let SnapshotError::UnknownField { frame, .. } | SnapshotError::EmptyFrame { frame } =
            &mut self
        {
            frame.get_or_insert_with(|| path.to_path_buf());
        }
        self
    }
}

/// The field names [`field_values`] accepts for `frame`: [`DERIVED_FIELDS`], then the
/// frame's stored fields not already listed.
pub fn available_fields(frame: &ParticleFrame) -> Vec<String> {
    let mut names: Vec<String> = DERIVED_FIELDS.iter().map(|s| s.to_string()).collect();
    for (name, _) in &frame.fields {
        if !names.contains(name) {
            names.push(name.clone());
        }
    }
    names
}

/// Per-particle values of the field `name` (see [`available_fields`]); a stored field wins
/// over a derived one of the same name. `None` for an unknown name.
pub fn field_values(frame: &ParticleFrame, name: &str) -> Option<Vec<f32>> {
    if let Some(v) = frame.field(name) {
        return Some(v.to_vec());
    }
    let component = |k: usize, of: &[[f32; 3]]| of.iter().map(|p| p[k]).collect();
    Some(match name {
        "speed" => frame
            .velocities
            .iter()
            .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
            .collect(),
        "vx" => component(0, &frame.velocities),
        "vy" => component(1, &frame.velocities),
        "vz" => component(2, &frame.velocities),
        "x" => component(0, &frame.positions),
        "y" => component(1, &frame.positions),
        "z" => component(2, &frame.positions),
        _ => return None,
    })
}

/// The SI unit of the fields `treacle run` writes (and of the derived fields), for labels.
pub fn field_unit(name: &str) -> Option<&'static str> {
    Some(match name {
        "speed" | "vx" | "vy" | "vz" => "m/s",
        "x" | "y" | "z" => "m",
        "density" => "kg/m³",
        "pressure" => "Pa",
        "mass" => "kg",
        _ => return None,
    })
}

/// Median distance from a particle to its nearest neighbour \[m\] (over up to 1024 particles
/// spread through the array; coincident particles are ignored). For particles seeded on a
/// lattice this is the seeding spacing Δx/particles_per_cell. `None` with fewer than two
/// distinct positions.
///
/// Uses a hash grid with cells of `extent / ∛N` (`extent` = largest side of the bounding box)
/// and searches up to three rings of cells around each sampled particle.
pub fn particle_spacing(positions: &[[f32; 3]]) -> Option<f64> {
    const SAMPLES: usize = 1024;
    const MAX_RING: i64 = 3;
    let n = positions.len();
    if n < 2 {
        return None;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    let extent = (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max);
    if !(extent > 0.0 && extent.is_finite()) {
        return None;
    }
    let h = extent / (n as f64).cbrt();
    let key = |p: &[f32; 3]| -> [i64; 3] {
        std::array::from_fn(|k| ((p[k] as f64 - lo[k]) / h).floor() as i64)
    };
    let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (i, p) in positions.iter().enumerate() {
        cells.entry(key(p)).or_default().push(i as u32);
    }
    let dist = |a: &[f32; 3], b: &[f32; 3]| -> f64 {
        (0..3)
            .map(|k| (a[k] as f64 - b[k] as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let mut nearest = Vec::with_capacity(SAMPLES.min(n));
    for i in (0..n).step_by((n / SAMPLES).max(1)) {
        let p = &positions[i];
        let c = key(p);
        let mut best = f64::INFINITY;
        for ring in 0..=MAX_RING {
            for dx in -ring..=ring {
                for dy in -ring..=ring {
                    for dz in -ring..=ring {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                            continue;
                        }
                        let Some(list) = cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                            continue;
                        };
                        for &j in list {
                            let d = dist(p, &positions[j as usize]);
                            if d > 0.0 && d < best {
                                best = d;
                            }
                        }
                    }
                }
            }
            // Cells beyond this ring are farther than ring·h from p.
            if best <= ring as f64 * h {
                break;
            }
        }
        if best.is_finite() {
            nearest.push(best);
        }
    }
    if nearest.is_empty() {
        return None;
    }
    let mid = nearest.len() / 2;
    let (_, median, _) = nearest.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*median)
}

/// A pixel rectangle, `x0..x1` × `y0..y1` (y down from the top of the image).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRect {
    /// Left edge (inclusive) \[px\].
    pub x0: i32,
    /// Right edge (exclusive) \[px\].
    pub x1: i32,
    /// Top edge (inclusive) \[px\].
    pub y0: i32,
    /// Bottom edge (exclusive) \[px\].
    pub y1: i32,
}

/// A rendered snapshot: the picture and facts about how it was drawn.
#[derive(Clone, Debug)]
pub struct Snapshot {
    /// The picture.
    pub canvas: Canvas,
    /// Where the particles are drawn (inside the axes).
    pub plot_area: PixelRect,
    /// The colour scale of the field (its minimum and maximum over the frame).
    pub scale: ColourScale,
    /// Estimated particle spacing \[m\] ([`particle_spacing`]).
    pub spacing: Option<f64>,
    /// Radius of the particle circles \[px\].
    pub radius_px: u32,
    /// Pixels per metre, the same horizontally and vertically.
    pub pixels_per_metre: f64,
}

impl Snapshot {
    /// Write the picture to `path` as PNG, atomically.
    pub fn write_png(&self, path: &Path) -> Result<(), SnapshotError> {
        Ok(self.canvas.write_png(path)?)
    }
}

/// Draw `frame` (see the [module docs](self)).
pub fn render_snapshot(
    frame: &ParticleFrame,
    opts: &SnapshotOptions,
) -> Result<Snapshot, SnapshotError> {
    let values = field_values(frame, &opts.field).ok_or_else(|| SnapshotError::UnknownField {
        frame: None,
        field: opts.field.clone(),
        available: available_fields(frame),
    })?;
    if frame.is_empty() {
        return Err(SnapshotError::EmptyFrame { frame: None });
    }
    let (width, height) = (opts.width, opts.height);
    if width < MIN_SNAPSHOT_SIZE.0 || height < MIN_SNAPSHOT_SIZE.1 {
        return Err(SnapshotError::TooSmall { width, height });
    }
    let mut canvas = Canvas::new(width, height)?;
    let scale = ColourScale::from_values(values.iter().map(|&v| v as f64))
        .expect("a validated, non-empty frame has finite values");
    let spacing = particle_spacing(&frame.positions);

    // Screen coordinates and depth.
    let b = opts.view.basis();
    let dot = |p: &[f32; 3], a: &[f64; 3]| -> f64 { (0..3).map(|k| p[k] as f64 * a[k]).sum() };
    let screen: Vec<(f64, f64)> = frame
        .positions
        .iter()
        .map(|p| (dot(p, &b.right), dot(p, &b.up)))
        .collect();
    let depth: Vec<f64> = frame.positions.iter().map(|p| dot(p, &b.forward)).collect();
    // Far to near; ties keep file order, so the picture is deterministic.
    let mut order: Vec<usize> = (0..frame.len()).collect();
    order.sort_by(|&i, &j| depth[j].total_cmp(&depth[i]));

    // Data bounds with a margin of 4 % of the body's size plus a particle radius.
    let bound = |f: &dyn Fn(&(f64, f64)) -> f64| {
        screen
            .iter()
            .map(f)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            })
    };
    let (u0, u1) = bound(&|s| s.0);
    let (v0, v1) = bound(&|s| s.1);
    let size = (u1 - u0).max(v1 - v0).max(spacing.unwrap_or(0.0));
    let size = if size > 0.0 { size } else { 1.0 };
    let pad = 0.04 * size + RADIUS_PER_SPACING * spacing.unwrap_or(0.0);
    let (u0, u1, v0, v1) = (u0 - pad, u1 + pad, v0 - pad, v1 + pad);

    let view = opts.view;
    let label = match field_unit(&opts.field) {
        Some(unit) => format!("{} [{unit}]", opts.field),
        None => opts.field.clone(),
    };
    let title = format!(
        "frame {} · t = {} s · {} particles · {}",
        frame.frame,
        format_number(frame.time),
        frame.len(),
        view.description()
    );
    let colours: Vec<RGBColor> = values.iter().map(|&v| scale.colour(v as f64)).collect();
    let layout = draw(
        &mut canvas,
        &Scene {
            title: &title,
            view,
            screen: &screen,
            order: &order,
            colours: &colours,
            bounds: (u0, u1, v0, v1),
            spacing,
            scale: &scale,
            bar_label: &label,
        },
    )?;
    Ok(Snapshot {
        canvas,
        plot_area: layout.plot_area,
        scale,
        spacing,
        radius_px: layout.radius_px,
        pixels_per_metre: layout.pixels_per_metre,
    })
}

/// Everything [`draw`] needs, in screen coordinates \[m\].
struct Scene<'a> {
    title: &'a str,
    view: View,
    screen: &'a [(f64, f64)],
    order: &'a [usize],
    colours: &'a [RGBColor],
    /// (u0, u1, v0, v1), margin included.
    bounds: (f64, f64, f64, f64),
    spacing: Option<f64>,
    scale: &'a ColourScale,
    bar_label: &'a str,
}

struct Layout {
    plot_area: PixelRect,
    radius_px: u32,
    pixels_per_metre: f64,
}

fn draw(canvas: &mut Canvas, s: &Scene<'_>) -> Result<Layout, PlotError> {
    let (width, height) = (canvas.width(), canvas.height());
    let font = font_size_for(height);
    let root = canvas.area()?;
    root.fill(&WHITE)?;
    let bar_width = (9.0 * font).round() as u32;
    let (main, bar) = root.split_horizontally(width - bar_width);
    // DejaVu Sans glyphs average about 0.55 em: drop the title's tail when it cannot fit.
    let title_font = 1.15 * font;
    let fits =
        |t: &str| t.chars().count() as f64 * 0.55 * title_font < main.dim_in_pixel().0 as f64;
    let mut title = s.title;
    while !fits(title) {
        match title.rsplit_once(" · ") {
            Some((head, _)) => title = head,
            None => break,
        }
    }
    let main = main.titled(title, (FONT_FAMILY, title_font))?;
    let margin = (0.8 * font).round() as u32;
    let x_labels = (3.6 * font).round() as u32;
    let y_labels = (5.2 * font).round() as u32;
    let builder = || {
        let mut b = ChartBuilder::on(&main);
        b.margin(margin)
            .x_label_area_size(x_labels)
            .y_label_area_size(y_labels);
        b
    };
    // Equal scales: the plotting area's size is fixed by the layout, so widen the shorter data
    // range around its centre until both give the same pixels per metre.
    let (pw, ph) = builder()
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)?
        .plotting_area()
        .dim_in_pixel();
    let (u0, u1, v0, v1) = s.bounds;
    let ppm = (pw as f64 / (u1 - u0)).min(ph as f64 / (v1 - v0));
    let (uc, vc) = (0.5 * (u0 + u1), 0.5 * (v0 + v1));
    let (hu, hv) = (0.5 * pw as f64 / ppm, 0.5 * ph as f64 / ppm);
    let mut chart = builder().build_cartesian_2d(uc - hu..uc + hu, vc - hv..vc + hv)?;

    let (x_title, y_title) = s.view.axis_titles();
    // The top view draws −z upwards; its labels show z.
    let flip = s.view == View::Y;
    let x_fmt = |v: &f64| format_tick(*v, 2.0 * hu);
    let y_fmt = |v: &f64| format_tick(if flip { -*v } else { *v }, 2.0 * hv);
    chart
        .configure_mesh()
        .x_desc(x_title)
        .y_desc(y_title)
        // At most one tick label per 5 (horizontal) or 2.5 (vertical) font heights.
        .x_labels((pw as f64 / (5.0 * font)).clamp(2.0, 10.0) as usize)
        .y_labels((ph as f64 / (2.5 * font)).clamp(2.0, 10.0) as usize)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style((FONT_FAMILY, font))
        .axis_desc_style((FONT_FAMILY, 1.1 * font))
        .bold_line_style(RGBColor(215, 215, 215))
        .light_line_style(RGBColor(240, 240, 240))
        .draw()?;

    let radius_px = match s.spacing {
        Some(sp) => (RADIUS_PER_SPACING * sp * ppm).round().clamp(1.0, 200.0) as u32,
        None => 3,
    };
    // Circles of 4 px and more get a darker rim so overlapping particles stay distinct.
    let rim = radius_px >= 4;
    chart.draw_series(s.order.iter().flat_map(|&i| {
        let c = s.colours[i];
        let at = s.screen[i];
        let dark = RGBColor(
            (c.0 as f64 * 0.7) as u8,
            (c.1 as f64 * 0.7) as u8,
            (c.2 as f64 * 0.7) as u8,
        );
        let fill = Circle::new(at, radius_px, c.filled());
        let edge = rim.then(|| Circle::new(at, radius_px, dark.stroke_width(1)));
        std::iter::once(fill).chain(edge)
    }))?;
    let (xr, yr) = chart.plotting_area().get_pixel_range();
    draw_colour_bar(&bar, s.scale, s.bar_label, font)?;
    root.present()?;
    Ok(Layout {
        plot_area: PixelRect {
            x0: xr.start,
            x1: xr.end,
            y0: yr.start,
            y1: yr.end,
        },
        radius_px,
        pixels_per_metre: ppm,
    })
}

/// Read the frame file `frame_path` (PLY or VTK, [`read_frame`]), draw it and write the PNG to
/// `png_path` atomically (the parent directory must exist). Errors name the file concerned.
pub fn snapshot_file(
    frame_path: &Path,
    png_path: &Path,
    opts: &SnapshotOptions,
) -> Result<Snapshot, SnapshotError> {
    let frame = read_frame(frame_path)?;
    let snap = render_snapshot(&frame, opts).map_err(|e| e.in_frame(frame_path))?;
    snap.write_png(png_path)?;
    Ok(snap)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_are_right_handed_and_orthonormal() {
        for v in View::ALL {
            let ViewBasis { right, up, forward } = v.basis();
            let dot = |a: [f64; 3], b: [f64; 3]| (0..3).map(|k| a[k] * b[k]).sum::<f64>();
            let cross = |a: [f64; 3], b: [f64; 3]| {
                [
                    a[1] * b[2] - a[2] * b[1],
                    a[2] * b[0] - a[0] * b[2],
                    a[0] * b[1] - a[1] * b[0],
                ]
            };
            for (a, b) in [(right, up), (up, forward), (forward, right)] {
                assert!(dot(a, b).abs() < 1e-15, "{v}");
            }
            for a in [right, up, forward] {
                assert!((dot(a, a) - 1.0).abs() < 1e-15, "{v}");
            }
            // Not mirrored: right = forward × up.
            let r = cross(forward, up);
            assert!((0..3).all(|k| (r[k] - right[k]).abs() < 1e-15), "{v}");
            assert_eq!(v.name().parse::<View>().unwrap(), v);
        }
        assert!("top".parse::<View>().is_err());
    }

    #[test]
    fn spacing_of_a_lattice() {
        // A 10×6×4 lattice with spacing 5 mm: every particle's nearest neighbour is at 5 mm.
        let mut p = Vec::new();
        for i in 0..10 {
            for j in 0..6 {
                for k in 0..4 {
                    p.push([i as f32 * 0.005, 1.0 + j as f32 * 0.005, k as f32 * 0.005]);
                }
            }
        }
        let s = particle_spacing(&p).unwrap();
        assert!((s - 0.005).abs() < 1e-6, "{s}");
        assert_eq!(particle_spacing(&p[..1]), None);
        assert_eq!(particle_spacing(&[[1.0; 3]; 4]), None);
    }

    #[test]
    fn fields() {
        let f = ParticleFrame {
            positions: vec![[1.0, 2.0, 3.0]],
            velocities: vec![[3.0, 0.0, -4.0]],
            fields: vec![("density".into(), vec![1000.0])],
            ..Default::default()
        };
        assert_eq!(field_values(&f, "speed").unwrap(), vec![5.0]);
        assert_eq!(field_values(&f, "vz").unwrap(), vec![-4.0]);
        assert_eq!(field_values(&f, "y").unwrap(), vec![2.0]);
        assert_eq!(field_values(&f, "density").unwrap(), vec![1000.0]);
        assert!(field_values(&f, "pressure").is_none());
        let e = render_snapshot(
            &f,
            &SnapshotOptions {
                field: "pressure".into(),
                ..Default::default()
            },
        )
        .unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown field \"pressure\" (available: speed, vx, vy, vz, x, y, z, density)"
        );
    }
}
