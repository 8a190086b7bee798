//! CARMEN log reader (`FLASER`, `ROBOTLASER1`, `ODOM`).
//!
//! Record layouts (CARMEN logger, one record per line, space separated):
//!
//! ```text
//! FLASER n r1 … rn x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp
//! ROBOTLASER1 laser_type start_angle fov angular_res max_range accuracy remission_mode
//!     n r1 … rn m e1 … em laser_x laser_y laser_theta robot_x robot_y robot_theta
//!     tv rv forward_safety_dist side_safety_dist turn_axis ipc_timestamp ipc_hostname logger_timestamp
//! ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp
//! ```
//!
//! `FLASER` carries no angles: a front laser spans 180° from -90°, with
//! `180/(n-1)`° between beams for an odd `n` (181, 361) and `180/n`° otherwise.
//! Other records (`PARAM`, `SYNC`, comments…) are skipped. Input is distrusted:
//! lines are capped at [`MAX_LINE_BYTES`], readings at [`MAX_READINGS`], and a
//! bad line is reported with its number and skipped, never a panic.

use crate::scan::{Beam, BeamKind, RangeScan};
use smokenav_shared_types::Pose2;
use std::io::BufRead;

/// A CARMEN log's text from `input`: logs are often shipped gzip-compressed
/// (Radish's, the corrected CSAIL log), so a gzip stream is decompressed on
/// the fly, told by its magic bytes rather than by a file name.
pub fn text<R: BufRead + 'static>(mut input: R) -> std::io::Result<Box<dyn BufRead>> {
    const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];
    let head = input.fill_buf()?;
    Ok(if head.starts_with(&GZIP_MAGIC) {
        // Multi-member: `cat a.gz b.gz` and block-wise compressors write several.
        Box::new(std::io::BufReader::new(
            flate2::bufread::MultiGzDecoder::new(input),
        ))
    } else {
        Box::new(input)
    })
}

/// Longest line accepted, bytes (a 1081-beam ROBOTLASER1 with remissions is ~15 kB).
pub const MAX_LINE_BYTES: usize = 256 * 1024;
/// Most readings accepted in one laser record.
pub const MAX_READINGS: usize = 8192;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LaserRecordKind {
    Flaser,
    RobotLaser1,
}

