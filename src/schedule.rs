//! The step schedule, its ordered system sets, and the frame driver.
//!
//! One frame (one `App::update`) advances the simulation by [`MpmConfig::frame_dt`]: the
//! driver system [`advance_frame`] runs the [`MpmStep`] schedule N times, each with the step
//! size chosen by the monitor of the previous step (ALGORITHM §2.15), the last one clipped to
//! the frame end. Inside [`MpmStep`], [`StepContext`] holds the current Δt and GS4 constants —
//! systems read it instead of a wall clock, so runs are reproducible.
//!
//! The schedule is single-threaded between systems (the order *is* the algorithm); systems
//! parallelise internally over particles or grid planes with deterministic results.
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{ScheduleLabel, SingleThreadedExecutor};

use crate::collision::{Collider, ColliderInstance, ColliderMotion, ColliderPose};
use crate::config::{MpmConfig, Scheme};
use crate::failure::SimulationStatus;
use crate::gs4::Gs4Params;
use crate::kernels::StepCoefficients;
use crate::step::commit::advance_pose;
use crate::step::monitor::StabilityMaxima;

/// The schedule of one MPM step.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct MpmStep;

/// The steps of ALGORITHM §2.3 in run order (configured with `.chain()`).
///
/// Stress is computed **after** P2G and scattered by its own pass (`GridForces`), as in \[Su21\];
/// within a step, "current" quantities are the predicted ones at t_{n+W₁} until `GridToParticle`
/// writes t_{n+1}.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MpmSystems {
    /// S1 (§2.4). Reads `Position`, `Velocity`, `Acceleration`; writes `PredictedPosition`;
    /// also gathers colliders at t_{n+1} into [`ActiveColliders`].
    Predict,
    /// S2–S3 (§2.5). Reads `PredictedPosition`, `Mass`, `Velocity`, `Acceleration`;
    /// writes `MpmGrid` mass/velocity/acceleration.
    ParticleToGrid,
    /// S4. Reads `MpmGrid`; writes `VelocityGradient` (and `PredictedDeformationGradient`).
    Kinematics,
    /// S5–S10 (§2.6–2.9). Writes `PredictedDensity`, `CauchyStress`, `StabilityData`; rheology
    /// models add to them in [`ConstitutiveSystems::Models`].
    Constitutive,
    /// S11 force scatter (§2.9). Writes `MpmGrid` force.
    GridForces,
    /// S11 grid update and collisions (§2.10–2.11). Writes `MpmGrid` new velocity/acceleration.
    GridUpdate,
    /// S12 heat solve (§3); empty without the thermal plugin.
    Thermal,
    /// S13–S14 (§2.12–2.13). Writes `Position`, `Velocity`, `Acceleration`,
    /// `DeformationGradient`.
    GridToParticle,
    /// S15 (§2.6, §2.8): commits GS4 pairs and model state; particle collisions.
    Commit,
    /// S16 (§4.4): emitters spawn particles; escaped particles are removed.
    Emit,
    /// Failure detection and the next Δt (§2.15).
    Monitor,
}

/// Sub-sets of [`MpmSystems::Constitutive`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ConstitutiveSystems {
    /// Density, pressure and the Newtonian local stress (overwrites the stress).
    Base,
    /// Rheology models: add extra stress, raise stability data.
    Models,
}

/// Sub-sets of [`MpmSystems::Commit`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CommitSystems {
    /// Core commits: density pair, particle collisions, collider motion.
    Core,
    /// Model state commits (they may read ρⁿ⁺¹ and xⁿ⁺¹).
    Models,
}

/// Δt and GS4 constants of the step being run.
#[derive(Resource, Clone, Copy, Debug)]
pub struct StepContext {
    /// Coefficients (Δt, GS4 weights, FLIP fractions) in the particle precision.
    pub coefficients: StepCoefficients,
    /// Δt of this step in f64 \[s\] (0 during the rate evaluation), for models that integrate
    /// their state in double precision.
    pub dt: f64,
    /// True during the start-up rate evaluation (Δt = 0, §2.14).
    pub rate_evaluation: bool,
}

