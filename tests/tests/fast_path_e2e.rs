//! The simulator's fast path against the real drivers, message by message.
//!
//! One world (the Pioneer in the corridor) feeds both: the fast path
//! (`DirectDrivers`: the drivers' own cores, no emulators, no processes) and,
//! through sim/link's base emulator and the URG-04LX emulator on real PTYs,
//! the REAL `smokenav-hokuyo` and `smokenav-pioneer` processes.
//!
//! What "the same" means. Stamps differ (the processes stamp with their host
//! clock, the fast path with sim time), and so do sequence numbers. Values
//! are compared for the same simulated instant: the world is held still at
//! instant t (the emulators keep reporting its state at t) until the real
//! drivers have published from it, and their last messages must equal the
//! fast path's messages for t:
//! * `LaserScan`: every field but the stamp and seq, exactly (layout, every
//!   beam's range or code);
//! * `SonarRing`: every reading (index, range, status) and the cap, exactly;
//! * `Odometry`: flags, bumpers, battery, velocities and frame exactly; the
//!   pose equal in the controller's own units (whole counts of its
//!   DistConvFactor and AngleConvFactor) and within 1e-9 in SI. The Pioneer
//!   driver integrates SIP counter deltas (to survive the 15-bit wrap); the
//!   held robot reports each instant's counters to it once, the fast path
//!   sees a SIP every 100 ms, so the same integer sum is added up in a
//!   different grouping and may differ in the last bits of a float.

use smokenav_hokuyo_emulator::{DeviceConfig, Emulator, EmulatorConfig};
use smokenav_platform_bus::{Bus, Subscriber, topics};
use smokenav_shared_types::{Health, HealthState, LaserScan, MonotonicClock, Odometry, SonarRing};
use smokenav_sim_link::base::BaseEmulator;
use smokenav_sim_link::{DirectDrivers, DirectMessage};
use smokenav_sim_world::laser::URG_STEPS;
use smokenav_sim_world::{Scenario, SonarSample, World};
use smokenav_tests::{Child, bin, open_bus, unique_instance, wait_for};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const MS: u64 = 1_000_000;
/// The held instants, sim ns.
const INSTANTS: [u64; 4] = [1000 * MS, 2000 * MS, 3000 * MS, 4000 * MS];
/// How long the world is held at each: several scans, SIPs and rings.
const HOLD: Duration = Duration::from_millis(900);
/// Messages younger than this after the feed may still carry the last instant.
const SETTLE: Duration = Duration::from_millis(450);

/// The newest message of a topic that arrived at least `SETTLE` after `fed`.
fn settled<T: smokenav_platform_bus::Message>(sub: &Subscriber<T>, fed: Instant) -> Option<T> {
    let mut last = None;
    while let Some(m) = sub.receive().unwrap() {
        if fed.elapsed() >= SETTLE {
            last = Some(*m);
        }
    }
    last
}

fn assert_same_scan(real: &LaserScan, fast: &LaserScan, t: u64) {
    let (mut a, mut b) = (*real, *fast);
    for s in [&mut a, &mut b] {
        s.header.stamp_ns = 0;
        s.header.seq = 0;
    }
    assert_eq!(a.header, b.header, "t {t}");
    assert_eq!(
        (
            a.angle_min,
            a.angle_increment,
            a.time_increment,
            a.scan_time
        ),
        (
            b.angle_min,
            b.angle_increment,
            b.time_increment,
            b.scan_time
        ),
        "t {t}"
    );
    assert_eq!(
        (a.range_min, a.range_max, a.count, a.has_intensities),
        (b.range_min, b.range_max, b.count, b.has_intensities),
        "t {t}"
    );
    for i in 0..a.len() {
        assert_eq!(a.beam(i), b.beam(i), "t {t} beam {i}");
        assert_eq!(a.intensities[i], b.intensities[i], "t {t} beam {i}");
    }
}

fn assert_same_ring(real: &SonarRing, fast: &SonarRing, t: u64) {
    assert_eq!(real.header.frame_id, fast.header.frame_id);
    assert_eq!(real.max_range, fast.max_range);
    assert_eq!(real.readings(), fast.readings(), "t {t}");
}

fn assert_same_odometry(real: &Odometry, fast: &Odometry, t: u64) {
    assert_eq!(real.header.frame_id, fast.header.frame_id);
    assert_eq!(
        (real.flags, real.bumpers, real.battery_v),
        (fast.flags, fast.bumpers, fast.battery_v),
        "t {t}"
    );
    assert_eq!((real.linear, real.angular), (fast.linear, fast.angular));
    // P3-DX: DistConvFactor 0.485 mm, AngleConvFactor 2π/4096 rad.
    let counts = |m: f64| (m * 1000.0 / 0.485).round() as i64;
    let units = |a: f64| (a / (std::f64::consts::TAU / 4096.0)).round() as i64;
    assert_eq!(
        (counts(real.x), counts(real.y), units(real.theta)),
        (counts(fast.x), counts(fast.y), units(fast.theta)),
        "t {t}: real {real:?} fast {fast:?}"
    );
    for (a, b) in [(real.x, fast.x), (real.y, fast.y), (real.theta, fast.theta)] {
        assert!((a - b).abs() < 1e-9, "t {t}: {a} vs {b}");
    }
}

