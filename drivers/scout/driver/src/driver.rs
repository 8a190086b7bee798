//! The cycle loop: open the port → configure the robot → one request per
//! cycle, each answered with the full state → messages to the sink; reopen
//! the port (the runtime's [`Reconnect`] policy) when the link is lost.
//!
//! No bus here: the process hands in a [`DriverSink`] that waits for (and
//! applies) velocity commands, publishes and reports health, so the loop
//! runs against the emulator in a test as it does in `smokenav-scout`.

use crate::core::{CoreStats, ScoutCore};
use crate::link::{Link, LinkError, LinkStats, PortSpec, reply_timeout};
use smokenav_platform_runtime::{HealthReporter, Reconnect, ReconnectPolicy, Report};
use smokenav_scout_codec::{Command, SplitterStats, StateSi};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{Odometry, SonarRing};
use std::time::{Duration, Instant};

/// Where the robot is and how fast the loop runs.
#[derive(Debug, Clone)]
pub struct DriverConfig {
    pub port: PortSpec,
    pub baud: u32,
    /// One request per period.
    pub period: Duration,
    /// No good reply for this long: the link is closed and reopened.
    pub link_timeout: Duration,
}

impl DriverConfig {
    /// Retry after 100 ms doubling to 400 ms, so a replugged robot is back
    /// within the second the Scout issue asks for.
    pub fn reconnect_policy(&self) -> ReconnectPolicy {
        ReconnectPolicy::new(Duration::from_millis(100), Duration::from_millis(400))
    }
}

/// What the loop tells its owner besides messages.
#[derive(Debug)]
pub enum DriverEvent<'a> {
    /// The robot is configured and answering; `first` on the first connection.
    Connected { first: bool },
    /// The link was closed: the loop reopens it.
    Lost(&'a str),
    /// A cycle's reply came too late to keep the rate.
    DeadlineMissed,
}

/// The process side of the loop.
pub trait DriverSink {
    /// Sleeps until `until` (or a stop request), handing velocity commands to
    /// `core` as they arrive.
    fn wait_until(&mut self, until: Instant, core: &mut ScoutCore) -> anyhow::Result<()>;
    /// One cycle's messages; `si` is the state they came from, `received`
    /// when its reply was read.
    fn publish(
        &mut self,
        odom: &Odometry,
        ring: &SonarRing,
        si: &StateSi,
        received: Instant,
    ) -> anyhow::Result<()>;
    fn event(&mut self, event: DriverEvent<'_>);
    /// Health upkeep after every cycle; true = stop.
    fn idle(&mut self, status: &DriverStatus<'_>) -> bool;
}

/// The loop's counters, for health.
#[derive(Debug, Clone, Copy)]
pub struct DriverStatus<'a> {
    pub link: &'a Reconnect,
    pub connected: bool,
    /// Over every link opened so far.
    pub exchanges: LinkStats,
    pub frames: SplitterStats,
    pub core: CoreStats,
}

impl Report for DriverStatus<'_> {
    fn report(&self, h: &mut HealthReporter) {
        let (s, f, c) = (self.exchanges, self.frames, self.core);
        h.set_metric("connected", f64::from(u8::from(self.connected)));
        h.set_metric("requests", s.requests as f64);
        h.set_metric("replies", s.replies as f64);
        h.set_metric("reply_timeouts", s.timeouts as f64);
        h.set_metric("naks", s.naks as f64);
        h.set_metric("stale_replies", s.stale_replies as f64);
        h.set_metric("checksum_errors", f.checksum_errors as f64);
        h.set_metric("bad_frames", (f.bad_frames() + s.bad_replies) as f64);
        h.set_metric("garbage_bytes", f.garbage_bytes as f64);
        h.set_metric("cmds_received", c.commands_received as f64);
        h.set_metric("cmds_rejected", c.commands_rejected as f64);
        h.set_metric("cmds_clamped", c.commands_clamped as f64);
        h.set_metric("cmd_timeouts", c.command_timeouts as f64);
    }
}

pub struct Driver {
    pub core: ScoutCore,
    cfg: DriverConfig,
    reply_timeout: Duration,
    link: Option<Link>,
    reconnect: Reconnect,
    /// Counters of links already closed (a reconnect opens a fresh `Link`).
    closed: LinkStats,
    closed_frames: SplitterStats,
    last_ok: Instant,
}

impl Driver {
    pub fn new(core: ScoutCore, cfg: DriverConfig) -> Self {
        let reconnect = Reconnect::new(cfg.reconnect_policy(), monotonic_now_ns());
        Self {
            core,
            reply_timeout: reply_timeout(cfg.period, cfg.baud, cfg.link_timeout),
            cfg,
            link: None,
            reconnect,
            closed: LinkStats::default(),
            closed_frames: SplitterStats::default(),
            last_ok: Instant::now(),
        }
    }

