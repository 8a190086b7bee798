//! Nomad Scout end to end: the Scout emulator on a real PTY (in this test
//! process) ↔ the real `smokenav-scout` binary (its own process) ↔ bus
//! subscribers and a command publisher (this process).

use smokenav_platform_bus::{Bus, Publisher, topics};
use smokenav_scout_emulator::{EmulatorConfig, Pose, ScoutEmulator, SonarOrder};
use smokenav_shared_types::{
    Health, HealthState, Odometry, OdometryFlags, SonarRing, SonarStatus, VelocityCommand,
};
use smokenav_tests::{Child, bin, open_bus, profile, unique_instance, wait_for};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

const INCH: f64 = 0.0254;

struct Rig {
    _dir: tempfile::TempDir,
    emu: ScoutEmulator,
    driver: Child,
    bus: Bus,
    instance: String,
}

/// Emulator + driver on a fresh bus instance; returns once odometry flows.
fn rig(test: &str) -> Rig {
    rig_with(test, |_| {})
}

/// [`rig`] with the profile edited first.
fn rig_with(test: &str, edit: impl FnOnce(&mut smokenav_platform_config::RobotConfig)) -> Rig {
    let dir = tempfile::tempdir().unwrap();
    let emu = ScoutEmulator::start(EmulatorConfig::new(dir.path().join("scout"))).unwrap();
    let config = profile(dir.path(), "nomad-scout.toml", edit);
    let instance = unique_instance(test);
    let bus = open_bus(&instance);
    let port = emu.path().to_string_lossy().into_owned();
    let driver = Child::spawn(
        &bin("smokenav-scout"),
        &["--config", &config.to_string_lossy(), "--port", &port],
        &instance,
    )
    .unwrap();
    wait_for::<Odometry>(&bus, topics::BASE_ODOM, Duration::from_secs(10), |_| true)
        .unwrap_or_else(|e| panic!("{e}\n{}", driver.output()));
    Rig {
        _dir: dir,
        emu,
        driver,
        bus,
        instance,
    }
}

/// Publishes a velocity command at 10 Hz (from its own thread and bus
/// connection) until the returned flag is cleared.
fn drive(
    instance: &str,
    linear: f64,
    angular: f64,
) -> (Arc<AtomicBool>, std::thread::JoinHandle<()>) {
    let running = Arc::new(AtomicBool::new(true));
    let flag = running.clone();
    let instance = instance.to_owned();
    let t = std::thread::spawn(move || {
        let bus = open_bus(&instance);
        let mut publisher: Publisher<VelocityCommand> =
            bus.publisher(topics::BASE_CMD_VEL).unwrap();
        while flag.load(Ordering::Relaxed) {
            publisher
                .publish(&VelocityCommand {
                    linear,
                    angular,
                    ..Default::default()
                })
                .unwrap();
            std::thread::sleep(Duration::from_millis(100));
        }
    });
    (running, t)
}

