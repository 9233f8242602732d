//! Triangle meshes: a minimal Wavefront OBJ reader and the closed-surface queries the scene
//! loader needs (volume by the divergence theorem, bounding box, closedness).
//!
//! The reader understands the subset of OBJ that describes geometry:
//!
//! - `v x y z [w]` vertex positions (`w` is ignored);
//! - `f i j k ...` faces with the index forms `i`, `i/t`, `i//n` and `i/t/n`; 1-based, negative
//!   indices count back from the last vertex read so far (`-1` is the latest vertex); polygons
//!   with more than three corners are fan-triangulated (`(i₀, i_k, i_k+1)`), which is exact for
//!   convex planar polygons;
//! - `#` comments (to the end of the line) and blank lines;
//! - every other statement (`vt`, `vn`, `o`, `g`, `s`, `usemtl`, `mtllib`, `l`, `p`, ...) is
//!   ignored.
//!
//! Errors name the file and the 1-based line ([`ObjError`]). The reader never panics on bad
//! input. Vertices are not welded: faces must share vertex indices for [`TriMesh::is_closed`]
//! to see the shared edges (every common exporter writes indexed meshes this way).
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::math::Vec3;

/// An error while reading an OBJ file: file, 1-based line (0 when the file could not be read)
/// and what is wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}:{line}: {message}", file.display())]
pub struct ObjError {
    /// The file.
    pub file: PathBuf,
    /// 1-based line number (0: the file itself, e.g. it could not be read).
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// An indexed triangle mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions \[m once scaled; OBJ files carry no unit\].
    pub vertices: Vec<Vec3>,
    /// Triangles as indices into `vertices`. For a positive [`TriMesh::signed_volume`] the
    /// corners are counter-clockwise seen from outside (outward normals).
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Reads an OBJ file. See the [module documentation](self) for the supported subset.
    pub fn load_obj(path: &Path) -> Result<TriMesh, ObjError> {
        let text = std::fs::read_to_string(path).map_err(|e| ObjError {
            file: path.to_path_buf(),
            line: 0,
            message: format!("cannot read mesh file: {e}"),
        })?;
        Self::parse_obj(&text, path)
    }

