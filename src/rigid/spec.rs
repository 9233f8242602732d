//! Rigid bodies in scene files (`rigid_bodies: [ ... ]`, reference in `docs/scenes.md`):
//! [`RigidShape`], [`RigidBodySpec`] and its conversion to a [`RigidBodyBundle`]. Scene types
//! only, no numerics (the mass properties are [`RigidBody`]'s).
use glam::Mat3;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::body::{RigidBody, RigidBodyBundle, RigidBodyError, RigidVelocity};
use crate::collision::{Collider, ColliderPose, ColliderShape};
use crate::config::BoundaryCondition;
use crate::math::RotationSpec;
use crate::math::{Real, Vec3};

/// Shape of a rigid body in a scene file (local frame, centred at the centre of mass).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum RigidShape {
    /// Solid ball.
    Sphere {
        /// Radius \[m\]; > 0.
        radius: Real,
    },
    /// Solid box.
    Box {
        /// Half extents \[m\]; each > 0.
        half_extents: Vec3,
    },
}

impl RigidShape {
    /// The collider shape.
    pub fn collider_shape(&self) -> ColliderShape {
        match *self {
            RigidShape::Sphere { radius } => ColliderShape::Sphere { radius },
            RigidShape::Box { half_extents } => ColliderShape::Box { half_extents },
        }
    }
}

/// A rigid body in a scene file (`rigid_bodies: [ ... ]`, reference in `docs/scenes.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigidBodySpec {
    /// Geometry.
    pub shape: RigidShape,
    /// Density \[kg/m³\] of a homogeneous solid; give exactly one of `density` and `mass`.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "plain_some",
        serialize_with = "plain_number"
    )]
    pub density: Option<Real>,
    /// Total mass \[kg\] (homogeneous inertia); give exactly one of `density` and `mass`.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "plain_some",
        serialize_with = "plain_number"
    )]
    pub mass: Option<Real>,
    /// Position of the centre of mass \[m\].
    pub position: Vec3,
    /// Orientation. Default none.
    #[serde(default)]
    pub rotation: RotationSpec,
    /// Initial velocity \[m/s\]. Default `(0, 0, 0)`.
    #[serde(default)]
    pub velocity: Vec3,
    /// Initial angular velocity, world frame \[rad/s\]. Default `(0, 0, 0)`.
    #[serde(default)]
    pub angular_velocity: Vec3,
    /// Condition on its surface towards the liquid: `Sticky`, `Slip` or `Friction(μ)`.
    pub boundary: BoundaryCondition,
}

fn plain_some<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Real>, D::Error> {
    Real::deserialize(d).map(Some)
}

fn plain_number<S: Serializer>(v: &Option<Real>, s: S) -> Result<S::Ok, S::Error> {
    match v {
        Some(x) => s.serialize_f32(*x),
        None => s.serialize_none(),
    }
}

impl RigidBodySpec {
    /// The body's components (`gravity` initialises its acceleration). Fails only for specs
    /// that [`validate_rigid_bodies`](crate::rigid::validate_rigid_bodies) rejects.
    pub fn to_bundle(&self, gravity: Vec3) -> Result<RigidBodyBundle, RigidBodyError> {
        let shape = self.shape.collider_shape();
        let body = match (self.density, self.mass) {
            (Some(rho), None) => RigidBody::solid(&shape, rho)?,
            (None, Some(m)) => RigidBody::with_mass(&shape, m)?,
            (rho, m) => {
                return Err(RigidBodyError::NotPositive {
                    what: "exactly one of density and mass",
                    unit: "",
                    value: rho.or(m).unwrap_or(f32::NAN) as f64,
                });
            }
        };
        Ok(RigidBodyBundle::new(
            body,
            Collider {
                shape,
                boundary: self.boundary,
            },
            ColliderPose {
                translation: self.position,
                rotation: self.rotation.to_quat(),
            },
            RigidVelocity {
                linear: self.velocity,
                angular: self.angular_velocity,
            },
            gravity,
        ))
    }

    /// Half extents of the world-axis-aligned box around the body at its initial orientation.
    pub(super) fn half_aabb(&self) -> Vec3 {
        match self.shape {
            RigidShape::Sphere { radius } => Vec3::splat(radius),
            RigidShape::Box { half_extents } => {
                let r = Mat3::from_quat(self.rotation.to_quat());
                let abs = Mat3::from_cols(r.x_axis.abs(), r.y_axis.abs(), r.z_axis.abs());
                abs * half_extents
            }
        }
    }
}
