//! Laser range scans.

use crate::header::Header;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Beams a scan can hold: a UTM-30LX / UST full sweep is 1081 steps; the
/// URG-04LX's 769 fits too.
pub const MAX_BEAMS: usize = 1081;

/// `beam_error` value of a beam that carries a measured range.
pub const BEAM_OK: u16 = 0;
/// No echo came back (out of range, or the beam was backscattered into nothing).
pub const BEAM_NO_RETURN: u16 = 1;
/// The range exceeds `range_max` (e.g. a sonar reading beyond its cap).
pub const BEAM_BEYOND_MAX: u16 = 2;
/// Set on `beam_error` when the low byte holds the sensor's own error code
/// (a Hokuyo value below DMIN, e.g. 0..19 on the URG-04LX).
pub const BEAM_SENSOR_CODE: u16 = 0x100;

/// What one beam of a scan says.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BeamReading {
    /// A measured range in metres.
    Range(f32),
    /// No return.
    NoReturn,
    /// Beyond the scan's `range_max`.
    BeyondMax,
    /// The sensor reported an error code instead of a range.
    SensorCode(u16),
}

impl BeamReading {
    /// The range, if the beam measured one.
    pub fn range(self) -> Option<f32> {
        match self {
            BeamReading::Range(r) => Some(r),
            _ => None,
        }
    }

    fn encode(self) -> (f32, u16) {
        match self {
            BeamReading::Range(r) => (r, BEAM_OK),
            BeamReading::NoReturn => (f32::INFINITY, BEAM_NO_RETURN),
            BeamReading::BeyondMax => (f32::INFINITY, BEAM_BEYOND_MAX),
            BeamReading::SensorCode(c) => (f32::NAN, BEAM_SENSOR_CODE | (c & 0xff)),
        }
    }

    fn decode(range: f32, code: u16) -> Self {
        match code {
            BEAM_OK => BeamReading::Range(range),
            BEAM_BEYOND_MAX => BeamReading::BeyondMax,
            c if c & BEAM_SENSOR_CODE != 0 => BeamReading::SensorCode(c & 0xff),
            _ => BeamReading::NoReturn,
        }
    }
}

/// The longest sweep a scan's `time_increment` is believed for, s: no
/// laser this handles takes half a second over one scan.
pub const MAX_SWEEP_S: f64 = 0.5;

/// One planar laser sweep, laid out like ROS `sensor_msgs/LaserScan`.
///
/// Beam `i` points at `angle_min + i * angle_increment` in the laser frame
/// (counter-clockwise positive, 0 = straight ahead) and was measured at
/// `header.stamp_ns + i * time_increment`.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::LaserScan")]
pub struct LaserScan {
    /// Stamp of the first beam, sequence number, laser frame.
    pub header: Header,
    /// Angle of the first beam, rad.
    pub angle_min: f32,
    /// Angle between beams, rad.
    pub angle_increment: f32,
    /// Time between beams, s.
    pub time_increment: f32,
    /// Time between scans, s.
    pub scan_time: f32,
    /// Shortest range the sensor can measure, m.
    pub range_min: f32,
    /// Longest range the sensor can measure, m.
    pub range_max: f32,
    /// Number of beams in use (`<= MAX_BEAMS`).
    pub count: u32,
    /// 1 when `intensities` is filled.
    pub has_intensities: u32,
    /// Range per beam, m. Only meaningful where `beam_error[i] == BEAM_OK`.
    pub ranges: [f32; MAX_BEAMS],
    /// Reflectance per beam (sensor units), when `has_intensities == 1`.
    pub intensities: [f32; MAX_BEAMS],
    /// `BEAM_OK`, or why the beam has no range (see the `BEAM_*` constants).
    pub beam_error: [u16; MAX_BEAMS],
}

impl Default for LaserScan {
    fn default() -> Self {
        Self {
            header: Header::default(),
            angle_min: 0.0,
            angle_increment: 0.0,
            time_increment: 0.0,
            scan_time: 0.0,
            range_min: 0.0,
            range_max: 0.0,
            count: 0,
            has_intensities: 0,
            ranges: [0.0; MAX_BEAMS],
            intensities: [0.0; MAX_BEAMS],
            beam_error: [BEAM_NO_RETURN; MAX_BEAMS],
        }
    }
}

impl LaserScan {
    /// Number of beams in use, clamped to the capacity (a peer could send anything).
    pub fn len(&self) -> usize {
        (self.count as usize).min(MAX_BEAMS)
    }

    /// Whether no beam is in use.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Beam `i` as a typed reading.
    pub fn beam(&self, i: usize) -> BeamReading {
        BeamReading::decode(self.ranges[i], self.beam_error[i])
    }

    /// Writes beam `i` (range and `beam_error` together).
    pub fn set_beam(&mut self, i: usize, reading: BeamReading) {
        let (r, c) = reading.encode();
        self.ranges[i] = r;
        self.beam_error[i] = c;
    }

    /// Angle of beam `i` in the laser frame, rad.
    pub fn angle(&self, i: usize) -> f32 {
        self.angle_min + i as f32 * self.angle_increment
    }

    /// Angle of the last beam in use, rad.
    pub fn angle_max(&self) -> f32 {
        self.angle(self.len().saturating_sub(1))
    }

    /// The time between beams if it describes a sweep: finite, positive and
    /// the whole scan within [`MAX_SWEEP_S`]; `None` otherwise (a log
    /// without it, a driver's garbage), when the beams count as taken at once.
    pub fn sweep_time_increment(&self) -> Option<f64> {
        let dt = f64::from(self.time_increment);
        (dt.is_finite() && dt > 0.0 && dt * f64::from(self.count) <= MAX_SWEEP_S).then_some(dt)
    }

    /// Iterates `(angle, reading)` over the beams in use.
    pub fn beams(&self) -> impl Iterator<Item = (f32, BeamReading)> + '_ {
        (0..self.len()).map(|i| (self.angle(i), self.beam(i)))
    }

    /// Valid ranges only.
    pub fn valid_ranges(&self) -> impl Iterator<Item = f32> + '_ {
        (0..self.len()).filter_map(|i| self.beam(i).range())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn beam_error_code_is_not_a_range() {
        let mut s = LaserScan {
            count: 3,
            ..Default::default()
        };
        s.set_beam(0, BeamReading::Range(1.5));
        s.set_beam(1, BeamReading::SensorCode(7));
        s.set_beam(2, BeamReading::NoReturn);
        assert_eq!(s.beam(0), BeamReading::Range(1.5));
        assert_eq!(s.beam(1), BeamReading::SensorCode(7));
        assert_eq!(s.beam(1).range(), None);
        assert_eq!(s.valid_ranges().collect::<Vec<_>>(), vec![1.5]);
    }

    #[test]
    fn capacity_holds_urg_and_utm_sweeps() {
        const { assert!(MAX_BEAMS >= 769 && MAX_BEAMS >= 1081) };
        let s = LaserScan {
            count: 5000,
            ..Default::default()
        };
        assert_eq!(s.len(), MAX_BEAMS);
    }
}
