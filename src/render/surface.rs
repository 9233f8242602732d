//! Surface mode: the reconstructed liquid surface ([`crate::surface::reconstruct_surface`])
//! drawn as a PBR mesh instead of the particles.
//!
//! [`SurfacePlugin`] (added by [`LiquidRenderPlugin`](super::LiquidRenderPlugin)) does nothing
//! while [`SurfaceSettings::enabled`] is false (one resource read a frame). When enabled, every
//! [`SurfaceSettings::every_n_frames`] frames in which the particles changed,
//! [`reconstruct_pending_surface`] reconstructs the surface from the positions in
//! [`ParticleInstances`](super::ParticleInstances) (the ones the particle renderer draws) and
//! puts it in [`PendingSurface`]; [`apply_pending_surface`] then swaps the mesh of the
//! [`LiquidSurface`] entity via [`surface_mesh_to_bevy`], and the particle cloud is hidden.
//! Reconstruction errors are logged once and leave the previous surface drawn.
use bevy::app::{App, Plugin, PostUpdate};
use bevy::asset::{Assets, RenderAssetUsages};
use bevy::camera::visibility::Visibility;
use bevy::color::Color;
use bevy::ecs::prelude::*;
use bevy::mesh::{Indices, Mesh, Mesh3d, PrimitiveTopology};
use bevy::pbr::{MeshMaterial3d, StandardMaterial};
use bevy::transform::components::Transform;

use crate::math::Vec3;
use crate::surface::{
    SurfaceMesh, SurfaceParams, estimate_spacing, reconstruct_surface, try_interpolate_to_vertices,
};

use super::colour::{ColourMap, colour_map_lut};
use super::particles::{ParticleCloud, ParticleInstances};
use super::{LiquidRenderSystems, ParticleStyle};

/// Why a [`SurfaceMesh`] cannot become a Bevy mesh.
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
pub fn surface_mesh_to_bevy(surface: &SurfaceMesh) -> Result<Mesh, SurfaceMeshError> {
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
    /// Clear, pale blue, glossy and transmissive.
    Water,
}

impl SurfacePreset {
    /// Every preset.
    pub const ALL: [Self; 5] = [
        Self::Honey,
        Self::Chocolate,
        Self::Ketchup,
        Self::Milk,
        Self::Water,
    ];

