//! What to send each cycle and what to publish from each reply.
//!
//! Pure: stamps come in as arguments, messages go out as values; the process
//! (`main.rs`) owns the port, the bus and the clock.

use smokenav_scout_codec::units::{SONAR_MAX_RANGE_M, SonarRange};
use smokenav_scout_codec::{Command, DiffDrive, SONARS, SonarOrder, StateSi};
use smokenav_shared_types::{
    Header, Odometry, OdometryFlags, SonarReading, SonarRing, SonarStatus, VelocityCommand,
};

/// Everything the core needs from the robot profile, in SI units.
#[derive(Debug, Clone)]
pub struct CoreConfig {
    pub drive: DiffDrive,
    /// Stop the robot when no velocity command arrived for this long, ns.
    pub cmd_timeout_ns: u64,
    pub max_linear_mps: f64,
    pub max_angular_rps: f64,
    pub watchdog_s: u8,
    pub sonar_rate: u8,
    pub sonar_order: SonarOrder,
    /// Send `dp(0,0)` and `da(0,0)` on the first connection.
    pub zero_on_start: bool,
    pub odom_frame: String,
    pub sonar_frame: String,
    pub sonar_min_range_m: f32,
    pub sonar_max_range_m: f32,
}

/// The robot profile has no usable `[base.scout]` table.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    #[error("the profile has no [base.scout] table")]
    NoScoutTable,
    #[error("base.scout.sonar_order: {0}")]
    SonarOrder(#[from] smokenav_scout_codec::SonarOrderError),
}

impl CoreConfig {
    /// From a robot profile: `[base]`, `[base.scout]` and `[sonar]`.
    pub fn from_profile(cfg: &smokenav_platform_config::RobotConfig) -> Result<Self, ProfileError> {
        let scout = cfg.base.scout.as_ref().ok_or(ProfileError::NoScoutTable)?;
        Ok(CoreConfig {
            drive: DiffDrive::new(scout.track_m, scout.wheel_order),
            cmd_timeout_ns: (cfg.base.cmd_timeout_s * 1e9) as u64,
            max_linear_mps: cfg.base.max_linear_mps,
            max_angular_rps: cfg.base.max_angular_dps.to_radians(),
            watchdog_s: scout.watchdog_s,
            sonar_rate: scout.sonar_rate,
            sonar_order: SonarOrder::from_indices(&scout.sonar_order)?,
            zero_on_start: !scout.keep_odometry,
            odom_frame: cfg.base.odom_frame.clone(),
            sonar_frame: "base_link".into(),
            sonar_min_range_m: cfg.sonar.min_range_m as f32,
            sonar_max_range_m: cfg.sonar.max_range_m as f32,
        })
    }

    /// Defaults matching `config/nomad-scout.toml`.
    pub fn scout_defaults(drive: DiffDrive) -> Self {
        Self {
            drive,
            cmd_timeout_ns: 500_000_000,
            max_linear_mps: 0.4,
            max_angular_rps: 60f64.to_radians(),
            watchdog_s: 1,
            sonar_rate: 15,
            sonar_order: SonarOrder::from_indices(&[
                0, 2, 15, 1, 14, 3, 13, 4, 12, 5, 11, 6, 10, 7, 9, 8,
            ])
            .unwrap_or(SonarOrder::DISABLED),
            zero_on_start: true,
            odom_frame: "odom".into(),
            sonar_frame: "base_link".into(),
            sonar_min_range_m: 0.15,
            sonar_max_range_m: SONAR_MAX_RANGE_M as f32,
        }
    }
}

/// Counters the core keeps (surfaced in Health).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CoreStats {
    pub commands_received: u64,
    /// Commands with a NaN or infinite value, dropped.
    pub commands_rejected: u64,
    /// Commands clamped to the configured limits.
    pub commands_clamped: u64,
    /// Times the command stream went quiet while driving and we sent `st`.
    pub command_timeouts: u64,
}

