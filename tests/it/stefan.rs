//! The two-phase Stefan problem (Neumann's similarity solution) through the whole MPM app:
//! a slab of solid at T_s = 0 at rest against a wall held at T_w = 1, melting at T_m = ½ with
//! latent heat L/c = 1, equal diffusivities k = 0.1 m²/s in both phases (ρc = 1). The front
//! is at X(t) = 2λ√(kt) with λ the root of
//!
//! L λ √π = (T_w − T_m) e^{−λ²}/erf λ − (T_m − T_s) e^{−λ²}/erfc λ.
//!
//! The melting band (`latent_width` ε, the Gaussian δ_ε of the apparent heat capacity) is set
//! as a number of cells at the front: 2ε = n · Δx · |∂T/∂x|, with the liquid-side gradient of the
//! similarity solution at the last time measured.
use crate::common;
use treacle::prelude::*;
use treacle::thermal::{Temperature, ThermalConfig, ThermalMaterial, WallTemperatures};

const K: f64 = 0.1;
const T_W: f64 = 1.0;
const T_M: f64 = 0.5;
const T_S: f64 = 0.0;
const LATENT: f64 = 1.0;
const FRAME_DT: f64 = 0.5;
const FRAMES: usize = 4;

/// λ of Neumann's solution (bisection on the Stefan condition).
fn neumann_lambda() -> f64 {
    let f = |l: f64| {
        let e = (-l * l).exp();
        (T_W - T_M) * e / libm::erf(l)
            - (T_M - T_S) * e / libm::erfc(l)
            - LATENT * l * std::f64::consts::PI.sqrt()
    };
    let (mut lo, mut hi) = (1e-6, 3.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if f(mid) > 0.0 { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

/// Liquid-side temperature gradient at the front at time t.
fn front_gradient(lambda: f64, t: f64) -> f64 {
    (T_W - T_M) * (-lambda * lambda).exp()
        / (libm::erf(lambda) * (std::f64::consts::PI * K * t).sqrt())
}

/// Solid-side temperature gradient (magnitude) at the front at time t.
fn solid_gradient(lambda: f64, t: f64) -> f64 {
    (T_M - T_S) * (-lambda * lambda).exp()
        / (libm::erfc(lambda) * (std::f64::consts::PI * K * t).sqrt())
}

/// Runs the slab at spacing `dx` with a band of `cells` cells and returns per frame (t, melted
/// length, its exact value). The melted length is X_φ = Σ φ(Tₚ) Vₚ / A, φ = ½(1 + erf((T −
/// T_m)/ε)) the melted fraction: an integral, so it does not step with the particle layers as
/// the T_m isotherm of a narrow band does (the particles of a melting layer sit on the plateau
/// together). Across a band narrow against the front's distance, T is linear on each side with
/// the gradients g_l, g_s of Neumann's solution, so X_φ = X + (ε/(2√π))(1/g_s − 1/g_l) exactly
/// for that profile (0.6 % of X for a one-cell band at Δx = 1/64); that is the exact value.
fn stefan_slab(cells: f64, dx: f32) -> Vec<(f64, f64, f64)> {
    let lambda = neumann_lambda();
    let t_end = FRAME_DT * FRAMES as f64;
    let eps = 0.5 * cells * dx as f64 * front_gradient(lambda, t_end);
    let width = 4.0 * dx;
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(1.0, width, width),
        dx,
        gravity: Vec3::ZERO,
        frame_dt: FRAME_DT,
        time_step: TimeStepConfig {
            mode: TimeStepMode::Fixed(1e-3),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut materials = Materials::default();
    let slab = materials.add(FluidMaterial::newtonian("slab", 1000.0, 1.0, 0.0));
    let heat = ThermalConfig {
        materials: vec![(
            slab,
            ThermalMaterial::fourier(K, T_S as f32)
                .with_melting(T_M as f32)
                .with_latent_heat(LATENT as f32, eps as f32),
        )],
        walls: WallTemperatures {
            x_min: Some(T_W as f32),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut app = common::heated_slab_app(&config, materials, heat, slab);
    let h = dx / 2.0;
    let area = (width * width) as f64;
    let volume = (h * h * h) as f64;
    let mut out = Vec::new();
    for _ in 0..FRAMES {
        app.update();
        assert!(!app.world().resource::<SimulationStatus>().failed());
        let t = app.world().resource::<SimulationClock>().time;
        let world = app.world_mut();
        let mut q = world.query::<&Temperature>();
        let melted: f64 = q
            .iter(world)
            .map(|temp| 0.5 * (1.0 + libm::erf((temp.value as f64 - T_M) / eps)) * volume)
            .sum();
        let front = 2.0 * lambda * (K * t).sqrt();
        let bias = eps / (2.0 * std::f64::consts::PI.sqrt())
            * (1.0 / solid_gradient(lambda, t) - 1.0 / front_gradient(lambda, t));
        out.push((t, melted / area, front + bias));
    }
    out
}

/// The front of a narrow melting band (one and two cells) follows Neumann's solution within
/// 5 % at Δx = 1/64 (the front is 9–19 cells from the wall over the run).
///
/// Before the particle enthalpy update the front ran 16–20 % fast at Δx = 1/32 with a
/// one-cell band (10 % with two, 8 % with four): the node capacity, evaluated at the
/// predictor, missed the band when a node crossed it within one step. With it the 1/32 front
/// no longer depends much on the band (+6.4 to +7.1 % for one cell, +2.7 to +5.6 % for two to
/// eight); what remains is the discretisation, measured with a two-cell band at t = 2 s:
/// +13.6 %, +5.6 %, +1.8 % at Δx = 1/16, 1/32, 1/64 (ratios 2.4 and 3.1). The bound is the
/// issue's 5 %; at 1/64 the measured errors are below 2.5 %, so a regression of the band
/// handling (the 1/32 error alone moved by 10 points) fails it.
#[test]
fn stefan_front_follows_neumann_with_a_narrow_band() {
    println!("λ = {:.6}", neumann_lambda());
    for cells in [1.0, 2.0] {
        let run = stefan_slab(cells, 1.0 / 64.0);
        for (t, x, exact) in &run {
            println!(
                "band {cells} cells, t = {t:.2}: front {x:.5}, Neumann {exact:.5}, error {:+.2} %",
                100.0 * (x / exact - 1.0)
            );
        }
        for (t, x, exact) in &run {
            assert!(
                (x / exact - 1.0).abs() < 0.05,
                "band {cells} cells, t = {t}: front {x} against {exact}"
            );
        }
    }
}
