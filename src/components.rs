//! Particle components: one per physical quantity (ALGORITHM §2.1, §10).
//!
//! A particle is an entity with [`Particle`], [`Position`], [`Velocity`], [`Acceleration`],
//! [`Mass`], [`Density`] and [`MaterialId`] (spawn them with [`ParticleBundle::new`]), plus the
//! per-step scratch components of [`StepScratch`], which [`Particle`] requires (Bevy adds them
//! with their defaults). Model-specific state
//! (polymer stress, temperature, plastic strain, ...) is carried only by particles whose material
//! needs it.
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;

use crate::material::MaterialId;
use crate::math::{Mat3, Real, Vec3};

/// Marker of an MPM particle. Every particle query filters on it (in Bevy 0.20 resources are
/// entities too, so `Query<Entity>` alone would also see them). Requires the scratch
/// components of [`StepScratch`].
#[derive(Component, Clone, Copy, Debug, Default)]
#[require(
    ParticleStencil,
    VelocityGradient,
    PredictedDensity,
    CauchyStress,
    StabilityData
)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct Particle;

/// Position x_p \[m\].
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct Position(pub Vec3);

/// Velocity v_p \[m/s\].
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct Velocity(pub Vec3);

/// Acceleration a_p [m/s²]: the GS4 rate of the velocity, carried between steps (§2.1).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct Acceleration(pub Vec3);

/// Mass m_p \[kg\], constant.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct Mass(pub Real);

/// Density ρ_p \[kg/m³\] and its material rate ρ̇_p \[kg/m³/s\] (GS4 pair, §2.6).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct Density {
    /// ρ_p.
    pub value: Real,
    /// Dρ/Dt.
    pub rate: Real,
}

/// Deformation gradient F_p (dimensionless). Only particles whose material needs a shape
/// memory (solid phase, elasto-plasticity) carry it; it is advanced with choice D7 (§2.13).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct DeformationGradient(pub Mat3);

impl Default for DeformationGradient {
    fn default() -> Self {
        Self(Mat3::IDENTITY)
    }
}

/// Solid fraction I_s ∈ [0, 1] of the particle (ALGORITHM §4.1): 1 solid, 0 fluid. Only
/// particles of materials with a melting temperature carry it (the thermal plugin's phase
/// change writes it; `crate::thermal::PhaseIndex` is this type).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PhaseIndex(pub Real);

/// Where the particle's B-spline stencil sits at its predicted position
/// x̃_p = x + W₁Λ₁Δt v + W₂Λ₂Δt² a at t_{n+W₁} (§2.4): the base node and the distance from it
/// in cells per axis, computed once per step by `Predict` ([`Stencil::locate`]). Every weight
/// of a step is evaluated at x̃_p, so x̃_p itself is not stored. The transfer passes expand this
/// into the weights and gradients ([`ParticleStencil::stencil`], a few dozen flops) instead of
/// reading 84 stored bytes per particle each (24 bytes here).
///
/// [`Stencil::locate`]: crate::kernels::Stencil::locate
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct ParticleStencil {
    /// Lowest node of the stencil (grid node coordinates).
    pub base: glam::IVec3,
    /// x̃ₚ/Δx minus `base`, per axis (in \[0.5, 1.5) unless the base was clamped).
    pub offset: Vec3,
}

impl ParticleStencil {
    /// The stencil of a particle at `x` on `grid`.
    #[inline(always)]
    pub fn at(grid: &crate::grid::GridLayout, x: Vec3) -> Self {
        let (base, offset) = crate::kernels::Stencil::locate(grid, x);
        Self { base, offset }
    }

    /// Its weights and gradients: [`Stencil::new`](crate::kernels::Stencil::new) at x̃ₚ, bit
    /// for bit.
    #[inline(always)]
    pub fn stencil(&self, grid: &crate::grid::GridLayout) -> crate::kernels::Stencil {
        crate::kernels::Stencil::from_offset(grid, self.base, self.offset)
    }
}

