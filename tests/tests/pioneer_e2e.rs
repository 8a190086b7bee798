//! Pioneer end to end: the ARCOS emulator on a real PTY or TCP port (in this
//! test process) ↔ the real `smokenav-pioneer` binary (its own process) ↔ bus
//! subscribers here and the real `smokenav drive` CLI as the controller.

use smokenav_pioneer_emulator::{Emulator, Phase, Pose, RobotConfig};
use smokenav_platform_bus::{Bus, Publisher, Subscriber, Waiter, topics};
use smokenav_shared_types::{
    Health, Odometry, OdometryFlags, SonarRing, SonarStatus, VelocityCommand,
};
use smokenav_tests::{Child, bin, open_bus, profile, unique_instance, wait_for};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

enum Transport {
    Pty,
    Tcp,
}

struct Rig {
    _dir: tempfile::TempDir,
    emu: Emulator,
    driver: Child,
    bus: Bus,
    instance: String,
}

fn start(
    test: &str,
    robot: RobotConfig,
    transport: Transport,
    edit: impl FnOnce(&mut smokenav_platform_config::RobotConfig),
) -> (tempfile::TempDir, Emulator, Child, Bus, String) {
    let dir = tempfile::tempdir().unwrap();
    let emu = match transport {
        Transport::Pty => Emulator::pty(&dir.path().join("pioneer"), robot).unwrap(),
        Transport::Tcp => Emulator::tcp("127.0.0.1:0", robot).unwrap(),
    };
    let port = emu.port_arg();
    let is_tcp = port.starts_with("tcp://");
    let config = profile(dir.path(), "pioneer-3dx.toml", |c| {
        if !is_tcp {
            c.base.port = port.clone();
        }
        edit(c);
    });
    let instance = unique_instance(test);
    let bus = open_bus(&instance);
    let config = config.to_string_lossy().into_owned();
    let mut args = vec!["--config", config.as_str()];
    // TCP goes through --port, as a user would point the driver at MobileSim.
    if is_tcp {
        args.extend(["--port", port.as_str()]);
    }
    let driver = Child::spawn(&bin("smokenav-pioneer"), &args, &instance).unwrap();
    (dir, emu, driver, bus, instance)
}

/// Emulator + driver on a fresh bus instance; returns once odometry flows.
fn rig(test: &str, robot: RobotConfig, transport: Transport) -> Rig {
    rig_with(test, robot, transport, |_| {})
}

/// [`rig`] with the profile edited first.
fn rig_with(
    test: &str,
    robot: RobotConfig,
    transport: Transport,
    edit: impl FnOnce(&mut smokenav_platform_config::RobotConfig),
) -> Rig {
    let (dir, emu, driver, bus, instance) = start(test, robot, transport, edit);
    wait_for::<Odometry>(&bus, topics::BASE_ODOM, Duration::from_secs(15), |_| true)
        .unwrap_or_else(|e| panic!("{e}\n{}", driver.output()));
    Rig {
        _dir: dir,
        emu,
        driver,
        bus,
        instance,
    }
}

/// Everything `sub` receives for `d`.
fn collect<T: smokenav_platform_bus::Message>(sub: &Subscriber<T>, d: Duration) -> Vec<T> {
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(sub).unwrap();
    let end = Instant::now() + d;
    let mut got = Vec::new();
    loop {
        while let Some(s) = sub.receive().unwrap() {
            got.push(*s);
        }
        let now = Instant::now();
        if now >= end {
            return got;
        }
        waiter.wait(Some(end - now)).unwrap();
    }
}

/// Publishes a velocity command at 10 Hz from its own thread until stopped.
fn keep_driving(instance: &str, linear: f64) -> (Arc<AtomicBool>, std::thread::JoinHandle<()>) {
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
                    ..Default::default()
                })
                .unwrap();
            std::thread::sleep(Duration::from_millis(100));
        }
    });
    (running, t)
}

fn health_metric(r: &Rig, name: &str, pred: impl Fn(f64) -> bool) -> Health {
    let hs = wait_for::<Health>(
        &r.bus,
        topics::health("pioneer"),
        Duration::from_secs(5),
        |h| h.metric(name).is_some_and(&pred),
    )
    .unwrap_or_else(|e| panic!("{e}\n{}", r.driver.output()));
    *hs.last().unwrap()
}

