//! Generalized-Newtonian (shear-rate dependent) viscosities of \[Li\] (ALGORITHM §6.1–6.2):
//! power law, Cross, Carreau(-Yasuda), Bingham (bi-viscous), Casson, Herschel–Bulkley and the
//! Papanastasiou-regularised Bingham and Herschel–Bulkley fluids.
//!
//! # Models (s = the chosen shear-rate measure, all μ clamped to \[μ_min, μ_max\] at the end)
//!
//! | [`LiModel`] | μ_eff(s) | μ_tan = d(μs)/ds |
//! |---|---|---|
//! | `PowerLaw` | m ŝ^{n−1}, ŝ = max(s, s_min) | nμ (s > s_min), μ (s ≤ s_min) |
//! | `Cross` | μ∞ + (μ0 − μ∞)/(1 + (ms)^n) | μ − (μ0 − μ∞) n (ms)^n/(1 + (ms)^n)² |
//! | `Carreau` | μ∞ + (μ0 − μ∞)\[1 + (ms)^a\]^{(n−1)/a} | μ + (μ0 − μ∞)(n − 1)(ms)^a \[1 + (ms)^a\]^{(n−1)/a − 1} |
//! | `Bingham` | μ0 (s ≤ s_c), μ∞ + τ0/s (s > s_c), τ0 = s_c(μ0 − μ∞) | μ0 / μ∞ |
//! | `Casson` | min(μ0, (√μ_c + √(τ0/s))²) | μ0 / μ_c + √(μ_c τ0/s) |
//! | `HerschelBulkley` | μ0 (s ≤ s_c), τ0/s + m s^{n−1} (s > s_c), τ0 = μ0 s_c − m s_c^n | μ0 / n m s^{n−1} |
//! | `BinghamPapanastasiou` | μ∞ + τ0(1 − e^{−Ms})/s | μ∞ + τ0 M e^{−Ms} |
//! | `HerschelBulkleyPapanastasiou` | m s^{n−1} + τ0(1 − e^{−Ms})/s | n m s^{n−1} + τ0 M e^{−Ms} |
//!
//! Carreau is the paper's standard form (note **Li-L1**: \[Li\]'s code uses a different
//! expression, which is not reproduced). Where a clamp is active, μ is constant and
//! μ_tan = μ_eff.
//!
//! # Shear-rate measure (choice D14)
//!
//! [`ShearMeasure::Gamma`] (default): s = γ̇ = √(2 D̃:D̃), the shear rate in simple shear.
//! [`ShearMeasure::Frobenius`]: s = ‖D̃‖_F = γ̇/√2, \[Li\]'s measure; use it to reuse \[Li\]'s
//! parameter tables unchanged.
//!
//! # Stress convention
//!
//! The model **replaces** the material's constant Newtonian viscosity: the material must have
//! `viscosity == 0` (checked by [`LiViscosity::validate_for`]), so that the core's local part
//! 2F_vμD̃ vanishes, and the model returns the whole viscous stress
//! σ_extra = 2 F_v μ_eff(s) D̃, with F_v the material's `local_fraction`.
//!
//! # Stability data (§6.2 note, §7.2)
//!
//! The viscosity is explicit: `tangent_viscosity` = F_v max(μ_eff, μ_tan), which covers the
//! shear-thickening models (μ_tan = nμ > μ for n > 1) and the thinning / yield models
//! (μ_tan ≤ μ_eff). No modulus, no relaxation rate. Yield-stress models have μ up to μ0 (or
//! μ_max) at rest, so the viscous Δt limit follows that plateau: cap it with `mu_max`.
//!
//! # State
//!
//! None: the particles carry the marker [`GeneralizedNewtonian`] only (no history; `commit`
//! does nothing).
use glam::DMat3;
use serde::{Deserialize, Serialize};

use super::{InvalidParameter, ParameterWarning, Rheology, RheologyContext, RheologyOutput};
use crate::material::FluidMaterial;
use bevy_ecs::prelude::Component;

