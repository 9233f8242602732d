//! Tests of the generalized-Newtonian viscosities of \[Li\] (`LiViscosity`, ALGORITHM §6.2):
//! §9 R1 (each law at tabulated s versus its closed form, with \[Li\]'s armadillo-table
//! parameters), R2 (continuity of Bingham and Herschel–Bulkley at s_c), R3 (μ_tan = d(μs)/ds
//! versus a central difference), the shear-rate measure (D14), the stress convention, parameter
//! validation, an App run and the scene variant `Li2024`.
use crate::common;

use std::path::Path;

use bevy_app::App;
use bevy_ecs::prelude::*;
use common::*;
use treacle::prelude::*;
use treacle::rheology::{
    FirstOrderCoefficients, GeneralizedNewtonian, LiModel, LiViscosity, Rheology, RheologyContext,
    RheologyPlugin, ShearMeasure, attach_model,
};

/// Shear rates at which the laws are tabulated \[1/s\] (both sides of every s_c and of the
/// Casson cap switch s ≈ 2.14).
const S: [f64; 9] = [1e-3, 0.05, 0.5, 1.0, 2.0, 3.0, 9.0, 11.0, 100.0];

/// \[Li\]'s armadillo-table parameters (ALGORITHM §6.2).
fn power_law_thinning() -> LiModel {
    LiModel::PowerLaw {
        m: 4.5,
        n: 0.667,
        s_min: 1e-4,
    }
}
fn power_law_thickening() -> LiModel {
    LiModel::PowerLaw {
        m: 1.0,
        n: 1.5,
        s_min: 0.0,
    }
}
fn cross() -> LiModel {
    LiModel::Cross {
        mu0: 10.0,
        mu_inf: 0.1,
        m: 1.0,
        n: 0.667,
    }
}
fn carreau() -> LiModel {
    LiModel::Carreau {
        mu0: 10.0,
        mu_inf: 0.1,
        m: 0.2,
        n: 0.1,
        a: 2.0,
    }
}
fn bingham() -> LiModel {
    LiModel::Bingham {
        mu0: 10.0,
        mu_inf: 0.1,
        s_c: 1.0,
    }
}
fn casson() -> LiModel {
    LiModel::Casson {
        mu_c: 1.0,
        tau0: 10.0,
        mu0: 10.0,
    }
}
fn herschel_bulkley() -> LiModel {
    LiModel::HerschelBulkley {
        mu0: 10.0,
        m: 10.0,
        n: 0.667,
        s_c: 10.0,
    }
}
/// Papanastasiou versions with the yield stresses of the bi-viscous ones (τ0 = 9.9 Pa for
/// Bingham; HB: τ0 = μ0 s_c − m s_c^n) and M = 100 s.
fn bingham_pap() -> LiModel {
    LiModel::BinghamPapanastasiou {
        mu_inf: 0.1,
        tau0: 9.9,
        m_reg: 100.0,
    }
}
fn hb_pap() -> LiModel {
    LiModel::HerschelBulkleyPapanastasiou {
        m: 10.0,
        n: 0.667,
        tau0: 100.0 - 10.0 * 10f64.powf(0.667),
        m_reg: 100.0,
    }
}

fn all_models() -> Vec<(&'static str, LiModel)> {
    vec![
        ("power law n<1", power_law_thinning()),
        ("power law n>1", power_law_thickening()),
        ("Cross", cross()),
        ("Carreau", carreau()),
        ("Bingham", bingham()),
        ("Casson", casson()),
        ("Herschel-Bulkley", herschel_bulkley()),
        ("Bingham-Papanastasiou", bingham_pap()),
        ("HB-Papanastasiou", hb_pap()),
    ]
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs().max(1e-300)
}

