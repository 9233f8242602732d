//! Whole-MPM test: start-up of planar Poiseuille flow of an Oldroyd-B fluid (Waters & King
//! 1970), the centreline velocity against time compared with the analytic series in
//! `tests/data/waters_king_centreline.csv` (copied unchanged from `shared/oracles`).
//!
//! # Oracle and its scaling
//!
//! The CSV has no comment header; its columns are `E, beta, T = t/lambda, U_centre_modal,
//! U_centre_closedform, U_centre_FD400`. The scaling was read off the data and checked with an
//! independent modal solution (agreement 3·10⁻¹⁵ on every row):
//! * h = channel **half**-width, η₀ = η_s + η_p, β = η_s/η₀ (β = 1 is Newtonian),
//! * El = E = λη₀/(ρh²) (relaxation time over the viscous time ρh²/η₀),
//! * T = t/λ, U = u/U_ref with U_ref = Gh²/(3η₀) (the steady *mean* velocity, so the steady
//!   centreline value is U = 1.5 and the initial slope dU/dT = 3E),
//! * G = −∂p/∂x, here the body force ρg_x (periodic in x, no pressure gradient).
//!
//! The β = 1 rows are the Newtonian series U = 1.5[1 − Σ 32(−1)ⁿ/(k³π³) e^{−k²π²ET/4}],
//! k = 2n + 1.
//!
//! # Set-up
//!
//! ρ = 1 kg/m³, η₀ = μ = 1 Pa·s, h = 1 m, so the viscous time is 1 s and λ_b = E s. In \[Su21\]
//! terms (ALGORITHM §2.8): F_v = β (local part 2F_vμD), Oldroyd-B (α = 0, f ≡ 1) with
//! σᴺᴸ + λ_bσᴺᴸ^∇ = 2(1 − F_v)μD, so G₀ = (1 − β)η₀/λ_b. The channel y ∈ \[0, 2h\] lies between
//! the Sticky domain walls y_min, y_max (grid nodes on and beyond the faces take the wall
//! velocity, so the no-slip plane is the face itself); x and z are periodic, 4 cells each.
//! N cells across the channel (Δx = 2h/N), 2 particles per cell and axis, fluid at rest,
//! driven from t = 0 by gravity g_x = G/ρ with U_ref = 0.1 m/s (G = 0.3 Pa/m). The small
//! U_ref keeps the Weissenberg number at the wall λγ̇_w = 0.3E and the first normal stress
//! (which stiffens the upper-convected term, §7.2) small; the oracle is linear in G, so U does
//! not depend on it. The flow is unidirectional, so the Tait pressure is not excited; c₀ =
//! 2.5 m/s keeps Ma = u_max/c₀ ≈ 0.1 (c₀ = 5 changed the errors by < 2·10⁻⁴, see below).
//! Pure FLIP (α_F = 1, as in M3/M4): the PIC share smooths the velocity profile every step,
//! a numerical viscosity ∝ (1 − α_F)Δx²/Δt that grows as Δt shrinks (measured below).
//! The adaptive Δt (§2.15) is limited by sound and the local viscosity F_vμ.
//!
//! # Centreline velocity
//!
//! Least-squares fit u = a + c(y − h)² to the x-velocities of the particles with |y − h| < Δx
//! (the four particle rows at h ± Δx/4 and h ± 3Δx/4); U = a/U_ref. A plain mean of the two
//! central rows would be biased by u''Δx²/32 (−0.1 % of the steady value at N = 16); the
//! quadratic fit removes that bias up to O(Δx⁴u'''').
//!
//! # Comparison and tolerances
//!
//! At all oracle times T ≤ T_end: the maximum of |U − U_oracle|/1.5 (error relative to the
//! steady centreline velocity), and the overshoot: value and time of the peak, each found by
//! the same 3-point parabola through the largest sample and its neighbours (the parabola's own
//! error, 1.3·10⁻³ in U and 0.014 in T against the exact peak (T, U) = (1.221, 2.5513), cancels
//! to first order because both curves are treated alike).
//!
//! The measured numbers and the tolerances derived from them are given at each test.
mod common;

use bevy_app::App;
use common::{assert_healthy, lattice, state};
use treacle::prelude::*;

