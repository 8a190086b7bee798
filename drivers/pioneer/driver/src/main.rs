//! `smokenav-pioneer`: the Pioneer driver process.
//!
//! Thin wiring: open the port (serial device or `tcp://host:port` for
//! MobileSim/AMRISim) → ARCOS session (handshake, stale-session recovery) →
//! SIPs to `base/odom` and `base/sonar`; `base/cmd_vel` to VEL/RVEL with a stop
//! when commands stop arriving; CLOSE on shutdown; reopen the port when the
//! link is lost.
//!
//! One thread: it sleeps in `poll()` on the port until data, the session's
//! next deadline, or at most [`MAX_WAIT`] (the bus cannot share that poll), so
//! a velocity command is picked up within that time.

use anyhow::Context;
use clap::Parser;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use smokenav_pioneer_codec::{Command, Framer, OdometryIntegrator, PacketBuf};
use smokenav_pioneer_driver::messages::{self, SonarAssembler, SonarGeometry};
use smokenav_pioneer_driver::motion::{MotionGuard, MotionLimits};
use smokenav_pioneer_driver::port::{Link, PortSpec, parse_port};
use smokenav_pioneer_driver::session::{Session, SessionConfig, SessionEvent};
use smokenav_platform_bus::{Publisher, Subscriber, topics};
use smokenav_platform_runtime::{CommonArgs, HealthReporter, Process};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{Header, HealthState, Odometry, SonarRing, VelocityCommand};
use std::process::ExitCode;
use std::time::Duration;

const ROLE: &str = "pioneer";
/// Longest sleep: bounds how late a velocity command is seen.
const MAX_WAIT: Duration = Duration::from_millis(25);
/// Between attempts to reopen a lost port.
const REOPEN_INTERVAL: Duration = Duration::from_millis(200);
const SONAR_FRAME: &str = "base_link";

#[derive(Parser)]
#[command(
    version,
    about = "Pioneer (ARCOS) driver: odometry and sonar out, velocity commands in; serial or tcp://host:8101 (MobileSim)"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main(ROLE, &args.common, run)
}

fn secs(s: f64) -> Duration {
    Duration::from_secs_f64(s.max(0.0))
}

fn ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

/// Everything the loop keeps between iterations.
struct Driver {
    spec: PortSpec,
    link: Option<Link>,
    retry_at_ns: u64,
    framer: Framer,
    session: Session,
    guard: MotionGuard,
    odometry: Option<OdometryIntegrator>,
    sonar: SonarAssembler,
    odom_frame: String,
    /// Reused buffers: commands and events of one step.
    commands: Vec<Command<'static>>,
    events: Vec<SessionEvent>,
    packet: PacketBuf,
    odom_pub: Publisher<Odometry>,
    sonar_pub: Publisher<SonarRing>,
    cmd_sub: Subscriber<VelocityCommand>,
    /// Marks one SIP on the health rate (the runtime does not export `RateId`).
    mark_sip: Box<dyn Fn(&mut HealthReporter)>,
    connects: u64,
    ever_running: bool,
}

fn run(p: &mut Process) -> anyhow::Result<()> {
    let cfg = p.config.clone();
    let spec = parse_port(p.port(&cfg.base.port), cfg.base.baud)?;
    let opts = cfg.base.pioneer.clone().unwrap_or_default();
    let session = Session::new(SessionConfig {
        sync_timeout: secs(opts.sync_timeout_s),
        close_settle: Duration::from_millis(300),
        link_timeout: secs(cfg.base.link_timeout_s),
        refresh: secs(opts.refresh_s),
        subclass_override: opts.subclass.clone(),
        enable_motors: opts.enable_motors,
        sonar: opts.sonar,
        reset_odometry: opts.reset_odometry,
        request_config: true,
    });
    let guard = MotionGuard::new(
        secs(cfg.base.cmd_timeout_s),
        MotionLimits {
            max_linear_mps: cfg.base.max_linear_mps,
            max_angular_dps: cfg.base.max_angular_dps,
        },
    );
    let geometry = SonarGeometry {
        indices: cfg.sonar.transducers.iter().map(|t| t.index).collect(),
        max_range_m: cfg.sonar.max_range_m as f32,
        min_range_m: cfg.sonar.min_range_m as f32,
    };
    let mut d = Driver {
        spec,
        link: None,
        retry_at_ns: 0,
        framer: Framer::new(),
        session,
        guard,
        odometry: None,
        sonar: SonarAssembler::new(geometry, 1.0),
        odom_frame: cfg.base.odom_frame.clone(),
        commands: Vec::with_capacity(16),
        events: Vec::with_capacity(16),
        packet: PacketBuf::new(),
        odom_pub: p.bus.publisher(topics::BASE_ODOM)?,
        sonar_pub: p.bus.publisher(topics::BASE_SONAR)?,
        cmd_sub: p.bus.subscriber(topics::BASE_CMD_VEL)?,
        mark_sip: {
            let id = p.health.add_rate("sip_hz", Some(cfg.base.rate_hz));
            Box::new(move |h: &mut HealthReporter| h.mark(id))
        },
        connects: 0,
        ever_running: false,
    };
    p.status(&format!("connecting to {}", d.spec));
    let result = (|| -> anyhow::Result<()> {
        while !p.shutdown_requested() {
            d.step(p)?;
            d.report(p);
            p.tick()?;
        }
        Ok(())
    })();
    d.shutdown();
    result
}

