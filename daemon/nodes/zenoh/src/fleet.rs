//! The operator's side: several robots' health and pose over Zenoh.
//!
//! Each robot's bridge declares an rmw_zenoh node token under its
//! namespace; while the token lives the robot is reachable (Zenoh removes
//! it the moment the bridge's session ends, or when its link's lease
//! expires), and its `health/*` and `slam/pose` samples say how it is.
//! Everything arrives through one bounded queue; when it is full, samples
//! are dropped and counted, never queued without bound.

use crate::bridge::{BridgeError, open_session, session_config};
use crate::keys::{self, NODE_NAME};
use crate::rihs;
use smokenav_platform_recording::{AnyMessage, ros2, schema};
use smokenav_shared_types::{Health, MessageKind, PoseEstimate};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::time::{Duration, Instant};
use zenoh::Wait;
use zenoh::sample::{Sample, SampleKind};

/// Samples waiting for [`Fleet::poll`]; more are dropped (and counted).
const QUEUE: usize = 1024;

enum Event {
    Token {
        namespace: String,
        alive: bool,
    },
    Health {
        namespace: String,
        health: Box<Health>,
    },
    Pose {
        namespace: String,
        pose: PoseEstimate,
    },
    Undecodable,
}

/// What the operator knows about one robot.
#[derive(Debug, Clone, Default)]
pub struct RobotView {
    /// Its ROS namespace (`/robot1`; empty for none).
    pub namespace: String,
    /// Its bridge's node token is alive.
    pub reachable: bool,
    /// When it was last seen going away.
    pub lost_at: Option<Instant>,
    /// The newest report of each role, and when it arrived.
    pub health: BTreeMap<String, (Box<Health>, Instant)>,
    /// The newest SLAM pose and when it arrived.
    pub pose: Option<(PoseEstimate, Instant)>,
}

/// A Zenoh session watching every smokenav robot of one domain.
pub struct Fleet {
    _session: zenoh::Session,
    _subs: Vec<zenoh::pubsub::Subscriber<()>>,
    _live: zenoh::pubsub::Subscriber<()>,
    rx: Receiver<Event>,
    domain: u32,
    pub robots: BTreeMap<String, RobotView>,
    dropped: Arc<AtomicU64>,
    /// Samples whose payload did not decode.
    pub undecodable: u64,
}

/// The namespace in a data key `<domain>/<ns…>/<marker>/…`, if it has the marker.
pub fn namespace_of(key: &str, domain: u32, marker: &str) -> Option<String> {
    let rest = key.strip_prefix(&format!("{domain}/"))?;
    let rest = format!("/{rest}");
    let at = rest.rfind(marker)?;
    Some(rest[..at].to_owned())
}

