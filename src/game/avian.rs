//! Two-way coupling of [Avian](https://docs.rs/avian3d/0.8) rigid bodies with the liquid (cargo
//! feature `avian`, avian3d 0.8).
//!
//! ```text
//! App::new()
//!     .add_plugins((MinimalPlugins, TransformPlugin, PhysicsPlugins::default()))
//!     .add_plugins(MpmPlugins.set(MpmCorePlugin { schedule: FixedUpdate.intern() }))
//!     .add_plugins((GamePlugin::default(), AvianCouplingPlugin::default()))
//! ```
//!
//! **Design: a treacle shadow per Avian entity; Avian owns the motion.** Every Avian entity
//! whose collider treacle can represent gets a *shadow*: a separate entity (no `Transform`, so
//! the `Transform` placement of [`super`] leaves it alone) that the liquid sees, linked both
//! ways by [`LiquidShadow`] (on the Avian entity) and [`AvianSource`] (on the shadow).
//! - A **dynamic** Avian body with a ball or cuboid collider on its own entity becomes one of
//!   the crate's coupled rigid bodies ([`crate::rigid`]: [`RigidBody`], sphere or box
//!   [`Collider`]). At the start of each liquid frame ([`DriverSystems::Pace`],
//!   [`sync_shadows_from_avian`]) the shadow's pose (centre of mass), velocity, mass and
//!   principal inertia are set from Avian's `Position`, `Rotation`, `ComputedCenterOfMass`,
//!   `LinearVelocity`, `AngularVelocity`, `ComputedMass` and `ComputedAngularInertia` (the
//!   diagonal of the local tensor: exact for a ball, and for a cuboid about its centre). The
//!   shadow keeps its GS4 rate ([`RigidAcceleration`]) from frame to frame, as the exact
//!   momentum exchange of [`crate::rigid`] needs. The frame then integrates the shadow coupled
//!   with the liquid, semi-implicitly in every sub-step, exactly as for the crate's own bodies.
//!   After the frame ([`DriverSystems::Publish`], [`hand_impulses_to_avian`]) the liquid's
//!   impulse on the body over the frame,
//!   J = M(V_end − V_start) − M g T − Σ J_wall,
//!   and its angular counterpart ΔL = I_w(q_end) Ω_end − I_w(q_start) Ω_start (the change of
//!   the shadow's angular momentum about its centre of mass in the world frame, so the
//!   gyroscopic term needs no special treatment) are applied to the Avian body as the force
//!   J/Δt and the torque ΔL/Δt over Avian's coming step Δt (`Forces::apply_force`,
//!   `apply_torque`; Δt is the fixed step, `Res<Time>` in the driver's schedule). Avian then
//!   integrates the body with its gravity, its contacts with other bodies and this force; the
//!   shadow never moves the Avian body itself. Without Avian contacts (and with Avian's gravity
//!   equal to treacle's, which [`sync_shadows_from_avian`] ensures) Avian's new velocity equals
//!   the shadow's, so the liquid and the body together gain exactly M_total g T per frame, as
//!   the crate's own bodies do (`tests/it/avian.rs`). A frame in which no liquid touched the
//!   shadow (no coupling node in any sub-step) hands over exactly zero, so a body in the air
//!   feels no round-off force.
//!
//!   *Why a force and not an impulse.* Both change Avian's velocity by exactly J/M (a force
//!   J/Δt over Avian's step Δt, whatever the liquid frame T was, so momentum is conserved even
//!   when the [`FrameBudget`](crate::step::pacing::FrameBudget) cut the liquid frame short).
//!   They differ in the position: an impulse is applied before Avian's step, so the body moves
//!   with the whole velocity change over the step, J/M·Δt, where the shadow (trapezoidal rule,
//!   the change spread over the frame) moved J/M·Δt/2. For a floating body J ≈ −M g Δt every
//!   frame, so the impulse lifted it by g Δt²/2 per frame more than the liquid did — a steady
//!   upward drift of g Δt/2 (0.08 m/s at 60 Hz) that the liquid can only balance by holding
//!   the body too high (measured: a box of half the liquid's density floated with a submerged
//!   fraction of 0.36 instead of 0.5). A force is integrated by Avian exactly as its gravity
//!   is, so at equilibrium (force = −weight) the two cancel in every Avian sub-step and no
//!   drift remains; away from equilibrium the position differs from the shadow's by
//!   O(|J|/M·Δt/n) per frame for Avian's n sub-steps, not cumulative (the shadow is placed at
//!   Avian's pose again at the next frame).
//!
//!   *Walls.* The shadow also meets treacle's domain walls (they keep it in the grid); their
//!   impulses Σ J_wall are external to the liquid and are *not* handed over: Avian does not
//!   know treacle's domain, so give the tank walls an Avian static collider too if bodies can
//!   reach them (the wall's angular impulse is not reported by [`RigidExchange`] and stays in
//!   ΔL; it only matters for a body touching a wall).
//! - A **static** or **kinematic** Avian body, or a collider without a body, becomes a treacle
//!   [`Collider`] whose [`ColliderPose`] is the Avian pose at the start of the frame and whose
//!   [`ColliderMotion`] is Avian's velocity (kinematic bodies; the velocity of the collider's
//!   origin, V + Ω × (origin − centre of mass)), so the sub-steps move it the way Avian will.
//!   Shapes: ball, cuboid, cylinder (along local y) and half-space.
//!
//! Any other shape (capsule, compound, mesh…), a collider on a child entity of its body, a
//! dynamic body whose centre of mass is not its collider's centre (treacle's bodies have their
//! origin at their centre of mass) or one with a shape other than ball/cuboid is skipped with
//! one warning per entity ([`SkippedByLiquid`]). A dynamic body whose mass Avian has not
//! computed yet (its first frame) is picked up at the next frame.
//!
//! **Time: both in the fixed-timestep schedules.** Run the liquid's frame driver in
//! `FixedUpdate` (`MpmCorePlugin { schedule: FixedUpdate.intern() }`); Avian runs in
//! `FixedPostUpdate` (its default). Each fixed tick then advances the liquid from t to
//! t + Δt_fixed, reading the bodies at t, and hands the impulses to Avian, which then advances
//! the bodies over the same interval. With the liquid in `Update` the two clocks would cover
//! different intervals (a variable frame against a fixed tick) and the impulse of one frame
//! would be applied over several ticks or none; [`AvianCouplingPlugin`] logs a warning if the
//! driver is not in `FixedUpdate`.
//!
//! **Boundary condition** of a shadow towards the liquid: [`LiquidBoundary`] on the Avian
//! entity, else [`AvianCouplingPlugin::dynamic_boundary`] (dynamic bodies, default `Sticky`)
//! or [`AvianCouplingPlugin::boundary`] (static and kinematic colliders, default `Slip`).
//!
//! *Why dynamic bodies default to `Sticky`* (measured, `examples/game_avian.rs`: a box
//! 8 × 4 × 8 cells of half the water's density in the `Water` preset at Δx = 2.5 cm): with
//! `Slip` the box floats at the right draught for about a second, then an acoustic mode
//! trapped under it grows (the largest particle density below the box rises from 1.07 ρ₀ to
//! 1.28 ρ₀ over 2 s, the sub-steps per frame from 12 to 18) and the box sinks steadily — its
//! submerged fraction goes from 0.49 to 0.72 in 4 s, where 0.5 is right. The crate's own rigid
//! bodies do the same in that setting (so it is not the hand-over to Avian); 500× the
//! viscosity does not stop it; pure PIC damps it (0.56 after 4 s). With `Sticky` the same box
//! stays at 0.41–0.46 for 4 s with 12 sub-steps per frame throughout. The slip projection only
//! removes the approaching normal velocity, and the iterated exchange of [`crate::rigid`] then
//! switches nodes in and out of contact every step; with the no-slip projection the exchange
//! is linear (exact after one pass). `Slip` bodies remain available (the flotation test uses
//! them, in a viscous liquid, with a box 10 Δx tall).
//!
//! *Known defect (measured, open).* A small light dynamic body — a ball of radius 1.6 Δx and
//! 700 kg/m³ floating in the `Water` preset — blows up the run after about 2 s with `Sticky`
//! (the crate's own bodies too, with or without Avian, with Avian's rotation locked): the
//! semi-implicit exchange of [`crate::rigid`] stops converging (8 of 8 passes) in single
//! frames, the angular velocity of the last iterate jumps to hundreds of rad/s, and the
//! liquid on its nodes follows. With `Slip` the same ball floats for 4 s (no torque reaches a
//! sphere through a frictionless contact). Linearising the exchange with the first moment
//! of the wet nodes (the exact Jacobian for `Sticky`) postponed the blow-up (3.1 s instead of
//! 2.2 s) without removing it. Keep dynamic bodies at least about 4 Δx across, or give small
//! ones [`LiquidBoundary`]`(Slip)`. Two coupled bodies whose skins overlap, and a treacle
//! collider moving through a body, are not resolved either (the liquid between them is the
//! only contact; an 8 cm ball next to the floating box dragged it 2.7 cm down in 2.5 s).
//!
//! **Gravity:** treacle's `MpmConfig::gravity` is copied to Avian's `Gravity` every frame, so
//! liquid and bodies fall alike.
use bevy_app::{App, FixedUpdate, Plugin};
use bevy_ecs::intern::Interned;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleLabel;
use bevy_time::Time;
use bevy_transform::components::GlobalTransform;
use glam::Quat;

