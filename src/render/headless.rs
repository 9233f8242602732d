//! Headless rendering to PNG: a Bevy app without a window renders into an `Image`, reads it
//! back with Bevy's screenshot API and writes PNG files; used by `treacle render`.
//!
//! ```rust,ignore
//! let mut r = HeadlessRenderer::new(&RenderOptions::default())?;
//! r.set_scene_objects(&scene);                      // colliders, bodies, nozzles
//! r.set_frame(&frame, &ColourField::Speed, ColourRange::Auto)?;
//! r.frame_camera(lo, hi);
//! r.render()?.write_png(Path::new("frame.png"))?;
//! ```
//!
//! It needs a GPU adapter: on a machine without a GPU, Mesa's software Vulkan driver lavapipe
//! (Debian: `apt-get install mesa-vulkan-drivers`).
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use bevy::DefaultPlugins;
use bevy::app::{App, PluginGroup};
use bevy::asset::{Assets, Handle};
use bevy::camera::{
    Camera, Camera3d, ClearColorConfig, PerspectiveProjection, Projection, RenderTarget,
};
use bevy::color::Color;
use bevy::ecs::prelude::*;
use bevy::image::Image;
use bevy::render::RenderApp;
use bevy::render::RenderPlugin;
use bevy::render::pipelined_rendering::PipelinedRenderingPlugin;
use bevy::render::render_resource::{PipelineCache, TextureFormat};
use bevy::render::settings::{Backends, RenderCreation, WgpuSettings};
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::render::view::{Msaa, Tonemapping};
use bevy::transform::components::{GlobalTransform, Transform};
use bevy::window::{ExitCondition, WindowPlugin};

use crate::collision::{Collider, ColliderMotion, ColliderPose};
use crate::emit::{EmitterFrame, NozzleEmitter};
use crate::math::Vec3;
use crate::output::{OutputError, ParticleFrame};
use crate::rigid::RigidBody;
use crate::scene::{CameraPlacement, CameraSpec, Scene};
use crate::step::schedule::SimulationClock;

use super::surface::{SurfaceLook, SurfacePreset, SurfaceSettings};
use super::{
    ColourField, ColourRange, LiquidCamera, LiquidRenderPlugin, ParticleFeed, ParticleInstances,
    ParticleStyle, StageFloor, ViewFraming,
};

/// Options of a [`HeadlessRenderer`].
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Image width \[px\].
    pub width: u32,
    /// Image height \[px\].
    pub height: u32,
    /// Vertical field of view \[rad\].
    pub fov_y: f32,
    /// Background colour (sRGB).
    pub background: [f32; 3],
    /// Keep Bevy's log output (wgpu warnings and errors) on stderr.
    pub log: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            width: 960,
            height: 640,
            fov_y: std::f32::consts::FRAC_PI_4,
            background: [0.78, 0.84, 0.90],
            log: false,
        }
    }
}

/// Errors of headless rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// Bevy found no GPU adapter (or could not start the renderer).
    #[error(
        "cannot start the renderer: {0}\n(no GPU adapter? on a machine without a GPU install \
         Mesa's software Vulkan driver: apt-get install mesa-vulkan-drivers)"
    )]
    NoRenderer(String),
    /// The screenshot did not arrive.
    #[error("the renderer produced no image after {0} updates")]
    NoImage(u32),
    /// The image read back has an unexpected size or format.
    #[error("the image read back is {got} bytes, expected {expected} (RGBA8 {width}x{height})")]
    BadImage {
        /// Bytes received.
        got: usize,
        /// Bytes expected.
        expected: usize,
        /// Width \[px\].
        width: u32,
        /// Height \[px\].
        height: u32,
    },
    /// Image size out of range.
    #[error("image size {width}x{height}: width and height must be between 16 and 8192 pixels")]
    BadSize {
        /// Width \[px\].
        width: u32,
        /// Height \[px\].
        height: u32,
    },
    /// A frame lacks the field to colour by.
    #[error("{path}: no field `{field}` to colour by (available: {available})")]
    MissingField {
        /// The frame file (or the scene).
        path: PathBuf,
        /// The field asked for.
        field: String,
        /// The fields it has.
        available: String,
    },
    /// A frame file could not be read.
    #[error(transparent)]
    Frame(#[from] OutputError),
    /// The simulation of a scene failed.
    #[error("{0}")]
    Simulation(String),
    /// A PNG could not be written.
    #[error("cannot write {path}: {message}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
}

