//! The 3D-printing nozzle: a volume source that emits particles along a tool path
//! (ALGORITHM §4.4, step S16 of §2.3).
//!
//! # Model (§4.4)
//!
//! Eq. (13) of \[Su21\] adds the source ρQ̇δ(x − x_s) to the continuity equation (and
//! ρcT_inj Q̇δ to the energy equation). In MPM this is particle emission: mass and energy enter
//! with the new particles.
//!
//! ```text
//! disk lattice S = {i h u + j h w : (i h)² + (j h)² ≤ r_n²},  u, w ⊥ e,  N_layer = |S|
//! extrusion speed v_e = Q̇ / (N_layer h²)                        → mass rate exactly ρ₀Q̇
//! per step: s += v_e Δt_extruding
//!     while s ≥ h: s −= h; for s_k ∈ S spawn at x_s(t) + s e + s_k (+ jitter),
//!                  v = v_e e + ẋ_s(t), a = g, m = ρ₀h³, ρ = ρ₀, F = I, σᴺᴸ = 0, T = T_inj
//! ```
//! Δt_extruding is the part of the step during which the tool path extrudes (travel moves do
//! not emit, [`ToolPath::extruding_time`]). s starts at h/2 (§4.4 leaves it open), so the
//! deposited mass is ρ₀Q̇ times the extruding time rounded to the nearest layer, within half a
//! layer N_layer ρ₀h³ (test C2 of §9). The emitted particles get exactly the
//! state a new particle needs: [`ParticleBundle`](crate::components::ParticleBundle), the
//! initial state of the material's rheology models and phase change
//! ([`ParticleInitializers`](super::ParticleInitializers)) and, for an emitter with an
//! injection temperature, the thermal pair T = T_inj, Ṫ = 0, d = ḋ = 0.
//!
//! # Determinism
//!
//! Emission runs in one exclusive system, emitters in entity order, jitter from a
//! [`SplitMix64`] stream seeded per emitter: the same scene gives the same particles for any
//! thread count.
#[cfg(feature = "reflect")]
use bevy_ecs::reflect::ReflectComponent;
use std::sync::Arc;

use bevy_ecs::prelude::*;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::material::MaterialId;
use crate::math::{Real, Vec3};
use crate::sampling::SplitMix64;

/// One straight piece of a tool path, in scene coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathSegment {
    /// Start point of the nozzle tip \[m\].
    pub start: DVec3,
    /// End point \[m\].
    pub end: DVec3,
    /// Time to traverse it \[s\] (> 0).
    pub duration: f64,
    /// Whether the nozzle extrudes (emits) along it; travel moves do not.
    pub extrude: bool,
}

/// A timed polyline x_s(t) of the nozzle tip (§4.4), t = 0 at its start. Before 0 the nozzle
/// is at the first point, after the end at the last one (at rest, not extruding).
#[derive(Clone, Debug, PartialEq)]
pub struct ToolPath {
    segments: Vec<PathSegment>,
    /// Start time of each segment \[s\]; one more entry: the total duration.
    starts: Vec<f64>,
    /// Extruding time before each segment \[s\]; one more entry: the total.
    extruded_before: Vec<f64>,
}

/// Why a tool path could not be built.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ToolPathError {
    /// No segment at all.
    #[error("the tool path is empty")]
    Empty,
    /// A segment with a non-finite point or a duration ≤ 0.
    #[error("segment {index}: {problem}")]
    BadSegment {
        /// Index of the segment.
        index: usize,
        /// What is wrong.
        problem: String,
    },
    /// Nothing is extruded.
    #[error("the tool path extrudes nothing")]
    NoExtrusion,
}

impl ToolPath {
    /// A path from its segments (each must have finite points and a finite duration > 0;
    /// at least one must extrude).
    pub fn new(segments: Vec<PathSegment>) -> Result<Self, ToolPathError> {
        if segments.is_empty() {
            return Err(ToolPathError::Empty);
        }
        let mut starts = Vec::with_capacity(segments.len() + 1);
        let mut extruded_before = Vec::with_capacity(segments.len() + 1);
        let (mut t, mut e) = (0.0, 0.0);
        for (index, s) in segments.iter().enumerate() {
            if !(s.start.is_finite() && s.end.is_finite()) {
                return Err(ToolPathError::BadSegment {
                    index,
                    problem: "non-finite point".into(),
                });
            }
            if !(s.duration.is_finite() && s.duration > 0.0) {
                return Err(ToolPathError::BadSegment {
                    index,
                    problem: format!("duration must be finite and > 0 s (got {})", s.duration),
                });
            }
            starts.push(t);
            extruded_before.push(e);
            t += s.duration;
            if s.extrude {
                e += s.duration;
            }
        }
        starts.push(t);
        extruded_before.push(e);
        if e == 0.0 {
            return Err(ToolPathError::NoExtrusion);
        }
        Ok(Self {
            segments,
            starts,
            extruded_before,
        })
    }

