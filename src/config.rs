//! Simulation configuration resources.
//!
//! Every field states its unit, its default and how it affects stability. The scene loader
//! ([`crate::scene`]) fills these resources, but a Bevy app can insert and change them directly.
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectResource;
use serde::{Deserialize, Serialize};

use crate::math::{Real, Vec3};

/// Global MPM configuration: the domain, the grid, gravity and the integrator.
///
/// Changing `dx` or the domain at run time is not supported (the grid is sized once);
/// everything else may be changed between frames.
#[derive(Resource, Clone, Debug, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Resource))]
pub struct MpmConfig {
    /// Lower corner of the simulation domain \[m\]. Default `(0, 0, 0)`.
    pub domain_min: Vec3,
    /// Upper corner of the simulation domain \[m\]. Default `(1, 1, 1)`.
    /// The domain walls ([`DomainWalls`]) sit on the faces of this box.
    pub domain_max: Vec3,
    /// Grid spacing Δx \[m\]. Default `0.02`. The explicit time step shrinks with Δx
    /// (linearly for sound and advection, quadratically for viscosity; ALGORITHM §7.2).
    pub dx: Real,
    /// Gravity \[m/s²\]. Default `(0, -9.81, 0)`.
    pub gravity: Vec3,
    /// The time integrator settings.
    pub integrator: IntegratorConfig,
    /// How the time step is chosen.
    pub time_step: TimeStepConfig,
    /// Simulated time between two frames (one `App::update`) \[s\]. Default `1/60`.
    pub frame_dt: f64,
    /// The six domain walls.
    pub walls: DomainWalls,
}

impl Default for MpmConfig {
    fn default() -> Self {
        Self {
            domain_min: Vec3::ZERO,
            domain_max: Vec3::ONE,
            dx: 0.02,
            gravity: Vec3::new(0.0, -9.81, 0.0),
            integrator: IntegratorConfig::default(),
            time_step: TimeStepConfig::default(),
            frame_dt: 1.0 / 60.0,
            walls: DomainWalls::default(),
        }
    }
}

/// Settings of the time integrator (ALGORITHM §1, §2, §5.2).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub struct IntegratorConfig {
    /// The time-integration scheme. Default [`Scheme::Gs4Explicit`].
    pub scheme: Scheme,
    /// GS4 spectral radius at infinity ρ∞ ∈ \[0, 1\]. Default `0.5`.
    /// Smaller values damp high frequencies more; (ρ∞, ρs) = (1, 1) is unstable explicitly.
    pub rho_inf: f64,
    /// GS4 spurious-root parameter ρs ∈ \[0, ρ∞\]. Default `0` (ALGORITHM §1.3 recommends 0
    /// for every explicit field; larger values shrink the stable time step).
    pub rho_s: f64,
    /// FLIP fraction α_F ∈ \[0, 1\] of the particle update, kept over one
    /// [`flip_interval`](Self::flip_interval) (ALGORITHM §2.12). Default `0.95`.
    /// `0` is pure PIC (dissipative, very stable), `1` pure FLIP (noisy, no transfer damping).
    pub flip: Real,
    /// The interval over which the particles keep the FLIP fraction `flip` (ALGORITHM §2.12).
    /// Default [`FlipInterval::SoundCrossing`]`(0.35)`: the PIC smoothing acts per unit time, so
    /// it does not grow as Δt shrinks. [`FlipInterval::Step`] applies `flip` every step.
    pub flip_interval: FlipInterval,
    /// How often the nodes of a `Sticky` domain face reset the particles next to them through
    /// their FLIP increment (ALGORITHM §2.11, choice D20). Default [`StickyReset::EveryStep`].
    pub sticky_reset: StickyReset,
    /// FLIP form of the GS4 particle update (ALGORITHM §2.12). Default
    /// [`FlipUpdate::ParticleGs4`]. Only the GS4 schemes use it.
    pub flip_update: FlipUpdate,
    /// How the GS4 schemes move particles that carry a deformation gradient F (solids: the
    /// solid phase of phase change, neo-Hookean and elasto-plastic models; ALGORITHM §2.13).
    /// Default [`SolidMotion::ParticleVelocity`].
    pub solid_motion: SolidMotion,
    /// Density integration (ALGORITHM §2.6, choice D2). Default GS4 continuity.
    pub density: DensityUpdate,
    /// Evaluate consistent initial rates (a⁰, ρ̇⁰, ...) before the first step (§2.14).
    /// Default `true`. With `false` the stored rates are used as given (a⁰ = g for new particles).
    pub consistent_startup: bool,
    /// Conjugate-gradient settings of the implicit viscous solve (schemes
    /// [`Scheme::BackwardEulerViscous`] and [`Scheme::Gs4SemiImplicit`]; ignored otherwise).
    /// Default: relative residual 1e-8, at most 500 iterations. A solve that does not converge
    /// stops the run with a diagnostic.
    pub viscous_solver: crate::krylov::CgParams,
    /// How the pressure is found: the weakly compressible Tait equation of state (default, the
    /// paper's) or a projection on the grid that keeps the liquid's volume without a sound-speed
    /// limit on Δt ([`PressureSolve::Projection`], [`crate::step::implicit::pressure`]).
    pub pressure: PressureSolve,
    /// Where the first-order schemes take the particles' velocity gradient Lₚ for the stress:
    /// gathered from the transferred grid velocities every step (default, ALGORITHM §2.3 S4), or
    /// carried over from the last G2P ([`VelocityGradientSource::Carried`]: one gather fewer
    /// per step, the practice of APIC/MLS-MPM codes).
    pub velocity_gradient: VelocityGradientSource,
}

