//! Triangle-mesh colliders (`ColliderShape::Mesh`, `treacle::collision::MeshSdf`) against the
//! analytic shapes: a box mesh reproduces the analytic box's φ and normal, an icosphere stays
//! within its chord error of the analytic sphere, the fast query agrees with the exact one
//! where the collision operator acts, the inside test agrees with the ray-parity sampler on
//! the bunny, and liquid falls on / is pushed by a mesh box like by the analytic box.
use crate::common;

use std::collections::HashMap;
use std::sync::Arc;

use common::*;
use glam::Quat;
use treacle::collision::{ColliderInstance, MeshSdf};
use treacle::diagnostics::measure;
use treacle::mesh::TriMesh;
use treacle::prelude::*;
use treacle::sampling::{Lattice, SplitMix64, sample_mesh};

/// Closed box mesh [−h, h] (12 triangles, outward).
fn box_mesh(h: Vec3) -> TriMesh {
    let v = (0..8)
        .map(|i| {
            Vec3::new(
                if i & 1 == 0 { -h.x } else { h.x },
                if i & 2 == 0 { -h.y } else { h.y },
                if i & 4 == 0 { -h.z } else { h.z },
            )
        })
        .collect();
    // Quads (counter-clockwise seen from outside), split into two triangles each.
    let quads = [
        [0, 2, 3, 1], // z−
        [4, 5, 7, 6], // z+
        [0, 1, 5, 4], // y−
        [2, 6, 7, 3], // y+
        [0, 4, 6, 2], // x−
        [1, 3, 7, 5], // x+
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    TriMesh {
        vertices: v,
        triangles,
    }
}

/// Icosahedron subdivided `levels` times, vertices on the sphere of radius `r`, outward.
fn icosphere(r: f32, levels: u32) -> TriMesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut v: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut midpoint = |a: u32, b: u32, v: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a as usize] + v[b as usize]) * 0.5).normalize());
                (v.len() - 1) as u32
            })
        };
        let mut next = Vec::with_capacity(f.len() * 4);
        for [a, b, c] in f {
            let ab = midpoint(a, b, &mut v);
            let bc = midpoint(b, c, &mut v);
            let ca = midpoint(c, a, &mut v);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = next;
    }
    // Orient every face outwards (the mesh is convex around the origin).
    for t in &mut f {
        let [a, b, c] = t.map(|i| v[i as usize]);
        if (b - a).cross(c - a).dot(a + b + c) < 0.0 {
            t.swap(1, 2);
        }
    }
    TriMesh {
        vertices: v.into_iter().map(|p| p * r).collect(),
        triangles: f,
    }
}

fn random_point(rng: &mut SplitMix64, half: Vec3) -> Vec3 {
    let mut u = || (2.0 * rng.next_f64() - 1.0) as f32;
    Vec3::new(u() * half.x, u() * half.y, u() * half.z)
}

