//! The reconnecting run loop: open → connect → stream → (lost) → wait → again.

use crate::port::PortSpec;
use crate::session::{SensorInfo, Session, SessionError};
use crate::stream::{ScanConverter, ScanSink, StreamConfig, StreamCounters, stream};
use smokenav_hokuyo_codec::{ClockSync, SyncConfig, SyncStats};
use smokenav_shared_types::Clock;
use std::sync::Arc;
use std::time::Duration;

#[derive(Debug, Clone)]
pub struct DriverConfig {
    pub port: PortSpec,
    /// Wanted serial rate (SS switches an RS-232 04LX to it).
    pub baud: u32,
    pub frame_id: String,
    pub stream: StreamConfig,
    /// Pause between connection attempts.
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
}

pub struct Driver {
    cfg: DriverConfig,
    clock: Arc<dyn Clock>,
    sync: ClockSync,
    conv: ScanConverter,
    pub counters: StreamCounters,
    pub info: Option<SensorInfo>,
}

impl Driver {
    pub fn new(cfg: DriverConfig, clock: Arc<dyn Clock>) -> Self {
        let conv = ScanConverter::new(&cfg.frame_id);
        Driver {
            cfg,
            clock,
            sync: ClockSync::new(SyncConfig::default()),
            conv,
            counters: StreamCounters::default(),
            info: None,
        }
    }

    pub fn sync_stats(&self) -> SyncStats {
        self.sync.stats()
    }

    /// Runs until the sink asks to stop; sends QT on the way out.
    pub fn run(&mut self, sink: &mut dyn DriverSink) {
        let bauds = self.cfg.probe_bauds();
        let mut connected_before = false;
        loop {
            if sink.idle(&self.counters) {
                return;
            }
            if !self.cfg.port.present() {
                self.wait(sink);
                continue;
            }
            let mut session = match Session::open(&self.cfg.port, bauds[0], self.clock.clone()) {
                Ok(s) => s,
                Err(e) => {
                    self.counters.connect_failures += 1;
                    sink.event(DriverEvent::Lost(&e));
                    self.wait(sink);
                    continue;
                }
            };
            let info =
                match session.connect(&bauds, self.cfg.baud, &mut self.sync, self.cfg.tm_samples) {
                    Ok(i) => i,
                    Err(e) => {
                        self.counters.connect_failures += 1;
                        sink.event(DriverEvent::Lost(&e));
                        self.wait(sink);
                        continue;
                    }
                };
            if connected_before {
                self.counters.reconnects += 1;
            }
            connected_before = true;
            self.counters.connected = true;
            self.counters.sync = self.sync.stats();
            sink.event(DriverEvent::Connected(&info));
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
                    sink.event(DriverEvent::Lost(&e));
                    // Best effort: a sensor that still listens should stop streaming.
                    let _ = session.quit();
                    drop(session);
                    self.wait(sink);
                }
            }
        }
    }

    fn wait(&self, sink: &mut dyn DriverSink) {
        // Short sleeps so a stop request is seen promptly.
        let step = Duration::from_millis(50);
        let mut left = self.cfg.retry_delay;
        while !left.is_zero() {
            if sink.idle(&self.counters) {
                return;
            }
            let d = left.min(step);
            std::thread::sleep(d);
            left -= d;
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
