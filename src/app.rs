//! Building a headless simulation app (used by the CLI, tests and benches).
use bevy_app::App;

use crate::config::MpmConfig;
use crate::material::Materials;
use crate::plugin::MpmPlugins;

/// An app with only the MPM plugins (no window, no renderer, no wall clock): each
/// `app.update()` advances one frame of `config.frame_dt`.
pub fn headless_app(config: MpmConfig, materials: Materials) -> App {
    let mut app = App::new();
    app.insert_resource(config);
    app.insert_resource(materials);
    app.add_plugins(MpmPlugins);
    app.finish();
    app.cleanup();
    app
}
