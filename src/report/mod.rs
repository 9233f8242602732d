//! `treacle report`: temporal accuracy and stability reports (the user's "error against run
//! time" and "numerical stability on stiff and extreme cases").
//!
//! * [`accuracy`]: `treacle report accuracy SPEC` runs each case of a SPEC to a fixed end time on
//!   a ladder of fixed Δt for each named integrator, measures the displacement, velocity and
//!   stress errors against a much smaller Δt of the same discretisation (and against the
//!   analytic solution where the case has one), fits the observed order on the asymptotic part
//!   of the ladder ([`fit`]) and compares the integrators in work-precision terms.
//! * [`stability`]: `treacle report stability SPEC` runs a catalogue of stiff and extreme cases
//!   to completion or to a detected failure and classifies each outcome (finished, stopped with
//!   a diagnostic, silent blow-up, panic), with fixed Δt at multiples of the predicted limit of
//!   ALGORITHM §7.2 ([`time_step_limits`](crate::step::monitor::time_step_limits)).
//!
//! Both write one folder: a CSV with one row per run, a markdown summary and PNG plots drawn
//! with plotters ([`crate::plot`]). They are **resumable**: every run's result is written
//! atomically to `OUT/runs/` as soon as it finishes ([`store`]), keyed by a hash of its
//! definition and scene, and a rerun loads those instead of running again. Progress is shown
//! with indicatif on a terminal. The SPEC formats are documented in `docs/reports.md`; the
//! shipped SPECs are in `scenes/reports/`.
//!
//! Integrators are named in a SPEC as an [`IntegratorConfig`](crate::config::IntegratorConfig)
//! (every field optional, with its defaults) and applied by setting the scene's
//! [`MpmConfig::integrator`](crate::config::MpmConfig::integrator) before the app is built,
//! so the reports follow whatever integrators the configuration offers.
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::output::OutputError;
use crate::plot::PlotError;
use crate::scene::{FieldIssue, SceneError};

pub mod accuracy;
pub mod cases;
pub mod coiling;
pub mod drive;
pub mod fit;
pub mod metrics_chart;
mod plots;
pub mod stability;
pub mod store;
pub mod viscosity;

pub use accuracy::{AccuracyReport, AccuracySpec, run_accuracy};
pub use stability::{StabilityReport, StabilitySpec, run_stability};

/// Why a report could not be produced (a case that fails numerically is a result, not an
/// error).
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The SPEC could not be read, parsed or validated; the message names the file, line and
    /// field (scene files a case names are checked here too).
    #[error(transparent)]
    Spec(#[from] SceneError),
    /// A result file could not be written or read back.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// A plot could not be drawn or written.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// Written output holds a non-finite number (a bug: every writer rejects them).
    #[error("non-finite numbers in written output: {0}")]
    NonFinite(String),
}

/// Options shared by both reports.
#[derive(Clone, Debug)]
pub struct ReportOptions {
    /// Output folder (created if missing; results already in it are reused).
    pub out_dir: PathBuf,
    /// Run the SPEC's quick (CI) subset instead of the full report.
    pub quick: bool,
    /// Show an indicatif progress bar (it draws only when stderr is a terminal).
    pub progress: bool,
    /// Stability report: keep the per-case particle files (first and last healthy state)
    /// after their NaN check instead of deleting them.
    pub keep_frames: bool,
}

impl ReportOptions {
    /// Options writing to `out_dir`, full report, no progress bar, frames not kept.
    pub fn new(out_dir: impl Into<PathBuf>) -> Self {
        Self {
            out_dir: out_dir.into(),
            quick: false,
            progress: false,
            keep_frames: false,
        }
    }
}

/// Writes `DIR/name` (atomically): `header`, then one line per row; records the path in
/// `files`.
fn write_csv(
    dir: &Path,
    name: &str,
    header: &str,
    rows: impl Iterator<Item = String>,
    files: &mut Vec<PathBuf>,
) -> Result<(), ReportError> {
    let mut csv = String::from(header);
    csv.push('\n');
    for row in rows {
        csv.push_str(&row);
        csv.push('\n');
    }
    let path = dir.join(name);
    crate::output::write_atomic(&path, csv.as_bytes())?;
    files.push(path);
    Ok(())
}

/// A report's title: the SPEC's own, else "`kind` report: SPEC path".
fn report_title(title: &str, kind: &str, spec_path: &Path) -> String {
    if title.is_empty() {
        format!("{kind} report: {}", spec_path.display())
    } else {
        title.to_string()
    }
}

/// The default output folder of a SPEC: `out/reports/<kind>-<spec stem>[-quick]`.
pub fn default_out_dir(kind: &str, spec: &Path, quick: bool) -> PathBuf {
    let stem = spec
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "spec".into());
    let name = if quick {
        format!("{kind}-{stem}-quick")
    } else {
        format!("{kind}-{stem}")
    };
    PathBuf::from("out").join("reports").join(name)
}

/// Reads and parses a SPEC (RON with the `implicit_some` extension on), then validates it
/// with `validate`; errors are located in the file like scene errors.
pub(crate) fn load_spec<T: DeserializeOwned>(
    path: &Path,
    validate: impl FnOnce(&T, &Path) -> Vec<FieldIssue>,
) -> Result<(T, String), SceneError> {
    let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let spec: T = ron::Options::default()
        .with_default_extension(ron::extensions::Extensions::IMPLICIT_SOME)
        .from_str(&text)
        .map_err(|e| SceneError::from_ron(path, &text, e))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let issues = validate(&spec, base);
    if !issues.is_empty() {
        return Err(SceneError::from_issues(path, Some(&text), issues));
    }
    Ok((spec, text))
}

/// RON text of a value (for run hashes).
pub(crate) fn ron_text<T: Serialize>(v: &T) -> String {
    ron::to_string(v).unwrap_or_default()
}

/// A progress bar over `len` runs (hidden unless `enabled`).
pub(crate) fn progress_bar(len: u64, enabled: bool) -> ProgressBar {
    if !enabled {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {wide_msg}",
        )
        .expect("valid template"),
    );
    bar
}

/// Checks every `.csv` and `.md` file directly in `dir` and in `dir/runs` for non-finite
/// number fields ([`store::non_finite_fields`]); returns the number of files checked.
pub(crate) fn check_text_outputs(dir: &Path) -> Result<usize, ReportError> {
    let mut checked = 0;
    let mut bad = Vec::new();
    for d in [dir.to_path_buf(), dir.join("runs")] {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        paths.sort();
        for p in paths {
            let ext = p.extension().and_then(|e| e.to_str()).unwrap_or("");
            if !matches!(ext, "csv" | "md" | "ron") {
                continue;
            }
            let text = std::fs::read_to_string(&p).map_err(|e| OutputError::io("read", &p, e))?;
            let fields = store::non_finite_fields(&text);
            if !fields.is_empty() {
                bad.push(format!("{} at {}", p.display(), fields.join(" ")));
            }
            checked += 1;
        }
    }
    if bad.is_empty() {
        Ok(checked)
    } else {
        Err(ReportError::NonFinite(bad.join("; ")))
    }
}
