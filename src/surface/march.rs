//! Marching tetrahedra on the Freudenthal subdivision (module docs of [`super`], steps 2–4).
//!
//! Cube corners are numbered by their offset bits: corner `c` is at `(c & 1, c >> 1 & 1,
//! c >> 2 & 1)`. The six tetrahedra of a cube are the monotone paths 0 → e_a → e_a + e_b → 7
//! over the permutations (a, b, c) of the axes; every edge of them joins a corner `u` to a
//! corner `v ⊇ u` (bitwise), i.e. runs from node u along one of the seven directions
//! `v ^ u` ∈ {x, y, xy, z, xz, yz, xyz}. A grid edge holds at most one vertex, numbered by
//! (node, direction) in grid order, so triangles of neighbouring cubes share it.
use super::field::VolumeFraction;
use super::{SurfaceMesh, SurfaceParams};
use crate::math::Vec3;
use crate::parallel;

/// Edge directions from a node, as corner offset bits (x = 1, y = 2, z = 4).
const DIRECTIONS: [u8; 7] = [1, 2, 3, 4, 5, 6, 7];

/// Direction index of the offset bits `d` (1..=7): `DIRECTIONS[d - 1] == d`.
#[inline(always)]
fn direction_index(d: u8) -> usize {
    d as usize - 1
}

/// A triangle as three tetrahedron edges, each a pair of cube corners `(u, v)` with u ⊂ v.
type TriEdges = [(u8, u8); 3];

/// Per tetrahedron (6) and inside-mask of its four vertices (16): the triangles, outward.
struct Tables {
    /// The four cube corners of each tetrahedron, positively oriented.
    tets: [[u8; 4]; 6],
    /// `tris[t][mask]`: up to two triangles.
    tris: [[Vec<TriEdges>; 16]; 6],
}

fn corner(c: u8) -> [i32; 3] {
    [(c & 1) as i32, (c >> 1 & 1) as i32, (c >> 2 & 1) as i32]
}

fn orientation(t: [u8; 4]) -> i32 {
    let p = t.map(corner);
    let d = |k: usize| [0, 1, 2].map(|a| p[k][a] - p[0][a]);
    let (a, b, c) = (d(1), d(2), d(3));
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0])
}

/// The even permutations of (0, 1, 2, 3).
fn even_permutations() -> Vec<[usize; 4]> {
    let mut out = Vec::new();
    for a in 0..4 {
        for b in 0..4 {
            for c in 0..4 {
                for d in 0..4 {
                    let p = [a, b, c, d];
                    let distinct = (0..4).all(|i| (0..i).all(|j| p[i] != p[j]));
                    let inversions = (0..4)
                        .flat_map(|i| (i + 1..4).map(move |j| (i, j)))
                        .filter(|&(i, j)| p[i] > p[j])
                        .count();
                    if distinct && inversions % 2 == 0 {
                        out.push(p);
                    }
                }
            }
        }
    }
    out
}

