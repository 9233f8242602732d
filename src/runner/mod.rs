//! Running a loaded scene headless: frames, output files, metrics, failures.
//!
//! The CLI (`treacle run`, `treacle bench`) is a thin layer over [`run_scene`] and
//! [`bench_scene`]; both are ordinary library functions so examples and tests can use them.
pub mod ranks;

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
use crate::step::schedule::{SimulationClock, StepProgress, StopRequest};

/// Why a run stopped early.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The simulation detected a numerical failure (state at the failure is not written).
    #[error("{0}")]
    Failed(Box<FailureReport>),
    /// An output file could not be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The scene needs more memory than the run may use ([`RunOptions::max_memory`]).
    #[error("{0}")]
    TooLarge(String),
    /// A run on several ranks could not start (the scene is not supported distributed, the
    /// ranks cannot split its grid, or another rank's set-up failed).
    #[error("{0}")]
    Distributed(String),
    /// The output folder holds files of another run ([`RunOptions::replace`] is off).
    #[error(
        "{dir} already holds {count} file(s) of another run ({first}, …); pass --force to \
         replace them or choose another output folder",
        dir = .dir.display()
    )]
    ExistingOutput {
        /// The folder.
        dir: PathBuf,
        /// Frame files and metrics.csv found.
        count: usize,
        /// The first of them.
        first: String,
    },
    /// A surface mesh could not be reconstructed or written ([`RunOptions::surface`]).
    #[cfg(feature = "surface")]
    #[error("surface of frame {frame}: {source}")]
    Surface {
        /// The output frame.
        frame: u64,
        /// What went wrong.
        #[source]
        source: crate::surface::SurfaceError,
    },
    /// A [`StopRequest`] ended the run after `frames` complete frames; the files written so
    /// far are complete and metrics.csv lists exactly those frames.
    #[error(
        "interrupted at t = {time:.6e} s after {steps} steps; frames 0..={frames} and \
         metrics.csv in {dir} are complete",
        dir = .dir.display()
    )]
    Interrupted {
        /// Complete frames simulated.
        frames: u64,
        /// Simulated time reached \[s\].
        time: f64,
        /// Steps taken.
        steps: u64,
        /// The output folder.
        dir: PathBuf,
    },
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
    /// Memory the run may use \[B\]; a scene whose [`ResourceEstimate`](crate::scene::ResourceEstimate) exceeds it is refused
    /// before anything is allocated. Default: the memory the machine has available
    /// ([`available_memory`]; no check where that is unknown).
    pub max_memory: Option<u64>,
    /// Replace the frames and metrics.csv of an earlier run in `out_dir` (they are removed
    /// first) instead of refusing to mix them with this run's. Default false.
    pub replace: bool,
    /// Counters updated after every step, for a progress display on another thread.
    pub progress: Option<StepProgress>,
    /// A flag that stops the run after the current step (e.g. set by a SIGINT handler).
    pub stop: Option<StopRequest>,
    /// On several ranks ([`ranks::run_scene_on_ranks`]): rank 0 gathers every frame and writes
    /// it as one file, instead of each rank writing its part and rank 0 an index
    /// ([`crate::output::parts`]). Ignored in one process. Default false.
    pub gather_frames: bool,
    /// Also write a surface mesh per output frame, `surface_NNNNN.obj|ply` beside
    /// `frame_NNNNN.*` (feature `surface`). Default `None`.
    #[cfg(feature = "surface")]
    pub surface: Option<SurfaceOutput>,
}

/// Surface meshes written by [`run_scene`] beside each particle frame.
#[cfg(feature = "surface")]
#[derive(Clone, Debug, Default)]
pub struct SurfaceOutput {
    /// File format.
    pub format: crate::surface::SurfaceFormat,
    /// Reconstruction parameters; `None`: the defaults with the scene's particle spacing and
    /// domain ([`surface_params`]).
    pub params: Option<crate::surface::SurfaceParams>,
}

/// The surface parameters of a scene: the defaults with its particle spacing (the first
/// body's h = (particle volume)^⅓, which is Δx / `particles_per_cell`; Δx/2, the default
/// seeding, for a scene without bodies) and its domain as the clipping box, whose faces with
/// a wall (sticky, slip or friction; not open or periodic) have a wall layer of Δx
/// ([`crate::surface::SurfaceDomain`]).
#[cfg(feature = "surface")]
pub fn surface_params(scene: &Scene) -> crate::surface::SurfaceParams {
    use crate::config::BoundaryCondition;
    let c = &scene.config;
    let spacing = scene
        .particles
        .first()
        .map_or(c.dx / 2.0, |b| (b.particle_volume as f64).cbrt() as f32);
    let walls = std::array::from_fn(|face| {
        !matches!(
            c.walls.face(face / 2, face % 2 == 1),
            BoundaryCondition::Open | BoundaryCondition::Periodic
        )
    });
    crate::surface::SurfaceParams {
        domain: Some(
            crate::surface::SurfaceDomain::new(c.domain_min, c.domain_max).with_walls(walls, c.dx),
        ),
        ..crate::surface::SurfaceParams::for_spacing(spacing)
    }
}

