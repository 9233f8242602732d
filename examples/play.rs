//! A playable windowed game (features `avian` and `window`): pour liquid from a nozzle onto
//! Avian boxes in a tank, switch between the four [`GameLiquid`] presets, and watch the frame
//! rate, the particle count and how far the simulation falls behind real time.
//!
//! ```text
//! cargo play                       # = cargo run --release --ignore-rust-version
//!                                  #   --features game,avian,render,window --example play
//! cargo play -- --screenshot docs/img/play.png --frames 600   # scripted: see below
//! ```
//!
//! **Controls**
//! - **mouse**: aim — the nozzle moves (at most 1 m/s) above the point under the cursor: the
//!   box, the ramp or the floor the liquid will land on;
//! - **left button** (hold) or **Space** (toggle): pour;
//! - **1 2 3 4**: the liquid of newly poured particles — water, honey, ketchup, slime (XPP);
//!   particles are coloured by liquid (the HUD shows the colours);
//! - **mouse wheel** or **↑ ↓**: the nozzle's height above its target (6–35 cm);
//! - **D**: open or close the drain (the dark disc in the near corner), **R**: remove all the
//!   liquid and put the boxes back, **C**: colour by liquid or by speed, **Esc**: quit.
//!
//! Pouring pauses at `--max-particles` (default 3,000, a count the simulation keeps up with at
//! 60 frames/s on two cores: BENCHMARKS.md (h)); open the drain or reset to pour again.
//!
//! **HUD** (top left): frames per second and frame time, the particle count, the simulated
//! time against real time since the first frame — the *lag behind real time* — and, of that,
//! what the frame budget dropped (`SimulationLag`), and the sub-steps of the last tick.
//!
//! **How it runs.** The liquid's frame driver runs in `FixedUpdate` at 60 ticks/s beside Avian
//! (`AvianCouplingPlugin`, see `treacle::game::avian`), each tick within a budget of 24
//! sub-steps and 8 ms of wall time; Bevy's virtual clock advances at most 50 ms per frame (at
//! most three ticks), so a slow machine plays in slow motion instead of piling up ticks: both
//! show on the HUD as lag. The tank is 80 × 50 × 50 cm at Δx = 2.5 cm (`game_config`); the
//! boxes, the ramp, the tank's floor and walls are Avian colliders (the liquid sees them through
//! their treacle shadows; the domain walls hold the liquid). The front and right walls and the
//! floor's shadow are not drawn (they would hide the tank, or fight with the stage floor).
//!
//! **Scripted mode** (`--frames N`, optionally `--screenshot PATH`): the nozzle follows a fixed
//! figure-of-eight over the tank and pours all the time, switching the liquid every N/4
//! frames; after N frames it takes a screenshot of the window (PNG, HUD included), prints the
//! frame time (median and mean of frames 60..N, wall time between frames) and the state of the
//! liquid, and exits. `--no-vsync` presents without waiting for vertical sync (the
//! scripted mode's default), `--size WxH` sets the window size (default 1280x720).
//!
//! Needs a GPU (or Mesa's lavapipe: `apt-get install mesa-vulkan-drivers`) and an X11 display
//! (`xvfb-run -s "-screen 0 1280x720x24" cargo play -- --frames 600` without one).
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use avian3d::prelude as av;
use bevy::ecs::schedule::ScheduleLabel;
use bevy::input::mouse::AccumulatedMouseScroll;
use bevy::prelude::*;
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::render::view::{Msaa, Tonemapping};
use bevy::window::{PresentMode, PrimaryWindow, WindowResolution};
use treacle::components::Particle;
use treacle::config::{BoundaryCondition, DomainWalls, MpmConfig};
use treacle::emit::{EmitterPlugin, NozzleEmitter, PathSegment, ToolPath};
use treacle::failure::SimulationStatus;
use treacle::game::avian::{AvianCouplingPlugin, AvianSource};
use treacle::game::{GAME_DX, GameLiquid, GamePlugin, game_config};
use treacle::material::MaterialId;
use treacle::plugin::{MpmCorePlugin, MpmPlugins};
use treacle::render::colour::{ColourMap, colour_srgb};
use treacle::render::headless::RenderedImage;
use treacle::render::{
    ColourField, ColourRange, LiquidCamera, LiquidRenderPlugin, NoLiquidVisual, ParticleCloud,
    ParticleStyle, ViewFraming, slot_mesh,
};
use treacle::step::pacing::{DriverSystems, FrameBudget, SimulationLag};
use treacle::step::schedule::SimulationClock;

/// The tank (the simulation domain) \[m\].
const TANK: Vec3 = Vec3::new(0.8, 0.5, 0.5);
/// Largest speed of the nozzle \[m/s\] (its motion is added to the poured liquid's velocity).
const NOZZLE_SPEED: f32 = 1.0;
/// Nozzle radius \[m\] and volume rate \[m³/s\] (about 200 particles/s).
const NOZZLE_RADIUS: f32 = 0.02;
const NOZZLE_RATE: f64 = 4e-4;
/// The drain: a disc on the floor in the corner nearest the camera \[m\].
const DRAIN_CENTRE: Vec3 = Vec3::new(0.72, 0.0, 0.42);
const DRAIN_RADIUS: f32 = 0.06;
/// Frames left out of the frame-time statistics (shader compilation, first uploads).
const WARM_UP_FRAMES: usize = 60;

