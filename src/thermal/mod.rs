//! Heat transfer (ALGORITHM §3): the C-F (non-Fourier) heat equation with the GS4
//! semi-implicit scheme on the MPM grid, solved by multigrid-preconditioned conjugate
//! gradients.
//!
//! | file | content | ALGORITHM |
//! |---|---|---|
//! | [`components`] | particle state `Temperature`, `FluxDivergence`, `PredictedTemperature`, `PhaseIndex` | §2.1, §3.4, §4.1 |
//! | [`multigrid`] | node classes, the matrix-free operator b I − β L_h, the V-cycle preconditioner | §3.3, §3.5 |
//! | [`solve`] | the GS4-1 C-F node update (right-hand side, CG solve, Δḋ, T/Ṫ/d/ḋ updates) | §3.2 |
//! | [`systems`] | the ECS systems: predictor, P2G, grid solve, G2P | §2.3 S1, S3, S12, S13; §3.4 |
//! | [`phase`] | melting/solidification and temperature-dependent viscosity | §4.1–4.3 |
//!
//! # Using it
//!
//! [`ThermalPlugin`] is added only when a scene has heat (the scene loader does so when the
//! file has a `thermal` section): without it no particle carries a thermal component and no
//! thermal system runs. Heated materials are listed in [`ThermalConfig::materials`]; every
//! particle of such a material gets [`Temperature`] (initial value
//! [`ThermalMaterial::initial_temperature`] unless it already has one, e.g. set by an
//! emitter), [`FluxDivergence`] and [`PredictedTemperature`] ([`PhaseIndex`] belongs to the
//! phase-change systems of [`phase`]). Prescribed temperatures: domain faces ([`WallTemperatures`]) and colliders
//! carrying [`PrescribedTemperature`]; everything else is insulated (the free surface is
//! adiabatic, §3.3) unless [`ThermalConfig::ambient`] is set.
//!
//! ```rust,no_run
//! use bevy_app::App;
//! use treacle::prelude::*;
//! use treacle::thermal::{ThermalConfig, ThermalMaterial, ThermalPlugin, WallTemperatures};
//!
//! let mut materials = Materials::default();
//! let wax = materials.add(FluidMaterial::newtonian("wax", 1000.0, 10.0, 1.0));
//! let config = MpmConfig::default();
//! let heat = ThermalConfig {
//!     materials: vec![(wax, ThermalMaterial::fourier(0.01, 0.0).with_melting(0.1))],
//!     walls: WallTemperatures { y_min: Some(1.0), ..Default::default() },
//!     ..Default::default()
//! };
//! let app = treacle::app::headless_app_with(config, materials, |app| {
//!     app.add_plugins(ThermalPlugin::new(heat));
//! });
//! ```
//!
//! # Scope and choices
//!
//! * ρc = 1 (k is a diffusivity), scalar flux divergence d (choice D9); mechanical heating
//!   (D10) is off unless a material sets [`ThermalMaterial::mechanical_heating`]: then
//!   Q_p += s·(σ̃_p + p̃_p I):D̃_p, scattered in the `Thermal` set from the stress of this
//!   step. The stress it reads is the particle's whole [`crate::components::CauchyStress`]
//!   minus the Tait pressure, so a solid phase's elastic stress power counts too, and with an
//!   implicit viscous integrator the Newtonian viscous stress (solved on the grid, not on the
//!   particle) does not.
//! * Latent heat (§3.1, optional): [`ThermalMaterial::latent_heat`] makes ρc the apparent heat
//!   capacity 1 + (L/c) δ_ε(T̃ − T_m) per node, evaluated at the GS4 predictor T̃; the operator
//!   becomes b C − β L_h (still symmetric positive definite; the multigrid levels keep C = 1).
//!   Fourier conduction only.
//! * One set of (k, τ, F_T) per run: the solve has constant coefficients (§3.1 assumes
//!   spatially constant k, τ); heated materials with different values are rejected by
//!   [`ThermalConfig::validate`].
//! * Periodic domain faces are insulated for heat (the thermal lattice is not folded).
//! * Only particles of heated materials enter the thermal P2G; other materials act as
//!   insulators (their nodes are Exterior).
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use serde::{Deserialize, Serialize};

use crate::material::MaterialId;
use crate::math::Real;
use crate::step::schedule::{
    GridToParticleSystems, MpmStep, MpmSystems, ParticleToGridSystems, PredictSystems,
    init_step_schedule,
};

