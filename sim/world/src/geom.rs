//! Plane geometry: points and wall segments; poses are the shared `Pose2`.

use std::ops::{Add, Mul, Sub};

#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Vec2 {
    pub x: f64,
    pub y: f64,
}

impl Vec2 {
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }

    /// Unit vector at `angle` rad.
    pub fn from_angle(angle: f64) -> Self {
        Self::new(angle.cos(), angle.sin())
    }

    pub fn dot(self, o: Vec2) -> f64 {
        self.x * o.x + self.y * o.y
    }

    /// z component of the 3D cross product.
    pub fn cross(self, o: Vec2) -> f64 {
        self.x * o.y - self.y * o.x
    }

    pub fn norm(self) -> f64 {
        self.x.hypot(self.y)
    }

    pub fn normalized(self) -> Vec2 {
        let n = self.norm();
        if n > 0.0 { self * (1.0 / n) } else { self }
    }

    /// Rotated 90° counter-clockwise.
    pub fn perp(self) -> Vec2 {
        Vec2::new(-self.y, self.x)
    }

    pub fn rotated(self, angle: f64) -> Vec2 {
        let (s, c) = angle.sin_cos();
        Vec2::new(c * self.x - s * self.y, s * self.x + c * self.y)
    }

    pub fn is_finite(self) -> bool {
        self.x.is_finite() && self.y.is_finite()
    }
}

impl Add for Vec2 {
    type Output = Vec2;
    fn add(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x + o.x, self.y + o.y)
    }
}

impl Sub for Vec2 {
    type Output = Vec2;
    fn sub(self, o: Vec2) -> Vec2 {
        Vec2::new(self.x - o.x, self.y - o.y)
    }
}

impl Mul<f64> for Vec2 {
    type Output = Vec2;
    fn mul(self, k: f64) -> Vec2 {
        Vec2::new(self.x * k, self.y * k)
    }
}

pub use smokenav_shared_types::geometry::{Pose2, normalize_angle};

/// A pose's position as the simulator's vector.
pub trait Position {
    fn position(&self) -> Vec2;
}

impl Position for Pose2 {
    fn position(&self) -> Vec2 {
        Vec2::new(self.x, self.y)
    }
}

/// A reflecting wall piece. `normal` is the unit normal used for incidence
/// angles (either side; users take its absolute cosine). For vector walls it
/// is the geometric normal; for walls traced from a pixel map it is the
/// smoothed image gradient, so a diagonal wall drawn as a staircase of pixels
/// still reflects like a diagonal wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub a: Vec2,
    pub b: Vec2,
    pub normal: Vec2,
    /// Heights it spans above the floor, m: `[base, top]`. Walls span
    /// [`FULL_HEIGHT`]; a table top or a low box spans less, so a planar
    /// laser above or below it passes by while a sonar cone may hit it.
    pub z: [f64; 2],
}

/// The height range of a wall: floor to infinity.
pub const FULL_HEIGHT: [f64; 2] = [0.0, f64::INFINITY];

impl Segment {
    pub fn new(a: Vec2, b: Vec2) -> Self {
        Self {
            a,
            b,
            normal: (b - a).perp().normalized(),
            z: FULL_HEIGHT,
        }
    }

    /// The same segment spanning `z` (`[base, top]`, m).
    pub fn with_height(self, z: [f64; 2]) -> Self {
        Self { z, ..self }
    }

    /// Whether the segment reaches height `h`.
    pub fn spans(&self, h: f64) -> bool {
        h >= self.z[0] && h <= self.z[1]
    }

    /// Whether the whole of it is full height.
    pub fn is_full_height(&self) -> bool {
        self.z == FULL_HEIGHT
    }

    pub fn length(&self) -> f64 {
        (self.b - self.a).norm()
    }

    /// Distance along the ray `o + t·d` (|d| = 1) to this segment, if it is hit at `t > 0`.
    pub fn ray_hit(&self, o: Vec2, d: Vec2) -> Option<f64> {
        let e = self.b - self.a;
        let denom = d.cross(e);
        if denom.abs() < 1e-12 {
            return None; // parallel: a grazing ray sees no surface
        }
        let ao = self.a - o;
        let t = ao.cross(e) / denom;
        let u = ao.cross(d) / denom;
        (t > 1e-9 && (-1e-9..=1.0 + 1e-9).contains(&u)).then_some(t)
    }

    /// Shortest distance from `p` to the segment.
    pub fn distance_to(&self, p: Vec2) -> f64 {
        let e = self.b - self.a;
        let len2 = e.dot(e);
        let s = if len2 > 0.0 {
            ((p - self.a).dot(e) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (self.a + e * s - p).norm()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_hits_wall_in_front_at_its_distance() {
        let wall = Segment::new(Vec2::new(3.0, -1.0), Vec2::new(3.0, 1.0));
        let t = wall
            .ray_hit(Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0))
            .unwrap();
        assert!((t - 3.0).abs() < 1e-12);
        assert_eq!(
            wall.ray_hit(Vec2::new(0.0, 0.0), Vec2::new(-1.0, 0.0)),
            None
        );
        assert_eq!(wall.ray_hit(Vec2::new(0.0, 0.0), Vec2::new(0.0, 1.0)), None);
    }

    #[test]
    fn pose_lerp_takes_the_short_way_round() {
        let a = Pose2::new(0.0, 0.0, 3.0);
        let b = Pose2::new(1.0, 0.0, -3.0);
        let m = a.interpolate(&b, 0.5);
        assert!(
            (m.theta.abs() - std::f64::consts::PI).abs() < 1e-9,
            "{}",
            m.theta
        );
        assert!((m.x - 0.5).abs() < 1e-12);
    }

    #[test]
    fn point_to_segment_distance_uses_the_endpoint_beyond_the_ends() {
        let s = Segment::new(Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0));
        assert!((s.distance_to(Vec2::new(0.5, 2.0)) - 2.0).abs() < 1e-12);
        assert!((s.distance_to(Vec2::new(4.0, 4.0)) - 5.0).abs() < 1e-12);
    }
}
