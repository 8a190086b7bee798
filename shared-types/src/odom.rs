//! Wheel odometry and velocity commands.

use crate::header::Header;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Bits of [`Odometry::flags`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OdometryFlags;

impl OdometryFlags {
    /// The motors are powered.
    pub const MOTORS_ENABLED: u32 = 1 << 0;
    /// The left wheel is stalled.
    pub const LEFT_STALL: u32 = 1 << 1;
    /// The right wheel is stalled.
    pub const RIGHT_STALL: u32 = 1 << 2;
    /// Odometry was reset (robot reconnected or zeroed); pose jumps are expected.
    pub const RESET: u32 = 1 << 3;
}

/// Pose of the robot base in its odometry frame, integrated from the wheels.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::Odometry")]
pub struct Odometry {
    /// Stamp, sequence number, odometry frame (`odom`).
    pub header: Header,
    /// Position in the odometry frame, m.
    pub x: f64,
    /// Position in the odometry frame, m.
    pub y: f64,
    /// Heading, rad, normalised to (-π, π].
    pub theta: f64,
    /// Forward velocity, m/s.
    pub linear: f64,
    /// Turn rate, rad/s (counter-clockwise positive).
    pub angular: f64,
    /// [`OdometryFlags`] bits.
    pub flags: u32,
    /// One bit per bumper segment that is pressed (front bits 0–7, rear 8–15).
    pub bumpers: u32,
    /// Battery voltage, V (0 when the base does not report it).
    pub battery_v: f32,
    /// Zero.
    pub _reserved: u32,
}

impl Odometry {
    /// Whether the motors are powered.
    pub fn motors_enabled(&self) -> bool {
        self.flags & OdometryFlags::MOTORS_ENABLED != 0
    }

    /// Whether either wheel is stalled.
    pub fn stalled(&self) -> bool {
        self.flags & (OdometryFlags::LEFT_STALL | OdometryFlags::RIGHT_STALL) != 0
    }
}

/// A velocity command for the base, published on `base/cmd_vel`.
/// Drivers stop the robot when these stop arriving.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::VelocityCommand")]
pub struct VelocityCommand {
    /// Stamp, sequence number, frame.
    pub header: Header,
    /// Forward velocity, m/s.
    pub linear: f64,
    /// Turn rate, rad/s (counter-clockwise positive).
    pub angular: f64,
}

pub use crate::geometry::normalize_angle;

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn angles_wrap_into_half_open_interval() {
        assert!((normalize_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((normalize_angle(-PI) - PI).abs() < 1e-12);
        assert!((normalize_angle(0.5) - 0.5).abs() < 1e-12);
        assert!((normalize_angle(-7.0) - (-7.0 + 2.0 * PI)).abs() < 1e-12);
    }
}
