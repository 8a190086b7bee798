//! Requests: encoding on the host side and parsing on the device side (for emulators).

use crate::error::RequestError;
use crate::status::Command;

/// Longest tag SCIP accepts.
pub const MAX_TAG_LEN: usize = 16;
/// Longest encoded request: `MD` + 13 digits + `;` + 16-char tag + LF.
pub const MAX_REQUEST_LEN: usize = 2 + 13 + 1 + MAX_TAG_LEN + 1;

/// A validated request tag (≤ 16 letters, digits, spaces or `._+@`), echoed by the sensor.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Tag {
    bytes: [u8; MAX_TAG_LEN],
    len: u8,
}

impl Tag {
    pub fn new(tag: &[u8]) -> Result<Tag, RequestError> {
        if tag.len() > MAX_TAG_LEN {
            return Err(RequestError::TagTooLong { len: tag.len() });
        }
        if let Some(&byte) = tag.iter().find(|&&b| !is_tag_char(b)) {
            return Err(RequestError::TagChar { byte });
        }
        let mut bytes = [0u8; MAX_TAG_LEN];
        bytes[..tag.len()].copy_from_slice(tag);
        Ok(Tag {
            bytes,
            len: tag.len() as u8,
        })
    }

    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len).min(MAX_TAG_LEN)]
    }
}

impl std::fmt::Debug for Tag {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Tag({:?})", String::from_utf8_lossy(self.as_bytes()))
    }
}

/// Characters the spec allows in a tag.
pub fn is_tag_char(b: u8) -> bool {
    b.is_ascii_alphanumeric() || matches!(b, b' ' | b'.' | b'_' | b'+' | b'@')
}

/// `TM` control codes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeMode {
    /// TM0: enter time-adjust mode.
    Enter = 0,
    /// TM1: read the sensor time.
    Read = 1,
    /// TM2: leave time-adjust mode.
    Leave = 2,
}

/// The part of the sweep to measure, as GD/GS/MD/MS/ME ask for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepRange {
    pub start: u16,
    pub end: u16,
    /// Steps merged into one value (0 and 1 both mean none).
    pub cluster: u8,
}

impl StepRange {
    /// Values a reply to this range carries: ceil((end − start + 1) / cluster), 0 if end < start.
    pub fn value_count(&self) -> usize {
        if self.end < self.start {
            return 0;
        }
        let steps = usize::from(self.end - self.start) + 1;
        steps.div_ceil(usize::from(self.cluster.max(1)))
    }
}

/// One SCIP request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    Scip20,
    Vv,
    Pp,
    Ii,
    Bm,
    Qt,
    Rs,
    Tm(TimeMode),
    /// `SS`: new bit rate in bit/s (6 digits).
    Ss(u32),
    /// `GD` (3-char) or `GS` (2-char) single scan.
    Get {
        three_char: bool,
        range: StepRange,
    },
    /// `MD`/`MS`/`ME` streaming: `interval` scans skipped between transmissions, `count`
    /// scans (0 = until QT).
    Stream {
        command: Command,
        range: StepRange,
        interval: u8,
        count: u8,
    },
}

/// An encoded request in a fixed buffer (no allocation).
#[derive(Clone, Copy)]
pub struct EncodedRequest {
    buf: [u8; MAX_REQUEST_LEN],
    len: usize,
}

impl EncodedRequest {
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len.min(MAX_REQUEST_LEN)]
    }

    /// The line without its LF: what the sensor echoes.
    pub fn echo(&self) -> &[u8] {
        let b = self.as_bytes();
        b.strip_suffix(b"\n").unwrap_or(b)
    }

    fn push(&mut self, bytes: &[u8]) {
        let end = (self.len + bytes.len()).min(MAX_REQUEST_LEN);
        let n = end - self.len;
        self.buf[self.len..end].copy_from_slice(&bytes[..n]);
        self.len = end;
    }

    fn push_decimal(
        &mut self,
        field: &'static str,
        value: u32,
        digits: usize,
    ) -> Result<(), RequestError> {
        if digits < 10 && value >= 10u32.pow(digits as u32) {
            return Err(RequestError::FieldTooLarge {
                field,
                value,
                digits,
            });
        }
        let mut tmp = [b'0'; 10];
        let mut v = value;
        for slot in tmp[..digits].iter_mut().rev() {
            *slot = b'0' + (v % 10) as u8;
            v /= 10;
        }
        self.push(&tmp[..digits]);
        Ok(())
    }
}

