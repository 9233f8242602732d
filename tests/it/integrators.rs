//! Time integrators ([`Scheme`]): temporal order on the viscous shear layer (ALGORITHM §9 M3),
//! implicit viscosity far above the explicit viscous limit, CG convergence and determinism of
//! the implicit solve, the scene and command-line switches, and the Krylov solver itself.
use crate::common;

use std::path::Path;
use std::process::Command;

use common::*;
use treacle::diagnostics::measure;
use treacle::implicit::ImplicitSolveStats;
use treacle::krylov::{
    CgError, CgParams, CgScratch, IdentityPreconditioner, JacobiPreconditioner, LinearOperator,
    conjugate_gradient, dot,
};
use treacle::prelude::*;

// ---------------------------------------------------------------------------------------------
// Krylov solver.

/// A dense symmetric matrix as a [`LinearOperator`].
struct Dense {
    n: usize,
    a: Vec<f64>,
}

impl LinearOperator for Dense {
    fn dim(&self) -> usize {
        self.n
    }
    fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        for (i, y) in y.iter_mut().enumerate() {
            *y = dot(&self.a[i * self.n..(i + 1) * self.n], x);
        }
    }
}

/// Seeded LCG in [−1, 1).
fn rng(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((s >> 11) as f64) / ((1u64 << 53) as f64) * 2.0 - 1.0
    }
}

/// A = BᵀB + diag(d) with d spanning 1e-2 … 1e2 (condition ≈ 1e4, badly scaled rows so the
/// Jacobi preconditioner matters).
fn spd(n: usize, seed: u64) -> Dense {
    let mut r = rng(seed);
    let b: Vec<f64> = (0..n * n).map(|_| r()).collect();
    let mut a = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            a[i * n + j] = (0..n).map(|k| b[k * n + i] * b[k * n + j]).sum::<f64>() / n as f64;
        }
        a[i * n + i] += 10f64.powf(-2.0 + 4.0 * i as f64 / (n - 1) as f64);
    }
    Dense { n, a }
}

/// Manufactured solution (faer's `test_cg` style): b = A x*, solve, and the true residual
/// ‖b − A x‖ meets the tolerance. The recursively updated residual that CG tests drifts from
/// the true one by O(ε κ ‖b‖); with κ ≈ 1e4 that is ≈ 1e-12 ‖b‖, so a factor 2 on 1e-10 is
/// ample. Jacobi needs fewer iterations than plain CG on this badly scaled matrix.
#[test]
fn cg_solves_a_manufactured_spd_system() {
    let n = 60;
    let mut a = spd(n, 7);
    let mut r = rng(11);
    let x_star: Vec<f64> = (0..n).map(|_| r()).collect();
    let mut b = vec![0.0; n];
    a.apply(&x_star, &mut b);
    let params = CgParams {
        rel_tol: 1e-10,
        ..Default::default()
    };
    let mut scratch = CgScratch::default();
    let inverse_diagonal = (0..n).map(|i| 1.0 / a.a[i * n + i]).collect();
    let mut jacobi = JacobiPreconditioner { inverse_diagonal };
    let mut x = vec![0.0; n];
    let info = conjugate_gradient(&mut a, &mut jacobi, &b, &mut x, &params, &mut scratch).unwrap();
    let mut ax = vec![0.0; n];
    a.apply(&x, &mut ax);
    let res: f64 = b
        .iter()
        .zip(&ax)
        .map(|(b, y)| (b - y).powi(2))
        .sum::<f64>()
        .sqrt();
    let bn = dot(&b, &b).sqrt();
    eprintln!(
        "Jacobi-PCG: {} iterations, reported {:.3e}, true {:.3e}",
        info.iterations,
        info.rel_residual,
        res / bn
    );
    assert!(info.rel_residual <= 1e-10);
    assert!(res <= 2e-10 * bn, "true residual {}", res / bn);
    let mut x0 = vec![0.0; n];
    let plain = conjugate_gradient(
        &mut a,
        &mut IdentityPreconditioner,
        &b,
        &mut x0,
        &params,
        &mut scratch,
    )
    .unwrap();
    eprintln!("plain CG: {} iterations", plain.iterations);
    assert!(info.iterations < plain.iterations);
    // Starting from the solution: converged at iteration 0.
    let again = conjugate_gradient(&mut a, &mut jacobi, &b, &mut x, &params, &mut scratch).unwrap();
    assert_eq!(again.iterations, 0);
}

