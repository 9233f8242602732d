//! RON scene files: schema, validation, particle sampling and spawning.
//!
//! A scene file describes a complete run: the domain and grid, gravity, duration and frame
//! rate, integrator and time-step settings, walls, materials, liquid bodies (box, sphere,
//! cylinder, OBJ mesh), colliders and output. The reference for every field, unit, default and
//! constraint is `docs/scenes.md`.
//!
//! Loading goes parse → validate → sample and fails before anything is simulated:
//!
//! - [`load_scene`] / [`parse_scene_str`] give a [`Scene`] or a [`SceneError`] whose messages
//!   read `file:line:col: field `path`: message`; syntax and type errors come from `ron`,
//!   semantic errors are all collected ([`SceneError::Invalid`]);
//! - [`Scene::apply`] inserts the [`MpmConfig`] and [`Materials`] resources and spawns the
//!   particles and colliders into a `World`.
//!
//! The loader sits on top of the public API: everything a scene does can be done in code
//! with [`MpmConfig`], [`Materials::add`], the samplers of [`crate::sampling`],
//! [`ParticleBundle::new`] (see [`spawn_particles`]) and the collider components.
mod camera;
mod error;
mod estimate;
mod locate;
mod schema;
mod validate;
mod warnings;

use std::path::{Path, PathBuf};

use bevy_ecs::world::World;

pub use camera::{CameraPlacement, CameraSpec, DEFAULT_FOV_DEG, validate_camera};
pub use error::{FieldError, FieldIssue, SceneError};
pub use estimate::{
    ASSUMED_PARTICLE_STEPS_PER_SECOND, BYTES_PER_PARTICLE, IMPLICIT_BYTES_PER_NODE,
    ResourceEstimate, THERMAL_BYTES_PER_NODE,
};
pub use locate::{Locator, parent_path};
pub use schema::{
    Axis, BodyShape, BodySpec, ColliderShapeSpec, ColliderSpec, DEFAULT_PARTICLES_PER_CELL,
    DomainSpec, MeshFile, ModelSpec, OutputField, OutputFormatSpec, OutputSpec, PathKey,
    RheologySpec, RotationSpec, SceneFile,
};
pub use validate::{
    ASSETS_DIR, LoadedAssets, MAX_FRAMES, MAX_GRID_CELLS, MAX_PARTICLES, MAX_PARTICLES_PER_CELL,
    resolve_asset_path, validate_scene,
};

use crate::collision::{Collider, ColliderMotion, ColliderPose};
use crate::components::ParticleBundle;
use crate::config::MpmConfig;
use crate::grid::GridLayout;
use crate::material::{FluidMaterial, MaterialId, Materials};
use crate::math::{Real, Vec3};
use crate::rheology::ModelRegistry;
use crate::sampling::{self, Lattice, ParticleSample};

/// The particles of one body.
#[derive(Clone, Debug, PartialEq)]
pub struct BodyParticles {
    /// Positions \[m\].
    pub positions: Vec<Vec3>,
    /// Volume of each particle h³ \[m³\] (mass = volume × material density).
    pub particle_volume: Real,
    /// Material.
    pub material: MaterialId,
    /// Initial velocity of every particle \[m/s\].
    pub velocity: Vec3,
    /// Exact volume of the shape \[m³\] (analytic, or the mesh volume), to compare with the
    /// sampled volume N·h³.
    pub shape_volume: f64,
    /// Simulation time at which the body appears \[s\] (0: at the start; later: a
    /// [`crate::emit::DelayedBody`]).
    pub release_time: f64,
}

impl BodyParticles {
    /// Sampled volume N·h³ \[m³\].
    pub fn sampled_volume(&self) -> f64 {
        self.positions.len() as f64 * self.particle_volume as f64
    }
}

/// A collider ready to spawn: components, with motion only when it moves and a lifetime only
/// when it is removed during the run.
pub type SceneCollider = (
    Collider,
    ColliderPose,
    Option<ColliderMotion>,
    Option<crate::collision::ColliderLifetime>,
    Option<crate::collision::ColliderPath>,
);

