//! Hokuyo driver: link / core / thin main, around the pure SCIP codec.
//!
//! - [`link`]: serial (serialport) or TCP byte pipe with read deadlines.
//! - [`session`]: robust handshake over the link (baud probing, SCIP 1.1 → 2.0,
//!   time-adjust mode, a stream left running), VV/PP/II, TM clock calibration.
//! - [`core`]: pure: which steps are streamed, frames of the stream told
//!   apart, raw values to `LaserScan`s without allocation; the counters.
//! - [`driver`]: the reconnecting run loop (the runtime's [`Reconnect`]
//!   policy) that the `smokenav-hokuyo` binary wires to the bus through a
//!   [`DriverSink`].
//!
//! [`Reconnect`]: smokenav_platform_runtime::Reconnect

pub mod core;
pub mod driver;
pub mod link;
pub mod session;

pub use core::{ScanConverter, StreamConfig, StreamCounters};
pub use driver::{Driver, DriverConfig, DriverEvent, DriverSink, ScanSink};
pub use link::{Port, PortSpec};
pub use session::{Recovered, SensorInfo, Session, SessionError};
