//! The messages as ordinary owned Rust values with serde support.
//!
//! This is the JSON-lines form `smokenav topic echo --json` prints (one
//! [`TopicRecord`] per line) and offline tools such as `smokenav fuse` read.
//! Each bus type has a record type and a [`JsonForm`] impl; the catalog
//! ([`crate::catalog`]) ties them to the tagged enum [`Message`].
//!
//! Reading a record back gives the message that was written, field for
//! field: unused capacity and reserved fields come back as their defaults
//! (what `publish_with` gives every publisher), and a beam without a range
//! gets the range its reason implies (NaN for a sensor error code, +∞
//! otherwise), as [`LaserScan::set_beam`] writes it.
//!
//! Floats: JSON has no NaN or infinity, so those are the strings `"NaN"`,
//! `"Infinity"` and `"-Infinity"` (see [`float`]); a `null` float reads as
//! NaN. Beams without a range are `null` in `ranges`, with the reason in
//! `beam_error`.

pub mod float;

use crate::ConversionError;
use crate::fused::{FusedScan, FusionMethod, SectionDecision, SectionSource, SyncState};
use crate::header::Header;
use crate::health::{Health, HealthState, MAX_METRICS};
use crate::laser::{BEAM_NO_RETURN, BEAM_OK, BEAM_SENSOR_CODE, LaserScan, MAX_BEAMS};
use crate::odom::{Odometry, VelocityCommand};
use crate::slam::{MapInfo, PoseEstimate};
use crate::smoke::{SmokeReading, SmokeSensorState, SmokeTrend};
use crate::sonar::{MAX_SONARS, SonarReading, SonarRing, SonarStatus};
use crate::text::FixedStr;
use crate::voxels::{MAX_VOXELS, VoxelCloud};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// One line of `topic echo --json`: the topic and the message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TopicRecord {
    /// Bus topic the message was received on.
    pub topic: String,
    /// The message, tagged with its type (`"type": "LaserScan"`).
    #[serde(flatten)]
    pub message: Message,
}

/// A bus message type's JSON form.
pub trait JsonForm: Sized {
    /// The owned record serde reads and writes.
    type Record: Serialize + DeserializeOwned + Clone + PartialEq + core::fmt::Debug;
    /// The record of `self`.
    fn to_record(&self) -> Self::Record;
    /// Overwrites every field of `out` from `record` (no large temporary:
    /// `out` may be a reused buffer).
    fn write_record(record: &Self::Record, out: &mut Self) -> Result<(), ConversionError>;
}

macro_rules! json_enum {
    (
        fixed {
            $(
                $kind:ident {
                    doc: $doc:literal,
                    rust: $ty:ty,
                    header: [$($h:ident).+],
                    owned: $owned:ty,
                    json: $json:ty,
                    topics: [$($tconst:ident = $topic:literal),*],
                    family: [$($fconst:ident = $prefix:literal),*],
                    ros2: $ros2:literal,
                    companion: $companion:expr,
                    latched: $latched:literal $(,)?
                }
            )*
        }
        map {
            $mkind:ident {
                name: $mname:ident,
                doc: $mdoc:literal,
                info: $mty:ty,
                cell: $cell:ty,
                json: $mjson:ty,
                topics: [$($mtconst:ident = $mtopic:literal),*],
                ros2: $mros2:literal,
                companion: $mcompanion:expr,
                latched: $mlatched:literal $(,)?
            }
        }
    ) => {
        /// A message in its JSON form, tagged with its type name
        /// (`"type": "LaserScan"`; the map's is `"MapInfo"`).
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(tag = "type")]
        pub enum Message {
            $(#[doc = $doc] $kind($json),)*
            #[doc = $mdoc]
            $mname($mjson),
        }

        impl Message {
            /// The message's header.
            pub fn header(&self) -> &HeaderRecord {
                match self {
                    $(Message::$kind(m) => &m.$($h).+,)*
                    Message::$mname(m) => &m.header,
                }
            }

            /// The message's type.
            pub fn kind(&self) -> crate::catalog::MessageKind {
                match self {
                    $(Message::$kind(_) => crate::catalog::MessageKind::$kind,)*
                    Message::$mname(_) => crate::catalog::MessageKind::$mkind,
                }
            }
        }
    };
}

crate::for_each_message!(json_enum);

/// [`Header`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct HeaderRecord {
    /// When the data was measured, ns of the host `CLOCK_MONOTONIC`.
    pub stamp_ns: u64,
    /// Per-publisher sequence number.
    pub seq: u64,
    /// Coordinate frame of the data.
    pub frame_id: String,
}

