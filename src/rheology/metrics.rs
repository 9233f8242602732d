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
//! The pass is serial over the particles, once per step.
use bevy_app::{App, Plugin};
use bevy_ecs::prelude::*;
use glam::DMat3;

use crate::components::{CauchyStress, Particle, VelocityGradient};
use crate::diagnostics::{MetricsColumns, MetricsSource};
use crate::step::schedule::{MonitorSystems, MpmStep, init_step_schedule};

/// The maxima since the last `metrics.csv` row.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct RheologyMaxima {
    /// max ‖D̃‖_F \[1/s\].
    pub strain_rate: f64,
    /// max apparent viscosity \[Pa·s\].
    pub apparent_viscosity: f64,
}

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
                columns: |_| {
                    vec![
                        "max_apparent_viscosity".to_string(),
                        "max_strain_rate".to_string(),
                    ]
                },
                values: |world| {
                    let m = world
                        .get_resource_mut::<RheologyMaxima>()
                        .map(|mut m| std::mem::take(&mut *m))
                        .unwrap_or_default();
                    vec![m.apparent_viscosity, m.strain_rate]
                },
            });
        app.add_systems(
            MpmStep,
            track_rheology_maxima.in_set(MonitorSystems::Plugins),
        );
    }
}

/// Σᵢ≠ⱼ aᵢⱼbᵢⱼ.
fn shear_dot(a: &DMat3, b: &DMat3) -> f64 {
    2.0 * (a.y_axis.x * b.y_axis.x + a.z_axis.x * b.z_axis.x + a.z_axis.y * b.z_axis.y)
}

/// Folds this step's maxima into [`RheologyMaxima`].
pub fn track_rheology_maxima(
    mut maxima: ResMut<RheologyMaxima>,
    q: Query<(&VelocityGradient, &CauchyStress), With<Particle>>,
) {
    let sym = |l: &VelocityGradient| {
        let l = l.0.as_dmat3();
        0.5 * (l + l.transpose())
    };
    let mut strain = 0.0f64;
    let mut largest_shear = 0.0f64;
    for (l, _) in &q {
        let d = sym(l);
        let frob =
            d.x_axis.length_squared() + d.y_axis.length_squared() + d.z_axis.length_squared();
        strain = strain.max(frob.sqrt());
        largest_shear = largest_shear.max(shear_dot(&d, &d));
    }
    let floor = 1e-6 * largest_shear;
    let mut eta = 0.0f64;
    if largest_shear > 0.0 {
        for (l, sigma) in &q {
            let d = sym(l);
            let n2 = shear_dot(&d, &d);
            if n2 > floor {
                eta = eta.max(shear_dot(&sigma.0.as_dmat3(), &d) / (2.0 * n2));
            }
        }
    }
    if strain.is_finite() && eta.is_finite() {
        maxima.strain_rate = maxima.strain_rate.max(strain);
        maxima.apparent_viscosity = maxima.apparent_viscosity.max(eta);
    }
}
