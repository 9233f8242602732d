//! The first-order schemes' own stages: [`Scheme::SymplecticEuler`] and the frame of
//! [`Scheme::BackwardEulerViscous`] (whose grid update is the implicit solve of
//! [`crate::step::implicit`]).
//!
//! The standard MPM step that users of other MPM codes know (e.g. Stomakhin et al. 2013, the
//! Taichi `mpm88` example), written with the GS4 stages of this crate and
//! [`first_order_coefficients`] (W₁Λ₁ = W₁Λ₄ = W₂Λ₂ = W₂Λ₅ = 0, W₁Λ₆ = λ₄ = λ₅ = 1):
//!
//! | set | system | what it computes |
//! |---|---|---|
//! | `Predict` | `predict_positions` (shared) | x̃ₚ = xₚⁿ: weights at the current positions |
//! | `ParticleToGrid` | `particle_to_grid` (shared) | mᵢ, vᵢⁿ = Σ mₚwᵢₚvₚ/mᵢ |
//! | `Kinematics` | shared | Lₚⁿ = Σ vᵢⁿ ⊗ ∇wᵢₚ, F̃ₚ = Fₚⁿ (with [`VelocityGradientSource::Carried`]: Lₚⁿ from the last G2P, no gather) |
//! | `Constitutive` | shared | ρ̃ₚ = ρₚⁿ, p(ρₚⁿ), σₚ = −p I + 2F_vμ Dₚⁿ (no viscous term for BE) |
//! | `GridForces` | shared | fᵢ = −Σ Vₚ σₚ ∇wᵢₚ |
//! | `GridUpdate` | [`grid_update`] (SE) / [`crate::step::implicit`] (BE) | vᵢⁿ⁺¹ = vᵢⁿ + Δt (fᵢ/mᵢ + g), then collisions |
//! | `GridToParticle` | [`grid_to_particle`] | PIC/FLIP velocity, xₚⁿ⁺¹ = xₚⁿ + Δt Σ wᵢₚvᵢⁿ⁺¹, Lₚⁿ⁺¹ (stored when carried), Fₚⁿ⁺¹ = (I + ΔtLₚⁿ⁺¹)Fₚⁿ, ρₚⁿ⁺¹ |
//! | `Commit` | shared, without the GS4 density commit | particle collisions, model state |
//!
//! **Density (first-order form).** ρₚⁿ⁺¹ = ρₚⁿ / (1 + Δt tr Lₚⁿ⁺¹): the determinant update
//! Jⁿ⁺¹ = (1 + Δt tr C)Jⁿ of standard MPM (mpm88's `J *= 1 + dt * C.trace()`) written for ρ = ρ₀/J,
//! the first-order counterpart of the GS4 continuity update of ALGORITHM §2.6. The new velocity
//! makes it symplectic: pressure from ρⁿ drives vⁿ⁺¹, and vⁿ⁺¹ updates ρ and x, which is stable
//! for ωΔt < 2 (Ω_crit = 2, against √2 for explicit GS4 with ρs = 0). The stored rate is
//! ρ̇ = (ρⁿ⁺¹ − ρⁿ)/Δt.
//!
//! **Acceleration.** The scheme does not use the particle acceleration; `Acceleration` receives
//! the PIC value Σ wᵢₚ(fᵢ/mᵢ + g) for output (and for a later switch back to GS4).
use bevy_ecs::prelude::*;
use glam::IVec3;
use glam::{Mat3A, Vec3A};

use crate::components::{
    Acceleration, DeformationGradient, Density, Particle, ParticleStencil, Position, Velocity,
    VelocityGradient,
};
use crate::config::{MpmConfig, Scheme, VelocityGradientSource};
use crate::failure::{FailureCollector, FailureReport};
use crate::grid::{GhostCopy, GridLayout, GridNode, MpmGrid};
use crate::kernels::{Stencil, StepCoefficients, add_row_gradient, row_sum};
use crate::math::{Mat3, Real, Vec3};
use crate::scatter::{BlockPlan, GatherScratch, SharedMut};
use crate::step::grid_update::{collide_node, for_each_active_row_indexed};
use crate::step::schedule::{ActiveColliders, StepContext};

