//! SLAM for smokenav: a Rao-Blackwellised particle filter of the GMapping
//! class (Grisetti et al.), as a pure library.
//!
//! The algorithm sits behind [`SlamBackend`] so other back-ends (graph SLAM,
//! voting over several SLAMs) can follow; the SLAM process and the offline
//! runner only call that trait. No I/O, no clock: time comes from the scans'
//! stamps, randomness from a seeded generator, so a run is reproducible.
//!
//! - [`filter::Rbpf`]: the particle filter (motion model, scan-matched
//!   proposal, likelihood weights, N_eff resampling, copy-on-write maps).
//! - [`frontend`]: odometry correction by branch-and-bound correlative
//!   matching against the last scans (bridges late or stalled odometry).
//! - [`carmen`]: reader for CARMEN logs (`FLASER`, `ROBOTLASER1`, `ODOM`).
//! - [`eval`]: trajectory comparison after the best rigid 2D alignment.
//! - [`offline`]: feeding a CARMEN log to a back-end; [`odom_buffer`]: pairing
//!   scans with odometry interpolated to their stamps (the SLAM process).
//!
//! On the MIT CSAIL log (1988 scans, 30 particles) the smoothed trajectory
//! lands about 0.1 m RMS from GMapping's corrected poses; `cargo bench -p
//! smokenav-slam --bench csail` prints the figures and
//! `cargo test --release -p smokenav-algorithms-slam --test csail -- --ignored` checks them.

pub mod carmen;
pub mod eval;
pub mod filter;
pub mod frontend;
pub mod graph;
pub mod grid;
pub mod matcher;
pub mod motion;
pub mod odom_buffer;
pub mod offline;
pub mod pose;
pub mod rng;
pub mod scan;

pub use filter::Rbpf;
pub use pose::Pose2;
pub use scan::{Beam, BeamKind, RangeScan};

use smokenav_platform_map::OccupancyGrid;

/// A pose with the stamp of the scan it belongs to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    pub stamp_ns: u64,
    pub pose: Pose2,
}

/// What a back-end reports after each scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlamUpdate {
    /// Stamp of the scan.
    pub stamp_ns: u64,
    /// Best estimate of the robot pose in the map frame.
    pub pose: Pose2,
    /// Row-major covariance of (x, y, θ) over the particles.
    pub covariance: [f64; 9],
    /// Effective sample size after the update.
    pub n_eff: f64,
    pub particles: usize,
    /// False when the scan only moved the particles (below the update thresholds).
    pub processed: bool,
    pub resampled: bool,
}

/// A SLAM algorithm: scans and odometry in, poses and a map out.
pub trait SlamBackend {
    /// Processes one scan; `odom` is the odometry pose of the robot at the scan's stamp.
    fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate;
    /// The current best pose, once a scan was processed.
    fn pose(&self) -> Option<Pose2>;
    /// The current best map, once a scan was processed.
    fn map(&self) -> Option<OccupancyGrid>;
    /// The best estimate of the whole trajectory so far (smoothed where the
    /// back-end can; empty if it keeps no history).
    fn trajectory(&self) -> Vec<StampedPose>;
}
