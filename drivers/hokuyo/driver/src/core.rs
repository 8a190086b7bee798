//! The pure part of the driver: SCIP frames in, `LaserScan`s out.
//!
//! What is streamed ([`streamed_range`]), how a frame of the stream is told
//! apart from the rest ([`classify_frame`]) and how raw values become a
//! `LaserScan` ([`ScanConverter`]): no port, no bus, no clock (stamps come
//! in as arguments). The simulator's fast path uses the same converter, so
//! its scans follow these rules too. Nothing here allocates after start-up.

use smokenav_hokuyo_codec::{
    ClockSync, Command, DecodeError, Geometry, Reading, ScanEcho, ScanHeader, Status, StatusKind,
    StepRange, SyncStats, parse_reply,
};
use smokenav_platform_runtime::{HealthReporter, Report};
use smokenav_shared_types::Header;
use smokenav_shared_types::laser::{BeamReading, LaserScan, MAX_BEAMS};
use std::time::Duration;

/// Streaming settings.
#[derive(Debug, Clone)]
pub struct StreamConfig {
    /// Ask for intensities (ME) where the model supports them.
    pub intensity: bool,
    /// Scans the sensor skips between transmissions (SCIP interval, 0–9).
    pub skip_scans: u8,
    /// No scan for this long: the device is treated as gone.
    pub stall_timeout: Duration,
    /// Consecutive damaged frames before reconnecting (urg_node uses 4 read failures;
    /// damaged lines on a noisy cable are dropped one by one, so this is higher).
    pub max_consecutive_errors: u32,
}

impl Default for StreamConfig {
    fn default() -> Self {
        StreamConfig {
            intensity: false,
            skip_scans: 0,
            stall_timeout: Duration::from_secs(1),
            max_consecutive_errors: 20,
        }
    }
}

/// Counters for health, cumulative over reconnects.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StreamCounters {
    pub scans_published: u64,
    /// Frames whose line checksums failed (each a lost scan when it was scan data).
    pub checksum_errors: u64,
    /// Frames damaged otherwise (truncated, garbage, wrong count).
    pub damaged_frames: u64,
    /// Frames that were not part of our stream.
    pub stale_frames: u64,
    /// Statuses 21–97: the sensor stopped for an error check or reports trouble.
    pub sensor_errors: u64,
    /// Bytes the frame splitter dropped (oversized garbage).
    pub dropped_bytes: u64,
    /// Frames that carried no scan we could publish (checksum, damaged,
    /// stale, sensor errors): each one a scan lost or a reply not ours.
    pub discarded_frames: u64,
    /// Every byte read and not published: discarded frames, garbage cut
    /// off before a scan's echo, and the splitter's dropped bytes.
    pub discarded_bytes: u64,
    /// Whether a sensor is connected and streaming.
    pub connected: bool,
    /// Sensor-clock synchronisation state.
    pub sync: SyncStats,
}

impl Report for StreamCounters {
    fn report(&self, h: &mut HealthReporter) {
        h.set_metric("scans", self.scans_published as f64);
        h.set_metric("checksum_errors", self.checksum_errors as f64);
        h.set_metric("damaged_frames", self.damaged_frames as f64);
        h.set_metric("stale_frames", self.stale_frames as f64);
        h.set_metric("sensor_errors", self.sensor_errors as f64);
        h.set_metric("dropped_bytes", self.dropped_bytes as f64);
        h.set_metric("discarded_frames", self.discarded_frames as f64);
        h.set_metric("discarded_bytes", self.discarded_bytes as f64);
        h.set_metric("connected", f64::from(u8::from(self.connected)));
        h.set_metric(
            "clock_calibrated",
            f64::from(u8::from(self.sync.calibrated)),
        );
        h.set_metric("clock_drift_ppm", self.sync.drift_ppm);
        h.set_metric("clock_resets", self.sync.resets as f64);
        h.set_metric("clock_wraps", self.sync.wraps as f64);
    }
}

/// The steps the driver streams: every measurable one (AMIN..=AMAX), one
/// value per step.
pub fn streamed_range(g: &Geometry) -> StepRange {
    StepRange {
        start: g.amin as u16,
        end: g.amax as u16,
        cluster: 1,
    }
}

/// Turns decoded raw values into a `LaserScan` in place.
pub struct ScanConverter {
    frame_id: String,
    seq: u64,
    ranges: Box<[u32; MAX_BEAMS]>,
    intensities: Box<[u32; MAX_BEAMS]>,
    scan: Box<LaserScan>,
}

impl ScanConverter {
    pub fn new(frame_id: &str) -> Self {
        ScanConverter {
            frame_id: frame_id.to_string(),
            seq: 0,
            ranges: Box::new([0; MAX_BEAMS]),
            intensities: Box::new([0; MAX_BEAMS]),
            scan: Box::default(),
        }
    }

