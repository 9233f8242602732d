//! The background grid (a Resource) and its node storage.
//!
//! Nodes sit at `domain_min + Δx·(i, j, k)`. The node box covers the domain plus
//! [`GRID_PAD`] nodes on every side, so a quadratic B-spline stencil of any particle inside the
//! domain (or slightly outside, between a wall and its projection) stays in bounds.
//! Storage is one array of [`GridNode`] (array of structs: a particle's 3×3×3 stencil touches
//! 9 runs of 3 consecutive nodes), z fastest.
use bevy_ecs::prelude::*;
use glam::{IVec3, Vec3A};

use crate::math::{Real, Vec3};

/// Nodes added beyond the domain on every side.
pub const GRID_PAD: i32 = 3;

/// State of one grid node during a step (ALGORITHM §2.1 "Grid"). Transient: rebuilt each step.
///
/// Vectors are 16-byte `Vec3A` so the 27-node loops of the transfer kernels run as SSE
/// instructions (one instruction per vector operation instead of three).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C)]
pub struct GridNode {
    /// vᵢⁿ \[m/s\] (momentum during P2G, velocity after normalisation).
    pub velocity: Vec3A,
    /// aᵢⁿ \[m/s²\] (m·a during P2G).
    pub acceleration: Vec3A,
    /// f̃ᵢ \[N\] (internal force from the stress scatter).
    pub force: Vec3A,
    /// vᵢⁿ⁺¹ \[m/s\].
    pub new_velocity: Vec3A,
    /// aᵢⁿ⁺¹ \[m/s²\].
    pub new_acceleration: Vec3A,
    /// m̃ᵢ \[kg\].
    pub mass: Real,
}

/// Geometry of the node box (cheap to copy into parallel tasks).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridLayout {
    /// Δx \[m\].
    pub dx: Real,
    /// 1/Δx \[1/m\].
    pub inv_dx: Real,
    /// World position of node (0, 0, 0) (the domain's lower corner) \[m\].
    pub origin: Vec3,
    /// Lowest node index on each axis (−GRID_PAD).
    pub lo: IVec3,
    /// Node counts on each axis (including padding).
    pub dims: IVec3,
}

impl GridLayout {
    /// A node box covering `[min, max]` with spacing `dx` (plus padding).
    pub fn new(min: Vec3, max: Vec3, dx: Real) -> Self {
        let n = ((max - min) / dx).ceil().as_ivec3();
        Self {
            dx,
            inv_dx: 1.0 / dx,
            origin: min,
            lo: IVec3::splat(-GRID_PAD),
            dims: n + IVec3::splat(2 * GRID_PAD + 1),
        }
    }

    /// Storage index of node `(i, j, k)`. The caller guarantees it is inside the node box.
    #[inline(always)]
    pub fn index(&self, node: IVec3) -> usize {
        let r = node - self.lo;
        ((r.x as usize) * (self.dims.y as usize) + r.y as usize) * (self.dims.z as usize)
            + r.z as usize
    }

    /// World position of node `(i, j, k)`.
    #[inline(always)]
    pub fn node_position(&self, node: IVec3) -> Vec3 {
        self.origin + node.as_vec3() * self.dx
    }

    /// Integer coordinates of storage index `idx`.
    #[inline]
    pub fn node_of_index(&self, idx: usize) -> IVec3 {
        let dz = self.dims.z as usize;
        let dy = self.dims.y as usize;
        let k = idx % dz;
        let j = (idx / dz) % dy;
        let i = idx / (dz * dy);
        IVec3::new(i as i32, j as i32, k as i32) + self.lo
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        (self.dims.x as usize) * (self.dims.y as usize) * (self.dims.z as usize)
    }

    /// Lowest and highest valid stencil base (so that base..base+2 is in bounds).
    #[inline(always)]
    pub fn base_bounds(&self) -> (IVec3, IVec3) {
        (self.lo, self.lo + self.dims - IVec3::splat(3))
    }