/// An RGBA8 (sRGB) image read back from the GPU.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RenderedImage {
    /// Width \[px\].
    pub width: u32,
    /// Height \[px\].
    pub height: u32,
    /// Row-major RGBA bytes, top row first.
    pub rgba: Vec<u8>,
}

impl RenderedImage {
    /// The RGBA of pixel (x, y), (0, 0) at the top left.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [
            self.rgba[i],
            self.rgba[i + 1],
            self.rgba[i + 2],
            self.rgba[i + 3],
        ]
    }

    /// PNG bytes (RGB, 8 bit).
    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
            let rgb: Vec<u8> = self
                .rgba
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect();
            // Writing into a Vec cannot fail for a consistent header and data length.
            let mut w = enc.write_header().expect("PNG header into memory");
            w.write_image_data(&rgb).expect("PNG data into memory");
        }
        out
    }

    /// Writes the image as PNG (its directory must exist).
    pub fn write_png(&self, path: &Path) -> Result<(), RenderError> {
        crate::output::write_atomic(path, &self.encode_png()).map_err(|e| RenderError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }
}

/// A windowless Bevy app with [`LiquidRenderPlugin`] (fed externally) rendering into an image.
pub struct HeadlessRenderer {
    app: App,
    target: Handle<Image>,
    camera: Entity,
    width: u32,
    height: u32,
    warm: bool,
    /// Mirrors of another world's colliders and nozzles (source entity → entity here).
    mirrors: HashMap<Entity, Entity>,
    /// Colliders of a scene with their scripted motion (for frames read from files).
    scripted: Vec<(
        Entity,
        ColliderPose,
        ColliderMotion,
        Option<crate::collision::ColliderPath>,
    )>,
    /// Colliders of a scene removed at a time (`remove_at`): drawn in frames before it only.
    timed: Vec<(Entity, crate::collision::Collider, f64)>,
    /// The camera was placed at a fixed eye ([`HeadlessRenderer::place_camera`]).
    fixed_camera: bool,
    /// Sphere radius of [`HeadlessRenderer::set_frame`] (`None`: from the frame's spacing).
    frame_radius: Option<f32>,
}

/// Most updates waited for a screenshot (and, before the first, for shaders and pipelines).
const MAX_UPDATES: u32 = 400;

impl HeadlessRenderer {
    /// Starts the renderer (Vulkan, synchronous pipeline compilation, no window), fed
    /// externally ([`ParticleFeed::External`]: [`set_particles`](Self::set_particles),
    /// [`set_frame`](Self::set_frame)).
    pub fn new(opts: &RenderOptions) -> Result<Self, RenderError> {
        Self::with_app(opts, ParticleFeed::External, |_| {})
    }

