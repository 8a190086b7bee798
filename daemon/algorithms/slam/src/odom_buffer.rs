//! Pairs a scan with the odometry at its stamp: a bounded history of
//! odometry poses, interpolated between the two readings around the stamp.

use smokenav_shared_types::Pose2;
use std::collections::VecDeque;

/// Where the odometry for a stamp came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OdomAt {
    /// Interpolated between two readings around the stamp.
    Interpolated(Pose2),
    /// The stamp lies after the newest reading, by at most the allowed gap: that reading.
    Held(Pose2),
    /// The stamp lies before the oldest reading kept: that reading.
    Oldest(Pose2),
    /// Newer odometry may still arrive: ask again later.
    NotYet,
    /// No odometry at all.
    Missing,
}

impl OdomAt {
    pub fn pose(&self) -> Option<Pose2> {
        match *self {
            OdomAt::Interpolated(p) | OdomAt::Held(p) | OdomAt::Oldest(p) => Some(p),
            OdomAt::NotYet | OdomAt::Missing => None,
        }
    }
}

#[derive(Debug, Clone)]
pub struct OdomBuffer {
    readings: VecDeque<(u64, Pose2)>,
    capacity: usize,
    /// Readings dropped because their stamp went backwards.
    pub out_of_order: u64,
}

impl OdomBuffer {
    pub fn new(capacity: usize) -> Self {
        Self {
            readings: VecDeque::with_capacity(capacity.max(2)),
            capacity: capacity.max(2),
            out_of_order: 0,
        }
    }

    /// Adds a reading; stamps must increase (an older one is counted and dropped).
    pub fn push(&mut self, stamp_ns: u64, pose: Pose2) {
        if !pose.is_finite() {
            self.out_of_order += 1;
            return;
        }
        if let Some(&(last, _)) = self.readings.back()
            && stamp_ns <= last
        {
            if stamp_ns < last {
                self.out_of_order += 1;
            }
            return;
        }
        if self.readings.len() == self.capacity {
            self.readings.pop_front();
        }
        self.readings.push_back((stamp_ns, pose));
    }

    /// Forgets everything (e.g. after an odometry reset).
    pub fn clear(&mut self) {
        self.readings.clear();
    }

    pub fn newest_stamp(&self) -> Option<u64> {
        self.readings.back().map(|r| r.0)
    }

    /// The newest reading: its stamp and pose.
    pub fn newest(&self) -> Option<(u64, Pose2)> {
        self.readings.back().copied()
    }

    /// Odometry at `stamp_ns` only where two readings (or one exactly) are
    /// there to say it: nothing is waited for, held or extrapolated.
    pub fn interpolated(&self, stamp_ns: u64) -> Option<Pose2> {
        match self.at(stamp_ns, u64::MAX, 0, 0) {
            OdomAt::Interpolated(p) => Some(p),
            _ => None,
        }
    }

