//! `treacle report accuracy|stability`: the shipped quick subsets run and write CSV, markdown
//! and PNG; a rerun resumes (skips every run, same results); the order fit on synthetic
//! ladders; a blow-up is reported as stopped with a diagnostic; bad SPECs are located errors;
//! no written file holds a non-finite number.
use std::path::{Path, PathBuf};

use treacle::report::accuracy::{AccuracyReport, Metric};
use treacle::report::fit::{LadderPoint, Reach, fit_order, time_to_reach};
use treacle::report::stability::Outcome;
use treacle::report::{ReportOptions, run_accuracy, run_stability};

fn manifest(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("treacle-report-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
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
    for case in ["shear_layer", "oldroyd_b_particle", "oldroyd_b_shear_cell"] {
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
