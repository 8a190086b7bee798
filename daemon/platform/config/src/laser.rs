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
    /// The layout of the scans the laser publishes (its own parameters),
    /// for consumers that need it before the first scan arrives (fusion's
    /// sonar-only output). Without it they wait for a scan.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scan: Option<ScanLayout>,
}

/// A rotating scanner's scan layout in its own units, as the sensor states
/// it (a Hokuyo's PP reply: ARES, AMIN, AMAX, AFRT, DMIN, DMAX, SCAN).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanLayout {
    /// Steps in a full turn.
    pub steps_per_turn: u32,
    /// First and last step measured (one beam each).
    pub first_step: u32,
    pub last_step: u32,
    /// The step pointing straight ahead (angle 0).
    pub front_step: u32,
    /// Shortest and longest range measured, mm.
    pub range_min_mm: u32,
    pub range_max_mm: u32,
    /// Motor speed, revolutions per minute.
    pub rpm: u32,
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
        // Every message carries its frame in a fixed 32-byte field: a longer
        // name would be cut on the wire and match no transform.
        if self.frame_id.len() > smokenav_shared_types::header::FRAME_ID_LEN {
            v.fail(
                format!("{key}.frame_id"),
                format!(
                    "must be at most {} bytes (the messages' frame_id field), got {} bytes",
                    smokenav_shared_types::header::FRAME_ID_LEN,
                    self.frame_id.len()
                ),
            );
        }
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
        if let Some(l) = &self.scan {
            let k = format!("{key}.scan");
            if l.steps_per_turn == 0 {
                v.fail(format!("{k}.steps_per_turn"), "must be at least 1");
            }
            if !(l.first_step <= l.last_step && l.last_step < l.steps_per_turn.max(1)) {
                v.fail(
                    format!("{k}.last_step"),
                    format!(
                        "expected first_step <= last_step < steps_per_turn, got {} .. {} of {}",
                        l.first_step, l.last_step, l.steps_per_turn
                    ),
                );
            }
            if l.front_step >= l.steps_per_turn.max(1) {
                v.fail(format!("{k}.front_step"), "must be below steps_per_turn");
            }
            if l.range_min_mm >= l.range_max_mm {
                v.fail(format!("{k}.range_min_mm"), "must be below range_max_mm");
            }
            if l.rpm == 0 {
                v.fail(format!("{k}.rpm"), "must be at least 1");
            }
        }
    }
}
