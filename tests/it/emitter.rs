//! The 3D-printing nozzle (ALGORITHM §4.4): the G-code reader (absolute/relative coordinates
//! and extrusion, units, travel moves, errors with file and line), the tool path, the disk
//! lattice, test C2 of §9 (mass rate ρ₀Q̇ within one layer, no emission on travel), the state of
//! emitted particles, the scene section (bad G-code and T_inj ≤ T_m rejected with file, line
//! and field), and the printing scene run through the CLI: deposited mass against ρ₀Q̇t at every
//! frame, printed height against the G-code's layers, and determinism across thread counts.
use crate::common::{crate_dir, scratch};
use std::fs;
use std::path::Path;
use std::process::Command;

use bevy_ecs::prelude::*;
use glam::DVec3;
use treacle::app::headless_app_with;
use treacle::components::{
    Acceleration, DeformationGradient, Density, Mass, Particle, Position, Velocity,
};
use treacle::emit::{
    EmitterPlugin, GcodeMapping, GcodeUp, InBore, NozzleEmitter, PathSegment, ToolPath,
    disk_lattice, load_gcode, parse_gcode,
};
use treacle::output::read_ply;
use treacle::prelude::*;
use treacle::scene::{load_scene, parse_scene_str};
use treacle::schedule::SimulationClock;
use treacle::thermal::components::{PhaseIndex, PredictedTemperature, Temperature};
use treacle::thermal::phase::{PhaseChange, PhaseChangePlugin};

const BIN: &str = env!("CARGO_BIN_EXE_treacle");

fn close(a: DVec3, b: DVec3) -> bool {
    (a - b).length() < 1e-9
}

// ---------------------------------------------------------------------------------------------
// G-code reader

/// G90/G91 switch the coordinates (and, as in Marlin, the extrusion); M82/M83 switch only the
/// extrusion. Durations are length / (F/60).
#[test]
fn gcode_absolute_and_relative_moves_and_extrusion() {
    let text = "\
G21 ; mm
G90
M82
G1 X10 Y0 Z0.5 E1 F600
G91
G1 X5 E0.5
G90
M83
G1 X20 E0.25
G1 X30 E-0.5 ; retraction while moving: travel
M82
G1 X40 E2.0 ; absolute E: 2.0 - 1.25 = 0.75
G92 E0
G1 X50 E0.5
";
    let p = parse_gcode(text).unwrap();
    assert_eq!(p.moves.len(), 6);
    let m = &p.moves;
    assert!(close(m[0].from, DVec3::ZERO) && close(m[0].to, DVec3::new(10.0, 0.0, 0.5)));
    assert!((m[0].duration - (100.25f64).sqrt() / 10.0).abs() < 1e-12);
    assert!((m[0].extrusion - 1.0).abs() < 1e-12 && m[0].extrudes());
    assert_eq!(m[0].line, 4);
    // G91: relative X and E.
    assert!(close(m[1].to, DVec3::new(15.0, 0.0, 0.5)));
    assert!((m[1].extrusion - 0.5).abs() < 1e-12);
    assert!((m[1].duration - 0.5).abs() < 1e-12);
    // G90 then M83: absolute X, relative E.
    assert!(close(m[2].to, DVec3::new(20.0, 0.0, 0.5)));
    assert!((m[2].extrusion - 0.25).abs() < 1e-12);
    assert!(!m[3].extrudes(), "negative E is not extrusion");
    // M82 again: absolute E, the running total was 1 + 0.5 + 0.25 − 0.5 = 1.25.
    assert!((m[4].extrusion - 0.75).abs() < 1e-12);
    // G92 E0 resets the E origin.
    assert!((m[5].extrusion - 0.5).abs() < 1e-12);
    assert_eq!(p.layer_heights(), vec![0.5]);
}

/// G20 reads inches (coordinates, E and F); G21 millimetres again.
#[test]
fn gcode_units() {
    let p = parse_gcode("G20\nG1 X1 E0.1 F60\nG21\nG1 X35.4 E2.64 F600\n").unwrap();
    // 1 in at 60 in/min = 1 s.
    assert!(close(p.moves[0].to, DVec3::new(25.4, 0.0, 0.0)));
    assert!((p.moves[0].duration - 1.0).abs() < 1e-12);
    assert!((p.moves[0].extrusion - 2.54).abs() < 1e-12);
    // Back in mm: 10 mm at 10 mm/s.
    assert!(close(p.moves[1].to, DVec3::new(35.4, 0.0, 0.0)));
    assert!((p.moves[1].duration - 1.0).abs() < 1e-12);
    assert!((p.moves[1].extrusion - 0.1).abs() < 1e-9);
}

/// Travel (G0, or G1 without E) does not extrude; comments, line numbers, checksums and M/T
/// commands with any parameters are skipped; a dwell takes time.
#[test]
fn gcode_travel_comments_and_dwell() {
    let text = "\
; header
M117 Printing (message text is ignored)
M104 S210
T0
N1 G28 *12
N2 G0 X10 F6000 (travel)
G1 X20 E1 F600
G4 P500
G1 Z1 ; Z move without E: travel
";
    let p = parse_gcode(text).unwrap();
    assert_eq!(p.moves.len(), 4);
    assert!(!p.moves[0].extrudes() && (p.moves[0].duration - 0.1).abs() < 1e-12);
    assert!(p.moves[1].extrudes() && (p.moves[1].duration - 1.0).abs() < 1e-12);
    assert!(!p.moves[2].extrudes() && (p.moves[2].duration - 0.5).abs() < 1e-12);
    assert!(!p.moves[3].extrudes());
    assert!((p.extruding_time() - 1.0).abs() < 1e-12);
    assert!((p.duration() - (0.1 + 1.0 + 0.5 + 0.1)).abs() < 1e-12);
}

