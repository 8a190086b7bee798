//! Pure ARCOS/P2OS codec for Pioneer robots (bytes in, typed values out, no I/O).
//!
//! - [`wire`]: packet layout, checksum, [`PacketBuf`] (fixed, no allocation).
//! - [`framer`]: incremental stream splitter that resynchronises after noise.
//! - [`command`]: host commands (sign-magnitude ints, strings), encode and decode.
//! - [`sync`], [`sip`], [`config`]: what the robot sends.
//! - [`params`]: conversion factors per subclass; [`odometry`]: 15-bit wrap and
//!   the pose integrator.
//! - [`capture`]: a hex or raw capture to one JSON object per packet
//!   (`smokenav arcos decode`).
//!
//! Facts: the ARCOS protocol as the Pioneer 3 Operations Manual, ARIA and
//! p2os give it (REFERENCES.md); the AMRISim capture used by the tests is in
//! `fixtures/`.

pub mod capture;
pub mod command;
pub mod config;
pub mod framer;
pub mod odometry;
pub mod params;
pub mod sip;
pub mod sync;
pub mod wire;

pub use command::{Arg, Command, CommandError, RawCommand, decode_command, encode_raw};
pub use config::ConfigPacket;
pub use framer::{FrameError, Framer, FramerStats};
pub use odometry::{OdomEstimate, OdometryIntegrator, wrap15_delta};
pub use params::{KNOWN_ROBOTS, RobotParams, UnknownSubclass, params_for};
pub use sip::{Sip, SonarSample, SonarSamples};
pub use sync::RobotIdent;
pub use wire::{EncodeError, PacketBuf, checksum};

use thiserror::Error;

/// Why a robot packet's payload could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum DecodeError {
    #[error("empty payload")]
    Empty,
    #[error("expected {expected}, got packet type 0x{got:02X}")]
    WrongType { expected: &'static str, got: u8 },
    #[error("{what}: needs {needed} more bytes, {remaining} left")]
    Truncated {
        what: &'static str,
        needed: usize,
        remaining: usize,
    },
    #[error("{what}: {len} exceeds the limit of {max}")]
    TooLong {
        what: &'static str,
        len: usize,
        max: usize,
    },
}

/// A packet from the robot, by type.
// SIPs are the hot path (10 Hz): they stay inline so decoding one allocates nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum RobotPacket {
    /// SYNC0 or SYNC1 echoed (payload `[0]` or `[1]`).
    SyncEcho(u8),
    /// SYNC2 reply.
    Ident(RobotIdent),
    Sip(Sip),
    Config(Box<ConfigPacket>),
    /// A packet type this codec does not decode (encoder, IO, …).
    Other {
        packet_type: u8,
        len: usize,
    },
}

/// Decodes a payload the robot sent (type byte first).
///
/// Types 0 and 1 with no data are SYNC echoes; type 2 is the SYNC2 reply. A
/// host that knows the handshake is over can treat them as unexpected.
pub fn decode_robot_packet(payload: &[u8]) -> Result<RobotPacket, DecodeError> {
    match payload {
        [] => Err(DecodeError::Empty),
        [seq @ (0 | 1)] => Ok(RobotPacket::SyncEcho(*seq)),
        [2, ..] => RobotIdent::decode(payload).map(RobotPacket::Ident),
        [sip::SIP_STOPPED | sip::SIP_MOVING, ..] => Sip::decode(payload).map(RobotPacket::Sip),
        [config::CONFIG_PACKET, ..] => {
            ConfigPacket::decode(payload).map(|c| RobotPacket::Config(Box::new(c)))
        }
        [t, ..] => Ok(RobotPacket::Other {
            packet_type: *t,
            len: payload.len(),
        }),
    }
}

/// Bytes as lower-case hex pairs separated by spaces (`fa fb 03 00 00 00`).
pub fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write;
    let mut s = String::with_capacity(bytes.len() * 3);
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let _ = write!(s, "{b:02x}");
    }
    s
}

#[cfg(test)]
mod fuzz_tests {
    use super::*;
    use proptest::prelude::*;

    fn arb_sip() -> impl Strategy<Value = Sip> {
        (
            any::<(u16, u16, i16, i16, i16, u8, u16, i16, u16, u8)>(),
            proptest::collection::vec(any::<(u8, u16)>(), 0..=32),
            (
                any::<(u8, u8, u8, u8, u8, u16, u8)>(),
                any::<(i16, u16, i16, i8, u8, u32, u32)>(),
            ),
            0usize..=14,
        )
            .prop_map(|(a, sonars, (t, u), n_opt)| {
                let mut s = Sip {
                    packet_type: if a.0 % 2 == 0 {
                        sip::SIP_STOPPED
                    } else {
                        sip::SIP_MOVING
                    },
                    x: a.0,
                    y: a.1,
                    th: a.2,
                    left_vel: a.3,
                    right_vel: a.4,
                    battery_dv: a.5,
                    stall_bumpers: a.6,
                    control: a.7,
                    flags: a.8,
                    compass: a.9,
                    ..Default::default()
                };
                for (index, range) in sonars {
                    s.sonars.push(SonarSample { index, range });
                }
                let n = n_opt;
                macro_rules! set {
                    ($i:expr, $f:ident, $v:expr) => {
                        if n > $i {
                            s.$f = Some($v);
                        }
                    };
                }
                set!(0, grip_state, t.0);
                set!(1, anport, t.1);
                set!(2, analog, t.2);
                set!(3, digin, t.3);
                set!(4, digout, t.4);
                set!(5, battery_x10, t.5);
                set!(6, charge_state, t.6);
                set!(7, rot_vel, u.0);
                set!(8, fault_flags, u.1);
                set!(9, lat_vel, u.2);
                set!(10, temperature, u.3);
                set!(11, soc, u.4);
                set!(12, uc_time, u.5);
                set!(13, flags3, u.6);
                s
            })
    }

    proptest! {
        #[test]
        fn arbitrary_payloads_never_panic(payload in proptest::collection::vec(any::<u8>(), 0..256)) {
            let _ = decode_robot_packet(&payload);
            let _ = Sip::decode(&payload);
            let _ = ConfigPacket::decode(&payload);
            let _ = RobotIdent::decode(&payload);
            let _ = decode_command(&payload);
        }

        #[test]
        fn arbitrary_sip_payload_after_type_byte_never_panics(
            t in prop_oneof![Just(0x32u8), Just(0x33u8), Just(0x20u8), Just(0x02u8)],
            rest in proptest::collection::vec(any::<u8>(), 0..200),
        ) {
            let mut p = vec![t];
            p.extend(rest);
            let _ = decode_robot_packet(&p);
        }

        #[test]
        fn arbitrary_capture_input_never_panics(data in proptest::collection::vec(any::<u8>(), 0..2048)) {
            let mut n = 0;
            let _ = capture::decode_capture(&data, capture::CaptureFormat::Auto, capture::Direction::Unknown, None, |_| n += 1);
            let text: String = data.iter().map(|b| char::from(b"0123456789abcdefTXR \n<>x"[usize::from(*b) % 24])).collect();
            let _ = capture::decode_capture(text.as_bytes(), capture::CaptureFormat::Hex, capture::Direction::Unknown, None, |_| n += 1);
        }

        #[test]
        fn sip_encode_decode_round_trips(s in arb_sip()) {
            let mut p = PacketBuf::new();
            s.encode(&mut p).unwrap();
            let d = Sip::decode(p.payload()).unwrap();
            prop_assert_eq!(d, s);
        }
    }
}
