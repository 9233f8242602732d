//! Two-way coupled rigid bodies: dynamic spheres and boxes moved by gravity and by the
//! momentum they exchange with the MPM grid at their boundary nodes (ALGORITHM §2.11 applied
//! to a collision object whose motion is an unknown of the step).
//!
//! A dynamic body is an entity with [`RigidBody`] (mass and principal inertia), a [`Collider`]
//! (shape and boundary condition towards the liquid) and a [`ColliderPose`]; [`RigidVelocity`],
//! [`RigidAcceleration`], [`RigidExchange`] and [`ColliderMotion`] are added automatically
//! (required components) or by [`RigidBodyBundle`]. Its pose's origin is its centre of mass.
//! Shapes: [`ColliderShape::Sphere`] and [`ColliderShape::Box`]. The systems are added by
//! [`RigidBodyPlugin`] (part of [`crate::plugin::MpmPlugins`]) and do nothing without bodies.
//!
//! # The step
//!
//! **The body is integrated like a grid node: GS4-II, η = 0, with the grid's (ρ∞, ρs)** (§1.2
//! eq. 1.4). It carries a velocity *and* an acceleration (the GS4 rate, [`RigidAcceleration`]),
//! linear and angular. In `Predict` ([`predict_rigid_bodies`]):
//! ΔA = (g − Aⁿ)/W₁Λ₆, Â = Aⁿ + ΔA, V̂ = Vⁿ + λ₄Δt Aⁿ + λ₅Δt ΔA, and for the rotation the same
//! with the gyroscopic acceleration −I⁻¹(Ω × IΩ) (world frame) in place of g.
//!
//! **Coupling** ([`couple_rigid_bodies`], in `GridUpdate` after the grid update). Every node
//! with mass inside the body or within half a cell of its surface (φ ≤ ½Δx at the body's pose
//! at t_{n+1}, see *which nodes* below) is projected with the
//! collision rule of §2.11 relative to the body's velocity field V + Ω × r, its acceleration
//! projected relative to the body's acceleration field A + α × r + Ω × (Ω × r) (choice D5), with
//! the same friction correction as the walls ([`project_velocity`]). What the projection removes
//! from the node goes to the body:
//! J_v = Σ mᵢ(vᵢ − vᵢ′), L_v = Σ rᵢ × mᵢ(vᵢ − vᵢ′), J_a = Σ mᵢ(aᵢ − aᵢ′), L_a = Σ rᵢ × mᵢ(aᵢ − aᵢ′),
//! Vⁿ⁺¹ = V̂ + J_v/M, Aⁿ⁺¹ = Â + J_a/M, Ωⁿ⁺¹ = Ω̂ + I⁻¹L_v, αⁿ⁺¹ = α̂ + I⁻¹L_a.
//!
//! *Why the acceleration is exchanged too (exact momentum conservation).* G2P conserves both
//! sums exactly (Σₚ mₚvₚⁿ⁺¹ = Σᵢ mᵢvᵢⁿ⁺¹ and Σₚ mₚaₚⁿ⁺¹ = Σᵢ mᵢaᵢⁿ⁺¹ for any PIC/FLIP blend), and
//! Σᵢ f̃ᵢ = 0. With P = Σ mv + MV and 𝒜 = Σ ma + MA over liquid and body, the step above gives
//! 𝒜ⁿ⁺¹ = 𝒜ⁿ + (M_tot g − 𝒜ⁿ)/W₁Λ₆ and Pⁿ⁺¹ = Pⁿ + λ₄Δt 𝒜ⁿ + λ₅Δt(𝒜ⁿ⁺¹ − 𝒜ⁿ): with a consistent
//! start (𝒜⁰ = M_tot g, §2.14) 𝒜 stays M_tot g and **P changes by exactly M_tot g Δt per step**.
//! Exchanging only J_v (a body with a plain Euler update) leaves the projected accelerations
//! out of 𝒜 and adds (λ₄ − λ₅/W₁Λ₆)Δt (𝒜 − M_tot g) per step; for (0.5, 0) a resting contact
//! would then pass on only λ₅/W₁Λ₆ = 6/7 of the liquid's pressure force, so a floating body
//! would displace 7/6 of its Archimedes volume (derivation, not a measurement).
//!
//! *Semi-implicit exchange.* Projecting against the predicted V̂ and then adding J_v/M is the
//! usual explicit coupling; when the liquid mass on the boundary nodes m_c exceeds M it
//! overshoots and creates energy. The projection is therefore iterated: (V*, Ω*, A*, α*) start at
//! the predicted values and are updated with the contact mass as preconditioner,
//! V* ← (M V̂ + J_v(V*) + m_c V*)/(M + m_c) (Ω* with I + I_c, I_c = Σ mᵢ(|rᵢ|²𝟙 − rᵢrᵢᵀ) over the
//! projected nodes), which is exact after one update for sticky contact (the momentum-weighted
//! mean velocity) and reduces to the explicit scheme for m_c ≪ M; at most
//! [`MAX_COUPLING_ITERATIONS`] passes. The nodes are projected against the last iterate, and the
//! body receives exactly what that projection removed, so momentum is conserved whether or not
//! the iteration converged.
//!
//! *Which nodes.* A node belongs to the body when φ ≤ ½Δx ([`COUPLING_SKIN_CELLS`]): the
//! body's discrete surface is then the node layer nearest to its true surface, off by at most
//! ½Δx either way and unbiased on average. With φ ≤ 0 (the rule of the static colliders) it lies
//! between 0 and Δx inside, ½Δx on average, and the body displaces too little liquid. Measured
//! with a sphere of half the liquid's density released at its draught: radius 4Δx, 1.6Δx too
//! deep after 1 s; radius 8Δx, 1.1 coarse cells too deep after 0.8 s (first order, both still
//! sinking slowly); a static sphere (radius 4Δx, φ ≤ 0) received half of the Archimedes force.
//! With ½Δx the sphere floats within 0.3Δx of its draught (`tests/rigid.rs`).
//!
//! **Pose** (in `Commit`, [`commit_rigid_bodies`]): trapezoidal, xⁿ⁺¹ = xⁿ + Δt/2 (Vⁿ + Vⁿ⁺¹)
//! — identity (1.1) of GS4, the same rule the particles follow, exact for free fall (semi-
//! implicit Euler would lag by gΔt t/2). The rotation turns by Δt/2 (Ωⁿ + Ωⁿ⁺¹) and the
//! quaternion is renormalised.
//!
//! **Domain walls** act on the body as contact constraints with restitution 0 and the wall's
//! condition (`Sticky`: no slip at the contact point, `Slip`: frictionless, `Friction(μ)`:
//! Coulomb), solved by projected Gauss–Seidel on the support points (the sphere's lowest point
//! towards each wall, the box's corners) that penetrate at the end-of-step pose; remaining
//! penetration is removed by translating the body (no velocity change). The same solve is
//! applied to the predicted velocity, so the liquid sees a resting body at rest. `Open` faces
//! do not constrain the body; along `Periodic` axes it wraps around. Wall impulses are external
//! and are reported in [`RigidExchange::wall_impulse`].
//!
//! **Particles** that end inside a body are moved to its surface (position only, in `Commit`,
//! [`push_particles_out_of_rigid_bodies`]): the velocity exchange happens on the grid, where
//! it is accounted for, so this pass changes no momentum.
//!
//! **Time step**: the advection limit of §2.15 also holds for the body's fastest surface point
//! |V| + |Ω| r_b ([`limit_time_step_by_rigid_bodies`]).
//!
//! **Determinism**: bodies are processed one after another in entity order and each body's
//! nodes in (i, j, k) order, in one thread, so the sums do not depend on the thread count.
//!
//! Not modelled: contacts between two bodies or between a body and a static collider. Known
//! limitation: a liquid film thinner than a cell resting on top of a body does not drain (the
//! grid cannot resolve its flow); a sphere released fully submerged (radius 4Δx, half the
//! liquid's density) stopped 2.5Δx below its draught under such a film.
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3, IVec3, Mat3, Quat};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::collision::{
    Collider, ColliderMotion, ColliderPose, ColliderShape, CoupledCollider, project_acceleration,
    project_velocity,
};
use crate::components::{Particle, Position};
use crate::config::{BoundaryCondition, DomainWalls, MpmConfig, TimeStepMode};
use crate::diagnostics::{MetricsColumns, MetricsSource};
use crate::failure::{FailureCollector, FailureReport, SimulationStatus};
use crate::grid::MpmGrid;
use crate::math::RotationSpec;
use crate::math::{Real, Vec3};
use crate::step::energy::EnergyTerms;
use crate::step::grid_update::collide_node;
use crate::step::schedule::{
    CommitSystems, GridUpdateSystems, MonitorSystems, MpmStep, PredictSystems, SimulationClock,
    StepContext, init_step_schedule,
};
use crate::validation::FieldIssue;