    /// The raw buffers a scan is decoded into: (ranges, intensities).
    pub fn buffers(&mut self) -> (&mut [u32], &mut [u32]) {
        (&mut self.ranges[..], &mut self.intensities[..])
    }

    /// The last converted scan.
    pub fn scan(&self) -> &LaserScan {
        &self.scan
    }

    /// Fills the scan from the raw values of `h`, geometry from PP, `stamp_ns` for
    /// the scan's sensor timestamp (the rear of the sweep) in host time.
    pub fn convert(&mut self, h: &ScanHeader, g: &Geometry, skip: u8, stamp_ns: u64) -> &LaserScan {
        let n = h.count.min(MAX_BEAMS);
        let cluster = u32::from(h.echo.range.cluster.max(1));
        let start = u32::from(h.echo.range.start);
        let s = &mut *self.scan;
        // Stamp the first beam: the sensor timestamp is taken at the rear (±π).
        let first = stamp_ns + (g.time_from_rear_s(start) * 1e9) as u64;
        s.header = Header::new(first, self.seq, &self.frame_id);
        self.seq += 1;
        s.angle_min = g.step_angle(start) as f32;
        s.angle_increment = (g.step_rad() * f64::from(cluster)) as f32;
        s.time_increment = (g.step_time_s() * f64::from(cluster)) as f32;
        s.scan_time = (g.scan_period_s() * (f64::from(skip) + 1.0)) as f32;
        s.range_min = g.dmin_mm as f32 / 1000.0;
        s.range_max = g.dmax_mm as f32 / 1000.0;
        s.count = n as u32;
        let with_i = h.command == Command::Me;
        s.has_intensities = u32::from(with_i);
        for i in 0..n {
            let reading = match g.classify(self.ranges[i]) {
                Reading::Range(mm) => BeamReading::Range(mm as f32 / 1000.0),
                Reading::BeyondMax(_) => BeamReading::BeyondMax,
                Reading::Code(c) => BeamReading::SensorCode(c as u16),
            };
            s.set_beam(i, reading);
            s.intensities[i] = if with_i {
                self.intensities[i] as f32
            } else {
                0.0
            };
        }
        &self.scan
    }

    /// [`ScanConverter::convert`] for an MD scan of the [`streamed_range`]
    /// whose ranges the caller wrote into [`ScanConverter::buffers`] (no
    /// SCIP frame: the simulator's fast path).
    pub fn convert_streamed(&mut self, g: &Geometry, skip: u8, stamp_ns: u64) -> &LaserScan {
        let range = streamed_range(g);
        let h = ScanHeader {
            command: Command::Md,
            echo: ScanEcho {
                range,
                interval: skip,
                remaining: 0,
            },
            timestamp: 0,
            count: range.value_count(),
        };
        self.convert(&h, g, skip, stamp_ns)
    }
}

/// What one frame of the stream was.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Frame {
    /// A scan, converted (see [`ScanConverter::scan`]).
    Scan,
    Checksum,
    Damaged,
    /// Not part of our stream (a late reply, another request's echo).
    Other,
    SensorError(StatusKind, Status),
}

/// Decodes one frame of the stream started with the echo `head` (its first
/// 13 characters), converting a scan in `conv` stamped through `sync` at
/// `received_ns` (when its last byte was read).
/// Where the reply echoing `head` starts in `frame`: line noise before a
/// scan lands in front of its echo (the splitter cuts on LF LF only), and
/// cutting it off saves the scan instead of losing it.
pub fn reply_start(frame: &[u8], head: &[u8; 13]) -> usize {
    if frame.starts_with(head) {
        return 0;
    }
    frame
        .windows(head.len())
        .position(|w| w == head)
        .unwrap_or(0)
}

