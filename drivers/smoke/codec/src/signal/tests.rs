//! Behaviour of the signal chain on synthetic MQ303A output.
//!
//! The puff here is a deliberately small stand-in for the emulator's sensor
//! model (which cannot be a dependency of this crate): a 300 mV response
//! that follows the concentration with τ = 1.5 s on the way up and τ = 20 s
//! on the way down, on a 10-bit / 5 V ADC with ±5 mV of noise, sampled at
//! 10 Hz as in the paper.

use super::*;
use crate::adc::AdcScale;

const MS: u64 = 1_000_000;
const CLEAN_MV: f64 = 2500.0;

/// xorshift64: deterministic noise without a dependency.
struct Noise(u64);

impl Noise {
    /// Uniform in ±amp.
    fn next(&mut self, amp: f64) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * amp
    }
}

/// Sensor drop (mV below clean air) for a concentration stepping to 1
/// over `[on_s, off_s)`, integrated exactly per 100 ms step.
struct Puff {
    drop_mv: f64,
    on_s: f64,
    off_s: f64,
}

impl Puff {
    fn step(&mut self, t_s: f64) -> f64 {
        let target = if (self.on_s..self.off_s).contains(&t_s) {
            300.0
        } else {
            0.0
        };
        let tau = if target > self.drop_mv { 1.5 } else { 20.0 };
        self.drop_mv = target + (self.drop_mv - target) * (-0.1f64 / tau).exp();
        self.drop_mv
    }
}

fn adc() -> AdcScale {
    AdcScale::new(5000.0, 10).unwrap()
}

fn config() -> SignalConfig {
    SignalConfig {
        warmup_s: 5.0,
        baseline: BaselineMode::Calibrate { window_s: 2.0 },
        ..SignalConfig::default()
    }
}

/// Runs `mv_at(t)` through ADC quantisation and the chain at 10 Hz.
fn run(cfg: SignalConfig, seconds: u64, mut mv_at: impl FnMut(f64) -> f64) -> Vec<Reading> {
    let adc = adc();
    let mut p = SmokeProcessor::new(cfg, 0).unwrap();
    (0..seconds * 10)
        .map(|k| {
            let t_s = k as f64 / 10.0;
            let m = adc
                .measure_counts(i64::from(adc.mv_to_counts(mv_at(t_s))))
                .unwrap();
            p.update(k * 100 * MS, m)
        })
        .collect()
}

fn at(readings: &[Reading], t_s: f64) -> &Reading {
    &readings[(t_s * 10.0).round() as usize]
}

fn between(readings: &[Reading], from_s: f64, to_s: f64) -> &[Reading] {
    &readings[(from_s * 10.0) as usize..(to_s * 10.0) as usize]
}

/// The trends in order with repeats collapsed.
fn trend_sequence(readings: &[Reading]) -> Vec<Trend> {
    let mut seq: Vec<Trend> = readings.iter().map(|r| r.trend).collect();
    seq.dedup();
    seq
}

fn puff_run() -> Vec<Reading> {
    let mut noise = Noise(0x5EED_5EED);
    let mut puff = Puff {
        drop_mv: 0.0,
        on_s: 10.0,
        off_s: 15.0,
    };
    run(config(), 90, |t| CLEAN_MV - puff.step(t) + noise.next(5.0))
}

#[test]
fn smoke_puff_is_rising_on_the_fast_rise_and_falling_on_the_slow_recovery() {
    let r = puff_run();
    // Rise: 0 → 289 mV in 5 s; reported rising within 1.5 s of the onset.
    assert!(
        between(&r, 11.5, 15.0)
            .iter()
            .all(|x| x.trend == Trend::Rising),
        "{:?}",
        trend_sequence(between(&r, 10.0, 16.0))
    );
    // Recovery: 289 e^(−t/20); the slope is −14 mV/s at the top and crosses
    // the −2.5 mV/s exit threshold at ~50 mV, 35 s after the puff clears.
    assert!(
        between(&r, 17.0, 45.0)
            .iter()
            .all(|x| x.trend == Trend::Falling)
    );
    assert!(
        between(&r, 65.0, 90.0)
            .iter()
            .all(|x| x.trend == Trend::Steady)
    );
}

