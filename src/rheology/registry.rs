//! The models a scene file can name: [`ModelRegistry`] (name → parameter type) and
//! [`ModelSpec`], one model with its parameters, of any registered type.
//!
//! A model is one file plus one registration: [`RheologyPlugin<M>`](super::RheologyPlugin)
//! registers `M` in the app's registry (and [`ModelRegistry::default`] holds the shipped
//! models). The scene loader parses `model: NAME((...))` through the registry it is given, and
//! validation, warnings, the plugins a scene adds and the attachment of the model's state all
//! dispatch through [`ModelSpec`], so neither the loader nor the emitter names a model type.
//!
//! ```
//! use treacle::rheology::{ModelRegistry, Su2021Unified};
//! let registry = ModelRegistry::default();
//! let spec = registry
//!     .parse_model(
//!         "Su2021Unified((backbone_relaxation_time: 0.1, stretch_relaxation_time: 0.1, \
//!          modulus: Derived, anisotropy: 0.1, arms: 2.0, f_mode: Full, \
//!          implicit_relaxation: true, stretch_limit: Unbounded))",
//!     )
//!     .unwrap();
//! assert_eq!(spec.name(), "Su2021Unified");
//! assert!(spec.downcast_ref::<Su2021Unified>().is_some());
//! ```
use std::any::{Any, TypeId};
use std::cell::RefCell;
use std::fmt;

use bevy_app::App;
use bevy_ecs::prelude::*;
use serde::de::{self, DeserializeSeed, Deserializer, EnumAccess, VariantAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

use super::plugin::{AttachError, RheologyPlugin, attach_model};
use super::{
    InvalidParameter, Li2024ElastoPlastic, LiViscosity, NeoHookean, ParameterWarning, Rheology,
    RheologyTable, Su2021Unified,
};
use crate::material::{FluidMaterial, MaterialId};

/// The object-safe face of a [`Rheology`] parameter value (implemented for every model).
trait DynModel: Any + Send + Sync {
    fn name(&self) -> &'static str;
    fn clone_box(&self) -> Box<dyn DynModel>;
    fn eq_dyn(&self, other: &dyn DynModel) -> bool;
    fn fmt_dyn(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result;
    fn as_any(&self) -> &dyn Any;
    fn as_any_mut(&mut self) -> &mut dyn Any;
    fn erased(&self) -> &dyn erased_serde::Serialize;
    fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>>;
    fn warnings(&self, material: &FluidMaterial) -> Vec<ParameterWarning>;
    fn add_to_app(&self, app: &mut App, material: MaterialId);
    fn attach(&self, world: &mut World, material: MaterialId) -> Result<usize, AttachError>;
}

impl<M: Rheology> DynModel for M {
    fn name(&self) -> &'static str {
        M::NAME
    }
    fn clone_box(&self) -> Box<dyn DynModel> {
        Box::new(self.clone())
    }
    fn eq_dyn(&self, other: &dyn DynModel) -> bool {
        other.as_any().downcast_ref::<M>() == Some(self)
    }
    fn fmt_dyn(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self, f)
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }
    fn erased(&self) -> &dyn erased_serde::Serialize {
        self
    }
    fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        Rheology::validate(self, material)
    }
    fn warnings(&self, material: &FluidMaterial) -> Vec<ParameterWarning> {
        Rheology::warnings(self, material)
    }
    fn add_to_app(&self, app: &mut App, material: MaterialId) {
        if app.is_plugin_added::<RheologyPlugin<M>>() {
            app.world_mut()
                .resource_mut::<RheologyTable<M>>()
                .insert(material, self.clone());
        } else {
            app.add_plugins(RheologyPlugin::<M>::default().with(material, self.clone()));
        }
    }
    fn attach(&self, world: &mut World, material: MaterialId) -> Result<usize, AttachError> {
        attach_model::<M>(world, material)
    }
}

/// One rheology model with its parameters, of any registered type: what a scene's
/// `rheology[i].model` holds. In RON it reads `NAME((field: value, ...))`.
pub struct ModelSpec(Box<dyn DynModel>);

impl ModelSpec {
    /// Wraps the parameters of model `M`.
    pub fn new<M: Rheology>(model: M) -> Self {
        Self(Box::new(model))
    }