use avian3d::prelude::{
    AngularVelocity, ColliderOf, ComputedAngularInertia, ComputedCenterOfMass, ComputedMass,
    Forces, Gravity, LinearVelocity, Position, Rotation, WriteRigidBodyForces,
};

use crate::collision::{Collider, ColliderMotion, ColliderPose, ColliderShape};
use crate::config::{BoundaryCondition, MpmConfig};
use crate::math::{Real, Vec3};
use crate::rigid::{RigidAcceleration, RigidBody, RigidExchange, RigidVelocity};
use crate::step::pacing::{DriverSchedule, DriverSystems};
use crate::step::schedule::{CommitSystems, MpmStep, SimulationClock};

/// The Avian crate this module is built with.
pub use avian3d;

/// On an Avian entity: its treacle shadow (added by [`sync_shadows_from_avian`]).
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LiquidShadow(pub Entity);

/// On an Avian entity: the condition its shadow imposes on the liquid (default
/// [`AvianCouplingPlugin::dynamic_boundary`] or [`AvianCouplingPlugin::boundary`]).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct LiquidBoundary(pub BoundaryCondition);

/// On an Avian entity that the liquid cannot see (unsupported shape or layout; warned once).
#[derive(Component, Clone, Debug, PartialEq, Eq)]
pub struct SkippedByLiquid(pub String);

