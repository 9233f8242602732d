//! Simulation configuration resources.
//!
//! Every field states its unit, its default and how it affects stability. The scene loader
//! ([`crate::scene`]) fills these resources, but a Bevy app can insert and change them directly.
use bevy_ecs::prelude::*;
use serde::{Deserialize, Serialize};

use crate::math::{Real, Vec3};

/// Global MPM configuration: the domain, the grid, gravity and the integrator.
///
/// Changing `dx` or the domain at run time is not supported (the grid is sized once);
/// everything else may be changed between frames.
#[derive(Resource, Clone, Debug, PartialEq)]
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

/// Settings of the explicit GS4 integrator (ALGORITHM §1, §2).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntegratorConfig {
    /// GS4 spectral radius at infinity ρ∞ ∈ \[0, 1\]. Default `0.5`.
    /// Smaller values damp high frequencies more; (ρ∞, ρs) = (1, 1) is unstable explicitly.
    pub rho_inf: f64,
    /// GS4 spurious-root parameter ρs ∈ \[0, ρ∞\]. Default `0` (ALGORITHM §1.3 recommends 0
    /// for every explicit field; larger values shrink the stable time step).
    pub rho_s: f64,
    /// FLIP fraction α_F ∈ \[0, 1\] of the particle update (ALGORITHM §2.12). Default `0.95`.
    /// `0` is pure PIC (dissipative, very stable), `1` pure FLIP (noisy, no transfer damping).
    pub flip: Real,
    /// Density integration (ALGORITHM §2.6, choice D2). Default GS4 continuity.
    pub density: DensityUpdate,
    /// Evaluate consistent initial rates (a⁰, ρ̇⁰, ...) before the first step (§2.14).
    /// Default `true`. With `false` the stored rates are used as given (a⁰ = g for new particles).
    pub consistent_startup: bool,
}

impl Default for IntegratorConfig {
    fn default() -> Self {
        Self {
            rho_inf: 0.5,
            rho_s: 0.0,
            flip: 0.95,
            density: DensityUpdate::Gs4Continuity,
            consistent_startup: true,
        }
    }
}

/// How particle density is advanced (ALGORITHM §2.6, choice D2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum DensityUpdate {
    /// GS4-1 integration of Dρ/Dt = −ρ ∇·v, pointwise implicit in ρ (the paper's choice).
    Gs4Continuity,
}

/// How the step size Δt is chosen (ALGORITHM §2.15).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
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
pub enum BoundaryCondition {
    /// No-slip: the liquid takes the wall's velocity.
    Sticky,
    /// Free slip: only the velocity into the wall is removed.
    Slip,
    /// Coulomb friction with coefficient μ_f ≥ 0 (0 = slip).
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
