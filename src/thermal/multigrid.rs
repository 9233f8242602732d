//! Assembly-free multigrid V-cycle for the heat system (b I − β L_h) x = r on the MPM node
//! lattice (ALGORITHM §3.3, §3.5), used as the preconditioner of conjugate gradients
//! ([`crate::krylov::conjugate_gradient`]) or as a stationary solver ([`Multigrid::solve`]).
//!
//! # Lattice and operator (§3.3)
//!
//! [`LatticeOperator`] stores one class per node ([`NodeClass`]: Interior, Dirichlet,
//! Exterior, and Ghost in a distributed solve) on a block-sparse lattice ([`BlockLattice`]): blocks of 4³ nodes, allocated
//! only where the caller marks them (the heated particles' stencils, widened by one node),
//! found through a block table, plus one all-Exterior dummy block that every unallocated node
//! maps to (so neighbour lookups need no bounds checks). A face neighbour inside a block is a
//! fixed storage step away, across a block face it is in the block's neighbouring slot (a
//! table of six slots per block). The unknowns live on Interior nodes; every vector
//! handed to the operator or the preconditioner must vanish elsewhere (the solvers here keep
//! it so):
//!
//! (A x)ᵢ = b xᵢ + β/h² [nᵢ xᵢ − Σ_{j∈𝒩(i)∩I} xⱼ],  nᵢ = |𝒩(i) ∩ (I ∪ 𝒟)|,
//!
//! i.e. Dirichlet neighbours count in the diagonal (their values enter the right-hand side
//! only), Exterior neighbours are omitted (zero flux). A is symmetric positive definite on the
//! Interior nodes for b > 0, β ≥ 0.
//!
//! # Hierarchy (§3.5)
//!
//! Nodes are treated as the cells of a cell-centred grid: level ℓ+1 cell I has the children
//! 2I + e, e ∈ {0,1}³, and spacing h_{ℓ+1} = 2h_ℓ. A coarse cell is Dirichlet if any child
//! is, else Interior if any child is, else Exterior. Coarse operators are re-discretised
//! with the same b and β. A level's blocks are the parents (block key ÷ 2) of the finer
//! level's blocks that hold a node other than Exterior, so every level is as sparse as the
//! region it covers. Coarsening stops when a level has at most
//! [`MultigridParams::coarsest_cells`] Interior cells.
//!
//! * Prolongation P: trilinear, 1-D weights ¾ (parent) and ¼ (the parent's neighbour on the
//!   child's side).
//! * Restriction R = 2⁻ᵈ Pᵀ (1-D stencil ⅛[1, 3, 3, 1]); computed as the exact transpose of
//!   the prolongation loop. (Xue's code uses R = Pᵀ, which over-scales the coarse correction by
//!   2ᵈ — §3.5 source disagreement.)
//! * Smoother: damped Jacobi, ω = ⅔ by default, with the exact diagonal b + β nᵢ/h². One
//!   smoothing call is `boundary_sweeps` sweeps over the boundary band (Interior cells within
//!   `boundary_band` steps of a non-Interior cell), `pre_smooth` sweeps over all Interior
//!   cells, and again `boundary_sweeps` band sweeps — a palindrome, so pre- and
//!   post-smoothing (with `post_smooth == pre_smooth`) make the V-cycle symmetric.
//! * Bottom: a fixed number of Jacobi sweeps from zero (a fixed linear symmetric operator; an
//!   inner iterative solve to a tolerance would make the preconditioner non-linear).
//!
//! With a zero initial guess on every level, the V-cycle is a fixed linear, symmetric and
//! positive definite map r ↦ z (damped Jacobi with ω ≤ 1 is convergent in the A-norm because
//! the eigenvalues of D⁻¹A lie in (0, 2)), which is what preconditioned CG needs.
//!
//! # Memory and determinism
//!
//! [`Multigrid`] keeps every level's operator and vectors and reuses them across
//! [`Multigrid::setup`] calls: once sized, no allocation. Memory is proportional to the
//! allocated blocks (plus 4 bytes per block of the table's box), not to a bounding box. All
//! loops are serial in storage order (blocks in ascending key), so results are bit-identical
//! for any thread count.
use thiserror::Error;

use crate::krylov::{JacobiPreconditioner, LinearOperator, Preconditioner, ResidualNorm};

/// Class of a lattice node in the heat solve (ALGORITHM §3.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum NodeClass {
    /// No material (air): omitted from the stencil, zero flux. Default.
    #[default]
    Exterior = 0,
    /// An unknown: m̃ᵢ > m_ε and not inside a prescribed-temperature object.
    Interior = 1,
    /// Inside a prescribed-temperature object: T = T_D, Ṫ = 0, ΔṪ = 0.
    Dirichlet = 2,
    /// An unknown another rank owns (a distributed solve, ALGORITHM §12): a neighbour of this
    /// rank's Interior nodes like an Interior one, not an unknown here; its values are the
    /// owner's, copied in before every use (the caller's halo exchange). The multigrid
    /// preconditioner coarsens it like a Dirichlet node (zero there: block Jacobi over ranks).
    Ghost = 3,
}

/// Cells per block edge of a [`BlockLattice`].
pub const BLOCK_EDGE: i32 = 4;
/// Cells per block of a [`BlockLattice`] (4³, z fastest).
pub const BLOCK_CELLS: usize = 64;

/// Block-sparse cell storage of one lattice level (module docs, "Lattice and operator").
///
/// Cells have integer coordinates c ≥ 0; the block of c is c >> 2 (4³ cells). A *table* over
/// the box of the marked blocks, widened by one block on every side, maps a block to its
/// *slot* (0 = not allocated); slot s holds the cells s·64 … s·64 + 63 of every vector, in the
/// order x-major, z fastest. Slot 0 is a *dummy* block that every unallocated cell maps to: its
/// cells are Exterior and every vector holds zeros there, so a neighbour lookup never fails and
/// needs no branch. Slots are numbered in ascending block key (x-major), so the storage order
/// follows from the marked blocks alone.
#[derive(Clone, Debug, Default)]
pub struct BlockLattice {
    table_lo: [i32; 3],
    table_dims: [usize; 3],
    table: Vec<u32>,
    blocks: Vec<[i32; 3]>,
}

