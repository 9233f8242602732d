//! `treacle report accuracy SPEC`: temporal accuracy and work-precision of the integrators.
//!
//! For every (case, integrator) of the SPEC ([`AccuracySpec`], format in `docs/reports.md`):
//!
//! 1. a **reference run** with the much smaller `reference_dt`, same scene, same spatial
//!    discretisation, same transfer;
//! 2. a **ladder** of runs with fixed Δt ([`StepRule::Exact`]: exactly end_time/Δt steps);
//! 3. per run, the error norms of [`cases`](super::cases) (mass-weighted RMS displacement and
//!    velocity differences, largest polymer-stress difference) against the reference (the
//!    *temporal* error, from which the orders are fitted) and against the analytic solution
//!    where the case declares one (the *total* error: temporal + spatial), and the wall time.
//!
//! Every run uses the SPEC's FLIP fraction (default 1 = pure FLIP): PIC damping acts once per
//! transfer, not per unit time, so any PIC fraction adds an error that grows as Δt shrinks and
//! spoils temporal convergence (ALGORITHM §2.5).
//!
//! Output (one folder): `accuracy.csv` (one row per run), `summary.md` (orders fitted with
//! [`fit_order`], work-precision winners with [`time_to_reach`]), and per case
//! `<case>_error_vs_dt.png` (error against Δt, order-1 and order-2 guide lines) and
//! `<case>_work_precision.png` (error against wall time).
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use bevy_ecs::schedule::IntoScheduleConfigs;
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use super::cases::{
    Errors, Exact, GridDrive, OldroydBParticle, ParticleState, ShearBandDrive, TemperatureField,
    VelocityField, compare, drive_shear_bands, drive_shear_bands_transferred,
};
use super::drive::{StepRule, drive};
use super::fit::{LadderPoint, OrderFit, Reach, error_levels, fit_order, time_to_reach};
use super::plots::{PALETTE, Panel, Series, draw_log_log};
use super::store::{RunStore, content_hash, csv_field, file_stem, num, short};
use super::{ReportError, ReportOptions, check_text_outputs, load_spec, progress_bar, ron_text};
use crate::config::{BoundaryCondition, IntegratorConfig, TimeStepMode};
use crate::gs4::Gs4Params;
use crate::math::{Real, Vec3};
use crate::output::{OutputError, ParticleFrame, read_ply, write_ply};
use crate::rheology::Su2021Unified;
use crate::rheology::su2021_unified::{PlateauModulus, XppFMode};
use crate::runner::scene_app;
use crate::scene::{FieldIssue, Scene, load_scene};
use crate::step::schedule::MpmSystems;

/// A SPEC of `treacle report accuracy` (RON, `AccuracySpec(...)`; `docs/reports.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, rename = "AccuracySpec")]
pub struct AccuracySpec {
    /// Title of the summary. Default empty (the SPEC's file name is used).
    #[serde(default)]
    pub title: String,
    /// FLIP fraction α_F ∈ \[0, 1\] of every run (overrides the integrators' `flip`, and the
    /// heat transfer's `thermal.transfer.flip` of scenes with heat).
    /// Default 1 (pure FLIP).
    #[serde(default = "default_flip")]
    pub flip: Real,
    /// The integrators compared; at least one.
    pub integrators: Vec<IntegratorSpec>,
    /// The cases; at least one.
    pub cases: Vec<AccuracyCase>,
    /// Error levels of the work-precision comparison (in the unit of each case's `metric`).
    /// Default empty: three levels inside the error range all integrators cover, per case.
    #[serde(default)]
    pub error_levels: Vec<f64>,
}

fn default_flip() -> Real {
    1.0
}

/// A named integrator: an [`IntegratorConfig`] (fields not given take their defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IntegratorSpec {
    /// Name used in tables, plots and file names; unique.
    pub name: String,
    /// The integrator settings put into the scene's `MpmConfig::integrator`. Default
    /// [`IntegratorConfig::default`]. Its `flip` is replaced by the SPEC's.
    #[serde(default)]
    pub config: IntegratorConfig,
}

/// One accuracy case.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccuracyCase {
    /// Name (unique; used in file names).
    pub name: String,
    /// What is simulated.
    pub source: CaseSource,
    /// Simulated time of every run \[s\]; a whole number of every Δt.
    pub end_time: f64,
    /// The Δt ladder \[s\] (fixed steps); each divides `end_time`.
    pub dt: Vec<f64>,
    /// Δt of the reference runs \[s\]; smaller than every ladder Δt (¼ or less of the smallest
    /// recommended: the temporal error of the reference is subtracted from nothing).
    pub reference_dt: f64,
    /// The error norm the orders are fitted on first and the work-precision comparison uses.
    /// Default `Velocity`.
    #[serde(default)]
    pub metric: Metric,
    /// Names of the integrators to run on this case. Default empty: all.
    #[serde(default)]
    pub integrators: Vec<String>,
    /// The ladder of the quick (CI) subset; cases without one are left out of `--quick`.
    #[serde(default)]
    pub quick: Option<QuickLadder>,
}

/// The quick subset of a case.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QuickLadder {
    /// Δt ladder \[s\].
    pub dt: Vec<f64>,
    /// Reference Δt \[s\].
    pub reference_dt: f64,
    /// End time \[s\]. Default the case's.
    #[serde(default)]
    pub end_time: Option<f64>,
}

/// What a case simulates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum CaseSource {
    /// A scene file (path relative to the SPEC's folder), optionally modified in code before
    /// the start-up.
    Scene {
        /// The scene file.
        path: String,
        /// Initial velocity of every particle (replaces the bodies' velocities).
        #[serde(default)]
        initial_velocity: Option<VelocityField>,
        /// A velocity imposed on grid nodes every step.
        #[serde(default)]
        drive: Option<GridDrive>,
        /// The analytic solution to compare with.
        #[serde(default)]
        analytic: Option<Analytic>,
        /// Initial temperature of every heated particle (replaces the materials' initial
        /// temperature; the scene needs heat).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        initial_temperature: Option<TemperatureField>,
    },
    /// The particle-level Oldroyd-B start-up of shear (ALGORITHM §9 S1), no grid.
    OldroydBParticle(OldroydBParticle),
}

/// Analytic solutions a scene case can declare.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Analytic {
    /// Viscous decay of the `ShearWave` initial velocity with ν = μ/ρ of the scene's (single)
    /// material.
    ShearDecay,
    /// Oldroyd-B start-up under the `SimpleShear` initial velocity, with λ_b and G₀ of the
    /// scene's `Su2021Unified` Oldroyd-B model.
    OldroydBStartup,
    /// Fourier decay of the `Cosine` initial temperature in an insulated slab at rest,
    /// e^{−kπ²t/L²}, with k of the scene's (single) heated material.
    HeatDecay,
}

/// An error norm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Metric {
    /// Mass-weighted RMS displacement difference \[m\].
    Displacement,
    /// Mass-weighted RMS velocity difference \[m/s\].
    #[default]
    Velocity,
    /// Largest polymer-stress component difference \[Pa\].
    Stress,
    /// Mass-weighted RMS temperature difference (L2 over the particles; scenes with heat).
    Temperature,
}

impl Metric {
    const ALL: [Metric; 4] = [
        Metric::Displacement,
        Metric::Velocity,
        Metric::Stress,
        Metric::Temperature,
    ];

