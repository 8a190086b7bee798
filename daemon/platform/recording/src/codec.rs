//! smokenav messages ⇄ CDR payloads of their ROS 2 and `smokenav_msgs` forms.
//!
//! Pure functions: a message in, bytes out; bytes in, a message (or a typed
//! error) out. The standard message of a pair is decoded first into the
//! smokenav type (what it can carry), then its companion completes it
//! (`apply_*`), so the pair reproduces the original exactly.

use crate::cdr::{CdrError, CdrReader, CdrWriter};
use smokenav_shared_types::fused::SectionDecision;
use smokenav_shared_types::header::FRAME_ID_LEN;
use smokenav_shared_types::health::{LAST_ERROR_LEN, MAX_METRICS, METRIC_NAME_LEN, ROLE_LEN};
use smokenav_shared_types::laser::{BEAM_OK, BEAM_SENSOR_CODE};
use smokenav_shared_types::{
    FixedStr, FusedScan, Header, Health, LaserScan, MAX_BEAMS, MAX_SONARS, MAX_VOXELS, MapInfo,
    Metric, Odometry, PoseEstimate, SimClock, SmokeReading, SonarReading, SonarRing,
    VelocityCommand, VoxelCloud,
};

/// `child_frame_id` of odometry and of the odom → base transform.
pub const BASE_FRAME: &str = "base_link";

/// Largest occupancy grid a recording may hold (a 16 384² grid, 256 MiB).
pub const MAX_MAP_CELLS: usize = 1 << 28;

// ---- shared pieces -----------------------------------------------------------

/// `builtin_interfaces/Time` of a nanosecond stamp. The second saturates at
/// `i32::MAX` (68 years of uptime); the companion keeps the exact `u64`.
pub fn ros_time(stamp_ns: u64) -> (i32, u32) {
    let sec = (stamp_ns / 1_000_000_000).min(i32::MAX as u64) as i32;
    (sec, (stamp_ns % 1_000_000_000) as u32)
}

fn time_ns(sec: i32, nanosec: u32) -> u64 {
    (sec.max(0) as u64) * 1_000_000_000 + u64::from(nanosec)
}

fn write_time(w: &mut CdrWriter, stamp_ns: u64) {
    let (sec, nanosec) = ros_time(stamp_ns);
    w.i32(sec);
    w.u32(nanosec);
}

fn write_header(w: &mut CdrWriter, stamp_ns: u64, frame_id: &str) {
    write_time(w, stamp_ns);
    w.string(frame_id);
}

fn read_time(r: &mut CdrReader) -> Result<u64, CdrError> {
    let sec = r.i32("stamp.sec")?;
    let nanosec = r.u32("stamp.nanosec")?;
    Ok(time_ns(sec, nanosec))
}

/// A `std_msgs/Header` as a smokenav header (stamp rounded to what Time holds, seq 0).
fn read_header(r: &mut CdrReader) -> Result<Header, CdrError> {
    let stamp_ns = read_time(r)?;
    let frame = r.string("header.frame_id", FRAME_ID_LEN)?;
    Ok(Header::new(stamp_ns, 0, frame))
}

/// Quaternion (x, y, z, w) of a rotation by `yaw` about z.
pub fn yaw_quaternion(yaw: f64) -> [f64; 4] {
    let h = yaw * 0.5;
    [0.0, 0.0, h.sin(), h.cos()]
}

