//! Dam break against Martin & Moyce (1952): the surge front of a collapsing square column.
//!
//! A water column of width a and height 2a (n² = 2) collapses along a horizontal floor. The
//! experiment reports the front position Z = x_front/a against T = t·√(2g/a). The acceptance
//! criterion of the dam-break issue: for T ≤ 2.5 the simulated front is within 10 % of the
//! experimental data.
//!
//! The test runs the shipped `scenes/dam_break.ron` through the library API
//! ([`load_scene`] + [`scene_app`] + `App::update`, one update per 1/100 s frame), measures
//! the front after every frame, interpolates it linearly in time to the experimental T values
//! and compares point by point.
//!
//! **Front.** Z = (x_f + h/2)/a, where x_f is the largest x among particles that have another
//! particle within one cell Δx, and h = Δx/ppc is the particle spacing:
//!
//! - the plain maximum would let a single particle thrown ahead of the surge (spray; with
//!   FLIP 0.95 individual particles do separate from the thin tip) define the front. A particle
//!   with a neighbour closer than Δx is part of a resolved (at least two-particle) film; the
//!   experimental front is the leading edge of the visible liquid, not of droplets;
//! - a high percentile of x would instead depend on the number of particles behind the tip
//!   (i.e. on resolution and column size), biasing the front backwards by an amount that
//!   changes as the tongue thins;
//! - each particle stands for a cube of side h around its centre, so the liquid extends h/2
//!   beyond the outermost particle centre: with this offset the initial front is exactly
//!   x = a (Z = 1, the experiment's T = 0 point) instead of a − h/2.
//!
//! **Time sampling.** One sample per frame, ΔT = 0.01 s·√(2g/a) = 0.14. Between samples the
//! front is interpolated linearly; the simulated front's curvature is |d²Z/dT²| ≲ 0.5 for
//! T ≤ 2.5, so the interpolation error is ≤ |Z''|ΔT²/8 ≈ 1.2·10⁻³ (≈ 0.1 % of Z), negligible
//! against the 10 % criterion.
//!
//! **Experimental data.** The oracle (`/work/shared/oracles/martin_moyce_1952.csv`, copied
//! below) lists four sources: O and L are two transcriptions of Martin & Moyce's Tables 2 and 6
//! (a = 2.25 in), P225 and P1125 are points digitised from their Fig. 3 for a = 2.25 in and
//! 1.125 in. The sources do not share T values (so there is no common grid on which to average
//! them) and agree with each other within ≈ 2 % where they overlap, i.e. they are one
//! experiment, not independent estimates whose mean would be more accurate. Every point with
//! T ≤ 2.5 is therefore compared on its own, each within 10 %: the strictest reading of the
//! criterion. The table also prints the error against the mean of the sources' own
//! piecewise-linear curves at each T (those that bracket it), for information.
use std::path::PathBuf;
use std::time::Instant;

use crate::common::front_x;
use bevy_ecs::prelude::*;
use treacle::components::{Particle, Position};
use treacle::config::{MpmConfig, PressureSolve, ProjectionConfig, Scheme, VelocityGradientSource};
use treacle::failure::SimulationStatus;
use treacle::math::Vec3;
use treacle::runner::scene_app;
use treacle::scene::load_scene;
use treacle::schedule::SimulationClock;

/// Martin & Moyce (1952), square column n² = 2: source, T = t·√(2g/a), Z = x_front/a.
/// Copied from `/work/shared/oracles/martin_moyce_1952.csv` (rows with T ≤ 2.6; the test
/// uses T ≤ 2.5). Sources: O = Ocellaris `scripts/plot_dam_break.py` ("Table 2 and 6",
/// a = 2.25 in); L = Lethe `examples/multiphysics/dam-break/dam-break-2d.py`; P225 / P1125 =
/// PySPH `pysph/examples/db_exp_data.py` (digitised Fig. 3, a = 2.25 in / 1.125 in).
const MARTIN_MOYCE: &str = "\
O,0.410,1.110
O,0.840,1.220
O,1.190,1.440
O,1.430,1.670
O,1.630,1.890
O,1.830,2.110
O,1.980,2.330
O,2.200,2.560
O,2.320,2.780
O,2.510,3.000
L,0.000,1.000
L,0.410,1.110
L,0.840,1.230
L,1.190,1.440
L,1.430,1.670
L,1.630,1.890
L,1.820,2.110
L,1.970,2.330
L,2.200,2.560
L,2.320,2.780
L,2.500,3.000
P225,0.832,1.217
P225,1.219,1.474
P225,1.997,2.292
P225,2.547,2.995
P1125,0.849,1.245
P1125,1.212,1.443
P1125,1.602,1.884
P1125,2.283,2.689
";