    /// A renderer whose app also gets `setup` (called after Bevy's plugins and
    /// [`LiquidRenderPlugin`], before the app is finished): e.g. `MpmPlugins` and a liquid, with
    /// `feed` = [`ParticleFeed::World`] so that the particle entities of the same world are
    /// drawn.
    pub fn with_app(
        opts: &RenderOptions,
        feed: ParticleFeed,
        setup: impl FnOnce(&mut App) + std::panic::UnwindSafe,
    ) -> Result<Self, RenderError> {
        let (width, height) = (opts.width, opts.height);
        if !(16..=8192).contains(&width) || !(16..=8192).contains(&height) {
            return Err(RenderError::BadSize { width, height });
        }
        let log = opts.log;
        let built = std::panic::catch_unwind(move || {
            let mut app = App::new();
            let mut plugins = DefaultPlugins
                .build()
                .set(WindowPlugin {
                    primary_window: None,
                    exit_condition: ExitCondition::DontExit,
                    close_when_requested: false,
                    ..Default::default()
                })
                .set(RenderPlugin {
                    render_creation: RenderCreation::from(WgpuSettings {
                        backends: Some(Backends::VULKAN),
                        ..Default::default()
                    }),
                    synchronous_pipeline_compilation: true,
                    ..Default::default()
                })
                .disable::<PipelinedRenderingPlugin>()
                .disable::<bevy::app::TerminalCtrlCHandlerPlugin>();
            if !log {
                plugins = plugins.disable::<bevy::log::LogPlugin>();
            }
            // The `window` feature (examples/play.rs) adds winit, which needs a display, and the
            // UI and text plugins to Bevy's group: a headless renderer leaves them out and keeps
            // the plugins of the `render` build.
            #[cfg(feature = "window")]
            {
                plugins = plugins
                    .disable::<bevy::winit::WinitPlugin>()
                    .disable::<bevy::sprite::SpritePlugin>()
                    .disable::<bevy::sprite_render::SpriteRenderPlugin>()
                    .disable::<bevy::text::TextPlugin>()
                    .disable::<bevy::ui::UiPlugin>()
                    .disable::<bevy::ui_render::UiRenderPlugin>();
            }
            app.add_plugins(plugins)
                .add_plugins(LiquidRenderPlugin { feed, stage: true });
            setup(&mut app);
            app.finish();
            app.cleanup();
            app
        });
        let mut app = built.map_err(|p| {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "panic while starting Bevy's renderer".into());
            RenderError::NoRenderer(msg)
        })?;
        let target =
            app.world_mut()
                .resource_mut::<Assets<Image>>()
                .add(Image::new_target_texture(
                    width,
                    height,
                    TextureFormat::Rgba8UnormSrgb,
                    None,
                ));
        let [r, g, b] = opts.background;
        let camera = app
            .world_mut()
            .spawn((
                Camera3d::default(),
                Camera {
                    clear_color: ClearColorConfig::Custom(Color::srgb(r, g, b)),
                    ..Default::default()
                },
                RenderTarget::Image(target.clone().into()),
                Projection::Perspective(PerspectiveProjection {
                    fov: opts.fov_y,
                    aspect_ratio: width as f32 / height as f32,
                    near: 1e-4,
                    ..Default::default()
                }),
                // Exact colours: the colour map is not to be tone-mapped.
                Tonemapping::None,
                Msaa::Sample4,
                LiquidCamera::default(),
                Transform::from_xyz(0.0, 0.5, 2.0).looking_at(Vec3::ZERO, Vec3::Y),
            ))
            .id();
        Ok(Self {
            app,
            target,
            camera,
            width,
            height,
            warm: false,
            mirrors: HashMap::new(),
            scripted: Vec::new(),
            timed: Vec::new(),
            fixed_camera: false,
            frame_radius: None,
        })
    }

    /// The Bevy app (to add or inspect entities and resources).
    pub fn app_mut(&mut self) -> &mut App {
        &mut self.app
    }

    /// Image width and height \[px\].
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The particles to draw: positions, the values to colour by, the colour range, the
    /// sphere radius \[m\] and the simulated time (nozzles are drawn where they are then).
    pub fn set_particles(
        &mut self,
        positions: &[[f32; 3]],
        values: &[f32],
        range: ColourRange,
        radius: f32,
        time: f64,
    ) {
        let world = self.app.world_mut();
        let mut inst = world.resource_mut::<ParticleInstances>();
        inst.fill(positions, values, range);
        inst.radius = radius;
        world.resource_mut::<ParticleStyle>().radius = radius;
        world.insert_resource(SimulationClock {
            time,
            ..Default::default()
        });
        for (e, pose, motion, path) in &self.scripted {
            let t = time as f32;
            let rotation =
                bevy::math::Quat::from_scaled_axis(motion.angular_velocity * t) * pose.rotation;
            let translation = match path {
                Some(path) => path.at(time),
                None => pose.translation + motion.linear_velocity * t,
            };
            let p = ColliderPose {
                translation,
                rotation,
            };
            if let Ok(mut ent) = world.get_entity_mut(*e) {
                ent.insert(p);
            }
        }
        for (e, collider, remove_at) in &self.timed {
            if let Ok(mut ent) = world.get_entity_mut(*e) {
                match (
                    time >= *remove_at,
                    ent.contains::<crate::collision::Collider>(),
                ) {
                    (true, true) => {
                        ent.remove::<crate::collision::Collider>();
                    }
                    (false, false) => {
                        ent.insert(collider.clone());
                    }
                    _ => {}
                }
            }
        }
    }

    /// The sphere radius of the frames set next by [`set_frame`](Self::set_frame) \[m\]
    /// (`None`: half the frame's particle spacing).
    pub fn set_frame_radius(&mut self, radius: Option<f32>) {
        self.frame_radius = radius;
    }

    /// A frame read from a file, coloured by `field` (see [`frame_values`]); the sphere radius
    /// is [`set_frame_radius`](Self::set_frame_radius)'s, else half the frame's particle
    /// spacing.
    pub fn set_frame(
        &mut self,
        frame: &ParticleFrame,
        field: &ColourField,
        range: ColourRange,
        path: &Path,
    ) -> Result<(), RenderError> {
        let values = frame_values(frame, field, path)?;
        let radius = self.frame_radius.unwrap_or_else(|| {
            crate::snapshot::particle_spacing(&frame.positions).map_or(0.005, |h| 0.5 * h as f32)
        });
        self.set_particles(&frame.positions, &values, range, radius, frame.time);
        Ok(())
    }

    /// Spawns the scene's colliders (each moving with its scripted [`ColliderMotion`] when
    /// frames are set, and drawn only before its `remove_at`), rigid bodies (at their initial pose) and nozzles; puts the floor at the
    /// bottom of its domain.
    pub fn set_scene_objects(&mut self, scene: &Scene) {
        let world = self.app.world_mut();
        for (collider, pose, motion, lifetime, path) in &scene.colliders {
            let e = world.spawn((collider.clone(), *pose)).id();
            if let Some(m) = motion {
                self.scripted.push((e, *pose, *m, path.clone()));
            }
            if let Some(l) = lifetime {
                self.timed.push((e, collider.clone(), l.remove_at));
            }
        }
        for body in &scene.rigid_bodies {
            world.spawn((body.body, body.collider.clone(), body.pose));
        }
        for emitter in &scene.emitters {
            world.spawn((emitter.clone(), EmitterFrame::default()));
        }
        world.insert_resource(StageFloor::under_domain(&scene.config));
        world.insert_resource(scene.config.clone());
    }

    /// Mirrors the colliders, rigid bodies and nozzles of `source` (a running simulation's
    /// world) and its clock: new ones are spawned here, poses and shapes copied, removed ones
    /// despawned.
    #[allow(clippy::type_complexity)]
    pub fn sync_objects_from(&mut self, source: &mut World) {
        let mut colliders =
            source.query::<(Entity, &Collider, &ColliderPose, Option<&RigidBody>)>();
        let mut emitters = source.query::<(Entity, &NozzleEmitter, &EmitterFrame)>();
        let time = source
            .get_resource::<SimulationClock>()
            .map_or(0.0, |c| c.time);
        let world = self.app.world_mut();
        let mut seen = Vec::new();
        for (src, collider, pose, body) in colliders.iter(source) {
            seen.push(src);
            match self
                .mirrors
                .get(&src)
                .and_then(|e| world.get_entity_mut(*e).ok())
            {
                Some(mut e) => {
                    if e.get::<Collider>() != Some(collider) {
                        e.insert(collider.clone());
                    }
                    e.insert(*pose);
                }
                None => {
                    let mut e = world.spawn((collider.clone(), *pose));
                    if let Some(b) = body {
                        e.insert(*b);
                    }
                    self.mirrors.insert(src, e.id());
                }
            }
        }
        for (src, emitter, frame) in emitters.iter(source) {
            seen.push(src);
            match self
                .mirrors
                .get(&src)
                .and_then(|e| world.get_entity_mut(*e).ok())
            {
                Some(mut e) => {
                    e.insert(*frame);
                }
                None => {
                    let id = world.spawn((emitter.clone(), *frame)).id();
                    self.mirrors.insert(src, id);
                }
            }
        }
        self.mirrors.retain(|src, mirror| {
            let keep = seen.contains(src);
            if !keep {
                let _ = world.try_despawn(*mirror);
            }
            keep
        });
        world.insert_resource(SimulationClock {
            time,
            ..Default::default()
        });
    }

    /// Surface mode: draw the liquid surface reconstructed from the particles of every frame
    /// set, with the material `preset` or coloured by the particles' field (`look`), instead
    /// of the particles (`preset` `None`: particles). `params`: the reconstruction parameters
    /// (`None`: the spacing estimated from the first frame).
    pub fn set_surface(
        &mut self,
        preset: Option<SurfacePreset>,
        look: SurfaceLook,
        params: Option<crate::surface::SurfaceParams>,
    ) {
        let world = self.app.world_mut();
        world.insert_resource(SurfaceSettings {
            enabled: preset.is_some(),
            preset: preset.unwrap_or_default(),
            look,
            every_n_frames: 1,
            params,
        });
        // Reconstruct the current particles on the next update, and wait for the surface
        // material's pipelines before the next image.
        world.resource_mut::<ParticleInstances>().set_changed();
        self.warm = false;
    }

    /// Places the camera as a scene's `camera` section says: looking along a direction
    /// (framed by [`frame_camera`](Self::frame_camera)), or fixed at an eye looking at a
    /// target; its field of view too.
    pub fn place_camera(&mut self, spec: &CameraSpec) {
        let world = self.app.world_mut();
        let fov = spec.fov_y();
        let mut camera = world.entity_mut(self.camera);
        if let Some(mut p) = camera.get_mut::<Projection>()
            && let Projection::Perspective(persp) = p.as_mut()
        {
            persp.fov = fov;
        }
        match spec.placement() {
            CameraPlacement::Framed(direction) => {
                if let Some(mut c) = camera.get_mut::<LiquidCamera>() {
                    c.direction = direction;
                }
            }
            CameraPlacement::Fixed { eye, target } => {
                let up = if (target - eye).cross(Vec3::Y).length_squared() < 1e-12 {
                    Vec3::NEG_Z
                } else {
                    Vec3::Y
                };
                camera.insert(Transform::from_translation(eye).looking_at(target, up));
                world.insert_resource(ViewFraming::Manual);
                self.fixed_camera = true;
            }
            CameraPlacement::Default => {}
        }
    }

    /// Frames the camera on the box `[lo, hi]` (from the camera's direction); no effect after
    /// a fixed [`place_camera`](Self::place_camera).
    pub fn frame_camera(&mut self, lo: Vec3, hi: Vec3) {
        if self.fixed_camera {
            return;
        }
        self.app
            .world_mut()
            .insert_resource(ViewFraming::Bounds(lo, hi));
    }

    /// The pixel (x right, y down, in pixels from the top left) where the camera projects the
    /// world point `p`, with the camera as last rendered; `None` behind the camera.
    pub fn world_to_pixel(&mut self, p: Vec3) -> Option<bevy::math::Vec2> {
        let world = self.app.world_mut();
        let mut q = world.query::<(&Camera, &GlobalTransform)>();
        let (camera, transform) = q.get(world, self.camera).ok()?;
        camera.world_to_viewport(transform, p).ok()
    }

    /// Renders one image with the current particles, solids and camera, and reads it back.
    pub fn render(&mut self) -> Result<RenderedImage, RenderError> {
        if !self.warm {
            self.warm_up()?;
        }
        let slot: Arc<Mutex<Option<Image>>> = Arc::default();
        let sink = slot.clone();
        self.app
            .world_mut()
            .spawn(Screenshot::image(self.target.clone()))
            .observe(move |shot: On<ScreenshotCaptured>| {
                if let Ok(mut s) = sink.lock() {
                    *s = Some(shot.image.clone());
                }
            });
        for _ in 0..MAX_UPDATES {
            self.app.update();
            let taken = slot.lock().ok().and_then(|mut s| s.take());
            if let Some(image) = taken {
                return self.to_rgba(image);
            }
        }
        Err(RenderError::NoImage(MAX_UPDATES))
    }

    /// Runs updates until the shaders are loaded and no pipeline waits to be compiled (a
    /// screenshot taken earlier could miss the particles).
    fn warm_up(&mut self) -> Result<(), RenderError> {
        let mut settled = 0;
        for _ in 0..MAX_UPDATES {
            self.app.update();
            let waiting = self
                .app
                .get_sub_app(RenderApp)
                .and_then(|a| a.world().get_resource::<PipelineCache>())
                .map_or(0, |c| c.waiting_pipelines().count());
            settled = if waiting == 0 { settled + 1 } else { 0 };
            // A few quiet updates in a row: shaders loaded, materials prepared, pipelines built.
            if settled >= 4 {
                self.warm = true;
                return Ok(());
            }
        }
        Err(RenderError::NoImage(MAX_UPDATES))
    }

    fn to_rgba(&self, image: Image) -> Result<RenderedImage, RenderError> {
        let (w, h) = (image.width(), image.height());
        let expected = 4 * w as usize * h as usize;
        let data = image.data.unwrap_or_default();
        if data.len() != expected || w != self.width || h != self.height {
            return Err(RenderError::BadImage {
                got: data.len(),
                expected: 4 * self.width as usize * self.height as usize,
                width: self.width,
                height: self.height,
            });
        }
        let mut rgba = data;
        if matches!(
            image.texture_descriptor.format,
            TextureFormat::Bgra8UnormSrgb | TextureFormat::Bgra8Unorm
        ) {
            for p in rgba.chunks_exact_mut(4) {
                p.swap(0, 2);
            }
        }
        Ok(RenderedImage {
            width: w,
            height: h,
            rgba,
        })
    }
}

