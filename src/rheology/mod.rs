//! Rheology models: extra stress and history state on particles (ALGORITHM §6.1).
//!
//! A rheology model is a pure constitutive function plus a per-particle history state. It plugs
//! into the step at two points:
//!
//! | when | set | what the model does |
//! |---|---|---|
//! | S7–S9 | [`ConstitutiveSystems::Models`] | [`Rheology::evaluate`]: returns the extra Cauchy stress at t_{n+W₁} and its stability data; may store the step's increment in its state |
//! | S15 | [`CommitSystems::Models`](crate::schedule::CommitSystems::Models) | [`Rheology::commit`]: advances the history state to t_{n+1} |
//!
//! [`RheologyPlugin<M>`] registers both systems for a model type `M`; the model's parameters
//! live per material in [`RheologyTable<M>`] (keyed by [`MaterialId`]); a particle takes part
//! only if it carries the model's state component [`Rheology::State`], attached with
//! [`attach_model`] (exclusive access) or [`RheologyCommandsExt::attach_model`] (from a system).
//! Particles without the state pay nothing: the systems query `&mut M::State` and do not run at
//! all while no entity has it.
//!
//! # Stress and viscosity convention
//!
//! The core ([`crate::step::constitutive`]) already writes the **local** (Newtonian, solvent)
//! part σ̃ᴸ = 2 F_v μ D̃ of the material (`FluidMaterial::viscosity` μ, `local_fraction` F_v)
//! together with the pressure −p̃ I. A model returns only what comes **on top** of that, e.g. the
//! non-local (polymer) stress σ̃ᴺᴸ of the \[Su21\] split μ = F_v μ + (1 − F_v) μ. It must not
//! repeat the local part. The total is (ALGORITHM §2.9, §6.1)
//! σ̃ = −p̃ I + 2 F_v μ D̃ + Σ_models σ̃_extra.
//!
//! The core has no phase index yet. When the solid phase arrives (§2.9:
//! σ̃ = −p̃I + (1 − I_s)(σ̃ᴸ + σ̃ᴺᴸ) + I_s σ̃ˢ), the (1 − I_s) blend must also scale the
//! model stresses of liquid-phase models. That blend belongs to the core, not to each model.
//!
//! # Stability data
//!
//! The evaluate system adds the model's moduli to the particle's [`StabilityData`] so that the
//! adaptive step (§2.15) accounts for them: c² += (4/3 G_el + K_el)/ρ̃;
//! ν = max(ν, μ_tan/ρ̃); k_relax = max(k_relax, relaxation rate).
//!
//! # Precision
//!
//! The core stores particle state in `f32`. The context hands models the step's GS4 weights in
//! `f64` ([`FirstOrderCoefficients`], built from [`Gs4Params`], not from the `f32`
//! [`StepCoefficients`](crate::kernels::StepCoefficients)), so a model that keeps its history
//! in `f64` integrates to `f64` accuracy.
//!
//! # Writing a model
//!
//! 1. A parameter struct `M: Clone + Send + Sync + 'static` and a state component
//!    (`#[derive(Component, Clone)]` with a `Default` that means "at rest"; note that glam's
//!    `Mat3::default()` is the identity, so write `Default` by hand for matrix states).
//! 2. `impl Rheology for M`: `evaluate` reads the context and the state at t_n, returns the
//!    stress at t_{n+W₁} and stores what `commit` needs; `commit` advances the state. For a
//!    GS4-1 history pair (y, ẏ), use [`FirstOrderCoefficients`] as in [`su2021_unified`].
//!    `evaluate` must not advance the history: a failed step has to leave the state at t_n.
//! 3. `validate` lists every ill-posed parameter ([`InvalidParameter`]).
//! 4. A file per model, named after its source (`author2021_model.rs`), and tests that drive
//!    evaluate/commit in a loop without an App (`tests/rheology.rs`).
//! 5. A model that reads the deformation gradient sets [`Rheology::NEEDS_DEFORMATION_GRADIENT`]
//!    ([`neo_hookean`]); one that needs its own strain history keeps it in its state
//!    ([`li2024_elastoplastic`] integrates its own F).
//!
//! A complete model written outside the crate with the public API only (the Giesekus fluid) is
//! `examples/custom_rheology.rs`.
//!
//! # Models
//!
//! | file | model |
//! |---|---|
//! | [`li2024_elastoplastic`] | von Mises elasto-plastic solid of \[Li\] with elastic / plastic limits and fracture (ALGORITHM §6.3) |
//! | [`li2024_generalized_newtonian`] | generalized-Newtonian viscosities of \[Li\] (ALGORITHM §6.2) |
//! | [`neo_hookean`] | neo-Hookean solid from the core's deformation gradient (ALGORITHM §4.2) |
//! | [`su2021_unified`] | XPP / Oldroyd-B / UCM polymer stress of \[Su21\] (ALGORITHM §2.8) |
use std::fmt;

