//! The live view: every bus topic, as the CDR the recordings carry, served
//! to Foxglove or Lichtblick over a WebSocket (`foxglove.websocket.v1`).
//!
//! [`Pump`] turns bus messages into channel messages with the recording's
//! own [`Encoder`] (so `/tf`, `/tf_static` and the sonar points are exactly
//! the recording's), and [`server::ViewServer`] queues them per client.

pub mod channels;
pub mod server;

pub use channels::{ChannelDef, Lane, channel_table};
pub use server::{ClientStats, Limits, ServerError, ViewServer};

use smokenav_platform_recording::{AnyMessageRef, Batch, Encoder, RobotGeometry};
use std::collections::HashMap;

/// Bus messages in, channel messages out to the server.
pub struct Pump {
    encoder: Encoder,
    batch: Batch,
    /// The encoder's channel index → the server's channel id.
    ids: Vec<Option<u32>>,
    by_topic: HashMap<String, u32>,
    /// Encoded messages whose topic the server does not advertise.
    pub unadvertised: u64,
}

impl Pump {
    /// A pump for `server`'s channels; `geometry` as for the recorder.
    pub fn new(server: &ViewServer, geometry: Option<RobotGeometry>) -> Self {
        Pump {
            encoder: Encoder::new(geometry),
            batch: Batch::new(),
            ids: Vec::new(),
            by_topic: server
                .channels()
                .iter()
                .map(|c| (c.topic.clone(), c.id))
                .collect(),
            unadvertised: 0,
        }
    }

    /// The robot profile's fixed transforms (`/tf_static`), latched.
    pub fn static_transforms(&mut self, server: &ViewServer, now_ns: u64) {
        self.batch.clear();
        self.encoder.static_transforms(now_ns, &mut self.batch);
        self.forward(server);
    }

    /// Encodes `msg`, received on bus topic `topic` at `log_time` (ns), and
    /// hands it to the server.
    pub fn push(
        &mut self,
        server: &ViewServer,
        topic: &str,
        msg: AnyMessageRef<'_>,
        log_time: u64,
    ) {
        self.batch.clear();
        self.encoder.encode(topic, msg, log_time, &mut self.batch);
        self.forward(server);
    }

    fn forward(&mut self, server: &ViewServer) {
        for (i, spec) in &self.batch.new_channels {
            if self.ids.len() <= *i {
                self.ids.resize(i + 1, None);
            }
            self.ids[*i] = self.by_topic.get(&spec.topic).copied();
        }
        for m in self.batch.messages() {
            match self.ids.get(m.channel).copied().flatten() {
                Some(id) => server.publish(id, m.log_time, &m.data),
                None => self.unadvertised += 1,
            }
        }
    }
}
