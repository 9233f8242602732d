//! Surface reconstruction (feature `surface`, issue 16): a lattice sphere against its
//! analytic volume, the droplet scene's meshes read back with `tobj`, determinism across
//! thread counts, and bad input.
use std::path::{Path, PathBuf};

use treacle::math::Vec3;
use treacle::output::read_frame;
use treacle::surface::{SurfaceError, SurfaceParams, reconstruct_surface};

use crate::common::{crate_dir, scratch, treacle};

/// Cell-centred lattice points of spacing `h` inside the sphere of radius `radius` around
/// the origin.
fn lattice_sphere(radius: f32, h: f32) -> Vec<Vec3> {
    let m = (radius / h).ceil() as i32 + 1;
    let mut out = Vec::new();
    for k in -m..m {
        for j in -m..m {
            for i in -m..m {
                let p = (Vec3::new(i as f32, j as f32, k as f32) + 0.5) * h;
                if p.length() < radius {
                    out.push(p);
                }
            }
        }
    }
    out
}

/// A lattice sphere meshes closed, with the volume of the particle-filled sphere N h³ less
/// the smoothing's curvature shrinkage, within the bounds derived below.
///
/// Derivation (ℓ the kernel scale, c the cell, R the radius of the sphere of volume N h³):
/// * φ integrates to N h³ exactly (each particle adds h³ ∫W = h³). The level φ = ½ of an
///   indicator smoothed by a kernel of per-axis variance σ² (σ² = ℓ²/3 for the cubic
///   B-spline, 4 × 1/12) sits at R − σ²/R + O(σ⁴/R³) on a sphere (second-order expansion of
///   the surface across the kernel), so the expected volume is V* = (4/3)π(R − σ²/R)³.
/// * The tensor-product kernel is not isotropic: E[|y_t|² | y_n = 0] varies with the normal
///   direction by at most the σ² of one axis, bounding the error of the shift by half of it,
///   ≤ 3σ²/(2R²) in volume.
/// * Marching tetrahedra: vertices are on the level set up to linear interpolation along an
///   edge of length ≤ √3c; at φ = ½ the profile across the surface has an inflection, so the
///   interpolation error is third order. The triangles are chords of the sphere: sagitta ≤
///   (√3c)²/(8R), a volume deficit ≤ 3 · 3c²/(8R²).
/// * The lattice sphere's staircase, averaged over the kernel: its cells' centres lie inside R,
///   the filled volume N h³ is the reference; the staircase's remaining ripple after smoothing
///   over ≥ 4 spacings of support enters through the same curvature expansion, O(h²/R²),
///   bounded by one further 3h²/(8R²).
#[test]
fn lattice_sphere_is_closed_with_the_filled_volume() {
    let h = 0.01f32;
    for radius_in_h in [10.0f32, 20.0] {
        let positions = lattice_sphere(radius_in_h * h, h);
        let params = SurfaceParams::for_spacing(h);
        let t0 = std::time::Instant::now();
        let mesh = reconstruct_surface(&positions, &params).unwrap();
        let seconds = t0.elapsed().as_secs_f64();
        let n = positions.len() as f64;
        let h = h as f64;
        let filled = n * h.powi(3);
        let r = (3.0 * filled / (4.0 * std::f64::consts::PI)).cbrt();
        let sigma2 = (params.smoothing as f64 * h).powi(2) / 3.0;
        let c = params.cell as f64 * h;
        let expected = 4.0 / 3.0 * std::f64::consts::PI * (r - sigma2 / r).powi(3);
        let tolerance =
            1.5 * sigma2 / (r * r) + 9.0 * c * c / (8.0 * r * r) + 3.0 * h * h / (8.0 * r * r);
        let v = mesh.volume();
        println!(
            "sphere R = {radius_in_h} h: {n} particles, {} vertices, {} triangles, {:.1} ms; \
             volume {v:.6e} m³ = {:.5} × N h³ = {:.5} × V* (tolerance ±{:.5}); \
             boundary edges {}",
            mesh.vertices.len(),
            mesh.triangles.len(),
            seconds * 1e3,
            v / filled,
            v / expected,
            tolerance,
            mesh.boundary_edges()
        );
        assert_eq!(mesh.boundary_edges(), 0);
        assert_eq!(mesh.non_manifold_edges(), 0);
        assert_eq!(mesh.misoriented_edges(), 0);
        assert!(
            (v / expected - 1.0).abs() <= tolerance,
            "volume {v} vs {expected}: {:+.5} beyond ±{tolerance:.5}",
            v / expected - 1.0
        );
        // The mesh is a sphere: every vertex within a cell of radius R − σ²/R.
        let worst = mesh
            .vertices
            .iter()
            .map(|p| (p.as_dvec3().length() - (r - sigma2 / r)).abs())
            .fold(0.0, f64::max);
        assert!(worst < c, "a vertex {worst} m off the sphere");
    }
}

