//! Behaviour checks on the shipped scenes (issue 4), on shortened runs through the library API:
//! the scene file is loaded as shipped, optionally with one documented parameter changed, and
//! run frame by frame with `App::update`. The longer checks (hourglass die swell, golf ball,
//! tomatoes) are in docs/gallery.md with their measured numbers.
use std::path::PathBuf;

use bevy_ecs::prelude::*;
use treacle::components::{Particle, Position};
use treacle::diagnostics::measure;
use treacle::failure::SimulationStatus;
use treacle::runner::scene_app;
use treacle::scene::{Scene, load_scene};

fn scene(name: &str) -> Scene {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("scenes")
        .join(name);
    load_scene(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Runs `frames` frames; returns per frame (after it) the centre-of-mass height and the
/// thickness of the liquid: highest minus lowest particle centre plus one particle spacing
/// `h` (the extent of the particles' cells). The thickness is measured from the lowest particle,
/// not from the floor: next to a sticky floor the particles rest ≈ 0.4Δx above it (the
/// first grid node is fixed), a gap that is not liquid.
fn run_heights(scene: &Scene, frames: u64) -> Vec<(f64, f64)> {
    let h = (scene.particles[0].particle_volume as f64).cbrt();
    let mut app = scene_app(scene);
    let mut out = Vec::new();
    for frame in 1..=frames {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            panic!("{}: frame {frame}: {f}", scene.source.display());
        }
        let world = app.world_mut();
        let com = measure(world).center_of_mass[1];
        let (lo, hi) = world
            .query_filtered::<&Position, With<Particle>>()
            .iter(world)
            .map(|p| p.0.y as f64)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), y| {
                (lo.min(y), hi.max(y))
            });
        out.push((com, hi - lo + h));
    }
    out
}

/// Half a particle spacing of the cube scenes \[m\]: the rise that counts as a rebound.
const REBOUND: f64 = 0.0025;

/// How far the centre of mass rises after its lowest frame \[m\] (0 if the minimum is last).
fn rise_after_minimum(h: &[(f64, f64)]) -> f64 {
    let (i_min, &(com_min, _)) = h
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.0.total_cmp(&b.1.0))
        .unwrap();
    h[i_min..].iter().map(|x| x.0).fold(com_min, f64::max) - com_min
}

/// [Su21] Table 4 row 1: the Newtonian cube (μ = 4.9 Pa·s, ρ = 1000) spreads on the floor: its
/// thickness falls below 25 % of the initial 0.1 m by the end of the shipped 1 s run.
#[test]
fn newtonian_cube_spreads() {
    let s = scene("cube_impact_1.ron");
    let h = run_heights(&s, s.frames());
    let height = h.last().unwrap().1;
    println!("cube_impact_1: final height {height:.4} m (initial 0.1 m)");
    assert!(
        height < 0.25 * 0.1,
        "final height {height} m ≥ 25 % of 0.1 m"
    );
    // The rebound criterion of `xpp_cubes_rebound` discriminates: over the same 12 frames the
    // liquid cube's centre of mass does not rise by 2.5 mm after its minimum.
    let rise = rise_after_minimum(&h[..12]);
    println!("cube_impact_1: rise after the minimum {:.2} mm", rise * 1e3);
    assert!(rise < REBOUND, "Newtonian cube rises {rise} m");
}

/// [Su21] Table 4 rows 2–4 with α = 0.15 instead of the printed α = 100 (which makes the XPP
/// conformation lose positive-definiteness; the shipped scenes stop at impact, see their header):
/// after the impact the centre of mass moves upward again (rebound). The minimum must be followed
/// by a rise of at least half a particle spacing (2.5 mm) within 12 frames of 1/60 s, far above
/// the run-to-run noise (the runs are deterministic) and above the settling of a liquid, whose
/// centre of mass only goes down.
#[test]
fn xpp_cubes_rebound() {
    for name in [
        "cube_impact_2.ron",
        "cube_impact_3.ron",
        "cube_impact_4.ron",
    ] {
        let mut s = scene(name);
        for (_, model) in &mut s.rheology {
            let Some(m) = model.downcast_mut::<treacle::rheology::Su2021Unified>() else {
                panic!("{name}: expected the Su2021Unified model")
            };
            assert_eq!(m.anisotropy, 100.0, "{name}: printed α");
            m.anisotropy = 0.15;
        }
        let h = run_heights(&s, 12);
        let coms: Vec<String> = h.iter().map(|x| format!("{:.4}", x.0)).collect();
        println!("{name}: centre of mass per frame [m]: {}", coms.join(" "));
        let rise = rise_after_minimum(&h);
        println!("{name}: rise after the minimum {:.2} mm", rise * 1e3);
        assert!(
            rise > REBOUND,
            "{name}: the centre of mass rises only {rise} m after the impact"
        );
    }
}

/// The printed values that ALGORITHM §7.4 flags are shipped as printed and warned about at load,
/// located at the field: α = 100 (cube impacts 2–4, ball impact) and the bunny-impact G₀ that is
/// 10× (1 − F_v)μ/λ_b. A consistent scene draws no warning.
#[test]
fn printed_inconsistencies_are_warned() {
    for name in [
        "cube_impact_2.ron",
        "cube_impact_3.ron",
        "cube_impact_4.ron",
        "ball_impact.ron",
    ] {
        let s = scene(name);
        assert_eq!(s.warnings.len(), 1, "{name}: {:?}", s.warnings);
        let w = &s.warnings[0];
        assert!(
            w.line > 0 && w.field == "rheology[0].model.anisotropy",
            "{w}"
        );
        assert!(w.message.contains("α = 100"), "{w}");
    }
    let s = scene("bunny_impact.ron");
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].field == "rheology[0].model.modulus"
            && s.warnings[0].message.contains("10.007×"),
        "{}",
        s.warnings[0]
    );
    assert!(scene("bunny_piling.ron").warnings.is_empty());
    assert!(scene("cube_impact_1.ron").warnings.is_empty());
}

