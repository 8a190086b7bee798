//! The world's laser frames, handed to the URG-04LX emulator scan by scan.
//!
//! The emulated sensor keeps its own motor: scan `k` starts (at the rear of
//! the sweep, angle ±π) at `epoch + k · 100 ms` of the host clock, and the
//! driver stamps it from the sensor's timer. The world computes its frames on
//! its own 100 ms grid, step 0 at the frame's start. So that a scan's stamp
//! says when the world measured it, the link runs the world a little ahead of
//! real time, puts sim time 0 on the sensor's grid (see
//! [`crate::timebase::align_start`]) and, when the emulator asks for scan `k`,
//! hands it the frame whose step 0 fell at the host time the sensor's step 0
//! of that scan did. Until the world runs, every beam reads "no object".

use crate::timebase::TimeBase;
use smokenav_hokuyo_codec::Geometry;
use smokenav_hokuyo_emulator::ScanSource;
use smokenav_shared_types::Clock;
use smokenav_sim_world::LaserFrame;
use smokenav_sim_world::laser::CODE_NO_OBJECT;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

/// Frames kept for the emulator to pick from (the world runs < 1 s ahead).
const FRAMES_KEPT: usize = 16;

/// What the feed has done.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LaserFeedStats {
    /// Scans filled from a world frame.
    pub fed: u64,
    /// Scans filled from a frame more than half a scan period off the sensor's timing
    /// (the world fell behind, or runs at another speed).
    pub misaligned: u64,
    /// Scans filled with "no object" because no frame was there (before the run:
    /// all of them; during the run: the world stalled).
    pub empty: u64,
}

#[derive(Debug)]
struct State {
    frames: VecDeque<LaserFrame>,
    timebase: Option<TimeBase>,
    /// Host time the sensor's scan 0 started (rear of the sweep).
    epoch: Option<u64>,
    /// The epoch came from the emulator's own record, not from fill times.
    epoch_exact: bool,
    stats: LaserFeedStats,
}

/// Shared between the link (which pushes frames) and the emulator thread (which pulls scans).
#[derive(Clone)]
pub struct LaserFeed {
    state: Arc<Mutex<State>>,
    clock: Arc<dyn Clock>,
    period_ns: u64,
    /// From the sensor's timestamp (rear) to its step 0, ns.
    rear_to_step0_ns: u64,
    /// From the sensor's timestamp to the end of the sweep it streams (when it sends), ns.
    rear_to_send_ns: u64,
}

