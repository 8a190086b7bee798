//! Host-to-robot commands: encoding (driver side) and decoding (emulator side).
//!
//! A command payload is `[cmd]` or `[cmd, argtype, …]`. Integer arguments are
//! sign-magnitude: `0x3B` then the value LSB first for ≥ 0, `0x1B` then the
//! *absolute* value for < 0 (not two's complement). Strings are `0x2B`, a
//! length byte, the bytes (`ArRobotPacketSender`).

use crate::wire::{EncodeError, MAX_PAYLOAD, PacketBuf, PacketWriter, Reader};
use serde::Serialize;
use thiserror::Error;

/// Command numbers (`ArCommands.h`).
pub mod num {
    pub const PULSE: u8 = 0;
    pub const OPEN: u8 = 1;
    pub const CLOSE: u8 = 2;
    pub const POLLING: u8 = 3;
    pub const ENABLE: u8 = 4;
    pub const SETA: u8 = 5;
    pub const SETV: u8 = 6;
    pub const SETO: u8 = 7;
    pub const MOVE: u8 = 8;
    pub const ROTATE: u8 = 9;
    pub const SETRV: u8 = 10;
    pub const VEL: u8 = 11;
    pub const HEAD: u8 = 12;
    pub const DHEAD: u8 = 13;
    pub const CONFIG: u8 = 18;
    pub const ENCODER: u8 = 19;
    pub const RVEL: u8 = 21;
    pub const SETRA: u8 = 23;
    pub const SONAR: u8 = 28;
    pub const STOP: u8 = 29;
    pub const VEL2: u8 = 32;
    pub const IOREQUEST: u8 = 40;
    pub const HOSTBAUD: u8 = 50;
    pub const ESTOP: u8 = 55;
    /// SYNC0..2 share their numbers (and, bare, their bytes) with PULSE, OPEN
    /// and CLOSE; the robot tells them apart by its handshake state.
    pub const SYNC0: u8 = 0;
    pub const SYNC1: u8 = 1;
    pub const SYNC2: u8 = 2;
}

/// Argument type bytes.
pub const ARG_INT: u8 = 0x3B;
pub const ARG_NEG_INT: u8 = 0x1B;
pub const ARG_STR: u8 = 0x2B;

/// Largest magnitude an integer argument carries (two bytes).
pub const MAX_INT_ARG: i32 = 0xFFFF;
/// Longest string argument (`ArRobotPacket`: a length byte, at most 199 in
/// ARIA, bounded here by the payload).
pub const MAX_STR_ARG: usize = MAX_PAYLOAD - 3;

/// A command argument as it is on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Arg<'a> {
    None,
    /// Decoded from sign-magnitude; -65535..=65535.
    Int(i32),
    Str(#[serde(serialize_with = "ser_lossy")] &'a [u8]),
    /// An argument-type byte with no value after it, as in p2os's SETO
    /// `FA FB 04 07 3B 07 3B`, which AMRISim accepts.
    TypeOnly(u8),
}

fn ser_lossy<S: serde::Serializer>(b: &&[u8], s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&String::from_utf8_lossy(b))
}

impl Arg<'_> {
    pub fn int(&self) -> Option<i32> {
        match self {
            Arg::Int(v) => Some(*v),
            _ => None,
        }
    }
}

/// A command as the robot receives it: number plus argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct RawCommand<'a> {
    pub cmd: u8,
    pub arg: Arg<'a>,
}

/// Why a command payload could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CommandError {
    #[error("empty command payload")]
    Empty,
    #[error("command {cmd}: unknown argument type 0x{argtype:02X} (expected 0x3B, 0x1B or 0x2B)")]
    UnknownArgType { cmd: u8, argtype: u8 },
    #[error("command {cmd}: integer argument needs 2 bytes, got {got}")]
    ShortInt { cmd: u8, got: usize },
    #[error("command {cmd}: string argument declares {declared} bytes, {got} present")]
    ShortString {
        cmd: u8,
        declared: usize,
        got: usize,
    },
    #[error("command {cmd}: {extra} unexpected bytes after the argument")]
    TrailingBytes { cmd: u8, extra: usize },
}