/// The errors: too few iterations, an indefinite operator, a NaN right-hand side. Never a
/// panic, and the iterate stays finite.
#[test]
fn cg_reports_failures() {
    let n = 30;
    let mut a = spd(n, 3);
    let b: Vec<f64> = (0..n).map(|i| (i as f64).sin()).collect();
    let mut x = vec![0.0; n];
    let mut scratch = CgScratch::default();
    let few = CgParams {
        max_iters: 2,
        ..Default::default()
    };
    let e = conjugate_gradient(
        &mut a,
        &mut IdentityPreconditioner,
        &b,
        &mut x,
        &few,
        &mut scratch,
    )
    .unwrap_err();
    assert!(
        matches!(e, CgError::NoConvergence { iterations: 2, .. }),
        "{e}"
    );
    assert!(x.iter().all(|v| v.is_finite()));
    let mut neg = Dense {
        n,
        a: a.a.iter().map(|v| -v).collect(),
    };
    let mut x = vec![0.0; n];
    let e = conjugate_gradient(
        &mut neg,
        &mut IdentityPreconditioner,
        &b,
        &mut x,
        &CgParams::default(),
        &mut scratch,
    )
    .unwrap_err();
    assert!(
        matches!(e, CgError::NonPositiveDefiniteOperator { iteration: 1 }),
        "{e}"
    );
    let mut bad = b.clone();
    bad[3] = f64::NAN;
    let e = conjugate_gradient(
        &mut a,
        &mut IdentityPreconditioner,
        &bad,
        &mut x,
        &CgParams::default(),
        &mut scratch,
    )
    .unwrap_err();
    assert!(matches!(e, CgError::NonFinite { .. }), "{e}");
    assert!(
        CgParams {
            rel_tol: -1.0,
            ..Default::default()
        }
        .validate()
        .is_err()
    );
    assert!(
        CgParams {
            max_iters: 0,
            ..Default::default()
        }
        .validate()
        .is_err()
    );
}

// ---------------------------------------------------------------------------------------------
// Temporal order on the shear layer (M3).

/// The shear layer of `tests/mpm.rs` (M3): v = (A sin κy, 0, 0), κ = 2π/L, periodic in x and
/// y, on a coarse grid (Δx = L/8, 2 particles per cell and axis) where the viscous mode is
/// stiff enough for the temporal error to stand well above the f32 round-off: ν = 0.2 m²/s,
/// νκ² = 7.9 s⁻¹, T = 0.5 s (amplitude e⁻³·⁹ of the start). c₀ = 0.2 m/s puts the sound limit
/// at 0.44 s, out of the way; the mode is divergence-free, so no pressure acts. Pure FLIP
/// (flip = 1): PIC damping acts per transfer, not per unit time, and spoils temporal
/// convergence. Returns the particle velocities after `steps` fixed steps.
fn shear_layer(scheme: Scheme, flip_update: FlipUpdate, steps: u32) -> Vec<Vec3> {
    let (dx, nu, t_end) = (1.0f32 / 8.0, 0.2f32, 0.5f64);
    let cfg = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(1.0, 1.0, 2.0 * dx),
        dx,
        gravity: Vec3::ZERO,
        frame_dt: t_end,
        integrator: IntegratorConfig {
            scheme,
            flip_update,
            flip: 1.0,
            ..Default::default()
        },
        time_step: TimeStepConfig {
            mode: TimeStepMode::Fixed(t_end / steps as f64),
            ..Default::default()
        },
        walls: DomainWalls {
            x_min: BoundaryCondition::Periodic,
            x_max: BoundaryCondition::Periodic,
            y_min: BoundaryCondition::Periodic,
            y_max: BoundaryCondition::Periodic,
            ..Default::default()
        },
    };
    let h = dx / 2.0;
    let x0 = lattice(Vec3::ZERO, cfg.domain_max, h);
    let mat = FluidMaterial::newtonian("fluid", 1.0, 0.2, nu);
    let k = 2.0 * std::f32::consts::PI;
    let mut app = app_with(cfg, mat, &x0, h, move |x| {
        Vec3::new(0.01 * (k * x.y).sin(), 0.0, 0.0)
    });
    app.update();
    assert_healthy(&app);
    let t = app.world().resource::<SimulationClock>().time;
    assert!((t - t_end).abs() < 1e-12);
    state(&mut app).into_iter().map(|(_, _, v)| v).collect()
}

