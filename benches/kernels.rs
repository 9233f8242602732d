//! Criterion benchmarks of the transfer kernels on plain slices (no App), at the size of the
//! performance target: the 65 536 particles of `scenes/bench_block.ron` (a jitter-free block
//! lattice, 2 particles per cell and axis) on its 64³-cell grid, with 2 compute threads
//! (`TREACLE_BENCH_THREADS` overrides).
//!
//! Every benchmark processes all particles once per iteration and reports the throughput in
//! particles/s (`thrpt`, elements/s); ns/particle = 10⁹ / thrpt. `*_par` benches run on the
//! compute pool through the block-sparse grid exactly as the step systems do ([`BlockPlan`]:
//! block-coloured scatters, gathers by block neighbourhood); `*_serial*` benches are plain loops
//! on the calling thread over a dense node array (the cost per particle of the kernels alone).
//! `TREACLE_BENCH_THREADS=1` sizes the pool to 1.
//!
//! Run: `cargo bench --bench kernels` (a filter selects benches: `cargo bench --bench kernels
//! -- g2p`). Results are summarised in `BENCHMARKS.md`.
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

use bevy_tasks::{ComputeTaskPool, TaskPoolBuilder};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use treacle::grid::{GridNode, MpmGrid};
use treacle::kernels::{
    G2pResult, Stencil, StepCoefficients, force_stencil, g2p_stencil, kinematics_stencil,
    p2g_stencil,
};
use treacle::math::{Mat3, Real, Vec3};
use treacle::scatter::BlockPlan;
use treacle::schedule::{Gs4Constants, coefficients};
use treacle::step::symplectic_euler::{FirstOrderG2p, first_order_coefficients, g2p_first_order};

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

/// The particles of the bench block, the block-sparse grid of a step and a dense copy of its
/// node box (the serial references run the kernels on plain dense slices).
struct Block {
    grid: MpmGrid,
    plan: BlockPlan,
    /// A dense array over the whole node box, holding the same transferred state.
    dense: Vec<GridNode>,
    /// Positions, used as the predicted positions x̃ (jitter-free lattice, sampling order).
    xs: Vec<Vec3>,
    stencils: Vec<Stencil>,
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
        let stencils = xs.iter().map(|x| Stencil::new(&grid.layout, *x)).collect();
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
        let dense = vec![GridNode::default(); grid.layout.node_count()];
        let mut block = Self {
            grid,
            plan: BlockPlan::default(),
            dense,
            xs,
            stencils,
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

    /// P2G, normalisation, and plausible new velocities/accelerations, so that the gathers read
    /// the same kind of data as in a step; the dense copy receives the same node values.
    fn fill_grid(&mut self) {
        scatter_p2g(self);
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
        self.dense.fill(GridNode::default());
        for (idx, n) in self.grid.nodes.iter().enumerate() {
            let c = self.grid.node_of_index(idx);
            self.dense[self.grid.layout.index(c)] = *n;
        }
    }
}

/// Orders the particles by block (reused when unchanged, as in a step), allocates the reached
/// blocks and scatters mass, momentum and m·a: the work of the `ParticleToGrid` system without
/// its folds and normalisation pass.
fn scatter_p2g(b: &mut Block) {
    let layout = b.grid.layout;
    b.plan.build(&layout, b.stencils.iter().map(|s| s.base));
    let mut keys = Vec::new();
    b.plan.reached_blocks(&layout, &mut keys);
    keys.sort_unstable();
    keys.dedup();
    b.grid.allocate(&keys);
    let mut nodes = std::mem::take(&mut b.grid.nodes);
    let (sts, ms, vs, as_) = (&b.stencils, &b.masses, &b.velocities, &b.accelerations);
    b.plan.scatter(
        &b.grid,
        &mut nodes,
        |n: &mut GridNode, h: &GridNode| {
            n.mass += h.mass;
            n.velocity += h.velocity;
            n.acceleration += h.acceleration;
        },
        |i, local, hood| {
            // SAFETY: the neighbourhood holds the particle's whole stencil.
            unsafe { p2g_stencil(local, hood.as_mut_ptr(), &sts[i], ms[i], vs[i], as_[i]) };
        },
    );
    b.grid.nodes = nodes;
}

/// Scatters Ṽσ̃∇w̃ with the P2G plan: the work of the `GridForces` system.
fn scatter_forces(b: &mut Block) {
    let mut nodes = std::mem::take(&mut b.grid.nodes);
    let (sts, vs) = (&b.stencils, &b.v_sigma);
    b.plan.scatter(
        &b.grid,
        &mut nodes,
        |n: &mut GridNode, h: &GridNode| n.force += h.force,
        |i, local, hood| {
            // SAFETY: as in scatter_p2g.
            unsafe { force_stencil(local, hood.as_mut_ptr(), &sts[i], vs[i]) };
        },
    );
    b.grid.nodes = nodes;
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
        "bench block: {n} particles, {} blocks, {} allocated nodes × {} B = {:.1} MB (dense node \
         box: {} nodes)",
        b.grid.block_count(),
        b.grid.nodes.len(),
        std::mem::size_of::<GridNode>(),
        (b.grid.nodes.len() * std::mem::size_of::<GridNode>()) as f64 / 1e6,
        b.dense.len()
    );
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

    // Ordering the particles by block from scratch (a step reuses it while no particle
    // changed block).
    group.bench_function(name!("block_plan_build"), |bch| {
        let layout = b.grid.layout;
        bch.iter(|| {
            let mut plan = BlockPlan::default();
            plan.build(&layout, black_box(&b.stencils).iter().map(|s| s.base));
            black_box(plan.block_count())
        })
    });

