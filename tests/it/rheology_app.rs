//! App-level tests of the rheology plugin: Newtonian particles carry no model state and cost
//! no model work; a viscoelastic block attached through the public API runs; the failure
//! policy covers model output; and ALGORITHM §9 M4 (a shear wave in a UCM medium travels at
//! √(G₀/ρ)).
use crate::common;

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use bevy_app::App;
use bevy_ecs::prelude::*;
use bevy_ecs::system::RunSystemOnce;
use common::*;
use treacle::prelude::*;
use treacle::rheology::su2021_unified::{PolymerStress, Su2021Unified};
use treacle::rheology::{
    AttachError, Rheology, RheologyCommandsExt, RheologyContext, RheologyOutput, RheologyPlugin,
    RheologyTable, attach_model,
};

/// A test-only model that counts its evaluations and commits (and can return a NaN stress).
/// In a scene file only `nan` can be given (the counters start at 0).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
struct CountingModel {
    #[serde(skip)]
    evaluations: Arc<AtomicUsize>,
    #[serde(skip)]
    commits: Arc<AtomicUsize>,
    nan: bool,
}

impl PartialEq for CountingModel {
    /// Same parameters (the counters are not parameters).
    fn eq(&self, other: &Self) -> bool {
        self.nan == other.nan
    }
}

#[derive(Component, Clone, Default)]
struct CountingState;

impl Rheology for CountingModel {
    const NAME: &'static str = "Counting";

    type State = CountingState;

    fn evaluate(&self, _ctx: &RheologyContext, _state: &mut CountingState) -> RheologyOutput {
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        let mut out = RheologyOutput::default();
        if self.nan {
            out.stress.x_axis.x = f32::NAN;
        }
        out
    }

    fn commit(&self, _ctx: &RheologyContext, _state: &mut CountingState) {
        self.commits.fetch_add(1, Ordering::Relaxed);
    }
}

/// An app like `headless_app`, with extra plugins added before `finish` (plugins cannot be
/// added after it, so `headless_app` itself cannot take rheology plugins).
fn app_with_plugins(config: MpmConfig, materials: Materials, add: impl FnOnce(&mut App)) -> App {
    let mut app = App::new();
    app.insert_resource(config).insert_resource(materials);
    app.add_plugins(MpmPlugins);
    add(&mut app);
    app.finish();
    app.cleanup();
    app
}

fn box_config() -> MpmConfig {
    MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.4),
        dx: 0.02,
        frame_dt: 0.01,
        ..Default::default()
    }
}

fn spawn_block(app: &mut App, min: Vec3, max: Vec3, h: f32, material: MaterialId) -> usize {
    spawn_moving_block(app, min, max, h, material, Vec3::ZERO)
}

fn spawn_moving_block(
    app: &mut App,
    min: Vec3,
    max: Vec3,
    h: f32,
    material: MaterialId,
    velocity: Vec3,
) -> usize {
    let rho0 = app.world().resource::<Materials>().get(material).density;
    let g = app.world().resource::<MpmConfig>().gravity;
    let batch: Vec<ParticleBundle> = lattice(min, max, h)
        .into_iter()
        .map(|x| ParticleBundle::new(x, velocity, g, h * h * h, rho0, material))
        .collect();
    let n = batch.len();
    app.world_mut().spawn_batch(batch);
    n
}

fn count_with<C: Component>(app: &mut App) -> usize {
    let world = app.world_mut();
    world
        .query_filtered::<(), (With<Particle>, With<C>)>()
        .iter(world)
        .count()
}