#[test]
fn odometry_and_all_16_sonars_match_what_the_emulator_was_fed() {
    let r = rig("scout_feed");
    // The driver configured the robot as the profile says.
    let snap = r.emu.snapshot();
    assert_eq!(
        snap.watchdog_s, 1,
        "conf_tm(1) from [base.scout] watchdog_s"
    );
    assert_eq!(snap.sonar_rate, 15);
    assert_eq!(
        snap.sonar_order,
        SonarOrder::from_indices(&[0, 2, 15, 1, 14, 3, 13, 4, 12, 5, 11, 6, 10, 7, 9, 8]).unwrap()
    );
    assert_eq!(
        snap.stats.define, 2,
        "dp(0,0) and da(0,0) on the first connection"
    );

    // Sixteen different ranges, one of them 255 in (no echo), one 4 in
    // (below the Polaroid's 0.15 m minimum), the rest echoes.
    let fed: [u8; 16] = [
        20, 35, 50, 65, 80, 95, 110, 125, 140, 155, 170, 185, 200, 215, 255, 4,
    ];
    r.emu.set_sonar_inches(fed);
    // Pose in 1/10 in and 1/10 degree steps, so the expected values are exact.
    let pose = Pose::new(1500.0 * 0.00254, -750.0 * 0.00254, (33.5f64).to_radians());
    r.emu.set_pose(pose);

    let rings = wait_for::<SonarRing>(&r.bus, topics::BASE_SONAR, Duration::from_secs(5), |s| {
        s.readings().len() == 16
            && s.readings()
                .iter()
                .zip(fed)
                .all(|(rd, inches)| match inches {
                    255 => rd.status() == SonarStatus::Saturated,
                    4 => rd.status() == SonarStatus::Invalid,
                    n => rd.valid_range() == Some((n as f64 * INCH) as f32),
                })
    })
    .unwrap_or_else(|e| panic!("{e}\n{}", r.driver.output()));
    let ring = rings.last().unwrap();
    for (i, rd) in ring.readings().iter().enumerate() {
        assert_eq!(rd.index as usize, i);
    }
    assert_eq!(ring.readings()[14].range, ring.max_range);
    assert!((ring.max_range - 6.477).abs() < 1e-6);

    let odoms = wait_for::<Odometry>(&r.bus, topics::BASE_ODOM, Duration::from_secs(2), |o| {
        (o.x - pose.x).abs() < 1e-9
    })
    .unwrap();
    let o = odoms.last().unwrap();
    assert!((o.x - 3.81).abs() < 1e-9, "x = {}", o.x);
    assert!((o.y + 1.905).abs() < 1e-9, "y = {}", o.y);
    assert!((o.theta - pose.theta).abs() < 1e-9, "theta = {}", o.theta);
    assert_eq!(o.header.frame_id.as_str(), "odom");

    // Commanded motion reaches the wheels and comes back as velocity.
    let (run, t) = drive(&r.instance, 0.2, 0.3);
    let odoms = wait_for::<Odometry>(&r.bus, topics::BASE_ODOM, Duration::from_secs(3), |o| {
        (o.linear - 0.2).abs() < 0.005 && (o.angular - 0.3).abs() < 0.02
    })
    .unwrap_or_else(|e| panic!("{e}\n{}", r.driver.output()));
    let (snap, _) = r
        .emu
        .wait_for(Duration::from_secs(1), |s| s.wheels.left > 0.0);
    let o = odoms.last().unwrap();
    // Wheels: 0.2 ∓ 0.3·0.345/2 = 0.148 / 0.252 m/s, in whole 1/10 in/s.
    assert!(
        (snap.wheels.left - 0.14825).abs() < 0.0013,
        "{:?}",
        snap.wheels
    );
    assert!(
        (snap.wheels.right - 0.25175).abs() < 0.0013,
        "{:?}",
        snap.wheels
    );
    assert!(o.motors_enabled());
    run.store(false, Ordering::Relaxed);
    t.join().unwrap();

    // Health reports the link as fine.
    let h = wait_for::<Health>(
        &r.bus,
        topics::health("scout"),
        Duration::from_secs(5),
        |h| {
            h.state() == HealthState::Ok && h.metrics().iter().any(|m| m.name.as_str() == "odom_hz")
        },
    )
    .unwrap();
    let h = h.last().unwrap();
    let metric = |n: &str| {
        h.metrics()
            .iter()
            .find(|m| m.name.as_str() == n)
            .map(|m| m.value)
    };
    assert_eq!(metric("connected"), Some(1.0));
    // 10 Hz from the emulator; health said Ok, so the rate was above its
    // 80 % floor over a whole window. The last window may be a little short
    // on a loaded 2-core machine (7.95 Hz seen).
    assert!(metric("odom_hz").unwrap() > 7.0, "{:?}", metric("odom_hz"));
}

#[test]
fn command_timeout_stops_the_robot() {
    // The profile's timeout is shorter now; this checks a configured one holds.
    let r = rig_with("scout_timeout", |c| c.base.cmd_timeout_s = 0.5);
    let (run, t) = drive(&r.instance, 0.3, 0.0);
    let (_, moving) = r.emu.wait_for(Duration::from_secs(3), |s| {
        (s.wheels.left - 0.3).abs() < 0.002
    });
    assert!(moving, "robot never reached 0.3 m/s\n{}", r.driver.output());
    run.store(false, Ordering::Relaxed);
    t.join().unwrap();
    let quiet_since = Instant::now();
    let (snap, stopped) = r.emu.wait_for(Duration::from_secs(3), |s| {
        s.wheels.left == 0.0 && s.wheels.right == 0.0
    });
    let took = quiet_since.elapsed();
    eprintln!("robot stopped {took:?} after the last velocity command");
    assert!(stopped, "robot still driving: {snap:?}");
    // cmd_timeout_s = 0.5 in the profile, plus at most one 100 ms cycle.
    assert!(took < Duration::from_millis(800), "stopped after {took:?}");
    assert!(
        took > Duration::from_millis(350),
        "stopped too early: {took:?}"
    );
    // The driver stopped it (st), not the robot-side watchdog.
    assert!(snap.stats.stop >= 1);
    assert_eq!(snap.watchdog_trips, 0);
    let odoms = wait_for::<Odometry>(&r.bus, topics::BASE_ODOM, Duration::from_secs(2), |o| {
        o.linear == 0.0
    })
    .unwrap();
    assert_eq!(odoms.last().unwrap().linear, 0.0);
}