impl BlockLattice {
    /// Starts a lattice whose cells will lie in `lo ..= hi` (per axis, ≥ 0): clears the table
    /// over their blocks plus one padding block per side. Mark blocks, then [`Self::finish`].
    pub fn begin(&mut self, lo: [i32; 3], hi: [i32; 3]) {
        let blo = lo.map(|v| v.max(0) / BLOCK_EDGE - 1);
        let bhi = hi.map(|v| v.max(0) / BLOCK_EDGE + 1);
        self.table_lo = blo;
        self.table_dims = [0, 1, 2].map(|a| (bhi[a] - blo[a] + 1) as usize);
        self.table.clear();
        self.table
            .resize(self.table_dims.iter().product::<usize>(), 0);
        self.blocks.clear();
    }

    #[inline(always)]
    fn table_index(&self, b: [i32; 3]) -> Option<usize> {
        let mut t = 0usize;
        for ((&v, &lo), &dim) in b.iter().zip(&self.table_lo).zip(&self.table_dims) {
            let o = v - lo;
            if o < 0 || o as usize >= dim {
                return None;
            }
            t = t * dim + o as usize;
        }
        Some(t)
    }

    /// Marks the blocks holding the cells `lo ..= hi` (inside the range given to
    /// [`Self::begin`]).
    pub fn mark_cells(&mut self, lo: [i32; 3], hi: [i32; 3]) {
        for bx in lo[0] >> 2..=hi[0] >> 2 {
            for by in lo[1] >> 2..=hi[1] >> 2 {
                for bz in lo[2] >> 2..=hi[2] >> 2 {
                    self.mark_block([bx, by, bz]);
                }
            }
        }
    }

    /// Marks block `b` (inside the range given to [`Self::begin`]).
    #[inline]
    pub fn mark_block(&mut self, b: [i32; 3]) {
        let t = self
            .table_index(b)
            .expect("a marked block lies inside the lattice's range");
        self.table[t] = 1;
    }

    /// Numbers the marked blocks' slots (1, 2, … in ascending block key; slot 0 is the dummy).
    pub fn finish(&mut self) {
        self.blocks.clear();
        self.blocks.push([i32::MIN; 3]);
        let [_, dy, dz] = self.table_dims;
        for (t, slot) in self.table.iter_mut().enumerate() {
            if *slot != 0 {
                *slot = self.blocks.len() as u32;
                let b = [
                    (t / (dy * dz)) as i32,
                    ((t / dz) % dy) as i32,
                    (t % dz) as i32,
                ];
                self.blocks.push([0, 1, 2].map(|a| b[a] + self.table_lo[a]));
            }
        }
    }

    /// Allocated blocks (without the dummy).
    pub fn blocks(&self) -> usize {
        self.blocks.len().saturating_sub(1)
    }

    /// Block coordinates of slot `s` (1 ≤ s ≤ [`Self::blocks`]).
    #[inline]
    pub fn block(&self, s: usize) -> [i32; 3] {
        self.blocks[s]
    }

    /// Length of every vector on this lattice: the dummy block and the allocated ones, 64
    /// cells each.
    pub fn len(&self) -> usize {
        self.blocks.len() * BLOCK_CELLS
    }

    /// Whether the lattice has no storage (before [`Self::finish`]).
    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    #[inline(always)]
    fn local(c: [i32; 3]) -> usize {
        (((c[0] & 3) << 4) | ((c[1] & 3) << 2) | (c[2] & 3)) as usize
    }

    /// Storage index of cell `c` (a cell of the dummy block when `c`'s block is not
    /// allocated).
    #[inline(always)]
    pub fn index(&self, c: [i32; 3]) -> usize {
        let slot = self
            .table_index(c.map(|v| v >> 2))
            .map_or(0, |t| self.table[t] as usize);
        slot * BLOCK_CELLS + Self::local(c)
    }

    /// Coordinates of storage index `idx` (`None` in the dummy block).
    #[inline]
    pub fn coords(&self, idx: usize) -> Option<[i32; 3]> {
        let slot = idx / BLOCK_CELLS;
        if slot == 0 || slot >= self.blocks.len() {
            return None;
        }
        let l = (idx % BLOCK_CELLS) as i32;
        let b = self.blocks[slot];
        Some([
            b[0] * BLOCK_EDGE + (l >> 4),
            b[1] * BLOCK_EDGE + ((l >> 2) & 3),
            b[2] * BLOCK_EDGE + (l & 3),
        ])
    }

