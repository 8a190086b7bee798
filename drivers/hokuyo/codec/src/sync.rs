//! Sensor-clock synchronisation: maps the sensor's 24-bit millisecond timestamps to
//! host monotonic nanoseconds.
//!
//! Pure: every function takes host stamps from its caller; nothing reads a clock.
//!
//! 1. Calibration (TM0, then repeated TM1 with the host time taken before and after
//!    each, then TM2): offset = sensor time − round-trip midpoint; the samples with
//!    the shortest round trips are kept and their median offset is used.
//! 2. Streaming: every scan gives `delay = receive time − mapped sensor time`. Its
//!    lower envelope (the minimum per window of scans) moves only when the clocks
//!    drift apart, so a straight line fitted through the recent window minima gives
//!    the drift and the offset's wander; the first window after calibration fixes the
//!    true minimum delay (`floor`) that the envelope is measured against.
//! 3. The 24-bit counter wraps every 16 777 216 ms (4 h 40 min); a jump of more than
//!    100 ms away from the prediction for a few scans in a row (or the sensor time
//!    going backwards, as after RS) re-anchors on the envelope and is counted.

use thiserror::Error;

/// The sensor counter wraps at 2^24 ms.
pub const SENSOR_WRAP_MS: u64 = 1 << 24;
const NS_PER_MS: i64 = 1_000_000;

/// Unwraps the 24-bit sensor time into a monotonic 64-bit millisecond count.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WrapTracker {
    last: Option<u32>,
    wraps: u64,
}

impl WrapTracker {
    /// Unwrapped time of `raw` (only its low 24 bits are used).
    pub fn unwrap(&mut self, raw: u32) -> u64 {
        let raw = raw & 0xFF_FFFF;
        let half = 1u32 << 23;
        if let Some(last) = self.last {
            if raw < last && last - raw > half {
                self.wraps += 1;
            } else if raw > last && raw - last > half && self.wraps > 0 {
                // A late sample from before the last wrap: place it, keep the state.
                return (self.wraps - 1) * SENSOR_WRAP_MS + u64::from(raw);
            }
        }
        self.last = Some(raw);
        self.wraps * SENSOR_WRAP_MS + u64::from(raw)
    }

    pub fn wraps(&self) -> u64 {
        self.wraps
    }
}

/// One TM1 exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimeSample {
    /// Host time just before the TM1 request was written, ns.
    pub host_before_ns: u64,
    /// Host time just after the reply was read, ns.
    pub host_after_ns: u64,
    /// The sensor time in the reply, ms (24-bit).
    pub sensor_ms: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum SyncError {
    #[error("clock calibration needs at least one TM1 sample, got none")]
    NoSamples,
    #[error(
        "TM1 sample {index}: host time after ({after} ns) is before host time before ({before} ns)"
    )]
    HostTimeBackwards {
        index: usize,
        before: u64,
        after: u64,
    },
}

/// Result of a calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OffsetEstimate {
    /// host_ns = sensor_ms · 10⁶ + offset_ns (sensor time unwrapped).
    pub offset_ns: i64,
    /// Median round trip of the samples used, ns.
    pub round_trip_ns: u64,
    /// Samples used / given.
    pub used: usize,
    pub given: usize,
}

/// Tuning of [`ClockSync`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyncConfig {
    /// Scans per envelope window (20 = 2 s at 10 Hz).
    pub window_scans: usize,
    /// Delay jump, ns, that counts as the clocks disagreeing (urg_node uses 0.1 s).
    pub jump_threshold_ns: i64,
    /// Consecutive disagreeing scans before re-anchoring.
    pub jump_confirm: u32,
    /// Delay assumed between the sensor timestamp and the last byte received when
    /// no calibration was possible, ns (one 04LX scan period: data is sent after the sweep).
    pub uncalibrated_delay_ns: i64,
}