impl Request {
    pub fn command(&self) -> Command {
        match self {
            Request::Scip20 => Command::Scip20,
            Request::Vv => Command::Vv,
            Request::Pp => Command::Pp,
            Request::Ii => Command::Ii,
            Request::Bm => Command::Bm,
            Request::Qt => Command::Qt,
            Request::Rs => Command::Rs,
            Request::Tm(_) => Command::Tm,
            Request::Ss(_) => Command::Ss,
            Request::Get {
                three_char: true, ..
            } => Command::Gd,
            Request::Get {
                three_char: false, ..
            } => Command::Gs,
            Request::Stream { command, .. } => *command,
        }
    }

    /// Encodes the request line (with optional tag) terminated by LF.
    pub fn encode(&self, tag: Option<&Tag>) -> Result<EncodedRequest, RequestError> {
        let mut out = EncodedRequest {
            buf: [0; MAX_REQUEST_LEN],
            len: 0,
        };
        match self {
            Request::Scip20 => out.push(b"SCIP2.0"),
            Request::Vv => out.push(b"VV"),
            Request::Pp => out.push(b"PP"),
            Request::Ii => out.push(b"II"),
            Request::Bm => out.push(b"BM"),
            Request::Qt => out.push(b"QT"),
            Request::Rs => out.push(b"RS"),
            Request::Tm(mode) => {
                out.push(b"TM");
                out.push(&[b'0' + *mode as u8]);
            }
            Request::Ss(baud) => {
                out.push(b"SS");
                out.push_decimal("bit rate", *baud, 6)?;
            }
            Request::Get { three_char, range } => {
                out.push(if *three_char { b"GD" } else { b"GS" });
                push_range(&mut out, range)?;
            }
            Request::Stream {
                command,
                range,
                interval,
                count,
            } => {
                let name: &[u8] = match command {
                    Command::Ms => b"MS",
                    Command::Me => b"ME",
                    _ => b"MD",
                };
                out.push(name);
                push_range(&mut out, range)?;
                out.push_decimal("interval", u32::from(*interval), 1)?;
                out.push_decimal("count", u32::from(*count), 2)?;
            }
        }
        if let Some(tag) = tag {
            out.push(b";");
            out.push(tag.as_bytes());
        }
        out.push(b"\n");
        Ok(out)
    }
}

fn push_range(out: &mut EncodedRequest, r: &StepRange) -> Result<(), RequestError> {
    out.push_decimal("start step", u32::from(r.start), 4)?;
    out.push_decimal("end step", u32::from(r.end), 4)?;
    out.push_decimal("cluster", u32::from(r.cluster), 2)
}

/// Why a device rejects a request line, with the status it answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rejection {
    pub command: Command,
    /// The two status characters the device sends back.
    pub status: [u8; 2],
}

/// A request line as a device reads it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParsedRequest<'a> {
    pub request: Request,
    /// The tag as sent (already validated), without the `;`.
    pub tag: Option<&'a [u8]>,
}

