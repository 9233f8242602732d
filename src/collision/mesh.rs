//! Triangle-mesh colliders: the signed distance φ and outward normal of a closed triangle
//! mesh, for the grid collision operator of ALGORITHM §2.11 (φ ≤ 0 and n = ∇φ at a node).
//!
//! A [`MeshSdf`] is built once from a closed, consistently oriented [`TriMesh`] (in the
//! collider's local frame) and shared between colliders and steps through an `Arc`
//! ([`ColliderShape::Mesh`](super::ColliderShape::Mesh)). It holds:
//!
//! - a parry3d `TriMesh` with its bounding-volume hierarchy and angle-weighted
//!   **pseudo-normals** (Bærentzen & Aanæs 2005): the closest point on the surface comes from
//!   a BVH search, and the point is inside iff `(p − closest) · pseudo-normal < 0`, where the
//!   pseudo-normal is that of the closest feature (face, edge or vertex). This sign is exact
//!   for a closed, consistently oriented mesh;
//! - a coarse **inside/outside voxel grid** (spacing `s` = longest side / [`VOXELS`], filled
//!   by ray parity with [`sample_mesh`]) used to skip the
//!   unbounded distance search far from the surface.
//!
//! [`MeshSdf::sdf`] is what the per-node collision loop calls; it is fast because it only
//! computes what the projection needs:
//!
//! 1. farther than the band `r = s` from the mesh's bounding box: the distance to the box and
//!    the normal pointing away from it. A point outside the box is outside the mesh, so
//!    φ > 0 is all the collision operator uses (it projects only where φ ≤ 0); the returned
//!    φ is a **lower bound** (> r);
//! 2. otherwise, the closest surface point within `r` (a bounded BVH search, cheap): exact φ
//!    and normal;
//! 3. no surface within `r`: the point's voxel centre is within `√3·s/2 < r` of it, so no
//!    surface separates them and the voxel's sign is the point's. Outside: φ = r (a lower
//!    bound) with a normal pointing away from the box centre. Inside: the exact distance by
//!    a search of growing radius.
//!
//! So φ and n are exact wherever φ ≤ r, in particular wherever the collision operator acts,
//! and elsewhere φ is a lower bound with r ≤ φ ≤ φ_exact. [`MeshSdf::exact_sdf`] is exact
//! everywhere.
use std::fmt;
use std::path::Path;

use parry3d::query::PointQueryWithLocation;
use parry3d::shape::{TriMesh as ParryTriMesh, TriMeshFlags, TrianglePointLocation};

use glam::DVec3;

use crate::math::{Real, Vec3};
use crate::mesh::{ObjError, TriMesh};
use crate::sampling::{Lattice, sample_mesh};

/// Voxels of the inside/outside grid along the mesh's longest bounding-box side.
pub const VOXELS: u32 = 128;

/// Why a mesh cannot become a collider.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshSdfError {
    /// The OBJ file could not be read or parsed.
    #[error(transparent)]
    Obj(#[from] ObjError),
    /// No triangles.
    #[error("the mesh has no triangles")]
    Empty,
    /// A vertex coordinate is NaN or infinite (e.g. after scaling).
    #[error("the mesh has non-finite vertex coordinates")]
    NonFinite,
    /// Some edges are not shared by exactly two triangles.
    #[error(
        "the mesh is not closed: {open_edges} edges are not shared by exactly two triangles \
         (the inside of an open surface is undefined)"
    )]
    NotClosed {
        /// Number of such edges ([`TriMesh::open_edge_count`]).
        open_edges: usize,
    },
    /// The enclosed volume is zero (or too small to be represented).
    #[error("the mesh encloses no volume")]
    NoVolume,
    /// Vertex coordinates below the smallest normal single-precision number (e.g. after a
    /// tiny scale): their geometry is lost to rounding (and the bounding-volume hierarchy
    /// would degenerate).
    #[error(
        "the mesh is too small for single precision: vertex coordinates below {:e} m",
        f32::MIN_POSITIVE
    )]
    TooSmall,
    /// parry3d rejected the mesh.
    #[error("cannot build the mesh collider: {0}")]
    Build(String),
}

