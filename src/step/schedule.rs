//! The step schedule: its label, its ordered system sets (with the sub-sets other plugins hook
//! into) and the resources of the step being run.
//!
//! One frame (one `App::update`) advances the simulation by
//! [`MpmConfig::frame_dt`](crate::config::MpmConfig::frame_dt): the driver system
//! [`advance_frame`](crate::step::driver::advance_frame) runs the [`MpmStep`] schedule N times,
//! each with the step size chosen by the monitor of the previous step (ALGORITHM §2.15), the
//! last one clipped to the frame end. Inside [`MpmStep`], [`StepContext`] holds the current Δt
//! and GS4 constants — systems read it instead of a wall clock, so runs are reproducible.
//!
//! Every plugin that adds systems to the step first calls [`init_step_schedule`] (which
//! creates the schedule with its sets if it is absent) and then puts its systems into the
//! sub-set of the stage it belongs to, so plugins may be added in any order and none orders
//! itself against another module's function.
//!
//! The schedule is single-threaded between systems (the order *is* the algorithm); systems
//! parallelise internally over particles or grid planes with deterministic results.
use bevy_ecs::prelude::*;

use crate::math::Real;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectResource;
use bevy_ecs::schedule::{ScheduleLabel, SingleThreadedExecutor};

use crate::collision::ColliderInstance;
use crate::config::Scheme;
use crate::gs4::Gs4Params;
use crate::kernels::StepCoefficients;
use crate::step::monitor::StabilityMaxima;

/// The schedule of one MPM step.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct MpmStep;

/// The steps of ALGORITHM §2.3 in run order (configured with `.chain()`).
///
/// Stress is computed **after** P2G and scattered by its own pass (`GridForces`), as in \[Su21\];
/// within a step, "current" quantities are the predicted ones at t_{n+W₁} until `GridToParticle`
/// writes t_{n+1}.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MpmSystems {
    /// S1 (§2.4). Reads `Position`, `Velocity`, `Acceleration`; writes `ParticleStencil`;
    /// also gathers colliders at t_{n+1} into [`ActiveColliders`].
    Predict,
    /// S2–S3 (§2.5). Reads `ParticleStencil`, `Mass`, `Velocity`, `Acceleration`;
    /// writes `MpmGrid` mass/velocity/acceleration.
    ParticleToGrid,
    /// S4. Reads `MpmGrid`; writes `VelocityGradient` (and `PredictedDeformationGradient`).
    Kinematics,
    /// S5–S10 (§2.6–2.9). Writes `PredictedDensity`, `CauchyStress`, `StabilityData`; rheology
    /// models add to them in [`ConstitutiveSystems::Models`].
    Constitutive,
    /// S11 force scatter (§2.9). Writes `MpmGrid` force.
    GridForces,
    /// S11 grid update and collisions (§2.10–2.11). Writes `MpmGrid` new velocity/acceleration.
    GridUpdate,
    /// S12 heat solve (§3); empty without the thermal plugin.
    Thermal,
    /// S13–S14 (§2.12–2.13). Writes `Position`, `Velocity`, `Acceleration`,
    /// `DeformationGradient`.
    GridToParticle,
    /// S15 (§2.6, §2.8): commits GS4 pairs and model state; particle collisions.
    Commit,
    /// S16 (§4.4): emitters spawn particles; escaped particles are removed.
    Emit,
    /// Failure detection and the next Δt (§2.15).
    Monitor,
}

/// Sub-sets of [`MpmSystems::Predict`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PredictSystems {
    /// Particle positions x̂ and stencils, the colliders at t_{n+1}.
    Core,
    /// Bodies a plugin moves (rigid-body poses at t_{n+1}).
    Bodies,
    /// Other particle fields (temperatures; the thermal state of new particles).
    Fields,
    /// On several ranks: particles whose stencils moved into another rank's grid columns go
    /// there ([`crate::distributed::migrate_particles`]); empty in one process.
    Migrate,
}

/// Sub-sets of [`MpmSystems::ParticleToGrid`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ParticleToGridSystems {
    /// Mass, momentum and acceleration (§2.5); sets the stencils' weights.
    Momentum,
    /// Other fields scattered with the momentum weights (heat, §3.4).
    Fields,
}

/// Sub-sets of [`MpmSystems::Constitutive`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ConstitutiveSystems {
    /// Density, pressure and the Newtonian local stress (overwrites the stress).
    Base,
    /// Rheology models: add extra stress, raise stability data.
    Models,
    /// Blends of the total stress (the solid/fluid blend of a phase change, §4.1).
    Blend,
}

