//! Scene entries of phase change and temperature-dependent viscosity (`phase_change: [ ... ]`,
//! `temperature_viscosity: [ ... ]`): [`PhaseChangeSpec`], [`TemperatureViscositySpec`], their
//! simulation values ([`PhaseChange`] of §4.1–4.2, [`TemperatureViscosity`] of §4.3) and the
//! checks of both sections ([`validate_phase_entries`]).
use super::model::PhaseChange;
use super::temperature_viscosity::TemperatureViscosity;
use crate::validation::MaterialEntry;

/// Scene entry of a phase change (`phase_change: [ ... ]`): a material name and the
/// [`PhaseChange`] fields, written flat.
pub type PhaseChangeSpec = MaterialEntry<PhaseChange>;

/// Scene entry of a temperature-dependent viscosity (`temperature_viscosity: [ ... ]`): a
/// material name and the [`TemperatureViscosity`] fields, written flat.
pub type TemperatureViscositySpec = MaterialEntry<TemperatureViscosity>;

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
        for e in p.validate().err().unwrap_or_default() {
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
        for e in v.validate(m.viscosity as f64).err().unwrap_or_default() {
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