fn quaternion_yaw(q: [f64; 4]) -> f64 {
    let [x, y, z, w] = q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

fn write_pose(w: &mut CdrWriter, x: f64, y: f64, yaw: f64) {
    w.f64(x);
    w.f64(y);
    w.f64(0.0);
    for c in yaw_quaternion(yaw) {
        w.f64(c);
    }
}

/// (x, y, yaw) of a `geometry_msgs/Pose`.
fn read_pose(r: &mut CdrReader) -> Result<(f64, f64, f64), CdrError> {
    let x = r.f64("pose.position.x")?;
    let y = r.f64("pose.position.y")?;
    let _z = r.f64("pose.position.z")?;
    let mut q = [0.0; 4];
    r.array_f64("pose.orientation", &mut q)?;
    Ok((x, y, quaternion_yaw(q)))
}

/// The stamp and sequence number every companion starts with.
fn read_stamp_seq(r: &mut CdrReader) -> Result<(u64, u64), CdrError> {
    Ok((r.u64("stamp_ns")?, r.u64("seq")?))
}

// ---- sensor_msgs/LaserScan + smokenav_msgs/ScanExtras ------------------------

/// The REP 117 value a beam without a range shows in `LaserScan.ranges`.
fn rep117_range(code: u16) -> f32 {
    if code & BEAM_SENSOR_CODE != 0 {
        f32::NAN // an erroneous measurement
    } else {
        f32::INFINITY // no return / beyond max
    }
}

pub fn encode_laser_scan(scan: &LaserScan, buf: &mut Vec<u8>) {
    let n = scan.len();
    let mut w = CdrWriter::new(buf);
    write_header(&mut w, scan.header.stamp_ns, scan.header.frame_id.as_str());
    w.f32(scan.angle_min);
    w.f32(scan.angle_max());
    w.f32(scan.angle_increment);
    w.f32(scan.time_increment);
    w.f32(scan.scan_time);
    w.f32(scan.range_min);
    w.f32(scan.range_max);
    w.seq_f32((0..n).map(|i| match scan.beam_error[i] {
        BEAM_OK => scan.ranges[i],
        code => rep117_range(code),
    }));
    if scan.has_intensities != 0 {
        w.seq_f32(scan.intensities[..n].iter().copied());
    } else {
        w.seq_f32(std::iter::empty());
    }
}

/// Decodes a `sensor_msgs/LaserScan` into `out` (every field of `out` is
/// reset first). `beam_error`, the exact stamp and `seq` come from the companion.
pub fn decode_laser_scan(data: &[u8], out: &mut LaserScan) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    reset_scan(out);
    out.header = read_header(&mut r)?;
    out.angle_min = r.f32("angle_min")?;
    let _angle_max = r.f32("angle_max")?;
    out.angle_increment = r.f32("angle_increment")?;
    out.time_increment = r.f32("time_increment")?;
    out.scan_time = r.f32("scan_time")?;
    out.range_min = r.f32("range_min")?;
    out.range_max = r.f32("range_max")?;
    let n = r.seq_f32_into("ranges", &mut out.ranges)?;
    out.count = n as u32;
    let ni = r.seq_f32_into("intensities", &mut out.intensities)?;
    if ni != 0 && ni != n {
        return Err(CdrError::WrongLength {
            field: "intensities",
            got: ni,
            expected: n,
        });
    }
    out.has_intensities = u32::from(ni != 0);
    // Until the companion says otherwise, read the ranges the REP 117 way.
    for i in 0..n {
        out.beam_error[i] = if out.ranges[i].is_finite() {
            BEAM_OK
        } else if out.ranges[i].is_nan() {
            BEAM_SENSOR_CODE
        } else {
            smokenav_shared_types::laser::BEAM_NO_RETURN
        };
    }
    Ok(())
}

fn reset_scan(s: &mut LaserScan) {
    s.header = Header::default();
    s.angle_min = 0.0;
    s.angle_increment = 0.0;
    s.time_increment = 0.0;
    s.scan_time = 0.0;
    s.range_min = 0.0;
    s.range_max = 0.0;
    s.count = 0;
    s.has_intensities = 0;
    s.ranges.fill(0.0);
    s.intensities.fill(0.0);
    s.beam_error
        .fill(smokenav_shared_types::laser::BEAM_NO_RETURN);
}

fn write_scan_extras(w: &mut CdrWriter, scan: &LaserScan) {
    let n = scan.len();
    w.u64(scan.header.stamp_ns);
    w.u64(scan.header.seq);
    w.bool(scan.has_intensities != 0);
    w.seq_u16(&scan.beam_error[..n]);
    let errors = scan.beam_error[..n]
        .iter()
        .filter(|&&c| c != BEAM_OK)
        .count();
    w.seq_len(errors);
    for i in 0..n {
        if scan.beam_error[i] != BEAM_OK {
            w.f32(scan.ranges[i]);
        }
    }
}

pub fn encode_scan_extras(scan: &LaserScan, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_scan_extras(&mut w, scan);
}