// ---------------------------------------------------------------------------------------------
// Command line

/// Options of the example.
#[derive(Resource, Clone, Debug)]
struct Options {
    /// Scripted mode: run this many frames, then exit.
    frames: Option<usize>,
    /// Scripted mode: save a screenshot after the last frame.
    screenshot: Option<PathBuf>,
    /// Pouring pauses at this many particles.
    max_particles: usize,
    /// Window size \[px\].
    size: (u32, u32),
    /// Present without vsync.
    no_vsync: bool,
}

const USAGE: &str = "usage: play [--frames N] [--screenshot PATH] [--max-particles N] \
                     [--size WxH] [--no-vsync] [--vsync]";

fn parse_options(args: impl Iterator<Item = String>) -> Result<Options, String> {
    let mut o = Options {
        frames: None,
        screenshot: None,
        max_particles: 3000,
        size: (1280, 720),
        no_vsync: false,
    };
    let mut vsync: Option<bool> = None;
    let mut args = args;
    while let Some(a) = args.next() {
        let mut value = |name: &str| {
            args.next()
                .ok_or_else(|| format!("{name} needs a value\n{USAGE}"))
        };
        match a.as_str() {
            "--frames" => {
                let v = value("--frames")?;
                let n: usize = v
                    .parse()
                    .map_err(|_| format!("--frames: not a count: {v}"))?;
                if !(1..=1_000_000).contains(&n) {
                    return Err(format!("--frames must be 1..=1000000 (got {n})"));
                }
                o.frames = Some(n);
            }
            "--screenshot" => o.screenshot = Some(PathBuf::from(value("--screenshot")?)),
            "--max-particles" => {
                let v = value("--max-particles")?;
                let n: usize = v
                    .parse()
                    .map_err(|_| format!("--max-particles: not a count: {v}"))?;
                if !(100..=1_000_000).contains(&n) {
                    return Err(format!("--max-particles must be 100..=1000000 (got {n})"));
                }
                o.max_particles = n;
            }
            "--size" => {
                let v = value("--size")?;
                let parsed = v
                    .split_once(['x', 'X'])
                    .and_then(|(w, h)| Some((w.parse::<u32>().ok()?, h.parse::<u32>().ok()?)));
                match parsed {
                    Some((w, h)) if (64..=8192).contains(&w) && (64..=8192).contains(&h) => {
                        o.size = (w, h)
                    }
                    _ => return Err(format!("--size: expected WxH, 64..=8192 each (got {v})")),
                }
            }
            "--no-vsync" => vsync = Some(false),
            "--vsync" => vsync = Some(true),
            "-h" | "--help" => return Err(USAGE.to_string()),
            other => return Err(format!("unknown argument {other}\n{USAGE}")),
        }
    }
    if o.screenshot.is_some() && o.frames.is_none() {
        o.frames = Some(600);
    }
    // The scripted mode measures the frame time: no waiting for vsync unless asked.
    o.no_vsync = !vsync.unwrap_or(o.frames.is_none());
    Ok(o)
}

// ---------------------------------------------------------------------------------------------
// Game state

/// The four liquids: material ids in [`GameLiquid::ALL`] order.
#[derive(Resource, Clone, Debug)]
struct Liquids(Vec<(GameLiquid, MaterialId)>);

/// What the player asked for.
#[derive(Resource, Clone, Debug)]
struct Pour {
    /// Held mouse button (this frame).
    held: bool,
    /// Toggled with Space.
    toggled: bool,
    /// Index into [`Liquids`].
    liquid: usize,
    /// Nozzle height above its target \[m\].
    clearance: f32,
    /// Where the liquid should land \[m\].
    target: Vec3,
    /// The drain is open.
    drain_open: bool,
    /// The particle cap is reached (pouring paused).
    full: bool,
    /// Particles now.
    particles: usize,
    /// R was pressed: reset before the next frame.
    reset: bool,
}

impl Pour {
    fn pouring(&self) -> bool {
        (self.held || self.toggled) && !self.full
    }

    /// Where the nozzle's tip should be.
    fn nozzle_goal(&self) -> Vec3 {
        let y = (self.target.y + self.clearance).clamp(0.08, TANK.y - 0.04);
        Vec3::new(self.target.x, y, self.target.z)
    }
}

/// Marks the nozzle entity.
#[derive(Component)]
struct Nozzle;

/// An Avian entity whose treacle shadow is not drawn.
#[derive(Component)]
struct HiddenShadow;

/// An Avian entity the aiming ray ignores (tank walls).
#[derive(Component)]
struct Wall;

