//! Building blocks of the accuracy cases: particle states and their error norms, prescribed
//! initial velocity fields, the shear-band grid drive, analytic solutions and the
//! particle-level Oldroyd-B driver.
//!
//! # Error norms (\[Su21\] §7.1.3)
//!
//! Between two states of the same particles (matched by entity index):
//!
//! * displacement error e_x = √(Σₚ mₚ |xₚ − x̂ₚ|² / Σₚ mₚ) \[m\] (mass-weighted RMS over the
//!   particles; the initial positions are the same in both runs, so this is the RMS of the
//!   displacement difference). On a periodic axis the difference is wrapped into
//!   \[−L/2, L/2).
//! * velocity error e_v = √(Σₚ mₚ |vₚ − v̂ₚ|² / Σₚ mₚ) \[m/s\] (mass-weighted RMS).
//! * stress error e_σ = maxₚ max_ij |σᴺᴸ_ij − σ̂ᴺᴸ_ij| \[Pa\] (largest component of the polymer
//!   stress over the particles: the measure of ALGORITHM §9 S1, so its reference numbers can be
//!   compared directly).
//! * temperature error e_T = √(Σₚ mₚ (Tₚ − T̂ₚ)² / Σₚ mₚ) (mass-weighted RMS, i.e. the discrete
//!   L2 norm over the particles; scene temperature unit), where both states carry a
//!   temperature.
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use crate::components::{Mass, Particle, Position, Velocity};
use crate::config::IntegratorConfig;
use crate::grid::MpmGrid;
use crate::gs4::Gs4Params;
use crate::material::FluidMaterial;
use crate::math::{Mat3, Real, Vec3};
use crate::rheology::{
    FirstOrderCoefficients, PolymerStress, Rheology, RheologyContext, Su2021Unified,
};
use crate::thermal::{PredictedTemperature, Temperature, ThermalConfig};

/// The particle state at one time, sorted by entity index.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleState {
    /// Entity index of each particle (the key that matches particles between runs).
    pub ids: Vec<u32>,
    /// Masses \[kg\].
    pub mass: Vec<f64>,
    /// Positions \[m\].
    pub x: Vec<Vec3>,
    /// Velocities \[m/s\].
    pub v: Vec<Vec3>,
    /// Polymer stress σᴺᴸ \[Pa\] of every particle, if the particles carry one.
    pub stress: Option<Vec<DMat3>>,
    /// Temperature Tₚ of every particle, if every particle carries one (heat).
    pub temperature: Option<Vec<f64>>,
}

impl ParticleState {
    /// Captures the particles of `world` (with their [`PolymerStress`] and their
    /// [`Temperature`] when every particle has one).
    pub fn capture(world: &mut World) -> Self {
        type Row = (u32, f64, Vec3, Vec3, Option<DMat3>, Option<f64>);
        let mut q = world.query_filtered::<(
            Entity,
            &Position,
            &Velocity,
            &Mass,
            Option<&PolymerStress>,
            Option<&Temperature>,
        ), With<Particle>>();
        let mut rows: Vec<Row> = q
            .iter(world)
            .map(|(e, x, v, m, s, t)| {
                (
                    e.index_u32(),
                    m.0 as f64,
                    x.0,
                    v.0,
                    s.map(|s| s.value),
                    t.map(|t| t.value as f64),
                )
            })
            .collect();
        rows.sort_by_key(|r| r.0);
        let all_stress = !rows.is_empty() && rows.iter().all(|r| r.4.is_some());
        let all_temperature = !rows.is_empty() && rows.iter().all(|r| r.5.is_some());
        Self {
            ids: rows.iter().map(|r| r.0).collect(),
            mass: rows.iter().map(|r| r.1).collect(),
            x: rows.iter().map(|r| r.2).collect(),
            v: rows.iter().map(|r| r.3).collect(),
            stress: all_stress.then(|| rows.iter().map(|r| r.4.unwrap_or(DMat3::ZERO)).collect()),
            temperature: all_temperature.then(|| rows.iter().map(|r| r.5.unwrap_or(0.0)).collect()),
        }
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.ids.len()
    }