fn read_scan_extras(r: &mut CdrReader, scan: &mut LaserScan) -> Result<(), CdrError> {
    let (stamp_ns, seq) = read_stamp_seq(r)?;
    scan.header.stamp_ns = stamp_ns;
    scan.header.seq = seq;
    let has_intensities = r.bool("has_intensities")?;
    let n = scan.len();
    if has_intensities && scan.has_intensities == 0 && n > 0 {
        return Err(CdrError::WrongLength {
            field: "intensities",
            got: 0,
            expected: n,
        });
    }
    scan.has_intensities = u32::from(has_intensities);
    let mut codes = [0u16; MAX_BEAMS];
    let nc = r.seq_u16_into("beam_error", &mut codes)?;
    if nc != n {
        return Err(CdrError::WrongLength {
            field: "beam_error",
            got: nc,
            expected: n,
        });
    }
    scan.beam_error[..n].copy_from_slice(&codes[..n]);
    let expected = codes[..n].iter().filter(|&&c| c != BEAM_OK).count();
    let mut errs = [0f32; MAX_BEAMS];
    let ne = r.seq_f32_into("error_ranges", &mut errs)?;
    if ne != expected {
        return Err(CdrError::WrongLength {
            field: "error_ranges",
            got: ne,
            expected,
        });
    }
    let mut next = errs[..ne].iter();
    for i in 0..n {
        if scan.beam_error[i] != BEAM_OK
            && let Some(&v) = next.next()
        {
            scan.ranges[i] = v;
        }
    }
    Ok(())
}

/// Completes a scan decoded by [`decode_laser_scan`] with its `ScanExtras`.
pub fn apply_scan_extras(data: &[u8], scan: &mut LaserScan) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    read_scan_extras(&mut r, scan)
}

// ---- fusion/scan: LaserScan + smokenav_msgs/FusedDecisions -------------------

pub fn encode_fused_decisions(f: &FusedScan, buf: &mut Vec<u8>) {
    let n = f.scan.len();
    let mut w = CdrWriter::new(buf);
    write_scan_extras(&mut w, &f.scan);
    w.seq_u8(&f.beam_source[..n]);
    w.u8(f.method);
    w.u8(f.sync_state);
    let sections = f.sections();
    w.seq_len(sections.len());
    for s in sections {
        w.u16(s.first_beam);
        w.u16(s.end_beam);
        w.u8(s.sonar_index);
        w.u8(s.source);
        w.f32(s.rho_sonar);
        w.f32(s.rho_laser);
        w.f32(s.sonar_range);
    }
    w.f32(f.smoke_level);
    w.f32(f.laser_spread);
    w.u64(f.sonar_stamp_ns);
    w.u64(f.smoke_stamp_ns);
}

/// Completes a fused scan whose `scan` was decoded by [`decode_laser_scan`].
pub fn apply_fused_decisions(data: &[u8], f: &mut FusedScan) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    read_scan_extras(&mut r, &mut f.scan)?;
    let n = f.scan.len();
    let src = r.seq_bytes("beam_source", MAX_BEAMS)?;
    if src.len() != n {
        return Err(CdrError::WrongLength {
            field: "beam_source",
            got: src.len(),
            expected: n,
        });
    }
    f.beam_source.fill(0);
    f.beam_source[..n].copy_from_slice(src);
    f.method = r.u8("method")?;
    f.sync_state = r.u8("sync_state")?;
    f._reserved = [0; 2];
    let count = r.seq_len("sections", MAX_SONARS, 16)?;
    f.sections = [SectionDecision::default(); MAX_SONARS];
    for s in &mut f.sections[..count] {
        s.first_beam = r.u16("sections.first_beam")?;
        s.end_beam = r.u16("sections.end_beam")?;
        s.sonar_index = r.u8("sections.sonar_index")?;
        s.source = r.u8("sections.source")?;
        s.rho_sonar = r.f32("sections.rho_sonar")?;
        s.rho_laser = r.f32("sections.rho_laser")?;
        s.sonar_range = r.f32("sections.sonar_range")?;
    }
    f.section_count = count as u32;
    f.smoke_level = r.f32("smoke_level")?;
    f.laser_spread = r.f32("laser_spread")?;
    f.sonar_stamp_ns = r.u64("sonar_stamp_ns")?;
    f.smoke_stamp_ns = r.u64("smoke_stamp_ns")?;
    Ok(())
}

// ---- nav_msgs/Odometry + smokenav_msgs/OdometryExtras ------------------------

