//! Turns a raw SCIP byte capture into one JSON object per reply (`smokenav scip decode`).
//!
//! This is the debugging path, not the hot path: it owns its output.

use crate::error::DecodeError;
use crate::params::{Geometry, ModelFamily, Reading, SensorSpec};
use crate::reply::{Reply, parse_reply};
use crate::splitter::FrameSplitter;
use crate::status::Command;
use serde::Serialize;
use serde::ser::SerializeMap;

/// Options for [`decode_capture`].
#[derive(Debug, Clone, Copy)]
pub struct CaptureOptions {
    /// DMIN used to tell error codes from ranges until the capture holds a PP reply
    /// (20 mm: URG-04LX and UG01).
    pub fallback_dmin_mm: u32,
}

impl Default for CaptureOptions {
    fn default() -> Self {
        CaptureOptions {
            fallback_dmin_mm: 20,
        }
    }
}

/// `KEY:VALUE` pairs serialised as a JSON object in reply order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OrderedParams(pub Vec<(String, String)>);

impl Serialize for OrderedParams {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut m = s.serialize_map(Some(self.0.len()))?;
        for (k, v) in &self.0 {
            m.serialize_entry(k, v)?;
        }
        m.end()
    }
}

/// One beam the sensor reported as an error code instead of a range.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BeamError {
    /// Index into `ranges_m`.
    pub index: usize,
    /// Sensor step of the (first beam of the) cluster.
    pub step: u32,
    pub code: u32,
    pub meaning: &'static str,
}

/// A decoded scan.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScanJson {
    pub timestamp_ms: u32,
    pub start_step: u16,
    pub end_step: u16,
    pub cluster: u8,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub remaining: Option<u8>,
    pub count: usize,
    /// DMIN that separated codes from ranges (from a PP reply in the capture, or the fallback).
    pub dmin_mm: u32,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angle_min_rad: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angle_increment_rad: Option<f64>,
    /// Metres; `null` where the sensor reported an error code (see `errors`).
    pub ranges_m: Vec<Option<f64>>,
    pub errors: Vec<BeamError>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub intensities: Option<Vec<u32>>,
}

/// One reply of a capture.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplyJson {
    /// Index of the reply in the capture, from 0.
    pub reply: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub command: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub echo: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tag: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub status: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub status_meaning: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub params: Option<OrderedParams>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_ms: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scan: Option<ScanJson>,
    /// Why this reply (or stretch of bytes) could not be decoded.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

impl ReplyJson {
    fn empty(reply: usize) -> Self {
        ReplyJson {
            reply,
            command: None,
            echo: None,
            tag: None,
            status: None,
            status_meaning: None,
            params: None,
            time_ms: None,
            scan: None,
            error: None,
        }
    }

    /// One line of JSON.
    pub fn to_json_line(&self) -> String {
        serde_json::to_string(self)
            .unwrap_or_else(|e| format!("{{\"error\":\"serialising: {e}\"}}"))
    }
}

struct State {
    geometry: Option<Geometry>,
    family: ModelFamily,
    opts: CaptureOptions,
}

/// Decodes every reply in a raw capture. Damaged replies become objects with an
/// `error` field; decoding goes on with the next reply.
pub fn decode_capture(bytes: &[u8], opts: &CaptureOptions) -> Vec<ReplyJson> {
    let mut splitter = FrameSplitter::new(64 * 1024);
    let mut state = State {
        geometry: None,
        family: ModelFamily::Urg04lx,
        opts: *opts,
    };
    let mut out = Vec::new();
    splitter.feed(bytes, |frame| {
        let n = out.len();
        out.push(decode_frame(frame, n, &mut state));
    });
    let pending = splitter.pending();
    if pending.iter().any(|&b| b != b'\n') {
        let mut j = ReplyJson::empty(out.len());
        j.error = Some(format!(
            "capture ends inside a reply: {} bytes without the closing LF LF",
            pending.len()
        ));
        out.push(j);
    }
    let dropped = splitter.stats().discarded_bytes;
    if dropped > 0 {
        let mut j = ReplyJson::empty(out.len());
        j.error = Some(format!(
            "{dropped} bytes dropped: longer than 64 KiB without a reply end"
        ));
        out.push(j);
    }
    out
}