    /// True without particles.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// All numbers finite.
    pub fn is_finite(&self) -> bool {
        self.x.iter().all(|x| x.is_finite())
            && self.v.iter().all(|v| v.is_finite())
            && self
                .stress
                .as_ref()
                .is_none_or(|s| s.iter().all(|m| m.is_finite()))
            && self
                .temperature
                .as_ref()
                .is_none_or(|t| t.iter().all(|v| v.is_finite()))
    }
}

/// Error norms between two states (module docs); `None` where not defined.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Errors {
    /// Mass-weighted RMS displacement difference \[m\].
    pub displacement: Option<f64>,
    /// Mass-weighted RMS velocity difference \[m/s\].
    pub velocity: Option<f64>,
    /// Largest polymer-stress component difference \[Pa\].
    pub stress: Option<f64>,
    /// Mass-weighted RMS temperature difference (L2 over the particles; temperature unit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temperature: Option<f64>,
}

/// Error norms of `a` against `b` over the particles present in both. `periods[k]` is the
/// domain length of axis k if it is periodic. `kinematics` false leaves the displacement and
/// velocity norms out (particle-level cases).
pub fn compare(
    a: &ParticleState,
    b: &ParticleState,
    periods: [Option<f64>; 3],
    kinematics: bool,
) -> Errors {
    let (mut i, mut j) = (0, 0);
    let (mut m, mut ex, mut ev) = (0.0f64, 0.0f64, 0.0f64);
    let mut es: Option<f64> = match (&a.stress, &b.stress) {
        (Some(_), Some(_)) => Some(0.0),
        _ => None,
    };
    let temps = match (&a.temperature, &b.temperature) {
        (Some(ta), Some(tb)) => Some((ta, tb)),
        _ => None,
    };
    let mut et = 0.0f64;
    let mut matched = 0usize;
    while i < a.len() && j < b.len() {
        match a.ids[i].cmp(&b.ids[j]) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                let w = a.mass[i];
                let mut dx = (a.x[i] - b.x[j]).as_dvec3();
                for (k, p) in periods.iter().enumerate() {
                    if let Some(l) = p {
                        dx[k] -= l * (dx[k] / l).round();
                    }
                }
                let dv = (a.v[i] - b.v[j]).as_dvec3();
                m += w;
                ex += w * dx.length_squared();
                ev += w * dv.length_squared();
                if let (Some(e), Some(sa), Some(sb)) = (es.as_mut(), &a.stress, &b.stress) {
                    let d = sa[i] - sb[j];
                    for c in d.to_cols_array() {
                        *e = e.max(c.abs());
                    }
                }
                if let Some((ta, tb)) = temps {
                    et += w * (ta[i] - tb[j]).powi(2);
                }
                matched += 1;
                i += 1;
                j += 1;
            }
        }
    }
    if matched == 0 {
        return Errors::default();
    }
    let kin = kinematics && m > 0.0;
    Errors {
        displacement: kin.then(|| (ex / m).sqrt()),
        velocity: kin.then(|| (ev / m).sqrt()),
        stress: es,
        temperature: (temps.is_some() && m > 0.0).then(|| (et / m).sqrt()),
    }
}

/// A prescribed initial temperature field, set on every heated particle before the start-up.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum TemperatureField {
    /// T = T₀ + A cos(π (x − x_min)/L): the slowest mode of a slab of length L along x with
    /// insulated ends at x_min and x_min + L (Fourier: it decays as e^{−kπ²t/L²} in shape).
    Cosine {
        /// Mean T₀ (temperature unit).
        mean: Real,
        /// Amplitude A (temperature unit).
        amplitude: Real,
        /// Slab length L \[m\] (normally the domain's extent along x).
        length: Real,
    },
}

impl TemperatureField {
    /// The temperature at `x` in a domain starting at `min`.
    pub fn at(&self, x: Vec3, min: Vec3) -> f64 {
        match *self {
            TemperatureField::Cosine {
                mean,
                amplitude,
                length,
            } => {
                let k = std::f64::consts::PI / length as f64;
                mean as f64 + amplitude as f64 * (k * (x.x - min.x) as f64).cos()
            }
        }
    }