use bevy_app::{App, Plugin};
use bevy_ecs::component::Mutable;
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::common_conditions::any_with_component;
use thiserror::Error;

use crate::components::{
    CauchyStress, DeformationGradient, Particle, PredictedDeformationGradient, PredictedDensity,
    StabilityData, VelocityGradient,
};
use crate::config::MpmConfig;
use crate::failure::{FailureCollector, FailureReport};
use crate::gs4::Gs4Params;
use crate::material::{FluidMaterial, MaterialId, MaterialTable, Materials};
use crate::math::{Mat3, Real};
use crate::schedule::{ConstitutiveSystems, Gs4Constants, MpmStep, StepContext};

pub mod li2024_elastoplastic;
pub mod li2024_generalized_newtonian;
pub mod neo_hookean;
pub mod su2021_unified;
pub mod tensor;

pub use li2024_elastoplastic::{ElastoPlasticState, Li2024ElastoPlastic};
pub use li2024_generalized_newtonian::{GeneralizedNewtonian, LiModel, LiViscosity, ShearMeasure};
pub use neo_hookean::{NeoHookean, NeoHookeanSolid};
pub use su2021_unified::{PolymerStress, Su2021Unified};

/// The GS4-1 weights of one step in `f64` (ALGORITHM §1.2): what a first-order particle field
/// (y, ẏ) needs for ŷ = y + W₁Λ₄Δt ẏ, Δẏ = (g(ŷ) − ẏ)/(W₁Λ₆ + η W₂Λ₅Δt K),
/// ỹ = ŷ + W₂Λ₅Δt Δẏ, yⁿ⁺¹ = y + λ₄Δt ẏ + λ₅Δt Δẏ, ẏⁿ⁺¹ = ẏ + Δẏ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FirstOrderCoefficients {
    /// Δt \[s\] (0 in the start-up rate evaluation).
    pub dt: f64,
    /// W₁Λ₄: predictor weight.
    pub w1l4: f64,
    /// W₁Λ₆: weight of the rate increment in the balance (the "effective mass").
    pub w1l6: f64,
    /// W₂Λ₅: weight of Δt Δẏ in the algorithmic value ỹ.
    pub w2l5: f64,
    /// λ₄: weight of Δt ẏ in yⁿ⁺¹.
    pub l4: f64,
    /// λ₅: weight of Δt Δẏ in yⁿ⁺¹.
    pub l5: f64,
}

impl FirstOrderCoefficients {
    /// The weights of a step of size `dt` \[s\] with the GS4 parameters `p`.
    pub fn step(p: &Gs4Params, dt: f64) -> Self {
        Self {
            dt,
            w1l4: p.w1l4,
            w1l6: p.w1l6,
            w2l5: p.w2l5,
            l4: p.l4,
            l5: p.l5,
        }
    }

    /// The start-up rate evaluation of §2.14: Δt = 0 and W₁Λ₆ = 1, so that evaluate + commit
    /// leave the value unchanged and set the rate to g(y⁰) (ẏ⁰ = g(y⁰), any stored ẏ is
    /// replaced).
    pub fn rate_evaluation() -> Self {
        Self {
            dt: 0.0,
            w1l4: 0.0,
            w1l6: 1.0,
            w2l5: 0.0,
            l4: 0.0,
            l5: 0.0,
        }
    }
}