    /// This norm of `e`, if measured.
    pub fn of(self, e: &Errors) -> Option<f64> {
        match self {
            Metric::Displacement => e.displacement,
            Metric::Velocity => e.velocity,
            Metric::Stress => e.stress,
            Metric::Temperature => e.temperature,
        }
    }

    fn label(self) -> &'static str {
        match self {
            Metric::Displacement => "displacement error [m]",
            Metric::Velocity => "velocity error [m/s]",
            Metric::Stress => "stress error [Pa]",
            Metric::Temperature => "temperature error (L2 over particles)",
        }
    }

    fn short(self) -> &'static str {
        match self {
            Metric::Displacement => "displacement",
            Metric::Velocity => "velocity",
            Metric::Stress => "stress",
            Metric::Temperature => "temperature",
        }
    }
}

/// The stored result of one run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AccuracyRun {
    /// Case name.
    pub case: String,
    /// Integrator name.
    pub integrator: String,
    /// True for the reference run.
    pub reference: bool,
    /// Δt \[s\].
    pub dt: f64,
    /// Steps.
    pub steps: u64,
    /// End time \[s\].
    pub end_time: f64,
    /// Δt of the reference run it is compared with \[s\].
    pub reference_dt: f64,
    /// FLIP fraction used.
    pub flip: Real,
    /// Particles.
    pub particles: usize,
    /// `ok`, or why there are no errors (`failed: <diagnostic>`, `no reference`).
    pub status: String,
    /// Wall time of the simulation \[s\].
    pub wall_seconds: f64,
    /// Errors against the reference run (temporal error).
    pub vs_reference: Errors,
    /// Errors against the analytic solution (total error).
    pub vs_exact: Errors,
    /// Size of the solution for relative errors: RMS displacement and velocity and largest
    /// stress component of this run's final state.
    pub scale: Errors,
}

/// What [`run_accuracy`] produced.
#[derive(Clone, Debug)]
pub struct AccuracyReport {
    /// Output folder.
    pub out_dir: PathBuf,
    /// Every run (references included), in plan order.
    pub runs: Vec<AccuracyRun>,
    /// Runs simulated now.
    pub simulated: usize,
    /// Runs loaded from an earlier report in the folder.
    pub resumed: usize,
    /// Observed orders of every (case, integrator, metric), against the reference and, where
    /// the case has one, against the analytic solution.
    pub orders: Vec<FittedOrder>,
    /// Files written (CSV, markdown, PNGs).
    pub files: Vec<PathBuf>,
}

/// One fitted order of [`AccuracyReport::orders`].
#[derive(Clone, Debug, PartialEq)]
pub struct FittedOrder {
    /// Case name.
    pub case: String,
    /// Integrator name.
    pub integrator: String,
    /// The error norm.
    pub metric: Metric,
    /// Fitted on the errors against the analytic solution (else against the reference).
    pub against_exact: bool,
    /// The fit (`None` with fewer than two usable points).
    pub fit: Option<OrderFit>,
}

impl AccuracyReport {
    /// The temporal order (errors against the reference) of `case`/`integrator` on `metric`.
    pub fn order(&self, case: &str, integrator: &str, metric: Metric) -> Option<OrderFit> {
        self.find_order(case, integrator, metric, false)
    }

    /// The order of the errors against the analytic solution.
    pub fn order_exact(&self, case: &str, integrator: &str, metric: Metric) -> Option<OrderFit> {
        self.find_order(case, integrator, metric, true)
    }

    fn find_order(&self, case: &str, integ: &str, metric: Metric, exact: bool) -> Option<OrderFit> {
        self.orders
            .iter()
            .find(|o| {
                o.case == case
                    && o.integrator == integ
                    && o.metric == metric
                    && o.against_exact == exact
            })
            .and_then(|o| o.fit)
    }
}

/// Loads and validates an accuracy SPEC.
pub fn load_accuracy_spec(path: &Path) -> Result<(AccuracySpec, String), ReportError> {
    Ok(load_spec(path, validate)?)
}

fn whole_steps(end: f64, dt: f64) -> Option<u64> {
    let n = end / dt;
    let r = n.round();
    ((n - r).abs() <= 1e-6 * r.max(1.0) && r >= 1.0).then_some(r as u64)
}

fn check_ladder(issues: &mut Vec<FieldIssue>, at: &str, end: f64, dt: &[f64], reference: f64) {
    if dt.is_empty() {
        issues.push(FieldIssue::new(
            format!("{at}.dt"),
            "must list at least one Δt",
        ));
    }
    for (k, &d) in dt.iter().enumerate() {
        if !(d > 0.0 && d.is_finite()) {
            issues.push(FieldIssue::new(
                format!("{at}.dt"),
                format!("Δt[{k}] must be > 0 s (got {d})"),
            ));
        } else if end > 0.0 && whole_steps(end, d).is_none() {
            issues.push(FieldIssue::new(
                format!("{at}.dt"),
                format!(
                    "Δt[{k}] = {d} s does not divide the end time {end} s ({} steps): every run must take a whole number of fixed steps",
                    end / d
                ),
            ));
        }
    }
    let smallest = dt.iter().copied().fold(f64::INFINITY, f64::min);
    if !(reference > 0.0 && reference.is_finite()) {
        issues.push(FieldIssue::new(
            format!("{at}.reference_dt"),
            format!("must be > 0 s (got {reference})"),
        ));
    } else if reference >= smallest {
        issues.push(FieldIssue::new(
            format!("{at}.reference_dt"),
            format!(
                "must be smaller than every ladder Δt (smallest {smallest} s, got {reference} s)"
            ),
        ));
    } else if end > 0.0 && whole_steps(end, reference).is_none() {
        issues.push(FieldIssue::new(
            format!("{at}.reference_dt"),
            format!("{reference} s does not divide the end time {end} s"),
        ));
    }
}

/// The Oldroyd-B parameters (λ_b, η_p) of a scene's single Su2021Unified model, or why not.
fn oldroyd_b_of(scene: &Scene) -> Result<(f64, f64), String> {
    let models: Vec<_> = scene
        .rheology
        .iter()
        .filter_map(|(id, m)| m.downcast_ref::<Su2021Unified>().map(|m| (*id, m)))
        .collect();
    let [(id, m)] = models.as_slice() else {
        return Err(format!(
            "needs exactly one Su2021Unified model in the scene (found {})",
            models.len()
        ));
    };
    if m.f_mode != XppFMode::One || m.anisotropy != 0.0 {
        return Err(
            "the Su2021Unified model must be Oldroyd-B (f_mode: One, anisotropy: 0)".into(),
        );
    }
    let mat = scene.materials.get(*id);
    let mu = m.viscosity.unwrap_or(mat.viscosity as f64);
    let fv = m.local_fraction.unwrap_or(mat.local_fraction as f64);
    let lambda = m.backbone_relaxation_time;
    let g0 = match m.modulus {
        PlateauModulus::Derived => (1.0 - fv) * mu / lambda,
        PlateauModulus::User(g) => g,
    };
    Ok((lambda, g0 * lambda))
}

