//! The step of the explicit GS4-MPM (ALGORITHM §2.3): the schedule and its sets
//! ([`schedule`]), the frame driver and the core systems' registration ([`driver`]), how much
//! time one update advances and within what budget ([`pacing`]), and one file per stage. Nothing here names a plugin: plugins hook into the sub-sets of
//! [`schedule`].
//!
//! | set ([`MpmSystems`](crate::step::schedule::MpmSystems)) | file | section |
//! |---|---|---|
//! | `Predict` | [`predict`] | §2.4 (S1) |
//! | `ParticleToGrid` | [`p2g`] | §2.5 (S2–S3) |
//! | `Kinematics` | [`kinematics`] | §2.3 S4 |
//! | `Constitutive` | [`constitutive`] | §2.6–2.7 (S5–S10) |
//! | `GridForces` | [`grid_forces`] | §2.9 (S11) |
//! | `GridUpdate` | [`grid_update`] | §2.9–2.11 (S11) |
//! | `Thermal` | — (heat plugin) | §3 (S12) |
//! | `GridToParticle` | [`g2p`] | §2.12–2.13 (S13–S14) |
//! | `Commit` | [`commit`] | §2.6, §2.11 (S15) |
//! | `Emit` | — (emitter plugins) | §4.4 (S16) |
//! | `Monitor` | [`monitor`] | §2.15, failure policy |
//!
//! Other schemes ([`Scheme`](crate::config::Scheme)) replace stages through run conditions:
//! [`symplectic_euler`] (first-order grid update and G2P), [`crate::step::implicit`] (implicit
//! viscous grid update).
pub mod commit;
pub mod constitutive;
pub mod driver;
pub mod energy;
pub mod g2p;
pub mod grid_forces;
pub mod grid_update;
pub mod implicit;
pub mod kinematics;
pub mod monitor;
pub mod p2g;
pub mod pacing;
pub mod predict;
pub mod schedule;
pub mod symplectic_euler;
