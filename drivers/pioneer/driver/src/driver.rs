//! The loop: open the port (the runtime's [`Reconnect`] policy) → the
//! [`PioneerCore`] talks ARCOS over it → its messages to a [`DriverSink`].
//!
//! One thread: it sleeps in `poll()` on the port until data, the session's
//! next deadline, or at most [`MAX_WAIT`] (the bus cannot share that poll),
//! so a velocity command is picked up within that time. CLOSE on the way out.

use crate::core::{CoreCounters, Output, PioneerCore};
use crate::link::{Link, PortSpec};
use anyhow::Context;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use smokenav_platform_runtime::{Reconnect, ReconnectPolicy};
use smokenav_shared_types::clock::monotonic_now_ns;
use std::time::Duration;

/// Longest sleep: bounds how late a velocity command is seen.
pub const MAX_WAIT: Duration = Duration::from_millis(25);

/// Retry after 200 ms doubling to 500 ms.
pub fn reconnect_policy() -> ReconnectPolicy {
    ReconnectPolicy::new(Duration::from_millis(200), Duration::from_millis(500))
}

/// The process side of the loop.
pub trait DriverSink {
    /// Hands the velocity commands that arrived to `core`.
    fn commands(&mut self, core: &mut PioneerCore) -> anyhow::Result<()>;
    /// A message or session event; an `Err` ends the loop (a fatal
    /// configuration problem, a bus failure).
    fn output(&mut self, out: Output) -> anyhow::Result<()>;
    /// The port was lost (the loop reopens it).
    fn lost(&mut self, why: &str);
    /// Health upkeep every loop turn; true = stop.
    fn idle(&mut self, counters: &CoreCounters, link: &Reconnect) -> bool;
}

fn ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

pub struct Driver {
    spec: PortSpec,
    link: Option<Link>,
    reconnect: Reconnect,
    pub core: PioneerCore,
}

impl Driver {
    pub fn new(spec: PortSpec, core: PioneerCore) -> Self {
        Self {
            spec,
            link: None,
            reconnect: Reconnect::new(reconnect_policy(), monotonic_now_ns()),
            core,
        }
    }

    pub fn link(&self) -> &Reconnect {
        &self.reconnect
    }

    /// Runs until the sink asks to stop or a fatal error; sends stop and CLOSE on the way out.
    pub fn run(&mut self, sink: &mut dyn DriverSink) -> anyhow::Result<()> {
        let result = (|| -> anyhow::Result<()> {
            while !sink.idle(&self.core.counters(), &self.reconnect) {
                self.step(sink)?;
            }
            Ok(())
        })();
        self.shutdown();
        result
    }

    fn step(&mut self, sink: &mut dyn DriverSink) -> anyhow::Result<()> {
        let now = monotonic_now_ns();
        if self.link.is_none() && self.reconnect.due(now) {
            self.connect(now);
        }
        sink.commands(&mut self.core)?;
        self.core.poll(now, self.link.is_some());
        self.flush(sink, now)?;

        let mut deadline = self.core.next_deadline(now).min(now + ns(MAX_WAIT));
        if let Some(at) = self.reconnect.retry_at_ns() {
            deadline = deadline.min(at.max(now));
        }
        let wait = Duration::from_nanos(deadline.saturating_sub(now));
        let readable = match &self.link {
            Some(link) => {
                let mut fds = [PollFd::new(link.fd(), PollFlags::POLLIN)];
                let ms = i32::try_from(wait.as_millis()).unwrap_or(i32::MAX);
                match poll(
                    &mut fds,
                    PollTimeout::try_from(ms).unwrap_or(PollTimeout::ZERO),
                ) {
                    Ok(n) => n > 0,
                    Err(nix::errno::Errno::EINTR) => false,
                    Err(e) => return Err(e).context("poll on the robot port"),
                }
            }
            None => {
                std::thread::sleep(wait);
                false
            }
        };
        if readable {
            self.read(sink);
            self.flush(sink, monotonic_now_ns())?;
        }
        Ok(())
    }

    fn connect(&mut self, now: u64) {
        match Link::open(&self.spec) {
            Ok(link) => {
                tracing::info!("opened {}", self.spec);
                self.link = Some(link);
                self.reconnect.opened(now);
                self.core.link_up(now);
            }
            Err(e) => self.reconnect.open_failed(now, e),
        }
    }

    fn drop_link(&mut self, sink: &mut dyn DriverSink, why: &str) {
        if self.link.take().is_some() {
            self.reconnect.lost(monotonic_now_ns(), why);
            sink.lost(why);
        }
    }

    fn read(&mut self, sink: &mut dyn DriverSink) {
        let mut buf = [0u8; 512];
        let Some(link) = self.link.as_mut() else {
            return;
        };
        let n = match link.read(&mut buf) {
            Ok(0) => {
                self.drop_link(sink, "the other end closed the connection");
                return;
            }
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                return;
            }
            Err(e) => {
                self.drop_link(sink, &e.to_string());
                return;
            }
        };
        self.core
            .on_bytes(buf.get(..n).unwrap_or(&[]), monotonic_now_ns());
    }

    /// Sends what the core queued and hands its output to the sink.
    fn flush(&mut self, sink: &mut dyn DriverSink, now: u64) -> anyhow::Result<()> {
        let sent = match self.link.as_mut() {
            Some(link) => self.core.send(|b| link.write_all(b)),
            None => self.core.send(|_| Ok(())),
        };
        if let Err(e) = sent {
            self.drop_link(sink, &e.to_string());
        }
        let mut result = Ok(());
        self.core.drain(now, &mut |out| {
            if result.is_ok() {
                result = sink.output(out);
            }
        });
        result
    }

    /// Stop, then CLOSE: a robot must not be left in an open session.
    fn shutdown(&mut self) {
        self.core.close(monotonic_now_ns());
        if let Some(link) = self.link.as_mut() {
            let _ = self.core.send(|b| link.write_all(b));
            tracing::info!("sent CLOSE to {}", self.spec);
        } else {
            let _ = self.core.send(|_| Ok(()));
        }
    }
}
