//! Headless GPU rendering (feature `render`): a droplet frame and a scene with a box collider
//! rendered to PNG through Bevy's renderer (on machines without a GPU: Mesa's lavapipe).
//!
//! `cargo render-test --test render -- --nocapture` prints the measured coverages. The PNGs
//! are written to `<target>/tmp/treacle-render/`.
use std::path::{Path, PathBuf};

use glam::Vec3;
use treacle::output::ParticleFrame;
use treacle::render::ColourField;
use treacle::render::ColourRange;
use treacle::render::headless::{HeadlessRenderer, RenderOptions, RenderedImage};

const BIN: &str = env!("CARGO_BIN_EXE_treacle");

fn out_dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("treacle-render")
        .join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Particles on a cubic lattice of spacing `h` inside a sphere.
fn sphere_lattice(center: Vec3, radius: f32, h: f32) -> Vec<[f32; 3]> {
    let n = (radius / h).ceil() as i32;
    let mut p = Vec::new();
    for i in -n..=n {
        for j in -n..=n {
            for k in -n..=n {
                let d = Vec3::new(i as f32 + 0.5, j as f32 + 0.5, k as f32 + 0.5) * h;
                if d.length() <= radius {
                    p.push((center + d).to_array());
                }
            }
        }
    }
    p
}

/// A falling droplet: velocity −(1 + y − y_min) m/s downwards, so speed grows with height.
fn droplet_frame(center: Vec3, radius: f32, h: f32) -> ParticleFrame {
    let positions = sphere_lattice(center, radius, h);
    let y0 = center.y - radius;
    let velocities: Vec<[f32; 3]> = positions
        .iter()
        .map(|p| [0.0, -(1.0 + 10.0 * (p[1] - y0)), 0.0])
        .collect();
    ParticleFrame::from_vec3(
        3,
        0.05,
        &positions.iter().map(|p| Vec3::from(*p)).collect::<Vec<_>>(),
        &velocities
            .iter()
            .map(|v| Vec3::from(*v))
            .collect::<Vec<_>>(),
    )
}

/// Liquid-coloured: a saturated colour (the viridis map is; the background, the grey floor and
/// the grey colliders are not: their HSV saturation is ≤ 0.15). The brightness floor keeps
/// quantisation noise of near-black pixels out.
fn is_liquid(p: [u8; 4]) -> bool {
    let max = p[0].max(p[1]).max(p[2]) as f32;
    let min = p[0].min(p[1]).min(p[2]) as f32;
    max >= 30.0 && (max - min) / max > 0.35
}

/// [`variety`] of `img`, printed with the image's path and particle count.
fn variety_printed(img: &RenderedImage, png: &Path, particles: usize) -> (usize, f64) {
    let (colours, sd) = variety(img);
    println!(
        "{}: {particles} particles, {colours} colours, luminance sd {sd:.1}",
        png.display()
    );
    (colours, sd)
}

fn colour_distance(a: [u8; 4], b: [u8; 4]) -> i32 {
    (0..3)
        .map(|i| (a[i] as i32 - b[i] as i32).abs())
        .max()
        .unwrap()
}

