//! The grid pressure projection (`PressureSolve::Projection`, ALGORITHM §5.4): a pool at rest
//! keeps still and its cell pressures are hydrostatic, a collapsing column keeps its volume,
//! and the sound speed no longer limits Δt.
use bevy_app::App;
use treacle::grid::MpmGrid;
use treacle::implicit::{PressureScratch, PressureSolveStats};
use treacle::prelude::*;

use crate::common::{app_with, assert_healthy, lattice};

fn projected(scheme: Scheme, min: Vec3, max: Vec3, dx: f32) -> MpmConfig {
    let mut config = MpmConfig {
        domain_min: min,
        domain_max: max,
        dx,
        walls: DomainWalls::all(BoundaryCondition::Slip),
        frame_dt: 1.0 / 60.0,
        ..MpmConfig::default()
    };
    config.integrator.scheme = scheme;
    config.integrator.pressure = PressureSolve::Projection(ProjectionConfig::default());
    config.time_step.max_dt = 1.0 / 60.0;
    config
}

fn volumes(app: &mut App, rho0: f32) -> (f64, f64) {
    let world = app.world_mut();
    let mut q = world.query::<(&Mass, &Density)>();
    q.iter(world).fold((0.0, 0.0), |(cur, rest), (m, r)| {
        (cur + (m.0 / r.value) as f64, rest + (m.0 / rho0) as f64)
    })
}

fn max_speed(app: &mut App) -> f32 {
    let world = app.world_mut();
    let mut q = world.query::<&Velocity>();
    q.iter(world).map(|v| v.0.length()).fold(0.0, f32::max)
}

/// A pool 0.3 m deep at rest, Δx = 2.5 cm, two particles per cell and axis, one second with
/// symplectic Euler and the projection. Exact for the discrete system: the hydrostatic cell
/// pressures balance gravity, so the velocities stay at the solver's residual.
#[test]
fn a_projected_pool_at_rest_stays_at_rest_with_hydrostatic_pressure() {
    let (dx, depth) = (0.025_f32, 0.3_f32);
    let config = projected(
        Scheme::SymplecticEuler,
        Vec3::ZERO,
        Vec3::new(0.2, 0.5, 0.2),
        dx,
    );
    let material = FluidMaterial::newtonian("water", 1000.0, 5.0, 1e-3);
    let h = 0.5 * dx;
    let positions = lattice(Vec3::ZERO, Vec3::new(0.2, depth, 0.2), h);
    let mut app = app_with(config, material, &positions, h, |_| Vec3::ZERO);
    let (v0, _) = volumes(&mut app, 1000.0);
    for frame in 0..60 {
        app.update();
        assert_healthy(&app);
        if frame % 10 == 9 {
            let (v, _) = volumes(&mut app, 1000.0);
            let vmax = max_speed(&mut app);
            let clock = app.world().resource::<SimulationClock>();
            let stats = app.world().resource::<PressureSolveStats>().0;
            println!(
                "t {:.3} steps {} max |v| {:.3e} volume {:.5} iterations mean {:.1} max {}",
                clock.time,
                clock.steps,
                vmax,
                v / v0,
                stats.mean_iterations(),
                stats.max_iterations
            );
        }
    }
    let world = app.world();
    let cells = world
        .resource::<PressureScratch>()
        .cell_pressures(world.resource::<MpmGrid>());
    let mut worst: f64 = 0.0;
    for (x, p) in &cells {
        let hydro = 1000.0 * 9.81 * (depth - x.y) as f64;
        worst = worst.max((p - hydro).abs());
    }
    println!(
        "{} cells, worst |p − ρg(H − y)| = {worst:.1} Pa of ρgH = {:.0}",
        cells.len(),
        1000.0 * 9.81 * depth
    );
    // The discrete hydrostatic state is an exact fixed point of the projected step; what is
    // left comes from stopping CG at rel_tol of the divergence gravity adds in a step (g Δt),
    // each solve correcting the whole residual (warm start): |v| ≲ rel_tol · g Δt_max, ×10 for
    // the uneven node masses at the surface.
    let rel_tol = ProjectionConfig::default().solver.rel_tol as f32;
    let bound = 10.0 * rel_tol * 9.81 / 60.0;
    let vmax = max_speed(&mut app);
    assert!(vmax <= bound, "max |v| {vmax:.3e} m/s above {bound:.3e}");
    // The cell pressures: the free surface is known to within half a particle spacing
    // (Δx/4), so ρg(H − y) within ρgΔx/4.
    let allowed = 1000.0 * 9.81 * 0.25 * dx as f64;
    assert!(
        worst <= allowed,
        "pressure {worst:.1} Pa from hydrostatic, allowed {allowed:.1}"
    );
    // No sound limit: 60 frames took at most two steps each (Tait at c₀ = 5 m/s would need
    // Δt ≤ 0.5 · Δx/c₀ = 2.5 ms, 400 steps in this second).
    let steps = app.world().resource::<SimulationClock>().steps;
    assert!(steps <= 120, "{steps} steps in one second");
}

