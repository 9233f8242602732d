//! Collision objects and the grid collision operator (ALGORITHM §2.11, choice D5).
//!
//! A collider is an entity with [`Collider`] (shape + boundary condition) and [`ColliderPose`];
//! add [`ColliderMotion`] to move it by script (its pose is advanced every step and the wall
//! velocity enters the projection). Domain walls are configured in
//! [`MpmConfig::walls`](crate::config::MpmConfig).
//!
//! The projection is applied to the new nodal velocity **and** to the new nodal acceleration,
//! so the GS4 memory does not re-inject the removed momentum (no artificial bounce, D5).
//!
//! Closed triangle meshes collide through [`ColliderShape::Mesh`] and a prepared [`MeshSdf`]
//! (module [`mesh`]).
pub mod mesh;

#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use std::sync::Arc;

use bevy_ecs::prelude::*;
use glam::Quat;
use serde::{Deserialize, Serialize};

use crate::config::BoundaryCondition;
use crate::math::{Real, Vec3};
pub use mesh::{MeshSdf, MeshSdfError};

/// Collider geometry in the collider's local frame (centred at the pose origin).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(
    feature = "reflect",
    derive(bevy_reflect::Reflect),
    reflect(opaque, Debug, PartialEq)
)]
#[serde(deny_unknown_fields)]
pub enum ColliderShape {
    /// Half-space {x : n·x ≤ 0}: the solid lies below the plane through the origin with
    /// outward unit normal `normal` (local frame).
    HalfSpace {
        /// Outward normal (normalised on use).
        normal: Vec3,
    },
    /// Solid sphere.
    Sphere {
        /// Radius \[m\].
        radius: Real,
    },
    /// Solid box.
    Box {
        /// Half extents \[m\].
        half_extents: Vec3,
    },
    /// Solid cylinder along the local y axis.
    Cylinder {
        /// Radius \[m\].
        radius: Real,
        /// Half height \[m\].
        half_height: Real,
    },
    /// Closed triangle mesh, prepared once ([`MeshSdf::new`], [`MeshSdf::from_obj`]) and shared
    /// by reference counting: cloning the shape (every step, for every collider) is cheap,
    /// and two `Mesh` shapes are equal only if they share the same `MeshSdf`. Not
    /// (de)serialisable: a scene file names the OBJ file instead (`docs/scenes.md`).
    #[serde(skip)]
    Mesh(Arc<MeshSdf>),
}

impl ColliderShape {
    /// Bounds of the solid in its local frame (min, max corners); `None` for the unbounded
    /// [`ColliderShape::HalfSpace`].
    pub fn local_bounds(&self) -> Option<(Vec3, Vec3)> {
        match *self {
            ColliderShape::HalfSpace { .. } => None,
            ColliderShape::Sphere { radius } => Some((Vec3::splat(-radius), Vec3::splat(radius))),
            ColliderShape::Box { half_extents } => Some((-half_extents, half_extents)),
            ColliderShape::Cylinder {
                radius,
                half_height,
            } => {
                let h = Vec3::new(radius, half_height, radius);
                Some((-h, h))
            }
            ColliderShape::Mesh(ref mesh) => Some(mesh.aabb()),
        }
    }

    /// Signed distance φ (negative inside the solid) and outward unit normal at local point `p`.
    ///
    /// For [`ColliderShape::Mesh`], φ is exact where φ ≤ [`MeshSdf::band`] and a positive lower
    /// bound farther outside, which is all the collision operator needs (it acts where φ ≤ 0).
    pub fn sdf(&self, p: Vec3) -> (Real, Vec3) {
        match *self {
            ColliderShape::Mesh(ref mesh) => mesh.sdf(p),
            ColliderShape::HalfSpace { normal } => {
                let n = normal.normalize_or_zero();
                (p.dot(n), n)
            }
            ColliderShape::Sphere { radius } => {
                let d = p.length();
                let n = if d > 0.0 { p / d } else { Vec3::Y };
                (d - radius, n)
            }
            ColliderShape::Box { half_extents } => box_sdf(p, half_extents),
            ColliderShape::Cylinder {
                radius,
                half_height,
            } => {
                let r = Vec3::new(p.x, 0.0, p.z);
                let rl = r.length();
                let dr = rl - radius;
                let dy = p.y.abs() - half_height;
                let radial_n = if rl > 0.0 { r / rl } else { Vec3::X };
                let axial_n = Vec3::new(0.0, p.y.signum(), 0.0);
                if dr > 0.0 && dy > 0.0 {
                    let v = Vec3::new(dr, dy, 0.0);
                    let d = v.length();
                    ((d), (radial_n * dr + axial_n * dy) / d)
                } else if dr > dy {
                    (dr, radial_n)
                } else {
                    (dy, axial_n)
                }
            }
        }
    }
}

