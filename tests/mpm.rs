//! Whole-step tests of ALGORITHM §9: M1 (free fall), M3 (viscous decay and the predicted
//! explicit limit), M5 (volume drift against c₀), M6 (friction on an incline, no bounce),
//! plus a headless App test and in-process determinism.
mod common;

use common::*;
use treacle::diagnostics::measure;
use treacle::prelude::*;

fn free_fall_config() -> MpmConfig {
    MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::ONE,
        dx: 0.05,
        gravity: Vec3::new(0.0, -9.81, 0.0),
        frame_dt: 0.02,
        ..Default::default()
    }
}

/// M1: stress-free free fall is exact: x(t) = x₀ + ½gt² (GS4 with a⁰ = g, identity 1.1).
/// Tolerance: f32 rounding of positions O(1) m over ~100 steps, 2e-5 m.
#[test]
fn m1_free_fall_is_exact() {
    let h = 0.025;
    let x0 = lattice(Vec3::new(0.4, 0.7, 0.4), Vec3::new(0.6, 0.9, 0.6), h);
    let water = FluidMaterial::newtonian("water", 1000.0, 20.0, 0.0);
    let mut app = app_with(free_fall_config(), water, &x0, h, |_| Vec3::ZERO);
    for _ in 0..10 {
        app.update();
    }
    assert_healthy(&app);
    let t = app.world().resource::<SimulationClock>().time;
    assert!((t - 0.2).abs() < 1e-12, "t = {t}");
    let steps = app.world().resource::<SimulationClock>().steps;
    assert!(steps > 10, "adaptive steps {steps}");
    let drop = 0.5 * 9.81 * t * t;
    for ((_, x, v), x0) in state(&mut app).iter().zip(&x0) {
        let expect = *x0 - Vec3::new(0.0, drop as f32, 0.0);
        assert!((*x - expect).length() < 2e-5, "{x} vs {expect}");
        assert!((v.y + 9.81 * t as f32).abs() < 1e-4, "v = {v}");
    }
}

/// M1 (second part): with an inconsistent start (a⁰ = 0, no start-up evaluation) the
/// acceleration error decays geometrically for ρ∞ < 1 (§2.14): after the transient the
/// particles accelerate at g.
#[test]
fn m1_inconsistent_start_decays() {
    let h = 0.025;
    let x0 = lattice(Vec3::new(0.4, 0.7, 0.4), Vec3::new(0.5, 0.8, 0.5), h);
    let mut cfg = free_fall_config();
    cfg.integrator.consistent_startup = false;
    cfg.time_step.mode = TimeStepMode::Fixed(1e-3);
    let water = FluidMaterial::newtonian("water", 1000.0, 20.0, 0.0);
    let mut app = app_with(cfg, water, &x0, h, |_| Vec3::ZERO);
    {
        let world = app.world_mut();
        let mut q = world.query::<&mut Acceleration>();
        for mut a in q.iter_mut(world) {
            a.0 = Vec3::ZERO;
        }
    }
    app.update();
    assert_healthy(&app);
    let world = app.world_mut();
    let mut q = world.query::<&Acceleration>();
    for a in q.iter(world) {
        assert!((a.0.y + 9.81).abs() < 1e-3, "a = {}", a.0);
    }
}

/// The viscous shear layer of ALGORITHM §9 M3: v = (A sin κy, 0, 0), κ = 2π/L, periodic in x
/// and y (thin slip slab in z). Linear Stokes mode; amplitude ∝ e^{−νκ²t}. The field is
/// divergence-free on the grid too, so no acoustic mode is excited.
fn shear_layer(dx: f32, dt_mode: TimeStepMode, nu: f32, c0: f32) -> bevy_app::App {
    let l = 1.0f32;
    let cfg = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(l, l, 2.0 * dx),
        dx,
        gravity: Vec3::ZERO,
        frame_dt: 0.05,
        integrator: IntegratorConfig {
            flip: 1.0,
            ..Default::default()
        },
        time_step: TimeStepConfig {
            mode: dt_mode,
            ..Default::default()
        },
        walls: DomainWalls {
            x_min: BoundaryCondition::Periodic,
            x_max: BoundaryCondition::Periodic,
            y_min: BoundaryCondition::Periodic,
            y_max: BoundaryCondition::Periodic,
            ..Default::default()
        },
        ..Default::default()
    };
    let h = dx / 2.0;
    let x0 = lattice(Vec3::ZERO, cfg.domain_max, h);
    let mat = FluidMaterial::newtonian("fluid", 1.0, c0, nu);
    let k = 2.0 * std::f32::consts::PI / l;
    app_with(cfg, mat, &x0, h, move |x| Vec3::new(0.01 * (k * x.y).sin(), 0.0, 0.0))
}