/// ‖a − b‖₂ / ‖b‖₂ over all particle velocities ([Su21] §7.1.3's velocity error).
fn rel_l2(a: &[Vec3], b: &[Vec3]) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (p, q) in a.iter().zip(b) {
        num += ((*p - *q).length() as f64).powi(2);
        den += (q.length() as f64).powi(2);
    }
    (num / den).sqrt()
}

/// Least-squares slope of log e against log Δt.
fn fitted_order(points: &[(f64, f64)]) -> f64 {
    let n = points.len() as f64;
    let (mx, my) = points.iter().fold((0.0, 0.0), |(a, b), (dt, e)| {
        (a + dt.ln() / n, b + e.ln() / n)
    });
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), (dt, e)| {
        let (x, y) = (dt.ln() - mx, e.ln() - my);
        (a + x * y, b + x * x)
    });
    sxy / sxx
}

/// Steps of the Δt ladder: Δt = 0.02 … 0.0025 s. The coarsest is 1.8× the predicted explicit
/// viscous limit 0.0112 s, which the explicit schemes survive on this noise-free mode (the
/// limit is conservative by 8–12× here, `tests/mpm.rs`).
const LADDER: [u32; 4] = [25, 50, 100, 200];

/// Observed order of `scheme` against a fine-Δt run of the same discretisation.
///
/// The reference takes Δt/16 of the finest rung for the first-order schemes and Δt/4 for the
/// second-order ones: its own error is then 1/16 of the finest rung's either way (a fit bias of
/// ≈ −0.03), and the second-order reference takes 4× fewer steps, which halves the round-off
/// floor. The asymptotic part of the ladder is where the error stands ≥ 10× above that floor,
/// measured as the difference between the reference and a run with one step more (their
/// temporal errors differ by ≲ 1e-6 relative; what remains is the f32 round-off accumulated
/// over the reference's FLIP updates, 2–5e-5). At least three such points are required.
fn observed_order(scheme: Scheme, flip_update: FlipUpdate) -> f64 {
    let finest = LADDER[LADDER.len() - 1];
    let reference_steps = finest * if scheme.formal_order() == 2 { 4 } else { 16 };
    let reference = shear_layer(scheme, flip_update, reference_steps);
    let floor = rel_l2(
        &shear_layer(scheme, flip_update, reference_steps + 1),
        &reference,
    );
    let mut points = Vec::new();
    for n in LADDER {
        let e = rel_l2(&shear_layer(scheme, flip_update, n), &reference);
        let dt = 0.5 / n as f64;
        eprintln!("{scheme} ({flip_update:?}): Δt = {dt:.5} s, velocity error {e:.4e}");
        if e >= 10.0 * floor {
            points.push((dt, e));
        }
    }
    let order = fitted_order(&points);
    eprintln!(
        "{scheme} ({flip_update:?}): round-off floor {floor:.3e}, order {order:.3} over {} points",
        points.len()
    );
    assert!(
        points.len() >= 3,
        "{scheme}: too few points above the floor"
    );
    order
}

