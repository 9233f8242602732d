//! In a Bevy game (feature `game`, issue 15): simulated time from Bevy's clock within a frame
//! budget; liquids, nozzles and colliders placed by `Transform`.
//!
//! The apps here use `bevy_time`'s `TimePlugin` with `TimeUpdateStrategy::ManualDuration`, so
//! every update advances virtual time by exactly one game frame.
use std::time::Duration;

use bevy_app::App;
use bevy_ecs::prelude::*;
use treacle::app::headless_app_with;
use treacle::collision::{Collider, ColliderMotion, ColliderPose, ColliderShape};
use treacle::emit::{EmitterPlugin, NozzleEmitter, PathSegment, ToolPath};
use treacle::game::bevy_time::{Time, TimePlugin, TimeUpdateStrategy, Virtual};
use treacle::game::bevy_transform::components::Transform;
use treacle::game::{GamePlugin, LiquidBody, SpawnedLiquid, game_config_projected};
use treacle::prelude::*;

use crate::common::{assert_healthy, lattice, state};

/// A water-like liquid: ρ₀ = 1000 kg/m³, c₀ = `sound_speed`, μ = 0.01 Pa·s.
fn water(sound_speed: f32) -> FluidMaterial {
    FluidMaterial::newtonian("water", 1000.0, sound_speed, 0.01)
}

/// A tank `size` with slip walls, Δx = `dx`.
fn tank(size: Vec3, dx: f32) -> MpmConfig {
    MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: size,
        dx,
        walls: DomainWalls::all(BoundaryCondition::Slip),
        ..Default::default()
    }
}

/// A game app: time advanced by `1/hz` per update, the MPM plugins, `GamePlugin` with
/// `budget`, `extra` plugins; a water layer `layer` (box) if given.
fn game_app(
    config: MpmConfig,
    material: FluidMaterial,
    hz: f64,
    game: GamePlugin,
    layer: Option<(Vec3, Vec3)>,
    extra: impl FnOnce(&mut App),
) -> App {
    let mut materials = Materials::default();
    let rho0 = material.density;
    let id = materials.add(material);
    let (g, dx) = (config.gravity, config.dx);
    let mut app = headless_app_with(config, materials, |app| {
        app.add_plugins((TimePlugin, game));
        app.insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
            1.0 / hz,
        )));
        extra(app);
    });
    if let Some((min, max)) = layer {
        let h = 0.5 * dx;
        let batch: Vec<ParticleBundle> = lattice(min, max, h)
            .into_iter()
            .map(|x| ParticleBundle::new(x, Vec3::ZERO, g, h * h * h, rho0, id))
            .collect();
        app.world_mut().spawn_batch(batch);
    }
    app
}

/// An empty 40 cm tank without gravity at 60 Hz, water at c₀ = 10 m/s, `extra` plugins.
fn weightless_tank(dx: f32, extra: impl FnOnce(&mut App)) -> App {
    let mut config = tank(Vec3::new(0.4, 0.4, 0.4), dx);
    config.gravity = Vec3::ZERO;
    game_app(
        config,
        water(10.0),
        60.0,
        GamePlugin::default(),
        None,
        extra,
    )
}

/// A hose: a nozzle held at its entity's origin for 100 s, extruding along local −y
/// (radius 12 mm, 0.2 l/s, particle spacing Δx/2).
fn hose(material: MaterialId, dx: f32) -> NozzleEmitter {
    let hold = ToolPath::new(vec![PathSegment {
        start: glam::DVec3::ZERO,
        end: glam::DVec3::ZERO,
        duration: 100.0,
        extrude: true,
    }])
    .unwrap();
    NozzleEmitter::new(hold, -Vec3::Y, 0.012, 2e-4, 0.5 * dx, material)
}

fn sim_time(app: &App) -> f64 {
    app.world().resource::<SimulationClock>().time
}

fn virtual_elapsed(app: &App) -> f64 {
    app.world().resource::<Time<Virtual>>().elapsed_secs_f64()
}

