//! The bodies' share of the time-step control (`Monitor`): the advection limit of
//! ALGORITHM §2.15 for a body's fastest surface point |V| + |Ω| r_b
//! ([`limit_time_step_by_rigid_bodies`]).
use bevy_ecs::prelude::*;

use super::active::ActiveRigidBodies;
use super::body::bounding_radius;
use crate::config::{MpmConfig, TimeStepMode};
use crate::failure::SimulationStatus;
use crate::math::Real;
use crate::step::schedule::SimulationClock;

/// Caps the next step by the advection limit of the bodies' fastest surface points (§2.15):
/// C_s·C_adv·Δx/(|V| + |Ω| r_b) in adaptive mode, 0.5 Δx/(…) with the paper's rule; a fixed
/// step is left alone. Bodies farther than their size from the domain are ignored.
pub fn limit_time_step_by_rigid_bodies(
    config: Res<MpmConfig>,
    active: Res<ActiveRigidBodies>,
    status: Res<SimulationStatus>,
    mut clock: ResMut<SimulationClock>,
) {
    if status.failed() {
        return;
    }
    let mut speed: Real = 0.0;
    for b in &active.bodies {
        let rb = bounding_radius(&b.shape);
        let c = b.new_pose.translation;
        let near = (0..3).all(|a| {
            c[a] >= config.domain_min[a] - 2.0 * rb && c[a] <= config.domain_max[a] + 2.0 * rb
        });
        if near {
            speed =
                speed.max(b.new_velocity.linear.length() + rb * b.new_velocity.angular.length());
        }
    }
    if speed <= 0.0 {
        return;
    }
    let ts = &config.time_step;
    let dx = config.dx as f64;
    let speed = speed as f64;
    let limit = ts.advection * dx / speed;
    clock.predicted_limit = clock.predicted_limit.min(limit);
    let next = match ts.mode {
        TimeStepMode::Adaptive => ts.safety * limit,
        TimeStepMode::Paper => 0.5 * dx / speed,
        TimeStepMode::Fixed(_) => return,
    };
    clock.next_dt = clock.next_dt.min(next);
}
