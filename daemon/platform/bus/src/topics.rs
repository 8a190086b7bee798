//! Topic names and their quality of service.
//!
//! Names users and scripts rely on; keep them stable.

pub const LASER_SCAN: &str = "laser/scan";
pub const BASE_ODOM: &str = "base/odom";
pub const BASE_SONAR: &str = "base/sonar";
pub const BASE_CMD_VEL: &str = "base/cmd_vel";
pub const SMOKE_LEVEL: &str = "smoke/level";
pub const FUSION_SCAN: &str = "fusion/scan";
pub const SLAM_POSE: &str = "slam/pose";
pub const SLAM_MAP: &str = "slam/map";
/// Prefix of the per-process health topics, `health/<role>`.
pub const HEALTH_PREFIX: &str = "health/";

/// The process roles; each has a `health/<role>` topic.
pub const ROLES: &[&str] = &["hokuyo", "pioneer", "scout", "smoke", "fusion", "slam"];

pub fn health(role: &str) -> String {
    format!("{HEALTH_PREFIX}{role}")
}

/// Every fixed topic with the message type it carries.
pub const FIXED_TOPICS: &[(&str, &str)] = &[
    (LASER_SCAN, "LaserScan"),
    (BASE_ODOM, "Odometry"),
    (BASE_SONAR, "SonarRing"),
    (BASE_CMD_VEL, "VelocityCommand"),
    (SMOKE_LEVEL, "SmokeReading"),
    (FUSION_SCAN, "FusedScan"),
    (SLAM_POSE, "PoseEstimate"),
    (SLAM_MAP, "MapInfo"),
];

/// The message type name carried by a topic, `None` for topics we do not know.
pub fn type_of(topic: &str) -> Option<&'static str> {
    if topic.starts_with(HEALTH_PREFIX) {
        return Some("Health");
    }
    FIXED_TOPICS
        .iter()
        .find(|(t, _)| *t == topic)
        .map(|(_, ty)| *ty)
}

/// Quality of service of one topic. Every process derives it from this table,
/// so whichever process creates a service, the others can open it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Samples a late-joining subscriber receives on connect.
    pub history: usize,
    /// Samples queued per subscriber; when full, the oldest is overwritten
    /// (publishers never block on a slow or dead subscriber) and the
    /// subscriber sees a gap in sequence numbers.
    pub buffer: usize,
    /// Publishers allowed at once (drivers, `smokenav play`, `smokenav drive`, taps).
    pub max_publishers: usize,
    /// Subscribers allowed at once (consumers, `topic echo/hz`, `record`, `status`).
    pub max_subscribers: usize,
}

/// Default for sensor streams: a second of 10 Hz data absorbs a descheduled consumer.
const SENSOR: Qos = Qos {
    history: 1,
    buffer: 32,
    max_publishers: 4,
    max_subscribers: 16,
};

pub fn qos(topic: &str) -> Qos {
    match topic {
        // Several sources may command the base (controller, `smokenav drive`, replay).
        BASE_CMD_VEL => Qos {
            history: 0,
            buffer: 16,
            max_publishers: 8,
            max_subscribers: 8,
        },
        // Maps are large and only the newest matters.
        SLAM_MAP => Qos {
            history: 1,
            buffer: 2,
            max_publishers: 2,
            max_subscribers: 6,
        },
        t if t.starts_with(HEALTH_PREFIX) => Qos {
            history: 1,
            buffer: 4,
            max_publishers: 2,
            max_subscribers: 8,
        },
        // Bus self-tests and benchmarks use `test/...` topics.
        t if t.starts_with("test/") => Qos {
            history: 0,
            buffer: 64,
            max_publishers: 4,
            max_subscribers: 4,
        },
        _ => SENSOR,
    }
}
