//! The emulator over a real pseudo-terminal, spoken to the way a driver does
//! (serialport at 38400 8N1 on the stable link path).

use smokenav_scout_codec::units::SONAR_NO_ECHO;
use smokenav_scout_codec::{
    Command, Direction, FrameError, PacketType, Reply, SonarOrder, Splitter, StateReply,
};
use smokenav_scout_emulator::{EmulatorConfig, ScoutEmulator};
use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

struct Host {
    port: serialport::TTYPort,
    splitter: Splitter,
    errors: Vec<FrameError>,
}

#[derive(Debug)]
enum Got {
    Reply(Reply),
    Timeout,
    LinkLost(#[allow(dead_code)] std::io::Error),
}

impl Host {
    fn open(path: &Path) -> std::io::Result<Host> {
        let port = serialport::new(path.to_string_lossy(), 38400)
            .timeout(Duration::from_millis(50))
            .open_native()
            .map_err(std::io::Error::other)?;
        Ok(Host {
            port,
            splitter: Splitter::new(Direction::ScoutReplies),
            errors: Vec::new(),
        })
    }

    fn send(&mut self, cmd: Command) {
        let mut out = [0u8; 32];
        let n = cmd.encode(&mut out).unwrap();
        self.send_raw(&out[..n]);
    }

    fn send_raw(&mut self, bytes: &[u8]) {
        self.port.write_all(bytes).unwrap();
    }

    fn recv(&mut self, timeout: Duration) -> Got {
        let deadline = Instant::now() + timeout;
        let mut buf = [0u8; 256];
        loop {
            while let Some(item) = self.splitter.next_frame() {
                match item {
                    Ok(f) => return Got::Reply(Reply::decode(f).unwrap()),
                    Err(e) => self.errors.push(e),
                }
            }
            if Instant::now() >= deadline {
                return Got::Timeout;
            }
            match self.port.read(&mut buf) {
                Ok(0) => return Got::LinkLost(std::io::ErrorKind::UnexpectedEof.into()),
                Ok(n) => {
                    self.splitter.feed(&buf[..n]);
                }
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) => return Got::LinkLost(e),
            }
        }
    }

    fn request(&mut self, cmd: Command) -> StateReply {
        self.splitter.clear();
        self.send(cmd);
        match self.recv(Duration::from_secs(1)) {
            Got::Reply(Reply::State { to, state }) => {
                assert_eq!(to, cmd.packet_type(), "reply type echoes the command");
                state
            }
            other => panic!("{cmd:?}: expected a state reply, got {other:?}"),
        }
    }
}

fn start() -> (tempfile::TempDir, ScoutEmulator) {
    let dir = tempfile::tempdir().unwrap();
    let emu = ScoutEmulator::start(EmulatorConfig::new(dir.path().join("scout"))).unwrap();
    (dir, emu)
}

#[test]
fn link_path_points_at_a_pts_device() {
    let (_dir, emu) = start();
    let target = std::fs::read_link(emu.path()).unwrap();
    assert!(target.starts_with("/dev/pts/"), "{target:?}");
    assert_eq!(Some(target), emu.device_path());
}

#[test]
fn gs_reply_carries_the_fed_sonar_ranges() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    let fed: [u8; 16] = [
        12,
        24,
        36,
        48,
        60,
        72,
        84,
        96,
        108,
        120,
        132,
        144,
        156,
        168,
        200,
        SONAR_NO_ECHO,
    ];
    emu.set_sonar_inches(fed);
    // rate 1 × 4 ms: the whole ring fires in 64 ms.
    let order =
        SonarOrder::from_indices(&[0, 2, 15, 1, 14, 3, 13, 4, 12, 5, 11, 6, 10, 7, 9, 8]).unwrap();
    host.request(Command::ConfSonar { rate: 1, order });
    std::thread::sleep(Duration::from_millis(100));
    let s = host.request(Command::GetState);
    assert_eq!(s.sonar_in, fed);
    let snap = emu.snapshot();
    assert_eq!(snap.sonar_rate, 1);
    assert_eq!(snap.sonar_order, order);
    assert_eq!(snap.stats.conf_sonar, 1);
}

