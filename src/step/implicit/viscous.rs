//! The matrix-free viscous operator A = M + θK on the active grid nodes, the boundary
//! projection, and the grid-update system of the implicit schemes (module docs of
//! [`crate::step::implicit`]).
//!
//! Unknowns are the three velocity components of every active node (m̃ᵢ > m_ε; on periodic
//! axes only the nodes inside the domain, their ghosts are copies; beyond a mirror face
//! (§2.11, D18) none, those nodes are reflected copies), stored as one flat `f64`
//! vector `[u₀ₓ, u₀ᵧ, u₀𝓏, u₁ₓ, …]`. One operator application is
//!
//! 1. nodal velocities from the vector (constrained nodes projected, ghosts copied);
//! 2. a parallel gather per particle, block by block: Sₚ = 2F_vμₚṼₚ sym(Σᵢ uᵢ ⊗ ∇w̃ᵢₚ);
//! 3. the block-coloured scatter (Ku)ᵢ = Σₚ Sₚ∇w̃ᵢₚ ([`BlockPlan`], deterministic), folds;
//! 4. yᵢ = m̃ᵢuᵢ + θ(Ku)ᵢ, projected.
//!
//! On several ranks (ALGORITHM §12) each rank's unknowns are its active nodes; a node of a
//! column two ranks share is an unknown on both, but only the rank that counts it
//! ([`Ranks::counts_node`]) holds its entries in the CG vectors (zero on the other). Step 1
//! then copies the counting rank's velocities to the other ([`SharedColumns::copy_counted_vector`]),
//! step 3 sums the shared columns' forces over the two ranks
//! ([`SharedColumns::sum_halo_vector`]), and the CG's inner products are summed over the ranks; after
//! the solve the counting rank's velocities are copied again, so both write the same new
//! nodal state.
//!
//! The stencils and the weights are those of the explicit force scatter
//! ([`crate::step::grid_forces`]), so K is exactly the linearisation of the explicit viscous
//! force, and it is symmetric to rounding (the same `f32` gradients enter both passes).
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};

use super::ImplicitSolveStats;
use crate::collision::ColliderInstance;
use crate::components::{Mass, Particle, ParticleStencil, PredictedDensity};
use crate::config::{BoundaryCondition, DomainWalls, FlipUpdate, MpmConfig, Scheme};
use crate::distributed::{RankReduction, Ranks, SharedColumns};
use crate::failure::{FailureCollector, FailureReport};
use crate::grid::{GhostCopy, MirrorFace, MpmGrid};
use crate::gs4::Gs4Params;
use crate::kernels::Stencil;
use crate::krylov::{
    CgError, CgInfo, CgParams, CgScratch, JacobiPreconditioner, LinearOperator, Reduction,
    ResidualNorm, conjugate_gradient_reduced,
};
use crate::material::{MaterialId, Materials};
use crate::math::Vec3;
use crate::scatter::{BlockPlan, SharedMut};
use crate::step::grid_update::collide_node;
use crate::step::p2g::{copy_ghosts, mirror_faces, periodic_counts};
use crate::step::schedule::{ActiveColliders, Gs4Constants, StepContext};

/// The per-scheme coefficients of one implicit step (table of [`crate::step::implicit`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImplicitStep {
    /// [`Scheme::BackwardEulerViscous`] or [`Scheme::Gs4SemiImplicit`].
    pub scheme: Scheme,
    /// Δt \[s\].
    pub dt: f64,
    /// θ \[s\]: Δt (BE) or W₂Λ₅Δt/W₁Λ₆ (GS4).
    pub theta: f64,
    /// The GS4 weights (GS4 only).
    pub gs4: Gs4Params,
}

impl ImplicitStep {
    /// The coefficients of a step of size `dt` \[s\].
    pub fn new(scheme: Scheme, gs4: &Gs4Params, dt: f64) -> Self {
        let theta = match scheme {
            Scheme::Gs4SemiImplicit => gs4.w2l5 * dt / gs4.w1l6,
            _ => dt,
        };
        Self {
            scheme,
            dt,
            theta,
            gs4: *gs4,
        }
    }

    fn is_gs4(&self) -> bool {
        self.scheme == Scheme::Gs4SemiImplicit
    }

    /// û and g′ of a node with velocity vⁿ, acceleration aⁿ and transfer defect `d`
    /// (GS4 with [`FlipUpdate::ParticleGs4`]: Dᵢ = ((I − PW)R⁰)ᵢ, else 0; see
    /// [`implicit_viscous_update`]).
    #[inline]
    pub fn predictor(&self, v: DVec3, a: DVec3, d: DVec3, g: DVec3) -> (DVec3, DVec3) {
        if self.is_gs4() {
            (v + self.gs4.w1l4 * self.dt * a - self.theta * d, g - a)
        } else {
            (v, g)
        }
    }

