//! `treacle report stability SPEC`: a catalogue of stiff and extreme cases, each run unattended
//! to its end time or to a detected failure ([`SimulationStatus::failure`](crate::failure::SimulationStatus)).
//!
//! A SPEC ([`StabilitySpec`], format in `docs/reports.md`) lists **families**; a family expands
//! into the cases scenes × parameter values × integrators × time-step choices, where
//!
//! * the parameter ([`Knob`]) is set on the loaded scene in code (viscosity, sound speed,
//!   impact speed, XPP anisotropy α, elasto-plastic Young's modulus E, the shear modulus G_s
//!   of a phase-change solid);
//! * the time step is either the scene's own rule ([`TimeStepChoice::Adaptive`]) or fixed at a
//!   multiple of the **predicted limit** of ALGORITHM §7.2 for the initial state
//!   ([`TimeStepChoice::Limit`]): the start-up rate evaluation runs first, then
//!   [`time_step_limits`](crate::step::monitor::time_step_limits) (kept by the monitor in
//!   [`SimulationClock::predicted_limit`](crate::step::schedule::SimulationClock)) gives the limit
//!   without the safety factor.
//!
//! # Outcome of a case
//!
//! * **finished**: reached the end time with bounded energy;
//! * **stopped**: the failure monitor stopped it with a diagnostic (step, particle, quantity,
//!   suggested Δt);
//! * **silent blow-up**: not stopped, but the energy or the speed grew beyond what the loads
//!   can explain: kinetic energy growth minus the work done by gravity,
//!   ΔE = (KE(t) − KE(0)) − Σₚ mₚ g·(xₚ(t) − xₚ(0)), above `energy_tolerance` × (KE(0) + max|W_g|)
//!   (a stable run of a dissipative liquid, at rest density and stress-free at t = 0, has
//!   ΔE ≤ 0: elastic and compression energies are non-negative); or a speed above
//!   2 (|v₀|max + √(2|g|H) + |v_collider|max) (H the domain extent along gravity). The energy
//!   test is skipped for scenes with moving colliders (their work is not measured);
//! * **incomplete**: the report's step budget ran out first;
//! * **panic**: the run panicked (caught; a bug).
//!
//! Per case the report also gives steps, Δt min/max, mass drift (against the initial mass plus
//! what emitters added) and volume drift (grid volume per unit mass, \[Su21\] §7.1.2, largest
//! |(V/M)/(V₀/M₀) − 1| over the samples), max speed, wall time, and a NaN check of
//! the written output: the case's first and last healthy particle states (PLY) and its
//! `metrics.csv` are read back and checked for non-finite numbers (the PLY files are deleted
//! afterwards unless `keep_frames`).
//!
//! Output: `stability.csv` (one row per case), `summary.md` (per family: the Δt ratio at which
//! instability actually began against the §7.2 prediction), `stability_map.png`.
use std::collections::HashMap;
use std::fmt::Write as _;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::*;
use serde::{Deserialize, Serialize};

use super::accuracy::IntegratorSpec;
use super::drive::{StepRule, drive};
use super::plots::{MapMark, MapPanel, draw_stability_map};
use super::store::{REPORT_VERSION, RunStore, content_hash, csv_field, file_stem, num, short};
use super::{ReportError, ReportOptions, check_text_outputs, load_spec, progress_bar, ron_text};
use crate::components::{Mass, Particle, Position};
use crate::config::TimeStepMode;
use crate::diagnostics::measure;
use crate::math::{Real, Vec3};
use crate::output::{
    MetricsRow, MetricsWriter, OutputError, OutputFormat, read_frame, write_frame,
};
use crate::rheology::{Li2024ElastoPlastic, Su2021Unified};
use crate::runner::{scene_app, snapshot};
use crate::scene::{FieldIssue, ModelSpec, OutputField, Scene, load_scene};
use crate::step::schedule::SimulationClock;

/// A SPEC of `treacle report stability` (RON, `StabilitySpec(...)`; `docs/reports.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, rename = "StabilitySpec")]
pub struct StabilitySpec {
    /// Title of the summary. Default empty (the SPEC's file name is used).
    #[serde(default)]
    pub title: String,
    /// Integrators families may name. Default empty: every case runs with its scene's own
    /// integrator settings.
    #[serde(default)]
    pub integrators: Vec<IntegratorSpec>,
    /// Relative energy growth beyond the work of gravity that counts as a blow-up. Default 0.05.
    #[serde(default = "default_energy_tolerance")]
    pub energy_tolerance: f64,
    /// The families of cases; at least one.
    pub families: Vec<Family>,
}

fn default_energy_tolerance() -> f64 {
    0.05
}

/// A family of cases: scenes × values × integrators × time steps.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Family {
    /// Name (unique).
    pub name: String,
    /// What the family probes (copied into the summary). Default empty.
    #[serde(default)]
    pub description: String,
    /// Scene files, relative to the SPEC's folder; at least one.
    pub scenes: Vec<String>,
    /// Simulated time of every case \[s\]. Default: each scene's duration.
    #[serde(default)]
    pub end_time: Option<f64>,
    /// The parameter swept over `values`. Default none (one case per scene).
    #[serde(default)]
    pub parameter: Option<Knob>,
    /// Values of `parameter` (in its unit). Required with a parameter.
    #[serde(default)]
    pub values: Vec<f64>,
    /// Time-step choices. Default `[Adaptive]`.
    #[serde(default = "default_time_steps")]
    pub time_steps: Vec<TimeStepChoice>,
    /// Integrator names (from the SPEC's `integrators`). Default empty: the scene's own.
    #[serde(default)]
    pub integrators: Vec<String>,
    /// Largest number of steps of one case (a safety net; ran out = "incomplete").
    /// Default 200 000.
    #[serde(default = "default_max_steps")]
    pub max_steps: u64,
    /// The quick (CI) subset; families without one are left out of `--quick`.
    #[serde(default)]
    pub quick: Option<FamilyQuick>,
}

fn default_time_steps() -> Vec<TimeStepChoice> {
    vec![TimeStepChoice::Adaptive]
}

fn default_max_steps() -> u64 {
    200_000
}

