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

#[cfg(test)]
mod tests {
    use super::*;

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
