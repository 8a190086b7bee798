//! The emulator over a real pseudo-terminal (opened with `serialport`, as a
//! driver opens a robot) and over TCP.

use smokenav_pioneer_codec::{
    Command, Framer, FramerStats, RobotIdent, RobotPacket, Sip, decode_robot_packet,
};
use smokenav_pioneer_emulator::{Emulator, Phase, Pose, RobotConfig};
use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// The host side of the link, reading through the codec's framer.
struct Host {
    port: Box<dyn ReadWrite>,
    framer: Framer,
}

trait ReadWrite: Read + Write + Send {}
impl<T: Read + Write + Send> ReadWrite for T {}

impl Host {
    fn serial(path: &std::path::Path) -> Self {
        let port = serialport::new(path.to_string_lossy(), 9600)
            .timeout(Duration::from_millis(20))
            .open_native()
            .expect("open the emulator's PTY like a serial port");
        Self {
            port: Box::new(port),
            framer: Framer::new(),
        }
    }

    fn tcp(addr: std::net::SocketAddr) -> Self {
        let s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_millis(20))).unwrap();
        Self {
            port: Box::new(s),
            framer: Framer::new(),
        }
    }

    fn send(&mut self, c: Command<'_>) {
        self.port.write_all(c.packet().unwrap().as_bytes()).unwrap();
    }

    /// Everything that arrives within `d`. `Err` when the port failed.
    fn recv_for(&mut self, d: Duration) -> Result<Vec<RobotPacket>, std::io::Error> {
        let end = Instant::now() + d;
        let mut out = Vec::new();
        let mut buf = [0u8; 256];
        while Instant::now() < end {
            match self.port.read(&mut buf) {
                Ok(0) => return Err(ErrorKind::UnexpectedEof.into()),
                Ok(n) => self.framer.feed(&buf[..n], |r| {
                    if let Ok(p) = r {
                        out.push(decode_robot_packet(p).unwrap());
                    }
                }),
                Err(e) if matches!(e.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock) => {}
                Err(e) => return Err(e),
            }
        }
        Ok(out)
    }

    fn sips_for(&mut self, d: Duration) -> Vec<Sip> {
        sips(self.recv_for(d).unwrap())
    }

    fn handshake(&mut self) -> RobotIdent {
        let mut ident = None;
        for c in [Command::Sync0, Command::Sync1, Command::Sync2] {
            self.send(c);
            for p in self.recv_for(Duration::from_millis(150)).unwrap() {
                if let RobotPacket::Ident(id) = p {
                    ident = Some(id);
                }
            }
        }
        ident.expect("SYNC2 reply")
    }

    fn stats(&self) -> FramerStats {
        self.framer.stats()
    }
}

fn sips(packets: Vec<RobotPacket>) -> Vec<Sip> {
    packets
        .into_iter()
        .filter_map(|p| match p {
            RobotPacket::Sip(s) => Some(s),
            _ => None,
        })
        .collect()
}

fn link_path(dir: &tempfile::TempDir) -> PathBuf {
    dir.path().join("pioneer")
}

#[test]
fn handshake_and_sips_at_10_hz_over_a_real_pty() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&link_path(&dir), RobotConfig::default()).unwrap();
    let mut host = Host::serial(&link_path(&dir));
    let id = host.handshake();
    assert_eq!(id, RobotIdent::new("smokenav-emulator", "Pioneer", "p3dx"));
    host.send(Command::Open);
    host.send(Command::Enable(true));
    host.send(Command::Sonar(true));
    let sips = host.sips_for(Duration::from_millis(1500));
    // 100 ms period: 15 ± 2 in 1.5 s.
    assert!((13..=17).contains(&sips.len()), "{} SIPs", sips.len());
    let last = sips.last().unwrap();
    assert!(last.motors_enabled());
    assert_eq!(last.sonars.len(), 16);
    assert_eq!(last.battery_x10, Some(130));
    assert_eq!(emu.handle().status().robot.counters.opens, 1);
}