/// A closed box mesh gives the analytic box's φ and normal (ALGORITHM §2.11 needs both) at
/// random points inside and around it, through the fast query (`ColliderShape::sdf`), the
/// exact one and a rotated, translated collider pose.
///
/// Tolerances: the mesh computes φ from a closest point in f32 (coordinates ≤ 0.6 m, rounding
/// ≈ 4·10⁻⁸ m per operation), so φ agrees to 10⁻⁵ relative to max(|φ|, 0.1 m); the normal
/// (p − q)/|φ| carries that ~10⁻⁷ m error divided by |φ|, so it is compared to
/// 10⁻⁵ + 10⁻⁶ m/|φ|. Inside, the analytic normal is that of the nearest face, which is
/// ambiguous where two faces are (nearly) equidistant: those points (gap < 10⁻³ m) are
/// skipped for the normal only.
#[test]
fn box_mesh_matches_analytic_box() {
    let he = Vec3::new(0.3, 0.2, 0.1);
    let sdf = Arc::new(MeshSdf::new(&box_mesh(he)).unwrap());
    assert!((sdf.volume() - 8.0 * 0.3 * 0.2 * 0.1).abs() < 1e-6);
    let mesh = ColliderShape::Mesh(sdf.clone());
    let analytic = ColliderShape::Box { half_extents: he };
    let pose = ColliderPose {
        translation: Vec3::new(0.4, -0.1, 0.25),
        rotation: Quat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1),
    };
    let instance = |shape: &ColliderShape| ColliderInstance {
        shape: shape.clone(),
        boundary: BoundaryCondition::Slip,
        pose,
        motion: ColliderMotion::default(),
    };
    let (im, ib) = (instance(&mesh), instance(&analytic));
    let mut rng = SplitMix64::new(7);
    let (mut inside, mut compared_normals) = (0, 0);
    for _ in 0..20_000 {
        let p = random_point(&mut rng, Vec3::splat(0.6));
        let (pb, nb) = analytic.sdf(p);
        let tol = 1e-5 * pb.abs().max(0.1);
        let q = p.abs() - he;
        let mut d = [-q.x, -q.y, -q.z];
        d.sort_by(f32::total_cmp);
        let ambiguous = pb < 0.0 && d[1] - d[0] < 1e-3;
        for (what, (pm, nm)) in [("sdf", mesh.sdf(p)), ("exact", sdf.exact_sdf(p))] {
            assert!(
                (pm - pb).abs() <= tol,
                "{what} at {p}: mesh φ {pm} vs box φ {pb}"
            );
            if pb.abs() > 1e-4 && !ambiguous {
                let tol_n = 1e-5 + 1e-6 / pb.abs();
                assert!(
                    (nm - nb).length() <= tol_n,
                    "{what} at {p} (φ {pb}): mesh n {nm} vs box n {nb}"
                );
                compared_normals += 1;
            }
        }
        inside += (pb < 0.0) as u32;
        // Same through a collider pose (world point; the rotation adds f32 rounding).
        let x = pose.translation + pose.rotation * p;
        let ((pm, nm, _), (pb2, nb2, _)) = (im.query(x), ib.query(x));
        assert!((pm - pb2).abs() <= 2.0 * tol, "posed at {x}: {pm} vs {pb2}");
        if pb.abs() > 1e-2 && !ambiguous {
            assert!((nm - nb2).length() <= 1e-4, "posed n {nm} vs {nb2}");
        }
    }
    // Enough points on both sides for the comparison to mean something.
    assert!(
        inside > 300 && compared_normals > 30_000,
        "{inside} {compared_normals}"
    );
}

/// An icosphere (5120 triangles) inscribed in the sphere of radius R contains the ball of
/// radius R − e, e = R − (smallest distance from the centre to a face plane) (the chord
/// error, computed from the mesh). Signed distance is monotone under inclusion, so
/// φ_sphere(R) ≤ φ_mesh ≤ φ_sphere(R) + e everywhere. Outside, the mesh normal is the
/// normal at the closest point q, and p = q + φ n lies in q's normal cone, so its angle to
/// the radial (analytic) normal p/|p| is at most θ = the largest angle between a face normal
/// and the direction of one of its corners. Also: the fast query equals the exact one where
/// φ ≤ band (where the collision operator acts), and is a positive lower bound beyond.
#[test]
fn icosphere_matches_analytic_sphere_within_chord_error() {
    let r = 0.25f32;
    let m = icosphere(r, 4);
    assert_eq!(m.triangles.len(), 5120);
    assert!(m.is_closed());
    let (mut plane_min, mut theta) = (f32::INFINITY, 0f32);
    for t in &m.triangles {
        let [a, b, c] = t.map(|i| m.vertices[i as usize]);
        let n = (b - a).cross(c - a).normalize();
        plane_min = plane_min.min(n.dot(a));
        for v in [a, b, c] {
            theta = theta.max(n.angle_between(v));
        }
    }
    let e = r - plane_min;
    assert!(e > 0.0 && e < 0.01 * r, "chord error {e}");
    let sdf = MeshSdf::new(&m).unwrap();
    let sphere = ColliderShape::Sphere { radius: r };
    let mut rng = SplitMix64::new(11);
    let (mut beyond_band, mut in_band) = (0, 0);
    // f32 rounding of coordinates ≤ 0.4 m: a few 10⁻⁸ m; allow 10⁻⁶ m.
    let eps = 1e-6;
    for _ in 0..20_000 {
        let p = random_point(&mut rng, Vec3::splat(1.6 * r));
        let (ps, ns) = sphere.sdf(p);
        let (pe, ne) = sdf.exact_sdf(p);
        assert!(
            pe >= ps - eps && pe <= ps + e + eps,
            "at {p}: mesh φ {pe} outside [{ps}, {}]",
            ps + e
        );
        if pe > 1e-4 {
            assert!(
                ne.angle_between(ns) <= theta + 1e-3,
                "at {p}: normal {ne} vs radial {ns} (θ = {theta})"
            );
        }
        let (pf, nf) = sdf.sdf(p);
        if pe <= sdf.band() {
            in_band += 1;
            assert!(
                (pf - pe).abs() <= eps && (nf - ne).length() <= 1e-4,
                "fast ({pf}, {nf}) vs exact ({pe}, {ne}) at {p}"
            );
        } else {
            beyond_band += 1;
            assert!(
                pf >= sdf.band() - eps && pf <= pe + eps,
                "fast {pf} vs exact {pe} (band {}) at {p}",
                sdf.band()
            );
        }
    }
    assert!(
        in_band > 1000 && beyond_band > 1000,
        "{in_band} {beyond_band}"
    );
}