/// R1: every law at the tabulated s equals its closed form (written out here independently of
/// the implementation), to 1e-13 relative; plus a few hand-checked numbers.
#[test]
fn r1_models_match_closed_forms() {
    for &s in &S {
        let expected: [(LiModel, f64); 9] = [
            (power_law_thinning(), 4.5 * s.max(1e-4).powf(0.667 - 1.0)),
            (power_law_thickening(), 1.0 * s.powf(0.5)),
            (cross(), 0.1 + (10.0 - 0.1) / (1.0 + (1.0 * s).powf(0.667))),
            (
                carreau(),
                0.1 + (10.0 - 0.1) * (1.0 + (0.2 * s).powi(2)).powf((0.1 - 1.0) / 2.0),
            ),
            (
                bingham(),
                if s <= 1.0 {
                    10.0
                } else {
                    0.1 + 1.0 * (10.0 - 0.1) / s
                },
            ),
            (casson(), f64::min(10.0, (1.0 + (10.0 / s).sqrt()).powi(2))),
            (
                herschel_bulkley(),
                if s <= 10.0 {
                    10.0
                } else {
                    (10.0 * 10.0 - 10.0 * 10f64.powf(0.667)) / s + 10.0 * s.powf(0.667 - 1.0)
                },
            ),
            (bingham_pap(), 0.1 + 9.9 * (1.0 - (-100.0 * s).exp()) / s),
            (
                hb_pap(),
                10.0 * s.powf(0.667 - 1.0)
                    + (100.0 - 10.0 * 10f64.powf(0.667)) * (1.0 - (-100.0 * s).exp()) / s,
            ),
        ];
        for (model, want) in expected {
            let got = LiViscosity::new(model).mu_eff(s);
            assert!(
                rel(got, want) < 1e-13,
                "{model:?} at s = {s}: {got} vs {want}"
            );
        }
    }
    // Hand-checked values.
    let mu = |m: LiModel, s: f64| LiViscosity::new(m).mu_eff(s);
    assert!(rel(mu(power_law_thickening(), 4.0), 2.0) < 1e-15);
    assert!(rel(mu(cross(), 1.0), 0.1 + 9.9 / 2.0) < 1e-15);
    assert!(rel(mu(bingham(), 2.0), 0.1 + 9.9 / 2.0) < 1e-15);
    assert!(rel(mu(casson(), 10.0), 4.0) < 1e-15); // (1 + 1)²
    // Casson cap switch at (1 + √(10/s))² = 10: s = 10/(√10 − 1)² ≈ 2.139.
    let s_cap = 10.0 / (10f64.sqrt() - 1.0).powi(2);
    assert!((s_cap - 2.139).abs() < 1e-3);
    assert_eq!(mu(casson(), 0.999 * s_cap), 10.0);
    assert!(mu(casson(), 1.001 * s_cap) < 10.0);
    // Papanastasiou plateau μ∞ + τ0 M at s = 0 (regular).
    assert!(rel(mu(bingham_pap(), 0.0), 0.1 + 9.9 * 100.0) < 1e-15);
    assert!(rel(mu(bingham_pap(), 1e-12), 0.1 + 9.9 * 100.0) < 1e-9);
    // Cross and Carreau at rest: μ0.
    assert_eq!(mu(cross(), 0.0), 10.0);
    assert_eq!(mu(carreau(), 0.0), 10.0);
    // Power law below s_min: constant m s_min^{n−1}.
    assert_eq!(
        mu(power_law_thinning(), 0.0),
        mu(power_law_thinning(), 1e-4)
    );
}

/// The clamps: μ_eff ∈ [μ_min, μ_max], and μ_tan = μ_eff where a clamp is active.
#[test]
fn clamps_bound_viscosity_and_tangent() {
    let v = LiViscosity::new(power_law_thickening()).with_clamp(0.5, 3.0);
    assert_eq!(v.mu_eff(0.0), 0.5);
    assert_eq!(v.mu_tangent(0.0), 0.5);
    assert_eq!(v.mu_eff(100.0), 3.0);
    assert_eq!(v.mu_tangent(100.0), 3.0);
    assert!(rel(v.mu_eff(4.0), 2.0) < 1e-15);
    assert!(rel(v.mu_tangent(4.0), 3.0) < 1e-15); // n μ = 1.5 · 2
    // A singular law at rest is finite with a finite cap.
    let v = LiViscosity::new(LiModel::PowerLaw {
        m: 1.0,
        n: 0.5,
        s_min: 0.0,
    })
    .with_clamp(0.0, 50.0);
    assert_eq!(v.mu_eff(0.0), 50.0);
    assert!(v.validate().is_ok());
}

