//! The von Mises elasto-plastic solid of \[Li\] (Li, Gao, He, Cheng, Li, Hao, Qin, §4.2, after
//! O'Brien et al. 2002 / Müller & Gross 2004) with an elastic limit γ₁, a plastic limit γ₂ and
//! fracture, in the MPM form of ALGORITHM §6.3 with the corrections Li-L3, Li-L4 and Li-L5.
//!
//! # Model (ALGORITHM §6.3)
//!
//! ```text
//! F = R S (polar),  ε = S − I,  ε_e = ε − ε_p                      corotated small strain
//! s = 2G dev(ε_e)                    (choice D15: the Tait EOS carries the volume), or
//! s = 2G ε_e + λ tr(ε_e) I           (`volumetric: true`)
//! P = R s,  σ_extra = J̃⁻¹ sym(P Fᵀ) = J̃⁻¹ R sym(s S) Rᵀ   (dev of it with D15), J̃ = ρ₀/ρ̃ (D11)
//! fractured ⇒ σ_extra = 0
//! ```
//! with G = E/(2(1 + ν)) and λ = Eν/((1 + ν)(1 − 2ν)). Plastic flow at the end of each step
//! (in [`Rheology::commit`], with Fⁿ⁺¹):
//!
//! ```text
//! e′ = dev(ε − ε_p)                                  the ELASTIC strain (Li-L3)
//! if ‖e′‖_F > γ₁:  ε_trial = ε_p + (‖e′‖_F − γ₁)/‖e′‖_F · e′       (return to ‖e′‖_F = γ₁)
//!                  ε_p = ε_trial · min(1, γ₂/‖ε_trial‖_F);  fractured |= ‖ε_trial‖_F > γ₂
//! ```
//!
//! Corrections of \[Li\] applied here (ALGORITHM §6.3):
//! * **Li-L3**: the yield test uses the deviator of the *elastic* strain ε − ε_p (the paper uses
//!   the total strain, so plastic strain grew while a body was held at constant deformation; its
//!   C++ code used the previous step's elastic strain). Evaluated once per step, at commit.
//! * **Li-L4**: tensor shear strains with σ = λ tr(ε) I + 2Gε (the codes' Voigt C₃₃ = G halved
//!   the shear stress).
//! * **Li-L5**: ‖·‖_F counts the off-diagonal entries of the symmetric tensors twice.
//!
//! The symmetric part of J̃⁻¹PFᵀ is taken because s and S do not commute once ε_p ≠ 0 (the
//! skew part is of second order in the strain; a skew Cauchy stress would violate the balance
//! of angular momentum).
//!
//! # Deformation state and its integration (GS4-1, as [`su2021_unified`](super::su2021_unified))
//!
//! The model keeps its own deformation gradient F in its state ([`ElastoPlasticState`], `f64`),
//! advanced from the velocity gradient by the material ODE DF/Dt = L F with the same GS4-1
//! value/rate scheme as the polymer stress of §2.8 (a pair (F, Ḟ), Ḟ = DF/Dt):
//!
//! ```text
//! F̂  = F + W₁Λ₄Δt Ḟ                       predictor
//! ΔḞ = (L̃ F̂ − Ḟ) / W₁Λ₆                    explicit: the rate is bounded by |L̃|, no stiffness
//! F̃  = F̂ + W₂Λ₅Δt ΔḞ                       used for the stress at t_{n+W₁}
//! commit: F ← F + λ₄Δt Ḟ + λ₅Δt ΔḞ,  Ḟ ← Ḟ + ΔḞ;  then the plastic update with Fⁿ⁺¹
//! ```
//!
//! So only the particles of an elasto-plastic material carry F (they need no core
//! [`DeformationGradient`](crate::components::DeformationGradient)), the strain is kept in
//! `f64` (elastic limits of 10⁻³ are a few thousand `f32` ulps of F), and F is second-order
//! consistent with the stress integration. In the start-up rate evaluation (Δt = 0,
//! W₁Λ₆ = 1) the update sets Ḟ⁰ = L⁰F⁰ and leaves F unchanged (§2.14).
//!
//! # Stability data (§7.2)
//!
//! Shear modulus G (wave limit c² += (4/3 G + K)/ρ̃), bulk modulus K = λ + 2G/3 only with
//! `volumetric` (then c² = (λ + 2G)/ρ̃ on top of the Tait sound speed), no viscous part
//! (tangent viscosity 0) and no relaxation. A fractured particle contributes nothing.
//! Stiffness is real: \[Li\]'s tomato (E = 10⁷ Pa, ν = 0.42) has c ≈ 160 m/s at ρ = 1000, so
//! Δt ≈ 0.7Δx/160.
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use super::tensor::{deviator, frobenius_norm, polar_decomposition, sym, trace};
use super::{InvalidParameter, Rheology, RheologyContext, RheologyOutput};
use crate::material::FluidMaterial;
use bevy_ecs::prelude::Component;

