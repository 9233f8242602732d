//! End of step: failure detection and the next time step (ALGORITHM §2.15, §7.2).
//!
//! Every particle's position, velocity, acceleration and density pair is checked for NaN/∞
//! and for a blow-up (a particle moving more than [`BLOWUP_CELLS`]·Δx in one step, which the
//! advection limit forbids, or leaving the grid). The first offender (lowest entity) stops the
//! run with a [`FailureReport`].
//!
//! The next step is Δt = C_s · min{C_adv Δx/|v|max, \[2c/(Ω_crit Δx) + 8ν/(z_crit Δx²)\]⁻¹,
//! z_crit/k_relax, √(2 C_adv Δx/|g|)}, capped by `max_dt` (or the paper's rule, or a fixed
//! step). The last term (§7.2, choice D17) bounds the distance a particle at rest falls in one
//! step; without it a gravity so large that ½|g|Δt² spans many cells throws the predicted
//! positions out of their stencils, and the liquid freezes instead of falling. A next step that
//! is not finite and positive stops the run with a diagnostic naming the limiting term.
use std::sync::atomic::{AtomicU32, Ordering};

use bevy_ecs::prelude::*;

use crate::components::{Acceleration, Density, Particle, Position, StabilityData, Velocity};
use crate::config::{MpmConfig, TimeStepMode};
use crate::failure::{FailureCollector, FailureReport, SimulationStatus};
use crate::grid::MpmGrid;
use crate::material::{MaterialId, Materials};
use crate::math::Real;
use crate::step::schedule::{Gs4Constants, SimulationClock, StepContext};

/// A particle moving more than this many cells in one step is a blow-up.
pub const BLOWUP_CELLS: Real = 2.0;

/// A particle faster than this multiple of its material's sound speed c₀ is a blow-up: the
/// weakly compressible model is meaningless far beyond Mach 1 (the paper's fastest impacts are
/// Mach 5), and an unstable mode reaches this long before it overflows.
pub const BLOWUP_MACH: Real = 10.0;

/// Largest values over the particles, gathered in parallel (max is order independent, so the
/// result is deterministic). Non-negative finite floats order like their bit patterns.
#[derive(Default)]
struct SharedMaxima([AtomicU32; 4]);

impl SharedMaxima {
    fn get(&self, k: usize) -> Real {
        Real::from_bits(self.0[k].load(Ordering::Relaxed))
    }
}

/// Per-batch maxima, merged into [`SharedMaxima`] once when the batch ends (on drop). One
/// atomic per particle and quantity made the two threads fight over one cache line: a third of
/// a step at 2 threads (BENCHMARKS.md).
struct BatchMaxima<'a> {
    shared: &'a SharedMaxima,
    local: [Real; 4],
}

impl BatchMaxima<'_> {
    #[inline(always)]
    fn update(&mut self, k: usize, v: Real) {
        self.local[k] = self.local[k].max(v);
    }
}

impl Drop for BatchMaxima<'_> {
    fn drop(&mut self) {
        for (a, v) in self.shared.0.iter().zip(self.local) {
            a.fetch_max(v.max(0.0).to_bits(), Ordering::Relaxed);
        }
    }
}

/// Maxima of the quantities that limit the time step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
pub struct StabilityMaxima {
    /// max |vₚ| \[m/s\].
    pub speed: Real,
    /// max c² \[m²/s²\].
    pub wave_speed_sq: Real,
    /// max ν \[m²/s\].
    pub kinematic_viscosity: Real,
    /// max relaxation rate \[1/s\].
    pub relaxation_rate: Real,
}

