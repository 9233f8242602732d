//! PCG on the heat system (b I − β L_h) x = f of ALGORITHM §3.2–3.3: iterations to a relative
//! residual ‖r‖₂/‖f‖₂ ≤ 1e-8 and solve time per unknown, multigrid V-cycle (§3.5) against
//! Jacobi preconditioning, on N³ Interior nodes with a Dirichlet node layer around them
//! (h = 1/(N+1), the domain of H1/H2 in §3.6) and a pseudo-random right-hand side (fixed
//! seed).
//!
//! Two coefficient sets: (b, β) = (1, 1) (β/h² ≫ b: Poisson-like, the hard case of a large
//! diffusivity or time step) and (1, 1e-3). The solve is serial (deterministic for any thread
//! count). Times are the best of `TREACLE_BENCH_REPEATS` (default 3; 1 at 128³) solves,
//! including the multigrid setup (the hierarchy is rebuilt every step in a simulation).
//!
//! Run: `cargo bench --bench multigrid` (`-- 64` runs only N = 64). Prints a markdown table;
//! results are in `BENCHMARKS.md`.
use std::hint::black_box;
use std::time::Instant;

use treacle::krylov::{
    CgParams, CgScratch, JacobiPreconditioner, ResidualNorm, conjugate_gradient_in_norm,
};
use treacle::thermal::multigrid::{
    BlockLattice, LatticeOperator, Multigrid, MultigridParams, NodeClass,
};

fn problem(n: usize, b: f64, beta: f64) -> (LatticeOperator, Vec<f64>) {
    let mut op = LatticeOperator::default();
    let h = 1.0 / (n + 1) as f64;
    op.rebuild([n + 2; 3], h, b, beta, |c| {
        if c.iter().any(|&v| v == 0 || v == n + 1) {
            NodeClass::Dirichlet
        } else {
            NodeClass::Interior
        }
    });
    // Pseudo-random right-hand side (all frequencies; a single sine mode is an eigenvector
    // of the operator and of Jacobi-preconditioned CG, which then converges in 1 iteration).
    let f = random_rhs(&op);
    (op, f)
}

/// The same N³ Interior nodes split into two halves (N/2 × N × N each, with their Dirichlet
/// layers) in opposite corners of a box 4× larger on x and z: the block-sparse lattice stores
/// only the two halves' blocks (and their parents on the coarse levels), so the iterations
/// and the time per unknown should match the cube's. Right-hand side as in [`problem`].
fn problem_split(n: usize, b: f64, beta: f64) -> (LatticeOperator, Vec<f64>) {
    let h = 1.0 / (n + 1) as f64;
    let half = n / 2;
    let big = 4 * (n + 2);
    // Half 0 starts at the origin; half 1 ends at the far corner on x and z.
    let (w, top) = (half as i32 + 1, n as i32 + 1);
    let far = big as i32 - 1;
    let halves = [
        ([0, 0, 0], [w, top, top]),
        ([far - w, 0, far - top], [far, top, far]),
    ];
    let mut lattice = BlockLattice::default();
    lattice.begin([0; 3], [big as i32 - 1, n as i32 + 1, big as i32 - 1]);
    for (lo, hi) in halves {
        lattice.mark_cells(lo, hi);
    }
    lattice.finish();
    let mut op = LatticeOperator::default();
    op.rebuild_on(&lattice, [big, n + 2, big], h, b, beta, |c, _| {
        let c = c.map(|v| v as i32);
        for (lo, hi) in halves {
            if (0..3).all(|a| c[a] >= lo[a] && c[a] <= hi[a]) {
                let edge = (0..3).any(|a| c[a] == lo[a] || c[a] == hi[a]);
                return if edge {
                    NodeClass::Dirichlet
                } else {
                    NodeClass::Interior
                };
            }
        }
        NodeClass::Exterior
    });
    let f = random_rhs(&op);
    (op, f)
}

