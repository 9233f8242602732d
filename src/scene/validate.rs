//! Validation of a parsed scene, before anything is sampled or simulated.
//!
//! Every check adds a [`FieldIssue`] naming the field path, the constraint, its unit and the
//! value found; all issues are collected, not just the first. Meshes are loaded here (their
//! existence, syntax and closedness are part of validity) and handed on to sampling.
use std::collections::HashMap;
use std::fmt::Display;
use std::path::{Path, PathBuf};

use super::error::FieldIssue;
use std::sync::Arc;

use super::schema::{
    BodyShape, ColliderShapeSpec, ColliderSpec, MeshFile, OutputField, RotationSpec, SceneFile,
};
use crate::collision::{ColliderShape, MeshSdf, MeshSdfError};
use crate::config::{BoundaryCondition, TimeStepMode};
use crate::material::FluidMaterial;
use crate::math::{Real, Vec3};
use crate::mesh::TriMesh;
use crate::sampling::Lattice;
use crate::validation::SceneContext;
pub use crate::validation::{ASSETS_DIR, resolve_asset_path};

/// Largest accepted grid, in cells (2³⁰ ≈ 1.07·10⁹), so that absurd inputs fail cleanly
/// instead of exhausting memory.
pub const MAX_GRID_CELLS: f64 = (1u64 << 30) as f64;

/// Largest accepted number of particles (2²⁸ ≈ 2.7·10⁸), estimated from the bodies'
/// bounding boxes before sampling.
pub const MAX_PARTICLES: u64 = 1 << 28;

/// Largest accepted number of frames, duration × frame_rate.
pub const MAX_FRAMES: f64 = u32::MAX as f64;

/// Largest fixed-Δt step count, duration / Δt (10¹⁰: weeks of computing for the smallest
/// scene); a smaller fixed step would never reach the end.
pub const MAX_FIXED_STEPS: f64 = 1e10;

/// Headroom of the single-precision checks: a derived quantity must lie within
/// [`f32::MIN_POSITIVE`] × this … [`f32::MAX`] / this, so that the step's sums over particles
/// and nodes and its products of two such quantities stay finite and normal.
pub const SINGLE_PRECISION_HEADROOM: f64 = 1e6;

/// Largest particles-per-cell value.
pub const MAX_PARTICLES_PER_CELL: u32 = 8;

/// What validation loaded and sampling reuses.
#[derive(Clone, Debug, Default)]
pub struct LoadedAssets {
    /// Per body: its mesh in world coordinates (scaled and translated), or `None` for
    /// analytic shapes.
    pub meshes: Vec<Option<TriMesh>>,
    /// Per collider: its prepared mesh (local frame, scaled) for a `Mesh` shape, or `None`.
    /// Colliders naming the same file and scale share one [`MeshSdf`].
    pub colliders: Vec<Option<Arc<MeshSdf>>>,
}

struct Checker {
    issues: Vec<FieldIssue>,
}

/// The sections of [`validate_scene`] that need only the scene (and what earlier sections
/// found).
impl Checker {
    /// `duration` and `frame_rate`.
    fn time(&mut self, scene: &SceneFile) {
        let duration_ok = self.positive("duration", scene.duration, "s");
        let rate_ok = self.positive("frame_rate", scene.frame_rate, "frames/s");
        let frames = scene.duration * scene.frame_rate;
        if duration_ok && rate_ok && frames < 1.0 - 1e-9 {
            self.push(
                "frame_rate",
                format!(
                    "one frame lasts 1/frame_rate = {:.3e} s, longer than duration = {} s: the \
                     run would end past its duration; frame_rate must be ≥ 1/duration = {:.3e} \
                     frames/s",
                    1.0 / scene.frame_rate,
                    scene.duration,
                    1.0 / scene.duration
                ),
            );
        } else if duration_ok
            && rate_ok
            && frames <= MAX_FRAMES
            && (frames - frames.round()).abs() > 1e-9 * frames.max(1.0)
        {
            self.push(
                "frame_rate",
                format!(
                    "duration × frame_rate = {frames} is not a whole number of frames: the last \
                     frame would end at {:.6e} s, past duration = {} s",
                    frames.ceil() / scene.frame_rate,
                    scene.duration
                ),
            );
        }
        if duration_ok && rate_ok && scene.duration * scene.frame_rate > MAX_FRAMES {
            self.push(
                "duration",
                format!(
                    "duration × frame_rate = {:.3e} frames, more than the limit {MAX_FRAMES}",
                    scene.duration * scene.frame_rate
                ),
            );
        }
    }

