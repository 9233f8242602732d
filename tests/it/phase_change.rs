//! Phase change (ALGORITHM §4.1–4.2, choices D11, D12) and temperature-dependent viscosity
//! (§4.3, D13; \[Li\]'s μ₀e^{−dT}): test C1 of §9 (a particle crossing T_m switches from the
//! fluid to the neo-Hookean solid stress; with D12 a solidified blob has no memory of its
//! pre-melt shape, drop test), the Cross-WLF samples of §4.3, the temperature factor on the
//! stress and the Δt data, and the scene sections. Temperatures are set directly on the
//! particles (no heat solve needed).
use bevy_ecs::prelude::*;
use bevy_ecs::system::RunSystemOnce;
use glam::DMat3;
use treacle::app::headless_app_with;
use treacle::components::{
    CauchyStress, DeformationGradient, Particle, ParticleBundle, Position,
    PredictedDeformationGradient, PredictedDensity, StabilityData, VelocityGradient,
};
use treacle::failure::FailureCollector;
use treacle::prelude::*;
use treacle::sampling::{Lattice, sample_sphere};
use treacle::scene::parse_scene_str;
use treacle::thermal::components::{PhaseIndex, PredictedTemperature, Temperature};
use treacle::thermal::phase::{
    PhaseChange, PhaseChangePlugin, PhaseChangeTable, TemperatureViscosity,
    TemperatureViscosityTable, attach_phase_change, blend_phase_stress, cross_wlf_viscosity,
    cross_wlf_zero_shear,
};

const RHO0: f32 = 1000.0;
const MU: f32 = 2.0;

/// A world with one material and one particle in simple shear: L = γ̇ e_x⊗e_y, F̃ = I + γ e_x⊗e_y,
/// and the stress the core writes (−p I + 2μD with p = 0 at rest density).
fn shear_world(gamma_dot: f32, gamma: f32, t: f32) -> (World, Entity) {
    // The systems iterate in parallel; a bare World needs the task pool (an App's plugins
    // would set it up).
    bevy_tasks::ComputeTaskPool::get_or_init(bevy_tasks::TaskPool::default);
    let mut world = World::new();
    let mut materials = Materials::default();
    let id = materials.add(FluidMaterial::newtonian("melt", RHO0, 10.0, MU));
    world.insert_resource(materials);
    world.insert_resource(FailureCollector::default());
    let l = Mat3::from_cols(Vec3::ZERO, Vec3::new(gamma_dot, 0.0, 0.0), Vec3::ZERO);
    let d = 0.5 * (l + l.transpose());
    let f = Mat3::IDENTITY + Mat3::from_cols(Vec3::ZERO, Vec3::new(gamma, 0.0, 0.0), Vec3::ZERO);
    let e = world
        .spawn((
            Particle,
            id,
            PredictedDensity {
                value: RHO0,
                rate_increment: 0.0,
            },
            VelocityGradient(l),
            PredictedDeformationGradient(f),
            DeformationGradient(f),
            CauchyStress(2.0 * MU * d),
            StabilityData {
                wave_speed_sq: 100.0,
                kinematic_viscosity: MU / RHO0,
                relaxation_rate: 0.0,
            },
            Temperature {
                value: t,
                rate: 0.0,
            },
            PredictedTemperature(t),
            PhaseIndex(0.0),
        ))
        .id();
    (world, e)
}

fn blend(world: &mut World, e: Entity) -> (Mat3, f32, StabilityData) {
    world.run_system_once(blend_phase_stress).unwrap();
    let s = world.get::<CauchyStress>(e).unwrap().0;
    let i_s = world.get::<PhaseIndex>(e).unwrap().0;
    let stab = *world.get::<StabilityData>(e).unwrap();
    (s, i_s, stab)
}