#[test]
fn commanding_0_3_mps_for_2_s_moves_odometry_about_0_6_m_and_sigterm_closes() {
    let mut r = rig("pioneer_06m", RobotConfig::default(), Transport::Pty);
    let h = r.emu.handle();
    let odom = r.bus.subscriber::<Odometry>(topics::BASE_ODOM).unwrap();
    let mut drive = Child::spawn(
        &bin("smokenav"),
        &["drive", "0.3", "0", "--for", "2"],
        &r.instance,
    )
    .unwrap();
    assert!(
        drive.wait_exit(Duration::from_secs(10)).unwrap().success(),
        "{}",
        drive.output()
    );
    h.wait_for(Duration::from_secs(3), |s| {
        s.robot.commanded.trans == 0.0 && s.robot.actual.trans == 0.0
    })
    .expect("robot stops after the drive command ends");
    let msgs = collect(&odom, Duration::from_millis(400));
    let last = msgs
        .last()
        .unwrap_or_else(|| panic!("no odometry\n{}", r.driver.output()));
    assert!(
        (last.x - 0.6).abs() < 0.05,
        "x = {:.3} m (expected about 0.6)",
        last.x
    );
    assert!(last.y.abs() < 0.01 && last.theta.abs() < 0.01, "{last:?}");
    // The published odometry agrees with the emulator's own pose to the
    // counter resolution (0.485 mm per unit on a p3dx).
    let truth = h.status().robot.pose;
    assert!(
        (last.x - truth.x_mm / 1000.0).abs() < 0.002,
        "{} vs {}",
        last.x,
        truth.x_mm
    );
    assert!(last.motors_enabled());
    assert!((last.battery_v - 13.0).abs() < 1e-6);

    // A clean stop sends CLOSE: session ended, motors off.
    assert!(
        r.driver
            .terminate(Duration::from_secs(5))
            .unwrap()
            .success()
    );
    let st = h
        .wait_for(Duration::from_secs(2), |s| s.robot.counters.closes >= 1)
        .expect("CLOSE on shutdown");
    assert_eq!(st.robot.phase, Phase::Handshake { next: 0 });
    assert!(!st.robot.motors_enabled && !st.robot.streaming);
}

#[test]
fn crashed_controller_stops_the_robot_within_the_0_5_s_command_timeout() {
    // The profile's timeout is shorter now; this checks a configured one holds.
    let r = rig_with(
        "pioneer_crash",
        RobotConfig::default(),
        Transport::Pty,
        |c| c.base.cmd_timeout_s = 0.5,
    );
    let h = r.emu.handle();
    let ctl = Child::spawn(
        &bin("smokenav"),
        &["drive", "0.3", "0", "--for", "60"],
        &r.instance,
    )
    .unwrap();
    h.wait_for(Duration::from_secs(10), |s| {
        s.robot.commanded.trans == 300.0
    })
    .unwrap_or_else(|| panic!("never drove\n{}\n{}", r.driver.output(), ctl.output()));
    std::thread::sleep(Duration::from_millis(800));
    // The controller dies without a word.
    ctl.signal(nix::sys::signal::Signal::SIGKILL);
    let killed = Instant::now();
    let st = h
        .wait_for(Duration::from_secs(3), |s| s.robot.commanded.trans == 0.0)
        .expect("the driver stops the robot");
    let dt = killed.elapsed();
    eprintln!("robot commanded to stop {dt:?} after the controller was killed");
    // Last command ≤ 0.1 s before the kill; timeout 0.5 s; loop ≤ 25 ms.
    assert!(
        dt <= Duration::from_millis(700),
        "stopped {dt:?} after the crash"
    );
    assert!(
        dt >= Duration::from_millis(300),
        "stopped {dt:?} after the crash: too early for the timeout"
    );
    // The driver did it, not the 2 s firmware watchdog.
    assert_eq!(st.robot.counters.watchdog_trips, 0);
    h.wait_for(Duration::from_secs(1), |s| s.robot.actual.trans == 0.0)
        .expect("wheels stop");
    let health = health_metric(&r, "cmd_timeouts", |v| v >= 1.0);
    assert_eq!(health.metric("cmd_timeouts"), Some(1.0));
}

