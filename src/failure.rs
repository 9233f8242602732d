//! Failure policy: numerical failure is detected, never written to a file, and reported with
//! the step, the particle, the quantity and a suggested time step.
use std::fmt;
use std::sync::Mutex;

use bevy_ecs::prelude::*;

use crate::math::Vec3;

/// What went wrong, where, and what to try.
#[derive(Clone, Debug, PartialEq)]
pub struct FailureReport {
    /// Step index (0-based) in which it was detected.
    pub step: u64,
    /// Simulated time at the start of that step \[s\].
    pub time: f64,
    /// Step size of that step \[s\].
    pub dt: f64,
    /// The particle, if one particle is to blame.
    pub entity: Option<Entity>,
    /// Its position, if known.
    pub position: Option<Vec3>,
    /// The quantity: "position", "velocity", "acceleration", "density", "time step", ...
    pub quantity: String,
    /// The offending value (NaN, ∞, or the out-of-range number).
    pub value: f64,
    /// Explanation.
    pub reason: String,
    /// A time step that should be stable from the last healthy state \[s\] (0 if unknown).
    pub suggested_dt: f64,
}

impl FailureReport {
    /// A failure not tied to one particle (configuration, time step); step, time and Δt are
    /// filled in by the monitor when it happens during a step.
    pub fn global(quantity: &str, value: f64, reason: impl Into<String>) -> Self {
        Self {
            step: 0,
            time: 0.0,
            dt: 0.0,
            entity: None,
            position: None,
            quantity: quantity.to_string(),
            value,
            reason: reason.into(),
            suggested_dt: 0.0,
        }
    }

    /// A per-particle failure; step, time and Δt are filled in by the monitor.
    pub fn particle(entity: Entity, quantity: &str, value: f64, reason: &str) -> Self {
        Self {
            step: 0,
            time: 0.0,
            dt: 0.0,
            entity: Some(entity),
            position: None,
            quantity: quantity.to_string(),
            value,
            reason: reason.to_string(),
            suggested_dt: 0.0,
        }
    }
}

impl fmt::Display for FailureReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "numerical failure at step {} (t = {:.6e} s, Δt = {:.3e} s): {} = {}",
            self.step, self.time, self.dt, self.quantity, self.value
        )?;
        if let Some(e) = self.entity {
            write!(f, " on particle {e}")?;
        }
        if let Some(p) = self.position {
            write!(f, " at ({:.4}, {:.4}, {:.4}) m", p.x, p.y, p.z)?;
        }
        write!(f, "; {}", self.reason)?;
        if self.suggested_dt > 0.0 {
            write!(
                f,
                ". Suggested fix: a time step of at most {:.3e} s (time_step: (mode: Fixed({:.3e})) or a smaller `safety`), or a smaller sound speed / viscosity",
                self.suggested_dt, self.suggested_dt
            )?;
        }
        Ok(())
    }
}

/// Collects failures found by parallel systems during a step; the monitor turns the first one
/// (lowest entity, so the report does not depend on thread timing) into the run's status.
#[derive(Resource, Default, Debug)]
pub struct FailureCollector(Mutex<Option<FailureReport>>);

impl FailureCollector {
    /// Records a failure (keeps the one with the lowest entity).
    pub fn record(&self, report: FailureReport) {
        let mut slot = self.0.lock().unwrap_or_else(|p| p.into_inner());
        let replace = match &*slot {
            None => true,
            Some(old) => match (old.entity, report.entity) {
                (Some(a), Some(b)) => b.to_bits() < a.to_bits(),
                (None, Some(_)) => false,
                _ => false,
            },
        };
        if replace {
            *slot = Some(report);
        }
    }

    /// Takes the recorded failure.
    pub fn take(&self) -> Option<FailureReport> {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).take()
    }
}

/// Whether the simulation is running or stopped by a failure. Once failed, no further step
/// runs (the state is kept as it was at the end of the failed step for inspection, and output
/// writers must not write it).
#[derive(Resource, Default, Debug, Clone)]
pub struct SimulationStatus {
    /// The failure that stopped the run.
    pub failure: Option<FailureReport>,
}

impl SimulationStatus {
    /// True once a failure was detected.
    pub fn failed(&self) -> bool {
        self.failure.is_some()
    }
}
