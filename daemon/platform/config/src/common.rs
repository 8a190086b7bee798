//! Types shared by several sections.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

/// A 2D mounting pose in the robot's base frame (`base_link`: x forward, y left, z up).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MountPose {
    /// Forward offset from the base centre, m.
    pub x: f64,
    /// Leftward offset, m.
    pub y: f64,
    /// Heading relative to the robot's forward axis, degrees, counter-clockwise positive.
    pub yaw_deg: f64,
}

impl MountPose {
    pub fn yaw_rad(&self) -> f64 {
        self.yaw_deg.to_radians()
    }
}

impl Validate for MountPose {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.within(&format!("{key}.x"), self.x, -5.0, 5.0);
        v.within(&format!("{key}.y"), self.y, -5.0, 5.0);
        v.within(&format!("{key}.yaw_deg"), self.yaw_deg, -360.0, 360.0);
    }
}

/// Where a device is: a serial device path or `tcp://host:port`.
pub fn validate_port(v: &mut Validator, key: &str, port: &str) {
    if port.trim().is_empty() {
        v.fail(
            key,
            "must name a device (e.g. /dev/ttyACM0) or tcp://host:port",
        );
    } else if let Some(rest) = port.strip_prefix("tcp://") {
        let ok = rest
            .rsplit_once(':')
            .is_some_and(|(host, p)| !host.is_empty() && p.parse::<u16>().is_ok_and(|p| p > 0));
        if !ok {
            v.fail(key, format!("`{port}` is not of the form tcp://host:port"));
        }
    }
}

/// Serial baud rates the devices we drive use.
pub const STANDARD_BAUDS: &[u32] = &[
    4800, 9600, 19200, 38400, 57600, 115200, 230400, 250000, 500000, 750000, 921600,
];

pub fn validate_baud(v: &mut Validator, key: &str, baud: u32) {
    if !STANDARD_BAUDS.contains(&baud) {
        v.fail(
            key,
            format!("{baud} is not a standard baud rate ({STANDARD_BAUDS:?})"),
        );
    }
}
