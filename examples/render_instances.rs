//! Per-frame CPU cost of the particle renderer (feature `render`): for N particle entities,
//! the time of [`gather_particle_instances`] (entities → `[x, y, z, value]`, colour range) and
//! [`upload_particle_instances`] (→ the GPU buffer asset, which Bevy's extraction then moves to
//! the render world without a copy). No GPU is needed: the systems run in a plain app with
//! the asset plugin. Prints the median and 90th percentile over 200 frames.
//!
//! `cargo render-example render_instances -- [N ...]` (default 100000 and 1000000).
use std::time::Instant;

use bevy::app::{App, TaskPoolPlugin};
use bevy::asset::{AssetApp, AssetPlugin};
use bevy::ecs::schedule::Schedule;
use bevy::mesh::Mesh;
use bevy::render::storage::ShaderBuffer;
use treacle::prelude::*;
use treacle::render::{
    ParticleInstances, ParticleMaterial, ParticleStyle, gather_particle_instances,
    upload_particle_instances,
};

fn percentile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn measure(n: usize) {
    let mut app = App::new();
    app.add_plugins((TaskPoolPlugin::default(), AssetPlugin::default()))
        .init_asset::<ShaderBuffer>()
        .init_asset::<Mesh>()
        .init_asset::<ParticleMaterial>()
        .insert_resource(ParticleStyle {
            radius: 0.0025,
            ..Default::default()
        })
        .init_resource::<ParticleInstances>();
    app.finish();
    app.cleanup();
    let world = app.world_mut();
    // A block of particles with a velocity field, as the step leaves them.
    let side = (n as f64).cbrt().ceil() as usize;
    let h = 0.005;
    let batch: Vec<_> = (0..n)
        .map(|i| {
            let (x, y, z) = (i % side, (i / side) % side, i / (side * side));
            let p = Vec3::new(x as f32, y as f32, z as f32) * h;
            ParticleBundle::new(
                p,
                Vec3::new(0.0, -p.y, 0.1),
                Vec3::ZERO,
                h * h * h,
                1000.0,
                MaterialId(0),
            )
        })
        .collect();
    world.spawn_batch(batch);
    world
        .run_system_cached(treacle::render::spawn_particle_cloud)
        .unwrap();
    let mut gather = Schedule::default();
    gather.add_systems(gather_particle_instances);
    let mut upload = Schedule::default();
    upload.add_systems(upload_particle_instances);
    let (mut tg, mut tu) = (Vec::new(), Vec::new());
    for frame in 0..220 {
        let t0 = Instant::now();
        gather.run(world);
        let t1 = Instant::now();
        upload.run(world);
        let t2 = Instant::now();
        if frame >= 20 {
            tg.push((t1 - t0).as_secs_f64() * 1e3);
            tu.push((t2 - t1).as_secs_f64() * 1e3);
        }
    }
    let total: Vec<f64> = tg.iter().zip(&tu).map(|(a, b)| a + b).collect();
    println!(
        "particles={n} gather_ms median={:.3} p90={:.3} upload_ms median={:.3} p90={:.3} total_ms median={:.3} p90={:.3}",
        percentile(tg.clone(), 0.5),
        percentile(tg, 0.9),
        percentile(tu.clone(), 0.5),
        percentile(tu, 0.9),
        percentile(total.clone(), 0.5),
        percentile(total, 0.9),
    );
}

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("particle counts"))
        .collect();
    let counts = if args.is_empty() {
        vec![100_000, 1_000_000]
    } else {
        args
    };
    for n in counts {
        measure(n);
    }
}