/// What an Avian entity is to the liquid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShadowKind {
    /// A coupled rigid body (Avian dynamic).
    Dynamic,
    /// A collider placed by Avian (static, kinematic or body-less).
    Placed,
}

/// On a shadow: the Avian entity it stands for.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct AvianSource {
    /// The Avian entity.
    pub entity: Entity,
    /// Dynamic body or placed collider.
    pub kind: ShadowKind,
}

/// On a dynamic shadow: the state at the start of the current frame and what the treacle
/// domain walls gave it during the frame.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct ShadowFrame {
    /// Simulated time at the start of the frame \[s\].
    pub time: f64,
    /// Velocity of the centre of mass at the start \[m/s\].
    pub linear: Vec3,
    /// Angular momentum about the centre of mass at the start (world frame) \[kg m²/s\].
    pub angular_momentum: Vec3,
    /// Σ of the walls' impulses over the frame's sub-steps \[kg m/s\].
    pub wall_impulse: Vec3,
    /// Whether liquid touched the body in some sub-step of the frame.
    pub touched: bool,
    /// The impulse handed to Avian after the last frame \[kg m/s\].
    pub handed_impulse: Vec3,
    /// The angular impulse handed to Avian after the last frame \[kg m²/s\].
    pub handed_angular_impulse: Vec3,
}

/// Couples Avian bodies and colliders with the liquid (see the module docs). Needs
/// [`GamePlugin`](super::GamePlugin), [`MpmPlugins`](crate::plugin::MpmPlugins) (driver in
/// `FixedUpdate`) and Avian's `PhysicsPlugins`, in any order; like `GamePlugin` its systems are
/// added in `Plugin::finish`.
#[derive(Clone, Copy, Debug)]
pub struct AvianCouplingPlugin {
    /// Condition of static and kinematic Avian colliders towards the liquid unless the
    /// Avian entity has a [`LiquidBoundary`]. Default `Slip`.
    pub boundary: BoundaryCondition,
    /// Condition of dynamic Avian bodies' shadows towards the liquid unless the Avian entity
    /// has a [`LiquidBoundary`]. Default `Sticky` (module docs: with `Slip` a floating body
    /// in a low-viscosity liquid drifts down).
    pub dynamic_boundary: BoundaryCondition,
}

