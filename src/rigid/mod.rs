//! Two-way coupled rigid bodies: dynamic spheres and boxes moved by gravity and by the
//! momentum they exchange with the MPM grid at their boundary nodes (ALGORITHM §2.11 applied
//! to a collision object whose motion is an unknown of the step).
//!
//! A dynamic body is an entity with [`RigidBody`] (mass and principal inertia), a [`Collider`](crate::collision::Collider)
//! (shape and boundary condition towards the liquid) and a [`ColliderPose`](crate::collision::ColliderPose); [`RigidVelocity`],
//! [`RigidAcceleration`], [`RigidExchange`] and [`ColliderMotion`](crate::collision::ColliderMotion) are added automatically
//! (required components) or by [`RigidBodyBundle`]. Its pose's origin is its centre of mass.
//! Shapes: [`ColliderShape::Sphere`](crate::collision::ColliderShape::Sphere) and [`ColliderShape::Box`](crate::collision::ColliderShape::Box). The systems are added by
//! [`RigidBodyPlugin`] (part of [`crate::plugin::MpmPlugins`]) and do nothing without bodies.
//!
//! # The step
//!
//! **The body is integrated like a grid node: GS4-II, η = 0, with the grid's (ρ∞, ρs)** (§1.2
//! eq. 1.4). It carries a velocity *and* an acceleration (the GS4 rate, [`RigidAcceleration`]),
//! linear and angular. In `Predict` ([`predict_rigid_bodies`]):
//! ΔA = (g − Aⁿ)/W₁Λ₆, Â = Aⁿ + ΔA, V̂ = Vⁿ + λ₄Δt Aⁿ + λ₅Δt ΔA, and for the rotation the same
//! with the gyroscopic acceleration −I⁻¹(Ω × IΩ) (world frame) in place of g.
//!
//! **Coupling** ([`couple_rigid_bodies`], in `GridUpdate` after the grid update). Every node
//! with mass inside the body or within half a cell of its surface (φ ≤ ½Δx at the body's pose
//! at t_{n+1}, see *which nodes* below) is projected with the
//! collision rule of §2.11 relative to the body's velocity field V + Ω × r, its acceleration
//! projected relative to the body's acceleration field A + α × r + Ω × (Ω × r) (choice D5), with
//! the same friction correction as the walls ([`project_velocity`](crate::collision::project_velocity)). What the projection removes
//! from the node goes to the body:
//! J_v = Σ mᵢ(vᵢ − vᵢ′), L_v = Σ rᵢ × mᵢ(vᵢ − vᵢ′), J_a = Σ mᵢ(aᵢ − aᵢ′), L_a = Σ rᵢ × mᵢ(aᵢ − aᵢ′),
//! Vⁿ⁺¹ = V̂ + J_v/M, Aⁿ⁺¹ = Â + J_a/M, Ωⁿ⁺¹ = Ω̂ + I⁻¹L_v, αⁿ⁺¹ = α̂ + I⁻¹L_a.
//!
//! *Why the acceleration is exchanged too (exact momentum conservation).* G2P conserves both
//! sums exactly (Σₚ mₚvₚⁿ⁺¹ = Σᵢ mᵢvᵢⁿ⁺¹ and Σₚ mₚaₚⁿ⁺¹ = Σᵢ mᵢaᵢⁿ⁺¹ for any PIC/FLIP blend), and
//! Σᵢ f̃ᵢ = 0. With P = Σ mv + MV and 𝒜 = Σ ma + MA over liquid and body, the step above gives
//! 𝒜ⁿ⁺¹ = 𝒜ⁿ + (M_tot g − 𝒜ⁿ)/W₁Λ₆ and Pⁿ⁺¹ = Pⁿ + λ₄Δt 𝒜ⁿ + λ₅Δt(𝒜ⁿ⁺¹ − 𝒜ⁿ): with a consistent
//! start (𝒜⁰ = M_tot g, §2.14) 𝒜 stays M_tot g and **P changes by exactly M_tot g Δt per step**.
//! Exchanging only J_v (a body with a plain Euler update) leaves the projected accelerations
//! out of 𝒜 and adds (λ₄ − λ₅/W₁Λ₆)Δt (𝒜 − M_tot g) per step; for (0.5, 0) a resting contact
//! would then pass on only λ₅/W₁Λ₆ = 6/7 of the liquid's pressure force, so a floating body
//! would displace 7/6 of its Archimedes volume (derivation, not a measurement).
//!
//! *Semi-implicit exchange.* Projecting against the predicted V̂ and then adding J_v/M is the
//! usual explicit coupling; when the liquid mass on the boundary nodes m_c exceeds M it
//! overshoots and creates energy. The projection is therefore iterated: (V*, Ω*, A*, α*) start at
//! the predicted values and are updated with the contact mass as preconditioner,
//! V* ← (M V̂ + J_v(V*) + m_c V*)/(M + m_c) (Ω* with I + I_c, I_c = Σ mᵢ(|rᵢ|²𝟙 − rᵢrᵢᵀ) over the
//! projected nodes), which is exact after one update for sticky contact (the momentum-weighted
//! mean velocity) and reduces to the explicit scheme for m_c ≪ M; at most
//! [`MAX_COUPLING_ITERATIONS`] passes. The nodes are projected against the last iterate, and the
//! body receives exactly what that projection removed, so momentum is conserved whether or not
//! the iteration converged.
//!
//! *Which nodes.* A node belongs to the body when φ ≤ ½Δx ([`COUPLING_SKIN_CELLS`]): the
//! body's discrete surface is then the node layer nearest to its true surface, off by at most
//! ½Δx either way and unbiased on average. With φ ≤ 0 (the rule of the static colliders) it lies
//! between 0 and Δx inside, ½Δx on average, and the body displaces too little liquid. Measured
//! with a sphere of half the liquid's density released at its draught: radius 4Δx, 1.6Δx too
//! deep after 1 s; radius 8Δx, 1.1 coarse cells too deep after 0.8 s (first order, both still
//! sinking slowly); a static sphere (radius 4Δx, φ ≤ 0) received half of the Archimedes force.
//! With ½Δx the sphere floats within 0.3Δx of its draught (`tests/it/rigid.rs`).
//!
//! **Pose** (in `Commit`, [`commit_rigid_bodies`]): trapezoidal, xⁿ⁺¹ = xⁿ + Δt/2 (Vⁿ + Vⁿ⁺¹)
//! — identity (1.1) of GS4, the same rule the particles follow, exact for free fall (semi-
//! implicit Euler would lag by gΔt t/2). The rotation turns by Δt/2 (Ωⁿ + Ωⁿ⁺¹) and the
//! quaternion is renormalised.
//!
//! **Domain walls** act on the body as contact constraints with restitution 0 and the wall's
//! condition (`Sticky`: no slip at the contact point, `Slip`: frictionless, `Friction(μ)`:
//! Coulomb), solved by projected Gauss–Seidel on the support points (the sphere's lowest point
//! towards each wall, the box's corners) that penetrate at the end-of-step pose; remaining
//! penetration is removed by translating the body (no velocity change). The same solve is
//! applied to the predicted velocity, so the liquid sees a resting body at rest. `Open` faces
//! do not constrain the body; along `Periodic` axes it wraps around. Wall impulses are external
//! and are reported in [`RigidExchange::wall_impulse`].
//!
//! **Particles** that end inside a body are moved to its surface (position only, in `Commit`,
//! [`push_particles_out_of_rigid_bodies`]): the velocity exchange happens on the grid, where
//! it is accounted for, so this pass changes no momentum.
//!
//! **Time step**: the advection limit of §2.15 also holds for the body's fastest surface point
//! |V| + |Ω| r_b ([`limit_time_step_by_rigid_bodies`]).
//!
//! **Determinism**: bodies are processed one after another in entity order and each body's
//! nodes in (i, j, k) order, in one thread, so the sums do not depend on the thread count.
//!
//! Not modelled: contacts between two bodies or between a body and a static collider. Known
//! limitation: a liquid film thinner than a cell resting on top of a body does not drain (the
//! grid cannot resolve its flow); a sphere released fully submerged (radius 4Δx, half the
//! liquid's density) stopped 2.5Δx below its draught under such a film.
//!
//! # Files
//!
//! | file | content | ALGORITHM |
//! |---|---|---|
//! | `body` | components [`RigidBody`] (mass properties of spheres and boxes), [`RigidVelocity`], [`RigidAcceleration`], [`RigidExchange`], [`RigidBodyBundle`] | §2.1 |
//! | `active` | the bodies of the current step ([`ActiveRigidBodies`]) and the trapezoidal pose update | |
//! | `contact` | contacts with the domain walls, keeping a body in the domain | §2.11 |
//! | `predict` | S1: the GS4 predictor of the body ([`predict_rigid_bodies`]) | §1.2 |
//! | `coupling` | S11: the momentum exchange with the grid ([`couple_rigid_bodies`]) | §2.11 |
//! | `commit` | S15: the new pose and components, particles pushed out ([`commit_rigid_bodies`]) | |
//! | `time_step` | the bodies' advection limit ([`limit_time_step_by_rigid_bodies`]) | §2.15 |
//! | `energy` | the bodies' energy for the monitor ([`rigid_body_energy`]) | §7 |
//! | `spec` | scene types [`RigidShape`], [`RigidBodySpec`] | |
//! | `validate` | checks of a scene's bodies ([`validate_rigid_bodies`]) | |
//! | `metrics` | the `rigid{i}_*` columns of `metrics.csv` ([`metrics_columns`]) | |
//!
//! This file holds [`RigidBodyPlugin`]. Each file depends only on the ones above it.
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;

