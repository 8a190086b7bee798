//! Link events in, `SmokeReading`s to publish out: the signal chain, the
//! publishing rate, what a replug means, and the counters behind health.
//! No bus and no clock: stamps come with the events.

use crate::link::LinkEvent;
use crate::settings::{FRAME_ID, Settings};
use smokenav_platform_config::AdcBackend;
use smokenav_platform_runtime::HealthReporter;
use smokenav_shared_types::{Header, HealthState, SmokeReading, SmokeSensorState, SmokeTrend};
use smokenav_smoke_codec::{RateDecimator, Reading, SensorState, SmokeProcessor, Trend};

/// After a malformed or out-of-range input, health stays `degraded` this
/// long, so one report period cannot miss it.
pub const ERROR_MEMORY_NS: u64 = 3_000_000_000;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counters {
    pub samples: u64,
    pub published: u64,
    /// Lines or attribute values that did not decode (all kinds).
    pub parse_errors: u64,
    pub checksum_errors: u64,
    pub overlong_lines: u64,
    pub out_of_range: u64,
    pub connects: u64,
    /// Open devices that failed (unplug, removal).
    pub losses: u64,
    pub open_failures: u64,
}

pub struct DriverCore {
    processor: SmokeProcessor,
    decimator: RateDecimator,
    period_ns: u64,
    next_idle_ns: u64,
    /// A serial board powers the sensor heater from USB: a replug restarts
    /// warm-up. An IIO ADC on the host's own bus keeps its power.
    replug_restarts_warmup: bool,
    link_up: bool,
    ever_connected: bool,
    last: Option<Reading>,
    last_error_ns: Option<u64>,
    counters: Counters,
}

/// The bus message for a chain output.
pub fn to_message(r: &Reading) -> SmokeReading {
    SmokeReading {
        header: Header::new(r.stamp_ns, 0, FRAME_ID),
        raw_mv: r.raw_mv as f32,
        raw_counts: r.raw_counts,
        level: r.level as f32,
        baseline_mv: r.baseline_mv.unwrap_or(0.0) as f32,
        trend: match r.trend {
            Trend::Steady => SmokeTrend::Steady,
            Trend::Rising => SmokeTrend::Rising,
            Trend::Falling => SmokeTrend::Falling,
        } as u8,
        state: match r.state {
            SensorState::WarmingUp => SmokeSensorState::WarmingUp,
            SensorState::Ready => SmokeSensorState::Ready,
            SensorState::Disconnected => SmokeSensorState::Disconnected,
            SensorState::Saturated => SmokeSensorState::Saturated,
        } as u8,
        _reserved: [0; 6],
    }
}

impl DriverCore {
    pub fn new(
        settings: &Settings,
        start_ns: u64,
    ) -> Result<Self, smokenav_smoke_codec::SignalConfigError> {
        let period_ns = (1e9 / settings.rate_hz) as u64;
        Ok(Self {
            processor: SmokeProcessor::new(settings.signal, start_ns)?,
            decimator: RateDecimator::new(settings.rate_hz),
            period_ns,
            next_idle_ns: start_ns,
            replug_restarts_warmup: settings.backend == AdcBackend::Serial,
            link_up: false,
            ever_connected: false,
            last: None,
            last_error_ns: None,
            counters: Counters::default(),
        })
    }

    pub fn counters(&self) -> &Counters {
        &self.counters
    }

    pub fn last_reading(&self) -> Option<&Reading> {
        self.last.as_ref()
    }

    pub fn baseline_mv(&self) -> Option<f64> {
        self.processor.baseline_mv()
    }

    pub fn warmup_left_s(&self, now_ns: u64) -> f64 {
        self.processor.warmup_left_s(now_ns)
    }

    pub fn link_up(&self) -> bool {
        self.link_up
    }

    fn emit(&mut self, r: Reading) -> SmokeReading {
        self.counters.published += 1;
        self.next_idle_ns = r.stamp_ns.saturating_add(self.period_ns);
        self.last = Some(r);
        to_message(&r)
    }