/// Explicit GS4 with the particle-consistent FLIP update: second order (ALGORITHM §1.3).
#[test]
fn shear_layer_order_gs4_explicit() {
    let p = observed_order(Scheme::Gs4Explicit, FlipUpdate::ParticleGs4);
    assert!((p - 2.0).abs() <= 0.2, "order {p}");
}

/// The GS4 semi-implicit viscous solve (η = 1) with the particle-consistent FLIP update and
/// the transfer-consistent predictor of `implicit_viscous_update`: second order.
#[test]
fn shear_layer_order_gs4_semi_implicit() {
    let p = observed_order(Scheme::Gs4SemiImplicit, FlipUpdate::ParticleGs4);
    assert!((p - 2.0).abs() <= 0.2, "order {p}");
}

/// Symplectic Euler: first order.
#[test]
fn shear_layer_order_symplectic_euler() {
    let p = observed_order(Scheme::SymplecticEuler, FlipUpdate::default());
    assert!((p - 1.0).abs() <= 0.2, "order {p}");
}

/// Semi-implicit backward Euler: first order.
#[test]
fn shear_layer_order_backward_euler() {
    let p = observed_order(Scheme::BackwardEulerViscous, FlipUpdate::default());
    assert!((p - 1.0).abs() <= 0.2, "order {p}");
}

/// Why [`FlipUpdate::ParticleGs4`] exists: with the default grid-increment FLIP update both GS4
/// schemes are first order in time on this case (observed 1.0–1.4): the predictor
/// P2G(vₚ + W₁Λ₄Δt aₚ) uses Σ w̃ aᵢ for the rate of vₚ, which differs from it by
/// (I − PW)·rate = O((κΔx)²), an O(Δt) error in the force's evaluation point. This test pins
/// that finding (it fails if the default becomes second order, and then this note and the
/// docs of `FlipUpdate` must change).
#[test]
fn shear_layer_order_gs4_with_grid_increment_flip_is_first_order() {
    for scheme in [Scheme::Gs4Explicit, Scheme::Gs4SemiImplicit] {
        let p = observed_order(scheme, FlipUpdate::GridIncrement);
        assert!(p < 1.5, "{scheme}: order {p}");
    }
}

// ---------------------------------------------------------------------------------------------
// Implicit viscosity at large steps.

/// A 4 cm cube of the Coiling 1 syrup (ρ = 1000 kg/m³, μ = 61.25 Pa·s, Δx = 5 mm as in
/// `scenes/coiling_1.ron`) falling at 0.5 m/s onto a sticky floor 5 mm below, at a fixed Δt of
/// 10× the explicit viscous limit z_crit ρΔx²/(8μ) = 5.83e-5 s (GS4 (0.5, 0)). c₀ = 5 m/s puts
/// the sound limit of the explicit pressure at √2 Δx/(2c₀) = 7.1e-4 s (GS4) and 1e-3 s (BE),
/// above the step.
fn syrup_cube(scheme: Scheme) -> bevy_app::App {
    syrup_cube_with(scheme, FlipUpdate::GridIncrement, 10.0)
}