/// Largest T compared (the acceptance range).
const T_MAX: f64 = 2.5;
/// Acceptance: relative error of Z at every experimental point.
const TOLERANCE: f64 = 0.10;

struct Point {
    source: &'static str,
    t: f64,
    z: f64,
}

fn all_points() -> Vec<Point> {
    MARTIN_MOYCE
        .lines()
        .map(|l| {
            let mut c = l.split(',');
            let source = c.next().unwrap();
            let t = c.next().unwrap().parse().unwrap();
            let z = c.next().unwrap().parse().unwrap();
            Point { source, t, z }
        })
        .collect()
}

fn positions(world: &mut World) -> Vec<Vec3> {
    let mut q = world.query_filtered::<&Position, With<Particle>>();
    q.iter(world).map(|x| x.0).collect()
}

/// Linear interpolation of the sampled series (t ascending) at `t`.
fn interpolate(series: &[(f64, f64)], t: f64) -> f64 {
    let k = series.partition_point(|s| s.0 < t);
    if k == 0 {
        return series[0].1;
    }
    assert!(k < series.len(), "T = {t} beyond the simulated range");
    let (t0, z0) = series[k - 1];
    let (t1, z1) = series[k];
    z0 + (z1 - z0) * (t - t0) / (t1 - t0)
}

