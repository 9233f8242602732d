//! Energy monitor: stops a run whose mechanical energy grows (ALGORITHM §7; issue 5 "never a
//! silent blow-up").
//!
//! The per-particle checks of [`monitor_step`](super::monitor::monitor_step) catch a blow-up
//! once a particle outruns the grid (2Δx per step) or reaches 10 c₀. A mild instability above
//! the stable step (a viscous or elastic mode growing by a few per cent per step) can pump
//! energy into the whole body for a long time before either happens. Nothing in the
//! continuous problem creates mechanical energy, so we watch it directly:
//!
//! E = Σₚ mₚ(½|vₚ|² − g·xₚ + e(ρₚ)) + Σ_bodies (½M|V|² + ½ωᵀIω − M g·X),
//!
//! with e(ρ) the energy the Tait pressure stores per unit mass (0 with the projected pressure of
//! §5.4, a constraint force)
//! ([`FluidMaterial::internal_energy`](crate::material::FluidMaterial::internal_energy)):
//! liquid compressed after a reference was taken springs back, which without e(ρ) would read
//! as kinetic energy from nowhere. Viscosity, plasticity and the transfers dissipate E,
//! elastic models store part of it (they start unstressed), walls at rest do no work, so
//! E(t) ≤ E(0). The run
//! stops when E(t) − E(0) > [`ENERGY_GROWTH_TOLERANCE`] · S, with S = KE(0) + the largest
//! |gravity work| so far + Σ m |g| Δx (a floor so that a run starting at rest is measured against
//! a meaningful scale). The failure names the fastest particle, its speed and the step.
//!
//! The check is off where the energy balance has an unknown input: a scripted collider that
//! moves (it does work on the liquid), or gravity along a periodic axis (positions wrap). When
//! particles appear or disappear (emitters, open faces) the reference is taken anew, and it is
//! taken anew after every step in which a nozzle extrudes
//! ([`EnergyTerms::unmeasured_input`]): new particles placed into liquid already there push it
//! aside over the following steps, work the monitor cannot measure (a hose a game snaps round
//! by 90° in one frame into the liquid it poured grew E by 0.26 S in zero gravity,
//! `tests/it/game.rs`).
//!
//! The sums run after every step (a frame is written only if all its steps passed) over fixed
//! chunks of each table in parallel, added in chunk order, so the outcome is the same for every
//! thread count; the cost is one pass over five components (a serial pass with `powf` in e(ρ)
//! was 3–6 % of a step).
use bevy_ecs::prelude::*;

use crate::collision::{Collider, ColliderMotion, CoupledCollider};
use crate::components::{Density, Mass, Particle, Position, Velocity};
use crate::config::MpmConfig;
use crate::failure::{FailureReport, SimulationStatus};
use crate::material::{MaterialId, Materials};
use crate::step::schedule::{SimulationClock, StepContext};

/// Allowed growth of the mechanical energy, as a fraction of the energy scale S (module docs).
/// Healthy runs lose energy; the unstable runs of the stability report gain 1–300 S.
pub const ENERGY_GROWTH_TOLERANCE: f64 = 0.25;

/// Mechanical energy of what plugins move besides the particles (dynamic rigid bodies), added
/// to the particles' sums by [`monitor_energy`] and reset by it after every check. A plugin
/// adds its terms in [`MonitorSystems::Plugins`](crate::step::schedule::MonitorSystems::Plugins).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct EnergyTerms {
    /// Kinetic energy \[J\].
    pub kinetic: f64,
    /// Potential energy −m g·x \[J\].
    pub potential: f64,
    /// Mass \[kg\] (for the energy floor).
    pub mass: f64,
    /// Set by a plugin whose work on the liquid in this step is not measured (a nozzle
    /// extruding into the liquid): the monitor takes its reference anew instead of checking.
    pub unmeasured_input: bool,
}

/// Reference state of the energy monitor.
#[derive(Resource, Clone, Debug, Default)]
pub struct EnergyMonitor {
    /// Mechanical energy at the reference \[J\]; `None` before the first check.
    pub reference: Option<f64>,
    /// Kinetic energy at the reference \[J\].
    pub kinetic_reference: f64,
    /// Potential energy at the reference \[J\].
    pub potential_reference: f64,
    /// Largest |potential − potential at the reference| seen since \[J\].
    pub largest_gravity_work: f64,
    /// Σ m |g| Δx at the reference \[J\].
    pub floor: f64,
    /// Particle count at the reference.
    pub particles: usize,
    /// Set once a scripted collider has moved: the check is off for the rest of the run.
    pub disabled: bool,
}

/// Particles per chunk of the energy sums (chunks are summed in parallel, then added in order).
const ENERGY_CHUNK: usize = 8192;

/// Partial sums of the energy check over a run of particles.
#[derive(Clone, Copy, Debug, Default)]
struct EnergySums {
    kinetic: f64,
    potential: f64,
    stored: f64,
    mass: f64,
    /// Largest |v|² and the first particle (entity, position) that has it.
    top_speed: f64,
    fastest: Option<(Entity, crate::math::Vec3)>,
}

impl EnergySums {
    /// Adds the sums of the particles that follow these (the earlier particle wins a tie).
    fn add(&mut self, later: &EnergySums) {
        self.kinetic += later.kinetic;
        self.potential += later.potential;
        self.stored += later.stored;
        self.mass += later.mass;
        if later.top_speed > self.top_speed {
            self.top_speed = later.top_speed;
            self.fastest = later.fastest;
        }
    }
}

