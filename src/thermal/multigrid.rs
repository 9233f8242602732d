//! Assembly-free multigrid V-cycle for the heat system (b I − β L_h) x = r on the MPM node
//! lattice (ALGORITHM §3.3, §3.5), used as the preconditioner of conjugate gradients
//! ([`crate::krylov::conjugate_gradient`]) or as a stationary solver ([`Multigrid::solve`]).
//!
//! # Lattice and operator (§3.3)
//!
//! [`LatticeOperator`] stores one class per node ([`NodeClass`]: Interior, Dirichlet,
//! Exterior) on a box of `core` nodes surrounded by a one-node Exterior halo (so neighbour
//! lookups need no bounds checks). The unknowns live on Interior nodes; every vector handed
//! to the operator or the preconditioner must vanish elsewhere (the solvers here keep it so):
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
//! with the same b and β. Coarsening stops when a level has at most
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
//! [`Multigrid::setup`] calls: once sized, no allocation. All loops are serial in index
//! order, so results are bit-identical for any thread count.
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
}

/// The matrix-free operator A = b I − β L_h on one lattice (module docs).
#[derive(Clone, Debug, Default)]
pub struct LatticeOperator {
    core: [usize; 3],
    dims: [usize; 3],
    strides: [usize; 3],
    h: f64,
    b: f64,
    beta: f64,
    class: Vec<NodeClass>,
    neighbours: Vec<u8>,
    diag: Vec<f64>,
    inv_diag: Vec<f64>,
    interior: Vec<u32>,
}

impl LatticeOperator {
    /// Rebuilds the operator for a box of `core` nodes (per axis) with spacing `h` and
    /// coefficients `b` (> 0) and `beta` (≥ 0); `class_of(c)` gives the class of the node
    /// with core coordinates `c` (0 ≤ c < core). Reuses the storage.
    pub fn rebuild(
        &mut self,
        core: [usize; 3],
        h: f64,
        b: f64,
        beta: f64,
        mut class_of: impl FnMut([usize; 3]) -> NodeClass,
    ) {
        self.resize(core);
        for i in 0..core[0] {
            for j in 0..core[1] {
                let row = self.index([i, j, 0]);
                for k in 0..core[2] {
                    self.class[row + k] = class_of([i, j, k]);
                }
            }
        }
        self.finish(h, b, beta);
    }

    fn resize(&mut self, core: [usize; 3]) {
        self.core = core;
        self.dims = core.map(|n| n + 2);
        self.strides = [self.dims[1] * self.dims[2], self.dims[2], 1];
        let n = self.dims[0] * self.dims[1] * self.dims[2];
        self.class.clear();
        self.class.resize(n, NodeClass::Exterior);
        self.neighbours.clear();
        self.neighbours.resize(n, 0);
        self.diag.clear();
        self.diag.resize(n, 0.0);
        self.inv_diag.clear();
        self.inv_diag.resize(n, 0.0);
    }

