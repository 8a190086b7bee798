//! The serial sample-line format an Arduino-class ADC board prints.
//!
//! One sample per line, ASCII:
//!
//! ```text
//! line       = sample [ "*" checksum ] eol
//!            / "#" *any eol                ; banner or comment, ignored
//! sample     = "A" channel ":" value
//! channel    = 1*2DIGIT                    ; 0–99, the board's analog pin (A0 …)
//! value      = counts / millivolts
//! counts     = 1*8DIGIT                    ; raw ADC counts
//! millivolts = 1*6DIGIT [ "." 1*3DIGIT ] "mV"   ; unit letters in any case
//! checksum   = 2HEXDIG                     ; XOR of every byte from "A" up to "*"
//! eol        = LF / CR LF / CR
//! ```
//!
//! Examples: `A0:512`, `A0:512*7D`, `A1:2480.5mV`, `# smoke-adc v1`.
//!
//! Tolerance: leading and trailing ASCII whitespace and NUL bytes (what a
//! board emits around a reset) are ignored, blank lines are ignored, and a
//! line without a checksum is accepted unless [`ChecksumPolicy::Required`].
//! Everything else is a typed [`LineError`] naming what was expected.
//!
//! A minimal Arduino sketch producing this format prints, every 100 ms,
//! `Serial.print("A0:"); Serial.println(analogRead(A0));`.

use crate::show::Found;
use std::fmt::{self, Write as _};

/// Most digits accepted in a count: a 24-bit ADC (the widest the config
/// allows) tops out at 16 777 215.
pub const MAX_COUNT_DIGITS: usize = 8;
/// Most integer digits in a millivolt value (999 999 mV, far above any vref).
pub const MAX_MV_INT_DIGITS: usize = 6;
/// Most decimals in a millivolt value.
pub const MAX_MV_FRAC_DIGITS: usize = 3;
/// Highest channel number a line may name.
pub const MAX_CHANNEL: u8 = 99;

/// The value a sample line carries.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SampleValue {
    /// Raw ADC counts (`A0:512`).
    Counts(u32),
    /// Millivolts measured by the board itself (`A0:2480.5mV`).
    Millivolts(f32),
}

/// One decoded sample line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub channel: u8,
    pub value: SampleValue,
}

/// What a complete line turned out to be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Line {
    Sample(Sample),
    /// A `#` line: board banner or comment.
    Comment,
    /// Only whitespace/NUL.
    Blank,
}

/// Whether a line must carry a `*XX` checksum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ChecksumPolicy {
    /// Checked when present.
    #[default]
    Optional,
    /// Lines without one are rejected.
    Required,
}

/// A line that does not follow the format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LineError {
    #[error("expected a sample line starting with 'A' (or a '#' comment), found {found}")]
    MissingPrefix { found: Found },
    #[error("expected 1–2 channel digits after 'A', found {found}")]
    BadChannel { found: Found },
    #[error("expected ':' after the channel number, found {found}")]
    MissingColon { found: Found },
    #[error("expected a decimal value after ':', found {found}")]
    MissingValue { found: Found },
    #[error("expected at most {max} digits in the {part}, found more")]
    TooManyDigits { part: &'static str, max: usize },
    #[error("expected 1–{max} decimals after '.', found {found}", max = MAX_MV_FRAC_DIGITS)]
    BadFraction { found: Found },
    #[error("expected the unit \"mV\" after a decimal value, found {found}")]
    MissingUnit { found: Found },
    #[error("expected end of line or a '*' checksum after the value, found {found}")]
    TrailingGarbage { found: Found },
    #[error("expected two hex digits after '*', found {found}")]
    BadChecksumField { found: Found },
    #[error("checksum mismatch: the line states {stated:02X}, its bytes XOR to {computed:02X}")]
    ChecksumMismatch { stated: u8, computed: u8 },
    #[error("expected a '*XX' checksum (required by configuration), found none")]
    MissingChecksum,
}

impl LineError {
    /// True for errors that mean the bytes were damaged in transit rather
    /// than the board printing something this format does not know.
    pub fn is_checksum(&self) -> bool {
        matches!(
            self,
            LineError::ChecksumMismatch { .. } | LineError::BadChecksumField { .. }
        )
    }
}

fn is_filler(b: u8) -> bool {
    b.is_ascii_whitespace() || b == 0
}

/// XOR of `bytes`, the checksum the format uses (as NMEA 0183 does).
pub fn xor_checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |acc, b| acc ^ b)
}

fn hex_value(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'a'..=b'f' => Some(b - b'a' + 10),
        b'A'..=b'F' => Some(b - b'A' + 10),
        _ => None,
    }
}