    // allocate (zeroing) + block-coloured scatter on the pool.
    group.bench_function(name!("p2g_scatter_par"), |bch| {
        bch.iter(|| scatter_p2g(&mut b))
    });

    // Zeroing the dense node box + a plain serial loop in sampling order (the single-thread
    // reference on a dense grid).
    let layout = b.grid.layout;
    group.bench_function(name!("p2g_serial_loop"), |bch| {
        bch.iter(|| {
            b.dense.fill(GridNode::default());
            let p = b.dense.as_mut_ptr();
            for i in 0..n {
                // SAFETY: single thread; the stencil is clamped into the node box.
                unsafe {
                    p2g_stencil(
                        &layout,
                        p,
                        &b.stencils[i],
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
    group.bench_function(name!("force_scatter_par"), |bch| {
        bch.iter(|| scatter_forces(&mut b))
    });
    // The same in a plain serial loop on the dense grid (the single-thread reference).
    group.bench_function(name!("force_serial_loop"), |bch| {
        bch.iter(|| {
            let p = b.dense.as_mut_ptr();
            for i in 0..n {
                // SAFETY: single thread; the stencil is clamped into the node box.
                unsafe { force_stencil(&layout, p, &b.stencils[i], b.v_sigma[i]) };
            }
        })
    });
    for node in &mut b.grid.nodes {
        node.force = Default::default();
    }

    let mut ls = vec![Mat3::ZERO; n];
    group.bench_function(name!("kinematics_serial"), |bch| {
        bch.iter(|| {
            for (st, l) in b.stencils.iter().zip(&mut ls) {
                *l = kinematics_stencil(&layout, &b.dense, st, &b.coeffs, false).0;
            }
        })
    });
    group.bench_function(name!("kinematics_par"), |bch| {
        bch.iter(|| {
            b.plan
                .gather_into(&b.grid, &b.grid.nodes, &mut ls, |i, local, hood| {
                    kinematics_stencil(local, hood, &b.stencils[i], &b.coeffs, false).0
                })
        })
    });
    black_box(&ls);

    // Results written like the components: position, velocity, acceleration.
    let mut out = vec![G2pResult::default(); n];
    group.bench_function(name!("g2p_serial"), |bch| {
        bch.iter(|| {
            for (i, r) in out.iter_mut().enumerate() {
                *r = g2p_stencil(
                    &layout,
                    &b.dense,
                    &b.stencils[i],
                    b.xs[i],
                    b.velocities[i],
                    b.accelerations[i],
                    &b.coeffs,
                );
            }
        })
    });
    group.bench_function(name!("g2p_par"), |bch| {
        bch.iter(|| {
            b.plan
                .gather_into(&b.grid, &b.grid.nodes, &mut out, |i, local, hood| {
                    g2p_stencil(
                        local,
                        hood,
                        &b.stencils[i],
                        b.xs[i],
                        b.velocities[i],
                        b.accelerations[i],
                        &b.coeffs,
                    )
                })
        })
    });
    black_box(&out);

    // The first-order (symplectic Euler) G2P: velocity, position and the velocity gradient.
    let fo = first_order_coefficients(DT, 0.0);
    let mut out1 = vec![FirstOrderG2p::default(); n];
    group.bench_function(name!("g2p_first_order_serial"), |bch| {
        bch.iter(|| {
            for (i, r) in out1.iter_mut().enumerate() {
                *r = g2p_first_order(
                    &layout,
                    &b.dense,
                    &b.stencils[i],
                    b.xs[i],
                    b.velocities[i],
                    &fo,
                );
            }
        })
    });
    black_box(&out1);

    group.finish();
    bench_polymer_commit(c);
}

/// The XPP slime's first-order commit (`Su2021Unified`, the convected update of choice D22) on
/// 65,536 particles with random symmetric stresses and velocity gradients, serial. Each iteration
/// commits the states the last one left (the cost does not depend on the values; they stay
/// finite, checked after the benches).
fn bench_polymer_commit(c: &mut Criterion) {
    use treacle::gs4::Gs4Params;
    use treacle::material::FluidMaterial;
    use treacle::rheology::{
        FirstOrderCoefficients, PolymerStress, Rheology, RheologyContext, Su2021Unified,
    };
    let model = Su2021Unified::xpp(0.5, 0.25, 0.15, 4.0);
    let material = FluidMaterial {
        local_fraction: 0.1,
        ..FluidMaterial::newtonian("slime", 1050.0, 10.0, 20.0)
    };
    let coefficients =
        FirstOrderCoefficients::step(&Gs4Params::default(), 2e-3).with_first_order_mechanics(true);
    let mut rng = Lcg(7);
    let n = 65_536;
    let ls: Vec<Mat3> = (0..n)
        .map(|_| Mat3::from_cols(rng.vec(20.0), rng.vec(20.0), rng.vec(20.0)))
        .collect();
    let mut states: Vec<PolymerStress> = (0..n)
        .map(|_| {
            let a = Mat3::from_cols(rng.vec(10.0), rng.vec(10.0), rng.vec(10.0)).as_dmat3();
            PolymerStress {
                value: a + a.transpose(),
                ..Default::default()
            }
        })
        .collect();
    let context = |l: &Mat3| RheologyContext::new(*l, 1050.0, &material, coefficients, false);
    let mut group = c.benchmark_group("rheology");
    group.throughput(Throughput::Elements(n as u64));
    group.bench_function(name!("xpp_commit"), |bch| {
        bch.iter(|| {
            for (l, s) in ls.iter().zip(states.iter_mut()) {
                model.commit(&context(l), s);
            }
        })
    });
    black_box(&states);
    black_box(&states);
    group.finish();
    assert!(
        states
            .iter()
            .all(|s| s.value.is_finite() && s.rate.is_finite())
    );
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
