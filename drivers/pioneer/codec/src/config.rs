//! The CONFIG packet (reply type 0x20 to command 18).
//!
//! Field order from ARIA's `ArRobotConfigPacketReader::packetHandler`. The
//! fields up to `watchdog` are present in every firmware we know of; later ones
//! were added over the years (AMRISim stops after `charge_threshold`), so each
//! is read only while bytes remain.

use crate::DecodeError;
use crate::wire::{EncodeError, PacketBuf, PacketWriter, Reader};
use serde::Serialize;

pub const CONFIG_PACKET: u8 = 0x20;

/// A field type that can be read from and written to a packet.
trait Field: Sized {
    fn read(r: &mut Reader<'_>) -> Option<Self>;
    fn write(&self, w: &mut PacketWriter<'_>) -> Result<(), EncodeError>;
}

macro_rules! int_field {
    ($($t:ident),*) => {$(
        impl Field for $t {
            fn read(r: &mut Reader<'_>) -> Option<Self> {
                r.$t()
            }
            fn write(&self, w: &mut PacketWriter<'_>) -> Result<(), EncodeError> {
                w.$t(*self)
            }
        }
    )*};
}
int_field!(u8, i8, u16, i16, u32);

impl Field for String {
    fn read(r: &mut Reader<'_>) -> Option<Self> {
        r.cstr().map(|b| String::from_utf8_lossy(b).into_owned())
    }
    fn write(&self, w: &mut PacketWriter<'_>) -> Result<(), EncodeError> {
        w.cstr("config string", self)
    }
}

macro_rules! config_packet {
    (
        required { $( $(#[$rm:meta])* $req:ident : $rt:ty ),* $(,)? }
        optional { $( $(#[$om:meta])* $opt:ident : $ot:ty ),* $(,)? }
    ) => {
        /// A decoded CONFIG packet. Units are the robot's (mm/s, deg/s, ms, decivolts).
        #[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
        pub struct ConfigPacket {
            $( $(#[$rm])* pub $req: $rt, )*
            $( $(#[$om])* pub $opt: Option<$ot>, )*
            /// Bytes after the last field we know.
            pub unparsed_tail: u8,
        }

        impl ConfigPacket {
            /// Decodes a CONFIG payload (type byte 0x20 first).
            pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
                let mut r = Reader::new(payload);
                match r.u8() {
                    Some(CONFIG_PACKET) => {}
                    Some(got) => return Err(DecodeError::WrongType { expected: "CONFIG (0x20)", got }),
                    None => return Err(DecodeError::Empty),
                }
                let mut c = ConfigPacket::default();
                $(
                    c.$req = <$rt as Field>::read(&mut r).ok_or(DecodeError::Truncated {
                        what: concat!("CONFIG ", stringify!($req)),
                        needed: 1,
                        remaining: r.remaining(),
                    })?;
                )*
                $(
                    match <$ot as Field>::read(&mut r) {
                        Some(v) => c.$opt = Some(v),
                        None => {
                            c.unparsed_tail = r.remaining().min(255) as u8;
                            return Ok(c);
                        }
                    }
                )*
                c.unparsed_tail = r.remaining().min(255) as u8;
                Ok(c)
            }

            /// Encodes this packet; optional fields up to the first `None`.
            pub fn encode(&self, out: &mut PacketBuf) -> Result<(), EncodeError> {
                let mut w = PacketWriter::new(out);
                w.u8(CONFIG_PACKET)?;
                $( Field::write(&self.$req, &mut w)?; )*
                $(
                    match &self.$opt {
                        Some(v) => Field::write(v, &mut w)?,
                        None => return w.finish(),
                    }
                )*
                w.finish()
            }
        }
    };
}

config_packet! {
    required {
        robot_type: String,
        subtype: String,
        serial_number: String,
        /// Set on ATs with P2OS; unused.
        four_mots: u8,
        rot_vel_top: u16,
        trans_vel_top: u16,
        rot_accel_top: u16,
        trans_accel_top: u16,
        pwm_max: u16,
        name: String,
        /// SIP cycle, ms.
        sip_cycle: u8,
        /// HOSTBAUD index: 0=9600 … 4=115200.
        host_baud: u8,
        aux1_baud: u8,
        has_gripper: u16,
        front_sonar: u16,
        rear_sonar: u8,
        low_battery: u16,
        rev_count: u16,
        /// Watchdog, ms: the robot stops when no command arrived for this long.
        watchdog: u16,
    }
    optional {
        normal_mpacs: u8,
        stall_val: u16,
        stall_count: u16,
        joy_vel: u16,
        joy_rot_vel: u16,
        rot_vel_max: u16,
        trans_vel_max: u16,
        rot_accel: u16,
        rot_decel: u16,
        rot_kp: u16,
        rot_kv: u16,
        rot_ki: u16,
        trans_accel: u16,
        trans_decel: u16,
        trans_kp: u16,
        trans_kv: u16,
        trans_ki: u16,
        front_bumps: u8,
        rear_bumps: u8,
        has_charger: u8,
        sonar_cycle: u8,
        /// 2 = the robot resets to 9600 baud when the session ends.
        reset_baud: u8,
        gyro_type: u8,
        drift_factor: i16,
        aux2_baud: u8,
        aux3_baud: u8,
        ticks_mm: u16,
        shutdown_voltage: u16,
        firmware_version: String,
        gyro_cw: u16,
        gyro_ccw: u16,
        kinematics_delay: u8,
        lat_vel_top: u16,
        lat_accel_top: u16,
        lat_vel_max: u16,
        lat_accel: u16,
        lat_decel: u16,
        charge_threshold: u16,
        pdb_port: u8,
        gyro_rate_limit: u16,
        high_temperature_shutdown: i8,
        power_bits: u16,
        battery_type: u8,
        state_of_charge_low: u16,
        state_of_charge_shutdown: u16,
        bootloader_version: String,
        config_flags: u32,
        gyro_fw_version: i16,
    }
}

impl ConfigPacket {
    /// Baud rate the HOSTBAUD index stands for.
    pub fn host_baud_rate(&self) -> Option<u32> {
        host_baud_rate(self.host_baud)
    }
}

/// HOSTBAUD index to baud rate (NOTES §1.1).
pub fn host_baud_rate(index: u8) -> Option<u32> {
    match index {
        0 => Some(9600),
        1 => Some(19200),
        2 => Some(38400),
        3 => Some(57600),
        4 => Some(115200),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What AMRISim sends (EmulatePioneer.cc): fields through charge_threshold.
    fn amrisim_like() -> ConfigPacket {
        ConfigPacket {
            robot_type: "Pioneer".into(),
            subtype: "p3dx".into(),
            serial_number: "SIM".into(),
            rot_vel_top: 360,
            trans_vel_top: 2200,
            pwm_max: 400,
            name: "AMRISim".into(),
            sip_cycle: 100,
            front_sonar: 1,
            rear_sonar: 1,
            watchdog: 2000,
            normal_mpacs: Some(0),
            stall_val: Some(0),
            stall_count: Some(0),
            joy_vel: Some(0),
            joy_rot_vel: Some(0),
            rot_vel_max: Some(100),
            trans_vel_max: Some(1500),
            rot_accel: Some(100),
            rot_decel: Some(100),
            rot_kp: Some(0),
            rot_kv: Some(0),
            rot_ki: Some(0),
            trans_accel: Some(300),
            trans_decel: Some(300),
            trans_kp: Some(0),
            trans_kv: Some(0),
            trans_ki: Some(0),
            front_bumps: Some(0),
            rear_bumps: Some(0),
            has_charger: Some(0),
            sonar_cycle: Some(0),
            reset_baud: Some(2),
            gyro_type: Some(0),
            drift_factor: Some(0),
            aux2_baud: Some(0),
            aux3_baud: Some(0),
            ticks_mm: Some(0),
            shutdown_voltage: Some(0),
            firmware_version: Some("1.0".into()),
            gyro_cw: Some(0),
            gyro_ccw: Some(0),
            kinematics_delay: Some(0),
            lat_vel_top: Some(0),
            lat_accel_top: Some(0),
            lat_vel_max: Some(0),
            lat_accel: Some(0),
            lat_decel: Some(0),
            charge_threshold: Some(0),
            ..Default::default()
        }
    }

    #[test]
    fn amrisim_config_without_newer_fields_round_trips() {
        let c = amrisim_like();
        let mut p = PacketBuf::new();
        c.encode(&mut p).unwrap();
        let d = ConfigPacket::decode(p.payload()).unwrap();
        assert_eq!(d, c);
        assert_eq!(d.watchdog, 2000);
        assert_eq!(d.pdb_port, None);
        assert_eq!(d.host_baud_rate(), Some(9600));
    }

    #[test]
    fn config_missing_watchdog_is_typed_error() {
        let c = amrisim_like();
        let mut p = PacketBuf::new();
        c.encode(&mut p).unwrap();
        // Cut inside the required block: type + 3 strings + … stops before watchdog.
        let payload = p.payload();
        let cut = payload.iter().position(|&b| b == b'A').unwrap() + 8 + 3 + 4 + 2;
        let e = ConfigPacket::decode(&payload[..cut]).unwrap_err();
        assert!(matches!(e, DecodeError::Truncated { .. }), "{e}");
    }

    #[test]
    fn full_modern_config_decodes_every_field() {
        let mut c = amrisim_like();
        c.pdb_port = Some(1);
        c.gyro_rate_limit = Some(300);
        c.high_temperature_shutdown = Some(-128);
        c.power_bits = Some(0xFFFF);
        c.battery_type = Some(2);
        c.state_of_charge_low = Some(20);
        c.state_of_charge_shutdown = Some(5);
        c.bootloader_version = Some("b2".into());
        c.config_flags = Some(0x11);
        c.gyro_fw_version = Some(-1);
        let mut p = PacketBuf::new();
        c.encode(&mut p).unwrap();
        let d = ConfigPacket::decode(p.payload()).unwrap();
        assert_eq!(d, c);
        assert_eq!(d.unparsed_tail, 0);
    }
}