/// Where a first-order step takes the velocity gradient Lₚⁿ of its stress
/// ([`IntegratorConfig::velocity_gradient`], ALGORITHM §5.4).
///
/// | variant | Lₚⁿ | cost |
/// |---|---|---|
/// | `Gather` | Σᵢ vᵢⁿ ⊗ ∇wᵢₚ from the velocities P2G just transferred (S4) | one gather over the 27 nodes per particle |
/// | `Carried` | Σᵢ vᵢⁿ ⊗ ∇wᵢₚ from the *updated* velocities the last G2P read (at the particle's old position) | none: G2P computes it anyway for F and ρ |
///
/// Both are first-order accurate in Δt for the same time level: they differ by the P2G/G2P
/// round trip (the PIC smoothing of the transferred field) and by the weights of one step's
/// motion. `Carried` needs a first-order scheme (GS4 needs L̃ at t_{n+W₁}); a particle born
/// since the last step starts with L = 0 (no viscous stress in its first step).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum VelocityGradientSource {
    /// Gathered from the grid every step (the Kinematics stage). Default.
    #[default]
    Gather,
    /// The last first-order G2P's Lₚⁿ⁺¹, kept on the particle.
    Carried,
}

impl VelocityGradientSource {
    /// Checks the combination with the scheme; the error names the field and the constraint.
    pub fn validate(&self, scheme: Scheme) -> Result<(), (String, String)> {
        if *self == Self::Carried && scheme.is_gs4() {
            return Err((
                "integrator.velocity_gradient".into(),
                format!(
                    "Carried needs a first-order scheme (integrator.scheme: SymplecticEuler or \
                     BackwardEulerViscous); got {scheme:?}, whose stages need L at t_(n+W1)"
                ),
            ));
        }
        Ok(())
    }
}

/// How the liquid's pressure is found (ALGORITHM §2.6, §5.4).
///
/// | variant | pressure | Δt limited by sound | volume |
/// |---|---|---|---|
/// | `Tait` | p(ρ) = ρ₀c₀²/γ\[(ρ/ρ₀)^γ − 1\] on the particles, explicit | yes: Δt ∝ Δx/c₀ | compresses by ≈ gH/c₀² at depth H and ≈ Ma²/2 in flow |
/// | `Projection` | cell pressures from a Poisson-type solve on the grid after the grid update | no | kept to the solver tolerance, drift relaxed over `volume_relaxation` |
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum PressureSolve {
    /// The Tait equation of state of ALGORITHM §2.6 (the materials' `sound_speed`,
    /// `tait_gamma`). Default.
    #[default]
    Tait,
    /// The grid projection of [`crate::step::implicit::pressure`]: the Tait pressure is left out
    /// of the particle stress and its sound limit out of Δt. Needs a first-order scheme
    /// ([`Scheme::SymplecticEuler`] or [`Scheme::BackwardEulerViscous`]) and no periodic axis.
    Projection(ProjectionConfig),
}

