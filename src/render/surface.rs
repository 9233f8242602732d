//! Surface mode hook: a reconstructed liquid surface drawn as a PBR mesh instead of (or over)
//! the particles.
//!
//! The reconstruction itself is `treacle::surface` (another branch; not part of this module):
//!
//! ```text
//! pub fn reconstruct_surface(positions: &[Vec3], params: &SurfaceParams)
//!     -> Result<SurfaceMesh, SurfaceError>;
//! pub struct SurfaceMesh { vertices: Vec<Vec3>, normals: Vec<Vec3>, triangles: Vec<[u32; 3]> }
//! ```
//!
//! This module is written against [`SurfaceMeshData`], a stand-in with the same fields. When
//! `treacle::surface` is merged, **the plug-in point** is: implement
//! [`From<treacle::surface::SurfaceMesh>`] for [`SurfaceMeshData`] (a field-by-field move), or
//! replace the stand-in by a re-export, and have a system that every
//! [`SurfaceSettings::every_n_frames`] frames calls `reconstruct_surface` on the particle
//! positions and writes the result into [`PendingSurface`]. [`apply_pending_surface`] (added by
//! [`SurfacePlugin`]) then swaps the mesh of the [`LiquidSurface`] entity via
//! [`surface_mesh_to_bevy`]; per-vertex field colours (`interpolate_to_vertices`) can go into
//! `ATTRIBUTE_COLOR` the same way.
use bevy::app::{App, Plugin, PostUpdate};
use bevy::asset::{Assets, RenderAssetUsages};
use bevy::color::Color;
use bevy::ecs::prelude::*;
use bevy::mesh::{Indices, Mesh, Mesh3d, PrimitiveTopology};
use bevy::pbr::{MeshMaterial3d, StandardMaterial};
use bevy::transform::components::Transform;

use crate::math::Vec3;

/// Stand-in for `treacle::surface::SurfaceMesh` (same fields): an indexed triangle mesh with
/// per-vertex normals, triangles counter-clockwise seen from outside the liquid.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SurfaceMeshData {
    /// Vertex positions \[m\].
    pub vertices: Vec<Vec3>,
    /// Unit outward normals, one per vertex.
    pub normals: Vec<Vec3>,
    /// Vertex indices of each triangle.
    pub triangles: Vec<[u32; 3]>,
}

/// Why a [`SurfaceMeshData`] cannot become a Bevy mesh.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SurfaceMeshError {
    /// `normals` and `vertices` differ in length.
    #[error("surface mesh: {normals} normals for {vertices} vertices")]
    NormalCount {
        /// Number of vertices.
        vertices: usize,
        /// Number of normals.
        normals: usize,
    },
    /// A triangle names a vertex that does not exist.
    #[error("surface mesh: triangle {triangle} uses vertex {index} of {vertices}")]
    BadIndex {
        /// Triangle number.
        triangle: usize,
        /// The index.
        index: u32,
        /// Number of vertices.
        vertices: usize,
    },
}

/// The Bevy mesh of a reconstructed surface (indexed triangle list, positions and normals),
/// checked: every triangle index must name a vertex and there must be one normal per vertex.
pub fn surface_mesh_to_bevy(surface: &SurfaceMeshData) -> Result<Mesh, SurfaceMeshError> {
    let n = surface.vertices.len();
    if surface.normals.len() != n {
        return Err(SurfaceMeshError::NormalCount {
            vertices: n,
            normals: surface.normals.len(),
        });
    }
    let mut indices = Vec::with_capacity(3 * surface.triangles.len());
    for (i, t) in surface.triangles.iter().enumerate() {
        for &index in t {
            if index as usize >= n {
                return Err(SurfaceMeshError::BadIndex {
                    triangle: i,
                    index,
                    vertices: n,
                });
            }
            indices.push(index);
        }
    }
    let positions: Vec<[f32; 3]> = surface.vertices.iter().map(|v| v.to_array()).collect();
    let normals: Vec<[f32; 3]> = surface.normals.iter().map(|v| v.to_array()).collect();
    Ok(Mesh::new(
        PrimitiveTopology::TriangleList,
        RenderAssetUsages::RENDER_WORLD | RenderAssetUsages::MAIN_WORLD,
    )
    .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
    .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, normals)
    .with_inserted_indices(Indices::U32(indices)))
}

/// PBR looks of the liquid surface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SurfacePreset {
    /// Translucent amber, glossy.
    #[default]
    Honey,
    /// Dark brown, satin.
    Chocolate,
    /// Deep red, glossy.
    Ketchup,
    /// White, slightly translucent, soft.
    Milk,
}

