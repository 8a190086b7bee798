//! SmokeNav fusion end to end: this test process publishes constructed laser
//! scans, sonar rings and smoke readings on the bus at 10 Hz; the real
//! `smokenav-fusion` binary (its own process) fuses them; the fused scans and
//! the health reports are checked here, and the fused scans are compared with
//! an offline replay of exactly the published inputs (`smokenav fuse`'s library).

use smokenav_algorithms_fusion::offline::fuse_jsonl;
use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_algorithms_fusion::testkit::{Room, smoke_reading, smoky_scan};
use smokenav_platform_bus::{Bus, Publisher, Subscriber, Waiter, topics};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::record::{FusedScanRecord, Message, TopicRecord};
use smokenav_shared_types::{
    FusedScan, FusionMethod, Health, HealthState, LaserScan, SmokeReading, SmokeSensorState,
    SmokeTrend, SonarRing, SyncState,
};
use smokenav_tests::{Child, bin, open_bus, profile, unique_instance, wait_for};
use std::path::PathBuf;
use std::time::{Duration, Instant};

const CYCLE: Duration = Duration::from_millis(100);
const MS: u64 = 1_000_000;

struct Rig {
    _dir: tempfile::TempDir,
    cfg_path: PathBuf,
    cfg: RobotConfig,
    fusion: Child,
    bus: Bus,
    laser: Publisher<LaserScan>,
    sonar: Publisher<SonarRing>,
    smoke: Publisher<SmokeReading>,
    fused: Subscriber<FusedScan>,
    /// Every input as published (with the seq the bus gave it), as `topic echo --json` prints it.
    recording: Vec<String>,
}

fn record(topic: &str, message: Message) -> String {
    serde_json::to_string(&TopicRecord {
        topic: topic.into(),
        message,
    })
    .unwrap()
}

impl Rig {
    fn start(test: &str, method: FusionMethod) -> Rig {
        let dir = tempfile::tempdir().unwrap();
        let cfg_path = profile(dir.path(), "pioneer-3dx.toml", |c| {
            c.fusion.method = method;
            c.bus.health_period_s = 0.2;
        });
        let cfg = RobotConfig::load(&cfg_path).unwrap();
        let instance = unique_instance(test);
        let fusion = Child::spawn(
            &bin("smokenav-fusion"),
            &["--config", cfg_path.to_str().unwrap()],
            &instance,
        )
        .unwrap();
        fusion
            .wait_for_line("fusing", Duration::from_secs(30))
            .unwrap();
        let bus = open_bus(&instance);
        let fused = bus.subscriber::<FusedScan>(topics::FUSION_SCAN).unwrap();
        let laser = bus.publisher::<LaserScan>(topics::LASER_SCAN).unwrap();
        let sonar = bus.publisher::<SonarRing>(topics::BASE_SONAR).unwrap();
        let smoke = bus.publisher::<SmokeReading>(topics::SMOKE_LEVEL).unwrap();
        for c in [
            laser.update_connections(),
            sonar.update_connections(),
            smoke.update_connections(),
        ] {
            c.unwrap();
        }
        Rig {
            _dir: dir,
            cfg_path,
            cfg,
            fusion,
            bus,
            laser,
            sonar,
            smoke,
            fused,
            recording: Vec::new(),
        }
    }

    /// One 10 Hz cycle: laser stamped 2 ms ago, sonar 1 ms ago, smoke now.
    /// `dense`: smoke in front of the laser (0.5 m, uniform) and level 250.
    /// Returns the laser scan as published.
    fn publish_cycle(&mut self, k: u64, dense: bool, with_sonar: bool) -> LaserScan {
        let t = monotonic_now_ns();
        let room = Room::default();
        let mut scan = if dense {
            smoky_scan(t - 2 * MS, k)
        } else {
            room.scan(t - 2 * MS, k)
        };
        scan.header.seq = self.laser.publish(&scan).unwrap();
        self.recording
            .push(record("laser/scan", Message::LaserScan((&scan).into())));
        if with_sonar {
            let pipeline = FusionPipeline::from_config(&self.cfg, None).unwrap();
            let mut ring = room.ring(
                pipeline.engine().geometry(),
                self.cfg.sonar.cone_deg / 2.0,
                t - MS,
                k,
            );
            ring.header.seq = self.sonar.publish(&ring).unwrap();
            self.recording
                .push(record("base/sonar", Message::SonarRing((&ring).into())));
        }
        let mut reading = smoke_reading(t, k, if dense { 250.0 } else { 0.0 }, SmokeTrend::Rising);
        reading.header.seq = self.smoke.publish(&reading).unwrap();
        self.recording.push(record(
            "smoke/level",
            Message::SmokeReading((&reading).into()),
        ));
        scan
    }

