//! The robot behind the serial port: kinematics, watchdog, sonar firing.
//!
//! Pure and lazy: time is passed in (ns of whatever clock the caller uses)
//! and the model catches up on every call, so nothing needs a periodic tick.

use smokenav_scout_codec::reply::SONARS;
use smokenav_scout_codec::sonar::SonarOrder;
use smokenav_scout_codec::units::{
    self, CPU_VOLTAGE_RANGE, MOTOR_VOLTAGE_RANGE, SONAR_NO_ECHO, m_to_tenth_inches, rad_to_heading,
    voltage_raw, wrap_angle,
};
use smokenav_scout_codec::{Battery, Command, DiffDrive, MotorStatus, StateReply, WheelSpeeds};

/// A planar pose, m and rad.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Pose {
    pub fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    /// `self ∘ other`.
    pub fn compose(&self, o: &Pose) -> Pose {
        let (s, c) = self.theta.sin_cos();
        Pose {
            x: self.x + c * o.x - s * o.y,
            y: self.y + s * o.x + c * o.y,
            theta: wrap_angle(self.theta + o.theta),
        }
    }

    pub fn inverse(&self) -> Pose {
        let (s, c) = self.theta.sin_cos();
        Pose {
            x: -(c * self.x + s * self.y),
            y: s * self.x - c * self.y,
            theta: wrap_angle(-self.theta),
        }
    }
}

/// Where the reported pose comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Kinematics {
    /// The emulator integrates the commanded wheel speeds itself.
    #[default]
    Internal,
    /// Whoever drives the emulator (the simulator) feeds the pose with
    /// `set_pose` and reads the commanded wheel speeds; `dp`/`da`/`zr` move
    /// the robot's odometry origin relative to that pose.
    External,
}

/// The firing schedule the robot starts with. Nomadic does not document the
/// power-on order; we assume all sixteen in index order at 15 × 4 ms.
pub const DEFAULT_SONAR_RATE: u8 = 15;

#[derive(Debug, Clone)]
pub struct RobotModel {
    drive: DiffDrive,
    kinematics: Kinematics,
    /// Internal: the odometry pose. External: the last fed pose.
    pose: Pose,
    /// External only: robot odometry frame = `origin ∘ fed pose`.
    origin: Pose,
    wheels: WheelSpeeds,
    now: u64,
    start: u64,
    last_command: u64,
    watchdog_s: u8,
    watchdog_trips: u64,
    sonar_fed: [u8; SONARS],
    sonar_reported: [u8; SONARS],
    sonar_rate: u8,
    sonar_order: SonarOrder,
    fire_cursor: usize,
    next_fire: u64,
    pub bumpers: u32,
    pub estop: bool,
    pub battery: Battery,
    pub plugged_in: bool,
    pub charging: bool,
    pub cpu_v: f64,
    pub motor_v: f64,
}

impl RobotModel {
    pub fn new(drive: DiffDrive, kinematics: Kinematics, now: u64) -> Self {
        let all: Vec<u8> = (0..SONARS as u8).collect();
        Self {
            drive,
            kinematics,
            pose: Pose::default(),
            origin: Pose::default(),
            wheels: WheelSpeeds::default(),
            now,
            start: now,
            last_command: now,
            watchdog_s: 0,
            watchdog_trips: 0,
            sonar_fed: [SONAR_NO_ECHO; SONARS],
            sonar_reported: [SONAR_NO_ECHO; SONARS],
            sonar_rate: DEFAULT_SONAR_RATE,
            sonar_order: SonarOrder::from_indices(&all).unwrap_or(SonarOrder::DISABLED),
            fire_cursor: 0,
            next_fire: now,
            bumpers: 0,
            estop: false,
            battery: Battery::High,
            plugged_in: false,
            charging: false,
            cpu_v: 11.5,
            motor_v: 12.3,
        }
    }

    pub fn drive(&self) -> DiffDrive {
        self.drive
    }