    /// Sets the temperature (and the predicted temperature, if already attached) of every
    /// particle of a heated material ([`ThermalConfig::materials`]) to the field, with rate
    /// Ṫ = 0 (the start-up rate evaluation computes Ṫ(0)); returns how many were set.
    pub fn apply(&self, world: &mut World, min: Vec3) -> usize {
        let Some(config) = world.get_resource::<ThermalConfig>().cloned() else {
            return 0;
        };
        let targets: Vec<(Entity, f64)> = world
            .query_filtered::<(Entity, &Position, &crate::material::MaterialId), With<Particle>>()
            .iter(world)
            .filter(|(_, _, m)| config.material(**m).is_some())
            .map(|(e, x, _)| (e, self.at(x.0, min)))
            .collect();
        for &(e, t) in &targets {
            let mut em = world.entity_mut(e);
            let rate = 0.0;
            em.insert(Temperature {
                value: t as Real,
                rate,
            });
            if em.contains::<PredictedTemperature>() {
                em.insert(PredictedTemperature(t as Real));
            }
        }
        targets.len()
    }
}

/// A prescribed initial velocity field, set on every particle before the start-up.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum VelocityField {
    /// v = (A sin(2π (y − y_min)/λ), 0, 0): a shear wave (the viscous shear layer, ALGORITHM §9
    /// M3), divergence-free, an exact solution of the Navier–Stokes equations.
    ShearWave {
        /// Amplitude A \[m/s\].
        amplitude: Real,
        /// Wavelength λ \[m\] (the domain height for one period).
        wavelength: Real,
    },
    /// v = (γ̇ (y − y_c), 0, 0) with y_c the middle of the domain: homogeneous simple shear.
    SimpleShear {
        /// Shear rate γ̇ \[1/s\].
        rate: Real,
    },
}

impl VelocityField {
    /// The velocity at `x` in the domain `[min, max]` \[m/s\].
    pub fn at(&self, x: Vec3, min: Vec3, max: Vec3) -> Vec3 {
        match *self {
            VelocityField::ShearWave {
                amplitude,
                wavelength,
            } => {
                let k = std::f32::consts::TAU / wavelength;
                Vec3::new(amplitude * (k * (x.y - min.y)).sin(), 0.0, 0.0)
            }
            VelocityField::SimpleShear { rate } => {
                Vec3::new(rate * (x.y - 0.5 * (min.y + max.y)), 0.0, 0.0)
            }
        }
    }

    /// Sets every particle's velocity to the field.
    pub fn apply(&self, world: &mut World, min: Vec3, max: Vec3) {
        let mut q = world.query_filtered::<(&Position, &mut Velocity), With<Particle>>();
        for (x, mut v) in q.iter_mut(world) {
            v.0 = self.at(x.0, min, max);
        }
    }
}

/// A velocity imposed on grid nodes every step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum GridDrive {
    /// Nodes within `width` cells of the lower and upper y faces of the domain (and beyond
    /// them) get vᵢ = (γ̇ (y − y_c), 0, 0) and aᵢ = 0 after the transfer to the grid and
    /// again after the grid update: a
    /// simple-shear cell driven by its boundary layers. With a regular particle lattice the
    /// interior then stays in exact homogeneous simple shear (P2G of a linear field on a
    /// sheared lattice with quadratic B-splines at 2 particles per cell is exact), so every
    /// particle integrates the same stress ODE as the particle-level case.
    ShearBands {
        /// Shear rate γ̇ \[1/s\].
        rate: Real,
        /// Band width \[cells\]; ≥ 1.5 covers every node whose particle support is cut by a
        /// face.
        width: Real,
    },
}

/// The parameters of [`GridDrive::ShearBands`] in world units.
#[derive(Resource, Clone, Copy, Debug)]
pub struct ShearBandDrive {
    /// γ̇ \[1/s\].
    pub rate: Real,
    /// Centre line y_c \[m\].
    pub center: Real,
    /// Nodes with y below this are driven \[m\].
    pub below: Real,
    /// Nodes with y above this are driven \[m\].
    pub above: Real,
}

/// Imposes [`ShearBandDrive`] on the transferred grid state vᵢⁿ, aᵢⁿ (runs after
/// `MpmSystems::ParticleToGrid`, before `MpmSystems::Kinematics`): the P2G average of a node
/// whose particle support is cut by a face is biased towards the interior, and the velocity
/// gradient of the particles near the faces is taken from these nodes. Reads
/// `ShearBandDrive`; writes `MpmGrid` velocity and acceleration.
pub fn drive_shear_bands_transferred(drive: Res<ShearBandDrive>, mut grid: ResMut<MpmGrid>) {
    let layout = grid.layout;
    let drive = *drive;
    grid.for_each_row(|first, row| {
        // One z-row shares y.
        let y = layout.node_position(first).y;
        if y < drive.below || y > drive.above {
            for n in row {
                n.velocity = Vec3::new(drive.rate * (y - drive.center), 0.0, 0.0).into();
                n.acceleration = Vec3::ZERO.into();
            }
        }
    });
}