#[test]
fn commanded_velocity_is_visible_to_the_owner_and_moves_odometry() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&link_path(&dir), RobotConfig::default()).unwrap();
    let h = emu.handle();
    let mut host = Host::serial(&link_path(&dir));
    host.handshake();
    host.send(Command::Open);
    host.send(Command::Enable(true));
    host.send(Command::Vel(300));
    host.send(Command::RVel(-20));
    // Two packets: the emulator may have taken the first and not yet the
    // second when it reports (a flake seen once in `./test`).
    let st = h
        .wait_for(Duration::from_secs(1), |s| {
            s.robot.commanded.trans == 300.0 && s.robot.commanded.rot == -20.0
        })
        .unwrap();
    assert_eq!(st.robot.commanded.rot, -20.0);
    let sips = host.sips_for(Duration::from_millis(1000));
    let first = sips.first().unwrap();
    let last = sips.last().unwrap();
    assert!(last.x > first.x + 300, "x {} -> {}", first.x, last.x);
    assert!(last.th < 0);
    assert!(last.is_moving());
    assert_eq!(last.rot_vel, Some(-200));
}

#[test]
fn sonar_ranges_set_by_the_owner_appear_in_sips() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&link_path(&dir), RobotConfig::default()).unwrap();
    emu.handle().set_sonar_ranges(&[400, 900, 5000]);
    let mut host = Host::serial(&link_path(&dir));
    host.handshake();
    host.send(Command::Open);
    host.send(Command::Sonar(true));
    let s = host.sips_for(Duration::from_millis(400)).pop().unwrap();
    let r: Vec<(u8, u16)> = s
        .sonars
        .as_slice()
        .iter()
        .take(4)
        .map(|r| (r.index, r.range))
        .collect();
    assert_eq!(r, [(0, 400), (1, 900), (2, 5000), (3, 5000)]);
}

#[test]
fn corrupted_checksums_are_dropped_and_the_stream_recovers() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&link_path(&dir), RobotConfig::default()).unwrap();
    let mut host = Host::serial(&link_path(&dir));
    host.handshake();
    host.send(Command::Open);
    host.sips_for(Duration::from_millis(250));
    emu.handle().corrupt_next_packets(3);
    emu.handle()
        .inject_noise(&[0x00, 0xFA, 0xFB, 0x00, 0x13, 0x37]);
    let after = host.sips_for(Duration::from_millis(800));
    assert_eq!(host.stats().checksum_errors, 3);
    assert!(host.stats().bad_counts + host.stats().discarded_bytes > 0);
    assert!(
        after.len() >= 3,
        "{} good SIPs after the faults",
        after.len()
    );
    assert_eq!(emu.handle().status().link.tx_corrupted, 3);
}

#[test]
fn silence_fault_stops_all_output_until_lifted() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&link_path(&dir), RobotConfig::default()).unwrap();
    let mut host = Host::serial(&link_path(&dir));
    host.handshake();
    host.send(Command::Open);
    assert!(!host.sips_for(Duration::from_millis(300)).is_empty());
    emu.handle().set_silent(true);
    host.recv_for(Duration::from_millis(150)).unwrap(); // in flight
    assert!(
        host.recv_for(Duration::from_millis(500))
            .unwrap()
            .is_empty()
    );
    emu.handle().set_silent(false);
    assert!(!host.sips_for(Duration::from_millis(300)).is_empty());
}

#[test]
fn stale_session_streams_before_sync_until_closed() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(
        &link_path(&dir),
        RobotConfig {
            start_open: true,
            ..Default::default()
        },
    )
    .unwrap();
    let mut host = Host::serial(&link_path(&dir));
    // SYNC0 on an open session is a PULSE: no echo, SIPs keep coming.
    host.send(Command::Sync0);
    let got = host.recv_for(Duration::from_millis(400)).unwrap();
    assert!(
        !got.is_empty() && got.iter().all(|p| matches!(p, RobotPacket::Sip(_))),
        "{got:?}"
    );
    host.send(Command::Close);
    host.recv_for(Duration::from_millis(150)).unwrap();
    assert!(
        host.recv_for(Duration::from_millis(300))
            .unwrap()
            .is_empty()
    );
    assert_eq!(
        emu.handle().status().robot.phase,
        Phase::Handshake { next: 0 }
    );
    host.handshake();
}