    /// Odometry at `stamp_ns`. A stamp past the newest reading gives `NotYet`
    /// until `now_ns` is more than `max_wait_ns` past the stamp; then the newest
    /// reading is held if it is at most `max_gap_ns` older than the stamp.
    /// With no reading at all the scan waits the same `max_wait_ns`: at
    /// start-up the first scan may well come before the first odometry.
    pub fn at(&self, stamp_ns: u64, now_ns: u64, max_wait_ns: u64, max_gap_ns: u64) -> OdomAt {
        let may_come = now_ns.saturating_sub(stamp_ns) <= max_wait_ns;
        let (Some(&(first_t, first)), Some(&(last_t, last))) =
            (self.readings.front(), self.readings.back())
        else {
            return if may_come {
                OdomAt::NotYet
            } else {
                OdomAt::Missing
            };
        };
        if stamp_ns > last_t {
            if may_come {
                return OdomAt::NotYet;
            }
            return if stamp_ns - last_t <= max_gap_ns {
                OdomAt::Held(last)
            } else {
                OdomAt::Missing
            };
        }
        if stamp_ns <= first_t {
            return if stamp_ns == first_t {
                OdomAt::Interpolated(first)
            } else {
                OdomAt::Oldest(first)
            };
        }
        // First reading at or after the stamp; the one before it brackets the stamp.
        let i = self.readings.partition_point(|r| r.0 < stamp_ns);
        let (t1, p1) = self.readings[i];
        let (t0, p0) = self.readings[i - 1];
        let t = (stamp_ns - t0) as f64 / (t1 - t0) as f64;
        OdomAt::Interpolated(p0.interpolate(&p1, t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn scan_between_readings_gets_interpolated_odometry() {
        let mut b = OdomBuffer::new(8);
        b.push(100 * MS, Pose2::new(0.0, 0.0, 0.0));
        b.push(200 * MS, Pose2::new(1.0, 0.0, 0.2));
        let OdomAt::Interpolated(p) = b.at(175 * MS, 300 * MS, 50 * MS, 200 * MS) else {
            panic!()
        };
        assert!((p.x - 0.75).abs() < 1e-12 && (p.theta - 0.15).abs() < 1e-12);
    }

    #[test]
    fn only_a_bracketed_or_exact_stamp_is_interpolated() {
        let mut b = OdomBuffer::new(8);
        b.push(100 * MS, Pose2::new(0.0, 0.0, 0.0));
        b.push(200 * MS, Pose2::new(1.0, 0.0, 0.2));
        assert!((b.interpolated(150 * MS).unwrap().x - 0.5).abs() < 1e-12);
        assert_eq!(b.interpolated(200 * MS), Some(Pose2::new(1.0, 0.0, 0.2)));
        assert_eq!(b.interpolated(100 * MS), Some(Pose2::new(0.0, 0.0, 0.0)));
        assert_eq!(b.interpolated(99 * MS), None, "before the oldest");
        assert_eq!(b.interpolated(201 * MS), None, "after the newest");
    }

    #[test]
    fn scan_newer_than_odometry_waits_then_holds_then_gives_up() {
        let mut b = OdomBuffer::new(8);
        b.push(100 * MS, Pose2::new(1.0, 2.0, 0.0));
        assert_eq!(b.at(130 * MS, 150 * MS, 50 * MS, 200 * MS), OdomAt::NotYet);
        assert_eq!(
            b.at(130 * MS, 190 * MS, 50 * MS, 200 * MS),
            OdomAt::Held(Pose2::new(1.0, 2.0, 0.0))
        );
        assert_eq!(
            b.at(900 * MS, 1000 * MS, 50 * MS, 200 * MS),
            OdomAt::Missing
        );
        assert_eq!(OdomBuffer::new(4).at(1, 2, 0, 0), OdomAt::Missing);
    }

    #[test]
    fn a_scan_before_any_odometry_waits_for_it() {
        let mut b = OdomBuffer::new(8);
        assert_eq!(b.at(100 * MS, 120 * MS, 50 * MS, 200 * MS), OdomAt::NotYet);
        assert_eq!(b.at(100 * MS, 151 * MS, 50 * MS, 200 * MS), OdomAt::Missing);
        b.push(110 * MS, Pose2::new(576.5, 0.1, -2.2));
        assert_eq!(
            b.at(100 * MS, 120 * MS, 50 * MS, 200 * MS),
            OdomAt::Oldest(Pose2::new(576.5, 0.1, -2.2))
        );
    }

    #[test]
    fn history_is_bounded_and_out_of_order_readings_are_counted() {
        let mut b = OdomBuffer::new(3);
        for k in 1..=5 {
            b.push(k * 10, Pose2::new(k as f64, 0.0, 0.0));
        }
        b.push(20, Pose2::default());
        b.push(60, Pose2::new(f64::NAN, 0.0, 0.0));
        assert_eq!(b.out_of_order, 2);
        assert_eq!(
            b.at(5, 100, 0, 0),
            OdomAt::Oldest(Pose2::new(3.0, 0.0, 0.0))
        );
        assert_eq!(b.newest_stamp(), Some(50));
    }
}
