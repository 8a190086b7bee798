//! The controller itself, without I/O: command payloads and the time in,
//! reply packets out. Time is always passed in (ns of some monotonic base).
//!
//! Behaviour follows ARCOS as ARIA and AMRISim expect it: SYNC0/1 echoed,
//! SYNC2 answered with name/class/subclass, OPEN starts SIPs every 100 ms,
//! CLOSE ends the session and disables the motors, a watchdog stops the robot
//! when no command arrived for `watchdog_ms` (a real controller stops;
//! AMRISim only warns).

use smokenav_pioneer_codec::command::{num, vel2_split};
use smokenav_pioneer_codec::odometry::normalize_angle;
use smokenav_pioneer_codec::sip::{SIP_MOVING, SIP_STOPPED, SonarSample, flag};
use smokenav_pioneer_codec::{
    Arg, ConfigPacket, PacketBuf, RobotIdent, RobotParams, Sip, decode_command, params_for,
};

/// Most transducers a ring can have here.
pub const MAX_SONARS: usize = 32;
/// Motor-model step while the wheels move or ramp, ns.
pub const MOTION_STEP_NS: u64 = 10_000_000;

/// A planar pose: mm and radians.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose {
    pub x_mm: f64,
    pub y_mm: f64,
    pub th: f64,
}

impl Pose {
    pub fn new(x_mm: f64, y_mm: f64, th: f64) -> Self {
        Self { x_mm, y_mm, th }
    }

    /// `self` expressed in the frame whose origin is `origin`.
    pub fn relative_to(&self, origin: &Pose) -> Pose {
        let (s, c) = origin.th.sin_cos();
        let dx = self.x_mm - origin.x_mm;
        let dy = self.y_mm - origin.y_mm;
        Pose {
            x_mm: c * dx + s * dy,
            y_mm: -s * dx + c * dy,
            th: normalize_angle(self.th - origin.th),
        }
    }
}

/// Which sonars each SIP carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SonarMode {
    /// Every transducer in every SIP, as AMRISim does.
    All,
    /// `per_sip` transducers per SIP, round-robin, as a real controller
    /// firing one transducer per array every 40 ms.
    Cycle { per_sip: u8 },
}

#[derive(Debug, Clone)]
pub struct RobotConfig {
    /// SYNC2 strings.
    pub name: String,
    pub class: String,
    pub subclass: String,
    /// Conversion factors to emulate when `subclass` is not in the table
    /// (MobileSim's "box", a new firmware name): the host must cope with the
    /// unknown name, the emulator still needs units. `None`: from `subclass`.
    pub factors_from: Option<String>,
    /// 8 (front array) or 16 (front and rear).
    pub sonar_count: u8,
    pub sonar_mode: SonarMode,
    /// Range reported when nothing echoes, mm (simulator: 5000).
    pub sonar_max_mm: u16,
    pub sip_period_ms: u64,
    /// 0 disables the watchdog.
    pub watchdog_ms: u16,
    /// mm/s² and deg/s². SETA/SETRA change them at run time.
    pub trans_accel: f64,
    pub trans_decel: f64,
    pub rot_accel: f64,
    pub rot_decel: f64,
    /// mm/s and deg/s; SETV/SETRV change them.
    pub max_vel: f64,
    pub max_rot_vel: f64,
    pub battery_dv: u8,
    /// Stop the SIP after the sonar readings, as older firmware does.
    pub legacy_sip: bool,
    /// Send 0x33 while moving (a real controller); AMRISim always sends 0x32.
    pub moving_type: bool,
    /// Motors on at OPEN without an ENABLE (AMRISim); a real P3-DX needs ENABLE.
    pub motors_enabled_at_open: bool,
    /// Start with a session left open by a previous client: SIPs stream
    /// before any SYNC.
    pub start_open: bool,
    pub initial_pose: Pose,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            name: "smokenav-emulator".into(),
            class: "Pioneer".into(),
            subclass: "p3dx".into(),
            factors_from: None,
            sonar_count: 16,
            sonar_mode: SonarMode::All,
            sonar_max_mm: 5000,
            sip_period_ms: 100,
            watchdog_ms: 2000,
            // Quick, symmetric ramps: a step settles in 0.3 s and a commanded
            // v for T seconds still travels v·T once stopped.
            trans_accel: 1000.0,
            trans_decel: 1000.0,
            rot_accel: 300.0,
            rot_decel: 300.0,
            max_vel: 1500.0,
            max_rot_vel: 300.0,
            battery_dv: 130,
            legacy_sip: false,
            moving_type: true,
            motors_enabled_at_open: false,
            start_open: false,
            initial_pose: Pose::default(),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Waiting for SYNC`next`.
    Handshake { next: u8 },
    /// Handshake done; commands accepted, SIPs only after OPEN.
    Connected,
}

