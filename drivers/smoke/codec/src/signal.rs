//! The MQ303A signal chain: millivolts in, a smoke level with trend and
//! sensor state out.
//!
//! ```text
//! Measurement (counts, mV) ──► fault check ──► low-pass ──► level ──► trend
//!                                 │               (τ)   baseline−mV  (fit + hysteresis)
//!                                 └─ disconnected / saturated / stale
//! ```
//!
//! * **Level** is on the SmokeNav paper's scale: millivolts the sensor output has
//!   moved away from its clean-air baseline, so 0 is clean air and SmokeNav
//!   v1's SMOKE_MIN / SMOKE_MAX_UP / SMOKE_MAX_DOWN are 130 / 200 / 240. The
//!   MQ303A's output is *inversely* proportional to the concentration, so by
//!   default `level = baseline − filtered` (`inverse = false` flips it for a
//!   sensor wired the other way). The level is clamped at 0; the trend uses
//!   the unclamped value so noise around clean air is not rectified into a
//!   rise.
//! * **Baseline** is either fixed by configuration or calibrated as the mean
//!   output over `window_s` right after warm-up, when the robot is expected
//!   to be in clean air.
//! * **State**: [`SensorState::WarmingUp`] from start until warm-up *and*
//!   calibration are done; a sample below `disconnected_below_mv` or above
//!   `saturated_above_mv` is [`Disconnected`](SensorState::Disconnected) /
//!   [`Saturated`](SensorState::Saturated) and is kept out of the filter,
//!   baseline and trend; no sample for `stale_after_s` is `Disconnected`.
//!
//! Pure: time comes only from the stamps passed in.

use crate::adc::Measurement;
use crate::trend::{Trend, TrendConfig, TrendDetector};

/// How the clean-air baseline is obtained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BaselineMode {
    /// Known clean-air output, mV.
    Fixed { mv: f64 },
    /// Mean output over this long after warm-up, s (0: the first sample).
    Calibrate { window_s: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SignalConfig {
    /// Output falls as concentration rises (the MQ303A).
    pub inverse: bool,
    pub baseline: BaselineMode,
    /// Low-pass time constant, s (0: no filtering).
    pub filter_tau_s: f64,
    pub trend: TrendConfig,
    /// Heater warm-up after start, s.
    pub warmup_s: f64,
    pub disconnected_below_mv: f64,
    pub saturated_above_mv: f64,
    /// No sample for this long means the sensor (or its board) is gone, s.
    pub stale_after_s: f64,
}

impl Default for SignalConfig {
    /// The `[smoke]` section's defaults.
    fn default() -> Self {
        Self {
            inverse: true,
            baseline: BaselineMode::Calibrate { window_s: 5.0 },
            filter_tau_s: 0.3,
            trend: TrendConfig::default(),
            warmup_s: 60.0,
            disconnected_below_mv: 20.0,
            saturated_above_mv: 4980.0,
            stale_after_s: 1.0,
        }
    }
}

/// A configuration the chain cannot run with.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SignalConfigError {
    #[error("{field} must be a finite number ≥ 0, got {value}")]
    NotNonNegative { field: &'static str, value: f64 },
    #[error("trend rate must be a positive number, got {0}")]
    TrendRate(f64),
    #[error("disconnected_below_mv ({below}) must be below saturated_above_mv ({above})")]
    FaultBands { below: f64, above: f64 },
}

impl SignalConfig {
    pub fn validate(&self) -> Result<(), SignalConfigError> {
        let window = match self.baseline {
            BaselineMode::Fixed { mv } => ("baseline_mv", mv),
            BaselineMode::Calibrate { window_s } => ("baseline_window_s", window_s),
        };
        for (field, value) in [
            ("filter_tau_s", self.filter_tau_s),
            ("trend_hold_s", self.trend.hold_s),
            ("trend_window_s", self.trend.window_s),
            ("warmup_s", self.warmup_s),
            ("stale_after_s", self.stale_after_s),
            window,
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SignalConfigError::NotNonNegative { field, value });
            }
        }
        if !(self.trend.rate.is_finite() && self.trend.rate > 0.0) {
            return Err(SignalConfigError::TrendRate(self.trend.rate));
        }
        // Written so NaN in either bound also fails.
        let ordered = self.disconnected_below_mv.is_finite()
            && self.saturated_above_mv.is_finite()
            && self.disconnected_below_mv < self.saturated_above_mv;
        if !ordered {
            return Err(SignalConfigError::FaultBands {
                below: self.disconnected_below_mv,
                above: self.saturated_above_mv,
            });
        }
        Ok(())
    }
}