/// Sub-sets of [`MpmSystems::GridUpdate`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GridUpdateSystems {
    /// The grid update of the scheme and the collisions with walls and colliders (§2.10–2.11).
    Update,
    /// Two-way coupling with bodies a plugin moves (rigid bodies).
    Coupling,
}

/// Sub-sets of [`MpmSystems::GridToParticle`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum GridToParticleSystems {
    /// Deformation gradients, velocities, accelerations and positions (§2.12–2.13).
    Momentum,
    /// Other fields gathered with the same weights (temperatures).
    Fields,
}

/// Sub-sets of [`MpmSystems::Commit`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CommitSystems {
    /// Bodies a plugin moves: their commit and the particles pushed out of them.
    Bodies,
    /// Core commits: density pair, particle collisions, collider motion.
    Core,
    /// Model state commits (they may read ρⁿ⁺¹ and xⁿ⁺¹).
    Models,
    /// Resets after the model commits (the shape-memory reset of melted particles, D12).
    Reset,
}

/// Sub-sets of [`MpmSystems::Emit`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum EmitSystems {
    /// Particles beyond open faces and expired colliders are removed.
    Remove,
    /// Emitters spawn particles (§4.4).
    Spawn,
}

/// Sub-sets of [`MpmSystems::Monitor`], in order.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MonitorSystems {
    /// Failure detection and the next Δt from the particles (§2.15).
    Core,
    /// Plugin limits on the next Δt and plugin energy terms
    /// ([`EnergyTerms`](crate::step::energy::EnergyTerms)).
    Plugins,
    /// The energy check.
    Energy,
    /// On several ranks: a failure on any rank stops all of them
    /// ([`crate::distributed::agree_on_failure`]); empty in one process.
    Agree,
}

/// Δt and GS4 constants of the step being run.
#[derive(Resource, Clone, Copy, Debug)]
pub struct StepContext {
    /// Coefficients (Δt, GS4 weights, FLIP fractions) in the particle precision.
    pub coefficients: StepCoefficients,
    /// Δt of this step in f64 \[s\] (0 during the rate evaluation), for models that integrate
    /// their state in double precision.
    pub dt: f64,
    /// True during the start-up rate evaluation (Δt = 0, §2.14).
    pub rate_evaluation: bool,
    /// Share β ∈ \[0, 1\] of the reset by the nodes of a `Sticky` domain face in this step
    /// ([`crate::config::StickyReset::share`], §2.11, choice D20; 1 in the rate evaluation).
    pub sticky_share: Real,
    /// The interval τ \[s\] over which a transfer keeps its FLIP fraction
    /// ([`crate::config::FlipInterval::seconds`] of `integrator.flip_interval`, §2.12, choice
    /// D19), or `None` for a fraction applied every step. Other transferred fields (the
    /// temperature) take their PIC share per unit time with it.
    pub flip_interval: Option<f64>,
}

impl StepContext {
    /// The FLIP fraction of this step that keeps `flip` over [`Self::flip_interval`]
    /// (`flip` itself without an interval, and in the rate evaluation).
    pub fn flip_per_step(&self, flip: f64) -> f64 {
        if self.rate_evaluation {
            return flip;
        }
        crate::config::flip_over_interval(flip, self.dt, self.flip_interval)
    }
}

impl Default for StepContext {
    fn default() -> Self {
        Self {
            coefficients: coefficients(&Gs4Params::default(), 0.0, 1.0, true),
            dt: 0.0,
            rate_evaluation: false,
            sticky_share: 1.0,
            flip_interval: None,
        }
    }
}

/// Gives `app` the [`MpmStep`] schedule with its sets ordered, if it has none yet; leaves an
/// existing one (and its systems) as it is. Every plugin that adds systems to the step calls
/// it first, so plugins may be added in any order (the shape of Avian's `init_schedule` /
/// `edit_schedule`).
pub fn init_step_schedule(app: &mut bevy_app::App) {
    let has_step = app
        .world()
        .get_resource::<Schedules>()
        .is_some_and(|s| s.contains(MpmStep));
    if !has_step {
        app.add_schedule(new_step_schedule());
    }
}

