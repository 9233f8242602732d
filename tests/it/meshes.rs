//! The shipped CGAL demo meshes (assets/meshes/{bunny,armadillo,cow}.obj, see ORIGIN.md there):
//! each loads, is closed and outward-oriented, matches the numbers recorded in ORIGIN.md, and
//! fills with particles to its own volume within the lattice bound; the parallel mesh fill is
//! identical to the serial one for every thread count.
use std::path::PathBuf;

use glam::Vec3;
use treacle::mesh::TriMesh;
use treacle::sampling::{Lattice, sample_mesh, sample_mesh_with_threads};

const MESHES: [&str; 3] = ["bunny", "armadillo", "cow"];

fn meshes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/meshes")
}

fn load(name: &str) -> TriMesh {
    let path = meshes_dir().join(format!("{name}.obj"));
    TriMesh::load_obj(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// Surface area Σ |(b − a) × (c − a)| / 2 in `f64`.
fn area(m: &TriMesh) -> f64 {
    m.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| m.vertices[i as usize].as_dvec3());
            0.5 * (b - a).cross(c - a).length()
        })
        .sum()
}

/// The row of ORIGIN.md's table for `name`: (vertices, triangles, volume, area).
fn origin_row(name: &str) -> (usize, usize, f64, f64) {
    let text = std::fs::read_to_string(meshes_dir().join("ORIGIN.md")).unwrap();
    let row = text
        .lines()
        .find(|l| l.starts_with(&format!("| `{name}.obj`")))
        .unwrap_or_else(|| panic!("no row for {name} in ORIGIN.md"));
    let cols: Vec<&str> = row.split('|').map(str::trim).collect();
    // | file | original | vertices | triangles | bbox | volume | area | notes |
    (
        cols[3].parse().unwrap(),
        cols[4].parse().unwrap(),
        cols[6].parse().unwrap(),
        cols[7].parse().unwrap(),
    )
}

#[test]
fn shipped_meshes_are_closed_and_match_origin() {
    for name in MESHES {
        let m = load(name);
        assert!(m.is_closed(), "{name}: {} open edges", m.open_edge_count());
        let v = m.signed_volume();
        assert!(v > 0.0, "{name}: signed volume {v} (inward normals)");
        let (nv, nt, vol, a) = origin_row(name);
        assert_eq!(m.vertices.len(), nv, "{name} vertices");
        assert_eq!(m.triangles.len(), nt, "{name} triangles");
        // ORIGIN.md prints 6 significant digits of the f64 values computed from the decimal
        // text; the f32 coordinates read here differ by ≤ 2⁻²⁴ relative per coordinate, so
        // the two agree to well within 1e-5 relative.
        assert!((v / vol - 1.0).abs() < 1e-5, "{name}: volume {v} vs {vol}");
        let area = area(&m);
        assert!((area / a - 1.0).abs() < 1e-5, "{name}: area {area} vs {a}");
        eprintln!(
            "{name}: {nv} vertices, {nt} triangles, volume {v:.6}, area {area:.6}, aabb {:?}",
            m.aabb().unwrap()
        );
    }
}

/// Each mesh filled on a lattice of spacing h = (longest side)/150: a lattice point stands for
/// its cube of side h and is counted iff its centre is inside, so only cubes cut by the
/// surface can be misclassified. Those lie within δ = (√3/2)·h of the surface, a shell of
/// volume ≈ 2δ·A = √3·h·A (A = surface area; curvature corrections are O(δ²) per unit area
/// and negligible at this h). Hence |N·h³ − V| ≤ √3·h·A, here 14 %–28 % of V, so an
/// inverted or lost parity (errors ~100 %) fails.
#[test]
fn shipped_meshes_fill_to_their_volume() {
    for name in MESHES {
        let m = load(name);
        let (lo, hi) = m.aabb().unwrap();
        let h = (hi - lo).max_element() / 150.0;
        let lattice = Lattice {
            origin: lo - Vec3::splat(2.0 * h),
            spacing: h,
        };
        let s = sample_mesh(&lattice, &m);
        let (sampled, exact) = (s.sampled_volume(), s.mesh_volume);
        assert!((exact / m.volume() - 1.0).abs() < 1e-12);
        let bound = 3f64.sqrt() * h as f64 * area(&m);
        let err = (sampled - exact).abs();
        eprintln!(
            "{name}: h = {h:.4e}, {} particles, sampled {sampled:.6e} vs mesh {exact:.6e} \
             (error {:.3} %, bound {:.1} %)",
            s.sample.positions.len(),
            100.0 * err / exact,
            100.0 * bound / exact
        );
        assert!(err <= bound, "{name}: |{sampled} − {exact}| > {bound}");
        // Every particle lies inside the mesh's bounding box.
        assert!(
            s.sample
                .positions
                .iter()
                .all(|p| p.cmpge(lo).all() && p.cmple(hi).all())
        );
    }
}

/// The parallel fill returns exactly the serial particles in the serial order, whatever the
/// thread count (including more threads than columns).
#[test]
fn parallel_mesh_fill_is_identical_to_serial() {
    let m = load("cow");
    let lattice = Lattice {
        origin: Vec3::splat(-0.6),
        spacing: 0.01,
    };
    let serial = sample_mesh_with_threads(&lattice, &m, 1);
    assert!(serial.sample.positions.len() > 1000);
    for threads in [2, 3, 7, 1000] {
        let par = sample_mesh_with_threads(&lattice, &m, threads);
        assert_eq!(par, serial, "{threads} threads differ from the serial fill");
    }
    assert_eq!(sample_mesh(&lattice, &m), serial);
}