/// Issue #22 point 3: from the last velocity command to wheels at rest with
/// the shipped profile (its command timeout; the robot-side watchdog armed
/// at 1 s, the smallest `conf_tm` takes, as the backstop).
#[test]
fn silent_controller_at_0_3_mps_leaves_the_scout_at_standstill_within_0_5_s() {
    let r = rig("scout_standstill");
    let timeout_s =
        smokenav_platform_config::RobotConfig::load(&r._dir.path().join("test-nomad-scout.toml"))
            .map(|c| c.base.cmd_timeout_s)
            .unwrap_or_else(|e| panic!("profile: {e}"));
    let (run, t) = drive(&r.instance, 0.3, 0.0);
    let (snap, moving) = r.emu.wait_for(Duration::from_secs(3), |s| {
        (s.wheels.left - 0.3).abs() < 0.002
    });
    assert!(moving, "robot never reached 0.3 m/s\n{}", r.driver.output());
    assert_eq!(snap.watchdog_s, 1);
    run.store(false, Ordering::Relaxed);
    t.join().unwrap();
    let quiet_since = Instant::now();
    let (snap, stopped) = r.emu.wait_for(Duration::from_secs(3), |s| {
        s.wheels.left == 0.0 && s.wheels.right == 0.0
    });
    let took = quiet_since.elapsed();
    eprintln!(
        "scout at rest {:.0} ms after the last velocity command (cmd_timeout_s {timeout_s})",
        took.as_secs_f64() * 1e3
    );
    assert!(stopped, "robot still driving: {snap:?}");
    assert!(took <= Duration::from_millis(500), "at rest after {took:?}");
    assert!(snap.stats.stop >= 1);
    assert_eq!(snap.watchdog_trips, 0);
}

#[test]
fn link_pulled_and_restored_resumes_within_1_s() {
    let r = rig("scout_replug");
    r.emu.disconnect();
    std::thread::sleep(Duration::from_millis(1500));
    // Nothing is published while the robot is unreachable.
    let stale = wait_for::<Odometry>(
        &r.bus,
        topics::BASE_ODOM,
        Duration::from_millis(400),
        |_| true,
    );
    // Messages queued before the unplug may still be delivered; none after.
    if let Ok(msgs) = &stale {
        let newest = msgs.iter().map(|m| m.header.stamp_ns).max().unwrap_or(0);
        let unplugged_ago = smokenav_shared_types::clock::monotonic_now_ns() - newest;
        assert!(unplugged_ago > 1_000_000_000, "published while unplugged");
    }
    // The clock is read before the replug: on a loaded machine this thread can
    // be descheduled after `reconnect()` long enough for the driver to reopen,
    // reconfigure and publish its first (RESET) message with an earlier stamp.
    let back = Instant::now();
    let replugged_at = smokenav_shared_types::clock::monotonic_now_ns();
    r.emu.reconnect();
    let odoms = wait_for::<Odometry>(&r.bus, topics::BASE_ODOM, Duration::from_secs(3), |o| {
        o.header.stamp_ns > replugged_at
    })
    .unwrap_or_else(|e| panic!("{e}\n{}", r.driver.output()));
    let took = back.elapsed();
    eprintln!("odometry resumed {took:?} after the replug");
    assert!(took < Duration::from_secs(1), "resumed after {took:?}");
    let first = odoms.last().unwrap();
    assert!(
        first.flags & OdometryFlags::RESET != 0,
        "first message after a reconnect is flagged RESET"
    );
    // Reconfigured (watchdog, sonar) but not re-zeroed.
    let snap = r.emu.snapshot();
    assert_eq!(snap.stats.conf_timeout, 2);
    assert_eq!(snap.stats.conf_sonar, 2);
    assert_eq!(snap.stats.define, 2);
    let h = wait_for::<Health>(
        &r.bus,
        topics::health("scout"),
        Duration::from_secs(5),
        |h| {
            h.metrics()
                .iter()
                .any(|m| m.name.as_str() == "reconnects" && m.value == 1.0)
        },
    );
    assert!(h.is_ok(), "health never reported the reconnect");
}

#[test]
fn corrupted_replies_are_counted_and_odometry_keeps_flowing() {
    let r = rig("scout_corrupt");
    // One reply in five fails its checksum (placed by the emulator's seed).
    r.emu.set_corrupt_rate(0.2);
    let mut n = 0;
    wait_for::<Odometry>(&r.bus, topics::BASE_ODOM, Duration::from_secs(10), |_| {
        n += 1;
        n >= 30
    })
    .unwrap_or_else(|e| panic!("{e}\n{}", r.driver.output()));
    let corrupted = r.emu.stats().corrupted;
    assert!(corrupted > 0);
    let h = wait_for::<Health>(
        &r.bus,
        topics::health("scout"),
        Duration::from_secs(5),
        |h| {
            h.metrics()
                .iter()
                .any(|m| m.name.as_str() == "checksum_errors" && m.value > 0.0)
        },
    )
    .unwrap();
    let h = h.last().unwrap();
    let metric = |n: &str| {
        h.metrics()
            .iter()
            .find(|m| m.name.as_str() == n)
            .map(|m| m.value)
    };
    eprintln!(
        "corrupted {corrupted}: health checksum_errors {:?}, reply_timeouts {:?}, reconnects {:?}, latency p99 {} µs",
        metric("checksum_errors"),
        metric("reply_timeouts"),
        metric("reconnects"),
        h.latency_p99_us
    );
    assert_eq!(metric("connected"), Some(1.0));
    assert_eq!(
        metric("reconnects"),
        Some(0.0),
        "a lost reply is not a lost link"
    );
}