/// Velocities: commanded by the host, or what the wheels do.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Motion {
    /// mm/s.
    pub trans: f64,
    /// deg/s, counter-clockwise positive.
    pub rot: f64,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct RobotCounters {
    /// Valid command packets, by command number.
    pub by_command: Vec<u64>,
    pub commands: u64,
    /// Command payloads that did not decode.
    pub bad_commands: u64,
    /// Commands the emulator does not implement (MOVE, HEAD, …).
    pub unsupported: u64,
    pub sips: u64,
    pub sync_replies: u64,
    /// Handshakes restarted because a SYNC came out of order.
    pub sync_restarts: u64,
    pub opens: u64,
    pub closes: u64,
    pub watchdog_trips: u64,
}

impl RobotCounters {
    pub fn count(&self, cmd: u8) -> u64 {
        self.by_command.get(usize::from(cmd)).copied().unwrap_or(0)
    }
}

/// Everything about the robot a test may want to look at.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotStatus {
    pub phase: Phase,
    pub streaming: bool,
    pub motors_enabled: bool,
    pub sonar_on: bool,
    pub commanded: Motion,
    pub actual: Motion,
    /// Wheel speeds, mm/s.
    pub left: f64,
    pub right: f64,
    /// True pose in the world.
    pub pose: Pose,
    /// What the controller's odometry says (pose relative to the last SETO).
    pub odometry: Pose,
    pub watchdog_tripped: bool,
    pub counters: RobotCounters,
    pub last_command_ns: Option<u64>,
}

/// The emulated controller.
pub struct ArcosRobot {
    cfg: RobotConfig,
    params: RobotParams,
    phase: Phase,
    streaming: bool,
    motors_enabled: bool,
    sonar_on: bool,
    estop: bool,
    commanded: Motion,
    actual: Motion,
    trans_accel: f64,
    trans_decel: f64,
    rot_accel: f64,
    rot_decel: f64,
    max_vel: f64,
    max_rot_vel: f64,
    pose: Pose,
    odom_origin: Pose,
    external_motion: bool,
    sonar_mm: [u16; MAX_SONARS],
    next_sonar: usize,
    stall_bumpers: u16,
    battery_dv: u8,
    last_tick_ns: Option<u64>,
    next_sip_ns: u64,
    last_command_ns: Option<u64>,
    watchdog_tripped: bool,
    counters: RobotCounters,
}

/// The subclass has no conversion factors: the emulator cannot report odometry.
pub use smokenav_pioneer_codec::UnknownSubclass;

impl ArcosRobot {
    pub fn new(cfg: RobotConfig) -> Result<Self, UnknownSubclass> {
        let params = *params_for(cfg.factors_from.as_deref().unwrap_or(&cfg.subclass))?;
        let mut r = Self {
            params,
            phase: Phase::Handshake { next: 0 },
            streaming: false,
            motors_enabled: false,
            sonar_on: false,
            estop: false,
            commanded: Motion::default(),
            actual: Motion::default(),
            trans_accel: cfg.trans_accel,
            trans_decel: cfg.trans_decel,
            rot_accel: cfg.rot_accel,
            rot_decel: cfg.rot_decel,
            max_vel: cfg.max_vel,
            max_rot_vel: cfg.max_rot_vel,
            pose: cfg.initial_pose,
            odom_origin: Pose::default(),
            external_motion: false,
            sonar_mm: [cfg.sonar_max_mm; MAX_SONARS],
            next_sonar: 0,
            stall_bumpers: 0,
            battery_dv: cfg.battery_dv,
            last_tick_ns: None,
            next_sip_ns: 0,
            last_command_ns: None,
            watchdog_tripped: false,
            counters: RobotCounters {
                by_command: vec![0; 256],
                ..Default::default()
            },
            cfg,
        };
        if r.cfg.start_open {
            r.open_stale_session();
        }
        Ok(r)
    }

