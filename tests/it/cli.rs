//! The `treacle` command-line tool, run as a separate process: `run` (determinism across
//! thread counts and runs, VTK output, the failure path), `validate` (good and bad scenes) and
//! `bench` (the summary line).
use crate::common::{BIN, crate_dir, scratch, treacle};
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use treacle::output::read_ply;

fn scene(name: &str) -> PathBuf {
    crate_dir().join("scenes").join(name)
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn describe(o: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}\n--- stderr\n{}",
        o.status.code(),
        stdout(o),
        stderr(o)
    )
}

/// Runs `treacle run SCENE --out DIR EXTRA...` and asserts success.
fn run_ok(scene: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = treacle(&args);
    assert!(
        o.status.success(),
        "treacle {args:?} failed:\n{}",
        describe(&o)
    );
    o
}

/// The file names in `dir` (including hidden ones), sorted.
fn file_names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// The particle files (`frame_*.EXT`) in `dir`, sorted.
fn frames(dir: &Path, ext: &str) -> Vec<String> {
    file_names(dir)
        .into_iter()
        .filter(|n| n.starts_with("frame_") && n.ends_with(&format!(".{ext}")))
        .collect()
}

/// `metrics.csv` as rows of cells with the `wall_seconds` column removed (the only column
/// that may differ between two runs of the same scene).
fn metrics_without_wall_time(dir: &Path) -> Vec<Vec<String>> {
    let text = fs::read_to_string(dir.join("metrics.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("metrics header").split(',').collect();
    let wall = header
        .iter()
        .position(|c| *c == "wall_seconds")
        .expect("a wall_seconds column");
    let strip = |line: &str| -> Vec<String> {
        line.split(',')
            .enumerate()
            .filter(|(i, _)| *i != wall)
            .map(|(_, c)| c.to_string())
            .collect()
    };
    std::iter::once(strip(&header.join(",")))
        .chain(lines.map(strip))
        .collect()
}

/// Asserts that two output directories hold the same particle files, byte for byte, and the
/// same metrics apart from the wall time.
fn assert_same_output(a: &Path, b: &Path, what: &str) {
    let fa = frames(a, "ply");
    let fb = frames(b, "ply");
    assert_eq!(fa, fb, "{what}: different particle files");
    for name in &fa {
        let ba = fs::read(a.join(name)).unwrap();
        let bb = fs::read(b.join(name)).unwrap();
        assert!(
            ba == bb,
            "{what}: {name} differs ({} vs {} bytes)",
            ba.len(),
            bb.len()
        );
    }
    let ma = metrics_without_wall_time(a);
    let mb = metrics_without_wall_time(b);
    assert_eq!(ma.len(), mb.len(), "{what}: metrics.csv row counts");
    for (ra, rb) in ma.iter().zip(&mb) {
        assert_eq!(
            ra, rb,
            "{what}: metrics.csv rows differ (wall_seconds excluded)"
        );
    }
}

/// `treacle run` writes byte-identical particle files (and metrics up to the wall time) with 1
/// and 2 worker threads, and again on a second run with the same thread count (1 and 2): the
/// scatter and every reduction are designed to be independent of the thread count and of
/// thread timing.
#[test]
fn run_is_deterministic_across_thread_counts_and_runs() {
    let droplet = scene("droplet.ron");
    let base = scratch("determinism");
    let (t1, t1b) = (base.join("t1"), base.join("t1b"));
    let (t2, t2b) = (base.join("t2"), base.join("t2b"));
    let o = run_ok(&droplet, &t1, &["--frames", "3", "--threads", "1"]);
    assert!(
        stdout(&o).contains("3 frames"),
        "summary line: {}",
        stdout(&o)
    );
    run_ok(&droplet, &t2, &["--frames", "3", "--threads", "2"]);
    run_ok(&droplet, &t1b, &["--frames", "3", "--threads", "1"]);
    run_ok(&droplet, &t2b, &["--frames", "3", "--threads", "2"]);

    // Frames 0..=3 plus metrics.csv, nothing else (no temporary files left behind).
    let expect: Vec<String> = (0..=3).map(|f| format!("frame_{f:05}.ply")).collect();
    assert_eq!(frames(&t1, "ply"), expect);
    for dir in [&t1, &t1b, &t2, &t2b] {
        let mut all = expect.clone();
        all.push("metrics.csv".into());
        all.sort();
        assert_eq!(file_names(dir), all, "{}", dir.display());
    }
    // The particles moved (otherwise identical files would prove little).
    let f0 = read_ply(&t1.join("frame_00000.ply")).unwrap();
    let f3 = read_ply(&t1.join("frame_00003.ply")).unwrap();
    assert_eq!(f0.len(), f3.len());
    assert!(f0.len() > 1000, "droplet particles: {}", f0.len());
    assert!(
        f3.velocities.iter().any(|v| v[1] < -0.1),
        "the droplet falls"
    );
    assert!(
        (f3.time - 3.0 / 60.0).abs() < 1e-9,
        "frame 3 at t = {}",
        f3.time
    );

    assert_same_output(&t1, &t2, "--threads 1 vs --threads 2");
    assert_same_output(&t1, &t1b, "two runs with --threads 1");
    assert_same_output(&t2, &t2b, "two runs with --threads 2");
    let _ = fs::remove_dir_all(&base);
}

/// The same with enough particles that the block-sparse transfers split every colour phase of
/// the scatter into several parallel tasks (the droplet at Δx = 5 mm: 33,552 particles, tasks
/// of 2048): the grid sums stay in colour and particle order, so 1 and 2 threads agree bit for
/// bit.
#[test]
fn run_is_deterministic_across_thread_counts_with_parallel_block_tasks() {
    let base = scratch("determinism-blocks");
    fs::create_dir_all(&base).unwrap();
    let text = fs::read_to_string(scene("droplet.ron")).unwrap();
    assert!(text.contains("dx: 0.01,"));
    let fine = base.join("droplet_fine.ron");
    fs::write(&fine, text.replacen("dx: 0.01,", "dx: 0.005,", 1)).unwrap();
    let (t1, t2) = (base.join("t1"), base.join("t2"));
    run_ok(&fine, &t1, &["--frames", "1", "--threads", "1"]);
    run_ok(&fine, &t2, &["--frames", "1", "--threads", "2"]);
    let f1 = read_ply(&t1.join("frame_00001.ply")).unwrap();
    assert!(f1.len() > 16 * 2048, "particles: {}", f1.len());
    assert_same_output(&t1, &t2, "fine droplet, --threads 1 vs --threads 2");
    let _ = fs::remove_dir_all(&base);
}

/// `--format vtk` writes legacy VTK files (one per frame) instead of PLY.
#[test]
fn run_format_vtk_writes_vtk_files() {
    let dir = scratch("vtk");
    let out = dir.join("out");
    run_ok(
        &scene("droplet.ron"),
        &out,
        &["--frames", "2", "--threads", "1", "--format", "vtk"],
    );
    let vtk = frames(&out, "vtk");
    assert_eq!(
        vtk,
        ["frame_00000.vtk", "frame_00001.vtk", "frame_00002.vtk"]
    );
    assert!(
        frames(&out, "ply").is_empty(),
        "no PLY files with --format vtk"
    );
    for name in &vtk {
        let bytes = fs::read(out.join(name)).unwrap();
        assert!(
            bytes.starts_with(b"# vtk DataFile Version"),
            "{name}: not a legacy VTK file"
        );
        let head = String::from_utf8_lossy(&bytes[..bytes.len().min(512)]).into_owned();
        assert!(head.contains("BINARY"), "{name}: header {head:?}");
        assert!(head.contains("POLYDATA"), "{name}: header {head:?}");
    }
    assert!(out.join("metrics.csv").is_file());
    let _ = fs::remove_dir_all(&dir);
}

/// `treacle validate` accepts every shipped scene and prints an `ok` line.
#[test]
fn validate_accepts_a_good_scene() {
    for name in ["droplet.ron", "dam_break.ron"] {
        let path = scene(name);
        let o = treacle(&["validate", path.to_str().unwrap()]);
        assert!(o.status.success(), "{name}:\n{}", describe(&o));
        assert!(stdout(&o).contains(": ok"), "{name}:\n{}", describe(&o));
    }
}

/// A scene with `dx: -1.0` *and* an unknown field: the parser stops at the unknown field
/// (syntax and type errors come before validation, see docs/scenes.md), so stderr names the
/// file, the line of the unknown field and the field. The same scene without the unknown
/// field is rejected by validation at the line of `dx`.
#[test]
fn validate_rejects_a_bad_scene_naming_file_line_and_field() {
    let dir = scratch("validate-bad");
    let bad = dir.join("bad_scene.ron");
    let text = "Scene(
    domain: (min: (0, 0, 0), max: (1, 1, 1)),
    dx: -1.0,
    duration: 0.1,
    frame_rate: 30,
    bogus_field: 3,
    materials: [(name: \"water\", density: 1000, sound_speed: 20)],
    bodies: [(material: \"water\", shape: Box(min: (0.1, 0.1, 0.1), max: (0.3, 0.3, 0.3)))],
)
";
    fs::write(&bad, text).unwrap();
    let o = treacle(&["validate", bad.to_str().unwrap()]);
    assert!(!o.status.success(), "bad scene accepted:\n{}", describe(&o));
    let err = stderr(&o);
    assert!(err.contains("bad_scene.ron:6:"), "file and line 6:\n{err}");
    assert!(err.contains("bogus_field"), "names the field:\n{err}");

    // Only the invalid value left: validation names `dx` at line 3.
    let bad_dx = dir.join("bad_dx.ron");
    fs::write(&bad_dx, text.replace("    bogus_field: 3,\n", "")).unwrap();
    let o = treacle(&["validate", bad_dx.to_str().unwrap()]);
    assert!(!o.status.success(), "dx = -1 accepted:\n{}", describe(&o));
    let err = stderr(&o);
    assert!(err.contains("bad_dx.ron:3:"), "file and line 3:\n{err}");
    assert!(err.contains("field `dx`"), "names the field:\n{err}");
    assert!(err.contains("-1"), "shows the value:\n{err}");

    // A missing file is an error too, naming the file.
    let missing = dir.join("no_such_scene.ron");
    let o = treacle(&["validate", missing.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no_such_scene.ron"), "{}", describe(&o));
    let _ = fs::remove_dir_all(&dir);
}

/// `treacle bench --steps 5` ends with `particles=P steps=5 seconds=T particle_steps_per_s=X`.
#[test]
fn bench_prints_the_summary_line() {
    let path = scene("droplet.ron");
    let o = treacle(&[
        "bench",
        path.to_str().unwrap(),
        "--steps",
        "5",
        "--threads",
        "1",
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    let out = stdout(&o);
    let last = out.lines().last().expect("some output");
    let kv: Vec<(&str, &str)> = last
        .split(' ')
        .map(|f| {
            f.split_once('=')
                .unwrap_or_else(|| panic!("field {f:?} in {last:?}"))
        })
        .collect();
    let keys: Vec<&str> = kv.iter().map(|(k, _)| *k).collect();
    assert_eq!(
        keys,
        ["particles", "steps", "seconds", "particle_steps_per_s"],
        "{last:?}"
    );
    let particles: u64 = kv[0].1.parse().unwrap_or_else(|_| panic!("P in {last:?}"));
    assert!(particles > 1000, "{last:?}");
    assert_eq!(kv[1].1, "5", "{last:?}");
    let seconds: f64 = kv[2].1.parse().unwrap_or_else(|_| panic!("T in {last:?}"));
    assert!(seconds.is_finite() && seconds >= 0.0, "{last:?}");
    let rate: f64 = kv[3].1.parse().unwrap_or_else(|_| panic!("X in {last:?}"));
    assert!(rate.is_finite() && rate >= 0.0, "{last:?}");
    // The droplet scene (r = 5 cm sphere, h = 5 mm) has ~4 200 particles.
    let validate = treacle(&["validate", path.to_str().unwrap()]);
    assert!(
        stdout(&validate).contains(&format!("{particles} particles")),
        "bench and validate disagree on the particle count:\n{}\n{}",
        out,
        stdout(&validate)
    );
}

/// Runs a falling water block with the given `time_step` setting, which must blow up, and
/// checks the failure path: exit code 2; stderr names the scene, the step, the particle, the
/// quantity and suggests a smaller Δt; the particle files written before the failure are
/// frames 0, 1, … without gaps, each reads back as a complete, finite frame, `metrics.csv` has
/// one row per written frame, and no temporary file remains. Returns the number of frames
/// written.
fn assert_blow_up(name: &str, time_step: &str, failed_dt: f64) -> usize {
    let dir = scratch(name);
    let path = dir.join(format!("{name}.ron"));
    // Water with c0 = 20 m/s at dx = 1 cm: the stable step is ~0.35 ms (sound) at rest and
    // shrinks as the block hits the floor.
    fs::write(
        &path,
        format!(
            "Scene(
    domain: (min: (0, 0, 0), max: (0.3, 0.3, 0.3)),
    dx: 0.01,
    duration: 1.0,
    frame_rate: 60,
    time_step: {time_step},
    walls: (y_min: Sticky),
    materials: [(name: \"water\", density: 1000, sound_speed: 20, viscosity: 0.001)],
    bodies: [
        (material: \"water\", shape: Box(min: (0.1, 0.0, 0.1), max: (0.2, 0.1, 0.2)),
         velocity: (0.0, -1.0, 0.0)),
    ],
)
"
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let o = treacle(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--threads",
        "2",
    ]);
    assert_eq!(o.status.code(), Some(2), "{name}: {}", describe(&o));
    let err = stderr(&o);
    assert!(
        err.contains(&format!("{name}.ron")),
        "names the scene:\n{err}"
    );
    assert!(
        err.contains("numerical failure at step "),
        "names the step:\n{err}"
    );
    assert!(err.contains(" on particle "), "names the particle:\n{err}");
    assert!(
        [
            "position",
            "velocity",
            "acceleration",
            "density",
            "kinetic energy"
        ]
        .iter()
        .any(|q| err.contains(&format!("): {q}"))),
        "names the quantity:\n{err}"
    );
    assert!(
        err.contains("Suggested fix: a time step of at most"),
        "suggests a time step:\n{err}"
    );
    let suggested: f64 = err
        .split("a time step of at most ")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("suggested Δt in:\n{err}"));
    assert!(
        suggested > 0.0 && suggested < failed_dt,
        "suggested Δt {suggested} s is not below the failed {failed_dt} s"
    );

    let written = frames(&out, "ply");
    let expect: Vec<String> = (0..written.len())
        .map(|f| format!("frame_{f:05}.ply"))
        .collect();
    assert!(!written.is_empty(), "{name}: frame 0 is always written");
    assert_eq!(written, expect, "{name}: frames 0, 1, … without gaps");
    for file in &written {
        let f = read_ply(&out.join(file)).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert_eq!(
            f.len(),
            8000,
            "{file}: 20³ particles in the 10 cm block (h = 5 mm)"
        );
        assert!(
            f.positions.iter().flatten().all(|v| v.is_finite())
                && f.velocities.iter().flatten().all(|v| v.is_finite())
                && f.fields
                    .iter()
                    .all(|(_, c)| c.iter().all(|v| v.is_finite())),
            "{file}: non-finite values"
        );
    }
    let metrics = fs::read_to_string(out.join("metrics.csv")).unwrap();
    assert_eq!(
        metrics.lines().count(),
        1 + written.len(),
        "{name}: metrics.csv rows:\n{metrics}"
    );
    let leftovers: Vec<String> = file_names(&out)
        .into_iter()
        .filter(|n| n.ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    assert!(written.len() < 60, "{name}: did not stop early");
    let _ = fs::remove_dir_all(&dir);
    written.len()
}

/// `Fixed(0.05)` (with `max_dt` raised so it is not capped at the default 1 ms; the step is
/// still clipped to the frame end, 1/60 s ≈ 50× the limit) blows up in the first step: only
/// frame 0 exists.
#[test]
fn run_failure_in_the_first_step_exits_2() {
    let n = assert_blow_up(
        "blowup_first_step",
        "(mode: Fixed(0.05), max_dt: 0.05)",
        1.0 / 60.0,
    );
    assert_eq!(n, 1, "only the initial frame");
}

/// `Fixed(4e-4)`, just above the limit (with the default `ParticleGs4` FLIP update
/// `Fixed(3.7e-4)` runs to the end, `Fixed(3.8e-4)` fails in frame 4; the adaptive step averages
/// 0.15 ms here): the instability grows for two frames (the block is on the floor by then)
/// before the monitor stops the run at step 109; the frames written until then are complete
/// and finite.
#[test]
fn run_failure_after_some_frames_keeps_healthy_frames() {
    let n = assert_blow_up("blowup_later", "(mode: Fixed(4e-4))", 4e-4);
    assert!(n >= 2, "{n} frames written before the failure");
}

/// Bad command lines exit non-zero without running anything.
#[test]
fn run_rejects_zero_threads_and_missing_scenes() {
    let dir = scratch("bad-args");
    let out = dir.join("out");
    let droplet = scene("droplet.ron");
    let o = treacle(&[
        "run",
        droplet.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--threads",
        "0",
    ]);
    assert!(!o.status.success(), "{}", describe(&o));
    assert!(stderr(&o).contains("--threads"), "{}", describe(&o));
    assert!(!out.exists(), "nothing written for a rejected command line");
    let o = treacle(&["run", dir.join("missing.ron").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", describe(&o));
    assert!(stderr(&o).contains("missing.ron"), "{}", describe(&o));
    let _ = fs::remove_dir_all(&dir);
}

/// `treacle validate X | head -0`: a closed stdout ends the command quietly (exit 0, no
/// panic message) instead of panicking on the broken pipe.
#[test]
fn closed_stdout_is_not_a_panic() {
    use std::process::Stdio;
    let mut child = Command::new(BIN)
        .args(["validate", "scenes/droplet.ron"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Close the read end before the child writes (it loads and samples the scene first).
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "stderr: {stderr}");
    assert!(
        out.status.success(),
        "status {:?}, stderr: {stderr}",
        out.status
    );
}

/// Without the `surface` feature, `run --surface` and `treacle surface` fail at once with a
/// message naming the feature (exit code 1), before any work.
#[cfg(not(feature = "surface"))]
#[test]
fn surface_options_name_the_missing_feature() {
    let dir = scratch("no_surface");
    let droplet = scene("droplet.ron");
    for args in [
        vec![
            "run",
            droplet.to_str().unwrap(),
            "--out",
            dir.to_str().unwrap(),
            "--surface",
        ],
        vec!["surface", dir.to_str().unwrap()],
    ] {
        let o = treacle(&args);
        assert_eq!(o.status.code(), Some(1), "{}", describe(&o));
        assert!(
            stderr(&o).contains("`surface` cargo feature"),
            "{}",
            describe(&o)
        );
    }
    assert_eq!(file_names(&dir), Vec::<String>::new(), "nothing written");
}

/// Without the `render` feature, `treacle render` is a clear error (exit 1) that says how to
/// build it, not a usage error or a panic.
#[cfg(not(feature = "render"))]
#[test]
fn render_without_the_feature_says_how_to_build_it() {
    let dir = scratch("render_without_feature");
    let o = Command::new(BIN)
        .args(["render", "out/none", "--out"])
        .arg(dir.join("png"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", describe(&o));
    let err = stderr(&o);
    assert!(
        err.contains("without the `render` feature") && err.contains("cargo render-build"),
        "{}",
        describe(&o)
    );
}

/// `treacle viscosity`: the armadillo scene's eight laws as η(γ̇) from the code. Checked against
/// the laws' closed forms at points where they are simple (the chart draws the same values):
/// the Newtonian material is its μ at every rate; the Cross law (Frobenius measure, so
/// s = γ̇/√2) is halfway between μ0 = 10 and μ∞ = 0.1 where m s = 1, i.e. γ̇ = √2/m; the
/// shear-thickening power law (m = 1, n = 1.5) is s^0.5. The PNG is written and decodable.
#[test]
fn viscosity_chart_draws_the_scene_laws() {
    use treacle::report::viscosity::viscosity_curves;
    let s = treacle::scene::load_scene(&scene("li_armadillos.ron")).unwrap();
    let sq2 = std::f64::consts::SQRT_2;
    // Four rates √2·10⁻², √2·10⁻¹, √2, √2·10 (logarithmic spacing between the ends).
    let c = viscosity_curves(&s, sq2 * 1e-2, sq2 * 1e1, 4);
    assert!(c.skipped.is_empty(), "{:?}", c.skipped);
    assert_eq!(c.curves.len(), 8);
    let curve = |name: &str| &c.curves.iter().find(|k| k.material == name).unwrap().points;
    for (_, eta) in curve("newtonian") {
        assert_eq!(*eta, 10.0);
    }
    let cross = curve("cross");
    let (rate, eta) = cross[2];
    assert!((rate - sq2).abs() < 1e-12, "{rate}");
    assert!((eta - (0.1 + 9.9 / 2.0)).abs() < 1e-12, "{eta}");
    for (rate, eta) in curve("power_thick") {
        let s = rate / sq2;
        assert!((eta / s.sqrt() - 1.0).abs() < 1e-12, "γ̇ {rate}: {eta}");
    }
    // A model with a history (XPP) has no single curve and is named as skipped.
    let xpp = treacle::scene::load_scene(&scene("cube_impact_4.ron")).unwrap();
    let c = viscosity_curves(&xpp, 0.1, 10.0, 3);
    assert!(!c.skipped.is_empty(), "{c:?}");

    let dir = scratch("viscosity_chart");
    let png = dir.join("chart.png");
    let o = treacle(&[
        "viscosity",
        "scenes/li_armadillos.ron",
        "--out",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    assert!(
        stdout(&o).contains("herschel_bulkley, "),
        "{}",
        describe(&o)
    );
    let decoder = png::Decoder::new(std::io::BufReader::new(fs::File::open(&png).unwrap()));
    let info = decoder.read_info().unwrap();
    assert_eq!((info.info().width, info.info().height), (1000, 700));
    // A rate range that is not 0 < min < max is a usage error naming the flags.
    let o = treacle(&[
        "viscosity",
        "scenes/li_armadillos.ron",
        "--out",
        png.to_str().unwrap(),
        "--min-rate",
        "0",
    ]);
    assert_eq!(o.status.code(), Some(64), "{}", describe(&o));
    assert!(stderr(&o).contains("--min-rate"), "{}", describe(&o));
}

/// `treacle plot` draws a column of several runs' metrics.csv, one coloured line per run, and
/// names the file, line and column of bad input.
#[test]
fn plot_draws_metrics_columns_of_runs() {
    let dir = scratch("plot_metrics");
    let write = |name: &str, text: &str| {
        let d = dir.join(name);
        fs::create_dir_all(&d).unwrap();
        fs::write(d.join("metrics.csv"), text).unwrap();
        d
    };
    let rows = |f: fn(f64) -> f64| {
        let mut s = String::from("frame,time,volume\n");
        for k in 0..=10 {
            let t = 0.05 * k as f64;
            s += &format!("{k},{t},{}\n", f(t));
        }
        s
    };
    let a = write("c0.1", &rows(|t| 1.0 - 0.4 * t));
    let b = write("c10", &rows(|_| 1.0));
    let png = dir.join("volume.png");
    let arg = |p: &std::path::Path| p.to_str().unwrap().to_owned();
    let o = treacle(&[
        "plot",
        &arg(&a),
        &arg(&b),
        "--column",
        "volume",
        "--out",
        &arg(&png),
    ]);
    assert!(o.status.success(), "{}", describe(&o));
    // Both lines are drawn in the first two palette colours (blue, vermilion).
    let decoder = png::Decoder::new(std::io::BufReader::new(fs::File::open(&png).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let px = &buf[..info.buffer_size()];
    let count = |rgb: [u8; 3]| px.chunks(3).filter(|p| *p == rgb).count();
    let (blue, vermilion) = (count([0, 114, 178]), count([213, 94, 0]));
    // Each line spans most of the 700-pixel-wide panel, 2 pixels thick.
    assert!(blue > 500 && vermilion > 500, "{blue} {vermilion}");

    // A column the file does not have: exit 1, naming the file, the column and what it has.
    let o = treacle(&["plot", &arg(&a), "-c", "mass", "--out", &arg(&png)]);
    assert_eq!(o.status.code(), Some(1), "{}", describe(&o));
    let e = stderr(&o);
    assert!(
        e.contains("metrics.csv") && e.contains("\"mass\"") && e.contains("frame, time, volume"),
        "{e}"
    );
    // A value that is not a number: the line and the column.
    let bad = write("bad", "frame,time,volume\n0,0,1\n1,0.05,abc\n");
    let o = treacle(&["plot", &arg(&bad), "-c", "volume", "--out", &arg(&png)]);
    assert_eq!(o.status.code(), Some(1), "{}", describe(&o));
    let e = stderr(&o);
    assert!(e.contains("line 3") && e.contains("column volume"), "{e}");
    // One label per run, or a usage error.
    let o = treacle(&[
        "plot",
        &arg(&a),
        &arg(&b),
        "-c",
        "volume",
        "--labels",
        "one",
        "--out",
        &arg(&png),
    ]);
    assert_eq!(o.status.code(), Some(64), "{}", describe(&o));
}

/// Started by an MPI launcher as one of several processes (the launchers' world-size variable
/// set, as `mpirun -n 2` sets it), `treacle run` refuses before loading anything, with exit
/// code 64, the variable and what to do; it writes no output. As the only process of a launch
/// (size 1) it runs.
#[test]
#[cfg(not(feature = "mpi"))]
fn run_under_an_mpi_launcher_with_several_processes_is_refused() {
    let dir = scratch("mpi_launch");
    for var in ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "MV2_COMM_WORLD_SIZE"] {
        let out = dir.join(var);
        let o = Command::new(BIN)
            .args(["run", "scenes/droplet.ron", "--frames", "1", "--out"])
            .arg(&out)
            .env(var, "2")
            .current_dir(crate_dir())
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(64), "{var}: {}", describe(&o));
        let err = stderr(&o);
        assert!(err.contains("one of 2 processes"), "{err}");
        assert!(err.contains(&format!("{var}=2")), "{err}");
        assert!(err.contains("--threads"), "{err}");
        assert!(err.contains("--features mpi"), "{err}");
        assert!(!out.exists(), "{var}: output written");
    }
    let out = dir.join("size_one");
    let o = Command::new(BIN)
        .args(["run", "scenes/droplet.ron", "--frames", "1", "--out"])
        .arg(&out)
        .env("OMPI_COMM_WORLD_SIZE", "1")
        .current_dir(crate_dir())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", describe(&o));
    let _ = fs::remove_dir_all(&dir);
}
