//! Typed publisher paired with a notifier.

use crate::bus::{Bus, with_qos};
use crate::error::BusError;
use crate::message::Message;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher as IoxPublisher;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;

/// Publishes `T` on one topic and wakes the topic's subscribers.
///
/// Sending never blocks: each subscriber's queue overwrites its oldest sample
/// when full (the subscriber sees the gap in `header.seq`).
pub struct Publisher<T: Message> {
    service: String,
    publisher: IoxPublisher<ipc::Service, T, ()>,
    notifier: Notifier<ipc::Service>,
    next_seq: u64,
}

impl<T: Message> Publisher<T> {
    pub(crate) fn create(bus: &Bus, topic: &str) -> Result<Self, BusError> {
        let (full, name) = bus.iox_name(topic)?;
        let pubsub = with_qos(
            bus.node().service_builder(&name).publish_subscribe::<T>(),
            topic,
        )
        .open_or_create()
        .map_err(|e| BusError::service(&full, "open publish-subscribe service", e))?;
        let event = crate::subscriber::open_event(bus, &full, &name, topic)?;
        let publisher = pubsub
            .publisher_builder()
            .create()
            .map_err(|e| BusError::service(&full, "create publisher", e))?;
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

    pub fn service(&self) -> &str {
        &self.service
    }

    /// Sequence number the next message will carry.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// Publishes a copy of `msg`, with `header.seq` set by the bus. Returns the sequence number.
    pub fn publish(&mut self, msg: &T) -> Result<u64, BusError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| BusError::service(&self.service, "loan sample", e))?
            .write_payload(*msg);
        self.finish(sample)
    }

    /// Builds the message in shared memory: `fill` gets a default-initialised
    /// `T` to write into, then `header.seq` is set and the sample is sent.
    pub fn publish_with(&mut self, fill: impl FnOnce(&mut T)) -> Result<u64, BusError> {
        let mut sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| BusError::service(&self.service, "loan sample", e))?
            .write_payload(T::default());
        fill(sample.payload_mut());
        self.finish(sample)
    }

    /// Stamps the sequence number, sends, and wakes the subscribers.
    fn finish(&mut self, mut sample: SampleMut<ipc::Service, T, ()>) -> Result<u64, BusError> {
        let seq = self.next_seq;
        sample.payload_mut().header_mut().seq = seq;
        sample
            .send()
            .map_err(|e| BusError::service(&self.service, "send", e))?;
        self.next_seq += 1;
        // A lost notification only delays the subscriber to its next wake-up;
        // the sample itself is already delivered.
        if let Err(e) = self.notifier.notify() {
            tracing::debug!(service = %self.service, error = ?e, "notify failed");
        }
        Ok(seq)
    }

    /// Connects to subscribers that appeared since the last send (iceoryx2
    /// connects lazily; call before the first send when a subscriber must not miss it).
    pub fn update_connections(&self) -> Result<(), BusError> {
        use iceoryx2::port::update_connections::UpdateConnections;
        self.publisher
            .update_connections()
            .map_err(|e| BusError::service(&self.service, "update connections", e))
    }
}