/// A loaded, validated and sampled scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Simulation configuration (domain, dx, gravity, integrator, time step, walls,
    /// frame_dt = 1/frame_rate).
    pub config: MpmConfig,
    /// Materials; bodies refer to them by id (their order in the file).
    pub materials: Materials,
    /// Particles, grouped by body, in file order.
    pub particles: Vec<BodyParticles>,
    /// Colliders, in file order.
    pub colliders: Vec<SceneCollider>,
    /// Dynamic rigid bodies, in file order. Liquid particles that would start inside one are
    /// not created.
    pub rigid_bodies: Vec<crate::rigid::RigidBodyBundle>,
    /// Rheology models per material.
    pub rheology: Vec<(MaterialId, ModelSpec)>,
    /// Nozzle emitters (ALGORITHM §4.4), spawned as entities by [`Scene::apply`].
    pub emitters: Vec<crate::emit::NozzleEmitter>,
    /// Phase change per material (ALGORITHM §4.1–4.2).
    pub phase_change: Vec<(MaterialId, crate::thermal::phase::PhaseChange)>,
    /// Temperature-dependent viscosity per material (ALGORITHM §4.3).
    pub temperature_viscosity: Vec<(MaterialId, crate::thermal::phase::TemperatureViscosity)>,
    /// Heat transfer (ALGORITHM §3); `None` when the scene has no heat.
    pub thermal: Option<crate::thermal::scene::SceneThermal>,
    /// Simulated time \[s\].
    pub duration: f64,
    /// Frames per simulated second \[1/s\].
    pub frame_rate: f64,
    /// Output settings.
    pub output: OutputSpec,
    /// How renderers look at the scene (`None`: their default).
    pub camera: Option<CameraSpec>,
    /// Jitter seed.
    pub seed: u64,
    /// The scene file (as given; empty for scenes not read from a file).
    pub source: PathBuf,
    /// Accepted but questionable parameters, located in the file when it was read from text
    /// (line 0 otherwise). The CLI prints them before running.
    pub warnings: Vec<FieldError>,
}

impl Scene {
    /// Number of frames to simulate: ⌈duration · frame_rate⌉, where a product within a
    /// relative 10⁻⁹ of an integer counts as that integer (so 0.5 s at 60 fps is 30 frames
    /// despite rounding). At least 1.
    pub fn frames(&self) -> u64 {
        frame_count(self.duration, self.frame_rate)
    }

    /// Total number of particles.
    pub fn particle_count(&self) -> usize {
        self.particles.iter().map(|b| b.positions.len()).sum()
    }

    /// Inserts `config` and `materials` as resources (replacing existing ones) and spawns every
    /// particle ([`ParticleBundle`]) and collider (`(Collider, ColliderPose[, ColliderMotion])`).
    /// Adds the plugins the scene's rheology models need (call before the app is finished;
    /// [`crate::runner::scene_app`] does). A scene without models adds nothing.
    pub fn add_plugins(&self, app: &mut bevy_app::App) {
        for (id, model) in &self.rheology {
            model.add_to_app(app, *id);
        }
        if !self.phase_change.is_empty() || !self.temperature_viscosity.is_empty() {
            let mut p = crate::thermal::phase::PhaseChangePlugin::default();
            for (id, ph) in &self.phase_change {
                p = p.with_phase_change(*id, ph.clone());
            }
            for (id, v) in &self.temperature_viscosity {
                p = p.with_temperature_viscosity(*id, v.clone());
            }
            app.add_plugins(p);
        }
        if !self.emitters.is_empty() || self.particles.iter().any(|b| b.release_time > 0.0) {
            app.add_plugins(crate::emit::EmitterPlugin);
        }
        if let Some(t) = &self.thermal {
            app.add_plugins(t.plugin());
        }
    }

