//! The unified viscoelastic stress of \[Su21\] (Su, Xue, Han, Jiang, Aanjaneya 2021, §4.4 and
//! eqs. 10–11, 33–34, 37) in the corrected form of ALGORITHM §2.8: the non-local (polymer)
//! stress σᴺᴸ of an extended Pom-Pom (XPP) fluid, with Oldroyd-B, UCM and Newtonian as limits.
//!
//! # Model (choice D3: Verbeeten, Peters & Baaijens 2001 single-equation XPP)
//!
//! σ̇ = Dσ/Dt = H(σ, L) = Lσ + σLᵀ + R(σ, D), with
//! R = 2G₀D − (1/λ_b)\[(α/G₀)σ·σ + f σ + G₀(f − 1)I\],
//! f = 2(λ_b/λ_s)(1 − 1/Λ) + (1 − α tr(σ·σ)/(3G₀²))/Λ²,  Λ = √(1 + tr σ/(3G₀)),
//! λ_s = λ₀ₛ e^{−ν(Λ−1)}, ν = 2/q, and the plateau modulus G₀ = (1 − F_v)μ/λ_b (or given).
//! The polymer viscosity is η_p = G₀λ_b; the core already applies the local part 2F_vμD̃.
//!
//! | limit | parameters | constructor |
//! |---|---|---|
//! | XPP | α ≥ 0, q ≥ 1, f Full | [`Su2021Unified::xpp`] |
//! | Oldroyd-B: σ + λ_b σ^∇ = 2(1−F_v)μD | α = 0, f ≡ 1 | [`Su2021Unified::oldroyd_b`] |
//! | UCM | Oldroyd-B with F_v = 0 | [`Su2021Unified::ucm`] |
//! | Newtonian | F_v = 1 (σᴺᴸ ≡ 0) | [`Su2021Unified::newtonian`] — do not attach it |
//!
//! # Integration (GS4-1 per particle, linearly implicit relaxation; choices D1, D8)
//!
//! ```text
//! σ̂  = σ + W₁Λ₄Δt σ̇                                   predictor
//! K  = (f + 2α‖σ̂‖₂/G₀)/λ_b                            scalar relaxation stiffness
//! Δσ̇ = sym(H(σ̂, L̃) − σ̇) / (W₁Λ₆ + η_σ W₂Λ₅Δt K)      η_σ = 1 (D8) or 0
//! σ̃  = σ̂ + W₂Λ₅Δt Δσ̇                                  returned stress at t_{n+W₁}
//! commit: σ ← σ + λ₄Δt σ̇ + λ₅Δt Δσ̇,  σ̇ ← σ̇ + Δσ̇
//! ```
//! (Errata E5, E6: one combined increment; splitting the upper-convected part from the
//! relaxation as printed cancels the convected term.) The convective term u·∇σ is carried by the
//! particle motion (D1: σᴺᴸ lives on particles only). In the start-up rate evaluation (Δt = 0,
//! W₁Λ₆ = 1) the update gives σ̇⁰ = H(σ⁰, L⁰) (§2.14).
//!
//! # Under a first-order scheme: the convected update (choice D22)
//!
//! When the mechanics run symplectic Euler or backward-Euler viscosity
//! ([`FirstOrderCoefficients::first_order_mechanics`](super::FirstOrderCoefficients::first_order_mechanics)),
//! the force takes σⁿ and the commit advances the conformation c = I + σ/G₀ multiplicatively:
//!
//! ```text
//! A    = (I − ΔtL/2)⁻¹(I + ΔtL/2)                 Cayley map of ΔtL (L of the commit's context)
//! σ*   = AσAᵀ + G₀(AAᵀ − I)                       c* = AcAᵀ: the upper-convected part and 2G₀D
//! σⁿ⁺¹ = σ* + Δt R₀(σ*) / (1 + η_σ Δt K_F(σ*))     R₀ = R without 2G₀D (the relaxation),
//!                                                  K_F = K with ‖σ*‖_F for ‖σ*‖₂
//! σ̇ⁿ⁺¹ = (σⁿ⁺¹ − σⁿ)/Δt
//! ```
//! AcAᵀ is positive definite whenever c is, and A is a rotation when L is a spin, so the
//! conformation stays physical at any ‖L‖Δt. The GS4-1 pair above leaves the upper-convected
//! term explicit: at the one-cell-per-step time steps of the game liquids (‖L‖Δt ≈ 0.7 in a
//! splash) it made det c negative and the slime blew up (BENCHMARKS.md (h)).
//!
//! # Clamps (choice D4)
//!
//! 1 + tr σ/(3G₀) is clamped to \[Λ_min², Λ_max²\] with Λ_min = 10⁻³ (strong compression or α > 0
//! can make it ≤ 0). For the upper bound D4 reads Λ_max = q (the pom-pom maximum stretch), to
//! keep e^{ν(Λ−1)} finite. That bound changes the model: it does not reproduce the XPP oracle
//! (`xpp_single_mode_startup_shear.csv`, q = 1 blows up at Wi ≥ 1). The default here is
//! therefore [`StretchLimit::Unbounded`], which only caps ν(Λ−1) at the overflow of `exp`.
//! [`StretchLimit::Arms`] keeps the literal D4 clamp. G₀ = 0 selects the Oldroyd-B branch
//! (α must then be 0).
//!
//! # Stability data (§7.2)
//!
//! Shear modulus G₀ + ‖σ̃‖₂ (the upper-convected term stiffens with stress), no explicit viscous
//! part, relaxation rate K only when η_σ = 0 (with η_σ = 1 the relaxation is A-stable).
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use super::tensor::{frobenius_norm, sym, symmetric_spectral_norm, trace};
use super::{InvalidParameter, ParameterWarning, Rheology, RheologyContext, RheologyOutput};
use crate::material::FluidMaterial;
use bevy_ecs::prelude::Component;

/// Λ_min of choice D4.
pub const MIN_STRETCH: f64 = 1e-3;

/// Largest exponent ν(Λ − 1) allowed in e^{ν(Λ−1)} (e^{700} ≈ 1e304, below f64 overflow).
pub const MAX_STRETCH_EXPONENT: f64 = 700.0;

