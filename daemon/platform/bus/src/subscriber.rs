//! Typed subscriber paired with a listener, with loss accounting.

use crate::error::BusError;
use crate::port::{Inbox, SubscriberStats};
use crate::service::Endpoint;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample as IoxSample;
use smokenav_shared_types::Message;

/// A received message, borrowed from shared memory (no copy). Dereferences to `T`.
pub type Sample<T> = IoxSample<ipc::Service, T, ()>;

/// Receives `T` from one topic; attach it to a [`crate::Waiter`] to sleep until data arrives.
pub struct Subscriber<T: Message> {
    subscriber: IoxSubscriber<ipc::Service, T, ()>,
    inbox: Inbox,
}

impl<T: Message> Subscriber<T> {
    pub(crate) fn create(endpoint: &Endpoint, topic: &str) -> Result<Self, BusError> {
        let service = endpoint.service(topic)?;
        let pubsub = service
            .publish_subscribe::<T>()
            .open_or_create()
            .map_err(|e| service.open_or_create_error(e))?;
        let inbox = Inbox::create(&service, &service.event()?)?;
        let subscriber = pubsub
            .subscriber_builder()
            .buffer_size(service.qos().buffer)
            .create()
            .map_err(|e| service.error("create subscriber", e))?;
        Ok(Self { subscriber, inbox })
    }

    /// The full service name, `<instance>/<topic>`.
    pub fn service(&self) -> &str {
        self.inbox.service()
    }

    /// What this subscriber has received and lost so far.
    pub fn stats(&self) -> SubscriberStats {
        self.inbox.stats()
    }

    pub(crate) fn listener(&self) -> &Listener<ipc::Service> {
        self.inbox.listener()
    }

    /// Takes the next queued message, if any. Never blocks: wait with a
    /// [`crate::Waiter`] first.
    pub fn receive(&self) -> Result<Option<Sample<T>>, BusError> {
        self.inbox.receive(
            || {
                self.subscriber
                    .receive()
                    .map_err(|e| self.inbox.error("receive", e))
            },
            |s| (s.header().publisher_id().value(), s.payload().header().seq),
        )
    }

    /// Drains the queue and returns only the newest message (counting the rest as received).
    pub fn receive_latest(&self) -> Result<Option<Sample<T>>, BusError> {
        let mut latest = None;
        while let Some(s) = self.receive()? {
            latest = Some(s);
        }
        Ok(latest)
    }
}