/// A column 0.2 × 0.4 × 0.2 m collapses in a tank 0.8 × 0.6 × 0.2 m and settles: the pool it
/// leaves is as deep as the column's volume over the floor, V/A = 0.1 m. The depth is read as
/// twice the particles' mean height (exact for a flat layer), averaged over the fifth second to
/// take out the sloshing that is left. With the particles bunching up the pool would be
/// shallower: the Tait liquid at the same c₀ = 5 m/s reads 0.075 m (measured). Tolerance: a
/// quarter cell, Δx/4 — the floor's first particle layer compacts next to the mirror wall in
/// both pressure forms (1.6× a full layer here, 1.9× with Tait), which lowers the mean by about
/// that much.
#[test]
fn a_projected_dam_break_settles_to_the_depth_of_its_volume() {
    settle_depth(VelocityGradientSource::Gather);
}

fn settle_depth(source: VelocityGradientSource) {
    let dx = 0.025_f32;
    let mut config = projected(
        Scheme::SymplecticEuler,
        Vec3::ZERO,
        Vec3::new(0.8, 0.6, 0.2),
        dx,
    );
    config.integrator.flip_interval = FlipInterval::Seconds(1.0 / 60.0);
    config.integrator.velocity_gradient = source;
    let material = FluidMaterial::newtonian("water", 1000.0, 5.0, 1e-3);
    let h = 0.5 * dx;
    let positions = lattice(Vec3::ZERO, Vec3::new(0.2, 0.4, 0.2), h);
    let mut app = app_with(config, material, &positions, h, |_| Vec3::ZERO);
    let (mut sum, mut samples) = (0.0, 0);
    for frame in 0..300 {
        app.update();
        assert_healthy(&app);
        if frame >= 240 {
            let world = app.world_mut();
            let mut q = world.query::<&Position>();
            let (y, n) = q
                .iter(world)
                .fold((0.0f64, 0usize), |(y, n), x| (y + x.0.y as f64, n + 1));
            sum += 2.0 * y / n as f64;
            samples += 1;
        }
    }
    let depth = sum / samples as f64;
    let stats = app.world().resource::<PressureSolveStats>().0;
    let expected = 0.4 * 0.2 / 0.8;
    println!(
        "{source:?}: depth {depth:.4} m against V/A = {expected:.4} m; CG iterations mean \
         {:.1}, max {}",
        stats.mean_iterations(),
        stats.max_iterations
    );
    let tolerance = 0.25 * dx as f64;
    assert!(
        (depth - expected).abs() <= tolerance,
        "depth {depth:.4} m, V/A = {expected:.4} m, allowed ±{tolerance:.4}"
    );
}

/// The same collapse with the velocity gradient carried from G2P (`game_config_projected`'s
/// setting) settles to the same depth, with the same tolerance and reason.
#[test]
fn a_projected_dam_break_with_a_carried_velocity_gradient_settles_to_the_same_depth() {
    settle_depth(VelocityGradientSource::Carried);
}