/// Every problem names its line, and the file when read from one.
#[test]
fn gcode_errors_name_the_line_and_file() {
    let cases: &[(&str, usize, &str)] = &[
        ("G21\nG1 X1 E1 F100\nG2 X0 Y1 I1 J0 E2\n", 3, "G2"),
        ("G1 X1.2.3 E1 F100\n", 1, "X1.2.3"),
        ("G21\nG1 X1 E1\n", 2, "feed rate"),
        ("G1 X1 E1 F100\nG1 Q5\n", 2, "`Q`"),
        ("G1 X1 E1 F100\nX5\n", 2, "without a command"),
        ("G1 X1 E1 F100\nG1 X2 F-5\n", 2, "F must be > 0"),
        ("G1 X1 E1 F100 (unclosed\n", 1, "unclosed"),
        ("G1 X1 E1 F100\nG1 X2 X3\n", 2, "twice"),
        ("G1 X1 E1 F100\nG17\n", 2, "unsupported command G17"),
        ("G0 X10 F100\n", 0, "extrudes nothing"),
    ];
    for (text, line, needle) in cases {
        let e = parse_gcode(text).unwrap_err();
        assert_eq!(e.line, *line, "{text:?}: {e}");
        assert!(e.message.contains(needle), "{text:?}: {e}");
    }
    let dir = scratch("gcode-errors");
    let file = dir.join("bad.gcode");
    fs::write(&file, "G21\nG1 X1 E1 F100\nG1 X2 Y=3\n").unwrap();
    let e = load_gcode(&file).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.starts_with(&format!("{}:3: ", file.display())),
        "message names file and line: {msg}"
    );
    let missing = load_gcode(&dir.join("missing.gcode")).unwrap_err();
    assert!(missing.to_string().contains("missing.gcode"), "{missing}");
}

/// The shipped G-code: 5 layers of 0.5 mm, extruding without pause, 50 mm³/s of bead.
#[test]
fn shipped_ring_gcode() {
    let p = load_gcode(&crate_dir().join("assets/gcode/ring_tube.gcode")).unwrap();
    assert_eq!(p.layer_heights(), vec![0.5, 1.0, 1.5, 2.0, 2.5]);
    // Everything but the final retraction extrudes.
    let travel: Vec<_> = p.moves.iter().filter(|m| !m.extrudes()).collect();
    assert_eq!(travel.len(), 1, "only the final retraction is travel");
    let t = p.extruding_time();
    assert!((t - 0.6481).abs() < 1e-3, "extruding time {t} s");
    println!("ring_tube.gcode: {p}");
}

// ---------------------------------------------------------------------------------------------
// Tool path and lattice

#[test]
fn tool_path_sampling_and_extruding_time() {
    // Extrude 1 s, travel 1 s, extrude 1 s (X in mm at 10 mm/s, travel at 10 mm/s).
    let p = parse_gcode("G1 X10 E1 F600\nG0 X20\nG1 X30 E2\n").unwrap();
    let mapping = GcodeMapping {
        scale: 1e-3,
        origin: DVec3::new(1.0, 2.0, 3.0),
        up: GcodeUp::Y,
        feed_scale: 2.0,
    };
    let path = p.to_tool_path(&mapping).unwrap();
    // feed_scale 2: each move takes 0.5 s.
    assert!((path.duration() - 1.5).abs() < 1e-12);
    assert!((path.extruding_time(0.25) - 0.25).abs() < 1e-12);
    assert!((path.extruding_time(0.75) - 0.5).abs() < 1e-12);
    assert!((path.extruding_time(1.25) - 0.75).abs() < 1e-12);
    assert_eq!(path.extruding_time(-1.0), 0.0);
    assert!((path.extruding_time(9.0) - 1.0).abs() < 1e-12);
    let (x, v, extruding) = path.sample(0.25);
    assert!(close(x, DVec3::new(1.005, 2.0, 3.0)), "{x}");
    assert!(close(v, DVec3::new(0.02, 0.0, 0.0)), "{v}");
    assert!(extruding);
    assert!(!path.sample(0.75).2);
    let (end, v_end, e_end) = path.sample(5.0);
    assert!(close(end, DVec3::new(1.03, 2.0, 3.0)) && v_end == DVec3::ZERO && !e_end);
    // Y-up mapping: G-code (X, Y, Z) → (X, Z, −Y), a rotation.
    let m = GcodeMapping::default();
    assert!(close(
        m.map_point(DVec3::new(1.0, 2.0, 3.0)),
        DVec3::new(1e-3, 3e-3, -2e-3)
    ));
    assert!(ToolPath::new(vec![]).is_err());
    assert!(
        ToolPath::new(vec![PathSegment {
            start: DVec3::ZERO,
            end: DVec3::X,
            duration: 0.0,
            extrude: true
        }])
        .is_err()
    );
}

