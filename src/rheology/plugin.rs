//! [`RheologyPlugin<M>`]: one model's systems in the step, its particle initializer and its
//! scene entry; attaching a model to a material's particles ([`attach_model`]).
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use bevy_ecs::schedule::common_conditions::any_with_component;
use thiserror::Error;

use super::{
    FirstOrderCoefficients, InvalidParameter, ModelRegistry, Rheology, RheologyContext,
    RheologyOutput, RheologyTable,
};
use crate::components::{
    CauchyStress, DeformationGradient, Particle, PredictedDeformationGradient, PredictedDensity,
    StabilityData, VelocityGradient,
};
use crate::config::MpmConfig;
use crate::failure::{FailureCollector, FailureReport};
use crate::material::{MaterialId, Materials};
use crate::math::Real;
use crate::spawn::ParticleInitializers;
use crate::step::schedule::{
    CommitSystems, ConstitutiveSystems, Gs4Constants, MpmStep, StepContext, init_step_schedule,
};

/// The sets of one model's systems, named by [`Rheology::NAME`]. Models run in the order of
/// their names (each [`RheologyPlugin`] orders its sets against the models added before it), so
/// that a particle carrying two models' states gets the same sum of stresses whatever the
/// order in which the plugins were added.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ModelSet {
    /// The model's evaluate system, in [`ConstitutiveSystems::Models`].
    Evaluate(&'static str),
    /// The model's commit system, in [`CommitSystems::Models`].
    Commit(&'static str),
}

/// Registers model `M`: the [`RheologyTable<M>`] resource (with the entries given here, merged
/// into an existing table) and its evaluate and commit systems in the [`MpmStep`] schedule.
///
/// It also registers the model's particle initializer ([`init_rheology_state`] in
/// [`ParticleInitializers`], so that emitted particles get the model's state) and its scene
/// entry in the app's [`ModelRegistry`] (so that a scene loaded with that registry can name it:
/// `model: NAME((...))`). Plugins may be added in any order. Then attach the model to the
/// particles of each material with [`attach_model`].
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
        init_step_schedule(app);
        if !app.is_plugin_added::<super::metrics::RheologyMetricsPlugin>() {
            app.add_plugins(super::metrics::RheologyMetricsPlugin);
        }
        app.init_resource::<ParticleInitializers>()
            .init_resource::<ModelRegistry>();
        let world = app.world_mut();
        world
            .resource_mut::<ParticleInitializers>()
            .add(std::any::type_name::<M>(), init_rheology_state::<M>);
        M::travel(world);
        if M::NEEDS_DEFORMATION_GRADIENT {
            crate::distributed::travel::<crate::components::DeformationGradient>(world);
            crate::distributed::travel::<crate::components::PredictedDeformationGradient>(world);
        }
        if let Some(mut table) = world.get_resource_mut::<RheologyTable<M>>() {
            for (id, m) in self.table.iter() {
                table.insert(id, m.clone());
            }
        } else {
            world.insert_resource(self.table.clone());
        }
        // Order this model's sets against the models added before it, by name.
        let earlier = {
            let mut registry = world.resource_mut::<ModelRegistry>();
            registry.register::<M>();
            registry.mark_systems_added::<M>()
        };
        for other in earlier {
            for (mine, theirs) in [
                (ModelSet::Evaluate(M::NAME), ModelSet::Evaluate(other)),
                (ModelSet::Commit(M::NAME), ModelSet::Commit(other)),
            ] {
                if other < M::NAME {
                    app.configure_sets(MpmStep, mine.after(theirs));
                } else {
                    app.configure_sets(MpmStep, mine.before(theirs));
                }
            }
        }
        app.configure_sets(
            MpmStep,
            (
                ModelSet::Evaluate(M::NAME).in_set(ConstitutiveSystems::Models),
                ModelSet::Commit(M::NAME).in_set(CommitSystems::Models),
            ),
        );
        app.add_systems(
            MpmStep,
            (
                evaluate_model::<M>
                    .in_set(ModelSet::Evaluate(M::NAME))
                    .run_if(any_with_component::<M::State>),
                commit_model::<M>
                    .in_set(ModelSet::Commit(M::NAME))
                    .run_if(any_with_component::<M::State>),
            ),
        );
    }

    fn is_unique(&self) -> bool {
        true
    }
}

/// Gives `particles` the initial state of model `M` if their material uses it (an entry in
/// [`RheologyTable<M>`]), plus F = I and F̃ = I where missing for a model that reads the
/// deformation gradient ([`Rheology::NEEDS_DEFORMATION_GRADIENT`]).
pub fn init_rheology_state<M: Rheology>(
    world: &mut World,
    material: MaterialId,
    particles: &[Entity],
) {
    let Some(state) = world
        .get_resource::<RheologyTable<M>>()
        .and_then(|t| t.initial_state(material))
    else {
        return;
    };
    if M::NEEDS_DEFORMATION_GRADIENT {
        world.insert_batch_if_new(particles.iter().map(|&e| {
            (
                e,
                (
                    DeformationGradient::default(),
                    PredictedDeformationGradient::default(),
                ),
            )
        }));
    }
    world.insert_batch_if_new(particles.iter().map(|&e| (e, state.clone())));
}

/// The GS4-1 weights of the step being run, in `f64`, and whether the mechanics are first order.
fn step_coefficients(ctx: &StepContext, gs4: &Gs4Constants) -> FirstOrderCoefficients {
    if ctx.rate_evaluation {
        FirstOrderCoefficients::rate_evaluation()
    } else {
        FirstOrderCoefficients::step(&gs4.params, ctx.dt)
            .with_first_order_mechanics(!gs4.scheme.is_gs4())
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