    /// Values that overflow or underflow single precision in the quantities the step derives:
    /// particle mass ρ₀h³, Tait pressure and squared wave speed at the largest expected density
    /// 2ρ₀ (the §2.6 guard stops a run long before), momentum, kinetic energy and viscous
    /// stress at the largest speed the set-up explains (fastest body plus free fall across the
    /// domain, √(2|g|H)). Each is checked against [`SINGLE_PRECISION_HEADROOM`] and names the
    /// field that drives it. Runs only on finite, positive inputs (other checks report those).
    fn single_precision(&mut self, scene: &SceneFile) {
        let (ceiling, floor) = (
            f32::MAX as f64 / SINGLE_PRECISION_HEADROOM,
            f32::MIN_POSITIVE as f64 * SINGLE_PRECISION_HEADROOM,
        );
        let dx = scene.dx as f64;
        let ppc = scene.particles_per_cell.max(1) as f64;
        if !(dx.is_finite() && dx > 0.0) {
            return;
        }
        let h = dx / ppc;
        let g = scene.gravity.as_dvec3();
        let extent = (scene.domain.max - scene.domain.min).as_dvec3();
        let fall = if g.length() > 0.0 && extent.is_finite() {
            (2.0 * g.length() * g.normalize().abs().dot(extent.abs())).sqrt()
        } else {
            0.0
        };
        let fastest_body = scene
            .bodies
            .iter()
            .map(|b| b.velocity.as_dvec3().length())
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        let speed = fastest_body + fall;
        let speed_field = if fall >= fastest_body {
            "gravity"
        } else {
            "bodies"
        };
        if speed * speed > ceiling {
            self.push(
                speed_field,
                format!(
                    "the largest speed the set-up explains, {speed:.3e} m/s (fastest body \
                     {fastest_body:.3e} m/s + free fall √(2|g|H) = {fall:.3e} m/s), squared \
                     exceeds single precision (limit {ceiling:.3e})"
                ),
            );
            return;
        }
        for (i, m) in scene.materials.iter().enumerate() {
            let (rho, c, gamma, mu) = (
                m.density as f64,
                m.sound_speed as f64,
                m.tait_gamma as f64,
                m.viscosity as f64,
            );
            if ![rho, c, gamma, mu]
                .iter()
                .all(|v| v.is_finite() && *v >= 0.0)
                || rho == 0.0
            {
                continue;
            }
            let field = |f: &str| format!("materials[{i}].{f}");
            let mass = rho * h * h * h;
            let pressure = rho * c * c / gamma.max(1e-30) * (2f64.powf(gamma) - 1.0);
            let wave_sq = c * c * 2f64.powf(gamma - 1.0);
            let checks = [
                ("density", "particle mass ρ₀h³", "kg", mass),
                ("sound_speed", "Tait pressure at 2ρ₀", "Pa", pressure),
                ("sound_speed", "squared wave speed at 2ρ₀", "m²/s²", wave_sq),
                (
                    "density",
                    "particle momentum at the largest speed",
                    "kg·m/s",
                    mass * speed,
                ),
                (
                    "density",
                    "particle kinetic energy at the largest speed",
                    "J",
                    0.5 * mass * speed * speed,
                ),
                (
                    "viscosity",
                    "viscous stress μ·v/Δx at the largest speed",
                    "Pa",
                    mu * speed / dx,
                ),
            ];
            for (f, what, unit, value) in checks {
                if !value.is_finite() || value > ceiling {
                    self.push(
                        field(f),
                        format!(
                            "gives a {what} of {value:.3e} {unit}, beyond single precision \
                             (limit {ceiling:.3e} {unit})"
                        ),
                    );
                    break;
                }
            }
            if mass < floor {
                self.push(
                    field("density"),
                    format!(
                        "gives a particle mass ρ₀h³ = {mass:.3e} kg (h = dx/particles_per_cell \
                         = {h:.3e} m) below single precision's normal range (limit {floor:.3e} kg)"
                    ),
                );
            }
        }
    }