impl PressureSolve {
    /// The projection settings, when the pressure is projected.
    pub fn projection(&self) -> Option<&ProjectionConfig> {
        match self {
            Self::Tait => None,
            Self::Projection(p) => Some(p),
        }
    }

    /// Checks the combination with the other settings; the error names the field and the
    /// constraint.
    pub fn validate(&self, scheme: Scheme, walls: &DomainWalls) -> Result<(), (String, String)> {
        let Some(p) = self.projection() else {
            return Ok(());
        };
        if scheme.is_gs4() {
            return Err((
                "integrator.pressure".into(),
                format!(
                    "Projection needs a first-order scheme (integrator.scheme: SymplecticEuler \
                     or BackwardEulerViscous); got {scheme:?}, whose GS4 rates the projection \
                     would not update"
                ),
            ));
        }
        if walls.periodic_axes().iter().any(|p| *p) {
            return Err((
                "integrator.pressure".into(),
                "Projection does not support periodic walls yet (the cell lattice does not wrap)"
                    .into(),
            ));
        }
        if let Err((field, constraint)) = p.solver.validate() {
            return Err((
                format!("integrator.pressure.solver.{field}"),
                format!("{constraint} (got {:?})", p.solver),
            ));
        }
        if !(p.volume_relaxation.is_finite() && p.volume_relaxation > 0.0) {
            return Err((
                "integrator.pressure.volume_relaxation".into(),
                format!(
                    "must be a finite number > 0 s (got {})",
                    p.volume_relaxation
                ),
            ));
        }
        Ok(())
    }
}

/// Settings of [`PressureSolve::Projection`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub struct ProjectionConfig {
    /// Conjugate-gradient settings of the pressure solve. Default: relative residual 1e-2
    /// (of the divergence the solve removes; the tolerance the tests' volume and rest bounds
    /// are derived from), at most 1000 iterations.
    pub solver: crate::krylov::CgParams,
    /// Time \[s\] over which a cell's volume error (its fill φ > 1 read off the transferred node
    /// masses: the drift the particle transfer leaves) is relaxed back: the solve asks an
    /// overfull cell for the divergence Δx³ ln φ / max(τ, Δt). Default `0.05`.
    pub volume_relaxation: f64,
}

impl Default for ProjectionConfig {
    fn default() -> Self {
        Self {
            solver: crate::krylov::CgParams {
                rel_tol: 1e-2,
                abs_tol: 0.0,
                max_iters: 1000,
            },
            volume_relaxation: 0.05,
        }
    }
}

impl Default for IntegratorConfig {
    fn default() -> Self {
        Self {
            scheme: Scheme::Gs4Explicit,
            rho_inf: 0.5,
            rho_s: 0.0,
            flip: 0.95,
            flip_interval: FlipInterval::default(),
            sticky_reset: StickyReset::EveryStep,
            flip_update: FlipUpdate::ParticleGs4,
            solid_motion: SolidMotion::ParticleVelocity,
            density: DensityUpdate::Gs4Continuity,
            consistent_startup: true,
            viscous_solver: crate::krylov::CgParams::default(),
            pressure: PressureSolve::Tait,
            velocity_gradient: VelocityGradientSource::Gather,
        }
    }
}

