//! Ground truth: the true pose on the bus (topic [`TRUTH_TOPIC`]) and in files.
//!
//! On the bus the true pose is a `PoseEstimate` (no new message type): frame
//! [`TRUTH_FRAME`], the world's coordinates (those of the true map), stamped
//! in host monotonic time like every driver message, so it lines up with the
//! scans and with `slam/pose`; covariance zero, `particles` 0.

use smokenav_platform_bus::{Bus, BusError, Publisher};
use smokenav_shared_types::{Header, PoseEstimate};
use smokenav_sim_world::{Pose2, SimError, TruthSample};
use std::path::Path;

/// The bus topic of the true pose.
pub const TRUTH_TOPIC: &str = "sim/truth";
/// Frame of the true pose: the world (the true map's frame).
pub const TRUTH_FRAME: &str = "world";

/// The bus message for a true pose at host time `stamp_ns`.
pub fn truth_message(pose: &Pose2, stamp_ns: u64) -> PoseEstimate {
    PoseEstimate {
        header: Header::new(stamp_ns, 0, TRUTH_FRAME),
        x: pose.x,
        y: pose.y,
        theta: pose.theta,
        ..Default::default()
    }
}

/// Publishes true poses on [`TRUTH_TOPIC`].
pub struct TruthPublisher {
    publisher: Publisher<PoseEstimate>,
}

impl TruthPublisher {
    pub fn new(bus: &Bus) -> Result<Self, BusError> {
        Ok(Self {
            publisher: bus.publisher(smokenav_platform_bus::Topic::new(TRUTH_TOPIC))?,
        })
    }

    pub fn publish(&mut self, sample: &TruthSample, stamp_ns: u64) -> Result<(), BusError> {
        self.publisher
            .publish(&truth_message(&sample.pose, stamp_ns))
            .map(|_| ())
    }
}

/// The true trajectory with host-time stamps.
#[derive(Debug, Clone, Default)]
pub struct TruthTrack {
    samples: Vec<TruthSample>,
}

impl TruthTrack {
    /// Appends the pose at host time `stamp_ns`.
    pub fn push(&mut self, stamp_ns: u64, pose: Pose2, smoke_gpm3: f64) {
        self.samples.push(TruthSample {
            t_ns: stamp_ns,
            pose,
            smoke_gpm3,
        });
    }

    /// Samples stamped in host time.
    pub fn samples(&self) -> &[TruthSample] {
        &self.samples
    }

    pub fn last_sample(&self) -> Option<TruthSample> {
        self.samples.last().copied()
    }

    pub fn len(&self) -> usize {
        self.samples.len()
    }

    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// `timestamp x y theta` lines (what `smokenav eval` reads).
    pub fn write(&self, path: &Path) -> Result<(), SimError> {
        smokenav_sim_world::truth::write_trajectory(
            path,
            self.samples.iter().map(|s| (s.t_ns, &s.pose)),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truth_message_is_a_pose_in_the_world_frame_without_uncertainty() {
        let m = truth_message(&Pose2::new(1.5, -2.0, 0.25), 42);
        assert_eq!(m.header.frame_id.as_str(), "world");
        assert_eq!(
            (m.header.stamp_ns, m.x, m.y, m.theta),
            (42, 1.5, -2.0, 0.25)
        );
        assert_eq!(m.covariance, [0.0; 9]);
        assert_eq!(m.particles, 0);
    }

    #[test]
    fn the_track_writes_timestamp_x_y_theta_lines() {
        let dir = tempfile::tempdir().unwrap();
        let mut t = TruthTrack::default();
        t.push(1_500_000_000, Pose2::new(1.0, 2.0, 0.5), 0.0);
        t.push(1_600_000_000, Pose2::new(1.1, 2.0, 0.5), 0.1);
        let p = dir.path().join("t.txt");
        t.write(&p).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(
            text.contains("1.500000 1.000000 2.000000 0.500000"),
            "{text}"
        );
        assert_eq!(text.lines().filter(|l| !l.starts_with('#')).count(), 2);
    }
}
