//! One particle output frame ([`ParticleFrame`]) and its validation.
//!
//! A frame is plain data in single precision (the simulation's `Real = f32`): positions,
//! velocities and any number of named per-particle scalar fields. [`ParticleFrame::validate`]
//! is the single gate every writer passes through before touching the file system, so a frame
//! with NaN/inf values, ragged arrays or unusable field names is never written.
use super::error::OutputError;
use crate::math::Vec3;

/// Property names the writers use for positions and velocities; fields may not reuse them.
pub const RESERVED_NAMES: [&str; 6] = ["x", "y", "z", "vx", "vy", "vz"];

/// Longest accepted field name, in bytes (legacy VTK readers use fixed 256-byte buffers).
pub const MAX_NAME_LEN: usize = 128;

const AXES: [&str; 3] = ["x", "y", "z"];

/// One output frame: per-particle positions, velocities and named scalar fields.
///
/// Invariants checked by [`validate`](Self::validate) (not by construction, the fields are
/// public): `velocities` and every field have `positions.len()` entries, every value and
/// `time` are finite, and field names are unique, non-reserved, non-empty, at most
/// [`MAX_NAME_LEN`] bytes of `[A-Za-z0-9_.-]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ParticleFrame {
    /// Output frame number (used in file names `frame_00042.*`).
    pub frame: u32,
    /// Simulation time of the frame.
    pub time: f64,
    /// Particle positions.
    pub positions: Vec<[f32; 3]>,
    /// Particle velocities, one per position.
    pub velocities: Vec<[f32; 3]>,
    /// Named per-particle scalars (e.g. `"density"`, `"pressure"`, `"material"`), written in
    /// this order.
    pub fields: Vec<(String, Vec<f32>)>,
}

impl ParticleFrame {
    /// An empty frame.
    pub fn new(frame: u32, time: f64) -> Self {
        Self {
            frame,
            time,
            ..Self::default()
        }
    }

    /// A frame from simulation vectors (no scalar fields yet).
    pub fn from_vec3(frame: u32, time: f64, positions: &[Vec3], velocities: &[Vec3]) -> Self {
        Self {
            frame,
            time,
            positions: positions.iter().map(|v| v.to_array()).collect(),
            velocities: velocities.iter().map(|v| v.to_array()).collect(),
            fields: Vec::new(),
        }
    }

    /// Append a scalar field (not checked until [`validate`](Self::validate)).
    pub fn push_field(&mut self, name: impl Into<String>, values: Vec<f32>) {
        self.fields.push((name.into(), values));
    }

    /// Builder form of [`push_field`](Self::push_field).
    pub fn with_field(mut self, name: impl Into<String>, values: Vec<f32>) -> Self {
        self.push_field(name, values);
        self
    }

    /// The values of the field called `name`, if present.
    pub fn field(&self, name: &str) -> Option<&[f32]> {
        self.fields
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }

    /// Number of particles (`positions.len()`).
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// `true` if the frame has no particles.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Check the invariants listed on [`ParticleFrame`]. The returned error has `path: None`;
    /// writers attach the path with [`OutputError::with_path`].
    ///
    /// Checks happen in this order: time, array lengths and names (velocities, then fields in
    /// order), then finiteness of positions, velocities and fields; the first non-finite value
    /// in that order is reported with its particle index.
    pub fn validate(&self) -> Result<(), OutputError> {
        if !self.time.is_finite() {
            return Err(OutputError::NonFiniteTime {
                path: None,
                value: self.time,
            });
        }
        let n = self.positions.len();
        check_len("velocities", n, self.velocities.len())?;
        for (k, (name, values)) in self.fields.iter().enumerate() {
            check_field_name(name)?;
            if self.fields[..k].iter().any(|(other, _)| other == name) {
                return Err(OutputError::InvalidFieldName {
                    path: None,
                    name: name.clone(),
                    reason: "duplicate field name",
                });
            }
            check_len(name, n, values.len())?;
        }
        check_vec3("position", &self.positions)?;
        check_vec3("velocity", &self.velocities)?;
        for (name, values) in &self.fields {
            if !all_finite(values) {
                let (index, &value) = values
                    .iter()
                    .enumerate()
                    .find(|(_, v)| !v.is_finite())
                    .expect("a non-finite value exists");
                return Err(OutputError::NonFinite {
                    path: None,
                    index,
                    quantity: name.clone(),
                    value,
                });
            }
        }
        Ok(())
    }
}