/// How the XPP function f is evaluated (ALGORITHM §2.8 `xpp_f_mode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum XppFMode {
    /// The full Verbeeten f(σ).
    Full,
    /// f ≡ 1 (the model switch of the paper's "f = 1" and of the Su group's MATLAB code):
    /// with α = 0 this is Oldroyd-B.
    One,
}

/// Where the plateau modulus G₀ comes from (choice D3).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum PlateauModulus {
    /// G₀ = (1 − F_v)μ/λ_b: the polymer viscosity (1 − F_v)μ spread over λ_b.
    Derived,
    /// A given G₀ \[Pa\] ≥ 0 (e.g. \[Su21\] Table 4 rows whose G₀ ≠ (1 − F_v)μ/λ_b); 0 selects the
    /// Oldroyd-B branch with zero forcing.
    User(f64),
}

/// Upper bound of the backbone stretch Λ (choice D4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum StretchLimit {
    /// Only ν(Λ − 1) ≤ [`MAX_STRETCH_EXPONENT`], so that e^{ν(Λ−1)} stays finite: Verbeeten's
    /// XPP, which has no maximum stretch (the default). Reproduces the XPP start-up oracle for
    /// every q.
    Unbounded,
    /// Λ ≤ q, the maximum stretch of the original pom-pom model (the literal reading of
    /// ALGORITHM D4). **Changes the model** once Λ reaches q: with Λ pinned at q = 1,
    /// f = 1 − α tr(σ·σ)/(3G₀²) can turn negative and the stress grows without bound (q = 1
    /// start-up shear at Wi = 1 blows up, see `tests/it/rheology.rs`). Only for comparison with
    /// codes that clamp.
    Arms,
}

/// Parameters of the unified XPP / Oldroyd-B / UCM polymer stress of \[Su21\] (one value per
/// material in [`RheologyTable`](super::RheologyTable)).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Su2021Unified {
    /// Total viscosity μ \[Pa·s\] ≥ 0 whose non-local share (1 − F_v)μ is the polymer viscosity.
    /// `None` (default): the material's `viscosity`.
    pub viscosity: Option<f64>,
    /// Local fraction F_v ∈ \[0, 1\]. `None` (default): the material's `local_fraction`, which is
    /// what the core uses for 2F_vμD̃. A given value must equal the material's (checked by
    /// [`validate_for`](Su2021Unified::validate_for)), so the split stays consistent.
    pub local_fraction: Option<f64>,
    /// Backbone relaxation time λ_b \[s\] > 0 (the Weissenberg time).
    pub backbone_relaxation_time: f64,
    /// Stretch relaxation time λ₀ₛ \[s\] > 0 (used with [`XppFMode::Full`]; \[Su21\]'s
    /// λ_b/λ₀ₛ ≈ 1–11).
    pub stretch_relaxation_time: f64,
    /// Plateau modulus G₀. Default [`PlateauModulus::Derived`].
    pub modulus: PlateauModulus,
    /// Anisotropy α ≥ 0 (erratum E4; physical range 0–0.5, \[Su21\] uses up to 100, which is
    /// stiff: keep `implicit_relaxation`).
    pub anisotropy: f64,
    /// Number of arms q ≥ 1 (\[Su21\]'s Q); ν = 2/q.
    pub arms: f64,
    /// Full f or f ≡ 1.
    pub f_mode: XppFMode,
    /// η_σ of choice D8: true (default) treats the relaxation linearly implicitly (no Δt limit
    /// from λ_b); false is fully explicit, stable for Δt ≤ z_crit/K.
    pub implicit_relaxation: bool,
    /// Upper bound of Λ. Default [`StretchLimit::Unbounded`].
    pub stretch_limit: StretchLimit,
}

impl Su2021Unified {
    /// XPP with relaxation times λ_b, λ₀ₛ \[s\], anisotropy α and q arms; μ and F_v from the
    /// material, G₀ derived, full f, implicit relaxation.
    pub fn xpp(
        backbone_relaxation_time: f64,
        stretch_relaxation_time: f64,
        anisotropy: f64,
        arms: f64,
    ) -> Self {
        Self {
            viscosity: None,
            local_fraction: None,
            backbone_relaxation_time,
            stretch_relaxation_time,
            modulus: PlateauModulus::Derived,
            anisotropy,
            arms,
            f_mode: XppFMode::Full,
            implicit_relaxation: true,
            stretch_limit: StretchLimit::Unbounded,
        }
    }

    /// Oldroyd-B (α = 0, f ≡ 1) with relaxation time λ_b \[s\]: σ + λ_b σ^∇ = 2(1 − F_v)μD.
    pub fn oldroyd_b(relaxation_time: f64) -> Self {
        Self {
            f_mode: XppFMode::One,
            ..Self::xpp(relaxation_time, relaxation_time, 0.0, 1.0)
        }
    }

    /// Upper-convected Maxwell: Oldroyd-B with F_v = 0 (the material's `local_fraction` must
    /// be 0 too), so G₀ = μ/λ_b.
    pub fn ucm(relaxation_time: f64) -> Self {
        Self {
            local_fraction: Some(0.0),
            ..Self::oldroyd_b(relaxation_time)
        }
    }

    /// The Newtonian limit F_v = 1: σᴺᴸ ≡ 0. Only for completeness and tests — a Newtonian
    /// material needs no model: do not put it in the table, so its particles carry no state
    /// and cost nothing.
    pub fn newtonian() -> Self {
        Self {
            local_fraction: Some(1.0),
            ..Self::oldroyd_b(1.0)
        }
    }

    /// With an own total viscosity μ \[Pa·s\].
    pub fn with_viscosity(mut self, viscosity: f64) -> Self {
        self.viscosity = Some(viscosity);
        self
    }

    /// With a given local fraction F_v.
    pub fn with_local_fraction(mut self, local_fraction: f64) -> Self {
        self.local_fraction = Some(local_fraction);
        self
    }

    /// With a given plateau modulus G₀ \[Pa\].
    pub fn with_modulus(mut self, modulus: f64) -> Self {
        self.modulus = PlateauModulus::User(modulus);
        self
    }

    /// With the given f mode.
    pub fn with_f_mode(mut self, f_mode: XppFMode) -> Self {
        self.f_mode = f_mode;
        self
    }

