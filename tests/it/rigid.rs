//! Two-way coupled rigid bodies (`treacle::rigid`): free fall, momentum exchange with the
//! liquid, Archimedes flotation and sinking, scene files, determinism across thread counts.
use crate::common;

use bevy_app::App;
use bevy_ecs::prelude::*;
use common::*;
use glam::Quat;
use treacle::prelude::*;
use treacle::rigid::ActiveRigidBodies;

fn config(max: Vec3, dx: f32) -> MpmConfig {
    MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: max,
        dx,
        frame_dt: 0.02,
        ..Default::default()
    }
}

fn sphere_body(
    radius: f32,
    density: f32,
    at: Vec3,
    velocity: RigidVelocity,
    boundary: BoundaryCondition,
    gravity: Vec3,
) -> RigidBodyBundle {
    let shape = ColliderShape::Sphere { radius };
    RigidBodyBundle::new(
        RigidBody::solid(&shape, density).unwrap(),
        Collider { shape, boundary },
        ColliderPose {
            translation: at,
            rotation: Quat::IDENTITY,
        },
        velocity,
        gravity,
    )
}

fn body_state(app: &App, e: Entity) -> (ColliderPose, RigidVelocity) {
    (
        *app.world().get::<ColliderPose>(e).unwrap(),
        *app.world().get::<RigidVelocity>(e).unwrap(),
    )
}

/// Σ mₚvₚ over the particles, in f64.
fn liquid_momentum(app: &mut App) -> [f64; 3] {
    let world = app.world_mut();
    let mut q = world.query_filtered::<(&Mass, &Velocity), With<Particle>>();
    let mut p = [0.0f64; 3];
    for (m, v) in q.iter(world) {
        for (k, pk) in p.iter_mut().enumerate() {
            *pk += m.0 as f64 * v.0[k] as f64;
        }
    }
    p
}

fn liquid_mass(app: &mut App) -> f64 {
    let world = app.world_mut();
    let mut q = world.query_filtered::<&Mass, With<Particle>>();
    q.iter(world).map(|m| m.0 as f64).sum()
}

/// A tilted box dropped on a floor with friction in an empty domain lands on an edge, tips
/// over onto its largest face and comes to rest there (restitution 0, Coulomb friction μ = 0.5,
/// `rigid` module docs): its centre ends at the half height 0.02 m above the floor (the wall
/// push-out is exact; 10⁻⁴ m allows the projected Gauss–Seidel residual of the last steps), its
/// bottom face level, and it is at rest.
#[test]
fn tilted_box_settles_flat_on_the_floor() {
    let mut cfg = config(Vec3::ONE, 0.02);
    cfg.walls.y_min = BoundaryCondition::Friction(0.5);
    let g = cfg.gravity;
    let mut app = app_with(
        cfg,
        FluidMaterial::newtonian("water", 1000.0, 20.0, 0.001),
        &[],
        0.01,
        |_| Vec3::ZERO,
    );
    let shape = ColliderShape::Box {
        half_extents: Vec3::new(0.05, 0.02, 0.03),
    };
    let e = app
        .world_mut()
        .spawn(RigidBodyBundle::new(
            RigidBody::solid(&shape, 800.0).unwrap(),
            Collider {
                shape,
                boundary: BoundaryCondition::Slip,
            },
            ColliderPose {
                translation: Vec3::new(0.5, 0.2, 0.5),
                rotation: Quat::from_rotation_z(0.35) * Quat::from_rotation_x(0.1),
            },
            RigidVelocity::default(),
            g,
        ))
        .id();
    for _ in 0..60 {
        app.update();
    }
    assert_healthy(&app);
    let (pose, v) = body_state(&app, e);
    let up = pose.rotation * Vec3::Y;
    println!(
        "box: centre {}, local y axis {up}, v = {}, ω = {}",
        pose.translation, v.linear, v.angular
    );
    assert!(
        (pose.translation.y - 0.02).abs() < 1e-4,
        "not resting flat: y = {}",
        pose.translation.y
    );
    assert!(up.y.abs() > 1.0 - 1e-4, "bottom face not level: {up}");
    assert!(
        v.linear.length() < 1e-3 && v.angular.length() < 1e-2,
        "still moving"
    );
}