/// Imposes [`ShearBandDrive`] on the updated grid state vᵢⁿ⁺¹, aᵢⁿ⁺¹ (runs after
/// `MpmSystems::GridUpdate`, before `MpmSystems::GridToParticle`). Reads `ShearBandDrive`;
/// writes `MpmGrid` new velocity and new acceleration.
pub fn drive_shear_bands(drive: Res<ShearBandDrive>, mut grid: ResMut<MpmGrid>) {
    let layout = grid.layout;
    let drive = *drive;
    grid.for_each_row(|first, row| {
        // One z-row shares y.
        let y = layout.node_position(first).y;
        if y < drive.below || y > drive.above {
            for n in row {
                n.new_velocity = Vec3::new(drive.rate * (y - drive.center), 0.0, 0.0).into();
                n.new_acceleration = Vec3::ZERO.into();
            }
        }
    });
}

/// A closed-form solution a case is compared with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exact {
    /// Viscous decay of a shear wave: vₓ = A sin(κ(y − y_min)) e^{−νκ²t}, particles move along
    /// x only: x = x₀ + A sin(κ(y₀ − y_min)) (1 − e^{−νκ²t})/(νκ²).
    ShearDecay {
        /// A \[m/s\].
        amplitude: f64,
        /// κ = 2π/λ \[1/m\].
        wavenumber: f64,
        /// ν = μ/ρ \[m²/s\].
        kinematic_viscosity: f64,
        /// y_min \[m\].
        y_min: f64,
    },
    /// Oldroyd-B start-up of simple shear v = (γ̇ (y − y_c), 0, 0) from rest stress (ALGORITHM §9
    /// S1): σ_xy = η_pγ̇(1 − e^{−t/λ}), σ_xx = 2η_pλγ̇²\[1 − e^{−t/λ}(1 + t/λ)\], others 0; the
    /// particles translate with the flow.
    OldroydBStartup {
        /// γ̇ \[1/s\].
        rate: f64,
        /// y_c \[m\].
        center: f64,
        /// λ_b \[s\].
        relaxation_time: f64,
        /// η_p = G₀λ_b \[Pa·s\].
        polymer_viscosity: f64,
    },
    /// Fourier conduction of the [`TemperatureField::Cosine`] mode in an insulated slab with
    /// the particles at rest: T = T₀ + A cos(π(x − x_min)/L) e^{−kπ²t/L²} (ρc = 1, k the
    /// diffusivity); positions and velocities stay at their initial values.
    HeatDecay {
        /// T₀.
        mean: f64,
        /// A.
        amplitude: f64,
        /// L \[m\].
        length: f64,
        /// x_min \[m\].
        x_min: f64,
        /// k \[m²/s\].
        diffusivity: f64,
    },
}

impl Exact {
    /// The temperature of [`Exact::HeatDecay`] at position `x` (m) and time `t`.
    pub fn heat_decay_temperature(
        mean: f64,
        amplitude: f64,
        length: f64,
        diffusivity: f64,
        x: f64,
        t: f64,
    ) -> f64 {
        let k = std::f64::consts::PI / length;
        mean + amplitude * (k * x).cos() * (-diffusivity * k * k * t).exp()
    }

    /// The Oldroyd-B start-up stress at time `t`.
    pub fn oldroyd_b_stress(rate: f64, lambda: f64, eta_p: f64, t: f64) -> DMat3 {
        let e = (-t / lambda).exp();
        let sxy = eta_p * rate * (1.0 - e);
        let sxx = 2.0 * eta_p * lambda * rate * rate * (1.0 - e * (1.0 + t / lambda));
        DMat3::from_cols(
            DVec3::new(sxx, sxy, 0.0),
            DVec3::new(sxy, 0.0, 0.0),
            DVec3::ZERO,
        )
    }

