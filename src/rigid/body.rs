//! The components of a dynamic rigid body and its mass properties: [`RigidBody`] (mass and
//! principal inertia, homogeneous spheres and boxes), [`RigidVelocity`], [`RigidAcceleration`]
//! (the GS4 rates, ALGORITHM §2.1), [`RigidExchange`] (what the coupling gave the body) and
//! [`RigidBodyBundle`].
use bevy_ecs::lifecycle::HookContext;
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use bevy_ecs::world::DeferredWorld;
use glam::{Mat3, Quat};

use crate::collision::{Collider, ColliderMotion, ColliderPose, ColliderShape, CoupledCollider};
use crate::math::{Real, Vec3};

/// Why a rigid body cannot be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RigidBodyError {
    /// Only spheres and boxes have mass properties and wall contacts.
    #[error("rigid bodies support the Sphere and Box shapes only (got {0})")]
    UnsupportedShape(String),
    /// A size, mass, density or inertia is not a finite positive number.
    #[error("{what} must be a finite number > 0 {unit} (got {value})")]
    NotPositive {
        /// The quantity.
        what: &'static str,
        /// Its unit.
        unit: &'static str,
        /// The value found.
        value: f64,
    },
}

/// Mass properties of a dynamic rigid body. The body's origin ([`ColliderPose::translation`])
/// is its centre of mass; the collider's local axes are its principal axes.
///
/// Requires (and adds with defaults) [`RigidVelocity`], [`RigidAcceleration`],
/// [`RigidExchange`] and [`ColliderMotion`]; the entity also needs a [`Collider`] (sphere or
/// box), whose [`ColliderPose`] it requires in turn (in a game, a `Transform` sets it). Build
/// it with [`RigidBody::solid`] or [`RigidBody::with_mass`]:
/// `(RigidBody::solid(&shape, 500.0)?, Collider { shape, boundary }, ColliderPose { .. })` is a
/// complete body at rest. A body added with a zero [`RigidAcceleration`] starts in free fall
/// (the hook sets its rate to `MpmConfig::gravity`, as [`RigidBodyBundle::new`] does; the
/// consistent start-up of §2.14 overwrites it for the bodies present at the start).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[component(on_add = start_in_free_fall)]
#[require(
    RigidVelocity,
    RigidAcceleration,
    RigidExchange,
    ColliderMotion,
    CoupledCollider
)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct RigidBody {
    /// Mass M \[kg\]; > 0.
    pub mass: Real,
    /// Principal moments of inertia about the centre of mass, along the collider's local
    /// x, y, z axes \[kg m²\]; each > 0.
    pub inertia: Vec3,
}

/// `on_add` hook of [`RigidBody`]: a zero GS4 rate becomes free fall (see [`RigidBody`]).
fn start_in_free_fall(mut world: DeferredWorld, ctx: HookContext) {
    let Some(g) = world
        .get_resource::<crate::config::MpmConfig>()
        .map(|c| c.gravity)
    else {
        return;
    };
    if let Some(mut a) = world.get_mut::<RigidAcceleration>(ctx.entity)
        && *a == RigidAcceleration::default()
    {
        a.linear = g;
    }
}

/// Volume \[m³\] and inertia per unit mass \[m²\] of a supported shape.
pub(super) fn shape_mass_properties(shape: &ColliderShape) -> Result<(f64, Vec3), RigidBodyError> {
    if let ColliderShape::Sphere { radius } = *shape {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(RigidBodyError::NotPositive {
                what: "radius",
                unit: "m",
                value: radius as f64,
            });
        }
        let r = radius as f64;
        Ok((
            4.0 / 3.0 * std::f64::consts::PI * r * r * r,
            Vec3::splat(0.4 * radius * radius),
        ))
    } else if let ColliderShape::Box { half_extents: h } = *shape {
        if !(h.is_finite() && h.min_element() > 0.0) {
            return Err(RigidBodyError::NotPositive {
                what: "every half extent",
                unit: "m",
                value: h.min_element() as f64,
            });
        }
        let hd = h.as_dvec3();
        let sq = h * h;
        Ok((
            8.0 * hd.x * hd.y * hd.z,
            Vec3::new(sq.y + sq.z, sq.x + sq.z, sq.x + sq.y) / 3.0,
        ))
    } else {
        Err(RigidBodyError::UnsupportedShape(shape_name(shape)))
    }
}

/// The variant name of a shape (its `Debug` text up to the first non-identifier character).
fn shape_name(shape: &ColliderShape) -> String {
    format!("{shape:?}")
        .chars()
        .take_while(|c| c.is_alphanumeric() || *c == '_')
        .collect()
}

/// Radius of a sphere around the body's origin that contains it \[m\] (0 if unsupported).
pub fn bounding_radius(shape: &ColliderShape) -> Real {
    if let ColliderShape::Sphere { radius } = *shape {
        radius
    } else if let ColliderShape::Box { half_extents } = *shape {
        half_extents.length()
    } else {
        0.0
    }
}

impl RigidBody {
    /// A body with the given mass \[kg\] and principal inertia \[kg m²\].
    pub fn new(mass: Real, inertia: Vec3) -> Result<Self, RigidBodyError> {
        if !(mass.is_finite() && mass > 0.0) {
            return Err(RigidBodyError::NotPositive {
                what: "mass",
                unit: "kg",
                value: mass as f64,
            });
        }
        if !(inertia.is_finite() && inertia.min_element() > 0.0) {
            return Err(RigidBodyError::NotPositive {
                what: "every principal moment of inertia",
                unit: "kg m²",
                value: inertia.min_element() as f64,
            });
        }
        Ok(Self { mass, inertia })
    }