    /// Receives fused scans for `d`.
    fn collect(&self, d: Duration, into: &mut Vec<FusedScan>) {
        let waiter = Waiter::new().unwrap();
        let _g = waiter.attach(&self.fused).unwrap();
        let end = Instant::now() + d;
        loop {
            while let Some(s) = self.fused.receive().unwrap() {
                into.push(*s);
            }
            let now = Instant::now();
            if now >= end {
                return;
            }
            waiter.wait(Some(end - now)).unwrap();
        }
    }

    /// Publishes `n` cycles at 10 Hz and returns (published scans, fused scans).
    fn run(
        &mut self,
        n: u64,
        dense: impl Fn(u64) -> bool,
        with_sonar: bool,
    ) -> (Vec<LaserScan>, Vec<FusedScan>) {
        let (mut sent, mut got) = (Vec::new(), Vec::new());
        for k in 0..n {
            let next = Instant::now() + CYCLE;
            sent.push(self.publish_cycle(k, dense(k), with_sonar));
            self.collect(next.saturating_duration_since(Instant::now()), &mut got);
        }
        let end = Instant::now() + Duration::from_secs(5);
        while got.len() < sent.len() && Instant::now() < end {
            self.collect(Duration::from_millis(100), &mut got);
        }
        (sent, got)
    }
}

/// The fused scan without the sequence number the fusion publisher assigned.
fn comparable(f: &FusedScan) -> FusedScanRecord {
    let mut r = FusedScanRecord::from(f);
    r.scan.header.seq = 0;
    r
}

fn bits(s: &LaserScan) -> (Vec<u32>, Vec<u16>) {
    let n = s.len();
    (
        s.ranges[..n].iter().map(|r| r.to_bits()).collect(),
        s.beam_error[..n].to_vec(),
    )
}

#[test]
fn dense_smoke_sections_use_the_sonar_and_a_replay_gives_the_same_scans() {
    let mut rig = Rig::start("fusion_e2e_v2", FusionMethod::V2);
    let smoky = |k: u64| (10..20).contains(&k);
    let (sent, got) = rig.run(30, smoky, true);
    assert_eq!(got.len(), sent.len(), "one fused scan per laser scan");
    for (k, (f, s)) in got.iter().zip(&sent).enumerate() {
        let k = k as u64;
        assert_eq!(
            f.scan.header.stamp_ns, s.header.stamp_ns,
            "scan {k}: in order, none lost"
        );
        assert_eq!(f.sync_state(), SyncState::Complete, "scan {k}");
        assert_eq!(f.sections().len(), 8, "the P3-DX's 8 front sonars");
        if smoky(k) {
            // The laser sees a phantom wall at 0.5 m; every section takes the
            // sonar's arc (the room's walls are 1.3–2.3 m away) and the
            // uncovered beams are dropped, so nothing of the phantom remains.
            assert!(
                f.sections()
                    .iter()
                    .all(|d| d.source() == smokenav_shared_types::SectionSource::Sonar),
                "scan {k}"
            );
            assert_eq!(f.sonar_usage(), 1.0);
            let ranges: Vec<f32> = (0..f.scan.len())
                .filter_map(|i| f.scan.beam(i).range())
                .collect();
            assert!(
                ranges.len() > 8 * 30,
                "sonar arcs painted: {}",
                ranges.len()
            );
            assert!(
                ranges.iter().all(|&r| r > 1.0),
                "no phantom wall left in scan {k}"
            );
        } else {
            assert_eq!(
                bits(&f.scan),
                bits(s),
                "clean scan {k} must be the laser, bit for bit"
            );
            assert_eq!(f.sonar_usage(), 0.0);
        }
    }

    // Replay: the same inputs through the offline pipeline give the same fused scans.
    let cfg = RobotConfig::load(&rig.cfg_path).unwrap();
    let mut pipeline = FusionPipeline::from_config(&cfg, None).unwrap();
    let mut out = Vec::new();
    let input = rig.recording.join("\n");
    let report = fuse_jsonl(&mut pipeline, input.as_bytes(), &mut out, |b| {
        panic!("bad line {}: {}", b.line, b.error)
    })
    .unwrap();
    assert_eq!(report.written, 30);
    let replayed: Vec<FusedScanRecord> = String::from_utf8(out)
        .unwrap()
        .lines()
        .map(
            |l| match serde_json::from_str::<TopicRecord>(l).unwrap().message {
                Message::FusedScan(mut f) => {
                    f.scan.header.seq = 0;
                    f
                }
                other => panic!("{other:?}"),
            },
        )
        .collect();
    let live: Vec<FusedScanRecord> = got.iter().map(comparable).collect();
    assert_eq!(
        live, replayed,
        "the process and the offline replay must agree exactly"
    );

    // Health: method v2, a third of the sections used the sonar, nothing dropped.
    let h = wait_for::<Health>(
        &rig.bus,
        topics::health("fusion"),
        Duration::from_secs(5),
        |h: &Health| h.metric("fused_total") == Some(30.0),
    )
    .unwrap();
    let h = h.last().unwrap();
    assert_eq!(h.metric("method"), Some(2.0));
    assert!((h.metric("sonar_usage").unwrap() - 1.0 / 3.0).abs() < 1e-9);
    assert_eq!(h.metric("sync_drops"), Some(0.0));
    // Ok, or degraded only because the output rate fell when the test stopped
    // feeding (health compares it with the expected 10 Hz).
    match h.state() {
        HealthState::Ok => {}
        HealthState::Degraded => assert!(
            h.last_error.as_str().contains("fused_hz"),
            "degraded: {}",
            h.last_error.as_str()
        ),
        other => panic!("fusion health {other:?}: {}", h.last_error.as_str()),
    }
    rig.fusion.terminate(Duration::from_secs(5)).unwrap();
}

