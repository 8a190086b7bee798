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
    /// ADC resolution, bits.
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
            v.fail(format!("{key}.adc_bits"), format!("must be 6–24, got {}", self.adc_bits));
        }
        v.within(&format!("{key}.rate_hz"), self.rate_hz, 0.5, 1000.0);
        v.within(&format!("{key}.warmup_s"), self.warmup_s, 0.0, 3600.0);
        if let Some(b) = self.baseline_mv {
            v.within(&format!("{key}.baseline_mv"), b, 0.0, self.vref_mv);
        }
        v.within(&format!("{key}.filter_tau_s"), self.filter_tau_s, 0.0, 60.0);
        v.positive(&format!("{key}.trend_rate"), self.trend_rate);
        v.within(&format!("{key}.trend_hold_s"), self.trend_hold_s, 0.0, 60.0);
        v.ordered(
            &format!("{key}.disconnected_below_mv"),
            self.disconnected_below_mv,
            &format!("{key}.saturated_above_mv"),
            self.saturated_above_mv,
        );
    }
}
