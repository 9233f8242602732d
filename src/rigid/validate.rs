//! Checks of a scene's `rigid_bodies` ([`validate_rigid_bodies`]): sizes, density or mass,
//! finite vectors and rotation, the boundary condition towards the liquid, and the body's place
//! in the domain. Every issue is reported with its field path.
use super::body::bounding_radius;
use super::spec::{RigidBodySpec, RigidShape};
use crate::config::{BoundaryCondition, DomainWalls};
use crate::math::RotationSpec;
use crate::math::{Real, Vec3};
use crate::validation::FieldIssue;

fn fmt_vec(v: Vec3) -> String {
    format!("({}, {}, {})", v.x, v.y, v.z)
}

/// Checks the `rigid_bodies` of a scene: sizes, density or mass, finite vectors and rotation,
/// the boundary condition, and that each body lies inside the domain (touching a wall is
/// allowed) and is smaller than the domain along periodic axes. `domain` and `dx` are `None`
/// when they are themselves invalid (the checks that need them are skipped).
pub fn validate_rigid_bodies(
    specs: &[RigidBodySpec],
    domain: Option<(Vec3, Vec3)>,
    dx: Option<Real>,
    walls: &DomainWalls,
) -> Vec<FieldIssue> {
    let mut out = Vec::new();
    for (i, s) in specs.iter().enumerate() {
        let at = |f: &str| format!("rigid_bodies[{i}].{f}");
        let mut push = |f: String, m: String| out.push(FieldIssue::new(f, m));
        let mut shape_ok = true;
        match s.shape {
            RigidShape::Sphere { radius } => {
                if !(radius.is_finite() && radius > 0.0) {
                    push(
                        at("shape.radius"),
                        format!("must be a finite number > 0 m (got {radius})"),
                    );
                    shape_ok = false;
                }
            }
            RigidShape::Box { half_extents } => {
                if !(half_extents.is_finite() && half_extents.min_element() > 0.0) {
                    push(
                        at("shape.half_extents"),
                        format!(
                            "must be finite and > 0 m on every axis (got {})",
                            fmt_vec(half_extents)
                        ),
                    );
                    shape_ok = false;
                }
            }
        }
        match (s.density, s.mass) {
            (Some(rho), None) => {
                if !(rho.is_finite() && rho > 0.0) {
                    push(
                        at("density"),
                        format!("must be a finite number > 0 kg/m³ (got {rho})"),
                    );
                }
            }
            (None, Some(m)) => {
                if !(m.is_finite() && m > 0.0) {
                    push(
                        at("mass"),
                        format!("must be a finite number > 0 kg (got {m})"),
                    );
                }
            }
            (Some(_), Some(_)) => push(
                at("mass"),
                "give either `density` or `mass`, not both".to_string(),
            ),
            (None, None) => push(
                format!("rigid_bodies[{i}]"),
                "needs `density: ρ` (kg/m³) or `mass: M` (kg)".to_string(),
            ),
        }
        let mut pos_ok = true;
        for (name, v, unit) in [
            ("position", s.position, "m"),
            ("velocity", s.velocity, "m/s"),
            ("angular_velocity", s.angular_velocity, "rad/s"),
        ] {
            if !v.is_finite() {
                push(
                    at(name),
                    format!("must have finite components [{unit}] (got {})", fmt_vec(v)),
                );
                pos_ok &= name != "position";
            }
        }
        let mut rot_ok = true;
        match s.rotation {
            RotationSpec::AxisAngle { axis, degrees } => {
                if !(axis.is_finite() && axis.length_squared() > 0.0) {
                    push(
                        at("rotation.axis"),
                        format!("must be a finite non-zero vector (got {})", fmt_vec(axis)),
                    );
                    rot_ok = false;
                }
                if !degrees.is_finite() {
                    push(
                        at("rotation.degrees"),
                        format!("must be finite (got {degrees})"),
                    );
                    rot_ok = false;
                }
            }
            RotationSpec::Euler { x, y, z } => {
                for (name, v) in [("x", x), ("y", y), ("z", z)] {
                    if !v.is_finite() {
                        push(
                            at(&format!("rotation.{name}")),
                            format!("must be finite (got {v})"),
                        );
                        rot_ok = false;
                    }
                }
            }
        }
        match s.boundary {
            BoundaryCondition::Friction(mu) if !(mu.is_finite() && mu >= 0.0) => push(
                at("boundary"),
                format!("friction coefficient must be a finite number ≥ 0 (got {mu})"),
            ),
            BoundaryCondition::Open | BoundaryCondition::Periodic => push(
                at("boundary"),
                format!(
                    "{:?} is not a condition between a body and the liquid; use Sticky, Slip or \
                     Friction(μ)",
                    s.boundary
                ),
            ),
            _ => {}
        }
        let Some((dmin, dmax)) = domain else { continue };
        if !(shape_ok && pos_ok && rot_ok) {
            continue;
        }
        let e = s.half_aabb();
        let (lo, hi) = (s.position - e, s.position + e);
        let periodic = walls.periodic_axes();
        const AXES: [&str; 3] = ["x", "y", "z"];
        let mut problems = Vec::new();
        for a in 0..3 {
            if periodic[a] {
                let rb = bounding_radius(&s.shape.collider_shape());
                let room = (dmax[a] - dmin[a]) - 2.0 * dx.unwrap_or(0.0);
                if 2.0 * rb >= room {
                    problems.push(format!(
                        "along the periodic {} axis its size 2·{rb} m must be less than the \
                         domain length minus 2·dx = {room} m",
                        AXES[a]
                    ));
                }
            } else if lo[a] < dmin[a] || hi[a] > dmax[a] {
                problems.push(format!(
                    "on {} it spans [{}, {}] m but the domain is [{}, {}] m",
                    AXES[a], lo[a], hi[a], dmin[a], dmax[a]
                ));
            }
        }
        if !problems.is_empty() {
            push(
                at("position"),
                format!(
                    "the body must lie inside the domain: {}",
                    problems.join("; ")
                ),
            );
        }
    }
    out
}
