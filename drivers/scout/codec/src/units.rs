//! Wire units ↔ SI, and the Scout's differential-drive kinematics.
//!
//! The Scout reports position in 1/10 inch, heading in 1/10 degree (0–3599,
//! counter-clockwise positive), wheel speeds in 1/10 in/s and sonar ranges in
//! whole inches (255 = no echo).

use crate::int::saturate_sm16;
use crate::reply::{MotorStatus, SONARS, StateReply};
use std::f64::consts::{PI, TAU};

pub const METRES_PER_INCH: f64 = 0.0254;
pub const METRES_PER_TENTH_INCH: f64 = 0.00254;
/// A sonar byte of 255 means no echo: 255 in = 6.477 m is the ring's maximum.
pub const SONAR_NO_ECHO: u8 = 255;
pub const SONAR_MAX_RANGE_M: f64 = SONAR_NO_ECHO as f64 * METRES_PER_INCH;
/// `RANGE_CPU_VOLTAGE` in `Ndirect.c` (measured after the slip-ring losses).
pub const CPU_VOLTAGE_RANGE: f64 = 12.0;
/// `RANGE_MOTOR_VOLTAGE` in `Ndirect.c`.
pub const MOTOR_VOLTAGE_RANGE: f64 = 12.85;

pub fn tenth_inches_to_m(v: i16) -> f64 {
    v as f64 * METRES_PER_TENTH_INCH
}

/// Metres to 1/10 inch, rounded and clamped to ±32767 (±83.2 m).
pub fn m_to_tenth_inches(m: f64) -> i16 {
    saturate_sm16(m / METRES_PER_TENTH_INCH)
}

/// Wraps an angle to (-π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let mut a = a % TAU;
    if a <= -PI {
        a += TAU;
    } else if a > PI {
        a -= TAU;
    }
    a
}

/// 1/10 degree to radians in (-π, π].
pub fn tenth_degrees_to_rad(v: i16) -> f64 {
    wrap_angle((v as f64 / 10.0).to_radians())
}

/// Radians to the robot's heading convention, 0–3599 tenths of a degree.
pub fn rad_to_heading(rad: f64) -> i16 {
    if !rad.is_finite() {
        return 0;
    }
    let tenths = (rad.to_degrees() * 10.0).round().rem_euclid(3600.0);
    // rem_euclid can return 3600.0 after rounding of values just below it.
    (tenths as i16) % 3600
}

/// One sonar reading in SI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SonarRange {
    /// An echo at this range, m.
    Echo(f64),
    /// 255 in: nothing within range, or a surface at a specular angle.
    NoEcho,
}

pub fn sonar_range(inches: u8) -> SonarRange {
    if inches == SONAR_NO_ECHO {
        SonarRange::NoEcho
    } else {
        SonarRange::Echo(inches as f64 * METRES_PER_INCH)
    }
}

/// Metres to the sonar byte (for emulators): rounded inches, ≥ 6.477 m → 255.
pub fn sonar_byte(range_m: f64) -> u8 {
    if range_m.is_nan() || range_m >= SONAR_MAX_RANGE_M {
        return SONAR_NO_ECHO;
    }
    (range_m / METRES_PER_INCH)
        .round()
        .clamp(0.0, (SONAR_NO_ECHO - 1) as f64) as u8
}

/// `v = (2 + 3·raw/255) · range/5` (`voltConvert` in `Ndirect.c`).
pub fn voltage(raw: u8, range: f64) -> f64 {
    (2.0 + 3.0 * raw as f64 / 255.0) * range / 5.0
}

/// The raw byte whose [`voltage`] is closest to `v`.
pub fn voltage_raw(v: f64, range: f64) -> u8 {
    if v.is_nan() {
        return 0;
    }
    ((v * 5.0 / range - 2.0) * 255.0 / 3.0)
        .round()
        .clamp(0.0, 255.0) as u8
}

