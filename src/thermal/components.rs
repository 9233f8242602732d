//! Thermal particle components (ALGORITHM §3.4, §4.1). Only particles of heated materials carry
//! them; a scene without heat has none of them on any particle.
use bevy_ecs::prelude::*;

use crate::math::Real;

/// Temperature T_p and its material rate Ṫ_p (the GS4 value/rate pair of §3.2), in the scene's
/// temperature unit (the \[Su21\] examples use normalised temperatures, T_m = 0.1).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct Temperature {
    /// T_p.
    pub value: Real,
    /// DT/Dt.
    pub rate: Real,
}

/// The non-Fourier flux divergence d_p = ∇·q^NL and its rate ḋ_p (choice D9, §3.1).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct FluxDivergence {
    /// d_p.
    pub value: Real,
    /// Dd/Dt.
    pub rate: Real,
}

/// Predicted temperature T̂_p at t_{n+W₁} (§2.4, §3.4); phase index and temperature-dependent
/// viscosity read it. Written by the thermal predictor.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PredictedTemperature(pub Real);

/// Defined with the particle components (the step reads it: `integrator.solid_motion`).
pub use crate::components::PhaseIndex;

/// The value/rate pairs travel with a particle that migrates to another rank (bit for bit).
macro_rules! value_rate_travels {
    ($($t:ty),*) => {$(
        impl crate::distributed::Travels for $t {
            const WORDS: usize = 2;
            fn pack(&self, out: &mut Vec<u32>) {
                out.extend([self.value.to_bits(), self.rate.to_bits()]);
            }
            fn unpack(w: &[u32]) -> Self {
                Self {
                    value: Real::from_bits(w[0]),
                    rate: Real::from_bits(w[1]),
                }
            }
        }
    )*};
}

value_rate_travels!(Temperature, FluxDivergence);

impl crate::distributed::Travels for PredictedTemperature {
    const WORDS: usize = 1;
    fn pack(&self, out: &mut Vec<u32>) {
        out.push(self.0.to_bits());
    }
    fn unpack(w: &[u32]) -> Self {
        Self(Real::from_bits(w[0]))
    }
}
