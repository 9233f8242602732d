//! The `treacle` command-line tool: run, validate and benchmark RON scenes headless.
use std::path::PathBuf;
use std::process::ExitCode;

use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};
use clap::{Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use treacle::config::Scheme;
use treacle::implicit::ImplicitSolveStats;
use treacle::output::OutputFormat;
use treacle::runner::{RunError, RunOptions, bench_scene, default_out_dir, run_scene};
use treacle::scene::load_scene;
use treacle::step::schedule::{StepProgress, StopRequest};

#[derive(Parser)]
#[command(
    name = "treacle",
    version,
    about = "Viscous and viscoelastic liquids with the GS4 Material Point Method"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// `println!` that ends the process quietly when stdout is closed (`treacle validate X | head`)
/// instead of panicking on the broken pipe.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout().lock(), $($arg)*) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
            eprintln!("error: cannot write to stdout: {e}");
            std::process::exit(1);
        }
    }};
}

#[derive(Clone, Copy, ValueEnum)]
enum Format {
    /// Binary little-endian PLY (positions, velocities, scalar fields).
    Ply,
    /// Legacy VTK polydata (binary); every field survives VTK/ParaView readers.
    Vtk,
}

impl From<Format> for OutputFormat {
    fn from(f: Format) -> Self {
        match f {
            Format::Ply => OutputFormat::Ply,
            Format::Vtk => OutputFormat::Vtk,
        }
    }
}

/// Format of surface meshes.
#[derive(Clone, Copy, ValueEnum)]
enum MeshFormat {
    /// Wavefront OBJ (text: positions, normals, triangles).
    Obj,
    /// Binary little-endian PLY (positions, normals, triangles).
    Ply,
}

/// The message for a surface option in a build without the `surface` feature.
#[cfg(not(feature = "surface"))]
const NO_SURFACE: &str = "surface meshes need the `surface` cargo feature; this treacle was \
     built without it (build with `cargo build --release --features surface`)";