    /// With η_σ = 1 (`true`) or 0.
    pub fn with_implicit_relaxation(mut self, implicit: bool) -> Self {
        self.implicit_relaxation = implicit;
        self
    }

    /// With the given stretch limit.
    pub fn with_stretch_limit(mut self, limit: StretchLimit) -> Self {
        self.stretch_limit = limit;
        self
    }

    /// The coefficients of the rate function for `material` (resolves μ, F_v and G₀).
    #[inline]
    pub fn resolve(&self, material: &FluidMaterial) -> XppCoefficients {
        let mu = self.viscosity.unwrap_or(material.viscosity as f64);
        let fv = self
            .local_fraction
            .unwrap_or(material.local_fraction as f64);
        let lambda_b = self.backbone_relaxation_time;
        let g0 = match self.modulus {
            PlateauModulus::Derived => (1.0 - fv) * mu / lambda_b,
            PlateauModulus::User(g) => g,
        };
        let nu = 2.0 / self.arms;
        let max_stretch = match self.stretch_limit {
            StretchLimit::Arms => self.arms,
            StretchLimit::Unbounded => 1.0 + MAX_STRETCH_EXPONENT / nu,
        };
        // Divisions by per-material constants are done here once, so that the per-particle
        // chain of `rate_and_norm` multiplies (G₀ = 0 takes the Oldroyd-B branch, choice D4,
        // which uses none of them).
        let inv_g0 = if g0 > 0.0 { 1.0 / g0 } else { 0.0 };
        XppCoefficients {
            modulus: g0,
            inv_backbone_time: 1.0 / lambda_b,
            time_ratio: lambda_b / self.stretch_relaxation_time,
            anisotropy: self.anisotropy,
            nu,
            full_f: self.f_mode == XppFMode::Full,
            stretch_sq_range: (MIN_STRETCH * MIN_STRETCH, max_stretch * max_stretch),
            inv_three_modulus: inv_g0 * (1.0 / 3.0),
            anisotropy_over_modulus: self.anisotropy * inv_g0,
            anisotropy_over_three_modulus_sq: self.anisotropy * inv_g0 * inv_g0 * (1.0 / 3.0),
        }
    }

    /// Checks the parameters on their own (every violated constraint is listed). See also
    /// [`validate_for`](Self::validate_for), which adds the checks that need the material.
    pub fn validate(&self) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        let mut bad = |field, constraint| e.push(InvalidParameter { field, constraint });
        if let Some(mu) = self.viscosity
            && !(mu.is_finite() && mu >= 0.0)
        {
            bad("viscosity", "must be a finite number ≥ 0 Pa·s");
        }
        if let Some(fv) = self.local_fraction
            && !(fv.is_finite() && (0.0..=1.0).contains(&fv))
        {
            bad("local_fraction", "must lie in [0, 1]");
        }
        let lb = self.backbone_relaxation_time;
        if !(lb.is_finite() && lb > 0.0) {
            bad("backbone_relaxation_time", "must be a finite number > 0 s");
        }
        let ls = self.stretch_relaxation_time;
        if self.f_mode == XppFMode::Full && !(ls.is_finite() && ls > 0.0) {
            bad(
                "stretch_relaxation_time",
                "must be a finite number > 0 s (with f_mode Full)",
            );
        }
        if let PlateauModulus::User(g) = self.modulus
            && !(g.is_finite() && g >= 0.0)
        {
            bad("modulus", "must be a finite number ≥ 0 Pa");
        }
        let a = self.anisotropy;
        if !(a.is_finite() && a >= 0.0) {
            bad("anisotropy", "must be a finite number ≥ 0 (erratum E4)");
        }
        if !(self.arms.is_finite() && self.arms >= 1.0) {
            bad("arms", "must be a finite number ≥ 1");
        }
        let zero_modulus = match self.modulus {
            PlateauModulus::User(g) => g == 0.0,
            PlateauModulus::Derived => {
                self.viscosity == Some(0.0) || self.local_fraction == Some(1.0)
            }
        };
        if zero_modulus && a > 0.0 {
            bad(
                "anisotropy",
                "must be 0 when G₀ = 0 (α/G₀ and Λ are undefined; G₀ = 0 selects the Oldroyd-B branch, choice D4)",
            );
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }

    /// [`validate`](Self::validate) plus the checks against the material the model is used
    /// with: a given F_v must equal the material's, and α must be 0 if the resolved G₀ is 0.
    pub fn validate_for(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        let mut e = self.validate().err().unwrap_or_default();
        if let Some(fv) = self.local_fraction
            && fv != material.local_fraction as f64
        {
            e.push(InvalidParameter {
                field: "local_fraction",
                constraint: "must equal the material's local_fraction (the core applies 2F_vμD with the material's value; a different F_v double-counts or loses viscosity)",
            });
        }
        if self.resolve(material).modulus == 0.0
            && self.anisotropy > 0.0
            && !e.iter().any(|x| x.field == "anisotropy")
        {
            e.push(InvalidParameter {
                field: "anisotropy",
                constraint: "must be 0 when G₀ = 0 (here G₀ = (1 − F_v)μ/λ_b = 0 for this material; α/G₀ and Λ are undefined)",
            });
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

/// The XPP rate function with resolved coefficients (from [`Su2021Unified::resolve`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct XppCoefficients {
    /// G₀ \[Pa\].
    pub modulus: f64,
    /// 1/λ_b \[1/s\].
    pub inv_backbone_time: f64,
    /// λ_b/λ₀ₛ.
    pub time_ratio: f64,
    /// α.
    pub anisotropy: f64,
    /// ν = 2/q.
    pub nu: f64,
    /// Full f (else f ≡ 1).
    pub full_f: bool,
    /// Clamp range \[Λ_min², Λ_max²\] of 1 + tr σ/(3G₀).
    pub stretch_sq_range: (f64, f64),
    /// 1/(3G₀) (0 if G₀ = 0), derived by [`Su2021Unified::resolve`].
    inv_three_modulus: f64,
    /// α/G₀ (0 if G₀ = 0).
    anisotropy_over_modulus: f64,
    /// α/(3G₀²) (0 if G₀ = 0).
    anisotropy_over_three_modulus_sq: f64,
}

impl XppCoefficients {
    /// σ·σ on its six independent entries (00, 11, 22, 01, 02, 12) and f(σ) (§2.8), for
    /// [`rate_and_norm`](Self::rate_and_norm) and the relaxation of the convected update.
    /// Needs G₀ > 0.
    #[inline(always)]
    fn square_and_f(&self, sigma: DMat3) -> ([f64; 6], f64) {
        let (s00, s11, s22) = (sigma.x_axis.x, sigma.y_axis.y, sigma.z_axis.z);
        let (s01, s02, s12) = (sigma.y_axis.x, sigma.z_axis.x, sigma.z_axis.y);
        // σ·σ: (σσ)_ij = (σ_i0 σ_0j + σ_i1 σ_1j) + σ_i2 σ_2j.
        let ss00 = (s00 * s00 + s01 * s01) + s02 * s02;
        let ss11 = (s01 * s01 + s11 * s11) + s12 * s12;
        let ss22 = (s02 * s02 + s12 * s12) + s22 * s22;
        let ss01 = (s00 * s01 + s01 * s11) + s02 * s12;
        let ss02 = (s00 * s02 + s01 * s12) + s02 * s22;
        let ss12 = (s01 * s02 + s11 * s12) + s12 * s22;
        let f = if self.full_f {
            let (lo, hi) = self.stretch_sq_range;
            // Λ = √(1 + tr σ/(3G₀)), clamped (choice D4).
            let stretch_sq = (1.0 + trace(sigma) * self.inv_three_modulus).clamp(lo, hi);
            let stretch = stretch_sq.sqrt();
            // 1/Λ² and 1/Λ = Λ/Λ²: the division runs alongside the square root.
            let inv_stretch_sq = 1.0 / stretch_sq;
            let inv_stretch = stretch * inv_stretch_sq;
            // λ_b/λ_s = (λ_b/λ₀ₛ) e^{ν(Λ−1)}.
            let ratio = self.time_ratio * (self.nu * (stretch - 1.0)).exp();
            // f = 2(λ_b/λ_s)(1 − 1/Λ) + (1 − α tr(σ·σ)/(3G₀²))/Λ².
            2.0 * ratio * (1.0 - inv_stretch)
                + (1.0 - ((ss00 + ss11) + ss22) * self.anisotropy_over_three_modulus_sq)
                    * inv_stretch_sq
        } else {
            1.0
        };
        ([ss00, ss11, ss22, ss01, ss02, ss12], f)
    }

    /// The relaxation R₀(σ) = −(1/λ_b)[(α/G₀)σ·σ + fσ + G₀(f − 1)I] \[Pa/s\] (R without 2G₀D)
    /// and the stiffness K_F = (f + 2α‖σ‖_F/G₀)/λ_b \[1/s\]: [`rate`](Self::rate) at L = 0,
    /// without the products with L, and with the Frobenius norm, an upper bound of ‖σ‖₂ that
    /// costs no eigenvalue solve. (K only damps the linearly implicit increment
    /// ΔtR₀/(1 + ΔtK), at O(Δt²): a larger K keeps it stable and first order.)
    #[inline(always)]
    pub fn relaxation(&self, sigma: DMat3) -> (DMat3, f64) {
        let (r, k) = self.relaxation_sym(Sym::of(sigma));
        (r.to_mat(), k)
    }

    /// [`relaxation`](Self::relaxation) on the six entries of a symmetric σ.
    #[inline(always)]
    fn relaxation_sym(&self, sigma: Sym) -> (Sym, f64) {
        let g0 = self.modulus;
        let inv_lb = self.inv_backbone_time;
        if g0 == 0.0 {
            return (Sym(sigma.0.map(|s| -inv_lb * s)), inv_lb);
        }
        let ([ss00, ss11, ss22, ss01, ss02, ss12], f) = self.square_and_f(sigma.to_mat());
        // ‖σ‖_F² = tr(σ·σ).
        let frobenius = ((ss00 + ss11) + ss22).sqrt();
        let iso = g0 * (f - 1.0);
        let a = self.anisotropy_over_modulus;
        let [s00, s11, s22, s01, s02, s12] = sigma.0;
        let r = |bracket: f64| -inv_lb * bracket;
        let relaxation = Sym([
            r((a * ss00 + f * s00) + iso),
            r((a * ss11 + f * s11) + iso),
            r((a * ss22 + f * s22) + iso),
            r(a * ss01 + f * s01),
            r(a * ss02 + f * s02),
            r(a * ss12 + f * s12),
        ]);
        let k = (f + 2.0 * self.anisotropy_over_modulus * frobenius) * inv_lb;
        (relaxation, k)
    }

    /// The material rate H(σ, L) = Lσ + σLᵀ + R(σ, D) \[Pa/s\] and the scalar relaxation
    /// stiffness K = (f + 2α‖σ‖₂/G₀)/λ_b \[1/s\] (ALGORITHM §2.8).
    pub fn rate(&self, sigma: DMat3, l: DMat3) -> (DMat3, f64) {
        let (h, k, _) = self.rate_and_norm(sigma, l);
        (h, k)
    }

    /// [`rate`](Self::rate) plus ‖σ‖₂ when it was computed on the way (α > 0 and G₀ > 0), so
    /// that callers needing the norm too do not pay for a second eigenvalue solve. `sigma` must
    /// be symmetric (as σᴺᴸ always is).
    ///
    /// Per particle this is one long dependency chain of divisions, square roots and an `exp`
    /// (BENCHMARKS.md (e)): ‖σ‖₂ (the longest link, through the closed-form eigenvalues) is
    /// started first and runs alongside f; divisions by the per-material constants G₀, 3G₀,
    /// 3G₀² are multiplications by reciprocals from [`Su2021Unified::resolve`] (this changes
    /// results at round-off level only).
    #[inline(always)]
    pub fn rate_and_norm(&self, sigma: DMat3, l: DMat3) -> (DMat3, f64, Option<f64>) {
        let g0 = self.modulus;
        let inv_lb = self.inv_backbone_time;
        if g0 == 0.0 {
            // Choice D4: Oldroyd-B branch with zero forcing (Λ and α/G₀ undefined).
            // Upper-convected part Lσ + σLᵀ = Lσ + (Lσ)ᵀ (σ symmetric: the same sums).
            let l_sigma = l * sigma;
            return (l_sigma + l_sigma.transpose() - inv_lb * sigma, inv_lb, None);
        }
        let alpha = self.anisotropy;
        // ‖σ‖₂ (for K below) only when it enters K, i.e. α > 0.
        let norm = (alpha > 0.0).then(|| symmetric_spectral_norm(sigma));
        // The symmetric tensors σ·σ, D, R and H are formed on their six independent entries
        // (upper triangle, then mirrored), written out by hand so that they stay in registers:
        // each entry is the same sum, in the same order, as glam's full 3×3 product, so the
        // result is bit for bit that of the full matrices.
        let (s00, s11, s22) = (sigma.x_axis.x, sigma.y_axis.y, sigma.z_axis.z);
        let (s01, s02, s12) = (sigma.y_axis.x, sigma.z_axis.x, sigma.z_axis.y);
        let ([ss00, ss11, ss22, ss01, ss02, ss12], f) = self.square_and_f(sigma);
        // Lσ: (Lσ)_ij = (L_i0 σ_0j + L_i1 σ_1j) + L_i2 σ_2j; glam is column-major, so row i of
        // L is (x_axis[i], y_axis[i], z_axis[i]).
        let (lx, ly, lz) = (l.x_axis, l.y_axis, l.z_axis);
        let ls = |i: usize, c0: f64, c1: f64, c2: f64| (lx[i] * c0 + ly[i] * c1) + lz[i] * c2;
        let (m00, m01, m02) = (
            ls(0, s00, s01, s02),
            ls(0, s01, s11, s12),
            ls(0, s02, s12, s22),
        );
        let (m10, m11, m12) = (
            ls(1, s00, s01, s02),
            ls(1, s01, s11, s12),
            ls(1, s02, s12, s22),
        );
        let (m20, m21, m22) = (
            ls(2, s00, s01, s02),
            ls(2, s01, s11, s12),
            ls(2, s02, s12, s22),
        );
        // H = U + R with U = Lσ + σLᵀ = Lσ + (Lσ)ᵀ (σ symmetric) and
        // R = 2G₀D − (1/λ_b)[(α/G₀)σ·σ + fσ + G₀(f − 1)I], D = ½(L + Lᵀ) (§2.8).
        let two_g0 = 2.0 * g0;
        let iso = g0 * (f - 1.0);
        let a = self.anisotropy_over_modulus;
        let entry = |convected: f64, l_ij: f64, l_ji: f64, bracket: f64| {
            convected + (two_g0 * (0.5 * (l_ij + l_ji)) - inv_lb * bracket)
        };
        let h00 = entry(m00 + m00, lx.x, lx.x, (a * ss00 + f * s00) + iso);
        let h11 = entry(m11 + m11, ly.y, ly.y, (a * ss11 + f * s11) + iso);
        let h22 = entry(m22 + m22, lz.z, lz.z, (a * ss22 + f * s22) + iso);
        let h01 = entry(m01 + m10, ly.x, lx.y, a * ss01 + f * s01);
        let h02 = entry(m02 + m20, lz.x, lx.z, a * ss02 + f * s02);
        let h12 = entry(m12 + m21, lz.y, ly.z, a * ss12 + f * s12);
        let h = DMat3::from_cols(
            DVec3::new(h00, h01, h02),
            DVec3::new(h01, h11, h12),
            DVec3::new(h02, h12, h22),
        );
        match norm {
            // K = (f + 2α‖σ‖₂/G₀)/λ_b.
            Some(norm) => (
                h,
                (f + 2.0 * self.anisotropy_over_modulus * norm) * inv_lb,
                Some(norm),
            ),
            None => (h, f * inv_lb, None),
        }
    }
}

/// |det(I − ΔtL/2)| below which the convected update falls back from the Cayley map to
/// A = I + ΔtL: an eigenvalue of ΔtL within about 1 % of 2, i.e. a neighbourhood that more
/// than triples its size in one step, which the advection limit (§7.2) excludes.
const CAYLEY_MIN_DETERMINANT: f64 = 1e-2;

impl XppCoefficients {
    /// One first-order step of the polymer stress (choice D22, module docs): σⁿ⁺¹ from σⁿ, the
    /// velocity gradient `l` \[1/s\] and `dt` \[s\] > 0, with the relaxation linearly implicit
    /// (`implicit`, η_σ = 1) or explicit.
    ///
    /// Per particle this is one chain of dependent operations (a division, a square root, an
    /// `exp`, a division), so it is written for a short chain: on scalars and the six entries
    /// of the symmetric tensors (500 instructions where the `DMat3` form took 760), with the
    /// products of the Cayley map not waiting for its division, and 1/Λ² not waiting for Λ
    /// (`cargo bench --bench kernels -- xpp_commit`: 0.84–0.91× the time of the `DMat3` form,
    /// BENCHMARKS.md (h)).
    #[inline(always)]
    pub fn convected_step(&self, sigma: DMat3, l: DMat3, dt: f64, implicit: bool) -> DMat3 {
        let star = self.convected_star(sigma, l, dt);
        let (relaxation, k) = self.relaxation_sym(star);
        let eta = if implicit { 1.0 } else { 0.0 };
        let w = dt / (1.0 + eta * dt * k.max(0.0));
        Sym(std::array::from_fn(|n| star.0[n] + w * relaxation.0[n])).to_mat()
    }

    /// σ* = A(σ + G₀I)Aᵀ − G₀I of [`convected_step`](Self::convected_step): the stress
    /// convected by the Cayley map A of ΔtL, before the relaxation.
    #[inline(always)]
    fn convected_star(&self, sigma: DMat3, l: DMat3, dt: f64) -> Sym {
        let l = l.to_cols_array_2d(); // l[j][i] = L_ij (columns)
        // M = I − H with H = ΔtL/2; m[i][j] = M_ij.
        let h = 0.5 * dt;
        let m = std::array::from_fn::<[f64; 3], 3, _>(|i| {
            std::array::from_fn(|j| if i == j { 1.0 } else { 0.0 } - h * l[j][i])
        });
        // The cofactors C_ij of M; (I − H)⁻¹ = Cᵀ/det.
        let cof = |i: usize, j: usize| {
            let (i1, i2) = ((i + 1) % 3, (i + 2) % 3);
            let (j1, j2) = ((j + 1) % 3, (j + 2) % 3);
            m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1]
        };
        let c: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| cof(i, j)));
        let det = m[0][0] * c[0][0] + m[0][1] * c[0][1] + m[0][2] * c[0][2];
        // A = (I − H)⁻¹(I + H) = 2(I − H)⁻¹ − I = s adj − I with s = 2/det and adj = Cᵀ,
        // and c* = A c Aᵀ with c = I + σ/G₀: σ* = A B Aᵀ − G₀I with B = σ + G₀I
        // (symmetric). Expanded, A B Aᵀ = s²(CᵀBC) − s(CᵀB + BC) + B: the products do not
        // wait for the division. Near a singular I − H, A = I + ΔtL instead.
        let g0 = self.modulus;
        let sg = Sym::of(sigma);
        let b = Sym([
            sg.0[0] + g0,
            sg.0[1] + g0,
            sg.0[2] + g0,
            sg.0[3],
            sg.0[4],
            sg.0[5],
        ]);
        let delta = |i: usize, j: usize| if i == j { 1.0 } else { 0.0 };
        if det.abs() > CAYLEY_MIN_DETERMINANT {
            let s = 2.0 / det;
            // bc[i][j] = (BC)_ij.
            let bc: [[f64; 3]; 3] = std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    (b.at(i, 0) * c[0][j] + b.at(i, 1) * c[1][j]) + b.at(i, 2) * c[2][j]
                })
            });
            // (CᵀBC)_ij = Σ_k C_ki (BC)_kj; (CᵀB + BC)_ij = (BC)_ji + (BC)_ij.
            let e = |i: usize, j: usize| {
                let q = (c[0][i] * bc[0][j] + c[1][i] * bc[1][j]) + c[2][i] * bc[2][j];
                s * (s * q - (bc[j][i] + bc[i][j])) + b.at(i, j) - g0 * delta(i, j)
            };
            Sym([e(0, 0), e(1, 1), e(2, 2), e(0, 1), e(0, 2), e(1, 2)])
        } else {
            let a: [[f64; 3]; 3] =
                std::array::from_fn(|i| std::array::from_fn(|j| delta(i, j) + dt * l[j][i]));
            let t: [[f64; 3]; 3] = std::array::from_fn(|i| {
                std::array::from_fn(|j| {
                    (a[i][0] * b.at(0, j) + a[i][1] * b.at(1, j)) + a[i][2] * b.at(2, j)
                })
            });
            let e = |i: usize, j: usize| {
                (t[i][0] * a[j][0] + t[i][1] * a[j][1]) + t[i][2] * a[j][2] - g0 * delta(i, j)
            };
            Sym([e(0, 0), e(1, 1), e(2, 2), e(0, 1), e(0, 2), e(1, 2)])
        }
    }
}