/// The step coefficients of the first-order schemes: predictors off (x̃ = x, ṽ = v, ρ̃ = ρ),
/// unit effective mass, λ₄ = λ₅ = 1.
pub fn first_order_coefficients(dt: f64, flip: Real) -> StepCoefficients {
    StepCoefficients {
        dt: dt as Real,
        w1l1: 0.0,
        w1l4: 0.0,
        w1l6: 1.0,
        w2l2: 0.0,
        w2l5: 0.0,
        l4: 1.0,
        l5: 1.0,
        flip_velocity: flip,
        flip_acceleration: flip,
    }
}

/// Run condition: the step is a [`Scheme::SymplecticEuler`] step (not the start-up rate
/// evaluation, which every scheme runs through the explicit GS4 stages).
pub fn symplectic_euler_step(config: Res<MpmConfig>, ctx: Res<StepContext>) -> bool {
    config.integrator.scheme == Scheme::SymplecticEuler && !ctx.rate_evaluation
}

/// Run condition: a first-order step (symplectic or backward Euler), not the rate evaluation.
pub fn first_order_step(config: Res<MpmConfig>, ctx: Res<StepContext>) -> bool {
    !config.integrator.scheme.is_gs4() && !ctx.rate_evaluation
}

/// Run condition: the particles are updated by the GS4 stages (GS4 schemes, and the start-up
/// rate evaluation of every scheme).
pub fn gs4_transfer(config: Res<MpmConfig>, ctx: Res<StepContext>) -> bool {
    config.integrator.scheme.is_gs4() || ctx.rate_evaluation
}

/// Explicit grid update of symplectic Euler: aᵢ = fᵢ/mᵢ + g, vᵢⁿ⁺¹ = vᵢⁿ + Δt aᵢ, then the
/// collision projection of ALGORITHM §2.11 on vᵢⁿ⁺¹ and aᵢ.
pub fn grid_update(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    colliders: Res<ActiveColliders>,
    mut grid: ResMut<MpmGrid>,
) {
    let dt = ctx.coefficients.dt;
    let g = config.gravity;
    let eps = grid.mass_epsilon;
    let layout: GridLayout = grid.layout;
    let walls = config.walls;
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    let colliders = &colliders.list;
    for_each_active_row_indexed(&mut grid, |first, row| {
        for (k, n) in row.iter_mut().enumerate() {
            if n.mass <= eps {
                continue;
            }
            let mut a_new = Vec3::from(n.force) / n.mass + g;
            let mut v_new = Vec3::from(n.velocity) + dt * a_new;
            let x = layout.node_position(first + IVec3::new(0, 0, k as i32));
            collide_node(
                x, 0.0, &walls, dmin, dmax, colliders, &mut v_new, &mut a_new,
            );
            n.new_velocity = v_new.into();
            n.new_acceleration = a_new.into();
        }
    });
    crate::step::p2g::copy_ghosts(&config, &mut grid, GhostCopy::Update);
}

/// Result of the first-order gather of one particle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FirstOrderG2p {
    /// PIC/FLIP-blended vₚⁿ⁺¹.
    pub velocity: Vec3,
    /// Σ wᵢₚ aᵢⁿ⁺¹ (PIC).
    pub acceleration: Vec3,
    /// xₚⁿ⁺¹ = xₚⁿ + Δt Σ wᵢₚ vᵢⁿ⁺¹.
    pub position: Vec3,
    /// Lₚⁿ⁺¹ = Σ vᵢⁿ⁺¹ ⊗ ∇wᵢₚ.
    pub velocity_gradient: Mat3,
}

/// The first-order G2P of one particle (weights at xₚⁿ): the stencil's rows summed first
/// ([`Stencil::for_each_row`]).
#[inline(always)]
pub fn g2p_first_order(
    grid: &GridLayout,
    nodes: &[GridNode],
    st: &Stencil,
    x: Vec3,
    v: Vec3,
    c: &StepCoefficients,
) -> FirstOrderG2p {
    let (mut v_pic, mut v_old, mut a_pic) = (Vec3A::ZERO, Vec3A::ZERO, Vec3A::ZERO);
    let mut l = [Vec3A::ZERO; 3];
    let z = st.z_factors();
    st.for_each_row(grid, |idx, r| {
        let n = [0, 1, 2].map(|k| &nodes[idx + k]);
        let v_new = n.map(|n| n.new_velocity);
        let wxy = Vec3A::splat(r.z);
        v_pic += wxy * row_sum(&z.0, v_new);
        v_old += wxy * row_sum(&z.0, n.map(|n| n.velocity));
        a_pic += wxy * row_sum(&z.0, n.map(|n| n.new_acceleration));
        add_row_gradient(&mut l, &z, r, v_new);
    });
    let (v_pic, v_old) = (Vec3::from(v_pic), Vec3::from(v_old));
    let v_flip = v + (v_pic - v_old);
    FirstOrderG2p {
        velocity: v_pic + c.flip_velocity * (v_flip - v_pic),
        acceleration: Vec3::from(a_pic),
        position: x + c.dt * v_pic,
        velocity_gradient: Mat3::from(Mat3A::from_cols(l[0], l[1], l[2])),
    }
}

