//! Particle sources: the 3D-printing nozzle (ALGORITHM §4.4, step S16 of §2.3).
//!
//! - [`NozzleEmitter`] (an entity) moves along a [`ToolPath`] and deposits particles of one
//!   material with volume rate Q̇; [`nozzle`] has the model.
//! - The tool path comes from a G-code file ([`gcode`]: G0/G1 with X Y Z E F, G90/G91,
//!   M82/M83, G20/G21; travel moves do not emit), mapped into the scene by [`GcodeMapping`]
//!   (scale, axes, origin), from a polyline ([`ToolPath::polyline`]) or held at one point
//!   ([`ToolPath::fixed`]).
//! - [`EmitterPlugin`] runs [`emit_particles`] in
//!   [`EmitSystems::Spawn`], after the commit of the step, so
//!   new particles start the next step with the state of t_{n+1}.
//! - [`DelayedBody`] ([`release`]) holds a liquid body that appears at a given time; the
//!   same plugin releases it.
//! - New particles get the per-particle state of their material from
//!   [`ParticleInitializers`]: the shipped rheology models' initial states are registered by
//!   the plugin; other plugins (a custom model, phase change) add theirs.
//!
//! In a scene file the `emitters` list builds them ([`EmitterSpec`], `docs/scenes.md`).
//!
//! ```
//! use bevy_app::App;
//! use glam::DVec3;
//! use treacle::emit::{EmitterPlugin, NozzleEmitter, ToolPath};
//! use treacle::prelude::*;
//!
//! let mut materials = Materials::default();
//! let paste = materials.add(FluidMaterial::newtonian("paste", 1000.0, 2.0, 1.0));
//! let config = MpmConfig { dx: 0.01, ..Default::default() };
//! let mut app = App::new();
//! app.insert_resource(config).insert_resource(materials).add_plugins(MpmPlugins);
//! app.add_plugins(EmitterPlugin);
//! // A straight bead 0.2 m long at 0.1 m/s, 0.05 m above the floor.
//! let path = ToolPath::polyline(&[DVec3::new(0.4, 0.05, 0.5), DVec3::new(0.6, 0.05, 0.5)], 0.1).unwrap();
//! app.world_mut().spawn(NozzleEmitter::new(path, Vec3::NEG_Y, 0.01, 1e-5, 0.005, paste));
//! app.update();
//! ```
pub mod gcode;
pub mod nozzle;
pub mod release;

use std::path::Path;

use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

pub use gcode::{GcodeError, GcodeMove, GcodeProgram, load_gcode, parse_gcode};
pub use nozzle::{
    Emission, EmitterFrame, EmitterState, InBore, NozzleEmitter, PathSegment, Slot, ToolPath,
    ToolPathError, disk_lattice, slot_lattice,
};
pub use release::{DelayedBody, release_bodies};

use crate::components::{Acceleration, ParticleBundle, Position, StabilityData, Velocity};
use crate::config::MpmConfig;
use crate::material::{MaterialId, Materials};
use crate::math::{Real, Vec3};
pub use crate::spawn::{ParticleInitializer, ParticleInitializers};
use crate::step::schedule::{
    EmitSystems, MpmStep, SimulationClock, StepContext, init_step_schedule,
};
use crate::thermal::components::{FluxDivergence, PredictedTemperature, Temperature};
use crate::validation::{FieldIssue, SceneContext};

/// Registers [`emit_particles`] and then [`release_bodies`] in [`EmitSystems::Spawn`].
/// Plugins may be added in any order; the state new particles need comes from the
/// [`ParticleInitializers`] other plugins register (every `RheologyPlugin<M>` registers its
/// model's).
pub struct EmitterPlugin;

impl Plugin for EmitterPlugin {
    fn build(&self, app: &mut App) {
        init_step_schedule(app);
        app.init_resource::<ParticleInitializers>();
        crate::distributed::travel_with::<InBore>(app.world_mut(), 1, pack_in_bore, insert_in_bore);
        app.add_systems(
            MpmStep,
            (emit_particles, release_bodies)
                .chain()
                .in_set(EmitSystems::Spawn),
        );
    }
}