/// (a) A Newtonian-only scene with the rheology plugins added: no particle carries a model
/// state, the model is never evaluated or committed (its systems do not run: the counting
/// model's counters stay 0 although its material has a table entry), and the material cannot
/// get the XPP state by accident (no table entry → `attach_model` refuses).
#[test]
fn newtonian_scene_has_no_model_state_and_no_model_work() {
    let counting = CountingModel::default();
    let mut materials = Materials::default();
    let water = materials.add(FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01));
    let model = counting.clone();
    let mut app = app_with_plugins(box_config(), materials, move |app| {
        app.add_plugins(RheologyPlugin::<Su2021Unified>::default());
        app.add_plugins(RheologyPlugin::<CountingModel>::default().with(water, model));
    });
    let n = spawn_block(&mut app, Vec3::splat(0.1), Vec3::splat(0.2), 0.01, water);
    for _ in 0..3 {
        app.update();
    }
    assert_healthy(&app);
    let steps = app.world().resource::<SimulationClock>().steps;
    assert!(steps >= 3 && n > 0);
    assert_eq!(count_with::<PolymerStress>(&mut app), 0);
    assert_eq!(count_with::<CountingState>(&mut app), 0);
    assert_eq!(counting.evaluations.load(Ordering::Relaxed), 0);
    assert_eq!(counting.commits.load(Ordering::Relaxed), 0);
    let err = attach_model::<Su2021Unified>(app.world_mut(), water).unwrap_err();
    assert!(matches!(err, AttachError::NoModel { .. }), "{err}");
    assert_eq!(count_with::<PolymerStress>(&mut app), 0);
}

/// (b) An Oldroyd-B block (F_v = 0.1, μ = 10 Pa·s, λ_b = 0.1 s → G₀ = 90 Pa) hits the floor at
/// 1 m/s next to a Newtonian block at rest, for 5 frames in an App with `RheologyPlugin<Su2021Unified>`: the run stays
/// healthy, exactly the polymer particles carry `PolymerStress`, their stress becomes non-zero
/// and stays finite, and the wave-speed data includes the modulus. A counting model attached
/// from a system (`commands.attach_model`) is evaluated and committed exactly once per
/// particle per step (+1 evaluation and commit for the start-up rate evaluation).
#[test]
fn oldroyd_b_block_runs_in_an_app() {
    let mut materials = Materials::default();
    let water = materials.add(FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01));
    let polymer = materials.add(FluidMaterial {
        local_fraction: 0.1,
        ..FluidMaterial::newtonian("polymer", 1000.0, 20.0, 10.0)
    });
    let counting = CountingModel::default();
    let model = counting.clone();
    let mut app = app_with_plugins(box_config(), materials, move |app| {
        app.add_plugins(
            RheologyPlugin::<Su2021Unified>::default().with(polymer, Su2021Unified::oldroyd_b(0.1)),
        );
        app.add_plugins(RheologyPlugin::<CountingModel>::default().with(polymer, model));
    });
    let n_polymer = spawn_moving_block(
        &mut app,
        Vec3::new(0.05, 0.02, 0.1),
        Vec3::new(0.15, 0.12, 0.2),
        0.01,
        polymer,
        Vec3::new(0.0, -1.0, 0.0),
    );
    let n_water = spawn_block(
        &mut app,
        Vec3::new(0.25, 0.05, 0.1),
        Vec3::new(0.35, 0.15, 0.2),
        0.01,
        water,
    );
    assert_eq!(
        attach_model::<Su2021Unified>(app.world_mut(), polymer).unwrap(),
        n_polymer
    );
    // Attaching twice adds nothing.
    assert_eq!(
        attach_model::<Su2021Unified>(app.world_mut(), polymer).unwrap(),
        0
    );
    app.world_mut()
        .run_system_once(move |mut commands: Commands| {
            commands.attach_model::<CountingModel>(polymer);
        })
        .unwrap();
    assert_eq!(count_with::<CountingState>(&mut app), n_polymer);
    for _ in 0..5 {
        app.update();
        assert_healthy(&app);
    }
    assert_eq!(count_with::<PolymerStress>(&mut app), n_polymer);
    let mats = app.world().resource::<Materials>().clone();
    let world = app.world_mut();
    let mut q = world.query::<(
        &MaterialId,
        Option<&PolymerStress>,
        &StabilityData,
        &PredictedDensity,
    )>();
    let mut max_stress = 0.0f64;
    for (m, s, stab, rho) in q.iter(world) {
        if *m == water {
            assert!(s.is_none());
            continue;
        }
        let s = s.unwrap();
        let v = s.value.to_cols_array();
        assert!(v.iter().all(|x| x.is_finite()));
        max_stress = v.iter().fold(max_stress, |a, x| a.max(x.abs()));
        // c² = c_Tait² + 4/3 (G₀ + ‖σ‖₂)/ρ̃ with G₀ = 90 Pa.
        let extra = stab.wave_speed_sq - mats.get(*m).sound_speed_sq(rho.value);
        assert!(extra >= 0.999 * 4.0 / 3.0 * 90.0 / rho.value, "{extra}");
    }
    eprintln!("max |σᴺᴸ| in the polymer block after 5 frames: {max_stress:.3e} Pa");
    assert!(max_stress > 1.0, "the polymer stress stayed ≈ 0");
    let steps = app.world().resource::<SimulationClock>().steps as usize;
    let expect = n_polymer * (steps + 1);
    assert_eq!(counting.evaluations.load(Ordering::Relaxed), expect);
    assert_eq!(counting.commits.load(Ordering::Relaxed), expect);
    assert_eq!(n_water + n_polymer, state(&mut app).len());
}

