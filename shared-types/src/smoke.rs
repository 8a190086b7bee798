//! Smoke (alcohol/glycol vapour) sensor readings.

use crate::header::Header;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Direction the smoke level is moving, with hysteresis applied by the driver.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum SmokeTrend {
    #[default]
    /// Neither rising nor falling.
    Steady = 0,
    /// The level is rising.
    Rising = 1,
    /// The level is falling.
    Falling = 2,
}

impl SmokeTrend {
    /// The trend a `u8` field holds; unknown values read as `Steady`.
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => SmokeTrend::Rising,
            2 => SmokeTrend::Falling,
            _ => SmokeTrend::Steady,
        }
    }

    /// Its name (`steady`, `rising`, `falling`).
    pub fn as_str(self) -> &'static str {
        match self {
            SmokeTrend::Steady => "steady",
            SmokeTrend::Rising => "rising",
            SmokeTrend::Falling => "falling",
        }
    }
}

/// Whether a reading can be trusted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum SmokeSensorState {
    /// The MQ303A heater has not reached its working temperature yet.
    #[default]
    WarmingUp = 0,
    /// Warm and reading.
    Ready = 1,
    /// No signal: the ADC reads the rail or nothing arrives.
    Disconnected = 2,
    /// The reading is pinned at the ADC's other limit.
    Saturated = 3,
}

impl SmokeSensorState {
    /// The state a `u8` field holds; unknown values read as `WarmingUp`.
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => SmokeSensorState::Ready,
            2 => SmokeSensorState::Disconnected,
            3 => SmokeSensorState::Saturated,
            _ => SmokeSensorState::WarmingUp,
        }
    }

    /// Its name (`warming_up`, `ready`, `disconnected`, `saturated`).
    pub fn as_str(self) -> &'static str {
        match self {
            SmokeSensorState::WarmingUp => "warming_up",
            SmokeSensorState::Ready => "ready",
            SmokeSensorState::Disconnected => "disconnected",
            SmokeSensorState::Saturated => "saturated",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::SmokeReading")]
/// One smoke sensor reading, published on `smoke/level`.
pub struct SmokeReading {
    /// Stamp, sequence number, sensor frame.
    pub header: Header,
    /// Sensor output as read by the ADC, mV. The MQ303A's output falls as the
    /// concentration rises.
    pub raw_mv: f32,
    /// Raw ADC counts behind `raw_mv`.
    pub raw_counts: u32,
    /// Smoke concentration index derived from the filtered signal, on the
    /// SmokeNav paper's scale: mV the output moved from its clean-air baseline
    /// (for the MQ303A, the drop below it). 0 is clean air; SmokeNav v1
    /// thresholds 130/200/240; v2 treats "below 20" as clean.
    pub level: f32,
    /// Clean-air baseline the level is measured against, mV.
    pub baseline_mv: f32,
    /// A [`SmokeTrend`] as `u8`.
    pub trend: u8,
    /// A [`SmokeSensorState`] as `u8`.
    pub state: u8,
    /// Zero.
    pub _reserved: [u8; 6],
}

impl SmokeReading {
    /// The [`SmokeTrend`].
    pub fn trend(&self) -> SmokeTrend {
        SmokeTrend::from_u8(self.trend)
    }

    /// The [`SmokeSensorState`].
    pub fn state(&self) -> SmokeSensorState {
        SmokeSensorState::from_u8(self.state)
    }

    /// Whether the sensor is warm and reading.
    pub fn is_ready(&self) -> bool {
        self.state() == SmokeSensorState::Ready
    }
}