#[test]
fn silent_sonar_degrades_to_the_laser_alone_and_health_says_so() {
    let mut rig = Rig::start("fusion_e2e_silent", FusionMethod::V1);
    let (sent, got) = rig.run(15, |_| true, false);
    // Held until the sonar has been silent for the 0.5 s timeout, then every
    // scan goes out as the laser alone, untouched despite the dense smoke.
    assert_eq!(got.len(), sent.len());
    for (f, s) in got.iter().zip(&sent) {
        assert_eq!(f.sync_state(), SyncState::LaserOnly);
        assert_eq!(bits(&f.scan), bits(s));
        assert_eq!(f.sonar_usage(), 0.0);
    }
    let h = wait_for::<Health>(
        &rig.bus,
        topics::health("fusion"),
        Duration::from_secs(5),
        |h: &Health| h.state() == HealthState::Degraded,
    )
    .unwrap();
    let h = h.last().unwrap();
    assert_eq!(
        h.metric("sync_state"),
        Some(f64::from(SyncState::LaserOnly as u8))
    );
    assert!(
        h.last_error.as_str().contains("sonar silent"),
        "{}",
        h.last_error.as_str()
    );
    // The sonar comes back: complete sets again.
    let (_, got) = rig.run(5, |_| false, true);
    assert!(
        got.last()
            .is_some_and(|f| f.sync_state() == SyncState::Complete),
        "{:?}",
        got.iter().map(|f| f.sync_state()).collect::<Vec<_>>()
    );
    rig.fusion.terminate(Duration::from_secs(5)).unwrap();
}

/// A corridor (10 × 2 m) with a smoke front 0.6 m ahead: a phantom wall over
/// ±0.3 rad the laser sees and the sonars do not. The scan keeps a wide
/// spread (real side and end walls), so only the sonar witness can catch it.
const PHANTOM_M: f32 = 0.6;
const PHANTOM_HALF_RAD: f64 = 0.3;

impl Rig {
    /// One 10 Hz cycle of the phantom wall; `smoke`: the sensor state to
    /// publish (level 0), or `None` for a sensor that sends nothing.
    fn publish_phantom_cycle(&mut self, k: u64, smoke: Option<SmokeSensorState>) {
        let t = monotonic_now_ns();
        let corridor = Room {
            half_x: 5.0,
            half_y: 3.0,
        };
        let scan = smokenav_algorithms_fusion::testkit::urg_scan(t - 2 * MS, k, |_, a| {
            if a.abs() < PHANTOM_HALF_RAD {
                PHANTOM_M
            } else {
                corridor.range(0.0, 0.0, a) as f32
            }
        });
        self.laser.publish(&scan).unwrap();
        let pipeline = FusionPipeline::from_config(&self.cfg, None).unwrap();
        let ring = corridor.ring(
            pipeline.engine().geometry(),
            self.cfg.sonar.cone_deg / 2.0,
            t - MS,
            k,
        );
        self.sonar.publish(&ring).unwrap();
        if let Some(state) = smoke {
            let mut reading = smoke_reading(t, k, 0.0, SmokeTrend::Steady);
            reading.state = state as u8;
            self.smoke.publish(&reading).unwrap();
        }
    }