    /// Handles one event; returns the reading to publish, if one is due.
    pub fn on_event(&mut self, ev: &LinkEvent) -> Option<SmokeReading> {
        match *ev {
            LinkEvent::Connected { stamp_ns, .. } => {
                self.counters.connects += 1;
                if self.ever_connected && self.replug_restarts_warmup {
                    self.processor.restart(stamp_ns);
                }
                self.ever_connected = true;
                self.link_up = true;
                None
            }
            LinkEvent::Sample {
                stamp_ns,
                measurement,
            } => {
                self.counters.samples += 1;
                let r = self.processor.update(stamp_ns, measurement);
                if self.decimator.accept(stamp_ns) {
                    Some(self.emit(r))
                } else {
                    self.last = Some(r);
                    None
                }
            }
            LinkEvent::Malformed { stamp_ns, error } => {
                self.counters.parse_errors += 1;
                self.counters.checksum_errors += u64::from(error.is_checksum());
                self.counters.overlong_lines += u64::from(error.is_overlong());
                self.last_error_ns = Some(stamp_ns);
                None
            }
            LinkEvent::OutOfRange { stamp_ns, .. } => {
                self.counters.out_of_range += 1;
                self.last_error_ns = Some(stamp_ns);
                None
            }
            LinkEvent::Lost { stamp_ns, .. } => {
                self.counters.losses += 1;
                self.link_up = false;
                self.last_error_ns = Some(stamp_ns);
                let r = self.processor.disconnect(stamp_ns);
                Some(self.emit(r))
            }
            LinkEvent::OpenFailed { stamp_ns, .. } => {
                self.counters.open_failures += 1;
                self.link_up = false;
                self.last_error_ns = Some(stamp_ns);
                None
            }
        }
    }

    /// Call whenever a link step ends: while no samples arrive (device gone
    /// or silent past `stale_after_s`), a `Disconnected` reading is due once
    /// per publishing period.
    pub fn on_idle(&mut self, now_ns: u64) -> Option<SmokeReading> {
        if now_ns < self.next_idle_ns {
            return None;
        }
        let r = if self.link_up {
            self.processor.poll(now_ns)?
        } else {
            self.processor.disconnect(now_ns)
        };
        Some(self.emit(r))
    }

    /// Shows the signal chain in health at `now_ns`: its state, counters and
    /// the latest reading (the link's own counters are the link's report).
    pub fn report(&self, h: &mut HealthReporter, now_ns: u64) {
        let c = self.counters;
        h.set_state(self.health_state(now_ns));
        h.set_metric("parse_errors", c.parse_errors as f64);
        h.set_metric("checksum_errors", c.checksum_errors as f64);
        h.set_metric("overlong_lines", c.overlong_lines as f64);
        h.set_metric("out_of_range", c.out_of_range as f64);
        h.set_metric("samples", c.samples as f64);
        h.set_metric(
            "baseline_known",
            f64::from(u8::from(self.baseline_mv().is_some())),
        );
        h.set_metric("baseline_mv", self.baseline_mv().unwrap_or(0.0));
        h.set_metric("warmup_left_s", self.warmup_left_s(now_ns));
        if let Some(r) = self.last_reading() {
            let msg = to_message(r);
            h.set_metric("sensor_state", f64::from(msg.state));
            h.set_metric("trend", f64::from(msg.trend));
            h.set_metric("level", r.level);
            h.set_metric("raw_mv", r.raw_mv);
        }
    }