/// Which scalar measure of the strain rate D̃ the viscosity laws take (choice D14).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum ShearMeasure {
    /// s = γ̇ = √(2 D̃:D̃) (the shear rate in simple shear; \[Su21\]'s measure). Default.
    #[default]
    Gamma,
    /// s = ‖D̃‖_F = γ̇/√2 (\[Li\]'s measure, for \[Li\]'s parameter tables).
    Frobenius,
}

impl ShearMeasure {
    /// The shear-rate measure of the strain rate `d` (symmetric) \[1/s\].
    pub fn of(self, d: DMat3) -> f64 {
        let dd = d.x_axis.dot(d.x_axis) + d.y_axis.dot(d.y_axis) + d.z_axis.dot(d.z_axis);
        match self {
            Self::Gamma => (2.0 * dd).sqrt(),
            Self::Frobenius => dd.sqrt(),
        }
    }
}

fn default_yasuda() -> f64 {
    2.0
}

/// The viscosity laws of \[Li\] (ALGORITHM §6.2). Viscosities in Pa·s, shear rates in 1/s,
/// stresses in Pa; `m` is a consistency (Pa·sⁿ, power law / HB) or a time constant (s, Cross /
/// Carreau).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum LiModel {
    /// μ = m max(s, s_min)^{n−1}. n < 1 is singular at rest: needs s_min > 0 or a finite
    /// `mu_max`; n > 1 gives μ → 0 at rest (clamped to `mu_min`).
    PowerLaw {
        /// Consistency m \[Pa·sⁿ\] > 0.
        m: f64,
        /// Flow index n > 0.
        n: f64,
        /// Lower bound of s in the law \[1/s\] ≥ 0.
        s_min: f64,
    },
    /// μ = μ∞ + (μ0 − μ∞)/(1 + (ms)^n).
    Cross {
        /// Zero-shear viscosity μ0 \[Pa·s\] > 0.
        mu0: f64,
        /// Infinite-shear viscosity μ∞ \[Pa·s\] ≥ 0.
        mu_inf: f64,
        /// Time constant m \[s\] > 0.
        m: f64,
        /// Exponent n > 0 (\[Li\]'s default 2/3).
        n: f64,
    },
    /// μ = μ∞ + (μ0 − μ∞)\[1 + (ms)^a\]^{(n−1)/a} (the paper's Carreau for a = 2, Yasuda's
    /// generalisation for other a; Li-L1).
    Carreau {
        /// Zero-shear viscosity μ0 \[Pa·s\] > 0.
        mu0: f64,
        /// Infinite-shear viscosity μ∞ \[Pa·s\] ≥ 0.
        mu_inf: f64,
        /// Time constant m \[s\] > 0.
        m: f64,
        /// Power-law index n > 0.
        n: f64,
        /// Yasuda exponent a > 0 (default 2: Carreau).
        #[serde(default = "default_yasuda")]
        a: f64,
    },
    /// Bi-viscous Bingham: μ0 for s ≤ s_c, μ∞ + τ0/s above, τ0 = s_c(μ0 − μ∞) (continuous).
    Bingham {
        /// Plateau (unyielded) viscosity μ0 \[Pa·s\] > 0, ≥ μ∞.
        mu0: f64,
        /// Plastic viscosity μ∞ \[Pa·s\] ≥ 0.
        mu_inf: f64,
        /// Critical shear rate s_c \[1/s\] > 0.
        s_c: f64,
    },
    /// Casson: μ = min(μ0, (√μ_c + √(τ0/s))²) (μ0 is the bi-viscous cap at rest).
    Casson {
        /// Casson viscosity μ_c \[Pa·s\] > 0.
        mu_c: f64,
        /// Yield stress τ0 \[Pa\] ≥ 0.
        tau0: f64,
        /// Cap μ0 \[Pa·s\] > 0 (the plateau at small s).
        mu0: f64,
    },
    /// Bi-viscous Herschel–Bulkley: μ0 for s ≤ s_c, τ0/s + m s^{n−1} above, with
    /// τ0 = μ0 s_c − m s_c^n ≥ 0 (continuous at s_c).
    HerschelBulkley {
        /// Plateau viscosity μ0 \[Pa·s\] > 0; below m s_c^{n−1} τ0 < 0 (accepted with a warning).
        mu0: f64,
        /// Consistency m \[Pa·sⁿ\] > 0.
        m: f64,
        /// Flow index n > 0.
        n: f64,
        /// Critical shear rate s_c \[1/s\] > 0.
        s_c: f64,
    },
    /// Papanastasiou-regularised Bingham: μ = μ∞ + τ0(1 − e^{−Ms})/s (plateau μ∞ + τ0M at 0).
    BinghamPapanastasiou {
        /// Plastic viscosity μ∞ \[Pa·s\] ≥ 0.
        mu_inf: f64,
        /// Yield stress τ0 \[Pa\] ≥ 0.
        tau0: f64,
        /// Regularisation M \[s\] > 0.
        m_reg: f64,
    },
    /// Papanastasiou-regularised Herschel–Bulkley: μ = m s^{n−1} + τ0(1 − e^{−Ms})/s. Singular
    /// at rest for n < 1: needs a finite `mu_max`.
    HerschelBulkleyPapanastasiou {
        /// Consistency m \[Pa·sⁿ\] > 0.
        m: f64,
        /// Flow index n > 0.
        n: f64,
        /// Yield stress τ0 \[Pa\] ≥ 0.
        tau0: f64,
        /// Regularisation M \[s\] > 0.
        m_reg: f64,
    },
}