#[derive(Subcommand)]
enum Command {
    /// Run a scene and write one particle file per output frame plus metrics.csv.
    Run {
        /// The scene file (RON).
        scene: PathBuf,
        /// Output directory [default: out/<scene name>].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Number of frames [default: duration × frame_rate of the scene].
        #[arg(long)]
        frames: Option<u64>,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
        /// File format [default: the scene's output.format].
        #[arg(long, value_enum)]
        format: Option<Format>,
        /// Time integrator, overriding the scene's `integrator.scheme`: gs4,
        /// symplectic-euler, backward-euler or gs4-implicit.
        #[arg(long)]
        integrator: Option<Scheme>,
        /// Replace the frames and metrics.csv of an earlier run in the output folder (they
        /// are removed first); without it such a folder is refused.
        #[arg(long)]
        force: bool,
        /// Memory the run may use, e.g. 512M, 8G (bytes without a suffix) [default: the
        /// memory the machine has available].
        #[arg(long, value_parser = parse_bytes)]
        max_memory: Option<u64>,
        /// Under mpirun: rank 0 gathers every frame and writes it as one file
        /// (frame_NNNNN.ply), instead of each rank writing its part (ranks/) and rank 0 an
        /// index (frame_NNNNN.parts) that `treacle snapshot`, `render` and `surface` open as
        /// the frame. Ignored in one process.
        #[arg(long)]
        gather: bool,
        /// Also write the liquid's surface mesh per frame, surface_NNNNN.obj beside
        /// frame_NNNNN.ply (needs the `surface` feature).
        #[arg(long)]
        surface: bool,
        /// File format of the surface meshes.
        #[arg(long, value_enum, default_value = "obj", requires = "surface")]
        surface_format: MeshFormat,
    },
    /// Reconstruct the liquid surface of every frame of an earlier run (surface_NNNNN.obj
    /// beside frame_NNNNN.ply; needs the `surface` feature).
    Surface {
        /// The run's output folder (holding frame_*.ply, frame_*.vtk or frame_*.parts).
        run_dir: PathBuf,
        /// File format of the meshes.
        #[arg(long, value_enum, default_value = "obj")]
        format: MeshFormat,
        /// Particle spacing h [m] [default: the median nearest-neighbour distance in the
        /// first frame].
        #[arg(long)]
        spacing: Option<f32>,
        /// Kernel scale in spacings.
        #[arg(long, default_value_t = 1.0)]
        smoothing: f32,
        /// Grid cell in spacings.
        #[arg(long, default_value_t = 0.75)]
        cell: f32,
        /// Iso value of the particle volume fraction, in (0, 1).
        #[arg(long, default_value_t = 0.5)]
        iso: f32,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Check a scene file without running it.
    Validate {
        /// The scene file (RON).
        scene: PathBuf,
    },
    /// Time a number of steps of a scene.
    Bench {
        /// The scene file (RON).
        scene: PathBuf,
        /// Steps to time (after the start-up evaluation).
        #[arg(long, default_value_t = 100)]
        steps: u64,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
        /// Time integrator, overriding the scene's `integrator.scheme`: gs4,
        /// symplectic-euler, backward-euler or gs4-implicit.
        #[arg(long)]
        integrator: Option<Scheme>,
    },
    /// Draw one particle frame written by `run` (PLY, VTK, or the index of a run on ranks) as a
    /// PNG picture.
    #[cfg(feature = "plot")]
    Snapshot {
        /// The frame file, e.g. out/droplet/frame_00010.ply (frame_00010.parts after a run on
        /// MPI ranks).
        frame: PathBuf,
        /// The PNG file to write (its directory is created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Field to colour by: speed (= |velocity|), vx, vy, vz, x, y, z, or a field stored in
        /// the file (density, pressure, material, ...).
        #[arg(long, visible_alias = "colour", default_value = "speed")]
        color: String,
        /// Projection: z (side view, looking along -z), x (side view along +x), y (top view)
        /// or iso.
        #[arg(long, default_value = "z")]
        view: String,
        /// Image size in pixels, WIDTHxHEIGHT.
        #[arg(long, default_value = "1024x768")]
        size: String,
    },
    /// Chart the steady simple-shear viscosity η(γ̇) of a scene's materials, from the laws as
    /// implemented (log-log PNG, and the values at each decade on stdout).
    #[cfg(feature = "plot")]
    Viscosity {
        /// The scene file (RON).
        scene: PathBuf,
        /// The PNG file to write (its directory is created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Lowest shear rate [1/s] (> 0).
        #[arg(long, default_value_t = 1e-2)]
        min_rate: f64,
        /// Highest shear rate [1/s] (> min-rate).
        #[arg(long, default_value_t = 1e3)]
        max_rate: f64,
    },
    /// Plot columns of runs' metrics.csv against time (one line per run, one panel per
    /// column), e.g. `treacle plot out/a out/b --column volume --out volume.png`.
    #[cfg(feature = "plot")]
    Plot {
        /// Run directories (their metrics.csv) or metrics CSV files.
        #[arg(required = true)]
        runs: Vec<PathBuf>,
        /// A column to plot (repeat for more panels).
        #[arg(long, short = 'c', required = true)]
        column: Vec<String>,
        /// The column on the horizontal axis.
        #[arg(long, default_value = "time")]
        x: String,
        /// Legend labels, one per run, comma-separated [default: the runs' directory names].
        #[arg(long, value_delimiter = ',')]
        labels: Option<Vec<String>>,
        /// Title of the picture [default: the columns and runs].
        #[arg(long)]
        title: Option<String>,
        /// Logarithmic vertical axis (non-positive values are left out).
        #[arg(long)]
        log_y: bool,
        /// The PNG file to write (its directory is created if missing).
        #[arg(long)]
        out: PathBuf,
    },
    /// Render a run's frames, or a scene simulated on the fly, to PNG images with the GPU
    /// renderer (headless; needs the `render` feature and a Vulkan driver).
    Render {
        /// A run directory (frame files written by `run`) or a scene file (RON), which is
        /// simulated and rendered frame by frame.
        input: PathBuf,
        /// Directory of the PNG images (frame_NNNNN.png; created if missing).
        #[arg(long)]
        out: PathBuf,
        /// For a run directory: the scene file whose colliders, bodies and nozzles are drawn
        /// with the frames.
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Field to colour by: speed, temperature, phase, material, stress (deviatoric stress
        /// norm; scenes only), density, y, or a field stored in the frame files.
        #[arg(long, visible_alias = "colour", default_value = "speed")]
        color: String,
        /// Colour range MIN:MAX [default: the values' range over the frames].
        #[arg(long)]
        range: Option<String>,
        /// Image size in pixels, WIDTHxHEIGHT.
        #[arg(long, default_value = "960x640")]
        size: String,
        /// For a scene: number of frames to simulate [default: duration × frame_rate].
        #[arg(long)]
        frames: Option<u64>,
        /// Worker threads of the simulation [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
        /// Draw the liquid surface reconstructed from the particles (PBR material) instead of
        /// the particles.
        #[arg(long)]
        surface: bool,
        /// Material of the surface: honey, chocolate, ketchup, milk, water, or `field` (the
        /// --color field on the surface, e.g. temperature) (implies --surface).
        #[arg(long, value_name = "NAME")]
        material: Option<String>,
        /// View direction, framed on the liquid and the scene's objects: iso, front, side,
        /// top, or X,Y,Z (the direction looked along) [default: the scene's `camera`, else
        /// iso].
        #[arg(long)]
        view: Option<String>,
    },
    /// Accuracy and stability reports from a SPEC file (docs/reports.md).
    #[cfg(feature = "plot")]
    Report {
        #[command(subcommand)]
        kind: ReportKind,
    },
}

/// Options shared by the report kinds.
#[cfg(feature = "plot")]
#[derive(clap::Args)]
struct ReportArgs {
    /// The SPEC file (RON).
    spec: PathBuf,
    /// Output folder; results already in it are reused (resume) [default:
    /// out/reports/<kind>-<spec name>].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Run the SPEC's quick (CI) subset.
    #[arg(long)]
    quick: bool,
    /// Worker threads [default: all cores].
    #[arg(long)]
    threads: Option<usize>,
}

#[cfg(feature = "plot")]
#[derive(Subcommand)]
enum ReportKind {
    /// Error against Δt and against wall time of each integrator on a ladder of fixed steps.
    Accuracy(ReportArgs),
    /// Stiff and extreme cases run to completion or to a detected failure.
    Stability {
        #[command(flatten)]
        args: ReportArgs,
        /// Keep each case's first and last particle files (deleted after their NaN check by
        /// default).
        #[arg(long)]
        keep_frames: bool,
    },
}

/// Prints the CG statistics of the implicit viscous solves, if there were any.
fn print_solver_stats(stats: &ImplicitSolveStats) {
    if stats.solves > 0 {
        out!(
            "viscous_solves={} cg_iterations={} cg_iterations_per_solve={:.2} cg_max_iterations={}",
            stats.solves,
            stats.iterations,
            stats.mean_iterations(),
            stats.max_iterations
        );
    }
}

fn init_threads(threads: Option<usize>) -> Result<usize, String> {
    let n = match threads {
        Some(n) if !(1..=MAX_THREADS).contains(&n) => {
            return Err(format!(
                "--threads must lie in 1..={MAX_THREADS} (got {n}); this machine has {} cores",
                std::thread::available_parallelism().map_or(1, |n| n.get())
            ));
        }
        Some(n) => n,
        None => std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1),
    };
    ComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(n).build());
    Ok(n)
}