/// A dynamic box and its starting pose (for reset).
#[derive(Component)]
struct Crate(Transform);

/// The drain's disc.
#[derive(Component)]
struct DrainDisc;

/// HUD texts.
#[derive(Component)]
struct StatsText;
#[derive(Component)]
struct LiquidSpan(usize);
#[derive(Component)]
struct StatusText;

/// Frame times and the real-time reference.
#[derive(Resource, Default)]
struct FrameStats {
    /// Wall time of the first frame.
    start: Option<Instant>,
    /// Simulated time at the first frame \[s\].
    sim_start: f64,
    last: Option<Instant>,
    /// Wall time between frames \[ms\], every frame.
    frames_ms: Vec<f64>,
    /// Smoothed frame time for the HUD \[ms\].
    smoothed_ms: f64,
    /// Load average (1 min) at the first frame.
    load_start: Option<f64>,
}

/// Scripted mode: the screenshot was written (or failed).
#[derive(Resource, Default)]
struct ScriptState {
    shot_requested: bool,
    shot_done: Option<Result<(), String>>,
    waited: usize,
}

// ---------------------------------------------------------------------------------------------

fn main() -> ExitCode {
    let options = match parse_options(std::env::args().skip(1)) {
        Ok(o) => o,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(64);
        }
    };
    let (w, h) = options.size;
    let mut app = App::new();
    app.add_plugins(DefaultPlugins.set(WindowPlugin {
        primary_window: Some(Window {
            title: "treacle: pour liquid on the boxes".into(),
            resolution: WindowResolution::new(w, h),
            present_mode: if options.no_vsync {
                PresentMode::AutoNoVsync
            } else {
                PresentMode::AutoVsync
            },
            ..default()
        }),
        ..default()
    }));
    app.insert_resource(MpmConfig {
        walls: DomainWalls::all(BoundaryCondition::Slip),
        ..game_config(Vec3::ZERO, TANK)
    });
    // The liquid's frame driver in `FixedUpdate`, beside Avian's `FixedPostUpdate`.
    app.add_plugins((
        av::PhysicsPlugins::default(),
        MpmPlugins.set(MpmCorePlugin {
            schedule: FixedUpdate.intern(),
        }),
        GamePlugin {
            budget: FrameBudget {
                max_substeps: Some(24),
                max_wall_time: Some(Duration::from_millis(8)),
            },
        },
        AvianCouplingPlugin::default(),
        EmitterPlugin,
        LiquidRenderPlugin::default(),
    ));
    let liquids: Vec<_> = GameLiquid::ALL
        .iter()
        .map(|&l| (l, l.add_to(&mut app)))
        .collect();
    let ids: Vec<f32> = liquids.iter().map(|(_, id)| id.0 as f32).collect();
    let (lo, hi) = ids
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    app.insert_resource(ParticleStyle {
        field: ColourField::Material,
        range: ColourRange::Fixed { min: lo, max: hi },
        ..default()
    });
    let scripted = options.frames.is_some();
    app.insert_resource(Time::<Fixed>::from_hz(60.0))
        .insert_resource(Liquids(liquids))
        .insert_resource(Pour {
            held: false,
            toggled: scripted,
            liquid: 0,
            clearance: 0.15,
            target: Vec3::new(0.4, 0.0, 0.25),
            drain_open: false,
            full: false,
            particles: 0,
            reset: false,
        })
        .insert_resource(ViewFraming::Bounds(Vec3::ZERO, TANK))
        .insert_resource(options.clone())
        .init_resource::<FrameStats>()
        .init_resource::<ScriptState>()
        .add_systems(Startup, (setup_scene, setup_hud))
        .insert_resource(bevy::light::DirectionalLightShadowMap { size: 1024 })
        .add_systems(PostStartup, (pre_size_particle_cloud, light_shadows))
        .add_systems(FixedUpdate, drive_nozzle.before(DriverSystems::Pace))
        .add_systems(
            Update,
            (
                drain_and_cap,
                hide_shadows,
                (frame_stats, update_hud).chain(),
            ),
        );
    if scripted {
        app.add_systems(Update, scripted_aim)
            .add_systems(Last, finish_script);
    } else {
        app.add_systems(Update, (player_input, reset_game).chain());
    }
    match app.run() {
        AppExit::Success => ExitCode::SUCCESS,
        AppExit::Error(code) => ExitCode::from(code.get()),
    }
}

// ---------------------------------------------------------------------------------------------
// Startup

