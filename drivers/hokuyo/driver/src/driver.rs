//! The reconnecting run loop: open → connect → stream → (lost) → back off → again.

use crate::core::{
    Frame, ScanConverter, StreamConfig, StreamCounters, classify_frame, reply_start, streamed_range,
};
use crate::link::PortSpec;
use crate::session::{SensorInfo, Session, SessionError, use_intensity};
use smokenav_hokuyo_codec::{
    ClockSync, Command, Request, StatusKind, SyncConfig, SyncStats, parse_reply,
};
use smokenav_platform_runtime::{Reconnect, ReconnectPolicy};
use smokenav_shared_types::Clock;
use smokenav_shared_types::laser::LaserScan;
use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct DriverConfig {
    pub port: PortSpec,
    /// Wanted serial rate (SS switches an RS-232 04LX to it).
    pub baud: u32,
    pub frame_id: String,
    pub stream: StreamConfig,
    /// First pause between connection attempts (it doubles up to 500 ms).
    pub retry_delay: Duration,
    /// TM1 exchanges per clock calibration.
    pub tm_samples: usize,
}

impl DriverConfig {
    /// From the `[laser]` section; `port` overrides the configured device.
    pub fn from_section(s: &smokenav_platform_config::LaserSection, port: Option<&str>) -> Self {
        DriverConfig {
            port: PortSpec::parse(port.unwrap_or(&s.port)),
            baud: s.baud,
            frame_id: s.frame_id.clone(),
            stream: StreamConfig {
                intensity: s.intensity,
                skip_scans: s.skip_scans.min(9) as u8,
                stall_timeout: Duration::from_secs_f64(s.stall_timeout_s),
                ..StreamConfig::default()
            },
            retry_delay: Duration::from_millis(200),
            tm_samples: 10,
        }
    }

    /// Rates to probe: the wanted one first, then the 04LX's power-up 19200, then the rest.
    pub fn probe_bauds(&self) -> Vec<u32> {
        let mut v = vec![self.baud];
        for b in [19_200, 115_200, 57_600] {
            if !v.contains(&b) {
                v.push(b);
            }
        }
        v
    }

    /// Retry after `retry_delay`, doubling to 500 ms: a replugged sensor is
    /// streaming again within a second.
    pub fn reconnect_policy(&self) -> ReconnectPolicy {
        ReconnectPolicy::new(self.retry_delay, Duration::from_millis(500))
    }
}

/// Where scans go, and how the loop learns it should stop.
pub trait ScanSink {
    /// Publishes one scan; `received_ns` is when its last byte was read.
    fn publish(&mut self, scan: &LaserScan, received_ns: u64);
    /// Called after every read (at least every 100 ms): health upkeep; true = stop.
    fn idle(&mut self, counters: &StreamCounters) -> bool;
}