/// Simulated time follows virtual time at 30, 60 and 144 frames per second: after every
/// update the simulated time equals the virtual time elapsed, to rounding (the driver sums
/// the frame times in f64 and splits each frame into sub-steps that end exactly on it).
#[test]
fn simulated_time_follows_virtual_time() {
    for hz in [30.0, 60.0, 144.0] {
        let config = tank(Vec3::new(0.2, 0.2, 0.1), 0.01);
        let mut app = game_app(
            config,
            water(10.0),
            hz,
            GamePlugin::default(),
            Some((Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.1, 0.06, 0.1))),
            |_| {},
        );
        let mut worst = 0.0f64;
        let mut steps = Vec::new();
        for _ in 0..(0.25 * hz).round() as usize {
            app.update();
            assert_healthy(&app);
            let (t, v) = (sim_time(&app), virtual_elapsed(&app));
            worst = worst.max((t - v).abs());
            steps.push(app.world().resource::<SimulationClock>().frame_steps);
        }
        let v = virtual_elapsed(&app);
        println!(
            "{hz} Hz: virtual {v:.6} s, simulated {:.6} s, largest |difference| {worst:.1e} s, \
             sub-steps per frame {:?}…",
            sim_time(&app),
            &steps[..steps.len().min(6)]
        );
        assert!(v > 0.2, "virtual time advanced ({v} s)");
        assert!(
            worst <= 1e-12,
            "simulated time off virtual time by {worst} s"
        );
        let lag = *app.world().resource::<SimulationLag>();
        assert_eq!(lag.total, 0.0, "no budget, no lag");
    }
}

/// A still pool under the projected game configuration takes one step per frame: no limit of
/// §7.2 is near a frame there (gravity's √(2Δx/g) = 71 ms, nothing moves), so one step is what
/// the driver must take.
/// - 60 Hz with `max_dt` = 1/60 s: Bevy's clock gives frame lengths in whole nanoseconds
///   (16,666,667 ns, above 1/60 s by a third of a nanosecond); without the driver's relative
///   slack of 10⁻⁶ every such frame took two half steps.
/// - 57 Hz (17.5 ms, a frame that ran long) with the configuration's own `max_dt` (1/30 s).
#[test]
fn a_still_pool_takes_one_step_per_frame() {
    for (hz, max_dt) in [(60.0, Some(1.0 / 60.0)), (57.0, None)] {
        let size = Vec3::new(0.3, 0.3, 0.3);
        let mut config = game_config_projected(Vec3::ZERO, size);
        if let Some(m) = max_dt {
            config.time_step.max_dt = m;
        }
        let mut app = game_app(
            config,
            water(5.0),
            hz,
            GamePlugin::default(),
            Some((Vec3::ZERO, Vec3::new(0.3, 0.1, 0.3))),
            |_| {},
        );
        let mut steps = Vec::new();
        for _ in 0..10 {
            app.update();
            assert_healthy(&app);
            steps.push(app.world().resource::<SimulationClock>().frame_steps);
        }
        println!("{hz} Hz: sub-steps per frame {steps:?}");
        // The first update starts the run (virtual time advances from the second on).
        assert!(
            steps[2..].iter().all(|&n| n == 1),
            "{hz} Hz: sub-steps per frame {steps:?}"
        );
    }
}

