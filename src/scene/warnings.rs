//! Load-time warnings: parameters that are accepted but questionable (a model outside its
//! physical range, printed values that contradict each other). They never stop a load; the
//! CLI prints them, located like errors (`file:line:col: field ...`), and the API keeps them in
//! [`Scene::warnings`](super::Scene::warnings).
use super::error::FieldIssue;
use super::schema::SceneFile;

/// The warnings of a valid scene file, unlocated (field paths as in errors).
pub(crate) fn scene_warnings(scene: &SceneFile) -> Vec<FieldIssue> {
    let mut out = Vec::new();
    for (i, r) in scene.rheology.iter().enumerate() {
        let Some(material) = scene.materials.iter().find(|m| m.name == r.material) else {
            continue;
        };
        for w in r.model.warnings(material) {
            out.push(FieldIssue::new(
                format!("rheology[{i}].model.{}", w.field),
                format!("{} (material `{}`)", w.message, r.material),
            ));
        }
    }
    out
}