    /// An extruding polyline through `points` \[m\] traversed at `speed` \[m/s\] (> 0).
    /// Repeated points are skipped.
    pub fn polyline(points: &[DVec3], speed: f64) -> Result<Self, ToolPathError> {
        if !(speed.is_finite() && speed > 0.0) {
            return Err(ToolPathError::BadSegment {
                index: 0,
                problem: format!("speed must be finite and > 0 m/s (got {speed})"),
            });
        }
        let segments = points
            .windows(2)
            .filter(|w| w[0] != w[1])
            .map(|w| PathSegment {
                start: w[0],
                end: w[1],
                duration: (w[1] - w[0]).length() / speed,
                extrude: true,
            })
            .collect();
        Self::new(segments)
    }

    /// A nozzle held at `at` \[m\], extruding for `duration` \[s\] (> 0): a fixed source, such
    /// as the nozzle above a plate that pours a coiling rope.
    pub fn fixed(at: DVec3, duration: f64) -> Result<Self, ToolPathError> {
        Self::new(vec![PathSegment {
            start: at,
            end: at,
            duration,
            extrude: true,
        }])
    }

    /// The segments.
    pub fn segments(&self) -> &[PathSegment] {
        &self.segments
    }

    /// Total duration \[s\].
    pub fn duration(&self) -> f64 {
        *self.starts.last().unwrap_or(&0.0)
    }

    /// Total extruding time \[s\].
    pub fn total_extruding_time(&self) -> f64 {
        *self.extruded_before.last().unwrap_or(&0.0)
    }

    /// Index of the segment active at time `t` (clamped to the path).
    fn segment_at(&self, t: f64) -> usize {
        // starts[i] ≤ t < starts[i+1].
        let i = self.starts.partition_point(|&s| s <= t);
        i.saturating_sub(1).min(self.segments.len() - 1)
    }

    /// Nozzle tip position \[m\], velocity \[m/s\] and whether it extrudes, at path time `t`.
    pub fn sample(&self, t: f64) -> (DVec3, DVec3, bool) {
        if t.is_nan() || t < 0.0 {
            return (self.segments[0].start, DVec3::ZERO, false);
        }
        if t >= self.duration() {
            let last = self.segments[self.segments.len() - 1];
            return (last.end, DVec3::ZERO, false);
        }
        let i = self.segment_at(t);
        let s = &self.segments[i];
        let u = ((t - self.starts[i]) / s.duration).clamp(0.0, 1.0);
        let v = (s.end - s.start) / s.duration;
        (s.start + (s.end - s.start) * u, v, s.extrude)
    }

    /// Time spent extruding during \[0, t\] \[s\] (0 for t ≤ 0, the total for t ≥ the duration).
    pub fn extruding_time(&self, t: f64) -> f64 {
        if t.is_nan() || t <= 0.0 {
            return 0.0;
        }
        if t >= self.duration() {
            return self.total_extruding_time();
        }
        let i = self.segment_at(t);
        let s = &self.segments[i];
        let inside = if s.extrude { t - self.starts[i] } else { 0.0 };
        self.extruded_before[i] + inside.clamp(0.0, s.duration)
    }

    /// Axis-aligned bounds of the path \[m\].
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.segments.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), s| (lo.min(s.start).min(s.end), hi.max(s.start).max(s.end)),
        )
    }
}

