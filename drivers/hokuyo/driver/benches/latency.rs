//! Driver latency: from the read that delivered a scan's last byte to the
//! `LaserScan` published on the bus (target p99 < 100 µs). The emulator serves a
//! real PTY (URG-04LX, 682-step MD at 10 Hz) and TCP (UTM-30LX-EW, 1081-step ME at
//! 40 Hz); the driver core publishes through a real iceoryx2 publisher with a
//! subscriber attached. `cargo bench -p smokenav-hokuyo-driver --bench latency`.

use hdrhistogram::Histogram;
use smokenav_hokuyo_driver::{
    Driver, DriverConfig, DriverEvent, DriverSink, PortSpec, ScanSink, StreamConfig, StreamCounters,
};
use smokenav_hokuyo_emulator::{BootState, DeviceConfig, Emulator, EmulatorConfig, Model};
use smokenav_platform_bus::{Bus, BusOptions, Publisher, Subscriber, topics};
use smokenav_shared_types::laser::LaserScan;
use smokenav_shared_types::{Clock, MonotonicClock};
use std::sync::Arc;
use std::time::Duration;

struct Bench {
    publisher: Publisher<LaserScan>,
    subscriber: Subscriber<LaserScan>,
    hist: Histogram<u64>,
    /// Read → scan ready (decode, convert, clock sync), without the bus.
    decode_hist: Histogram<u64>,
    want: u64,
    received: u64,
}

impl ScanSink for Bench {
    fn publish(&mut self, scan: &LaserScan, received_ns: u64) {
        let _ = self
            .decode_hist
            .record(MonotonicClock.now_ns().saturating_sub(received_ns));
        self.publisher.publish(scan).expect("publish");
        let ns = MonotonicClock.now_ns().saturating_sub(received_ns);
        let _ = self.hist.record(ns);
    }

    fn idle(&mut self, _: &StreamCounters) -> bool {
        while let Ok(Some(_)) = self.subscriber.receive() {
            self.received += 1;
        }
        self.hist.len() >= self.want
    }
}

impl DriverSink for Bench {
    fn event(&mut self, e: DriverEvent<'_>) {
        if let DriverEvent::Lost(e) = e {
            eprintln!("lost: {e}");
        }
    }
}

fn run(label: &str, emu: &Emulator, intensity: bool, scans: u64, bus: &Bus) {
    let cfg = DriverConfig {
        port: PortSpec::parse(&emu.port()),
        baud: 115_200,
        frame_id: "laser".into(),
        stream: StreamConfig {
            intensity,
            ..StreamConfig::default()
        },
        retry_delay: Duration::from_millis(100),
        tm_samples: 8,
    };
    let mut sink = Bench {
        publisher: bus.publisher(topics::LASER_SCAN).expect("publisher"),
        subscriber: bus.subscriber(topics::LASER_SCAN).expect("subscriber"),
        hist: Histogram::new(3).expect("histogram"),
        decode_hist: Histogram::new(3).expect("histogram"),
        want: scans,
        received: 0,
    };
    Driver::new(cfg, Arc::new(MonotonicClock)).run(&mut sink);
    let h = &sink.hist;
    println!(
        "{label}: last byte read → LaserScan published, {} scans: p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs (target p99 < 100 µs); subscriber got {}",
        h.len(),
        h.value_at_quantile(0.5) as f64 / 1e3,
        h.value_at_quantile(0.99) as f64 / 1e3,
        h.max() as f64 / 1e3,
        sink.received
    );
    let d = &sink.decode_hist;
    println!(
        "{label}:   of which read → scan ready (split, parse, decode, convert, clock sync): p50 {:.1} µs, p99 {:.1} µs",
        d.value_at_quantile(0.5) as f64 / 1e3,
        d.value_at_quantile(0.99) as f64 / 1e3
    );
}

fn main() {
    let instance = format!("hokuyo_latency_{}", std::process::id());
    let bus = Bus::open(&BusOptions::new(&instance, "bench")).expect("bus");
    let dir = std::env::temp_dir().join(format!("hokuyo-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");

    let urg = Emulator::spawn(EmulatorConfig::pty(
        DeviceConfig {
            boot: BootState {
                scip11: Some(false),
                ..Default::default()
            },
            ..Default::default()
        },
        Some(dir.join("urg")),
    ))
    .expect("emulator");
    run("URG-04LX, 682-step MD over a PTY", &urg, false, 150, &bus);
    drop(urg);

    let utm = Emulator::spawn(EmulatorConfig::tcp(DeviceConfig {
        model: Model::Utm30lxEw,
        ..Default::default()
    }))
    .expect("emulator");
    run("UTM-30LX-EW, 1081-step ME over TCP", &utm, true, 400, &bus);
    let _ = std::fs::remove_dir_all(&dir);
}
