//! A liquid surface: a closed triangle mesh reconstructed from particle positions (issue 16).
//!
//! Feature `surface` (not default; the future `render` feature enables it). It adds no
//! dependency: about 1,300 lines of code (without tests) and nothing to the dependency graph
//! (BENCHMARKS.md (i) compares it with `splashsurf_lib`).
//!
//! # Method
//!
//! 1. **A volume-fraction field on a grid.** Each particle stands for the volume h³ of its
//!    lattice cell (h = [`SurfaceParams::spacing`]). The field
//!    φ(x) = Σₚ h³ W(x − xₚ) uses the tensor-product cubic B-spline
//!    W(r) = Πₖ N₃(rₖ/ℓ)/ℓ of scale ℓ = [`smoothing`](SurfaceParams::smoothing) · h
//!    (support ±2ℓ per axis). N₃ is a partition of unity, so φ = 1 exactly inside a region
//!    filled with particles on a lattice of spacing h = ℓ, φ ≈ 1 for any other scale or a
//!    disordered filling, and φ → 0 outside. A half-space of lattice particles gives φ = ½
//!    exactly on the plane half a spacing beyond its last particles, i.e. on the face of the
//!    particle-filled volume N h³. The field is sampled on a regular grid of cell
//!    [`cell`](SurfaceParams::cell) · h covering the particles plus the kernel support; each
//!    particle adds to its (4ℓ/c + 1)³ nodes.
//! 2. **Marching tetrahedra.** Every grid cube is split into the six tetrahedra of the
//!    Freudenthal (Kuhn) subdivision along its main diagonal; the split of each cube face
//!    matches its neighbour's, so the surface φ = [`iso`](SurfaceParams::iso) is extracted
//!    without ambiguous cases and the mesh is closed: every edge is shared by exactly two
//!    triangles, consistently oriented, with outward normals. Vertices lie on grid edges
//!    (cube edges, face diagonals, main diagonals) where φ crosses the iso value, placed by
//!    linear interpolation and shared by all triangles around the edge. The case tables are
//!    generated when the module runs, from the tetrahedra's orientation and the twelve even
//!    permutations of four vertices, not written out by hand.
//! 3. **Normals** are −∇φ/|∇φ| at each vertex (central differences at the grid nodes,
//!    interpolated like the position).
//! 4. **Domain** ([`SurfaceParams::domain`], [`SurfaceDomain`]). Vertices beyond the box (the
//!    simulation domain) are moved onto its faces, and within a wall layer of a wall face the
//!    field is extended onto the wall (MPM particles stop short of walls): a puddle on the
//!    floor ends flat on the floor and the mesh stays closed (its part on the floor is a face
//!    of the mesh, so [`SurfaceMesh::volume`] is the liquid's volume).
//!
//! Accuracy: the iso-surface of a smoothed body lies inside it by σ² times its mean curvature
//! (σ² = ℓ²/3, the kernel's variance per axis; σ²/R on a sphere of radius R), and the grid's
//! chords and linear interpolation misplace it by O(c²/R). `tests/it/surface.rs`: a lattice
//! sphere of 33,552 particles (R = 20 h) meshes to 0.9968 × N h³ = 0.9993 × (4/3)π(R − σ²/R)³
//! (4,224 particles, R = 10 h: 0.9875 and 0.9974); the droplet scene's meshes enclose 0.979–0.988 ×
//! Σ m/ρ of their frames.
//!
//! Determinism: the output depends only on the positions and the parameters, bit for bit,
//! for any number of threads (the grid is filled slab by slab in two phases, like the
//! particle-to-grid scatter; vertices and triangles are numbered by grid order).
//!
//! Cost (BENCHMARKS.md (i), 2 threads, defaults): a lattice sphere of 100k particles in about
//! 23 ms, 1M in about 330 ms, measured on a 2-core machine shared with other builds.
//!
//! ```
//! use treacle::math::Vec3;
//! use treacle::surface::{SurfaceParams, reconstruct_surface};
//!
//! let h = 0.01;
//! let mut positions = Vec::new();
//! for i in 0..10 {
//!     for j in 0..10 {
//!         for k in 0..10 {
//!             positions.push((Vec3::new(i as f32, j as f32, k as f32) + 0.5) * h);
//!         }
//!     }
//! }
//! let mesh = reconstruct_surface(&positions, &SurfaceParams::for_spacing(h))?;
//! assert_eq!(mesh.boundary_edges(), 0);
//! // A 10 cm cube, rounded at its edges and corners by the kernel.
//! assert!((mesh.volume() / 1e-3 - 1.0).abs() < 0.05);
//! # Ok::<(), treacle::surface::SurfaceError>(())
//! ```
mod field;
mod io;
mod march;
mod neighbours;

