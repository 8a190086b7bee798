//! What every port does around iceoryx2's own send and receive: a
//! publishing port numbers its messages and wakes the subscribers; a
//! subscribing port consumes its wake-ups and counts what it lost.
//! [`crate::Publisher`], [`crate::Subscriber`] and the map ports all use these.

use crate::error::BusError;
use crate::service::TopicService;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use std::cell::{Cell, RefCell};

/// The sending side's bookkeeping: sequence numbers and the notifier.
pub(crate) struct Outbox {
    service: String,
    notifier: Notifier<ipc::Service>,
    next_seq: u64,
}

impl Outbox {
    pub(crate) fn create(
        service: &TopicService<'_>,
        event: &EventFactory<ipc::Service>,
    ) -> Result<Self, BusError> {
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|e| service.error("create notifier", e))?;
        Ok(Self {
            service: service.full.clone(),
            notifier,
            next_seq: 0,
        })
    }

    pub(crate) fn service(&self) -> &str {
        &self.service
    }

    /// The sequence number the next message carries.
    pub(crate) fn next_seq(&self) -> u64 {
        self.next_seq
    }

    /// Records that the message numbered [`Outbox::next_seq`] was sent and
    /// wakes the subscribers; returns its number.
    pub(crate) fn sent(&mut self) -> u64 {
        let seq = self.next_seq;
        self.next_seq += 1;
        // A lost notification only delays the subscriber to its next wake-up;
        // the sample itself is already delivered.
        if let Err(e) = self.notifier.notify() {
            tracing::debug!(service = %self.service, error = ?e, "notify failed");
        }
        seq
    }

    /// An error of `op` on this port's service.
    pub(crate) fn error(&self, op: &'static str, e: impl core::fmt::Debug) -> BusError {
        BusError::service(&self.service, op, e)
    }
}

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

/// The receiving side's bookkeeping: the listener and loss accounting.
pub(crate) struct Inbox {
    service: String,
    listener: Listener<ipc::Service>,
    // Interior mutability so a subscriber can be received from while it is
    // attached (borrowed) to a Waiter.
    stats: Cell<SubscriberStats>,
    /// (publisher id, last seq, last use) — fixed size: no allocation per message.
    origins: RefCell<[Option<(u128, u64, u64)>; TRACKED_PUBLISHERS]>,
}

impl Inbox {
    pub(crate) fn create(
        service: &TopicService<'_>,
        event: &EventFactory<ipc::Service>,
    ) -> Result<Self, BusError> {
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| service.error("create listener", e))?;
        Ok(Self {
            service: service.full.clone(),
            listener,
            stats: Cell::new(SubscriberStats::default()),
            origins: RefCell::new([None; TRACKED_PUBLISHERS]),
        })
    }

    pub(crate) fn service(&self) -> &str {
        &self.service
    }

    pub(crate) fn listener(&self) -> &Listener<ipc::Service> {
        &self.listener
    }

    pub(crate) fn stats(&self) -> SubscriberStats {
        self.stats.get()
    }

    /// Takes the next queued sample with `take`, accounting for it with the
    /// (publisher id, sequence number) `origin` gives.
    pub(crate) fn receive<S>(
        &self,
        take: impl Fn() -> Result<Option<S>, BusError>,
        origin: impl FnOnce(&S) -> (u128, u64),
    ) -> Result<Option<S>, BusError> {
        let mut sample = take()?;
        if sample.is_none() {
            // Queue empty: consume the pending wake-ups (one syscall per batch,
            // not per sample) so the waiter does not fire again for samples
            // already read, then look once more — a publisher sends before it
            // notifies, so a sample whose notification we just consumed is queued.
            let _ = self.listener.try_wait(|_| {});
            sample = take()?;
        }
        if let Some(s) = &sample {
            let (id, seq) = origin(s);
            self.account(id, seq);
        }
        Ok(sample)
    }

    /// An error of `op` on this port's service.
    pub(crate) fn error(&self, op: &'static str, e: impl core::fmt::Debug) -> BusError {
        BusError::service(&self.service, op, e)
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