#[test]
fn vm_moves_the_robot_and_st_stops_it() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    // vm(100, 100, 0): 10 in/s on both wheels.
    let s = host.request(Command::Velocity([100, 100, 0]));
    assert_eq!(s.velocity, [100, 100, 0]);
    std::thread::sleep(Duration::from_millis(500));
    let s = host.request(Command::Stop);
    // ≈ 5 in after 0.5 s (pacing and scheduling add a little).
    assert!((45..=65).contains(&s.x), "x = {} tenths of an inch", s.x);
    assert_eq!(s.velocity, [0, 0, 0]);
    let x_stopped = s.x;
    std::thread::sleep(Duration::from_millis(200));
    assert_eq!(host.request(Command::GetState).x, x_stopped);
}

#[test]
fn reverse_turn_reports_negative_wheel_speeds() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    // vm(107, -107, 0): right forward, left back ⇒ turning counter-clockwise.
    host.request(Command::Velocity([107, -107, 0]));
    std::thread::sleep(Duration::from_millis(300));
    let s = host.request(Command::GetState);
    assert_eq!(s.velocity, [107, -107, 0]);
    assert!(s.heading > 0 && s.heading < 900, "heading {}", s.heading);
    assert!(s.motor.left_moving() && s.motor.right_moving());
}

#[test]
fn conf_tm_watchdog_stops_the_wheels_when_the_host_goes_quiet() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    host.request(Command::ConfTimeout(1));
    host.request(Command::Velocity([100, 100, 0]));
    let (snap, stopped) = emu.wait_for(Duration::from_secs(3), |s| s.watchdog_trips == 1);
    assert!(stopped, "watchdog did not fire: {snap:?}");
    assert_eq!(snap.wheels.left, 0.0);
    assert_eq!(snap.watchdog_s, 1);
    // It ran for the 1 s watchdog period: 10 in.
    let s = host.request(Command::GetState);
    assert!((95..=110).contains(&s.x), "x = {}", s.x);
    assert_eq!(s.velocity, [0, 0, 0]);
}

#[test]
fn corrupted_reply_fails_its_checksum_and_the_next_one_is_good() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    emu.corrupt_next_replies(1);
    host.send(Command::GetState);
    assert!(matches!(
        host.recv(Duration::from_millis(300)),
        Got::Timeout
    ));
    assert!(
        host.errors
            .iter()
            .any(|e| matches!(e, FrameError::BadChecksum { .. })),
        "{:?}",
        host.errors
    );
    host.request(Command::GetState);
    assert_eq!(emu.stats().corrupted, 1);
}

#[test]
fn damaged_command_is_answered_with_nak() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    // gs with its checksum 0x0A changed to 0x0B.
    host.send_raw(&[0x01, 0x02, 0x00, 0x07, 0x0B, 0x5C]);
    assert!(matches!(
        host.recv(Duration::from_secs(1)),
        Got::Reply(Reply::Nak)
    ));
    assert_eq!(emu.stats().host_frame_errors, 1);
    assert_eq!(emu.stats().get_state, 0);
}

#[test]
fn nak_hook_refuses_commands_without_running_them() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    emu.nak_next_commands(1);
    host.send(Command::Velocity([100, 100, 0]));
    assert!(matches!(
        host.recv(Duration::from_secs(1)),
        Got::Reply(Reply::Nak)
    ));
    assert_eq!(emu.snapshot().wheels.left, 0.0);
    let s = host.request(Command::Velocity([100, 100, 0]));
    assert_eq!(s.velocity, [100, 100, 0]);
    assert_eq!(emu.stats().naks, 1);
}

#[test]
fn garbage_on_the_line_is_skipped_by_the_host_splitter() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    emu.send_garbage(&[0xFF, 0x01, 0x13, 0x37, 0x5C, 0x00]);
    std::thread::sleep(Duration::from_millis(50));
    host.send(Command::GetState);
    match host.recv(Duration::from_secs(1)) {
        Got::Reply(Reply::State { to, .. }) => assert_eq!(to, PacketType::Gs),
        other => panic!("{other:?}"),
    }
    assert!(host.splitter.stats().garbage_bytes + host.splitter.stats().bad_frames() > 0);
    assert_eq!(emu.stats().garbage_sent, 6);
}