/// What the loop tells its owner besides scans.
#[derive(Debug)]
pub enum DriverEvent<'a> {
    Connected(&'a SensorInfo),
    /// The link failed or could not be set up; the loop retries.
    Lost(&'a SessionError),
}

pub trait DriverSink: ScanSink {
    fn event(&mut self, event: DriverEvent<'_>);
    /// The link's state after every change (up, an attempt failed, lost), for health.
    fn link(&mut self, _link: &Reconnect) {}
}

pub struct Driver {
    cfg: DriverConfig,
    clock: Arc<dyn Clock>,
    sync: ClockSync,
    conv: ScanConverter,
    link: Reconnect,
    pub counters: StreamCounters,
    pub info: Option<SensorInfo>,
}

impl Driver {
    pub fn new(cfg: DriverConfig, clock: Arc<dyn Clock>) -> Self {
        let conv = ScanConverter::new(&cfg.frame_id);
        let link = Reconnect::new(cfg.reconnect_policy(), clock.now_ns());
        Driver {
            cfg,
            clock,
            sync: ClockSync::new(SyncConfig::default()),
            conv,
            link,
            counters: StreamCounters::default(),
            info: None,
        }
    }

    pub fn sync_stats(&self) -> SyncStats {
        self.sync.stats()
    }

    /// The link to the sensor: up or down, opens, failures, losses.
    pub fn link(&self) -> &Reconnect {
        &self.link
    }

    fn failed(&mut self, e: &SessionError, sink: &mut dyn DriverSink) {
        self.link.open_failed(self.clock.now_ns(), e);
        sink.event(DriverEvent::Lost(e));
        sink.link(&self.link);
    }

    /// Runs until the sink asks to stop; sends QT on the way out.
    pub fn run(&mut self, sink: &mut dyn DriverSink) {
        let bauds = self.cfg.probe_bauds();
        sink.link(&self.link);
        loop {
            if sink.idle(&self.counters) {
                return;
            }
            if !self.link.due(self.clock.now_ns()) {
                self.wait(sink);
                continue;
            }
            if !self.cfg.port.present() {
                // A USB device node that vanished: nothing to open until it is back.
                self.link
                    .open_failed(self.clock.now_ns(), "no such device (unplugged?)");
                sink.link(&self.link);
                continue;
            }
            let mut session = match Session::open(&self.cfg.port, bauds[0], self.clock.clone()) {
                Ok(s) => s,
                Err(e) => {
                    self.failed(&e, sink);
                    continue;
                }
            };
            let info =
                match session.connect(&bauds, self.cfg.baud, &mut self.sync, self.cfg.tm_samples) {
                    Ok(i) => i,
                    Err(e) => {
                        self.failed(&e, sink);
                        continue;
                    }
                };
            self.link.opened(self.clock.now_ns());
            self.counters.connected = true;
            self.counters.sync = self.sync.stats();
            sink.event(DriverEvent::Connected(&info));
            sink.link(&self.link);
            let result = stream(
                &mut session,
                &info,
                &self.cfg.stream,
                &mut self.sync,
                &mut self.conv,
                &mut self.counters,
                sink,
            );
            self.counters.stale_frames += session.counters.stale_frames;
            self.counters.connected = false;
            self.info = Some(info);
            match result {
                Ok(()) => {
                    if let Err(e) = session.quit() {
                        tracing::warn!("QT on shutdown: {e}");
                    }
                    return;
                }
                Err(e) => {
                    self.link.lost(self.clock.now_ns(), &e);
                    sink.event(DriverEvent::Lost(&e));
                    sink.link(&self.link);
                    // Best effort: a sensor that still listens should stop streaming.
                    let _ = session.quit();
                }
            }
        }
    }

    /// Sleeps until the next attempt is due, in short steps so a stop request is seen promptly.
    fn wait(&self, sink: &mut dyn DriverSink) {
        let step = Duration::from_millis(50);
        loop {
            let left = self.link.wait(self.clock.now_ns());
            if left.is_zero() || sink.idle(&self.counters) {
                return;
            }
            std::thread::sleep(left.min(step));
        }
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
        range: streamed_range(&g),
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
        while let Some(whole) = session.splitter.next_frame() {
            let start = reply_start(whole, &head);
            counters.discarded_bytes += start as u64;
            let frame = &whole[start..];
            let kind = classify_frame(frame, &head, &g, cfg.skip_scans, sync, conv, received_ns);
            if !matches!(kind, Frame::Scan) {
                counters.discarded_frames += 1;
                counters.discarded_bytes += frame.len() as u64;
            }
            match kind {
                Frame::Scan => {
                    consecutive_errors = 0;
                    last_scan = received_ns;
                    counters.scans_published += 1;
                    counters.sync = sync.stats();
                    sink.publish(conv.scan(), received_ns);
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
        counters.discarded_bytes += dropped - seen_dropped;
        seen_dropped = dropped;
        if consecutive_errors >= cfg.max_consecutive_errors {
            return Err(SessionError::TooManyErrors(consecutive_errors));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probe_order_is_wanted_rate_then_04lx_power_up_rate() {
        let cfg = DriverConfig {
            port: PortSpec::parse("/dev/hokuyo"),
            baud: 57_600,
            frame_id: "laser".into(),
            stream: StreamConfig::default(),
            retry_delay: Duration::from_millis(200),
            tm_samples: 10,
        };
        assert_eq!(cfg.probe_bauds(), vec![57_600, 19_200, 115_200]);
        assert_eq!(
            DriverConfig {
                baud: 19_200,
                ..cfg
            }
            .probe_bauds(),
            vec![19_200, 115_200, 57_600]
        );
    }

    #[test]
    fn tcp_ports_are_recognised() {
        assert_eq!(
            PortSpec::parse("tcp://192.0.2.10:10940"),
            PortSpec::Tcp("192.0.2.10:10940".into())
        );
        assert_eq!(PortSpec::parse("/dev/ttyACM0").to_string(), "/dev/ttyACM0");
    }
}
