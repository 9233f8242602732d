//! Collision objects (ALGORITHM §2.11): static and scripted moving colliders, sticky walls, and
//! the paper-compatible time-step rule.
use crate::common;

use common::*;
use glam::Quat;
use treacle::diagnostics::measure;
use treacle::prelude::*;

fn config(max: Vec3, dx: f32) -> MpmConfig {
    MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: max,
        dx,
        frame_dt: 0.02,
        ..Default::default()
    }
}

fn signed_distance(c: &Collider, pose: &ColliderPose, x: Vec3) -> f32 {
    let local = pose.rotation.inverse() * (x - pose.translation);
    c.shape.sdf(local).0
}

/// A liquid cube dropped on a static box "table" (inside the domain, above the floor) comes to
/// rest on top of it: no particle ends inside the table (beyond a small fraction of a cell,
/// the particle-level push-out tolerance) and the liquid's centre of mass stays above the
/// table's top face.
#[test]
fn liquid_rests_on_a_static_box() {
    let dx = 0.02;
    let h = dx / 2.0;
    let x0 = lattice(Vec3::new(0.4, 0.5, 0.4), Vec3::new(0.6, 0.7, 0.6), h);
    let mat = FluidMaterial::newtonian("honey", 1000.0, 20.0, 5.0);
    let mut app = app_with(config(Vec3::ONE, dx), mat, &x0, h, |_| Vec3::ZERO);
    let table = Collider {
        shape: ColliderShape::Box {
            half_extents: Vec3::new(0.3, 0.1, 0.3),
        },
        boundary: BoundaryCondition::Slip,
    };
    let pose = ColliderPose {
        translation: Vec3::new(0.5, 0.2, 0.5),
        rotation: Quat::IDENTITY,
    };
    app.world_mut().spawn((table.clone(), pose));
    for _ in 0..30 {
        app.update();
    }
    assert_healthy(&app);
    let st = state(&mut app);
    let worst = st
        .iter()
        .map(|s| signed_distance(&table, &pose, s.1))
        .fold(f32::INFINITY, f32::min);
    assert!(
        worst > -0.05 * dx,
        "a particle is {worst} m inside the table"
    );
    let com = measure(app.world_mut()).center_of_mass;
    assert!(
        com[1] > 0.3,
        "the liquid fell through: centre of mass y = {}",
        com[1]
    );
}

/// A sphere moved by script through a resting pool pushes the liquid: the liquid gains
/// momentum along the sphere's motion, and no particle is left inside the sphere.
#[test]
fn scripted_sphere_pushes_liquid() {
    let dx = 0.02;
    let h = dx / 2.0;
    let x0 = lattice(Vec3::ZERO, Vec3::new(1.0, 0.2, 0.2), h);
    let mat = FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01);
    let mut app = app_with(config(Vec3::new(1.0, 0.4, 0.2), dx), mat, &x0, h, |_| {
        Vec3::ZERO
    });
    let sphere = Collider {
        shape: ColliderShape::Sphere { radius: 0.06 },
        boundary: BoundaryCondition::Slip,
    };
    let pose = ColliderPose {
        translation: Vec3::new(0.2, 0.1, 0.1),
        rotation: Quat::IDENTITY,
    };
    let e = app
        .world_mut()
        .spawn((
            sphere.clone(),
            pose,
            ColliderMotion {
                linear_velocity: Vec3::new(1.0, 0.0, 0.0),
                angular_velocity: Vec3::ZERO,
            },
        ))
        .id();
    for _ in 0..10 {
        app.update();
    }
    assert_healthy(&app);
    let pose_now = *app.world().get::<ColliderPose>(e).unwrap();
    assert!(
        (pose_now.translation.x - 0.4).abs() < 1e-4,
        "{}",
        pose_now.translation
    );
    let st = state(&mut app);
    let px: f32 = st.iter().map(|s| s.2.x).sum();
    assert!(px > 0.0, "no momentum along the motion: {px}");
    let worst = st
        .iter()
        .map(|s| signed_distance(&sphere, &pose_now, s.1))
        .fold(f32::INFINITY, f32::min);
    assert!(
        worst > -0.05 * dx,
        "a particle is {worst} m inside the sphere"
    );
}

