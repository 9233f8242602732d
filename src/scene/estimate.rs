//! What a loaded scene will cost before it runs: grid nodes, particles (including everything
//! the emitters add over the run), bytes, and the number of steps the §7.2 limits predict.
//!
//! `treacle validate` prints it; [`crate::runner::run_scene`] refuses a scene whose memory
//! exceeds the machine's available memory (or a given limit) with this estimate in the
//! message, instead of letting the allocation abort the process.
//!
//! The byte counts are estimates, not bounds: a particle costs its components and its entity
//! ([`BYTES_PER_PARTICLE`]), a grid node its [`GridNode`] plus, with heat or implicit
//! viscosity, that solve's node arrays. The MPM grid is block-sparse (ALGORITHM §11): it
//! stores the blocks the particles reach, estimated at [`SPARSE_NODES_PER_PARTICLE`] nodes per
//! particle (never more than the domain's node box), plus a block table of 4 B per 64 nodes of
//! the node box. The heat solve's lattice is block-sparse too (§11): it allocates the blocks
//! the heated particles' stencils reach, taken as one lattice node per grid node.
use std::fmt;

use crate::grid::{GridLayout, GridNode};
use crate::step::monitor::{StabilityMaxima, TimeStepLimits};
use crate::step::schedule::Gs4Constants;

use super::Scene;

/// Allocated grid nodes per particle assumed by the estimate. A compact body at 8 particles per
/// cell allocates about 0.2 (its cells, one block layer beyond, the 6³ neighbourhoods of its
/// blocks); 1 leaves room for the liquid to spread into sheets and drops five times as thin.
pub const SPARSE_NODES_PER_PARTICLE: f64 = 1.0;

/// Estimated memory of one particle (its components, change ticks and entity, and its share of
/// the step's per-particle buffers) \[B\]. Measured peak memory of the Newtonian bench block:
/// 390 B per particle at 1–2 M particles, grid included (BENCHMARKS.md (r)); a model's state
/// adds its size (the XPP state 224 B with its change ticks), heat about 200 B (temperature
/// components and the thermal transfer's per-particle item). 768 B covers either.
pub const BYTES_PER_PARTICLE: u64 = 768;

/// Estimated memory of the heat solve per grid node (about 25 `f64` node arrays of the C-F
/// solve, its CG and its multigrid levels, which add 1/7) \[B\].
pub const THERMAL_BYTES_PER_NODE: u64 = 240;

/// Estimated memory of the implicit viscous solve per grid node (its velocity, force and
/// prediction arrays and the CG vectors) \[B\].
pub const IMPLICIT_BYTES_PER_NODE: u64 = 240;

/// Particle-steps per second assumed for the run-time figure (this project's measured rate on a
/// 2-core machine, BENCHMARKS.md): a rough guide, not a promise.
pub const ASSUMED_PARTICLE_STEPS_PER_SECOND: f64 = 2.0e6;

/// The cost of a scene, see the module docs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ResourceEstimate {
    /// Grid nodes the step is expected to allocate (see the module docs).
    pub grid_nodes: u64,
    /// Bytes per allocated grid node (the step's node plus the implicit and heat solves'
    /// arrays).
    pub bytes_per_node: u64,
    /// Nodes of the domain's node box (with padding).
    pub box_nodes: u64,
    /// Bytes per node of the node box: the block table (4 B per 64 nodes).
    pub bytes_per_box_node: u64,
    /// Particles the bodies create.
    pub initial_particles: u64,
    /// Particles the emitters add by the end of the run (Q̇ × extruding time / h_p³).
    pub emitted_particles: u64,
    /// Estimated simulation steps: duration over the first step the §7.2 rule allows for the
    /// materials at rest (speeds add an advection limit, so adaptive runs may take more).
    pub steps: f64,
    /// That first step \[s\].
    pub first_dt: f64,
}

impl ResourceEstimate {
    /// Most particles alive at once (bodies plus everything emitted).
    pub fn particles(&self) -> u64 {
        self.initial_particles
            .saturating_add(self.emitted_particles)
    }

    /// Bytes of the grid: the allocated nodes plus what scales with the node box.
    pub fn grid_bytes(&self) -> u64 {
        self.grid_nodes
            .saturating_mul(self.bytes_per_node)
            .saturating_add(self.box_nodes.saturating_mul(self.bytes_per_box_node) / 64)
    }

    /// Bytes of the particles.
    pub fn particle_bytes(&self) -> u64 {
        self.particles().saturating_mul(BYTES_PER_PARTICLE)
    }

    /// Total estimated memory \[B\].
    pub fn bytes(&self) -> u64 {
        self.grid_bytes().saturating_add(self.particle_bytes())
    }

    /// Rough wall time at [`ASSUMED_PARTICLE_STEPS_PER_SECOND`] \[s\].
    pub fn wall_seconds(&self) -> f64 {
        self.steps * self.particles().max(1) as f64 / ASSUMED_PARTICLE_STEPS_PER_SECOND
    }