    /// Inserts the scene's resources and spawns its particles, colliders and rigid bodies;
    /// particles of a material with a rheology model get the model's state (the model's plugin
    /// must have been added with [`Scene::add_plugins`]).
    ///
    /// # Panics
    /// If a model's plugin is missing (a programming error: use
    /// [`crate::runner::scene_app`] or call [`Scene::add_plugins`] first).
    pub fn apply(&self, world: &mut World) {
        world.insert_resource(self.config.clone());
        world.insert_resource(self.materials.clone());
        for body in &self.particles {
            if body.release_time > 0.0 {
                world.spawn(crate::emit::DelayedBody {
                    release_time: body.release_time,
                    positions: body.positions.clone(),
                    velocity: body.velocity,
                    particle_volume: body.particle_volume,
                    material: body.material,
                });
                continue;
            }
            // In chunks, each given its model and heat state before the next is spawned: a
            // particle that gains components moves to another table, and Bevy keeps the
            // capacity of the table it left. Spawned all at once, the plain particles' table
            // would keep a whole body's worth of columns after the move (262 B per
            // particle); in chunks it keeps one chunk's. A body whose particles gain nothing is
            // spawned at once (its table then has exactly its size).
            let material = self.materials.get(body.material);
            let order = spawn_order(world, &body.positions);
            let chunk = if self.gains_state(body.material) {
                SPAWN_CHUNK
            } else {
                usize::MAX
            };
            for chunk in order.chunks(chunk) {
                spawn_in_order(
                    world,
                    chunk.iter().map(|&i| body.positions[i as usize]),
                    body.velocity,
                    self.config.gravity,
                    body.particle_volume,
                    material,
                    body.material,
                );
                self.attach_particle_state(world);
            }
        }
        self.attach_particle_state(world);
        let mut collider_entities = Vec::with_capacity(self.colliders.len());
        for (collider, pose, motion, lifetime, path) in &self.colliders {
            let mut e = world.spawn((collider.clone(), *pose));
            if let Some(m) = motion {
                e.insert(*m);
            }
            if let Some(l) = lifetime {
                e.insert(*l);
            }
            if let Some(p) = path {
                e.insert(p.clone());
            }
            collider_entities.push(e.id());
        }
        for (i, t) in self.thermal.iter().flat_map(|t| &t.collider_temperatures) {
            if let Some(&e) = collider_entities.get(*i) {
                world
                    .entity_mut(e)
                    .insert(crate::thermal::PrescribedTemperature(*t));
            }
        }
        for body in &self.rigid_bodies {
            world.spawn(body.clone());
        }
        for emitter in &self.emitters {
            world.spawn(emitter.clone());
        }
    }

    /// Frees the bodies' sampled positions (the particles, once [`Scene::apply`] has spawned
    /// them, carry their own); the rest of the scene (counts aside) is unchanged. A scene
    /// applied after this spawns no particles. [`crate::runner::run_scene`] calls it after
    /// spawning.
    pub fn forget_sampled_positions(&mut self) {
        for body in &mut self.particles {
            body.positions = Vec::new();
        }
    }

    /// Whether [`Scene::attach_particle_state`] gives particles of `material` anything.
    fn gains_state(&self, material: MaterialId) -> bool {
        self.thermal.is_some()
            || self.phase_change.iter().any(|(id, _)| *id == material)
            || self.rheology.iter().any(|(id, _)| *id == material)
    }

    /// Gives the particles spawned so far that lack it their heat state, their phase-change
    /// state and their rheology model's state (idempotent: particles that have them keep them).
    fn attach_particle_state(&self, world: &mut World) {
        if self.thermal.is_some() {
            crate::thermal::systems::attach_thermal_state(world);
        }
        for (id, _) in &self.phase_change {
            crate::thermal::phase::attach_missing_phase_state(world, *id);
        }
        for (id, model) in &self.rheology {
            model
                .attach(world, *id)
                .unwrap_or_else(|e| panic!("{e} (add the scene's plugins first)"));
        }
    }
}

