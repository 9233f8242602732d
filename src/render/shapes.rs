//! Meshes of the solid things the liquid meets: every [`ColliderShape`], nozzles, the floor.
use bevy::asset::RenderAssetUsages;
use bevy::math::{Dir3, Vec2};
use bevy::mesh::Meshable;
use bevy::mesh::{Indices, Mesh, PrimitiveTopology};
use bevy::shape::{Cuboid, Cylinder, Plane3d, Sphere};

use crate::collision::ColliderShape;
use crate::collision::MeshSdf;
use crate::math::Vec3;

/// A Bevy mesh of `shape` in the collider's local frame (the frame [`ColliderPose`] places).
///
/// - [`ColliderShape::HalfSpace`]: a square of half side `half_space_size` in the boundary
///   plane (the solid's face), centred at the local origin;
/// - sphere, box and cylinder (along local y): Bevy's primitive meshes of the same size;
/// - [`ColliderShape::Mesh`]: the collider's own triangles with flat normals.
///
/// [`ColliderPose`]: crate::collision::ColliderPose
pub fn collider_mesh(shape: &ColliderShape, half_space_size: f32) -> Mesh {
    match shape {
        ColliderShape::HalfSpace { normal } => {
            let n = Dir3::new(*normal).unwrap_or(Dir3::Y);
            Mesh::from(Plane3d::new(*n, Vec2::splat(half_space_size.max(1e-3))))
        }
        ColliderShape::Sphere { radius } => Sphere::new(*radius)
            .mesh()
            .ico(4)
            .unwrap_or_else(|_| Mesh::from(Sphere::new(*radius))),
        ColliderShape::Box { half_extents } => Mesh::from(Cuboid::from_size(*half_extents * 2.0)),
        ColliderShape::Cylinder {
            radius,
            half_height,
        } => Mesh::from(Cylinder::new(*radius, 2.0 * half_height)),
        ColliderShape::Mesh(sdf) => triangle_mesh(sdf),
    }
}

/// The triangles of a mesh collider as a flat-shaded Bevy mesh.
pub fn triangle_mesh(sdf: &MeshSdf) -> Mesh {
    triangles_to_mesh(sdf.vertices(), sdf.triangles())
}

/// Flat-shaded mesh of triangles (counter-clockwise seen from outside): every triangle gets its
/// own three vertices and its face normal.
pub fn triangles_to_mesh(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Mesh {
    let mut positions = Vec::with_capacity(3 * triangles.len());
    let mut normals = Vec::with_capacity(3 * triangles.len());
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices.get(i as usize).copied().unwrap_or(Vec3::ZERO));
        let n = (b - a).cross(c - a).normalize_or(Vec3::Y);
        for p in [a, b, c] {
            positions.push(p.to_array());
            normals.push(n.to_array());
        }
    }
    Mesh::new(
        PrimitiveTopology::TriangleList,
        RenderAssetUsages::RENDER_WORLD | RenderAssetUsages::MAIN_WORLD,
    )
    .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
    .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
}

