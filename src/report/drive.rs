//! The step loop of the reports: runs an app's [`MpmStep`](crate::step::schedule::MpmStep) directly
//! (as [`bench_scene`](crate::runner::bench_scene) does) rather than by frames, so that a fixed
//! Δt is used exactly N times (the frame driver may split the last step of a frame) and the
//! wall time covers the simulation only (not the scene sampling or app construction).
use std::time::Instant;

use bevy_app::App;
use bevy_ecs::world::World;

use crate::failure::{FailureReport, SimulationStatus};
use crate::step::driver::{run_step, start};
use crate::step::schedule::SimulationClock;

/// How the loop chooses Δt.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StepRule {
    /// Exactly `steps` steps of `dt` \[s\]; the end time is `steps · dt`.
    Exact {
        /// Δt \[s\].
        dt: f64,
        /// Number of steps.
        steps: u64,
    },
    /// The monitor's next Δt (adaptive, paper rule or the configured fixed step), clipped to
    /// the end time.
    Monitor,
    /// A fixed Δt \[s\], never clipped: ⌈end_time/Δt⌉ steps (the run may end up to one step
    /// after the end time).
    Fixed(f64),
}

/// What a loop did.
#[derive(Clone, Debug, Default)]
pub struct DriveOutcome {
    /// Steps taken.
    pub steps: u64,
    /// Simulated time reached \[s\].
    pub time: f64,
    /// Smallest and largest Δt used \[s\] (0 without steps).
    pub dt_min: f64,
    /// See `dt_min`.
    pub dt_max: f64,
    /// Wall time of start-up and steps \[s\].
    pub wall_seconds: f64,
    /// The failure that stopped the run.
    pub failure: Option<FailureReport>,
    /// True if `max_steps` ran out before the end time.
    pub budget_exhausted: bool,
}

/// Runs the start-up (if not done yet) and steps until `end_time` (or the failure, or
/// `max_steps`). `on_sample(world, time)` is called after the start-up, then whenever the
/// time passes a multiple of `end_time / samples`, and at the end of a healthy run;
/// `on_progress(fraction)` about every 1 % of the end time. Time spent in the callbacks is not
/// counted in the wall time.
pub fn drive(
    app: &mut App,
    end_time: f64,
    rule: StepRule,
    max_steps: u64,
    samples: u32,
    mut on_sample: impl FnMut(&mut World, f64),
    mut on_progress: impl FnMut(f64),
) -> DriveOutcome {
    let world = app.world_mut();
    let mut out = DriveOutcome {
        dt_min: f64::INFINITY,
        ..Default::default()
    };
    let mut wall = 0.0;
    let t0 = Instant::now();
    if !world.resource::<SimulationClock>().started {
        start(world);
    }
    wall += t0.elapsed().as_secs_f64();
    if let Some(f) = world.resource::<SimulationStatus>().failure.clone() {
        out.failure = Some(f);
        out.dt_min = 0.0;
        out.wall_seconds = wall;
        return out;
    }
    on_sample(world, 0.0);
    let end_time = match rule {
        StepRule::Exact { dt, steps } => dt * steps as f64,
        _ => end_time,
    };
    let sample_dt = end_time / samples.max(1) as f64;
    let mut next_sample = sample_dt;
    let mut next_progress = 0.01 * end_time;
    let mut t = 0.0f64;
    loop {
        let dt = match rule {
            StepRule::Exact { dt, steps } => {
                if out.steps >= steps {
                    break;
                }
                dt
            }
            StepRule::Fixed(dt) => {
                if t >= end_time * (1.0 - 1e-12) {
                    break;
                }
                dt
            }
            StepRule::Monitor => {
                let remaining = end_time - t;
                if remaining <= 1e-12 * end_time {
                    break;
                }
                let next = world.resource::<SimulationClock>().next_dt;
                if !(next > 0.0 && next.is_finite()) {
                    out.failure = Some(FailureReport::global(
                        "time step",
                        next,
                        "the next time step is not a positive finite number",
                    ));
                    break;
                }
                // As the frame driver: no sliver step at the end.
                crate::step::driver::step_towards(next, remaining)
            }
        };
        if out.steps >= max_steps {
            out.budget_exhausted = true;
            break;
        }
        let ts = Instant::now();
        run_step(world, dt, false);
        wall += ts.elapsed().as_secs_f64();
        if let Some(f) = world.resource::<SimulationStatus>().failure.clone() {
            out.failure = Some(f);
            break;
        }
        out.steps += 1;
        t = match rule {
            StepRule::Exact { dt, .. } => out.steps as f64 * dt,
            _ => t + dt,
        };
        out.dt_min = out.dt_min.min(dt);
        out.dt_max = out.dt_max.max(dt);
        {
            let mut c = world.resource_mut::<SimulationClock>();
            c.time = t;
            c.steps += 1;
        }
        if t >= next_sample - 1e-12 * end_time && t < end_time - 1e-12 * end_time {
            on_sample(world, t);
            while next_sample <= t + 1e-12 * end_time {
                next_sample += sample_dt;
            }
        }
        if t >= next_progress {
            on_progress((t / end_time).min(1.0));
            next_progress = t + 0.01 * end_time;
        }
    }
    out.time = t;
    if out.failure.is_none() && !out.budget_exhausted {
        on_sample(world, t);
    }
    if out.steps == 0 {
        out.dt_min = 0.0;
    }
    out.wall_seconds = wall;
    out
}