/// C1 (§9): as the predicted temperature crosses T_m the shear stress switches from the fluid's
/// μγ̇ to the neo-Hookean solid's G_s γ (simple shear, det F = 1: σ_xy = G_s γ,
/// σ_xx − σ_yy = G_s γ²), and the phase index from 0 to 1. With a ramp ΔT_m the stress at T_m
/// is the average of the two.
#[test]
fn c1_particle_crossing_tm_switches_stress() {
    let (gamma_dot, gamma, g_s) = (3.0f32, 0.2f32, 500.0);
    let tm = 0.1;
    let fluid_xy = MU * gamma_dot; // 6 Pa
    let solid_xy = g_s as f32 * gamma; // 100 Pa
    println!("T̂        I_s   σ_xy [Pa]   σ_xx − σ_yy [Pa]");
    for (t, i_expect, xy_expect) in [
        (0.15f32, 0.0f32, fluid_xy),
        (0.1001, 0.0, fluid_xy),
        (0.1, 0.0, fluid_xy),
        (0.0999, 1.0, solid_xy),
        (0.05, 1.0, solid_xy),
    ] {
        let (mut world, e) = shear_world(gamma_dot, gamma, t);
        let mut table = PhaseChangeTable::default();
        table.0.insert(MaterialId(0), PhaseChange::new(tm, g_s));
        world.insert_resource(table);
        let (s, i_s, stab) = blend(&mut world, e);
        println!(
            "{t:<8} {i_s:>4} {:>10.4} {:>12.4}",
            s.y_axis.x,
            s.x_axis.x - s.y_axis.y
        );
        assert_eq!(i_s, i_expect, "T = {t}");
        assert!(
            (s.y_axis.x - xy_expect).abs() < 1e-3 * xy_expect,
            "T = {t}: {s}"
        );
        assert!((s.y_axis.x - s.x_axis.y).abs() < 1e-4, "symmetric");
        if i_s == 1.0 {
            assert!((s.x_axis.x - s.y_axis.y - g_s as f32 * gamma * gamma).abs() < 1e-2);
            // The trace is the (common) pressure: 0 at rest density.
            assert!((s.x_axis.x + s.y_axis.y + s.z_axis.z).abs() < 1e-3);
            // Stability: no explicit viscosity, the solid's shear wave.
            assert_eq!(stab.kinematic_viscosity, 0.0);
            assert!(stab.wave_speed_sq > 100.0 + 4.0 / 3.0 * g_s as f32 / RHO0 * 0.999);
        } else {
            assert!((s.x_axis.x - s.y_axis.y).abs() < 1e-4);
            assert_eq!(stab.kinematic_viscosity, MU / RHO0);
        }
    }
    // Smooth ramp: I_s = ½ at T_m, the deviators averaged.
    let (mut world, e) = shear_world(gamma_dot, gamma, tm);
    let mut table = PhaseChangeTable::default();
    table
        .0
        .insert(MaterialId(0), PhaseChange::new(tm, g_s).with_ramp(0.02));
    world.insert_resource(table);
    let (s, i_s, _) = blend(&mut world, e);
    assert!((i_s - 0.5).abs() < 1e-6, "{i_s}");
    assert!((s.y_axis.x - 0.5 * (fluid_xy + solid_xy)).abs() < 1e-3 * solid_xy);
}

/// Height (max − min y) and the mean ‖dev B̄‖ of the shape memory F of every particle.
fn shape(world: &mut World) -> (f32, f64) {
    let mut q = world.query_filtered::<(&Position, &DeformationGradient), With<Particle>>();
    let (mut lo, mut hi, mut dev, mut n) = (f32::MAX, f32::MIN, 0.0, 0);
    for (x, f) in q.iter(world) {
        lo = lo.min(x.0.y);
        hi = hi.max(x.0.y);
        let f = f.0.as_dmat3();
        let b = f * f.transpose() * f.determinant().powf(-2.0 / 3.0);
        let tr = (b.x_axis.x + b.y_axis.y + b.z_axis.z) / 3.0;
        let d = b - DMat3::from_diagonal(glam::DVec3::splat(tr));
        dev += (d.x_axis.length_squared() + d.y_axis.length_squared() + d.z_axis.length_squared())
            .sqrt();
        n += 1;
    }
    (hi - lo, dev / n as f64)
}