fn setup_scene(
    mut commands: Commands,
    liquids: Res<Liquids>,
    mut virtual_time: ResMut<Time<Virtual>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    // At most three fixed ticks per frame: a slow frame plays in slow motion.
    virtual_time.set_max_delta(Duration::from_millis(50));
    commands.spawn((
        Camera3d::default(),
        LiquidCamera {
            direction: Vec3::new(-0.45, -0.6, -1.0),
            margin: 0.02,
        },
        Tonemapping::None,
        Msaa::Off,
        Transform::from_xyz(1.2, 1.0, 1.4).looking_at(0.5 * TANK, Vec3::Y),
    ));
    // The nozzle: held at its entity's origin for a long time, pouring along −y; moved by its
    // Transform, switched on and off by its stop time.
    let hold = ToolPath::new(vec![PathSegment {
        start: glam::DVec3::ZERO,
        end: glam::DVec3::ZERO,
        duration: 1.0e9,
        extrude: true,
    }]);
    match hold {
        Ok(path) => {
            let emitter = NozzleEmitter::new(
                path,
                -Vec3::Y,
                NOZZLE_RADIUS,
                NOZZLE_RATE,
                0.5 * GAME_DX,
                liquids.0.first().map_or(MaterialId(0), |l| l.1),
            )
            .with_window(0.0, Some(0.0));
            commands.spawn((emitter, Transform::from_xyz(0.4, 0.3, 0.25), Nozzle));
        }
        Err(e) => error!("nozzle path: {e}"),
    }
    // Avian dynamic boxes (each at least 4 Δx across: see the treacle::game::avian docs).
    for (half, density, at) in [
        (Vec3::splat(0.06), 400.0, Vec3::new(0.32, 0.06, 0.18)),
        (
            Vec3::new(0.15, 0.03, 0.06),
            600.0,
            Vec3::new(0.5, 0.03, 0.34),
        ),
        (Vec3::splat(0.05), 2500.0, Vec3::new(0.62, 0.05, 0.12)),
    ] {
        let start = Transform::from_translation(at);
        commands.spawn((
            av::RigidBody::Dynamic,
            av::Collider::cuboid(2.0 * half.x, 2.0 * half.y, 2.0 * half.z),
            av::ColliderDensity(density),
            start,
            Crate(start),
        ));
    }
    // A static ramp sloping down towards +x.
    commands.spawn((
        av::RigidBody::Static,
        av::Collider::cuboid(0.26, 0.02, 0.18),
        Transform::from_xyz(0.14, 0.13, 0.36).with_rotation(Quat::from_rotation_z(-0.45)),
    ));
    // The tank for Avian: floor and walls (treacle's domain walls hold the liquid).
    let t = 0.05;
    let c = 0.5 * TANK;
    let walls = [
        // (centre, size, drawn)
        (
            Vec3::new(c.x, -0.5 * t, c.z),
            Vec3::new(TANK.x, t, TANK.z),
            false,
        ),
        (
            Vec3::new(-0.5 * t, c.y, c.z),
            Vec3::new(t, TANK.y, TANK.z),
            true,
        ),
        (
            Vec3::new(TANK.x + 0.5 * t, c.y, c.z),
            Vec3::new(t, TANK.y, TANK.z),
            false,
        ),
        (
            Vec3::new(c.x, c.y, -0.5 * t),
            Vec3::new(TANK.x, TANK.y, t),
            true,
        ),
        (
            Vec3::new(c.x, c.y, TANK.z + 0.5 * t),
            Vec3::new(TANK.x, TANK.y, t),
            false,
        ),
    ];
    for (i, (centre, size, drawn)) in walls.into_iter().enumerate() {
        let mut e = commands.spawn((
            av::RigidBody::Static,
            av::Collider::cuboid(size.x, size.y, size.z),
            Transform::from_translation(centre),
        ));
        if i > 0 {
            e.insert(Wall);
        }
        if !drawn {
            e.insert(HiddenShadow);
        }
    }
    // The drain.
    commands.spawn((
        Mesh3d(meshes.add(Cylinder::new(DRAIN_RADIUS, 0.004))),
        MeshMaterial3d(materials.add(StandardMaterial {
            base_color: Color::srgb(0.25, 0.25, 0.27),
            perceptual_roughness: 0.9,
            ..default()
        })),
        Transform::from_translation(DRAIN_CENTRE + Vec3::Y * 0.001),
        DrainDisc,
    ));
}

/// Sizes the particle cloud's slot mesh for the cap before its first upload, so that it never
/// grows while the game runs.
fn pre_size_particle_cloud(
    options: Res<Options>,
    cloud: Option<ResMut<ParticleCloud>>,
    mut meshes: ResMut<Assets<Mesh>>,
) {
    let Some(mut cloud) = cloud else { return };
    let wanted = (options.max_particles + 2048).next_power_of_two();
    if wanted > cloud.capacity {
        cloud.capacity = wanted;
        if let Some(mut mesh) = meshes.get_mut(&cloud.mesh) {
            *mesh = slot_mesh(wanted);
        }
    }
}

/// One shadow cascade over the tank (a software rasteriser draws every cascade's map).
fn light_shadows(mut commands: Commands, suns: Query<Entity, With<DirectionalLight>>) {
    let cascades = bevy::light::CascadeShadowConfigBuilder {
        num_cascades: 1,
        minimum_distance: 0.1,
        maximum_distance: 4.0,
        ..default()
    }
    .build();
    for sun in &suns {
        commands.entity(sun).insert(cascades.clone());
    }
}