/// Parses one request line (without its terminator) the way a SCIP 2.0 device does,
/// returning the status it would answer when it rejects it. Range limits that depend
/// on the model (end step beyond AMAX, …) are for the device to check.
pub fn parse_request(line: &[u8]) -> Result<ParsedRequest<'_>, Rejection> {
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    let Some(command) = Command::from_line(line) else {
        return Err(Rejection {
            command: Command::Other([line.first().copied().unwrap_or(0), 0]),
            status: *b"0E",
        });
    };
    let rest = line.get(command.text_len()..).unwrap_or(&[]);
    let (params, tag) = match rest.iter().position(|&b| b == b';') {
        Some(i) => (&rest[..i], Some(&rest[i + 1..])),
        None => (rest, None),
    };
    let reject = |status: &[u8; 2]| Rejection {
        command,
        status: *status,
    };
    if let Some(t) = tag {
        if t.len() > MAX_TAG_LEN {
            return Err(reject(b"0G"));
        }
        if !t.iter().all(|&b| is_tag_char(b)) {
            return Err(reject(b"0H"));
        }
    }
    let no_params = |req: Request| {
        if params.is_empty() {
            Ok(req)
        } else {
            Err(reject(b"0C"))
        }
    };
    let request = match command {
        Command::Scip20 => no_params(Request::Scip20)?,
        Command::Vv => no_params(Request::Vv)?,
        Command::Pp => no_params(Request::Pp)?,
        Command::Ii => no_params(Request::Ii)?,
        Command::Bm => no_params(Request::Bm)?,
        Command::Qt => no_params(Request::Qt)?,
        Command::Rs => no_params(Request::Rs)?,
        Command::Tm => match params {
            [b'0'] => Request::Tm(TimeMode::Enter),
            [b'1'] => Request::Tm(TimeMode::Read),
            [b'2'] => Request::Tm(TimeMode::Leave),
            [_] => return Err(reject(b"01")),
            _ => return Err(reject(b"0C")),
        },
        Command::Ss => {
            if params.len() != 6 {
                return Err(reject(b"0C"));
            }
            Request::Ss(decimal(params).ok_or(reject(b"01"))?)
        }
        Command::Gd | Command::Gs => {
            if params.len() != 10 {
                return Err(reject(b"0C"));
            }
            Request::Get {
                three_char: command == Command::Gd,
                range: parse_range(params).map_err(|s| reject(&s))?,
            }
        }
        Command::Md | Command::Ms | Command::Me => {
            if params.len() != 13 {
                return Err(reject(b"0C"));
            }
            let range = parse_range(params).map_err(|s| reject(&s))?;
            let interval = decimal(&params[10..11]).ok_or(reject(b"06"))? as u8;
            let count = decimal(&params[11..13]).ok_or(reject(b"07"))? as u8;
            Request::Stream {
                command,
                range,
                interval,
                count,
            }
        }
        Command::Other(_) => return Err(reject(b"0E")),
    };
    Ok(ParsedRequest { request, tag })
}

/// start(4) end(4) cluster(2) with the spec's per-field statuses 01/02/03.
fn parse_range(p: &[u8]) -> Result<StepRange, [u8; 2]> {
    let start = decimal(p.get(0..4).unwrap_or(&[])).ok_or(*b"01")? as u16;
    let end = decimal(p.get(4..8).unwrap_or(&[])).ok_or(*b"02")? as u16;
    let cluster = decimal(p.get(8..10).unwrap_or(&[])).ok_or(*b"03")? as u8;
    Ok(StepRange {
        start,
        end,
        cluster,
    })
}

