//! The messages as ordinary owned Rust values with serde support.
//!
//! This is the JSON-lines form `smokenav topic echo --json` prints (one
//! [`TopicRecord`] per line) and offline tools such as `smokenav fuse` read.
//! JSON has no NaN or infinity, so beams without a range are `null` in
//! `ranges`, with the reason in `beam_error`.

use crate::ConversionError;
use crate::fused::{FusedScan, FusionMethod, SectionDecision, SectionSource, SyncState};
use crate::header::Header;
use crate::health::{Health, HealthState, MAX_METRICS};
use crate::laser::{BEAM_OK, LaserScan, MAX_BEAMS};
use crate::odom::{Odometry, VelocityCommand};
use crate::slam::{MapInfo, PoseEstimate};
use crate::smoke::{SmokeReading, SmokeSensorState, SmokeTrend};
use crate::sonar::{MAX_SONARS, SonarReading, SonarRing, SonarStatus};
use crate::text::FixedStr;
use serde::{Deserialize, Serialize};

/// One line of `topic echo --json`: the topic and the message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TopicRecord {
    pub topic: String,
    #[serde(flatten)]
    pub message: Message,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type")]
pub enum Message {
    LaserScan(LaserScanRecord),
    SonarRing(SonarRingRecord),
    Odometry(OdometryRecord),
    VelocityCommand(VelocityCommandRecord),
    SmokeReading(SmokeReadingRecord),
    FusedScan(FusedScanRecord),
    PoseEstimate(PoseEstimateRecord),
    MapInfo(MapInfoRecord),
    Health(HealthRecord),
}

impl Message {
    pub fn header(&self) -> &HeaderRecord {
        match self {
            Message::LaserScan(m) => &m.header,
            Message::SonarRing(m) => &m.header,
            Message::Odometry(m) => &m.header,
            Message::VelocityCommand(m) => &m.header,
            Message::SmokeReading(m) => &m.header,
            Message::FusedScan(m) => &m.scan.header,
            Message::PoseEstimate(m) => &m.header,
            Message::MapInfo(m) => &m.header,
            Message::Health(m) => &m.header,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct HeaderRecord {
    pub stamp_ns: u64,
    pub seq: u64,
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

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LaserScanRecord {
    pub header: HeaderRecord,
    pub angle_min: f32,
    pub angle_increment: f32,
    pub time_increment: f32,
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    /// Range per beam, m; `null` where the beam has no range.
    pub ranges: Vec<Option<f32>>,
    /// Per beam: 0 = range, 1 = no return, 2 = beyond max, 256 + code = sensor error code.
    pub beam_error: Vec<u16>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
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

impl LaserScanRecord {
    /// Writes this record into an existing scan (no 10 kB temporary on the stack).
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
                    s.beam_error[i] = crate::laser::BEAM_NO_RETURN;
                    f32::INFINITY
                }
                (_, _) => f32::INFINITY,
            };
        }
        s.has_intensities = self.intensities.is_some() as u32;
        if let Some(int) = &self.intensities {
            s.intensities[..n].copy_from_slice(int);
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

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SonarReadingRecord {
    pub index: u8,
    pub range: f32,
    /// `valid`, `saturated` or `invalid`.
    pub status: String,
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SonarRingRecord {
    pub header: HeaderRecord,
    pub max_range: f32,
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

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct OdometryRecord {
    pub header: HeaderRecord,
    pub x: f64,
    pub y: f64,
    pub theta: f64,
    pub linear: f64,
    pub angular: f64,
    pub flags: u32,
    pub bumpers: u32,
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

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct VelocityCommandRecord {
    pub header: HeaderRecord,
    pub linear: f64,
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

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SmokeReadingRecord {
    pub header: HeaderRecord,
    pub raw_mv: f32,
    pub raw_counts: u32,
    pub level: f32,
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

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SectionRecord {
    pub first_beam: u16,
    pub end_beam: u16,
    pub sonar_index: u8,
    /// `laser`, `sonar`, `both` or `neither`.
    pub source: String,
    pub rho_sonar: f32,
    pub rho_laser: f32,
    pub sonar_range: f32,
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct FusedScanRecord {
    pub scan: LaserScanRecord,
    /// Per beam: 0 laser, 1 sonar, 2 both, 3 neither.
    pub beam_source: Vec<u8>,
    /// `laser-only`, `v1` or `v2`.
    pub method: String,
    /// `complete`, `laser-only` or `sonar-only`.
    pub sync_state: String,
    pub sections: Vec<SectionRecord>,
    pub smoke_level: f32,
    pub laser_spread: f32,
    pub sonar_stamp_ns: u64,
    pub smoke_stamp_ns: u64,
    /// Share of sections that used the sonar.
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
    pub fn write_into(&self, f: &mut FusedScan) -> Result<(), ConversionError> {
        self.scan.write_into(&mut f.scan)?;
        let n = f.scan.len();
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
        f.beam_source[..n].copy_from_slice(&self.beam_source);
        f.method =
            FusionMethod::parse(&self.method).ok_or_else(|| ConversionError::UnknownValue {
                field: "method",
                value: self.method.clone(),
            })? as u8;
        f.sync_state = match self.sync_state.as_str() {
            "complete" => SyncState::Complete,
            "laser-only" => SyncState::LaserOnly,
            "sonar-only" => SyncState::SonarOnly,
            other => {
                return Err(ConversionError::UnknownValue {
                    field: "sync_state",
                    value: other.to_owned(),
                });
            }
        } as u8;
        f.section_count = self.sections.len() as u32;
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

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseEstimateRecord {
    pub header: HeaderRecord,
    pub x: f64,
    pub y: f64,
    pub theta: f64,
    pub covariance: [f64; 9],
    pub n_eff: f32,
    pub particles: u32,
    pub scans_skipped: u64,
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

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MapInfoRecord {
    pub header: HeaderRecord,
    pub resolution: f32,
    pub width: u32,
    pub height: u32,
    pub origin_x: f64,
    pub origin_y: f64,
    pub origin_theta: f64,
    /// Cells, row-major from the lower-left corner (-1 unknown, 0..100). Omitted by `echo` unless asked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data: Option<Vec<i8>>,
}

impl From<&MapInfo> for MapInfoRecord {
    fn from(m: &MapInfo) -> Self {
        Self {
            header: (&m.header).into(),
            resolution: m.resolution,
            width: m.width,
            height: m.height,
            origin_x: m.origin_x,
            origin_y: m.origin_y,
            origin_theta: m.origin_theta,
            data: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MetricRecord {
    pub name: String,
    pub value: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub expected: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct HealthRecord {
    pub header: HeaderRecord,
    pub role: String,
    pub pid: u32,
    /// `starting`, `ok`, `degraded`, `error` or `stopping`.
    pub state: String,
    pub uptime_s: f64,
    pub latency_p50_us: f32,
    pub latency_p99_us: f32,
    pub latency_max_us: f32,
    pub deadline_misses: u64,
    pub metrics: Vec<MetricRecord>,
    pub last_error: String,
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
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
                    value: if m.value.is_finite() { m.value } else { 0.0 },
                    expected: finite(m.expected),
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
