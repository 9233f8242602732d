//! The compressible neo-Hookean solid of \[Su21\] (§4, eq. 14) in the decoupled form of
//! ALGORITHM §4.2, as a material of its own: an elastic solid whose stress comes from the
//! core's deformation gradient F (§2.13, choice D7).
//!
//! # Model (ALGORITHM §4.2, choice D11)
//!
//! ```text
//! σ̃_extra = (G/J̃) dev(B̄) + ½K (J̃ − 1/J̃) I,   B̄ = det(F̃)^{−2/3} F̃F̃ᵀ,   J̃ = ρ₀/ρ̃
//! ```
//! The first term is \[Su21\]'s G J^{−5/3} B′, the isochoric neo-Hookean Cauchy stress; its
//! volume J̃ is taken from the density (one consistent volume measure, D11) while the isochoric
//! stretch B̄ comes from F̃. The volumetric response is the material's Tait pressure (§4.2: "the
//! volumetric part is the (shared) Tait pressure"); an optional extra bulk modulus K adds the
//! volumetric stress of U(J) = ½K(½(J² − 1) − ln J) (Simo–Miehe), whose small-strain limit is
//! K(J − 1). With K = 0 (default) the linearised solid has the Lamé constants μ = G and
//! λ = K_Tait − 2G/3 (K_Tait = ρ₀c₀²); with K > 0, λ = K_Tait + K − 2G/3.
//!
//! # Deformation gradient
//!
//! The model reads F̃ from the core ([`PredictedDeformationGradient`](crate::components::PredictedDeformationGradient),
//! advanced by §2.4/§2.13). [`Rheology::NEEDS_DEFORMATION_GRADIENT`] is true, so
//! [`attach_model`](super::attach_model) gives the material's particles a
//! [`DeformationGradient`](crate::components::DeformationGradient) (F = I: the reference
//! configuration is the one at attachment) unless they carry one already. Particles spawned
//! later need `DeformationGradient` and `PredictedDeformationGradient` in their bundle too.
//! No phase change here (choice D12 does not apply): the material is always solid.
//!
//! # Stability data (§4.2, §7.2)
//!
//! Shear modulus (G/J̃)·max(1, λ_max(B̄)): G in the reference state, raised with the stretch
//! (the incremental shear stiffness of a stretched neo-Hookean solid grows like the largest
//! eigenvalue of B̄), so c_s² = (K_Tait + K + 4/3 G_eff)/ρ̃. Bulk modulus ½K(J̃ + 1/J̃) (the
//! tangent J dp/dJ of the volumetric term). No viscous part, no relaxation.
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use super::tensor::{deviator, symmetric_eigenvalues};
use super::{InvalidParameter, Rheology, RheologyContext, RheologyOutput};
use crate::material::FluidMaterial;
use bevy_ecs::prelude::Component;

/// Parameters of the neo-Hookean solid (one value per material in
/// [`RheologyTable`](super::RheologyTable)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NeoHookean {
    /// Shear modulus G (μ_s) \[Pa\] > 0.
    pub shear_modulus: f64,
    /// Extra bulk modulus K \[Pa\] ≥ 0 on top of the material's Tait pressure. Default 0 (the
    /// Tait equation carries the volume, ALGORITHM §4.2).
    #[serde(default)]
    pub bulk_modulus: f64,
}

impl NeoHookean {
    /// Shear modulus G \[Pa\]; the Tait pressure carries the volume.
    pub fn new(shear_modulus: f64) -> Self {
        Self {
            shear_modulus,
            bulk_modulus: 0.0,
        }
    }

    /// From Lamé constants μ, λ \[Pa\] of the extra stress: G = μ, K = λ + 2μ/3 (needs
    /// λ ≥ −2μ/3, checked by [`validate`](Self::validate) as K ≥ 0).
    pub fn from_lame(mu: f64, lambda: f64) -> Self {
        Self {
            shear_modulus: mu,
            bulk_modulus: lambda + 2.0 / 3.0 * mu,
        }
    }