/// Reconstructs the surface of `frame` and writes it to `dir` (an empty mesh for a frame
/// without particles). Returns the path written.
#[cfg(feature = "surface")]
pub fn write_surface(
    dir: &Path,
    frame: &ParticleFrame,
    params: &crate::surface::SurfaceParams,
    format: crate::surface::SurfaceFormat,
) -> Result<PathBuf, crate::surface::SurfaceError> {
    let positions: Vec<crate::math::Vec3> = frame
        .positions
        .iter()
        .map(|p| crate::math::Vec3::from_array(*p))
        .collect();
    let mesh = if positions.is_empty() {
        crate::surface::SurfaceMesh::default()
    } else {
        crate::surface::reconstruct_surface(&positions, params)?
    };
    let path = dir.join(format.file_name(frame.frame));
    mesh.write(&path, format)?;
    Ok(path)
}

impl RunOptions {
    /// Defaults: the scene's frames and format, memory checked against what is available, no
    /// replacing, no progress counters, no stop flag.
    pub fn new(out_dir: impl Into<PathBuf>) -> Self {
        Self {
            out_dir: out_dir.into(),
            frames: None,
            format: None,
            max_memory: None,
            replace: false,
            progress: None,
            stop: None,
            gather_frames: false,
            #[cfg(feature = "surface")]
            surface: None,
        }
    }
}

/// The memory this process can still allocate \[B\], on Linux: the smaller of `MemAvailable`
/// (/proc/meminfo) and what the cgroup's `memory.max` leaves; `None` where neither is known.
pub fn available_memory() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| {
            text.lines()
                .find_map(|l| l.strip_prefix("MemAvailable:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
                .map(|kb| kb * 1024)
        });
    let read = |f: &str| {
        std::fs::read_to_string(Path::new("/sys/fs/cgroup").join(f))
            .ok()
            .and_then(|v| v.trim().parse::<u64>().ok())
    };
    let cgroup =
        read("memory.max").map(|max| max.saturating_sub(read("memory.current").unwrap_or(0)));
    match (meminfo, cgroup) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// Refuses a scene whose [`crate::scene::ResourceEstimate`] exceeds `max_memory` or, when that
/// is `None`, the [`available_memory`] (no check where that is unknown).
pub fn check_memory(scene: &Scene, max_memory: Option<u64>) -> Result<(), RunError> {
    let estimate = scene.resource_estimate();
    if let Some((limit, what)) = max_memory
        .map(|m| (m, "the given limit"))
        .or_else(|| available_memory().map(|m| (m, "the available memory")))
        && estimate.bytes() > limit
    {
        return Err(RunError::TooLarge(format!(
            "{}: {}",
            scene.source.display(),
            estimate.too_large(limit, what)
        )));
    }
    Ok(())
}

/// Whether `name` is a file a run writes into its folder: a frame, a surface mesh or
/// metrics.csv.
fn is_run_file(name: &str) -> bool {
    name == crate::output::METRICS_FILE
        || crate::output::frame_number(name).is_some()
        || (name.starts_with(SURFACE_PREFIX) && (name.ends_with(".obj") || name.ends_with(".ply")))
}

/// File-name prefix of surface meshes (`crate::surface::SURFACE_PREFIX`, also known without
/// the feature so that `--force` removes them).
const SURFACE_PREFIX: &str = "surface_";

/// Creates `dir`, removes temporary files that a killed run left behind, and refuses (or, with
/// `replace`, removes) the frames and metrics.csv of an earlier run, the part files of a
/// distributed run's frames (in `dir/ranks`, [`crate::output::parts`]) included.
pub fn prepare_output_dir(dir: &Path, replace: bool) -> Result<(), RunError> {
    let io = |source: std::io::Error| {
        RunError::Output(OutputError::Io {
            action: "prepare the output folder",
            path: dir.to_path_buf(),
            source,
        })
    };
    std::fs::create_dir_all(dir).map_err(io)?;
    let mut existing = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        let name = entry.file_name().to_string_lossy().into_owned();
        // Temporary files of interrupted atomic writes of frames or metrics.csv.
        if crate::output::is_temp_name(&name, "frame_")
            || crate::output::is_temp_name(&name, SURFACE_PREFIX)
            || crate::output::is_temp_name(&name, crate::output::METRICS_FILE)
        {
            std::fs::remove_file(entry.path()).map_err(io)?;
        } else if is_run_file(&name) {
            existing.push(name);
        }
    }
    let parts = dir.join(crate::output::PARTS_DIR);
    if parts.is_dir() {
        for entry in std::fs::read_dir(&parts).map_err(io)? {
            let name = entry
                .map_err(io)?
                .file_name()
                .to_string_lossy()
                .into_owned();
            if crate::output::is_temp_name(&name, "frame_") {
                std::fs::remove_file(parts.join(&name)).map_err(io)?;
            } else if crate::output::part_number(&name).is_some() {
                existing.push(format!("{}/{name}", crate::output::PARTS_DIR));
            }
        }
    }
    existing.sort();
    if existing.is_empty() {
        return Ok(());
    }
    if !replace {
        return Err(RunError::ExistingOutput {
            dir: dir.to_path_buf(),
            count: existing.len(),
            first: existing[0].clone(),
        });
    }
    for name in existing {
        std::fs::remove_file(dir.join(name)).map_err(io)?;
    }
    // The parts' folder, if that left it empty (a run that writes parts creates it again).
    let _ = std::fs::remove_dir(&parts);
    Ok(())
}

