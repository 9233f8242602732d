//! Contacts of a body with the domain walls: restitution 0 and the wall's condition (`Sticky`,
//! `Slip`, `Friction(μ)`: the conditions of ALGORITHM §2.11 applied to the body as a whole),
//! solved by projected Gauss–Seidel on the support points that penetrate at the end-of-step
//! pose, and the translation that keeps a body inside the domain and wraps it along periodic
//! axes (see the module docs). Used by the predictor and the commit.
use glam::Mat3;

use super::active::advance_pose_trapezoid;
use super::body::{RigidBody, RigidVelocity};
use crate::collision::{ColliderPose, ColliderShape};
use crate::config::{BoundaryCondition, DomainWalls, MpmConfig};
use crate::math::{Real, Vec3};

/// Projected Gauss–Seidel sweeps of the wall-contact solve.
pub const WALL_CONTACT_ITERATIONS: usize = 16;

/// Points of the body that can touch a domain wall: the sphere's six extreme points, the box's
/// eight corners.
fn support_points(shape: &ColliderShape, pose: &ColliderPose) -> Vec<Vec3> {
    let c = pose.translation;
    if let ColliderShape::Sphere { radius } = *shape {
        Vec3::AXES
            .iter()
            .flat_map(|a| [c - radius * *a, c + radius * *a])
            .collect()
    } else if let ColliderShape::Box { half_extents: h } = *shape {
        (0..8)
            .map(|k| {
                let s = Vec3::new(
                    if k & 1 == 0 { -1.0 } else { 1.0 },
                    if k & 2 == 0 { -1.0 } else { 1.0 },
                    if k & 4 == 0 { -1.0 } else { 1.0 },
                );
                c + pose.rotation * (s * h)
            })
            .collect()
    } else {
        Vec::new()
    }
}

/// The walls that constrain a body: (axis, upper, inward normal, condition).
fn constraining_walls(
    walls: &DomainWalls,
) -> impl Iterator<Item = (usize, bool, Vec3, BoundaryCondition)> + '_ {
    (0..3).flat_map(move |axis| {
        [false, true].into_iter().filter_map(move |upper| {
            let bc = walls.face(axis, upper);
            if matches!(bc, BoundaryCondition::Open | BoundaryCondition::Periodic) {
                return None;
            }
            let n = if upper {
                -Vec3::AXES[axis]
            } else {
                Vec3::AXES[axis]
            };
            Some((axis, upper, n, bc))
        })
    })
}

/// Depth of point `p` beyond a wall (> 0: outside the domain).
fn wall_depth(p: Vec3, axis: usize, upper: bool, config: &MpmConfig) -> Real {
    if upper {
        p[axis] - config.domain_max[axis]
    } else {
        config.domain_min[axis] - p[axis]
    }
}

struct WallContact {
    r: Vec3,
    n: Vec3,
    mu: Real,
    normal_impulse: Real,
    tangent_impulse: Vec3,
}

/// Velocity change of the body for an impulse `p` at offset `r` from its centre.
#[inline]
fn apply_impulse(v: &mut RigidVelocity, inv_mass: Real, inv_inertia: &Mat3, r: Vec3, p: Vec3) {
    v.linear += inv_mass * p;
    v.angular += *inv_inertia * r.cross(p);
}

/// Inverse effective mass of the body at offset `r` along unit direction `d`.
#[inline]
fn inverse_effective_mass(inv_mass: Real, inv_inertia: &Mat3, r: Vec3, d: Vec3) -> Real {
    inv_mass + d.dot((*inv_inertia * r.cross(d)).cross(r))
}

/// Resolves the domain-wall contacts of a body moving from `pose` with `v0` to the end of the
/// step with `v` (restitution 0, Coulomb friction from the wall's condition; see the module
/// docs). Returns the wall impulse \[kg m/s\]; `v` is changed in place.
pub(super) fn resolve_wall_contacts(
    shape: &ColliderShape,
    body: &RigidBody,
    pose: ColliderPose,
    v0: &RigidVelocity,
    v: &mut RigidVelocity,
    dt: Real,
    config: &MpmConfig,
) -> Vec3 {
    let end = advance_pose_trapezoid(pose, v0, v, dt);
    let points = support_points(shape, &end);
    let mut contacts = Vec::new();
    for (axis, upper, n, bc) in constraining_walls(&config.walls) {
        let mu = match bc {
            BoundaryCondition::Sticky => Real::INFINITY,
            BoundaryCondition::Friction(mu) => mu.max(0.0),
            _ => 0.0,
        };
        for p in &points {
            if wall_depth(*p, axis, upper, config) > 0.0 {
                contacts.push(WallContact {
                    r: *p - end.translation,
                    n,
                    mu,
                    normal_impulse: 0.0,
                    tangent_impulse: Vec3::ZERO,
                });
            }
        }
    }
    if contacts.is_empty() {
        return Vec3::ZERO;
    }
    let inv_mass = 1.0 / body.mass;
    let inv_i = body.world_inverse_inertia(end.rotation);
    let mut total = Vec3::ZERO;
    for _ in 0..WALL_CONTACT_ITERATIONS {
        for c in &mut contacts {
            let vn = (v.linear + v.angular.cross(c.r)).dot(c.n);
            let kn = inverse_effective_mass(inv_mass, &inv_i, c.r, c.n);
            let jn = (c.normal_impulse - vn / kn).max(0.0);
            let dj = (jn - c.normal_impulse) * c.n;
            c.normal_impulse = jn;
            apply_impulse(v, inv_mass, &inv_i, c.r, dj);
            total += dj;
            if c.mu <= 0.0 {
                continue;
            }
            let vp = v.linear + v.angular.cross(c.r);
            let vt = vp - vp.dot(c.n) * c.n;
            let vt_len = vt.length();
            if vt_len <= 0.0 {
                continue;
            }
            let t = vt / vt_len;
            let kt = inverse_effective_mass(inv_mass, &inv_i, c.r, t);
            let mut jt = c.tangent_impulse - (vt_len / kt) * t;
            let bound = c.mu * c.normal_impulse;
            if jt.length() > bound {
                jt *= bound / jt.length();
            }
            let dj = jt - c.tangent_impulse;
            c.tangent_impulse = jt;
            apply_impulse(v, inv_mass, &inv_i, c.r, dj);
            total += dj;
        }
    }
    total
}

/// Translates a body out of the constraining walls and wraps it along periodic axes.
pub(super) fn keep_in_domain(shape: &ColliderShape, pose: &mut ColliderPose, config: &MpmConfig) {
    for (axis, upper, n, _) in constraining_walls(&config.walls) {
        let depth = support_points(shape, pose)
            .iter()
            .map(|p| wall_depth(*p, axis, upper, config))
            .fold(0.0, Real::max);
        if depth > 0.0 {
            pose.translation += depth * n;
        }
    }
    let periodic = config.walls.periodic_axes();
    for (a, _) in periodic.iter().enumerate().filter(|(_, p)| **p) {
        let (lo, hi) = (config.domain_min[a], config.domain_max[a]);
        let x = pose.translation[a];
        if x < lo || x >= hi {
            pose.translation[a] = lo + (x - lo).rem_euclid(hi - lo);
        }
    }
}