/// The quick subset of a family: each list replaces the family's when non-empty.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FamilyQuick {
    /// Scenes. Default: the family's.
    #[serde(default)]
    pub scenes: Vec<String>,
    /// Values. Default: the family's.
    #[serde(default)]
    pub values: Vec<f64>,
    /// Time steps. Default: the family's.
    #[serde(default)]
    pub time_steps: Vec<TimeStepChoice>,
    /// End time \[s\]. Default: the family's.
    #[serde(default)]
    pub end_time: Option<f64>,
}

/// A parameter set on the loaded scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Knob {
    /// Dynamic viscosity μ \[Pa·s\] of every material (and of every model that takes the
    /// material's).
    Viscosity,
    /// Sound speed c₀ \[m/s\] of every material.
    SoundSpeed,
    /// Speed \[m/s\] of every body's initial velocity (direction kept; along gravity for a body
    /// at rest).
    ImpactSpeed,
    /// Anisotropy α of every `Su2021Unified` model.
    Anisotropy,
    /// Young's modulus E \[Pa\] of every `Li2024ElastoPlastic` model.
    YoungsModulus,
    /// Shear modulus G_s \[Pa\] of the neo-Hookean solid phase of every `phase_change` entry
    /// (ALGORITHM §4.2).
    SolidShearModulus,
}

impl Knob {
    fn label(self) -> &'static str {
        match self {
            Knob::Viscosity => "viscosity μ [Pa·s]",
            Knob::SoundSpeed => "sound speed c₀ [m/s]",
            Knob::ImpactSpeed => "impact speed [m/s]",
            Knob::Anisotropy => "anisotropy α",
            Knob::YoungsModulus => "Young's modulus E [Pa]",
            Knob::SolidShearModulus => "solid shear modulus G_s [Pa]",
        }
    }

    fn short(self) -> &'static str {
        match self {
            Knob::Viscosity => "mu",
            Knob::SoundSpeed => "c0",
            Knob::ImpactSpeed => "v",
            Knob::Anisotropy => "alpha",
            Knob::YoungsModulus => "E",
            Knob::SolidShearModulus => "Gs",
        }
    }

    /// Why the knob does not apply to `scene`, if it does not.
    pub fn check(self, scene: &Scene) -> Option<&'static str> {
        let has = |f: fn(&ModelSpec) -> bool| scene.rheology.iter().any(|(_, m)| f(m));
        match self {
            Knob::Anisotropy if !has(|m| m.downcast_ref::<Su2021Unified>().is_some()) => {
                Some("Anisotropy needs a Su2021Unified model in the scene")
            }
            Knob::YoungsModulus if !has(|m| m.downcast_ref::<Li2024ElastoPlastic>().is_some()) => {
                Some("YoungsModulus needs a Li2024ElastoPlastic model in the scene")
            }
            Knob::SolidShearModulus if scene.phase_change.is_empty() => {
                Some("SolidShearModulus needs a `phase_change` entry in the scene")
            }
            _ => None,
        }
    }

    /// Sets the knob to `value` on the loaded `scene` (before its app is built).
    pub fn apply(self, scene: &mut Scene, value: f64) {
        match self {
            Knob::Viscosity => {
                for m in &mut scene.materials.list {
                    m.viscosity = value as Real;
                }
            }
            Knob::SoundSpeed => {
                for m in &mut scene.materials.list {
                    m.sound_speed = value as Real;
                }
            }
            Knob::ImpactSpeed => {
                let down = scene.config.gravity.normalize_or(Vec3::NEG_Y);
                for b in &mut scene.particles {
                    b.velocity = b.velocity.normalize_or(down) * value as Real;
                }
            }
            Knob::Anisotropy => {
                for (_, m) in &mut scene.rheology {
                    if let Some(m) = m.downcast_mut::<Su2021Unified>() {
                        m.anisotropy = value;
                    }
                }
            }
            Knob::YoungsModulus => {
                for (_, m) in &mut scene.rheology {
                    if let Some(m) = m.downcast_mut::<Li2024ElastoPlastic>() {
                        m.youngs_modulus = value;
                    }
                }
            }
            Knob::SolidShearModulus => {
                for (_, ph) in &mut scene.phase_change {
                    ph.shear_modulus = value;
                }
            }
        }
    }
}

/// How a case chooses Δt.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum TimeStepChoice {
    /// The scene's own rule (normally adaptive, ALGORITHM §2.15).
    Adaptive,
    /// A fixed Δt = factor × the predicted limit of ALGORITHM §7.2 for the initial state.
    Limit(f64),
}

impl TimeStepChoice {
    fn label(self) -> String {
        match self {
            TimeStepChoice::Adaptive => "adaptive".into(),
            TimeStepChoice::Limit(f) => format!("fixed {f}x limit"),
        }
    }
}

/// How a case ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Outcome {
    /// Reached the end time with bounded energy and speed.
    Finished,
    /// Stopped by the failure monitor with a diagnostic.
    Stopped,
    /// Energy or speed grew unboundedly without being stopped.
    SilentBlowUp,
    /// The step budget ran out first.
    Incomplete,
    /// The run panicked (caught).
    Panic,
}

impl Outcome {
    fn label(self) -> &'static str {
        match self {
            Outcome::Finished => "finished",
            Outcome::Stopped => "stopped",
            Outcome::SilentBlowUp => "silent blow-up",
            Outcome::Incomplete => "incomplete",
            Outcome::Panic => "panic",
        }
    }

    fn symbol(self) -> &'static str {
        match self {
            Outcome::Finished => "✓",
            Outcome::Stopped => "✗ stopped",
            Outcome::SilentBlowUp => "‼ silent blow-up",
            Outcome::Incomplete => "… incomplete",
            Outcome::Panic => "panic",
        }
    }

    fn mark(self) -> MapMark {
        match self {
            Outcome::Finished => MapMark::Finished,
            Outcome::Stopped => MapMark::Stopped,
            Outcome::SilentBlowUp => MapMark::SilentBlowUp,
            Outcome::Incomplete | Outcome::Panic => MapMark::Other,
        }
    }
}

