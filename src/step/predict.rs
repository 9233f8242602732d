//! S1: particle predictors at t_{n+W₁} (ALGORITHM §2.4, eq. 30):
//! x̃ₚ = xₚ + W₁Λ₁Δt vₚ + W₂Λ₂Δt² aₚ. (v̂ₚ is not stored: P2G transfers v and a separately and
//! forms ṽᵢ = vᵢ + W₁Λ₄Δt aᵢ on the grid, which equals the rasterised v̂ₚ, §2.5.)
//!
//! Reads `Position`, `Velocity`, `Acceleration`; writes `PredictedPosition`.
use bevy_ecs::prelude::*;

use crate::components::{Acceleration, Particle, Position, PredictedPosition, Velocity};
use crate::schedule::StepContext;

/// Computes x̃ₚ for every particle.
pub fn predict_positions(
    ctx: Res<StepContext>,
    mut q: Query<(&Position, &Velocity, &Acceleration, &mut PredictedPosition), With<Particle>>,
) {
    let c = ctx.coefficients;
    let sv = c.w1l1 * c.dt;
    let sa = c.w2l2 * c.dt * c.dt;
    q.par_iter_mut().for_each(|(x, v, a, mut xt)| {
        xt.bypass_change_detection().0 = x.0 + sv * v.0 + sa * a.0;
    });
}
