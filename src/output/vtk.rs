//! Legacy VTK (`.vtk`, version 3.0) particle files for ParaView/VisIt.
//!
//! Unlike PLY, where many readers drop non-standard vertex properties (`vx`, `density`, …),
//! the VTK readers keep every point-data array, so this is the format to use when all fields
//! must reach the visualisation.
//!
//! # Written layout
//!
//! Legacy binary VTK is big-endian by definition, whatever the host. Every binary block is
//! followed by a single `\n`.
//!
//! ```text
//! # vtk DataFile Version 3.0
//! treacle frame <frame> time <time>
//! BINARY
//! DATASET POLYDATA
//! FIELD FieldData 2
//! TIME 1 1 double
//! <f64 BE>
//! CYCLE 1 1 int
//! <i32 BE>
//! POINTS <N> float
//! <N × 3 f32 BE>
//! VERTICES <N> <2N>
//! <N × (i32 1, i32 i) BE>        one single-point vertex cell per particle
//! POINT_DATA <N>
//! VECTORS velocity float
//! <N × 3 f32 BE>
//! SCALARS <field> float 1         (one block per field, in order)
//! LOOKUP_TABLE default
//! <N f32 BE>
//! ```
//!
//! `TIME`/`CYCLE` are the dataset field-data arrays VisIt and ParaView display as the
//! simulation time and frame number. One vertex cell per particle (rather than one
//! poly-vertex cell) lets cell-based filters such as Threshold and Extract Selection work per
//! particle. Cell connectivity is 32-bit, so a frame is limited to [`MAX_VTK_PARTICLES`].
//!
//! # Reader
//!
//! [`read_vtk`] reads the files written here and, more generally, legacy `BINARY` (big-endian)
//! `DATASET POLYDATA` files: `POINTS` become positions; `VERTICES`, `LINES`, `POLYGONS` and
//! `TRIANGLE_STRIPS` are skipped; in `POINT_DATA`, the `VECTORS` array named `velocity` becomes
//! the velocities (missing means zero velocity), other `VECTORS` become three fields
//! `<name>.x`, `<name>.y`, `<name>.z`, one-component `SCALARS` and one-component `FIELD` arrays
//! become fields in file order; the dataset `FIELD` arrays `TIME` and `CYCLE` set
//! [`ParticleFrame::time`]/[`ParticleFrame::frame`] (default 0). Value types `char` …
//! `unsigned_long`, `vtktypeint64`/`vtktypeuint64`, `float` and `double` are converted to `f32`.
//! ASCII files, other datasets, `CELL_DATA`, `NORMALS`, `COLOR_SCALARS` and
//! `TEXTURE_COORDINATES` are rejected with [`OutputError::MalformedVtk`]. The result is
//! validated, so NaN/inf in a file is an error.
use std::fs;
use std::io::{self, Write};
use std::path::Path;

use super::atomic::write_atomic_with;
use super::error::OutputError;
use super::frame::ParticleFrame;
use super::records::{put_f32_be, write_records};

/// Largest particle count a legacy VTK file can hold (`2N` must fit in an `i32`).
pub const MAX_VTK_PARTICLES: usize = (i32::MAX / 2) as usize;

/// Encode `frame` as legacy binary VTK in memory (validates first).
pub fn encode_vtk(frame: &ParticleFrame) -> Result<Vec<u8>, OutputError> {
    frame.validate()?;
    check_count(frame, Path::new("<memory>"))?;
    let mut out = Vec::with_capacity(vtk_size_estimate(frame));
    write_vtk_to(frame, &mut out).expect("writing to a Vec cannot fail");
    Ok(out)
}

/// Validate `frame`, then atomically write it to `path` as legacy binary VTK.
/// Nothing is created if validation fails. The parent directory must exist.
pub fn write_vtk(path: &Path, frame: &ParticleFrame) -> Result<(), OutputError> {
    frame.validate().map_err(|e| e.with_path(path))?;
    write_vtk_unchecked(path, frame)
}

/// [`write_vtk`] without [`ParticleFrame::validate`] (the caller has validated `frame`).
pub(crate) fn write_vtk_unchecked(path: &Path, frame: &ParticleFrame) -> Result<(), OutputError> {
    check_count(frame, path)?;
    write_atomic_with(path, |w| write_vtk_to(frame, w))
}