/// The signed distance field of a closed triangle mesh (see the [module documentation](self)).
///
/// Equality is **identity**: two `MeshSdf` values are equal only if they are the same object
/// (so `Arc<MeshSdf>` compares by pointer, which is what [`ColliderShape`](super::ColliderShape)'s
/// `PartialEq` needs; comparing two meshes triangle by triangle is never wanted there).
pub struct MeshSdf {
    mesh: ParryTriMesh,
    /// Triangles around each vertex (CSR: `fans[fan_start[v]..fan_start[v + 1]]`).
    fan_start: Vec<u32>,
    fans: Vec<u32>,
    min: Vec3,
    max: Vec3,
    band: Real,
    inside: InsideGrid,
    volume: f64,
    label: String,
}

impl PartialEq for MeshSdf {
    fn eq(&self, other: &Self) -> bool {
        std::ptr::eq(self, other)
    }
}

impl fmt::Debug for MeshSdf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("MeshSdf")
            .field("label", &self.label)
            .field("vertices", &self.mesh.vertices().len())
            .field("triangles", &self.mesh.indices().len())
            .field("aabb", &(self.min, self.max))
            .field("volume", &self.volume)
            .field("band", &self.band)
            .finish_non_exhaustive()
    }
}

/// Inside/outside flags at the voxel centres `origin + (i + ½)·spacing`.
#[derive(Clone)]
struct InsideGrid {
    origin: Vec3,
    spacing: Real,
    dims: [usize; 3],
    bits: Vec<u64>,
}

impl InsideGrid {
    fn new(mesh: &TriMesh, min: Vec3, max: Vec3) -> Self {
        let extent = max - min;
        let spacing = extent.max_element() / VOXELS as Real;
        // One voxel of padding on every side.
        let origin = min - Vec3::splat(spacing);
        let dims: [usize; 3] =
            std::array::from_fn(|a| (extent[a] / spacing).ceil().max(1.0) as usize + 2);
        let mut grid = Self {
            origin,
            spacing,
            dims,
            bits: vec![0; (dims[0] * dims[1] * dims[2]).div_ceil(64)],
        };
        let lattice = Lattice { origin, spacing };
        for p in sample_mesh(&lattice, mesh).sample.positions {
            if let Some(i) = grid.index(p) {
                grid.bits[i / 64] |= 1 << (i % 64);
            }
        }
        grid
    }

    /// Linear index of the voxel containing `p`.
    fn index(&self, p: Vec3) -> Option<usize> {
        let t = (p - self.origin) / self.spacing;
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let f = t[a].floor();
            if !(f >= 0.0 && (f as usize) < self.dims[a]) {
                return None;
            }
            idx[a] = f as usize;
        }
        Some((idx[0] * self.dims[1] + idx[1]) * self.dims[2] + idx[2])
    }

    /// Whether the centre of the voxel containing `p` is inside the mesh.
    fn inside(&self, p: Vec3) -> Option<bool> {
        self.index(p)
            .map(|i| self.bits[i / 64] & (1 << (i % 64)) != 0)
    }
}

impl MeshSdf {
    /// Prepares a closed mesh (vertices in the collider's local frame \[m\]). A mesh with a
    /// negative signed volume (inward normals) is re-oriented. Errors if the mesh is empty,
    /// not closed ([`TriMesh::is_closed`]), has non-finite coordinates or encloses no volume.
    pub fn new(mesh: &TriMesh) -> Result<Self, MeshSdfError> {
        Self::with_label(mesh, String::new())
    }

    /// Reads an OBJ file ([`TriMesh::load_obj`]), scales it by `scale` about the OBJ origin
    /// (which becomes the collider origin) and prepares it with [`MeshSdf::new`].
    pub fn from_obj(path: &Path, scale: Real) -> Result<Self, MeshSdfError> {
        let mesh = TriMesh::load_obj(path)?.transformed(scale, Vec3::ZERO);
        Self::with_label(&mesh, format!("{} ×{scale}", path.display()))
    }