/// Amplitude of the shear mode in the particle velocities (least-squares projection onto
/// sin κy x̂).
fn mode_amplitude(app: &mut bevy_app::App) -> f64 {
    let k = 2.0 * std::f32::consts::PI;
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (_, x, v) in state(app) {
        let phi = (k * x.y).sin();
        num += (v.x * phi) as f64;
        den += (phi * phi) as f64;
    }
    num / den
}

/// M3: decay rate νκ² of the viscous shear layer. The quadratic B-spline operator
/// underestimates κ² by O((κΔx)²) (κΔx = 0.39 at Δx = L/16), so the rate must be within 5 %
/// at Δx = L/16 and converge (smaller error at L/32). Pure FLIP: no PIC damping.
#[test]
fn m3_viscous_decay_rate() {
    let nu = 0.02f32;
    let rate_exact = nu as f64 * (2.0 * std::f64::consts::PI).powi(2);
    let mut errors = vec![];
    for n in [16.0f32, 32.0] {
        let mut app = shear_layer(1.0 / n, TimeStepMode::Adaptive, nu, 2.0);
        let a0 = mode_amplitude(&mut app);
        for _ in 0..10 {
            app.update();
        }
        assert_healthy(&app);
        let t = app.world().resource::<SimulationClock>().time;
        let a1 = mode_amplitude(&mut app);
        let rate = -(a1 / a0).ln() / t;
        let rel = (rate - rate_exact).abs() / rate_exact;
        eprintln!("Δx = 1/{n}: amplitude decay rate {rate:.5} vs exact {rate_exact:.5} (rel. error {rel:.5})");
        errors.push(rel);
    }
    assert!(errors[0] < 0.05, "rate error at 1/16: {}", errors[0]);
    assert!(errors[1] < errors[0], "no convergence: {errors:?}");
}

/// M3 (limit): a fixed Δt at 0.9× the predicted explicit limit of §7.2 is stable; at 4× the
/// run is stopped by the monitor with a diagnostic (never NaN in the state it reports).
#[test]
fn m3_predicted_explicit_limit() {
    let nu = 0.02f32;
    let dx = 1.0f32 / 16.0;
    // Predicted combined limit [2c/(Ω_crit Δx) + 8ν/(z_crit Δx²)]⁻¹ for (0.5, 0).
    let gs4 = treacle::schedule::Gs4Constants::new(0.5, 0.0).unwrap();
    let c0 = 0.2f64;
    let limit = 1.0
        / (2.0 * c0 / (gs4.omega_crit * dx as f64)
            + 8.0 * nu as f64 / (gs4.z_crit * (dx as f64).powi(2)));
    let mut stable = shear_layer(dx, TimeStepMode::Fixed(0.9 * limit), nu, c0 as f32);
    let e0 = measure(stable.world_mut()).kinetic_energy;
    for _ in 0..10 {
        stable.update();
    }
    assert_healthy(&stable);
    assert!(measure(stable.world_mut()).kinetic_energy < e0);

    let mut unstable = shear_layer(dx, TimeStepMode::Fixed(4.0 * limit), nu, c0 as f32);
    for _ in 0..40 {
        unstable.update();
    }
    let f = failure(&unstable).expect("4× the predicted limit must be detected as unstable");
    eprintln!("{f}");
    assert!(f.suggested_dt > 0.0 && f.suggested_dt < 4.0 * limit);
}

/// A droplet (sphere) dropped on a slip floor; returns the largest relative volume change.
fn droplet_volume_drift(c0: f32) -> f64 {
    let dx = 0.01;
    let h = dx / 2.0;
    let cfg = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.2),
        dx,
        frame_dt: 0.01,
        ..Default::default()
    };
    let centre = Vec3::new(0.1, 0.1, 0.1);
    let x0: Vec<Vec3> = lattice(Vec3::splat(0.05), Vec3::splat(0.15), h)
        .into_iter()
        .filter(|x| (*x - centre).length() < 0.04)
        .collect();
    let mat = FluidMaterial::newtonian("liquid", 1000.0, c0, 1.0);
    let mut app = app_with(cfg, mat, &x0, h, |_| Vec3::new(0.0, -1.0, 0.0));
    let v0 = measure(app.world_mut()).volume;
    let mut drift = 0.0f64;
    for _ in 0..25 {
        app.update();
        assert_healthy(&app);
        let v = measure(app.world_mut()).volume;
        drift = drift.max((v / v0 - 1.0).abs());
    }
    drift
}

/// M5: weak compressibility — the volume error shrinks with the sound speed (Ma² scaling,
/// [Su21] Fig. 10): c₀ = 10 m/s must drift less than c₀ = 1 m/s, by well over an order of
/// magnitude (Ma² ratio 100).
#[test]
fn m5_volume_drift_decreases_with_sound_speed() {
    let slow = droplet_volume_drift(1.0);
    let fast = droplet_volume_drift(10.0);
    eprintln!("max |ΔV/V|: c0 = 1 → {slow:.4e}, c0 = 10 → {fast:.4e}");
    assert!(fast < slow / 10.0, "c0=10: {fast}, c0=1: {slow}");
}

