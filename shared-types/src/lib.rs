//! Message types every smokenav process exchanges.
//!
//! Each bus message is a fixed-size `#[repr(C)]` value with an explicit
//! `#[type_name]`, so iceoryx2 can move it between processes without copying
//! or serialising, and renaming a Rust module never changes its wire identity.
//! All quantities are SI: metres, radians, seconds; stamps are nanoseconds of
//! the host's `CLOCK_MONOTONIC` (see [`clock`]).
//!
//! The [`catalog`] lists every message type once, with its bus topics, its
//! JSON form and its ROS 2 type; the bus, the recording and the tools work
//! from it. The [`record`] module holds the same messages as ordinary owned
//! Rust values with serde support: what `smokenav topic echo --json` prints
//! and `smokenav fuse` reads back.

#![warn(missing_docs)]

pub mod catalog;
pub mod clock;
pub mod fused;
pub mod geometry;
pub mod header;
pub mod health;
pub mod identical;
pub mod laser;
pub mod odom;
pub mod record;
pub mod rng;
pub mod sim_clock;
pub mod slam;
pub mod smoke;
pub mod sonar;
pub mod text;
pub mod voxels;

pub use catalog::{AnyMessage, AnyMessageRef, Cataloged, Message, MessageKind, MessageVisitor};
pub use clock::{Clock, MockClock, MonotonicClock, Stamp};
pub use fused::{FusedScan, FusionMethod, SectionDecision, SectionSource, SyncState};
pub use geometry::{Pose2, Sweep, Twist2, normalize_angle};
pub use header::Header;
pub use health::{Health, HealthState, Metric};
pub use identical::BitIdentical;
pub use laser::{BeamReading, LaserScan, MAX_BEAMS};
pub use odom::{Odometry, OdometryFlags, VelocityCommand};
pub use rng::Rng;
pub use sim_clock::SimClock;
pub use slam::{MapInfo, PoseEstimate};
pub use smoke::{SmokeReading, SmokeSensorState, SmokeTrend};
pub use sonar::{MAX_SONARS, SonarReading, SonarRing, SonarStatus};
pub use text::FixedStr;
pub use voxels::{MAX_VOXELS, VoxelCloud};

/// Re-exported so crates deriving bus messages need no direct iceoryx2 dependency.
pub use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Error converting between the fixed-size bus types and their owned forms.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConversionError {
    /// More elements than the fixed-size message has room for.
    #[error("{field}: {len} elements exceed the fixed capacity of {capacity}")]
    TooLong {
        /// The field.
        field: &'static str,
        /// Elements given.
        len: usize,
        /// Elements the message holds at most.
        capacity: usize,
    },
    /// Two fields that must have one element each per beam (or cell) do not.
    #[error("{field}: {len} elements, expected {expected}")]
    LengthMismatch {
        /// The field.
        field: &'static str,
        /// Elements given.
        len: usize,
        /// Elements expected.
        expected: usize,
    },
    /// An enumeration field holds a name it does not have.
    #[error("{field}: unknown value {value:?}")]
    UnknownValue {
        /// The field.
        field: &'static str,
        /// What it held.
        value: String,
    },
    /// A record of one message type where another was expected.
    #[error("expected a {expected} record, got a {got} record")]
    WrongType {
        /// The type expected.
        expected: &'static str,
        /// The type of the record.
        got: &'static str,
    },
}