/// Issue #22 point 3: from the controller's SIGKILL to wheels at rest, with
/// the profile's command timeout and E_STOP (the emulator's ramp would be
/// 1 m/s²: 523 ms and 0.114 m with a plain VEL 0).
#[test]
fn crashed_controller_at_0_3_mps_leaves_the_robot_at_standstill_within_0_5_s() {
    let robot = RobotConfig::default();
    let decel_mps2 = robot.trans_decel / 1000.0;
    let r = rig("pioneer_standstill", robot, Transport::Pty);
    let timeout_s =
        smokenav_platform_config::RobotConfig::load(&r._dir.path().join("test-pioneer-3dx.toml"))
            .map(|c| c.base.cmd_timeout_s)
            .unwrap_or_else(|e| panic!("profile: {e}"));
    let h = r.emu.handle();
    let ctl = Child::spawn(
        &bin("smokenav"),
        &["drive", "0.3", "0", "--for", "60"],
        &r.instance,
    )
    .unwrap();
    h.wait_for(Duration::from_secs(10), |s| s.robot.actual.trans == 300.0)
        .unwrap_or_else(|| {
            panic!(
                "never reached 0.3 m/s\n{}\n{}",
                r.driver.output(),
                ctl.output()
            )
        });
    std::thread::sleep(Duration::from_millis(500));
    let at_kill = h.status().robot.pose;
    ctl.signal(nix::sys::signal::Signal::SIGKILL);
    let killed = Instant::now();
    let st = h
        .wait_for(Duration::from_secs(3), |s| s.robot.actual.trans == 0.0)
        .expect("the robot comes to rest");
    let dt = killed.elapsed();
    let coast_m =
        (st.robot.pose.x_mm - at_kill.x_mm).hypot(st.robot.pose.y_mm - at_kill.y_mm) / 1000.0;
    eprintln!(
        "standstill {:.0} ms and {coast_m:.3} m after the controller was killed at 0.3 m/s \
         (cmd_timeout_s {timeout_s}, E_STOP; ramp {decel_mps2} m/s²)",
        dt.as_secs_f64() * 1e3
    );
    // Last command ≤ 0.1 s before the kill, then the timeout, then E_STOP
    // (no ramp: v / decel would add 0.3 s), plus the driver's loop and the
    // motor model's 10 ms step. The goal is at rest within 0.5 s.
    assert!(
        dt <= Duration::from_millis(500),
        "at rest {dt:?} after the crash"
    );
    // Coasting: at most the time until the timeout at 0.3 m/s.
    assert!(
        coast_m <= 0.3 * (timeout_s + 0.15),
        "coasted {coast_m:.3} m"
    );
    assert_eq!(st.robot.counters.watchdog_trips, 0);
}

#[test]
fn odometry_stays_continuous_across_the_15_bit_wrap() {
    // 15.8 m out on a p3dx is counter 32577: 190 units (92 mm) from the wrap.
    let r = rig(
        "pioneer_wrap",
        RobotConfig {
            initial_pose: Pose::new(15_800.0, 0.0, 0.0),
            ..Default::default()
        },
        Transport::Pty,
    );
    let h = r.emu.handle();
    let odom = r.bus.subscriber::<Odometry>(topics::BASE_ODOM).unwrap();
    let (run, t) = keep_driving(&r.instance, 0.3);
    let mut msgs = collect(&odom, Duration::from_millis(2000));
    run.store(false, Ordering::Relaxed);
    t.join().unwrap();
    h.wait_for(Duration::from_secs(3), |s| s.robot.actual.trans == 0.0)
        .expect("stops after the commands end");
    msgs.extend(collect(&odom, Duration::from_millis(300)));
    assert!(msgs.len() >= 18, "{} odometry messages", msgs.len());
    for w in msgs.windows(2) {
        let dx = w[1].x - w[0].x;
        assert!(
            (-1e-6..0.05).contains(&dx),
            "odometry jumped by {dx} m at x = {}",
            w[0].x
        );
    }
    let last = msgs.last().unwrap();
    // The controller's counter wrapped: its odometry is past 32768 × 0.485 mm.
    let controller_x = h.status().robot.odometry.x_mm;
    assert!(
        controller_x > 32768.0 * 0.485,
        "counter did not wrap: {controller_x} mm"
    );
    let moved = (controller_x - 15_800.0) / 1000.0;
    assert!(
        (last.x - moved).abs() < 0.002,
        "published {} m, controller moved {moved} m",
        last.x
    );
    assert!(last.x > 0.4, "{}", last.x);
}