/// Particles [`Scene::apply`] spawns at a time (one chunk's columns is what the table of
/// particles without model state keeps after they move on).
pub const SPAWN_CHUNK: usize = 1 << 13;

/// ⌈duration · frame_rate⌉ with a relative tolerance of 10⁻⁹, at least 1 (0 for invalid
/// input).
pub fn frame_count(duration: f64, frame_rate: f64) -> u64 {
    let n = duration * frame_rate;
    if !(n.is_finite() && n > 0.0) {
        return 0;
    }
    let r = n.round();
    let frames = if (n - r).abs() <= 1e-9 * r.max(1.0) {
        r
    } else {
        n.ceil()
    };
    (frames as u64).max(1)
}

/// Spawns particles of one material at rest density with [`ParticleBundle::new`], in one
/// batch. When the world holds a [`MpmConfig`], the particles are spawned in the order of
/// their grid block ([`crate::grid::block_order`]), so that code and scene files that spawn
/// the same positions get the same entities in the same memory order.
pub fn spawn_particles(
    world: &mut World,
    positions: &[Vec3],
    velocity: Vec3,
    gravity: Vec3,
    particle_volume: Real,
    material: &FluidMaterial,
    id: MaterialId,
) {
    let order = spawn_order(world, positions);
    spawn_in_order(
        world,
        order.iter().map(|&i| positions[i as usize]),
        velocity,
        gravity,
        particle_volume,
        material,
        id,
    );
}

/// The indices of `positions` in the order of their grid block when the world holds a
/// [`MpmConfig`], else in the order given.
fn spawn_order(world: &World, positions: &[Vec3]) -> Vec<u32> {
    match world.get_resource::<MpmConfig>() {
        Some(c) => {
            let layout = GridLayout::new(c.domain_min, c.domain_max, c.dx);
            crate::grid::block_order(&layout, positions)
        }
        None => (0..positions.len() as u32).collect(),
    }
}

/// Spawns particles at `positions`, in the order given, in one batch.
fn spawn_in_order(
    world: &mut World,
    positions: impl ExactSizeIterator<Item = Vec3>,
    velocity: Vec3,
    gravity: Vec3,
    particle_volume: Real,
    material: &FluidMaterial,
    id: MaterialId,
) {
    let rho0 = material.density;
    world.spawn_batch(
        positions
            .map(move |p| ParticleBundle::new(p, velocity, gravity, particle_volume, rho0, id)),
    );
}

/// Deepest nesting of brackets a scene file may have (the shipped scenes need at most about
/// eight levels). Deeper text is refused before it is parsed.
pub const MAX_NESTING: usize = 64;

/// The byte offset of 1-based (line, column in characters) in `text` (its end if beyond).
fn byte_offset(text: &str, line: usize, col: usize) -> usize {
    let start: usize = text
        .split_inclusive('\n')
        .take(line.saturating_sub(1))
        .map(str::len)
        .sum();
    text[start..]
        .char_indices()
        .nth(col.saturating_sub(1))
        .map_or(text.len(), |(i, _)| start + i)
}

/// The file's bytes as UTF-8 text (a leading byte-order mark is dropped by the parser), or an
/// error naming the byte offset, line and column of the first invalid sequence.
fn decode_utf8<'a>(bytes: &'a [u8], path: &Path) -> Result<&'a str, SceneError> {
    std::str::from_utf8(bytes).map_err(|e| {
        let valid = &bytes[..e.valid_up_to()];
        // The prefix is valid UTF-8 by construction.
        let prefix = std::str::from_utf8(valid).unwrap_or_default();
        let line = prefix.matches('\n').count() + 1;
        let col = prefix.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        SceneError::Text(Box::new(FieldError {
            file: path.to_path_buf(),
            line,
            col,
            field: if locate::too_deep(prefix, MAX_NESTING).is_none() {
                Locator::new(prefix)
                    .path_at(ron::error::Position { line, col })
                    .filter(|p| !p.is_empty())
                    .unwrap_or(error::ROOT_FIELD)
                    .to_string()
            } else {
                error::ROOT_FIELD.to_string()
            },
            message: format!(
                "the file is not UTF-8 text: invalid byte 0x{:02x} at byte offset {}",
                bytes[e.valid_up_to()],
                e.valid_up_to()
            ),
        }))
    })
}

