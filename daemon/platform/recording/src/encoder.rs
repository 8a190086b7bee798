//! Bus messages → the MCAP channels that represent them.
//!
//! One bus message becomes a [`Batch`]: its standard ROS 2 message, then the
//! `smokenav_msgs` companion that completes it (same MCAP sequence number,
//! written next in the same chunk), then any derived views (`/tf`, sonar
//! points). A batch is never split across chunks, so a file cut short still
//! holds complete pairs only.

use crate::codec::{self, SonarPoint, Transform2};
use crate::ros2;
use crate::schema::{self, MsgDef};
use smokenav_shared_types::catalog::ros2_topic_name;
use smokenav_shared_types::header::FRAME_ID_LEN;
use smokenav_shared_types::{AnyMessageRef, FixedStr, MessageKind, SonarRing, SonarStatus};
use std::collections::HashMap;

/// Suffix of the sonar ring's PointCloud2 view (`/base/sonar/points`).
pub const POINTS_SUFFIX: &str = "/points";
/// The transforms of odometry and SLAM poses.
pub const TF_TOPIC: &str = "/tf";
/// The robot profile's fixed transforms.
pub const TF_STATIC_TOPIC: &str = "/tf_static";

/// What a channel is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelRole {
    /// A standard ROS 2 message; with its companion it replays exactly.
    Standard,
    /// `smokenav_msgs`: what the standard message before it cannot carry.
    Companion,
    /// `smokenav_msgs`: the whole message (no standard type fits).
    Complete,
    /// Derived for viewers (`/tf`, `/tf_static`, sonar points); not replayed.
    View,
}

/// The QoS a ROS 2 publisher of this channel would offer (`offered_qos_profiles`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RosQos {
    /// reliable, volatile, keep last 10: accepted by sensor-data and default subscribers.
    Stream,
    /// reliable, transient local, keep last 1: `/tf_static` and maps (late joiners get the last).
    Latched,
}

impl RosQos {
    /// rosbag2's YAML with integer enums (readable by Humble and, by its
    /// auto-detection, every later rosbag2). Durations 0 = unspecified.
    pub fn yaml(self) -> String {
        let (depth, durability) = match self {
            RosQos::Stream => (10, 2), // VOLATILE
            RosQos::Latched => (1, 1), // TRANSIENT_LOCAL
        };
        let zero = "\n    sec: 0\n    nsec: 0";
        format!(
            "- history: 1\n  depth: {depth}\n  reliability: 1\n  durability: {durability}\n  \
             deadline:{zero}\n  lifespan:{zero}\n  liveliness: 1\n  \
             liveliness_lease_duration:{zero}\n  avoid_ros_namespace_conventions: false\n"
        )
    }
}

#[derive(Debug, Clone)]
pub struct ChannelSpec {
    /// ROS topic, `/` + the bus topic (+ a suffix for companions and views).
    pub topic: String,
    pub schema: &'static MsgDef,
    pub role: ChannelRole,
    pub qos: RosQos,
}

/// One encoded MCAP message of a batch.
#[derive(Debug, Default)]
pub struct Encoded {
    /// Index into [`Encoder::channels`].
    pub channel: usize,
    /// MCAP sequence: the smokenav `header.seq`, truncated to 32 bits.
    pub sequence: u32,
    pub log_time: u64,
    pub publish_time: u64,
    pub data: Vec<u8>,
}

/// The messages one bus message became. Reused: buffers keep their capacity.
#[derive(Debug, Default)]
pub struct Batch {
    /// Channels first used by this batch: (index, spec). The sink registers them.
    pub new_channels: Vec<(usize, ChannelSpec)>,
    items: Vec<Encoded>,
    used: usize,
}

impl Batch {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn clear(&mut self) {
        self.new_channels.clear();
        self.used = 0;
    }

    pub fn messages(&self) -> &[Encoded] {
        &self.items[..self.used]
    }

    pub fn is_empty(&self) -> bool {
        self.used == 0
    }

    /// Total payload bytes.
    pub fn bytes(&self) -> usize {
        self.messages().iter().map(|m| m.data.len()).sum()
    }

    /// Removes message `i` (tests build damaged files with it).
    #[cfg(test)]
    pub(crate) fn remove(&mut self, i: usize) {
        if i < self.used {
            let e = self.items.remove(i);
            self.items.push(e);
            self.used -= 1;
        }
    }

    fn slot(
        &mut self,
        channel: usize,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
    ) -> &mut Vec<u8> {
        if self.used == self.items.len() {
            self.items.push(Encoded::default());
        }
        let e = &mut self.items[self.used];
        self.used += 1;
        e.channel = channel;
        e.sequence = sequence;
        e.log_time = log_time;
        e.publish_time = publish_time;
        &mut e.data
    }
}

