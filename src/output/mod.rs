//! Particle output files.
//!
//! * [`ParticleFrame`]: one frame of per-particle data (positions, velocities, named scalar
//!   fields, time, frame number) with [`ParticleFrame::validate`].
//! * [`write_frame`]: validate and write `DIR/frame_00042.ply` or `.vtk`
//!   ([`OutputFormat`]). PLY ([`ply`]) is binary little-endian and can be read back with
//!   [`read_ply`]; legacy VTK ([`vtk`]) is big-endian binary POLYDATA for ParaView/VisIt and can
//!   be read back with [`read_vtk`]. [`read_frame`] reads either, recognised by content.
//!   VTK readers keep every field; some PLY readers drop non-standard properties such as
//!   `vx` or `density`.
//! * [`parts`]: a frame of a distributed run written as one file per rank and an index,
//!   `frame_NNNNN.parts`, that [`read_frame`] opens as the whole frame; [`frame_files`] lists a
//!   run folder's frames of either kind.
//! * [`MetricsWriter`]: per-frame [`MetricsRow`]s in `DIR/metrics.csv`.
//! * [`write_atomic`] / [`write_atomic_with`]: write-to-temporary-then-rename, used by all of
//!   the above and available to other modules.
//!
//! Guarantees shared by all writers: the frame is validated *before* anything touches the file
//! system, so NaN/inf is never written and a rejected frame leaves no file (not even a
//! temporary one); files are replaced atomically, so readers never see a partial file; the
//! bytes depend only on the frame, so writing the same frame twice gives identical files.
mod atomic;
mod error;
mod frame;
mod metrics;
pub mod parts;
pub mod ply;
mod records;
pub mod vtk;

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

pub use atomic::{is_temp_name, write_atomic, write_atomic_with};
pub use error::{OutputError, PlyLocation};
#[cfg(feature = "surface")]
pub(crate) use frame::name_problem;
pub use frame::{MAX_NAME_LEN, ParticleFrame, RESERVED_NAMES};
pub use metrics::{
    METRICS_COLUMNS, METRICS_FILE, MetricsRow, MetricsTable, MetricsWriter, format_metric,
};
pub use parts::{
    FramePart, PARTS_DIR, PARTS_EXTENSION, PartsIndex, index_file_name, part_file_name,
    part_number, write_frame_part, write_parts_index,
};
pub use ply::{encode_ply, read_ply, write_ply};
pub use vtk::{MAX_VTK_PARTICLES, encode_vtk, read_vtk, write_vtk};

/// File format of particle frames.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum OutputFormat {
    /// Binary little-endian PLY (`.ply`), readable with [`read_ply`].
    #[default]
    Ply,
    /// Legacy binary VTK POLYDATA (`.vtk`).
    Vtk,
}

impl OutputFormat {
    /// File extension without the dot: `"ply"` or `"vtk"`.
    pub fn extension(self) -> &'static str {
        match self {
            OutputFormat::Ply => "ply",
            OutputFormat::Vtk => "vtk",
        }
    }

    /// File name of `frame`: `frame_00042.ply`. The number is zero-padded to at least five
    /// digits (frames ≥ 100000 get more digits, which breaks plain lexical sorting there).
    pub fn file_name(self, frame: u32) -> String {
        format!("frame_{frame:05}.{}", self.extension())
    }
}

impl fmt::Display for OutputFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.extension())
    }
}

impl FromStr for OutputFormat {
    type Err = OutputError;

    /// `"ply"` or `"vtk"`, case-insensitive, with or without a leading dot.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let t = s.strip_prefix('.').unwrap_or(s);
        if t.eq_ignore_ascii_case("ply") {
            Ok(OutputFormat::Ply)
        } else if t.eq_ignore_ascii_case("vtk") {
            Ok(OutputFormat::Vtk)
        } else {
            Err(OutputError::UnknownFormat { name: s.to_owned() })
        }
    }
}

/// Validate `frame` and atomically write it to `dir/frame_NNNNN.<ext>`, creating `dir` if it
/// does not exist; an existing file of that name is replaced. Returns the path written.
///
/// On a validation error nothing is created (not even `dir`) and the error names the path that
/// would have been written.
pub fn write_frame(
    dir: &Path,
    frame: &ParticleFrame,
    format: OutputFormat,
) -> Result<PathBuf, OutputError> {
    let path = dir.join(format.file_name(frame.frame));
    frame.validate().map_err(|e| e.with_path(&path))?;
    atomic::ensure_dir(dir)?;
    write_frame_at(&path, frame, format)?;
    Ok(path)
}

/// Atomically writes the validated `frame` to `path` in `format` (the folder exists).
fn write_frame_at(
    path: &Path,
    frame: &ParticleFrame,
    format: OutputFormat,
) -> Result<(), OutputError> {
    match format {
        OutputFormat::Ply => ply::write_ply_unchecked(path, frame),
        OutputFormat::Vtk => vtk::write_vtk_unchecked(path, frame),
    }
}

