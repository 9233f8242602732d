//! Drawing the liquid with Bevy's renderer (cargo feature `render`).
//!
//! [`LiquidRenderPlugin`] goes next to [`MpmPlugins`](crate::plugin::MpmPlugins) in an app
//! with Bevy's `DefaultPlugins` (a window, or headless: [`headless::HeadlessRenderer`] renders
//! to an image and reads it back):
//!
//! ```rust,ignore
//! use bevy::prelude::*;
//! use treacle::render::{LiquidRenderPlugin, LiquidCamera, ParticleStyle, ColourField};
//!
//! app.add_plugins((DefaultPlugins, MpmPlugins, GamePlugin::default(), LiquidRenderPlugin::default()))
//!     .insert_resource(ParticleStyle { field: ColourField::Speed, ..default() });
//! app.world_mut().spawn((Camera3d::default(), LiquidCamera::default()));
//! ```
//!
//! What it draws:
//! - **Particles** as sphere impostors in **one draw call**: a static mesh of one triangle per
//!   particle slot whose vertex shader pulls the particle's centre and field value from one
//!   storage buffer (`[x, y, z, value]`, 16 bytes a particle), so the per-frame CPU cost is
//!   the copy of positions and values into that buffer ([`ParticleInstances`]). The value is
//!   mapped on the GPU through a perceptual colour map ([`colour::ColourMap::Viridis`]); the
//!   field and its range are chosen by the [`ParticleStyle`] resource.
//! - **Solids** following their pose every frame: every [`Collider`] (all
//!   [`ColliderShape`](crate::collision::ColliderShape) variants, triangle meshes included,
//!   placed by [`ColliderPose`]), the crate's rigid bodies (colliders with a
//!   [`RigidBody`]) and [`NozzleEmitter`]s (a tube whose tip is the path point at the current
//!   simulated time, turned along the emitter's axis by its [`EmitterFrame`]). Add
//!   [`NoLiquidVisual`] to an entity to leave it undrawn (e.g. one the game draws itself).
//! - **Stage** (with [`LiquidRenderPlugin::stage`]): a floor at the bottom of the domain (or
//!   where [`StageFloor`] says), a sun with shadows and ambient light; cameras with
//!   [`LiquidCamera`] are framed on the liquid's bounding box (or given bounds).
//! - **Surface mode** (with [`surface::SurfaceSettings::enabled`]): instead of the particles,
//!   the liquid surface reconstructed from them ([`crate::surface::reconstruct_surface`])
//!   every N frames, drawn with a PBR preset (honey, chocolate, ketchup, milk, water); see
//!   [`surface`].
//!
//! The plugin's systems run in `PostUpdate` ([`LiquidRenderSystems`]), before Bevy flushes the
//! frame's asset events: the particle slot mesh and instance buffer are render-world-only
//! assets, so a replacement after the flush would be extracted a frame late, find its data
//! gone and drop the particles from the image. Systems of your own that replace those assets
//! belong in [`LiquidRenderSystems::Upload`].
//!
//! Bevy's render crates declare a rust-version above this crate's but compile with it: build
//! with the `cargo render-build` / `render-test` / `render-clippy` / `render-run` aliases of
//! `.cargo/config.toml`, which add `--ignore-rust-version --features game,render`.
pub mod camera;
pub mod colour;
pub mod headless;
mod particles;
pub mod shapes;
pub mod surface;

use bevy::app::{App, Plugin, PostUpdate, Startup};
use bevy::asset::{AssetEventSystems, Assets, embedded_asset};
use bevy::color::Color;
use bevy::ecs::prelude::*;
use bevy::light::{DirectionalLight, GlobalAmbientLight};
use bevy::math::Quat;
use bevy::mesh::{Mesh, Mesh3d};
use bevy::pbr::{MaterialPlugin, MeshMaterial3d, StandardMaterial};
use bevy::transform::components::Transform;

