//! `smokenav-hokuyo`: publishes `laser/scan` from a Hokuyo on a serial port or TCP.
//!
//! Thin wiring: the runtime (config, bus, signals, health, systemd) around
//! [`smokenav_hokuyo_driver::Driver`], which owns the port, the codec and reconnects.

use clap::Parser;
use smokenav_hokuyo_driver::{
    Driver, DriverConfig, DriverEvent, DriverSink, ScanSink, StreamCounters,
};
use smokenav_platform_bus::{Publisher, topics};
use smokenav_platform_runtime::{CommonArgs, Process, RateId, Reconnect, Report};
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
    scan_rate: RateId,
    port: String,
    link: Option<Reconnect>,
    connected_once: bool,
    publish_errors: u64,
    /// Scans the sensor skips between transmissions (sets the expected rate).
    skip_scans: u8,
}

impl ScanSink for BusSink<'_> {
    fn publish(&mut self, scan: &LaserScan, received_ns: u64) {
        if let Err(e) = self.scans.publish(scan) {
            self.publish_errors += 1;
            self.p.health.error(&format!("publishing laser/scan: {e}"));
            return;
        }
        self.p.health.mark(self.scan_rate);
        self.p.health.record_latency(Duration::from_nanos(
            MonotonicClock.now_ns().saturating_sub(received_ns),
        ));
    }

    fn idle(&mut self, counters: &StreamCounters) -> bool {
        let h = &mut self.p.health;
        counters.report(h);
        if let Some(link) = &self.link {
            link.report(h, &self.port, MonotonicClock.now_ns());
        }
        h.set_metric("publish_errors", self.publish_errors as f64);
        if let Err(e) = self.p.tick() {
            tracing::warn!("health: {e:#}");
        }
        self.p.shutdown_requested()
    }
}

impl DriverSink for BusSink<'_> {
    fn event(&mut self, event: DriverEvent<'_>) {
        let info = match event {
            DriverEvent::Connected(info) => info,
            DriverEvent::Lost(_) => {
                self.p
                    .status(&format!("waiting for the laser on {}", self.port));
                return;
            }
        };
        let g = info.spec.geometry;
        let nominal_hz = f64::from(g.scan_rpm) / 60.0;
        // The sensor sends one scan in every `skip_scans + 1`.
        let expected_hz = nominal_hz / (1.0 + f64::from(self.skip_scans));
        let h = &mut self.p.health;
        h.set_metric("scan_hz_nominal", nominal_hz);
        h.set_expected_rate(self.scan_rate, Some(expected_hz));
        h.set_metric("steps", g.step_count() as f64);
        h.set_metric(
            "sensor_stat_ok",
            f64::from(u8::from(info.state.is_healthy())),
        );
        if info.state.is_healthy() {
            h.set_state(HealthState::Ok);
        } else {
            h.set_state(HealthState::Degraded);
            h.error(&format!("sensor STAT: {}", info.state.stat));
        }
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
    }

    fn link(&mut self, link: &Reconnect) {
        self.link = Some(link.clone());
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    smokenav_platform_runtime::main("hokuyo", &args.common, |p: &mut Process| {
        let cfg = DriverConfig::from_section(&p.config.laser, p.port_override.as_deref());
        let port = cfg.port.to_string();
        let scans = p.bus.publisher::<LaserScan>(topics::LASER_SCAN)?;
        // Expected rate set once the sensor states its speed.
        let scan_rate = p.health.add_rate("scan_hz", None);
        let skip_scans = cfg.stream.skip_scans;
        p.status(&format!("connecting to the laser on {port}"));
        let mut sink = BusSink {
            p,
            scans,
            scan_rate,
            port,
            link: None,
            connected_once: false,
            publish_errors: 0,
            skip_scans,
        };
        Driver::new(cfg, Arc::new(MonotonicClock)).run(&mut sink);
        Ok(())
    })
}
