//! The RON scene schema: plain serde structs, every one with `deny_unknown_fields`.
//!
//! The field-by-field reference (units, defaults, constraints) is `docs/scenes.md`; the doc
//! comments here repeat the essentials. Vectors (`Vec3`) are written as RON tuples
//! `(x, y, z)` (glam's serde format; `Vec3(x, y, z)` is accepted too, `[x, y, z]` is not).
//! Several types are reused from the simulation API so that a scene file is only a way of
//! filling it: [`IntegratorConfig`], [`TimeStepConfig`], [`DomainWalls`],
//! [`BoundaryCondition`] and [`FluidMaterial`]; collider shapes ([`ColliderShapeSpec`]) mirror
//! [`ColliderShape`] and add OBJ meshes.
use std::sync::Arc;

use serde::de::value::{EnumAccessDeserializer, MapAccessDeserializer, StringDeserializer};
use serde::de::{
    self, DeserializeSeed, EnumAccess, IntoDeserializer, MapAccess, VariantAccess, Visitor,
};
use serde::ser::SerializeStructVariant;
use serde::{Deserialize, Serialize};

use crate::collision::{ColliderShape, MeshSdf};
use crate::config::{BoundaryCondition, DomainWalls, IntegratorConfig, TimeStepConfig};
use crate::material::FluidMaterial;
pub use crate::math::RotationSpec;
use crate::math::{Real, Vec3};
pub use crate::sampling::Axis;
use crate::validation::Identifier;

/// A scene file. In RON: `Scene(domain: (...), dx: 0.01, ...)` or just `(domain: ..., ...)`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, rename = "Scene")]
pub struct SceneFile {
    /// The simulation box \[m\]; walls ([`SceneFile::walls`]) sit on its six faces.
    pub domain: DomainSpec,
    /// Grid spacing Δx \[m\]; > 0.
    pub dx: Real,
    /// Particles per grid cell and dimension (ppc³ per cell), 1..=8. Default 2.
    #[serde(default = "default_ppc")]
    pub particles_per_cell: u32,
    /// Gravity \[m/s²\]. Default `(0, -9.81, 0)`.
    #[serde(default = "default_gravity")]
    pub gravity: Vec3,
    /// Simulated time \[s\]; > 0.
    pub duration: f64,
    /// Output frames per simulated second \[1/s\]; > 0. One frame lasts 1/frame_rate.
    pub frame_rate: f64,
    /// Seed of the sampling jitter. Default 0.
    #[serde(default)]
    pub seed: u64,
    /// GS4 integrator settings. Default [`IntegratorConfig::default`].
    #[serde(default)]
    pub integrator: IntegratorConfig,
    /// Time-step rule. Default [`TimeStepConfig::default`].
    #[serde(default)]
    pub time_step: TimeStepConfig,
    /// Boundary conditions of the six domain faces. Default: slip everywhere.
    #[serde(default)]
    pub walls: DomainWalls,
    /// Materials, referred to by name from the bodies. Default none.
    #[serde(default)]
    pub materials: Vec<FluidMaterial>,
    /// Liquid bodies filled with particles at start. Default none.
    #[serde(default)]
    pub bodies: Vec<BodySpec>,
    /// Collision objects. Default none.
    #[serde(default)]
    pub colliders: Vec<ColliderSpec>,
    /// Dynamic rigid spheres and boxes, moved by gravity and the liquid
    /// ([`crate::rigid::RigidBodySpec`]). Default none.
    #[serde(default)]
    pub rigid_bodies: Vec<crate::rigid::RigidBodySpec>,
    /// Rheology models attached to materials (beyond their Newtonian viscosity). A model's
    /// plugin and per-particle state exist only if some entry uses it. Default none.
    #[serde(default)]
    pub rheology: Vec<RheologySpec>,
    /// Nozzle emitters that deposit particles during the run (3D printing, ALGORITHM §4.4,
    /// [`crate::emit::EmitterSpec`]). Default none.
    #[serde(default)]
    pub emitters: Vec<crate::emit::EmitterSpec>,
    /// Melting and solidification per material (ALGORITHM §4.1–4.2,
    /// [`crate::thermal::phase::PhaseChangeSpec`]). Default none.
    #[serde(default)]
    pub phase_change: Vec<crate::thermal::phase::PhaseChangeSpec>,
    /// Temperature-dependent viscosity per material (ALGORITHM §4.3,
    /// [`crate::thermal::phase::TemperatureViscositySpec`]). Default none.
    #[serde(default)]
    pub temperature_viscosity: Vec<crate::thermal::phase::TemperatureViscositySpec>,
    /// Heat transfer (ALGORITHM §3, [`crate::thermal::scene::ThermalSpec`]): heated
    /// materials, prescribed wall and collider temperatures, solver. Default: no heat (no
    /// thermal plugin, no thermal state on any particle).
    #[serde(default)]
    pub thermal: crate::thermal::scene::ThermalSpec,
    /// Output settings. Default [`OutputSpec::default`].
    #[serde(default)]
    pub output: OutputSpec,
    /// How renderers look at the scene ([`super::CameraSpec`]). Default: framed on the
    /// liquid from the renderer's default direction.
    #[serde(default)]
    pub camera: super::CameraSpec,
}