/// Convex hull (counter-clockwise, Andrew's monotone chain) of 2D points.
fn hull(mut pts: Vec<[f32; 2]>) -> Vec<[f32; 2]> {
    pts.sort_by(|a, b| a.partial_cmp(b).unwrap());
    pts.dedup();
    if pts.len() < 3 {
        return pts;
    }
    let cross = |o: [f32; 2], a: [f32; 2], b: [f32; 2]| {
        (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
    };
    let mut lower: Vec<[f32; 2]> = Vec::new();
    for &p in &pts {
        while lower.len() >= 2 && cross(lower[lower.len() - 2], lower[lower.len() - 1], p) <= 0.0 {
            lower.pop();
        }
        lower.push(p);
    }
    let mut upper: Vec<[f32; 2]> = Vec::new();
    for &p in pts.iter().rev() {
        while upper.len() >= 2 && cross(upper[upper.len() - 2], upper[upper.len() - 1], p) <= 0.0 {
            upper.pop();
        }
        upper.push(p);
    }
    lower.pop();
    upper.pop();
    lower.extend(upper);
    lower
}

/// Signed distance from `p` to the convex polygon `h` (negative inside).
fn hull_distance(h: &[[f32; 2]], p: [f32; 2]) -> f32 {
    let mut d = f32::NEG_INFINITY;
    for i in 0..h.len() {
        let (a, b) = (h[i], h[(i + 1) % h.len()]);
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let len = (ex * ex + ey * ey).sqrt().max(1e-9);
        // (ey, −ex)/len points out of the polygon for one orientation; `coverage` reverses
        // the hull if the centroid comes out positive.
        let n = (ey / len, -ex / len);
        d = d.max((p[0] - a[0]) * n.0 + (p[1] - a[1]) * n.1);
    }
    d
}

/// Measures of a rendered droplet against its projection. "Drawn" pixels differ from the same
/// view rendered without particles (particles cast no shadow, so nothing else changes).
struct Coverage {
    /// Fraction of projected particle centres on drawn pixels.
    centres: f64,
    /// Fraction of pixels inside the hull of the projected centres (shrunk by 2 px) that are
    /// drawn.
    hull_inside: f64,
    /// Fraction of those that are liquid-coloured (saturated; specular highlights are not).
    hull_liquid: f64,
    /// Fraction of pixels farther than a projected radius + 2 px from every centre that are
    /// drawn (should be none).
    outside_drawn: f64,
    /// Fraction of those that are liquid-coloured (should be none).
    outside_liquid: f64,
    /// Liquid-coloured pixels in the image.
    liquid_pixels: usize,
}

/// Pixels differing by more than this in a channel (0–255) from the particle-free render are
/// drawn: well above the ±1 of sRGB rounding, well below the contrast of a shaded sphere on
/// the background or floor (≥ 60 here).
const DRAWN: i32 = 12;

fn coverage(
    r: &mut HeadlessRenderer,
    img: &RenderedImage,
    empty: &RenderedImage,
    positions: &[[f32; 3]],
    radius: f32,
) -> Coverage {
    let drawn = |x: u32, y: u32| colour_distance(img.pixel(x, y), empty.pixel(x, y)) > DRAWN;
    let (w, h) = (img.width as i64, img.height as i64);
    let mut centres = Vec::new();
    // Largest projected radius: the centre to its ±radius offsets along the world axes.
    let mut r_px: f32 = 0.0;
    for p in positions {
        let c = r
            .world_to_pixel(Vec3::from(*p))
            .expect("particle in front of the camera");
        for axis in [Vec3::X, Vec3::Y, Vec3::Z] {
            for s in [-1.0, 1.0] {
                if let Some(q) = r.world_to_pixel(Vec3::from(*p) + axis * radius * s) {
                    r_px = r_px.max(q.distance(c));
                }
            }
        }
        centres.push([c.x, c.y]);
    }
    let on_liquid = centres
        .iter()
        .filter(|c| {
            let (x, y) = (c[0] as i64, c[1] as i64);
            x >= 0 && y >= 0 && x < w && y < h && drawn(x as u32, y as u32)
        })
        .count();
    // Pixels near a projected particle.
    let mut near = vec![false; (w * h) as usize];
    let reach = r_px + 2.0;
    for c in &centres {
        let (x0, x1) = ((c[0] - reach).floor() as i64, (c[0] + reach).ceil() as i64);
        let (y0, y1) = ((c[1] - reach).floor() as i64, (c[1] + reach).ceil() as i64);
        for y in y0.max(0)..=y1.min(h - 1) {
            for x in x0.max(0)..=x1.min(w - 1) {
                let (dx, dy) = (x as f32 + 0.5 - c[0], y as f32 + 0.5 - c[1]);
                if dx * dx + dy * dy <= reach * reach {
                    near[(y * w + x) as usize] = true;
                }
            }
        }
    }
    let mut hull_pts = hull(centres.clone());
    // Make the hull counter-clockwise in y-down pixel coordinates if needed (the distance
    // function assumes outward normals (ey, −ex)).
    let centroid = centres
        .iter()
        .fold([0.0f32; 2], |a, c| [a[0] + c[0], a[1] + c[1]]);
    let centroid = [
        centroid[0] / centres.len() as f32,
        centroid[1] / centres.len() as f32,
    ];
    if hull_distance(&hull_pts, centroid) > 0.0 {
        hull_pts.reverse();
    }
    let (mut inside, mut inside_drawn, mut inside_liquid) = (0, 0, 0);
    let (mut outside, mut outside_drawn, mut outside_liquid, mut liquid) = (0, 0, 0, 0);
    for y in 0..h {
        for x in 0..w {
            let l = is_liquid(img.pixel(x as u32, y as u32)) as usize;
            let d = drawn(x as u32, y as u32) as usize;
            liquid += l;
            let p = [x as f32 + 0.5, y as f32 + 0.5];
            if hull_distance(&hull_pts, p) < -2.0 {
                inside += 1;
                inside_drawn += d;
                inside_liquid += l;
            }
            if !near[(y * w + x) as usize] {
                outside += 1;
                outside_drawn += d;
                outside_liquid += l;
            }
        }
    }
    println!(
        "projected radius {r_px:.1} px, {} centres, hull {inside} px, outside {outside} px",
        centres.len()
    );
    let frac = |a: usize, b: usize| a as f64 / b.max(1) as f64;
    let c = Coverage {
        centres: frac(on_liquid, centres.len()),
        hull_inside: frac(inside_drawn, inside),
        hull_liquid: frac(inside_liquid, inside),
        outside_drawn: frac(outside_drawn, outside),
        outside_liquid: frac(outside_liquid, outside),
        liquid_pixels: liquid,
    };
    println!(
        "centres drawn {:.4}, hull interior drawn {:.4} liquid-coloured {:.4}, outside drawn {:.5} liquid-coloured {:.5}, liquid pixels {}",
        c.centres, c.hull_inside, c.hull_liquid, c.outside_drawn, c.outside_liquid, c.liquid_pixels
    );
    c
}

/// The droplet's coverage assertions (tolerances justified in `droplet_frame_renders…`).
fn assert_covers(c: &Coverage) {
    assert!(c.centres >= 0.995, "centres drawn: {}", c.centres);
    assert!(
        c.hull_inside >= 0.99,
        "hull interior drawn: {}",
        c.hull_inside
    );
    assert!(
        c.hull_liquid >= 0.9,
        "hull interior liquid-coloured: {}",
        c.hull_liquid
    );
    assert!(
        c.outside_drawn <= 0.0005,
        "drawn outside: {}",
        c.outside_drawn
    );
    assert!(
        c.outside_liquid <= 0.0005,
        "liquid outside: {}",
        c.outside_liquid
    );
}

/// Distinct colours and the standard deviation of the luminance (0–255).
fn variety(img: &RenderedImage) -> (usize, f64) {
    let mut colours: Vec<[u8; 3]> = img
        .rgba
        .chunks_exact(4)
        .map(|p| [p[0], p[1], p[2]])
        .collect();
    let lum: Vec<f64> = colours
        .iter()
        .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
        .collect();
    let mean = lum.iter().sum::<f64>() / lum.len() as f64;
    let sd = (lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / lum.len() as f64).sqrt();
    colours.sort();
    colours.dedup();
    (colours.len(), sd)
}

fn options() -> RenderOptions {
    RenderOptions {
        width: 480,
        height: 360,
        ..Default::default()
    }
}

#[test]
fn droplet_frame_renders_where_its_particles_project() {
    let dir = out_dir("droplet");
    let frame = droplet_frame(Vec3::new(0.15, 0.15, 0.15), 0.05, 0.005);
    let mut r =
        HeadlessRenderer::new(&options()).expect("renderer (is a Vulkan driver installed?)");
    r.set_frame(
        &frame,
        &ColourField::Speed,
        ColourRange::Auto,
        Path::new("droplet"),
    )
    .unwrap();
    let radius = 0.0025;
    let lo = Vec3::new(0.1, 0.1, 0.1) - Vec3::splat(radius);
    let hi = Vec3::new(0.2, 0.2, 0.2) + Vec3::splat(radius);
    r.frame_camera(lo, hi);
    let img = r.render().unwrap();
    let png = dir.join("droplet.png");
    img.write_png(&png).unwrap();
    // The same view without particles.
    r.set_particles(&[], &[], ColourRange::Auto, radius, 0.05);
    let empty = r.render().unwrap();
    empty.write_png(&dir.join("droplet_empty.png")).unwrap();
    r.set_frame(
        &frame,
        &ColourField::Speed,
        ColourRange::Auto,
        Path::new("droplet"),
    )
    .unwrap();
    let again = r.render().unwrap();
    let c = coverage(&mut r, &img, &empty, &frame.positions, radius);
    let (colours, sd) = variety_printed(&img, &png, frame.len());
    // Every particle's centre pixel lies in its own disc or in a nearer one; spheres touching
    // on a lattice leave no holes through several layers; nothing is drawn where no particle
    // projects. The tolerances (0.5 % of centres, 1 % of the hull, 0.05 % outside) cover the
    // multisampled pixels where a centre or the hull's edge falls within a pixel of the
    // silhouette; 10 % of the hull may be specular highlights (unsaturated).
    assert_covers(&c);
    // Rendering is repeatable: the same frame gives the same image.
    assert_eq!(img, again, "a second render of the same frame differs");
    // Neither blank nor uniform: the droplet, background and floor, shaded.
    assert!(c.liquid_pixels > 2000, "{} liquid pixels", c.liquid_pixels);
    assert!(colours > 100 && sd > 10.0, "{colours} colours, sd {sd}");
    // Colour follows the field: the top particle (fastest) is yellow-green (red and green
    // above blue), the map's high end; it is visible from a camera above the horizon.
    let top = frame
        .positions
        .iter()
        .max_by(|a, b| a[1].partial_cmp(&b[1]).unwrap())
        .unwrap();
    let q = r.world_to_pixel(Vec3::from(*top)).unwrap();
    let p = img.pixel(q.x as u32, q.y as u32);
    println!("top particle pixel {p:?}");
    assert!(
        p[1] > p[2] && p[0] > p[2] / 2,
        "top pixel {p:?} is not at the yellow end"
    );
}

const BOX_SCENE: &str = r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.4, 0.3, 0.3)),
    dx: 0.01,
    particles_per_cell: 2,
    duration: 0.02,
    frame_rate: 100.0,
    materials: [(name: "water", density: 1000.0, sound_speed: 10.0, viscosity: 0.01)],
    bodies: [(material: "water", shape: Sphere(center: (0.1, 0.15, 0.15), radius: 0.04))],
    colliders: [
        (shape: Box(half_extents: (0.05, 0.04, 0.05)), boundary: Slip, translation: (0.28, 0.06, 0.15), remove_at: Some(0.5)),
    ],
    output: (format: Ply, every: 1, fields: [Density]),
)"#;

