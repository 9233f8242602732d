//! Bad input and faults (issue 14): each reproducer of the issue is refused at load with the
//! field named, or stopped with a diagnostic, never a panic, an abort, a hang or a silent
//! wrong result; the output folder policy, signals and kill -9 leave complete files.
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use crate::common::{BIN, crate_dir, scratch, treacle};
use treacle::output::read_frame;
use treacle::runner::{RunError, RunOptions, bench_scene, run_scene};
use treacle::scene::{Scene, SceneError, parse_scene_str};

fn droplet_text() -> String {
    std::fs::read_to_string(crate_dir().join("scenes/droplet.ron")).unwrap()
}

/// The droplet with `from` replaced by `to` (which must occur).
fn droplet_with(from: &str, to: &str) -> String {
    let text = droplet_text();
    assert!(text.contains(from), "the droplet scene has `{from}`");
    text.replacen(from, to, 1)
}

fn parse(text: &str) -> Result<Scene, SceneError> {
    parse_scene_str(text, Path::new("mutant.ron"), &crate_dir().join("scenes"))
}

/// The load error's located fields (panics if the text loads).
fn refused(text: &str) -> Vec<(usize, String, String)> {
    match parse(text) {
        Ok(_) => panic!("the scene was accepted"),
        Err(e) => {
            assert!(!e.errors().is_empty(), "a located error: {e}");
            e.errors()
                .iter()
                .map(|f| (f.line, f.field.clone(), f.message.clone()))
                .collect()
        }
    }
}