/// What a finished run did.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    /// Frames simulated.
    pub frames: u64,
    /// Steps taken.
    pub steps: u64,
    /// Files written: particle frames and, with [`RunOptions`]`::surface`, surface meshes.
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
    metrics_row_of(&m, world.resource::<SimulationClock>(), frame, wall)
}

/// The core columns of a `metrics.csv` row from measured state `m` and the clock `c`.
pub(crate) fn metrics_row_of(
    m: &crate::diagnostics::StateMetrics,
    c: &SimulationClock,
    frame: u32,
    wall: f64,
) -> MetricsRow {
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
/// Before anything is allocated, the scene's [`crate::scene::ResourceEstimate`] is checked
/// against [`RunOptions::max_memory`] and the folder is prepared ([`prepare_output_dir`]).
/// Frame 0 (the initial state) is written first. `on_frame(frame, total)` is called after
/// every simulated frame (for progress bars). A numerical failure stops the run with
/// [`RunError::Failed`]; files already written are complete and finite.
///
/// The scene is taken by value: its bodies' sampled positions are freed once the particles
/// are spawned ([`Scene::forget_sampled_positions`]), 12 B or more per particle for the rest
/// of the run.
pub fn run_scene(
    mut scene: Scene,
    opts: &RunOptions,
    mut on_frame: impl FnMut(u64, u64),
) -> Result<RunSummary, RunError> {
    let wall0 = Instant::now();
    check_memory(&scene, opts.max_memory)?;
    prepare_output_dir(&opts.out_dir, opts.replace)?;
    let mut app = scene_app(&scene);
    scene.forget_sampled_positions();
    let scene = &scene;
    if let Some(p) = &opts.progress {
        app.insert_resource(p.clone());
    }
    if let Some(s) = &opts.stop {
        app.insert_resource(s.clone());
    }
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
    #[cfg(feature = "surface")]
    let surface = opts.surface.as_ref().map(|s| {
        (
            s.params.clone().unwrap_or_else(|| surface_params(scene)),
            s.format,
        )
    });
    let write = |app: &mut App, frame: u64, summary: &mut RunSummary| -> Result<(), RunError> {
        let snap = snapshot(app.world_mut(), frame as u32, &scene.output.fields);
        summary
            .files
            .push(write_frame(&opts.out_dir, &snap, format)?);
        #[cfg(feature = "surface")]
        if let Some((params, format)) = &surface {
            let path = write_surface(&opts.out_dir, &snap, params, *format)
                .map_err(|source| RunError::Surface { frame, source })?;
            summary.files.push(path);
        }
        Ok(())
    };
    write(&mut app, 0, &mut summary)?;
    metrics.push(row(&mut app, 0, 0.0))?;
    for frame in 1..=total {
        let stop_requested = opts.stop.as_ref().is_some_and(StopRequest::requested);
        if !stop_requested {
            app.update();
        }
        if let Some(f) = app.world().resource::<SimulationStatus>().failure.clone() {
            summary.wall_seconds = wall0.elapsed().as_secs_f64();
            return Err(RunError::Failed(Box::new(f)));
        }
        let clock = app.world().resource::<SimulationClock>();
        if stop_requested || clock.interrupted {
            return Err(RunError::Interrupted {
                frames: frame - 1,
                time: clock.time,
                steps: clock.steps,
                dir: opts.out_dir.clone(),
            });
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

/// Times `steps` adaptive steps of a scene (after the start-up evaluation, not timed). A scene
/// beyond the available memory is refused ([`check_memory`]). The scene is taken by value, as
/// in [`run_scene`], so that its sampled positions are freed before the steps.
pub fn bench_scene(scene: Scene, steps: u64) -> Result<BenchResult, RunError> {
    check_memory(&scene, None)?;
    let mut app = scene_app(&scene);
    drop(scene);
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