/// A sticky floor holds the bottom of a layer that starts sliding at 1 m/s: the particles of
/// the lowest particle row (within ½ cell of the floor) move much slower than the layer's
/// mean, while with a slip floor the whole layer keeps its speed (no gravity along x).
#[test]
fn sticky_floor_holds_the_bottom_layer() {
    let dx = 0.02;
    let h = dx / 2.0;
    let run = |bc: BoundaryCondition| {
        let mut cfg = config(Vec3::new(0.4, 0.2, 2.0 * dx), dx);
        cfg.walls = DomainWalls {
            x_min: BoundaryCondition::Periodic,
            x_max: BoundaryCondition::Periodic,
            y_min: bc,
            ..Default::default()
        };
        let x0 = lattice(Vec3::ZERO, Vec3::new(0.4, 0.1, 2.0 * dx), h);
        let mat = FluidMaterial::newtonian("oil", 1000.0, 20.0, 0.5);
        let mut app = app_with(cfg, mat, &x0, h, |_| Vec3::new(1.0, 0.0, 0.0));
        for _ in 0..5 {
            app.update();
        }
        assert_healthy(&app);
        let st = state(&mut app);
        let bottom: Vec<f32> = st
            .iter()
            .filter(|s| s.1.y < 0.5 * h + 1e-3)
            .map(|s| s.2.x)
            .collect();
        let mean = st.iter().map(|s| s.2.x).sum::<f32>() / st.len() as f32;
        (bottom.iter().sum::<f32>() / bottom.len() as f32, mean)
    };
    let (bottom_sticky, mean_sticky) = run(BoundaryCondition::Sticky);
    let (bottom_slip, mean_slip) = run(BoundaryCondition::Slip);
    eprintln!(
        "sticky: bottom {bottom_sticky:.3} mean {mean_sticky:.3}; slip: bottom {bottom_slip:.3} mean {mean_slip:.3}"
    );
    assert!(bottom_sticky < 0.5 * mean_sticky);
    assert!((mean_slip - 1.0).abs() < 1e-3 && (bottom_slip - 1.0).abs() < 1e-3);
}

/// The paper-compatible rule ([Su21] §7.1.4) gives Δt = 0.5 min{Δx/|u|, [2ν/Δx² + |u|/Δx]⁻¹}
/// — no sound-speed term — capped by max_dt.
#[test]
fn paper_time_step_rule() {
    let dx = 0.02;
    let h = dx / 2.0;
    let mut cfg = config(Vec3::ONE, dx);
    cfg.gravity = Vec3::ZERO;
    cfg.time_step.mode = TimeStepMode::Paper;
    cfg.time_step.max_dt = 1.0; // so the formula, not the cap, decides
    let x0 = lattice(Vec3::splat(0.4), Vec3::splat(0.6), h);
    let (mu, rho, u) = (2.0f32, 1000.0f32, 0.5f32);
    let mat = FluidMaterial::newtonian("syrup", rho, 50.0, mu);
    let mut app = app_with(cfg, mat, &x0, h, move |_| Vec3::new(u, 0.0, 0.0));
    app.update();
    assert_healthy(&app);
    let clock = app.world().resource::<SimulationClock>().clone();
    // ν is max μ/ρ̃ over particles (predicted density), within 1e-3 of μ/ρ₀ here.
    let nu = clock.maxima.kinematic_viscosity as f64;
    assert!((nu / (mu / rho) as f64 - 1.0).abs() < 1e-3);
    let speed = clock.maxima.speed as f64;
    let dx = dx as f64;
    let expect = 0.5 * (dx / speed).min(1.0 / (2.0 * nu / (dx * dx) + speed / dx));
    assert!(expect < 0.02, "the case must not be capped by the frame");
    assert!(
        (clock.next_dt - expect).abs() < 1e-9 * expect,
        "{} vs {expect}",
        clock.next_dt
    );
}

/// A tilted plane collider (half-space through (0.5, 0.3, 0.5), normal tilted 20° about z):
/// liquid dropped on it ends above the plane (no particle deeper than a small fraction of a
/// cell) and slides down its slope (+x for this tilt).
#[test]
fn liquid_slides_on_a_tilted_plane() {
    let dx = 0.02;
    let h = dx / 2.0;
    let x0 = lattice(Vec3::new(0.4, 0.45, 0.4), Vec3::new(0.6, 0.6, 0.6), h);
    let mat = FluidMaterial::newtonian("oil", 1000.0, 20.0, 1.0);
    let mut app = app_with(config(Vec3::ONE, dx), mat, &x0, h, |_| Vec3::ZERO);
    let tilt = 20.0f32.to_radians();
    let plane = Collider {
        shape: ColliderShape::HalfSpace { normal: Vec3::Y },
        boundary: BoundaryCondition::Slip,
    };
    let pose = ColliderPose {
        translation: Vec3::new(0.5, 0.3, 0.5),
        rotation: Quat::from_rotation_z(-tilt),
    };
    app.world_mut().spawn((plane.clone(), pose));
    for _ in 0..20 {
        app.update();
    }
    assert_healthy(&app);
    let st = state(&mut app);
    let worst = st
        .iter()
        .map(|s| signed_distance(&plane, &pose, s.1))
        .fold(f32::INFINITY, f32::min);
    assert!(
        worst > -0.05 * dx,
        "a particle is {worst} m below the plane"
    );
    let vx = st.iter().map(|s| s.2.x).sum::<f32>() / st.len() as f32;
    assert!(
        vx > 0.05,
        "the liquid does not slide down the slope: mean vx = {vx}"
    );
}