impl Default for SyncConfig {
    fn default() -> Self {
        SyncConfig {
            window_scans: 20,
            jump_threshold_ns: 100_000_000,
            jump_confirm: 3,
            uncalibrated_delay_ns: 100_000_000,
        }
    }
}

/// Windows of envelope history kept for the drift fit.
pub const ENVELOPE_WINDOWS: usize = 32;

/// Counters and estimates for health reports.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SyncStats {
    /// Scans mapped.
    pub scans: u64,
    /// Times the mapping was re-anchored (clock jump, sensor reset).
    pub resets: u64,
    /// Estimated sensor-clock drift against the host, ppm (positive: sensor slow).
    pub drift_ppm: f64,
    /// Last observed delay from the (corrected) sensor stamp to receipt, ns.
    pub last_delay_ns: i64,
    /// Whether a TM calibration anchors the mapping.
    pub calibrated: bool,
    /// 24-bit wraps seen.
    pub wraps: u64,
}

#[derive(Debug, Clone, Copy)]
struct Anchor {
    host_ns: i64,
    sensor_ms: u64,
}

/// Streaming sensor→host time mapping. Fixed size; no allocation.
#[derive(Debug, Clone)]
pub struct ClockSync {
    cfg: SyncConfig,
    wrap: WrapTracker,
    anchor: Option<Anchor>,
    last_sensor_ms: Option<u64>,
    /// Minimum delay seen in the first window after anchoring.
    floor_ns: Option<i64>,
    win_min: i64,
    win_min_x: f64,
    win_n: usize,
    /// (sensor ms since anchor, window-minimum delay ns), ring.
    env: [(f64, f64); ENVELOPE_WINDOWS],
    env_len: usize,
    env_next: usize,
    /// correction(x) = fit_a + fit_b · x − floor, ns.
    fit_a: f64,
    fit_b: f64,
    has_fit: bool,
    disagreeing: u32,
    stats: SyncStats,
}

impl ClockSync {
    pub fn new(cfg: SyncConfig) -> Self {
        ClockSync {
            cfg,
            wrap: WrapTracker::default(),
            anchor: None,
            last_sensor_ms: None,
            floor_ns: None,
            win_min: i64::MAX,
            win_min_x: 0.0,
            win_n: 0,
            env: [(0.0, 0.0); ENVELOPE_WINDOWS],
            env_len: 0,
            env_next: 0,
            fit_a: 0.0,
            fit_b: 0.0,
            has_fit: false,
            disagreeing: 0,
            stats: SyncStats::default(),
        }
    }

    pub fn stats(&self) -> SyncStats {
        SyncStats {
            wraps: self.wrap.wraps(),
            ..self.stats
        }
    }

    /// Anchors the mapping on TM1 samples (taken in one TM0…TM2 session, in order).
    /// Discards the streaming history: call it on every (re)connection.
    pub fn calibrate(&mut self, samples: &[TimeSample]) -> Result<OffsetEstimate, SyncError> {
        if samples.is_empty() {
            return Err(SyncError::NoSamples);
        }
        let mut wrap = WrapTracker::default();
        // At most 64 samples are considered; calibration uses a handful.
        let mut offsets = [(0u64, 0i64); 64];
        let n = samples.len().min(offsets.len());
        let mut last_unwrapped = 0;
        for (i, s) in samples.iter().take(n).enumerate() {
            if s.host_after_ns < s.host_before_ns {
                return Err(SyncError::HostTimeBackwards {
                    index: i,
                    before: s.host_before_ns,
                    after: s.host_after_ns,
                });
            }
            let rtt = s.host_after_ns - s.host_before_ns;
            let mid = s.host_before_ns as i64 + (rtt / 2) as i64;
            let unwrapped = wrap.unwrap(s.sensor_ms);
            last_unwrapped = unwrapped;
            // The counter truncates: the sensor instant lies in [ms, ms + 1).
            let sensor_ns = unwrapped as i64 * NS_PER_MS + NS_PER_MS / 2;
            offsets[i] = (rtt, mid - sensor_ns);
        }
        let used = &mut offsets[..n];
        used.sort_unstable_by_key(|&(rtt, _)| rtt);
        // Keep the faster half (at least one): long round trips hide queueing.
        let keep = n.div_ceil(2);
        let round_trip_ns = used[keep / 2].0;
        let best = &mut used[..keep];
        best.sort_unstable_by_key(|&(_, off)| off);
        let offset_ns = best[keep / 2].1;

        self.wrap = wrap;
        self.anchor = Some(Anchor {
            host_ns: last_unwrapped as i64 * NS_PER_MS + offset_ns,
            sensor_ms: last_unwrapped,
        });
        self.last_sensor_ms = Some(last_unwrapped);
        self.reset_history();
        self.floor_ns = None;
        self.stats.calibrated = true;
        Ok(OffsetEstimate {
            offset_ns,
            round_trip_ns,
            used: keep,
            given: samples.len(),
        })
    }