#[derive(Debug, Clone)]
pub struct ScoutCore {
    cfg: CoreConfig,
    /// Latest (linear, angular) and when it arrived.
    cmd: Option<(f64, f64, u64)>,
    /// True once the timeout stop went out for the current silence.
    timed_out: bool,
    connected_before: bool,
    /// The next odometry message carries the RESET flag.
    reset_pending: bool,
    /// The last reply showed a wheel turning.
    robot_moving: bool,
    odom_seq: u64,
    sonar_seq: u64,
    stats: CoreStats,
}

impl ScoutCore {
    pub fn new(cfg: CoreConfig) -> Self {
        Self {
            cfg,
            cmd: None,
            timed_out: false,
            connected_before: false,
            reset_pending: true,
            robot_moving: false,
            odom_seq: 0,
            sonar_seq: 0,
            stats: CoreStats::default(),
        }
    }

    pub fn config(&self) -> &CoreConfig {
        &self.cfg
    }

    pub fn stats(&self) -> CoreStats {
        self.stats
    }

    /// The commands that configure the robot after a (re)connect: the
    /// watchdog first (a crash mid-setup must not leave it disarmed), then the
    /// sonar order, then — until one connection has been set up — zeroed
    /// odometry. A reconnect keeps the robot's odometry: it never stopped
    /// counting.
    pub fn setup_commands(&self) -> Vec<Command> {
        let mut setup = vec![
            Command::ConfTimeout(self.cfg.watchdog_s),
            Command::ConfSonar {
                rate: self.cfg.sonar_rate,
                order: self.cfg.sonar_order,
            },
        ];
        if self.cfg.zero_on_start && !self.connected_before {
            setup.push(Command::DefinePosition { x: 0, y: 0 });
            setup.push(Command::DefineAngles {
                heading: 0,
                turret: 0,
            });
        }
        setup
    }

    /// Every setup command was acknowledged: the next odometry is flagged RESET.
    pub fn on_connected(&mut self) {
        self.connected_before = true;
        self.reset_pending = true;
    }

    /// A velocity command from the bus, received at `now`.
    pub fn on_velocity(&mut self, cmd: &VelocityCommand, now: u64) {
        self.stats.commands_received += 1;
        if !cmd.linear.is_finite() || !cmd.angular.is_finite() {
            self.stats.commands_rejected += 1;
            return;
        }
        let v = cmd
            .linear
            .clamp(-self.cfg.max_linear_mps, self.cfg.max_linear_mps);
        let w = cmd
            .angular
            .clamp(-self.cfg.max_angular_rps, self.cfg.max_angular_rps);
        if v != cmd.linear || w != cmd.angular {
            self.stats.commands_clamped += 1;
        }
        self.cmd = Some((v, w, now));
        self.timed_out = false;
    }

    /// When the current command goes stale (for the process's wait deadline).
    pub fn command_deadline(&self) -> Option<u64> {
        match self.cmd {
            Some((_, _, at)) if !self.timed_out => Some(at.saturating_add(self.cfg.cmd_timeout_ns)),
            _ => None,
        }
    }

    /// The request for this cycle. Every request is answered with the full
    /// state, so a `vm` doubles as the state poll.
    pub fn next_request(&mut self, now: u64) -> Command {
        if let Some((v, w, at)) = self.cmd {
            if now.saturating_sub(at) <= self.cfg.cmd_timeout_ns {
                let wheels = self.cfg.drive.wheels_for(v, w);
                return Command::Velocity(self.cfg.drive.vm_args(wheels));
            }
            if !self.timed_out {
                self.timed_out = true;
                self.stats.command_timeouts += 1;
                return Command::Stop;
            }
        }
        // Nobody is commanding: a robot still moving (left so by a crashed
        // controller or a previous run) is stopped.
        if self.robot_moving {
            Command::Stop
        } else {
            Command::GetState
        }
    }