/// Values of `field` for every particle of `frame`: speed and height are derived from the
/// velocities and positions when the file does not store them; any other field must be stored
/// (`path` names the file in the error, which lists the fields it has).
pub fn frame_values(
    frame: &ParticleFrame,
    field: &ColourField,
    path: &Path,
) -> Result<Vec<f32>, RenderError> {
    let name = field.frame_name();
    if let Some(v) = frame.field(name) {
        return Ok(v.to_vec());
    }
    match field {
        ColourField::Speed => Ok(frame
            .velocities
            .iter()
            .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
            .collect()),
        ColourField::Height => Ok(frame.positions.iter().map(|p| p[1]).collect()),
        _ => {
            let mut available = vec!["speed".to_string(), "y".to_string()];
            available.extend(frame.fields.iter().map(|(n, _)| n.clone()));
            Err(RenderError::MissingField {
                path: path.to_path_buf(),
                field: name.to_string(),
                available: available.join(", "),
            })
        }
    }
}

/// What `treacle render` draws and how.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RenderJob {
    /// Image size, field of view, background.
    pub options: RenderOptions,
    /// Field mapped to colour.
    pub field: ColourField,
    /// Its range; [`ColourRange::Auto`] is taken over all frames (first and last frame for a
    /// run directory, which [`render_run_dir`] reads ahead), so colours mean the same in every
    /// image.
    pub range: ColourRange,
    /// Frames to simulate when rendering a scene \[default: the scene's\].
    pub frames: Option<u64>,
    /// Surface mode: draw the reconstructed liquid surface with this material instead of the
    /// particles (spacing and domain from the scene, [`crate::runner::surface_params`], or
    /// the spacing estimated from the first frame without one).
    pub surface: Option<SurfacePreset>,
    /// With `surface`: the preset's colour or the particles' `field` on the surface.
    pub surface_look: SurfaceLook,
    /// The camera (overrides the scene's `camera` section; `None`: the scene's, or framed
    /// from the default direction).
    pub camera: Option<CameraSpec>,
}

