//! The pure Pioneer driver: bytes from the controller and velocity
//! commands in (with the time), bytes to send and bus messages out.
//!
//! It composes the ARCOS [`Session`] state machine, the [`MotionGuard`]
//! (limits, stop on command timeout), the codec's packet framer and odometry
//! integrator and the [`SonarAssembler`]. No port, no bus, no clock: the
//! loop in [`crate::driver`] owns those.

use crate::messages::{self, SonarAssembler, SonarCounters, SonarGeometry};
use crate::motion::{MotionCounters, MotionGuard, MotionLimits};
use crate::session::{Session, SessionConfig, SessionCounters, SessionEvent};
use smokenav_pioneer_codec::{Command, Framer, FramerStats, OdometryIntegrator, PacketBuf, Sip};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_runtime::{HealthReporter, Report};
use smokenav_shared_types::{Header, Odometry, SonarRing};
use std::time::Duration;

/// Frame id of the sonar rings (the transducer poses are in the base frame).
pub const SONAR_FRAME: &str = "base_link";

/// What the core produced for the process.
#[derive(Debug, Clone)]
pub enum Output {
    Odometry(Odometry),
    Sonar(Box<SonarRing>),
    /// Everything else the session reported (connected, running, config, link lost, …).
    Event(Box<SessionEvent>),
}

/// Counters of every part, for health.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CoreCounters {
    pub running: bool,
    pub framer: FramerStats,
    pub session: SessionCounters,
    pub motion: MotionCounters,
    pub sonar: SonarCounters,
    /// The latest SIP's robot state.
    pub last_sip: Option<SipStatus>,
}

/// The robot state one SIP reports, for health.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SipStatus {
    pub battery_v: f64,
    pub motors_enabled: bool,
    pub estop: bool,
    pub stall_left: bool,
    pub stall_right: bool,
    pub bumpers_front: u8,
    pub bumpers_rear: u8,
}

impl SipStatus {
    fn of(sip: &Sip) -> Self {
        Self {
            battery_v: sip.battery_volts(),
            motors_enabled: sip.motors_enabled(),
            estop: sip.estop(),
            stall_left: sip.left_stall(),
            stall_right: sip.right_stall(),
            bumpers_front: sip.front_bumpers(),
            bumpers_rear: sip.rear_bumpers(),
        }
    }
}

impl Report for CoreCounters {
    fn report(&self, h: &mut HealthReporter) {
        let (f, s, m) = (self.framer, self.session, self.motion);
        h.set_metric("connected", f64::from(u8::from(self.running)));
        h.set_metric("checksum_errors", f.checksum_errors as f64);
        h.set_metric("bad_counts", f.bad_counts as f64);
        h.set_metric("discarded_bytes", f.discarded_bytes as f64);
        h.set_metric("links_lost", s.links_lost as f64);
        h.set_metric("sync_timeouts", s.sync_timeouts as f64);
        h.set_metric("stale_sessions_closed", s.stale_sessions_closed as f64);
        h.set_metric("cmd_received", m.commands as f64);
        h.set_metric("cmd_timeouts", m.timeouts as f64);
        h.set_metric("cmd_rejected", m.rejected as f64);
        h.set_metric("sonar_saturated", self.sonar.saturated as f64);
        if let Some(sip) = self.last_sip {
            let flag = |b: bool| f64::from(u8::from(b));
            h.set_metric("battery_v", sip.battery_v);
            h.set_metric("motors_enabled", flag(sip.motors_enabled));
            h.set_metric("estop", flag(sip.estop));
            h.set_metric("stall_left", flag(sip.stall_left));
            h.set_metric("stall_right", flag(sip.stall_right));
            h.set_metric("bumpers_front", f64::from(sip.bumpers_front));
            h.set_metric("bumpers_rear", f64::from(sip.bumpers_rear));
        }
    }
}

pub struct PioneerCore {
    framer: Framer,
    session: Session,
    guard: MotionGuard,
    /// A silent controller gets E_STOP, not a ramp (`estop_on_timeout`).
    estop_on_timeout: bool,
    odometry: Option<OdometryIntegrator>,
    sonar: SonarAssembler,
    odom_frame: String,
    last_sip: Option<SipStatus>,
    /// Reused: commands and events of one step.
    commands: Vec<Command<'static>>,
    events: Vec<SessionEvent>,
    packet: PacketBuf,
}

fn secs(s: f64) -> Duration {
    Duration::from_secs_f64(s.max(0.0))
}

impl PioneerCore {
    /// The core a robot profile describes: `[base]` (timeouts, limits,
    /// `[base.pioneer]` options) and the `[sonar]` transducers it lists.
    pub fn from_profile(cfg: &RobotConfig) -> Self {
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
        let sonar = SonarGeometry {
            indices: cfg.sonar.transducers.iter().map(|t| t.index).collect(),
            max_range_m: cfg.sonar.max_range_m as f32,
            min_range_m: cfg.sonar.min_range_m as f32,
        };
        Self::new(session, guard, sonar, &cfg.base.odom_frame)
            .with_estop_on_timeout(opts.estop_on_timeout)
    }

    /// Whether a silent controller gets E_STOP (default) or a plain zero
    /// target that ramps down at the robot's deceleration.
    pub fn with_estop_on_timeout(mut self, on: bool) -> Self {
        self.estop_on_timeout = on;
        self
    }

