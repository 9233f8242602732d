//! Cameras framed on the liquid: a view direction, the bounds to show, and the distance at which
//! they fit in the field of view.
use bevy::camera::{PerspectiveProjection, Projection};
use bevy::ecs::prelude::*;
use bevy::transform::components::Transform;

use crate::math::Vec3;

use super::ParticleInstances;

/// A camera that [`LiquidRenderPlugin`](super::LiquidRenderPlugin) frames on the liquid (see
/// [`ViewFraming`]).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct LiquidCamera {
    /// Direction the camera looks along (from the camera towards the target; normalised on
    /// use). Default: from the front right, 25° above the horizon.
    pub direction: Vec3,
    /// Room left at the image border, as a fraction of the field of view's half-angle
    /// tangents.
    pub margin: f32,
}

impl Default for LiquidCamera {
    fn default() -> Self {
        Self {
            direction: Vec3::new(-0.45, -0.47, -1.0),
            margin: 0.06,
        }
    }
}

/// What [`LiquidCamera`]s show (a resource).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub enum ViewFraming {
    /// The particles' bounding box, framed once when particles first exist.
    #[default]
    Auto,
    /// These bounds (min, max corners) \[m\], framed whenever this resource changes.
    Bounds(Vec3, Vec3),
    /// The camera's `Transform` is left alone.
    Manual,
}

/// Camera transform that shows the box `[min, max]` looking along `direction` with a perspective
/// projection of vertical field of view `fov_y` \[rad\] and aspect ratio `aspect` (width /
/// height): the camera looks at the box centre from the smallest distance at which all eight
/// corners lie inside both the vertical and the horizontal field of view, shrunk by `margin`
/// (a fraction of the half-angles' tangents left free at the image border).
pub fn frame_bounds(
    min: Vec3,
    max: Vec3,
    direction: Vec3,
    fov_y: f32,
    aspect: f32,
    margin: f32,
) -> Transform {
    let center = 0.5 * (min + max);
    let dir = direction.normalize_or(Vec3::NEG_Z);
    // Keep "up" well defined when looking straight down.
    let up_hint = if dir.cross(Vec3::Y).length_squared() < 1e-6 {
        Vec3::NEG_Z
    } else {
        Vec3::Y
    };
    let right = dir.cross(up_hint).normalize();
    let up = right.cross(dir);
    let shrink = 1.0 / (1.0 + margin.max(0.0));
    let tan_y = (0.5 * fov_y).tan() * shrink;
    let tan_x = (0.5 * fov_y).tan() * aspect.max(1e-3) * shrink;
    // A corner at offset r from the centre is inside when |r·right| ≤ tan_x (d + r·dir) and
    // |r·up| ≤ tan_y (d + r·dir), d being the camera's distance to the centre.
    let mut distance: f32 = 1e-3;
    for i in 0..8 {
        let c = Vec3::new(
            if i & 1 == 0 { min.x } else { max.x },
            if i & 2 == 0 { min.y } else { max.y },
            if i & 4 == 0 { min.z } else { max.z },
        );
        let r = c - center;
        let depth = r.dot(dir);
        distance = distance
            .max(r.dot(right).abs() / tan_x - depth)
            .max(r.dot(up).abs() / tan_y - depth);
    }
    // Stay outside the box (its nearest corner in front of the camera).
    let half_diag = 0.5 * (max - min).length();
    distance = distance.max(half_diag * 1.05);
    Transform::from_translation(center - dir * distance).looking_at(center, up_hint)
}

