//! Process health, published periodically on `health/<role>`.

use crate::header::Header;
use crate::text::FixedStr;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Metrics one health report can hold.
pub const MAX_METRICS: usize = 48;
/// Longest metric name, bytes.
pub const METRIC_NAME_LEN: usize = 28;
/// Longest role name, bytes.
pub const ROLE_LEN: usize = 16;
/// Longest `last_error` text, bytes.
pub const LAST_ERROR_LEN: usize = 160;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
/// What a process says about itself.
pub enum HealthState {
    #[default]
    /// Starting up, not yet working.
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
    /// The state a `u8` field holds; unknown values read as `Starting`.
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => HealthState::Ok,
            2 => HealthState::Degraded,
            3 => HealthState::Error,
            4 => HealthState::Stopping,
            _ => HealthState::Starting,
        }
    }

    /// Its name (`starting`, `ok`, `degraded`, `error`, `stopping`).
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
    /// Metric name (`scan_hz`, `checksum_errors`, …).
    pub name: FixedStr<METRIC_NAME_LEN>,
    /// Its current value.
    pub value: f64,
    /// The value expected in normal operation (a rate's nominal Hz); NaN when none.
    pub expected: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::Health")]
/// A process's health report, published periodically on `health/<role>`.
pub struct Health {
    /// `stamp_ns` = when this report was made; `seq` counts reports.
    pub header: Header,
    /// The process role: `hokuyo`, `pioneer`, `scout`, `smoke`, `fusion`, `slam`, …
    pub role: FixedStr<ROLE_LEN>,
    /// Process id.
    pub pid: u32,
    /// A [`HealthState`] as `u8`.
    pub state: u8,
    /// Zero.
    pub _reserved: [u8; 3],
    /// Seconds since the process started.
    pub uptime_s: f64,
    /// Processing latency percentiles over the last reporting window, µs.
    pub latency_p50_us: f32,
    /// 99th percentile latency of the window, µs.
    pub latency_p99_us: f32,
    /// Worst latency of the window, µs.
    pub latency_max_us: f32,
    /// Zero.
    pub _reserved2: u32,
    /// Cycles that missed their deadline since start.
    pub deadline_misses: u64,
    /// Metrics in use (`<= MAX_METRICS`).
    pub metric_count: u32,
    /// Zero.
    pub _reserved3: u32,
    /// The metrics; the first `metric_count` are in use.
    pub metrics: [Metric; MAX_METRICS],
    /// The most recent error, empty when none.
    pub last_error: FixedStr<LAST_ERROR_LEN>,
}

// By hand: the standard library derives `Default` for arrays of up to 32.
impl Default for Health {
    fn default() -> Self {
        Self {
            header: Header::default(),
            role: FixedStr::default(),
            pid: 0,
            state: 0,
            _reserved: [0; 3],
            uptime_s: 0.0,
            latency_p50_us: 0.0,
            latency_p99_us: 0.0,
            latency_max_us: 0.0,
            _reserved2: 0,
            deadline_misses: 0,
            metric_count: 0,
            _reserved3: 0,
            metrics: [Metric::default(); MAX_METRICS],
            last_error: FixedStr::default(),
        }
    }
}

impl Health {
    /// An empty report for `role` (truncated to [`ROLE_LEN`] bytes) and process `pid`.
    pub fn new(role: &str, pid: u32) -> Self {
        Self {
            role: FixedStr::from_str_truncate(role),
            pid,
            ..Default::default()
        }
    }

    /// The reported [`HealthState`].
    pub fn state(&self) -> HealthState {
        HealthState::from_u8(self.state)
    }

    /// Sets the reported state.
    pub fn set_state(&mut self, s: HealthState) {
        self.state = s as u8;
    }

    /// The metrics in use.
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

    /// The value of metric `name`, if reported.
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