#[test]
fn disk_lattice_sizes() {
    let h = 0.001;
    assert_eq!(disk_lattice(Vec3::NEG_Y, 0.5 * h, h).len(), 1);
    assert_eq!(disk_lattice(Vec3::NEG_Y, h, h).len(), 5);
    assert_eq!(disk_lattice(Vec3::NEG_Y, 2.0 * h, h).len(), 13);
    // Points lie in the plane ⊥ e and within r.
    for e in [Vec3::NEG_Y, Vec3::X, Vec3::new(1.0, 1.0, 0.0)] {
        for p in disk_lattice(e, 3.0 * h, h) {
            assert!(p.dot(e.normalize()).abs() < 1e-9 && p.length() <= 3.0 * h * 1.000_001);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// C2 and the emitted state

const RHO0: f32 = 1000.0;

/// A 5 cm box with a Newtonian paste and one emitter along `path`.
fn emitter_app(
    emitter: impl FnOnce(MaterialId) -> NozzleEmitter,
    frame_rate: f64,
) -> bevy_app::App {
    let mut materials = Materials::default();
    let paste = materials.add(FluidMaterial::newtonian("paste", RHO0, 2.0, 0.5));
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.05),
        dx: 0.002,
        frame_dt: 1.0 / frame_rate,
        ..Default::default()
    };
    let mut app = headless_app_with(config, materials, |app| {
        app.add_plugins(EmitterPlugin);
    });
    app.world_mut().spawn(emitter(paste));
    app
}

fn particle_mass(world: &mut World) -> (usize, f64) {
    let mut q = world.query_filtered::<&Mass, With<Particle>>();
    let v: Vec<f64> = q.iter(world).map(|m| m.0 as f64).collect();
    (v.len(), v.iter().sum())
}

/// C2 (§9): the deposited mass is ρ₀Q̇ × the extruding time within half a layer at every
/// frame; nothing is emitted during the travel move; the rate over the run is ρ₀Q̇.
#[test]
fn c2_mass_rate_equals_rho0_q_and_travel_does_not_emit() {
    let h = 0.001f32;
    let q_dot = 2e-6; // m³/s
    // Extrude 0.1 s along x, travel 0.05 s, extrude 0.1 s back along z; 4 cm above the floor.
    let y = 0.04;
    let seg = |a: DVec3, b: DVec3, d: f64, e: bool| PathSegment {
        start: a,
        end: b,
        duration: d,
        extrude: e,
    };
    let (a, b, c, d) = (
        DVec3::new(0.01, y, 0.01),
        DVec3::new(0.03, y, 0.01),
        DVec3::new(0.03, y, 0.02),
        DVec3::new(0.03, y, 0.04),
    );
    let path = ToolPath::new(vec![
        seg(a, b, 0.1, true),
        seg(b, c, 0.05, false),
        seg(c, d, 0.1, true),
    ])
    .unwrap();
    let radius = 2.0 * h;
    let mut app = emitter_app(
        |m| NozzleEmitter::new(path, Vec3::NEG_Y, radius, q_dot, h, m).with_jitter(0.1, 3),
        200.0,
    );
    let n_layer = disk_lattice(Vec3::NEG_Y, radius, h).len();
    assert_eq!(n_layer, 13);
    let layer_mass = n_layer as f64 * (h as f64).powi(3) * RHO0 as f64;
    let v_e = q_dot / (n_layer as f64 * (h as f64).powi(2));
    println!(
        "N_layer = {n_layer}, v_e = {v_e:.4} m/s, layer mass {layer_mass:.3e} kg, ρ₀Q̇ = {} kg/s",
        RHO0 as f64 * q_dot
    );
    let mut worst: f64 = 0.0;
    let mut counts = Vec::new();
    for frame in 1..=60 {
        app.update();
        assert!(
            app.world().resource::<SimulationStatus>().failure.is_none(),
            "{:?}",
            app.world().resource::<SimulationStatus>().failure
        );
        let t = app.world().resource::<SimulationClock>().time;
        let (n, m) = particle_mass(app.world_mut());
        let t_ext = t.min(0.1) + (t - 0.15).clamp(0.0, 0.1);
        let expected = RHO0 as f64 * q_dot * t_ext;
        let err_layers = (m - expected) / layer_mass;
        worst = worst.max(err_layers.abs());
        assert!(
            err_layers.abs() <= 0.5 + 1e-3,
            "frame {frame}, t = {t}: mass {m} vs ρ₀Q̇t_ext = {expected} ({err_layers:+.3} layers)"
        );
        counts.push((t, n));
    }
    // No emission during the travel move (0.1 s < t < 0.15 s, up to the step that crosses
    // the boundary).
    let during: Vec<usize> = counts
        .iter()
        .filter(|(t, _)| *t > 0.101 && *t < 0.149)
        .map(|c| c.1)
        .collect();
    assert!(during.len() >= 8);
    assert!(
        during.iter().all(|&n| n == during[0]),
        "travel emits: {during:?}"
    );
    // Rate over the whole run: 2 × 0.1 s of extrusion.
    let (_, m_end) = particle_mass(app.world_mut());
    let rate = m_end / 0.2;
    println!(
        "mass rate {rate:.6e} kg/s vs ρ₀Q̇ = {:.6e} kg/s; worst frame error {worst:.3} layers",
        RHO0 as f64 * q_dot
    );
    assert!((rate / (RHO0 as f64 * q_dot) - 1.0).abs() < layer_mass / (RHO0 as f64 * q_dot * 0.2));
}

/// Emitted particles carry exactly the state a new particle needs: mass ρ₀h³, rest density,
/// a = g, v = v_e e + ẋ_s, the material's model state (here the polymer stress of
/// `Su2021Unified`), F and the phase index for a phase-change material, and T = T_inj only for
/// a heated emitter.
#[test]
fn emitted_particles_carry_the_state_their_material_needs() {
    let h = 0.001f32;
    let q_dot = 1e-6;
    let speed = 0.05;
    let path = ToolPath::polyline(
        &[DVec3::new(0.01, 0.04, 0.025), DVec3::new(0.04, 0.04, 0.025)],
        speed,
    )
    .unwrap();
    let mut materials = Materials::default();
    let plain = materials.add(FluidMaterial::newtonian("plain", RHO0, 2.0, 0.5));
    let melt = materials.add(FluidMaterial {
        local_fraction: 0.5,
        ..FluidMaterial::newtonian("melt", RHO0, 2.0, 0.5)
    });
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.05),
        dx: 0.002,
        frame_dt: 0.01,
        ..Default::default()
    };
    let g = config.gravity;
    let mut app = headless_app_with(config, materials, |app| {
        app.add_plugins(
            RheologyPlugin::<Su2021Unified>::default().with(melt, Su2021Unified::oldroyd_b(1.0)),
        );
        app.add_plugins(
            PhaseChangePlugin::default().with_phase_change(melt, PhaseChange::new(0.1, 100.0)),
        );
        app.add_plugins(EmitterPlugin);
    });
    let cold = NozzleEmitter::new(path.clone(), Vec3::NEG_Y, h, q_dot, h, plain);
    let hot = NozzleEmitter::new(path, Vec3::NEG_Y, h, q_dot, h, melt).with_temperature(0.2);
    app.world_mut().spawn(cold);
    app.world_mut().spawn(hot);
    // One step after the start-up: check the particles right after their emission.
    treacle::schedule::start(app.world_mut());
    treacle::schedule::run_step(app.world_mut(), 1e-3, false);
    let world = app.world_mut();
    let mut q = world.query_filtered::<(
        &MaterialId,
        &Position,
        &Velocity,
        &Acceleration,
        &Mass,
        &Density,
        Option<&treacle::rheology::PolymerStress>,
        Option<&DeformationGradient>,
        Option<&PhaseIndex>,
        Option<&Temperature>,
        Option<&PredictedTemperature>,
    ), With<Particle>>();
    let v_e = q_dot / (5.0 * (h as f64).powi(2));
    let mut seen = [0usize; 2];
    for (mat, x, v, a, m, rho, polymer, f, phase, temp, pred) in q.iter(world) {
        assert!((m.0 / (RHO0 * h * h * h) - 1.0).abs() < 1e-6);
        assert_eq!(rho.value, RHO0);
        assert_eq!(rho.rate, 0.0);
        assert_eq!(a.0, g);
        let v_expect = Vec3::new(speed as f32, -(v_e as f32), 0.0);
        assert!((v.0 - v_expect).length() < 1e-5, "v = {}", v.0);
        assert!(
            (x.0.y - 0.04).abs() <= h * 1.0001,
            "emitted at the tip: {}",
            x.0
        );
        if *mat == plain {
            seen[0] += 1;
            assert!(polymer.is_none() && f.is_none() && phase.is_none());
            assert!(
                temp.is_none() && pred.is_none(),
                "unheated: no thermal state"
            );
        } else {
            seen[1] += 1;
            assert!(polymer.is_some_and(|p| p.value == glam::DMat3::ZERO));
            assert!(f.is_some_and(|f| f.0 == Mat3::IDENTITY));
            assert!(phase.is_some());
            assert_eq!(temp.map(|t| (t.value, t.rate)), Some((0.2, 0.0)));
            assert_eq!(pred.map(|p| p.0), Some(0.2));
        }
    }
    // 1 ms at v_e = 0.2 m/s from half a layer: ⌊(0.5 h + 0.2 mm)/h⌋ = 0 or more layers; run a
    // frame to be sure both emitted.
    if seen.contains(&0) {
        app.update();
        let (n, _) = particle_mass(app.world_mut());
        assert!(n > 0);
    } else {
        println!("emitted {} plain and {} melt particles", seen[0], seen[1]);
    }
}