impl Default for AvianCouplingPlugin {
    fn default() -> Self {
        Self {
            boundary: BoundaryCondition::Slip,
            dynamic_boundary: BoundaryCondition::Sticky,
        }
    }
}

impl AvianCouplingPlugin {
    /// The same condition for every Avian entity.
    pub fn with_boundary(boundary: BoundaryCondition) -> Self {
        Self {
            boundary,
            dynamic_boundary: boundary,
        }
    }
}

/// The plugin's settings as a resource.
#[derive(Resource, Clone, Copy, Debug)]
pub struct AvianCoupling {
    /// See [`AvianCouplingPlugin::boundary`].
    pub boundary: BoundaryCondition,
    /// See [`AvianCouplingPlugin::dynamic_boundary`].
    pub dynamic_boundary: BoundaryCondition,
}

impl Plugin for AvianCouplingPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(AvianCoupling {
            boundary: self.boundary,
            dynamic_boundary: self.dynamic_boundary,
        });
        app.add_systems(
            MpmStep,
            accumulate_wall_impulses
                .in_set(CommitSystems::Bodies)
                .after(crate::rigid::commit_rigid_bodies),
        );
    }

    fn finish(&self, app: &mut App) {
        let schedule: Interned<dyn ScheduleLabel> = app
            .world()
            .get_resource::<DriverSchedule>()
            .map_or_else(|| bevy_app::Update.intern(), |s| s.0);
        if schedule != FixedUpdate.intern() {
            log::warn!(
                "AvianCouplingPlugin: the liquid's frame driver runs in {schedule:?}, not \
                 FixedUpdate; Avian (FixedPostUpdate) and the liquid then cover different time \
                 intervals (see treacle::game::avian)"
            );
        }
        app.add_systems(
            schedule,
            (
                sync_shadows_from_avian
                    .in_set(DriverSystems::Pace)
                    .after(super::request_from_time),
                hand_impulses_to_avian.in_set(DriverSystems::Publish),
            ),
        );
    }
}

/// Treacle's shape for an Avian collider (scaled), or why there is none.
fn treacle_shape(
    collider: &avian3d::prelude::Collider,
    dynamic: bool,
) -> Result<ColliderShape, String> {
    let shape = collider.shape_scaled();
    if let Some(ball) = shape.as_ball() {
        return Ok(ColliderShape::Sphere {
            radius: ball.radius,
        });
    }
    if let Some(cuboid) = shape.as_cuboid() {
        return Ok(ColliderShape::Box {
            half_extents: cuboid.half_extents,
        });
    }
    let kind = format!("{:?}", shape.shape_type());
    if dynamic {
        return Err(format!(
            "a dynamic body's collider must be a ball or a cuboid for the liquid (got {kind})"
        ));
    }
    if let Some(c) = shape.as_cylinder() {
        return Ok(ColliderShape::Cylinder {
            radius: c.radius,
            half_height: c.half_height,
        });
    }
    if let Some(h) = shape.as_halfspace() {
        return Ok(ColliderShape::HalfSpace { normal: h.normal });
    }
    Err(format!(
        "the liquid supports ball, cuboid, cylinder and half-space colliders (got {kind})"
    ))
}

/// World inertia R diag(I) Rᵀ times Ω.
fn angular_momentum(body: &RigidBody, rotation: Quat, omega: Vec3) -> Vec3 {
    body.world_inertia(rotation) * omega
}

/// The pose of an Avian entity: `Position`/`Rotation` if it has them, else its
/// `GlobalTransform`.
fn avian_pose(
    position: Option<&Position>,
    rotation: Option<&Rotation>,
    global: Option<&GlobalTransform>,
) -> Option<(Vec3, Quat)> {
    match (position, rotation, global) {
        (Some(p), Some(r), _) => Some((p.0, r.0)),
        (_, _, Some(g)) => {
            let (_, rot, t) = g.to_scale_rotation_translation();
            Some((t, rot))
        }
        _ => None,
    }
}

/// The Avian side of [`sync_shadows_from_avian`].
type AvianItem<'a> = (
    Entity,
    &'a avian3d::prelude::Collider,
    Option<&'a avian3d::prelude::RigidBody>,
    Option<&'a ColliderOf>,
    (
        Option<&'a Position>,
        Option<&'a Rotation>,
        Option<&'a GlobalTransform>,
    ),
    (Option<&'a LinearVelocity>, Option<&'a AngularVelocity>),
    (
        Option<&'a ComputedMass>,
        Option<&'a ComputedAngularInertia>,
        Option<&'a ComputedCenterOfMass>,
    ),
    Option<&'a LiquidShadow>,
    Option<&'a LiquidBoundary>,
);