/// The diffusivity k of a scene whose heat has an analytic Fourier solution in an insulated
/// slab at rest, or why not.
fn heat_decay_of(scene: &Scene) -> Result<f64, String> {
    let Some(th) = &scene.thermal else {
        return Err("HeatDecay needs a scene with heat (a `thermal` section)".into());
    };
    let c = &th.config;
    let [(_, m)] = c.materials.as_slice() else {
        return Err(format!(
            "HeatDecay needs exactly one heated material (found {})",
            c.materials.len()
        ));
    };
    if !(m.relaxation_time == 0.0 || m.fourier_fraction == 1.0) {
        return Err(
            "HeatDecay needs Fourier conduction (relaxation_time 0 or fourier_fraction 1)".into(),
        );
    }
    if c.walls.any() || c.ambient.is_some() || !th.collider_temperatures.is_empty() {
        return Err("HeatDecay needs an insulated slab: no wall or collider temperatures, no ambient exchange".into());
    }
    if m.volumetric_source != 0.0 || m.surface_source != 0.0 {
        return Err("HeatDecay needs a material without heat sources".into());
    }
    if scene.config.gravity != Vec3::ZERO {
        return Err("HeatDecay needs particles at rest: set gravity to (0, 0, 0)".into());
    }
    Ok(m.diffusivity)
}

fn validate(spec: &AccuracySpec, base: &Path) -> Vec<FieldIssue> {
    let mut issues = Vec::new();
    if !(0.0..=1.0).contains(&spec.flip) {
        issues.push(FieldIssue::new(
            "flip",
            format!("must be in [0, 1] (got {})", spec.flip),
        ));
    }
    if spec.integrators.is_empty() {
        issues.push(FieldIssue::new(
            "integrators",
            "must list at least one integrator",
        ));
    }
    validate_integrators(&spec.integrators, &[], &mut issues);
    for &l in &spec.error_levels {
        if !(l > 0.0 && l.is_finite()) {
            issues.push(FieldIssue::new(
                "error_levels",
                format!("levels must be > 0 (got {l})"),
            ));
        }
    }
    if spec.cases.is_empty() {
        issues.push(FieldIssue::new("cases", "must list at least one case"));
    }
    for (i, case) in spec.cases.iter().enumerate() {
        let at = format!("cases[{i}]");
        if case.name.trim().is_empty() {
            issues.push(FieldIssue::new(format!("{at}.name"), "must not be empty"));
        }
        if spec.cases[..i].iter().any(|o| o.name == case.name) {
            issues.push(FieldIssue::new(
                format!("{at}.name"),
                format!("`{}` is used twice; names must be unique", case.name),
            ));
        }
        if !(case.end_time > 0.0 && case.end_time.is_finite()) {
            issues.push(FieldIssue::new(
                format!("{at}.end_time"),
                format!("must be > 0 s (got {})", case.end_time),
            ));
        }
        check_ladder(&mut issues, &at, case.end_time, &case.dt, case.reference_dt);
        if let Some(q) = &case.quick {
            let end = q.end_time.unwrap_or(case.end_time);
            if !(end > 0.0 && end.is_finite()) {
                issues.push(FieldIssue::new(
                    format!("{at}.quick.end_time"),
                    format!("must be > 0 s (got {end})"),
                ));
            }
            check_ladder(
                &mut issues,
                &format!("{at}.quick"),
                end,
                &q.dt,
                q.reference_dt,
            );
        }
        for name in &case.integrators {
            if !spec.integrators.iter().any(|s| &s.name == name) {
                issues.push(FieldIssue::new(
                    format!("{at}.integrators"),
                    format!("unknown integrator `{name}` (not in `integrators`)"),
                ));
            }
        }
        match &case.source {
            CaseSource::OldroydBParticle(p) => {
                for (field, v) in [
                    ("shear_rate", p.shear_rate),
                    ("relaxation_time", p.relaxation_time),
                    ("polymer_viscosity", p.polymer_viscosity),
                ] {
                    if !(v > 0.0 && v.is_finite()) {
                        issues.push(FieldIssue::new(
                            format!("{at}.source.{field}"),
                            format!("must be > 0 (got {v})"),
                        ));
                    }
                }
                if case.metric != Metric::Stress {
                    issues.push(FieldIssue::new(
                        format!("{at}.metric"),
                        "a particle-level case has only the stress error: use `metric: Stress`",
                    ));
                }
            }
            CaseSource::Scene {
                path,
                initial_velocity,
                drive,
                analytic,
                initial_temperature,
            } => {
                let scene = match load_scene(&base.join(path)) {
                    Ok(s) => s,
                    Err(e) => {
                        issues.push(FieldIssue::new(
                            format!("{at}.source.path"),
                            format!("cannot load the scene: {e}"),
                        ));
                        continue;
                    }
                };
                if let Some(GridDrive::ShearBands { width, .. }) = drive
                    && (width.is_nan() || *width < 1.0)
                {
                    issues.push(FieldIssue::new(
                        format!("{at}.source.drive"),
                        format!("width must be ≥ 1 cell (got {width})"),
                    ));
                }
                if initial_temperature.is_some() && scene.thermal.is_none() {
                    issues.push(FieldIssue::new(
                        format!("{at}.source.initial_temperature"),
                        "needs a scene with heat (a `thermal` section)",
                    ));
                }
                if case.metric == Metric::Temperature && scene.thermal.is_none() {
                    issues.push(FieldIssue::new(
                        format!("{at}.metric"),
                        "the temperature error needs a scene with heat (a `thermal` section)",
                    ));
                }
                match analytic {
                    Some(Analytic::HeatDecay) => {
                        if !matches!(initial_temperature, Some(TemperatureField::Cosine { .. })) {
                            issues.push(FieldIssue::new(
                                format!("{at}.source.analytic"),
                                "HeatDecay needs `initial_temperature: Cosine(...)`",
                            ));
                        }
                        if let Err(e) = heat_decay_of(&scene) {
                            issues.push(FieldIssue::new(format!("{at}.source.analytic"), e));
                        }
                    }
                    Some(Analytic::ShearDecay) => {
                        if !matches!(initial_velocity, Some(VelocityField::ShearWave { .. })) {
                            issues.push(FieldIssue::new(
                                format!("{at}.source.analytic"),
                                "ShearDecay needs `initial_velocity: ShearWave(...)`",
                            ));
                        }
                        if scene.materials.list.len() != 1 {
                            issues.push(FieldIssue::new(
                                format!("{at}.source.analytic"),
                                "ShearDecay needs a scene with exactly one material",
                            ));
                        }
                    }
                    Some(Analytic::OldroydBStartup) => {
                        if !matches!(initial_velocity, Some(VelocityField::SimpleShear { .. })) {
                            issues.push(FieldIssue::new(
                                format!("{at}.source.analytic"),
                                "OldroydBStartup needs `initial_velocity: SimpleShear(...)`",
                            ));
                        }
                        if let Err(e) = oldroyd_b_of(&scene) {
                            issues.push(FieldIssue::new(format!("{at}.source.analytic"), e));
                        }
                    }
                    None => {}
                }
                if case.metric == Metric::Stress
                    && !scene
                        .rheology
                        .iter()
                        .any(|(_, m)| m.downcast_ref::<Su2021Unified>().is_some())
                {
                    issues.push(FieldIssue::new(
                        format!("{at}.metric"),
                        "the stress error needs a Su2021Unified model in the scene",
                    ));
                }
            }
        }
    }
    issues
}

/// A case ready to run.
struct Prepared {
    name: String,
    kind: Kind,
    end_time: f64,
    dt: Vec<f64>,
    reference_dt: f64,
    metric: Metric,
    integrators: Vec<usize>,
    exact: Option<Exact>,
    periods: [Option<f64>; 3],
    /// Hash of everything the case's results depend on besides integrator and Δt.
    hash: u64,
    description: String,
}