    /// The preset's CLI name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Honey => "honey",
            Self::Chocolate => "chocolate",
            Self::Ketchup => "ketchup",
            Self::Milk => "milk",
            Self::Water => "water",
        }
    }

    /// Parses a CLI name (honey, chocolate, ketchup, milk, water).
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// The preset's material (base colour in sRGB, roughness, specular transmission, IOR,
    /// thickness for transmission).
    pub fn material(self) -> StandardMaterial {
        let (color, roughness, transmission, thickness) = match self {
            Self::Honey => (Color::srgb(0.85, 0.52, 0.08), 0.08, 0.6, 0.05),
            Self::Chocolate => (Color::srgb(0.24, 0.12, 0.06), 0.35, 0.0, 0.0),
            Self::Ketchup => (Color::srgb(0.62, 0.05, 0.03), 0.12, 0.0, 0.0),
            Self::Milk => (Color::srgb(0.95, 0.94, 0.90), 0.3, 0.15, 0.02),
            Self::Water => (Color::srgb(0.62, 0.78, 0.90), 0.04, 0.85, 0.05),
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

/// How the surface is coloured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SurfaceLook {
    /// The [`SurfaceSettings::preset`]'s material.
    #[default]
    Preset,
    /// The particles' field of [`ParticleStyle`](super::ParticleStyle) (temperature, phase,
    /// speed, ...), interpolated to the vertices ([`interpolate_to_vertices`]) and mapped
    /// through its colour map over the particles' colour range, on a glossy white material
    /// (the melting and printing scenes). Where a particle has no value (NaN), the surface
    /// falls back to the preset.
    Field,
}

/// The material of a surface coloured per vertex ([`SurfaceLook::Field`]): white (the vertex
/// colours are the base colour), moderately glossy, opaque.
pub fn field_material() -> StandardMaterial {
    StandardMaterial {
        base_color: Color::WHITE,
        perceptual_roughness: 0.35,
        reflectance: 0.4,
        ..Default::default()
    }
}

/// Surface mode settings (a resource).
#[derive(Resource, Clone, Debug, PartialEq)]
pub struct SurfaceSettings {
    /// Draw the surface.
    pub enabled: bool,
    /// Material preset.
    pub preset: SurfacePreset,
    /// Preset colour or field colours.
    pub look: SurfaceLook,
    /// Reconstruct every N frames in which the particles changed (0 counts as 1).
    pub every_n_frames: u32,
    /// Reconstruction parameters; `None`: the defaults with the particle spacing estimated
    /// ([`estimate_spacing`]) from the first particles reconstructed, then kept (set them, e.g.
    /// `treacle::runner::surface_params(&scene)`, when the spacing is known).
    pub params: Option<SurfaceParams>,
}

impl Default for SurfaceSettings {
    fn default() -> Self {
        Self {
            enabled: false,
            preset: SurfacePreset::Honey,
            look: SurfaceLook::Preset,
            every_n_frames: 4,
            params: None,
        }
    }
}

/// A freshly reconstructed surface waiting to be drawn (written by the reconstruction system,
/// taken by [`apply_pending_surface`]).
#[derive(Resource, Clone, Debug, Default)]
pub struct PendingSurface {
    /// The mesh.
    pub mesh: Option<SurfaceMesh>,
    /// Linear-RGBA colour per vertex ([`SurfaceLook::Field`]), or `None`: the preset's colour.
    pub colours: Option<Vec<[f32; 4]>>,
}

/// The entity drawing the liquid surface.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct LiquidSurface;

/// Adds the surface-mode resources, [`reconstruct_pending_surface`] and
/// [`apply_pending_surface`] (in [`LiquidRenderSystems::Upload`], before the particle upload)
/// and [`sync_particle_visibility`] in `PostUpdate` (see the module docs).
///
/// Added by [`LiquidRenderPlugin`](super::LiquidRenderPlugin); it does nothing while
/// [`SurfaceSettings::enabled`] is false (one resource read a frame).
#[derive(Clone, Copy, Debug, Default)]
pub struct SurfacePlugin;

impl Plugin for SurfacePlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<SurfaceSettings>()
            .init_resource::<PendingSurface>()
            .add_systems(
                PostUpdate,
                (reconstruct_pending_surface, apply_pending_surface)
                    .chain()
                    .in_set(LiquidRenderSystems::Upload)
                    .before(super::upload_particle_instances),
            )
            .add_systems(
                PostUpdate,
                sync_particle_visibility.in_set(LiquidRenderSystems::Upload),
            );
    }
}

/// `PostUpdate`: with surface mode on, every [`SurfaceSettings::every_n_frames`]-th frame in
/// which [`ParticleInstances`] changed, reconstructs the surface of its positions into
/// [`PendingSurface`]. An error (no particles, bad parameters, a grid too large) is logged the
/// first time only; the previous surface stays drawn.
pub fn reconstruct_pending_surface(
    mut settings: ResMut<SurfaceSettings>,
    instances: Res<ParticleInstances>,
    style: Res<ParticleStyle>,
    mut pending: ResMut<PendingSurface>,
    mut changed_frames: Local<u64>,
    mut logged: Local<bool>,
) {
    if !settings.enabled || !instances.is_changed() {
        return;
    }
    let n = u64::from(settings.every_n_frames.max(1));
    let due = (*changed_frames).is_multiple_of(n);
    *changed_frames += 1;
    if !due {
        return;
    }
    let positions: Vec<Vec3> = instances
        .data
        .iter()
        .map(|d| Vec3::new(d[0], d[1], d[2]))
        .collect();
    if settings.params.is_none()
        && let Some(h) = estimate_spacing(&positions)
    {
        settings.bypass_change_detection().params = Some(SurfaceParams::for_spacing(h));
    }
    let params = settings.params.clone().unwrap_or_default();
    if positions.is_empty() {
        *pending = PendingSurface {
            mesh: Some(SurfaceMesh::default()),
            colours: None,
        };
        return;
    }
    match reconstruct_surface(&positions, &params) {
        Ok(mesh) => {
            let colours = match settings.look {
                SurfaceLook::Preset => None,
                SurfaceLook::Field => {
                    vertex_colours(&mesh, &positions, &instances, &params, style.map)
                }
            };
            *pending = PendingSurface {
                mesh: Some(mesh),
                colours,
            };
        }
        Err(e) => {
            if !*logged {
                *logged = true;
                log::warn!("surface reconstruction failed: {e} (logged once; surface not updated)");
            }
        }
    }
}

