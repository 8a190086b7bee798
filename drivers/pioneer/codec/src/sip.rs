//! The standard server information packet (SIP, types 0x32 stopped / 0x33 moving).
//!
//! Field order is ARIA's `ArRobot::processMotorPacket`. Everything from
//! GRIP_STATE on is optional: older firmware stops earlier, and (like ARIA)
//! we read each optional field only while bytes remain.

use crate::DecodeError;
use crate::wire::{EncodeError, PacketBuf, PacketWriter, Reader};
use serde::Serialize;
use serde::ser::SerializeSeq;

pub const SIP_STOPPED: u8 = 0x32;
pub const SIP_MOVING: u8 = 0x33;

/// Readings one SIP can carry: (198 − 20 fixed bytes) / 3 = 59, rounded up.
pub const MAX_SIP_SONARS: usize = 64;

/// Positions are 15-bit counters (`XPOS & 0x7FFF`).
pub const POS_MASK: u16 = 0x7FFF;

/// Bits of [`Sip::flags`].
pub mod flag {
    pub const MOTORS_ENABLED: u16 = 1 << 0;
    /// Bits 1–4: sonar arrays on.
    pub const SONAR_ARRAYS_SHIFT: u16 = 1;
    pub const SONAR_ARRAYS_MASK: u16 = 0x0F << 1;
    pub const ESTOP: u16 = 1 << 5;
    pub const CHARGER_POWER_GOOD: u16 = 1 << 10;
}

/// One sonar reading: transducer number and range in robot units
/// (× RangeConvFactor → mm).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct SonarSample {
    pub index: u8,
    pub range: u16,
}

/// The sonar readings of one SIP, in a fixed array.
#[derive(Clone, PartialEq, Eq)]
pub struct SonarSamples {
    items: [SonarSample; MAX_SIP_SONARS],
    len: u8,
}

impl Default for SonarSamples {
    fn default() -> Self {
        Self {
            items: [SonarSample::default(); MAX_SIP_SONARS],
            len: 0,
        }
    }
}

impl SonarSamples {
    pub fn as_slice(&self) -> &[SonarSample] {
        self.items.get(..usize::from(self.len)).unwrap_or(&[])
    }

    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Returns false when full.
    pub fn push(&mut self, s: SonarSample) -> bool {
        match self.items.get_mut(usize::from(self.len)) {
            Some(slot) => {
                *slot = s;
                self.len += 1;
                true
            }
            None => false,
        }
    }

    pub fn clear(&mut self) {
        self.len = 0;
    }
}

impl std::fmt::Debug for SonarSamples {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.as_slice()).finish()
    }
}

impl Serialize for SonarSamples {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.len()))?;
        for x in self.as_slice() {
            seq.serialize_element(x)?;
        }
        seq.end()
    }
}

/// A decoded standard SIP. Raw robot units; convert with [`crate::RobotParams`].
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct Sip {
    /// 0x32 (stopped) or 0x33 (moving). AMRISim always sends 0x32.
    pub packet_type: u8,
    /// Position counters as sent. Only the low 15 bits count ([`Sip::x_pos`]);
    /// AMRISim sends small negatives as 16-bit two's complement (`fe ff`).
    pub x: u16,
    pub y: u16,
    /// Heading, × AngleConvFactor → radians.
    pub th: i16,
    /// Wheel velocities, × VelConvFactor → mm/s.
    pub left_vel: i16,
    pub right_vel: i16,
    /// Battery, decivolts.
    pub battery_dv: u8,
    /// Low byte: bit 0 left stall, bits 1–7 rear bumpers; high byte: bit 0
    /// right stall, bits 1–7 front bumpers.
    pub stall_bumpers: u16,
    /// Legacy heading setpoint.
    pub control: i16,
    /// See [`flag`].
    pub flags: u16,
    /// × 2 = degrees.
    pub compass: u8,
    pub sonars: SonarSamples,
    // Optional trailing fields, in wire order.
    pub grip_state: Option<u8>,
    pub anport: Option<u8>,
    pub analog: Option<u8>,
    pub digin: Option<u8>,
    pub digout: Option<u8>,
    pub battery_x10: Option<u16>,
    pub charge_state: Option<u8>,
    /// 0.1 deg/s.
    pub rot_vel: Option<i16>,
    pub fault_flags: Option<u16>,
    pub lat_vel: Option<i16>,
    /// °C; −127 = unknown.
    pub temperature: Option<i8>,
    pub soc: Option<u8>,
    pub uc_time: Option<u32>,
    pub flags3: Option<u32>,
    /// Bytes after the last field we know (newer firmware, or a field cut short).
    pub unparsed_tail: u8,
}

fn need(what: &'static str, needed: usize, r: &Reader<'_>) -> DecodeError {
    DecodeError::Truncated {
        what,
        needed,
        remaining: r.remaining(),
    }
}