/// With a budget of N sub-steps, no update runs more than N, simulated time falls behind and
/// the lag resource accounts for every second of the shortfall.
#[test]
fn a_substep_budget_bounds_every_frame_and_reports_the_lag() {
    // c₀ = 50 m/s, Δx = 5 mm: Δt ≈ 0.5·Δx/c₀ = 5e-5 s, about 330 sub-steps per 1/60 s frame.
    let config = tank(Vec3::new(0.1, 0.1, 0.05), 0.005);
    let budget = 8;
    let mut app = game_app(
        config,
        water(50.0),
        60.0,
        GamePlugin::with_max_substeps(budget),
        Some((Vec3::ZERO, Vec3::new(0.05, 0.04, 0.05))),
        |_| {},
    );
    for _ in 0..10 {
        app.update();
        assert_healthy(&app);
        let steps = app.world().resource::<SimulationClock>().frame_steps;
        assert!(
            steps <= budget as u64,
            "{steps} sub-steps > budget {budget}"
        );
    }
    let lag = *app.world().resource::<SimulationLag>();
    let (t, v) = (sim_time(&app), virtual_elapsed(&app));
    println!(
        "budget {budget}: virtual {v:.5} s, simulated {t:.3e} s, lag {:.5} s over {} frames",
        lag.total, lag.frames_behind
    );
    assert!(
        lag.frames_behind >= 9,
        "frames cut short: {}",
        lag.frames_behind
    );
    assert!(
        lag.last_frame > 0.0 && t < 0.1 * v,
        "simulated time fell behind"
    );
    assert!(
        (t + lag.total - v).abs() <= 1e-12,
        "simulated {t} + lag {} ≠ virtual {v}",
        lag.total
    );
}

/// Pausing virtual time stops the liquid: no sub-step runs and no particle moves.
#[test]
fn pausing_virtual_time_stops_the_liquid() {
    let config = tank(Vec3::new(0.2, 0.2, 0.1), 0.01);
    let mut app = game_app(
        config,
        water(10.0),
        60.0,
        GamePlugin::default(),
        Some((Vec3::new(0.0, 0.05, 0.0), Vec3::new(0.1, 0.1, 0.1))),
        |_| {},
    );
    for _ in 0..5 {
        app.update();
    }
    assert_healthy(&app);
    app.world_mut().resource_mut::<Time<Virtual>>().pause();
    let (before, t0) = (state(&mut app), sim_time(&app));
    assert!(t0 > 0.0);
    for _ in 0..5 {
        app.update();
        assert_eq!(app.world().resource::<SimulationClock>().frame_steps, 0);
    }
    assert_eq!(sim_time(&app), t0);
    assert_eq!(state(&mut app), before, "particles moved while paused");
    app.world_mut().resource_mut::<Time<Virtual>>().unpause();
    app.update();
    app.update();
    assert!(sim_time(&app) > t0, "resumes");
}

/// A kinematic box moved through a water layer by its `Transform` displaces the liquid like the
/// same motion scripted with [`ColliderMotion`]: particle positions within one Δx after the same
/// time. (The Transform's motion over a frame gives the collider the velocity v = Δx/Δt that
/// the scripted collider has; both start moving after one frame at rest, since a Transform seen
/// for the first time only places its collider.)
#[test]
fn a_collider_moved_by_its_transform_pushes_like_a_scripted_one() {
    let dx = 0.01;
    let (speed, frames, hz) = (0.5f32, 15, 60.0);
    let paddle = ColliderShape::Box {
        half_extents: Vec3::new(0.01, 0.05, 0.05),
    };
    let start = Vec3::new(0.06, 0.05, 0.025);
    let run = |by_transform: bool| {
        let config = tank(Vec3::new(0.3, 0.12, 0.05), dx);
        let mut app = game_app(
            config,
            water(10.0),
            hz,
            GamePlugin::default(),
            Some((Vec3::ZERO, Vec3::new(0.3, 0.04, 0.05))),
            |_| {},
        );
        let collider = Collider {
            shape: paddle.clone(),
            boundary: BoundaryCondition::Slip,
        };
        let e = if by_transform {
            app.world_mut()
                .spawn((collider, Transform::from_translation(start)))
                .id()
        } else {
            app.world_mut()
                .spawn((
                    collider,
                    ColliderPose {
                        translation: start,
                        ..Default::default()
                    },
                    ColliderMotion::default(),
                ))
                .id()
        };
        app.update();
        for frame in 1..=frames {
            if by_transform {
                let x = start + Vec3::X * speed * (frame as f32 / hz as f32);
                app.world_mut().get_mut::<Transform>(e).unwrap().translation = x;
            } else {
                app.world_mut()
                    .get_mut::<ColliderMotion>(e)
                    .unwrap()
                    .linear_velocity = Vec3::X * speed;
            }
            app.update();
            assert_healthy(&app);
        }
        let pose = *app.world().get::<ColliderPose>(e).unwrap();
        let mut s = state(&mut app);
        s.sort_by_key(|p| p.0);
        (pose, s)
    };
    let (pose_t, moved_t) = run(true);
    let (pose_s, moved_s) = run(false);
    assert_eq!(moved_t.len(), moved_s.len());
    let worst = moved_t
        .iter()
        .zip(&moved_s)
        .map(|(a, b)| a.1.distance(b.1))
        .fold(0.0f32, f32::max);
    let pushed = moved_t
        .iter()
        .filter(|p| p.1.x > start.x + 0.5 * speed * (frames as f32 / hz as f32))
        .count();
    println!(
        "paddle at x = {:.4} (Transform) / {:.4} (scripted) m; largest particle distance \
         {worst:.2e} m (Δx = {dx}); {pushed} particles ahead of the paddle's mid-way point",
        pose_t.translation.x, pose_s.translation.x
    );
    assert!(
        (pose_t.translation - pose_s.translation).length() < 1e-5,
        "same paddle pose"
    );
    assert!(worst <= dx, "particles differ by {worst} m > Δx");
    // The motion did something: the paddle (0.125 m travel) pushed water ahead of it.
    let travelled = pose_s.translation.x - start.x;
    assert!(travelled > 0.1, "paddle travelled {travelled} m");
}

