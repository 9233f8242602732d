//! `Reflect` on the public components and configuration resources (feature `reflect`): what an
//! inspector or a Bevy scene sees.
use bevy_ecs::reflect::{AppTypeRegistry, ReflectComponent, ReflectResource};
use bevy_reflect::GetPath;
use treacle::app::headless_app;
use treacle::prelude::*;

/// The particle components and the configuration are registered with their component and
/// resource reflection; a field read and written by path changes the live value.
#[test]
fn components_and_config_are_reflected() {
    let mut materials = Materials::default();
    let id = materials.add(FluidMaterial::newtonian("water", 1000.0, 10.0, 0.001));
    let config = MpmConfig::default();
    let g = config.gravity;
    let mut app = headless_app(config, materials);
    let e = app
        .world_mut()
        .spawn(ParticleBundle::new(
            Vec3::new(0.5, 0.25, 0.5),
            Vec3::ZERO,
            g,
            1e-6,
            1000.0,
            id,
        ))
        .id();
    let registry = app.world().resource::<AppTypeRegistry>().clone();
    let types = registry.read();
    for name in [
        "Position",
        "Velocity",
        "Density",
        "Mass",
        "MaterialId",
        "Collider",
        "ColliderPose",
        "RigidBody",
    ] {
        let t = types
            .get_with_short_type_path(name)
            .unwrap_or_else(|| panic!("{name} not registered"));
        assert!(
            t.data::<ReflectComponent>().is_some(),
            "{name}: ReflectComponent"
        );
    }
    for name in [
        "MpmConfig",
        "Materials",
        "SimulationClock",
        "FrameBudget",
        "SimulationLag",
    ] {
        let t = types
            .get_with_short_type_path(name)
            .unwrap_or_else(|| panic!("{name} not registered"));
        assert!(
            t.data::<ReflectResource>().is_some(),
            "{name}: ReflectResource"
        );
    }
    // A particle's position through reflection.
    let reflect_position = types
        .get_with_short_type_path("Position")
        .unwrap()
        .data::<ReflectComponent>()
        .unwrap()
        .clone();
    drop(types);
    let entity = app.world().entity(e);
    let position = reflect_position.reflect(entity).unwrap();
    let y: f32 = *position.path::<f32>(".0.y").unwrap();
    assert_eq!(y, 0.25);
    // The configuration edited through a reflected path, as an inspector does.
    let mut config = app.world_mut().resource_mut::<MpmConfig>();
    *config.path_mut::<f64>("frame_dt").unwrap() = 0.01;
    *config.path_mut::<f32>("integrator.flip").unwrap() = 0.9;
    let config = app.world().resource::<MpmConfig>();
    assert_eq!((config.frame_dt, config.integrator.flip), (0.01, 0.9));
}