/// The offsets s_k of the disk lattice S of §4.4: points i·h·u + j·h·w with
/// (ih)² + (jh)² ≤ r², u, w a fixed orthonormal basis of the plane ⊥ `axis`. At least the
/// centre. Deterministic order (j, then i, ascending).
pub fn disk_lattice(axis: Vec3, radius: Real, spacing: Real) -> Vec<Vec3> {
    let e = axis.as_dvec3().normalize_or_zero();
    let e = if e == DVec3::ZERO { DVec3::NEG_Y } else { e };
    let reference = if e.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let u = e.cross(reference).normalize();
    let w = e.cross(u);
    let (r, h) = (radius as f64, spacing as f64);
    let n = if h > 0.0 && r.is_finite() {
        (r / h).floor().min(1e4) as i64
    } else {
        0
    };
    let mut out = Vec::new();
    for j in -n..=n {
        for i in -n..=n {
            let (a, b) = (i as f64 * h, j as f64 * h);
            if a * a + b * b <= r * r * (1.0 + 1e-12) {
                out.push((u * a + w * b).as_vec3());
            }
        }
    }
    if out.is_empty() {
        out.push(Vec3::ZERO);
    }
    out
}

/// The offsets of a slot nozzle's layer (§4.4): a rectangle of `length` along `direction`
/// (projected ⊥ `axis`) and width 2·`half_width` across it, filled with points
/// (k + ½)·h·u + j·h·w for |(k + ½)h| ≤ length/2, |jh| ≤ half_width: the half-step offset along
/// the slot gives an even count spaced h, so a slot as long as a periodic domain joins its own
/// image with the same spacing. At least two points (one either side of the centre).
/// Deterministic order (j, then k, ascending).
pub fn slot_lattice(
    axis: Vec3,
    direction: Vec3,
    half_width: Real,
    length: Real,
    spacing: Real,
) -> Vec<Vec3> {
    let e = axis.as_dvec3().normalize_or_zero();
    let e = if e == DVec3::ZERO { DVec3::NEG_Y } else { e };
    let d = direction.as_dvec3();
    let u = (d - e * d.dot(e)).normalize_or_zero();
    let u = if u == DVec3::ZERO {
        let reference = if e.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        e.cross(reference).normalize()
    } else {
        u
    };
    let w = e.cross(u);
    let (r, l, h) = (half_width as f64, length as f64, spacing as f64);
    if !(h > 0.0 && r.is_finite() && l.is_finite()) {
        return vec![Vec3::ZERO];
    }
    let nj = (r / h).floor().clamp(0.0, 1e4) as i64;
    let nk = ((l / h).floor() as i64 / 2).clamp(1, 10_000);
    let mut out = Vec::new();
    for j in -nj..=nj {
        for k in -nk..nk {
            let a = (k as f64 + 0.5) * h;
            out.push((u * a + w * (j as f64 * h)).as_vec3());
        }
    }
    out
}

/// A slot nozzle's shape ([`NozzleEmitter::slot`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Slot {
    /// Direction of the slot's long side (projected ⊥ the nozzle axis; non-zero, not along
    /// the axis).
    pub direction: Vec3,
    /// Length of the slot \[m\] (≥ 2 particle spacings); its width is twice the nozzle radius.
    pub length: Real,
}

/// A nozzle that deposits particles of one material along a tool path (ALGORITHM §4.4).
/// Spawn it as an entity (its [`EmitterState`] is added automatically); the
/// [`EmitterPlugin`](super::EmitterPlugin) runs it in
/// [`MpmSystems::Emit`](crate::step::schedule::MpmSystems::Emit).
#[derive(Component, Clone, Debug)]
#[require(EmitterState, EmitterFrame)]
pub struct NozzleEmitter {
    /// Tool path x_s(t) of the nozzle tip, in scene coordinates; path time 0 is simulation
    /// time `start_time`.
    pub path: Arc<ToolPath>,
    /// Extrusion direction e (normalised on use; usually −up).
    pub axis: Vec3,
    /// Nozzle radius r_n \[m\] (> 0).
    pub radius: Real,
    /// Volume rate Q̇ \[m³/s\] (> 0) while the path extrudes.
    pub volume_rate: f64,
    /// Particle spacing h_p \[m\] (> 0), normally Δx/ppc; the particle volume is h_p³.
    pub spacing: Real,
    /// Injection temperature T_inj (scene temperature unit): emitted particles carry the
    /// thermal components ([`Temperature`](crate::thermal::components::Temperature) = T_inj,
    /// [`FluxDivergence`](crate::thermal::components::FluxDivergence) = 0,
    /// [`PredictedTemperature`](crate::thermal::components::PredictedTemperature) = T_inj).
    /// `None` for unheated materials (no thermal component).
    pub temperature: Option<Real>,
    /// Material of the emitted particles.
    pub material: MaterialId,
    /// Simulation time at which the path starts \[s\] (≥ 0).
    pub start_time: f64,
    /// Simulation time after which nothing is emitted \[s\]; `None`: the path's end.
    pub stop_time: Option<f64>,
    /// Random displacement of each emitted particle as a fraction of h_p, in \[0, 0.1\]:
    /// each coordinate moves by U(−j·h_p/2, j·h_p/2).
    pub jitter: Real,
    /// Seed of the jitter stream.
    pub seed: u64,
    /// Length of the nozzle's bore \[m\] (≥ 0; 0: none, the default). With a bore the layers
    /// are born inside it, up to `bore` behind the tip, and the liquid in it is driven: every
    /// step each particle still behind the tip gets the extrusion velocity (and a zero
    /// acceleration), as the liquid pushed through a real nozzle. The bore holds the jet that
    /// hangs from the nozzle; without it nothing holds the top of a falling jet, which then
    /// falls freely away from the layers emitted after it ([`InBore`]).
    pub bore: Real,
    /// A slot instead of a round opening: a rectangle `slot.length` long and 2·`radius` wide
    /// ([`slot_lattice`]), which pours a sheet (a slot as long as a periodic domain pours an
    /// endless one). `None` (the default): round.
    pub slot: Option<Slot>,
}