/// Reads, parses, validates and samples a scene file. Mesh paths are resolved against the
/// file's directory, then the crate's `assets/` ([`resolve_asset_path`]). Rheology models are
/// those of [`ModelRegistry::default`] (the shipped ones); see [`load_scene_with`].
pub fn load_scene(path: &Path) -> Result<Scene, SceneError> {
    load_scene_with(path, &ModelRegistry::default())
}

/// [`load_scene`] with the rheology models of `registry` (e.g. an app's, after it added a
/// `RheologyPlugin` of its own model: `app.world().resource::<ModelRegistry>()`).
pub fn load_scene_with(path: &Path, registry: &ModelRegistry) -> Result<Scene, SceneError> {
    let bytes = std::fs::read(path).map_err(|source| SceneError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let text = decode_utf8(&bytes, path)?;
    let base_dir = path.parent().unwrap_or(Path::new("."));
    registry.while_parsing(|| parse_scene_str(text, path, base_dir))
}

/// Parses, validates and samples scene text (rheology models: those of the innermost
/// [`ModelRegistry::while_parsing`] on this thread, else the shipped ones). `path_for_messages` names the file in errors
/// (and becomes [`Scene::source`]); relative mesh paths are resolved against `base_dir`.
pub fn parse_scene_str(
    text: &str,
    path_for_messages: &Path,
    base_dir: &Path,
) -> Result<Scene, SceneError> {
    let file = parse_scene_file(text, path_for_messages)?;
    let mut scene = file
        .build(base_dir, path_for_messages)
        .map_err(|issues| SceneError::from_issues(path_for_messages, Some(text), issues))?;
    scene.warnings = error::locate_issues(
        path_for_messages,
        Some(text),
        warnings::scene_warnings(&file),
    );
    Ok(scene)
}

/// Parses scene text into the schema without validating it (syntax, types, unknown and
/// missing fields only).
pub fn parse_scene_file(text: &str, path_for_messages: &Path) -> Result<SceneFile, SceneError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    if let Some(at) = locate::too_deep(text, MAX_NESTING) {
        // The field that holds the bracket: located in the text before it, which is at most
        // MAX_NESTING deep (the locator's records grow with the depth).
        let before = byte_offset(text, at.line, at.col);
        let field = Locator::new(&text[..before])
            .path_at(at)
            .filter(|p| !p.is_empty())
            .unwrap_or(error::ROOT_FIELD)
            .to_string();
        return Err(SceneError::Text(Box::new(FieldError {
            file: path_for_messages.to_path_buf(),
            line: at.line,
            col: at.col,
            field,
            message: format!(
                "values nested more than {MAX_NESTING} levels deep (a scene needs fewer than \
                 ten); is a bracket unbalanced?"
            ),
        })));
    }
    ron::Options::default()
        .from_str::<SceneFile>(text)
        .map_err(|e| SceneError::from_ron(path_for_messages, text, e))
}

impl SceneFile {
    /// All constraint violations (empty if valid). Loads meshes to check them.
    pub fn validate(&self, base_dir: &Path) -> Vec<FieldIssue> {
        validate_scene(self, base_dir).err().unwrap_or_default()
    }