/// The frame files (`frame_NNNNN.ply`, `.vtk` or `.parts`) of a run directory, in frame
/// order ([`crate::output::frame_files`]).
pub fn frame_files(dir: &Path) -> Result<Vec<PathBuf>, RenderError> {
    Ok(crate::output::frame_files(dir)?)
}

/// Union of the world bounds of the scene's bounded colliders, bodies and nozzle paths.
fn scene_object_bounds(scene: &Scene) -> Option<(Vec3, Vec3)> {
    let mut b: Option<(Vec3, Vec3)> = None;
    let mut add = |lo: Vec3, hi: Vec3| {
        b = Some(match b {
            Some((l, h)) => (l.min(lo), h.max(hi)),
            None => (lo, hi),
        });
    };
    let mut add_shape = |shape: &crate::collision::ColliderShape, pose: &ColliderPose| {
        if let Some((lo, hi)) = shape.local_bounds() {
            // The 8 corners of the local box, posed.
            let mut wl = Vec3::splat(f32::INFINITY);
            let mut wh = Vec3::splat(f32::NEG_INFINITY);
            for i in 0..8 {
                let c = Vec3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                );
                let w = pose.translation + pose.rotation * c;
                wl = wl.min(w);
                wh = wh.max(w);
            }
            add(wl, wh);
        }
    };
    for (c, pose, _, _, _) in &scene.colliders {
        add_shape(&c.shape, pose);
    }
    for body in &scene.rigid_bodies {
        add_shape(&body.collider.shape, &body.pose);
    }
    for e in &scene.emitters {
        let (lo, hi) = e.path.bounds();
        add(lo.as_vec3(), hi.as_vec3());
    }
    b
}