/// R2: Bingham and Herschel–Bulkley are continuous at s_c: the left value (s = s_c, plateau
/// branch) and the right limit (the next f64 above s_c) agree to 1e-12 relative.
#[test]
fn r2_bingham_and_hb_are_continuous_at_s_c() {
    let cases = [
        (bingham(), 1.0),
        (herschel_bulkley(), 10.0),
        // [Li]'s tomato (20, 1.1, 10, 1e-3) and (50, 1.1, 100, 100), and cow (1, 0.9, 80, 5e-4).
        (
            LiModel::HerschelBulkley {
                mu0: 10.0,
                m: 20.0,
                n: 1.1,
                s_c: 1e-3,
            },
            1e-3,
        ),
        (
            LiModel::HerschelBulkley {
                mu0: 100.0,
                m: 50.0,
                n: 1.1,
                s_c: 100.0,
            },
            100.0,
        ),
        (
            LiModel::HerschelBulkley {
                mu0: 80.0,
                m: 1.0,
                n: 0.9,
                s_c: 5e-4,
            },
            5e-4,
        ),
        (
            LiModel::Bingham {
                mu0: 3.0,
                mu_inf: 3.0,
                s_c: 0.2,
            },
            0.2,
        ),
    ];
    for (model, s_c) in cases {
        let v = LiViscosity::new(model);
        // ([Li]'s tomato (20, 1.1, 10, 1e-3) has τ0 < 0 and draws a warning, see
        // `validation_names_fields`; the law is still continuous.)
        let left = v.mu_eff(s_c);
        let right = v.mu_eff(s_c.next_up());
        assert!(rel(right, left) < 1e-12, "{model:?}: {left} vs {right}");
        // And the stress μs is continuous too (slightly above the plateau branch).
        let right_far = v.mu_eff(s_c * (1.0 + 1e-9));
        assert!(
            rel(right_far, left) < 1e-8,
            "{model:?}: {left} vs {right_far}"
        );
    }
}

/// R3: μ_tan = d(μ s)/ds against a central difference with step h = 1e-5 s. The truncation
/// error is h²/6 |(μs)'''| and the rounding error ≈ ε|μs|/h; with h/s = 1e-5 both are ≲ 1e-9
/// relative for these smooth laws away from s_c, the Casson cap switch and s_min, hence the
/// tolerance 1e-7.
#[test]
fn r3_tangent_viscosity_is_derivative_of_stress() {
    let points = [0.05, 0.5, 0.7, 3.0, 7.0, 20.0, 100.0];
    for (name, model) in all_models() {
        let v = LiViscosity::new(model);
        for &s in &points {
            // Stay away from the kinks (s_c = 1, 10; Casson switch ≈ 2.14).
            let h = 1e-5 * s;
            let g = |s: f64| v.mu_eff(s) * s;
            let fd = (g(s + h) - g(s - h)) / (2.0 * h);
            let tan = v.mu_tangent(s);
            assert!(
                rel(tan, fd) < 1e-7,
                "{name} at s = {s}: μ_tan {tan} vs FD {fd}"
            );
        }
    }
    // Branch values: shear thickening μ_tan = nμ > μ; thinning / yield ≤ μ.
    let v = LiViscosity::new(power_law_thickening());
    assert!(rel(v.mu_tangent(2.0), 1.5 * v.mu_eff(2.0)) < 1e-15);
    let v = LiViscosity::new(bingham());
    assert_eq!(v.mu_tangent(0.5), 10.0);
    assert_eq!(v.mu_tangent(5.0), 0.1);
    let v = LiViscosity::new(herschel_bulkley());
    assert!(rel(v.mu_tangent(20.0), 0.667 * 10.0 * 20f64.powf(-0.333)) < 1e-15);
}

fn simple_shear(gamma_dot: f32) -> Mat3 {
    // L_xy = ∂v_x/∂y = γ̇ (glam column-major: column y, row x).
    Mat3::from_cols(Vec3::ZERO, Vec3::new(gamma_dot, 0.0, 0.0), Vec3::ZERO)
}