fn check_count(frame: &ParticleFrame, path: &Path) -> Result<(), OutputError> {
    if frame.len() > MAX_VTK_PARTICLES {
        return Err(OutputError::TooManyParticles {
            path: path.to_path_buf(),
            count: frame.len(),
            max: MAX_VTK_PARTICLES,
        });
    }
    Ok(())
}

fn vtk_size_estimate(frame: &ParticleFrame) -> usize {
    512 + 64 * frame.fields.len() + frame.len() * (12 + 8 + 12 + 4 * frame.fields.len())
}

fn write_vtk_to(frame: &ParticleFrame, w: &mut dyn Write) -> io::Result<()> {
    let n = frame.len();
    // Saturates only beyond 2^31 - 1 frames.
    let cycle = i32::try_from(frame.frame).unwrap_or(i32::MAX);
    write!(
        w,
        "# vtk DataFile Version 3.0\ntreacle frame {} time {}\nBINARY\nDATASET POLYDATA\n\
         FIELD FieldData 2\nTIME 1 1 double\n",
        frame.frame, frame.time
    )?;
    w.write_all(&frame.time.to_be_bytes())?;
    w.write_all(b"\nCYCLE 1 1 int\n")?;
    w.write_all(&cycle.to_be_bytes())?;

    write!(w, "\nPOINTS {n} float\n")?;
    write_vec3_be(w, &frame.positions)?;

    write!(w, "\nVERTICES {n} {}\n", 2 * n)?;
    write_records(w, n, 8, |i, rec| {
        rec[..4].copy_from_slice(&1i32.to_be_bytes());
        // n <= MAX_VTK_PARTICLES, checked by the callers.
        rec[4..].copy_from_slice(&(i as i32).to_be_bytes());
    })?;

    write!(w, "\nPOINT_DATA {n}\nVECTORS velocity float\n")?;
    write_vec3_be(w, &frame.velocities)?;
    for (name, values) in &frame.fields {
        write!(w, "\nSCALARS {name} float 1\nLOOKUP_TABLE default\n")?;
        write_records(w, n, 4, |i, rec| put_f32_be(rec, 0, values[i]))?;
    }
    w.write_all(b"\n")
}

fn write_vec3_be(w: &mut dyn Write, values: &[[f32; 3]]) -> io::Result<()> {
    write_records(w, values.len(), 12, |i, rec| {
        let v = values[i];
        put_f32_be(rec, 0, v[0]);
        put_f32_be(rec, 4, v[1]);
        put_f32_be(rec, 8, v[2]);
    })
}

// ---------------------------------------------------------------------------------------------
// Reader

/// Read a legacy binary VTK POLYDATA file (see the [module docs](self) for what is accepted).
/// The returned frame has passed [`ParticleFrame::validate`].
pub fn read_vtk(path: &Path) -> Result<ParticleFrame, OutputError> {
    let bytes = fs::read(path).map_err(|e| OutputError::io("read", path, e))?;
    decode_vtk(path, &bytes)
}

/// [`read_vtk`] on the bytes of `path`, already read.
pub(crate) fn decode_vtk(path: &Path, bytes: &[u8]) -> Result<ParticleFrame, OutputError> {
    let frame =
        parse_vtk(bytes).map_err(|VtkMalformed(offset, message)| OutputError::MalformedVtk {
            path: path.to_path_buf(),
            offset: offset as u64,
            message,
        })?;
    frame.validate().map_err(|e| e.with_path(path))?;
    Ok(frame)
}

/// Byte offset and message.
struct VtkMalformed(usize, String);

type VtkParse<T> = Result<T, VtkMalformed>;

/// Scalar value types of legacy VTK, all big-endian in binary files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum VtkType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl VtkType {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" => VtkType::I8,
            "unsigned_char" => VtkType::U8,
            "short" => VtkType::I16,
            "unsigned_short" => VtkType::U16,
            "int" => VtkType::I32,
            "unsigned_int" => VtkType::U32,
            "long" | "vtktypeint64" => VtkType::I64,
            "unsigned_long" | "vtktypeuint64" => VtkType::U64,
            "float" => VtkType::F32,
            "double" => VtkType::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            VtkType::I8 | VtkType::U8 => 1,
            VtkType::I16 | VtkType::U16 => 2,
            VtkType::I32 | VtkType::U32 | VtkType::F32 => 4,
            VtkType::I64 | VtkType::U64 | VtkType::F64 => 8,
        }
    }

    /// Decode one big-endian value from the first `self.size()` bytes of `b`.
    fn decode(self, b: &[u8]) -> f64 {
        macro_rules! be {
            ($t:ty, $n:literal) => {
                <$t>::from_be_bytes(b[..$n].try_into().expect("slice has the type's size")) as f64
            };
        }
        match self {
            VtkType::I8 => b[0] as i8 as f64,
            VtkType::U8 => b[0] as f64,
            VtkType::I16 => be!(i16, 2),
            VtkType::U16 => be!(u16, 2),
            VtkType::I32 => be!(i32, 4),
            VtkType::U32 => be!(u32, 4),
            VtkType::I64 => be!(i64, 8),
            VtkType::U64 => be!(u64, 8),
            VtkType::F32 => be!(f32, 4),
            VtkType::F64 => be!(f64, 8),
        }
    }
}

