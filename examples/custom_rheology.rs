//! A rheology model the crate does not ship, added through the public API only: the Giesekus
//! (1982) polymer fluid.
//!
//! ```text
//! τ + λ τ^∇ + (αλ/η_p) τ·τ = 2η_p D        (upper-convected derivative τ^∇, ALGORITHM §0.1)
//! ```
//! with relaxation time λ \[s\], mobility α ∈ \[0, 1\] and polymer viscosity η_p = (1 − F_v)μ
//! from the material (the core already applies the solvent part 2F_vμD, as for \[Su21\]'s
//! split). α = 0 is Oldroyd-B (UCM for F_v = 0). Written as the Lagrangian ODE the MPM step
//! integrates per particle (ALGORITHM §2.8, erratum E6: one combined increment):
//!
//! ```text
//! Dτ/Dt = H(τ, L) = Lτ + τLᵀ + 2G D − τ/λ − (α/(λG)) τ·τ,   G = η_p/λ
//! ```
//! and integrated with the GS4-1 value/rate scheme handed to every model in
//! [`FirstOrderCoefficients`] (linearly implicit relaxation with the scalar stiffness
//! K = (1 + 2α‖τ‖₂/G)/λ, choice D8).
//!
//! Run: `cargo run --release --example custom_rheology`. It drops a block of a Giesekus liquid
//! onto the floor and prints the largest polymer stress and the block's height per frame; then
//! it loads `examples/custom_rheology.ron`, a scene file that names the model (a block and a
//! nozzle pouring the same liquid), with the registry of an app that added
//! `RheologyPlugin::<Giesekus>`, and runs it. `tests/it/custom_rheology.rs` includes this file and
//! checks the model against closed forms and the scene against the same set-up built in code.
use bevy_app::App;
use bevy_ecs::prelude::*;
use glam::DMat3;
use serde::{Deserialize, Serialize};
use treacle::app::headless_app_with;
use treacle::prelude::*;
use treacle::rheology::tensor::{spectral_norm, sym};
use treacle::rheology::{InvalidParameter, RheologyContext, RheologyOutput};

/// Parameters of the Giesekus model (one value per material in `RheologyTable<Giesekus>`). In
/// a scene file: `model: Giesekus((relaxation_time: 0.1, mobility: 0.3))`, once the app
/// registered the model (adding `RheologyPlugin::<Giesekus>` does).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Giesekus {
    /// Relaxation time λ \[s\] > 0.
    pub relaxation_time: f64,
    /// Mobility α ∈ \[0, 1\] (0: Oldroyd-B; physical range 0 – 0.5).
    pub mobility: f64,
}

/// Per-particle state: the polymer stress τ, its material rate τ̇ (a GS4-1 pair) and the step's
/// rate increment Δτ̇ (written by `evaluate`, consumed by `commit`).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct GiesekusStress {
    /// τ at t_n \[Pa\].
    pub value: DMat3,
    /// Dτ/Dt at t_n \[Pa/s\].
    pub rate: DMat3,
    /// Δτ̇ of the step being run \[Pa/s\].
    pub rate_increment: DMat3,
}

impl Default for GiesekusStress {
    /// Stress-free (by hand: glam's `DMat3::default()` is the identity).
    fn default() -> Self {
        Self {
            value: DMat3::ZERO,
            rate: DMat3::ZERO,
            rate_increment: DMat3::ZERO,
        }
    }
}

impl Giesekus {
    /// The modulus G = η_p/λ = (1 − F_v)μ/λ \[Pa\] for `material`.
    pub fn modulus(&self, material: &FluidMaterial) -> f64 {
        (1.0 - material.local_fraction as f64) * material.viscosity as f64 / self.relaxation_time
    }

    /// The rate H(τ, L) \[Pa/s\] and the relaxation stiffness K \[1/s\] at modulus `g` \[Pa\].
    pub fn rate(&self, tau: DMat3, l: DMat3, g: f64) -> (DMat3, f64) {
        let inv_lambda = 1.0 / self.relaxation_time;
        let a = self.mobility;
        let h = l * tau + tau * l.transpose() + 2.0 * g * sym(l)
            - inv_lambda * tau
            - (a * inv_lambda / g) * (tau * tau);
        (h, (1.0 + 2.0 * a * spectral_norm(tau) / g) * inv_lambda)
    }
}

impl Rheology for Giesekus {
    const NAME: &'static str = "Giesekus";

    type State = GiesekusStress;

    fn evaluate(&self, ctx: &RheologyContext, state: &mut GiesekusStress) -> RheologyOutput {
        let c = ctx.coefficients;
        let g = self.modulus(ctx.material);
        let tau_hat = state.value + (c.w1l4 * c.dt) * state.rate;
        let (h, k) = self.rate(tau_hat, ctx.velocity_gradient.as_dmat3(), g);
        let delta = sym(h - state.rate) * (1.0 / (c.w1l6 + c.w2l5 * c.dt * k));
        state.rate_increment = delta;
        let tau_tilde = tau_hat + (c.w2l5 * c.dt) * delta;
        RheologyOutput {
            stress: tau_tilde.as_mat3(),
            // The upper-convected term stiffens with stress (ALGORITHM §7.2); the relaxation is
            // implicit, so it sets no step limit.
            shear_modulus: (g + spectral_norm(tau_tilde)) as f32,
            ..RheologyOutput::default()
        }
    }

