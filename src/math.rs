//! Scalar and vector types used by the simulation.
//!
//! Particle and grid state are stored in single precision (`Real = f32`): it halves memory
//! traffic in the transfer kernels. Global reductions (mass, energy) and the GS4 constants are
//! computed in `f64`.
/// Floating-point type of particle and grid state.
pub type Real = f32;
pub use glam::{Mat3, Vec3};
