//! Reply frames: echo · status · payload lines · empty line.

use crate::chars::{self, checksum};
use crate::error::{DecodeError, EchoError};
use crate::request::{StepRange, decimal};
use crate::status::{Command, Status};

/// Longest data line: 64 data characters + checksum.
pub const MAX_DATA_LINE: usize = 65;

/// The echo line of a reply: the request as the sensor read it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Echo<'a> {
    /// The whole line, tag included, without LF.
    pub line: &'a [u8],
    pub command: Command,
    /// Parameter digits between the command and the tag.
    pub params: &'a [u8],
    /// The tag without its `;`.
    pub tag: Option<&'a [u8]>,
}

/// What GD/GS/MD/MS/ME echoes say about the data that follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanEcho {
    pub range: StepRange,
    /// MD/MS/ME: scans skipped between transmissions.
    pub interval: u8,
    /// MD/MS/ME: the remaining-scans field (count in the ack, countdown in data echoes).
    pub remaining: u8,
}

impl<'a> Echo<'a> {
    pub fn parse(line: &'a [u8]) -> Result<Echo<'a>, EchoError> {
        let not_a_command = || EchoError::NotACommand {
            len: line.len(),
            first: line.first().copied().unwrap_or(0),
        };
        let command = Command::from_line(line).ok_or_else(not_a_command)?;
        if let Command::Other([a, b]) = command
            && !(a.is_ascii_uppercase() && b.is_ascii_uppercase())
        {
            return Err(not_a_command());
        }
        let rest = line.get(command.text_len()..).unwrap_or(&[]);
        let (params, tag) = match rest.iter().position(|&b| b == b';') {
            Some(i) => (&rest[..i], rest.get(i + 1..)),
            None => (rest, None),
        };
        Ok(Echo {
            line,
            command,
            params,
            tag,
        })
    }

    /// The start/end/cluster (and interval/remaining for streams) of a scan echo.
    pub fn scan(&self) -> Result<ScanEcho, EchoError> {
        let command = self.command;
        let expected = match command {
            Command::Gd | Command::Gs => 10,
            Command::Md | Command::Ms | Command::Me => 13,
            _ => {
                return Err(EchoError::ParamLength {
                    command,
                    expected: 10,
                    found: self.params.len(),
                });
            }
        };
        let p = self.params;
        if p.len() != expected {
            return Err(EchoError::ParamLength {
                command,
                expected,
                found: p.len(),
            });
        }
        let field = |range: std::ops::Range<usize>, name: &'static str| {
            p.get(range).and_then(decimal).ok_or(EchoError::NotNumeric {
                command,
                field: name,
            })
        };
        let start = field(0..4, "start")? as u16;
        let end = field(4..8, "end")? as u16;
        let cluster = field(8..10, "cluster")? as u8;
        if end < start {
            return Err(EchoError::EndBeforeStart {
                command,
                start,
                end,
            });
        }
        let (interval, remaining) = if expected == 13 {
            (
                field(10..11, "interval")? as u8,
                field(11..13, "count")? as u8,
            )
        } else {
            (0, 0)
        };
        Ok(ScanEcho {
            range: StepRange {
                start,
                end,
                cluster,
            },
            interval,
            remaining,
        })
    }

    /// True if `other` is a data echo of the same stream request: the first 13
    /// characters (command + start/end/cluster/interval) and the tag agree; the
    /// remaining-scans field counts down and is ignored.
    pub fn same_stream(&self, other: &Echo<'_>) -> bool {
        fn head(line: &[u8]) -> &[u8] {
            line.get(..13).unwrap_or(line)
        }
        head(self.line) == head(other.line) && self.tag == other.tag
    }
}

/// One parsed reply frame, borrowing the bytes it came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reply<'a> {
    pub echo: Echo<'a>,
    pub status: Status,
    /// Payload lines after the status, each LF-terminated (empty for status-only replies).
    body: &'a [u8],
}

/// Timestamp and layout of a decoded scan; the values went to the caller's buffers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanHeader {
    pub command: Command,
    pub echo: ScanEcho,
    /// Sensor time at the scan's start (rear of the sweep), ms, 24-bit wrapping.
    pub timestamp: u32,
    /// Values written to the range buffer (and intensity buffer for ME).
    pub count: usize,
}