#[test]
fn scene_with_box_collider_shows_liquid_and_collider() {
    let dir = out_dir("box_scene");
    let scene_path = dir.join("box.ron");
    std::fs::write(&scene_path, BOX_SCENE).unwrap();
    let scene = treacle::scene::load_scene(&scene_path).unwrap();
    let positions: Vec<[f32; 3]> = scene.particles[0]
        .positions
        .iter()
        .map(|p| p.to_array())
        .collect();
    let heights: Vec<f32> = positions.iter().map(|p| p[1]).collect();
    let radius = 0.0025;
    let mut r = HeadlessRenderer::new(&options()).unwrap();
    r.set_scene_objects(&scene);
    r.set_particles(&positions, &heights, ColourRange::Auto, radius, 0.0);
    r.frame_camera(Vec3::new(0.05, 0.0, 0.1), Vec3::new(0.34, 0.2, 0.2));
    let with_box = r.render().unwrap();
    with_box.write_png(&dir.join("with_box.png")).unwrap();
    r.set_particles(&[], &[], ColourRange::Auto, radius, 0.0);
    let empty = r.render().unwrap();
    empty
        .write_png(&dir.join("with_box_no_particles.png"))
        .unwrap();
    let c = coverage(&mut r, &with_box, &empty, &positions, radius);
    assert_covers(&c);

    // The same view after the collider's `remove_at` (0.5 s): its drawing goes with it.
    let count_colliders = |r: &mut HeadlessRenderer| {
        let world = r.app_mut().world_mut();
        world
            .query_filtered::<bevy::ecs::entity::Entity, bevy::ecs::query::With<treacle::collision::Collider>>()
            .iter(world)
            .count()
    };
    assert_eq!(count_colliders(&mut r), 1);
    r.set_particles(&[], &[], ColourRange::Auto, radius, 0.5);
    assert_eq!(count_colliders(&mut r), 0, "removed at its remove_at");
    let without = r.render().unwrap();
    without.write_png(&dir.join("without_box.png")).unwrap();

    // Sample points on the box's visible faces: the centre of the top face and of the front
    // (+z) and right (+x) faces, and points between them, all seen by a camera above, in
    // front and to the right. There the two images differ (the box hides floor and
    // background) and the box is grey, not liquid-coloured.
    let centre = Vec3::new(0.28, 0.06, 0.15);
    let h = Vec3::new(0.05, 0.04, 0.05);
    let mut samples = Vec::new();
    for (face, u, v) in [
        (Vec3::Y, Vec3::X, Vec3::Z),
        (Vec3::Z, Vec3::X, Vec3::Y),
        (Vec3::X, Vec3::Y, Vec3::Z),
    ] {
        for (a, b) in [
            (0.0, 0.0),
            (0.5, 0.5),
            (-0.5, 0.5),
            (0.5, -0.5),
            (-0.5, -0.5),
        ] {
            samples.push(centre + face * h + u * h * a + v * h * b);
        }
    }
    let mut changed = 0;
    for s in &samples {
        let q = r.world_to_pixel(*s).unwrap();
        let (a, b) = (
            with_box.pixel(q.x as u32, q.y as u32),
            without.pixel(q.x as u32, q.y as u32),
        );
        println!("box sample {s:?} at {q:?}: with {a:?} without {b:?}");
        assert!(!is_liquid(a), "box pixel {a:?} looks like liquid");
        if colour_distance(a, b) > 20 {
            changed += 1;
        }
    }
    assert!(
        changed >= samples.len() - 1,
        "box visible at {changed}/{} samples",
        samples.len()
    );
    let (colours, sd) = variety(&with_box);
    assert!(colours > 100 && sd > 10.0);
    // A frame before the removal (frames rendered out of order) draws it again.
    r.set_particles(&[], &[], ColourRange::Auto, radius, 0.25);
    assert_eq!(
        count_colliders(&mut r),
        1,
        "drawn again before its remove_at"
    );
}

