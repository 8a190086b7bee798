//! The emulator over a real pseudo-terminal (and TCP), checked with the codec.

mod common;

use common::Host;
use nix::sys::termios::BaudRate;
use smokenav_hokuyo_codec::{Command, SensorSpec, SensorState, Status, VersionInfo, parse_reply};
use smokenav_hokuyo_emulator::{BootState, DeviceConfig, Emulator, EmulatorConfig, Link, Model};
use std::path::PathBuf;
use std::time::Duration;

fn spawn(device: DeviceConfig) -> (Emulator, tempfile::TempDir) {
    let dir = tempfile::tempdir().unwrap();
    let emu =
        Emulator::spawn(EmulatorConfig::pty(device, Some(dir.path().join("hokuyo")))).unwrap();
    (emu, dir)
}

fn host(emu: &Emulator) -> Host {
    Host::open_pty(&PathBuf::from(emu.port()), BaudRate::B115200)
}

fn status_of(frame: &[u8]) -> Status {
    parse_reply(frame).unwrap().status
}

fn ramp() -> Vec<u16> {
    // 682 steps: codes 0, 6, 7 at a few steps, ranges elsewhere.
    (0..682u16)
        .map(|i| match i {
            0 => 0,
            1 => 6,
            2 => 7,
            i => 100 + i * 7,
        })
        .collect()
}

#[test]
fn boots_in_scip11_and_switches_to_scip20_like_the_04lx() {
    let (emu, _dir) = spawn(DeviceConfig::default());
    let mut h = host(&emu);
    // SCIP 1.1 does not know QT: echo, bare `E`.
    assert_eq!(status_of(&h.ask("QT")), Status::Bare(b'E'));
    let f = h.ask("SCIP2.0");
    assert_eq!(f, b"SCIP2.0\n0\n\n");
    // Already in 2.0: status 0E with its checksum `e`.
    assert_eq!(h.ask("SCIP2.0"), b"SCIP2.0\n0Ee\n\n");
    assert_eq!(h.ask("QT"), b"QT\n00P\n\n");

    let vv = VersionInfo::from_reply(&parse_reply(&h.ask("VV")).unwrap()).unwrap();
    assert_eq!(vv.firmware, "3.1.00(18/Jan./2007)");
    let pp_frame = h.ask("PP");
    // The PP reply is byte-identical to the real capture.
    let capture = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../codec/tests/vectors/A_wiki_vv_pp_ii.txt"
    ))
    .unwrap();
    let start = capture.windows(3).position(|w| w == b"PP\n").unwrap();
    assert_eq!(&capture[start..start + pp_frame.len()], &pp_frame[..]);
    let pp = SensorSpec::from_reply(&parse_reply(&pp_frame).unwrap()).unwrap();
    assert_eq!(
        (pp.geometry.amin, pp.geometry.amax, pp.geometry.ares),
        (44, 725, 1024)
    );
    let ii = SensorState::from_reply(&parse_reply(&h.ask("II")).unwrap()).unwrap();
    assert_eq!(ii.laser, "OFF");
    assert!(ii.is_healthy());
}

#[test]
fn md_stream_counts_down_n_minus_1_to_00_at_10_hz() {
    let (emu, _dir) = spawn(DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    });
    emu.set_scan(&ramp());
    let mut h = host(&emu);
    let ack = h.ask("MD0044072501003;run.1");
    assert_eq!(ack, b"MD0044072501003;run.1\n00P\n\n");
    let mut stamps = Vec::new();
    let mut ranges = [0u32; 1081];
    for expected_remaining in [2u8, 1, 0] {
        let f = h
            .frame(Duration::from_millis(500))
            .expect("scan within 500 ms");
        let r = parse_reply(&f).unwrap();
        assert_eq!(r.status, Status::SCAN_DATA);
        assert_eq!(r.echo.tag, Some(&b"run.1"[..]));
        assert!(parse_reply(&ack).unwrap().echo.same_stream(&r.echo));
        let sh = r.decode_scan(&mut ranges, &mut []).unwrap();
        assert_eq!(sh.echo.remaining, expected_remaining);
        assert_eq!(sh.count, 682);
        let fed: Vec<u32> = ramp().iter().map(|&v| u32::from(v)).collect();
        assert_eq!(&ranges[..682], &fed[..]);
        stamps.push(sh.timestamp);
    }
    // 600 rpm: scans 100 ms apart on the sensor clock.
    assert_eq!(stamps[1] - stamps[0], 100);
    assert_eq!(stamps[2] - stamps[1], 100);
    // The count is exhausted: nothing more comes.
    assert!(h.frame(Duration::from_millis(300)).is_none());
    let sent = emu.sent_scans();
    assert_eq!(sent.len(), 3);
    assert_eq!(
        sent.iter().map(|s| s.timestamp_ms).collect::<Vec<_>>(),
        stamps
    );
}

