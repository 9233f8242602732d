//! Particles binned on a coarse grid: nearest-neighbour spacing and vertex interpolation.
use super::SurfaceParams;
use super::field::cubic_bspline;
use crate::math::Vec3;
use crate::parallel;

/// Particles sorted into cubic bins of side `size` over their bounding box.
struct Bins {
    lo: Vec3,
    size: f32,
    dims: [usize; 3],
    /// `order[starts[b]..starts[b + 1]]`: particle indices in bin b, ascending.
    starts: Vec<u32>,
    order: Vec<u32>,
}

impl Bins {
    /// Bins of side `size` (> 0) around finite, non-empty `positions`; the side grows if the
    /// box would need more than 2²⁴ bins.
    fn new(positions: &[Vec3], size: f32) -> Self {
        let (lo, hi) = positions
            .iter()
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(*p), hi.max(*p))
            });
        let extent = (hi - lo).as_dvec3();
        let mut size = size as f64;
        let count = |s: f64| (extent / s).floor() + 1.0;
        while count(size).element_product() > (1u64 << 24) as f64 {
            size *= 2.0;
        }
        let dims = count(size).to_array().map(|d| d as usize);
        let size = size as f32;
        let mut bins = Self {
            lo,
            size,
            dims,
            starts: vec![0; dims[0] * dims[1] * dims[2] + 1],
            order: vec![0; positions.len()],
        };
        for p in positions {
            let b = bins.bin(bins.cell(*p));
            bins.starts[b + 1] += 1;
        }
        for b in 1..bins.starts.len() {
            bins.starts[b] += bins.starts[b - 1];
        }
        let mut fill = bins.starts.clone();
        for (i, p) in positions.iter().enumerate() {
            let b = bins.bin(bins.cell(*p));
            bins.order[fill[b] as usize] = i as u32;
            fill[b] += 1;
        }
        bins
    }

    /// Bin coordinates of `p`, clamped into the box.
    fn cell(&self, p: Vec3) -> [usize; 3] {
        let c = ((p - self.lo) / self.size).floor().to_array();
        std::array::from_fn(|a| (c[a].max(0.0) as usize).min(self.dims[a] - 1))
    }

    fn bin(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    /// Calls `f(particle)` for the particles in the bins within `ring` bins of `c`.
    fn around(&self, c: [usize; 3], ring: usize, mut f: impl FnMut(u32)) {
        let range = |a: usize| c[a].saturating_sub(ring)..=(c[a] + ring).min(self.dims[a] - 1);
        for k in range(2) {
            for j in range(1) {
                for i in range(0) {
                    let b = self.bin([i, j, k]);
                    for &p in &self.order[self.starts[b] as usize..self.starts[b + 1] as usize] {
                        f(p);
                    }
                }
            }
        }
    }
}

/// The median distance from a particle to its nearest neighbour \[m\], over up to 2048
/// particles evenly spread through the list (deterministic); `None` for fewer than two
/// particles, non-finite positions, or particles that all coincide. For particles seeded on a
/// lattice and moved little this is the seeding spacing h ([`SurfaceParams::spacing`]).
pub fn estimate_spacing(positions: &[Vec3]) -> Option<f32> {
    const SAMPLES: usize = 2048;
    const MAX_RING: usize = 4;
    let n = positions.len();
    if n < 2 || positions.iter().any(|p| !p.is_finite()) {
        return None;
    }
    let (lo, hi) = positions
        .iter()
        .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
    let extent = (hi - lo).max_element();
    if extent.is_nan() || extent <= 0.0 {
        return None;
    }
    // About one particle per bin for a compact body.
    let bins = Bins::new(positions, (extent / (n as f32).cbrt()).max(extent * 1e-6));
    let mut nearest: Vec<f32> = Vec::with_capacity(SAMPLES.min(n));
    for i in (0..n).step_by((n / SAMPLES).max(1)) {
        let p = positions[i];
        let c = bins.cell(p);
        let mut best = f32::INFINITY;
        for ring in 1..=MAX_RING {
            bins.around(c, ring, |j| {
                let d = positions[j as usize].distance(p);
                if j as usize != i && d > 0.0 && d < best {
                    best = d;
                }
            });
            // Every particle closer than `ring` bins has been seen.
            if best <= ring as f32 * bins.size {
                break;
            }
        }
        if best.is_finite() {
            nearest.push(best);
        }
    }
    if nearest.is_empty() {
        return None;
    }
    nearest.sort_by(f32::total_cmp);
    Some(nearest[nearest.len() / 2])
}

/// Vertices per task of the interpolation.
const VERTICES_PER_TASK: usize = 16384;

/// Shepard interpolation of `values` at `vertices` (inputs checked by the caller).
pub(super) fn interpolate(
    vertices: &[Vec3],
    positions: &[Vec3],
    values: &[f32],
    params: &SurfaceParams,
) -> Vec<f32> {
    let support = params.support();
    let inv_scale = 1.0 / params.kernel_scale();
    let bins = Bins::new(positions, support);
    let chunks = parallel::ranges(vertices.len(), vertices.len().div_ceil(VERTICES_PER_TASK));
    parallel::map(chunks.len(), |t| {
        chunks[t]
            .clone()
            .map(|v| {
                let x = vertices[v];
                let (mut sum, mut weight) = (0.0f64, 0.0f64);
                // Bins are at least one support wide: ring 1 holds every particle in reach.
                bins.around(bins.cell(x), 1, |p| {
                    let w = ((positions[p as usize] - x) * inv_scale)
                        .to_array()
                        .map(cubic_bspline);
                    let w = (w[0] * w[1] * w[2]) as f64;
                    sum += w * values[p as usize] as f64;
                    weight += w;
                });
                if weight > 0.0 {
                    return (sum / weight) as f32;
                }
                let (mut nearest, mut best) = (None, 2.0 * support);
                bins.around(bins.cell(x), 2, |p| {
                    let d = positions[p as usize].distance(x);
                    if d < best {
                        (nearest, best) = (Some(p), d);
                    }
                });
                nearest.map_or(0.0, |p| values[p as usize])
            })
            .collect::<Vec<f32>>()
    })
    .concat()
}
