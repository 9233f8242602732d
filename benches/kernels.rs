//! Criterion benchmarks of the transfer kernels on plain slices (no App), at the size of the
//! performance target: the 65 536 particles of `scenes/bench_block.ron` (a jitter-free block
//! lattice, 2 particles per cell and axis) on its 64³-cell grid, with 2 compute threads
//! (`TREACLE_BENCH_THREADS` overrides).
//!
//! Every benchmark processes all particles once per iteration and reports the throughput in
//! particles/s (`thrpt`, elements/s); ns/particle = 10⁹ / thrpt. `*_par` benches run on the
//! compute pool: scatters through the deterministic slab-coloured [`ScatterPlan`] exactly as the
//! step systems do, gathers split into chunks; `*_serial*` benches are plain loops on the
//! calling thread (the cost per particle). `TREACLE_BENCH_THREADS=1` sizes the pool to 1.
//!
//! Run: `cargo bench --bench kernels` (a filter selects benches: `cargo bench --bench kernels
//! -- g2p`). Results are summarised in `BENCHMARKS.md`.
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use bevy_tasks::{ComputeTaskPool, ParallelSliceMut, TaskPool, TaskPoolBuilder};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use treacle::grid::{GridNode, MpmGrid, NodeBox};
use treacle::kernels::{
    Stencil, StepCoefficients, force_particle, g2p_particle, kinematics_particle, p2g_particle,
};
use treacle::math::{Mat3, Real, Vec3};
use treacle::scatter::{ScatterPlan, SharedMut};
use treacle::schedule::{Gs4Constants, coefficients};

/// Compute threads: 2 (the target machine; the default pool would get one on this 2-core
/// box), or `TREACLE_BENCH_THREADS` (e.g. 1 for the single-thread reference).
fn threads() -> usize {
    std::env::var("TREACLE_BENCH_THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .filter(|n| *n >= 1)
        .unwrap_or(2)
}

/// A typical step of the bench block (its adaptive Δt is ≈ 2.7·10⁻⁴ s) [s].
const DT: f64 = 2.5e-4;

/// Benchmark id `kernels::<name>` (named after the module path, STYLE §7 item 12).
macro_rules! name {
    ($s:literal) => {
        concat!(module_path!(), "::", $s)
    };
}

/// Deterministic pseudo-random numbers in [0, 1) (fixed seed: reproducible inputs).
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> Real {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as Real) / ((1u64 << 24) as Real)
    }

    fn vec(&mut self, scale: Real) -> Vec3 {
        scale * (2.0 * Vec3::new(self.next(), self.next(), self.next()) - Vec3::ONE)
    }
}

/// The particles of the bench block and a grid holding a realistic transferred state.
struct Block {
    grid: MpmGrid,
    /// Positions, used as the predicted positions x̃ (jitter-free lattice, sampling order).
    xs: Vec<Vec3>,
    masses: Vec<Real>,
    velocities: Vec<Vec3>,
    accelerations: Vec<Vec3>,
    /// Ṽσ̃ (volume times a pressure-plus-shear stress).
    v_sigma: Vec<Mat3>,
    coeffs: StepCoefficients,
}

impl Block {
    fn new() -> Self {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/bench_block.ron");
        let scene = treacle::scene::load_scene(&path).expect("scenes/bench_block.ron loads");
        let body = &scene.particles[0];
        let rho0 = scene.materials.list[body.material.0 as usize].density;
        let config = &scene.config;
        let grid = MpmGrid::new(config.domain_min, config.domain_max, config.dx);
        let xs = body.positions.clone();
        let n = xs.len();
        let mut rng = Lcg(0);
        let masses = vec![body.particle_volume * rho0; n];
        let velocities = (0..n).map(|_| rng.vec(0.5)).collect();
        let accelerations = (0..n).map(|_| config.gravity + rng.vec(1.0)).collect();
        let v_sigma = (0..n)
            .map(|_| {
                let p = 1000.0 * rng.next();
                let shear = Mat3::from_cols(rng.vec(1.0), rng.vec(1.0), rng.vec(1.0));
                body.particle_volume * (Mat3::from_diagonal(Vec3::splat(-p)) + shear)
            })
            .collect();
        let gs4 = Gs4Constants::new(config.integrator.rho_inf, config.integrator.rho_s)
            .expect("default GS4 parameters");
        let coeffs = coefficients(&gs4.params, DT, config.integrator.flip, false);
        let mut block = Self {
            grid,
            xs,
            masses,
            velocities,
            accelerations,
            v_sigma,
            coeffs,
        };
        block.fill_grid();
        block
    }

