//! Hokuyo end to end: the URG-04LX emulator on a real PTY (in this test process)
//! ↔ the real `smokenav-hokuyo` binary (its own process) ↔ bus subscribers (this
//! process). Scans are checked beam by beam against what the emulator was fed.

use smokenav_hokuyo_emulator::pattern::{check_pattern_scan as check_scan, pattern};
use smokenav_hokuyo_emulator::{BootState, DeviceConfig, Emulator, EmulatorConfig};
use smokenav_platform_bus::{Bus, Subscriber, Waiter, topics};
use smokenav_shared_types::laser::LaserScan;
use smokenav_shared_types::{Health, HealthState};
use smokenav_tests::{Child, bin, open_bus, profile, unique_instance, wait_for};
use std::time::{Duration, Instant};

struct Rig {
    dir: tempfile::TempDir,
    emu: Emulator,
    driver: Option<Child>,
    bus: Bus,
    instance: String,
}

fn emulator(dir: &tempfile::TempDir, device: DeviceConfig) -> Emulator {
    let emu =
        Emulator::spawn(EmulatorConfig::pty(device, Some(dir.path().join("hokuyo")))).unwrap();
    emu.set_scan_source(pattern);
    emu
}

impl Rig {
    fn new(test: &str, device: DeviceConfig) -> Rig {
        let dir = tempfile::tempdir().unwrap();
        let emu = emulator(&dir, device);
        let instance = unique_instance(test);
        let bus = open_bus(&instance);
        Rig {
            dir,
            emu,
            driver: None,
            bus,
            instance,
        }
    }

    fn start_driver(&mut self) {
        // The stable link, as a udev rule would name the device.
        let port = self.emu.port();
        let config = profile(self.dir.path(), "pioneer-3dx.toml", |c| {
            c.laser.port = port.clone()
        });
        let driver = Child::spawn(
            &bin("smokenav-hokuyo"),
            &["--config", &config.to_string_lossy()],
            &self.instance,
        )
        .unwrap();
        self.driver = Some(driver);
    }

    fn output(&self) -> String {
        self.driver.as_ref().map(|d| d.output()).unwrap_or_default()
    }

    fn scans(&self, n: usize, timeout: Duration) -> Vec<LaserScan> {
        let mut got = 0;
        wait_for::<LaserScan>(&self.bus, topics::LASER_SCAN, timeout, |_| {
            got += 1;
            got >= n
        })
        .unwrap_or_else(|e| panic!("{e}\n{}", self.output()))
    }

    fn health(&self, timeout: Duration, done: impl FnMut(&Health) -> bool) -> Health {
        let hs = wait_for::<Health>(&self.bus, topics::health("hokuyo"), timeout, done)
            .unwrap_or_else(|e| panic!("{e}\n{}", self.output()));
        *hs.last().unwrap()
    }
}

#[test]
fn published_scans_match_every_fed_beam_and_stamps_follow_the_sensor_clock() {
    // Power-up state of a URG-04LX: SCIP 1.1. Its clock runs 40 ppm slow.
    let mut rig = Rig::new(
        "hokuyo_every_beam",
        DeviceConfig {
            clock_drift_ppm: 40.0,
            ..Default::default()
        },
    );
    rig.start_driver();
    let scans = rig.scans(30, Duration::from_secs(15));
    let sent = rig.emu.sent_scans();
    let mut ks = Vec::new();
    for s in &scans {
        let k = check_scan(s);
        // First-beam stamp: the scan's true start + 16.797 ms (rear of the sweep to step 44).
        let truth = sent
            .iter()
            .find(|x| x.scan_no % 5000 == k)
            .unwrap()
            .start_host_ns
            + 16_796_875;
        let err = s.header.stamp_ns as i64 - truth as i64;
        assert!(err.abs() < 3_000_000, "scan {k}: stamp off by {err} ns");
        ks.push(k);
    }
    // In order, nothing lost between the driver and this subscriber.
    for w in ks.windows(2) {
        assert_eq!(w[1], w[0] + 1, "{ks:?}");
    }
    let h = rig.health(Duration::from_secs(5), |h| {
        h.metric("scans").unwrap_or(0.0) >= 30.0
    });
    assert_eq!(h.state(), HealthState::Ok);
    assert_eq!(h.metric("clock_calibrated"), Some(1.0));
    assert_eq!(h.metric("checksum_errors"), Some(0.0));
    assert_eq!(h.metric("scan_hz_nominal"), Some(10.0));
    assert_eq!(
        h.metric("sensor_stat_ok"),
        Some(1.0),
        "II STAT: Sensor works well."
    );
    rig.driver
        .as_ref()
        .unwrap()
        .wait_for_line("streaming URG-04LX", Duration::from_secs(1))
        .unwrap();

    // SIGTERM: the driver sends QT and exits cleanly.
    let driver = rig.driver.as_mut().unwrap();
    let status = driver.terminate(Duration::from_secs(5)).unwrap();
    assert!(status.success(), "{status:?}\n{}", driver.output());
    assert!(
        !rig.emu.state().streaming,
        "QT on shutdown stops the stream"
    );
    assert!(rig.emu.command_log().iter().any(|l| l == "QT"));
    assert_eq!(
        rig.emu.stats().me_requests,
        0,
        "ME is never sent to a URG-04LX"
    );
}

