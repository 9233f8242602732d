//! The frame driver and the assembly of the [`MpmStep`] schedule.
//!
//! One frame (one `App::update`) advances the simulation by [`MpmConfig::frame_dt`]: the
//! driver system [`advance_frame`] runs the [`MpmStep`] schedule N times, each with the step
//! size chosen by the monitor of the previous step (§2.15), the last one clipped to the frame
//! end. [`run_step`] sets the [`StepContext`] of one step; [`start`] runs the consistent
//! start-up of §2.14.
use bevy_ecs::prelude::*;

use super::pacing::{FrameBudget, FramePacing, SimulationLag};
use super::schedule::{
    CommitSystems, ConstitutiveSystems, EmitSystems, GridToParticleSystems, GridUpdateSystems,
    Gs4Constants, MonitorSystems, MpmStep, MpmSystems, ParticleToGridSystems, PredictSystems,
    SimulationClock, StepContext, StepProgress, StopRequest, coefficients, init_step_schedule,
};
use crate::config::MpmConfig;
use crate::failure::SimulationStatus;
use crate::material::Materials;

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
    if let Err(e) = config.integrator.flip_interval.validate() {
        return Err(format!("integrator.flip_interval {e}"));
    }
    if let Err((field, constraint)) = config
        .integrator
        .pressure
        .validate(config.integrator.scheme, &config.walls)
    {
        return Err(format!("{field}: {constraint}"));
    }
    if let Err((field, constraint)) = config
        .integrator
        .velocity_gradient
        .validate(config.integrator.scheme)
    {
        return Err(format!("{field}: {constraint}"));
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
    // The wave speed of the Δt rule (§7.2) at the last monitor, at least the materials' c₀.
    let c_max = world
        .resource::<Materials>()
        .list
        .iter()
        .map(|m| m.sound_speed as f64)
        .fold(
            (world.resource::<SimulationClock>().maxima.wave_speed_sq as f64).sqrt(),
            f64::max,
        );
    let ig = &config.integrator;
    let interval = ig.flip_interval.seconds(config.dx as f64, c_max);
    let flip = crate::config::flip_over_interval(ig.flip as f64, dt, interval) as crate::math::Real;
    // The start-up rate evaluation (Δt = 0) keeps the transferred state as it is.
    let sticky_share = if rate_evaluation {
        1.0
    } else {
        ig.sticky_reset.share(dt, interval)
    };
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
        sticky_share,
        flip_interval: interval,
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

/// A predicted step may exceed its limit by this fraction to end the frame in one step: frame
/// lengths from Bevy's clock are whole nanoseconds, so a 60 Hz frame arrives as 16,666,667 ns,
/// 0.33 ns longer than a `max_dt` of 1/60 s, and without this slack every such frame took two
/// half steps. 10⁻⁶ is far inside the safety factor of every step limit (§7.2).
pub const STEP_SLACK: f64 = 1e-6;

/// The step that advances `remaining` seconds of a frame given the predicted `next` Δt: all of
/// it when `next` covers it (to within [`STEP_SLACK`]); half of it when it is less than 1.5
/// steps (no sliver step at the end); otherwise `next`.
pub fn step_towards(next: f64, remaining: f64) -> f64 {
    if next * (1.0 + STEP_SLACK) >= remaining {
        remaining
    } else if next * 1.5 > remaining {
        0.5 * remaining
    } else {
        next
    }
}

/// Advances the simulation by one frame: `MpmConfig::frame_dt` exactly, or under
/// [`FramePacing::Requested`] the requested time within the [`FrameBudget`], recording any
/// shortfall in [`SimulationLag`]. Does nothing once failed.
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
    let pacing = world
        .get_resource::<FramePacing>()
        .copied()
        .unwrap_or_default();
    let (frame, t0) = {
        let c = world.resource::<SimulationClock>();
        (c.frame, c.time)
    };
    let (target, budget) = match pacing {
        // Frame ends at (frame+1)·frame_dt exactly, so long runs do not drift.
        FramePacing::Fixed => ((frame + 1) as f64 * frame_dt, FrameBudget::default()),
        FramePacing::Requested { dt } => (
            if dt.is_finite() && dt > 0.0 {
                t0 + dt
            } else {
                t0
            },
            world
                .get_resource::<FrameBudget>()
                .copied()
                .unwrap_or_default(),
        ),
    };
    let wall = std::time::Instant::now();
    let mut t = t0;
    let (mut dmin, mut dmax, mut steps) = (f64::INFINITY, 0.0f64, 0u64);
    let (mut interrupted, mut over_budget) = (false, false);
    while t < target {
        if budget.max_substeps.is_some_and(|n| steps >= n as u64)
            || budget.max_wall_time.is_some_and(|w| wall.elapsed() >= w)
        {
            over_budget = true;
            break;
        }
        let next = world.resource::<SimulationClock>().next_dt;
        let remaining = target - t;
        let dt = step_towards(next, remaining);
        let next_t = if dt == remaining { target } else { t + dt };
        if !(dt.is_finite() && dt > 0.0 && next_t > t) {
            // No progress: a Δt that is not finite and positive, or one too small to change t
            // in double precision, would end the frame silently or loop forever (§7.2).
            stall(world, dt, t);
            break;
        }
        run_step(world, dt, false);
        if world.resource::<SimulationStatus>().failed() {
            break;
        }
        t = next_t;
        dmin = dmin.min(dt);
        dmax = dmax.max(dt);
        steps += 1;
        let mut c = world.resource_mut::<SimulationClock>();
        c.time = t;
        c.steps += 1;
        let total_steps = c.steps;
        if let Some(p) = world.get_resource::<StepProgress>() {
            p.store(total_steps, t);
        }
        if t < target
            && world
                .get_resource::<StopRequest>()
                .is_some_and(StopRequest::requested)
        {
            interrupted = true;
            break;
        }
    }
    // A frame cut short by a failure or a stop request is not completed.
    let completed = !world.resource::<SimulationStatus>().failed() && !interrupted;
    let mut c = world.resource_mut::<SimulationClock>();
    c.interrupted = interrupted;
    if completed {
        c.frame += 1;
    }
    c.frame_dt_min = if steps > 0 { dmin } else { 0.0 };
    c.frame_dt_max = dmax;
    c.frame_steps = steps;
    if matches!(pacing, FramePacing::Requested { .. }) {
        record_lag(world, target - t, over_budget, steps, budget);
    }
}

