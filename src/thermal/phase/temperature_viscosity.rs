//! Temperature-dependent viscosity (ALGORITHM §4.3, choice D13; \[Li\]'s μ₀e^{−dT}):
//! [`TemperatureLaw`] (exponential or Cross-WLF), the Cross-WLF viscosity functions,
//! [`TemperatureViscosity`] with its factor φ on the fluid deviatoric stress, and the
//! per-material [`TemperatureViscosityTable`].
use bevy_ecs::prelude::*;
use serde::{Deserialize, Serialize};

use crate::material::MaterialTable;
use crate::validation::InvalidParameter;

/// A temperature dependence of the viscosity (§4.3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum TemperatureLaw {
    /// φ = e^{−d(T − T_ref)}: \[Li\]'s μ₀e^{−dT} with T_ref = 0 and μ₀ the material's (or
    /// model's) viscosity.
    Exponential {
        /// d \[1/temperature unit\] (\[Li\]'s ice cream: 0.1).
        coefficient: f64,
        /// T_ref (temperature unit) at which φ = 1. Default 0.
        #[serde(default)]
        reference_temperature: f64,
    },
    /// The Cross-WLF viscosity of §4.3 (D13 reading) replacing the material's viscosity μ
    /// (which must be > 0): φ = μ(T, γ̇)/μ. T in the unit of D₂ (°C for the \[Su21\] constants).
    CrossWlf {
        /// D₁ \[Pa·s\] > 0 (\[Su21\]: 3.32e9).
        d1: f64,
        /// A₁ ≥ 0 (\[Su21\]: 20.194).
        a1: f64,
        /// A₂ > 0 (temperature unit; 51.6, the universal WLF constant).
        a2: f64,
        /// D₂ = T* (temperature unit; 100).
        d2: f64,
        /// τ* \[Pa\] > 0. Default 5.66e3 (D13).
        #[serde(default = "default_tau_star")]
        tau_star: f64,
        /// Power-law index n ∈ \[0, 1\]. Default 0.25 (D13).
        #[serde(default = "default_power_index")]
        n: f64,
    },
}

fn default_tau_star() -> f64 {
    5.66e3
}
fn default_power_index() -> f64 {
    0.25
}

/// Cross-WLF zero-shear viscosity μ₀(T) = D₁ exp(−A₁(T_eff − D₂)/(A₂ + T_eff − D₂)) \[Pa·s\],
/// T_eff = max(T, D₂) (the D13 clamp: μ₀ ≤ D₁). NaN temperatures give D₁.
pub fn cross_wlf_zero_shear(d1: f64, a1: f64, a2: f64, d2: f64, t: f64) -> f64 {
    let t = if t.is_nan() { d2 } else { t.max(d2) };
    d1 * (-a1 * (t - d2) / (a2 + t - d2)).exp()
}

/// Cross-WLF viscosity μ(T, γ̇) = μ₀(T)/(1 + (μ₀(T)γ̇/τ*)^{1−n}) \[Pa·s\] (§4.3, D13).
#[expect(
    clippy::too_many_arguments,
    reason = "the six constants of §4.3 and (T, γ̇), in the order of the formula"
)]
pub fn cross_wlf_viscosity(
    d1: f64,
    a1: f64,
    a2: f64,
    d2: f64,
    tau_star: f64,
    n: f64,
    t: f64,
    shear_rate: f64,
) -> f64 {
    let mu0 = cross_wlf_zero_shear(d1, a1, a2, d2, t);
    let x = (mu0 * shear_rate.abs() / tau_star).max(0.0);
    mu0 / (1.0 + x.powf(1.0 - n))
}

/// A temperature-dependent viscosity of one material (§4.3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureViscosity {
    /// The law.
    pub law: TemperatureLaw,
    /// Cap μ_max \[Pa·s\] of the scaled viscosity φ·μ (D13). Default none.
    #[serde(default)]
    pub max_viscosity: Option<f64>,
}

impl TemperatureViscosity {
    /// \[Li\]'s μ₀e^{−dT} (the material's viscosity is μ₀).
    pub fn exponential(coefficient: f64) -> Self {
        Self {
            law: TemperatureLaw::Exponential {
                coefficient,
                reference_temperature: 0.0,
            },
            max_viscosity: None,
        }
    }