/// One comparison row: source, T, Z_sim, Z_exp, relative error.
type Row = (&'static str, f64, f64, f64, f64);

/// Runs `scenes/dam_break.ron` (a = 0.1 m, Δx = a/20, slip walls, c₀ = 20 m/s, FLIP 0.95) as
/// shipped and compares the surge front with every Martin & Moyce point with T ≤ 2.5.
/// Returns the rows and the simulated series (T, Z).
/// `flip`: replaces the scene's FLIP fraction.
fn dam_break_comparison(flip: Option<f32>) -> (Vec<Row>, Vec<(f64, f64)>) {
    dam_break_comparison_with(|config| {
        if let Some(flip) = flip {
            config.integrator.flip = flip;
        }
    })
}

/// [`dam_break_comparison`] with the scene's configuration changed by `configure`.
fn dam_break_comparison_with(
    configure: impl FnOnce(&mut MpmConfig),
) -> (Vec<Row>, Vec<(f64, f64)>) {
    let wall = Instant::now();
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/dam_break.ron");
    let mut scene = load_scene(&path).unwrap_or_else(|e| panic!("{e}"));
    configure(&mut scene.config);

    // The geometry the comparison relies on: one body, a box [0, a] × [0, 2a] against the
    // x_min wall, gravity along −y.
    assert_eq!(scene.particles.len(), 1);
    let body = &scene.particles[0];
    let x0 = positions_of(&body.positions);
    let h = body.particle_volume.cbrt();
    let a = (x0.max_x + h / 2.0) as f64;
    let height = (x0.max_y + h / 2.0) as f64;
    assert!((a - 0.1).abs() < 1e-6, "column width {a}");
    assert!(
        (height - 2.0 * a).abs() < 1e-6,
        "column height {height} ≠ 2a"
    );
    assert!(x0.min_x < h && x0.min_y < h, "column in the corner");
    let g = -scene.config.gravity.y as f64;
    assert_eq!(scene.config.gravity.x, 0.0);
    let dx = scene.config.dx;
    let t_scale = (2.0 * g / a).sqrt(); // T = t·t_scale

    let all = all_points();
    let experiment: Vec<&Point> = all.iter().filter(|p| p.t <= T_MAX).collect();
    let t_end = experiment.iter().map(|p| p.t).fold(0.0, f64::max) / t_scale;
    let frames = (t_end / scene.config.frame_dt).ceil() as u64;

    let mut app = scene_app(&scene);
    let mut series = Vec::with_capacity(frames as usize + 1);
    let front = |world: &mut World| {
        let xs = positions(world);
        assert!(
            xs.iter().all(|x| x.is_finite()),
            "non-finite particle position"
        );
        ((front_x(&xs, dx) + h / 2.0) as f64) / a
    };
    series.push((0.0, front(app.world_mut())));
    for _ in 0..frames {
        app.update();
        if let Some(f) = &app.world().resource::<SimulationStatus>().failure {
            panic!("simulation failed: {f}");
        }
        let t = app.world().resource::<SimulationClock>().time;
        let z = front(app.world_mut());
        series.push((t * t_scale, z));
    }
    let clock = app.world().resource::<SimulationClock>();
    let (steps, t_final) = (clock.steps, clock.time);
    let sim_seconds = wall.elapsed().as_secs_f64();
    assert!(
        (series[0].1 - 1.0).abs() < 1e-6,
        "initial front {}",
        series[0].1
    );

    println!(
        "dam break (Martin & Moyce 1952): a = {a:.4} m, Δx = a/{:.0}, FLIP {}, {} particles, \
         {frames} frames to t = {t_final:.3} s (T = {:.3}), {steps} steps, {sim_seconds:.1} s wall",
        a / dx as f64,
        scene.config.integrator.flip,
        body.positions.len(),
        t_final * t_scale
    );
    println!(
        "{:>6} {:>6} {:>7} {:>7} {:>8}   {:>7} {:>8}",
        "source", "T", "Z_sim", "Z_exp", "rel.err", "Z_mean", "err/mean"
    );
    let mut worst: (f64, &str, f64) = (0.0, "", 0.0);
    let mut rows = Vec::new();
    for p in &experiment {
        let z_sim = interpolate(&series, p.t);
        let err = (z_sim - p.z) / p.z;
        let mean = mean_of_sources(&all, p.t);
        println!(
            "{:>6} {:>6.3} {:>7.3} {:>7.3} {:>+7.1}%   {:>7.3} {:>+7.1}%",
            p.source,
            p.t,
            z_sim,
            p.z,
            100.0 * err,
            mean,
            100.0 * (z_sim - mean) / mean
        );
        if err.abs() > worst.0.abs() {
            worst = (err, p.source, p.t);
        }
        rows.push((p.source, p.t, z_sim, p.z, err));
    }
    println!(
        "worst relative error {:+.1} % ({} at T = {:.3}); total {:.1} s",
        100.0 * worst.0,
        worst.1,
        worst.2,
        wall.elapsed().as_secs_f64()
    );
    (rows, series)
}

/// The rows whose relative error `e` satisfies `bad(e)`, described.
fn rows_where(rows: &[Row], bad: impl Fn(f64) -> bool) -> Vec<String> {
    rows.iter()
        .filter(|r| bad(r.4))
        .map(|r| {
            format!(
                "{} T = {:.3}: Z_sim = {:.3}, Z_exp = {:.3} ({:+.1} %)",
                r.0,
                r.1,
                r.2,
                r.3,
                100.0 * r.4
            )
        })
        .collect()
}

/// The acceptance criterion: Z(T) within 10 % of every Martin & Moyce point with
/// T ≤ 2.5. **Not met** (ignored so CI stays meaningful; run with `--ignored`): the front is
/// up to 15.1 % ahead at T ≈ 1.2 (P1125), while the late surge speed matches. Since the `Slip`
/// walls are mirrors (§2.11, D18; issue 14) the floor is an exact free-slip plane; before, the
/// node row below the floor carried the mean velocity of the particles above it, a numerical
/// friction that held the front back (worst +12.4 %). Refining makes it worse (measured before
/// D18: Δx = a/10: 8.2 %, a/20: 12.4 %, a/40: 15.6 %), so the converged inviscid, free-slip,
/// weakly compressible model runs ahead of the experiment at early times.
///
/// Measured causes (before D18; worst error at T = 1.212 unless stated):
/// - the 5 % PIC share of FLIP 0.95 is a per-step damping, so the shipped result depends on
///   the step count: time-step safety 0.5 → 0.25 → 0.125 → 0.0625 gives +12.4, +8.6, −10.3
///   (at T = 2.5), −18.7 % (at T = 2.5). Pure FLIP is Δt-converged (+17.2 % and +17.0 % at
///   safety 0.5 and 0.25) and converges in Δx *away* from the data: a/10 +13.4, a/20 +17.2,
///   a/40 +20.1 %. FLIP 0.95 at the shipped step therefore understates the model's lead;
/// - not the start-up transient: a hydrostatic initial density (Tait inverted for
///   p = ρ₀g(H − y), mass ρh³) moves the front further ahead (+12.9 %; pure FLIP +17.8 %),
///   because the uniform-density start delays the collapse slightly;
/// - not compressibility: c₀ = 40 m/s with pure FLIP gives +18.4 % (vs +17.2 % at 20 m/s);
/// - not the particle count: 1, 2, 3 particles per cell and axis give +12.9, +12.4, +12.4 %;
/// - the floor condition decides the tip: a no-slip floor (not physical at this resolution,
///   the boundary layer √(νt) ≈ 0.3 mm ≪ Δx) gives −16.5 % (at T = 2.5).
///
/// What remains is physics the model leaves out at the thin leading tongue (floor friction
/// and contact-line resistance, which blunt the nose; surface tension) and the gate removal
/// of the experiment, which the literature cites for simulations leading Martin & Moyce at
/// early T. Passing via numerical damping (coarse grid, PIC, small Δt with PIC) or a fitted
/// floor friction would be tuning to the data.
#[test]
#[ignore = "issue-2 criterion not met: up to 15.1 % ahead of Martin & Moyce at T ≈ 1.2 (see doc comment)"]
fn dam_break_front_within_10_percent_of_martin_moyce() {
    let (rows, _) = dam_break_comparison(None);
    let bad = rows_where(&rows, |e| e.abs() > TOLERANCE);
    assert!(
        bad.is_empty(),
        "front outside {:.0} % of Martin & Moyce at {} of {} points:\n{}",
        100.0 * TOLERANCE,
        bad.len(),
        rows.len(),
        bad.join("\n")
    );
}

/// Regression guard on the dam break (not the acceptance criterion above), three checks that
/// follow from the model, each able to fail:
///
/// - the established surge speed dZ/dT between T = 2.0 and 2.5 is within 10 % of the
///   experiment's (the shallow-water front speed is what a correct pressure/gravity balance
///   sets);
/// - the front never trails the experiment by more than the 10 % of the acceptance criterion:
///   an inviscid liquid on a free-slip floor has none of the experiment's friction, so being
///   slower than it is a defect (spurious wall friction, as before D18, or damping);
/// - the shipped FLIP 0.95 front is nowhere ahead of the pure-FLIP (1.0) front of the same
///   scene by more than one particle spacing h (the front is read off particles, each a cube of
///   side h; plus the interpolation error ≤ 1.2·10⁻³): the 5 % PIC share only removes kinetic
///   energy, so it cannot speed the surge up. This bounds the lead over the experiment by the
///   model's own lead without dissipation in the transfer.
///
/// (Before D18 this guard was "no point more than 15 % off", a margin over the then worst
/// +12.4 %; the exact free-slip floor moved the worst point to +15.1 %, see above.)
#[test]
fn dam_break_surge_speed_and_front_regression() {
    let (rows, series) = dam_break_comparison(None);
    let slope = |t0: f64, t1: f64, z: &dyn Fn(f64) -> f64| (z(t1) - z(t0)) / (t1 - t0);
    let sim = slope(2.0, 2.5, &|t| interpolate(&series, t));
    // Experimental slope from the source that spans [2.0, 2.5] most closely (L: 2.5 and the O
    // points are one experiment): least squares over the points with T in [1.9, 2.55].
    let pts: Vec<(f64, f64)> = all_points()
        .iter()
        .filter(|p| p.t >= 1.9 && p.t <= 2.55)
        .map(|p| (p.t, p.z))
        .collect();
    let n = pts.len() as f64;
    let (mt, mz) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let exp = pts.iter().map(|p| (p.0 - mt) * (p.1 - mz)).sum::<f64>()
        / pts.iter().map(|p| (p.0 - mt).powi(2)).sum::<f64>();
    println!(
        "surge speed dZ/dT on [2, 2.5]: simulation {sim:.3}, experiment {exp:.3} ({} points)",
        pts.len()
    );
    assert!((sim - exp).abs() < 0.1 * exp, "surge speed {sim} vs {exp}");

    let behind = rows_where(&rows, |e| e < -TOLERANCE);
    assert!(
        behind.is_empty(),
        "front behind the experiment:\n{}",
        behind.join("\n")
    );

    let (pure, _) = dam_break_comparison(Some(1.0));
    // One particle spacing h in units of a (0.1 m, asserted above), plus the interpolation
    // error.
    let scene = load_scene(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/dam_break.ron"))
        .unwrap_or_else(|e| panic!("{e}"));
    let slack = scene.particles[0].particle_volume.cbrt() as f64 / 0.1 + 1.2e-3;
    let mut lead = f64::NEG_INFINITY;
    for (r, p) in rows.iter().zip(&pure) {
        lead = lead.max(r.2 - p.2);
        assert!(
            r.2 <= p.2 + slack,
            "{} T = {:.3}: FLIP 0.95 front {:.3} ahead of pure FLIP {:.3} by more than {slack:.3}",
            r.0,
            r.1,
            r.2,
            p.2
        );
    }
    println!("largest lead of FLIP 0.95 over pure FLIP: {lead:+.4} (slack {slack:.4})");
}

/// Mean over the sources of each source's own piecewise-linear Z(T) at `t` (sources whose
/// points do not bracket `t` are left out).
fn mean_of_sources(points: &[Point], t: f64) -> f64 {
    let mut sources: Vec<&str> = points.iter().map(|p| p.source).collect();
    sources.dedup();
    let values: Vec<f64> = sources
        .iter()
        .filter_map(|s| {
            let curve: Vec<(f64, f64)> = points
                .iter()
                .filter(|p| p.source == *s)
                .map(|p| (p.t, p.z))
                .collect();
            let (first, last) = (curve[0].0, curve[curve.len() - 1].0);
            (first <= t && t <= last).then(|| interpolate(&curve, t))
        })
        .collect();
    values.iter().sum::<f64>() / values.len() as f64
}

struct Extent {
    min_x: f32,
    max_x: f32,
    min_y: f32,
    max_y: f32,
}

fn positions_of(p: &[Vec3]) -> Extent {
    let mut e = Extent {
        min_x: f32::INFINITY,
        max_x: f32::NEG_INFINITY,
        min_y: f32::INFINITY,
        max_y: f32::NEG_INFINITY,
    };
    for x in p {
        e.min_x = e.min_x.min(x.x);
        e.max_x = e.max_x.max(x.x);
        e.min_y = e.min_y.min(x.y);
        e.max_y = e.max_y.max(x.y);
    }
    e
}

/// The projected pressure (`PressureSolve::Projection` with symplectic Euler, ALGORITHM §5.4:
/// no sound speed, Δt from advection alone) runs the same dam break as the shipped weakly
/// compressible scene (Tait, c₀ = 20 m/s) and must give the same front: at every experimental
/// time the two fronts lie within one particle spacing h of each other (the front is read off
/// particles) plus the weakly compressible model's own density error, Ma² ≤ (2/20)² = 1 % of Z.
/// Both sources of the stress's velocity gradient are held to it (gathered every step, and
/// carried from the last G2P as `game_config_projected` does).
#[test]
fn the_projected_dam_break_front_matches_the_weakly_compressible_one() {
    let (tait, _) = dam_break_comparison(None);
    let scene = load_scene(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/dam_break.ron"))
        .unwrap_or_else(|e| panic!("{e}"));
    let h = scene.particles[0].particle_volume.cbrt() as f64 / 0.1;
    for source in [
        VelocityGradientSource::Gather,
        VelocityGradientSource::Carried,
    ] {
        let (projected, _) = dam_break_comparison_with(|c| {
            c.integrator.scheme = Scheme::SymplecticEuler;
            c.integrator.pressure = PressureSolve::Projection(ProjectionConfig::default());
            c.integrator.velocity_gradient = source;
        });
        let mut worst: f64 = 0.0;
        for (t, p) in tait.iter().zip(&projected) {
            let allowed = h + 0.01 * t.2;
            let d = (p.2 - t.2).abs();
            worst = worst.max(d / allowed);
            assert!(
                d <= allowed,
                "{source:?}: {} T = {:.3}: projected Z = {:.3}, Tait Z = {:.3}, allowed \
                 ±{allowed:.3}",
                p.0,
                p.1,
                p.2,
                t.2
            );
        }
        println!("{source:?}: largest front difference {worst:.2} of the allowance");
    }
}