/// Decodes a command payload (type byte first).
pub fn decode_command(payload: &[u8]) -> Result<RawCommand<'_>, CommandError> {
    let mut r = Reader::new(payload);
    let cmd = r.u8().ok_or(CommandError::Empty)?;
    let Some(argtype) = r.u8() else {
        return Ok(RawCommand {
            cmd,
            arg: Arg::None,
        });
    };
    let arg = match argtype {
        ARG_INT | ARG_NEG_INT if r.is_empty() => Arg::TypeOnly(argtype),
        ARG_INT | ARG_NEG_INT => {
            let got = r.remaining();
            let mag = r.u16().ok_or(CommandError::ShortInt { cmd, got })?;
            let mag = i32::from(mag);
            Arg::Int(if argtype == ARG_INT { mag } else { -mag })
        }
        ARG_STR => {
            let declared = usize::from(r.u8().unwrap_or(0));
            let rest = r.rest();
            let s = rest.get(..declared).ok_or(CommandError::ShortString {
                cmd,
                declared,
                got: rest.len(),
            })?;
            if rest.len() > declared {
                return Err(CommandError::TrailingBytes {
                    cmd,
                    extra: rest.len() - declared,
                });
            }
            Arg::Str(s)
        }
        _ => return Err(CommandError::UnknownArgType { cmd, argtype }),
    };
    if !r.is_empty() {
        return Err(CommandError::TrailingBytes {
            cmd,
            extra: r.remaining(),
        });
    }
    Ok(RawCommand { cmd, arg })
}

/// Encodes `cmd` with `arg` into `out`.
pub fn encode_raw(cmd: u8, arg: Arg<'_>, out: &mut PacketBuf) -> Result<(), EncodeError> {
    let mut w = PacketWriter::new(out);
    w.u8(cmd)?;
    match arg {
        Arg::None => {}
        Arg::TypeOnly(t) => w.u8(t)?,
        Arg::Int(v) => {
            if !(-MAX_INT_ARG..=MAX_INT_ARG).contains(&v) {
                return Err(EncodeError::OutOfRange {
                    what: "integer argument",
                    value: i64::from(v),
                    min: i64::from(-MAX_INT_ARG),
                    max: i64::from(MAX_INT_ARG),
                });
            }
            w.u8(if v >= 0 { ARG_INT } else { ARG_NEG_INT })?;
            // |v| <= 0xFFFF checked above.
            w.u16(v.unsigned_abs() as u16)?;
        }
        Arg::Str(s) => {
            if s.len() > MAX_STR_ARG {
                return Err(EncodeError::TooLong { len: s.len() + 3 });
            }
            w.u8(ARG_STR)?;
            w.u8(s.len() as u8)?;
            w.bytes(s)?;
        }
    }
    w.finish()
}

/// The commands this project sends, typed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command<'a> {
    Sync0,
    Sync1,
    Sync2,
    /// Keep-alive for the watchdog (bare, same bytes as SYNC0).
    Pulse,
    /// Starts the session. Bare, as p2os sends it and the AMRISim capture shows
    /// (ARIA adds an int 1; controllers accept both).
    Open,
    /// Ends the session and disables the motors. With ARIA's int 1, so it
    /// cannot be mistaken for a bare SYNC2.
    Close,
    /// Sonar firing sequence.
    Polling(&'a [u8]),
    Enable(bool),
    /// SETA: acceleration if positive, deceleration if negative, mm/s².
    SetAccel(i16),
    /// SETV: maximum translational speed, mm/s.
    SetMaxVel(u16),
    /// SETO: reset odometry to (0, 0, 0); bare, as ARIA sends it.
    ResetOdometry,
    /// MOVE: relative distance, mm.
    Move(i16),
    /// HEAD: absolute heading, degrees.
    Head(i16),
    /// DHEAD: relative heading, degrees.
    DHead(i16),
    /// VEL: translational velocity, mm/s.
    Vel(i16),
    /// RVEL: rotational velocity, deg/s.
    RVel(i16),
    /// SETRV: maximum rotational speed, deg/s.
    SetMaxRotVel(u16),
    /// SETRA: rotational accel (positive) or decel (negative), deg/s².
    SetRotAccel(i16),
    Sonar(bool),
    Stop,
    EStop,
    /// VEL2: wheel speeds in units of `Vel2Divisor` mm/s (20 on a P3-DX).
    Vel2 {
        left: i8,
        right: i8,
    },
    /// CONFIG request (reply type 0x20), sent with int 1 as ARIA does.
    Config,
    /// HOSTBAUD: 0=9600, 1=19200, 2=38400, 3=57600, 4=115200.
    HostBaud(u8),
    Raw {
        cmd: u8,
        arg: Arg<'a>,
    },
}

