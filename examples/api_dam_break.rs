//! Everything through the public API, no scene file: a Bevy app with the MPM plugins, a
//! material, a block of liquid, a scripted moving sphere and a user system that reads the
//! particles each frame.
//!
//! Run with `cargo run --release --example api_dam_break`.
use bevy_app::{App, Update};
use bevy_ecs::prelude::*;
use glam::Quat;
use treacle::prelude::*;

/// Prints the centre of mass once per frame (a user system running next to the simulation).
fn report(clock: Res<SimulationClock>, q: Query<(&Position, &Mass), With<Particle>>) {
    let (mut m, mut c) = (0.0f32, Vec3::ZERO);
    for (x, mass) in &q {
        m += mass.0;
        c += x.0 * mass.0;
    }
    println!(
        "t = {:.3} s  steps = {:5}  particles = {}  centre of mass = ({:.3}, {:.3}, {:.3}) m",
        clock.time,
        clock.steps,
        q.iter().len(),
        c.x / m,
        c.y / m,
        c.z / m
    );
}

fn main() {
    let dx = 0.01;
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(0.6, 0.3, 0.1),
        dx,
        frame_dt: 1.0 / 30.0,
        ..Default::default()
    };
    let mut materials = Materials::default();
    let water = materials.add(FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01));

    let mut app = App::new();
    app.insert_resource(config.clone())
        .insert_resource(materials)
        .add_plugins(MpmPlugins)
        .add_systems(Update, report.after(treacle::schedule::advance_frame));
    app.finish();
    app.cleanup();

    // A column of water: 2 particles per cell per dimension.
    let h = dx / 2.0;
    let mut batch = Vec::new();
    for i in 0..20 {
        for j in 0..40 {
            for k in 0..20 {
                let x = (Vec3::new(i as f32, j as f32, k as f32) + 0.5) * h;
                batch.push(ParticleBundle::new(
                    x,
                    Vec3::ZERO,
                    config.gravity,
                    h * h * h,
                    1000.0,
                    water,
                ));
            }
        }
    }
    app.world_mut().spawn_batch(batch);

    // A sphere sweeping through the domain at 0.5 m/s (a scripted collider).
    app.world_mut().spawn((
        Collider {
            shape: ColliderShape::Sphere { radius: 0.04 },
            boundary: BoundaryCondition::Slip,
        },
        ColliderPose {
            translation: Vec3::new(0.55, 0.05, 0.05),
            rotation: Quat::IDENTITY,
        },
        ColliderMotion {
            linear_velocity: Vec3::new(-0.5, 0.0, 0.0),
            angular_velocity: Vec3::ZERO,
        },
    ));

    for _ in 0..15 {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            eprintln!("{f}");
            std::process::exit(2);
        }
    }
}