/// Asserts that `text` is refused with an error on `field` whose message contains `needle`.
fn refused_on(text: &str, field: &str, needle: &str) {
    let errors = refused(text);
    assert!(
        errors
            .iter()
            .any(|(line, f, m)| *line > 0 && f == field && m.contains(needle)),
        "expected an error on `{field}` mentioning `{needle}`, got {errors:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// Reproducers refused at load

/// A mesh collider scaled to denormal coordinates (`scale: 1e-40`, found by the fuzz with seed
/// 2027) overflowed the stack in the bounding-volume hierarchy's build (every box the same);
/// it is refused at the scale.
#[test]
fn a_mesh_scaled_below_single_precision_is_refused() {
    let text = std::fs::read_to_string(crate_dir().join("scenes/stamping_bunny.ron")).unwrap();
    let text = text.replace(
        "Mesh(path: \"meshes/bunny.obj\", scale: 0.15)",
        "Mesh(path: \"meshes/bunny.obj\", scale: 1e-40)",
    );
    assert!(text.contains("scale: 1e-40"));
    refused_on(
        &text,
        "colliders[0].shape.scale",
        "too small for single precision",
    );
}

/// `density: 1e-40` gave "30 frames, 0 steps", exit 0: the particle mass underflows f32.
#[test]
fn underflowing_density_is_refused() {
    refused_on(
        &droplet_with("density: 1000.0", "density: 1e-40"),
        "materials[0].density",
        "particle mass",
    );
}

/// `time_step: (mode: Fixed(1e-30))` hung forever (t + Δt = t).
#[test]
fn a_fixed_step_that_cannot_reach_the_end_is_refused() {
    refused_on(
        &droplet_with(
            "frame_rate: 60.0,",
            "frame_rate: 60.0, time_step: (mode: Fixed(1e-30)),",
        ),
        "time_step.mode",
        "never finish",
    );
}

/// A frame rate below 1/duration ran past the duration without bound; 1e-30 hung.
#[test]
fn a_frame_longer_than_the_run_is_refused() {
    for rate in ["1e-30", "1.0"] {
        refused_on(
            &droplet_with("frame_rate: 60.0,", &format!("frame_rate: {rate},")),
            "frame_rate",
            "1/duration",
        );
    }
    // 0.5 s at 45 frames/s is 22.5 frames: the last one would end past the duration.
    refused_on(
        &droplet_with("frame_rate: 60.0,", "frame_rate: 45.0,"),
        "frame_rate",
        "not a whole number",
    );
}

/// Finite overflows (velocity, sound speed or density near 1e30–3e38) ended in the output
/// writer; they are field errors now.
#[test]
fn single_precision_overflows_are_refused_at_load() {
    refused_on(
        &droplet_with("sound_speed: 10.0", "sound_speed: 1e19"),
        "materials[0].sound_speed",
        "Tait pressure",
    );
    // ρ₀ = 3e38 overflows first in the Tait pressure ρ₀c²/γ(2^γ − 1).
    refused_on(
        &droplet_with("density: 1000.0", "density: 3e38"),
        "materials[0].sound_speed",
        "Tait pressure",
    );
    refused_on(
        &droplet_with("velocity: (0.0, 0.0, 0.0)", "velocity: (1e30, 0.0, 0.0)"),
        "bodies",
        "exceeds single precision",
    );
}

/// A 100,000-level nesting used 5.5 GB in the error-location pass; now a linear pre-scan
/// refuses it at the bracket that crosses the limit.
#[test]
fn deep_nesting_is_refused_with_its_position() {
    let deep = format!("Scene(dx: {}{})", "[".repeat(100_000), "]".repeat(100_000));
    match parse(&deep) {
        Err(SceneError::Text(e)) => {
            assert_eq!(e.line, 1);
            // `Scene(` is level 1, `dx: [` … the 64th `[` is level 65.
            assert_eq!(e.col, "Scene(dx: ".len() + 64);
            assert!(e.message.contains("nested more than 64"), "{e}");
        }
        other => panic!("expected a nesting error, got {other:?}"),
    }
}

#[test]
fn byte_order_mark_is_accepted_and_invalid_utf8_is_located() {
    let dir = scratch("encoding");
    let bom = dir.join("bom.ron");
    std::fs::write(&bom, format!("\u{feff}{}", droplet_text())).unwrap();
    treacle::scene::load_scene(&bom).expect("a UTF-8 byte-order mark is accepted");

    let text = droplet_text();
    let at = text.find("\"viscous\"").unwrap() + 3;
    let mut bytes = text.clone().into_bytes();
    bytes.insert(at, 0xff);
    let bad = dir.join("bad.ron");
    std::fs::write(&bad, &bytes).unwrap();
    let e = treacle::scene::load_scene(&bad).unwrap_err();
    let line = text[..at].matches('\n').count() + 1;
    let col = at - text[..at].rfind('\n').map_or(0, |i| i + 1) + 1;
    assert_eq!((e.errors()[0].line, e.errors()[0].col), (line, col), "{e}");
    assert!(e.to_string().contains(&format!("byte offset {at}")), "{e}");
}

/// A 3 MB material name is not echoed in full.
#[test]
fn long_strings_are_shortened_in_messages() {
    let long = "x".repeat(3_000_000);
    let text = droplet_with("name: \"viscous\"", &format!("name: \"{long}\""));
    let message = parse(&text).unwrap_err().to_string();
    assert!(message.len() < 2_000, "message of {} bytes", message.len());
    assert!(message.contains("characters]"), "{message}");
}

/// `G1 X1e1 F6000` was read as `X1 E1` and extruded.
#[test]
fn gcode_exponents_are_errors_with_the_line() {
    let e = treacle::emit::gcode::parse_gcode("G21\nG90\nG1 X1e1 F6000\n").unwrap_err();
    let text = e.to_string();
    assert!(text.starts_with("<gcode>:3: `X1e1`"), "{text}");
    assert!(text.contains("no exponent"), "{text}");
    // Numbers of the grammar still read, with or without a space after the letter.
    let p = treacle::emit::gcode::parse_gcode("G21\nG90\nG1 X10 Y-2.5 E.5 F6000\n").unwrap();
    assert!(!p.moves.is_empty());
}

// ---------------------------------------------------------------------------------------------
// Reproducers stopped with a diagnostic

/// Gravity 1e15 froze the liquid (predicted positions far outside their stencils) and the run
/// exited 0 with frozen frames (from about 1e11 on). Now the gravity term of the time-step
/// rule (D17) shrinks Δt; at 1e15 the droplet reaches the floor within a few steps and the run
/// stops with a diagnostic naming the limiting term.
#[test]
fn huge_gravity_stops_with_a_diagnostic() {
    let scene = parse(&droplet_with("(0.0, -9.81, 0.0)", "(0.0, -1e15, 0.0)")).unwrap();
    let opts = RunOptions {
        frames: Some(3),
        ..RunOptions::new(scratch("gravity"))
    };
    match run_scene(scene.clone(), &opts, |_, _| {}) {
        Err(RunError::Failed(f)) => {
            assert!(f.step < 100, "stopped only at step {}", f.step);
            assert!(f.reason.contains("limited by"), "{f}");
        }
        other => panic!("expected a numerical failure, got {other:?}"),
    }
}

/// At 1e11 (where the liquid used to freeze) it falls: after 10 steps the droplet's momentum is
/// its mass times g·t, the free fall it is in (no wall is within reach: it starts 0.1 m above
/// the floor and falls ½gt² ≈ 0.025 m), to f32 rounding of the summed momenta (10⁻⁴).
#[test]
fn a_droplet_under_extreme_gravity_falls_freely() {
    use bevy_ecs::prelude::*;
    use treacle::components::{Mass, Particle, Velocity};
    use treacle::step::driver::{run_step, start};
    use treacle::step::schedule::SimulationClock;
    let g = -1e11;
    let scene = parse(&droplet_with(
        "(0.0, -9.81, 0.0)",
        &format!("(0.0, {g:e}, 0.0)"),
    ))
    .unwrap();
    let mut app = treacle::runner::scene_app(&scene);
    let world = app.world_mut();
    start(world);
    let mut t = 0.0;
    for _ in 0..10 {
        let dt = world.resource::<SimulationClock>().next_dt;
        assert!(
            dt > 0.0 && dt < 1e-6,
            "Δt = {dt} (the gravity term limits it)"
        );
        run_step(world, dt, false);
        assert!(
            !world
                .resource::<treacle::failure::SimulationStatus>()
                .failed()
        );
        t += dt;
    }
    let mut q = world.query_filtered::<(&Mass, &Velocity), With<Particle>>();
    let (m, p) = q.iter(world).fold((0.0, 0.0), |(m, p), (mi, v)| {
        (m + mi.0 as f64, p + (mi.0 * v.0.y) as f64)
    });
    let expected = g * t;
    assert!(
        (p / m - expected).abs() <= 1e-4 * expected.abs(),
        "mean velocity {:.6e} m/s, free fall {expected:.6e} m/s",
        p / m
    );
}

/// The predictor check: with the gravity term removed by a fixed step, a particle whose
/// predicted position jumps more than 2Δx stops the run at the first step instead of freezing.
#[test]
fn a_predictor_jump_is_a_blow_up() {
    let scene = parse(&droplet_with(
        "(0.0, -9.81, 0.0)",
        "(0.0, -1e9, 0.0), time_step: (mode: Fixed(1e-4))",
    ))
    .unwrap();
    match run_scene(scene.clone(), &RunOptions::new(scratch("jump")), |_, _| {}) {
        Err(RunError::Failed(f)) => {
            assert_eq!(f.step, 0, "{f}");
            assert_eq!(f.quantity, "predicted position", "{f}");
            assert!(f.entity.is_some(), "names the particle: {f}");
        }
        other => panic!("expected a blow-up, got {other:?}"),
    }
}

/// A step that cannot advance the time (t + Δt = t) stops the run instead of looping.
#[test]
fn a_step_that_does_not_advance_time_is_a_failure() {
    use treacle::step::schedule::SimulationClock;
    let scene = parse(&droplet_with(
        "frame_rate: 60.0,",
        "frame_rate: 60.0, time_step: (mode: Fixed(1e-5)),",
    ))
    .unwrap();
    let mut app = treacle::runner::scene_app(&scene);
    app.update();
    // Far into the run, the fixed step is below the spacing of doubles near t.
    app.world_mut().resource_mut::<SimulationClock>().time = 1e12;
    app.world_mut().resource_mut::<SimulationClock>().frame = (1e12 * 60.0) as u64;
    app.update();
    let status = app.world().resource::<treacle::failure::SimulationStatus>();
    let f = status.failure.as_ref().expect("the run stopped");
    assert_eq!(f.quantity, "time step");
    assert!(f.reason.contains("does not advance"), "{f}");
}

/// The droplet in a 1 m box at dx = 2 mm validated "ok" and aborted allocating 12.5 GB of dense
/// grid; with the block-sparse grid its 125 M-node box costs only the block table (4 B per 64
/// nodes) and the estimate fits in 4 GB. The same droplet at dx = 0.5 mm has 8.4 M particles (about
/// 7 GB) and is refused before anything is allocated, naming the fields that drive the
/// estimate; so is the emitter of `letters.ron` with `volume_rate: 1e3`.
#[test]
fn scenes_beyond_the_memory_limit_are_refused() {
    let limit: u64 = 4 << 30;
    let big_box = parse(
        &droplet_with("max: (0.3, 0.3, 0.3)", "max: (1.0, 1.0, 1.0)").replacen(
            "dx: 0.01,",
            "dx: 0.002,",
            1,
        ),
    )
    .unwrap();
    let estimate = big_box.resource_estimate();
    assert!(estimate.box_nodes > 125_000_000, "{estimate}");
    // The allocated nodes follow the particles, not the box.
    assert!(estimate.grid_nodes <= estimate.particles(), "{estimate}");
    assert!(estimate.bytes() < limit, "{estimate}");

    let fine = parse(&droplet_with("dx: 0.01,", "dx: 0.0005,")).unwrap();
    let estimate = fine.resource_estimate();
    assert!(estimate.bytes() > limit, "{estimate}");
    let dir = scratch("big");
    let opts = RunOptions {
        max_memory: Some(limit),
        ..RunOptions::new(&dir)
    };
    match run_scene(fine.clone(), &opts, |_, _| {}) {
        Err(RunError::TooLarge(m)) => {
            assert!(
                m.contains("`dx`") && m.contains("`particles_per_cell`"),
                "{m}"
            )
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    assert_eq!(
        std::fs::read_dir(&dir).unwrap().count(),
        0,
        "nothing written"
    );

    let letters = std::fs::read_to_string(crate_dir().join("scenes/letters.ron")).unwrap();
    let rate = letters
        .lines()
        .find(|l| l.trim_start().starts_with("volume_rate:"))
        .expect("letters.ron has an emitter")
        .to_string();
    let flood = parse(&letters.replacen(&rate, "volume_rate: 1e3,", 1)).unwrap();
    let estimate = flood.resource_estimate();
    assert!(estimate.emitted_particles > 1_000_000_000, "{estimate}");
    match run_scene(flood.clone(), &RunOptions::new(scratch("flood")), |_, _| {}) {
        Err(RunError::TooLarge(m)) => assert!(m.contains("volume_rate"), "{m}"),
        other => panic!("expected a refusal, got {other:?}"),
    }
    assert!(matches!(
        bench_scene(flood.clone(), 1),
        Err(RunError::TooLarge(_))
    ));
}

/// `validate` prints the estimate (nodes, particles, memory, steps) and the CLI refuses at
/// run time with exit 1.
#[test]
fn validate_prints_the_estimate_and_run_refuses_with_exit_1() {
    let o = treacle(&["validate", "scenes/droplet.ron"]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success());
    assert!(
        out.contains("(node box 54872)") && out.contains("4224 particles") && out.contains("steps"),
        "{out}"
    );
    let dir = scratch("cli-refuse");
    let o = treacle(&[
        "run",
        "scenes/droplet.ron",
        "--out",
        dir.to_str().unwrap(),
        "--max-memory",
        "1M",
    ]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("the given limit"));
}

// ---------------------------------------------------------------------------------------------
// Command line

#[test]
fn usage_errors_and_thread_counts_have_their_exit_code() {
    for args in [
        &["run", "--bogus"][..],
        &["run"][..],
        &["run", "scenes/droplet.ron", "--threads", "100000"][..],
        &["run", "scenes/droplet.ron", "--threads", "0"][..],
        &["run", "scenes/droplet.ron", "--max-memory", "lots"][..],
    ] {
        let o = treacle(args);
        assert_eq!(o.status.code(), Some(64), "{args:?}");
        assert!(!o.stderr.is_empty());
    }
    assert_eq!(treacle(&["--help"]).status.code(), Some(0));
}

// ---------------------------------------------------------------------------------------------
// Output folders, signals, kill -9

/// A short droplet run (2 frames of 1/60 s) into `dir`.
fn short_run(dir: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        "scenes/droplet.ron",
        "--frames",
        "2",
        "--out",
        dir.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    treacle(&args)
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn a_folder_of_another_run_is_refused_unless_forced() {
    let dir = scratch("folder");
    // An earlier, longer run's frames and a temporary file a killed writer left.
    assert!(short_run(&dir, &[]).status.success());
    std::fs::copy(dir.join("frame_00002.ply"), dir.join("frame_00009.ply")).unwrap();
    std::fs::write(dir.join(".frame_00003.ply.999-1.tmp"), b"partial").unwrap();
    std::fs::write(dir.join("notes.txt"), b"the user's").unwrap();
    let o = short_run(&dir, &[]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--force") && err.contains("frame_00000.ply"),
        "{err}"
    );
    assert!(
        !names(&dir).iter().any(|n| n.ends_with(".tmp")),
        "temp files removed"
    );
    let o = short_run(&dir, &["--force"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        names(&dir),
        [
            "frame_00000.ply",
            "frame_00001.ply",
            "frame_00002.ply",
            "metrics.csv",
            "notes.txt"
        ]
    );
}

/// Every frame file in `dir` reads back whole, there is no temporary file, and metrics.csv
/// has one row per frame from 0 to the last frame written. Returns the frame count.
fn assert_consistent(dir: &Path) -> usize {
    let all = names(dir);
    assert!(!all.iter().any(|n| n.ends_with(".tmp")), "{all:?}");
    let frames: Vec<&String> = all.iter().filter(|n| n.starts_with("frame_")).collect();
    for f in &frames {
        read_frame(&dir.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
    }
    if let Ok(metrics) = std::fs::read_to_string(dir.join("metrics.csv")) {
        let rows = metrics.lines().count() - 1;
        // A kill between a frame file and its metrics row leaves the metrics one frame behind.
        assert!(
            rows == frames.len() || rows + 1 == frames.len(),
            "{rows} metrics rows for {} frames",
            frames.len()
        );
    }
    frames.len()
}

/// Waits until `dir` holds `frame` (or the process ends).
fn wait_for(dir: &Path, frame: &str, child: &mut std::process::Child) {
    for _ in 0..6000 {
        if dir.join(frame).exists() || child.try_wait().unwrap().is_some() {
            return;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    panic!("{frame} never appeared");
}

#[cfg(unix)]
#[test]
fn sigint_and_sigterm_stop_after_the_step_with_consistent_files() {
    for (signal, code) in [("INT", 130), ("TERM", 143)] {
        let dir = scratch(&format!("sig{signal}"));
        let mut child = Command::new(BIN)
            .args(["run", "scenes/droplet.ron", "--out", dir.to_str().unwrap()])
            .current_dir(crate_dir())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        wait_for(&dir, "frame_00002.ply", &mut child);
        // The shell's built-in `kill` (no procps needed on a bare machine).
        let kill = Command::new("sh")
            .args(["-c", &format!("kill -{signal} {}", child.id())])
            .status()
            .unwrap();
        assert!(kill.success());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "SIG{signal}: {err}");
        assert!(err.contains("interrupted at t ="), "{err}");
        let frames = assert_consistent(&dir);
        assert!((3..31).contains(&frames), "{frames} frames");
        let metrics = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
        assert_eq!(
            metrics.lines().count() - 1,
            frames,
            "one metrics row per frame"
        );
    }
}

/// `kill -9` at ten moments spread over a run (deterministic delays) leaves only complete
/// frames; the next start (with --force) removes the temporary files and writes a whole run.
#[cfg(unix)]
#[test]
fn kill_9_leaves_complete_frames_and_the_next_start_cleans_up() {
    let dir = scratch("kill9");
    for k in 0..10u64 {
        let mut child = Command::new(BIN)
            .args([
                "run",
                "scenes/droplet.ron",
                "--frames",
                "12",
                "--force",
                "--out",
                dir.to_str().unwrap(),
            ])
            .current_dir(crate_dir())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        // 20 … 470 ms: from loading to late frames.
        std::thread::sleep(Duration::from_millis(20 + 50 * ((k * 7) % 10)));
        let _ = child.kill();
        let _ = child.wait();
        // Frames already written are complete (temporary files may remain until the next
        // start).
        for f in names(&dir).iter().filter(|n| n.starts_with("frame_")) {
            read_frame(&dir.join(f)).unwrap_or_else(|e| panic!("kill {k}: {f}: {e}"));
        }
    }
    let o = short_run(&dir, &["--force"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(assert_consistent(&dir), 3);
}