/// Default particles per cell and dimension.
pub const DEFAULT_PARTICLES_PER_CELL: u32 = 2;

fn default_ppc() -> u32 {
    DEFAULT_PARTICLES_PER_CELL
}

fn default_gravity() -> Vec3 {
    Vec3::new(0.0, -9.81, 0.0)
}

fn default_one() -> Real {
    1.0
}

/// The axis-aligned simulation box.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomainSpec {
    /// Lower corner \[m\]; also the grid and particle-lattice origin.
    pub min: Vec3,
    /// Upper corner \[m\].
    pub max: Vec3,
}

/// A liquid body: a shape filled with particles of one material at start.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    /// Name of a material in [`SceneFile::materials`].
    pub material: String,
    /// The region to fill.
    pub shape: BodyShape,
    /// Initial velocity of every particle \[m/s\]. Default `(0, 0, 0)`.
    #[serde(default)]
    pub velocity: Vec3,
    /// Random displacement of each particle as a fraction of the particle spacing
    /// h = dx/particles_per_cell, in [0, 1]: each coordinate moves by U(−j·h/2, j·h/2).
    /// Default 0 (regular lattice).
    #[serde(default)]
    pub jitter: Real,
    /// Simulation time at which the body appears \[s\], in \[0, duration): its particles are
    /// spawned at the end of the first step that reaches it (a drop released during the run,
    /// [`crate::emit::DelayedBody`]). Default 0 (present from the start).
    #[serde(default)]
    pub release_time: f64,
}

/// The region of a body. Every particle whose lattice point lies inside is created.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum BodyShape {
    /// Axis-aligned box [min, max) \[m\].
    Box {
        /// Lower corner \[m\].
        min: Vec3,
        /// Upper corner \[m\]; > min on every axis.
        max: Vec3,
    },
    /// Ball.
    Sphere {
        /// Centre \[m\].
        center: Vec3,
        /// Radius \[m\]; > 0.
        radius: Real,
    },
    /// Solid circular cylinder.
    Cylinder {
        /// Centre (middle of the axis) \[m\].
        center: Vec3,
        /// Radius \[m\]; > 0.
        radius: Real,
        /// Half length along the axis \[m\]; > 0.
        half_height: Real,
        /// Direction of the axis. Default `Y`.
        #[serde(default)]
        axis: Axis,
    },
    /// Closed triangle mesh from an OBJ file, placed at `scale · v + translation`.
    Mesh {
        /// File path: absolute, or relative to the scene file's directory, or (if not found
        /// there) relative to the crate's `assets/` directory.
        path: String,
        /// Uniform scale factor (OBJ units → m); > 0. Default 1.
        #[serde(default = "default_one")]
        scale: Real,
        /// Translation after scaling \[m\]. Default `(0, 0, 0)`.
        #[serde(default)]
        translation: Vec3,
    },
}

