//! Pure odometry from SIPs: 15-bit position wraparound, heading wrap, and
//! the integrator that turns successive SIPs into a continuous pose.

use crate::params::RobotParams;
use crate::sip::Sip;

/// Units of THPOS per revolution (AngleConvFactor = 2π/4096).
pub const HEADING_UNITS: i32 = 4096;

/// Difference between two 15-bit position counters, as ARIA takes it: a jump
/// of more than 0x1000 units is a wrap, not motion.
pub fn wrap15_delta(prev: u16, now: u16) -> i32 {
    let mut d = i32::from(now & 0x7FFF) - i32::from(prev & 0x7FFF);
    if d > 0x1000 {
        d -= 0x8000;
    } else if d < -0x1000 {
        d += 0x8000;
    }
    d
}

/// Difference between two headings in THPOS units, into [-2048, 2048).
pub fn heading_delta(prev: i16, now: i16) -> i32 {
    (i32::from(now) - i32::from(prev) + HEADING_UNITS / 2).rem_euclid(HEADING_UNITS)
        - HEADING_UNITS / 2
}

/// Wraps an angle to (−π, π].
pub fn normalize_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let mut a = a % TAU;
    if a <= -PI {
        a += TAU;
    } else if a > PI {
        a -= TAU;
    }
    a
}

/// Pose and velocity after one SIP, SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdomEstimate {
    pub x_m: f64,
    pub y_m: f64,
    /// rad, (−π, π].
    pub theta: f64,
    pub linear_mps: f64,
    /// rad/s, counter-clockwise positive.
    pub angular_rps: f64,
    /// This SIP only set the baseline (first after start or [`OdometryIntegrator::rebase`]).
    pub baseline: bool,
}

/// Integrates SIP position counters into a pose that starts at (0, 0, 0) and
/// never jumps at the 15-bit wrap.
///
/// The controller reports x, y in its own odometry frame. We keep our own
/// frame: its origin is the pose at the first SIP, and after a reconnect
/// ([`OdometryIntegrator::rebase`]) it continues from the last pose, so a link
/// drop does not teleport the robot.
#[derive(Debug, Clone)]
pub struct OdometryIntegrator {
    params: RobotParams,
    last: Option<(u16, u16, i16)>,
    x_mm: f64,
    y_mm: f64,
    theta: f64,
    /// Our heading minus the controller's.
    offset: f64,
}

impl OdometryIntegrator {
    pub fn new(params: RobotParams) -> Self {
        Self {
            params,
            last: None,
            x_mm: 0.0,
            y_mm: 0.0,
            theta: 0.0,
            offset: 0.0,
        }
    }

    pub fn params(&self) -> &RobotParams {
        &self.params
    }

    /// Switches conversion factors (e.g. a new SYNC2 subclass); keeps the pose.
    pub fn set_params(&mut self, params: RobotParams) {
        self.params = params;
        self.last = None;
    }

    /// The next SIP becomes the new baseline; the pose is kept.
    pub fn rebase(&mut self) {
        self.last = None;
    }

    /// Back to (0, 0, 0) at the next SIP.
    pub fn reset(&mut self) {
        self.last = None;
        self.x_mm = 0.0;
        self.y_mm = 0.0;
        self.theta = 0.0;
    }

