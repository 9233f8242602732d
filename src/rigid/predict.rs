//! S1 for bodies (`Predict`): the GS4-II predictor of a body's velocity and rates (η = 0 with
//! the grid's (ρ∞, ρs), ALGORITHM §1.2 eq. 1.4; the gyroscopic acceleration in place of g for
//! the rotation), the wall contacts of the predicted motion and the pose at t_{n+1} the liquid
//! will meet ([`predict_rigid_bodies`]).
use bevy_ecs::prelude::*;

use super::active::{ActiveRigidBodies, RigidInstance, advance_pose_trapezoid};
use super::body::{
    RigidAcceleration, RigidBody, RigidExchange, RigidVelocity, shape_mass_properties,
};
use super::contact::resolve_wall_contacts;
use crate::collision::{Collider, ColliderPose};
use crate::config::MpmConfig;
use crate::failure::{FailureCollector, FailureReport};
use crate::step::schedule::StepContext;

/// S1 for bodies: the GS4 predictor of the velocity (module docs), the wall contacts of the
/// predicted motion and the pose at t_{n+1} the liquid will meet. Rebuilds
/// [`ActiveRigidBodies`]. A body with an unsupported shape stops the run with a report.
pub fn predict_rigid_bodies(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    failures: Res<FailureCollector>,
    mut active: ResMut<ActiveRigidBodies>,
    q: Query<(
        Entity,
        &RigidBody,
        &Collider,
        &ColliderPose,
        &RigidVelocity,
        &RigidAcceleration,
    )>,
) {
    let c = ctx.coefficients;
    let dt = c.dt;
    active.bodies.clear();
    let mut items: Vec<_> = q.iter().collect();
    items.sort_by_key(|it| it.0);
    for (entity, body, collider, pose, vel, acc) in items {
        if let Err(e) = shape_mass_properties(&collider.shape) {
            failures.record(FailureReport::global(
                "rigid body",
                f64::NAN,
                format!("rigid body {entity}: {e}"),
            ));
            continue;
        }
        let i_w = body.world_inertia(pose.rotation);
        let inv_i = body.world_inverse_inertia(pose.rotation);
        let gyroscopic = inv_i * (-vel.angular.cross(i_w * vel.angular));
        let da = (config.gravity - acc.linear) / c.w1l6;
        let dal = (gyroscopic - acc.angular) / c.w1l6;
        let predicted_acceleration = RigidAcceleration {
            linear: acc.linear + da,
            angular: acc.angular + dal,
        };
        let mut predicted_velocity = RigidVelocity {
            linear: vel.linear + (c.l4 * dt) * acc.linear + (c.l5 * dt) * da,
            angular: vel.angular + (c.l4 * dt) * acc.angular + (c.l5 * dt) * dal,
        };
        resolve_wall_contacts(
            &collider.shape,
            body,
            *pose,
            vel,
            &mut predicted_velocity,
            dt,
            &config,
        );
        let predicted_pose = advance_pose_trapezoid(*pose, vel, &predicted_velocity, dt);
        active.bodies.push(RigidInstance {
            entity,
            body: *body,
            shape: collider.shape.clone(),
            boundary: collider.boundary,
            pose: *pose,
            velocity: *vel,
            predicted_velocity,
            predicted_acceleration,
            predicted_pose,
            new_velocity: predicted_velocity,
            new_acceleration: predicted_acceleration,
            new_pose: predicted_pose,
            exchange: RigidExchange::default(),
        });
    }
}
