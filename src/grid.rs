//! The background grid (a Resource) and its block-sparse node storage (ALGORITHM §11).
//!
//! Nodes sit at `domain_min + Δx·(i, j, k)`. The node box covers the domain plus
//! [`GRID_PAD`] nodes on every side, so a quadratic B-spline stencil of any particle inside the
//! domain (or slightly outside, between a wall and its projection) stays in bounds. Only the
//! blocks of [`BLOCK`]³ nodes that the step's particle stencils reach hold storage
//! ([`MpmGrid`]); a scene pays for the nodes its liquid touches, not for its domain.
//! A node is an array-of-structs [`GridNode`], z fastest inside a block.
use bevy_ecs::prelude::*;
use bevy_tasks::ComputeTaskPool;
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
    /// Block counts on each axis (⌈dims / BLOCK⌉).
    pub blocks: IVec3,
}

impl GridLayout {
    /// A node box covering `[min, max]` with spacing `dx` (plus padding).
    pub fn new(min: Vec3, max: Vec3, dx: Real) -> Self {
        let n = ((max - min) / dx).ceil().as_ivec3();
        let dims = n + IVec3::splat(2 * GRID_PAD + 1);
        Self {
            dx,
            inv_dx: 1.0 / dx,
            origin: min,
            lo: IVec3::splat(-GRID_PAD),
            dims,
            blocks: (dims + IVec3::splat(BLOCK - 1)) / BLOCK,
        }
    }

    /// The dense layout of the node box `[first, first + n − 1]` with this one's geometry (the
    /// neighbourhood of a particle block in the transfers; [`GridLayout::index`] addresses it).
    #[inline(always)]
    pub fn sub_box(&self, first: IVec3, n: i32) -> Self {
        Self {
            lo: first,
            dims: IVec3::splat(n),
            blocks: IVec3::ZERO,
            ..*self
        }
    }

    /// The dense layout of the node box `[first, first + dims − 1]` with this one's geometry
    /// (a box of any shape: [`GridLayout::sub_box`] for cubes).
    pub fn node_range(&self, first: IVec3, dims: IVec3) -> Self {
        Self {
            lo: first,
            dims,
            blocks: IVec3::ZERO,
            ..*self
        }
    }

    /// Key (table index) of block `b` (block coordinates), if it is inside the node box.
    #[inline(always)]
    pub fn key_of_block(&self, b: IVec3) -> Option<u32> {
        if b.min_element() < 0
            || b.x >= self.blocks.x
            || b.y >= self.blocks.y
            || b.z >= self.blocks.z
        {
            return None;
        }
        Some(((b.x * self.blocks.y + b.y) * self.blocks.z + b.z) as u32)
    }

    /// Block coordinates of block key `key`.
    #[inline(always)]
    pub fn block_of_key(&self, key: u32) -> IVec3 {
        let k = key as i32;
        let (by, bz) = (self.blocks.y, self.blocks.z);
        IVec3::new(k / (by * bz), (k / bz) % by, k % bz)
    }

    /// Block coordinates of the block holding node `c` (inside the node box).
    #[inline(always)]
    pub fn block_of_node(&self, c: IVec3) -> IVec3 {
        (c - self.lo) >> 2
    }

    /// Storage index of node `(i, j, k)` in a dense array over this node box (z fastest). The
    /// caller guarantees it is inside the box. The grid itself is block-sparse
    /// ([`MpmGrid::index`]); dense boxes are the transfers' block neighbourhoods
    /// ([`GridLayout::sub_box`]).
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

    /// Integer coordinates of dense storage index `idx` (see [`GridLayout::index`]).
    #[inline]
    pub fn node_of_index(&self, idx: usize) -> IVec3 {
        let dz = self.dims.z as usize;
        let dy = self.dims.y as usize;
        let k = idx % dz;
        let j = (idx / dz) % dy;
        let i = idx / (dz * dy);
        IVec3::new(i as i32, j as i32, k as i32) + self.lo
    }

