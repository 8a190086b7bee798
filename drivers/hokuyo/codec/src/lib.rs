//! Pure SCIP 2.0 codec for Hokuyo laser scanners (bytes in, typed values out, no I/O).
//!
//! - [`chars`]: checksums and the 2/3/4-character encoding.
//! - [`request`]: request encoding (with tags) and device-side parsing.
//! - [`splitter`]: an incremental `LF LF` frame splitter with a fixed buffer.
//! - [`reply`]: reply parsing; scans decode into caller buffers without allocating.
//! - [`params`]: typed VV/PP/II and the [`Geometry`] PP defines.
//! - [`writer`]: reply encoding, as a device (or emulator) writes it.
//! - [`sync`]: sensor-clock → host-clock mapping (TM calibration, drift, 24-bit wrap).
//! - [`capture`]: a raw capture to one JSON object per reply.

pub mod capture;
pub mod chars;
pub mod error;
pub mod params;
pub mod reply;
pub mod request;
pub mod splitter;
pub mod status;
pub mod sync;
pub mod writer;

pub use capture::{CaptureOptions, ReplyJson, decode_capture};
pub use error::{CharError, DecodeError, EchoError, ParamError, RequestError};
pub use params::{Geometry, ModelFamily, Reading, SensorSpec, SensorState, VersionInfo};
pub use reply::{Echo, Param, Reply, ScanEcho, ScanHeader, parse_param_line, parse_reply};
pub use request::{
    EncodedRequest, ParsedRequest, Rejection, Request, StepRange, Tag, TimeMode, parse_request,
};
pub use splitter::{FrameSplitter, SplitterStats};
pub use status::{Command, Status, StatusKind};
pub use sync::{
    ClockSync, OffsetEstimate, SyncConfig, SyncError, SyncStats, TimeSample, WrapTracker,
};
pub use writer::ReplyWriter;