/// What a model sees of one particle at t_{n+W₁} (ALGORITHM §6.1 input). Plain data: no ECS
/// types, so models can be tested and reused without an `App`.
///
/// In [`Rheology::commit`] the same context is passed with one difference:
/// `deformation_gradient` is F^{n+1} (after `GridToParticle`) instead of F̃.
#[derive(Clone, Copy, Debug)]
pub struct RheologyContext<'a> {
    /// Velocity gradient L̃ \[1/s\], L_ab = ∂v_a/∂x_b (glam is column-major: column b holds
    /// ∂v/∂x_b, so `l.y_axis.x` = ∂v_x/∂y).
    pub velocity_gradient: Mat3,
    /// Strain rate D̃ = ½(L̃ + L̃ᵀ) \[1/s\].
    pub strain_rate: Mat3,
    /// Shear rate γ̇ = √(2 D̃:D̃) \[1/s\] (choice D14; \[Li\]'s tables use γ̇/√2).
    pub shear_rate: Real,
    /// F̃ (evaluate) or Fⁿ⁺¹ (commit); `None` unless the particle carries a
    /// [`DeformationGradient`].
    pub deformation_gradient: Option<Mat3>,
    /// Algorithmic density ρ̃ \[kg/m³\].
    pub density: Real,
    /// Volume ratio J̃ = ρ₀/ρ̃ (choice D11).
    pub volume_ratio: Real,
    /// The particle's material (μ, F_v, ρ₀, c₀).
    pub material: &'a FluidMaterial,
    /// GS4-1 weights of this step.
    pub coefficients: FirstOrderCoefficients,
    /// True during the start-up rate evaluation (Δt = 0, §2.14).
    pub rate_evaluation: bool,
}

impl<'a> RheologyContext<'a> {
    /// A context for velocity gradient `l`, density `density` (ρ̃) and `material`; derives D̃,
    /// γ̇ and J̃; no deformation gradient. (Inlined: a model that does not read D̃, γ̇ or J̃
    /// and is itself inlined into the per-particle loop does not pay for them.)
    #[inline]
    pub fn new(
        l: Mat3,
        density: Real,
        material: &'a FluidMaterial,
        coefficients: FirstOrderCoefficients,
        rate_evaluation: bool,
    ) -> Self {
        let d = 0.5 * (l + l.transpose());
        let dd = d.x_axis.dot(d.x_axis) + d.y_axis.dot(d.y_axis) + d.z_axis.dot(d.z_axis);
        Self {
            velocity_gradient: l,
            strain_rate: d,
            shear_rate: (2.0 * dd).sqrt(),
            deformation_gradient: None,
            density,
            volume_ratio: material.density / density,
            material,
            coefficients,
            rate_evaluation,
        }
    }

    /// The same context with a deformation gradient.
    pub fn with_deformation_gradient(mut self, f: Mat3) -> Self {
        self.deformation_gradient = Some(f);
        self
    }
}

/// What a model returns for one particle (ALGORITHM §6.1 output). `Default` is "nothing":
/// zero stress and zero moduli.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RheologyOutput {
    /// Extra Cauchy stress σ̃_extra at t_{n+W₁} \[Pa\], added to [`CauchyStress`]. Symmetric.
    pub stress: Mat3,
    /// Tangent viscosity μ_tan = d|τ|/dγ̇ of any **explicit** viscous part \[Pa·s\] (viscous Δt
    /// limit); 0 if the model has none.
    pub tangent_viscosity: Real,
    /// Instantaneous shear modulus G_el \[Pa\] (wave Δt limit).
    pub shear_modulus: Real,
    /// Extra bulk modulus K_el \[Pa\]; 0 when the Tait equation carries the volume response.
    pub bulk_modulus: Real,
    /// Stiffest explicitly integrated pointwise relaxation rate \[1/s\] (Δt ≤ z_crit/rate);
    /// 0 if none or treated implicitly.
    pub relaxation_rate: Real,
}

impl Default for RheologyOutput {
    fn default() -> Self {
        // By hand: glam's `Mat3::default()` is the identity.
        Self {
            stress: Mat3::ZERO,
            tangent_viscosity: 0.0,
            shear_modulus: 0.0,
            bulk_modulus: 0.0,
            relaxation_rate: 0.0,
        }
    }
}

impl RheologyOutput {
    /// True if every number is finite.
    pub fn is_finite(&self) -> bool {
        self.stress.is_finite()
            && self.tangent_viscosity.is_finite()
            && self.shear_modulus.is_finite()
            && self.bulk_modulus.is_finite()
            && self.relaxation_rate.is_finite()
    }
}