#[test]
fn truncated_reply_times_out_and_the_link_recovers() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    emu.truncate_next_replies(1);
    host.send(Command::GetState);
    assert!(matches!(
        host.recv(Duration::from_millis(300)),
        Got::Timeout
    ));
    host.request(Command::GetState);
    assert_eq!(emu.stats().truncated, 1);
}

#[test]
fn silent_robot_does_not_answer_or_execute() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    emu.set_silent(true);
    host.send(Command::Velocity([100, 100, 0]));
    assert!(matches!(
        host.recv(Duration::from_millis(300)),
        Got::Timeout
    ));
    assert_eq!(emu.snapshot().wheels.left, 0.0);
    assert_eq!(emu.stats().ignored, 1);
    emu.set_silent(false);
    host.request(Command::GetState);
}

#[test]
fn stall_ends_by_itself() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    emu.stall_for(Duration::from_millis(300));
    host.send(Command::GetState);
    assert!(matches!(
        host.recv(Duration::from_millis(200)),
        Got::Timeout
    ));
    std::thread::sleep(Duration::from_millis(150));
    host.request(Command::GetState);
}

#[test]
fn unplug_fails_the_open_port_and_replug_serves_the_same_path() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    host.request(Command::Velocity([50, 50, 0]));
    let first = emu.device_path().unwrap();
    emu.disconnect();
    assert!(!emu.snapshot().connected);
    assert!(!emu.path().exists(), "link path removed while unplugged");
    // Writing or reading the unplugged port fails (serialport reports the
    // hang-up as a broken pipe on write, an I/O error on read).
    let write = host.port.write_all(&[0x01, 0x02, 0x00, 0x07, 0x0A, 0x5C]);
    if write.is_ok() {
        assert!(
            matches!(host.recv(Duration::from_millis(500)), Got::LinkLost(_)),
            "reads on an unplugged port must fail"
        );
    }
    assert!(Host::open(emu.path()).is_err());
    emu.reconnect();
    assert!(emu.snapshot().connected);
    let mut host = Host::open(emu.path()).unwrap();
    let s = host.request(Command::GetState);
    // The robot kept driving while unplugged (no watchdog armed).
    assert_eq!(s.velocity, [50, 50, 0]);
    assert!(s.x > 0);
    assert_eq!(emu.stats().reconnects, 1);
    let second = emu.device_path().unwrap();
    assert!(second.starts_with("/dev/pts/"), "{first:?} → {second:?}");
}

#[test]
fn dp_and_da_redefine_the_reported_odometry() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    let s = host.request(Command::DefinePosition { x: -1234, y: 4321 });
    assert_eq!((s.x, s.y), (-1234, 4321));
    let s = host.request(Command::DefineAngles {
        heading: 1800,
        turret: 0,
    });
    assert_eq!(s.heading, 1800);
    let s = host.request(Command::Zero);
    assert_eq!((s.x, s.y, s.heading), (0, 0, 0));
}

#[test]
fn voltages_and_power_bits_reach_the_state_reply() {
    let (_dir, emu) = start();
    let mut host = Host::open(emu.path()).unwrap();
    emu.set_voltages(10.0, 12.0);
    emu.set_power(smokenav_scout_emulator::Battery::Medium, true, true);
    emu.set_bumpers(0b101);
    let s = host.request(Command::GetState);
    let si =
        smokenav_scout_codec::DiffDrive::new(0.345, smokenav_scout_codec::WheelOrder::RightLeft)
            .state_si(&s);
    assert!((si.cpu_v - 10.0).abs() < 0.03, "{}", si.cpu_v);
    assert!((si.motor_v - 12.0).abs() < 0.03, "{}", si.motor_v);
    assert_eq!(s.motor.battery(), smokenav_scout_emulator::Battery::Medium);
    assert!(s.motor.plugged_in() && s.motor.charging() && !s.motor.estop());
    assert_eq!(s.bumpers, 0b101);
}