impl<'a> Command<'a> {
    /// Command number and argument as they go on the wire.
    pub fn to_raw(&self) -> RawCommand<'a> {
        use num::*;
        let (cmd, arg) = match *self {
            Command::Sync0 => (SYNC0, Arg::None),
            Command::Sync1 => (SYNC1, Arg::None),
            Command::Sync2 => (SYNC2, Arg::None),
            Command::Pulse => (PULSE, Arg::None),
            Command::Open => (OPEN, Arg::None),
            Command::Close => (CLOSE, Arg::Int(1)),
            Command::Polling(s) => (POLLING, Arg::Str(s)),
            Command::Enable(on) => (ENABLE, Arg::Int(i32::from(on))),
            Command::SetAccel(v) => (SETA, Arg::Int(v.into())),
            Command::SetMaxVel(v) => (SETV, Arg::Int(v.into())),
            Command::ResetOdometry => (SETO, Arg::None),
            Command::Move(v) => (MOVE, Arg::Int(v.into())),
            Command::Head(v) => (HEAD, Arg::Int(v.into())),
            Command::DHead(v) => (DHEAD, Arg::Int(v.into())),
            Command::Vel(v) => (VEL, Arg::Int(v.into())),
            Command::RVel(v) => (RVEL, Arg::Int(v.into())),
            Command::SetMaxRotVel(v) => (SETRV, Arg::Int(v.into())),
            Command::SetRotAccel(v) => (SETRA, Arg::Int(v.into())),
            Command::Sonar(on) => (SONAR, Arg::Int(i32::from(on))),
            Command::Stop => (STOP, Arg::None),
            Command::EStop => (ESTOP, Arg::None),
            Command::Vel2 { left, right } => (VEL2, Arg::Int(vel2_word(left, right).into())),
            Command::Config => (CONFIG, Arg::Int(1)),
            Command::HostBaud(b) => (HOSTBAUD, Arg::Int(b.into())),
            Command::Raw { cmd, arg } => (cmd, arg),
        };
        RawCommand { cmd, arg }
    }

    pub fn encode(&self, out: &mut PacketBuf) -> Result<(), EncodeError> {
        let r = self.to_raw();
        encode_raw(r.cmd, r.arg, out)
    }

    /// Encodes into a fresh buffer.
    pub fn packet(&self) -> Result<PacketBuf, EncodeError> {
        let mut p = PacketBuf::new();
        self.encode(&mut p)?;
        Ok(p)
    }
}

/// VEL2's argument: ARIA's `com2Bytes(VEL2, left, right)` packs left into the
/// high byte and right into the low byte, then sends the word as a *signed*
/// short, so a negative left wheel goes out as 0x1B plus the magnitude.
pub fn vel2_word(left: i8, right: i8) -> i16 {
    i16::from_be_bytes([left as u8, right as u8])
}

/// Splits a VEL2 argument back into (left, right) wheel units.
pub fn vel2_split(arg: i32) -> (i8, i8) {
    // The argument is the signed short ARIA sent; its two's-complement bytes
    // are the two wheel values.
    let [hi, lo] = (arg as i16).to_be_bytes();
    (hi as i8, lo as i8)
}