    /// `integrator` and `time_step`.
    fn integrator(&mut self, scene: &SceneFile) {
        let ig = &scene.integrator;
        let rho_inf_ok = self.in_range("integrator.rho_inf", ig.rho_inf, 0.0, 1.0, "");
        if rho_inf_ok {
            self.in_range(
                "integrator.rho_s",
                ig.rho_s,
                0.0,
                ig.rho_inf,
                " (0 ≤ rho_s ≤ rho_inf)",
            );
        }
        if ig.rho_inf == 1.0 && ig.rho_s == 1.0 {
            self.push(
                "integrator",
                "(rho_inf, rho_s) = (1, 1) is unconditionally unstable with the explicit scheme",
            );
        }
        self.in_range("integrator.flip", ig.flip as f64, 0.0, 1.0, "");
        if let Err(constraint) = ig.flip_interval.validate() {
            self.push("integrator.flip_interval", constraint);
        }
        if let Err((field, constraint)) = ig.viscous_solver.validate() {
            self.push(
                format!("integrator.viscous_solver.{field}"),
                format!("{constraint} (got {:?})", ig.viscous_solver),
            );
        }
        if let Err((field, constraint)) = ig.pressure.validate(ig.scheme, &scene.walls) {
            self.push(field, constraint);
        }
        if let Err((field, constraint)) = ig.velocity_gradient.validate(ig.scheme) {
            self.push(field, constraint);
        }
        let ts = &scene.time_step;
        if !(ts.safety.is_finite() && ts.safety > 0.0 && ts.safety <= 1.0) {
            self.push(
                "time_step.safety",
                format!("must lie in (0, 1] (got {})", ts.safety),
            );
        }
        if !(ts.advection.is_finite() && ts.advection > 0.0 && ts.advection <= 1.0) {
            self.push(
                "time_step.advection",
                format!("must lie in (0, 1] (got {})", ts.advection),
            );
        }
        let max_ok = self.positive("time_step.max_dt", ts.max_dt, "s");
        if self.positive("time_step.min_dt", ts.min_dt, "s") && max_ok && ts.min_dt > ts.max_dt {
            self.push(
                "time_step.min_dt",
                format!(
                    "must not exceed time_step.max_dt = {} s (got {})",
                    ts.max_dt, ts.min_dt
                ),
            );
        }
        if let TimeStepMode::Fixed(dt) = ts.mode
            && self.positive("time_step.mode", dt, "s")
            && scene.duration.is_finite()
            && scene.duration > 0.0
        {
            let steps = scene.duration / dt;
            // The last step of the run must still advance t in double precision.
            let stalls = scene.duration + dt <= scene.duration;
            if stalls || steps > MAX_FIXED_STEPS {
                self.push(
                    "time_step.mode",
                    format!(
                        "the fixed step {dt:.3e} s needs duration / Δt = {steps:.3e} steps, more \
                         than the limit {MAX_FIXED_STEPS:.0e}{}",
                        if stalls {
                            " (and t + Δt = t in double precision before the end: the run \
                             would never finish)"
                        } else {
                            ""
                        }
                    ),
                );
            }
        }
    }

    /// `walls` (and, with a valid `domain`, the whole-cells rule of periodic axes).
    fn walls(&mut self, scene: &SceneFile, domain: Option<(Vec3, Vec3)>) {
        let w = &scene.walls;
        for (name, bc) in [
            ("walls.x_min", w.x_min),
            ("walls.x_max", w.x_max),
            ("walls.y_min", w.y_min),
            ("walls.y_max", w.y_max),
            ("walls.z_min", w.z_min),
            ("walls.z_max", w.z_max),
        ] {
            self.boundary(name, bc);
        }
        for a in 0..3 {
            let lo = matches!(w.face(a, false), BoundaryCondition::Periodic);
            let hi = matches!(w.face(a, true), BoundaryCondition::Periodic);
            let (lo_name, hi_name) = (
                format!("walls.{}_min", AXES[a]),
                format!("walls.{}_max", AXES[a]),
            );
            if lo != hi {
                let (set, other) = if lo {
                    (lo_name, hi_name)
                } else {
                    (hi_name, lo_name)
                };
                self.push(
                other,
                format!(
                    "must be Periodic too: Periodic must be set on both faces of an axis ({set} is)"
                ),
            );
            } else if let (true, Some((dmin, dmax))) = (lo, domain) {
                let cells = (dmax[a] as f64 - dmin[a] as f64) / scene.dx as f64;
                if (cells - cells.round()).abs() > 1e-3 || cells.round() < 4.0 {
                    self.push(
                    lo_name,
                    format!(
                        "the {} axis is periodic, so the domain length along it must be a whole \
                         number (≥ 4) of cells dx (got {cells} cells)",
                        AXES[a]
                    ),
                );
                }
            }
        }
    }