// ---------------------------------------------------------------------------------------------
// Scene section

fn scene_with_emitter(gcode: &Path, temperature: &str) -> String {
    format!(
        r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.01, 0.005, 0.01)),
    dx: 0.0005,
    duration: 0.1,
    frame_rate: 20.0,
    materials: [(name: "melt", density: 1000.0, sound_speed: 3.0, viscosity: 1.0)],
    phase_change: [(material: "melt", melting_temperature: 0.1, shear_modulus: 3000.0)],
    emitters: [
        (
            material: "melt",
            path: Gcode(file: "{}", origin: (0.005, 0.001, 0.005)),
            radius: 0.0003,
            volume_rate: 5e-8,
            temperature: {temperature},
        ),
    ],
)"#,
        gcode.display()
    )
}

/// A G-code line that cannot be parsed, and T_inj ≤ T_m, are rejected with file, line and
/// field; a good one loads.
#[test]
fn scene_rejects_bad_gcode_and_cold_injection() {
    let dir = scratch("scene");
    let good = crate_dir().join("assets/gcode/ring_tube.gcode");
    let scene_path = dir.join("print.ron");
    let text = scene_with_emitter(&good, "Some(0.2)");
    let scene = parse_scene_str(&text, &scene_path, &dir).unwrap();
    assert_eq!(scene.emitters.len(), 1);

    let bad = dir.join("bad.gcode");
    fs::write(&bad, "G21\nG1 X1 E1 F600\nG1 X2 E2 Y\n").unwrap();
    let text = scene_with_emitter(&bad, "Some(0.2)");
    let e = parse_scene_str(&text, &scene_path, &dir)
        .unwrap_err()
        .to_string();
    println!("{e}");
    assert!(e.contains("print.ron:"), "{e}");
    assert!(e.contains("emitters[0].path.file"), "{e}");
    assert!(e.contains(&format!("{}:3:", bad.display())), "{e}");

    let text = scene_with_emitter(&good, "Some(0.05)");
    let e = parse_scene_str(&text, &scene_path, &dir)
        .unwrap_err()
        .to_string();
    println!("{e}");
    assert!(
        e.contains("emitters[0].temperature") && e.contains("T_m"),
        "{e}"
    );

    let text = scene_with_emitter(&good, "None");
    let e = parse_scene_str(&text, &scene_path, &dir)
        .unwrap_err()
        .to_string();
    assert!(e.contains("emitters[0].temperature"), "{e}");

    let text = scene_with_emitter(&dir.join("nope.gcode"), "Some(0.2)");
    let e = parse_scene_str(&text, &scene_path, &dir)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("emitters[0].path.file") && e.contains("not found"),
        "{e}"
    );

    let text =
        scene_with_emitter(&good, "Some(0.2)").replace("0.005, 0.001, 0.005", "0.0, 0.001, 0.005");
    let e = parse_scene_str(&text, &scene_path, &dir)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("emitters[0].path") && e.contains("outside the domain"),
        "{e}"
    );
}