/// Reads an OBJ surface with the `tobj` crate: (positions, triangles).
fn read_obj(path: &Path) -> (Vec<[f64; 3]>, Vec<[usize; 3]>) {
    let (models, _) = tobj::load_obj(
        path,
        &tobj::LoadOptions {
            single_index: false,
            triangulate: false,
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(models.len(), 1, "{}", path.display());
    let mesh = &models[0].mesh;
    assert_eq!(
        mesh.normals.len(),
        mesh.positions.len(),
        "one normal per vertex"
    );
    assert!(mesh.face_arities.is_empty() || mesh.face_arities.iter().all(|&a| a == 3));
    let positions = mesh
        .positions
        .chunks(3)
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect();
    let triangles = mesh
        .indices
        .chunks(3)
        .map(|t| [t[0] as usize, t[1] as usize, t[2] as usize])
        .collect();
    (positions, triangles)
}

/// Edges not shared by exactly two triangles, and how many of them lie on the box faces.
fn open_edges(
    positions: &[[f64; 3]],
    triangles: &[[usize; 3]],
    lo: [f64; 3],
    hi: [f64; 3],
) -> (usize, usize) {
    let mut edges: Vec<(usize, usize)> = triangles
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    edges.sort_unstable();
    let on_face = |p: [f64; 3]| (0..3).any(|a| p[a] == lo[a] || p[a] == hi[a]);
    let (mut open, mut on_boundary) = (0, 0);
    for run in edges.chunk_by(|a, b| a == b) {
        if run.len() != 2 {
            open += 1;
            let (a, b) = run[0];
            if on_face(positions[a]) && on_face(positions[b]) {
                on_boundary += 1;
            }
        }
    }
    (open, on_boundary)
}

fn obj_volume(positions: &[[f64; 3]], triangles: &[[usize; 3]]) -> f64 {
    let o = positions[0];
    let sub = |p: [f64; 3]| [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| sub(positions[i]));
            a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0])
        })
        .sum::<f64>()
        / 6.0
}