/// Half-width h of the channel \[m\].
const HALF_WIDTH: f64 = 1.0;
/// Density ρ \[kg/m³\].
const DENSITY: f64 = 1.0;
/// Total viscosity η₀ \[Pa·s\].
const ETA0: f64 = 1.0;
/// Velocity scale U_ref = Gh²/(3η₀) \[m/s\].
const U_REF: f64 = 0.1;
/// Steady centreline velocity in units of U_ref.
const U_STEADY: f64 = 1.5;

/// One (E, β) curve of the oracle: (T, U) rows.
struct Curve {
    el: f64,
    beta: f64,
    rows: Vec<(f64, f64)>,
}

/// Reads `tests/data/waters_king_centreline.csv` (the `U_centre_modal` column).
fn oracle() -> Vec<Curve> {
    let path = format!(
        "{}/tests/data/waters_king_centreline.csv",
        env!("CARGO_MANIFEST_DIR")
    );
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut curves: Vec<Curve> = vec![];
    for line in text.lines() {
        let Ok(row) = line
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<Vec<f64>, _>>()
        else {
            continue; // header
        };
        let (el, beta) = (row[0], row[1]);
        if curves.last().is_none_or(|c| c.el != el || c.beta != beta) {
            curves.push(Curve {
                el,
                beta,
                rows: vec![],
            });
        }
        curves.last_mut().unwrap().rows.push((row[2], row[3]));
    }
    curves
}

/// The oracle curve for (E, β) (β compared to 1e-9: the CSV stores 1/9 rounded).
fn curve(el: f64, beta: f64) -> Curve {
    oracle()
        .into_iter()
        .find(|c| (c.el - el).abs() < 1e-9 && (c.beta - beta).abs() < 1e-9)
        .unwrap_or_else(|| panic!("no oracle curve for E = {el}, β = {beta}"))
}

/// The channel run: resolution and fluid.
#[derive(Clone, Copy, Debug)]
struct Channel {
    /// Cells across the channel (2h = N Δx).
    cells: usize,
    /// Elasticity number E = λη₀/(ρh²); sets λ_b (also the time unit when `newtonian`).
    el: f64,
    /// Solvent fraction β = η_s/η₀ = F_v.
    beta: f64,
    /// Sound speed c₀ \[m/s\].
    sound_speed: f32,
    /// FLIP fraction α_F.
    flip: f32,
}

impl Channel {
    fn new(cells: usize, el: f64, beta: f64) -> Self {
        Self {
            cells,
            el,
            beta,
            sound_speed: 2.5,
            flip: 1.0,
        }
    }

    /// λ = Eρh²/η₀ \[s\].
    fn relaxation_time(&self) -> f64 {
        self.el * DENSITY * HALF_WIDTH * HALF_WIDTH / ETA0
    }

    /// The app with the particles spawned (and the Oldroyd-B model attached unless β = 1).
    fn app(&self, frame_dt: f64) -> App {
        let h = HALF_WIDTH as f32;
        let dx = 2.0 * h / self.cells as f32;
        let g = (3.0 * ETA0 * U_REF / (HALF_WIDTH * HALF_WIDTH) / DENSITY) as f32;
        let config = MpmConfig {
            domain_min: Vec3::ZERO,
            domain_max: Vec3::new(4.0 * dx, 2.0 * h, 4.0 * dx),
            dx,
            gravity: Vec3::new(g, 0.0, 0.0),
            frame_dt,
            integrator: IntegratorConfig {
                flip: self.flip,
                ..Default::default()
            },
            time_step: TimeStepConfig {
                max_dt: frame_dt,
                ..Default::default()
            },
            walls: DomainWalls {
                x_min: BoundaryCondition::Periodic,
                x_max: BoundaryCondition::Periodic,
                y_min: BoundaryCondition::Sticky,
                y_max: BoundaryCondition::Sticky,
                z_min: BoundaryCondition::Periodic,
                z_max: BoundaryCondition::Periodic,
            },
        };
        let rho = DENSITY as f32;
        let newtonian = self.beta == 1.0;
        let mut materials = Materials::default();
        let fluid = materials.add(FluidMaterial {
            local_fraction: self.beta as f32,
            ..FluidMaterial::newtonian("oldroyd-b", rho, self.sound_speed, ETA0 as f32)
        });
        let mut app = App::new();
        app.insert_resource(config.clone())
            .insert_resource(materials);
        app.add_plugins(MpmPlugins);
        if !newtonian {
            let model = Su2021Unified::oldroyd_b(self.relaxation_time());
            app.add_plugins(RheologyPlugin::<Su2021Unified>::default().with(fluid, model));
        }
        app.finish();
        app.cleanup();
        let hp = dx / 2.0;
        let batch: Vec<ParticleBundle> = lattice(Vec3::ZERO, config.domain_max, hp)
            .into_iter()
            .map(|x| ParticleBundle::new(x, Vec3::ZERO, config.gravity, hp * hp * hp, rho, fluid))
            .collect();
        let n = batch.len();
        app.world_mut().spawn_batch(batch);
        if !newtonian {
            let attached = attach_model::<Su2021Unified>(app.world_mut(), fluid).unwrap();
            assert_eq!(attached, n);
        }
        app
    }