    /// The exact state at time `t` of the particles that started as `initial`.
    pub fn state(&self, initial: &ParticleState, t: f64) -> ParticleState {
        let mut s = ParticleState {
            ids: initial.ids.clone(),
            mass: initial.mass.clone(),
            x: Vec::with_capacity(initial.len()),
            v: Vec::with_capacity(initial.len()),
            stress: None,
            temperature: None,
        };
        match *self {
            Exact::ShearDecay {
                amplitude,
                wavenumber: k,
                kinematic_viscosity: nu,
                y_min,
            } => {
                let rate = nu * k * k;
                let decay = (-rate * t).exp();
                let travel = if rate > 0.0 { (1.0 - decay) / rate } else { t };
                for x0 in &initial.x {
                    let a = amplitude * (k * (x0.y as f64 - y_min)).sin();
                    s.x.push(*x0 + Vec3::new((a * travel) as f32, 0.0, 0.0));
                    s.v.push(Vec3::new((a * decay) as f32, 0.0, 0.0));
                }
            }
            Exact::OldroydBStartup {
                rate,
                center,
                relaxation_time,
                polymer_viscosity,
            } => {
                for x0 in &initial.x {
                    let u = rate * (x0.y as f64 - center);
                    s.x.push(*x0 + Vec3::new((u * t) as f32, 0.0, 0.0));
                    s.v.push(Vec3::new(u as f32, 0.0, 0.0));
                }
                let sigma = Self::oldroyd_b_stress(rate, relaxation_time, polymer_viscosity, t);
                s.stress = Some(vec![sigma; initial.len()]);
            }
            Exact::HeatDecay {
                mean,
                amplitude,
                length,
                x_min,
                diffusivity,
            } => {
                s.x = initial.x.clone();
                s.v = vec![Vec3::ZERO; initial.len()];
                s.temperature = Some(
                    initial
                        .x
                        .iter()
                        .map(|x0| {
                            Self::heat_decay_temperature(
                                mean,
                                amplitude,
                                length,
                                diffusivity,
                                x0.x as f64 - x_min,
                                t,
                            )
                        })
                        .collect(),
                );
            }
        }
        s
    }
}

/// The particle-level Oldroyd-B start-up of shear (ALGORITHM §9 S1): one material point of
/// an Oldroyd-B fluid (UCM split, F_v = 0) driven at a constant velocity gradient
/// L = γ̇ eₓ⊗e_y, integrated by [`Su2021Unified`] exactly as the MPM step drives it (start-up
/// rate evaluation, then evaluate at t_{n+W₁} and commit per step), without a grid.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct OldroydBParticle {
    /// γ̇ \[1/s\].
    pub shear_rate: f64,
    /// λ_b \[s\].
    pub relaxation_time: f64,
    /// η_p \[Pa·s\] (G₀ = η_p/λ_b).
    pub polymer_viscosity: f64,
    /// η_σ of choice D8: linearly implicit relaxation (true) or fully explicit (false).
    pub implicit_relaxation: bool,
}

impl OldroydBParticle {
    /// The exact solution.
    pub fn exact(&self) -> Exact {
        Exact::OldroydBStartup {
            rate: self.shear_rate,
            center: 0.0,
            relaxation_time: self.relaxation_time,
            polymer_viscosity: self.polymer_viscosity,
        }
    }

    /// The initial state: one particle of unit mass at the origin, at rest, stress-free.
    pub fn initial(&self) -> ParticleState {
        ParticleState {
            ids: vec![0],
            mass: vec![1.0],
            x: vec![Vec3::ZERO],
            v: vec![Vec3::ZERO],
            stress: Some(vec![DMat3::ZERO]),
            temperature: None,
        }
    }