pub mod components;
pub mod enthalpy;
pub mod multigrid;
pub mod phase;
pub mod scene;
pub mod solve;
pub mod systems;

pub use components::{FluxDivergence, PhaseIndex, PredictedTemperature, Temperature};
pub use multigrid::{
    BlockLattice, LatticeOperator, Multigrid, MultigridError, MultigridInfo, MultigridParams,
    NodeClass,
};
pub use solve::{
    HeatCoefficients, HeatNodes, HeatParameters, HeatPreconditioner, HeatSolveError, HeatSolver,
    HeatSolverConfig,
};
pub use systems::{ThermalGrid, ThermalStats};

/// Thermal parameters of a material (ALGORITHM §3.1, ρc = 1).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalMaterial {
    /// Diffusivity k \[m²/s\] (≥ 0). The \[Su21\] examples use 0.01.
    pub diffusivity: f64,
    /// Relaxation time τ of the non-Fourier flux \[s\] (≥ 0). Default 0 (Fourier).
    #[serde(default)]
    pub relaxation_time: f64,
    /// Fourier fraction F_T ∈ \[0, 1\]: 1 Fourier, 0 Cattaneo. Default 1.
    #[serde(default = "default_one")]
    pub fourier_fraction: f64,
    /// Temperature of new particles (scene units, e.g. normalised). Default 0.
    #[serde(default)]
    pub initial_temperature: Real,
    /// Melting temperature T_m (optional): particles of the material count as melted in the
    /// `melted_fraction` metric when T̂ ≥ T_m (the stress blend itself is [`phase`]'s).
    #[serde(default)]
    pub melting_temperature: Option<Real>,
    /// Volumetric heat source Q \[K/s\] in the material (rasterised like T). Default 0.
    #[serde(default)]
    pub volumetric_source: Real,
    /// Surface heat source \[K/s\] applied to Interior nodes with an Exterior neighbour
    /// (the \[Li\] "surface particles" source, §3.3), mass-weighted like T. Default 0.
    #[serde(default)]
    pub surface_source: Real,
    /// Mechanical heating scale s = 1/(ρc) \[K·m³/J\] (≥ 0; choice D10): the particle source
    /// Q_p = s·Φ_p with Φ_p = (σ̃_p + p̃_p I) : D̃_p, the stress power without the reversible
    /// pressure work, at t_{n+W₁}. Default 0 (off).
    #[serde(default)]
    pub mechanical_heating: Real,
    /// Latent heat of melting over the heat capacity, L/c \[temperature units\] (≥ 0;
    /// §3.1's apparent heat capacity): the heat equation's ρc becomes
    /// 1 + (L/c) δ_ε(T − T_m) with the Gaussian δ_ε of width [`Self::latent_width`]. Needs
    /// [`Self::melting_temperature`] and Fourier conduction (τ = 0). Default 0 (none).
    #[serde(default)]
    pub latent_heat: Real,
    /// Width ε of the melting range over which the latent heat is released \[temperature
    /// units\] (> 0). Default 0.01.
    #[serde(default = "default_latent_width")]
    pub latent_width: Real,
}

fn default_latent_width() -> Real {
    0.01
}

fn default_one() -> f64 {
    1.0
}

impl ThermalMaterial {
    /// A Fourier material (τ = 0, F_T = 1) with diffusivity `k` and initial temperature `t0`.
    pub fn fourier(k: f64, t0: Real) -> Self {
        Self {
            diffusivity: k,
            relaxation_time: 0.0,
            fourier_fraction: 1.0,
            initial_temperature: t0,
            melting_temperature: None,
            volumetric_source: 0.0,
            surface_source: 0.0,
            mechanical_heating: 0.0,
            latent_heat: 0.0,
            latent_width: default_latent_width(),
        }
    }

    /// With latent heat L/c released over the melting range of width `width` around T_m.
    pub fn with_latent_heat(mut self, latent_heat: Real, width: Real) -> Self {
        self.latent_heat = latent_heat;
        self.latent_width = width;
        self
    }

    /// With melting temperature `t_m`.
    pub fn with_melting(mut self, t_m: Real) -> Self {
        self.melting_temperature = Some(t_m);
        self
    }

    /// With relaxation time τ and Fourier fraction F_T (C-F model).
    pub fn with_non_fourier(mut self, tau: f64, fourier_fraction: f64) -> Self {
        self.relaxation_time = tau;
        self.fourier_fraction = fourier_fraction;
        self
    }

