use super::*;

/// Cell-centred lattice of spacing `h` filling the cube `[0, n h]³`.
fn cube(n: usize, h: f32) -> Vec<Vec3> {
    let mut out = Vec::with_capacity(n * n * n);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                out.push((Vec3::new(i as f32, j as f32, k as f32) + 0.5) * h);
            }
        }
    }
    out
}

#[test]
fn lattice_cube_is_closed_oriented_and_has_the_filled_volume() {
    let h = 0.01;
    let mesh = reconstruct_surface(&cube(12, h), &SurfaceParams::for_spacing(h)).unwrap();
    assert!(!mesh.triangles.is_empty());
    assert_eq!(mesh.boundary_edges(), 0);
    assert_eq!(mesh.non_manifold_edges(), 0);
    assert_eq!(mesh.misoriented_edges(), 0);
    assert_eq!(mesh.normals.len(), mesh.vertices.len());
    // Faces sit exactly on the filled cube's faces (φ = 1/2 there); edges and corners are
    // rounded by the kernel: a loss of order 12 edges × L × σ² ≈ 12 · 12h · h²/3 · O(1).
    let filled = (12.0 * h as f64).powi(3);
    let rel = mesh.volume() / filled - 1.0;
    assert!(
        rel < 0.0 && rel > -0.04,
        "volume {} vs {filled}: {rel}",
        mesh.volume()
    );
    // Normals point outwards: away from the centre.
    let centre = Vec3::splat(6.0 * h);
    for (v, n) in mesh.vertices.iter().zip(&mesh.normals) {
        assert!((n.length() - 1.0).abs() < 1e-5);
        assert!(n.dot(*v - centre) > 0.0, "normal {n} at {v}");
    }
    // Triangles face the same way as the normals of their vertices.
    let mut against = 0;
    let mut worst = 0.0f32;
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let face = (b - a).cross(c - a);
        let n =
            mesh.normals[t[0] as usize] + mesh.normals[t[1] as usize] + mesh.normals[t[2] as usize];
        if face.dot(n) < 0.0 {
            against += 1;
            worst = worst.max(face.length() / (h * h));
        }
    }
    // Except slivers of area ~0 (two vertices on one node where φ = iso exactly, as on this
    // lattice's faces), whose orientation is f32 rounding of positions ~1e-7 · 0.1 m.
    assert!(
        worst < 1e-5,
        "{against} of {}; largest area/h² {worst}",
        mesh.triangles.len()
    );
}

#[test]
fn domain_flattens_without_opening() {
    let h = 0.01;
    let particles = cube(8, h);
    // A floor through the cube, two spacings above its bottom face.
    let floor = 2.0 * h;
    let params = SurfaceParams::for_spacing(h).with_domain(Vec3::new(-1.0, floor, -1.0), Vec3::ONE);
    let mesh = reconstruct_surface(&particles, &params).unwrap();
    assert_eq!(mesh.boundary_edges(), 0);
    let lowest = mesh
        .vertices
        .iter()
        .map(|v| v.y)
        .fold(f32::INFINITY, f32::min);
    assert_eq!(lowest, floor, "the bottom lies on the floor");
    // The part above the floor: 6/8 of the cube, whose bottom edges are no longer rounded
    // (the free cube loses less than 4 % to rounding, lattice_cube_… above).
    let free = reconstruct_surface(&particles, &SurfaceParams::for_spacing(h)).unwrap();
    let ratio = mesh.volume() / free.volume();
    assert!((0.75..0.75 / 0.96).contains(&ratio), "{ratio}");
}

#[test]
fn wall_layer_extends_liquid_onto_the_wall() {
    let h = 0.01;
    // A cube whose lowest particles are 2.5 h above the floor y = 0, so its faces are at
    // y = 2 h and 10 h: a gap of 2 h under it.
    let particles: Vec<Vec3> = cube(8, h)
        .iter()
        .map(|p| *p + Vec3::new(0.0, 2.0 * h, 0.0))
        .collect();
    let walls = [false, false, true, false, false, false];
    let domain = SurfaceDomain::new(Vec3::splat(-1.0).with_y(0.0), Vec3::ONE);
    let free = reconstruct_surface(&particles, &SurfaceParams::for_spacing(h)).unwrap();
    // A layer thinner than the gap leaves it: only clamping, which changes nothing here.
    let thin = SurfaceParams {
        domain: Some(domain.with_walls(walls, 1.5 * h)),
        ..SurfaceParams::for_spacing(h)
    };
    assert_eq!(reconstruct_surface(&particles, &thin).unwrap(), free);
    // A layer of 3 h: the liquid reaches down to the floor, a mesh still closed.
    let thick = SurfaceParams {
        domain: Some(domain.with_walls(walls, 3.0 * h)),
        ..SurfaceParams::for_spacing(h)
    };
    let mesh = reconstruct_surface(&particles, &thick).unwrap();
    assert_eq!(mesh.boundary_edges(), 0);
    let lowest = mesh
        .vertices
        .iter()
        .map(|v| v.y)
        .fold(f32::INFINITY, f32::min);
    assert_eq!(lowest, 0.0);
    // Added: the 2 h gap under the 8 h × 8 h face, plus what the free cube lost to the
    // rounding of its four bottom edges (a third of its edge loss, which is < 4 % of the
    // cube, ~1.3 % of the slab).
    let added = (mesh.volume() - free.volume()) / (2.0 * 64.0 * (h as f64).powi(3));
    assert!((1.0..=1.03).contains(&added), "{added}");
}