/// Exit code of a command-line usage error (unknown option, missing argument): EX_USAGE of
/// sysexits.h, distinct from bad input (1) and numerical failure (2).
const EXIT_USAGE: u8 = 64;

/// Exit codes of a run ended by SIGINT and SIGTERM (128 + the signal number, as shells report).
const EXIT_SIGINT: u8 = 130;
const EXIT_SIGTERM: u8 = 143;

/// Most worker threads accepted by `--threads`.
const MAX_THREADS: usize = 1024;

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            let code = if e.use_stderr() { EXIT_USAGE } else { 0 };
            let _ = e.print();
            return ExitCode::from(code);
        }
    };
    // With the `mpi` feature `treacle run` splits the scene over the launcher's ranks.
    let distributed_run = cfg!(feature = "mpi") && matches!(cli.command, Command::Run { .. });
    if !distributed_run && let Some(msg) = mpi_launch(|var| std::env::var(var).ok()) {
        eprintln!("error: {msg}");
        return ExitCode::from(EXIT_USAGE);
    }
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err((code, msg)) => {
            eprintln!("error: {msg}");
            ExitCode::from(code)
        }
    }
}

/// `treacle run` on the ranks of `mpirun` (feature `mpi`): rank 0 writes the files and prints
/// the summary; every rank prints what it owned and sent.
#[cfg(feature = "mpi")]
fn run_on_ranks(
    path: &std::path::Path,
    scene: &treacle::scene::Scene,
    opts: RunOptions,
) -> Result<(), (u8, String)> {
    let comm = treacle::distributed::mpi_comm::MpiComm::init().ok_or((
        1,
        "MPI could not be initialised with serialised threading".to_owned(),
    ))?;
    let rank = treacle::distributed::Communicator::rank(&comm);
    // A signal on any rank stops every rank after the same frame.
    let stop = StopRequest::default();
    let signal = install_signal_handlers(&stop);
    let out_dir = opts.out_dir.clone();
    let opts = RunOptions {
        stop: Some(stop),
        ..opts
    };
    match treacle::runner::ranks::run_scene_on_ranks(scene, &opts, Box::new(comm), |_, _| {}) {
        Ok(sum) => {
            let steps = sum.run.steps.max(1) as f64;
            out!(
                "rank {rank}: block layers {}..{} along {}, {} particles at the end, {} migrations sent, \
                 {} rebalances, {} halo exchanges, {} halo bytes sent ({:.0} per step), {} \
                 exchanges in all; steps {:.3} s, of which waiting in communication {:.3} s; \
                 output {:.3} s",
                sum.columns.start,
                sum.columns.end,
                ["x", "y", "z"][sum.axis],
                sum.particles,
                sum.stats.migrations,
                sum.stats.rebalances,
                sum.stats.halo_exchanges,
                4 * sum.stats.halo_words,
                4.0 * sum.stats.halo_words as f64 / steps,
                sum.stats.exchanges,
                sum.step_seconds,
                sum.stats.comm_seconds,
                sum.output_seconds
            );
            if rank == 0 {
                out!(
                    "{}: {} frames, {} steps, {} files in {} ({:.2} s)",
                    path.display(),
                    sum.run.frames,
                    sum.run.steps,
                    sum.run.files.len(),
                    out_dir.display(),
                    sum.run.wall_seconds
                );
            }
            Ok(())
        }
        Err(RunError::Failed(f)) => Err((
            2,
            format!(
                "{} (rank {rank}): {f}\n(the files in {} stop at the last healthy frame)",
                path.display(),
                out_dir.display()
            ),
        )),
        Err(e @ RunError::Interrupted { .. }) => Err((
            signal.exit_code(),
            format!("{} (rank {rank}): {e}", path.display()),
        )),
        Err(e) => Err((1, format!("rank {rank}: {e}"))),
    }
}

/// The number of processes of the MPI launch that started this one, if one did.
#[cfg(feature = "mpi")]
fn mpi_world_size(env: impl Fn(&str) -> Option<String>) -> Option<u64> {
    MPI_SIZE_VARS
        .iter()
        .find_map(|var| env(var)?.trim().parse().ok())
}

/// The world-size variables MPI launchers set in each process they start: Open MPI's
/// `mpirun`, MPICH's and Intel MPI's Hydra (and Slurm's `srun` with PMI), MVAPICH.
const MPI_SIZE_VARS: [&str; 3] = ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "MV2_COMM_WORLD_SIZE"];