    pub fn params(&self) -> &RobotParams {
        &self.params
    }

    pub fn config(&self) -> &RobotConfig {
        &self.cfg
    }

    /// As if a previous client crashed without CLOSE: connected, SIPs streaming.
    pub fn open_stale_session(&mut self) {
        self.phase = Phase::Connected;
        self.streaming = true;
        self.sonar_on = true;
    }

    /// The link went away (TCP client closed): like AMRISim, end the session.
    pub fn end_session(&mut self) {
        self.phase = Phase::Handshake { next: 0 };
        self.streaming = false;
        self.motors_enabled = false;
        self.commanded = Motion::default();
    }

    pub fn status(&self) -> RobotStatus {
        let (left, right) = self.wheels();
        RobotStatus {
            phase: self.phase,
            streaming: self.streaming,
            motors_enabled: self.motors_enabled,
            sonar_on: self.sonar_on,
            commanded: self.commanded,
            actual: self.actual,
            left,
            right,
            pose: self.pose,
            odometry: self.pose.relative_to(&self.odom_origin),
            watchdog_tripped: self.watchdog_tripped,
            counters: self.counters.clone(),
            last_command_ns: self.last_command_ns,
        }
    }

    pub fn set_pose(&mut self, pose: Pose) {
        self.pose = pose;
    }

    /// When true, the owner moves the robot with [`ArcosRobot::set_pose`] and
    /// the emulator only reports; its own integration is off.
    pub fn set_external_motion(&mut self, on: bool) {
        self.external_motion = on;
    }

    /// Sets the range a transducer will report, mm (clamped to the sonar max).
    pub fn set_sonar_range(&mut self, index: usize, mm: u16) {
        if let Some(r) = self.sonar_mm.get_mut(index) {
            *r = mm.min(self.cfg.sonar_max_mm);
        }
    }

    pub fn set_stall_bumpers(&mut self, v: u16) {
        self.stall_bumpers = v;
    }

    pub fn set_battery_dv(&mut self, dv: u8) {
        self.battery_dv = dv;
    }

    pub fn set_estop(&mut self, on: bool) {
        self.estop = on;
        if on {
            self.commanded = Motion::default();
            self.actual = Motion::default();
        }
    }

    /// When the controller next needs [`ArcosRobot::tick`]. While the wheels
    /// move or ramp, every [`MOTION_STEP_NS`]: a real controller's servo loop
    /// is far faster than its SIP cycle, and standstill must be observable
    /// when it happens, not at the next SIP.
    pub fn next_deadline_ns(&self, now_ns: u64) -> u64 {
        let next = if self.streaming {
            self.next_sip_ns.max(now_ns)
        } else {
            now_ns + self.cfg.sip_period_ms * 1_000_000
        };
        if self.actual != Motion::default() || self.motion_target() != self.actual {
            next.min(now_ns + MOTION_STEP_NS)
        } else {
            next
        }
    }

    /// Handles one command payload (checksum already verified).
    pub fn on_packet(&mut self, payload: &[u8], now_ns: u64, out: &mut impl FnMut(&PacketBuf)) {
        self.advance(now_ns);
        let cmd = match decode_command(payload) {
            Ok(c) => c,
            Err(e) => {
                tracing::debug!("emulator: undecodable command: {e}");
                self.counters.bad_commands += 1;
                return;
            }
        };
        match self.phase {
            Phase::Handshake { next } => self.on_sync(cmd.cmd, cmd.arg, next, out),
            Phase::Connected => self.on_command(cmd.cmd, cmd.arg, now_ns, out),
        }
    }

    fn on_sync(&mut self, id: u8, arg: Arg<'_>, next: u8, out: &mut impl FnMut(&PacketBuf)) {
        if arg != Arg::None || id > 2 {
            // Not a SYNC packet; a controller in the handshake ignores it.
            return;
        }
        if id != next {
            // ARCOS restarts the handshake on an out-of-order SYNC.
            self.counters.sync_restarts += 1;
            self.phase = Phase::Handshake { next: 0 };
            if id != 0 {
                return;
            }
        }
        let mut p = PacketBuf::new();
        let ok = if id == 2 {
            RobotIdent::new(&self.cfg.name, &self.cfg.class, &self.cfg.subclass)
                .encode(&mut p)
                .is_ok()
        } else {
            p.set_payload(&[id]).is_ok()
        };
        if ok {
            out(&p);
            self.counters.sync_replies += 1;
        }
        self.phase = if id == 2 {
            Phase::Connected
        } else {
            Phase::Handshake { next: id + 1 }
        };
    }