/// The field values of `instances` interpolated to the vertices of `mesh` and mapped through
/// `map` over the instances' colour range; `None` when a particle has no value (NaN).
fn vertex_colours(
    mesh: &SurfaceMesh,
    positions: &[Vec3],
    instances: &ParticleInstances,
    params: &SurfaceParams,
    map: ColourMap,
) -> Option<Vec<[f32; 4]>> {
    let values: Vec<f32> = instances.data.iter().map(|d| d[3]).collect();
    let at_vertices = try_interpolate_to_vertices(mesh, positions, &values, params).ok()?;
    let lut = colour_map_lut(map);
    let span = instances.max - instances.min;
    Some(
        at_vertices
            .iter()
            .map(|v| {
                let t = if span > 0.0 {
                    ((v - instances.min) / span).clamp(0.0, 1.0)
                } else {
                    0.5
                };
                lut[(t * (lut.len() - 1) as f32).round() as usize]
            })
            .collect(),
    )
}

/// `PostUpdate`: hides the particle cloud while surface mode is on, shows it when off.
pub fn sync_particle_visibility(
    settings: Res<SurfaceSettings>,
    cloud: Option<Res<ParticleCloud>>,
    mut visibility: Query<&mut Visibility>,
) {
    let Some(cloud) = cloud else {
        return;
    };
    let want = if settings.enabled {
        Visibility::Hidden
    } else {
        Visibility::Inherited
    };
    if let Ok(mut v) = visibility.get_mut(cloud.entity)
        && *v != want
    {
        *v = want;
    }
}

/// `PostUpdate`: turns a [`PendingSurface`] into the [`LiquidSurface`] entity's mesh (spawned
/// on first use with the preset's material). A malformed mesh is logged and skipped.
pub fn apply_pending_surface(
    mut commands: Commands,
    settings: Res<SurfaceSettings>,
    mut pending: ResMut<PendingSurface>,
    mut surfaces: Query<
        (&Mesh3d, &MeshMaterial3d<StandardMaterial>, &mut Visibility),
        With<LiquidSurface>,
    >,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut drawn_look: Local<Option<(SurfacePreset, bool)>>,
) {
    if !settings.enabled {
        return;
    }
    let Some(surface) = pending.mesh.take() else {
        return;
    };
    let colours = pending.colours.take();
    if surface.triangles.is_empty() {
        // No liquid (or only spray): nothing to draw.
        for (_, _, mut v) in &mut surfaces {
            *v = Visibility::Hidden;
        }
        return;
    }
    let colours = colours.filter(|c| c.len() == surface.vertices.len());
    let look = (settings.preset, colours.is_some());
    let material = if look.1 {
        field_material()
    } else {
        settings.preset.material()
    };
    let mesh = match surface_mesh_to_bevy(&surface) {
        Ok(m) => match colours {
            Some(c) => m.with_inserted_attribute(Mesh::ATTRIBUTE_COLOR, c),
            None => m,
        },
        Err(e) => {
            log::warn!("{e}; surface not drawn");
            return;
        }
    };
    match surfaces.single_mut() {
        Ok((handle, mat, mut v)) => {
            if let Some(mut m) = meshes.get_mut(&handle.0) {
                *m = mesh;
            }
            if *drawn_look != Some(look)
                && let Some(mut m) = materials.get_mut(&mat.0)
            {
                *m = material;
            }
            *v = Visibility::Inherited;
        }
        Err(_) => {
            commands.spawn((
                Mesh3d(meshes.add(mesh)),
                MeshMaterial3d(materials.add(material)),
                Transform::IDENTITY,
                LiquidSurface,
            ));
        }
    }
    *drawn_look = Some(look);
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevy::mesh::VertexAttributeValues;

    fn tetrahedron() -> SurfaceMesh {
        let vertices = vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
        let c = Vec3::splat(0.25);
        SurfaceMesh {
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
        let all = SurfacePreset::ALL;
        for p in all {
            assert_eq!(SurfacePreset::parse(p.name()), Some(p));
        }
        assert_eq!(SurfacePreset::parse("mustard"), None);
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                assert_ne!(a.material().base_color, b.material().base_color);
            }
        }
    }
}