/// The emitters of `world` in entity order: the order they were spawned in, the same on every
/// rank of a distributed run (each spawns the scene's emitters in scene order), whatever
/// their `Entity`.
fn emitters_in_order(world: &World) -> Vec<Entity> {
    let mut emitters: Vec<Entity> = world
        .try_query_filtered::<Entity, With<NozzleEmitter>>()
        .map(|mut q| q.iter(world).collect())
        .unwrap_or_default();
    emitters.sort();
    emitters
}

/// [`InBore`] travels between ranks as its emitter's place in [`emitters_in_order`].
fn pack_in_bore(world: &World, e: Entity, out: &mut Vec<u32>) -> bool {
    let Some(bore) = world.get::<InBore>(e) else {
        return false;
    };
    let at = emitters_in_order(world).iter().position(|&n| n == bore.0);
    out.push(at.map_or(u32::MAX, |i| i as u32));
    true
}

/// The [`InBore`] of [`pack_in_bore`] on the receiving rank (none if its emitter is gone: the
/// particle has left the bore).
fn insert_in_bore(e: &mut EntityWorldMut<'_>, w: &[u32]) {
    let emitter = emitters_in_order(e.world()).get(w[0] as usize).copied();
    if let Some(emitter) = emitter {
        e.insert(InBore(emitter));
    }
}

/// S16 (§4.4): advances every [`NozzleEmitter`] over the step just taken
/// (\[t_n, t_n + Δt\]) and spawns its particles, with the state their material needs.
/// Nothing happens in the start-up rate evaluation.
///
/// Reads `StepContext`, `SimulationClock`, `MpmConfig`, `Materials`, `NozzleEmitter`,
/// `ParticleInitializers`; writes `EmitterState` and `EnergyTerms::unmeasured_input` (while a
/// nozzle extrudes); spawns particles.
pub fn emit_particles(world: &mut World) {
    let ctx = *world.resource::<StepContext>();
    if ctx.rate_evaluation || ctx.dt.is_nan() || ctx.dt <= 0.0 {
        return;
    }
    let t0 = world.resource::<SimulationClock>().time;
    let t1 = t0 + ctx.dt;
    let mut q = world.query::<(
        Entity,
        &NozzleEmitter,
        &mut EmitterState,
        Option<&EmitterFrame>,
    )>();
    let mut emitters: Vec<(Entity, NozzleEmitter, EmitterFrame)> = q
        .iter(world)
        .map(|(e, n, _, f)| (e, n.clone(), f.copied().unwrap_or_default()))
        .collect();
    if emitters.is_empty() {
        return;
    }
    emitters.sort_by_key(|(e, _, _)| *e);
    if emitters
        .iter()
        .any(|(_, n, _)| n.extruding_time(t1) > n.extruding_time(t0))
        && let Some(mut terms) = world.get_resource_mut::<crate::step::energy::EnergyTerms>()
    {
        terms.unmeasured_input = true;
    }
    drive_bores(world, &emitters, t1);
    let mut out = Vec::new();
    for (entity, emitter, frame) in emitters {
        out.clear();
        let Ok((_, _, mut state, _)) = q.get_mut(world, entity) else {
            continue;
        };
        state.advance(&emitter, &frame, t0, t1, &mut out);
        if out.is_empty() {
            continue;
        }
        let h = emitter.spacing;
        let born = spawn_liquid(
            world,
            &out,
            h * h * h,
            emitter.material,
            emitter.temperature,
        );
        if emitter.bore > 0.0 {
            for e in born {
                world.entity_mut(e).insert(InBore(entity));
            }
        }
    }
}