/// A symmetric 3 × 3 tensor by its six independent entries (00, 11, 22, 01, 02, 12).
#[derive(Clone, Copy)]
struct Sym([f64; 6]);

impl Sym {
    #[inline(always)]
    fn of(m: DMat3) -> Self {
        Sym([
            m.x_axis.x, m.y_axis.y, m.z_axis.z, m.y_axis.x, m.z_axis.x, m.z_axis.y,
        ])
    }

    /// Entry (i, j) (i, j < 3; constant-folded in unrolled loops).
    #[inline(always)]
    fn at(&self, i: usize, j: usize) -> f64 {
        const INDEX: [[usize; 3]; 3] = [[0, 3, 4], [3, 1, 5], [4, 5, 2]];
        self.0[INDEX[i][j]]
    }

    #[inline(always)]
    fn to_mat(self) -> DMat3 {
        let [s00, s11, s22, s01, s02, s12] = self.0;
        DMat3::from_cols(
            DVec3::new(s00, s01, s02),
            DVec3::new(s01, s11, s12),
            DVec3::new(s02, s12, s22),
        )
    }
}

/// Per-particle state of [`Su2021Unified`]: the non-local stress σᴺᴸ, its material rate σ̇ᴺᴸ
/// (a GS4-1 pair, §2.1) and the step's increment Δσ̇ (written by evaluate, consumed by
/// commit). Symmetric tensors.
///
/// Stored in `f64` (216 bytes per particle): \[Su21\] runs with Δt/λ_b down to 10⁻⁶ (Table 4), where
/// the per-step relaxation λ₄Δt σ̇ is a few `f32` ulps of σ and would be quantised.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct PolymerStress {
    /// σᴺᴸ at t_n \[Pa\].
    pub value: DMat3,
    /// σ̇ᴺᴸ = Dσᴺᴸ/Dt at t_n \[Pa/s\].
    pub rate: DMat3,
    /// Δσ̇ᴺᴸ of the GS4 step being run \[Pa/s\] (0 outside a step; the first-order schemes
    /// neither read nor write it).
    pub rate_increment: DMat3,
}

