//! The occupancy-grid topic: a variable-length `i8` slice with a `MapInfo` user header.

use crate::error::BusError;
use crate::port::{Inbox, Outbox, SubscriberStats};
use crate::service::{Endpoint, TopicService};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample as IoxSample;
use smokenav_shared_types::MapInfo;

/// A received map: `user_header()` is the [`MapInfo`], `payload()` the cells.
pub type MapSample = IoxSample<ipc::Service, [i8], MapInfo>;

/// Initial shared-memory slot size; grows in powers of two as the map grows.
const INITIAL_CELLS: usize = 256 * 256;

type MapService =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [i8], MapInfo>;

fn open_map_service(service: &TopicService<'_>) -> Result<MapService, BusError> {
    let builder = service.publish_subscribe::<[i8]>().user_header::<MapInfo>();
    service
        .with_qos(builder)
        .open_or_create()
        .map_err(|e| service.open_or_create_error(e))
}

/// Publishes maps on one topic and wakes its subscribers.
pub struct MapPublisher {
    publisher: IoxPublisher<ipc::Service, [i8], MapInfo>,
    outbox: Outbox,
}

impl MapPublisher {
    pub(crate) fn create(endpoint: &Endpoint, topic: &str) -> Result<Self, BusError> {
        let service = endpoint.service(topic)?;
        let pubsub = open_map_service(&service)?;
        let outbox = Outbox::create(&service, &service.event()?)?;
        let publisher = pubsub
            .publisher_builder()
            .initial_max_slice_len(INITIAL_CELLS)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| service.error("create map publisher", e))?;
        Ok(Self { publisher, outbox })
    }

    /// Publishes `cells` (row-major, `info.width × info.height`) with `info`; `header.seq` is set here.
    pub fn publish(&mut self, info: &MapInfo, cells: &[i8]) -> Result<u64, BusError> {
        if cells.len() != info.cell_count() {
            return Err(BusError::Service {
                service: self.outbox.service().to_owned(),
                op: "publish map",
                reason: format!(
                    "{} cells given for a {}×{} map",
                    cells.len(),
                    info.width,
                    info.height
                ),
            });
        }
        let mut sample = self
            .publisher
            .loan_slice_uninit(cells.len())
            .map_err(|e| self.outbox.error("loan map slice", e))?;
        *sample.user_header_mut() = MapInfo {
            header: smokenav_shared_types::Header {
                seq: self.outbox.next_seq(),
                ..info.header
            },
            ..*info
        };
        let sample = sample.write_from_slice(cells);
        sample
            .send()
            .map_err(|e| self.outbox.error("send map", e))?;
        Ok(self.outbox.sent())
    }
}

/// Receives maps from one topic, with the same loss accounting as [`crate::Subscriber`].
pub struct MapSubscriber {
    subscriber: IoxSubscriber<ipc::Service, [i8], MapInfo>,
    inbox: Inbox,
}

impl MapSubscriber {
    pub(crate) fn create(endpoint: &Endpoint, topic: &str) -> Result<Self, BusError> {
        let service = endpoint.service(topic)?;
        let pubsub = open_map_service(&service)?;
        let inbox = Inbox::create(&service, &service.event()?)?;
        let subscriber = pubsub
            .subscriber_builder()
            .create()
            .map_err(|e| service.error("create map subscriber", e))?;
        Ok(Self { subscriber, inbox })
    }

    pub(crate) fn listener(&self) -> &Listener<ipc::Service> {
        self.inbox.listener()
    }

    /// What this subscriber has received and lost so far.
    pub fn stats(&self) -> SubscriberStats {
        self.inbox.stats()
    }

    /// Takes the next queued map, if any. Never blocks.
    pub fn receive(&self) -> Result<Option<MapSample>, BusError> {
        self.inbox.receive(
            || {
                self.subscriber
                    .receive()
                    .map_err(|e| self.inbox.error("receive map", e))
            },
            |s| {
                (
                    s.header().publisher_id().value(),
                    s.user_header().header.seq,
                )
            },
        )
    }
}
