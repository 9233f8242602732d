//! The error type of the output layer.
//!
//! Every variant says *what* went wrong and, where a file is involved, *which* file. Errors
//! produced by [`ParticleFrame::validate`](super::ParticleFrame::validate) have no path yet
//! (`path: None`); the writers attach the target path before returning them, so an error from
//! [`write_frame`](super::write_frame) always names the file that was *not* written.
use std::fmt;
use std::io;
use std::path::{Path, PathBuf};

/// Where in a PLY file a problem was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyLocation {
    /// 1-based line number inside the ASCII header.
    HeaderLine(usize),
    /// 1-based line number of the file, inside an ASCII body.
    Line(usize),
    /// Byte offset from the start of the file, inside a binary body.
    Offset(u64),
}

impl fmt::Display for PlyLocation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PlyLocation::HeaderLine(line) => write!(f, "header line {line}"),
            PlyLocation::Line(line) => write!(f, "line {line}"),
            PlyLocation::Offset(offset) => write!(f, "byte offset {offset}"),
        }
    }
}

/// Errors of the output layer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OutputError {
    /// An I/O operation on `path` failed. `action` is a short verb phrase such as `"write"`.
    #[error("cannot {action} {}: {source}", path.display())]
    Io {
        /// What was being done, e.g. `"write"`.
        action: &'static str,
        /// The file concerned.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: io::Error,
    },

    /// A per-particle value is NaN or infinite. `quantity` is e.g. `"position.x"`,
    /// `"velocity.y"` or a field name such as `"density"`.
    #[error("non-finite {quantity} = {value} at particle {index}{}", in_path(path))]
    NonFinite {
        /// The file that was not written (`None` straight from `validate`).
        path: Option<PathBuf>,
        /// Particle index.
        index: usize,
        /// What the value is: `"position.x"`, `"velocities"`, a field name, ….
        quantity: String,
        /// The offending value.
        value: f32,
    },

    /// The frame time is NaN or infinite.
    #[error("non-finite frame time {value}{}", in_path(path))]
    NonFiniteTime {
        /// The file that was not written (`None` straight from `validate`).
        path: Option<PathBuf>,
        /// The offending time.
        value: f64,
    },

    /// A per-particle array does not have one entry per particle. `quantity` is `"velocities"`
    /// or the field name; `expected` is the number of positions.
    #[error(
        "{quantity} has {found} entries but there are {expected} particles{}",
        in_path(path)
    )]
    LengthMismatch {
        /// The file that was not written (`None` straight from `validate`).
        path: Option<PathBuf>,
        /// What the value is: `"position.x"`, `"velocities"`, a field name, ….
        quantity: String,
        /// The required number.
        expected: usize,
        /// The number found.
        found: usize,
    },

    /// A field name cannot be written (empty, reserved, duplicated or with characters outside
    /// `[A-Za-z0-9_.-]`).
    #[error("invalid field name {name:?}: {reason}{}", in_path(path))]
    InvalidFieldName {
        /// The file that was not written (`None` straight from `validate`).
        path: Option<PathBuf>,
        /// The rejected name.
        name: String,
        /// Why it was rejected.
        reason: &'static str,
    },

    /// The frame has more particles than the format can index.
    #[error("{count} particles exceed the limit of {max} for {}", path.display())]
    TooManyParticles {
        /// The file concerned.
        path: PathBuf,
        /// Number of particles in the frame.
        count: usize,
        /// Largest supported number.
        max: usize,
    },

    /// A PLY file could not be parsed (or uses a feature the reader does not support).
    #[error("malformed PLY {} at {at}: {message}", path.display())]
    MalformedPly {
        /// The file concerned.
        path: PathBuf,
        /// Where in the file.
        at: PlyLocation,
        /// What is wrong.
        message: String,
    },

    /// A legacy VTK file could not be parsed (or uses a feature the reader does not support).
    #[error("malformed VTK {} at byte offset {offset}: {message}", path.display())]
    MalformedVtk {
        /// The file concerned.
        path: PathBuf,
        /// Byte offset from the start of the file where the problem was found.
        offset: u64,
        /// What is wrong.
        message: String,
    },

    /// A file given as a particle frame is neither PLY, legacy VTK nor a frame index.
    #[error(
        "{} is not a particle frame: expected a PLY file (starting with \"ply\"), a legacy VTK \
         file (starting with \"# vtk\") or a frame index (starting with \"treacle frame \
         parts\"), found {found}",
        path.display()
    )]
    UnrecognisedFrameFile {
        /// The file concerned.
        path: PathBuf,
        /// A short, printable description of the file's first bytes.
        found: String,
    },

    /// A metrics value is NaN or infinite; `column` is the CSV column name.
    #[error("non-finite metric {column} = {value} in frame {frame} for {}", path.display())]
    NonFiniteMetric {
        /// The file concerned.
        path: PathBuf,
        /// Frame number of the row.
        frame: u32,
        /// CSV column name.
        column: String,
        /// The offending value.
        value: f64,
    },

    /// A metrics row carries a different number of extra values than the writer has extra
    /// columns.
    #[error(
        "metrics row for frame {frame} has {found} extra values but {} has {expected} extra columns",
        path.display()
    )]
    MetricsColumnCount {
        /// The file concerned.
        path: PathBuf,
        /// Frame number of the row.
        frame: u32,
        /// The required number.
        expected: usize,
        /// The number found.
        found: usize,
    },

    /// An extra metrics column name is unusable (empty, duplicated or not `[A-Za-z0-9_.-]`).
    #[error("invalid metrics column name {name:?} for {}: {reason}", path.display())]
    InvalidColumnName {
        /// The file concerned.
        path: PathBuf,
        /// The rejected name.
        name: String,
        /// Why it was rejected.
        reason: &'static str,
    },

    /// A `metrics.csv` being read back is malformed: `line` is 1-based (1 is the header).
    #[error("malformed metrics file {} at line {line}: {message}", path.display())]
    MalformedMetrics {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },

    /// A frame's index of parts (`frame_NNNNN.parts`) is malformed or does not fit its parts:
    /// `line` is 1-based.
    #[error("malformed frame index {} at line {line}: {message}", path.display())]
    MalformedParts {
        /// The index file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },

    /// An output format name was not recognised (expected `ply` or `vtk`).
    #[error("unknown output format {name:?} (expected \"ply\" or \"vtk\")")]
    UnknownFormat {
        /// The unrecognised name.
        name: String,
    },
}