/// The shear-rate measure (D14): in simple shear Gamma gives γ̇ and Frobenius γ̇/√2; the model
/// returns σ = 2F_vμ_eff(s)D̃ and μ_tan = F_v max(μ_eff, μ_tan(s)).
#[test]
fn shear_measure_and_stress_convention() {
    let gd = 4.0f32;
    let material = FluidMaterial {
        local_fraction: 0.5,
        ..FluidMaterial::newtonian("shear-thickening", 1000.0, 20.0, 0.0)
    };
    let ctx = RheologyContext::new(
        simple_shear(gd),
        1000.0,
        &material,
        FirstOrderCoefficients::rate_evaluation(),
        false,
    );
    let d = ctx.strain_rate.as_dmat3();
    assert!(rel(ShearMeasure::Gamma.of(d), 4.0) < 1e-15);
    assert!(rel(ShearMeasure::Frobenius.of(d), 4.0 / 2f64.sqrt()) < 1e-15);
    assert!(rel(ShearMeasure::Gamma.of(d), ctx.shear_rate as f64) < 1e-6);

    for (measure, s) in [
        (ShearMeasure::Gamma, 4.0),
        (ShearMeasure::Frobenius, 4.0 / 2f64.sqrt()),
    ] {
        let v = LiViscosity::new(power_law_thickening()).with_shear_measure(measure);
        let mut state = GeneralizedNewtonian;
        let out = v.evaluate(&ctx, &mut state);
        let mu = s.sqrt(); // m s^{n−1}, m = 1, n = 1.5
        // σ_xy = 2 F_v μ D_xy = F_v μ γ̇.
        let sxy = out.stress.y_axis.x as f64;
        assert!(rel(sxy, 0.5 * mu * 4.0) < 1e-6, "{measure:?}: {sxy}");
        assert!(rel(out.stress.x_axis.y as f64, sxy) < 1e-7);
        assert_eq!(out.stress.x_axis.x, 0.0);
        assert!(rel(out.tangent_viscosity as f64, 0.5 * 1.5 * mu) < 1e-6);
        assert_eq!(out.shear_modulus, 0.0);
        assert_eq!(out.bulk_modulus, 0.0);
        assert_eq!(out.relaxation_rate, 0.0);
        // Thinning: the tangent viscosity reported is F_v μ_eff (≥ μ_tan).
        let v = LiViscosity::new(cross()).with_shear_measure(measure);
        let out = v.evaluate(&ctx, &mut state);
        assert!(rel(out.tangent_viscosity as f64, 0.5 * v.mu_eff(s)) < 1e-6);
    }
    // Default is Gamma.
    assert_eq!(ShearMeasure::default(), ShearMeasure::Gamma);
}

fn fields(v: &LiViscosity, m: &FluidMaterial) -> Vec<&'static str> {
    match v.validate_for(m) {
        Ok(()) => vec![],
        Err(e) => e.into_iter().map(|e| e.field).collect(),
    }
}

