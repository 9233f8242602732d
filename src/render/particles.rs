//! Particles: the instance data on the CPU ([`ParticleInstances`]), its copy into one GPU
//! storage buffer per frame, and the impostor material that draws every particle in one draw.
use bevy::asset::{Asset, Assets, Handle, RenderAssetUsages};
use bevy::camera::visibility::NoFrustumCulling;
use bevy::ecs::prelude::*;
use bevy::mesh::{Mesh, Mesh3d, PrimitiveTopology};
use bevy::pbr::{Material, MaterialPipeline, MaterialPipelineKey, MeshMaterial3d};
use bevy::reflect::TypePath;
use bevy::render::render_resource::{
    AsBindGroup, RenderPipelineDescriptor, SpecializedMeshPipelineError,
};
use bevy::render::storage::ShaderBuffer;
use bevy::shader::ShaderRef;
use bevy::transform::components::Transform;

use bevy::mesh::MeshVertexBufferLayoutRef;

use crate::components::{CauchyStress, Density, Particle, Position, Velocity};
use crate::material::MaterialId;
use crate::thermal::{PhaseIndex, Temperature};

use super::colour::colour_map_lut;
use super::{ColourField, ColourRange, ParticleStyle};

/// The particle shader (embedded; see `particles.wesl`).
pub(crate) const PARTICLE_SHADER: &str = "embedded://treacle/render/particles.wesl";

/// Billboard corners in sphere radii: an equilateral triangle whose inscribed circle is the
/// unit disc (counter-clockwise seen from the camera).
const CORNERS: [[f32; 2]; 3] = [[0.0, 2.0], [-1.732_050_8, -1.0], [1.732_050_8, -1.0]];

/// Slots of the first particle mesh; the mesh and buffer double when the count exceeds it.
const MIN_CAPACITY: usize = 1024;

/// The per-particle data the GPU draws, filled every frame on the CPU: one `[x, y, z, value]`
/// per particle (16 bytes), the colour range and the sphere radius.
///
/// With [`ParticleFeed::World`](super::ParticleFeed::World) the plugin fills it from the
/// particle entities (`Position`, `Velocity`, ... `With<Particle>`) in `PostUpdate`; with
/// [`ParticleFeed::External`](super::ParticleFeed::External) the caller does (frame files).
#[derive(Resource, Clone, Debug, Default)]
pub struct ParticleInstances {
    /// `[x, y, z, value]` per particle \[m\], value in the field's unit (NaN: no value, grey).
    pub data: Vec<[f32; 4]>,
    /// Value mapped to the first colour of the map.
    pub min: f32,
    /// Value mapped to the last colour of the map.
    pub max: f32,
    /// Sphere radius \[m\].
    pub radius: f32,
}

impl ParticleInstances {
    /// Fills `data` from positions and values (same length) and sets the colour range from
    /// `range` (for [`ColourRange::Auto`], the finite values' min and max).
    pub fn fill(&mut self, positions: &[[f32; 3]], values: &[f32], range: ColourRange) {
        self.data.clear();
        self.data.reserve(positions.len());
        for (p, v) in positions.iter().zip(values) {
            self.data.push([p[0], p[1], p[2], *v]);
        }
        self.set_range(range);
    }

    /// Sets `min`/`max` from `range`, scanning `data` for [`ColourRange::Auto`] (a range of
    /// zero width is widened so that the colour is the middle of the map).
    pub fn set_range(&mut self, range: ColourRange) {
        let (lo, hi) = match range {
            ColourRange::Fixed { min, max } => (min, max),
            ColourRange::Auto => {
                let mut lo = f32::INFINITY;
                let mut hi = f32::NEG_INFINITY;
                for d in &self.data {
                    if d[3].is_finite() {
                        lo = lo.min(d[3]);
                        hi = hi.max(d[3]);
                    }
                }
                if lo > hi { (0.0, 1.0) } else { (lo, hi) }
            }
        };
        let (lo, hi) = if hi > lo {
            (lo, hi)
        } else {
            let pad = lo.abs().max(1.0) * 0.5;
            (lo - pad, lo + pad)
        };
        self.min = lo;
        self.max = hi;
    }

    /// Axis-aligned bounds of the particle centres, `None` when there are none.
    pub fn bounds(&self) -> Option<(glam::Vec3, glam::Vec3)> {
        let mut it = self.data.iter().map(|d| glam::Vec3::new(d[0], d[1], d[2]));
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p))))
    }
}