    /// Forgets calibration and history (a different sensor, or a power cycle).
    pub fn forget(&mut self) {
        *self = ClockSync {
            stats: SyncStats {
                resets: self.stats.resets,
                ..SyncStats::default()
            },
            ..ClockSync::new(self.cfg)
        };
    }

    fn reset_history(&mut self) {
        self.win_min = i64::MAX;
        self.win_n = 0;
        self.env_len = 0;
        self.env_next = 0;
        self.has_fit = false;
        self.fit_a = 0.0;
        self.fit_b = 0.0;
        self.disagreeing = 0;
    }

    fn correction_ns(&self, x: f64) -> f64 {
        match (self.has_fit, self.floor_ns) {
            (true, Some(floor)) => self.fit_a + self.fit_b * x - floor as f64,
            _ => 0.0,
        }
    }

    /// Host time (ns) at which the sensor took `sensor_raw` (the scan timestamp),
    /// given the host time the scan's last byte was received.
    pub fn on_scan(&mut self, sensor_raw: u32, host_recv_ns: u64) -> u64 {
        let recv = host_recv_ns as i64;
        let s = self.wrap.unwrap(sensor_raw);
        self.stats.scans += 1;
        let went_back = self.last_sensor_ms.is_some_and(|last| s < last);
        self.last_sensor_ms = Some(s);
        let anchor = match self.anchor {
            Some(a) if !went_back => a,
            _ => {
                if self.anchor.is_some() {
                    self.stats.resets += 1;
                }
                self.reanchor(s, recv)
            }
        };
        let x = (s as i64 - anchor.sensor_ms as i64) as f64;
        let nominal = anchor.host_ns + (s as i64 - anchor.sensor_ms as i64) * NS_PER_MS;
        let delay = recv - nominal;
        let predicted_delay = self
            .floor_ns
            .map_or(delay, |f| f + self.correction_ns(x) as i64);
        if (delay - predicted_delay).abs() > self.cfg.jump_threshold_ns {
            self.disagreeing += 1;
            if self.disagreeing >= self.cfg.jump_confirm {
                self.stats.resets += 1;
                let a = self.reanchor(s, recv);
                self.stats.last_delay_ns = recv - a.host_ns;
                return a.host_ns.max(0) as u64;
            }
        } else {
            self.disagreeing = 0;
            self.observe(x, delay);
        }
        let stamp = (nominal as f64 + self.correction_ns(x)) as i64;
        let stamp = stamp.min(recv);
        self.stats.last_delay_ns = recv - stamp;
        stamp.max(0) as u64
    }

    /// Re-anchors on this scan assuming it came with the minimum delay.
    fn reanchor(&mut self, s: u64, recv: i64) -> Anchor {
        let floor = self.floor_ns.unwrap_or(self.cfg.uncalibrated_delay_ns);
        let a = Anchor {
            host_ns: recv - floor,
            sensor_ms: s,
        };
        self.anchor = Some(a);
        self.reset_history();
        self.floor_ns = Some(floor);
        a
    }

