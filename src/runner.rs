//! Running a loaded scene headless: frames, output files, metrics, failures.
//!
//! The CLI (`treacle run`, `treacle bench`) is a thin layer over [`run_scene`] and
//! [`bench_scene`]; both are ordinary library functions so examples and tests can use them.
use std::path::{Path, PathBuf};
use std::time::Instant;

use bevy_app::App;
use bevy_ecs::prelude::*;

use crate::app::headless_app_with;
use crate::components::{Density, Mass, Particle, Position, Velocity};
use crate::diagnostics::{MetricsColumns, measure};
use crate::failure::{FailureReport, SimulationStatus};
use crate::material::{MaterialId, Materials};
use crate::output::{
    MetricsRow, MetricsWriter, OutputError, OutputFormat, ParticleFrame, write_frame,
};
use crate::scene::{OutputField, Scene};
use crate::step::driver::{run_step, start};
use crate::step::schedule::SimulationClock;

/// Why a run stopped early.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The simulation detected a numerical failure (state at the failure is not written).
    #[error("{0}")]
    Failed(Box<FailureReport>),
    /// An output file could not be written.
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// Options of [`run_scene`].
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Output directory (created if missing).
    pub out_dir: PathBuf,
    /// Number of frames to run (default: the scene's duration × frame rate).
    pub frames: Option<u64>,
    /// File format override (default: the scene's).
    pub format: Option<OutputFormat>,
}

/// What a finished run did.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    /// Frames simulated.
    pub frames: u64,
    /// Steps taken.
    pub steps: u64,
    /// Particle files written.
    pub files: Vec<PathBuf>,
    /// Wall time \[s\].
    pub wall_seconds: f64,
    /// CG statistics of the implicit viscous solves (all zero for explicit schemes).
    pub viscous_solves: crate::step::implicit::ImplicitSolveStats,
}

/// Builds the app of a scene: the MPM plugins, the scene's resources, bodies and colliders.
pub fn scene_app(scene: &Scene) -> App {
    let mut app = headless_app_with(scene.config.clone(), scene.materials.clone(), |app| {
        scene.add_plugins(app)
    });
    scene.apply(app.world_mut());
    app
}

/// The current particle state as an output frame with the requested fields.
pub fn snapshot(world: &mut World, frame: u32, fields: &[OutputField]) -> ParticleFrame {
    let time = world.resource::<SimulationClock>().time;
    let materials = world.resource::<Materials>().clone();
    let mut q = world.query_filtered::<(
        &Position,
        &Velocity,
        &Mass,
        &Density,
        &MaterialId,
        Option<&crate::thermal::Temperature>,
        Option<&crate::thermal::PhaseIndex>,
    ), With<Particle>>();
    let n = q.iter(world).len();
    let mut out = ParticleFrame::new(frame, time);
    out.positions.reserve(n);
    out.velocities.reserve(n);
    let mut cols: Vec<Vec<f32>> = fields.iter().map(|_| Vec::with_capacity(n)).collect();
    for (x, v, m, rho, mat, temp, phase) in q.iter(world) {
        out.positions.push(x.0.to_array());
        out.velocities.push(v.0.to_array());
        for (f, col) in fields.iter().zip(&mut cols) {
            col.push(match f {
                OutputField::Density => rho.value,
                OutputField::Pressure => materials.get(*mat).pressure(rho.value),
                OutputField::Mass => m.0,
                OutputField::Material => mat.0 as f32,
                OutputField::Speed => v.0.length(),
                OutputField::Temperature => temp.map_or(0.0, |t| t.value),
                OutputField::Phase => phase.map_or(0.0, |p| p.0),
            });
        }
    }
    for (f, col) in fields.iter().zip(cols) {
        out.push_field(f.name(), col);
    }
    out
}

fn metrics_row(world: &mut World, frame: u32, wall: f64) -> MetricsRow {
    let m = measure(world);
    let c = world.resource::<SimulationClock>();
    MetricsRow {
        frame,
        time: c.time,
        steps: c.steps,
        dt_min: c.frame_dt_min,
        dt_max: c.frame_dt_max,
        particles: m.particles,
        mass: m.mass,
        volume: m.volume,
        kinetic_energy: m.kinetic_energy,
        max_speed: m.max_speed,
        wall_seconds: wall,
        extra: Vec::new(),
    }
}

