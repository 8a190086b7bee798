//! Taps: smokenav bus messages to MCAP files that Foxglove and `ros2 bag`
//! open, and back, bit for bit.
//!
//! A recording is an MCAP file in the `ros2` profile: every channel is CDR
//! (little-endian, hand-written in [`cdr`]) with a `ros2msg` schema
//! ([`schema`]) and `offered_qos_profiles`; the file ends with a summary
//! holding Statistics. Each bus message maps to a standard ROS 2 message
//! where one exists, and to a `smokenav_msgs` message for what the standard
//! one cannot carry, so [`Playback`] reproduces the original exactly.
//! The message catalog (`smokenav_shared_types::catalog`) names each
//! type's ROS 2 type and companion; [`ros2`] resolves them to schemas and
//! holds the CDR of each, for the recorder here and for live bridges alike.
//!
//! | bus topic (type)             | MCAP channel              | schema                              | role       |
//! |------------------------------|---------------------------|-------------------------------------|------------|
//! | `laser/scan` (LaserScan)     | `/laser/scan`             | `sensor_msgs/msg/LaserScan`         | standard   |
//! |                              | `/laser/scan/extras`      | `smokenav_msgs/msg/ScanExtras`      | companion  |
//! | `fusion/scan` (FusedScan)    | `/fusion/scan`            | `sensor_msgs/msg/LaserScan`         | standard   |
//! |                              | `/fusion/scan/decisions`  | `smokenav_msgs/msg/FusedDecisions`  | companion  |
//! | `base/odom` (Odometry)       | `/base/odom`              | `nav_msgs/msg/Odometry`             | standard   |
//! |                              | `/base/odom/extras`       | `smokenav_msgs/msg/OdometryExtras`  | companion  |
//! | `base/sonar` (SonarRing)     | `/base/sonar`             | `smokenav_msgs/msg/SonarRing`       | complete   |
//! |                              | `/base/sonar/points`      | `sensor_msgs/msg/PointCloud2`       | view¹      |
//! | `base/cmd_vel` (VelocityCmd) | `/base/cmd_vel`           | `geometry_msgs/msg/TwistStamped`    | standard   |
//! |                              | `/base/cmd_vel/extras`    | `smokenav_msgs/msg/StampSeq`        | companion  |
//! | `smoke/level` (SmokeReading) | `/smoke/level`            | `smokenav_msgs/msg/SmokeReading`    | complete   |
//! | `clock` (SimClock)           | `/clock`                  | `rosgraph_msgs/msg/Clock`           | standard   |
//! |                              | `/clock/extras`           | `smokenav_msgs/msg/StampSeq`        | companion  |
//! | `slam/pose` (PoseEstimate)   | `/slam/pose`              | `geometry_msgs/msg/PoseStamped`     | standard   |
//! |                              | `/slam/pose/extras`       | `smokenav_msgs/msg/PoseExtras`      | companion  |
//! | `slam/map` (MapInfo + cells) | `/slam/map`               | `nav_msgs/msg/OccupancyGrid`        | standard   |
//! |                              | `/slam/map/extras`        | `smokenav_msgs/msg/MapExtras`       | companion  |
//! | `health/<role>` (Health)     | `/health/<role>`          | `smokenav_msgs/msg/Health`          | complete   |
//! | (odometry, SLAM pose)        | `/tf`                     | `tf2_msgs/msg/TFMessage`            | view       |
//! | (robot profile)              | `/tf_static`              | `tf2_msgs/msg/TFMessage`            | view¹      |
//!
//! ¹ only when the recorder knows the robot profile (sensor mounting poses).
//!
//! What the companions carry (standard messages cannot): the exact `u64`
//! stamp (`builtin_interfaces/Time` has an `int32` second) and the bus
//! sequence number; for scans, `beam_error` per beam (REP 117 ranges show
//! +inf for "no return" and "beyond max" alike and NaN for every sensor error
//! code), the original range value of each such beam, and the intensities
//! flag; for fused scans, the per-beam source and per-section decisions; for
//! odometry the exact heading (a quaternion round trip is not bit-exact),
//! flags, bumpers and battery; for poses the heading, 3×3 covariance,
//! particle statistics and timing; for maps the exact origin heading.
//! A companion is written right after its standard message, with the same
//! MCAP sequence number, in the same chunk.
//!
//! Sonar is `smokenav_msgs/SonarRing` plus a `PointCloud2` view rather than
//! `sensor_msgs/Range`: Range gained a `variance` field in Jazzy, so one
//! Range payload cannot match both Humble and Jazzy subscribers, whereas
//! PointCloud2 is the same in every ROS 2 distribution and Foxglove's 3D
//! panel draws it next to the laser scan (points in `base_link`; NaN for
//! readings without an echo; `range`, `index`, `status` as extra fields).
//!
//! Reproduced exactly: every field of every message, unused capacity
//! (beams past `count`, readings past `count`, …) and reserved bytes as
//! their defaults — what `publish_with` gives every publisher. A publisher
//! that leaves other values in unused capacity or reserved fields gets the
//! defaults back. `has_intensities` is replayed as 0 or 1.

