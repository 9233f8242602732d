//! Plugin order never matters, and the order inside every set of the step is explicit.
//!
//! A scene with heat, an XPP liquid with a phase change, a nozzle emitter and a dynamic rigid
//! body is built with its plugins added in several orders (the core plugin first, last and in
//! the middle): every order gives the same systems in the step and bit-identical particles
//! after three frames, equal to the loader's own app (`runner::scene_app`). A second test builds
//! the step with Bevy's ambiguity detection set to error: two systems that touch the same data
//! without an order between them fail the build.
use bevy_app::App;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::{LogLevel, ScheduleBuildSettings, Schedules};
use treacle::emit::EmitterPlugin;
use treacle::prelude::*;
use treacle::scene::{Scene, parse_scene_str};
use treacle::thermal::phase::PhaseChangePlugin;

const SCENE: &str = r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.2, 0.2, 0.2)),
    dx: 0.02,
    particles_per_cell: 2,
    gravity: (0.0, -9.81, 0.0),
    duration: 0.1,
    frame_rate: 30.0,
    seed: 3,
    walls: (x_min: Slip, x_max: Slip, y_min: Sticky, y_max: Slip, z_min: Slip, z_max: Slip),
    materials: [
        (name: "melt", density: 1000.0, sound_speed: 5.0, viscosity: 2.0, local_fraction: 0.5),
    ],
    rheology: [
        (material: "melt", model: Su2021Unified((
            backbone_relaxation_time: 0.05,
            stretch_relaxation_time: 0.04,
            modulus: Derived,
            anisotropy: 0.1,
            arms: 2.0,
            f_mode: Full,
            implicit_relaxation: true,
            stretch_limit: Unbounded,
        ))),
    ],
    phase_change: [(material: "melt", melting_temperature: 0.1, shear_modulus: 300.0)],
    thermal: (
        materials: [(material: "melt", diffusivity: 1e-3, initial_temperature: 0.2, melting_temperature: Some(0.1))],
        colliders: [(collider: 0, temperature: 0.0)],
    ),
    colliders: [
        (shape: Box(half_extents: (0.1, 0.01, 0.1)), boundary: Sticky, translation: (0.1, 0.01, 0.1)),
    ],
    bodies: [
        (shape: Box(min: (0.04, 0.04, 0.04), max: (0.12, 0.1, 0.12)), material: "melt"),
    ],
    rigid_bodies: [
        (shape: Sphere(radius: 0.02), mass: 0.01, position: (0.16, 0.12, 0.16), velocity: (0.0, -0.5, 0.0), boundary: Slip),
    ],
    emitters: [
        (
            material: "melt",
            path: Polyline(points: [(0.08, 0.16, 0.08), (0.08, 0.16, 0.14)], speed: 0.3),
            axis: (0.0, -1.0, 0.0),
            radius: 0.02,
            volume_rate: 2e-4,
            temperature: Some(0.2),
        ),
    ],
)"#;

fn scene() -> Scene {
    parse_scene_str(SCENE, "order.ron".as_ref(), ".".as_ref()).unwrap_or_else(|e| panic!("{e}"))
}

/// Adds one plugin to an app.
type AddPlugin = Box<dyn Fn(&mut App)>;

/// The scene's plugins, named, each as a closure adding it to an app.
fn plugins(scene: &Scene) -> Vec<(&'static str, AddPlugin)> {
    let (id, model) = scene.rheology[0].clone();
    let xpp = model.downcast_ref::<Su2021Unified>().unwrap().clone();
    let (pid, phase) = scene.phase_change[0].clone();
    let thermal = scene.thermal.as_ref().unwrap().plugin();
    vec![
        (
            "core",
            Box::new(|app: &mut App| {
                app.add_plugins(MpmCorePlugin::default());
            }),
        ),
        (
            "rigid",
            Box::new(|app: &mut App| {
                app.add_plugins(RigidBodyPlugin);
            }),
        ),
        (
            "xpp",
            Box::new(move |app: &mut App| {
                app.add_plugins(RheologyPlugin::<Su2021Unified>::default().with(id, xpp.clone()));
            }),
        ),
        (
            "phase",
            Box::new(move |app: &mut App| {
                app.add_plugins(PhaseChangePlugin::default().with_phase_change(pid, phase.clone()));
            }),
        ),
        (
            "emitter",
            Box::new(|app: &mut App| {
                app.add_plugins(EmitterPlugin);
            }),
        ),
        (
            "thermal",
            Box::new(move |app: &mut App| {
                app.add_plugins(thermal.clone());
            }),
        ),
    ]
}

fn app_in_order(scene: &Scene, order: &[&str]) -> App {
    let all = plugins(scene);
    let mut app = App::new();
    app.insert_resource(scene.config.clone())
        .insert_resource(scene.materials.clone());
    for name in order {
        let (_, add) = all.iter().find(|(n, _)| n == name).unwrap();
        add(&mut app);
    }
    app.finish();
    app.cleanup();
    scene.apply(app.world_mut());
    app
}