/// Two independent inside tests agree on the bunny: the SDF sign (pseudo-normals, voxel grid,
/// BVH) and the ray-parity mesh fill, on every point of a lattice over the bunny's bounding
/// box, except points within 10⁻⁵ of the surface (where rounding decides either way).
#[test]
fn bunny_sdf_sign_agrees_with_ray_parity() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/meshes/bunny.obj");
    let m = TriMesh::load_obj(&path).unwrap();
    let t0 = std::time::Instant::now();
    let sdf = MeshSdf::from_obj(&path, 1.0).unwrap();
    eprintln!(
        "bunny MeshSdf: {} triangles, band {:.4}, built in {:.3} s",
        sdf.triangle_count(),
        sdf.band(),
        t0.elapsed().as_secs_f64()
    );
    let (lo, hi) = m.aabb().unwrap();
    let h = 0.0173; // not commensurate with the mesh's voxel grid
    let lattice = Lattice {
        origin: lo - Vec3::splat(0.05),
        spacing: h,
    };
    let inside: std::collections::HashSet<[u32; 3]> = sample_mesh(&lattice, &m)
        .sample
        .positions
        .iter()
        .map(|p| p.to_array().map(f32::to_bits))
        .collect();
    let n = ((hi - lo + Vec3::splat(0.1)) / h).ceil().as_uvec3();
    let (mut checked, mut skipped) = (0u32, 0u32);
    let t0 = std::time::Instant::now();
    for i in 0..n.x {
        for j in 0..n.y {
            for k in 0..n.z {
                let p = lattice.point(i as i64, j as i64, k as i64);
                let (phi, normal) = sdf.sdf(p);
                assert!(
                    (normal.length() - 1.0).abs() < 1e-4,
                    "normal {normal} at {p}"
                );
                if phi.abs() < 1e-5 {
                    skipped += 1;
                    continue;
                }
                checked += 1;
                let parity = inside.contains(&p.to_array().map(f32::to_bits));
                assert_eq!(phi < 0.0, parity, "at {p}: φ = {phi}, ray parity {parity}");
            }
        }
    }
    let us = t0.elapsed().as_secs_f64() * 1e6 / (checked + skipped) as f64;
    eprintln!(
        "{checked} points agree ({} inside), {skipped} skipped; {us:.2} µs per sdf query",
        inside.len()
    );
    assert!(inside.len() > 10_000 && checked > 100_000);
}

fn config(max: Vec3, dx: f32) -> MpmConfig {
    MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: max,
        dx,
        frame_dt: 0.02,
        ..Default::default()
    }
}

/// The table's centre: its faces lie between grid nodes (x = 0.2043…, y = 0.3037…), so no
/// node sits within rounding of the surface, where the mesh and the analytic box (different
/// f32 operations) could classify it differently.
const TABLE_CENTRE: Vec3 = Vec3::new(0.5043, 0.2037, 0.4969);