impl Tables {
    /// Derives the tables. For a positively oriented tetrahedron (a, b, c, d) (an even
    /// permutation of a positive one), the triangle through the edges ab, ac, ad is oriented
    /// with its normal pointing away from a; it is the surface when a alone is inside, and
    /// reversed when a alone is outside. With a and b inside, the quadrilateral ac, ad, bd, bc
    /// (split along ac–bd) faces away from the edge ab.
    fn new() -> Self {
        let axes_perms = [
            [0, 1, 2],
            [0, 2, 1],
            [1, 0, 2],
            [1, 2, 0],
            [2, 0, 1],
            [2, 1, 0],
        ];
        let tets = axes_perms.map(|[a, b, _]| {
            let (ea, eb) = (1u8 << a, 1u8 << b);
            let mut t = [0, ea, ea | eb, 7];
            if orientation(t) < 0 {
                t.swap(2, 3);
            }
            debug_assert_eq!(orientation(t), 1);
            t
        });
        let evens = even_permutations();
        let edge = |t: &[u8; 4], p: usize, q: usize| {
            let (u, v) = (t[p], t[q]);
            if u & v == u { (u, v) } else { (v, u) }
        };
        let tris = std::array::from_fn(|ti| {
            let t = &tets[ti];
            std::array::from_fn(|mask: usize| {
                let inside = |k: usize| mask >> k & 1 == 1;
                match mask.count_ones() {
                    1 | 3 => {
                        let lone_inside = mask.count_ones() == 1;
                        let p = evens
                            .iter()
                            .find(|p| inside(p[0]) == lone_inside)
                            .expect("some even permutation starts with the lone vertex");
                        let (ab, ac, ad) = (
                            edge(t, p[0], p[1]),
                            edge(t, p[0], p[2]),
                            edge(t, p[0], p[3]),
                        );
                        if lone_inside {
                            vec![[ab, ac, ad]]
                        } else {
                            vec![[ab, ad, ac]]
                        }
                    }
                    2 => {
                        let p = evens
                            .iter()
                            .find(|p| inside(p[0]) && inside(p[1]))
                            .expect("some even permutation starts with the inside pair");
                        let ac = edge(t, p[0], p[2]);
                        let ad = edge(t, p[0], p[3]);
                        let bc = edge(t, p[1], p[2]);
                        let bd = edge(t, p[1], p[3]);
                        vec![[ac, ad, bd], [ac, bd, bc]]
                    }
                    _ => Vec::new(),
                }
            })
        });
        Self { tets, tris }
    }
}

/// Grid planes per task of the marching passes.
const PLANES_PER_TASK: usize = 4;