#[test]
fn gd_needs_bm_and_clusters_report_the_smallest_valid_value() {
    let (emu, _dir) = spawn(DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    });
    emu.set_scan(&ramp());
    let mut h = host(&emu);
    assert_eq!(h.ask("GD0044072501"), b"GD0044072501\n10Q\n\n");
    assert_eq!(h.ask("BM"), b"BM\n00P\n\n");
    assert_eq!(h.ask("BM"), b"BM\n02R\n\n");
    std::thread::sleep(Duration::from_millis(120));
    let f = h.ask("GD0044072503");
    let mut r = [0u32; 1081];
    let sh = parse_reply(&f)
        .unwrap()
        .decode_scan(&mut r, &mut [])
        .unwrap();
    // 682 steps in clusters of 3 → 228 values; the first cluster holds codes 0, 6, 7
    // and no valid range, so it reports the first step's code.
    assert_eq!(sh.count, 228);
    assert_eq!(r[0], 0);
    assert_eq!(r[1], 100 + 3 * 7);
    // End beyond AMAX (725) and end before start are refused.
    assert_eq!(status_of(&h.ask("GD0044072601")), Status::Code(*b"04"));
    assert_eq!(status_of(&h.ask("GD0100005001")), Status::Code(*b"05"));
    assert_eq!(status_of(&h.ask("GS0044072501")), Status::OK);
}

#[test]
fn time_adjust_mode_refuses_other_commands_with_0e() {
    let (emu, _dir) = spawn(DeviceConfig {
        boot: BootState {
            time_adjust: true,
            ..Default::default()
        },
        sensor_time_start_ms: 16_777_000,
        ..Default::default()
    });
    let mut h = host(&emu);
    // A sensor left in time-adjust mode: QT answers 0E, TM2 gets it out.
    assert_eq!(h.ask("QT"), b"QT\n0Ee\n\n");
    let before = emu.sensor_ms();
    let f = h.ask("TM1");
    let t = parse_reply(&f).unwrap().time().unwrap();
    let after = emu.sensor_ms();
    // The timer started at 16 777 000 ms and wraps at 2^24 = 16 777 216.
    let unwrap = |v: u32| {
        if v < 1_000_000 {
            u64::from(v) + (1 << 24)
        } else {
            u64::from(v)
        }
    };
    assert!(
        unwrap(before) <= unwrap(t) && unwrap(t) <= unwrap(after),
        "{before} {t} {after}"
    );
    assert_eq!(h.ask("TM0"), b"TM0\n02R\n\n");
    assert_eq!(h.ask("TM2"), b"TM2\n00P\n\n");
    assert_eq!(status_of(&h.ask("TM2")), Status::Code(*b"03"));
    assert_eq!(status_of(&h.ask("TM1")), Status::Code(*b"04"));
    assert_eq!(h.ask("QT"), b"QT\n00P\n\n");
}

#[test]
fn sensor_left_streaming_sends_scans_unasked_until_qt() {
    let (emu, _dir) = spawn(DeviceConfig {
        boot: BootState {
            streaming: true,
            ..Default::default()
        },
        ..Default::default()
    });
    let mut h = host(&emu);
    let f = h
        .frame(Duration::from_millis(500))
        .expect("a streamed scan");
    let r = parse_reply(&f).unwrap();
    assert_eq!(r.echo.command, Command::Md);
    assert_eq!(r.status, Status::SCAN_DATA);
    h.send("QT");
    // Scans already in flight may come first; the QT reply follows.
    let mut got_qt = false;
    for _ in 0..5 {
        let f = h.frame(Duration::from_millis(500)).expect("frame");
        if parse_reply(&f).unwrap().echo.command == Command::Qt {
            got_qt = true;
            break;
        }
    }
    assert!(got_qt);
    assert!(h.frame(Duration::from_millis(300)).is_none());
    assert!(!emu.state().streaming);
}

#[test]
fn injected_faults_damage_exactly_what_they_say() {
    let (emu, _dir) = spawn(DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    });
    let mut h = host(&emu);
    emu.set_corrupt_line_fraction(1.0);
    h.ask("MD0044072501001");
    let f = h.frame(Duration::from_millis(500)).unwrap();
    let mut r = [0u32; 1081];
    let err = parse_reply(&f)
        .unwrap()
        .decode_scan(&mut r, &mut [])
        .unwrap_err();
    assert!(
        matches!(
            err,
            smokenav_hokuyo_codec::DecodeError::Checksum { line: 4, .. }
        ),
        "{err}"
    );
    // 682·3 = 2046 chars → 32 data lines, all corrupted.
    assert_eq!(emu.stats().lines_corrupted, 32);
    assert_eq!(emu.stats().scans_damaged, 1);

    emu.set_corrupt_line_fraction(0.0);
    emu.truncate_next_lines(1);
    h.ask("MD0044072501001");
    let f = h.frame(Duration::from_millis(500)).unwrap();
    assert!(
        parse_reply(&f)
            .unwrap()
            .decode_scan(&mut r, &mut [])
            .is_err()
    );

    emu.inject_garbage(b"\x00\xffgarbage");
    let f = h.ask("QT");
    // Garbage lands in front of the echo: that frame is lost, the next is fine.
    assert!(parse_reply(&f).is_err());
    assert_eq!(h.ask("QT"), b"QT\n00P\n\n");
}

