//! How much simulated time one `App::update` advances, and within what budget.
//!
//! - [`FramePacing::Fixed`] (the default; CLI, reports, tests): one frame of exactly
//!   [`MpmConfig::frame_dt`](crate::config::MpmConfig::frame_dt), every sub-step the time-step
//!   rule asks for. Deterministic.
//! - [`FramePacing::Requested`]: the update advances by the time a clock asked for (a game's
//!   frame time, written every update by `game::GameClockPlugin` from Bevy's `Time`), within
//!   a [`FrameBudget`] of sub-steps and wall time. When the liquid cannot keep up, simulated
//!   time falls behind instead of the frame stalling: the part of the request the budget did
//!   not allow is dropped, not carried over (carrying it would make every later frame slower
//!   still), and recorded in [`SimulationLag`].
//!
//! The systems that set the request or place things before a frame run in
//! [`DriverSystems::Pace`] of the driver's schedule, the driver in [`DriverSystems::Advance`],
//! what reads the result back (e.g. rigid bodies written to `Transform`) in
//! [`DriverSystems::Publish`].
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectResource;
use std::time::Duration;

use bevy_ecs::intern::Interned;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleLabel;

/// The sets of the frame driver's schedule (the `schedule` of
/// [`MpmCorePlugin`](crate::plugin::MpmCorePlugin), `Update` by default), in this order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DriverSystems {
    /// Before the frame: the clock's request, things placed by `Transform`. Game code that
    /// moves colliders or emitters orders itself before this set.
    Pace,
    /// The frame driver ([`advance_frame`](super::driver::advance_frame)).
    Advance,
    /// After the frame: results written back (rigid bodies to `Transform`).
    Publish,
}

/// The schedule the frame driver runs in (inserted by
/// [`MpmCorePlugin`](crate::plugin::MpmCorePlugin)); plugins that add systems around the driver
/// read it in `Plugin::finish`, so the order in which plugins are added does not matter.
#[derive(Resource, Clone, Copy, Debug)]
pub struct DriverSchedule(pub Interned<dyn ScheduleLabel>);

/// How much simulated time the next `App::update` advances (see the module docs).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Resource))]
pub enum FramePacing {
    /// One frame of exactly `MpmConfig::frame_dt`, with every sub-step (deterministic).
    #[default]
    Fixed,
    /// `dt` seconds of simulated time (≥ 0; 0 pauses), within the [`FrameBudget`].
    Requested {
        /// The simulated time wanted this update \[s\].
        dt: f64,
    },
}

impl FramePacing {
    /// The simulated time this update asks for \[s\] (`frame_dt` for [`FramePacing::Fixed`]).
    pub fn wanted(&self, frame_dt: f64) -> f64 {
        match *self {
            FramePacing::Fixed => frame_dt,
            FramePacing::Requested { dt } => dt,
        }
    }
}

/// Limits on the work of one update under [`FramePacing::Requested`] (ignored by
/// [`FramePacing::Fixed`], whose frames always complete). `None` = no limit.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Resource))]
pub struct FrameBudget {
    /// At most this many sub-steps per update.
    pub max_substeps: Option<u32>,
    /// No new sub-step starts once this much wall time has passed in the update (the step
    /// that is running finishes, so one step's time may be exceeded).
    pub max_wall_time: Option<Duration>,
}

impl FrameBudget {
    /// At most `n` sub-steps per update.
    pub fn substeps(n: u32) -> Self {
        Self {
            max_substeps: Some(n),
            ..Self::default()
        }
    }

    /// At most `ms` milliseconds of wall time per update.
    pub fn wall_millis(ms: u64) -> Self {
        Self {
            max_wall_time: Some(Duration::from_millis(ms)),
            ..Self::default()
        }
    }
}

/// How far simulated time has fallen behind the time the clock asked for, written by the
/// frame driver after every update. A game reads it to show or react to the lag (coarser
/// particles, a smaller sound speed, fewer liquids).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Resource))]
pub struct SimulationLag {
    /// Simulated time requested but not simulated in the last update \[s\].
    pub last_frame: f64,
    /// The same, summed over all updates \[s\].
    pub total: f64,
    /// Updates cut short by the budget.
    pub frames_behind: u64,
    /// Sub-steps taken in the last update.
    pub last_substeps: u32,
    /// Whether the one-time warning has been logged.
    pub warned: bool,
}