impl Default for StepContext {
    fn default() -> Self {
        Self {
            coefficients: coefficients(&Gs4Params::default(), 0.0, 1.0, true),
            dt: 0.0,
            rate_evaluation: false,
        }
    }
}

/// Panics with a message naming `plugin` unless `app` already has the [`MpmStep`] schedule
/// (plugins that add systems to it must come after `MpmPlugins` / `MpmCorePlugin`).
pub fn require_step_schedule(app: &bevy_app::App, plugin: &str) {
    let has_step = app
        .world()
        .get_resource::<Schedules>()
        .is_some_and(|s| s.contains(MpmStep));
    assert!(
        has_step,
        "{plugin} needs the MPM step schedule: add MpmPlugins (or MpmCorePlugin) before it"
    );
}

/// Builds the per-step coefficients from the GS4 parameters.
pub fn coefficients(p: &Gs4Params, dt: f64, flip: f32, rate_eval: bool) -> StepCoefficients {
    if rate_eval {
        // §2.14: one rate evaluation with Δt = 0 and unit effective mass, so that
        // aᵢ = fᵢ/mᵢ + g, ρ̇ = −ρ tr L, σ̇ = H(σ, L); PIC for the rates, positions unchanged.
        return StepCoefficients {
            dt: 0.0,
            w1l1: 0.0,
            w1l4: 0.0,
            w1l6: 1.0,
            w2l2: 0.0,
            w2l5: 0.0,
            l4: 0.0,
            l5: 0.0,
            flip_velocity: 1.0,
            flip_acceleration: 0.0,
        };
    }
    StepCoefficients {
        dt: dt as f32,
        w1l1: p.w1l1 as f32,
        w1l4: p.w1l4 as f32,
        w1l6: p.w1l6 as f32,
        w2l2: p.w2l2 as f32,
        w2l5: p.w2l5 as f32,
        l4: p.l4 as f32,
        l5: p.l5 as f32,
        flip_velocity: flip,
        flip_acceleration: flip,
    }
}

/// GS4 parameters of the mechanics and the explicit stability constants of the momentum
/// update of the chosen scheme (§1.3, §7.2).
#[derive(Resource, Clone, Copy, Debug)]
pub struct Gs4Constants {
    /// The parameter set (also used by rheology models for their GS4-1 histories, whatever
    /// the scheme).
    pub params: Gs4Params,
    /// Largest stable kΔt of the explicit viscous term: z_crit of explicit GS4-1, or 2 for the
    /// forward-Euler viscosity of [`Scheme::SymplecticEuler`] (and for explicit model
    /// viscosities under [`Scheme::BackwardEulerViscous`]).
    pub z_crit: f64,
    /// Largest stable ωΔt of waves: Ω_crit of explicit GS4-II, or 2 for the symplectic-Euler
    /// pressure update of the first-order schemes.
    pub omega_crit: f64,
    /// The scheme these constants are for.
    pub scheme: Scheme,
}

impl Gs4Constants {
    /// Computes the constants for (ρ∞, ρs) and the explicit GS4 scheme.
    pub fn new(rho_inf: f64, rho_s: f64) -> Result<Self, crate::gs4::Gs4Error> {
        Self::for_scheme(Scheme::Gs4Explicit, rho_inf, rho_s)
    }

    /// Computes the constants for (ρ∞, ρs) and `scheme`.
    pub fn for_scheme(
        scheme: Scheme,
        rho_inf: f64,
        rho_s: f64,
    ) -> Result<Self, crate::gs4::Gs4Error> {
        let params = Gs4Params::new(rho_inf, rho_s)?;
        let (z_crit, omega_crit) = if scheme.is_gs4() {
            (params.z_crit(), params.omega_crit(0.0))
        } else {
            // Forward Euler on ẏ = −ky: |1 − z| ≤ 1; symplectic Euler on an oscillator: Ω ≤ 2.
            (2.0, 2.0)
        };
        Ok(Self {
            params,
            z_crit,
            omega_crit,
            scheme,
        })
    }
}