fn set_temperature(world: &mut World, t: f32) {
    let mut q = world.query::<(&mut Temperature, &mut PredictedTemperature)>();
    for (mut temp, mut pred) in q.iter_mut(world) {
        temp.value = t;
        pred.0 = t;
    }
}

/// Mean ‖σ_dev‖_F \[Pa\] over the particles.
fn mean_deviatoric_stress(world: &mut World) -> f64 {
    let mut q = world.query_filtered::<&CauchyStress, With<Particle>>();
    let (mut sum, mut n) = (0.0, 0);
    for s in q.iter(world) {
        let s = s.0.as_dmat3();
        let tr = (s.x_axis.x + s.y_axis.y + s.z_axis.z) / 3.0;
        let d = s - DMat3::from_diagonal(glam::DVec3::splat(tr));
        sum += (d.x_axis.length_squared() + d.y_axis.length_squared() + d.z_axis.length_squared())
            .sqrt();
        n += 1;
    }
    sum / n as f64
}

/// What [`drop_and_solidify`] measured.
#[derive(Debug)]
struct DropResult {
    /// Height when solidified \[m\].
    h0: f32,
    /// Mean ‖dev B̄‖ of the shape memory when solidified.
    memory: f64,
    /// Mean ‖σ_dev‖ \[Pa\] in the first solid step.
    stress: f64,
    /// Height 0.2 s later, or the failure that stopped the run (energy created).
    h1: Result<f32, String>,
}

/// A ball of melt dropped on a sticky floor spreads as a fluid for 0.3 s, then is solidified
/// (T set below T_m) and runs 0.2 s more. μ = 2 Pa·s: the spread pancake is settling smoothly
/// when it solidifies (kinetic energy 8e-6 J, ≈ 1 % of its peak, height 5.5 mm), so its
/// height then does not depend on the FLIP form (5.51 mm with `ParticleGs4`, 5.24 mm with
/// `GridIncrement`). With 0.5 Pa·s the sub-cell pancake was still collapsing at 0.3 s (8.0 →
/// 1.4 mm over the next 0.4 s) and its height at the moment of solidifying differed by 1.2 mm
/// (0.12Δx) between the two forms.
fn drop_and_solidify(reset_shape_memory: bool) -> DropResult {
    let mut materials = Materials::default();
    let melt = materials.add(FluidMaterial::newtonian("melt", RHO0, 5.0, 2.0));
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(0.12, 0.08, 0.12),
        dx: 0.01,
        frame_dt: 0.05,
        walls: treacle::config::DomainWalls {
            y_min: treacle::config::BoundaryCondition::Sticky,
            ..Default::default()
        },
        ..Default::default()
    };
    let g = config.gravity;
    let phase = PhaseChange {
        reset_shape_memory,
        ..PhaseChange::new(0.1, 3000.0)
    };
    let mut app = headless_app_with(config, materials, |app| {
        app.add_plugins(PhaseChangePlugin::default().with_phase_change(melt, phase));
    });
    let lattice = Lattice::new(Vec3::ZERO, 0.01, 2);
    let ball = sample_sphere(&lattice, Vec3::new(0.06, 0.04, 0.06), 0.025);
    let world = app.world_mut();
    world.spawn_batch(ball.positions.iter().map(|&p| {
        (
            ParticleBundle::new(p, Vec3::ZERO, g, ball.particle_volume, RHO0, melt),
            Temperature {
                value: 0.2,
                rate: 0.0,
            },
            PredictedTemperature(0.2),
        )
    }));
    assert_eq!(attach_phase_change(world, melt), ball.positions.len());
    for _ in 0..6 {
        app.update();
    }
    let status = app.world().resource::<SimulationStatus>();
    assert!(status.failure.is_none(), "{:?}", status.failure);
    let (h0, memory) = shape(app.world_mut());
    set_temperature(app.world_mut(), 0.0);
    // One short step: the stress of the freshly solidified material.
    let dt = 0.2 * app.world().resource::<SimulationClock>().next_dt;
    treacle::schedule::run_step(app.world_mut(), dt, false);
    let stress = mean_deviatoric_stress(app.world_mut());
    let mut h1 = Ok(0.0);
    for frame in 0..4 {
        app.update();
        let world = app.world_mut();
        if let Some(f) = &world.resource::<SimulationStatus>().failure {
            h1 = Err(f.to_string());
            break;
        }
        let (h, _) = shape(world);
        println!(
            "  reset {reset_shape_memory}: solid frame {frame}: height {:.2} mm",
            h * 1e3
        );
        h1 = Ok(h);
    }
    if h1.is_ok() {
        let mut q = app.world_mut().query::<&PhaseIndex>();
        assert!(q.iter(app.world()).all(|i| i.0 == 1.0), "all solid");
    }
    DropResult {
        h0,
        memory,
        stress,
        h1,
    }
}