    /// The Cross-WLF law with the \[Su21\] constants read as in D13 (T in °C).
    pub fn cross_wlf_su2021() -> Self {
        Self {
            law: TemperatureLaw::CrossWlf {
                d1: 3.32e9,
                a1: 20.194,
                a2: 51.6,
                d2: 100.0,
                tau_star: 5.66e3,
                n: 0.25,
            },
            max_viscosity: None,
        }
    }

    /// With a viscosity cap μ_max \[Pa·s\].
    pub fn with_max_viscosity(mut self, max_viscosity: f64) -> Self {
        self.max_viscosity = Some(max_viscosity);
        self
    }

    /// The factor φ ≥ 0 on the fluid deviatoric stress at temperature `t`, shear rate
    /// `shear_rate` \[1/s\], for a material of viscosity `viscosity` \[Pa·s\]. Always finite.
    pub fn factor(&self, t: f64, shear_rate: f64, viscosity: f64) -> f64 {
        let mut phi = match self.law {
            TemperatureLaw::Exponential {
                coefficient,
                reference_temperature,
            } => (-coefficient * (t - reference_temperature)).exp(),
            TemperatureLaw::CrossWlf {
                d1,
                a1,
                a2,
                d2,
                tau_star,
                n,
            } => {
                if viscosity > 0.0 {
                    cross_wlf_viscosity(d1, a1, a2, d2, tau_star, n, t, shear_rate) / viscosity
                } else {
                    1.0
                }
            }
        };
        if let Some(cap) = self.max_viscosity
            && viscosity > 0.0
        {
            phi = phi.min(cap / viscosity);
        }
        if phi.is_nan() {
            1.0
        } else {
            phi.clamp(0.0, f64::MAX)
        }
    }

    /// Checks the parameters for a material of viscosity `viscosity`.
    pub fn validate(&self, viscosity: f64) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        let mut bad = |field, constraint| e.push(InvalidParameter { field, constraint });
        match self.law {
            TemperatureLaw::Exponential {
                coefficient,
                reference_temperature,
            } => {
                if !coefficient.is_finite() {
                    bad("law.coefficient", "must be a finite number");
                }
                if !reference_temperature.is_finite() {
                    bad("law.reference_temperature", "must be a finite number");
                }
            }
            TemperatureLaw::CrossWlf {
                d1,
                a1,
                a2,
                d2,
                tau_star,
                n,
            } => {
                if !(d1.is_finite() && d1 > 0.0) {
                    bad("law.d1", "must be a finite number > 0 Pa·s");
                }
                if !(a1.is_finite() && a1 >= 0.0) {
                    bad("law.a1", "must be a finite number ≥ 0");
                }
                if !(a2.is_finite() && a2 > 0.0) {
                    bad("law.a2", "must be a finite number > 0");
                }
                if !d2.is_finite() {
                    bad("law.d2", "must be a finite number");
                }
                if !(tau_star.is_finite() && tau_star > 0.0) {
                    bad("law.tau_star", "must be a finite number > 0 Pa");
                }
                if !(n.is_finite() && (0.0..=1.0).contains(&n)) {
                    bad("law.n", "must lie in [0, 1]");
                }
                if viscosity.is_nan() || viscosity <= 0.0 {
                    bad(
                        "law",
                        "CrossWlf replaces the material's viscosity, which must then be > 0 Pa·s",
                    );
                }
            }
        }
        if let Some(cap) = self.max_viscosity
            && !(cap.is_finite() && cap > 0.0)
        {
            bad("max_viscosity", "must be a finite number > 0 Pa·s");
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

/// Temperature-dependent viscosity per material (may be changed at run time).
#[derive(Resource, Clone, Debug, Default)]
pub struct TemperatureViscosityTable(pub MaterialTable<TemperatureViscosity>);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cross_wlf_samples() {
        let mu0 = |t| cross_wlf_zero_shear(3.32e9, 20.194, 51.6, 100.0, t);
        assert!((mu0(200.0) / 5.45e3 - 1.0).abs() < 5e-3, "{}", mu0(200.0));
        assert_eq!(mu0(100.0), 3.32e9);
        assert_eq!(mu0(20.0), 3.32e9); // clamped T_eff = D₂
    }
}