/// Simulated time and step statistics.
#[derive(Resource, Clone, Debug, Default)]
pub struct SimulationClock {
    /// Simulated time t \[s\].
    pub time: f64,
    /// Steps taken so far.
    pub steps: u64,
    /// Frames completed so far.
    pub frame: u64,
    /// Δt of the next step (from the last monitor pass) \[s\].
    pub next_dt: f64,
    /// Predicted stability limit (no safety factor) at the last healthy step \[s\].
    pub predicted_limit: f64,
    /// Smallest and largest Δt used during the last frame \[s\].
    pub frame_dt_min: f64,
    /// See `frame_dt_min`.
    pub frame_dt_max: f64,
    /// Steps taken during the last frame.
    pub frame_steps: u64,
    /// Whether the start-up rate evaluation has run.
    pub started: bool,
    /// Particles removed through open faces so far.
    pub escaped_particles: u64,
    /// Stability maxima at the last monitor pass.
    pub maxima: StabilityMaxima,
    /// The largest speed the set-up itself explains \[m/s\]: the fastest initial particle plus
    /// free fall across the domain, |v₀|max + √(2|g|H). Set by the start-up; the monitor's
    /// Mach blow-up test uses max(c₀, this) (a scene that throws liquid faster than its sound
    /// speed is not blowing up at its first step).
    pub speed_scale: f64,
}

/// Colliders in world frame at t_{n+1}, gathered once per step.
#[derive(Resource, Clone, Debug, Default)]
pub struct ActiveColliders {
    /// The colliders.
    pub list: Vec<ColliderInstance>,
}

/// Gathers colliders (pose advanced to t_{n+1} for moving ones). Dynamic bodies
/// ([`crate::rigid::RigidBody`]) are not among them: [`crate::rigid`] couples those.
pub fn gather_colliders(
    ctx: Res<StepContext>,
    mut active: ResMut<ActiveColliders>,
    q: Query<(&Collider, &ColliderPose, Option<&ColliderMotion>), Without<crate::rigid::RigidBody>>,
) {
    let dt = ctx.coefficients.dt;
    active.list.clear();
    for (c, pose, motion) in &q {
        let motion = motion.copied().unwrap_or_default();
        active.list.push(ColliderInstance {
            shape: c.shape.clone(),
            boundary: c.boundary,
            pose: advance_pose(*pose, &motion, dt),
            motion,
        });
    }
}

/// Makes sure the grid and GS4 constants match the configuration (called by the driver).
fn sync_resources(world: &mut World) {
    let config = world.resource::<MpmConfig>().clone();
    let rebuild = match world.get_resource::<crate::grid::MpmGrid>() {
        None => true,
        Some(g) => {
            g.layout
                != crate::grid::GridLayout::new(config.domain_min, config.domain_max, config.dx)
        }
    };
    if rebuild {
        world.insert_resource(crate::grid::MpmGrid::new(
            config.domain_min,
            config.domain_max,
            config.dx,
        ));
    }
    let want = (
        config.integrator.rho_inf,
        config.integrator.rho_s,
        config.integrator.scheme,
    );
    let have = world
        .get_resource::<Gs4Constants>()
        .map(|c| (c.params.rho_inf, c.params.rho_s, c.scheme));
    if have != Some(want) {
        match Gs4Constants::for_scheme(want.2, want.0, want.1) {
            Ok(c) => {
                world.insert_resource(c);
            }
            Err(e) => {
                world.resource_mut::<SimulationStatus>().failure = Some(
                    crate::failure::FailureReport::global("integrator", f64::NAN, e.to_string()),
                );
            }
        }
    }
}

/// Checks constraints the step relies on (the scene validator reports the same with file and
/// line; this guards configurations built in code).
pub fn check_config(config: &MpmConfig) -> Result<(), String> {
    if !(config.dx > 0.0 && config.dx.is_finite()) {
        return Err(format!("dx must be > 0 (got {})", config.dx));
    }
    let walls = config.walls;
    for a in 0..3 {
        let lo = matches!(
            walls.face(a, false),
            crate::config::BoundaryCondition::Periodic
        );
        let hi = matches!(
            walls.face(a, true),
            crate::config::BoundaryCondition::Periodic
        );
        if lo != hi {
            return Err(format!("axis {a}: Periodic must be set on both faces"));
        }
        if lo {
            let cells = (config.domain_max[a] - config.domain_min[a]) / config.dx;
            if (cells - cells.round()).abs() > 1e-3 || cells.round() < 4.0 {
                return Err(format!(
                    "axis {a} is periodic, so its length must be a whole number (≥ 4) of cells dx (got {cells} cells)"
                ));
            }
        }
    }
    Ok(())
}