#[test]
fn smoke_puff_trend_never_flaps() {
    let r = puff_run();
    let seq = trend_sequence(&r);
    let direct = [Trend::Steady, Trend::Rising, Trend::Falling, Trend::Steady];
    let via_peak = [
        Trend::Steady,
        Trend::Rising,
        Trend::Steady,
        Trend::Falling,
        Trend::Steady,
    ];
    assert!(seq == direct || seq == via_peak, "{seq:?}");
}

#[test]
fn smoke_puff_level_reaches_the_paper_thresholds_on_its_scale() {
    let r = puff_run();
    // Clean air before the puff: below the v2 "clean" mark of 20.
    assert!(between(&r, 7.0, 10.0).iter().all(|x| x.level < 20.0));
    let peak = r.iter().map(|x| x.level).fold(0.0, f64::max);
    assert!((270.0..300.0).contains(&peak), "peak {peak}");
    // Above SMOKE_MAX_DOWN (240) at the top, back under SMOKE_MIN (130)
    // 15 + 20 ln(289/130) ≈ 31 s.
    assert!(at(&r, 15.0).level > 240.0);
    let below_min = r
        .iter()
        .skip(150)
        .position(|x| x.level < 130.0)
        .map(|i| (i + 150) as f64 / 10.0)
        .unwrap();
    assert!(
        (29.0..33.5).contains(&below_min),
        "under SMOKE_MIN at {below_min} s"
    );
}

#[test]
fn warmup_then_calibration_are_reported_as_warming_up() {
    let r = puff_run();
    // 5 s heater warm-up, then 2 s of baseline calibration.
    assert!(
        between(&r, 0.0, 7.0)
            .iter()
            .all(|x| x.state == SensorState::WarmingUp)
    );
    assert!(
        between(&r, 0.0, 5.0)
            .iter()
            .all(|x| x.baseline_mv.is_none())
    );
    assert!(r[70..].iter().all(|x| x.state == SensorState::Ready));
    let baseline = at(&r, 8.0).baseline_mv.unwrap();
    assert!((baseline - CLEAN_MV).abs() < 5.0, "baseline {baseline}");
    assert!(
        between(&r, 0.0, 7.0)
            .iter()
            .all(|x| x.trend == Trend::Steady)
    );
}

#[test]
fn fixed_baseline_is_ready_as_soon_as_warmup_ends() {
    let cfg = SignalConfig {
        warmup_s: 3.0,
        baseline: BaselineMode::Fixed { mv: 2600.0 },
        ..SignalConfig::default()
    };
    let r = run(cfg, 5, |_| 2500.0);
    assert_eq!(at(&r, 2.9).state, SensorState::WarmingUp);
    assert_eq!(at(&r, 3.0).state, SensorState::Ready);
    // 100 mV below the fixed baseline (to ADC resolution).
    assert!((at(&r, 4.0).level - 100.0).abs() < 5.0);
}

#[test]
fn zero_warmup_and_zero_window_is_ready_on_the_first_sample() {
    let cfg = SignalConfig {
        warmup_s: 0.0,
        baseline: BaselineMode::Calibrate { window_s: 0.0 },
        ..SignalConfig::default()
    };
    let r = run(cfg, 1, |_| 2500.0);
    assert_eq!(r[0].state, SensorState::Ready);
    assert_eq!(r[0].baseline_mv, Some(2500.0));
}

#[test]
fn non_inverse_sensor_counts_a_rise_as_smoke() {
    let cfg = SignalConfig {
        inverse: false,
        warmup_s: 0.0,
        baseline: BaselineMode::Fixed { mv: 1000.0 },
        ..SignalConfig::default()
    };
    let r = run(cfg, 3, |_| 1200.0);
    assert!((r[29].level - 200.0).abs() < 5.0);
    let inverse = SignalConfig {
        inverse: true,
        ..cfg
    };
    let r = run(inverse, 3, |_| 1200.0);
    assert_eq!(r[29].level, 0.0, "a rise is cleaner-than-baseline air");
}