/// The shadow side of [`sync_shadows_from_avian`].
type ShadowItem<'a> = (
    &'a AvianSource,
    &'a mut Collider,
    &'a mut ColliderPose,
    Option<&'a mut ColliderMotion>,
    Option<&'a mut RigidBody>,
    Option<&'a mut RigidVelocity>,
    Option<&'a mut ShadowFrame>,
);

/// Start of a liquid frame ([`DriverSystems::Pace`]): creates, updates and removes the shadows
/// of the Avian entities (see the module docs), and copies treacle's gravity to Avian.
#[allow(clippy::type_complexity)]
pub fn sync_shadows_from_avian(
    mut commands: Commands,
    coupling: Res<AvianCoupling>,
    config: Res<MpmConfig>,
    clock: Res<SimulationClock>,
    gravity: Option<ResMut<Gravity>>,
    avian: Query<AvianItem, Without<SkippedByLiquid>>,
    mut shadows: Query<(Entity, ShadowItem)>,
) {
    if let Some(mut gravity) = gravity
        && gravity.0 != config.gravity
    {
        gravity.0 = config.gravity;
    }
    // Shadows whose Avian entity is gone, changed kind or lost its collider.
    for (shadow, (source, ..)) in &shadows {
        let keep = avian.get(source.entity).is_ok_and(|item| {
            let dynamic = is_dynamic(item.2);
            item.7.map(|s| s.0) == Some(shadow) && (source.kind == ShadowKind::Dynamic) == dynamic
        });
        if !keep {
            commands.entity(shadow).despawn();
            if let Ok(mut e) = commands.get_entity(source.entity) {
                e.try_remove::<LiquidShadow>();
            }
        }
    }
    for (entity, collider, body, collider_of, pose, velocity, mass, shadow, boundary) in &avian {
        let dynamic = is_dynamic(body);
        let default = if dynamic {
            coupling.dynamic_boundary
        } else {
            coupling.boundary
        };
        let boundary = boundary.map_or(default, |b| b.0);
        let skip = |commands: &mut Commands, why: String| {
            log::warn!("the liquid ignores Avian entity {entity}: {why}");
            commands.entity(entity).insert(SkippedByLiquid(why));
        };
        if collider_of.is_some_and(|c| c.body != entity) {
            skip(
                &mut commands,
                "its collider is attached to another entity's body (only colliders on the \
                 body's own entity are supported)"
                    .into(),
            );
            continue;
        }
        let shape = match treacle_shape(collider, dynamic) {
            Ok(s) => s,
            Err(why) => {
                skip(&mut commands, why);
                continue;
            }
        };
        let Some((position, rotation)) = avian_pose(pose.0, pose.1, pose.2) else {
            continue;
        };
        let (v, w) = (
            velocity.0.map_or(Vec3::ZERO, |v| v.0),
            velocity.1.map_or(Vec3::ZERO, |w| w.0),
        );
        let com_local = mass.2.map_or(Vec3::ZERO, |c| c.0);
        let treacle_collider = Collider { shape, boundary };
        if dynamic {
            let (Some(m), Some(inertia)) = (mass.0, mass.1) else {
                continue;
            };
            let m = m.value();
            let diagonal = {
                let t = inertia.tensor();
                Vec3::new(t.m00, t.m11, t.m22)
            };
            if !(m.is_finite() && m > 0.0 && diagonal.is_finite() && diagonal.min_element() > 0.0) {
                // Mass properties not computed yet (first frame) or infinite: wait.
                continue;
            }
            let size = crate::rigid::bounding_radius(&treacle_collider.shape);
            if com_local.length() > 1e-4 * size {
                skip(
                    &mut commands,
                    format!(
                        "its centre of mass {com_local} is off its collider's centre (treacle's \
                         bodies have their origin at the centre of mass)"
                    ),
                );
                continue;
            }
            let rigid = RigidBody {
                mass: m as Real,
                inertia: diagonal,
            };
            let new_pose = ColliderPose {
                translation: position,
                rotation,
            };
            let frame = ShadowFrame {
                time: clock.time,
                linear: v,
                angular_momentum: angular_momentum(&rigid, rotation, w),
                ..Default::default()
            };
            let vel = RigidVelocity {
                linear: v,
                angular: w,
            };
            match shadow.and_then(|s| shadows.get_mut(s.0).ok()) {
                Some((_, (_, mut c, mut p, _, Some(mut b), Some(mut rv), Some(mut f)))) => {
                    if *c != treacle_collider {
                        *c = treacle_collider;
                    }
                    *p = new_pose;
                    *b = rigid;
                    *rv = vel;
                    *f = frame;
                }
                _ => {
                    let s = commands
                        .spawn((
                            AvianSource {
                                entity,
                                kind: ShadowKind::Dynamic,
                            },
                            rigid,
                            treacle_collider,
                            new_pose,
                            vel,
                            RigidAcceleration {
                                linear: config.gravity,
                                angular: Vec3::ZERO,
                            },
                            frame,
                        ))
                        .id();
                    commands.entity(entity).insert(LiquidShadow(s));
                }
            }
        } else {
            // Velocity of the collider's origin (Avian's velocities are those of the centre
            // of mass).
            let com_world = rotation * com_local;
            let motion = ColliderMotion {
                linear_velocity: v - w.cross(com_world),
                angular_velocity: w,
            };
            let new_pose = ColliderPose {
                translation: position,
                rotation,
            };
            match shadow.and_then(|s| shadows.get_mut(s.0).ok()) {
                Some((_, (_, mut c, mut p, Some(mut m), None, _, _))) => {
                    if *c != treacle_collider {
                        *c = treacle_collider;
                    }
                    if *p != new_pose {
                        *p = new_pose;
                    }
                    if *m != motion {
                        *m = motion;
                    }
                }
                _ => {
                    let s = commands
                        .spawn((
                            AvianSource {
                                entity,
                                kind: ShadowKind::Placed,
                            },
                            treacle_collider,
                            new_pose,
                            motion,
                        ))
                        .id();
                    commands.entity(entity).insert(LiquidShadow(s));
                }
            }
        }
    }
}