    /// Storage indices of the 3×3×3 cells `c0 + (i, j, k)`, i, j, k ∈ {0, 1, 2}, at
    /// `(i·3 + j)·3 + k` (a transfer stencil; cells of unallocated blocks give dummy indices).
    /// Three cells span at most two blocks per axis, so this looks up at most 8 table entries.
    #[inline(always)]
    pub fn stencil_indices(&self, c0: [i32; 3]) -> [u32; 27] {
        let strides = [
            self.table_dims[1] * self.table_dims[2],
            self.table_dims[2],
            1,
        ];
        // Per axis: the table offsets (times the stride) of the first cell's block and of the
        // next block (`None` outside the table), which of the two each cell is in, and the
        // cells' local bits.
        let mut first = [0usize; 3];
        let mut next = [0usize; 3];
        let mut ok = [[true; 2]; 3];
        let mut which = [[0usize; 3]; 3];
        let mut local = [[0u32; 3]; 3];
        for a in 0..3 {
            let b0 = (c0[a] >> 2) - self.table_lo[a];
            let inside = |o: i32| o >= 0 && (o as usize) < self.table_dims[a];
            ok[a] = [inside(b0), inside(b0 + 1)];
            first[a] = b0.max(0) as usize * strides[a];
            next[a] = (b0 + 1).max(0) as usize * strides[a];
            for t in 0..3 {
                let v = c0[a] + t as i32;
                which[a][t] = ((v >> 2) - (c0[a] >> 2)) as usize;
                local[a][t] = ((v & 3) as u32) << (4 - 2 * a as u32);
            }
        }
        // Slots of the (up to) 8 blocks, 0 (the dummy) outside the table.
        let mut slot = [[[0u32; 2]; 2]; 2];
        for (x, plane) in slot.iter_mut().enumerate() {
            for (y, row) in plane.iter_mut().enumerate() {
                for (z, s) in row.iter_mut().enumerate() {
                    if ok[0][x] && ok[1][y] && ok[2][z] {
                        let t = [first, next];
                        *s = self.table[t[x][0] + t[y][1] + t[z][2]];
                    }
                }
            }
        }
        let mut out = [0u32; 27];
        for i in 0..3 {
            for j in 0..3 {
                let lxy = local[0][i] + local[1][j];
                let row = &slot[which[0][i]][which[1][j]];
                for k in 0..3 {
                    out[(i * 3 + j) * 3 + k] =
                        row[which[2][k]] * BLOCK_CELLS as u32 + lxy + local[2][k];
                }
            }
        }
        out
    }
}

/// The matrix-free operator A = b I − β L_h on one block-sparse lattice (module docs).
#[derive(Clone, Debug, Default)]
pub struct LatticeOperator {
    lattice: BlockLattice,
    core: [usize; 3],
    h: f64,
    b: f64,
    beta: f64,
    class: Vec<NodeClass>,
    neighbours: Vec<u8>,
    diag: Vec<f64>,
    inv_diag: Vec<f64>,
    interior: Vec<u32>,
    /// The slots of the six face-neighbour blocks (−x, +x, −y, +y, −z, +z) of every slot
    /// (0, the dummy, where not allocated): a node's neighbour inside its block is a fixed
    /// storage step away, and across a block face it is in this block (see `adjacent`).
    slot_adjacent: Vec<[u32; 6]>,
}

/// Storage steps of the six face neighbours (−x, +x, −y, +y, −z, +z) inside a block (z
/// fastest), and the steps of the wrapped position in the neighbouring block.
const INNER_STEP: [isize; 6] = [-16, 16, -4, 4, -1, 1];
const WRAP_STEP: [isize; 6] = [48, -48, 12, -12, 3, -3];

impl LatticeOperator {
    /// Rebuilds the operator for a dense box of `core` nodes (per axis) with spacing `h` and
    /// coefficients `b` (> 0) and `beta` (≥ 0); `class_of(c)` gives the class of the node
    /// with core coordinates `c` (0 ≤ c < core). Every block of the box is allocated; nodes
    /// outside it are Exterior. Reuses the storage.
    pub fn rebuild(
        &mut self,
        core: [usize; 3],
        h: f64,
        b: f64,
        beta: f64,
        mut class_of: impl FnMut([usize; 3]) -> NodeClass,
    ) {
        let hi = core.map(|n| n.max(1) as i32 - 1);
        self.lattice.begin([0; 3], hi);
        if core.iter().all(|&n| n > 0) {
            self.lattice.mark_cells([0; 3], hi);
        }
        self.lattice.finish();
        self.rebuild_classes(core, |c, _| class_of(c));
        self.finish(h, b, beta);
    }

    /// Rebuilds the operator on the allocated blocks of `lattice` (cells outside
    /// `0 ≤ c < core` or in unallocated blocks are Exterior); `class_of(c, idx)` gives the class
    /// of the node with coordinates `c` and storage index `idx`. Reuses the storage.
    pub fn rebuild_on(
        &mut self,
        lattice: &BlockLattice,
        core: [usize; 3],
        h: f64,
        b: f64,
        beta: f64,
        class_of: impl FnMut([usize; 3], usize) -> NodeClass,
    ) {
        self.lattice.clone_from(lattice);
        self.rebuild_classes(core, class_of);
        self.finish(h, b, beta);
    }

    /// Sizes the per-node arrays to the lattice and sets the classes of the allocated core
    /// nodes.
    fn rebuild_classes(
        &mut self,
        core: [usize; 3],
        mut class_of: impl FnMut([usize; 3], usize) -> NodeClass,
    ) {
        self.resize(core);
        for idx in BLOCK_CELLS..self.len() {
            if let Some(c) = self.coords(idx) {
                self.class[idx] = class_of(c, idx);
            }
        }
    }

    fn resize(&mut self, core: [usize; 3]) {
        self.core = core;
        let n = self.lattice.len();
        self.class.clear();
        self.class.resize(n, NodeClass::Exterior);
        self.neighbours.clear();
        self.neighbours.resize(n, 0);
        self.diag.clear();
        self.diag.resize(n, 0.0);
        self.inv_diag.clear();
        self.inv_diag.resize(n, 0.0);
    }

    /// Lists Interior nodes with their face neighbours, counts neighbours and sets the
    /// coefficients.
    fn finish(&mut self, h: f64, b: f64, beta: f64) {
        self.h = h;
        self.slot_adjacent.clear();
        self.slot_adjacent.push([0; 6]);
        for s in 1..=self.lattice.blocks() {
            let b = self.lattice.block(s);
            let mut adjacent = [0u32; 6];
            for (f, slot) in adjacent.iter_mut().enumerate() {
                let mut d = b.map(|v| v * BLOCK_EDGE);
                d[f / 2] += if f % 2 == 0 { -BLOCK_EDGE } else { BLOCK_EDGE };
                *slot = (self.lattice.index(d) / BLOCK_CELLS) as u32;
            }
            self.slot_adjacent.push(adjacent);
        }
        self.interior.clear();
        for idx in BLOCK_CELLS..self.class.len() {
            if self.class[idx] != NodeClass::Interior {
                continue;
            }
            let n = self
                .adjacent(idx)
                .iter()
                .filter(|&&j| self.class[j] != NodeClass::Exterior)
                .count();
            self.interior.push(idx as u32);
            self.neighbours[idx] = n as u8;
        }
        self.set_coefficients(b, beta);
    }