/// One table's columns of the first-order [`grid_to_particle`].
#[derive(Clone, Copy)]
pub struct FirstOrderColumns {
    entities: SharedMut<Entity>,
    x: SharedMut<Position>,
    v: SharedMut<Velocity>,
    a: SharedMut<Acceleration>,
    rho: SharedMut<Density>,
    l: SharedMut<VelocityGradient>,
    f: Option<SharedMut<DeformationGradient>>,
}

/// G2P, positions, deformation gradient and density of the first-order schemes (module docs),
/// each particle's result written into its own components.
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn grid_to_particle(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    grid: Res<MpmGrid>,
    failures: Res<FailureCollector>,
    shared: Res<BlockPlan>,
    mut scratch: Local<GatherScratch<FirstOrderColumns>>,
    mut q: Query<
        (
            Entity,
            &ParticleStencil,
            &mut Position,
            &mut Velocity,
            &mut Acceleration,
            &mut Density,
            &mut VelocityGradient,
            Option<&mut DeformationGradient>,
        ),
        With<Particle>,
    >,
) {
    let c = ctx.coefficients;
    let dt = c.dt;
    // With a projected pressure (§5.4) the particles keep their rest volume.
    let compressible = config.integrator.pressure.projection().is_none();
    // The next step's stress takes this Lₚⁿ⁺¹ instead of gathering it again.
    let carry = config.integrator.velocity_gradient == VelocityGradientSource::Carried;
    let layout = grid.layout;
    scratch.clear();
    for (entities, st, mut x, mut v, mut a, mut rho, mut lp, f) in q
        .contiguous_iter_mut()
        .expect("particle components are table components")
    {
        let cols = FirstOrderColumns {
            entities: SharedMut::read(entities),
            x: SharedMut::slice(x.bypass_change_detection()),
            v: SharedMut::slice(v.bypass_change_detection()),
            a: SharedMut::slice(a.bypass_change_detection()),
            rho: SharedMut::slice(rho.bypass_change_detection()),
            l: SharedMut::slice(lp.bypass_change_detection()),
            f: f.map(|mut f| SharedMut::slice(f.bypass_change_detection())),
        };
        // SAFETY: the slices are this query's table columns, borrowed by it for the whole
        // system; nothing else touches them before the pushed tables are cleared below.
        unsafe { scratch.push(st, cols) };
    }
    scratch.gather(&shared, &grid, &grid.nodes, |st, t, k, local, hood| {
        // SAFETY: `gather` visits each row of each table once; the entity is only read.
        let (x, v, a, rho, lp) = unsafe {
            (
                &mut *t.x.get().add(k),
                &mut *t.v.get().add(k),
                &mut *t.a.get().add(k),
                &mut *t.rho.get().add(k),
                &mut *t.l.get().add(k),
            )
        };
        let r = g2p_first_order(local, hood, &st.stencil(&layout), x.0, v.0, &c);
        x.0 = r.position;
        v.0 = r.velocity;
        a.0 = r.acceleration;
        let l = r.velocity_gradient;
        if carry {
            lp.0 = l;
        }
        let theta = l.x_axis.x + l.y_axis.y + l.z_axis.z;
        let j = if compressible { 1.0 + dt * theta } else { 1.0 };
        if theta.is_nan() || j <= 0.0 {
            failures.record(FailureReport::particle(
                // SAFETY: as above.
                unsafe { *t.entities.get().add(k) },
                "density",
                theta as f64,
                "strong compression: 1 + Δt·∇·v ≤ 0 in the first-order density update",
            ));
        }
        let new = rho.value / j;
        if dt > 0.0 {
            rho.rate = (new - rho.value) / dt;
        }
        rho.value = new;
        if let Some(f) = t.f {
            // SAFETY: as above.
            let f = unsafe { &mut *f.get().add(k) };
            f.0 = (Mat3::IDENTITY + dt * l) * f.0;
        }
    });
}
