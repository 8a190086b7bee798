//! Planar poses (SE(2)) for everything that is not a wire codec: the
//! simulator, SLAM and the recorder share this one type.
//!
//! The linear algebra is nalgebra's (`Rotation2` times `Vector2`); the heading
//! is kept as an angle wrapped to (-π, π] rather than as a unit complex
//! number, so a pose reads and prints as the `x y theta` every log and file
//! format uses, and a composition's heading is the wrapped sum of the two
//! headings exactly (no round trip through `atan2`).

use nalgebra::{Isometry2, Point2, Rotation2, Vector2};
use std::f64::consts::{PI, TAU};

/// Wraps an angle to (-π, π].
pub fn normalize_angle(a: f64) -> f64 {
    let mut a = a % TAU;
    if a <= -PI {
        a += TAU;
    } else if a > PI {
        a -= TAU;
    }
    a
}

/// A pose in the plane: position in metres, heading in radians (counter-clockwise from +x).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pose2 {
    /// Position along x, m.
    pub x: f64,
    /// Position along y, m.
    pub y: f64,
    /// Heading, rad.
    pub theta: f64,
}

impl Pose2 {
    /// A pose from its parts (the heading is taken as given).
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }

    /// The position as a vector.
    pub fn translation(&self) -> Vector2<f64> {
        Vector2::new(self.x, self.y)
    }

    /// The heading as a rotation.
    pub fn rotation(&self) -> Rotation2<f64> {
        Rotation2::new(self.theta)
    }

    /// The pose as a rigid transform (robot frame → parent frame).
    pub fn to_isometry(&self) -> Isometry2<f64> {
        Isometry2::new(self.translation(), self.theta)
    }

    /// The pose of a rigid transform.
    pub fn from_isometry(iso: &Isometry2<f64>) -> Self {
        let t = iso.translation.vector;
        Self::new(t.x, t.y, normalize_angle(iso.rotation.angle()))
    }

    fn from_parts(t: Vector2<f64>, theta: f64) -> Self {
        Self::new(t.x, t.y, normalize_angle(theta))
    }

    /// `self ⊕ d`: applies `d`, expressed in this pose's frame.
    pub fn compose(&self, d: &Pose2) -> Pose2 {
        Self::from_parts(
            self.translation() + self.rotation() * d.translation(),
            self.theta + d.theta,
        )
    }

    /// The pose that undoes this one (`p ⊕ p⁻¹` is the identity).
    pub fn inverse(&self) -> Pose2 {
        Self::from_parts(
            -(self.rotation().inverse() * self.translation()),
            -self.theta,
        )
    }

    /// `self⁻¹ ⊕ other`: `other` expressed in this pose's frame (the motion
    /// from `self` to `other`, e.g. an odometry delta).
    pub fn between(&self, other: &Pose2) -> Pose2 {
        Self::from_parts(
            self.rotation().inverse() * (other.translation() - self.translation()),
            other.theta - self.theta,
        )
    }

    /// Interpolates towards `to` (`t` = 0 gives `self`, 1 gives `to`), along the shorter turn.
    pub fn interpolate(&self, to: &Pose2, t: f64) -> Pose2 {
        Pose2::new(
            self.x + t * (to.x - self.x),
            self.y + t * (to.y - self.y),
            normalize_angle(self.theta + t * normalize_angle(to.theta - self.theta)),
        )
    }

    /// A point given in this pose's frame, in the parent frame.
    pub fn transform_point(&self, p: &Point2<f64>) -> Point2<f64> {
        Point2::from(self.translation() + self.rotation() * p.coords)
    }

    /// Distance from the origin, m.
    pub fn translation_norm(&self) -> f64 {
        self.x.hypot(self.y)
    }

    /// No part is NaN or infinite.
    pub fn is_finite(&self) -> bool {
        self.x.is_finite() && self.y.is_finite() && self.theta.is_finite()
    }
}

/// A planar velocity in the robot's own frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Twist2 {
    /// Forward, m/s.
    pub vx: f64,
    /// To the left, m/s.
    pub vy: f64,
    /// Turn rate, rad/s (counter-clockwise positive).
    pub w: f64,
}

impl Twist2 {
    /// A velocity from its parts.
    pub const fn new(vx: f64, vy: f64, w: f64) -> Self {
        Self { vx, vy, w }
    }

    /// No part is NaN or infinite.
    pub fn is_finite(&self) -> bool {
        self.vx.is_finite() && self.vy.is_finite() && self.w.is_finite()
    }

    /// Where `t` s at this velocity take the robot, seen from where it set
    /// out. First order (the turn applied after the straight move): over a
    /// laser's 0.1 s sweep it is within a millimetre of the arc.
    pub fn motion(&self, t: f64) -> Pose2 {
        Pose2::new(self.vx * t, self.vy * t, self.w * t)
    }
}

/// A sensor that takes its beams one after another while the robot moves
/// (a scanning laser: the URG-04LX sweeps its 240° in 67 ms, and turning at
/// 1 rad/s its last beam is taken 3.8° further round than its first). Puts
/// each beam where it would have been had the whole sweep been taken at its
/// first beam, the stamp: the walls a turning robot maps stop bending.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sweep {
    sensor: Pose2,
    to_sensor: Pose2,
    twist: Twist2,
    time_increment_s: f64,
}