/// C1 with D12 (drop test): while fluid the shape memory is reset every step, so when the
/// spread ball solidifies its F is isotropic (‖dev B̄‖ = 0), the new solid is unstressed and
/// keeps the spread shape. Without the reset F remembers the ball: the solid starts with a
/// large elastic stress that springs it back (mechanical energy out of nothing, which the
/// energy monitor may stop as a blow-up).
#[test]
fn c1_d12_solidified_blob_has_no_memory_of_its_pre_melt_shape() {
    let with = drop_and_solidify(true);
    let without = drop_and_solidify(false);
    println!("D12 reset: {with:?}");
    println!("no reset:  {without:?}");
    assert!(
        (with.h0 - without.h0).abs() < 1e-6,
        "same fluid phase either way"
    );
    assert!(with.h0 < 0.04, "the ball spread (height {})", with.h0);
    assert!(
        with.memory < 1e-5,
        "no shape memory with D12: {}",
        with.memory
    );
    assert!(
        without.memory > 0.3,
        "the pre-melt shape is remembered without D12"
    );
    assert!(
        without.stress > 10.0 * with.stress,
        "the remembered shape stresses the new solid: {} vs {} Pa",
        without.stress,
        with.stress
    );
    let h1 = with.h1.clone().expect("the D12 solid runs healthily");
    assert!(
        (h1 / with.h0 - 1.0).abs() < 0.1,
        "the solid keeps its spread shape: {} → {h1}",
        with.h0
    );
    match &without.h1 {
        Ok(k1) => assert!(
            k1 / without.h0 - 1.0 > 0.2,
            "without D12 it springs back: {k1}"
        ),
        Err(f) => assert!(f.contains("energy"), "{f}"),
    }
}