/// The stored result of one case.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StabilityCase {
    /// Family name.
    pub family: String,
    /// Case name (`family/scene[/param=value]/time step[/integrator]`).
    pub name: String,
    /// Scene file as given in the SPEC.
    pub scene: String,
    /// The swept parameter's label, if any.
    pub parameter: Option<String>,
    /// Its value.
    pub value: Option<f64>,
    /// The x coordinate of the stability map: the parameter value, or 1/predicted limit.
    pub stiffness: f64,
    /// Integrator name (`scene` for the scene's own).
    pub integrator: String,
    /// `adaptive` or `fixed <f>x limit`.
    pub time_step: String,
    /// The factor f of a fixed step.
    pub ratio: Option<f64>,
    /// Predicted stable Δt for the initial state (ALGORITHM §7.2, no safety factor) \[s\].
    pub predicted_limit: Option<f64>,
    /// How it ended.
    pub outcome: Outcome,
    /// The failure diagnostic, the blow-up evidence, or the panic message.
    pub diagnostic: String,
    /// Steps taken.
    pub steps: u64,
    /// Simulated time reached \[s\].
    pub time: f64,
    /// End time \[s\].
    pub end_time: f64,
    /// Smallest Δt used \[s\].
    pub dt_min: f64,
    /// Largest Δt used \[s\].
    pub dt_max: f64,
    /// Σm(end)/(Σm(0) + emitted mass) − 1.
    pub mass_drift: Option<f64>,
    /// Mass added by the scene's emitters during the run \[kg\] (`None` without emitters).
    #[serde(default)]
    pub emitted_mass: Option<f64>,
    /// Largest |(V/M)(t)/(V/M)(0) − 1| of the grid volume per unit mass over the samples
    /// (|V(t)/V(0) − 1| at constant mass).
    pub volume_drift: Option<f64>,
    /// Largest particle speed over the samples \[m/s\].
    pub max_speed: Option<f64>,
    /// The speed bound of the blow-up test \[m/s\].
    pub speed_bound: Option<f64>,
    /// Largest (KE growth − gravity work)/(KE(0) + max|W_g|) over the samples; `None` where
    /// the energy test does not apply (moving colliders).
    pub energy_growth: Option<f64>,
    /// `ok (n files)` or what holds a non-finite number.
    pub nan_check: String,
    /// Wall time of the simulation \[s\].
    pub wall_seconds: f64,
}

/// What [`run_stability`] produced.
#[derive(Clone, Debug)]
pub struct StabilityReport {
    /// Output folder.
    pub out_dir: PathBuf,
    /// Every case, in plan order.
    pub cases: Vec<StabilityCase>,
    /// Cases simulated now.
    pub simulated: usize,
    /// Cases loaded from an earlier report in the folder.
    pub resumed: usize,
    /// Files written (CSV, markdown, PNG).
    pub files: Vec<PathBuf>,
}

/// Loads and validates a stability SPEC.
pub fn load_stability_spec(path: &Path) -> Result<(StabilitySpec, String), ReportError> {
    Ok(load_spec(path, validate)?)
}

fn validate(spec: &StabilitySpec, base: &Path) -> Vec<FieldIssue> {
    let mut issues = Vec::new();
    if !(spec.energy_tolerance > 0.0 && spec.energy_tolerance.is_finite()) {
        issues.push(FieldIssue::new(
            "energy_tolerance",
            format!("must be > 0 (got {})", spec.energy_tolerance),
        ));
    }
    super::accuracy::validate_integrators(&spec.integrators, &["scene"], &mut issues);
    if spec.families.is_empty() {
        issues.push(FieldIssue::new("families", "must list at least one family"));
    }
    let mut loaded: HashMap<String, Option<Scene>> = HashMap::new();
    for (i, fam) in spec.families.iter().enumerate() {
        let at = format!("families[{i}]");
        if fam.name.trim().is_empty() {
            issues.push(FieldIssue::new(format!("{at}.name"), "must not be empty"));
        }
        if spec.families[..i].iter().any(|o| o.name == fam.name) {
            issues.push(FieldIssue::new(
                format!("{at}.name"),
                format!("`{}` is used twice; names must be unique", fam.name),
            ));
        }
        if fam.scenes.is_empty() {
            issues.push(FieldIssue::new(
                format!("{at}.scenes"),
                "must list at least one scene",
            ));
        }
        let quick = fam.quick.clone().unwrap_or_default();
        for (field, end) in [
            ("end_time", fam.end_time),
            ("quick.end_time", quick.end_time),
        ] {
            if let Some(t) = end
                && !(t > 0.0 && t.is_finite())
            {
                issues.push(FieldIssue::new(
                    format!("{at}.{field}"),
                    format!("must be > 0 s (got {t})"),
                ));
            }
        }
        if fam.time_steps.is_empty() {
            issues.push(FieldIssue::new(
                format!("{at}.time_steps"),
                "must list at least one choice",
            ));
        }
        for (field, list) in [
            ("time_steps", &fam.time_steps),
            ("quick.time_steps", &quick.time_steps),
        ] {
            for ts in list {
                if let TimeStepChoice::Limit(f) = ts
                    && !(*f > 0.0 && f.is_finite())
                {
                    issues.push(FieldIssue::new(
                        format!("{at}.{field}"),
                        format!("Limit factors must be > 0 (got {f})"),
                    ));
                }
            }
        }
        if fam.max_steps == 0 {
            issues.push(FieldIssue::new(format!("{at}.max_steps"), "must be ≥ 1"));
        }
        match fam.parameter {
            Some(_) if fam.values.is_empty() => issues.push(FieldIssue::new(
                format!("{at}.values"),
                "a family with a parameter must list its values",
            )),
            None if !fam.values.is_empty() || !quick.values.is_empty() => issues.push(
                FieldIssue::new(format!("{at}.values"), "values need a `parameter` to set"),
            ),
            _ => {}
        }
        for (field, list) in [("values", &fam.values), ("quick.values", &quick.values)] {
            for v in list {
                if !(*v > 0.0 && v.is_finite()) {
                    issues.push(FieldIssue::new(
                        format!("{at}.{field}"),
                        format!("values must be > 0 (got {v})"),
                    ));
                }
            }
        }
        for name in &fam.integrators {
            if !spec.integrators.iter().any(|s| &s.name == name) {
                issues.push(FieldIssue::new(
                    format!("{at}.integrators"),
                    format!("unknown integrator `{name}` (not in `integrators`)"),
                ));
            }
        }
        for (field, list) in [("scenes", &fam.scenes), ("quick.scenes", &quick.scenes)] {
            for path in list {
                let entry = loaded
                    .entry(path.clone())
                    .or_insert_with(|| load_scene(&base.join(path)).ok());
                match entry {
                    None => {
                        let e = load_scene(&base.join(path))
                            .err()
                            .map(|e| e.to_string())
                            .unwrap_or_default();
                        issues.push(FieldIssue::new(
                            format!("{at}.{field}"),
                            format!("cannot load the scene `{path}`: {e}"),
                        ));
                    }
                    Some(scene) => {
                        if let Some(k) = fam.parameter
                            && let Some(why) = k.check(scene)
                        {
                            issues.push(FieldIssue::new(
                                format!("{at}.parameter"),
                                format!("{why} (`{path}` has none)"),
                            ));
                        }
                    }
                }
            }
        }
    }
    issues
}

