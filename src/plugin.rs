//! The plugin group a Bevy app adds in one line: `app.add_plugins(MpmPlugins)`.
use bevy_app::{App, Plugin, PluginGroup, PluginGroupBuilder, Update};
use bevy_ecs::intern::Interned;
use bevy_ecs::schedule::IntoScheduleConfigs;
use bevy_ecs::schedule::ScheduleLabel;
use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};

use crate::config::MpmConfig;
use crate::failure::{FailureCollector, SimulationStatus};
use crate::material::Materials;
use crate::scatter::BlockPlan;
use crate::step::driver::{add_core_systems, advance_frame};
use crate::step::pacing::{DriverSchedule, DriverSystems, FrameBudget, FramePacing, SimulationLag};
use crate::step::schedule::{ActiveColliders, SimulationClock, StepContext};

/// All treacle plugins: [`MpmCorePlugin`] and [`RigidBodyPlugin`](crate::rigid::RigidBodyPlugin)
/// (idle without rigid bodies). Rheology, thermal and emitter plugins are
/// added by the user (or by the scene loader) only when a scene needs them.
pub struct MpmPlugins;

impl PluginGroup for MpmPlugins {
    fn build(self) -> PluginGroupBuilder {
        PluginGroupBuilder::start::<Self>()
            .add(MpmCorePlugin::default())
            .add(crate::rigid::RigidBodyPlugin)
    }
}

/// The explicit GS4-MPM core: resources, the [`MpmStep`](crate::step::schedule::MpmStep) schedule,
/// and the frame driver in `schedule` (default `Update`; `FixedUpdate` steps the liquid with
/// Bevy's fixed clock), in [`DriverSystems::Advance`]. How much one update advances:
/// [`FramePacing`] (fixed frames unless a clock such as `game::GameClockPlugin` asks otherwise).
pub struct MpmCorePlugin {
    /// Schedule in which one frame of simulation is advanced. Default `Update`.
    pub schedule: Interned<dyn ScheduleLabel>,
}

impl Default for MpmCorePlugin {
    fn default() -> Self {
        Self {
            schedule: Update.intern(),
        }
    }
}

impl Plugin for MpmCorePlugin {
    fn build(&self, app: &mut App) {
        // Bevy's default task pool gives the compute pool one thread on a 2-core machine
        // (BEVY-NOTES); use every core unless the application initialised the pool itself.
        ComputeTaskPool::get_or_init(|| {
            let n = std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1);
            TaskPoolBuilder::new().num_threads(n).build()
        });
        if !app.world().contains_resource::<MpmConfig>() {
            app.insert_resource(MpmConfig::default());
        }
        app.init_resource::<Materials>()
            .init_resource::<SimulationClock>()
            .init_resource::<SimulationStatus>()
            .init_resource::<FailureCollector>()
            .init_resource::<StepContext>()
            .init_resource::<BlockPlan>()
            .init_resource::<ActiveColliders>()
            .init_resource::<crate::step::energy::EnergyMonitor>()
            .init_resource::<crate::step::implicit::ImplicitSolveStats>()
            .init_resource::<crate::step::implicit::ViscousSolveScratch>()
            .init_resource::<crate::step::implicit::PressureSolveStats>()
            .init_resource::<crate::step::implicit::PressureScratch>()
            .init_resource::<crate::step::energy::EnergyTerms>()
            .init_resource::<FramePacing>()
            .init_resource::<FrameBudget>()
            .init_resource::<SimulationLag>()
            .insert_resource(DriverSchedule(self.schedule))
            .configure_sets(
                self.schedule,
                (
                    DriverSystems::Pace,
                    DriverSystems::Advance,
                    DriverSystems::Publish,
                )
                    .chain(),
            )
            .add_systems(self.schedule, advance_frame.in_set(DriverSystems::Advance));
        add_core_systems(app);
        #[cfg(feature = "reflect")]
        register_reflected(app);
    }
}

/// Registers the reflected public types (feature `reflect`) for inspectors and Bevy scenes.
#[cfg(feature = "reflect")]
fn register_reflected(app: &mut App) {
    use crate::collision::{
        Collider, ColliderLifetime, ColliderMotion, ColliderPose, ColliderShape, CoupledCollider,
    };
    use crate::components::{
        Acceleration, CauchyStress, Density, Mass, Particle, Position, StabilityData, Velocity,
    };
    use crate::config::{
        BoundaryCondition, DensityUpdate, DomainWalls, FlipUpdate, IntegratorConfig, Scheme,
        TimeStepConfig, TimeStepMode,
    };
    use crate::material::{FluidMaterial, MaterialId};
    use crate::rigid::{RigidAcceleration, RigidBody, RigidExchange, RigidVelocity};
    app.register_type::<Particle>()
        .register_type::<Position>()
        .register_type::<Velocity>()
        .register_type::<Acceleration>()
        .register_type::<Mass>()
        .register_type::<Density>()
        .register_type::<CauchyStress>()
        .register_type::<StabilityData>()
        .register_type::<MaterialId>()
        .register_type::<FluidMaterial>()
        .register_type::<Materials>()
        .register_type::<MpmConfig>()
        .register_type::<IntegratorConfig>()
        .register_type::<Scheme>()
        .register_type::<FlipUpdate>()
        .register_type::<DensityUpdate>()
        .register_type::<TimeStepMode>()
        .register_type::<TimeStepConfig>()
        .register_type::<BoundaryCondition>()
        .register_type::<DomainWalls>()
        .register_type::<Collider>()
        .register_type::<ColliderShape>()
        .register_type::<ColliderPose>()
        .register_type::<ColliderMotion>()
        .register_type::<CoupledCollider>()
        .register_type::<ColliderLifetime>()
        .register_type::<FramePacing>()
        .register_type::<FrameBudget>()
        .register_type::<SimulationLag>()
        .register_type::<SimulationClock>()
        .register_type::<crate::step::monitor::StabilityMaxima>()
        .register_type::<crate::emit::EmitterFrame>()
        .register_type::<RigidBody>()
        .register_type::<RigidVelocity>()
        .register_type::<RigidAcceleration>()
        .register_type::<RigidExchange>();
}