    fn with_label(mesh: &TriMesh, label: String) -> Result<Self, MeshSdfError> {
        if mesh.triangles.is_empty() {
            return Err(MeshSdfError::Empty);
        }
        if !mesh.vertices.iter().all(|v| v.is_finite()) {
            return Err(MeshSdfError::NonFinite);
        }
        if mesh
            .vertices
            .iter()
            .any(|v| v.to_array().iter().any(|c| *c != 0.0 && !c.is_normal()))
        {
            return Err(MeshSdfError::TooSmall);
        }
        let open_edges = mesh.open_edge_count();
        if open_edges > 0 {
            return Err(MeshSdfError::NotClosed { open_edges });
        }
        let signed = mesh.signed_volume();
        let (min, max) = mesh.aabb().ok_or(MeshSdfError::Empty)?;
        let extent = (max - min).max_element();
        if !(signed.abs() > 0.0 && extent > 0.0 && extent.is_finite()) {
            return Err(MeshSdfError::NoVolume);
        }
        let mut oriented = mesh.clone();
        if signed < 0.0 {
            for t in &mut oriented.triangles {
                t.swap(1, 2);
            }
        }
        let inside = InsideGrid::new(&oriented, min, max);
        let band = inside.spacing;
        let parry = ParryTriMesh::with_flags(
            oriented.vertices.clone(),
            oriented.triangles.clone(),
            TriMeshFlags::ORIENTED,
        )
        .map_err(|e| MeshSdfError::Build(format!("{e:?}")))?;
        let (fan_start, fans) = vertex_fans(&oriented);
        Ok(Self {
            mesh: parry,
            fan_start,
            fans,
            min,
            max,
            band,
            inside,
            volume: signed.abs(),
            label,
        })
    }

    /// Bounding box `(min, max)` in the local frame \[m\].
    pub fn aabb(&self) -> (Vec3, Vec3) {
        (self.min, self.max)
    }

    /// Enclosed volume \[m³\].
    pub fn volume(&self) -> f64 {
        self.volume
    }

    /// Band r \[m\]: [`MeshSdf::sdf`] is exact wherever φ ≤ r.
    pub fn band(&self) -> Real {
        self.band
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.mesh.indices().len()
    }

    /// Vertices in the local frame \[m\] (for drawing the mesh).
    pub fn vertices(&self) -> &[Vec3] {
        self.mesh.vertices()
    }

    /// Triangles (vertex indices), oriented with outward normals (counter-clockwise seen from
    /// outside).
    pub fn triangles(&self) -> &[[u32; 3]] {
        self.mesh.indices()
    }

    /// Where the mesh came from (file and scale for [`MeshSdf::from_obj`], else empty).
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Signed distance φ \[m\] (negative inside) and outward unit normal at local point `p`,
    /// exact where φ ≤ [`band`](Self::band) and a positive lower bound elsewhere (see the
    /// [module documentation](self)). A non-finite `p` gives (+∞, +y).
    pub fn sdf(&self, p: Vec3) -> (Real, Vec3) {
        if !p.is_finite() {
            return (Real::INFINITY, Vec3::Y);
        }
        let q = p.clamp(self.min, self.max);
        let d = p - q;
        let dl = d.length();
        if dl > self.band {
            return (dl, d / dl);
        }
        if let Some(hit) = self.closest(p, self.band) {
            return hit;
        }
        match self.inside.inside(p) {
            Some(false) => {
                let away = (p - 0.5 * (self.min + self.max)).normalize_or(Vec3::Y);
                (self.band, away)
            }
            _ => self.search_from(p, 4.0 * self.band),
        }
    }

    /// Exact signed distance φ \[m\] and outward unit normal at local point `p`, also far from
    /// the surface (slower than [`MeshSdf::sdf`] there). A non-finite `p` gives (+∞, +y).
    pub fn exact_sdf(&self, p: Vec3) -> (Real, Vec3) {
        if !p.is_finite() {
            return (Real::INFINITY, Vec3::Y);
        }
        self.search_from(p, self.band)
    }