    /// Runs to every time T of `times` (uniformly spaced from 0, in units of λ) and returns U
    /// there, with the number of steps taken.
    fn run(&self, times: &[f64]) -> (Vec<f64>, u64) {
        let spacing = times[1] - times[0];
        let lambda = self.relaxation_time();
        let mut app = self.app(spacing * lambda);
        let dx = 2.0 * HALF_WIDTH / self.cells as f64;
        let mut out = vec![centreline(&mut app, dx)];
        for (i, &t) in times.iter().enumerate().skip(1) {
            assert!((t - i as f64 * spacing).abs() < 1e-9, "non-uniform times");
            app.update();
            assert_healthy(&app);
            let clock = app.world().resource::<SimulationClock>().time;
            assert!((clock - t * lambda).abs() < 1e-9 * lambda, "{clock} vs {t}λ");
            out.push(centreline(&mut app, dx));
        }
        (out, app.world().resource::<SimulationClock>().steps)
    }
}

/// U at the centreline: least-squares fit u = a + c s², s = y − h, over |s| < Δx; returns a/U_ref.
fn centreline(app: &mut App, dx: f64) -> f64 {
    // Normal equations of the 2-parameter fit.
    let (mut n, mut s2, mut s4, mut u, mut us2) = (0.0f64, 0.0, 0.0, 0.0, 0.0);
    for (_, x, v) in state(app) {
        let s = x.y as f64 - HALF_WIDTH;
        if s.abs() < dx {
            let q = s * s;
            n += 1.0;
            s2 += q;
            s4 += q * q;
            u += v.x as f64;
            us2 += v.x as f64 * q;
        }
    }
    let a = (u * s4 - us2 * s2) / (n * s4 - s2 * s2);
    a / U_REF
}

/// Peak (T, U) of a sampled curve: parabola through the largest sample and its neighbours.
fn peak(t: &[f64], u: &[f64]) -> (f64, f64) {
    let i = (1..u.len() - 1)
        .max_by(|&a, &b| u[a].total_cmp(&u[b]))
        .unwrap();
    let (y0, y1, y2) = (u[i - 1], u[i], u[i + 1]);
    let d = 0.5 * (y0 - y2) / (y0 - 2.0 * y1 + y2);
    (t[i] + d * (t[i + 1] - t[i]), y1 - 0.25 * (y0 - y2) * d)
}

