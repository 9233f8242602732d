//! Per-frame metrics: particle count, mass, volume, kinetic energy, max speed.
//!
//! The volume follows \[Su21\] §7.1.2: the particles' mass and mass-weighted density are
//! rasterised to the grid (same quadratic B-splines, at the current positions) and the volume
//! is Σᵢ mᵢ/ρᵢ over active nodes. All sums are serial and in f64, so they are deterministic.
use bevy_ecs::prelude::*;

use crate::components::{Density, Mass, Particle, Position, Velocity};
use crate::grid::{GridLayout, MpmGrid};
use crate::kernels::Stencil;
use crate::math::{Real, Vec3};
use glam::IVec3;

/// Metrics of the current state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StateMetrics {
    /// Number of particles.
    pub particles: u64,
    /// Σ mₚ \[kg\].
    pub mass: f64,
    /// Σᵢ mᵢ/ρᵢ on the grid \[m³\] (\[Su21\] §7.1.2).
    pub volume: f64,
    /// Σ mₚ/ρₚ over particles \[m³\].
    pub particle_volume: f64,
    /// Σ ½ mₚ|vₚ|² \[J\].
    pub kinetic_energy: f64,
    /// max |vₚ| \[m/s\].
    pub max_speed: f64,
    /// Mass-weighted mean position \[m\].
    pub center_of_mass: [f64; 3],
}

/// Reusable buffers for [`measure`]: the nodal sums over the node box the particles' stencils
/// cover (not the whole domain).
#[derive(Resource, Default)]
pub struct MetricsScratch {
    mass: Vec<f64>,
    mass_rho: Vec<f64>,
    layout: Option<GridLayout>,
}

/// Measures the current particle state.
pub fn measure(world: &mut World) -> StateMetrics {
    let layout: GridLayout = match world.get_resource::<MpmGrid>() {
        Some(g) => g.layout,
        None => {
            let c = world.resource::<crate::config::MpmConfig>();
            GridLayout::new(c.domain_min, c.domain_max, c.dx)
        }
    };
    let mut scratch = world
        .remove_resource::<MetricsScratch>()
        .unwrap_or_default();
    let mut q = world.query_filtered::<(&Position, &Velocity, &Mass, &Density), With<Particle>>();
    q.update_archetypes(world);
    let (q, w) = (&q, &*world);
    let m = measure_particles(&layout, &mut scratch, || {
        q.iter_manual(w)
            .map(|(x, v, m, rho)| (x.0, v.0, m.0, rho.value))
    });
    world.insert_resource(scratch);
    m
}

/// [`measure`] of particles given as (position, velocity, mass, density), in this order (the
/// sums are serial, so the order fixes the bits); `particles` is called twice (once for the
/// node box the stencils cover, once for the sums) and must give the same particles both times.
pub fn measure_particles<I: Iterator<Item = (Vec3, Vec3, Real, Real)>>(
    layout: &GridLayout,
    scratch: &mut MetricsScratch,
    particles: impl Fn() -> I,
) -> StateMetrics {
    let mut m = particle_sums(layout, scratch, particles);
    m.volume = scratch.grid_volume();
    m.finish_center_of_mass();
    m
}