enum Kind {
    Scene {
        scene: Box<Scene>,
        initial_velocity: Option<VelocityField>,
        drive: Option<GridDrive>,
        initial_temperature: Option<TemperatureField>,
    },
    Particle(OldroydBParticle),
}

fn prepare(spec: &AccuracySpec, base: &Path, quick: bool) -> Result<Vec<Prepared>, ReportError> {
    let mut out = Vec::new();
    for case in &spec.cases {
        let (dt, reference_dt, end_time) = match (&case.quick, quick) {
            (_, false) => (case.dt.clone(), case.reference_dt, case.end_time),
            (Some(q), true) => (
                q.dt.clone(),
                q.reference_dt,
                q.end_time.unwrap_or(case.end_time),
            ),
            (None, true) => continue,
        };
        let integrators: Vec<usize> = spec
            .integrators
            .iter()
            .enumerate()
            .filter(|(_, s)| case.integrators.is_empty() || case.integrators.contains(&s.name))
            .map(|(i, _)| i)
            .collect();
        let (kind, exact, periods, source_text, description) = match &case.source {
            CaseSource::OldroydBParticle(p) => (
                Kind::Particle(*p),
                Some(p.exact()),
                [None; 3],
                String::new(),
                format!(
                    "built-in particle-level Oldroyd-B start-up of shear (ALGORITHM §9 S1): γ̇ = {} 1/s, λ_b = {} s, η_p = {} Pa·s, {} relaxation, no grid",
                    p.shear_rate,
                    p.relaxation_time,
                    p.polymer_viscosity,
                    if p.implicit_relaxation {
                        "linearly implicit (η_σ = 1)"
                    } else {
                        "explicit (η_σ = 0)"
                    }
                ),
            ),
            CaseSource::Scene {
                path,
                initial_velocity,
                drive,
                analytic,
                initial_temperature,
            } => {
                let file = base.join(path);
                let scene = load_scene(&file)?;
                let text = std::fs::read_to_string(&file)
                    .map_err(|e| OutputError::io("read", &file, e))?;
                let c = &scene.config;
                let periodic = c.walls.periodic_axes();
                let periods = [0, 1, 2]
                    .map(|a| periodic[a].then(|| (c.domain_max[a] - c.domain_min[a]) as f64));
                let exact = match (analytic, initial_velocity) {
                    (
                        Some(Analytic::ShearDecay),
                        Some(VelocityField::ShearWave {
                            amplitude,
                            wavelength,
                        }),
                    ) => {
                        let m = &scene.materials.list[0];
                        Some(Exact::ShearDecay {
                            amplitude: *amplitude as f64,
                            wavenumber: std::f64::consts::TAU / *wavelength as f64,
                            kinematic_viscosity: m.viscosity as f64 / m.density as f64,
                            y_min: c.domain_min.y as f64,
                        })
                    }
                    (
                        Some(Analytic::OldroydBStartup),
                        Some(VelocityField::SimpleShear { rate }),
                    ) => {
                        let (lambda, eta_p) = oldroyd_b_of(&scene).unwrap_or((1.0, 0.0));
                        Some(Exact::OldroydBStartup {
                            rate: *rate as f64,
                            center: 0.5 * (c.domain_min.y + c.domain_max.y) as f64,
                            relaxation_time: lambda,
                            polymer_viscosity: eta_p,
                        })
                    }
                    (Some(Analytic::HeatDecay), _) => initial_temperature.map(|f| match f {
                        TemperatureField::Cosine {
                            mean,
                            amplitude,
                            length,
                        } => Exact::HeatDecay {
                            mean: mean as f64,
                            amplitude: amplitude as f64,
                            length: length as f64,
                            x_min: c.domain_min.x as f64,
                            diffusivity: heat_decay_of(&scene).unwrap_or(0.0),
                        },
                    }),
                    _ => None,
                };
                let mut d = format!(
                    "scene `{}` ({} particles, Δx = {} m)",
                    file.display(),
                    scene.particle_count(),
                    c.dx
                );
                if let Some(v) = initial_velocity {
                    let _ = write!(d, ", initial velocity {v:?}");
                }
                if let Some(g) = drive {
                    let _ = write!(d, ", grid drive {g:?}");
                }
                if let Some(t) = initial_temperature {
                    let _ = write!(d, ", initial temperature {t:?}");
                }
                if let Some(a) = analytic {
                    let _ = write!(d, ", analytic solution {a:?}");
                }
                (
                    Kind::Scene {
                        scene: Box::new(scene),
                        initial_velocity: *initial_velocity,
                        drive: *drive,
                        initial_temperature: *initial_temperature,
                    },
                    exact,
                    periods,
                    text,
                    d,
                )
            }
        };
        let hash = content_hash(&format!(
            "{}|{}|{end_time}|{}|{source_text}",
            super::store::REPORT_VERSION,
            ron_text(&case.source),
            spec.flip
        ));
        out.push(Prepared {
            name: case.name.clone(),
            kind,
            end_time,
            dt,
            reference_dt,
            metric: case.metric,
            integrators,
            exact,
            periods,
            hash,
            description,
        });
    }
    Ok(out)
}

/// The outcome of one simulation.
struct Simulated {
    initial: ParticleState,
    last: ParticleState,
    steps: u64,
    wall_seconds: f64,
    failure: Option<String>,
}

fn simulate(
    case: &Prepared,
    integrator: &IntegratorConfig,
    flip: Real,
    dt: f64,
    mut progress: impl FnMut(f64),
) -> Simulated {
    let steps = whole_steps(case.end_time, dt).unwrap_or(1);
    match &case.kind {
        Kind::Particle(p) => {
            let t0 = Instant::now();
            let r = p.run(integrator, dt, steps);
            let wall_seconds = t0.elapsed().as_secs_f64();
            let initial = p.initial();
            match r {
                Ok(last) => Simulated {
                    initial,
                    last,
                    steps,
                    wall_seconds,
                    failure: None,
                },
                Err(e) => Simulated {
                    last: initial.clone(),
                    initial,
                    steps: 0,
                    wall_seconds,
                    failure: Some(e),
                },
            }
        }
        Kind::Scene {
            scene,
            initial_velocity,
            drive: grid_drive,
            initial_temperature,
        } => {
            let mut s = (**scene).clone();
            s.config.integrator = *integrator;
            s.config.integrator.flip = flip;
            // The SPEC's FLIP fraction also applies to the temperature transfer (its PIC part
            // acts per step, like the velocity's).
            if let Some(t) = s.thermal.as_mut() {
                t.config.transfer.flip = flip as f64;
            }
            s.config.time_step.mode = TimeStepMode::Fixed(dt);
            let mut app = scene_app(&s);
            let (min, max) = (s.config.domain_min, s.config.domain_max);
            if let Some(v) = initial_velocity {
                v.apply(app.world_mut(), min, max);
            }
            if let Some(t) = initial_temperature {
                t.apply(app.world_mut(), min);
            }
            if let Some(GridDrive::ShearBands { rate, width }) = grid_drive {
                let w = width * s.config.dx;
                app.insert_resource(ShearBandDrive {
                    rate: *rate,
                    center: 0.5 * (min.y + max.y),
                    below: min.y + w,
                    above: max.y - w,
                });
                app.add_systems(
                    crate::step::schedule::MpmStep,
                    (
                        drive_shear_bands_transferred
                            .after(MpmSystems::ParticleToGrid)
                            .before(MpmSystems::Kinematics),
                        drive_shear_bands
                            .after(MpmSystems::GridUpdate)
                            .before(MpmSystems::GridToParticle),
                    ),
                );
            }
            let initial = ParticleState::capture(app.world_mut());
            let out = drive(
                &mut app,
                case.end_time,
                StepRule::Exact { dt, steps },
                u64::MAX,
                1,
                |_, _| {},
                &mut progress,
            );
            let last = ParticleState::capture(app.world_mut());
            Simulated {
                initial,
                last,
                steps: out.steps,
                wall_seconds: out.wall_seconds,
                failure: out.failure.map(|f| f.to_string()),
            }
        }
    }
}