/// The time-integration scheme of the momentum equation (ALGORITHM §1, §2, §5.2).
///
/// | scheme | pressure and other stresses | local viscosity 2F_vμD | temporal order | Δt limited by |
/// |---|---|---|---|---|
/// | `Gs4Explicit` | explicit GS4-II | explicit | 2 | advection, sound + viscosity, relaxation |
/// | `SymplecticEuler` | explicit, first order | explicit | 1 | the same, with Ω_crit = z_crit = 2 |
/// | `BackwardEulerViscous` | explicit, first order | implicit (backward Euler) | 1 | advection, sound, relaxation |
/// | `Gs4SemiImplicit` | explicit GS4-II | implicit (GS4, η = 1) | 2 | advection, sound, relaxation |
///
/// The implicit schemes solve the velocity form of ALGORITHM §5.2 on the grid,
/// (M + θK) u = M(û + θ(f/m + g′)), by preconditioned conjugate gradients
/// ([`crate::step::implicit`]); only the material's local Newtonian viscosity F_v μ is implicit,
/// rheology-model stresses stay explicit (and keep their own Δt limits). In the first-order
/// schemes rheology models still integrate their history with GS4-1; the momentum, density
/// and position updates are first order ([`crate::step::symplectic_euler`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum Scheme {
    /// The explicit GS4-MPM step of \[Su21\] with (ρ∞, ρs) (ALGORITHM §2). Default.
    #[default]
    Gs4Explicit,
    /// The standard first-order MPM step: P2G of m v, vᵢⁿ⁺¹ = vᵢ + Δt (fᵢ/mᵢ + g), collisions,
    /// G2P with PIC/FLIP, xₚ += Δt Σ w vᵢⁿ⁺¹, ρ ← ρ/(1 + Δt ∇·vⁿ⁺¹).
    SymplecticEuler,
    /// Semi-implicit backward Euler (\[Su21\] eq. 17 restricted to the local viscosity,
    /// ALGORITHM §5.2): symplectic Euler for pressure and explicit stresses, the viscous term
    /// implicit: (M + ΔtK) vⁿ⁺¹ = M v*.
    BackwardEulerViscous,
    /// The GS4 semi-implicit viscous solve (η = 1, ALGORITHM §5.2) inside the explicit GS4
    /// step: (M + θK) ṽ = M v̂ + θ(f + M(g − aⁿ)), θ = W₂Λ₅Δt/W₁Λ₆.
    Gs4SemiImplicit,
}

impl Scheme {
    /// Every scheme, in declaration order.
    pub const ALL: [Scheme; 4] = [
        Scheme::Gs4Explicit,
        Scheme::SymplecticEuler,
        Scheme::BackwardEulerViscous,
        Scheme::Gs4SemiImplicit,
    ];

    /// Whether the local viscosity is solved implicitly on the grid.
    pub fn implicit_viscosity(self) -> bool {
        matches!(self, Scheme::BackwardEulerViscous | Scheme::Gs4SemiImplicit)
    }

    /// Whether the step is a GS4 step (predictors at t_{n+W₁}, GS4 grid and particle updates).
    pub fn is_gs4(self) -> bool {
        matches!(self, Scheme::Gs4Explicit | Scheme::Gs4SemiImplicit)
    }

    /// The command-line name: `gs4`, `symplectic-euler`, `backward-euler`, `gs4-implicit`.
    pub fn cli_name(self) -> &'static str {
        match self {
            Scheme::Gs4Explicit => "gs4",
            Scheme::SymplecticEuler => "symplectic-euler",
            Scheme::BackwardEulerViscous => "backward-euler",
            Scheme::Gs4SemiImplicit => "gs4-implicit",
        }
    }

    /// The scheme's formal temporal order: 2 for the GS4 schemes, 1 for the first-order ones.
    pub fn formal_order(self) -> u32 {
        if self.is_gs4() { 2 } else { 1 }
    }
}

impl std::fmt::Display for Scheme {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.cli_name())
    }
}

impl std::str::FromStr for Scheme {
    type Err = String;

    /// Parses a command-line name ([`Scheme::cli_name`]) or the scene-file variant name.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Scheme::ALL
            .into_iter()
            .find(|k| k.cli_name() == s || format!("{k:?}") == s)
            .ok_or_else(|| {
                format!(
                    "unknown integrator '{s}' (expected one of: {})",
                    Scheme::ALL.map(|k| k.cli_name()).join(", ")
                )
            })
    }
}