    fn on_command(&mut self, id: u8, arg: Arg<'_>, now_ns: u64, out: &mut impl FnMut(&PacketBuf)) {
        self.counters.commands += 1;
        if let Some(c) = self.counters.by_command.get_mut(usize::from(id)) {
            *c += 1;
        }
        self.last_command_ns = Some(now_ns);
        self.watchdog_tripped = false;
        let int = arg.int().unwrap_or(0);
        match id {
            num::PULSE => {}
            num::OPEN => {
                if !self.streaming {
                    self.next_sip_ns = now_ns;
                }
                self.streaming = true;
                self.counters.opens += 1;
                if self.cfg.motors_enabled_at_open {
                    self.motors_enabled = true;
                }
            }
            num::CLOSE => {
                self.end_session();
                self.counters.closes += 1;
            }
            num::ENABLE => {
                self.motors_enabled = int != 0;
                if !self.motors_enabled {
                    self.commanded = Motion::default();
                }
            }
            num::SONAR => self.sonar_on = int != 0,
            num::VEL if !self.estop => {
                self.commanded.trans = f64::from(int).clamp(-self.max_vel, self.max_vel);
            }
            num::RVEL if !self.estop => {
                self.commanded.rot = f64::from(int).clamp(-self.max_rot_vel, self.max_rot_vel);
            }
            num::VEL2 if !self.estop => {
                let (l, r) = vel2_split(int);
                let left = f64::from(l) * self.params.vel2_divisor;
                let right = f64::from(r) * self.params.vel2_divisor;
                self.commanded.trans = ((left + right) / 2.0).clamp(-self.max_vel, self.max_vel);
                let rot = ((right - left) / 2.0 * self.params.diff_conv).to_degrees();
                self.commanded.rot = rot.clamp(-self.max_rot_vel, self.max_rot_vel);
            }
            num::VEL | num::RVEL | num::VEL2 => {}
            num::STOP => self.commanded = Motion::default(),
            num::ESTOP => {
                self.commanded = Motion::default();
                self.actual = Motion::default();
            }
            num::SETO => self.odom_origin = self.pose,
            num::SETA if int > 0 => self.trans_accel = f64::from(int),
            num::SETA if int < 0 => self.trans_decel = f64::from(-int),
            num::SETRA if int > 0 => self.rot_accel = f64::from(int),
            num::SETRA if int < 0 => self.rot_decel = f64::from(-int),
            num::SETA | num::SETRA => {}
            num::SETV => self.max_vel = f64::from(int.max(0)),
            num::SETRV => self.max_rot_vel = f64::from(int.max(0)),
            num::CONFIG => {
                let mut p = PacketBuf::new();
                if self.config_packet().encode(&mut p).is_ok() {
                    out(&p);
                }
            }
            // Serial speed means nothing on a PTY or socket.
            num::HOSTBAUD => {}
            _ => {
                tracing::debug!("emulator: command {id} not implemented");
                self.counters.unsupported += 1;
            }
        }
    }

    fn config_packet(&self) -> ConfigPacket {
        let u16_of = |v: f64| v.clamp(0.0, f64::from(u16::MAX)) as u16;
        ConfigPacket {
            robot_type: self.cfg.class.clone(),
            subtype: self.cfg.subclass.clone(),
            serial_number: "EMU".into(),
            rot_vel_top: u16_of(self.params.max_rot_vel_deg_s),
            trans_vel_top: u16_of(self.params.max_vel_mm_s),
            rot_accel_top: 500,
            trans_accel_top: 2000,
            pwm_max: 1000,
            name: self.cfg.name.clone(),
            sip_cycle: self.cfg.sip_period_ms.min(255) as u8,
            host_baud: 0,
            aux1_baud: 0,
            has_gripper: 0,
            front_sonar: u16::from(self.cfg.sonar_count > 0),
            rear_sonar: u8::from(self.cfg.sonar_count > 8),
            low_battery: 110,
            rev_count: 16570,
            watchdog: self.cfg.watchdog_ms,
            normal_mpacs: Some(0),
            stall_val: Some(0),
            stall_count: Some(0),
            joy_vel: Some(0),
            joy_rot_vel: Some(0),
            rot_vel_max: Some(u16_of(self.max_rot_vel)),
            trans_vel_max: Some(u16_of(self.max_vel)),
            rot_accel: Some(u16_of(self.rot_accel)),
            rot_decel: Some(u16_of(self.rot_decel)),
            rot_kp: Some(0),
            rot_kv: Some(0),
            rot_ki: Some(0),
            trans_accel: Some(u16_of(self.trans_accel)),
            trans_decel: Some(u16_of(self.trans_decel)),
            ..Default::default()
        }
    }

