//! A game with Avian physics (feature `avian`), headless: game code pours a pool of water by
//! `Transform`, sweeps a paddle through it by moving the paddle's `Transform`, and drops an
//! Avian box of half the water's density, which floats behind an Avian static breakwater.
//! The liquid runs in `FixedUpdate` beside Avian's
//! `FixedPostUpdate`, at 60 ticks/s within a budget of sub-steps; a game system reads the
//! liquid, the box and the lag after each frame.
//!
//! The box's shadow meets the liquid with the coupling's default for dynamic bodies, no-slip
//! (`AvianCouplingPlugin::dynamic_boundary`): with `Slip` such a box in this near-inviscid
//! water sinks steadily (the `treacle::game::avian` module docs).
//!
//! Avian does not know treacle's domain or treacle's own colliders: the tank's floor and walls
//! are Avian static colliders too, and a breakwater (an Avian static box above the bed, which
//! the liquid flows under) keeps the floating bodies away from the paddle — a treacle
//! collider does not push treacle's or Avian's bodies (only the liquid between them does);
//! make a collider that must push bodies an Avian kinematic body instead.
//!
//! `cargo avian-example game_avian` (an alias of `.cargo/config.toml`: `cargo run --release
//! --ignore-rust-version --features game,avian --example game_avian`; avian3d needs the
//! top-level `bevy` crate, whose rust-version is above this crate's).
use std::time::Duration;

use avian3d::prelude as av;
use bevy_app::{App, FixedUpdate, PluginGroup, Update};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleLabel;
use treacle::game::avian::AvianCouplingPlugin;
use treacle::game::bevy_time::{Fixed, Time, TimePlugin, TimeUpdateStrategy};
use treacle::game::bevy_transform::TransformPlugin;
use treacle::game::bevy_transform::components::Transform;
use treacle::game::{GameLiquid, GamePlugin, LiquidBody, game_config};
use treacle::plugin::{MpmCorePlugin, MpmPlugins};
use treacle::prelude::*;

/// The tank (the simulation domain) and the pool's depth \[m\].
const TANK: Vec3 = Vec3::new(0.8, 0.4, 0.4);
const DEPTH: f32 = 0.15;
/// The floating box's half extents \[m\].
const BOX_HALF: Vec3 = Vec3::new(0.1, 0.05, 0.1);

/// Marks the paddle the game moves.
#[derive(Component)]
struct Paddle;

/// Marks the floating box.
#[derive(Component)]
struct Float;

/// Game code: the paddle sweeps back and forth along z near the x = 0 end (before the
/// liquid's frame).
fn move_paddle(time: Res<Time>, mut q: Query<&mut Transform, With<Paddle>>) {
    let t = time.elapsed_secs();
    for mut tf in &mut q {
        tf.translation.z = 0.2 + 0.1 * (2.0 * t).sin();
    }
}

/// Game code: reads the liquid and the box after the frame, printing twice a second.
#[allow(clippy::type_complexity)]
fn report(
    time: Res<Time>,
    clock: Res<SimulationClock>,
    lag: Res<SimulationLag>,
    liquid: Query<&Position, With<Particle>>,
    born: Query<(), Added<Particle>>,
    float: Query<&Transform, With<Float>>,
    mut frames: Local<u32>,
) {
    *frames += 1;
    if !(*frames).is_multiple_of(30) {
        return;
    }
    let n = liquid.iter().len();
    // The liquid level away from the box: particles fill their columns evenly, so the level is
    // twice the particles' mean height (capped by the highest one).
    let box_y = float.iter().next().map(|t| t.translation);
    let level = box_y.map(|b| {
        let far: Vec<f32> = liquid
            .iter()
            .filter(|x| (x.0.x - b.x).abs() > 2.0 * BOX_HALF.x && x.0.x > 0.2)
            .map(|x| x.0.y)
            .collect();
        let top = far.iter().copied().fold(0.0f32, f32::max);
        // Particles fill their columns evenly: the mean height is half the level.
        (2.0 * far.iter().sum::<f32>() / far.len().max(1) as f32).min(top + 1e-3)
    });
    let box_y = box_y.map(|b| b.y);
    let submerged = match (level, box_y) {
        (Some(l), Some(y)) => ((l - (y - BOX_HALF.y)) / (2.0 * BOX_HALF.y)).clamp(0.0, 1.0),
        _ => f32::NAN,
    };
    println!(
        "t = {:5.2} s (liquid {:5.2} s, {:2} sub-steps last tick, lag {:.3} s): {n} particles \
         ({} new), box centre {:.3} m, submerged fraction {submerged:.2}",
        time.elapsed_secs(),
        clock.time,
        lag.last_substeps,
        lag.total,
        born.iter().count(),
        box_y.unwrap_or(f32::NAN),
    );
}