/// The FLIP part of the GS4 grid-to-particle update (ALGORITHM §2.12; see
/// [`crate::kernels::g2p_stencil`] and [`crate::kernels::g2p_stencil_particle_gs4`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum FlipUpdate {
    /// v_F = vₚ + Σ w̃ (vᵢⁿ⁺¹ − vᵢⁿ), a_F = aₚ + Σ w̃ (aᵢⁿ⁺¹ − aᵢⁿ): the grid increments only.
    /// Stable, but the GS4 predictor then uses Σ w̃ aᵢⁿ instead of the particle velocity's own
    /// rate, and with pure FLIP the step is only **first** order in time
    /// (`tests/it/integrators.rs`: observed orders 1.0–1.4 on the shear layer). The default
    /// of versions before the switch to [`FlipUpdate::ParticleGs4`].
    GridIncrement,
    /// GS4-II applied to the particle ODE: the grid increments plus a decaying correction of
    /// the part of aₚ the grid does not see. Second order in time with pure FLIP. Default
    /// (it costs nothing measurable, BENCHMARKS.md (n)).
    #[default]
    ParticleGs4,
}

/// How the GS4 schemes move particles that carry F ([`IntegratorConfig::solid_motion`],
/// ALGORITHM §2.13). The symplectic Euler scheme always moves them with the grid velocity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum SolidMotion {
    /// Like every particle: xₚⁿ⁺¹ = xₚ + Δt/2 (vₚ + v_FLIP), the particle's own velocity
    /// (eq. 45). F follows the grid's displacement instead (D7), so the part of vₚ the grid
    /// does not see moves a solid's particles without its F (and its stress) knowing: measured
    /// on a strip of solid resting on a rod, it sags and creeps the more steps it takes
    /// (docs/gallery.md, letters). Default, as in \[Su21\].
    #[default]
    ParticleVelocity,
    /// With the grid displacement F is advanced with: xₚⁿ⁺¹ = xₚ + Δt/2 Σ w̃ (vᵢⁿ + vᵢⁿ⁺¹), so
    /// positions and F stay consistent (the standard MPM choice for solids). A particle of a
    /// phase-change material (which carries F in both phases) takes the blend
    /// I_s·(grid displacement) + (1 − I_s)·(its own) with its solid fraction I_s
    /// ([`PhaseIndex`](crate::components::PhaseIndex)), so its melt moves as a liquid.
    GridVelocity,
}

/// How often a `Sticky` domain face resets the particles next to it (ALGORITHM §2.11, choice
/// D20).
///
/// The FLIP increment vᵢⁿ⁺¹ − vᵢⁿ of a node on a sticky face subtracts the transferred velocity
/// vᵢⁿ of the particles next to the wall from them. Every step, that is a friction whose strength
/// grows as 1/Δt: the wall's particles are held in place, but the result depends on Δt (the
/// droplet converges at order ≈ 0.45, docs/reports.md). The other variants scale vᵢⁿ and aᵢⁿ
/// of those nodes after P2G by β, the share of the reset a step keeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum StickyReset {
    /// β = 1: every step (\[Su21\] and every version of treacle before this field). Default.
    #[default]
    EveryStep,
    /// β = min(1, Δt/τ) with τ the interval of [`IntegratorConfig::flip_interval`]: once per
    /// interval, the same hold per unit time at every Δt below τ.
    PerInterval,
    /// β = 0: the wall acts on the particles only through the step's forces (the no-slip shear
    /// stress, an impact's compression) and the PIC share. With pure FLIP and
    /// [`FlipUpdate::ParticleGs4`] the droplet is second order in time, but particles that
    /// reach the wall slide along it.
    Never,
}

impl StickyReset {
    /// The share β ∈ \[0, 1\] of the reset in a step of size `dt` (`interval` τ, if any).
    pub fn share(self, dt: f64, interval: Option<f64>) -> Real {
        match (self, interval) {
            (Self::EveryStep, _) => 1.0,
            (Self::PerInterval, Some(tau)) if tau > 0.0 => (dt / tau).min(1.0) as Real,
            (Self::PerInterval, _) => 1.0,
            (Self::Never, _) => 0.0,
        }
    }
}