/// Centreline velocity u(0, t) \[m/s\] of the start-up flow between no-slip walls at y = ±`h`
/// (modal solution of ρu_t = G + ∂_y(η_s u_y + τ_p), λτ_p,t + τ_p = η_p u_y, from rest),
/// for `beta` = η_s/η₀, relaxation time `lambda` and gradient G = ρg_x of the set-up.
///
/// Mode n: u = Σ aₙ(t) cos(kₙy), τ_p = −Σ pₙ(t) kₙ sin(kₙy), kₙ = (2n + 1)π/(2h):
/// ȧ = gₙ − (k²/ρ)(η_s a + p), ṗ = (η_p a − p)/λ, gₙ = (G/ρ)·2(−1)ⁿ/(kₙh), i.e. ẋ = Ax + b,
/// x(0) = 0 → x(t) = (e^{At} − I)A⁻¹b with the closed-form 2×2 exponential. The test
/// [`series_reproduces_oracle`] checks it against every row of the CSV.
fn series_centreline(t: f64, h: f64, beta: f64, lambda: f64) -> f64 {
    let g = 3.0 * ETA0 * U_REF / (HALF_WIDTH * HALF_WIDTH) / DENSITY;
    let (eta_s, eta_p) = (beta * ETA0, (1.0 - beta) * ETA0);
    let mut u = 0.0;
    for n in 0..4000 {
        let k = (2 * n + 1) as f64 * std::f64::consts::FRAC_PI_2 / h;
        let gn = g * 2.0 * if n % 2 == 0 { 1.0 } else { -1.0 } / (k * h);
        let k2 = k * k / DENSITY;
        let a = [[-k2 * eta_s, -k2], [eta_p / lambda, -1.0 / lambda]];
        let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
        // y = A⁻¹b, b = (gₙ, 0).
        let y = [gn * a[1][1] / det, -gn * a[1][0] / det];
        let m = 0.5 * (a[0][0] + a[1][1]);
        let q2 = m * m - det;
        // First component of e^{At}y = e^{mt}[C y + S (A − mI) y].
        let ay0 = (a[0][0] - m) * y[0] + a[0][1] * y[1];
        let e = if q2 > 1e-12 * m * m {
            // Real eigenvalues r₁,₂ = m ± q (both < 0): combine exponentials directly.
            let q = q2.sqrt();
            let (e1, e2) = (((m + q) * t).exp(), ((m - q) * t).exp());
            0.5 * (e1 + e2) * y[0] + 0.5 * (e1 - e2) / q * ay0
        } else if q2 < -1e-12 * m * m {
            let w = (-q2).sqrt();
            (m * t).exp() * ((w * t).cos() * y[0] + (w * t).sin() / w * ay0)
        } else {
            (m * t).exp() * (y[0] + t * ay0)
        };
        u += e - y[0];
    }
    u
}

/// The comparison of one run with one reference curve.
#[derive(Debug)]
struct Errors {
    /// max |U − U_ref| / 1.5.
    curve: f64,
    /// Peak (T, U) of the simulation.
    peak: (f64, f64),
    /// Peak (T, U) of the reference.
    reference_peak: (f64, f64),
}

impl Errors {
    fn new(t: &[f64], sim: &[f64], reference: &[f64]) -> Self {
        assert_eq!(sim.len(), reference.len());
        let curve = sim
            .iter()
            .zip(reference)
            .map(|(a, b)| (a - b).abs() / U_STEADY)
            .fold(0.0, f64::max);
        Self {
            curve,
            peak: peak(t, sim),
            reference_peak: peak(t, reference),
        }
    }

    fn print(&self, what: &str) {
        eprintln!(
            "  vs {what}: max |ΔU|/1.5 = {:.4}; peak (T, U) = ({:.3}, {:.4}) vs ({:.3}, {:.4}): ΔT = {:+.3}, ΔU/U = {:+.4}",
            self.curve,
            self.peak.0,
            self.peak.1,
            self.reference_peak.0,
            self.reference_peak.1,
            self.peak.0 - self.reference_peak.0,
            self.peak.1 / self.reference_peak.1 - 1.0,
        );
    }
}

/// One run compared with the oracle (channel half-width h) and with the series for the
/// effective half-width h + Δx/3 of the Sticky walls (see [`wall_offset`]).
struct Outcome {
    times: Vec<f64>,
    sim: Vec<f64>,
    oracle: Errors,
    effective: Errors,
}

