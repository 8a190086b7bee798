//! The bus handle: one iceoryx2 node per process, named services per instance.

use crate::error::BusError;
use crate::map::{MapPublisher, MapSubscriber};
use crate::publisher::Publisher;
use crate::service::{Endpoint, TopicPorts};
use crate::subscriber::Subscriber;
use crate::topics::Topic;
use iceoryx2::config::Config;
use iceoryx2::prelude::*;
use iceoryx2::service::static_config::messaging_pattern::MessagingPattern as StaticPattern;
use smokenav_shared_types::{MapInfo, Message};

/// How to open the bus.
#[derive(Debug, Clone)]
pub struct BusOptions {
    /// Instance prefix: `<instance>/<topic>`. Two robots, or two test runs, on
    /// one machine use different instances and never see each other's data.
    pub instance: String,
    /// Name of this process's node (its role), shown by iceoryx2 tools.
    pub node_name: String,
    /// iceoryx2 root directory (node and service files). Every process of one
    /// instance must use the same. `None`: iceoryx2's default (`/tmp/iceoryx2/`).
    pub root_path: Option<String>,
}

impl BusOptions {
    /// Options for node `node_name` on `instance`, with iceoryx2's default root path.
    pub fn new(instance: &str, node_name: &str) -> Self {
        Self {
            instance: instance.to_owned(),
            node_name: node_name.to_owned(),
            root_path: None,
        }
    }

    /// Sets the iceoryx2 root path (`None`: the default).
    pub fn with_root_path(mut self, root: Option<String>) -> Self {
        self.root_path = root;
        self
    }
}

/// The iceoryx2 configuration for a root path (shared by every process of an instance).
pub fn iceoryx2_config(root_path: Option<&str>) -> Result<Config, BusError> {
    let mut cfg = Config::default();
    if let Some(root) = root_path {
        let mut root = root.to_owned();
        if !root.ends_with('/') {
            root.push('/');
        }
        let path =
            iceoryx2::prelude::Path::new(root.as_bytes()).map_err(|e| BusError::InvalidName {
                name: root.clone(),
                reason: format!("not a usable iceoryx2 root path: {e:?}"),
            })?;
        cfg.global.set_root_path(&path);
    }
    Ok(cfg)
}

/// A service seen on the bus (for `smokenav topic list`).
#[derive(Debug, Clone, PartialEq)]
pub struct ServiceInfo {
    /// Topic without the instance prefix.
    pub topic: String,
    /// iceoryx2 type name of the payload (e.g. `smokenav::LaserScan`).
    pub type_name: String,
    /// Processes (iceoryx2 nodes) attached to the service.
    pub nodes: usize,
}

/// One process's connection to the bus.
pub struct Bus {
    endpoint: Endpoint,
    config: Config,
}