use crate::diagnostics::{MetricsColumns, MetricsSource};
use crate::step::energy::EnergyTerms;
use crate::step::schedule::{
    CommitSystems, GridUpdateSystems, MonitorSystems, MpmStep, PredictSystems, init_step_schedule,
};

mod active;
mod body;
mod commit;
mod contact;
mod coupling;
mod energy;
mod metrics;
mod predict;
mod spec;
mod time_step;
mod validate;

pub use active::{ActiveRigidBodies, RigidInstance, advance_pose_trapezoid};
pub use body::{
    RigidAcceleration, RigidBody, RigidBodyBundle, RigidBodyError, RigidExchange, RigidVelocity,
    bounding_radius,
};
pub use commit::{commit_rigid_bodies, push_particles_out_of_rigid_bodies};
pub use contact::WALL_CONTACT_ITERATIONS;
pub use coupling::{COUPLING_SKIN_CELLS, MAX_COUPLING_ITERATIONS, couple_rigid_bodies};
pub use energy::rigid_body_energy;
pub use metrics::{MetricsBodies, metrics_columns, metrics_values, rigid_body_entities};
pub use predict::predict_rigid_bodies;
pub use spec::{RigidBodySpec, RigidShape};
pub use time_step::limit_time_step_by_rigid_bodies;
pub use validate::validate_rigid_bodies;