    fn commit(&self, ctx: &RheologyContext, state: &mut GiesekusStress) {
        let c = ctx.coefficients;
        state.value += (c.l4 * c.dt) * state.rate + (c.l5 * c.dt) * state.rate_increment;
        state.rate += state.rate_increment;
        state.rate_increment = DMat3::ZERO;
    }

    fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        if !(self.relaxation_time.is_finite() && self.relaxation_time > 0.0) {
            e.push(InvalidParameter {
                field: "relaxation_time",
                constraint: "must be a finite number > 0 s",
            });
        }
        if !(0.0..=1.0).contains(&self.mobility) {
            e.push(InvalidParameter {
                field: "mobility",
                constraint: "must lie in [0, 1]",
            });
        }
        if !(material.viscosity > 0.0 && material.local_fraction < 1.0) {
            e.push(InvalidParameter {
                field: "viscosity",
                constraint: "(1 − local_fraction)·viscosity of the material must be > 0 (the polymer viscosity η_p)",
            });
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

/// A 0.4 m box with a 0.1 m cube of a Giesekus liquid (μ = 20 Pa·s, 10 % solvent, λ = 0.1 s,
/// α = 0.3) at rest 0.1 m above the floor, built with the public API only. Returns the app
/// and the liquid's material id.
pub fn demo_app() -> (App, MaterialId) {
    let mut materials = Materials::default();
    let liquid = materials.add(FluidMaterial {
        local_fraction: 0.1,
        ..FluidMaterial::newtonian("giesekus liquid", 1000.0, 20.0, 20.0)
    });
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.4),
        dx: 0.02,
        frame_dt: 1.0 / 60.0,
        ..Default::default()
    };
    let model = Giesekus {
        relaxation_time: 0.1,
        mobility: 0.3,
    };
    let gravity = config.gravity;
    let mut app = headless_app_with(config, materials, |app| {
        app.add_plugins(RheologyPlugin::<Giesekus>::default().with(liquid, model));
    });
    let h = 0.01; // 2 particles per cell and axis
    let mut batch = Vec::new();
    for i in 0..10 {
        for j in 0..10 {
            for k in 0..10 {
                let x = Vec3::new(0.15, 0.1, 0.15)
                    + (Vec3::new(i as f32, j as f32, k as f32) + 0.5) * h;
                batch.push(ParticleBundle::new(
                    x,
                    Vec3::ZERO,
                    gravity,
                    h * h * h,
                    1000.0,
                    liquid,
                ));
            }
        }
    }
    app.world_mut().spawn_batch(batch);
    attach_model::<Giesekus>(app.world_mut(), liquid).expect("valid Giesekus parameters");
    (app, liquid)
}

/// The largest ‖τ‖₂ \[Pa\] and the lowest and highest particle height \[m\].
pub fn summary(app: &mut App) -> (f64, f32, f32) {
    let world = app.world_mut();
    let mut q = world.query_filtered::<(&Position, &GiesekusStress), With<Particle>>();
    q.iter(world).fold(
        (0.0, f32::INFINITY, f32::NEG_INFINITY),
        |(s, lo, hi), (x, tau)| {
            (
                s.max(spectral_norm(tau.value)),
                lo.min(x.0.y),
                hi.max(x.0.y),
            )
        },
    )
}

/// The scene file of this example (`examples/custom_rheology.rs`'s sibling).
pub fn scene_path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/custom_rheology.ron")
}

/// Loads [`scene_path`] with the models of an app that registered `Giesekus` (by adding its
/// plugin), the way a game or a research tool would name its own model in scene files.
pub fn load_scene() -> Result<treacle::scene::Scene, treacle::scene::SceneError> {
    let mut app = App::new();
    app.add_plugins(RheologyPlugin::<Giesekus>::default());
    let registry = app.world().resource::<ModelRegistry>();
    treacle::scene::load_scene_with(&scene_path(), registry)
}

fn main() {
    let (mut app, _) = demo_app();
    println!("frame   t [s]   max |tau| [Pa]   y_min [m]   y_max [m]");
    for _ in 0..30 {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            eprintln!("simulation failed: {f}");
            std::process::exit(1);
        }
        let (frame, t) = {
            let c = app.world().resource::<SimulationClock>();
            (c.frame, c.time)
        };
        let (tau, lo, hi) = summary(&mut app);
        println!("{frame:5} {t:7.3} {tau:16.3} {lo:11.4} {hi:11.4}");
    }

    let scene = load_scene().unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(1);
    });
    let mut app = treacle::runner::scene_app(&scene);
    for _ in 0..10 {
        app.update();
    }
    let world = app.world_mut();
    let with_state = world
        .query_filtered::<&GiesekusStress, With<Particle>>()
        .iter(world)
        .count();
    let all = world
        .query_filtered::<(), With<Particle>>()
        .iter(world)
        .count();
    println!(
        "{}: {all} particles after 10 frames ({with_state} carry the Giesekus state, emitted ones included)",
        scene_path().display()
    );
}
