//! `smokenav-hokuyo`: publishes `laser/scan` from a Hokuyo on a serial port or TCP.
//!
//! Thin wiring: the runtime (config, bus, signals, health, systemd) around
//! [`smokenav_hokuyo_driver::Driver`], which owns the port, the codec and reconnects.

use clap::Parser;
use smokenav_hokuyo_driver::{
    Driver, DriverConfig, DriverEvent, DriverSink, ScanSink, StreamCounters,
};
use smokenav_platform_bus::{Publisher, topics};
use smokenav_platform_runtime::{CommonArgs, HealthReporter, Process};
use smokenav_shared_types::laser::LaserScan;
use smokenav_shared_types::{Clock, HealthState, MonotonicClock};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

#[derive(Parser)]
#[command(
    name = "smokenav-hokuyo",
    about = "Hokuyo laser driver: SCIP 2.0 over serial or TCP → laser/scan"
)]
struct Args {
    #[command(flatten)]
    common: CommonArgs,
}

struct BusSink<'a> {
    p: &'a mut Process,
    scans: Publisher<LaserScan>,
    /// Marks one scan on the `scan_hz` rate (`RateId` is not exported by the runtime).
    mark_scan: Box<dyn Fn(&mut HealthReporter)>,
    clock: MonotonicClock,
    port: String,
    connected_once: bool,
    publish_errors: u64,
}

impl ScanSink for BusSink<'_> {
    fn publish(&mut self, scan: &LaserScan, received_ns: u64) {
        if let Err(e) = self.scans.publish(scan) {
            self.publish_errors += 1;
            self.p.health.error(&format!("publishing laser/scan: {e}"));
            return;
        }
        (self.mark_scan)(&mut self.p.health);
        self.p.health.record_latency(Duration::from_nanos(
            self.clock.now_ns().saturating_sub(received_ns),
        ));
    }

    fn idle(&mut self, c: &StreamCounters) -> bool {
        let h = &mut self.p.health;
        h.set_metric("scans", c.scans_published as f64);
        h.set_metric("checksum_errors", c.checksum_errors as f64);
        h.set_metric("damaged_frames", c.damaged_frames as f64);
        h.set_metric("stale_frames", c.stale_frames as f64);
        h.set_metric("sensor_errors", c.sensor_errors as f64);
        h.set_metric("dropped_bytes", c.dropped_bytes as f64);
        h.set_metric("reconnects", c.reconnects as f64);
        h.set_metric("connect_failures", c.connect_failures as f64);
        h.set_metric("connected", f64::from(u8::from(c.connected)));
        h.set_metric("clock_calibrated", f64::from(u8::from(c.sync.calibrated)));
        h.set_metric("clock_drift_ppm", c.sync.drift_ppm);
        h.set_metric("clock_resets", c.sync.resets as f64);
        h.set_metric("clock_wraps", c.sync.wraps as f64);
        h.set_metric("publish_errors", self.publish_errors as f64);
        if let Err(e) = self.p.tick() {
            tracing::warn!("health: {e:#}");
        }
        self.p.shutdown_requested()
    }
}

impl DriverSink for BusSink<'_> {
    fn event(&mut self, event: DriverEvent<'_>) {
        match event {
            DriverEvent::Connected(info) => {
                let g = info.spec.geometry;
                let nominal_hz = f64::from(g.scan_rpm) / 60.0;
                self.p.health.set_metric("scan_hz_nominal", nominal_hz);
                self.p.health.set_metric("steps", g.step_count() as f64);
                let status = format!(
                    "streaming {} firmware {} serial {} on {} ({} steps, {:.0} Hz); STAT: {}",
                    info.spec.model,
                    info.version.firmware,
                    info.version.serial,
                    self.port,
                    g.step_count(),
                    nominal_hz,
                    info.state.stat
                );
                if self.connected_once {
                    self.p.status(&status);
                    tracing::info!("reconnected: {status}");
                } else {
                    self.p.ready(&status);
                    self.connected_once = true;
                }
                self.p.health.set_metric(
                    "sensor_stat_ok",
                    f64::from(u8::from(info.state.is_healthy())),
                );
                if info.state.is_healthy() {
                    self.p.health.set_state(HealthState::Ok);
                    self.p.health.clear_error();
                } else {
                    self.p.health.set_state(HealthState::Degraded);
                    self.p
                        .health
                        .error(&format!("sensor STAT: {}", info.state.stat));
                }
            }
            DriverEvent::Lost(e) => {
                let state = if self.connected_once {
                    HealthState::Degraded
                } else {
                    HealthState::Error
                };
                self.p.health.set_state(state);
                self.p
                    .health
                    .error(&format!("{}: {e}; reconnecting", self.port));
                self.p
                    .status(&format!("waiting for the laser on {}", self.port));
            }
        }
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("hokuyo", &args.common, |p: &mut Process| {
        let section = p.config.laser.clone();
        let cfg = DriverConfig::from_section(&section, p.port_override.as_deref());
        let port = cfg.port.to_string();
        let scans = p.bus.publisher::<LaserScan>(topics::LASER_SCAN)?;
        let rate = p.health.add_rate("scan_hz", None);
        let mark_scan = Box::new(move |h: &mut HealthReporter| h.mark(rate));
        p.status(&format!("connecting to the laser on {port}"));
        let mut sink = BusSink {
            p,
            scans,
            mark_scan,
            clock: MonotonicClock,
            port,
            connected_once: false,
            publish_errors: 0,
        };
        let mut driver = Driver::new(cfg, Arc::new(MonotonicClock));
        driver.run(&mut sink);
        Ok(())
    })
}