impl From<&Header> for HeaderRecord {
    fn from(h: &Header) -> Self {
        Self {
            stamp_ns: h.stamp_ns,
            seq: h.seq,
            frame_id: h.frame_id.as_str().to_owned(),
        }
    }
}

impl From<&HeaderRecord> for Header {
    fn from(h: &HeaderRecord) -> Self {
        Header::new(h.stamp_ns, h.seq, &h.frame_id)
    }
}

/// [`LaserScan`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LaserScanRecord {
    /// Stamp of the first beam, sequence number, laser frame.
    pub header: HeaderRecord,
    /// Angle of the first beam, rad.
    #[serde(with = "float")]
    pub angle_min: f32,
    /// Angle between beams, rad.
    #[serde(with = "float")]
    pub angle_increment: f32,
    /// Time between beams, s.
    #[serde(with = "float")]
    pub time_increment: f32,
    /// Time between scans, s.
    #[serde(with = "float")]
    pub scan_time: f32,
    /// Shortest measurable range, m.
    #[serde(with = "float")]
    pub range_min: f32,
    /// Longest measurable range, m.
    #[serde(with = "float")]
    pub range_max: f32,
    /// Range per beam, m; `null` where the beam has no range.
    #[serde(with = "float::vec_option")]
    pub ranges: Vec<Option<f32>>,
    /// Per beam: 0 = range, 1 = no return, 2 = beyond max, 256 + code = sensor error code.
    pub beam_error: Vec<u16>,
    /// Reflectance per beam, when the sensor reports it.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        with = "float::option_vec"
    )]
    pub intensities: Option<Vec<f32>>,
}

impl From<&LaserScan> for LaserScanRecord {
    fn from(s: &LaserScan) -> Self {
        let n = s.len();
        Self {
            header: (&s.header).into(),
            angle_min: s.angle_min,
            angle_increment: s.angle_increment,
            time_increment: s.time_increment,
            scan_time: s.scan_time,
            range_min: s.range_min,
            range_max: s.range_max,
            ranges: (0..n).map(|i| s.beam(i).range()).collect(),
            beam_error: s.beam_error[..n].to_vec(),
            intensities: (s.has_intensities != 0).then(|| s.intensities[..n].to_vec()),
        }
    }
}

/// The range a beam without one holds, as [`LaserScan::set_beam`] writes it.
fn no_range(code: u16) -> f32 {
    if code & BEAM_SENSOR_CODE != 0 {
        f32::NAN
    } else {
        f32::INFINITY
    }
}

impl LaserScanRecord {
    /// Writes this record into an existing scan (no 10 kB temporary on the
    /// stack). Every field is overwritten; beams past the record's are reset.
    pub fn write_into(&self, s: &mut LaserScan) -> Result<(), ConversionError> {
        let n = self.ranges.len();
        if n > MAX_BEAMS {
            return Err(ConversionError::TooLong {
                field: "ranges",
                len: n,
                capacity: MAX_BEAMS,
            });
        }
        if self.beam_error.len() != n {
            return Err(ConversionError::LengthMismatch {
                field: "beam_error",
                len: self.beam_error.len(),
                expected: n,
            });
        }
        if let Some(i) = &self.intensities
            && i.len() != n
        {
            return Err(ConversionError::LengthMismatch {
                field: "intensities",
                len: i.len(),
                expected: n,
            });
        }
        s.header = (&self.header).into();
        s.angle_min = self.angle_min;
        s.angle_increment = self.angle_increment;
        s.time_increment = self.time_increment;
        s.scan_time = self.scan_time;
        s.range_min = self.range_min;
        s.range_max = self.range_max;
        s.count = n as u32;
        for i in 0..n {
            let code = self.beam_error[i];
            s.beam_error[i] = code;
            s.ranges[i] = match (code, self.ranges[i]) {
                (BEAM_OK, Some(r)) => r,
                (BEAM_OK, None) => {
                    // A valid beam without a range is inconsistent; treat as no return.
                    s.beam_error[i] = BEAM_NO_RETURN;
                    f32::INFINITY
                }
                (code, _) => no_range(code),
            };
        }
        s.ranges[n..].fill(0.0);
        s.beam_error[n..].fill(BEAM_NO_RETURN);
        s.has_intensities = self.intensities.is_some() as u32;
        match &self.intensities {
            Some(int) => {
                s.intensities[..n].copy_from_slice(int);
                s.intensities[n..].fill(0.0);
            }
            None => s.intensities.fill(0.0),
        }
        Ok(())
    }
}