fn setup_hud(mut commands: Commands, liquids: Res<Liquids>, style: Res<ParticleStyle>) {
    let small = TextFont::from_font_size(15.0);
    let root = commands
        .spawn((
            Node {
                position_type: PositionType::Absolute,
                left: Val::Px(10.0),
                top: Val::Px(10.0),
                padding: UiRect::all(Val::Px(8.0)),
                flex_direction: FlexDirection::Column,
                row_gap: Val::Px(4.0),
                ..default()
            },
            BackgroundColor(Color::srgba(0.0, 0.0, 0.0, 0.55)),
        ))
        .id();
    let stats = commands
        .spawn((
            Text::new("starting..."),
            TextFont::from_font_size(18.0),
            StatsText,
        ))
        .id();
    let legend = commands.spawn((Text::new("liquid: "), small.clone())).id();
    for (i, (liquid, id)) in liquids.0.iter().enumerate() {
        let span = commands
            .spawn((
                TextSpan::new(format!(" {} {} ", i + 1, liquid.name())),
                small.clone(),
                TextColor(liquid_colour(&style, *id)),
                LiquidSpan(i),
            ))
            .id();
        commands.entity(legend).add_child(span);
    }
    let help = commands
        .spawn((
            Text::new(
                "mouse: aim | hold left button / Space: pour | 1-4: liquid | wheel / Up Down: \
                 height | D: drain | R: reset | C: colour | Esc: quit",
            ),
            TextFont::from_font_size(13.0),
            TextColor(Color::srgb(0.8, 0.8, 0.8)),
        ))
        .id();
    let status = commands
        .spawn((
            Text::new(""),
            small,
            TextColor(Color::srgb(1.0, 0.8, 0.3)),
            StatusText,
        ))
        .id();
    commands
        .entity(root)
        .add_children(&[stats, legend, help, status]);
}

/// The colour particles of material `id` get (the colour map at its place in the range).
fn liquid_colour(style: &ParticleStyle, id: MaterialId) -> Color {
    let (lo, hi) = match style.range {
        ColourRange::Fixed { min, max } => (min, max),
        ColourRange::Auto => (0.0, 3.0),
    };
    let t = if hi > lo {
        ((id.0 as f32 - lo) / (hi - lo)).clamp(0.0, 1.0)
    } else {
        0.5
    };
    let [r, g, b] = colour_srgb(ColourMap::Viridis, t as f64);
    // Lifted a little towards white so that the darkest colour reads on the HUD's background.
    let lift = |c: u8| (c as f32 / 255.0) * 0.75 + 0.25;
    Color::srgb(lift(r), lift(g), lift(b))
}

// ---------------------------------------------------------------------------------------------
// Input

/// The player: aim with the mouse, keys for the rest.
#[allow(clippy::too_many_arguments)]
fn player_input(
    window: Option<Single<&Window, With<PrimaryWindow>>>,
    camera: Option<Single<(&Camera, &GlobalTransform)>>,
    spatial: av::SpatialQuery,
    walls: Query<Entity, With<Wall>>,
    mouse: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    scroll: Res<AccumulatedMouseScroll>,
    mut pour: ResMut<Pour>,
    mut style: ResMut<ParticleStyle>,
    liquids: Res<Liquids>,
    mut exit: MessageWriter<AppExit>,
) {
    if keys.just_pressed(KeyCode::Escape) {
        exit.write(AppExit::Success);
    }
    pour.held = mouse.pressed(MouseButton::Left);
    if keys.just_pressed(KeyCode::Space) {
        pour.toggled = !pour.toggled;
    }
    for (i, key) in [
        KeyCode::Digit1,
        KeyCode::Digit2,
        KeyCode::Digit3,
        KeyCode::Digit4,
    ]
    .into_iter()
    .enumerate()
    {
        if keys.just_pressed(key) || keys.just_pressed(numpad(i)) {
            pour.liquid = i;
        }
    }
    let mut dh = 0.02 * scroll.delta.y.clamp(-5.0, 5.0);
    if keys.just_pressed(KeyCode::ArrowUp) {
        dh += 0.02;
    }
    if keys.just_pressed(KeyCode::ArrowDown) {
        dh -= 0.02;
    }
    if dh.is_finite() {
        pour.clearance = (pour.clearance + dh).clamp(0.06, 0.35);
    }
    if keys.just_pressed(KeyCode::KeyD) {
        pour.drain_open = !pour.drain_open;
    }
    if keys.just_pressed(KeyCode::KeyC) {
        let (field, range) = match style.field {
            ColourField::Material => (
                ColourField::Speed,
                ColourRange::Fixed { min: 0.0, max: 1.5 },
            ),
            _ => (ColourField::Material, material_range(&liquids)),
        };
        style.field = field;
        style.range = range;
    }
    if keys.just_pressed(KeyCode::KeyR) {
        pour.reset = true;
    }
    // Aim: the first collider under the cursor (walls excepted), else the floor plane.
    let (Some(window), Some(camera)) = (window, camera) else {
        return;
    };
    let (camera, camera_transform) = *camera;
    let Some(cursor) = window.cursor_position() else {
        return;
    };
    let Ok(ray) = camera.viewport_to_world(camera_transform, cursor) else {
        return;
    };
    let filter = av::SpatialQueryFilter::from_excluded_entities(walls.iter());
    let hit = spatial
        .cast_ray(ray.origin, ray.direction, 20.0, true, &filter)
        .map(|h| ray.origin + *ray.direction * h.distance);
    let floor = (ray.direction.y < -1e-4).then(|| {
        let s = -ray.origin.y / ray.direction.y;
        ray.origin + *ray.direction * s
    });
    if let Some(p) = hit.or(floor).filter(|p| p.is_finite()) {
        pour.target = clamp_to_tank(p);
    }
}