impl Default for PolymerStress {
    /// Stress-free, at rest (glam's `DMat3::default()` is the identity, hence by hand).
    fn default() -> Self {
        Self {
            value: DMat3::ZERO,
            rate: DMat3::ZERO,
            rate_increment: DMat3::ZERO,
        }
    }
}

/// The stress pair and increment travel with a particle that migrates between ranks.
impl crate::distributed::Travels for PolymerStress {
    const WORDS: usize = 3 * 18;
    fn pack(&self, out: &mut Vec<u32>) {
        crate::distributed::push_dmat3s(out, [&self.value, &self.rate, &self.rate_increment]);
    }
    fn unpack(w: &[u32]) -> Self {
        use crate::distributed::dmat3_at;
        Self {
            value: dmat3_at(w, 0),
            rate: dmat3_at(w, 1),
            rate_increment: dmat3_at(w, 2),
        }
    }
}

impl Rheology for Su2021Unified {
    const NAME: &'static str = "Su2021Unified";

    type State = PolymerStress;

    fn travel(world: &mut bevy_ecs::world::World) {
        crate::distributed::travel::<PolymerStress>(world);
    }

    // `#[inline]`: inlined into the plugin's per-particle loop, the parts of the context this
    // model does not read (D̃, γ̇, J̃) are not computed at all.
    #[inline]
    fn evaluate(&self, ctx: &RheologyContext, state: &mut PolymerStress) -> RheologyOutput {
        let c = ctx.coefficients;
        let p = self.resolve(ctx.material);
        if c.first_order_mechanics {
            // Choice D22: the force takes σⁿ; the commit advances it.
            // Δσ̇ is left as it is: the first-order commit does not read it (and a GS4
            // evaluate overwrites it), and not writing it saves 72 bytes per particle-step.
            let sigma = state.value;
            return RheologyOutput {
                stress: sigma.as_mat3(),
                tangent_viscosity: 0.0,
                // The Frobenius norm bounds ‖σ‖₂ from above (conservative).
                shear_modulus: (p.modulus + frobenius_norm(sigma)) as f32,
                bulk_modulus: 0.0,
                relaxation_rate: if self.implicit_relaxation {
                    0.0
                } else {
                    p.rate(sigma, DMat3::ZERO).1.max(0.0) as f32
                },
            };
        }
        let sigma_hat = state.value + (c.w1l4 * c.dt) * state.rate;
        let (h, k, norm_hat) = p.rate_and_norm(sigma_hat, ctx.velocity_gradient.as_dmat3());
        // (1.3) needs K ≥ 0: f < 0 (Λ < 1 under compression) is growth, not relaxation, and
        // is left explicit.
        let k = k.max(0.0);
        let eta = if self.implicit_relaxation { 1.0 } else { 0.0 };
        let delta = sym(h - state.rate) * (1.0 / (c.w1l6 + eta * c.w2l5 * c.dt * k));
        state.rate_increment = delta;
        let sigma_tilde = sigma_hat + (c.w2l5 * c.dt) * delta;
        RheologyOutput {
            stress: sigma_tilde.as_mat3(),
            tangent_viscosity: 0.0,
            // Stability data only: ‖σ̂‖₂ (already computed when α > 0; it differs from ‖σ̃‖₂ by
            // O(Δt)), else the Frobenius norm of σ̃, an upper bound of ‖σ̃‖₂ (conservative).
            shear_modulus: (p.modulus + norm_hat.unwrap_or_else(|| frobenius_norm(sigma_tilde)))
                as f32,
            bulk_modulus: 0.0,
            relaxation_rate: if self.implicit_relaxation {
                0.0
            } else {
                k as f32
            },
        }
    }

