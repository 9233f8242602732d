//! A game's view of treacle (feature `game`), headless: game code spawns a pool of water by
//! `Transform`, sweeps a paddle through it by moving the paddle's `Transform` every frame, and
//! drops a light box (one of the crate's rigid bodies) that floats; the liquid runs on Bevy's
//! virtual clock at 60 frames/s within a budget of sub-steps, and a game system reads the
//! liquid and the lag once per frame.
//!
//! Run with `cargo run --release --features game --example game_liquid`.
use std::time::Duration;

use bevy_app::{App, Update};
use bevy_ecs::prelude::*;
use treacle::game::bevy_time::{Time, TimePlugin, TimeUpdateStrategy};
use treacle::game::bevy_transform::components::Transform;
use treacle::game::{GamePlugin, LiquidBody};
use treacle::prelude::*;
use treacle::rigid::{RigidBodyBundle, RigidVelocity};

/// Marks the paddle the game moves.
#[derive(Component)]
struct Paddle;

/// Marks the floating box.
#[derive(Component)]
struct Float;

/// Game code: the paddle sweeps back and forth along x (before the liquid's frame).
fn move_paddle(time: Res<Time>, mut q: Query<&mut Transform, With<Paddle>>) {
    let t = time.elapsed_secs();
    for mut tf in &mut q {
        tf.translation.x = 0.25 + 0.12 * (1.2 * t).sin();
    }
}

/// Game code: reads the liquid and the lag after the frame, printing every 15th frame.
fn report(
    clock: Res<SimulationClock>,
    lag: Res<SimulationLag>,
    liquid: Query<&Position, With<Particle>>,
    float: Query<&Transform, With<Float>>,
    mut frames: Local<u32>,
) {
    *frames += 1;
    if !(*frames).is_multiple_of(15) {
        return;
    }
    let top = liquid.iter().map(|x| x.0.y).fold(0.0f32, f32::max);
    let box_y = float.iter().next().map_or(f32::NAN, |t| t.translation.y);
    println!(
        "frame {:3}: simulated {:.3} s ({} sub-steps last frame, lag {:.3} s in all), {} \
         particles, liquid top {top:.3} m, box centre {box_y:.3} m",
        *frames,
        clock.time,
        lag.last_substeps,
        lag.total,
        liquid.iter().len()
    );
}

fn main() {
    // Game-like settings: Δx = 1 cm, c₀ = 5 m/s (about 10× the fastest flow here, Mach ≈ 0.1).
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(0.5, 0.3, 0.1),
        dx: 0.01,
        walls: DomainWalls::all(BoundaryCondition::Slip),
        ..Default::default()
    };
    let gravity = config.gravity;
    let mut materials = Materials::default();
    let water = materials.add(FluidMaterial::newtonian("water", 1000.0, 5.0, 0.01));
    let mut app = App::new();
    app.insert_resource(config)
        .insert_resource(materials)
        .add_plugins((TimePlugin, MpmPlugins, GamePlugin::with_max_substeps(60)))
        // Headless: each update is one 1/60 s game frame (a game uses the real clock).
        .insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
            1.0 / 60.0,
        )))
        .add_systems(Update, move_paddle.before(DriverSystems::Pace))
        .add_systems(Update, report.after(DriverSystems::Publish));

    // A pool 8 cm deep, placed by its Transform (its centre).
    app.world_mut().spawn((
        LiquidBody::new(
            ColliderShape::Box {
                half_extents: Vec3::new(0.25, 0.04, 0.05),
            },
            water,
        ),
        Transform::from_xyz(0.25, 0.04, 0.05),
    ));
    // The paddle: a kinematic box the game moves.
    app.world_mut().spawn((
        Collider {
            shape: ColliderShape::Box {
                half_extents: Vec3::new(0.01, 0.05, 0.05),
            },
            boundary: BoundaryCondition::Slip,
        },
        Transform::from_xyz(0.25, 0.1, 0.05),
        Paddle,
    ));
    // A box of density 500 kg/m³ dropped onto the water: it floats.
    let shape = ColliderShape::Box {
        half_extents: Vec3::new(0.03, 0.02, 0.03),
    };
    let body = RigidBody::solid(&shape, 500.0).expect("valid box");
    app.world_mut().spawn((
        RigidBodyBundle::new(
            body,
            Collider {
                shape,
                boundary: BoundaryCondition::Slip,
            },
            ColliderPose::default(),
            RigidVelocity::default(),
            gravity,
        ),
        Transform::from_xyz(0.4, 0.15, 0.05),
        Float,
    ));
    // `App::run` would do this; a loop of `update` calls must finish the plugins first.
    app.finish();
    app.cleanup();
    for _ in 0..180 {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            eprintln!("simulation failed: {f}");
            std::process::exit(2);
        }
    }
}
