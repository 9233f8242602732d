//! The `thermal` section of a scene file (reference: `docs/scenes.md`, "Heat").
//!
//! ```ron
//! thermal: (
//!     materials: [(material: "wax", diffusivity: 0.01, initial_temperature: 0.0,
//!                  melting_temperature: Some(0.1))],
//!     walls: (y_min: Some(1.0)),                       // hot floor; other faces insulated
//!     colliders: [(collider: 0, temperature: 0.0)],    // colliders[0] is a cold body
//! ),
//! ```
//!
//! A scene has heat when `materials` is not empty; only then is the [`ThermalPlugin`]
//! added.
use serde::{Deserialize, Serialize};

use super::{
    AmbientExchange, HeatSolverConfig, HeatTransfer, ThermalConfig, ThermalMaterial, ThermalPlugin,
    WallTemperatures,
};
use crate::material::Materials;
use crate::math::Real;
use crate::validation::{FieldIssue, MaterialEntry, SceneContext};

/// The `thermal` section. Default: no heat.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ThermalSpec {
    /// Heated materials (each names a material of the scene once).
    pub materials: Vec<ThermalMaterialSpec>,
    /// Prescribed temperatures of the domain faces (`Some(T)`); `None` = insulated.
    pub walls: WallTemperatures,
    /// Prescribed-temperature colliders.
    pub colliders: Vec<ColliderTemperatureSpec>,
    /// Optional exchange with an ambient temperature at the free surface.
    pub ambient: Option<AmbientExchange>,
    /// CG and multigrid settings.
    pub solver: HeatSolverConfig,
    /// GS4 (ρ∞, ρs) of the heat equation; default: the integrator's.
    pub gs4: Option<(f64, f64)>,
    /// Particle update of the temperature (`flip` fraction, kept over `integrator.flip_interval`).
    /// Default: α_T = 0.99.
    pub transfer: HeatTransfer,
}

/// Thermal parameters of one material in a scene file: its name and the fields of
/// [`ThermalMaterial`], written flat (`(material: "honey", diffusivity: 0.01, ...)`).
pub type ThermalMaterialSpec = MaterialEntry<ThermalMaterial>;

/// A prescribed temperature on the collider `colliders[collider]` of the scene.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColliderTemperatureSpec {
    /// Index into the scene's `colliders`.
    pub collider: usize,
    /// Temperature T_D of the nodes inside it.
    pub temperature: Real,
}

/// The thermal part of a loaded scene.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneThermal {
    /// The resource of the [`ThermalPlugin`].
    pub config: ThermalConfig,
    /// (collider index in file order, T_D).
    pub collider_temperatures: Vec<(usize, Real)>,
}

impl SceneThermal {
    /// The plugin for this scene.
    pub fn plugin(&self) -> ThermalPlugin {
        ThermalPlugin::new(self.config.clone())
    }
}

impl ThermalSpec {
    /// Whether the scene has heat (some heated material).
    pub fn has_heat(&self) -> bool {
        !self.materials.is_empty()
    }

    /// The runtime configuration (`None` without heat). Materials must exist (validated).
    pub fn to_scene(&self, materials: &Materials) -> Option<SceneThermal> {
        if !self.has_heat() {
            return None;
        }
        let config = ThermalConfig {
            materials: self
                .materials
                .iter()
                .filter_map(|m| Some((materials.find(&m.material)?, m.params)))
                .collect(),
            walls: self.walls,
            ambient: self.ambient,
            solver: self.solver,
            gs4: self.gs4,
            transfer: self.transfer,
        };
        Some(SceneThermal {
            config,
            collider_temperatures: self
                .colliders
                .iter()
                .map(|c| (c.collider, c.temperature))
                .collect(),
        })
    }
}

