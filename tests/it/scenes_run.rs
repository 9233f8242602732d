//! Every shipped scene (`scenes/*.ron`, one test each) loads and runs a few short frames through
//! the library API (`load_scene` + `scene_app` + `App::update`) without a numerical failure and
//! with finite, in-domain particle state, conserved particle count and mass.
use std::path::{Path, PathBuf};
use std::time::Instant;

use bevy_ecs::prelude::*;
use treacle::components::{Acceleration, Density, Mass, Particle, Position, Velocity};
use treacle::config::BoundaryCondition;
use treacle::diagnostics::measure;
use treacle::failure::SimulationStatus;
use treacle::runner::scene_app;
use treacle::scene::{Scene, load_scene};
use treacle::schedule::SimulationClock;

/// Frames run per scene.
const FRAMES: u64 = 3;

/// The test's frame as a share of the scene's frame. A quarter keeps the start-up and the
/// first few hundred steps of the stiffest scenes (the tomatoes take ~1,900 steps per 1/60 s
/// frame) while the suite's share of CI stays small; every scene's own frame end is still
/// exercised, as the frame-end step that hits the shortened frame's time exactly.
const FRAME_SHARE: f64 = 0.25;

fn scene_files() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ron"))
        .collect();
    files.sort();
    files
}

/// What one scene did in [`FRAMES`] frames.
struct Outcome {
    particles: usize,
    steps: u64,
    seconds: f64,
}

/// Runs `FRAMES` frames of a loaded scene and checks the state after every frame.
fn run(path: &Path, scene: &Scene) -> Outcome {
    let name = path.file_name().unwrap().to_string_lossy().into_owned();
    let t0 = Instant::now();
    let mut app = scene_app(scene);
    // Present from the start (bodies with a release time come later).
    let expected: usize = scene
        .particles
        .iter()
        .filter(|b| b.release_time == 0.0)
        .map(|b| b.positions.len())
        .sum();
    let mass0 = measure(app.world_mut()).mass;
    // Scenes with emitters (3D printing) may start empty and gain particles.
    let emitting = !scene.emitters.is_empty();
    assert!(mass0 > 0.0 || emitting, "{name}: no mass");
    let (lo, hi) = (scene.config.domain_min, scene.config.domain_max);
    // With an open face particles may leave (and are removed): count and mass then only
    // decrease. Every shipped scene is closed.
    let w = &scene.config.walls;
    let open = [w.x_min, w.x_max, w.y_min, w.y_max, w.z_min, w.z_max]
        .iter()
        .any(|bc| matches!(bc, BoundaryCondition::Open));
    for frame in 1..=FRAMES {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            panic!("{name}: frame {frame}: simulation failed: {f}");
        }
        let clock = app.world().resource::<SimulationClock>();
        let t_expect = frame as f64 * scene.config.frame_dt;
        assert!(
            (clock.time - t_expect).abs() <= 1e-9 * t_expect.max(1.0),
            "{name}: frame {frame} ends at t = {} s, expected {t_expect} s",
            clock.time
        );
        assert!(clock.steps >= frame, "{name}: {} steps", clock.steps);

        let world = app.world_mut();
        let mut q = world.query_filtered::<
            (&Position, &Velocity, &Acceleration, &Density, &Mass),
            With<Particle>,
        >();
        let mut n = 0;
        for (x, v, a, rho, m) in q.iter(world) {
            n += 1;
            assert!(
                x.0.is_finite() && v.0.is_finite() && a.0.is_finite(),
                "{name}: frame {frame}: x = {}, v = {}, a = {}",
                x.0,
                v.0,
                a.0
            );
            assert!(
                rho.value.is_finite() && rho.value > 0.0 && rho.rate.is_finite(),
                "{name}: frame {frame}: density {} (rate {})",
                rho.value,
                rho.rate
            );
            assert!(m.0.is_finite() && m.0 > 0.0, "{name}: mass {}", m.0);
            // Inside the domain (walls, periodic wrap, or removal through open faces).
            let tol = 1e-4 * scene.config.dx;
            assert!(
                x.0.cmpge(lo - tol).all() && x.0.cmple(hi + tol).all(),
                "{name}: frame {frame}: particle at {} outside the domain [{lo}, {hi}]",
                x.0
            );
        }
        let m = measure(world);
        // Bodies released during the run (`release_time`) are there once a frame end reaches
        // their time.
        let t = scene.config.frame_dt * frame as f64;
        let due: Vec<_> = scene
            .particles
            .iter()
            .filter(|b| b.release_time > 0.0 && b.release_time <= t * (1.0 + 1e-12))
            .collect();
        let expected = expected + due.iter().map(|b| b.positions.len()).sum::<usize>();
        let mass0 = mass0
            + due
                .iter()
                .map(|b| {
                    // The particle mass as spawned: volume × ρ₀ in single precision.
                    let m = b.particle_volume * scene.materials.get(b.material).density;
                    b.positions.len() as f64 * m as f64
                })
                .sum::<f64>();
        if emitting {
            assert!(
                n >= expected && m.mass >= mass0 * (1.0 - 1e-12),
                "{name}: frame {frame}: {n} particles, mass {}",
                m.mass
            );
        } else if open {
            assert!(
                n <= expected && m.mass <= mass0 * (1.0 + 1e-12),
                "{name}: {n} particles"
            );
        } else {
            assert_eq!(n, expected, "{name}: frame {frame}: particle count");
            assert!(
                ((m.mass - mass0) / mass0).abs() < 1e-12,
                "{name}: frame {frame}: mass {} ≠ {mass0}",
                m.mass
            );
        }
        assert!(
            m.kinetic_energy.is_finite() && m.volume.is_finite() && (m.volume > 0.0 || n == 0),
            "{name}: frame {frame}: metrics {m:?}"
        );
    }
    let steps = app.world().resource::<SimulationClock>().steps;
    Outcome {
        particles: expected,
        steps,
        seconds: t0.elapsed().as_secs_f64(),
    }
}