fn union(a: Option<(Vec3, Vec3)>, b: Option<(Vec3, Vec3)>) -> Option<(Vec3, Vec3)> {
    match (a, b) {
        (Some(a), Some(b)) => Some((a.0.min(b.0), a.1.max(b.1))),
        (a, None) => a,
        (None, b) => b,
    }
}

fn positions_bounds(p: &[[f32; 3]]) -> Option<(Vec3, Vec3)> {
    let mut it = p.iter().map(|p| Vec3::from(*p));
    let first = it.next()?;
    Some(it.fold((first, first), |(l, h), p| (l.min(p), h.max(p))))
}

/// The box the camera shows: the particles of the given frames and the scene's bounded objects,
/// clipped to the scene's domain.
fn view_bounds(frames: &[&[[f32; 3]]], scene: Option<&Scene>) -> (Vec3, Vec3) {
    let mut b = None;
    for f in frames {
        b = union(b, positions_bounds(f));
    }
    if let Some(s) = scene {
        b = union(b, scene_object_bounds(s));
        if let Some((lo, hi)) = b {
            let (dl, dh) = (s.config.domain_min, s.config.domain_max);
            // The floor (domain bottom) stays in view.
            let lo = lo.max(dl).min(Vec3::new(lo.x, dl.y, lo.z));
            b = Some((lo, hi.min(dh).max(lo)));
        }
    }
    b.unwrap_or((Vec3::ZERO, Vec3::ONE))
}

