//! Replaying a recording must not drive the robot (issue #22, point 2): the
//! ARCOS emulator on a real PTY ↔ the real `smokenav-pioneer` driver ↔ the
//! real `smokenav record` and `smokenav play` CLIs, all on one bus instance.
//!
//! A run is recorded while `smokenav drive` moves the robot; replaying it onto
//! the live bus is refused (naming the driver) and moves nothing; forced, it
//! still leaves the velocity commands out, so the robot stays put.

use smokenav_pioneer_emulator::{Emulator, RobotConfig};
use smokenav_platform_bus::topics;
use smokenav_platform_recording::Playback;
use smokenav_shared_types::Odometry;
use smokenav_tests::{Child, bin, open_bus, profile, unique_instance, wait_for};
use std::time::Duration;

fn smokenav(args: &[&str], instance: &str) -> Child {
    Child::spawn(&bin("smokenav"), args, instance).unwrap()
}

fn run_to_end(args: &[&str], instance: &str, timeout: Duration) -> (bool, String) {
    let mut c = smokenav(args, instance);
    let status = c.wait_exit(timeout).unwrap();
    (status.success(), c.output())
}

/// The emulated robot's position, m.
fn position(h: &smokenav_pioneer_emulator::EmulatorHandle) -> (f64, f64) {
    let p = h.status().robot.pose;
    (p.x_mm / 1000.0, p.y_mm / 1000.0)
}

#[test]
fn replaying_a_drive_onto_the_live_bus_is_refused_and_never_moves_the_robot() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&dir.path().join("pioneer"), RobotConfig::default()).unwrap();
    let port = emu.port_arg();
    let config = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.base.port = port.clone()
    });
    let instance = unique_instance("replay_safety");
    let bus = open_bus(&instance);
    let config = config.to_string_lossy().into_owned();
    let mut driver =
        Child::spawn(&bin("smokenav-pioneer"), &["--config", &config], &instance).unwrap();
    wait_for::<Odometry>(&bus, topics::BASE_ODOM, Duration::from_secs(15), |_| true)
        .unwrap_or_else(|e| panic!("{e}\n{}", driver.output()));
    let h = emu.handle();

    // Record a 2 s drive at 0.3 m/s (the recorder's defaults: every topic,
    // base/cmd_vel included).
    let file = dir.path().join("drive.mcap");
    let file_s = file.to_string_lossy().into_owned();
    let mut recorder = smokenav(&["record", "-o", &file_s, "--duration", "3.5"], &instance);
    std::thread::sleep(Duration::from_millis(500));
    let (ok, out) = run_to_end(
        &["drive", "0.3", "0", "--for", "2"],
        &instance,
        Duration::from_secs(10),
    );
    assert!(ok, "{out}");
    assert!(
        recorder
            .wait_exit(Duration::from_secs(15))
            .unwrap()
            .success(),
        "{}",
        recorder.output()
    );
    let mut commands = 0;
    let mut playback = Playback::open(&file).unwrap();
    while let Some(p) = playback.read_next().unwrap() {
        commands += u32::from(p.topic == "base/cmd_vel");
    }
    assert!(commands >= 10, "the recording holds {commands} commands");
    h.wait_for(Duration::from_secs(3), |s| {
        s.robot.commanded.trans == 0.0 && s.robot.actual.trans == 0.0
    })
    .expect("robot stops after the drive");
    let before = position(&h);
    assert!(before.0 > 0.4, "the drive moved the robot to {before:?}");

    // Plain `play` onto the live bus: refused, naming the topics and the
    // driver that publishes them, and nothing is published.
    let (ok, out) = run_to_end(
        &["play", &file_s, "--fast"],
        &instance,
        Duration::from_secs(20),
    );
    eprintln!("plain play onto the live bus:\n{out}");
    assert!(!ok, "play onto a live bus must fail\n{out}");
    assert!(out.contains("refusing to play"), "{out}");
    assert!(out.contains("base/odom <- "), "{out}");
    assert!(out.contains("pioneer"), "names the driver: {out}");
    assert!(
        !out.contains("base/cmd_vel <-"),
        "commands are not even candidates: {out}"
    );
    assert!(!out.contains("played "), "{out}");

    // Forced, at the recorded pace: odometry and health go out, commands do not.
    let (ok, out) = run_to_end(
        &["play", &file_s, "--force"],
        &instance,
        Duration::from_secs(20),
    );
    assert!(ok, "{out}");
    assert!(
        out.contains(&format!("left out {commands} velocity commands")),
        "{out}"
    );
    assert!(!out.contains("base/cmd_vel    published"), "{out}");
    std::thread::sleep(Duration::from_millis(500));
    let after = position(&h);
    let moved = ((after.0 - before.0).powi(2) + (after.1 - before.1).powi(2)).sqrt();
    eprintln!("replay moved the robot {moved:.3} m (before the fix: about 0.6 m)");
    assert!(moved < 0.005, "the replay moved the robot {moved:.3} m");
    assert_eq!(h.status().robot.commanded.trans, 0.0);
    assert!(driver.terminate(Duration::from_secs(5)).unwrap().success());
}
