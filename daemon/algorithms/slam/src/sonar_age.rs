//! How old each sonar reading is when its scan is taken.
//!
//! A ring fires its transducers one after another and reports the last
//! range of every one of them each cycle: the Scout fires one every 60 ms
//! (`conf_sn` rate 15), so a transducer's value is refreshed once a second
//! and a ring message holds readings up to a second old. A robot driving
//! at 0.3 m/s has moved up to 0.3 m since the front transducer heard the
//! wall ahead: painted as if heard now, that wall lands 0.15 m too far on
//! average (the one behind as much too near). Nothing in the ring's
//! message says when a transducer fired, but its value changes when it
//! does (on a moving robot nearly every firing, in whole inches on the
//! Scout): the change dates the firing to within one ring message, and
//! the ring's cycle — the time between a transducer's changes, most
//! often one cycle — carries that date forward while the value repeats.
//!
//! [`SonarAges`] keeps, per transducer, when its value last changed, and an
//! estimate of the cycle (the mean of the last intervals between changes
//! near their median) and of the ring's message period; [`SonarAges::age_s`] gives a
//! reading's age at a scan's stamp. The pipeline moves each echo painted
//! from that transducer by the robot's odometry motion over that age
//! ([`crate::scan::RangeScan::compensate_sonar`]).

/// Transducers tracked (indices at or above are ignored).
pub const MAX_TRANSDUCERS: usize = 32;
/// Intervals between changes kept for the cycle's median.
const INTERVALS: usize = 64;
/// A change this small is the same reading (ranges pass through `f32`).
const SAME_RANGE_M: f64 = 1e-4;
/// Intervals between changes longer than this say nothing of the cycle
/// (a transducer that heard the same wall for a while), s.
const MAX_CYCLE_S: f64 = 3.0;
/// Ring message periods outside this are gaps, not the period, s.
const MAX_PERIOD_S: f64 = 0.5;

#[derive(Debug, Clone, Copy, Default)]
struct Transducer {
    range: f64,
    /// Ring stamp at which the current value was first seen, ns.
    changed_ns: Option<u64>,
}

/// Per-transducer reading ages, from the changes seen in successive rings.
#[derive(Debug, Clone)]
pub struct SonarAges {
    transducers: [Transducer; MAX_TRANSDUCERS],
    intervals: [f64; INTERVALS],
    interval_count: usize,
    interval_next: usize,
    /// Mean of `intervals` near their median, s (updated as they come).
    cycle_s: Option<f64>,
    last_ring_ns: Option<u64>,
    /// Running mean of the ring message period, s.
    period_s: Option<f64>,
    scratch: [f64; INTERVALS],
}

impl Default for SonarAges {
    fn default() -> Self {
        Self {
            transducers: [Transducer::default(); MAX_TRANSDUCERS],
            intervals: [0.0; INTERVALS],
            interval_count: 0,
            interval_next: 0,
            cycle_s: None,
            last_ring_ns: None,
            period_s: None,
            scratch: [0.0; INTERVALS],
        }
    }
}

impl SonarAges {
    /// Forgets everything (an odometry reset, a new run).
    pub fn clear(&mut self) {
        *self = Self::default();
    }

    /// One ring message's readings, `(transducer index, range m)`, taken at
    /// `stamp_ns`. A ring older than the last one seen is ignored.
    pub fn observe(&mut self, stamp_ns: u64, readings: &[(u8, f64)]) {
        match self.last_ring_ns {
            Some(last) if stamp_ns <= last => return,
            Some(last) => {
                let dt = (stamp_ns - last) as f64 * 1e-9;
                if dt <= MAX_PERIOD_S {
                    self.period_s = Some(match self.period_s {
                        Some(p) => p + 0.1 * (dt - p),
                        None => dt,
                    });
                }
            }
            None => {}
        }
        let first_ring = self.last_ring_ns.is_none();
        self.last_ring_ns = Some(stamp_ns);
        let mut new_interval = false;
        for &(index, range) in readings {
            let Some(t) = self.transducers.get_mut(usize::from(index)) else {
                continue;
            };
            if !range.is_finite() {
                continue;
            }
            if (range - t.range).abs() <= SAME_RANGE_M && !first_ring {
                continue;
            }
            // The first ring dates nothing: its values may be of any age.
            let previous = t.changed_ns;
            t.range = range;
            t.changed_ns = (!first_ring).then_some(stamp_ns);
            if let Some(prev) = previous {
                let dt = (stamp_ns - prev) as f64 * 1e-9;
                if dt > 0.0 && dt <= MAX_CYCLE_S {
                    self.intervals[self.interval_next] = dt;
                    self.interval_next = (self.interval_next + 1) % INTERVALS;
                    self.interval_count = (self.interval_count + 1).min(INTERVALS);
                    new_interval = true;
                }
            }
        }
        if new_interval {
            let n = self.interval_count;
            self.scratch[..n].copy_from_slice(&self.intervals[..n]);
            let mid = n / 2;
            self.scratch[..n].select_nth_unstable_by(mid, f64::total_cmp);
            // Each interval is a whole number of ring messages (0.9 or 1.0 s
            // for a 0.96 s cycle): the mean of those near the median is the
            // cycle, the median alone would be off by up to a period, and
            // carrying the phase over a few cycles would multiply that.
            let median = self.scratch[mid];
            let (sum, count) = self.scratch[..n]
                .iter()
                .filter(|&&d| (d - median).abs() <= 0.25 * median)
                .fold((0.0, 0u32), |(s, c), &d| (s + d, c + 1));
            self.cycle_s = Some(sum / f64::from(count.max(1)));
        }
    }