    /// Stencil base node of world position `x`, unclamped: ⌊(x − origin)/Δx − ½⌋.
    #[inline(always)]
    pub fn base_of(&self, x: Vec3) -> IVec3 {
        let r = (x - self.origin) * self.inv_dx - Vec3::splat(0.5);
        use crate::math::fast_floor;
        IVec3::new(fast_floor(r.x), fast_floor(r.y), fast_floor(r.z))
    }
}

/// An axis-aligned box of nodes `[min, max]` (inclusive); empty when any max < min.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NodeBox {
    /// Lowest node.
    pub min: IVec3,
    /// Highest node.
    pub max: IVec3,
}

impl Default for NodeBox {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl NodeBox {
    /// The empty box.
    pub const EMPTY: NodeBox = NodeBox {
        min: IVec3::MAX,
        max: IVec3::MIN,
    };

    /// Whether the box holds no node.
    pub fn is_empty(&self) -> bool {
        self.max.x < self.min.x || self.max.y < self.min.y || self.max.z < self.min.z
    }

    /// Calls `f(storage index of the first node of the row, row length)` for each z-row.
    pub fn for_each_row(&self, layout: &GridLayout, mut f: impl FnMut(usize, usize)) {
        if self.is_empty() {
            return;
        }
        let len = (self.max.z - self.min.z + 1) as usize;
        for i in self.min.x..=self.max.x {
            for j in self.min.y..=self.max.y {
                f(layout.index(IVec3::new(i, j, self.min.z)), len);
            }
        }
    }
}

/// Which node fields a periodic fold adds onto the images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fold {
    /// Mass, momentum and m·a (after the P2G scatter).
    Transfer,
    /// Internal force (after the force scatter).
    Force,
}

/// Which node fields a mirror copy writes onto the ghosts ([`MpmGrid::copy_mirror`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GhostCopy {
    /// m̃ᵢ, vᵢⁿ, aᵢⁿ (after the P2G normalisation).
    Transfer,
    /// vᵢⁿ⁺¹, aᵢⁿ⁺¹ (after the grid update; the transferred state is left as it is).
    Update,
}

/// A domain face on which the node fields are mirrored: a free-slip wall that lies on a node
/// plane (ALGORITHM §2.11, choice D18). Nodes beyond it are ghosts of their mirror images.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MirrorFace {
    /// Normal axis (0, 1, 2).
    pub axis: usize,
    /// Node coordinate of the face along `axis`.
    pub node: i32,
    /// Whether it is the max face (ghosts above `node`) or the min face (ghosts below).
    pub upper: bool,
}

impl MirrorFace {
    /// Mirror image of node coordinate `c` along the face's axis.
    #[inline]
    pub fn image(&self, c: i32) -> i32 {
        2 * self.node - c
    }

    /// Whether node coordinate `c` (along the face's axis) lies strictly beyond the face.
    #[inline]
    pub fn beyond(&self, c: i32) -> bool {
        if self.upper {
            c > self.node
        } else {
            c < self.node
        }
    }
}

/// `v` with its component along `axis` negated (the reflection of a mirror face).
#[inline]
pub fn reflect(mut v: Vec3A, axis: usize) -> Vec3A {
    v[axis] = -v[axis];
    v
}

/// The grid resource: layout, nodes, and the box of nodes touched by the current step.
#[derive(Resource, Clone, Debug)]
pub struct MpmGrid {
    /// Geometry.
    pub layout: GridLayout,
    /// Node storage (z fastest).
    pub nodes: Vec<GridNode>,
    /// Nodes that may be non-zero (touched by the last scatter); everything outside is zero.
    pub active: NodeBox,
    /// Nodes with m̃ᵢ ≤ this mass are inactive \[kg\] (set from the particle masses, §2.5).
    pub mass_epsilon: Real,
}

impl MpmGrid {
    /// A zeroed grid covering `[min, max]` with spacing `dx`.
    pub fn new(min: Vec3, max: Vec3, dx: Real) -> Self {
        let layout = GridLayout::new(min, max, dx);
        Self {
            nodes: vec![GridNode::default(); layout.node_count()],
            layout,
            active: NodeBox::EMPTY,
            mass_epsilon: 0.0,
        }
    }

