//! The Nomad Scout driver: link / core / loop / thin main.
//!
//! - [`link`]: the serial (or TCP) port and one request/reply exchange;
//! - [`core`]: pure: what to send each cycle, the messages of each reply,
//!   velocity command limits and timeout;
//! - [`driver`]: the cycle loop with the runtime's reconnect policy, talking
//!   to the process through a [`DriverSink`]; `main.rs` wires it to the bus.

pub mod core;
pub mod driver;
pub mod link;

pub use core::{CoreConfig, CoreStats, ScoutCore};
pub use driver::{Driver, DriverConfig, DriverEvent, DriverSink, DriverStatus};
pub use link::{Link, LinkError, LinkStats, PortSpec};
