//! The header every message starts with.

use crate::text::FixedStr;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Capacity of a frame id such as `laser`, `base_link` or `sonar_ring`.
pub const FRAME_ID_LEN: usize = 32;

#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
/// Stamp, sequence number and frame: the start of every bus message.
pub struct Header {
    /// When the data was measured, in nanoseconds of the host `CLOCK_MONOTONIC`.
    /// Drivers correct this for transport delay (e.g. the Hokuyo's clock sync),
    /// so it is the best estimate of the measurement instant, not the receive time.
    pub stamp_ns: u64,
    /// Per-publisher sequence number, starting at 0 and incremented by one
    /// per message: a gap means messages were lost.
    pub seq: u64,
    /// The coordinate frame the data is expressed in.
    pub frame_id: FixedStr<FRAME_ID_LEN>,
}

impl Header {
    /// A header with `frame_id` truncated to [`FRAME_ID_LEN`] bytes.
    pub fn new(stamp_ns: u64, seq: u64, frame_id: &str) -> Self {
        Self {
            stamp_ns,
            seq,
            frame_id: FixedStr::from_str_truncate(frame_id),
        }
    }

    /// Stamp in seconds, for algorithms that work in floating point.
    pub fn stamp_s(&self) -> f64 {
        self.stamp_ns as f64 * 1e-9
    }
}
