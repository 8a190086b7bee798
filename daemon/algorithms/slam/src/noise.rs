//! How smoke widens the laser's noise.
//!
//! Sevcik & Oh 2007 (REFERENCES.md) measured the range variance of a laser
//! scanner in clear air, rain and fog: 5, 8.39 and 13.75 (mm²). SLAM reads a
//! fused scan's smoke level (SmokeNav's mV scale, in which v1's thresholds
//! are given) as the obscurant: clear below the light threshold's start, the
//! rain variance at the light threshold, the fog variance from the dense one
//! on, linear in variance between. The laser endpoint σ of the matcher and
//! of the likelihood is multiplied by the square root of the variance ratio.

use smokenav_platform_config::SlamSection;

/// The smoke → laser noise model, from the `[slam]` variance and smoke-level keys.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaserNoiseModel {
    pub variance_clear: f64,
    pub variance_light: f64,
    pub variance_dense: f64,
    pub smoke_level_light: f64,
    pub smoke_level_dense: f64,
}

impl LaserNoiseModel {
    pub fn from_config(c: &SlamSection) -> Self {
        Self {
            variance_clear: c.laser_variance_clear,
            variance_light: c.laser_variance_light,
            variance_dense: c.laser_variance_dense,
            smoke_level_light: c.smoke_level_light,
            smoke_level_dense: c.smoke_level_dense,
        }
    }

    /// Standard-deviation multiplier of laser beams at `smoke_level` (SmokeNav's
    /// mV scale); 1 in clear air and for a level that is not a number.
    pub fn factor(&self, smoke_level: f64) -> f64 {
        let clear = self.variance_clear;
        let variance = if !smoke_level.is_finite() || smoke_level <= 0.0 {
            clear
        } else if smoke_level < self.smoke_level_light {
            let t = smoke_level / self.smoke_level_light.max(f64::MIN_POSITIVE);
            clear + t * (self.variance_light - clear)
        } else if smoke_level < self.smoke_level_dense {
            let t = (smoke_level - self.smoke_level_light)
                / (self.smoke_level_dense - self.smoke_level_light);
            self.variance_light + t * (self.variance_dense - self.variance_light)
        } else {
            self.variance_dense
        };
        (variance / clear).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn laser_noise_widens_from_clear_to_fog_as_sevcik_and_oh_measured() {
        let s = LaserNoiseModel::from_config(&SlamSection::default());
        assert_eq!(s.factor(0.0), 1.0);
        // Rain-like variance 8.39 vs 5 at the light threshold: σ × 1.295.
        assert!((s.factor(130.0) - (8.39f64 / 5.0).sqrt()).abs() < 1e-9);
        // Fog 13.75 vs 5 at and beyond the dense threshold: σ × 1.658.
        assert!((s.factor(300.0) - (13.75f64 / 5.0).sqrt()).abs() < 1e-9);
        assert!(s.factor(185.0) > s.factor(130.0));
        assert_eq!(s.factor(f64::NAN), 1.0);
    }
}