fn is_dynamic(body: Option<&avian3d::prelude::RigidBody>) -> bool {
    body.is_some_and(|b| b.is_dynamic())
}

/// After every sub-step (in [`CommitSystems::Bodies`], after the bodies' commit): sums the
/// walls' impulses on the dynamic shadows and whether liquid touched them.
pub fn accumulate_wall_impulses(mut q: Query<(&RigidExchange, &mut ShadowFrame)>) {
    for (exchange, mut frame) in &mut q {
        frame.wall_impulse += exchange.wall_impulse;
        frame.touched |= exchange.iterations > 0 || exchange.contact_mass > 0.0;
    }
}

/// After the frame ([`DriverSystems::Publish`]): hands each dynamic shadow's liquid impulse
/// over the frame to its Avian body as a force over Avian's coming step (see the module docs).
#[allow(clippy::type_complexity)]
pub fn hand_impulses_to_avian(
    config: Res<MpmConfig>,
    clock: Res<SimulationClock>,
    mut shadows: Query<(
        &AvianSource,
        &RigidBody,
        &ColliderPose,
        &RigidVelocity,
        &mut ShadowFrame,
    )>,
    time: Res<Time>,
    mut bodies: Query<Forces>,
) {
    let step = time.delta_secs_f64();
    for (source, body, pose, velocity, mut frame) in &mut shadows {
        let t = clock.time - frame.time;
        let (j, dl) = if frame.touched && t > 0.0 {
            let m = body.mass as f64;
            let dv = velocity.linear.as_dvec3() - frame.linear.as_dvec3();
            let j = m * dv - m * config.gravity.as_dvec3() * t - frame.wall_impulse.as_dvec3();
            let l_end = angular_momentum(body, pose.rotation, velocity.angular);
            (j.as_vec3(), l_end - frame.angular_momentum)
        } else {
            (Vec3::ZERO, Vec3::ZERO)
        };
        frame.handed_impulse = j;
        frame.handed_angular_impulse = dl;
        frame.wall_impulse = Vec3::ZERO;
        frame.touched = false;
        if let Ok(mut forces) = bodies.get_mut(source.entity) {
            if step > 0.0 {
                forces.apply_force(j / step as Real);
                forces.apply_torque(dl / step as Real);
            } else {
                forces.apply_linear_impulse(j);
                forces.apply_angular_impulse(dl);
            }
        }
    }
}