/// The sums of [`measure_particles`] over `particles`, with the grid volume left zero, the
/// centre of mass left as Σ mₚxₚ, and the nodal sums Σ w m, Σ w m ρ left in `scratch` (a
/// distributed run adds other ranks' sums to them before [`MetricsScratch::grid_volume`]).
pub fn particle_sums<I: Iterator<Item = (Vec3, Vec3, Real, Real)>>(
    layout: &GridLayout,
    scratch: &mut MetricsScratch,
    particles: impl Fn() -> I,
) -> StateMetrics {
    // The dense sums cover the box of the particles' stencil bases (clamped as in the
    // transfers) plus two nodes: a node's sums and the order of the volume's sum are those of
    // a box over the whole domain, at a fraction of its memory for a liquid in a large domain.
    let (mut first, mut last) = (IVec3::MAX, IVec3::MIN);
    for (x, ..) in particles() {
        let base = Stencil::locate(layout, x).0;
        (first, last) = (first.min(base), last.max(base));
    }
    let boxed = if first.x > last.x {
        layout.node_range(layout.lo, IVec3::ZERO)
    } else {
        layout.node_range(first, last - first + IVec3::splat(3))
    };
    scratch.mass.clear();
    scratch.mass.resize(boxed.node_count(), 0.0);
    scratch.mass_rho.clear();
    scratch.mass_rho.resize(boxed.node_count(), 0.0);
    scratch.layout = Some(boxed);
    let mut m = StateMetrics::default();
    for (x, v, mass, rho) in particles() {
        let mp = mass as f64;
        m.particles += 1;
        m.mass += mp;
        m.particle_volume += mp / rho as f64;
        let s = v.length() as f64;
        m.kinetic_energy += 0.5 * mp * s * s;
        m.max_speed = m.max_speed.max(s);
        for (c, xk) in m.center_of_mass.iter_mut().zip(x.to_array()) {
            *c += mp * xk as f64;
        }
        let st = Stencil::new(&boxed, x);
        st.for_each_weight(&boxed, |idx, w| {
            scratch.mass[idx] += w as f64 * mp;
            scratch.mass_rho[idx] += w as f64 * mp * rho as f64;
        });
    }
    m
}

impl StateMetrics {
    /// Turns the Σ mₚxₚ of [`particle_sums`] into the centre of mass (left zero without mass).
    pub fn finish_center_of_mass(&mut self) {
        let mass = self.mass;
        self.center_of_mass = if mass > 0.0 {
            self.center_of_mass.map(|c| c / mass)
        } else {
            [0.0; 3]
        };
    }
}

impl MetricsScratch {
    /// The nodal sums (Σ w m, Σ w m ρ) of the last [`particle_sums`], by storage index of
    /// [`MetricsScratch::layout`].
    pub fn nodal_sums_mut(&mut self) -> (&mut [f64], &mut [f64]) {
        (&mut self.mass, &mut self.mass_rho)
    }

    /// The node box of the last [`particle_sums`] (its [`GridLayout::index`] and
    /// [`GridLayout::node_of_index`] map the nodal sums to nodes).
    pub fn layout(&self) -> Option<GridLayout> {
        self.layout
    }

    /// Grows the node box of the nodal sums to hold `nodes` too (their sums start at zero);
    /// the sums' values and the order of [`MetricsScratch::grid_volume`] over the nodes stay.
    pub fn widen(&mut self, nodes: impl Iterator<Item = IVec3>) {
        let Some(old) = self.layout else { return };
        let bounds = (old.node_count() > 0).then(|| (old.lo, old.lo + old.dims - IVec3::ONE));
        let (mut first, mut last) = bounds.unwrap_or((IVec3::MAX, IVec3::MIN));
        for n in nodes {
            (first, last) = (first.min(n), last.max(n));
        }
        if first.x > last.x || Some((first, last)) == bounds {
            return;
        }
        let boxed = old.node_range(first, last - first + IVec3::ONE);
        let mut mass = vec![0.0; boxed.node_count()];
        let mut mass_rho = vec![0.0; boxed.node_count()];
        for (idx, (m, mr)) in self.mass.iter().zip(&self.mass_rho).enumerate() {
            let to = boxed.index(old.node_of_index(idx));
            (mass[to], mass_rho[to]) = (*m, *mr);
        }
        (self.mass, self.mass_rho, self.layout) = (mass, mass_rho, Some(boxed));
    }

    /// Σᵢ mᵢ/ρᵢ over the nodes with mass of the nodal sums (\[Su21\] §7.1.2).
    pub fn grid_volume(&self) -> f64 {
        let mut volume = 0.0;
        for (mi, mr) in self.mass.iter().zip(&self.mass_rho) {
            if *mi > 0.0 {
                // ρᵢ = Σ w m ρ / Σ w m, so mᵢ/ρᵢ = mᵢ² / Σ w m ρ.
                volume += mi * mi / mr;
            }
        }
        volume
    }
}

