//! `[zenoh]`: the link off the robot (`smokenav-zenoh`), on rmw_zenoh's key
//! expressions so ROS 2 nodes using rmw_zenoh see the robot's topics.
//!
//! Off the robot only what is asked for: the process has its own unit, not
//! enabled by default; multicast scouting is off (a robot must not announce
//! itself on every interface); the default endpoints are loopback only, as
//! rmw_zenoh's own session (listen on `tcp/127.0.0.1:0`, connect to a router
//! on `tcp/127.0.0.1:7447`). Input from outside (`cmd_vel`, `initialpose`)
//! is opt-in.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};
use smokenav_shared_types::catalog;

/// The Zenoh session's role.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ZenohMode {
    /// Listens and connects; talks directly to other peers (rmw_zenoh's default).
    #[default]
    Peer,
    /// Only connects, to a router; everything goes through it.
    Client,
}

impl ZenohMode {
    /// Zenoh's own spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            ZenohMode::Peer => "peer",
            ZenohMode::Client => "client",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZenohSection {
    #[serde(default)]
    pub mode: ZenohMode,
    /// Endpoints to listen on (peer mode), `tcp/ADDR:PORT`.
    #[serde(default = "default_listen")]
    pub listen: Vec<String>,
    /// Endpoints to connect to (a router or other peers), `tcp/ADDR:PORT`.
    #[serde(default = "default_connect")]
    pub connect: Vec<String>,
    /// UDP multicast scouting: announces the robot on every interface.
    #[serde(default)]
    pub multicast_scouting: bool,
    /// `ROS_DOMAIN_ID`: the first chunk of every key (0..=232, as ROS 2).
    #[serde(default)]
    pub domain_id: u32,
    /// The robot's ROS namespace (`/robot1`), before every topic: one per
    /// robot, so several robots share one Zenoh network. Empty: none.
    #[serde(default)]
    pub namespace: String,
    /// Bus topics that go out (`laser/scan`, `health/slam`); empty: every
    /// catalog topic and every process's health.
    #[serde(default)]
    pub topics: Vec<String>,
    /// Subscribe to `<namespace>/cmd_vel` (geometry_msgs/Twist) from outside
    /// and publish it on `base/cmd_vel`, where the base driver's command
    /// timeout stops the robot when it goes quiet.
    #[serde(default)]
    pub cmd_vel: bool,
    /// Subscribe to `<namespace>/initialpose`
    /// (geometry_msgs/PoseWithCovarianceStamped: RViz's "2D Pose Estimate")
    /// and publish it on `slam/initial_pose`, where a localising SLAM
    /// searches around it. Off: nobody off the robot moves its estimate.
    #[serde(default)]
    pub initial_pose: bool,
}

fn default_listen() -> Vec<String> {
    vec!["tcp/127.0.0.1:0".into()]
}

fn default_connect() -> Vec<String> {
    vec!["tcp/127.0.0.1:7447".into()]
}

impl Default for ZenohSection {
    fn default() -> Self {
        Self {
            mode: ZenohMode::default(),
            listen: default_listen(),
            connect: default_connect(),
            multicast_scouting: false,
            domain_id: 0,
            namespace: String::new(),
            topics: Vec::new(),
            cmd_vel: false,
            initial_pose: false,
        }
    }
}

/// Why `endpoint` is not a `tcp/HOST:PORT` locator (only TCP is built in).
pub fn endpoint_problem(endpoint: &str) -> Option<String> {
    let Some(rest) = endpoint.strip_prefix("tcp/") else {
        return Some(format!(
            "`{endpoint}`: only tcp/HOST:PORT endpoints (the bridge is built with the TCP transport only)"
        ));
    };
    let (host, port) = match rest.rsplit_once(':') {
        Some(hp) => hp,
        None => return Some(format!("`{endpoint}`: no port (tcp/HOST:PORT)")),
    };
    if host.is_empty() || port.parse::<u16>().is_err() {
        return Some(format!(
            "`{endpoint}`: expected tcp/HOST:PORT with a port 0..65535"
        ));
    }
    None
}

/// Why `ns` is no ROS namespace: empty, or `/name(/name)*` of `[A-Za-z0-9_]`.
pub fn namespace_problem(ns: &str) -> Option<String> {
    if ns.is_empty() {
        return None;
    }
    let ok = ns.starts_with('/')
        && ns[1..].split('/').all(|c| {
            !c.is_empty()
                && !c.starts_with(|ch: char| ch.is_ascii_digit())
                && c.chars().all(|ch| ch.is_ascii_alphanumeric() || ch == '_')
        });
    (!ok).then(|| {
        format!(
            "`{ns}`: a ROS namespace is `/name` or `/a/b` (letters, digits, `_`; no digit first)"
        )
    })
}

impl Validate for ZenohSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        for e in self.listen.iter().chain(&self.connect) {
            if let Some(p) = endpoint_problem(e) {
                let which = if self.listen.contains(e) {
                    "listen"
                } else {
                    "connect"
                };
                v.fail(k(which), p);
            }
        }
        if self.mode == ZenohMode::Client && self.connect.is_empty() {
            v.fail(
                k("connect"),
                "client mode needs at least one endpoint to connect to",
            );
        }
        if self.domain_id > 232 {
            v.fail(
                k("domain_id"),
                format!("must be within [0, 232], got {}", self.domain_id),
            );
        }
        if let Some(p) = namespace_problem(&self.namespace) {
            v.fail(k("namespace"), p);
        }
        for t in &self.topics {
            if catalog::topic_kind(t).is_none() {
                v.fail(k("topics"), format!("`{t}` is not a catalog topic"));
            }
        }
    }
}