#[test]
fn one_percent_corrupted_lines_lose_only_the_corrupted_scans() {
    let rig_dev = DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut rig = Rig::new("hokuyo_corrupt", rig_dev);
    rig.emu.set_corrupt_line_fraction(0.01);
    rig.start_driver();
    let scans = rig.scans(80, Duration::from_secs(30));
    std::thread::sleep(Duration::from_millis(300));
    let ks: Vec<u64> = scans.iter().map(check_scan).collect();
    let (first, last) = (ks[0], *ks.last().unwrap());
    let sent = rig.emu.sent_scans();
    let window: Vec<_> = sent
        .iter()
        .filter(|s| s.scan_no >= first && s.scan_no <= last)
        .collect();
    let clean: Vec<u64> = window
        .iter()
        .filter(|s| !s.damaged)
        .map(|s| s.scan_no)
        .collect();
    let damaged = window.len() - clean.len();
    // 682·3 chars = 32 data lines per scan: 1 % of lines damages ~27 % of scans.
    assert!(damaged >= 5, "only {damaged} damaged scans");
    assert_eq!(ks, clean, "exactly the clean scans are published");
    let h = rig.health(Duration::from_secs(5), |h| {
        h.metric("scans").unwrap_or(0.0) >= 80.0
    });
    let counted = h.metric("checksum_errors").unwrap() + h.metric("damaged_frames").unwrap();
    assert!(
        counted >= damaged as f64,
        "health counts {counted}, {damaged} damaged in the window"
    );
    assert!(counted <= rig.emu.stats().scans_damaged as f64);
    assert_eq!(h.metric("reconnects"), Some(0.0));
    assert!(rig.driver.as_mut().unwrap().is_running());
}

#[test]
fn replugged_laser_resumes_publishing_within_a_second() {
    let mut rig = Rig::new("hokuyo_replug", DeviceConfig::default());
    rig.start_driver();
    rig.scans(5, Duration::from_secs(15));
    let sub: Subscriber<LaserScan> = rig.bus.subscriber(topics::LASER_SCAN).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&sub).unwrap();

    // USB unplug: the device node vanishes; the driver notices and reports it.
    rig.emu.disconnect();
    let h = rig.health(Duration::from_secs(5), |h| {
        h.metric("connected") == Some(0.0)
    });
    assert_eq!(h.state(), HealthState::Degraded);
    std::thread::sleep(Duration::from_millis(500));
    while sub.receive().unwrap().is_some() {}

    // Plugged back in: a power-cycled 04LX (SCIP 1.1 again) behind the same link.
    rig.emu.reconnect(true);
    let back = Instant::now();
    let first = loop {
        if let Some(s) = sub.receive().unwrap() {
            break *s;
        }
        assert!(
            back.elapsed() < Duration::from_secs(3),
            "no scan after replug\n{}",
            rig.output()
        );
        waiter.wait(Some(Duration::from_millis(100))).unwrap();
    };
    let took = back.elapsed();
    check_scan(&first);
    assert!(
        took < Duration::from_secs(1),
        "publishing resumed {took:?} after the device returned"
    );
    let h = rig.health(Duration::from_secs(5), |h| {
        h.metric("reconnects") == Some(1.0)
    });
    assert_eq!(h.state(), HealthState::Ok);
    assert_eq!(rig.emu.stats().power_cycles, 1);
}

#[test]
fn sensor_left_streaming_at_startup_is_recovered() {
    let mut rig = Rig::new(
        "hokuyo_left_streaming",
        DeviceConfig {
            boot: BootState {
                streaming: true,
                ..Default::default()
            },
            ..Default::default()
        },
    );
    // A previous run left MD going: scans pile up in the port before the driver opens it.
    std::thread::sleep(Duration::from_millis(400));
    assert!(rig.emu.state().streaming);
    rig.start_driver();
    let scans = rig.scans(10, Duration::from_secs(15));
    for s in &scans {
        check_scan(s);
    }
    let log = rig.emu.command_log();
    assert_eq!(
        log.iter().filter(|l| l.starts_with("MD")).count(),
        1,
        "{log:?}"
    );
    assert!(
        log.first().is_some_and(|l| l == "QT"),
        "QT stops the stale stream first: {log:?}"
    );
}