use std::path::{Path, PathBuf};

use crate::math::Vec3;
use crate::output::OutputError;

pub use neighbours::estimate_spacing;

/// Parameters of [`reconstruct_surface`] and [`interpolate_to_vertices`].
///
/// Lengths other than [`spacing`](Self::spacing) are in particle spacings, so the defaults
/// suit any resolution once the spacing is set ([`SurfaceParams::for_spacing`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceParams {
    /// Particle spacing h \[m\]: each particle stands for the volume h³. Scenes seed particles
    /// at h = Δx / `particles_per_cell` (Δx/2 by default); for a frame of unknown origin use
    /// [`estimate_spacing`]. Default 0.01 m (set it: the default is only a placeholder).
    pub spacing: f32,
    /// Kernel scale ℓ in spacings: the cubic B-spline reaches 2ℓ from a particle along each
    /// axis. Larger is smoother (and rounder at edges, and slower). Default 1.0, which gives
    /// φ = 1 exactly inside a lattice filling.
    pub smoothing: f32,
    /// Iso value of the volume fraction φ that is the surface, in (0, 1). Default 0.5 (the
    /// face of the particle-filled volume for a flat surface). With ℓ = h an isolated
    /// particle peaks at φ = (2/3)³ ≈ 0.30 and a pair of neighbours at 0.43, so lone spray
    /// particles and pairs leave no surface; a square of four neighbours does (0.61).
    pub iso: f32,
    /// Grid cell size c in spacings (the marching-tetrahedra resolution). Default 0.75:
    /// triangles about half a spacing across. The work grows about as 1/c³ (BENCHMARKS.md
    /// (i): 0.5 costs 3× the default for 2.3× the triangles, and changes the volume of a
    /// lattice sphere by 2·10⁻⁴).
    pub cell: f32,
    /// The box the liquid is confined to (the simulation domain) and its walls: vertices
    /// beyond it are moved onto its faces, so liquid resting on a wall ends flat on the wall
    /// and the mesh stays closed. Default `None` (no clipping).
    pub domain: Option<SurfaceDomain>,
    /// Largest number of grid nodes [`reconstruct_surface`] may allocate (about 9 bytes each).
    /// Default 2²⁷ (134 M nodes, 1.2 GB), a 512³ grid.
    pub max_nodes: u64,
}

impl Default for SurfaceParams {
    fn default() -> Self {
        Self {
            spacing: 0.01,
            smoothing: 1.0,
            iso: 0.5,
            cell: 0.75,
            domain: None,
            max_nodes: 1 << 27,
        }
    }
}

impl SurfaceParams {
    /// The defaults with particle spacing `spacing` \[m\].
    pub fn for_spacing(spacing: f32) -> Self {
        Self {
            spacing,
            ..Self::default()
        }
    }

    /// Builder: the domain box `[min, max]` without walls (see [`SurfaceParams::domain`]).
    pub fn with_domain(mut self, min: Vec3, max: Vec3) -> Self {
        self.domain = Some(SurfaceDomain::new(min, max));
        self
    }

    /// Kernel scale ℓ \[m\].
    pub fn kernel_scale(&self) -> f32 {
        self.smoothing * self.spacing
    }

    /// Grid cell \[m\].
    pub fn cell_size(&self) -> f32 {
        self.cell * self.spacing
    }

    /// Kernel support radius per axis, 2ℓ \[m\].
    pub fn support(&self) -> f32 {
        2.0 * self.kernel_scale()
    }

