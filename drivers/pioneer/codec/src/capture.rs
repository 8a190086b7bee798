//! A capture in, one JSON object per packet out (`smokenav arcos decode`).
//!
//! Two input forms:
//! - **hex**: text lines of hex bytes (`fa fb 03 00 00 00`, `FAFB030000`,
//!   `0xfa 0xfb …`). The bytes are the trailing run of hex tokens on a line,
//!   so annotated captures like `amrisim_capture.txt`
//!   (`RX type 0x32 t=0.20  ok=True len=89 fa fb 56 …`) work as they are. A
//!   line starting with `TX`/`>` is host→robot, `RX`/`<` robot→host. A packet
//!   may span lines; each direction has its own framer.
//! - **raw**: the bytes as they crossed the wire (one direction).

use crate::command::{command_name, decode_command};
use crate::framer::{FrameError, Framer, FramerStats};
use crate::params::{RobotParams, params_for};
use crate::sip::Sip;
use crate::wire::PacketBuf;
use crate::{RobotPacket, decode_robot_packet, hex};
use serde::Serialize;
use serde_json::{Value, json};

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum Direction {
    /// Host to robot: commands.
    #[cfg_attr(feature = "clap", value(name = "host"))]
    ToRobot,
    /// Robot to host: SYNC replies, SIPs, CONFIG.
    #[cfg_attr(feature = "clap", value(name = "robot"))]
    FromRobot,
    /// Not marked: guessed per packet from its type and length.
    #[default]
    #[cfg_attr(feature = "clap", value(name = "guess"))]
    Unknown,
}

impl Direction {
    fn slot(self) -> usize {
        match self {
            Direction::ToRobot => 0,
            Direction::FromRobot => 1,
            Direction::Unknown => 2,
        }
    }
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum CaptureFormat {
    /// Raw if the input contains `FA FB` as bytes, else hex text.
    #[default]
    Auto,
    Hex,
    Raw,
}

/// Totals over a whole capture.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct CaptureSummary {
    /// Objects emitted (packets and framing errors).
    pub objects: u64,
    pub framing: FramerStats,
}

/// The direction marker and bytes of one hex line (`None` direction: unmarked).
pub fn parse_hex_line(line: &str) -> (Option<Direction>, Vec<u8>) {
    let tokens: Vec<&str> = line
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
        .collect();
    let dir = match tokens.first().map(|t| t.to_ascii_lowercase()) {
        Some(t) if t == "tx" || t == ">" || t == "->" => Some(Direction::ToRobot),
        Some(t) if t == "rx" || t == "<" || t == "<-" => Some(Direction::FromRobot),
        _ => None,
    };
    let mut start = tokens.len();
    while start > 0
        && tokens
            .get(start - 1)
            .is_some_and(|t| hex_token(t).is_some())
    {
        start -= 1;
    }
    let bytes = tokens
        .get(start..)
        .unwrap_or(&[])
        .iter()
        .filter_map(|t| hex_token(t))
        .flatten()
        .collect();
    (dir, bytes)
}

/// `fa`, `FAFB03`, `0xfa` → bytes; anything else → None.
fn hex_token(t: &str) -> Option<Vec<u8>> {
    let digits = t
        .strip_prefix("0x")
        .or_else(|| t.strip_prefix("0X"))
        .unwrap_or(t);
    if t.len() != digits.len() && digits.len() != 2 {
        return None;
    }
    if digits.is_empty()
        || !digits.len().is_multiple_of(2)
        || !digits.bytes().all(|b| b.is_ascii_hexdigit())
    {
        return None;
    }
    (0..digits.len())
        .step_by(2)
        .map(|i| {
            digits
                .get(i..i + 2)
                .and_then(|p| u8::from_str_radix(p, 16).ok())
        })
        .collect()
}

/// Stateful decoder: frames per direction, remembers the subclass from a
/// SYNC2 reply to add SI conversions to later SIPs.
pub struct CaptureDecoder {
    framers: [Framer; 3],
    n: u64,
    params: Option<&'static RobotParams>,
    default_dir: Direction,
    summary: CaptureSummary,
}

impl CaptureDecoder {
    /// `default_dir` applies to bytes without a direction marker.
    pub fn new(default_dir: Direction) -> Self {
        Self {
            framers: [Framer::new(), Framer::new(), Framer::new()],
            n: 0,
            params: None,
            default_dir,
            summary: CaptureSummary::default(),
        }
    }

    /// Use these factors for SI conversions until a SYNC2 reply names others.
    pub fn set_subclass(&mut self, subclass: &str) -> Result<(), crate::UnknownSubclass> {
        self.params = Some(params_for(subclass)?);
        Ok(())
    }

    pub fn summary(&self) -> CaptureSummary {
        let mut s = self.summary;
        for f in &self.framers {
            let st = f.stats();
            s.framing.packets += st.packets;
            s.framing.checksum_errors += st.checksum_errors;
            s.framing.bad_counts += st.bad_counts;
            s.framing.discarded_bytes += st.discarded_bytes;
        }
        s
    }

    /// Feeds bytes seen travelling in `dir` (`None`: the default direction).
    pub fn feed(
        &mut self,
        dir: Option<Direction>,
        line: Option<usize>,
        bytes: &[u8],
        emit: &mut impl FnMut(Value),
    ) {
        let dir = dir.unwrap_or(self.default_dir);
        let mut frames: Vec<Result<Vec<u8>, FrameError>> = Vec::new();
        if let Some(f) = self.framers.get_mut(dir.slot()) {
            f.feed(bytes, |r| frames.push(r.map(<[u8]>::to_vec)));
        }
        for r in frames {
            let v = match r {
                Ok(payload) => self.describe(dir, line, &payload),
                Err(e) => {
                    let mut v = json!({ "n": self.n, "dir": dir, "error": e.to_string() });
                    if let Some(l) = line {
                        v["line"] = json!(l);
                    }
                    v
                }
            };
            self.n += 1;
            self.summary.objects += 1;
            emit(v);
        }
    }

