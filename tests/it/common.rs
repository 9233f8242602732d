//! Helpers shared by the whole-step tests: build an app, fill boxes, measure.
#![allow(dead_code)]
use bevy_app::App;
use bevy_ecs::prelude::*;
use treacle::app::headless_app;
use treacle::prelude::*;

/// Cell-centred lattice positions filling `[min, max]` with spacing `h`.
pub fn lattice(min: Vec3, max: Vec3, h: f32) -> Vec<Vec3> {
    let n = ((max - min) / h).round().as_ivec3();
    let mut out = Vec::with_capacity((n.x * n.y * n.z) as usize);
    for i in 0..n.x {
        for j in 0..n.y {
            for k in 0..n.z {
                out.push(min + (glam::IVec3::new(i, j, k).as_vec3() + Vec3::splat(0.5)) * h);
            }
        }
    }
    out
}

/// An app with one material and the given particles (volume h³ each, velocity from `vel`).
pub fn app_with(
    config: MpmConfig,
    material: FluidMaterial,
    positions: &[Vec3],
    h: f32,
    vel: impl Fn(Vec3) -> Vec3,
) -> App {
    let mut materials = Materials::default();
    let rho0 = material.density;
    let id = materials.add(material);
    let g = config.gravity;
    let mut app = headless_app(config, materials);
    spawn_particles(&mut app, positions, h, g, rho0, id, vel);
    app
}

/// Spawns particles of material `id` (rest density `rho0`, volume h³ each) at `positions`,
/// velocity from `vel`, acceleration `g`.
pub fn spawn_particles(
    app: &mut App,
    positions: &[Vec3],
    h: f32,
    g: Vec3,
    rho0: f32,
    id: MaterialId,
    vel: impl Fn(Vec3) -> Vec3,
) {
    let batch: Vec<ParticleBundle> = positions
        .iter()
        .map(|x| ParticleBundle::new(*x, vel(*x), g, h * h * h, rho0, id))
        .collect();
    app.world_mut().spawn_batch(batch);
}

/// All particle positions and velocities, in query order.
pub fn state(app: &mut App) -> Vec<(Entity, Vec3, Vec3)> {
    let world = app.world_mut();
    let mut q = world.query_filtered::<(Entity, &Position, &Velocity), With<Particle>>();
    q.iter(world).map(|(e, x, v)| (e, x.0, v.0)).collect()
}

/// The failure, if the run stopped.
pub fn failure(app: &App) -> Option<FailureReport> {
    app.world().resource::<SimulationStatus>().failure.clone()
}

/// Panics with the failure report if the run stopped.
pub fn assert_healthy(app: &App) {
    if let Some(f) = failure(app) {
        panic!("simulation failed: {f}");
    }
}

/// The crate root (scenes, assets and tests/data are found from here).
pub fn crate_dir() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// A fresh, empty scratch directory for one test, under Cargo's per-target temp dir and named
/// after the calling test module and `name`, so that names never collide across modules.
#[track_caller]
pub fn scratch(name: &str) -> std::path::PathBuf {
    let module = std::path::Path::new(std::panic::Location::caller().file())
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("treacle-it-{}", std::process::id()))
        .join(module)
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A material with ρ₀ = 1 (J̃ = 1 at ρ̃ = 1), sound speed 1, viscosity μ and local fraction F_v
/// (η_p = (1 − F_v)μ), for driving a rheology model outside the step.
pub fn material(viscosity: f32, local_fraction: f32) -> FluidMaterial {
    FluidMaterial {
        local_fraction,
        ..FluidMaterial::newtonian("test", 1.0, 1.0, viscosity)
    }
}

/// L of simple shear v = (γ̇ y, 0, 0): L_xy = ∂v_x/∂y = γ̇ (column y, row x).
pub fn shear(rate: f32) -> treacle::math::Mat3 {
    let mut l = treacle::math::Mat3::ZERO;
    l.y_axis.x = rate;
    l
}

/// Drives `model` like the MPM step: start-up rate evaluation, then `steps` steps of `dt` with
/// GS4 (0.5, 0) in f64 and L evaluated at t_{n+W₁}. `observe(n, state)` sees the state at t_n
/// (n = 0 after the start-up). Returns the final state.
pub fn drive<M: treacle::rheology::Rheology>(
    model: &M,
    material: &FluidMaterial,
    initial: M::State,
    l: impl Fn(f64) -> treacle::math::Mat3,
    dt: f64,
    steps: usize,
    observe: impl FnMut(usize, &M::State),
) -> M::State {
    drive_with(model, material, initial, l, dt, steps, false, observe)
}