pub fn classify_frame(
    frame: &[u8],
    head: &[u8; 13],
    g: &Geometry,
    skip: u8,
    sync: &mut ClockSync,
    conv: &mut ScanConverter,
    received_ns: u64,
) -> Frame {
    let reply = match parse_reply(frame) {
        Ok(r) => r,
        Err(DecodeError::Checksum { .. }) => return Frame::Checksum,
        Err(_) => return Frame::Damaged,
    };
    if reply.echo.line.get(..13) != Some(&head[..]) {
        return Frame::Other;
    }
    match reply.status.kind(reply.echo.command) {
        StatusKind::ScanData => {}
        StatusKind::Ok | StatusKind::Resumed => return Frame::Other,
        kind => return Frame::SensorError(kind, reply.status),
    }
    match reply.decode_scan(&mut conv.ranges[..], &mut conv.intensities[..]) {
        Ok(h) => {
            let stamp = sync.on_scan(h.timestamp, received_ns);
            conv.convert(&h, g, skip, stamp);
            Frame::Scan
        }
        Err(DecodeError::Checksum { .. }) => Frame::Checksum,
        Err(_) => Frame::Damaged,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_hokuyo_codec::{ReplyWriter, parse_reply};

    #[test]
    fn converter_keeps_codes_apart_and_stamps_the_first_beam() {
        let g = Geometry::URG_04LX;
        let values: Vec<u32> = (0..682)
            .map(|i| match i {
                0 => 7,
                1 => 5601,
                i => 1000 + i,
            })
            .collect();
        let mut frame = Vec::new();
        ReplyWriter::new(&mut frame)
            .echo(b"MD0044072501000")
            .status(*b"99")
            .time(5000)
            .data(3, values)
            .end();
        let mut conv = ScanConverter::new("laser");
        let (ranges, intensities) = conv.buffers();
        let h = parse_reply(&frame)
            .unwrap()
            .decode_scan(ranges, intensities)
            .unwrap();
        let s = *conv.convert(&h, &g, 1, 1_000_000_000);
        assert_eq!(s.count, 682);
        assert_eq!(s.beam(0), BeamReading::SensorCode(7));
        assert_eq!(s.beam(1), BeamReading::BeyondMax);
        assert_eq!(s.beam(2), BeamReading::Range(1.002));
        // Step 44 is 16.797 ms after the rear of the sweep.
        assert_eq!(s.header.stamp_ns, 1_000_000_000 + 16_796_875);
        // Skip 1: every second scan, 200 ms apart.
        assert!((s.scan_time - 0.2).abs() < 1e-6);
        assert_eq!(s.header.frame_id.as_str(), "laser");
        assert_eq!(conv.convert(&h, &g, 1, 0).header.seq, 1);
    }

    #[test]
    fn line_noise_before_a_scans_echo_is_cut_off_and_the_scan_kept() {
        let g = Geometry::URG_04LX;
        let mut frame = b"\x07#~?garbage\r".to_vec();
        let noise = frame.len();
        ReplyWriter::new(&mut frame)
            .echo(b"MD0044072500000")
            .status(*b"99")
            .time(0)
            .data(3, (0..682).map(|i| 400 + i))
            .end();
        let mut head = [0u8; 13];
        head.copy_from_slice(&b"MD0044072500000"[..13]);
        let mut sync = ClockSync::new(smokenav_hokuyo_codec::SyncConfig::default());
        let mut conv = ScanConverter::new("laser");
        // Before: the noise hides the echo and the scan is lost.
        assert!(!matches!(
            classify_frame(&frame, &head, &g, 0, &mut sync, &mut conv, 1),
            Frame::Scan
        ));
        let start = reply_start(&frame, &head);
        assert_eq!(start, noise);
        assert!(matches!(
            classify_frame(&frame[start..], &head, &g, 0, &mut sync, &mut conv, 1),
            Frame::Scan
        ));
        // A frame without our echo is left whole (and classified as before).
        assert_eq!(reply_start(b"QT\n00P\n\n", &head), 0);
    }

    #[test]
    fn values_without_a_frame_convert_as_the_streamed_md_scan_does() {
        let g = Geometry::URG_04LX;
        let values: Vec<u32> = (0..682).map(|i| if i == 9 { 3 } else { 400 + i }).collect();
        let mut frame = Vec::new();
        ReplyWriter::new(&mut frame)
            .echo(b"MD0044072500000")
            .status(*b"99")
            .time(0)
            .data(3, values.iter().copied())
            .end();
        let mut from_frame = ScanConverter::new("laser");
        let (r, i) = from_frame.buffers();
        let h = parse_reply(&frame).unwrap().decode_scan(r, i).unwrap();
        let a = *from_frame.convert(&h, &g, 0, 5_000);
        let mut direct = ScanConverter::new("laser");
        for (slot, v) in direct.buffers().0.iter_mut().zip(&values) {
            *slot = *v;
        }
        let b = *direct.convert_streamed(&g, 0, 5_000);
        assert_eq!(a.header, b.header);
        assert_eq!(
            (
                a.angle_min,
                a.angle_increment,
                a.time_increment,
                a.scan_time
            ),
            (
                b.angle_min,
                b.angle_increment,
                b.time_increment,
                b.scan_time
            )
        );
        assert_eq!(
            (a.count, a.range_min, a.range_max),
            (b.count, b.range_min, b.range_max)
        );
        for k in 0..682 {
            assert_eq!(a.beam(k), b.beam(k), "beam {k}");
        }
    }
}