    /// Number of distinct nodes along a periodic axis of length `len` (= len/Δx).
    pub fn periodic_count(&self, len: Real) -> i32 {
        (len * self.layout.inv_dx).round() as i32
    }

    /// Extends the active box to the whole node range along periodic axes.
    pub fn widen_periodic(&mut self, periodic: [bool; 3]) {
        if self.active.is_empty() {
            return;
        }
        let (lo, hi) = (
            self.layout.lo,
            self.layout.lo + self.layout.dims - IVec3::ONE,
        );
        for a in 0..3 {
            if periodic[a] {
                self.active.min[a] = lo[a];
                self.active.max[a] = hi[a];
            }
        }
    }

    /// Visits every node of the active box whose coordinate on `axis` is a ghost (outside
    /// `[0, n)`), with its image's storage index.
    fn for_each_ghost(&self, axis: usize, n: i32, mut f: impl FnMut(usize, usize)) {
        let b = self.active;
        if b.is_empty() {
            return;
        }
        for i in b.min.x..=b.max.x {
            for j in b.min.y..=b.max.y {
                for k in b.min.z..=b.max.z {
                    let c = IVec3::new(i, j, k);
                    if c[axis] >= 0 && c[axis] < n {
                        continue;
                    }
                    let mut img = c;
                    img[axis] = c[axis].rem_euclid(n);
                    f(self.layout.index(c), self.layout.index(img));
                }
            }
        }
    }

    /// Adds ghost-node contributions onto their periodic images and zeroes the ghosts
    /// (axes in order x, y, z, so edges and corners end on the unique node).
    /// `counts[a]` is the number of distinct nodes along periodic axis `a`.
    pub fn fold_periodic(&mut self, periodic: [bool; 3], counts: [i32; 3], what: Fold) {
        for a in 0..3 {
            if !periodic[a] {
                continue;
            }
            let mut pairs = Vec::new();
            self.for_each_ghost(a, counts[a], |g, i| pairs.push((g, i)));
            for (g, i) in pairs {
                let ghost = self.nodes[g];
                let img = &mut self.nodes[i];
                match what {
                    Fold::Transfer => {
                        img.mass += ghost.mass;
                        img.velocity += ghost.velocity;
                        img.acceleration += ghost.acceleration;
                        let gn = &mut self.nodes[g];
                        gn.mass = 0.0;
                        gn.velocity = Vec3A::ZERO;
                        gn.acceleration = Vec3A::ZERO;
                    }
                    Fold::Force => {
                        img.force += ghost.force;
                        self.nodes[g].force = Vec3A::ZERO;
                    }
                }
            }
        }
    }

    /// Copies every node's image onto its ghosts (axes in order z, y, x — the reverse of the
    /// fold — so ghosts of ghosts are filled from filled ghosts).
    pub fn copy_periodic(&mut self, periodic: [bool; 3], counts: [i32; 3]) {
        for a in (0..3).rev() {
            if !periodic[a] {
                continue;
            }
            let mut pairs = Vec::new();
            self.for_each_ghost(a, counts[a], |g, i| pairs.push((g, i)));
            for (g, i) in pairs {
                self.nodes[g] = self.nodes[i];
            }
        }
    }

    /// Extends the active box by the mirror images of its nodes beyond `faces` (the fold adds
    /// onto them). Along a face's axis only.
    pub fn widen_mirror(&mut self, faces: &[MirrorFace]) {
        if self.active.is_empty() {
            return;
        }
        let (lo, hi) = (
            self.layout.lo,
            self.layout.lo + self.layout.dims - IVec3::ONE,
        );
        for f in faces {
            let a = f.axis;
            if f.upper {
                if self.active.max[a] > f.node {
                    self.active.min[a] = self.active.min[a].min(f.image(self.active.max[a]));
                }
            } else if self.active.min[a] < f.node {
                self.active.max[a] = self.active.max[a].max(f.image(self.active.min[a]));
            }
            self.active.min[a] = self.active.min[a].max(lo[a]);
            self.active.max[a] = self.active.max[a].min(hi[a]);
        }
    }