    /// Runs `steps` steps of `dt` with the GS4 parameters of `integrator`; returns the final
    /// state (position and velocity stay zero: the point is not advected).
    pub fn run(
        &self,
        integrator: &IntegratorConfig,
        dt: f64,
        steps: u64,
    ) -> Result<ParticleState, String> {
        let p = Gs4Params::new(integrator.rho_inf, integrator.rho_s).map_err(|e| e.to_string())?;
        let material = FluidMaterial {
            local_fraction: 0.0,
            ..FluidMaterial::newtonian("oldroyd-b", 1.0, 1.0, self.polymer_viscosity as Real)
        };
        let model = Su2021Unified::oldroyd_b(self.relaxation_time)
            .with_viscosity(self.polymer_viscosity)
            .with_implicit_relaxation(self.implicit_relaxation);
        let mut l = Mat3::ZERO;
        l.y_axis.x = self.shear_rate as Real;
        let mut state = PolymerStress::default();
        let start = RheologyContext::new(
            l,
            1.0,
            &material,
            FirstOrderCoefficients::rate_evaluation(),
            true,
        );
        model.evaluate(&start, &mut state);
        model.commit(&start, &mut state);
        let c = FirstOrderCoefficients::step(&p, dt);
        let ctx = RheologyContext::new(l, 1.0, &material, c, false);
        for _ in 0..steps {
            model.evaluate(&ctx, &mut state);
            model.commit(&ctx, &mut state);
        }
        let mut s = self.initial();
        s.stress = Some(vec![state.value]);
        Ok(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(x: &[f32], v: &[f32], mass: &[f64]) -> ParticleState {
        ParticleState {
            ids: (0..x.len() as u32).collect(),
            mass: mass.to_vec(),
            x: x.iter().map(|&a| Vec3::new(a, 0.0, 0.0)).collect(),
            v: v.iter().map(|&a| Vec3::new(a, 0.0, 0.0)).collect(),
            stress: None,
            temperature: None,
        }
    }

    #[test]
    fn mass_weighted_rms_and_periodic_wrap() {
        let a = state(&[0.0, 0.0], &[1.0, 0.0], &[3.0, 1.0]);
        let b = state(&[0.5, 0.0], &[0.0, 0.0], &[3.0, 1.0]);
        let e = compare(&a, &b, [None; 3], true);
        // √((3·0.25 + 0)/4), √(3/4).
        assert!((e.displacement.unwrap() - (0.75f64 / 4.0).sqrt()).abs() < 1e-12);
        assert!((e.velocity.unwrap() - 0.75f64.sqrt()).abs() < 1e-12);
        // Periodic axis of length 0.6: 0.5 wraps to −0.1.
        let b = state(&[0.5, 0.0], &[1.0, 0.0], &[3.0, 1.0]);
        let e = compare(&a, &b, [Some(0.6), None, None], true);
        assert!((e.displacement.unwrap() - (3.0 * 0.01f64 / 4.0).sqrt()).abs() < 1e-7);
    }

    #[test]
    fn temperature_norm_is_mass_weighted_rms_and_heat_decay_is_exact() {
        let mut a = state(&[0.0, 0.5], &[0.0, 0.0], &[3.0, 1.0]);
        let mut b = a.clone();
        a.temperature = Some(vec![1.0, 2.0]);
        b.temperature = Some(vec![0.0, 0.0]);
        // √((3·1 + 1·4)/4).
        let e = compare(&a, &b, [None; 3], true);
        assert!((e.temperature.unwrap() - (7.0f64 / 4.0).sqrt()).abs() < 1e-12);
        // Without a temperature on one side there is no temperature norm.
        b.temperature = None;
        assert_eq!(compare(&a, &b, [None; 3], true).temperature, None);
        // HeatDecay: positions and velocities kept, T = T₀ + A cos(πx/L) e^{−kπ²t/L²}.
        let exact = Exact::HeatDecay {
            mean: 1.0,
            amplitude: 0.5,
            length: 2.0,
            x_min: 0.0,
            diffusivity: 0.1,
        };
        let s = exact.state(&a, 3.0);
        let decay = (-0.1 * (std::f64::consts::PI / 2.0).powi(2) * 3.0).exp();
        let t = s.temperature.unwrap();
        assert!((t[0] - (1.0 + 0.5 * decay)).abs() < 1e-12);
        // x = 0.5: cos(π/4).
        assert!((t[1] - (1.0 + 0.5 * std::f64::consts::FRAC_1_SQRT_2 * decay)).abs() < 1e-7);
        assert_eq!(s.x, a.x);
    }

    #[test]
    fn oldroyd_b_exact_limits() {
        let s = Exact::oldroyd_b_stress(1.0, 1.0, 1.0, 50.0);
        // Steady state: σxy = η_pγ̇, σxx = 2η_pλγ̇².
        assert!((s.y_axis.x - 1.0).abs() < 1e-12 && (s.x_axis.x - 2.0).abs() < 1e-12);
    }
}
