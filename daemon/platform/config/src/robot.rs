//! `[robot]` and `[bus]`: who this robot is and how its processes find each other.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Platform {
    /// Pioneer 2/3 family over ARCOS (the P3-DX of SmokeNav (Santos et al. 2015)).
    Pioneer,
    /// Nomad Scout over the Nomadic direct serial protocol.
    Scout,
}

impl Platform {
    /// The process role (`smokenav-<role>`) that drives this base.
    pub fn driver_role(self) -> &'static str {
        match self {
            Platform::Pioneer => "pioneer",
            Platform::Scout => "scout",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSection {
    /// Human-readable profile name.
    pub name: String,
    pub platform: Platform,
    /// Bus instance prefix: services are named `<instance>/<topic>`. The
    /// `SMOKENAV_INSTANCE` environment variable overrides it, so two robots (or
    /// two test runs) on one machine never collide.
    #[serde(default = "default_instance")]
    pub instance: String,
    /// Robot footprint radius, m (used by the simulator, for sanity checks and
    /// by SLAM's `[slam] clear_footprint`).
    #[serde(default = "default_radius")]
    pub radius_m: f64,
}

fn default_instance() -> String {
    "smokenav".into()
}

fn default_radius() -> f64 {
    0.25
}

impl Validate for RobotSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.non_empty(&format!("{key}.name"), &self.name);
        validate_instance(v, &format!("{key}.instance"), &self.instance);
        v.within(&format!("{key}.radius_m"), self.radius_m, 0.05, 2.0);
    }
}

/// Instance names become part of iceoryx2 service names and file names.
pub fn validate_instance(v: &mut Validator, key: &str, instance: &str) {
    if instance.is_empty()
        || instance.len() > 48
        || !instance
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        v.fail(
            key,
            format!("`{instance}` must be 1–48 characters of [A-Za-z0-9_-]"),
        );
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSection {
    /// Directory for iceoryx2's node and service files. Every process of one
    /// robot must use the same one; under systemd it must be outside
    /// `PrivateTmp` (e.g. `/run/smokenav/iox2/`). The `SMOKENAV_IOX2_ROOT`
    /// environment variable overrides it. Unset: iceoryx2's default `/tmp/iceoryx2/`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub root_path: Option<String>,
    /// How often each process publishes its `Health`, s.
    #[serde(default = "default_health_period")]
    pub health_period_s: f64,
    /// A process reports `degraded` while a rate it publishes (scans,
    /// odometry, fused output) runs below this fraction of its expected rate.
    #[serde(default = "default_health_rate_floor")]
    pub health_rate_floor: f64,
}

fn default_health_period() -> f64 {
    1.0
}
fn default_health_rate_floor() -> f64 {
    0.8
}

impl Default for BusSection {
    fn default() -> Self {
        Self {
            root_path: None,
            health_period_s: default_health_period(),
            health_rate_floor: default_health_rate_floor(),
        }
    }
}

impl Validate for BusSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        if let Some(p) = &self.root_path
            && !p.starts_with('/')
        {
            v.fail(
                format!("{key}.root_path"),
                format!("`{p}` must be an absolute path"),
            );
        }
        v.within(
            &format!("{key}.health_period_s"),
            self.health_period_s,
            0.05,
            60.0,
        );
        v.within(
            &format!("{key}.health_rate_floor"),
            self.health_rate_floor,
            0.05,
            1.0,
        );
    }
}