    /// Wheel speeds, mm/s, from the body velocities.
    fn wheels(&self) -> (f64, f64) {
        let half_diff = self.actual.rot.to_radians() / self.params.diff_conv;
        (self.actual.trans - half_diff, self.actual.trans + half_diff)
    }

    /// What the wheels ramp towards.
    fn motion_target(&self) -> Motion {
        if self.motors_enabled && !self.estop {
            self.commanded
        } else {
            Motion::default()
        }
    }

    /// Moves time forward: velocity ramps, pose integration, watchdog.
    fn advance(&mut self, now_ns: u64) {
        let dt = match self.last_tick_ns {
            Some(t) if now_ns > t => (now_ns - t) as f64 * 1e-9,
            Some(_) => 0.0,
            None => 0.0,
        };
        if self.last_tick_ns.is_none_or(|t| now_ns > t) {
            self.last_tick_ns = Some(now_ns);
        }
        if self.phase == Phase::Connected
            && self.cfg.watchdog_ms > 0
            && !self.watchdog_tripped
            && self.last_command_ns.is_some_and(|t| {
                now_ns.saturating_sub(t) > u64::from(self.cfg.watchdog_ms) * 1_000_000
            })
        {
            self.watchdog_tripped = true;
            self.counters.watchdog_trips += 1;
            self.commanded = Motion::default();
        }
        if dt <= 0.0 {
            return;
        }
        let target = self.motion_target();
        self.actual.trans = ramp(
            self.actual.trans,
            target.trans,
            self.trans_accel,
            self.trans_decel,
            dt,
        );
        self.actual.rot = ramp(
            self.actual.rot,
            target.rot,
            self.rot_accel,
            self.rot_decel,
            dt,
        );
        if !self.external_motion {
            // Midpoint heading: exact enough at 100 ms steps.
            let w = self.actual.rot.to_radians();
            let mid = self.pose.th + w * dt / 2.0;
            self.pose.x_mm += self.actual.trans * dt * mid.cos();
            self.pose.y_mm += self.actual.trans * dt * mid.sin();
            self.pose.th = normalize_angle(self.pose.th + w * dt);
        }
    }

    /// Advances to `now_ns` and sends a SIP when one is due.
    pub fn tick(&mut self, now_ns: u64, out: &mut impl FnMut(&PacketBuf)) {
        self.advance(now_ns);
        if !self.streaming || now_ns < self.next_sip_ns {
            return;
        }
        let period = self.cfg.sip_period_ms * 1_000_000;
        self.next_sip_ns += period;
        if self.next_sip_ns <= now_ns {
            // Fell behind (the thread was descheduled): don't burst.
            self.next_sip_ns = now_ns + period;
        }
        let mut p = PacketBuf::new();
        if self.sip().encode(&mut p).is_ok() {
            out(&p);
            self.counters.sips += 1;
        }
    }