/// One laser scan with the poses the logger attached.
#[derive(Debug, Clone, PartialEq)]
pub struct LaserRecord {
    pub kind: LaserRecordKind,
    /// Angle of the first beam in the laser frame, rad.
    pub start_angle: f64,
    /// Angle between beams, rad.
    pub angular_resolution: f64,
    /// The sensor's maximum range, m (infinite when the record does not say).
    pub max_range: f64,
    pub ranges: Vec<f32>,
    /// Pose of the laser in the odometry frame.
    pub laser_pose: Pose2,
    /// Odometry pose of the robot.
    pub robot_pose: Pose2,
    pub ipc_timestamp_ns: u64,
    /// The smallest step the stamp as written can show, ns (1 000 for
    /// `1134864629.895182`; 10¹³ for GMapping's `1.13486e+09`).
    pub stamp_resolution_ns: u64,
    /// Significant digits the stamp is written with ([`significant_digits`]).
    pub stamp_digits: u32,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdomRecord {
    pub pose: Pose2,
    pub tv: f64,
    pub rv: f64,
    pub ipc_timestamp_ns: u64,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    Laser(LaserRecord),
    Odom(OdomRecord),
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CarmenError {
    #[error("{record}: expected at least {expected} fields, got {got} (truncated line?)")]
    Truncated {
        record: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("{record}: field {index} ({what}) should be a number, got {text:?}")]
    BadNumber {
        record: &'static str,
        index: usize,
        what: &'static str,
        text: String,
    },
    #[error("{record}: {count} readings declared, at most {MAX_READINGS} accepted")]
    TooManyReadings { record: &'static str, count: usize },
    #[error("line longer than {MAX_LINE_BYTES} bytes")]
    LineTooLong,
    #[error("line is not UTF-8")]
    NotUtf8,
    #[error("read error: {0}")]
    Io(String),
    #[error("{0}")]
    Odometry(#[from] crate::offline::ImplausibleOdometry),
}

/// A line that could not be used, with its 1-based number.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {error}")]
pub struct LineError {
    pub line: usize,
    pub error: CarmenError,
}

struct Fields<'a> {
    record: &'static str,
    f: Vec<&'a str>,
}

impl<'a> Fields<'a> {
    fn need(&self, n: usize) -> Result<(), CarmenError> {
        if self.f.len() < n {
            return Err(CarmenError::Truncated {
                record: self.record,
                expected: n,
                got: self.f.len(),
            });
        }
        Ok(())
    }

    fn text(&self, i: usize) -> Result<&'a str, CarmenError> {
        self.need(i + 1)?;
        Ok(self.f[i])
    }

    /// A finite number.
    fn num(&self, i: usize, what: &'static str) -> Result<f64, CarmenError> {
        let t = self.text(i)?;
        t.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| CarmenError::BadNumber {
                record: self.record,
                index: i,
                what,
                text: t.chars().take(40).collect(),
            })
    }

    /// A number that may be `nan`/`inf` (a range reading the sensor could not make).
    fn reading(&self, i: usize) -> Result<f32, CarmenError> {
        let t = self.text(i)?;
        t.parse::<f32>().map_err(|_| CarmenError::BadNumber {
            record: self.record,
            index: i,
            what: "range reading",
            text: t.chars().take(40).collect(),
        })
    }

    fn count(&self, i: usize, what: &'static str) -> Result<usize, CarmenError> {
        let v = self.num(i, what)?;
        if v < 0.0 || v.fract() != 0.0 {
            return Err(CarmenError::BadNumber {
                record: self.record,
                index: i,
                what,
                text: self.f[i].chars().take(40).collect(),
            });
        }
        if v > MAX_READINGS as f64 {
            return Err(CarmenError::TooManyReadings {
                record: self.record,
                count: v.min(usize::MAX as f64) as usize,
            });
        }
        Ok(v as usize)
    }

    fn pose(&self, i: usize, what: &'static str) -> Result<Pose2, CarmenError> {
        Ok(Pose2::new(
            self.num(i, what)?,
            self.num(i + 1, what)?,
            self.num(i + 2, what)?,
        ))
    }

    fn stamp(&self, i: usize) -> Result<u64, CarmenError> {
        let t = self.text(i)?;
        parse_stamp_ns(t).ok_or_else(|| CarmenError::BadNumber {
            record: self.record,
            index: i,
            what: "ipc_timestamp",
            text: t.chars().take(40).collect(),
        })
    }
}

/// Parses one log line. `Ok(None)` for records this reader does not use.
pub fn parse_line(line: &str) -> Result<Option<Record>, CarmenError> {
    let mut it = line.split_whitespace();
    let Some(tag) = it.next() else {
        return Ok(None);
    };
    let record: &'static str = match tag {
        "FLASER" => "FLASER",
        "ROBOTLASER1" => "ROBOTLASER1",
        "ODOM" => "ODOM",
        _ => return Ok(None),
    };
    let f = Fields {
        record,
        f: line.split_whitespace().skip(1).collect(),
    };
    match record {
        "FLASER" => {
            let n = f.count(0, "num_readings")?;
            f.need(1 + n + 7)?;
            let ranges = (0..n)
                .map(|i| f.reading(1 + i))
                .collect::<Result<Vec<_>, _>>()?;
            let laser_pose = f.pose(1 + n, "laser pose")?;
            let robot_pose = f.pose(1 + n + 3, "odometry pose")?;
            let ipc_timestamp_ns = f.stamp(1 + n + 6)?;
            let stamp_resolution_ns = stamp_resolution_ns(f.text(1 + n + 6)?);
            let stamp_digits = significant_digits(f.text(1 + n + 6)?);
            let fov = std::f64::consts::PI;
            let angular_resolution = match n {
                0 | 1 => fov,
                n if n % 2 == 1 => fov / (n - 1) as f64,
                n => fov / n as f64,
            };
            Ok(Some(Record::Laser(LaserRecord {
                kind: LaserRecordKind::Flaser,
                start_angle: -fov / 2.0,
                angular_resolution,
                max_range: f64::INFINITY,
                ranges,
                laser_pose,
                robot_pose,
                ipc_timestamp_ns,
                stamp_resolution_ns,
                stamp_digits,
            })))
        }
        "ROBOTLASER1" => {
            let start_angle = f.num(1, "start_angle")?;
            let angular_resolution = f.num(3, "angular_res")?;
            let max_range = f.num(4, "maximum_range")?;
            let n = f.count(7, "num_readings")?;
            let ranges = (0..n)
                .map(|i| f.reading(8 + i))
                .collect::<Result<Vec<_>, _>>()?;
            let m = f.count(8 + n, "num_remissions")?;
            let base = 9 + n + m;
            f.need(base + 12)?;
            let laser_pose = f.pose(base, "laser pose")?;
            let robot_pose = f.pose(base + 3, "robot pose")?;
            let ipc_timestamp_ns = f.stamp(base + 11)?;
            let stamp_resolution_ns = stamp_resolution_ns(f.text(base + 11)?);
            let stamp_digits = significant_digits(f.text(base + 11)?);
            Ok(Some(Record::Laser(LaserRecord {
                kind: LaserRecordKind::RobotLaser1,
                start_angle,
                angular_resolution,
                max_range,
                ranges,
                laser_pose,
                robot_pose,
                ipc_timestamp_ns,
                stamp_resolution_ns,
                stamp_digits,
            })))
        }
        _ => {
            f.need(7)?;
            Ok(Some(Record::Odom(OdomRecord {
                pose: f.pose(0, "odometry pose")?,
                tv: f.num(3, "tv")?,
                rv: f.num(4, "rv")?,
                ipc_timestamp_ns: f.stamp(6)?,
            })))
        }
    }
}