/// The driven bores ([`NozzleEmitter::bore`]) at the end of a step (time `t`): a particle
/// still behind its nozzle's tip gets the bore's velocity and a zero acceleration; one that
/// has passed the tip (or whose emitter is gone) leaves the bore for good.
fn drive_bores(world: &mut World, emitters: &[(Entity, NozzleEmitter, EmitterFrame)], t: f64) {
    let drives: Vec<(Entity, (DVec3, DVec3, Vec3))> = emitters
        .iter()
        .filter(|(_, n, _)| n.bore > 0.0)
        .map(|(e, n, f)| {
            let layer = world
                .get::<EmitterState>(*e)
                .and_then(EmitterState::layer_size)
                .unwrap_or_else(|| n.lattice().len());
            (*e, n.bore_drive(f, t, layer))
        })
        .collect();
    let mut q = world.query::<(Entity, &InBore, &Position, &mut Velocity, &mut Acceleration)>();
    let mut left = Vec::new();
    for (particle, bore, x, mut v, mut a) in q.iter_mut(world) {
        match drives.iter().find(|(e, _)| *e == bore.0) {
            Some((_, (tip, axis, velocity))) if (x.0.as_dvec3() - *tip).dot(*axis) < 0.0 => {
                v.0 = *velocity;
                a.0 = Vec3::ZERO;
            }
            _ => left.push(particle),
        }
    }
    for particle in left {
        world.entity_mut(particle).remove::<InBore>();
    }
}

/// [`spawn_liquid`] for a body: particles at `positions`, all moving at `velocity` (a body
/// released during the run, a game's splash).
pub fn spawn_liquid_body(
    world: &mut World,
    positions: &[Vec3],
    velocity: Vec3,
    volume: Real,
    material: MaterialId,
    temperature: Option<Real>,
) -> Vec<Entity> {
    let particles: Vec<Emission> = positions
        .iter()
        .map(|&position| Emission { position, velocity })
        .collect();
    spawn_liquid(world, &particles, volume, material, temperature)
}

/// Spawns particles of `material` at rest density, volume `volume` \[m³\] each, at the
/// positions and velocities of `particles`, with the state a particle born during a run needs:
/// the stability data of its material (so that the next Δt accounts for it), the thermal
/// components at `temperature` (`None`: unheated) and what the registered
/// [`ParticleInitializers`] add (a rheology model's state). Returns the new entities in the
/// order of `particles`; nothing for an unknown material. On several ranks
/// ([`crate::distributed::Ranks`]) every rank runs the same emitters and spawns only the
/// particles it owns (ALGORITHM §12), and the entities are those of its own particles.
pub fn spawn_liquid(
    world: &mut World,
    particles: &[Emission],
    volume: Real,
    material: MaterialId,
    temperature: Option<Real>,
) -> Vec<Entity> {
    let owned: Vec<Emission>;
    let particles = match world
        .get_resource::<crate::distributed::Ranks>()
        .filter(|r| r.size() > 1)
    {
        Some(ranks) => {
            let layout = crate::distributed::layout_of(world);
            owned = particles
                .iter()
                .filter(|p| ranks.owns(&layout, p.position))
                .copied()
                .collect();
            &owned[..]
        }
        None => particles,
    };
    let gravity = world.resource::<MpmConfig>().gravity;
    // ρ₀ and the stability data at rest density (no copy of the material: this runs every step
    // an emitter emits).
    let Some((rho0, stability)) = world
        .resource::<Materials>()
        .list
        .get(material.0 as usize)
        .map(|m| {
            (
                m.density,
                StabilityData {
                    wave_speed_sq: m.sound_speed * m.sound_speed,
                    kinematic_viscosity: m.local_fraction * m.viscosity / m.density,
                    relaxation_rate: 0.0,
                },
            )
        })
    else {
        return Vec::new();
    };
    let ids: Vec<Entity> = world
        .spawn_batch(particles.iter().map(|p| {
            (
                ParticleBundle::new(p.position, p.velocity, gravity, volume, rho0, material),
                stability,
            )
        }))
        .collect();
    if let Some(t) = temperature {
        world.insert_batch(ids.iter().map(|&e| {
            (
                e,
                (
                    Temperature {
                        value: t,
                        rate: 0.0,
                    },
                    FluxDivergence::default(),
                    PredictedTemperature(t),
                ),
            )
        }));
    }
    if let Some(inits) = world.get_resource::<ParticleInitializers>().cloned() {
        inits.run(world, material, &ids);
    }
    ids
}