    /// The SIP the controller would send now.
    pub fn sip(&mut self) -> Sip {
        let p = self.params;
        let odo = self.pose.relative_to(&self.odom_origin);
        let counter = |mm: f64| ((mm / p.dist_conv).round() as i64).rem_euclid(0x8000) as u16;
        let th_units = ((odo.th / p.angle_conv).round() as i64 + 2048).rem_euclid(4096) - 2048;
        let (left, right) = self.wheels();
        let moving = left.abs() >= 0.5 || right.abs() >= 0.5;
        let mut flags = 0u16;
        if self.motors_enabled {
            flags |= flag::MOTORS_ENABLED;
        }
        if self.sonar_on {
            let arrays: u16 = if self.cfg.sonar_count > 8 { 0b11 } else { 0b01 };
            flags |= arrays << flag::SONAR_ARRAYS_SHIFT;
        }
        if self.estop {
            flags |= flag::ESTOP;
        }
        let to_i16 = |v: f64| v.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16;
        let mut s = Sip {
            packet_type: if moving && self.cfg.moving_type {
                SIP_MOVING
            } else {
                SIP_STOPPED
            },
            x: counter(odo.x_mm),
            y: counter(odo.y_mm),
            th: th_units as i16,
            left_vel: to_i16(left / p.vel_conv),
            right_vel: to_i16(right / p.vel_conv),
            battery_dv: self.battery_dv,
            stall_bumpers: self.stall_bumpers,
            control: 0,
            flags,
            compass: 0,
            ..Default::default()
        };
        if self.sonar_on {
            let n = usize::from(self.cfg.sonar_count).min(MAX_SONARS);
            let (start, count) = match self.cfg.sonar_mode {
                SonarMode::All => (0, n),
                SonarMode::Cycle { per_sip } => (self.next_sonar, usize::from(per_sip).min(n)),
            };
            for k in 0..count {
                let i = (start + k) % n.max(1);
                let mm = self
                    .sonar_mm
                    .get(i)
                    .copied()
                    .unwrap_or(self.cfg.sonar_max_mm);
                s.sonars.push(SonarSample {
                    index: i as u8,
                    range: to_i16(f64::from(mm) / p.range_conv).max(0) as u16,
                });
            }
            self.next_sonar = (start + count) % n.max(1);
        }
        if !self.cfg.legacy_sip {
            // What AMRISim sends after the sonars.
            s.grip_state = Some(0);
            s.anport = Some(0);
            s.analog = Some(0);
            s.digin = Some(0xFF);
            s.digout = Some(0xFF);
            s.battery_x10 = Some(u16::from(self.battery_dv));
            s.charge_state = Some(0);
            s.rot_vel = Some(to_i16(self.actual.rot * 10.0));
            s.fault_flags = Some(0);
            s.lat_vel = Some(0);
            s.temperature = Some(-127);
            s.soc = Some(0);
        }
        s
    }
}