    /// `materials`; returns the index of every (first) name.
    fn materials<'a>(&mut self, scene: &'a SceneFile) -> HashMap<&'a str, usize> {
        if scene.materials.len() > u16::MAX as usize + 1 {
            self.push(
                "materials",
                format!(
                    "at most {} materials are supported (got {})",
                    u16::MAX as usize + 1,
                    scene.materials.len()
                ),
            );
        }
        let mut names: HashMap<&str, usize> = HashMap::new();
        for (i, m) in scene.materials.iter().enumerate() {
            if let Err((field, constraint)) = m.validate() {
                self.push(
                    format!("materials[{i}].{field}"),
                    format!("{constraint} (got {})", material_value(m, field)),
                );
            }
            if m.name.trim().is_empty() {
                self.push(format!("materials[{i}].name"), "must not be empty");
            } else if let Some(first) = names.get(m.name.as_str()) {
                self.push(
                    format!("materials[{i}].name"),
                    format!(
                        "duplicate material name `{}` (already defined by materials[{first}])",
                        m.name
                    ),
                );
            } else {
                names.insert(&m.name, i);
            }
        }
        names
    }

    /// `rheology`: known material, one model of each kind per material, the model's own
    /// validation through the registry ([`ModelSpec::validate`](crate::rheology::ModelSpec::validate)).
    fn rheology(&mut self, scene: &SceneFile, names: &HashMap<&str, usize>) {
        // One model of each kind per material; different kinds add up (\[Li\]'s generalized Maxwell
        // parallel sum, ALGORITHM §6.1), e.g. a Herschel–Bulkley viscosity with plasticity.
        let mut with_model: HashMap<(&str, std::any::TypeId), usize> = HashMap::new();
        for (i, r) in scene.rheology.iter().enumerate() {
            let Some(&mi) = names.get(r.material.as_str()) else {
                self.push(
                    format!("rheology[{i}].material"),
                    format!("unknown material `{}`", r.material),
                );
                continue;
            };
            if let Some(first) = with_model.insert((&r.material, r.model.model_type()), i) {
                self.push(
                    format!("rheology[{i}].material"),
                    format!(
                        "material `{}` already has a model of this kind (rheology[{first}]); \
                     different kinds may be combined, their stresses add",
                        r.material
                    ),
                );
            }
            let material = &scene.materials[mi];
            for e in r.model.validate(material).err().unwrap_or_default() {
                self.push(
                    format!("rheology[{i}].model.{}", e.field),
                    format!("{} (material `{}`)", e.constraint, r.material),
                );
            }
        }
    }
}

fn fmt_vec(v: Vec3) -> String {
    format!("({}, {}, {})", v.x, v.y, v.z)
}

const AXES: [&str; 3] = ["x", "y", "z"];

impl Checker {
    fn push(&mut self, field: impl Into<String>, message: impl Into<String>) {
        self.issues.push(FieldIssue::new(field, message));
    }

    /// `value` finite and > 0. Returns whether it is.
    fn positive<T: Into<f64> + Display + Copy>(
        &mut self,
        field: &str,
        value: T,
        unit: &str,
    ) -> bool {
        let v: f64 = value.into();
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        if !v.is_finite() {
            self.push(
                field,
                format!("must be a finite number > 0{unit} (got {value})"),
            );
            false
        } else if v <= 0.0 {
            self.push(field, format!("must be > 0{unit} (got {value})"));
            false
        } else {
            true
        }
    }

    /// `value` finite and in \[lo, hi\].
    fn in_range(&mut self, field: &str, value: f64, lo: f64, hi: f64, what: &str) -> bool {
        if value.is_finite() && value >= lo && value <= hi {
            true
        } else {
            self.push(
                field,
                format!("must lie in [{lo}, {hi}]{what} (got {value})"),
            );
            false
        }
    }

    fn finite_vec(&mut self, field: &str, v: Vec3, unit: &str) -> bool {
        if v.is_finite() {
            true
        } else {
            self.push(
                field,
                format!("must have finite components [{unit}] (got {})", fmt_vec(v)),
            );
            false
        }
    }

    fn boundary(&mut self, field: &str, bc: BoundaryCondition) {
        if let BoundaryCondition::Friction(mu) = bc
            && !(mu.is_finite() && mu >= 0.0)
        {
            self.push(
                field,
                format!("friction coefficient must be a finite number ≥ 0 (got {mu})"),
            );
        }
    }
}

/// Value of a material field named by [`FluidMaterial::validate`], for the message.
fn material_value(m: &FluidMaterial, field: &str) -> String {
    match field {
        "density" => m.density.to_string(),
        "sound_speed" => m.sound_speed.to_string(),
        "tait_gamma" => m.tait_gamma.to_string(),
        "viscosity" => m.viscosity.to_string(),
        "local_fraction" => m.local_fraction.to_string(),
        "name" => format!("{:?}", m.name),
        _ => "?".into(),
    }
}