impl TryFrom<&LaserScanRecord> for LaserScan {
    type Error = ConversionError;
    fn try_from(r: &LaserScanRecord) -> Result<Self, Self::Error> {
        let mut s = LaserScan::default();
        r.write_into(&mut s)?;
        Ok(s)
    }
}

impl JsonForm for LaserScan {
    type Record = LaserScanRecord;
    fn to_record(&self) -> LaserScanRecord {
        self.into()
    }
    fn write_record(r: &LaserScanRecord, out: &mut Self) -> Result<(), ConversionError> {
        r.write_into(out)
    }
}

/// One [`SonarReading`] as JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SonarReadingRecord {
    /// Transducer index, as numbered in the robot profile.
    pub index: u8,
    /// Range to the nearest echo, m.
    #[serde(with = "float")]
    pub range: f32,
    /// `valid`, `saturated` or `invalid`.
    pub status: String,
}

/// [`SonarRing`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SonarRingRecord {
    /// Stamp, sequence number, frame.
    pub header: HeaderRecord,
    /// Maximum range the transducers report, m.
    #[serde(with = "float")]
    pub max_range: f32,
    /// The readings in use.
    pub readings: Vec<SonarReadingRecord>,
}

fn sonar_status_str(s: SonarStatus) -> &'static str {
    match s {
        SonarStatus::Valid => "valid",
        SonarStatus::Saturated => "saturated",
        SonarStatus::Invalid => "invalid",
    }
}

impl From<&SonarRing> for SonarRingRecord {
    fn from(r: &SonarRing) -> Self {
        Self {
            header: (&r.header).into(),
            max_range: r.max_range,
            readings: r
                .readings()
                .iter()
                .map(|s| SonarReadingRecord {
                    index: s.index,
                    range: s.range,
                    status: sonar_status_str(s.status()).to_owned(),
                })
                .collect(),
        }
    }
}

impl TryFrom<&SonarRingRecord> for SonarRing {
    type Error = ConversionError;
    fn try_from(r: &SonarRingRecord) -> Result<Self, Self::Error> {
        if r.readings.len() > MAX_SONARS {
            return Err(ConversionError::TooLong {
                field: "readings",
                len: r.readings.len(),
                capacity: MAX_SONARS,
            });
        }
        let mut ring = SonarRing {
            header: (&r.header).into(),
            max_range: r.max_range,
            ..Default::default()
        };
        for s in &r.readings {
            let status = match s.status.as_str() {
                "valid" => SonarStatus::Valid,
                "saturated" => SonarStatus::Saturated,
                "invalid" => SonarStatus::Invalid,
                other => {
                    return Err(ConversionError::UnknownValue {
                        field: "status",
                        value: other.to_owned(),
                    });
                }
            };
            ring.push(SonarReading::new(s.index, s.range, status));
        }
        Ok(ring)
    }
}

impl JsonForm for SonarRing {
    type Record = SonarRingRecord;
    fn to_record(&self) -> SonarRingRecord {
        self.into()
    }
    fn write_record(r: &SonarRingRecord, out: &mut Self) -> Result<(), ConversionError> {
        *out = r.try_into()?;
        Ok(())
    }
}

/// [`Odometry`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct OdometryRecord {
    /// Stamp, sequence number, odometry frame.
    pub header: HeaderRecord,
    /// Position in the odometry frame, m.
    #[serde(with = "float")]
    pub x: f64,
    /// Position in the odometry frame, m.
    #[serde(with = "float")]
    pub y: f64,
    /// Heading, rad.
    #[serde(with = "float")]
    pub theta: f64,
    /// Forward velocity, m/s.
    #[serde(with = "float")]
    pub linear: f64,
    /// Turn rate, rad/s.
    #[serde(with = "float")]
    pub angular: f64,
    /// [`crate::OdometryFlags`] bits.
    pub flags: u32,
    /// Pressed bumper segments, one bit each.
    pub bumpers: u32,
    /// Battery voltage, V.
    #[serde(with = "float")]
    pub battery_v: f32,
}

impl From<&Odometry> for OdometryRecord {
    fn from(o: &Odometry) -> Self {
        Self {
            header: (&o.header).into(),
            x: o.x,
            y: o.y,
            theta: o.theta,
            linear: o.linear,
            angular: o.angular,
            flags: o.flags,
            bumpers: o.bumpers,
            battery_v: o.battery_v,
        }
    }
}