/// Moves `v` toward `target`: `accel` when speeding up, `decel` when slowing.
fn ramp(v: f64, target: f64, accel: f64, decel: f64, dt: f64) -> f64 {
    let slowing = target.abs() < v.abs() || (target.signum() != v.signum() && v != 0.0);
    let rate = if slowing { decel } else { accel };
    let step = rate.max(1.0) * dt;
    if (target - v).abs() <= step {
        target
    } else {
        v + step * (target - v).signum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_pioneer_codec::{Command, Framer, RobotPacket, decode_robot_packet};

    const MS: u64 = 1_000_000;

    struct Bench {
        robot: ArcosRobot,
        now: u64,
        replies: Vec<Vec<u8>>,
    }

    impl Bench {
        fn new(cfg: RobotConfig) -> Self {
            Self {
                robot: ArcosRobot::new(cfg).unwrap(),
                now: 1_000 * MS,
                replies: Vec::new(),
            }
        }

        fn send(&mut self, c: Command<'_>) {
            let p = c.packet().unwrap();
            let replies = &mut self.replies;
            self.robot
                .on_packet(p.payload(), self.now, &mut |r: &PacketBuf| {
                    replies.push(r.as_bytes().to_vec())
                });
        }

        fn run_for(&mut self, ms: u64) {
            for _ in 0..ms {
                self.now += MS;
                let replies = &mut self.replies;
                self.robot.tick(self.now, &mut |r: &PacketBuf| {
                    replies.push(r.as_bytes().to_vec())
                });
            }
        }

        fn take(&mut self) -> Vec<RobotPacket> {
            let mut f = Framer::new();
            let mut out = Vec::new();
            for r in self.replies.drain(..) {
                f.feed(&r, |p| out.push(decode_robot_packet(p.unwrap()).unwrap()));
            }
            out
        }

        fn connect(&mut self) {
            self.send(Command::Sync0);
            self.send(Command::Sync1);
            self.send(Command::Sync2);
            self.send(Command::Open);
            self.send(Command::Enable(true));
            self.send(Command::Sonar(true));
            self.take();
        }

        fn sips(&mut self) -> Vec<Sip> {
            self.take()
                .into_iter()
                .filter_map(|p| match p {
                    RobotPacket::Sip(s) => Some(s),
                    _ => None,
                })
                .collect()
        }
    }

    #[test]
    fn handshake_echoes_sync0_sync1_and_names_itself_on_sync2() {
        let mut b = Bench::new(RobotConfig::default());
        b.send(Command::Sync0);
        b.send(Command::Sync1);
        b.send(Command::Sync2);
        assert_eq!(b.replies[0], [0xFA, 0xFB, 0x03, 0x00, 0x00, 0x00]);
        assert_eq!(b.replies[1], [0xFA, 0xFB, 0x03, 0x01, 0x00, 0x01]);
        let got = b.take();
        assert_eq!(
            got[2],
            RobotPacket::Ident(RobotIdent::new("smokenav-emulator", "Pioneer", "p3dx"))
        );
        // No SIPs before OPEN.
        b.run_for(500);
        assert!(b.take().is_empty());
    }

    #[test]
    fn unknown_subclass_is_reported_with_borrowed_factors() {
        let mut b = Bench::new(RobotConfig {
            subclass: "box".into(),
            factors_from: Some("p3dx-sh".into()),
            ..Default::default()
        });
        assert_eq!(b.robot.params().dist_conv, 1.0);
        b.send(Command::Sync0);
        b.send(Command::Sync1);
        b.send(Command::Sync2);
        assert!(matches!(&b.take()[2], RobotPacket::Ident(id) if id.subclass == "box"));
        assert!(
            ArcosRobot::new(RobotConfig {
                subclass: "box".into(),
                ..Default::default()
            })
            .is_err()
        );
    }

    #[test]
    fn out_of_order_sync_restarts_the_handshake() {
        let mut b = Bench::new(RobotConfig::default());
        b.send(Command::Sync0);
        b.send(Command::Sync2); // skipped SYNC1
        assert_eq!(b.robot.status().phase, Phase::Handshake { next: 0 });
        assert_eq!(b.robot.status().counters.sync_restarts, 1);
        assert_eq!(b.take().len(), 1); // only the SYNC0 echo
    }

    #[test]
    fn open_streams_sips_every_100_ms() {
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.run_for(1000);
        let sips = b.sips();
        assert!((10..=11).contains(&sips.len()), "{}", sips.len());
        assert!(
            sips.iter()
                .all(|s| s.motors_enabled() && s.sonars.len() == 16)
        );
    }

    #[test]
    fn vel_300_for_2_s_travels_600_mm_once_stopped() {
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.send(Command::Vel(300));
        b.run_for(1000);
        b.send(Command::Pulse); // keep the watchdog quiet
        b.run_for(1000);
        b.send(Command::Vel(0));
        b.run_for(1000);
        let st = b.robot.status();
        assert!((st.pose.x_mm - 600.0).abs() < 2.0, "{:?}", st.pose);
        assert_eq!(st.actual.trans, 0.0);
        // p3dx: the counter reads 600 / 0.485 = 1237 units.
        let s = b.robot.sip();
        assert!((i32::from(s.x) - 1237).abs() <= 4, "{}", s.x);
    }

    #[test]
    fn motor_model_steps_every_10_ms_while_ramping_and_idles_at_standstill() {
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.run_for(50);
        let idle = b.robot.next_deadline_ns(b.now);
        assert!(
            idle > b.now + MOTION_STEP_NS,
            "idle robot wakes only for SIPs"
        );
        b.send(Command::Vel(300));
        assert_eq!(b.robot.next_deadline_ns(b.now), b.now + MOTION_STEP_NS);
        b.run_for(1000);
        b.send(Command::Vel(0));
        assert_eq!(b.robot.next_deadline_ns(b.now), b.now + MOTION_STEP_NS);
        // 300 mm/s at 1000 mm/s² decel: standstill after 0.3 s.
        b.run_for(299);
        assert!(b.robot.status().actual.trans > 0.0);
        b.run_for(2);
        assert_eq!(b.robot.status().actual.trans, 0.0);
        assert!(b.robot.next_deadline_ns(b.now) > b.now + MOTION_STEP_NS);
    }

    #[test]
    fn watchdog_stops_the_robot_after_2_s_without_commands() {
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.send(Command::Vel(200));
        b.run_for(1900);
        assert_eq!(b.robot.status().commanded.trans, 200.0);
        b.run_for(200);
        let st = b.robot.status();
        assert!(st.watchdog_tripped);
        assert_eq!(st.commanded.trans, 0.0);
        assert_eq!(st.counters.watchdog_trips, 1);
    }

    #[test]
    fn close_ends_session_disables_motors_and_stops_sips() {
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.send(Command::Vel(200));
        b.send(Command::Close);
        let st = b.robot.status();
        assert_eq!(st.phase, Phase::Handshake { next: 0 });
        assert!(!st.motors_enabled && !st.streaming);
        assert_eq!(st.commanded.trans, 0.0);
        b.take();
        b.run_for(300);
        assert!(b.sips().is_empty());
    }

    #[test]
    fn stale_session_streams_sips_and_treats_sync0_as_pulse() {
        let mut b = Bench::new(RobotConfig {
            start_open: true,
            ..Default::default()
        });
        b.run_for(250);
        b.send(Command::Sync0);
        b.run_for(100);
        let got = b.take();
        assert!(
            got.iter().all(|p| matches!(p, RobotPacket::Sip(_))),
            "{got:?}"
        );
        assert!(got.len() >= 3);
    }

    #[test]
    fn vel2_wheels_become_body_velocities() {
        // VEL2 10/5 ×20: left 200, right 100 mm/s -> 150 mm/s, turning right.
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.send(Command::Vel2 { left: 10, right: 5 });
        b.run_for(1000);
        let st = b.robot.status();
        assert!(
            (st.left - 200.0).abs() < 1.0 && (st.right - 100.0).abs() < 1.0,
            "{st:?}"
        );
    }

    #[test]
    fn odometry_counter_wraps_at_15_bits() {
        // Start 15.8 m out: 15800 / 0.485 = 32577 units, 190 from the wrap.
        let mut b = Bench::new(RobotConfig {
            initial_pose: Pose::new(15_800.0, 0.0, 0.0),
            ..Default::default()
        });
        b.connect();
        assert_eq!(b.robot.sip().x, 32577);
        b.send(Command::Vel(300));
        b.run_for(1000);
        let x = b.robot.sip().x;
        assert!(x < 0x1000, "counter should have wrapped: {x}");
    }

    #[test]
    fn seto_zeroes_odometry_but_not_the_true_pose() {
        let mut b = Bench::new(RobotConfig {
            initial_pose: Pose::new(1000.0, 500.0, 0.5),
            ..Default::default()
        });
        b.connect();
        b.send(Command::ResetOdometry);
        let s = b.robot.sip();
        assert_eq!((s.x, s.y, s.th), (0, 0, 0));
        assert_eq!(b.robot.status().pose.x_mm, 1000.0);
    }

    #[test]
    fn cycle_mode_sends_a_few_sonars_per_sip_round_robin() {
        let mut b = Bench::new(RobotConfig {
            sonar_mode: SonarMode::Cycle { per_sip: 3 },
            sonar_count: 8,
            ..Default::default()
        });
        b.connect();
        b.robot.set_sonar_range(2, 812);
        b.run_for(300);
        let idx: Vec<u8> = b
            .sips()
            .iter()
            .flat_map(|s| {
                s.sonars
                    .as_slice()
                    .iter()
                    .map(|r| r.index)
                    .collect::<Vec<_>>()
            })
            .collect();
        assert_eq!(&idx[..8], &[0, 1, 2, 3, 4, 5, 6, 7]);
        let s = b.robot.sip();
        assert!(s.sonars.as_slice().iter().all(|r| r.index < 8));
    }

    #[test]
    fn legacy_firmware_sip_has_no_trailing_fields() {
        let mut b = Bench::new(RobotConfig {
            legacy_sip: true,
            ..Default::default()
        });
        b.connect();
        let s = b.robot.sip();
        assert_eq!(s.battery_x10, None);
        assert_eq!(s.rot_vel, None);
    }

    #[test]
    fn config_reply_reports_watchdog_and_subclass() {
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.send(Command::Config);
        match b.take().pop() {
            Some(RobotPacket::Config(c)) => {
                assert_eq!(c.watchdog, 2000);
                assert_eq!(c.subtype, "p3dx");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn motors_disabled_means_no_motion() {
        let mut b = Bench::new(RobotConfig::default());
        b.connect();
        b.send(Command::Enable(false));
        b.send(Command::Vel(300));
        b.run_for(500);
        assert_eq!(b.robot.status().pose.x_mm, 0.0);
    }
}