/// A nozzle whose entity turns 90° emits along its new direction: the particles born after the
/// turn move along the rotated axis (at the extrusion speed, the hose now at rest).
#[test]
fn a_nozzle_that_turns_emits_along_its_new_direction() {
    let dx = 0.01;
    let mut app = weightless_tank(dx, |app| {
        app.add_plugins(EmitterPlugin);
    });
    let id = app.world().resource::<Materials>().find("water").unwrap();
    // A hose: the path holds the nozzle at the entity's origin; it extrudes along local −y.
    let nozzle = hose(id, dx);
    let e = app
        .world_mut()
        .spawn((nozzle, Transform::from_xyz(0.2, 0.3, 0.2)))
        .id();
    let born = |app: &mut App, known: &std::collections::HashSet<Entity>| -> Vec<Vec3> {
        state(app)
            .into_iter()
            .filter(|p| !known.contains(&p.0))
            .map(|p| p.2)
            .collect()
    };
    for _ in 0..5 {
        app.update();
    }
    assert_healthy(&app);
    let first = born(&mut app, &Default::default());
    assert!(!first.is_empty(), "the nozzle emits");
    let mean = first.iter().copied().sum::<Vec3>() / first.len() as f32;
    println!(
        "before the turn: {} particles, mean velocity {mean}",
        first.len()
    );
    assert!(mean.normalize().dot(-Vec3::Y) > 0.99, "along −y: {mean}");
    // Turn the hose 90° about z over 6 frames (0.1 s, as a player swings it): local −y
    // becomes world +x.
    let known: std::collections::HashSet<Entity> = state(&mut app).iter().map(|p| p.0).collect();
    for k in 1..=6 {
        let angle = std::f32::consts::FRAC_PI_2 * k as f32 / 6.0;
        app.world_mut().get_mut::<Transform>(e).unwrap().rotation =
            glam::Quat::from_rotation_z(angle);
        app.update();
    }
    let known2: std::collections::HashSet<Entity> = state(&mut app).iter().map(|p| p.0).collect();
    for _ in 0..4 {
        app.update();
    }
    let known3: std::collections::HashSet<Entity> = state(&mut app).iter().map(|p| p.0).collect();
    app.update();
    assert_healthy(&app);
    assert!(known.len() < known2.len());
    // Where the particles born after the turn went, from the nozzle: along +x.
    let nozzle = Vec3::new(0.2, 0.3, 0.2);
    let after: Vec<(Entity, Vec3, Vec3)> = state(&mut app)
        .into_iter()
        .filter(|p| !known2.contains(&p.0))
        .collect();
    assert!(!after.is_empty());
    let offset = after.iter().map(|p| p.1 - nozzle).sum::<Vec3>() / after.len() as f32;
    // The velocity of those born in the last frame (at most one frame after their birth).
    let newest: Vec<Vec3> = after
        .iter()
        .filter(|p| !known3.contains(&p.0))
        .map(|p| p.2)
        .collect();
    let mean = newest.iter().copied().sum::<Vec3>() / newest.len() as f32;
    println!(
        "after the turn: {} particles, mean offset from the nozzle {offset}; the {} born in the \
         last frame move at {mean}",
        after.len(),
        newest.len()
    );
    assert!(
        offset.normalize().dot(Vec3::X) > 0.95,
        "placed along +x: {offset}"
    );
    assert!(
        mean.normalize().dot(Vec3::X) > 0.95,
        "moving along +x: {mean}"
    );
}