/// A pool filling the domain's width stays at rest between its side walls: the min and max faces
/// act alike. With Δx = 0.01 m the node on the max face sits at 20 · 0.01f32 < 0.2f32; before
/// the wall test allowed for that rounding, the max faces had no wall layer on the face and the
/// pool drifted towards them (mean vx = 1.85e-2 m/s after 0.1 s, particles reaching the face).
#[test]
fn pool_at_rest_does_not_drift_towards_the_max_walls() {
    let text = r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.2, 0.1, 0.2)),
    dx: 0.01,
    gravity: (0.0, -9.81, 0.0),
    duration: 0.05,
    frame_rate: 20.0,
    walls: (y_min: Sticky),
    materials: [(name: "w", density: 1000.0, sound_speed: 20.0, viscosity: 1.0)],
    bodies: [(material: "w", shape: Box(min: (0.0, 0.0, 0.0), max: (0.2, 0.05, 0.2)))],
)"#;
    let scene = treacle::scene::parse_scene_str(
        text,
        std::path::Path::new("pool.ron"),
        std::path::Path::new("scenes"),
    )
    .unwrap();
    let mut app = treacle::runner::scene_app(&scene);
    app.update();
    let world = app.world_mut();
    assert!(world.resource::<SimulationStatus>().failure.is_none());
    let (mut n, mut sum, mut lo, mut hi) = (0.0f64, Vec3::ZERO.as_dvec3(), 1.0f32, 0.0f32);
    for (x, v) in world
        .query_filtered::<(&Position, &Velocity), bevy_ecs::query::With<Particle>>()
        .iter(world)
    {
        n += 1.0;
        sum += v.0.as_dvec3();
        lo = lo.min(x.0.x.min(x.0.z));
        hi = hi.max(x.0.x.max(x.0.z));
    }
    let mean = sum / n;
    // Symmetric set-up: the mean horizontal velocity is zero up to f32 round-off of the sums
    // (≈ 1e-7 of the ≈ 0.05 m/s sloshing speeds).
    assert!(
        mean.x.abs() < 1e-5 && mean.z.abs() < 1e-5,
        "mean velocity {mean}"
    );
    // Particles start h/2 = 2.5 mm from each wall; a few tenths of a millimetre of settling
    // is allowed on both sides alike.
    assert!(
        (lo - (0.2 - hi)).abs() < 2e-4,
        "gap at the min faces {lo} m, at the max faces {} m",
        0.2 - hi
    );
}

/// Mean height and mean vertical velocity of the (equal-mass) particles \[m, m/s\].
fn mean_height(app: &mut bevy_app::App) -> (f64, f64) {
    let world = app.world_mut();
    let mut q = world.query::<(&Position, &Velocity)>();
    let (s, v, n) = q.iter(world).fold((0.0, 0.0, 0.0), |(s, v, n), (x, u)| {
        (s + x.0.y as f64, v + u.0.y as f64, n + 1.0)
    });
    (s / n, v / n)
}