/// One planned case.
struct Planned {
    family: usize,
    scene_path: String,
    value: Option<f64>,
    integrator: Option<usize>,
    time_step: TimeStepChoice,
    end_time: Option<f64>,
    name: String,
}

fn plan(spec: &StabilitySpec, quick: bool) -> Vec<Planned> {
    let mut out = Vec::new();
    for (fi, fam) in spec.families.iter().enumerate() {
        let q = match (&fam.quick, quick) {
            (_, false) => FamilyQuick::default(),
            (Some(q), true) => q.clone(),
            (None, true) => continue,
        };
        let pick =
            |a: &Vec<String>, b: &Vec<String>| if a.is_empty() { b.clone() } else { a.clone() };
        let scenes = pick(&q.scenes, &fam.scenes);
        let values: Vec<Option<f64>> = if fam.parameter.is_none() {
            vec![None]
        } else if q.values.is_empty() {
            fam.values.iter().map(|v| Some(*v)).collect()
        } else {
            q.values.iter().map(|v| Some(*v)).collect()
        };
        let time_steps = if q.time_steps.is_empty() {
            fam.time_steps.clone()
        } else {
            q.time_steps.clone()
        };
        let integrators: Vec<Option<usize>> = if fam.integrators.is_empty() {
            vec![None]
        } else {
            fam.integrators
                .iter()
                .filter_map(|n| spec.integrators.iter().position(|s| &s.name == n).map(Some))
                .collect()
        };
        let end_time = q.end_time.or(fam.end_time);
        for s in &scenes {
            let stem = Path::new(s)
                .file_stem()
                .map(|x| x.to_string_lossy().into_owned())
                .unwrap_or_default();
            for &value in &values {
                for &integ in &integrators {
                    for &ts in &time_steps {
                        let mut name = format!("{}/{stem}", fam.name);
                        if let (Some(k), Some(v)) = (fam.parameter, value) {
                            let _ = write!(name, "/{}={v:e}", k.short());
                        }
                        let _ = write!(
                            name,
                            "/{}",
                            match ts {
                                TimeStepChoice::Adaptive => "adaptive".to_string(),
                                TimeStepChoice::Limit(f) => format!("{f}x"),
                            }
                        );
                        if let Some(i) = integ {
                            let _ = write!(name, "/{}", spec.integrators[i].name);
                        }
                        out.push(Planned {
                            family: fi,
                            scene_path: s.clone(),
                            value,
                            integrator: integ,
                            time_step: ts,
                            end_time,
                            name,
                        });
                    }
                }
            }
        }
    }
    out
}

/// Runs a stability SPEC (see the module docs); resumes from results already in
/// `opts.out_dir`.
pub fn run_stability(
    spec_path: &Path,
    opts: &ReportOptions,
) -> Result<StabilityReport, ReportError> {
    let (spec, _) = load_stability_spec(spec_path)?;
    let base = spec_path.parent().unwrap_or(Path::new("."));
    let planned = plan(&spec, opts.quick);
    std::fs::create_dir_all(&opts.out_dir)
        .map_err(|e| OutputError::io("create directory", &opts.out_dir, e))?;
    let store = RunStore::new(&opts.out_dir);
    store.ensure()?;
    let bar = progress_bar(planned.len() as u64, opts.progress);
    let mut report = StabilityReport {
        out_dir: opts.out_dir.clone(),
        cases: Vec::new(),
        simulated: 0,
        resumed: 0,
        files: Vec::new(),
    };
    let mut scenes: HashMap<String, (Scene, String)> = HashMap::new();
    for p in &planned {
        let fam = &spec.families[p.family];
        if !scenes.contains_key(&p.scene_path) {
            let file = base.join(&p.scene_path);
            let scene = load_scene(&file)?;
            let text =
                std::fs::read_to_string(&file).map_err(|e| OutputError::io("read", &file, e))?;
            scenes.insert(p.scene_path.clone(), (scene, text));
        }
        let (scene, text) = &scenes[&p.scene_path];
        let integ = p.integrator.map(|i| &spec.integrators[i]);
        let hash = content_hash(&format!(
            "{REPORT_VERSION}|{}|{:?}|{:?}|{}|{:?}|{:?}|{}|{}|{text}",
            p.name,
            fam.parameter,
            p.value,
            integ.map(|s| ron_text(&s.config)).unwrap_or_default(),
            p.time_step,
            p.end_time,
            fam.max_steps,
            spec.energy_tolerance,
        ));
        if let Some(done) = store.load::<StabilityCase>(&p.name, hash) {
            report.resumed += 1;
            report.cases.push(done);
            bar.inc(1);
            continue;
        }
        bar.set_message(p.name.clone());
        let frames_dir = opts.out_dir.join("frames").join(file_stem(&p.name));
        let result = catch_unwind(AssertUnwindSafe(|| {
            run_case(&spec, p, scene, &frames_dir, opts.keep_frames, |f| {
                bar.set_message(format!("{} {:.0} %", p.name, 100.0 * f))
            })
        }));
        let case = match result {
            Ok(Ok(c)) => c,
            Ok(Err(e)) => return Err(e),
            Err(panic) => {
                let msg = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic payload".into());
                StabilityCase {
                    family: fam.name.clone(),
                    name: p.name.clone(),
                    scene: p.scene_path.clone(),
                    parameter: fam.parameter.map(|k| k.label().to_string()),
                    value: p.value,
                    stiffness: p.value.unwrap_or(1.0),
                    integrator: integ
                        .map(|s| s.name.clone())
                        .unwrap_or_else(|| "scene".into()),
                    time_step: p.time_step.label(),
                    ratio: match p.time_step {
                        TimeStepChoice::Limit(f) => Some(f),
                        TimeStepChoice::Adaptive => None,
                    },
                    predicted_limit: None,
                    outcome: Outcome::Panic,
                    diagnostic: format!("panicked: {msg}"),
                    steps: 0,
                    time: 0.0,
                    end_time: p.end_time.unwrap_or(scene.duration),
                    dt_min: 0.0,
                    dt_max: 0.0,
                    mass_drift: None,
                    emitted_mass: None,
                    volume_drift: None,
                    max_speed: None,
                    speed_bound: None,
                    energy_growth: None,
                    nan_check: "not run".into(),
                    wall_seconds: 0.0,
                }
            }
        };
        store.save(&p.name, hash, &case)?;
        report.simulated += 1;
        report.cases.push(case);
        bar.inc(1);
    }
    bar.finish_and_clear();
    write_outputs(&spec, spec_path, opts, &mut report)?;
    Ok(report)
}