/// The iso-surface φ = iso of `grid` as a closed mesh (vertices clamped into the domain).
pub(super) fn extract(grid: &VolumeFraction, params: &SurfaceParams) -> SurfaceMesh {
    let [nx, ny, nz] = grid.dims;
    let plane = nx * ny;
    let iso = params.iso;
    let phi = &grid.phi;
    let inside = |n: usize| phi[n] > iso;
    let offset =
        |d: u8| (d & 1) as usize + nx * ((d >> 1 & 1) as usize) + plane * ((d >> 2 & 1) as usize);
    let domain = params.domain;

    // Pass 1, per task of PLANES_PER_TASK planes: per node the bit set of its edges (seven
    // directions) that cross the surface and the task-local index of its first vertex; the
    // task's vertices (position, normal) in (node, direction) order. The outermost nodes are
    // outside (padding): edges leaving the grid never cross and are not looked at.
    let mut masks = vec![0u8; nx * ny * nz];
    let mut first = vec![0u32; nx * ny * nz];
    let tasks = nz.div_ceil(PLANES_PER_TASK);
    let planes = |t: usize| t * PLANES_PER_TASK..((t + 1) * PLANES_PER_TASK).min(nz);
    let lens = (0..tasks).map(|t| planes(t).len() * plane);
    let items: Vec<(&mut [u8], &mut [u32])> = parallel::split_lens(&mut masks, lens.clone())
        .zip(parallel::split_lens(&mut first, lens))
        .collect();
    let parts: Vec<(Vec<Vec3>, Vec<Vec3>)> = parallel::map_items(items, |t, (masks, first)| {
        let base = planes(t).start * plane;
        let (mut pos, mut nor) = (Vec::new(), Vec::new());
        for k in planes(t) {
            for j in 0..ny {
                for i in 0..nx {
                    let n = grid.index(i, j, k);
                    first[n - base] = pos.len() as u32;
                    if i + 1 == nx || j + 1 == ny || k + 1 == nz {
                        continue;
                    }
                    let here = inside(n);
                    let mut m = 0u8;
                    for (b, &d) in DIRECTIONS.iter().enumerate() {
                        m |= ((inside(n + offset(d)) != here) as u8) << b;
                    }
                    masks[n - base] = m;
                    if m == 0 {
                        continue;
                    }
                    let node = Vec3::new(i as f32, j as f32, k as f32);
                    let g0 = grid.gradient(i, j, k);
                    for (b, &d) in DIRECTIONS.iter().enumerate() {
                        if m >> b & 1 == 0 {
                            continue;
                        }
                        let c = corner(d);
                        let (a, z) = (phi[n], phi[n + offset(d)]);
                        let s = ((iso - a) / (z - a)).clamp(0.0, 1.0);
                        let step = Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32);
                        let mut p = grid.origin + grid.cell * (node + s * step);
                        if let Some(d) = &domain {
                            p = p.clamp(d.min, d.max);
                        }
                        let g1 =
                            grid.gradient(i + c[0] as usize, j + c[1] as usize, k + c[2] as usize);
                        let g = g0 + s * (g1 - g0);
                        // φ falls outwards; along the edge it falls from the inside end.
                        let fallback = if a > z { step } else { -step };
                        pos.push(p);
                        nor.push((-g).try_normalize().unwrap_or_else(|| fallback.normalize()));
                    }
                }
            }
        }
        (pos, nor)
    });
    let mut starts = Vec::with_capacity(tasks);
    let mut vertices = Vec::new();
    let mut normals = Vec::new();
    for (p, n) in parts {
        starts.push(vertices.len() as u32);
        vertices.extend(p);
        normals.extend(n);
    }

    // Pass 2: triangles, cube by cube in grid order. The seven edges from a node reach the
    // other seven corners of the cube it is the base of: the cube is cut iff its mask ≠ 0.
    let tables = Tables::new();
    let vertex_of = |node: usize, d: u8| -> u32 {
        let b = direction_index(d);
        starts[node / plane / PLANES_PER_TASK]
            + first[node]
            + (masks[node] & ((1u8 << b) - 1)).count_ones()
    };
    let corner_offsets: [usize; 8] = std::array::from_fn(|c| offset(c as u8));
    let parts: Vec<Vec<[u32; 3]>> = parallel::map(tasks, |t| {
        let mut tris = Vec::new();
        for k in planes(t) {
            for j in 0..ny {
                for i in 0..nx {
                    let n = grid.index(i, j, k);
                    if masks[n] == 0 {
                        continue;
                    }
                    let mut cmask = 0u8;
                    for (c, &o) in corner_offsets.iter().enumerate() {
                        cmask |= (inside(n + o) as u8) << c;
                    }
                    for (ti, tet) in tables.tets.iter().enumerate() {
                        let m = tet
                            .iter()
                            .enumerate()
                            .fold(0usize, |m, (q, &c)| m | ((cmask >> c & 1) as usize) << q);
                        for tri in &tables.tris[ti][m] {
                            tris.push(
                                tri.map(|(u, v)| vertex_of(n + corner_offsets[u as usize], v ^ u)),
                            );
                        }
                    }
                }
            }
        }
        tris
    });
    SurfaceMesh {
        vertices,
        normals,
        triangles: parts.concat(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_are_consistent() {
        let t = Tables::new();
        // Six tetrahedra of volume 1/6 fill the unit cube.
        for tet in &t.tets {
            assert_eq!(orientation(*tet), 1);
        }
        assert_eq!(even_permutations().len(), 12);
        for ti in 0..6 {
            for mask in 0..16usize {
                let n = t.tris[ti][mask].len();
                let expected = match mask.count_ones() {
                    0 | 4 => 0,
                    1 | 3 => 1,
                    _ => 2,
                };
                assert_eq!(n, expected, "tet {ti} mask {mask}");
                // Every triangle edge joins an inside corner to an outside corner.
                for tri in &t.tris[ti][mask] {
                    for (u, v) in tri {
                        let q = |c: u8| t.tets[ti].iter().position(|&x| x == c).unwrap();
                        assert_ne!(mask >> q(*u) & 1, mask >> q(*v) & 1);
                        assert_eq!(u & v, *u);
                    }
                }
            }
        }
    }
}