/// Whether a reading can be trusted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SensorState {
    /// Heater warming up, or the baseline still being calibrated.
    #[default]
    WarmingUp,
    Ready,
    /// Output at the low rail, or no samples arriving.
    Disconnected,
    /// Output at the ADC's upper limit.
    Saturated,
}

/// One output of the chain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Stamp of the sample (or of the staleness check that produced it).
    pub stamp_ns: u64,
    pub raw_counts: u32,
    pub raw_mv: f64,
    /// Low-pass filtered output, mV (equals `raw_mv` right after a fault).
    pub filtered_mv: f64,
    /// Smoke level, mV from the clean-air baseline, ≥ 0. Meaningful only
    /// when `state` is `Ready`; 0 when no baseline is known or on a fault.
    pub level: f64,
    pub baseline_mv: Option<f64>,
    /// Fitted level slope, mV/s, when the trend window is full enough.
    pub slope: Option<f64>,
    pub trend: Trend,
    pub state: SensorState,
}

#[derive(Debug, Clone, Copy, Default)]
struct Calibration {
    since_ns: Option<u64>,
    sum_mv: f64,
    n: u64,
}

/// The stateful chain. Feed it with [`update`](Self::update) per sample and
/// [`poll`](Self::poll) when no sample came.
#[derive(Debug, Clone)]
pub struct SmokeProcessor {
    cfg: SignalConfig,
    start_ns: u64,
    filtered_mv: Option<f64>,
    last_sample_ns: Option<u64>,
    baseline_mv: Option<f64>,
    calibration: Calibration,
    trend: TrendDetector,
    stale: bool,
}