    /// End-of-step velocity and acceleration (vⁿ⁺¹, aⁿ⁺¹) from the solution u; `u_hat` is the
    /// û of [`Self::predictor`].
    #[inline]
    pub fn finish(&self, u: DVec3, u_hat: DVec3, v: DVec3, a: DVec3) -> (DVec3, DVec3) {
        let dt = self.dt;
        if self.is_gs4() {
            let p = &self.gs4;
            let da = (u - u_hat) / (p.w2l5 * dt);
            (v + p.l4 * dt * a + p.l5 * dt * da, a + da)
        } else {
            (u, (u - v) / dt)
        }
    }

    /// The unknown u whose end-of-step velocity is `v_end` (inverse of [`Self::finish`]).
    #[inline]
    pub fn unknown_of_velocity(&self, v_end: DVec3, u_hat: DVec3, v: DVec3, a: DVec3) -> DVec3 {
        let dt = self.dt;
        if self.is_gs4() {
            let p = &self.gs4;
            let da = (v_end - v - p.l4 * dt * a) / (p.l5 * dt);
            u_hat + p.w2l5 * dt * da
        } else {
            v_end
        }
    }

    /// (W₁Λ₆ − λ₅)Δt for the friction bound of [`collide_node`] (0 for BE).
    fn extra_dt(&self) -> f32 {
        if self.is_gs4() {
            ((self.gs4.w1l6 - self.gs4.l5).max(0.0) * self.dt) as f32
        } else {
            0.0
        }
    }
}

/// One unknown node.
#[derive(Clone, Copy, Debug)]
struct Dof {
    /// Storage index in the grid.
    node: usize,
    /// World position \[m\].
    position: Vec3,
    /// m̃ᵢ \[kg\].
    mass: f64,
    /// vᵢⁿ, aᵢⁿ.
    v: DVec3,
    a: DVec3,
    /// Whether this rank holds the node's entries in the CG vectors (always in one process;
    /// on ranks, [`Ranks::counts_node`]).
    counted: bool,
}

/// A node with constrained components: u = `free`·x + `fixed`.
#[derive(Clone, Copy, Debug)]
struct Constraint {
    dof: usize,
    /// Projector on the free components (symmetric, idempotent).
    free: DMat3,
    /// The prescribed part (orthogonal to the free space).
    fixed: DVec3,
}

/// Reusable memory of the implicit viscous solve (a Resource): per-particle terms, the unknown
/// list, node-sized `f64` work arrays and the CG vectors. Grown on demand, never shrunk.
#[derive(Resource, Default)]
pub struct ViscousSolveScratch {
    particles: Vec<(Stencil, f64)>,
    stress: Vec<DMat3>,
    dofs: Vec<Dof>,
    u_hat: Vec<DVec3>,
    constraints: Vec<Constraint>,
    ghosts: Vec<GhostSet>,
    u_node: Vec<DVec3>,
    f_node: Vec<DVec3>,
    b: Vec<f64>,
    x: Vec<f64>,
    tmp: Vec<f64>,
    predicted: Vec<DVec3>,
    jacobi: JacobiPreconditioner,
    cg: CgScratch,
}

/// The operator P(M + θK)P over borrowed scratch (see the module docs for one application).
struct GridViscousOperator<'a> {
    grid: &'a MpmGrid,
    plan: &'a BlockPlan,
    particles: &'a [(Stencil, f64)],
    dofs: &'a [Dof],
    constraints: &'a [Constraint],
    ghosts: &'a [GhostSet],
    theta: f64,
    u_node: &'a mut [DVec3],
    f_node: &'a mut [DVec3],
    stress: &'a mut [DMat3],
    /// Project the input on the free components (off only to apply A to the fixed part).
    project_input: bool,
    /// The shared columns of a distributed run (more than one rank).
    ranks: Option<&'a SharedColumns<'a>>,
}