/// The stable step predicted by ALGORITHM §2.15 **without** the safety factor (the "predicted
/// limit" that reports compare against) and the step the rule actually takes.
///
/// The constants are those of the scheme ([`Gs4Constants::for_scheme`]). With implicit
/// viscosity ([`Scheme::implicit_viscosity`](crate::config::Scheme::implicit_viscosity)) the
/// maxima carry no local viscosity (the constitutive stage reports ν = 0 for it), so the limit
/// is advection, sound (+ explicit model viscosities) and relaxation only.
pub fn time_step_limits(config: &MpmConfig, gs4: &Gs4Constants, m: &StabilityMaxima) -> (f64, f64) {
    let l = TimeStepLimits::new(config, gs4, m);
    (l.limit(), l.step(config, m))
}

/// The terms of the §7.2 time-step rule, each the largest stable Δt it allows (∞ when the term
/// is absent), without the safety factor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeStepLimits {
    /// C_adv Δx/|v|max.
    pub advection: f64,
    /// \[2c/(Ω_crit Δx) + 8ν/(z_crit Δx²)\]⁻¹ (sound and explicit viscosity).
    pub wave_viscous: f64,
    /// z_crit/k_relax (model relaxation).
    pub relaxation: f64,
    /// √(2 C_adv Δx/|g|): from rest, a particle falls at most C_adv Δx in one step (D17).
    pub gravity: f64,
}

impl TimeStepLimits {
    /// The terms for the maxima `m`.
    pub fn new(config: &MpmConfig, gs4: &Gs4Constants, m: &StabilityMaxima) -> Self {
        let ts = &config.time_step;
        let dx = config.dx as f64;
        let speed = m.speed as f64;
        let c = (m.wave_speed_sq as f64).sqrt();
        let nu = m.kinematic_viscosity as f64;
        let inverse = |rate: f64| {
            if rate > 0.0 {
                1.0 / rate
            } else {
                f64::INFINITY
            }
        };
        let g = config.gravity.as_dvec3().length();
        Self {
            advection: ts.advection * dx * inverse(speed),
            wave_viscous: inverse(
                2.0 * c / (gs4.omega_crit * dx) + 8.0 * nu / (gs4.z_crit * dx * dx),
            ),
            // Model relaxations are GS4-1 histories whatever the momentum scheme
            // (crate::config::Scheme).
            relaxation: gs4.params.z_crit() * inverse(m.relaxation_rate as f64),
            gravity: (2.0 * ts.advection * dx * inverse(g)).sqrt(),
        }
    }

    /// The predicted limit: the smallest term. NaN if any term is NaN.
    pub fn limit(&self) -> f64 {
        let terms = [
            self.advection,
            self.wave_viscous,
            self.relaxation,
            self.gravity,
        ];
        if terms.iter().any(|t| t.is_nan()) {
            return f64::NAN;
        }
        terms.into_iter().fold(f64::INFINITY, f64::min)
    }

    /// The name of the smallest term (or of a NaN term), with the maxima it comes from.
    pub fn limiting(&self, m: &StabilityMaxima) -> String {
        let named = [
            (
                self.advection,
                format!("advection (max speed {:.3e} m/s)", m.speed),
            ),
            (
                self.wave_viscous,
                format!(
                    "sound and viscosity (max wave speed {:.3e} m/s, max ν {:.3e} m²/s)",
                    (m.wave_speed_sq as f64).sqrt(),
                    m.kinematic_viscosity
                ),
            ),
            (
                self.relaxation,
                format!("model relaxation (max rate {:.3e} 1/s)", m.relaxation_rate),
            ),
            (self.gravity, "gravity".to_string()),
        ];
        named
            .iter()
            .find(|(t, _)| t.is_nan())
            .or_else(|| named.iter().min_by(|a, b| a.0.total_cmp(&b.0)))
            .map(|(_, n)| n.clone())
            .unwrap_or_default()
    }

