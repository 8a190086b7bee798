//! The ARCOS session, as a pure state machine: decoded packets and the time
//! in, commands to send and events out. The process owns the port and the
//! clock; this owns the protocol logic.
//!
//! - SYNC0 → SYNC1 → SYNC2 with a reply timeout each; a wrong reply restarts
//!   at SYNC0 (ARIA does the same).
//! - A SIP during the handshake means a previous client left the session open
//!   (rosaria #36): send CLOSE, let the stream drain, start again.
//! - Two silent SYNC tries in a row: send CLOSE as well (a controller that is
//!   connected but not open takes our SYNC0 for a PULSE and stays quiet).
//! - After SYNC2: OPEN, ENABLE, SONAR, optionally SETO, CONFIG; the first SIP
//!   means running.
//! - Running: no SIP for `link_timeout` → link lost, handshake again. Velocity
//!   targets go out as VEL/RVEL when they change and are refreshed every
//!   `refresh`; otherwise a PULSE keeps the firmware watchdog fed.

use smokenav_pioneer_codec::sip::{SIP_MOVING, SIP_STOPPED};
use smokenav_pioneer_codec::{
    Command, ConfigPacket, RobotIdent, RobotPacket, RobotParams, Sip, UnknownSubclass,
    decode_robot_packet, params_for,
};
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct SessionConfig {
    /// Wait this long for each SYNC reply.
    pub sync_timeout: Duration,
    /// After a CLOSE, ignore the stream this long before SYNC0 again.
    pub close_settle: Duration,
    /// No SIP for this long: the link is lost.
    pub link_timeout: Duration,
    /// Send VEL/RVEL (or PULSE when stopped) at least this often; below the
    /// firmware watchdog (2 s on a P3-DX).
    pub refresh: Duration,
    /// Use this subclass's factors instead of the one SYNC2 reports.
    pub subclass_override: Option<String>,
    pub enable_motors: bool,
    pub sonar: bool,
    pub reset_odometry: bool,
    pub request_config: bool,
}