/// [`syrup_cube`] with a FLIP update and a step of `factor` × the explicit viscous limit.
fn syrup_cube_with(scheme: Scheme, flip_update: FlipUpdate, factor: f64) -> bevy_app::App {
    let dx = 0.005f32;
    let mu = 61.25f32;
    let limit = (8.0 / 7.0) * 1000.0 * (dx as f64).powi(2) / (8.0 * mu as f64);
    let cfg = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.08),
        dx,
        frame_dt: 0.02,
        integrator: IntegratorConfig {
            scheme,
            flip_update,
            ..Default::default()
        },
        time_step: TimeStepConfig {
            mode: TimeStepMode::Fixed(factor * limit),
            ..Default::default()
        },
        walls: DomainWalls {
            y_min: BoundaryCondition::Sticky,
            ..Default::default()
        },
        ..Default::default()
    };
    let h = dx / 2.0;
    let x0 = lattice(
        Vec3::new(0.02, 0.005, 0.02),
        Vec3::new(0.06, 0.045, 0.06),
        h,
    );
    let mat = FluidMaterial::newtonian("syrup", 1000.0, 5.0, mu);
    app_with(cfg, mat, &x0, h, |_| Vec3::new(0.0, -0.5, 0.0))
}

/// Runs the syrup cube's 5 frames (0.1 s), asserting a healthy state after each, and returns
/// the largest kinetic energy and its bound: the initial one plus the work gravity can have
/// done (the fall height is at most the 5 mm gap plus the cube's 4 cm).
fn run_healthy_frames(app: &mut bevy_app::App) -> (f64, f64) {
    let m0 = measure(app.world_mut());
    let bound = m0.kinetic_energy + m0.mass * 9.81 * 0.045;
    let mut e_max = 0.0f64;
    for _ in 0..5 {
        app.update();
        assert_healthy(app);
        e_max = e_max.max(measure(app.world_mut()).kinetic_energy);
    }
    (e_max, bound)
}

/// BE and GS4 semi-implicit are stable at 10× the explicit viscous limit for 0.1 s (170
/// steps): no failure, kinetic energy bounded by the initial one plus the work gravity can
/// have done (the fall height is at most the 5 mm gap plus the cube's 4 cm), and every CG
/// solve converged to the relative residual 1e-8. Explicit GS4 at the same step is stopped by
/// the monitor with a diagnostic (the test would prove nothing if it were not).
#[test]
fn implicit_viscosity_is_stable_at_ten_times_the_explicit_limit() {
    for scheme in [Scheme::BackwardEulerViscous, Scheme::Gs4SemiImplicit] {
        let mut app = syrup_cube(scheme);
        let (e_max, bound) = run_healthy_frames(&mut app);
        let stats = *app.world().resource::<ImplicitSolveStats>();
        let steps = app.world().resource::<SimulationClock>().steps;
        eprintln!(
            "{scheme}: {steps} steps, KE max {e_max:.3e} J (bound {bound:.3e}), CG {} solves, \
             {:.2} iterations per solve, max {}, last relative residual {:.2e}",
            stats.solves,
            stats.mean_iterations(),
            stats.max_iterations,
            stats.last.rel_residual
        );
        assert!(steps >= 170, "steps {steps}");
        assert_eq!(stats.solves, steps);
        assert!(stats.last.rel_residual <= 1e-8);
        assert!(e_max <= bound, "KE {e_max} > {bound}");
        // The cube has landed and is slowing down (the solve does act).
        let m = measure(app.world_mut());
        assert!(m.max_speed < 0.5, "max speed {}", m.max_speed);
    }
    let mut app = syrup_cube(Scheme::Gs4Explicit);
    for _ in 0..5 {
        app.update();
    }
    let f = failure(&app).expect("explicit GS4 at 10× its viscous limit must be stopped");
    eprintln!("explicit GS4: {f}");
    assert!(f.suggested_dt > 0.0);
}

