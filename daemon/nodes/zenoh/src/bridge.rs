//! The robot's side: bus messages in, rmw_zenoh samples out.
//!
//! Every channel the recording encoder makes of a bus message (the standard
//! ROS 2 message, its `smokenav_msgs` companion, `/tf`, `/tf_static`, the
//! sonar points) becomes one Zenoh publisher on rmw_zenoh's key with a
//! liveliness token, declared when the channel first carries a message.
//! Publishers drop rather than block when the network is congested (a slow
//! link must never slow the bus); what was dropped is counted.

use crate::keys::{self, EntityKind, Qos};
use crate::rihs;
use smokenav_platform_config::ZenohSection;
use smokenav_platform_recording::encoder::RosQos;
use smokenav_platform_recording::{AnyMessageRef, Batch, Encoder, RobotGeometry};
use thiserror::Error;
use zenoh::Wait;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;

#[derive(Debug, Error)]
pub enum BridgeError {
    #[error("zenoh configuration `{key}`: {reason}")]
    Config { key: String, reason: String },
    #[error("cannot open the Zenoh session: {0}")]
    Open(String),
    #[error("cannot declare `{key}`: {reason}")]
    Declare { key: String, reason: String },
    #[error(transparent)]
    Hash(#[from] rihs::HashError),
}

/// The Zenoh configuration of `cfg`: mode, endpoints, scouting. Only what
/// is asked for is opened: no listener unless listed, no multicast unless on.
pub fn session_config(
    mode: &str,
    listen: &[String],
    connect: &[String],
    multicast: bool,
) -> Result<zenoh::Config, BridgeError> {
    let mut c = zenoh::Config::default();
    let json = |v: &[String]| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
    let set = |c: &mut zenoh::Config, key: &str, value: String| {
        c.insert_json5(key, &value)
            .map_err(|e| BridgeError::Config {
                key: key.into(),
                reason: e.to_string(),
            })
    };
    set(&mut c, "mode", format!("\"{mode}\""))?;
    set(&mut c, "listen/endpoints", json(listen))?;
    set(&mut c, "connect/endpoints", json(connect))?;
    set(&mut c, "scouting/multicast/enabled", multicast.to_string())?;
    Ok(c)
}

/// Opens a session with `c`.
pub fn open_session(c: zenoh::Config) -> Result<zenoh::Session, BridgeError> {
    zenoh::open(c)
        .wait()
        .map_err(|e| BridgeError::Open(e.to_string()))
}

struct Outlet {
    publisher: Publisher<'static>,
    _token: LivelinessToken,
    gid: [u8; 16],
    seq: i64,
}

/// Counters of the bridge.
#[derive(Debug, Default, Clone, Copy)]
pub struct BridgeStats {
    /// Samples handed to Zenoh.
    pub sent: u64,
    pub bytes: u64,
    /// Samples Zenoh refused.
    pub put_errors: u64,
    /// Publishers declared.
    pub publishers: u64,
}

/// The bridge: one session, one publisher per channel.
pub struct Bridge {
    session: zenoh::Session,
    zid: String,
    domain: u32,
    namespace: String,
    encoder: Encoder,
    batch: Batch,
    outlets: Vec<Option<Outlet>>,
    next_entity: u32,
    _node: LivelinessToken,
    pub stats: BridgeStats,
}

impl Bridge {
    /// Opens the session of `cfg` and declares the node.
    pub fn open(cfg: &ZenohSection, geometry: Option<RobotGeometry>) -> Result<Self, BridgeError> {
        let session = open_session(session_config(
            cfg.mode.as_str(),
            &cfg.listen,
            &cfg.connect,
            cfg.multicast_scouting,
        )?)?;
        let zid = session.zid().to_string();
        let node_key = keys::node_token(cfg.domain_id, &zid, &cfg.namespace);
        let node = declare_token(&session, &node_key)?;
        Ok(Bridge {
            session,
            zid,
            domain: cfg.domain_id,
            namespace: cfg.namespace.clone(),
            encoder: Encoder::new(geometry),
            batch: Batch::new(),
            outlets: Vec::new(),
            next_entity: 1,
            _node: node,
            stats: BridgeStats::default(),
        })
    }

