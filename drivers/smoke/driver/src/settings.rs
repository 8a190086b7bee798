//! What the driver runs with: the `[smoke]` section and command-line
//! overrides, turned into codec configuration.

use smokenav_platform_config::{AdcBackend, SmokeSection};
use smokenav_smoke_codec::{AdcScale, BaselineMode, ChecksumPolicy, SignalConfig, TrendConfig};
use std::path::Path;

/// Frame id of every `SmokeReading`.
pub const FRAME_ID: &str = "smoke_sensor";

#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    pub port: String,
    pub backend: AdcBackend,
    pub baud: u32,
    pub channel: u8,
    pub adc: AdcScale,
    pub rate_hz: f64,
    pub checksum: ChecksumPolicy,
    pub signal: SignalConfig,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SettingsError {
    #[error("--warmup must be a number of seconds within [0, 3600], got {0}")]
    Warmup(f64),
    #[error("[smoke] ADC: {0}")]
    Adc(#[from] smokenav_smoke_codec::AdcConfigError),
    #[error("[smoke] signal chain: {0}")]
    Signal(#[from] smokenav_smoke_codec::SignalConfigError),
}

/// The back-end for `port`: an explicit `backend` in the section wins for
/// the configured port; otherwise (and always for `--port`, which may name
/// either kind) a directory, a path under `/sys/` or one named
/// `iio:deviceN` is IIO, anything else a serial device.
pub fn choose_backend(section: &SmokeSection, port: &str, overridden: bool) -> AdcBackend {
    if !overridden && let Some(b) = section.backend {
        return b;
    }
    let path = Path::new(port);
    let iio_name = path
        .file_name()
        .is_some_and(|n| n.to_string_lossy().starts_with("iio:device"));
    if path.is_dir() || port.starts_with("/sys/") || iio_name {
        AdcBackend::Iio
    } else {
        AdcBackend::Serial
    }
}

impl Settings {
    pub fn new(
        section: &SmokeSection,
        port_override: Option<&str>,
        warmup_override: Option<f64>,
    ) -> Result<Self, SettingsError> {
        let port = port_override.unwrap_or(&section.port).to_owned();
        let backend = choose_backend(section, &port, port_override.is_some());
        let warmup_s = match warmup_override {
            Some(w) if w.is_finite() && (0.0..=3600.0).contains(&w) => w,
            Some(w) => return Err(SettingsError::Warmup(w)),
            None => section.warmup_s,
        };
        let signal = SignalConfig {
            inverse: section.inverse,
            baseline: match section.baseline_mv {
                Some(mv) => BaselineMode::Fixed { mv },
                None => BaselineMode::Calibrate {
                    window_s: section.baseline_window_s,
                },
            },
            filter_tau_s: section.filter_tau_s,
            trend: TrendConfig {
                rate: section.trend_rate,
                hold_s: section.trend_hold_s,
                window_s: section.trend_window_s,
            },
            warmup_s,
            disconnected_below_mv: section.disconnected_below_mv,
            saturated_above_mv: section.saturated_above_mv,
            stale_after_s: section.stale_after_s,
        };
        signal.validate()?;
        Ok(Self {
            port,
            backend,
            baud: section.baud,
            channel: section.channel,
            adc: AdcScale::new(section.vref_mv, section.adc_bits)?,
            rate_hz: section.rate_hz,
            checksum: if section.require_checksum {
                ChecksumPolicy::Required
            } else {
                ChecksumPolicy::Optional
            },
            signal,
        })
    }
}

/// The section with the profile defaults, for tests.
#[cfg(test)]
pub(crate) fn test_section(port: &str) -> SmokeSection {
    SmokeSection {
        port: port.into(),
        backend: None,
        baud: 115_200,
        channel: 0,
        vref_mv: 5000.0,
        adc_bits: 10,
        rate_hz: 10.0,
        warmup_s: 60.0,
        baseline_mv: None,
        inverse: true,
        filter_tau_s: 0.3,
        trend_rate: 5.0,
        trend_hold_s: 0.5,
        disconnected_below_mv: 20.0,
        saturated_above_mv: 4980.0,
        baseline_window_s: 5.0,
        trend_window_s: 2.0,
        stale_after_s: 1.0,
        require_checksum: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(port: &str) -> SmokeSection {
        test_section(port)
    }

    #[test]
    fn port_flag_may_name_an_iio_directory_anywhere() {
        let dir = tempfile::tempdir().unwrap();
        let s = section("/dev/smoke-adc");
        let port = dir.path().to_string_lossy().into_owned();
        assert_eq!(
            Settings::new(&s, None, None).unwrap().backend,
            AdcBackend::Serial
        );
        let over = Settings::new(&s, Some(&port), None).unwrap();
        assert_eq!(
            (over.backend, over.port.as_str()),
            (AdcBackend::Iio, port.as_str())
        );
        assert_eq!(
            choose_backend(&s, "/sys/bus/iio/devices/iio:device0", true),
            AdcBackend::Iio
        );
        assert_eq!(
            choose_backend(&s, "/tmp/gone/iio:device3", true),
            AdcBackend::Iio
        );
    }

    #[test]
    fn explicit_backend_wins_for_the_configured_port() {
        let mut s = section("/dev/odd-name");
        s.backend = Some(AdcBackend::Iio);
        assert_eq!(
            Settings::new(&s, None, None).unwrap().backend,
            AdcBackend::Iio
        );
    }

    #[test]
    fn warmup_flag_overrides_the_profile_and_is_checked() {
        let s = section("/dev/smoke-adc");
        assert_eq!(Settings::new(&s, None, None).unwrap().signal.warmup_s, 60.0);
        assert_eq!(
            Settings::new(&s, None, Some(0.0)).unwrap().signal.warmup_s,
            0.0
        );
        assert_eq!(
            Settings::new(&s, None, Some(-1.0)).unwrap_err(),
            SettingsError::Warmup(-1.0)
        );
    }

    #[test]
    fn fixed_baseline_and_checksum_policy_come_from_the_section() {
        let mut s = section("/dev/smoke-adc");
        s.baseline_mv = Some(3000.0);
        s.require_checksum = true;
        let st = Settings::new(&s, None, None).unwrap();
        assert_eq!(st.signal.baseline, BaselineMode::Fixed { mv: 3000.0 });
        assert_eq!(st.checksum, ChecksumPolicy::Required);
    }
}