// ---------------------------------------------------------------------------------------------
// The printing scene through the CLI

fn run_cli(scene: &Path, out: &Path, extra: &[&str]) {
    let o = Command::new(BIN)
        .arg("run")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .args(extra)
        .current_dir(crate_dir())
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

/// `(time, mass)` of every row of `metrics.csv`.
fn metrics_mass(dir: &Path) -> Vec<(f64, f64)> {
    let text = fs::read_to_string(dir.join("metrics.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let it = header.iter().position(|c| *c == "time").unwrap();
    let im = header.iter().position(|c| *c == "mass").unwrap();
    lines
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            (c[it].parse().unwrap(), c[im].parse().unwrap())
        })
        .collect()
}

/// The printing scene run by `treacle run`: deposited mass within 2 % of ρ₀Q̇t at every output
/// frame (t capped at the G-code's extruding time), and the final height of the print (above
/// the bed's top, and from its lowest to its highest particle) within 20 % of the G-code's
/// total layer height (the melt solidifies on the cold bed).
#[test]
fn printing_scene_mass_and_height_via_cli() {
    let path = crate_dir().join("scenes/printing.ron");
    let scene = load_scene(&path).unwrap();
    let emitter = &scene.emitters[0];
    let rho0 = scene.materials.get(emitter.material).density as f64;
    let out = scratch("printing");
    run_cli(&path, &out, &[]);
    let rows = metrics_mass(&out);
    assert_eq!(rows.len() as u64, scene.frames() + 1);
    let mut worst: f64 = 0.0;
    for &(t, m) in &rows[1..] {
        let expected = emitter.expected_mass(rho0, t);
        let err = (m - expected) / expected;
        worst = worst.max(err.abs());
        println!(
            "t = {t:.3} s: mass {m:.6e} kg, ρ₀Q̇t = {expected:.6e} kg ({:+.3} %)",
            100.0 * err
        );
        assert!(err.abs() < 0.02, "t = {t}: {:+.3} %", 100.0 * err);
    }
    println!("worst deposited-mass error {:.3} %", 100.0 * worst);
    // Height of the print above the bed (top face at y = 1 mm): the 99th percentile of the
    // particle heights plus half a particle spacing, against 5 layers × 0.5 mm.
    let last = out.join(format!("frame_{:05}.ply", scene.frames()));
    let frame = read_ply(&last).unwrap();
    let mut ys: Vec<f32> = frame.positions.iter().map(|p| p[1]).collect();
    ys.sort_by(f32::total_cmp);
    let half = 0.5 * emitter.spacing as f64;
    let top = ys[(ys.len() as f64 * 0.99) as usize] as f64 + half;
    let bottom = ys[0] as f64 - half;
    let above_bed = top - 1e-3;
    let extent = top - bottom;
    let gcode_height = 2.5e-3;
    println!(
        "printed height above the bed {:.3} mm ({:+.1} %), object extent {:.3} mm ({:+.1} %), \
         G-code {:.3} mm; {} particles, lowest particle {:.3} mm above the bed",
        above_bed * 1e3,
        100.0 * (above_bed / gcode_height - 1.0),
        extent * 1e3,
        100.0 * (extent / gcode_height - 1.0),
        gcode_height * 1e3,
        ys.len(),
        (ys[0] as f64 - 1e-3) * 1e3
    );
    for h in [above_bed, extent] {
        assert!(
            (h / gcode_height - 1.0).abs() < 0.2,
            "printed height {h} m vs the G-code's {gcode_height} m"
        );
    }
    let _ = fs::remove_dir_all(&out);
}

/// The printing scene gives byte-identical particle files with 1 and 2 worker threads.
#[test]
fn printing_is_deterministic_across_thread_counts() {
    let path = crate_dir().join("scenes/printing.ron");
    let base = scratch("threads");
    let (t1, t2) = (base.join("t1"), base.join("t2"));
    run_cli(&path, &t1, &["--frames", "2", "--threads", "1"]);
    run_cli(&path, &t2, &["--frames", "2", "--threads", "2"]);
    for f in 0..=2 {
        let name = format!("frame_{f:05}.ply");
        let a = fs::read(t1.join(&name)).unwrap();
        let b = fs::read(t2.join(&name)).unwrap();
        assert!(a == b, "{name} differs between 1 and 2 threads");
    }
    let f2 = read_ply(&t1.join("frame_00002.ply")).unwrap();
    assert!(f2.len() > 100, "{} particles", f2.len());
    let _ = fs::remove_dir_all(&base);
}

// ---------------------------------------------------------------------------------------------
// A fixed nozzle and its driven bore

/// A syrup jet (μ = 20 Pa·s, ρ = 1000, c₀ = 2 m/s) poured for 0.12 s at v_e = 0.2 m/s from a
/// nozzle held at 9 cm (radius 5 mm, Δx = 5 mm, h_p = 2.5 mm) with a bore of length `bore`.
/// Returns the largest gap between consecutive heights of the particles within 4 cm below the
/// tip, the largest deviation of a bore particle's velocity from the extrusion velocity, and
/// how many particles are in the bore.
fn pour_jet(bore: f32) -> (f64, f64, usize) {
    let mut materials = Materials::default();
    let syrup = materials.add(FluidMaterial::newtonian("syrup", RHO0, 2.0, 20.0));
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::new(0.06, 0.1, 0.06),
        dx: 0.005,
        frame_dt: 0.02,
        ..Default::default()
    };
    let mut app = headless_app_with(config, materials, |app| {
        app.add_plugins(EmitterPlugin);
    });
    let tip = DVec3::new(0.03, 0.09, 0.03);
    let (h, q_dot) = (0.0025f32, 0.2 * 13.0 * 0.0025f64.powi(2));
    let path = ToolPath::fixed(tip, 1.0).unwrap();
    let nozzle = NozzleEmitter::new(path, Vec3::NEG_Y, 0.005, q_dot, h, syrup).with_bore(bore);
    assert_eq!(nozzle.lattice().len(), 13, "v_e = Q̇/(13 h²) = 0.2 m/s");
    let nozzle = app.world_mut().spawn(nozzle).id();
    for _ in 0..6 {
        app.update();
        let status = app.world().resource::<treacle::failure::SimulationStatus>();
        assert!(status.failure.is_none(), "{:?}", status.failure);
    }
    let world = app.world_mut();
    let mut q = world.query_filtered::<(&Position, &Velocity, Option<&InBore>), With<Particle>>();
    let mut ys = Vec::new();
    let (mut worst_v, mut in_bore) = (0.0f64, 0);
    for (x, v, b) in q.iter(world) {
        let y = x.0.y as f64;
        if y < tip.y && y > tip.y - 0.04 {
            ys.push(y);
        }
        if let Some(b) = b {
            assert_eq!(b.0, nozzle);
            assert!(
                y < tip.y + bore as f64 + 0.01 * h as f64,
                "bore particle above the bore: {y}"
            );
            worst_v = worst_v.max((v.0.as_dvec3() - DVec3::new(0.0, -0.2, 0.0)).length());
            in_bore += 1;
        }
    }
    ys.sort_by(f64::total_cmp);
    let gap = ys
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(tip.y - ys.last().copied().unwrap_or(0.0), f64::max);
    (gap, worst_v, in_bore)
}