    /// Parses OBJ text; `file` is only used in error messages.
    pub fn parse_obj(text: &str, file: &Path) -> Result<TriMesh, ObjError> {
        let err = |line: usize, message: String| ObjError {
            file: file.to_path_buf(),
            line,
            message,
        };
        let mut mesh = TriMesh::default();
        let mut corners: Vec<u32> = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line_no = i + 1;
            let line = raw.split('#').next().unwrap_or("");
            let mut words = line.split_whitespace();
            let Some(keyword) = words.next() else {
                continue;
            };
            match keyword {
                "v" => {
                    let mut c = [0.0f32; 3];
                    for (axis, slot) in c.iter_mut().enumerate() {
                        let word = words.next().ok_or_else(|| {
                            err(line_no, format!("vertex needs 3 coordinates, found {axis}"))
                        })?;
                        let value: f32 = word.parse().map_err(|_| {
                            err(line_no, format!("invalid vertex coordinate `{word}`"))
                        })?;
                        if !value.is_finite() {
                            return Err(err(
                                line_no,
                                format!("vertex coordinate `{word}` is not finite"),
                            ));
                        }
                        *slot = value;
                    }
                    if mesh.vertices.len() >= u32::MAX as usize {
                        return Err(err(line_no, "too many vertices".into()));
                    }
                    mesh.vertices.push(Vec3::from_array(c));
                }
                "f" => {
                    corners.clear();
                    for word in words {
                        let index_text = word.split('/').next().unwrap_or("");
                        let index: i64 = index_text
                            .parse()
                            .map_err(|_| err(line_no, format!("invalid face vertex `{word}`")))?;
                        let n = mesh.vertices.len() as i64;
                        let resolved = if index > 0 {
                            index - 1
                        } else if index < 0 {
                            n + index
                        } else {
                            return Err(err(
                                line_no,
                                "face index 0 is invalid (OBJ indices start at 1)".into(),
                            ));
                        };
                        if resolved < 0 || resolved >= n {
                            return Err(err(
                                line_no,
                                format!(
                                    "face index {index} refers to a missing vertex \
                                     ({n} vertices defined so far)"
                                ),
                            ));
                        }
                        corners.push(resolved as u32);
                    }
                    if corners.len() < 3 {
                        return Err(err(
                            line_no,
                            format!("face needs at least 3 vertices, found {}", corners.len()),
                        ));
                    }
                    for k in 1..corners.len() - 1 {
                        mesh.triangles
                            .push([corners[0], corners[k], corners[k + 1]]);
                    }
                }
                _ => {}
            }
        }
        Ok(mesh)
    }

    /// The mesh with every vertex mapped to `scale · v + translation`.
    pub fn transformed(mut self, scale: f32, translation: Vec3) -> TriMesh {
        for v in &mut self.vertices {
            *v = *v * scale + translation;
        }
        self
    }

    /// Signed enclosed volume Σ a·(b×c)/6 over the triangles (divergence theorem) \[m³\],
    /// computed in `f64`. Positive when the triangles are oriented outwards. Meaningful only
    /// for a closed mesh.
    pub fn signed_volume(&self) -> f64 {
        let mut sum = 0.0f64;
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.vertices[i as usize].as_dvec3());
            sum += a.dot(b.cross(c));
        }
        sum / 6.0
    }

    /// Enclosed volume |[`signed_volume`](Self::signed_volume)| \[m³\].
    pub fn volume(&self) -> f64 {
        self.signed_volume().abs()
    }

    /// Axis-aligned bounding box `(min, max)` of the vertices referenced by triangles, or
    /// `None` if there are no triangles.
    pub fn aabb(&self) -> Option<(Vec3, Vec3)> {
        let mut it = self
            .triangles
            .iter()
            .flat_map(|t| t.iter())
            .map(|&i| self.vertices[i as usize]);
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v))))
    }

    /// Number of edges not shared by exactly two triangles (0 for a closed mesh).
    pub fn open_edge_count(&self) -> usize {
        let mut count: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 2);
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                *count.entry((a.min(b), a.max(b))).or_insert(0) += 1;
            }
        }
        count.values().filter(|&&n| n != 2).count()
    }

    /// Whether the mesh is closed: it has triangles and every edge is shared by exactly two
    /// triangles.
    pub fn is_closed(&self) -> bool {
        !self.triangles.is_empty() && self.open_edge_count() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<TriMesh, ObjError> {
        TriMesh::parse_obj(text, Path::new("test.obj"))
    }

    const CUBE: &str = "\
# unit cube
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 4 3 2
f 5 6 7 8
f 1 2 6 5
f 2 3 7 6
f 3 4 8 7
f 4 1 5 8
";

    #[test]
    fn cube_volume_and_closedness() {
        let m = parse(CUBE).unwrap();
        assert_eq!(m.triangles.len(), 12);
        assert!(m.is_closed());
        assert!((m.signed_volume() - 1.0).abs() < 1e-12);
        assert_eq!(m.aabb(), Some((Vec3::ZERO, Vec3::ONE)));
        let s = m.transformed(2.0, Vec3::X);
        assert!((s.volume() - 8.0).abs() < 1e-9);
    }

    #[test]
    fn index_forms_and_negative_indices() {
        let m = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf -3/1/1 2//1 3/1\n").unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
        assert!(!m.is_closed());
        assert_eq!(m.open_edge_count(), 3);
    }

    #[test]
    fn errors_name_line() {
        let e = parse("v 0 0 0\nv 1 0\n").unwrap_err();
        assert_eq!(e.line, 2);
        assert!(e.to_string().starts_with("test.obj:2:"), "{e}");
        let e = parse("v 0 0 0\nv 1 0 0\nv 0 1 0\n\n f 1 2 4\n").unwrap_err();
        assert_eq!(e.line, 5);
        assert!(e.message.contains("missing vertex"));
        assert_eq!(parse("v 0 0 0\nf 0 1 1").unwrap_err().line, 2);
        assert_eq!(parse("v 0 0 0\nf 1 1").unwrap_err().line, 2);
        assert_eq!(parse("v 0 x 0").unwrap_err().line, 1);
        assert_eq!(parse("v 0 inf 0").unwrap_err().line, 1);
        assert_eq!(parse("v 0 0 0\nf a 1 1").unwrap_err().line, 2);
    }
}