    pub fn new(
        session: Session,
        guard: MotionGuard,
        sonar: SonarGeometry,
        odom_frame: &str,
    ) -> Self {
        Self {
            framer: Framer::new(),
            session,
            guard,
            estop_on_timeout: true,
            odometry: None,
            sonar: SonarAssembler::new(sonar, 1.0),
            odom_frame: odom_frame.to_owned(),
            last_sip: None,
            commands: Vec::with_capacity(16),
            events: Vec::with_capacity(16),
            packet: PacketBuf::new(),
        }
    }

    pub fn counters(&self) -> CoreCounters {
        CoreCounters {
            running: self.session.is_running(),
            framer: self.framer.stats(),
            session: self.session.counters(),
            motion: self.guard.counters(),
            sonar: self.sonar.counters(),
            last_sip: self.last_sip,
        }
    }

    pub fn session(&self) -> &Session {
        &self.session
    }

    /// A port was (re)opened at `now`: start the handshake from scratch.
    pub fn link_up(&mut self, now: u64) {
        self.framer.clear();
        self.sonar.clear();
        let cmds = &mut self.commands;
        self.session.restart(now, &mut |c| cmds.push(c));
    }

    /// A velocity command from the bus, received at `now`.
    pub fn on_velocity(&mut self, linear_mps: f64, angular_rps: f64, now: u64) {
        self.guard.command(linear_mps, angular_rps, now);
    }

    /// Timeouts, keep-alive and the velocity target, at `now` (`link`: a port is open).
    pub fn poll(&mut self, now: u64, link: bool) {
        let target = self.guard.target(now);
        if self.guard.take_timeout() && self.estop_on_timeout {
            self.session.emergency_stop();
        } else {
            self.session.set_target(target);
        }
        if link {
            let (cmds, evs) = (&mut self.commands, &mut self.events);
            self.session
                .poll(now, &mut |c| cmds.push(c), &mut |e| evs.push(e));
        }
    }

    /// Bytes read from the controller at `now`.
    pub fn on_bytes(&mut self, bytes: &[u8], now: u64) {
        let Self {
            framer,
            session,
            commands,
            events,
            ..
        } = self;
        framer.feed(bytes, |r| match r {
            Ok(payload) => session.on_payload(payload, now, &mut |c| commands.push(c), &mut |e| {
                events.push(e)
            }),
            Err(e) => tracing::debug!("dropped a packet: {e}"),
        });
    }

    /// Stop, then CLOSE: queued for [`PioneerCore::send`] on the way out.
    pub fn close(&mut self, now: u64) {
        let cmds = &mut self.commands;
        self.session.close(now, &mut |c| cmds.push(c));
    }

    /// When the core next needs [`PioneerCore::poll`] (ns).
    pub fn next_deadline(&self, now: u64) -> u64 {
        let mut deadline = self.session.next_deadline(now);
        if let Some(t) = self.guard.expires_at() {
            deadline = deadline.min(t);
        }
        deadline
    }

    /// Encodes the queued commands and hands each packet to `write`; stops
    /// at the first write error (the link is gone) and drops the rest.
    pub fn send(
        &mut self,
        mut write: impl FnMut(&[u8]) -> std::io::Result<()>,
    ) -> std::io::Result<()> {
        let mut result = Ok(());
        for c in self.commands.drain(..) {
            if let Err(e) = c.encode(&mut self.packet) {
                tracing::error!("cannot encode {c:?}: {e}");
                continue;
            }
            if let Err(e) = write(self.packet.as_bytes()) {
                result = Err(e);
                break;
            }
        }
        self.commands.clear();
        result
    }

    /// Turns what the session reported into messages, stamped `now`.
    pub fn drain(&mut self, now: u64, emit: &mut impl FnMut(Output)) {
        let mut events = std::mem::take(&mut self.events);
        for ev in events.drain(..) {
            match ev {
                SessionEvent::Connected { params, .. } => {
                    match &mut self.odometry {
                        // Same pose, new baseline: a reconnect does not move the robot.
                        Some(o) => o.set_params(params),
                        None => self.odometry = Some(OdometryIntegrator::new(params)),
                    }
                    self.sonar.set_range_conv(params.range_conv);
                    self.sonar.clear();
                    emit(Output::Event(Box::new(ev)));
                }
                SessionEvent::Sip(sip) => {
                    self.last_sip = Some(SipStatus::of(&sip));
                    if let Some(o) = &mut self.odometry {
                        let est = o.update(&sip);
                        // The first message after (re)connecting: consumers must
                        // expect the pose to have jumped (motion while the link
                        // was down is not in it).
                        let msg =
                            messages::odometry(&est, &sip, now, 0, &self.odom_frame, est.baseline);
                        emit(Output::Odometry(msg));
                    }
                    self.sonar
                        .add(sip.sonars.as_slice(), now, &mut |mut ring: SonarRing| {
                            ring.header = Header::new(ring.header.stamp_ns, 0, SONAR_FRAME);
                            emit(Output::Sonar(Box::new(ring)));
                        });
                }
                other => emit(Output::Event(Box::new(other))),
            }
        }
        self.events = events;
    }
}