    /// Checks every parameter; the error names the first bad one.
    pub fn validate(&self) -> Result<(), SurfaceError> {
        let bad = |name: &'static str, value: f32, reason: &'static str| {
            Err(SurfaceError::InvalidParameter {
                name,
                value: value as f64,
                reason,
            })
        };
        if !(self.spacing.is_finite() && self.spacing > 0.0) {
            return bad("spacing", self.spacing, "must be a positive length [m]");
        }
        if !(self.smoothing.is_finite() && self.smoothing > 0.0) {
            return bad("smoothing", self.smoothing, "must be positive [spacings]");
        }
        if !(self.cell.is_finite() && self.cell > 0.0) {
            return bad("cell", self.cell, "must be positive [spacings]");
        }
        if !(self.iso > 0.0 && self.iso < 1.0) {
            return bad("iso", self.iso, "must lie strictly between 0 and 1");
        }
        if self.smoothing / self.cell > MAX_SUPPORT_CELLS {
            return bad(
                "cell",
                self.cell,
                "is too small for the smoothing length: smoothing/cell must be at most 7",
            );
        }
        // Products of spacing and the factors must stay finite and non-zero.
        let scale = self.kernel_scale();
        let cell = self.cell_size();
        if !(scale.is_normal() && cell.is_normal() && (4.0 * scale).is_finite()) {
            return bad(
                "spacing",
                self.spacing,
                "times smoothing or cell leaves the range of f32",
            );
        }
        if let Some(d) = &self.domain {
            if !(d.min.is_finite() && d.max.is_finite() && d.min.cmplt(d.max).all()) {
                return Err(SurfaceError::InvalidDomain {
                    min: d.min.to_array(),
                    max: d.max.to_array(),
                });
            }
            if !(d.wall_layer.is_finite() && d.wall_layer >= 0.0) {
                return bad(
                    "domain.wall_layer",
                    d.wall_layer,
                    "must be a length ≥ 0 [m]",
                );
            }
        }
        Ok(())
    }
}

/// The box the liquid is confined to ([`SurfaceParams::domain`]).
///
/// Every vertex is clamped into `[min, max]`. Faces marked in `walls` are solid walls the
/// liquid rests against: MPM particles stop short of a wall (the wall conditions act on the
/// grid nodes next to it; in `scenes/droplet.ron` the lowest particles of the spread droplet
/// sit 6 mm above the floor with Δx = 1 cm), so the particle surface would leave a gap that
/// the simulated liquid does not have. Within `wall_layer` of a wall face, φ is raised to
/// its value at distance `wall_layer` from the face (the liquid touching the layer is
/// extended straight onto the wall); elsewhere the field is untouched.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SurfaceDomain {
    /// Lower corner \[m\].
    pub min: Vec3,
    /// Upper corner \[m\].
    pub max: Vec3,
    /// Which faces are walls, in the order x min, x max, y min, y max, z min, z max.
    pub walls: [bool; 6],
    /// Distance from a wall face within which liquid is extended onto the wall \[m\]
    /// (`treacle run --surface` uses the grid spacing Δx). 0 disables the extension.
    pub wall_layer: f32,
}

impl SurfaceDomain {
    /// The box `[min, max]` without walls: vertices are only clamped into it.
    pub fn new(min: Vec3, max: Vec3) -> Self {
        Self {
            min,
            max,
            walls: [false; 6],
            wall_layer: 0.0,
        }
    }

    /// Builder: the wall faces and the wall layer \[m\].
    pub fn with_walls(mut self, walls: [bool; 6], wall_layer: f32) -> Self {
        self.walls = walls;
        self.wall_layer = wall_layer;
        self
    }
}

/// Largest accepted ratio smoothing / cell (a particle then touches at most 29³ nodes).
const MAX_SUPPORT_CELLS: f32 = 7.0;

