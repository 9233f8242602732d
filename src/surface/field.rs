//! The volume-fraction field φ on a regular grid (module docs of [`super`], step 1).
use super::{SurfaceError, SurfaceParams};
use crate::math::Vec3;
use crate::parallel::{self, SharedMut};

/// Most nodes a particle touches along one axis (validation keeps 4ℓ/c ≤ 28).
const MAX_STENCIL: usize = 32;

/// Fewest grid planes in a slab of the two-phase fill.
const MIN_SLAB_PLANES: usize = 4;

/// φ sampled at the nodes `origin + cell·(i, j, k)`, `i` fastest.
pub(super) struct VolumeFraction {
    /// Position of node (0, 0, 0) \[m\].
    pub origin: Vec3,
    /// Node spacing \[m\].
    pub cell: f32,
    /// Nodes per axis.
    pub dims: [usize; 3],
    /// φ per node.
    pub phi: Vec<f32>,
}

/// The cubic B-spline N₃ (support (−2, 2), partition of unity on the integers).
#[inline(always)]
pub(super) fn cubic_bspline(x: f32) -> f32 {
    let a = x.abs();
    if a < 1.0 {
        2.0 / 3.0 - a * a + 0.5 * a * a * a
    } else if a < 2.0 {
        let t = 2.0 - a;
        t * t * t / 6.0
    } else {
        0.0
    }
}

/// The nodes a particle at node coordinate `u` reaches with kernel half-width `s` (in nodes)
/// on an axis of `n` nodes: the first node and the weights N₃((i − u)/`scale`) of the
/// following ones (`len` ≤ ⌊2s⌋ + 1 of them, never past the last node).
#[inline(always)]
fn axis_weights(
    u: f32,
    s: f32,
    inv_scale: f32,
    n: usize,
    w: &mut [f32; MAX_STENCIL],
) -> (usize, usize) {
    let first = ((u - s).floor() + 1.0).max(0.0);
    let last = (u + s).ceil() - 1.0;
    let start = (first as usize).min(n);
    let len = ((last - first) as isize + 1).clamp(0, MAX_STENCIL as isize) as usize;
    let len = len.min(n - start);
    for (o, w) in w.iter_mut().enumerate().take(len) {
        *w = cubic_bspline((first + o as f32 - u) * inv_scale);
    }
    (start, len)
}

impl VolumeFraction {
    /// Node count per axis and origin for `positions` (finite, non-empty), or the size error.
    fn layout(
        positions: &[Vec3],
        params: &SurfaceParams,
    ) -> Result<(Vec3, [usize; 3]), SurfaceError> {
        let (lo, hi) = positions
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        let cell = params.cell_size();
        // One cell beyond the support: the outermost nodes have φ = 0 (outside); one cell
        // beyond the wall layer: the grid reaches a wall that particles are within the layer of.
        let layer = params.domain.map_or(0.0, |d| d.wall_layer);
        let pad = params.support().max(layer) + cell;
        let origin = lo - pad;
        let extent = (hi - lo).as_dvec3() + 2.0 * pad as f64;
        let dims_f = (extent / cell as f64).ceil() + 1.0;
        let nodes = dims_f.x * dims_f.y * dims_f.z;
        if nodes.is_nan() || nodes > params.max_nodes as f64 {
            return Err(SurfaceError::GridTooLarge {
                nodes: if nodes.is_finite() {
                    nodes as u64
                } else {
                    u64::MAX
                },
                dims: dims_f.to_array().map(|d| d.min(u64::MAX as f64) as u64),
                max: params.max_nodes,
                extent: (hi - lo).to_array(),
            });
        }
        Ok((origin, dims_f.to_array().map(|d| d as usize)))
    }