/// The GS4 semi-implicit solve with the particle-consistent FLIP update (whose
/// transfer-consistent predictor is explicit in the predictor rate) stays stable far beyond the
/// explicit viscous limit: the syrup cube at 20× and 50× the limit (θ·8ν/Δx² = 13 and 33)
/// runs 0.1 s without a failure and with its kinetic energy bounded by the initial one plus
/// gravity's work. These steps (1.2e-3 and 2.9e-3 s) also exceed the sound limit of the
/// explicit pressure (7.1e-4 s), which this slow syrup tolerates: the grid-increment update runs
/// the 20× step bounded too. With the correction applied at every step (before
/// `TRANSFER_CORRECTION_MAX_STIFFNESS`) the run was stopped with a kinetic-energy blow-up at
/// step 4 (20×) and step 1 (40×).
#[test]
fn particle_gs4_implicit_viscosity_is_stable_far_beyond_the_explicit_limit() {
    for factor in [20.0, 50.0] {
        let mut app = syrup_cube_with(Scheme::Gs4SemiImplicit, FlipUpdate::ParticleGs4, factor);
        let (e_max, bound) = run_healthy_frames(&mut app);
        eprintln!("{factor}× the explicit limit: KE max {e_max:.3e} J (bound {bound:.3e})");
        assert!(e_max <= bound, "{factor}×: KE {e_max} > {bound}");
    }
}

/// A CG solve that cannot converge (2 iterations allowed, relative residual 1e-12 asked) stops
/// the run at its first step with a diagnostic naming the solve, the iterations, the residual
/// and what to change; nothing panics and the particles stay finite.
#[test]
fn cg_failure_stops_the_run_with_a_diagnostic() {
    let mut app = syrup_cube(Scheme::BackwardEulerViscous);
    app.world_mut()
        .resource_mut::<MpmConfig>()
        .integrator
        .viscous_solver = CgParams {
        rel_tol: 1e-12,
        max_iters: 2,
        ..Default::default()
    };
    app.update();
    let f = failure(&app).expect("the solve cannot converge in 2 iterations");
    let text = f.to_string();
    eprintln!("{text}");
    assert_eq!(f.quantity, "viscous solve");
    assert_eq!(f.step, 0);
    assert!(
        f.value > 1e-12 && f.value.is_finite(),
        "residual {}",
        f.value
    );
    for needle in [
        "after 2 conjugate-gradient iterations",
        "max_iters",
        "Suggested fix",
    ] {
        assert!(text.contains(needle), "`{needle}` missing: {text}");
    }
    for (_, x, v) in state(&mut app) {
        assert!(x.is_finite() && v.is_finite());
    }
}

/// With implicit viscosity the adaptive step is set by advection and sound only: on the syrup
/// cube, the first adaptive Δt of the implicit schemes is far above the explicit one, which
/// the viscous limit binds.
#[test]
fn implicit_viscosity_drops_the_viscous_time_step_limit() {
    let mut dts = Vec::new();
    for scheme in [
        Scheme::Gs4Explicit,
        Scheme::BackwardEulerViscous,
        Scheme::Gs4SemiImplicit,
    ] {
        let mut app = syrup_cube(scheme);
        app.world_mut().resource_mut::<MpmConfig>().time_step.mode = TimeStepMode::Adaptive;
        app.update();
        assert_healthy(&app);
        let c = app.world().resource::<SimulationClock>();
        let m = c.maxima;
        eprintln!(
            "{scheme}: predicted limit {:.3e} s, ν max {:.3e} m²/s",
            c.predicted_limit, m.kinematic_viscosity
        );
        dts.push((c.predicted_limit, m.kinematic_viscosity));
    }
    // Explicit: the viscous term binds ([2c/(Ω Δx) + 8ν/(z Δx²)]⁻¹ < 5.83e-5 s).
    assert!(dts[0].0 < 5.9e-5 && dts[0].1 > 0.06);
    // Implicit: sound only, √2 Δx/(2c) (GS4) and 2 Δx/(2c) (BE), with c ≥ c₀ = 5 m/s.
    for (limit, nu) in &dts[1..] {
        assert_eq!(*nu, 0.0);
        assert!(*limit > 10.0 * dts[0].0, "{limit}");
    }
    assert!(
        dts[1].0 > dts[2].0,
        "BE (Ω = 2) allows more than GS4 (Ω = √2)"
    );
}

// ---------------------------------------------------------------------------------------------
// Scene file, command line, determinism.