    /// A homogeneous solid of `density` \[kg/m³\]: sphere M = ρ·4/3πr³, I = 2/5 Mr²; box with
    /// half extents h: M = 8ρ h_x h_y h_z, I_x = M(h_y² + h_z²)/3 (cyclic).
    pub fn solid(shape: &ColliderShape, density: Real) -> Result<Self, RigidBodyError> {
        if !(density.is_finite() && density > 0.0) {
            return Err(RigidBodyError::NotPositive {
                what: "density",
                unit: "kg/m³",
                value: density as f64,
            });
        }
        let (volume, per_mass) = shape_mass_properties(shape)?;
        let mass = (volume * density as f64) as Real;
        Self::new(mass, per_mass * mass)
    }

    /// A homogeneous solid of total `mass` \[kg\] (inertia as in [`RigidBody::solid`]).
    pub fn with_mass(shape: &ColliderShape, mass: Real) -> Result<Self, RigidBodyError> {
        let (_, per_mass) = shape_mass_properties(shape)?;
        Self::new(mass, per_mass * mass)
    }

    /// Inertia tensor in the world frame for orientation `rotation`: R diag(I) Rᵀ \[kg m²\].
    pub fn world_inertia(&self, rotation: Quat) -> Mat3 {
        let r = Mat3::from_quat(rotation);
        r * Mat3::from_diagonal(self.inertia) * r.transpose()
    }

    /// Inverse world inertia R diag(1/I) Rᵀ \[1/(kg m²)\].
    pub fn world_inverse_inertia(&self, rotation: Quat) -> Mat3 {
        let r = Mat3::from_quat(rotation);
        r * Mat3::from_diagonal(self.inertia.recip()) * r.transpose()
    }
}

/// Velocity of a rigid body: of its centre of mass and angular, both in the world frame.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct RigidVelocity {
    /// Velocity of the centre of mass \[m/s\].
    pub linear: Vec3,
    /// Angular velocity \[rad/s\] (world frame).
    pub angular: Vec3,
}

/// The GS4 rates of a body's velocity (the body's counterpart of the particles'
/// `Acceleration`, ALGORITHM §2.1), world frame. Start it at gravity for a body at rest (as
/// [`RigidBodyBundle::new`] does); the consistent start-up (§2.14) overwrites it.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct RigidAcceleration {
    /// Linear acceleration \[m/s²\].
    pub linear: Vec3,
    /// Angular acceleration \[rad/s²\].
    pub angular: Vec3,
}

/// What a body exchanged in its last step (read-only output of the coupling).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct RigidExchange {
    /// Momentum the liquid gave the body, J_v = Σ mᵢ(vᵢ − vᵢ′) \[kg m/s\]; J_v/Δt is the
    /// hydrodynamic force.
    pub impulse: Vec3,
    /// Angular momentum about the centre of mass the liquid gave the body \[kg m²/s\].
    pub angular_impulse: Vec3,
    /// The acceleration counterpart J_a = Σ mᵢ(aᵢ − aᵢ′) \[kg m/s²\] (see the module docs).
    pub rate_exchange: Vec3,
    /// Impulse of the domain walls on the body \[kg m/s\].
    pub wall_impulse: Vec3,
    /// Liquid mass on the projected boundary nodes \[kg\].
    pub contact_mass: Real,
    /// Projection passes the semi-implicit exchange used (0: no liquid touched the body).
    pub iterations: u32,
}

/// The components of a dynamic body.
#[derive(Bundle, Clone, Debug)]
pub struct RigidBodyBundle {
    /// Mass properties.
    pub body: RigidBody,
    /// Shape and boundary condition towards the liquid.
    pub collider: Collider,
    /// Pose (origin = centre of mass).
    pub pose: ColliderPose,
    /// Velocity.
    pub velocity: RigidVelocity,
    /// GS4 rate of the velocity.
    pub acceleration: RigidAcceleration,
    /// Mirror of the velocity for code that reads collider motion.
    pub motion: ColliderMotion,
    /// Last step's exchange.
    pub exchange: RigidExchange,
}

impl RigidBodyBundle {
    /// A body at `pose` moving with `velocity`, its acceleration initialised to `gravity`
    /// \[m/s²\] (free fall; consistent with [`crate::components::ParticleBundle::new`]).
    pub fn new(
        body: RigidBody,
        collider: Collider,
        pose: ColliderPose,
        velocity: RigidVelocity,
        gravity: Vec3,
    ) -> Self {
        Self {
            body,
            collider,
            pose,
            velocity,
            acceleration: RigidAcceleration {
                linear: gravity,
                angular: Vec3::ZERO,
            },
            motion: ColliderMotion {
                linear_velocity: velocity.linear,
                angular_velocity: velocity.angular,
            },
            exchange: RigidExchange::default(),
        }
    }

    /// Whether world point `x` lies strictly inside the body.
    pub fn contains(&self, x: Vec3) -> bool {
        let local = self.pose.rotation.inverse() * (x - self.pose.translation);
        self.collider.shape.sdf(local).0 < 0.0
    }
}