fn box_sdf(p: Vec3, h: Vec3) -> (Real, Vec3) {
    let q = p.abs() - h;
    let outside = q.max(Vec3::ZERO);
    let out_len = outside.length();
    if out_len > 0.0 {
        let n = outside * p.signum() / out_len;
        (out_len, n)
    } else {
        // Inside: distance to the nearest face.
        let (axis, d) = if q.x >= q.y && q.x >= q.z {
            (0, q.x)
        } else if q.y >= q.z {
            (1, q.y)
        } else {
            (2, q.z)
        };
        let mut n = Vec3::ZERO;
        n[axis] = if p[axis] >= 0.0 { 1.0 } else { -1.0 };
        (d, n)
    }
}

/// A collision object. Its pose is [`ColliderPose`] (added at the origin if missing).
#[derive(Component, Clone, Debug, PartialEq)]
#[require(ColliderPose)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct Collider {
    /// Geometry.
    pub shape: ColliderShape,
    /// Sticky, slip or friction.
    pub boundary: BoundaryCondition,
}

/// World pose of a collider.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct ColliderPose {
    /// Translation of the local origin \[m\].
    pub translation: Vec3,
    /// Rotation local → world.
    pub rotation: Quat,
}

impl Default for ColliderPose {
    fn default() -> Self {
        Self {
            translation: Vec3::ZERO,
            rotation: Quat::IDENTITY,
        }
    }
}

/// Marks a collider whose motion and coupling with the grid belong to a plugin (a dynamic rigid
/// body): the core neither advances its pose (`commit::move_colliders`) nor collides grid nodes
/// with it (`predict::gather_colliders`), and the energy monitor counts its motion through
/// [`EnergyTerms`](crate::step::energy::EnergyTerms) instead of as scripted work.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct CoupledCollider;

/// Scripted rigid motion of a collider: constant linear and angular velocity about its origin.
/// Users may change it at run time (e.g. from a keyframe system) to script any path.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct ColliderMotion {
    /// Linear velocity \[m/s\].
    pub linear_velocity: Vec3,
    /// Angular velocity \[rad/s\] (world frame).
    pub angular_velocity: Vec3,
}

/// A scripted path of a collider's origin through keyframes (time \[s\], position \[m\]):
/// piecewise linear between them, at rest at the first key before its time and at the last
/// after it. Every step, the step system `follow_collider_paths` puts the origin on the path at
/// t_n and sets the [`ColliderMotion`]'s linear velocity to the mean velocity over the step,
/// (x(t_n + Δt) − x(t_n))/Δt, so the collider reaches x(t_{n+1}) exactly and the liquid sees
/// the velocity it moves with (a stamp pressed in, held, and pulled out). The rotation is the
/// pose's, turned by the motion's angular velocity if any.
#[derive(Component, Clone, Debug, PartialEq)]
#[require(ColliderMotion)]
pub struct ColliderPath {
    keys: Vec<(f64, Vec3)>,
}

impl ColliderPath {
    /// A path through `keys` (time \[s\], position \[m\]); at least one key, finite values,
    /// times strictly increasing.
    pub fn new(keys: Vec<(f64, Vec3)>) -> Result<Self, String> {
        if keys.is_empty() {
            return Err("a path needs at least one key".into());
        }
        for (i, (t, x)) in keys.iter().enumerate() {
            if !t.is_finite() || !x.is_finite() {
                return Err(format!("key {i} is not finite (time {t}, position {x})"));
            }
            if i > 0 && *t <= keys[i - 1].0 {
                return Err(format!(
                    "key times must increase: key {i} at {t} s follows {} s",
                    keys[i - 1].0
                ));
            }
        }
        Ok(Self { keys })
    }

    /// The keys (time \[s\], position \[m\]).
    pub fn keys(&self) -> &[(f64, Vec3)] {
        &self.keys
    }

    /// The largest speed along the path \[m/s\] (its fastest segment).
    pub fn max_speed(&self) -> Real {
        self.keys
            .windows(2)
            .map(|w| (w[1].1 - w[0].1).length() / (w[1].0 - w[0].0) as Real)
            .fold(0.0, Real::max)
    }