impl Fleet {
    /// Connects to `endpoints` (a router, or the robots' bridges) as a
    /// peer that listens on nothing and never scouts by multicast.
    pub fn open(endpoints: &[String], domain: u32) -> Result<Self, BridgeError> {
        let session = open_session(session_config("peer", &[], endpoints, false)?)?;
        let (tx, rx) = sync_channel::<Event>(QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        let send = {
            let dropped = dropped.clone();
            move |tx: &SyncSender<Event>, e: Event| {
                if let Err(TrySendError::Full(_)) = tx.try_send(e) {
                    dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
        };
        let declare = |key: String, f: Box<dyn Fn(Sample) + Send + Sync>| {
            session
                .declare_subscriber(key.clone())
                .callback(f)
                .wait()
                .map_err(|e| BridgeError::Declare {
                    key,
                    reason: e.to_string(),
                })
        };
        let health_ty = rihs::dds_type_name(schema::HEALTH.name);
        let pose_ty = rihs::dds_type_name(schema::POSE_STAMPED.name);
        let (t1, s1) = (tx.clone(), send.clone());
        let health = declare(
            format!("{domain}/**/health/*/{health_ty}/*"),
            Box::new(move |s: Sample| {
                let Some(namespace) = namespace_of(s.key_expr().as_str(), domain, "/health/")
                else {
                    return;
                };
                let e = match ros2::decode(MessageKind::Health, &s.payload().to_bytes(), None) {
                    Ok(AnyMessage::Health(h)) => Event::Health {
                        namespace,
                        health: h,
                    },
                    _ => Event::Undecodable,
                };
                s1(&t1, e);
            }),
        )?;
        let (t2, s2) = (tx.clone(), send.clone());
        let pose = declare(
            format!("{domain}/**/slam/pose/{pose_ty}/*"),
            Box::new(move |s: Sample| {
                let Some(namespace) = namespace_of(s.key_expr().as_str(), domain, "/slam/pose/")
                else {
                    return;
                };
                let e = match ros2::decode(MessageKind::PoseEstimate, &s.payload().to_bytes(), None)
                {
                    Ok(AnyMessage::PoseEstimate(p)) => Event::Pose { namespace, pose: p },
                    _ => Event::Undecodable,
                };
                s2(&t2, e);
            }),
        )?;
        let (t3, s3) = (tx, send);
        let lkey = format!("{}/{domain}/**", keys::ADMIN_SPACE);
        let live = session
            .liveliness()
            .declare_subscriber(lkey.clone())
            .history(true)
            .callback(move |s: Sample| {
                let Some(t) = keys::parse_node_token(s.key_expr().as_str()) else {
                    return;
                };
                if t.node != NODE_NAME {
                    return;
                }
                s3(
                    &t3,
                    Event::Token {
                        namespace: t.namespace,
                        alive: s.kind() == SampleKind::Put,
                    },
                );
            })
            .wait()
            .map_err(|e| BridgeError::Declare {
                key: lkey,
                reason: e.to_string(),
            })?;
        Ok(Fleet {
            _session: session,
            _subs: vec![health, pose],
            _live: live,
            rx,
            domain,
            robots: BTreeMap::new(),
            dropped,
            undecodable: 0,
        })
    }

    pub fn domain(&self) -> u32 {
        self.domain
    }

    /// Samples dropped because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Makes sure `namespace` is listed (reachable or not).
    pub fn expect(&mut self, namespace: &str) {
        self.robot(namespace);
    }

    fn robot(&mut self, namespace: &str) -> &mut RobotView {
        self.robots
            .entry(namespace.to_owned())
            .or_insert_with(|| RobotView {
                namespace: namespace.to_owned(),
                ..Default::default()
            })
    }

    /// Takes in what arrives until `deadline` (blocking, woken per sample).
    pub fn poll_until(&mut self, deadline: Instant) {
        loop {
            let now = Instant::now();
            if now >= deadline {
                return;
            }
            match self.rx.recv_timeout(deadline - now) {
                Ok(e) => self.apply(e),
                Err(RecvTimeoutError::Timeout) | Err(RecvTimeoutError::Disconnected) => return,
            }
        }
    }

    /// Polls for `window`.
    pub fn poll(&mut self, window: Duration) {
        self.poll_until(Instant::now() + window);
    }

    fn apply(&mut self, e: Event) {
        let now = Instant::now();
        match e {
            Event::Token { namespace, alive } => {
                let r = self.robot(&namespace);
                r.reachable = alive;
                if !alive {
                    r.lost_at = Some(now);
                }
            }
            Event::Health { namespace, health } => {
                let role = health.role.as_str().to_owned();
                self.robot(&namespace).health.insert(role, (health, now));
            }
            Event::Pose { namespace, pose } => {
                self.robot(&namespace).pose = Some((pose, now));
            }
            Event::Undecodable => self.undecodable += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn namespaces_come_from_the_key() {
        let k = "0/robot1/health/slam/smokenav_msgs::msg::dds_::Health_/RIHS01_x";
        assert_eq!(namespace_of(k, 0, "/health/").as_deref(), Some("/robot1"));
        let k = "0/health/slam/smokenav_msgs::msg::dds_::Health_/RIHS01_x";
        assert_eq!(namespace_of(k, 0, "/health/").as_deref(), Some(""));
        let k = "3/a/b/slam/pose/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_x";
        assert_eq!(namespace_of(k, 3, "/slam/pose/").as_deref(), Some("/a/b"));
        assert_eq!(namespace_of(k, 0, "/slam/pose/"), None);
    }
}
