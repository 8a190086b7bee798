//! Requests from the host to the robot.

use crate::PacketType;
use crate::error::DecodeError;
use crate::frame::{EncodeError, Frame, encode_frame};
use crate::int::{decode_sm16, encode_sm16};
use crate::sonar::{ORDER_SLOTS, SonarOrder};

/// The commands a Scout driver needs (and the emulator understands).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `gs()`: reply with the state.
    GetState,
    /// `st()`: stop and hold position.
    Stop,
    /// `lp()`: motors limp.
    Limp,
    /// `vm(a, b, c)`: velocity mode. On the Scout `a` and `b` are the two
    /// wheel speeds in 1/10 in/s (which is which: [`crate::WheelOrder`]);
    /// `c` is unused (N200 turret).
    Velocity([i16; 3]),
    /// `conf_sn(rate, order)`: fire one sonar every `rate` × 4 ms in `order`.
    ConfSonar { rate: u8, order: SonarOrder },
    /// `conf_tm(s)`: stop the robot after `s` seconds without a command; 0 disables.
    ConfTimeout(u8),
    /// `dp(x, y)`: define the current position, 1/10 in.
    DefinePosition { x: i16, y: i16 },
    /// `da(th, tu)`: define the current heading and turret angle, 1/10 degree.
    DefineAngles { heading: i16, turret: i16 },
    /// `zr()`: zero position and angles (can take up to 120 s to answer).
    Zero,
}

impl Command {
    pub fn packet_type(&self) -> PacketType {
        match self {
            Command::GetState => PacketType::Gs,
            Command::Stop => PacketType::St,
            Command::Limp => PacketType::Lp,
            Command::Velocity(_) => PacketType::Vm,
            Command::ConfSonar { .. } => PacketType::ConfSn,
            Command::ConfTimeout(_) => PacketType::ConfTm,
            Command::DefinePosition { .. } => PacketType::Dp,
            Command::DefineAngles { .. } => PacketType::Da,
            Command::Zero => PacketType::Zr,
        }
    }

