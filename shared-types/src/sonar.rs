//! Sonar ring readings.

use crate::header::Header;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Sonars one ring message can hold (Pioneer: 8 or 16; Scout: 16).
pub const MAX_SONARS: usize = 32;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
/// What one sonar reading says.
pub enum SonarStatus {
    /// An echo at `range`.
    #[default]
    Valid = 0,
    /// No echo within the sonar's maximum range (or the reading is at that
    /// maximum): free space *or* a surface hit at a specular angle. Never an obstacle.
    Saturated = 1,
    /// This sonar did not fire in this cycle, or its reading is unusable.
    Invalid = 2,
}

impl SonarStatus {
    /// The status a `u8` field holds; unknown values read as `Invalid`.
    pub fn from_u8(v: u8) -> Self {
        match v {
            0 => SonarStatus::Valid,
            1 => SonarStatus::Saturated,
            _ => SonarStatus::Invalid,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
/// One transducer's reading.
pub struct SonarReading {
    /// Range to the nearest echo, m (the sonar's max range when saturated).
    pub range: f32,
    /// Index of the transducer on the ring, as numbered in the robot profile.
    pub index: u8,
    /// A [`SonarStatus`] as `u8`.
    pub status: u8,
    /// Zero.
    pub _reserved: [u8; 2],
}

impl SonarReading {
    /// A reading of transducer `index`.
    pub fn new(index: u8, range: f32, status: SonarStatus) -> Self {
        Self {
            range,
            index,
            status: status as u8,
            _reserved: [0; 2],
        }
    }

    /// The reading's [`SonarStatus`].
    pub fn status(&self) -> SonarStatus {
        SonarStatus::from_u8(self.status)
    }

    /// The range if the sonar saw an echo.
    pub fn valid_range(&self) -> Option<f32> {
        (self.status() == SonarStatus::Valid).then_some(self.range)
    }
}

/// One cycle of the sonar ring. Ranges are along each transducer's axis; its
/// pose on the robot comes from the robot profile, keyed by `index`.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::SonarRing")]
pub struct SonarRing {
    /// Stamp, sequence number, frame of the ring.
    pub header: Header,
    /// Maximum range the transducers report, m.
    pub max_range: f32,
    /// Readings in use (`<= MAX_SONARS`).
    pub count: u32,
    /// The readings; the first `count` are in use.
    pub readings: [SonarReading; MAX_SONARS],
}

impl SonarRing {
    /// Readings in use, clamped to the capacity (a peer could send anything).
    pub fn len(&self) -> usize {
        (self.count as usize).min(MAX_SONARS)
    }

    /// Whether no reading is in use.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The readings in use.
    pub fn readings(&self) -> &[SonarReading] {
        &self.readings[..self.len()]
    }

    /// Appends a reading; returns false when the ring is full.
    pub fn push(&mut self, r: SonarReading) -> bool {
        let n = self.len();
        if n >= MAX_SONARS {
            return false;
        }
        self.readings[n] = r;
        self.count = n as u32 + 1;
        true
    }

    /// The reading for transducer `index`, if present.
    pub fn by_index(&self, index: u8) -> Option<&SonarReading> {
        self.readings().iter().find(|r| r.index == index)
    }
}
