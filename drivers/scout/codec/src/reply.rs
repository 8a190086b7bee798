//! Replies from the robot: the Scout's state packet and NAK.

use crate::PacketType;
use crate::error::DecodeError;
use crate::frame::{EncodeError, Frame, encode_frame};
use crate::int::{decode_sm16, encode_sm16};

/// Sonars on the Scout's ring.
pub const SONARS: usize = 16;
/// Data bytes of a Scout state reply (after the type byte).
pub const STATE_DATA_LEN: usize = 42;

/// Battery level from motor-status bits 2–3.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Battery {
    Low,
    Medium,
    High,
    /// The code 11, which the sources do not define.
    Unknown,
}

/// The motor-status byte (bits from `nomadic_driver_node.cpp`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MotorStatus(pub u8);

impl MotorStatus {
    pub const LEFT_MOVING: u8 = 1 << 0;
    pub const RIGHT_MOVING: u8 = 1 << 1;
    pub const PLUGGED_IN: u8 = 1 << 4;
    pub const CHARGING: u8 = 1 << 5;
    pub const ESTOP: u8 = 1 << 6;

    pub fn new(
        left_moving: bool,
        right_moving: bool,
        battery: Battery,
        plugged_in: bool,
        charging: bool,
        estop: bool,
    ) -> Self {
        let bat = match battery {
            Battery::Low => 0,
            Battery::Medium => 1,
            Battery::High => 2,
            Battery::Unknown => 3,
        };
        Self(
            (left_moving as u8)
                | (right_moving as u8) << 1
                | bat << 2
                | (plugged_in as u8) << 4
                | (charging as u8) << 5
                | (estop as u8) << 6,
        )
    }

    pub fn left_moving(self) -> bool {
        self.0 & Self::LEFT_MOVING != 0
    }
    pub fn right_moving(self) -> bool {
        self.0 & Self::RIGHT_MOVING != 0
    }
    pub fn battery(self) -> Battery {
        match (self.0 >> 2) & 0b11 {
            0 => Battery::Low,
            1 => Battery::Medium,
            2 => Battery::High,
            _ => Battery::Unknown,
        }
    }
    pub fn plugged_in(self) -> bool {
        self.0 & Self::PLUGGED_IN != 0
    }
    pub fn charging(self) -> bool {
        self.0 & Self::CHARGING != 0
    }
    pub fn estop(self) -> bool {
        self.0 & Self::ESTOP != 0
    }
}

/// The Scout's state packet in wire units, as `Process_State_Pkg` reads it
/// with the Scout's fixed sensor mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StateReply {
    /// Ranges in inches; 255 = no echo.
    pub sonar_in: [u8; SONARS],
    /// Bumper vector, Scout byte order: b0 + b1·256 + b2·65536.
    pub bumpers: u32,
    /// Position, 1/10 inch.
    pub x: i16,
    pub y: i16,
    /// Heading (the N200's "steering" axis), 1/10 degree, 0–3599.
    pub heading: i16,
    pub turret: i16,
    /// The three velocity words. On the Scout the first two are the wheel
    /// speeds in 1/10 in/s (`STATE_VEL_RIGHT` = 38 first, `STATE_VEL_LEFT` = 39).
    pub velocity: [i16; 3],
    pub compass: i16,
    pub motor: MotorStatus,
    /// The 6811's time counter (unit not documented).
    pub time: u32,
    /// Raw voltage bytes; see [`crate::units::cpu_voltage`].
    pub cpu_voltage_raw: u8,
    pub motor_voltage_raw: u8,
}

impl StateReply {
    /// Decodes the data of a state packet (without the type byte).
    pub fn decode(ptype: u8, d: &[u8]) -> Result<Self, DecodeError> {
        let d: &[u8; STATE_DATA_LEN] = d.try_into().map_err(|_| DecodeError::WrongLength {
            ptype,
            expected: STATE_DATA_LEN,
            got: d.len(),
        })?;
        let sm = |i: usize| decode_sm16([d[i], d[i + 1]]);
        let mut sonar_in = [0u8; SONARS];
        sonar_in.copy_from_slice(&d[..16]);
        Ok(Self {
            sonar_in,
            bumpers: d[16] as u32 | (d[17] as u32) << 8 | (d[18] as u32) << 16,
            x: sm(19),
            y: sm(21),
            heading: sm(23),
            turret: sm(25),
            velocity: [sm(27), sm(29), sm(31)],
            compass: sm(33),
            motor: MotorStatus(d[35]),
            time: u32::from_le_bytes([d[36], d[37], d[38], d[39]]),
            cpu_voltage_raw: d[40],
            motor_voltage_raw: d[41],
        })
    }

    /// The 42 data bytes (for the emulator). Fails only on `i16::MIN` fields.
    pub fn encode_data(&self) -> Result<[u8; STATE_DATA_LEN], EncodeError> {
        let mut d = [0u8; STATE_DATA_LEN];
        d[..16].copy_from_slice(&self.sonar_in);
        d[16] = self.bumpers as u8;
        d[17] = (self.bumpers >> 8) as u8;
        d[18] = (self.bumpers >> 16) as u8;
        let words = [
            self.x,
            self.y,
            self.heading,
            self.turret,
            self.velocity[0],
            self.velocity[1],
            self.velocity[2],
            self.compass,
        ];
        for (i, w) in words.iter().enumerate() {
            let at = 19 + 2 * i;
            d[at..at + 2].copy_from_slice(&encode_sm16(*w as i32)?);
        }
        d[35] = self.motor.0;
        d[36..40].copy_from_slice(&self.time.to_le_bytes());
        d[40] = self.cpu_voltage_raw;
        d[41] = self.motor_voltage_raw;
        Ok(d)
    }