/// Human name of a command number (for captures and logs).
pub fn command_name(cmd: u8) -> &'static str {
    match cmd {
        0 => "SYNC0/PULSE",
        1 => "SYNC1/OPEN",
        2 => "SYNC2/CLOSE",
        3 => "POLLING",
        4 => "ENABLE",
        5 => "SETA",
        6 => "SETV",
        7 => "SETO",
        8 => "MOVE",
        9 => "ROTATE",
        10 => "SETRV",
        11 => "VEL",
        12 => "HEAD",
        13 => "DHEAD",
        18 => "CONFIG",
        19 => "ENCODER",
        21 => "RVEL",
        23 => "SETRA",
        28 => "SONAR",
        29 => "STOP",
        32 => "VEL2",
        40 => "IOREQUEST",
        50 => "HOSTBAUD",
        55 => "ESTOP",
        _ => "UNKNOWN",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes(c: Command<'_>) -> Vec<u8> {
        c.packet().unwrap().as_bytes().to_vec()
    }

    // Every ARCOS command vector (as ARIA and p2os encode them), byte for byte.
    #[test]
    fn notes_command_vectors_encode_byte_for_byte() {
        let cases: [(Command<'_>, &[u8]); 9] = [
            (
                Command::Enable(true),
                &[0xFA, 0xFB, 0x06, 0x04, 0x3B, 0x01, 0x00, 0x05, 0x3B],
            ),
            (
                Command::Enable(false),
                &[0xFA, 0xFB, 0x06, 0x04, 0x3B, 0x00, 0x00, 0x04, 0x3B],
            ),
            (
                Command::Sonar(true),
                &[0xFA, 0xFB, 0x06, 0x1C, 0x3B, 0x01, 0x00, 0x1D, 0x3B],
            ),
            (
                Command::Sonar(false),
                &[0xFA, 0xFB, 0x06, 0x1C, 0x3B, 0x00, 0x00, 0x1C, 0x3B],
            ),
            (
                Command::Vel(300),
                &[0xFA, 0xFB, 0x06, 0x0B, 0x3B, 0x2C, 0x01, 0x37, 0x3C],
            ),
            (
                Command::Vel(-300),
                &[0xFA, 0xFB, 0x06, 0x0B, 0x1B, 0x2C, 0x01, 0x37, 0x1C],
            ),
            (
                Command::RVel(-30),
                &[0xFA, 0xFB, 0x06, 0x15, 0x1B, 0x1E, 0x00, 0x33, 0x1B],
            ),
            (
                Command::SetAccel(-1000),
                &[0xFA, 0xFB, 0x06, 0x05, 0x1B, 0xE8, 0x03, 0xED, 0x1E],
            ),
            (
                Command::HostBaud(4),
                &[0xFA, 0xFB, 0x06, 0x32, 0x3B, 0x04, 0x00, 0x36, 0x3B],
            ),
        ];
        for (c, want) in cases {
            assert_eq!(bytes(c), want, "{c:?}");
        }
    }

    #[test]
    fn odd_length_string_vector_encodes_byte_for_byte() {
        // NOTES §2: `FA FB 07 0F 2B 02 61 62 11 EE` (command 15, string "ab").
        let c = Command::Raw {
            cmd: 0x0F,
            arg: Arg::Str(b"ab"),
        };
        assert_eq!(
            bytes(c),
            [0xFA, 0xFB, 0x07, 0x0F, 0x2B, 0x02, 0x61, 0x62, 0x11, 0xEE]
        );
    }

    #[test]
    fn seto_both_forms_encode_as_documented() {
        // ARIA: bare `FA FB 03 07 00 07`; p2os/HCS12: `FA FB 04 07 3B 07 3B`.
        assert_eq!(
            bytes(Command::ResetOdometry),
            [0xFA, 0xFB, 0x03, 0x07, 0x00, 0x07]
        );
        let p2os = Command::Raw {
            cmd: num::SETO,
            arg: Arg::TypeOnly(ARG_INT),
        };
        assert_eq!(bytes(p2os), [0xFA, 0xFB, 0x04, 0x07, 0x3B, 0x07, 0x3B]);
    }

    #[test]
    fn hcs12_set_accel_plus_1000_verifies() {
        // SetAcc1 (+1000): 05 3B E8 03 -> 0x053B + 0xE803 = 0xED3E.
        assert_eq!(
            bytes(Command::SetAccel(1000)),
            [0xFA, 0xFB, 0x06, 0x05, 0x3B, 0xE8, 0x03, 0xED, 0x3E]
        );
    }

    #[test]
    fn capture_tx_packets_encode_byte_for_byte() {
        // amrisim_capture.txt TX lines.
        assert_eq!(bytes(Command::Sync0), [0xFA, 0xFB, 0x03, 0x00, 0x00, 0x00]);
        assert_eq!(bytes(Command::Sync1), [0xFA, 0xFB, 0x03, 0x01, 0x00, 0x01]);
        assert_eq!(bytes(Command::Sync2), [0xFA, 0xFB, 0x03, 0x02, 0x00, 0x02]);
        assert_eq!(bytes(Command::Open), [0xFA, 0xFB, 0x03, 0x01, 0x00, 0x01]);
        assert_eq!(
            bytes(Command::Vel(200)),
            [0xFA, 0xFB, 0x06, 0x0B, 0x3B, 0xC8, 0x00, 0xD3, 0x3B]
        );
        assert_eq!(
            bytes(Command::RVel(-20)),
            [0xFA, 0xFB, 0x06, 0x15, 0x1B, 0x14, 0x00, 0x29, 0x1B]
        );
    }

    #[test]
    fn python_script_enable_with_swapped_bytes_fails_checksum() {
        // NOTES §2 counter-example `FA FB 06 04 3B 00 01 10 84`.
        let mut f = crate::Framer::new();
        let mut errs = 0;
        f.feed(
            &[0xFA, 0xFB, 0x06, 0x04, 0x3B, 0x00, 0x01, 0x10, 0x84],
            |r| errs += usize::from(r.is_err()),
        );
        assert_eq!(errs, 1);
    }

    #[test]
    fn vel2_high_10_low_5_matches_amrisim() {
        // NOTES §1.3: high 10 / low 5 gave lvel 199, rvel 100 (×20 mm/s).
        let p = bytes(Command::Vel2 { left: 10, right: 5 });
        assert_eq!(&p[3..7], &[0x20, 0x3B, 0x05, 0x0A]);
    }

    #[test]
    fn vel2_negative_left_goes_out_sign_magnitude_and_round_trips() {
        // left -5 (0xFB), right 10: word 0xFB0A = -1270 -> 0x1B F6 04.
        let p = Command::Vel2 {
            left: -5,
            right: 10,
        }
        .packet()
        .unwrap();
        assert_eq!(&p.as_bytes()[3..7], &[0x20, 0x1B, 0xF6, 0x04]);
        let raw = decode_command(p.payload()).unwrap();
        assert_eq!(raw.arg, Arg::Int(-1270));
        assert_eq!(vel2_split(-1270), (-5, 10));
        for l in [-128i8, -1, 0, 1, 127] {
            for r in [-128i8, -1, 0, 1, 127] {
                let p = Command::Vel2 { left: l, right: r }.packet().unwrap();
                let raw = decode_command(p.payload()).unwrap();
                assert_eq!(vel2_split(raw.arg.int().unwrap()), (l, r));
            }
        }
    }

    #[test]
    fn decode_round_trips_ints_and_strings() {
        for v in [-65535, -300, -1, 0, 1, 300, 65535] {
            let mut p = PacketBuf::new();
            encode_raw(num::VEL, Arg::Int(v), &mut p).unwrap();
            assert_eq!(decode_command(p.payload()).unwrap().arg, Arg::Int(v));
        }
        let mut p = PacketBuf::new();
        encode_raw(num::POLLING, Arg::Str(b"\x01\x02\x03"), &mut p).unwrap();
        assert_eq!(
            decode_command(p.payload()).unwrap().arg,
            Arg::Str(b"\x01\x02\x03")
        );
        assert!(encode_raw(num::VEL, Arg::Int(65536), &mut p).is_err());
    }

    #[test]
    fn malformed_commands_give_typed_errors() {
        assert_eq!(decode_command(&[]), Err(CommandError::Empty));
        assert_eq!(
            decode_command(&[0x0B, 0x99, 1, 0]),
            Err(CommandError::UnknownArgType {
                cmd: 11,
                argtype: 0x99
            })
        );
        assert_eq!(
            decode_command(&[0x0B, 0x3B, 1]),
            Err(CommandError::ShortInt { cmd: 11, got: 1 })
        );
        assert_eq!(
            decode_command(&[0x03, 0x2B, 5, b'a']),
            Err(CommandError::ShortString {
                cmd: 3,
                declared: 5,
                got: 1
            })
        );
        assert_eq!(
            decode_command(&[0x0B, 0x3B, 1, 0, 9]),
            Err(CommandError::TrailingBytes { cmd: 11, extra: 1 })
        );
    }
}