#[test]
fn low_pass_filter_follows_a_step_with_its_time_constant() {
    let cfg = SignalConfig {
        warmup_s: 0.0,
        baseline: BaselineMode::Fixed { mv: 2500.0 },
        filter_tau_s: 1.0,
        ..SignalConfig::default()
    };
    let r = run(cfg, 5, |t| if t < 1.0 { 2500.0 } else { 2000.0 });
    // Ten 100 ms samples after the step (the one at 1.0 s counts as the
    // first) are one τ: 1 − e⁻¹ = 63 % of the drop, which the ADC quantises
    // to 2500 − 1997.1 = 502.9 mV, so 317.9 mV.
    let level = at(&r, 1.9).level;
    assert!((level - 317.9).abs() < 0.5, "level {level}");
}

#[test]
fn output_at_ground_is_disconnected_and_kept_out_of_the_filter() {
    let cfg = SignalConfig {
        warmup_s: 0.0,
        baseline: BaselineMode::Fixed { mv: 2500.0 },
        ..SignalConfig::default()
    };
    let r = run(
        cfg,
        6,
        |t| if (2.0..3.0).contains(&t) { 0.0 } else { 2500.0 },
    );
    assert!(
        between(&r, 2.0, 3.0)
            .iter()
            .all(|x| x.state == SensorState::Disconnected)
    );
    assert!(between(&r, 2.0, 3.0).iter().all(|x| x.level == 0.0));
    // Back to ready at once, with no fake trend from the 2.5 V jump.
    assert!(
        between(&r, 3.0, 6.0)
            .iter()
            .all(|x| x.state == SensorState::Ready)
    );
    assert!(
        between(&r, 3.0, 6.0)
            .iter()
            .all(|x| x.trend == Trend::Steady)
    );
    assert!(at(&r, 3.0).level < 5.0);
}

#[test]
fn output_at_full_scale_is_saturated() {
    let cfg = SignalConfig {
        warmup_s: 0.0,
        ..SignalConfig::default()
    };
    // 1023 counts = 4995 mV, above the 4980 mV default.
    let r = run(cfg, 1, |_| 5000.0);
    assert_eq!(r[0].raw_counts, 1023);
    assert_eq!(r[0].state, SensorState::Saturated);
}

#[test]
fn silence_longer_than_stale_after_reports_disconnected_until_a_sample() {
    let cfg = SignalConfig {
        warmup_s: 0.0,
        baseline: BaselineMode::Fixed { mv: 2500.0 },
        stale_after_s: 1.0,
        ..SignalConfig::default()
    };
    let adc = adc();
    let mut p = SmokeProcessor::new(cfg, 0).unwrap();
    // Nothing yet, 0.5 s after start: not stale.
    assert_eq!(p.poll(500 * MS), None);
    // Nothing ever, 1 s after start: disconnected.
    assert_eq!(
        p.poll(1000 * MS).map(|r| r.state),
        Some(SensorState::Disconnected)
    );
    let m = adc.measure_counts(512).unwrap();
    assert_eq!(p.update(1100 * MS, m).state, SensorState::Ready);
    assert!(!p.is_stale());
    assert_eq!(p.poll(2000 * MS), None);
    let r = p.poll(2100 * MS).unwrap();
    assert_eq!(
        (r.state, r.stamp_ns),
        (SensorState::Disconnected, 2100 * MS)
    );
    assert!(p.is_stale());
    assert_eq!(p.update(2200 * MS, m).state, SensorState::Ready);
}