    pub fn link(&self) -> &Reconnect {
        &self.reconnect
    }

    /// Exchange and framing counters over every link opened so far.
    pub fn link_stats(&self) -> (LinkStats, SplitterStats) {
        let mut s = self.closed;
        let mut f = self.closed_frames;
        if let Some(l) = &self.link {
            s += l.stats();
            f += l.frame_stats();
        }
        (s, f)
    }

    pub fn status(&self) -> DriverStatus<'_> {
        let (exchanges, frames) = self.link_stats();
        DriverStatus {
            link: &self.reconnect,
            connected: self.link.is_some(),
            exchanges,
            frames,
            core: self.core.stats(),
        }
    }

    fn close(&mut self, why: &str, sink: &mut dyn DriverSink) {
        let (s, f) = self.link_stats();
        self.closed = s;
        self.closed_frames = f;
        self.link = None;
        self.reconnect.lost(monotonic_now_ns(), why);
        sink.event(DriverEvent::Lost(why));
    }

    /// Opens the port and configures the robot; false when it did not work.
    fn connect(&mut self) -> bool {
        let now = monotonic_now_ns();
        let mut link = match Link::open(&self.cfg.port, self.cfg.baud) {
            Ok(l) => l,
            Err(e) => {
                self.reconnect.open_failed(now, &e);
                return false;
            }
        };
        for cmd in self.core.setup_commands() {
            if let Err(e) = link.exchange(cmd, self.reply_timeout.max(Duration::from_millis(300))) {
                self.closed += link.stats();
                self.closed_frames += link.frame_stats();
                self.reconnect.open_failed(
                    monotonic_now_ns(),
                    format!("configuring the robot ({cmd:?}) failed: {e}"),
                );
                return false;
            }
        }
        self.core.on_connected();
        self.link = Some(link);
        self.last_ok = Instant::now();
        self.reconnect.opened(monotonic_now_ns());
        true
    }

    /// Runs until the sink asks to stop; leaves the robot stopped.
    pub fn run(&mut self, sink: &mut dyn DriverSink) -> anyhow::Result<()> {
        // The request goes out at `sent`; the robot samples its state as the
        // request's last byte arrives (6 bytes × 10 bits at `baud`).
        let request_wire_ns = 60 * 1_000_000_000 / u64::from(self.cfg.baud.max(1));
        let mut next_cycle = Instant::now();
        loop {
            if self.link.is_none() {
                let now = monotonic_now_ns();
                if !(self.reconnect.due(now) && self.connect()) {
                    let wait = self.reconnect.wait(monotonic_now_ns());
                    sink.wait_until(Instant::now() + wait, &mut self.core)?;
                    if sink.idle(&self.status()) {
                        break;
                    }
                    continue;
                }
                sink.event(DriverEvent::Connected {
                    first: self.reconnect.counters().opens == 1,
                });
                next_cycle = Instant::now();
            }
            sink.wait_until(next_cycle, &mut self.core)?;
            if sink.idle(&self.status()) {
                break;
            }
            let request = self.core.next_request(monotonic_now_ns());
            let sent = monotonic_now_ns();
            let Some(link) = self.link.as_mut() else {
                continue;
            };
            match link.exchange(request, self.reply_timeout) {
                Ok(state) => {
                    let got = Instant::now();
                    let si = self.core.config().drive.state_si(&state);
                    let (odom, ring) = self.core.on_state(&si, sent + request_wire_ns);
                    sink.publish(&odom, &ring, &si, got)?;
                    self.last_ok = got;
                }
                Err(e) if e.is_fatal() => self.close(&e.to_string(), sink),
                Err(e) => {
                    if matches!(e, LinkError::Nak) {
                        tracing::debug!("{request:?} refused");
                    }
                    if self.last_ok.elapsed() > self.cfg.link_timeout {
                        let why = format!("no reply for {:?} ({e})", self.cfg.link_timeout);
                        self.close(&why, sink);
                    }
                }
            }
            next_cycle += self.cfg.period;
            let now = Instant::now();
            if next_cycle < now {
                // A slow reply (or none) ate the cycle: start the next one now
                // rather than bursting to catch up.
                if self.link.is_some() {
                    sink.event(DriverEvent::DeadlineMissed);
                }
                next_cycle = now;
            }
        }
        // Leave the robot stopped, not driving on its last command until the
        // robot-side watchdog notices.
        if let Some(link) = self.link.as_mut() {
            match link.exchange(Command::Stop, self.reply_timeout) {
                Ok(_) => tracing::info!("robot stopped"),
                Err(e) => tracing::warn!("could not stop the robot on exit: {e}"),
            }
        }
        Ok(())
    }
}