    #[inline]
    fn commit(&self, ctx: &RheologyContext, state: &mut PolymerStress) {
        let c = ctx.coefficients;
        if c.first_order_mechanics {
            let p = self.resolve(ctx.material);
            let next = p.convected_step(
                state.value,
                ctx.velocity_gradient.as_dmat3(),
                c.dt,
                self.implicit_relaxation,
            );
            state.rate = (next - state.value) * (1.0 / c.dt);
            state.value = next;
            return;
        }
        state.value += (c.l4 * c.dt) * state.rate + (c.l5 * c.dt) * state.rate_increment;
        state.rate += state.rate_increment;
        state.rate_increment = DMat3::ZERO;
    }

    fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        self.validate_for(material)
    }

    fn warnings(&self, material: &FluidMaterial) -> Vec<ParameterWarning> {
        self.warnings_for(material)
    }
}

impl Su2021Unified {
    /// Accepted but questionable parameters (ALGORITHM §7.4):
    ///
    /// - α > 1: the conformation c = I + σᴺᴸ/G₀ loses positive-definiteness. Where an eigenvalue
    ///   of c reaches 0 the upper-convected terms vanish along its eigenvector and the relaxation
    ///   leaves ċ = −(α − 1)/λ_b < 0, so the eigenvalue turns negative and the quadratic α term
    ///   then drives σᴺᴸ → −∞ in finite time under compression (an impact). Expect the run to
    ///   stop with a blow-up diagnostic; XPP's physical range is 0 ≤ α ≲ 0.5.
    /// - A user G₀ more than 2× away from (1 − F_v)μ/λ_b: the polymer's viscosity G₀λ_b is not
    ///   the (1 − F_v)μ the local/non-local split assumes (\[Su21\] Table 4 bunny impact, E20).
    pub fn warnings_for(&self, material: &FluidMaterial) -> Vec<ParameterWarning> {
        let mut w = Vec::new();
        if self.anisotropy > 1.0 && self.f_mode == XppFMode::Full {
            w.push(ParameterWarning {
                field: "anisotropy",
                message: format!(
                    "α = {} > 1 lets the XPP conformation lose positive-definiteness (ċ = −(α − 1)/λ_b at a zero eigenvalue): under compression the polymer stress diverges and the run is expected to stop with a blow-up diagnostic; XPP's physical range is 0 ≤ α ≲ 0.5",
                    self.anisotropy
                ),
            });
        }
        if let PlateauModulus::User(g0) = self.modulus {
            let mu = self.viscosity.unwrap_or(material.viscosity as f64);
            let fv = self
                .local_fraction
                .unwrap_or(material.local_fraction as f64);
            let derived = (1.0 - fv) * mu / self.backbone_relaxation_time;
            if g0 > 0.0 && derived > 0.0 && !(0.5..=2.0).contains(&(g0 / derived)) {
                w.push(ParameterWarning {
                    field: "modulus",
                    message: format!(
                        "G₀ = {g0} Pa is {:.3}× (1 − F_v)μ/λ_b = {derived:.4} Pa: the polymer viscosity G₀λ_b = {:.4} Pa·s differs from the (1 − F_v)μ = {:.4} Pa·s the viscosity split assumes",
                        g0 / derived,
                        g0 * self.backbone_relaxation_time,
                        (1.0 - fv) * mu
                    ),
                });
            }
        }
        w
    }
}

#[cfg(test)]
mod rate_tests {
    use super::*;
    use crate::rheology::tensor::spectral_norm;
    use glam::DVec3;