/// A position in the file with text-line and binary-block access.
struct VtkCursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> VtkCursor<'a> {
    fn err<T>(&self, at: usize, message: impl Into<String>) -> VtkParse<T> {
        Err(VtkMalformed(at, message.into()))
    }

    /// The next line exactly (without `\n` / `\r\n`), with its start offset; `None` at the end
    /// of the file.
    fn raw_line(&mut self) -> VtkParse<Option<(usize, &'a str)>> {
        if self.pos >= self.bytes.len() {
            return Ok(None);
        }
        let start = self.pos;
        let rest = &self.bytes[start..];
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos = start + len + 1;
        let raw = &rest[..len];
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        match std::str::from_utf8(raw) {
            Ok(line) => Ok(Some((start, line))),
            Err(_) => self.err(start, "expected a text line, found non-UTF-8 bytes"),
        }
    }

    /// The next non-blank text line, trimmed.
    fn keyword_line(&mut self) -> VtkParse<Option<(usize, &'a str)>> {
        while self
            .bytes
            .get(self.pos)
            .is_some_and(|b| b.is_ascii_whitespace())
        {
            self.pos += 1;
        }
        Ok(self.raw_line()?.map(|(at, line)| (at, line.trim())))
    }

    /// `count` values of `ty` as a binary block.
    fn block(&mut self, count: usize, ty: VtkType, what: &str) -> VtkParse<&'a [u8]> {
        let need = count.checked_mul(ty.size());
        let left = self.bytes.len().saturating_sub(self.pos);
        match need {
            Some(need) if need <= left => {
                let b = &self.bytes[self.pos..self.pos + need];
                self.pos += need;
                Ok(b)
            }
            _ => self.err(
                self.bytes.len(),
                format!(
                    "file ends inside {what}: {count} values of {} bytes needed, {left} bytes left",
                    ty.size()
                ),
            ),
        }
    }

    /// `count` values of `ty` converted to `f32`.
    fn values(&mut self, count: usize, ty: VtkType, what: &str) -> VtkParse<Vec<f32>> {
        let b = self.block(count, ty, what)?;
        Ok(b.chunks_exact(ty.size())
            .map(|c| ty.decode(c) as f32)
            .collect())
    }
}

fn parse_count(at: usize, s: &str, what: &str) -> VtkParse<usize> {
    s.parse::<usize>()
        .map_err(|_| VtkMalformed(at, format!("invalid {what} {s:?}")))
}

fn parse_type(at: usize, s: &str) -> VtkParse<VtkType> {
    VtkType::parse(s).ok_or_else(|| VtkMalformed(at, format!("unsupported value type {s:?}")))
}