pub use smokenav_shared_types::Pose2;

/// Where the sensors sit on the robot (from the robot profile), for `/tf_static`
/// and the sonar points. Without it those views are not written.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RobotGeometry {
    pub laser_frame: String,
    pub laser: Pose2,
    /// (transducer index, pose on the base).
    pub sonars: Vec<(u8, Pose2)>,
}

impl RobotGeometry {
    /// The sensor poses of a robot profile.
    pub fn from_config(cfg: &smokenav_platform_config::RobotConfig) -> Self {
        RobotGeometry {
            laser_frame: cfg.laser.frame_id.clone(),
            laser: Pose2::new(
                cfg.laser.mount.x,
                cfg.laser.mount.y,
                cfg.laser.mount.yaw_rad(),
            ),
            sonars: cfg
                .sonar
                .transducers
                .iter()
                .map(|t| (t.index, Pose2::new(t.x, t.y, t.yaw_deg.to_radians())))
                .collect(),
        }
    }
}

/// The channels of one bus topic: the main one, its companion, a view.
#[derive(Debug, Clone, Copy)]
struct TopicChannels {
    main: usize,
    companion: Option<usize>,
    view: Option<usize>,
}

/// Turns bus messages into batches; owns the channel table.
#[derive(Debug, Default)]
pub struct Encoder {
    channels: Vec<ChannelSpec>,
    by_topic: HashMap<String, TopicChannels>,
    tf: Option<usize>,
    geometry: Option<RobotGeometry>,
    /// Latest odometry pose and its frame, for map → odom.
    last_odom: Option<(Pose2, FixedStr<FRAME_ID_LEN>)>,
    points: Vec<SonarPoint>,
    /// Added to bus (monotonic) times to make MCAP log and publish times; see
    /// [`Encoder::set_unix_offset`].
    unix_offset_ns: i64,
}

/// CLOCK_REALTIME − CLOCK_MONOTONIC now, ns: what turns a bus stamp into a
/// Unix time. Read several times, keeping the pair read closest together, so a
/// preemption between the two reads does not skew it.
pub fn unix_offset_now() -> i64 {
    let mut best: Option<(u64, i64)> = None;
    for _ in 0..5 {
        let m0 = smokenav_shared_types::clock::monotonic_now_ns();
        let unix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos() as i128)
            .unwrap_or(0);
        let m1 = smokenav_shared_types::clock::monotonic_now_ns();
        let spread = m1.saturating_sub(m0);
        let mid = (m0 as i128 + m1 as i128) / 2;
        let off = (unix - mid).clamp(i64::MIN as i128, i64::MAX as i128) as i64;
        if best.is_none_or(|(s, _)| spread < s) {
            best = Some((spread, off));
        }
    }
    best.map_or(0, |(_, o)| o)
}

/// `t + offset`, saturating at the ends of u64.
pub fn shift_ns(t: u64, offset: i64) -> u64 {
    (t as i128 + offset as i128).clamp(0, u64::MAX as i128) as u64
}

impl Encoder {
    pub fn new(geometry: Option<RobotGeometry>) -> Self {
        Self {
            geometry,
            ..Default::default()
        }
    }

    pub fn channels(&self) -> &[ChannelSpec] {
        &self.channels
    }

    fn add_channel(
        &mut self,
        batch: &mut Batch,
        topic: String,
        schema: &'static MsgDef,
        role: ChannelRole,
        qos: RosQos,
    ) -> usize {
        let i = self.channels.len();
        let spec = ChannelSpec {
            topic,
            schema,
            role,
            qos,
        };
        self.channels.push(spec.clone());
        batch.new_channels.push((i, spec));
        i
    }

    /// The channels of `topic` for messages of `kind`, created on first use.
    fn topic_channels(
        &mut self,
        batch: &mut Batch,
        topic: &str,
        kind: MessageKind,
    ) -> TopicChannels {
        if let Some(&c) = self.by_topic.get(topic) {
            return c;
        }
        let layout = ros2::layout(kind);
        let base = ros2_topic_name(topic);
        let qos = if layout.latched {
            RosQos::Latched
        } else {
            RosQos::Stream
        };
        let view = (kind == MessageKind::SonarRing && self.geometry.is_some())
            .then_some((POINTS_SUFFIX, &schema::POINT_CLOUD2));
        let main_role = if layout.companion.is_some() {
            ChannelRole::Standard
        } else {
            ChannelRole::Complete
        };
        let c = TopicChannels {
            main: self.add_channel(batch, base.clone(), layout.standard, main_role, qos),
            companion: layout.companion.map(|(sfx, def)| {
                self.add_channel(
                    batch,
                    format!("{base}{sfx}"),
                    def,
                    ChannelRole::Companion,
                    qos,
                )
            }),
            view: view.map(|(sfx, def)| {
                self.add_channel(batch, format!("{base}{sfx}"), def, ChannelRole::View, qos)
            }),
        };
        self.by_topic.insert(topic.to_owned(), c);
        c
    }