/// Which scene axis the G-code's Z (up) axis becomes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum GcodeUp {
    /// Scene y is up (the default gravity): G-code (X, Y, Z) → scene (X, Z, −Y), a proper
    /// rotation (no mirror image).
    #[default]
    Y,
    /// Scene z is up: G-code (X, Y, Z) → scene (X, Y, Z).
    Z,
}

/// How a G-code program is placed into the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GcodeMapping {
    /// Metres per G-code millimetre (e.g. 10⁻³ for a life-size print; larger values enlarge
    /// it).
    pub scale: f64,
    /// Scene position of the G-code origin \[m\] (normally a point on the bed's top face).
    pub origin: DVec3,
    /// Up axis of the scene.
    pub up: GcodeUp,
    /// Factor on every feed rate (> 0): 2 runs the program twice as fast. Time in the
    /// G-code is otherwise kept (a scaled-up print moves faster in m/s).
    pub feed_scale: f64,
}

impl Default for GcodeMapping {
    fn default() -> Self {
        Self {
            scale: 1e-3,
            origin: DVec3::ZERO,
            up: GcodeUp::Y,
            feed_scale: 1.0,
        }
    }
}

impl GcodeMapping {
    /// A G-code point \[mm\] in scene coordinates \[m\].
    pub fn map_point(&self, p: DVec3) -> DVec3 {
        let q = match self.up {
            GcodeUp::Y => DVec3::new(p.x, p.z, -p.y),
            GcodeUp::Z => p,
        };
        self.origin + q * self.scale
    }
}

impl GcodeProgram {
    /// The tool path of this program in the scene. Errors if the mapping is degenerate or no
    /// move extrudes.
    pub fn to_tool_path(&self, mapping: &GcodeMapping) -> Result<ToolPath, ToolPathError> {
        if !(mapping.feed_scale.is_finite() && mapping.feed_scale > 0.0) {
            return Err(ToolPathError::BadSegment {
                index: 0,
                problem: format!("feed_scale must be > 0 (got {})", mapping.feed_scale),
            });
        }
        let segments = self
            .moves
            .iter()
            .map(|m| PathSegment {
                start: mapping.map_point(m.from),
                end: mapping.map_point(m.to),
                duration: m.duration / mapping.feed_scale,
                extrude: m.extrudes(),
            })
            .collect();
        ToolPath::new(segments)
    }
}

/// Where a scene emitter's tool path comes from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum ToolPathSpec {
    /// A G-code file ([`gcode`]), placed by a [`GcodeMapping`].
    Gcode {
        /// File path: absolute, or relative to the scene file's directory, or (if not found
        /// there) to the crate's `assets/` directory.
        file: String,
        /// Metres per G-code millimetre; > 0. Default 0.001.
        #[serde(default = "default_scale")]
        scale: f64,
        /// Scene position of the G-code origin \[m\]. Default `(0, 0, 0)`.
        #[serde(default)]
        origin: Vec3,
        /// Scene up axis. Default `Y`.
        #[serde(default)]
        up: GcodeUp,
        /// Factor on every feed rate; > 0. Default 1.
        #[serde(default = "default_feed_scale")]
        feed_scale: f64,
    },
    /// A polyline through `points` \[m\], all extruding, at `speed` \[m/s\].
    Polyline {
        /// Points \[m\] (at least two distinct).
        points: Vec<Vec3>,
        /// Nozzle speed \[m/s\]; > 0.
        speed: f64,
    },
    /// A nozzle held at `at` \[m\], extruding for `duration` \[s\] ([`ToolPath::fixed`]).
    Fixed {
        /// Position of the nozzle tip \[m\].
        at: Vec3,
        /// Extruding time \[s\]; finite and > 0.
        duration: f64,
    },
}

fn default_scale() -> f64 {
    1e-3
}
fn default_feed_scale() -> f64 {
    1.0
}
fn default_axis() -> Vec3 {
    Vec3::NEG_Y
}