/// A liquid body spawned at a Transform appears there: its particles fill the placed, rotated
/// box (centroid at the Transform's translation, every particle inside the box, the count
/// that fills its volume).
#[test]
fn a_liquid_body_spawned_at_a_transform_appears_there() {
    let dx = 0.01;
    let mut app = weightless_tank(dx, |_| {});
    let id = app.world().resource::<Materials>().find("water").unwrap();
    let half = Vec3::new(0.06, 0.04, 0.05);
    let place = Transform::from_xyz(0.21, 0.17, 0.19)
        .with_rotation(glam::Quat::from_rotation_y(std::f32::consts::FRAC_PI_4));
    let e = app
        .world_mut()
        .spawn((
            LiquidBody::new(ColliderShape::Box { half_extents: half }, id),
            place,
        ))
        .id();
    app.update();
    assert_healthy(&app);
    let spawned = app.world().get::<SpawnedLiquid>(e).copied().unwrap();
    assert!(app.world().get::<LiquidBody>(e).is_none());
    let xs: Vec<Vec3> = state(&mut app).iter().map(|p| p.1).collect();
    assert_eq!(xs.len(), spawned.particles);
    let h = 0.5 * dx;
    let volume = 8.0 * half.x * half.y * half.z;
    let n_expected = volume / (h * h * h);
    // Lattice points of a rotated box: the count is the volume over h³ up to the points
    // within h/2 of the surface, at most area·(h/2)/h³.
    let area = 8.0 * (half.x * half.y + half.y * half.z + half.x * half.z);
    let slack = area * 0.5 * h / (h * h * h);
    let centroid = xs.iter().copied().sum::<Vec3>() / xs.len() as f32;
    let inverse = place.rotation.inverse();
    let outside = xs
        .iter()
        .map(|&x| inverse * (x - place.translation))
        .filter(|l| (l.abs() - half).max_element() > h)
        .count();
    println!(
        "liquid body: {} particles (volume/h³ = {n_expected:.0} ± {slack:.0}), centroid {centroid}",
        xs.len()
    );
    assert!((xs.len() as f32 - n_expected).abs() <= slack);
    assert!(
        (centroid - place.translation).length() <= h,
        "centroid {centroid}"
    );
    assert_eq!(outside, 0, "particles outside the placed box");
}

/// What game code reads once per frame (after `DriverSystems::Publish`).
#[derive(Resource, Default)]
struct Tally {
    born: u64,
    removed: u64,
    frames: u64,
    /// Frames where the live count differed from the last one plus births minus removals.
    inconsistent: Vec<(u64, usize, usize, u64, u64)>,
    last_count: usize,
}

fn tally(
    mut t: ResMut<Tally>,
    live: Query<(), With<Particle>>,
    added: Query<(), Added<Particle>>,
    mut removed: RemovedComponents<Particle>,
) {
    let (b, r) = (added.iter().count() as u64, removed.read().count() as u64);
    let n = live.iter().count();
    t.frames += 1;
    if n as u64 + r != t.last_count as u64 + b {
        let entry = (t.frames, t.last_count, n, b, r);
        t.inconsistent.push(entry);
    }
    t.born += b;
    t.removed += r;
    t.last_count = n;
}

