//! Implicit viscosity on the MPM grid: the velocity form of ALGORITHM §5.2, matrix-free,
//! solved by Jacobi-preconditioned conjugate gradients ([`crate::krylov`]).
//!
//! # The system
//!
//! With the local (Newtonian) viscous stress σᴸ = 2F_vμ D(v) moved out of the explicit stress,
//! the grid momentum balance of one step becomes, for both implicit schemes,
//!
//! (M + θK) u = M û + θ (f + M g′),   K u = Dᵀ(2μ)D u,  (K u)ᵢ = Σₚ Ṽₚ 2F_vμₚ sym(Σⱼ uⱼ ⊗ ∇w̃ⱼₚ) ∇w̃ᵢₚ,
//!
//! with M = diag(m̃ᵢ), f the explicit internal force (pressure and rheology-model stresses) and
//! the same weights as the explicit force (ALGORITHM §2.9). Per scheme:
//!
//! | scheme | unknown u | θ | û | g′ | afterwards |
//! |---|---|---|---|---|---|
//! | [`BackwardEulerViscous`](crate::config::Scheme::BackwardEulerViscous) | vⁿ⁺¹ | Δt | vⁿ | g | aⁿ⁺¹ = (vⁿ⁺¹ − vⁿ)/Δt |
//! | [`Gs4SemiImplicit`](crate::config::Scheme::Gs4SemiImplicit) | ṽ (at t_{n+W₁}) | W₂Λ₅Δt/W₁Λ₆ | v̂ = vⁿ + W₁Λ₄Δt aⁿ (− θD, below) | g − aⁿ | Δa = (ṽ − û)/(W₂Λ₅Δt), eq. (38) |
//!
//! BE is \[Su21\] eq. (17) with the stresses eliminated (§5.2: ρ/Δt M + Dᵀ2μD). For GS4, §5.2
//! writes the η = 1 system in Δu̇ = Δa: \[b M + a K\] Δa = M(g − aⁿ) + f − K v̂ with a = W₂Λ₅Δt,
//! b = W₁Λ₆ (the viscous force evaluated at ṽ = v̂ + aΔa); substituting u = ṽ and dividing by
//! b gives the row above, so both schemes share one operator. The GS4 form reduces to
//! ρ/Δt → ρW₁Λ₆/(W₂Λ₅Δt), i.e. 2ρ/Δt for (1, 1) and 3ρ/(2Δt) for (0, 0), as §5.2 says.
//! A is symmetric positive definite on the active nodes (m̃ᵢ > m_ε).
//!
//! # Temporal order
//!
//! Backward Euler is first order. The GS4 solve is second order at the particle level only
//! with [`FlipUpdate::ParticleGs4`](crate::config::FlipUpdate::ParticleGs4), and then only
//! with the transfer-consistent predictor û = v̂ − θD of [`implicit_viscous_update`]
//! (D = (I − PW)R⁰ corrects for the lumped-mass transfer P W ≠ I; without it the order drops
//! to one). With the `GridIncrement` FLIP update both GS4 schemes are first order in
//! time (`tests/it/integrators.rs` measures all of these on the shear layer).
//!
//! # Boundary conditions (implicit MPM projection)
//!
//! Before the solve, every active node inside a domain wall or collider is classified with the
//! inviscid prediction u* = û + θ(f/m + g′) (the end-of-step velocity it implies):
//! `Sticky` fixes all three components to the wall velocity; `Slip` and `Friction` fix the
//! normal component when the predicted relative normal velocity points into the wall (several
//! walls: their normals, orthonormalised). With P the projector on the free components and
//! u = P x + u_f, CG solves P A P x = P(b − A u_f). Afterwards the usual collision operator of
//! §2.11 ([`collide_node`](crate::step::grid_update::collide_node)) runs on every node, with the
//! predicted normal velocity restored on the constrained components, so that Coulomb friction
//! acts with the normal impulse of the contact and the acceleration is projected as in choice D5.
//!
//! # Stability
//!
//! The local viscosity then adds no time-step limit: the constitutive stage reports ν = 0 for
//! it, and the adaptive Δt of §2.15 keeps only the advection, sound (+ model viscosity) and
//! relaxation limits. The sound limit is that of the explicit part: Ω_crit = √2 for GS4
//! ((ρ∞, 0)), 2 for backward Euler (symplectic in the pressure).
//!
//! # Failure
//!
//! A solve that does not converge (or finds a non-positive curvature or a non-finite number)
//! stops the run through the usual [`FailureReport`](crate::failure::FailureReport): step,
//! iterations, residual and what to change. The grid still receives the last finite iterate, so
//! no NaN reaches the particles.
//!
//! # Determinism
//!
//! The particle passes of the operator are a parallel gather (independent per particle) and the
//! slab-coloured scatter of [`crate::scatter`]; periodic folds and all inner products run
//! serially in a fixed order. Results are bit-identical for any thread count.
pub mod pressure;
pub mod viscous;

use bevy_ecs::prelude::*;

use crate::config::{MpmConfig, Scheme};
use crate::krylov::CgInfo;
use crate::step::schedule::StepContext;

pub use pressure::{
    PressureScratch, PressureSolveStats, pressure_projection_step, project_pressure,
};
pub use viscous::{ViscousSolveScratch, implicit_viscous_update};

/// Statistics of the implicit viscous solves of a run (a Resource, reset by nobody: read the
/// difference between two moments for a window).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct ImplicitSolveStats {
    /// Solves done (one per implicit step).
    pub solves: u64,
    /// Total CG iterations over all solves.
    pub iterations: u64,
    /// Most iterations of one solve.
    pub max_iterations: usize,
    /// Unknowns (3 × active nodes) of the last solve.
    pub unknowns: usize,
    /// Result of the last solve.
    pub last: CgInfo,
}

impl ImplicitSolveStats {
    /// Mean CG iterations per solve (0 before the first).
    pub fn mean_iterations(&self) -> f64 {
        if self.solves == 0 {
            0.0
        } else {
            self.iterations as f64 / self.solves as f64
        }
    }
}

/// Run condition: an implicit-viscosity step (the start-up rate evaluation, at Δt = 0, runs the
/// explicit stages instead: with Δt = 0 the implicit system is M u = M û).
pub fn implicit_viscosity_step(config: Res<MpmConfig>, ctx: Res<StepContext>) -> bool {
    config.integrator.scheme.implicit_viscosity() && !ctx.rate_evaluation
}

/// Run condition: the explicit GS4 grid update runs (scheme [`Scheme::Gs4Explicit`], and the
/// rate evaluation of every scheme).
pub fn explicit_gs4_update(config: Res<MpmConfig>, ctx: Res<StepContext>) -> bool {
    config.integrator.scheme == Scheme::Gs4Explicit || ctx.rate_evaluation
}
