//! Tests of [`super`]: its pieces one by one, and every packet of the AMRISim capture.

use super::*;

#[test]
fn annotated_line_yields_direction_and_trailing_bytes() {
    let (d, b) = parse_hex_line("RX type 0x32 t=0.20          ok=True len=6 fa fb 03 00 00 00");
    assert_eq!(d, Some(Direction::FromRobot));
    assert_eq!(b, [0xfa, 0xfb, 0x03, 0x00, 0x00, 0x00]);
    let (d, b) = parse_hex_line("TX VEL +200 ok=True len=9 fa fb 06 0b 3b c8 00 d3 3b");
    assert_eq!(d, Some(Direction::ToRobot));
    assert_eq!(b.len(), 9);
    let (d, b) = parse_hex_line("FAFB030000 0x00");
    assert_eq!(d, None);
    assert_eq!(b, [0xfa, 0xfb, 0x03, 0x00, 0x00, 0x00]);
}

#[test]
fn raw_capture_with_noise_reports_error_objects_and_packets() {
    let mut input = vec![0x00, 0x13];
    input.extend_from_slice(&[0xFA, 0xFB, 0x06, 0x04, 0x3B, 0x01, 0x00, 0x05, 0x3C]); // bad ck
    input.extend_from_slice(&[0xFA, 0xFB, 0x06, 0x0B, 0x3B, 0x2C, 0x01, 0x37, 0x3C]); // VEL 300
    let mut out = Vec::new();
    let sum = decode_capture(&input, CaptureFormat::Auto, Direction::ToRobot, None, |v| {
        out.push(v)
    })
    .unwrap();
    assert_eq!(out.len(), 2);
    assert!(out[0]["error"].as_str().unwrap().contains("bad checksum"));
    assert_eq!(out[1]["name"], "VEL");
    assert_eq!(out[1]["arg"]["int"], 300);
    assert_eq!(sum.framing.checksum_errors, 1);
}

#[test]
fn unmarked_vel2_is_a_command_not_a_config_reply() {
    // VEL2 is command 32 = 0x20, the CONFIG reply's type.
    let mut out = Vec::new();
    decode_capture(
        b"fa fb 06 20 3b 05 0a 25 45",
        CaptureFormat::Hex,
        Direction::Unknown,
        None,
        |v| out.push(v),
    )
    .unwrap();
    assert_eq!(out[0]["kind"], "command");
    assert_eq!(out[0]["name"], "VEL2");
}

/// Every packet of the AMRISim capture (`fixtures/amrisim_capture.txt`),
/// checked against the values the ARCOS protocol defines.
mod amrisim {
    use crate::capture::{CaptureFormat, Direction, decode_capture, parse_hex_line};
    use crate::command::{Arg, decode_command, num};
    use crate::sip::{SIP_STOPPED, SonarSample};
    use crate::{
        Framer, OdometryIntegrator, PacketBuf, RobotIdent, RobotPacket, Sip, decode_robot_packet,
        params_for,
    };

    const CAPTURE: &str = include_str!("../../fixtures/amrisim_capture.txt");

    struct Line {
        dir: Direction,
        label: String,
        bytes: Vec<u8>,
    }