    /// Changes b and β (classes unchanged).
    pub fn set_coefficients(&mut self, b: f64, beta: f64) {
        self.b = b;
        self.beta = beta;
        let c = beta / (self.h * self.h);
        for &i in &self.interior {
            let i = i as usize;
            self.diag[i] = b + c * self.neighbours[i] as f64;
            self.inv_diag[i] = 1.0 / self.diag[i];
        }
    }

    /// Scales the b term node by node: A = b C − β L_h with C = diag(`capacity`) (Interior
    /// entries ≥ 1; the apparent heat capacity of latent heat, §3.1). Call after
    /// [`Self::set_coefficients`]; the coarse levels of a [`Multigrid`] keep C = 1 (the V-cycle
    /// stays a symmetric positive definite preconditioner of the scaled operator).
    pub fn scale_capacity(&mut self, capacity: &[f64]) {
        let c = self.beta / (self.h * self.h);
        for &i in &self.interior {
            let i = i as usize;
            self.diag[i] = self.b * capacity[i] + c * self.neighbours[i] as f64;
            self.inv_diag[i] = 1.0 / self.diag[i];
        }
    }

    /// The block lattice the nodes are stored on.
    pub fn lattice(&self) -> &BlockLattice {
        &self.lattice
    }

    /// Storage index of the node with core coordinates `c`.
    #[inline]
    pub fn index(&self, c: [usize; 3]) -> usize {
        self.lattice.index(c.map(|v| v as i32))
    }

    /// Core coordinates of storage index `idx` (`None` outside the core box or in the dummy
    /// block).
    pub fn coords(&self, idx: usize) -> Option<[usize; 3]> {
        let c = self.lattice.coords(idx)?;
        (0..3)
            .all(|a| c[a] >= 0 && (c[a] as usize) < self.core[a])
            .then(|| c.map(|v| v as usize))
    }

    /// Number of stored nodes (the dummy block and the allocated blocks): the length of
    /// every vector.
    pub fn len(&self) -> usize {
        self.class.len()
    }

    /// Whether the lattice has no node.
    pub fn is_empty(&self) -> bool {
        self.class.is_empty()
    }

    /// Extent of the core box (nodes per axis).
    pub fn core_dims(&self) -> [usize; 3] {
        self.core
    }

    /// Spacing h.
    pub fn spacing(&self) -> f64 {
        self.h
    }

    /// b (coefficient of the identity).
    pub fn b(&self) -> f64 {
        self.b
    }

    /// β (coefficient of −L_h).
    pub fn beta(&self) -> f64 {
        self.beta
    }

    /// Node classes, by storage index.
    pub fn classes(&self) -> &[NodeClass] {
        &self.class
    }

    /// Storage indices of the Interior nodes, ascending.
    pub fn interior(&self) -> &[u32] {
        &self.interior
    }

    /// Number of Exterior face neighbours of node `idx` (6 − nᵢ).
    pub fn exterior_faces(&self, idx: usize) -> usize {
        6 - self.neighbours[idx] as usize
    }

    /// Storage indices of the six face neighbours (−x, +x, −y, +y, −z, +z) of the allocated
    /// node `i` (dummy-block indices where a neighbour's block is not allocated).
    #[inline(always)]
    fn adjacent(&self, i: usize) -> [usize; 6] {
        let l = i % BLOCK_CELLS;
        let across = &self.slot_adjacent[i / BLOCK_CELLS];
        let at_face = [
            l >> 4 == 0,
            l >> 4 == 3,
            (l >> 2) & 3 == 0,
            (l >> 2) & 3 == 3,
            l & 3 == 0,
            l & 3 == 3,
        ];
        std::array::from_fn(|f| {
            if at_face[f] {
                (across[f] as usize * BLOCK_CELLS).wrapping_add_signed(l as isize + WRAP_STEP[f])
            } else {
                i.wrapping_add_signed(INNER_STEP[f])
            }
        })
    }

    /// (A x)ᵢ for the Interior node at position `k` of [`Self::interior`] (x must vanish off
    /// Interior nodes).
    #[inline(always)]
    fn row(&self, x: &[f64], k: usize) -> f64 {
        let i = self.interior[k] as usize;
        let adjacent = self.adjacent(i);
        debug_assert!(adjacent.iter().all(|&j| j < x.len()));
        // SAFETY: `adjacent` returns indices of allocated or dummy blocks (slot ≤ blocks,
        // local < 64), all below `self.len()`, and every caller of `row` asserts
        // `x.len() == self.len()`.
        let [a, b, c, d, e, f] = adjacent.map(|j| unsafe { *x.get_unchecked(j) });
        let off = a + b + c + d + e + f;
        self.diag[i] * x[i] - self.beta / (self.h * self.h) * off
    }

    /// r = f − A x on Interior nodes, 0 elsewhere.
    pub fn residual(&self, x: &[f64], f: &[f64], r: &mut [f64]) {
        assert_eq!(
            x.len(),
            self.len(),
            "vector length differs from the lattice's"
        );
        r.fill(0.0);
        for (k, &i) in self.interior.iter().enumerate() {
            let i = i as usize;
            r[i] = f[i] - self.row(x, k);
        }
    }

