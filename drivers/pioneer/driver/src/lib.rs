//! The Pioneer driver: link / core / loop / thin main, testable without a
//! port or a bus:
//!
//! - [`link`]: serial device or `tcp://host:port` (MobileSim/AMRISim);
//! - [`core`]: pure: the ARCOS [`session`] state machine (handshake,
//!   stale-session recovery, link loss, velocity refresh and keep-alive),
//!   [`motion`] (bus velocity commands to a safe target: limits, stop on
//!   timeout) and [`messages`] (SIPs to `Odometry` and `SonarRing`);
//! - [`driver`]: the poll loop with the runtime's reconnect policy, talking
//!   to the process through a [`driver::DriverSink`].

pub mod core;
pub mod driver;
pub mod link;
pub mod messages;
pub mod motion;
pub mod session;

pub use core::{CoreCounters, Output, PioneerCore};
pub use driver::{Driver, DriverSink};