    pub fn update(&mut self, sip: &Sip) -> OdomEstimate {
        let p = &self.params;
        let robot_th = f64::from(sip.th) * p.angle_conv;
        let baseline = match self.last {
            None => {
                self.offset = self.theta - robot_th;
                true
            }
            Some((lx, ly, lth)) => {
                let dx = f64::from(wrap15_delta(lx, sip.x_pos())) * p.dist_conv;
                let dy = f64::from(wrap15_delta(ly, sip.y_pos())) * p.dist_conv;
                let (s, c) = self.offset.sin_cos();
                self.x_mm += c * dx - s * dy;
                self.y_mm += s * dx + c * dy;
                // Headings are absolute; the delta only matters across the wrap.
                let dth = f64::from(heading_delta(lth, sip.th)) * p.angle_conv;
                self.theta = normalize_angle(self.theta + dth);
                false
            }
        };
        self.last = Some((sip.x_pos(), sip.y_pos(), sip.th));
        let left = f64::from(sip.left_vel) * p.vel_conv;
        let right = f64::from(sip.right_vel) * p.vel_conv;
        let angular_rps = match sip.rot_vel {
            Some(v) => (f64::from(v) / 10.0).to_radians(),
            None => (right - left) / 2.0 * p.diff_conv,
        };
        OdomEstimate {
            x_m: self.x_mm / 1000.0,
            y_m: self.y_mm / 1000.0,
            theta: self.theta,
            linear_mps: (left + right) / 2.0 / 1000.0,
            angular_rps,
            baseline,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::params_for;

    fn sip(x: u16, y: u16, th: i16) -> Sip {
        Sip {
            packet_type: crate::sip::SIP_STOPPED,
            x: x & 0x7FFF,
            y: y & 0x7FFF,
            th,
            ..Default::default()
        }
    }

    #[test]
    fn forward_across_15_bit_wrap_is_continuous() {
        // 32760 -> 5 is +13 units, not -32755.
        assert_eq!(wrap15_delta(32760, 5), 13);
        assert_eq!(wrap15_delta(5, 32760), -13);
        assert_eq!(wrap15_delta(100, 0x1000 + 100), 0x1000);
        assert_eq!(wrap15_delta(0, 0x1001), 0x1001 - 0x8000);
    }

    #[test]
    fn heading_delta_wraps_at_4096_units() {
        assert_eq!(heading_delta(2040, -2040), 16);
        assert_eq!(heading_delta(-2040, 2040), -16);
        assert_eq!(heading_delta(0, -11), -11);
    }

    #[test]
    fn integrator_follows_counter_through_wrap_p3dx() {
        // p3dx: 0.485 mm per unit. Drive +40 units per SIP from 32700 past 0x7FFF.
        let mut odo = OdometryIntegrator::new(*params_for("p3dx").unwrap());
        let mut x = 32700u32;
        let first = odo.update(&sip(x as u16, 0, 0));
        assert!(first.baseline);
        let mut last = 0.0;
        for _ in 0..10 {
            x = (x + 40) % 0x8000;
            let e = odo.update(&sip(x as u16, 0, 0));
            assert!(e.x_m > last, "odometry went back at counter {x}");
            last = e.x_m;
        }
        assert!((last - 400.0 * 0.485 / 1000.0).abs() < 1e-9, "{last}");
    }

    #[test]
    fn backward_across_zero_is_continuous() {
        let mut odo = OdometryIntegrator::new(*params_for("p3dx-sh").unwrap());
        odo.update(&sip(10, 0, 0));
        let e = odo.update(&sip(0x7FF6, 0, 0)); // 10 -> -10
        assert!((e.x_m + 0.020).abs() < 1e-12, "{}", e.x_m);
    }

    #[test]
    fn pose_starts_at_origin_whatever_the_counters() {
        // Controller at x=1000 units, heading 1024 units (90°).
        let mut odo = OdometryIntegrator::new(*params_for("p3dx-sh").unwrap());
        let e = odo.update(&sip(1000, 0, 1024));
        assert_eq!((e.x_m, e.y_m, e.theta), (0.0, 0.0, 0.0));
        // The controller moves +y in its frame (forward, since it faces +y):
        // in our frame that is +x.
        let e = odo.update(&sip(1000, 100, 1024));
        assert!((e.x_m - 0.1).abs() < 1e-9 && e.y_m.abs() < 1e-5, "{e:?}");
    }

    #[test]
    fn rebase_continues_from_last_pose() {
        let mut odo = OdometryIntegrator::new(*params_for("p3dx-sh").unwrap());
        odo.update(&sip(0, 0, 0));
        odo.update(&sip(500, 0, 0));
        odo.rebase();
        // Controller restarted with its counters at zero.
        let e = odo.update(&sip(0, 0, 0));
        assert!(e.baseline);
        assert!((e.x_m - 0.5).abs() < 1e-9);
        let e = odo.update(&sip(100, 0, 0));
        assert!((e.x_m - 0.6).abs() < 1e-9);
    }

    #[test]
    fn velocities_use_rotvel_when_present_else_wheel_difference() {
        let mut odo = OdometryIntegrator::new(*params_for("p3dx").unwrap());
        let mut s = sip(0, 0, 0);
        // Capture, t=1.82: lvel 262, rvel 137, ROTVEL -200 (-20.0 deg/s).
        s.left_vel = 262;
        s.right_vel = 137;
        s.rot_vel = Some(-200);
        let e = odo.update(&s);
        assert!((e.linear_mps - 0.1995).abs() < 1e-9);
        assert!((e.angular_rps - (-20f64).to_radians()).abs() < 1e-9);
        s.rot_vel = None;
        let e = odo.update(&s);
        // (137 - 262) / 2 * 0.0056 = -0.35 rad/s
        assert!((e.angular_rps + 0.35).abs() < 1e-9);
    }
}