/// A spinning ball thrown in an empty domain follows x = x₀ + v₀t + ½gt² and v = v₀ + gt.
/// The body's update is GS4 with the consistent rate A = g, so ΔA = 0 and the trapezoidal
/// position rule is exact for constant acceleration: the only error is f32 round-off. Bound:
/// each of the N steps rounds the position (≤ ½ulp(|x|max)) and the velocity (≤ ½ulp(|v|max));
/// a velocity error made at step k moves the position by Δt per remaining step, so
/// |δx| ≤ N·½ulp(x) + Δt·N²/2·½ulp(v) and |δv| ≤ N·½ulp(v).
#[test]
fn ball_falls_freely_in_an_empty_domain() {
    let cfg = config(Vec3::ONE, 0.02);
    let g = cfg.gravity;
    let mut app = app_with(
        cfg,
        FluidMaterial::newtonian("water", 1000.0, 20.0, 0.001),
        &[],
        0.01,
        |_| Vec3::ZERO,
    );
    let x0 = Vec3::new(0.3, 0.8, 0.5);
    let v0 = Vec3::new(0.4, 0.5, -0.1);
    let w0 = Vec3::new(1.0, 2.0, 3.0);
    let e = app
        .world_mut()
        .spawn(sphere_body(
            0.05,
            1130.0,
            x0,
            RigidVelocity {
                linear: v0,
                angular: w0,
            },
            BoundaryCondition::Friction(0.3),
            g,
        ))
        .id();
    let frames = 20;
    for _ in 0..frames {
        app.update();
    }
    assert_healthy(&app);
    let clock = app.world().resource::<SimulationClock>().clone();
    let t = clock.time;
    let (pose, vel) = body_state(&app, e);
    let exact_x = x0.as_dvec3() + v0.as_dvec3() * t + 0.5 * g.as_dvec3() * t * t;
    let exact_v = v0.as_dvec3() + g.as_dvec3() * t;
    let n = clock.steps as f64;
    let dt = t / n;
    let half_ulp =
        |v: f64| (v as f32).abs().max(f32::MIN_POSITIVE) as f64 * f32::EPSILON as f64 * 0.5;
    let v_max = v0.length() as f64 + 9.81 * t;
    let tol_x = n * half_ulp(1.0) + dt * n * n / 2.0 * half_ulp(v_max);
    let tol_v = n * half_ulp(v_max);
    let err_x = (pose.translation.as_dvec3() - exact_x).abs().max_element();
    let err_v = (vel.linear.as_dvec3() - exact_v).abs().max_element();
    println!(
        "free fall: {} steps, t = {t}, |δx| = {err_x:.3e} (bound {tol_x:.3e}), |δv| = {err_v:.3e} (bound {tol_v:.3e})",
        clock.steps
    );
    assert!(clock.steps >= 20, "too few steps: {}", clock.steps);
    assert!(
        err_x <= tol_x,
        "position {} vs exact {exact_x}",
        pose.translation
    );
    assert!(err_v <= tol_v, "velocity {} vs exact {exact_v}", vel.linear);
    // A torque-free sphere keeps its angular velocity (its inertia is isotropic).
    assert!(
        (vel.angular - w0).length() <= 1e-5 * w0.length(),
        "angular velocity {} vs {w0}",
        vel.angular
    );
    // The pose turned by |ω|t about ω.
    let expected = Quat::from_axis_angle(w0.normalize(), w0.length() * t as f32);
    assert!(
        pose.rotation.angle_between(expected) < 1e-4,
        "rotation {:?} vs {expected:?}",
        pose.rotation
    );
}