/// The frame number of a run folder's frame file name: `frame_NNNNN.ply`, `.vtk` or
/// `.parts` (an index, [`parts`]); `None` for any other name.
pub fn frame_number(file_name: &str) -> Option<u32> {
    let (num, ext) = file_name.strip_prefix("frame_")?.split_once('.')?;
    let known = [
        OutputFormat::Ply.extension(),
        OutputFormat::Vtk.extension(),
        PARTS_EXTENSION,
    ];
    if !known.contains(&ext) || num.is_empty() || !num.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    num.parse().ok()
}

/// The frame files of the run folder `dir` ([`frame_number`]: PLY, VTK and part indexes), in
/// frame order (by file name within a frame).
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, OutputError> {
    let io = |e| OutputError::io("read directory", dir, e);
    let mut files: Vec<(u32, PathBuf)> = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if let Some(n) = path
            .file_name()
            .and_then(|n| n.to_str())
            .and_then(frame_number)
        {
            files.push((n, path));
        }
    }
    files.sort();
    Ok(files.into_iter().map(|(_, p)| p).collect())
}

/// Read a particle frame file, PLY, legacy VTK or an index of parts ([`parts`]), recognised
/// by its first bytes (`ply`, `# vtk` or `treacle frame parts`), not by its extension. See [`read_ply`] and [`read_vtk`] for what each accepts; the
/// returned frame has passed [`ParticleFrame::validate`].
///
/// Errors name `path`: [`OutputError::Io`] if it cannot be read,
/// [`OutputError::UnrecognisedFrameFile`] for any other content, [`OutputError::MalformedPly`]
/// / [`OutputError::MalformedVtk`] with the location of a parse error (a truncated file
/// included), or a validation error (e.g. NaN in the file).
pub fn read_frame(path: &Path) -> Result<ParticleFrame, OutputError> {
    let bytes = std::fs::read(path).map_err(|e| OutputError::io("read", path, e))?;
    if bytes.starts_with(parts::PARTS_MAGIC.as_bytes()) {
        parts::decode_parts(path, &bytes)
    } else {
        decode_frame_bytes(path, &bytes)
    }
}

/// The PLY or VTK frame in `bytes` (the contents of `path`).
fn decode_frame_bytes(path: &Path, bytes: &[u8]) -> Result<ParticleFrame, OutputError> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        ply::decode_ply(path, bytes)
    } else if bytes.starts_with(b"# vtk") {
        vtk::decode_vtk(path, bytes)
    } else {
        Err(OutputError::UnrecognisedFrameFile {
            path: path.to_path_buf(),
            found: describe_start(bytes),
        })
    }
}

/// `"an empty file"` or the first few bytes, escaped.
fn describe_start(bytes: &[u8]) -> String {
    if bytes.is_empty() {
        return "an empty file".to_owned();
    }
    let head = &bytes[..bytes.len().min(16)];
    format!("\"{}\"", head.escape_ascii())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_names() {
        assert_eq!(OutputFormat::Ply.file_name(42), "frame_00042.ply");
        assert_eq!(OutputFormat::Vtk.file_name(123456), "frame_123456.vtk");
        assert_eq!("VTK".parse::<OutputFormat>().unwrap(), OutputFormat::Vtk);
        assert_eq!(".ply".parse::<OutputFormat>().unwrap(), OutputFormat::Ply);
        assert!("obj".parse::<OutputFormat>().is_err());
    }

    #[test]
    fn read_frame_recognises_content() {
        let dir = std::env::temp_dir().join(format!("treacle-read-frame-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let f = ParticleFrame {
            frame: 3,
            time: 0.05,
            positions: vec![[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]],
            velocities: vec![[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]],
            fields: vec![("density".into(), vec![1000.0, 1001.0])],
        };
        for format in [OutputFormat::Ply, OutputFormat::Vtk] {
            let path = write_frame(&dir, &f, format).unwrap();
            // The extension is irrelevant: rename to something neutral.
            let neutral = dir.join(format!("frame.{format}.bin"));
            std::fs::rename(&path, &neutral).unwrap();
            assert_eq!(read_frame(&neutral).unwrap(), f, "{format}");
        }
        let junk = dir.join("junk.ply");
        std::fs::write(&junk, b"solid cube\n").unwrap();
        let e = read_frame(&junk).unwrap_err();
        assert!(
            matches!(e, OutputError::UnrecognisedFrameFile { .. }),
            "{e}"
        );
        assert!(e.to_string().contains("junk.ply") && e.to_string().contains("solid cube"));
        let missing = dir.join("missing.ply");
        assert!(matches!(read_frame(&missing), Err(OutputError::Io { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn frame_numbers_of_file_names() {
        assert_eq!(frame_number("frame_00042.ply"), Some(42));
        assert_eq!(frame_number("frame_123456.vtk"), Some(123456));
        assert_eq!(frame_number("frame_00007.parts"), Some(7));
        for other in [
            "frame_00007.rank0.ply",
            "frame_.ply",
            "frame_+7.ply",
            "frame_7.obj",
            "metrics.csv",
            "surface_00001.ply",
        ] {
            assert_eq!(frame_number(other), None, "{other}");
        }
    }
}
