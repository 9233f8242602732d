//! The integration tests, one module per subject, linked into one binary (one link instead
//! of one per file). `common` holds the helpers several modules share.

#[cfg(feature = "avian")]
mod avian;
mod behaviour;
mod citations;
mod cli;
mod collisions;
mod common;
mod custom_rheology;
mod dam_break;
mod distributed;
mod emitter;
mod energy_monitor;
mod faults;
mod fuzz;
#[cfg(feature = "game")]
mod game;
mod gs4;
mod heat;
mod integrators;
mod kernels;
mod layers;
mod mesh_collider;
mod meshes;
mod mpm;
mod output;
mod phase_change;
mod plugin_order;
mod poiseuille;
mod pressure;
#[cfg(feature = "reflect")]
mod reflect;
mod report;
mod rheology;
mod rheology_app;
mod rheology_ep;
mod rheology_li;
mod rheology_neo_hookean;
mod rigid;
mod scene;
mod scenes_run;
mod slip_mirror;
mod snapshot;
mod stefan;
#[cfg(feature = "surface")]
mod surface;
mod transfer;