    /// From Young's modulus E \[Pa\] and Poisson's ratio ν ∈ (−1, ½) of the extra stress.
    pub fn from_young(youngs_modulus: f64, poisson_ratio: f64) -> Self {
        let nu = poisson_ratio;
        Self {
            shear_modulus: youngs_modulus / (2.0 * (1.0 + nu)),
            bulk_modulus: youngs_modulus / (3.0 * (1.0 - 2.0 * nu)),
        }
    }

    /// With an extra bulk modulus K \[Pa\].
    pub fn with_bulk_modulus(mut self, bulk_modulus: f64) -> Self {
        self.bulk_modulus = bulk_modulus;
        self
    }

    /// The extra Cauchy stress \[Pa\] at deformation gradient `f` and volume ratio
    /// J̃ = `volume_ratio`, and the effective shear modulus of the stability estimate. `None`
    /// if det F ≤ 0 (inverted material).
    pub fn stress(&self, f: DMat3, volume_ratio: f64) -> Option<(DMat3, f64)> {
        let det = f.determinant();
        if !(det > 0.0 && det.is_finite()) {
            return None;
        }
        let b_bar = (f * f.transpose()) * det.powf(-2.0 / 3.0);
        let j = volume_ratio;
        let g = self.shear_modulus;
        let mut sigma = deviator(b_bar) * (g / j);
        if self.bulk_modulus != 0.0 {
            sigma += DMat3::from_diagonal(DVec3::splat(0.5 * self.bulk_modulus * (j - 1.0 / j)));
        }
        let stretch = symmetric_eigenvalues(b_bar)[0].max(1.0);
        Some((sigma, g / j * stretch))
    }

    /// Checks the parameters (every violated constraint is listed).
    pub fn validate(&self) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        let g = self.shear_modulus;
        if !(g.is_finite() && g > 0.0) {
            e.push(InvalidParameter {
                field: "shear_modulus",
                constraint: "must be a finite number > 0 Pa (μ_s)",
            });
        }
        let k = self.bulk_modulus;
        if !(k.is_finite() && k >= 0.0) {
            e.push(InvalidParameter {
                field: "bulk_modulus",
                constraint: "must be a finite number ≥ 0 Pa (K = λ + 2μ/3, i.e. λ ≥ −2μ/3)",
            });
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

/// Marker state of [`NeoHookean`]: the particle uses the model (its history is the core's
/// [`DeformationGradient`](crate::components::DeformationGradient)).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NeoHookeanSolid;

/// The marker travels with a particle that migrates between ranks.
impl crate::distributed::Travels for NeoHookeanSolid {
    const WORDS: usize = 0;
    fn pack(&self, _: &mut Vec<u32>) {}
    fn unpack(_: &[u32]) -> Self {
        Self
    }
}

impl Rheology for NeoHookean {
    const NAME: &'static str = "NeoHookean";

    type State = NeoHookeanSolid;

    fn travel(world: &mut bevy_ecs::world::World) {
        crate::distributed::travel::<NeoHookeanSolid>(world);
    }

    const NEEDS_DEFORMATION_GRADIENT: bool = true;

    fn evaluate(&self, ctx: &RheologyContext, _state: &mut NeoHookeanSolid) -> RheologyOutput {
        let j = ctx.volume_ratio as f64;
        let result = ctx
            .deformation_gradient
            .and_then(|f| self.stress(f.as_dmat3(), j));
        let Some((sigma, g_eff)) = result else {
            // Inverted material (det F ≤ 0): a non-finite stress stops the run with a report.
            return RheologyOutput {
                stress: glam::Mat3::from_cols_array(&[f32::NAN; 9]),
                ..RheologyOutput::default()
            };
        };
        RheologyOutput {
            stress: sigma.as_mat3(),
            tangent_viscosity: 0.0,
            shear_modulus: g_eff as f32,
            bulk_modulus: (0.5 * self.bulk_modulus * (j + 1.0 / j)) as f32,
            relaxation_rate: 0.0,
        }
    }

    fn commit(&self, _ctx: &RheologyContext, _state: &mut NeoHookeanSolid) {}

    fn validate(&self, _material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        NeoHookean::validate(self)
    }
}