/// Checks every constraint of `scene` (see `docs/scenes.md`) and loads its meshes; mesh
/// paths are resolved with [`resolve_asset_path`] against `base_dir`. Returns all issues.
pub fn validate_scene(scene: &SceneFile, base_dir: &Path) -> Result<LoadedAssets, Vec<FieldIssue>> {
    let mut c = Checker { issues: Vec::new() };

    // Grid and domain.
    let dx_ok = c.positive("dx", scene.dx, "m");
    let dmin = scene.domain.min;
    let dmax = scene.domain.max;
    let mut domain_ok =
        c.finite_vec("domain.min", dmin, "m") & c.finite_vec("domain.max", dmax, "m");
    if domain_ok {
        let bad: Vec<String> = (0..3)
            .filter(|&a| dmax[a] <= dmin[a])
            .map(|a| format!("{}: {} ≤ {}", AXES[a], dmax[a], dmin[a]))
            .collect();
        if !bad.is_empty() {
            domain_ok = false;
            c.push(
                "domain.max",
                format!(
                    "must exceed domain.min on every axis ({}) m",
                    bad.join(", ")
                ),
            );
        }
    }
    if domain_ok && dx_ok {
        let dx = scene.dx as f64;
        let size = (dmax - dmin).as_dvec3();
        let narrow: Vec<String> = (0..3)
            .filter(|&a| size[a] < 4.0 * dx * (1.0 - 1e-6))
            .map(|a| format!("{} is {} m", AXES[a], size[a] as Real))
            .collect();
        if !narrow.is_empty() {
            c.push(
                "domain",
                format!(
                    "must be at least 4·dx = {} m wide on every axis ({})",
                    (4.0 * dx) as Real,
                    narrow.join(", ")
                ),
            );
        }
        let cells: f64 = (0..3).map(|a| (size[a] / dx).ceil()).product();
        if cells > MAX_GRID_CELLS {
            c.push(
                "dx",
                format!(
                    "gives a grid of {cells:.3e} cells, more than the limit {MAX_GRID_CELLS:.3e}; \
                     increase dx or shrink the domain"
                ),
            );
            domain_ok = false;
        }
    }
    let ppc_ok = (1..=MAX_PARTICLES_PER_CELL).contains(&scene.particles_per_cell);
    if !ppc_ok {
        c.push(
            "particles_per_cell",
            format!(
                "must lie in 1..={MAX_PARTICLES_PER_CELL} (got {})",
                scene.particles_per_cell
            ),
        );
    }
    c.finite_vec("gravity", scene.gravity, "m/s²");

    // Time, integrator and time step.
    c.time(scene);
    c.integrator(scene);

    // Walls.
    c.walls(scene, (dx_ok && domain_ok).then_some((dmin, dmax)));

    // Materials.
    let names = c.materials(scene);

    // Rheology models.
    c.rheology(scene, &names);

    // Derived quantities within single precision.
    if c.issues.is_empty() {
        c.single_precision(scene);
    }

    // Bodies.
    let lattice = (dx_ok && ppc_ok && domain_ok)
        .then(|| Lattice::new(dmin, scene.dx, scene.particles_per_cell));
    let mut meshes = Vec::with_capacity(scene.bodies.len());
    let mut particle_estimate = 0u64;
    for (i, body) in scene.bodies.iter().enumerate() {
        let at = |f: &str| format!("bodies[{i}].{f}");
        if !names.contains_key(body.material.as_str()) {
            let mut known: Vec<String> = Vec::new();
            for m in &scene.materials {
                let name = format!("`{}`", m.name);
                if !known.contains(&name) {
                    known.push(name);
                }
            }
            let defined = if known.is_empty() {
                "no materials are defined".to_string()
            } else {
                format!("defined: {}", known.join(", "))
            };
            c.push(
                at("material"),
                format!("unknown material `{}` ({defined})", body.material),
            );
        }
        c.finite_vec(&at("velocity"), body.velocity, "m/s");
        c.in_range(
            &at("jitter"),
            body.jitter as f64,
            0.0,
            1.0,
            " (fraction of the particle spacing)",
        );
        if scene.duration.is_finite() && scene.duration > 0.0 {
            c.in_range(
                &at("release_time"),
                body.release_time,
                0.0,
                scene.duration,
                " s (a body released at or after `duration` would never appear)",
            );
            if body.release_time == scene.duration {
                c.push(
                    at("release_time"),
                    format!(
                        "must be < duration = {} s (the body would never appear)",
                        scene.duration
                    ),
                );
            }
        }
        let (bbox, mesh) = check_shape(&mut c, &body.shape, &at("shape"), base_dir);
        meshes.push(mesh);
        let Some((lo, hi)) = bbox else { continue };
        if domain_ok {
            let outside: Vec<String> = (0..3)
                .filter(|&a| lo[a] < dmin[a] || hi[a] > dmax[a])
                .map(|a| {
                    format!(
                        "on {} it spans [{}, {}] m but the domain is [{}, {}] m",
                        AXES[a], lo[a], hi[a], dmin[a], dmax[a]
                    )
                })
                .collect();
            if !outside.is_empty() {
                c.push(
                    at("shape"),
                    format!("body lies outside the domain: {}", outside.join("; ")),
                );
                continue;
            }
        }
        if let Some(lattice) = &lattice {
            let n = lattice.count_in_box(lo, hi);
            particle_estimate = particle_estimate.saturating_add(n);
            if particle_estimate > MAX_PARTICLES {
                c.push(
                    at("shape"),
                    format!(
                        "the bodies up to this one would create up to {particle_estimate} \
                         particles, more than the limit {MAX_PARTICLES}; increase dx or \
                         decrease particles_per_cell"
                    ),
                );
                particle_estimate = 0;
            }
        }
    }

    // Colliders.
    let mut collider_meshes = Vec::with_capacity(scene.colliders.len());
    let mut mesh_cache = HashMap::new();
    for (i, col) in scene.colliders.iter().enumerate() {
        collider_meshes.push(check_collider(
            &mut c,
            col,
            &format!("colliders[{i}]"),
            base_dir,
            &mut mesh_cache,
        ));
    }

    // Rigid bodies.
    c.issues.extend(crate::rigid::validate_rigid_bodies(
        &scene.rigid_bodies,
        domain_ok.then_some((dmin, dmax)),
        dx_ok.then_some(scene.dx),
        &scene.walls,
    ));

    // Emitters, phase change and temperature-dependent viscosity (ALGORITHM §4).
    let ctx = SceneContext {
        domain_min: dmin,
        domain_max: dmax,
        dx: scene.dx,
        particles_per_cell: scene.particles_per_cell,
        material_names: scene.materials.iter().map(|m| m.name.as_str()).collect(),
        base_dir,
    };
    c.issues
        .extend(crate::thermal::phase::validate_phase_entries(
            &scene.phase_change,
            &scene.temperature_viscosity,
            &scene.thermal,
            &scene.materials,
        ));
    c.issues
        .extend(crate::emit::validate_emitters(&scene.emitters, &ctx));
    c.issues.extend(emitter_temperatures(scene));
    // Heat (ALGORITHM §3).
    c.issues.extend(crate::thermal::scene::validate_thermal(
        &scene.thermal,
        &ctx,
        scene.colliders.len(),
    ));

    // Output.
    if scene.output.every == 0 {
        c.push("output.every", "must be ≥ 1 frame (got 0)");
    }
    for (k, f) in scene.output.fields.iter().enumerate() {
        if scene.output.fields[..k].contains(f) {
            c.push(
                format!("output.fields[{k}]"),
                format!("duplicate field {f:?}"),
            );
        }
        if *f == OutputField::Temperature && !scene.thermal.has_heat() {
            c.push(
                format!("output.fields[{k}]"),
                "Temperature needs heat: the scene has no `thermal.materials`",
            );
        }
        if *f == OutputField::Phase && scene.phase_change.is_empty() {
            c.push(
                format!("output.fields[{k}]"),
                "Phase needs a `phase_change` section",
            );
        }
    }

    // Camera (renderers only).
    c.issues.extend(super::validate_camera(&scene.camera));

    if c.issues.is_empty() {
        Ok(LoadedAssets {
            meshes,
            colliders: collider_meshes,
        })
    } else {
        Err(c.issues)
    }
}