/// Failure policy: a model that returns a non-finite stress stops the run with a report naming
/// the particle and the quantity, and the table/parameter errors of `attach_model` name the
/// problem.
#[test]
fn non_finite_model_output_is_reported() {
    let mut materials = Materials::default();
    let goo = materials.add(FluidMaterial::newtonian("goo", 1000.0, 20.0, 1.0));
    let model = CountingModel {
        nan: true,
        ..Default::default()
    };
    let mut app = app_with_plugins(box_config(), materials, |app| {
        app.add_plugins(RheologyPlugin::<CountingModel>::default().with(goo, model));
    });
    spawn_block(&mut app, Vec3::splat(0.1), Vec3::splat(0.15), 0.01, goo);
    attach_model::<CountingModel>(app.world_mut(), goo).unwrap();
    app.update();
    let f = failure(&app).expect("a NaN stress must stop the run");
    eprintln!("{f}");
    assert_eq!(f.quantity, "rheology stress");
    assert!(f.entity.is_some() && f.value.is_nan());

    // Parameters are validated against the material on attach: a UCM needs F_v = 0.
    app.world_mut()
        .resource_mut::<RheologyTable<CountingModel>>()
        .remove(goo);
    let err = attach_model::<CountingModel>(app.world_mut(), goo).unwrap_err();
    assert!(matches!(err, AttachError::NoModel { .. }));
    assert!(matches!(
        attach_model::<Su2021Unified>(app.world_mut(), goo),
        Err(AttachError::NoTable { .. })
    ));
    let mut table = RheologyTable::<Su2021Unified>::default();
    table.insert(goo, Su2021Unified::ucm(1.0));
    app.world_mut().insert_resource(table);
    let err = attach_model::<Su2021Unified>(app.world_mut(), goo).unwrap_err();
    eprintln!("{err}");
    assert!(matches!(err, AttachError::InvalidParameters { .. }));
    assert!(err.to_string().contains("local_fraction"));
}

/// Plugin order does not matter: the model plugin added before `MpmPlugins` creates the step
/// schedule with its sets, and the core's systems join it (the model's evaluate system is still
/// there after the core plugin is added).
#[test]
fn plugin_before_core_keeps_its_systems() {
    let mut app = App::new();
    app.add_plugins(RheologyPlugin::<Su2021Unified>::default());
    app.add_plugins(MpmPlugins);
    app.finish();
    app.update();
    let schedules = app.world().resource::<bevy_ecs::schedule::Schedules>();
    let names: Vec<String> = schedules
        .get(treacle::schedule::MpmStep)
        .unwrap()
        .systems()
        .unwrap()
        .map(|(_, s)| s.name().to_string())
        .collect();
    assert!(
        names.iter().any(|n| n.contains("evaluate_model")),
        "{names:?}"
    );
    assert!(
        names.iter().any(|n| n.contains("particle_to_grid")),
        "{names:?}"
    );
}