/// The melt's spread radius after each of `frames` frames: the largest horizontal distance
/// from the bunny's vertical axis (x, z) = (0.2, 0.2) m among particles in the lowest 2 cm that
/// have another particle within Δx (a spray filter).
fn melt_spread(scene: &Scene, frames: u64) -> Vec<f64> {
    let dx2 = scene.config.dx.powi(2);
    let mut app = scene_app(scene);
    let mut out = Vec::new();
    for frame in 1..=frames {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            panic!("{}: frame {frame}: {f}", scene.source.display());
        }
        let world = app.world_mut();
        let low: Vec<glam::Vec3> = world
            .query_filtered::<&Position, With<Particle>>()
            .iter(world)
            .map(|p| p.0)
            .filter(|p| p.y < 0.02)
            .collect();
        let r = low
            .iter()
            .enumerate()
            .filter(|(i, p)| {
                low.iter()
                    .enumerate()
                    .any(|(j, q)| j != *i && q.distance_squared(**p) <= dx2)
            })
            .map(|(_, p)| (((p.x - 0.2).powi(2) + (p.z - 0.2).powi(2)) as f64).sqrt())
            .fold(0.0, f64::max);
        out.push(r);
    }
    out
}

/// [Su21] Fig. 14: the viscous melt (μ = 39.2 Pa·s, `bunny_melting_2.ron`) spreads less than
/// the inviscid one (μ = 0, `bunny_melting_1.ron`): at t = 0.367 s (frame 11) its spread radius
/// is smaller by more than one cell (Δx = 1 cm), twice the particle spacing that bounds the
/// measure's resolution. Measured: 0.1087 m against 0.0890 m; by t = 0.5 s 0.128 against
/// 0.112 m (docs/gallery.md).
#[test]
fn viscous_melt_spreads_less_than_inviscid() {
    let radius = |name: &str| {
        let s = scene(name);
        let r = melt_spread(&s, 11);
        let rs: Vec<String> = r.iter().map(|x| format!("{x:.4}")).collect();
        println!("{name}: spread radius per frame [m]: {}", rs.join(" "));
        (*r.last().unwrap(), s.config.dx as f64)
    };
    let (inviscid, dx) = radius("bunny_melting_1.ron");
    let (viscous, _) = radius("bunny_melting_2.ron");
    assert!(
        viscous + dx < inviscid,
        "viscous melt spreads to {viscous:.4} m, inviscid to {inviscid:.4} m"
    );
}

/// [Su21] Fig. 2, Coiling 1 (`coiling_1.ron`) at half its resolution (Δx = 2.5 mm: the nozzle
/// spans 4 cells; the shipped 8-cell run is in docs/gallery.md) for 1.6 s: the jet lands at
/// ≈ 0.5 s, stands straight on the plate, buckles at ≈ 0.75 s and coils. Measured with
/// `report::coiling` on the band 18–22 mm above the plate: while the jet stands (0.55–0.7 s) its
/// crossing sits on the nozzle's axis (radius < Δx/10); from 0.8 s it circles the axis (mean
/// radius > Δx, at least one net turn in one sense). Measured here: 0.02–0.09 mm while
/// standing; 7.7 mm and 1.9 turns at Ω = 15.6 rad/s while coiling.
#[test]
fn coiling_jet_revolves_about_the_axis() {
    use treacle::report::coiling::{coil_rate, coil_sample};
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/coiling_1.ron");
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("dx: 0.00125,", "dx: 0.0025,")
        .replace("duration: 2.0,", "duration: 1.6,");
    let s = treacle::scene::parse_scene_str(&text, &path, path.parent().unwrap())
        .unwrap_or_else(|e| panic!("{e}"));
    let dx = s.config.dx as f64;
    assert!((dx - 0.0025).abs() < 1e-9, "dx = {dx}");
    let mut app = scene_app(&s);
    let mut samples = Vec::new();
    for frame in 1..=s.frames() {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            panic!("coiling_1: frame {frame}: {f}");
        }
        let t = frame as f64 * s.config.frame_dt;
        let world = app.world_mut();
        let points: Vec<[f64; 3]> = world
            .query_filtered::<&Position, With<Particle>>()
            .iter(world)
            .map(|p| p.0.as_dvec3().to_array())
            .collect();
        samples.extend(coil_sample(t, points, [0.03, 0.03], (0.018, 0.022), 10));
    }
    let standing = coil_rate(&samples, (0.55, 0.7)).expect("the jet crosses the band");
    let coiling = coil_rate(&samples, (0.8, 1.6)).expect("the coil crosses the band");
    println!("standing: {standing:?}\ncoiling: {coiling:?}");
    assert!(
        standing.mean_radius < 0.1 * dx,
        "the standing jet is on the axis: {standing:?}"
    );
    assert!(
        coiling.mean_radius > dx,
        "the coil leaves the axis: {coiling:?}"
    );
    assert!(coiling.turns.abs() >= 1.0, "at least one turn: {coiling:?}");
}