pub fn encode_odometry(o: &Odometry, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_header(&mut w, o.header.stamp_ns, o.header.frame_id.as_str());
    w.string(BASE_FRAME);
    write_pose(&mut w, o.x, o.y, o.theta);
    w.array_f64(&[0.0; 36]); // unknown covariance
    for v in [o.linear, 0.0, 0.0, 0.0, 0.0, o.angular] {
        w.f64(v);
    }
    w.array_f64(&[0.0; 36]);
}

pub fn decode_odometry(data: &[u8]) -> Result<Odometry, CdrError> {
    let mut r = CdrReader::new(data)?;
    let header = read_header(&mut r)?;
    let _child = r.string("child_frame_id", FRAME_ID_LEN)?;
    let (x, y, theta) = read_pose(&mut r)?;
    let mut cov = [0.0; 36];
    r.array_f64("pose.covariance", &mut cov)?;
    let mut twist = [0.0; 6];
    r.array_f64("twist.twist", &mut twist)?;
    r.array_f64("twist.covariance", &mut cov)?;
    Ok(Odometry {
        header,
        x,
        y,
        theta,
        linear: twist[0],
        angular: twist[5],
        ..Default::default()
    })
}

pub fn encode_odometry_extras(o: &Odometry, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    w.u64(o.header.stamp_ns);
    w.u64(o.header.seq);
    w.f64(o.theta);
    w.u32(o.flags);
    w.u32(o.bumpers);
    w.f32(o.battery_v);
}

pub fn apply_odometry_extras(data: &[u8], o: &mut Odometry) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    let (stamp_ns, seq) = read_stamp_seq(&mut r)?;
    o.header.stamp_ns = stamp_ns;
    o.header.seq = seq;
    o.theta = r.f64("theta")?;
    o.flags = r.u32("flags")?;
    o.bumpers = r.u32("bumpers")?;
    o.battery_v = r.f32("battery_v")?;
    o._reserved = 0;
    Ok(())
}

// ---- geometry_msgs/TwistStamped + smokenav_msgs/StampSeq ---------------------

pub fn encode_twist_stamped(c: &VelocityCommand, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_header(&mut w, c.header.stamp_ns, c.header.frame_id.as_str());
    for v in [c.linear, 0.0, 0.0, 0.0, 0.0, c.angular] {
        w.f64(v);
    }
}

pub fn decode_twist_stamped(data: &[u8]) -> Result<VelocityCommand, CdrError> {
    let mut r = CdrReader::new(data)?;
    let header = read_header(&mut r)?;
    let mut t = [0.0; 6];
    r.array_f64("twist", &mut t)?;
    Ok(VelocityCommand {
        header,
        linear: t[0],
        angular: t[5],
    })
}

// ---- rosgraph_msgs/Clock + smokenav_msgs/StampSeq ----------------------------

pub fn encode_clock(c: &SimClock, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_time(&mut w, c.header.stamp_ns);
}

pub fn decode_clock(data: &[u8]) -> Result<SimClock, CdrError> {
    let mut r = CdrReader::new(data)?;
    let stamp_ns = read_time(&mut r)?;
    Ok(SimClock {
        header: Header::new(stamp_ns, 0, ""),
    })
}

pub fn encode_stamp_seq(h: &Header, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    w.u64(h.stamp_ns);
    w.u64(h.seq);
}

pub fn apply_stamp_seq(data: &[u8], h: &mut Header) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    let (stamp_ns, seq) = read_stamp_seq(&mut r)?;
    h.stamp_ns = stamp_ns;
    h.seq = seq;
    Ok(())
}

// ---- geometry_msgs/PoseStamped + smokenav_msgs/PoseExtras --------------------

pub fn encode_pose_stamped(p: &PoseEstimate, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_header(&mut w, p.header.stamp_ns, p.header.frame_id.as_str());
    write_pose(&mut w, p.x, p.y, p.theta);
}

pub fn decode_pose_stamped(data: &[u8]) -> Result<PoseEstimate, CdrError> {
    let mut r = CdrReader::new(data)?;
    let header = read_header(&mut r)?;
    let (x, y, theta) = read_pose(&mut r)?;
    Ok(PoseEstimate {
        header,
        x,
        y,
        theta,
        ..Default::default()
    })
}