impl From<&OdometryRecord> for Odometry {
    fn from(o: &OdometryRecord) -> Self {
        Odometry {
            header: (&o.header).into(),
            x: o.x,
            y: o.y,
            theta: o.theta,
            linear: o.linear,
            angular: o.angular,
            flags: o.flags,
            bumpers: o.bumpers,
            battery_v: o.battery_v,
            _reserved: 0,
        }
    }
}

impl JsonForm for Odometry {
    type Record = OdometryRecord;
    fn to_record(&self) -> OdometryRecord {
        self.into()
    }
    fn write_record(r: &OdometryRecord, out: &mut Self) -> Result<(), ConversionError> {
        *out = r.into();
        Ok(())
    }
}

/// [`SimClock`](crate::SimClock) as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SimClockRecord {
    /// The simulated time, sequence number.
    pub header: HeaderRecord,
}

impl JsonForm for crate::sim_clock::SimClock {
    type Record = SimClockRecord;
    fn to_record(&self) -> SimClockRecord {
        SimClockRecord {
            header: (&self.header).into(),
        }
    }
    fn write_record(r: &SimClockRecord, out: &mut Self) -> Result<(), ConversionError> {
        out.header = (&r.header).into();
        Ok(())
    }
}

/// [`VelocityCommand`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct VelocityCommandRecord {
    /// Stamp, sequence number, frame.
    pub header: HeaderRecord,
    /// Forward velocity, m/s.
    #[serde(with = "float")]
    pub linear: f64,
    /// Turn rate, rad/s.
    #[serde(with = "float")]
    pub angular: f64,
}

impl From<&VelocityCommand> for VelocityCommandRecord {
    fn from(c: &VelocityCommand) -> Self {
        Self {
            header: (&c.header).into(),
            linear: c.linear,
            angular: c.angular,
        }
    }
}

impl From<&VelocityCommandRecord> for VelocityCommand {
    fn from(c: &VelocityCommandRecord) -> Self {
        VelocityCommand {
            header: (&c.header).into(),
            linear: c.linear,
            angular: c.angular,
        }
    }
}

impl JsonForm for VelocityCommand {
    type Record = VelocityCommandRecord;
    fn to_record(&self) -> VelocityCommandRecord {
        self.into()
    }
    fn write_record(r: &VelocityCommandRecord, out: &mut Self) -> Result<(), ConversionError> {
        *out = r.into();
        Ok(())
    }
}

/// [`SmokeReading`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SmokeReadingRecord {
    /// Stamp, sequence number, frame.
    pub header: HeaderRecord,
    /// Sensor output as read by the ADC, mV.
    #[serde(with = "float")]
    pub raw_mv: f32,
    /// Raw ADC counts.
    pub raw_counts: u32,
    /// Smoke concentration index (mV below the clean-air baseline).
    #[serde(with = "float")]
    pub level: f32,
    /// Clean-air baseline, mV.
    #[serde(with = "float")]
    pub baseline_mv: f32,
    /// `steady`, `rising` or `falling`.
    pub trend: String,
    /// `warming_up`, `ready`, `disconnected` or `saturated`.
    pub state: String,
}

impl From<&SmokeReading> for SmokeReadingRecord {
    fn from(s: &SmokeReading) -> Self {
        Self {
            header: (&s.header).into(),
            raw_mv: s.raw_mv,
            raw_counts: s.raw_counts,
            level: s.level,
            baseline_mv: s.baseline_mv,
            trend: s.trend().as_str().to_owned(),
            state: s.state().as_str().to_owned(),
        }
    }
}

impl TryFrom<&SmokeReadingRecord> for SmokeReading {
    type Error = ConversionError;
    fn try_from(s: &SmokeReadingRecord) -> Result<Self, Self::Error> {
        let trend = match s.trend.as_str() {
            "steady" => SmokeTrend::Steady,
            "rising" => SmokeTrend::Rising,
            "falling" => SmokeTrend::Falling,
            other => {
                return Err(ConversionError::UnknownValue {
                    field: "trend",
                    value: other.to_owned(),
                });
            }
        };
        let state = match s.state.as_str() {
            "warming_up" => SmokeSensorState::WarmingUp,
            "ready" => SmokeSensorState::Ready,
            "disconnected" => SmokeSensorState::Disconnected,
            "saturated" => SmokeSensorState::Saturated,
            other => {
                return Err(ConversionError::UnknownValue {
                    field: "state",
                    value: other.to_owned(),
                });
            }
        };
        Ok(SmokeReading {
            header: (&s.header).into(),
            raw_mv: s.raw_mv,
            raw_counts: s.raw_counts,
            level: s.level,
            baseline_mv: s.baseline_mv,
            trend: trend as u8,
            state: state as u8,
            _reserved: [0; 6],
        })
    }
}