/// Energy, speed and volume bookkeeping over the samples of one run.
///
/// Particles added during the run (emitters) enter the balance when a sample first sees them:
/// their kinetic energy then counts as energy brought in (`ke_in`) and their gravity work is
/// measured from that position. The volume drift compares the grid volume per unit mass,
/// (V/M)/(V₀/M₀) − 1, which is V/V₀ − 1 while the mass is constant and stays meaningful while
/// an emitter adds mass (M₀, V₀: the first sample with particles).
#[derive(Default)]
struct Watch {
    x0: HashMap<Entity, Vec3>,
    ke0: f64,
    ke_in: f64,
    mass0: f64,
    volume_per_mass0: f64,
    mass: f64,
    max_excess: f64,
    max_work: f64,
    max_speed: f64,
    volume_drift: f64,
    samples: u32,
}

impl Watch {
    fn sample(&mut self, world: &mut World, g: Vec3) -> crate::diagnostics::StateMetrics {
        let m = measure(world);
        let mut q = world
            .query_filtered::<(Entity, &Position, &crate::components::Velocity, &Mass), With<Particle>>();
        if self.samples == 0 {
            self.ke0 = m.kinetic_energy;
            self.mass0 = m.mass;
        }
        for (e, x, v, mass) in q.iter(world) {
            if let std::collections::hash_map::Entry::Vacant(slot) = self.x0.entry(e) {
                slot.insert(x.0);
                if self.samples > 0 {
                    self.ke_in += 0.5 * mass.0 as f64 * v.0.length_squared() as f64;
                }
            }
        }
        let gd = g.as_dvec3();
        let work: f64 = q
            .iter(world)
            .filter_map(|(e, x, _, mass)| {
                self.x0
                    .get(&e)
                    .map(|x0| mass.0 as f64 * gd.dot((x.0 - *x0).as_dvec3()))
            })
            .sum();
        self.max_work = self.max_work.max(work.abs());
        self.max_excess = self
            .max_excess
            .max(m.kinetic_energy - self.ke0 - self.ke_in - work);
        self.max_speed = self.max_speed.max(m.max_speed);
        if m.mass > 0.0 && m.volume > 0.0 {
            let vm = m.volume / m.mass;
            if self.volume_per_mass0 > 0.0 {
                self.volume_drift = self
                    .volume_drift
                    .max((vm / self.volume_per_mass0 - 1.0).abs());
            } else {
                self.volume_per_mass0 = vm;
            }
        }
        self.mass = m.mass;
        self.samples += 1;
        m
    }
}

/// Mass emitted so far by the world's [`NozzleEmitter`](crate::emit::NozzleEmitter)s \[kg\]
/// (particles × ρ₀h³, the mass each emitted particle gets), `None` without emitters.
fn emitted_mass(world: &mut World) -> Option<f64> {
    let materials = world.get_resource::<crate::material::Materials>()?.clone();
    let mut q = world.query::<(&crate::emit::NozzleEmitter, &crate::emit::EmitterState)>();
    let mut any = false;
    let mut total = 0.0;
    for (n, st) in q.iter(world) {
        any = true;
        let rho0 = materials
            .list
            .get(n.material.0 as usize)
            .map_or(0.0, |m| m.density);
        let h = n.spacing;
        total += st.particles as f64 * (h * h * h * rho0) as f64;
    }
    any.then_some(total)
}

/// The largest speed of the particles the world's emitters add \[m/s\]: extrusion speed plus
/// the fastest extruding move of the tool path (0 without emitters).
fn emitter_speed(world: &mut World) -> f64 {
    let mut q = world.query::<&crate::emit::NozzleEmitter>();
    q.iter(world)
        .map(|n| {
            let path = n
                .path
                .segments()
                .iter()
                .filter(|s| s.extrude)
                .map(|s| (s.end - s.start).length() / s.duration)
                .fold(0.0, f64::max);
            n.extrusion_speed(n.lattice().len()) + path
        })
        .fold(0.0, f64::max)
}