/// Bit patterns of every particle's position, velocity and temperature, by entity, and the
/// rigid body's position.
fn state(app: &mut App) -> Vec<u32> {
    let world = app.world_mut();
    let mut q = world.query_filtered::<(
        Entity,
        &Position,
        &Velocity,
        Option<&treacle::thermal::Temperature>,
    ), With<Particle>>();
    let mut rows: Vec<(Entity, [u32; 7])> = q
        .iter(world)
        .map(|(e, x, v, t)| {
            let t = t.map_or(f32::NAN, |t| t.value);
            let b = |f: f32| f.to_bits();
            (
                e,
                [
                    b(x.0.x),
                    b(x.0.y),
                    b(x.0.z),
                    b(v.0.x),
                    b(v.0.y),
                    b(v.0.z),
                    b(t),
                ],
            )
        })
        .collect();
    rows.sort_by_key(|r| r.0);
    let mut out: Vec<u32> = rows.into_iter().flat_map(|r| r.1).collect();
    let mut bodies = world.query::<(&RigidBody, &treacle::collision::ColliderPose)>();
    for (_, pose) in bodies.iter(world) {
        out.extend(pose.translation.to_array().map(f32::to_bits));
    }
    out
}

fn step_systems(app: &App) -> Vec<String> {
    let schedules = app.world().resource::<Schedules>();
    let mut names: Vec<String> = schedules
        .get(treacle::schedule::MpmStep)
        .unwrap()
        .systems()
        .unwrap()
        .map(|(_, s)| s.name().to_string())
        .collect();
    names.sort();
    names
}

fn run(app: &mut App, frames: usize) {
    for _ in 0..frames {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            panic!("simulation failed: {f}");
        }
    }
}

#[test]
fn plugin_order_does_not_change_the_systems_or_the_output() {
    let scene = scene();
    let orders: [&[&str]; 4] = [
        &["core", "rigid", "xpp", "phase", "emitter", "thermal"],
        &["thermal", "emitter", "phase", "xpp", "rigid", "core"],
        &["emitter", "xpp", "core", "thermal", "rigid", "phase"],
        &["phase", "thermal", "rigid", "emitter", "core", "xpp"],
    ];
    let mut reference = treacle::runner::scene_app(&scene);
    run(&mut reference, 3);
    let want_state = state(&mut reference);
    let want_systems = step_systems(&reference);
    let emitted = want_state.len() / 7 > scene.particle_count();
    assert!(
        emitted,
        "the nozzle must have emitted particles for the test to mean something"
    );
    assert!(
        want_systems
            .iter()
            .any(|s| s.contains("couple_rigid_bodies"))
            && want_systems.iter().any(|s| s.contains("thermal_solve"))
            && want_systems.iter().any(|s| s.contains("evaluate_model"))
            && want_systems.iter().any(|s| s.contains("emit_particles")),
        "{want_systems:#?}"
    );
    for order in orders {
        let mut app = app_in_order(&scene, order);
        run(&mut app, 3);
        assert_eq!(step_systems(&app), want_systems, "order {order:?}");
        let got = state(&mut app);
        assert!(
            got == want_state,
            "order {order:?}: the particles differ from the loader's app"
        );
    }
}

/// Builds the app's step with Bevy's ambiguity detection set to error; the error lists every
/// unordered pair of systems with conflicting data access.
fn ambiguities(app: &mut App) -> Result<(), String> {
    let mut schedule = app
        .world_mut()
        .resource_mut::<Schedules>()
        .remove(treacle::schedule::MpmStep)
        .unwrap();
    schedule.set_build_settings(ScheduleBuildSettings {
        ambiguity_detection: LogLevel::Error,
        ..Default::default()
    });
    schedule
        .initialize(app.world_mut())
        .map(|_| ())
        .map_err(|e| e.to_string(schedule.graph(), app.world()))
}

#[test]
fn every_set_orders_its_conflicting_systems() {
    let scene = scene();
    for order in [
        &["core", "rigid", "xpp", "phase", "emitter", "thermal"][..],
        &["thermal", "emitter", "phase", "xpp", "rigid", "core"][..],
    ] {
        let mut app = app_in_order(&scene, order);
        if let Err(e) = ambiguities(&mut app) {
            panic!("order {order:?}: {e}");
        }
    }
}

/// Every shipped scene's step, built by the loader, orders every pair of systems that touch the
/// same data.
#[test]
fn shipped_scenes_have_no_ambiguous_systems() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut checked = 0;
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    paths.sort();
    for path in paths {
        let scene = treacle::scene::load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
        if scene.particle_count() > 200_000 {
            continue; // the benchmark blocks: same plugins as smaller scenes, slow to sample
        }
        let mut app = treacle::runner::scene_app(&scene);
        if let Err(e) = ambiguities(&mut app) {
            panic!("{}: {e}", path.display());
        }
        checked += 1;
    }
    assert!(checked >= 25, "only {checked} scenes checked");
}
