//! Typed subscriber paired with a listener, with loss accounting.

use crate::bus::{Bus, qos, with_qos};
use crate::error::BusError;
use crate::message::Message;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber as IoxSubscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample as IoxSample;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use std::cell::{Cell, RefCell};

/// A received message, borrowed from shared memory (no copy). Dereferences to `T`.
pub type Sample<T> = IoxSample<ipc::Service, T, ()>;

/// What a subscriber has seen.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SubscriberStats {
    /// Messages received.
    pub received: u64,
    /// Messages missed: gaps in a publisher's sequence numbers (overwritten
    /// while this subscriber was slow, or published while it was disconnected).
    pub lost: u64,
    /// Times a publisher's sequence restarted (the publishing process restarted).
    pub publisher_restarts: u64,
}

/// Publishers tracked per subscriber for sequence accounting.
const TRACKED_PUBLISHERS: usize = 8;

pub struct Subscriber<T: Message> {
    service: String,
    subscriber: IoxSubscriber<ipc::Service, T, ()>,
    listener: Listener<ipc::Service>,
    // Interior mutability so a subscriber can be received from while it is
    // attached (borrowed) to a Waiter.
    stats: Cell<SubscriberStats>,
    /// (publisher id, last seq, last use) — fixed size: no allocation per message.
    origins: RefCell<[Option<(u128, u64, u64)>; TRACKED_PUBLISHERS]>,
}

pub(crate) fn open_event(
    bus: &Bus,
    full: &str,
    name: &ServiceName,
    topic: &str,
) -> Result<EventFactory<ipc::Service>, BusError> {
    let q = qos(topic);
    bus.node()
        .service_builder(name)
        .event()
        .max_notifiers(q.max_publishers + 2)
        .max_listeners(q.max_subscribers + 2)
        .max_nodes(32)
        .open_or_create()
        .map_err(|e| BusError::service(full, "open event service", e))
}

impl<T: Message> Subscriber<T> {
    pub(crate) fn create(bus: &Bus, topic: &str) -> Result<Self, BusError> {
        let (full, name) = bus.iox_name(topic)?;
        let q = qos(topic);
        let pubsub = with_qos(
            bus.node().service_builder(&name).publish_subscribe::<T>(),
            topic,
        )
        .open_or_create()
        .map_err(|e| BusError::service(&full, "open publish-subscribe service", e))?;
        let event = open_event(bus, &full, &name, topic)?;
        let subscriber = pubsub
            .subscriber_builder()
            .buffer_size(q.buffer)
            .create()
            .map_err(|e| BusError::service(&full, "create subscriber", e))?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| BusError::service(&full, "create listener", e))?;
        Ok(Self {
            service: full,
            subscriber,
            listener,
            stats: Cell::new(SubscriberStats::default()),
            origins: RefCell::new([None; TRACKED_PUBLISHERS]),
        })
    }

    pub fn service(&self) -> &str {
        &self.service
    }

    pub fn stats(&self) -> SubscriberStats {
        self.stats.get()
    }

    pub(crate) fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    /// Takes the next queued message, if any. Never blocks: wait with a
    /// [`crate::Waiter`] first.
    pub fn receive(&self) -> Result<Option<Sample<T>>, BusError> {
        let mut sample = self.take()?;
        if sample.is_none() {
            // Queue empty: consume the pending wake-ups (one syscall per batch,
            // not per sample) so the waiter does not fire again for samples
            // already read, then look once more — a publisher sends before it
            // notifies, so a sample whose notification we just consumed is queued.
            let _ = self.listener.try_wait(|_| {});
            sample = self.take()?;
        }
        if let Some(s) = &sample {
            let origin = s.header().publisher_id().value();
            self.account(origin, s.payload().header().seq);
        }
        Ok(sample)
    }

    /// Drains the queue and returns only the newest message (counting the rest as received).
    pub fn receive_latest(&self) -> Result<Option<Sample<T>>, BusError> {
        let mut latest = None;
        while let Some(s) = self.receive()? {
            latest = Some(s);
        }
        Ok(latest)
    }

    fn take(&self) -> Result<Option<Sample<T>>, BusError> {
        self.subscriber
            .receive()
            .map_err(|e| BusError::service(&self.service, "receive", e))
    }

    fn account(&self, origin: u128, seq: u64) {
        let mut stats = self.stats.get();
        let mut origins = self.origins.borrow_mut();
        stats.received += 1;
        let tick = stats.received;
        if let Some(slot) = origins
            .iter_mut()
            .flatten()
            .find(|(id, _, _)| *id == origin)
        {
            let last = slot.1;
            if seq > last {
                stats.lost += seq - last - 1;
            } else {
                // Same publisher id cannot go back; treat as a restart to stay safe.
                stats.publisher_restarts += 1;
            }
            slot.1 = seq;
            slot.2 = tick;
            self.stats.set(stats);
            return;
        }
        // A publisher we have not seen: a new process (or a restarted one, which
        // gets a new id). Its first sample is not a gap unless it started past 0
        // while we were connected (history delivers only the newest).
        if stats.received > 1 {
            stats.publisher_restarts += u64::from(seq == 0);
        }
        self.stats.set(stats);
        let slot = match origins.iter().position(Option::is_none) {
            Some(free) => free,
            None => origins
                .iter()
                .enumerate()
                .min_by_key(|(_, o)| o.map(|(_, _, t)| t).unwrap_or(0))
                .map(|(i, _)| i)
                .unwrap_or(0),
        };
        origins[slot] = Some((origin, seq, tick));
    }
}
