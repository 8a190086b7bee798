//! The driver core (handshake, streaming, reconnect) against the emulator on a
//! real pseudo-terminal. The bus is not involved here: tests/tests/hokuyo_e2e.rs
//! in the workspace covers the full process chain.

use smokenav_hokuyo_codec::{ClockSync, SyncConfig};
use smokenav_hokuyo_driver::{
    Driver, DriverConfig, DriverEvent, DriverSink, PortSpec, ScanSink, Session, StreamConfig,
    StreamCounters,
};
use smokenav_hokuyo_emulator::pattern::{check_pattern_scan as check_scan, pattern};
use smokenav_hokuyo_emulator::{BootState, DeviceConfig, Emulator, EmulatorConfig, Link, Model};
use smokenav_shared_types::laser::LaserScan;
use smokenav_shared_types::{Clock, MonotonicClock};
use std::sync::Arc;
use std::time::{Duration, Instant};

type Until = Box<dyn FnMut(&Collect, &StreamCounters) -> bool>;

struct Collect {
    /// (k, stamp_ns, seq)
    scans: Vec<(u64, u64, u64)>,
    events: Vec<String>,
    until: Until,
    deadline: Instant,
}

impl Collect {
    fn new(
        timeout: Duration,
        until: impl FnMut(&Collect, &StreamCounters) -> bool + 'static,
    ) -> Self {
        Collect {
            scans: vec![],
            events: vec![],
            until: Box::new(until),
            deadline: Instant::now() + timeout,
        }
    }
}

impl ScanSink for Collect {
    fn publish(&mut self, scan: &LaserScan, _received_ns: u64) {
        let k = check_scan(scan);
        self.scans.push((k, scan.header.stamp_ns, scan.header.seq));
    }

    fn idle(&mut self, c: &StreamCounters) -> bool {
        let mut until = std::mem::replace(&mut self.until, Box::new(|_, _| true));
        let stop = until(self, c) || Instant::now() > self.deadline;
        self.until = until;
        stop
    }
}

impl DriverSink for Collect {
    fn event(&mut self, e: DriverEvent<'_>) {
        self.events.push(match e {
            DriverEvent::Connected(i) => format!("connected {} {:?}", i.spec.model, i.recovered),
            DriverEvent::Lost(e) => format!("lost {e}"),
        });
    }
}

fn emulator(device: DeviceConfig) -> (Emulator, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::spawn(EmulatorConfig::pty(device, Some(dir.path().join("urg")))).unwrap();
    emu.set_scan_source(pattern);
    (emu, dir)
}

fn config(port: &str) -> DriverConfig {
    DriverConfig {
        port: PortSpec::parse(port),
        baud: 115_200,
        frame_id: "laser".into(),
        stream: StreamConfig::default(),
        retry_delay: Duration::from_millis(100),
        tm_samples: 8,
    }
}

fn driver(emu: &Emulator) -> Driver {
    Driver::new(config(&emu.port()), Arc::new(MonotonicClock))
}

#[test]
fn scip11_04lx_is_switched_and_streams_every_beam_stamped_by_the_sensor_clock() {
    // 50 ppm drift, and the 24-bit timer wraps about 1 s after power-up.
    let (emu, _d) = emulator(DeviceConfig {
        clock_drift_ppm: 50.0,
        sensor_time_start_ms: 16_776_000,
        ..Default::default()
    });
    let mut drv = driver(&emu);
    let mut sink = Collect::new(Duration::from_secs(10), |c, _| c.scans.len() >= 25);
    drv.run(&mut sink);
    assert!(sink.scans.len() >= 25, "{:?}", sink.events);
    assert!(
        sink.events[0].contains("from_scip11: true"),
        "{:?}",
        sink.events
    );
    // Consecutive scans: k and seq step by one (nothing lost).
    for w in sink.scans.windows(2) {
        assert_eq!(w[1].0, w[0].0 + 1);
        assert_eq!(w[1].2, w[0].2 + 1);
    }
    // First-beam stamp = true start of the sweep + 16.797 ms (rear to step 44).
    let sent = emu.sent_scans();
    for &(k, stamp, _) in &sink.scans {
        let truth = sent
            .iter()
            .find(|s| s.scan_no % 5000 == k)
            .unwrap()
            .start_host_ns
            + 16_796_875;
        let err = stamp as i64 - truth as i64;
        assert!(err.abs() < 3_000_000, "scan {k}: stamp off by {err} ns");
    }
    assert_eq!(drv.sync_stats().wraps, 1);
    // QT on the way out; a 04LX is never asked for ME.
    std::thread::sleep(Duration::from_millis(100));
    assert!(!emu.state().streaming);
    assert_eq!(emu.stats().me_requests, 0);
    assert!(!emu.command_log().iter().any(|l| l.starts_with("ME")));
}