/// Drops a liquid cube on a static table (`shape`), returns the centre-of-mass height and the
/// deepest particle penetration (most negative φ of the analytic table).
fn drop_on_table(shape: ColliderShape) -> (f64, f32) {
    let dx = 0.02;
    let h = dx / 2.0;
    let x0 = lattice(Vec3::new(0.4, 0.5, 0.4), Vec3::new(0.6, 0.7, 0.6), h);
    let mat = FluidMaterial::newtonian("honey", 1000.0, 20.0, 5.0);
    let mut app = app_with(config(Vec3::ONE, dx), mat, &x0, h, |_| Vec3::ZERO);
    let he = Vec3::new(0.3, 0.1, 0.3);
    let pose = ColliderPose {
        translation: TABLE_CENTRE,
        rotation: Quat::IDENTITY,
    };
    app.world_mut().spawn((
        Collider {
            shape,
            boundary: BoundaryCondition::Slip,
        },
        pose,
    ));
    for _ in 0..30 {
        app.update();
    }
    assert_healthy(&app);
    let table = ColliderShape::Box { half_extents: he };
    let worst = state(&mut app)
        .iter()
        .map(|s| table.sdf(s.1 - pose.translation).0)
        .fold(f32::INFINITY, f32::min);
    (measure(app.world_mut()).center_of_mass[1], worst)
}

/// Liquid dropped on a static mesh box comes to rest on it like on the analytic box: the two
/// geometries agree to f32 rounding (~10⁻⁷ m ≪ Δx = 0.02 m, previous test), so the runs can
/// differ only through nodes or particles within rounding of the surface; the centre-of-mass
/// heights agree to 1 % of a cell, both stay above the table top (y ≈ 0.304), and no particle
/// ends deeper than the particle push-out tolerance (5 % of a cell).
#[test]
fn liquid_rests_on_a_mesh_box_like_on_the_analytic_box() {
    let he = Vec3::new(0.3, 0.1, 0.3);
    let mesh = ColliderShape::Mesh(Arc::new(MeshSdf::new(&box_mesh(he)).unwrap()));
    let (com_mesh, worst_mesh) = drop_on_table(mesh);
    let (com_box, worst_box) = drop_on_table(ColliderShape::Box { half_extents: he });
    eprintln!(
        "centre of mass y: mesh {com_mesh:.6}, box {com_box:.6}; deepest {worst_mesh} / {worst_box}"
    );
    let dx = 0.02;
    assert!(
        (com_mesh - com_box).abs() < 0.01 * dx,
        "{com_mesh} vs {com_box}"
    );
    assert!(com_mesh > 0.3 && com_box > 0.3);
    assert!(worst_mesh > -0.05 * dx as f32, "{worst_mesh}");
}

