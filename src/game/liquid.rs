//! A body of liquid spawned as an entity and placed by its `Transform`.
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use bevy_transform::components::Transform;

use crate::collision::ColliderShape;
use crate::config::MpmConfig;
use crate::emit::spawn_liquid_body;
use crate::material::MaterialId;
use crate::math::{Real, Vec3};
use crate::sampling::{Lattice, sample_where};

/// A body of liquid to spawn: the solid of `shape` (any collider shape, e.g. a box, a sphere
/// or a closed triangle mesh) placed by the entity's `Transform` (translation and rotation;
/// scale is ignored), filled with particles on the simulation's particle lattice (the grid
/// origin, Δx/`particles_per_cell`) before the next frame, all moving at `velocity`. Then the
/// component is replaced by [`SpawnedLiquid`]; the particles are entities of their own.
#[derive(Component, Clone, Debug)]
#[require(Transform)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct LiquidBody {
    /// Shape in the entity's frame.
    pub shape: ColliderShape,
    /// Material of the particles.
    pub material: MaterialId,
    /// Initial velocity \[m/s\] (world frame).
    pub velocity: Vec3,
    /// Particles per grid cell and axis (≥ 1). Default 2.
    pub particles_per_cell: u32,
    /// Temperature of the particles (`None`: unheated).
    pub temperature: Option<Real>,
}

impl LiquidBody {
    /// A body of `material` with the shape `shape`, at rest, 2 particles per cell and axis.
    pub fn new(shape: ColliderShape, material: MaterialId) -> Self {
        Self {
            shape,
            material,
            velocity: Vec3::ZERO,
            particles_per_cell: 2,
            temperature: None,
        }
    }

    /// With initial velocity `velocity`.
    pub fn with_velocity(mut self, velocity: Vec3) -> Self {
        self.velocity = velocity;
        self
    }
}

/// What a [`LiquidBody`] became.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct SpawnedLiquid {
    /// Particles spawned (0 if the shape lies outside the domain or is thinner than the
    /// particle spacing).
    pub particles: usize,
}

/// Fills every [`LiquidBody`] with particles (lattice points inside the placed shape and the
/// domain) and replaces it by [`SpawnedLiquid`]. Runs in
/// [`DriverSystems::Pace`](crate::step::pacing::DriverSystems::Pace).
pub fn fill_liquid_bodies(world: &mut World) {
    let mut q = world.query::<(Entity, &LiquidBody, &Transform)>();
    let mut bodies: Vec<(Entity, LiquidBody, Transform)> =
        q.iter(world).map(|(e, b, t)| (e, b.clone(), *t)).collect();
    if bodies.is_empty() {
        return;
    }
    bodies.sort_by_key(|(e, _, _)| *e);
    let config = world.resource::<MpmConfig>().clone();
    for (entity, body, t) in bodies {
        let lattice = Lattice::new(config.domain_min, config.dx, body.particles_per_cell);
        let (mut min, mut max) = (config.domain_min, config.domain_max);
        if let Some((lo, hi)) = body.shape.local_bounds() {
            let corners = (0..8).map(|i| {
                let c = Vec3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                );
                t.translation + t.rotation * c
            });
            let (a, b) = corners.fold(
                (Vec3::splat(Real::INFINITY), Vec3::splat(Real::NEG_INFINITY)),
                |(a, b), c| (a.min(c), b.max(c)),
            );
            min = min.max(a);
            max = max.min(b);
        }
        let inverse = t.rotation.inverse();
        let sample = if min.cmplt(max).all() {
            sample_where(&lattice, min, max, |p| {
                body.shape.sdf(inverse * (p - t.translation)).0 < 0.0
            })
        } else {
            Default::default()
        };
        let spawned = spawn_liquid_body(
            world,
            &sample.positions,
            body.velocity,
            lattice.particle_volume(),
            body.material,
            body.temperature,
        );
        world
            .entity_mut(entity)
            .remove::<LiquidBody>()
            .insert(SpawnedLiquid {
                particles: spawned.len(),
            });
    }
}