/// Length of the run of ASCII digits starting at `from`.
fn digits_at(bytes: &[u8], from: usize) -> usize {
    bytes.get(from..).map_or(0, |rest| {
        rest.iter().take_while(|b| b.is_ascii_digit()).count()
    })
}

/// Decimal value of ASCII digits (at most 9, so it fits a `u32`).
fn digits_value(digits: &[u8]) -> u32 {
    digits.iter().fold(0u32, |acc, d| {
        acc.wrapping_mul(10).wrapping_add(u32::from(d - b'0'))
    })
}

/// Decodes one complete line (terminator already removed, or still present:
/// trailing CR/LF are ignored).
pub fn parse_line(line: &[u8], policy: ChecksumPolicy) -> Result<Line, LineError> {
    let start = line.iter().position(|&b| !is_filler(b));
    let Some(start) = start else {
        return Ok(Line::Blank);
    };
    let end = line
        .iter()
        .rposition(|&b| !is_filler(b))
        .map_or(start, |e| e + 1);
    let text = line.get(start..end).unwrap_or(&[]);

    match text.first() {
        Some(b'#') => return Ok(Line::Comment),
        Some(b'A') => {}
        _ => {
            return Err(LineError::MissingPrefix {
                found: Found::at(text, 0),
            });
        }
    }

    let (body, stated) = match text.iter().position(|&b| b == b'*') {
        Some(star) => {
            let body = text.get(..star).unwrap_or(&[]);
            let field = text.get(star + 1..).unwrap_or(&[]);
            let stated = match field {
                [hi, lo] => match (hex_value(*hi), hex_value(*lo)) {
                    (Some(h), Some(l)) => (h << 4) | l,
                    (None, _) => {
                        return Err(LineError::BadChecksumField {
                            found: Found::Byte(*hi),
                        });
                    }
                    (_, None) => {
                        return Err(LineError::BadChecksumField {
                            found: Found::Byte(*lo),
                        });
                    }
                },
                _ => {
                    let bad = field
                        .iter()
                        .position(|&b| hex_value(b).is_none())
                        .unwrap_or(2);
                    return Err(LineError::BadChecksumField {
                        found: Found::at(field, bad),
                    });
                }
            };
            (body, Some(stated))
        }
        None => (text, None),
    };

    match stated {
        Some(stated) => {
            let computed = xor_checksum(body);
            if computed != stated {
                return Err(LineError::ChecksumMismatch { stated, computed });
            }
        }
        None if policy == ChecksumPolicy::Required => return Err(LineError::MissingChecksum),
        None => {}
    }

    parse_body(body).map(Line::Sample)
}

/// `A<channel>:<value>` without checksum; `body[0]` is known to be `A`.
fn parse_body(body: &[u8]) -> Result<Sample, LineError> {
    let mut i = 1;
    let n = digits_at(body, i);
    if n == 0 {
        return Err(LineError::BadChannel {
            found: Found::at(body, i),
        });
    }
    if n > 2 {
        return Err(LineError::TooManyDigits {
            part: "channel",
            max: 2,
        });
    }
    let channel = digits_value(body.get(i..i + n).unwrap_or(&[])) as u8;
    i += n;

    if body.get(i) != Some(&b':') {
        return Err(LineError::MissingColon {
            found: Found::at(body, i),
        });
    }
    i += 1;

    let n = digits_at(body, i);
    if n == 0 {
        return Err(LineError::MissingValue {
            found: Found::at(body, i),
        });
    }
    let int_digits = body.get(i..i + n).unwrap_or(&[]);
    i += n;

    let mut frac_digits: &[u8] = &[];
    if body.get(i) == Some(&b'.') {
        i += 1;
        let f = digits_at(body, i);
        if f == 0 {
            return Err(LineError::BadFraction {
                found: Found::at(body, i),
            });
        }
        if f > MAX_MV_FRAC_DIGITS {
            return Err(LineError::TooManyDigits {
                part: "decimals",
                max: MAX_MV_FRAC_DIGITS,
            });
        }
        frac_digits = body.get(i..i + f).unwrap_or(&[]);
        i += f;
    }

    let unit = body.get(i..i + 2);
    let has_unit = unit.is_some_and(|u| u.eq_ignore_ascii_case(b"mV"));
    if has_unit {
        i += 2;
    } else if !frac_digits.is_empty() {
        return Err(LineError::MissingUnit {
            found: Found::at(body, i),
        });
    }
    if i != body.len() {
        return Err(LineError::TrailingGarbage {
            found: Found::at(body, i),
        });
    }

    let value = if has_unit {
        if int_digits.len() > MAX_MV_INT_DIGITS {
            return Err(LineError::TooManyDigits {
                part: "millivolt value",
                max: MAX_MV_INT_DIGITS,
            });
        }
        let frac = digits_value(frac_digits) as f32 / 10f32.powi(frac_digits.len() as i32);
        SampleValue::Millivolts(digits_value(int_digits) as f32 + frac)
    } else {
        if int_digits.len() > MAX_COUNT_DIGITS {
            return Err(LineError::TooManyDigits {
                part: "count",
                max: MAX_COUNT_DIGITS,
            });
        }
        SampleValue::Counts(digits_value(int_digits))
    };
    Ok(Sample { channel, value })
}