/// Every issue of a scene's `thermal` section `spec`, with field paths
/// (`thermal.materials[0].diffusivity`), given the scene's facts `ctx` and its number of
/// colliders.
pub fn validate_thermal(
    spec: &ThermalSpec,
    ctx: &SceneContext,
    colliders: usize,
) -> Vec<FieldIssue> {
    let mut issues = Vec::new();
    for (i, m) in spec.materials.iter().enumerate() {
        let path = format!("thermal.materials[{i}]");
        if ctx.material(&m.material).is_none() {
            issues.push(FieldIssue::new(
                format!("{path}.material"),
                format!("unknown material `{}`", m.material),
            ));
        }
        if let Some(k) = spec.materials[..i]
            .iter()
            .position(|q| q.material == m.material)
        {
            issues.push(FieldIssue::new(
                format!("{path}.material"),
                format!(
                    "material `{}` already has thermal parameters (thermal.materials[{k}])",
                    m.material
                ),
            ));
        }
        if let Err((field, constraint)) = m.params.validate() {
            let value = match field {
                "diffusivity" => m.diffusivity.to_string(),
                "relaxation_time" => m.relaxation_time.to_string(),
                "fourier_fraction" => m.fourier_fraction.to_string(),
                "initial_temperature" => m.initial_temperature.to_string(),
                "melting_temperature" => format!("{:?}", m.melting_temperature),
                "volumetric_source" => m.volumetric_source.to_string(),
                "mechanical_heating" => m.mechanical_heating.to_string(),
                "latent_heat" => m.latent_heat.to_string(),
                "latent_width" => m.latent_width.to_string(),
                _ => m.surface_source.to_string(),
            };
            issues.push(FieldIssue::new(
                format!("{path}.{field}"),
                format!("{constraint} (got {value})"),
            ));
        }
        if i > 0 && m.params.heat_parameters() != spec.materials[0].params.heat_parameters() {
            issues.push(FieldIssue::new(
                path.clone(),
                "all heated materials must share diffusivity, relaxation_time and \
                 fourier_fraction (the heat solve has constant coefficients, ALGORITHM §3.1)",
            ));
        }
    }
    let latent: Vec<(usize, &ThermalMaterialSpec)> = spec
        .materials
        .iter()
        .enumerate()
        .filter(|(_, m)| m.latent_heat > 0.0)
        .collect();
    if let Some((j, first)) = latent.first() {
        for (i, m) in &latent[1..] {
            if m.melting_temperature != first.melting_temperature
                || m.latent_width != first.latent_width
            {
                issues.push(FieldIssue::new(
                    format!("thermal.materials[{i}].latent_heat"),
                    format!(
                        "materials with latent heat must share melting_temperature and \
                         latent_width (thermal.materials[{j}] has {:?} and {})",
                        first.melting_temperature, first.latent_width
                    ),
                ));
            }
        }
    }
    for (i, c) in spec.colliders.iter().enumerate() {
        if c.collider >= colliders {
            issues.push(FieldIssue::new(
                format!("thermal.colliders[{i}].collider"),
                format!(
                    "no collider with index {} (the scene has {})",
                    c.collider, colliders
                ),
            ));
        }
        if !c.temperature.is_finite() {
            issues.push(FieldIssue::new(
                format!("thermal.colliders[{i}].temperature"),
                "must be finite",
            ));
        }
    }
    for (name, t) in [
        ("x_min", spec.walls.x_min),
        ("x_max", spec.walls.x_max),
        ("y_min", spec.walls.y_min),
        ("y_max", spec.walls.y_max),
        ("z_min", spec.walls.z_min),
        ("z_max", spec.walls.z_max),
    ] {
        if t.is_some_and(|t| !t.is_finite()) {
            issues.push(FieldIssue::new(
                format!("thermal.walls.{name}"),
                "must be finite",
            ));
        }
    }
    if let Some(a) = spec.ambient {
        if !a.temperature.is_finite() {
            issues.push(FieldIssue::new(
                "thermal.ambient.temperature",
                "must be finite",
            ));
        }
        if !(a.coefficient.is_finite() && a.coefficient >= 0.0) {
            issues.push(FieldIssue::new(
                "thermal.ambient.coefficient",
                format!("must be a finite number ≥ 0 m/s (got {})", a.coefficient),
            ));
        }
    }
    if let Err((field, constraint)) = spec.solver.cg.validate() {
        issues.push(FieldIssue::new(
            format!("thermal.solver.cg.{field}"),
            constraint,
        ));
    }
    if let Err(super::MultigridError::InvalidParameter { field, reason }) =
        spec.solver.multigrid.validate()
    {
        issues.push(FieldIssue::new(
            format!("thermal.solver.multigrid.{field}"),
            reason,
        ));
    }
    if let Some((ri, rs)) = spec.gs4
        && let Err(e) = crate::gs4::Gs4Params::new(ri, rs)
    {
        issues.push(FieldIssue::new("thermal.gs4", e.to_string()));
    }
    let flip = spec.transfer.flip;
    if !(flip.is_finite() && (0.0..=1.0).contains(&flip)) {
        issues.push(FieldIssue::new(
            "thermal.transfer.flip",
            format!("must lie in [0, 1] (got {flip})"),
        ));
    }
    issues
}