/// Range of values over several frames (finite values; a constant is widened by
/// [`ParticleInstances::set_range`]).
/// Sphere radius for a scene's particles: half the lattice spacing h = (particle volume)^⅓ of
/// its first body (random or stretched particles have nearest neighbours much closer than h,
/// so the frame's own spacing would draw them as dust); `None` for a scene without bodies.
fn scene_particle_radius(scene: &Scene) -> Option<f32> {
    scene
        .particles
        .iter()
        .find(|b| !b.positions.is_empty())
        .map(|b| 0.5 * b.particle_volume.cbrt())
}

fn range_over(values: &[&[f32]]) -> ColourRange {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for v in values
        .iter()
        .flat_map(|v| v.iter())
        .filter(|v| v.is_finite())
    {
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    if lo > hi {
        ColourRange::Auto
    } else {
        ColourRange::Fixed { min: lo, max: hi }
    }
}

/// PNG path for frame file `path` in `out`: `frame_00010.ply` → `out/frame_00010.png`.
fn png_path(out: &Path, frame: u32) -> PathBuf {
    out.join(format!("frame_{frame:05}.png"))
}

fn ensure_dir(out: &Path) -> Result<(), RenderError> {
    std::fs::create_dir_all(out).map_err(|e| RenderError::Write {
        path: out.to_path_buf(),
        message: e.to_string(),
    })
}

/// Renders every frame file of the run directory `dir` into `out/frame_NNNNN.png`, with the
/// colliders, bodies and nozzles of `scene` when given (scripted collider motion applied;
/// bodies at their initial pose). `on_frame(done, total)` after each image. Returns the PNGs.
pub fn render_run_dir(
    dir: &Path,
    scene: Option<&Scene>,
    out: &Path,
    job: &RenderJob,
    mut on_frame: impl FnMut(usize, usize),
) -> Result<Vec<PathBuf>, RenderError> {
    let files = frame_files(dir)?;
    if files.is_empty() {
        return Err(RenderError::Frame(OutputError::io(
            "find frame files (frame_NNNNN.ply or .vtk) in",
            dir,
            std::io::Error::new(std::io::ErrorKind::NotFound, "none found"),
        )));
    }
    ensure_dir(out)?;
    let first = crate::output::read_frame(&files[0])?;
    let last = crate::output::read_frame(&files[files.len() - 1])?;
    let range = match job.range {
        ColourRange::Auto => range_over(&[
            &frame_values(&first, &job.field, &files[0])?,
            &frame_values(&last, &job.field, &files[files.len() - 1])?,
        ]),
        r => r,
    };
    let (lo, hi) = view_bounds(&[&first.positions, &last.positions], scene);
    let mut r = HeadlessRenderer::new(&job.options)?;
    if let Some(c) = job.camera.or(scene.and_then(|s| s.camera)) {
        r.place_camera(&c);
    }
    if let Some(s) = scene {
        r.set_scene_objects(s);
        r.set_frame_radius(scene_particle_radius(s));
    }
    if job.surface.is_some() {
        let params = match scene {
            Some(s) => Some(crate::runner::surface_params(s)),
            None => {
                let p: Vec<Vec3> = first.positions.iter().map(|p| Vec3::from(*p)).collect();
                crate::surface::estimate_spacing(&p).map(crate::surface::SurfaceParams::for_spacing)
            }
        };
        r.set_surface(job.surface, job.surface_look, params);
    }
    r.frame_camera(lo, hi);
    let mut written = Vec::with_capacity(files.len());
    for (i, path) in files.iter().enumerate() {
        let frame = crate::output::read_frame(path)?;
        r.set_frame(&frame, &job.field, range, path)?;
        let png = png_path(out, frame.frame);
        r.render()?.write_png(&png)?;
        written.push(png);
        on_frame(i + 1, files.len());
    }
    Ok(written)
}

/// Simulates `scene` and renders frame 0 and every simulated frame into
/// `out/frame_NNNNN.png` (colliders, bodies and nozzles where the simulation has them). The
/// colour range of [`ColourRange::Auto`] is the first frame's, widened as later frames exceed
/// it (colours of earlier images are not redrawn). `on_frame(done, total)` after each image.
pub fn render_scene(
    scene: &Scene,
    out: &Path,
    job: &RenderJob,
    mut on_frame: impl FnMut(usize, usize),
) -> Result<Vec<PathBuf>, RenderError> {
    ensure_dir(out)?;
    let mut sim = crate::runner::scene_app(scene);
    let total = job.frames.unwrap_or_else(|| scene.frames());
    let mut r = HeadlessRenderer::new(&job.options)?;
    if let Some(c) = job.camera.or(scene.camera) {
        r.place_camera(&c);
    }
    if job.surface.is_some() {
        r.set_surface(
            job.surface,
            job.surface_look,
            Some(crate::runner::surface_params(scene)),
        );
    }
    let source = scene.source.clone();
    let (positions, values) = world_particles(sim.world_mut(), &job.field);
    let mut range = match job.range {
        ColourRange::Auto => range_over(&[&values]),
        r => r,
    };
    let (lo, hi) = view_bounds(&[&positions], Some(scene));
    r.app_mut()
        .world_mut()
        .insert_resource(StageFloor::under_domain(&scene.config));
    r.app_mut()
        .world_mut()
        .insert_resource(scene.config.clone());
    r.frame_camera(lo, hi);
    let radius = scene_particle_radius(scene)
        .or_else(|| crate::snapshot::particle_spacing(&positions).map(|h| 0.5 * h as f32))
        .unwrap_or(0.25 * scene.config.dx);
    let mut written = Vec::new();
    for frame in 0..=total {
        if frame > 0 {
            sim.update();
            if let Some(f) = sim
                .world()
                .resource::<crate::failure::SimulationStatus>()
                .failure
                .clone()
            {
                return Err(RenderError::Simulation(format!(
                    "{}: frame {frame}: {f}",
                    source.display()
                )));
            }
        }
        let (positions, values) = world_particles(sim.world_mut(), &job.field);
        if job.range == ColourRange::Auto
            && let ColourRange::Fixed { min: l, max: h } = range_over(&[&values])
        {
            // Widened as frames exceed it; fixed by the first frame with values (a scene may
            // start with no particles, e.g. a nozzle only).
            range = match range {
                ColourRange::Fixed { min, max } => ColourRange::Fixed {
                    min: min.min(l),
                    max: max.max(h),
                },
                ColourRange::Auto => ColourRange::Fixed { min: l, max: h },
            };
        }
        let time = sim.world().resource::<SimulationClock>().time;
        r.sync_objects_from(sim.world_mut());
        r.set_particles(&positions, &values, range, radius, time);
        let png = png_path(out, frame as u32);
        r.render()?.write_png(&png)?;
        written.push(png);
        on_frame(frame as usize + 1, total as usize + 1);
    }
    Ok(written)
}

/// Positions and `field` values of the particles of a simulation world (the live-world
/// counterpart of [`frame_values`]; a stored-only field is NaN, drawn grey).
pub fn world_particles(world: &mut World, field: &ColourField) -> (Vec<[f32; 3]>, Vec<f32>) {
    use crate::components::{CauchyStress, Density, Particle, Position, Velocity};
    use crate::material::MaterialId;
    use crate::thermal::{PhaseIndex, Temperature};
    let mut q = world.query_filtered::<(
        &Position,
        &Velocity,
        &MaterialId,
        Option<&Density>,
        Option<&Temperature>,
        Option<&PhaseIndex>,
        Option<&CauchyStress>,
    ), With<Particle>>();
    let mut positions = Vec::new();
    let mut values = Vec::new();
    for (x, v, m, rho, t, ph, s) in q.iter(world) {
        positions.push(x.0.to_array());
        values.push(super::particles::particle_value(
            field, x, v, m, rho, t, ph, s,
        ));
    }
    (positions, values)
}