/// A scripted mesh box moving down at constant velocity into a resting pool (the "stamp"
/// motion) pushes the liquid like the analytic box: the scripted pose after the run, the same
/// kinetic energy given to the liquid within 1 % and the same centre-of-mass height within 1 %
/// of a cell (the geometries agree to rounding, see above; the side faces lie between grid
/// nodes, the moving bottom face passes node layers at discrete steps ~1.7·10⁻⁴ m apart, so
/// it is within rounding (10⁻⁷ m) of a node layer with probability ~10⁻³), and no particle
/// left inside the moving box.
#[test]
fn moving_mesh_box_pushes_like_the_analytic_box() {
    let dx = 0.02;
    let h = dx / 2.0;
    let he = Vec3::new(0.06, 0.04, 0.06);
    let run = |shape: ColliderShape| {
        let x0 = lattice(Vec3::ZERO, Vec3::new(0.4, 0.12, 0.4), h);
        let mat = FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01);
        let mut app = app_with(config(Vec3::new(0.4, 0.4, 0.4), dx), mat, &x0, h, |_| {
            Vec3::ZERO
        });
        let e = app
            .world_mut()
            .spawn((
                Collider {
                    shape,
                    boundary: BoundaryCondition::Sticky,
                },
                ColliderPose {
                    translation: Vec3::new(0.2031, 0.2, 0.1957),
                    rotation: Quat::IDENTITY,
                },
                ColliderMotion {
                    linear_velocity: Vec3::new(0.0, -0.5, 0.0),
                    angular_velocity: Vec3::ZERO,
                },
            ))
            .id();
        for _ in 0..8 {
            app.update();
        }
        assert_healthy(&app);
        let pose = *app.world().get::<ColliderPose>(e).unwrap();
        let table = ColliderShape::Box { half_extents: he };
        let worst = state(&mut app)
            .iter()
            .map(|s| table.sdf(s.1 - pose.translation).0)
            .fold(f32::INFINITY, f32::min);
        let m = measure(app.world_mut());
        (
            pose.translation,
            m.kinetic_energy,
            m.center_of_mass[1],
            worst,
        )
    };
    let mesh = ColliderShape::Mesh(Arc::new(MeshSdf::new(&box_mesh(he)).unwrap()));
    let (t_mesh, ke_mesh, com_mesh, worst_mesh) = run(mesh);
    let (t_box, ke_box, com_box, worst_box) = run(ColliderShape::Box { half_extents: he });
    eprintln!(
        "box bottom at y = {:.4}; kinetic energy: mesh {ke_mesh:.6e}, box {ke_box:.6e} J; \
         centre of mass y: mesh {com_mesh:.6}, box {com_box:.6}; deepest {worst_mesh} / {worst_box}",
        t_mesh.y - he.y
    );
    // 8 frames of 0.02 s at 0.5 m/s: 0.08 m down, the bottom at 0.2 − 0.04 − 0.08 = 0.08 m,
    // inside the 0.12 m deep pool.
    assert!((t_mesh.y - 0.12).abs() < 1e-4, "{t_mesh}");
    assert!((t_mesh - t_box).length() < 1e-5, "{t_mesh} {t_box}");
    // The moving box set liquid in motion: more than the energy of 80 g of liquid moving at
    // the box speed 0.5 m/s (½·0.08·0.5² = 0.01 J); measured ≈ 0.13 J.
    assert!(ke_box > 0.01, "the box moved no liquid: {ke_box} J");
    assert!(
        (ke_mesh - ke_box).abs() <= 0.01 * ke_box,
        "{ke_mesh} vs {ke_box}"
    );
    assert!((com_mesh - com_box).abs() < 0.01 * dx as f64);
    assert!(worst_mesh > -0.05 * dx, "{worst_mesh}");
}

/// A small scene with `colliders` inserted; the scene "lives" in a scratch directory.
fn scene_with_colliders(colliders: &str) -> String {
    format!(
        r#"Scene(
    domain: (min: (0, 0, 0), max: (1, 1, 1)),
    dx: 0.05,
    duration: 0.1,
    frame_rate: 30,
    materials: [(name: "water", density: 1000, sound_speed: 20)],
    bodies: [
        (material: "water", shape: Box(min: (0.1, 0.1, 0.1), max: (0.9, 0.3, 0.9))),
    ],
    colliders: [
{colliders}
    ],
)
"#
    )
}