/// Marks a particle still inside the bore of the emitter entity it names
/// ([`NozzleEmitter::bore`]); removed when the particle passes the tip.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct InBore(pub Entity);

impl NozzleEmitter {
    /// An emitter along `path` with extrusion direction `axis`, nozzle radius `radius` \[m\],
    /// volume rate `volume_rate` \[m³/s\] and particle spacing `spacing` \[m\], for `material`;
    /// unheated, starting at t = 0, no stop, no jitter, seed 0.
    pub fn new(
        path: ToolPath,
        axis: Vec3,
        radius: Real,
        volume_rate: f64,
        spacing: Real,
        material: MaterialId,
    ) -> Self {
        Self {
            path: Arc::new(path),
            axis,
            radius,
            volume_rate,
            spacing,
            temperature: None,
            material,
            start_time: 0.0,
            stop_time: None,
            jitter: 0.0,
            seed: 0,
            bore: 0.0,
            slot: None,
        }
    }

    /// With a slot opening ([`NozzleEmitter::slot`]) of `length` along `direction`.
    pub fn with_slot(mut self, direction: Vec3, length: Real) -> Self {
        self.slot = Some(Slot { direction, length });
        self
    }

    /// With a driven bore of length `bore` \[m\] ([`NozzleEmitter::bore`]).
    pub fn with_bore(mut self, bore: Real) -> Self {
        self.bore = bore;
        self
    }

    /// Whether the nozzle extrudes at simulation time `t` (inside its window, on an extruding
    /// piece of the path).
    pub fn extrudes_at(&self, t: f64) -> bool {
        let (_, _, extruding) = self.path.sample(t - self.start_time);
        extruding && t >= self.start_time && self.stop_time.is_none_or(|s| t < s)
    }

    /// The drive of the bore at simulation time `t`, in the world placed by `frame`: the tip
    /// position, the unit extrusion axis and the velocity of the liquid in the bore (the
    /// extrusion speed for a lattice of `layer_size` points while extruding, plus the nozzle's
    /// motion).
    pub fn bore_drive(
        &self,
        frame: &EmitterFrame,
        t: f64,
        layer_size: usize,
    ) -> (DVec3, DVec3, Vec3) {
        let e = self.axis.as_dvec3().normalize();
        let (x_s, v_s, _) = self.path.sample(t - self.start_time);
        let v_e = if self.extrudes_at(t) {
            self.extrusion_speed(layer_size)
        } else {
            0.0
        };
        let tip = frame.point(x_s);
        let axis = (frame.point(x_s + e) - tip).normalize();
        (tip, axis, frame.velocity(x_s, e * v_e + v_s).as_vec3())
    }

    /// With an injection temperature T_inj.
    pub fn with_temperature(mut self, temperature: Real) -> Self {
        self.temperature = Some(temperature);
        self
    }

    /// With jitter (fraction of h_p, clamped to \[0, 0.1\]) and its seed.
    pub fn with_jitter(mut self, jitter: Real, seed: u64) -> Self {
        self.jitter = jitter;
        self.seed = seed;
        self
    }