impl JsonForm for SmokeReading {
    type Record = SmokeReadingRecord;
    fn to_record(&self) -> SmokeReadingRecord {
        self.into()
    }
    fn write_record(r: &SmokeReadingRecord, out: &mut Self) -> Result<(), ConversionError> {
        *out = r.try_into()?;
        Ok(())
    }
}

/// One [`SectionDecision`] as JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SectionRecord {
    /// First beam of the section.
    pub first_beam: u16,
    /// One past its last beam.
    pub end_beam: u16,
    /// The sonar that defines it.
    pub sonar_index: u8,
    /// `laser`, `sonar`, `both` or `neither`.
    pub source: String,
    /// Trust in the sonar, ρS.
    #[serde(with = "float")]
    pub rho_sonar: f32,
    /// Trust in the laser, ρL.
    #[serde(with = "float")]
    pub rho_laser: f32,
    /// The sonar range used or rejected, m.
    #[serde(with = "float")]
    pub sonar_range: f32,
}

/// [`FusedScan`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct FusedScanRecord {
    /// The combined scan.
    pub scan: LaserScanRecord,
    /// Per beam: 0 laser, 1 sonar, 2 both, 3 neither.
    pub beam_source: Vec<u8>,
    /// `laser-only`, `v1` or `v2`.
    pub method: String,
    /// `complete`, `laser-only` or `sonar-only`.
    pub sync_state: String,
    /// The per-section decisions.
    pub sections: Vec<SectionRecord>,
    /// Smoke level the decision used.
    #[serde(with = "float")]
    pub smoke_level: f32,
    /// Standard deviation of the valid laser ranges, m.
    #[serde(with = "float")]
    pub laser_spread: f32,
    /// Stamp of the fused sonar ring, ns (0 when absent).
    pub sonar_stamp_ns: u64,
    /// Stamp of the fused smoke reading, ns (0 when absent).
    pub smoke_stamp_ns: u64,
    /// Share of sections that used the sonar (derived; ignored when read back).
    #[serde(with = "float")]
    pub sonar_usage: f32,
}

impl From<&FusedScan> for FusedScanRecord {
    fn from(f: &FusedScan) -> Self {
        let n = f.scan.len();
        Self {
            scan: (&f.scan).into(),
            beam_source: f.beam_source[..n].to_vec(),
            method: f.method().as_str().to_owned(),
            sync_state: f.sync_state().as_str().to_owned(),
            sections: f
                .sections()
                .iter()
                .map(|d| SectionRecord {
                    first_beam: d.first_beam,
                    end_beam: d.end_beam,
                    sonar_index: d.sonar_index,
                    source: d.source().as_str().to_owned(),
                    rho_sonar: d.rho_sonar,
                    rho_laser: d.rho_laser,
                    sonar_range: d.sonar_range,
                })
                .collect(),
            smoke_level: f.smoke_level,
            laser_spread: f.laser_spread,
            sonar_stamp_ns: f.sonar_stamp_ns,
            smoke_stamp_ns: f.smoke_stamp_ns,
            sonar_usage: f.sonar_usage(),
        }
    }
}

