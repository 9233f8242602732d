//! Scalar and vector types used by the simulation.
//!
//! Particle and grid state are stored in single precision (`Real = f32`): it halves memory
//! traffic in the transfer kernels. Global reductions (mass, energy) and the GS4 constants are
//! computed in `f64`.
/// Floating-point type of particle and grid state.
pub type Real = f32;
pub use glam::{Mat3, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// ⌊x⌋ for |x| < 2³¹ without a libm call (baseline x86-64 has no SSE4.1 `roundps`; `floorf`
/// showed up at 6 % of a step in profiles).
#[inline(always)]
pub fn fast_floor(x: Real) -> i32 {
    let i = x as i32;
    if (i as Real) > x { i - 1 } else { i }
}

/// An orientation, in degrees.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum RotationSpec {
    /// Rotation by `degrees` about `axis` (right-hand rule; the axis is normalised).
    AxisAngle {
        /// Rotation axis (non-zero).
        axis: Vec3,
        /// Angle \[°\].
        degrees: Real,
    },
    /// Rotation about the fixed world axes, first x, then y, then z:
    /// R = R_z(z) · R_y(y) · R_x(x) (extrinsic X-Y-Z; equal to intrinsic Z-Y'-X'').
    Euler {
        /// Angle about x \[°\]. Default 0.
        #[serde(default)]
        x: Real,
        /// Angle about y \[°\]. Default 0.
        #[serde(default)]
        y: Real,
        /// Angle about z \[°\]. Default 0.
        #[serde(default)]
        z: Real,
    },
}

impl Default for RotationSpec {
    fn default() -> Self {
        RotationSpec::Euler {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }
    }
}

impl RotationSpec {
    /// The rotation as a unit quaternion (identity for a zero axis).
    pub fn to_quat(&self) -> Quat {
        match *self {
            RotationSpec::AxisAngle { axis, degrees } => {
                let a = axis.normalize_or_zero();
                if a == Vec3::ZERO {
                    Quat::IDENTITY
                } else {
                    Quat::from_axis_angle(a, degrees.to_radians())
                }
            }
            RotationSpec::Euler { x, y, z } => {
                Quat::from_rotation_z(z.to_radians())
                    * Quat::from_rotation_y(y.to_radians())
                    * Quat::from_rotation_x(x.to_radians())
            }
        }
    }
}