#[test]
fn scip_decode_cli_prints_one_json_object_per_reply() {
    let vectors = smokenav_tests::workspace_root().join("drivers/hokuyo/codec/tests/vectors");
    let run = |file: &str| {
        std::process::Command::new(bin("smokenav"))
            .args(["scip", "decode", &vectors.join(file).to_string_lossy()])
            .output()
            .unwrap()
    };
    let out = run("D_ug01_gd_full.txt");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 1);
    let scan = &lines[0]["scan"];
    assert_eq!(lines[0]["command"], "GD");
    assert_eq!(scan["timestamp_ms"], 11_149_560);
    assert_eq!(scan["ranges_m"].as_array().unwrap().len(), 682);
    // 53 zeros, 24 sixes and 8 sevens in the UG01 capture are codes, not ranges.
    assert_eq!(scan["errors"].as_array().unwrap().len(), 85);

    let vv_pp_ii = run("A_wiki_vv_pp_ii.txt");
    assert!(vv_pp_ii.status.success());
    let text = String::from_utf8(vv_pp_ii.stdout).unwrap();
    assert_eq!(text.lines().count(), 3);
    assert!(text.contains("\"STAT\":\"Sensor works well.\""), "{text}");

    // The spec's PP with OCR-damaged checksums: printed with its error, exit status 1.
    let damaged = run("C_spec_pp.txt");
    assert_eq!(damaged.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&damaged.stdout).contains("checksum expected"));
}

fn streaming_rig(test: &str) -> Rig {
    let dev = DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    };
    let mut rig = Rig::new(test, dev);
    rig.start_driver();
    rig.scans(5, Duration::from_secs(15));
    rig
}

/// Issue #22 point 5: 1000 B/s of line noise (100 bytes before every scan)
/// is counted byte for byte, and cutting it off keeps the scans.
#[test]
fn line_noise_at_1000_bytes_per_s_is_counted_and_scans_keep_their_rate() {
    let rig = streaming_rig("hokuyo_noise");
    // Line noise without LF (an LF pair would make a frame of its own,
    // counted too, but leading LFs are skipped without a count).
    let mut x = 0x2545_f491_u32;
    let mut noise = [0u8; 100];
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(3) {
        for b in &mut noise {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            *b = match (x >> 24) as u8 {
                b'\n' => b'#',
                v => v,
            };
        }
        rig.emu.inject_garbage(&noise);
        std::thread::sleep(Duration::from_millis(100));
    }
    let injected = rig.emu.stats().garbage_bytes as f64;
    assert!(injected >= 2500.0, "injected {injected} bytes");
    let h = rig.health(Duration::from_secs(5), |h| {
        h.metric("discarded_bytes").unwrap_or(0.0) >= injected
    });
    let hz = h.metric("scan_hz").unwrap();
    eprintln!(
        "{injected} B of noise in 3 s: discarded_bytes {}, discarded_frames {}, scan_hz {hz:.1}",
        h.metric("discarded_bytes").unwrap(),
        h.metric("discarded_frames").unwrap()
    );
    assert!(hz >= 8.0, "scan rate under noise {hz} Hz\n{}", rig.output());
    assert_eq!(h.state(), HealthState::Ok, "{}", h.last_error.as_str());
}

/// Issue #22 point 5: 2 % of lines corrupted loses about half the scans;
/// health goes `degraded` (rate below 80 % of the sensor's 10 Hz),
/// `smokenav status` says so with exit 1, and it recovers with the rate.
#[test]
fn lost_scans_turn_health_degraded_and_status_fails_until_the_rate_recovers() {
    let rig = streaming_rig("hokuyo_lost");
    rig.health(Duration::from_secs(5), |h| h.state() == HealthState::Ok);
    rig.emu.set_corrupt_line_fraction(0.02);
    let h = rig.health(Duration::from_secs(8), |h| {
        h.state() == HealthState::Degraded
    });
    let hz = h.metric("scan_hz").unwrap();
    eprintln!(
        "degraded at scan_hz {hz:.1} (expected {:?}), discarded_frames {}: {}",
        h.metrics()
            .iter()
            .find(|m| m.name.as_str() == "scan_hz")
            .map(|m| m.expected),
        h.metric("discarded_frames").unwrap(),
        h.last_error.as_str()
    );
    assert!(hz < 8.0, "degraded at {hz} Hz");
    assert!(h.last_error.as_str().contains("scan_hz"));
    assert!(h.metric("discarded_frames").unwrap() >= 1.0);
    let out = std::process::Command::new(bin("smokenav"))
        .args(["status", "--json", "--roles", "hokuyo"])
        .env("SMOKENAV_INSTANCE", &rig.instance)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    let v: serde_json::Value = serde_json::from_str(text.trim())
        .unwrap_or_else(|e| panic!("{e}: {text} {}", String::from_utf8_lossy(&out.stderr)));
    assert_eq!(v["processes"][0]["status"], "degraded", "{v}");
    assert!(!out.status.success(), "exit 0 while degraded: {v}");
    rig.emu.set_corrupt_line_fraction(0.0);
    let h = rig.health(Duration::from_secs(5), |h| h.state() == HealthState::Ok);
    assert!(
        h.last_error.as_str().is_empty(),
        "{}",
        h.last_error.as_str()
    );
}