    /// Position of the origin at time `t` \[m\].
    pub fn at(&self, t: f64) -> Vec3 {
        let k = &self.keys;
        let i = k.partition_point(|(tk, _)| *tk <= t);
        if i == 0 {
            return k[0].1;
        }
        if i == k.len() {
            return k[i - 1].1;
        }
        let ((t0, x0), (t1, x1)) = (k[i - 1], k[i]);
        let s = ((t - t0) / (t1 - t0)) as Real;
        x0 + (x1 - x0) * s
    }
}

/// Removes its collider from the world at simulated time `remove_at` \[s\] (the end of the
/// first step reaching it), e.g. the bed under a printed object that is then dropped. Any
/// collider entity may carry it; rigid bodies too.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct ColliderLifetime {
    /// Simulated time of removal \[s\].
    pub remove_at: f64,
}

/// A collider flattened to world-frame data for the per-node loop.
#[derive(Clone, Debug)]
pub struct ColliderInstance {
    /// Local shape.
    pub shape: ColliderShape,
    /// Boundary condition.
    pub boundary: BoundaryCondition,
    /// Pose at the evaluation time.
    pub pose: ColliderPose,
    /// Motion (zero for static colliders).
    pub motion: ColliderMotion,
}

impl ColliderInstance {
    /// Signed distance, outward world normal and the object's velocity at world point `x`.
    #[inline]
    pub fn query(&self, x: Vec3) -> (Real, Vec3, Vec3) {
        let local = self.pose.rotation.inverse() * (x - self.pose.translation);
        let (phi, n_local) = self.shape.sdf(local);
        let n = self.pose.rotation * n_local;
        let v = self.motion.linear_velocity
            + self
                .motion
                .angular_velocity
                .cross(x - self.pose.translation);
        (phi, n, v)
    }
}

/// Projects a velocity relative to a wall (Stomakhin et al. 2013 §8; ALGORITHM §2.11).
/// `v` is the velocity, `v_wall` the wall velocity, `n` the outward unit normal.
/// Returns the projected velocity. Only an approaching motion (v_rel·n < 0) is modified,
/// except for `Sticky`, which always takes the wall velocity.
///
/// `extra_normal_speed` ≥ 0 is added to the removed normal speed |v_n| in the Coulomb bound
/// |Δv_t| ≤ μ_f (|v_n| + extra). The grid update passes (W₁Λ₆ − λ₅)Δt·|a_n| (the into-wall
/// acceleration the D5 projection removes): with the stored acceleration projected, a resting
/// contact removes only λ₅Δt Δa_n of normal velocity per step while the contact impulse is
/// W₁Λ₆Δt Δa_n, so without the extra term friction would be λ₅/W₁Λ₆ = 6/7 of Coulomb's for
/// (0.5, 0) (measured: M6 in `tests/it/mpm.rs`).
#[inline]
pub fn project_velocity(
    v: Vec3,
    v_wall: Vec3,
    n: Vec3,
    bc: BoundaryCondition,
    extra_normal_speed: Real,
) -> Vec3 {
    match bc {
        BoundaryCondition::Open | BoundaryCondition::Periodic => v,
        BoundaryCondition::Sticky => v_wall,
        BoundaryCondition::Slip => {
            let rel = v - v_wall;
            let vn = rel.dot(n);
            if vn >= 0.0 { v } else { rel - vn * n + v_wall }
        }
        BoundaryCondition::Friction(mu) => {
            let rel = v - v_wall;
            let vn = rel.dot(n);
            if vn >= 0.0 {
                return v;
            }
            let vt = rel - vn * n;
            let vt_len = vt.length();
            let bound = mu * (-vn + extra_normal_speed.max(0.0));
            if vt_len <= bound {
                v_wall
            } else {
                vt - (bound / vt_len) * vt + v_wall
            }
        }
    }
}

/// Projects a nodal acceleration with the same rule as its velocity (choice D5): the
/// into-wall normal component is removed (slip/friction, when the velocity was projected)
/// or the wall's acceleration (zero for scripted constant motion) is imposed (sticky).
#[inline]
pub fn project_acceleration(
    a: Vec3,
    n: Vec3,
    bc: BoundaryCondition,
    velocity_was_projected: bool,
) -> Vec3 {
    match bc {
        BoundaryCondition::Open | BoundaryCondition::Periodic => a,
        BoundaryCondition::Sticky => Vec3::ZERO,
        BoundaryCondition::Slip | BoundaryCondition::Friction(_) => {
            if !velocity_was_projected {
                return a;
            }
            let an = a.dot(n);
            if an < 0.0 { a - an * n } else { a }
        }
    }
}
