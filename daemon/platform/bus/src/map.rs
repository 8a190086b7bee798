//! The occupancy-grid topic: a variable-length `i8` slice with a `MapInfo` user header.

use crate::bus::{Bus, with_qos};
use crate::error::BusError;
use crate::subscriber::open_event;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
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
type EventService = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;

fn open_map_service(
    bus: &Bus,
    topic: &str,
) -> Result<(String, MapService, EventService), BusError> {
    let (full, name) = bus.iox_name(topic)?;
    let builder = bus
        .node()
        .service_builder(&name)
        .publish_subscribe::<[i8]>()
        .user_header::<MapInfo>();
    let pubsub = with_qos(builder, topic)
        .open_or_create()
        .map_err(|e| BusError::service(&full, "open map service", e))?;
    let event = open_event(bus, &full, &name, topic)?;
    Ok((full, pubsub, event))
}

pub struct MapPublisher {
    service: String,
    publisher: IoxPublisher<ipc::Service, [i8], MapInfo>,
    notifier: Notifier<ipc::Service>,
    next_seq: u64,
}

impl MapPublisher {
    pub fn create(bus: &Bus, topic: &str) -> Result<Self, BusError> {
        let (full, pubsub, event) = open_map_service(bus, topic)?;
        let publisher = pubsub
            .publisher_builder()
            .initial_max_slice_len(INITIAL_CELLS)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .create()
            .map_err(|e| BusError::service(&full, "create map publisher", e))?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|e| BusError::service(&full, "create notifier", e))?;
        Ok(Self {
            service: full,
            publisher,
            notifier,
            next_seq: 0,
        })
    }

    /// Publishes `cells` (row-major, `info.width × info.height`) with `info`; `header.seq` is set here.
    pub fn publish(&mut self, info: &MapInfo, cells: &[i8]) -> Result<u64, BusError> {
        if cells.len() != info.cell_count() {
            return Err(BusError::Service {
                service: self.service.clone(),
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
            .map_err(|e| BusError::service(&self.service, "loan map slice", e))?;
        let seq = self.next_seq;
        *sample.user_header_mut() = MapInfo {
            header: smokenav_shared_types::Header { seq, ..info.header },
            ..*info
        };
        let sample = sample.write_from_slice(cells);
        sample
            .send()
            .map_err(|e| BusError::service(&self.service, "send map", e))?;
        self.next_seq += 1;
        if let Err(e) = self.notifier.notify() {
            tracing::debug!(service = %self.service, error = ?e, "notify failed");
        }
        Ok(seq)
    }
}

pub struct MapSubscriber {
    service: String,
    subscriber: IoxSubscriber<ipc::Service, [i8], MapInfo>,
    listener: Listener<ipc::Service>,
}

impl MapSubscriber {
    pub fn create(bus: &Bus, topic: &str) -> Result<Self, BusError> {
        let (full, pubsub, event) = open_map_service(bus, topic)?;
        let subscriber = pubsub
            .subscriber_builder()
            .create()
            .map_err(|e| BusError::service(&full, "create map subscriber", e))?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| BusError::service(&full, "create listener", e))?;
        Ok(Self {
            service: full,
            subscriber,
            listener,
        })
    }

    pub(crate) fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    pub fn receive(&self) -> Result<Option<MapSample>, BusError> {
        let _ = self.listener.try_wait(|_| {});
        self.subscriber
            .receive()
            .map_err(|e| BusError::service(&self.service, "receive map", e))
    }
}