    /// The model's name ([`Rheology::NAME`]).
    pub fn name(&self) -> &'static str {
        self.0.name()
    }

    /// The parameters, if the model is `M`.
    pub fn downcast_ref<M: Rheology>(&self) -> Option<&M> {
        self.0.as_any().downcast_ref()
    }

    /// The parameters, mutably, if the model is `M`.
    pub fn downcast_mut<M: Rheology>(&mut self) -> Option<&mut M> {
        self.0.as_any_mut().downcast_mut()
    }

    /// The Rust type of the model (two specs of the same model compare equal).
    pub fn model_type(&self) -> TypeId {
        self.0.as_any().type_id()
    }

    /// Every violated parameter constraint for `material` ([`Rheology::validate`]).
    pub fn validate(&self, material: &FluidMaterial) -> Result<(), Vec<InvalidParameter>> {
        self.0.validate(material)
    }

    /// Accepted but questionable parameters for `material` ([`Rheology::warnings`]).
    pub fn warnings(&self, material: &FluidMaterial) -> Vec<ParameterWarning> {
        self.0.warnings(material)
    }

    /// Gives `material` this model in `app`: adds the model's [`RheologyPlugin`] with the entry,
    /// or inserts the entry into its table if the plugin is already there.
    pub fn add_to_app(&self, app: &mut App, material: MaterialId) {
        self.0.add_to_app(app, material)
    }

    /// Attaches the model's state to the particles of `material` ([`attach_model`]).
    pub fn attach(&self, world: &mut World, material: MaterialId) -> Result<usize, AttachError> {
        self.0.attach(world, material)
    }
}

impl Clone for ModelSpec {
    fn clone(&self) -> Self {
        Self(self.0.clone_box())
    }
}

impl PartialEq for ModelSpec {
    fn eq(&self, other: &Self) -> bool {
        self.0.eq_dyn(other.0.as_ref())
    }
}

impl fmt::Debug for ModelSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}(", self.name())?;
        self.0.fmt_dyn(f)?;
        f.write_str(")")
    }
}

impl Serialize for ModelSpec {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_newtype_variant("ModelSpec", 0, self.name(), self.0.erased())
    }
}

type DeserializeFn =
    fn(&mut dyn erased_serde::Deserializer<'_>) -> Result<ModelSpec, erased_serde::Error>;

/// A registered model: its scene name, Rust type and parameter parser.
#[derive(Clone, Copy)]
pub struct ModelEntry {
    /// [`Rheology::NAME`].
    pub name: &'static str,
    /// The Rust type name (for messages).
    pub type_name: &'static str,
    type_id: TypeId,
    deserialize: DeserializeFn,
}

impl fmt::Debug for ModelEntry {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.name, self.type_name)
    }
}

fn deserialize_model<M: Rheology>(
    d: &mut dyn erased_serde::Deserializer<'_>,
) -> Result<ModelSpec, erased_serde::Error> {
    erased_serde::deserialize::<M>(d).map(ModelSpec::new)
}

/// The rheology models a scene may name (a Resource of the app: every
/// [`RheologyPlugin<M>`](super::RheologyPlugin) registers its model). The default holds the
/// shipped models: `Su2021Unified`, `Li2024` ([`LiViscosity`]), `Li2024ElastoPlastic` and
/// `NeoHookean`.
#[derive(Resource, Clone, Debug)]
pub struct ModelRegistry {
    entries: Vec<ModelEntry>,
    /// Names of the models whose plugin (systems) was added, in the order added.
    with_systems: Vec<&'static str>,
}

impl Default for ModelRegistry {
    fn default() -> Self {
        let mut r = Self::empty();
        r.register::<Su2021Unified>();
        r.register::<LiViscosity>();
        r.register::<Li2024ElastoPlastic>();
        r.register::<NeoHookean>();
        r
    }
}

thread_local! {
    /// The registries scene parsing on this thread resolves model names with (innermost last).
    static PARSING: RefCell<Vec<ModelRegistry>> = const { RefCell::new(Vec::new()) };
}

impl ModelRegistry {
    /// A registry without models.
    pub fn empty() -> Self {
        Self {
            entries: Vec::new(),
            with_systems: Vec::new(),
        }
    }

