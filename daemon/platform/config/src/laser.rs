//! `[laser]`: the Hokuyo scanner.

use crate::common::{MountPose, validate_baud, validate_port};
use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaserSection {
    /// Serial device (`/dev/hokuyo`, `/dev/ttyACM0`) or `tcp://host:10940` for Ethernet models.
    pub port: String,
    /// Serial baud rate. USB URG models ignore it; RS-232 URG-04LX boots at 19200
    /// and the driver switches to this rate with `SS`.
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Frame id stamped on published scans.
    #[serde(default = "default_frame")]
    pub frame_id: String,
    /// Where the scanner sits on the robot (its 0° beam along `yaw_deg`).
    pub mount: MountPose,
    /// Request intensities (`ME`) where the model supports them. Never used on a URG-04LX.
    #[serde(default)]
    pub intensity: bool,
    /// Publish every `skip + 1`-th scan only (the sensor's own scan-skip setting).
    #[serde(default)]
    pub skip_scans: u32,
    /// Seconds without a scan before the driver treats the device as gone and reconnects.
    #[serde(default = "default_stall")]
    pub stall_timeout_s: f64,
}

fn default_baud() -> u32 {
    115_200
}

fn default_frame() -> String {
    "laser".into()
}

fn default_stall() -> f64 {
    1.0
}

impl Validate for LaserSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        validate_port(v, &format!("{key}.port"), &self.port);
        validate_baud(v, &format!("{key}.baud"), self.baud);
        v.non_empty(&format!("{key}.frame_id"), &self.frame_id);
        self.mount.validate(&format!("{key}.mount"), v);
        if self.skip_scans > 9 {
            v.fail(
                format!("{key}.skip_scans"),
                format!("must be 0–9 (SCIP limit), got {}", self.skip_scans),
            );
        }
        v.within(
            &format!("{key}.stall_timeout_s"),
            self.stall_timeout_s,
            0.2,
            30.0,
        );
    }
}