/// Adds the rigid-body systems to the [`MpmStep`] schedule (see the module docs for where
/// each runs). Part of [`crate::plugin::MpmPlugins`]; the systems run only while some entity
/// has a [`RigidBody`].
pub struct RigidBodyPlugin;

impl Plugin for RigidBodyPlugin {
    fn build(&self, app: &mut App) {
        init_step_schedule(app);
        app.init_resource::<ActiveRigidBodies>()
            .init_resource::<EnergyTerms>()
            .init_resource::<MetricsColumns>();
        app.world_mut()
            .resource_mut::<MetricsColumns>()
            .add(MetricsSource {
                key: "rigid",
                columns: |world| {
                    let bodies = rigid_body_entities(world);
                    let columns = metrics_columns(bodies.len());
                    world.insert_resource(MetricsBodies(bodies));
                    columns
                },
                values: metrics_of_bodies,
                // Every rank moves the bodies alike (their exchange is summed over the ranks):
                // rank 0's values are the run's.
                across_ranks: Some(crate::diagnostics::AcrossRanks {
                    parts: metrics_of_bodies,
                    combine: |ranks| ranks.first().cloned().unwrap_or_default(),
                }),
            });
        let any = any_with_component::<RigidBody>;
        app.add_systems(
            MpmStep,
            (
                predict_rigid_bodies
                    .in_set(PredictSystems::Bodies)
                    .run_if(any),
                couple_rigid_bodies
                    .in_set(GridUpdateSystems::Coupling)
                    .run_if(any),
                (commit_rigid_bodies, push_particles_out_of_rigid_bodies)
                    .chain()
                    .in_set(CommitSystems::Bodies)
                    .run_if(any),
                (limit_time_step_by_rigid_bodies, rigid_body_energy)
                    .chain()
                    .in_set(MonitorSystems::Plugins)
                    .run_if(any),
            ),
        );
    }
}

/// The metrics values of the bodies named when the columns were asked for.
fn metrics_of_bodies(world: &mut World) -> Vec<f64> {
    let bodies = world
        .get_resource::<MetricsBodies>()
        .map(|b| b.0.clone())
        .unwrap_or_default();
    metrics_values(world, &bodies)
}