    fn observe(&mut self, x: f64, delay: i64) {
        if delay < self.win_min {
            self.win_min = delay;
            self.win_min_x = x;
        }
        self.win_n += 1;
        if self.win_n < self.cfg.window_scans.max(1) {
            return;
        }
        if self.floor_ns.is_none() {
            self.floor_ns = Some(self.win_min);
        }
        self.env[self.env_next] = (self.win_min_x, self.win_min as f64);
        self.env_next = (self.env_next + 1) % ENVELOPE_WINDOWS;
        self.env_len = (self.env_len + 1).min(ENVELOPE_WINDOWS);
        self.win_min = i64::MAX;
        self.win_n = 0;
        self.fit();
    }

    /// Least-squares line through the envelope points.
    fn fit(&mut self) {
        let len = self.env_len;
        // Window minima carry up to ~1 ms of noise (1 ms sensor resolution plus
        // jitter); a slope from a short baseline would amplify it, so until
        // MIN_SLOPE_WINDOWS exist only the level of the newest minima is used.
        if len < MIN_SLOPE_WINDOWS {
            let k = len.min(3);
            let level: f64 = (0..k)
                .map(|i| self.env[(self.env_next + ENVELOPE_WINDOWS - 1 - i) % ENVELOPE_WINDOWS].1)
                .sum::<f64>()
                / k as f64;
            self.fit_a = level;
            self.fit_b = 0.0;
            self.has_fit = true;
            return;
        }
        let pts = &self.env[..len];
        let n = len as f64;
        let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
        let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        self.fit_b = b;
        self.fit_a = my - b * mx;
        self.has_fit = true;
        // b is ns of extra delay per ms of sensor time: 1 ns/ms = 1 ppm.
        self.stats.drift_ppm = b;
    }
}

