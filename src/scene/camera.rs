//! The scene file's optional `camera`: how `treacle render` (and any renderer reading the
//! scene) looks at the scene.
use serde::{Deserialize, Serialize};

use crate::math::Vec3;

use super::FieldIssue;

/// Default vertical field of view \[degrees\].
pub const DEFAULT_FOV_DEG: f32 = 35.0;

/// Where the camera of a rendered scene is.
///
/// Either a view `direction` (the camera is framed on the liquid and the scene's bounded
/// objects, looking along it), or a fixed `eye` and `target`. Without a `camera` section the
/// renderer's default direction is used (from the front right, 25° above the horizon).
///
/// ```ron
/// camera: (direction: Some((0.0, -0.3, -1.0))),        // framed, looking along −z, from above
/// camera: (eye: Some((0.5, 0.4, 0.9)), target: Some((0.2, 0.05, 0.2)), fov_deg: 30.0), // fixed
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Direction the camera looks along (from the camera to the target; any length > 0).
    #[serde(default)]
    pub direction: Option<Vec3>,
    /// Camera position \[m\] (with `target`, instead of `direction`).
    #[serde(default)]
    pub eye: Option<Vec3>,
    /// Point looked at \[m\] (with `eye`).
    #[serde(default)]
    pub target: Option<Vec3>,
    /// Vertical field of view \[degrees\], in (1, 150). Default [`DEFAULT_FOV_DEG`].
    #[serde(default = "default_fov")]
    pub fov_deg: f32,
}

fn default_fov() -> f32 {
    DEFAULT_FOV_DEG
}

impl Default for CameraSpec {
    fn default() -> Self {
        Self {
            direction: None,
            eye: None,
            target: None,
            fov_deg: DEFAULT_FOV_DEG,
        }
    }
}

/// Where a validated [`CameraSpec`] puts the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CameraPlacement {
    /// Framed on the scene, looking along this direction.
    Framed(Vec3),
    /// At `eye`, looking at `target`.
    Fixed {
        /// Camera position \[m\].
        eye: Vec3,
        /// Point looked at \[m\].
        target: Vec3,
    },
    /// The renderer's default.
    Default,
}

impl CameraSpec {
    /// The placement this spec asks for (call on a validated spec).
    pub fn placement(&self) -> CameraPlacement {
        match (self.direction, self.eye, self.target) {
            (Some(d), _, _) => CameraPlacement::Framed(d),
            (None, Some(eye), Some(target)) => CameraPlacement::Fixed { eye, target },
            _ => CameraPlacement::Default,
        }
    }

    /// The vertical field of view \[rad\].
    pub fn fov_y(&self) -> f32 {
        self.fov_deg.to_radians()
    }
}

/// Checks the scene's `camera` section: `direction` or `eye` + `target` (not both), finite,
/// non-zero direction, eye ≠ target, field of view in (1°, 150°).
pub fn validate_camera(camera: &CameraSpec) -> Vec<FieldIssue> {
    let mut issues = Vec::new();
    let mut push = |field: &str, msg: String| issues.push(FieldIssue::new(field, msg));
    let finite = |v: Vec3| v.is_finite();
    for (name, v) in [
        ("camera.direction", camera.direction),
        ("camera.eye", camera.eye),
        ("camera.target", camera.target),
    ] {
        if let Some(v) = v
            && !finite(v)
        {
            push(name, format!("must be finite (got {v})"));
        }
    }
    if let Some(d) = camera.direction
        && finite(d)
        && d.length() < 1e-6
    {
        push("camera.direction", format!("must be non-zero (got {d})"));
    }
    match (camera.direction, camera.eye, camera.target) {
        (Some(_), Some(_), _) | (Some(_), _, Some(_)) => push(
            "camera",
            "give either `direction` (framed on the scene) or `eye` and `target`, not both".into(),
        ),
        (None, Some(_), None) => push("camera.target", "`eye` needs a `target`".into()),
        (None, None, Some(_)) => push("camera.eye", "`target` needs an `eye`".into()),
        (None, Some(e), Some(t)) if finite(e) && finite(t) && (e - t).length() < 1e-6 => push(
            "camera.target",
            format!("must differ from `eye` (both {e})"),
        ),
        _ => {}
    }
    if !(camera.fov_deg > 1.0 && camera.fov_deg < 150.0) {
        push(
            "camera.fov_deg",
            format!("must be in (1, 150) degrees (got {})", camera.fov_deg),
        );
    }
    issues
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fields(c: &CameraSpec) -> Vec<String> {
        validate_camera(c).into_iter().map(|i| i.field).collect()
    }

    #[test]
    fn placements_and_their_errors() {
        let framed = CameraSpec {
            direction: Some(Vec3::NEG_Z),
            ..Default::default()
        };
        assert!(fields(&framed).is_empty());
        assert_eq!(framed.placement(), CameraPlacement::Framed(Vec3::NEG_Z));
        let fixed = CameraSpec {
            eye: Some(Vec3::ONE),
            target: Some(Vec3::ZERO),
            ..Default::default()
        };
        assert!(fields(&fixed).is_empty());
        assert_eq!(
            fixed.placement(),
            CameraPlacement::Fixed {
                eye: Vec3::ONE,
                target: Vec3::ZERO
            }
        );
        assert_eq!(CameraSpec::default().placement(), CameraPlacement::Default);
        let both = CameraSpec {
            direction: Some(Vec3::X),
            ..fixed
        };
        assert_eq!(fields(&both), ["camera"]);
        let zero = CameraSpec {
            direction: Some(Vec3::ZERO),
            fov_deg: 0.5,
            ..Default::default()
        };
        assert_eq!(fields(&zero), ["camera.direction", "camera.fov_deg"]);
        let lonely = CameraSpec {
            eye: Some(Vec3::ONE),
            ..Default::default()
        };
        assert_eq!(fields(&lonely), ["camera.target"]);
        let same = CameraSpec {
            eye: Some(Vec3::ONE),
            target: Some(Vec3::ONE),
            ..Default::default()
        };
        assert_eq!(fields(&same), ["camera.target"]);
        let nan = CameraSpec {
            eye: Some(Vec3::NAN),
            target: Some(Vec3::ONE),
            ..Default::default()
        };
        assert_eq!(fields(&nan), ["camera.eye"]);
    }
}
