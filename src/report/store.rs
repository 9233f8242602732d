//! Resumable result storage: one small RON file per finished run under `OUT/runs/`, written
//! atomically as soon as the run ends, keyed by a hash of everything the result depends on
//! (the run's definition, the scene file's text and [`REPORT_VERSION`]). A rerun loads a stored
//! result whose hash matches instead of running again; a changed definition or scene runs anew.
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize, de::DeserializeOwned};

use crate::output::{OutputError, write_atomic};

/// Bumped whenever the meaning of a stored result changes, so old results are not reused.
pub const REPORT_VERSION: u32 = 1;

/// FNV-1a (64 bit) of `text`: a stable, dependency-free content hash (not cryptographic).
pub fn content_hash(text: &str) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// `text` with every character outside `[A-Za-z0-9._-]` replaced by `_`: a file-name stem.
pub fn file_stem(text: &str) -> String {
    text.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .collect()
}

#[derive(Serialize, Deserialize)]
struct Stored<T> {
    hash: String,
    result: T,
}

/// The `runs/` folder of a report.
#[derive(Clone, Debug)]
pub struct RunStore {
    dir: PathBuf,
}

impl RunStore {
    /// The store in `out_dir/runs` (created on the first save).
    pub fn new(out_dir: &Path) -> Self {
        Self {
            dir: out_dir.join("runs"),
        }
    }

    /// Creates the folder if missing.
    pub fn ensure(&self) -> Result<(), OutputError> {
        std::fs::create_dir_all(&self.dir)
            .map_err(|e| OutputError::io("create directory", &self.dir, e))
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Path of the result file of run `id`.
    pub fn path(&self, id: &str) -> PathBuf {
        self.dir.join(format!("{}.ron", file_stem(id)))
    }

    /// A path for another file of run `id` with extension `ext` (e.g. a reference state).
    pub fn side_file(&self, id: &str, ext: &str) -> PathBuf {
        self.dir.join(format!("{}.{ext}", file_stem(id)))
    }

    /// The stored result of run `id` if its hash is `hash` (`None` if missing, stale or
    /// unreadable).
    pub fn load<T: DeserializeOwned>(&self, id: &str, hash: u64) -> Option<T> {
        let text = std::fs::read_to_string(self.path(id)).ok()?;
        let stored: Stored<T> = ron::from_str(&text).ok()?;
        (stored.hash == format!("{hash:016x}")).then_some(stored.result)
    }

    /// Stores the result of run `id` atomically.
    pub fn save<T: Serialize>(&self, id: &str, hash: u64, result: &T) -> Result<(), OutputError> {
        self.ensure()?;
        let stored = Stored {
            hash: format!("{hash:016x}"),
            result,
        };
        let text = ron::ser::to_string_pretty(&stored, ron::ser::PrettyConfig::default()).map_err(
            |e| {
                OutputError::io(
                    "serialise result for",
                    &self.path(id),
                    std::io::Error::other(e),
                )
            },
        )?;
        write_atomic(&self.path(id), text.as_bytes())
    }
}

/// A CSV field: quoted (with doubled quotes) when it contains a comma, a quote or a newline.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// An optional number for CSV and markdown: shortest round-trip form, empty when `None`.
pub fn num(v: Option<f64>) -> String {
    match v {
        Some(x) if x.is_finite() => crate::output::format_metric(x),
        _ => String::new(),
    }
}

/// A number with four significant digits for markdown tables (`–` when `None`).
pub fn short(v: Option<f64>) -> String {
    match v {
        Some(x) if x.is_finite() => {
            if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e5) {
                format!("{x:.3e}")
            } else {
                crate::plot::format_number(x)
            }
        }
        _ => "–".to_string(),
    }
}

/// Checks a written text file for non-finite numbers: every comma- or `|`-separated field
/// that is exactly a spelling of NaN or infinity (text such as a diagnostic naming "NaN" is
/// not a number field). Returns the offending `line:field` positions.
pub fn non_finite_fields(text: &str) -> Vec<String> {
    let mut bad = Vec::new();
    for (i, line) in text.lines().enumerate() {
        for (j, field) in line.split([',', '|']).enumerate() {
            let f = field.trim().trim_matches('"').to_ascii_lowercase();
            if matches!(
                f.as_str(),
                "nan" | "-nan" | "inf" | "-inf" | "+inf" | "infinity" | "-infinity"
            ) {
                bad.push(format!("{}:{}", i + 1, j + 1));
            }
        }
    }
    bad
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_and_names() {
        assert_eq!(content_hash(""), 0xcbf2_9ce4_8422_2325);
        assert_ne!(content_hash("a"), content_hash("b"));
        assert_eq!(file_stem("gs4 (0.5, 0)/dt=1e-3"), "gs4__0.5__0__dt_1e-3");
        assert_eq!(csv_field("a,b"), "\"a,b\"");
        assert_eq!(
            non_finite_fields("a,b\n1,NaN\nx, inf |3"),
            vec!["2:2", "3:2"]
        );
        assert!(non_finite_fields("velocity.x = NaN on particle 3").is_empty());
    }
}