impl Driver {
    fn step(&mut self, p: &mut Process) -> anyhow::Result<()> {
        let now = monotonic_now_ns();
        if self.link.is_none() && now >= self.retry_at_ns {
            self.connect(p, now);
        }
        // Velocity commands: all that queued up, the newest wins.
        while let Some(c) = self.cmd_sub.receive()? {
            self.guard.command(c.linear, c.angular, now);
        }
        self.session.set_target(self.guard.target(now));
        if self.link.is_some() {
            // With the port gone there is nobody to talk to; `connect`
            // restarts the handshake.
            let (cmds, evs) = (&mut self.commands, &mut self.events);
            self.session
                .poll(now, &mut |c| cmds.push(c), &mut |e| evs.push(e));
        }
        self.flush(p, now);
        self.handle_events(p, now)?;

        let mut deadline = self.session.next_deadline(now).min(now + ns(MAX_WAIT));
        if let Some(t) = self.guard.expires_at() {
            deadline = deadline.min(t);
        }
        if self.link.is_none() {
            deadline = deadline.min(self.retry_at_ns.max(now));
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
            self.read(p);
            let now = monotonic_now_ns();
            self.flush(p, now);
            self.handle_events(p, now)?;
        }
        Ok(())
    }

    fn connect(&mut self, p: &mut Process, now: u64) {
        match Link::open(&self.spec) {
            Ok(link) => {
                self.connects += 1;
                tracing::info!("opened {}", self.spec);
                self.link = Some(link);
                self.framer.clear();
                self.sonar.clear();
                let cmds = &mut self.commands;
                self.session.restart(now, &mut |c| cmds.push(c));
                p.status(&format!("handshake with {}", self.spec));
            }
            Err(e) => {
                self.retry_at_ns = now + ns(REOPEN_INTERVAL);
                if p.health.health().last_error.as_str() != e.to_string() {
                    p.health.error(&e.to_string());
                }
                if self.ever_running {
                    p.health.set_state(HealthState::Degraded);
                }
            }
        }
    }

    fn drop_link(&mut self, p: &mut Process, why: &str) {
        if self.link.take().is_some() {
            p.health
                .error(&format!("link to {} lost: {why}", self.spec));
            p.health.set_state(HealthState::Degraded);
            p.status("reconnecting");
        }
        self.retry_at_ns = monotonic_now_ns() + ns(REOPEN_INTERVAL);
    }

    fn read(&mut self, p: &mut Process) {
        let mut buf = [0u8; 512];
        let Some(link) = self.link.as_mut() else {
            return;
        };
        let n = match link.read(&mut buf) {
            Ok(0) => {
                self.drop_link(p, "the other end closed the connection");
                return;
            }
            Ok(n) => n,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return;
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => return,
            Err(e) => {
                self.drop_link(p, &e.to_string());
                return;
            }
        };
        let now = monotonic_now_ns();
        let Self {
            framer,
            session,
            commands,
            events,
            ..
        } = self;
        framer.feed(buf.get(..n).unwrap_or(&[]), |r| match r {
            Ok(payload) => session.on_payload(payload, now, &mut |c| commands.push(c), &mut |e| {
                events.push(e)
            }),
            Err(e) => tracing::debug!("dropped a packet: {e}"),
        });
    }

    /// Sends the commands the session queued.
    fn flush(&mut self, p: &mut Process, _now: u64) {
        let mut failed = None;
        for c in self.commands.drain(..) {
            let Some(link) = self.link.as_mut() else {
                break;
            };
            if let Err(e) = c.encode(&mut self.packet) {
                tracing::error!("cannot encode {c:?}: {e}");
                continue;
            }
            if let Err(e) = link.write_all(self.packet.as_bytes()) {
                failed = Some(e.to_string());
                break;
            }
        }
        self.commands.clear();
        if let Some(why) = failed {
            self.drop_link(p, &why);
        }
    }