fn run_case(
    spec: &StabilitySpec,
    p: &Planned,
    scene: &Scene,
    frames_dir: &Path,
    keep_frames: bool,
    progress: impl FnMut(f64),
) -> Result<StabilityCase, ReportError> {
    let fam = &spec.families[p.family];
    let mut s = scene.clone();
    if let (Some(k), Some(v)) = (fam.parameter, p.value) {
        k.apply(&mut s, v);
    }
    let integ = p.integrator.map(|i| &spec.integrators[i]);
    if let Some(i) = integ {
        s.config.integrator = i.config;
    }
    let end_time = p.end_time.unwrap_or(s.duration);
    let g = s.config.gravity;
    // Speed bound of the blow-up test.
    let v0 = s
        .particles
        .iter()
        .map(|b| b.velocity.length())
        .fold(0.0, f32::max) as f64;
    let extent = (s.config.domain_max - s.config.domain_min).as_dvec3();
    let gn = g.as_dvec3().normalize_or_zero();
    let height = extent.x * gn.x.abs() + extent.y * gn.y.abs() + extent.z * gn.z.abs();
    let v_coll = s
        .colliders
        .iter()
        .filter_map(|(_, _, m, _, path)| {
            m.map(|m| {
                let path = path.as_ref().map_or(0.0, |p| p.max_speed());
                m.linear_velocity.length().max(path) as f64
            })
        })
        .fold(0.0, f64::max);
    let moving_colliders = s.colliders.iter().any(|c| c.2.is_some());

    let mut app = scene_app(&s);
    let world = app.world_mut();
    let v0 = v0.max(emitter_speed(world));
    let speed_bound = 2.0 * (v0 + (2.0 * g.length() as f64 * height).sqrt() + v_coll);
    let t0 = std::time::Instant::now();
    crate::step::driver::start(world);
    let startup_wall = t0.elapsed().as_secs_f64();
    let clock = world.resource::<SimulationClock>();
    let limit = clock.predicted_limit;
    let predicted_limit = (limit.is_finite() && limit > 0.0).then_some(limit);
    let (rule, ratio) = match (p.time_step, predicted_limit) {
        (TimeStepChoice::Adaptive, _) => (StepRule::Monitor, None),
        (TimeStepChoice::Limit(f), Some(l)) => {
            world
                .resource_mut::<crate::config::MpmConfig>()
                .time_step
                .mode = TimeStepMode::Fixed(f * l);
            (StepRule::Fixed(f * l), Some(f))
        }
        // No finite prediction (start-up failed): nothing to scale; the start-up failure is
        // reported below.
        (TimeStepChoice::Limit(f), None) => (StepRule::Monitor, Some(f)),
    };
    let stiffness = p
        .value
        .unwrap_or_else(|| predicted_limit.map(|l| 1.0 / l).unwrap_or(1.0));

    // Output: metrics.csv over the samples, first and last healthy states as PLY.
    let _ = std::fs::remove_dir_all(frames_dir);
    let mut metrics = MetricsWriter::new(frames_dir);
    let mut written: Vec<PathBuf> = Vec::new();
    let mut watch = Watch::default();
    let mut write_error: Option<OutputError> = None;
    let mut frame = 0u32;
    let mut last_snapshot: Option<crate::output::ParticleFrame> = None;
    let fields = [OutputField::Density, OutputField::Pressure];
    let sample_wall = std::cell::Cell::new(0.0f64);
    let outcome = drive(
        &mut app,
        end_time,
        rule,
        fam.max_steps,
        50,
        |world, _t| {
            let m = watch.sample(world, g);
            let c = world.resource::<SimulationClock>();
            let row = MetricsRow {
                frame,
                time: c.time,
                steps: c.steps,
                dt_min: 0.0,
                dt_max: c.next_dt.min(1e30),
                particles: m.particles,
                mass: m.mass,
                volume: m.volume,
                kinetic_energy: m.kinetic_energy,
                max_speed: m.max_speed,
                wall_seconds: sample_wall.get(),
                extra: Vec::new(),
            };
            if let Err(e) = metrics.push(row) {
                write_error.get_or_insert(e);
            }
            let snap = snapshot(world, frame, &fields);
            if frame == 0 {
                match write_frame(frames_dir, &snap, OutputFormat::Ply) {
                    Ok(p) => written.push(p),
                    Err(e) => {
                        write_error.get_or_insert(e);
                    }
                }
            }
            last_snapshot = Some(snap);
            frame += 1;
        },
        progress,
    );
    let wall_seconds = startup_wall + outcome.wall_seconds;
    let emitted = emitted_mass(app.world_mut());
    // The last healthy sample (the end state of a finished run).
    if let Some(snap) = last_snapshot.take().filter(|s| s.frame > 0) {
        match write_frame(frames_dir, &snap, OutputFormat::Ply) {
            Ok(p) => written.push(p),
            Err(e) => {
                write_error.get_or_insert(e);
            }
        }
    }
    // NaN check of everything written for the case.
    let mut bad = Vec::new();
    let mut checked = 0;
    for f in &written {
        checked += 1;
        if let Err(e) = read_frame(f) {
            bad.push(e.to_string());
        }
    }
    if let Ok(text) = std::fs::read_to_string(metrics.path()) {
        checked += 1;
        let fields = super::store::non_finite_fields(&text);
        if !fields.is_empty() {
            bad.push(format!(
                "{} at {}",
                metrics.path().display(),
                fields.join(" ")
            ));
        }
    }
    if let Some(e) = write_error {
        bad.push(format!("write failed: {e}"));
    }
    let nan_check = if bad.is_empty() {
        format!("ok ({checked} files)")
    } else {
        format!("FAILED: {}", bad.join("; "))
    };
    if !keep_frames {
        for f in &written {
            let _ = std::fs::remove_file(f);
        }
    }

    let energy_scale = watch.ke0 + watch.ke_in + watch.max_work;
    let energy_growth = (!moving_colliders && energy_scale > 0.0 && watch.samples > 1)
        .then(|| watch.max_excess / energy_scale);
    let blew_energy = energy_growth.is_some_and(|e| e > spec.energy_tolerance);
    let blew_speed = watch.max_speed > speed_bound;
    let (outcome_kind, diagnostic) = if let Some(f) = &outcome.failure {
        (Outcome::Stopped, f.to_string())
    } else if blew_energy || blew_speed {
        let mut why = Vec::new();
        if blew_energy {
            why.push(format!(
                "kinetic energy grew beyond the work of gravity by {} × (KE₀ + largest gravity work) (tolerance {})",
                short(energy_growth),
                spec.energy_tolerance
            ));
        }
        if blew_speed {
            why.push(format!(
                "max speed {} m/s above the bound {} m/s",
                short(Some(watch.max_speed)),
                short(Some(speed_bound))
            ));
        }
        (
            Outcome::SilentBlowUp,
            format!("not detected by the monitor: {}", why.join("; ")),
        )
    } else if outcome.budget_exhausted {
        (
            Outcome::Incomplete,
            format!(
                "step budget of {} steps ran out at t = {} s",
                fam.max_steps,
                short(Some(outcome.time))
            ),
        )
    } else {
        (Outcome::Finished, String::new())
    };
    let diagnostic = if nan_check.starts_with("FAILED") {
        format!("{diagnostic} [output check {nan_check}]")
    } else {
        diagnostic
    };
    Ok(StabilityCase {
        family: fam.name.clone(),
        name: p.name.clone(),
        scene: p.scene_path.clone(),
        parameter: fam.parameter.map(|k| k.label().to_string()),
        value: p.value,
        stiffness,
        integrator: integ
            .map(|s| s.name.clone())
            .unwrap_or_else(|| "scene".into()),
        time_step: p.time_step.label(),
        ratio,
        predicted_limit,
        outcome: outcome_kind,
        diagnostic,
        steps: outcome.steps,
        time: outcome.time,
        end_time,
        dt_min: outcome.dt_min,
        dt_max: outcome.dt_max,
        mass_drift: {
            let expected = watch.mass0 + emitted.unwrap_or(0.0);
            (expected > 0.0 && watch.samples > 0).then(|| watch.mass / expected - 1.0)
        },
        emitted_mass: emitted,
        volume_drift: (watch.samples > 0).then_some(watch.volume_drift),
        max_speed: (watch.samples > 0).then_some(watch.max_speed),
        speed_bound: Some(speed_bound),
        energy_growth,
        nan_check,
        wall_seconds,
    })
}