/// An [`MpmStep`] schedule without systems: single-threaded between systems (the order is the
/// algorithm), with the sets of [`MpmSystems`] chained and every sub-set chained inside its
/// set.
pub fn new_step_schedule() -> Schedule {
    let mut s = Schedule::new(MpmStep);
    s.set_executor(SingleThreadedExecutor::new());
    s.configure_sets(
        (
            MpmSystems::Predict,
            MpmSystems::ParticleToGrid,
            MpmSystems::Kinematics,
            MpmSystems::Constitutive,
            MpmSystems::GridForces,
            MpmSystems::GridUpdate,
            MpmSystems::Thermal,
            MpmSystems::GridToParticle,
            MpmSystems::Commit,
            MpmSystems::Emit,
            MpmSystems::Monitor,
        )
            .chain(),
    );
    s.configure_sets(
        (
            PredictSystems::Core,
            PredictSystems::Bodies,
            PredictSystems::Fields,
            PredictSystems::Migrate,
        )
            .chain()
            .in_set(MpmSystems::Predict),
    );
    s.configure_sets(
        (
            ParticleToGridSystems::Momentum,
            ParticleToGridSystems::Fields,
        )
            .chain()
            .in_set(MpmSystems::ParticleToGrid),
    );
    s.configure_sets(
        (
            ConstitutiveSystems::Base,
            ConstitutiveSystems::Models,
            ConstitutiveSystems::Blend,
        )
            .chain()
            .in_set(MpmSystems::Constitutive),
    );
    s.configure_sets(
        (GridUpdateSystems::Update, GridUpdateSystems::Coupling)
            .chain()
            .in_set(MpmSystems::GridUpdate),
    );
    s.configure_sets(
        (
            GridToParticleSystems::Momentum,
            GridToParticleSystems::Fields,
        )
            .chain()
            .in_set(MpmSystems::GridToParticle),
    );
    s.configure_sets(
        (
            CommitSystems::Bodies,
            CommitSystems::Core,
            CommitSystems::Models,
            CommitSystems::Reset,
        )
            .chain()
            .in_set(MpmSystems::Commit),
    );
    s.configure_sets(
        (EmitSystems::Remove, EmitSystems::Spawn)
            .chain()
            .in_set(MpmSystems::Emit),
    );
    s.configure_sets(
        (
            MonitorSystems::Core,
            MonitorSystems::Plugins,
            MonitorSystems::Energy,
            MonitorSystems::Agree,
        )
            .chain()
            .in_set(MpmSystems::Monitor),
    );
    s
}

/// Builds the per-step coefficients from the GS4 parameters.
pub fn coefficients(p: &Gs4Params, dt: f64, flip: f32, rate_eval: bool) -> StepCoefficients {
    if rate_eval {
        // §2.14: one rate evaluation with Δt = 0 and unit effective mass, so that
        // aᵢ = fᵢ/mᵢ + g, ρ̇ = −ρ tr L, σ̇ = H(σ, L); PIC for the rates, positions unchanged.
        return StepCoefficients {
            dt: 0.0,
            w1l1: 0.0,
            w1l4: 0.0,
            w1l6: 1.0,
            w2l2: 0.0,
            w2l5: 0.0,
            l4: 0.0,
            l5: 0.0,
            flip_velocity: 1.0,
            flip_acceleration: 0.0,
        };
    }
    StepCoefficients {
        dt: dt as f32,
        w1l1: p.w1l1 as f32,
        w1l4: p.w1l4 as f32,
        w1l6: p.w1l6 as f32,
        w2l2: p.w2l2 as f32,
        w2l5: p.w2l5 as f32,
        l4: p.l4 as f32,
        l5: p.l5 as f32,
        flip_velocity: flip,
        flip_acceleration: flip,
    }
}

/// GS4 parameters of the mechanics and the explicit stability constants of the momentum
/// update of the chosen scheme (§1.3, §7.2).
#[derive(Resource, Clone, Copy, Debug)]
pub struct Gs4Constants {
    /// The parameter set (also used by rheology models for their GS4-1 histories, whatever
    /// the scheme).
    pub params: Gs4Params,
    /// Largest stable kΔt of the explicit viscous term: z_crit of explicit GS4-1, or 2 for the
    /// forward-Euler viscosity of [`Scheme::SymplecticEuler`] (and for explicit model
    /// viscosities under [`Scheme::BackwardEulerViscous`]).
    pub z_crit: f64,
    /// Largest stable ωΔt of waves: Ω_crit of explicit GS4-II, or 2 for the symplectic-Euler
    /// pressure update of the first-order schemes.
    pub omega_crit: f64,
    /// The scheme these constants are for.
    pub scheme: Scheme,
}

