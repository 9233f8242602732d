//! S15: commit of the particle density pair, particle-level collisions, open boundaries, and
//! scripted collider motion (ALGORITHM §2.6, §2.11).
//!
//! ρⁿ⁺¹ = ρ + λ₄Δt ρ̇ + λ₅Δt Δρ̇, ρ̇ⁿ⁺¹ = ρ̇ + Δρ̇. Particles that ended inside a wall or a
//! collider are pushed back to its surface and lose their into-wall velocity (Stomakhin et al.
//! 2013, recommended in §2.11). Particles that left through an open face are despawned.
//!
//! Rheology models add their own commit systems to `MpmSystems::Commit`.
use bevy_ecs::prelude::*;

use crate::collision::{ColliderMotion, ColliderPose};
use crate::components::{Density, Particle, Position, PredictedDensity, Velocity};
use crate::config::{BoundaryCondition, MpmConfig};
use crate::math::Vec3;
use crate::step::schedule::{ActiveColliders, SimulationClock, StepContext};

/// Density commit.
pub fn commit_density(
    ctx: Res<StepContext>,
    mut q: Query<(&PredictedDensity, &mut Density), With<Particle>>,
) {
    let c = ctx.coefficients;
    q.par_iter_mut().for_each(|(rt, mut rho)| {
        let rho = rho.bypass_change_detection();
        rho.value += c.l4 * c.dt * rho.rate + c.l5 * c.dt * rt.rate_increment;
        rho.rate += rt.rate_increment;
    });
}

/// Pushes particles out of walls and colliders; flags particles beyond open faces.
pub fn particle_collisions(
    config: Res<MpmConfig>,
    colliders: Res<ActiveColliders>,
    mut q: Query<(&mut Position, &mut Velocity), With<Particle>>,
) {
    let walls = config.walls;
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    let list = &colliders.list;
    let periodic = walls.periodic_axes();
    q.par_iter_mut().for_each(|(mut x, mut v)| {
        let mut p = x.0;
        let mut vel = v.0;
        for c in list {
            let (phi, n, vw) = c.query(p);
            if phi < 0.0 && !matches!(c.boundary, BoundaryCondition::Open) {
                p -= phi * n;
                let vn = (vel - vw).dot(n);
                if vn < 0.0 {
                    vel -= vn * n;
                }
            }
        }
        for axis in 0..3 {
            if periodic[axis] {
                let len = dmax[axis] - dmin[axis];
                if p[axis] < dmin[axis] || p[axis] >= dmax[axis] {
                    p[axis] = dmin[axis] + (p[axis] - dmin[axis]).rem_euclid(len);
                }
                continue;
            }
            if !matches!(walls.face(axis, false), BoundaryCondition::Open) && p[axis] < dmin[axis] {
                p[axis] = dmin[axis];
                vel[axis] = vel[axis].max(0.0);
            }
            if !matches!(walls.face(axis, true), BoundaryCondition::Open) && p[axis] > dmax[axis] {
                p[axis] = dmax[axis];
                vel[axis] = vel[axis].min(0.0);
            }
        }
        if p != x.0 {
            x.0 = p;
        }
        if vel != v.0 {
            v.0 = vel;
        }
    });
}

/// Despawns particles that left the domain through an open face (counted in the clock).
pub fn remove_escaped(
    mut commands: Commands,
    config: Res<MpmConfig>,
    mut clock: ResMut<SimulationClock>,
    q: Query<(Entity, &Position), With<Particle>>,
) {
    let w = config.walls;
    let any_open = (0..3).any(|a| {
        matches!(w.face(a, false), BoundaryCondition::Open)
            || matches!(w.face(a, true), BoundaryCondition::Open)
    });
    if !any_open {
        return;
    }
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    for (e, x) in &q {
        let outside = x.0.cmplt(dmin).any() || x.0.cmpgt(dmax).any();
        if outside {
            commands.entity(e).despawn();
            clock.escaped_particles += 1;
        }
    }
}

/// Despawns colliders whose [`ColliderLifetime`](crate::collision::ColliderLifetime) ends by
/// t_{n+1}.
pub fn expire_colliders(
    mut commands: Commands,
    ctx: Res<StepContext>,
    clock: Res<crate::step::schedule::SimulationClock>,
    q: Query<(Entity, &crate::collision::ColliderLifetime)>,
) {
    let t_next = clock.time + ctx.dt;
    for (e, life) in &q {
        if t_next >= life.remove_at {
            commands.entity(e).despawn();
        }
    }
}

/// Advances scripted colliders to t_{n+1} (a [`CoupledCollider`](crate::collision::CoupledCollider) is moved by its plugin).
pub fn move_colliders(
    ctx: Res<StepContext>,
    mut q: Query<(&mut ColliderPose, &ColliderMotion), Without<crate::collision::CoupledCollider>>,
) {
    let dt = ctx.coefficients.dt;
    for (mut pose, motion) in &mut q {
        if motion.linear_velocity == Vec3::ZERO && motion.angular_velocity == Vec3::ZERO {
            continue;
        }
        *pose = advance_pose(*pose, motion, dt);
    }
}

/// Pose after moving with `motion` for `dt`.
pub fn advance_pose(pose: ColliderPose, motion: &ColliderMotion, dt: f32) -> ColliderPose {
    let w = motion.angular_velocity;
    let angle = w.length() * dt;
    let rotation = if angle > 0.0 {
        (glam::Quat::from_axis_angle(w.normalize(), angle) * pose.rotation).normalize()
    } else {
        pose.rotation
    };
    ColliderPose {
        translation: pose.translation + motion.linear_velocity * dt,
        rotation,
    }
}