    fn len(&self) -> usize {
        self.xs.len()
    }

    /// P2G (serial), normalisation, and plausible new velocities/accelerations, so that the
    /// gathers read the same kind of data as in a step.
    fn fill_grid(&mut self) {
        let mut plan = ScatterPlan::default();
        scatter_p2g(self, &mut plan);
        let mut rng = Lcg(1);
        let dt = DT as Real;
        for n in &mut self.grid.nodes {
            if n.mass > 0.0 {
                n.velocity /= n.mass;
                n.acceleration /= n.mass;
                // (Vec3::from / into: independent of the node's vector type.)
                let a_new = Vec3::from(n.acceleration) + rng.vec(1.0);
                n.new_acceleration = a_new.into();
                n.new_velocity = (Vec3::from(n.velocity) + dt * a_new).into();
            }
        }
    }
}

/// Clears the nodes the last scatter touched, bins the particles and scatters mass, momentum
/// and m·a: the work of the `ParticleToGrid` system without its normalisation pass.
fn scatter_p2g(b: &mut Block, plan: &mut ScatterPlan) {
    b.grid.clear_active();
    plan.build(&b.grid.layout, b.xs.iter().copied());
    b.grid.active = plan.touched;
    let layout = b.grid.layout;
    let nodes = SharedMut(b.grid.nodes.as_mut_ptr());
    let (xs, ms, vs, as_) = (&b.xs, &b.masses, &b.velocities, &b.accelerations);
    plan.run(|i| {
        // SAFETY: ScatterPlan::run never runs two particles whose stencils share a node
        // concurrently; the pointer covers the whole node array and stencils are clamped.
        unsafe { p2g_particle(&layout, nodes.get(), xs[i], ms[i], vs[i], as_[i]) };
    });
}

/// Scatters Ṽσ̃∇w̃ with an already built plan: the work of the `GridForces` system, which
/// reuses the P2G plan of the same step.
fn scatter_forces(b: &mut Block, plan: &ScatterPlan) {
    let layout = b.grid.layout;
    let nodes = SharedMut(b.grid.nodes.as_mut_ptr());
    let (xs, vs) = (&b.xs, &b.v_sigma);
    plan.run(|i| {
        // SAFETY: as in scatter_p2g.
        unsafe { force_particle(&layout, nodes.get(), xs[i], vs[i]) };
    });
}

/// Runs `f(first particle index, chunk)` over `out` split into chunks on the compute pool
/// (4 chunks per thread, like a `par_iter` with a few batches per thread).
fn par_chunks<T: Send>(
    pool: &TaskPool,
    mut out: &mut [T],
    f: impl Fn(usize, &mut [T]) + Send + Sync,
) {
    let chunk = out.len().div_ceil(4 * pool.thread_num()).max(1);
    out.par_chunk_map_mut(pool, chunk, |ci, c| f(ci * chunk, c));
}

