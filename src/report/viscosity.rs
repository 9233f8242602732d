//! `treacle viscosity SCENE`: the steady simple-shear viscosity η(γ̇) of every material of a
//! scene, from the laws as implemented (\[Li\] Fig. 5 drawn from our code, not copied).
//!
//! In simple shear at rate γ̇ (D̃ with D̃ₓᵧ = D̃ᵧₓ = γ̇/2), the local stress of a material is
//! 2F_v μ D̃, so the shear viscosity is η = σₓᵧ/γ̇ = F_v μ: μ constant for a Newtonian material,
//! μ_eff(s) of its law for a generalized-Newtonian one ([`LiViscosity`], s the law's own shear
//! measure of that D̃, so Frobenius-measure laws are drawn against γ̇ as well). Models whose
//! stress has a history (Oldroyd-B, XPP, elasto-plastic) have no single curve and are listed as
//! skipped.
use std::path::Path;

use glam::DMat3;

use super::plots::{PALETTE, Panel, Series, draw_log_log};
use crate::plot::PlotError;
use crate::rheology::LiViscosity;
use crate::scene::Scene;

/// One material's η(γ̇).
#[derive(Clone, Debug, PartialEq)]
pub struct ViscosityCurve {
    /// Material name.
    pub material: String,
    /// (γ̇ \[1/s\], η \[Pa·s\]), γ̇ ascending.
    pub points: Vec<(f64, f64)>,
}

/// The curves of a scene, and the materials without one (name, model name).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ViscosityCurves {
    /// Materials with a steady simple-shear viscosity, in the scene's order.
    pub curves: Vec<ViscosityCurve>,
    /// Materials whose stress has a history: (name, model name).
    pub skipped: Vec<(String, &'static str)>,
}

/// η(γ̇) of every material of `scene` at `n` shear rates spaced logarithmically over
/// `[rate_min, rate_max]` (both > 0, `n` ≥ 2).
pub fn viscosity_curves(scene: &Scene, rate_min: f64, rate_max: f64, n: usize) -> ViscosityCurves {
    let rates: Vec<f64> = (0..n)
        .map(|i| rate_min * (rate_max / rate_min).powf(i as f64 / (n - 1).max(1) as f64))
        .collect();
    let mut out = ViscosityCurves::default();
    for (i, material) in scene.materials.list.iter().enumerate() {
        let f_v = material.local_fraction as f64;
        let model = scene.rheology.iter().find(|(id, _)| id.0 as usize == i);
        let eta: Box<dyn Fn(f64) -> f64> = match model {
            None => {
                let mu = material.viscosity as f64;
                Box::new(move |_| f_v * mu)
            }
            Some((_, spec)) => match spec.downcast_ref::<LiViscosity>() {
                Some(law) => {
                    let law = law.clone();
                    Box::new(move |rate| {
                        let mut d = DMat3::ZERO;
                        d.x_axis.y = 0.5 * rate;
                        d.y_axis.x = 0.5 * rate;
                        f_v * law.mu_eff(law.shear_measure.of(d))
                    })
                }
                None => {
                    out.skipped.push((material.name.clone(), spec.name()));
                    continue;
                }
            },
        };
        out.curves.push(ViscosityCurve {
            material: material.name.clone(),
            points: rates.iter().map(|&r| (r, eta(r))).collect(),
        });
    }
    out
}

/// Draws `curves` as one log-log panel into a PNG at `path`.
///
/// # Errors
/// [`PlotError`] when drawing or writing fails.
pub fn draw_viscosity_chart(
    path: &Path,
    title: &str,
    curves: &ViscosityCurves,
) -> Result<(), PlotError> {
    let series = curves
        .curves
        .iter()
        .enumerate()
        .map(|(i, c)| Series {
            label: c.material.clone(),
            colour: PALETTE[i % PALETTE.len()],
            points: c.points.clone(),
            dashed: i >= PALETTE.len(),
        })
        .collect();
    let panel = Panel {
        title: "steady simple shear".into(),
        x_label: "shear rate dγ/dt [1/s]".into(),
        y_label: "viscosity η = σxy / (dγ/dt) [Pa·s]".into(),
        series,
        guides: Vec::new(),
    };
    draw_log_log(path, title, &[panel], 1000, 700)
}
