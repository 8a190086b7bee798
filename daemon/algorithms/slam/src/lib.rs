//! SLAM for smokenav, as a pure library: one pipeline over pluggable back-ends.
//!
//! [`pipeline::SlamPipeline`] is what every caller runs — the SLAM process,
//! `smokenav slam` over CARMEN logs and the demo's offline comparison — so a
//! replay does what the robot did. It owns everything around the algorithm:
//! odometry pairing and resets ([`odom_buffer`]), scan conversion
//! ([`scan`]), the smoke → laser noise model ([`noise`]), the correlative
//! front end ([`frontend`]) and the update gate ([`motion_filter`]); the
//! algorithm sits behind [`backend::SlamBackend`]. No I/O, no clock: time is
//! passed in, randomness comes from a seeded generator, so a run is reproducible.
//!
//! Back-ends, one folder each: [`rbpf`], the Rao-Blackwellised particle filter
//! of the GMapping class (Grisetti et al.); [`fuzzy`], fuzzy confidence maps
//! registered by Cuckoo search (Hou et al. 2014); [`vote`], a per-cell vote
//! over the maps of several back-ends on their own threads (SLAMfusion).
//!
//! Shared pieces: [`grid`] (tiled copy-on-write occupancy grid), [`carmen`]
//! (reader for CARMEN logs: `FLASER`, `ROBOTLASER1`, `ODOM`), [`offline`]
//! (feeding a log or a recording through the pipeline). Trajectory accuracy
//! is `smokenav-algorithms-eval`'s.
//!
//! On the MIT CSAIL log (1988 scans, 30 particles) the smoothed trajectory
//! lands about 0.09 m RMS from GMapping's corrected poses; `cargo bench -p
//! smokenav-algorithms-slam --bench csail` prints the figures and
//! `cargo test --release -p smokenav-algorithms-slam --test csail -- --ignored` checks them.

pub mod backend;
pub mod carmen;
pub mod degeneracy;
pub mod drift;
pub mod frontend;
pub mod fuzzy;
pub mod graph;
pub mod grid;
pub mod motion_filter;
pub mod noise;
pub mod odom_buffer;
pub mod offline;
pub mod pipeline;
pub mod projected;
pub mod rbpf;
pub mod scan;
pub mod side_wall;
pub mod sonar_age;
#[cfg(test)]
mod testkit;
pub mod vote;

pub use backend::{
    BackendOptions, ExportJob, MapJob, RelocalizeError, SlamBackend, SlamUpdate, StampedPose,
};
pub use pipeline::SlamPipeline;
pub use rbpf::Rbpf;
pub use scan::{Beam, BeamKind, RangeScan};
pub use smokenav_shared_types::Pose2;