    fn tf_channel(&mut self, batch: &mut Batch) -> usize {
        match self.tf {
            Some(c) => c,
            None => {
                let c = self.add_channel(
                    batch,
                    TF_TOPIC.into(),
                    &schema::TF_MESSAGE,
                    ChannelRole::View,
                    RosQos::Stream,
                );
                self.tf = Some(c);
                c
            }
        }
    }

    /// Makes MCAP log and publish times `offset_ns` later than the bus times
    /// given (the recorder passes [`unix_offset_now`], so they are Unix
    /// times: real dates in Foxglove and `ros2 bag`). The messages' own header
    /// stamps stay on the bus's monotonic clock, so a replay is bit for bit.
    pub fn set_unix_offset(&mut self, offset_ns: i64) {
        self.unix_offset_ns = offset_ns;
    }

    fn wall(&self, t: u64) -> u64 {
        shift_ns(t, self.unix_offset_ns)
    }

    /// The `/tf_static` transforms of the robot profile (base → laser), if known.
    pub fn static_transforms(&mut self, log_time: u64, batch: &mut Batch) {
        if self.geometry.is_none() {
            return;
        }
        let ch = self.add_channel(
            batch,
            TF_STATIC_TOPIC.into(),
            &schema::TF_MESSAGE,
            ChannelRole::View,
            RosQos::Latched,
        );
        let Some(g) = &self.geometry else { return };
        let t = Transform2 {
            stamp_ns: log_time,
            parent: codec::BASE_FRAME,
            child: &g.laser_frame,
            x: g.laser.x,
            y: g.laser.y,
            yaw: g.laser.theta,
        };
        let wall = self.wall(log_time);
        codec::encode_tf_message(&[t], batch.slot(ch, 0, wall, wall));
    }

    /// Appends the channels for `msg`, published on bus topic `topic`, to `batch`.
    pub fn encode(&mut self, topic: &str, msg: AnyMessageRef, log_time: u64, batch: &mut Batch) {
        let ids = self.topic_channels(batch, topic, msg.kind());
        let h = msg.header();
        let (seq, stamp) = (h.seq as u32, h.stamp_ns);
        let (log_time, publish_time) = (self.wall(log_time), self.wall(stamp));
        ros2::encode_standard(msg, batch.slot(ids.main, seq, log_time, publish_time));
        if let Some(c) = ids.companion {
            ros2::encode_companion(msg, batch.slot(c, seq, log_time, publish_time));
        }
        match msg {
            AnyMessageRef::SonarRing(r) => {
                if let Some(v) = ids.view {
                    self.sonar_points(r);
                    codec::encode_sonar_points(
                        stamp,
                        &self.points,
                        batch.slot(v, seq, log_time, publish_time),
                    );
                }
            }
            AnyMessageRef::Odometry(o) => {
                let pose = Pose2::new(o.x, o.y, o.theta);
                self.last_odom = Some((pose, o.header.frame_id));
                let t = Transform2 {
                    stamp_ns: stamp,
                    parent: o.header.frame_id.as_str(),
                    child: codec::BASE_FRAME,
                    x: pose.x,
                    y: pose.y,
                    yaw: pose.theta,
                };
                let tf = self.tf_channel(batch);
                codec::encode_tf_message(&[t], batch.slot(tf, 0, log_time, publish_time));
            }
            AnyMessageRef::PoseEstimate(p) => {
                // map → odom needs the odometry the pose was estimated against;
                // the latest one is the best estimate the recorder has.
                if let Some((odom, odom_frame)) = self.last_odom {
                    let slam = Pose2::new(p.x, p.y, p.theta);
                    let mo = map_to_odom(slam, odom);
                    let t = Transform2 {
                        stamp_ns: stamp,
                        parent: p.header.frame_id.as_str(),
                        child: odom_frame.as_str(),
                        x: mo.x,
                        y: mo.y,
                        yaw: mo.theta,
                    };
                    let tf = self.tf_channel(batch);
                    codec::encode_tf_message(&[t], batch.slot(tf, 0, log_time, publish_time));
                }
            }
            _ => {}
        }
    }

