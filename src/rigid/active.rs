//! The bodies of the current step: [`RigidInstance`] (state at t_n, predicted and new) and
//! [`ActiveRigidBodies`] (rebuilt in `Predict`, read by the coupling, the commit and the time
//! step), and the trapezoidal pose update [`advance_pose_trapezoid`] (identity (1.1) of GS4)
//! that the predictor, the wall contacts and the commit share.
use bevy_ecs::prelude::*;
use glam::Quat;

use super::body::{RigidAcceleration, RigidBody, RigidExchange, RigidVelocity};
use crate::collision::{ColliderPose, ColliderShape};
use crate::config::BoundaryCondition;
use crate::math::Real;

/// One body during a step: its state at t_n, the predicted and the new state.
#[derive(Clone, Debug)]
pub struct RigidInstance {
    /// The body's entity.
    pub entity: Entity,
    /// Mass properties.
    pub body: RigidBody,
    /// Shape.
    pub shape: ColliderShape,
    /// Condition towards the liquid.
    pub boundary: BoundaryCondition,
    /// Pose at t_n.
    pub pose: ColliderPose,
    /// Velocity at t_n.
    pub velocity: RigidVelocity,
    /// Predicted velocity V̂, Ω̂ (after the wall contacts).
    pub predicted_velocity: RigidVelocity,
    /// Predicted rates Â, α̂.
    pub predicted_acceleration: RigidAcceleration,
    /// Pose at t_{n+1} moved with the predicted velocity: where the liquid meets the body.
    pub predicted_pose: ColliderPose,
    /// Velocity at t_{n+1} (after the exchange; the walls act in `Commit`).
    pub new_velocity: RigidVelocity,
    /// Rates at t_{n+1}.
    pub new_acceleration: RigidAcceleration,
    /// Pose at t_{n+1} (set in `Commit`).
    pub new_pose: ColliderPose,
    /// This step's exchange.
    pub exchange: RigidExchange,
}

/// The bodies of the current step, in entity order (rebuilt in `Predict`).
#[derive(Resource, Clone, Debug, Default)]
pub struct ActiveRigidBodies {
    /// The bodies.
    pub bodies: Vec<RigidInstance>,
}

/// Pose after moving for `dt` with the mean of two velocities (trapezoidal rule, identity 1.1).
pub fn advance_pose_trapezoid(
    pose: ColliderPose,
    v0: &RigidVelocity,
    v1: &RigidVelocity,
    dt: Real,
) -> ColliderPose {
    let w = 0.5 * (v0.angular + v1.angular);
    let angle = w.length() * dt;
    let rotation = if angle > 0.0 {
        (Quat::from_axis_angle(w.normalize(), angle) * pose.rotation).normalize()
    } else {
        pose.rotation
    };
    ColliderPose {
        translation: pose.translation + (0.5 * dt) * (v0.linear + v1.linear),
        rotation,
    }
}