/// Why a sample cannot be written in the line format.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum EncodeError {
    #[error("channel {0} is above the format's maximum of {MAX_CHANNEL}")]
    Channel(u8),
    #[error("value {0} does not fit the format (counts ≤ 99 999 999, 0 ≤ mV < 1 000 000)")]
    Value(f64),
}

/// Capacity of a [`LineBuf`]; the longest line the encoder writes,
/// `A99:999999.9mV*FF\r\n`, is 19 bytes.
pub const LINE_BUF_LEN: usize = 32;

/// An encoded line, inline.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct LineBuf {
    buf: [u8; LINE_BUF_LEN],
    len: usize,
}

impl LineBuf {
    fn new() -> Self {
        Self {
            buf: [0; LINE_BUF_LEN],
            len: 0,
        }
    }

    pub fn as_bytes(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }
}

impl fmt::Debug for LineBuf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "LineBuf({})", crate::show::Snippet::new(self.as_bytes()))
    }
}

impl fmt::Write for LineBuf {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        let dst = self
            .buf
            .get_mut(self.len..self.len + s.len())
            .ok_or(fmt::Error)?;
        dst.copy_from_slice(s.as_bytes());
        self.len += s.len();
        Ok(())
    }
}

/// Line terminator the encoder writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Eol {
    #[default]
    Lf,
    /// What Arduino's `Serial.println` sends.
    CrLf,
}

