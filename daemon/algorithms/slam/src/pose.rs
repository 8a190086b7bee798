//! Planar poses (SE(2)) and their composition.

use smokenav_shared_types::odom::normalize_angle;

/// A pose in the plane: position in metres, heading in radians (counter-clockwise).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose2 {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Pose2 {
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    /// `self ⊕ d`: applies `d`, expressed in this pose's frame.
    pub fn compose(&self, d: &Pose2) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2 {
            x: self.x + c * d.x - s * d.y,
            y: self.y + s * d.x + c * d.y,
            theta: normalize_angle(self.theta + d.theta),
        }
    }

    /// The pose that undoes this one.
    pub fn inverse(&self) -> Pose2 {
        let (s, c) = self.theta.sin_cos();
        Pose2 {
            x: -c * self.x - s * self.y,
            y: s * self.x - c * self.y,
            theta: normalize_angle(-self.theta),
        }
    }

    /// `base⁻¹ ⊕ self`: this pose expressed in `base`'s frame (the odometry delta
    /// from `base` to `self`).
    pub fn relative_to(&self, base: &Pose2) -> Pose2 {
        let (s, c) = base.theta.sin_cos();
        let (dx, dy) = (self.x - base.x, self.y - base.y);
        Pose2 {
            x: c * dx + s * dy,
            y: -s * dx + c * dy,
            theta: normalize_angle(self.theta - base.theta),
        }
    }

    /// A point given in this pose's frame, in the parent frame.
    pub fn transform_point(&self, px: f64, py: f64) -> (f64, f64) {
        let (s, c) = self.theta.sin_cos();
        (self.x + c * px - s * py, self.y + s * px + c * py)
    }

    pub fn translation_norm(&self) -> f64 {
        self.x.hypot(self.y)
    }

    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }
}

/// Interpolates between two poses (`t` = 0 gives `a`, 1 gives `b`), along the shorter turn.
pub fn interpolate(a: &Pose2, b: &Pose2, t: f64) -> Pose2 {
    Pose2 {
        x: a.x + t * (b.x - a.x),
        y: a.y + t * (b.y - a.y),
        theta: normalize_angle(a.theta + t * normalize_angle(b.theta - a.theta)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    fn close(a: &Pose2, b: &Pose2) -> bool {
        (a.x - b.x).abs() < 1e-12
            && (a.y - b.y).abs() < 1e-12
            && normalize_angle(a.theta - b.theta).abs() < 1e-12
    }

    #[test]
    fn forward_step_after_quarter_turn_moves_along_y() {
        let p = Pose2::new(1.0, 2.0, FRAC_PI_2).compose(&Pose2::new(0.5, 0.0, 0.0));
        assert!(close(&p, &Pose2::new(1.0, 2.5, FRAC_PI_2)), "{p:?}");
    }

    #[test]
    fn relative_then_compose_recovers_the_pose() {
        let a = Pose2::new(576.536523, 0.106594, -2.255213);
        let b = Pose2::new(589.036547, -27.878596, -1.258152);
        let d = b.relative_to(&a);
        assert!(close(&a.compose(&d), &b));
        assert!(close(&a.compose(&a.inverse()), &Pose2::default()));
    }

    #[test]
    fn interpolation_takes_the_short_way_round() {
        let a = Pose2::new(0.0, 0.0, 3.0);
        let b = Pose2::new(2.0, 0.0, -3.0);
        let m = interpolate(&a, &b, 0.5);
        assert!((m.x - 1.0).abs() < 1e-12);
        assert!(m.theta.abs() > 3.1, "{m:?}");
    }
}