    /// With start and stop times \[s\].
    pub fn with_window(mut self, start_time: f64, stop_time: Option<f64>) -> Self {
        self.start_time = start_time;
        self.stop_time = stop_time;
        self
    }

    /// Checks the parameters; the error names the field and the constraint.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        if !(self.axis.is_finite() && self.axis.length_squared() > 0.0) {
            return Err(("axis", "must be a finite non-zero vector".into()));
        }
        if !(self.radius.is_finite() && self.radius > 0.0) {
            return Err(("radius", format!("must be > 0 m (got {})", self.radius)));
        }
        if !(self.volume_rate.is_finite() && self.volume_rate > 0.0) {
            return Err((
                "volume_rate",
                format!("must be > 0 m³/s (got {})", self.volume_rate),
            ));
        }
        if !(self.spacing.is_finite() && self.spacing > 0.0) {
            return Err(("spacing", format!("must be > 0 m (got {})", self.spacing)));
        }
        if self.temperature.is_some_and(|t| !t.is_finite()) {
            return Err(("temperature", "must be finite".into()));
        }
        if !(self.start_time.is_finite() && self.start_time >= 0.0) {
            return Err((
                "start_time",
                format!("must be ≥ 0 s (got {})", self.start_time),
            ));
        }
        if let Some(stop) = self.stop_time
            && !(stop.is_finite() && stop >= self.start_time)
        {
            return Err((
                "stop_time",
                format!("must be ≥ start_time = {} s (got {stop})", self.start_time),
            ));
        }
        if !(self.jitter.is_finite() && (0.0..=0.1).contains(&self.jitter)) {
            return Err((
                "jitter",
                format!("must lie in [0, 0.1] (got {})", self.jitter),
            ));
        }
        if !(self.bore.is_finite() && self.bore >= 0.0) {
            return Err(("bore", format!("must be ≥ 0 m (got {})", self.bore)));
        }
        if let Some(slot) = self.slot {
            let (d, e) = (slot.direction, self.axis.normalize_or_zero());
            if !d.is_finite() || (d - e * d.dot(e)).length() <= 1e-6 * d.length() {
                return Err((
                    "slot.direction",
                    format!(
                        "must be a finite vector not along the nozzle axis (got ({}, {}, {}))",
                        d.x, d.y, d.z
                    ),
                ));
            }
            if !(slot.length.is_finite() && slot.length >= 2.0 * self.spacing) {
                return Err((
                    "slot.length",
                    format!(
                        "must be ≥ 2 particle spacings = {} m (got {})",
                        2.0 * self.spacing,
                        slot.length
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The layer lattice S of this nozzle: [`disk_lattice`], or [`slot_lattice`] for a slot.
    pub fn lattice(&self) -> Vec<Vec3> {
        match self.slot {
            None => disk_lattice(self.axis, self.radius, self.spacing),
            Some(slot) => slot_lattice(
                self.axis,
                slot.direction,
                self.radius,
                slot.length,
                self.spacing,
            ),
        }
    }

    /// Extrusion speed v_e = Q̇/(N_layer h²) \[m/s\] for a lattice of `layer_size` points.
    pub fn extrusion_speed(&self, layer_size: usize) -> f64 {
        let h = self.spacing as f64;
        self.volume_rate / (layer_size.max(1) as f64 * h * h)
    }

    /// Extruding time during simulation time \[0, t\] \[s\] (path offset by `start_time`,
    /// cut at `stop_time`).
    pub fn extruding_time(&self, t: f64) -> f64 {
        let end = self.stop_time.map_or(t, |s| t.min(s));
        self.path.extruding_time(end - self.start_time)
    }

    /// Mass the emitter has to deposit by simulation time `t`: ρ₀Q̇ × extruding time \[kg\]
    /// (the emitted mass is within half a layer of it).
    pub fn expected_mass(&self, rest_density: f64, t: f64) -> f64 {
        rest_density * self.volume_rate * self.extruding_time(t)
    }
}

/// The frame a [`NozzleEmitter`]'s path, axis and velocities are given in: the world pose
/// and motion of its entity (identity by default: scene coordinates). `game` sets it from the
/// entity's `Transform` every frame, so that a nozzle follows its entity (a hose the player
/// moves) and emits along its rotated axis.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[cfg_attr(feature = "reflect", reflect(Component))]
pub struct EmitterFrame {
    /// Position of the frame's origin \[m\].
    pub translation: Vec3,
    /// Rotation frame → world.
    pub rotation: glam::Quat,
    /// Velocity of the frame's origin \[m/s\] (added to the emitted velocity).
    pub linear_velocity: Vec3,
    /// Angular velocity of the frame \[rad/s\] (world; adds ω × r to the emitted velocity).
    pub angular_velocity: Vec3,
}

impl Default for EmitterFrame {
    fn default() -> Self {
        Self {
            translation: Vec3::ZERO,
            rotation: glam::Quat::IDENTITY,
            linear_velocity: Vec3::ZERO,
            angular_velocity: Vec3::ZERO,
        }
    }
}

impl EmitterFrame {
    /// World position of the frame point `p`.
    pub fn point(&self, p: DVec3) -> DVec3 {
        self.translation.as_dvec3() + self.rotation.as_dquat() * p
    }

    /// World velocity of material moving at `v` (frame) at the frame point `p`.
    pub fn velocity(&self, p: DVec3, v: DVec3) -> DVec3 {
        let r = self.rotation.as_dquat() * p;
        self.rotation.as_dquat() * v
            + self.linear_velocity.as_dvec3()
            + self.angular_velocity.as_dvec3().cross(r)
    }
}

/// Run-time state of a [`NozzleEmitter`] (added automatically when the emitter is spawned).
#[derive(Component, Clone, Debug, Default)]
pub struct EmitterState {
    /// Extruded length s not yet emitted as a layer \[m\], in \[0, h_p) (h_p/2 at the start).
    pub pending: f64,
    /// Layers emitted so far.
    pub layers: u64,
    /// Particles emitted so far.
    pub particles: u64,
    /// Jitter generator (seeded from the emitter at its first step).
    rng: Option<SplitMix64>,
    /// Cached disk lattice (computed at the first step).
    lattice: Vec<Vec3>,
}

/// One particle to spawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Emission {
    /// Position \[m\].
    pub position: Vec3,
    /// Velocity \[m/s\].
    pub velocity: Vec3,
}

impl EmitterState {
    /// Points per emitted layer, once the first step has built the disk lattice.
    pub fn layer_size(&self) -> Option<usize> {
        (!self.lattice.is_empty()).then_some(self.lattice.len())
    }

    /// Advances the emitter over the step \[t0, t1\] (simulation times \[s\]) and appends the
    /// particles to emit to `out` (§4.4), placed in the world by `frame`. Pure: no ECS access;
    /// the caller spawns them.
    pub fn advance(
        &mut self,
        emitter: &NozzleEmitter,
        frame: &EmitterFrame,
        t0: f64,
        t1: f64,
        out: &mut Vec<Emission>,
    ) {
        if t1.partial_cmp(&t0) != Some(std::cmp::Ordering::Greater) || emitter.validate().is_err() {
            return;
        }
        let h = emitter.spacing as f64;
        if self.rng.is_none() {
            self.lattice = emitter.lattice();
            // Start half a layer full: the emitted mass is ρ₀Q̇t rounded to the nearest layer
            // (error ≤ ½ layer) instead of rounded down.
            self.pending = 0.5 * h;
        }
        let rng = self
            .rng
            .get_or_insert_with(|| SplitMix64::new(emitter.seed));
        let v_e = emitter.extrusion_speed(self.lattice.len());
        let extruded = emitter.extruding_time(t1) - emitter.extruding_time(t0);
        if extruded <= 0.0 {
            return;
        }
        self.pending += v_e * extruded;
        let e = emitter.axis.as_dvec3().normalize();
        let (x_s, v_s, _) = emitter.path.sample(t1 - emitter.start_time);
        let velocity = frame.velocity(x_s, e * v_e + v_s).as_vec3();
        let amp = emitter.jitter.clamp(0.0, 0.1) as f64 * h;
        // A guard against absurd inputs: at most 10⁶ layers per step.
        let mut budget = 1_000_000u32;
        while self.pending >= h && budget > 0 {
            budget -= 1;
            self.pending -= h;
            let centre = x_s + e * (self.pending - emitter.bore as f64);
            for s_k in &self.lattice {
                let mut p = centre + s_k.as_dvec3();
                if amp > 0.0 {
                    p += DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) * amp
                        - DVec3::splat(0.5 * amp);
                }
                out.push(Emission {
                    position: frame.point(p).as_vec3(),
                    velocity,
                });
            }
            self.layers += 1;
            self.particles += self.lattice.len() as u64;
        }
    }
}