impl Sip {
    /// Decodes a SIP payload (type byte first).
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(payload);
        let packet_type = r.u8().ok_or(DecodeError::Empty)?;
        if packet_type != SIP_STOPPED && packet_type != SIP_MOVING {
            return Err(DecodeError::WrongType {
                expected: "standard SIP (0x32 or 0x33)",
                got: packet_type,
            });
        }
        let mut s = Sip {
            packet_type,
            ..Default::default()
        };
        s.x = r.u16().ok_or_else(|| need("XPOS", 2, &r))?;
        s.y = r.u16().ok_or_else(|| need("YPOS", 2, &r))?;
        s.th = r.i16().ok_or_else(|| need("THPOS", 2, &r))?;
        s.left_vel = r.i16().ok_or_else(|| need("L VEL", 2, &r))?;
        s.right_vel = r.i16().ok_or_else(|| need("R VEL", 2, &r))?;
        s.battery_dv = r.u8().ok_or_else(|| need("BATTERY", 1, &r))?;
        s.stall_bumpers = r.u16().ok_or_else(|| need("STALL/BUMPERS", 2, &r))?;
        s.control = r.i16().ok_or_else(|| need("CONTROL", 2, &r))?;
        s.flags = r.u16().ok_or_else(|| need("FLAGS", 2, &r))?;
        s.compass = r.u8().ok_or_else(|| need("COMPASS", 1, &r))?;
        let count = r.u8().ok_or_else(|| need("SONAR_COUNT", 1, &r))?;
        if usize::from(count) > MAX_SIP_SONARS {
            return Err(DecodeError::TooLong {
                what: "SONAR_COUNT",
                len: usize::from(count),
                max: MAX_SIP_SONARS,
            });
        }
        if r.remaining() < 3 * usize::from(count) {
            return Err(need("sonar readings", 3 * usize::from(count), &r));
        }
        for _ in 0..count {
            let index = r.u8().unwrap_or(0);
            let range = r.u16().unwrap_or(0);
            s.sonars.push(SonarSample { index, range });
        }
        // Optional tail: each field only if it fits; stop at the first that doesn't.
        macro_rules! opt {
            ($field:ident, $read:ident) => {
                match r.$read() {
                    Some(v) => s.$field = Some(v),
                    None => {
                        s.unparsed_tail = r.remaining() as u8;
                        return Ok(s);
                    }
                }
            };
        }
        opt!(grip_state, u8);
        opt!(anport, u8);
        opt!(analog, u8);
        opt!(digin, u8);
        opt!(digout, u8);
        opt!(battery_x10, u16);
        opt!(charge_state, u8);
        opt!(rot_vel, i16);
        opt!(fault_flags, u16);
        opt!(lat_vel, i16);
        opt!(temperature, i8);
        opt!(soc, u8);
        opt!(uc_time, u32);
        opt!(flags3, u32);
        // The payload is at most 198 bytes.
        s.unparsed_tail = r.remaining().min(255) as u8;
        Ok(s)
    }

    /// Encodes this SIP; optional fields are written up to the first `None`.
    pub fn encode(&self, out: &mut PacketBuf) -> Result<(), EncodeError> {
        let mut w = PacketWriter::new(out);
        w.u8(self.packet_type)?;
        w.u16(self.x)?;
        w.u16(self.y)?;
        w.i16(self.th)?;
        w.i16(self.left_vel)?;
        w.i16(self.right_vel)?;
        w.u8(self.battery_dv)?;
        w.u16(self.stall_bumpers)?;
        w.i16(self.control)?;
        w.u16(self.flags)?;
        w.u8(self.compass)?;
        w.u8(self.sonars.len() as u8)?;
        for s in self.sonars.as_slice() {
            w.u8(s.index)?;
            w.u16(s.range)?;
        }
        macro_rules! opt {
            ($field:ident, $write:ident) => {
                match self.$field {
                    Some(v) => w.$write(v)?,
                    None => return w.finish(),
                }
            };
        }
        opt!(grip_state, u8);
        opt!(anport, u8);
        opt!(analog, u8);
        opt!(digin, u8);
        opt!(digout, u8);
        opt!(battery_x10, u16);
        opt!(charge_state, u8);
        opt!(rot_vel, i16);
        opt!(fault_flags, u16);
        opt!(lat_vel, i16);
        opt!(temperature, i8);
        opt!(soc, u8);
        opt!(uc_time, u32);
        opt!(flags3, u32);
        w.finish()
    }

    /// The 15-bit X counter (× DistConvFactor → mm, modulo the wrap).
    pub fn x_pos(&self) -> u16 {
        self.x & POS_MASK
    }

    /// The 15-bit Y counter.
    pub fn y_pos(&self) -> u16 {
        self.y & POS_MASK
    }

    pub fn is_moving(&self) -> bool {
        self.packet_type == SIP_MOVING
    }

    pub fn motors_enabled(&self) -> bool {
        self.flags & flag::MOTORS_ENABLED != 0
    }

    /// Bit per sonar array that is on (bit 0 = first array).
    pub fn sonar_arrays(&self) -> u8 {
        ((self.flags & flag::SONAR_ARRAYS_MASK) >> flag::SONAR_ARRAYS_SHIFT) as u8
    }

    pub fn estop(&self) -> bool {
        self.flags & flag::ESTOP != 0
    }

    pub fn charger_power_good(&self) -> bool {
        self.flags & flag::CHARGER_POWER_GOOD != 0
    }

    pub fn left_stall(&self) -> bool {
        self.stall_bumpers & 0x0001 != 0
    }

    pub fn right_stall(&self) -> bool {
        self.stall_bumpers & 0x0100 != 0
    }

    /// Front bumper segments, bit 0 = first segment.
    pub fn front_bumpers(&self) -> u8 {
        ((self.stall_bumpers >> 9) & 0x7F) as u8
    }

    /// Rear bumper segments, bit 0 = first segment.
    pub fn rear_bumpers(&self) -> u8 {
        ((self.stall_bumpers >> 1) & 0x7F) as u8
    }

    /// Battery voltage, V: BATTERYX10 when the firmware sends it, else BATTERY.
    pub fn battery_volts(&self) -> f64 {
        match self.battery_x10 {
            Some(v) if v > 0 => f64::from(v) / 10.0,
            _ => f64::from(self.battery_dv) / 10.0,
        }
    }

    /// Temperature, °C, when known (−127 means unknown).
    pub fn temperature_c(&self) -> Option<i8> {
        self.temperature.filter(|&t| t != -127)
    }

    pub fn compass_deg(&self) -> u16 {
        u16::from(self.compass) * 2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trailing_fields_older_firmware_omits_are_none() {
        // A SIP that stops after the sonar readings (older firmware).
        let mut s = Sip {
            packet_type: SIP_STOPPED,
            x: 100,
            battery_dv: 125,
            ..Default::default()
        };
        s.sonars.push(SonarSample {
            index: 3,
            range: 812,
        });
        let mut p = PacketBuf::new();
        s.encode(&mut p).unwrap();
        assert_eq!(p.payload().len(), 20 + 3);
        let d = Sip::decode(p.payload()).unwrap();
        assert_eq!(d, s);
        assert_eq!(d.battery_x10, None);
        assert!((d.battery_volts() - 12.5).abs() < 1e-9);
    }

    #[test]
    fn field_cut_short_leaves_unparsed_tail() {
        // IO block present, then one byte of BATTERYX10.
        let s = Sip {
            packet_type: SIP_STOPPED,
            grip_state: Some(0),
            anport: Some(0),
            analog: Some(0),
            digin: Some(0),
            digout: Some(0),
            ..Default::default()
        };
        let mut p = PacketBuf::new();
        s.encode(&mut p).unwrap();
        let mut payload = p.payload().to_vec();
        payload.push(0x82);
        let d = Sip::decode(&payload).unwrap();
        assert_eq!(d.digout, Some(0));
        assert_eq!(d.battery_x10, None);
        assert_eq!(d.unparsed_tail, 1);
    }

    #[test]
    fn position_counters_keep_15_bits() {
        let mut payload = vec![SIP_MOVING, 0xFF, 0xFF, 0x01, 0x80];
        payload.extend_from_slice(&[0; 15]);
        let d = Sip::decode(&payload).unwrap();
        assert_eq!(d.x_pos(), 0x7FFF);
        assert_eq!(d.y_pos(), 0x0001);
        assert_eq!(d.y, 0x8001);
        assert!(d.is_moving());
    }

    #[test]
    fn sonar_count_beyond_payload_is_truncated_error() {
        let mut payload = vec![SIP_STOPPED];
        payload.extend_from_slice(&[0; 18]);
        payload.push(16); // 16 readings announced, none present
        let e = Sip::decode(&payload).unwrap_err();
        assert!(
            matches!(
                e,
                DecodeError::Truncated {
                    what: "sonar readings",
                    needed: 48,
                    remaining: 0
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn stall_and_bumper_bits_follow_aria() {
        let s = Sip {
            // right stall + front bumper 1; left stall + rear bumper 0 and 2
            stall_bumpers: 0x0100 | (0b10 << 9) | 0x0001 | (0b101 << 1),
            flags: flag::MOTORS_ENABLED | (0b0011 << 1) | flag::ESTOP,
            ..Default::default()
        };
        assert!(s.left_stall() && s.right_stall());
        assert_eq!(s.front_bumpers(), 0b10);
        assert_eq!(s.rear_bumpers(), 0b101);
        assert!(s.motors_enabled() && s.estop());
        assert_eq!(s.sonar_arrays(), 0b11);
    }
}