/// Validation names each bad field: HB τ0 < 0 ([Li]'s "tomato 1"), material viscosity ≠ 0,
/// μ_min > μ_max, non-positive parameters; [Li]'s good parameter sets pass.
#[test]
fn validation_names_fields() {
    let ok = FluidMaterial::newtonian("gn", 1000.0, 20.0, 0.0);
    for (name, model) in all_models() {
        // (HB-Papanastasiou with n < 1 needs a finite cap.)
        assert_eq!(
            fields(&LiViscosity::new(model).with_clamp(0.0, 1e6), &ok),
            Vec::<&str>::new(),
            "{name}"
        );
    }
    // [Li]'s tomato non-Newtonian 1: τ0 = 0.1·1e-5 − (1e-5)^0.667 < 0.
    let tomato1 = LiViscosity::new(LiModel::HerschelBulkley {
        mu0: 0.1,
        m: 1.0,
        n: 0.667,
        s_c: 1e-5,
    });
    assert!(tomato1.model.yield_stress() < 0.0);
    // Accepted (ALGORITHM §6.2: warn on load), with a warning naming μ0 and τ0.
    assert!(tomato1.validate_for(&ok).is_ok());
    let w = tomato1.warnings_for();
    assert_eq!(w.len(), 1);
    assert_eq!(w[0].field, "model.mu0");
    assert!(w[0].message.contains("τ0"), "{}", w[0]);

    // [Li]'s tomato (m, n, μ0, s_c) = (20, 1.1, 10, 1e-3): τ0 = 0.01 − 20·(1e-3)^1.1 < 0 too.
    let tomato2 = LiViscosity::new(LiModel::HerschelBulkley {
        mu0: 10.0,
        m: 20.0,
        n: 1.1,
        s_c: 1e-3,
    });
    assert!(tomato2.model.yield_stress() < 0.0);
    assert_eq!(fields(&tomato2, &ok), Vec::<&str>::new());
    assert_eq!(tomato2.warnings_for().len(), 1);
    // The other HB sets of [Li] are yield-stress fluids.
    for (m, n, mu0, s_c) in [(50.0, 1.1, 100.0, 100.0), (1.0, 0.9, 80.0, 5e-4)] {
        let v = LiViscosity::new(LiModel::HerschelBulkley { mu0, m, n, s_c });
        assert!(
            v.model.yield_stress() > 0.0 && v.validate().is_ok() && v.warnings_for().is_empty(),
            "{v:?}"
        );
    }

    let water = FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01);
    assert_eq!(
        fields(&LiViscosity::new(cross()), &water),
        vec!["viscosity"]
    );
    assert!(LiViscosity::new(cross()).validate().is_ok());

    assert_eq!(
        fields(&LiViscosity::new(cross()).with_clamp(2.0, 1.0), &ok),
        vec!["mu_min"]
    );
    assert_eq!(
        fields(&LiViscosity::new(cross()).with_clamp(-1.0, f64::NAN), &ok),
        vec!["mu_min", "mu_max"]
    );
    let bad = LiViscosity::new(LiModel::Carreau {
        mu0: 0.0,
        mu_inf: -1.0,
        m: 0.0,
        n: -1.0,
        a: 0.0,
    });
    assert_eq!(
        fields(&bad, &ok),
        vec!["model.mu0", "model.mu_inf", "model.m", "model.n", "model.a"]
    );
    let bad = LiViscosity::new(LiModel::Bingham {
        mu0: 1.0,
        mu_inf: 2.0,
        s_c: 0.0,
    });
    assert_eq!(fields(&bad, &ok), vec!["model.mu0", "model.s_c"]);
    // Singular at rest without a cap.
    let bad = LiViscosity::new(LiModel::PowerLaw {
        m: 1.0,
        n: 0.5,
        s_min: 0.0,
    });
    assert_eq!(fields(&bad, &ok), vec!["model.s_min"]);
    let bad = LiViscosity::new(LiModel::HerschelBulkleyPapanastasiou {
        m: 1.0,
        n: 0.5,
        tau0: -1.0,
        m_reg: 0.0,
    });
    assert_eq!(
        fields(&bad, &ok),
        vec!["mu_max", "model.tau0", "model.m_reg"]
    );
    assert!(
        fields(
            &LiViscosity::new(LiModel::HerschelBulkleyPapanastasiou {
                m: 1.0,
                n: 0.5,
                tau0: 1.0,
                m_reg: 10.0,
            })
            .with_clamp(0.0, 100.0),
            &ok
        )
        .is_empty()
    );
    let bad = LiViscosity::new(LiModel::Casson {
        mu_c: 0.0,
        tau0: -1.0,
        mu0: f64::INFINITY,
    });
    assert_eq!(
        fields(&bad, &ok),
        vec!["model.mu_c", "model.tau0", "model.mu0"]
    );
}

fn count_with<C: Component>(app: &mut App) -> usize {
    let world = app.world_mut();
    world
        .query_filtered::<(), (With<Particle>, With<C>)>()
        .iter(world)
        .count()
}

/// An app with `model` on material `paste` (no particles yet).
fn li_app(config: MpmConfig, materials: Materials, paste: MaterialId, model: &LiViscosity) -> App {
    let mut app = App::new();
    app.insert_resource(config).insert_resource(materials);
    app.add_plugins(MpmPlugins);
    app.add_plugins(RheologyPlugin::<LiViscosity>::default().with(paste, model.clone()));
    app.finish();
    app.cleanup();
    app
}

