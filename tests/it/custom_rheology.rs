//! The Giesekus model of `examples/custom_rheology.rs` (a model the crate does not ship, added
//! through the public API only), tested at particle level against known limits and in an App.
//!
//! The example file is included as a module, so the test runs exactly the example's code.
#[path = "../../examples/custom_rheology.rs"]
#[allow(dead_code)]
mod custom;

use crate::common::{self, material, shear};
use custom::{Giesekus, GiesekusStress};
use glam::DMat3;
use treacle::prelude::*;
use treacle::rheology::su2021_unified::PolymerStress;
use treacle::rheology::tensor::frobenius_norm;

/// The states of [`common::drive`] under constant L from the model's initial state.
fn drive<M: Rheology>(
    model: &M,
    material: &FluidMaterial,
    l: Mat3,
    dt: f64,
    steps: usize,
) -> Vec<M::State> {
    let mut out = Vec::with_capacity(steps + 1);
    common::drive(
        model,
        material,
        model.initial_state(),
        |_| l,
        dt,
        steps,
        |_, s| out.push(s.clone()),
    );
    out
}

/// α = 0 reduces the Giesekus model to UCM / Oldroyd-B: the start-up of simple shear
/// (γ̇ = 1, λ = 1, η_p = μ = 1, F_v = 0) matches the crate's [Su21] Oldroyd-B model step by
/// step (same GS4-1 scheme, same implicit relaxation stiffness 1/λ: to round-off), and at
/// T = 2 its error against the closed form σ_xy = η_pγ̇(1 − e^{−t/λ}),
/// σ_xx = 2η_pλγ̇²[1 − e^{−t/λ}(1 + t/λ)] is the number ALGORITHM §9 S1 quotes for η_σ = 1,
/// to every printed digit: 3.477e−3, 8.573e−4, 2.129e−4, 5.304e−5 for Δt = 0.1 … 0.0125.
#[test]
fn zero_mobility_is_oldroyd_b() {
    let m = material(1.0, 0.0);
    let giesekus = Giesekus {
        relaxation_time: 1.0,
        mobility: 0.0,
    };
    let oldroyd = Su2021Unified::oldroyd_b(1.0);
    let quotes = [
        (0.1, 3.477e-3, 0.5e-6),
        (0.05, 8.573e-4, 0.5e-7),
        (0.025, 2.129e-4, 0.5e-7),
        (0.0125, 5.304e-5, 0.5e-8),
    ];
    for (dt, quoted, half_digit) in quotes {
        let steps = (2.0f64 / dt).round() as usize;
        let g: Vec<GiesekusStress> = drive(&giesekus, &m, shear(1.0), dt, steps);
        let o: Vec<PolymerStress> = drive(&oldroyd, &m, shear(1.0), dt, steps);
        for (a, b) in g.iter().zip(&o) {
            assert!(
                frobenius_norm(a.value - b.value) <= 1e-13 * (1.0 + frobenius_norm(b.value)),
                "Giesekus(α = 0) {} vs Oldroyd-B {}",
                a.value,
                b.value
            );
        }
        let s = g.last().unwrap().value;
        let t: f64 = 2.0;
        let error = (s.y_axis.x - (1.0 - (-t).exp()))
            .abs()
            .max((s.x_axis.x - 2.0 * (1.0 - (-t).exp() * (1.0 + t))).abs());
        println!("Δt = {dt}: S1 error {error:.4e} (ALGORITHM §9 S1: {quoted:.3e})");
        assert!(
            (error - quoted).abs() <= half_digit,
            "Δt = {dt}: error {error:e}, quoted {quoted:e}"
        );
        // UCM: no second normal stress.
        assert!(s.y_axis.y.abs() <= 1e-12 && s.z_axis.z.abs() <= 1e-12);
    }
}

