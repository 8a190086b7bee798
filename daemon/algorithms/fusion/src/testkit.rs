//! Constructed inputs for tests, benchmarks and end-to-end checks: a
//! rectangular room seen by a URG-04LX, the sonar readings a ring would get in
//! it, smoke in front of the laser, smoke-sensor readings.

use crate::geometry::{ScanShape, SonarGeometry};
use smokenav_shared_types::{
    BeamReading, Header, LaserScan, SmokeReading, SmokeSensorState, SmokeTrend, SonarReading,
    SonarRing, SonarStatus,
};

/// A box room around the laser: walls at x = ±`half_x`, y = ±`half_y` (laser frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Room {
    pub half_x: f64,
    pub half_y: f64,
}

impl Default for Room {
    /// 4 × 3 m: every wall within the 2.5 m sonar cap from the robot's centre.
    fn default() -> Self {
        Self {
            half_x: 2.0,
            half_y: 1.5,
        }
    }
}

impl Room {
    /// Distance from `(x0, y0)` along `theta` to the nearest wall.
    pub fn range(&self, x0: f64, y0: f64, theta: f64) -> f64 {
        let (s, c) = theta.sin_cos();
        let mut best = f64::INFINITY;
        for (d, wall, origin) in [
            (c, self.half_x, x0),
            (c, -self.half_x, x0),
            (s, self.half_y, y0),
            (s, -self.half_y, y0),
        ] {
            if d.abs() > 1e-12 {
                let t = (wall - origin) / d;
                if t > 0.0 {
                    best = best.min(t);
                }
            }
        }
        best
    }

    /// The scan a URG-04LX at the laser origin sees.
    pub fn scan(&self, stamp_ns: u64, seq: u64) -> LaserScan {
        urg_scan(stamp_ns, seq, |_, a| self.range(0.0, 0.0, a) as f32)
    }

    /// What each sonar of `geometry` reads: the nearest wall within ±`half_cone_deg` of its axis.
    pub fn ring(
        &self,
        geometry: &SonarGeometry,
        half_cone_deg: f64,
        stamp_ns: u64,
        seq: u64,
    ) -> SonarRing {
        let mut ring = empty_ring(stamp_ns, seq);
        let half = half_cone_deg.to_radians();
        for p in geometry.poses() {
            let r = (-10..=10)
                .map(|k| self.range(p.x, p.y, p.yaw + half * f64::from(k) / 10.0))
                .fold(f64::INFINITY, f64::min);
            ring.push(SonarReading::new(p.index, r as f32, SonarStatus::Valid));
        }
        ring
    }
}

/// An empty ring message (5 m transducers).
pub fn empty_ring(stamp_ns: u64, seq: u64) -> SonarRing {
    SonarRing {
        header: Header::new(stamp_ns, seq, "base_link"),
        max_range: 5.0,
        ..Default::default()
    }
}

/// Every sonar of `geometry` saturated (no echo within 5 m).
pub fn saturated_ring(geometry: &SonarGeometry, stamp_ns: u64, seq: u64) -> SonarRing {
    let mut ring = empty_ring(stamp_ns, seq);
    for p in geometry.poses() {
        ring.push(SonarReading::new(p.index, 5.0, SonarStatus::Saturated));
    }
    ring
}

/// The layout of the Hokuyo URG-04LX SmokeNav (Santos et al. 2015) used (steps 44–725 of 1024 per
/// turn, step 384 ahead): the test scans' shape.
pub fn urg_04lx_shape() -> ScanShape {
    let inc = std::f64::consts::TAU / 1024.0;
    ScanShape {
        angle_min: (44.0 - 384.0) * inc,
        inc,
        count: 682,
    }
}

/// A URG-04LX scan (682 beams, 0.352°) with `range(beam, angle)` per beam.
pub fn urg_scan(stamp_ns: u64, seq: u64, range: impl Fn(usize, f64) -> f32) -> LaserScan {
    let shape = urg_04lx_shape();
    let mut s = LaserScan {
        header: Header::new(stamp_ns, seq, "laser"),
        angle_min: shape.angle_min as f32,
        angle_increment: shape.inc as f32,
        time_increment: 0.1 / 1024.0,
        scan_time: 0.1,
        range_min: 0.02,
        range_max: 5.6,
        count: shape.count as u32,
        ..Default::default()
    };
    for i in 0..shape.count {
        s.set_beam(i, BeamReading::Range(range(i, f64::from(s.angle(i)))));
    }
    s
}

/// Dense smoke in front of the laser: short, nearly uniform returns (0.5 m ± 1 cm).
pub fn smoky_scan(stamp_ns: u64, seq: u64) -> LaserScan {
    urg_scan(stamp_ns, seq, |i, _| {
        0.5 + 0.01 * ((i * 7919 % 13) as f32 / 6.0 - 1.0)
    })
}

/// A ready smoke-sensor reading at `level` (the SmokeNav paper's mV scale).
pub fn smoke_reading(stamp_ns: u64, seq: u64, level: f32, trend: SmokeTrend) -> SmokeReading {
    SmokeReading {
        header: Header::new(stamp_ns, seq, "smoke"),
        level,
        trend: trend as u8,
        state: SmokeSensorState::Ready as u8,
        ..Default::default()
    }
}