impl FusedScanRecord {
    /// Writes this record into an existing fused scan. Every field is
    /// overwritten; beams and sections past the record's are reset.
    pub fn write_into(&self, f: &mut FusedScan) -> Result<(), ConversionError> {
        let n = self.scan.ranges.len();
        if self.beam_source.len() != n {
            return Err(ConversionError::LengthMismatch {
                field: "beam_source",
                len: self.beam_source.len(),
                expected: n,
            });
        }
        if self.sections.len() > MAX_SONARS {
            return Err(ConversionError::TooLong {
                field: "sections",
                len: self.sections.len(),
                capacity: MAX_SONARS,
            });
        }
        let method =
            FusionMethod::parse(&self.method).ok_or_else(|| ConversionError::UnknownValue {
                field: "method",
                value: self.method.clone(),
            })?;
        let sync_state = match self.sync_state.as_str() {
            "complete" => SyncState::Complete,
            "laser-only" => SyncState::LaserOnly,
            "sonar-only" => SyncState::SonarOnly,
            "no-smoke" => SyncState::NoSmoke,
            other => {
                return Err(ConversionError::UnknownValue {
                    field: "sync_state",
                    value: other.to_owned(),
                });
            }
        };
        self.scan.write_into(&mut f.scan)?;
        f.beam_source[..n].copy_from_slice(&self.beam_source);
        f.beam_source[n..].fill(0);
        f.method = method as u8;
        f.sync_state = sync_state as u8;
        f._reserved = [0; 2];
        f.section_count = self.sections.len() as u32;
        f.sections.fill(SectionDecision::default());
        for (d, r) in f.sections.iter_mut().zip(&self.sections) {
            *d = SectionDecision {
                first_beam: r.first_beam,
                end_beam: r.end_beam,
                sonar_index: r.sonar_index,
                source: SectionSource::parse(&r.source).ok_or_else(|| {
                    ConversionError::UnknownValue {
                        field: "source",
                        value: r.source.clone(),
                    }
                })? as u8,
                _reserved: [0; 2],
                rho_sonar: r.rho_sonar,
                rho_laser: r.rho_laser,
                sonar_range: r.sonar_range,
            };
        }
        f.smoke_level = self.smoke_level;
        f.laser_spread = self.laser_spread;
        f.sonar_stamp_ns = self.sonar_stamp_ns;
        f.smoke_stamp_ns = self.smoke_stamp_ns;
        Ok(())
    }
}

impl JsonForm for FusedScan {
    type Record = FusedScanRecord;
    fn to_record(&self) -> FusedScanRecord {
        self.into()
    }
    fn write_record(r: &FusedScanRecord, out: &mut Self) -> Result<(), ConversionError> {
        r.write_into(out)
    }
}

/// [`PoseEstimate`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseEstimateRecord {
    /// Stamp of the scan the pose belongs to, sequence number, map frame.
    pub header: HeaderRecord,
    /// Position in the map frame, m.
    #[serde(with = "float")]
    pub x: f64,
    /// Position in the map frame, m.
    #[serde(with = "float")]
    pub y: f64,
    /// Heading, rad.
    #[serde(with = "float")]
    pub theta: f64,
    /// Row-major 3×3 covariance of (x, y, θ).
    #[serde(with = "float::array")]
    pub covariance: [f64; 9],
    /// Effective sample size of the particle weights.
    #[serde(with = "float")]
    pub n_eff: f32,
    /// Particles in the filter.
    pub particles: u32,
    /// Scans skipped so far.
    pub scans_skipped: u64,
    /// Processing time of this scan, µs.
    pub processing_us: u32,
}

impl From<&PoseEstimate> for PoseEstimateRecord {
    fn from(p: &PoseEstimate) -> Self {
        Self {
            header: (&p.header).into(),
            x: p.x,
            y: p.y,
            theta: p.theta,
            covariance: p.covariance,
            n_eff: p.n_eff,
            particles: p.particles,
            scans_skipped: p.scans_skipped,
            processing_us: p.processing_us,
        }
    }
}

impl From<&PoseEstimateRecord> for PoseEstimate {
    fn from(p: &PoseEstimateRecord) -> Self {
        PoseEstimate {
            header: (&p.header).into(),
            x: p.x,
            y: p.y,
            theta: p.theta,
            covariance: p.covariance,
            n_eff: p.n_eff,
            particles: p.particles,
            scans_skipped: p.scans_skipped,
            processing_us: p.processing_us,
            _reserved: 0,
        }
    }
}

impl JsonForm for PoseEstimate {
    type Record = PoseEstimateRecord;
    fn to_record(&self) -> PoseEstimateRecord {
        self.into()
    }
    fn write_record(r: &PoseEstimateRecord, out: &mut Self) -> Result<(), ConversionError> {
        *out = r.into();
        Ok(())
    }
}

/// [`VoxelCloud`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct VoxelCloudRecord {
    /// Stamp, sequence number, map frame.
    pub header: HeaderRecord,
    /// Voxel side, m.
    #[serde(with = "float")]
    pub resolution: f32,
    /// Occupied voxels left out because the message was full.
    pub truncated: u32,
    /// Voxel centres, `x, y, z` after one another, m.
    #[serde(with = "float::vec")]
    pub xyz: Vec<f32>,
}

