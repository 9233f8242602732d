//! How many particles keep up with a 60 Hz game (feature `game`): for each [`GameLiquid`]
//! preset and a ladder of particle counts, a column of the liquid collapses in a tank at
//! [`GAME_DX`] (a dam break: the first second of a game liquid's typical motion), run through
//! [`GamePlugin`] without a budget, one update per 1/60 s of game time; prints the median wall
//! time of an update over the second (or `--seconds S`), whether it fits in 16.7 ms, and the
//! largest compression (99th percentile of ρ/ρ₀ over the run: what the sound speed costs in
//! accuracy). A numerical failure stops the example with its report.
//!
//! `cargo run --release --features game --example game_keepup -- [--threads N] [--dx M]
//! [--sound-speed C] [--safety S] [--scheme NAME] [--projection] [--gather] [--versus-gather]
//! [--only N] [--at-least] [--seconds S] [preset ...]`
//! (`--dx`, `--sound-speed`, `--safety`, `--scheme` replace the presets' choice, to map the
//! trade-off; `--projection` runs [`GameLiquid::config_projected`] (the liquid's own safety:
//! 1 for every preset), whose particles keep ρ₀, so its
//! ρ99/ρ₀ column reads 1 and the "CG it" column gives the pressure solve's mean iterations;
//! `--gather` gathers the velocity gradient every step instead of carrying it from G2P, the
//! setting of `game_config_projected`; `--versus-gather` runs the gathered variant beside each
//! run, one update of each in turn, and prints the median of the paired time ratios; `--only N`
//! runs one count instead of the ladder; `--at-least` narrows each column across the flow
//! by whole cells to the fewest particles not below the count, e.g. 20,384 for 20,000, where
//! the square columns jump from 18,928 to 21,952).
use std::time::{Duration, Instant};

use bevy_app::App;
use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};
use treacle::app::headless_app_with;
use treacle::game::bevy_time::{TimePlugin, TimeUpdateStrategy};
use treacle::game::bevy_transform::components::Transform;
use treacle::game::{GAME_DX, GameLiquid, GamePlugin, LiquidBody, SpawnedLiquid, game_config};
use treacle::prelude::*;

/// Particle counts tried (about: the column is rounded to whole cells; 10,000–40,000 give
/// 9,680, 13,824, 16,224, 18,928, 21,952, 25,200, 28,800, 32,768 and 41,616 particles).
const LADDER: [u32; 14] = [
    1_250, 2_500, 5_000, 10_000, 12_500, 17_500, 19_000, 20_000, 25_000, 28_000, 32_000, 40_000,
    80_000, 160_000,
];

/// The grid spacing and sound speed of a run.
#[derive(Clone, Copy)]
struct Setting {
    dx: f32,
    sound_speed: Option<f32>,
    safety: Option<f64>,
    scheme: Option<Scheme>,
    projection: bool,
    /// Gather Lₚ every step instead of carrying it from G2P (the projected runs).
    gather: bool,
    /// Narrow the column across the flow by whole cells to the fewest particles ≥ the count
    /// asked for (the ladder's columns are square, so their counts jump by 15 %).
    at_least: bool,
}

/// One run of a dam break through the game plugin.
struct Run {
    app: App,
    body: bevy_ecs::entity::Entity,
    liquid: GameLiquid,
    rest_density: f32,
    times: Vec<Duration>,
    steps: Vec<u64>,
    compression: f32,
    densities: Vec<f32>,
}

/// What a run measured: the median update time, the median sub-steps, the particle count, the
/// largest compression seen (the 99th percentile of ρₚ/ρ₀ after each update, its maximum over
/// the run) and the mean CG iterations of the pressure solve.
struct Outcome {
    time: Duration,
    steps: u64,
    particles: usize,
    compression: f32,
    cg: f64,
    /// The update times in order (for paired comparisons).
    times: Vec<Duration>,
}

