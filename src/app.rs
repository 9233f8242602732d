//! Building a headless simulation app (used by the CLI, tests and benches).
use bevy_app::App;

use crate::config::MpmConfig;
use crate::material::Materials;
use crate::plugin::MpmPlugins;

/// An app with only the MPM plugins (no window, no renderer, no wall clock): each
/// `app.update()` advances one frame of `config.frame_dt`.
pub fn headless_app(config: MpmConfig, materials: Materials) -> App {
    headless_app_with(config, materials, |_| {})
}

/// As [`headless_app`], with `setup` run after the MPM plugins are added and before the app
/// is finished (add rheology or other plugins there).
pub fn headless_app_with(
    config: MpmConfig,
    materials: Materials,
    setup: impl FnOnce(&mut App),
) -> App {
    let mut app = App::new();
    app.insert_resource(config);
    app.insert_resource(materials);
    app.add_plugins(MpmPlugins);
    setup(&mut app);
    app.finish();
    app.cleanup();
    app
}