/// Runs one step of size `dt` (or the start-up rate evaluation when `rate_evaluation`).
pub fn run_step(world: &mut World, dt: f64, rate_evaluation: bool) {
    let config = world.resource::<MpmConfig>();
    let flip = config.integrator.flip;
    let gs4_path = config.integrator.scheme.is_gs4() || rate_evaluation;
    let gs4 = world.resource::<Gs4Constants>().params;
    *world.resource_mut::<StepContext>() = StepContext {
        coefficients: if gs4_path {
            coefficients(&gs4, dt, flip, rate_evaluation)
        } else {
            crate::step::symplectic_euler::first_order_coefficients(dt, flip)
        },
        dt: if rate_evaluation { 0.0 } else { dt },
        rate_evaluation,
    };
    world.run_schedule(MpmStep);
}

/// The consistent start-up of §2.14 (run once before the first step when enabled), then the
/// first time step from the initial state.
pub fn start(world: &mut World) {
    sync_resources(world);
    if let Err(reason) = check_config(world.resource::<MpmConfig>()) {
        world.resource_mut::<SimulationStatus>().failure = Some(
            crate::failure::FailureReport::global("configuration", f64::NAN, reason),
        );
    }
    if world.resource::<SimulationStatus>().failed() {
        return;
    }
    let consistent = world.resource::<MpmConfig>().integrator.consistent_startup;
    // The rate evaluation leaves positions, velocities and densities unchanged and sets the
    // rates; its monitor pass also computes the first Δt. Without it we still need the first
    // Δt, so the pass runs either way, restoring the rates afterwards if not wanted.
    if consistent {
        run_step(world, 0.0, true);
    } else {
        let saved: Vec<(
            Entity,
            crate::components::Acceleration,
            crate::components::Density,
        )> = world
            .query_filtered::<(
                Entity,
                &crate::components::Acceleration,
                &crate::components::Density,
            ), With<crate::components::Particle>>()
            .iter(world)
            .map(|(e, a, d)| (e, *a, *d))
            .collect();
        run_step(world, 0.0, true);
        for (e, a, d) in saved {
            if let Ok(mut em) = world.get_entity_mut(e) {
                if let Some(mut x) = em.get_mut::<crate::components::Acceleration>() {
                    *x = a;
                }
                if let Some(mut x) = em.get_mut::<crate::components::Density>() {
                    *x = d;
                }
            }
        }
    }
    world.resource_mut::<SimulationClock>().started = true;
}

/// Advances the simulation by one frame (`MpmConfig::frame_dt`). Does nothing once failed.
pub fn advance_frame(world: &mut World) {
    if world.resource::<SimulationStatus>().failed() {
        return;
    }
    if !world.resource::<SimulationClock>().started {
        start(world);
        if world.resource::<SimulationStatus>().failed() {
            return;
        }
    }
    sync_resources(world);
    let frame_dt = world.resource::<MpmConfig>().frame_dt;
    let (frame, t0) = {
        let c = world.resource::<SimulationClock>();
        (c.frame, c.time)
    };
    // Frame ends at (frame+1)·frame_dt exactly, so long runs do not drift.
    let target = (frame + 1) as f64 * frame_dt;
    let mut t = t0;
    let (mut dmin, mut dmax, mut steps) = (f64::INFINITY, 0.0f64, 0u64);
    while t < target {
        let next = world.resource::<SimulationClock>().next_dt;
        let remaining = target - t;
        // Avoid a sliver step: if the remainder is less than 1.5 steps, split it evenly.
        let dt = if next >= remaining {
            remaining
        } else if next * 1.5 > remaining {
            0.5 * remaining
        } else {
            next
        };
        if dt.is_nan() || dt <= 0.0 || dt.is_infinite() {
            break;
        }
        run_step(world, dt, false);
        if world.resource::<SimulationStatus>().failed() {
            break;
        }
        t = if dt == remaining { target } else { t + dt };
        dmin = dmin.min(dt);
        dmax = dmax.max(dt);
        steps += 1;
        let mut c = world.resource_mut::<SimulationClock>();
        c.time = t;
        c.steps += 1;
    }
    // A frame cut short by a failure is not completed.
    let completed = !world.resource::<SimulationStatus>().failed();
    let mut c = world.resource_mut::<SimulationClock>();
    if completed {
        c.frame += 1;
    }
    c.frame_dt_min = if steps > 0 { dmin } else { 0.0 };
    c.frame_dt_max = dmax;
    c.frame_steps = steps;
}