/// A collision object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColliderSpec {
    /// Geometry in the collider's frame (see [`ColliderShapeSpec`]).
    pub shape: ColliderShapeSpec,
    /// Boundary condition on its surface.
    pub boundary: BoundaryCondition,
    /// Position of the collider's origin \[m\]. Default `(0, 0, 0)`.
    #[serde(default)]
    pub translation: Vec3,
    /// Orientation. Default none.
    #[serde(default)]
    pub rotation: RotationSpec,
    /// Scripted linear velocity \[m/s\]. Default `(0, 0, 0)`.
    #[serde(default)]
    pub linear_velocity: Vec3,
    /// Scripted angular velocity about the collider origin, world frame \[rad/s\].
    /// Default `(0, 0, 0)`.
    #[serde(default)]
    pub angular_velocity: Vec3,
    /// Simulated time at which the collider is removed \[s\] (> 0), e.g. to drop what
    /// rests on it. Default: never.
    #[serde(default)]
    pub remove_at: Option<f64>,
    /// Keyframed path of the origin ([`crate::collision::ColliderPath`]): piecewise linear
    /// through the keys, at rest before the first and after the last. Replaces `translation`
    /// and `linear_velocity` (leave them out). Default: none.
    #[serde(default)]
    pub path: Vec<PathKey>,
}

/// One key of a collider's path.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathKey {
    /// Time \[s\], ≥ 0; keys in increasing time.
    pub time: f64,
    /// Position of the collider's origin at that time \[m\].
    pub translation: Vec3,
}

/// File format of the particle output.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum OutputFormatSpec {
    /// Binary little-endian PLY point clouds.
    #[default]
    Ply,
    /// Legacy VTK polydata.
    Vtk,
}

/// A per-particle scalar written besides positions and velocities (always written).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum OutputField {
    /// Density ρ \[kg/m³\] (`density`).
    Density,
    /// Tait pressure p \[Pa\] (`pressure`).
    Pressure,
    /// Mass m \[kg\] (`mass`).
    Mass,
    /// Material index (`material`).
    Material,
    /// Speed |v| \[m/s\] (`speed`).
    Speed,
    /// Temperature Tₚ (`temperature`, scene units); 0 on particles without heat. Needs a
    /// `thermal` section.
    Temperature,
    /// Phase index I_s (`phase`): 1 solid, 0 liquid (§4.1); 0 on particles of materials
    /// without phase change. Needs a `phase_change` section.
    Phase,
}

impl OutputField {
    /// The field name used in output files.
    pub fn name(self) -> &'static str {
        match self {
            OutputField::Density => "density",
            OutputField::Pressure => "pressure",
            OutputField::Mass => "mass",
            OutputField::Material => "material",
            OutputField::Speed => "speed",
            OutputField::Temperature => "temperature",
            OutputField::Phase => "phase",
        }
    }
}

/// Output settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// File format. Default `Ply`.
    #[serde(default)]
    pub format: OutputFormatSpec,
    /// Write every n-th frame (frame 0 is always written); ≥ 1. Default 1.
    #[serde(default = "default_every")]
    pub every: u32,
    /// Scalar fields besides position and velocity. Default `[Density, Pressure, Material]`.
    #[serde(default = "default_fields")]
    pub fields: Vec<OutputField>,
}

fn default_every() -> u32 {
    1
}

fn default_fields() -> Vec<OutputField> {
    vec![
        OutputField::Density,
        OutputField::Pressure,
        OutputField::Material,
    ]
}

impl Default for OutputSpec {
    fn default() -> Self {
        Self {
            format: OutputFormatSpec::default(),
            every: default_every(),
            fields: default_fields(),
        }
    }
}

/// A collider's geometry as a scene file writes it: an analytic [`ColliderShape`] in its own
/// syntax (`Sphere(radius: 0.1)`, `Box(half_extents: (..))`, ...) or a closed OBJ mesh
/// (`Mesh(path: "meshes/bunny.obj", scale: 0.5)`), the one shape a file cannot hold itself.
/// Unknown fields are rejected.
#[derive(Clone, Debug, PartialEq)]
pub enum ColliderShapeSpec {
    /// Every [`ColliderShape`] but [`ColliderShape::Mesh`], read by its own `Deserialize`.
    Analytic(ColliderShape),
    /// [`ColliderShape::Mesh`]: a closed triangle mesh from an OBJ file, scaled by `scale`
    /// about the OBJ origin, which is the collider's origin (placed and moved by the
    /// collider's `translation`, `rotation` and velocities).
    Mesh(MeshFile),
}

/// The OBJ file of a [`ColliderShapeSpec::Mesh`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshFile {
    /// File path, resolved like a mesh body's ([`super::resolve_asset_path`]).
    pub path: String,
    /// Uniform scale factor (OBJ units → m); > 0. Default 1.
    #[serde(default = "default_one")]
    pub scale: Real,
}