    /// Visits every node of the active box on or beyond `face`: `f(storage index, storage index
    /// of its image or None for a node on the face)`.
    pub fn for_each_mirror_node(&self, face: &MirrorFace, mut f: impl FnMut(usize, Option<usize>)) {
        let a = face.axis;
        // Only the slab of the active box on or beyond the face.
        let mut b = self.active;
        if face.upper {
            b.min[a] = b.min[a].max(face.node);
        } else {
            b.max[a] = b.max[a].min(face.node);
        }
        if b.is_empty() {
            return;
        }
        let (hi_box, lo_box) = (
            self.layout.lo + self.layout.dims - IVec3::ONE,
            self.layout.lo,
        );
        for i in b.min.x..=b.max.x {
            for j in b.min.y..=b.max.y {
                for k in b.min.z..=b.max.z {
                    let c = IVec3::new(i, j, k);
                    if c[a] == face.node {
                        f(self.layout.index(c), None);
                    } else if face.beyond(c[a]) {
                        let mut img = c;
                        img[a] = face.image(c[a]);
                        if img[a] < lo_box[a] || img[a] > hi_box[a] {
                            continue;
                        }
                        f(self.layout.index(c), Some(self.layout.index(img)));
                    }
                }
            }
        }
    }

    /// Mirror fold (choice D18): adds the reflected contributions of the nodes beyond each face
    /// onto their images and zeroes them, and removes the normal component on the face nodes —
    /// what mirror-image particles would scatter. Faces in order (x, y, z first), so edges and
    /// corners end on the unique interior node.
    pub fn fold_mirror(&mut self, faces: &[MirrorFace], what: Fold) {
        for face in faces {
            let a = face.axis;
            let mut pairs = Vec::new();
            self.for_each_mirror_node(face, |g, i| pairs.push((g, i)));
            for (g, i) in pairs {
                let Some(i) = i else {
                    let n = &mut self.nodes[g];
                    match what {
                        Fold::Transfer => {
                            n.velocity[a] = 0.0;
                            n.acceleration[a] = 0.0;
                        }
                        Fold::Force => n.force[a] = 0.0,
                    }
                    continue;
                };
                let ghost = self.nodes[g];
                let img = &mut self.nodes[i];
                match what {
                    Fold::Transfer => {
                        img.mass += ghost.mass;
                        img.velocity += reflect(ghost.velocity, a);
                        img.acceleration += reflect(ghost.acceleration, a);
                        let gn = &mut self.nodes[g];
                        gn.mass = 0.0;
                        gn.velocity = Vec3A::ZERO;
                        gn.acceleration = Vec3A::ZERO;
                    }
                    Fold::Force => {
                        img.force += reflect(ghost.force, a);
                        self.nodes[g].force = Vec3A::ZERO;
                    }
                }
            }
        }
    }

    /// Copies the reflected fields `what` of every node's image onto its ghosts beyond each
    /// face (faces in reverse order, as [`MpmGrid::copy_periodic`]).
    pub fn copy_mirror(&mut self, faces: &[MirrorFace], what: GhostCopy) {
        for face in faces.iter().rev() {
            let a = face.axis;
            let mut pairs = Vec::new();
            self.for_each_mirror_node(face, |g, i| pairs.push((g, i)));
            for (g, i) in pairs {
                let Some(i) = i else { continue };
                let n = self.nodes[i];
                let ghost = &mut self.nodes[g];
                match what {
                    GhostCopy::Transfer => {
                        ghost.mass = n.mass;
                        ghost.velocity = reflect(n.velocity, a);
                        ghost.acceleration = reflect(n.acceleration, a);
                    }
                    GhostCopy::Update => {
                        ghost.new_velocity = reflect(n.new_velocity, a);
                        ghost.new_acceleration = reflect(n.new_acceleration, a);
                    }
                }
            }
        }
    }

    /// Zeroes the active box (everything else is already zero) and empties it.
    pub fn clear_active(&mut self) {
        let nodes = &mut self.nodes;
        self.active.for_each_row(&self.layout, |start, len| {
            nodes[start..start + len].fill(GridNode::default());
        });
        self.active = NodeBox::EMPTY;
    }
}
