//! Simulated time, published by `smokenav play` on `clock` (ROS 2 `/clock`).

use crate::header::Header;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// The data's time during a replay: `header.stamp_ns` is the instant of the
/// recording being played (on the clock of its stamps), so a consumer that
/// follows it (ROS 2's `use_sim_time`) sees the data on time at any `--rate`.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::SimClock")]
pub struct SimClock {
    /// The simulated time (stamp), sequence number; no frame.
    pub header: Header,
}