/// §4.3 samples of the Cross-WLF zero-shear viscosity (D13 reading, T in °C) and the clamps.
#[test]
fn cross_wlf_samples_and_clamps() {
    let mu0 = |t| cross_wlf_zero_shear(3.32e9, 20.194, 51.6, 100.0, t);
    println!(
        "μ0(200) = {:.4e}, μ0(150) = {:.4e}, μ0(100) = {:.4e}",
        mu0(200.0),
        mu0(150.0),
        mu0(100.0)
    );
    assert!((mu0(200.0) / 5.45e3 - 1.0).abs() < 2e-3);
    assert!((mu0(150.0) / 1.6e5 - 1.0).abs() < 0.05);
    assert_eq!(mu0(100.0), 3.32e9);
    // T_eff = max(T, D₂): below D₂ (and at the WLF pole T = 48.4) μ₀ stays D₁.
    assert_eq!(mu0(48.4), 3.32e9);
    assert_eq!(mu0(-20.0), 3.32e9);
    assert_eq!(mu0(f64::NAN), 3.32e9);
    // Cross thinning with τ* = 5.66e3 Pa, n = 0.25: μ = μ₀/(1 + (μ₀γ̇/τ*)^0.75).
    let mu = cross_wlf_viscosity(3.32e9, 20.194, 51.6, 100.0, 5.66e3, 0.25, 200.0, 10.0);
    let x: f64 = mu0(200.0) * 10.0 / 5.66e3;
    assert!((mu - mu0(200.0) / (1.0 + x.powf(0.75))).abs() < 1e-9 * mu);
    assert!(mu < mu0(200.0));
    // γ̇ → 0 gives μ₀.
    let mu_zero = cross_wlf_viscosity(3.32e9, 20.194, 51.6, 100.0, 5.66e3, 0.25, 200.0, 0.0);
    assert_eq!(mu_zero, mu0(200.0));
    // As a factor on a material of viscosity 1e3 Pa·s, capped at μ_max = 1e6 Pa·s.
    let law = TemperatureViscosity::cross_wlf_su2021().with_max_viscosity(1e6);
    assert!((law.factor(200.0, 0.0, 1e3) - mu0(200.0) / 1e3).abs() < 1e-9);
    assert_eq!(law.factor(100.0, 0.0, 1e3), 1e3, "capped at μ_max/μ");
}

/// \[Li\]'s μ₀e^{−dT} (μ₀ = 1000 Pa·s, d = 0.1) scales the fluid deviatoric stress (whatever
/// rheology wrote it) and the viscous Δt data; the pressure is untouched.
#[test]
fn exponential_temperature_factor_scales_stress_and_viscous_limit() {
    let law = TemperatureViscosity::exponential(0.1);
    assert!((law.factor(0.0, 0.0, 1000.0) - 1.0).abs() < 1e-15);
    assert!((1000.0 * law.factor(10.0, 0.0, 1000.0) - 367.879_441).abs() < 1e-5);
    for t in [0.0f32, 5.0, 20.0] {
        let (mut world, e) = shear_world(3.0, 0.0, t);
        // An extra (model) shear stress of 1 Pa on top of 2μD.
        world.get_mut::<CauchyStress>(e).unwrap().0 += Mat3::from_cols(
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::ZERO,
        );
        let before = world.get::<CauchyStress>(e).unwrap().0;
        let mut table = TemperatureViscosityTable::default();
        table.0.insert(MaterialId(0), law.clone());
        world.insert_resource(table);
        let (s, i_s, stab) = blend(&mut world, e);
        let phi = (-0.1 * t as f64).exp() as f32;
        assert_eq!(i_s, 0.0, "no phase change: PhaseIndex untouched");
        assert!(
            (s.y_axis.x - phi * before.y_axis.x).abs() < 1e-5,
            "T = {t}: {s}"
        );
        assert!((stab.kinematic_viscosity - phi * MU / RHO0).abs() < 1e-9);
        println!(
            "T = {t}: φ = {phi:.5}, μ = {:.2} Pa·s, σ_xy {} → {}",
            1000.0 * phi,
            before.y_axis.x,
            s.y_axis.x
        );
    }
}

