//! `[sonar]`: the sonar ring's geometry.

use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SonarSection {
    /// Number of transducers the ring has; each index `0..count` needs a pose.
    pub count: u8,
    /// Full beam width, degrees (Pioneer ~15°, Polaroid 6500 on the Scout ~20–25°).
    pub cone_deg: f64,
    /// Longest range the transducers report, m; a reading at this range is saturated.
    pub max_range_m: f64,
    /// Shortest range they report, m.
    #[serde(default = "default_min_range")]
    pub min_range_m: f64,
    pub transducers: Vec<Transducer>,
}

fn default_min_range() -> f64 {
    0.1
}

/// One transducer's pose in the base frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Transducer {
    pub index: u8,
    /// Forward offset, m.
    pub x: f64,
    /// Leftward offset, m.
    pub y: f64,
    /// Axis direction, degrees, counter-clockwise from forward.
    pub yaw_deg: f64,
}

impl SonarSection {
    pub fn transducer(&self, index: u8) -> Option<&Transducer> {
        self.transducers.iter().find(|t| t.index == index)
    }
}

impl Validate for SonarSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        if self.count == 0 || self.count > 32 {
            v.fail(
                format!("{key}.count"),
                format!("must be 1–32, got {}", self.count),
            );
        }
        v.within(&format!("{key}.cone_deg"), self.cone_deg, 1.0, 90.0);
        v.within(&format!("{key}.max_range_m"), self.max_range_m, 0.3, 20.0);
        v.within(&format!("{key}.min_range_m"), self.min_range_m, 0.0, 2.0);
        v.ordered(
            &format!("{key}.min_range_m"),
            self.min_range_m,
            &format!("{key}.max_range_m"),
            self.max_range_m,
        );
        for (i, t) in self.transducers.iter().enumerate() {
            let k = format!("{key}.transducers[{i}]");
            if t.index >= self.count {
                v.fail(
                    format!("{k}.index"),
                    format!("{} is not below `{key}.count` ({})", t.index, self.count),
                );
            }
            if self.transducers[..i].iter().any(|o| o.index == t.index) {
                v.fail(
                    format!("{k}.index"),
                    format!("index {} appears twice", t.index),
                );
            }
            v.within(&format!("{k}.x"), t.x, -2.0, 2.0);
            v.within(&format!("{k}.y"), t.y, -2.0, 2.0);
            v.within(&format!("{k}.yaw_deg"), t.yaw_deg, -360.0, 360.0);
        }
        let missing: Vec<u8> = (0..self.count.min(32))
            .filter(|i| self.transducer(*i).is_none())
            .collect();
        if !missing.is_empty() {
            v.fail(
                format!("{key}.transducers"),
                format!(
                    "no pose for sonar index {missing:?} (every index 0..{} needs one)",
                    self.count
                ),
            );
        }
    }
}