use crate::collision::{Collider, ColliderPose};
use crate::config::MpmConfig;
use crate::emit::{EmitterFrame, NozzleEmitter};
use crate::math::Vec3;
use crate::rigid::RigidBody;
use crate::step::schedule::SimulationClock;

pub use camera::{LiquidCamera, ViewFraming, frame_bounds};
pub use colour::ColourMap;
pub use particles::{
    ParticleCloud, ParticleInstances, ParticleMaterial, deviatoric_norm, gather_particle_instances,
    slot_mesh, spawn_particle_cloud, upload_particle_instances,
};

/// Where the particle positions and values come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ParticleFeed {
    /// The particle entities of this world (`Position` ... `With<Particle>`), read every frame
    /// in `PostUpdate` ([`gather_particle_instances`]).
    #[default]
    World,
    /// The app writes [`ParticleInstances`] itself (frames read from files).
    External,
}

/// The particle field mapped to colour.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum ColourField {
    /// |v| \[m/s\].
    #[default]
    Speed,
    /// Temperature (scene unit); particles without one are grey.
    Temperature,
    /// Phase index (0 liquid … 1 solid); particles without one are grey.
    Phase,
    /// Material id (its order in the scene).
    Material,
    /// ‖dev σ‖ \[Pa\], the Frobenius norm of the deviatoric Cauchy stress
    /// ([`deviatoric_norm`]).
    StressNorm,
    /// Density ρ \[kg/m³\].
    Density,
    /// Height y \[m\].
    Height,
    /// A field stored in a frame file by name (frames only; grey in the live world).
    Stored(String),
}

impl ColourField {
    /// Parses a CLI name: speed, temperature, phase, material, stress, density, y, or any
    /// other name (a field stored in the frame files).
    pub fn parse(name: &str) -> Self {
        match name {
            "speed" => Self::Speed,
            "temperature" => Self::Temperature,
            "phase" => Self::Phase,
            "material" => Self::Material,
            "stress" | "stress_norm" => Self::StressNorm,
            "density" => Self::Density,
            "y" | "height" => Self::Height,
            other => Self::Stored(other.to_string()),
        }
    }

    /// The name used in frame files (`treacle run` output fields) for this field.
    pub fn frame_name(&self) -> &str {
        match self {
            Self::Speed => "speed",
            Self::Temperature => "temperature",
            Self::Phase => "phase",
            Self::Material => "material",
            Self::StressNorm => "stress",
            Self::Density => "density",
            Self::Height => "y",
            Self::Stored(s) => s,
        }
    }
}

/// The value range mapped onto the colour map.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum ColourRange {
    /// The current particles' min and max (recomputed every frame).
    #[default]
    Auto,
    /// A fixed range (values outside are clamped to the end colours).
    Fixed {
        /// Value of the first colour.
        min: f32,
        /// Value of the last colour.
        max: f32,
    },
}

/// How particles look (a resource; change it at run time).
#[derive(Resource, Clone, Debug, PartialEq)]
pub struct ParticleStyle {
    /// Field mapped to colour.
    pub field: ColourField,
    /// Its range.
    pub range: ColourRange,
    /// Colour map (read when the plugin starts).
    pub map: ColourMap,
    /// Sphere radius \[m\]; [`LiquidRenderPlugin`] sets Δx/4 from `MpmConfig` at startup when
    /// this is 0 (two particles per cell along an axis, spheres just touching).
    pub radius: f32,
}

impl Default for ParticleStyle {
    fn default() -> Self {
        Self {
            field: ColourField::Speed,
            range: ColourRange::Auto,
            map: ColourMap::Viridis,
            radius: 0.0,
        }
    }
}

/// The floor of the stage (a resource): a horizontal square at height `y` centred at
/// `(center_x, center_z)`. Without it the floor lies at the bottom of `MpmConfig`'s domain.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct StageFloor {
    /// Height of the floor \[m\].
    pub y: f32,
    /// Centre x \[m\].
    pub center_x: f32,
    /// Centre z \[m\].
    pub center_z: f32,
    /// Half side \[m\].
    pub half_size: f32,
}