    /// Registers model `M` under [`Rheology::NAME`] (again: no change).
    ///
    /// # Panics
    /// If another type is registered under the same name (two models cannot share a name in
    /// scene files).
    pub fn register<M: Rheology>(&mut self) -> &mut Self {
        let type_id = TypeId::of::<M>();
        if let Some(e) = self.get(M::NAME) {
            assert!(
                e.type_id == type_id,
                "rheology model name `{}` is registered for {} and {}",
                M::NAME,
                e.type_name,
                std::any::type_name::<M>()
            );
            return self;
        }
        self.entries.push(ModelEntry {
            name: M::NAME,
            type_name: std::any::type_name::<M>(),
            type_id,
            deserialize: deserialize_model::<M>,
        });
        self
    }

    /// Records that `M`'s systems were added; returns the models added before it.
    pub(crate) fn mark_systems_added<M: Rheology>(&mut self) -> Vec<&'static str> {
        let earlier: Vec<&'static str> = self
            .with_systems
            .iter()
            .copied()
            .filter(|n| *n != M::NAME)
            .collect();
        if !self.with_systems.contains(&M::NAME) {
            self.with_systems.push(M::NAME);
        }
        earlier
    }

    /// The entry registered under `name`.
    pub fn get(&self, name: &str) -> Option<&ModelEntry> {
        self.entries.iter().find(|e| e.name == name)
    }

    /// The registered names, in registration order.
    pub fn names(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.entries.iter().map(|e| e.name)
    }

    /// Runs `f` (which deserialises [`ModelSpec`]s, e.g. parses a scene file) with this
    /// registry resolving model names.
    pub fn while_parsing<R>(&self, f: impl FnOnce() -> R) -> R {
        struct Pop;
        impl Drop for Pop {
            fn drop(&mut self) {
                PARSING.with(|p| p.borrow_mut().pop());
            }
        }
        PARSING.with(|p| p.borrow_mut().push(self.clone()));
        let _pop = Pop;
        f()
    }

    /// Parses one model from RON text (`NAME((...))`).
    pub fn parse_model(&self, text: &str) -> Result<ModelSpec, ron::error::SpannedError> {
        self.while_parsing(|| ron::from_str(text))
    }
}

/// The registry of the innermost [`ModelRegistry::while_parsing`] on this thread, or the
/// default one.
fn active_registry() -> ModelRegistry {
    PARSING
        .with(|p| p.borrow().last().cloned())
        .unwrap_or_default()
}

impl<'de> Deserialize<'de> for ModelSpec {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let registry = active_registry();
        // serde wants 'static variant names for its messages; a registry has few entries
        // and is built once per app, so the leak is bounded.
        let names: &'static [&'static str] =
            Box::leak(registry.names().collect::<Vec<_>>().into_boxed_slice());
        deserializer.deserialize_enum("ModelSpec", names, ModelVisitor { registry, names })
    }
}

struct ModelVisitor {
    registry: ModelRegistry,
    names: &'static [&'static str],
}

impl<'de> Visitor<'de> for ModelVisitor {
    type Value = ModelSpec;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "a rheology model, one of {:?}", self.names)
    }

    fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<ModelSpec, A::Error> {
        let (name, variant) = data.variant_seed(VariantName)?;
        let Some(entry) = self.registry.get(&name) else {
            return Err(de::Error::unknown_variant(&name, self.names));
        };
        variant.newtype_variant_seed(EntrySeed(*entry))
    }
}

/// The variant name, read as an identifier (`NAME` in `NAME((...))`).
struct VariantName;

impl<'de> DeserializeSeed<'de> for VariantName {
    type Value = String;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<String, D::Error> {
        deserializer.deserialize_identifier(self)
    }
}

impl Visitor<'_> for VariantName {
    type Value = String;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("a rheology model name")
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<String, E> {
        Ok(v.to_string())
    }
}

struct EntrySeed(ModelEntry);

impl<'de> DeserializeSeed<'de> for EntrySeed {
    type Value = ModelSpec;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<ModelSpec, D::Error> {
        let mut erased = <dyn erased_serde::Deserializer>::erase(deserializer);
        (self.0.deserialize)(&mut erased).map_err(de::Error::custom)
    }
}