    /// The ring's cycle: the typical time between a transducer's changes, s.
    pub fn cycle_s(&self) -> Option<f64> {
        self.cycle_s
    }

    /// How old transducer `index`'s reading is at `at_ns`, s: since its
    /// value changed (dated half a ring period before the message that
    /// showed it), modulo the cycle while the value repeats. `None` before
    /// a change and a cycle were seen.
    pub fn age_s(&self, index: u8, at_ns: u64) -> Option<f64> {
        let t = self.transducers.get(usize::from(index))?;
        let changed = t.changed_ns?;
        let cycle = self.cycle_s?;
        let half_period = 0.5 * self.period_s.unwrap_or(0.0);
        let since = at_ns.saturating_sub(changed) as f64 * 1e-9 + half_period;
        Some(since % cycle)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// A ring reporting every 100 ms whose transducers 0 and 1 fire every
    /// 960 ms, 0 at 20 ms into each cycle and 1 at 500 ms, each reading
    /// `range(transducer, firing time s)`.
    fn run(until_ms: u64, range: impl Fn(u8, f64) -> f64) -> SonarAges {
        let mut ages = SonarAges::default();
        let fired = |phase_ms: u64, now_ms: u64| -> Option<u64> {
            (now_ms >= phase_ms).then(|| now_ms - (now_ms - phase_ms) % 960)
        };
        for now in (0..=until_ms).step_by(100) {
            let mut readings = Vec::new();
            for (k, phase) in [(0u8, 20u64), (1, 500)] {
                if let Some(f) = fired(phase, now) {
                    readings.push((k, range(k, f as f64 * 1e-3)));
                }
            }
            ages.observe(now * MS, &readings);
        }
        ages
    }

    #[test]
    fn a_changing_reading_is_dated_by_its_change_and_the_cycle_is_learnt() {
        // Approaching a wall: every firing reads a new range.
        let ages = run(10_000, |k, t| 3.0 - 0.3 * t - f64::from(k));
        let cycle = ages.cycle_s().expect("cycle");
        assert!((cycle - 0.96).abs() < 0.06, "cycle {cycle}");
        // At 10.0 s: transducer 0 fired at 9.620 s, 1 at 9.140 s.
        for (k, truth) in [(0u8, 0.38), (1, 0.86)] {
            let age = ages.age_s(k, 10_000 * MS).expect("age");
            assert!(
                (age - truth).abs() <= 0.06,
                "transducer {k}: {age} vs {truth}"
            );
        }
    }

    #[test]
    fn a_repeating_reading_keeps_its_phase() {
        // Transducer 0 changes until 5 s, then hears the same range; the
        // cycle is learnt from transducer 1, which keeps changing.
        let ages = run(10_000, |k, t| {
            if k == 0 && t > 5.0 {
                1.0
            } else {
                3.0 - 0.1 * t - f64::from(k)
            }
        });
        let age = ages.age_s(0, 10_000 * MS).expect("age");
        assert!((age - 0.38).abs() <= 0.12, "{age}");
    }

    #[test]
    fn nothing_is_dated_before_a_change() {
        // The same ranges throughout (a robot standing still): no change, no cycle.
        let ages = run(5_000, |k, _| 1.0 + f64::from(k));
        assert_eq!(ages.age_s(0, 5_000 * MS), None);
        assert_eq!(ages.cycle_s(), None);
        // Out-of-range indices, non-finite ranges and old rings do not panic or count.
        let mut a = SonarAges::default();
        a.observe(100 * MS, &[(200, 1.0), (0, f64::NAN)]);
        a.observe(50 * MS, &[(0, 2.0)]);
        assert_eq!(a.age_s(200, 100 * MS), None);
        assert_eq!(a.age_s(0, 100 * MS), None);
    }
}