/// α > 0: the start-up of simple shear tends to the closed-form steady state of the Giesekus
/// fluid (Bird, Armstrong & Hassager, Dynamics of Polymeric Liquids vol. 1):
///
/// ```text
/// χ² = (√(1 + 16α(1−α)Wi²) − 1)/(8α(1−α)Wi²),   f = (1 − χ)/(1 + (1 − 2α)χ),   Wi = λγ̇
/// η/η_p = (1 − f)²/(1 + (1 − 2α)f),   Ψ₁/(η_pλ) = 2f(1 − αf)/(Wi²α(1 − f)),   Ψ₂/(η_pλ) = −f/Wi²
/// ```
/// (α = 0.3, Wi = 3: η/η_p = 0.34820, Ψ₁/η_pλ = 0.38367, Ψ₂/η_pλ = −0.040886). After 30λ the
/// transient is below e⁻²⁰; with Δt = 10⁻³λ the second-order time error is ≈ 10⁻⁶ relative, so
/// 10⁻⁵ is the tolerance.
#[test]
fn steady_shear_matches_closed_form() {
    let (lambda, alpha, rate, mu) = (1.0, 0.3, 3.0, 2.0);
    let giesekus = Giesekus {
        relaxation_time: lambda,
        mobility: alpha,
    };
    let m = material(mu as f32, 0.0);
    let eta_p = mu;
    let dt = 1e-3;
    let states = drive(&giesekus, &m, shear(rate as f32), dt, (30.0 / dt) as usize);
    let s = states.last().unwrap().value;
    let wi = lambda * rate;
    let chi = (((1.0 + 16.0 * alpha * (1.0 - alpha) * wi * wi).sqrt() - 1.0)
        / (8.0 * alpha * (1.0 - alpha) * wi * wi))
        .sqrt();
    let f = (1.0 - chi) / (1.0 + (1.0 - 2.0 * alpha) * chi);
    let eta = eta_p * (1.0 - f).powi(2) / (1.0 + (1.0 - 2.0 * alpha) * f);
    let psi1 = eta_p * lambda * 2.0 * f * (1.0 - alpha * f) / (wi * wi * alpha * (1.0 - f));
    let psi2 = -eta_p * lambda * f / (wi * wi);
    let measured = [
        s.y_axis.x / rate,
        (s.x_axis.x - s.y_axis.y) / (rate * rate),
        (s.y_axis.y - s.z_axis.z) / (rate * rate),
    ];
    let expected = [eta, psi1, psi2];
    println!(
        "Giesekus steady shear (η, Ψ₁, Ψ₂): measured {measured:.6?}, closed form {expected:.6?}"
    );
    for (what, (a, b)) in ["η", "Ψ₁", "Ψ₂"].iter().zip(measured.iter().zip(expected)) {
        assert!(
            (a / b - 1.0).abs() <= 1e-5,
            "{what}: {a} vs closed form {b}"
        );
    }
    // Shear thinning: η < η_p for α > 0.
    assert!(eta < 0.5 * eta_p);
}

/// The example's App (a Giesekus block dropped 0.1 m onto the floor, built with the public API
/// only) runs 15 frames (0.25 s; it lands after √(2·0.1/g) = 0.14 s) without failure or NaN,
/// the block falls, and the impact builds up polymer stress.
#[test]
fn app_runs_without_nan() {
    let (mut app, liquid) = custom::demo_app();
    let (_, _, top0) = custom::summary(&mut app);
    for _ in 0..15 {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            panic!("simulation failed: {f}");
        }
    }
    let world = app.world_mut();
    let mut q = world.query::<(&Position, &MaterialId, &GiesekusStress)>();
    let mut n = 0;
    for (x, m, tau) in q.iter(world) {
        assert!(x.0.is_finite() && tau.value.is_finite() && tau.rate.is_finite());
        assert_eq!(*m, liquid);
        assert_eq!(tau.rate_increment, DMat3::ZERO, "committed");
        n += 1;
    }
    assert_eq!(n, 1000);
    let (tau, lo, hi) = custom::summary(&mut app);
    println!("after 0.25 s: max |τ| = {tau:.3} Pa, y in [{lo:.4}, {hi:.4}] m (top was {top0:.4})");
    assert!(hi < top0 - 0.02, "the block falls (top {top0} → {hi})");
    assert!(tau > 0.0, "polymer stress builds up");
}

