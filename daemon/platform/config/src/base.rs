//! `[base]`: the mobile base (Pioneer over ARCOS, or Nomad Scout).

use crate::common::{validate_baud, validate_port};
use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseSection {
    /// Serial device (`/dev/pioneer`) or `tcp://127.0.0.1:8101` (MobileSim/AMRISim).
    pub port: String,
    /// Serial baud rate. Pioneer controllers open at 9600; the Scout's default is 38400.
    pub baud: u32,
    /// The robot is stopped when no velocity command arrived for this long, s.
    /// Two command periods at the 10 Hz command rate: one late command does
    /// not stop the robot, a dead controller does within 0.2 s. Time to
    /// standstill after a crash is this plus v / deceleration (0.3 s from
    /// 0.3 m/s at 1 m/s²), so every 0.1 s here costs 3 cm of coasting.
    #[serde(default = "default_cmd_timeout")]
    pub cmd_timeout_s: f64,
    /// Commands are clamped to these limits.
    #[serde(default = "default_max_linear")]
    pub max_linear_mps: f64,
    #[serde(default = "default_max_angular")]
    pub max_angular_dps: f64,
    /// Rate at which odometry (and sonar) is published, Hz.
    #[serde(default = "default_rate")]
    pub rate_hz: f64,
    /// Seconds without a reply before the link counts as lost and is reopened.
    #[serde(default = "default_link_timeout")]
    pub link_timeout_s: f64,
    #[serde(default = "default_odom_frame")]
    pub odom_frame: String,
    /// Pioneer-only options.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pioneer: Option<PioneerOptions>,
    /// Scout-only options.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scout: Option<ScoutOptions>,
}