pub fn encode_pose_extras(p: &PoseEstimate, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    w.u64(p.header.stamp_ns);
    w.u64(p.header.seq);
    w.f64(p.theta);
    w.array_f64(&p.covariance);
    w.f32(p.n_eff);
    w.u32(p.particles);
    w.u64(p.scans_skipped);
    w.u32(p.processing_us);
}

pub fn apply_pose_extras(data: &[u8], p: &mut PoseEstimate) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    let (stamp_ns, seq) = read_stamp_seq(&mut r)?;
    p.header.stamp_ns = stamp_ns;
    p.header.seq = seq;
    p.theta = r.f64("theta")?;
    r.array_f64("covariance", &mut p.covariance)?;
    p.n_eff = r.f32("n_eff")?;
    p.particles = r.u32("particles")?;
    p.scans_skipped = r.u64("scans_skipped")?;
    p.processing_us = r.u32("processing_us")?;
    p._reserved = 0;
    Ok(())
}

// ---- nav_msgs/OccupancyGrid + smokenav_msgs/MapExtras ------------------------

pub fn encode_occupancy_grid(info: &MapInfo, cells: &[i8], buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_header(&mut w, info.header.stamp_ns, info.header.frame_id.as_str());
    write_time(&mut w, info.header.stamp_ns); // map_load_time
    w.f32(info.resolution);
    w.u32(info.width);
    w.u32(info.height);
    write_pose(&mut w, info.origin_x, info.origin_y, info.origin_theta);
    w.seq_i8(cells);
}

pub fn decode_occupancy_grid(data: &[u8]) -> Result<(MapInfo, Vec<i8>), CdrError> {
    let mut r = CdrReader::new(data)?;
    let header = read_header(&mut r)?;
    let _load_time = read_time(&mut r)?;
    let resolution = r.f32("info.resolution")?;
    let width = r.u32("info.width")?;
    let height = r.u32("info.height")?;
    let (origin_x, origin_y, origin_theta) = read_pose(&mut r)?;
    let cells = r.seq_bytes("data", MAX_MAP_CELLS)?;
    let expected = width as usize * height as usize;
    if cells.len() != expected {
        return Err(CdrError::WrongLength {
            field: "data",
            got: cells.len(),
            expected,
        });
    }
    let info = MapInfo {
        header,
        resolution,
        width,
        height,
        _reserved: 0,
        origin_x,
        origin_y,
        origin_theta,
    };
    Ok((info, cells.iter().map(|&c| c as i8).collect()))
}

pub fn encode_map_extras(info: &MapInfo, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    w.u64(info.header.stamp_ns);
    w.u64(info.header.seq);
    w.f64(info.origin_theta);
}

pub fn apply_map_extras(data: &[u8], info: &mut MapInfo) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    let (stamp_ns, seq) = read_stamp_seq(&mut r)?;
    info.header.stamp_ns = stamp_ns;
    info.header.seq = seq;
    info.origin_theta = r.f64("origin_theta")?;
    Ok(())
}

// ---- complete smokenav_msgs: SonarRing, SmokeReading, Health -----------------

fn write_full_header(w: &mut CdrWriter, h: &Header) {
    write_header(w, h.stamp_ns, h.frame_id.as_str());
    w.u64(h.stamp_ns);
    w.u64(h.seq);
}

fn read_full_header(r: &mut CdrReader) -> Result<Header, CdrError> {
    let mut h = read_header(r)?;
    let (stamp_ns, seq) = read_stamp_seq(r)?;
    h.stamp_ns = stamp_ns;
    h.seq = seq;
    Ok(h)
}

pub fn encode_sonar_ring(s: &SonarRing, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_full_header(&mut w, &s.header);
    w.f32(s.max_range);
    let readings = s.readings();
    w.seq_len(readings.len());
    for r in readings {
        w.u8(r.index);
        w.u8(r.status);
        w.f32(r.range);
    }
}

pub fn decode_sonar_ring(data: &[u8]) -> Result<SonarRing, CdrError> {
    let mut r = CdrReader::new(data)?;
    let mut ring = SonarRing {
        header: read_full_header(&mut r)?,
        max_range: r.f32("max_range")?,
        ..Default::default()
    };
    let n = r.seq_len("readings", MAX_SONARS, 6)?;
    for slot in &mut ring.readings[..n] {
        let index = r.u8("readings.index")?;
        let status = r.u8("readings.status")?;
        let range = r.f32("readings.range")?;
        *slot = SonarReading {
            range,
            index,
            status,
            _reserved: [0; 2],
        };
    }
    ring.count = n as u32;
    Ok(ring)
}