/// (1 − e^{−Ms})/s without cancellation, = M at s = 0.
fn papanastasiou(m_reg: f64, s: f64) -> f64 {
    if s > 0.0 {
        -(-m_reg * s).exp_m1() / s
    } else {
        m_reg
    }
}

impl LiModel {
    /// The unclamped μ(s) and d(μs)/ds of the law at s ≥ 0.
    pub fn raw(&self, s: f64) -> (f64, f64) {
        let s = s.max(0.0);
        match *self {
            Self::PowerLaw { m, n, s_min } => {
                if s > s_min {
                    let mu = m * s.powf(n - 1.0);
                    (mu, n * mu)
                } else {
                    let mu = m * s_min.powf(n - 1.0);
                    (mu, mu)
                }
            }
            Self::Cross { mu0, mu_inf, m, n } => {
                let x = (m * s).powf(n);
                let mu = mu_inf + (mu0 - mu_inf) / (1.0 + x);
                (mu, mu - (mu0 - mu_inf) * n * x / ((1.0 + x) * (1.0 + x)))
            }
            Self::Carreau {
                mu0,
                mu_inf,
                m,
                n,
                a,
            } => {
                let x = (m * s).powf(a);
                let b = 1.0 + x;
                let p = (n - 1.0) / a;
                let mu = mu_inf + (mu0 - mu_inf) * b.powf(p);
                (mu, mu + (mu0 - mu_inf) * (n - 1.0) * x * b.powf(p - 1.0))
            }
            Self::Bingham { mu0, mu_inf, s_c } => {
                if s <= s_c {
                    (mu0, mu0)
                } else {
                    (mu_inf + s_c * (mu0 - mu_inf) / s, mu_inf)
                }
            }
            Self::Casson { mu_c, tau0, mu0 } => {
                // √(τ0/s), with 0/0 (τ0 = 0 at rest) read as 0.
                let y = if s > 0.0 {
                    (tau0 / s).sqrt()
                } else if tau0 > 0.0 {
                    f64::INFINITY
                } else {
                    0.0
                };
                let raw = (mu_c.sqrt() + y).powi(2);
                if raw >= mu0 {
                    (mu0, mu0)
                } else {
                    (raw, mu_c + mu_c.sqrt() * y)
                }
            }
            Self::HerschelBulkley { mu0, m, n, s_c } => {
                if s <= s_c {
                    (mu0, mu0)
                } else {
                    let tau0 = mu0 * s_c - m * s_c.powf(n);
                    let k = m * s.powf(n - 1.0);
                    (tau0 / s + k, n * k)
                }
            }
            Self::BinghamPapanastasiou {
                mu_inf,
                tau0,
                m_reg,
            } => (
                mu_inf + tau0 * papanastasiou(m_reg, s),
                mu_inf + tau0 * m_reg * (-m_reg * s).exp(),
            ),
            Self::HerschelBulkleyPapanastasiou { m, n, tau0, m_reg } => {
                let k = m * s.powf(n - 1.0);
                (
                    k + tau0 * papanastasiou(m_reg, s),
                    n * k + tau0 * m_reg * (-m_reg * s).exp(),
                )
            }
        }
    }