    fn handle_events(&mut self, p: &mut Process, now: u64) -> anyhow::Result<()> {
        let mut events = std::mem::take(&mut self.events);
        for ev in events.drain(..) {
            match ev {
                SessionEvent::Connected { ident, params } => {
                    tracing::info!(
                        "connected: {} ({} {}), DistConvFactor {}",
                        ident.name,
                        ident.class,
                        ident.subclass,
                        params.dist_conv
                    );
                    match &mut self.odometry {
                        // Same pose, new baseline: a reconnect does not move the robot.
                        Some(o) => o.set_params(params),
                        None => self.odometry = Some(OdometryIntegrator::new(params)),
                    }
                    self.sonar.set_range_conv(params.range_conv);
                    self.sonar.clear();
                }
                SessionEvent::Running => {
                    let msg = format!("streaming from {}", self.spec);
                    if !self.ever_running {
                        p.ready(&msg);
                    } else {
                        tracing::info!("{msg}");
                    }
                    self.ever_running = true;
                    p.health.set_state(HealthState::Ok);
                    p.status(&msg);
                }
                SessionEvent::Sip(sip) => {
                    (self.mark_sip)(&mut p.health);
                    if let Some(o) = &mut self.odometry {
                        let est = o.update(&sip);
                        // The first message after (re)connecting: consumers must
                        // expect the pose to have jumped (motion while the link
                        // was down is not in it).
                        let msg =
                            messages::odometry(&est, &sip, now, 0, &self.odom_frame, est.baseline);
                        self.odom_pub.publish(&msg)?;
                    }
                    let pubr = &mut self.sonar_pub;
                    let mut err = None;
                    self.sonar
                        .add(sip.sonars.as_slice(), now, &mut |mut ring: SonarRing| {
                            ring.header = Header::new(ring.header.stamp_ns, 0, SONAR_FRAME);
                            if let Err(e) = pubr.publish(&ring) {
                                err = Some(e);
                            }
                        });
                    if let Some(e) = err {
                        return Err(e.into());
                    }
                    p.health.set_metric("battery_v", sip.battery_volts());
                    p.health
                        .set_metric("motors_enabled", f64::from(u8::from(sip.motors_enabled())));
                    p.health
                        .set_metric("estop", f64::from(u8::from(sip.estop())));
                    p.health
                        .set_metric("stall_left", f64::from(u8::from(sip.left_stall())));
                    p.health
                        .set_metric("stall_right", f64::from(u8::from(sip.right_stall())));
                    p.health
                        .set_metric("bumpers_front", f64::from(sip.front_bumpers()));
                    p.health
                        .set_metric("bumpers_rear", f64::from(sip.rear_bumpers()));
                }
                SessionEvent::Config(c) => {
                    tracing::info!(
                        "controller config: watchdog {} ms, SIP cycle {} ms, firmware {}",
                        c.watchdog,
                        c.sip_cycle,
                        c.firmware_version.as_deref().unwrap_or("not reported")
                    );
                    p.health
                        .set_metric("robot_watchdog_ms", f64::from(c.watchdog));
                }
                SessionEvent::StaleSessionClosed => {
                    p.health.error(
                        "a previous session was left open (SIPs during SYNC): sent CLOSE, retrying",
                    );
                }
                SessionEvent::LinkLost { reason } => {
                    p.health
                        .error(&format!("link to {}: {reason}; handshake again", self.spec));
                    p.health.set_state(HealthState::Degraded);
                    p.status("reconnecting");
                }
                SessionEvent::Undecodable { packet_type, error } => {
                    tracing::debug!("packet type 0x{packet_type:02X} did not decode: {error}");
                }
                SessionEvent::Fatal(e) => {
                    // Only a profile change fixes it: exit 78, which systemd does not restart.
                    p.health.set_state(HealthState::Error);
                    p.health.error(&e.to_string());
                    return Err(anyhow::anyhow!(smokenav_platform_runtime::ConfigFailure(
                        e.to_string()
                    )));
                }
            }
        }
        self.events = events;
        Ok(())
    }

    fn report(&self, p: &mut Process) {
        let f = self.framer.stats();
        let s = self.session.counters();
        let m = self.guard.counters();
        let sc = self.sonar.counters();
        let h = &mut p.health;
        h.set_metric("connected", f64::from(u8::from(self.session.is_running())));
        h.set_metric("checksum_errors", f.checksum_errors as f64);
        h.set_metric("bad_counts", f.bad_counts as f64);
        h.set_metric("discarded_bytes", f.discarded_bytes as f64);
        h.set_metric("port_opens", self.connects as f64);
        h.set_metric("links_lost", s.links_lost as f64);
        h.set_metric("sync_timeouts", s.sync_timeouts as f64);
        h.set_metric("stale_sessions_closed", s.stale_sessions_closed as f64);
        h.set_metric("cmd_received", m.commands as f64);
        h.set_metric("cmd_timeouts", m.timeouts as f64);
        h.set_metric("cmd_rejected", m.rejected as f64);
        h.set_metric("sonar_saturated", sc.saturated as f64);
    }

    /// Stop, then CLOSE: a robot must not be left in an open session.
    fn shutdown(&mut self) {
        let now = monotonic_now_ns();
        let cmds = &mut self.commands;
        self.session.close(now, &mut |c| cmds.push(c));
        if let Some(link) = self.link.as_mut() {
            for c in self.commands.drain(..) {
                if c.encode(&mut self.packet).is_ok()
                    && link.write_all(self.packet.as_bytes()).is_err()
                {
                    break;
                }
            }
            tracing::info!("sent CLOSE to {}", self.spec);
        }
        self.commands.clear();
    }
}