impl Default for SessionConfig {
    fn default() -> Self {
        Self {
            sync_timeout: Duration::from_millis(300),
            close_settle: Duration::from_millis(300),
            link_timeout: Duration::from_secs(1),
            refresh: Duration::from_millis(500),
            subclass_override: None,
            enable_motors: true,
            sonar: true,
            reset_odometry: false,
            request_config: true,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Waiting for the reply to SYNC`seq`, sent at `sent_ns`.
    Syncing {
        seq: u8,
        sent_ns: u64,
    },
    /// CLOSE sent; SYNC0 again at `until_ns`.
    Closing {
        until_ns: u64,
    },
    /// OPEN sent at `since_ns`; waiting for the first SIP.
    Opening {
        since_ns: u64,
    },
    Running,
    /// A configuration problem no retry can fix (unknown subclass).
    Failed,
}

#[derive(Debug, Clone, PartialEq)]
pub enum SessionEvent {
    /// SYNC2 answered; `params` are the factors in use from now on.
    Connected {
        ident: RobotIdent,
        params: RobotParams,
    },
    /// The first SIP after OPEN.
    Running,
    Sip(Sip),
    Config(Box<ConfigPacket>),
    /// A SIP arrived during the handshake: the old session was closed.
    StaleSessionClosed,
    LinkLost {
        reason: &'static str,
    },
    Fatal(UnknownSubclass),
    /// A packet that did not decode (checksum was fine).
    Undecodable {
        packet_type: u8,
        error: String,
    },
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SessionCounters {
    pub handshakes: u64,
    pub sync_timeouts: u64,
    pub sync_restarts: u64,
    pub stale_sessions_closed: u64,
    pub links_lost: u64,
    pub sips: u64,
    pub unexpected_packets: u64,
    pub undecodable: u64,
    pub commands_sent: u64,
    pub pulses: u64,
    /// E_STOPs sent because the controller went silent.
    pub estops: u64,
}

/// Velocity target in ARCOS units: VEL mm/s, RVEL deg/s.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct VelocityTarget {
    pub vel: i16,
    pub rvel: i16,
}

pub struct Session {
    cfg: SessionConfig,
    phase: Phase,
    last_tx_ns: u64,
    last_sip_ns: u64,
    /// What the robot was last told, and when.
    sent: Option<(VelocityTarget, u64)>,
    target: VelocityTarget,
    /// E_STOP goes out with the next zero target (the controller died).
    estop_pending: bool,
    silent_tries: u32,
    counters: SessionCounters,
}

fn ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

impl Session {
    pub fn new(cfg: SessionConfig) -> Self {
        Self {
            cfg,
            phase: Phase::Syncing { seq: 0, sent_ns: 0 },
            last_tx_ns: 0,
            last_sip_ns: 0,
            sent: None,
            target: VelocityTarget::default(),
            estop_pending: false,
            silent_tries: 0,
            counters: SessionCounters::default(),
        }
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    pub fn is_running(&self) -> bool {
        self.phase == Phase::Running
    }

    pub fn counters(&self) -> SessionCounters {
        self.counters
    }

    /// The velocity the robot should have; sent on the next [`Session::poll`].
    pub fn set_target(&mut self, t: VelocityTarget) {
        self.target = t;
        if t != VelocityTarget::default() {
            self.estop_pending = false;
        }
    }

    /// Stop as hard as the robot can (ARCOS E_STOP, which overrides the
    /// deceleration) if it is moving, then hold a zero target.
    pub fn emergency_stop(&mut self) {
        self.target = VelocityTarget::default();
        self.estop_pending = true;
    }

    fn tx(&mut self, c: Command<'static>, now: u64, out: &mut impl FnMut(Command<'static>)) {
        out(c);
        self.last_tx_ns = now;
        self.counters.commands_sent += 1;
    }

    /// (Re)starts the handshake: after opening the port or losing the link.
    pub fn restart(&mut self, now: u64, out: &mut impl FnMut(Command<'static>)) {
        if self.phase == Phase::Failed {
            return;
        }
        self.counters.handshakes += 1;
        self.sent = None;
        self.phase = Phase::Syncing {
            seq: 0,
            sent_ns: now,
        };
        self.tx(Command::Sync0, now, out);
    }

    /// Handles one checked payload from the robot.
    pub fn on_payload(
        &mut self,
        payload: &[u8],
        now: u64,
        out: &mut impl FnMut(Command<'static>),
        ev: &mut impl FnMut(SessionEvent),
    ) {
        let ptype = payload.first().copied().unwrap_or(0);
        match self.phase {
            Phase::Failed | Phase::Closing { .. } => {}
            Phase::Syncing { seq, .. } => self.on_sync_reply(payload, seq, now, out, ev),
            Phase::Opening { .. } | Phase::Running => match decode_robot_packet(payload) {
                Ok(RobotPacket::Sip(s)) => {
                    self.last_sip_ns = now;
                    self.counters.sips += 1;
                    if self.phase != Phase::Running {
                        self.phase = Phase::Running;
                        ev(SessionEvent::Running);
                    }
                    ev(SessionEvent::Sip(s));
                }
                Ok(RobotPacket::Config(c)) => ev(SessionEvent::Config(c)),
                Ok(_) => self.counters.unexpected_packets += 1,
                Err(e) => {
                    self.counters.undecodable += 1;
                    ev(SessionEvent::Undecodable {
                        packet_type: ptype,
                        error: e.to_string(),
                    });
                }
            },
        }
    }

    fn on_sync_reply(
        &mut self,
        payload: &[u8],
        seq: u8,
        now: u64,
        out: &mut impl FnMut(Command<'static>),
        ev: &mut impl FnMut(SessionEvent),
    ) {
        match payload {
            [SIP_STOPPED | SIP_MOVING, ..] => {
                // Someone left the session open.
                self.counters.stale_sessions_closed += 1;
                self.tx(Command::Close, now, out);
                self.phase = Phase::Closing {
                    until_ns: now + ns(self.cfg.close_settle),
                };
                ev(SessionEvent::StaleSessionClosed);
            }
            [s] if *s == seq && seq < 2 => {
                self.silent_tries = 0;
                let next = seq + 1;
                self.phase = Phase::Syncing {
                    seq: next,
                    sent_ns: now,
                };
                self.tx(
                    if next == 1 {
                        Command::Sync1
                    } else {
                        Command::Sync2
                    },
                    now,
                    out,
                );
            }
            [2, ..] if seq == 2 => {
                self.silent_tries = 0;
                let ident = match RobotIdent::decode(payload) {
                    Ok(id) => id,
                    Err(e) => {
                        self.counters.undecodable += 1;
                        ev(SessionEvent::Undecodable {
                            packet_type: 2,
                            error: e.to_string(),
                        });
                        self.restart_sync(now, out);
                        return;
                    }
                };
                let wanted = self
                    .cfg
                    .subclass_override
                    .clone()
                    .unwrap_or_else(|| ident.subclass.clone());
                match params_for(&wanted) {
                    Ok(p) => {
                        ev(SessionEvent::Connected { ident, params: *p });
                        self.open(now, out);
                    }
                    Err(e) => {
                        // Leave the controller closed, and stop trying.
                        self.tx(Command::Close, now, out);
                        self.phase = Phase::Failed;
                        ev(SessionEvent::Fatal(e));
                    }
                }
            }
            _ => {
                // Out of sequence (a late echo, a reply meant for an earlier try).
                self.restart_sync(now, out);
            }
        }
    }

    fn restart_sync(&mut self, now: u64, out: &mut impl FnMut(Command<'static>)) {
        self.counters.sync_restarts += 1;
        self.phase = Phase::Syncing {
            seq: 0,
            sent_ns: now,
        };
        self.tx(Command::Sync0, now, out);
    }

    fn open(&mut self, now: u64, out: &mut impl FnMut(Command<'static>)) {
        self.tx(Command::Open, now, out);
        if self.cfg.enable_motors {
            self.tx(Command::Enable(true), now, out);
        }
        self.tx(Command::Sonar(self.cfg.sonar), now, out);
        if self.cfg.reset_odometry {
            self.tx(Command::ResetOdometry, now, out);
        }
        if self.cfg.request_config {
            self.tx(Command::Config, now, out);
        }
        self.sent = None;
        self.last_sip_ns = now;
        self.phase = Phase::Opening { since_ns: now };
    }

    /// Timeouts, keep-alive and velocity updates. Call at least at
    /// [`Session::next_deadline`] and after every [`Session::set_target`].
    pub fn poll(
        &mut self,
        now: u64,
        out: &mut impl FnMut(Command<'static>),
        ev: &mut impl FnMut(SessionEvent),
    ) {
        match self.phase {
            Phase::Failed => {}
            Phase::Syncing { sent_ns, .. } => {
                if now.saturating_sub(sent_ns) >= ns(self.cfg.sync_timeout) {
                    self.counters.sync_timeouts += 1;
                    self.silent_tries += 1;
                    if self.silent_tries.is_multiple_of(2) {
                        // Connected-but-not-open controllers ignore SYNC0.
                        self.tx(Command::Close, now, out);
                    }
                    self.phase = Phase::Syncing {
                        seq: 0,
                        sent_ns: now,
                    };
                    self.tx(Command::Sync0, now, out);
                }
            }
            Phase::Closing { until_ns } => {
                if now >= until_ns {
                    self.phase = Phase::Syncing {
                        seq: 0,
                        sent_ns: now,
                    };
                    self.tx(Command::Sync0, now, out);
                }
            }
            Phase::Opening { .. } | Phase::Running => {
                if now.saturating_sub(self.last_sip_ns) >= ns(self.cfg.link_timeout) {
                    self.counters.links_lost += 1;
                    ev(SessionEvent::LinkLost {
                        reason: if self.phase == Phase::Running {
                            "no SIP within the link timeout"
                        } else {
                            "no SIP after OPEN"
                        },
                    });
                    self.restart(now, out);
                    return;
                }
                self.drive(now, out);
            }
        }
    }

    fn drive(&mut self, now: u64, out: &mut impl FnMut(Command<'static>)) {
        let refresh = ns(self.cfg.refresh);
        let due = match self.sent {
            None => true,
            Some((t, at)) => {
                t != self.target
                    || (t != VelocityTarget::default() && now.saturating_sub(at) >= refresh)
            }
        };
        if due {
            let t = self.target;
            let moving = self
                .sent
                .is_some_and(|(s, _)| s != VelocityTarget::default());
            if std::mem::take(&mut self.estop_pending) && moving {
                self.counters.estops += 1;
                self.tx(Command::EStop, now, out);
            }
            self.tx(Command::Vel(t.vel), now, out);
            self.tx(Command::RVel(t.rvel), now, out);
            self.sent = Some((t, now));
        } else if now.saturating_sub(self.last_tx_ns) >= refresh {
            self.counters.pulses += 1;
            self.tx(Command::Pulse, now, out);
        }
    }

    /// When [`Session::poll`] must run next (ns).
    pub fn next_deadline(&self, now: u64) -> u64 {
        let refresh = ns(self.cfg.refresh);
        match self.phase {
            Phase::Failed => now + refresh,
            Phase::Syncing { sent_ns, .. } => sent_ns + ns(self.cfg.sync_timeout),
            Phase::Closing { until_ns } => until_ns,
            Phase::Opening { .. } | Phase::Running => {
                let link = self.last_sip_ns + ns(self.cfg.link_timeout);
                let motion = match self.sent {
                    None => now,
                    Some((t, at)) if t != self.target => now.min(at),
                    Some((t, at)) if t != VelocityTarget::default() => at + refresh,
                    Some(_) => self.last_tx_ns + refresh,
                };
                link.min(motion.max(now))
            }
        }
    }

    /// Shutdown: stop and close the session (the motors are disabled by CLOSE).
    pub fn close(&mut self, now: u64, out: &mut impl FnMut(Command<'static>)) {
        if matches!(self.phase, Phase::Running | Phase::Opening { .. }) {
            self.tx(Command::Vel(0), now, out);
            self.tx(Command::RVel(0), now, out);
        }
        self.tx(Command::Close, now, out);
        if self.phase != Phase::Failed {
            self.phase = Phase::Closing { until_ns: u64::MAX };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_pioneer_codec::PacketBuf;
    use smokenav_pioneer_codec::sip::SIP_STOPPED;

    const MS: u64 = 1_000_000;

    #[derive(Default)]
    struct Out {
        sent: Vec<Command<'static>>,
        events: Vec<SessionEvent>,
    }

    fn payload(bytes: &[u8]) -> Vec<u8> {
        bytes.to_vec()
    }

    fn sip_payload() -> Vec<u8> {
        let s = Sip {
            packet_type: SIP_STOPPED,
            ..Default::default()
        };
        let mut p = PacketBuf::new();
        s.encode(&mut p).unwrap();
        p.payload().to_vec()
    }

    fn ident(sub: &str) -> Vec<u8> {
        let mut p = PacketBuf::new();
        RobotIdent::new("AMRISim", "Pioneer", sub)
            .encode(&mut p)
            .unwrap();
        p.payload().to_vec()
    }

    impl Out {
        fn feed(&mut self, s: &mut Session, p: &[u8], now: u64) {
            let (sent, events) = (&mut self.sent, &mut self.events);
            s.on_payload(p, now, &mut |c| sent.push(c), &mut |e| events.push(e));
        }
        fn poll(&mut self, s: &mut Session, now: u64) {
            let (sent, events) = (&mut self.sent, &mut self.events);
            s.poll(now, &mut |c| sent.push(c), &mut |e| events.push(e));
        }
        fn take(&mut self) -> Vec<Command<'static>> {
            std::mem::take(&mut self.sent)
        }
    }

    fn connected(cfg: SessionConfig) -> (Session, Out) {
        let mut s = Session::new(cfg);
        let mut o = Out::default();
        s.restart(0, &mut |c| o.sent.push(c));
        o.feed(&mut s, &payload(&[0]), MS);
        o.feed(&mut s, &payload(&[1]), 2 * MS);
        o.feed(&mut s, &ident("p3dx"), 3 * MS);
        o.feed(&mut s, &sip_payload(), 50 * MS);
        o.take();
        o.events.clear();
        (s, o)
    }

    #[test]
    fn handshake_then_open_enable_sonar_config() {
        let mut s = Session::new(SessionConfig::default());
        let mut o = Out::default();
        s.restart(0, &mut |c| o.sent.push(c));
        o.feed(&mut s, &[0], MS);
        o.feed(&mut s, &[1], 2 * MS);
        o.feed(&mut s, &ident("p3dx"), 3 * MS);
        assert_eq!(
            o.take(),
            [
                Command::Sync0,
                Command::Sync1,
                Command::Sync2,
                Command::Open,
                Command::Enable(true),
                Command::Sonar(true),
                Command::Config
            ]
        );
        match &o.events[0] {
            SessionEvent::Connected { params, ident } => {
                assert_eq!(params.dist_conv, 0.485);
                assert_eq!(ident.name, "AMRISim");
            }
            e => panic!("{e:?}"),
        }
        o.feed(&mut s, &sip_payload(), 100 * MS);
        assert!(s.is_running());
        assert!(matches!(o.events[1], SessionEvent::Running));
        assert!(matches!(o.events[2], SessionEvent::Sip(_)));
    }

    #[test]
    fn sip_during_sync_closes_the_stale_session_and_retries() {
        let mut s = Session::new(SessionConfig::default());
        let mut o = Out::default();
        s.restart(0, &mut |c| o.sent.push(c));
        o.feed(&mut s, &sip_payload(), 10 * MS);
        assert_eq!(o.take(), [Command::Sync0, Command::Close]);
        assert!(matches!(o.events[0], SessionEvent::StaleSessionClosed));
        // SIPs still draining are ignored during the settle time.
        o.feed(&mut s, &sip_payload(), 100 * MS);
        o.poll(&mut s, 200 * MS);
        assert!(o.take().is_empty());
        o.poll(&mut s, 310 * MS);
        assert_eq!(o.take(), [Command::Sync0]);
        assert_eq!(s.counters().stale_sessions_closed, 1);
    }

    #[test]
    fn silent_sync_retries_and_closes_every_second_try() {
        let mut s = Session::new(SessionConfig::default());
        let mut o = Out::default();
        s.restart(0, &mut |c| o.sent.push(c));
        o.poll(&mut s, 300 * MS);
        o.poll(&mut s, 600 * MS);
        assert_eq!(
            o.take(),
            [
                Command::Sync0,
                Command::Sync0,
                Command::Close,
                Command::Sync0
            ]
        );
        assert_eq!(s.counters().sync_timeouts, 2);
    }

    #[test]
    fn out_of_order_echo_restarts_at_sync0() {
        let mut s = Session::new(SessionConfig::default());
        let mut o = Out::default();
        s.restart(0, &mut |c| o.sent.push(c));
        o.feed(&mut s, &[1], MS);
        assert_eq!(o.take(), [Command::Sync0, Command::Sync0]);
        assert_eq!(
            s.phase(),
            Phase::Syncing {
                seq: 0,
                sent_ns: MS
            }
        );
    }

    #[test]
    fn unknown_subclass_is_fatal_unless_overridden() {
        let mut s = Session::new(SessionConfig::default());
        let mut o = Out::default();
        s.restart(0, &mut |c| o.sent.push(c));
        o.feed(&mut s, &[0], MS);
        o.feed(&mut s, &[1], MS);
        o.feed(&mut s, &ident("box"), MS);
        assert_eq!(s.phase(), Phase::Failed);
        assert!(matches!(&o.events[0], SessionEvent::Fatal(e) if e.subclass == "box"));
        assert_eq!(o.take().last(), Some(&Command::Close));

        let mut s = Session::new(SessionConfig {
            subclass_override: Some("p3dx-sh".into()),
            ..Default::default()
        });
        let mut o = Out::default();
        s.restart(0, &mut |c| o.sent.push(c));
        o.feed(&mut s, &[0], MS);
        o.feed(&mut s, &[1], MS);
        o.feed(&mut s, &ident("box"), MS);
        assert!(
            matches!(&o.events[0], SessionEvent::Connected { params, .. } if params.dist_conv == 1.0)
        );
    }

    #[test]
    fn target_changes_go_out_as_vel_and_rvel_and_zero_is_not_repeated() {
        let (mut s, mut o) = connected(SessionConfig::default());
        o.poll(&mut s, 60 * MS);
        // First poll after OPEN states zero explicitly.
        assert_eq!(o.take(), [Command::Vel(0), Command::RVel(0)]);
        s.set_target(VelocityTarget {
            vel: 300,
            rvel: -20,
        });
        o.poll(&mut s, 70 * MS);
        assert_eq!(o.take(), [Command::Vel(300), Command::RVel(-20)]);
        // Unchanged non-zero target: refreshed every 500 ms.
        o.feed(&mut s, &sip_payload(), 500 * MS);
        o.poll(&mut s, 500 * MS);
        assert!(o.take().is_empty());
        o.poll(&mut s, 570 * MS);
        assert_eq!(o.take(), [Command::Vel(300), Command::RVel(-20)]);
        // Zero: sent once, then only PULSEs.
        s.set_target(VelocityTarget::default());
        o.poll(&mut s, 600 * MS);
        assert_eq!(o.take(), [Command::Vel(0), Command::RVel(0)]);
        o.feed(&mut s, &sip_payload(), 1000 * MS);
        o.poll(&mut s, 1100 * MS);
        assert_eq!(o.take(), [Command::Pulse]);
    }

    #[test]
    fn a_dead_controller_gets_one_estop_and_a_normal_stop_none() {
        let (mut s, mut o) = connected(SessionConfig::default());
        o.poll(&mut s, 60 * MS);
        o.take();
        let drive = VelocityTarget { vel: 300, rvel: 0 };
        s.set_target(drive);
        o.poll(&mut s, 70 * MS);
        o.take();
        s.emergency_stop();
        o.poll(&mut s, 80 * MS);
        assert_eq!(
            o.take(),
            [Command::EStop, Command::Vel(0), Command::RVel(0)]
        );
        // Held at zero without repeating E_STOP.
        s.set_target(VelocityTarget::default());
        o.feed(&mut s, &sip_payload(), 500 * MS);
        o.poll(&mut s, 600 * MS);
        assert_eq!(o.take(), [Command::Pulse]);
        assert_eq!(s.counters().estops, 1);
        // Standing still, a dead controller needs no E_STOP; a commanded
        // stop ramps down as the robot is configured to.
        s.emergency_stop();
        o.poll(&mut s, 700 * MS);
        assert!(!o.take().contains(&Command::EStop));
        s.set_target(drive);
        o.poll(&mut s, 800 * MS);
        o.take();
        s.set_target(VelocityTarget::default());
        o.poll(&mut s, 900 * MS);
        assert_eq!(o.take(), [Command::Vel(0), Command::RVel(0)]);
        assert_eq!(s.counters().estops, 1);
    }

    #[test]
    fn no_sip_for_link_timeout_restarts_handshake() {
        let (mut s, mut o) = connected(SessionConfig::default());
        o.poll(&mut s, 60 * MS);
        o.take();
        o.poll(&mut s, 1060 * MS);
        assert!(matches!(
            o.events.last(),
            Some(SessionEvent::LinkLost { .. })
        ));
        assert_eq!(o.take(), [Command::Sync0]);
        assert_eq!(s.counters().links_lost, 1);
    }

    #[test]
    fn close_stops_then_closes() {
        let (mut s, mut o) = connected(SessionConfig::default());
        s.close(60 * MS, &mut |c| o.sent.push(c));
        assert_eq!(
            o.take(),
            [Command::Vel(0), Command::RVel(0), Command::Close]
        );
    }

    #[test]
    fn deadline_tracks_the_next_thing_to_do() {
        let (mut s, mut o) = connected(SessionConfig::default());
        assert_eq!(s.next_deadline(60 * MS), 60 * MS);
        o.poll(&mut s, 60 * MS);
        // Stopped: next PULSE at 60 + 500 ms; link timeout at 50 + 1000.
        assert_eq!(s.next_deadline(61 * MS), 560 * MS);
    }
}
