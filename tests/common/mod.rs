//! Helpers shared by the whole-step tests: build an app, fill boxes, measure.
#![allow(dead_code)]
use bevy_app::App;
use bevy_ecs::prelude::*;
use treacle::app::headless_app;
use treacle::prelude::*;

/// Cell-centred lattice positions filling `[min, max]` with spacing `h`.
pub fn lattice(min: Vec3, max: Vec3, h: f32) -> Vec<Vec3> {
    let n = ((max - min) / h).round().as_ivec3();
    let mut out = Vec::with_capacity((n.x * n.y * n.z) as usize);
    for i in 0..n.x {
        for j in 0..n.y {
            for k in 0..n.z {
                out.push(min + (glam::IVec3::new(i, j, k).as_vec3() + Vec3::splat(0.5)) * h);
            }
        }
    }
    out
}

/// An app with one material and the given particles (volume h³ each, velocity from `vel`).
pub fn app_with(
    config: MpmConfig,
    material: FluidMaterial,
    positions: &[Vec3],
    h: f32,
    vel: impl Fn(Vec3) -> Vec3,
) -> App {
    let mut materials = Materials::default();
    let rho0 = material.density;
    let id = materials.add(material);
    let g = config.gravity;
    let mut app = headless_app(config, materials);
    let batch: Vec<ParticleBundle> = positions
        .iter()
        .map(|x| ParticleBundle::new(*x, vel(*x), g, h * h * h, rho0, id))
        .collect();
    app.world_mut().spawn_batch(batch);
    app
}

/// All particle positions and velocities, in query order.
pub fn state(app: &mut App) -> Vec<(Entity, Vec3, Vec3)> {
    let world = app.world_mut();
    let mut q = world.query_filtered::<(Entity, &Position, &Velocity), With<Particle>>();
    q.iter(world).map(|(e, x, v)| (e, x.0, v.0)).collect()
}

/// The failure, if the run stopped.
pub fn failure(app: &App) -> Option<FailureReport> {
    app.world().resource::<SimulationStatus>().failure.clone()
}

/// Panics with the failure report if the run stopped.
pub fn assert_healthy(app: &App) {
    if let Some(f) = failure(app) {
        panic!("simulation failed: {f}");
    }
}