    /// The model parameters (k, τ, F_T).
    pub fn heat_parameters(&self) -> HeatParameters {
        HeatParameters {
            diffusivity: self.diffusivity,
            relaxation_time: self.relaxation_time,
            fourier_fraction: self.fourier_fraction,
        }
    }

    /// Checks the parameters; the error names the field and the constraint.
    pub fn validate(&self) -> Result<(), (&'static str, &'static str)> {
        if !(self.diffusivity.is_finite() && self.diffusivity >= 0.0) {
            return Err(("diffusivity", "must be a finite number ≥ 0 m²/s"));
        }
        if !(self.relaxation_time.is_finite() && self.relaxation_time >= 0.0) {
            return Err(("relaxation_time", "must be a finite number ≥ 0 s"));
        }
        if !(self.fourier_fraction.is_finite() && (0.0..=1.0).contains(&self.fourier_fraction)) {
            return Err(("fourier_fraction", "must lie in [0, 1]"));
        }
        if !self.initial_temperature.is_finite() {
            return Err(("initial_temperature", "must be finite"));
        }
        if self.melting_temperature.is_some_and(|t| !t.is_finite()) {
            return Err(("melting_temperature", "must be finite"));
        }
        if !self.volumetric_source.is_finite() {
            return Err(("volumetric_source", "must be finite"));
        }
        if !self.surface_source.is_finite() {
            return Err(("surface_source", "must be finite"));
        }
        if !(self.mechanical_heating.is_finite() && self.mechanical_heating >= 0.0) {
            return Err(("mechanical_heating", "must be a finite number ≥ 0 K·m³/J"));
        }
        if !(self.latent_heat.is_finite() && self.latent_heat >= 0.0) {
            return Err(("latent_heat", "must be a finite number ≥ 0"));
        }
        if !(self.latent_width.is_finite() && self.latent_width > 0.0) {
            return Err(("latent_width", "must be a finite number > 0"));
        }
        if self.latent_heat > 0.0 && self.melting_temperature.is_none() {
            return Err((
                "latent_heat",
                "needs melting_temperature (the latent heat is released around T_m)",
            ));
        }
        if self.latent_heat > 0.0 && self.relaxation_time > 0.0 {
            return Err((
                "latent_heat",
                "needs Fourier conduction (relaxation_time = 0): the apparent heat capacity is \
                 implemented for the Fourier heat equation only",
            ));
        }
        Ok(())
    }
}

/// Prescribed temperatures of the six domain faces (`None` = insulated, the default). A node
/// on or beyond a face with a temperature is Dirichlet (§3.3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WallTemperatures {
    /// Face x = min.
    pub x_min: Option<Real>,
    /// Face x = max.
    pub x_max: Option<Real>,
    /// Face y = min.
    pub y_min: Option<Real>,
    /// Face y = max.
    pub y_max: Option<Real>,
    /// Face z = min.
    pub z_min: Option<Real>,
    /// Face z = max.
    pub z_max: Option<Real>,
}

impl WallTemperatures {
    /// The temperature of face (`axis`, `upper`).
    pub fn face(&self, axis: usize, upper: bool) -> Option<Real> {
        match (axis, upper) {
            (0, false) => self.x_min,
            (0, true) => self.x_max,
            (1, false) => self.y_min,
            (1, true) => self.y_max,
            (2, false) => self.z_min,
            _ => self.z_max,
        }
    }

    /// Whether any face has a temperature.
    pub fn any(&self) -> bool {
        (0..3).any(|a| self.face(a, false).is_some() || self.face(a, true).is_some())
    }
}

/// Heat exchange of the free surface with an ambient temperature (Newton cooling, optional):
/// an Interior node with e Exterior faces gets Q += −h e (T̃ − T_amb)/Δx (explicit in T̃).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmbientExchange {
    /// Ambient temperature T_amb.
    pub temperature: Real,
    /// Transfer coefficient h over ρc \[m/s\] (≥ 0).
    pub coefficient: Real,
}

/// Marks a collider (an entity with [`crate::collision::Collider`] and
/// [`crate::collision::ColliderPose`]) as a prescribed-temperature body: grid nodes inside it
/// are Dirichlet with this temperature (§3.3), e.g. a hot pan or a cold printer bed.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct PrescribedTemperature(pub Real);