fn check_len(quantity: &str, expected: usize, found: usize) -> Result<(), OutputError> {
    if expected == found {
        Ok(())
    } else {
        Err(OutputError::LengthMismatch {
            path: None,
            quantity: quantity.to_owned(),
            expected,
            found,
        })
    }
}

/// Branch-free scan (vectorises); the slow search for the index only runs on failure.
#[inline]
fn all_finite(values: &[f32]) -> bool {
    values.iter().fold(true, |ok, v| ok & v.is_finite())
}

fn check_vec3(what: &str, values: &[[f32; 3]]) -> Result<(), OutputError> {
    if all_finite(values.as_flattened()) {
        return Ok(());
    }
    for (index, v) in values.iter().enumerate() {
        for (axis, &value) in v.iter().enumerate() {
            if !value.is_finite() {
                return Err(OutputError::NonFinite {
                    path: None,
                    index,
                    quantity: format!("{what}.{}", AXES[axis]),
                    value,
                });
            }
        }
    }
    unreachable!("a non-finite value exists")
}

/// `Some(reason)` if `name` is not a usable column/field token: it must be non-empty, at most
/// [`MAX_NAME_LEN`] bytes, and only contain `[A-Za-z0-9_.-]` (no whitespace for PLY/VTK
/// headers, no commas or quotes for CSV, no `%` which legacy VTK readers decode).
pub(crate) fn name_problem(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        Some("name is empty")
    } else if name.len() > MAX_NAME_LEN {
        Some("name is longer than 128 bytes")
    } else if !name
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'.' | b'-'))
    {
        Some("name may only contain ASCII letters, digits, '_', '.' and '-'")
    } else {
        None
    }
}

fn check_field_name(name: &str) -> Result<(), OutputError> {
    let reason = name_problem(name).or_else(|| {
        RESERVED_NAMES
            .contains(&name)
            .then_some("name is reserved for positions/velocities (x y z vx vy vz)")
    });
    match reason {
        None => Ok(()),
        Some(reason) => Err(OutputError::InvalidFieldName {
            path: None,
            name: name.to_owned(),
            reason,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(n: usize) -> ParticleFrame {
        ParticleFrame {
            frame: 1,
            time: 0.5,
            positions: vec![[1.0, 2.0, 3.0]; n],
            velocities: vec![[0.0; 3]; n],
            fields: vec![("density".into(), vec![1000.0; n])],
        }
    }

    #[test]
    fn valid_frame_passes() {
        frame(5).validate().unwrap();
        ParticleFrame::new(0, 0.0).validate().unwrap();
    }

    #[test]
    fn reports_first_non_finite_with_index_and_quantity() {
        let mut f = frame(5);
        f.velocities[3][1] = f32::NAN;
        f.fields[0].1[1] = f32::INFINITY;
        match f.validate().unwrap_err() {
            OutputError::NonFinite {
                index,
                quantity,
                value,
                path: None,
            } => {
                assert_eq!((index, quantity.as_str()), (3, "velocity.y"));
                assert!(value.is_nan());
            }
            e => panic!("unexpected {e}"),
        }
        f.velocities[3][1] = 0.0;
        let e = f.validate().unwrap_err();
        assert_eq!(
            e.to_string(),
            "non-finite density = inf at particle 1",
            "{e:?}"
        );
    }

    #[test]
    fn length_and_names() {
        let mut f = frame(3);
        f.fields[0].1.pop();
        assert!(matches!(
            f.validate(),
            Err(OutputError::LengthMismatch { ref quantity, expected: 3, found: 2, .. })
                if quantity == "density"
        ));
        for bad in ["", "vx", "a b", "a,b", "dens%20"] {
            let f = frame(1).with_field(bad, vec![0.0]);
            assert!(
                matches!(f.validate(), Err(OutputError::InvalidFieldName { .. })),
                "{bad:?}"
            );
        }
        let f = frame(1).with_field("density", vec![0.0]);
        assert!(matches!(
            f.validate(),
            Err(OutputError::InvalidFieldName {
                reason: "duplicate field name",
                ..
            })
        ));
        let mut f = frame(1);
        f.time = f64::NAN;
        assert!(matches!(
            f.validate(),
            Err(OutputError::NonFiniteTime { .. })
        ));
    }
}