/// Checks a body shape; returns its bounding box (if the shape is valid) and its mesh.
fn check_shape(
    c: &mut Checker,
    shape: &BodyShape,
    at: &str,
    base_dir: &Path,
) -> (Option<(Vec3, Vec3)>, Option<TriMesh>) {
    let f = |name: &str| format!("{at}.{name}");
    match shape {
        BodyShape::Box { min, max } => {
            let ok = c.finite_vec(&f("min"), *min, "m") & c.finite_vec(&f("max"), *max, "m");
            if !ok {
                return (None, None);
            }
            let bad: Vec<String> = (0..3)
                .filter(|&a| max[a] <= min[a])
                .map(|a| format!("{}: {} ≤ {}", AXES[a], max[a], min[a]))
                .collect();
            if !bad.is_empty() {
                c.push(
                    f("max"),
                    format!("must exceed min on every axis ({}) m", bad.join(", ")),
                );
                return (None, None);
            }
            (Some((*min, *max)), None)
        }
        BodyShape::Sphere { center, radius } => {
            let ok =
                c.finite_vec(&f("center"), *center, "m") & c.positive(&f("radius"), *radius, "m");
            let e = Vec3::splat(*radius);
            (ok.then_some((*center - e, *center + e)), None)
        }
        BodyShape::Cylinder {
            center,
            radius,
            half_height,
            axis,
        } => {
            let ok = c.finite_vec(&f("center"), *center, "m")
                & c.positive(&f("radius"), *radius, "m")
                & c.positive(&f("half_height"), *half_height, "m");
            let mut e = Vec3::splat(*radius);
            e[axis.index()] = *half_height;
            (ok.then_some((*center - e, *center + e)), None)
        }
        BodyShape::Mesh {
            path,
            scale,
            translation,
        } => {
            let ok = c.positive(&f("scale"), *scale, "")
                & c.finite_vec(&f("translation"), *translation, "m");
            let file = match resolve_asset_path(path, base_dir) {
                Ok(file) => file,
                Err(tried) => {
                    let tried: Vec<String> =
                        tried.iter().map(|p| format!("`{}`", p.display())).collect();
                    c.push(
                        f("path"),
                        format!("mesh file `{path}` not found (tried {})", tried.join(", ")),
                    );
                    return (None, None);
                }
            };
            let mesh = match TriMesh::load_obj(&file) {
                Ok(m) => m,
                Err(e) => {
                    c.push(f("path"), format!("invalid mesh: {e}"));
                    return (None, None);
                }
            };
            let mut valid = true;
            if mesh.triangles.is_empty() {
                c.push(f("path"), format!("mesh `{}` has no faces", file.display()));
                valid = false;
            } else if !mesh.is_closed() {
                c.push(
                    f("path"),
                    format!(
                        "mesh `{}` is not closed: {} edges are not shared by exactly two \
                         triangles (the inside of an open surface is undefined)",
                        file.display(),
                        mesh.open_edge_count()
                    ),
                );
                valid = false;
            }
            if !ok || !valid {
                return (None, None);
            }
            let mesh = mesh.transformed(*scale, *translation);
            if !mesh.vertices.iter().all(|v| v.is_finite()) {
                c.push(f("scale"), "the scaled mesh has non-finite coordinates");
                return (None, None);
            }
            if mesh.volume() <= 0.0 {
                c.push(
                    f("path"),
                    format!("mesh `{}` encloses no volume", file.display()),
                );
                return (None, None);
            }
            (mesh.aabb(), Some(mesh))
        }
    }
}