    /// The yield stress τ0 \[Pa\] of the yield-stress laws (derived for Bingham and HB), 0 for
    /// the others.
    pub fn yield_stress(&self) -> f64 {
        match *self {
            Self::Bingham { mu0, mu_inf, s_c } => s_c * (mu0 - mu_inf),
            Self::HerschelBulkley { mu0, m, n, s_c } => mu0 * s_c - m * s_c.powf(n),
            Self::Casson { tau0, .. }
            | Self::BinghamPapanastasiou { tau0, .. }
            | Self::HerschelBulkleyPapanastasiou { tau0, .. } => tau0,
            _ => 0.0,
        }
    }
}

/// A generalized-Newtonian viscosity of \[Li\] (one value per material in
/// [`RheologyTable`](super::RheologyTable)). The material's own `viscosity` must be 0: the model
/// returns the whole viscous stress 2F_vμ_eff(s)D̃.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LiViscosity {
    /// The viscosity law.
    pub model: LiModel,
    /// The shear-rate measure s. Default [`ShearMeasure::Gamma`].
    #[serde(default)]
    pub shear_measure: ShearMeasure,
    /// Lower clamp μ_min \[Pa·s\] ≥ 0 (default 0).
    #[serde(default)]
    pub mu_min: f64,
    /// Upper clamp μ_max \[Pa·s\] ≥ μ_min (default +∞; a finite cap bounds the viscous Δt).
    #[serde(default = "infinity")]
    pub mu_max: f64,
}

fn infinity() -> f64 {
    f64::INFINITY
}

impl LiViscosity {
    /// The law `model` with s = γ̇ and no clamps.
    pub fn new(model: LiModel) -> Self {
        Self {
            model,
            shear_measure: ShearMeasure::Gamma,
            mu_min: 0.0,
            mu_max: f64::INFINITY,
        }
    }

    /// With the shear-rate measure `measure`.
    pub fn with_shear_measure(mut self, measure: ShearMeasure) -> Self {
        self.shear_measure = measure;
        self
    }

    /// With the clamps \[mu_min, mu_max\] \[Pa·s\].
    pub fn with_clamp(mut self, mu_min: f64, mu_max: f64) -> Self {
        self.mu_min = mu_min;
        self.mu_max = mu_max;
        self
    }

    /// The effective viscosity μ_eff(s) \[Pa·s\] (clamped) at shear-rate measure s \[1/s\].
    pub fn mu_eff(&self, s: f64) -> f64 {
        self.eval(s).0
    }

    /// The tangent viscosity μ_tan(s) = d(μ_eff s)/ds \[Pa·s\] (μ_eff where a clamp is active).
    pub fn mu_tangent(&self, s: f64) -> f64 {
        self.eval(s).1
    }

    fn eval(&self, s: f64) -> (f64, f64) {
        let (mu, tan) = self.model.raw(s);
        if mu > self.mu_max {
            (self.mu_max, self.mu_max)
        } else if mu < self.mu_min {
            (self.mu_min, self.mu_min)
        } else {
            (mu, tan)
        }
    }