/// `remove_at` (a [`ColliderLifetime`]): a viscous block rests on a shelf until the shelf is
/// removed at t = 0.05 s, then falls freely. Held: the centre of mass moves < 5 mm in the
/// first 0.05 s (settling on the shelf). Dropped: 0.1 s later, still in free fall (the
/// floor is 8 cm below), the centre of mass has moved by v₁·0.1 s + ½g(0.1 s)² (≈ 5 cm) from
/// its height and mean velocity v₁ at t = 0.05 s; tolerance 5 %: the removal happens at the
/// end of the step reaching 0.05 s, so the fall may start up to one step (Δt ≈ 1 ms) late,
/// ≈ g·0.1 s·Δt ≈ 1 mm = 2 % of the drop.
#[test]
fn collider_removed_at_its_time_drops_what_rests_on_it() {
    let text = r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.2, 0.24, 0.2)),
    dx: 0.01,
    duration: 0.15,
    frame_rate: 20.0,
    materials: [(name: "goo", density: 1000.0, sound_speed: 10.0, viscosity: 0.5)],
    bodies: [(material: "goo", shape: Box(min: (0.06, 0.12, 0.06), max: (0.14, 0.16, 0.14)))],
    colliders: [(shape: Box(half_extents: (0.08, 0.01, 0.08)), boundary: Sticky,
                 translation: (0.1, 0.11, 0.1), remove_at: Some(0.05))],
)"#;
    let scene = treacle::scene::parse_scene_str(
        text,
        std::path::Path::new("shelf.ron"),
        std::path::Path::new("."),
    )
    .unwrap();
    let mut app = treacle::runner::scene_app(&scene);
    let (y0, _) = mean_height(&mut app);
    app.update();
    let (y1, v1) = mean_height(&mut app);
    let colliders = {
        let world = app.world_mut();
        world.query::<&Collider>().iter(world).count()
    };
    app.update();
    app.update();
    let (y3, _) = mean_height(&mut app);
    let (t, g) = (0.1, 9.81);
    let expected = -v1 * t + 0.5 * g * t * t;
    println!(
        "centre height {y0:.4} → {y1:.4} (t = 0.05, v = {v1:.4}) → {y3:.4} (t = 0.15); \
         drop {:.4} against {expected:.4}",
        y1 - y3
    );
    assert_eq!(colliders, 0, "the shelf is gone at t = 0.05 s");
    assert!((y0 - y1).abs() < 5e-3, "held: moved {} m", y0 - y1);
    let drop = y1 - y3;
    assert!(
        (drop / expected - 1.0).abs() < 0.05,
        "dropped {drop} m, free fall {expected} m"
    );
}

/// A non-positive `remove_at` is rejected with the field path.
#[test]
fn non_positive_remove_at_is_rejected() {
    let text = r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.2, 0.2, 0.2)),
    dx: 0.01,
    duration: 0.1,
    frame_rate: 20.0,
    materials: [(name: "goo", density: 1000.0, sound_speed: 10.0, viscosity: 0.5)],
    bodies: [(material: "goo", shape: Box(min: (0.06, 0.12, 0.06), max: (0.14, 0.16, 0.14)))],
    colliders: [(shape: Box(half_extents: (0.08, 0.01, 0.08)), boundary: Sticky,
                 translation: (0.1, 0.11, 0.1), remove_at: Some(-1.0))],
)"#;
    let err = treacle::scene::parse_scene_str(
        text,
        std::path::Path::new("shelf.ron"),
        std::path::Path::new("."),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("colliders[0].remove_at"), "{err}");
    assert!(err.contains("> 0"), "{err}");
}

/// A sphere pushing through a pool, scripted either by a constant velocity or by a keyframed
/// path (`colliders[0].path`) with the same motion: at rest until 0.02 s, then 0.8 m/s along
/// x. `motion` is the collider's motion fields in the scene text.
fn pushed_pool_text(motion: &str) -> String {
    format!(
        r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.4, 0.2, 0.2)),
    dx: 0.02,
    duration: 0.1,
    frame_rate: 50.0,
    materials: [(name: "water", density: 1000.0, sound_speed: 20.0, viscosity: 0.01)],
    bodies: [(material: "water", shape: Box(min: (0.0, 0.0, 0.0), max: (0.4, 0.1, 0.2)))],
    colliders: [(shape: Sphere(radius: 0.05), boundary: Sticky,
        {motion})],
)"#
    )
}