    /// Turns a state reply received at `stamp_ns` into the messages to publish.
    pub fn on_state(&mut self, si: &StateSi, stamp_ns: u64) -> (Odometry, SonarRing) {
        self.robot_moving = si.motor.left_moving()
            || si.motor.right_moving()
            || si.wheels.left != 0.0
            || si.wheels.right != 0.0;
        let reset = std::mem::take(&mut self.reset_pending);
        let odom = odometry(
            si,
            Header::new(stamp_ns, self.odom_seq, &self.cfg.odom_frame),
            reset,
        );
        self.odom_seq += 1;
        let ring = sonar_ring(
            si,
            Header::new(stamp_ns, self.sonar_seq, &self.cfg.sonar_frame),
            self.cfg.sonar_min_range_m,
            self.cfg.sonar_max_range_m,
        );
        self.sonar_seq += 1;
        (odom, ring)
    }
}

/// The robot's state as an [`Odometry`] message.
pub fn odometry(si: &StateSi, header: Header, reset: bool) -> Odometry {
    let mut flags = 0;
    // The Scout has no motor-enable switch; the e-stop is what cuts the motors.
    if !si.motor.estop() {
        flags |= OdometryFlags::MOTORS_ENABLED;
    }
    if reset {
        flags |= OdometryFlags::RESET;
    }
    Odometry {
        header,
        x: si.x_m,
        y: si.y_m,
        theta: si.heading_rad,
        linear: si.linear_mps,
        angular: si.angular_rps,
        flags,
        bumpers: si.bumpers,
        battery_v: si.motor_v as f32,
        _reserved: 0,
    }
}

