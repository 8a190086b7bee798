//! Pure codec for the Nomadic direct serial protocol of the Nomad Scout (bytes in, typed values out, no I/O).
//!
//! Facts come from Nomadic's host library `Ndirect.c` (v2.6.13, the Nomadic
//! direct protocol in REFERENCES.md):
//! - [`frame`]: `01 | len_lo len_hi | type | data | chk | 5C` framing and an
//!   incremental [`Splitter`] that resynchronises after garbage;
//! - [`int`]: sign-magnitude 16-bit integers;
//! - [`Command`]: the requests a Scout driver sends (gs, vm, st, conf_sn,
//!   conf_tm, dp, da, zr, lp) and their decoding (for the emulator);
//! - [`Reply`] / [`StateReply`]: NAK and the Scout's fixed-mask state packet;
//! - [`SonarOrder`]: the `conf_sn` firing order; [`DecodeError`]: what did not decode;
//! - [`units`]: conversions to SI and differential-drive kinematics.

pub mod command;
pub mod error;
pub mod frame;
pub mod int;
pub mod reply;
pub mod sonar;
pub mod units;

pub use command::Command;
pub use error::DecodeError;
pub use frame::{
    Direction, EncodeError, Frame, FrameError, MAX_FRAME, Splitter, SplitterStats, encode_frame,
    parse_frame,
};
pub use reply::{Battery, MotorStatus, Reply, SONARS, StateReply};
pub use sonar::{SonarOrder, SonarOrderError};
pub use units::{DiffDrive, SonarRange, StateSi, WheelOrder, WheelSpeeds};

/// `len` of a Scout state reply: type + 42 data bytes + checksum.
pub const STATE_LEN: usize = reply::STATE_DATA_LEN + 2;

/// Packet types of the direct protocol (`Ndirect.c`'s command type list).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum PacketType {
    Ac = 1,
    Sp = 2,
    Pr = 3,
    Pa = 4,
    Vm = 5,
    Ct = 6,
    Gs = 7,
    Nak = 8,
    St = 9,
    Lp = 10,
    Tk = 11,
    Dp = 12,
    Zr = 13,
    ConfIr = 14,
    ConfSn = 15,
    ConfCp = 16,
    ConfLs = 17,
    ConfTm = 18,
    GetIr = 19,
    GetSn = 20,
    GetRc = 21,
    GetRv = 22,
    GetRa = 23,
    GetCp = 24,
    GetLs = 25,
    SetupLs = 26,
    GetBp = 27,
    ConfSg = 28,
    GetSg = 29,
    Da = 30,
    Ws = 31,
    ConfSer = 35,
    Mv = 43,
    Special = 128,
}

impl PacketType {
    pub fn from_u8(v: u8) -> Option<Self> {
        use PacketType::*;
        Some(match v {
            1 => Ac,
            2 => Sp,
            3 => Pr,
            4 => Pa,
            5 => Vm,
            6 => Ct,
            7 => Gs,
            8 => Nak,
            9 => St,
            10 => Lp,
            11 => Tk,
            12 => Dp,
            13 => Zr,
            14 => ConfIr,
            15 => ConfSn,
            16 => ConfCp,
            17 => ConfLs,
            18 => ConfTm,
            19 => GetIr,
            20 => GetSn,
            21 => GetRc,
            22 => GetRv,
            23 => GetRa,
            24 => GetCp,
            25 => GetLs,
            26 => SetupLs,
            27 => GetBp,
            28 => ConfSg,
            29 => GetSg,
            30 => Da,
            31 => Ws,
            35 => ConfSer,
            43 => Mv,
            128 => Special,
            _ => return None,
        })
    }

    /// The robot answers these with a full state packet of the same type
    /// (`Process_Robot_Resp`).
    pub fn replies_with_state(self) -> bool {
        use PacketType::*;
        matches!(
            self,
            Ac | Sp
                | Pr
                | Pa
                | Vm
                | Mv
                | Ct
                | Gs
                | St
                | Lp
                | Dp
                | Da
                | Ws
                | Zr
                | Tk
                | ConfIr
                | ConfSn
                | ConfLs
                | ConfTm
                | ConfSg
                | ConfSer
                | SetupLs
        )
    }

    /// The `len` of this command as the host library builds it, or None when
    /// it varies (talk strings, user packets) or the type is reply-only.
    pub fn command_len(self) -> Option<usize> {
        use PacketType::*;
        match self {
            Ac | Sp | Pr | Pa | Vm | ConfLs => Some(8),
            Ct => Some(9),
            Gs | St | Lp | Zr | GetIr | GetSn | GetRc | GetRv | GetRa | GetCp | GetLs | GetBp
            | GetSg | SetupLs => Some(2),
            Dp | Da | Ws => Some(6),
            ConfIr | ConfSn => Some(19),
            ConfCp | ConfTm => Some(3),
            ConfSg | ConfSer => Some(5),
            Mv => Some(14),
            Nak | Tk | Special => None,
        }
    }
}