fn default_cmd_timeout() -> f64 {
    0.2
}
fn default_max_linear() -> f64 {
    0.5
}
fn default_max_angular() -> f64 {
    60.0
}
fn default_rate() -> f64 {
    10.0
}
fn default_link_timeout() -> f64 {
    1.0
}
fn default_odom_frame() -> String {
    "odom".into()
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PioneerOptions {
    /// Use this subclass's conversion factors instead of the one the robot
    /// reports in SYNC2 (for controllers reporting an unknown subclass).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub subclass: Option<String>,
    /// Turn the sonar ring on when connecting (SONAR 1).
    #[serde(default = "pioneer_default_true")]
    pub sonar: bool,
    /// Enable the motors when connecting (ENABLE 1). Off: odometry and sonar
    /// only, the robot never moves.
    #[serde(default = "pioneer_default_true")]
    pub enable_motors: bool,
    /// Zero the controller's odometry when connecting (SETO). The published
    /// odometry starts at (0, 0, 0) either way.
    #[serde(default)]
    pub reset_odometry: bool,
    /// Wait this long for each SYNC reply, s.
    #[serde(default = "pioneer_default_sync_timeout")]
    pub sync_timeout_s: f64,
    /// Velocity commands are repeated (or a PULSE sent) at least this often,
    /// s; must stay below the controller's watchdog (2 s on a P3-DX).
    #[serde(default = "pioneer_default_refresh")]
    pub refresh_s: f64,
    /// When the controller goes silent (`cmd_timeout_s`), stop with ARCOS's
    /// E_STOP, which overrides the deceleration, instead of VEL 0 at the
    /// robot's configured deceleration (v / decel more coasting: 0.3 s and
    /// 4.5 cm from 0.3 m/s at 1 m/s²). Normal stops always ramp down.
    #[serde(default = "pioneer_default_true")]
    pub estop_on_timeout: bool,
}

impl Default for PioneerOptions {
    fn default() -> Self {
        Self {
            subclass: None,
            sonar: true,
            enable_motors: true,
            reset_odometry: false,
            sync_timeout_s: pioneer_default_sync_timeout(),
            refresh_s: pioneer_default_refresh(),
            estop_on_timeout: true,
        }
    }
}

fn pioneer_default_true() -> bool {
    true
}
fn pioneer_default_sync_timeout() -> f64 {
    0.3
}
fn pioneer_default_refresh() -> f64 {
    0.5
}

/// Argument order of the Scout's `vm` command (the codec's own type).
pub use smokenav_scout_codec::WheelOrder;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScoutOptions {
    /// Argument order of the `vm` command. The public sources disagree, so
    /// this is a choice per robot (see `config/nomad-scout.toml`).
    pub wheel_order: WheelOrder,
    /// Distance between the wheels, m.
    pub track_m: f64,
    /// Robot-side watchdog (`conf_tm`), s: the firmware stops the wheels if the host goes quiet.
    #[serde(default = "default_watchdog")]
    pub watchdog_s: u8,
    /// Sonar firing interval in 4 ms units (`conf_sn` rate).
    #[serde(default = "default_sonar_rate")]
    pub sonar_rate: u8,
    /// Sonar firing order (`conf_sn` order), at most 16 indices.
    #[serde(default = "default_sonar_order")]
    pub sonar_order: Vec<u8>,
    /// Keep the robot's odometry when the driver starts. By default the
    /// driver zeroes it (`dp(0,0)`, `da(0,0)`) on its first connection, so
    /// every run starts at the origin; a reconnect never zeroes.
    #[serde(default)]
    pub keep_odometry: bool,
}

fn default_watchdog() -> u8 {
    1
}
fn default_sonar_rate() -> u8 {
    15
}
fn default_sonar_order() -> Vec<u8> {
    vec![0, 2, 15, 1, 14, 3, 13, 4, 12, 5, 11, 6, 10, 7, 9, 8]
}

impl Validate for BaseSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        validate_port(v, &format!("{key}.port"), &self.port);
        validate_baud(v, &format!("{key}.baud"), self.baud);
        v.within(
            &format!("{key}.cmd_timeout_s"),
            self.cmd_timeout_s,
            0.05,
            10.0,
        );
        v.within(
            &format!("{key}.max_linear_mps"),
            self.max_linear_mps,
            0.0,
            2.2,
        );
        v.within(
            &format!("{key}.max_angular_dps"),
            self.max_angular_dps,
            0.0,
            500.0,
        );
        v.within(&format!("{key}.rate_hz"), self.rate_hz, 1.0, 100.0);
        v.within(
            &format!("{key}.link_timeout_s"),
            self.link_timeout_s,
            0.1,
            30.0,
        );
        v.non_empty(&format!("{key}.odom_frame"), &self.odom_frame);
        if let Some(p) = &self.pioneer {
            if let Some(sub) = &p.subclass {
                v.non_empty(&format!("{key}.pioneer.subclass"), sub);
            }
            v.within(
                &format!("{key}.pioneer.sync_timeout_s"),
                p.sync_timeout_s,
                0.05,
                5.0,
            );
            v.within(&format!("{key}.pioneer.refresh_s"), p.refresh_s, 0.05, 1.9);
        }
        if let Some(s) = &self.scout {
            v.within(&format!("{key}.scout.track_m"), s.track_m, 0.1, 1.0);
            if s.sonar_order.len() > 16 {
                v.fail(
                    format!("{key}.scout.sonar_order"),
                    format!("at most 16 entries, got {}", s.sonar_order.len()),
                );
            }
            if let Some(bad) = s.sonar_order.iter().find(|&&i| i > 15) {
                v.fail(
                    format!("{key}.scout.sonar_order"),
                    format!("sonar index {bad} is not 0–15"),
                );
            }
        }
    }
}

#[cfg(test)]
mod pioneer_options_tests {
    use crate::RobotConfig;
    use std::path::Path;

    fn profile_with(pioneer: &str) -> String {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../config/pioneer-3dx.toml");
        let text = std::fs::read_to_string(path).unwrap();
        text.replace("[base.pioneer]\n", &format!("[base.pioneer]\n{pioneer}\n"))
    }

    #[test]
    fn pioneer_options_default_to_sonar_on_motors_on_half_second_refresh() {
        let cfg = RobotConfig::parse(&profile_with(""), Path::new("t.toml")).unwrap();
        let p = cfg.base.pioneer.unwrap();
        assert!(p.sonar && p.enable_motors && !p.reset_odometry);
        assert_eq!((p.sync_timeout_s, p.refresh_s), (0.3, 0.5));
        assert_eq!(p, super::PioneerOptions::default());
    }

    #[test]
    fn refresh_at_or_above_the_2_s_watchdog_is_rejected() {
        let e =
            RobotConfig::parse(&profile_with("refresh_s = 2.5"), Path::new("t.toml")).unwrap_err();
        assert!(e.to_string().contains("base.pioneer.refresh_s"), "{e}");
        let cfg = RobotConfig::parse(
            &profile_with("subclass = \"p3dx-sh\"\nsonar = false"),
            Path::new("t.toml"),
        )
        .unwrap();
        let p = cfg.base.pioneer.unwrap();
        assert_eq!(p.subclass.as_deref(), Some("p3dx-sh"));
        assert!(!p.sonar);
    }
}
