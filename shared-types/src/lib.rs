//! Message types every smokenav process exchanges.
//!
//! Each bus message is a fixed-size `#[repr(C)]` value with an explicit
//! `#[type_name]`, so iceoryx2 can move it between processes without copying
//! or serialising, and renaming a Rust module never changes its wire identity.
//! All quantities are SI: metres, radians, seconds; stamps are nanoseconds of
//! the host's `CLOCK_MONOTONIC` (see [`clock`]).
//!
//! The [`record`] module holds the same messages as ordinary owned Rust
//! values with serde support: what `smokenav topic echo --json` prints and
//! `smokenav fuse` reads back.

pub mod clock;
pub mod fused;
pub mod geometry;
pub mod header;
pub mod health;
pub mod laser;
pub mod odom;
pub mod record;
pub mod slam;
pub mod smoke;
pub mod sonar;
pub mod text;

pub use clock::{Clock, MockClock, MonotonicClock, Stamp};
pub use fused::{FusedScan, FusionMethod, SectionDecision, SectionSource, SyncState};
pub use geometry::{Pose2, normalize_angle};
pub use header::Header;
pub use health::{Health, HealthState, Metric};
pub use laser::{BeamReading, LaserScan, MAX_BEAMS};
pub use odom::{Odometry, OdometryFlags, VelocityCommand};
pub use slam::{MapInfo, PoseEstimate};
pub use smoke::{SmokeReading, SmokeSensorState, SmokeTrend};
pub use sonar::{MAX_SONARS, SonarReading, SonarRing, SonarStatus};
pub use text::FixedStr;

/// Re-exported so crates deriving bus messages need no direct iceoryx2 dependency.
pub use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Error converting between the fixed-size bus types and their owned forms.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConversionError {
    #[error("{field}: {len} elements exceed the fixed capacity of {capacity}")]
    TooLong {
        field: &'static str,
        len: usize,
        capacity: usize,
    },
    #[error("{field}: {len} elements, expected {expected} (one per beam)")]
    LengthMismatch {
        field: &'static str,
        len: usize,
        expected: usize,
    },
    #[error("{field}: unknown value {value:?}")]
    UnknownValue { field: &'static str, value: String },
}