    /// Whether local point `p` is inside the mesh (φ < 0 by [`MeshSdf::sdf`]).
    pub fn contains(&self, p: Vec3) -> bool {
        self.sdf(p).0 < 0.0
    }

    /// Closest-point search with a radius growing ×4 from `radius` (each bounded search
    /// prunes the BVH to the triangles near `p`), unbounded once it covers the bounding box.
    fn search_from(&self, p: Vec3, mut radius: Real) -> (Real, Vec3) {
        let reach = (p - 0.5 * (self.min + self.max)).length() + (self.max - self.min).length();
        while radius < reach {
            if let Some(hit) = self.closest(p, radius) {
                return hit;
            }
            radius *= 4.0;
        }
        self.closest(p, Real::MAX)
            .unwrap_or((Real::INFINITY, Vec3::Y))
    }

    /// φ and n from the closest surface point within `max_dist`, if there is one.
    ///
    /// parry's search compares distances in f32, so near an edge or vertex it may return the
    /// neighbouring triangle whose closest point is that edge or vertex although a face is
    /// closer by less than an f32 ulp; the direction to it is then off by up to
    /// ~√(2·ulp/φ) ≈ 3·10⁻⁴ rad. When it reports an edge or a vertex, the triangles around
    /// that feature are therefore re-projected in f64 and the closest one kept.
    fn closest(&self, p: Vec3, max_dist: Real) -> Option<(Real, Vec3)> {
        let (proj, (tri, location)) = self
            .mesh
            .project_local_point_and_get_location_with_max_dist(p, false, max_dist)?;
        let feature = match location {
            TrianglePointLocation::OnFace(..) | TrianglePointLocation::OnSolid => Feature::Face,
            TrianglePointLocation::OnEdge(i, _) => Feature::Edge(i),
            TrianglePointLocation::OnVertex(i) => Feature::Vertex(i),
        };
        let pd = p.as_dvec3();
        let (q, tri, feature) = match feature {
            Feature::Face => (proj.point.as_dvec3(), tri, feature),
            _ => self.refine(pd, tri, feature),
        };
        let pseudo = self.pseudo_normal(tri, feature);
        let dv = pd - q;
        let d = dv.length();
        let inside = if pseudo.length_squared() > 0.0 && pseudo.is_finite() {
            dv.dot(pseudo.as_dvec3()) <= 0.0
        } else {
            // Only with degenerate (zero-area) neighbourhoods: fall back to the winding number.
            self.winding_number(p) > 0.5
        };
        // Below this distance the direction p − closest is rounding noise; use the feature's
        // pseudo-normal instead (it is the limit of ∇φ on the surface).
        let tiny = 1e-6 * (self.max - self.min).max_element() as f64;
        let n = if d > tiny {
            (if inside { -dv / d } else { dv / d }).as_vec3()
        } else {
            pseudo.normalize_or(Vec3::Y)
        };
        Some(((if inside { -d } else { d }) as Real, n))
    }

    /// The closest point to `p` (f64) among the triangles around `feature` of triangle `tri`.
    fn refine(&self, p: DVec3, tri: u32, feature: Feature) -> (DVec3, u32, Feature) {
        let idx = self.mesh.indices()[tri as usize];
        let fan = |v: u32| {
            let v = v as usize;
            &self.fans[self.fan_start[v] as usize..self.fan_start[v + 1] as usize]
        };
        // The triangles around the feature: those sharing the vertex, or both edge ends.
        let (a, b) = match feature {
            Feature::Edge(i) => (idx[i as usize], Some(idx[(i as usize + 1) % 3])),
            Feature::Vertex(i) => (idx[i as usize], None),
            Feature::Face => (idx[0], Some(idx[1])),
        };
        let mut best = (f64::INFINITY, DVec3::ZERO, tri, feature);
        for &t in fan(a) {
            if b.is_some_and(|b| !fan(b).contains(&t)) {
                continue;
            }
            let [va, vb, vc] = self.mesh.indices()[t as usize]
                .map(|v| self.mesh.vertices()[v as usize].as_dvec3());
            let (q, f) = closest_on_triangle(p, va, vb, vc);
            let d2 = (p - q).length_squared();
            if d2 < best.0 {
                best = (d2, q, t, f);
            }
        }
        (best.1, best.2, best.3)
    }

