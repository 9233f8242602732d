//! `treacle report accuracy|stability`: the shipped quick subsets run and write CSV, markdown
//! and PNG; a rerun resumes (skips every run, same results); the order fit on synthetic
//! ladders; a blow-up is reported as stopped with a diagnostic; bad SPECs are located errors;
//! no written file holds a non-finite number.
use crate::common::scratch;
use std::path::{Path, PathBuf};

use treacle::report::accuracy::{AccuracyReport, Metric};
use treacle::report::fit::{LadderPoint, Reach, fit_order, time_to_reach};
use treacle::report::stability::Outcome;
use treacle::report::{ReportOptions, run_accuracy, run_stability};

fn manifest(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn quick(out: &Path) -> ReportOptions {
    ReportOptions {
        quick: true,
        ..ReportOptions::new(out)
    }
}

/// Every `.csv`, `.md` and `.ron` file under `dir` (recursively) has no NaN/inf number field,
/// and every `.ply` reads back (the reader rejects non-finite values).
fn assert_no_non_finite(dir: &Path) -> usize {
    let mut n = 0;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
                continue;
            }
            match p.extension().and_then(|e| e.to_str()) {
                Some("csv" | "md" | "ron") => {
                    let text = std::fs::read_to_string(&p).unwrap();
                    let bad = treacle::report::store::non_finite_fields(&text);
                    assert!(
                        bad.is_empty(),
                        "{}: non-finite fields at {bad:?}",
                        p.display()
                    );
                    n += 1;
                }
                Some("ply") => {
                    treacle::output::read_frame(&p)
                        .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
                    n += 1;
                }
                _ => {}
            }
        }
    }
    n
}

fn assert_png(path: &Path) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert!(
        bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
        "{} is not a PNG",
        path.display()
    );
    assert!(
        bytes.len() > 10_000,
        "{} is suspiciously small",
        path.display()
    );
}

fn ladder_error(r: &AccuracyReport, case: &str, integ: &str, dt: f64) -> f64 {
    r.runs
        .iter()
        .find(|x| x.case == case && x.integrator == integ && !x.reference && x.dt == dt)
        .and_then(|x| x.vs_exact.stress)
        .unwrap_or_else(|| panic!("no stress error for {case}/{integ}/{dt}"))
}