    /// H(σ, L) and K of ALGORITHM §2.8 with full 3×3 products and the divisions as written.
    fn reference(c: &XppCoefficients, sigma: DMat3, l: DMat3) -> (DMat3, f64) {
        let g0 = c.modulus;
        let alpha = c.anisotropy;
        let ss = sigma * sigma;
        let stretch = (1.0 + trace(sigma) / (3.0 * g0))
            .clamp(c.stretch_sq_range.0, c.stretch_sq_range.1)
            .sqrt();
        let ratio = c.time_ratio * (c.nu * (stretch - 1.0)).exp();
        let f = 2.0 * ratio * (1.0 - 1.0 / stretch)
            + (1.0 - alpha * trace(ss) / (3.0 * g0 * g0)) / (stretch * stretch);
        let bracket =
            (alpha / g0) * ss + f * sigma + DMat3::from_diagonal(DVec3::splat(g0 * (f - 1.0)));
        let h =
            l * sigma + sigma * l.transpose() + 2.0 * g0 * sym(l) - c.inv_backbone_time * bracket;
        let k = (f + 2.0 * alpha * spectral_norm(sigma) / g0) * c.inv_backbone_time;
        (h, k)
    }

    /// The six-entry form of `rate_and_norm` (reciprocals of the per-material constants,
    /// one product Lσ) agrees with the full-matrix formula to round-off and returns an
    /// exactly symmetric H.
    #[test]
    fn rate_matches_full_matrix_formula() {
        let material = FluidMaterial {
            local_fraction: 0.01,
            ..FluidMaterial::newtonian("xpp", 1000.0, 20.0, 4.9)
        };
        let c = Su2021Unified::xpp(0.0098, 0.008829, 0.15, 8.0).resolve(&material);
        let mut rng = crate::rheology::tensor::TestMatrices(0x9E37_79B9_7F4A_7C15);
        let mut worst: f64 = 0.0;
        for _ in 0..2000 {
            let sigma = sym(rng.next_matrix()) * (3.0 * c.modulus);
            let l = rng.next_matrix() * 50.0;
            let (h, k, norm) = c.rate_and_norm(sigma, l);
            assert_eq!(h, h.transpose());
            assert_eq!(norm, Some(spectral_norm(sigma)));
            let (h_ref, k_ref) = reference(&c, sigma, l);
            let scale = h_ref.abs().to_cols_array().into_iter().fold(0.0, f64::max);
            worst = worst.max(
                (h - h_ref)
                    .abs()
                    .to_cols_array()
                    .into_iter()
                    .fold(0.0, f64::max)
                    / scale,
            );
            // K's natural scale is 1/λ_b (f = 1 at rest); f itself can cross 0.
            worst = worst.max((k - k_ref).abs() / (k_ref.abs() + c.inv_backbone_time));
        }
        assert!(worst < 1e-13, "worst relative difference {worst:e}");
    }

    /// σ* of the convected update of choice D22 as written in the module docs, with full 3×3
    /// products and a matrix inverse: A = (I − ΔtL/2)⁻¹(I + ΔtL/2) (A = I + ΔtL where
    /// |det(I − ΔtL/2)| ≤ [`CAYLEY_MIN_DETERMINANT`]), σ* = A(σ + G₀I)Aᵀ − G₀I; and A.
    fn convected_reference(c: &XppCoefficients, sigma: DMat3, l: DMat3, dt: f64) -> (DMat3, DMat3) {
        let h = 0.5 * dt * l;
        let lhs = DMat3::IDENTITY - h;
        let a = if lhs.determinant().abs() > CAYLEY_MIN_DETERMINANT {
            lhs.inverse() * (DMat3::IDENTITY + h)
        } else {
            DMat3::IDENTITY + dt * l
        };
        let g = DMat3::from_diagonal(DVec3::splat(c.modulus));
        (a * (sigma + g) * a.transpose() - g, a)
    }

    /// σ* of `convected_step` (scalar, symmetric, the Cayley products expanded around the
    /// division) against the full-matrix form, on both branches of the map. They differ by
    /// round-off in A (relative ε·κ(I − ΔtL/2) each, κ in the max norm) and in the products:
    /// per entry of A(σ + G₀I)Aᵀ at most 2 × 27 products of size ≤ a²b (a, b the largest
    /// entries of A and σ + G₀I). So |Δσ*| ≤ 64ε·27a²b·(1 + κ) bounds both.
    #[test]
    fn convected_star_matches_full_matrix_form() {
        let material = FluidMaterial {
            local_fraction: 0.1,
            ..FluidMaterial::newtonian("slime", 1050.0, 10.0, 20.0)
        };
        let c = Su2021Unified::xpp(0.5, 0.25, 0.15, 4.0).resolve(&material);
        let mut rng = crate::rheology::tensor::TestMatrices(0x2545_F491_4F6C_DD1D);
        let dt = 4e-3;
        let (mut cayley, mut fallback) = (0, 0);
        let mut worst: f64 = 0.0;
        for n in 0..4000 {
            let sigma = sym(rng.next_matrix()) * (2.0 * c.modulus);
            let mut l = rng.next_matrix() * 60.0;
            if n % 4 == 0 {
                // I − ΔtL/2 nearly singular: L_00 close to 2/Δt (the fallback branch).
                l.x_axis.x = 2.0 / dt * (1.0 - 1e-3 * rng.next_matrix().x_axis.x.abs());
                l.y_axis.x = 0.0;
                l.z_axis.x = 0.0;
            }
            let lhs = DMat3::IDENTITY - 0.5 * dt * l;
            let max_abs = |m: DMat3| m.abs().to_cols_array().into_iter().fold(0.0, f64::max);
            let kappa = if lhs.determinant().abs() > CAYLEY_MIN_DETERMINANT {
                cayley += 1;
                9.0 * max_abs(lhs) * max_abs(lhs.inverse())
            } else {
                fallback += 1;
                0.0
            };
            let got = c.convected_star(sigma, l, dt).to_mat();
            let (want, a_ref) = convected_reference(&c, sigma, l, dt);
            let (a, b) = (max_abs(a_ref), max_abs(sigma) + c.modulus);
            let bound = 64.0 * f64::EPSILON * 27.0 * a * a * b * (1.0 + kappa);
            let diff = max_abs(got - want);
            worst = worst.max(diff / bound);
            assert!(diff <= bound, "case {n}: difference {diff:e} > {bound:e}");
        }
        eprintln!("largest difference / bound: {worst:.3e}");
        assert!(cayley > 2000 && fallback > 500, "{cayley} {fallback}");
    }
}
