//! Hokuyo driver: a thin loop around the pure SCIP codec.
//!
//! - [`port`]: serial (serialport) or TCP byte pipe with read deadlines.
//! - [`session`]: robust handshake (baud probing, SCIP 1.1 → 2.0, time-adjust mode,
//!   a stream left running), VV/PP/II, TM clock calibration.
//! - [`stream`]: MD/ME streaming into `LaserScan`s without allocation.
//! - [`driver`]: the reconnecting run loop the `smokenav-hokuyo` binary wires to the bus.

pub mod driver;
pub mod port;
pub mod session;
pub mod stream;

pub use driver::{Driver, DriverConfig, DriverEvent, DriverSink};
pub use port::{Port, PortSpec};
pub use session::{Recovered, SensorInfo, Session, SessionError};
pub use stream::{ScanConverter, ScanSink, StreamConfig, StreamCounters};