/// Largest |value| of each norm of a state against its initial state.
fn magnitudes(
    last: &ParticleState,
    initial: &ParticleState,
    periods: [Option<f64>; 3],
    kin: bool,
) -> Errors {
    let mut rest = initial.clone();
    for v in &mut rest.v {
        *v = Vec3::ZERO;
    }
    if let Some(s) = &mut rest.stress {
        for m in s {
            *m = DMat3::ZERO;
        }
    }
    if let Some(t) = &mut rest.temperature {
        t.fill(0.0);
    }
    compare(last, &rest, periods, kin)
}

fn state_frame(s: &ParticleState, time: f64) -> ParticleFrame {
    let mut f = ParticleFrame::from_vec3(0, time, &s.x, &s.v)
        .with_field("id", s.ids.iter().map(|&i| i as f32).collect())
        .with_field("mass", s.mass.iter().map(|&m| m as f32).collect());
    if let Some(st) = &s.stress {
        for (name, (c, r)) in [
            ("sxx", (0, 0)),
            ("syy", (1, 1)),
            ("szz", (2, 2)),
            ("sxy", (1, 0)),
            ("sxz", (2, 0)),
            ("syz", (2, 1)),
        ] {
            f.push_field(name, st.iter().map(|m| m.col(c)[r] as f32).collect());
        }
    }
    if let Some(t) = &s.temperature {
        f.push_field("temperature", t.iter().map(|&v| v as f32).collect());
    }
    f
}

fn frame_state(f: &ParticleFrame) -> Option<ParticleState> {
    let ids = f.field("id")?.iter().map(|&i| i as u32).collect();
    let mass = f.field("mass")?.iter().map(|&m| m as f64).collect();
    let stress = match (
        f.field("sxx"),
        f.field("syy"),
        f.field("szz"),
        f.field("sxy"),
        f.field("sxz"),
        f.field("syz"),
    ) {
        (Some(xx), Some(yy), Some(zz), Some(xy), Some(xz), Some(yz)) => Some(
            (0..f.len())
                .map(|k| {
                    DMat3::from_cols(
                        DVec3::new(xx[k] as f64, xy[k] as f64, xz[k] as f64),
                        DVec3::new(xy[k] as f64, yy[k] as f64, yz[k] as f64),
                        DVec3::new(xz[k] as f64, yz[k] as f64, zz[k] as f64),
                    )
                })
                .collect(),
        ),
        _ => None,
    };
    Some(ParticleState {
        ids,
        mass,
        x: f.positions.iter().map(|p| Vec3::from_array(*p)).collect(),
        v: f.velocities.iter().map(|p| Vec3::from_array(*p)).collect(),
        stress,
        temperature: f
            .field("temperature")
            .map(|t| t.iter().map(|&v| v as f64).collect()),
    })
}

/// Runs an accuracy SPEC (see the module docs); resumes from results already in
/// `opts.out_dir`.
pub fn run_accuracy(spec_path: &Path, opts: &ReportOptions) -> Result<AccuracyReport, ReportError> {
    let (spec, _) = load_accuracy_spec(spec_path)?;
    let base = spec_path.parent().unwrap_or(Path::new("."));
    let cases = prepare(&spec, base, opts.quick)?;
    std::fs::create_dir_all(&opts.out_dir)
        .map_err(|e| OutputError::io("create directory", &opts.out_dir, e))?;
    let store = RunStore::new(&opts.out_dir);
    store.ensure()?;
    let total: u64 = cases
        .iter()
        .map(|c| (c.integrators.len() * (c.dt.len() + 1)) as u64)
        .sum();
    let bar = progress_bar(total, opts.progress);
    let mut report = AccuracyReport {
        out_dir: opts.out_dir.clone(),
        runs: Vec::new(),
        simulated: 0,
        resumed: 0,
        orders: Vec::new(),
        files: Vec::new(),
    };
    let mut agreement: HashMap<String, Vec<(String, Errors)>> = HashMap::new();
    for case in &cases {
        let kin = !matches!(case.kind, Kind::Particle(_));
        let mut references: Vec<(String, ParticleState)> = Vec::new();
        for &ii in &case.integrators {
            let integ = &spec.integrators[ii];
            let base_id = format!("{}__{}", case.name, integ.name);
            let ref_hash = content_hash(&format!(
                "{}|{}|{}",
                case.hash,
                ron_text(&integ.config),
                case.reference_dt
            ));
            // The reference run (or its stored result and state).
            let ref_id = format!("{base_id}__reference");
            let ref_state_path = store.side_file(&ref_id, "ply");
            bar.set_message(format!(
                "{} · {} · reference Δt = {:e}",
                case.name, integ.name, case.reference_dt
            ));
            let stored: Option<AccuracyRun> = store.load(&ref_id, ref_hash);
            let loaded_state = stored
                .as_ref()
                .filter(|r| r.status == "ok")
                .and_then(|_| read_ply(&ref_state_path).ok())
                .and_then(|f| frame_state(&f));
            let (ref_run, ref_state) = match (stored, loaded_state) {
                (Some(run), state) if run.status != "ok" || state.is_some() => {
                    report.resumed += 1;
                    (run, state)
                }
                _ => {
                    let msg = format!("{} · {} · reference", case.name, integ.name);
                    let sim = simulate(case, &integ.config, spec.flip, case.reference_dt, |f| {
                        bar.set_message(format!("{msg} {:.0} %", 100.0 * f))
                    });
                    let (run, ok) =
                        run_record(case, &integ.name, spec.flip, case.reference_dt, &sim, None);
                    if ok {
                        write_ply(&ref_state_path, &state_frame(&sim.last, case.end_time))?;
                    }
                    store.save(&ref_id, ref_hash, &run)?;
                    report.simulated += 1;
                    (run, ok.then_some(sim.last))
                }
            };
            bar.inc(1);
            report.runs.push(ref_run.clone());
            if let Some(s) = &ref_state {
                references.push((integ.name.clone(), s.clone()));
            }
            // The ladder.
            for &dt in &case.dt {
                let id = format!("{base_id}__dt_{dt:e}");
                let hash = content_hash(&format!("{ref_hash}|{dt}"));
                if let Some(run) = store.load::<AccuracyRun>(&id, hash) {
                    report.resumed += 1;
                    report.runs.push(run);
                    bar.inc(1);
                    continue;
                }
                let msg = format!("{} · {} · Δt = {dt:e}", case.name, integ.name);
                bar.set_message(msg.clone());
                let sim = simulate(case, &integ.config, spec.flip, dt, |f| {
                    bar.set_message(format!("{msg} {:.0} %", 100.0 * f))
                });
                let (run, _) = run_record(
                    case,
                    &integ.name,
                    spec.flip,
                    dt,
                    &sim,
                    Some(ref_state.as_ref()),
                );
                store.save(&id, hash, &run)?;
                report.simulated += 1;
                report.runs.push(run);
                bar.inc(1);
            }
        }
        // How far apart the integrators' references are (they should agree to well below the
        // ladder errors for the work-precision comparison to be fair).
        if let Some((first, r0)) = references.first() {
            let list = references
                .iter()
                .skip(1)
                .map(|(name, r)| {
                    (
                        format!("{name} vs {first}"),
                        compare(r, r0, case.periods, kin),
                    )
                })
                .collect();
            agreement.insert(case.name.clone(), list);
        }
    }
    bar.finish_and_clear();
    write_outputs(&spec, spec_path, &cases, &agreement, opts, &mut report)?;
    Ok(report)
}