/// Which wheel the first `vm` argument (and the first state velocity word)
/// drives. The sources disagree: Nomadic's `scout_vm` sends `vm(right, left,
/// 0)` and its header names state word 38 `STATE_VEL_RIGHT`; CARMEN sends
/// `vm(left, right, 0)`. One setting covers both directions, as Nomadic's
/// own headers are consistent with each other.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "kebab-case")
)]
pub enum WheelOrder {
    /// `vm(right, left, 0)`: Nomadic's own `scout_vm` macro.
    #[default]
    RightLeft,
    /// `vm(left, right, 0)`: CARMEN's scout_lib.
    LeftRight,
}

/// Wheel surface speeds, m/s.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WheelSpeeds {
    pub left: f64,
    pub right: f64,
}

/// Differential-drive geometry and the `vm` argument order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiffDrive {
    /// Distance between the wheels, m (Nomadic's 0.118597 in/deg ⇒ 0.345 m).
    pub track_m: f64,
    pub order: WheelOrder,
}

impl DiffDrive {
    pub fn new(track_m: f64, order: WheelOrder) -> Self {
        Self { track_m, order }
    }

    /// Wheel speeds for a body velocity (m/s, rad/s counter-clockwise).
    pub fn wheels_for(&self, linear: f64, angular: f64) -> WheelSpeeds {
        let half = angular * self.track_m / 2.0;
        WheelSpeeds {
            left: linear - half,
            right: linear + half,
        }
    }

    /// Body velocity (m/s, rad/s) of given wheel speeds.
    pub fn body_for(&self, w: WheelSpeeds) -> (f64, f64) {
        ((w.left + w.right) / 2.0, (w.right - w.left) / self.track_m)
    }

    /// `vm` arguments (1/10 in/s) for wheel speeds, clamped to ±32767.
    pub fn vm_args(&self, w: WheelSpeeds) -> [i16; 3] {
        let l = saturate_sm16(w.left / METRES_PER_TENTH_INCH);
        let r = saturate_sm16(w.right / METRES_PER_TENTH_INCH);
        match self.order {
            WheelOrder::RightLeft => [r, l, 0],
            WheelOrder::LeftRight => [l, r, 0],
        }
    }

    /// Wheel speeds from `vm` arguments or state velocity words.
    pub fn wheels_from_words(&self, words: [i16; 3]) -> WheelSpeeds {
        let (a, b) = (tenth_inches_to_m(words[0]), tenth_inches_to_m(words[1]));
        match self.order {
            WheelOrder::RightLeft => WheelSpeeds { left: b, right: a },
            WheelOrder::LeftRight => WheelSpeeds { left: a, right: b },
        }
    }

    /// A state reply in SI units.
    pub fn state_si(&self, s: &StateReply) -> StateSi {
        let wheels = self.wheels_from_words(s.velocity);
        let (linear, angular) = self.body_for(wheels);
        StateSi {
            x_m: tenth_inches_to_m(s.x),
            y_m: tenth_inches_to_m(s.y),
            heading_rad: tenth_degrees_to_rad(s.heading),
            wheels,
            linear_mps: linear,
            angular_rps: angular,
            sonar: s.sonar_in.map(sonar_range),
            bumpers: s.bumpers,
            motor: s.motor,
            cpu_v: voltage(s.cpu_voltage_raw, CPU_VOLTAGE_RANGE),
            motor_v: voltage(s.motor_voltage_raw, MOTOR_VOLTAGE_RANGE),
            time: s.time,
        }
    }
}