/// A nozzle emitter in a scene file (`emitters: [ ... ]`), see `docs/scenes.md`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EmitterSpec {
    /// Name of a material in the scene's `materials`.
    pub material: String,
    /// The tool path.
    pub path: ToolPathSpec,
    /// Extrusion direction e (non-zero; normalised). Default `(0, -1, 0)`.
    #[serde(default = "default_axis")]
    pub axis: Vec3,
    /// Nozzle radius r_n \[m\]; > 0.
    pub radius: Real,
    /// Volume rate Q̇ \[m³/s\] while extruding; > 0.
    pub volume_rate: f64,
    /// Particle spacing h_p \[m\]. Default dx / particles_per_cell.
    #[serde(default)]
    pub spacing: Option<Real>,
    /// Injection temperature T_inj (scene temperature unit). Required for materials with a
    /// phase change or a temperature-dependent viscosity; must exceed their melting
    /// temperature. Default none (unheated).
    #[serde(default)]
    pub temperature: Option<Real>,
    /// Simulation time at which the path starts \[s\]; ≥ 0. Default 0.
    #[serde(default)]
    pub start_time: f64,
    /// Simulation time after which nothing is emitted \[s\]. Default: the path's end.
    #[serde(default)]
    pub stop_time: Option<f64>,
    /// Jitter as a fraction of h_p, in \[0, 0.1\]. Default 0.1.
    #[serde(default = "default_jitter")]
    pub jitter: Real,
    /// Length of the driven bore \[m\] ([`NozzleEmitter::bore`]); ≥ 0. Default 0 (none).
    #[serde(default)]
    pub bore: Real,
    /// A slot opening ([`NozzleEmitter::slot`]): `Some((direction: (x, y, z), length: L))`.
    /// Default `None` (round).
    #[serde(default)]
    pub slot: Option<Slot>,
}

fn default_jitter() -> Real {
    0.1
}

impl EmitterSpec {
    /// Reads the tool path (G-code files resolved against `base_dir`, then `assets/`).
    /// Errors are `(field, message)`; G-code errors name file and line.
    pub fn tool_path(&self, base_dir: &Path) -> Result<ToolPath, (&'static str, String)> {
        match &self.path {
            ToolPathSpec::Gcode {
                file,
                scale,
                origin,
                up,
                feed_scale,
            } => {
                if !(scale.is_finite() && *scale > 0.0) {
                    return Err(("path.scale", format!("must be > 0 m/mm (got {scale})")));
                }
                if !(feed_scale.is_finite() && *feed_scale > 0.0) {
                    return Err(("path.feed_scale", format!("must be > 0 (got {feed_scale})")));
                }
                if !origin.is_finite() {
                    return Err(("path.origin", "must have finite components [m]".into()));
                }
                let resolved =
                    crate::validation::resolve_asset_path(file, base_dir).map_err(|tried| {
                        let tried: Vec<String> =
                            tried.iter().map(|p| format!("`{}`", p.display())).collect();
                        (
                            "path.file",
                            format!(
                                "G-code file `{file}` not found (tried {})",
                                tried.join(", ")
                            ),
                        )
                    })?;
                let program = load_gcode(&resolved).map_err(|e| ("path.file", e.to_string()))?;
                let mapping = GcodeMapping {
                    scale: *scale,
                    origin: origin.as_dvec3(),
                    up: *up,
                    feed_scale: *feed_scale,
                };
                program
                    .to_tool_path(&mapping)
                    .map_err(|e| ("path.file", format!("{}: {e}", resolved.display())))
            }
            ToolPathSpec::Polyline { points, speed } => {
                if points.iter().any(|p| !p.is_finite()) {
                    return Err(("path.points", "must have finite components [m]".into()));
                }
                let pts: Vec<DVec3> = points.iter().map(|p| p.as_dvec3()).collect();
                ToolPath::polyline(&pts, *speed).map_err(|e| match e {
                    ToolPathError::BadSegment { index: 0, problem }
                        if problem.contains("speed") =>
                    {
                        ("path.speed", problem)
                    }
                    other => (
                        "path.points",
                        format!("{other} (need at least two distinct points)"),
                    ),
                })
            }
            ToolPathSpec::Fixed { at, duration } => {
                if !at.is_finite() {
                    return Err(("path.at", "must have finite components [m]".into()));
                }
                ToolPath::fixed(at.as_dvec3(), *duration).map_err(|_| {
                    (
                        "path.duration",
                        format!("must be finite and > 0 s (got {duration})"),
                    )
                })
            }
        }
    }