/// The interval over which the particle update keeps the FLIP fraction α_F
/// ([`IntegratorConfig::flip`], ALGORITHM §2.12).
///
/// A PIC share 1 − α_F applied every step smooths the particle velocities with a numerical
/// viscosity of about (1 − α_F)Δx²/(4Δt), which doubles when Δt halves. Over an interval τ of
/// time the share per step is 1 − α_F^(Δt/τ), so the smoothing per unit time, and with it the
/// numerical viscosity ≈ −ln(α_F)Δx²/(4τ), does not depend on Δt. Pure FLIP (α_F = 1) and pure
/// PIC (α_F = 0) are the same under every interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum FlipInterval {
    /// α_F every step, whatever Δt (\[Su21\] eq. 44 and every version of treacle before the
    /// interval existed).
    Step,
    /// α_F over `k` Δx/c, where c is the largest wave speed of the Δt rule at the last step
    /// (Tait sound with the rheology models' elastic moduli, ALGORITHM §7.2), at least the
    /// materials' largest c₀. `k` > 0.
    /// The default `0.35` is the sound limit's step at the default safety factor
    /// (0.5 · Ω_crit/2 ≈ 0.354 Δx/c), so a sound-limited run smooths as `Step` did; a run
    /// whose Δt is smaller (viscosity, a smaller safety factor, a fixed step) smooths the same
    /// per unit time instead of more.
    SoundCrossing(f64),
    /// α_F over a fixed time τ \[s\] > 0.
    Seconds(f64),
}

impl Default for FlipInterval {
    fn default() -> Self {
        Self::SoundCrossing(0.35)
    }
}

impl FlipInterval {
    /// The interval τ \[s\] for grid spacing `dx` and largest sound speed `c_max`, or `None` for
    /// [`FlipInterval::Step`] (and when `c_max` is not positive).
    pub fn seconds(self, dx: f64, c_max: f64) -> Option<f64> {
        match self {
            Self::Step => None,
            Self::SoundCrossing(k) => (c_max > 0.0).then(|| k * dx / c_max),
            Self::Seconds(tau) => Some(tau),
        }
    }

    /// `Err` with the constraint when the interval's parameter is not finite and positive.
    pub fn validate(self) -> Result<(), String> {
        match self {
            Self::Step => Ok(()),
            Self::SoundCrossing(v) | Self::Seconds(v) if v.is_finite() && v > 0.0 => Ok(()),
            Self::SoundCrossing(v) | Self::Seconds(v) => {
                Err(format!("must be finite and > 0 (got {v})"))
            }
        }
    }

    /// The FLIP fraction of one step of size `dt` that keeps `flip` over this interval.
    pub fn per_step(self, flip: Real, dt: f64, dx: f64, c_max: f64) -> Real {
        flip_over_interval(flip as f64, dt, self.seconds(dx, c_max)) as Real
    }
}

/// The FLIP fraction of a step of size `dt` that keeps `flip` over the interval `tau` \[s\]:
/// flip^(Δt/τ); `flip` itself without an interval (and for pure FLIP or pure PIC).
pub fn flip_over_interval(flip: f64, dt: f64, tau: Option<f64>) -> f64 {
    match tau {
        Some(tau) if tau > 0.0 && flip > 0.0 && flip < 1.0 => flip.powf(dt / tau),
        _ => flip,
    }
}

/// How particle density is advanced (ALGORITHM §2.6, choice D2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum DensityUpdate {
    /// GS4-1 integration of Dρ/Dt = −ρ ∇·v, pointwise implicit in ρ (the paper's choice).
    Gs4Continuity,
}