/// Impostor material of the particle cloud: the instance buffer (header + one `vec4` per
/// particle) and the colour map, both storage buffers. Unlit by the scene's lights (its own
/// key light in the shader), casts no shadow, has no prepass.
#[derive(Asset, AsBindGroup, Clone, Debug)]
pub struct ParticleMaterial {
    /// Header `[count (u32 bits), min, max, radius]`, then `[x, y, z, value]` per particle.
    #[storage(0, read_only)]
    pub instances: Handle<ShaderBuffer>,
    /// Linear-RGBA colours, low values first.
    #[storage(1, read_only)]
    pub colour_map: Handle<ShaderBuffer>,
}

// By hand: the derive names `bevy_reflect`, which this crate lists only for its `reflect`
// feature.
impl TypePath for ParticleMaterial {
    fn type_path() -> &'static str {
        "treacle::render::ParticleMaterial"
    }

    fn short_type_path() -> &'static str {
        "ParticleMaterial"
    }
}

impl Material for ParticleMaterial {
    fn vertex_shader() -> ShaderRef {
        ShaderRef::Path(PARTICLE_SHADER.into())
    }

    fn fragment_shader() -> ShaderRef {
        ShaderRef::Path(PARTICLE_SHADER.into())
    }

    fn enable_prepass() -> bool {
        false
    }

    fn enable_shadows() -> bool {
        false
    }

    fn specialize(
        _pipeline: &MaterialPipeline,
        descriptor: &mut RenderPipelineDescriptor,
        _layout: &MeshVertexBufferLayoutRef,
        _key: MaterialPipelineKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        // Billboards always face the camera; no culling needed (and none wanted if a custom
        // projection flips the winding).
        descriptor.primitive.cull_mode = None;
        Ok(())
    }
}

/// The entity drawing the particle cloud and the GPU resources behind it.
#[derive(Resource, Debug)]
pub struct ParticleCloud {
    /// The drawing entity (mesh + material).
    pub entity: Entity,
    /// Its material.
    pub material: Handle<ParticleMaterial>,
    /// The instance storage buffer.
    pub buffer: Handle<ShaderBuffer>,
    /// The slot mesh.
    pub mesh: Handle<Mesh>,
    /// Particle slots in the mesh and the buffer.
    pub capacity: usize,
}

/// A mesh of `capacity` triangles, one per particle slot (see `particles.wesl`).
pub fn slot_mesh(capacity: usize) -> Mesh {
    let mut positions = Vec::with_capacity(3 * capacity);
    for slot in 0..capacity {
        for c in CORNERS {
            positions.push([c[0], c[1], slot as f32]);
        }
    }
    Mesh::new(
        PrimitiveTopology::TriangleList,
        RenderAssetUsages::RENDER_WORLD,
    )
    .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, positions)
}

/// Bytes of the instance buffer for `capacity` slots (header included).
fn buffer_bytes(capacity: usize) -> u64 {
    ((capacity + 1) * 16) as u64
}

/// Startup: creates the particle-cloud entity, its material and buffers ([`ParticleCloud`]).
pub fn spawn_particle_cloud(
    mut commands: Commands,
    mut meshes: ResMut<Assets<Mesh>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut materials: ResMut<Assets<ParticleMaterial>>,
    style: Res<ParticleStyle>,
) {
    let capacity = MIN_CAPACITY;
    let mut instances = ShaderBuffer::new(vec![[0.0f32; 4]], RenderAssetUsages::RENDER_WORLD);
    instances.resize_buffer(buffer_bytes(capacity));
    instances.label = "treacle particle instances".into();
    let buffer = buffers.add(instances);
    let colour_map = buffers.add(ShaderBuffer::new(
        colour_map_lut(style.map),
        RenderAssetUsages::RENDER_WORLD,
    ));
    let material = materials.add(ParticleMaterial {
        instances: buffer.clone(),
        colour_map,
    });
    let mesh = meshes.add(slot_mesh(capacity));
    let entity = commands
        .spawn((
            Mesh3d(mesh.clone()),
            MeshMaterial3d(material.clone()),
            Transform::IDENTITY,
            NoFrustumCulling,
            Name::new("treacle particles"),
        ))
        .id();
    commands.insert_resource(ParticleCloud {
        entity,
        material,
        buffer,
        mesh,
        capacity,
    });
}

