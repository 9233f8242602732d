//! Frames written in parts: one particle file per rank of a distributed run, and an index that
//! readers open as the whole frame.
//!
//! # Layout
//!
//! ```text
//! DIR/frame_00042.parts           the index (text, below): the frame readers open
//! DIR/ranks/frame_00042.rank0.ply rank 0's particles (an ordinary PLY or VTK frame file)
//! DIR/ranks/frame_00042.rank1.ply …
//! ```
//!
//! The index:
//!
//! ```text
//! treacle frame parts 1
//! frame 42
//! time 0.123
//! part ranks/frame_00042.rank0.ply 1188
//! part ranks/frame_00042.rank1.ply 3036
//! ```
//!
//! One `part <path> <particles>` line per part, in rank order; paths are relative to the
//! index's folder. [`read_frame`](super::read_frame) recognises an index by its first line and
//! returns the parts' particles concatenated in the listed order, after checking that each part
//! is a frame file (not another index) of the index's frame and time, with the listed particle
//! count and the first part's fields. Each part is an ordinary frame file, so a tool that reads
//! PLY or VTK can open it alone.
//!
//! The index is written last and atomically: a frame whose index exists is complete.
use std::path::{Component, Path, PathBuf};

use super::atomic::{ensure_dir, write_atomic};
use super::error::OutputError;
use super::frame::ParticleFrame;
use super::{OutputFormat, write_frame_at};

/// Extension of a frame's index file (`frame_00042.parts`).
pub const PARTS_EXTENSION: &str = "parts";

/// Folder of the part files, inside the run's output folder.
pub const PARTS_DIR: &str = "ranks";

/// First line of an index file (the format's name and version).
pub(crate) const PARTS_MAGIC: &str = "treacle frame parts 1";

/// File name of `frame`'s index: `frame_00042.parts`.
pub fn index_file_name(frame: u32) -> String {
    format!("frame_{frame:05}.{PARTS_EXTENSION}")
}

/// Path of part `part` of `frame`, relative to the run's folder:
/// `ranks/frame_00042.rank3.ply`.
pub fn part_file_name(format: OutputFormat, frame: u32, part: usize) -> String {
    format!(
        "{PARTS_DIR}/frame_{frame:05}.rank{part}.{}",
        format.extension()
    )
}

/// The frame and part numbers of a part file's name (`frame_00042.rank3.ply` → (42, 3)), as
/// found in [`PARTS_DIR`]; `None` for any other name.
pub fn part_number(file_name: &str) -> Option<(u32, usize)> {
    let (stem, ext) = file_name.rsplit_once('.')?;
    if ext != OutputFormat::Ply.extension() && ext != OutputFormat::Vtk.extension() {
        return None;
    }
    let (frame, part) = stem.strip_prefix("frame_")?.split_once(".rank")?;
    let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
    if !digits(frame) || !digits(part) {
        return None;
    }
    Some((frame.parse().ok()?, part.parse().ok()?))
}

/// One part of a frame: its path relative to the index's folder and its particle count.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FramePart {
    /// Path relative to the folder of the index ([`part_file_name`]).
    pub path: String,
    /// Particles in the part.
    pub particles: usize,
}

/// A frame's index: its number and time, and its parts in order.
#[derive(Clone, Debug, PartialEq)]
pub struct PartsIndex {
    /// Frame number.
    pub frame: u32,
    /// Simulation time \[s\].
    pub time: f64,
    /// The parts, in the order their particles make up the frame.
    pub parts: Vec<FramePart>,
}

impl PartsIndex {
    /// The index's text.
    pub fn encode(&self) -> String {
        let mut s = format!("{PARTS_MAGIC}\nframe {}\ntime {}\n", self.frame, self.time);
        for p in &self.parts {
            s.push_str(&format!("part {} {}\n", p.path, p.particles));
        }
        s
    }

    /// Parses an index's text; errors name `path` and the 1-based line.
    pub fn parse(text: &str, path: &Path) -> Result<Self, OutputError> {
        Self::parse_with_lines(text, path).map(|(index, _)| index)
    }