fn pushed_pool(motion: &str) -> bevy_app::App {
    let scene = treacle::scene::parse_scene_str(
        &pushed_pool_text(motion),
        std::path::Path::new("push.ron"),
        std::path::Path::new("."),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    treacle::runner::scene_app(&scene)
}

/// A keyframed path moves a collider through its keys (the pose after each frame is the
/// path's position, its motion the segment's velocity), at rest before the first key, and it
/// pushes the liquid as the same motion scripted by a velocity does: after 0.08 s of motion
/// every particle is within 10⁻³ Δx of its place in the velocity-scripted run (the two differ
/// only in how the pose is rounded: reset to the path each step, or advanced by v·Δt).
#[test]
fn keyframed_collider_path_moves_like_a_scripted_velocity() {
    let mut by_path = pushed_pool(
        "path: [(time: 0.02, translation: (0.08, 0.1, 0.1)), \
         (time: 0.12, translation: (0.16, 0.1, 0.1))]",
    );
    let mut at_rest = pushed_pool("translation: (0.08, 0.1, 0.1)");
    // Both at rest for the first frame (0.02 s).
    by_path.update();
    at_rest.update();
    let poses = |app: &mut bevy_app::App| {
        let world = app.world_mut();
        let mut q = world.query::<(&ColliderPose, Option<&ColliderMotion>)>();
        q.iter(world)
            .map(|(p, m)| (*p, m.copied()))
            .collect::<Vec<_>>()
    };
    let (p, m) = poses(&mut by_path)[0];
    assert!((p.translation - Vec3::new(0.08, 0.1, 0.1)).length() < 1e-6);
    assert_eq!(
        m.unwrap().linear_velocity,
        Vec3::ZERO,
        "at rest before the motion"
    );
    let first = state(&mut by_path);
    let rest = state(&mut at_rest);
    for (a, b) in first.iter().zip(&rest) {
        assert_eq!(a.1, b.1, "identical while the path is at rest");
    }
    // From here: the velocity-scripted twin moves at 0.8 m/s.
    {
        let world = at_rest.world_mut();
        let mut q =
            world.query_filtered::<bevy_ecs::entity::Entity, bevy_ecs::query::With<Collider>>();
        let e = q.single(world).unwrap();
        world.entity_mut(e).insert(ColliderMotion {
            linear_velocity: Vec3::new(0.8, 0.0, 0.0),
            angular_velocity: Vec3::ZERO,
        });
    }
    for frame in 2..=5 {
        by_path.update();
        at_rest.update();
        let t = 0.02 * frame as f32;
        let (p, m) = poses(&mut by_path)[0];
        let expect = Vec3::new(0.08 + 0.8 * (t - 0.02), 0.1, 0.1);
        assert!(
            (p.translation - expect).length() < 1e-5,
            "frame {frame}: at {} against {expect}",
            p.translation
        );
        let v = m.unwrap().linear_velocity;
        assert!((v - Vec3::new(0.8, 0.0, 0.0)).length() < 1e-3, "v = {v}");
    }
    assert_healthy(&by_path);
    let a = state(&mut by_path);
    let b = state(&mut at_rest);
    let dx = 0.02f32;
    let worst = a
        .iter()
        .zip(&b)
        .map(|(a, b)| (a.1 - b.1).length())
        .fold(0.0f32, f32::max);
    let moved = a
        .iter()
        .zip(&first)
        .map(|(a, b)| (a.1 - b.1).length())
        .fold(0.0f32, f32::max);
    println!("largest particle gap {worst:.3e} m; largest displacement {moved:.3e} m");
    assert!(moved > dx, "the sphere pushed the liquid ({moved} m)");
    assert!(
        worst < 1e-3 * dx,
        "path and velocity runs differ by {worst} m"
    );
}

/// A path that goes back in time, or comes with a `translation`, is rejected with the field
/// path and the line.
#[test]
fn bad_collider_paths_are_rejected() {
    let parse = |motion: &str| {
        let text = pushed_pool_text(motion);
        treacle::scene::parse_scene_str(
            &text,
            std::path::Path::new("push.ron"),
            std::path::Path::new("."),
        )
        .map(|_| ())
        .map_err(|e| e.to_string())
    };
    let err = parse(
        "path: [(time: 0.05, translation: (0.1, 0.1, 0.1)), \
         (time: 0.05, translation: (0.2, 0.1, 0.1))]",
    )
    .unwrap_err();
    assert!(
        err.contains("colliders[0].path[1].time") && err.contains("increase"),
        "{err}"
    );
    assert!(err.contains("push.ron:9"), "{err}");
    let err =
        parse("translation: (0.1, 0.1, 0.1), path: [(time: 0.0, translation: (0.1, 0.1, 0.1))]")
            .unwrap_err();
    assert!(
        err.contains("colliders[0].path") && err.contains("translation"),
        "{err}"
    );
    let err = parse("path: [(time: -1.0, translation: (0.1, 0.1, 0.1))]").unwrap_err();
    assert!(err.contains("colliders[0].path[0].time"), "{err}");
    assert!(parse("path: [(time: 0.0, translation: (0.1, 0.1, 0.1))]").is_ok());
}