pub fn encode_smoke_reading(s: &SmokeReading, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_full_header(&mut w, &s.header);
    w.f32(s.raw_mv);
    w.u32(s.raw_counts);
    w.f32(s.level);
    w.f32(s.baseline_mv);
    w.u8(s.trend);
    w.u8(s.state);
}

pub fn decode_smoke_reading(data: &[u8]) -> Result<SmokeReading, CdrError> {
    let mut r = CdrReader::new(data)?;
    Ok(SmokeReading {
        header: read_full_header(&mut r)?,
        raw_mv: r.f32("raw_mv")?,
        raw_counts: r.u32("raw_counts")?,
        level: r.f32("level")?,
        baseline_mv: r.f32("baseline_mv")?,
        trend: r.u8("trend")?,
        state: r.u8("state")?,
        _reserved: [0; 6],
    })
}

pub fn encode_health(h: &Health, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_full_header(&mut w, &h.header);
    w.string(h.role.as_str());
    w.u32(h.pid);
    w.u8(h.state);
    w.f64(h.uptime_s);
    w.f32(h.latency_p50_us);
    w.f32(h.latency_p99_us);
    w.f32(h.latency_max_us);
    w.u64(h.deadline_misses);
    let metrics = h.metrics();
    w.seq_len(metrics.len());
    for m in metrics {
        w.string(m.name.as_str());
        w.f64(m.value);
        w.f64(m.expected);
    }
    w.string(h.last_error.as_str());
}

/// Decodes into `out` (a `Health` is 1.4 kB; callers reuse one).
pub fn decode_health(data: &[u8], out: &mut Health) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    *out = Health::default();
    out.header = read_full_header(&mut r)?;
    out.role = FixedStr::from_str_truncate(r.string("role", ROLE_LEN)?);
    out.pid = r.u32("pid")?;
    out.state = r.u8("state")?;
    out.uptime_s = r.f64("uptime_s")?;
    out.latency_p50_us = r.f32("latency_p50_us")?;
    out.latency_p99_us = r.f32("latency_p99_us")?;
    out.latency_max_us = r.f32("latency_max_us")?;
    out.deadline_misses = r.u64("deadline_misses")?;
    let n = r.seq_len("metrics", MAX_METRICS, 4 + 1 + 16)?;
    for slot in &mut out.metrics[..n] {
        let name = FixedStr::from_str_truncate(r.string("metrics.name", METRIC_NAME_LEN)?);
        *slot = Metric {
            name,
            value: r.f64("metrics.value")?,
            expected: r.f64("metrics.expected")?,
        };
    }
    out.metric_count = n as u32;
    out.last_error = FixedStr::from_str_truncate(r.string("last_error", LAST_ERROR_LEN)?);
    Ok(())
}

// ---- views: tf2_msgs/TFMessage, sensor_msgs/PointCloud2 ----------------------

/// A planar transform `parent → child` for `/tf` and `/tf_static`.
#[derive(Debug, Clone, PartialEq)]
pub struct Transform2<'a> {
    pub stamp_ns: u64,
    pub parent: &'a str,
    pub child: &'a str,
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
}

pub fn encode_tf_message(transforms: &[Transform2], buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    w.seq_len(transforms.len());
    for t in transforms {
        write_header(&mut w, t.stamp_ns, t.parent);
        w.string(t.child);
        w.f64(t.x);
        w.f64(t.y);
        w.f64(0.0);
        for c in yaw_quaternion(t.yaw) {
            w.f64(c);
        }
    }
}

/// One sonar return in the base frame, for the PointCloud2 view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarPoint {
    /// NaN when the reading has no echo or the transducer's pose is unknown.
    pub x: f32,
    pub y: f32,
    pub range: f32,
    pub index: u8,
    pub status: u8,
}

/// Bytes per point: x, y, z, range (float32), index, status (uint8), 2 padding.
pub const SONAR_POINT_STEP: u32 = 20;