    /// Catches the model up to `now`: motion, watchdog, sonar firings.
    pub fn advance(&mut self, now: u64) {
        if now <= self.now {
            return;
        }
        if self.watchdog_s > 0 && self.moving() {
            let deadline = self.last_command + self.watchdog_s as u64 * 1_000_000_000;
            if deadline < now {
                if deadline > self.now {
                    self.integrate(deadline);
                }
                self.wheels = WheelSpeeds::default();
                self.watchdog_trips += 1;
            }
        }
        self.integrate(now);
        self.fire_sonars(now);
    }

    fn moving(&self) -> bool {
        self.wheels.left != 0.0 || self.wheels.right != 0.0
    }

    fn integrate(&mut self, to: u64) {
        let dt = to.saturating_sub(self.now) as f64 * 1e-9;
        self.now = self.now.max(to);
        if self.kinematics == Kinematics::External || dt <= 0.0 {
            return;
        }
        let (v, w) = self.drive.body_for(self.wheels);
        let th = self.pose.theta;
        if w.abs() < 1e-9 {
            self.pose.x += v * dt * th.cos();
            self.pose.y += v * dt * th.sin();
        } else {
            // Exact arc for constant wheel speeds.
            let r = v / w;
            self.pose.x += r * ((th + w * dt).sin() - th.sin());
            self.pose.y -= r * ((th + w * dt).cos() - th.cos());
        }
        self.pose.theta = wrap_angle(th + w * dt);
    }

    fn fire_sonars(&mut self, now: u64) {
        let order = self.sonar_order.raw();
        let n = self.sonar_order.indices().count();
        if n == 0 {
            return;
        }
        if self.sonar_rate == 0 {
            for &i in &order[..n] {
                self.sonar_reported[i as usize] = self.sonar_fed[i as usize];
            }
            return;
        }
        let period = self.sonar_rate as u64 * 4_000_000;
        // Fed values only change between calls, so after one full round every
        // sonar in the order holds the current value: cap the loop there.
        let mut fired = 0;
        while self.next_fire <= now && fired < n {
            let i = order[self.fire_cursor % n] as usize;
            self.sonar_reported[i] = self.sonar_fed[i];
            self.fire_cursor = (self.fire_cursor + 1) % n;
            self.next_fire += period;
            fired += 1;
        }
        if self.next_fire <= now {
            let skip = (now - self.next_fire) / period + 1;
            self.fire_cursor = ((self.fire_cursor as u64 + skip) % n as u64) as usize;
            self.next_fire += skip * period;
        }
    }

    /// The pose the robot reports.
    pub fn odometry_pose(&self) -> Pose {
        match self.kinematics {
            Kinematics::Internal => self.pose,
            Kinematics::External => self.origin.compose(&self.pose),
        }
    }

    fn define_pose(&mut self, target: Pose) {
        match self.kinematics {
            Kinematics::Internal => self.pose = target,
            Kinematics::External => self.origin = target.compose(&self.pose.inverse()),
        }
    }

    /// Feeds the pose (External) or overrides the integrated one (Internal).
    pub fn set_pose(&mut self, now: u64, pose: Pose) {
        self.advance(now);
        self.pose = pose;
    }

    pub fn set_sonar_inches(&mut self, now: u64, inches: [u8; SONARS]) {
        self.advance(now);
        self.sonar_fed = inches;
    }

    pub fn wheels(&self) -> WheelSpeeds {
        self.wheels
    }

    pub fn watchdog_s(&self) -> u8 {
        self.watchdog_s
    }

    pub fn watchdog_trips(&self) -> u64 {
        self.watchdog_trips
    }

    pub fn sonar_config(&self) -> (u8, SonarOrder) {
        (self.sonar_rate, self.sonar_order)
    }

    pub fn sonar_reported(&self) -> [u8; SONARS] {
        self.sonar_reported
    }