    /// The graph Laplacian of §3.3 on Interior nodes, 0 elsewhere:
    /// (L_h y)ᵢ = Σ_{j∈𝒩(i)∩(I∪𝒟)} (yⱼ − yᵢ)/h² (y is read on Interior, Dirichlet and Ghost nodes).
    pub fn laplacian(&self, y: &[f64], out: &mut [f64]) {
        out.fill(0.0);
        let c = 1.0 / (self.h * self.h);
        for &i in &self.interior {
            let i = i as usize;
            let mut s = 0.0;
            for j in self.adjacent(i) {
                if self.class[j] != NodeClass::Exterior {
                    s += y[j] - y[i];
                }
            }
            out[i] = c * s;
        }
    }

    /// Fills `pc` with the inverse diagonal (0 off Interior nodes): Jacobi-preconditioned CG,
    /// for comparison with the multigrid preconditioner.
    pub fn jacobi_preconditioner(&self, pc: &mut JacobiPreconditioner) {
        pc.inverse_diagonal.clear();
        pc.inverse_diagonal.resize(self.len(), 0.0);
        for &i in &self.interior {
            pc.inverse_diagonal[i as usize] = self.inv_diag[i as usize];
        }
    }

    /// One damped Jacobi sweep over the Interior nodes at `positions` (of
    /// [`Self::interior`]): xᵢ += ω/Aᵢᵢ (fᵢ − (Ax)ᵢ), computed out of place in `tmp`.
    fn sweep(
        &self,
        omega: f64,
        x: &mut [f64],
        f: &[f64],
        tmp: &mut [f64],
        positions: impl Iterator<Item = usize> + Clone,
    ) {
        assert_eq!(
            x.len(),
            self.len(),
            "vector length differs from the lattice's"
        );
        for k in positions.clone() {
            let i = self.interior[k] as usize;
            tmp[i] = x[i] + omega * self.inv_diag[i] * (f[i] - self.row(x, k));
        }
        for k in positions {
            let i = self.interior[k] as usize;
            x[i] = tmp[i];
        }
    }

    /// One damped Jacobi sweep over all Interior nodes.
    fn sweep_all(&self, omega: f64, x: &mut [f64], f: &[f64], tmp: &mut [f64]) {
        self.sweep(omega, x, f, tmp, 0..self.interior.len());
    }

    /// Builds the coarse operator of `fine` into `self` (classes Dirichlet > Interior >
    /// Exterior over the 2×2×2 children, spacing 2h, same b and β): the coarse blocks are
    /// those of the fine blocks holding a node that is not Exterior.
    fn coarsen_from(&mut self, fine: &LatticeOperator) {
        let core = fine.core.map(|n| n.div_ceil(2));
        self.lattice
            .begin([0; 3], core.map(|n| n.max(1) as i32 - 1));
        for s in 1..=fine.lattice.blocks() {
            let cells = &fine.class[s * BLOCK_CELLS..(s + 1) * BLOCK_CELLS];
            if cells.iter().any(|&c| c != NodeClass::Exterior) {
                self.lattice
                    .mark_block(fine.lattice.block(s).map(|v| v >> 1));
            }
        }
        self.lattice.finish();
        self.resize(core);
        for idx in BLOCK_CELLS..fine.class.len() {
            let cf = fine.class[idx];
            if cf == NodeClass::Exterior {
                continue;
            }
            let c = fine
                .lattice
                .coords(idx)
                .expect("allocated nodes have coordinates");
            let ci = self.lattice.index(c.map(|v| v >> 1));
            // A ghost is zero in the V-cycle: a homogeneous Dirichlet node from here down.
            let cf = if cf == NodeClass::Ghost {
                NodeClass::Dirichlet
            } else {
                cf
            };
            let cc = &mut self.class[ci];
            if cf == NodeClass::Dirichlet || *cc == NodeClass::Exterior {
                *cc = cf;
            }
        }
        self.finish(2.0 * fine.h, fine.b, fine.beta);
    }
}

impl LinearOperator for LatticeOperator {
    fn dim(&self) -> usize {
        self.len()
    }

    fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        assert_eq!(
            x.len(),
            self.len(),
            "vector length differs from the lattice's"
        );
        y.fill(0.0);
        for (k, &i) in self.interior.iter().enumerate() {
            y[i as usize] = self.row(x, k);
        }
    }
}

/// Parameters of [`Multigrid`] (as a preconditioner and as a stationary solver), in the
/// shape of faer's solver parameters (STYLE §7 item 10). Defaults are those of the
/// ALGORITHM §3.6 prototype plus a boundary band.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MultigridParams {
    /// Absolute tolerance of [`Multigrid::solve`] on the residual norm. Default `0`.
    pub abs_tolerance: f64,
    /// Relative tolerance of [`Multigrid::solve`] against the right-hand side's norm.
    /// Default `1e-8`.
    pub rel_tolerance: f64,
    /// Largest number of V-cycles of [`Multigrid::solve`]. Default `100`.
    pub max_cycles: usize,
    /// Jacobi sweeps over all Interior cells before the coarse correction. Default `2`.
    pub pre_smooth: usize,
    /// Jacobi sweeps after the coarse correction; must equal `pre_smooth` for a symmetric
    /// preconditioner. Default `2`.
    pub post_smooth: usize,
    /// Jacobi damping ω ∈ (0, 1]. Default ⅔.
    pub omega: f64,
    /// Width (in face steps) of the boundary band that gets extra sweeps. Default `2`.
    pub boundary_band: usize,
    /// Extra band sweeps before and after the Interior sweeps of every smoothing call
    /// (0 disables the band). Default `2`.
    pub boundary_sweeps: usize,
    /// Fixed number of Jacobi sweeps on the coarsest level. Default `50`.
    pub bottom_sweeps: usize,
    /// Stop coarsening once a level has at most this many Interior cells. Default `64` (4³).
    pub coarsest_cells: usize,
    /// Largest number of levels (including the finest). Default `16`.
    pub max_levels: usize,
    /// Norm of the stopping test of [`Multigrid::solve`]. Default max-norm (§3.5).
    pub norm: ResidualNorm,
}