/// How particle temperatures are updated from the grid (G2P, §3.4; see
/// [`systems::thermal_grid_to_particle`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HeatTransfer {
    /// FLIP fraction α_T ∈ \[0, 1\] of the temperature update (1 − α_T is the PIC part),
    /// kept over the velocity's interval τ (`integrator.flip_interval`, choice D19): each step
    /// uses α_T^(Δt/τ). Default 0.99. The PIC part of a temperature transfer is numerical
    /// diffusion: every PIC transfer smooths T over a grid cell, an effective diffusivity of
    /// order −ln(α_T)Δx²/(4τ), which does not depend on Δt (≈ 7.2e-4 m²/s at Δx = 1 cm for
    /// α_T = 0.99 and τ = 0.35Δx/c with c = 10 m/s). With `FlipInterval::Step` the fraction
    /// applies every step and the diffusivity (1 − α_T)Δx²/(4Δt) grows as Δt shrinks (≈ 2.5e-3
    /// m²/s at Δt = 1e-4 s). Pure FLIP (1) has none, but keeps sub-cell temperature differences
    /// between the particles of a cell, which the grid cannot see, for ever.
    pub flip: f64,
    /// Whether the heat solve takes the transfer-consistent predictor of
    /// [`systems::thermal_solve`] (default `true`): with it, pure FLIP (`flip` = 1) is second
    /// order in time; it costs one Laplacian and one transfer round trip per step (+18 % on a
    /// 1-thread step of `bunny_melting_1`, BENCHMARKS.md (g)), and with a PIC share
    /// (`flip` < 1) the PIC smoothing keeps the update first order anyway, so `false` is the
    /// cheaper choice there (measured effect on the shipped heat scenes: ≤ 0.001 in melted
    /// fraction, docs/gallery.md).
    pub consistent_predictor: bool,
}

impl Default for HeatTransfer {
    fn default() -> Self {
        Self {
            flip: 0.99,
            consistent_predictor: true,
        }
    }
}

/// The thermal configuration of a run (a Resource inserted by [`ThermalPlugin`]).
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct ThermalConfig {
    /// Heated materials and their thermal parameters.
    pub materials: Vec<(MaterialId, ThermalMaterial)>,
    /// Prescribed temperatures of the domain faces. Default: all insulated.
    pub walls: WallTemperatures,
    /// Optional exchange with an ambient temperature at the free surface. Default none.
    pub ambient: Option<AmbientExchange>,
    /// CG and multigrid settings.
    pub solver: HeatSolverConfig,
    /// GS4 (ρ∞, ρs) of the heat equation; `None` (default) uses the mechanics' values. Any
    /// admissible pair is stable (the solve is implicit, §8.3).
    pub gs4: Option<(f64, f64)>,
    /// The particle update of T, Ṫ, d, ḋ. Default: FLIP fraction α_T = 0.99.
    pub transfer: HeatTransfer,
}

impl ThermalConfig {
    /// The thermal parameters of material `id`, if heated.
    pub fn material(&self, id: MaterialId) -> Option<&ThermalMaterial> {
        self.materials
            .iter()
            .find(|(m, _)| *m == id)
            .map(|(_, t)| t)
    }

    /// A magnitude of the run's temperatures, for the blow-up check of the particle update
    /// ([`systems::BLOWUP_TEMPERATURE_FACTOR`]): the largest |T| among the materials' initial
    /// and melting temperatures, the wall temperatures and the ambient temperature, and at
    /// least 1.
    pub fn temperature_scale(&self) -> f64 {
        let mut s = 1.0f64;
        for (_, m) in &self.materials {
            s = s.max(m.initial_temperature.abs() as f64);
            if let Some(t) = m.melting_temperature {
                s = s.max(t.abs() as f64);
            }
        }
        for a in 0..3 {
            for upper in [false, true] {
                if let Some(t) = self.walls.face(a, upper) {
                    s = s.max(t.abs() as f64);
                }
            }
        }
        if let Some(a) = self.ambient {
            s = s.max(a.temperature.abs() as f64);
        }
        s
    }

    /// (T_m, ε) of the materials with latent heat (shared, [`Self::validate`]), if any.
    pub fn melting_band(&self) -> Option<(f64, f64)> {
        self.materials.iter().find_map(|(_, m)| {
            (m.latent_heat > 0.0).then(|| {
                (
                    m.melting_temperature.unwrap_or(0.0) as f64,
                    m.latent_width as f64,
                )
            })
        })
    }

    /// The (k, τ, F_T) of the run: those of the first heated material.
    pub fn heat_parameters(&self) -> Option<HeatParameters> {
        self.materials.first().map(|(_, m)| m.heat_parameters())
    }