/// Loads `scenes/<file>`, runs [`FRAMES`] frames of [`FRAME_SHARE`] of its frame and prints what
/// it cost.
fn run_shipped(file: &str) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(file);
    let mut scene = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
    assert!(scene.frames() >= FRAMES, "{}: too short", path.display());
    scene.config.frame_dt *= FRAME_SHARE;
    let o = run(&path, &scene);
    println!(
        "{file}: {} particles, {} steps, {:.2} s",
        o.particles, o.steps, o.seconds
    );
}

/// One test per shipped scene (so the test harness spreads them over its threads), named after
/// the file; [`every_shipped_scene_has_a_test`] checks that the list covers `scenes/*.ron`.
macro_rules! shipped_scenes {
    ($($name:ident),* $(,)?) => {
        const SHIPPED: &[&str] = &[$(concat!(stringify!($name), ".ron")),*];
        $(
            #[test]
            fn $name() {
                run_shipped(concat!(stringify!($name), ".ron"));
            }
        )*
    };
}

shipped_scenes!(
    ball_impact,
    bench_block,
    bench_block_xpp,
    buckling_1,
    buckling_2,
    bunny_impact,
    bunny_melting_1,
    bunny_melting_2,
    bunny_piling,
    coiling_1,
    coiling_2,
    coiling_3,
    cube_impact_1,
    cube_impact_2,
    cube_impact_3,
    cube_impact_4,
    dam_break,
    droplet,
    hourglass_1,
    hourglass_2,
    letters,
    li_armadillos,
    li_cow,
    li_golf_cornstarch,
    li_golf_ketchup,
    li_honey,
    li_ice_cream,
    li_tomatoes,
    printing,
    stamping_bunny,
    stamping_label,
);

/// Every `scenes/*.ron` has its test above (a new scene without one fails here), and every
/// listed scene exists.
#[test]
fn every_shipped_scene_has_a_test() {
    let files: Vec<String> = scene_files()
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert!(
        files.len() >= 4,
        "expected the shipped scenes, found {files:?}"
    );
    let listed: Vec<String> = SHIPPED.iter().map(|s| s.to_string()).collect();
    assert_eq!(
        files, listed,
        "scenes/*.ron and the shipped_scenes! list differ: add the new scene to the list"
    );
}