/// `PostUpdate`: copies [`ParticleInstances`] into the GPU instance buffer (one memcpy-like
/// pass; the buffer and the slot mesh double when the particles outgrow them).
pub fn upload_particle_instances(
    instances: Res<ParticleInstances>,
    mut cloud: ResMut<ParticleCloud>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut meshes: ResMut<Assets<Mesh>>,
) {
    let n = instances.data.len();
    if n > cloud.capacity {
        let mut capacity = cloud.capacity;
        while capacity < n {
            capacity *= 2;
        }
        cloud.capacity = capacity;
        if let Some(mut mesh) = meshes.get_mut(&cloud.mesh) {
            *mesh = slot_mesh(capacity);
        }
    }
    let mut data = Vec::with_capacity(n + 1);
    data.push([
        f32::from_bits(n as u32),
        instances.min,
        instances.max,
        instances.radius,
    ]);
    data.extend_from_slice(&instances.data);
    let mut buffer = ShaderBuffer::new(data, RenderAssetUsages::RENDER_WORLD);
    buffer.resize_buffer(buffer_bytes(cloud.capacity));
    buffer.label = "treacle particle instances".into();
    if let Some(mut b) = buffers.get_mut(&cloud.buffer) {
        *b = buffer;
    }
}

/// `PostUpdate` with [`ParticleFeed::World`](super::ParticleFeed::World): reads the particle
/// entities into [`ParticleInstances`] (positions and the [`ParticleStyle`] field).
#[allow(clippy::type_complexity)]
pub fn gather_particle_instances(
    style: Res<ParticleStyle>,
    mut instances: ResMut<ParticleInstances>,
    particles: Query<
        (
            &Position,
            &Velocity,
            &MaterialId,
            Option<&Density>,
            Option<&Temperature>,
            Option<&PhaseIndex>,
            Option<&CauchyStress>,
        ),
        With<Particle>,
    >,
) {
    let instances = instances.as_mut();
    instances.data.clear();
    instances.data.reserve(particles.iter().len());
    let field = &style.field;
    for (x, v, mat, rho, temp, phase, stress) in &particles {
        let value = particle_value(field, x, v, mat, rho, temp, phase, stress);
        instances.data.push([x.0.x, x.0.y, x.0.z, value]);
    }
    instances.set_range(style.range);
    instances.radius = style.radius;
}

/// The value of `field` for one particle (NaN when it lacks the component or the field is
/// stored-only).
#[allow(clippy::too_many_arguments)]
pub(crate) fn particle_value(
    field: &ColourField,
    x: &Position,
    v: &Velocity,
    mat: &MaterialId,
    rho: Option<&Density>,
    temp: Option<&Temperature>,
    phase: Option<&PhaseIndex>,
    stress: Option<&CauchyStress>,
) -> f32 {
    match field {
        ColourField::Speed => v.0.length(),
        ColourField::Temperature => temp.map_or(f32::NAN, |t| t.value),
        ColourField::Phase => phase.map_or(f32::NAN, |p| p.0),
        ColourField::Material => mat.0 as f32,
        ColourField::StressNorm => stress.map_or(f32::NAN, |s| deviatoric_norm(s.0)),
        ColourField::Density => rho.map_or(f32::NAN, |d| d.value),
        ColourField::Height => x.0.y,
        ColourField::Stored(_) => f32::NAN,
    }
}

/// Frobenius norm of the deviatoric part of `sigma`, √(s:s) with s = σ − tr(σ)/3·I \[Pa\]
/// (the shear stress; the pressure is the `density`/`pressure` field's business).
pub fn deviatoric_norm(sigma: glam::Mat3) -> f32 {
    let p = (sigma.x_axis.x + sigma.y_axis.y + sigma.z_axis.z) / 3.0;
    let s = sigma - glam::Mat3::from_diagonal(glam::Vec3::splat(p));
    (s.x_axis.length_squared() + s.y_axis.length_squared() + s.z_axis.length_squared()).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deviatoric_norm_of_pressure_is_zero_and_of_shear_is_sqrt2_tau() {
        let p = glam::Mat3::from_diagonal(glam::Vec3::splat(-7.0));
        assert!(deviatoric_norm(p).abs() < 1e-6);
        // Simple shear σ_xy = σ_yx = τ: s:s = 2τ².
        let tau = 3.0;
        let shear = glam::Mat3::from_cols(
            glam::Vec3::new(0.0, tau, 0.0),
            glam::Vec3::new(tau, 0.0, 0.0),
            glam::Vec3::ZERO,
        );
        assert!((deviatoric_norm(shear) - 2f32.sqrt() * tau).abs() < 1e-5);
    }

    #[test]
    fn auto_range_spans_finite_values_and_widens_a_constant() {
        let mut i = ParticleInstances::default();
        i.fill(
            &[[0.0; 3], [1.0; 3], [2.0; 3]],
            &[2.0, f32::NAN, 5.0],
            ColourRange::Auto,
        );
        assert_eq!((i.min, i.max), (2.0, 5.0));
        i.fill(&[[0.0; 3]], &[4.0], ColourRange::Auto);
        assert!(i.min < 4.0 && i.max > 4.0 && (i.min + i.max - 8.0).abs() < 1e-6);
    }
}