#[test]
fn bad_input_is_an_error() {
    let h = 0.01;
    let p = SurfaceParams::for_spacing(h);
    assert!(matches!(
        reconstruct_surface(&[], &p),
        Err(SurfaceError::NoParticles)
    ));
    let mut pts = cube(3, h);
    pts[5].y = f32::NAN;
    let e = reconstruct_surface(&pts, &p).unwrap_err();
    assert!(
        matches!(e, SurfaceError::NonFinitePosition { index: 5, .. }),
        "{e}"
    );
    for spacing in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        let e = reconstruct_surface(&cube(3, h), &SurfaceParams::for_spacing(spacing)).unwrap_err();
        assert!(
            matches!(
                e,
                SurfaceError::InvalidParameter {
                    name: "spacing",
                    ..
                }
            ),
            "{spacing}: {e}"
        );
        assert!(e.to_string().contains("spacing"));
    }
    for (name, params) in [
        (
            "iso",
            SurfaceParams {
                iso: 1.0,
                ..p.clone()
            },
        ),
        (
            "iso",
            SurfaceParams {
                iso: 0.0,
                ..p.clone()
            },
        ),
        (
            "cell",
            SurfaceParams {
                cell: 0.0,
                ..p.clone()
            },
        ),
        (
            "cell",
            SurfaceParams {
                cell: 0.01,
                ..p.clone()
            },
        ),
        (
            "smoothing",
            SurfaceParams {
                smoothing: -1.0,
                ..p.clone()
            },
        ),
    ] {
        match reconstruct_surface(&cube(3, h), &params) {
            Err(SurfaceError::InvalidParameter { name: n, .. }) => assert_eq!(n, name),
            other => panic!("{name}: {other:?}"),
        }
    }
    let e = reconstruct_surface(&cube(3, h), &p.clone().with_domain(Vec3::ONE, Vec3::ZERO));
    assert!(matches!(e, Err(SurfaceError::InvalidDomain { .. })));
    // Two particles a kilometre apart at a millimetre's resolution.
    let far = [Vec3::ZERO, Vec3::splat(1000.0)];
    let e = reconstruct_surface(&far, &SurfaceParams::for_spacing(0.001)).unwrap_err();
    assert!(matches!(e, SurfaceError::GridTooLarge { .. }), "{e}");
    assert!(e.to_string().contains("cell"), "{e}");
}

#[test]
fn interpolation_reproduces_constant_and_linear_fields() {
    let h = 0.01;
    let pts = cube(10, h);
    let p = SurfaceParams::for_spacing(h);
    let mesh = reconstruct_surface(&pts, &p).unwrap();
    let ones = interpolate_to_vertices(&mesh, &pts, &vec![3.5; pts.len()], &p);
    assert!(ones.iter().all(|&v| (v - 3.5).abs() < 1e-5));
    // A linear field is reproduced up to the kernel-weighted centroid's offset from the
    // vertex, at most the support 2ℓ = 2h near the surface: |Δ| ≤ slope · 2h.
    let lin: Vec<f32> = pts.iter().map(|x| 100.0 * x.x).collect();
    let at = interpolate_to_vertices(&mesh, &pts, &lin, &p);
    for (v, f) in mesh.vertices.iter().zip(&at) {
        let inside = v.x.clamp(0.5 * h, 9.5 * h);
        assert!((f - 100.0 * inside).abs() <= 100.0 * 2.0 * h, "{f} at {v}");
    }
    let e = try_interpolate_to_vertices(&mesh, &pts, &[1.0], &p).unwrap_err();
    assert!(matches!(e, SurfaceError::LengthMismatch { .. }));
    let mut bad = vec![0.0; pts.len()];
    bad[7] = f32::NAN;
    let e = try_interpolate_to_vertices(&mesh, &pts, &bad, &p).unwrap_err();
    assert!(matches!(e, SurfaceError::NonFiniteValue { index: 7, .. }));
}

#[test]
fn spacing_of_a_lattice() {
    let pts = cube(20, 0.004);
    let h = estimate_spacing(&pts).unwrap();
    assert!((h - 0.004).abs() < 1e-6, "{h}");
    assert_eq!(estimate_spacing(&pts[..1]), None);
    assert_eq!(estimate_spacing(&[Vec3::ONE, Vec3::ONE]), None);
}

#[test]
fn files_are_refused_with_nan_and_written_atomically() {
    let dir = std::env::temp_dir().join(format!("treacle-surface-io-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let h = 0.01;
    let mut mesh = reconstruct_surface(&cube(4, h), &SurfaceParams::for_spacing(h)).unwrap();
    let obj = dir.join("a.obj");
    let ply = dir.join("a.ply");
    mesh.write_obj(&obj).unwrap();
    mesh.write_ply(&ply).unwrap();
    let text = std::fs::read_to_string(&obj).unwrap();
    assert_eq!(
        text.lines().filter(|l| l.starts_with("v ")).count(),
        mesh.vertices.len()
    );
    assert_eq!(
        text.lines().filter(|l| l.starts_with("f ")).count(),
        mesh.triangles.len()
    );
    let bytes = std::fs::read(&ply).unwrap();
    let header = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    assert_eq!(
        bytes.len() - header,
        mesh.vertices.len() * 24 + mesh.triangles.len() * 13
    );
    mesh.vertices[3].x = f32::NAN;
    let e = mesh.write_obj(&dir.join("b.obj")).unwrap_err();
    assert!(e.to_string().contains("vertex 3"), "{e}");
    assert!(!dir.join("b.obj").exists());
    let entries = std::fs::read_dir(&dir).unwrap().count();
    assert_eq!(entries, 2, "no temporary file left");
    std::fs::remove_dir_all(&dir).unwrap();
}
