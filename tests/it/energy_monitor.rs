//! The energy monitor (`treacle::step::energy`): a run whose mechanical energy grows is stopped
//! with a diagnostic instead of blowing up silently (issue 5), and a stable run is not stopped.
//!
//! The case is the stability report's droplet (`scenes/reports/stability_droplet.ron`) with
//! μ = 10 Pa·s, whose explicit limit is 1.134e-3 s (sound + viscosity, ALGORITHM §7.2). At
//! 4× that limit the viscous mode grows by a factor of a few per step, yet no particle outruns
//! the grid or reaches 10 c₀ before the end of the run: the stability report listed it as a
//! silent blow-up before the monitor existed.
use std::path::Path;

use treacle::failure::SimulationStatus;
use treacle::runner::scene_app;

fn droplet(dt: f64) -> treacle::scene::Scene {
    // Two frames exactly (a duration that is not a whole number of frames is refused).
    let duration = 2.0 / 31.5;
    let text = format!(
        r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.3, 0.2, 0.3)),
    dx: 0.02,
    gravity: (0.0, -9.81, 0.0),
    duration: {duration},
    frame_rate: 31.5,
    time_step: (mode: Fixed({dt})),
    walls: (y_min: Sticky),
    materials: [(name: "liquid", density: 1000.0, sound_speed: 10.0, viscosity: 10.0)],
    bodies: [(
        material: "liquid",
        shape: Sphere(center: (0.15, 0.06, 0.15), radius: 0.05),
        velocity: (0.0, -1.0, 0.0),
    )],
)"#
    );
    treacle::scene::parse_scene_str(&text, Path::new("droplet.ron"), Path::new("scenes"))
        .unwrap_or_else(|e| panic!("{e}"))
}

/// Runs both frames; returns the failure message, if any.
fn run(dt: f64) -> Option<String> {
    let mut app = scene_app(&droplet(dt));
    for _ in 0..2 {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            return Some(f.to_string());
        }
    }
    None
}

#[test]
fn growing_energy_stops_the_run_with_a_diagnostic() {
    // 4 × the predicted limit 1.134e-3 s.
    let msg = run(4.535e-3).expect("the unstable run must be stopped");
    assert!(msg.contains("mechanical energy"), "{msg}");
    assert!(msg.contains("step"), "{msg}");
    assert!(msg.contains("on particle"), "{msg}");
    assert!(msg.contains("Suggested fix"), "{msg}");
}

#[test]
fn stable_run_is_not_stopped() {
    // 0.5 × the predicted limit.
    assert_eq!(run(5.67e-4), None);
}