/// Strips one trailing CR (replies over some links carry CR LF).
#[inline]
fn strip_cr(line: &[u8]) -> &[u8] {
    line.strip_suffix(b"\r").unwrap_or(line)
}

/// Splits `bytes` at the first LF: (line without LF, rest after LF).
#[inline]
fn split_line(bytes: &[u8]) -> (&[u8], &[u8]) {
    match bytes.iter().position(|&b| b == b'\n') {
        Some(i) => (&bytes[..i], &bytes[i + 1..]),
        None => (bytes, &[]),
    }
}

/// Parses one reply frame ending in LF LF (as [`crate::FrameSplitter`] yields them).
/// Leading LFs (answers to empty requests) are skipped. The status checksum is
/// verified here; payload checksums when the payload is read.
pub fn parse_reply(frame: &[u8]) -> Result<Reply<'_>, DecodeError> {
    let start = frame
        .iter()
        .position(|&b| b != b'\n')
        .ok_or(DecodeError::Empty)?;
    let frame = &frame[start..];
    let Some(content) = frame.strip_suffix(b"\n\n") else {
        return Err(DecodeError::Unterminated { len: frame.len() });
    };
    // `content` holds lines separated by LF, the last without its LF.
    let (echo_line, rest) = split_line(content);
    if rest.is_empty() && !content.contains(&b'\n') {
        return Err(DecodeError::MissingStatus);
    }
    let echo = Echo::parse(strip_cr(echo_line))?;
    let (status_line, body) = split_line(rest);
    let status = parse_status(strip_cr(status_line))?;
    // Re-attach the LF the strip removed so every body line is LF-terminated.
    let body = if body.is_empty() {
        body
    } else {
        &frame[frame.len() - 1 - body.len() - 1..frame.len() - 1]
    };
    Ok(Reply { echo, status, body })
}

fn parse_status(line: &[u8]) -> Result<Status, DecodeError> {
    match *line {
        [a, b, sum] => {
            let expected = checksum(&[a, b]);
            if sum != expected {
                return Err(DecodeError::Checksum {
                    line: 2,
                    expected,
                    found: sum,
                });
            }
            Ok(Status::Code([a, b]))
        }
        [bare] => Ok(Status::Bare(bare)),
        _ => Err(DecodeError::BadStatus { len: line.len() }),
    }
}

/// One `KEY:VALUE` parameter line of a VV/PP/II reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Param<'a> {
    pub key: &'a [u8],
    pub value: &'a [u8],
}

impl Param<'_> {
    pub fn key_str(&self) -> std::borrow::Cow<'_, str> {
        String::from_utf8_lossy(self.key)
    }

    pub fn value_str(&self) -> std::borrow::Cow<'_, str> {
        String::from_utf8_lossy(self.value)
    }
}

/// Parses `KEY:VALUE;c` (checksum over `KEY:VALUE`), parsing from the right because the
/// value may itself contain `;`. A line `KEY:VALUEc` without `;` is accepted too.
/// `line_no` only labels errors.
pub fn parse_param_line(line: &[u8], line_no: usize) -> Result<Param<'_>, DecodeError> {
    let line = strip_cr(line);
    let Some((&sum, before)) = line.split_last() else {
        return Err(DecodeError::EmptyLine { line: line_no });
    };
    let payload = match before.split_last() {
        Some((b';', payload)) if checksum(payload) == sum => payload,
        _ if checksum(before) == sum => before.strip_suffix(b";").unwrap_or(before),
        Some((b';', payload)) => {
            return Err(DecodeError::Checksum {
                line: line_no,
                expected: checksum(payload),
                found: sum,
            });
        }
        _ => {
            return Err(DecodeError::Checksum {
                line: line_no,
                expected: checksum(before),
                found: sum,
            });
        }
    };
    let colon = payload
        .iter()
        .position(|&b| b == b':')
        .ok_or(DecodeError::ParamNoColon { line: line_no })?;
    Ok(Param {
        key: &payload[..colon],
        value: &payload[colon + 1..],
    })
}

/// Iterator over the parameter lines of a reply.
#[derive(Debug, Clone)]
pub struct Params<'a> {
    rest: &'a [u8],
    line_no: usize,
}

impl<'a> Iterator for Params<'a> {
    type Item = Result<Param<'a>, DecodeError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.rest.is_empty() {
            return None;
        }
        let (line, rest) = split_line(self.rest);
        self.rest = rest;
        self.line_no += 1;
        Some(parse_param_line(line, self.line_no))
    }
}