    fn lines() -> Vec<Line> {
        CAPTURE
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                let (dir, bytes) = parse_hex_line(l);
                let label = l.split("ok=").next().unwrap().trim().to_owned();
                Line {
                    dir: dir.unwrap(),
                    label,
                    bytes,
                }
            })
            .collect()
    }

    /// The single payload a capture line frames to.
    fn payload(line: &Line) -> Vec<u8> {
        let mut f = Framer::new();
        let mut out = Vec::new();
        f.feed(&line.bytes, |r| {
            out.push(r.expect("capture checksum").to_vec())
        });
        assert_eq!(out.len(), 1, "{}", line.label);
        out.pop().unwrap()
    }

    fn sips() -> Vec<(String, Sip)> {
        lines()
            .iter()
            .filter(|l| l.dir == Direction::FromRobot && l.label.contains("0x32"))
            .map(|l| match decode_robot_packet(&payload(l)).unwrap() {
                RobotPacket::Sip(s) => (l.label.clone(), s),
                other => panic!("{}: {other:?}", l.label),
            })
            .collect()
    }

    #[test]
    fn capture_has_50_packets_all_checksums_valid() {
        // The capture was described as "40 packets"; the file holds 50: 8 TX commands, the
        // 3 SYNC replies and 39 SIPs.
        let ls = lines();
        assert_eq!(ls.len(), 50);
        for l in &ls {
            let p = payload(l);
            // The count byte is len(payload) + 2 and the line's len= matches.
            assert_eq!(l.bytes[2] as usize, p.len() + 2, "{}", l.label);
        }
    }

    #[test]
    fn sync0_and_sync1_echoes_are_byte_identical() {
        let ls = lines();
        assert_eq!(ls[0].bytes, [0xfa, 0xfb, 0x03, 0x00, 0x00, 0x00]);
        assert_eq!(ls[1].bytes, ls[0].bytes);
        assert_eq!(ls[2].bytes, [0xfa, 0xfb, 0x03, 0x01, 0x00, 0x01]);
        assert_eq!(ls[3].bytes, ls[2].bytes);
        assert_eq!(
            decode_robot_packet(&payload(&ls[1])),
            Ok(RobotPacket::SyncEcho(0))
        );
        assert_eq!(
            decode_robot_packet(&payload(&ls[3])),
            Ok(RobotPacket::SyncEcho(1))
        );
    }

    #[test]
    fn sync2_reply_is_amrisim_pioneer_p3dx() {
        let ls = lines();
        assert_eq!(ls[4].bytes, [0xfa, 0xfb, 0x03, 0x02, 0x00, 0x02]);
        let id = match decode_robot_packet(&payload(&ls[5])).unwrap() {
            RobotPacket::Ident(id) => id,
            other => panic!("{other:?}"),
        };
        assert_eq!(id, RobotIdent::new("AMRISim", "Pioneer", "p3dx"));
        assert_eq!(params_for(&id.subclass).unwrap().dist_conv, 0.485);
    }

    #[test]
    fn tx_commands_decode_to_open_enable_sonar_vel_rvel() {
        let ls = lines();
        let tx: Vec<_> = ls.iter().filter(|l| l.dir == Direction::ToRobot).collect();
        let want: [(u8, Arg<'static>); 8] = [
            (num::SYNC0, Arg::None),
            (num::SYNC1, Arg::None),
            (num::SYNC2, Arg::None),
            (num::OPEN, Arg::None),
            (num::ENABLE, Arg::Int(1)),
            (num::SONAR, Arg::Int(1)),
            (num::VEL, Arg::Int(200)),
            (num::RVEL, Arg::Int(-20)),
        ];
        assert_eq!(tx.len(), want.len());
        for (l, (cmd, arg)) in tx.iter().zip(want) {
            let p = payload(l);
            let c = decode_command(&p).unwrap();
            assert_eq!((c.cmd, c.arg), (cmd, arg), "{}", l.label);
        }
    }

    #[test]
    fn stationary_sip_matches_notes_field_by_field() {
        // NOTES §2: 89 bytes, count 0x56, 16 readings, flags 0x1F, battery 0x82
        // = 13.0 V, temperature 0x81 = -127.
        let ls = lines();
        let first = ls
            .iter()
            .find(|l| l.label.starts_with("RX type 0x32 t=0.20"))
            .unwrap();
        assert_eq!(first.bytes.len(), 89);
        assert_eq!(first.bytes[2], 0x56);
        let s = Sip::decode(&payload(first)).unwrap();
        assert_eq!(s.packet_type, SIP_STOPPED);
        assert_eq!((s.x, s.y, s.th, s.left_vel, s.right_vel), (0, 0, 0, 0, 0));
        assert_eq!(s.battery_dv, 0x82);
        assert!((s.battery_volts() - 13.0).abs() < 1e-9);
        assert_eq!(
            (s.stall_bumpers, s.control, s.flags, s.compass),
            (0, 0, 0x1F, 0)
        );
        assert!(s.motors_enabled());
        assert_eq!(s.sonar_arrays(), 0b1111);
        let ranges: Vec<(u8, u16)> = s
            .sonars
            .as_slice()
            .iter()
            .map(|r| (r.index, r.range))
            .collect();
        assert_eq!(
            ranges,
            [
                (0, 1593),
                (1, 3484),
                (2, 2801),
                (3, 1869),
                (4, 5000), // 88 13: no echo, the simulator's max
                (5, 4707),
                (6, 4573),
                (7, 1102),
                (8, 960),
                (9, 837),
                (10, 872),
                (11, 551),
                (12, 533),
                (13, 991),
                (14, 959),
                (15, 1363)
            ]
        );
        assert_eq!(
            (s.grip_state, s.anport, s.analog, s.digin, s.digout),
            (Some(0), Some(0), Some(0), Some(0xff), Some(0xff))
        );
        assert_eq!(s.battery_x10, Some(130));
        assert_eq!(
            (s.charge_state, s.rot_vel, s.fault_flags, s.lat_vel),
            (Some(0), Some(0), Some(0), Some(0))
        );
        assert_eq!(s.temperature, Some(-127));
        assert_eq!(s.temperature_c(), None);
        assert_eq!(s.soc, Some(0));
        assert_eq!((s.uc_time, s.flags3), (None, None));
        assert_eq!(s.unparsed_tail, 0);
    }

    #[test]
    fn first_moving_sip_is_x6_th_minus11_lvel61_rvel_minus1() {
        // NOTES §2: after VEL +200 / RVEL -20: x=6, th=-11, lvel=61, rvel=-1,
        // ROTVEL=-100 (-10.0 deg/s).
        let all = sips();
        let (_, s) = all.iter().find(|(l, _)| l.contains("t=1.21")).unwrap();
        assert_eq!(
            (s.x, s.y, s.th, s.left_vel, s.right_vel),
            (6, 0, -11, 61, -1)
        );
        assert_eq!(s.rot_vel, Some(-100));
        assert_eq!(
            s.sonars.as_slice()[0],
            SonarSample {
                index: 0,
                range: 0x0623
            }
        );
    }

    #[test]
    fn every_sip_decodes_with_nothing_left_over_and_reencodes_identically() {
        let all = sips();
        assert_eq!(all.len(), 39);
        for (label, s) in &all {
            // AMRISim always sends 0x32, even while moving.
            assert_eq!(s.packet_type, SIP_STOPPED, "{label}");
            assert_eq!(s.sonars.len(), 16, "{label}");
            assert_eq!(s.unparsed_tail, 0, "{label}");
            assert_eq!(s.temperature, Some(-127), "{label}");
            assert_eq!(s.battery_x10, Some(130), "{label}");
            let mut p = PacketBuf::new();
            s.encode(&mut p).unwrap();
            let line = lines().into_iter().find(|l| &l.label == label).unwrap();
            assert_eq!(p.as_bytes(), &line.bytes[..], "{label}");
        }
    }

    #[test]
    fn capture_odometry_ends_near_0_44_m_ahead_and_0_25_m_right() {
        // Last SIP: x=0x0389=905, y=0xfdfd (15 bits: 32253, i.e. -515 through
        // the wrap), th=0xfd78=-648. p3dx: 0.485 mm/unit, 0.001534 rad/unit.
        let mut odo = OdometryIntegrator::new(*params_for("p3dx").unwrap());
        let mut last = None;
        for (_, s) in sips() {
            last = Some(odo.update(&s));
        }
        let e = last.unwrap();
        assert!((e.x_m - 905.0 * 0.485 / 1000.0).abs() < 1e-9, "{e:?}");
        assert!((e.y_m - (-515.0 * 0.485 / 1000.0)).abs() < 1e-9, "{e:?}");
        assert!((e.theta - (-648.0 * 0.001534)).abs() < 1e-9, "{e:?}");
        // ~-20 deg/s from ROTVEL, ~0.2 m/s from the wheels.
        assert!((e.angular_rps - (-20f64).to_radians()).abs() < 1e-9);
        assert!((e.linear_mps - 0.1995).abs() < 1e-9);
    }

    #[test]
    fn capture_decodes_to_one_json_object_per_packet() {
        let mut out = Vec::new();
        let sum = decode_capture(
            CAPTURE.as_bytes(),
            CaptureFormat::Auto,
            Direction::Unknown,
            None,
            |v| out.push(v),
        )
        .unwrap();
        assert_eq!(out.len(), 50);
        assert_eq!(sum.framing.packets, 50);
        assert_eq!(sum.framing.checksum_errors, 0);
        assert_eq!(out[0]["dir"], "to_robot");
        assert_eq!(out[0]["name"], "SYNC0/PULSE");
        assert_eq!(out[1]["kind"], "sync_echo");
        assert_eq!(out[5]["ident"]["subclass"], "p3dx");
        let sip = &out[9];
        assert_eq!(sip["kind"], "sip");
        assert_eq!(sip["len"], 89);
        assert_eq!(sip["sip"]["flags"], 0x1F);
        assert_eq!(sip["sip"]["sonars"].as_array().unwrap().len(), 16);
        assert_eq!(sip["derived"]["battery_v"], 13.0);
        assert_eq!(sip["derived"]["temperature_c"], serde_json::Value::Null);
        assert_eq!(sip["derived"]["subclass"], "p3dx");
        assert_eq!(
            sip["derived"]["sonar_mm"][4],
            serde_json::json!([4, 5000.0])
        );
        assert_eq!(sip["line"], 10);
    }
}