    /// Runs a command received at `now` and returns the state to reply with.
    pub fn execute(&mut self, now: u64, cmd: &Command) -> StateReply {
        self.advance(now);
        // Any command, gs included, feeds the robot-side watchdog.
        self.last_command = now;
        match *cmd {
            Command::GetState => {}
            Command::Stop | Command::Limp => self.wheels = WheelSpeeds::default(),
            Command::Velocity(args) => {
                self.wheels = if self.estop {
                    WheelSpeeds::default()
                } else {
                    self.drive.wheels_from_words(args)
                };
            }
            Command::ConfSonar { rate, order } => {
                self.sonar_rate = rate;
                self.sonar_order = order;
                self.fire_cursor = 0;
                self.next_fire = now;
                self.fire_sonars(now);
            }
            Command::ConfTimeout(s) => self.watchdog_s = s,
            Command::DefinePosition { x, y } => {
                let p = self.odometry_pose();
                self.define_pose(Pose::new(
                    units::tenth_inches_to_m(x),
                    units::tenth_inches_to_m(y),
                    p.theta,
                ));
            }
            Command::DefineAngles { heading, .. } => {
                let p = self.odometry_pose();
                self.define_pose(Pose::new(p.x, p.y, units::tenth_degrees_to_rad(heading)));
            }
            Command::Zero => {
                self.wheels = WheelSpeeds::default();
                self.define_pose(Pose::default());
            }
        }
        self.state()
    }

