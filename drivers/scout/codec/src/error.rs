//! What a packet that does not decode was.

use crate::sonar::SonarOrderError;

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("packet type {0} is not a Nomadic packet type")]
    UnknownType(u8),
    #[error("packet type {ptype} should carry {expected} data bytes, got {got}")]
    WrongLength {
        ptype: u8,
        expected: usize,
        got: usize,
    },
    #[error("command type {0} is not one this codec handles")]
    UnsupportedCommand(u8),
    #[error("reply type {0} is not a state packet or NAK")]
    UnsupportedReply(u8),
    #[error("bad conf_sn order: {0}")]
    SonarOrder(SonarOrderError),
}
