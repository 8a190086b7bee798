//! `[mapping]`: the 2D/3D occupancy mapping process (`smokenav-mapping`).
//!
//! The fusion rule of the published fused grid and projected map, the voxel
//! and cell side, and the publishing rate. Bayes (log-odds with OctoMap's
//! clamping) is the default because it is the rule that leaves a cell seen by
//! one sensor at that sensor's value (Tran et al. 2021); the other rules keep
//! per-sensor maps as well and cost about three times the memory.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

/// How the laser's and the sonar's opinions of a cell are pooled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum MappingRule {
    /// Linear Opinion Pool: weighted mean of the probabilities.
    #[serde(rename = "lop")]
    Lop,
    /// Logarithmic Independent Opinion Pool: weighted geometric mean.
    #[serde(rename = "liop")]
    Liop,
    /// Independent Opinion Pool: renormalised product.
    #[serde(rename = "iop")]
    Iop,
    /// Bayes filter in log-odds with clamping (OctoMap's update).
    #[default]
    #[serde(rename = "bayes")]
    Bayes,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappingSection {
    /// Fusion rule of `mapping/grid` and `mapping/projected`.
    #[serde(default)]
    pub rule: MappingRule,
    /// Voxel and cell side, m.
    #[serde(default = "default_resolution")]
    pub resolution_m: f64,
    /// Rate of `mapping/grid`, `mapping/projected` and `mapping/voxels`, Hz.
    #[serde(default = "default_rate")]
    pub publish_rate_hz: f64,
    /// Side of the square the maps cover, centred on the map origin, m.
    #[serde(default = "default_size")]
    pub size_m: f64,
    /// Height of the laser's scan plane above the floor, m.
    #[serde(default = "default_laser_height")]
    pub laser_height_m: f64,
    /// Height of the sonar ring's axes above the floor, m.
    #[serde(default = "default_sonar_height")]
    pub sonar_height_m: f64,
    /// The robot's top, m: the projected map marks everything between the
    /// floor and this height as an obstacle.
    #[serde(default = "default_robot_height")]
    pub robot_height_m: f64,
    /// The highest floor obstacle the base drives over (a cable, a sill), m.
    /// A sonar cone's lower edge comes down to it at some range; an echo
    /// from farther may be such an obstacle (or the floor itself), so the
    /// SLAM vote's projected member does not map it as one.
    #[serde(default)]
    pub climb_height_m: f64,
    /// Folder the process writes `octree.bt` to, on SIGUSR1 or for
    /// `smokenav map save` (its `--map-dir` overrides it; unset: the
    /// current folder). `smokenav map save --config` copies the file from here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub map_dir: Option<String>,
}

fn default_laser_height() -> f64 {
    0.40
}

fn default_sonar_height() -> f64 {
    0.30
}

fn default_robot_height() -> f64 {
    0.60
}

fn default_resolution() -> f64 {
    0.05
}

fn default_rate() -> f64 {
    2.0
}

fn default_size() -> f64 {
    40.0
}

impl Default for MappingSection {
    fn default() -> Self {
        Self {
            rule: MappingRule::default(),
            resolution_m: default_resolution(),
            publish_rate_hz: default_rate(),
            size_m: default_size(),
            laser_height_m: default_laser_height(),
            sonar_height_m: default_sonar_height(),
            robot_height_m: default_robot_height(),
            climb_height_m: 0.0,
            map_dir: None,
        }
    }
}

impl Validate for MappingSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        v.within(&k("resolution_m"), self.resolution_m, 0.01, 1.0);
        v.within(&k("publish_rate_hz"), self.publish_rate_hz, 0.1, 20.0);
        v.within(&k("size_m"), self.size_m, 1.0, 200.0);
        v.within(&k("laser_height_m"), self.laser_height_m, 0.0, 3.0);
        v.within(&k("sonar_height_m"), self.sonar_height_m, 0.0, 3.0);
        v.within(&k("robot_height_m"), self.robot_height_m, 0.05, 3.0);
        v.within(&k("climb_height_m"), self.climb_height_m, 0.0, 0.5);
        if let Some(d) = &self.map_dir {
            v.non_empty(&k("map_dir"), d);
        }
        // The published grids are one bus sample each: keep them under 16 M cells.
        if self.resolution_m.is_finite()
            && self.size_m.is_finite()
            && self.resolution_m > 0.0
            && (self.size_m / self.resolution_m).powi(2) > 16e6
        {
            v.fail(
                k("size_m"),
                format!(
                    "{} m at {} m is more than 4000 × 4000 cells",
                    self.size_m, self.resolution_m
                ),
            );
        }
    }
}