/// A pseudo-random right-hand side on the Interior nodes (fixed seed).
fn random_rhs(op: &LatticeOperator) -> Vec<f64> {
    let mut seed = 0x2545_F491_4F6C_DD1Du64;
    let mut f = vec![0.0; op.len()];
    for &i in op.interior() {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        f[i as usize] = (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
    }
    f
}

#[derive(Clone, Copy)]
enum Pc {
    Multigrid,
    Jacobi,
}

/// One solve from zero; returns (iterations, seconds).
fn solve(op: &mut LatticeOperator, f: &[f64], pc: Pc) -> (usize, f64) {
    let params = CgParams {
        rel_tol: 1e-8,
        abs_tol: 0.0,
        max_iters: 10_000,
    };
    let mut x = vec![0.0; op.len()];
    let mut scratch = CgScratch::default();
    let t0 = Instant::now();
    let info = match pc {
        Pc::Multigrid => {
            let mut mg = Multigrid::new(MultigridParams::default()).unwrap();
            mg.setup(op);
            conjugate_gradient_in_norm(
                op,
                &mut mg,
                f,
                &mut x,
                &params,
                ResidualNorm::Euclidean,
                &mut scratch,
            )
        }
        Pc::Jacobi => {
            let mut jac = JacobiPreconditioner::default();
            op.jacobi_preconditioner(&mut jac);
            conjugate_gradient_in_norm(
                op,
                &mut jac,
                f,
                &mut x,
                &params,
                ResidualNorm::Euclidean,
                &mut scratch,
            )
        }
    };
    let secs = t0.elapsed().as_secs_f64();
    black_box(&x);
    (info.expect("PCG converges").iterations, secs)
}

fn main() {
    let filter: Option<usize> = std::env::args().skip(1).find_map(|a| a.parse().ok());
    let repeats: usize = std::env::var("TREACLE_BENCH_REPEATS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    println!(
        "| N³ | b, β | MG-PCG its | MG-PCG s | MG ns/unknown | Jacobi-PCG its | Jacobi s | Jacobi ns/unknown |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (b, beta) in [(1.0, 1.0), (1.0, 1e-3)] {
        for n in [32usize, 64, 128] {
            if filter.is_some_and(|f| f != n) {
                continue;
            }
            let (mut op, f) = problem(n, b, beta);
            let reps = if n >= 128 { 1 } else { repeats };
            let mut row = Vec::new();
            for pc in [Pc::Multigrid, Pc::Jacobi] {
                let mut best = f64::INFINITY;
                let mut its = 0;
                for _ in 0..reps {
                    let (i, s) = solve(&mut op, &f, pc);
                    its = i;
                    best = best.min(s);
                }
                let per = best * 1e9 / (n * n * n) as f64;
                row.push(format!("{its} | {best:.3} | {per:.0}"));
            }
            println!("| {n}³ | {b}, {beta} | {} | {} |", row[0], row[1]);
        }
    }
    // The same unknowns in two halves far apart (block-sparse lattice): multigrid only.
    println!();
    println!(
        "| N³ in two halves, box 4(N+2) × (N+2) × 4(N+2) | b, β | unknowns | stored nodes | box nodes | MG-PCG its | MG-PCG s | MG ns/unknown |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (b, beta) in [(1.0, 1.0), (1.0, 1e-3)] {
        for n in [32usize, 64, 128] {
            if filter.is_some_and(|f| f != n) {
                continue;
            }
            let (mut op, f) = problem_split(n, b, beta);
            let reps = if n >= 128 { 1 } else { repeats };
            let mut best = f64::INFINITY;
            let mut its = 0;
            for _ in 0..reps {
                let (i, s) = solve(&mut op, &f, Pc::Multigrid);
                its = i;
                best = best.min(s);
            }
            let unknowns = op.interior().len();
            let per = best * 1e9 / unknowns as f64;
            let box_nodes: usize = op.core_dims().iter().product();
            println!(
                "| {n}³ | {b}, {beta} | {unknowns} | {} | {box_nodes} | {its} | {best:.3} | {per:.0} |",
                op.len()
            );
        }
    }
}