/// A hot drop with μ₀e^{−dT} spreads faster than the same drop cold (App run, the factor read
/// from the particles' predicted temperature).
#[test]
fn hot_drop_spreads_faster_than_cold_drop() {
    let spread = |t: f32| {
        let mut materials = Materials::default();
        let m = materials.add(FluidMaterial::newtonian("honey", RHO0, 5.0, 20.0));
        let config = MpmConfig {
            domain_min: Vec3::ZERO,
            domain_max: Vec3::new(0.12, 0.08, 0.12),
            dx: 0.01,
            frame_dt: 0.05,
            ..Default::default()
        };
        let g = config.gravity;
        let mut app = headless_app_with(config, materials, |app| {
            app.add_plugins(
                PhaseChangePlugin::default()
                    .with_temperature_viscosity(m, TemperatureViscosity::exponential(0.1)),
            );
        });
        let lattice = Lattice::new(Vec3::ZERO, 0.01, 2);
        let ball = sample_sphere(&lattice, Vec3::new(0.06, 0.03, 0.06), 0.025);
        app.world_mut().spawn_batch(ball.positions.iter().map(|&p| {
            (
                ParticleBundle::new(p, Vec3::ZERO, g, ball.particle_volume, RHO0, m),
                Temperature {
                    value: t,
                    rate: 0.0,
                },
                PredictedTemperature(t),
            )
        }));
        for _ in 0..4 {
            app.update();
        }
        assert!(app.world().resource::<SimulationStatus>().failure.is_none());
        let mut q = app
            .world_mut()
            .query_filtered::<&Position, With<Particle>>();
        let r: f32 = q
            .iter(app.world())
            .map(|x| ((x.0.x - 0.06).powi(2) + (x.0.z - 0.06).powi(2)).sqrt())
            .fold(0.0, f32::max);
        r
    };
    let (cold, hot) = (spread(0.0), spread(30.0));
    println!("radius after 0.2 s: cold (μ = 20 Pa·s) {cold:.4} m, hot (μ = 1.0 Pa·s) {hot:.4} m");
    assert!(hot > cold + 0.005, "hot {hot} vs cold {cold}");
}

/// Scene sections: `phase_change` and `temperature_viscosity` load into the scene and reject
/// bad parameters with their field.
#[test]
fn scene_sections_validate() {
    let base = r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.1, 0.1, 0.1)),
    dx: 0.01,
    duration: 0.1,
    frame_rate: 20.0,
    materials: [(name: "melt", density: 1000.0, sound_speed: 5.0, viscosity: VISC)],
    bodies: [(material: "melt", shape: Sphere(center: (0.05, 0.05, 0.05), radius: 0.02))],
    phase_change: [(material: "melt", melting_temperature: 0.1, ramp: RAMP, shear_modulus: 3000.0)],
    temperature_viscosity: [(material: "melt", law: LAW)],
)"#;
    let make = |visc: &str, ramp: &str, law: &str| {
        base.replace("VISC", visc)
            .replace("RAMP", ramp)
            .replace("LAW", law)
    };
    let p = std::path::Path::new("t.ron");
    let dir = std::path::Path::new(".");
    let ok = parse_scene_str(&make("1.0", "0.0", "Exponential(coefficient: 0.1)"), p, dir).unwrap();
    assert_eq!(ok.phase_change.len(), 1);
    assert_eq!(ok.temperature_viscosity.len(), 1);
    let ok = parse_scene_str(
        &make(
            "1.0",
            "0.01",
            "CrossWlf(d1: 3.32e9, a1: 20.194, a2: 51.6, d2: 100.0)",
        ),
        p,
        dir,
    )
    .unwrap();
    assert_eq!(ok.phase_change[0].1.ramp, 0.01);
    let e = parse_scene_str(
        &make("1.0", "-1.0", "Exponential(coefficient: 0.1)"),
        p,
        dir,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("phase_change[0].ramp"), "{e}");
    let e = parse_scene_str(
        &make(
            "0.0",
            "0.0",
            "CrossWlf(d1: 3.32e9, a1: 20.194, a2: 51.6, d2: 100.0, n: 2.0)",
        ),
        p,
        dir,
    )
    .unwrap_err()
    .to_string();
    println!("{e}");
    assert!(e.contains("temperature_viscosity[0].law.n"), "{e}");
    assert!(
        e.contains("temperature_viscosity[0].law:") || e.contains("temperature_viscosity[0].law`"),
        "{e}"
    );
}