/// What the energy check reads of a particle.
type EnergyItem = (
    Entity,
    &'static Mass,
    &'static Position,
    &'static Velocity,
    &'static Density,
    &'static MaterialId,
);

/// The energy check (runs after `monitor_step` in [`MpmSystems::Monitor`](crate::step::schedule::MpmSystems::Monitor)).
#[allow(clippy::too_many_arguments)]
pub fn monitor_energy(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    clock: Res<SimulationClock>,
    mut monitor: ResMut<EnergyMonitor>,
    mut status: ResMut<SimulationStatus>,
    materials: Res<Materials>,
    particles: Query<EnergyItem, With<Particle>>,
    mut terms: ResMut<EnergyTerms>,
    scripted: Query<&ColliderMotion, (With<Collider>, Without<CoupledCollider>)>,
    ranks: Option<Res<crate::distributed::Ranks>>,
) {
    let terms = std::mem::take(&mut *terms);
    if ctx.rate_evaluation || status.failure.is_some() || monitor.disabled {
        return;
    }
    if terms.unmeasured_input {
        monitor.reference = None;
    }
    let g = config.gravity.as_dvec3();
    let periodic = config.walls.periodic_axes();
    if (0..3).any(|a| periodic[a] && g[a] != 0.0)
        || scripted.iter().any(|m| {
            m.linear_velocity != crate::math::Vec3::ZERO
                || m.angular_velocity != crate::math::Vec3::ZERO
        })
    {
        monitor.disabled = true;
        return;
    }
    // A projected pressure (§5.4) stores no energy in the density: it is a constraint force.
    let tait = config.integrator.pressure.projection().is_none();
    let mut count = particles.iter().len();
    let mut sums = EnergySums::default();
    // One table slice at a time, in fixed chunks summed in parallel and added in chunk order:
    // the result depends on the particles only, not on the thread count.
    for (entities, m, x, v, rho, id) in particles
        .contiguous_iter()
        .expect("particle components are table components")
    {
        let chunks = entities.len().div_ceil(ENERGY_CHUNK);
        let mut partial = vec![EnergySums::default(); chunks];
        let sum_chunk = |k: usize, out: &mut EnergySums| {
            let r = k * ENERGY_CHUNK..((k + 1) * ENERGY_CHUNK).min(entities.len());
            for i in r {
                let mi = m[i].0 as f64;
                let vi = v[i].0.as_dvec3();
                let s2 = vi.length_squared();
                out.kinetic += 0.5 * mi * s2;
                out.potential -= mi * g.dot(x[i].0.as_dvec3());
                if let Some(material) = materials.list.get(id[i].0 as usize).filter(|_| tait) {
                    out.stored += mi * material.internal_energy(rho[i].value);
                }
                out.mass += mi;
                if s2 > out.top_speed {
                    out.top_speed = s2;
                    out.fastest = Some((entities[i], x[i].0));
                }
            }
        };
        crate::parallel::for_each_item(chunks > 1, partial.iter_mut().enumerate(), |(k, out)| {
            sum_chunk(k, out)
        });
        for p in &partial {
            sums.add(p);
        }
    }
    let EnergySums {
        mut kinetic,
        mut potential,
        mut stored,
        mut mass,
        mut top_speed,
        fastest,
    } = sums;
    if let Some(ranks) = ranks {
        // The whole body's energy, summed in rank order (the same on every rank).
        let s = ranks.sum(&[kinetic, potential, stored, mass, count as f64]);
        (kinetic, potential, stored, mass) = (s[0], s[1], s[2], s[3]);
        count = s[4] as usize;
        top_speed = ranks.max(&[top_speed])[0];
    }
    // Plugin terms (rigid bodies), in f64: a sum of sums, so for one body the result is the
    // same as adding it after the particles.
    kinetic += terms.kinetic;
    potential += terms.potential;
    mass += terms.mass;
    let energy = kinetic + potential + stored;
    let Some(reference) = monitor.reference.filter(|_| count == monitor.particles) else {
        *monitor = EnergyMonitor {
            reference: Some(energy),
            kinetic_reference: kinetic,
            potential_reference: potential,
            largest_gravity_work: 0.0,
            floor: mass * g.length() * config.dx as f64,
            particles: count,
            disabled: false,
        };
        return;
    };
    monitor.largest_gravity_work = monitor
        .largest_gravity_work
        .max((potential - monitor.potential_reference).abs());
    let scale = monitor.kinetic_reference + monitor.largest_gravity_work + monitor.floor;
    let growth = (energy - reference) / scale;
    if growth > ENERGY_GROWTH_TOLERANCE && growth.is_finite() {
        let dt = ctx.coefficients.dt as f64;
        let mut f = match fastest {
            Some((e, x)) => {
                let mut f = FailureReport::particle(
                    e,
                    "kinetic energy",
                    kinetic,
                    "blow-up: the mechanical energy grew instead of decaying",
                );
                f.position = Some(x);
                f
            }
            None => FailureReport::global(
                "kinetic energy",
                kinetic,
                "blow-up: the mechanical energy grew instead of decaying",
            ),
        };
        f.reason = format!(
            "blow-up: the mechanical energy (kinetic + gravitational + stored by the pressure) grew by {growth:.3} × its scale \
             (initial kinetic energy + largest gravity work + Σm|g|Δx = {scale:.3e} J; tolerance \
             {ENERGY_GROWTH_TOLERANCE}); the fastest particle moves at {:.3e} m/s",
            top_speed.sqrt()
        );
        f.step = clock.steps;
        f.time = clock.time;
        f.dt = dt;
        f.suggested_dt = 0.5 * dt;
        status.failure = Some(f);
    }
}