impl Default for MultigridParams {
    fn default() -> Self {
        Self {
            abs_tolerance: 0.0,
            rel_tolerance: 1e-8,
            max_cycles: 100,
            pre_smooth: 2,
            post_smooth: 2,
            omega: 2.0 / 3.0,
            boundary_band: 2,
            boundary_sweeps: 2,
            bottom_sweeps: 50,
            coarsest_cells: 64,
            max_levels: 16,
            norm: ResidualNorm::Max,
        }
    }
}

impl MultigridParams {
    /// Checks the parameters; the error names the field.
    pub fn validate(&self) -> Result<(), MultigridError> {
        let bad = |field: &'static str, reason: &'static str| {
            Err(MultigridError::InvalidParameter { field, reason })
        };
        if !(self.abs_tolerance.is_finite() && self.abs_tolerance >= 0.0) {
            return bad("abs_tolerance", "must be a finite number ≥ 0");
        }
        if !(self.rel_tolerance.is_finite() && (0.0..1.0).contains(&self.rel_tolerance)) {
            return bad("rel_tolerance", "must be a finite number in [0, 1)");
        }
        if self.abs_tolerance == 0.0 && self.rel_tolerance == 0.0 {
            return bad(
                "rel_tolerance",
                "abs_tolerance and rel_tolerance cannot both be 0",
            );
        }
        if self.max_cycles == 0 {
            return bad("max_cycles", "must be ≥ 1");
        }
        if self.pre_smooth == 0 {
            return bad("pre_smooth", "must be ≥ 1");
        }
        if self.post_smooth != self.pre_smooth {
            return bad(
                "post_smooth",
                "must equal pre_smooth (a symmetric preconditioner for CG)",
            );
        }
        if !(self.omega.is_finite() && self.omega > 0.0 && self.omega <= 1.0) {
            return bad("omega", "must lie in (0, 1]");
        }
        if self.bottom_sweeps == 0 {
            return bad("bottom_sweeps", "must be ≥ 1");
        }
        if self.max_levels == 0 {
            return bad("max_levels", "must be ≥ 1");
        }
        if self.boundary_band > 255 {
            return bad("boundary_band", "must be ≤ 255");
        }
        Ok(())
    }
}

/// What a successful [`Multigrid::solve`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MultigridInfo {
    /// V-cycles done.
    pub cycles: usize,
    /// Final residual norm.
    pub abs_residual: f64,
    /// Final residual norm over the right-hand side's norm (0 when it is 0).
    pub rel_residual: f64,
}

/// Why a multigrid solve failed or could not start.
#[derive(Clone, Copy, Debug, PartialEq, Error)]
pub enum MultigridError {
    /// `max_cycles` V-cycles did not reach the tolerance.
    #[error(
        "multigrid did not converge in {cycles} cycles (relative residual {rel_residual:.3e}, absolute {abs_residual:.3e})"
    )]
    NoConvergence {
        /// Cycles done.
        cycles: usize,
        /// Residual norm at the end.
        abs_residual: f64,
        /// Relative residual at the end.
        rel_residual: f64,
    },
    /// A parameter is out of range.
    #[error("multigrid parameter {field} {reason}")]
    InvalidParameter {
        /// The field of [`MultigridParams`].
        field: &'static str,
        /// The constraint.
        reason: &'static str,
    },
    /// A NaN or infinity appeared.
    #[error("a non-finite number appeared in multigrid cycle {cycle}")]
    NonFinite {
        /// The cycle.
        cycle: usize,
    },
}

#[derive(Clone, Debug, Default)]
struct Level {
    op: LatticeOperator,
    /// Positions (in `op.interior`) of the boundary band's cells.
    band: Vec<u32>,
    layer: Vec<u8>,
    /// Storage indices, on the next coarser level, of the 8 cells that prolongate onto each
    /// Interior cell (by position in `op.interior`), in the order of [`PARENT_WEIGHTS`];
    /// empty on the coarsest level.
    parents: Vec<[u32; 8]>,
    x: Vec<f64>,
    f: Vec<f64>,
    tmp: Vec<f64>,
}

/// Trilinear prolongation weights of the 8 parents (1-D: ¾ the parent, ¼ its neighbour on the
/// child's side), x-major over (parent, neighbour) per axis.
const PARENT_WEIGHTS: [f64; 8] = {
    let w = [0.75, 0.25];
    let mut out = [0.0; 8];
    let mut m = 0;
    while m < 8 {
        out[m] = w[m >> 2] * w[(m >> 1) & 1] * w[m & 1];
        m += 1;
    }
    out
};

impl Level {
    fn size_vectors(&mut self) {
        let n = self.op.len();
        for v in [&mut self.x, &mut self.f, &mut self.tmp] {
            v.clear();
            v.resize(n, 0.0);
        }
    }

    /// Interior cells within `radius` face steps of a non-Interior cell (breadth-first
    /// layers), as positions in ascending order.
    fn build_band(&mut self, radius: usize) {
        self.band.clear();
        if radius == 0 {
            return;
        }
        let op = &self.op;
        self.layer.clear();
        self.layer.resize(op.len(), 0);
        for layer in 1..=radius as u8 {
            for &i in &op.interior {
                let i = i as usize;
                if self.layer[i] != 0 {
                    continue;
                }
                let touches = op.adjacent(i).into_iter().any(|j| {
                    if layer == 1 {
                        op.class[j] != NodeClass::Interior
                    } else {
                        self.layer[j] == layer - 1
                    }
                });
                if touches {
                    self.layer[i] = layer;
                }
            }
        }
        self.band.extend(
            op.interior
                .iter()
                .enumerate()
                .filter(|&(_, &i)| self.layer[i as usize] != 0)
                .map(|(k, _)| k as u32),
        );
    }

