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
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;
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
            Err(e) => Err(self.error("open publish-subscribe service", e)),
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
            Err(e) => Err(self.error("open publish-subscribe service", e)),
        }
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
