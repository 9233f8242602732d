//! Materials: the Tait equation of state and the Newtonian (local) viscosity.
//!
//! Particles name their material with [`MaterialId`], an index into the [`Materials`]
//! resource. Material parameters may be changed at run time through `ResMut<Materials>`.
//! Rheology plugins keep their own per-material parameter tables keyed by the same id.
use bevy_ecs::prelude::*;
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::{ReflectComponent, ReflectResource};
use serde::{Deserialize, Serialize};

use crate::math::Real;

/// Index of a particle's material in [`Materials`].
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct MaterialId(pub u16);

/// A weakly compressible viscous liquid (ALGORITHM §2.6–2.7).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub struct FluidMaterial {
    /// Name used in scene files and diagnostics.
    pub name: String,
    /// Rest density ρ₀ \[kg/m³\]. Must be > 0.
    pub density: Real,
    /// Speed of sound c₀ of the Tait equation \[m/s\]. Must be > 0. The explicit step is
    /// limited by ≈0.7 Δx/c₀; keep the largest flow speed below ≈0.1 c₀ for a volume error
    /// of about 1 % (weak compressibility, ALGORITHM §7.2).
    pub sound_speed: Real,
    /// Tait exponent γ. Default 7 (water). Must be ≥ 1.
    #[serde(default = "default_tait_gamma")]
    pub tait_gamma: Real,
    /// Dynamic viscosity μ \[Pa·s\] (≥ 0). The explicit step is limited by ≈0.14 ρΔx²/(F_v μ).
    #[serde(default)]
    pub viscosity: Real,
    /// Local (solvent) fraction F_v ∈ \[0, 1\] of the viscosity: the Newtonian stress is
    /// 2 F_v μ D (ALGORITHM §2.7). Default 1 (purely Newtonian).
    #[serde(default = "default_local_fraction")]
    pub local_fraction: Real,
}

fn default_tait_gamma() -> Real {
    7.0
}
fn default_local_fraction() -> Real {
    1.0
}

impl FluidMaterial {
    /// A Newtonian liquid with the given rest density, sound speed and viscosity.
    pub fn newtonian(name: &str, density: Real, sound_speed: Real, viscosity: Real) -> Self {
        Self {
            name: name.to_string(),
            density,
            sound_speed,
            tait_gamma: 7.0,
            viscosity,
            local_fraction: 1.0,
        }
    }

    /// Tait pressure p(ρ) = ρ₀c₀²/γ \[(ρ/ρ₀)^γ − 1\] \[Pa\] (ALGORITHM §2.6).
    #[inline]
    pub fn pressure(&self, rho: Real) -> Real {
        let b = self.density * self.sound_speed * self.sound_speed / self.tait_gamma;
        b * (pow(rho / self.density, self.tait_gamma) - 1.0)
    }

    /// Specific internal energy e(ρ) = ∫_{ρ₀}^{ρ} p(s)/s² ds \[J/kg\] the Tait pressure stores
    /// (the work of compressing or stretching a unit mass from ρ₀ to ρ):
    /// e = (c₀²/γ) \[(r^{γ−1} − 1)/(γ − 1) + 1/r − 1\] with r = ρ/ρ₀ (ln r for γ = 1);
    /// e ≥ 0, zero only at ρ₀. In f64: near ρ₀ it is a difference of nearly equal terms.
    pub fn internal_energy(&self, rho: Real) -> f64 {
        let r = rho as f64 / self.density as f64;
        let gamma = self.tait_gamma as f64;
        let c2 = (self.sound_speed as f64).powi(2);
        let stretch = if gamma == 1.0 {
            r.ln()
        } else if gamma.fract() == 0.0 && gamma <= 16.0 {
            // Integer γ (7 for water): repeated multiplication, not `powf` (the energy monitor
            // evaluates this for every particle every step; `powf` was 3 % of a step).
            (r.powi(gamma as i32 - 1) - 1.0) / (gamma - 1.0)
        } else {
            (r.powf(gamma - 1.0) - 1.0) / (gamma - 1.0)
        };
        c2 / gamma * (stretch + 1.0 / r - 1.0)
    }

    /// Squared local sound speed c² = dp/dρ = c₀² (ρ/ρ₀)^(γ−1) \[m²/s²\].
    #[inline]
    pub fn sound_speed_sq(&self, rho: Real) -> Real {
        self.sound_speed * self.sound_speed * pow(rho / self.density, self.tait_gamma - 1.0)
    }

    /// Checks the parameter constraints; the error names the field and the constraint.
    pub fn validate(&self) -> Result<(), (&'static str, &'static str)> {
        let finite_pos = |v: Real| v.is_finite() && v > 0.0;
        if !finite_pos(self.density) {
            return Err(("density", "must be a finite number > 0 kg/m³"));
        }
        if !finite_pos(self.sound_speed) {
            return Err(("sound_speed", "must be a finite number > 0 m/s"));
        }
        if !(self.tait_gamma.is_finite() && self.tait_gamma >= 1.0) {
            return Err(("tait_gamma", "must be a finite number ≥ 1"));
        }
        if !(self.viscosity.is_finite() && self.viscosity >= 0.0) {
            return Err(("viscosity", "must be a finite number ≥ 0 Pa·s"));
        }
        if !(self.local_fraction.is_finite() && (0.0..=1.0).contains(&self.local_fraction)) {
            return Err(("local_fraction", "must lie in [0, 1]"));
        }
        Ok(())
    }
}