/// A parameter that violates a constraint: the field name and the constraint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InvalidParameter {
    /// Field name as in the model struct (and the scene file).
    pub field: &'static str,
    /// The violated constraint, e.g. "must be > 0 s".
    pub constraint: &'static str,
}

impl fmt::Display for InvalidParameter {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {}", self.field, self.constraint)
    }
}

/// A parameter that is accepted but questionable: the field name and why.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParameterWarning {
    /// Field name as in the model struct (and the scene file).
    pub field: &'static str,
    /// What the value implies.
    pub message: String,
}

impl fmt::Display for ParameterWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.field, self.message)
    }
}

/// A rheology model: parameters (`self`, one value per material) and a pure constitutive
/// update. Implementors must not touch ECS types; [`RheologyPlugin`] does the gathering and
/// scattering.
pub trait Rheology: Clone + Send + Sync + 'static {
    /// Per-particle state: the history (e.g. polymer stress and its rate) and any per-step
    /// value that [`commit`](Rheology::commit) needs (e.g. the rate increment).
    type State: Component<Mutability = Mutable> + Clone + Default;

    /// Whether the model reads the deformation gradient ([`RheologyContext::deformation_gradient`]).
    /// If true, [`attach_model`] also gives the particles a [`DeformationGradient`] (F = I) and
    /// a [`PredictedDeformationGradient`] unless they carry them already, so that the core
    /// advances F (§2.4, §2.13); a particle with the state but without F stops the run with a
    /// failure report. Default false.
    const NEEDS_DEFORMATION_GRADIENT: bool = false;

    /// Evaluates the model at t_{n+W₁}: returns the extra stress and the stability data, and
    /// may write the step's increment into `state`. Must not advance the history (a failed
    /// step must leave the state at t_n).
    fn evaluate(&self, ctx: &RheologyContext, state: &mut Self::State) -> RheologyOutput;

    /// Advances the history to t_{n+1} (S15), after the grid update and G2P.
    fn commit(&self, ctx: &RheologyContext, state: &mut Self::State);

    /// The state a particle starts with when the model is attached. Default: `State::default()`.
    fn initial_state(&self) -> Self::State {
        Self::State::default()
    }

    /// Checks the parameters for use with `material`. Default: always valid.
    fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        let _ = material;
        Ok(())
    }

    /// Parameters that are accepted but questionable (outside the model's physical range,
    /// inconsistent with each other, likely to blow up): reported at load, never rejected.
    /// Default: none.
    fn warnings(&self, material: &FluidMaterial) -> Vec<ParameterWarning> {
        let _ = material;
        Vec::new()
    }
}

/// The parameters of model `M` per material: `MaterialId(i)` → `M`. Materials without an
/// entry do not use the model.
#[derive(Resource, Clone)]
pub struct RheologyTable<M: Rheology> {
    entries: MaterialTable<M>,
}

impl<M: Rheology> Default for RheologyTable<M> {
    fn default() -> Self {
        Self {
            entries: MaterialTable::default(),
        }
    }
}

impl<M: Rheology> RheologyTable<M> {
    /// Sets the model of `material`; returns the previous one. Takes effect from the next
    /// step (parameters may be changed at run time through `ResMut<RheologyTable<M>>`).
    pub fn insert(&mut self, material: MaterialId, model: M) -> Option<M> {
        self.entries.insert(material, model)
    }

    /// Removes the model of `material`. Particles that still carry the state then stop the
    /// run with a failure report at their next step (remove their state too).
    pub fn remove(&mut self, material: MaterialId) -> Option<M> {
        self.entries.remove(material)
    }

    /// The model of `material`, if any.
    #[inline]
    pub fn get(&self, material: MaterialId) -> Option<&M> {
        self.entries.get(material)
    }

    /// The model of `material`, mutably.
    pub fn get_mut(&mut self, material: MaterialId) -> Option<&mut M> {
        self.entries.get_mut(material)
    }

    /// All (material, model) pairs.
    pub fn iter(&self) -> impl Iterator<Item = (MaterialId, &M)> {
        self.entries.iter()
    }