/// How the step size Δt is chosen (ALGORITHM §2.15).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum TimeStepMode {
    /// Δt = C_s · min{C_adv Δx/|v|max, \[2c/(Ω_crit Δx) + 8ν/(z_crit Δx²)\]⁻¹, Δt_relax}:
    /// advection, sound + viscosity and relaxation limits (ALGORITHM §2.15, §7.2).
    Adaptive,
    /// The rule printed in \[Su21\] §7.1.4: Δt = 0.5 min{Δx/|u|max, \[2μ/(ρΔx²) + |u|max/Δx\]⁻¹}.
    /// It ignores the sound speed; kept for regression against the paper.
    Paper,
    /// A fixed step \[s\] (clipped to the frame end only; `max_dt` does not apply).
    Fixed(f64),
}

/// Time-step settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub struct TimeStepConfig {
    /// Rule. Default [`TimeStepMode::Adaptive`].
    pub mode: TimeStepMode,
    /// Safety factor C_s ∈ (0, 1] applied to the adaptive limits. Default `0.5`.
    /// Values close to 1 run at the predicted stability limit.
    pub safety: f64,
    /// Advection Courant number C_adv ∈ (0, 1]. Default `1.0` (multiplied by `safety`).
    pub advection: f64,
    /// Largest adaptive (or paper-rule) step \[s\]. Default `1e-3`. Not applied to `Fixed`.
    pub max_dt: f64,
    /// Smallest acceptable adaptive step \[s\]; a smaller prediction stops the run with a
    /// diagnostic (it means the state has become too stiff or too fast). Default `1e-9`.
    pub min_dt: f64,
}

impl Default for TimeStepConfig {
    fn default() -> Self {
        Self {
            mode: TimeStepMode::Adaptive,
            safety: 0.5,
            advection: 1.0,
            max_dt: 1e-3,
            min_dt: 1e-9,
        }
    }
}

/// Boundary condition of a wall or collider (ALGORITHM §2.11).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum BoundaryCondition {
    /// No-slip: the liquid takes the wall's velocity.
    Sticky,
    /// Free slip: only the velocity into the wall is removed. A domain face on a node plane
    /// is a mirror of the grid fields (ALGORITHM §2.11, choice D18).
    Slip,
    /// Coulomb friction with coefficient μ_f ≥ 0 (0 = slip, without the mirror of `Slip`).
    Friction(Real),
    /// No wall: liquid leaving the domain through this face is removed.
    Open,
    /// Periodic: must be set on both faces of an axis, whose domain length must be a whole
    /// number of cells. Liquid leaving through one face re-enters through the other.
    Periodic,
}

/// Conditions on the six faces of the domain box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub struct DomainWalls {
    /// Face x = min. Default slip.
    pub x_min: BoundaryCondition,
    /// Face x = max. Default slip.
    pub x_max: BoundaryCondition,
    /// Face y = min (the floor with the default gravity). Default slip.
    pub y_min: BoundaryCondition,
    /// Face y = max. Default slip.
    pub y_max: BoundaryCondition,
    /// Face z = min. Default slip.
    pub z_min: BoundaryCondition,
    /// Face z = max. Default slip.
    pub z_max: BoundaryCondition,
}

impl Default for DomainWalls {
    fn default() -> Self {
        Self::all(BoundaryCondition::Slip)
    }
}

impl DomainWalls {
    /// The same condition on every face.
    pub fn all(bc: BoundaryCondition) -> Self {
        Self {
            x_min: bc,
            x_max: bc,
            y_min: bc,
            y_max: bc,
            z_min: bc,
            z_max: bc,
        }
    }

    /// Which axes are periodic (both faces `Periodic`).
    pub fn periodic_axes(&self) -> [bool; 3] {
        [0, 1, 2].map(|a| {
            matches!(self.face(a, false), BoundaryCondition::Periodic)
                && matches!(self.face(a, true), BoundaryCondition::Periodic)
        })
    }

    /// Condition of face `axis` (0, 1, 2), `upper` = the max face.
    pub fn face(&self, axis: usize, upper: bool) -> BoundaryCondition {
        match (axis, upper) {
            (0, false) => self.x_min,
            (0, true) => self.x_max,
            (1, false) => self.y_min,
            (1, true) => self.y_max,
            (_, false) => self.z_min,
            (_, true) => self.z_max,
        }
    }
}