    pub fn session(&self) -> &zenoh::Session {
        &self.session
    }

    pub fn zid(&self) -> &str {
        &self.zid
    }

    /// The data key of ROS 2 topic `ros2_topic` of this robot, for type `def`.
    pub fn key_of(
        &self,
        ros2_topic: &str,
        def: &smokenav_platform_recording::schema::MsgDef,
    ) -> Result<String, BridgeError> {
        Ok(keys::topic_key(
            self.domain,
            &keys::qualified(&self.namespace, ros2_topic),
            &rihs::dds_type_name(def.name),
            &rihs::type_hash(def)?,
        ))
    }

    /// The profile's fixed transforms (`/tf_static`).
    pub fn static_transforms(&mut self, now_ns: u64) -> Result<(), BridgeError> {
        self.batch.clear();
        self.encoder.static_transforms(now_ns, &mut self.batch);
        self.forward()
    }

    /// Encodes `msg` of bus topic `topic` and publishes every channel it became.
    pub fn push(
        &mut self,
        topic: &str,
        msg: AnyMessageRef<'_>,
        log_time: u64,
    ) -> Result<(), BridgeError> {
        self.batch.clear();
        self.encoder.encode(topic, msg, log_time, &mut self.batch);
        self.forward()
    }

    fn forward(&mut self) -> Result<(), BridgeError> {
        for (i, spec) in std::mem::take(&mut self.batch.new_channels) {
            let qualified = keys::qualified(&self.namespace, &spec.topic);
            let dds = rihs::dds_type_name(spec.schema.name);
            let hash = rihs::type_hash(spec.schema)?;
            let key = keys::topic_key(self.domain, &qualified, &dds, &hash);
            let qos = match spec.qos {
                // No publication cache here: a late subscriber gets the next
                // map (SLAM republishes it), so every topic is offered volatile.
                RosQos::Stream | RosQos::Latched => Qos {
                    transient_local: false,
                    depth: 10,
                },
            };
            let token_key = keys::entity_token(
                self.domain,
                &self.zid,
                self.next_entity,
                EntityKind::Publisher,
                &self.namespace,
                &qualified,
                &dds,
                &hash,
                qos,
            );
            self.next_entity += 1;
            let publisher = self
                .session
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Drop)
                .wait()
                .map_err(|e| BridgeError::Declare {
                    key: key.clone(),
                    reason: e.to_string(),
                })?;
            let token = declare_token(&self.session, &token_key)?;
            tracing::debug!(%key, "publishing");
            if self.outlets.len() <= i {
                self.outlets.resize_with(i + 1, || None);
            }
            self.outlets[i] = Some(Outlet {
                publisher,
                _token: token,
                gid: keys::gid(&token_key),
                seq: 0,
            });
            self.stats.publishers += 1;
        }
        let now = unix_now_ns();
        for m in self.batch.messages() {
            let Some(Some(o)) = self.outlets.get_mut(m.channel) else {
                continue;
            };
            o.seq += 1;
            let att = keys::attachment(o.seq, now, &o.gid);
            match o
                .publisher
                .put(m.data.as_slice())
                .attachment(att.as_slice())
                .wait()
            {
                Ok(()) => {
                    self.stats.sent += 1;
                    self.stats.bytes += m.data.len() as u64;
                }
                Err(e) => {
                    self.stats.put_errors += 1;
                    tracing::debug!("put failed: {e}");
                }
            }
        }
        Ok(())
    }
}

/// Declares liveliness token `key`.
pub fn declare_token(session: &zenoh::Session, key: &str) -> Result<LivelinessToken, BridgeError> {
    session
        .liveliness()
        .declare_token(key.to_owned())
        .wait()
        .map_err(|e| BridgeError::Declare {
            key: key.into(),
            reason: e.to_string(),
        })
}

/// Now, ns since the Unix epoch (rmw_zenoh's attachment time).
pub fn unix_now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as i64)
        .unwrap_or(0)
}