const CSV_HEADER: &str = "family,case,scene,integrator,parameter,value,stiffness,time_step,ratio,predicted_limit,outcome,steps,time,end_time,dt_min,dt_max,mass_drift,emitted_mass,volume_drift,max_speed,speed_bound,energy_growth,nan_check,wall_seconds,diagnostic";

fn csv_row(c: &StabilityCase) -> String {
    [
        csv_field(&c.family),
        csv_field(&c.name),
        csv_field(&c.scene),
        csv_field(&c.integrator),
        csv_field(c.parameter.as_deref().unwrap_or("")),
        num(c.value),
        num(Some(c.stiffness)),
        csv_field(&c.time_step),
        num(c.ratio),
        num(c.predicted_limit),
        c.outcome.label().to_string(),
        c.steps.to_string(),
        num(Some(c.time)),
        num(Some(c.end_time)),
        num(Some(c.dt_min)),
        num(Some(c.dt_max)),
        num(c.mass_drift),
        num(c.emitted_mass),
        num(c.volume_drift),
        num(c.max_speed),
        num(c.speed_bound),
        num(c.energy_growth),
        csv_field(&c.nan_check),
        num(Some(c.wall_seconds)),
        csv_field(&c.diagnostic),
    ]
    .join(",")
}

/// "began between 2× and 4×" for one group of fixed-ratio cases.
fn onset(cases: &[&StabilityCase]) -> String {
    let mut fixed: Vec<&&StabilityCase> = cases.iter().filter(|c| c.ratio.is_some()).collect();
    fixed.sort_by(|a, b| a.ratio.unwrap_or(0.0).total_cmp(&b.ratio.unwrap_or(0.0)));
    if fixed.is_empty() {
        return "–".into();
    }
    let first_bad = fixed.iter().position(|c| c.outcome != Outcome::Finished);
    match first_bad {
        None => format!(
            "stable up to {}× (no instability in the tested range)",
            fixed
                .last()
                .and_then(|c| c.ratio)
                .map(crate::plot::format_number)
                .unwrap_or_default()
        ),
        Some(0) => format!(
            "not stable even at {}× ({})",
            crate::plot::format_number(fixed[0].ratio.unwrap_or(0.0)),
            fixed[0].outcome.label()
        ),
        Some(k) => format!(
            "between {}× and {}× ({} at {}×)",
            crate::plot::format_number(fixed[k - 1].ratio.unwrap_or(0.0)),
            crate::plot::format_number(fixed[k].ratio.unwrap_or(0.0)),
            fixed[k].outcome.label(),
            crate::plot::format_number(fixed[k].ratio.unwrap_or(0.0)),
        ),
    }
}

/// The summary section of one family (onset table and details) and its stability-map panel.
fn write_family(
    md: &mut String,
    fam: &Family,
    fam_name: &str,
    cases: &[&StabilityCase],
) -> MapPanel {
    let _ = writeln!(md, "## Family `{fam_name}`\n");
    if !fam.description.is_empty() {
        let _ = writeln!(md, "{}\n", fam.description);
    }
    // Onset table: one row per (scene, value, integrator).
    let mut groups: Vec<(String, Option<f64>, String)> = Vec::new();
    for c in cases {
        let key = (c.scene.clone(), c.value, c.integrator.clone());
        if !groups.contains(&key) {
            groups.push(key);
        }
    }
    let mut columns: Vec<String> = Vec::new();
    for c in cases {
        if !columns.contains(&c.time_step) {
            columns.push(c.time_step.clone());
        }
    }
    let param = fam.parameter.map(|k| k.label()).unwrap_or("");
    let _ = writeln!(
        md,
        "| scene | {} integrator | predicted limit [s] | {} | instability began (Δt / predicted limit) |",
        if param.is_empty() {
            String::new()
        } else {
            format!("{param} |")
        },
        columns.join(" | ")
    );
    let _ = writeln!(
        md,
        "|---|{}---|---|{}---|",
        if param.is_empty() { "" } else { "---|" },
        "---|".repeat(columns.len())
    );
    for (scene, value, integ) in &groups {
        let group: Vec<&StabilityCase> = cases
            .iter()
            .copied()
            .filter(|c| &c.scene == scene && c.value == *value && &c.integrator == integ)
            .collect();
        let limit = group.iter().find_map(|c| c.predicted_limit);
        let cells: Vec<String> = columns
            .iter()
            .map(|col| {
                group
                    .iter()
                    .find(|c| &c.time_step == col)
                    .map(|c| c.outcome.symbol().to_string())
                    .unwrap_or_default()
            })
            .collect();
        let _ = writeln!(
            md,
            "| {} | {} {} | {} | {} | {} |",
            scene,
            if param.is_empty() {
                String::new()
            } else {
                format!("{} |", short(*value))
            },
            integ,
            short(limit),
            cells.join(" | "),
            onset(&group)
        );
    }
    // The family in one line: was the prediction safe, where did instability begin first.
    let mut safe = 0usize;
    let mut tested = 0usize;
    let mut earliest: Option<(f64, String)> = None;
    for (scene, value, integ) in &groups {
        let mut fixed: Vec<&StabilityCase> = cases
            .iter()
            .copied()
            .filter(|c| {
                &c.scene == scene
                    && c.value == *value
                    && &c.integrator == integ
                    && c.ratio.is_some()
            })
            .collect();
        if fixed.is_empty() {
            continue;
        }
        fixed.sort_by(|a, b| a.ratio.unwrap_or(0.0).total_cmp(&b.ratio.unwrap_or(0.0)));
        tested += 1;
        if fixed
            .iter()
            .filter(|c| c.ratio.is_some_and(|r| r <= 1.0))
            .all(|c| c.outcome == Outcome::Finished)
        {
            safe += 1;
        }
        if let Some(bad) = fixed.iter().find(|c| c.outcome != Outcome::Finished) {
            let r = bad.ratio.unwrap_or(0.0);
            if earliest.as_ref().is_none_or(|e| r < e.0) {
                let what = match (fam.parameter, value) {
                    (Some(k), Some(v)) => format!("{} = {}", k.label(), short(Some(*v))),
                    _ => scene.clone(),
                };
                earliest = Some((r, format!("{what}, {integ}")));
            }
        }
    }
    if tested > 0 {
        let _ = writeln!(
            md,
            "\n**In short:** in {safe} of {tested} groups every fixed-Δt run at or below the predicted limit finished; {}.",
            match &earliest {
                Some((r, at)) => format!(
                    "the earliest instability was at {}× the prediction ({at})",
                    crate::plot::format_number(*r)
                ),
                None => "no fixed-Δt run became unstable".to_string(),
            }
        );
    }
    // Details.
    let _ = writeln!(
        md,
        "\n<details><summary>All {} cases of `{fam_name}`</summary>\n\n| case | outcome | steps | t [s] | Δt min [s] | Δt max [s] | mass drift | volume drift | max speed [m/s] | energy growth | NaN check | wall [s] | diagnostic |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        cases.len()
    );
    for c in cases {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            c.name,
            c.outcome.label(),
            c.steps,
            short(Some(c.time)),
            short(Some(c.dt_min)),
            short(Some(c.dt_max)),
            short(c.mass_drift),
            short(c.volume_drift),
            short(c.max_speed),
            short(c.energy_growth),
            c.nan_check,
            short(Some(c.wall_seconds)),
            c.diagnostic.replace('|', "/")
        );
    }
    let _ = writeln!(md, "\n</details>\n");
    MapPanel {
        title: fam_name.to_string(),
        x_label: fam
            .parameter
            .map(|k| k.label().to_string())
            .unwrap_or_else(|| "1 / predicted limit [1/s]".into()),
        points: cases
            .iter()
            .map(|c| {
                let y = match (c.ratio, c.predicted_limit) {
                    (Some(r), _) => r,
                    (None, Some(l)) if c.dt_max > 0.0 => c.dt_max / l,
                    _ => 0.5,
                };
                (c.stiffness, y, c.outcome.mark(), c.ratio.is_none())
            })
            .collect(),
    }
}

