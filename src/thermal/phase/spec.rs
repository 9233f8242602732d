//! Scene entries of phase change and temperature-dependent viscosity (`phase_change: [ ... ]`,
//! `temperature_viscosity: [ ... ]`): [`PhaseChangeSpec`], [`TemperatureViscositySpec`], their
//! simulation values ([`PhaseChange`] of §4.1–4.2, [`TemperatureViscosity`] of §4.3) and the
//! checks of both sections ([`validate_phase_entries`]).
use serde::{Deserialize, Serialize};

use super::model::{PhaseChange, default_true};
use super::temperature_viscosity::{TemperatureLaw, TemperatureViscosity};
use crate::math::Real;

/// Scene entry of a phase change (`phase_change: [ ... ]`): a material name and the
/// [`PhaseChange`] fields.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseChangeSpec {
    /// Name of a material.
    pub material: String,
    /// T_m.
    pub melting_temperature: Real,
    /// ΔT_m ≥ 0. Default 0.
    #[serde(default)]
    pub ramp: Real,
    /// G_s \[Pa\] > 0.
    pub shear_modulus: f64,
    /// D12 reset. Default true.
    #[serde(default = "default_true")]
    pub reset_shape_memory: bool,
}

impl PhaseChangeSpec {
    /// The simulation value.
    pub fn to_phase_change(&self) -> PhaseChange {
        PhaseChange {
            melting_temperature: self.melting_temperature,
            ramp: self.ramp,
            shear_modulus: self.shear_modulus,
            reset_shape_memory: self.reset_shape_memory,
        }
    }
}

/// Scene entry of a temperature-dependent viscosity (`temperature_viscosity: [ ... ]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TemperatureViscositySpec {
    /// Name of a material.
    pub material: String,
    /// The law.
    pub law: TemperatureLaw,
    /// μ_max \[Pa·s\]. Default none.
    #[serde(default)]
    pub max_viscosity: Option<f64>,
}

impl TemperatureViscositySpec {
    /// The simulation value.
    pub fn to_temperature_viscosity(&self) -> TemperatureViscosity {
        TemperatureViscosity {
            law: self.law.clone(),
            max_viscosity: self.max_viscosity,
        }
    }
}

/// Checks a scene's `phase_change` and `temperature_viscosity` sections (known material, one
/// entry per material, parameters, the melting temperature against the material's `thermal`
/// entry) given the scene's `materials` and `thermal` section. Returns every issue.
pub fn validate_phase_entries(
    phase_change: &[PhaseChangeSpec],
    temperature_viscosity: &[TemperatureViscositySpec],
    thermal: &crate::thermal::scene::ThermalSpec,
    materials: &[crate::material::FluidMaterial],
) -> Vec<crate::validation::FieldIssue> {
    use crate::validation::FieldIssue;
    let mut issues = Vec::new();
    let find = |name: &str| materials.iter().find(|m| m.name == name);
    for (i, p) in phase_change.iter().enumerate() {
        if find(&p.material).is_none() {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].material"),
                format!("unknown material `{}`", p.material),
            ));
        }
        if let Some(k) = phase_change[..i]
            .iter()
            .position(|q| q.material == p.material)
        {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].material"),
                format!(
                    "material `{}` already has a phase change (phase_change[{k}])",
                    p.material
                ),
            ));
        }
        if let Some(t) = thermal
            .materials
            .iter()
            .find(|m| m.material == p.material)
            .and_then(|m| m.melting_temperature)
            && t != p.melting_temperature
        {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].melting_temperature"),
                format!(
                    "must equal the material's thermal melting_temperature {t} (got {})",
                    p.melting_temperature
                ),
            ));
        }
        for e in p.to_phase_change().validate().err().unwrap_or_default() {
            issues.push(FieldIssue::new(
                format!("phase_change[{i}].{}", e.field),
                format!("{} (got {})", e.constraint, phase_value(p, e.field)),
            ));
        }
    }
    for (i, v) in temperature_viscosity.iter().enumerate() {
        let Some(m) = find(&v.material) else {
            issues.push(FieldIssue::new(
                format!("temperature_viscosity[{i}].material"),
                format!("unknown material `{}`", v.material),
            ));
            continue;
        };
        if let Some(k) = temperature_viscosity[..i]
            .iter()
            .position(|q| q.material == v.material)
        {
            issues.push(FieldIssue::new(
                format!("temperature_viscosity[{i}].material"),
                format!(
                    "material `{}` already has a temperature law (temperature_viscosity[{k}])",
                    v.material
                ),
            ));
        }
        for e in v
            .to_temperature_viscosity()
            .validate(m.viscosity as f64)
            .err()
            .unwrap_or_default()
        {
            issues.push(FieldIssue::new(
                format!("temperature_viscosity[{i}].{}", e.field),
                e.constraint,
            ));
        }
    }
    issues
}

fn phase_value(p: &PhaseChangeSpec, field: &str) -> String {
    match field {
        "melting_temperature" => p.melting_temperature.to_string(),
        "ramp" => p.ramp.to_string(),
        "shear_modulus" => p.shear_modulus.to_string(),
        _ => "?".into(),
    }
}
