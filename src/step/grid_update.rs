//! S11 (second half): GS4 acceleration increment, grid update and collisions
//! (ALGORITHM §2.9–2.11, eqs. 36, 38; errata E7; choice D5).
//!
//! Δaᵢ = (f̃ᵢ/m̃ᵢ + g − aᵢⁿ)/W₁Λ₆ (gravity is not divided by the mass, E7),
//! aᵢⁿ⁺¹ = aᵢⁿ + Δaᵢ, vᵢⁿ⁺¹ = vᵢⁿ + λ₄Δt aᵢⁿ + λ₅Δt Δaᵢ, then the collision projection of
//! [`crate::collision`] on vᵢⁿ⁺¹ and aᵢⁿ⁺¹ for domain walls and colliders.
//!
//! Reads `MpmGrid` (mass, velocity, acceleration, force), `MpmConfig`, colliders; writes
//! `MpmGrid` (new velocity, new acceleration).
use bevy_ecs::prelude::*;
use glam::IVec3;

use crate::collision::{ColliderInstance, project_acceleration, project_velocity};
use crate::config::{BoundaryCondition, DomainWalls, MpmConfig};
use crate::grid::{GhostCopy, GridLayout, GridNode, MpmGrid};
use crate::math::Vec3;
use crate::step::schedule::{ActiveColliders, StepContext};

/// Calls `f` on every z-row of the allocated blocks ([`MpmGrid::for_each_row`]), blocks in
/// parallel when the pool allows. The result does not depend on the thread count.
pub fn for_each_active_row(grid: &mut MpmGrid, f: impl Fn(&mut [GridNode]) + Sync) {
    grid.for_each_row(|_, row| f(row));
}

/// As [`for_each_active_row`], also passing the node coordinates of the row's first node.
pub fn for_each_active_row_indexed(grid: &mut MpmGrid, f: impl Fn(IVec3, &mut [GridNode]) + Sync) {
    grid.for_each_row(f);
}

/// Rounding allowance (in units of f32 ε relative to the coordinates) within which a node counts
/// as lying on a domain face.
const WALL_TOLERANCE_ULPS: f32 = 8.0;

/// Whether a node at coordinate `x` with signed distance `phi` to a domain face at `bound`
/// (positive inside the domain) is a wall node, i.e. on the face or beyond it, up to rounding.
#[inline]
pub fn on_or_beyond_face(phi: f32, x: f32, bound: f32) -> bool {
    phi <= WALL_TOLERANCE_ULPS * f32::EPSILON * (x.abs() + bound.abs())
}

/// Whether a node at world position `x` lies on or beyond the domain face (`axis`, `upper`) of
/// the box from `lo` to `hi`, up to rounding ([`on_or_beyond_face`]).
#[inline]
pub fn on_domain_face(x: Vec3, axis: usize, upper: bool, lo: Vec3, hi: Vec3) -> bool {
    if upper {
        on_or_beyond_face(hi[axis] - x[axis], x[axis], hi[axis])
    } else {
        on_or_beyond_face(x[axis] - lo[axis], x[axis], lo[axis])
    }
}

/// Applies the domain walls and colliders to a node at world position `x`.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn collide_node(
    x: Vec3,
    extra_dt: f32,
    walls: &DomainWalls,
    domain_min: Vec3,
    domain_max: Vec3,
    colliders: &[ColliderInstance],
    v: &mut Vec3,
    a: &mut Vec3,
) {
    for axis in 0..3 {
        for upper in [false, true] {
            let bc = walls.face(axis, upper);
            if matches!(bc, BoundaryCondition::Open | BoundaryCondition::Periodic) {
                continue;
            }
            let n = if upper {
                -Vec3::AXES[axis]
            } else {
                Vec3::AXES[axis]
            };
            // A node on the face is a wall node. Node positions are origin + i·Δx in f32, so
            // the node on the max face can land an ulp inside the domain (0.01f32 · 20 <
            // 0.2f32): without the tolerance the max faces lost their first wall layer and a
            // pool at rest drifted towards them (mean vx 1.9e-2 m/s in 0.1 s).
            if on_domain_face(x, axis, upper, domain_min, domain_max) {
                apply(v, a, Vec3::ZERO, n, bc, extra_dt);
            }
        }
    }
    for c in colliders {
        let (phi, n, vw) = c.query(x);
        if phi <= 0.0 {
            apply(v, a, vw, n, c.boundary, extra_dt);
        }
    }
}

/// `extra_dt` = (W₁Λ₆ − λ₅)Δt, see [`project_velocity`].
#[inline]
fn apply(v: &mut Vec3, a: &mut Vec3, v_wall: Vec3, n: Vec3, bc: BoundaryCondition, extra_dt: f32) {
    let extra = extra_dt * (-a.dot(n)).max(0.0);
    let nv = project_velocity(*v, v_wall, n, bc, extra);
    let projected = nv != *v;
    *v = nv;
    *a = project_acceleration(*a, n, bc, projected);
}

/// Grid update with collisions.
pub fn grid_update(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    colliders: Res<ActiveColliders>,
    mut grid: ResMut<MpmGrid>,
) {
    let c = ctx.coefficients;
    let g = config.gravity;
    let eps = grid.mass_epsilon;
    let layout: GridLayout = grid.layout;
    let walls = config.walls;
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    let colliders = &colliders.list;
    let inv_w1l6 = 1.0 / c.w1l6;
    let extra_dt = (c.w1l6 - c.l5).max(0.0) * c.dt;
    for_each_active_row_indexed(&mut grid, |first, row| {
        for (k, n) in row.iter_mut().enumerate() {
            if n.mass <= eps {
                continue;
            }
            let (force, acc, vel) = (
                Vec3::from(n.force),
                Vec3::from(n.acceleration),
                Vec3::from(n.velocity),
            );
            let da = (force / n.mass + g - acc) * inv_w1l6;
            let mut a_new = acc + da;
            let mut v_new = vel + (c.l4 * c.dt) * acc + (c.l5 * c.dt) * da;
            let x = layout.node_position(first + IVec3::new(0, 0, k as i32));
            collide_node(
                x, extra_dt, &walls, dmin, dmax, colliders, &mut v_new, &mut a_new,
            );
            n.new_velocity = v_new.into();
            n.new_acceleration = a_new.into();
        }
    });
    crate::step::p2g::copy_ghosts(&config, &mut grid, GhostCopy::Update);
}