fn bench_kernels(c: &mut Criterion) {
    let threads = threads();
    let pool = ComputeTaskPool::get_or_init(|| TaskPoolBuilder::new().num_threads(threads).build());
    assert_eq!(
        pool.thread_num(),
        threads,
        "compute pool initialised elsewhere"
    );
    eprintln!("compute threads: {threads}");
    let mut b = Block::new();
    let n = b.len();
    assert_eq!(n, 65_536, "bench_block.ron must hold 65 536 particles");
    eprintln!(
        "bench block: {n} particles, {} grid nodes × {} B = {:.1} MB",
        b.grid.nodes.len(),
        std::mem::size_of::<GridNode>(),
        (b.grid.nodes.len() * std::mem::size_of::<GridNode>()) as f64 / 1e6
    );
    let mut plan = ScatterPlan::default();
    let mut group = c.benchmark_group("kernels");
    group.throughput(Throughput::Elements(n as u64));

    // Weights only: 3 × 3 B-spline evaluations and a floor per particle.
    group.bench_function(name!("stencil_new"), |bch| {
        let layout = b.grid.layout;
        bch.iter(|| {
            let mut acc = 0.0;
            for x in &b.xs {
                let st = Stencil::new(&layout, *x);
                acc += st.w[0][1] + st.dw[2][0];
            }
            black_box(acc)
        })
    });

    // Zeroing the touched node box (part of `ParticleToGrid`).
    plan.build(&b.grid.layout, b.xs.iter().copied());
    let touched: NodeBox = plan.touched;
    group.bench_function(name!("grid_clear_active"), |bch| {
        bch.iter(|| {
            b.grid.active = touched;
            b.grid.clear_active();
        })
    });

    group.bench_function(name!("scatter_plan_build"), |bch| {
        bch.iter(|| plan.build(&b.grid.layout, black_box(&b.xs).iter().copied()))
    });

    // clear + build + slab-coloured scatter on the pool.
    group.bench_function(name!("p2g_scatter_par"), |bch| {
        bch.iter(|| scatter_p2g(&mut b, &mut plan))
    });

    // clear + a plain serial loop in sampling order (the single-thread reference).
    group.bench_function(name!("p2g_serial_loop"), |bch| {
        bch.iter(|| {
            b.grid.active = touched;
            b.grid.clear_active();
            let layout = b.grid.layout;
            let p = b.grid.nodes.as_mut_ptr();
            for i in 0..n {
                // SAFETY: single thread; the stencil is clamped into the node box.
                unsafe {
                    p2g_particle(
                        &layout,
                        p,
                        b.xs[i],
                        b.masses[i],
                        b.velocities[i],
                        b.accelerations[i],
                    )
                };
            }
        })
    });

    // The P2G benches left the grid with un-normalised sums: restore the gather state.
    b.fill_grid();

    // Scatter of the stress divergence on the pool with the P2G plan (forces accumulate; the
    // cost does not depend on the values).
    plan.build(&b.grid.layout, b.xs.iter().copied());
    group.bench_function(name!("force_scatter_par"), |bch| {
        bch.iter(|| scatter_forces(&mut b, &plan))
    });
    // The same in a plain serial loop (the single-thread reference).
    group.bench_function(name!("force_serial_loop"), |bch| {
        bch.iter(|| {
            let layout = b.grid.layout;
            let p = b.grid.nodes.as_mut_ptr();
            for i in 0..n {
                // SAFETY: single thread; the stencil is clamped into the node box.
                unsafe { force_particle(&layout, p, b.xs[i], b.v_sigma[i]) };
            }
        })
    });
    for node in &mut b.grid.nodes {
        node.force = Default::default();
    }

    let mut ls = vec![Mat3::ZERO; n];
    group.bench_function(name!("kinematics_serial"), |bch| {
        bch.iter(|| {
            for (x, l) in b.xs.iter().zip(&mut ls) {
                *l = kinematics_particle(&b.grid.layout, &b.grid.nodes, *x, &b.coeffs, false).0;
            }
        })
    });
    group.bench_function(name!("kinematics_par"), |bch| {
        bch.iter(|| {
            par_chunks(pool, &mut ls, |first, chunk| {
                for (l, x) in chunk.iter_mut().zip(&b.xs[first..]) {
                    *l = kinematics_particle(&b.grid.layout, &b.grid.nodes, *x, &b.coeffs, false).0;
                }
            })
        })
    });
    black_box(&ls);

    // Results written like the components: [position, velocity, acceleration].
    let mut out = vec![[Vec3::ZERO; 3]; n];
    let g2p = |b: &Block, i: usize| {
        let r = g2p_particle(
            &b.grid.layout,
            &b.grid.nodes,
            b.xs[i],
            b.xs[i],
            b.velocities[i],
            b.accelerations[i],
            &b.coeffs,
        );
        [r.position, r.velocity, r.acceleration]
    };
    group.bench_function(name!("g2p_serial"), |bch| {
        bch.iter(|| {
            for (i, r) in out.iter_mut().enumerate() {
                *r = g2p(&b, i);
            }
        })
    });
    group.bench_function(name!("g2p_par"), |bch| {
        bch.iter(|| {
            par_chunks(pool, &mut out, |first, chunk| {
                for (k, r) in chunk.iter_mut().enumerate() {
                    *r = g2p(&b, first + k);
                }
            })
        })
    });
    black_box(&out);

    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = bench_kernels
}
criterion_main!(benches);
