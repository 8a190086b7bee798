//! The mapping between the world's time (ns since the scenario started) and
//! the host's monotonic clock, which every driver stamps its messages with.

/// `host = t0 + sim / speed`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimeBase {
    /// Host time of sim time 0, ns.
    pub t0_host_ns: u64,
    /// Sim seconds per host second (1 = real time).
    pub speed: f64,
}

impl TimeBase {
    pub fn new(t0_host_ns: u64, speed: f64) -> Self {
        let speed = if speed.is_finite() && speed > 0.0 {
            speed
        } else {
            1.0
        };
        Self { t0_host_ns, speed }
    }

    pub fn sim_to_host(&self, sim_ns: u64) -> u64 {
        self.t0_host_ns
            .saturating_add((sim_ns as f64 / self.speed).round() as u64)
    }

    /// Sim time at `host_ns`; 0 before the start.
    pub fn host_to_sim(&self, host_ns: u64) -> u64 {
        (host_ns.saturating_sub(self.t0_host_ns) as f64 * self.speed).round() as u64
    }

    /// Signed sim time at `host_ns` (negative before the start), ns.
    pub fn host_to_sim_signed(&self, host_ns: u64) -> i64 {
        let d = host_ns as i128 - self.t0_host_ns as i128;
        (d as f64 * self.speed).round() as i64
    }
}

/// The first host time at or after `not_before` that is congruent to
/// `anchor + offset` modulo `period`: where to put sim time 0 so the world's
/// scan grid falls on the emulated sensor's own scan grid.
pub fn align_start(not_before: u64, anchor: u64, offset: u64, period: u64) -> u64 {
    if period == 0 {
        return not_before;
    }
    let phase = anchor.wrapping_add(offset) % period;
    let base = not_before - not_before % period + phase;
    if base >= not_before {
        base
    } else {
        base + period
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn real_time_maps_one_to_one_and_speed_compresses_host_time() {
        let t = TimeBase::new(5_000, 1.0);
        assert_eq!(t.sim_to_host(100), 5_100);
        assert_eq!(t.host_to_sim(5_100), 100);
        assert_eq!(t.host_to_sim(10), 0);
        assert_eq!(t.host_to_sim_signed(4_000), -1_000);
        let fast = TimeBase::new(0, 4.0);
        assert_eq!(fast.sim_to_host(400_000_000), 100_000_000);
        assert_eq!(fast.host_to_sim(100_000_000), 400_000_000);
    }

    #[test]
    fn start_is_aligned_to_the_sensor_scan_grid() {
        // Sensor scans start at 1_037 + k·100 ms; sim frames must start 12.5 ms after.
        let p = 100_000_000;
        let s = align_start(5_000_000_000, 1_037, 12_500_000, p);
        assert!(s >= 5_000_000_000 && s < 5_000_000_000 + p);
        assert_eq!((s - 1_037 - 12_500_000) % p, 0);
        assert_eq!(align_start(7, 0, 0, 0), 7);
    }
}