fn scene_text(integrator: &str) -> String {
    format!(
        r#"Scene(
    domain: (min: (0, 0, 0), max: (1, 1, 1)),
    dx: 0.05,
    duration: 0.1,
    frame_rate: 30,
    integrator: {integrator},
    materials: [(name: "water", density: 1000, sound_speed: 20)],
    bodies: [
        (material: "water", shape: Box(min: (0.1, 0.1, 0.1), max: (0.3, 0.3, 0.3))),
    ],
)
"#
    )
}

fn parse(text: &str) -> Result<treacle::scene::Scene, treacle::scene::SceneError> {
    treacle::scene::parse_scene_str(text, Path::new("test.ron"), Path::new("scenes"))
}

/// `integrator: (scheme: …, viscous_solver: (…))` in a scene; the default keeps GS4; bad
/// values name the field and its line.
#[test]
fn scene_file_selects_the_scheme() {
    let s = parse(&scene_text("()")).unwrap();
    assert_eq!(s.config.integrator.scheme, Scheme::Gs4Explicit);
    assert_eq!(s.config.integrator.flip_update, FlipUpdate::ParticleGs4);
    let s = parse(&scene_text(
        "(scheme: BackwardEulerViscous, viscous_solver: (rel_tol: 1e-6, max_iters: 50))",
    ))
    .unwrap();
    assert_eq!(s.config.integrator.scheme, Scheme::BackwardEulerViscous);
    assert_eq!(s.config.integrator.viscous_solver.rel_tol, 1e-6);
    assert_eq!(s.config.integrator.viscous_solver.max_iters, 50);
    let s = parse(&scene_text(
        "(scheme: Gs4SemiImplicit, flip_update: GridIncrement)",
    ))
    .unwrap();
    assert_eq!(s.config.integrator.scheme, Scheme::Gs4SemiImplicit);
    assert_eq!(s.config.integrator.flip_update, FlipUpdate::GridIncrement);
    let e = parse(&scene_text("(viscous_solver: (rel_tol: -1))")).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("integrator.viscous_solver.rel_tol"), "{msg}");
    assert!(msg.contains("test.ron:6"), "{msg}");
    let e = parse(&scene_text("(scheme: Euler)")).unwrap_err();
    assert!(e.to_string().contains("Euler"), "{e}");
    for k in Scheme::ALL {
        assert_eq!(k.cli_name().parse::<Scheme>(), Ok(k));
    }
    assert!("rk4".parse::<Scheme>().is_err());
}

const BIN: &str = env!("CARGO_BIN_EXE_treacle");

fn run_cli(out: &Path, args: &[&str]) -> String {
    let o = Command::new(BIN)
        .args(["run", "scenes/coiling_1.ron", "--frames", "1", "--out"])
        .arg(out)
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(
        o.status.success(),
        "{args:?}: {stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    stdout
}

/// `treacle run --integrator backward-euler|gs4-implicit` on Coiling 1 (8 320 particles, so the
/// gather and the slab scatter of the operator run in parallel with 2 threads): the particle
/// file after one frame is byte-identical with 1 and 2 threads, and the summary reports the CG
/// iterations.
#[test]
fn implicit_solve_is_deterministic_across_thread_counts() {
    for integrator in ["backward-euler", "gs4-implicit"] {
        let dir = scratch(integrator);
        let (t1, t2) = (dir.join("t1"), dir.join("t2"));
        let out = run_cli(&t1, &["--threads", "1", "--integrator", integrator]);
        eprint!("{integrator}: {out}");
        assert!(out.contains("cg_iterations_per_solve="), "{out}");
        run_cli(&t2, &["--threads", "2", "--integrator", integrator]);
        let a = std::fs::read(t1.join("frame_00001.ply")).unwrap();
        let b = std::fs::read(t2.join("frame_00001.ply")).unwrap();
        assert!(
            a == b,
            "{integrator}: frames differ between 1 and 2 threads"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