    /// The step the configured rule takes.
    pub fn step(&self, config: &MpmConfig, m: &StabilityMaxima) -> f64 {
        let ts = &config.time_step;
        let dx = config.dx as f64;
        let speed = m.speed as f64;
        let nu = m.kinematic_viscosity as f64;
        let dt = match ts.mode {
            TimeStepMode::Adaptive => ts.safety * self.limit(),
            TimeStepMode::Paper => {
                let dt1 = if speed > 0.0 {
                    dx / speed
                } else {
                    f64::INFINITY
                };
                let dt2 = 1.0 / (2.0 * nu / (dx * dx) + speed / dx);
                (0.5 * dt1.min(dt2)).min(ts.safety * self.gravity)
            }
            // A fixed step is taken as given (only clipped to the frame end by the driver).
            TimeStepMode::Fixed(dt) => return dt,
        };
        if dt.is_nan() { dt } else { dt.min(ts.max_dt) }
    }
}

/// Checks the state and chooses the next step.
#[allow(clippy::too_many_arguments)]
#[expect(clippy::type_complexity, reason = "a Bevy query tuple")]
pub fn monitor_step(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    gs4: Res<Gs4Constants>,
    grid: Res<MpmGrid>,
    failures: Res<FailureCollector>,
    materials: Res<Materials>,
    mut status: ResMut<SimulationStatus>,
    mut clock: ResMut<SimulationClock>,
    ranks: Option<Res<crate::distributed::Ranks>>,
    q: Query<
        (
            Entity,
            &Position,
            &Velocity,
            &Acceleration,
            &Density,
            &StabilityData,
            &MaterialId,
        ),
        With<Particle>,
    >,
) {
    let dt = ctx.coefficients.dt;
    let dx = config.dx;
    let layout = grid.layout;
    let (lo, hi) = layout.base_bounds();
    let speed_scale = clock.speed_scale as Real;
    let shared = SharedMaxima::default();
    let failures_ref = &*failures;
    let init = || BatchMaxima {
        shared: &shared,
        local: [0.0; 4],
    };
    q.par_iter()
        .for_each_init(init, |maxima, (e, x, v, a, rho, stab, mat)| {
            let check = |name: &str, val: Real| {
                if !val.is_finite() {
                    failures_ref.record(FailureReport::particle(
                        e,
                        name,
                        val as f64,
                        "non-finite value",
                    ));
                }
            };
            // Fast path: one test for the usual all-finite case; details only on failure.
            let all_finite = x.0.is_finite()
                && v.0.is_finite()
                && a.0.is_finite()
                && rho.value.is_finite()
                && rho.rate.is_finite();
            if !all_finite {
                for (name, vec) in [("position", x.0), ("velocity", v.0), ("acceleration", a.0)] {
                    for (k, comp) in ["x", "y", "z"].iter().enumerate() {
                        if !vec[k].is_finite() {
                            check(&format!("{name}.{comp}"), vec[k]);
                        }
                    }
                }
                check("density", rho.value);
                check("density rate", rho.rate);
            }
            if rho.value <= 0.0 {
                failures_ref.record(FailureReport::particle(
                    e,
                    "density",
                    rho.value as f64,
                    "density is not positive",
                ));
            }
            let s = v.0.length();
            if dt > 0.0 && s * dt > BLOWUP_CELLS * dx {
                failures_ref.record(FailureReport::particle(
                    e,
                    "velocity",
                    s as f64,
                    "blow-up: the particle moved more than 2Δx in one step",
                ));
            }
            let c0 = materials.get(*mat).sound_speed.max(speed_scale);
            if !ctx.rate_evaluation && s > BLOWUP_MACH * c0 {
                failures_ref.record(FailureReport::particle(
                    e,
                    "velocity",
                    s as f64,
                    "blow-up: the particle is faster than 10× the material's sound speed \
                     (or than 10× the initial speed plus free fall across the domain, if larger)",
                ));
            }
            let b = layout.base_of(x.0);
            if x.0.is_finite() && (b.cmplt(lo).any() || b.cmpgt(hi).any()) {
                failures_ref.record(FailureReport::particle(
                    e,
                    "position",
                    x.0.length() as f64,
                    "the particle left the grid",
                ));
            }
            maxima.update(0, s);
            maxima.update(1, stab.wave_speed_sq);
            maxima.update(2, stab.kinematic_viscosity);
            maxima.update(3, stab.relaxation_rate);
        });
    let mut maxima = StabilityMaxima {
        speed: shared.get(0),
        wave_speed_sq: shared.get(1),
        kinematic_viscosity: shared.get(2),
        relaxation_rate: shared.get(3),
    };
    if let Some(ranks) = ranks {
        // Every rank takes the same Δt: from the maxima over all particles.
        let m = ranks.max(&[0, 1, 2, 3].map(|k| shared.get(k) as f64));
        maxima = StabilityMaxima {
            speed: m[0] as Real,
            wave_speed_sq: m[1] as Real,
            kinematic_viscosity: m[2] as Real,
            relaxation_rate: m[3] as Real,
        };
    }
    let limits = TimeStepLimits::new(&config, &gs4, &maxima);
    let (limit, next) = (limits.limit(), limits.step(&config, &maxima));
    clock.maxima = maxima;
    if ctx.rate_evaluation {
        clock.speed_scale = explained_speed(&config, maxima.speed);
    }
    let mut failure = failures.take();
    if failure.is_none() && !ctx.rate_evaluation {
        failure = collapsed_time_step(&config, next, &limits, &maxima);
    }
    if let Some(mut f) = failure {
        if let Some(e) = f.entity
            && let Ok((_, x, ..)) = q.get(e)
        {
            f.position = Some(x.0);
        }
        complete_failure(&mut f, &clock, dt as f64);
        status.failure = Some(f);
        return;
    }
    clock.predicted_limit = limit;
    clock.next_dt = next;
}