/// Envelope windows needed before a drift slope is fitted (12 s at 10 Hz).
const MIN_SLOPE_WINDOWS: usize = 6;

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic jitter in [0, max) ns.
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self, max: u64) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (self.0 >> 33) % max
        }
    }

    #[test]
    fn wrap_tracker_unwraps_across_2_pow_24() {
        let mut w = WrapTracker::default();
        assert_eq!(w.unwrap(16_777_000), 16_777_000);
        assert_eq!(w.unwrap(100), SENSOR_WRAP_MS + 100);
        // A late sample from before the wrap lands before it.
        assert_eq!(w.unwrap(16_777_100), 16_777_100);
        assert_eq!(w.unwrap(200), SENSOR_WRAP_MS + 200);
        assert_eq!(w.wraps(), 1);
    }

    #[test]
    fn calibration_takes_the_median_of_the_fast_round_trips() {
        // Sensor time = (host − 5 s) / 1 ms, truncated; round trips 2 ms, one of 80 ms.
        let offset = 5_000_000_000i64;
        let samples: Vec<TimeSample> = (0..9u64)
            .map(|i| {
                let before = 10_000_000_000 + i * 20_000_000;
                let rtt = if i == 4 { 80_000_000 } else { 2_000_000 };
                let mid = before + rtt / 2;
                TimeSample {
                    host_before_ns: before,
                    host_after_ns: before + rtt,
                    sensor_ms: ((mid as i64 - offset) / NS_PER_MS) as u32,
                }
            })
            .collect();
        let mut sync = ClockSync::new(SyncConfig::default());
        let est = sync.calibrate(&samples).unwrap();
        assert!(
            (est.offset_ns - offset).abs() <= 500_000,
            "offset {}",
            est.offset_ns
        );
        assert_eq!(est.round_trip_ns, 2_000_000);
        assert_eq!(est.used, 5);
        assert_eq!(sync.calibrate(&[]), Err(SyncError::NoSamples));
    }

    /// Simulates a 10 Hz sensor whose clock runs `drift_ppm` slow, delays
    /// `floor + jitter`, and returns the worst |stamp − truth| after `settle` scans.
    fn simulate(
        drift_ppm: f64,
        sensor_start_ms: u32,
        scans: usize,
        settle: usize,
        reset_at: Option<usize>,
    ) -> (i64, ClockSync) {
        let host0: i64 = 50_000_000_000;
        let to_sensor = |host: i64, base: i64| {
            base + ((host - host0) as f64 * (1.0 - drift_ppm * 1e-6) / 1e6).floor() as i64
        };
        let mut sync = ClockSync::new(SyncConfig::default());
        let samples: Vec<TimeSample> = (0..10)
            .map(|i| {
                let before = host0 - 2_000_000_000 + i * 10_000_000;
                let after = before + 1_500_000;
                let sensor = to_sensor((before + after) / 2, i64::from(sensor_start_ms));
                TimeSample {
                    host_before_ns: before as u64,
                    host_after_ns: after as u64,
                    sensor_ms: (sensor as u64 & 0xFF_FFFF) as u32,
                }
            })
            .collect();
        sync.calibrate(&samples).unwrap();
        let mut rng = Lcg(7);
        let mut worst = 0i64;
        let mut base = i64::from(sensor_start_ms);
        for k in 0..scans {
            let truth = host0 + k as i64 * 100_000_000;
            if Some(k) == reset_at {
                // RS: the sensor counter restarts at 0.
                base = -to_sensor(truth, 0);
            }
            let sensor = to_sensor(truth, base);
            let recv = truth + 104_000_000 + rng.next(6_000_000) as i64;
            let stamp = sync.on_scan((sensor as u64 & 0xFF_FFFF) as u32, recv as u64) as i64;
            if k >= settle && reset_at.is_none_or(|r| k < r || k >= r + 40) {
                worst = worst.max((stamp - truth).abs());
            }
        }
        (worst, sync)
    }

    // Error budget with a 1 ms sensor counter: ±0.5 ms truncation of each scan
    // stamp, up to 0.5 ms calibration bias (TM1 times truncate too), and ~0.5 ms
    // of window-minimum noise from the 0–6 ms delay jitter: 2 ms worst case.
    const BUDGET_NS: i64 = 2_000_000;

    #[test]
    fn stamps_track_a_100_ppm_drift_within_2_ms_over_20_minutes() {
        // 100 ppm over 20 min is 120 ms of accumulated drift.
        let (worst, sync) = simulate(100.0, 1_000_000, 12_000, 0, None);
        assert!(worst < BUDGET_NS, "worst error {worst} ns");
        let drift = sync.stats().drift_ppm;
        assert!((drift - 100.0).abs() < 10.0, "drift {drift} ppm");
        assert_eq!(sync.stats().resets, 0);
    }

    #[test]
    fn stamps_stay_continuous_across_the_24_bit_wrap() {
        // Start 60 s before the wrap and run 5 minutes.
        let (worst, sync) = simulate(20.0, (SENSOR_WRAP_MS - 60_000) as u32, 3000, 0, None);
        assert!(worst < BUDGET_NS, "worst error {worst} ns");
        assert_eq!(sync.stats().wraps, 1);
        assert_eq!(sync.stats().resets, 0);
    }

    #[test]
    fn a_sensor_reset_reanchors_and_is_counted() {
        let (worst, sync) = simulate(0.0, 3_000_000, 2000, 0, Some(1000));
        assert_eq!(sync.stats().resets, 1);
        // Re-anchoring assumes the minimum delay: the error is at most the jitter.
        assert!(worst < 7_000_000, "worst error {worst} ns");
    }

    #[test]
    fn uncalibrated_stamps_subtract_the_assumed_delay() {
        let mut sync = ClockSync::new(SyncConfig::default());
        let stamp = sync.on_scan(1234, 10_000_000_000);
        assert_eq!(stamp, 9_900_000_000);
        assert!(!sync.stats().calibrated);
    }
}