/// Game code reads births and removals once per frame: a nozzle pours towards an open face,
/// and a system after the frame counts `Added<Particle>` and `RemovedComponents<Particle>`.
/// Every frame the live count equals the last one plus the births minus the removals
/// (nothing is born and removed within one frame here: the liquid needs 0.2 s to reach the
/// face), and the totals equal what the nozzle emitted and what the clock counts as escaped.
#[test]
fn game_code_reads_births_and_removals_each_frame() {
    let dx = 0.01;
    let mut config = tank(Vec3::new(0.4, 0.4, 0.4), dx);
    config.gravity = Vec3::ZERO;
    config.walls.x_max = BoundaryCondition::Open;
    let mut app = game_app(
        config,
        water(10.0),
        60.0,
        GamePlugin::default(),
        None,
        |app| {
            app.add_plugins(EmitterPlugin);
            app.init_resource::<Tally>();
            app.add_systems(bevy_app::Update, tally.after(DriverSystems::Publish));
        },
    );
    let id = app.world().resource::<Materials>().find("water").unwrap();
    // Local −y turned to world +x: the hose points at the open face 0.1 m away.
    let nozzle = hose(id, dx);
    app.world_mut().spawn((
        nozzle,
        Transform::from_xyz(0.3, 0.2, 0.2)
            .with_rotation(glam::Quat::from_rotation_z(std::f32::consts::FRAC_PI_2)),
    ));
    for _ in 0..60 {
        app.update();
        assert_healthy(&app);
    }
    let live = state(&mut app).len() as u64;
    let escaped = app.world().resource::<SimulationClock>().escaped_particles;
    let t = app.world().resource::<Tally>();
    println!(
        "60 frames: {} born, {} removed (clock: {escaped} escaped), {live} live; inconsistent \
         frames {:?}",
        t.born, t.removed, t.inconsistent
    );
    assert!(t.removed > 0, "the liquid reached the open face");
    assert!(t.inconsistent.is_empty(), "{:?}", t.inconsistent);
    assert_eq!(t.removed, escaped);
    assert_eq!(t.born, live + escaped);
}

/// A hose snapped round by 90° in one frame (a player flicking it) and back: the liquid it
/// already poured meets the new jet; the run stays healthy (the energy monitor counts the
/// Tait pressure's stored energy, so the compressed meeting region is not taken for energy
/// growth).
#[test]
fn a_nozzle_snapped_round_in_one_frame_keeps_the_run_healthy() {
    let dx = 0.01;
    let mut app = weightless_tank(dx, |app| {
        app.add_plugins(EmitterPlugin);
    });
    let id = app.world().resource::<Materials>().find("water").unwrap();
    let nozzle = hose(id, dx);
    let e = app
        .world_mut()
        .spawn((nozzle, Transform::from_xyz(0.2, 0.3, 0.2)))
        .id();
    for frame in 0..40 {
        let angle = match frame {
            0..10 => 0.0,
            10..20 => std::f32::consts::FRAC_PI_2,
            20..30 => 0.0,
            _ => -std::f32::consts::FRAC_PI_2,
        };
        app.world_mut().get_mut::<Transform>(e).unwrap().rotation =
            glam::Quat::from_rotation_z(angle);
        app.update();
        assert_healthy(&app);
    }
    println!("{} particles after 40 frames", state(&mut app).len());
}

