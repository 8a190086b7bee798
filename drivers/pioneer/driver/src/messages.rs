//! SIPs to bus messages: `Odometry` per SIP, a `SonarRing` per firing cycle.

use smokenav_pioneer_codec::{OdomEstimate, Sip, SonarSample};
use smokenav_shared_types::{
    Header, MAX_SONARS, Odometry, OdometryFlags, SonarReading, SonarRing, SonarStatus,
};

/// The odometry message for one SIP.
pub fn odometry(
    est: &OdomEstimate,
    sip: &Sip,
    stamp_ns: u64,
    seq: u64,
    frame: &str,
    reset: bool,
) -> Odometry {
    let mut flags = 0;
    if sip.motors_enabled() {
        flags |= OdometryFlags::MOTORS_ENABLED;
    }
    if sip.left_stall() {
        flags |= OdometryFlags::LEFT_STALL;
    }
    if sip.right_stall() {
        flags |= OdometryFlags::RIGHT_STALL;
    }
    if reset {
        flags |= OdometryFlags::RESET;
    }
    Odometry {
        header: Header::new(stamp_ns, seq, frame),
        x: est.x_m,
        y: est.y_m,
        theta: est.theta,
        linear: est.linear_mps,
        angular: est.angular_rps,
        flags,
        bumpers: u32::from(sip.front_bumpers()) | (u32::from(sip.rear_bumpers()) << 8),
        battery_v: sip.battery_volts() as f32,
        _reserved: 0,
    }
}

/// Which transducers the profile has and how far they see.
#[derive(Debug, Clone, PartialEq)]
pub struct SonarGeometry {
    /// Transducer indices the robot profile gives a pose for.
    pub indices: Vec<u8>,
    pub max_range_m: f32,
    pub min_range_m: f32,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SonarCounters {
    pub readings: u64,
    /// Readings of transducers the profile does not list (e.g. the rear
    /// array when the profile has the front 8; rosaria #7).
    pub unconfigured: u64,
    pub saturated: u64,
    pub rings: u64,
}

/// Collects readings until every configured transducer reported once (or
/// one reports again), then emits a ring. AMRISim sends all 16 in every SIP:
/// one ring per SIP. A real controller fires a few per SIP: one ring per cycle.
pub struct SonarAssembler {
    geometry: SonarGeometry,
    range_conv: f64,
    wanted: u32,
    seen: u32,
    pending: SonarRing,
    counters: SonarCounters,
}

impl SonarAssembler {
    pub fn new(geometry: SonarGeometry, range_conv: f64) -> Self {
        let wanted = geometry
            .indices
            .iter()
            .filter(|&&i| usize::from(i) < MAX_SONARS)
            .fold(0u32, |m, &i| m | (1 << i));
        Self {
            geometry,
            range_conv,
            wanted,
            seen: 0,
            pending: SonarRing::default(),
            counters: SonarCounters::default(),
        }
    }

    pub fn counters(&self) -> SonarCounters {
        self.counters
    }

    /// Conversion factor of the connected robot (mm per range unit).
    pub fn set_range_conv(&mut self, range_conv: f64) {
        self.range_conv = range_conv;
    }

    /// Drop a half-collected cycle (after a reconnect).
    pub fn clear(&mut self) {
        self.seen = 0;
        self.pending = SonarRing::default();
    }

    /// Adds one SIP's readings; `emit` gets each completed ring (header
    /// stamped `stamp_ns`, seq and frame left for the publisher).
    pub fn add(
        &mut self,
        samples: &[SonarSample],
        stamp_ns: u64,
        emit: &mut impl FnMut(SonarRing),
    ) {
        for s in samples {
            let bit = match 1u32.checked_shl(u32::from(s.index)) {
                Some(b) if self.wanted & b != 0 => b,
                _ => {
                    self.counters.unconfigured += 1;
                    continue;
                }
            };
            if self.seen & bit != 0 {
                self.flush(emit);
            }
            self.counters.readings += 1;
            let range_m = (f64::from(s.range) * self.range_conv / 1000.0) as f32;
            let max = self.geometry.max_range_m;
            let reading = if s.range == 0 {
                SonarReading::new(s.index, 0.0, SonarStatus::Invalid)
            } else if range_m >= max {
                // No echo within range: free space or a specular miss, never an obstacle.
                self.counters.saturated += 1;
                SonarReading::new(s.index, max, SonarStatus::Saturated)
            } else {
                SonarReading::new(s.index, range_m, SonarStatus::Valid)
            };
            self.pending.push(reading);
            self.pending.header.stamp_ns = stamp_ns;
            self.seen |= bit;
        }
        if self.seen == self.wanted && self.wanted != 0 {
            self.flush(emit);
        }
    }