    /// Checks every material, the solver settings, and that all heated materials share
    /// (k, τ, F_T). The error names the field (`materials[i].diffusivity`, ...).
    pub fn validate(&self) -> Result<(), (String, String)> {
        for (i, (_, m)) in self.materials.iter().enumerate() {
            m.validate()
                .map_err(|(f, c)| (format!("materials[{i}].{f}"), c.to_string()))?;
        }
        if let Some(p) = self.heat_parameters() {
            for (i, (_, m)) in self.materials.iter().enumerate().skip(1) {
                if m.heat_parameters() != p {
                    return Err((
                        format!("materials[{i}]"),
                        "all heated materials must share diffusivity, relaxation_time and \
                         fourier_fraction (the heat solve has constant coefficients, ALGORITHM \
                         §3.1)"
                            .into(),
                    ));
                }
            }
        }
        let mut band: Option<(usize, Real, Real)> = None;
        for (i, (_, m)) in self.materials.iter().enumerate() {
            if m.latent_heat > 0.0 {
                let t_m = m.melting_temperature.unwrap_or(Real::NAN);
                match band {
                    None => band = Some((i, t_m, m.latent_width)),
                    Some((j, t, w)) if t != t_m || w != m.latent_width => {
                        return Err((
                            format!("materials[{i}].latent_heat"),
                            format!(
                                "materials with latent heat must share melting_temperature and \
                                 latent_width (materials[{j}] has {t} and {w})"
                            ),
                        ));
                    }
                    _ => {}
                }
            }
        }
        if let Some(a) = self.ambient
            && !(a.temperature.is_finite() && a.coefficient.is_finite() && a.coefficient >= 0.0)
        {
            return Err((
                "ambient".into(),
                "temperature must be finite and coefficient a finite number ≥ 0".into(),
            ));
        }
        for a in 0..3 {
            for upper in [false, true] {
                if self.walls.face(a, upper).is_some_and(|t| !t.is_finite()) {
                    return Err(("walls".into(), "temperatures must be finite".into()));
                }
            }
        }
        self.solver
            .cg
            .validate()
            .map_err(|(f, c)| (format!("solver.cg.{f}"), c.to_string()))?;
        self.solver
            .multigrid
            .validate()
            .map_err(|e| ("solver.multigrid".to_string(), e.to_string()))?;
        if let Some((ri, rs)) = self.gs4 {
            crate::gs4::Gs4Params::new(ri, rs).map_err(|e| ("gs4".to_string(), e.to_string()))?;
        }
        if !(self.transfer.flip.is_finite() && (0.0..=1.0).contains(&self.transfer.flip)) {
            return Err(("transfer.flip".into(), "must lie in [0, 1]".into()));
        }
        Ok(())
    }
}

/// The thermal plugin: [`ThermalConfig`], [`ThermalGrid`], [`ThermalStats`] and the systems
/// of [`systems`] in the [`MpmStep`] schedule:
///
/// | set | system | what |
/// |---|---|---|
/// | `Predict` | [`systems::attach_thermal_state`], [`systems::predict_temperature`] | thermal components on new heated particles; T̂ = T + W₁Λ₄Δt Ṫ (§2.4) |
/// | `ParticleToGrid` | [`systems::thermal_particle_to_grid`] | mass-weighted T, Ṫ, d, ḋ, Q with the momentum weights (§2.5, §3.4) |
/// | `Thermal` | [`systems::thermal_solve`] | node classes, GS4 C-F solve (§3.2–3.3, §3.5) |
/// | `GridToParticle` | [`systems::thermal_grid_to_particle`] | PIC/FLIP update of T, Ṫ, d, ḋ (§2.12) |
///
/// The commit of the thermal pairs happens in G2P (like the velocity's); nothing runs in
/// `Commit`. Add it only for scenes with heat.
#[derive(Clone, Debug, Default)]
pub struct ThermalPlugin {
    /// The configuration inserted as a resource.
    pub config: ThermalConfig,
}

impl ThermalPlugin {
    /// A plugin with `config`.
    pub fn new(config: ThermalConfig) -> Self {
        Self { config }
    }
}