/// One plugin's extra `metrics.csv` columns: their names, asked once when a run starts, and
/// their values, asked after every frame (as many as names).
#[derive(Clone, Copy, Debug)]
pub struct MetricsSource {
    /// Sort key and identity (a second source with the same key is ignored).
    pub key: &'static str,
    /// The column names (may record what the values need, e.g. which bodies, in a resource).
    pub columns: fn(&mut World) -> Vec<String>,
    /// The values of the columns for the current state.
    pub values: fn(&mut World) -> Vec<f64>,
    /// How the values come together in a distributed run, where each rank holds part of the
    /// particles (`None`: the source cannot run on ranks, and a distributed run is refused).
    pub across_ranks: Option<AcrossRanks>,
}

/// A [`MetricsSource`]'s values from the parts of several ranks: each rank computes its
/// `parts` (sums, extrema, counts over its own particles), rank 0 `combine`s every rank's, in
/// rank order, into the values.
#[derive(Clone, Copy, Debug)]
pub struct AcrossRanks {
    /// This rank's parts.
    pub parts: fn(&mut World) -> Vec<f64>,
    /// The values from every rank's parts (rank order).
    pub combine: fn(&[Vec<f64>]) -> Vec<f64>,
}

/// The extra metrics columns plugins contribute (a Resource): the runner writes them after
/// the core columns, in the order of the sources' keys, so that plugin order does not change
/// the file.
#[derive(Resource, Clone, Debug, Default)]
pub struct MetricsColumns {
    sources: Vec<MetricsSource>,
}

impl MetricsColumns {
    /// Adds `source` (ignored if one with the same key is there).
    pub fn add(&mut self, source: MetricsSource) {
        if !self.sources.iter().any(|s| s.key == source.key) {
            self.sources.push(source);
            self.sources.sort_by_key(|s| s.key);
        }
    }

    /// The column names of every source of `world` (none without the resource).
    pub fn columns(world: &mut World) -> Vec<String> {
        let sources = Self::sources_of(world);
        sources.iter().flat_map(|s| (s.columns)(world)).collect()
    }

    /// The values of every source of `world`, in the order of [`MetricsColumns::columns`].
    pub fn values(world: &mut World) -> Vec<f64> {
        let sources = Self::sources_of(world);
        sources.iter().flat_map(|s| (s.values)(world)).collect()
    }

    /// The keys of the sources of `world` that have columns but cannot be combined across
    /// ranks.
    pub fn not_across_ranks(world: &mut World) -> Vec<&'static str> {
        Self::sources_of(world)
            .iter()
            .filter(|s| s.across_ranks.is_none() && !(s.columns)(world).is_empty())
            .map(|s| s.key)
            .collect()
    }

    /// This rank's parts of every source ([`AcrossRanks::parts`]), each preceded by its length.
    pub fn rank_parts(world: &mut World) -> Vec<f64> {
        let mut out = Vec::new();
        for s in Self::sources_of(world) {
            let p = s.across_ranks.map_or_else(Vec::new, |a| (a.parts)(world));
            out.push(p.len() as f64);
            out.extend(p);
        }
        out
    }

    /// The values of every source from every rank's [`MetricsColumns::rank_parts`] (rank
    /// order), in the order of [`MetricsColumns::columns`].
    pub fn combine_ranks(world: &World, ranks: &[Vec<f64>]) -> Vec<f64> {
        let mut at = vec![0usize; ranks.len()];
        let mut out = Vec::new();
        for s in Self::sources_of(world) {
            let parts: Vec<Vec<f64>> = ranks
                .iter()
                .zip(&mut at)
                .map(|(r, k)| {
                    let n = r[*k] as usize;
                    let p = r[*k + 1..*k + 1 + n].to_vec();
                    *k += 1 + n;
                    p
                })
                .collect();
            if let Some(a) = s.across_ranks {
                out.extend((a.combine)(&parts));
            }
        }
        out
    }

    fn sources_of(world: &World) -> Vec<MetricsSource> {
        world
            .get_resource::<Self>()
            .map(|m| m.sources.clone())
            .unwrap_or_default()
    }
}