/// Errors of surface reconstruction and mesh output.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SurfaceError {
    /// No particles were given.
    #[error("no particles to reconstruct a surface from")]
    NoParticles,
    /// A position is NaN or infinite.
    #[error("particle {index} has a non-finite position {position:?}")]
    NonFinitePosition {
        /// Particle index.
        index: usize,
        /// Its position.
        position: [f32; 3],
    },
    /// A parameter is out of range.
    #[error("surface parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// The field of [`SurfaceParams`].
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it must satisfy.
        reason: &'static str,
    },
    /// The domain box is not finite with min < max on every axis.
    #[error("surface domain {min:?}..{max:?} must be finite with min < max on every axis")]
    InvalidDomain {
        /// Lower corner.
        min: [f32; 3],
        /// Upper corner.
        max: [f32; 3],
    },
    /// The grid around the particles would exceed [`SurfaceParams::max_nodes`].
    #[error(
        "the surface grid would have {nodes} nodes ({dims:?}), more than the limit {max}; the \
         particles spread over {extent:?} m: raise `cell` or `max_nodes`, or set `domain`"
    )]
    GridTooLarge {
        /// Nodes needed.
        nodes: u64,
        /// Nodes per axis.
        dims: [u64; 3],
        /// The limit.
        max: u64,
        /// Extent of the particles' bounding box \[m\].
        extent: [f32; 3],
    },
    /// `values` does not have one entry per position.
    #[error("{values} values for {positions} particles")]
    LengthMismatch {
        /// Number of positions.
        positions: usize,
        /// Number of values.
        values: usize,
    },
    /// A value to interpolate is NaN or infinite.
    #[error("particle {index} has a non-finite value {value}")]
    NonFiniteValue {
        /// Particle index.
        index: usize,
        /// The value.
        value: f32,
    },
    /// A mesh to write has a non-finite vertex or normal, or a triangle with an index out of
    /// range (only possible for a mesh built by hand); nothing was written.
    #[error("mesh not written to {}: {what}", path.display())]
    InvalidMesh {
        /// The file that was not written.
        path: PathBuf,
        /// What is wrong.
        what: String,
    },
    /// Writing a file failed.
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// A triangle mesh: vertices with normals, and triangles as vertex-index triples, oriented
/// counter-clockwise seen from outside (normals point out of the liquid).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceMesh {
    /// Vertex positions \[m\].
    pub vertices: Vec<Vec3>,
    /// Unit outward normal per vertex.
    pub normals: Vec<Vec3>,
    /// Triangles, counter-clockwise from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl SurfaceMesh {
    /// Enclosed volume \[m³\] by the divergence theorem, Σ (a·(b×c))/6 over triangles (in f64,
    /// relative to the first vertex). Exact for a closed mesh; for an open one it depends on
    /// that reference point.
    pub fn volume(&self) -> f64 {
        let Some(o) = self.vertices.first() else {
            return 0.0;
        };
        let o = o.as_dvec3();
        let mut six = 0.0f64;
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.vertices[i as usize].as_dvec3() - o);
            six += a.dot(b.cross(c));
        }
        six / 6.0
    }

    /// Total triangle area \[m²\].
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize].as_dvec3());
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Number of edges used by exactly one triangle: 0 for a closed mesh.
    pub fn boundary_edges(&self) -> usize {
        self.edge_counts().0
    }

    /// Number of edges used by more than two triangles: 0 for a manifold mesh.
    pub fn non_manifold_edges(&self) -> usize {
        self.edge_counts().1
    }

    /// Number of directed edges (a → b) that appear in two triangles: 0 when neighbouring
    /// triangles are consistently oriented.
    pub fn misoriented_edges(&self) -> usize {
        let mut directed: Vec<u64> = self
            .triangles
            .iter()
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, b)| ((a as u64) << 32) | b as u64)
            .collect();
        directed.sort_unstable();
        directed.windows(2).filter(|w| w[0] == w[1]).count()
    }

    /// (edges used once, edges used more than twice).
    fn edge_counts(&self) -> (usize, usize) {
        let mut edges: Vec<u64> = self
            .triangles
            .iter()
            .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
            .map(|(a, b)| ((a.min(b) as u64) << 32) | a.max(b) as u64)
            .collect();
        edges.sort_unstable();
        let (mut once, mut more) = (0, 0);
        let mut i = 0;
        while i < edges.len() {
            let mut j = i + 1;
            while j < edges.len() && edges[j] == edges[i] {
                j += 1;
            }
            match j - i {
                1 => once += 1,
                2 => {}
                _ => more += 1,
            }
            i = j;
        }
        (once, more)
    }

    /// Writes the mesh as a Wavefront OBJ file (`v`, `vn`, `f a//a b//b c//c`), atomically
    /// ([`crate::output::write_atomic_with`]). The parent directory must exist. A mesh with a
    /// non-finite coordinate or an index out of range is refused and nothing is written.
    pub fn write_obj(&self, path: &Path) -> Result<(), SurfaceError> {
        io::write_obj(self, path)
    }

    /// Writes the mesh as a binary little-endian PLY file (vertex `x y z nx ny nz` as float,
    /// face `vertex_indices` as a uchar-counted list of uint), atomically. Refuses a mesh as
    /// [`write_obj`](Self::write_obj) does.
    pub fn write_ply(&self, path: &Path) -> Result<(), SurfaceError> {
        io::write_ply(self, path, None)
    }

    /// [`write_ply`](Self::write_ply) with one per-vertex float property `name` (e.g. a
    /// temperature from [`interpolate_to_vertices`]). `name` must be a valid field name
    /// ([`crate::output::MAX_NAME_LEN`] bytes of `[A-Za-z0-9_.-]`, not `x y z nx ny nz`).
    pub fn write_ply_with(
        &self,
        path: &Path,
        name: &str,
        values: &[f32],
    ) -> Result<(), SurfaceError> {
        io::write_ply(self, path, Some((name, values)))
    }

    /// Writes the mesh in `format` ([`SurfaceFormat`]).
    pub fn write(&self, path: &Path, format: SurfaceFormat) -> Result<(), SurfaceError> {
        match format {
            SurfaceFormat::Obj => self.write_obj(path),
            SurfaceFormat::Ply => self.write_ply(path),
        }
    }
}

