//! Bit-for-bit comparison of smokenav messages.
//!
//! `PartialEq` says NaN ≠ NaN, yet sensor-code beams carry NaN ranges and a
//! replay must reproduce them (payload bits included). These compare every
//! field, unused capacity and reserved bytes included, by bit pattern. The
//! catalog's [`AnyMessage`](crate::catalog::AnyMessage) compares through these.

use crate::{
    FusedScan, Header, Health, LaserScan, MapInfo, Odometry, PoseEstimate, SmokeReading, SonarRing,
    VelocityCommand, VoxelCloud,
};

/// Equality by bit pattern, NaN payloads, unused capacity and reserved bytes included.
pub trait BitIdentical {
    /// True when `self` and `other` hold the same bits in every field.
    fn bit_identical(&self, other: &Self) -> bool;
}

fn f32s(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

fn f64s(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

impl BitIdentical for Header {
    fn bit_identical(&self, o: &Self) -> bool {
        // FixedStr's equality compares its length and all its bytes.
        self == o
    }
}

impl BitIdentical for LaserScan {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && f32s(
                &[
                    self.angle_min,
                    self.angle_increment,
                    self.time_increment,
                    self.scan_time,
                    self.range_min,
                    self.range_max,
                ],
                &[
                    o.angle_min,
                    o.angle_increment,
                    o.time_increment,
                    o.scan_time,
                    o.range_min,
                    o.range_max,
                ],
            )
            && (self.count, self.has_intensities) == (o.count, o.has_intensities)
            && f32s(&self.ranges, &o.ranges)
            && f32s(&self.intensities, &o.intensities)
            && self.beam_error == o.beam_error
    }
}

impl BitIdentical for FusedScan {
    fn bit_identical(&self, o: &Self) -> bool {
        self.scan.bit_identical(&o.scan)
            && self.beam_source == o.beam_source
            && (
                self.method,
                self.sync_state,
                self._reserved,
                self.section_count,
            ) == (o.method, o.sync_state, o._reserved, o.section_count)
            && self.sections.iter().zip(&o.sections).all(|(a, b)| {
                (
                    a.first_beam,
                    a.end_beam,
                    a.sonar_index,
                    a.source,
                    a._reserved,
                ) == (
                    b.first_beam,
                    b.end_beam,
                    b.sonar_index,
                    b.source,
                    b._reserved,
                ) && f32s(
                    &[a.rho_sonar, a.rho_laser, a.sonar_range],
                    &[b.rho_sonar, b.rho_laser, b.sonar_range],
                )
            })
            && f32s(
                &[self.smoke_level, self.laser_spread],
                &[o.smoke_level, o.laser_spread],
            )
            && (self.sonar_stamp_ns, self.smoke_stamp_ns) == (o.sonar_stamp_ns, o.smoke_stamp_ns)
    }
}

impl BitIdentical for Odometry {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && f64s(
                &[self.x, self.y, self.theta, self.linear, self.angular],
                &[o.x, o.y, o.theta, o.linear, o.angular],
            )
            && (
                self.flags,
                self.bumpers,
                self.battery_v.to_bits(),
                self._reserved,
            ) == (o.flags, o.bumpers, o.battery_v.to_bits(), o._reserved)
    }
}

impl BitIdentical for SonarRing {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && self.max_range.to_bits() == o.max_range.to_bits()
            && self.count == o.count
            && self.readings.iter().zip(&o.readings).all(|(a, b)| {
                (a.range.to_bits(), a.index, a.status, a._reserved)
                    == (b.range.to_bits(), b.index, b.status, b._reserved)
            })
    }
}

impl BitIdentical for crate::sim_clock::SimClock {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
    }
}

impl BitIdentical for VelocityCommand {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && f64s(&[self.linear, self.angular], &[o.linear, o.angular])
    }
}

impl BitIdentical for SmokeReading {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && f32s(
                &[self.raw_mv, self.level, self.baseline_mv],
                &[o.raw_mv, o.level, o.baseline_mv],
            )
            && (self.raw_counts, self.trend, self.state, self._reserved)
                == (o.raw_counts, o.trend, o.state, o._reserved)
    }
}

impl BitIdentical for PoseEstimate {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && f64s(&[self.x, self.y, self.theta], &[o.x, o.y, o.theta])
            && f64s(&self.covariance, &o.covariance)
            && self.n_eff.to_bits() == o.n_eff.to_bits()
            && (
                self.particles,
                self.scans_skipped,
                self.processing_us,
                self._reserved,
            ) == (o.particles, o.scans_skipped, o.processing_us, o._reserved)
    }
}

impl BitIdentical for VoxelCloud {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && self.resolution.to_bits() == o.resolution.to_bits()
            && (self.count, self.truncated, self._reserved) == (o.count, o.truncated, o._reserved)
            && self.points.iter().zip(&o.points).all(|(a, b)| f32s(a, b))
    }
}

impl BitIdentical for MapInfo {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && self.resolution.to_bits() == o.resolution.to_bits()
            && (self.width, self.height, self._reserved) == (o.width, o.height, o._reserved)
            && f64s(
                &[self.origin_x, self.origin_y, self.origin_theta],
                &[o.origin_x, o.origin_y, o.origin_theta],
            )
    }
}

impl BitIdentical for Health {
    fn bit_identical(&self, o: &Self) -> bool {
        self.header.bit_identical(&o.header)
            && self.role == o.role
            && (self.pid, self.state, self._reserved) == (o.pid, o.state, o._reserved)
            && self.uptime_s.to_bits() == o.uptime_s.to_bits()
            && f32s(
                &[
                    self.latency_p50_us,
                    self.latency_p99_us,
                    self.latency_max_us,
                ],
                &[o.latency_p50_us, o.latency_p99_us, o.latency_max_us],
            )
            && (
                self._reserved2,
                self.deadline_misses,
                self.metric_count,
                self._reserved3,
            ) == (
                o._reserved2,
                o.deadline_misses,
                o.metric_count,
                o._reserved3,
            )
            && self.metrics.iter().zip(&o.metrics).all(|(a, b)| {
                a.name == b.name
                    && a.value.to_bits() == b.value.to_bits()
                    && a.expected.to_bits() == b.expected.to_bits()
            })
            && self.last_error == o.last_error
    }
}