    /// The state packet as of the last `advance`.
    pub fn state(&self) -> StateReply {
        let p = self.odometry_pose();
        let args = self.drive.vm_args(self.wheels);
        StateReply {
            sonar_in: self.sonar_reported,
            bumpers: self.bumpers & 0xFF_FFFF,
            x: m_to_tenth_inches(p.x),
            y: m_to_tenth_inches(p.y),
            heading: rad_to_heading(p.theta),
            turret: 0,
            velocity: args,
            compass: 0,
            motor: MotorStatus::new(
                self.wheels.left != 0.0,
                self.wheels.right != 0.0,
                self.battery,
                self.plugged_in,
                self.charging,
                self.estop,
            ),
            // Milliseconds since power-on: the unit of the 6811 counter is
            // not documented.
            time: ((self.now - self.start) / 1_000_000) as u32,
            cpu_voltage_raw: voltage_raw(self.cpu_v, CPU_VOLTAGE_RANGE),
            motor_voltage_raw: voltage_raw(self.motor_v, MOTOR_VOLTAGE_RANGE),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_scout_codec::WheelOrder;
    use std::f64::consts::PI;

    const S: u64 = 1_000_000_000;

    fn model() -> RobotModel {
        RobotModel::new(
            DiffDrive::new(0.345, WheelOrder::RightLeft),
            Kinematics::Internal,
            0,
        )
    }

    #[test]
    fn vm_100_100_drives_2_54_cm_per_second_forward() {
        let mut m = model();
        // vm(100, 100, 0) = 10 in/s = 0.254 m/s on both wheels.
        m.execute(0, &Command::Velocity([100, 100, 0]));
        let s = m.execute(2 * S, &Command::GetState);
        assert_eq!(s.x, 200, "20 in after 2 s, in tenths");
        assert_eq!(s.y, 0);
        assert_eq!(s.velocity, [100, 100, 0]);
        assert!(s.motor.left_moving() && s.motor.right_moving());
    }

    #[test]
    fn right_wheel_faster_turns_counter_clockwise() {
        let mut m = model();
        let w = m.drive().wheels_for(0.0, PI / 4.0);
        m.execute(0, &Command::Velocity(m.drive().vm_args(w)));
        let s = m.execute(2 * S, &Command::GetState);
        // ≈ 90° after 2 s at 45°/s (wheel speeds are rounded to 1/10 in/s).
        // 45°/s ⇒ 53.3 tenth-in/s per wheel, sent as 53: 89.4° after 2 s.
        assert!((s.heading - 900).abs() <= 10, "heading {}", s.heading);
    }

    #[test]
    fn watchdog_stops_wheels_after_silence() {
        let mut m = model();
        m.execute(0, &Command::ConfTimeout(1));
        m.execute(0, &Command::Velocity([100, 100, 0]));
        m.advance(3 * S);
        assert_eq!(m.wheels(), WheelSpeeds::default());
        assert_eq!(m.watchdog_trips(), 1);
        // Moved for exactly the 1 s watchdog period: 10 in.
        assert_eq!(m.state().x, 100);
    }

    #[test]
    fn polling_gs_keeps_the_watchdog_fed() {
        let mut m = model();
        m.execute(0, &Command::ConfTimeout(1));
        m.execute(0, &Command::Velocity([100, 100, 0]));
        for k in 1..=30 {
            m.execute(k * S / 10, &Command::GetState);
        }
        assert_eq!(m.watchdog_trips(), 0);
        assert_eq!(m.state().x, 300);
    }

    #[test]
    fn st_stops_and_dp_redefines_position() {
        let mut m = model();
        m.execute(0, &Command::Velocity([100, 100, 0]));
        m.execute(S, &Command::Stop);
        let s = m.execute(2 * S, &Command::DefinePosition { x: -50, y: 70 });
        assert_eq!((s.x, s.y), (-50, 70));
        assert_eq!(s.velocity, [0, 0, 0]);
        let s = m.execute(
            2 * S,
            &Command::DefineAngles {
                heading: 2700,
                turret: 0,
            },
        );
        assert_eq!(s.heading, 2700);
        let s = m.execute(3 * S, &Command::Zero);
        assert_eq!((s.x, s.y, s.heading), (0, 0, 0));
    }

    #[test]
    fn sonars_fire_in_the_configured_order_at_the_configured_rate() {
        let mut m = model();
        let order = SonarOrder::from_indices(&[3, 5]).unwrap();
        // The power-on schedule (all 16 every 960 ms) has fired each once by 1 s.
        m.set_sonar_inches(0, [40; SONARS]);
        // rate 25 × 4 ms = 100 ms per firing; the conf_sn fires sonar 3 at once.
        m.execute(S, &Command::ConfSonar { rate: 25, order });
        m.set_sonar_inches(S, [60; SONARS]);
        m.advance(S + 50_000_000);
        assert_eq!(m.sonar_reported()[3], 40);
        assert_eq!(m.sonar_reported()[5], 40, "not fired again yet");
        m.advance(S + 100_000_000);
        assert_eq!(m.sonar_reported()[5], 60);
        m.advance(S + 200_000_000);
        assert_eq!(m.sonar_reported()[3], 60);
        // Sonar 7 is not in the order: it keeps its last reading.
        assert_eq!(m.sonar_reported()[7], 40);
    }

    #[test]
    fn disabled_order_freezes_readings() {
        let mut m = model();
        m.set_sonar_inches(0, [30; SONARS]);
        m.advance(2 * S);
        m.execute(
            2 * S,
            &Command::ConfSonar {
                rate: 15,
                order: SonarOrder::DISABLED,
            },
        );
        m.set_sonar_inches(2 * S, [90; SONARS]);
        m.advance(10 * S);
        assert_eq!(m.sonar_reported(), [30; SONARS]);
    }

    #[test]
    fn external_pose_is_reported_relative_to_the_defined_origin() {
        let mut m = RobotModel::new(
            DiffDrive::new(0.345, WheelOrder::RightLeft),
            Kinematics::External,
            0,
        );
        m.set_pose(0, Pose::new(2.0, 1.0, PI / 2.0));
        m.execute(0, &Command::Zero);
        // The robot moves 1 m along its heading (+y in the world).
        m.set_pose(S, Pose::new(2.0, 2.0, PI / 2.0));
        let s = m.execute(S, &Command::GetState);
        assert_eq!((s.x, s.y, s.heading), (394, 0, 0));
        // Commanded wheels are reported, not integrated.
        m.execute(S, &Command::Velocity([100, 100, 0]));
        m.advance(5 * S);
        assert_eq!(m.state().x, 394);
        assert!((m.wheels().left - 0.254).abs() < 1e-9);
    }

    #[test]
    fn estop_ignores_velocity() {
        let mut m = model();
        m.estop = true;
        let s = m.execute(0, &Command::Velocity([100, 100, 0]));
        assert_eq!(s.velocity, [0, 0, 0]);
        assert!(s.motor.estop());
    }

    #[test]
    fn pose_compose_inverse_is_identity() {
        let p = Pose::new(1.0, -2.0, 0.7);
        let id = p.compose(&p.inverse());
        assert!(id.x.abs() < 1e-12 && id.y.abs() < 1e-12 && id.theta.abs() < 1e-12);
    }
}