/// A nozzle: a tube of outer radius 1.6 r and length 8 r whose open end (the tip) is at the
/// local origin and which extends along local +y (upstream; the pose turns +y to −axis).
pub fn nozzle_mesh(radius: f32) -> Mesh {
    const SEGMENTS: u32 = 24;
    let outer = 1.6 * radius;
    let inner = radius;
    let length = 8.0 * radius;
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut indices = Vec::new();
    // Outer wall, inner wall (normals inward), bottom ring: each a strip of quads.
    let ring = |r: f32, y: f32, k: u32| {
        let a = std::f32::consts::TAU * k as f32 / SEGMENTS as f32;
        (
            Vec3::new(r * a.cos(), y, r * a.sin()),
            Vec3::new(a.cos(), 0.0, a.sin()),
        )
    };
    let mut strip = |bottom: &dyn Fn(u32) -> (Vec3, Vec3), top: &dyn Fn(u32) -> (Vec3, Vec3)| {
        let base = positions.len() as u32;
        for k in 0..=SEGMENTS {
            for (p, n) in [bottom(k), top(k)] {
                positions.push(p.to_array());
                normals.push(n.to_array());
            }
        }
        for k in 0..SEGMENTS {
            let (b0, t0, b1, t1) = (
                base + 2 * k,
                base + 2 * k + 1,
                base + 2 * k + 2,
                base + 2 * k + 3,
            );
            indices.extend_from_slice(&[b0, t0, b1, b1, t0, t1]);
        }
    };
    strip(&|k| ring(outer, 0.0, k), &|k| ring(outer, length, k));
    strip(
        &|k| {
            let (p, n) = ring(inner, length, k);
            (p, -n)
        },
        &|k| {
            let (p, n) = ring(inner, 0.0, k);
            (p, -n)
        },
    );
    strip(&|k| (ring(inner, 0.0, k).0, -Vec3::Y), &|k| {
        (ring(outer, 0.0, k).0, -Vec3::Y)
    });
    Mesh::new(
        PrimitiveTopology::TriangleList,
        RenderAssetUsages::RENDER_WORLD | RenderAssetUsages::MAIN_WORLD,
    )
    .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
    .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
    .with_inserted_indices(Indices::U32(indices))
}

/// A horizontal floor: a square of half side `half_size` facing +y at the local origin.
pub fn floor_mesh(half_size: f32) -> Mesh {
    Mesh::from(Plane3d::new(Vec3::Y, Vec2::splat(half_size.max(1e-3))))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::mesh::VertexAttributeValues;

    fn positions(m: &Mesh) -> Vec<[f32; 3]> {
        match m.attribute(Mesh::ATTRIBUTE_POSITION) {
            Some(VertexAttributeValues::Float32x3(p)) => p.clone(),
            _ => panic!("no positions"),
        }
    }

    fn bounds(m: &Mesh) -> (Vec3, Vec3) {
        positions(m).iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p))),
        )
    }

    #[test]
    fn primitive_meshes_have_the_collider_extents() {
        // Mesh vertices lie on the exact surface for boxes and cylinders (to f32 rounding).
        let b = collider_mesh(
            &ColliderShape::Box {
                half_extents: Vec3::new(0.1, 0.2, 0.3),
            },
            1.0,
        );
        let (lo, hi) = bounds(&b);
        assert!((hi - Vec3::new(0.1, 0.2, 0.3)).abs().max_element() < 1e-6);
        assert!((lo + Vec3::new(0.1, 0.2, 0.3)).abs().max_element() < 1e-6);
        let c = collider_mesh(
            &ColliderShape::Cylinder {
                radius: 0.05,
                half_height: 0.2,
            },
            1.0,
        );
        let (lo, hi) = bounds(&c);
        assert!((hi.y - 0.2).abs() < 1e-6 && (lo.y + 0.2).abs() < 1e-6);
        assert!((hi.x - 0.05).abs() < 1e-6);
        // Icosphere vertices lie on the sphere.
        let s = collider_mesh(&ColliderShape::Sphere { radius: 0.3 }, 1.0);
        for p in positions(&s) {
            assert!((Vec3::from(p).length() - 0.3).abs() < 1e-5);
        }
    }

    #[test]
    fn triangle_mesh_normals_point_away_from_the_centroid() {
        // A tetrahedron, counter-clockwise from outside.
        let v = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
        let t = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
        let m = triangles_to_mesh(&v, &t);
        let centroid = Vec3::splat(0.25);
        let p = positions(&m);
        let Some(VertexAttributeValues::Float32x3(n)) = m.attribute(Mesh::ATTRIBUTE_NORMAL) else {
            panic!("no normals");
        };
        assert_eq!(p.len(), 12);
        for (p, n) in p.iter().zip(n) {
            assert!((Vec3::from(*p) - centroid).dot(Vec3::from(*n)) > 0.0);
        }
    }
}
