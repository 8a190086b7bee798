//! The Hokuyo driver library against the URG-04LX emulator on a real
//! pseudo-terminal, with no bus: the emulator boots in SCIP 1.1 as a real
//! sensor does, the driver switches it to SCIP 2.0, calibrates the sensor
//! clock, streams, and hands every `LaserScan` to a sink; this sink prints
//! five and stops the driver (which sends QT on the way out).

use smokenav_hokuyo_driver::{
    Driver, DriverConfig, DriverEvent, DriverSink, PortSpec, ScanSink, StreamConfig, StreamCounters,
};
use smokenav_hokuyo_emulator::pattern::pattern;
use smokenav_hokuyo_emulator::{DeviceConfig, Emulator, EmulatorConfig};
use smokenav_shared_types::{LaserScan, MonotonicClock};
use std::sync::Arc;
use std::time::Duration;

struct Print {
    scans: usize,
}

impl ScanSink for Print {
    fn publish(&mut self, scan: &LaserScan, _received_ns: u64) {
        self.scans += 1;
        let valid = scan.ranges[..scan.len()]
            .iter()
            .filter(|r| r.is_finite())
            .count();
        println!(
            "scan {} from {}: {} beams ({valid} valid) over {:.1}°",
            scan.header.seq,
            scan.header.frame_id.as_str(),
            scan.len(),
            (scan.angle_increment * scan.len() as f32).to_degrees()
        );
    }

    /// Called between reads: returning true stops the driver.
    fn idle(&mut self, _counters: &StreamCounters) -> bool {
        self.scans >= 5
    }
}

impl DriverSink for Print {
    fn event(&mut self, e: DriverEvent<'_>) {
        match e {
            DriverEvent::Connected(info) => println!("connected to a {}", info.spec.model),
            DriverEvent::Lost(reason) => println!("lost the sensor: {reason}"),
        }
    }
}

fn main() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let emu = Emulator::spawn(EmulatorConfig::pty(
        DeviceConfig::default(),
        Some(dir.path().join("hokuyo")),
    ))?;
    emu.set_scan_source(pattern);
    let cfg = DriverConfig {
        port: PortSpec::parse(&emu.port()),
        baud: 115_200,
        frame_id: "laser".into(),
        stream: StreamConfig::default(),
        retry_delay: Duration::from_millis(100),
        tm_samples: 8,
    };
    let mut driver = Driver::new(cfg, Arc::new(MonotonicClock));
    let mut sink = Print { scans: 0 };
    driver.run(&mut sink);
    println!("done: {} scans", sink.scans);
    Ok(())
}