    /// Writes the packet into `out` and returns its length (at most 25 bytes).
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut data = [0u8; 17];
        let n = match *self {
            Command::GetState | Command::Stop | Command::Limp | Command::Zero => 0,
            Command::Velocity(v) => {
                for (chunk, &x) in data.chunks_exact_mut(2).zip(v.iter()) {
                    chunk.copy_from_slice(&encode_sm16(x as i32)?);
                }
                6
            }
            Command::ConfSonar { rate, order } => {
                data[0] = rate;
                data[1..17].copy_from_slice(&order.raw());
                17
            }
            Command::ConfTimeout(s) => {
                data[0] = s;
                1
            }
            Command::DefinePosition { x: a, y: b }
            | Command::DefineAngles {
                heading: a,
                turret: b,
            } => {
                data[..2].copy_from_slice(&encode_sm16(a as i32)?);
                data[2..4].copy_from_slice(&encode_sm16(b as i32)?);
                4
            }
        };
        encode_frame(self.packet_type() as u8, &data[..n], out)
    }

    /// Decodes a command packet (the robot's side of the link).
    pub fn decode(frame: Frame<'_>) -> Result<Command, DecodeError> {
        let Some(ptype) = PacketType::from_u8(frame.ptype) else {
            return Err(DecodeError::UnknownType(frame.ptype));
        };
        let d = frame.data;
        let want = |n: usize| {
            if d.len() == n {
                Ok(())
            } else {
                Err(DecodeError::WrongLength {
                    ptype: frame.ptype,
                    expected: n,
                    got: d.len(),
                })
            }
        };
        let sm = |i: usize| decode_sm16([d[i], d[i + 1]]);
        Ok(match ptype {
            PacketType::Gs => want(0).map(|_| Command::GetState)?,
            PacketType::St => want(0).map(|_| Command::Stop)?,
            PacketType::Lp => want(0).map(|_| Command::Limp)?,
            PacketType::Zr => want(0).map(|_| Command::Zero)?,
            PacketType::Vm => {
                want(6)?;
                Command::Velocity([sm(0), sm(2), sm(4)])
            }
            PacketType::ConfSn => {
                want(17)?;
                let mut raw = [0u8; ORDER_SLOTS];
                raw.copy_from_slice(&d[1..17]);
                Command::ConfSonar {
                    rate: d[0],
                    order: SonarOrder::from_raw(raw).map_err(DecodeError::SonarOrder)?,
                }
            }
            PacketType::ConfTm => {
                want(1)?;
                Command::ConfTimeout(d[0])
            }
            PacketType::Dp => {
                want(4)?;
                Command::DefinePosition { x: sm(0), y: sm(2) }
            }
            PacketType::Da => {
                want(4)?;
                Command::DefineAngles {
                    heading: sm(0),
                    turret: sm(2),
                }
            }
            _ => return Err(DecodeError::UnsupportedCommand(frame.ptype)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{Direction, parse_frame};
    use crate::sonar::SonarOrderError;

    fn bytes(cmd: Command) -> Vec<u8> {
        let mut out = [0u8; 32];
        let n = cmd.encode(&mut out).unwrap();
        out[..n].to_vec()
    }

    fn round_trip(cmd: Command) {
        let b = bytes(cmd);
        let (frame, used) = parse_frame(&b, Direction::Commands).unwrap();
        assert_eq!(used, b.len());
        assert_eq!(Command::decode(frame).unwrap(), cmd);
    }

    #[test]
    fn notes_vectors_encode_byte_for_byte() {
        // Packets as Nomadic's host library (`Ndirect.c`) builds them.
        assert_eq!(
            bytes(Command::GetState),
            [0x01, 0x02, 0x00, 0x07, 0x0A, 0x5C]
        );
        assert_eq!(bytes(Command::Stop), [0x01, 0x02, 0x00, 0x09, 0x0C, 0x5C]);
        assert_eq!(
            bytes(Command::ConfTimeout(5)),
            [0x01, 0x03, 0x00, 0x12, 0x05, 0x1B, 0x5C]
        );
        assert_eq!(
            bytes(Command::Velocity([100, 100, 0])),
            [
                0x01, 0x08, 0x00, 0x05, 0x64, 0x00, 0x64, 0x00, 0x00, 0x00, 0xD6, 0x5C
            ]
        );
        assert_eq!(
            bytes(Command::Velocity([107, -107, 0])),
            [
                0x01, 0x08, 0x00, 0x05, 0x6B, 0x00, 0x6B, 0x80, 0x00, 0x00, 0x64, 0x5C
            ]
        );
    }

    #[test]
    fn notes_vectors_decode_to_their_commands() {
        let cases: [(&[u8], Command); 5] = [
            (&[0x01, 0x02, 0x00, 0x07, 0x0A, 0x5C], Command::GetState),
            (&[0x01, 0x02, 0x00, 0x09, 0x0C, 0x5C], Command::Stop),
            (
                &[0x01, 0x03, 0x00, 0x12, 0x05, 0x1B, 0x5C],
                Command::ConfTimeout(5),
            ),
            (
                &[
                    0x01, 0x08, 0x00, 0x05, 0x64, 0x00, 0x64, 0x00, 0x00, 0x00, 0xD6, 0x5C,
                ],
                Command::Velocity([100, 100, 0]),
            ),
            (
                &[
                    0x01, 0x08, 0x00, 0x05, 0x6B, 0x00, 0x6B, 0x80, 0x00, 0x00, 0x64, 0x5C,
                ],
                Command::Velocity([107, -107, 0]),
            ),
        ];
        for (wire, cmd) in cases {
            let (frame, _) = parse_frame(wire, Direction::Commands).unwrap();
            assert_eq!(Command::decode(frame).unwrap(), cmd);
        }
    }

    #[test]
    fn conf_sn_front_first_order_is_19_long() {
        let order =
            SonarOrder::from_indices(&[0, 2, 15, 1, 14, 3, 13, 4, 12, 5, 11, 6, 10, 7, 9, 8])
                .unwrap();
        let b = bytes(Command::ConfSonar { rate: 15, order });
        // 01 | 13 00 | 0F | rate 0F | 16 indices | chk | 5C
        assert_eq!(&b[..5], &[0x01, 19, 0x00, 0x0F, 15]);
        assert_eq!(
            &b[5..21],
            &[0, 2, 15, 1, 14, 3, 13, 4, 12, 5, 11, 6, 10, 7, 9, 8]
        );
        let sum: u32 = b[..21].iter().map(|&x| x as u32).sum();
        assert_eq!(b[21] as u32, sum % 256);
        assert_eq!(b[22], 0x5C);
        round_trip(Command::ConfSonar { rate: 15, order });
    }

    #[test]
    fn short_order_is_terminated_by_255() {
        let order = SonarOrder::from_indices(&[0, 1, 15]).unwrap();
        assert_eq!(order.raw()[..4], [0, 1, 15, 255]);
        assert_eq!(order.indices().collect::<Vec<_>>(), vec![0, 1, 15]);
        assert_eq!(SonarOrder::DISABLED.indices().count(), 0);
        assert_eq!(
            SonarOrder::from_indices(&[16]),
            Err(SonarOrderError::BadIndex(16))
        );
        assert_eq!(
            SonarOrder::from_indices(&[0; 17]),
            Err(SonarOrderError::TooLong(17))
        );
    }

    #[test]
    fn negative_positions_and_angles_round_trip() {
        round_trip(Command::DefinePosition { x: -1234, y: 32767 });
        round_trip(Command::DefineAngles {
            heading: -3599,
            turret: 0,
        });
        round_trip(Command::Velocity([-32767, -1, 0]));
        round_trip(Command::Zero);
        round_trip(Command::Limp);
        round_trip(Command::ConfTimeout(0));
    }

    #[test]
    fn dp_zero_is_the_zero_odometry_packet() {
        // dp(0, 0): 01 06 00 0C 00 00 00 00 | 1+6+12 = 0x13 | 5C
        assert_eq!(
            bytes(Command::DefinePosition { x: 0, y: 0 }),
            [0x01, 0x06, 0x00, 0x0C, 0, 0, 0, 0, 0x13, 0x5C]
        );
    }

    #[test]
    fn i16_min_cannot_be_sent() {
        let mut out = [0u8; 32];
        assert_eq!(
            Command::Velocity([i16::MIN, 0, 0]).encode(&mut out),
            Err(EncodeError::OutOfRange { value: -32768 })
        );
    }

    #[test]
    fn unsupported_command_is_a_typed_error() {
        let mut out = [0u8; 16];
        let n = encode_frame(PacketType::GetIr as u8, &[], &mut out).unwrap();
        let (frame, _) = parse_frame(&out[..n], Direction::Commands).unwrap();
        assert_eq!(
            Command::decode(frame),
            Err(DecodeError::UnsupportedCommand(19))
        );
    }

    #[test]
    fn bad_sonar_index_in_conf_sn_is_rejected() {
        let mut data = [255u8; 17];
        data[0] = 15;
        data[1] = 3;
        data[2] = 40;
        let frame = Frame {
            ptype: PacketType::ConfSn as u8,
            data: &data,
        };
        assert_eq!(
            Command::decode(frame),
            Err(DecodeError::SonarOrder(SonarOrderError::BadIndex(40)))
        );
    }
}
