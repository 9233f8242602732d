//! S1: particle predictors at t_{n+W₁} (ALGORITHM §2.4, eq. 30):
//! x̃ₚ = xₚ + W₁Λ₁Δt vₚ + W₂Λ₂Δt² aₚ. (v̂ₚ is not stored: P2G transfers v and a separately and
//! forms ṽᵢ = vᵢ + W₁Λ₄Δt aᵢ on the grid, which equals the rasterised v̂ₚ, §2.5.)
//!
//! Reads `Position`, `Velocity`, `Acceleration`; writes where the stencil of the predicted
//! position sits, `ParticleStencil`. A predictor more than [`BLOWUP_CELLS`]·Δx from its particle is a
//! failure: its stencil no longer overlaps the particle's, so the transfers would
//! silently lose the motion (an extreme gravity or force froze the liquid that way).
use bevy_ecs::prelude::*;

use crate::collision::{
    Collider, ColliderInstance, ColliderMotion, ColliderPath, ColliderPose, CoupledCollider,
};
use crate::components::{Acceleration, Particle, ParticleStencil, Position, Velocity};
use crate::failure::{FailureCollector, FailureReport};
use crate::grid::MpmGrid;
use crate::math::Real;
use crate::step::commit::advance_pose;
use crate::step::monitor::BLOWUP_CELLS;
use crate::step::schedule::{ActiveColliders, SimulationClock, StepContext};

/// Computes x̃ₚ and its B-spline weights for every particle.
pub fn predict_positions(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    failures: Res<FailureCollector>,
    mut q: Query<
        (
            Entity,
            &Position,
            &Velocity,
            &Acceleration,
            &mut ParticleStencil,
        ),
        With<Particle>,
    >,
) {
    let c = ctx.coefficients;
    let sv = c.w1l1 * c.dt;
    let sa = c.w2l2 * c.dt * c.dt;
    let layout = grid.layout;
    let reach_sq = (BLOWUP_CELLS * layout.dx).powi(2);
    let failures = &*failures;
    q.par_iter_mut().for_each(|(e, x, v, a, mut st)| {
        let p = x.0 + sv * v.0 + sa * a.0;
        let jump_sq = (p - x.0).length_squared();
        // Non-finite values are the monitor's (it names the component).
        if jump_sq.is_finite() && jump_sq > reach_sq {
            failures.record(FailureReport::particle(
                e,
                "predicted position",
                jump_sq.sqrt() as f64,
                "blow-up: the predictor x + W₁Λ₁Δt v + W₂Λ₂Δt² a moved more than 2Δx from the \
                 particle (the acceleration is too large for Δt)",
            ));
        }
        *st.bypass_change_detection() = ParticleStencil::at(&layout, p);
    });
}

/// Moves every collider with a [`ColliderPath`] onto its path at the step's start and gives it
/// the mean velocity over the step (in the start-up rate evaluation, Δt = 0: the velocity of
/// the path just after t_n). Runs before the colliders are gathered (`PredictSystems::Core`).
pub fn follow_collider_paths(
    ctx: Res<StepContext>,
    clock: Res<SimulationClock>,
    mut q: Query<(&ColliderPath, &mut ColliderPose, &mut ColliderMotion)>,
) {
    let t = clock.time;
    let dt = if ctx.dt > 0.0 { ctx.dt } else { 1e-6 };
    for (path, mut pose, mut motion) in &mut q {
        let x0 = path.at(t);
        let v = (path.at(t + dt) - x0) / dt as Real;
        if pose.translation != x0 {
            pose.translation = x0;
        }
        if motion.linear_velocity != v {
            motion.linear_velocity = v;
        }
    }
}

/// Gathers colliders (pose advanced to t_{n+1} for moving ones). Colliders a plugin couples
/// ([`CoupledCollider`], e.g. dynamic rigid bodies) are not among them.
pub fn gather_colliders(
    ctx: Res<StepContext>,
    mut active: ResMut<ActiveColliders>,
    q: Query<(&Collider, &ColliderPose, Option<&ColliderMotion>), Without<CoupledCollider>>,
) {
    let dt = ctx.coefficients.dt;
    active.list.clear();
    for (c, pose, motion) in &q {
        let motion = motion.copied().unwrap_or_default();
        active.list.push(ColliderInstance {
            shape: c.shape.clone(),
            boundary: c.boundary,
            pose: advance_pose(*pose, &motion, dt),
            motion,
        });
    }
}