/// The `integrators` of a SPEC: names non-empty, unique and not in `reserved`; GS4
/// parameters valid. Shared by the accuracy and stability SPECs.
pub(crate) fn validate_integrators(
    integrators: &[IntegratorSpec],
    reserved: &[&str],
    issues: &mut Vec<FieldIssue>,
) {
    for (i, integ) in integrators.iter().enumerate() {
        if integ.name.trim().is_empty() || reserved.contains(&integ.name.as_str()) {
            let mut rule = String::from("must not be empty");
            for r in reserved {
                rule.push_str(&format!(
                    " or `{r}` (reserved for the scene's own settings)"
                ));
            }
            issues.push(FieldIssue::new(format!("integrators[{i}].name"), rule));
        }
        if integrators[..i].iter().any(|o| o.name == integ.name) {
            issues.push(FieldIssue::new(
                format!("integrators[{i}].name"),
                format!("`{}` is used twice; names must be unique", integ.name),
            ));
        }
        if let Err(e) = Gs4Params::new(integ.config.rho_inf, integ.config.rho_s) {
            issues.push(FieldIssue::new(
                format!("integrators[{i}].config"),
                e.to_string(),
            ));
        }
    }
}

/// The record of a finished simulation of `case` with step `dt`, and whether its final state
/// is usable (no failure, all finite): errors against the exact solution, and, for a ladder
/// run (`reference` is `Some`), against the reference state (`Some(None)`: the reference
/// run failed).
fn run_record(
    case: &Prepared,
    integrator: &str,
    flip: Real,
    dt: f64,
    sim: &Simulated,
    reference: Option<Option<&ParticleState>>,
) -> (AccuracyRun, bool) {
    let kin = !matches!(case.kind, Kind::Particle(_));
    let ok = sim.failure.is_none() && sim.last.is_finite();
    let vs_reference = match (reference, ok) {
        (Some(Some(r)), true) => compare(&sim.last, r, case.periods, kin),
        _ => Errors::default(),
    };
    let vs_exact = match (&case.exact, ok) {
        (Some(e), true) => compare(
            &sim.last,
            &e.state(&sim.initial, case.end_time),
            case.periods,
            kin,
        ),
        _ => Errors::default(),
    };
    let status = match (&sim.failure, ok, reference) {
        (Some(f), _, _) => format!("failed: {f}"),
        (None, false, _) => "failed: non-finite final state".into(),
        (None, true, Some(None)) => "no reference (the reference run failed)".into(),
        (None, true, _) => "ok".into(),
    };
    let run = AccuracyRun {
        case: case.name.clone(),
        integrator: integrator.to_string(),
        reference: reference.is_none(),
        dt,
        steps: sim.steps,
        end_time: case.end_time,
        reference_dt: case.reference_dt,
        flip,
        particles: sim.last.len(),
        status,
        wall_seconds: sim.wall_seconds,
        vs_reference,
        vs_exact,
        scale: if ok {
            magnitudes(&sim.last, &sim.initial, case.periods, kin)
        } else {
            Errors::default()
        },
    };
    (run, ok)
}

fn ladder_runs<'a>(report: &'a AccuracyReport, case: &str, integ: &str) -> Vec<&'a AccuracyRun> {
    let mut v: Vec<&AccuracyRun> = report
        .runs
        .iter()
        .filter(|r| r.case == case && r.integrator == integ && !r.reference)
        .collect();
    v.sort_by(|a, b| b.dt.total_cmp(&a.dt));
    v
}

const CSV_HEADER: &str = "case,integrator,kind,dt,steps,end_time,reference_dt,flip,particles,status,wall_seconds,displacement_error_ref,velocity_error_ref,stress_error_ref,temperature_error_ref,displacement_error_exact,velocity_error_exact,stress_error_exact,temperature_error_exact,displacement_scale,velocity_scale,stress_scale,temperature_scale";

fn csv_row(r: &AccuracyRun) -> String {
    let e = |x: &Errors| {
        [
            num(x.displacement),
            num(x.velocity),
            num(x.stress),
            num(x.temperature),
        ]
        .join(",")
    };
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        csv_field(&r.case),
        csv_field(&r.integrator),
        if r.reference { "reference" } else { "ladder" },
        num(Some(r.dt)),
        r.steps,
        num(Some(r.end_time)),
        num(Some(r.reference_dt)),
        num(Some(r.flip as f64)),
        r.particles,
        csv_field(&r.status),
        num(Some(r.wall_seconds)),
        e(&r.vs_reference),
        e(&r.vs_exact),
        e(&r.scale)
    )
}

fn flip_text(flip: Real) -> String {
    if flip == 1.0 {
        "pure FLIP (α_F = 1)".into()
    } else if flip == 0.0 {
        "pure PIC (α_F = 0)".into()
    } else {
        format!("PIC/FLIP blend α_F = {flip} (a PIC fraction spoils temporal convergence)")
    }
}