    /// The error message for a scene that needs more than `available` bytes: names the
    /// fields that drive the estimate.
    pub fn too_large(&self, available: u64, what: &str) -> String {
        format!(
            "the scene needs about {} but {what} is {}: the grid is {} allocated nodes × {} B \
             plus {} B per 64 nodes of its {}-node box = {} (fields `domain` and `dx`), the \
             particles {} × {} B = {} (fields `bodies`, `particles_per_cell`, `dx` and the \
             emitters' `volume_rate`); increase dx, shrink the domain or lower the emitted \
             volume",
            bytes(self.bytes()),
            bytes(available),
            self.grid_nodes,
            self.bytes_per_node,
            self.bytes_per_box_node,
            self.box_nodes,
            bytes(self.grid_bytes()),
            self.particles(),
            BYTES_PER_PARTICLE,
            bytes(self.particle_bytes()),
        )
    }
}

impl fmt::Display for ResourceEstimate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "estimate: {} grid nodes allocated (node box {}), {} particles ({} from bodies, {} \
             from emitters), memory ≈ {}; first Δt {:.3e} s, ≈ {:.3e} steps, ≈ {} at {:.0e} \
             particle-steps/s",
            self.grid_nodes,
            self.box_nodes,
            self.particles(),
            self.initial_particles,
            self.emitted_particles,
            bytes(self.bytes()),
            self.first_dt,
            self.steps,
            duration(self.wall_seconds()),
            ASSUMED_PARTICLE_STEPS_PER_SECOND
        )
    }
}

/// `n` bytes with a binary-prefixed unit.
pub fn bytes(n: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{n} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// Seconds as s, min, h or days.
fn duration(s: f64) -> String {
    if !s.is_finite() {
        "an unbounded time".into()
    } else if s < 120.0 {
        format!("{s:.0} s")
    } else if s < 7200.0 {
        format!("{:.0} min", s / 60.0)
    } else if s < 2.0 * 86400.0 {
        format!("{:.1} h", s / 3600.0)
    } else {
        format!("{:.1} days", s / 86400.0)
    }
}

impl Scene {
    /// The scene's [`ResourceEstimate`].
    pub fn resource_estimate(&self) -> ResourceEstimate {
        let c = &self.config;
        let layout = GridLayout::new(c.domain_min, c.domain_max, c.dx);
        let box_nodes: u64 = (0..3).map(|a| layout.dims[a].max(0) as u64).product();
        let mut bytes_per_node = std::mem::size_of::<GridNode>() as u64;
        if c.integrator.scheme.implicit_viscosity() {
            bytes_per_node += IMPLICIT_BYTES_PER_NODE;
        }
        if self.thermal.is_some() {
            bytes_per_node += THERMAL_BYTES_PER_NODE;
        }
        // Block table: 4 B per block of 64 nodes.
        let bytes_per_box_node = 4;
        let emitted: f64 = self
            .emitters
            .iter()
            .map(|e| {
                let h = e.spacing as f64;
                (e.volume_rate * e.extruding_time(self.duration) / (h * h * h)).ceil()
            })
            .sum();
        let first_dt = self.first_time_step();
        let particles = (self.particle_count() as f64 + emitted).min(u64::MAX as f64);
        let grid_nodes = ((particles * SPARSE_NODES_PER_PARTICLE).ceil() as u64).min(box_nodes);
        ResourceEstimate {
            grid_nodes,
            bytes_per_node,
            box_nodes,
            bytes_per_box_node,
            initial_particles: self.particle_count() as u64,
            emitted_particles: if emitted.is_finite() {
                emitted.min(u64::MAX as f64) as u64
            } else {
                u64::MAX
            },
            steps: self.duration / first_dt,
            first_dt,
        }
    }

    /// The first step of the §7.2 rule ([`TimeStepLimits`]) for the materials at rest: their
    /// sound speed (not with a projected pressure) and explicit viscosity, gravity and
    /// `max_dt`; or the fixed step. NaN if the
    /// integrator's (ρ∞, ρs) are invalid (validation refuses those).
    fn first_time_step(&self) -> f64 {
        let c = &self.config;
        let ig = &c.integrator;
        let Ok(gs4) = Gs4Constants::for_scheme(ig.scheme, ig.rho_inf, ig.rho_s) else {
            return f64::NAN;
        };
        let implicit = ig.scheme.implicit_viscosity();
        // A projected pressure (§5.4) has no sound limit.
        let tait = ig.pressure.projection().is_none();
        let mut maxima = StabilityMaxima::default();
        for m in &self.materials.list {
            if tait {
                maxima.wave_speed_sq = maxima.wave_speed_sq.max(m.sound_speed * m.sound_speed);
            }
            if !implicit {
                maxima.kinematic_viscosity = maxima
                    .kinematic_viscosity
                    .max(m.local_fraction * m.viscosity / m.density);
            }
        }
        TimeStepLimits::new(c, &gs4, &maxima).step(c, &maxima)
    }
}