impl GridViscousOperator<'_> {
    /// (Ku)ᵢ into `f_node` from the nodal velocities in `u_node` (ghosts already copied).
    fn viscous_force(&mut self) {
        let (grid, plan) = (self.grid, self.plan);
        let particles = self.particles;
        let n = particles.len();
        let stress = SharedMut(self.stress[..n].as_mut_ptr());
        plan.gather(grid, self.u_node, |i, local, u| {
            let (st, c) = &particles[i];
            let mut l = DMat3::ZERO;
            st.for_each(local, |idx, _, g| {
                let ui = u[idx];
                l.x_axis += ui * g.x as f64;
                l.y_axis += ui * g.y as f64;
                l.z_axis += ui * g.z as f64;
            });
            // SAFETY: each particle index is gathered once; `stress` holds `n` entries.
            unsafe { *stress.get().add(i) = (0.5 * c) * (l + l.transpose()) };
        });
        let f = &mut *self.f_node;
        f.fill(DVec3::ZERO);
        let stress = &*self.stress;
        plan.scatter(
            grid,
            f,
            |n: &mut DVec3, h: &DVec3| *n += *h,
            |i, local, hood| {
                let s = stress[i];
                particles[i].0.for_each(local, |idx, _, g| {
                    hood[idx] += s * DVec3::new(g.x as f64, g.y as f64, g.z as f64);
                });
            },
        );
        if let Some(r) = self.ranks {
            r.sum_halo_vector(grid, f);
        }
        fold(f, self.ghosts);
    }
}

/// The ghost nodes of one periodic axis or one mirror face: (ghost, image) storage indices
/// and the factor between their vectors (ones on a periodic axis, the reflection of a mirror).
#[derive(Default)]
struct GhostSet {
    pairs: Vec<(usize, usize)>,
    factor: DVec3,
}

/// Adds ghost values onto their images (periodic axes x, y, z, then the mirror faces) and
/// zeroes the ghosts, as [`MpmGrid::fold_periodic`] and [`MpmGrid::fold_mirror`] (the normal
/// component on a mirror face is the constraint's, see [`classify`]).
fn fold(f: &mut [DVec3], ghosts: &[GhostSet]) {
    for set in ghosts {
        for &(g, i) in &set.pairs {
            let v = f[g];
            f[i] += set.factor * v;
            f[g] = DVec3::ZERO;
        }
    }
}

/// Copies images onto ghosts in the reverse order of [`fold`], as [`copy_ghosts`].
fn copy_to_ghosts(u: &mut [DVec3], ghosts: &[GhostSet]) {
    for set in ghosts.iter().rev() {
        for &(g, i) in &set.pairs {
            u[g] = set.factor * u[i];
        }
    }
}

impl LinearOperator for GridViscousOperator<'_> {
    fn dim(&self) -> usize {
        3 * self.dofs.len()
    }

    fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        for (d, dof) in self.dofs.iter().enumerate() {
            self.u_node[dof.node] = DVec3::new(x[3 * d], x[3 * d + 1], x[3 * d + 2]);
        }
        if self.project_input {
            for c in self.constraints {
                let n = self.dofs[c.dof].node;
                self.u_node[n] = c.free * self.u_node[n];
            }
        }
        if let Some(r) = self.ranks {
            r.copy_counted_vector(self.grid, self.u_node);
        }
        copy_to_ghosts(self.u_node, self.ghosts);
        self.viscous_force();
        for (d, dof) in self.dofs.iter().enumerate() {
            let r = if dof.counted {
                dof.mass * self.u_node[dof.node] + self.theta * self.f_node[dof.node]
            } else {
                DVec3::ZERO
            };
            y[3 * d..3 * d + 3].copy_from_slice(&r.to_array());
        }
        for c in self.constraints {
            let r = c.free * DVec3::from_slice(&y[3 * c.dof..3 * c.dof + 3]);
            y[3 * c.dof..3 * c.dof + 3].copy_from_slice(&r.to_array());
        }
    }
}