#[test]
fn cli_renders_a_run_directory_with_its_scene() {
    let dir = out_dir("cli");
    let scene_path = dir.join("box.ron");
    std::fs::write(&scene_path, BOX_SCENE).unwrap();
    let run = dir.join("run");
    let out = dir.join("png");
    let status = std::process::Command::new(BIN)
        .args([
            "run",
            scene_path.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
            "--frames",
            "2",
        ])
        .status()
        .unwrap();
    assert!(status.success());
    let o = std::process::Command::new(BIN)
        .args([
            "render",
            run.to_str().unwrap(),
            "--scene",
            scene_path.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--size",
            "320x240",
        ])
        .output()
        .unwrap();
    println!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success());
    for f in 0..=2 {
        let png = out.join(format!("frame_{f:05}.png"));
        let bytes = std::fs::read(&png).unwrap_or_else(|e| panic!("{}: {e}", png.display()));
        assert!(bytes.starts_with(b"\x89PNG"));
    }
    // Bad input is an error naming the field, not a panic.
    let o = std::process::Command::new(BIN)
        .args([
            "render",
            run.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--color",
            "vorticity",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no field `vorticity`") && err.contains("frame_00000.ply"),
        "{err}"
    );
}

/// The plugin next to `MpmPlugins` in one app, reading the particle entities of its world
/// (`ParticleFeed::World`): a resting droplet without gravity (it stays where it is while the
/// simulation runs during the renders) is drawn where its particles project.
#[test]
fn live_particles_next_to_mpm_plugins_are_drawn() {
    use bevy::ecs::query::With;
    use treacle::prelude::*;
    use treacle::render::{ParticleFeed, ParticleStyle};
    let dir = out_dir("live");
    let config = MpmConfig {
        dx: 0.01,
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.3),
        gravity: Vec3::ZERO,
        ..Default::default()
    };
    let mut materials = Materials::default();
    let water = materials.add(FluidMaterial::newtonian("water", 1000.0, 10.0, 0.01));
    let mut r = HeadlessRenderer::with_app(&options(), ParticleFeed::World, move |app| {
        app.insert_resource(config)
            .insert_resource(materials)
            .add_plugins(MpmPlugins);
    })
    .unwrap();
    let h = 0.005;
    let radius = 0.5 * h;
    let world = r.app_mut().world_mut();
    world.insert_resource(ParticleStyle {
        radius,
        ..Default::default()
    });
    let start = sphere_lattice(Vec3::splat(0.15), 0.04, h);
    world.spawn_batch(start.iter().map(|p| {
        ParticleBundle::new(
            Vec3::from(*p),
            Vec3::ZERO,
            Vec3::ZERO,
            h * h * h,
            1000.0,
            water,
        )
    }));
    r.frame_camera(Vec3::splat(0.1), Vec3::splat(0.2));
    let img = r.render().unwrap();
    img.write_png(&dir.join("live.png")).unwrap();
    let world = r.app_mut().world_mut();
    let mut q = world.query_filtered::<&Position, With<Particle>>();
    let now: Vec<[f32; 3]> = q.iter(world).map(|p| p.0.to_array()).collect();
    let moved = start
        .iter()
        .zip(&now)
        .map(|(a, b)| Vec3::from(*a).distance(Vec3::from(*b)))
        .fold(0.0f32, f32::max);
    let time = world.resource::<treacle::schedule::SimulationClock>().time;
    println!(
        "{} particles, simulated {time:.3} s during the renders, largest displacement {moved:.2e} m",
        now.len()
    );
    // The simulation ran while rendering (one frame_dt per update).
    assert!(time > 0.0);
    // At rest, at rest density, without gravity: nothing drives the droplet (a sub-micrometre
    // drift from the free surface is far below a pixel, 0.4 mm here).
    assert!(moved < 1e-4, "the droplet moved {moved} m");
    let particles: Vec<_> = world
        .query_filtered::<bevy::ecs::entity::Entity, With<Particle>>()
        .iter(world)
        .collect();
    for e in particles {
        world.despawn(e);
    }
    let empty = r.render().unwrap();
    empty.write_png(&dir.join("live_empty.png")).unwrap();
    let c = coverage(&mut r, &img, &empty, &now, radius);
    assert_covers(&c);
}

