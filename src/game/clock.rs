//! The request of simulated time from Bevy's clock.
use bevy_ecs::prelude::*;
use bevy_time::Time;

use crate::step::pacing::FramePacing;

/// Asks the frame driver for the time Bevy's clock advanced this update (`Time<Virtual>` in
/// `Update`, `Time<Fixed>` in `FixedUpdate`; 0 while paused). Runs in
/// [`DriverSystems::Pace`](crate::step::pacing::DriverSystems::Pace).
pub fn request_from_time(time: Res<Time>, mut pacing: ResMut<FramePacing>) {
    *pacing = FramePacing::Requested {
        dt: time.delta_secs_f64(),
    };
}