impl LaserRecord {
    /// Fills a filter scan: readings that are not finite, not positive or at/over
    /// the sensor's max range carry no range. The laser's mount is the laser pose
    /// relative to the robot pose.
    pub fn fill_range_scan(&self, out: &mut RangeScan) {
        out.clear();
        out.stamp_ns = self.ipc_timestamp_ns;
        let mount = self.robot_pose.between(&self.laser_pose);
        out.sensor_pose = if mount.is_finite() {
            mount
        } else {
            Pose2::default()
        };
        for (i, &r) in self.ranges.iter().enumerate() {
            let valid = r.is_finite() && r > 0.0 && (r as f64) < self.max_range;
            out.beams.push(Beam {
                angle: (self.start_angle + i as f64 * self.angular_resolution) as f32,
                range: valid.then_some(r),
                kind: BeamKind::Laser,
            });
        }
    }
}

/// Reads records from a log, skipping lines it does not use and reporting bad
/// ones (with line numbers) as `Err` items; reading goes on after an error.
pub struct CarmenReader<R> {
    inner: R,
    line_no: usize,
    buf: Vec<u8>,
    done: bool,
    /// Laser records of kinds not read (`RAWLASER1`–`4`: no pose of their
    /// own; `RLASER`: a rear laser), counted so a log of only those can say why
    /// it gave no scan.
    pub unread_laser_records: usize,
}

impl<R: BufRead> CarmenReader<R> {
    pub fn new(inner: R) -> Self {
        Self {
            inner,
            line_no: 0,
            buf: Vec::new(),
            done: false,
            unread_laser_records: 0,
        }
    }

    /// Number of the last line read.
    pub fn line(&self) -> usize {
        self.line_no
    }

    /// Reads one line into `buf` (without the newline), keeping at most
    /// `MAX_LINE_BYTES`. Returns Ok(None) at the end, Ok(Some(too_long)).
    fn read_line(&mut self) -> std::io::Result<Option<bool>> {
        self.buf.clear();
        let mut too_long = false;
        let mut any = false;
        loop {
            let chunk = match self.inner.fill_buf() {
                Ok(c) => c,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            if chunk.is_empty() {
                return Ok(any.then_some(too_long));
            }
            any = true;
            let (part, used, end) = match chunk.iter().position(|&b| b == b'\n') {
                Some(p) => (&chunk[..p], p + 1, true),
                None => (chunk, chunk.len(), false),
            };
            let room = MAX_LINE_BYTES.saturating_sub(self.buf.len());
            if part.len() > room {
                too_long = true;
            }
            self.buf.extend_from_slice(&part[..part.len().min(room)]);
            self.inner.consume(used);
            if end {
                return Ok(Some(too_long));
            }
        }
    }
}

impl<R: BufRead> Iterator for CarmenReader<R> {
    type Item = Result<Record, LineError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.done {
            let too_long = match self.read_line() {
                Ok(Some(t)) => t,
                Ok(None) => {
                    self.done = true;
                    return None;
                }
                Err(e) => {
                    self.done = true;
                    return Some(Err(LineError {
                        line: self.line_no + 1,
                        error: CarmenError::Io(e.to_string()),
                    }));
                }
            };
            self.line_no += 1;
            let line = self.line_no;
            if too_long {
                return Some(Err(LineError {
                    line,
                    error: CarmenError::LineTooLong,
                }));
            }
            let Ok(text) = std::str::from_utf8(&self.buf) else {
                return Some(Err(LineError {
                    line,
                    error: CarmenError::NotUtf8,
                }));
            };
            match parse_line(text) {
                Ok(Some(r)) => return Some(Ok(r)),
                Ok(None) => {
                    if text.starts_with("RAWLASER") || text.starts_with("RLASER") {
                        self.unread_laser_records += 1;
                    }
                    continue;
                }
                Err(error) => return Some(Err(LineError { line, error })),
            }
        }
        None
    }
}