/// Checks a collider; returns the prepared mesh of a `Mesh` shape (shared through `cache`,
/// keyed by resolved file and scale).
fn check_collider(
    c: &mut Checker,
    col: &ColliderSpec,
    at: &str,
    base_dir: &Path,
    cache: &mut HashMap<(PathBuf, u32), Arc<MeshSdf>>,
) -> Option<Arc<MeshSdf>> {
    let f = |name: &str| format!("{at}.{name}");
    let mut prepared = None;
    match &col.shape {
        ColliderShapeSpec::Mesh(MeshFile { path, scale }) => {
            prepared = check_collider_mesh(c, path, *scale, &f("shape"), base_dir, cache);
        }
        ColliderShapeSpec::Analytic(shape) => check_analytic_shape(c, shape, &f("shape")),
    }
    c.boundary(&f("boundary"), col.boundary);
    if col.boundary == BoundaryCondition::Periodic {
        c.push(
            f("boundary"),
            "Periodic applies to domain walls only; use Sticky, Slip or Friction(μ)",
        );
    }
    c.finite_vec(&f("translation"), col.translation, "m");
    c.finite_vec(&f("linear_velocity"), col.linear_velocity, "m/s");
    c.finite_vec(&f("angular_velocity"), col.angular_velocity, "rad/s");
    if !col.path.is_empty() {
        if col.translation != Vec3::ZERO || col.linear_velocity != Vec3::ZERO {
            c.push(
                f("path"),
                "a path places and moves the collider: leave out `translation` and \
                 `linear_velocity` (the first key is the start position)",
            );
        }
        for (k, key) in col.path.iter().enumerate() {
            let at = format!("{at}.path[{k}]");
            if !(key.time.is_finite() && key.time >= 0.0) {
                c.push(
                    format!("{at}.time"),
                    format!("must be a finite time ≥ 0 s (got {})", key.time),
                );
            } else if k > 0 && key.time <= col.path[k - 1].time {
                c.push(
                    format!("{at}.time"),
                    format!(
                        "key times must increase (got {} s after {} s)",
                        key.time,
                        col.path[k - 1].time
                    ),
                );
            }
            c.finite_vec(&format!("{at}.translation"), key.translation, "m");
        }
    }
    if let Some(t) = col.remove_at
        && !(t.is_finite() && t > 0.0)
    {
        c.push(
            f("remove_at"),
            format!("must be a finite time > 0 s (got {t})"),
        );
    }
    match col.rotation {
        RotationSpec::AxisAngle { axis, degrees } => {
            if !(axis.is_finite() && axis.length_squared() > 0.0) {
                c.push(
                    f("rotation.axis"),
                    format!("must be a finite non-zero vector (got {})", fmt_vec(axis)),
                );
            }
            if !degrees.is_finite() {
                c.push(
                    f("rotation.degrees"),
                    format!("must be finite (got {degrees})"),
                );
            }
        }
        RotationSpec::Euler { x, y, z } => {
            for (name, v) in [("x", x), ("y", y), ("z", z)] {
                if !v.is_finite() {
                    c.push(
                        f(&format!("rotation.{name}")),
                        format!("must be finite (got {v})"),
                    );
                }
            }
        }
    }
    prepared
}

/// Checks the parameters of an analytic collider shape at `at` (e.g. `colliders[0].shape`).
fn check_analytic_shape(c: &mut Checker, shape: &ColliderShape, at: &str) {
    let f = |name: &str| format!("{at}.{name}");
    match *shape {
        ColliderShape::HalfSpace { normal } => {
            if !(normal.is_finite() && normal.length_squared() > 0.0) {
                c.push(
                    f("normal"),
                    format!("must be a finite non-zero vector (got {})", fmt_vec(normal)),
                );
            }
        }
        ColliderShape::Sphere { radius } => {
            c.positive(&f("radius"), radius, "m");
        }
        ColliderShape::Box { half_extents } => {
            if !(half_extents.is_finite() && half_extents.min_element() > 0.0) {
                c.push(
                    f("half_extents"),
                    format!(
                        "must be finite and > 0 m on every axis (got {})",
                        fmt_vec(half_extents)
                    ),
                );
            }
        }
        ColliderShape::Cylinder {
            radius,
            half_height,
        } => {
            c.positive(&f("radius"), radius, "m");
            c.positive(&f("half_height"), half_height, "m");
        }
        // A prepared mesh was checked when it was made.
        ColliderShape::Mesh(_) => {}
    }
}

