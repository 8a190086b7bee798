//! The Nomad Scout driver: the pure cycle logic ([`core`]) and the link to
//! the robot ([`link`]); `main.rs` wires them to the bus.

pub mod core;
pub mod link;

pub use core::{CoreConfig, CoreStats, ScoutCore};
pub use link::{Link, LinkError, LinkStats, PortSpec};
