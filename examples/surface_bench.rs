//! Times `treacle::surface::reconstruct_surface` on lattice spheres of 20k, 100k and 1M
//! particles (BENCHMARKS.md (i)).
//!
//! `cargo run --release --features surface --example surface_bench -- [THREADS] [CELL]`
//! (default 2 threads, cell 0.5 spacings). Prints one line per size: best and median of the
//! repetitions, mesh size and volume against N h³.
use std::time::Instant;

use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};
use treacle::math::Vec3;
use treacle::surface::{SurfaceParams, reconstruct_surface};

/// Cell-centred lattice points of spacing `h` in the sphere holding about `n` of them.
fn lattice_sphere(n: usize, h: f32) -> Vec<Vec3> {
    let radius = (3.0 * n as f32 / (4.0 * std::f32::consts::PI)).cbrt() * h;
    let m = (radius / h).ceil() as i32 + 1;
    let mut out = Vec::with_capacity(n + n / 10);
    for k in -m..m {
        for j in -m..m {
            for i in -m..m {
                let p = (Vec3::new(i as f32, j as f32, k as f32) + 0.5) * h;
                if p.length() < radius {
                    out.push(p);
                }
            }
        }
    }
    out
}

fn main() {
    let mut args = std::env::args().skip(1);
    let threads: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(2);
    let cell: f32 = args.next().and_then(|s| s.parse().ok()).unwrap_or(0.5);
    ComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(threads).build());
    let h = 0.01;
    let params = SurfaceParams {
        cell,
        ..SurfaceParams::for_spacing(h)
    };
    for (n, reps) in [(20_000, 15), (100_000, 9), (1_000_000, 5)] {
        let positions = lattice_sphere(n, h);
        let mesh = reconstruct_surface(&positions, &params).expect("valid input");
        let mut times: Vec<f64> = (0..reps)
            .map(|_| {
                let t0 = Instant::now();
                let m = reconstruct_surface(&positions, &params).expect("valid input");
                let t = t0.elapsed().as_secs_f64();
                assert_eq!(m, mesh, "deterministic");
                t
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let filled = positions.len() as f64 * (h as f64).powi(3);
        println!(
            "particles={} threads={threads} cell={cell} best_ms={:.1} median_ms={:.1} \
             vertices={} triangles={} boundary_edges={} volume/Nh3={:.5}",
            positions.len(),
            times[0] * 1e3,
            times[reps / 2] * 1e3,
            mesh.vertices.len(),
            mesh.triangles.len(),
            mesh.boundary_edges(),
            mesh.volume() / filled
        );
    }
}