/// The projection needs a first-order scheme and no periodic axis, and so does the carried
/// velocity gradient; the error names the field.
#[test]
fn the_projection_refuses_the_gs4_scheme_and_periodic_walls() {
    let p = PressureSolve::Projection(ProjectionConfig::default());
    let walls = DomainWalls::all(BoundaryCondition::Slip);
    let err = p.validate(Scheme::Gs4Explicit, &walls).unwrap_err();
    assert_eq!(err.0, "integrator.pressure");
    assert!(err.1.contains("first-order scheme"), "{}", err.1);
    let err = p
        .validate(
            Scheme::SymplecticEuler,
            &DomainWalls::all(BoundaryCondition::Periodic),
        )
        .unwrap_err();
    assert!(err.1.contains("periodic"), "{}", err.1);
    assert!(p.validate(Scheme::SymplecticEuler, &walls).is_ok());
    assert!(p.validate(Scheme::BackwardEulerViscous, &walls).is_ok());
    let carried = VelocityGradientSource::Carried;
    let err = carried.validate(Scheme::Gs4Explicit).unwrap_err();
    assert_eq!(err.0, "integrator.velocity_gradient");
    assert!(err.1.contains("first-order scheme"), "{}", err.1);
    assert!(carried.validate(Scheme::SymplecticEuler).is_ok());
    assert!(
        VelocityGradientSource::Gather
            .validate(Scheme::Gs4Explicit)
            .is_ok()
    );
}

/// The quasi-2D Martin & Moyce dam break at Δx = 2.5 mm and 4 cells deep (102,400 particles,
/// about 12,800 liquid cells: P2G's scatter, G2P's gather, the projection's block loops and
/// its operator's passes all run as parallel tasks on 2 threads) with the projection and the
/// carried velocity gradient, written as a scene file: `treacle run` gives byte-identical
/// particle files after two frames with 1 and 2 threads.
#[test]
fn the_projected_carried_step_is_deterministic_across_thread_counts() {
    let dir = crate::common::scratch("projected_threads");
    std::fs::create_dir_all(&dir).unwrap();
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("scenes/dam_break.ron")).unwrap();
    let integrator = "    integrator: (scheme: SymplecticEuler, pressure: Projection(()), \
                      velocity_gradient: Carried, flip_interval: Seconds(0.0166)),\n    \
                      time_step: (safety: 1.0, max_dt: 0.0166),\n    dx: 0.0025,";
    let text = text
        .replacen("    dx: 0.005,", integrator, 1)
        .replacen("max: (0.5, 0.25, 0.02)", "max: (0.5, 0.25, 0.01)", 1)
        .replacen("max: (0.1, 0.2, 0.02)", "max: (0.1, 0.2, 0.01)", 1);
    let scene = dir.join("dam_break_projected.ron");
    std::fs::write(&scene, text).unwrap();
    let run = |threads: &str| {
        let out = dir.join(format!("t{threads}"));
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_treacle"))
            .arg("run")
            .arg(&scene)
            .args(["--frames", "2", "--threads", threads, "--out"])
            .arg(&out)
            .current_dir(root)
            .output()
            .unwrap();
        assert!(
            o.status.success(),
            "{threads} threads: {}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        );
        std::fs::read(out.join("frame_00002.ply")).unwrap()
    };
    let (a, b) = (run("1"), run("2"));
    assert!(a == b, "the frames differ between 1 and 2 threads");
    let _ = std::fs::remove_dir_all(&dir);
}

/// In a scene file, `velocity_gradient: Carried` with the default GS4 scheme is refused with the
/// file, line and field; with symplectic Euler it loads.
#[test]
fn a_scene_file_refuses_a_carried_gradient_with_gs4() {
    let scene = |integrator: &str| {
        format!(
            "Scene(\n    domain: (min: (0, 0, 0), max: (1, 1, 1)),\n    dx: 0.05,\n    \
             duration: 0.1,\n    frame_rate: 30,\n    integrator: {integrator},\n    \
             materials: [(name: \"water\", density: 1000, sound_speed: 20)],\n    bodies: \
             [(material: \"water\", shape: Box(min: (0.1, 0.1, 0.1), max: (0.3, 0.3, 0.3)))],\n)\n"
        )
    };
    let parse = |text: &str| {
        treacle::scene::parse_scene_str(
            text,
            std::path::Path::new("test.ron"),
            std::path::Path::new("scenes"),
        )
    };
    let e = parse(&scene("(velocity_gradient: Carried)")).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("integrator.velocity_gradient"), "{msg}");
    assert!(msg.contains("test.ron:6"), "{msg}");
    assert!(msg.contains("first-order scheme"), "{msg}");
    let s = parse(&scene(
        "(scheme: SymplecticEuler, velocity_gradient: Carried)",
    ))
    .unwrap();
    assert_eq!(
        s.config.integrator.velocity_gradient,
        VelocityGradientSource::Carried
    );
}
