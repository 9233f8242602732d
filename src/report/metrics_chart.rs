//! `treacle plot`: columns of runs' `metrics.csv` against time (or another column), one line
//! per run and one panel per column, e.g. the volume of a drop for several sound speeds
//! (\[Su21\] Fig. 10) or the largest apparent viscosity and strain rate per frame (\[Li\] Fig. 11).
use std::path::{Path, PathBuf};

use super::plots::{PALETTE, Panel, Series, draw_lines};
use crate::output::{METRICS_FILE, MetricsTable, OutputError};
use crate::plot::PlotError;

/// Errors of [`read_runs`] and [`draw_metrics_chart`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MetricsChartError {
    /// A metrics file could not be read or parsed.
    #[error(transparent)]
    Read(#[from] OutputError),
    /// A run's metrics file has no column of this name.
    #[error("{} has no column {column:?} (its columns: {})", path.display(), available.join(", "))]
    MissingColumn {
        /// The metrics file.
        path: PathBuf,
        /// The column asked for.
        column: String,
        /// The columns the file has.
        available: Vec<String>,
    },
    /// A run has fewer than two rows: nothing to draw a line through.
    #[error("{} has {rows} rows; a line needs at least 2", path.display())]
    TooFewRows {
        /// The metrics file.
        path: PathBuf,
        /// Its number of rows.
        rows: usize,
    },
    /// Drawing or writing the picture failed.
    #[error("{}: {source}", path.display())]
    Plot {
        /// The PNG file.
        path: PathBuf,
        /// What failed.
        #[source]
        source: PlotError,
    },
}

/// One run to draw: its legend label and its metrics.
#[derive(Debug, Clone)]
pub struct MetricsRun {
    /// Legend text.
    pub label: String,
    /// The run's metrics.
    pub table: MetricsTable,
}

/// Reads the metrics of each path: a run directory (its `metrics.csv`) or a CSV file. The
/// label of each run is its directory's name.
///
/// # Errors
/// [`MetricsChartError::Read`] naming the file that could not be read or parsed.
pub fn read_runs(paths: &[PathBuf]) -> Result<Vec<MetricsRun>, MetricsChartError> {
    paths
        .iter()
        .map(|p| {
            let file = if p.is_dir() {
                p.join(METRICS_FILE)
            } else {
                p.clone()
            };
            let dir = if p.is_dir() {
                p.as_path()
            } else {
                p.parent().unwrap_or(Path::new("."))
            };
            let label = dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_else(|| dir.display().to_string());
            Ok(MetricsRun {
                label,
                table: MetricsTable::read(&file)?,
            })
        })
        .collect()
}

/// The (x, y) points of column `y` against column `x` of `table`.
fn points(table: &MetricsTable, x: &str, y: &str) -> Result<Vec<(f64, f64)>, MetricsChartError> {
    let col = |name: &str| {
        table
            .column(name)
            .ok_or_else(|| MetricsChartError::MissingColumn {
                path: table.path.clone(),
                column: name.to_owned(),
                available: table.columns.clone(),
            })
    };
    let (xs, ys) = (col(x)?, col(y)?);
    if xs.len() < 2 {
        return Err(MetricsChartError::TooFewRows {
            path: table.path.clone(),
            rows: xs.len(),
        });
    }
    Ok(xs.into_iter().zip(ys).collect())
}

/// The axis text of a column: its name, with the unit for the columns every run writes.
pub fn axis_label(column: &str) -> String {
    let unit = match column {
        "time" | "wall_seconds" | "dt_min" | "dt_max" => "s",
        "mass" => "kg",
        "volume" => "m³",
        "kinetic_energy" => "J",
        "max_speed" => "m/s",
        "max_apparent_viscosity" => "Pa·s",
        "max_strain_rate" => "1/s",
        _ => return column.to_owned(),
    };
    format!("{column} [{unit}]")
}

/// Draws columns `ys` of every run against column `x` into a PNG at `out`: one panel per
/// column side by side, one line per run, linear axes (a logarithmic y axis with `log_y`).
///
/// # Errors
/// [`MetricsChartError::MissingColumn`] if a run lacks a column, [`MetricsChartError::TooFewRows`]
/// if it has fewer than two frames, [`MetricsChartError::Plot`] if drawing or writing fails.
pub fn draw_metrics_chart(
    out: &Path,
    title: &str,
    runs: &[MetricsRun],
    x: &str,
    ys: &[String],
    log_y: bool,
) -> Result<(), MetricsChartError> {
    let mut panels = Vec::with_capacity(ys.len());
    for y in ys {
        let series = runs
            .iter()
            .enumerate()
            .map(|(i, run)| {
                Ok(Series {
                    label: run.label.clone(),
                    colour: PALETTE[i % PALETTE.len()],
                    points: points(&run.table, x, y)?,
                    dashed: i >= PALETTE.len(),
                })
            })
            .collect::<Result<Vec<_>, MetricsChartError>>()?;
        panels.push(Panel {
            title: y.clone(),
            x_label: axis_label(x),
            y_label: axis_label(y),
            series,
            guides: Vec::new(),
        });
    }
    let width = 200 + 700 * panels.len().max(1) as u32;
    draw_lines(out, title, &panels, (width, 650), log_y).map_err(|source| MetricsChartError::Plot {
        path: out.to_path_buf(),
        source,
    })
}