fn decode_frame(frame: &[u8], index: usize, state: &mut State) -> ReplyJson {
    let mut j = ReplyJson::empty(index);
    let reply = match parse_reply(frame) {
        Ok(r) => r,
        Err(e) => {
            j.error = Some(e.to_string());
            return j;
        }
    };
    let cmd = reply.echo.command;
    j.command = Some(cmd.to_string());
    j.echo = Some(String::from_utf8_lossy(reply.echo.line).into_owned());
    j.tag = reply
        .echo
        .tag
        .map(|t| String::from_utf8_lossy(t).into_owned());
    j.status = Some(reply.status.to_string());
    j.status_meaning = Some(reply.status.meaning(cmd));
    let result = match cmd {
        Command::Vv | Command::Pp | Command::Ii if !reply.body().is_empty() => {
            decode_params(&reply, &mut j, state)
        }
        Command::Tm if !reply.body().is_empty() => reply
            .time()
            .map(|t| j.time_ms = Some(t))
            .map_err(|e| e.to_string()),
        c if c.is_scan() && reply.has_scan_data() => {
            decode_scan_json(&reply, state).map(|s| j.scan = Some(s))
        }
        _ => Ok(()),
    };
    if let Err(e) = result {
        j.error = Some(e);
    }
    j
}

fn decode_params(reply: &Reply<'_>, j: &mut ReplyJson, state: &mut State) -> Result<(), String> {
    let pairs = crate::params::collect_params(reply).map_err(|e| e.to_string())?;
    j.params = Some(OrderedParams(pairs));
    if reply.echo.command == Command::Pp && reply.status.is_ok() {
        let spec = SensorSpec::from_reply(reply).map_err(|e| e.to_string())?;
        state.family = spec.family();
        state.geometry = Some(spec.geometry);
    }
    Ok(())
}

fn decode_scan_json(reply: &Reply<'_>, state: &State) -> Result<ScanJson, String> {
    let echo = reply
        .echo
        .scan()
        .map_err(|e| DecodeError::from(e).to_string())?;
    let n = echo.range.value_count();
    let mut ranges = vec![0u32; n];
    let mut intensities = vec![
        0u32;
        if reply.echo.command == Command::Me {
            n
        } else {
            0
        }
    ];
    let h = reply
        .decode_scan(&mut ranges, &mut intensities)
        .map_err(|e| e.to_string())?;
    let dmin = state
        .geometry
        .map_or(state.opts.fallback_dmin_mm, |g| g.dmin_mm);
    let classify = |raw: u32| match state.geometry {
        Some(g) => g.classify(raw),
        None if raw < dmin => Reading::Code(raw),
        None => Reading::Range(raw),
    };
    let cluster = u32::from(echo.range.cluster.max(1));
    let mut errors = Vec::new();
    let ranges_m = ranges
        .iter()
        .enumerate()
        .map(|(index, &raw)| match classify(raw) {
            Reading::Range(mm) | Reading::BeyondMax(mm) => Some(f64::from(mm) / 1000.0),
            Reading::Code(code) => {
                errors.push(BeamError {
                    index,
                    step: u32::from(echo.range.start) + index as u32 * cluster,
                    code,
                    meaning: state.family.error_meaning(code),
                });
                None
            }
        })
        .collect();
    let stream = reply.echo.command.is_stream();
    Ok(ScanJson {
        timestamp_ms: h.timestamp,
        start_step: echo.range.start,
        end_step: echo.range.end,
        cluster: echo.range.cluster,
        remaining: stream.then_some(echo.remaining),
        count: h.count,
        dmin_mm: dmin,
        angle_min_rad: state
            .geometry
            .map(|g| g.step_angle(u32::from(echo.range.start))),
        angle_increment_rad: state.geometry.map(|g| g.step_rad() * f64::from(cluster)),
        ranges_m,
        errors,
        intensities: (reply.echo.command == Command::Me).then_some(intensities),
    })
}