impl Bus {
    /// Creates this process's node. Stale resources of crashed processes are
    /// cleaned up here (iceoryx2 does so on node creation), which is what lets
    /// a restarted driver reconnect.
    pub fn open(opts: &BusOptions) -> Result<Self, BusError> {
        validate_instance(&opts.instance)?;
        let config = iceoryx2_config(opts.root_path.as_deref())?;
        let node_name = NodeName::new(&opts.node_name).map_err(|e| BusError::InvalidName {
            name: opts.node_name.clone(),
            reason: format!("{e:?}"),
        })?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            // Processes handle SIGINT/SIGTERM themselves (smokenav-runtime); a
            // signal still interrupts a blocking wait, which returns `Shutdown`
            // or `Interrupted` for the caller to check its own flag.
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| BusError::Node {
                node: opts.node_name.clone(),
                reason: format!("{e:?}"),
            })?;
        Ok(Self {
            endpoint: Endpoint::new(node, opts.instance.clone()),
            config,
        })
    }

    /// The instance this bus connects to.
    pub fn instance(&self) -> &str {
        self.endpoint.instance()
    }

    /// The full iceoryx2 service name of a topic.
    pub fn service_name(&self, topic: &str) -> String {
        self.endpoint.service_name(topic)
    }

    /// A publisher of `topic`'s type on `topic`.
    pub fn publisher<T: Message>(&self, topic: Topic<T>) -> Result<Publisher<T>, BusError> {
        Publisher::create(&self.endpoint, topic.name())
    }

    /// A subscriber of `topic`'s type on `topic`.
    pub fn subscriber<T: Message>(&self, topic: Topic<T>) -> Result<Subscriber<T>, BusError> {
        Subscriber::create(&self.endpoint, topic.name())
    }

    /// A publisher of occupancy grids on `topic` (`topics::SLAM_MAP`).
    pub fn map_publisher(&self, topic: Topic<MapInfo>) -> Result<MapPublisher, BusError> {
        MapPublisher::create(&self.endpoint, topic.name())
    }

    /// A subscriber of occupancy grids on `topic` (`topics::SLAM_MAP`).
    pub fn map_subscriber(&self, topic: Topic<MapInfo>) -> Result<MapSubscriber, BusError> {
        MapSubscriber::create(&self.endpoint, topic.name())
    }

    /// The live processes other than this one that publish on `topic`
    /// (their node names); empty if nobody has opened the topic yet.
    pub fn live_publishers<T: Message>(&self, topic: Topic<T>) -> Result<Vec<String>, BusError> {
        let service = self.endpoint.service(topic.name())?;
        service.live_publishers(service.publish_subscribe::<T>())
    }

    /// [`Bus::live_publishers`] for the occupancy-grid topic.
    pub fn live_map_publishers(&self, topic: Topic<MapInfo>) -> Result<Vec<String>, BusError> {
        let service = self.endpoint.service(topic.name())?;
        service.live_slice_publishers(service.publish_subscribe::<[i8]>().user_header::<MapInfo>())
    }

    /// The publishers, subscribers and QoS of `topic` as iceoryx2 reports
    /// them; `None` if no process has created the topic yet.
    pub fn topic_ports<T: Message>(&self, topic: Topic<T>) -> Result<Option<TopicPorts>, BusError> {
        let service = self.endpoint.service(topic.name())?;
        service.ports(service.publish_subscribe::<T>().open())
    }

    /// [`Bus::topic_ports`] for the occupancy-grid topics.
    pub fn map_topic_ports(&self, topic: Topic<MapInfo>) -> Result<Option<TopicPorts>, BusError> {
        let service = self.endpoint.service(topic.name())?;
        service.ports(
            service
                .with_qos(service.publish_subscribe::<[i8]>().user_header::<MapInfo>())
                .open(),
        )
    }

    /// The services of this instance, as topics.
    pub fn list(&self) -> Result<Vec<ServiceInfo>, BusError> {
        list_services(&self.config, self.instance())
    }
}

/// Lists the publish–subscribe services of `instance` under `config`'s root path.
pub fn list_services(config: &Config, instance: &str) -> Result<Vec<ServiceInfo>, BusError> {
    let prefix = format!("{instance}/");
    let mut out = Vec::new();
    ipc::Service::list(config, |details| {
        let name = details.static_details.name().as_str();
        if let Some(topic) = name.strip_prefix(&prefix)
            && let StaticPattern::PublishSubscribe(ps) = details.static_details.messaging_pattern()
        {
            let nodes = details
                .dynamic_details
                .as_ref()
                .map(|d| d.nodes.len())
                .unwrap_or(0);
            out.push(ServiceInfo {
                topic: topic.to_owned(),
                type_name: ps.message_type_details().payload.type_name().to_string(),
                nodes,
            });
        }
        CallbackProgression::Continue
    })
    .map_err(|e| BusError::service(&prefix, "list services", e))?;
    out.sort_by(|a, b| a.topic.cmp(&b.topic));
    Ok(out)
}

fn validate_instance(instance: &str) -> Result<(), BusError> {
    let ok = !instance.is_empty()
        && instance.len() <= 48
        && instance
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    if ok {
        Ok(())
    } else {
        Err(BusError::InvalidName {
            name: instance.to_owned(),
            reason: "an instance is 1–48 characters of [A-Za-z0-9_-]".into(),
        })
    }
}