fn run_droplet(out: &Path, extra: &[&str]) {
    let scene = crate_dir().join("scenes/droplet.ron");
    let mut args = vec![
        "run",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--frames",
        "12",
        "--force",
    ];
    args.extend_from_slice(extra);
    let o = treacle(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `treacle run droplet --surface`: one OBJ per frame that `tobj` reads back, closed (or open
/// only along the domain's faces), enclosing Σ m/ρ of the frame's particles within 10 %.
#[test]
fn droplet_surfaces_are_closed_with_the_particle_volume() {
    let out = scratch("droplet");
    run_droplet(&out, &["--surface", "--threads", "2"]);
    // droplet.ron: domain [0, 0.3]³, ρ₀ = 1000, h = Δx/2 = 5 mm, output fields Density, ….
    let (lo, hi) = ([0.0; 3], [0.3; 3]);
    let (rho0, h) = (1000.0f64, 0.005f64);
    for frame in [0u32, 6, 12] {
        let obj = out.join(format!("surface_{frame:05}.obj"));
        let (positions, triangles) = read_obj(&obj);
        let (open, on_boundary) = open_edges(&positions, &triangles, lo, hi);
        let particles = read_frame(&out.join(format!("frame_{frame:05}.ply"))).unwrap();
        let density = particles.field("density").expect("droplet writes density");
        // m = ρ₀ h³ per particle (the scene seeds volume h³ at rest density).
        let particle_volume: f64 = density
            .iter()
            .map(|&rho| rho0 * h.powi(3) / rho as f64)
            .sum();
        let v = obj_volume(&positions, &triangles);
        println!(
            "droplet frame {frame} (t = {:.4} s): {} vertices, {} triangles, open edges {open} \
             ({on_boundary} on the domain faces); mesh volume {v:.6e} m³ = {:.4} × Σ m/ρ \
             ({particle_volume:.6e} m³, {} particles)",
            particles.time,
            positions.len(),
            triangles.len(),
            v / particle_volume,
            particles.len()
        );
        assert!(!triangles.is_empty());
        assert_eq!(
            open, on_boundary,
            "frame {frame}: open edges off the domain faces"
        );
        assert!(
            (v / particle_volume - 1.0).abs() <= 0.10,
            "frame {frame}: {v} vs {particle_volume}"
        );
    }
    // One mesh per frame, and nothing else but frames and metrics.
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names.iter().filter(|n| n.starts_with("surface_")).count(),
        13
    );
    assert_eq!(names.len(), 13 + 13 + 1, "{names:?}");
}

fn surface_files(dir: &Path, ext: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| {
            let n = p.file_name().unwrap().to_string_lossy();
            n.starts_with("surface_") && n.ends_with(ext)
        })
        .collect();
    v.sort();
    v
}

/// `treacle surface RUN_DIR` writes a mesh per frame, bit-identical for 1 and 2 threads and
/// identical to what `run --surface` wrote (same spacing); a missing folder is a clear error.
#[test]
fn surface_subcommand_is_deterministic() {
    let out = scratch("subcommand");
    run_droplet(&out, &["--surface", "--surface-format", "ply"]);
    let from_run: Vec<Vec<u8>> = surface_files(&out, ".ply")
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    assert_eq!(from_run.len(), 13);
    let mut per_threads = Vec::new();
    for threads in ["1", "2"] {
        let o = treacle(&[
            "surface",
            out.to_str().unwrap(),
            "--format",
            "ply",
            "--spacing",
            "0.005",
            "--threads",
            threads,
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let files: Vec<Vec<u8>> = surface_files(&out, ".ply")
            .iter()
            .map(|p| std::fs::read(p).unwrap())
            .collect();
        per_threads.push(files);
    }
    assert_eq!(per_threads[0], per_threads[1], "1 vs 2 threads");
    // `run --surface` clips to the domain and extends liquid onto the walls; without a scene
    // the subcommand does neither. Frame 0 (a sphere in mid-air) is unaffected by both.
    assert_eq!(per_threads[0][0], from_run[0]);

    // The spacing estimated from the first frame is the seeding spacing.
    let o = treacle(&["surface", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    let spacing: f64 = text
        .rsplit_once("spacing ")
        .and_then(|(_, s)| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no spacing in {text}"));
    assert!((spacing - 0.005).abs() < 1e-6, "{text}");
    assert_eq!(surface_files(&out, ".obj").len(), 13);

    let missing = out.join("missing");
    let o = treacle(&["surface", missing.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing"));
    for bad in ["--spacing=-1", "--spacing=0"] {
        let o = treacle(&["surface", out.to_str().unwrap(), bad]);
        assert_eq!(o.status.code(), Some(1), "{bad}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains("`spacing`") && !err.contains("panicked"),
            "{err}"
        );
    }
}

/// Bad input is a `SurfaceError` naming the problem, never a panic.
#[test]
fn bad_input_is_a_clear_error() {
    let h = 0.01;
    let good = lattice_sphere(3.0 * h, h);
    let params = SurfaceParams::for_spacing(h);
    let e = reconstruct_surface(&[], &params).unwrap_err();
    assert!(matches!(e, SurfaceError::NoParticles), "{e}");
    println!("empty: {e}");
    let mut nan = good.clone();
    nan[4] = Vec3::new(0.0, f32::NAN, 0.0);
    let e = reconstruct_surface(&nan, &params).unwrap_err();
    assert!(
        matches!(e, SurfaceError::NonFinitePosition { index: 4, .. }),
        "{e}"
    );
    println!("NaN: {e}");
    for spacing in [0.0, -0.01] {
        let e = reconstruct_surface(&good, &SurfaceParams::for_spacing(spacing)).unwrap_err();
        assert!(
            matches!(
                e,
                SurfaceError::InvalidParameter {
                    name: "spacing",
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("spacing"), "{e}");
        println!("spacing {spacing}: {e}");
    }
}