    /// Counts neighbours, lists Interior nodes and sets the coefficients.
    fn finish(&mut self, h: f64, b: f64, beta: f64) {
        self.h = h;
        self.interior.clear();
        let [sx, sy, sz] = self.strides;
        for i in 1..=self.core[0] {
            for j in 1..=self.core[1] {
                let row = i * sx + j * sy;
                for k in 1..=self.core[2] {
                    let idx = row + k;
                    if self.class[idx] != NodeClass::Interior {
                        continue;
                    }
                    self.interior.push(idx as u32);
                    let n = [idx - sx, idx + sx, idx - sy, idx + sy, idx - sz, idx + sz]
                        .iter()
                        .filter(|&&j| self.class[j] != NodeClass::Exterior)
                        .count();
                    self.neighbours[idx] = n as u8;
                }
            }
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

    /// Storage index of the node with core coordinates `c`.
    #[inline]
    pub fn index(&self, c: [usize; 3]) -> usize {
        (c[0] + 1) * self.strides[0] + (c[1] + 1) * self.strides[1] + c[2] + 1
    }

    /// Core coordinates of storage index `idx` (`None` for halo nodes).
    pub fn coords(&self, idx: usize) -> Option<[usize; 3]> {
        let i = idx / self.strides[0];
        let j = (idx / self.strides[1]) % self.dims[1];
        let k = idx % self.dims[2];
        let ok = (1..=self.core[0]).contains(&i)
            && (1..=self.core[1]).contains(&j)
            && (1..=self.core[2]).contains(&k);
        ok.then(|| [i - 1, j - 1, k - 1])
    }

    /// Number of stored nodes (core and halo): the length of every vector.
    pub fn len(&self) -> usize {
        self.class.len()
    }

    /// Whether the lattice has no node.
    pub fn is_empty(&self) -> bool {
        self.class.is_empty()
    }

    /// Nodes per axis without the halo.
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

    /// (A x)ᵢ for an Interior node (x must vanish off Interior nodes).
    #[inline(always)]
    fn row(&self, x: &[f64], i: usize) -> f64 {
        let [sx, sy, _] = self.strides;
        let off = x[i - sx] + x[i + sx] + x[i - sy] + x[i + sy] + x[i - 1] + x[i + 1];
        self.diag[i] * x[i] - self.beta / (self.h * self.h) * off
    }

    /// r = f − A x on Interior nodes, 0 elsewhere.
    pub fn residual(&self, x: &[f64], f: &[f64], r: &mut [f64]) {
        r.fill(0.0);
        for &i in &self.interior {
            let i = i as usize;
            r[i] = f[i] - self.row(x, i);
        }
    }

    /// The graph Laplacian of §3.3 on Interior nodes, 0 elsewhere:
    /// (L_h y)ᵢ = Σ_{j∈𝒩(i)∩(I∪𝒟)} (yⱼ − yᵢ)/h² (y is read on Interior and Dirichlet nodes).
    pub fn laplacian(&self, y: &[f64], out: &mut [f64]) {
        out.fill(0.0);
        let [sx, sy, sz] = self.strides;
        let c = 1.0 / (self.h * self.h);
        for &i in &self.interior {
            let i = i as usize;
            let mut s = 0.0;
            for j in [i - sx, i + sx, i - sy, i + sy, i - sz, i + sz] {
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

    /// One damped Jacobi sweep over `cells` (Interior indices): xᵢ += ω/Aᵢᵢ (fᵢ − (Ax)ᵢ),
    /// computed out of place in `tmp`.
    fn sweep(&self, omega: f64, x: &mut [f64], f: &[f64], tmp: &mut [f64], cells: &[u32]) {
        for &i in cells {
            let i = i as usize;
            tmp[i] = x[i] + omega * self.inv_diag[i] * (f[i] - self.row(x, i));
        }
        for &i in cells {
            x[i as usize] = tmp[i as usize];
        }
    }

    /// Builds the coarse operator of `fine` into `self` (classes Dirichlet > Interior >
    /// Exterior over the 2×2×2 children, spacing 2h, same b and β).
    fn coarsen_from(&mut self, fine: &LatticeOperator) {
        let core = fine.core.map(|n| n.div_ceil(2));
        self.resize(core);
        for i in 0..fine.core[0] {
            for j in 0..fine.core[1] {
                for k in 0..fine.core[2] {
                    let cf = fine.class[fine.index([i, j, k])];
                    if cf == NodeClass::Exterior {
                        continue;
                    }
                    let ci = self.index([i / 2, j / 2, k / 2]);
                    let cc = &mut self.class[ci];
                    if cf == NodeClass::Dirichlet || *cc == NodeClass::Exterior {
                        *cc = cf;
                    }
                }
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
        y.fill(0.0);
        for &i in &self.interior {
            let i = i as usize;
            y[i] = self.row(x, i);
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
    band: Vec<u32>,
    layer: Vec<u8>,
    x: Vec<f64>,
    f: Vec<f64>,
    tmp: Vec<f64>,
}

impl Level {
    fn size_vectors(&mut self) {
        let n = self.op.len();
        for v in [&mut self.x, &mut self.f, &mut self.tmp] {
            v.clear();
            v.resize(n, 0.0);
        }
    }

    /// Interior cells within `radius` face steps of a non-Interior cell (breadth-first
    /// layers), ascending.
    fn build_band(&mut self, radius: usize) {
        self.band.clear();
        if radius == 0 {
            return;
        }
        let op = &self.op;
        self.layer.clear();
        self.layer.resize(op.len(), 0);
        let [sx, sy, sz] = op.strides;
        for layer in 1..=radius as u8 {
            for &i in &op.interior {
                let i = i as usize;
                if self.layer[i] != 0 {
                    continue;
                }
                let touches = [i - sx, i + sx, i - sy, i + sy, i - sz, i + sz]
                    .iter()
                    .any(|&j| {
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
                .copied()
                .filter(|&i| self.layer[i as usize] != 0),
        );
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
    for _ in 0..bands {
        op.sweep(params.omega, x, f, tmp, band);
    }
    for _ in 0..nu {
        op.sweep(params.omega, x, f, tmp, &op.interior);
    }
    for _ in 0..bands {
        op.sweep(params.omega, x, f, tmp, band);
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
            op.sweep(params.omega, x, f, tmp, &op.interior);
        }
        return;
    }
    smooth(cur, params, x, f, params.pre_smooth);
    cur.op.residual(x, f, &mut cur.tmp);
    let next = &mut rest[0];
    restrict(&cur.op, &cur.tmp, &next.op, &mut next.f);
    let mut xc = std::mem::take(&mut next.x);
    let fc = std::mem::take(&mut next.f);
    vcycle(rest, params, &mut xc, &fc);
    prolongate_add(&rest[0].op, &xc, &cur.op, x);
    rest[0].x = xc;
    rest[0].f = fc;
    smooth(cur, params, x, f, params.post_smooth);
}

/// Calls `f(coarse storage index, weight)` for the 8 coarse cells that prolongate onto the
/// fine cell with core coordinates `c` (trilinear, 1-D weights ¾ parent, ¼ neighbour).
#[inline(always)]
fn for_each_parent(coarse: &LatticeOperator, c: [usize; 3], mut f: impl FnMut(usize, f64)) {
    // Padded coarse coordinates of the parent and of the neighbour on the child's side.
    let mut near = [0usize; 3];
    let mut far = [0usize; 3];
    for a in 0..3 {
        let p = c[a] / 2 + 1;
        near[a] = p;
        far[a] = if c[a].is_multiple_of(2) { p - 1 } else { p + 1 };
    }
    let [sx, sy, _] = coarse.strides;
    for (xi, wx) in [(near[0], 0.75), (far[0], 0.25)] {
        for (yi, wy) in [(near[1], 0.75), (far[1], 0.25)] {
            let row = xi * sx + yi * sy;
            let w = wx * wy;
            f(row + near[2], w * 0.75);
            f(row + far[2], w * 0.25);
        }
    }
}

/// x_fine += P x_coarse on fine Interior cells.
fn prolongate_add(coarse: &LatticeOperator, xc: &[f64], fine: &LatticeOperator, x: &mut [f64]) {
    for &i in &fine.interior {
        let i = i as usize;
        let c = fine.coords(i).expect("interior nodes are core nodes");
        let mut s = 0.0;
        for_each_parent(coarse, c, |j, w| s += w * xc[j]);
        x[i] += s;
    }
}

/// r_coarse = 2⁻³ Pᵀ r_fine, restricted to coarse Interior cells.
fn restrict(fine: &LatticeOperator, r: &[f64], coarse: &LatticeOperator, rc: &mut [f64]) {
    rc.fill(0.0);
    for &i in &fine.interior {
        let i = i as usize;
        let c = fine.coords(i).expect("interior nodes are core nodes");
        let v = 0.125 * r[i];
        for_each_parent(coarse, c, |j, w| rc[j] += w * v);
    }
    for (v, class) in rc.iter_mut().zip(&coarse.class) {
        if *class != NodeClass::Interior {
            *v = 0.0;
        }
    }
}