impl Run {
    fn new(liquid: GameLiquid, particles: u32, setting: Setting) -> Run {
        // A column w × 2d × w (w = 2d) against a wall of a tank 2w × 3d × w: N = 8d³/h³.
        let dx = setting.dx;
        let h = 0.5 * dx as f64;
        let d = (particles as f64 * h.powi(3) / 8.0).cbrt();
        let snap = |x: f64| ((x / dx as f64).round().max(2.0) * dx as f64) as f32;
        let (w, dd) = (snap(2.0 * d), snap(d));
        // The depth (z, across the flow): w, or with `at_least` the fewest whole cells whose
        // column holds at least `particles` (two particles per cell and axis).
        let per_cell_layer = (w / dx * 2.0).round() * (2.0 * dd / dx * 2.0).round() * 2.0;
        let depth = if setting.at_least {
            let cells = (particles as f32 / per_cell_layer).ceil().max(1.0);
            (cells * dx).min(w)
        } else {
            w
        };
        let tank = (Vec3::ZERO, Vec3::new(2.0 * w, 3.0 * dd, depth));
        let mut config = MpmConfig {
            dx,
            walls: DomainWalls::all(BoundaryCondition::Slip),
            ..if setting.projection {
                liquid.config_projected(tank.0, tank.1)
            } else {
                game_config(tank.0, tank.1)
            }
        };
        if let Some(s) = setting.safety {
            config.time_step.safety = s;
        }
        if let Some(s) = setting.scheme {
            config.integrator.scheme = s;
        }
        if setting.gather {
            config.integrator.velocity_gradient = VelocityGradientSource::Gather;
        }
        let mut id = None;
        let mut app: App = headless_app_with(config, Materials::default(), |app| {
            app.add_plugins((TimePlugin, GamePlugin::default()));
            app.insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
                1.0 / 60.0,
            )));
            let material = liquid.add_to(app);
            if let Some(c) = setting.sound_speed {
                app.world_mut().resource_mut::<Materials>().list[material.0 as usize].sound_speed =
                    c;
            }
            id = Some(material);
        });
        let body = app
            .world_mut()
            .spawn((
                LiquidBody::new(
                    ColliderShape::Box {
                        half_extents: Vec3::new(0.5 * w, dd, 0.5 * depth),
                    },
                    id.unwrap(),
                ),
                Transform::from_xyz(0.5 * w, dd, 0.5 * depth),
            ))
            .id();
        let rest_density = app.world().resource::<Materials>().list[id.unwrap().0 as usize].density;
        Run {
            app,
            body,
            liquid,
            rest_density,
            times: Vec::new(),
            steps: Vec::new(),
            compression: 1.0,
            densities: Vec::new(),
        }
    }

    /// One update of 1/60 s, timed; then (outside the timing) the compression and the health.
    fn frame(&mut self) {
        let t = Instant::now();
        self.app.update();
        self.times.push(t.elapsed());
        self.steps
            .push(self.app.world().resource::<SimulationClock>().frame_steps);
        self.densities.clear();
        let world = self.app.world_mut();
        let rest = self.rest_density;
        self.densities.extend(
            world
                .query::<&Density>()
                .iter(world)
                .map(|d| d.value / rest),
        );
        if !self.densities.is_empty() {
            let k = (self.densities.len() * 99) / 100;
            let (_, p99, _) = self.densities.select_nth_unstable_by(k, f32::total_cmp);
            self.compression = self.compression.max(*p99);
        }
        if let Some(f) = &self.app.world().resource::<SimulationStatus>().failure {
            panic!("{:?}: {f}", self.liquid);
        }
    }

    fn finish(self) -> Outcome {
        // The first update only fills the body (virtual time starts with a zero step).
        let ordered = self.times[1..].to_vec();
        let (mut times, mut steps) = (ordered.clone(), self.steps[1..].to_vec());
        times.sort();
        steps.sort();
        let particles = self
            .app
            .world()
            .get::<SpawnedLiquid>(self.body)
            .unwrap()
            .particles;
        let cg = self
            .app
            .world()
            .get_resource::<treacle::implicit::PressureSolveStats>()
            .map_or(0.0, |s| s.0.mean_iterations());
        Outcome {
            time: times[times.len() / 2],
            steps: steps[steps.len() / 2],
            particles,
            compression: self.compression,
            cg,
            times: ordered,
        }
    }
}