/// ROS 2 bags in (rosbag2 folders, `.mcap`, `.db3`): see [`bag`].
pub mod bag;
pub mod bag_decode;
pub mod bag_sonar;
pub mod cdr;
pub mod codec;
pub mod encoder;
pub mod info;
pub mod initial_pose;
pub mod reader;
pub mod ros2;
pub mod schema;
pub mod writer;

pub use encoder::{
    Batch, ChannelRole, ChannelSpec, Encoder, Pose2, RobotGeometry, shift_ns, unix_offset_now,
};
pub use reader::{EndOfData, McapSource, Playback, PlaybackStats, Played, ReadError};
pub use ros2::{Ros2Codec, Ros2Layout};
pub use smokenav_shared_types::{AnyMessage, AnyMessageRef, BitIdentical};
pub use writer::{Compression, McapSink, SinkOptions, SinkStats, WriteError};

use std::collections::BTreeMap;
use std::io::{Seek, Write};

/// Key of the [`writer::METADATA_NAME`] metadata record holding the offset,
/// ns, that was added to the bus's monotonic times to make the file's log and
/// publish times Unix times. Absent in older recordings (offset 0).
pub const UNIX_OFFSET_KEY: &str = "unix_offset_ns";

/// The offset of [`UNIX_OFFSET_KEY`] in a file's metadata records (0 if absent).
pub fn unix_offset(metadata: &[(String, BTreeMap<String, String>)]) -> i64 {
    metadata
        .iter()
        .filter(|(name, _)| name == writer::METADATA_NAME)
        .find_map(|(_, m)| m.get(UNIX_OFFSET_KEY)?.parse().ok())
        .unwrap_or(0)
}

/// Encoder and sink together, for single-threaded recording.
pub struct Recorder<W: Write + Seek> {
    encoder: Encoder,
    sink: McapSink<W>,
    batch: Batch,
}

impl<W: Write + Seek> Recorder<W> {
    /// Starts a recording; writes `/tf_static` when `geometry` is known.
    pub fn create(
        w: W,
        opts: SinkOptions,
        geometry: Option<RobotGeometry>,
        metadata: &BTreeMap<String, String>,
        now_ns: u64,
    ) -> Result<Self, WriteError> {
        let mut r = Self {
            encoder: Encoder::new(geometry),
            sink: McapSink::create(w, opts, metadata)?,
            batch: Batch::new(),
        };
        r.encoder.static_transforms(now_ns, &mut r.batch);
        if !r.batch.is_empty() || !r.batch.new_channels.is_empty() {
            r.sink.write_batch(&r.batch, now_ns)?;
        }
        Ok(r)
    }

    /// Records one bus message received at `log_time` (ns).
    pub fn record(
        &mut self,
        topic: &str,
        msg: AnyMessageRef,
        log_time: u64,
    ) -> Result<(), WriteError> {
        self.batch.clear();
        self.encoder.encode(topic, msg, log_time, &mut self.batch);
        self.sink.write_batch(&self.batch, log_time)
    }

    /// Closes the open chunk if it is old; see [`McapSink::tick`].
    pub fn tick(&mut self, now_ns: u64) -> Result<bool, WriteError> {
        self.sink.tick(now_ns)
    }

    pub fn commit(&mut self) -> Result<(), WriteError> {
        self.sink.commit()
    }

    pub fn stats(&self) -> SinkStats {
        self.sink.stats()
    }

    pub fn finish(
        self,
        stats_metadata: Option<BTreeMap<String, String>>,
    ) -> Result<(W, SinkStats), WriteError> {
        self.sink.finish(stats_metadata)
    }
}

#[cfg(test)]
mod tests;
