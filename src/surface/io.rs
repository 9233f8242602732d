//! OBJ and PLY writers of [`SurfaceMesh`], atomic and refusing non-finite data.
use std::path::Path;

use super::{SurfaceError, SurfaceMesh};
use crate::output::{RESERVED_NAMES, write_atomic_with};

/// Why `mesh` (and the optional per-vertex values) may not be written, if it may not.
fn problem(mesh: &SurfaceMesh, values: Option<(&str, &[f32])>) -> Option<String> {
    let n = mesh.vertices.len();
    if mesh.normals.len() != n {
        return Some(format!("{} normals for {n} vertices", mesh.normals.len()));
    }
    if let Some(i) = mesh.vertices.iter().position(|v| !v.is_finite()) {
        return Some(format!("vertex {i} is {:?}", mesh.vertices[i]));
    }
    if let Some(i) = mesh.normals.iter().position(|v| !v.is_finite()) {
        return Some(format!("normal {i} is {:?}", mesh.normals[i]));
    }
    if n > u32::MAX as usize {
        return Some(format!("{n} vertices do not fit 32-bit indices"));
    }
    if let Some(i) = mesh
        .triangles
        .iter()
        .position(|t| t.iter().any(|&v| v as usize >= n))
    {
        return Some(format!(
            "triangle {i} {:?} indexes beyond {n} vertices",
            mesh.triangles[i]
        ));
    }
    if let Some((name, values)) = values {
        if let Some(reason) = crate::output::name_problem(name) {
            return Some(format!("vertex property name {name:?}: {reason}"));
        }
        if RESERVED_NAMES.contains(&name) || ["nx", "ny", "nz"].contains(&name) {
            return Some(format!("vertex property name {name:?} is reserved"));
        }
        if values.len() != n {
            return Some(format!(
                "{} values of {name} for {n} vertices",
                values.len()
            ));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Some(format!("{name} at vertex {i} is {}", values[i]));
        }
    }
    None
}

fn check(
    mesh: &SurfaceMesh,
    path: &Path,
    values: Option<(&str, &[f32])>,
) -> Result<(), SurfaceError> {
    match problem(mesh, values) {
        None => Ok(()),
        Some(what) => Err(SurfaceError::InvalidMesh {
            path: path.to_path_buf(),
            what,
        }),
    }
}

pub(super) fn write_obj(mesh: &SurfaceMesh, path: &Path) -> Result<(), SurfaceError> {
    check(mesh, path, None)?;
    write_atomic_with(path, |w| {
        writeln!(
            w,
            "# treacle surface mesh: {} vertices, {} triangles",
            mesh.vertices.len(),
            mesh.triangles.len()
        )?;
        for v in &mesh.vertices {
            writeln!(w, "v {} {} {}", v.x, v.y, v.z)?;
        }
        for n in &mesh.normals {
            writeln!(w, "vn {} {} {}", n.x, n.y, n.z)?;
        }
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| i as u64 + 1);
            writeln!(w, "f {a}//{a} {b}//{b} {c}//{c}")?;
        }
        Ok(())
    })?;
    Ok(())
}

pub(super) fn write_ply(
    mesh: &SurfaceMesh,
    path: &Path,
    values: Option<(&str, &[f32])>,
) -> Result<(), SurfaceError> {
    check(mesh, path, values)?;
    write_atomic_with(path, |w| {
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\ncomment treacle surface mesh\n\
             element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
             property float nx\nproperty float ny\nproperty float nz\n",
            mesh.vertices.len()
        )?;
        if let Some((name, _)) = values {
            writeln!(w, "property float {name}")?;
        }
        write!(
            w,
            "element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
            mesh.triangles.len()
        )?;
        for (i, (v, n)) in mesh.vertices.iter().zip(&mesh.normals).enumerate() {
            for x in v.to_array().into_iter().chain(n.to_array()) {
                w.write_all(&x.to_le_bytes())?;
            }
            if let Some((_, values)) = values {
                w.write_all(&values[i].to_le_bytes())?;
            }
        }
        for t in &mesh.triangles {
            w.write_all(&[3u8])?;
            for i in t {
                w.write_all(&i.to_le_bytes())?;
            }
        }
        Ok(())
    })?;
    Ok(())
}