#[test]
fn sensor_left_streaming_is_stopped_and_restarted() {
    let (emu, _d) = emulator(DeviceConfig {
        boot: BootState {
            streaming: true,
            ..Default::default()
        },
        ..Default::default()
    });
    // Let it stream into the PTY before the driver opens it.
    std::thread::sleep(Duration::from_millis(350));
    let mut drv = driver(&emu);
    let mut sink = Collect::new(Duration::from_secs(10), |c, _| c.scans.len() >= 5);
    drv.run(&mut sink);
    assert_eq!(sink.scans.len(), 5, "{:?}", sink.events);
    assert_eq!(sink.events.len(), 1, "{:?}", sink.events);
    assert!(sink.events[0].starts_with("connected"), "{:?}", sink.events);
}

#[test]
fn sensor_stuck_in_time_adjust_mode_is_released_with_tm2() {
    let (emu, _d) = emulator(DeviceConfig {
        boot: BootState {
            time_adjust: true,
            ..Default::default()
        },
        ..Default::default()
    });
    let mut drv = driver(&emu);
    let mut sink = Collect::new(Duration::from_secs(10), |c, _| c.scans.len() >= 3);
    drv.run(&mut sink);
    assert_eq!(sink.scans.len(), 3);
    assert!(
        sink.events[0].contains("from_time_adjust: true"),
        "{:?}",
        sink.events
    );
}

#[test]
fn rs232_04lx_is_found_at_19200_and_switched_to_115200() {
    let (emu, _d) = emulator(DeviceConfig {
        link: Link::Rs232,
        ..Default::default()
    });
    let mut drv = driver(&emu);
    let mut sink = Collect::new(Duration::from_secs(10), |c, _| c.scans.len() >= 3);
    drv.run(&mut sink);
    assert_eq!(sink.scans.len(), 3, "{:?}", sink.events);
    assert_eq!(emu.state().baud, 115_200);
    // The first probe at 115200 went unheard.
    assert!(emu.stats().bytes_at_wrong_baud > 0);
    assert_eq!(drv.info.as_ref().unwrap().baud, 115_200);
}

#[test]
fn one_percent_corrupted_lines_lose_only_the_damaged_scans() {
    let (emu, _d) = emulator(DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    });
    emu.set_corrupt_line_fraction(0.01);
    let mut drv = driver(&emu);
    let mut sink = Collect::new(Duration::from_secs(15), |c, _| c.scans.len() >= 60);
    drv.run(&mut sink);
    std::thread::sleep(Duration::from_millis(50));
    let sent = emu.sent_scans();
    let (first, last) = (sink.scans[0].0, sink.scans.last().unwrap().0);
    let window: Vec<_> = sent
        .iter()
        .filter(|s| s.scan_no >= first && s.scan_no <= last)
        .collect();
    let damaged = window.iter().filter(|s| s.damaged).count() as u64;
    let clean: Vec<u64> = window
        .iter()
        .filter(|s| !s.damaged)
        .map(|s| s.scan_no)
        .collect();
    let published: Vec<u64> = sink.scans.iter().map(|s| s.0).collect();
    // 32 data lines per scan at 1 % each damage about 27 % of the scans.
    assert!(damaged > 0);
    assert_eq!(
        published, clean,
        "every clean scan published, no damaged one"
    );
    let counted = drv.counters.checksum_errors + drv.counters.damaged_frames;
    assert!(
        counted >= damaged && counted <= emu.stats().scans_damaged,
        "{counted} counted, {damaged} damaged"
    );
    assert_eq!(drv.link().counters().reconnects(), 0);
}

