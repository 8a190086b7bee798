//! Service plumbing every port shares: the iceoryx2 service name of a topic,
//! its QoS, and the event service paired with each publish–subscribe service.
//!
//! Ports (`publisher.rs`, `subscriber.rs`, `map.rs`) open their services only
//! through here, so whichever process creates a service, the others open it
//! with identical settings.

use crate::error::BusError;
use crate::topics::{self, Qos};
use iceoryx2::identifiers::UniqueNodeId;
use iceoryx2::node::{NodeState, NodeView};
use iceoryx2::prelude::*;
use iceoryx2::service::builder::publish_subscribe::Builder as PubSubBuilder;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::dynamic_config::publish_subscribe::DynamicConfig;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;

/// Most processes that may attach to one service (publishers, subscribers,
/// tools): drivers, consumers, `topic echo/hz`, `record`, `play`, `status`.
const MAX_NODES: usize = 32;

/// This process's node and the instance its topics live in.
pub(crate) struct Endpoint {
    node: Node<ipc::Service>,
    instance: String,
}

impl Endpoint {
    pub(crate) fn new(node: Node<ipc::Service>, instance: String) -> Self {
        Self { node, instance }
    }

    pub(crate) fn instance(&self) -> &str {
        &self.instance
    }

    /// The full iceoryx2 service name of a topic: `<instance>/<topic>`.
    pub(crate) fn service_name(&self, topic: &str) -> String {
        format!("{}/{}", self.instance, topic)
    }

    /// The service of `topic` in this instance, ready to be opened.
    pub(crate) fn service(&self, topic: &str) -> Result<TopicService<'_>, BusError> {
        let full = self.service_name(topic);
        let name = ServiceName::new(&full).map_err(|e| BusError::InvalidName {
            name: full.clone(),
            reason: format!("{e:?}"),
        })?;
        Ok(TopicService {
            node: &self.node,
            full,
            name,
            qos: topics::qos(topic),
        })
    }
}

/// One topic's service: its names and its QoS.
pub(crate) struct TopicService<'n> {
    node: &'n Node<ipc::Service>,
    /// `<instance>/<topic>`, for errors and logs.
    pub(crate) full: String,
    name: ServiceName,
    qos: Qos,
}