fn parse_vtk(bytes: &[u8]) -> VtkParse<ParticleFrame> {
    let mut c = VtkCursor { bytes, pos: 0 };
    match c.raw_line()? {
        Some((_, l)) if l.starts_with("# vtk DataFile Version") => {}
        _ => {
            return c.err(
                0,
                "not a legacy VTK file (no \"# vtk DataFile Version\" line)",
            );
        }
    }
    if c.raw_line()?.is_none() {
        return c.err(bytes.len(), "file ends before the title line");
    }
    match c.keyword_line()? {
        Some((_, l)) if l.eq_ignore_ascii_case("BINARY") => {}
        Some((at, l)) if l.eq_ignore_ascii_case("ASCII") => {
            return c.err(
                at,
                "ASCII VTK is not supported (only BINARY, as treacle writes)",
            );
        }
        Some((at, l)) => return c.err(at, format!("expected BINARY, found {l:?}")),
        None => return c.err(bytes.len(), "file ends before BINARY"),
    }
    match c.keyword_line()? {
        Some((_, l))
            if l.split_ascii_whitespace().collect::<Vec<_>>() == ["DATASET", "POLYDATA"] => {}
        Some((at, l)) => {
            return c.err(at, format!("expected DATASET POLYDATA, found {l:?}"));
        }
        None => return c.err(bytes.len(), "file ends before DATASET"),
    }

    let mut frame = ParticleFrame::default();
    let mut points: Option<usize> = None;
    let mut point_data = false;
    let mut has_velocity = false;
    while let Some((at, line)) = c.keyword_line()? {
        let toks: Vec<&str> = line.split_ascii_whitespace().collect();
        match toks.as_slice() {
            ["POINTS", n, ty] => {
                if points.is_some() {
                    return c.err(at, "duplicate POINTS section");
                }
                let n = parse_count(at, n, "point count")?;
                let ty = parse_type(at, ty)?;
                let v = c.values(n.saturating_mul(3), ty, "POINTS")?;
                frame.positions = v.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
                points = Some(n);
            }
            [
                kw @ ("VERTICES" | "LINES" | "POLYGONS" | "TRIANGLE_STRIPS"),
                _,
                size,
            ] => {
                let size = parse_count(at, size, "cell list size")?;
                c.block(size, VtkType::I32, kw)?;
            }
            ["POINT_DATA", n] => {
                let n = parse_count(at, n, "point count")?;
                if Some(n) != points {
                    return c.err(
                        at,
                        format!(
                            "POINT_DATA {n} does not match POINTS {}",
                            points.map_or("(missing)".to_string(), |p| p.to_string())
                        ),
                    );
                }
                point_data = true;
            }
            ["VECTORS", name, ty] => {
                let n = point_data_count(&c, at, point_data, points, "VECTORS")?;
                let ty = parse_type(at, ty)?;
                let v = c.values(3 * n, ty, "VECTORS")?;
                if *name == "velocity" && !has_velocity {
                    frame.velocities = v.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
                    has_velocity = true;
                } else {
                    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                        let values = v.iter().skip(k).step_by(3).copied().collect();
                        frame.push_field(format!("{name}.{axis}"), values);
                    }
                }
            }
            ["SCALARS", name, ty, rest @ ..] => {
                let n = point_data_count(&c, at, point_data, points, "SCALARS")?;
                let ty = parse_type(at, ty)?;
                match rest {
                    [] | ["1"] => {}
                    _ => return c.err(at, "only one-component SCALARS are supported"),
                }
                match c.keyword_line()? {
                    Some((_, l)) if l.starts_with("LOOKUP_TABLE") => {}
                    _ => return c.err(c.pos, format!("SCALARS {name} lacks LOOKUP_TABLE")),
                }
                let values = c.values(n, ty, "SCALARS")?;
                frame.push_field(*name, values);
            }
            ["FIELD", _, arrays] => {
                let arrays = parse_count(at, arrays, "FIELD array count")?;
                for _ in 0..arrays {
                    let Some((at, line)) = c.keyword_line()? else {
                        return c.err(bytes.len(), "file ends inside FIELD");
                    };
                    let toks: Vec<&str> = line.split_ascii_whitespace().collect();
                    let [name, comps, tuples, ty] = toks.as_slice() else {
                        return c.err(at, format!("expected a FIELD array header, found {line:?}"));
                    };
                    let comps = parse_count(at, comps, "component count")?;
                    let tuples = parse_count(at, tuples, "tuple count")?;
                    let ty = parse_type(at, ty)?;
                    let count = comps.saturating_mul(tuples);
                    let data = c.block(count, ty, name)?;
                    let first = data.get(..ty.size()).map(|b| ty.decode(b));
                    match (*name, count, first) {
                        ("TIME", 1, Some(t)) if !point_data => frame.time = t,
                        ("CYCLE", 1, Some(f)) if !point_data => {
                            frame.frame = if f >= 0.0 && f <= u32::MAX as f64 {
                                f as u32
                            } else {
                                return c.err(at, format!("invalid CYCLE {f}"));
                            };
                        }
                        _ if point_data && comps == 1 && Some(tuples) == points => {
                            let values = data.chunks_exact(ty.size()).map(|b| ty.decode(b) as f32);
                            frame.push_field(*name, values.collect());
                        }
                        _ => {}
                    }
                }
            }
            [kw, ..] => {
                return c.err(at, format!("unsupported VTK section {kw:?}"));
            }
            [] => unreachable!("keyword_line skips blank lines"),
        }
    }
    let Some(n) = points else {
        return c.err(bytes.len(), "no POINTS section");
    };
    if !has_velocity {
        frame.velocities = vec![[0.0; 3]; n];
    }
    Ok(frame)
}