/// Parameters of the von Mises elasto-plastic solid of \[Li\] §4.2 (one value per material in
/// [`RheologyTable`](super::RheologyTable)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Li2024ElastoPlastic {
    /// Young's modulus E \[Pa\] > 0.
    pub youngs_modulus: f64,
    /// Poisson's ratio ν ∈ (−1, ½).
    pub poisson_ratio: f64,
    /// Elastic limit γ₁ > 0 (dimensionless): the yield radius of ‖dev(ε − ε_p)‖_F.
    pub elastic_limit: f64,
    /// Plastic limit γ₂ ≥ γ₁ (dimensionless): the largest ‖ε_p‖_F; a plastic strain beyond it
    /// fractures the particle (its elastic stress vanishes for good). May be `inf` (no
    /// fracture, no cap).
    pub plastic_limit: f64,
    /// Whether the model also carries the volumetric response λ tr(ε_e) I (bulk modulus
    /// λ + 2G/3 on top of the material's Tait pressure). Default `false`: deviatoric stress
    /// only, the Tait equation of state carries the volume (choice D15).
    #[serde(default)]
    pub volumetric: bool,
}

impl Li2024ElastoPlastic {
    /// Young's modulus E \[Pa\], Poisson's ratio ν, elastic limit γ₁ and plastic limit γ₂;
    /// deviatoric (D15).
    pub fn new(
        youngs_modulus: f64,
        poisson_ratio: f64,
        elastic_limit: f64,
        plastic_limit: f64,
    ) -> Self {
        Self {
            youngs_modulus,
            poisson_ratio,
            elastic_limit,
            plastic_limit,
            volumetric: false,
        }
    }

    /// With (`true`) or without the volumetric term λ tr(ε_e) I.
    pub fn with_volumetric(mut self, volumetric: bool) -> Self {
        self.volumetric = volumetric;
        self
    }

    /// Shear modulus G = E/(2(1 + ν)) \[Pa\].
    pub fn shear_modulus(&self) -> f64 {
        self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))
    }

    /// Lamé's first parameter λ = Eν/((1 + ν)(1 − 2ν)) \[Pa\].
    pub fn lame_lambda(&self) -> f64 {
        let nu = self.poisson_ratio;
        self.youngs_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    }

    /// Bulk modulus λ + 2G/3 \[Pa\] of the volumetric term (used only with `volumetric`).
    pub fn bulk_modulus(&self) -> f64 {
        self.lame_lambda() + 2.0 / 3.0 * self.shear_modulus()
    }

    /// The extra Cauchy stress \[Pa\] at deformation gradient `f`, plastic strain `plastic_strain`
    /// and volume ratio J̃ = `volume_ratio` (of an unfractured particle). `None` if det F ≤ 0
    /// (no polar decomposition: inverted material).
    pub fn stress(&self, f: DMat3, plastic_strain: DMat3, volume_ratio: f64) -> Option<DMat3> {
        let (r, s) = polar_decomposition(f)?;
        let eps_e = s - DMat3::IDENTITY - plastic_strain;
        let g = self.shear_modulus();
        let s_rot = if self.volumetric {
            2.0 * g * eps_e + DMat3::from_diagonal(DVec3::splat(self.lame_lambda() * trace(eps_e)))
        } else {
            2.0 * g * deviator(eps_e)
        };
        // σ = J̃⁻¹ sym(P Fᵀ), P = R s_rot, F = R S.
        let sigma = r * sym(s_rot * s) * r.transpose() * (1.0 / volume_ratio);
        Some(if self.volumetric {
            sigma
        } else {
            deviator(sigma)
        })
    }

    /// The plastic update of §6.3 at deformation gradient `f` (Fⁿ⁺¹): returns the new plastic
    /// strain and whether the particle fractures. `None` if det F ≤ 0.
    pub fn plastic_update(&self, f: DMat3, plastic_strain: DMat3) -> Option<(DMat3, bool)> {
        let (_, s) = polar_decomposition(f)?;
        let e_dev = deviator(s - DMat3::IDENTITY - plastic_strain);
        let norm = frobenius_norm(e_dev);
        let g1 = self.elastic_limit;
        if norm <= g1 {
            return Some((plastic_strain, false));
        }
        let trial = plastic_strain + e_dev * ((norm - g1) / norm);
        let trial_norm = frobenius_norm(trial);
        let g2 = self.plastic_limit;
        if trial_norm > g2 {
            Some((trial * (g2 / trial_norm), true))
        } else {
            Some((trial, false))
        }
    }

    /// Checks the parameters (every violated constraint is listed).
    pub fn validate(&self) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        let mut bad = |field, constraint| e.push(InvalidParameter { field, constraint });
        let ym = self.youngs_modulus;
        if !(ym.is_finite() && ym > 0.0) {
            bad("youngs_modulus", "must be a finite number > 0 Pa (E)");
        }
        let nu = self.poisson_ratio;
        if !(nu.is_finite() && nu > -1.0 && nu < 0.5) {
            bad(
                "poisson_ratio",
                "must lie in the open interval (−1, 0.5) (ν; 0.5 is incompressible: λ = ∞)",
            );
        }
        let g1 = self.elastic_limit;
        let g1_ok = g1.is_finite() && g1 > 0.0;
        if !g1_ok {
            bad("elastic_limit", "must be a finite number > 0 (γ₁)");
        }
        let g2 = self.plastic_limit;
        if g2.is_nan() || g2 <= 0.0 {
            bad("plastic_limit", "must be > 0 (γ₂; may be inf: no fracture)");
        } else if g1_ok && g2 < g1 {
            bad(
                "plastic_limit",
                "must be ≥ elastic_limit (γ2 < γ1: the plastic limit lies inside the elastic one)",
            );
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

/// Per-particle state of [`Li2024ElastoPlastic`]: the model's own deformation gradient as a
/// GS4-1 pair (F, Ḟ = DF/Dt) with the step's increment ΔḞ (written by evaluate, consumed by
/// commit), the plastic strain ε_p (symmetric, in the corotated frame) and the fracture flag.
/// `f64` (as [`PolymerStress`](super::PolymerStress)).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct ElastoPlasticState {
    /// Deformation gradient F at t_n (relative to the particle's configuration when the
    /// model was attached).
    pub deformation: DMat3,
    /// Ḟ = DF/Dt at t_n \[1/s\].
    pub deformation_rate: DMat3,
    /// ΔḞ of the step being run \[1/s\] (0 outside a step).
    pub rate_increment: DMat3,
    /// Plastic strain ε_p at t_n (symmetric, deviatoric).
    pub plastic_strain: DMat3,
    /// True once ‖ε_p‖_F exceeded the plastic limit γ₂: the particle carries no elastic
    /// stress any more (it stays a liquid of the material's Tait pressure and viscosity).
    pub fractured: bool,
}