impl JsonForm for VoxelCloud {
    type Record = VoxelCloudRecord;
    fn to_record(&self) -> VoxelCloudRecord {
        VoxelCloudRecord {
            header: (&self.header).into(),
            resolution: self.resolution,
            truncated: self.truncated,
            xyz: self.points().iter().flatten().copied().collect(),
        }
    }
    fn write_record(r: &VoxelCloudRecord, out: &mut Self) -> Result<(), ConversionError> {
        if !r.xyz.len().is_multiple_of(3) {
            return Err(ConversionError::LengthMismatch {
                field: "xyz",
                len: r.xyz.len(),
                expected: r.xyz.len() / 3 * 3,
            });
        }
        let n = r.xyz.len() / 3;
        if n > MAX_VOXELS {
            return Err(ConversionError::TooLong {
                field: "xyz",
                len: n,
                capacity: MAX_VOXELS,
            });
        }
        out.header = (&r.header).into();
        out.resolution = r.resolution;
        out.truncated = r.truncated;
        out._reserved = 0;
        out.count = n as u32;
        for (p, c) in out.points.iter_mut().zip(r.xyz.chunks_exact(3)) {
            *p = [c[0], c[1], c[2]];
        }
        out.points[n..].fill([0.0; 3]);
        Ok(())
    }
}

/// The occupancy grid ([`MapInfo`] and, optionally, its cells) as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MapInfoRecord {
    /// Stamp, sequence number, map frame.
    pub header: HeaderRecord,
    /// Cell edge, m.
    #[serde(with = "float")]
    pub resolution: f32,
    /// Cells per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Lower-left corner of cell (0, 0) in the map frame, m.
    #[serde(with = "float")]
    pub origin_x: f64,
    /// Lower-left corner of cell (0, 0) in the map frame, m.
    #[serde(with = "float")]
    pub origin_y: f64,
    /// Heading of the grid in the map frame, rad.
    #[serde(with = "float")]
    pub origin_theta: f64,
    /// Cells, row-major from the lower-left corner (-1 unknown, 0..100). Omitted by `echo` unless asked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data: Option<Vec<i8>>,
}

impl From<&MapInfo> for MapInfoRecord {
    fn from(m: &MapInfo) -> Self {
        Self::from_map(m, None)
    }
}

impl MapInfoRecord {
    /// The record of a map, with its cells when given.
    pub fn from_map(m: &MapInfo, cells: Option<&[i8]>) -> Self {
        Self {
            header: (&m.header).into(),
            resolution: m.resolution,
            width: m.width,
            height: m.height,
            origin_x: m.origin_x,
            origin_y: m.origin_y,
            origin_theta: m.origin_theta,
            data: cells.map(<[i8]>::to_vec),
        }
    }

    /// The map this record holds: its info and exactly `width × height` cells.
    pub fn to_map(&self) -> Result<(MapInfo, Vec<i8>), ConversionError> {
        let info = MapInfo {
            header: (&self.header).into(),
            resolution: self.resolution,
            width: self.width,
            height: self.height,
            _reserved: 0,
            origin_x: self.origin_x,
            origin_y: self.origin_y,
            origin_theta: self.origin_theta,
        };
        let cells = self.data.clone().unwrap_or_default();
        if cells.len() != info.cell_count() {
            return Err(ConversionError::LengthMismatch {
                field: "data",
                len: cells.len(),
                expected: info.cell_count(),
            });
        }
        Ok((info, cells))
    }
}

/// One health [`crate::Metric`] as JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricRecord {
    /// Metric name.
    pub name: String,
    /// Its value.
    #[serde(with = "float")]
    pub value: f64,
    /// The value expected in normal operation; absent when there is none.
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        with = "float::option"
    )]
    pub expected: Option<f64>,
}

/// [`Health`] as JSON.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct HealthRecord {
    /// When the report was made; `seq` counts reports.
    pub header: HeaderRecord,
    /// The process role.
    pub role: String,
    /// Process id.
    pub pid: u32,
    /// `starting`, `ok`, `degraded`, `error` or `stopping`.
    pub state: String,
    /// Seconds since the process started.
    #[serde(with = "float")]
    pub uptime_s: f64,
    /// Median processing latency of the last window, µs.
    #[serde(with = "float")]
    pub latency_p50_us: f32,
    /// 99th percentile processing latency, µs.
    #[serde(with = "float")]
    pub latency_p99_us: f32,
    /// Worst processing latency, µs.
    #[serde(with = "float")]
    pub latency_max_us: f32,
    /// Cycles that missed their deadline since start.
    pub deadline_misses: u64,
    /// Named counters, rates and gauges.
    pub metrics: Vec<MetricRecord>,
    /// The most recent error, empty when none.
    pub last_error: String,
}

