//! SYNC handshake replies (robot to host).
//!
//! SYNC0 and SYNC1 are echoed unchanged; the SYNC2 reply (type 2) carries
//! three NUL-terminated strings: robot name, class, subclass.

use crate::DecodeError;
use crate::wire::{EncodeError, PacketBuf, PacketWriter, Reader};
use serde::Serialize;

/// Longest identity string kept (the payload bounds them anyway).
pub const MAX_IDENT_LEN: usize = 64;

/// What the robot says it is in its SYNC2 reply.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RobotIdent {
    /// "AMRISim", "MobileSim", or the robot's configured name.
    pub name: String,
    /// "Pioneer" for every ARCOS base.
    pub class: String,
    /// "p3dx", "p3dx-sh", …: selects the conversion factors.
    pub subclass: String,
}

impl RobotIdent {
    pub fn new(name: &str, class: &str, subclass: &str) -> Self {
        Self {
            name: name.into(),
            class: class.into(),
            subclass: subclass.into(),
        }
    }

    /// Decodes a SYNC2 reply payload (type byte 2 first).
    pub fn decode(payload: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader::new(payload);
        match r.u8() {
            Some(2) => {}
            Some(got) => {
                return Err(DecodeError::WrongType {
                    expected: "SYNC2 reply (0x02)",
                    got,
                });
            }
            None => return Err(DecodeError::Empty),
        }
        let name = ident_string(&mut r, "robot name")?;
        let class = ident_string(&mut r, "robot class")?;
        let subclass = ident_string(&mut r, "robot subclass")?;
        Ok(Self {
            name,
            class,
            subclass,
        })
    }

    pub fn encode(&self, out: &mut PacketBuf) -> Result<(), EncodeError> {
        let mut w = PacketWriter::new(out);
        w.u8(2)?;
        w.cstr("robot name", &self.name)?;
        w.cstr("robot class", &self.class)?;
        w.cstr("robot subclass", &self.subclass)?;
        w.finish()
    }
}

/// A NUL-terminated string; the last one may end with the payload instead
/// (we accept a missing final NUL rather than lose the subclass).
fn ident_string(r: &mut Reader<'_>, what: &'static str) -> Result<String, DecodeError> {
    let bytes = match r.cstr() {
        Some(s) => s,
        None if !r.is_empty() => r.rest(),
        None => {
            return Err(DecodeError::Truncated {
                what,
                needed: 1,
                remaining: 0,
            });
        }
    };
    if bytes.len() > MAX_IDENT_LEN {
        return Err(DecodeError::TooLong {
            what,
            len: bytes.len(),
            max: MAX_IDENT_LEN,
        });
    }
    Ok(String::from_utf8_lossy(bytes).into_owned())
}

/// A SYNC0/SYNC1 echo is the bare packet of that number.
pub fn is_sync_echo(payload: &[u8], seq: u8) -> bool {
    payload == [seq]
}

#[cfg(test)]
mod tests {
    use super::*;

    const AMRISIM_SYNC2: [u8; 27] = [
        0xfa, 0xfb, 0x18, 0x02, 0x41, 0x4d, 0x52, 0x49, 0x53, 0x69, 0x6d, 0x00, 0x50, 0x69, 0x6f,
        0x6e, 0x65, 0x65, 0x72, 0x00, 0x70, 0x33, 0x64, 0x78, 0x00, 0xeb, 0xbd,
    ];

    #[test]
    fn amrisim_sync2_reply_names_pioneer_p3dx() {
        let id = RobotIdent::decode(&AMRISIM_SYNC2[3..25]).unwrap();
        assert_eq!(id, RobotIdent::new("AMRISim", "Pioneer", "p3dx"));
    }

    #[test]
    fn sync2_reply_encodes_byte_for_byte() {
        let mut p = PacketBuf::new();
        RobotIdent::new("AMRISim", "Pioneer", "p3dx")
            .encode(&mut p)
            .unwrap();
        assert_eq!(p.as_bytes(), AMRISIM_SYNC2);
    }

    #[test]
    fn missing_subclass_is_a_typed_error() {
        let e = RobotIdent::decode(b"\x02AMRISim\0Pioneer\0").unwrap_err();
        assert!(
            matches!(
                e,
                DecodeError::Truncated {
                    what: "robot subclass",
                    ..
                }
            ),
            "{e}"
        );
        let e = RobotIdent::decode(b"\x32\0").unwrap_err();
        assert!(matches!(e, DecodeError::WrongType { got: 0x32, .. }));
    }

    #[test]
    fn final_nul_may_be_missing() {
        let id = RobotIdent::decode(b"\x02MobileSim\0Pioneer\0p3dx-sh").unwrap();
        assert_eq!(id.subclass, "p3dx-sh");
    }
}
