//! Criterion benchmarks of whole steps of `scenes/bench_block.ron` (65 536 particles, 64³
//! cells) through the App, with 2 compute threads (`TREACLE_BENCH_THREADS` overrides), and of
//! each system of the step alone.
//!
//! - `step::whole`: `run_step(world, dt, false)` with the adaptive Δt of the previous step
//!   (`SimulationClock::next_dt`), after the start-up evaluation, exactly like
//!   `treacle bench`. The block keeps evolving from iteration to iteration (a few hundred steps,
//!   ≈ 0.1 s of simulated time, in one run).
//! - `step::stage::<system>`: one system of the `MpmStep` schedule run repeatedly (as a
//!   registered system) on a fresh app advanced by a few steps. The systems are listed here in
//!   schedule order (mirroring `step::driver::add_core_systems`); the sum of the stages should
//!   match `step::whole` — if it does not, the schedule has gained systems this list lacks.
//!   Repeating a system on the same input costs what it costs inside a step (G2P and the
//!   commit move particles a little further each time, which does not change their cost).
//!
//! Throughput is reported in particles/s, i.e. particle-steps/s for `step::whole`.
//! Run: `cargo bench --bench step` (filter: `cargo bench --bench step -- whole`).
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use bevy_app::App;
use bevy_ecs::prelude::*;
use bevy_ecs::system::SystemId;
use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use treacle::components::Particle;
use treacle::failure::SimulationStatus;
use treacle::runner::scene_app;
use treacle::scene::{Scene, load_scene};
use treacle::schedule::{SimulationClock, run_step, start};
use treacle::step::predict::gather_colliders;
use treacle::step::{
    commit, constitutive, g2p, grid_forces, grid_update, kinematics, monitor, p2g, predict,
};

/// Compute threads: 2 (the target machine; the default pool would get one on this 2-core
/// box), or `TREACLE_BENCH_THREADS` (e.g. 1 for the single-thread reference).
fn threads() -> usize {
    std::env::var("TREACLE_BENCH_THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|n| *n >= 1)
        .unwrap_or(2)
}

/// Steps taken before a stage is timed (so grid, stress and rates hold a running state).
const WARM_STEPS: usize = 3;

/// Benchmark id `step::<name>` (named after the module path, STYLE §7 item 12).
macro_rules! name {
    ($s:expr) => {
        format!("{}::{}", module_path!(), $s)
    };
}

fn bench_scene() -> Scene {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/bench_block.ron");
    load_scene(&path).expect("scenes/bench_block.ron loads")
}

/// One adaptive step, as `runner::bench_scene` takes it.
fn step(world: &mut World) {
    let dt = world.resource::<SimulationClock>().next_dt;
    run_step(world, dt, false);
    if let Some(f) = &world.resource::<SimulationStatus>().failure {
        panic!("the bench block failed: {f}");
    }
    let mut c = world.resource_mut::<SimulationClock>();
    c.time += dt;
    c.steps += 1;
}

/// The scene's app after the start-up evaluation and `steps` steps.
fn started_app(scene: &Scene, steps: usize) -> App {
    let mut app = scene_app(scene);
    let world = app.world_mut();
    start(world);
    assert!(
        !world.resource::<SimulationStatus>().failed(),
        "start-up failed"
    );
    for _ in 0..steps {
        step(world);
    }
    app
}

/// Registers the systems of `MpmStep` in schedule order.
fn register_stages(world: &mut World) -> Vec<(&'static str, SystemId)> {
    vec![
        (
            "predict_positions",
            world.register_system(predict::predict_positions),
        ),
        ("gather_colliders", world.register_system(gather_colliders)),
        (
            "particle_to_grid",
            world.register_system(p2g::particle_to_grid),
        ),
        (
            "velocity_gradients",
            world.register_system(kinematics::velocity_gradients),
        ),
        (
            "velocity_and_deformation_gradients",
            world.register_system(kinematics::velocity_and_deformation_gradients),
        ),
        (
            "newtonian_stress",
            world.register_system(constitutive::newtonian_stress),
        ),
        (
            "grid_forces",
            world.register_system(grid_forces::grid_forces),
        ),
        (
            "grid_update",
            world.register_system(grid_update::grid_update),
        ),
        (
            "update_deformation_gradients",
            world.register_system(g2p::update_deformation_gradients),
        ),
        (
            "grid_to_particle",
            world.register_system(g2p::grid_to_particle),
        ),
        (
            "commit_density",
            world.register_system(commit::commit_density),
        ),
        (
            "particle_collisions",
            world.register_system(commit::particle_collisions),
        ),
        (
            "move_colliders",
            world.register_system(commit::move_colliders),
        ),
        (
            "remove_escaped",
            world.register_system(commit::remove_escaped),
        ),
        ("monitor_step", world.register_system(monitor::monitor_step)),
    ]
}

fn bench_step(c: &mut Criterion) {
    let threads = threads();
    let pool = ComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(threads).build());
    assert_eq!(
        pool.thread_num(),
        threads,
        "compute pool initialised elsewhere"
    );
    eprintln!("compute threads: {threads}");
    let scene = bench_scene();

    let mut app = started_app(&scene, 0);
    let world = app.world_mut();
    let particles = world
        .query_filtered::<(), With<Particle>>()
        .iter(world)
        .len() as u64;
    assert_eq!(
        particles, 65_536,
        "bench_block.ron must hold 65 536 particles"
    );

    let mut group = c.benchmark_group("step");
    group.throughput(Throughput::Elements(particles));
    group.bench_function(name!("whole"), |b| b.iter(|| step(world)));
    let clock = world.resource::<SimulationClock>();
    eprintln!(
        "step::whole: {} steps timed, t = {:.4} s, last Δt = {:.3e} s",
        clock.steps, clock.time, clock.next_dt
    );
    let stages = register_stages(world).len();
    drop(app);

    for i in 0..stages {
        // A fresh app per stage, so a repeated stage never sees another stage's leftovers.
        let mut app = started_app(&scene, WARM_STEPS);
        let world = app.world_mut();
        let (stage, id) = register_stages(world)[i];
        group.bench_function(name!(format!("stage::{stage}")), |b| {
            b.iter(|| black_box(world.run_system(id)).expect("system runs"))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = bench_step
}
criterion_main!(benches);