    fn describe(&mut self, dir: Direction, line: Option<usize>, payload: &[u8]) -> Value {
        let mut packet = PacketBuf::new();
        let wire = match packet.set_payload(payload) {
            Ok(()) => hex(packet.as_bytes()),
            Err(_) => String::new(),
        };
        let ptype = payload.first().copied().unwrap_or(0);
        let mut v = json!({
            "n": self.n,
            "dir": dir,
            "type": format!("0x{ptype:02x}"),
            "len": payload.len() + 5,
            "hex": wire,
        });
        if let Some(l) = line {
            v["line"] = json!(l);
        }
        let from_robot = match dir {
            Direction::FromRobot => true,
            Direction::ToRobot => false,
            Direction::Unknown => looks_like_robot_packet(payload),
        };
        let body = if from_robot {
            self.robot_packet(payload)
        } else {
            command_json(payload)
        };
        if let (Value::Object(o), Value::Object(b)) = (&mut v, body) {
            o.extend(b);
        }
        v
    }

    fn robot_packet(&mut self, payload: &[u8]) -> Value {
        match decode_robot_packet(payload) {
            Ok(RobotPacket::SyncEcho(seq)) => json!({ "kind": "sync_echo", "seq": seq }),
            Ok(RobotPacket::Ident(id)) => {
                let known = params_for(&id.subclass).ok();
                if known.is_some() {
                    self.params = known;
                }
                json!({ "kind": "sync2", "ident": id, "params_known": known.is_some() })
            }
            Ok(RobotPacket::Sip(s)) => {
                json!({ "kind": "sip", "sip": s, "derived": sip_derived(&s, self.params) })
            }
            Ok(RobotPacket::Config(c)) => json!({ "kind": "config", "config": c }),
            Ok(RobotPacket::Other { .. }) => json!({ "kind": "other" }),
            Err(e) => json!({ "kind": "undecodable", "error": e.to_string() }),
        }
    }
}

fn command_json(payload: &[u8]) -> Value {
    match decode_command(payload) {
        Ok(c) => {
            json!({ "kind": "command", "cmd": c.cmd, "name": command_name(c.cmd), "arg": c.arg })
        }
        Err(e) => json!({ "kind": "undecodable", "error": e.to_string() }),
    }
}

/// Without a direction marker: SIPs, SYNC2 replies and CONFIG replies are
/// recognisable by length; everything else reads as a command.
fn looks_like_robot_packet(payload: &[u8]) -> bool {
    match payload {
        [crate::sip::SIP_STOPPED | crate::sip::SIP_MOVING, rest @ ..] => rest.len() >= 19,
        [2, rest @ ..] => rest.contains(&0) && rest.len() >= 3,
        [crate::config::CONFIG_PACKET, rest @ ..] => rest.len() >= 20,
        _ => false,
    }
}

fn sip_derived(s: &Sip, params: Option<&RobotParams>) -> Value {
    let mut v = json!({
        "x15": s.x_pos(),
        "y15": s.y_pos(),
        "battery_v": s.battery_volts(),
        "motors_enabled": s.motors_enabled(),
        "sonar_arrays": s.sonar_arrays(),
        "estop": s.estop(),
        "left_stall": s.left_stall(),
        "right_stall": s.right_stall(),
        "front_bumpers": s.front_bumpers(),
        "rear_bumpers": s.rear_bumpers(),
        "compass_deg": s.compass_deg(),
        "temperature_c": s.temperature_c(),
        "rot_vel_dps": s.rot_vel.map(|r| f64::from(r) / 10.0),
    });
    if let Some(p) = params {
        v["subclass"] = json!(p.subclass);
        v["th_deg"] = json!((f64::from(s.th) * p.angle_conv).to_degrees());
        v["left_vel_mm_s"] = json!(f64::from(s.left_vel) * p.vel_conv);
        v["right_vel_mm_s"] = json!(f64::from(s.right_vel) * p.vel_conv);
        let sonar_mm: Vec<Value> = s
            .sonars
            .as_slice()
            .iter()
            .map(|r| json!([r.index, f64::from(r.range) * p.range_conv]))
            .collect();
        v["sonar_mm"] = Value::Array(sonar_mm);
    }
    v
}

/// Decodes a whole capture, calling `emit` with one JSON object per packet or
/// framing error.
pub fn decode_capture(
    input: &[u8],
    format: CaptureFormat,
    default_dir: Direction,
    subclass: Option<&str>,
    mut emit: impl FnMut(Value),
) -> Result<CaptureSummary, crate::UnknownSubclass> {
    let mut d = CaptureDecoder::new(default_dir);
    if let Some(s) = subclass {
        d.set_subclass(s)?;
    }
    let raw = match format {
        CaptureFormat::Raw => true,
        CaptureFormat::Hex => false,
        CaptureFormat::Auto => input.windows(2).any(|w| w == crate::wire::HEADER),
    };
    if raw {
        d.feed(None, None, input, &mut emit);
    } else {
        let text = String::from_utf8_lossy(input);
        for (i, line) in text.lines().enumerate() {
            if line.trim_start().starts_with('#') {
                continue;
            }
            let (dir, bytes) = parse_hex_line(line);
            if !bytes.is_empty() {
                d.feed(dir, Some(i + 1), &bytes, &mut emit);
            }
        }
    }
    Ok(d.summary())
}

#[cfg(test)]
mod tests;