    /// The initial state for a new particle of `material` (add it to the spawn bundle), or
    /// `None` if the material does not use the model.
    pub fn initial_state(&self, material: MaterialId) -> Option<M::State> {
        self.get(material).map(M::initial_state)
    }
}

/// Registers model `M`: the [`RheologyTable<M>`] resource (with the entries given here, merged
/// into an existing table) and its evaluate and commit systems in the [`MpmStep`] schedule.
///
/// Add it **after** [`MpmPlugins`](crate::plugin::MpmPlugins) (it panics otherwise: the step
/// schedule must exist). Then attach the model to the particles of each material with
/// [`attach_model`].
///
/// ```
/// use bevy_app::App;
/// use treacle::prelude::*;
///
/// let mut materials = Materials::default();
/// let polymer = materials.add(FluidMaterial {
///     local_fraction: 0.1, // 10 % solvent; the polymer carries (1 − F_v)μ
///     ..FluidMaterial::newtonian("polymer", 1000.0, 20.0, 10.0)
/// });
/// let mut app = App::new();
/// app.insert_resource(materials).add_plugins(MpmPlugins);
/// app.add_plugins(
///     RheologyPlugin::<Su2021Unified>::default().with(polymer, Su2021Unified::oldroyd_b(0.1)),
/// );
/// let g = Vec3::new(0.0, -9.81, 0.0);
/// app.world_mut().spawn(ParticleBundle::new(Vec3::splat(0.5), Vec3::ZERO, g, 1e-6, 1000.0, polymer));
/// // After spawning the material's particles:
/// assert_eq!(attach_model::<Su2021Unified>(app.world_mut(), polymer).unwrap(), 1);
/// app.update();
/// ```
pub struct RheologyPlugin<M: Rheology> {
    /// Entries to put into the table.
    pub table: RheologyTable<M>,
}

impl<M: Rheology> Default for RheologyPlugin<M> {
    fn default() -> Self {
        Self {
            table: RheologyTable::default(),
        }
    }
}

impl<M: Rheology> RheologyPlugin<M> {
    /// Adds a table entry.
    pub fn with(mut self, material: MaterialId, model: M) -> Self {
        self.table.insert(material, model);
        self
    }
}

impl<M: Rheology> Plugin for RheologyPlugin<M> {
    fn build(&self, app: &mut App) {
        crate::schedule::require_step_schedule(
            app,
            &format!("RheologyPlugin<{}>", std::any::type_name::<M>()),
        );
        let world = app.world_mut();
        if let Some(mut table) = world.get_resource_mut::<RheologyTable<M>>() {
            for (id, m) in self.table.iter() {
                table.insert(id, m.clone());
            }
        } else {
            world.insert_resource(self.table.clone());
        }
        app.add_systems(
            MpmStep,
            evaluate_model::<M>
                .in_set(ConstitutiveSystems::Models)
                .run_if(any_with_component::<M::State>),
        );
        app.add_systems(
            MpmStep,
            commit_model::<M>
                .in_set(crate::schedule::CommitSystems::Models)
                .run_if(any_with_component::<M::State>),
        );
    }
}

/// The GS4-1 weights of the step being run, in `f64`.
fn step_coefficients(ctx: &StepContext, gs4: &Gs4Constants) -> FirstOrderCoefficients {
    if ctx.rate_evaluation {
        FirstOrderCoefficients::rate_evaluation()
    } else {
        FirstOrderCoefficients::step(&gs4.params, ctx.dt)
    }
}

/// The first non-finite number of an output (for the failure report).
fn first_non_finite(out: &RheologyOutput) -> Real {
    out.stress
        .to_cols_array()
        .into_iter()
        .chain([
            out.tangent_viscosity,
            out.shear_modulus,
            out.bulk_modulus,
            out.relaxation_rate,
        ])
        .find(|v| !v.is_finite())
        .unwrap_or(Real::NAN)
}

fn missing_model<M>(e: Entity, mat: MaterialId) -> FailureReport {
    FailureReport::particle(
        e,
        "rheology",
        mat.0 as f64,
        &format!(
            "the particle carries the state of {} but its material (id {}) has no entry in RheologyTable",
            std::any::type_name::<M>(),
            mat.0
        ),
    )
}

