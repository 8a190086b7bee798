//! The loop: a link step (it blocks for at most [`MAX_WAIT`]) → its events
//! through the [`DriverCore`] → readings to the [`DriverSink`]; idle
//! readings while no samples come. The link reopens its device itself (the
//! runtime's reconnect policy, [`crate::link::reconnect_policy`]).

use crate::core::DriverCore;
use crate::link::{Link, LinkEvent};
use smokenav_shared_types::{Clock, SmokeReading};
use std::time::{Duration, Instant};

/// Longest a link step blocks: keeps health and the 10 Hz idle publishing on time.
pub const MAX_WAIT: Duration = Duration::from_millis(50);

/// Malformed input is counted always but logged at most this often.
pub const ERROR_LOG_PERIOD: Duration = Duration::from_secs(1);

/// The process side of the loop.
pub trait DriverSink {
    fn publish(&mut self, reading: &SmokeReading) -> anyhow::Result<()>;
    /// Every link event, before the core sees it.
    fn event(&mut self, event: &LinkEvent, link: &Link);
    /// Health upkeep after every step; true = stop.
    fn idle(&mut self, core: &DriverCore, link: &Link, now_ns: u64) -> bool;
}

pub struct Driver {
    pub core: DriverCore,
    pub link: Link,
    events: Vec<LinkEvent>,
}

impl Driver {
    pub fn new(core: DriverCore, link: Link) -> Self {
        Self {
            core,
            link,
            events: Vec::with_capacity(64),
        }
    }

    /// Runs until the sink asks to stop (or publishing fails).
    pub fn run(&mut self, clock: &dyn Clock, sink: &mut dyn DriverSink) -> anyhow::Result<()> {
        loop {
            self.events.clear();
            self.link.step(MAX_WAIT, clock, &mut self.events);
            for ev in &self.events {
                sink.event(ev, &self.link);
                if let Some(msg) = self.core.on_event(ev) {
                    sink.publish(&msg)?;
                }
            }
            if let Some(msg) = self.core.on_idle(clock.now_ns()) {
                sink.publish(&msg)?;
            }
            if sink.idle(&self.core, &self.link, clock.now_ns()) {
                return Ok(());
            }
        }
    }
}

/// Logs recurring input errors at most once per [`ERROR_LOG_PERIOD`].
#[derive(Debug, Default)]
pub struct ErrorLog {
    last: Option<Instant>,
    suppressed: u64,
}

impl ErrorLog {
    /// The message to record now, or `None` while suppressed.
    pub fn admit(&mut self, msg: &str) -> Option<String> {
        let now = Instant::now();
        if self
            .last
            .is_some_and(|t| now.duration_since(t) < ERROR_LOG_PERIOD)
        {
            self.suppressed += 1;
            return None;
        }
        let out = if self.suppressed > 0 {
            format!("{msg} (and {} more since the last report)", self.suppressed)
        } else {
            msg.to_owned()
        };
        self.last = Some(now);
        self.suppressed = 0;
        Some(out)
    }
}
