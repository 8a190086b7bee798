//! Process health, published periodically on `health/<role>`.

use crate::header::Header;
use crate::text::FixedStr;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

pub const MAX_METRICS: usize = 24;
pub const METRIC_NAME_LEN: usize = 28;
pub const ROLE_LEN: usize = 16;
pub const LAST_ERROR_LEN: usize = 160;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum HealthState {
    #[default]
    Starting = 0,
    /// Working as configured.
    Ok = 1,
    /// Working, but something is off (reconnecting, rate low, sensor warming up).
    Degraded = 2,
    /// Not doing its job (device missing, repeated failures).
    Error = 3,
    /// Shutting down.
    Stopping = 4,
}

impl HealthState {
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => HealthState::Ok,
            2 => HealthState::Degraded,
            3 => HealthState::Error,
            4 => HealthState::Stopping,
            _ => HealthState::Starting,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            HealthState::Starting => "starting",
            HealthState::Ok => "ok",
            HealthState::Degraded => "degraded",
            HealthState::Error => "error",
            HealthState::Stopping => "stopping",
        }
    }
}

/// One named number: a counter, a rate, a gauge.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
pub struct Metric {
    pub name: FixedStr<METRIC_NAME_LEN>,
    pub value: f64,
    /// The value expected in normal operation (a rate's nominal Hz); NaN when none.
    pub expected: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::Health")]
pub struct Health {
    /// `stamp_ns` = when this report was made; `seq` counts reports.
    pub header: Header,
    /// The process role: `hokuyo`, `pioneer`, `scout`, `smoke`, `fusion`, `slam`, …
    pub role: FixedStr<ROLE_LEN>,
    pub pid: u32,
    /// A [`HealthState`] as `u8`.
    pub state: u8,
    pub _reserved: [u8; 3],
    /// Seconds since the process started.
    pub uptime_s: f64,
    /// Processing latency percentiles over the last reporting window, µs.
    pub latency_p50_us: f32,
    pub latency_p99_us: f32,
    pub latency_max_us: f32,
    pub _reserved2: u32,
    /// Cycles that missed their deadline since start.
    pub deadline_misses: u64,
    pub metric_count: u32,
    pub _reserved3: u32,
    pub metrics: [Metric; MAX_METRICS],
    /// The most recent error, empty when none.
    pub last_error: FixedStr<LAST_ERROR_LEN>,
}

impl Health {
    pub fn new(role: &str, pid: u32) -> Self {
        Self {
            role: FixedStr::from_str_truncate(role),
            pid,
            ..Default::default()
        }
    }

    pub fn state(&self) -> HealthState {
        HealthState::from_u8(self.state)
    }

    pub fn set_state(&mut self, s: HealthState) {
        self.state = s as u8;
    }

    pub fn metrics(&self) -> &[Metric] {
        &self.metrics[..(self.metric_count as usize).min(MAX_METRICS)]
    }

    /// Sets (or adds) a metric. Returns false if the table is full.
    pub fn set_metric(&mut self, name: &str, value: f64, expected: Option<f64>) -> bool {
        let expected = expected.unwrap_or(f64::NAN);
        let n = (self.metric_count as usize).min(MAX_METRICS);
        if let Some(m) = self.metrics[..n]
            .iter_mut()
            .find(|m| m.name.as_str() == name)
        {
            m.value = value;
            m.expected = expected;
            return true;
        }
        if n == MAX_METRICS {
            return false;
        }
        self.metrics[n] = Metric {
            name: FixedStr::from_str_truncate(name),
            value,
            expected,
        };
        self.metric_count = n as u32 + 1;
        true
    }

    pub fn metric(&self, name: &str) -> Option<f64> {
        self.metrics()
            .iter()
            .find(|m| m.name.as_str() == name)
            .map(|m| m.value)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_update_in_place_and_cap() {
        let mut h = Health::new("hokuyo", 1);
        assert!(h.set_metric("scan_hz", 10.0, Some(10.0)));
        assert!(h.set_metric("scan_hz", 9.5, Some(10.0)));
        assert_eq!(h.metrics().len(), 1);
        assert_eq!(h.metric("scan_hz"), Some(9.5));
        for i in 1..MAX_METRICS {
            assert!(h.set_metric(&format!("m{i}"), 0.0, None));
        }
        assert!(!h.set_metric("one_too_many", 0.0, None));
    }
}