/// S7–S9 for model `M`: evaluates it on every particle with `M::State`, adds the stress to
/// [`CauchyStress`] and raises [`StabilityData`]. A non-finite result is reported as a failure.
///
/// Reads `StepContext`, `Gs4Constants`, `Materials`, `RheologyTable<M>`, `MaterialId`,
/// `VelocityGradient`, `PredictedDensity`, `PredictedDeformationGradient`; writes
/// `CauchyStress`, `StabilityData`, `M::State`.
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn evaluate_model<M: Rheology>(
    ctx: Res<StepContext>,
    gs4: Res<Gs4Constants>,
    materials: Res<Materials>,
    table: Res<RheologyTable<M>>,
    failures: Res<FailureCollector>,
    mut q: Query<
        (
            Entity,
            &MaterialId,
            &VelocityGradient,
            &PredictedDensity,
            Option<&PredictedDeformationGradient>,
            &mut CauchyStress,
            &mut StabilityData,
            &mut M::State,
        ),
        With<Particle>,
    >,
) {
    let coefficients = step_coefficients(&ctx, &gs4);
    let rate_evaluation = ctx.rate_evaluation;
    q.par_iter_mut()
        .for_each(|(e, mat, l, rho, ft, mut sigma, mut stab, mut state)| {
            let Some(model) = table.get(*mat) else {
                failures.record(missing_model::<M>(e, *mat));
                return;
            };
            if M::NEEDS_DEFORMATION_GRADIENT && ft.is_none() {
                failures.record(FailureReport::particle(
                    e,
                    "rheology",
                    mat.0 as f64,
                    &format!(
                        "the particle carries the state of {} but no DeformationGradient (attach the model with attach_model, or spawn DeformationGradient and PredictedDeformationGradient with the state)",
                        std::any::type_name::<M>()
                    ),
                ));
                return;
            }
            let material = materials.get(*mat);
            let mut rc =
                RheologyContext::new(l.0, rho.value, material, coefficients, rate_evaluation);
            rc.deformation_gradient = ft.map(|f| f.0);
            let out = model.evaluate(&rc, state.bypass_change_detection());
            if !out.is_finite() {
                failures.record(FailureReport::particle(
                    e,
                    "rheology stress",
                    first_non_finite(&out) as f64,
                    &format!(
                        "{} returned a non-finite stress or modulus (too large a step for its relaxation or stiffness, or ill-posed parameters)",
                        std::any::type_name::<M>()
                    ),
                ));
                return;
            }
            sigma.bypass_change_detection().0 += out.stress;
            let stab = stab.bypass_change_detection();
            let rho = rho.value;
            stab.wave_speed_sq += (4.0 / 3.0 * out.shear_modulus + out.bulk_modulus) / rho;
            stab.kinematic_viscosity = stab.kinematic_viscosity.max(out.tangent_viscosity / rho);
            stab.relaxation_rate = stab.relaxation_rate.max(out.relaxation_rate);
        });
}

/// S15 for model `M`: commits the state of every particle with `M::State`. During the
/// start-up rate evaluation it commits only if `consistent_startup` is on (otherwise the
/// stored rates are used as given, like the core's).
///
/// Reads `StepContext`, `Gs4Constants`, `MpmConfig`, `Materials`, `RheologyTable<M>`,
/// `MaterialId`, `VelocityGradient`, `PredictedDensity`, `DeformationGradient`; writes
/// `M::State`.
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn commit_model<M: Rheology>(
    ctx: Res<StepContext>,
    gs4: Res<Gs4Constants>,
    config: Res<MpmConfig>,
    materials: Res<Materials>,
    table: Res<RheologyTable<M>>,
    mut q: Query<
        (
            &MaterialId,
            &VelocityGradient,
            &PredictedDensity,
            Option<&DeformationGradient>,
            &mut M::State,
        ),
        With<Particle>,
    >,
) {
    if ctx.rate_evaluation && !config.integrator.consistent_startup {
        return;
    }
    let coefficients = step_coefficients(&ctx, &gs4);
    let rate_evaluation = ctx.rate_evaluation;
    q.par_iter_mut().for_each(|(mat, l, rho, f, mut state)| {
        // A missing entry was reported by the evaluate system of this step.
        let Some(model) = table.get(*mat) else {
            return;
        };
        let mut rc = RheologyContext::new(
            l.0,
            rho.value,
            materials.get(*mat),
            coefficients,
            rate_evaluation,
        );
        rc.deformation_gradient = f.map(|f| f.0);
        model.commit(&rc, state.bypass_change_detection());
    });
}