    /// Outward pseudo-normal (not normalised) of `feature` of triangle `tri`.
    fn pseudo_normal(&self, tri: u32, feature: Feature) -> Vec3 {
        let face = || self.mesh.triangle(tri).scaled_normal();
        let Some(pn) = self.mesh.pseudo_normals() else {
            return face();
        };
        match feature {
            Feature::Face => face(),
            Feature::Edge(i) => pn
                .edges_pseudo_normal
                .get(tri as usize)
                .map_or(Vec3::ZERO, |e| e[i as usize]),
            Feature::Vertex(i) => {
                let v = self.mesh.indices()[tri as usize][i as usize];
                pn.vertices_pseudo_normal
                    .get(v as usize)
                    .copied()
                    .unwrap_or(Vec3::ZERO)
            }
        }
    }

    /// Generalised winding number of the surface around `p` (1 inside, 0 outside), by the
    /// solid angles of the triangles (Van Oosterom & Strackee 1983), in `f64`. O(triangles).
    fn winding_number(&self, p: Vec3) -> f64 {
        let p = p.as_dvec3();
        let v = self.mesh.vertices();
        let mut sum = 0.0;
        for t in self.mesh.indices() {
            let [a, b, c] = t.map(|i| v[i as usize].as_dvec3() - p);
            let (la, lb, lc) = (a.length(), b.length(), c.length());
            let num = a.dot(b.cross(c));
            let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
            sum += 2.0 * num.atan2(den);
        }
        sum / (4.0 * std::f64::consts::PI)
    }
}

/// A feature of a triangle (corners a, b, c): its interior, edge 0 = ab, 1 = bc, 2 = ca, or
/// vertex 0, 1, 2 (parry's edge numbering, whose edge 2 is ac = ca).
#[derive(Clone, Copy, Debug, PartialEq)]
enum Feature {
    Face,
    Edge(u32),
    Vertex(u32),
}

/// The triangles around every vertex, as (offsets, list).
fn vertex_fans(mesh: &TriMesh) -> (Vec<u32>, Vec<u32>) {
    let mut start = vec![0u32; mesh.vertices.len() + 1];
    for t in &mesh.triangles {
        for &v in t {
            start[v as usize + 1] += 1;
        }
    }
    for i in 0..mesh.vertices.len() {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut fans = vec![0u32; start[mesh.vertices.len()] as usize];
    for (ti, t) in mesh.triangles.iter().enumerate() {
        for &v in t {
            fans[fill[v as usize] as usize] = ti as u32;
            fill[v as usize] += 1;
        }
    }
    (start, fans)
}

/// Closest point of triangle abc to p and the feature it lies on, by the Voronoi regions of
/// the vertices, edges and face (Ericson, *Real-Time Collision Detection*, §5.1.5), in f64.
fn closest_on_triangle(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> (DVec3, Feature) {
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return (a, Feature::Vertex(0));
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return (b, Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return (a + ab * (d1 / (d1 - d3)), Feature::Edge(0));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return (c, Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return (a + ac * (d2 / (d2 - d6)), Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && d4 - d3 >= 0.0 && d5 - d6 >= 0.0 {
        return (
            b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))),
            Feature::Edge(1),
        );
    }
    let denom = va + vb + vc;
    if denom <= 0.0 {
        // Degenerate (zero-area) triangle: its closest edge end, conservatively.
        let best = [(a, 0), (b, 1), (c, 2)]
            .into_iter()
            .min_by(|x, y| {
                (p - x.0)
                    .length_squared()
                    .total_cmp(&(p - y.0).length_squared())
            })
            .unwrap_or((a, 0));
        return (best.0, Feature::Vertex(best.1));
    }
    let (v, w) = (vb / denom, vc / denom);
    (a + ab * v + ac * w, Feature::Face)
}
