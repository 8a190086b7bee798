//! A test room for the filter and the pipeline: walls, ray casting, and a
//! 361-beam laser scan from a pose.

use crate::scan::{Beam, BeamKind, RangeScan};
use smokenav_shared_types::Pose2;

/// Wall segments of a 10 m × 6 m room with an inner wall and two pillars.
pub const WALLS: [(f64, f64, f64, f64); 10] = [
    (-5.0, -3.0, 5.0, -3.0),
    (5.0, -3.0, 5.0, 3.0),
    (5.0, 3.0, -5.0, 3.0),
    (-5.0, 3.0, -5.0, -3.0),
    (0.0, 3.0, 0.0, 1.0),
    (2.0, -1.0, 2.3, -1.0),
    (2.3, -1.0, 2.3, -0.7),
    (-2.5, 0.5, -2.2, 0.5),
    (-2.2, 0.5, -2.2, 0.8),
    (-3.0, -3.0, -4.0, -2.0),
];

/// Ray-cast range from `(x, y)` along `a` to the nearest wall.
pub fn cast(x: f64, y: f64, a: f64) -> Option<f64> {
    cast_in(&WALLS, x, y, a)
}

/// Ray-cast range from `(x, y)` along `a` to the nearest of `walls`
/// (segments `(x1, y1, x2, y2)`).
pub fn cast_in(walls: &[(f64, f64, f64, f64)], x: f64, y: f64, a: f64) -> Option<f64> {
    let (dx, dy) = (a.cos(), a.sin());
    let mut best: Option<f64> = None;
    for &(x1, y1, x2, y2) in walls {
        let (ex, ey) = (x2 - x1, y2 - y1);
        let den = dx * ey - dy * ex;
        if den.abs() < 1e-12 {
            continue;
        }
        let t = ((x1 - x) * ey - (y1 - y) * ex) / den;
        let u = ((x1 - x) * dy - (y1 - y) * dx) / den;
        if t > 0.0 && (0.0..=1.0).contains(&u) && best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    }
    best
}

pub fn scan_at(truth: &Pose2, stamp_ns: u64) -> RangeScan {
    scan_in(&WALLS, f64::INFINITY, truth, stamp_ns)
}

/// A 180°, 0.5° laser scan at `truth` of `walls`, no return beyond `max_range`.
pub fn scan_in(
    walls: &[(f64, f64, f64, f64)],
    max_range: f64,
    truth: &Pose2,
    stamp_ns: u64,
) -> RangeScan {
    let mut s = RangeScan {
        stamp_ns,
        laser_noise_factor: 1.0,
        ..Default::default()
    };
    for i in 0..361 {
        let a = -std::f64::consts::FRAC_PI_2 + i as f64 * std::f64::consts::PI / 360.0;
        s.beams.push(Beam {
            angle: a as f32,
            range: cast_in(walls, truth.x, truth.y, truth.theta + a)
                .filter(|&r| r < max_range)
                .map(|r| r as f32),
            kind: BeamKind::Laser,
        });
    }
    s
}