/// A ball thrown into a free-falling liquid ball, far from every wall: the total momentum of
/// liquid and body changes by exactly (M_liquid + M_body)·g·t (see the `rigid` module docs:
/// the exchange conserves the GS4 pair (P, 𝒜) exactly). What remains is f32 round-off of the
/// particle sums and of Σᵢf̃ᵢ = 0; the tolerance, 10⁻⁴ of the momentum the liquid and the body
/// exchanged, is far below what an inconsistent exchange produces: exchanging the velocity
/// alone changes P by (λ₄ − λ₅/W₁Λ₆)Δt(𝒜 − M g) = Δt/7·ΣJ_a per step, of the order of the
/// exchange itself.
#[test]
fn momentum_of_liquid_and_body_changes_only_by_gravity() {
    let dx = 0.02;
    let h = dx / 2.0;
    let cfg = config(Vec3::ONE, dx);
    let g = cfg.gravity;
    let (c_liquid, r_liquid) = (Vec3::new(0.6, 0.6, 0.5), 0.08);
    let x0: Vec<Vec3> = lattice(Vec3::splat(0.0), Vec3::ONE, h)
        .into_iter()
        .filter(|p| (*p - c_liquid).length() <= r_liquid)
        .collect();
    let mut app = app_with(
        cfg,
        FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01),
        &x0,
        h,
        |_| Vec3::new(-1.0, 0.0, 0.0),
    );
    let body = sphere_body(
        0.05,
        1200.0,
        Vec3::new(0.35, 0.6, 0.5),
        RigidVelocity {
            linear: Vec3::new(1.5, 0.0, 0.0),
            angular: Vec3::new(0.0, 0.0, 5.0),
        },
        BoundaryCondition::Friction(0.3),
        g,
    );
    let m_body = body.body.mass as f64;
    let v_body0 = body.velocity.linear.as_dvec3();
    let e = app.world_mut().spawn(body).id();
    let m_liquid = liquid_mass(&mut app);
    let p0 = glam::DVec3::from(liquid_momentum(&mut app)) + m_body * v_body0;
    let mut worst = 0.0f64;
    let mut exchanged = 0.0f64;
    for frame in 1..=12 {
        app.update();
        assert_healthy(&app);
        let t = app.world().resource::<SimulationClock>().time;
        // The premise: no particle near a wall (the walls would add their impulses).
        let st = state(&mut app);
        let wall_gap = st
            .iter()
            .map(|s| s.1.min_element().min((Vec3::ONE - s.1).min_element()))
            .fold(f32::INFINITY, f32::min);
        assert!(wall_gap > 3.0 * dx, "frame {frame}: liquid reached a wall");
        let (_, v) = body_state(&app, e);
        let p = glam::DVec3::from(liquid_momentum(&mut app)) + m_body * v.linear.as_dvec3();
        let expected = p0 + (m_liquid + m_body) * g.as_dvec3() * t;
        let err = (p - expected).length();
        // Momentum the liquid gave the body so far.
        let j = (m_body * (v.linear.as_dvec3() - v_body0 - g.as_dvec3() * t)).length();
        exchanged = exchanged.max(j);
        worst = worst.max(err);
        println!("t = {t:.3}: |P − P₀ − M g t| = {err:.3e} kg m/s, exchanged {j:.3e} kg m/s");
    }
    let active = app.world().resource::<ActiveRigidBodies>();
    println!(
        "momentum: worst error {worst:.3e}, exchanged {exchanged:.3e}, last exchange {:?}",
        active.bodies[0].exchange
    );
    assert!(
        exchanged > 0.1,
        "the body and the liquid barely met ({exchanged:.3e} kg m/s): the test is not testing"
    );
    assert!(
        worst <= 1e-4 * exchanged,
        "momentum error {worst:.3e} kg m/s exceeds 1e-4 of the exchange {exchanged:.3e}"
    );
}

/// Liquid pool for the flotation tests: `depth` of liquid in a `size` box, minus the
/// particles inside a sphere (`center`, `radius`).
fn pool_app(size: Vec3, dx: f32, depth: f32, center: Vec3, radius: f32) -> App {
    let h = dx / 2.0;
    let x0: Vec<Vec3> = lattice(Vec3::ZERO, Vec3::new(size.x, depth, size.z), h)
        .into_iter()
        .filter(|p| (*p - center).length() > radius)
        .collect();
    let mut cfg = config(size, dx);
    cfg.frame_dt = 0.02;
    app_with(
        cfg,
        // Water density; 500× water's viscosity so the heave oscillation decays in ~1 s.
        FluidMaterial::newtonian("viscous water", 1000.0, 10.0, 0.5),
        &x0,
        h,
        |_| Vec3::ZERO,
    )
}