/// The largest speed the set-up explains (for the Mach blow-up test, [`SimulationClock::speed_scale`]):
/// the fastest initial particle plus free fall across the domain along gravity,
/// |v₀|max + √(2|g|H).
fn explained_speed(config: &MpmConfig, fastest: Real) -> f64 {
    let g = config.gravity.as_dvec3();
    let extent = (config.domain_max - config.domain_min).as_dvec3();
    let height = if g.length() > 0.0 {
        (g.normalize().abs()).dot(extent)
    } else {
        0.0
    };
    fastest as f64 + (2.0 * g.length() * height).sqrt()
}

/// A failure if the next step is not finite and positive (whatever the rule: a NaN wave speed
/// from an underflowing density, say), or if the adaptive step fell below `min_dt` (a
/// collapsing Δt is a blow-up in the making); names the term of §7.2 that limited it.
fn collapsed_time_step(
    config: &MpmConfig,
    next: f64,
    limits: &TimeStepLimits,
    maxima: &StabilityMaxima,
) -> Option<FailureReport> {
    // The limiting term is named only on failure (no formatting on the healthy path).
    if !(next.is_finite() && next > 0.0) {
        return Some(FailureReport::global(
            "time step",
            next,
            format!(
                "the next time step is not finite and positive; limited by {}. \
                 Check the materials' density, sound speed and viscosity for values that \
                 overflow or underflow single precision",
                limits.limiting(maxima)
            ),
        ));
    }
    (matches!(config.time_step.mode, TimeStepMode::Adaptive) && next < config.time_step.min_dt)
        .then(|| {
            FailureReport::global(
                "time step",
                next,
                format!(
                    "the adaptive time step fell below min_dt = {:.3e} s; limited by {}",
                    config.time_step.min_dt,
                    limits.limiting(maxima)
                ),
            )
        })
}

/// Stamps a failure with the step, time and Δt, and suggests half the smaller of the Δt used
/// and the last healthy predicted limit.
fn complete_failure(f: &mut FailureReport, clock: &SimulationClock, dt: f64) {
    f.step = clock.steps;
    f.time = clock.time;
    f.dt = dt;
    let used = if dt > 0.0 { dt } else { clock.next_dt };
    let healthy_limit = if clock.predicted_limit.is_finite() {
        clock.predicted_limit
    } else {
        used
    };
    f.suggested_dt = 0.5 * used.min(healthy_limit);
}