/// Builds the [`MpmStep`] schedule with its sets and the core systems.
pub fn build_step_schedule() -> Schedule {
    use crate::step::*;
    let mut s = Schedule::new(MpmStep);
    s.set_executor(SingleThreadedExecutor::new());
    s.configure_sets(
        (
            MpmSystems::Predict,
            MpmSystems::ParticleToGrid,
            MpmSystems::Kinematics,
            MpmSystems::Constitutive,
            MpmSystems::GridForces,
            MpmSystems::GridUpdate,
            MpmSystems::Thermal,
            MpmSystems::GridToParticle,
            MpmSystems::Commit,
            MpmSystems::Emit,
            MpmSystems::Monitor,
        )
            .chain(),
    );
    s.configure_sets(
        (ConstitutiveSystems::Base, ConstitutiveSystems::Models)
            .chain()
            .in_set(MpmSystems::Constitutive),
    );
    s.configure_sets(
        (CommitSystems::Core, CommitSystems::Models)
            .chain()
            .in_set(MpmSystems::Commit),
    );
    s.add_systems((predict::predict_positions, gather_colliders).in_set(MpmSystems::Predict));
    s.add_systems(p2g::particle_to_grid.in_set(MpmSystems::ParticleToGrid));
    s.add_systems(
        (
            kinematics::velocity_gradients,
            kinematics::velocity_and_deformation_gradients,
        )
            .chain()
            .in_set(MpmSystems::Kinematics),
    );
    s.add_systems(constitutive::newtonian_stress.in_set(ConstitutiveSystems::Base));
    s.add_systems(grid_forces::grid_forces.in_set(MpmSystems::GridForces));
    // One grid update per scheme (run conditions; the default GS4 path only pays for the
    // condition). The rigid-body coupling runs after whichever ran.
    s.add_systems(
        (
            grid_update::grid_update.run_if(crate::implicit::explicit_gs4_update),
            symplectic_euler::grid_update.run_if(symplectic_euler::symplectic_euler_step),
            crate::implicit::implicit_viscous_update
                .run_if(crate::implicit::implicit_viscosity_step),
        )
            .in_set(MpmSystems::GridUpdate)
            .before(crate::rigid::couple_rigid_bodies),
    );
    s.add_systems(
        (g2p::update_deformation_gradients, g2p::grid_to_particle)
            .chain()
            .in_set(MpmSystems::GridToParticle)
            .run_if(symplectic_euler::gs4_transfer),
    );
    s.add_systems(
        symplectic_euler::grid_to_particle
            .in_set(MpmSystems::GridToParticle)
            .run_if(symplectic_euler::first_order_step),
    );
    s.add_systems(
        (
            commit::commit_density.run_if(symplectic_euler::gs4_transfer),
            commit::particle_collisions,
            commit::move_colliders,
        )
            .chain()
            .in_set(CommitSystems::Core),
    );
    s.add_systems((commit::remove_escaped, commit::expire_colliders).in_set(MpmSystems::Emit));
    s.add_systems(
        (monitor::monitor_step, energy::monitor_energy)
            .chain()
            .in_set(MpmSystems::Monitor),
    );
    s
}
