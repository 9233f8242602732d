//! S1: particle predictors at t_{n+W₁} (ALGORITHM §2.4, eq. 30):
//! x̃ₚ = xₚ + W₁Λ₁Δt vₚ + W₂Λ₂Δt² aₚ. (v̂ₚ is not stored: P2G transfers v and a separately and
//! forms ṽᵢ = vᵢ + W₁Λ₄Δt aᵢ on the grid, which equals the rasterised v̂ₚ, §2.5.)
//!
//! Reads `Position`, `Velocity`, `Acceleration`; writes `PredictedPosition` and the weights
//! `ParticleStencil`.
use bevy_ecs::prelude::*;

use crate::components::{
    Acceleration, Particle, ParticleStencil, Position, PredictedPosition, Velocity,
};
use crate::grid::MpmGrid;
use crate::kernels::Stencil;
use crate::schedule::StepContext;

/// Computes x̃ₚ and its B-spline weights for every particle.
pub fn predict_positions(
    ctx: Res<StepContext>,
    grid: Res<MpmGrid>,
    mut q: Query<
        (
            &Position,
            &Velocity,
            &Acceleration,
            &mut PredictedPosition,
            &mut ParticleStencil,
        ),
        With<Particle>,
    >,
) {
    let c = ctx.coefficients;
    let sv = c.w1l1 * c.dt;
    let sa = c.w2l2 * c.dt * c.dt;
    let layout = grid.layout;
    q.par_iter_mut().for_each(|(x, v, a, mut xt, mut st)| {
        let p = x.0 + sv * v.0 + sa * a.0;
        xt.bypass_change_detection().0 = p;
        st.bypass_change_detection().0 = Stencil::new(&layout, p);
    });
}