/// Surface mode: the droplet frame drawn as its reconstructed surface with the honey PBR
/// material instead of the particles.
#[test]
fn droplet_surface_renders_with_pbr_material_over_the_projected_region() {
    use treacle::render::surface::{SurfaceLook, SurfacePreset};
    use treacle::surface::SurfaceParams;
    let dir = out_dir("droplet_surface");
    let h = 0.005;
    let frame = droplet_frame(Vec3::new(0.15, 0.15, 0.15), 0.05, h);
    let mut r =
        HeadlessRenderer::new(&options()).expect("renderer (is a Vulkan driver installed?)");
    let lo = Vec3::splat(0.1 - h);
    let hi = Vec3::splat(0.2 + h);
    r.frame_camera(lo, hi);
    let set = |r: &mut HeadlessRenderer| {
        r.set_frame(
            &frame,
            &ColourField::Speed,
            ColourRange::Auto,
            Path::new("droplet"),
        )
        .unwrap()
    };
    // The particles, for comparison.
    set(&mut r);
    let particles = r.render().unwrap();
    particles
        .write_png(&dir.join("droplet_particles.png"))
        .unwrap();
    r.set_surface(
        Some(SurfacePreset::Honey),
        SurfaceLook::Preset,
        Some(SurfaceParams::for_spacing(h)),
    );
    let img = r.render().unwrap();
    let png = dir.join("droplet_surface.png");
    img.write_png(&png).unwrap();
    // The same view without particles (no surface either).
    r.set_particles(&[], &[], ColourRange::Auto, 0.5 * h, 0.05);
    let empty = r.render().unwrap();
    empty
        .write_png(&dir.join("droplet_surface_empty.png"))
        .unwrap();
    set(&mut r);
    let again = r.render().unwrap();
    // The surface lies about h/2 beyond the outermost centres (each particle stands for h³),
    // smoothed by the kernel: its silhouette is within h of them.
    let c = coverage(&mut r, &img, &empty, &frame.positions, h);
    let (colours, sd) = variety_printed(&img, &png, frame.len());
    // Hull interior: honey-coloured (red > green > blue) and unlike the particle image.
    let (w, hgt) = (img.width, img.height);
    let centre = r.world_to_pixel(Vec3::splat(0.15)).unwrap();
    let edge = r
        .world_to_pixel(Vec3::new(0.15 + 0.04, 0.15, 0.15))
        .unwrap();
    let disc = centre.distance(edge);
    let (mut n, mut amber, mut differ) = (0usize, 0usize, 0usize);
    let mut lum = Vec::new();
    for y in 0..hgt {
        for x in 0..w {
            let p = glam::Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            if p.distance(centre) > disc {
                continue;
            }
            let q = img.pixel(x, y);
            n += 1;
            amber += (q[0] > q[1] && q[1] > q[2]) as usize;
            differ += (colour_distance(q, particles.pixel(x, y)) > 40) as usize;
            lum.push(0.2126 * q[0] as f64 + 0.7152 * q[1] as f64 + 0.0722 * q[2] as f64);
        }
    }
    let mean = lum.iter().sum::<f64>() / lum.len() as f64;
    let lum_sd = (lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / lum.len() as f64).sqrt();
    let frac = |a: usize| a as f64 / n.max(1) as f64;
    println!(
        "disc {disc:.1} px, {n} px: amber {:.4}, differing from the particles {:.4}, luminance mean {mean:.1} sd {lum_sd:.1}",
        frac(amber),
        frac(differ)
    );
    assert!(c.centres >= 0.995, "centres drawn: {}", c.centres);
    assert!(
        c.hull_inside >= 0.99,
        "hull interior drawn: {}",
        c.hull_inside
    );
    assert!(
        c.outside_drawn <= 0.0005,
        "drawn outside: {}",
        c.outside_drawn
    );
    assert!(frac(amber) >= 0.9, "amber: {}", frac(amber));
    assert!(frac(differ) >= 0.8, "like the particles: {}", frac(differ));
    assert!(lum_sd > 5.0, "flat shading: sd {lum_sd}");
    assert_eq!(img, again, "a second render of the same frame differs");
    assert!(colours > 100 && sd > 10.0, "{colours} colours, sd {sd}");

    // The speed field on the surface (viridis): the fast top yellow-green (green over blue),
    // the slow bottom purple (blue over green), as the particles are coloured.
    r.set_surface(
        Some(SurfacePreset::Honey),
        SurfaceLook::Field,
        Some(SurfaceParams::for_spacing(h)),
    );
    let field = r.render().unwrap();
    field
        .write_png(&dir.join("droplet_surface_field.png"))
        .unwrap();
    let mean_near = |img: &treacle::render::headless::RenderedImage, p: glam::Vec2| {
        let mut sum = [0.0f64; 3];
        for dy in -2..=2 {
            for dx in -2..=2 {
                let q = img.pixel((p.x as i32 + dx) as u32, (p.y as i32 + dy) as u32);
                for c in 0..3 {
                    sum[c] += q[c] as f64 / 25.0;
                }
            }
        }
        sum
    };
    // Points of the sphere facing the camera (the default view looks down 25°) at heights
    // ±0.6 r: speeds at 20 % and 80 % of the range, viridis blue-purple and green.
    let toward = -treacle::render::LiquidCamera::default()
        .direction
        .normalize();
    let level = Vec3::new(toward.x, 0.0, toward.z).normalize();
    let mut at = |y: f32| {
        let n = Vec3::new(0.0, y, 0.0) + (1.0 - y * y).sqrt() * level;
        assert!(
            n.dot(toward) > 0.0,
            "the sample point faces away from the camera"
        );
        r.world_to_pixel(Vec3::splat(0.15) + 0.05 * n).unwrap()
    };
    let (p_top, p_bottom) = (at(0.6), at(-0.6));
    let (top, bottom) = (mean_near(&field, p_top), mean_near(&field, p_bottom));
    println!("field on the surface: top rgb {top:.0?}, bottom rgb {bottom:.0?}");
    // Hue (degrees) and saturation: lighting scales the channels, not their order.
    let hue_sat = |c: [f64; 3]| {
        let (max, min) = (c[0].max(c[1]).max(c[2]), c[0].min(c[1]).min(c[2]));
        let d = (max - min).max(1e-9);
        let h = if max == c[0] {
            60.0 * ((c[1] - c[2]) / d).rem_euclid(6.0)
        } else if max == c[1] {
            60.0 * ((c[2] - c[0]) / d + 2.0)
        } else {
            60.0 * ((c[0] - c[1]) / d + 4.0)
        };
        (h, d / max.max(1e-9))
    };
    let ((h_top, s_top), (h_bottom, s_bottom)) = (hue_sat(top), hue_sat(bottom));
    // Viridis at 80 %: green (hue ≈ 100°); at 20 %: blue-purple (hue ≈ 240°).
    assert!(
        (60.0..150.0).contains(&h_top) && s_top > 0.3,
        "top not green: hue {h_top:.0}, saturation {s_top:.2}"
    );
    assert!(
        (200.0..290.0).contains(&h_bottom) && s_bottom > 0.1,
        "bottom not blue-purple: hue {h_bottom:.0}, saturation {s_bottom:.2}"
    );
}
