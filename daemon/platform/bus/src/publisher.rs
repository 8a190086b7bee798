//! Typed publisher paired with a notifier.

use crate::error::BusError;
use crate::port::Outbox;
use crate::service::Endpoint;
use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;
use smokenav_shared_types::Message;

/// Publishes `T` on one topic and wakes the topic's subscribers.
///
/// Sending never blocks: each subscriber's queue overwrites its oldest sample
/// when full (the subscriber sees the gap in `header.seq`).
pub struct Publisher<T: Message> {
    publisher: IoxPublisher<ipc::Service, T, ()>,
    outbox: Outbox,
}

impl<T: Message> Publisher<T> {
    pub(crate) fn create(endpoint: &Endpoint, topic: &str) -> Result<Self, BusError> {
        let service = endpoint.service(topic)?;
        let pubsub = service
            .publish_subscribe::<T>()
            .open_or_create()
            .map_err(|e| service.open_or_create_error(e))?;
        let outbox = Outbox::create(&service, &service.event()?)?;
        let publisher = pubsub
            .publisher_builder()
            .create()
            .map_err(|e| service.error("create publisher", e))?;
        Ok(Self { publisher, outbox })
    }

    /// The full service name, `<instance>/<topic>`.
    pub fn service(&self) -> &str {
        self.outbox.service()
    }

    /// Sequence number the next message will carry.
    pub fn next_seq(&self) -> u64 {
        self.outbox.next_seq()
    }

    /// Publishes a copy of `msg`, with `header.seq` set by the bus. Returns the sequence number.
    pub fn publish(&mut self, msg: &T) -> Result<u64, BusError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| self.outbox.error("loan sample", e))?
            .write_payload(*msg);
        self.finish(sample)
    }

    /// Builds the message in shared memory: `fill` gets a default-initialised
    /// `T` to write into, then `header.seq` is set and the sample is sent.
    pub fn publish_with(&mut self, fill: impl FnOnce(&mut T)) -> Result<u64, BusError> {
        let mut sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| self.outbox.error("loan sample", e))?
            .write_payload(T::default());
        fill(sample.payload_mut());
        self.finish(sample)
    }

    /// Stamps the sequence number, sends, and wakes the subscribers.
    fn finish(&mut self, mut sample: SampleMut<ipc::Service, T, ()>) -> Result<u64, BusError> {
        sample.payload_mut().header_mut().seq = self.outbox.next_seq();
        sample.send().map_err(|e| self.outbox.error("send", e))?;
        Ok(self.outbox.sent())
    }

    /// Connects to subscribers that appeared since the last send (iceoryx2
    /// connects lazily; call before the first send when a subscriber must not miss it).
    pub fn update_connections(&self) -> Result<(), BusError> {
        use iceoryx2::port::update_connections::UpdateConnections;
        self.publisher
            .update_connections()
            .map_err(|e| self.outbox.error("update connections", e))
    }
}