impl StageFloor {
    /// The floor under the domain of `config`, twice its horizontal extent.
    pub fn under_domain(config: &MpmConfig) -> Self {
        let (lo, hi) = (config.domain_min, config.domain_max);
        let c = 0.5 * (lo + hi);
        Self {
            y: lo.y,
            center_x: c.x,
            center_z: c.z,
            half_size: (hi - lo).max_element().max(1e-3),
        }
    }
}

/// Draws the liquid's particles and the solids around it (see the [module docs](self)).
///
/// Add it after Bevy's `DefaultPlugins` (it needs the asset, render and PBR plugins).
#[derive(Clone, Copy, Debug)]
pub struct LiquidRenderPlugin {
    /// Where the particles come from.
    pub feed: ParticleFeed,
    /// Add a floor, a sun and ambient light.
    pub stage: bool,
}

impl Default for LiquidRenderPlugin {
    fn default() -> Self {
        Self {
            feed: ParticleFeed::World,
            stage: true,
        }
    }
}

/// System sets of [`LiquidRenderPlugin`] in `PostUpdate`, in this order.
#[derive(SystemSet, Clone, Copy, Debug, Hash, PartialEq, Eq)]
pub enum LiquidRenderSystems {
    /// Particle entities → [`ParticleInstances`] (with [`ParticleFeed::World`]).
    Gather,
    /// [`ParticleInstances`] → the GPU buffer; solids and nozzles follow their poses; cameras
    /// are framed.
    Upload,
}

impl Plugin for LiquidRenderPlugin {
    fn build(&self, app: &mut App) {
        embedded_asset!(app, "particles.wesl");
        app.add_plugins((
            MaterialPlugin::<ParticleMaterial>::default(),
            surface::SurfacePlugin,
        ))
        .init_resource::<ParticleStyle>()
        .init_resource::<ParticleInstances>()
        .init_resource::<ViewFraming>()
        // Before Bevy flushes the frame's asset events: the particle slot mesh and instance
        // buffer are render-world-only assets, whose data leaves the main world when extracted.
        // Replaced after the flush, their `Modified` event would reach the next frame's
        // extraction, which finds the data gone ("already extracted") and drops the GPU copy:
        // the particles vanish. `Assets` allows this ambiguity, so the order the schedule
        // picked used to depend on unrelated systems.
        .configure_sets(
            PostUpdate,
            (LiquidRenderSystems::Gather, LiquidRenderSystems::Upload)
                .chain()
                .before(AssetEventSystems),
        )
        .add_systems(
            Startup,
            (default_radius, particles::spawn_particle_cloud).chain(),
        )
        .add_systems(
            PostUpdate,
            (
                upload_particle_instances,
                sync_solid_visuals,
                sync_nozzle_visuals,
                camera::frame_cameras,
            )
                .in_set(LiquidRenderSystems::Upload),
        );
        if self.feed == ParticleFeed::World {
            app.add_systems(
                PostUpdate,
                gather_particle_instances.in_set(LiquidRenderSystems::Gather),
            );
        }
        if self.stage {
            app.add_systems(Startup, spawn_lights)
                .add_systems(PostUpdate, sync_floor.in_set(LiquidRenderSystems::Upload));
        }
    }
}

/// Startup: a zero [`ParticleStyle::radius`] becomes Δx/4 (or 5 mm without `MpmConfig`).
fn default_radius(mut style: ResMut<ParticleStyle>, config: Option<Res<MpmConfig>>) {
    if style.radius <= 0.0 {
        style.radius = config.map_or(0.005, |c| 0.25 * c.dx);
    }
}

/// Leaves an entity undrawn by [`LiquidRenderPlugin`] (a collider, body or nozzle the game
/// draws itself).
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct NoLiquidVisual;