#[test]
fn firmware_watchdog_stops_a_robot_left_driving() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(
        &link_path(&dir),
        RobotConfig {
            watchdog_ms: 300,
            ..Default::default()
        },
    )
    .unwrap();
    let h = emu.handle();
    let mut host = Host::serial(&link_path(&dir));
    host.handshake();
    host.send(Command::Open);
    host.send(Command::Enable(true));
    host.send(Command::Vel(200));
    h.wait_for(Duration::from_secs(1), |s| s.robot.commanded.trans == 200.0)
        .unwrap();
    let st = h
        .wait_for(Duration::from_secs(2), |s| s.robot.watchdog_tripped)
        .expect("watchdog trips");
    assert_eq!(st.robot.commanded.trans, 0.0);
    assert_eq!(st.robot.counters.watchdog_trips, 1);
}

#[test]
fn unplug_removes_the_device_and_replug_keeps_the_session_open() {
    let dir = tempfile::tempdir().unwrap();
    let link = link_path(&dir);
    let emu = Emulator::pty(&link, RobotConfig::default()).unwrap();
    let h = emu.handle();
    let before = h.status().link.device.unwrap();
    let mut host = Host::serial(&link);
    host.handshake();
    host.send(Command::Open);
    assert!(!host.sips_for(Duration::from_millis(300)).is_empty());
    h.unplug(Duration::from_millis(400));
    // The host's read fails (EIO/hang-up) or at least goes quiet.
    let r = host.recv_for(Duration::from_millis(250));
    assert!(r.as_ref().map_or(true, |p| p.len() <= 1), "{r:?}");
    assert!(
        std::fs::symlink_metadata(&link).is_err(),
        "symlink should be gone while unplugged"
    );
    let st = h
        .wait_for(Duration::from_secs(2), |s| {
            s.link.device.as_ref().is_some_and(|d| *d != before)
        })
        .expect("plugged back in");
    assert!(st.link.connected);
    let mut host = Host::serial(&link);
    // Nobody closed the session: SIPs come without a handshake.
    assert!(!host.sips_for(Duration::from_millis(400)).is_empty());
}

#[test]
fn tcp_like_mobilesim_new_client_new_session() {
    let emu = Emulator::tcp("127.0.0.1:0", RobotConfig::default()).unwrap();
    assert!(emu.port_arg().starts_with("tcp://127.0.0.1:"));
    let addr = emu.tcp_addr().unwrap();
    let mut host = Host::tcp(addr);
    host.handshake();
    host.send(Command::Open);
    host.send(Command::Enable(true));
    host.send(Command::Vel(100));
    assert!(host.sips_for(Duration::from_millis(500)).len() >= 3);
    drop(host);
    // Like AMRISim: the session ends with the connection, motion stops.
    let st = emu
        .handle()
        .wait_for(Duration::from_secs(1), |s| {
            s.robot.phase == Phase::Handshake { next: 0 }
        })
        .unwrap();
    assert_eq!(st.robot.commanded.trans, 0.0);
    let mut host = Host::tcp(addr);
    host.handshake();
    assert_eq!(emu.handle().status().link.clients, 2);
}

#[test]
fn owner_driven_pose_is_reported_as_odometry() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&link_path(&dir), RobotConfig::default()).unwrap();
    let h = emu.handle();
    h.set_external_motion(true);
    let mut host = Host::serial(&link_path(&dir));
    host.handshake();
    host.send(Command::Open);
    h.set_pose(Pose::new(485.0, -97.0, 0.0));
    host.recv_for(Duration::from_millis(150)).unwrap();
    let s = host.sips_for(Duration::from_millis(250)).pop().unwrap();
    // p3dx: 485 mm / 0.485 = 1000 units; -97 mm = -200 units -> 32568 in 15 bits.
    assert_eq!(s.x_pos(), 1000);
    assert_eq!(s.y_pos(), 0x8000 - 200);
}