    /// Publishes `n` phantom cycles; returns the fused scans and, if health
    /// degraded meanwhile, how long after the first cycle it was seen.
    fn run_phantom(
        &mut self,
        n: u64,
        smoke: Option<SmokeSensorState>,
    ) -> (Vec<FusedScan>, Option<Duration>) {
        let health = self
            .bus
            .subscriber::<Health>(topics::health("fusion"))
            .unwrap();
        let started = Instant::now();
        let mut degraded = None;
        let mut got = Vec::new();
        for k in 0..n {
            let next = Instant::now() + CYCLE;
            self.publish_phantom_cycle(k, smoke);
            self.collect(next.saturating_duration_since(Instant::now()), &mut got);
            while let Some(h) = health.receive().unwrap() {
                if degraded.is_none()
                    && h.state() == HealthState::Degraded
                    && h.metric("smoke_silent") == Some(1.0)
                {
                    degraded = Some(started.elapsed());
                }
            }
        }
        (got, degraded)
    }
}

/// The nearest range the fused scan reports within the phantom's sector.
fn nearest_ahead(f: &FusedScan) -> f32 {
    let s = &f.scan;
    (0..s.len())
        .filter(|&i| {
            let a = f64::from(s.angle_min) + i as f64 * f64::from(s.angle_increment);
            a.abs() < PHANTOM_HALF_RAD - 0.05
        })
        .filter_map(|i| s.beam(i).range())
        .fold(f32::INFINITY, f32::min)
}

/// `sync_state`: what the output must say (no reading at all: `NoSmoke`; a
/// reading of a sensor that is not ready still completes the set).
fn check_phantom_removed(
    test: &str,
    smoke: Option<SmokeSensorState>,
    sync_state: SyncState,
    expect_error: &str,
) {
    let mut rig = Rig::start(test, FusionMethod::V2);
    let (got, degraded) = rig.run_phantom(25, smoke);
    // The first sets wait for the synchroniser's timeout on a silent topic.
    let settled: Vec<&FusedScan> = got.iter().skip(got.len().saturating_sub(10)).collect();
    assert!(settled.len() >= 5, "{} fused scans", got.len());
    for f in &settled {
        eprintln!(
            "{test}: sync {} spread {:.2} m, nearest ahead {:.2} m, sonar usage {:.2}",
            f.sync_state().as_str(),
            f.laser_spread,
            nearest_ahead(f),
            f.sonar_usage()
        );
        assert_eq!(f.sync_state(), sync_state);
        assert!(
            nearest_ahead(f) > PHANTOM_M + 0.3,
            "the phantom wall at {PHANTOM_M} m survived: {:.2} m",
            nearest_ahead(f)
        );
    }
    let degraded = degraded.expect("health never said the smoke sensor is silent");
    eprintln!(
        "{test}: health degraded {:.2} s after the first cycle",
        degraded.as_secs_f64()
    );
    let h = wait_for::<Health>(
        &rig.bus,
        topics::health("fusion"),
        Duration::from_secs(5),
        |h: &Health| h.state() == HealthState::Degraded,
    )
    .unwrap();
    let h = h.last().unwrap();
    assert_eq!(h.metric("smoke_silent"), Some(1.0));
    assert!(
        h.last_error.as_str().contains(expect_error)
            && h.last_error.as_str().contains("sonar witness on"),
        "{}",
        h.last_error.as_str()
    );
    rig.fusion.terminate(Duration::from_secs(5)).unwrap();
}

#[test]
fn silent_smoke_sensor_keeps_the_sonar_witness_on_and_health_says_so() {
    // Nothing on smoke/level: after the sync timeout v2 fuses laser and sonar
    // assuming smoke; before, it fell back to the laser alone (phantom kept).
    check_phantom_removed(
        "fusion_e2e_smoke_silent",
        None,
        SyncState::NoSmoke,
        "smoke silent",
    );
}

#[test]
fn disconnected_smoke_sensor_keeps_the_sonar_witness_on_and_health_says_so() {
    // Readings flow but the sensor flags itself disconnected: its level is
    // unusable, so the witness must not read it as clean air.
    check_phantom_removed(
        "fusion_e2e_smoke_disconnected",
        Some(SmokeSensorState::Disconnected),
        SyncState::Complete,
        "smoke sensor not ready",
    );
}