/// Velocity gradient L̃_p = Σᵢ ṽᵢ ⊗ ∇w̃ᵢₚ at t_{n+W₁} (§2.3 S4), L_ab = ∂v_a/∂x_b.
/// Written by `Kinematics`.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct VelocityGradient(pub Mat3);

impl Default for VelocityGradient {
    fn default() -> Self {
        Self(Mat3::ZERO)
    }
}

/// Predicted deformation gradient F̃_p = (I + Ĝ_p) F_p (§2.3 S4, D16); only on particles with
/// a [`DeformationGradient`]. Written by `Kinematics`, read by `Constitutive` and `Commit`.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct PredictedDeformationGradient(pub Mat3);

impl Default for PredictedDeformationGradient {
    fn default() -> Self {
        Self(Mat3::IDENTITY)
    }
}

/// Algorithmic density ρ̃_p at t_{n+W₁} and the GS4 increment Δρ̇_p (§2.6). Written by
/// `Constitutive`, committed by `Commit`.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PredictedDensity {
    /// ρ̃_p \[kg/m³\].
    pub value: Real,
    /// Δρ̇_p \[kg/m³/s\].
    pub rate_increment: Real,
}

/// Total Cauchy stress σ̃_p at t_{n+W₁} \[Pa\] (§2.9). `Constitutive` writes −p̃I + 2F_vμD̃ first
/// (only −p̃I under implicit viscosity);
/// rheology models then add their stress to it. `GridForces` scatters −Ṽσ̃∇w̃.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct CauchyStress(pub Mat3);

impl Default for CauchyStress {
    fn default() -> Self {
        Self(Mat3::ZERO)
    }
}

/// What limits the explicit time step at this particle (§2.15, §7.2). Written by
/// `Constitutive` (core writes the Tait sound speed and the local viscosity; models raise the
/// values with their moduli, tangent viscosity and relaxation rate).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct StabilityData {
    /// Squared wave speed c² = (K + 4/3 G)/ρ̃ \[m²/s²\].
    pub wave_speed_sq: Real,
    /// Kinematic (tangent) viscosity ν = μ_L,tan/ρ̃ of the explicit viscous stress \[m²/s\].
    pub kinematic_viscosity: Real,
    /// Stiffest explicit pointwise relaxation rate \[1/s\] (0 if none or treated implicitly).
    pub relaxation_rate: Real,
}

/// The scratch components every particle carries (reused each step; never allocated per step),
/// required by [`Particle`].
pub type StepScratch = (
    ParticleStencil,
    VelocityGradient,
    PredictedDensity,
    CauchyStress,
    StabilityData,
);

/// The state a liquid particle starts with (the scratch components come with [`Particle`]).
/// Spawn with [`ParticleBundle::new`].
#[derive(Bundle, Clone, Debug)]
pub struct ParticleBundle {
    /// Marker.
    pub particle: Particle,
    /// x_p.
    pub position: Position,
    /// v_p.
    pub velocity: Velocity,
    /// a_p (initially gravity; the consistent start-up replaces it).
    pub acceleration: Acceleration,
    /// m_p.
    pub mass: Mass,
    /// ρ_p, ρ̇_p.
    pub density: Density,
    /// Material index.
    pub material: MaterialId,
}

impl ParticleBundle {
    /// A particle at rest density `rho0` with volume `volume` \[m³\], at `position` moving with
    /// `velocity`, with acceleration `gravity` (consistent for a stress-free particle, §2.14).
    pub fn new(
        position: Vec3,
        velocity: Vec3,
        gravity: Vec3,
        volume: Real,
        rho0: Real,
        material: MaterialId,
    ) -> Self {
        Self {
            particle: Particle,
            position: Position(position),
            velocity: Velocity(velocity),
            acceleration: Acceleration(gravity),
            mass: Mass(volume * rho0),
            density: Density {
                value: rho0,
                rate: 0.0,
            },
            material,
        }
    }
}