#[test]
fn tcp_mode_connects_like_aria_to_mobilesim() {
    let mut r = rig("pioneer_tcp", RobotConfig::default(), Transport::Tcp);
    let h = r.emu.handle();
    let (run, t) = keep_driving(&r.instance, 0.2);
    let st = h
        .wait_for(Duration::from_secs(5), |s| s.robot.pose.x_mm > 100.0)
        .unwrap_or_else(|| panic!("robot did not move over TCP\n{}", r.driver.output()));
    assert_eq!(st.robot.commanded.trans, 200.0);
    run.store(false, Ordering::Relaxed);
    t.join().unwrap();
    let o = wait_for::<Odometry>(&r.bus, topics::BASE_ODOM, Duration::from_secs(3), |o| {
        o.x > 0.1
    })
    .unwrap();
    assert!(o.last().unwrap().x > 0.1);
    assert!(
        r.driver
            .terminate(Duration::from_secs(5))
            .unwrap()
            .success()
    );
    h.wait_for(Duration::from_secs(2), |s| s.robot.counters.closes == 1)
        .expect("CLOSE over TCP on shutdown");
}

#[test]
fn session_left_open_by_a_crashed_driver_is_closed_and_reopened() {
    let r = rig(
        "pioneer_stale",
        RobotConfig {
            start_open: true,
            ..Default::default()
        },
        Transport::Pty,
    );
    let st = r.emu.handle().status();
    assert!(st.robot.counters.closes >= 1, "{:?}", st.robot.counters);
    assert!(st.robot.counters.opens >= 1);
    let health = health_metric(&r, "stale_sessions_closed", |v| v >= 1.0);
    assert_eq!(health.metric("connected"), Some(1.0));
}

#[test]
fn sonar_ring_has_the_profiles_8_and_max_range_is_saturated() {
    let r = rig("pioneer_sonar", RobotConfig::default(), Transport::Pty);
    // Index 8 is on the rear array, which the profile does not list.
    r.emu
        .handle()
        .set_sonar_ranges(&[800, 5000, 1200, 5000, 300, 4000, 2000, 4999, 700]);
    let rings = wait_for::<SonarRing>(&r.bus, topics::BASE_SONAR, Duration::from_secs(5), |s| {
        s.by_index(0).is_some_and(|x| (x.range - 0.8).abs() < 1e-6)
    })
    .unwrap();
    let ring = rings.last().unwrap();
    assert_eq!(ring.len(), 8);
    assert!(ring.by_index(8).is_none());
    assert_eq!(ring.max_range, 5.0);
    assert_eq!(ring.by_index(1).unwrap().status(), SonarStatus::Saturated);
    assert_eq!(ring.by_index(3).unwrap().status(), SonarStatus::Saturated);
    assert_eq!(ring.by_index(7).unwrap().valid_range(), Some(4.999));
    assert_eq!(ring.by_index(4).unwrap().valid_range(), Some(0.3));
    assert_eq!(ring.header.frame_id.as_str(), "base_link");
}

