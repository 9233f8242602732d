//! Liquid bodies released during the run: a blob dropped at a time (the bunnies of a pile
//! dropped one after another, a game's splash spawned on cue).
//!
//! A [`DelayedBody`] entity holds the particles of a body and its release time. At the end of
//! the first step that reaches the release time, [`release_bodies`] spawns them as liquid
//! particles (through [`spawn_liquid_body`], so they get the state their material needs: the
//! registered model states, and the material's initial temperature in a heated scene) and
//! despawns the holder. Bodies due in the same step are released in entity order, so a run is
//! reproducible.
//!
//! In a scene file a body's `release_time` makes it one (`docs/scenes.md`); a game can spawn a
//! `DelayedBody` itself, or call [`spawn_liquid_body`] directly when it wants the liquid at once.
use bevy_ecs::prelude::*;

use super::spawn_liquid_body;
use crate::material::MaterialId;
use crate::math::{Real, Vec3};
use crate::step::schedule::{SimulationClock, StepContext};

/// A liquid body waiting for its release time (module docs).
#[derive(Component, Clone, Debug, PartialEq)]
pub struct DelayedBody {
    /// Simulation time at which the body appears \[s\]: its particles are spawned at the end
    /// of the first step whose end time reaches it.
    pub release_time: f64,
    /// Particle positions \[m\].
    pub positions: Vec<Vec3>,
    /// Velocity of every particle at release \[m/s\].
    pub velocity: Vec3,
    /// Volume of each particle \[m³\] (mass = volume × the material's density).
    pub particle_volume: Real,
    /// Material.
    pub material: MaterialId,
}

/// S16 (§4.4): spawns the [`DelayedBody`]s whose release time the step just taken reached, in
/// entity order, and despawns their holders. Nothing happens in the start-up rate evaluation.
/// A release adds particles (and their energy) the energy monitor did not see, so the step
/// marks [`EnergyTerms::unmeasured_input`](crate::step::energy::EnergyTerms).
///
/// Reads `StepContext`, `SimulationClock`, `DelayedBody`, the thermal configuration (initial
/// temperatures); spawns particles, despawns holders.
pub fn release_bodies(world: &mut World) {
    let ctx = *world.resource::<StepContext>();
    if ctx.rate_evaluation || ctx.dt.is_nan() || ctx.dt <= 0.0 {
        return;
    }
    let t1 = world.resource::<SimulationClock>().time + ctx.dt;
    let mut q = world.query::<(Entity, &DelayedBody)>();
    let mut due: Vec<Entity> = q
        .iter(world)
        .filter(|(_, b)| b.release_time <= t1)
        .map(|(e, _)| e)
        .collect();
    if due.is_empty() {
        return;
    }
    due.sort();
    if let Some(mut terms) = world.get_resource_mut::<crate::step::energy::EnergyTerms>() {
        terms.unmeasured_input = true;
    }
    for holder in due {
        let Some(body) = world.entity_mut(holder).take::<DelayedBody>() else {
            continue;
        };
        world.despawn(holder);
        let temperature = world
            .get_resource::<crate::thermal::ThermalConfig>()
            .and_then(|c| c.material(body.material))
            .map(|m| m.initial_temperature);
        spawn_liquid_body(
            world,
            &body.positions,
            body.velocity,
            body.particle_volume,
            body.material,
            temperature,
        );
    }
}