/// Why a model could not be attached.
#[derive(Debug, Error)]
pub enum AttachError {
    /// `RheologyPlugin<M>` was not added.
    #[error("no RheologyTable<{model}>: add RheologyPlugin<{model}> first")]
    NoTable {
        /// The model type.
        model: &'static str,
    },
    /// The material is not in `Materials`.
    #[error("material id {0} is not in Materials")]
    UnknownMaterial(u16),
    /// The material has no entry in the model's table.
    #[error(
        "material '{material}' has no entry in RheologyTable<{model}>: insert its parameters first"
    )]
    NoModel {
        /// Material name.
        material: String,
        /// The model type.
        model: &'static str,
    },
    /// The parameters are invalid for this material.
    #[error("{model} parameters of material '{material}' are invalid: {}", list(.errors))]
    InvalidParameters {
        /// Material name.
        material: String,
        /// The model type.
        model: &'static str,
        /// Every violated constraint.
        errors: Vec<InvalidParameter>,
    },
}

fn list(errors: &[InvalidParameter]) -> String {
    errors
        .iter()
        .map(|e| e.to_string())
        .collect::<Vec<_>>()
        .join("; ")
}

/// Attaches model `M` to every particle of `material` that does not carry `M::State` yet:
/// inserts [`Rheology::initial_state`] (and, for a model with
/// [`Rheology::NEEDS_DEFORMATION_GRADIENT`], F = I where the particle has no F yet). The material must have an entry in
/// [`RheologyTable<M>`], which is validated against the material first. Returns the number of
/// particles that received the state.
///
/// Call it after spawning the material's particles and before the first frame (the start-up
/// rate evaluation then sets consistent initial rates). Particles spawned later need the state
/// in their spawn bundle ([`RheologyTable::initial_state`]) or another call.
///
/// Newtonian materials (F_v = 1) need no model: leave them out of the table so that their
/// particles carry no state and cost nothing.
pub fn attach_model<M: Rheology>(
    world: &mut World,
    material: MaterialId,
) -> Result<usize, AttachError> {
    let model_name = std::any::type_name::<M>();
    let Some(table) = world.get_resource::<RheologyTable<M>>() else {
        return Err(AttachError::NoTable { model: model_name });
    };
    let Some(mat) = world
        .get_resource::<Materials>()
        .and_then(|m| m.list.get(material.0 as usize))
    else {
        return Err(AttachError::UnknownMaterial(material.0));
    };
    let Some(model) = table.get(material) else {
        return Err(AttachError::NoModel {
            material: mat.name.clone(),
            model: model_name,
        });
    };
    if let Err(errors) = model.validate(mat) {
        return Err(AttachError::InvalidParameters {
            material: mat.name.clone(),
            model: model_name,
            errors,
        });
    }
    let state = model.initial_state();
    let targets: Vec<Entity> = world
        .query_filtered::<(Entity, &MaterialId), (With<Particle>, Without<M::State>)>()
        .iter(world)
        .filter(|(_, m)| **m == material)
        .map(|(e, _)| e)
        .collect();
    let n = targets.len();
    if M::NEEDS_DEFORMATION_GRADIENT {
        world.insert_batch_if_new(targets.iter().map(|&e| {
            (
                e,
                (
                    DeformationGradient::default(),
                    PredictedDeformationGradient::default(),
                ),
            )
        }));
    }
    world.insert_batch(targets.into_iter().map(|e| (e, state.clone())));
    Ok(n)
}

/// [`attach_model`] from a system: `commands.attach_model::<M>(material)`. The attachment
/// happens when the commands are applied; an error goes to Bevy's error handler (which
/// panics by default).
pub trait RheologyCommandsExt {
    /// Queues [`attach_model::<M>`](attach_model) for `material`.
    fn attach_model<M: Rheology>(&mut self, material: MaterialId);
}

impl RheologyCommandsExt for Commands<'_, '_> {
    fn attach_model<M: Rheology>(&mut self, material: MaterialId) {
        self.queue(move |world: &mut World| attach_model::<M>(world, material).map(|_| ()));
    }
}