    /// Validates and samples the scene. `source` is recorded in [`Scene::source`].
    pub fn build(&self, base_dir: &Path, source: &Path) -> Result<Scene, Vec<FieldIssue>> {
        let assets = validate_scene(self, base_dir)?;
        let mut materials = Materials::default();
        for m in &self.materials {
            materials.add(m.clone());
        }
        let lattice = Lattice::new(self.domain.min, self.dx, self.particles_per_cell);
        let mut particles = Vec::with_capacity(self.bodies.len());
        let mut issues = Vec::new();
        for (i, (body, mesh)) in self.bodies.iter().zip(&assets.meshes).enumerate() {
            let (mut sample, shape_volume) = sample_body(&lattice, &body.shape, mesh.as_ref());
            if sample.positions.is_empty() {
                issues.push(FieldIssue::new(
                    format!("bodies[{i}].shape"),
                    format!(
                        "contains no particle at this resolution (particle spacing \
                         dx/particles_per_cell = {} m); enlarge the body or decrease dx",
                        lattice.spacing
                    ),
                ));
                continue;
            }
            // One independent stream per body, derived from the scene seed.
            let body_seed = self
                .seed
                .wrapping_add((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            sampling::jitter(
                &mut sample.positions,
                lattice.spacing,
                body.jitter,
                body_seed,
            );
            let Some(material) = materials.find(&body.material) else {
                // Unreachable after validation; reported rather than panicking.
                issues.push(FieldIssue::new(
                    format!("bodies[{i}].material"),
                    format!("unknown material `{}`", body.material),
                ));
                continue;
            };
            particles.push(BodyParticles {
                positions: sample.positions,
                particle_volume: sample.particle_volume,
                material,
                velocity: body.velocity,
                shape_volume,
                release_time: body.release_time,
            });
        }
        if !issues.is_empty() {
            return Err(issues);
        }
        let mut colliders = Vec::with_capacity(self.colliders.len());
        for (i, (spec, mesh)) in self.colliders.iter().zip(&assets.colliders).enumerate() {
            match spec.to_components(mesh.as_ref()) {
                Some(c) => colliders.push(c),
                // Unreachable after validation (it prepares every mesh); reported, not a panic.
                None => issues.push(FieldIssue::new(
                    format!("colliders[{i}].shape.path"),
                    "mesh was not loaded",
                )),
            }
        }
        if !issues.is_empty() {
            return Err(issues);
        }
        let mut rigid_bodies = Vec::with_capacity(self.rigid_bodies.len());
        for (i, spec) in self.rigid_bodies.iter().enumerate() {
            match spec.to_bundle(self.gravity) {
                Ok(b) => rigid_bodies.push(b),
                // Unreachable after validation; reported, not a panic.
                Err(e) => issues.push(FieldIssue::new(format!("rigid_bodies[{i}]"), e.to_string())),
            }
        }
        if !issues.is_empty() {
            return Err(issues);
        }
        for body in &mut particles {
            body.positions
                .retain(|p| !rigid_bodies.iter().any(|b| b.contains(*p)));
        }
        let config = MpmConfig {
            domain_min: self.domain.min,
            domain_max: self.domain.max,
            dx: self.dx,
            gravity: self.gravity,
            integrator: self.integrator,
            time_step: self.time_step,
            frame_dt: 1.0 / self.frame_rate,
            walls: self.walls,
        };
        let rheology = self
            .rheology
            .iter()
            .filter_map(|r| materials.find(&r.material).map(|id| (id, r.model.clone())))
            .collect();
        let mut emitters = Vec::with_capacity(self.emitters.len());
        let spacing = self.dx / self.particles_per_cell.max(1) as Real;
        for (i, spec) in self.emitters.iter().enumerate() {
            let Some(id) = materials.find(&spec.material) else {
                continue; // reported by validation
            };
            match spec.build(
                base_dir,
                id,
                spacing,
                crate::emit::emitter_seed(self.seed, i),
            ) {
                Ok(e) => emitters.push(e),
                Err((field, message)) => {
                    issues.push(FieldIssue::new(format!("emitters[{i}].{field}"), message))
                }
            }
        }
        if !issues.is_empty() {
            return Err(issues);
        }
        let phase_change = self
            .phase_change
            .iter()
            .filter_map(|p| materials.find(&p.material).map(|id| (id, p.params.clone())))
            .collect();
        let temperature_viscosity = self
            .temperature_viscosity
            .iter()
            .filter_map(|v| materials.find(&v.material).map(|id| (id, v.params.clone())))
            .collect();
        let thermal = self.thermal.to_scene(&materials);
        Ok(Scene {
            config,
            materials,
            particles,
            colliders,
            rigid_bodies,
            rheology,
            emitters,
            phase_change,
            temperature_viscosity,
            thermal,
            duration: self.duration,
            frame_rate: self.frame_rate,
            output: self.output.clone(),
            camera: (self.camera != CameraSpec::default()).then_some(self.camera),
            seed: self.seed,
            source: source.to_path_buf(),
            warnings: error::locate_issues(source, None, warnings::scene_warnings(self)),
        })
    }
}

/// Samples one (validated) body shape; returns the particles and the exact shape volume.
/// `mesh` is the shape's mesh in world coordinates for [`BodyShape::Mesh`].
pub fn sample_body(
    lattice: &Lattice,
    shape: &BodyShape,
    mesh: Option<&crate::mesh::TriMesh>,
) -> (ParticleSample, f64) {
    use std::f64::consts::PI;
    match *shape {
        BodyShape::Box { min, max } => {
            let v = (max - min).as_dvec3();
            (sampling::sample_box(lattice, min, max), v.x * v.y * v.z)
        }
        BodyShape::Sphere { center, radius } => {
            let r = radius as f64;
            (
                sampling::sample_sphere(lattice, center, radius),
                4.0 / 3.0 * PI * r * r * r,
            )
        }
        BodyShape::Cylinder {
            center,
            radius,
            half_height,
            axis,
        } => {
            let r = radius as f64;
            (
                sampling::sample_cylinder(lattice, center, radius, half_height, axis),
                PI * r * r * 2.0 * half_height as f64,
            )
        }
        BodyShape::Mesh { .. } => match mesh {
            Some(mesh) => {
                let s = sampling::sample_mesh(lattice, mesh);
                (s.sample, s.mesh_volume)
            }
            None => (
                ParticleSample {
                    positions: Vec::new(),
                    particle_volume: lattice.particle_volume(),
                },
                0.0,
            ),
        },
    }
}

impl ColliderSpec {
    /// The collider's components; motion only if a velocity is non-zero. `mesh` is the
    /// prepared mesh of a `Mesh` shape ([`LoadedAssets::colliders`], or
    /// [`MeshSdf::from_obj`](crate::collision::MeshSdf::from_obj)); a `Mesh` shape without
    /// one gives `None`.
    pub fn to_components(
        &self,
        mesh: Option<&std::sync::Arc<crate::collision::MeshSdf>>,
    ) -> Option<SceneCollider> {
        let collider = Collider {
            shape: self.shape.to_shape(mesh)?,
            boundary: self.boundary,
        };
        let path = if self.path.is_empty() {
            None
        } else {
            // Validated keys; an invalid list gives `None` rather than a panic.
            crate::collision::ColliderPath::new(
                self.path.iter().map(|k| (k.time, k.translation)).collect(),
            )
            .ok()
        };
        let pose = ColliderPose {
            translation: path.as_ref().map_or(self.translation, |p| p.at(0.0)),
            rotation: self.rotation.to_quat(),
        };
        let moving = self.linear_velocity != Vec3::ZERO
            || self.angular_velocity != Vec3::ZERO
            || path.is_some();
        let motion = moving.then_some(ColliderMotion {
            linear_velocity: self.linear_velocity,
            angular_velocity: self.angular_velocity,
        });
        let lifetime = self
            .remove_at
            .map(|t| crate::collision::ColliderLifetime { remove_at: t });
        Some((collider, pose, motion, lifetime, path))
    }
}