/// Nodes closer to a body's surface than this many cells (φ ≤ ½Δx) are coupled to it: the
/// discrete surface is the node layer nearest to the true one (see the module docs).
pub const COUPLING_SKIN_CELLS: Real = 0.5;

/// Largest number of projection passes of the semi-implicit exchange per body and step.
pub const MAX_COUPLING_ITERATIONS: usize = 8;

/// Projected Gauss–Seidel sweeps of the wall-contact solve.
pub const WALL_CONTACT_ITERATIONS: usize = 16;

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
/// box) and a [`ColliderPose`]. Build it with [`RigidBody::solid`] or [`RigidBody::with_mass`].
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[require(
    RigidVelocity,
    RigidAcceleration,
    RigidExchange,
    ColliderMotion,
    CoupledCollider
)]
pub struct RigidBody {
    /// Mass M \[kg\]; > 0.
    pub mass: Real,
    /// Principal moments of inertia about the centre of mass, along the collider's local
    /// x, y, z axes \[kg m²\]; each > 0.
    pub inertia: Vec3,
}

/// Volume \[m³\] and inertia per unit mass \[m²\] of a supported shape.
fn shape_mass_properties(shape: &ColliderShape) -> Result<(f64, Vec3), RigidBodyError> {
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
pub struct RigidAcceleration {
    /// Linear acceleration \[m/s²\].
    pub linear: Vec3,
    /// Angular acceleration \[rad/s²\].
    pub angular: Vec3,
}

/// What a body exchanged in its last step (read-only output of the coupling).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
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

/// One body during a step: its state at t_n, the predicted and the new state.
#[derive(Clone, Debug)]
pub struct RigidInstance {
    /// The body's entity.
    pub entity: Entity,
    /// Mass properties.
    pub body: RigidBody,
    /// Shape.
    pub shape: ColliderShape,
    /// Condition towards the liquid.
    pub boundary: BoundaryCondition,
    /// Pose at t_n.
    pub pose: ColliderPose,
    /// Velocity at t_n.
    pub velocity: RigidVelocity,
    /// Predicted velocity V̂, Ω̂ (after the wall contacts).
    pub predicted_velocity: RigidVelocity,
    /// Predicted rates Â, α̂.
    pub predicted_acceleration: RigidAcceleration,
    /// Pose at t_{n+1} moved with the predicted velocity: where the liquid meets the body.
    pub predicted_pose: ColliderPose,
    /// Velocity at t_{n+1} (after the exchange; the walls act in `Commit`).
    pub new_velocity: RigidVelocity,
    /// Rates at t_{n+1}.
    pub new_acceleration: RigidAcceleration,
    /// Pose at t_{n+1} (set in `Commit`).
    pub new_pose: ColliderPose,
    /// This step's exchange.
    pub exchange: RigidExchange,
}

/// The bodies of the current step, in entity order (rebuilt in `Predict`).
#[derive(Resource, Clone, Debug, Default)]
pub struct ActiveRigidBodies {
    /// The bodies.
    pub bodies: Vec<RigidInstance>,
}

/// Pose after moving for `dt` with the mean of two velocities (trapezoidal rule, identity 1.1).
pub fn advance_pose_trapezoid(
    pose: ColliderPose,
    v0: &RigidVelocity,
    v1: &RigidVelocity,
    dt: Real,
) -> ColliderPose {
    let w = 0.5 * (v0.angular + v1.angular);
    let angle = w.length() * dt;
    let rotation = if angle > 0.0 {
        (Quat::from_axis_angle(w.normalize(), angle) * pose.rotation).normalize()
    } else {
        pose.rotation
    };
    ColliderPose {
        translation: pose.translation + (0.5 * dt) * (v0.linear + v1.linear),
        rotation,
    }
}

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
fn resolve_wall_contacts(
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
fn keep_in_domain(shape: &ColliderShape, pose: &mut ColliderPose, config: &MpmConfig) {
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

/// A grid node inside a body: storage index, world position (unwrapped along periodic axes),
/// offset from the centre, outward normal, mass and its velocity and acceleration after the
/// grid update.
struct BoundaryNode {
    idx: usize,
    x: Vec3,
    r: Vec3,
    n: Vec3,
    m: Real,
    v: Vec3,
    a: Vec3,
}

/// The body's velocity and acceleration fields during the exchange.
#[derive(Clone, Copy, Debug)]
struct BodyMotion {
    v: DVec3,
    w: DVec3,
    a: DVec3,
    alpha: DVec3,
}

impl BodyMotion {
    fn at(&self, r: Vec3) -> (Vec3, Vec3) {
        let (v, w, a, al) = (
            self.v.as_vec3(),
            self.w.as_vec3(),
            self.a.as_vec3(),
            self.alpha.as_vec3(),
        );
        (v + w.cross(r), a + al.cross(r) + w.cross(w.cross(r)))
    }
}

/// Sums of one projection pass.
#[derive(Default)]
struct ExchangeSums {
    jv: DVec3,
    lv: DVec3,
    ja: DVec3,
    la: DVec3,
    mass: f64,
    inertia: DMat3,
}

/// §2.11 projection of one node relative to the body (velocity, acceleration with D5, friction
/// correction `extra_dt` = (W₁Λ₆ − λ₅)Δt as for the walls). Returns v′, a′.
#[inline]
fn project_node(
    node: &BoundaryNode,
    motion: &BodyMotion,
    bc: BoundaryCondition,
    extra_dt: Real,
) -> (Vec3, Vec3) {
    let (vb, ab) = motion.at(node.r);
    let rel_a = node.a - ab;
    let extra = extra_dt * (-rel_a.dot(node.n)).max(0.0);
    let v = project_velocity(node.v, vb, node.n, bc, extra);
    let a = match bc {
        BoundaryCondition::Sticky => ab,
        _ if v != node.v => ab + project_acceleration(rel_a, node.n, bc, true),
        _ => node.a,
    };
    (v, a)
}

fn exchange_sums(
    nodes: &[BoundaryNode],
    motion: &BodyMotion,
    bc: BoundaryCondition,
    extra_dt: Real,
) -> ExchangeSums {
    let mut s = ExchangeSums::default();
    for node in nodes {
        let (v, a) = project_node(node, motion, bc, extra_dt);
        if v == node.v && a == node.a {
            continue;
        }
        let m = node.m as f64;
        let r = node.r.as_dvec3();
        let dv = m * (node.v - v).as_dvec3();
        let da = m * (node.a - a).as_dvec3();
        s.jv += dv;
        s.lv += r.cross(dv);
        s.ja += da;
        s.la += r.cross(da);
        s.mass += m;
        s.inertia += m * (DMat3::from_diagonal(DVec3::splat(r.dot(r))) - outer(r, r));
    }
    s
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The grid nodes with mass inside the body or within [`COUPLING_SKIN_CELLS`] of its surface at
/// its predicted pose, in (i, j, k) order.
fn boundary_nodes(grid: &MpmGrid, config: &MpmConfig, inst: &RigidInstance) -> Vec<BoundaryNode> {
    let b = grid.active;
    if b.is_empty() {
        return Vec::new();
    }
    let layout = grid.layout;
    let pose = inst.predicted_pose;
    let skin = COUPLING_SKIN_CELLS * layout.dx;
    let rb = bounding_radius(&inst.shape) + skin;
    let c = pose.translation;
    let mut lo = ((c - Vec3::splat(rb) - layout.origin) * layout.inv_dx)
        .floor()
        .as_ivec3();
    let mut hi = ((c + Vec3::splat(rb) - layout.origin) * layout.inv_dx)
        .ceil()
        .as_ivec3();
    let periodic = config.walls.periodic_axes();
    let counts = crate::step::p2g::periodic_counts(config, grid);
    for a in 0..3 {
        if periodic[a] {
            // Visit each distinct node at most once.
            hi[a] = hi[a].min(lo[a] + counts[a] - 1);
        } else {
            lo[a] = lo[a].max(b.min[a]);
            hi[a] = hi[a].min(b.max[a]);
        }
    }
    let inv_rot = pose.rotation.inverse();
    let eps = grid.mass_epsilon;
    let mut out = Vec::new();
    for i in lo.x..=hi.x {
        for j in lo.y..=hi.y {
            for k in lo.z..=hi.z {
                let u = IVec3::new(i, j, k);
                let mut img = u;
                for a in 0..3 {
                    if periodic[a] {
                        img[a] = u[a].rem_euclid(counts[a]);
                    }
                }
                let idx = layout.index(img);
                let node = &grid.nodes[idx];
                if node.mass <= eps {
                    continue;
                }
                let x = layout.node_position(u);
                let (phi, n_local) = inst.shape.sdf(inv_rot * (x - c));
                if phi > skin {
                    continue;
                }
                out.push(BoundaryNode {
                    idx,
                    x: layout.node_position(img),
                    r: x - c,
                    n: pose.rotation * n_local,
                    m: node.mass,
                    v: Vec3::from(node.new_velocity),
                    a: Vec3::from(node.new_acceleration),
                });
            }
        }
    }
    out
}

/// S11 for bodies: the momentum exchange with the grid at the body's boundary nodes and the
/// body's new velocity and rates (module docs). Runs after the grid update (walls and static
/// colliders are applied first; walls again on the nodes a body changed).
pub fn couple_rigid_bodies(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    mut active: ResMut<ActiveRigidBodies>,
    mut grid: ResMut<MpmGrid>,
) {
    let c = ctx.coefficients;
    let extra_dt = (c.w1l6 - c.l5).max(0.0) * c.dt;
    let walls = config.walls;
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    let mut touched = false;
    for inst in &mut active.bodies {
        let nodes = boundary_nodes(&grid, &config, inst);
        let pv = inst.predicted_velocity;
        let pa = inst.predicted_acceleration;
        let predicted = BodyMotion {
            v: pv.linear.as_dvec3(),
            w: pv.angular.as_dvec3(),
            a: pa.linear.as_dvec3(),
            alpha: pa.angular.as_dvec3(),
        };
        let mass = inst.body.mass as f64;
        let rot = inst.predicted_pose.rotation;
        let i_w = inst.body.world_inertia(rot).as_dmat3();
        let inv_i = inst.body.world_inverse_inertia(rot);
        let rb = bounding_radius(&inst.shape) as f64;
        let mut motion = predicted;
        let mut passes = 0u32;
        if !nodes.is_empty() {
            for _ in 1..MAX_COUPLING_ITERATIONS {
                let s = exchange_sums(&nodes, &motion, inst.boundary, extra_dt);
                passes += 1;
                if s.mass <= 0.0 {
                    break;
                }
                let denom = mass + s.mass;
                let lhs_inv = (i_w + s.inertia).inverse();
                let next = BodyMotion {
                    v: (mass * predicted.v + s.jv + s.mass * motion.v) / denom,
                    w: lhs_inv * (i_w * predicted.w + s.lv + s.inertia * motion.w),
                    a: (mass * predicted.a + s.ja + s.mass * motion.a) / denom,
                    alpha: lhs_inv * (i_w * predicted.alpha + s.la + s.inertia * motion.alpha),
                };
                let change = (next.v - motion.v).length() + rb * (next.w - motion.w).length();
                let correction =
                    (next.v - predicted.v).length() + rb * (next.w - predicted.w).length();
                motion = next;
                // Converged to 0.1 % of the correction (or below 0.1 µm/s).
                if change <= 1e-3 * correction + 1e-7 {
                    break;
                }
            }
        }
        // Final pass: project against the last iterate and give the body what it removed.
        let mut s = ExchangeSums::default();
        for node in &nodes {
            let (v, a) = project_node(node, &motion, inst.boundary, extra_dt);
            if v == node.v && a == node.a {
                continue;
            }
            let m = node.m as f64;
            let r = node.r.as_dvec3();
            let dv = m * (node.v - v).as_dvec3();
            let da = m * (node.a - a).as_dvec3();
            s.jv += dv;
            s.lv += r.cross(dv);
            s.ja += da;
            s.la += r.cross(da);
            s.mass += m;
            let (mut v, mut a) = (v, a);
            collide_node(node.x, extra_dt, &walls, dmin, dmax, &[], &mut v, &mut a);
            let gn = &mut grid.nodes[node.idx];
            gn.new_velocity = v.into();
            gn.new_acceleration = a.into();
            touched = true;
        }
        if !nodes.is_empty() {
            passes += 1;
        }
        let inv_m = 1.0 / inst.body.mass;
        let (jv, lv, ja, la) = (
            s.jv.as_vec3(),
            s.lv.as_vec3(),
            s.ja.as_vec3(),
            s.la.as_vec3(),
        );
        inst.new_velocity = RigidVelocity {
            linear: pv.linear + inv_m * jv,
            angular: pv.angular + inv_i * lv,
        };
        inst.new_acceleration = RigidAcceleration {
            linear: pa.linear + inv_m * ja,
            angular: pa.angular + inv_i * la,
        };
        inst.exchange = RigidExchange {
            impulse: jv,
            angular_impulse: lv,
            rate_exchange: ja,
            wall_impulse: Vec3::ZERO,
            contact_mass: s.mass as Real,
            iterations: passes,
        };
    }
    if touched {
        crate::step::p2g::copy_ghosts(&config, &mut grid);
    }
}

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

/// Caps the next step by the advection limit of the bodies' fastest surface points (§2.15):
/// C_s·C_adv·Δx/(|V| + |Ω| r_b) in adaptive mode, 0.5 Δx/(…) with the paper's rule; a fixed
/// step is left alone. Bodies farther than their size from the domain are ignored.
pub fn limit_time_step_by_rigid_bodies(
    config: Res<MpmConfig>,
    active: Res<ActiveRigidBodies>,
    status: Res<SimulationStatus>,
    mut clock: ResMut<SimulationClock>,
) {
    if status.failed() {
        return;
    }
    let mut speed: Real = 0.0;
    for b in &active.bodies {
        let rb = bounding_radius(&b.shape);
        let c = b.new_pose.translation;
        let near = (0..3).all(|a| {
            c[a] >= config.domain_min[a] - 2.0 * rb && c[a] <= config.domain_max[a] + 2.0 * rb
        });
        if near {
            speed =
                speed.max(b.new_velocity.linear.length() + rb * b.new_velocity.angular.length());
        }
    }
    if speed <= 0.0 {
        return;
    }
    let ts = &config.time_step;
    let dx = config.dx as f64;
    let speed = speed as f64;
    let limit = ts.advection * dx / speed;
    clock.predicted_limit = clock.predicted_limit.min(limit);
    let next = match ts.mode {
        TimeStepMode::Adaptive => ts.safety * limit,
        TimeStepMode::Paper => 0.5 * dx / speed,
        TimeStepMode::Fixed(_) => return,
    };
    clock.next_dt = clock.next_dt.min(next);
}

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

/// Adds the rigid-body systems to the [`MpmStep`] schedule (see the module docs for where
/// each runs). Part of [`crate::plugin::MpmPlugins`]; the systems run only while some entity
/// has a [`RigidBody`].
pub struct RigidBodyPlugin;

impl Plugin for RigidBodyPlugin {
    fn build(&self, app: &mut App) {
        init_step_schedule(app);
        app.init_resource::<ActiveRigidBodies>()
            .init_resource::<EnergyTerms>()
            .init_resource::<MetricsColumns>();
        app.world_mut()
            .resource_mut::<MetricsColumns>()
            .add(MetricsSource {
                key: "rigid",
                columns: |world| {
                    let bodies = rigid_body_entities(world);
                    let columns = metrics_columns(bodies.len());
                    world.insert_resource(MetricsBodies(bodies));
                    columns
                },
                values: |world| {
                    let bodies = world
                        .get_resource::<MetricsBodies>()
                        .map(|b| b.0.clone())
                        .unwrap_or_default();
                    metrics_values(world, &bodies)
                },
            });
        let any = any_with_component::<RigidBody>;
        app.add_systems(
            MpmStep,
            (
                predict_rigid_bodies
                    .in_set(PredictSystems::Bodies)
                    .run_if(any),
                couple_rigid_bodies
                    .in_set(GridUpdateSystems::Coupling)
                    .run_if(any),
                (commit_rigid_bodies, push_particles_out_of_rigid_bodies)
                    .chain()
                    .in_set(CommitSystems::Bodies)
                    .run_if(any),
                (limit_time_step_by_rigid_bodies, rigid_body_energy)
                    .chain()
                    .in_set(MonitorSystems::Plugins)
                    .run_if(any),
            ),
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Scene files and output.

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
    /// that [`validate_rigid_bodies`] rejects.
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
    fn half_aabb(&self) -> Vec3 {
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

fn fmt_vec(v: Vec3) -> String {
    format!("({}, {}, {})", v.x, v.y, v.z)
}

/// Checks the `rigid_bodies` of a scene: sizes, density or mass, finite vectors and rotation,
/// the boundary condition, and that each body lies inside the domain (touching a wall is
/// allowed) and is smaller than the domain along periodic axes. `domain` and `dx` are `None`
/// when they are themselves invalid (the checks that need them are skipped).
pub fn validate_rigid_bodies(
    specs: &[RigidBodySpec],
    domain: Option<(Vec3, Vec3)>,
    dx: Option<Real>,
    walls: &DomainWalls,
) -> Vec<FieldIssue> {
    let mut out = Vec::new();
    for (i, s) in specs.iter().enumerate() {
        let at = |f: &str| format!("rigid_bodies[{i}].{f}");
        let mut push = |f: String, m: String| out.push(FieldIssue::new(f, m));
        let mut shape_ok = true;
        match s.shape {
            RigidShape::Sphere { radius } => {
                if !(radius.is_finite() && radius > 0.0) {
                    push(
                        at("shape.radius"),
                        format!("must be a finite number > 0 m (got {radius})"),
                    );
                    shape_ok = false;
                }
            }
            RigidShape::Box { half_extents } => {
                if !(half_extents.is_finite() && half_extents.min_element() > 0.0) {
                    push(
                        at("shape.half_extents"),
                        format!(
                            "must be finite and > 0 m on every axis (got {})",
                            fmt_vec(half_extents)
                        ),
                    );
                    shape_ok = false;
                }
            }
        }
        match (s.density, s.mass) {
            (Some(rho), None) => {
                if !(rho.is_finite() && rho > 0.0) {
                    push(
                        at("density"),
                        format!("must be a finite number > 0 kg/m³ (got {rho})"),
                    );
                }
            }
            (None, Some(m)) => {
                if !(m.is_finite() && m > 0.0) {
                    push(
                        at("mass"),
                        format!("must be a finite number > 0 kg (got {m})"),
                    );
                }
            }
            (Some(_), Some(_)) => push(
                at("mass"),
                "give either `density` or `mass`, not both".to_string(),
            ),
            (None, None) => push(
                format!("rigid_bodies[{i}]"),
                "needs `density: ρ` (kg/m³) or `mass: M` (kg)".to_string(),
            ),
        }
        let mut pos_ok = true;
        for (name, v, unit) in [
            ("position", s.position, "m"),
            ("velocity", s.velocity, "m/s"),
            ("angular_velocity", s.angular_velocity, "rad/s"),
        ] {
            if !v.is_finite() {
                push(
                    at(name),
                    format!("must have finite components [{unit}] (got {})", fmt_vec(v)),
                );
                pos_ok &= name != "position";
            }
        }
        let mut rot_ok = true;
        match s.rotation {
            RotationSpec::AxisAngle { axis, degrees } => {
                if !(axis.is_finite() && axis.length_squared() > 0.0) {
                    push(
                        at("rotation.axis"),
                        format!("must be a finite non-zero vector (got {})", fmt_vec(axis)),
                    );
                    rot_ok = false;
                }
                if !degrees.is_finite() {
                    push(
                        at("rotation.degrees"),
                        format!("must be finite (got {degrees})"),
                    );
                    rot_ok = false;
                }
            }
            RotationSpec::Euler { x, y, z } => {
                for (name, v) in [("x", x), ("y", y), ("z", z)] {
                    if !v.is_finite() {
                        push(
                            at(&format!("rotation.{name}")),
                            format!("must be finite (got {v})"),
                        );
                        rot_ok = false;
                    }
                }
            }
        }
        match s.boundary {
            BoundaryCondition::Friction(mu) if !(mu.is_finite() && mu >= 0.0) => push(
                at("boundary"),
                format!("friction coefficient must be a finite number ≥ 0 (got {mu})"),
            ),
            BoundaryCondition::Open | BoundaryCondition::Periodic => push(
                at("boundary"),
                format!(
                    "{:?} is not a condition between a body and the liquid; use Sticky, Slip or \
                     Friction(μ)",
                    s.boundary
                ),
            ),
            _ => {}
        }
        let Some((dmin, dmax)) = domain else { continue };
        if !(shape_ok && pos_ok && rot_ok) {
            continue;
        }
        let e = s.half_aabb();
        let (lo, hi) = (s.position - e, s.position + e);
        let periodic = walls.periodic_axes();
        const AXES: [&str; 3] = ["x", "y", "z"];
        let mut problems = Vec::new();
        for a in 0..3 {
            if periodic[a] {
                let rb = bounding_radius(&s.shape.collider_shape());
                let room = (dmax[a] - dmin[a]) - 2.0 * dx.unwrap_or(0.0);
                if 2.0 * rb >= room {
                    problems.push(format!(
                        "along the periodic {} axis its size 2·{rb} m must be less than the \
                         domain length minus 2·dx = {room} m",
                        AXES[a]
                    ));
                }
            } else if lo[a] < dmin[a] || hi[a] > dmax[a] {
                problems.push(format!(
                    "on {} it spans [{}, {}] m but the domain is [{}, {}] m",
                    AXES[a], lo[a], hi[a], dmin[a], dmax[a]
                ));
            }
        }
        if !problems.is_empty() {
            push(
                at("position"),
                format!(
                    "the body must lie inside the domain: {}",
                    problems.join("; ")
                ),
            );
        }
    }
    out
}

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
