//! The update gate: a scan is used once the robot has moved or turned far
//! enough, or enough time has passed, since the last scan that was used
//! (GMapping's linearUpdate / angularUpdate / temporalUpdate). Scans in
//! between only move the estimate by their odometry.

use smokenav_platform_config::SlamSection;
use smokenav_shared_types::Pose2;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionFilterParams {
    /// Path length since the last used scan that makes the next one due, m (0: every scan).
    pub linear_m: f64,
    /// Turning since the last used scan that makes the next one due, rad (0: every scan).
    pub angular_rad: f64,
    /// Time since the last used scan after which the next one is due, s; `None`: never by time.
    pub temporal_s: Option<f64>,
}

impl MotionFilterParams {
    pub fn from_config(c: &SlamSection) -> Self {
        Self {
            linear_m: c.linear_update_m,
            angular_rad: c.angular_update_rad,
            temporal_s: (c.temporal_update_s >= 0.0).then_some(c.temporal_update_s),
        }
    }
}

#[derive(Debug, Clone)]
pub struct MotionFilter {
    p: MotionFilterParams,
    last: Option<Pose2>,
    /// Path length and turning accumulated since the last used scan.
    dist: f64,
    rot: f64,
    last_used_ns: u64,
    /// The next odometry is not compared with the last (its frame jumped).
    jumped: bool,
}

impl MotionFilter {
    pub fn new(p: MotionFilterParams) -> Self {
        Self {
            p,
            last: None,
            dist: 0.0,
            rot: 0.0,
            last_used_ns: 0,
            jumped: false,
        }
    }

    /// Whether the scan stamped `stamp_ns` with odometry `odom` should be
    /// used. The first scan always is; the motion counts path length (sum of
    /// the steps between scans), not displacement.
    pub fn check(&mut self, odom: &Pose2, stamp_ns: u64) -> bool {
        let Some(last) = self.last.replace(*odom) else {
            self.last_used_ns = stamp_ns;
            return true;
        };
        if !std::mem::take(&mut self.jumped) {
            let step = last.between(odom);
            self.dist += step.translation_norm();
            self.rot += step.theta.abs();
        }
        let elapsed_s = stamp_ns.saturating_sub(self.last_used_ns) as f64 * 1e-9;
        let due = self.dist >= self.p.linear_m
            || self.rot >= self.p.angular_rad
            || self.p.temporal_s.is_some_and(|t| elapsed_s > t);
        if due {
            self.dist = 0.0;
            self.rot = 0.0;
            self.last_used_ns = stamp_ns;
        }
        due
    }

    /// The odometry frame jumped: the next reading is not motion.
    pub fn odometry_reset(&mut self) {
        self.jumped = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: u64 = 1_000_000_000;

    fn filter(linear_m: f64, angular_rad: f64, temporal_s: Option<f64>) -> MotionFilter {
        MotionFilter::new(MotionFilterParams {
            linear_m,
            angular_rad,
            temporal_s,
        })
    }

    #[test]
    fn zero_thresholds_use_every_scan() {
        let mut f = filter(0.0, 0.0, None);
        assert!((0..5).all(|k| f.check(&Pose2::default(), k * S)));
    }

    #[test]
    fn distance_turn_and_time_each_make_a_scan_due() {
        let mut f = filter(0.5, 0.8, Some(3.0));
        assert!(
            f.check(&Pose2::default(), 0),
            "the first scan starts the map"
        );
        // 0.2 m steps: due at the third (0.6 m of path), counted from zero again.
        let due: Vec<bool> = (1..=6)
            .map(|k| f.check(&Pose2::new(0.2 * k as f64, 0.0, 0.0), k * S / 10))
            .collect();
        assert_eq!(due, [false, false, true, false, false, true]);
        // Turning on the spot.
        assert!(!f.check(&Pose2::new(1.2, 0.0, 0.5), 7 * S / 10));
        assert!(f.check(&Pose2::new(1.2, 0.0, 1.0), 8 * S / 10));
        // Standing still: due once more than 3 s passed.
        assert!(!f.check(&Pose2::new(1.2, 0.0, 1.0), 38 * S / 10));
        assert!(f.check(&Pose2::new(1.2, 0.0, 1.0), 39 * S / 10));
    }

    #[test]
    fn a_reset_odometry_jump_is_not_motion() {
        let mut f = filter(0.5, 0.8, None);
        f.check(&Pose2::default(), 0);
        f.odometry_reset();
        assert!(
            !f.check(&Pose2::new(40.0, -3.0, 2.0), S),
            "a jump, not 40 m of travel"
        );
        assert!(f.check(&Pose2::new(40.6, -3.0, 2.0), 2 * S));
    }
}