/// Σ mₚ/ρₚ \[m³\].
fn liquid_volume(app: &mut App) -> f64 {
    treacle::diagnostics::measure(app.world_mut()).particle_volume
}

/// Volume of the cap of a sphere of radius r below a plane at height `level`, centre `yc`.
fn submerged_volume(r: f64, yc: f64, level: f64) -> f64 {
    let h = (level - (yc - r)).clamp(0.0, 2.0 * r);
    std::f64::consts::PI * h * h * (3.0 * r - h) / 3.0
}

/// A sphere of half the liquid's density, released 1.6Δx below its Archimedes draught (its top
/// dry), rises and floats half immersed: its centre settles at the free surface L, where L
/// follows from the liquid volume Σmₚ/ρₚ plus the displaced volume over the pool's
/// cross-section.
///
/// Tolerance Δx: the liquid meets the body on the node layer nearest to its surface (φ ≤ ½Δx),
/// so the effective radius is R + δ with |δ| ≤ Δx/2; a half-immersed sphere of radius R + δ and
/// the same mass floats with its centre 2δ above the surface (the extra half-shell 2πR²δ of
/// displaced volume lifts it by 2δ over the waterplane πR²). The centre is averaged over the
/// last 0.4 s (several periods of the acoustic heave mode of the weakly compressible pool).
/// (A sphere released fully submerged carries a sub-cell film on its top that cannot drain;
/// see the `rigid` module docs.)
#[test]
fn light_sphere_floats_up_to_the_archimedes_draught() {
    let (dx, depth, radius) = (0.01f32, 0.12f32, 0.04f32);
    let size = Vec3::new(0.16, 0.24, 0.16);
    let start = Vec3::new(0.08, 0.10, 0.08);
    let mut app = pool_app(size, dx, depth, start, radius);
    let g = app.world().resource::<MpmConfig>().gravity;
    let area = (size.x * size.z) as f64;
    let r = radius as f64;
    let sphere_volume = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
    let level0 = (liquid_volume(&mut app) + 0.5 * sphere_volume) / area;
    let e = app
        .world_mut()
        .spawn(sphere_body(
            radius,
            500.0,
            start,
            RigidVelocity::default(),
            BoundaryCondition::Slip,
            g,
        ))
        .id();
    let frames = 100; // 2 s
    let mut ys = Vec::new();
    for f in 1..=frames {
        app.update();
        assert_healthy(&app);
        let (pose, v) = body_state(&app, e);
        if f % 10 == 0 {
            println!(
                "t = {:.2}: y = {:.4} vy = {:.4}",
                f as f32 * 0.02,
                pose.translation.y,
                v.linear.y
            );
        }
        if f > frames - 20 {
            ys.push(pose.translation.y as f64);
        }
    }
    let y_mean = ys.iter().sum::<f64>() / ys.len() as f64;
    // Level: A·L = V_liquid + V_submerged(L, y) (fixed point; V_sub varies slowly with L).
    let v_liquid = liquid_volume(&mut app);
    let mut level = v_liquid / area;
    for _ in 0..50 {
        level = (v_liquid + submerged_volume(r, y_mean, level)) / area;
    }
    let fraction = submerged_volume(r, y_mean, level) / sphere_volume;
    println!(
        "light sphere: start {:.4} m ({:.2} Δx below the expected surface {level0:.4} m), mean centre {y_mean:.5} m, surface {level:.5} m, centre − surface = {:.5} m ({:.2} Δx), immersed fraction {fraction:.3} (Archimedes 0.5)",
        start.y,
        (level0 - start.y as f64) / dx as f64,
        y_mean - level,
        (y_mean - level) / dx as f64
    );
    assert!(
        y_mean - start.y as f64 > 0.5 * (level - start.y as f64),
        "did not float up: centre {y_mean} from {}",
        start.y
    );
    assert!(
        (y_mean - level).abs() <= dx as f64,
        "centre {y_mean} vs surface {level}: more than Δx apart"
    );
}

