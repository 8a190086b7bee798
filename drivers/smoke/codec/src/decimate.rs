//! Thinning a sample stream to a publishing rate.
//!
//! A board may print faster than the 10 Hz the paper publishes at. Every
//! sample still goes through the filter; [`RateDecimator`] picks which ones
//! are published. Deadlines advance by exactly one period, so a 50 Hz input
//! yields 10 Hz on average, and a quarter-period tolerance lets a 10 Hz
//! input with jitter through whole instead of dropping every other sample.

#[derive(Debug, Clone)]
pub struct RateDecimator {
    period_ns: u64,
    next_due_ns: Option<u64>,
}

impl RateDecimator {
    /// `rate_hz` outside (0, 1e9] publishes everything.
    pub fn new(rate_hz: f64) -> Self {
        let period_ns = if rate_hz.is_finite() && rate_hz > 0.0 {
            (1e9 / rate_hz) as u64
        } else {
            0
        };
        Self {
            period_ns,
            next_due_ns: None,
        }
    }

    /// Whether the sample stamped `stamp_ns` should be published.
    pub fn accept(&mut self, stamp_ns: u64) -> bool {
        let tolerance = self.period_ns / 4;
        match self.next_due_ns {
            Some(due) if stamp_ns.saturating_add(tolerance) < due => false,
            Some(due) => {
                // After a gap longer than a period, restart the schedule
                // from this sample instead of publishing a burst.
                let next = due.saturating_add(self.period_ns);
                self.next_due_ns = Some(if next <= stamp_ns {
                    stamp_ns.saturating_add(self.period_ns)
                } else {
                    next
                });
                true
            }
            None => {
                self.next_due_ns = Some(stamp_ns.saturating_add(self.period_ns));
                true
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn published(dec: &mut RateDecimator, stamps_ms: impl Iterator<Item = u64>) -> usize {
        stamps_ms.filter(|&t| dec.accept(t * MS)).count()
    }

    #[test]
    fn board_at_50_hz_is_published_at_10_hz() {
        let mut dec = RateDecimator::new(10.0);
        // 500 samples 20 ms apart (0 … 9.98 s): one every 100 ms, both ends
        // included.
        assert_eq!(published(&mut dec, (0..10_000).step_by(20)), 101);
    }

    #[test]
    fn board_at_10_hz_with_15_ms_jitter_is_published_whole() {
        let mut dec = RateDecimator::new(10.0);
        let jitter = [0u64, 15, 3, 12, 0, 9, 14, 1];
        let stamps = (0..100u64).map(|k| k * 100 + jitter[(k % 8) as usize]);
        assert_eq!(published(&mut dec, stamps), 100);
    }

    #[test]
    fn gap_restarts_the_schedule_without_a_burst() {
        let mut dec = RateDecimator::new(10.0);
        assert!(dec.accept(0));
        // Two seconds of silence, then 50 Hz again: one sample, then every 5th.
        let after: Vec<bool> = (0..10u64)
            .map(|k| dec.accept((2000 + k * 20) * MS))
            .collect();
        assert_eq!(
            after,
            [
                true, false, false, false, true, false, false, false, false, true
            ]
        );
    }

    #[test]
    fn zero_rate_publishes_everything() {
        let mut dec = RateDecimator::new(0.0);
        assert_eq!(published(&mut dec, 0..10), 10);
    }
}
