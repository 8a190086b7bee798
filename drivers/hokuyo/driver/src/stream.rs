//! The streaming hot path: bytes → frames → scans → published `LaserScan`s.
//! After start-up nothing here allocates: fixed buffers, reused scan.

use crate::session::{SensorInfo, Session, SessionError, use_intensity};
use smokenav_hokuyo_codec::{
    ClockSync, Command, DecodeError, Geometry, ModelFamily, Reading, Request, ScanHeader,
    StatusKind, StepRange, SyncStats, parse_reply,
};
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
    /// Successful connections after the first.
    pub reconnects: u64,
    /// Attempts to open or set up the sensor that failed.
    pub connect_failures: u64,
    /// Whether a sensor is connected and streaming.
    pub connected: bool,
    /// Sensor-clock synchronisation state.
    pub sync: SyncStats,
}

/// Where scans go, and how the loop learns it should stop.
pub trait ScanSink {
    /// Publishes one scan; `received_ns` is when its last byte was read.
    fn publish(&mut self, scan: &LaserScan, received_ns: u64);
    /// Called after every read (at least every 100 ms): health upkeep; true = stop.
    fn idle(&mut self, counters: &StreamCounters) -> bool;
}

/// Turns decoded raw values into a `LaserScan` in place.
pub struct ScanConverter {
    frame_id: String,
    seq: u64,
    pub(crate) ranges: Box<[u32; MAX_BEAMS]>,
    pub(crate) intensities: Box<[u32; MAX_BEAMS]>,
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
}

/// Starts MD (or ME) over the full measurable range and publishes scans until the
/// sink says stop (`Ok`) or the link fails (`Err`: the caller reconnects).
pub fn stream(
    session: &mut Session,
    info: &SensorInfo,
    cfg: &StreamConfig,
    sync: &mut ClockSync,
    conv: &mut ScanConverter,
    counters: &mut StreamCounters,
    sink: &mut dyn ScanSink,
) -> Result<(), SessionError> {
    let g = info.spec.geometry;
    let command = if use_intensity(cfg.intensity, &info.spec) {
        Command::Me
    } else {
        Command::Md
    };
    let req = Request::Stream {
        command,
        range: StepRange {
            start: g.amin as u16,
            end: g.amax as u16,
            cluster: 1,
        },
        interval: cfg.skip_scans.min(9),
        count: 0,
    };
    let ack = parse_reply(session.transact(&req, Duration::from_secs(1))?)?;
    if !ack.status.is_ok() {
        let (c, st) = (ack.echo.command, ack.status);
        return Err(SessionError::Status {
            command: c,
            status: st,
            meaning: st.meaning(c),
        });
    }
    // Data echoes match the request on their first 13 characters.
    let mut head = [0u8; 13];
    head.copy_from_slice(ack.echo.line.get(..13).unwrap_or(&[0; 13]));
    tracing::info!(model = %info.spec.model, %command, "streaming");

    let clock = session.clock.clone();
    let stall_ns = cfg.stall_timeout.as_nanos() as u64;
    let mut last_scan = clock.now_ns();
    let mut consecutive_errors = 0u32;
    let mut seen_dropped = session.splitter.stats().discarded_bytes;
    loop {
        if sink.idle(counters) {
            return Ok(());
        }
        let now = clock.now_ns();
        if now.saturating_sub(last_scan) > stall_ns {
            return Err(SessionError::Stalled(cfg.stall_timeout));
        }
        let wait = Duration::from_nanos((last_scan + stall_ns).saturating_sub(now))
            .min(Duration::from_millis(100));
        let n = session.port.read_timeout(session.splitter.spare(), wait)?;
        let received_ns = clock.now_ns();
        session.splitter.commit(n);
        while let Some(frame) = session.splitter.next_frame() {
            let outcome = handle_frame(frame, &head, &g, cfg.skip_scans, sync, conv, received_ns);
            match outcome {
                Frame::Scan => {
                    consecutive_errors = 0;
                    last_scan = received_ns;
                    counters.scans_published += 1;
                    counters.sync = sync.stats();
                    sink.publish(&conv.scan, received_ns);
                }
                Frame::Checksum => {
                    consecutive_errors += 1;
                    counters.checksum_errors += 1;
                }
                Frame::Damaged => {
                    consecutive_errors += 1;
                    counters.damaged_frames += 1;
                }
                Frame::Other => counters.stale_frames += 1,
                Frame::SensorError(kind, status) => {
                    counters.sensor_errors += 1;
                    if kind == StatusKind::HardwareFault {
                        return Err(SessionError::Hardware {
                            command,
                            status,
                            meaning: status.meaning(command),
                        });
                    }
                    tracing::warn!("sensor status {status}: {}", status.meaning(command));
                }
            }
        }
        let dropped = session.splitter.stats().discarded_bytes;
        counters.dropped_bytes += dropped - seen_dropped;
        seen_dropped = dropped;
        if consecutive_errors >= cfg.max_consecutive_errors {
            return Err(SessionError::TooManyErrors(consecutive_errors));
        }
    }
}

enum Frame {
    Scan,
    Checksum,
    Damaged,
    Other,
    SensorError(StatusKind, smokenav_hokuyo_codec::Status),
}

fn handle_frame(
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

/// The model family from PP, for logs.
pub fn family(info: &SensorInfo) -> ModelFamily {
    info.spec.family()
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_hokuyo_codec::{ReplyWriter, parse_reply};

    #[test]
    fn converter_keeps_codes_apart_and_stamps_the_first_beam() {
        let g = Geometry {
            dmin_mm: 20,
            dmax_mm: 5600,
            ares: 1024,
            amin: 44,
            amax: 725,
            afrt: 384,
            scan_rpm: 600,
        };
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
        let h = parse_reply(&frame)
            .unwrap()
            .decode_scan(&mut conv.ranges[..], &mut conv.intensities[..])
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
}