/// The shipped quick subsets run end to end and write CSV (one row per run), markdown and the
/// PNGs; a second run over the same folder simulates nothing and rewrites identical CSVs.
#[test]
fn quick_reports_run_and_resume() {
    let out = scratch("quick-accuracy");
    let spec = manifest("scenes/reports/accuracy.ron");
    let r = run_accuracy(&spec, &quick(&out)).unwrap();
    assert!(r.simulated > 0 && r.resumed == 0);
    let csv = std::fs::read_to_string(out.join("accuracy.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + r.runs.len(), "one CSV row per run");
    assert!(r.runs.iter().all(|x| x.status == "ok"), "{:#?}", r.runs);
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    for needle in [
        "pure FLIP",
        "reference Δt",
        "Observed order",
        "Work-precision",
    ] {
        assert!(md.contains(needle), "summary lacks `{needle}`");
    }
    for case in [
        "shear_layer",
        "oldroyd_b_particle",
        "oldroyd_b_shear_cell",
        "fourier_slab",
    ] {
        assert_png(&out.join(format!("{case}_error_vs_dt.png")));
        assert_png(&out.join(format!("{case}_work_precision.png")));
    }

    // S1 reproduces ALGORITHM §9 (GS4 (0.5, 0), explicit relaxation): 1.522e-3, 3.738e-4,
    // 9.256e-5, 2.303e-5 for Δt = 0.1 … 0.0125; the quoted digits ± half a unit of the last.
    for (dt, quoted) in [
        (0.1, 1.522e-3),
        (0.05, 3.738e-4),
        (0.025, 9.256e-5),
        (0.0125, 2.303e-5),
    ] {
        let e = ladder_error(&r, "oldroyd_b_particle", "GS4 (0.5, 0)", dt);
        let tol = 0.5e-3 * 10f64.powf(f64::log10(quoted).floor());
        assert!(
            (e - quoted).abs() <= tol,
            "S1 Δt = {dt}: {e:.4e} vs ALGORITHM.md {quoted:e}"
        );
        // The MPM shear cell integrates the same ODE on every particle: its error equals the
        // particle-level one up to round-off. The f32 positions move by up to one ulp
        // (6e-8 m at x ≈ 0.5 m) per step, which breaks the lattice regularity that makes the
        // transfer of the linear velocity exact by ~1e-6 Δx per step; the stress (≈ 1 Pa)
        // drifts by ≤ 1.4e-7 Pa per step (measured on a 640-step run: 8.7e-5 Pa), so the
        // bound is 2e-7 Pa per step.
        let cell = r.runs.iter().find(|x| {
            x.case == "oldroyd_b_shear_cell"
                && x.integrator == "GS4 (0.5, 0)"
                && !x.reference
                && x.dt == dt
        });
        if let Some(cell) = cell {
            let c = cell.vs_exact.stress.unwrap();
            let tol = 2e-7 * cell.steps as f64;
            assert!(
                (c - e).abs() < tol,
                "cell {c:.6e} vs particle {e:.6e} at Δt = {dt}"
            );
        }
    }
    // Exactly second order on the particle-level ladder (the S1 errors halve twice per Δt
    // halving to 1 %: slope 2 ± 0.05).
    let fit = r
        .order("oldroyd_b_particle", "GS4 (0.5, 0)", Metric::Stress)
        .unwrap();
    assert!((fit.order - 2.0).abs() < 0.05 && fit.points == 4, "{fit:?}");
    let files = assert_no_non_finite(&out);
    assert!(files > r.runs.len(), "checked {files} files");

    // Resume: nothing simulated, identical CSV.
    let again = run_accuracy(&spec, &quick(&out)).unwrap();
    assert_eq!(again.simulated, 0);
    assert_eq!(again.resumed, r.runs.len());
    assert_eq!(
        std::fs::read_to_string(out.join("accuracy.csv")).unwrap(),
        csv
    );

    // Stability quick subset.
    let sout = scratch("quick-stability");
    let sspec = manifest("scenes/reports/stability.ron");
    let s = run_stability(&sspec, &quick(&sout)).unwrap();
    assert!(s.simulated > 0);
    let scsv = std::fs::read_to_string(sout.join("stability.csv")).unwrap();
    assert_eq!(scsv.lines().count(), 1 + s.cases.len());
    assert_png(&sout.join("stability_map.png"));
    let smd = std::fs::read_to_string(sout.join("summary.md")).unwrap();
    assert!(smd.contains("instability began"), "{smd}");
    assert!(
        s.cases.iter().all(|c| c.outcome != Outcome::Panic),
        "{:#?}",
        s.cases
    );
    assert!(
        s.cases.iter().all(|c| c.nan_check.starts_with("ok")),
        "{:#?}",
        s.cases
    );
    // Every case below the predicted limit finishes.
    for c in s.cases.iter().filter(|c| c.ratio.is_some_and(|r| r < 1.0)) {
        assert_eq!(c.outcome, Outcome::Finished, "{c:#?}");
    }
    assert_no_non_finite(&sout);
    let s2 = run_stability(&sspec, &quick(&sout)).unwrap();
    assert_eq!((s2.simulated, s2.resumed), (0, s.cases.len()));
    assert_eq!(
        std::fs::read_to_string(sout.join("stability.csv")).unwrap(),
        scsv
    );
    std::fs::remove_dir_all(&out).unwrap();
    std::fs::remove_dir_all(&sout).unwrap();
}

/// The order fit: exact on a pure power law; drops the pre-asymptotic coarse end and the
/// round-off floor at the fine end; `time_to_reach` interpolates in log-log.
#[test]
fn fitted_order_on_synthetic_ladders() {
    let ladder = |f: &dyn Fn(f64) -> f64| -> Vec<LadderPoint> {
        (0..6)
            .map(|k| {
                let dt = 0.1 / 2f64.powi(k);
                LadderPoint { dt, error: f(dt) }
            })
            .collect()
    };
    for p in [1.0, 2.0, 3.0] {
        let fit = fit_order(&ladder(&|dt: f64| 3.0 * dt.powf(p))).unwrap();
        assert!((fit.order - p).abs() < 1e-12, "{fit:?}");
        assert_eq!((fit.points, fit.floor_points, fit.coarse_points), (6, 0, 0));
    }
    // A sixth-order term equal to the second-order one at the largest Δt and 6 % of it at
    // the next: the largest Δt (local slope 2.9) is left out, the rest fits 2 to within the
    // remaining contamination (< 0.4 % at Δt = 0.025, slope error < 0.05).
    let fit = fit_order(&ladder(&|dt: f64| dt * dt + 1e4 * dt.powi(6))).unwrap();
    assert_eq!(fit.coarse_points, 1, "{fit:?}");
    assert!((fit.order - 2.0).abs() < 0.05, "{fit:?}");
    // A round-off floor of 1e-6 under e = 0.01 dt²: the smallest Δt (local slope 0.34) is the
    // floor, the next ones bend away from 2; the window is the three largest Δt, whose slope
    // is 2 to within the floor's contamination there (≤ 14 % of the error: slope within 0.1).
    let fit = fit_order(&ladder(&|dt: f64| 1e-2 * dt * dt + 1e-6)).unwrap();
    assert_eq!((fit.points, fit.floor_points), (3, 3), "{fit:?}");
    assert!((fit.order - 2.0).abs() < 0.1, "{fit:?}");
    // Fewer than two usable points: no order.
    assert!(
        fit_order(&[LadderPoint {
            dt: 0.1,
            error: 1.0
        }])
        .is_none()
    );
    assert!(
        fit_order(&[
            LadderPoint {
                dt: 0.1,
                error: f64::NAN
            },
            LadderPoint {
                dt: 0.05,
                error: 1.0
            }
        ])
        .is_none()
    );
    match time_to_reach(&[(1.0, 1e-2), (2.0, 1e-3)], 1e-2 / 10f64.sqrt()) {
        Reach::Interpolated(w) => assert!((w - 2f64.sqrt()).abs() < 1e-12, "{w}"),
        r => panic!("{r:?}"),
    }
}

fn write_spec(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("spec.ron");
    std::fs::write(&p, text).unwrap();
    p
}

/// A case far above its stability limit is reported as stopped with the monitor's diagnostic
/// (step, particle, quantity, suggested Δt), not as a panic, and its written files are finite.
#[test]
fn blow_up_is_reported_as_stopped() {
    let dir = scratch("blowup");
    let scene = manifest("scenes/reports/stability_droplet.ron");
    let spec = write_spec(
        &dir,
        &format!(
            r#"StabilitySpec(
    families: [(
        name: "too_large",
        scenes: ["{}"],
        time_steps: [Limit(0.5), Limit(16.0)],
    )],
)"#,
            scene.display()
        ),
    );
    let out = dir.join("out");
    let r = run_stability(&spec, &ReportOptions::new(&out)).unwrap();
    assert_eq!(r.cases.len(), 2);
    let ok = &r.cases[0];
    assert_eq!(ok.outcome, Outcome::Finished, "{ok:#?}");
    let bad = &r.cases[1];
    assert_eq!(bad.outcome, Outcome::Stopped, "{bad:#?}");
    for needle in ["numerical failure at step", "particle", "Suggested fix"] {
        assert!(
            bad.diagnostic.contains(needle),
            "diagnostic lacks `{needle}`: {}",
            bad.diagnostic
        );
    }
    assert!(bad.steps < 100 && bad.ratio == Some(16.0));
    assert!(bad.nan_check.starts_with("ok"), "{}", bad.nan_check);
    let md = std::fs::read_to_string(out.join("summary.md")).unwrap();
    assert!(md.contains("between 0.5× and 16×"), "{md}");
    assert_no_non_finite(&out);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Bad SPECs are rejected before anything runs, naming the file, line and field.
#[test]
fn bad_specs_name_file_line_and_field() {
    let dir = scratch("bad-spec");
    let spec = write_spec(
        &dir,
        r#"AccuracySpec(
    integrators: [(name: "a")],
    cases: [(
        name: "s1",
        source: OldroydBParticle((shear_rate: 1.0, relaxation_time: 1.0, polymer_viscosity: 1.0, implicit_relaxation: false)),
        end_time: 1.0,
        dt: [0.3],
        reference_dt: 0.01,
        metric: Stress,
        integrators: ["b"],
    )],
)"#,
    );
    let e = run_accuracy(&spec, &ReportOptions::new(dir.join("out")))
        .unwrap_err()
        .to_string();
    assert!(e.contains("spec.ron:7:"), "{e}");
    assert!(
        e.contains("field `cases[0].dt`") && e.contains("does not divide"),
        "{e}"
    );
    assert!(
        e.contains("field `cases[0].integrators`") && e.contains("unknown integrator `b`"),
        "{e}"
    );
    assert!(
        !dir.join("out").exists(),
        "nothing may be written for a bad SPEC"
    );

    let spec = write_spec(
        &dir,
        r#"StabilitySpec(families: [(name: "f", scenes: ["missing.ron"], time_steps: [Limit(-1.0)])])"#,
    );
    let e = run_stability(&spec, &ReportOptions::new(dir.join("out")))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("field `families[0].scenes`") && e.contains("missing.ron"),
        "{e}"
    );
    assert!(
        e.contains("field `families[0].time_steps`") && e.contains("must be > 0"),
        "{e}"
    );
    let spec = write_spec(&dir, "StabilitySpec(families: [(name: \"f\", scenez: [])])");
    let e = run_stability(&spec, &ReportOptions::new(dir.join("out")))
        .unwrap_err()
        .to_string();
    assert!(e.contains("spec.ron:1:") && e.contains("scenez"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `SolidShearModulus` sets G_s of every phase change on the loaded scene, and the predicted
/// limit of a fully solid block (ALGORITHM §7.2, "neo-Hookean solid": c_s² = (K + 4G_s/3)/ρ
/// in the wave limit) follows it: min{C_adv Δx/|v|max, Ω_crit Δx/(2c_s)} with
/// c_s² = c₀² + 4G_s/(3ρ₀) at rest density and F = I (the solid phase scales the local
/// viscosity by the fluid fraction 1 − I_s = 0). Without the solid modulus the limit would be
/// Ω_crit Δx/(2c₀), 11× larger at G_s = 1e7 Pa.
#[test]
fn solid_shear_modulus_knob_enters_the_predicted_limit() {
    use treacle::report::stability::Knob;
    use treacle::schedule::{Gs4Constants, SimulationClock};
    let path = manifest("scenes/reports/stability_solid_block.ron");
    let base = treacle::scene::load_scene(&path).unwrap();
    assert!(Knob::SolidShearModulus.check(&base).is_none());
    let droplet =
        treacle::scene::load_scene(&manifest("scenes/reports/stability_droplet.ron")).unwrap();
    assert!(
        Knob::SolidShearModulus.check(&droplet).is_some(),
        "a scene without phase change must be rejected"
    );
    let mut limits = Vec::new();
    for g in [1e4, 1e7] {
        let mut scene = base.clone();
        Knob::SolidShearModulus.apply(&mut scene, g);
        assert!(scene.phase_change.iter().all(|(_, p)| p.shear_modulus == g));
        let mut app = treacle::runner::scene_app(&scene);
        let world = app.world_mut();
        treacle::schedule::start(world);
        let limit = world.resource::<SimulationClock>().predicted_limit;
        let omega = world.resource::<Gs4Constants>().omega_crit;
        let mat = &scene.materials.list[0];
        let (rho, c0, dx) = (
            mat.density as f64,
            mat.sound_speed as f64,
            scene.config.dx as f64,
        );
        let cs = (c0 * c0 + 4.0 / 3.0 * g / rho).sqrt();
        let wave = omega * dx / (2.0 * cs);
        let speed = scene
            .particles
            .iter()
            .map(|b| b.velocity.length() as f64)
            .fold(0.0, f64::max);
        let adv = scene.config.time_step.advection * dx / speed;
        let expected = wave.min(adv);
        println!(
            "G_s = {g:e}: predicted {limit:.6e}, expected {expected:.6e} (wave {wave:.4e}, advection {adv:.4e})"
        );
        // f32 state (c², G/J): relative 1e-4.
        assert!(
            ((limit - expected) / expected).abs() < 1e-4,
            "G_s = {g:e}: predicted limit {limit:e}, expected {expected:e}"
        );
        limits.push(limit);
    }
    assert!(limits[1] < 0.2 * limits[0], "{limits:?}");
}

/// The Fourier slab of the accuracy catalogue, short: the temperature norm is the mass-weighted
/// RMS over the particles (recomputed here from the stored reference state against the closed
/// form); the particles stay at rest; the amplitude of the cosine mode decays between the
/// exact e^{−kπ²t/L²} and e^{−kπ²t/(L + 3Δx)²}: the thermal lattice's insulated faces lie
/// at most 1.5Δx beyond the material (the quadratic B-spline support of the outer particles
/// reaches one node beyond them, and the 7-point Laplacian puts the zero-flux face half a
/// cell beyond the last Interior node), 2 % allowed for the FLIP transfer.
#[test]
fn fourier_slab_temperature_error_against_the_analytic_decay() {
    use treacle::report::cases::{Exact, ParticleState, TemperatureField, compare};
    let scene_path = manifest("scenes/reports/fourier_slab.ron");
    // The initial field as set on the particles equals the closed form at t = 0.
    let scene = treacle::scene::load_scene(&scene_path).unwrap();
    let field = TemperatureField::Cosine {
        mean: 0.0,
        amplitude: 1.0,
        length: 1.0,
    };
    let k = 0.1;
    let exact = Exact::HeatDecay {
        mean: 0.0,
        amplitude: 1.0,
        length: 1.0,
        x_min: 0.0,
        diffusivity: k,
    };
    let mut app = treacle::runner::scene_app(&scene);
    let n = field.apply(app.world_mut(), scene.config.domain_min);
    assert_eq!(n, scene.particle_count());
    let initial = ParticleState::capture(app.world_mut());
    let e0 = compare(&initial, &exact.state(&initial, 0.0), [None; 3], true);
    assert!(e0.temperature.unwrap() < 1e-6, "{e0:?}");
    // The RMS of the field itself is A/√2 (32 layers of particles at the midpoints).
    let rest = ParticleState {
        temperature: Some(vec![0.0; initial.len()]),
        ..initial.clone()
    };
    let rms = compare(&initial, &rest, [None; 3], true)
        .temperature
        .unwrap();
    assert!((rms - 0.5f64.sqrt()).abs() < 1e-6, "{rms}");

    let dir = scratch("fourier");
    let end = 0.25;
    let spec = write_spec(
        &dir,
        &format!(
            r#"AccuracySpec(
    integrators: [(name: "GS4", config: (scheme: Gs4Explicit, rho_inf: 0.5, rho_s: 0.0, flip_update: ParticleGs4))],
    cases: [(
        name: "fourier",
        source: Scene(
            path: "{}",
            initial_temperature: Cosine(mean: 0.0, amplitude: 1.0, length: 1.0),
            analytic: HeatDecay,
        ),
        end_time: {end},
        dt: [0.05],
        reference_dt: 0.0125,
        metric: Temperature,
    )],
)"#,
            scene_path.display()
        ),
    );
    let out = dir.join("out");
    let r = run_accuracy(&spec, &ReportOptions::new(&out)).unwrap();
    assert!(r.runs.iter().all(|x| x.status == "ok"), "{:#?}", r.runs);
    let reference = r.runs.iter().find(|x| x.reference).unwrap();
    let ladder = r.runs.iter().find(|x| !x.reference).unwrap();
    assert!(ladder.vs_reference.temperature.is_some_and(|e| e > 0.0));
    for run in [reference, ladder] {
        assert!(run.vs_exact.displacement.unwrap() < 1e-6, "{run:#?}");
        assert!(run.vs_exact.velocity.unwrap() < 1e-6, "{run:#?}");
    }
    // Recompute the reference's error from its stored final state.
    let ply = std::fs::read_dir(out.join("runs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "ply"))
        .unwrap();
    let frame = treacle::output::read_ply(&ply).unwrap();
    let t = frame.field("temperature").expect("temperature stored");
    let mass = frame.field("mass").unwrap();
    let (mut m, mut se, mut proj) = (0.0f64, 0.0f64, 0.0f64);
    for (i, x) in frame.positions.iter().enumerate() {
        let (mp, tp, xp) = (mass[i] as f64, t[i] as f64, x[0] as f64);
        let te = Exact::heat_decay_temperature(0.0, 1.0, 1.0, k, xp, end);
        m += mp;
        se += mp * (tp - te).powi(2);
        proj += mp * tp * (std::f64::consts::PI * xp).cos();
    }
    let rms = (se / m).sqrt();
    let reported = reference.vs_exact.temperature.unwrap();
    assert!(
        (rms - reported).abs() <= 1e-5 * reported,
        "recomputed {rms:e}, reported {reported:e}"
    );
    let amplitude = 2.0 * proj / m;
    let rate = k * std::f64::consts::PI.powi(2);
    let dx = scene.config.dx as f64;
    let (lo, hi) = (
        (-rate * end).exp(),
        (-rate * end / (1.0 + 3.0 * dx).powi(2)).exp(),
    );
    println!("amplitude {amplitude:.5}: exact {lo:.5}, L + 3Δx {hi:.5}; error {reported:.3e}");
    assert!(
        amplitude > 0.98 * lo && amplitude < 1.02 * hi,
        "amplitude {amplitude} outside [{lo}, {hi}]"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A growing scene (the printer's nozzle emitter): the mass drift is judged against the
/// initial plus the emitted mass (particles × ρ₀h³, within half a layer of ρ₀Q̇ × extruding
/// time), so emitter growth is not a drift; the energy test counts the emitted particles'
/// kinetic energy as energy brought in; the speed bound includes the emitter's speeds.
#[test]
fn emitter_growth_is_not_a_mass_drift() {
    let dir = scratch("emitter");
    let scene = manifest("scenes/printing.ron");
    let end = 0.03;
    let spec = write_spec(
        &dir,
        &format!(
            r#"StabilitySpec(families: [(name: "printer", scenes: ["{}"], end_time: {end})])"#,
            scene.display()
        ),
    );
    let out = dir.join("out");
    let r = run_stability(&spec, &ReportOptions::new(&out)).unwrap();
    let c = &r.cases[0];
    assert_eq!(c.outcome, Outcome::Finished, "{c:#?}");
    let s = treacle::scene::load_scene(&scene).unwrap();
    let e = &s.emitters[0];
    let rho0 = s.materials.list[e.material.0 as usize].density as f64;
    let h = e.spacing as f64;
    let layer = e.lattice().len() as f64 * rho0 * h * h * h;
    let expected = e.expected_mass(rho0, end);
    let emitted = c
        .emitted_mass
        .expect("emitted mass of a scene with an emitter");
    assert!(expected > 10.0 * layer, "too short to test: {expected:e}");
    assert!(
        (emitted - expected).abs() <= 0.5 * layer + 1e-6 * expected,
        "emitted {emitted:e} vs ρ₀Q̇t {expected:e} (layer {layer:e})"
    );
    let drift = c.mass_drift.unwrap();
    assert!(drift.abs() < 1e-6, "mass drift {drift:e}");
    let v_e = e.extrusion_speed(e.lattice().len());
    assert!(c.speed_bound.unwrap() >= 2.0 * v_e, "{c:#?}");
    assert!(
        c.energy_growth.is_some_and(|g| g.is_finite() && g < 0.05),
        "{c:#?}"
    );
    assert!(
        c.volume_drift.is_some_and(|v| v.is_finite() && v < 0.1),
        "{c:#?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