    fn flush(&mut self, emit: &mut impl FnMut(SonarRing)) {
        if self.pending.is_empty() {
            return;
        }
        let mut ring = std::mem::take(&mut self.pending);
        ring.max_range = self.geometry.max_range_m;
        self.seen = 0;
        self.counters.rings += 1;
        emit(ring);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_pioneer_codec::sip::SIP_STOPPED;

    fn front8() -> SonarGeometry {
        SonarGeometry {
            indices: (0..8).collect(),
            max_range_m: 5.0,
            min_range_m: 0.1,
        }
    }

    fn samples(v: &[(u8, u16)]) -> Vec<SonarSample> {
        v.iter()
            .map(|&(index, range)| SonarSample { index, range })
            .collect()
    }

    #[test]
    fn amrisim_sip_of_16_gives_one_ring_of_the_8_configured() {
        // First capture SIP: sonar 4 reads 5000 (88 13) = no echo.
        let s = samples(&[
            (0, 1593),
            (1, 3484),
            (2, 2801),
            (3, 1869),
            (4, 5000),
            (5, 4707),
            (6, 4573),
            (7, 1102),
            (8, 960),
            (9, 837),
            (10, 872),
            (11, 551),
            (12, 533),
            (13, 991),
            (14, 959),
            (15, 1363),
        ]);
        let mut a = SonarAssembler::new(front8(), 1.0);
        let mut rings = Vec::new();
        a.add(&s, 42, &mut |r| rings.push(r));
        assert_eq!(rings.len(), 1);
        let r = &rings[0];
        assert_eq!(r.len(), 8);
        assert_eq!(r.header.stamp_ns, 42);
        assert_eq!(r.max_range, 5.0);
        assert_eq!(r.by_index(0).unwrap().valid_range(), Some(1.593));
        let four = r.by_index(4).unwrap();
        assert_eq!(four.status(), SonarStatus::Saturated);
        assert_eq!(four.valid_range(), None);
        assert_eq!(a.counters().unconfigured, 8);
    }

    #[test]
    fn real_controller_cycle_of_3_per_sip_completes_after_3_sips() {
        let mut a = SonarAssembler::new(front8(), 1.0);
        let mut rings = Vec::new();
        a.add(&samples(&[(0, 500), (1, 600), (2, 700)]), 1, &mut |r| {
            rings.push(r)
        });
        a.add(&samples(&[(3, 500), (4, 600), (5, 700)]), 2, &mut |r| {
            rings.push(r)
        });
        assert!(rings.is_empty());
        a.add(&samples(&[(6, 500), (7, 600), (0, 900)]), 3, &mut |r| {
            rings.push(r)
        });
        assert_eq!(rings.len(), 1);
        assert_eq!(rings[0].len(), 8);
        assert_eq!(rings[0].by_index(0).unwrap().range, 0.5);
        // The repeat of sonar 0 starts the next ring.
        a.add(&samples(&[(1, 500)]), 4, &mut |r| rings.push(r));
        assert_eq!(rings.len(), 1);
    }

    #[test]
    fn p2_range_conv_scales_ranges() {
        let mut a = SonarAssembler::new(front8(), 0.268);
        let mut rings = Vec::new();
        let all: Vec<(u8, u16)> = (0..8).map(|i| (i, 1000)).collect();
        a.add(&samples(&all), 0, &mut |r| rings.push(r));
        assert!((rings[0].readings()[0].range - 0.268).abs() < 1e-6);
    }

    #[test]
    fn odometry_message_carries_flags_bumpers_battery() {
        let sip = Sip {
            packet_type: SIP_STOPPED,
            flags: 1,
            stall_bumpers: 0x0100 | (0b11 << 9) | (0b1 << 1),
            battery_dv: 125,
            ..Default::default()
        };
        let est = OdomEstimate {
            x_m: 1.0,
            y_m: 2.0,
            theta: 0.5,
            linear_mps: 0.3,
            angular_rps: 0.1,
            baseline: false,
        };
        let m = odometry(&est, &sip, 7, 3, "odom", true);
        assert!(m.motors_enabled());
        assert_eq!(
            m.flags & OdometryFlags::RIGHT_STALL,
            OdometryFlags::RIGHT_STALL
        );
        assert_eq!(m.flags & OdometryFlags::RESET, OdometryFlags::RESET);
        assert_eq!(m.bumpers, 0b11 | (0b1 << 8));
        assert!((m.battery_v - 12.5).abs() < 1e-6);
        assert_eq!((m.header.stamp_ns, m.header.seq), (7, 3));
        assert_eq!(m.header.frame_id.as_str(), "odom");
    }
}
