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

/// Reusable buffers for [`measure`].
#[derive(Resource, Default)]
pub struct MetricsScratch {
    mass: Vec<f64>,
    mass_rho: Vec<f64>,
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
    let m = measure_particles(
        &layout,
        &mut scratch,
        q.iter(world)
            .map(|(x, v, m, rho)| (x.0, v.0, m.0, rho.value)),
    );
    world.insert_resource(scratch);
    m
}

/// [`measure`] of particles given as (position, velocity, mass, density), in this order (the
/// sums are serial, so the order fixes the bits).
pub fn measure_particles(
    layout: &GridLayout,
    scratch: &mut MetricsScratch,
    particles: impl Iterator<Item = (Vec3, Vec3, Real, Real)>,
) -> StateMetrics {
    scratch.mass.clear();
    scratch.mass.resize(layout.node_count(), 0.0);
    scratch.mass_rho.clear();
    scratch.mass_rho.resize(layout.node_count(), 0.0);
    let mut m = StateMetrics::default();
    let mut com = [0.0f64; 3];
    for (x, v, mass, rho) in particles {
        let mp = mass as f64;
        m.particles += 1;
        m.mass += mp;
        m.particle_volume += mp / rho as f64;
        let s = v.length() as f64;
        m.kinetic_energy += 0.5 * mp * s * s;
        m.max_speed = m.max_speed.max(s);
        for (c, xk) in com.iter_mut().zip(x.to_array()) {
            *c += mp * xk as f64;
        }
        let st = Stencil::new(layout, x);
        st.for_each(layout, |idx, w, _| {
            scratch.mass[idx] += w as f64 * mp;
            scratch.mass_rho[idx] += w as f64 * mp * rho as f64;
        });
    }
    for (mi, mr) in scratch.mass.iter().zip(&scratch.mass_rho) {
        if *mi > 0.0 {
            // ρᵢ = Σ w m ρ / Σ w m, so mᵢ/ρᵢ = mᵢ² / Σ w m ρ.
            m.volume += mi * mi / mr;
        }
    }
    if m.mass > 0.0 {
        m.center_of_mass = com.map(|c| c / m.mass);
    }
    m
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