/// A model defined outside the crate is named in a RON scene after the app registers it: the
/// scene's block gives the same particles, bit for bit, as the same set-up built in code (the
/// scene's sampled positions, `RheologyPlugin::<Giesekus>` and `attach_model`), and the
/// nozzle's particles carry the model's state (its initializer is registered by the plugin).
#[test]
fn scene_file_names_the_custom_model_and_its_nozzle_particles_carry_it() {
    use bevy_ecs::prelude::*;
    let scene = custom::load_scene().unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.rheology.len(), 1);
    assert_eq!(scene.rheology[0].1.name(), "Giesekus");
    let model = scene.rheology[0]
        .1
        .downcast_ref::<Giesekus>()
        .unwrap()
        .clone();
    assert_eq!(model.mobility, 0.3);
    // The default registry (the CLI's) does not know the model: a located error names it.
    let err = treacle::scene::load_scene(&custom::scene_path())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("Giesekus") && err.contains("custom_rheology.ron:"),
        "{err}"
    );

    let frames = 6;
    let mut from_file = treacle::runner::scene_app(&scene);
    // The same block in code: no emitter, so compare the block alone by removing the nozzle.
    let mut block_only = scene.clone();
    block_only.emitters.clear();
    let mut from_file_block = treacle::runner::scene_app(&block_only);
    let liquid = scene.rheology[0].0;
    let body = &scene.particles[0];
    let mut in_code =
        treacle::app::headless_app_with(scene.config.clone(), scene.materials.clone(), |app| {
            app.add_plugins(RheologyPlugin::<Giesekus>::default().with(liquid, model.clone()));
        });
    treacle::scene::spawn_particles(
        in_code.world_mut(),
        &body.positions,
        body.velocity,
        scene.config.gravity,
        body.particle_volume,
        scene.materials.get(liquid),
        liquid,
    );
    attach_model::<Giesekus>(in_code.world_mut(), liquid).unwrap();
    for _ in 0..frames {
        from_file.update();
        from_file_block.update();
        in_code.update();
    }
    fn bits(app: &mut bevy_app::App) -> Vec<(Entity, [u32; 3], [u64; 9])> {
        let world = app.world_mut();
        let mut q = world.query_filtered::<(Entity, &Position, &GiesekusStress), With<Particle>>();
        let mut v: Vec<_> = q
            .iter(world)
            .map(|(e, x, t)| {
                (
                    e,
                    x.0.to_array().map(f32::to_bits),
                    t.value.to_cols_array().map(f64::to_bits),
                )
            })
            .collect();
        v.sort_by_key(|r| r.0);
        v
    }
    let a = bits(&mut from_file_block);
    let b = bits(&mut in_code);
    assert_eq!(a.len(), body.positions.len());
    assert!(
        a == b,
        "the scene file's block differs from the same block built in code"
    );
    assert!(
        a.iter()
            .any(|r| r.2.iter().any(|&s| f64::from_bits(s) != 0.0)),
        "the model must have built up a polymer stress"
    );
    // With the nozzle: every particle, emitted ones included, carries the state.
    let world = from_file.world_mut();
    let all = world
        .query_filtered::<(), With<Particle>>()
        .iter(world)
        .count();
    let with_state = world
        .query_filtered::<(), (With<Particle>, With<GiesekusStress>)>()
        .iter(world)
        .count();
    assert!(
        all > body.positions.len(),
        "the nozzle must have emitted ({all} particles)"
    );
    assert_eq!(
        with_state, all,
        "emitted particles without the Giesekus state"
    );
}