/// A nozzle held at one point ([`ToolPath::fixed`]) with a driven bore holds the jet that
/// hangs from it: the bore's particles move at exactly the extrusion velocity and the jet
/// below the tip is continuous (no gap between consecutive particle heights wider than one
/// cell: 0.11 mm here). Without the bore nothing holds the top of the jet: it falls away from
/// the layers emitted after it, and the jet tears (a gap wider than a cell: 8.4 mm here).
#[test]
fn a_driven_bore_holds_the_jet_hanging_from_a_fixed_nozzle() {
    let dx = 0.005;
    let (gap, worst_v, in_bore) = pour_jet(0.01);
    println!(
        "bore 1 cm: largest gap {:.2} mm, bore particles {in_bore}, |v − v_e| ≤ {worst_v:.2e} m/s",
        gap * 1e3
    );
    assert!(
        in_bore >= 3 * 13,
        "the 1 cm bore holds ≥ 3 layers ({in_bore} particles)"
    );
    assert!(
        worst_v < 1e-6,
        "bore particles move at v_e (off by {worst_v} m/s)"
    );
    assert!(
        gap < dx,
        "the jet is continuous below the tip (gap {gap} m)"
    );
    let (gap, _, in_bore) = pour_jet(0.0);
    println!("no bore: largest gap {:.2} mm", gap * 1e3);
    assert_eq!(in_bore, 0);
    assert!(
        gap > dx,
        "without a bore the jet falls away from the nozzle (gap {gap} m)"
    );
}