/// Runs the settings side by side, one update of each in turn: the first update (which only
/// fills the body), then `60 × seconds` updates of 1/60 s.
fn run(liquid: GameLiquid, particles: u32, settings: &[Setting], seconds: f32) -> Vec<Outcome> {
    let mut runs: Vec<Run> = settings
        .iter()
        .map(|s| Run::new(liquid, particles, *s))
        .collect();
    for _ in 0..=(60.0 * seconds).round().max(1.0) as usize {
        for r in &mut runs {
            r.frame();
        }
    }
    runs.into_iter().map(Run::finish).collect()
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut threads = 2;
    if let Some(i) = args.iter().position(|a| a == "--threads") {
        threads = args[i + 1].parse().expect("--threads N");
        args.drain(i..=i + 1);
    }
    let scheme = args.iter().position(|a| a == "--scheme").map(|i| {
        let name = args.remove(i + 1);
        args.remove(i);
        Scheme::ALL
            .into_iter()
            .find(|s| s.cli_name() == name)
            .expect("--scheme gs4|symplectic-euler|backward-euler|gs4-implicit")
    });
    let projection = args
        .iter()
        .position(|a| a == "--projection")
        .map(|i| args.remove(i))
        .is_some();
    let mut flag = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .map(|i| args.remove(i))
            .is_some()
    };
    let gather = flag("--gather");
    let versus_gather = flag("--versus-gather");
    let at_least = flag("--at-least");
    let only = args.iter().position(|a| a == "--only").map(|i| {
        let n: u32 = args[i + 1].parse().expect("--only N");
        args.drain(i..=i + 1);
        n
    });
    let mut take = |flag: &str| {
        let i = args.iter().position(|a| a == flag)?;
        let value = args[i + 1].parse::<f32>().expect("a number");
        args.drain(i..=i + 1);
        Some(value)
    };
    let setting = Setting {
        dx: take("--dx").unwrap_or(GAME_DX),
        sound_speed: take("--sound-speed"),
        safety: take("--safety").map(f64::from),
        scheme,
        projection,
        gather,
        at_least,
    };
    let seconds = take("--seconds").unwrap_or(1.0);
    ComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(threads).build());
    let liquids: Vec<GameLiquid> = if args.is_empty() {
        GameLiquid::ALL.to_vec()
    } else {
        GameLiquid::ALL
            .into_iter()
            .filter(|l| args.iter().any(|a| a == l.name()))
            .collect()
    };
    let budget = Duration::from_secs_f64(1.0 / 60.0);
    println!(
        "threads {threads}, dx {} m, sound speed {}; median over {seconds} s of updates of 1/60 s",
        setting.dx,
        setting
            .sound_speed
            .map_or("of the preset".to_string(), |c| format!("{c} m/s"))
    );
    println!(
        "{:>8} {:>9} {:>10} {:>9} {:>6} {:>9} {:>6}",
        "liquid", "particles", "ms/update", "sub-steps", "60 Hz", "ρ99/ρ₀", "CG it"
    );
    for liquid in liquids {
        for n in only.map_or(LADDER.to_vec(), |n| vec![n]) {
            let mut settings = vec![setting];
            if versus_gather {
                settings.push(Setting {
                    gather: true,
                    ..setting
                });
            }
            let outcomes = run(liquid, n, &settings, seconds);
            let o = &outcomes[0];
            let ok = o.time <= budget;
            println!(
                "{:>8} {:>9} {:>10.2} {:>9} {:>6} {:>9.3} {:>6.1}",
                liquid.name(),
                o.particles,
                o.time.as_secs_f64() * 1e3,
                o.steps,
                if ok { "yes" } else { "no" },
                o.compression,
                o.cg
            );
            if let Some(g) = outcomes.get(1) {
                // Paired: update k of one run against update k of the other, run in turn.
                let mut ratios: Vec<f64> = o
                    .times
                    .iter()
                    .zip(&g.times)
                    .map(|(a, b)| a.as_secs_f64() / b.as_secs_f64())
                    .collect();
                ratios.sort_by(f64::total_cmp);
                println!(
                    "{:>8} {:>9} {:>10.2} {:>9} {:>6} {:>9.3} {:>6.1}   (gathered L; median of \
                     the paired ratios carried/gathered {:.3})",
                    "",
                    g.particles,
                    g.time.as_secs_f64() * 1e3,
                    g.steps,
                    if g.time <= budget { "yes" } else { "no" },
                    g.compression,
                    g.cg,
                    ratios[ratios.len() / 2]
                );
            }
            if !ok {
                break;
            }
        }
    }
}