/// Runs a scene, writing particle files and `metrics.csv` into `opts.out_dir`.
///
/// Frame 0 (the initial state) is written first. `on_frame(frame, total)` is called after
/// every simulated frame (for progress bars). A numerical failure stops the run with
/// [`RunError::Failed`]; files already written are complete and finite.
pub fn run_scene(
    scene: &Scene,
    opts: &RunOptions,
    mut on_frame: impl FnMut(u64, u64),
) -> Result<RunSummary, RunError> {
    let wall0 = Instant::now();
    let mut app = scene_app(scene);
    let total = opts.frames.unwrap_or_else(|| scene.frames());
    let format = opts.format.unwrap_or(match scene.output.format {
        crate::scene::OutputFormatSpec::Ply => OutputFormat::Ply,
        crate::scene::OutputFormatSpec::Vtk => OutputFormat::Vtk,
    });
    let every = scene.output.every.max(1) as u64;
    // Plugins add theirs (rigid bodies: `rigid{i}_*`; heat: `t_min, t_max, t_mean,
    // melted_fraction`).
    let columns = MetricsColumns::columns(app.world_mut());
    let names: Vec<&str> = columns.iter().map(String::as_str).collect();
    let mut metrics = MetricsWriter::new(&opts.out_dir).with_extra_columns(&names)?;
    let row = |app: &mut App, frame: u32, wall: f64| {
        let mut row = metrics_row(app.world_mut(), frame, wall);
        row.extra = MetricsColumns::values(app.world_mut());
        row
    };
    let mut summary = RunSummary::default();
    let write = |app: &mut App, frame: u64, summary: &mut RunSummary| -> Result<(), RunError> {
        let snap = snapshot(app.world_mut(), frame as u32, &scene.output.fields);
        summary
            .files
            .push(write_frame(&opts.out_dir, &snap, format)?);
        Ok(())
    };
    write(&mut app, 0, &mut summary)?;
    metrics.push(row(&mut app, 0, 0.0))?;
    for frame in 1..=total {
        app.update();
        if let Some(f) = app.world().resource::<SimulationStatus>().failure.clone() {
            summary.wall_seconds = wall0.elapsed().as_secs_f64();
            return Err(RunError::Failed(Box::new(f)));
        }
        let wall = wall0.elapsed().as_secs_f64();
        if frame % every == 0 || frame == total {
            write(&mut app, frame, &mut summary)?;
        }
        metrics.push(row(&mut app, frame as u32, wall))?;
        on_frame(frame, total);
        summary.frames = frame;
    }
    summary.steps = app.world().resource::<SimulationClock>().steps;
    summary.wall_seconds = wall0.elapsed().as_secs_f64();
    summary.viscous_solves = solve_stats(app.world());
    Ok(summary)
}

/// The implicit-solve statistics of a world (zero if it has none).
fn solve_stats(world: &World) -> crate::step::implicit::ImplicitSolveStats {
    world
        .get_resource::<crate::step::implicit::ImplicitSolveStats>()
        .copied()
        .unwrap_or_default()
}

/// Result of [`bench_scene`].
#[derive(Clone, Copy, Debug)]
pub struct BenchResult {
    /// Particles.
    pub particles: u64,
    /// Steps timed.
    pub steps: u64,
    /// Wall time of the timed steps \[s\].
    pub seconds: f64,
    /// CG statistics of the implicit viscous solves of the timed steps (zero for explicit
    /// schemes).
    pub viscous_solves: crate::step::implicit::ImplicitSolveStats,
}

impl BenchResult {
    /// Particle-steps per second.
    pub fn particle_steps_per_second(&self) -> f64 {
        self.particles as f64 * self.steps as f64 / self.seconds
    }
}

/// Times `steps` adaptive steps of a scene (after the start-up evaluation, not timed).
pub fn bench_scene(scene: &Scene, steps: u64) -> Result<BenchResult, RunError> {
    let mut app = scene_app(scene);
    let world = app.world_mut();
    start(world);
    let particles = world
        .query_filtered::<(), With<Particle>>()
        .iter(world)
        .len() as u64;
    let stats0 = solve_stats(world);
    let t0 = Instant::now();
    for _ in 0..steps {
        let dt = world.resource::<SimulationClock>().next_dt;
        run_step(world, dt, false);
        if let Some(f) = world.resource::<SimulationStatus>().failure.clone() {
            return Err(RunError::Failed(Box::new(f)));
        }
        let mut c = world.resource_mut::<SimulationClock>();
        c.time += dt;
        c.steps += 1;
    }
    let seconds = t0.elapsed().as_secs_f64();
    let stats1 = solve_stats(world);
    Ok(BenchResult {
        particles,
        steps,
        seconds,
        viscous_solves: crate::step::implicit::ImplicitSolveStats {
            solves: stats1.solves - stats0.solves,
            iterations: stats1.iterations - stats0.iterations,
            ..stats1
        },
    })
}

/// Default output directory for a scene: `out/<scene file stem>`.
pub fn default_out_dir(scene_path: &Path) -> PathBuf {
    let stem = scene_path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into());
    PathBuf::from("out").join(stem)
}
