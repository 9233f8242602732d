//! Melting and solidification of one material (ALGORITHM §4.1–4.2, choices D11, D12):
//! [`PhaseChange`] with its solid fraction I_s (step or ramp) and neo-Hookean solid stress, and
//! the per-material [`PhaseChangeTable`].
use bevy_ecs::prelude::*;
use glam::DMat3;
use serde::{Deserialize, Serialize};

use crate::material::MaterialTable;
use crate::math::Real;
use crate::rheology::NeoHookean;
use crate::validation::InvalidParameter;

/// Melting and solidification of one material (§4.1–4.2).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseChange {
    /// Melting temperature T_m (scene temperature unit; \[Su21\] uses T_m = 0.1 normalised).
    pub melting_temperature: Real,
    /// Half width ΔT_m ≥ 0 of the smooth ramp of I_s (0: the paper's step). Default 0.
    #[serde(default)]
    pub ramp: Real,
    /// Shear modulus G_s of the neo-Hookean solid \[Pa\] > 0.
    pub shear_modulus: f64,
    /// Choice D12: reset the shape memory F ← J^{1/3}I while fluid. Default true.
    #[serde(default = "default_true")]
    pub reset_shape_memory: bool,
}

pub(super) fn default_true() -> bool {
    true
}

impl PhaseChange {
    /// A step change at `melting_temperature` to a neo-Hookean solid of shear modulus
    /// `shear_modulus` \[Pa\], with the D12 reset.
    pub fn new(melting_temperature: Real, shear_modulus: f64) -> Self {
        Self {
            melting_temperature,
            ramp: 0.0,
            shear_modulus,
            reset_shape_memory: true,
        }
    }

    /// With a smooth ramp of half width ΔT_m.
    pub fn with_ramp(mut self, ramp: Real) -> Self {
        self.ramp = ramp;
        self
    }

    /// The solid fraction I_s ∈ \[0, 1\] at temperature `t` (§4.1). NaN gives 0 (fluid).
    pub fn solid_fraction(&self, t: Real) -> Real {
        let tm = self.melting_temperature;
        if self.ramp > 0.0 {
            let s = (tm + self.ramp - t) / (2.0 * self.ramp);
            if s.is_nan() { 0.0 } else { s.clamp(0.0, 1.0) }
        } else if t < tm {
            1.0
        } else {
            0.0
        }
    }

    /// Deviatoric solid stress σ̃ˢ_dev \[Pa\] at F̃ = `f` and J̃ = `volume_ratio`, and the
    /// effective shear modulus of the stability estimate \[Pa\] (§4.2, D11). `None` if
    /// det F̃ ≤ 0.
    pub fn solid_stress(&self, f: DMat3, volume_ratio: f64) -> Option<(DMat3, f64)> {
        NeoHookean::new(self.shear_modulus).stress(f, volume_ratio)
    }

    /// Checks the parameters (every violated constraint is listed).
    pub fn validate(&self) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        if !self.melting_temperature.is_finite() {
            e.push(InvalidParameter {
                field: "melting_temperature",
                constraint: "must be a finite number",
            });
        }
        if !(self.ramp.is_finite() && self.ramp >= 0.0) {
            e.push(InvalidParameter {
                field: "ramp",
                constraint: "must be a finite number ≥ 0 (temperature unit)",
            });
        }
        if !(self.shear_modulus.is_finite() && self.shear_modulus > 0.0) {
            e.push(InvalidParameter {
                field: "shear_modulus",
                constraint: "must be a finite number > 0 Pa (G_s of the solid)",
            });
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

/// Phase change per material (may be changed at run time).
#[derive(Resource, Clone, Debug, Default)]
pub struct PhaseChangeTable(pub MaterialTable<PhaseChange>);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_and_step() {
        let p = PhaseChange::new(0.1, 1.0);
        assert_eq!(p.solid_fraction(0.099), 1.0);
        assert_eq!(p.solid_fraction(0.1), 0.0);
        let r = p.with_ramp(0.02);
        assert!((r.solid_fraction(0.1) - 0.5).abs() < 1e-6);
        assert_eq!(r.solid_fraction(0.07), 1.0);
        assert_eq!(r.solid_fraction(0.13), 0.0);
        assert_eq!(r.solid_fraction(f32::NAN), 0.0);
    }
}