/// Why this process must not run, if an MPI launcher started it as one of several (`env` reads
/// an environment variable). This build runs a scene in one process; under `mpirun -n N` each
/// of the N copies would run the whole scene and write the same files.
fn mpi_launch(env: impl Fn(&str) -> Option<String>) -> Option<String> {
    MPI_SIZE_VARS.iter().find_map(|var| {
        let size: u64 = env(var)?.trim().parse().ok()?;
        (size > 1).then(|| {
            if cfg!(feature = "mpi") {
                format!(
                    "treacle was started as one of {size} processes by an MPI launcher \
                     ({var}={size}); only `treacle run` splits a scene over processes. Run \
                     other commands as one process."
                )
            } else {
                format!(
                    "treacle was started as one of {size} processes by an MPI launcher \
                     ({var}={size}), but this build has no `mpi` feature: each process would \
                     run the whole scene and write the same files. Build with `cargo build \
                     --release --features mpi` (needs an MPI library and libclang) to split a \
                     scene over ranks, or run it as one process (`treacle run SCENE --threads \
                     N` uses the cores of one machine)."
                )
            }
        })
    })
}

/// `512M`, `8G`, `1.5GiB`, `1000000`: a byte count with an optional binary-prefix suffix.
fn parse_bytes(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| format!("`{text}` is not a size such as 512M or 8G"))?;
    let scale = match unit.trim().to_ascii_uppercase().as_str() {
        "" | "B" => 1u64,
        "K" | "KB" | "KIB" => 1 << 10,
        "M" | "MB" | "MIB" => 1 << 20,
        "G" | "GB" | "GIB" => 1 << 30,
        "T" | "TB" | "TIB" => 1 << 40,
        other => return Err(format!("unknown size unit `{other}` (use K, M, G or T)")),
    };
    let bytes = value * scale as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!("`{text}` is not a positive size"));
    }
    Ok(bytes as u64)
}

/// Which signal asked the run to stop (0: none yet).
struct SignalSeen(std::sync::Arc<std::sync::atomic::AtomicUsize>);

impl SignalSeen {
    /// The exit code for a run the signal stopped.
    fn exit_code(&self) -> u8 {
        match self.0.load(std::sync::atomic::Ordering::SeqCst) {
            15 => EXIT_SIGTERM,
            _ => EXIT_SIGINT,
        }
    }
}

/// SIGINT and SIGTERM set `stop` (the run ends after the current step, with its files complete);
/// a second SIGINT while stopping exits at once with 130.
fn install_signal_handlers(stop: &StopRequest) -> SignalSeen {
    let seen = SignalSeen(Default::default());
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGINT, SIGTERM};
        use signal_hook::flag;
        let flag = stop.flag();
        // Registration fails only for forbidden signals; these two are allowed.
        let _ = flag::register_conditional_shutdown(SIGINT, EXIT_SIGINT as i32, flag.clone());
        for sig in [SIGINT, SIGTERM] {
            let _ = flag::register(sig, flag.clone());
            let _ = flag::register_usize(sig, seen.0.clone(), sig as usize);
        }
    }
    #[cfg(not(unix))]
    let _ = stop;
    seen
}

/// Progress display of `treacle run` on stderr: an indicatif bar on a terminal, plain lines
/// every few seconds otherwise (logs, CI). A line appears as soon as the run starts.
struct Progress {
    bar: Option<ProgressBar>,
}

/// Keeps the thread that copies the step counters into the display; stops it when dropped.
struct Ticker {
    done: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Drop for Ticker {
    fn drop(&mut self) {
        self.done.store(true, std::sync::atomic::Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Progress {
    fn start(scene: &std::path::Path) -> Self {
        use std::io::IsTerminal;
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = ProgressBar::new(1);
            bar.set_style(
                ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] {bar:30} {msg} (eta {eta})",
                )
                .expect("valid template"),
            );
            bar.enable_steady_tick(std::time::Duration::from_millis(200));
            bar
        });
        let p = Self { bar };
        p.println(format!("{}: loading", scene.display()));
        p
    }

    fn println(&self, line: String) {
        match &self.bar {
            Some(bar) => bar.println(line),
            None => eprintln!("{line}"),
        }
    }