/// `Fixed(at, duration)` and `bore` in a scene file; bad values name their field and line.
#[test]
fn scene_fixed_nozzle_and_bore() {
    let text = |path: &str, bore: &str| {
        format!(
            r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.06, 0.12, 0.06)),
    dx: 0.005,
    duration: 0.1,
    frame_rate: 50.0,
    materials: [(name: "syrup", density: 1000.0, sound_speed: 2.0, viscosity: 20.0)],
    emitters: [
        (
            material: "syrup",
            path: {path},
            radius: 0.005,
            volume_rate: 4e-6,
            bore: {bore},
        ),
    ],
)"#
        )
    };
    let parse = |t: &str| parse_scene_str(t, Path::new("pour.ron"), Path::new("scenes"));
    let s = parse(&text(
        "Fixed(at: (0.03, 0.09, 0.03), duration: 2.0)",
        "0.01",
    ))
    .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.emitters.len(), 1);
    let e = parse(&text(
        "Fixed(at: (0.03, 0.09, 0.03), duration: 0.0)",
        "0.01",
    ))
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("emitters[0].path.duration") && msg.contains("pour.ron:10"),
        "{msg}"
    );
    let e = parse(&text(
        "Fixed(at: (0.03, 0.09, 0.03), duration: 2.0)",
        "-0.01",
    ))
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("emitters[0].bore") && msg.contains("≥ 0"),
        "{msg}"
    );
    // The bore must fit in the domain behind the tip.
    let e = parse(&text(
        "Fixed(at: (0.03, 0.09, 0.03), duration: 2.0)",
        "0.03",
    ))
    .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("emitters[0].path") && msg.contains("bore"),
        "{msg}"
    );
}

// ---------------------------------------------------------------------------------------------
// Bodies released during the run (`bodies[i].release_time`, `DelayedBody`)

fn released_body_scene(release_time: &str) -> String {
    format!(
        r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.2, 0.2, 0.2)),
    dx: 0.01,
    gravity: (0.0, -9.81, 0.0),
    duration: 0.1,
    frame_rate: 50.0,
    materials: [
        (name: "water", density: 1000.0, sound_speed: 5.0, viscosity: 0.1),
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
    thermal: (
        materials: [(material: "melt", diffusivity: 1e-3, initial_temperature: 0.3)],
    ),
    bodies: [
        (material: "water", shape: Box(min: (0.0, 0.0, 0.0), max: (0.2, 0.04, 0.2))),
        (
            material: "melt",
            shape: Sphere(center: (0.1, 0.12, 0.1), radius: 0.03),
            velocity: (0.0, -0.5, 0.0),
            release_time: {release_time},
        ),
    ],
)"#
    )
}