fn numpad(i: usize) -> KeyCode {
    [
        KeyCode::Numpad1,
        KeyCode::Numpad2,
        KeyCode::Numpad3,
        KeyCode::Numpad4,
    ][i.min(3)]
}

fn material_range(liquids: &Liquids) -> ColourRange {
    let ids = liquids.0.iter().map(|(_, id)| id.0 as f32);
    let (min, max) = ids.fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    ColourRange::Fixed { min, max }
}

/// Keeps the target inside the tank, away from the walls by the nozzle's radius.
fn clamp_to_tank(p: Vec3) -> Vec3 {
    let m = NOZZLE_RADIUS + 0.02;
    Vec3::new(
        p.x.clamp(m, TANK.x - m),
        p.y.clamp(0.0, TANK.y - 0.15),
        p.z.clamp(m, TANK.z - m),
    )
}

/// Scripted mode: a figure-of-eight over the tank, pouring, the liquid switched every quarter.
fn scripted_aim(
    mut pour: ResMut<Pour>,
    options: Res<Options>,
    stats: Res<FrameStats>,
    liquids: Res<Liquids>,
) {
    let frame = stats.frames_ms.len();
    let total = options.frames.unwrap_or(600).max(4);
    let t = frame as f32 / 60.0;
    let w = 0.5;
    pour.target = clamp_to_tank(Vec3::new(
        0.4 + 0.24 * (w * t).sin(),
        0.0,
        0.25 + 0.12 * (2.0 * w * t).sin(),
    ));
    pour.clearance = 0.22;
    pour.toggled = true;
    pour.liquid = (frame * liquids.0.len() / total).min(liquids.0.len() - 1);
}

/// Reset: despawn the liquid, put the boxes back, clear a failure.
#[derive(bevy::ecs::system::SystemParam)]
struct ResetParams<'w, 's> {
    commands: Commands<'w, 's>,
    particles: Query<'w, 's, Entity, With<Particle>>,
    crates: Query<
        'w,
        's,
        (
            &'static Crate,
            &'static mut Transform,
            &'static mut av::Position,
            &'static mut av::Rotation,
            &'static mut av::LinearVelocity,
            &'static mut av::AngularVelocity,
        ),
    >,
    status: ResMut<'w, SimulationStatus>,
    pour: ResMut<'w, Pour>,
}

/// After [`player_input`] (which casts rays through Avian's colliders, so it cannot also move
/// the boxes): the reset R asked for.
fn reset_game(mut reset: ResetParams) {
    if std::mem::take(&mut reset.pour.reset) {
        reset.run();
    }
}

impl ResetParams<'_, '_> {
    fn run(&mut self) {
        for e in &self.particles {
            self.commands.entity(e).try_despawn();
        }
        for (start, mut t, mut p, mut r, mut v, mut w) in &mut self.crates {
            *t = start.0;
            p.0 = start.0.translation;
            r.0 = start.0.rotation;
            v.0 = Vec3::ZERO;
            w.0 = Vec3::ZERO;
        }
        self.status.failure = None;
    }
}

// ---------------------------------------------------------------------------------------------
// The game's systems

/// `FixedUpdate`, before the liquid's frame: moves the nozzle towards its goal (at most
/// [`NOZZLE_SPEED`]), sets its liquid, and starts or stops it.
fn drive_nozzle(
    time: Res<Time>,
    pour: Res<Pour>,
    liquids: Res<Liquids>,
    clock: Res<SimulationClock>,
    mut nozzle: Query<(&mut Transform, &mut NozzleEmitter), With<Nozzle>>,
) {
    let Ok((mut t, mut emitter)) = nozzle.single_mut() else {
        return;
    };
    let goal = pour.nozzle_goal();
    let step = goal - t.translation;
    let max = NOZZLE_SPEED * time.delta_secs();
    let moved = if step.length() > max {
        step.normalize_or_zero() * max
    } else {
        step
    };
    if moved != Vec3::ZERO && moved.is_finite() {
        t.translation += moved;
    }
    if let Some((_, id)) = liquids.0.get(pour.liquid)
        && emitter.material != *id
    {
        emitter.material = *id;
    }
    // On: no stop time; off: stopped now (nothing more is extruded).
    let stop = if pour.pouring() {
        None
    } else {
        Some(clock.time.max(emitter.start_time))
    };
    if pour.pouring() != emitter.stop_time.is_none() {
        emitter.stop_time = stop;
    }
}

