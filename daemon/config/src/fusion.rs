//! `[fusion]`: the synchroniser and the SmokeNav methods.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Method {
    #[serde(rename = "laser-only")]
    LaserOnly,
    #[serde(rename = "v1")]
    V1,
    #[serde(rename = "v2")]
    V2,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FusionSection {
    #[serde(default = "default_method")]
    pub method: Method,
    /// Sonar readings beyond this are treated as saturated (the paper limited sonar to 2.5 m).
    #[serde(default = "default_cap")]
    pub sonar_cap_m: f64,
    #[serde(default)]
    pub sync: SyncParams,
}

fn default_method() -> Method {
    Method::V2
}
fn default_cap() -> f64 {
    2.5
}

impl Default for FusionSection {
    fn default() -> Self {
        Self {
            method: default_method(),
            sonar_cap_m: default_cap(),
            sync: SyncParams::default(),
        }
    }
}

/// Approximate-time synchronisation (ROS message_filters semantics plus a timeout).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SyncParams {
    /// Messages kept per input topic.
    pub queue_size: usize,
    /// A set whose stamps span more than this is never formed, s.
    pub max_interval_s: f64,
    /// An input silent for this long no longer holds up the output, s.
    pub timeout_s: f64,
}

impl Default for SyncParams {
    fn default() -> Self {
        Self {
            queue_size: 8,
            max_interval_s: 0.15,
            timeout_s: 0.5,
        }
    }
}

impl Validate for FusionSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        v.within(&format!("{key}.sonar_cap_m"), self.sonar_cap_m, 0.2, 20.0);
        if !(2..=1000).contains(&self.sync.queue_size) {
            v.fail(format!("{key}.sync.queue_size"), format!("must be 2–1000, got {}", self.sync.queue_size));
        }
        v.within(&format!("{key}.sync.max_interval_s"), self.sync.max_interval_s, 0.001, 5.0);
        v.within(&format!("{key}.sync.timeout_s"), self.sync.timeout_s, 0.01, 10.0);
    }
}
