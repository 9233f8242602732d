//! Scene loading errors. Every message names the file, the line and column, and the field:
//!
//! ```text
//! scenes/dam_break.ron:14:9: field `bodies[1].shape.radius`: must be > 0 m (got -0.1)
//! ```
use std::fmt;
use std::path::{Path, PathBuf};

use super::locate::Locator;

pub use crate::validation::FieldIssue;
use crate::validation::shorten_message;

/// The field named by errors that are about the scene value as a whole (its opening, text
/// after it, nesting beyond [`super::MAX_NESTING`] outside every field).
pub const ROOT_FIELD: &str = "Scene";

/// A located problem: `file:line:col: field `path`: message`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FieldError {
    /// The scene file (as given by the caller).
    pub file: PathBuf,
    /// 1-based line (0 when unknown).
    pub line: usize,
    /// 1-based column in characters (0 when unknown).
    pub col: usize,
    /// Path of the field (`""` when the error is not about one field).
    pub field: String,
    /// What is wrong.
    pub message: String,
}

impl fmt::Display for FieldError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if self.line > 0 {
            write!(f, ":{}:{}", self.line, self.col)?;
        }
        let message = shorten_message(&self.message);
        if self.field.is_empty() {
            write!(f, ": {message}")
        } else {
            write!(f, ": field `{}`: {message}", shorten_message(&self.field))
        }
    }
}

/// Why a scene could not be loaded. Nothing has been simulated or spawned when this is
/// returned.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("{}: cannot read scene file: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// RON syntax error, wrong type, unknown or missing field or variant. The parser stops at
    /// the first one; its message (from `ron`) names the unknown field or the expected type.
    #[error("{error}")]
    Parse {
        /// Located message.
        error: Box<FieldError>,
        /// The original `ron` error.
        #[source]
        source: Box<ron::error::SpannedError>,
    },
    /// The text is not a scene the parser can take: invalid UTF-8, or values nested deeper
    /// than [`super::MAX_NESTING`].
    #[error("{0}")]
    Text(Box<FieldError>),
    /// The scene parsed but is invalid; all problems found, in file order.
    #[error("{}", DisplayList(.0))]
    Invalid(Vec<FieldError>),
}

struct DisplayList<'a>(&'a [FieldError]);

impl fmt::Display for DisplayList<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, e) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str("\n")?;
            }
            write!(f, "{e}")?;
        }
        Ok(())
    }
}

impl SceneError {
    /// The located errors (empty for [`SceneError::Io`]).
    pub fn errors(&self) -> &[FieldError] {
        match self {
            SceneError::Io { .. } => &[],
            SceneError::Parse { error, .. } | SceneError::Text(error) => {
                std::slice::from_ref(&**error)
            }
            SceneError::Invalid(list) => list,
        }
    }

    /// A RON error, located and attributed to the field it occurred in.
    pub(crate) fn from_ron(file: &Path, text: &str, source: ron::error::SpannedError) -> Self {
        let pos = source.span.start;
        let locator = Locator::new(text);
        let mut field = locator.path_at(pos).unwrap_or("").to_string();
        match &source.code {
            // Reported at the end of the struct: name the missing field itself.
            ron::Error::MissingStructField { field: missing, .. } => {
                field = if field.is_empty() {
                    (*missing).to_string()
                } else {
                    format!("{field}.{missing}")
                };
            }
            // Text after the scene: the error is about the file's one value.
            ron::Error::TrailingCharacters => field.clear(),
            // The text ended inside the innermost value still open there (the locator's
            // deepest unfinished entry); `path_at` found it.
            _ => {}
        }
        // An error outside every field (the opening `Scene(`, trailing text) is about the scene
        // value itself.
        if field.is_empty() {
            field = ROOT_FIELD.to_string();
        }
        SceneError::Parse {
            error: Box::new(FieldError {
                file: file.to_path_buf(),
                line: pos.line,
                col: pos.col,
                field,
                message: source.code.to_string(),
            }),
            source: Box::new(source),
        }
    }

    /// Validation issues, located in `text` and sorted by position.
    pub(crate) fn from_issues(file: &Path, text: Option<&str>, issues: Vec<FieldIssue>) -> Self {
        SceneError::Invalid(locate_issues(file, text, issues))
    }
}

/// Locates issues in `text` (line 0 when `text` is `None` or the field is not found) and sorts
/// them by position. Used for errors and for load-time warnings alike.
pub(crate) fn locate_issues(
    file: &Path,
    text: Option<&str>,
    issues: Vec<FieldIssue>,
) -> Vec<FieldError> {
    {
        let locator = text.map(Locator::new).unwrap_or_default();
        let mut errors: Vec<FieldError> = issues
            .into_iter()
            .map(|issue| {
                let (line, col) = locator
                    .locate(&issue.field)
                    .map(|(p, _)| (p.line, p.col))
                    .unwrap_or((0, 0));
                FieldError {
                    file: file.to_path_buf(),
                    line,
                    col,
                    field: issue.field,
                    message: issue.message,
                }
            })
            .collect();
        errors.sort_by_key(|e| (e.line, e.col));
        errors
    }
}