/// `PostUpdate`: frames the [`LiquidCamera`]s per [`ViewFraming`].
pub(crate) fn frame_cameras(
    framing: Res<ViewFraming>,
    instances: Res<ParticleInstances>,
    mut cameras: Query<(&LiquidCamera, &Projection, &mut Transform)>,
    mut framed_auto: Local<bool>,
) {
    let bounds = match *framing {
        ViewFraming::Manual => return,
        ViewFraming::Bounds(lo, hi) => {
            if !framing.is_changed() {
                return;
            }
            (lo, hi)
        }
        ViewFraming::Auto => {
            if framing.is_changed() {
                *framed_auto = false;
            }
            if *framed_auto {
                return;
            }
            let Some(b) = instances.bounds() else {
                return;
            };
            *framed_auto = true;
            // Grow by a particle radius: the spheres, not their centres, must fit.
            let r = Vec3::splat(instances.radius);
            (b.0 - r, b.1 + r)
        }
    };
    for (cam, projection, mut transform) in &mut cameras {
        let (fov, aspect) = match projection {
            Projection::Perspective(PerspectiveProjection {
                fov, aspect_ratio, ..
            }) => (*fov, *aspect_ratio),
            _ => (std::f32::consts::FRAC_PI_4, 1.0),
        };
        *transform = frame_bounds(bounds.0, bounds.1, cam.direction, fov, aspect, cam.margin);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framed_box_corners_lie_inside_the_view_cone() {
        let (lo, hi) = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(1.0, 0.5, 0.3));
        let fov = 0.8f32;
        for aspect in [0.5f32, 1.0, 16.0 / 9.0] {
            let t = frame_bounds(lo, hi, Vec3::new(-0.4, -0.5, -1.0), fov, aspect, 0.0);
            let fov_x = 2.0 * ((0.5 * fov).tan() * aspect).atan();
            for i in 0..8 {
                let c = Vec3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                );
                // Camera space: forward is −z.
                let v = t.rotation.inverse() * (c - t.translation);
                assert!(v.z < 0.0);
                assert!((v.y / -v.z).abs() <= (0.5 * fov).tan() + 1e-5);
                assert!((v.x / -v.z).abs() <= (0.5 * fov_x).tan() + 1e-5);
            }
        }
    }
}

/// Named view directions of `treacle render --view` (directions looked along).
pub const VIEWS: [(&str, Vec3); 4] = [
    ("iso", Vec3::new(-0.45, -0.47, -1.0)),
    ("front", Vec3::new(0.0, -0.3, -1.0)),
    ("side", Vec3::new(-1.0, -0.3, 0.0)),
    ("top", Vec3::new(0.0, -1.0, 0.0)),
];

/// A view given by name ([`VIEWS`]) or as `X,Y,Z` (the direction looked along), as a framed
/// [`CameraSpec`](crate::scene::CameraSpec).
pub fn parse_view(text: &str) -> Result<crate::scene::CameraSpec, String> {
    let direction = match VIEWS.iter().find(|(name, _)| *name == text) {
        Some((_, d)) => *d,
        None => {
            let parts: Vec<f32> = text
                .split(',')
                .map(|s| s.trim().parse::<f32>())
                .collect::<Result<_, _>>()
                .map_err(|_| {
                    format!("`{text}`: expected iso, front, side, top or X,Y,Z (three numbers)")
                })?;
            let [x, y, z] = parts[..] else {
                return Err(format!("`{text}`: expected three numbers X,Y,Z"));
            };
            Vec3::new(x, y, z)
        }
    };
    let spec = crate::scene::CameraSpec {
        direction: Some(direction),
        ..Default::default()
    };
    match crate::scene::validate_camera(&spec).first() {
        Some(issue) => Err(format!("`{text}`: {}", issue.message)),
        None => Ok(spec),
    }
}

#[cfg(test)]
mod view_tests {
    use super::*;

    #[test]
    fn views_by_name_and_by_numbers() {
        assert_eq!(parse_view("top").unwrap().direction, Some(Vec3::NEG_Y));
        assert_eq!(
            parse_view("1, 0,-2").unwrap().direction,
            Some(Vec3::new(1.0, 0.0, -2.0))
        );
        assert_eq!(
            LiquidCamera::default().direction,
            parse_view("iso").unwrap().direction.unwrap()
        );
        assert!(parse_view("0,0,0").unwrap_err().contains("non-zero"));
        assert!(parse_view("1,2").unwrap_err().contains("three numbers"));
        assert!(parse_view("diagonal").unwrap_err().contains("iso, front"));
    }
}