    /// Number of nodes of the node box (a dense array over it would hold this many).
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

/// The indices of `positions` in the order of the grid block of their stencil base (ALGORITHM
/// §11; stable, so particles of one block keep their order). Spawning particles in this order
/// lays their components out in memory in the order the block-sparse transfers visit them,
/// which the hardware prefetcher follows; positions outside the node box sort by their clamped
/// block. An index order (8 B per position while sorting, no scratch) rather than a sorted
/// copy, so that spawning a large body adds little to its positions' memory.
pub fn block_order(layout: &GridLayout, positions: &[Vec3]) -> Vec<u32> {
    let (lo, hi) = layout.base_bounds();
    let key = |x: Vec3| {
        let b = layout.block_of_node(layout.base_of(x).clamp(lo, hi.max(lo)));
        layout.key_of_block(b).unwrap_or(u32::MAX)
    };
    let mut keyed: Vec<(u32, u32)> = (0u32..).zip(positions).map(|(i, &x)| (key(x), i)).collect();
    // (key, index) pairs are distinct, so the unstable sort gives the stable order.
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
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

/// The grid resource: geometry, the block table and the nodes of the allocated blocks.
///
/// Nodes are stored in blocks of [`BLOCK`]³ (ALGORITHM §11): the node box is tiled by blocks
/// (block `(0, 0, 0)` starts at node [`GridLayout::lo`]), and a block holds storage — a *slot*
/// of [`BLOCK_NODES`] consecutive nodes, z fastest — only while a particle stencil of the step
/// reaches it (or it is the periodic or mirror image of such a block). `table` maps every block
/// of the node box to its slot; slots are in ascending block key, so storage order and every
/// loop over it are independent of the thread count. A later distributed grid can hand slots
/// to processes by key range (a block-to-owner map) with the blocks a neighbour's stencils
/// reach as its halo.
#[derive(Resource, Clone, Debug)]
pub struct MpmGrid {
    /// Geometry.
    pub layout: GridLayout,
    /// Slot of every block of the node box ([`EMPTY_SLOT`] when not allocated).
    table: Vec<u32>,
    /// Block key of every slot, ascending.
    keys: Vec<u32>,
    /// Node storage: slot `s` holds nodes `s·BLOCK_NODES ..`, local (x, y, z) with z fastest.
    pub nodes: Vec<GridNode>,
    /// Nodes with m̃ᵢ ≤ this mass are inactive \[kg\] (set from the particle masses, §2.5).
    pub mass_epsilon: Real,
    /// Ghost–image node pairs of the mirror faces, valid for the allocated blocks
    /// ([`MpmGrid::fold_mirror`], [`MpmGrid::copy_mirror`] run four times a step on them).
    mirror: MirrorPairs,
    /// The nodes the particle stencils of this step reach (set by the P2G transfer; the whole
    /// node box until then). Mirror folds and copies skip the ghost layers beyond it: nothing
    /// was scattered there and no gather reads them.
    pub reach: NodeBox,
}

/// Per mirror face, the (ghost or face node, image or [`EMPTY_SLOT`] for a face node) storage
/// indices of the allocated blocks, ordered by layer (distance from the face, 0 on it), then
/// slot; rebuilt when the faces or the allocated blocks change.
#[derive(Clone, Debug, Default)]
struct MirrorPairs {
    valid: bool,
    faces: Vec<MirrorFace>,
    pairs: Vec<Vec<(u32, u32)>>,
    /// Per face, `ends[l]`: the number of pairs in layers `0..=l`.
    ends: Vec<Vec<usize>>,
}

impl MirrorPairs {
    /// The pairs of face `f` whose layer is inside `reach` (none if the face is beyond it).
    fn reached(&self, f: usize, reach: &NodeBox) -> &[(u32, u32)] {
        let face = &self.faces[f];
        let a = face.axis;
        let ends = &self.ends[f];
        if reach.is_empty() || ends.is_empty() {
            return &[];
        }
        let layers = if face.upper {
            reach.max[a] - face.node
        } else {
            face.node - reach.min[a]
        };
        if layers < 0 {
            return &[];
        }
        let n = ends[(layers as usize).min(ends.len() - 1)];
        &self.pairs[f][..n]
    }
}

/// Nodes along each axis of a block.
pub const BLOCK: i32 = 4;
/// Nodes in a block.
pub const BLOCK_NODES: usize = (BLOCK * BLOCK * BLOCK) as usize;
/// Table entry of a block without storage.
pub const EMPTY_SLOT: u32 = u32::MAX;

/// Storage offset of local node `l` (each component in `0..BLOCK`) inside its block.
#[inline(always)]
pub fn local_offset(l: IVec3) -> usize {
    ((l.x * BLOCK + l.y) * BLOCK + l.z) as usize
}

/// Local coordinates in a block of the local storage offset `o` (the inverse of
/// [`local_offset`]).
#[inline(always)]
pub fn local_coords(o: usize) -> IVec3 {
    let o = o as i32;
    IVec3::new(o / (BLOCK * BLOCK), (o / BLOCK) % BLOCK, o % BLOCK)
}

impl MpmGrid {
    /// An empty grid (no block allocated) covering `[min, max]` with spacing `dx`.
    pub fn new(min: Vec3, max: Vec3, dx: Real) -> Self {
        let layout = GridLayout::new(min, max, dx);
        let b = layout.blocks;
        Self {
            table: vec![EMPTY_SLOT; (b.x as usize) * (b.y as usize) * (b.z as usize)],
            keys: Vec::new(),
            nodes: Vec::new(),
            layout,
            mass_epsilon: 0.0,
            mirror: MirrorPairs::default(),
            reach: NodeBox {
                min: layout.lo,
                max: layout.lo + layout.dims - IVec3::ONE,
            },
        }
    }

    /// Number of allocated blocks.
    pub fn block_count(&self) -> usize {
        self.keys.len()
    }

    /// Block keys of the allocated blocks, in slot order (ascending).
    pub fn block_keys(&self) -> &[u32] {
        &self.keys
    }

    /// Bytes held by the block table (one `u32` per block of the node box).
    pub fn table_bytes(&self) -> usize {
        self.table.len() * std::mem::size_of::<u32>()
    }

    /// Block coordinates of block key `key`.
    #[inline]
    pub fn block_of_key(&self, key: u32) -> IVec3 {
        self.layout.block_of_key(key)
    }

    /// Slot of block `b` (block coordinates), if it is inside the node box and allocated.
    #[inline(always)]
    pub fn slot_of_block(&self, b: IVec3) -> Option<usize> {
        let key = self.layout.key_of_block(b)?;
        let s = self.table[key as usize];
        (s != EMPTY_SLOT).then_some(s as usize)
    }

    /// The slots of the 27 blocks around slot `s` (itself included), block offset
    /// (dx, dy, dz) ∈ {−1, 0, 1}³ at index (dx + 1)·9 + (dy + 1)·3 + (dz + 1); `None` where not
    /// allocated. With [`MpmGrid::neighbour_index`] a node's neighbours are found without a
    /// table lookup each.
    pub fn neighbour_slots(&self, s: usize) -> [Option<usize>; 27] {
        let b = self.block_of_key(self.keys[s]);
        let mut out = [None; 27];
        for (k, o) in out.iter_mut().enumerate() {
            let d = IVec3::new(k as i32 / 9, (k as i32 / 3) % 3, k as i32 % 3) - IVec3::ONE;
            *o = self.slot_of_block(b + d);
        }
        out
    }

    /// Storage index of the node at local coordinates `l + d` of a block whose neighbour slots
    /// are `slots` ([`MpmGrid::neighbour_slots`]), for `l` in `0..BLOCK` and `d` in
    /// `−BLOCK..=BLOCK` on each axis (at most one block away).
    #[inline(always)]
    pub fn neighbour_index(slots: &[Option<usize>; 27], l: IVec3, d: IVec3) -> Option<usize> {
        let ll = l + d;
        let b: IVec3 = (ll >> 2i32) + IVec3::ONE;
        let s = slots[(b.x * 9 + b.y * 3 + b.z) as usize]?;
        Some(s * BLOCK_NODES + local_offset(ll & 3))
    }

    /// Storage index of node `c`, if its block is allocated.
    #[inline(always)]
    pub fn index(&self, c: IVec3) -> Option<usize> {
        let r = c - self.layout.lo;
        if r.min_element() < 0 {
            return None;
        }
        let s = self.slot_of_block(r >> 2)?;
        Some(s * BLOCK_NODES + local_offset(r & 3))
    }

    /// Node coordinates of storage index `idx`.
    #[inline]
    pub fn node_of_index(&self, idx: usize) -> IVec3 {
        self.slot_origin(idx / BLOCK_NODES) + local_coords(idx % BLOCK_NODES)
    }

    /// Node coordinates of the first node of slot `s`.
    #[inline]
    pub fn slot_origin(&self, s: usize) -> IVec3 {
        self.layout.lo + self.block_of_key(self.keys[s]) * BLOCK
    }

    /// Makes `keys` (ascending, distinct block keys) the allocated blocks, all nodes zero.
    pub fn allocate(&mut self, keys: &[u32]) {
        debug_assert!(keys.windows(2).all(|w| w[0] < w[1]));
        if keys != self.keys.as_slice() {
            self.mirror.valid = false;
        }
        for &k in &self.keys {
            self.table[k as usize] = EMPTY_SLOT;
        }
        self.keys.clear();
        self.keys.extend_from_slice(keys);
        for (s, &k) in keys.iter().enumerate() {
            self.table[k as usize] = s as u32;
        }
        self.nodes.clear();
        self.nodes
            .resize(keys.len() * BLOCK_NODES, GridNode::default());
    }

    /// Frees every block.
    pub fn clear(&mut self) {
        self.allocate(&[]);
    }

    /// Number of distinct nodes along a periodic axis of length `len` (= len/Δx).
    pub fn periodic_count(&self, len: Real) -> i32 {
        (len * self.layout.inv_dx).round() as i32
    }

    /// Calls `f(coordinates of the row's first node, row)` for every z-row of [`BLOCK`] nodes of
    /// the allocated blocks, groups of blocks in parallel when the pool allows. The result does
    /// not depend on the thread count (rows are independent).
    pub fn for_each_row(&mut self, f: impl Fn(IVec3, &mut [GridNode]) + Sync) {
        const BLOCKS_PER_TASK: usize = 32;
        let layout = self.layout;
        let keys = &self.keys;
        let do_blocks = |first_slot: usize, nodes: &mut [GridNode]| {
            for (s, block) in nodes.chunks_mut(BLOCK_NODES).enumerate() {
                let o = layout.lo + layout.block_of_key(keys[first_slot + s]) * BLOCK;
                for (r, row) in block.chunks_mut(BLOCK as usize).enumerate() {
                    let r = r as i32;
                    f(o + IVec3::new(r / BLOCK, r % BLOCK, 0), row);
                }
            }
        };
        let chunk = BLOCKS_PER_TASK * BLOCK_NODES;
        match ComputeTaskPool::try_get()
            .filter(|p| p.thread_num() > 1 && self.nodes.len() > 2 * chunk)
        {
            Some(pool) => {
                let do_blocks = &do_blocks;
                pool.scope(|s| {
                    for (c, nodes) in self.nodes.chunks_mut(chunk).enumerate() {
                        s.spawn(async move { do_blocks(c * BLOCKS_PER_TASK, nodes) });
                    }
                });
            }
            None => do_blocks(0, &mut self.nodes),
        }
    }

    /// Visits every allocated node whose block reaches outside `[0, n)` on `axis` and whose
    /// coordinate does: `f(storage index, storage index of its periodic image)` (slot order).
    /// Ghosts whose image has no storage hold nothing (the allocation includes the images of
    /// every reached ghost, [`image_closure`]) and are skipped.
    fn for_each_ghost(&self, axis: usize, n: i32, mut f: impl FnMut(usize, usize)) {
        for s in 0..self.keys.len() {
            let o = self.slot_origin(s);
            if o[axis] >= 0 && o[axis] + BLOCK <= n {
                continue;
            }
            for l in 0..BLOCK_NODES {
                let c = self.node_of_local(o, l);
                if c[axis] >= 0 && c[axis] < n {
                    continue;
                }
                let mut img = c;
                img[axis] = c[axis].rem_euclid(n);
                if let Some(i) = self.index(img) {
                    f(s * BLOCK_NODES + l, i);
                }
            }
        }
    }

    #[inline]
    fn node_of_local(&self, origin: IVec3, l: usize) -> IVec3 {
        let l = l as i32;
        origin + IVec3::new(l / (BLOCK * BLOCK), (l / BLOCK) % BLOCK, l % BLOCK)
    }

    /// Adds ghost-node contributions onto their periodic images and zeroes the ghosts
    /// (axes in order x, y, z, so edges and corners end on the unique node).
    /// `counts[a]` is the number of distinct nodes along periodic axis `a`.
    pub fn fold_periodic(&mut self, periodic: [bool; 3], counts: [i32; 3], what: Fold) {
        let mut pairs = Vec::new();
        for a in 0..3 {
            if !periodic[a] {
                continue;
            }
            pairs.clear();
            self.for_each_ghost(a, counts[a], |g, i| pairs.push((g, i)));
            for &(g, i) in &pairs {
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
        let mut pairs = Vec::new();
        for a in (0..3).rev() {
            if !periodic[a] {
                continue;
            }
            pairs.clear();
            self.for_each_ghost(a, counts[a], |g, i| pairs.push((g, i)));
            for &(g, i) in &pairs {
                self.nodes[g] = self.nodes[i];
            }
        }
    }

    /// The periodic ghost/image pairs of `axis` (storage indices, slot order).
    pub fn periodic_pairs(&self, axis: usize, n: i32, out: &mut Vec<(usize, usize)>) {
        out.clear();
        self.for_each_ghost(axis, n, |g, i| out.push((g, i)));
    }

    /// Visits every allocated node on or beyond `face`: `f(storage index, storage index of its
    /// image or None for a node on the face)` (slot order). Nodes whose image has no storage
    /// hold nothing and are skipped.
    pub fn for_each_mirror_node(&self, face: &MirrorFace, mut f: impl FnMut(usize, Option<usize>)) {
        let a = face.axis;
        for s in 0..self.keys.len() {
            let o = self.slot_origin(s);
            // Local coordinates along the axis on or beyond the face (empty if none).
            let (first, last) = if face.upper {
                ((face.node - o[a]).max(0), BLOCK - 1)
            } else {
                (0, (face.node - o[a]).min(BLOCK - 1))
            };
            if first > last {
                continue;
            }
            let mut range = [(0, BLOCK - 1); 3];
            range[a] = (first, last);
            for x in range[0].0..=range[0].1 {
                for y in range[1].0..=range[1].1 {
                    for z in range[2].0..=range[2].1 {
                        let l = IVec3::new(x, y, z);
                        let c = o + l;
                        let g = s * BLOCK_NODES + local_offset(l);
                        if c[a] == face.node {
                            f(g, None);
                        } else {
                            let mut img = c;
                            img[a] = face.image(c[a]);
                            if let Some(i) = self.index(img) {
                                f(g, Some(i));
                            }
                        }
                    }
                }
            }
        }
    }

    /// Takes the mirror pairs of `faces` for the allocated blocks (built if stale); give them
    /// back with `self.mirror = ..` after use.
    fn take_mirror_pairs(&mut self, faces: &[MirrorFace]) -> MirrorPairs {
        let mut m = std::mem::take(&mut self.mirror);
        if !m.valid || m.faces != faces {
            m.faces.clear();
            m.faces.extend_from_slice(faces);
            m.pairs.resize_with(faces.len(), Vec::new);
            m.ends.resize_with(faces.len(), Vec::new);
            let mut layered = Vec::new();
            for ((face, pairs), ends) in faces.iter().zip(&mut m.pairs).zip(&mut m.ends) {
                layered.clear();
                self.for_each_mirror_node(face, |g, i| {
                    let layer = (self.node_of_index(g)[face.axis] - face.node).unsigned_abs();
                    layered.push((layer, g as u32, i.map_or(EMPTY_SLOT, |i| i as u32)));
                });
                // Stable: slot order within a layer.
                layered.sort_by_key(|p| p.0);
                pairs.clear();
                pairs.extend(layered.iter().map(|p| (p.1, p.2)));
                ends.clear();
                if let Some(last) = layered.last() {
                    ends.resize(last.0 as usize + 1, 0);
                    for p in &layered {
                        ends[p.0 as usize] += 1;
                    }
                    for l in 1..ends.len() {
                        ends[l] += ends[l - 1];
                    }
                }
            }
            m.valid = true;
        }
        m
    }

    /// Mirror fold (choice D18): adds the reflected contributions of the nodes beyond each face
    /// onto their images and zeroes them, and removes the normal component on the face nodes —
    /// what mirror-image particles would scatter. Faces in order (x, y, z first), so edges and
    /// corners end on the unique interior node.
    pub fn fold_mirror(&mut self, faces: &[MirrorFace], what: Fold) {
        if faces.is_empty() {
            return;
        }
        let m = self.take_mirror_pairs(faces);
        for (f, face) in faces.iter().enumerate() {
            let a = face.axis;
            let pairs = m.reached(f, &self.reach);
            for &(g, i) in pairs {
                let g = g as usize;
                if i == EMPTY_SLOT {
                    let n = &mut self.nodes[g];
                    match what {
                        Fold::Transfer => {
                            n.velocity[a] = 0.0;
                            n.acceleration[a] = 0.0;
                        }
                        Fold::Force => n.force[a] = 0.0,
                    }
                    continue;
                }
                let ghost = self.nodes[g];
                let img = &mut self.nodes[i as usize];
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
        self.mirror = m;
    }

    /// Copies the reflected fields `what` of every node's image onto its ghosts beyond each
    /// face (faces in reverse order, as [`MpmGrid::copy_periodic`]).
    pub fn copy_mirror(&mut self, faces: &[MirrorFace], what: GhostCopy) {
        if faces.is_empty() {
            return;
        }
        let m = self.take_mirror_pairs(faces);
        for (f, face) in faces.iter().enumerate().rev() {
            let a = face.axis;
            let pairs = m.reached(f, &self.reach);
            for &(g, i) in pairs {
                if i == EMPTY_SLOT {
                    continue;
                }
                let n = self.nodes[i as usize];
                let ghost = &mut self.nodes[g as usize];
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
        self.mirror = m;
    }
}

/// Adds to `keys` (block keys, any order) the blocks holding the periodic and mirror images of
/// the ghost nodes of every block in it, repeatedly (images of images at edges and corners),
/// then sorts and deduplicates: the folds and ghost copies then find every image allocated.
pub fn image_closure(
    layout: &GridLayout,
    keys: &mut Vec<u32>,
    periodic: [bool; 3],
    counts: [i32; 3],
    faces: &[MirrorFace],
) {
    keys.sort_unstable();
    keys.dedup();
    if !periodic.iter().any(|p| *p) && faces.is_empty() {
        return;
    }
    let hi = layout.lo + layout.dims - IVec3::ONE;
    // Image node range along `a` of the ghost part of [o, o + BLOCK - 1] → blocks to add.
    let mut added = Vec::new();
    for _round in 0..4 {
        added.clear();
        for &k in keys.iter() {
            let b = layout.block_of_key(k);
            let o = layout.lo + b * BLOCK;
            let mut push_range = |a: usize, c0: i32, c1: i32| {
                let (c0, c1) = (c0.max(layout.lo[a]), c1.min(hi[a]));
                if c0 > c1 {
                    return;
                }
                for bc in ((c0 - layout.lo[a]) >> 2)..=((c1 - layout.lo[a]) >> 2) {
                    let mut nb = b;
                    nb[a] = bc;
                    if let Some(nk) = layout.key_of_block(nb) {
                        added.push(nk);
                    }
                }
            };
            for a in 0..3 {
                if !periodic[a] {
                    continue;
                }
                let n = counts[a];
                for c in o[a]..o[a] + BLOCK {
                    if c < 0 || c >= n {
                        let img = c.rem_euclid(n);
                        push_range(a, img, img);
                    }
                }
            }
            for f in faces {
                let a = f.axis;
                let (c0, c1) = (o[a], o[a] + BLOCK - 1);
                let (g0, g1) = if f.upper {
                    (c0.max(f.node + 1), c1)
                } else {
                    (c0, c1.min(f.node - 1))
                };
                if g0 <= g1 {
                    push_range(a, f.image(g1), f.image(g0));
                }
            }
        }
        let before = keys.len();
        keys.extend_from_slice(&added);
        keys.sort_unstable();
        keys.dedup();
        if keys.len() == before {
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `block_order` sorts by block key and keeps the given order within a block (the stable
    /// order the spawn relies on), for positions given out of order.
    #[test]
    fn block_order_is_by_block_then_by_index() {
        let layout = GridLayout::new(Vec3::ZERO, Vec3::splat(4.0), 0.25);
        // Blocks are 4 nodes (1 m) wide; stencil bases ⌊x/Δx − ½⌋.
        let positions = [
            Vec3::new(2.6, 0.6, 0.6), // block (2, 0, 0)
            Vec3::new(0.6, 0.6, 0.6), // block (0, 0, 0)
            Vec3::new(2.7, 0.5, 0.5), // block (2, 0, 0)
            Vec3::new(0.6, 0.6, 1.6), // block (0, 0, 1)
            Vec3::new(0.5, 0.7, 0.5), // block (0, 0, 0)
        ];
        let key = |x: Vec3| {
            layout
                .key_of_block(layout.block_of_node(layout.base_of(x)))
                .unwrap()
        };
        assert!(key(positions[1]) < key(positions[3]) && key(positions[3]) < key(positions[0]));
        assert_eq!(block_order(&layout, &positions), vec![1, 4, 3, 0, 2]);
    }

    /// A grid over `[0, 2]³` at Δx = 0.25 (8 cells, nodes 0..=8 inside) with every block of the
    /// node box allocated.
    fn full_grid() -> MpmGrid {
        let mut g = MpmGrid::new(Vec3::ZERO, Vec3::splat(2.0), 0.25);
        let b = g.layout.blocks;
        let keys: Vec<u32> = (0..(b.x * b.y * b.z) as u32).collect();
        g.allocate(&keys);
        g
    }

    /// Folding and copying only the ghost layers inside the stencils' reach gives, on every
    /// node of that reach, the same bits as handling every allocated ghost layer.
    #[test]
    fn mirror_layers_beyond_the_reach_change_nothing_inside_it() {
        let faces = [
            MirrorFace {
                axis: 0,
                node: 0,
                upper: false,
            },
            MirrorFace {
                axis: 0,
                node: 8,
                upper: true,
            },
            MirrorFace {
                axis: 1,
                node: 0,
                upper: false,
            },
            MirrorFace {
                axis: 2,
                node: 8,
                upper: true,
            },
        ];
        // Stencils reaching one ghost layer below x and y, two above x, none above z.
        let reach = NodeBox {
            min: IVec3::new(-1, -1, 0),
            max: IVec3::new(10, 8, 6),
        };
        let mut full = full_grid();
        let mut state = 0x2545_f491_u32;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state % 1000) as f32 / 1000.0 + 0.001
        };
        for idx in 0..full.nodes.len() {
            let c = full.node_of_index(idx);
            if c.cmpge(reach.min).all() && c.cmple(reach.max).all() {
                let n = &mut full.nodes[idx];
                n.mass = next();
                n.velocity = Vec3A::new(next(), -next(), next());
                n.acceleration = Vec3A::new(-next(), next(), next());
                n.force = Vec3A::new(next(), next(), -next());
            }
        }
        let mut limited = full.clone();
        limited.reach = reach;
        for g in [&mut full, &mut limited] {
            g.fold_mirror(&faces, Fold::Transfer);
            g.fold_mirror(&faces, Fold::Force);
            g.copy_mirror(&faces, GhostCopy::Transfer);
        }
        let mut compared = 0;
        for idx in 0..full.nodes.len() {
            let c = full.node_of_index(idx);
            if c.cmpge(reach.min).all() && c.cmple(reach.max).all() {
                let (a, b) = (&full.nodes[idx], &limited.nodes[idx]);
                assert_eq!(a.mass.to_bits(), b.mass.to_bits(), "mass at {c}");
                assert_eq!(a.velocity, b.velocity, "velocity at {c}");
                assert_eq!(a.acceleration, b.acceleration, "acceleration at {c}");
                assert_eq!(a.force, b.force, "force at {c}");
                compared += 1;
            }
        }
        assert_eq!(compared, 12 * 10 * 7);
        // The limited fold skipped allocated ghost layers (x ≤ −2, y ≤ −2, z ≥ 9).
        assert!(
            limited
                .mirror
                .pairs
                .iter()
                .zip(0..)
                .any(|(p, f)| { limited.mirror.reached(f, &reach).len() < p.len() })
        );
    }
}