impl SurfacePreset {
    /// The preset's material (base colour in sRGB, roughness, specular transmission, IOR,
    /// thickness for transmission).
    pub fn material(self) -> StandardMaterial {
        let (color, roughness, transmission, thickness) = match self {
            Self::Honey => (Color::srgb(0.85, 0.52, 0.08), 0.08, 0.6, 0.05),
            Self::Chocolate => (Color::srgb(0.24, 0.12, 0.06), 0.35, 0.0, 0.0),
            Self::Ketchup => (Color::srgb(0.62, 0.05, 0.03), 0.12, 0.0, 0.0),
            Self::Milk => (Color::srgb(0.95, 0.94, 0.90), 0.3, 0.15, 0.02),
        };
        StandardMaterial {
            base_color: color,
            perceptual_roughness: roughness,
            reflectance: 0.5,
            specular_transmission: transmission,
            thickness,
            ior: 1.45,
            ..Default::default()
        }
    }
}

/// Surface mode settings (a resource).
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct SurfaceSettings {
    /// Draw the surface.
    pub enabled: bool,
    /// Material preset.
    pub preset: SurfacePreset,
    /// Reconstruct every N rendered frames (≥ 1).
    pub every_n_frames: u32,
}

impl Default for SurfaceSettings {
    fn default() -> Self {
        Self {
            enabled: false,
            preset: SurfacePreset::Honey,
            every_n_frames: 4,
        }
    }
}

/// A freshly reconstructed surface waiting to be drawn (written by the reconstruction system,
/// taken by [`apply_pending_surface`]).
#[derive(Resource, Clone, Debug, Default)]
pub struct PendingSurface(pub Option<SurfaceMeshData>);

/// The entity drawing the liquid surface.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct LiquidSurface;

/// Adds the surface-mode resources and [`apply_pending_surface`]. (Reconstruction is not part
/// of it; see the module docs.)
#[derive(Clone, Copy, Debug, Default)]
pub struct SurfacePlugin;

impl Plugin for SurfacePlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<SurfaceSettings>()
            .init_resource::<PendingSurface>()
            .add_systems(PostUpdate, apply_pending_surface);
    }
}

/// `PostUpdate`: turns a [`PendingSurface`] into the [`LiquidSurface`] entity's mesh (spawned
/// on first use with the preset's material). A malformed mesh is logged and skipped.
pub fn apply_pending_surface(
    mut commands: Commands,
    settings: Res<SurfaceSettings>,
    mut pending: ResMut<PendingSurface>,
    surfaces: Query<&Mesh3d, With<LiquidSurface>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    if !settings.enabled {
        return;
    }
    let Some(surface) = pending.0.take() else {
        return;
    };
    let mesh = match surface_mesh_to_bevy(&surface) {
        Ok(m) => m,
        Err(e) => {
            log::warn!("{e}; surface not drawn");
            return;
        }
    };
    match surfaces.single() {
        Ok(handle) => {
            if let Some(mut m) = meshes.get_mut(&handle.0) {
                *m = mesh;
            }
        }
        Err(_) => {
            commands.spawn((
                Mesh3d(meshes.add(mesh)),
                MeshMaterial3d(materials.add(settings.preset.material())),
                Transform::IDENTITY,
                LiquidSurface,
            ));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::mesh::VertexAttributeValues;

    fn tetrahedron() -> SurfaceMeshData {
        let vertices = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
        let c = Vec3::splat(0.25);
        SurfaceMeshData {
            normals: vertices.iter().map(|v| (*v - c).normalize()).collect(),
            vertices,
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        }
    }

    #[test]
    fn surface_mesh_converts_with_its_indices_and_normals() {
        let s = tetrahedron();
        let m = surface_mesh_to_bevy(&s).expect("valid mesh");
        assert_eq!(m.count_vertices(), 4);
        let Some(Indices::U32(idx)) = m.indices() else {
            panic!("u32 indices expected");
        };
        assert_eq!(idx, &[0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]);
        let Some(VertexAttributeValues::Float32x3(n)) = m.attribute(Mesh::ATTRIBUTE_NORMAL) else {
            panic!("normals expected");
        };
        assert_eq!(n[1], s.normals[1].to_array());
    }

    #[test]
    fn malformed_surface_meshes_are_errors_not_panics() {
        let mut s = tetrahedron();
        s.triangles.push([0, 1, 9]);
        assert_eq!(
            surface_mesh_to_bevy(&s).unwrap_err(),
            SurfaceMeshError::BadIndex {
                triangle: 4,
                index: 9,
                vertices: 4
            }
        );
        let mut s = tetrahedron();
        s.normals.pop();
        assert!(matches!(
            surface_mesh_to_bevy(&s),
            Err(SurfaceMeshError::NormalCount { .. })
        ));
    }

    #[test]
    fn presets_differ() {
        let all = [
            SurfacePreset::Honey,
            SurfacePreset::Chocolate,
            SurfacePreset::Ketchup,
            SurfacePreset::Milk,
        ];
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                assert_ne!(a.material().base_color, b.material().base_color);
            }
        }
    }
}