/// The boundary constraint of a node from the walls and colliders that contain it (module
/// docs of [`crate::step::implicit`]), or `None` if it is free. `v_pred` is the predicted
/// end-of-step velocity, `unknown_of` maps a wall velocity to the unknown. On a mirror face
/// (`mirrored[axis][upper]`, §2.11 D18) the normal component is always constrained, as the
/// mirror's symmetry imposes.
#[allow(clippy::too_many_arguments)]
pub(crate) fn classify(
    x: Vec3,
    walls: &DomainWalls,
    mirrored: [[bool; 2]; 3],
    domain_min: Vec3,
    domain_max: Vec3,
    colliders: &[ColliderInstance],
    v_pred: DVec3,
    unknown_of: impl Fn(DVec3) -> DVec3,
) -> Option<(DMat3, DVec3)> {
    let mut normals: [(DVec3, f64); 3] = [(DVec3::ZERO, 0.0); 3];
    let mut count = 0usize;
    let mut fixed = DVec3::ZERO;
    let mut add = |n: Vec3, v_wall: Vec3, bc: BoundaryCondition, always: bool| -> bool {
        let n = n.as_dvec3();
        let vw = v_wall.as_dvec3();
        match bc {
            BoundaryCondition::Open | BoundaryCondition::Periodic => false,
            BoundaryCondition::Sticky => {
                fixed = unknown_of(vw);
                true
            }
            BoundaryCondition::Slip | BoundaryCondition::Friction(_) => {
                if (!always && (v_pred - vw).dot(n) >= 0.0) || count == 3 {
                    return false;
                }
                // n·u = n·U(v_wall), orthonormalised against the earlier constraints.
                let s = n.dot(unknown_of(vw));
                let mut r = n;
                let mut rhs = s;
                for &(e, se) in &normals[..count] {
                    let k = n.dot(e);
                    r -= k * e;
                    rhs -= k * se;
                }
                let len = r.length();
                if len > 1e-6 {
                    normals[count] = (r / len, rhs / len);
                    count += 1;
                }
                false
            }
        }
    };
    let mut sticky = false;
    for axis in 0..3 {
        for upper in [false, true] {
            let bc = walls.face(axis, upper);
            let (bound, phi, n) = if upper {
                (
                    domain_max[axis],
                    domain_max[axis] - x[axis],
                    -Vec3::AXES[axis],
                )
            } else {
                (
                    domain_min[axis],
                    x[axis] - domain_min[axis],
                    Vec3::AXES[axis],
                )
            };
            if crate::step::grid_update::on_or_beyond_face(phi, x[axis], bound) && !sticky {
                sticky = add(n, Vec3::ZERO, bc, mirrored[axis][upper as usize]);
            }
        }
    }
    for c in colliders {
        if sticky {
            break;
        }
        let (phi, n, vw) = c.query(x);
        if phi <= 0.0 {
            sticky = add(n, vw, c.boundary, false);
        }
    }
    if sticky {
        return Some((DMat3::ZERO, fixed));
    }
    if count == 0 {
        return None;
    }
    let mut free = DMat3::IDENTITY;
    let mut part = DVec3::ZERO;
    for &(e, s) in &normals[..count] {
        free -= outer(e, e);
        part += s * e;
    }
    Some((free, part))
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// Ghost/image pairs of the active box per periodic axis (same rule as the grid's folds).
fn ghost_pairs(
    grid: &MpmGrid,
    periodic: [bool; 3],
    counts: [i32; 3],
    mirrors: &[MirrorFace],
    out: &mut Vec<GhostSet>,
) {
    out.resize_with(3 + mirrors.len(), GhostSet::default);
    for (face, set) in mirrors.iter().zip(&mut out[3..]) {
        set.pairs.clear();
        set.factor = DVec3::ONE;
        set.factor[face.axis] = -1.0;
        grid.for_each_mirror_node(face, |g, i| {
            if let Some(i) = i {
                set.pairs.push((g, i));
            }
        });
    }
    for (axis, set) in out[..3].iter_mut().enumerate() {
        set.factor = DVec3::ONE;
        set.pairs.clear();
        if periodic[axis] {
            grid.periodic_pairs(axis, counts[axis], &mut set.pairs);
        }
    }
}

/// S11 of the implicit schemes: builds and solves (M + θK)u = M(û + θ(f/m + g′)) on the active
/// nodes, then writes vᵢⁿ⁺¹, aᵢⁿ⁺¹ (with collisions) like the explicit grid update. Runs in
/// `MpmSystems::GridUpdate` instead of the explicit update when
/// [`implicit_viscosity_step`](super::implicit_viscosity_step) holds.
///
/// **Transfer-consistent GS4 predictor.** With [`FlipUpdate::ParticleGs4`] the particle update
/// is GS4-II on the particle ODE v̇ₚ = Σ w̃ᵢₚRᵢ (R = f/m + g on the grid). Its implicit
/// evaluation point is P(v̂ₚ + W₂Λ₅Δt Δaₚ) = v̂ + θ(PW R − a) with a = P aₚ, whereas the grid
/// balance gives u = v̂ + θ(R − a): the lumped-mass transfer P W ≠ I shifts the point by
/// θ(I − PW)R = O(Δt), which made the scheme first order in time (measured: 0.9–1.1 on the
/// shear layer; so did the first correction tried, θ(I − PW)a, since a = P aₚ itself tracks
/// PW R, not R). We subtract θD with D = (I − PW)R⁰, R⁰ = (f − K v̂)/m + g the rate at the
/// predictor: the remaining shift θ(I − PW)(R − R⁰) is O(Δt²). Cost per step: one operator
/// application and one transfer round trip. The correction is explicit in R⁰ and runs only
/// while θ·8ν_max/Δx² ≤ [`crate::gs4::TRANSFER_CORRECTION_MAX_STIFFNESS`]: at 20× the
/// explicit viscous limit it blew the syrup cube up (`tests/it/integrators.rs`); larger steps take
/// the uncorrected first-order update. Off for backward Euler (first order anyway) and
/// for [`FlipUpdate::GridIncrement`] (first order in its particle update).
///
/// Reads `MpmGrid` (mass, velocity, acceleration, force), the particles' stencils, masses,
/// densities and materials, colliders; writes `MpmGrid` (new velocity, new acceleration),
/// [`ImplicitSolveStats`]; records a failure if CG fails.
#[allow(clippy::too_many_arguments)]
pub fn implicit_viscous_update(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    gs4: Res<Gs4Constants>,
    materials: Res<Materials>,
    colliders: Res<ActiveColliders>,
    failures: Res<FailureCollector>,
    mut grid: ResMut<MpmGrid>,
    mut plan: ResMut<BlockPlan>,
    mut scratch: ResMut<ViscousSolveScratch>,
    mut stats: ResMut<ImplicitSolveStats>,
    q: Query<(&ParticleStencil, &Mass, &PredictedDensity, &MaterialId), With<Particle>>,
    ranks: Option<Res<Ranks>>,
) {
    let ranks = ranks.as_deref().filter(|r| r.size() > 1);
    let reduce = RankReduction(ranks);
    let shared = ranks.map(|r| r.shared_columns(&grid));
    let shared = shared.as_ref();
    let step = ImplicitStep::new(config.integrator.scheme, &gs4.params, ctx.dt);
    let grid = &mut *grid;
    let layout = grid.layout;
    let items: Vec<_> = q.iter().collect();
    // The P2G plan of this step, rebuilt only if the particle set changed since.
    plan.build(&layout, items.iter().map(|it| it.0.base));
    let plan: &BlockPlan = &plan;
    let ViscousSolveScratch {
        particles,
        stress,
        dofs,
        u_hat,
        constraints,
        ghosts,
        u_node,
        f_node,
        b,
        x,
        tmp,
        predicted,
        jacobi,
        cg,
    } = &mut *scratch;
    particles.clear();
    particles.extend(items.iter().map(|(st, m, rho, mat)| {
        let mat = materials.get(**mat);
        let mu = mat.local_fraction * mat.viscosity;
        (
            st.stencil(&layout),
            2.0 * mu as f64 * (m.0 / rho.value) as f64,
        )
    }));
    stress.resize(particles.len(), DMat3::ZERO);
    // Node-sized work arrays over the allocated blocks (zero).
    let node_count = grid.nodes.len();
    u_node.clear();
    u_node.resize(node_count, DVec3::ZERO);
    f_node.clear();
    f_node.resize(node_count, DVec3::ZERO);

    // Unknowns: active canonical nodes.
    let periodic = config.walls.periodic_axes();
    let counts = periodic_counts(&config, grid);
    let g = config.gravity.as_dvec3();
    let mirrors = mirror_faces(&config, &layout);
    collect_unknowns(grid, periodic, counts, &mirrors, ranks, dofs);
    ghost_pairs(grid, periodic, counts, &mirrors, ghosts);
    let mut mirrored = [[false; 2]; 3];
    for f in &mirrors {
        mirrored[f.axis][f.upper as usize] = true;
    }
    let n = dofs.len();
    let theta = step.theta;
    let force = |dof: &Dof| Vec3::from(grid.nodes[dof.node].force).as_dvec3();

    // Predictor û (with the transfer-consistent correction, see the docs above).
    u_hat.clear();
    u_hat.extend(
        dofs.iter()
            .map(|d| step.predictor(d.v, d.a, DVec3::ZERO, g).0),
    );
    // The correction is explicit in R⁰: only while θ·8ν_max/Δx² is small (see
    // TRANSFER_CORRECTION_MAX_STIFFNESS).
    let nonstiff = || {
        let nu_max = items
            .iter()
            .map(|(_, _, rho, mat)| {
                let mat = materials.get(**mat);
                (mat.local_fraction * mat.viscosity / rho.value) as f64
            })
            .fold(0.0, f64::max);
        // Every rank takes the same branch (it holds collectives).
        let nu_max = reduce.max(nu_max);
        let dx = layout.dx as f64;
        theta * 8.0 * nu_max / (dx * dx) <= crate::gs4::TRANSFER_CORRECTION_MAX_STIFFNESS
    };
    if step.is_gs4() && config.integrator.flip_update == FlipUpdate::ParticleGs4 && nonstiff() {
        // R⁰ = (f − K v̂)/m + g on the unknowns, then into u_node (ghosts copied).
        let mut op = GridViscousOperator {
            grid,
            plan,
            particles,
            dofs,
            constraints: &[],
            ghosts,
            theta,
            u_node,
            f_node,
            stress,
            project_input: false,
            ranks: shared,
        };
        for (dof, uh) in op.dofs.iter().zip(u_hat.iter()) {
            op.u_node[dof.node] = *uh;
        }
        copy_to_ghosts(op.u_node, op.ghosts);
        op.viscous_force();
        for dof in op.dofs {
            op.u_node[dof.node] = (force(dof) - op.f_node[dof.node]) / dof.mass + g;
        }
        copy_to_ghosts(op.u_node, op.ghosts);
        // (PW R⁰)ᵢ = Σₚ mₚ w̃ᵢₚ (Σⱼ w̃ⱼₚ R⁰ⱼ) / m̃ᵢ.
        // The stencils expanded once above, in the order of `items`.
        let stencils = op.particles;
        let mut mrp = Vec::new();
        plan.gather_into(grid, op.u_node, &mut mrp, |i, local, r0| {
            let mut rp = DVec3::ZERO;
            stencils[i]
                .0
                .for_each_weight(local, |idx, w| rp += (w as f64) * r0[idx]);
            (items[i].1.0 as f64) * rp
        });
        let f = &mut *op.f_node;
        f.fill(DVec3::ZERO);
        plan.scatter(
            grid,
            f,
            |n: &mut DVec3, h: &DVec3| *n += *h,
            |i, local, hood| {
                let mrp = mrp[i];
                stencils[i]
                    .0
                    .for_each_weight(local, |idx, w| hood[idx] += (w as f64) * mrp);
            },
        );
        if let Some(r) = shared {
            r.sum_halo_vector(grid, f);
        }
        fold(f, ghosts);
        for (dof, uh) in dofs.iter().zip(u_hat.iter_mut()) {
            let d = u_node[dof.node] - f_node[dof.node] / dof.mass;
            *uh = step.predictor(dof.v, dof.a, d, g).0;
        }
        clear_unknowns(u_node, dofs, ghosts);
    }

    // Right-hand side, inviscid prediction, constraints.
    let walls = config.walls;
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    b.clear();
    x.clear();
    predicted.clear();
    constraints.clear();
    for (d, (dof, &uh)) in dofs.iter().zip(u_hat.iter()).enumerate() {
        let f = force(dof);
        let g_prime = step.predictor(dof.v, dof.a, DVec3::ZERO, g).1;
        let u_pred = uh + theta * (f / dof.mass + g_prime);
        let rhs = dof.mass * uh + theta * (f + dof.mass * g_prime);
        b.extend_from_slice(&rhs.to_array());
        x.extend_from_slice(&u_pred.to_array());
        let (v_end, _) = step.finish(u_pred, uh, dof.v, dof.a);
        predicted.push(v_end);
        if let Some((free, fixed)) = classify(
            dof.position,
            &walls,
            mirrored,
            dmin,
            dmax,
            &colliders.list,
            v_end,
            |vw| step.unknown_of_velocity(vw, uh, dof.v, dof.a),
        ) {
            constraints.push(Constraint {
                dof: d,
                free,
                fixed,
            });
        }
    }

    jacobi_diagonal(
        grid, plan, particles, ghosts, dofs, theta, f_node, jacobi, shared,
    );

    let mut op = GridViscousOperator {
        grid,
        plan,
        particles,
        dofs,
        constraints,
        ghosts,
        theta,
        u_node,
        f_node,
        stress,
        project_input: false,
        ranks: shared,
    };
    // u₀ = P u* + u_f satisfies the constraints; r₀ = P(b − A u₀) costs one application; CG
    // then solves P A P δ = r₀ from δ = 0 (no further application) and stops at
    // ‖r‖₂ ≤ max(abs_tol, rel_tol‖P b‖₂), the documented criterion of `viscous_solver`.
    for c in constraints.iter() {
        let xd = c.free * DVec3::from_slice(&x[3 * c.dof..3 * c.dof + 3]) + c.fixed;
        x[3 * c.dof..3 * c.dof + 3].copy_from_slice(&xd.to_array());
        let bd = c.free * DVec3::from_slice(&b[3 * c.dof..3 * c.dof + 3]);
        b[3 * c.dof..3 * c.dof + 3].copy_from_slice(&bd.to_array());
    }
    // On ranks, a shared node's entries live on the rank that counts it (module docs).
    for (d, dof) in dofs.iter().enumerate() {
        if !dof.counted {
            b[3 * d..3 * d + 3].fill(0.0);
        }
    }
    let b_norm = ResidualNorm::Euclidean.reduced(b, &reduce);
    tmp.clear();
    tmp.resize(3 * n, 0.0);
    op.apply(x, tmp);
    for (b, t) in b.iter_mut().zip(tmp.iter()) {
        *b -= t;
    }
    for c in constraints.iter() {
        let r = c.free * DVec3::from_slice(&b[3 * c.dof..3 * c.dof + 3]);
        b[3 * c.dof..3 * c.dof + 3].copy_from_slice(&r.to_array());
    }
    op.project_input = true;
    let params = config.integrator.viscous_solver;
    let mut tol = params.abs_tol.max(params.rel_tol * b_norm);
    if tol == 0.0 {
        // P b = 0 (nothing moves, no force): relative to the initial residual instead.
        tol = params.rel_tol * ResidualNorm::Euclidean.reduced(b, &reduce);
    }
    let inner = CgParams {
        rel_tol: 0.0,
        abs_tol: tol,
        max_iters: params.max_iters,
    };
    tmp.fill(0.0);
    let result = conjugate_gradient_reduced(
        &mut op,
        jacobi,
        b,
        tmp,
        &inner,
        ResidualNorm::Euclidean,
        cg,
        &reduce,
    );
    if tmp.iter().all(|v| v.is_finite()) {
        for (x, d) in x.iter_mut().zip(tmp.iter()) {
            *x += d;
        }
    }
    if let Some(r) = shared {
        // The counting rank's solution on the shared nodes, for both to write.
        for (d, dof) in dofs.iter().enumerate() {
            u_node[dof.node] = DVec3::from_slice(&x[3 * d..3 * d + 3]);
        }
        r.copy_counted_vector(grid, u_node);
        for (d, dof) in dofs.iter().enumerate() {
            x[3 * d..3 * d + 3].copy_from_slice(&u_node[dof.node].to_array());
        }
    }
    let (info, error) = CgInfo::of_result(result, b_norm);
    if let Some(e) = error {
        let (iterations, rel) = (info.iterations, info.rel_residual);
        let what = match e {
            CgError::NoConvergence { .. } => format!(
                "the relative residual stayed above rel_tol = {:.1e}",
                params.rel_tol
            ),
            other => other.to_string(),
        };
        failures.record(FailureReport::global(
            "viscous solve",
            rel,
            format!(
                "the implicit viscous solve ({}, {} unknowns) failed after {iterations} \
                 conjugate-gradient iterations (relative residual {rel:.3e}): {what}. To \
                 fix: raise integrator.viscous_solver.max_iters (now {}) or rel_tol, or take \
                 smaller steps (time_step.safety, max_dt); a non-positive-definite operator \
                 or a non-finite number means the state is already corrupt",
                step.scheme,
                3 * n,
                params.max_iters,
            ),
        ));
        if x.iter().any(|v| !v.is_finite()) {
            // Fall back to the inviscid prediction so no NaN reaches the particles.
            for (d, p) in predicted.iter().enumerate() {
                let dof = dofs[d];
                let u = step.unknown_of_velocity(*p, u_hat[d], dof.v, dof.a);
                x[3 * d..3 * d + 3].copy_from_slice(&u.to_array());
            }
        }
    }
    stats.solves += 1;
    stats.iterations += info.iterations as u64;
    stats.max_iterations = stats.max_iterations.max(info.iterations);
    stats.unknowns = 3 * n;
    stats.last = info;

    write_velocities(
        grid,
        &step,
        &walls,
        (dmin, dmax),
        &colliders.list,
        dofs,
        constraints,
        x,
        u_hat,
        predicted,
    );
    // Leave the node-sized buffers zero outside the next step's unknowns.
    clear_unknowns(u_node, dofs, ghosts);
    copy_ghosts(&config, grid, GhostCopy::Update);
}

/// The unknowns of the solve: every active canonical node (periodic images and the nodes
/// beyond mirror faces excluded) with mass above the grid's m_ε, with its position, mass, vⁿ
/// and aⁿ.
fn collect_unknowns(
    grid: &MpmGrid,
    periodic: [bool; 3],
    counts: [i32; 3],
    mirrors: &[MirrorFace],
    ranks: Option<&Ranks>,
    dofs: &mut Vec<Dof>,
) {
    let layout = grid.layout;
    let eps = grid.mass_epsilon;
    dofs.clear();
    for (idx, n) in grid.nodes.iter().enumerate() {
        if n.mass <= eps {
            continue;
        }
        let c = grid.node_of_index(idx);
        if (0..3).any(|a| periodic[a] && (c[a] < 0 || c[a] >= counts[a]))
            || mirrors.iter().any(|f| f.beyond(c[f.axis]))
        {
            continue;
        }
        dofs.push(Dof {
            node: idx,
            position: layout.node_position(c),
            mass: n.mass as f64,
            v: Vec3::from(n.velocity).as_dvec3(),
            a: Vec3::from(n.acceleration).as_dvec3(),
            counted: ranks.is_none_or(|r| r.counts_node(&layout, c)),
        });
    }
}

/// Jacobi diagonal: m̃ᵢ + θ·⅔ Σₚ 2F_vμṼ |∇w̃ᵢₚ|² (the mean of the three component diagonals
/// Σ F_vμṼ(|∇w|² + (∂_c w)²) of K; one scalar per node so it commutes with the projection).
#[allow(clippy::too_many_arguments)]
fn jacobi_diagonal(
    grid: &MpmGrid,
    plan: &BlockPlan,
    particles: &[(Stencil, f64)],
    ghosts: &[GhostSet],
    dofs: &[Dof],
    theta: f64,
    f: &mut [DVec3],
    jacobi: &mut JacobiPreconditioner,
    ranks: Option<&SharedColumns>,
) {
    f.fill(DVec3::ZERO);
    plan.scatter(
        grid,
        f,
        |n: &mut DVec3, h: &DVec3| *n += *h,
        |i, local, hood| {
            let (st, c) = &particles[i];
            st.for_each(local, |idx, _, g| {
                hood[idx].x += (2.0 / 3.0) * c * (g.length_squared() as f64);
            });
        },
    );
    if let Some(r) = ranks {
        r.sum_halo_vector(grid, f);
    }
    fold(f, ghosts);
    jacobi.inverse_diagonal.clear();
    for dof in dofs.iter() {
        let inv = 1.0 / (dof.mass + theta * f[dof.node].x);
        jacobi.inverse_diagonal.extend_from_slice(&[inv; 3]);
    }
}

/// u = P x + u_f → vⁿ⁺¹, aⁿ⁺¹; then the collision operator with the predicted normal
/// velocity restored on constrained components (friction, D5 projection of a).
#[allow(clippy::too_many_arguments)]
fn write_velocities(
    grid: &mut MpmGrid,
    step: &ImplicitStep,
    walls: &DomainWalls,
    domain: (Vec3, Vec3),
    colliders: &[ColliderInstance],
    dofs: &[Dof],
    constraints: &[Constraint],
    x: &[f64],
    u_hat: &[DVec3],
    predicted: &[DVec3],
) {
    let (dmin, dmax) = domain;
    let extra_dt = step.extra_dt();
    let mut next_constraint = constraints.iter().peekable();
    for (d, dof) in dofs.iter().enumerate() {
        let mut u = DVec3::from_slice(&x[3 * d..3 * d + 3]);
        let mut restore = DMat3::ZERO;
        if let Some(c) = next_constraint.next_if(|c| c.dof == d) {
            u = c.free * u + c.fixed;
            restore = DMat3::IDENTITY - c.free;
        }
        let (v_end, a_end) = step.finish(u, u_hat[d], dof.v, dof.a);
        let mut v = (v_end + restore * (predicted[d] - v_end)).as_vec3();
        let mut a = a_end.as_vec3();
        collide_node(
            dof.position,
            extra_dt,
            walls,
            dmin,
            dmax,
            colliders,
            &mut v,
            &mut a,
        );
        let node = &mut grid.nodes[dof.node];
        node.new_velocity = v.into();
        node.new_acceleration = a.into();
    }
}

/// Zeroes the node-sized buffer `u` on the unknowns and their periodic and mirror ghosts (the only
/// entries the solve writes), so it is zero elsewhere for the next use.
fn clear_unknowns(u: &mut [DVec3], dofs: &[Dof], ghosts: &[GhostSet]) {
    for dof in dofs {
        u[dof.node] = DVec3::ZERO;
    }
    for set in ghosts {
        for &(gn, _) in &set.pairs {
            u[gn] = DVec3::ZERO;
        }
    }
}