/// Loads and prepares a collider mesh; issues go to `{at}.scale` and `{at}.path`.
fn check_collider_mesh(
    c: &mut Checker,
    path: &str,
    scale: Real,
    at: &str,
    base_dir: &Path,
    cache: &mut HashMap<(PathBuf, u32), Arc<MeshSdf>>,
) -> Option<Arc<MeshSdf>> {
    let f = |name: &str| format!("{at}.{name}");
    let scale_ok = c.positive(&f("scale"), scale, "");
    let file = match resolve_asset_path(path, base_dir) {
        Ok(file) => file,
        Err(tried) => {
            let tried: Vec<String> = tried.iter().map(|p| format!("`{}`", p.display())).collect();
            c.push(
                f("path"),
                format!("mesh file `{path}` not found (tried {})", tried.join(", ")),
            );
            return None;
        }
    };
    if !scale_ok {
        return None;
    }
    let key = (file.clone(), scale.to_bits());
    if let Some(mesh) = cache.get(&key) {
        return Some(mesh.clone());
    }
    match MeshSdf::from_obj(&file, scale) {
        Ok(mesh) => {
            let mesh = Arc::new(mesh);
            cache.insert(key, mesh.clone());
            Some(mesh)
        }
        Err(MeshSdfError::Obj(e)) => {
            c.push(f("path"), format!("invalid mesh: {e}"));
            None
        }
        Err(MeshSdfError::NonFinite) => {
            c.push(
                f("scale"),
                format!(
                    "the mesh `{}` scaled by {scale} has non-finite coordinates",
                    file.display()
                ),
            );
            None
        }
        Err(e @ MeshSdfError::TooSmall) => {
            c.push(
                f("scale"),
                format!("the mesh `{}` scaled by {scale}: {e}", file.display()),
            );
            None
        }
        Err(e) => {
            c.push(f("path"), format!("mesh `{}`: {e}", file.display()));
            None
        }
    }
}

/// Cross-section check of the emitters against the heat and phase-change sections: a heated
/// material needs an injection temperature, and it must exceed the material's melting
/// temperature (a printer extrudes melt).
fn emitter_temperatures(scene: &SceneFile) -> Vec<FieldIssue> {
    let mut issues = Vec::new();
    for (i, spec) in scene.emitters.iter().enumerate() {
        let at = |f: &str| format!("emitters[{i}].{f}");
        if !scene.materials.iter().any(|m| m.name == spec.material) {
            continue; // reported by the emitters' validation
        }
        match (spec.temperature, heated_material(scene, &spec.material)) {
            (None, Some(why)) => issues.push(FieldIssue::new(
                at("temperature"),
                format!(
                    "material `{}` {why}: give the injection temperature T_inj",
                    spec.material
                ),
            )),
            (Some(t), _) => {
                if let Some(tm) = melting_temperature(scene, &spec.material)
                    && t <= tm
                {
                    issues.push(FieldIssue::new(
                        at("temperature"),
                        format!(
                            "T_inj = {t} must exceed the melting temperature T_m = {tm} of `{}` (a printer extrudes melt)",
                            spec.material
                        ),
                    ));
                }
            }
            (None, None) => {}
        }
    }
    issues
}

/// Why material `name` of `scene` is heated (it has thermal parameters, a phase change or a
/// temperature-dependent viscosity), or `None`.
fn heated_material(scene: &SceneFile, name: &str) -> Option<&'static str> {
    if scene.thermal.materials.iter().any(|m| m.material == name) {
        Some("is heated (it has thermal parameters)")
    } else if scene.phase_change.iter().any(|p| p.material == name) {
        Some("has a phase change")
    } else if scene
        .temperature_viscosity
        .iter()
        .any(|p| p.material == name)
    {
        Some("has a temperature-dependent viscosity")
    } else {
        None
    }
}

/// The melting temperature of material `name` of `scene`: its phase change's, else its
/// thermal parameters' (`thermal.materials[i].melting_temperature`), if any.
fn melting_temperature(scene: &SceneFile, name: &str) -> Option<Real> {
    scene
        .phase_change
        .iter()
        .find(|p| p.material == name)
        .map(|p| p.melting_temperature)
        .or_else(|| {
            scene
                .thermal
                .materials
                .iter()
                .find(|m| m.material == name)
                .and_then(|m| m.melting_temperature)
        })
}
