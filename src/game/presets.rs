//! Liquids for games: material parameters with a sound speed and a grid spacing chosen so that a
//! 60 Hz frame needs few sub-steps, and what that choice costs.
//!
//! **Why the sound speed decides the cost.** The explicit step is limited by sound:
//! Δt ≤ Ω_crit Δx/(2c₀) (§7.2; with the default (ρ∞, ρs) = (0.5, 0) and safety 0.5 the step is
//! about 0.28 Δx/c₀, measured), so a frame of 1/60 s needs about c₀/(16.5 Δx) sub-steps,
//! whatever the flow does. Real water (c₀ = 1480 m/s) at Δx = 2.5 cm would need 3,600. The
//! presets use a weakly compressible liquid instead: c₀ = [`GAME_SOUND_SPEED`] = 5 m/s at
//! Δx = [`GAME_DX`] = 2.5 cm gives about 12 sub-steps per frame, once the default cap
//! `max_dt` = 1 ms is lifted ([`game_config`]).
//!
//! **What it costs.** The density varies with depth and with the Mach number Ma = |v|/c₀. A
//! liquid at rest under its own weight is compressed at depth d to
//! ρ/ρ₀ = (1 + (γ − 1)gd/c₀²)^(1/(γ−1)) (Tait hydrostatics, γ = 7; ≈ 1 + gd/c₀² only while
//! gd ≪ c₀²): at c₀ = 5 m/s that is 3.6 % at the floor of a 10 cm pool and 13.9 % at the floor
//! of a 50 cm one, whose surface then sits about 3.5 cm low
//! (`tests/it/game.rs::the_water_preset_at_rest_is_compressed_as_tait_hydrostatics_says`
//! measures it). A flow at speed |v| changes the density by about Ma²/2 more (0.5 % at
//! 0.5 m/s, 4.5 % at 1.5 m/s; splashes look springier and volume is not conserved to better
//! than that; §9 M5, `tests/it/mpm.rs`, measures the Ma² scaling), and an impact by about
//! twice the hydrostatic value of the fall height: a 22 cm column collapsing in a tank
//! reaches ρ/ρ₀ = 1.10–1.24 at the 99th percentile (BENCHMARKS.md (h)). Keeping a liquid
//! H metres deep within 5 % at rest needs c₀ ≈ 13√H m/s; the sub-steps grow in proportion.
//! The grid spacing sets the smallest drop and the detail: Δx = 2.5 cm resolves puddles and
//! streams a few centimetres thick.
//!
//! The viscous liquids use viscosities whose explicit limit 8ν/(z_crit Δx²) stays below the
//! sound limit at [`GAME_DX`] (honey 10 Pa·s, ketchup capped at 20 Pa·s, slime 20 Pa·s), so they
//! cost no more sub-steps than water; their viscous stresses are resolved, not tuned.
use bevy_app::App;

use crate::config::{
    FlipInterval, MpmConfig, PressureSolve, ProjectionConfig, Scheme, TimeStepConfig,
    VelocityGradientSource,
};
use crate::material::{FluidMaterial, MaterialId, Materials};
use crate::math::{Real, Vec3};
use crate::rheology::{
    LiModel, LiViscosity, Rheology, RheologyPlugin, RheologyTable, ShearMeasure, Su2021Unified,
};

/// Sound speed of the presets \[m/s\] (see the module docs).
pub const GAME_SOUND_SPEED: Real = 5.0;

/// Grid spacing the presets are chosen for \[m\].
pub const GAME_DX: Real = 0.025;

/// A configuration for game liquids in the box `[min, max]`: Δx = [`GAME_DX`], and no cap on
/// the time step below two 60 Hz frames (the default `max_dt` of 1 ms would force 17 sub-steps
/// per frame whatever the liquid; the §7.2 limits alone decide here, and a frame that runs a
/// little long, 17 ms instead of 16.7, still takes one step where the limits allow it).
pub fn game_config(min: Vec3, max: Vec3) -> MpmConfig {
    MpmConfig {
        domain_min: min,
        domain_max: max,
        dx: GAME_DX,
        time_step: TimeStepConfig {
            max_dt: 1.0 / 30.0,
            ..TimeStepConfig::default()
        },
        ..MpmConfig::default()
    }
}

/// [`game_config`] with the liquid's volume kept by the grid pressure projection
/// ([`PressureSolve::Projection`], ALGORITHM §5.4) instead of the Tait equation: no sound
/// speed limits Δt (the presets' `sound_speed` is then unused), the liquid does not compress
/// (a pool at rest and a settled dam break keep their depth; `tests/it/pressure.rs`), and a frame
/// of 1/60 s takes 1–3 sub-steps, set by how far the fastest particle moves (one cell per step
/// at `safety` 1). The scheme is symplectic Euler (first order, which a game does not notice);
/// the PIC share of the transfer acts per 1/60 s of simulated time, and the stress takes the
/// velocity gradient the last G2P computed ([`VelocityGradientSource::Carried`]: one gather
/// of the 27 nodes per particle fewer each step).
///
/// What it does not do: the crate's rigid bodies and Avian bodies still exchange momentum with
/// the liquid through their coupling, but the cell pressure does not push on them (a body's
/// interior cells are air to the solve), so a floating body needs [`game_config`]. This
/// function keeps the crate's default `safety` 0.5 (half a cell per step, the margin for a
/// material the presets have not tried); [`GameLiquid::config_projected`] sets 1, which all
/// four presets ran at for 8 s of a dam break (BENCHMARKS.md (h); the slime's polymer stress
/// takes the convected update of the first-order schemes, ALGORITHM §2.8 choice D22).
pub fn game_config_projected(min: Vec3, max: Vec3) -> MpmConfig {
    let mut config = game_config(min, max);
    config.integrator.scheme = Scheme::SymplecticEuler;
    config.integrator.pressure = PressureSolve::Projection(ProjectionConfig::default());
    config.integrator.flip_interval = FlipInterval::Seconds(1.0 / 60.0);
    config.integrator.velocity_gradient = VelocityGradientSource::Carried;
    config
}