impl LaserFeed {
    pub fn new(geometry: &Geometry, clock: Arc<dyn Clock>) -> Self {
        let ns = |s: f64| (s * 1e9).round().max(0.0) as u64;
        Self {
            state: Arc::new(Mutex::new(State {
                frames: VecDeque::with_capacity(FRAMES_KEPT),
                timebase: None,
                epoch: None,
                epoch_exact: false,
                stats: LaserFeedStats::default(),
            })),
            clock,
            period_ns: ns(geometry.scan_period_s()),
            rear_to_step0_ns: ns(geometry.time_from_rear_s(0)),
            rear_to_send_ns: ns(geometry.time_from_rear_s(geometry.amax)),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // The emulator thread panicking must not stop the world.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Scan period of the sensor, ns.
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// From the sensor's scan timestamp to its step 0, ns (12.5 ms on the 04LX).
    pub fn rear_to_step0_ns(&self) -> u64 {
        self.rear_to_step0_ns
    }

    /// Host time the sensor's scan 0 started, once known.
    pub fn epoch(&self) -> Option<u64> {
        self.lock().epoch
    }

    /// The exact epoch, from the emulator's record of a sent scan.
    pub fn set_epoch(&self, scan_no: u64, start_host_ns: u64) {
        let mut s = self.lock();
        s.epoch = Some(start_host_ns.saturating_sub(scan_no.saturating_mul(self.period_ns)));
        s.epoch_exact = true;
    }

    /// Starts matching scans to world frames.
    pub fn set_timebase(&self, tb: TimeBase) {
        let mut s = self.lock();
        s.timebase = Some(tb);
        s.frames.clear();
        // Count what happens from the start of the run on.
        s.stats = LaserFeedStats::default();
    }

    /// A new frame from the world (frames arrive in time order).
    pub fn push(&self, frame: LaserFrame) {
        let mut s = self.lock();
        if s.frames.len() == FRAMES_KEPT {
            s.frames.pop_front();
        }
        s.frames.push_back(frame);
    }

    pub fn stats(&self) -> LaserFeedStats {
        self.lock().stats
    }

    /// Fills `ranges` for scan `scan_no`, asked for at host time `now_ns`.
    pub fn fill_at(&self, scan_no: u64, now_ns: u64, ranges: &mut [u16]) {
        let mut s = self.lock();
        // The emulator asks when the sweep is complete, never earlier: the
        // smallest estimate over all scans is the sensor's true epoch.
        let estimate = now_ns
            .saturating_sub(self.rear_to_send_ns)
            .saturating_sub(scan_no.saturating_mul(self.period_ns));
        if !s.epoch_exact {
            s.epoch = Some(s.epoch.map_or(estimate, |e| e.min(estimate)));
        }
        let (Some(tb), Some(epoch)) = (s.timebase, s.epoch) else {
            ranges.fill(CODE_NO_OBJECT);
            s.stats.empty += 1;
            return;
        };
        let step0_host = epoch + scan_no.saturating_mul(self.period_ns) + self.rear_to_step0_ns;
        let want = tb.host_to_sim_signed(step0_host);
        let best = s
            .frames
            .iter()
            .min_by_key(|f| (f.t_ns as i64 - want).unsigned_abs());
        match best {
            Some(f) => {
                let off = (f.t_ns as i64 - want).unsigned_abs() as f64 / tb.speed;
                for (r, v) in ranges.iter_mut().zip(f.ranges_mm.iter()) {
                    *r = *v;
                }
                // A shorter sweep than the frame's is filled from its start.
                if ranges.len() > f.ranges_mm.len() {
                    ranges[f.ranges_mm.len()..].fill(CODE_NO_OBJECT);
                }
                s.stats.fed += 1;
                if off > self.period_ns as f64 / 2.0 {
                    s.stats.misaligned += 1;
                }
            }
            None => {
                ranges.fill(CODE_NO_OBJECT);
                s.stats.empty += 1;
            }
        }
    }
}

impl ScanSource for LaserFeed {
    fn fill(&mut self, scan_no: u64, ranges: &mut [u16], intensities: &mut [u16]) {
        let now = self.clock.now_ns();
        self.fill_at(scan_no, now, ranges);
        // The URG-04LX cannot send intensities (ME hangs it); a plausible constant.
        intensities.fill(1000);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::MockClock;
    use smokenav_sim_world::laser::URG_STEPS;

    fn urg() -> Geometry {
        Geometry::URG_04LX
    }

    fn frame(t_ms: u64, mm: u16) -> LaserFrame {
        LaserFrame {
            seq: t_ms / 100,
            t_ns: t_ms * 1_000_000,
            ranges_mm: [mm; URG_STEPS],
        }
    }

    fn feed() -> LaserFeed {
        LaserFeed::new(&urg(), Arc::new(MockClock::new(0)))
    }

    #[test]
    fn urg_timing_constants_follow_pp() {
        let f = feed();
        assert_eq!(f.period_ns(), 100_000_000);
        // Step 0 is 128 steps after the rear: 128 · 97.66 µs = 12.5 ms.
        assert_eq!(f.rear_to_step0_ns(), 12_500_000);
    }

    #[test]
    fn before_the_run_every_beam_reads_no_object() {
        let f = feed();
        let mut r = [7u16; URG_STEPS];
        f.fill_at(3, 1_000_000_000, &mut r);
        assert!(r.iter().all(|&v| v == CODE_NO_OBJECT));
        assert_eq!(f.stats().empty, 1);
    }

    #[test]
    fn each_scan_gets_the_frame_measured_when_the_sensor_swept() {
        let f = feed();
        // Sensor scan 0 started at host 2.000 s; its step 0 at 2.0125 s = sim 0.
        f.set_epoch(0, 2_000_000_000);
        f.set_timebase(TimeBase::new(2_012_500_000, 1.0));
        for t in [0, 100, 200, 300] {
            f.push(frame(t, 1000 + t as u16));
        }
        let mut r = [0u16; URG_STEPS];
        // Scan 2 is asked for at its send time (2.2833 s, plus 3 ms of thread latency).
        f.fill_at(2, 2_286_300_000, &mut r);
        assert!(r.iter().all(|&v| v == 1200), "{}", r[0]);
        assert_eq!(f.stats().fed, 1);
        assert_eq!(f.stats().misaligned, 0);
    }

    #[test]
    fn the_epoch_is_learned_from_the_earliest_fill() {
        let f = feed();
        let mut r = [0u16; URG_STEPS];
        // Send time of scan k: epoch + k·100 ms + 83.3 ms (step 725 is 853 steps
        // after the rear: 853/1024 · 100 ms); fills come 0–4 ms late.
        let epoch = 1_000_000_000u64;
        let send = 83_300_781;
        for (k, late) in [(0u64, 4_000_000u64), (1, 250_000), (2, 2_000_000)] {
            f.fill_at(k, epoch + k * 100_000_000 + send + late, &mut r);
        }
        let learned = f.epoch().unwrap();
        assert!(learned.abs_diff(epoch) <= 250_000 + 1_000, "{learned}");
    }

    #[test]
    fn a_world_that_falls_behind_counts_misaligned_scans() {
        let f = feed();
        f.set_epoch(0, 0);
        f.set_timebase(TimeBase::new(12_500_000, 1.0));
        f.push(frame(0, 500));
        let mut r = [0u16; URG_STEPS];
        // Scan 5 wants the frame at sim 500 ms; only sim 0 exists.
        f.fill_at(5, 583_300_781, &mut r);
        assert_eq!(r[0], 500);
        assert_eq!(f.stats().misaligned, 1);
    }
}