    /// The emitter component (`seed` seeds its jitter; `default_spacing` is dx/ppc).
    pub fn build(
        &self,
        base_dir: &Path,
        material: MaterialId,
        default_spacing: Real,
        seed: u64,
    ) -> Result<NozzleEmitter, (&'static str, String)> {
        let path = self.tool_path(base_dir)?;
        let mut e = NozzleEmitter::new(
            path,
            self.axis,
            self.radius,
            self.volume_rate,
            self.spacing.unwrap_or(default_spacing),
            material,
        )
        .with_window(self.start_time, self.stop_time)
        .with_jitter(self.jitter, seed)
        .with_bore(self.bore);
        e.slot = self.slot;
        e.temperature = self.temperature;
        e.validate()?;
        Ok(e)
    }
}

/// The seed of emitter `index` of a scene with seed `seed` (a stream independent of the
/// bodies').
pub fn emitter_seed(seed: u64, index: usize) -> u64 {
    seed ^ 0xD1B5_4A32_D192_ED03u64.wrapping_mul(index as u64 + 1)
}

/// Checks a scene's `emitters` section (material, tool path and G-code, parameters, domain)
/// against the scene's facts `ctx`. Returns every issue. (The injection temperature against the
/// material's heat and phase change is a cross-section check of the loader.)
pub fn validate_emitters(emitters: &[EmitterSpec], ctx: &SceneContext) -> Vec<FieldIssue> {
    let mut issues = Vec::new();
    for (i, spec) in emitters.iter().enumerate() {
        let at = |f: &str| format!("emitters[{i}].{f}");
        let Some(mi) = ctx.material(&spec.material) else {
            issues.push(FieldIssue::new(
                at("material"),
                format!("unknown material `{}`", spec.material),
            ));
            continue;
        };
        let emitter = match spec.build(
            ctx.base_dir,
            MaterialId(mi as u16),
            ctx.particle_spacing(),
            0,
        ) {
            Ok(e) => e,
            Err((field, message)) => {
                issues.push(FieldIssue::new(at(field), message));
                continue;
            }
        };
        if emitter.spacing > ctx.dx {
            issues.push(FieldIssue::new(
                at("spacing"),
                format!(
                    "must not exceed dx = {} m (got {} m; the default is dx/particles_per_cell)",
                    ctx.dx, emitter.spacing
                ),
            ));
        }
        // The nozzle and its lattice must stay inside the domain.
        let (lo, hi) = emitter.path.bounds();
        let back = -emitter.axis.as_dvec3().normalize_or_zero() * emitter.bore as f64;
        let (lo, hi) = (lo.min(lo + back), hi.max(hi + back));
        // The layer's extent: the lattice's bounding box plus half a spacing (a particle's own
        // half cell).
        let half = 0.5 * emitter.spacing as f64;
        let (off_lo, off_hi) = emitter.lattice().iter().fold(
            (DVec3::splat(-half), DVec3::splat(half)),
            |(l, h), p| {
                let p = p.as_dvec3();
                (l.min(p - half), h.max(p + half))
            },
        );
        let (lo, hi) = (lo + off_lo, hi + off_hi);
        let (dmin, dmax) = (ctx.domain_min.as_dvec3(), ctx.domain_max.as_dvec3());
        // Single-precision offsets: a relative 10⁻⁶ of the domain is rounding, not overhang.
        let slack = 1e-6 * (dmax - dmin).max_element();
        if (lo + slack).cmplt(dmin).any() || (hi - slack).cmpgt(dmax).any() {
            issues.push(FieldIssue::new(
                at("path"),
                format!(
                    "the tool path (with the nozzle's opening and bore) spans [{:.4?}, {:.4?}] m, outside the domain [{}, {}] m",
                    lo.to_array(),
                    hi.to_array(),
                    ctx.domain_min,
                    ctx.domain_max
                ),
            ));
        }
    }
    issues
}