impl Default for ElastoPlasticState {
    /// Undeformed, at rest, no plastic strain (by hand: glam's `DMat3::default()` is the
    /// identity, which is right for F only).
    fn default() -> Self {
        Self {
            deformation: DMat3::IDENTITY,
            deformation_rate: DMat3::ZERO,
            rate_increment: DMat3::ZERO,
            plastic_strain: DMat3::ZERO,
            fractured: false,
        }
    }
}

/// The state travels with a particle that migrates between ranks.
impl crate::distributed::Travels for ElastoPlasticState {
    const WORDS: usize = 4 * 18 + 1;
    fn pack(&self, out: &mut Vec<u32>) {
        crate::distributed::push_dmat3s(
            out,
            [
                &self.deformation,
                &self.deformation_rate,
                &self.rate_increment,
                &self.plastic_strain,
            ],
        );
        out.push(u32::from(self.fractured));
    }
    fn unpack(w: &[u32]) -> Self {
        use crate::distributed::dmat3_at;
        Self {
            deformation: dmat3_at(w, 0),
            deformation_rate: dmat3_at(w, 1),
            rate_increment: dmat3_at(w, 2),
            plastic_strain: dmat3_at(w, 3),
            fractured: w[72] != 0,
        }
    }
}

impl Rheology for Li2024ElastoPlastic {
    const NAME: &'static str = "Li2024ElastoPlastic";

    type State = ElastoPlasticState;

    fn travel(world: &mut bevy_ecs::world::World) {
        crate::distributed::travel::<ElastoPlasticState>(world);
    }

    fn evaluate(&self, ctx: &RheologyContext, state: &mut ElastoPlasticState) -> RheologyOutput {
        let c = ctx.coefficients;
        let l = ctx.velocity_gradient.as_dmat3();
        let f_hat = state.deformation + (c.w1l4 * c.dt) * state.deformation_rate;
        let delta = (l * f_hat - state.deformation_rate) * (1.0 / c.w1l6);
        state.rate_increment = delta;
        if state.fractured {
            return RheologyOutput::default();
        }
        let f_tilde = f_hat + (c.w2l5 * c.dt) * delta;
        let Some(sigma) = self.stress(f_tilde, state.plastic_strain, ctx.volume_ratio as f64)
        else {
            // Inverted material: a non-finite stress stops the run with a failure report.
            return RheologyOutput {
                stress: glam::Mat3::from_cols_array(&[f32::NAN; 9]),
                ..RheologyOutput::default()
            };
        };
        RheologyOutput {
            stress: sigma.as_mat3(),
            tangent_viscosity: 0.0,
            shear_modulus: self.shear_modulus() as f32,
            bulk_modulus: if self.volumetric {
                self.bulk_modulus() as f32
            } else {
                0.0
            },
            relaxation_rate: 0.0,
        }
    }

    fn commit(&self, ctx: &RheologyContext, state: &mut ElastoPlasticState) {
        let c = ctx.coefficients;
        state.deformation +=
            (c.l4 * c.dt) * state.deformation_rate + (c.l5 * c.dt) * state.rate_increment;
        state.deformation_rate += state.rate_increment;
        state.rate_increment = DMat3::ZERO;
        if state.fractured {
            return;
        }
        // det F ≤ 0 is reported by the next evaluate (non-finite stress).
        if let Some((eps_p, fractured)) =
            self.plastic_update(state.deformation, state.plastic_strain)
        {
            state.plastic_strain = eps_p;
            state.fractured = fractured;
        }
    }

    fn validate(&self, _material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        Li2024ElastoPlastic::validate(self)
    }
}