pub fn encode_sonar_points(stamp_ns: u64, points: &[SonarPoint], buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_header(&mut w, stamp_ns, BASE_FRAME);
    w.u32(1); // height
    w.u32(points.len() as u32); // width
    const FLOAT32: u8 = 7;
    const UINT8: u8 = 2;
    let fields: [(&str, u32, u8); 6] = [
        ("x", 0, FLOAT32),
        ("y", 4, FLOAT32),
        ("z", 8, FLOAT32),
        ("range", 12, FLOAT32),
        ("index", 16, UINT8),
        ("status", 17, UINT8),
    ];
    w.seq_len(fields.len());
    for (name, offset, datatype) in fields {
        w.string(name);
        w.u32(offset);
        w.u8(datatype);
        w.u32(1);
    }
    w.bool(false); // is_bigendian
    w.u32(SONAR_POINT_STEP);
    w.u32(SONAR_POINT_STEP * points.len() as u32);
    w.seq_len(points.len() * SONAR_POINT_STEP as usize);
    for p in points {
        for v in [p.x, p.y, 0.0, p.range] {
            for b in v.to_le_bytes() {
                w.u8(b);
            }
        }
        w.u8(p.index);
        w.u8(p.status);
        w.u8(0);
        w.u8(0);
    }
    w.bool(false); // is_dense: readings without an echo are NaN points
}

// ---- sensor_msgs/PointCloud2 + smokenav_msgs/VoxelExtras ---------------------

/// Bytes per voxel point: x, y, z (float32).
pub const VOXEL_POINT_STEP: u32 = 12;

pub fn encode_voxel_cloud(c: &VoxelCloud, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    write_header(&mut w, c.header.stamp_ns, c.header.frame_id.as_str());
    let points = c.points();
    w.u32(1); // height
    w.u32(points.len() as u32); // width
    const FLOAT32: u8 = 7;
    w.seq_len(3);
    for (name, offset) in [("x", 0), ("y", 4), ("z", 8)] {
        w.string(name);
        w.u32(offset);
        w.u8(FLOAT32);
        w.u32(1);
    }
    w.bool(false); // is_bigendian
    w.u32(VOXEL_POINT_STEP);
    w.u32(VOXEL_POINT_STEP * points.len() as u32);
    w.seq_len(points.len() * VOXEL_POINT_STEP as usize);
    for v in points.iter().flatten() {
        for b in v.to_le_bytes() {
            w.u8(b);
        }
    }
    w.bool(true); // is_dense: every point is a voxel centre
}

/// Reads a cloud this encoder wrote: x, y, z float32 at offsets 0, 4, 8 of
/// a 12-byte point; any other layout is refused.
pub fn decode_voxel_cloud(data: &[u8], out: &mut VoxelCloud) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    out.header = read_header(&mut r)?;
    let height = r.u32("height")?;
    let width = r.u32("width")?;
    let n_fields = r.seq_len("fields", 3, 13)?;
    if n_fields != 3 {
        return Err(CdrError::InvalidValue {
            field: "fields",
            value: n_fields as u64,
        });
    }
    for (want, offset) in [("x", 0u32), ("y", 4), ("z", 8)] {
        let name = r.string("fields.name", 8)?;
        let off = r.u32("fields.offset")?;
        let datatype = r.u8("fields.datatype")?;
        let count = r.u32("fields.count")?;
        if name != want || off != offset || datatype != 7 || count != 1 {
            return Err(CdrError::InvalidValue {
                field: "fields",
                value: off.into(),
            });
        }
    }
    if r.bool("is_bigendian")? {
        return Err(CdrError::InvalidValue {
            field: "is_bigendian",
            value: 1,
        });
    }
    let step = r.u32("point_step")?;
    let _row_step = r.u32("row_step")?;
    if step != VOXEL_POINT_STEP {
        return Err(CdrError::InvalidValue {
            field: "point_step",
            value: step.into(),
        });
    }
    let n = (height as usize).saturating_mul(width as usize);
    let bytes = r.seq_len("data", MAX_VOXELS * VOXEL_POINT_STEP as usize, 1)?;
    if n > MAX_VOXELS || bytes != n * VOXEL_POINT_STEP as usize {
        return Err(CdrError::TooLong {
            field: "data",
            len: bytes,
            max: MAX_VOXELS * VOXEL_POINT_STEP as usize,
        });
    }
    for p in out.points.iter_mut().take(n) {
        for v in p.iter_mut() {
            let mut b = [0u8; 4];
            for x in &mut b {
                *x = r.u8("data")?;
            }
            *v = f32::from_le_bytes(b);
        }
    }
    out.points[n..].fill([0.0; 3]);
    out.count = n as u32;
    let _dense = r.bool("is_dense")?;
    Ok(())
}