#[test]
fn unplug_and_replug_resumes_within_a_second_of_the_return() {
    let (emu, _d) = emulator(DeviceConfig::default());
    let mut drv = driver(&emu);
    let emu = Arc::new(emu);
    let e2 = emu.clone();
    let mut phase = 0;
    let mut replugged_at: Option<Instant> = None;
    let resumed = Arc::new(std::sync::Mutex::new(None::<Duration>));
    let r2 = resumed.clone();
    let mut sink = Collect::new(Duration::from_secs(15), move |c, _| {
        match phase {
            0 if c.scans.len() >= 5 => {
                e2.disconnect();
                phase = 1;
            }
            1 if c.events.iter().any(|e| e.starts_with("lost")) => {
                std::thread::sleep(Duration::from_millis(400));
                e2.reconnect(true);
                replugged_at = Some(Instant::now());
                phase = 2;
            }
            2 if c.scans.len() >= 6 => {
                *r2.lock().unwrap() = replugged_at.map(|t| t.elapsed());
                return true;
            }
            _ => {}
        }
        false
    });
    drv.run(&mut sink);
    let took = resumed.lock().unwrap().expect("publishing resumed");
    assert!(
        took < Duration::from_secs(1),
        "resumed {took:?} after the device returned"
    );
    assert_eq!(drv.link().counters().reconnects(), 1);
    // The replugged 04LX came back in SCIP 1.1 and was switched again.
    assert!(
        sink.events.last().unwrap().contains("from_scip11: true"),
        "{:?}",
        sink.events
    );
}

#[test]
fn utm30lx_over_tcp_streams_me_with_its_own_geometry() {
    let emu = Emulator::spawn(EmulatorConfig::tcp(DeviceConfig {
        model: Model::Utm30lxEw,
        ..Default::default()
    }))
    .unwrap();
    let cfg = DriverConfig {
        stream: StreamConfig {
            intensity: true,
            ..StreamConfig::default()
        },
        ..config(&emu.port())
    };
    let mut drv = Driver::new(cfg, Arc::new(MonotonicClock));
    struct Utm(Vec<LaserScan>);
    impl ScanSink for Utm {
        fn publish(&mut self, s: &LaserScan, _: u64) {
            self.0.push(*s);
        }
        fn idle(&mut self, _: &StreamCounters) -> bool {
            self.0.len() >= 3
        }
    }
    impl DriverSink for Utm {
        fn event(&mut self, _: DriverEvent<'_>) {}
    }
    let mut sink = Utm(vec![]);
    drv.run(&mut sink);
    let s = &sink.0[2];
    assert_eq!(s.count, 1081);
    assert_eq!(s.has_intensities, 1);
    assert_eq!(s.intensities[0], 1000.0);
    // UTM-30LX-EW: step 0 at (0 − 540)·2π/1440 = −3π/4; 2400 rpm = 25 ms per scan.
    assert!((f64::from(s.angle_min) + 0.75 * std::f64::consts::PI).abs() < 1e-6);
    assert!((s.scan_time - 0.025).abs() < 1e-6);
    assert!(emu.command_log().iter().any(|l| l.starts_with("ME")));
}

#[test]
fn calibration_offset_matches_the_emulated_sensor_clock() {
    let (emu, _d) = emulator(DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        sensor_time_start_ms: 1234,
        ..Default::default()
    });
    let clock: Arc<dyn Clock> = Arc::new(MonotonicClock);
    let mut s = Session::open(&PortSpec::parse(&emu.port()), 115_200, clock.clone()).unwrap();
    let mut sync = ClockSync::new(SyncConfig::default());
    let before = clock.now_ns();
    let sensor_before = emu.sensor_ms();
    let est = s.calibrate(&mut sync, 10).unwrap();
    // host = sensor·10⁶ + offset: the emulator's timer read `sensor_before` at about `before`.
    let predicted = i64::from(sensor_before) * 1_000_000 + est.offset_ns;
    assert!(
        (predicted - before as i64).abs() < 3_000_000,
        "offset off by {} ns",
        predicted - before as i64
    );
    assert!(est.round_trip_ns < 20_000_000);
}

#[test]
fn absent_sensor_is_retried_with_a_growing_back_off() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("urg");
    let mut drv = Driver::new(
        DriverConfig {
            retry_delay: Duration::from_millis(200),
            ..config(&missing.to_string_lossy())
        },
        Arc::new(MonotonicClock),
    );
    let mut sink = Collect::new(Duration::from_millis(1300), |_, _| false);
    drv.run(&mut sink);
    // Attempts at 0, 0.2, 0.6 and 1.1 s (waits of 200, 400, 500 ms): a fixed
    // 200 ms retry would have made 7.
    let link = drv.link();
    assert!(!link.is_up());
    assert_eq!(link.counters().failures, 4, "{:?}", link.counters());
    assert!(link.reason().unwrap().contains("no such device"));
    assert!(sink.scans.is_empty());
}