/// A state reply in SI units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateSi {
    pub x_m: f64,
    pub y_m: f64,
    /// Counter-clockwise, (-π, π].
    pub heading_rad: f64,
    pub wheels: WheelSpeeds,
    pub linear_mps: f64,
    pub angular_rps: f64,
    pub sonar: [SonarRange; SONARS],
    pub bumpers: u32,
    pub motor: MotorStatus,
    pub cpu_v: f64,
    pub motor_v: f64,
    pub time: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPS: f64 = 1e-9;

    #[test]
    fn nomadic_rotation_constant_matches_0_345_m_track() {
        // scout_vm(t, s) = vm(t + s·0.118597, t − s·0.118597): 0.118597 in per
        // degree of turn is half the track, so the track is 2·0.118597·180/π in.
        let track_in = 2.0 * 0.118597 * 180.0 / PI;
        assert!((track_in - 13.59).abs() < 0.01);
        let drive = DiffDrive::new(track_in * METRES_PER_INCH, WheelOrder::RightLeft);
        // s = 100 tenths of a degree/s, t = 0 ⇒ vm(±11.86, ∓11.86) tenth-in/s.
        let w = drive.wheels_for(0.0, (10.0f64).to_radians());
        let args = drive.vm_args(w);
        assert_eq!(args, [12, -12, 0]);
    }

    #[test]
    fn right_left_order_puts_right_wheel_first() {
        let drive = DiffDrive::new(0.345, WheelOrder::RightLeft);
        // 0.254 m/s straight = 100 tenth-in/s per wheel: vm(100, 100, 0).
        assert_eq!(drive.vm_args(drive.wheels_for(0.254, 0.0)), [100, 100, 0]);
        let w = WheelSpeeds {
            left: -0.2718,
            right: 0.2718,
        };
        assert_eq!(drive.vm_args(w), [107, -107, 0]);
        let swapped = DiffDrive::new(0.345, WheelOrder::LeftRight);
        assert_eq!(swapped.vm_args(w), [-107, 107, 0]);
    }

    #[test]
    fn wheel_words_round_trip_through_both_orders() {
        for order in [WheelOrder::RightLeft, WheelOrder::LeftRight] {
            let drive = DiffDrive::new(0.345, order);
            let w = drive.wheels_for(0.3, -0.5);
            let back = drive.wheels_from_words(drive.vm_args(w));
            assert!((back.left - w.left).abs() < 0.0013);
            assert!((back.right - w.right).abs() < 0.0013);
            let (v, om) = drive.body_for(back);
            assert!((v - 0.3).abs() < 0.002 && (om + 0.5).abs() < 0.01);
        }
    }

    #[test]
    fn huge_speeds_saturate() {
        let drive = DiffDrive::new(0.345, WheelOrder::RightLeft);
        assert_eq!(drive.vm_args(drive.wheels_for(1e6, 0.0)), [32767, 32767, 0]);
    }

    #[test]
    fn heading_tenths_convert_to_wrapped_radians() {
        assert!((tenth_degrees_to_rad(900) - PI / 2.0).abs() < EPS);
        assert!((tenth_degrees_to_rad(2700) + PI / 2.0).abs() < EPS);
        assert!((tenth_degrees_to_rad(1800) - PI).abs() < EPS);
        assert!((tenth_degrees_to_rad(3599) + (0.1f64).to_radians()).abs() < EPS);
        assert_eq!(rad_to_heading(-PI / 2.0), 2700);
        assert_eq!(rad_to_heading(0.0), 0);
        assert_eq!(rad_to_heading(-1e-9), 0);
        assert_eq!(rad_to_heading(f64::NAN), 0);
    }

    #[test]
    fn sonar_255_inches_is_no_echo() {
        assert_eq!(sonar_range(255), SonarRange::NoEcho);
        assert_eq!(sonar_range(100), SonarRange::Echo(2.54));
        assert_eq!(sonar_byte(2.54), 100);
        assert_eq!(sonar_byte(6.477), 255);
        assert_eq!(sonar_byte(6.46), 254);
        assert_eq!(sonar_byte(-1.0), 0);
        assert_eq!(sonar_byte(f64::NAN), 255);
    }

    #[test]
    fn voltage_bytes_follow_volt_convert() {
        // raw 255 ⇒ the full range; raw 0 ⇒ 2/5 of it.
        assert!((voltage(255, CPU_VOLTAGE_RANGE) - 12.0).abs() < EPS);
        assert!((voltage(0, MOTOR_VOLTAGE_RANGE) - 5.14).abs() < EPS);
        assert_eq!(voltage_raw(12.0, CPU_VOLTAGE_RANGE), 255);
        let raw = voltage_raw(11.3, MOTOR_VOLTAGE_RANGE);
        assert!((voltage(raw, MOTOR_VOLTAGE_RANGE) - 11.3).abs() < 0.02);
    }

    #[test]
    fn position_saturates_at_83_m() {
        assert_eq!(m_to_tenth_inches(1.0), 394);
        assert_eq!(m_to_tenth_inches(-100.0), -32767);
        assert!((tenth_inches_to_m(-394) + 1.00076).abs() < 1e-9);
    }
}