fn write_outputs(
    spec: &AccuracySpec,
    spec_path: &Path,
    cases: &[Prepared],
    agreement: &HashMap<String, Vec<(String, Errors)>>,
    opts: &ReportOptions,
    report: &mut AccuracyReport,
) -> Result<(), ReportError> {
    let out = &opts.out_dir;
    super::write_csv(
        out,
        "accuracy.csv",
        CSV_HEADER,
        report.runs.iter().map(csv_row),
        &mut report.files,
    )?;

    // Markdown.
    let title = super::report_title(&spec.title, "Accuracy", spec_path);
    let mut md = String::new();
    let _ = writeln!(md, "# {title}\n");
    let _ = writeln!(
        md,
        "Generated by `treacle report accuracy {}{}` (treacle {}). {} runs ({} simulated now, {} reused from an earlier report in this folder).\n",
        spec_path.display(),
        if opts.quick { " --quick" } else { "" },
        env!("CARGO_PKG_VERSION"),
        report.runs.len(),
        report.simulated,
        report.resumed
    );
    let _ = writeln!(md, "## How to read it\n");
    let _ = writeln!(
        md,
        "* **Transfer:** every run uses {}. PIC damping acts once per transfer, not per unit time, so a PIC fraction adds an error that grows as Δt shrinks and would spoil the temporal orders.",
        flip_text(spec.flip)
    );
    let _ = writeln!(
        md,
        "* **Runs:** fixed Δt (`TimeStepMode::Fixed`), exactly end time / Δt steps each. Each integrator's *reference* run uses the case's reference Δt with the same scene, grid and transfer: the error against it is the **temporal error** of that integrator; the error against the analytic solution (where the case has one) is the **total error** (temporal + spatial)."
    );
    let _ = writeln!(
        md,
        "* **Norms** ([Su21] §7.1.3): displacement and velocity errors are mass-weighted RMS over the particles, √(Σ mₚ|xₚ − x̂ₚ|²/Σ mₚ) (periodic axes wrapped); the stress error is the largest component of σᴺᴸ − σ̂ᴺᴸ over the particles (the measure of ALGORITHM §9 S1); the temperature error (scenes with heat) is the mass-weighted RMS of Tₚ − T̂ₚ, the L2 norm over the particles. Norms that are identically 0 in a case (e.g. displacement and velocity of a heat case at rest) are not shown."
    );
    let _ = writeln!(
        md,
        "* **Observed order:** least-squares slope of log(error) against log(Δt) on the asymptotic part of the ladder: points at the small-Δt end whose error falls by less than Δt^{} are dropped as round-off floor; the window is then the longest run of consecutive ladder points whose local slopes all lie within {} % of the run's least-squares slope (ties: the best-agreeing run, then the one at smaller Δt). Points left out at large Δt are pre-asymptotic, at small Δt contaminated by round-off or by the reference's own error. The window used is given as `n pts, Δt range`.",
        super::fit::FLOOR_SLOPE,
        100.0 * super::fit::WINDOW_TOLERANCE
    );
    let _ = writeln!(
        md,
        "* **Work-precision:** for each error level (of the case's metric, temporal error), the wall time each integrator needs, interpolated linearly in log(wall time)–log(error) between the two ladder runs that bracket the level (`≤ t` when even the cheapest run is more accurate, `–` when no run reaches it). Wall times are of this machine and of one run each; differences below ~20 % are noise.\n"
    );
    for case in cases {
        write_case(&mut md, spec, case, agreement, out, report)?;
    }
    let md_path = out.join("summary.md");
    crate::output::write_atomic(&md_path, md.as_bytes())?;
    report.files.push(md_path);
    check_text_outputs(out)?;
    Ok(())
}

