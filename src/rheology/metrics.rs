//! Per-frame rheology maxima in `metrics.csv` (\[Li\] Fig. 11: the maximum viscosity and
//! strain-rate norm of each step): added with the first [`RheologyPlugin`](super::RheologyPlugin)
//! of an app, so a scene without rheology models pays nothing.
//!
//! Columns, each the maximum over the particles and over the steps since the previous row:
//!
//! * `max_strain_rate` = ‖D̃‖_F \[1/s\], D̃ = sym(L̃) of the step (\[Li\]'s measure);
//! * `max_apparent_viscosity` = Σᵢ≠ⱼ σᵢⱼD̃ᵢⱼ / (2 Σᵢ≠ⱼ D̃ᵢⱼ²) \[Pa·s\], the shear stress a
//!   particle carries against its shear rate: F_v μ_eff(s) for a generalized-Newtonian law, the
//!   local Newtonian F_v μ plus the polymer's response for viscoelastic models. Only the
//!   off-diagonal parts enter: the diagonal carries the pressure, whose f32 rounding
//!   (|p| · 6·10⁻⁸) would swamp the viscous stress of a slowly sheared particle. Particles whose
//!   off-diagonal ‖D̃‖ is below 10⁻³ of the step's largest are left out (the ratio is undefined
//!   at rest).
//!
//! Two parallel passes over the particles per step, only in runs that write metrics (the
//! columns were asked for; [`RheologyMaximaWanted`]): measured at 2–4 % of an XPP step
//! (BENCHMARKS.md (m)).
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use glam::DMat3;

use crate::components::{CauchyStress, Particle, VelocityGradient};
use crate::diagnostics::{AcrossRanks, MetricsColumns, MetricsSource};
use crate::step::schedule::{MonitorSystems, MpmStep, init_step_schedule};

/// The maxima since the last `metrics.csv` row.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct RheologyMaxima {
    /// max ‖D̃‖_F \[1/s\].
    pub strain_rate: f64,
    /// max apparent viscosity \[Pa·s\].
    pub apparent_viscosity: f64,
}

/// Present once the metrics columns were asked for (a run writing `metrics.csv`): the maxima
/// are tracked only then.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct RheologyMaximaWanted;

/// Adds [`RheologyMaxima`], the system that updates it every step and the two `metrics.csv`
/// columns.
pub struct RheologyMetricsPlugin;

impl Plugin for RheologyMetricsPlugin {
    fn build(&self, app: &mut App) {
        init_step_schedule(app);
        app.init_resource::<RheologyMaxima>()
            .init_resource::<MetricsColumns>();
        app.world_mut()
            .resource_mut::<MetricsColumns>()
            .add(MetricsSource {
                key: "rheology",
                columns: |world| {
                    // Asked once when a run that writes metrics starts: only then do the steps
                    // pay for the passes (`treacle bench` and game loops do not).
                    world.insert_resource(RheologyMaximaWanted);
                    vec![
                        "max_apparent_viscosity".to_string(),
                        "max_strain_rate".to_string(),
                    ]
                },
                values: take_maxima,
                // Each rank's maxima over its particles; the run's are their maxima.
                across_ranks: Some(AcrossRanks {
                    parts: take_maxima,
                    combine: |ranks| {
                        (0..2)
                            .map(|k| ranks.iter().map(|r| r[k]).fold(0.0, f64::max))
                            .collect()
                    },
                }),
            });
        app.add_systems(
            MpmStep,
            track_rheology_maxima
                .run_if(resource_exists::<RheologyMaximaWanted>)
                .in_set(MonitorSystems::Plugins),
        );
    }
}

/// Σᵢ≠ⱼ aᵢⱼbᵢⱼ.
fn shear_dot(a: &DMat3, b: &DMat3) -> f64 {
    2.0 * (a.y_axis.x * b.y_axis.x + a.z_axis.x * b.z_axis.x + a.z_axis.y * b.z_axis.y)
}

/// Per-batch maxima of a parallel pass, merged into the shared ones when the batch ends (max
/// is order-independent, so the result does not depend on the thread count).
struct BatchMax<'a> {
    shared: &'a std::sync::Mutex<[f64; 2]>,
    local: [f64; 2],
}

impl Drop for BatchMax<'_> {
    fn drop(&mut self) {
        let mut s = self.shared.lock().unwrap_or_else(|e| e.into_inner());
        s[0] = s[0].max(self.local[0]);
        s[1] = s[1].max(self.local[1]);
    }
}

/// The component-wise maxima of `f` over the particles of `q` (in parallel; 0 for none).
fn par_max(
    q: &Query<(&VelocityGradient, &CauchyStress), With<Particle>>,
    f: impl Fn(&VelocityGradient, &CauchyStress) -> [f64; 2] + Send + Sync,
) -> [f64; 2] {
    let shared = std::sync::Mutex::new([0.0f64; 2]);
    q.par_iter().for_each_init(
        || BatchMax {
            shared: &shared,
            local: [0.0; 2],
        },
        |m, (l, sigma)| {
            let v = f(l, sigma);
            m.local[0] = m.local[0].max(v[0]);
            m.local[1] = m.local[1].max(v[1]);
        },
    );
    shared.into_inner().unwrap_or_else(|e| e.into_inner())
}

/// Folds this step's maxima into [`RheologyMaxima`] (two parallel passes: the largest shear
/// sets the floor of the second).
pub fn track_rheology_maxima(
    mut maxima: ResMut<RheologyMaxima>,
    q: Query<(&VelocityGradient, &CauchyStress), With<Particle>>,
) {
    let sym = |l: &VelocityGradient| {
        let l = l.0.as_dmat3();
        0.5 * (l + l.transpose())
    };
    // Pass 1: max ‖D̃‖²_F and max shear part.
    let [frob2, largest_shear] = par_max(&q, |l, _| {
        let d = sym(l);
        let frob2 =
            d.x_axis.length_squared() + d.y_axis.length_squared() + d.z_axis.length_squared();
        [frob2, shear_dot(&d, &d)]
    });
    let strain = frob2.sqrt();
    let floor = 1e-6 * largest_shear;
    // Pass 2: the largest ratio above the floor.
    let eta = if largest_shear > 0.0 {
        par_max(&q, |l, sigma| {
            let d = sym(l);
            let n2 = shear_dot(&d, &d);
            let ratio = if n2 > floor {
                shear_dot(&sigma.0.as_dmat3(), &d) / (2.0 * n2)
            } else {
                0.0
            };
            [ratio, 0.0]
        })[0]
    } else {
        0.0
    };
    if strain.is_finite() && eta.is_finite() {
        maxima.strain_rate = maxima.strain_rate.max(strain);
        maxima.apparent_viscosity = maxima.apparent_viscosity.max(eta);
    }
}

/// The maxima since the last call (they restart from zero).
fn take_maxima(world: &mut World) -> Vec<f64> {
    let m = world
        .get_resource_mut::<RheologyMaxima>()
        .map(|mut m| std::mem::take(&mut *m))
        .unwrap_or_default();
    vec![m.apparent_viscosity, m.strain_rate]
}
