//! Waiting for data on several subscribers at once, with deadlines.

use crate::error::BusError;
use crate::map::MapSubscriber;
use crate::subscriber::Subscriber;
use iceoryx2::port::listener::Listener;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use smokenav_shared_types::Message;
use std::cell::Cell;
use std::time::Duration;

/// Why [`Waiter::wait`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WaitOutcome {
    /// At least one attached subscriber has new data (drain them all).
    Data,
    /// An attached deadline passed without data from that subscriber.
    DeadlineMissed,
    /// Nothing happened before the timeout.
    TimedOut,
    /// A signal interrupted the wait (SIGTERM/SIGINT): check the shutdown flag.
    Interrupted,
    /// iceoryx2 reported a termination request.
    Shutdown,
}

/// Keeps a subscriber attached to a [`Waiter`]; detaches on drop.
pub type Attachment<'w, 'a> = WaitSetGuard<'w, 'a, ipc::Service>;

/// An event multiplexer (epoll underneath): sleeps until a subscriber has data,
/// a deadline passes, or the timeout expires. No polling.
pub struct Waiter {
    waitset: WaitSet<ipc::Service>,
    deadlines: std::cell::RefCell<Vec<WaitSetAttachmentId<ipc::Service>>>,
    missed_deadlines: Cell<u64>,
}

/// Anything that can be attached: typed subscribers and the map subscriber.
pub trait Wakeable {
    /// The listener the waiter watches.
    fn wake_listener(&self) -> &Listener<ipc::Service>;
}

impl<T: Message> Wakeable for Subscriber<T> {
    fn wake_listener(&self) -> &Listener<ipc::Service> {
        self.listener()
    }
}

impl Wakeable for MapSubscriber {
    fn wake_listener(&self) -> &Listener<ipc::Service> {
        self.listener()
    }
}

impl Waiter {
    /// A waiter with nothing attached.
    pub fn new() -> Result<Self, BusError> {
        let waitset = WaitSetBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| BusError::WaitSet {
                op: "create",
                reason: format!("{e:?}"),
            })?;
        Ok(Self {
            waitset,
            deadlines: Default::default(),
            missed_deadlines: Cell::new(0),
        })
    }

    /// Wakes the waiter whenever `sub` receives data.
    pub fn attach<'w, 'a>(
        &'w self,
        sub: &'a impl Wakeable,
    ) -> Result<Attachment<'w, 'a>, BusError> {
        self.waitset
            .attach_notification(sub.wake_listener())
            .map_err(|e| BusError::WaitSet {
                op: "attach",
                reason: format!("{e:?}"),
            })
    }

    /// Like [`Waiter::attach`], and also wakes with [`WaitOutcome::DeadlineMissed`]
    /// (counted in [`Waiter::missed_deadlines`]) when `sub` is silent for `deadline`.
    pub fn attach_with_deadline<'w, 'a>(
        &'w self,
        sub: &'a impl Wakeable,
        deadline: Duration,
    ) -> Result<Attachment<'w, 'a>, BusError> {
        let guard = self
            .waitset
            .attach_deadline(sub.wake_listener(), deadline)
            .map_err(|e| BusError::WaitSet {
                op: "attach deadline",
                reason: format!("{e:?}"),
            })?;
        self.deadlines
            .borrow_mut()
            .push(WaitSetAttachmentId::from_guard(&guard));
        Ok(guard)
    }

    /// Deadlines missed so far.
    pub fn missed_deadlines(&self) -> u64 {
        self.missed_deadlines.get()
    }

    /// Blocks until data, a missed deadline, a signal, or `timeout` (forever when `None`).
    pub fn wait(&self, timeout: Option<Duration>) -> Result<WaitOutcome, BusError> {
        let mut data = false;
        let mut missed = false;
        let deadlines = self.deadlines.borrow();
        let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
            // A deadline attachment reports its own id only when the deadline passed.
            if deadlines.contains(&id) {
                missed = true;
            } else {
                data = true;
            }
            CallbackProgression::Continue
        };
        let result = match timeout {
            Some(t) => self.waitset.wait_and_process_once_with_timeout(on_event, t),
            None => self.waitset.wait_and_process_once(on_event),
        }
        .map_err(|e| BusError::WaitSet {
            op: "wait",
            reason: format!("{e:?}"),
        })?;
        if missed {
            self.missed_deadlines.set(self.missed_deadlines.get() + 1);
        }
        Ok(match result {
            WaitSetRunResult::TerminationRequest => WaitOutcome::Shutdown,
            WaitSetRunResult::Interrupt => WaitOutcome::Interrupted,
            _ if data => WaitOutcome::Data,
            _ if missed => WaitOutcome::DeadlineMissed,
            _ => WaitOutcome::TimedOut,
        })
    }
}