/// A sphere 2.5× denser than the liquid sinks and comes to rest on the floor: its centre ends
/// within a quarter cell of y = R (the floor contact keeps it at y ≥ R exactly; a liquid film
/// thinner than a cell cannot hold it up), at rest.
#[test]
fn dense_sphere_sinks_to_the_bottom() {
    let (dx, depth, radius) = (0.01f32, 0.12f32, 0.04f32);
    let size = Vec3::new(0.16, 0.24, 0.16);
    let start = Vec3::new(0.08, 0.075, 0.08);
    let mut app = pool_app(size, dx, depth, start, radius);
    let g = app.world().resource::<MpmConfig>().gravity;
    let e = app
        .world_mut()
        .spawn(sphere_body(
            radius,
            2500.0,
            start,
            RigidVelocity::default(),
            BoundaryCondition::Friction(0.3),
            g,
        ))
        .id();
    for f in 1..=40 {
        app.update();
        assert_healthy(&app);
        if f % 5 == 0 {
            let (pose, v) = body_state(&app, e);
            println!(
                "t = {:.2}: y = {:.4} vy = {:.4}",
                f as f32 * 0.02,
                pose.translation.y,
                v.linear.y
            );
        }
    }
    let (pose, v) = body_state(&app, e);
    println!(
        "dense sphere: centre y = {:.5} m (R = {radius}), v = {}",
        pose.translation.y, v.linear
    );
    assert!(pose.translation.y >= radius - 1e-6, "below the floor");
    assert!(
        pose.translation.y - radius <= 0.25 * dx,
        "not on the floor: y = {}",
        pose.translation.y
    );
    assert!(v.linear.length() < 0.02, "still moving: {}", v.linear);
}

// ---------------------------------------------------------------------------------------------
// Scene files, validation, output and determinism.

fn parse(text: &str) -> Result<treacle::scene::Scene, treacle::scene::SceneError> {
    treacle::scene::parse_scene_str(
        text,
        std::path::Path::new("rigid.ron"),
        &crate_dir().join("scenes"),
    )
}

/// A pool with a ball above it: `{RIGID}` is replaced by the `rigid_bodies` entries.
const POOL: &str = r#"Scene(
    domain: (min: (0, 0, 0), max: (0.2, 0.3, 0.2)),
    dx: 0.02,
    duration: 0.1,
    frame_rate: 50,
    materials: [(name: "ketchup", density: 1100, sound_speed: 10, viscosity: 1)],
    bodies: [(material: "ketchup", shape: Box(min: (0, 0, 0), max: (0.2, 0.12, 0.2)))],
    rigid_bodies: [
{RIGID}
    ],
)
"#;

fn pool(rigid: &str) -> String {
    POOL.replace("{RIGID}", rigid)
}