/// A shear-thinning power-law block (n = 0.5, m = 0.05 Pa·s^0.5, s_min = 0.01/s, μ_max =
/// 1 Pa·s, F_v = 1, material viscosity 0) falls onto the floor next to a water block, for 10
/// frames through `RheologyPlugin::<LiViscosity>`: healthy, only its particles carry the state,
/// and its viscous stability data follow the model.
#[test]
fn power_law_block_runs_in_an_app() {
    let mut materials = Materials::default();
    let water = materials.add(FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01));
    let paste = materials.add(FluidMaterial::newtonian("paste", 1000.0, 20.0, 0.0));
    let model = LiViscosity::new(LiModel::PowerLaw {
        m: 0.05,
        n: 0.5,
        s_min: 0.01,
    })
    .with_clamp(0.0, 1.0);
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.4),
        dx: 0.02,
        frame_dt: 0.01,
        ..Default::default()
    };
    let mut app = li_app(config, materials, paste, &model);
    let g = app.world().resource::<MpmConfig>().gravity;
    let h = 0.01;
    let mut spawn = |min: Vec3, max: Vec3, m: MaterialId, v: Vec3| {
        let batch: Vec<ParticleBundle> = lattice(min, max, h)
            .into_iter()
            .map(|x| ParticleBundle::new(x, v, g, h * h * h, 1000.0, m))
            .collect();
        let n = batch.len();
        app.world_mut().spawn_batch(batch);
        n
    };
    let n_paste = spawn(
        Vec3::new(0.05, 0.03, 0.1),
        Vec3::new(0.15, 0.13, 0.2),
        paste,
        Vec3::new(0.0, -1.0, 0.0),
    );
    let n_water = spawn(
        Vec3::new(0.25, 0.05, 0.1),
        Vec3::new(0.35, 0.15, 0.2),
        water,
        Vec3::ZERO,
    );
    assert!(n_paste > 0 && n_water > 0);
    assert!(attach_model::<LiViscosity>(app.world_mut(), water).is_err());
    assert_eq!(
        attach_model::<LiViscosity>(app.world_mut(), paste).unwrap(),
        n_paste
    );
    for _ in 0..10 {
        app.update();
        assert_healthy(&app);
    }
    assert!(app.world().resource::<SimulationClock>().steps >= 10);
    assert_eq!(count_with::<GeneralizedNewtonian>(&mut app), n_paste);
    let world = app.world_mut();
    let mut q = world.query::<(
        &MaterialId,
        Option<&GeneralizedNewtonian>,
        &StabilityData,
        &PredictedDensity,
        &Velocity,
    )>();
    let mut max_nu = 0.0f32;
    for (m, s, stab, rho, v) in q.iter(world) {
        assert!(v.0.is_finite());
        if *m == water {
            assert!(s.is_none());
        } else {
            assert!(s.is_some());
            // ν = μ_tan/ρ̃ with μ ∈ (0, μ_max]: the model's data reach the step.
            assert!(stab.kinematic_viscosity > 0.0);
            assert!(stab.kinematic_viscosity * rho.value <= 1.0 * 1.0001);
            max_nu = max_nu.max(stab.kinematic_viscosity);
        }
    }
    assert!(max_nu > 0.0);
}

const LI_SCENE: &str = r#"Scene(
    domain: (min: (0.0, 0.0, 0.0), max: (0.4, 0.4, 0.4)),
    dx: 0.02,
    duration: 0.05,
    frame_rate: 60.0,
    materials: [(name: "paste", density: 1000.0, sound_speed: 10.0, viscosity: VISC)],
    rheology: [
        (
            material: "paste",
            model: Li2024((
                model: HerschelBulkley(mu0: MU0, m: 1.0, n: 0.667, s_c: 1.0),
                shear_measure: Frobenius,
                mu_max: 100.0,
            )),
        ),
    ],
    bodies: [(material: "paste", shape: Box(min: (0.1, 0.0, 0.1), max: (0.3, 0.1, 0.3)))],
)"#;

fn parse(text: &str) -> Result<treacle::scene::Scene, String> {
    treacle::scene::parse_scene_str(text, Path::new("test.ron"), Path::new("."))
        .map_err(|e| e.to_string())
}