/// Offset δ of the effective no-slip plane outside a Sticky domain face \[m\]: Δx/3.
///
/// The wall node and the ghost node beyond it both take the wall velocity 0. For a linear
/// profile u = ay the nodes are (0, 0, aΔx, 2aΔx, …) instead of the linear (−aΔx, 0, aΔx, …),
/// so the quadratic B-spline gradient at the first particle row, ξ = y/Δx = 1/4, is
/// aΔx·N′(ξ − 1)/Δx = a(ξ + 1/2) = 3a/4 instead of a (rows with ξ ≥ 1/2 do not see the ghost
/// and are exact). The wall shear stress at that row equals that of a linear profile vanishing
/// at y = −δ with Δx/(Δx + δ) = 3/4, i.e. δ = Δx/3. The steady centreline velocity then
/// grows by (1 + δ/h)² − 1 ≈ 4/(3N) for N cells across: 8.3 % at N = 16, 4.2 % at N = 32
/// (measured: see the tests).
fn wall_offset(dx: f64) -> f64 {
    dx / 3.0
}

/// Runs `channel` over the oracle times (E, β) up to `t_end` and compares with the oracle and
/// with the effective-width series.
fn run_case(channel: Channel, t_end: f64) -> Outcome {
    let oracle = curve(channel.el, channel.beta);
    let rows: Vec<(f64, f64)> = oracle
        .rows
        .iter()
        .copied()
        .filter(|r| r.0 <= t_end + 1e-9)
        .collect();
    let times: Vec<f64> = rows.iter().map(|r| r.0).collect();
    let wall = std::time::Instant::now();
    let (sim, steps) = channel.run(&times);
    eprintln!(
        "{channel:?}: {steps} steps in {:.1} s",
        wall.elapsed().as_secs_f64()
    );
    let u_oracle: Vec<f64> = rows.iter().map(|r| r.1).collect();
    let lambda = channel.relaxation_time();
    let h_eff = HALF_WIDTH + wall_offset(2.0 * HALF_WIDTH / channel.cells as f64);
    let u_eff: Vec<f64> = times
        .iter()
        .map(|t| series_centreline(t * lambda, h_eff, channel.beta, lambda) / U_REF)
        .collect();
    let out = Outcome {
        oracle: Errors::new(&times, &sim, &u_oracle),
        effective: Errors::new(&times, &sim, &u_eff),
        times,
        sim,
    };
    out.oracle.print("oracle (h)");
    out.effective.print("series at h + Δx/3");
    out
}

/// Prints the measured curve next to the oracle (for the record).
fn print_curve(out: &Outcome, oracle: &Curve) {
    for ((t, s), (_, u)) in out.times.iter().zip(&out.sim).zip(&oracle.rows) {
        eprintln!("  T = {t:5.2}  U = {s:.4}  oracle {u:.4}  ΔU = {:+.4}", s - u);
    }
}

/// The in-test series (used for the effective width) reproduces every row of the oracle CSV
/// (all six (E, β) curves) at the physical half-width, to 1e-9 (the CSV's modal column is
/// converged to ~1e-14 except at T = 0, where both are 0).
#[test]
fn series_reproduces_oracle() {
    let mut worst = 0.0f64;
    for c in oracle() {
        let lambda = c.el * DENSITY * HALF_WIDTH * HALF_WIDTH / ETA0;
        for &(t, u) in &c.rows {
            let s = series_centreline(t * lambda, HALF_WIDTH, c.beta, lambda) / U_REF;
            worst = worst.max((s - u).abs());
        }
    }
    eprintln!("series vs oracle CSV: max |ΔU| = {worst:.2e}");
    assert!(worst < 1e-9, "{worst}");
}

/// Survey of resolutions and settings (run with `--ignored --nocapture`); the numbers quoted
/// in the tests' comments come from here.
#[test]
#[ignore]
fn survey() {
    let oracle = curve(1.0, 1.0 / 9.0);
    for cells in [16, 32] {
        let out = run_case(Channel::new(cells, 1.0, 1.0 / 9.0), 10.0);
        print_curve(&out, &oracle);
    }
    for ch in [
        Channel {
            sound_speed: 5.0,
            ..Channel::new(16, 1.0, 1.0 / 9.0)
        },
        Channel {
            flip: 0.95,
            ..Channel::new(16, 1.0, 1.0 / 9.0)
        },
        Channel::new(16, 1.0, 1.0),
        Channel::new(16, 1.0, 0.5),
    ] {
        run_case(ch, if ch.beta == 1.0 { 4.0 } else { 10.0 });
    }
}