    /// Lists the parents of every Interior cell on `coarse` (see `parents`).
    fn find_parents(&mut self, coarse: &LatticeOperator) {
        self.parents.clear();
        for &i in &self.op.interior {
            let c = self
                .op
                .lattice
                .coords(i as usize)
                .expect("interior nodes are allocated");
            // The parent, and its neighbour on the child's side.
            let near = c.map(|v| v >> 1);
            let far = [0, 1, 2].map(|a| near[a] + if c[a] % 2 == 0 { -1 } else { 1 });
            let mut p = [0u32; 8];
            for (m, slot) in p.iter_mut().enumerate() {
                let pick = |a: usize, bit: usize| if bit == 0 { near[a] } else { far[a] };
                let cc = [pick(0, m >> 2), pick(1, (m >> 1) & 1), pick(2, m & 1)];
                *slot = coarse.lattice.index(cc) as u32;
            }
            self.parents.push(p);
        }
    }
}

/// The multigrid hierarchy and its scratch memory (module docs). Implements
/// [`Preconditioner`] (one V-cycle from zero).
#[derive(Clone, Debug, Default)]
pub struct Multigrid {
    params: MultigridParams,
    levels: Vec<Level>,
    used: usize,
    residual: Vec<f64>,
    correction: Vec<f64>,
}

impl Multigrid {
    /// An empty hierarchy with `params` (checked).
    ///
    /// # Errors
    /// [`MultigridError::InvalidParameter`].
    pub fn new(params: MultigridParams) -> Result<Self, MultigridError> {
        params.validate()?;
        Ok(Self {
            params,
            ..Default::default()
        })
    }

    /// The parameters.
    pub fn params(&self) -> &MultigridParams {
        &self.params
    }

    /// Replaces the parameters (checked); takes effect at the next [`Multigrid::setup`].
    ///
    /// # Errors
    /// [`MultigridError::InvalidParameter`].
    pub fn set_params(&mut self, params: MultigridParams) -> Result<(), MultigridError> {
        params.validate()?;
        self.params = params;
        Ok(())
    }

    /// Number of levels of the current hierarchy (0 before [`Multigrid::setup`]).
    pub fn levels(&self) -> usize {
        self.used
    }

    /// Interior cells per level, finest first.
    pub fn interior_cells(&self) -> Vec<usize> {
        self.levels[..self.used]
            .iter()
            .map(|l| l.op.interior.len())
            .collect()
    }

    /// Builds the hierarchy for the fine operator (reusing all storage).
    pub fn setup(&mut self, fine: &LatticeOperator) {
        if self.levels.is_empty() {
            self.levels.push(Level::default());
        }
        self.levels[0].op.clone_from(fine);
        self.used = 1;
        loop {
            let cur = &self.levels[self.used - 1].op;
            let coarse_enough = cur.interior.len() <= self.params.coarsest_cells
                || cur.core.iter().all(|&n| n <= 2)
                || self.used >= self.params.max_levels;
            if coarse_enough {
                break;
            }
            if self.levels.len() == self.used {
                self.levels.push(Level::default());
            }
            let (done, rest) = self.levels.split_at_mut(self.used);
            rest[0].op.coarsen_from(&done[self.used - 1].op);
            if rest[0].op.interior.is_empty() {
                break;
            }
            self.used += 1;
        }
        let radius = self.params.boundary_band;
        for l in &mut self.levels[..self.used] {
            l.size_vectors();
            l.build_band(radius);
        }
        for l in 0..self.used {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            if l + 1 < self.used {
                fine[l].find_parents(&coarse[0].op);
            } else {
                fine[l].parents.clear();
            }
        }
        let n = fine.len();
        self.residual.clear();
        self.residual.resize(n, 0.0);
        self.correction.clear();
        self.correction.resize(n, 0.0);
    }

    /// Changes b and β on every level (classes unchanged).
    pub fn set_coefficients(&mut self, b: f64, beta: f64) {
        for l in &mut self.levels[..self.used] {
            l.op.set_coefficients(b, beta);
        }
    }

    /// One V-cycle z = M⁻¹ r from a zero initial guess (`z` is overwritten).
    pub fn vcycle(&mut self, r: &[f64], z: &mut [f64]) {
        if self.used == 0 {
            z.fill(0.0);
            return;
        }
        vcycle(&mut self.levels[..self.used], &self.params, z, r);
    }

    /// Solves A x = f by V-cycle iteration x ← x + M⁻¹(f − A x) from the `x` given, until
    /// ‖f − A x‖ ≤ max(abs_tolerance, rel_tolerance ‖f‖) in [`MultigridParams::norm`].
    ///
    /// # Errors
    /// [`MultigridError::NoConvergence`] after `max_cycles`; [`MultigridError::NonFinite`].
    pub fn solve(&mut self, f: &[f64], x: &mut [f64]) -> Result<MultigridInfo, MultigridError> {
        let norm = self.params.norm;
        let f_norm = norm.of(f);
        if !f_norm.is_finite() {
            return Err(MultigridError::NonFinite { cycle: 0 });
        }
        let tol = self
            .params
            .abs_tolerance
            .max(self.params.rel_tolerance * f_norm);
        let rel = |r: f64| if f_norm > 0.0 { r / f_norm } else { 0.0 };
        let mut r = std::mem::take(&mut self.residual);
        let mut e = std::mem::take(&mut self.correction);
        let mut result = Err(MultigridError::NonFinite { cycle: 0 });
        for cycle in 0..=self.params.max_cycles {
            if self.used == 0 {
                result = Ok(MultigridInfo::default());
                break;
            }
            self.levels[0].op.residual(x, f, &mut r);
            let res = norm.of(&r);
            if !res.is_finite() {
                result = Err(MultigridError::NonFinite { cycle });
                break;
            }
            if res <= tol {
                result = Ok(MultigridInfo {
                    cycles: cycle,
                    abs_residual: res,
                    rel_residual: rel(res),
                });
                break;
            }
            if cycle == self.params.max_cycles {
                result = Err(MultigridError::NoConvergence {
                    cycles: cycle,
                    abs_residual: res,
                    rel_residual: rel(res),
                });
                break;
            }
            vcycle(&mut self.levels[..self.used], &self.params, &mut e, &r);
            for &i in &self.levels[0].op.interior {
                x[i as usize] += e[i as usize];
            }
        }
        self.residual = r;
        self.correction = e;
        result
    }
}