/// The scene variant `Li2024`: parsed, its plugin added and its state attached; a bad
/// parameter is reported as `rheology[0].model.model.mu0` at the right file:line, τ0 < 0 is
/// a located warning, and a material viscosity ≠ 0 is reported as `rheology[0].model.viscosity`.
#[test]
fn scene_li2024_parses_and_reports_bad_parameters() {
    let good = LI_SCENE.replace("VISC", "0.0").replace("MU0", "10.0");
    let scene = parse(&good).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.rheology.len(), 1);
    let Some(m) = scene.rheology[0]
        .1
        .downcast_ref::<treacle::rheology::LiViscosity>()
    else {
        panic!("wrong variant")
    };
    assert_eq!(m.shear_measure, ShearMeasure::Frobenius);
    assert_eq!(m.mu_min, 0.0);
    assert_eq!(m.mu_max, 100.0);
    let mut app = treacle::runner::scene_app(&scene);
    app.update();
    assert_healthy(&app);
    assert_eq!(
        count_with::<GeneralizedNewtonian>(&mut app),
        scene.particle_count()
    );

    // A non-positive μ0 is rejected, located at the `mu0` line itself.
    let bad = LI_SCENE.replace("VISC", "0.0").replace("MU0", "-1.0");
    let line = bad.lines().position(|l| l.contains("mu0:")).unwrap() + 1;
    let e = parse(&bad).unwrap_err();
    assert!(
        e.contains(&format!("test.ron:{line}:")) && e.contains("rheology[0].model.model.mu0"),
        "{e}"
    );
    // τ0 = μ0 s_c − m s_c^n = 0.5 − 1 < 0: accepted with a warning at the `mu0` line
    // (ALGORITHM §6.2).
    let warned = LI_SCENE.replace("VISC", "0.0").replace("MU0", "0.5");
    let line = warned.lines().position(|l| l.contains("mu0:")).unwrap() + 1;
    let scene = parse(&warned).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(scene.warnings.len(), 1, "{:?}", scene.warnings);
    let w = scene.warnings[0].to_string();
    assert!(
        w.contains(&format!("test.ron:{line}:"))
            && w.contains("rheology[0].model.model.mu0")
            && w.contains("τ0"),
        "{w}"
    );
    // With RON's `unwrap_variant_newtypes` the inner parentheses go; same location.
    let unwrapped = format!(
        "#![enable(unwrap_variant_newtypes)]\n{}",
        bad.replace("Li2024((", "Li2024(")
            .replace("            )),", "            ),")
    );
    let line = unwrapped.lines().position(|l| l.contains("mu0:")).unwrap() + 1;
    let e = parse(&unwrapped).unwrap_err();
    assert!(
        e.contains(&format!("test.ron:{line}:")) && e.contains("rheology[0].model.model.mu0"),
        "{e}"
    );

    let bad = LI_SCENE.replace("VISC", "1.0").replace("MU0", "10.0");
    let e = parse(&bad).unwrap_err();
    assert!(
        e.contains("test.ron:") && e.contains("rheology[0].model.viscosity"),
        "{e}"
    );

    // Unknown fields are rejected.
    let bad = good.replace("shear_measure: Frobenius,", "shear_mesure: Frobenius,");
    assert!(parse(&bad).is_err());
}

/// Serde: defaults (Gamma, μ_min = 0, μ_max = +∞, Yasuda a = 2) and a RON round trip with an
/// infinite cap.
#[test]
fn serde_defaults_and_round_trip() {
    let v: LiViscosity =
        ron::from_str("(model: Carreau(mu0: 10.0, mu_inf: 0.1, m: 0.2, n: 0.1))").unwrap();
    assert_eq!(v, LiViscosity::new(carreau()));
    assert_eq!(v.mu_max, f64::INFINITY);
    let text = ron::to_string(&v).unwrap();
    let back: LiViscosity = ron::from_str(&text).unwrap();
    assert_eq!(back, v, "{text}");
    assert!(
        ron::from_str::<LiViscosity>(
            "(model: Cross(mu0: 1.0, mu_inf: 0.1, m: 1.0, n: 1.0, a: 2.0))"
        )
        .is_err()
    );
}