/// Writes `sample` as a line (with terminator); millivolts get one decimal.
pub fn encode_sample(sample: &Sample, checksum: bool, eol: Eol) -> Result<LineBuf, EncodeError> {
    if sample.channel > MAX_CHANNEL {
        return Err(EncodeError::Channel(sample.channel));
    }
    let mut out = LineBuf::new();
    let written = match sample.value {
        SampleValue::Counts(c) if c <= 99_999_999 => write!(out, "A{}:{}", sample.channel, c),
        SampleValue::Millivolts(mv) if mv.is_finite() && (0.0..999_999.95).contains(&mv) => {
            write!(out, "A{}:{:.1}mV", sample.channel, mv)
        }
        SampleValue::Counts(c) => return Err(EncodeError::Value(f64::from(c))),
        SampleValue::Millivolts(mv) => return Err(EncodeError::Value(f64::from(mv))),
    };
    // The buffer holds the longest line; a failure here would be a bug in
    // LINE_BUF_LEN, reported rather than panicking.
    written.map_err(|_| EncodeError::Value(f64::NAN))?;
    if checksum {
        let cs = xor_checksum(out.as_bytes());
        write!(out, "*{cs:02X}").map_err(|_| EncodeError::Value(f64::NAN))?;
    }
    let term = match eol {
        Eol::Lf => "\n",
        Eol::CrLf => "\r\n",
    };
    out.write_str(term)
        .map_err(|_| EncodeError::Value(f64::NAN))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(line: &[u8]) -> Result<Sample, LineError> {
        match parse_line(line, ChecksumPolicy::Optional)? {
            Line::Sample(s) => Ok(s),
            other => panic!("expected a sample, got {other:?}"),
        }
    }

    #[test]
    fn counts_line_decodes_channel_and_value() {
        assert_eq!(
            sample(b"A0:512"),
            Ok(Sample {
                channel: 0,
                value: SampleValue::Counts(512)
            })
        );
        assert_eq!(
            sample(b"A15:1023\r\n"),
            Ok(Sample {
                channel: 15,
                value: SampleValue::Counts(1023)
            })
        );
    }

    #[test]
    fn millivolt_line_decodes_with_and_without_decimals() {
        assert_eq!(
            sample(b"A1:2480.5mV").map(|s| s.value),
            Ok(SampleValue::Millivolts(2480.5))
        );
        assert_eq!(
            sample(b"A1:2480MV").map(|s| s.value),
            Ok(SampleValue::Millivolts(2480.0))
        );
        assert_eq!(
            sample(b"A1:0.125mv").map(|s| s.value),
            Ok(SampleValue::Millivolts(0.125))
        );
    }

    #[test]
    fn checksum_is_xor_of_bytes_before_star() {
        // 'A' 0x41 ^ '0' 0x30 ^ ':' 0x3A ^ '5' 0x35 ^ '1' 0x31 ^ '2' 0x32 = 0x7D
        assert_eq!(xor_checksum(b"A0:512"), 0x7D);
        assert!(sample(b"A0:512*7D").is_ok());
        assert!(sample(b"A0:512*7D\r").is_ok());
        assert_eq!(
            sample(b"A0:513*7D"),
            Err(LineError::ChecksumMismatch {
                stated: 0x7D,
                computed: 0x7C
            })
        );
    }

    #[test]
    fn required_checksum_rejects_bare_line() {
        assert_eq!(
            parse_line(b"A0:512", ChecksumPolicy::Required),
            Err(LineError::MissingChecksum)
        );
        assert!(parse_line(b"A0:512*7D", ChecksumPolicy::Required).is_ok());
    }

    #[test]
    fn reset_noise_around_a_line_is_ignored() {
        assert!(sample(b"\0\0  A0:512 \r").is_ok());
        assert_eq!(
            parse_line(b"\0 \r", ChecksumPolicy::Optional),
            Ok(Line::Blank)
        );
        assert_eq!(
            parse_line(b"# smoke-adc v1, 10 Hz", ChecksumPolicy::Optional),
            Ok(Line::Comment)
        );
    }

    #[test]
    fn partial_line_after_connect_names_what_came() {
        let err = sample(b"0:512").unwrap_err();
        assert_eq!(
            err,
            LineError::MissingPrefix {
                found: Found::Byte(b'0')
            }
        );
        assert_eq!(
            err.to_string(),
            "expected a sample line starting with 'A' (or a '#' comment), found '0'"
        );
    }

    #[test]
    fn malformed_lines_give_the_matching_error() {
        assert_eq!(
            sample(b"A:512"),
            Err(LineError::BadChannel {
                found: Found::Byte(b':')
            })
        );
        assert_eq!(
            sample(b"A123:5"),
            Err(LineError::TooManyDigits {
                part: "channel",
                max: 2
            })
        );
        assert_eq!(
            sample(b"A0=512"),
            Err(LineError::MissingColon {
                found: Found::Byte(b'=')
            })
        );
        assert_eq!(
            sample(b"A0:"),
            Err(LineError::MissingValue { found: Found::End })
        );
        assert_eq!(
            sample(b"A0:123456789"),
            Err(LineError::TooManyDigits {
                part: "count",
                max: 8
            })
        );
        assert_eq!(
            sample(b"A0:12.mV"),
            Err(LineError::BadFraction {
                found: Found::Byte(b'm')
            })
        );
        assert_eq!(
            sample(b"A0:12.5"),
            Err(LineError::MissingUnit { found: Found::End })
        );
        assert_eq!(
            sample(b"A0:512x"),
            Err(LineError::TrailingGarbage {
                found: Found::Byte(b'x')
            })
        );
        assert_eq!(
            sample(b"A0:512*3"),
            Err(LineError::BadChecksumField { found: Found::End })
        );
        assert_eq!(
            sample(b"A0:512*3G"),
            Err(LineError::BadChecksumField {
                found: Found::Byte(b'G')
            })
        );
        assert_eq!(
            sample(b"\xFF\xFE"),
            Err(LineError::MissingPrefix {
                found: Found::Byte(0xFF)
            })
        );
    }

    #[test]
    fn encoded_lines_parse_back() {
        for (s, cs) in [
            (
                Sample {
                    channel: 0,
                    value: SampleValue::Counts(512),
                },
                false,
            ),
            (
                Sample {
                    channel: 7,
                    value: SampleValue::Counts(0),
                },
                true,
            ),
            (
                Sample {
                    channel: 99,
                    value: SampleValue::Millivolts(2480.5),
                },
                true,
            ),
        ] {
            let line = encode_sample(&s, cs, Eol::CrLf).unwrap();
            let parsed = parse_line(line.as_bytes(), ChecksumPolicy::Optional);
            assert_eq!(parsed, Ok(Line::Sample(s)), "{line:?}");
        }
        let line = encode_sample(
            &Sample {
                channel: 0,
                value: SampleValue::Counts(512),
            },
            true,
            Eol::Lf,
        );
        assert_eq!(line.unwrap().as_bytes(), b"A0:512*7D\n");
    }

    #[test]
    fn encoder_refuses_what_the_format_cannot_hold() {
        let big = Sample {
            channel: 0,
            value: SampleValue::Counts(100_000_000),
        };
        assert!(encode_sample(&big, false, Eol::Lf).is_err());
        let neg = Sample {
            channel: 0,
            value: SampleValue::Millivolts(-1.0),
        };
        assert!(encode_sample(&neg, false, Eol::Lf).is_err());
        let ch = Sample {
            channel: 100,
            value: SampleValue::Counts(1),
        };
        assert_eq!(
            encode_sample(&ch, false, Eol::Lf),
            Err(EncodeError::Channel(100))
        );
    }
}