/// A body with a release time is absent until the first step end that reaches it, then
/// present with all its particles, its mass, its velocity, its model state and its
/// material's initial temperature; the run stays healthy (the energy monitor takes the new
/// particles as input, not as a blow-up).
#[test]
fn a_released_body_appears_at_its_release_time() {
    let scene = parse_scene_str(
        &released_body_scene("0.05"),
        Path::new("drop.ron"),
        Path::new("scenes"),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let (pool, drop) = (
        scene.particles[0].positions.len(),
        scene.particles[1].positions.len(),
    );
    assert!(drop > 100, "{drop} particles in the drop");
    let drop_mass = drop as f64 * scene.particles[1].particle_volume as f64 * 1000.0;
    let mut app = treacle::runner::scene_app(&scene);
    let (n0, m0) = particle_mass(app.world_mut());
    assert_eq!(n0, pool, "only the pool is there at the start");
    let melt = MaterialId(1);
    let mut released_at = None;
    for frame in 1..=5 {
        app.update();
        let t = app.world().resource::<SimulationClock>().time;
        assert!(
            app.world().resource::<SimulationStatus>().failure.is_none(),
            "frame {frame}: {:?}",
            app.world().resource::<SimulationStatus>().failure
        );
        let (n, m) = particle_mass(app.world_mut());
        if t < 0.05 - 1e-9 {
            assert_eq!(n, pool, "t = {t}: released too early");
            continue;
        }
        assert_eq!(n, pool + drop, "t = {t}: the whole drop appears");
        assert!(
            ((m - m0) / drop_mass - 1.0).abs() < 1e-6,
            "mass grows by the drop's: {} against {drop_mass}",
            m - m0
        );
        let world = app.world_mut();
        let mut q = world.query::<(
            &MaterialId,
            &Velocity,
            Option<&treacle::rheology::PolymerStress>,
            Option<&Temperature>,
        )>();
        let (mut count, mut mean_vy) = (0usize, 0.0f64);
        for (id, v, polymer, temp) in q.iter(world) {
            if *id != melt {
                continue;
            }
            count += 1;
            mean_vy += v.0.y as f64;
            assert!(polymer.is_some(), "the drop gets its model state");
            assert!(temp.is_some(), "the drop gets its thermal state");
        }
        assert_eq!(count, drop);
        mean_vy /= drop as f64;
        if released_at.is_none() {
            // Released at most one step (≤ 1 frame here) ago from −0.5 m/s, falling.
            assert!(
                (-0.75..=-0.45).contains(&mean_vy),
                "t = {t}: mean vy of the drop {mean_vy}"
            );
            released_at = Some(t);
        }
    }
    assert!(released_at.is_some(), "the drop was released");
    // Temperature at release: the material's initial temperature (the solve changes it later
    // only by conduction within the drop, which starts uniform).
    let world = app.world_mut();
    let mut q = world.query::<(&MaterialId, &Temperature)>();
    for (id, t) in q.iter(world) {
        if *id == melt {
            assert!((t.value - 0.3).abs() < 1e-4, "T = {}", t.value);
        }
    }
}

#[test]
fn scene_release_time_is_checked() {
    let parse = |t: &str| {
        parse_scene_str(
            &released_body_scene(t),
            Path::new("drop.ron"),
            Path::new("scenes"),
        )
    };
    for bad in ["0.1", "0.2", "-0.01", "inf"] {
        let msg = parse(bad).unwrap_err().to_string();
        assert!(
            msg.contains("bodies[1].release_time") && msg.contains("drop.ron:32"),
            "release_time {bad}: {msg}"
        );
    }
    assert!(parse("0.0").is_ok() && parse("0.099").is_ok());
}

// ---------------------------------------------------------------------------------------------
// Slot nozzles (`emitters[i].slot`, `slot_lattice`)

/// A slot's layer is a rectangle of points spaced h, offset by h/2 along the slot, so a slot as
/// long as a periodic span L holds L/h points per row that meet their images at spacing h; the
/// mass rate stays ρ₀Q̇ (v_e from the layer's size).
#[test]
fn slot_lattice_fills_a_rectangle_that_tiles_a_periodic_span() {
    let (h, r, l) = (0.000625f32, 0.005f32, 0.01f32);
    let pts = treacle::emit::slot_lattice(Vec3::NEG_Y, Vec3::Z, r, l, h);
    assert_eq!(pts.len(), 16 * 17, "16 along the slot, 17 across");
    let (zmin, zmax) = pts
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), p| {
            (a.min(p.z), b.max(p.z))
        });
    assert!((zmin + (l - h) / 2.0).abs() < 1e-7 && (zmax - (l - h) / 2.0).abs() < 1e-7);
    // The last point and the first's image one span further are h apart.
    assert!(((zmin + l) - zmax - h).abs() < 1e-7);
    assert!(
        pts.iter()
            .all(|p| p.y.abs() < 1e-9 && p.x.abs() <= r * (1.0 + 1e-6))
    );
    // Any direction is projected onto the plane ⊥ the axis.
    let tilted = treacle::emit::slot_lattice(Vec3::NEG_Y, Vec3::new(0.0, 0.5, 1.0), r, l, h);
    assert_eq!(tilted.len(), pts.len());
    assert!(tilted.iter().all(|p| p.y.abs() < 1e-9));
    let nozzle = NozzleEmitter::new(
        ToolPath::fixed(DVec3::new(0.04, 0.08, 0.005), 1.0).unwrap(),
        Vec3::NEG_Y,
        r,
        1e-5,
        h,
        MaterialId(0),
    )
    .with_slot(Vec3::Z, l);
    let v_e = nozzle.extrusion_speed(nozzle.lattice().len());
    let rate = v_e * nozzle.lattice().len() as f64 * (h as f64).powi(3) / h as f64;
    assert!((rate / 1e-5 - 1.0).abs() < 1e-12, "volume rate {rate}");
}

/// A slot along the nozzle axis, or shorter than two spacings, is rejected with its field.
#[test]
fn scene_slot_is_checked() {
    let text = |slot: &str| {
        format!(
            r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.08, 0.1, 0.01)),
    dx: 0.0025,
    duration: 0.1,
    frame_rate: 50.0,
    walls: (z_min: Periodic, z_max: Periodic),
    materials: [(name: "syrup", density: 1000.0, sound_speed: 2.0, viscosity: 20.0)],
    emitters: [
        (
            material: "syrup",
            path: Fixed(at: (0.04, 0.08, 0.005), duration: 1.0),
            radius: 0.005,
            slot: {slot},
            volume_rate: 1e-5,
        ),
    ],
)"#
        )
    };
    let parse = |t: &str| parse_scene_str(t, Path::new("sheet.ron"), Path::new("scenes"));
    let s = parse(&text("Some((direction: (0.0, 0.0, 1.0), length: 0.01))"))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(s.emitters[0].lattice().len(), 8 * 9);
    let msg = parse(&text("Some((direction: (0.0, -2.0, 0.0), length: 0.01))"))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("emitters[0].slot.direction") && msg.contains("sheet.ron:13"),
        "{msg}"
    );
    let msg = parse(&text("Some((direction: (0.0, 0.0, 1.0), length: 0.001))"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("emitters[0].slot.length"), "{msg}");
    // Longer than the periodic span: its layer would leave the domain.
    let msg = parse(&text("Some((direction: (0.0, 0.0, 1.0), length: 0.02))"))
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains("emitters[0].path") && msg.contains("outside"),
        "{msg}"
    );
}