#[test]
fn fast_path_gives_the_real_drivers_messages_for_the_same_simulated_instant() {
    let scenario = Scenario::builtin("corridor").unwrap();
    let mut profile = scenario.profile.clone();
    let dir = tempfile::tempdir().unwrap();
    let instance = unique_instance("fast_path");
    let clock = Arc::new(MonotonicClock);

    // The devices, idle (no echo, robot at the origin), as sim/link starts them.
    let held = Arc::new(Mutex::new(vec![0u16; URG_STEPS]));
    let laser = Emulator::spawn(EmulatorConfig::pty(
        DeviceConfig::default(),
        Some(dir.path().join("hokuyo")),
    ))
    .unwrap();
    let source = held.clone();
    laser.set_scan_source(move |_k: u64, ranges: &mut [u16]| {
        let h = source.lock().unwrap();
        for (r, v) in ranges.iter_mut().zip(h.iter()) {
            *r = *v;
        }
    });
    let mut base =
        BaseEmulator::start(&profile, &dir.path().join("pioneer"), clock, scenario.seed).unwrap();
    base.set_odometry(&Default::default());
    base.clear_sonar(profile.sonar.count);

    profile.laser.port = laser.port();
    profile.base.port = base.port();
    profile.robot.instance = instance.clone();
    let cfg = dir.path().join("robot.toml");
    std::fs::write(&cfg, profile.to_toml()).unwrap();
    let cfg = cfg.to_string_lossy().into_owned();
    let bus: Bus = open_bus(&instance);
    let scans: Subscriber<LaserScan> = bus.subscriber(topics::LASER_SCAN).unwrap();
    let rings: Subscriber<SonarRing> = bus.subscriber(topics::BASE_SONAR).unwrap();
    let odoms: Subscriber<Odometry> = bus.subscriber(topics::BASE_ODOM).unwrap();
    let mut procs = Vec::new();
    for role in ["hokuyo", "pioneer"] {
        let p = Child::spawn(
            &bin(&format!("smokenav-{role}")),
            &["--config", &cfg],
            &instance,
        )
        .unwrap();
        let pid = p.pid();
        wait_for::<Health>(&bus, topics::health(role), Duration::from_secs(30), |h| {
            h.pid == pid && h.state() == HealthState::Ok
        })
        .unwrap_or_else(|e| panic!("{role} not ready: {e}\n{}", p.output()));
        procs.push(p);
    }

    // The fast path over the whole run, keyed by the instant each message is for.
    let mut world = World::new(scenario.clone()).unwrap();
    let mut fast = DirectDrivers::new(&profile, 0).unwrap();
    let mut fast_scans: BTreeMap<u64, LaserScan> = BTreeMap::new();
    let mut fast_rings: BTreeMap<u64, SonarRing> = BTreeMap::new();
    let mut fast_odoms: BTreeMap<u64, Odometry> = BTreeMap::new();
    let mut poses = BTreeMap::new();
    let mut frames = BTreeMap::new();
    let end = INSTANTS[INSTANTS.len() - 1] + 200 * MS;
    while world.time_ns() < end {
        let out = world.step(Duration::from_millis(100));
        fast.convert(&out, |_, m| match m {
            // A frame starts at its instant; the scan is stamped 44 steps later.
            DirectMessage::Laser(s) => {
                fast_scans.insert(s.header.stamp_ns - 4_296_875, *s);
            }
            DirectMessage::Sonar(r) => {
                fast_rings.insert(r.header.stamp_ns, *r);
            }
            DirectMessage::Odometry(o) => {
                fast_odoms.insert(o.header.stamp_ns, o);
            }
            DirectMessage::Smoke(_) => {}
        });
        for o in &out.odometry {
            poses.insert(o.t_ns, o.pose);
        }
        for f in &out.laser {
            frames.insert(f.t_ns, f.ranges_mm);
        }
    }

    // Replay the instants into the devices, holding the world still at each.
    let mut world = World::new(scenario).unwrap();
    let mut latest: BTreeMap<u8, SonarSample> = BTreeMap::new();
    for &t in &INSTANTS {
        while world.time_ns() < t {
            let out = world.step(Duration::from_millis(5));
            for s in out.sonar {
                latest.insert(s.index, s);
            }
        }
        base.set_odometry(&poses[&t]);
        for s in latest.values() {
            base.set_sonar(s.index, s.range_m, s.saturated);
        }
        held.lock().unwrap().copy_from_slice(&frames[&t]);
        let fed = Instant::now();
        std::thread::sleep(HOLD);
        let scan = settled(&scans, fed).expect("a scan while held");
        let ring = settled(&rings, fed).expect("a ring while held");
        let odom = settled(&odoms, fed).expect("odometry while held");
        assert_same_scan(&scan, &fast_scans[&t], t);
        assert_same_ring(&ring, &fast_rings[&t], t);
        assert_same_odometry(&odom, &fast_odoms[&t], t);
    }
    // Not trivially equal: the robot drove, the walls were seen.
    let last = &fast_odoms[&INSTANTS[3]];
    assert!(last.x > 0.6, "{last:?}");
    assert!(fast_scans[&INSTANTS[3]].valid_ranges().count() > 100);
    for p in &procs {
        assert!(!p.output().contains("panicked"), "{}", p.output());
    }
}