    /// Shows `counters` (steps, simulated time) against `frames` frames of `frame_dt` until the
    /// returned ticker is dropped.
    fn follow(&self, counters: StepProgress, frames: u64, frame_dt: f64) -> Ticker {
        let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let end = frames as f64 * frame_dt;
        let bar = self.bar.clone();
        let stop = done.clone();
        let thread = std::thread::spawn(move || {
            const PER_MILLE: u64 = 1000;
            if let Some(bar) = &bar {
                bar.set_length(PER_MILLE);
            }
            let t0 = std::time::Instant::now();
            let mut last_line = t0;
            let mut first = true;
            while !stop.load(std::sync::atomic::Ordering::SeqCst) {
                let (steps, time) = (counters.steps(), counters.time());
                let elapsed = t0.elapsed().as_secs_f64().max(1e-9);
                let fraction = if end > 0.0 {
                    (time / end).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let msg = format!(
                    "t = {time:.4e} / {end:.4e} s, step {steps}, {:.0} steps/s",
                    steps as f64 / elapsed
                );
                match &bar {
                    Some(bar) => {
                        bar.set_position((fraction * PER_MILLE as f64) as u64);
                        bar.set_message(msg);
                    }
                    None if first || last_line.elapsed().as_secs_f64() >= 10.0 => {
                        let eta = if fraction > 0.0 {
                            format!("{:.0} s", elapsed * (1.0 - fraction) / fraction)
                        } else {
                            "unknown".into()
                        };
                        eprintln!("running: {msg}, {:.1} %, eta {eta}", 100.0 * fraction);
                        last_line = std::time::Instant::now();
                        first = false;
                    }
                    None => {}
                }
                std::thread::sleep(std::time::Duration::from_millis(200));
            }
        });
        Ticker {
            done,
            thread: Some(thread),
        }
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// Loads a scene; prints its load-time warnings to stderr.
fn load(path: &std::path::Path) -> Result<treacle::scene::Scene, (u8, String)> {
    let s = load_scene(path).map_err(|e| (1, e.to_string()))?;
    for w in &s.warnings {
        eprintln!("warning: {w}");
    }
    Ok(s)
}

fn run(cli: Cli) -> Result<(), (u8, String)> {
    match cli.command {
        Command::Validate { scene } => {
            let s = load(&scene)?;
            let c = &s.config;
            out!(
                "{}: ok — {} particles in {} bodies, {} colliders, {} materials, Δx = {} m, {} frames at {} fps",
                scene.display(),
                s.particle_count(),
                s.particles.len(),
                s.colliders.len(),
                s.materials.list.len(),
                c.dx,
                s.frames(),
                s.frame_rate
            );
            let estimate = s.resource_estimate();
            out!("  {estimate}");
            if estimate.wall_seconds() > 3600.0 {
                eprintln!(
                    "warning: the estimated run time exceeds an hour ({:.3e} steps of {:.3e} s); \
                     a smaller sound speed, viscosity or particle count shortens it",
                    estimate.steps, estimate.first_dt
                );
            }
            if let Some(avail) = treacle::runner::available_memory()
                && estimate.bytes() > avail
            {
                eprintln!(
                    "warning: {} (`treacle run` refuses it)",
                    estimate.too_large(avail, "the available memory")
                );
            }
            // Sampled volume N·h³ against the exact shape (or mesh) volume, per body.
            for (i, b) in s.particles.iter().enumerate() {
                out!(
                    "  bodies[{i}]: {} particles, sampled volume {:.6e} m³ vs shape volume \
                     {:.6e} m³ ({:+.3} %)",
                    b.positions.len(),
                    b.sampled_volume(),
                    b.shape_volume,
                    100.0 * (b.sampled_volume() / b.shape_volume - 1.0)
                );
            }
            Ok(())
        }
        Command::Run {
            scene,
            out,
            frames,
            threads,
            format,
            integrator,
            force,
            max_memory,
            gather,
            surface,
            surface_format,
        } => {
            #[cfg(not(feature = "surface"))]
            if surface {
                let _ = surface_format;
                return Err((1, NO_SURFACE.to_owned()));
            }
            init_threads(threads).map_err(|e| (EXIT_USAGE, e))?;
            let progress = Progress::start(&scene);
            let mut s = load(&scene)?;
            if let Some(scheme) = integrator {
                s.config.integrator.scheme = scheme;
            }
            let out_dir = out.unwrap_or_else(|| default_out_dir(&scene));
            // One process writes whole frames.
            #[cfg(not(feature = "mpi"))]
            let _ = gather;
            // Under an MPI launcher (`mpirun -n 1` included), the distributed runner.
            #[cfg(feature = "mpi")]
            if mpi_world_size(|var| std::env::var(var).ok()).is_some() {
                drop(progress);
                let opts = RunOptions {
                    frames,
                    format: format.map(OutputFormat::from),
                    max_memory,
                    replace: force,
                    gather_frames: gather,
                    ..RunOptions::new(out_dir)
                };
                return run_on_ranks(&scene, &s, opts);
            }
            progress.println(format!("{}", s.resource_estimate()));
            let total = frames.unwrap_or_else(|| s.frames());
            let stop = StopRequest::default();
            let signal = install_signal_handlers(&stop);
            let counters = StepProgress::default();
            let opts = RunOptions {
                frames,
                format: format.map(OutputFormat::from),
                max_memory,
                replace: force,
                progress: Some(counters.clone()),
                stop: Some(stop),
                #[cfg(feature = "surface")]
                surface: surface.then(|| treacle::runner::SurfaceOutput {
                    format: mesh_format(surface_format),
                    params: None,
                }),
                ..RunOptions::new(out_dir.clone())
            };
            let ticker = progress.follow(counters, total, s.config.frame_dt);
            let result = run_scene(s, &opts, |_, _| {});
            drop(ticker);
            progress.finish();
            match result {
                Ok(sum) => {
                    out!(
                        "{}: {} frames, {} steps, {} files in {} ({:.2} s)",
                        scene.display(),
                        sum.frames,
                        sum.steps,
                        sum.files.len(),
                        out_dir.display(),
                        sum.wall_seconds
                    );
                    print_solver_stats(&sum.viscous_solves);
                    Ok(())
                }
                Err(RunError::Failed(f)) => Err((
                    2,
                    format!(
                        "{}: {f}\n(the files in {} stop at the last healthy frame)",
                        scene.display(),
                        out_dir.display()
                    ),
                )),
                Err(e @ RunError::Interrupted { .. }) => {
                    Err((signal.exit_code(), format!("{}: {e}", scene.display())))
                }
                Err(e) => Err((1, e.to_string())),
            }
        }
        Command::Bench {
            scene,
            steps,
            threads,
            integrator,
        } => {
            let n = init_threads(threads).map_err(|e| (EXIT_USAGE, e))?;
            let mut s = load(&scene)?;
            if let Some(scheme) = integrator {
                s.config.integrator.scheme = scheme;
            }
            let r = bench_scene(s, steps).map_err(|e| match e {
                RunError::Failed(_) => (2, e.to_string()),
                other => (1, other.to_string()),
            })?;
            out!("scene={} threads={n}", scene.display());
            out!(
                "particles={} steps={} seconds={:.4} particle_steps_per_s={:.0}",
                r.particles,
                r.steps,
                r.seconds,
                r.particle_steps_per_second()
            );
            print_solver_stats(&r.viscous_solves);
            Ok(())
        }
        #[cfg(feature = "plot")]
        Command::Snapshot {
            frame,
            out,
            color,
            view,
            size,
        } => snapshot(&frame, &out, color, &view, &size).map_err(|e| (1, e)),
        #[cfg(feature = "plot")]
        Command::Report { kind } => report(kind),
        #[cfg(feature = "plot")]
        Command::Plot {
            runs,
            column,
            x,
            labels,
            title,
            log_y,
            out,
        } => metrics_chart(&runs, &column, &x, labels, title, log_y, &out),
        #[cfg(feature = "plot")]
        Command::Viscosity {
            scene,
            out,
            min_rate,
            max_rate,
        } => {
            if !(min_rate > 0.0 && max_rate > min_rate && max_rate.is_finite()) {
                return Err((
                    EXIT_USAGE,
                    format!(
                        "--min-rate {min_rate}, --max-rate {max_rate}: need 0 < min-rate < \
                         max-rate < ∞"
                    ),
                ));
            }
            let s = load(&scene)?;
            viscosity_chart(&s, &scene, &out, min_rate, max_rate).map_err(|e| (1, e))
        }
        #[cfg(not(feature = "surface"))]
        Command::Surface { .. } => Err((1, NO_SURFACE.to_owned())),
        #[cfg(feature = "surface")]
        Command::Surface {
            run_dir,
            format,
            spacing,
            smoothing,
            cell,
            iso,
            threads,
        } => {
            init_threads(threads).map_err(|e| (EXIT_USAGE, e))?;
            let params = treacle::surface::SurfaceParams {
                spacing: spacing.unwrap_or(f32::NAN),
                smoothing,
                cell,
                iso,
                ..Default::default()
            };
            surface_run_dir(&run_dir, mesh_format(format), params).map_err(|e| (1, e))
        }
        Command::Render {
            input,
            out,
            scene,
            color,
            range,
            size,
            frames,
            threads,
            surface,
            material,
            view,
        } => {
            init_threads(threads).map_err(|e| (EXIT_USAGE, e))?;
            render(RenderArgs {
                input,
                out,
                scene,
                color,
                range,
                size,
                frames,
                surface: surface || material.is_some(),
                material,
                view,
            })
        }
    }
}

#[cfg(feature = "surface")]
fn mesh_format(f: MeshFormat) -> treacle::surface::SurfaceFormat {
    match f {
        MeshFormat::Obj => treacle::surface::SurfaceFormat::Obj,
        MeshFormat::Ply => treacle::surface::SurfaceFormat::Ply,
    }
}

/// `treacle surface RUN_DIR`: a mesh per frame file, with a progress bar. A NaN spacing in
/// `params` means "estimate it from the first frame".
#[cfg(feature = "surface")]
fn surface_run_dir(
    dir: &std::path::Path,
    format: treacle::surface::SurfaceFormat,
    mut params: treacle::surface::SurfaceParams,
) -> Result<(), String> {
    use treacle::output::read_frame;
    use treacle::runner::write_surface;
    let frames = treacle::output::frame_files(dir).map_err(|e| e.to_string())?;
    if frames.is_empty() {
        return Err(format!(
            "{} holds no frame_*.ply, frame_*.vtk or frame_*.parts files (the output folder of \
             `treacle run`)",
            dir.display()
        ));
    }
    let t0 = std::time::Instant::now();
    let bar = ProgressBar::new(frames.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}")
            .expect("valid template"),
    );
    for path in &frames {
        bar.set_message(
            path.file_name()
                .map_or(String::new(), |n| n.to_string_lossy().into_owned()),
        );
        let frame = read_frame(path).map_err(|e| e.to_string())?;
        if params.spacing.is_nan() {
            let positions: Vec<treacle::math::Vec3> = frame
                .positions
                .iter()
                .map(|p| treacle::math::Vec3::from_array(*p))
                .collect();
            if let Some(h) = treacle::surface::estimate_spacing(&positions) {
                params.spacing = h;
                bar.println(format!(
                    "particle spacing {h:.6e} m (median nearest-neighbour distance in {})",
                    path.display()
                ));
            }
        }
        if params.spacing.is_nan() && !frame.is_empty() {
            return Err(format!(
                "{}: cannot estimate the particle spacing (fewer than two distinct particles); \
                 pass --spacing",
                path.display()
            ));
        }
        let out = write_surface(dir, &frame, &params, format)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        if let Ok(bytes) = std::fs::metadata(&out) {
            bar.set_message(format!("{} ({} kB)", out.display(), bytes.len() / 1024));
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    out!(
        "{}: {} surface meshes ({}) in {:.2} s, spacing {:.6e} m",
        dir.display(),
        frames.len(),
        format.extension(),
        t0.elapsed().as_secs_f64(),
        params.spacing
    );
    Ok(())
}

/// Arguments of `treacle render`.
#[cfg_attr(not(feature = "render"), allow(dead_code))]
struct RenderArgs {
    input: PathBuf,
    out: PathBuf,
    scene: Option<PathBuf>,
    color: String,
    range: Option<String>,
    size: String,
    frames: Option<u64>,
    surface: bool,
    material: Option<String>,
    view: Option<String>,
}

/// `treacle render` in a build without the renderer: a clear error.
#[cfg(not(feature = "render"))]
fn render(_: RenderArgs) -> Result<(), (u8, String)> {
    Err((
        1,
        "this treacle was built without the `render` feature; build it with \
         `cargo render-build` (cargo build --release --ignore-rust-version --features \
         game,render) and a Vulkan driver (apt-get install mesa-vulkan-drivers)"
            .into(),
    ))
}

/// `MIN:MAX` → a fixed colour range.
#[cfg(feature = "render")]
fn parse_range(text: &str) -> Result<treacle::render::ColourRange, String> {
    let (a, b) = text
        .split_once(':')
        .ok_or_else(|| format!("--range `{text}`: expected MIN:MAX, e.g. 0:2.5"))?;
    let parse = |s: &str| -> Result<f32, String> {
        s.trim()
            .parse::<f32>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("--range `{text}`: `{s}` is not a finite number"))
    };
    let (min, max) = (parse(a)?, parse(b)?);
    if max <= min {
        return Err(format!("--range `{text}`: MAX must exceed MIN"));
    }
    Ok(treacle::render::ColourRange::Fixed { min, max })
}

/// `treacle render`: bad input → 1, a failing simulation → 2.
#[cfg(feature = "render")]
fn render(args: RenderArgs) -> Result<(), (u8, String)> {
    use std::io::IsTerminal;
    use treacle::render::headless::{
        RenderError, RenderJob, RenderOptions, render_run_dir, render_scene,
    };
    use treacle::render::surface::{SurfaceLook, SurfacePreset};
    use treacle::render::{ColourField, ColourRange};
    let (width, height) =
        treacle::plot::parse_image_size(&args.size).map_err(|e| (1, format!("--size: {e}")))?;
    let range = match &args.range {
        Some(r) => parse_range(r).map_err(|e| (1, e))?,
        None => ColourRange::Auto,
    };
    let (surface, surface_look) = match (args.material.as_deref(), args.surface) {
        (Some("field"), _) => (Some(SurfacePreset::default()), SurfaceLook::Field),
        (Some(m), _) => (
            Some(SurfacePreset::parse(m).ok_or_else(|| {
                (
                    1,
                    format!(
                        "--material `{m}`: expected honey, chocolate, ketchup, milk, water or field"
                    ),
                )
            })?),
            SurfaceLook::Preset,
        ),
        (None, true) => (Some(SurfacePreset::default()), SurfaceLook::Preset),
        (None, false) => (None, SurfaceLook::Preset),
    };
    let job = RenderJob {
        options: RenderOptions {
            width,
            height,
            ..Default::default()
        },
        field: ColourField::parse(&args.color),
        range,
        frames: args.frames,
        surface,
        surface_look,
        camera: match args.view.as_deref() {
            Some(v) => Some(
                treacle::render::camera::parse_view(v).map_err(|e| (1, format!("--view: {e}")))?,
            ),
            None => None,
        },
    };
    let bar = std::io::stderr().is_terminal().then(|| {
        let bar = ProgressBar::new(1);
        bar.set_style(
            ProgressStyle::with_template(
                "[{elapsed_precise}] {bar:30} {pos}/{len} frames (eta {eta})",
            )
            .expect("valid template"),
        );
        bar
    });
    let started = std::time::Instant::now();
    let mut last_line = started;
    let mut progress = |done: usize, total: usize| match &bar {
        Some(bar) => {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
        None => {
            if done == total || last_line.elapsed().as_secs_f64() >= 10.0 {
                eprintln!("rendered {done}/{total} frames");
                last_line = std::time::Instant::now();
            }
        }
    };
    let map_err = |e: RenderError| match e {
        RenderError::Simulation(_) => (2, e.to_string()),
        other => (1, other.to_string()),
    };
    let written = if args.input.is_dir() {
        let scene = match &args.scene {
            Some(p) => Some(load(p)?),
            None => None,
        };
        render_run_dir(&args.input, scene.as_ref(), &args.out, &job, &mut progress)
            .map_err(map_err)?
    } else {
        if args.scene.is_some() {
            return Err((
                1,
                "--scene is for a run directory; the input is already a scene file".into(),
            ));
        }
        let scene = load(&args.input)?;
        render_scene(&scene, &args.out, &job, &mut progress).map_err(map_err)?
    };
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    out!(
        "{}: {} images ({}x{}, {}) in {} ({:.1} s)",
        args.input.display(),
        written.len(),
        width,
        height,
        job.field.frame_name(),
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `treacle report accuracy|stability`: bad SPEC or scene → exit code 1 (a case that fails
/// numerically is a result of the report, not an error).
#[cfg(feature = "plot")]
fn report(kind: ReportKind) -> Result<(), (u8, String)> {
    use treacle::report::{ReportOptions, default_out_dir, run_accuracy, run_stability};
    let (name, args, keep_frames) = match kind {
        ReportKind::Accuracy(a) => ("accuracy", a, false),
        ReportKind::Stability { args, keep_frames } => ("stability", args, keep_frames),
    };
    init_threads(args.threads).map_err(|e| (EXIT_USAGE, e))?;
    let out_dir = args
        .out
        .clone()
        .unwrap_or_else(|| default_out_dir(name, &args.spec, args.quick));
    let opts = ReportOptions {
        out_dir: out_dir.clone(),
        quick: args.quick,
        progress: true,
        keep_frames,
    };
    let (runs, simulated, resumed, files) = if name == "accuracy" {
        let r = run_accuracy(&args.spec, &opts).map_err(|e| (1, e.to_string()))?;
        (r.runs.len(), r.simulated, r.resumed, r.files)
    } else {
        let r = run_stability(&args.spec, &opts).map_err(|e| (1, e.to_string()))?;
        (r.cases.len(), r.simulated, r.resumed, r.files)
    };
    out!(
        "{}: {name} report with {runs} runs ({simulated} simulated, {resumed} reused) in {}",
        args.spec.display(),
        out_dir.display()
    );
    for f in files {
        out!("  {}", f.display());
    }
    Ok(())
}

/// `treacle plot`: reads the runs' metrics and draws the chart.
#[cfg(feature = "plot")]
fn metrics_chart(
    runs: &[PathBuf],
    columns: &[String],
    x: &str,
    labels: Option<Vec<String>>,
    title: Option<String>,
    log_y: bool,
    out: &std::path::Path,
) -> Result<(), (u8, String)> {
    use treacle::report::metrics_chart::{draw_metrics_chart, read_runs};
    let mut tables = read_runs(runs).map_err(|e| (1, e.to_string()))?;
    if let Some(labels) = labels {
        if labels.len() != tables.len() {
            return Err((
                EXIT_USAGE,
                format!(
                    "--labels has {} entries for {} runs",
                    labels.len(),
                    tables.len()
                ),
            ));
        }
        for (t, l) in tables.iter_mut().zip(labels) {
            t.label = l;
        }
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| (1, format!("{}: {e}", dir.display())))?;
    }
    let title = title.unwrap_or_else(|| format!("{} against {x}", columns.join(", ")));
    draw_metrics_chart(out, &title, &tables, x, columns, log_y).map_err(|e| (1, e.to_string()))?;
    println!("wrote {}", out.display());
    Ok(())
}

/// `treacle viscosity`: charts η(γ̇) of the scene's materials and prints the decade values.
#[cfg(feature = "plot")]
fn viscosity_chart(
    scene: &treacle::scene::Scene,
    path: &std::path::Path,
    out: &std::path::Path,
    min_rate: f64,
    max_rate: f64,
) -> Result<(), String> {
    use treacle::report::viscosity::{draw_viscosity_chart, viscosity_curves};
    let decades = (max_rate / min_rate).log10();
    let n = (10.0 * decades).ceil().max(2.0) as usize + 1;
    let curves = viscosity_curves(scene, min_rate, max_rate, n);
    if curves.curves.is_empty() {
        return Err(format!(
            "{}: no material has a steady shear viscosity to chart (skipped: {})",
            path.display(),
            curves
                .skipped
                .iter()
                .map(|(m, model)| format!("{m} ({model})"))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    let title = format!("viscosity against shear rate: {}", path.display());
    draw_viscosity_chart(out, &title, &curves).map_err(|e| format!("{}: {e}", out.display()))?;
    // The values at whole decades (every 10th point).
    let header: Vec<String> = curves.curves[0]
        .points
        .iter()
        .step_by(10)
        .map(|(r, _)| format!("{r:.0e}"))
        .collect();
    out!("material, η [Pa·s] at γ̇ [1/s] = {}", header.join(", "));
    for c in &curves.curves {
        let v: Vec<String> = c
            .points
            .iter()
            .step_by(10)
            .map(|(_, e)| format!("{e:.4e}"))
            .collect();
        out!("{}, {}", c.material, v.join(", "));
    }
    for (m, model) in &curves.skipped {
        out!("{m}: skipped ({model}: the stress has a history, no single curve)");
    }
    out!("wrote {}", out.display());
    Ok(())
}

/// `treacle snapshot`: every failure is bad input (exit code 1).
#[cfg(feature = "plot")]
fn snapshot(
    frame: &std::path::Path,
    out: &std::path::Path,
    field: String,
    view: &str,
    size: &str,
) -> Result<(), String> {
    use treacle::snapshot::{SnapshotOptions, snapshot_file};
    let view = view.parse().map_err(|e| format!("--view: {e}"))?;
    let (width, height) =
        treacle::plot::parse_image_size(size).map_err(|e| format!("--size: {e}"))?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create directory {}: {e}", dir.display()))?;
    }
    let opts = SnapshotOptions {
        field,
        view,
        width,
        height,
    };
    let snap = snapshot_file(frame, out, &opts).map_err(|e| e.to_string())?;
    out!(
        "{}: {}x{} px, {} from {} to {}, view {}",
        out.display(),
        width,
        height,
        opts.field,
        treacle::plot::format_number(snap.scale.min),
        treacle::plot::format_number(snap.scale.max),
        opts.view
    );
    Ok(())
}