    /// [`PartsIndex::parse`], and the line of each part.
    fn parse_with_lines(text: &str, path: &Path) -> Result<(Self, Vec<usize>), OutputError> {
        let bad = |line: usize, message: String| OutputError::MalformedParts {
            path: path.to_path_buf(),
            line,
            message,
        };
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
        match lines.next() {
            Some((_, PARTS_MAGIC)) => {}
            Some((n, l)) => {
                return Err(bad(n, format!("expected `{PARTS_MAGIC}`, found `{l}`")));
            }
            None => return Err(bad(1, "the file is empty".into())),
        }
        let (mut frame, mut time, mut parts, mut at) = (None, None, Vec::new(), Vec::new());
        for (n, line) in lines {
            if line.is_empty() {
                continue;
            }
            let words: Vec<&str> = line.split_whitespace().collect();
            match words.as_slice() {
                ["frame", v] => {
                    let v = v.parse::<u32>().map_err(|_| {
                        bad(n, format!("frame `{v}` is not a frame number (0 to 2³²−1)"))
                    })?;
                    frame = Some(v);
                }
                ["time", v] => {
                    let t = v
                        .parse::<f64>()
                        .ok()
                        .filter(|t| t.is_finite())
                        .ok_or_else(|| bad(n, format!("time `{v}` is not a finite number")))?;
                    time = Some(t);
                }
                ["part", p, count] => {
                    let particles = count.parse::<usize>().map_err(|_| {
                        bad(
                            n,
                            format!("particle count `{count}` is not a whole number ≥ 0"),
                        )
                    })?;
                    let rel = Path::new(p);
                    if !rel
                        .components()
                        .all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
                    {
                        return Err(bad(
                            n,
                            format!("part path `{p}` must be relative, inside the index's folder"),
                        ));
                    }
                    parts.push(FramePart {
                        path: (*p).to_owned(),
                        particles,
                    });
                    at.push(n);
                }
                _ => {
                    return Err(bad(
                        n,
                        format!(
                            "expected `frame <n>`, `time <t>` or `part <path> <particles>`, \
                             found `{line}`"
                        ),
                    ));
                }
            }
        }
        let end = text.lines().count().max(1);
        let frame = frame.ok_or_else(|| bad(end, "no `frame <n>` line".into()))?;
        let time = time.ok_or_else(|| bad(end, "no `time <t>` line".into()))?;
        if parts.is_empty() {
            return Err(bad(end, "no `part <path> <particles>` line".into()));
        }
        Ok((Self { frame, time, parts }, at))
    }
}

/// Validates `frame` and atomically writes it as part `part` of its frame in `dir`
/// (`dir/ranks/frame_NNNNN.rankK.<ext>`, [`part_file_name`]), creating the folders. Returns the
/// part's entry of the index.
pub fn write_frame_part(
    dir: &Path,
    frame: &ParticleFrame,
    format: OutputFormat,
    part: usize,
) -> Result<FramePart, OutputError> {
    let rel = part_file_name(format, frame.frame, part);
    let path = dir.join(&rel);
    frame.validate().map_err(|e| e.with_path(&path))?;
    ensure_dir(&dir.join(PARTS_DIR))?;
    write_frame_at(&path, frame, format)?;
    Ok(FramePart {
        path: rel,
        particles: frame.len(),
    })
}

/// Atomically writes `index` as `dir/frame_NNNNN.parts` ([`index_file_name`]); returns its
/// path. Write it after its parts: a reader that finds the index finds the whole frame.
pub fn write_parts_index(dir: &Path, index: &PartsIndex) -> Result<PathBuf, OutputError> {
    let path = dir.join(index_file_name(index.frame));
    ensure_dir(dir)?;
    write_atomic(&path, index.encode().as_bytes())?;
    Ok(path)
}

/// The frame of the index file `path` (text `bytes`): its parts' particles in order.
pub(crate) fn decode_parts(path: &Path, bytes: &[u8]) -> Result<ParticleFrame, OutputError> {
    let text = std::str::from_utf8(bytes).map_err(|e| OutputError::MalformedParts {
        path: path.to_path_buf(),
        line: text_line(bytes, e.valid_up_to()),
        message: "not UTF-8 text".into(),
    })?;
    let (index, lines) = PartsIndex::parse_with_lines(text, path)?;
    let folder = path.parent().unwrap_or(Path::new("."));
    let mut out = ParticleFrame::new(index.frame, index.time);
    for (k, part) in index.parts.iter().enumerate() {
        let part_path = folder.join(&part.path);
        let bad = |message: String| OutputError::MalformedParts {
            path: path.to_path_buf(),
            line: lines[k],
            message: format!("part {}: {message}", part_path.display()),
        };
        let bytes =
            std::fs::read(&part_path).map_err(|e| OutputError::io("read", &part_path, e))?;
        if bytes.starts_with(PARTS_MAGIC.as_bytes()) {
            return Err(bad("is an index, not a particle file".into()));
        }
        let f = super::decode_frame_bytes(&part_path, &bytes)?;
        if f.frame != index.frame || f.time.to_bits() != index.time.to_bits() {
            return Err(bad(format!(
                "holds frame {} at time {}, the index frame {} at time {}",
                f.frame, f.time, index.frame, index.time
            )));
        }
        if f.len() != part.particles {
            return Err(bad(format!(
                "holds {} particles, the index lists {}",
                f.len(),
                part.particles
            )));
        }
        if k == 0 {
            out.fields = f
                .fields
                .iter()
                .map(|(n, _)| (n.clone(), Vec::new()))
                .collect();
        }
        let names = |fr: &ParticleFrame| fr.fields.iter().map(|(n, _)| n.clone()).collect();
        let (want, have): (Vec<String>, Vec<String>) = (names(&out), names(&f));
        if want != have {
            return Err(bad(format!(
                "has the fields {have:?}, the first part {want:?}"
            )));
        }
        out.positions.extend(f.positions);
        out.velocities.extend(f.velocities);
        for ((_, all), (_, col)) in out.fields.iter_mut().zip(f.fields) {
            all.extend(col);
        }
    }
    out.validate().map_err(|e| e.with_path(path))?;
    Ok(out)
}

