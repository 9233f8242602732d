//! The validation vocabulary every layer above the math speaks: a problem with one field of an
//! input ([`FieldIssue`]), a violated parameter constraint ([`InvalidParameter`]), an accepted
//! but questionable value ([`ParameterWarning`]), the facts of a scene that a section's
//! validation may need ([`SceneContext`]) and where asset files are looked up
//! ([`resolve_asset_path`]), and [`MaterialEntry`], a runtime parameter type attached to a
//! material by name in a scene file.
//!
//! Each plugin validates its own section of a scene with these types; the scene loader
//! (`crate::scene`) collects the issues, adds the cross-section checks and locates every issue in
//! the file. Nothing here knows a scene file.
mod entry;

use std::fmt;
use std::path::{Path, PathBuf};

use crate::math::{Real, Vec3};
pub use entry::{Identifier, MaterialEntry};

/// A problem with one field of a scene, found by validation, before the file position is
/// known. The scene loader locates them in the file
/// (`file:line:col: field `path`: message`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FieldIssue {
    /// Path of the field, e.g. `bodies[1].shape.radius` (`""`: the scene as a whole).
    pub field: String,
    /// What is wrong, with the constraint, the unit and the value found.
    pub message: String,
}

impl FieldIssue {
    /// A new issue.
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            message: message.into(),
        }
    }
}

impl fmt::Display for FieldIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.field.is_empty() {
            f.write_str(&self.message)
        } else {
            write!(f, "field `{}`: {}", self.field, self.message)
        }
    }
}

/// A parameter that violates a constraint: the field name and the constraint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InvalidParameter {
    /// Field name as in the model struct (and the scene file).
    pub field: &'static str,
    /// The violated constraint, e.g. "must be > 0 s".
    pub constraint: &'static str,
}

impl fmt::Display for InvalidParameter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {}", self.field, self.constraint)
    }
}

/// A parameter that is accepted but questionable: the field name and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParameterWarning {
    /// Field name as in the model struct (and the scene file).
    pub field: &'static str,
    /// What the value implies.
    pub message: String,
}

impl fmt::Display for ParameterWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.field, self.message)
    }
}

/// The crate's asset directory, the second place mesh paths are looked up
/// (`<crate>/assets`, fixed at compile time).
pub const ASSETS_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/assets");

/// Resolves a mesh path: absolute paths as they are; relative paths against `base_dir`
/// (the scene file's directory) first, then against [`ASSETS_DIR`]. On failure returns the
/// candidates tried.
pub fn resolve_asset_path(path: &str, base_dir: &Path) -> Result<PathBuf, Vec<PathBuf>> {
    let p = Path::new(path);
    let candidates: Vec<PathBuf> = if p.is_absolute() {
        vec![p.to_path_buf()]
    } else {
        vec![base_dir.join(p), Path::new(ASSETS_DIR).join(p)]
    };
    candidates
        .iter()
        .find(|c| c.is_file())
        .cloned()
        .ok_or(candidates)
}

/// The facts of a scene that the validation of one section may need: the domain, the grid
/// spacing, the particle spacing and the material names (in file order: index = material id).
#[derive(Clone, Debug)]
pub struct SceneContext<'a> {
    /// Lower corner of the domain \[m\].
    pub domain_min: Vec3,
    /// Upper corner of the domain \[m\].
    pub domain_max: Vec3,
    /// Grid spacing Δx \[m\].
    pub dx: Real,
    /// Particles per cell and axis (≥ 1).
    pub particles_per_cell: u32,
    /// Material names, in file order.
    pub material_names: Vec<&'a str>,
    /// Directory relative asset paths are resolved against (the scene file's).
    pub base_dir: &'a Path,
}

impl SceneContext<'_> {
    /// The index (material id) of the material called `name`.
    pub fn material(&self, name: &str) -> Option<usize> {
        self.material_names.iter().position(|m| *m == name)
    }

    /// The default particle spacing dx / particles_per_cell \[m\].
    pub fn particle_spacing(&self) -> Real {
        self.dx / self.particles_per_cell.max(1) as Real
    }
}

/// Longest word (run of non-blank characters) a message shows in full; longer ones keep their
/// start and end around a count of what was left out.
pub const MESSAGE_WORD_CHARS: usize = 80;

/// Longest message shown in full \[characters\]; a longer one keeps its start and end.
pub const MESSAGE_CHARS: usize = 1000;

/// `message` with over-long words and an over-long whole shortened (see
/// [`MESSAGE_WORD_CHARS`], [`MESSAGE_CHARS`]), so that an error about a multi-megabyte string
/// in a file does not echo it.
pub fn shorten_message(message: &str) -> std::borrow::Cow<'_, str> {
    fn cut(text: &str, keep_head: usize, keep_tail: usize) -> String {
        let n = text.chars().count();
        let head: String = text.chars().take(keep_head).collect();
        let tail: String = text.chars().skip(n - keep_tail).collect();
        format!("{head}…[{} characters]…{tail}", n - keep_head - keep_tail)
    }
    let long_word = message
        .split(char::is_whitespace)
        .any(|w| w.chars().count() > MESSAGE_WORD_CHARS);
    if !long_word && message.chars().count() <= MESSAGE_CHARS {
        return std::borrow::Cow::Borrowed(message);
    }
    let mut out = String::new();
    let mut word = String::new();
    let flush = |word: &mut String, out: &mut String| {
        if word.chars().count() > MESSAGE_WORD_CHARS {
            out.push_str(&cut(word, 40, 20));
        } else {
            out.push_str(word);
        }
        word.clear();
    };
    for c in message.chars() {
        if c.is_whitespace() {
            flush(&mut word, &mut out);
            out.push(c);
        } else {
            word.push(c);
        }
    }
    flush(&mut word, &mut out);
    if out.chars().count() > MESSAGE_CHARS {
        out = cut(&out, MESSAGE_CHARS * 2 / 3, MESSAGE_CHARS / 4);
    }
    std::borrow::Cow::Owned(out)
}