impl TopicService<'_> {
    pub(crate) fn qos(&self) -> Qos {
        self.qos
    }

    /// The publish–subscribe builder for payload `P`, with the topic's QoS.
    /// Callers that add a user header call [`TopicService::with_qos`] after it.
    pub(crate) fn publish_subscribe<P>(&self) -> PubSubBuilder<P, (), ipc::Service>
    where
        P: core::fmt::Debug + IceoryxSend + ZeroCopySend + ?Sized,
    {
        self.with_qos(
            self.node
                .service_builder(&self.name)
                .publish_subscribe::<P>(),
        )
    }

    /// Applies the topic's QoS to a publish–subscribe builder.
    pub(crate) fn with_qos<P, H>(
        &self,
        builder: PubSubBuilder<P, H, ipc::Service>,
    ) -> PubSubBuilder<P, H, ipc::Service>
    where
        P: core::fmt::Debug + IceoryxSend + ?Sized,
        H: core::fmt::Debug + ZeroCopySend,
    {
        let q = self.qos;
        builder
            .history_size(q.history)
            .subscriber_max_buffer_size(q.buffer)
            .max_publishers(q.max_publishers)
            .max_subscribers(q.max_subscribers)
            .max_nodes(MAX_NODES)
            // Publishers never block: a full subscriber queue drops its oldest.
            .enable_safe_overflow(true)
    }

    /// The event service paired with the publish–subscribe service: it
    /// wakes subscribers so they wait for data instead of polling.
    pub(crate) fn event(&self) -> Result<EventFactory<ipc::Service>, BusError> {
        let q = self.qos;
        self.node
            .service_builder(&self.name)
            .event()
            // Room for a tool (`record`, `topic echo`) joining a full topic.
            .max_notifiers(q.max_publishers + 2)
            .max_listeners(q.max_subscribers + 2)
            .max_nodes(MAX_NODES)
            .open_or_create()
            .map_err(|e| self.error("open event service", e))
    }

    /// The names of the live processes, other than this one, that have a
    /// publisher on this service; empty if the service does not exist.
    /// Publishers of dead processes (not yet cleaned up) do not count.
    pub(crate) fn live_publishers<P>(
        &self,
        builder: PubSubBuilder<P, (), ipc::Service>,
    ) -> Result<Vec<String>, BusError>
    where
        P: core::fmt::Debug + IceoryxSend + ZeroCopySend,
    {
        match builder.open() {
            Ok(f) => {
                let ids = publishing_nodes(f.dynamic_config());
                self.alive_names(&f, &ids)
            }
            Err(PublishSubscribeOpenError::DoesNotExist) => Ok(Vec::new()),
            Err(e) => Err(self.open_error(e)),
        }
    }

    /// [`TopicService::live_publishers`] for a slice payload with a user header.
    pub(crate) fn live_slice_publishers<P, H>(
        &self,
        builder: PubSubBuilder<[P], H, ipc::Service>,
    ) -> Result<Vec<String>, BusError>
    where
        P: core::fmt::Debug + IceoryxSend + ZeroCopySend,
        H: core::fmt::Debug + ZeroCopySend,
    {
        match self.with_qos(builder).open() {
            Ok(f) => {
                let ids = publishing_nodes(f.dynamic_config());
                self.alive_names(&f, &ids)
            }
            Err(PublishSubscribeOpenError::DoesNotExist) => Ok(Vec::new()),
            Err(e) => Err(self.open_error(e)),
        }
    }

    /// The ports of the topic as iceoryx2's dynamic configuration lists them;
    /// `None` if nobody has created the topic's service yet.
    /// `opened` is the service opened with the topic's type and QoS.
    pub(crate) fn ports<P, H>(
        &self,
        opened: Result<
            iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, P, H>,
            PublishSubscribeOpenError,
        >,
    ) -> Result<Option<TopicPorts>, BusError>
    where
        P: core::fmt::Debug + IceoryxSend + ?Sized,
        H: core::fmt::Debug + ZeroCopySend,
    {
        let factory = match opened {
            Ok(f) => f,
            Err(PublishSubscribeOpenError::DoesNotExist) => return Ok(None),
            Err(e) => return Err(self.open_error(e)),
        };
        let own = *self.node.id();
        let mut nodes: Vec<(UniqueNodeId, String, bool)> = Vec::new();
        factory
            .nodes(|state| {
                let (view_id, name, alive) = match &state {
                    NodeState::Alive(v) => (
                        *v.id(),
                        v.details().as_ref().map(|d| d.name().as_str().to_owned()),
                        true,
                    ),
                    NodeState::Dead(v) => (
                        *v.id(),
                        v.details().as_ref().map(|d| d.name().as_str().to_owned()),
                        false,
                    ),
                    _ => return CallbackProgression::Continue,
                };
                nodes.push((
                    view_id,
                    name.unwrap_or_else(|| format!("{view_id:?}")),
                    alive,
                ));
                CallbackProgression::Continue
            })
            .map_err(|e| self.error("list nodes", e))?;
        let describe = |id: &UniqueNodeId| match nodes.iter().find(|(n, _, _)| n == id) {
            Some((_, name, alive)) => PortInfo {
                node: name.clone(),
                alive: *alive,
                this_process: *id == own,
            },
            None => PortInfo {
                node: format!("{id:?}"),
                alive: false,
                this_process: false,
            },
        };
        let d = factory.dynamic_config();
        let mut publishers = Vec::new();
        d.list_publishers(|p| {
            publishers.push(describe(&p.node_id));
            CallbackProgression::Continue
        });
        let mut subscribers = Vec::new();
        d.list_subscribers(|p| {
            subscribers.push(describe(&p.node_id));
            CallbackProgression::Continue
        });
        publishers.sort();
        subscribers.sort();
        let st = factory.static_config();
        Ok(Some(TopicPorts {
            type_name: st.message_type_details().payload.type_name().to_string(),
            publishers,
            subscribers,
            qos: Qos {
                history: st.history_size(),
                buffer: st.subscriber_max_buffer_size(),
                max_publishers: st.max_publishers(),
                max_subscribers: st.max_subscribers(),
            },
            safe_overflow: st.has_safe_overflow(),
        }))
    }

    /// The names of the live nodes among `ids`, this process's excepted.
    fn alive_names<F: PortFactory<Service = ipc::Service>>(
        &self,
        factory: &F,
        ids: &[UniqueNodeId],
    ) -> Result<Vec<String>, BusError> {
        let own = *self.node.id();
        let mut names = Vec::new();
        factory
            .nodes(|state| {
                if let NodeState::Alive(view) = &state
                    && *view.id() != own
                    && ids.contains(view.id())
                {
                    names.push(match view.details() {
                        Some(d) => d.name().as_str().to_owned(),
                        None => format!("{:?}", view.id()),
                    });
                }
                CallbackProgression::Continue
            })
            .map_err(|e| self.error("list nodes", e))?;
        names.sort();
        names.dedup();
        Ok(names)
    }

    /// An error of `op` on this service.
    pub(crate) fn error(&self, op: &'static str, e: impl core::fmt::Debug) -> BusError {
        BusError::service(&self.full, op, e)
    }

    /// The error of opening the publish–subscribe service: another layout
    /// of its type (another release's processes) said so, by name.
    pub(crate) fn open_error(&self, e: PublishSubscribeOpenError) -> BusError {
        match e {
            PublishSubscribeOpenError::IncompatibleTypes => BusError::IncompatibleType {
                service: self.full.clone(),
            },
            e => self.error("open publish-subscribe service", e),
        }
    }

    /// [`Self::open_error`] of opening or creating it.
    pub(crate) fn open_or_create_error(&self, e: PublishSubscribeOpenOrCreateError) -> BusError {
        match e {
            PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(e) => self.open_error(e),
            e => self.error("open publish-subscribe service", e),
        }
    }
}

/// One port (publisher or subscriber) of a topic and the process holding it.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct PortInfo {
    /// The iceoryx2 node name of the process (e.g. `hokuyo`, `topic-echo`).
    pub node: String,
    /// Whether iceoryx2 sees the node alive (a crashed one is dead until cleaned up).
    pub alive: bool,
    /// The port belongs to the process asking.
    pub this_process: bool,
}

/// What iceoryx2 knows about one topic's service.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicPorts {
    /// The iceoryx2 payload type name (`smokenav::LaserScan`).
    pub type_name: String,
    /// Its publishers, live or not yet cleaned up.
    pub publishers: Vec<PortInfo>,
    /// Its subscribers.
    pub subscribers: Vec<PortInfo>,
    /// The service's QoS as created (history, queue, port limits).
    pub qos: Qos,
    /// A full subscriber queue drops its oldest sample instead of blocking the publisher.
    pub safe_overflow: bool,
}

/// The nodes that hold a publisher of a service.
fn publishing_nodes(
    d: &DynamicConfig<<ipc::Service as iceoryx2::service::Service>::Bag>,
) -> Vec<UniqueNodeId> {
    let mut ids = Vec::new();
    d.list_publishers(|p| {
        ids.push(p.node_id);
        CallbackProgression::Continue
    });
    ids
}