impl Preconditioner for Multigrid {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        self.vcycle(r, z);
    }
}

/// One smoothing call: band, Interior, band sweeps (a palindrome).
fn smooth(level: &mut Level, params: &MultigridParams, x: &mut [f64], f: &[f64], nu: usize) {
    let Level { op, band, tmp, .. } = level;
    let bands = if band.is_empty() {
        0
    } else {
        params.boundary_sweeps
    };
    let band = band.iter().map(|&k| k as usize);
    for _ in 0..bands {
        op.sweep(params.omega, x, f, tmp, band.clone());
    }
    for _ in 0..nu {
        op.sweep_all(params.omega, x, f, tmp);
    }
    for _ in 0..bands {
        op.sweep(params.omega, x, f, tmp, band.clone());
    }
}

/// The V-cycle on `levels[0]` (finest of the slice) with zero initial guess.
fn vcycle(levels: &mut [Level], params: &MultigridParams, x: &mut [f64], f: &[f64]) {
    x.fill(0.0);
    let (cur, rest) = levels
        .split_first_mut()
        .expect("vcycle needs at least one level");
    if rest.is_empty() {
        let Level { op, tmp, .. } = cur;
        for _ in 0..params.bottom_sweeps {
            op.sweep_all(params.omega, x, f, tmp);
        }
        return;
    }
    smooth(cur, params, x, f, params.pre_smooth);
    cur.op.residual(x, f, &mut cur.tmp);
    let next = &mut rest[0];
    restrict(cur, &cur.tmp, &next.op, &mut next.f);
    let mut xc = std::mem::take(&mut next.x);
    let fc = std::mem::take(&mut next.f);
    vcycle(rest, params, &mut xc, &fc);
    prolongate_add(cur, &xc, x);
    rest[0].x = xc;
    rest[0].f = fc;
    smooth(cur, params, x, f, params.post_smooth);
}

/// x_fine += P x_coarse on the fine level's Interior cells.
fn prolongate_add(fine: &Level, xc: &[f64], x: &mut [f64]) {
    for (&i, parents) in fine.op.interior.iter().zip(&fine.parents) {
        let mut s = 0.0;
        for (&j, w) in parents.iter().zip(PARENT_WEIGHTS) {
            s += w * xc[j as usize];
        }
        x[i as usize] += s;
    }
}

/// r_coarse = 2⁻³ Pᵀ r_fine, restricted to coarse Interior cells.
fn restrict(fine: &Level, r: &[f64], coarse: &LatticeOperator, rc: &mut [f64]) {
    rc.fill(0.0);
    for (&i, parents) in fine.op.interior.iter().zip(&fine.parents) {
        let v = 0.125 * r[i as usize];
        for (&j, w) in parents.iter().zip(PARENT_WEIGHTS) {
            rc[j as usize] += w * v;
        }
    }
    for (v, class) in rc.iter_mut().zip(&coarse.class) {
        if *class != NodeClass::Interior {
            *v = 0.0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `stencil_indices` is `index` on each of the 27 cells, for stencils inside one block,
    /// across block faces, edges and corners, in unallocated blocks and outside the table.
    #[test]
    fn stencil_indices_match_index() {
        let mut lattice = BlockLattice::default();
        lattice.begin([0; 3], [23, 19, 27]);
        // A sparse pattern of blocks (some neighbours allocated, some not).
        for b in [
            [0, 0, 0],
            [1, 0, 0],
            [1, 1, 1],
            [2, 3, 4],
            [5, 4, 6],
            [4, 4, 6],
        ] {
            lattice.mark_block(b);
        }
        lattice.finish();
        assert_eq!(lattice.blocks(), 6);
        let mut checked = 0;
        for x in -6..26 {
            for y in -6..22 {
                for z in -6..30 {
                    let c0 = [x, y, z];
                    let got = lattice.stencil_indices(c0);
                    for i in 0..3 {
                        for j in 0..3 {
                            for k in 0..3 {
                                let c = [x + i, y + j, z + k];
                                let want = lattice.index(c);
                                assert_eq!(got[((i * 3 + j) * 3 + k) as usize] as usize, want);
                                if want >= BLOCK_CELLS {
                                    assert_eq!(lattice.coords(want), Some(c));
                                    checked += 1;
                                }
                            }
                        }
                    }
                }
            }
        }
        // Every allocated cell is seen 27 times.
        assert_eq!(checked, 27 * 6 * BLOCK_CELLS);
        // The operator's face neighbours are `index` of the six adjacent cells, inside a block
        // and across its faces, allocated or not.
        let mut op = LatticeOperator::default();
        op.rebuild_on(&lattice, [24, 20, 28], 1.0, 1.0, 1.0, |_, _| {
            NodeClass::Interior
        });
        for idx in BLOCK_CELLS..op.len() {
            let c = lattice.coords(idx).unwrap();
            let want: [usize; 6] = std::array::from_fn(|f| {
                let mut d = c;
                d[f / 2] += if f % 2 == 0 { -1 } else { 1 };
                lattice.index(d)
            });
            assert_eq!(op.adjacent(idx), want, "{c:?}");
        }
    }
}