/// The number of values per component of a point-data array, or an error outside
/// `POINT_DATA`.
fn point_data_count(
    c: &VtkCursor<'_>,
    at: usize,
    point_data: bool,
    points: Option<usize>,
    what: &str,
) -> VtkParse<usize> {
    match (point_data, points) {
        (true, Some(n)) => Ok(n),
        _ => c.err(at, format!("{what} outside POINT_DATA")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(bytes: &[u8]) -> Result<ParticleFrame, String> {
        parse_vtk(bytes).map_err(|VtkMalformed(at, m)| format!("{at}: {m}"))
    }

    fn sample_frame() -> ParticleFrame {
        ParticleFrame {
            frame: 17,
            time: 0.1 + 0.2,
            positions: vec![[0.0, 1.5, -2.0], [3.0, 4.0, 5.25], [1e-7, -0.0, 7.0]],
            velocities: vec![[1.0, 2.0, 3.0], [-1.0, 0.5, 0.0], [0.0, 0.0, -9.81]],
            fields: vec![
                ("density".into(), vec![1000.0, 998.5, 1002.25]),
                ("pressure".into(), vec![0.0, -150.0, 225.5]),
            ],
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let f = sample_frame();
        assert_eq!(parse(&encode_vtk(&f).unwrap()).unwrap(), f);
        let empty = ParticleFrame::new(0, 0.0);
        assert_eq!(parse(&encode_vtk(&empty).unwrap()).unwrap(), empty);
    }

    /// Legacy VTK has no section count or trailer, so a file cut exactly between two sections
    /// is a valid file with fewer arrays; every other cut must be an error, and none may panic.
    #[test]
    fn truncation_is_an_error_or_a_section_prefix() {
        let f = sample_frame();
        let bytes = encode_vtk(&f).unwrap();
        let mut accepted = 0;
        for len in 0..bytes.len() {
            if let Ok(g) = parse(&bytes[..len]) {
                accepted += 1;
                assert_eq!(g.positions, f.positions, "prefix of {len} bytes");
                assert!(f.fields.starts_with(&g.fields), "prefix of {len} bytes");
                assert!(g.fields.len() < f.fields.len() || len == bytes.len() - 1);
            }
        }
        // Cuts after the POINTS data, the VERTICES data, the `POINT_DATA 3` line, the velocity
        // block and the density block, each with or without the newline that follows, plus
        // the whole file without its final newline: 5 × 2 + 1.
        assert_eq!(accepted, 11, "{accepted} prefixes parsed");
    }

    #[test]
    fn errors_name_the_problem() {
        assert!(
            parse(b"ply\n")
                .unwrap_err()
                .contains("not a legacy VTK file")
        );
        let ascii = b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET POLYDATA\n";
        assert!(
            parse(ascii)
                .unwrap_err()
                .contains("ASCII VTK is not supported")
        );
        let grid = b"# vtk DataFile Version 3.0\nt\nBINARY\nDATASET STRUCTURED_POINTS\n";
        assert!(
            parse(grid)
                .unwrap_err()
                .contains("expected DATASET POLYDATA")
        );
        let mut bytes = encode_vtk(&sample_frame()).unwrap();
        let at = bytes
            .windows(12)
            .position(|w| w == b"POINT_DATA 3")
            .unwrap();
        bytes[at + 11] = b'4';
        assert!(
            parse(&bytes)
                .unwrap_err()
                .contains("POINT_DATA 4 does not match POINTS 3")
        );
    }

    #[test]
    fn empty_frame_layout() {
        let bytes = encode_vtk(&ParticleFrame::new(3, 1.5)).unwrap();
        let mut expected = b"# vtk DataFile Version 3.0\ntreacle frame 3 time 1.5\nBINARY\n\
            DATASET POLYDATA\nFIELD FieldData 2\nTIME 1 1 double\n"
            .to_vec();
        expected.extend_from_slice(&1.5f64.to_be_bytes());
        expected.extend_from_slice(b"\nCYCLE 1 1 int\n");
        expected.extend_from_slice(&3i32.to_be_bytes());
        expected.extend_from_slice(
            b"\nPOINTS 0 float\n\nVERTICES 0 0\n\nPOINT_DATA 0\nVECTORS velocity float\n\n",
        );
        assert_eq!(
            String::from_utf8_lossy(&bytes),
            String::from_utf8_lossy(&expected)
        );
    }
}