    /// Checks the parameters on their own (every violated constraint is listed). Field names
    /// of the law are prefixed `model.`.
    pub fn validate(&self) -> Result<(), Vec<InvalidParameter>> {
        let mut e = Vec::new();
        let mut bad = |field, constraint| e.push(InvalidParameter { field, constraint });
        let pos = |x: f64| x.is_finite() && x > 0.0;
        let nonneg = |x: f64| x.is_finite() && x >= 0.0;
        if !nonneg(self.mu_min) {
            bad("mu_min", "must be a finite number ≥ 0 Pa·s");
        }
        if self.mu_max.is_nan() || self.mu_max <= 0.0 {
            bad("mu_max", "must be > 0 Pa·s (may be +∞)");
        }
        if self.mu_min > self.mu_max {
            bad("mu_min", "must be ≤ mu_max");
        }
        // Per-law parameters: (field, value, must be > 0 (else ≥ 0), message).
        const VISC: &str = "must be a finite number > 0 Pa·s";
        const VISC0: &str = "must be a finite number ≥ 0 Pa·s";
        const CONS: &str = "must be a finite number > 0 Pa·sⁿ";
        const TIME: &str = "must be a finite number > 0 s";
        const EXP: &str = "must be a finite number > 0";
        const RATE: &str = "must be a finite number > 0 1/s";
        const STRESS: &str = "must be a finite number ≥ 0 Pa";
        let params: &[(&'static str, f64, bool, &'static str)] = match self.model {
            LiModel::PowerLaw { m, n, s_min } => &[
                ("model.m", m, true, CONS),
                ("model.n", n, true, EXP),
                (
                    "model.s_min",
                    s_min,
                    false,
                    "must be a finite number ≥ 0 1/s",
                ),
            ],
            LiModel::Cross { mu0, mu_inf, m, n } => &[
                ("model.mu0", mu0, true, VISC),
                ("model.mu_inf", mu_inf, false, VISC0),
                ("model.m", m, true, TIME),
                ("model.n", n, true, EXP),
            ],
            LiModel::Carreau {
                mu0,
                mu_inf,
                m,
                n,
                a,
            } => &[
                ("model.mu0", mu0, true, VISC),
                ("model.mu_inf", mu_inf, false, VISC0),
                ("model.m", m, true, TIME),
                ("model.n", n, true, EXP),
                ("model.a", a, true, EXP),
            ],
            LiModel::Bingham { mu0, mu_inf, s_c } => &[
                ("model.mu0", mu0, true, VISC),
                ("model.mu_inf", mu_inf, false, VISC0),
                ("model.s_c", s_c, true, RATE),
            ],
            LiModel::Casson { mu_c, tau0, mu0 } => &[
                ("model.mu_c", mu_c, true, VISC),
                ("model.tau0", tau0, false, STRESS),
                ("model.mu0", mu0, true, VISC),
            ],
            LiModel::HerschelBulkley { mu0, m, n, s_c } => &[
                ("model.mu0", mu0, true, VISC),
                ("model.m", m, true, CONS),
                ("model.n", n, true, EXP),
                ("model.s_c", s_c, true, RATE),
            ],
            LiModel::BinghamPapanastasiou {
                mu_inf,
                tau0,
                m_reg,
            } => &[
                ("model.mu_inf", mu_inf, false, VISC0),
                ("model.tau0", tau0, false, STRESS),
                ("model.m_reg", m_reg, true, TIME),
            ],
            LiModel::HerschelBulkleyPapanastasiou { m, n, tau0, m_reg } => &[
                ("model.m", m, true, CONS),
                ("model.n", n, true, EXP),
                ("model.tau0", tau0, false, STRESS),
                ("model.m_reg", m_reg, true, TIME),
            ],
        };
        // A relation between parameters, reported right after its anchor parameter when that
        // parameter (and, with `needs_all`, every earlier one) is itself valid:
        // (anchor, field, message, needs_all).
        let relation: Option<(&str, &'static str, &'static str, bool)> = match self.model {
            LiModel::PowerLaw { n, s_min, .. }
                if n < 1.0 && s_min == 0.0 && !self.mu_max.is_finite() =>
            {
                Some((
                    "model.s_min",
                    "model.s_min",
                    "must be > 0 for n < 1 unless mu_max is finite (μ = m s^{n−1} is infinite at rest)",
                    false,
                ))
            }
            LiModel::Bingham { mu0, mu_inf, .. } if mu_inf.is_finite() && mu0 < mu_inf => Some((
                "model.mu0",
                "model.mu0",
                "must be ≥ mu_inf (yield stress τ0 = s_c(μ0 − μ∞) ≥ 0)",
                false,
            )),
            LiModel::HerschelBulkleyPapanastasiou { n, .. }
                if n < 1.0 && !self.mu_max.is_finite() =>
            {
                Some((
                    "model.n",
                    "mu_max",
                    "must be finite for n < 1 (μ = m s^{n−1} + … is infinite at rest)",
                    false,
                ))
            }
            _ => None,
        };
        let mut all_ok = true;
        for &(field, value, positive, message) in params {
            let ok = if positive { pos(value) } else { nonneg(value) };
            all_ok &= ok;
            if !ok {
                bad(field, message);
            } else if let Some((anchor, rel_field, rel_message, needs_all)) = relation
                && anchor == field
                && (all_ok || !needs_all)
            {
                bad(rel_field, rel_message);
            }
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }

    /// [`validate`](Self::validate) plus the check against the material: its `viscosity` must
    /// be 0 (the model replaces the constant μ; otherwise the core would add 2F_vμD̃ twice).
    pub fn validate_for(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        let mut e = self.validate().err().unwrap_or_default();
        if material.viscosity != 0.0 {
            e.push(InvalidParameter {
                field: "viscosity",
                constraint: "of the material must be 0: a generalized-Newtonian model returns the whole viscous stress 2F_v μ_eff D̃",
            });
        }
        if e.is_empty() { Ok(()) } else { Err(e) }
    }
}

impl LiViscosity {
    /// Accepted but questionable parameters: a bi-viscous Herschel–Bulkley law with
    /// μ0 < m·s_c^(n−1) has a negative "yield stress" τ0 = μ0 s_c − m s_c^n (ALGORITHM §6.2:
    /// warn on load; \[Li\]'s tomatoes 1 and 2). The law stays positive and continuous
    /// (μs = τ0 + m sⁿ increases from μ0 s_c > 0 at s_c), but the material is not a
    /// yield-stress fluid.
    pub fn warnings_for(&self) -> Vec<ParameterWarning> {
        match self.model {
            LiModel::HerschelBulkley { mu0, m, n, s_c } if mu0 < m * s_c.powf(n - 1.0) => {
                vec![ParameterWarning {
                    field: "model.mu0",
                    message: format!(
                        "μ0 = {mu0} Pa·s < m·s_c^(n−1) = {:.6} Pa·s: the yield stress τ0 = μ0 s_c − m s_c^n \
                         = {:.3e} Pa is negative, so this is a bi-viscous power law, not a \
                         yield-stress fluid",
                        m * s_c.powf(n - 1.0),
                        self.model.yield_stress()
                    ),
                }]
            }
            _ => Vec::new(),
        }
    }
}

/// Marker state of [`LiViscosity`]: the particle uses the model (no history).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GeneralizedNewtonian;

/// The marker travels with a particle that migrates between ranks.
impl crate::distributed::Travels for GeneralizedNewtonian {
    const WORDS: usize = 0;
    fn pack(&self, _: &mut Vec<u32>) {}
    fn unpack(_: &[u32]) -> Self {
        Self
    }
}

impl Rheology for LiViscosity {
    const NAME: &'static str = "Li2024";

    type State = GeneralizedNewtonian;

    fn travel(world: &mut bevy_ecs::world::World) {
        crate::distributed::travel::<GeneralizedNewtonian>(world);
    }

    fn evaluate(&self, ctx: &RheologyContext, _state: &mut GeneralizedNewtonian) -> RheologyOutput {
        let d = ctx.strain_rate.as_dmat3();
        let s = self.shear_measure.of(d);
        let (mu, tan) = self.eval(s);
        let fv = ctx.material.local_fraction as f64;
        RheologyOutput {
            stress: (d * (2.0 * fv * mu)).as_mat3(),
            tangent_viscosity: (fv * mu.max(tan)) as f32,
            ..RheologyOutput::default()
        }
    }

    fn commit(&self, _ctx: &RheologyContext, _state: &mut GeneralizedNewtonian) {}

    fn warnings(&self, _material: &FluidMaterial) -> Vec<ParameterWarning> {
        self.warnings_for()
    }

    fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        self.validate_for(material)
    }
}
