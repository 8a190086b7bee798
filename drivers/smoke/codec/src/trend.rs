//! Rising / falling / steady with hysteresis.
//!
//! The slope is a least-squares fit over the last `window_s` of samples (a
//! fixed ring, no allocation). Three layers keep noise from flipping it:
//! the fit itself averages, a trend is *entered* at `rate` but only *left*
//! below `rate · EXIT_FRACTION`, and any change must be asked for
//! continuously for `hold_s` before it is reported.

/// Samples kept for the fit. At 10 Hz that is 12.8 s, far more than any
/// sensible window; at higher rates the window shrinks to the newest samples.
pub const TREND_CAPACITY: usize = 128;

/// A trend entered at `rate` persists until the slope falls below this
/// fraction of `rate` (Schmitt-trigger style hysteresis).
pub const EXIT_FRACTION: f64 = 0.5;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Trend {
    #[default]
    Steady,
    Rising,
    Falling,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrendConfig {
    /// Slope that starts a trend, level units per second (> 0).
    pub rate: f64,
    /// How long a change must persist before it is reported, s.
    pub hold_s: f64,
    /// Span of the slope fit, s.
    pub window_s: f64,
}

impl Default for TrendConfig {
    fn default() -> Self {
        Self {
            rate: 5.0,
            hold_s: 0.5,
            window_s: 2.0,
        }
    }
}

#[derive(Debug, Clone)]
pub struct TrendDetector {
    cfg: TrendConfig,
    stamps: [u64; TREND_CAPACITY],
    values: [f64; TREND_CAPACITY],
    /// Next slot to write.
    head: usize,
    len: usize,
    current: Trend,
    /// A different trend the slope asks for, and since when.
    pending: Option<(Trend, u64)>,
    slope: Option<f64>,
}

fn secs_to_ns(s: f64) -> u64 {
    if s.is_finite() && s > 0.0 {
        (s * 1e9) as u64
    } else {
        0
    }
}

impl TrendDetector {
    pub fn new(cfg: TrendConfig) -> Self {
        Self {
            cfg,
            stamps: [0; TREND_CAPACITY],
            values: [0.0; TREND_CAPACITY],
            head: 0,
            len: 0,
            current: Trend::Steady,
            pending: None,
            slope: None,
        }
    }

    /// Back to steady with no history (sensor reconnected, warm-up restarted).
    pub fn reset(&mut self) {
        self.len = 0;
        self.head = 0;
        self.current = Trend::Steady;
        self.pending = None;
        self.slope = None;
    }

    pub fn trend(&self) -> Trend {
        self.current
    }

    /// Latest fitted slope, units/s; `None` until the window has enough
    /// samples.
    pub fn slope(&self) -> Option<f64> {
        self.slope
    }

    /// Adds a sample; stamps must not go backwards (an older stamp is
    /// ignored).
    pub fn update(&mut self, stamp_ns: u64, value: f64) -> Trend {
        if !value.is_finite() {
            return self.current;
        }
        if self.len > 0 {
            let newest = (self.head + TREND_CAPACITY - 1) % TREND_CAPACITY;
            if stamp_ns < self.stamps[newest] {
                return self.current;
            }
        }
        self.stamps[self.head] = stamp_ns;
        self.values[self.head] = value;
        self.head = (self.head + 1) % TREND_CAPACITY;
        self.len = (self.len + 1).min(TREND_CAPACITY);

        self.slope = self.fit(stamp_ns);
        let Some(slope) = self.slope else {
            return self.current;
        };
        let rate = self.cfg.rate;
        let exit = rate * EXIT_FRACTION;
        let wanted = match self.current {
            Trend::Steady if slope > rate => Trend::Rising,
            Trend::Steady if slope < -rate => Trend::Falling,
            Trend::Steady => Trend::Steady,
            Trend::Rising if slope < -rate => Trend::Falling,
            Trend::Rising if slope < exit => Trend::Steady,
            Trend::Rising => Trend::Rising,
            Trend::Falling if slope > rate => Trend::Rising,
            Trend::Falling if slope > -exit => Trend::Steady,
            Trend::Falling => Trend::Falling,
        };
        if wanted == self.current {
            self.pending = None;
            return self.current;
        }
        let since = match self.pending {
            Some((t, since)) if t == wanted => since,
            _ => stamp_ns,
        };
        if stamp_ns.saturating_sub(since) >= secs_to_ns(self.cfg.hold_s) {
            self.current = wanted;
            self.pending = None;
        } else {
            self.pending = Some((wanted, since));
        }
        self.current
    }

    /// Least-squares slope over the samples within the window ending at
    /// `now_ns`. Needs three samples spanning half the window.
    fn fit(&self, now_ns: u64) -> Option<f64> {
        let window_ns = secs_to_ns(self.cfg.window_s);
        let oldest_allowed = now_ns.saturating_sub(window_ns);
        let (mut n, mut st, mut sv, mut stt, mut stv) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut span_ns = 0u64;
        for k in 0..self.len {
            let i = (self.head + TREND_CAPACITY - 1 - k) % TREND_CAPACITY;
            let stamp = self.stamps[i];
            if stamp < oldest_allowed {
                break;
            }
            span_ns = now_ns - stamp;
            // Seconds before now: small numbers, no precision loss.
            let t = -(span_ns as f64) * 1e-9;
            let v = self.values[i];
            n += 1.0;
            st += t;
            sv += v;
            stt += t * t;
            stv += t * v;
        }
        if n < 3.0 || span_ns < window_ns / 2 {
            return None;
        }
        let denom = n * stt - st * st;
        if denom <= f64::EPSILON {
            return None;
        }
        Some((n * stv - st * sv) / denom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// 5 units/s to enter, 0.5 s hold, 1 s fit.
    fn cfg() -> TrendConfig {
        TrendConfig {
            rate: 5.0,
            hold_s: 0.5,
            window_s: 1.0,
        }
    }

    fn run(
        det: &mut TrendDetector,
        from_ms: u64,
        to_ms: u64,
        f: impl Fn(f64) -> f64,
    ) -> Vec<Trend> {
        (from_ms..to_ms)
            .step_by(100)
            .map(|t| det.update(t * MS, f(t as f64 / 1000.0)))
            .collect()
    }

    #[test]
    fn ramp_of_20_per_second_is_rising_after_window_and_hold() {
        let mut det = TrendDetector::new(cfg());
        let got = run(&mut det, 0, 3000, |t| 20.0 * t);
        assert!((det.slope().unwrap() - 20.0).abs() < 1e-6);
        // Fit needs 0.5 s of span, then 0.5 s hold: rising from 1.0 s on.
        assert_eq!(got[..10], [Trend::Steady; 10]);
        assert_eq!(got[10..], [Trend::Rising; 20]);
    }

    #[test]
    fn slope_between_exit_and_entry_keeps_the_current_trend() {
        let mut det = TrendDetector::new(cfg());
        run(&mut det, 0, 2000, |t| -10.0 * t);
        assert_eq!(det.trend(), Trend::Falling);
        // −3/s: above the −2.5 exit, below the −5 entry.
        let v0 = -20.0;
        let got = run(&mut det, 2000, 6000, |t| v0 - 3.0 * (t - 2.0));
        assert!(got.iter().all(|&t| t == Trend::Falling), "{got:?}");
        // −1/s is below the exit: steady after the hold.
        let v1 = v0 - 12.0;
        let got = run(&mut det, 6000, 9000, |t| v1 - 1.0 * (t - 6.0));
        assert_eq!(*got.last().unwrap(), Trend::Steady);
    }

    #[test]
    fn brief_spike_shorter_than_hold_does_not_switch() {
        let cfg = TrendConfig {
            hold_s: 1.0,
            ..cfg()
        };
        let mut det = TrendDetector::new(cfg);
        run(&mut det, 0, 2000, |_| 0.0);
        // One 50-unit sample: the 1 s fit sees a slope for ~0.6 s, under the hold.
        let got = run(&mut det, 2000, 6000, |t| {
            if (t - 2.5).abs() < 0.01 { 50.0 } else { 0.0 }
        });
        assert!(got.iter().all(|&t| t == Trend::Steady), "{got:?}");
    }

    #[test]
    fn zero_hold_switches_on_the_first_qualifying_fit() {
        let cfg = TrendConfig {
            hold_s: 0.0,
            ..cfg()
        };
        let mut det = TrendDetector::new(cfg);
        let got = run(&mut det, 0, 1000, |t| 20.0 * t);
        assert_eq!(got[5], Trend::Rising);
    }

    #[test]
    fn stamps_going_backwards_are_ignored() {
        let mut det = TrendDetector::new(cfg());
        run(&mut det, 0, 2000, |t| 20.0 * t);
        assert_eq!(det.update(500 * MS, -1000.0), Trend::Rising);
        assert!((det.slope().unwrap() - 20.0).abs() < 1e-6);
    }

    #[test]
    fn reset_forgets_history() {
        let mut det = TrendDetector::new(cfg());
        run(&mut det, 0, 2000, |t| 20.0 * t);
        det.reset();
        assert_eq!(det.trend(), Trend::Steady);
        assert_eq!(det.slope(), None);
    }
}
