#![doc = include_str!("../README.md")]
#![warn(missing_docs)]

pub mod app;
pub mod collision;
pub mod components;
pub mod config;
pub mod diagnostics;
pub mod distributed;
pub mod emit;
pub mod failure;
#[cfg(feature = "game")]
pub mod game;
pub mod grid;
pub mod gs4;
pub mod kernels;
pub mod krylov;
pub mod material;
pub mod math;
pub mod mesh;
pub mod output;
pub(crate) mod parallel;
#[cfg(feature = "plot")]
pub mod plot;
pub mod plugin;
#[cfg(feature = "render")]
pub mod render;
#[cfg(feature = "plot")]
pub mod report;
pub mod rheology;
pub mod rigid;
pub mod runner;
pub mod sampling;
pub mod scatter;
pub mod scene;
#[cfg(feature = "plot")]
pub mod snapshot;
pub mod spawn;
pub mod step;
#[cfg(feature = "surface")]
pub mod surface;
pub mod thermal;
pub mod validation;

/// The step schedule's labels, resources and driver under their short paths
/// (canonical: [`step::schedule`] and [`step::driver`]).
pub mod schedule {
    pub use crate::step::driver::*;
    pub use crate::step::pacing::*;
    pub use crate::step::schedule::*;
}

/// Implicit viscosity under its short path (canonical: [`step::implicit`]).
pub mod implicit {
    pub use crate::step::implicit::*;
}

/// The types most applications need.
pub mod prelude {
    pub use crate::collision::{Collider, ColliderMotion, ColliderPose, ColliderShape};
    pub use crate::components::*;
    pub use crate::config::*;
    pub use crate::failure::{FailureReport, SimulationStatus};
    #[cfg(feature = "game")]
    pub use crate::game::{GamePlugin, LiquidBody, SpawnedLiquid};
    pub use crate::material::{FluidMaterial, MaterialId, Materials};
    pub use crate::math::{Mat3, Real, Vec3};
    pub use crate::plugin::{MpmCorePlugin, MpmPlugins};
    pub use crate::rheology::{
        Li2024ElastoPlastic, ModelRegistry, ModelSpec, NeoHookean, Rheology, RheologyCommandsExt,
        RheologyPlugin, RheologyTable, Su2021Unified, attach_model,
    };
    pub use crate::rigid::{
        RigidAcceleration, RigidBody, RigidBodyBundle, RigidBodyPlugin, RigidExchange,
        RigidVelocity,
    };
    pub use crate::step::pacing::{DriverSystems, FrameBudget, FramePacing, SimulationLag};
    pub use crate::step::schedule::{
        CommitSystems, ConstitutiveSystems, MpmStep, MpmSystems, SimulationClock,
    };
}