impl Gs4Constants {
    /// Computes the constants for (ρ∞, ρs) and the explicit GS4 scheme.
    pub fn new(rho_inf: f64, rho_s: f64) -> Result<Self, crate::gs4::Gs4Error> {
        Self::for_scheme(Scheme::Gs4Explicit, rho_inf, rho_s)
    }

    /// Computes the constants for (ρ∞, ρs) and `scheme`.
    pub fn for_scheme(
        scheme: Scheme,
        rho_inf: f64,
        rho_s: f64,
    ) -> Result<Self, crate::gs4::Gs4Error> {
        let params = Gs4Params::new(rho_inf, rho_s)?;
        let (z_crit, omega_crit) = if scheme.is_gs4() {
            (params.z_crit(), params.omega_crit(0.0))
        } else {
            // Forward Euler on ẏ = −ky: |1 − z| ≤ 1; symplectic Euler on an oscillator: Ω ≤ 2.
            (2.0, 2.0)
        };
        Ok(Self {
            params,
            z_crit,
            omega_crit,
            scheme,
        })
    }
}

/// Simulated time and step statistics.
#[derive(Resource, Clone, Debug, Default)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Resource))]
pub struct SimulationClock {
    /// Simulated time t \[s\].
    pub time: f64,
    /// Steps taken so far.
    pub steps: u64,
    /// Frames completed so far.
    pub frame: u64,
    /// Δt of the next step (from the last monitor pass) \[s\].
    pub next_dt: f64,
    /// Predicted stability limit (no safety factor) at the last healthy step \[s\].
    pub predicted_limit: f64,
    /// Smallest and largest Δt used during the last frame \[s\].
    pub frame_dt_min: f64,
    /// See `frame_dt_min`.
    pub frame_dt_max: f64,
    /// Steps taken during the last frame.
    pub frame_steps: u64,
    /// Whether the start-up rate evaluation has run.
    pub started: bool,
    /// Particles removed through open faces so far.
    pub escaped_particles: u64,
    /// Stability maxima at the last monitor pass.
    pub maxima: StabilityMaxima,
    /// The largest speed the set-up itself explains \[m/s\]: the fastest initial particle plus
    /// free fall across the domain, |v₀|max + √(2|g|H). Set by the start-up; the monitor's
    /// Mach blow-up test uses max(c₀, this) (a scene that throws liquid faster than its sound
    /// speed is not blowing up at its first step).
    pub speed_scale: f64,
    /// Whether the last frame was cut short by a [`StopRequest`] (it is not counted in
    /// `frame`; the state is that after the last full step).
    pub interrupted: bool,
}

/// Progress of a run that another thread can read while a frame runs (a progress bar's ticker
/// thread): steps taken and simulated time, stored by the frame driver after every step when
/// this resource is present. Clones share the counters.
#[derive(Resource, Clone, Debug, Default)]
pub struct StepProgress(std::sync::Arc<[std::sync::atomic::AtomicU64; 2]>);

impl StepProgress {
    /// Steps taken so far.
    pub fn steps(&self) -> u64 {
        self.0[0].load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Simulated time \[s\].
    pub fn time(&self) -> f64 {
        f64::from_bits(self.0[1].load(std::sync::atomic::Ordering::Relaxed))
    }

    /// Stores the current steps and time.
    pub fn store(&self, steps: u64, time: f64) {
        self.0[0].store(steps, std::sync::atomic::Ordering::Relaxed);
        self.0[1].store(time.to_bits(), std::sync::atomic::Ordering::Relaxed);
    }
}

/// A request to stop after the current step, settable from another thread or a signal
/// handler. When this resource is present and set, the frame driver ends the frame after the
/// step in progress and marks it [`SimulationClock::interrupted`]. Clones share the flag.
#[derive(Resource, Clone, Debug, Default)]
pub struct StopRequest(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl StopRequest {
    /// Asks the run to stop.
    pub fn request(&self) {
        self.0.store(true, std::sync::atomic::Ordering::SeqCst);
    }

    /// Whether a stop was asked for.
    pub fn requested(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// The shared flag itself (for a signal handler that sets it).
    pub fn flag(&self) -> std::sync::Arc<std::sync::atomic::AtomicBool> {
        self.0.clone()
    }
}

/// Colliders in world frame at t_{n+1}, gathered once per step.
#[derive(Resource, Clone, Debug, Default)]
pub struct ActiveColliders {
    /// The colliders.
    pub list: Vec<ColliderInstance>,
}