/// File format of surface meshes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SurfaceFormat {
    /// Wavefront OBJ (text).
    #[default]
    Obj,
    /// Binary little-endian PLY.
    Ply,
}

impl SurfaceFormat {
    /// `"obj"` or `"ply"`.
    pub fn extension(self) -> &'static str {
        match self {
            SurfaceFormat::Obj => "obj",
            SurfaceFormat::Ply => "ply",
        }
    }

    /// The surface file of output frame `frame`: `surface_00042.obj` (numbered like
    /// [`crate::output::OutputFormat::file_name`]).
    pub fn file_name(self, frame: u32) -> String {
        format!("{SURFACE_PREFIX}{frame:05}.{}", self.extension())
    }
}

/// File-name prefix of surface meshes written beside particle frames.
pub const SURFACE_PREFIX: &str = "surface_";

/// Reconstructs the liquid surface around `positions` (module docs: method, accuracy, cost).
///
/// Errors: no positions, a non-finite position (its index), a bad parameter
/// ([`SurfaceParams::validate`]), or a grid beyond [`SurfaceParams::max_nodes`]. Runs on the
/// `ComputeTaskPool` if one exists with more than one thread; the result is the same for any
/// thread count.
pub fn reconstruct_surface(
    positions: &[Vec3],
    params: &SurfaceParams,
) -> Result<SurfaceMesh, SurfaceError> {
    params.validate()?;
    check_positions(positions)?;
    let grid = field::VolumeFraction::build(positions, params)?;
    Ok(march::extract(&grid, params))
}

/// Per-vertex values interpolated from the particles' `values` (e.g. temperature or phase
/// for colouring the surface): the kernel-weighted (Shepard) mean
/// Σₚ W(v − xₚ) fₚ / Σₚ W(v − xₚ) with the kernel of the reconstruction; a vertex no particle
/// reaches (possible only after clipping to the domain) takes its nearest particle's value
/// within two kernel supports, or 0.
///
/// # Panics
///
/// If `values.len() != positions.len()`, a position or value is not finite, or `params` is
/// invalid; [`try_interpolate_to_vertices`] returns these as errors instead.
pub fn interpolate_to_vertices(
    mesh: &SurfaceMesh,
    positions: &[Vec3],
    values: &[f32],
    params: &SurfaceParams,
) -> Vec<f32> {
    try_interpolate_to_vertices(mesh, positions, values, params)
        .unwrap_or_else(|e| panic!("interpolate_to_vertices: {e}"))
}

/// [`interpolate_to_vertices`] returning bad input as an error.
pub fn try_interpolate_to_vertices(
    mesh: &SurfaceMesh,
    positions: &[Vec3],
    values: &[f32],
    params: &SurfaceParams,
) -> Result<Vec<f32>, SurfaceError> {
    params.validate()?;
    if values.len() != positions.len() {
        return Err(SurfaceError::LengthMismatch {
            positions: positions.len(),
            values: values.len(),
        });
    }
    if mesh.vertices.is_empty() {
        return Ok(Vec::new());
    }
    check_positions(positions)?;
    if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(SurfaceError::NonFiniteValue { index, value });
    }
    Ok(neighbours::interpolate(
        &mesh.vertices,
        positions,
        values,
        params,
    ))
}

fn check_positions(positions: &[Vec3]) -> Result<(), SurfaceError> {
    if positions.is_empty() {
        return Err(SurfaceError::NoParticles);
    }
    if let Some((index, p)) = positions.iter().enumerate().find(|(_, p)| !p.is_finite()) {
        return Err(SurfaceError::NonFinitePosition {
            index,
            position: p.to_array(),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests;