/// On a collider or nozzle: the entity that draws it.
#[derive(Component, Clone, Copy, Debug)]
pub struct SolidVisual(pub Entity);

/// On a drawing entity: the collider or nozzle it draws.
#[derive(Component, Clone, Copy, Debug)]
pub struct VisualOf(pub Entity);

/// Colours of the solids (linear RGB in a PBR material).
fn solid_material(kind: SolidKind) -> StandardMaterial {
    let (color, metallic, roughness) = match kind {
        SolidKind::Collider => (Color::srgb(0.62, 0.64, 0.70), 0.0, 0.7),
        SolidKind::Body => (Color::srgb(0.85, 0.45, 0.20), 0.0, 0.5),
        SolidKind::Nozzle => (Color::srgb(0.75, 0.76, 0.78), 0.9, 0.3),
        SolidKind::Floor => (Color::srgb(0.45, 0.46, 0.48), 0.0, 0.95),
    };
    StandardMaterial {
        base_color: color,
        metallic,
        perceptual_roughness: roughness,
        // Half-spaces and open tubes are seen from both sides.
        double_sided: matches!(kind, SolidKind::Nozzle),
        cull_mode: None,
        ..Default::default()
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum SolidKind {
    Collider,
    Body,
    Nozzle,
    Floor,
}

fn pose_transform(pose: &ColliderPose) -> Transform {
    Transform {
        translation: pose.translation,
        rotation: pose.rotation,
        scale: Vec3::ONE,
    }
}

/// Half side of the square drawn for a half-space: the domain's largest extent.
fn half_space_size(config: Option<&MpmConfig>) -> f32 {
    config.map_or(2.0, |c| {
        (c.domain_max - c.domain_min).max_element().max(1e-3)
    })
}

/// `PostUpdate`: gives every collider (and rigid body) a drawing entity, moves it to the
/// collider's pose, rebuilds its mesh when the shape changes, and removes drawings whose
/// collider is gone.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn sync_solid_visuals(
    mut commands: Commands,
    new: Query<
        (Entity, &Collider, &ColliderPose, Has<RigidBody>),
        (Without<SolidVisual>, Without<NoLiquidVisual>),
    >,
    changed: Query<(&Collider, &SolidVisual), Changed<Collider>>,
    drawn: Query<(&ColliderPose, &SolidVisual)>,
    mut visuals: Query<(Entity, &VisualOf, &mut Transform, Option<&Mesh3d>)>,
    sources: Query<(), Or<(With<Collider>, With<NozzleEmitter>)>>,
    config: Option<Res<MpmConfig>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    let size = half_space_size(config.as_deref());
    for (entity, collider, pose, is_body) in &new {
        let kind = if is_body {
            SolidKind::Body
        } else {
            SolidKind::Collider
        };
        let visual = commands
            .spawn((
                Mesh3d(meshes.add(shapes::collider_mesh(&collider.shape, size))),
                MeshMaterial3d(materials.add(solid_material(kind))),
                pose_transform(pose),
                VisualOf(entity),
            ))
            .id();
        commands.entity(entity).insert(SolidVisual(visual));
    }
    for (collider, visual) in &changed {
        if let Ok((_, _, _, Some(mesh))) = visuals.get(visual.0)
            && let Some(mut m) = meshes.get_mut(&mesh.0)
        {
            *m = shapes::collider_mesh(&collider.shape, size);
        }
    }
    for (pose, visual) in &drawn {
        if let Ok((_, _, mut t, _)) = visuals.get_mut(visual.0) {
            let new_t = pose_transform(pose);
            if *t != new_t {
                *t = new_t;
            }
        }
    }
    for (entity, of, _, _) in &visuals {
        if sources.get(of.0).is_err() {
            commands.entity(entity).despawn();
        }
    }
}

/// World pose of a nozzle's tip at simulated time `time`: the tool-path point in the
/// emitter's frame, with local +y turned to −axis (the tube extends upstream).
pub fn nozzle_pose(emitter: &NozzleEmitter, frame: &EmitterFrame, time: f64) -> Transform {
    let path_time = (time - emitter.start_time).clamp(0.0, emitter.path.duration().max(0.0));
    let (tip, _, _) = emitter.path.sample(path_time);
    let tip = frame.point(tip).as_vec3();
    let axis = (frame.rotation * emitter.axis).normalize_or(-Vec3::Y);
    Transform {
        translation: tip,
        rotation: Quat::from_rotation_arc(Vec3::Y, -axis),
        scale: Vec3::ONE,
    }
}

/// `PostUpdate`: draws every [`NozzleEmitter`] as a tube at its tip's current position.
#[allow(clippy::type_complexity)]
pub fn sync_nozzle_visuals(
    mut commands: Commands,
    new: Query<
        (Entity, &NozzleEmitter, &EmitterFrame),
        (Without<SolidVisual>, Without<NoLiquidVisual>),
    >,
    drawn: Query<(&NozzleEmitter, &EmitterFrame, &SolidVisual)>,
    mut transforms: Query<&mut Transform, With<VisualOf>>,
    clock: Option<Res<SimulationClock>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    let time = clock.map_or(0.0, |c| c.time);
    for (entity, emitter, frame) in &new {
        let visual = commands
            .spawn((
                Mesh3d(meshes.add(shapes::nozzle_mesh(emitter.radius))),
                MeshMaterial3d(materials.add(solid_material(SolidKind::Nozzle))),
                nozzle_pose(emitter, frame, time),
                VisualOf(entity),
            ))
            .id();
        commands.entity(entity).insert(SolidVisual(visual));
    }
    for (emitter, frame, visual) in &drawn {
        if let Ok(mut t) = transforms.get_mut(visual.0) {
            let new_t = nozzle_pose(emitter, frame, time);
            if *t != new_t {
                *t = new_t;
            }
        }
    }
}

/// The floor entity of the stage.
#[derive(Component, Clone, Copy, Debug)]
pub struct StageFloorVisual;

/// `PostUpdate` (with the stage): places the floor from [`StageFloor`], or under
/// `MpmConfig`'s domain; spawned on first use, moved when either changes.
fn sync_floor(
    mut commands: Commands,
    floor: Option<Res<StageFloor>>,
    config: Option<Res<MpmConfig>>,
    mut visual: Query<(&mut Transform, &Mesh3d), With<StageFloorVisual>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut last: Local<Option<StageFloor>>,
) {
    let Some(f) = floor
        .as_deref()
        .copied()
        .or_else(|| config.as_deref().map(StageFloor::under_domain))
    else {
        return;
    };
    if *last == Some(f) {
        return;
    }
    *last = Some(f);
    let t = Transform::from_xyz(f.center_x, f.y, f.center_z);
    match visual.single_mut() {
        Ok((mut tr, mesh)) => {
            *tr = t;
            if let Some(mut m) = meshes.get_mut(&mesh.0) {
                *m = shapes::floor_mesh(f.half_size);
            }
        }
        Err(_) => {
            commands.spawn((
                Mesh3d(meshes.add(shapes::floor_mesh(f.half_size))),
                MeshMaterial3d(materials.add(solid_material(SolidKind::Floor))),
                t,
                StageFloorVisual,
            ));
        }
    }
}

/// Startup (with the stage): a sun from the upper front left casting shadows, and ambient
/// light.
fn spawn_lights(mut commands: Commands) {
    commands.spawn((
        DirectionalLight {
            illuminance: 4_500.0,
            shadow_maps_enabled: true,
            ..Default::default()
        },
        Transform::from_xyz(-1.0, 3.0, 2.0).looking_at(Vec3::ZERO, Vec3::Y),
    ));
    commands.insert_resource(GlobalAmbientLight {
        color: Color::WHITE,
        brightness: 300.0,
        ..Default::default()
    });
}