impl Sweep {
    /// A sweep by the sensor mounted at `sensor` on the robot, `time_increment_s`
    /// between beams, the robot moving at `twist`; `None` if either is not a
    /// finite motion (a zero increment: the beams were taken at once).
    pub fn new(sensor: Pose2, twist: Twist2, time_increment_s: f64) -> Option<Self> {
        (twist.is_finite()
            && sensor.is_finite()
            && time_increment_s.is_finite()
            && time_increment_s > 0.0)
            .then(|| Self {
                sensor,
                to_sensor: sensor.inverse(),
                twist,
                time_increment_s,
            })
    }

    /// Beam `index` (angle rad and range m in the sensor's frame) as seen
    /// from the sensor at the sweep's first beam.
    pub fn beam(&self, index: usize, angle: f64, range: f64) -> (f64, f64) {
        let moved = self.twist.motion(index as f64 * self.time_increment_s);
        let (s, c) = angle.sin_cos();
        let end = moved
            .compose(&self.sensor)
            .compose(&Pose2::new(c * range, s * range, 0.0));
        let e = self.to_sensor.compose(&end);
        (e.y.atan2(e.x), e.x.hypot(e.y))
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
    fn between_then_compose_recovers_the_pose() {
        let a = Pose2::new(576.536523, 0.106594, -2.255213);
        let b = Pose2::new(589.036547, -27.878596, -1.258152);
        let d = a.between(&b);
        assert!(close(&a.compose(&d), &b));
        assert!(close(&a.compose(&a.inverse()), &Pose2::default()));
        assert!(close(&a.inverse().compose(&b), &d));
    }

    #[test]
    fn interpolation_takes_the_short_way_round() {
        let a = Pose2::new(0.0, 0.0, 3.0);
        let b = Pose2::new(2.0, 0.0, -3.0);
        let m = a.interpolate(&b, 0.5);
        assert!((m.x - 1.0).abs() < 1e-12);
        assert!(m.theta.abs() > 3.1, "{m:?}");
    }

    #[test]
    fn nalgebra_products_round_like_the_hand_written_formulas() {
        // The simulator's and SLAM's seeded runs were recorded with these
        // formulas: the nalgebra forms must give the same bits.
        let poses = [
            Pose2::new(576.536523, 0.106594, -2.255213),
            Pose2::new(-3.5, -1.5, 0.3),
            Pose2::new(1e-3, 7.25, 3.1),
        ];
        for a in &poses {
            for b in &poses {
                let (s, c) = a.theta.sin_cos();
                let composed = a.compose(b);
                assert_eq!(composed.x.to_bits(), (a.x + (c * b.x - s * b.y)).to_bits());
                assert_eq!(composed.y.to_bits(), (a.y + (s * b.x + c * b.y)).to_bits());
                let (dx, dy) = (b.x - a.x, b.y - a.y);
                let between = a.between(b);
                assert_eq!(between.x.to_bits(), (c * dx + s * dy).to_bits());
                assert_eq!(between.y.to_bits(), (-s * dx + c * dy).to_bits());
                let inverse = a.inverse();
                assert_eq!(inverse.x.to_bits(), (-c * a.x - s * a.y).to_bits());
                assert_eq!(inverse.y.to_bits(), (s * a.x - c * a.y).to_bits());
            }
        }
    }

    #[test]
    fn isometry_round_trip_keeps_the_pose() {
        let p = Pose2::new(1.5, -2.0, 2.9);
        assert!(close(&Pose2::from_isometry(&p.to_isometry()), &p));
        let q = Pose2::new(0.3, 0.1, -1.0);
        let iso = p.to_isometry() * q.to_isometry();
        assert!(close(&Pose2::from_isometry(&iso), &p.compose(&q)));
        let pt = p.transform_point(&Point2::new(1.0, 0.0));
        let (s, c) = p.theta.sin_cos();
        assert!((pt.x - (p.x + c)).abs() < 1e-12 && (pt.y - (p.y + s)).abs() < 1e-12);
    }

    #[test]
    fn angles_wrap_to_minus_pi_exclusive_pi_inclusive() {
        assert_eq!(normalize_angle(PI), PI);
        assert_eq!(normalize_angle(-PI), PI);
        assert!((normalize_angle(3.0 * PI) - PI).abs() < 1e-12);
        assert!((normalize_angle(-0.5 - TAU) + 0.5).abs() < 1e-12);
    }

    #[test]
    fn a_sweep_puts_a_beam_taken_later_where_the_first_beam_sees_it() {
        // A laser 0.1 m ahead of the axle; the robot turns at 1 rad/s and
        // drives at 0.5 m/s. A point 2 m ahead of the robot as it starts.
        let mount = Pose2::new(0.1, 0.0, 0.0);
        let twist = Twist2::new(0.5, 0.0, 1.0);
        let dt = 0.001;
        let sweep = Sweep::new(mount, twist, dt).unwrap();
        let point = Point2::new(2.0, 0.3);
        for i in [0usize, 10, 66] {
            // Where the laser saw the point from, 'i' beams in.
            let laser = twist.motion(i as f64 * dt).compose(&mount);
            let local = laser.inverse().transform_point(&point);
            let (a, r) = sweep.beam(i, local.y.atan2(local.x), local.coords.norm());
            let seen = mount.transform_point(&Point2::new(r * a.cos(), r * a.sin()));
            assert!((seen - point).norm() < 1e-12, "beam {i}: {seen} ≠ {point}");
        }
        // The first beam is left as it is; no motion, no sweep.
        assert_eq!(sweep.beam(0, 0.25, 3.0).0, 0.25);
        assert!(Sweep::new(mount, twist, 0.0).is_none());
        assert!(Sweep::new(mount, Twist2::new(f64::NAN, 0.0, 0.0), dt).is_none());
    }
}