#[test]
fn restart_repeats_warmup_but_keeps_the_calibrated_baseline() {
    let adc = adc();
    let cfg = SignalConfig {
        warmup_s: 1.0,
        baseline: BaselineMode::Calibrate { window_s: 0.0 },
        ..SignalConfig::default()
    };
    let mut p = SmokeProcessor::new(cfg, 0).unwrap();
    let m = adc.measure_counts(512).unwrap();
    assert_eq!(p.update(1000 * MS, m).state, SensorState::Ready);
    assert_eq!(p.baseline_mv(), Some(2500.0));
    p.restart(5000 * MS);
    assert_eq!(p.warmup_left_s(5500 * MS), 0.5);
    // Replugged in smoke (512 → 460 counts): warming up, then the smoke
    // shows against the old baseline instead of becoming the new one.
    let smoky = adc.measure_counts(460).unwrap();
    assert_eq!(p.update(5500 * MS, smoky).state, SensorState::WarmingUp);
    let r = p.update(6000 * MS, smoky);
    assert_eq!(r.state, SensorState::Ready);
    assert_eq!(r.baseline_mv, Some(2500.0));
    assert!((r.level - 52.0 * 4.8828125).abs() < 1e-6);
}

#[test]
fn restart_during_calibration_calibrates_afresh() {
    let adc = adc();
    let cfg = SignalConfig {
        warmup_s: 0.0,
        baseline: BaselineMode::Calibrate { window_s: 1.0 },
        ..SignalConfig::default()
    };
    let mut p = SmokeProcessor::new(cfg, 0).unwrap();
    p.update(0, adc.measure_counts(100).unwrap());
    p.restart(500 * MS);
    let m = adc.measure_counts(512).unwrap();
    assert_eq!(p.update(600 * MS, m).state, SensorState::WarmingUp);
    assert_eq!(p.update(1600 * MS, m).state, SensorState::Ready);
    assert_eq!(p.baseline_mv(), Some(2500.0));
}

#[test]
fn known_disconnect_is_reported_at_once_and_cleared_by_a_sample() {
    let cfg = SignalConfig {
        warmup_s: 0.0,
        baseline: BaselineMode::Fixed { mv: 2500.0 },
        ..SignalConfig::default()
    };
    let adc = adc();
    let mut p = SmokeProcessor::new(cfg, 0).unwrap();
    let m = adc.measure_counts(512).unwrap();
    p.update(0, m);
    let r = p.disconnect(100 * MS);
    assert_eq!((r.state, r.stamp_ns), (SensorState::Disconnected, 100 * MS));
    // Still disconnected on the next poll, well inside stale_after.
    assert_eq!(
        p.poll(200 * MS).map(|r| r.state),
        Some(SensorState::Disconnected)
    );
    assert_eq!(p.update(300 * MS, m).state, SensorState::Ready);
    assert_eq!(p.poll(400 * MS), None);
}

#[test]
fn five_minutes_of_noisy_clean_air_never_leave_steady() {
    let mut noise = Noise(42);
    // ±10 mV: two ADC counts of noise, worse than a quiet bench.
    let r = run(config(), 300, |_| CLEAN_MV + noise.next(10.0));
    assert!(r.iter().all(|x| x.trend == Trend::Steady));
    assert!(r[70..].iter().all(|x| x.level < 20.0));
}

#[test]
fn slow_drift_of_1_mv_per_second_stays_steady() {
    let r = run(config(), 60, |t| CLEAN_MV - 1.0 * t);
    assert!(r.iter().all(|x| x.trend == Trend::Steady));
}

#[test]
fn invalid_configuration_is_refused() {
    let bad_rate = SignalConfig {
        trend: TrendConfig {
            rate: 0.0,
            ..TrendConfig::default()
        },
        ..SignalConfig::default()
    };
    assert_eq!(
        SmokeProcessor::new(bad_rate, 0).err(),
        Some(SignalConfigError::TrendRate(0.0))
    );
    let bands = SignalConfig {
        disconnected_below_mv: 5000.0,
        ..SignalConfig::default()
    };
    assert!(matches!(
        SmokeProcessor::new(bands, 0).err(),
        Some(SignalConfigError::FaultBands { .. })
    ));
    let tau = SignalConfig {
        filter_tau_s: f64::NAN,
        ..SignalConfig::default()
    };
    assert!(SmokeProcessor::new(tau, 0).is_err());
}