    /// The process's health from the sensor's and the link's state.
    pub fn health_state(&self, now_ns: u64) -> HealthState {
        let recent_error = self
            .last_error_ns
            .is_some_and(|t| now_ns.saturating_sub(t) < ERROR_MEMORY_NS);
        if !self.link_up {
            return HealthState::Error;
        }
        match self.last.map(|r| r.state) {
            None => HealthState::Starting,
            Some(SensorState::Disconnected) => HealthState::Error,
            Some(SensorState::WarmingUp | SensorState::Saturated) => HealthState::Degraded,
            Some(SensorState::Ready) if recent_error => HealthState::Degraded,
            Some(SensorState::Ready) => HealthState::Ok,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::Malformed;
    use smokenav_platform_config::SmokeSection;
    use smokenav_smoke_codec::{AdcScale, LineError, StreamError};

    const MS: u64 = 1_000_000;

    fn settings(backend: AdcBackend) -> Settings {
        let section = SmokeSection {
            backend: Some(backend),
            baseline_mv: Some(3000.0),
            ..crate::settings::test_section("/dev/smoke-adc")
        };
        Settings::new(&section, None, Some(0.0)).unwrap()
    }

    fn sample(stamp_ms: u64, counts: i64) -> LinkEvent {
        LinkEvent::Sample {
            stamp_ns: stamp_ms * MS,
            measurement: AdcScale::AVR_5V_10BIT.measure_counts(counts).unwrap(),
        }
    }

    fn connected(stamp_ms: u64) -> LinkEvent {
        LinkEvent::Connected {
            stamp_ns: stamp_ms * MS,
            device: "/dev/x".into(),
        }
    }

    #[test]
    fn board_at_50_hz_is_published_at_10_hz_with_every_sample_filtered() {
        let mut core = DriverCore::new(&settings(AdcBackend::Serial), 0).unwrap();
        core.on_event(&connected(0));
        let published = (0..500u64)
            .filter(|k| core.on_event(&sample(k * 20, 614)).is_some())
            .count();
        // 0 … 9.98 s at 100 ms spacing, both ends included.
        assert_eq!(published, 101);
        assert_eq!(core.counters().samples, 500);
        assert_eq!(core.health_state(10_000 * MS), HealthState::Ok);
    }

    #[test]
    fn lost_device_publishes_disconnected_at_once_then_at_the_rate() {
        let mut core = DriverCore::new(&settings(AdcBackend::Iio), 0).unwrap();
        core.on_event(&connected(0));
        core.on_event(&sample(0, 614));
        let lost = LinkEvent::Lost {
            stamp_ns: 50 * MS,
            reason: "gone".into(),
        };
        let r = core.on_event(&lost).unwrap();
        assert_eq!(r.state(), SmokeSensorState::Disconnected);
        assert_eq!(core.health_state(60 * MS), HealthState::Error);
        // Nothing before a period has passed, then one per 100 ms.
        assert!(core.on_idle(100 * MS).is_none());
        let idle: Vec<_> = (15..=60)
            .filter_map(|k| core.on_idle(k * 10 * MS))
            .collect();
        assert_eq!(idle.len(), 5, "150 … 600 ms at 10 Hz");
        assert!(
            idle.iter()
                .all(|r| r.state() == SmokeSensorState::Disconnected)
        );
    }

    #[test]
    fn silent_open_port_turns_disconnected_after_stale_after() {
        let mut core = DriverCore::new(&settings(AdcBackend::Serial), 0).unwrap();
        core.on_event(&connected(0));
        core.on_event(&sample(0, 614));
        assert!(
            core.on_idle(500 * MS).is_none(),
            "1 s stale_after not reached"
        );
        let r = core.on_idle(1000 * MS).unwrap();
        assert_eq!(r.state(), SmokeSensorState::Disconnected);
        assert_eq!(core.health_state(1000 * MS), HealthState::Error);
    }

    #[test]
    fn malformed_input_is_counted_and_degrades_health_for_a_while() {
        let mut core = DriverCore::new(&settings(AdcBackend::Serial), 0).unwrap();
        core.on_event(&connected(0));
        core.on_event(&sample(0, 614));
        let bad = LinkEvent::Malformed {
            stamp_ns: 100 * MS,
            error: Malformed::Serial(StreamError::Line(LineError::ChecksumMismatch {
                stated: 0,
                computed: 1,
            })),
        };
        assert!(core.on_event(&bad).is_none());
        let oor = LinkEvent::OutOfRange {
            stamp_ns: 200 * MS,
            error: AdcScale::AVR_5V_10BIT.measure_counts(4096).unwrap_err(),
        };
        assert!(core.on_event(&oor).is_none());
        core.on_event(&sample(300, 614));
        let c = core.counters();
        assert_eq!(
            (c.parse_errors, c.checksum_errors, c.out_of_range),
            (1, 1, 1)
        );
        assert_eq!(core.health_state(400 * MS), HealthState::Degraded);
        core.on_event(&sample(3300, 614));
        assert_eq!(core.health_state(3300 * MS), HealthState::Ok);
    }

    #[test]
    fn serial_replug_restarts_warmup_but_iio_reappearance_does_not() {
        for (backend, expect) in [
            (AdcBackend::Serial, SmokeSensorState::WarmingUp),
            (AdcBackend::Iio, SmokeSensorState::Ready),
        ] {
            let mut s = settings(backend);
            s.signal.warmup_s = 5.0;
            let mut core = DriverCore::new(&s, 0).unwrap();
            core.on_event(&connected(0));
            assert_eq!(
                core.on_event(&sample(6000, 614)).unwrap().state(),
                SmokeSensorState::Ready
            );
            core.on_event(&LinkEvent::Lost {
                stamp_ns: 7000 * MS,
                reason: "gone".into(),
            });
            core.on_event(&connected(8000));
            assert_eq!(
                core.on_event(&sample(8100, 614)).unwrap().state(),
                expect,
                "{backend:?}"
            );
        }
    }

    #[test]
    fn message_carries_the_chain_output_on_the_types_scale() {
        let mut core = DriverCore::new(&settings(AdcBackend::Serial), 0).unwrap();
        core.on_event(&connected(0));
        // 560 counts = 2734.4 mV, 265.6 mV below the fixed 3000 mV baseline.
        let r = core.on_event(&sample(0, 560)).unwrap();
        assert_eq!(r.raw_counts, 560);
        assert!((r.raw_mv - 2734.375).abs() < 1e-3);
        assert!((r.level - 265.625).abs() < 1e-3);
        assert_eq!(r.baseline_mv, 3000.0);
        assert_eq!(r.header.frame_id.as_str(), FRAME_ID);
        assert_eq!(r.state(), SmokeSensorState::Ready);
        assert_eq!(r.trend(), SmokeTrend::Steady);
    }
}
