//! `[slam]`: the particle-filter SLAM.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SlamSection {
    /// Number of particles.
    pub particles: usize,
    /// Map cell size, m.
    pub resolution_m: f64,
    /// How often the map is published, Hz.
    pub map_rate_hz: f64,
}

impl Default for SlamSection {
    fn default() -> Self {
        Self {
            particles: 30,
            resolution_m: 0.05,
            map_rate_hz: 1.0,
        }
    }
}

impl Validate for SlamSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        if !(1..=1000).contains(&self.particles) {
            v.fail(format!("{key}.particles"), format!("must be 1–1000, got {}", self.particles));
        }
        v.within(&format!("{key}.resolution_m"), self.resolution_m, 0.005, 1.0);
        v.within(&format!("{key}.map_rate_hz"), self.map_rate_hz, 0.01, 20.0);
    }
}