/// A game liquid (see the module docs for the choices).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub enum GameLiquid {
    /// Water: ρ₀ = 1000 kg/m³, μ = 10⁻³ Pa·s (at Δx = 2.5 cm the grid's own dissipation is
    /// larger).
    Water,
    /// Honey: ρ₀ = 1420 kg/m³, Newtonian μ = 10 Pa·s.
    Honey,
    /// Ketchup: ρ₀ = 1100 kg/m³, shear-thinning power law μ = 5.86 γ̇^(0.26−1) Pa·s (\[Li\]'s
    /// golf-ball ketchup), capped at 20 Pa·s at rest.
    Ketchup,
    /// Slime: ρ₀ = 1050 kg/m³, viscoelastic extended Pom-Pom (XPP, \[Su21\]) with backbone and
    /// stretch relaxation times 0.5 s and 0.25 s, anisotropy 0.15, 4 arms, total viscosity
    /// 20 Pa·s, 10 % of it Newtonian: it bounces a little and strings.
    Slime,
}

impl GameLiquid {
    /// All presets.
    pub const ALL: [GameLiquid; 4] = [Self::Water, Self::Honey, Self::Ketchup, Self::Slime];

    /// The material name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Water => "water",
            Self::Honey => "honey",
            Self::Ketchup => "ketchup",
            Self::Slime => "slime",
        }
    }

    /// The material (sound speed [`GAME_SOUND_SPEED`]).
    pub fn material(self) -> FluidMaterial {
        let c = GAME_SOUND_SPEED;
        match self {
            Self::Water => FluidMaterial::newtonian("water", 1000.0, c, 0.001),
            Self::Honey => FluidMaterial::newtonian("honey", 1420.0, c, 10.0),
            // The law gives the viscosity; the material's own is not used.
            Self::Ketchup => FluidMaterial::newtonian("ketchup", 1100.0, c, 0.0),
            Self::Slime => FluidMaterial {
                local_fraction: 0.1,
                ..FluidMaterial::newtonian("slime", 1050.0, c, 20.0)
            },
        }
    }

    /// The `time_step.safety` this liquid runs at with the projected pressure: 1 (the fastest
    /// particle moves one cell per step) for every preset. (The slime needed 0.5 while its
    /// polymer stress took the GS4-1 pair, whose explicit upper-convected term lost the
    /// conformation's positive-definiteness in splashes; the first-order schemes now take
    /// the convected update, ALGORITHM §2.8 choice D22, BENCHMARKS.md (h).) A scene with
    /// several liquids takes the smallest.
    pub fn projected_safety(self) -> f64 {
        1.0
    }

    /// [`game_config_projected`] with this liquid's [`projected_safety`](Self::projected_safety):
    /// the setting whose particle counts at 60 frames/s BENCHMARKS.md (h) reports.
    pub fn config_projected(self, min: Vec3, max: Vec3) -> MpmConfig {
        let mut config = game_config_projected(min, max);
        config.time_step.safety = self.projected_safety();
        config
    }

    /// Adds the material to the app's [`Materials`] and its rheology model (if any) to the
    /// app, before or after [`MpmPlugins`](crate::plugin::MpmPlugins); returns its id.
    /// Particles spawned later by a [`LiquidBody`](super::LiquidBody) or a nozzle get the
    /// model's state.
    pub fn add_to(self, app: &mut App) -> MaterialId {
        let id = app
            .world_mut()
            .get_resource_or_init::<Materials>()
            .add(self.material());
        match self {
            Self::Water | Self::Honey => {}
            Self::Ketchup => add_model(
                app,
                id,
                LiViscosity::new(LiModel::PowerLaw {
                    m: 5.86,
                    n: 0.26,
                    s_min: 0.01,
                })
                .with_shear_measure(ShearMeasure::Frobenius)
                .with_clamp(0.0, 20.0),
            ),
            Self::Slime => add_model(app, id, Su2021Unified::xpp(0.5, 0.25, 0.15, 4.0)),
        }
        id
    }
}

/// Registers `model` for `material`: in the table of an existing `RheologyPlugin<M>`, or with
/// a new one.
fn add_model<M: Rheology>(app: &mut App, material: MaterialId, model: M) {
    if app.is_plugin_added::<RheologyPlugin<M>>() {
        app.world_mut()
            .resource_mut::<RheologyTable<M>>()
            .insert(material, model);
    } else {
        app.add_plugins(RheologyPlugin::<M>::default().with(material, model));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_materials() {
        for liquid in GameLiquid::ALL {
            let m = liquid.material();
            assert_eq!(m.name, liquid.name());
            assert!(m.validate().is_ok(), "{liquid:?}");
        }
    }

    #[test]
    fn projected_configs_are_valid_and_move_one_cell_per_step() {
        for liquid in GameLiquid::ALL {
            let config = liquid.config_projected(Vec3::ZERO, Vec3::ONE);
            assert!(
                crate::step::driver::check_config(&config).is_ok(),
                "{liquid:?}"
            );
            assert_eq!(config.time_step.safety, 1.0, "{liquid:?}");
        }
    }
}
