//! A `Slip` domain wall is a mirror (issue 14; ALGORITHM §2.11, choice D18).
//!
//! The dam break of `scenes/dam_break.ron` (a = 0.1 m, column a wide and 2a high, water with
//! c₀ = 20 m/s, quasi-2D) runs twice:
//!
//! - **wall**: the column stands against the `Slip` wall x = 0 of a tank L = 10a long;
//! - **mirror**: a column 2a wide centred at x = L in a tank 2L long, with no wall near it;
//!   its symmetry plane x = L is what a free-slip wall should be. Its right half, x − L (the
//!   left half folded over, |x − L|, which doubles the sample), is compared with the wall run.
//!
//! Nothing reaches the far walls before τ = 4 (front ≈ 8.4a < L − a), so both are the same problem.
//! Compared every frame (Δτ ≈ 0.1) up to τ = t√(g/a) = 4:
//!
//! - the **residual height** at the wall: the highest particle within one cell Δx of the wall
//!   (symmetry plane), plus h/2;
//! - the **front**: the largest x (|x − L|) among particles with another particle within Δx
//!   (the spray filter of `tests/it/dam_break.rs`), plus h/2.
//!
//! **Tolerance: one particle spacing h = Δx/2** for both (2 particles per cell and axis). Both
//! quantities are positions of single particles, and each particle stands for a cube of side h:
//! two particle sets describing the same resolved (grid) flow can put their outermost particle
//! anywhere within one spacing of the surface, so no comparison of surface positions read off
//! particles can be sharper than h. Anything larger is a difference in the flow itself.
//!
//! Measured (Δx = a/10, h = 0.05a, FLIP 0.99, 42 frames to τ = 4.06, largest |wall − mirror|):
//! before the mirror fold (D18) the column at the wall stood up to 0.333a (6.7h) higher than
//! the mirrored one (τ ≈ 2.7; already 0.099a at τ ≈ 1) and its front lagged by up to 0.039a
//! (τ ≈ 4); with the fold both agree to the printed digits (0.000a): the wall run is the half of
//! the mirrored run up to the rounding asymmetry of the latter's sums.
use std::path::Path;

use crate::common::front_x;
use bevy_ecs::prelude::*;
use treacle::components::{Particle, Position};
use treacle::failure::SimulationStatus;
use treacle::math::Vec3;
use treacle::runner::scene_app;
use treacle::scene::parse_scene_str;
use treacle::schedule::SimulationClock;

/// Column width a \[m\] (as `scenes/dam_break.ron`).
const A: f64 = 0.1;
/// Grid spacing: a/10.
const DX: f64 = A / 10.0;
/// Particles per cell and axis: spacing h = Δx/2.
const PPC: u32 = 2;
/// Tank length L in units of a (the mirrored tank is 2L).
const TANK: f64 = 10.0;
/// Last compared τ = t√(g/a).
const TAU_END: f64 = 4.0;
/// Less PIC damping makes the wall/mirror difference larger (issue 14).
const FLIP: f64 = 0.99;

fn scene(mirror: bool) -> String {
    let l = TANK * A;
    let (x_max, x0, x1) = if mirror {
        (2.0 * l, l - A, l + A)
    } else {
        (l, 0.0, A)
    };
    let depth = 4.0 * DX;
    // A whole number of 1/100 s frames reaching τ = TAU_END.
    let duration = (TAU_END / (9.81 / A).sqrt() * 100.0).ceil() / 100.0;
    format!(
        "Scene(
  domain: (min: (0.0, 0.0, 0.0), max: ({x_max}, {y_max}, {depth})),
  dx: {DX}, particles_per_cell: {PPC}, gravity: (0.0, -9.81, 0.0),
  duration: {duration}, frame_rate: 100.0,
  integrator: (flip: {FLIP}),
  walls: (x_min: Slip, x_max: Slip, y_min: Slip, y_max: Slip, z_min: Slip, z_max: Slip),
  materials: [(name: \"water\", density: 1000.0, sound_speed: 20.0, viscosity: 0.001)],
  bodies: [(material: \"water\",
            shape: Box(min: ({x0}, 0.0, 0.0), max: ({x1}, {height}, {depth})))],
  output: (format: Ply, every: 1, fields: []),
)",
        y_max = 2.5 * A,
        height = 2.0 * A,
    )
}

/// (τ, residual height / a, front / a) after every frame.
fn run(mirror: bool) -> Vec<(f64, f64, f64)> {
    let text = scene(mirror);
    let scene = parse_scene_str(&text, Path::new("slip_mirror.ron"), Path::new("."))
        .unwrap_or_else(|e| panic!("{e}"));
    let plane = if mirror { (TANK * A) as f32 } else { 0.0 };
    let h = (DX / PPC as f64) as f32;
    let tau_scale = (9.81 / A).sqrt();
    let mut app = scene_app(&scene);
    let mut series = Vec::new();
    for frame in 0..=scene.frames() {
        if frame > 0 {
            app.update();
            if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
                panic!("simulation failed: {f}");
            }
        }
        let t = app.world().resource::<SimulationClock>().time;
        let world = app.world_mut();
        let mut q = world.query_filtered::<&Position, With<Particle>>();
        // Distance from the wall (symmetry plane).
        let xs: Vec<Vec3> = q
            .iter(world)
            .map(|p| Vec3::new((p.0.x - plane).abs(), p.0.y, p.0.z))
            .collect();
        let height = xs
            .iter()
            .filter(|x| x.x < DX as f32)
            .map(|x| x.y)
            .fold(f32::NEG_INFINITY, f32::max)
            + h / 2.0;
        let front = front_x(&xs, DX as f32) + h / 2.0;
        series.push((t * tau_scale, height as f64 / A, front as f64 / A));
    }
    series
}

#[test]
fn slip_wall_dam_break_matches_its_mirrored_twin() {
    let wall = run(false);
    let mirror = run(true);
    assert_eq!(wall.len(), mirror.len());
    assert!(wall.last().unwrap().0 >= TAU_END - 1e-6);
    let tolerance = DX / PPC as f64 / A; // one particle spacing, in units of a
    println!(
        "slip wall vs mirror plane: a = {A} m, Δx = a/{:.0}, FLIP {FLIP}, tolerance h = {tolerance:.3}a",
        A / DX
    );
    println!(
        "{:>5} {:>7} {:>7} {:>7}   {:>7} {:>7} {:>7}",
        "tau", "H_wall", "H_mirr", "dH", "Z_wall", "Z_mirr", "dZ"
    );
    let (mut worst_h, mut worst_z) = (0.0f64, 0.0f64);
    for (w, m) in wall.iter().zip(&mirror) {
        let (dh, dz) = (w.1 - m.1, w.2 - m.2);
        println!(
            "{:5.2} {:7.3} {:7.3} {:+7.3}   {:7.3} {:7.3} {:+7.3}",
            w.0, w.1, m.1, dh, w.2, m.2, dz
        );
        // Nothing may reach the far wall.
        assert!(w.2 < TANK - 1.0, "front {} too close to the far wall", w.2);
        worst_h = worst_h.max(dh.abs());
        worst_z = worst_z.max(dz.abs());
    }
    println!("largest |dH| = {worst_h:.3}a, |dZ| = {worst_z:.3}a");
    assert!(
        worst_h <= tolerance,
        "residual height at the slip wall differs from the mirror plane by {worst_h:.3}a > h = {tolerance:.3}a"
    );
    assert!(
        worst_z <= tolerance,
        "front of the slip-wall run differs from the mirrored run by {worst_z:.3}a > h = {tolerance:.3}a"
    );
}