pub fn encode_voxel_extras(c: &VoxelCloud, buf: &mut Vec<u8>) {
    let mut w = CdrWriter::new(buf);
    w.u64(c.header.stamp_ns);
    w.u64(c.header.seq);
    w.f32(c.resolution);
    w.u32(c.truncated);
}

pub fn apply_voxel_extras(data: &[u8], c: &mut VoxelCloud) -> Result<(), CdrError> {
    let mut r = CdrReader::new(data)?;
    let (stamp_ns, seq) = read_stamp_seq(&mut r)?;
    c.header.stamp_ns = stamp_ns;
    c.header.seq = seq;
    c.resolution = r.f32("resolution")?;
    c.truncated = r.u32("truncated")?;
    c._reserved = 0;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamp_of_one_and_a_half_seconds_is_sec_1_nanosec_500000000() {
        assert_eq!(ros_time(1_500_000_000), (1, 500_000_000));
        assert_eq!(time_ns(1, 500_000_000), 1_500_000_000);
        // Beyond 68 years the second saturates; the companion holds the exact value.
        assert_eq!(ros_time(u64::MAX).0, i32::MAX);
    }

    #[test]
    fn yaw_survives_the_quaternion_to_within_rounding() {
        for yaw in [-3.1, -1.0, 0.0, 0.3, 1.5, 3.1] {
            let back = quaternion_yaw(yaw_quaternion(yaw));
            assert!((back - yaw).abs() < 1e-12, "{yaw} -> {back}");
        }
    }

    #[test]
    fn laser_scan_ranges_follow_rep_117_for_beams_without_range() {
        use smokenav_shared_types::BeamReading;
        let mut s = LaserScan {
            header: Header::new(2_000_000_001, 5, "laser"),
            angle_min: -1.0,
            angle_increment: 0.5,
            count: 4,
            range_max: 5.6,
            ..Default::default()
        };
        s.set_beam(0, BeamReading::Range(1.25));
        s.set_beam(1, BeamReading::NoReturn);
        s.set_beam(2, BeamReading::SensorCode(7));
        s.set_beam(3, BeamReading::BeyondMax);
        let mut buf = Vec::new();
        encode_laser_scan(&s, &mut buf);
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(read_time(&mut r).unwrap(), 2_000_000_001);
        assert_eq!(r.string("f", 32).unwrap(), "laser");
        let head: Vec<f32> = (0..7).map(|_| r.f32("x").unwrap()).collect();
        assert_eq!(head[1], 0.5, "angle_max = -1 + 3 × 0.5");
        assert_eq!(r.u32("n").unwrap(), 4);
        let ranges: Vec<f32> = (0..4).map(|_| r.f32("r").unwrap()).collect();
        assert_eq!(ranges[0], 1.25);
        assert_eq!(ranges[1], f32::INFINITY);
        assert!(ranges[2].is_nan());
        assert_eq!(ranges[3], f32::INFINITY);
        assert_eq!(r.u32("intensities").unwrap(), 0);
    }

    #[test]
    fn extras_with_fewer_codes_than_beams_are_rejected() {
        let s = LaserScan {
            count: 3,
            ..Default::default()
        };
        let mut buf = Vec::new();
        encode_laser_scan(&s, &mut buf);
        let mut out = LaserScan::default();
        decode_laser_scan(&buf, &mut out).unwrap();
        let two = LaserScan {
            count: 2,
            ..Default::default()
        };
        encode_scan_extras(&two, &mut buf);
        assert_eq!(
            apply_scan_extras(&buf, &mut out),
            Err(CdrError::WrongLength {
                field: "beam_error",
                got: 2,
                expected: 3
            })
        );
    }

    #[test]
    fn map_with_wrong_cell_count_is_rejected() {
        let info = MapInfo {
            width: 3,
            height: 2,
            ..Default::default()
        };
        let mut buf = Vec::new();
        encode_occupancy_grid(&info, &[0; 5], &mut buf);
        assert_eq!(
            decode_occupancy_grid(&buf).err(),
            Some(CdrError::WrongLength {
                field: "data",
                got: 5,
                expected: 6
            })
        );
    }
}