/// Amplitude of the mode sin(ky) x̂ in the particle velocities (least squares).
fn shear_mode(app: &mut App, k: f32) -> f64 {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (_, x, v) in state(app) {
        let phi = (k * x.y).sin();
        num += (v.x * phi) as f64;
        den += (phi * phi) as f64;
    }
    num / den
}

/// M4: a small shear perturbation v = A sin(ky) x̂ (A = 0.01 m/s: 1 % strain, linear regime)
/// in a UCM medium (F_v = 0, μ = 100 Pa·s, λ_b = 100 s → G₀ = 1 Pa, ρ = 1 kg/m³), periodic in
/// x and y (L = 1 m, Δx = L/32, thin slip slab in z), pure FLIP. For Δt ≪ λ_b the medium is an
/// elastic solid: the mode is a standing shear wave, A cos(ωt), ω = k√(G₀/ρ − 1/(4λ_b²k²))
/// = k·(1 − 6e−7). The phase speed ω/k is measured from two consecutive zero crossings of the
/// mode amplitude (frames every 0.01 s, linear interpolation; error O(0.01³)) and must be
/// within 5 % of √(G₀/ρ) = 1 m/s. Expected deviation: the B-spline operator's (kΔx)²/4 ≈ 1 %
/// (M3 measures the same operator's κ² error), the time error is O((ωΔt)²) < 1e−4.
#[test]
fn m4_ucm_shear_wave_speed() {
    let dx = 1.0f32 / 32.0;
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(1.0, 1.0, 2.0 * dx),
        dx,
        gravity: Vec3::ZERO,
        frame_dt: 0.01,
        integrator: IntegratorConfig {
            flip: 1.0,
            ..Default::default()
        },
        time_step: TimeStepConfig {
            max_dt: 0.01,
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
    let (rho, g0, lambda) = (1.0f32, 1.0f32, 100.0f32);
    let mut materials = Materials::default();
    let ucm = materials.add(FluidMaterial {
        local_fraction: 0.0,
        ..FluidMaterial::newtonian("ucm", rho, 4.0, g0 * lambda)
    });
    let mut app = app_with_plugins(config.clone(), materials, |app| {
        app.add_plugins(
            RheologyPlugin::<Su2021Unified>::default().with(ucm, Su2021Unified::ucm(lambda as f64)),
        );
    });
    let k = 2.0 * std::f32::consts::PI;
    let h = dx / 2.0;
    let batch: Vec<ParticleBundle> = lattice(Vec3::ZERO, config.domain_max, h)
        .into_iter()
        .map(|x| {
            let v = Vec3::new(0.01 * (k * x.y).sin(), 0.0, 0.0);
            ParticleBundle::new(x, v, Vec3::ZERO, h * h * h, rho, ucm)
        })
        .collect();
    app.world_mut().spawn_batch(batch);
    attach_model::<Su2021Unified>(app.world_mut(), ucm).unwrap();
    let mut samples = vec![(0.0f64, shear_mode(&mut app, k))];
    let mut crossings = vec![];
    while crossings.len() < 2 {
        app.update();
        assert_healthy(&app);
        let t = app.world().resource::<SimulationClock>().time;
        let a = shear_mode(&mut app, k);
        let (t0, a0) = *samples.last().unwrap();
        if a0 != 0.0 && a0.signum() != a.signum() {
            crossings.push(t0 + (t - t0) * a0 / (a0 - a));
        }
        samples.push((t, a));
        assert!(t < 2.0, "no two zero crossings within 2 s: {samples:?}");
    }
    let omega = std::f64::consts::PI / (crossings[1] - crossings[0]);
    let speed = omega / k as f64;
    let clock = app.world().resource::<SimulationClock>();
    eprintln!(
        "M4: zero crossings at {crossings:.5?} s → wave speed {speed:.5} m/s vs √(G₀/ρ) = 1 (error {:.2} %), {} steps, last Δt {:.2e} s",
        100.0 * (speed - 1.0),
        clock.steps,
        clock.frame_dt_max
    );
    assert!((speed - 1.0).abs() < 0.05, "wave speed {speed}");
}