/// The smallest step a stamp written as `text` can show, ns: `0.5` → 10⁸,
/// `1134864629.895182` → 10³, `1.13486e+09` → 10¹³ (six significant
/// digits, as C's `%g` writes them: a whole log under one stamp). At least 1.
pub fn stamp_resolution_ns(text: &str) -> u64 {
    let t = text.trim();
    let (mantissa, exp) = match t.split_once(['e', 'E']) {
        Some((m, e)) => (m, e.parse::<i32>().unwrap_or(0)),
        None => (t, 0),
    };
    let decimals = mantissa.split_once('.').map_or(0, |(_, f)| f.len()) as i32;
    // 10^(exp − decimals) s in ns, clamped to what a u64 holds.
    let power = exp.saturating_sub(decimals).saturating_add(9).clamp(0, 18);
    10u64.pow(power as u32)
}

/// The significant digits of a number written as `text` (the mantissa's
/// digits after any leading zeros): `32.9068` → 6, `940` → 3,
/// `1.13486e+09` → 6, `0.000246` → 3.
pub fn significant_digits(text: &str) -> u32 {
    let t = text.trim();
    let mantissa = t.split_once(['e', 'E']).map_or(t, |(m, _)| m);
    let digits = mantissa.bytes().filter(u8::is_ascii_digit);
    digits.skip_while(|&d| d == b'0').count() as u32
}

/// The step a stamp of `stamp_ns` shows when written with `digits`
/// significant digits, ns: what `%g` (C's shortest form) leaves of a stamp
/// whose trailing zeros it dropped. `940` written beside `32.9068` by
/// `%g`'s six digits is 940.000 s, a millisecond step, not a second. At
/// least 1.
pub fn resolution_at_digits_ns(stamp_ns: u64, digits: u32) -> u64 {
    if stamp_ns == 0 || digits == 0 {
        return 1;
    }
    // Digits of the whole seconds (0 for a stamp under 1 s, by its first non-zero decimal).
    let magnitude = (stamp_ns as f64 / 1e9).log10().floor() as i32;
    let power = (magnitude - digits as i32 + 1 + 9).clamp(0, 18);
    10u64.pow(power as u32)
}

/// Parses a decimal timestamp in seconds (`1134864629.895182`, or `1.13486e+09`)
/// into nanoseconds without going through floating point when it is plain decimal.
pub fn parse_stamp_ns(text: &str) -> Option<u64> {
    let t = text.trim();
    if t.is_empty() || t.starts_with('-') || t.starts_with('+') {
        return None;
    }
    if t.bytes().all(|b| b.is_ascii_digit() || b == b'.') {
        let (int, frac) = t.split_once('.').unwrap_or((t, ""));
        if int.is_empty() && frac.is_empty() || frac.contains('.') {
            return None;
        }
        let secs: u64 = if int.is_empty() { 0 } else { int.parse().ok()? };
        let mut ns = 0u64;
        for (i, b) in frac.bytes().take(9).enumerate() {
            ns += (b - b'0') as u64 * 10u64.pow(8 - i as u32);
        }
        return secs.checked_mul(1_000_000_000)?.checked_add(ns);
    }
    let v: f64 = t.parse().ok()?;
    (0.0..1.8e10).contains(&v).then(|| (v * 1e9).round() as u64)
}