/// \[Li\] Fig. 11's per-step maxima as `metrics.csv` columns (`treacle::rheology::metrics`): a
/// shear-thinning power-law block (m = 0.05, n = 0.5, s_min = 0.01/s) falls next to a water
/// block (μ = 0.01 Pa·s), one fixed step per frame, so each row's maxima are those of one step.
/// Recomputed here from the particles after each frame: max ‖D̃‖_F over all particles, and the
/// largest viscosity the laws give at the particles' own strain rates (μ_eff(√(2D̃:D̃)) for the
/// paste, 0.01 for the water) among the particles whose shear part of D̃ is above the floor.
/// Tolerance 1e-4 relative: the stresses are f32 (relative rounding ≈ 6e-8 per product, and
/// the off-diagonal ratio has no cancellation against the pressure).
#[test]
fn rheology_maxima_columns_follow_the_laws() {
    let mut materials = Materials::default();
    let water = materials.add(FluidMaterial::newtonian("water", 1000.0, 20.0, 0.01));
    let paste = materials.add(FluidMaterial::newtonian("paste", 1000.0, 20.0, 0.0));
    let model = LiViscosity::new(LiModel::PowerLaw {
        m: 0.05,
        n: 0.5,
        s_min: 0.01,
    });
    let dt = 2e-4;
    let config = MpmConfig {
        domain_min: Vec3::ZERO,
        domain_max: Vec3::splat(0.4),
        dx: 0.02,
        frame_dt: dt,
        // A fixed step longer than the frame: every frame is one step, clipped to its end.
        time_step: TimeStepConfig {
            mode: TimeStepMode::Fixed(1.5 * dt),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut app = li_app(config, materials, paste, &model);
    let g = app.world().resource::<MpmConfig>().gravity;
    let h = 0.01;
    for (min, max, m, v) in [
        (
            Vec3::new(0.05, 0.03, 0.1),
            Vec3::new(0.15, 0.13, 0.2),
            paste,
            -1.0,
        ),
        (
            Vec3::new(0.25, 0.05, 0.1),
            Vec3::new(0.35, 0.15, 0.2),
            water,
            -0.5,
        ),
    ] {
        let batch: Vec<ParticleBundle> = lattice(min, max, h)
            .into_iter()
            .map(|x| ParticleBundle::new(x, Vec3::new(0.3, v, 0.0), g, h * h * h, 1000.0, m))
            .collect();
        app.world_mut().spawn_batch(batch);
    }
    attach_model::<LiViscosity>(app.world_mut(), paste).unwrap();
    let columns = treacle::diagnostics::MetricsColumns::columns(app.world_mut());
    assert_eq!(columns, ["max_apparent_viscosity", "max_strain_rate"]);
    let mut compared = 0;
    for frame in 0..40 {
        app.update();
        assert_healthy(&app);
        let got = treacle::diagnostics::MetricsColumns::values(app.world_mut());
        assert_eq!(app.world().resource::<SimulationClock>().frame_steps, 1);
        let world = app.world_mut();
        let mut q = world.query::<(&MaterialId, &VelocityGradient)>();
        let mut rows = Vec::new();
        for (m, l) in q.iter(world) {
            let l = l.0.as_dmat3();
            let d = 0.5 * (l + l.transpose());
            let frob2 =
                d.x_axis.length_squared() + d.y_axis.length_squared() + d.z_axis.length_squared();
            let shear2 = 2.0 * (d.y_axis.x.powi(2) + d.z_axis.x.powi(2) + d.z_axis.y.powi(2));
            let eta = if *m == water {
                0.01
            } else {
                model.mu_eff((2.0 * frob2).sqrt())
            };
            rows.push((frob2.sqrt(), shear2, eta));
        }
        let strain = rows.iter().map(|r| r.0).fold(0.0, f64::max);
        let largest_shear = rows.iter().map(|r| r.1).fold(0.0, f64::max);
        let eta = rows
            .iter()
            .filter(|r| r.1 > 1e-6 * largest_shear)
            .map(|r| r.2)
            .fold(0.0, f64::max);
        assert!(
            (got[1] / strain - 1.0).abs() < 1e-9,
            "frame {frame}: strain {} against {strain}",
            got[1]
        );
        assert!(
            (got[0] / eta - 1.0).abs() < 1e-4,
            "frame {frame}: η {} against {eta}",
            got[0]
        );
        compared += 1;
    }
    assert_eq!(compared, 40);
}