fn secs(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

impl SmokeProcessor {
    /// A chain whose warm-up starts at `start_ns`.
    pub fn new(cfg: SignalConfig, start_ns: u64) -> Result<Self, SignalConfigError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            start_ns,
            filtered_mv: None,
            last_sample_ns: None,
            baseline_mv: match cfg.baseline {
                BaselineMode::Fixed { mv } => Some(mv),
                BaselineMode::Calibrate { .. } => None,
            },
            calibration: Calibration::default(),
            trend: TrendDetector::new(cfg.trend),
            stale: false,
        })
    }

    pub fn config(&self) -> &SignalConfig {
        &self.cfg
    }

    pub fn baseline_mv(&self) -> Option<f64> {
        self.baseline_mv
    }

    /// Start over as if the sensor was just powered: warm-up runs again from
    /// `start_ns` (a serial board unplugged from USB also cut its heater).
    /// A calibrated baseline is kept: clean-air output belongs to the sensor
    /// and its load resistor, and recalibrating after a replug in smoke
    /// would hide the smoke. An unfinished calibration starts over.
    pub fn restart(&mut self, start_ns: u64) {
        self.start_ns = start_ns;
        self.last_sample_ns = None;
        self.stale = false;
        self.calibration = Calibration::default();
        self.reset_signal();
    }

    fn reset_signal(&mut self) {
        self.filtered_mv = None;
        self.trend.reset();
    }

    fn warming_up(&self, stamp_ns: u64) -> bool {
        secs(stamp_ns.saturating_sub(self.start_ns)) < self.cfg.warmup_s
    }

    /// Processes one sample stamped `stamp_ns` (stamps should not go back;
    /// an older one is filtered as if simultaneous with the previous).
    pub fn update(&mut self, stamp_ns: u64, m: Measurement) -> Reading {
        let dt_s = self
            .last_sample_ns
            .map_or(0.0, |last| secs(stamp_ns.saturating_sub(last)));
        self.last_sample_ns = Some(stamp_ns);
        self.stale = false;

        let fault = if m.raw_mv < self.cfg.disconnected_below_mv {
            Some(SensorState::Disconnected)
        } else if m.raw_mv > self.cfg.saturated_above_mv {
            Some(SensorState::Saturated)
        } else {
            None
        };
        if let Some(state) = fault {
            self.reset_signal();
            return Reading {
                stamp_ns,
                raw_counts: m.raw_counts,
                raw_mv: m.raw_mv,
                filtered_mv: m.raw_mv,
                level: 0.0,
                baseline_mv: self.baseline_mv,
                slope: None,
                trend: Trend::Steady,
                state,
            };
        }

        let filtered = match self.filtered_mv {
            None => m.raw_mv,
            Some(prev) if self.cfg.filter_tau_s > 0.0 => {
                let alpha = 1.0 - (-dt_s / self.cfg.filter_tau_s).exp();
                prev + alpha * (m.raw_mv - prev)
            }
            Some(_) => m.raw_mv,
        };
        self.filtered_mv = Some(filtered);

        let mut state = SensorState::Ready;
        if self.warming_up(stamp_ns) {
            state = SensorState::WarmingUp;
        } else if let (None, BaselineMode::Calibrate { window_s }) =
            (self.baseline_mv, self.cfg.baseline)
        {
            let cal = &mut self.calibration;
            let since = *cal.since_ns.get_or_insert(stamp_ns);
            cal.sum_mv += m.raw_mv;
            cal.n += 1;
            if secs(stamp_ns.saturating_sub(since)) >= window_s {
                self.baseline_mv = Some(cal.sum_mv / cal.n as f64);
            } else {
                state = SensorState::WarmingUp;
            }
        }

        // Signed so the trend sees noise around clean air unrectified.
        let signed = self.baseline_mv.map(|baseline| {
            if self.cfg.inverse {
                baseline - filtered
            } else {
                filtered - baseline
            }
        });
        let trend = match (state, signed) {
            (SensorState::Ready, Some(signed)) => self.trend.update(stamp_ns, signed),
            _ => {
                self.trend.reset();
                Trend::Steady
            }
        };
        let level = signed.map_or(0.0, |v| v.max(0.0));

        Reading {
            stamp_ns,
            raw_counts: m.raw_counts,
            raw_mv: m.raw_mv,
            filtered_mv: filtered,
            level,
            baseline_mv: self.baseline_mv,
            slope: if state == SensorState::Ready {
                self.trend.slope()
            } else {
                None
            },
            trend,
            state,
        }
    }

    /// Call when no sample arrived: once `stale_after_s` has passed since
    /// the last sample (or since start, if none ever came) it returns a
    /// `Disconnected` reading stamped `now_ns`, and keeps doing so until a
    /// sample arrives.
    pub fn poll(&mut self, now_ns: u64) -> Option<Reading> {
        let since = self.last_sample_ns.unwrap_or(self.start_ns);
        if self.stale || secs(now_ns.saturating_sub(since)) >= self.cfg.stale_after_s {
            Some(self.disconnect(now_ns))
        } else {
            None
        }
    }

    /// The caller knows the input is gone (port closed, device removed):
    /// `Disconnected` now, without waiting for `stale_after_s`.
    pub fn disconnect(&mut self, now_ns: u64) -> Reading {
        if !self.stale {
            self.stale = true;
            self.reset_signal();
        }
        Reading {
            stamp_ns: now_ns,
            raw_counts: 0,
            raw_mv: 0.0,
            filtered_mv: 0.0,
            level: 0.0,
            baseline_mv: self.baseline_mv,
            slope: None,
            trend: Trend::Steady,
            state: SensorState::Disconnected,
        }
    }

    /// Whether warm-up (not calibration) is still running at `now_ns`, and
    /// for how long, s.
    pub fn warmup_left_s(&self, now_ns: u64) -> f64 {
        (self.cfg.warmup_s - secs(now_ns.saturating_sub(self.start_ns))).max(0.0)
    }

    /// True after [`poll`](Self::poll) found the input stale, until the next
    /// sample.
    pub fn is_stale(&self) -> bool {
        self.stale
    }
}

#[cfg(test)]
mod tests;