fn write_outputs(
    spec: &StabilitySpec,
    spec_path: &Path,
    opts: &ReportOptions,
    report: &mut StabilityReport,
) -> Result<(), ReportError> {
    let out = &opts.out_dir;
    super::write_csv(
        out,
        "stability.csv",
        CSV_HEADER,
        report.cases.iter().map(csv_row),
        &mut report.files,
    )?;
    let title = super::report_title(&spec.title, "Stability", spec_path);
    let count = |o: Outcome| report.cases.iter().filter(|c| c.outcome == o).count();
    let mut md = String::new();
    let _ = writeln!(md, "# {title}\n");
    let _ = writeln!(
        md,
        "Generated by `treacle report stability {}{}` (treacle {}). {} cases ({} simulated now, {} reused from an earlier report in this folder): **{} finished, {} stopped with a diagnostic, {} silent blow-ups, {} incomplete, {} panics.**\n",
        spec_path.display(),
        if opts.quick { " --quick" } else { "" },
        env!("CARGO_PKG_VERSION"),
        report.cases.len(),
        report.simulated,
        report.resumed,
        count(Outcome::Finished),
        count(Outcome::Stopped),
        count(Outcome::SilentBlowUp),
        count(Outcome::Incomplete),
        count(Outcome::Panic),
    );
    let _ = writeln!(md, "## How to read it\n");
    let _ = writeln!(
        md,
        "* **Predicted limit:** the stable Δt of ALGORITHM §7.2 for the initial state (after the start-up rate evaluation), without the safety factor: min{{C_adv Δx/|v|max, [2c/(Ω_crit Δx) + 8ν/(z_crit Δx²)]⁻¹, z_crit/k_relax}}. `fixed f× limit` runs use Δt = f × that limit for the whole run; `adaptive` runs use the scene's rule (safety factor included)."
    );
    let _ = writeln!(
        md,
        "* **Outcomes:** ✓ finished with bounded energy; ✗ stopped by the failure monitor (the diagnostic names step, particle, quantity and a suggested Δt); ‼ silent blow-up: not stopped, but the kinetic energy grew beyond the work done by gravity by more than {} of (KE₀ + max|W_g|), or the speed exceeded 2(|v₀| + √(2|g|H) + |v_collider|) (the energy test is skipped with moving colliders, `–`); … incomplete: step budget ran out.",
        spec.energy_tolerance
    );
    let _ = writeln!(
        md,
        "* **Drifts:** mass Σm(end)/(Σm(0) + emitted mass) − 1 (an emitter's growth is not a drift); volume: largest |(V/M)/(V₀/M₀) − 1| of the grid volume V ([Su21] §7.1.2) per unit mass over 50 samples (= |V/V₀ − 1| at constant mass). Particles an emitter adds enter the energy test when a sample first sees them (their kinetic energy counts as energy brought in). **NaN check:** the case's written files (first and last healthy particle states, metrics.csv) read back and checked for non-finite numbers.\n"
    );
    let families: Vec<&str> = spec
        .families
        .iter()
        .map(|f| f.name.as_str())
        .filter(|n| report.cases.iter().any(|c| c.family == *n))
        .collect();
    let mut panels = Vec::new();
    for fam_name in &families {
        let fam = spec
            .families
            .iter()
            .find(|f| f.name == *fam_name)
            .expect("listed");
        let cases: Vec<&StabilityCase> = report
            .cases
            .iter()
            .filter(|c| c.family == *fam_name)
            .collect();
        panels.push(write_family(&mut md, fam, fam_name, &cases));
    }
    let png = out.join("stability_map.png");
    draw_stability_map(
        &png,
        &format!("{title}: outcome by stiffness and Δt / predicted limit"),
        &panels,
    )?;
    let _ = writeln!(md, "![stability map](stability_map.png)");
    report.files.push(png);
    let md_path = out.join("summary.md");
    crate::output::write_atomic(&md_path, md.as_bytes())?;
    report.files.push(md_path);
    check_text_outputs(out)?;
    Ok(())
}