fn parse_scene(text: &str) -> Result<treacle::scene::Scene, treacle::scene::SceneError> {
    let dir = std::env::temp_dir().join(format!("treacle-mesh-collider-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    treacle::scene::parse_scene_str(text, std::path::Path::new("stamp.ron"), &dir)
}

/// 1-based line of the first line of `text` containing `needle`.
fn line_of(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).unwrap() + 1
}

/// A scene can express "a bunny-shaped mesh collider moving down at constant velocity": the
/// loader spawns a `ColliderShape::Mesh` of the scaled bunny with its pose and a
/// `ColliderMotion`; two colliders naming the same file and scale share one prepared mesh.
#[test]
fn scene_mesh_collider_moving_down() {
    let text = scene_with_colliders(
        r#"        (
            shape: Mesh(path: "meshes/bunny.obj", scale: 0.3),
            boundary: Sticky,
            translation: (0.5, 0.6, 0.5),
            rotation: Euler(y: 30),
            linear_velocity: (0, -0.5, 0),
        ),
        (shape: Mesh(path: "meshes/bunny.obj", scale: 0.3), boundary: Slip, translation: (0.2, 0.8, 0.2)),
        (shape: Mesh(path: "meshes/cow.obj"), boundary: Slip, translation: (0.8, 0.8, 0.8)),"#,
    );
    let scene = parse_scene(&text).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.colliders.len(), 3);
    let (collider, pose, motion, _, _) = &scene.colliders[0];
    let ColliderShape::Mesh(sdf) = &collider.shape else {
        panic!("not a mesh collider: {:?}", collider.shape)
    };
    assert_eq!(collider.boundary, BoundaryCondition::Sticky);
    assert_eq!(pose.translation, Vec3::new(0.5, 0.6, 0.5));
    assert!(
        (pose.rotation * Vec3::X
            - Vec3::new(30f32.to_radians().cos(), 0.0, -30f32.to_radians().sin()))
        .length()
            < 1e-6
    );
    assert_eq!(motion.unwrap().linear_velocity, Vec3::new(0.0, -0.5, 0.0));
    // Scaled by 0.3 about the OBJ origin: volume × 0.3³.
    let bunny = TriMesh::load_obj(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/meshes/bunny.obj"),
    )
    .unwrap();
    assert!((sdf.volume() / (bunny.volume() * 0.027) - 1.0).abs() < 1e-5);
    // Shared between colliders 0 and 1 (same file and scale): equal by pointer.
    assert_eq!(scene.colliders[1].0.shape, collider.shape);
    assert_ne!(scene.colliders[2].0.shape, collider.shape);
    assert!(scene.colliders[1].2.is_none() && scene.colliders[2].2.is_none());
    // The collider is inside-out correct in the world: its origin region is solid.
    let instance = ColliderInstance {
        shape: collider.shape.clone(),
        boundary: collider.boundary,
        pose: *pose,
        motion: motion.unwrap(),
    };
    let (phi, _, v) = instance.query(pose.translation + Vec3::new(0.0, 0.0, 0.01));
    assert!(phi < 0.0 && v == Vec3::new(0.0, -0.5, 0.0), "{phi} {v}");
}

/// Bad mesh colliders are rejected naming the file, the line and the field: a missing OBJ
/// file (`shape.path`), an open mesh (`shape.path`, with the open-edge count) and a
/// non-positive scale (`shape.scale`); all issues are reported together.
#[test]
fn scene_mesh_collider_errors_name_file_line_and_field() {
    let dir = std::env::temp_dir().join(format!("treacle-mesh-collider-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // One triangle: three open edges.
    std::fs::write(dir.join("open.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let text = scene_with_colliders(
        r#"        (shape: Mesh(path: "meshes/no_such.obj"), boundary: Slip),
        (shape: Mesh(path: "open.obj", scale: 0.1), boundary: Slip),
        (shape: Mesh(path: "meshes/cow.obj", scale: -2), boundary: Slip),
        (shape: Mesh(path: "meshes/cow.obj", scale: 0.1, colour: 3), boundary: Slip),"#,
    );
    // The unknown field is a parse error, reported alone with its line.
    let msg = parse_scene(&text).unwrap_err().to_string();
    assert!(
        msg.contains(&format!("stamp.ron:{}:", line_of(&text, "colour"))) && msg.contains("colour"),
        "{msg}"
    );
    let text = text.replace(", colour: 3", "");
    let msg = parse_scene(&text).unwrap_err().to_string();
    eprintln!("{msg}");
    let lines: Vec<&str> = msg.lines().collect();
    let expect = [
        ("no_such.obj", "colliders[0].shape.path", "not found"),
        ("open.obj", "colliders[1].shape.path", "not closed: 3 edges"),
        ("scale: -2", "colliders[2].shape.scale", "must be > 0"),
    ];
    for (needle, field, what) in expect {
        let line = line_of(&text, needle);
        assert!(
            lines
                .iter()
                .any(|l| l.starts_with(&format!("stamp.ron:{line}:"))
                    && l.contains(&format!("field `{field}`"))
                    && l.contains(what)),
            "no `{field}` error at line {line} mentioning `{what}`:\n{msg}"
        );
    }
    assert!(
        msg.contains("open.obj"),
        "the open mesh's file is named:\n{msg}"
    );
}