    /// Fills φ from `positions` (finite, non-empty; `params` valid).
    pub fn build(positions: &[Vec3], params: &SurfaceParams) -> Result<Self, SurfaceError> {
        let (origin, dims) = Self::layout(positions, params)?;
        let cell = params.cell_size();
        let [nx, ny, nz] = dims;
        let mut phi = vec![0.0f32; nx * ny * nz];
        // Kernel scale and half-width in nodes; φ = (h/ℓ)³ Σ Π N₃(rₖ/ℓ).
        let scale = params.kernel_scale() / cell;
        let inv_scale = 1.0 / scale;
        let half = 2.0 * scale;
        let norm = params.smoothing.powi(-3);
        let inv_cell = 1.0 / cell;
        let node_coord = |p: Vec3| (p - origin) * inv_cell;

        // Slabs of `planes` z-planes: a particle whose first plane is in slab s writes only
        // planes of slabs s and s + 1 (it reaches fewer than `planes` planes).
        let planes = ((2.0 * half).ceil() as usize + 1).max(MIN_SLAB_PLANES);
        let slabs = nz.div_ceil(planes);
        let slab_of = |p: &Vec3| {
            let first = (node_coord(*p).z - half).floor() + 1.0;
            (first.max(0.0) as usize / planes).min(slabs - 1)
        };
        // Counting sort by slab, particle order kept within a slab: deterministic.
        let mut offsets = vec![0u32; slabs + 1];
        for p in positions {
            offsets[slab_of(p) + 1] += 1;
        }
        for s in 0..slabs {
            offsets[s + 1] += offsets[s];
        }
        let mut fill = offsets.clone();
        let mut order = vec![0u32; positions.len()];
        for (i, p) in positions.iter().enumerate() {
            let s = slab_of(p);
            order[fill[s] as usize] = i as u32;
            fill[s] += 1;
        }

        let out = SharedMut(phi.as_mut_ptr());
        let splat = |slab: usize| {
            let (mut wx, mut wy, mut wz) =
                ([0.0; MAX_STENCIL], [0.0; MAX_STENCIL], [0.0; MAX_STENCIL]);
            for &i in &order[offsets[slab] as usize..offsets[slab + 1] as usize] {
                let u = node_coord(positions[i as usize]);
                let (i0, lx) = axis_weights(u.x, half, inv_scale, nx, &mut wx);
                let (j0, ly) = axis_weights(u.y, half, inv_scale, ny, &mut wy);
                let (k0, lz) = axis_weights(u.z, half, inv_scale, nz, &mut wz);
                for (dk, &wk) in wz[..lz].iter().enumerate() {
                    let wk = wk * norm;
                    for (dj, &wj) in wy[..ly].iter().enumerate() {
                        let wkj = wk * wj;
                        let row = i0 + nx * (j0 + dj + ny * (k0 + dk));
                        // SAFETY: `axis_weights` keeps every stencil node inside the grid
                        // (i0 + lx ≤ nx, j0 + dj < ny, k0 + dk < nz, so row + lx ≤ nx·ny·nz).
                        // This slab's particles start in planes [slab·planes, (slab+1)·planes)
                        // and reach fewer than `planes` planes, so it writes only planes of
                        // slabs `slab` and `slab + 1`; the tasks running at the same time have
                        // slab indices of one parity, so no two of them write the same node.
                        let row = unsafe { std::slice::from_raw_parts_mut(out.get().add(row), lx) };
                        for (r, &wi) in row.iter_mut().zip(&wx[..lx]) {
                            *r += wkj * wi;
                        }
                    }
                }
            }
        };
        for phase in 0..2 {
            let mine: Vec<usize> = (phase..slabs).step_by(2).collect();
            parallel::map(mine.len(), |t| splat(mine[t]));
        }
        let mut field = Self {
            origin,
            cell,
            dims,
            phi,
        };
        if let Some(d) = &params.domain
            && d.wall_layer > 0.0
        {
            for face in 0..6 {
                if d.walls[face] {
                    field.extend_to_wall(face / 2, face % 2 == 1, d);
                }
            }
        }
        Ok(field)
    }

    /// Raises φ between the face (`axis`, `upper`) of `domain` and the plane `wall_layer`
    /// inside it to φ on that plane (linear between node planes), at every node strictly
    /// inside the grid (the outermost planes stay outside, so the mesh stays closed). Nothing
    /// happens unless the grid reaches the face, i.e. unless some particle is within the
    /// layer of it (the padding is at least the layer plus a cell).
    fn extend_to_wall(&mut self, axis: usize, upper: bool, domain: &super::SurfaceDomain) {
        let n = self.dims[axis];
        let coord = |x: f32| (x - self.origin[axis]) / self.cell;
        let (face, layer) = if upper {
            (
                coord(domain.max[axis]),
                coord(domain.max[axis] - domain.wall_layer),
            )
        } else {
            (
                coord(domain.min[axis]),
                coord(domain.min[axis] + domain.wall_layer),
            )
        };
        let reaches = if upper {
            face <= (n - 2) as f32
        } else {
            face >= 1.0
        };
        if !(reaches && layer >= 0.0 && layer <= (n - 1) as f32) {
            return;
        }
        let i0 = (layer.floor() as usize).min(n - 2);
        let frac = layer - i0 as f32;
        // Node planes between the layer plane and the grid's edge, on the wall's side.
        let planes: Vec<usize> = if upper {
            (i0 + 1..n - 1).collect()
        } else {
            (1..=i0).collect()
        };
        let stride = [1, self.dims[0], self.dims[0] * self.dims[1]];
        let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
        for p in 0..self.dims[a1] {
            for q in 0..self.dims[a2] {
                let base = p * stride[a1] + q * stride[a2];
                let at = |i: usize| base + i * stride[axis];
                let on_layer = self.phi[at(i0)] + frac * (self.phi[at(i0 + 1)] - self.phi[at(i0)]);
                for &i in &planes {
                    let v = &mut self.phi[at(i)];
                    *v = v.max(on_layer);
                }
            }
        }
    }

    /// Linear index of node (i, j, k).
    #[inline(always)]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// ∇φ at node (i, j, k) by central differences (one-sided on the grid's faces).
    pub fn gradient(&self, i: usize, j: usize, k: usize) -> Vec3 {
        let c = [i, j, k];
        let stride = [1, self.dims[0], self.dims[0] * self.dims[1]];
        let n = self.index(i, j, k);
        let mut g = [0.0f32; 3];
        for a in 0..3 {
            let (lo, lo_w) = if c[a] > 0 {
                (n - stride[a], 1.0)
            } else {
                (n, 0.0)
            };
            let (hi, hi_w) = if c[a] + 1 < self.dims[a] {
                (n + stride[a], 1.0)
            } else {
                (n, 0.0)
            };
            let span = (lo_w + hi_w) * self.cell;
            g[a] = (self.phi[hi] - self.phi[lo]) / span;
        }
        Vec3::from_array(g)
    }
}
