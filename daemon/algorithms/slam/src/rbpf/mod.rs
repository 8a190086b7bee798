//! The Rao-Blackwellised particle filter back-end (GMapping class, Grisetti
//! et al.): the filter, its odometry motion model, its per-particle scan
//! matcher and likelihood, and systematic resampling.

pub mod filter;
pub mod matcher;
pub mod motion;
pub mod resample;

pub use filter::{FilterStats, Particle, PathNode, Rbpf, RbpfParams};