    fn sonar_points(&mut self, ring: &SonarRing) {
        self.points.clear();
        let Some(g) = &self.geometry else { return };
        for r in ring.readings() {
            let pose = g
                .sonars
                .iter()
                .find(|(i, _)| *i == r.index)
                .map(|(_, p)| *p);
            let (x, y) = match (r.status(), pose) {
                (SonarStatus::Valid, Some(p)) => (
                    (p.x + f64::from(r.range) * p.theta.cos()) as f32,
                    (p.y + f64::from(r.range) * p.theta.sin()) as f32,
                ),
                _ => (f32::NAN, f32::NAN),
            };
            self.points.push(SonarPoint {
                x,
                y,
                range: r.range,
                index: r.index,
                status: r.status,
            });
        }
    }
}

/// map → odom such that map → odom → base equals the SLAM pose.
pub fn map_to_odom(map_base: Pose2, odom_base: Pose2) -> Pose2 {
    map_base.compose(&odom_base.inverse())
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::{LaserScan, Odometry};

    #[test]
    fn map_to_odom_composes_back_to_the_slam_pose() {
        let odom = Pose2::new(1.0, 2.0, 0.5);
        let slam = Pose2::new(-0.3, 4.0, 1.2);
        let mo = map_to_odom(slam, odom);
        let (s, c) = mo.theta.sin_cos();
        let x = mo.x + c * odom.x - s * odom.y;
        let y = mo.y + s * odom.x + c * odom.y;
        assert!((x - slam.x).abs() < 1e-12 && (y - slam.y).abs() < 1e-12);
        assert!((mo.theta + odom.theta - slam.theta).abs() < 1e-12);
    }

    #[test]
    fn the_unix_offset_moves_log_and_publish_times_not_the_message_stamp() {
        let offset = unix_offset_now();
        let unix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos() as i128;
        let mono = smokenav_shared_types::clock::monotonic_now_ns() as i128;
        assert!(
            (unix - mono - offset as i128).abs() < 50_000_000,
            "{offset}"
        );
        let mut enc = Encoder::new(None);
        enc.set_unix_offset(1_000);
        let mut batch = Batch::new();
        let scan = LaserScan {
            header: smokenav_shared_types::Header::new(5, 7, "laser"),
            ..Default::default()
        };
        enc.encode("laser/scan", AnyMessageRef::LaserScan(&scan), 9, &mut batch);
        let main = &batch.messages()[0];
        assert_eq!((main.log_time, main.publish_time), (1_009, 1_005));
        // The CDR header stamp (after the 4-byte encapsulation: sec, nanosec) stays 5 ns.
        assert_eq!(&main.data[4..12], &[0, 0, 0, 0, 5, 0, 0, 0]);
        assert_eq!(shift_ns(3, -10), 0);
        assert_eq!(shift_ns(u64::MAX, 1), u64::MAX);
    }

    #[test]
    fn scan_becomes_laser_scan_then_extras_with_the_same_sequence() {
        let mut enc = Encoder::new(None);
        let mut batch = Batch::new();
        let scan = LaserScan {
            header: smokenav_shared_types::Header::new(5, 0x1_0000_0007, "laser"),
            count: 3,
            ..Default::default()
        };
        enc.encode("laser/scan", AnyMessageRef::LaserScan(&scan), 9, &mut batch);
        let topics: Vec<&str> = batch
            .messages()
            .iter()
            .map(|m| enc.channels()[m.channel].topic.as_str())
            .collect();
        assert_eq!(topics, ["/laser/scan", "/laser/scan/extras"]);
        assert!(batch.messages().iter().all(|m| m.sequence == 7));
        assert_eq!(batch.new_channels.len(), 2);
        batch.clear();
        enc.encode(
            "laser/scan",
            AnyMessageRef::LaserScan(&scan),
            10,
            &mut batch,
        );
        assert!(batch.new_channels.is_empty(), "channels are announced once");
    }

    #[test]
    fn odometry_adds_odom_to_base_link_on_tf() {
        let mut enc = Encoder::new(None);
        let mut batch = Batch::new();
        let o = Odometry {
            header: smokenav_shared_types::Header::new(1, 0, "odom"),
            x: 1.0,
            ..Default::default()
        };
        enc.encode("base/odom", AnyMessageRef::Odometry(&o), 1, &mut batch);
        let last = batch.messages().last().unwrap();
        assert_eq!(enc.channels()[last.channel].topic, "/tf");
        assert_eq!(enc.channels()[last.channel].role, ChannelRole::View);
    }

    #[test]
    fn qos_yaml_is_rosbag2_integer_form() {
        let y = RosQos::Latched.yaml();
        assert!(y.starts_with("- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"));
        assert!(y.contains("avoid_ros_namespace_conventions: false"));
    }
}