impl From<&Health> for HealthRecord {
    fn from(h: &Health) -> Self {
        Self {
            header: (&h.header).into(),
            role: h.role.as_str().to_owned(),
            pid: h.pid,
            state: h.state().as_str().to_owned(),
            uptime_s: h.uptime_s,
            latency_p50_us: h.latency_p50_us,
            latency_p99_us: h.latency_p99_us,
            latency_max_us: h.latency_max_us,
            deadline_misses: h.deadline_misses,
            metrics: h
                .metrics()
                .iter()
                .map(|m| MetricRecord {
                    name: m.name.as_str().to_owned(),
                    value: m.value,
                    // NaN is how a metric says it has no expected value.
                    expected: (!m.expected.is_nan()).then_some(m.expected),
                })
                .collect(),
            last_error: h.last_error.as_str().to_owned(),
        }
    }
}

impl TryFrom<&HealthRecord> for Health {
    type Error = ConversionError;
    fn try_from(r: &HealthRecord) -> Result<Self, Self::Error> {
        if r.metrics.len() > MAX_METRICS {
            return Err(ConversionError::TooLong {
                field: "metrics",
                len: r.metrics.len(),
                capacity: MAX_METRICS,
            });
        }
        let state = match r.state.as_str() {
            "starting" => HealthState::Starting,
            "ok" => HealthState::Ok,
            "degraded" => HealthState::Degraded,
            "error" => HealthState::Error,
            "stopping" => HealthState::Stopping,
            other => {
                return Err(ConversionError::UnknownValue {
                    field: "state",
                    value: other.to_owned(),
                });
            }
        };
        let mut h = Health::new(&r.role, r.pid);
        h.header = (&r.header).into();
        h.set_state(state);
        h.uptime_s = r.uptime_s;
        h.latency_p50_us = r.latency_p50_us;
        h.latency_p99_us = r.latency_p99_us;
        h.latency_max_us = r.latency_max_us;
        h.deadline_misses = r.deadline_misses;
        for m in &r.metrics {
            h.set_metric(&m.name, m.value, m.expected);
        }
        h.last_error = FixedStr::from_str_truncate(&r.last_error);
        Ok(h)
    }
}

impl JsonForm for Health {
    type Record = HealthRecord;
    fn to_record(&self) -> HealthRecord {
        self.into()
    }
    fn write_record(r: &HealthRecord, out: &mut Self) -> Result<(), ConversionError> {
        *out = r.try_into()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::laser::BeamReading;

    #[test]
    fn laser_scan_round_trips_through_json() {
        let mut s = LaserScan {
            header: Header::new(123, 4, "laser"),
            angle_min: -2.0,
            angle_increment: 0.006,
            count: 4,
            range_max: 5.6,
            ..Default::default()
        };
        s.set_beam(0, BeamReading::Range(1.25));
        s.set_beam(1, BeamReading::SensorCode(6));
        s.set_beam(2, BeamReading::NoReturn);
        s.set_beam(3, BeamReading::Range(0.5));
        let rec = TopicRecord {
            topic: "laser/scan".into(),
            message: Message::LaserScan((&s).into()),
        };
        let line = serde_json::to_string(&rec).unwrap();
        assert!(line.contains(r#""type":"LaserScan""#), "{line}");
        let back: TopicRecord = serde_json::from_str(&line).unwrap();
        let Message::LaserScan(r) = back.message else {
            panic!("wrong type")
        };
        let s2 = LaserScan::try_from(&r).unwrap();
        for i in 0..4 {
            assert_eq!(s.beam(i), s2.beam(i));
        }
        assert_eq!(s2.header, s.header);
    }

    #[test]
    fn oversized_record_is_rejected_not_truncated() {
        let r = LaserScanRecord {
            ranges: vec![Some(1.0); MAX_BEAMS + 1],
            beam_error: vec![0; MAX_BEAMS + 1],
            ..Default::default()
        };
        assert!(matches!(
            LaserScan::try_from(&r),
            Err(ConversionError::TooLong { .. })
        ));
    }

    #[test]
    fn health_round_trips() {
        let mut h = Health::new("fusion", 42);
        h.set_state(HealthState::Degraded);
        h.set_metric("sonar_usage", 0.25, None);
        h.set_metric("scan_hz", 9.9, Some(10.0));
        let rec = HealthRecord::from(&h);
        let json = serde_json::to_string(&rec).unwrap();
        let back: HealthRecord = serde_json::from_str(&json).unwrap();
        let h2 = Health::try_from(&back).unwrap();
        assert_eq!(h2.metric("scan_hz"), Some(9.9));
        assert_eq!(h2.state(), HealthState::Degraded);
    }
}
