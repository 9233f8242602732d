//! In a Bevy game (cargo feature `game`): the liquid advanced by Bevy's clock within a frame
//! budget, and liquids, nozzles and colliders placed by `Transform`.
//!
//! ```text
//! App::new()
//!     .add_plugins((MinimalPlugins or DefaultPlugins, MpmPlugins, GamePlugin::default()))
//! ```
//!
//! **Time.** [`GamePlugin`] sets [`FramePacing::Requested`](crate::step::pacing::FramePacing::Requested) every update from Bevy's `Time` in
//! the frame driver's schedule: with the driver in `Update` (the default of
//! [`MpmCorePlugin`](crate::plugin::MpmCorePlugin)) that is `Time<Virtual>`, so pausing, slow
//! motion (`Time<Virtual>::set_relative_speed`) and any frame rate behave as in the rest of
//! the game; with `MpmCorePlugin { schedule: FixedUpdate.intern() }` it is `Time<Fixed>`, and
//! the liquid advances in fixed ticks. The [`FrameBudget`] (a resource) caps the sub-steps
//! and wall time of one update; what it does not allow is dropped and shown in
//! [`SimulationLag`](crate::step::pacing::SimulationLag) (and logged once). The CLI and the reports never add this plugin: their
//! frames stay exact and deterministic.
//!
//! **Placement.** Entities with a `Transform` (root entities; a child's `GlobalTransform`,
//! propagated at the end of the previous frame, is used for children):
//! - [`LiquidBody`]: filled with particles at the entity's pose once, then the component is
//!   replaced by [`SpawnedLiquid`];
//! - a [`Collider`](crate::collision::Collider) follows its `Transform`: its velocity for the
//!   liquid is the Transform's motion over the frame (a paddle moved by game code pushes the
//!   liquid like a scripted [`ColliderMotion`](crate::collision::ColliderMotion)); its sub-steps move it from the last pose to
//!   the new one;
//! - a [`NozzleEmitter`](crate::emit::NozzleEmitter)'s path and axis are in its entity's
//!   frame ([`EmitterFrame`](crate::emit::EmitterFrame)): a hose that the player moves and turns emits along its new
//!   direction, with the hose's own velocity added;
//! - a coupled body (the crate's rigid bodies, [`CoupledCollider`](crate::collision::CoupledCollider)) takes its first pose from
//!   the `Transform` and writes its pose back to it after every frame.
//!
//! **Avian** (feature `avian`): `avian::AvianCouplingPlugin` couples Avian rigid bodies
//! two-way with the liquid.
//!
//! Game code that moves these entities runs before [`DriverSystems::Pace`].
//!
//! **Liquids.** [`GameLiquid`] presets (water, honey, ketchup, slime) with a sound speed and grid
//! spacing chosen for few sub-steps per frame, and what that costs in accuracy.
//!
//! **Reading the liquid.** Query `(&Position, &Velocity)` (and any field component such as
//! `Density`, `Temperature`) `With<Particle>`, once per frame after [`DriverSystems::Advance`].
//! New particles have `Added<Particle>`; removed ones (escaped through an open face, or
//! despawned by game code) show in `RemovedComponents<Particle>`. The step writes particle
//! fields through raw column access, which **bypasses change detection**: `Changed<Position>`
//! is not a signal of motion (every particle moves every step anyway).
#[cfg(feature = "avian")]
pub mod avian;
mod clock;
mod liquid;
mod placement;
pub mod presets;

/// The `bevy_time` and `bevy_transform` this module is built with (for apps without the
/// top-level `bevy` crate).
pub use {bevy_time, bevy_transform};

use bevy_app::{App, Plugin};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};

#[cfg(feature = "avian")]
pub use avian::AvianCouplingPlugin;
pub use clock::request_from_time;
pub use liquid::{LiquidBody, SpawnedLiquid, fill_liquid_bodies};
pub use placement::{PlacedByTransform, follow_transforms, publish_coupled_poses};
pub use presets::{GAME_DX, GAME_SOUND_SPEED, GameLiquid, game_config, game_config_projected};

use crate::step::pacing::{DriverSchedule, DriverSystems, FrameBudget};

/// The game integration (see the module docs): Bevy's clock, the frame budget, placement by
/// `Transform`. Needs `bevy_time`'s `TimePlugin` (part of `MinimalPlugins` and
/// `DefaultPlugins`) and [`MpmPlugins`](crate::plugin::MpmPlugins), added in any order. Its
/// systems are added in `Plugin::finish` (into the driver's schedule): `App::run` calls it; an
/// app driven by `App::update` calls `app.finish()` and `app.cleanup()` first.
#[derive(Clone, Copy, Debug, Default)]
pub struct GamePlugin {
    /// The budget of one update (also a resource, changeable at run time). Default: none.
    pub budget: FrameBudget,
}

impl GamePlugin {
    /// With a budget of `max_substeps` sub-steps per update.
    pub fn with_max_substeps(max_substeps: u32) -> Self {
        Self {
            budget: FrameBudget::substeps(max_substeps),
        }
    }
}

impl Plugin for GamePlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(self.budget);
        #[cfg(feature = "reflect")]
        app.register_type::<LiquidBody>()
            .register_type::<SpawnedLiquid>()
            .register_type::<PlacedByTransform>()
            .register_type::<GameLiquid>();
    }

    fn finish(&self, app: &mut App) {
        // The driver's schedule is known once every plugin is built.
        let schedule = app
            .world()
            .get_resource::<DriverSchedule>()
            .map_or_else(|| bevy_app::Update.intern(), |s| s.0);
        app.add_systems(
            schedule,
            (
                (request_from_time, follow_transforms, fill_liquid_bodies)
                    .chain()
                    .in_set(DriverSystems::Pace),
                publish_coupled_poses.in_set(DriverSystems::Publish),
            ),
        );
    }
}