/// Fixed-width unsigned decimal; `None` if empty or any byte is not a digit.
pub(crate) fn decimal(digits: &[u8]) -> Option<u32> {
    if digits.is_empty() || digits.len() > 9 {
        return None;
    }
    digits.iter().try_fold(0u32, |acc, &b| {
        b.is_ascii_digit().then(|| acc * 10 + u32::from(b - b'0'))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn md(start: u16, end: u16, cluster: u8, interval: u8, count: u8) -> Request {
        Request::Stream {
            command: Command::Md,
            range: StepRange {
                start,
                end,
                cluster,
            },
            interval,
            count,
        }
    }

    #[test]
    fn md_full_04lx_sweep_encodes_like_the_spec() {
        let r = md(44, 725, 1, 0, 0).encode(None).unwrap();
        assert_eq!(r.as_bytes(), b"MD0044072501000\n");
        assert_eq!(r.echo(), b"MD0044072501000");
    }

    #[test]
    fn tagged_requests_append_semicolon_and_tag() {
        let tag = Tag::new(b"sync.1").unwrap();
        assert_eq!(
            Request::Tm(TimeMode::Read)
                .encode(Some(&tag))
                .unwrap()
                .as_bytes(),
            b"TM1;sync.1\n"
        );
        assert_eq!(
            Request::Ss(115_200).encode(None).unwrap().as_bytes(),
            b"SS115200\n"
        );
        assert_eq!(
            Request::Scip20.encode(None).unwrap().as_bytes(),
            b"SCIP2.0\n"
        );
        let gd = Request::Get {
            three_char: true,
            range: StepRange {
                start: 44,
                end: 725,
                cluster: 1,
            },
        };
        assert_eq!(gd.encode(None).unwrap().as_bytes(), b"GD0044072501\n");
    }

    #[test]
    fn invalid_tags_and_fields_are_refused_before_sending() {
        assert_eq!(
            Tag::new(b"0123456789abcdefg"),
            Err(RequestError::TagTooLong { len: 17 })
        );
        assert_eq!(Tag::new(b"a;b"), Err(RequestError::TagChar { byte: b';' }));
        assert_eq!(
            md(44, 10_000, 1, 0, 0).encode(None).err(),
            Some(RequestError::FieldTooLarge {
                field: "end step",
                value: 10_000,
                digits: 4
            })
        );
        assert_eq!(
            md(44, 725, 1, 0, 100).encode(None).err(),
            Some(RequestError::FieldTooLarge {
                field: "count",
                value: 100,
                digits: 2
            })
        );
    }

    #[test]
    fn device_side_parse_round_trips_and_rejects_with_spec_statuses() {
        let req = md(44, 725, 1, 2, 5);
        let enc = req.encode(Some(&Tag::new(b"x").unwrap())).unwrap();
        let parsed = parse_request(enc.echo()).unwrap();
        assert_eq!(parsed.request, req);
        assert_eq!(parsed.tag, Some(&b"x"[..]));
        assert_eq!(
            parse_request(b"MD00x4072501000").unwrap_err().status,
            *b"01"
        );
        assert_eq!(
            parse_request(b"MD0044072501x00").unwrap_err().status,
            *b"06"
        );
        assert_eq!(
            parse_request(b"MD00440725010x0").unwrap_err().status,
            *b"07"
        );
        assert_eq!(parse_request(b"GD004407250").unwrap_err().status, *b"0C");
        assert_eq!(parse_request(b"TM3").unwrap_err().status, *b"01");
        assert_eq!(
            parse_request(b"QT;0123456789abcdefgh").unwrap_err().status,
            *b"0G"
        );
        assert_eq!(parse_request(b"QT;a-b").unwrap_err().status, *b"0H");
        assert_eq!(parse_request(b"ZZ").unwrap_err().status, *b"0E");
        assert_eq!(parse_request(b"SS11520x").unwrap_err().status, *b"01");
        assert_eq!(
            parse_request(b"SCIP2.0\r").unwrap().request,
            Request::Scip20
        );
    }

    #[test]
    fn value_count_rounds_clusters_up() {
        assert_eq!(
            StepRange {
                start: 44,
                end: 725,
                cluster: 1
            }
            .value_count(),
            682
        );
        assert_eq!(
            StepRange {
                start: 44,
                end: 725,
                cluster: 0
            }
            .value_count(),
            682
        );
        assert_eq!(
            StepRange {
                start: 44,
                end: 725,
                cluster: 3
            }
            .value_count(),
            228
        );
        assert_eq!(
            StepRange {
                start: 10,
                end: 5,
                cluster: 1
            }
            .value_count(),
            0
        );
    }
}