/// Formats nanoseconds as seconds with microseconds, the way CARMEN logs write stamps.
pub fn format_stamp(stamp_ns: u64) -> String {
    format!(
        "{}.{:06}",
        stamp_ns / 1_000_000_000,
        (stamp_ns % 1_000_000_000) / 1000
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn flaser(n: usize) -> String {
        let ranges: Vec<String> = (0..n)
            .map(|i| format!("{:.2}", 1.0 + i as f64 * 0.01))
            .collect();
        format!(
            "FLASER {n} {} 576.536523 0.106594 -2.255213 576.536523 0.106594 -2.255213 1134864629.895182 b21 0.086295",
            ranges.join(" ")
        )
    }

    #[test]
    fn stamps_keep_microseconds_exactly() {
        assert_eq!(
            parse_stamp_ns("1134864629.895182"),
            Some(1_134_864_629_895_182_000)
        );
        assert_eq!(format_stamp(1_134_864_629_895_182_000), "1134864629.895182");
        assert_eq!(
            parse_stamp_ns("1.13486e+09"),
            Some(1_134_860_000_000_000_000)
        );
        assert_eq!(parse_stamp_ns("-1"), None);
        assert_eq!(parse_stamp_ns("1.2.3"), None);
        assert_eq!(parse_stamp_ns("."), None);
        assert_eq!(parse_stamp_ns("99999999999999999999"), None);
    }

    #[test]
    fn flaser_361_spans_180_degrees_at_half_degree() {
        let Some(Record::Laser(r)) = parse_line(&flaser(361)).unwrap() else {
            panic!()
        };
        assert_eq!(r.ranges.len(), 361);
        assert!((r.start_angle + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((r.angular_resolution - 0.5f64.to_radians()).abs() < 1e-12);
        assert_eq!(r.robot_pose, Pose2::new(576.536523, 0.106594, -2.255213));
        assert_eq!(r.ipc_timestamp_ns, 1_134_864_629_895_182_000);
        let mut scan = RangeScan::default();
        r.fill_range_scan(&mut scan);
        assert_eq!(scan.sensor_pose, Pose2::default());
        assert!((scan.beams[360].angle as f64 - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
    }

    #[test]
    fn robotlaser1_and_odom_records_parse() {
        let line = "ROBOTLASER1 0 -1.5708 3.14159 0.5 81.9 0.01 0 3 1.0 2.0 81.9 0 \
                    0.1 0.2 0.3 0.0 0.0 0.3 0.5 0.1 0.0 0.0 0.0 1134864642.914187 pippo 1.0";
        let Some(Record::Laser(r)) = parse_line(line).unwrap() else {
            panic!()
        };
        assert_eq!(r.kind, LaserRecordKind::RobotLaser1);
        assert_eq!(r.ranges, vec![1.0, 2.0, 81.9]);
        assert_eq!(r.max_range, 81.9);
        let mut scan = RangeScan::default();
        r.fill_range_scan(&mut scan);
        assert_eq!(
            scan.beams[2].range, None,
            "a reading at max range is no return"
        );
        assert!((scan.sensor_pose.x - 0.1 * 0.3f64.cos() - 0.2 * 0.3f64.sin()).abs() < 1e-9);
        let Some(Record::Odom(o)) =
            parse_line("ODOM 1 2 0.5 0.3 0.1 0 1134864642.5 pippo 1.0").unwrap()
        else {
            panic!()
        };
        assert_eq!(o.pose, Pose2::new(1.0, 2.0, 0.5));
        assert_eq!(o.ipc_timestamp_ns, 1_134_864_642_500_000_000);
    }

    #[test]
    fn truncated_and_malformed_lines_are_reported_with_line_numbers() {
        let good = flaser(5);
        let truncated = &good[..good.len() - 60];
        let text = format!(
            "# comment\nPARAM robot_width 0.54 1 b21 1\n{good}\n{truncated}\nFLASER 3 1 x 2 0 0 0 0 0 0 1.0 h 1\n{good}\nFLASER 1e9 1\n"
        );
        let items: Vec<_> = CarmenReader::new(text.as_bytes()).collect();
        assert_eq!(items.len(), 5);
        assert!(items[0].is_ok() && items[3].is_ok());
        let e1 = items[1].as_ref().unwrap_err();
        assert_eq!(e1.line, 4);
        assert!(matches!(e1.error, CarmenError::Truncated { .. }), "{e1}");
        let e2 = items[2].as_ref().unwrap_err();
        assert_eq!(e2.line, 5);
        assert!(e2.to_string().contains("\"x\""), "{e2}");
        let e3 = items[4].as_ref().unwrap_err();
        assert_eq!(e3.line, 7);
        assert!(matches!(e3.error, CarmenError::TooManyReadings { .. }));
    }

    #[test]
    fn all_invalid_readings_give_a_scan_without_ranges() {
        let line = "FLASER 3 nan 0.0 -1 0 0 0 0 0 0 5.0 h 5.0";
        let Some(Record::Laser(r)) = parse_line(line).unwrap() else {
            panic!()
        };
        let mut scan = RangeScan::default();
        r.fill_range_scan(&mut scan);
        assert_eq!(scan.beams.len(), 3);
        assert_eq!(scan.valid_count(), 0);
    }

    #[test]
    fn a_stamps_resolution_is_what_its_text_can_show() {
        assert_eq!(significant_digits("32.9068"), 6);
        assert_eq!(significant_digits("940"), 3);
        assert_eq!(significant_digits("1.13486e+09"), 6);
        assert_eq!(significant_digits("0.000246"), 3);
        assert_eq!(significant_digits("1134864629.895182"), 16);
        assert_eq!(significant_digits("x"), 0);
        assert_eq!(resolution_at_digits_ns(940_000_000_000, 6), 1_000_000);
        assert_eq!(resolution_at_digits_ns(1_438_980_000_000, 6), 10_000_000);
        assert_eq!(resolution_at_digits_ns(250_000_000, 6), 1_000);
        assert_eq!(
            resolution_at_digits_ns(1_134_860_000_000_000_000, 6),
            10u64.pow(13)
        );
        assert_eq!(resolution_at_digits_ns(0, 6), 1);
        assert_eq!(resolution_at_digits_ns(u64::MAX, 1), 10u64.pow(18));
        assert_eq!(stamp_resolution_ns("1134864629.895182"), 1_000);
        assert_eq!(stamp_resolution_ns("0.5"), 100_000_000);
        assert_eq!(stamp_resolution_ns("12"), 1_000_000_000);
        // GMapping's corrected logs (`%g`): a whole run under one stamp.
        assert_eq!(stamp_resolution_ns("1.13486e+09"), 10_000_000_000_000);
        assert_eq!(stamp_resolution_ns("1.13486E9"), 10_000_000_000_000);
        assert_eq!(stamp_resolution_ns("1e-3"), 1_000_000);
        assert_eq!(stamp_resolution_ns("1.5e-12"), 1);
        assert_eq!(stamp_resolution_ns("1e99"), 10u64.pow(18));
        // Exponents at i32's ends (the stamp itself parses: 0 s) do not overflow.
        assert_eq!(stamp_resolution_ns("1.5e-2147483648"), 1);
        assert_eq!(stamp_resolution_ns("1e2147483647"), 10u64.pow(18));
        assert!(parse_line("FLASER 0 0 0 0 0 0 0 1.5e-2147483648 h 0").is_ok());
        let line = "FLASER 3 1.0 2.0 3.0 0.5 0.25 0.1 0.5 0.25 0.1 1.13486e+09 host 1.13486e+09";
        let Ok(Some(Record::Laser(l))) = parse_line(line) else {
            panic!("{line}")
        };
        assert_eq!(l.ipc_timestamp_ns, 1_134_860_000_000_000_000);
        assert_eq!(l.stamp_resolution_ns, 10_000_000_000_000);
    }

    #[test]
    fn overlong_line_is_skipped_and_reading_goes_on() {
        let text = format!("FLASER {}\n{}\n", "1 ".repeat(MAX_LINE_BYTES), flaser(3));
        let items: Vec<_> = CarmenReader::new(text.as_bytes()).collect();
        assert_eq!(items.len(), 2);
        assert_eq!(
            items[0].as_ref().unwrap_err().error,
            CarmenError::LineTooLong
        );
        assert!(items[1].is_ok());
    }

    proptest! {
        #[test]
        fn arbitrary_lines_never_panic(line in ".{0,400}") {
            let _ = parse_line(&line);
        }

        #[test]
        fn arbitrary_record_like_lines_never_panic(
            tag in prop::sample::select(vec!["FLASER", "ROBOTLASER1", "ODOM"]),
            fields in prop::collection::vec(
                prop_oneof![
                    Just("nan".to_string()), Just("-1".to_string()), Just("1e300".to_string()),
                    Just("3".to_string()), Just("361".to_string()), (-100.0f64..100.0).prop_map(|v| v.to_string()),
                    "[a-z0-9.+-]{1,6}",
                ],
                0..40,
            ),
        ) {
            let line = format!("{tag} {}", fields.join(" "));
            if let Ok(Some(Record::Laser(r))) = parse_line(&line) {
                let mut scan = RangeScan::default();
                r.fill_range_scan(&mut scan);
                prop_assert!(scan.beams.len() <= MAX_READINGS);
            }
        }

        #[test]
        fn arbitrary_bytes_never_panic_the_reader(bytes in prop::collection::vec(any::<u8>(), 0..2000)) {
            let n = CarmenReader::new(&bytes[..]).count();
            prop_assert!(n <= bytes.len() + 1);
        }
    }
}
