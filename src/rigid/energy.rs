//! The bodies' mechanical energy for the energy monitor (`Monitor`, ALGORITHM §7): kinetic and
//! potential energy and mass added to the step's [`EnergyTerms`] ([`rigid_body_energy`]).
use bevy_ecs::prelude::*;

use super::body::{RigidBody, RigidVelocity};
use crate::collision::ColliderPose;
use crate::config::MpmConfig;
use crate::step::energy::EnergyTerms;

/// The bodies' mechanical energy for the energy monitor (§7): Σ ½M|V|² + ½ωᵀIω and −M g·X.
pub fn rigid_body_energy(
    config: Res<MpmConfig>,
    mut terms: ResMut<EnergyTerms>,
    bodies: Query<(&RigidBody, &RigidVelocity, &ColliderPose)>,
) {
    let g = config.gravity.as_dvec3();
    for (b, v, pose) in &bodies {
        let m = b.mass as f64;
        let inertia = b.world_inertia(pose.rotation).as_dmat3();
        let w = v.angular.as_dvec3();
        terms.kinetic += 0.5 * m * v.linear.as_dvec3().length_squared() + 0.5 * w.dot(inertia * w);
        terms.potential -= m * g.dot(pose.translation.as_dvec3());
        terms.mass += m;
    }
}