#[test]
fn unplugged_serial_link_is_reopened_and_odometry_resumes_flagged() {
    let r = rig("pioneer_unplug", RobotConfig::default(), Transport::Pty);
    let h = r.emu.handle();
    let odom = r.bus.subscriber::<Odometry>(topics::BASE_ODOM).unwrap();
    let mut msgs = collect(&odom, Duration::from_millis(300));
    assert!(!msgs.is_empty());
    h.unplug(Duration::from_millis(600));
    msgs.extend(collect(&odom, Duration::from_millis(3500)));
    let gap = msgs
        .windows(2)
        .map(|w| w[1].header.stamp_ns.saturating_sub(w[0].header.stamp_ns))
        .max()
        .unwrap_or(0);
    assert!(
        gap >= 500_000_000,
        "no outage seen in the stamps (largest gap {gap} ns)"
    );
    let after = msgs
        .iter()
        .skip(1)
        .position(|o| o.flags & OdometryFlags::RESET != 0)
        .map(|i| i + 1)
        .unwrap_or_else(|| {
            panic!(
                "no RESET-flagged odometry after the replug\n{}",
                r.driver.output()
            )
        });
    assert!(msgs.len() - after >= 5, "odometry did not resume");
    // The pose carries on from where it was (the robot stood still).
    assert!((msgs[after].x - msgs[after - 1].x).abs() < 1e-9);
    let health = health_metric(&r, "port_opens", |v| v >= 2.0);
    assert_eq!(health.metric("connected"), Some(1.0));
}

#[test]
fn unknown_subclass_exits_with_a_clear_error_unless_the_profile_names_one() {
    let boxy = || RobotConfig {
        subclass: "box".into(),
        factors_from: Some("p3dx".into()),
        ..Default::default()
    };
    let (_dir, _emu, mut driver, _bus, _i) = start("pioneer_box", boxy(), Transport::Pty, |_| {});
    let status = driver.wait_exit(Duration::from_secs(10)).unwrap();
    // 78 (EX_CONFIG): the units' RestartPreventExitStatus, so systemd does not
    // restart a driver only a profile change can fix.
    assert_eq!(status.code(), Some(78), "{}", driver.output());
    let out = driver.output();
    assert!(out.contains("unknown robot subclass \"box\""), "{out}");
    assert!(out.contains("[base.pioneer]"), "{out}");

    let (_dir, _emu, driver, bus, _i) = start("pioneer_box_ok", boxy(), Transport::Pty, |c| {
        c.base.pioneer = Some(smokenav_platform_config::base::PioneerOptions {
            subclass: Some("p3dx".into()),
            ..Default::default()
        });
    });
    wait_for::<Odometry>(&bus, topics::BASE_ODOM, Duration::from_secs(15), |_| true)
        .unwrap_or_else(|e| panic!("{e}\n{}", driver.output()));
}

#[test]
fn corrupted_sips_and_line_noise_are_counted_in_health_and_odometry_continues() {
    let r = rig("pioneer_noise", RobotConfig::default(), Transport::Pty);
    let h = r.emu.handle();
    let odom = r.bus.subscriber::<Odometry>(topics::BASE_ODOM).unwrap();
    h.corrupt_next_packets(3);
    h.inject_noise(&[0x00, 0xFA, 0x13, 0x37, 0xFA, 0xFB, 0xFF]);
    let msgs = collect(&odom, Duration::from_millis(1500));
    assert!(msgs.len() >= 9, "{} odometry messages in 1.5 s", msgs.len());
    let health = health_metric(&r, "checksum_errors", |v| v >= 3.0);
    assert_eq!(health.metric("checksum_errors"), Some(3.0));
    assert!(
        health.metric("bad_counts").unwrap() + health.metric("discarded_bytes").unwrap() >= 1.0
    );
    assert_eq!(health.metric("links_lost"), Some(0.0));
}

#[test]
fn arcos_decode_prints_one_json_object_per_captured_packet() {
    let capture =
        smokenav_tests::workspace_root().join("drivers/pioneer/codec/fixtures/amrisim_capture.txt");
    let out = std::process::Command::new(bin("smokenav"))
        .args(["arcos", "decode"])
        .arg(&capture)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<serde_json::Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // 8 commands, 3 SYNC replies, 39 SIPs.
    assert_eq!(lines.len(), 50);
    assert_eq!(lines.iter().filter(|v| v["kind"] == "sip").count(), 39);
    assert_eq!(lines[5]["ident"]["subclass"], "p3dx");
    let moving = lines.iter().find(|v| v["sip"]["x"] == 6).unwrap();
    assert_eq!(moving["sip"]["th"], -11);
    assert_eq!(moving["sip"]["rot_vel"], -100);
    assert!(String::from_utf8_lossy(&out.stderr).contains("50 packets, 0 checksum errors"));
}