/// Removes the particles in the open drain; pauses pouring at the cap.
fn drain_and_cap(
    mut commands: Commands,
    options: Res<Options>,
    mut pour: ResMut<Pour>,
    particles: Query<(Entity, &treacle::components::Position), With<Particle>>,
    disc: Query<&MeshMaterial3d<StandardMaterial>, With<DrainDisc>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut drawn_open: Local<Option<bool>>,
) {
    let mut n = 0;
    for (e, x) in &particles {
        let d = Vec3::new(x.0.x - DRAIN_CENTRE.x, 0.0, x.0.z - DRAIN_CENTRE.z);
        if pour.drain_open && x.0.y < 0.05 && d.length() < DRAIN_RADIUS {
            commands.entity(e).try_despawn();
        } else {
            n += 1;
        }
    }
    pour.particles = n;
    // Hysteresis: pouring resumes 5 % below the cap.
    if n >= options.max_particles {
        pour.full = true;
    } else if n * 20 < options.max_particles * 19 {
        pour.full = false;
    }
    if *drawn_open != Some(pour.drain_open)
        && let Ok(m) = disc.single()
        && let Some(mut mat) = materials.get_mut(&m.0)
    {
        *drawn_open = Some(pour.drain_open);
        let c = if pour.drain_open { 0.04 } else { 0.25 };
        mat.base_color = Color::srgb(c, c, c + 0.02);
    }
}

/// Treacle shadows of Avian entities that have just appeared and are still drawn.
type NewShadows = (Added<AvianSource>, Without<NoLiquidVisual>);