impl<'a> Reply<'a> {
    /// Payload lines after the status line, raw.
    pub fn body(&self) -> &'a [u8] {
        self.body
    }

    /// The parameter lines of a VV/PP/II reply (lines 3…).
    pub fn params(&self) -> Params<'a> {
        Params {
            rest: self.body,
            line_no: 2,
        }
    }

    /// True for replies that carry ranges: GD/GS with `00`, MD/MS/ME with `99`.
    pub fn has_scan_data(&self) -> bool {
        match self.echo.command {
            Command::Gd | Command::Gs => self.status.is_ok() && !self.body.is_empty(),
            c if c.is_stream() => self.status.is_scan_data(),
            _ => false,
        }
    }

    /// The 4-character time of a TM1 reply, ms.
    pub fn time(&self) -> Result<u32, DecodeError> {
        let (line, _) = split_line(self.body);
        decode_time_line(strip_cr(line), 3).map_err(|e| match e {
            DecodeError::BadTimestamp { len } => DecodeError::BadTime {
                command: self.echo.command,
                len,
            },
            e => e,
        })
    }

    /// Decodes the ranges (and ME intensities) of a scan reply into the caller's
    /// buffers without allocating. Every line checksum is verified and values split
    /// across lines are joined. `intensities` may be empty unless the reply is ME.
    pub fn decode_scan(
        &self,
        ranges: &mut [u32],
        intensities: &mut [u32],
    ) -> Result<ScanHeader, DecodeError> {
        let command = self.echo.command;
        if !self.has_scan_data() {
            return Err(DecodeError::NotScanData {
                command,
                status: self.status,
            });
        }
        let echo = self.echo.scan()?;
        let count = echo.range.value_count();
        let with_intensity = command == Command::Me;
        let capacity = if with_intensity {
            ranges.len().min(intensities.len())
        } else {
            ranges.len()
        };
        if count > capacity {
            return Err(DecodeError::BufferTooSmall {
                needed: count,
                capacity,
            });
        }
        let (ts_line, mut rest) = split_line(self.body);
        let timestamp = decode_time_line(strip_cr(ts_line), 3)?;

        let width = command.range_width();
        let mut acc = 0u32;
        let mut chars_in_acc = 0usize;
        let mut index = 0usize;
        let mut intensity_next = false;
        let mut line_no = 3;
        while !rest.is_empty() {
            line_no += 1;
            let (line, tail) = split_line(rest);
            rest = tail;
            let line = strip_cr(line);
            let Some((&sum, data)) = line.split_last() else {
                return Err(DecodeError::EmptyLine { line: line_no });
            };
            if line.len() > MAX_DATA_LINE {
                return Err(DecodeError::LineTooLong {
                    line: line_no,
                    len: line.len(),
                    max: MAX_DATA_LINE,
                });
            }
            let mut total = 0u32;
            for (offset, &c) in data.iter().enumerate() {
                total += u32::from(c);
                let Some(d) = chars::char_value(c) else {
                    return Err(DecodeError::BadChar {
                        line: line_no,
                        offset,
                        byte: c,
                    });
                };
                acc = (acc << 6) | d;
                chars_in_acc += 1;
                if chars_in_acc == width {
                    if index >= count {
                        return Err(DecodeError::CountMismatch {
                            expected: count,
                            got: index + 1,
                        });
                    }
                    if intensity_next {
                        intensities[index] = acc;
                        index += 1;
                        intensity_next = false;
                    } else {
                        ranges[index] = acc;
                        if with_intensity {
                            intensity_next = true;
                        } else {
                            index += 1;
                        }
                    }
                    acc = 0;
                    chars_in_acc = 0;
                }
            }
            let expected = (total & 0x3F) as u8 + chars::CHAR_BASE;
            if sum != expected {
                return Err(DecodeError::Checksum {
                    line: line_no,
                    expected,
                    found: sum,
                });
            }
        }
        if chars_in_acc != 0 || intensity_next {
            return Err(DecodeError::PartialValue {
                chars: chars_in_acc + if intensity_next { width } else { 0 },
            });
        }
        if index != count {
            return Err(DecodeError::CountMismatch {
                expected: count,
                got: index,
            });
        }
        Ok(ScanHeader {
            command,
            echo,
            timestamp,
            count,
        })
    }
}

