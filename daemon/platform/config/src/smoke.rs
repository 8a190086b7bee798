//! `[smoke]`: the MQ303A alcohol sensor on an ADC.

use crate::common::{validate_baud, validate_port};
use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AdcBackend {
    /// A microcontroller printing one sample per line on a serial port.
    Serial,
    /// A Linux IIO ADC (`/sys/bus/iio/devices/iio:deviceN`).
    Iio,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmokeSection {
    /// Serial device or IIO device directory.
    pub port: String,
    /// Chosen from `port` when absent: a path under `/sys/` means IIO.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backend: Option<AdcBackend>,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// ADC channel (`in_voltage<N>_raw` for IIO, `A<N>` on the serial link).
    #[serde(default)]
    pub channel: u8,
    /// ADC reference voltage, mV.
    #[serde(default = "default_vref")]
    pub vref_mv: f64,
    /// ADC resolution, bits (the serial board's; an IIO device's own
    /// `scan_elements` type wins, and its scale always does).
    #[serde(default = "default_bits")]
    pub adc_bits: u8,
    /// Publishing rate, Hz.
    #[serde(default = "default_rate")]
    pub rate_hz: f64,
    /// Heater warm-up: readings are marked not-ready for this long after start, s.
    #[serde(default = "default_warmup")]
    pub warmup_s: f64,
    /// Clean-air output, mV. Absent: calibrated from the first seconds after warm-up.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline_mv: Option<f64>,
    /// The MQ303A's output *falls* as concentration rises; set false for sensors wired the other way.
    #[serde(default = "default_true")]
    pub inverse: bool,
    /// Low-pass filter time constant, s.
    #[serde(default = "default_tau")]
    pub filter_tau_s: f64,
    /// Level change per second that counts as a trend, in level units per second.
    #[serde(default = "default_trend_rate")]
    pub trend_rate: f64,
    /// Hysteresis: a trend must persist this long before it is reported, s.
    #[serde(default = "default_trend_hold")]
    pub trend_hold_s: f64,
    /// Output below this means a disconnected sensor (or a broken heater), mV.
    #[serde(default = "default_disconnected")]
    pub disconnected_below_mv: f64,
    /// Output above this means the ADC is saturated, mV.
    #[serde(default = "default_saturated")]
    pub saturated_above_mv: f64,
    /// Without `baseline_mv`: the clean-air baseline is the mean output over
    /// this long right after warm-up, s (0: the first sample).
    #[serde(default = "default_baseline_window")]
    pub baseline_window_s: f64,
    /// Span of the least-squares slope fit behind the trend, s.
    #[serde(default = "default_trend_window")]
    pub trend_window_s: f64,
    /// No sample for this long means the sensor or its board is gone
    /// (reported as disconnected), s.
    #[serde(default = "default_stale_after")]
    pub stale_after_s: f64,
    /// Serial back-end: reject lines without a `*XX` checksum.
    #[serde(default)]
    pub require_checksum: bool,
}

fn default_baud() -> u32 {
    115_200
}
fn default_vref() -> f64 {
    5000.0
}
fn default_bits() -> u8 {
    10
}
fn default_rate() -> f64 {
    10.0
}
fn default_warmup() -> f64 {
    60.0
}
fn default_true() -> bool {
    true
}
fn default_tau() -> f64 {
    0.3
}
fn default_trend_rate() -> f64 {
    5.0
}
fn default_trend_hold() -> f64 {
    0.5
}
fn default_disconnected() -> f64 {
    20.0
}
fn default_saturated() -> f64 {
    4980.0
}
fn default_baseline_window() -> f64 {
    5.0
}
fn default_trend_window() -> f64 {
    2.0
}
fn default_stale_after() -> f64 {
    1.0
}

impl SmokeSection {
    pub fn backend(&self) -> AdcBackend {
        self.backend.unwrap_or(if self.port.starts_with("/sys/") {
            AdcBackend::Iio
        } else {
            AdcBackend::Serial
        })
    }
}

impl Validate for SmokeSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        validate_port(v, &format!("{key}.port"), &self.port);
        validate_baud(v, &format!("{key}.baud"), self.baud);
        v.within(&format!("{key}.vref_mv"), self.vref_mv, 100.0, 50_000.0);
        if !(6..=24).contains(&self.adc_bits) {
            v.fail(
                format!("{key}.adc_bits"),
                format!("must be 6–24, got {}", self.adc_bits),
            );
        }
        v.within(&format!("{key}.rate_hz"), self.rate_hz, 0.5, 1000.0);
        v.within(&format!("{key}.warmup_s"), self.warmup_s, 0.0, 3600.0);
        if let Some(b) = self.baseline_mv {
            v.within(&format!("{key}.baseline_mv"), b, 0.0, self.vref_mv);
        }
        v.within(&format!("{key}.filter_tau_s"), self.filter_tau_s, 0.0, 60.0);
        v.positive(&format!("{key}.trend_rate"), self.trend_rate);
        v.within(&format!("{key}.trend_hold_s"), self.trend_hold_s, 0.0, 60.0);
        v.within(
            &format!("{key}.baseline_window_s"),
            self.baseline_window_s,
            0.0,
            600.0,
        );
        v.within(
            &format!("{key}.trend_window_s"),
            self.trend_window_s,
            0.1,
            60.0,
        );
        v.within(
            &format!("{key}.stale_after_s"),
            self.stale_after_s,
            0.05,
            60.0,
        );
        if self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.stale_after_s < 1.0 / self.rate_hz
        {
            v.fail(
                format!("{key}.stale_after_s"),
                format!(
                    "must be at least one sample period (1/rate_hz = {} s), got {}",
                    1.0 / self.rate_hz,
                    self.stale_after_s
                ),
            );
        }
        v.ordered(
            &format!("{key}.disconnected_below_mv"),
            self.disconnected_below_mv,
            &format!("{key}.saturated_above_mv"),
            self.saturated_above_mv,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(extra: &str) -> SmokeSection {
        toml::from_str(&format!("port = \"/dev/smoke-adc\"\n{extra}")).unwrap()
    }

    fn issue_keys(s: &SmokeSection) -> Vec<String> {
        let mut v = Validator::default();
        s.validate("smoke", &mut v);
        v.issues.into_iter().map(|i| i.key).collect()
    }

    #[test]
    fn signal_chain_defaults_apply_when_absent() {
        let s = section("");
        assert_eq!(s.baseline_window_s, 5.0);
        assert_eq!(s.trend_window_s, 2.0);
        assert_eq!(s.stale_after_s, 1.0);
        assert!(!s.require_checksum);
        assert!(issue_keys(&s).is_empty());
    }

    #[test]
    fn stale_timeout_shorter_than_a_sample_period_is_refused() {
        // 10 Hz: a sample every 0.1 s, so 0.05 s would always be stale.
        let s = section("stale_after_s = 0.05");
        assert_eq!(issue_keys(&s), ["smoke.stale_after_s"]);
    }

    #[test]
    fn sysfs_port_selects_the_iio_backend() {
        let mut s = section("");
        assert_eq!(s.backend(), AdcBackend::Serial);
        s.port = "/sys/bus/iio/devices/iio:device0".into();
        assert_eq!(s.backend(), AdcBackend::Iio);
    }

    #[test]
    fn unknown_smoke_key_is_rejected() {
        let err =
            toml::from_str::<SmokeSection>("port = \"/dev/x\"\ntrend_windows = 1.0").unwrap_err();
        assert!(err.to_string().contains("trend_windows"), "{err}");
    }
}