impl Plugin for ThermalPlugin {
    fn build(&self, app: &mut App) {
        init_step_schedule(app);
        app.init_resource::<crate::diagnostics::MetricsColumns>();
        app.world_mut()
            .resource_mut::<crate::diagnostics::MetricsColumns>()
            .add(crate::diagnostics::MetricsSource {
                key: "thermal",
                columns: |world| metrics_columns(world),
                values: metrics_values,
                across_ranks: Some(crate::diagnostics::AcrossRanks {
                    parts: |world| metrics_parts(world).to_vec(),
                    combine: |ranks| {
                        metrics_from_parts(
                            ranks
                                .iter()
                                .filter_map(|p| <[f64; 6]>::try_from(&p[..]).ok()),
                        )
                    },
                }),
            });
        app.insert_resource(self.config.clone())
            .init_resource::<ThermalGrid>()
            .init_resource::<ThermalStats>();
        // The particle state a migration between ranks carries.
        let world = app.world_mut();
        crate::distributed::travel::<components::Temperature>(world);
        crate::distributed::travel::<components::FluxDivergence>(world);
        crate::distributed::travel::<components::PredictedTemperature>(world);
        app.add_systems(
            MpmStep,
            (
                (systems::attach_thermal_state, systems::predict_temperature)
                    .chain()
                    .in_set(PredictSystems::Fields),
                systems::thermal_particle_to_grid.in_set(ParticleToGridSystems::Fields),
                systems::thermal_solve.in_set(MpmSystems::Thermal),
                systems::thermal_grid_to_particle.in_set(GridToParticleSystems::Fields),
            ),
        );
    }
}

/// Names of the thermal metrics columns (empty without the thermal plugin):
/// `t_min, t_max, t_mean, melted_fraction`.
pub fn metrics_columns(world: &World) -> Vec<String> {
    if world.contains_resource::<ThermalConfig>() {
        ["t_min", "t_max", "t_mean", "melted_fraction"]
            .map(String::from)
            .to_vec()
    } else {
        Vec::new()
    }
}

/// Values of [`metrics_columns`]: min, max and mass-weighted mean of Tₚ over heated
/// particles, and the melted mass fraction among particles that have a phase: a particle with
/// a [`PhaseIndex`] is melted when I_s < ½, otherwise one of a material with
/// [`ThermalMaterial::melting_temperature`] when T̂ₚ ≥ T_m (0 when no particle has a phase).
/// Serial, in f64; 0 instead of undefined values (no heated particle).
pub fn metrics_values(world: &mut World) -> Vec<f64> {
    if !world.contains_resource::<ThermalConfig>() {
        return Vec::new();
    }
    metrics_from_parts([metrics_parts(world)])
}

/// The sums behind [`metrics_values`] over the particles of `world` (in a distributed run, one
/// rank's): min and max of Tₚ, Σ m Tₚ, Σ m, the mass with a phase and the melted mass.
pub fn metrics_parts(world: &mut World) -> [f64; 6] {
    let Some(config) = world.get_resource::<ThermalConfig>().cloned() else {
        return [f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0, 0.0, 0.0];
    };
    let mut q = world.query_filtered::<(
        &crate::components::Mass,
        &MaterialId,
        &Temperature,
        Option<&PredictedTemperature>,
        Option<&PhaseIndex>,
    ), With<crate::components::Particle>>();
    let (mut t_min, mut t_max, mut sum, mut mass) = (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0);
    let (mut melt_mass, mut melted) = (0.0, 0.0);
    for (m, id, t, t_hat, phase) in q.iter(world) {
        let (m, tv) = (m.0 as f64, t.value as f64);
        t_min = t_min.min(tv);
        t_max = t_max.max(tv);
        sum += m * tv;
        mass += m;
        let is_melted = match phase {
            Some(p) => Some(p.0 < 0.5),
            None => config
                .material(*id)
                .and_then(|c| c.melting_temperature)
                .map(|t_m| t_hat.map_or(t.value, |p| p.0) >= t_m),
        };
        if let Some(is_melted) = is_melted {
            melt_mass += m;
            if is_melted {
                melted += m;
            }
        }
    }
    [t_min, t_max, sum, mass, melt_mass, melted]
}

/// [`metrics_values`] from the [`metrics_parts`] of one or several ranks (summed in their
/// order).
pub fn metrics_from_parts(parts: impl IntoIterator<Item = [f64; 6]>) -> Vec<f64> {
    let mut all = [f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0, 0.0, 0.0];
    for p in parts {
        all[0] = all[0].min(p[0]);
        all[1] = all[1].max(p[1]);
        for k in 2..6 {
            all[k] += p[k];
        }
    }
    let [t_min, t_max, sum, mass, melt_mass, melted] = all;
    if mass <= 0.0 || !t_min.is_finite() {
        return vec![0.0; 4];
    }
    let fraction = if melt_mass > 0.0 {
        melted / melt_mass
    } else {
        0.0
    };
    vec![t_min, t_max, sum / mass, fraction]
}