fn in_path(path: &Option<PathBuf>) -> String {
    match path {
        Some(p) => format!(" (file {})", p.display()),
        None => String::new(),
    }
}

impl OutputError {
    /// The file this error is about, if any.
    pub fn path(&self) -> Option<&Path> {
        match self {
            OutputError::Io { path, .. }
            | OutputError::TooManyParticles { path, .. }
            | OutputError::MalformedPly { path, .. }
            | OutputError::MalformedVtk { path, .. }
            | OutputError::UnrecognisedFrameFile { path, .. }
            | OutputError::NonFiniteMetric { path, .. }
            | OutputError::MetricsColumnCount { path, .. }
            | OutputError::InvalidColumnName { path, .. }
            | OutputError::MalformedMetrics { path, .. }
            | OutputError::MalformedParts { path, .. } => Some(path),
            OutputError::NonFinite { path, .. }
            | OutputError::NonFiniteTime { path, .. }
            | OutputError::LengthMismatch { path, .. }
            | OutputError::InvalidFieldName { path, .. } => path.as_deref(),
            OutputError::UnknownFormat { .. } => None,
        }
    }

    /// Attach `path` to a validation error that does not name a file yet. Errors that already
    /// name a file are returned unchanged.
    pub fn with_path(mut self, new_path: &Path) -> Self {
        match &mut self {
            OutputError::NonFinite { path, .. }
            | OutputError::NonFiniteTime { path, .. }
            | OutputError::LengthMismatch { path, .. }
            | OutputError::InvalidFieldName { path, .. }
                if path.is_none() =>
            {
                *path = Some(new_path.to_path_buf());
            }
            _ => {}
        }
        self
    }

    pub(crate) fn io(action: &'static str, path: &Path, source: io::Error) -> Self {
        OutputError::Io {
            action,
            path: path.to_path_buf(),
            source,
        }
    }
}
