//! Colliders, nozzles and coupled bodies placed by their entity's `Transform`.
use bevy_ecs::hierarchy::ChildOf;
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use bevy_transform::components::{GlobalTransform, Transform};
use glam::Quat;

use crate::collision::{Collider, ColliderMotion, ColliderPose, CoupledCollider};
use crate::config::MpmConfig;
use crate::emit::EmitterFrame;
use crate::math::Vec3;
use crate::step::pacing::FramePacing;

/// Marks an entity whose pose comes from its `Transform` and that has been placed at least
/// once (added by [`follow_transforms`]).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct PlacedByTransform;

/// World pose of an entity: its `Transform` for a root entity, its `GlobalTransform` (from the
/// previous frame's propagation) for a child.
fn world_pose(t: &Transform, global: Option<&GlobalTransform>, child: bool) -> (Vec3, Quat) {
    match global {
        Some(g) if child => {
            let (_, rotation, translation) = g.to_scale_rotation_translation();
            (translation, rotation)
        }
        _ => (t.translation, t.rotation),
    }
}

/// Linear and angular velocity that move `from` to `to` in `dt` (the shorter rotation).
fn motion_between(from: (Vec3, Quat), to: (Vec3, Quat), dt: f64) -> (Vec3, Vec3) {
    if dt.is_nan() || dt <= 0.0 {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let dt = dt as f32;
    let mut delta = (to.1 * from.1.inverse()).normalize();
    if delta.w < 0.0 {
        delta = -delta;
    }
    let (axis, angle) = delta.to_axis_angle();
    let angular = if angle.is_finite() && angle > 0.0 {
        axis * (angle / dt)
    } else {
        Vec3::ZERO
    };
    ((to.0 - from.0) / dt, angular)
}

type Placed<'a> = (
    Entity,
    &'a Transform,
    Option<&'a GlobalTransform>,
    Has<ChildOf>,
    Has<PlacedByTransform>,
);

/// Before each frame: colliders with a `Transform` get the motion that takes them from their
/// current pose to the Transform's over the frame (their first pose is the Transform's);
/// nozzles get the Transform as their [`EmitterFrame`], with the frame's velocity; coupled
/// bodies take their first pose from the Transform. Runs in
/// [`DriverSystems::Pace`](crate::step::pacing::DriverSystems::Pace), after the clock.
#[allow(clippy::type_complexity)]
pub fn follow_transforms(
    mut commands: Commands,
    pacing: Res<FramePacing>,
    config: Res<MpmConfig>,
    mut colliders: Query<
        (Placed, &mut ColliderPose, Option<&mut ColliderMotion>),
        (With<Collider>, Without<CoupledCollider>),
    >,
    mut coupled: Query<(Placed, &mut ColliderPose), With<CoupledCollider>>,
    mut nozzles: Query<(Placed, &mut EmitterFrame), Without<Collider>>,
) {
    let dt = pacing.wanted(config.frame_dt);
    for ((entity, t, g, child, placed), mut pose, motion) in &mut colliders {
        let target = world_pose(t, g, child);
        let (linear_velocity, angular_velocity) = if placed {
            motion_between((pose.translation, pose.rotation), target, dt)
        } else {
            commands.entity(entity).insert(PlacedByTransform);
            pose.translation = target.0;
            pose.rotation = target.1;
            (Vec3::ZERO, Vec3::ZERO)
        };
        let new = ColliderMotion {
            linear_velocity,
            angular_velocity,
        };
        match motion {
            Some(mut m) => *m = new,
            None => {
                commands.entity(entity).insert(new);
            }
        }
    }
    for ((entity, t, g, child, placed), mut pose) in &mut coupled {
        if !placed {
            let (translation, rotation) = world_pose(t, g, child);
            *pose = ColliderPose {
                translation,
                rotation,
            };
            commands.entity(entity).insert(PlacedByTransform);
        }
    }
    for ((entity, t, g, child, placed), mut frame) in &mut nozzles {
        let target = world_pose(t, g, child);
        let (linear_velocity, angular_velocity) = if placed {
            motion_between((frame.translation, frame.rotation), target, dt)
        } else {
            commands.entity(entity).insert(PlacedByTransform);
            (Vec3::ZERO, Vec3::ZERO)
        };
        *frame = EmitterFrame {
            translation: target.0,
            rotation: target.1,
            linear_velocity,
            angular_velocity,
        };
    }
}

/// After each frame: coupled bodies (the crate's rigid bodies) write their pose to their
/// `Transform` (root entities). Runs in
/// [`DriverSystems::Publish`](crate::step::pacing::DriverSystems::Publish).
#[allow(clippy::type_complexity)]
pub fn publish_coupled_poses(
    mut q: Query<(&ColliderPose, &mut Transform), (With<CoupledCollider>, Without<ChildOf>)>,
) {
    for (pose, mut t) in &mut q {
        t.translation = pose.translation;
        t.rotation = pose.rotation;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn motion_between_poses() {
        let from = (Vec3::ZERO, Quat::IDENTITY);
        let to = (Vec3::new(1.0, 0.0, 0.0), Quat::from_rotation_y(0.5));
        let (v, w) = motion_between(from, to, 0.5);
        assert!((v - Vec3::new(2.0, 0.0, 0.0)).length() < 1e-6);
        assert!((w - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-5, "{w}");
        // The shorter way round: −0.5 rad, not 2π − 0.5.
        let (_, w) = motion_between(to, from, 0.5);
        assert!((w - Vec3::new(0.0, -1.0, 0.0)).length() < 1e-5, "{w}");
        assert_eq!(motion_between(from, to, 0.0), (Vec3::ZERO, Vec3::ZERO));
    }
}