/// 1-based line of byte `offset` in `bytes`.
fn text_line(bytes: &[u8], offset: usize) -> usize {
    1 + bytes[..offset].iter().filter(|&&b| b == b'\n').count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::output::{read_frame, write_frame};

    fn frame(n: usize, first: f32) -> ParticleFrame {
        let positions: Vec<[f32; 3]> = (0..n).map(|i| [first + i as f32, 0.5, 0.25]).collect();
        ParticleFrame {
            frame: 7,
            time: 0.1 + 0.2,
            velocities: vec![[1.0, 0.0, -1.0]; n],
            fields: vec![(
                "density".into(),
                (0..n).map(|i| 1000.0 + i as f32).collect(),
            )],
            positions,
        }
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("treacle-parts-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        dir
    }

    /// Three parts (one empty) read back as the frame of their particles in order, in both
    /// formats; the same particles written as one file read back equal.
    #[test]
    fn parts_read_back_as_one_frame() {
        let dir = scratch("round-trip");
        for format in [OutputFormat::Ply, OutputFormat::Vtk] {
            let pieces = [frame(3, 0.0), frame(0, 0.0), frame(2, 10.0)];
            let parts = pieces
                .iter()
                .enumerate()
                .map(|(k, f)| write_frame_part(&dir, f, format, k).unwrap())
                .collect();
            let index = PartsIndex {
                frame: 7,
                time: 0.1 + 0.2,
                parts,
            };
            let path = write_parts_index(&dir, &index).unwrap();
            assert_eq!(path, dir.join("frame_00007.parts"));
            let whole = read_frame(&path).unwrap();
            let mut expected = frame(3, 0.0);
            let last = frame(2, 10.0);
            expected.positions.extend(&last.positions);
            expected.velocities.extend(&last.velocities);
            expected.fields[0].1.extend(&last.fields[0].1);
            assert_eq!(whole, expected, "{format}");
            let single = write_frame(&dir, &expected, format).unwrap();
            assert_eq!(read_frame(&single).unwrap(), whole);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn part_names() {
        assert_eq!(
            part_file_name(OutputFormat::Vtk, 42, 3),
            "ranks/frame_00042.rank3.vtk"
        );
        assert_eq!(part_number("frame_00042.rank3.ply"), Some((42, 3)));
        for other in [
            "frame_00042.ply",
            "frame_00042.rank.ply",
            "frame_x.rank1.ply",
            "frame_00042.rank3.obj",
        ] {
            assert_eq!(part_number(other), None, "{other}");
        }
    }

    /// A bad index or a part that does not fit it is an error naming the index, its line and
    /// what is wrong.
    #[test]
    fn bad_indexes_name_file_line_and_problem() {
        let dir = scratch("bad");
        let part = write_frame_part(&dir, &frame(3, 0.0), OutputFormat::Ply, 0).unwrap();
        let index = |body: &str| {
            let path = dir.join("frame_00007.parts");
            std::fs::write(&path, format!("{PARTS_MAGIC}\n{body}")).unwrap();
            read_frame(&path).unwrap_err().to_string()
        };
        let cases = [
            (
                "frame 7\ntime 0.30000000000000004\npart ranks/frame_00007.rank0.ply 4\n",
                "line 4",
                "holds 3 particles, the index lists 4",
            ),
            (
                "frame 8\ntime 0.30000000000000004\npart ranks/frame_00007.rank0.ply 3\n",
                "line 4",
                "the index frame 8",
            ),
            (
                "frame 7\ntime 0.3\npart ../frame_00007.rank0.ply 3\n",
                "line 4",
                "must be relative",
            ),
            ("frame 7\ntime nan\n", "line 3", "not a finite number"),
            ("frame 7\ntime 0.3\n", "line 3", "no `part"),
            ("frame seven\n", "line 2", "not a frame number"),
            (
                "frame 7\ntime 0.3\npart ranks/missing.ply 3\n",
                "missing.ply",
                "cannot read",
            ),
            ("frame 7\nspeed 3\n", "line 3", "expected `frame <n>`"),
        ];
        for (body, at, what) in cases {
            let e = index(body);
            assert!(
                e.contains("frame_00007.parts") || e.contains("missing.ply"),
                "{body}: {e}"
            );
            assert!(e.contains(at) && e.contains(what), "{body}: {e}");
        }
        assert_eq!(part.particles, 3);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