/// The golf ball of `docs/scenes.md`: mass given, inertia 2/5 M r², pose and velocity as
/// written; a second body given by density gets M = ρ·8 h_x h_y h_z; liquid particles inside
/// a body are not created.
#[test]
fn scene_rigid_bodies_load_with_mass_properties() {
    let text = pool(
        r#"        (shape: Sphere(radius: 0.02135), mass: 0.0459, position: (0.1, 0.2, 0.1),
         velocity: (0, -3, 0), angular_velocity: (0, 0, 10), boundary: Friction(0.3)),
        (shape: Box(half_extents: (0.02, 0.01, 0.03)), density: 500, position: (0.1, 0.1, 0.1),
         rotation: Euler(z: 20), boundary: Slip),"#,
    );
    let scene = parse(&text).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.rigid_bodies.len(), 2);
    let ball = &scene.rigid_bodies[0];
    assert_eq!(ball.body.mass, 0.0459);
    let i = 0.4 * 0.0459 * 0.02135f32 * 0.02135;
    assert!((ball.body.inertia - Vec3::splat(i)).abs().max_element() < 1e-6 * i);
    assert_eq!(ball.pose.translation, Vec3::new(0.1, 0.2, 0.1));
    assert_eq!(ball.velocity.linear, Vec3::new(0.0, -3.0, 0.0));
    assert_eq!(ball.velocity.angular, Vec3::new(0.0, 0.0, 10.0));
    assert_eq!(ball.acceleration.linear, scene.config.gravity);
    assert_eq!(ball.collider.boundary, BoundaryCondition::Friction(0.3));
    let plank = &scene.rigid_bodies[1];
    let m = 500.0 * 8.0 * 0.02 * 0.01 * 0.03;
    assert!(
        (plank.body.mass - m).abs() < 1e-6 * m,
        "{}",
        plank.body.mass
    );
    // The plank sits inside the pool: its particles were not created.
    let liquid = &scene.particles[0];
    assert!(liquid.positions.iter().all(|p| !plank.contains(*p)));
    let full = (0.2f64 * 0.12 * 0.2 / (0.01f64).powi(3)).round() as usize;
    let removed = full - liquid.positions.len();
    let expected = 8.0 * 0.02 * 0.01 * 0.03 / 1e-6; // volume / h³
    println!("particles removed by the plank: {removed} (its volume holds {expected:.0})");
    assert!(removed > 0 && (removed as f64) < 2.0 * expected);
}

/// Bad rigid bodies are rejected with the file, line and field: a negative radius, both
/// density and mass, a body outside the domain, a `Periodic` surface condition.
#[test]
fn scene_rigid_body_errors_name_file_line_and_field() {
    let cases = [
        (
            "        (shape: Sphere(radius: -0.01), density: 1000, position: (0.1, 0.2, 0.1), boundary: Slip),",
            "rigid_bodies[0].shape.radius",
            "must be a finite number > 0 m (got -0.01)",
        ),
        (
            "        (shape: Sphere(radius: 0.01), density: 1000, mass: 1, position: (0.1, 0.2, 0.1), boundary: Slip),",
            "rigid_bodies[0].mass",
            "not both",
        ),
        (
            "        (shape: Sphere(radius: 0.01), boundary: Slip, position: (0.1, 0.2, 0.1)),",
            "rigid_bodies[0]",
            "needs `density",
        ),
        (
            "        (shape: Box(half_extents: (0.0625, 0.0625, 0.0625)), mass: 1, position: (0.1, 0.25, 0.1), boundary: Slip),",
            "rigid_bodies[0].position",
            "on y it spans [0.1875, 0.3125] m but the domain is [0, 0.3] m",
        ),
        (
            "        (shape: Sphere(radius: 0.01), mass: 1, position: (0.1, 0.2, 0.1), boundary: Periodic),",
            "rigid_bodies[0].boundary",
            "use Sticky, Slip or Friction",
        ),
    ];
    for (entry, field, message) in cases {
        let text = pool(entry);
        let e = match parse(&text) {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e.to_string(),
        };
        // The entry is on line 9 of the scene text.
        assert!(
            e.contains("rigid.ron:9:")
                && e.contains(&format!("field `{field}`"))
                && e.contains(message),
            "expected `{field}`: {message} at rigid.ron:9, got:\n{e}"
        );
    }
}

/// The `rigid_bodies` example of `docs/scenes.md` is a valid section.
#[test]
fn documented_rigid_bodies_example_is_valid() {
    let doc = std::fs::read_to_string(crate_dir().join("docs/scenes.md")).unwrap();
    let section = &doc[doc
        .find("## `rigid_bodies`")
        .expect("the rigid_bodies section")..];
    let start = section.find("rigid_bodies: [").unwrap() + "rigid_bodies: [".len();
    let end = start + section[start..].find("\n],").unwrap();
    let text = format!(
        r#"Scene(domain: (min: (0, 0, 0), max: (0.3, 0.4, 0.2)), dx: 0.01, duration: 0.1,
        frame_rate: 50, rigid_bodies: [{}], )"#,
        &section[start..end]
    );
    let scene = parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(scene.rigid_bodies.len(), 2);
}

