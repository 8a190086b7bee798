//! The driver's link against the emulator on a real PTY.

use smokenav_scout_codec::Command;
use smokenav_scout_driver::{Link, LinkError, PortSpec};
use smokenav_scout_emulator::{EmulatorConfig, ScoutEmulator};
use std::time::Duration;

const T: Duration = Duration::from_millis(300);

fn start() -> (tempfile::TempDir, ScoutEmulator, Link) {
    let dir = tempfile::tempdir().unwrap();
    let emu = ScoutEmulator::start(EmulatorConfig::new(dir.path().join("scout"))).unwrap();
    let link = Link::open(
        &PortSpec::Serial(emu.path().to_string_lossy().into_owned()),
        38400,
    )
    .unwrap();
    (dir, emu, link)
}

#[test]
fn exchange_returns_the_state_reply_of_its_command() {
    let (_d, emu, mut link) = start();
    emu.set_sonar_inches([77; 16]);
    let s = link.exchange(Command::Velocity([-30, 30, 0]), T).unwrap();
    assert_eq!(s.velocity, [-30, 30, 0]);
    assert_eq!(link.stats().replies, 1);
    assert_eq!(emu.stats().velocity, 1);
}

#[test]
fn nak_is_reported_as_nak() {
    let (_d, emu, mut link) = start();
    emu.nak_next_commands(1);
    assert!(matches!(
        link.exchange(Command::GetState, T),
        Err(LinkError::Nak)
    ));
    assert!(link.exchange(Command::GetState, T).is_ok());
    assert_eq!(link.stats().naks, 1);
}

#[test]
fn corrupted_reply_times_out_and_is_counted() {
    let (_d, emu, mut link) = start();
    emu.corrupt_next_replies(1);
    let e = link.exchange(Command::GetState, T).unwrap_err();
    assert!(matches!(e, LinkError::Timeout(_)) && !e.is_fatal());
    assert_eq!(link.frame_stats().checksum_errors, 1);
    assert!(link.exchange(Command::GetState, T).is_ok());
}

#[test]
fn garbage_before_the_reply_is_skipped() {
    let (_d, emu, mut link) = start();
    emu.stall_for(Duration::from_millis(100));
    // The request is swallowed by the stall; garbage then a good exchange.
    let _ = link.exchange(Command::GetState, Duration::from_millis(150));
    emu.send_garbage(&[0x01, 0x2C, 0x00, 0x07, 0x99, 0x5C, 0xAA]);
    std::thread::sleep(Duration::from_millis(20));
    assert!(link.exchange(Command::GetState, T).is_ok());
}

#[test]
fn unplug_is_fatal_and_the_path_reopens_after_replug() {
    let (_d, emu, mut link) = start();
    emu.disconnect();
    let e = link.exchange(Command::GetState, T).unwrap_err();
    assert!(e.is_fatal(), "{e}");
    let spec = PortSpec::Serial(emu.path().to_string_lossy().into_owned());
    assert!(Link::open(&spec, 38400).is_err());
    emu.reconnect();
    let mut link = Link::open(&spec, 38400).unwrap();
    assert!(link.exchange(Command::GetState, T).is_ok());
}