/// A rigid body spawned in a game from its required components — `(RigidBody, Collider,
/// Transform)` — is the same body as one spawned with `RigidBodyBundle::new` at that
/// Transform: a box dropped into water lands bit-identically (its zero GS4 rate starts as free
/// fall, like the bundle's; without that it would fall slower for its first steps).
#[test]
fn a_rigid_body_from_required_components_equals_the_bundle() {
    let dx = 0.02;
    let run = |bundle: bool| {
        let config = tank(Vec3::new(0.4, 0.4, 0.4), dx);
        let g = config.gravity;
        let mut app = game_app(
            config,
            water(10.0),
            60.0,
            GamePlugin::default(),
            Some((Vec3::ZERO, Vec3::new(0.4, 0.1, 0.4))),
            |_| {},
        );
        let shape = ColliderShape::Box {
            half_extents: Vec3::new(0.05, 0.03, 0.05),
        };
        let body = treacle::rigid::RigidBody::solid(&shape, 600.0).unwrap();
        let collider = Collider {
            shape,
            boundary: BoundaryCondition::Sticky,
        };
        let place = Transform::from_xyz(0.2, 0.2, 0.2);
        let e = if bundle {
            app.world_mut()
                .spawn((
                    treacle::rigid::RigidBodyBundle::new(
                        body,
                        collider,
                        ColliderPose::default(),
                        Default::default(),
                        g,
                    ),
                    place,
                ))
                .id()
        } else {
            app.world_mut().spawn((body, collider, place)).id()
        };
        for _ in 0..30 {
            app.update();
            assert_healthy(&app);
        }
        *app.world().get::<ColliderPose>(e).unwrap()
    };
    let (a, b) = (run(true), run(false));
    println!("after 0.5 s: bundle {a:?}, required components {b:?}");
    assert!(a.translation.y < 0.2 - 0.05, "the box fell: {a:?}");
    assert_eq!(a, b);
}

/// The water preset's compression at rest, the cost its module docs state: a pool of depth
/// H = 0.5 m settles to the Tait hydrostatic profile. With p = (ρ₀c₀²/γ)((ρ/ρ₀)^γ − 1) and
/// dp = −ρg dy, the density at depth d is ρ/ρ₀ = (1 + (γ − 1)gd/c₀²)^(1/(γ−1)): 13.9 % at the
/// floor of the 50 cm pool with c₀ = 5 m/s, where the linear estimate gd/c₀² says 19.6 %. The
/// density of each particle of the bottom 10 cm, averaged over the second second (the
/// start-up's acoustic ringing has period 4H/c₀ ≈ 0.4 s), is compared with the profile at the
/// particle's depth below the settled surface. Tolerance: the pressure gradient is resolved on
/// 20 cells (Δx = 2.5 cm), and the surface and the floor layers are uncertain by about a cell
/// each, so the compression ρ/ρ₀ − 1 is allowed 2Δx/H = 10 % relative error.
#[test]
fn the_water_preset_at_rest_is_compressed_as_tait_hydrostatics_says() {
    use treacle::game::{GAME_DX, GAME_SOUND_SPEED, GameLiquid, game_config};
    let (dx, depth) = (GAME_DX, 0.5_f32);
    let config = MpmConfig {
        walls: DomainWalls::all(BoundaryCondition::Slip),
        ..game_config(Vec3::ZERO, Vec3::new(0.1, 0.7, 0.1))
    };
    let material = GameLiquid::Water.material();
    let (rho0, gamma) = (material.density as f64, material.tait_gamma as f64);
    let layer = (Vec3::ZERO, Vec3::new(0.1, depth, 0.1));
    let mut app = game_app(
        config,
        material,
        60.0,
        GamePlugin::default(),
        Some(layer),
        |_| {},
    );
    for _ in 0..60 {
        app.update();
    }
    let (c0, g) = (GAME_SOUND_SPEED as f64, 9.81_f64);
    let profile = |d: f64| (1.0 + (gamma - 1.0) * g * d / (c0 * c0)).powf(1.0 / (gamma - 1.0));
    let (mut measured, mut predicted, mut samples) = (0.0, 0.0, 0usize);
    for _ in 0..60 {
        app.update();
        assert_healthy(&app);
        let world = app.world_mut();
        let rows: Vec<(f32, f32)> = world
            .query::<(&Position, &Density)>()
            .iter(world)
            .map(|(x, r)| (x.0.y, r.value))
            .collect();
        // The settled surface: the top particle layer plus half a particle spacing.
        let top = rows.iter().map(|r| r.0).fold(f32::MIN, f32::max) + 0.25 * dx;
        for (y, rho) in rows.into_iter().filter(|r| r.0 < 0.1) {
            measured += rho as f64 / rho0 - 1.0;
            predicted += profile((top - y) as f64) - 1.0;
            samples += 1;
        }
    }
    let (measured, predicted) = (measured / samples as f64, predicted / samples as f64);
    let floor = profile(depth as f64) - 1.0;
    let tolerance = 2.0 * dx as f64 / depth as f64;
    println!(
        "bottom 10 cm: compression {:.2} % measured, {:.2} % Tait hydrostatic (floor {:.2} %, linear gH/c0² {:.2} %)",
        100.0 * measured,
        100.0 * predicted,
        100.0 * floor,
        100.0 * g * depth as f64 / (c0 * c0)
    );
    assert!(
        (measured / predicted - 1.0).abs() <= tolerance,
        "compression {measured:.4} against {predicted:.4}: more than {:.0} % apart",
        100.0 * tolerance
    );
}