fn incline(theta_deg: f32, mu_f: f32) -> bevy_app::App {
    let dx = 0.01;
    let h = dx / 2.0;
    let th = theta_deg.to_radians();
    let g = 9.81;
    let cfg = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(1.2, 0.2, 2.0 * dx),
        dx,
        gravity: Vec3::new(g * th.sin(), -g * th.cos(), 0.0),
        frame_dt: 0.01,
        walls: DomainWalls {
            y_min: BoundaryCondition::Friction(mu_f),
            ..Default::default()
        },
        ..Default::default()
    };
    let x0 = lattice(Vec3::new(0.05, 0.0, 0.0), Vec3::new(0.15, 0.05, 2.0 * dx), h);
    let mat = FluidMaterial::newtonian("block", 1000.0, 20.0, 20.0);
    app_with(cfg, mat, &x0, h, |_| Vec3::ZERO)
}

/// M6: a block sliding down a slope with Coulomb friction accelerates at
/// g(sin θ − μ_f cos θ) (momentum balance, whatever its deformation). Measured from the
/// centre-of-mass velocity between 0.1 s and 0.3 s; tolerance 5 % (pressure transient of the
/// weakly compressible block and the one-cell friction layer).
#[test]
fn m6_friction_on_incline() {
    let (theta, mu_f) = (30.0f32, 0.2f32);
    let mut app = incline(theta, mu_f);
    let com_v = |app: &mut bevy_app::App| {
        let m = measure(app.world_mut());
        let st = state(app);
        let n = st.len() as f32;
        let v: Vec3 = st.iter().map(|s| s.2).sum::<Vec3>() / n;
        (m, v)
    };
    for _ in 0..10 {
        app.update();
    }
    let (_, v1) = com_v(&mut app);
    for _ in 0..20 {
        app.update();
    }
    assert_healthy(&app);
    let (_, v2) = com_v(&mut app);
    let a = (v2.x - v1.x) / 0.2;
    let th = theta.to_radians();
    let expect = 9.81 * (th.sin() - mu_f * th.cos());
    eprintln!("incline acceleration {a:.4} vs {expect:.4}");
    assert!((a - expect).abs() < 0.05 * expect, "{a} vs {expect}");
}

/// M6 (no bounce, choice D5): a block at rest on a floor with friction larger than tan θ stays
/// at rest: its centre of mass never moves up (beyond the static compression settle of
/// ρg h/K ≈ 0.25 % of the height) and its speed stays below 1 mm/s after the settling.
#[test]
fn m6_resting_block_does_not_bounce() {
    let mut app = incline(0.0, 0.5);
    let y0 = measure(app.world_mut()).center_of_mass[1];
    let mut max_rise = f64::MIN;
    for frame in 0..40 {
        app.update();
        assert_healthy(&app);
        let m = measure(app.world_mut());
        max_rise = max_rise.max(m.center_of_mass[1] - y0);
        if frame > 20 {
            let st = state(&mut app);
            let v: Vec3 = st.iter().map(|s| s.2).sum::<Vec3>() / st.len() as f32;
            assert!(v.length() < 1e-3, "block drifts: {v}");
        }
    }
    eprintln!("max rise of the centre of mass: {max_rise:.3e} m");
    assert!(max_rise < 1e-5, "the block bounced: rise {max_rise}");
}

/// The plugin runs inside an ordinary App: each `update()` is one frame of `frame_dt`.
#[test]
fn headless_app_drives_the_plugin() {
    let h = 0.025;
    let x0 = lattice(Vec3::new(0.3, 0.05, 0.3), Vec3::new(0.5, 0.25, 0.5), h);
    let water = FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01);
    let mut app = app_with(free_fall_config(), water, &x0, h, |_| Vec3::ZERO);
    for i in 1..=5u64 {
        app.update();
        let clock = app.world().resource::<SimulationClock>();
        assert_eq!(clock.frame, i);
        assert!((clock.time - i as f64 * 0.02).abs() < 1e-12);
        assert!(clock.frame_steps >= 1);
    }
    assert_healthy(&app);
    assert_eq!(state(&mut app).len(), x0.len());
}

/// Same scene → bit-identical state (in one process; the CLI test covers thread counts).
#[test]
fn runs_are_bit_identical() {
    let run = || {
        let mut app = shear_layer(1.0 / 16.0, TimeStepMode::Adaptive, 0.05, 0.2);
        for _ in 0..3 {
            app.update();
        }
        state(&mut app)
            .into_iter()
            .map(|(_, x, v)| (x.to_array().map(f32::to_bits), v.to_array().map(f32::to_bits)))
            .collect::<Vec<_>>()
    };
    assert_eq!(run(), run());
}