    /// A full state packet answering a command of type `ptype`.
    pub fn encode(&self, ptype: PacketType, out: &mut [u8]) -> Result<usize, EncodeError> {
        encode_frame(ptype as u8, &self.encode_data()?, out)
    }
}

/// A reply from the Scout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply {
    /// A state packet; `to` is the type of the command it answers.
    State { to: PacketType, state: StateReply },
    /// The robot refused the command (e.g. it arrived damaged).
    Nak,
}

impl Reply {
    pub fn decode(frame: Frame<'_>) -> Result<Reply, DecodeError> {
        let Some(ptype) = PacketType::from_u8(frame.ptype) else {
            return Err(DecodeError::UnknownType(frame.ptype));
        };
        if ptype == PacketType::Nak {
            // Nomadic's host ignores any NAK data; so do we.
            return Ok(Reply::Nak);
        }
        if !ptype.replies_with_state() {
            return Err(DecodeError::UnsupportedReply(frame.ptype));
        }
        Ok(Reply::State {
            to: ptype,
            state: StateReply::decode(frame.ptype, frame.data)?,
        })
    }

    /// The packet type on the wire.
    pub fn packet_type(&self) -> PacketType {
        match self {
            Reply::State { to, .. } => *to,
            Reply::Nak => PacketType::Nak,
        }
    }

    pub fn encode(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        match self {
            Reply::State { to, state } => state.encode(*to, out),
            Reply::Nak => encode_frame(PacketType::Nak as u8, &[], out),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{Direction, MAX_FRAME, parse_frame};

    fn sample() -> StateReply {
        StateReply {
            sonar_in: [
                10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110, 120, 130, 140, 254, 255,
            ],
            bumpers: 0x03_02_01,
            x: -1234,
            y: 567,
            heading: 3599,
            turret: 0,
            velocity: [-107, 107, 0],
            compass: 0,
            motor: MotorStatus::new(true, true, Battery::High, false, false, false),
            time: 0xDEAD_BEEF,
            cpu_voltage_raw: 200,
            motor_voltage_raw: 180,
        }
    }

    #[test]
    fn state_reply_is_48_bytes_on_the_wire() {
        let mut out = [0u8; MAX_FRAME];
        let n = sample().encode(PacketType::Gs, &mut out).unwrap();
        // Ndirect.c's state packet: 43 bytes + checksum (≈48 on the wire); len = 44.
        assert_eq!(n, 48);
        assert_eq!(&out[..4], &[0x01, 44, 0x00, 0x07]);
        assert_eq!(out[47], 0x5C);
    }

    #[test]
    fn state_reply_fields_sit_where_process_state_pkg_reads_them() {
        let mut out = [0u8; MAX_FRAME];
        sample().encode(PacketType::Gs, &mut out).unwrap();
        let d = &out[4..46];
        assert_eq!(d[15], 255, "sonar 15");
        assert_eq!(&d[16..19], &[0x01, 0x02, 0x03], "bumper b0 b1 b2");
        // x = -1234 = -(4*256 + 210): D2 84
        assert_eq!(&d[19..21], &[0xD2, 0x84]);
        // heading 3599 = 14*256 + 15
        assert_eq!(&d[23..25], &[0x0F, 0x0E]);
        // right wheel -107, left +107
        assert_eq!(&d[27..31], &[0x6B, 0x80, 0x6B, 0x00]);
        assert_eq!(d[35], 0b1011, "both moving, battery high");
        assert_eq!(&d[36..40], &[0xEF, 0xBE, 0xAD, 0xDE], "time u32 LE");
        assert_eq!(&d[40..42], &[200, 180]);
    }

    #[test]
    fn state_reply_round_trips_with_negatives() {
        let mut out = [0u8; MAX_FRAME];
        let n = sample().encode(PacketType::Vm, &mut out).unwrap();
        let (frame, used) = parse_frame(&out[..n], Direction::ScoutReplies).unwrap();
        assert_eq!(used, n);
        assert_eq!(
            Reply::decode(frame).unwrap(),
            Reply::State {
                to: PacketType::Vm,
                state: sample()
            }
        );
    }

    #[test]
    fn nak_round_trips() {
        let mut out = [0u8; 16];
        let n = Reply::Nak.encode(&mut out).unwrap();
        assert_eq!(&out[..n], &[0x01, 0x02, 0x00, 0x08, 0x0B, 0x5C]);
        let (frame, _) = parse_frame(&out[..n], Direction::ScoutReplies).unwrap();
        assert_eq!(Reply::decode(frame).unwrap(), Reply::Nak);
    }

    #[test]
    fn short_state_data_is_a_length_error() {
        let frame = Frame {
            ptype: PacketType::Gs as u8,
            data: &[0u8; 41],
        };
        assert_eq!(
            Reply::decode(frame),
            Err(DecodeError::WrongLength {
                ptype: 7,
                expected: 42,
                got: 41
            })
        );
    }

    #[test]
    fn sonar_data_reply_is_unsupported() {
        let frame = Frame {
            ptype: PacketType::GetSn as u8,
            data: &[0u8; 20],
        };
        assert_eq!(Reply::decode(frame), Err(DecodeError::UnsupportedReply(20)));
    }

    #[test]
    fn motor_status_bits_decode() {
        // bit 0 left, bit 1 right, bits 2–3 battery, 4 plugged, 5 charging, 6 e-stop
        let m = MotorStatus(0b0111_0110);
        assert!(!m.left_moving());
        assert!(m.right_moving());
        assert_eq!(m.battery(), Battery::Medium);
        assert!(m.plugged_in() && m.charging() && m.estop());
        assert_eq!(MotorStatus(0b1100).battery(), Battery::Unknown);
        assert_eq!(MotorStatus(0).battery(), Battery::Low);
    }
}