#[test]
fn disconnect_removes_the_link_and_reconnect_recreates_it_power_cycled() {
    let (emu, dir) = spawn(DeviceConfig::default());
    let link = dir.path().join("hokuyo");
    let mut h = host(&emu);
    assert_eq!(h.ask("SCIP2.0"), b"SCIP2.0\n0\n\n");
    let first_slave = emu.slave_path().unwrap();
    emu.disconnect();
    // The host sees the device vanish: reads fail or hit end of file.
    assert!(h.frame(Duration::from_millis(500)).is_none());
    std::thread::sleep(Duration::from_millis(50));
    assert!(!link.exists());
    emu.reconnect(true);
    std::thread::sleep(Duration::from_millis(100));
    assert!(link.exists());
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        emu.slave_path().unwrap()
    );
    let _ = first_slave;
    let mut h = host(&emu);
    // Power-cycled: back in SCIP 1.1.
    assert_eq!(status_of(&h.ask("QT")), Status::Bare(b'E'));
    assert_eq!(emu.stats().power_cycles, 1);
}

#[test]
fn me_hangs_a_04lx_until_power_cycled() {
    let (emu, _dir) = spawn(DeviceConfig {
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    });
    let mut h = host(&emu);
    h.send("ME0044072501000");
    assert!(h.frame(Duration::from_millis(300)).is_none());
    h.send("QT");
    assert!(h.frame(Duration::from_millis(300)).is_none());
    assert!(emu.state().hung);
    assert_eq!(emu.stats().me_requests, 1);
}

#[test]
fn rs232_link_ignores_the_wrong_baud_and_follows_ss() {
    let (emu, _dir) = spawn(DeviceConfig {
        link: Link::Rs232,
        boot: BootState {
            scip11: Some(false),
            ..Default::default()
        },
        ..Default::default()
    });
    let mut h = host(&emu);
    // The port is at 115200, the 04LX at its power-up 19200: nothing intelligible.
    h.send("QT");
    assert!(h.frame(Duration::from_millis(200)).is_none());
    h.set_baud(BaudRate::B19200);
    assert_eq!(h.ask("QT"), b"QT\n00P\n\n");
    assert_eq!(h.ask("SS019200"), b"SS019200\n03S\n\n");
    assert_eq!(h.ask("SS115200"), b"SS115200\n00P\n\n");
    h.send("QT");
    assert!(h.frame(Duration::from_millis(200)).is_none());
    h.set_baud(BaudRate::B115200);
    assert_eq!(h.ask("QT"), b"QT\n00P\n\n");
    assert_eq!(emu.state().baud, 115_200);
    assert_eq!(status_of(&h.ask("SS038400")), Status::Code(*b"04"));
    assert_eq!(status_of(&h.ask("SS000123")), Status::Code(*b"02"));
}

#[test]
fn utm30lx_over_tcp_streams_me_with_intensities() {
    let emu = Emulator::spawn(EmulatorConfig::tcp(DeviceConfig {
        model: Model::Utm30lxEw,
        ..Default::default()
    }))
    .unwrap();
    let port = emu.port();
    let addr = port.strip_prefix("tcp://").unwrap();
    let mut h = Host::open_tcp(addr);
    assert_eq!(h.ask("SCIP2.0"), b"SCIP2.0\n0Ee\n\n");
    let pp = SensorSpec::from_reply(&parse_reply(&h.ask("PP")).unwrap()).unwrap();
    assert_eq!(
        (pp.geometry.ares, pp.geometry.amax, pp.geometry.scan_rpm),
        (1440, 1080, 2400)
    );
    assert_eq!(h.ask("ME0000108001001"), b"ME0000108001001\n00P\n\n");
    let f = h.frame(Duration::from_millis(200)).expect("a 40 Hz scan");
    let mut r = [0u32; 1081];
    let mut i = [0u32; 1081];
    let sh = parse_reply(&f)
        .unwrap()
        .decode_scan(&mut r, &mut i)
        .unwrap();
    assert_eq!(sh.count, 1081);
    assert_eq!((r[0], i[0]), (1000, 1000));
}
