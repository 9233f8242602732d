//! S15 for bodies (`Commit`): the wall contacts of the new velocity, the pose at t_{n+1} by the
//! trapezoidal rule (identity (1.1) of GS4, as for the particles) and the components
//! ([`commit_rigid_bodies`]); then the particles that ended inside a body are moved to its
//! surface, position only ([`push_particles_out_of_rigid_bodies`]).
use bevy_ecs::prelude::*;
use glam::Quat;

use super::active::{ActiveRigidBodies, advance_pose_trapezoid};
use super::body::{RigidAcceleration, RigidExchange, RigidVelocity, bounding_radius};
use super::contact::{keep_in_domain, resolve_wall_contacts};
use crate::collision::{ColliderMotion, ColliderPose, ColliderShape};
use crate::components::{Particle, Position};
use crate::config::MpmConfig;
use crate::failure::{FailureCollector, FailureReport};
use crate::math::Real;
use crate::step::schedule::StepContext;

/// S15 for bodies: wall contacts of the new velocity, the pose at t_{n+1} (trapezoidal rule),
/// and the components. A non-finite state stops the run with a report naming the body.
/// During a start-up evaluation without `consistent_startup` the stored rates are kept.
#[allow(clippy::type_complexity)]
pub fn commit_rigid_bodies(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    failures: Res<FailureCollector>,
    mut active: ResMut<ActiveRigidBodies>,
    mut q: Query<(
        &mut ColliderPose,
        &mut RigidVelocity,
        &mut RigidAcceleration,
        &mut RigidExchange,
        &mut ColliderMotion,
    )>,
) {
    let dt = ctx.coefficients.dt;
    let keep_rates = ctx.rate_evaluation && !config.integrator.consistent_startup;
    for inst in &mut active.bodies {
        let mut v = inst.new_velocity;
        let wall = resolve_wall_contacts(
            &inst.shape,
            &inst.body,
            inst.pose,
            &inst.velocity,
            &mut v,
            dt,
            &config,
        );
        let mut pose = advance_pose_trapezoid(inst.pose, &inst.velocity, &v, dt);
        keep_in_domain(&inst.shape, &mut pose, &config);
        let a = inst.new_acceleration;
        for (name, value) in [
            ("velocity", v.linear),
            ("angular velocity", v.angular),
            ("acceleration", a.linear),
            ("angular acceleration", a.angular),
            ("position", pose.translation),
        ] {
            if let Some(bad) = value.to_array().into_iter().find(|x| !x.is_finite()) {
                failures.record(FailureReport::global(
                    &format!("rigid body {name}"),
                    bad as f64,
                    format!("rigid body {} has a non-finite {name}", inst.entity),
                ));
                return;
            }
        }
        inst.new_velocity = v;
        inst.new_pose = pose;
        inst.exchange.wall_impulse = wall;
        let Ok((mut p, mut vel, mut acc, mut ex, mut motion)) = q.get_mut(inst.entity) else {
            continue;
        };
        *p = pose;
        *vel = v;
        if !keep_rates {
            *acc = a;
        }
        *ex = inst.exchange;
        *motion = ColliderMotion {
            linear_velocity: v.linear,
            angular_velocity: v.angular,
        };
    }
}

/// Moves particles that ended inside a body to its surface (position only; module docs).
pub fn push_particles_out_of_rigid_bodies(
    config: Res<MpmConfig>,
    active: Res<ActiveRigidBodies>,
    mut q: Query<&mut Position, With<Particle>>,
) {
    if active.bodies.is_empty() {
        return;
    }
    let periodic = config.walls.periodic_axes();
    let len = config.domain_max - config.domain_min;
    let bodies: Vec<(&ColliderShape, ColliderPose, Quat, Real)> = active
        .bodies
        .iter()
        .map(|b| {
            let r = bounding_radius(&b.shape);
            (&b.shape, b.new_pose, b.new_pose.rotation.inverse(), r * r)
        })
        .collect();
    q.par_iter_mut().for_each(|mut x| {
        let mut p = x.0;
        for (shape, pose, inv_rot, rb2) in &bodies {
            let mut d = p - pose.translation;
            for a in 0..3 {
                if periodic[a] {
                    d[a] -= len[a] * (d[a] / len[a]).round();
                }
            }
            if d.length_squared() >= *rb2 {
                continue;
            }
            let (phi, n) = shape.sdf(*inv_rot * d);
            if phi < 0.0 {
                p -= phi * (pose.rotation * n);
            }
        }
        if p != x.0 {
            x.0 = p;
        }
    });
}