/// A 4-character time + checksum line.
fn decode_time_line(line: &[u8], line_no: usize) -> Result<u32, DecodeError> {
    let [a, b, c, d, sum] = *line else {
        return Err(DecodeError::BadTimestamp { len: line.len() });
    };
    let chars = [a, b, c, d];
    let expected = checksum(&chars);
    if sum != expected {
        return Err(DecodeError::Checksum {
            line: line_no,
            expected,
            found: sum,
        });
    }
    chars::decode(&chars).map_err(|e| match e {
        crate::error::CharError::OutOfRange { byte, offset } => DecodeError::BadChar {
            line: line_no,
            offset,
            byte,
        },
        crate::error::CharError::Width { width } => DecodeError::BadTimestamp { len: width },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_only_reply_parses_with_empty_body() {
        let r = parse_reply(b"QT\n00P\n\n").unwrap();
        assert_eq!(r.echo.command, Command::Qt);
        assert_eq!(r.status, Status::OK);
        assert!(r.body().is_empty());
    }

    #[test]
    fn scip11_bare_status_and_leading_lfs_are_accepted() {
        let r = parse_reply(b"\n\nSCIP2.0\n0\n\n").unwrap();
        assert_eq!(r.echo.command, Command::Scip20);
        assert_eq!(r.status, Status::Bare(b'0'));
        assert!(r.status.is_ok());
        let e = parse_reply(b"QT\nE\n\n").unwrap();
        assert_eq!(e.status, Status::Bare(b'E'));
    }

    #[test]
    fn error_statuses_carry_checksums_too() {
        assert_eq!(
            parse_reply(b"SCIP2.0\n0Ee\n\n").unwrap().status,
            Status::Code(*b"0E")
        );
        assert_eq!(
            parse_reply(b"BM\n02R\n\n").unwrap().status,
            Status::Code(*b"02")
        );
        assert_eq!(
            parse_reply(b"GD0044072501\n10Q\n\n").unwrap().status,
            Status::Code(*b"10")
        );
        assert_eq!(
            parse_reply(b"BM\n02S\n\n"),
            Err(DecodeError::Checksum {
                line: 2,
                expected: b'R',
                found: b'S'
            })
        );
    }

    #[test]
    fn tm1_time_decodes_4_chars() {
        // `m2@0` = 16 000 000 ms; its checksum is computed, not typed.
        let sum = checksum(b"m2@0");
        let frame = [&b"TM1;t\n00P\nm2@0"[..], &[sum], b"\n\n"].concat();
        let r = parse_reply(&frame).unwrap();
        assert_eq!(r.echo.tag, Some(&b"t"[..]));
        assert_eq!(r.time(), Ok(16_000_000));
    }

    #[test]
    fn frames_without_lf_lf_or_status_are_rejected() {
        assert_eq!(
            parse_reply(b"QT\n00P\n"),
            Err(DecodeError::Unterminated { len: 7 })
        );
        assert_eq!(parse_reply(b"\n\n"), Err(DecodeError::Empty));
        assert_eq!(parse_reply(b"QT\n\n"), Err(DecodeError::MissingStatus));
        assert!(matches!(
            parse_reply(b"\x01\x02\n00P\n\n"),
            Err(DecodeError::Echo(_))
        ));
    }

    #[test]
    fn data_echo_matches_ack_on_first_13_chars() {
        let ack = Echo::parse(b"MD0044072501005;a").unwrap();
        let data = Echo::parse(b"MD0044072501004;a").unwrap();
        let other = Echo::parse(b"MD0044072502004;a").unwrap();
        assert!(ack.same_stream(&data));
        assert!(!ack.same_stream(&other));
        assert_eq!(data.scan().unwrap().remaining, 4);
    }

    #[test]
    fn param_line_value_with_semicolons_parses_from_the_right() {
        let sum = checksum(b"TIME:j;o[");
        let line = [&b"TIME:j;o[;"[..], &[sum]].concat();
        let p = parse_param_line(&line, 3).unwrap();
        assert_eq!(p.key, b"TIME");
        assert_eq!(p.value, b"j;o[");
    }

    #[test]
    fn param_line_without_semicolon_is_accepted() {
        let sum = checksum(b"DMIN:20");
        let line = [&b"DMIN:20"[..], &[sum]].concat();
        assert_eq!(parse_param_line(&line, 3).unwrap().value, b"20");
    }
}