/// Updates [`SimulationLag`] after a requested frame that left `shortfall` seconds undone.
fn record_lag(
    world: &mut World,
    shortfall: f64,
    over_budget: bool,
    steps: u64,
    budget: FrameBudget,
) {
    let next_dt = world.resource::<SimulationClock>().next_dt;
    let mut lag = world.get_resource_or_insert_with(SimulationLag::default);
    lag.last_frame = shortfall.max(0.0);
    lag.total += lag.last_frame;
    lag.last_substeps = steps.min(u32::MAX as u64) as u32;
    if over_budget {
        lag.frames_behind += 1;
        if !lag.warned {
            lag.warned = true;
            log::warn!(
                "treacle: the liquid cannot keep up with the game clock: the frame budget \
                 ({budget:?}) allowed {steps} sub-steps of Δt ≈ {next_dt:.2e} s and {:.2e} s of \
                 simulated time were dropped; simulated time now runs behind (see \
                 SimulationLag). A coarser dx, a smaller sound speed or viscosity, or a larger \
                 budget lets it keep up (logged once)",
                lag.last_frame
            );
        }
    }
}

/// Stops the run with a failure for a step `dt` that cannot advance the time `t`.
fn stall(world: &mut World, dt: f64, t: f64) {
    let (steps, limit) = {
        let c = world.resource::<SimulationClock>();
        (c.steps, c.predicted_limit)
    };
    let fixed = matches!(
        world.resource::<MpmConfig>().time_step.mode,
        crate::config::TimeStepMode::Fixed(_)
    );
    let mut f = crate::failure::FailureReport::global(
        "time step",
        dt,
        if fixed {
            format!(
                "the fixed time step {dt:.3e} s does not advance the simulated time t = {t:.6e} s \
                 (t + Δt = t in double precision)"
            )
        } else {
            format!(
                "the time step {dt:.3e} s does not advance the simulated time t = {t:.6e} s \
                 (not finite and positive, or t + Δt = t in double precision)"
            )
        },
    );
    f.step = steps;
    f.time = t;
    f.dt = dt;
    f.suggested_dt = if limit.is_finite() && limit > 0.0 {
        0.5 * limit
    } else {
        0.0
    };
    world.resource_mut::<SimulationStatus>().failure = Some(f);
}

/// Adds the core systems of one step to the [`MpmStep`] schedule (creating it if absent), each
/// in the sub-set of its stage.
pub fn add_core_systems(app: &mut bevy_app::App) {
    use super::*;
    init_step_schedule(app);
    app.add_systems(
        MpmStep,
        (
            (
                predict::predict_positions,
                predict::follow_collider_paths.before(predict::gather_colliders),
                predict::gather_colliders,
            )
                .in_set(PredictSystems::Core),
            p2g::particle_to_grid.in_set(ParticleToGridSystems::Momentum),
            (
                (
                    kinematics::velocity_gradients,
                    kinematics::velocity_and_deformation_gradients,
                )
                    .chain()
                    .run_if(kinematics::gathered_velocity_gradient),
                kinematics::carry_deformation_gradients
                    .run_if(not(kinematics::gathered_velocity_gradient)),
            )
                .chain()
                .in_set(MpmSystems::Kinematics),
            constitutive::newtonian_stress.in_set(ConstitutiveSystems::Base),
            grid_forces::grid_forces.in_set(MpmSystems::GridForces),
            // One grid update per scheme (run conditions; the default GS4 path only pays for
            // the condition); chained so that their order is explicit.
            (
                grid_update::grid_update.run_if(implicit::explicit_gs4_update),
                symplectic_euler::grid_update.run_if(symplectic_euler::symplectic_euler_step),
                implicit::implicit_viscous_update.run_if(implicit::implicit_viscosity_step),
                implicit::project_pressure.run_if(implicit::pressure_projection_step),
            )
                .chain()
                .in_set(GridUpdateSystems::Update),
        ),
    );
    app.add_systems(
        MpmStep,
        (
            // The GS4 transfer or the first-order one (run conditions), in an explicit order.
            (
                (g2p::update_deformation_gradients, g2p::grid_to_particle)
                    .chain()
                    .run_if(symplectic_euler::gs4_transfer),
                symplectic_euler::grid_to_particle.run_if(symplectic_euler::first_order_step),
            )
                .chain()
                .in_set(GridToParticleSystems::Momentum),
            (
                commit::commit_density.run_if(symplectic_euler::gs4_transfer),
                commit::particle_collisions,
                commit::move_colliders,
            )
                .chain()
                .in_set(CommitSystems::Core),
            (commit::remove_escaped, commit::expire_colliders)
                .chain()
                .in_set(EmitSystems::Remove),
            monitor::monitor_step.in_set(MonitorSystems::Core),
            energy::monitor_energy.in_set(MonitorSystems::Energy),
        ),
    );
}