impl ColliderShapeSpec {
    /// The simulation shape. `mesh` is the prepared mesh of a [`ColliderShapeSpec::Mesh`]
    /// (e.g. [`crate::collision::MeshSdf::from_obj`]); `None` for a mesh gives `None`.
    pub fn to_shape(&self, mesh: Option<&Arc<MeshSdf>>) -> Option<ColliderShape> {
        match self {
            ColliderShapeSpec::Analytic(shape) => Some(shape.clone()),
            ColliderShapeSpec::Mesh(_) => Some(ColliderShape::Mesh(mesh?.clone())),
        }
    }
}

/// The variants a scene file may name (those of [`ColliderShape`]).
const SHAPE_VARIANTS: &[&str] = &["HalfSpace", "Sphere", "Box", "Cylinder", "Mesh"];

impl<'de> Deserialize<'de> for ColliderShapeSpec {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_enum("ColliderShape", SHAPE_VARIANTS, ShapeVisitor)
    }
}

/// Reads the variant name, then hands the variant to [`MeshFile`] or to [`ColliderShape`]'s
/// own `Deserialize` (streaming: errors keep their position in the file).
struct ShapeVisitor;

impl<'de> Visitor<'de> for ShapeVisitor {
    type Value = ColliderShapeSpec;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a collider shape")
    }

    fn visit_enum<A: EnumAccess<'de>>(self, data: A) -> Result<Self::Value, A::Error> {
        let (Identifier(name), variant) = data.variant()?;
        if !SHAPE_VARIANTS.contains(&name.as_str()) {
            return Err(de::Error::unknown_variant(&name, SHAPE_VARIANTS));
        }
        if name == "Mesh" {
            return variant
                .struct_variant(&["path", "scale"], MeshFileVisitor)
                .map(ColliderShapeSpec::Mesh);
        }
        ColliderShape::deserialize(EnumAccessDeserializer::new(Named { name, variant }))
            .map(ColliderShapeSpec::Analytic)
    }
}

struct MeshFileVisitor;

impl<'de> Visitor<'de> for MeshFileVisitor {
    type Value = MeshFile;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("the fields of a mesh collider")
    }

    fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<MeshFile, A::Error> {
        MeshFile::deserialize(MapAccessDeserializer::new(map))
    }
}

/// An enum whose variant name was already read.
struct Named<V> {
    name: String,
    variant: V,
}

impl<'de, V: VariantAccess<'de>> EnumAccess<'de> for Named<V> {
    type Error = V::Error;
    type Variant = V;

    fn variant_seed<S: DeserializeSeed<'de>>(self, seed: S) -> Result<(S::Value, V), V::Error> {
        let name: StringDeserializer<V::Error> = self.name.into_deserializer();
        Ok((seed.deserialize(name)?, self.variant))
    }
}

impl Serialize for ColliderShapeSpec {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            ColliderShapeSpec::Analytic(shape) => shape.serialize(serializer),
            ColliderShapeSpec::Mesh(file) => {
                let mut s = serializer.serialize_struct_variant("ColliderShape", 4, "Mesh", 2)?;
                s.serialize_field("path", &file.path)?;
                s.serialize_field("scale", &file.scale)?;
                s.end()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn euler_convention() {
        // x = 90°: y → z.
        let q = RotationSpec::Euler {
            x: 90.0,
            y: 0.0,
            z: 0.0,
        }
        .to_quat();
        assert!((q * Vec3::Y - Vec3::Z).length() < 1e-6);
        // x = 90° then z = 90° (world axes): y → z → z; x → x → y.
        let q = RotationSpec::Euler {
            x: 90.0,
            y: 0.0,
            z: 90.0,
        }
        .to_quat();
        assert!((q * Vec3::Y - Vec3::Z).length() < 1e-6);
        assert!((q * Vec3::X - Vec3::Y).length() < 1e-6);
        let q = RotationSpec::AxisAngle {
            axis: Vec3::new(0.0, 0.0, 2.0),
            degrees: 90.0,
        }
        .to_quat();
        assert!((q * Vec3::X - Vec3::Y).length() < 1e-6);
    }
}

/// A rheology model attached to one material (all particles of that material carry its state).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RheologySpec {
    /// Name of a material in [`SceneFile::materials`].
    pub material: String,
    /// The model and its parameters.
    pub model: ModelSpec,
}

pub use crate::rheology::ModelSpec;
