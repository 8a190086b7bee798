//! What the bus can carry.

use iceoryx2::prelude::ZeroCopySend;
use smokenav_shared_types::{
    FusedScan, Header, Health, LaserScan, Odometry, PoseEstimate, SmokeReading, SonarRing,
    VelocityCommand,
};

/// A fixed-size message with a [`Header`]. The publisher fills in
/// `header.seq`; the subscriber uses it to count lost messages.
pub trait Message: ZeroCopySend + Copy + core::fmt::Debug + Default + 'static {
    /// The type's short name, as printed by `topic list` and `echo --json`.
    const NAME: &'static str;
    fn header(&self) -> &Header;
    fn header_mut(&mut self) -> &mut Header;
}

macro_rules! message {
    ($ty:ty, $name:literal, $($h:ident).+) => {
        impl Message for $ty {
            const NAME: &'static str = $name;
            fn header(&self) -> &Header {
                &self.$($h).+
            }
            fn header_mut(&mut self) -> &mut Header {
                &mut self.$($h).+
            }
        }
    };
}

message!(LaserScan, "LaserScan", header);
message!(SonarRing, "SonarRing", header);
message!(Odometry, "Odometry", header);
message!(VelocityCommand, "VelocityCommand", header);
message!(SmokeReading, "SmokeReading", header);
message!(FusedScan, "FusedScan", scan.header);
message!(PoseEstimate, "PoseEstimate", header);
message!(Health, "Health", header);