/// The slime preset at one cell per step (`GameLiquid::Slime.config_projected`, safety 1): a
/// 5,184-particle column of it collapses in a tank at Δx = 5 cm for 2 s of 60 Hz frames without
/// a numerical failure, its conformation c = I + σᴺᴸ/G₀ positive definite on every particle at
/// the end. With the GS4-1 pair for the polymer stress (the update before choice D22) the same
/// run stopped at t = 1.15 s with a blow-up (ALGORITHM §2.8, BENCHMARKS.md (h)).
#[test]
fn the_slime_collapses_at_one_cell_per_step() {
    use treacle::game::GameLiquid;
    use treacle::rheology::tensor::symmetric_eigenvalues;
    use treacle::rheology::{PolymerStress, RheologyTable, Su2021Unified};
    let liquid = GameLiquid::Slime;
    let (dx, w, d) = (0.05_f32, 0.45_f32, 0.2_f32);
    let tank = Vec3::new(2.0 * w, 3.0 * d, w);
    let config = MpmConfig {
        dx,
        walls: DomainWalls::all(BoundaryCondition::Slip),
        ..liquid.config_projected(Vec3::ZERO, tank)
    };
    assert_eq!(config.time_step.safety, 1.0);
    let mut material = None;
    let mut app = headless_app_with(config, Materials::default(), |app| {
        app.add_plugins((TimePlugin, GamePlugin::default()));
        app.insert_resource(TimeUpdateStrategy::ManualDuration(Duration::from_secs_f64(
            1.0 / 60.0,
        )));
        material = Some(liquid.add_to(app));
    });
    let body = app
        .world_mut()
        .spawn((
            LiquidBody::new(
                ColliderShape::Box {
                    half_extents: Vec3::new(0.5 * w, d, 0.5 * w),
                },
                material.unwrap(),
            ),
            Transform::from_xyz(0.5 * w, d, 0.5 * w),
        ))
        .id();
    for _ in 0..=120 {
        app.update();
        assert_healthy(&app);
    }
    let particles = app.world().get::<SpawnedLiquid>(body).unwrap().particles;
    // The preset's own G₀, as the model resolves it for the material.
    let g0 = {
        let id = material.unwrap();
        let model = app.world().resource::<RheologyTable<Su2021Unified>>();
        let materials = app.world().resource::<Materials>();
        model.get(id).unwrap().resolve(materials.get(id)).modulus
    };
    let world = app.world_mut();
    let lowest = world
        .query::<&PolymerStress>()
        .iter(world)
        .map(|s| {
            let e = symmetric_eigenvalues(glam::DMat3::IDENTITY + s.value * (1.0 / g0));
            e[0].min(e[1]).min(e[2])
        })
        .fold(f64::INFINITY, f64::min);
    println!(
        "slime: {particles} particles, {:.2} s simulated; smallest eigenvalue of c {lowest:.3}",
        sim_time(&app)
    );
    assert_eq!(particles, 5184);
    assert!(lowest > 0.0, "{lowest}");
}
