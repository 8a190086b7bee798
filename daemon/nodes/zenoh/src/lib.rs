//! The Zenoh link: the robot's topics as rmw_zenoh publishes them, so a
//! ROS 2 node using rmw_zenoh on another machine sees them, and the
//! operator's view of several robots over the same network.
//!
//! - [`keys`]: rmw_zenoh's key expressions, liveliness tokens and attachment.
//! - [`rihs`]: ROS 2 type hashes of the recordings' message definitions.
//! - [`bridge`]: bus messages in, Zenoh samples out.
//! - [`command`]: `cmd_vel` from outside, decoded and checked.
//! - [`fleet`]: the operator's view of every robot on the network.

pub mod bridge;
pub mod command;
pub mod fleet;
pub mod keys;
pub mod rihs;

pub use bridge::{Bridge, BridgeError, BridgeStats};
