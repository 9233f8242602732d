//! What a particle spawned during a run needs besides its [`ParticleBundle`](crate::components::ParticleBundle):
//! the registry of per-material initializers that plugins fill (a rheology model's state, a
//! phase index, …) and that whoever spawns particles mid-run (an emitter) runs on every batch.
use bevy_ecs::prelude::*;

use crate::material::MaterialId;

/// Inserts into freshly spawned particles `particles` of material `material` the state their
/// material needs (a rheology model's state, a deformation gradient, a phase index, …). Must
/// insert only what is missing (use `insert_batch_if_new` or check).
pub type ParticleInitializer = fn(&mut World, MaterialId, &[Entity]);

/// The initializers run on every batch of emitted particles, in registration order.
#[derive(Resource, Clone, Default)]
pub struct ParticleInitializers {
    list: Vec<(&'static str, ParticleInitializer)>,
}

impl ParticleInitializers {
    /// Registers `init` under `name` (a second registration under the same name is ignored).
    pub fn add(&mut self, name: &'static str, init: ParticleInitializer) {
        if !self.list.iter().any(|(n, _)| *n == name) {
            self.list.push((name, init));
        }
    }

    /// Runs every initializer on `particles` of `material`.
    pub fn run(&self, world: &mut World, material: MaterialId, particles: &[Entity]) {
        for (_, init) in &self.list {
            init(world, material, particles);
        }
    }
}