/// xᵉ with a multiplication fast path for the usual integer exponents (γ = 7: `powf` was 3 %
/// of a step).
#[inline(always)]
fn pow(x: Real, e: Real) -> Real {
    if e == 7.0 {
        let x2 = x * x;
        x2 * x2 * x2 * x
    } else if e == 6.0 {
        let x2 = x * x;
        x2 * x2 * x2
    } else if e == 1.0 {
        x
    } else if e == 0.0 {
        1.0
    } else {
        x.powf(e)
    }
}

/// All materials of the simulation, indexed by [`MaterialId`].
#[derive(Resource, Clone, Debug, Default)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Resource))]
pub struct Materials {
    /// The materials; `MaterialId(i)` refers to `list[i]`.
    pub list: Vec<FluidMaterial>,
}

impl Materials {
    /// Adds a material and returns its id.
    pub fn add(&mut self, material: FluidMaterial) -> MaterialId {
        self.list.push(material);
        MaterialId((self.list.len() - 1) as u16)
    }

    /// The material with this id.
    ///
    /// # Panics
    /// If the id was not returned by [`Materials::add`] (a programming error; scene files are
    /// validated before spawning).
    #[inline]
    pub fn get(&self, id: MaterialId) -> &FluidMaterial {
        &self.list[id.0 as usize]
    }

    /// Looks a material up by name.
    pub fn find(&self, name: &str) -> Option<MaterialId> {
        self.list
            .iter()
            .position(|m| m.name == name)
            .map(|i| MaterialId(i as u16))
    }
}

/// Per-material entries `MaterialId(i)` → `T` (rheology parameters, phase change, temperature
/// laws, ...). Materials without an entry do not use the feature.
#[derive(Clone, Debug)]
pub struct MaterialTable<T> {
    entries: Vec<Option<T>>,
}

impl<T> Default for MaterialTable<T> {
    fn default() -> Self {
        Self {
            entries: Vec::new(),
        }
    }
}

impl<T: Clone> MaterialTable<T> {
    /// Sets the entry of `material`; returns the previous one.
    pub fn insert(&mut self, material: MaterialId, value: T) -> Option<T> {
        let i = material.0 as usize;
        if self.entries.len() <= i {
            self.entries.resize(i + 1, None);
        }
        self.entries[i].replace(value)
    }

    /// Removes the entry of `material`; returns it.
    pub fn remove(&mut self, material: MaterialId) -> Option<T> {
        self.entries.get_mut(material.0 as usize)?.take()
    }

    /// The entry of `material`, mutably.
    pub fn get_mut(&mut self, material: MaterialId) -> Option<&mut T> {
        self.entries.get_mut(material.0 as usize)?.as_mut()
    }

    /// The entry of `material`.
    #[inline]
    pub fn get(&self, material: MaterialId) -> Option<&T> {
        self.entries.get(material.0 as usize)?.as_ref()
    }

    /// All (material, entry) pairs.
    pub fn iter(&self) -> impl Iterator<Item = (MaterialId, &T)> {
        self.entries
            .iter()
            .enumerate()
            .filter_map(|(i, m)| m.as_ref().map(|m| (MaterialId(i as u16), m)))
    }

    /// True if no material has an entry.
    pub fn is_empty(&self) -> bool {
        self.entries.iter().all(Option::is_none)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// e(ρ) against the integral ∫_{ρ₀}^{ρ} p(s)/s² ds by Simpson's rule, for γ = 7, a
    /// non-integer γ and γ = 1; zero at ρ₀, positive both under compression and in tension.
    /// Tolerance 10⁻⁵ relative: the integrand evaluates the f32 pressure, whose rounding
    /// (~10⁻⁷ of p, amplified by the cancellation p = B(rᵞ − 1) near ρ₀ to ~10⁻⁶) dominates
    /// Simpson's error with 2,000 intervals (~h⁴ f⁗/180, below 10⁻¹⁰ here).
    #[test]
    fn internal_energy_is_the_work_of_the_tait_pressure() {
        for gamma in [7.0, 2.5, 1.0] {
            let m = FluidMaterial {
                tait_gamma: gamma,
                ..FluidMaterial::newtonian("w", 1000.0, 5.0, 0.01)
            };
            assert_eq!(m.internal_energy(1000.0), 0.0);
            for r in [0.7f64, 0.95, 1.05, 1.3] {
                let rho = 1000.0 * r;
                let n = 2000;
                let h = (rho - 1000.0) / n as f64;
                let f = |s: f64| m.pressure(s as Real) as f64 / (s * s);
                let mut sum = f(1000.0) + f(rho);
                for i in 1..n {
                    sum += if i % 2 == 1 { 4.0 } else { 2.0 } * f(1000.0 + i as f64 * h);
                }
                let integral = sum * h / 3.0;
                let e = m.internal_energy(rho as Real);
                assert!(e > 0.0, "γ = {gamma}, r = {r}: e = {e}");
                // f32 pressure in the integrand: relative error ~1e-6 of p.
                assert!(
                    (e - integral).abs() <= 1e-5 * integral,
                    "γ = {gamma}, r = {r}: e = {e}, ∫ = {integral}"
                );
            }
        }
    }
}