/// [`drive`] with the mechanics of a first-order scheme (`first_order`: the coefficients'
/// `first_order_mechanics`, L evaluated at t_n) or of GS4 (`false`, as [`drive`]).
#[expect(
    clippy::too_many_arguments,
    reason = "drive's arguments and the scheme"
)]
pub fn drive_with<M: treacle::rheology::Rheology>(
    model: &M,
    material: &FluidMaterial,
    initial: M::State,
    l: impl Fn(f64) -> treacle::math::Mat3,
    dt: f64,
    steps: usize,
    first_order: bool,
    mut observe: impl FnMut(usize, &M::State),
) -> M::State {
    use treacle::rheology::{FirstOrderCoefficients, RheologyContext};
    let p = treacle::gs4::Gs4Params::default();
    let mut state = initial;
    let start = RheologyContext::new(
        l(0.0),
        1.0,
        material,
        FirstOrderCoefficients::rate_evaluation(),
        true,
    );
    model.evaluate(&start, &mut state);
    model.commit(&start, &mut state);
    observe(0, &state);
    let c = FirstOrderCoefficients::step(&p, dt).with_first_order_mechanics(first_order);
    let at = if first_order { 0.0 } else { p.w1 };
    for n in 0..steps {
        let t = n as f64 * dt + at * dt;
        let ctx = RheologyContext::new(l(t), 1.0, material, c, false);
        model.evaluate(&ctx, &mut state);
        model.commit(&ctx, &mut state);
        observe(n + 1, &state);
    }
    state
}

/// The `treacle` binary of this build.
pub const BIN: &str = env!("CARGO_BIN_EXE_treacle");

/// Runs `treacle ARGS` in the crate directory and waits for it.
pub fn treacle(args: &[&str]) -> std::process::Output {
    std::process::Command::new(BIN)
        .args(args)
        .current_dir(crate_dir())
        .output()
        .expect("the treacle binary runs")
}

/// The largest x among particles that have another particle within `radius` (spray filter).
pub fn front_x(positions: &[Vec3], radius: f32) -> f32 {
    let cell = |p: Vec3| (p / radius).floor().as_ivec3();
    let mut grid: std::collections::HashMap<glam::IVec3, Vec<usize>> =
        std::collections::HashMap::new();
    for (i, p) in positions.iter().enumerate() {
        grid.entry(cell(*p)).or_default().push(i);
    }
    let mut order: Vec<usize> = (0..positions.len()).collect();
    order.sort_by(|&a, &b| positions[b].x.total_cmp(&positions[a].x));
    let r2 = radius * radius;
    for &i in &order {
        let p = positions[i];
        let c = cell(p);
        let mut found = false;
        'search: for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(list) = grid.get(&(c + glam::IVec3::new(dx, dy, dz))) else {
                        continue;
                    };
                    if list
                        .iter()
                        .any(|&j| j != i && positions[j].distance_squared(p) <= r2)
                    {
                        found = true;
                        break 'search;
                    }
                }
            }
        }
        if found {
            return p.x;
        }
    }
    panic!("no particle has a neighbour within {radius} m");
}

/// A headless app with `heat` whose domain `config.domain_min..domain_max` is filled with
/// particles of `material` at rest, 2 per cell and axis (spacing Δx/2, density 1000 kg/m³):
/// the heat slabs of `heat.rs` (H5) and `stefan.rs`.
pub fn heated_slab_app(
    config: &MpmConfig,
    materials: Materials,
    heat: treacle::thermal::ThermalConfig,
    material: MaterialId,
) -> App {
    let mut app = treacle::app::headless_app_with(config.clone(), materials, |app| {
        app.add_plugins(treacle::thermal::ThermalPlugin::new(heat));
    });
    let h = config.dx / 2.0;
    let batch: Vec<ParticleBundle> = lattice(config.domain_min, config.domain_max, h)
        .iter()
        .map(|x| ParticleBundle::new(*x, Vec3::ZERO, Vec3::ZERO, h * h * h, 1000.0, material))
        .collect();
    app.world_mut().spawn_batch(batch);
    app
}