fn main() {
    let mut app = App::new();
    app.insert_resource(MpmConfig {
        walls: DomainWalls::all(BoundaryCondition::Slip),
        ..game_config(Vec3::ZERO, TANK)
    });
    app.add_plugins((TimePlugin, TransformPlugin, av::PhysicsPlugins::default()));
    // The liquid's frame driver in `FixedUpdate`, beside Avian.
    app.add_plugins(MpmPlugins.set(MpmCorePlugin {
        schedule: FixedUpdate.intern(),
    }));
    app.add_plugins((
        GamePlugin::with_max_substeps(24),
        AvianCouplingPlugin::default(),
    ));
    let water = GameLiquid::Water.add_to(&mut app);
    // Headless: each update is one 1/60 s frame of game time and one fixed tick (a game uses
    // the real clock: `DefaultPlugins` instead of `TimePlugin`).
    let tick = Duration::from_secs_f64(1.0 / 60.0);
    app.insert_resource(Time::<Fixed>::from_duration(tick))
        .insert_resource(TimeUpdateStrategy::ManualDuration(tick))
        .add_systems(FixedUpdate, move_paddle.before(DriverSystems::Pace))
        .add_systems(Update, report);

    let world = app.world_mut();
    // The pool, placed by its Transform (its centre).
    world.spawn((
        LiquidBody::new(
            ColliderShape::Box {
                half_extents: Vec3::new(0.5 * TANK.x, 0.5 * DEPTH, 0.5 * TANK.z),
            },
            water,
        ),
        Transform::from_xyz(0.5 * TANK.x, 0.5 * DEPTH, 0.5 * TANK.z),
    ));
    // The paddle: one of treacle's colliders, moved by game code through its Transform.
    world.spawn((
        Collider {
            shape: ColliderShape::Box {
                half_extents: Vec3::new(0.02, 0.12, 0.04),
            },
            boundary: BoundaryCondition::Slip,
        },
        Transform::from_xyz(0.08, 0.12, 0.2),
        Paddle,
    ));
    // An Avian box of 500 kg/m³ dropped onto the water: it floats.
    world.spawn((
        av::RigidBody::Dynamic,
        av::Collider::cuboid(2.0 * BOX_HALF.x, 2.0 * BOX_HALF.y, 2.0 * BOX_HALF.z),
        av::ColliderDensity(500.0),
        Transform::from_xyz(0.45, DEPTH + 0.08, 0.5 * TANK.z),
        Float,
    ));
    // The tank for Avian: floor and walls (treacle's domain walls hold the liquid).
    let t = 0.05;
    for (centre, size) in [
        (
            Vec3::new(0.5 * TANK.x, -0.5 * t, 0.5 * TANK.z),
            Vec3::new(TANK.x, t, TANK.z),
        ),
        (
            Vec3::new(-0.5 * t, 0.5 * TANK.y, 0.5 * TANK.z),
            Vec3::new(t, TANK.y, TANK.z),
        ),
        (
            Vec3::new(TANK.x + 0.5 * t, 0.5 * TANK.y, 0.5 * TANK.z),
            Vec3::new(t, TANK.y, TANK.z),
        ),
        (
            Vec3::new(0.5 * TANK.x, 0.5 * TANK.y, -0.5 * t),
            Vec3::new(TANK.x, TANK.y, t),
        ),
        (
            Vec3::new(0.5 * TANK.x, 0.5 * TANK.y, TANK.z + 0.5 * t),
            Vec3::new(TANK.x, TANK.y, t),
        ),
    ] {
        world.spawn((
            av::RigidBody::Static,
            av::Collider::cuboid(size.x, size.y, size.z),
            Transform::from_translation(centre),
        ));
    }
    // A breakwater between the paddle and the rest of the pool: the liquid flows under it,
    // floating bodies stay on their side.
    world.spawn((
        av::RigidBody::Static,
        av::Collider::cuboid(0.02, 0.2, TANK.z),
        Transform::from_xyz(0.2, 0.2, 0.5 * TANK.z),
    ));
    // `App::run` would do this; a loop of `update` calls must finish the plugins first.
    app.finish();
    app.cleanup();
    let mut wall = Vec::new();
    for _ in 0..240 {
        let t = std::time::Instant::now();
        app.update();
        wall.push(t.elapsed().as_secs_f64() * 1e3);
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            eprintln!("simulation failed: {f}");
            std::process::exit(2);
        }
    }
    wall.sort_by(f64::total_cmp);
    println!(
        "wall time per frame: median {:.1} ms, slowest {:.1} ms (a 60 Hz game has 16.7 ms)",
        wall[wall.len() / 2],
        wall[wall.len() - 1]
    );
}