/// All 16 sonars as a [`SonarRing`]: 255 in (no echo) or anything at or past
/// `max_range` is saturated; below `min_range` the Polaroid cannot measure,
/// so such a byte is marked invalid rather than read as an obstacle.
pub fn sonar_ring(si: &StateSi, header: Header, min_range: f32, max_range: f32) -> SonarRing {
    let mut ring = SonarRing {
        header,
        max_range,
        ..Default::default()
    };
    for (i, r) in si.sonar.iter().enumerate().take(SONARS) {
        let reading = match *r {
            SonarRange::NoEcho => SonarReading::new(i as u8, max_range, SonarStatus::Saturated),
            SonarRange::Echo(m) => {
                let m = m as f32;
                if m >= max_range {
                    SonarReading::new(i as u8, max_range, SonarStatus::Saturated)
                } else if m < min_range {
                    SonarReading::new(i as u8, m, SonarStatus::Invalid)
                } else {
                    SonarReading::new(i as u8, m, SonarStatus::Valid)
                }
            }
        };
        ring.push(reading);
    }
    ring
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_scout_codec::{MotorStatus, StateReply, WheelOrder};

    const MS: u64 = 1_000_000;

    fn core() -> ScoutCore {
        ScoutCore::new(CoreConfig::scout_defaults(DiffDrive::new(
            0.345,
            WheelOrder::RightLeft,
        )))
    }

    fn cmd(linear: f64, angular: f64) -> VelocityCommand {
        VelocityCommand {
            linear,
            angular,
            ..Default::default()
        }
    }

    fn si(state: StateReply) -> StateSi {
        DiffDrive::new(0.345, WheelOrder::RightLeft).state_si(&state)
    }

    #[test]
    fn first_connect_configures_and_zeroes_reconnect_only_configures() {
        let mut c = core();
        let first = c.setup_commands();
        assert_eq!(first[0], Command::ConfTimeout(1));
        assert!(matches!(first[1], Command::ConfSonar { rate: 15, .. }));
        assert!(first.contains(&Command::DefinePosition { x: 0, y: 0 }));
        // A setup that failed half-way is repeated in full.
        assert_eq!(c.setup_commands(), first);
        c.on_connected();
        let again = c.setup_commands();
        assert_eq!(again.len(), 2, "{again:?}");
    }

    #[test]
    fn fresh_command_becomes_vm_in_tenth_inches() {
        let mut c = core();
        c.on_velocity(&cmd(0.254, 0.0), 0);
        // 0.254 m/s = 100 tenth-in/s on both wheels.
        assert_eq!(c.next_request(100 * MS), Command::Velocity([100, 100, 0]));
    }

    #[test]
    fn command_timeout_sends_one_stop_then_polls() {
        let mut c = core();
        c.on_velocity(&cmd(0.2, 0.0), 0);
        assert!(matches!(c.next_request(400 * MS), Command::Velocity(_)));
        assert_eq!(c.next_request(600 * MS), Command::Stop);
        assert_eq!(c.stats().command_timeouts, 1);
        assert_eq!(c.next_request(700 * MS), Command::GetState);
        assert_eq!(c.command_deadline(), None);
    }

    #[test]
    fn robot_seen_moving_without_commands_is_stopped() {
        let mut c = core();
        let moving = StateReply {
            velocity: [50, 50, 0],
            motor: MotorStatus(0b11),
            ..Default::default()
        };
        c.on_state(&si(moving), 0);
        assert_eq!(c.next_request(0), Command::Stop);
        c.on_state(&si(StateReply::default()), 0);
        assert_eq!(c.next_request(0), Command::GetState);
    }

    #[test]
    fn commands_are_clamped_and_nan_is_dropped() {
        let mut c = core();
        c.on_velocity(&cmd(5.0, 0.0), 0);
        // 0.4 m/s limit = 157.5 tenth-in/s ⇒ 157 (rounded half away: 157.48).
        assert_eq!(c.next_request(0), Command::Velocity([157, 157, 0]));
        c.on_velocity(&cmd(f64::NAN, 0.0), 0);
        assert_eq!(c.stats().commands_rejected, 1);
        assert_eq!(c.stats().commands_clamped, 1);
        assert_eq!(c.next_request(0), Command::Velocity([157, 157, 0]));
    }

    #[test]
    fn state_becomes_si_odometry_with_reset_after_connect() {
        let mut c = core();
        c.on_connected();
        let s = StateReply {
            x: 394,  // 1.00076 m
            y: -197, // -0.50038 m
            heading: 900,
            velocity: [120, 80, 0], // right 0.3048, left 0.2032 m/s
            motor: MotorStatus(0b1011),
            bumpers: 0x21,
            ..Default::default()
        };
        let (odom, _) = c.on_state(&si(s), 42);
        assert!((odom.x - 1.00076).abs() < 1e-9);
        assert!((odom.y + 0.50038).abs() < 1e-9);
        assert!((odom.theta - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert!((odom.linear - 0.254).abs() < 1e-9);
        assert!((odom.angular - 0.1016 / 0.345).abs() < 1e-9);
        assert_eq!(odom.bumpers, 0x21);
        assert_eq!(odom.header.stamp_ns, 42);
        assert_eq!(odom.header.frame_id.as_str(), "odom");
        assert!(odom.flags & OdometryFlags::RESET != 0);
        assert!(odom.motors_enabled());
        let (odom2, _) = c.on_state(&si(s), 43);
        assert_eq!(odom2.flags & OdometryFlags::RESET, 0);
        assert_eq!(odom2.header.seq, 1);
    }

    #[test]
    fn sonar_255_is_saturated_and_below_min_is_invalid() {
        let mut sonar_in = [100u8; 16];
        sonar_in[3] = 255;
        sonar_in[4] = 5; // 0.127 m < 0.15 m
        sonar_in[5] = 254; // 6.4516 m
        let ring = sonar_ring(
            &si(StateReply {
                sonar_in,
                ..Default::default()
            }),
            Header::default(),
            0.15,
            6.477,
        );
        assert_eq!(ring.len(), 16);
        assert_eq!(ring.readings()[0].valid_range(), Some(2.54));
        assert_eq!(ring.readings()[3].status(), SonarStatus::Saturated);
        assert_eq!(ring.readings()[3].range, 6.477);
        assert_eq!(ring.readings()[4].status(), SonarStatus::Invalid);
        assert_eq!(ring.readings()[5].status(), SonarStatus::Valid);
        assert_eq!(ring.max_range, 6.477);
        for (i, r) in ring.readings().iter().enumerate() {
            assert_eq!(r.index as usize, i);
        }
    }

    #[test]
    fn estop_clears_motors_enabled() {
        let s = StateReply {
            motor: MotorStatus(1 << 6),
            ..Default::default()
        };
        let o = odometry(&si(s), Header::default(), false);
        assert!(!o.motors_enabled());
    }
}