/// The summary section of one case: set-up, run table, fitted orders, reference agreement,
/// work-precision comparison and plots (written to `out`, listed in `report.files`).
fn write_case(
    md: &mut String,
    spec: &AccuracySpec,
    case: &Prepared,
    agreement: &HashMap<String, Vec<(String, Errors)>>,
    out: &Path,
    report: &mut AccuracyReport,
) -> Result<(), ReportError> {
    let _ = writeln!(md, "## Case `{}`\n", case.name);
    let _ = writeln!(md, "{}.\n", case.description);
    let _ = writeln!(
        md,
        "End time {} s; ladder Δt = {} s; **reference Δt = {} s**; transfer {}; fitted metric: {}.\n",
        short(Some(case.end_time)),
        case.dt
            .iter()
            .map(|d| short(Some(*d)))
            .collect::<Vec<_>>()
            .join(", "),
        short(Some(case.reference_dt)),
        flip_text(spec.flip),
        case.metric.short()
    );
    let metrics: Vec<Metric> = Metric::ALL
        .into_iter()
        // Norms that are identically 0 (the particles of a heat case stay at rest) are
        // left out: they have no order and no place on a log scale.
        .filter(|m| {
            report
                .runs
                .iter()
                .any(|r| r.case == case.name && m.of(&r.vs_reference).is_some_and(|e| e > 0.0))
        })
        .collect();
    case_run_table(md, spec, case, &metrics, report);
    case_orders(md, spec, case, &metrics, report);
    // Reference agreement.
    if let Some(list) = agreement.get(&case.name).filter(|l| !l.is_empty()) {
        let _ = writeln!(
            md,
            "\nDistance between the integrators' reference runs ({}): {}. The work-precision comparison is fair where these are well below the errors compared.",
            case.metric.short(),
            list.iter()
                .map(|(n, e)| format!("{n}: {}", short(case.metric.of(e))))
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    case_work_precision(md, spec, case, report);
    case_plots(md, spec, case, &metrics, out, report)
}

/// The run table of one case: one row per integrator and Δt.
fn case_run_table(
    md: &mut String,
    spec: &AccuracySpec,
    case: &Prepared,
    metrics: &[Metric],
    report: &AccuracyReport,
) {
    // Run table.
    let _ = writeln!(
        md,
        "| integrator | Δt [s] | steps | wall [s] | {} | {} | status |",
        metrics
            .iter()
            .map(|m| format!("{} (ref)", m.short()))
            .collect::<Vec<_>>()
            .join(" | "),
        metrics
            .iter()
            .map(|m| format!("{} (exact)", m.short()))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(
        md,
        "|---|---|---|---|{}{}---|",
        "---|".repeat(metrics.len()),
        "---|".repeat(metrics.len())
    );
    for &ii in &case.integrators {
        let name = &spec.integrators[ii].name;
        let mut runs: Vec<&AccuracyRun> = report
            .runs
            .iter()
            .filter(|r| r.case == case.name && &r.integrator == name)
            .collect();
        runs.sort_by(|a, b| b.dt.total_cmp(&a.dt));
        for r in runs {
            let status = if r.status == "ok" {
                if r.reference {
                    "reference".to_string()
                } else {
                    "ok".to_string()
                }
            } else {
                r.status.replace('|', "/")
            };
            let _ = writeln!(
                md,
                "| {} | {} | {} | {} | {} | {} | {} |",
                name,
                short(Some(r.dt)),
                r.steps,
                short(Some(r.wall_seconds)),
                metrics
                    .iter()
                    .map(|m| short(m.of(&r.vs_reference)))
                    .collect::<Vec<_>>()
                    .join(" | "),
                metrics
                    .iter()
                    .map(|m| short(m.of(&r.vs_exact)))
                    .collect::<Vec<_>>()
                    .join(" | "),
                status
            );
        }
    }
}

/// The fitted orders of one case, against the reference and the analytic solution.
fn case_orders(
    md: &mut String,
    spec: &AccuracySpec,
    case: &Prepared,
    metrics: &[Metric],
    report: &mut AccuracyReport,
) {
    // Orders.
    // Orders: against the reference (temporal error) and, where the case has an analytic
    // solution, against it (total error: its slope flattens where the spatial error
    // dominates, and equals the temporal order where the set-up has none).
    let mut columns: Vec<(Metric, bool)> = metrics.iter().map(|&m| (m, false)).collect();
    for &m in metrics {
        if report
            .runs
            .iter()
            .any(|r| r.case == case.name && !r.reference && m.of(&r.vs_exact).is_some())
        {
            columns.push((m, true));
        }
    }
    let _ = writeln!(
        md,
        "\nObserved order (slope on the asymptotic part; **bold**: the case's metric against the reference, i.e. the temporal order):\n"
    );
    let _ = writeln!(
        md,
        "| integrator | {} |",
        columns
            .iter()
            .map(|(m, exact)| format!(
                "{} vs {}",
                m.short(),
                if *exact { "exact" } else { "reference" }
            ))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(md, "|---|{}", "---|".repeat(columns.len()));
    for &ii in &case.integrators {
        let name = &spec.integrators[ii].name;
        let runs: Vec<AccuracyRun> = ladder_runs(report, &case.name, name)
            .into_iter()
            .cloned()
            .collect();
        let mut cells = Vec::new();
        for &(m, exact) in &columns {
            let pts: Vec<LadderPoint> = runs
                .iter()
                .filter_map(|r| {
                    m.of(if exact { &r.vs_exact } else { &r.vs_reference })
                        .map(|e| LadderPoint { dt: r.dt, error: e })
                })
                .collect();
            let fit = fit_order(&pts);
            report.orders.push(FittedOrder {
                case: case.name.clone(),
                integrator: name.clone(),
                metric: m,
                against_exact: exact,
                fit,
            });
            let bold = m == case.metric && !exact;
            cells.push(match fit {
                Some(f) => format!(
                    "{}{:.2}{} ({} pts, Δt {}–{})",
                    if bold { "**" } else { "" },
                    f.order,
                    if bold { "**" } else { "" },
                    f.points,
                    short(Some(f.dt_min)),
                    short(Some(f.dt_max))
                ),
                None => "–".into(),
            });
        }
        let _ = writeln!(md, "| {} | {} |", name, cells.join(" | "));
    }
}

/// The work-precision comparison of one case's integrators.
fn case_work_precision(
    md: &mut String,
    spec: &AccuracySpec,
    case: &Prepared,
    report: &AccuracyReport,
) {
    // Work-precision.
    let per_integ: Vec<(String, Vec<(f64, f64)>)> = case
        .integrators
        .iter()
        .map(|&ii| {
            let name = spec.integrators[ii].name.clone();
            let pts = ladder_runs(report, &case.name, &name)
                .iter()
                .filter_map(|r| case.metric.of(&r.vs_reference).map(|e| (r.wall_seconds, e)))
                .collect();
            (name, pts)
        })
        .collect();
    let ranges: Vec<(f64, f64)> = per_integ
        .iter()
        .filter(|(_, p)| !p.is_empty())
        .map(|(_, p)| {
            let lo = p.iter().map(|x| x.1).fold(f64::INFINITY, f64::min);
            let hi = p.iter().map(|x| x.1).fold(0.0, f64::max);
            (lo, hi)
        })
        .collect();
    let levels = if spec.error_levels.is_empty() {
        error_levels(&ranges, 3)
    } else {
        spec.error_levels.clone()
    };
    if per_integ.len() > 1 && !levels.is_empty() {
        let _ = writeln!(
            md,
            "\nWork-precision ({}, temporal error): wall time to reach each level [s]\n",
            case.metric.label()
        );
        let _ = writeln!(
            md,
            "| level | {} | fastest |",
            per_integ
                .iter()
                .map(|p| p.0.as_str())
                .collect::<Vec<_>>()
                .join(" | ")
        );
        let _ = writeln!(md, "|---|{}---|", "---|".repeat(per_integ.len()));
        for level in levels {
            let reach: Vec<Reach> = per_integ
                .iter()
                .map(|(_, p)| time_to_reach(p, level))
                .collect();
            let best = reach
                .iter()
                .enumerate()
                .filter_map(|(i, r)| r.seconds().map(|s| (i, s)))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let cells: Vec<String> = reach
                .iter()
                .map(|r| match *r {
                    Reach::Interpolated(s) => match best {
                        Some((_, b)) if b > 0.0 => {
                            format!("{} (×{:.2})", short(Some(s)), s / b)
                        }
                        _ => short(Some(s)),
                    },
                    Reach::AtMost(s) => format!("≤ {}", short(Some(s))),
                    Reach::NotReached => "–".into(),
                })
                .collect();
            let fastest = best
                .map(|(i, _)| per_integ[i].0.clone())
                .unwrap_or_else(|| "none".into());
            let _ = writeln!(
                md,
                "| {} | {} | {} |",
                short(Some(level)),
                cells.join(" | "),
                fastest
            );
        }
    }
}

/// The error-against-Δt and error-against-time plots of one case.
fn case_plots(
    md: &mut String,
    spec: &AccuracySpec,
    case: &Prepared,
    metrics: &[Metric],
    out: &Path,
    report: &mut AccuracyReport,
) -> Result<(), ReportError> {
    // Plots.
    let stem = file_stem(&case.name);
    let mut panels = Vec::new();
    for &m in metrics {
        let mut series = Vec::new();
        for (k, &ii) in case.integrators.iter().enumerate() {
            let name = &spec.integrators[ii].name;
            let runs = ladder_runs(report, &case.name, name);
            let colour = PALETTE[k % PALETTE.len()];
            series.push(Series {
                label: name.clone(),
                colour,
                points: runs
                    .iter()
                    .filter_map(|r| m.of(&r.vs_reference).map(|e| (r.dt, e)))
                    .collect(),
                dashed: false,
            });
            let exact: Vec<(f64, f64)> = runs
                .iter()
                .filter_map(|r| m.of(&r.vs_exact).map(|e| (r.dt, e)))
                .collect();
            if !exact.is_empty() {
                series.push(Series {
                    label: format!("{name} vs exact"),
                    colour,
                    points: exact,
                    dashed: true,
                });
            }
        }
        panels.push(Panel {
            title: format!("{} vs reference (solid), vs exact (dashed)", m.short()),
            x_label: "Δt [s]".into(),
            y_label: m.label().into(),
            series,
            guides: vec![1.0, 2.0],
        });
    }
    if !panels.is_empty() {
        let path = out.join(format!("{stem}_error_vs_dt.png"));
        draw_log_log(
            &path,
            &format!(
                "{}: error against Δt (reference Δt = {} s, {})",
                case.name,
                short(Some(case.reference_dt)),
                flip_text(spec.flip)
            ),
            &panels,
            600 * panels.len() as u32,
            720,
        )?;
        let _ = writeln!(
            md,
            "\n![{} error against Δt]({})",
            case.name,
            path.file_name().unwrap_or_default().to_string_lossy()
        );
        report.files.push(path);
        let wp_panels: Vec<Panel> = metrics
            .iter()
            .map(|&m| Panel {
                title: format!("{} vs reference", m.short()),
                x_label: "wall time [s]".into(),
                y_label: m.label().into(),
                series: case
                    .integrators
                    .iter()
                    .enumerate()
                    .map(|(k, &ii)| {
                        let name = &spec.integrators[ii].name;
                        Series {
                            label: name.clone(),
                            colour: PALETTE[k % PALETTE.len()],
                            points: ladder_runs(report, &case.name, name)
                                .iter()
                                .filter_map(|r| m.of(&r.vs_reference).map(|e| (r.wall_seconds, e)))
                                .collect(),
                            dashed: false,
                        }
                    })
                    .collect(),
                guides: Vec::new(),
            })
            .collect();
        let path = out.join(format!("{stem}_work_precision.png"));
        draw_log_log(
            &path,
            &format!("{}: work-precision (error against wall time)", case.name),
            &wp_panels,
            600 * wp_panels.len() as u32,
            720,
        )?;
        let _ = writeln!(
            md,
            "![{} work-precision]({})\n",
            case.name,
            path.file_name().unwrap_or_default().to_string_lossy()
        );
        report.files.push(path);
    } else {
        let _ = writeln!(
            md,
            "\nNo errors to plot (every run failed or had no reference).\n"
        );
    }
    Ok(())
}

/// Periodic axes of a scene's walls: domain length of each periodic axis.
pub fn periodic_lengths(scene: &Scene) -> [Option<f64>; 3] {
    let c = &scene.config;
    [0, 1, 2].map(|a| {
        (matches!(c.walls.face(a, false), BoundaryCondition::Periodic)
            && matches!(c.walls.face(a, true), BoundaryCondition::Periodic))
        .then(|| (c.domain_max[a] - c.domain_min[a]) as f64)
    })
}
