//! The rigid bodies' `metrics.csv` columns: centre, velocity and angular velocity of each body
//! ([`metrics_columns`], [`metrics_values`]) for the bodies fixed when the run starts
//! ([`rigid_body_entities`], [`MetricsBodies`]).
use bevy_ecs::prelude::*;

use super::body::{RigidBody, RigidVelocity};
use crate::collision::ColliderPose;

/// The rigid bodies of `world` in entity order (the order of [`metrics_values`]).
pub fn rigid_body_entities(world: &mut World) -> Vec<Entity> {
    let mut q = world.query_filtered::<Entity, With<RigidBody>>();
    let mut list: Vec<Entity> = q.iter(world).collect();
    list.sort();
    list
}

/// The bodies the `rigid{i}_*` metrics columns of a run describe (fixed when the run starts).
#[derive(Resource, Clone, Debug, Default)]
pub struct MetricsBodies(pub Vec<Entity>);

/// Extra `metrics.csv` columns for `count` bodies: `rigid{i}_x, _y, _z` (centre \[m\]),
/// `_vx, _vy, _vz` (velocity \[m/s\]) and `_wx, _wy, _wz` (angular velocity \[rad/s\]).
pub fn metrics_columns(count: usize) -> Vec<String> {
    const SUFFIX: [&str; 9] = ["x", "y", "z", "vx", "vy", "vz", "wx", "wy", "wz"];
    (0..count)
        .flat_map(|i| SUFFIX.iter().map(move |s| format!("rigid{i}_{s}")))
        .collect()
}

/// The values of [`metrics_columns`] for `entities` (0 for a body that no longer exists).
pub fn metrics_values(world: &World, entities: &[Entity]) -> Vec<f64> {
    let mut out = Vec::with_capacity(9 * entities.len());
    for &e in entities {
        let pose = world.get::<ColliderPose>(e).copied().unwrap_or_default();
        let v = world.get::<RigidVelocity>(e).copied().unwrap_or_default();
        for x in [pose.translation, v.linear, v.angular] {
            out.extend(x.to_array().map(|c| c as f64));
        }
    }
    out
}