/// Hides the treacle shadows of the Avian entities marked [`HiddenShadow`] (before the renderer
/// gives them a drawing in `PostUpdate`).
fn hide_shadows(
    mut commands: Commands,
    shadows: Query<(Entity, &AvianSource), NewShadows>,
    hidden: Query<(), With<HiddenShadow>>,
) {
    for (shadow, source) in &shadows {
        if hidden.contains(source.entity) {
            commands.entity(shadow).insert(NoLiquidVisual);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// HUD and statistics

fn frame_stats(mut stats: ResMut<FrameStats>, clock: Res<SimulationClock>) {
    let now = Instant::now();
    if stats.start.is_none() {
        stats.start = Some(now);
        stats.sim_start = clock.time;
        stats.load_start = load_average();
    }
    if let Some(last) = stats.last {
        let ms = (now - last).as_secs_f64() * 1e3;
        stats.frames_ms.push(ms);
        stats.smoothed_ms = if stats.smoothed_ms > 0.0 {
            0.95 * stats.smoothed_ms + 0.05 * ms
        } else {
            ms
        };
    }
    stats.last = Some(now);
}

#[allow(clippy::too_many_arguments)]
fn update_hud(
    stats: Res<FrameStats>,
    pour: Res<Pour>,
    clock: Res<SimulationClock>,
    lag: Res<SimulationLag>,
    status: Res<SimulationStatus>,
    options: Res<Options>,
    mut text: Query<&mut Text, With<StatsText>>,
    mut status_text: Query<&mut Text, (With<StatusText>, Without<StatsText>)>,
    mut spans: Query<(&mut TextSpan, &LiquidSpan)>,
    liquids: Res<Liquids>,
    mut refreshed: Local<Option<Instant>>,
) {
    // Four times a second: a text change is laid out again.
    if refreshed.is_some_and(|t| t.elapsed() < Duration::from_millis(250)) {
        return;
    }
    *refreshed = Some(Instant::now());
    let real = stats.start.map_or(0.0, |s| s.elapsed().as_secs_f64());
    let simulated = clock.time - stats.sim_start;
    let fps = if stats.smoothed_ms > 0.0 {
        1000.0 / stats.smoothed_ms
    } else {
        0.0
    };
    if let Ok(mut t) = text.single_mut() {
        t.0 = format!(
            "{fps:5.1} FPS ({:5.1} ms)   {} / {} particles   {} sub-steps last tick\n\
             simulated {simulated:6.2} s, real {real:6.2} s: {:5.2} s behind real time \
             (budget cuts {:.2} s)",
            stats.smoothed_ms,
            pour.particles,
            options.max_particles,
            lag.last_substeps,
            (real - simulated).max(0.0),
            lag.total,
        );
    }
    for (mut span, LiquidSpan(i)) in &mut spans {
        let name = liquids.0.get(*i).map_or("?", |(l, _)| l.name());
        let label = if *i == pour.liquid {
            format!("[{} {name}]", i + 1)
        } else {
            format!(" {} {name} ", i + 1)
        };
        if span.0 != label {
            span.0 = label;
        }
    }
    if let Ok(mut t) = status_text.single_mut() {
        let msg = if let Some(f) = &status.failure {
            format!("simulation failed: {f} (R: reset)")
        } else if pour.full {
            format!(
                "tank full ({} particles): open the drain (D) or reset (R)",
                options.max_particles
            )
        } else {
            format!(
                "{} | nozzle {:.0} cm above target | drain {}",
                if pour.pouring() {
                    "pouring"
                } else {
                    "not pouring"
                },
                100.0 * pour.clearance,
                if pour.drain_open { "open" } else { "closed" }
            )
        };
        if t.0 != msg {
            t.0 = msg;
        }
    }
}

/// The 1-minute load average (Linux).
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Scripted mode: after the last frame, a screenshot, the statistics, exit.
#[allow(clippy::too_many_arguments)]
fn finish_script(
    mut commands: Commands,
    options: Res<Options>,
    stats: Res<FrameStats>,
    mut script: ResMut<ScriptState>,
    clock: Res<SimulationClock>,
    lag: Res<SimulationLag>,
    status: Res<SimulationStatus>,
    pour: Res<Pour>,
    mut exit: MessageWriter<AppExit>,
) {
    let Some(frames) = options.frames else { return };
    if stats.frames_ms.len() < frames {
        return;
    }
    if let Some(path) = &options.screenshot {
        if !script.shot_requested {
            script.shot_requested = true;
            let path = path.clone();
            commands.spawn(Screenshot::primary_window()).observe(
                move |shot: On<ScreenshotCaptured>, mut s: ResMut<ScriptState>| {
                    s.shot_done = Some(save_png(&shot.image, &path));
                },
            );
            return;
        }
        script.waited += 1;
        if script.shot_done.is_none() && script.waited < 120 {
            return;
        }
    }
    let measured = &stats.frames_ms[WARM_UP_FRAMES.min(frames.saturating_sub(1))..frames];
    let mut sorted = measured.to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(f64::NAN);
    let mean = sorted.iter().sum::<f64>() / sorted.len().max(1) as f64;
    let p95 = sorted
        .get((sorted.len() * 95 / 100).min(sorted.len().saturating_sub(1)))
        .copied()
        .unwrap_or(f64::NAN);
    let real = stats.start.map_or(0.0, |s| s.elapsed().as_secs_f64());
    let simulated = clock.time - stats.sim_start;
    println!(
        "frames {}..{frames}: frame time median {median:.1} ms, mean {mean:.1} ms, p95 {p95:.1} ms \
         ({:.1} FPS by the median)",
        frames - measured.len(),
        1000.0 / median
    );
    println!(
        "particles {} (cap {}), simulated {simulated:.2} s in {real:.2} s real ({:.2} s behind; \
         budget cuts {:.2} s), {} sub-steps last tick",
        pour.particles,
        options.max_particles,
        (real - simulated).max(0.0),
        lag.total,
        lag.last_substeps
    );
    println!(
        "load average (1 min): {} at the first frame, {} now",
        stats
            .load_start
            .map_or("?".to_string(), |l| format!("{l:.2}")),
        load_average().map_or("?".to_string(), |l| format!("{l:.2}"))
    );
    let mut code = 0u8;
    if let Some(f) = &status.failure {
        eprintln!("simulation failed: {f}");
        code = 2;
    }
    match &script.shot_done {
        Some(Ok(())) => {
            if let Some(p) = &options.screenshot {
                println!("screenshot: {}", p.display());
            }
        }
        Some(Err(e)) => {
            eprintln!("screenshot: {e}");
            code = 1;
        }
        None if options.screenshot.is_some() => {
            eprintln!("screenshot: none arrived after 120 frames");
            code = 1;
        }
        None => {}
    }
    exit.write(if code == 0 {
        AppExit::Success
    } else {
        AppExit::from_code(code)
    });
}

/// Writes a captured window image as PNG (8-bit RGBA or BGRA surfaces).
fn save_png(image: &Image, path: &std::path::Path) -> Result<(), String> {
    let (width, height) = (image.width(), image.height());
    let Some(data) = image.data.clone() else {
        return Err("the screenshot has no data".into());
    };
    if data.len() != 4 * width as usize * height as usize {
        return Err(format!(
            "the screenshot is {} bytes for {width}x{height} ({:?})",
            data.len(),
            image.texture_descriptor.format
        ));
    }
    let mut rgba = data;
    use bevy::render::render_resource::TextureFormat;
    match image.texture_descriptor.format {
        TextureFormat::Bgra8UnormSrgb | TextureFormat::Bgra8Unorm => {
            for p in rgba.chunks_exact_mut(4) {
                p.swap(0, 2);
            }
        }
        TextureFormat::Rgba8UnormSrgb | TextureFormat::Rgba8Unorm => {}
        other => return Err(format!("unsupported screenshot format {other:?}")),
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    }
    RenderedImage {
        width,
        height,
        rgba,
    }
    .write_png(path)
    .map_err(|e| e.to_string())
}