/// `treacle run` on a scene with a ball dropped into a viscous pool gives identical files
/// (particle frames and metrics.csv without the wall time) with 1 and 2 worker threads, and
/// metrics.csv carries the ball's columns, which follow free fall before the ball reaches the
/// liquid.
#[test]
fn run_with_a_rigid_body_is_deterministic_across_thread_counts() {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("treacle-rigid-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("ball.ron");
    std::fs::write(
        &scene,
        pool(
            "        (shape: Sphere(radius: 0.03), density: 1300, position: (0.1, 0.25, 0.1), \
             velocity: (0, -1, 0), angular_velocity: (3, 0, 1), boundary: Friction(0.3)),",
        )
        .replace("duration: 0.1", "duration: 0.12"),
    )
    .unwrap();
    let run = |threads: &str, out: &str| {
        let out = dir.join(out);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_treacle"))
            .args([
                "run",
                scene.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ])
            .args(["--threads", threads])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        out
    };
    let (a, b) = (run("1", "t1"), run("2", "t2"));
    let metrics = |d: &std::path::Path| -> Vec<Vec<String>> {
        let text = std::fs::read_to_string(d.join("metrics.csv")).unwrap();
        let mut rows: Vec<Vec<String>> = text
            .lines()
            .map(|l| l.split(',').map(str::to_string).collect())
            .collect();
        let wall = rows[0].iter().position(|c| c == "wall_seconds").unwrap();
        for r in &mut rows {
            r.remove(wall);
        }
        rows
    };
    let (ma, mb) = (metrics(&a), metrics(&b));
    assert_eq!(ma, mb, "metrics differ between 1 and 2 threads");
    let mut frames: Vec<_> = std::fs::read_dir(&a)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.to_string_lossy().ends_with(".ply"))
        .collect();
    frames.sort();
    assert_eq!(frames.len(), 7);
    for f in &frames {
        assert!(
            std::fs::read(a.join(f)).unwrap() == std::fs::read(b.join(f)).unwrap(),
            "{f:?} differs between 1 and 2 threads"
        );
    }
    // The ball's columns: y(t) = 0.25 − t − g t²/2 until it nears the liquid (at t = 0.02 s its
    // bottom is 5 cm above the highest node the liquid reaches). Tolerance: f32 round-off of
    // about 20 steps, N·½ulp(y) + Δt·N²/2·½ulp(v) ≈ 3·10⁻⁷ m (see the free-fall test), ×3.
    let header = &ma[0];
    let col = |name: &str| header.iter().position(|c| c == name).expect(name);
    let (t, y, vy) = (col("time"), col("rigid0_y"), col("rigid0_vy"));
    // Row 1 is frame 0; row 2 is the end of frame 1.
    let row1: Vec<f64> = ma[2].iter().map(|v| v.parse().unwrap()).collect();
    let t1 = row1[t];
    let y_exact = 0.25 - t1 - 0.5 * 9.81 * t1 * t1;
    println!(
        "ball at t = {t1}: y = {} (free fall {y_exact}), vy = {}",
        row1[y], row1[vy]
    );
    assert!(
        (row1[y] - y_exact).abs() < 1e-6,
        "y = {} vs {y_exact}",
        row1[y]
    );
    let last: Vec<f64> = ma
        .last()
        .unwrap()
        .iter()
        .map(|v| v.parse().unwrap())
        .collect();
    println!(
        "ball at t = {}: y = {}, vy = {}",
        last[t], last[y], last[vy]
    );
    // It entered the liquid (centre below surface + radius) and the liquid slowed it far
    // below its free-fall speed 1 + g t.
    let free_fall_speed = 1.0 + 9.81 * last[t];
    assert!(
        last[y] < 0.12 + 0.03,
        "the ball did not enter the liquid: y = {}",
        last[y]
    );
    assert!(
        last[vy].abs() < 0.5 * free_fall_speed,
        "the liquid did not slow the ball: vy = {}",
        last[vy]
    );
}
