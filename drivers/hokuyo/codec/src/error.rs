//! Typed errors: each variant says what was expected and what came.
//!
//! Errors on the hot path are `Copy` and allocation-free, so a corrupt scan costs
//! nothing but the counter the caller bumps.

use crate::status::{Command, Status};
use thiserror::Error;

/// A run of encoded characters could not be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum CharError {
    #[error("expected a SCIP character 0x30..=0x6F, got 0x{byte:02X} at offset {offset}")]
    OutOfRange { byte: u8, offset: usize },
    #[error("expected 1..=5 encoded characters, got {width}")]
    Width { width: usize },
}

/// The echo line of a reply could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum EchoError {
    #[error("expected a two-letter command, got {len} bytes starting 0x{first:02X}")]
    NotACommand { len: usize, first: u8 },
    #[error("{command}: expected {expected} parameter digits, got {found}")]
    ParamLength {
        command: Command,
        expected: usize,
        found: usize,
    },
    #[error("{command}: parameter `{field}` is not a decimal number")]
    NotNumeric {
        command: Command,
        field: &'static str,
    },
    #[error("{command}: end step {end} is before start step {start}")]
    EndBeforeStart {
        command: Command,
        start: u16,
        end: u16,
    },
}

/// A reply frame (or one of its lines) is malformed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum DecodeError {
    #[error("empty frame: expected an echo line")]
    Empty,
    #[error("frame of {len} bytes does not end in LF LF")]
    Unterminated { len: usize },
    #[error("line 2: expected a status line, the frame ended after the echo")]
    MissingStatus,
    #[error(
        "line 2: expected 2 status characters + checksum (or a bare SCIP 1.1 status), got {len} bytes"
    )]
    BadStatus { len: usize },
    #[error("line {line}: checksum expected {:?}, got {:?}", char::from(*expected), char::from(*found))]
    Checksum {
        line: usize,
        expected: u8,
        found: u8,
    },
    #[error("line {line}: expected payload + checksum, got an empty line")]
    EmptyLine { line: usize },
    #[error("line {line}: {len} bytes exceed the {max}-byte maximum of a data line")]
    LineTooLong { line: usize, len: usize, max: usize },
    #[error(
        "line {line}, offset {offset}: expected a SCIP data character 0x30..=0x6F, got 0x{byte:02X}"
    )]
    BadChar {
        line: usize,
        offset: usize,
        byte: u8,
    },
    #[error("echo line: {0}")]
    Echo(#[from] EchoError),
    #[error("{command} reply with status {status} carries no scan data")]
    NotScanData { command: Command, status: Status },
    #[error("scan data: expected a timestamp line of 4 characters + checksum, got {len} bytes")]
    BadTimestamp { len: usize },
    #[error("scan data: expected {expected} values from the echo's start/end/cluster, got {got}")]
    CountMismatch { expected: usize, got: usize },
    #[error(
        "scan data: {chars} characters left over at the end (a value split with no continuation)"
    )]
    PartialValue { chars: usize },
    #[error("scan data: {needed} values do not fit the caller's buffer of {capacity}")]
    BufferTooSmall { needed: usize, capacity: usize },
    #[error("{command} reply: expected a time line of 4 characters + checksum, got {len} bytes")]
    BadTime { command: Command, len: usize },
    #[error("parameter line {line}: expected KEY:VALUE;checksum, found no ':'")]
    ParamNoColon { line: usize },
}

/// A VV/PP/II reply could not be turned into typed parameters.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ParamError {
    #[error(transparent)]
    Decode(#[from] DecodeError),
    #[error("expected a {expected} reply, got {got}")]
    WrongCommand { expected: Command, got: Command },
    #[error("{command} answered status {status} ({meaning}), expected 00")]
    Status {
        command: Command,
        status: Status,
        meaning: &'static str,
    },
    #[error("{command} reply lacks the {key} parameter")]
    Missing { command: Command, key: &'static str },
    #[error("{key}: expected a decimal number, got {value:?}")]
    NotNumber { key: &'static str, value: String },
    #[error("PP geometry is inconsistent: {0}")]
    Geometry(String),
}

/// A request cannot be encoded (the host asked for something SCIP cannot say).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum RequestError {
    #[error("{field} = {value} does not fit {digits} decimal digits")]
    FieldTooLarge {
        field: &'static str,
        value: u32,
        digits: usize,
    },
    #[error("tag of {len} characters exceeds the 16-character limit")]
    TagTooLong { len: usize },
    #[error("tag character 0x{byte:02X} is not a letter, digit, space or one of ._+@")]
    TagChar { byte: u8 },
    #[error("TM control code {code} is not 0, 1 or 2")]
    TimeCode { code: u8 },
}
