//! Values read from a Linux IIO ADC's sysfs attributes.
//!
//! The kernel's IIO ABI (`Documentation/ABI/testing/sysfs-bus-iio`) exposes a
//! voltage channel as `in_voltageY_raw` (an integer), `in_voltageY_scale`
//! (millivolts per count, a decimal such as `1.220703125`) and optionally
//! `in_voltageY_offset`; the value in mV is `(raw + offset) · scale`. The
//! scale and offset may instead be shared by all channels
//! (`in_voltage_scale`), which the reader tries second. Each read of `_raw`
//! triggers a conversion, so the driver polls it at its publishing rate.
//!
//! These functions parse the text of one attribute; reading the file is the
//! driver's business.

use crate::adc::{Measurement, RangeError};
use crate::show::Snippet;

/// Longest attribute text accepted; real ones are under 24 bytes.
pub const MAX_ATTR_LEN: usize = 64;

/// Name of the per-channel raw attribute, `in_voltage<channel>_raw`.
pub fn raw_attr(channel: u8) -> String {
    format!("in_voltage{channel}_raw")
}

/// Per-channel scale attribute, `in_voltage<channel>_scale`.
pub fn scale_attr(channel: u8) -> String {
    format!("in_voltage{channel}_scale")
}

/// Per-channel offset attribute, `in_voltage<channel>_offset`.
pub fn offset_attr(channel: u8) -> String {
    format!("in_voltage{channel}_offset")
}

/// The channel's sample format, `scan_elements/in_voltage<channel>_type`
/// (present on ADCs with buffer support): the one place IIO states the
/// converter's resolution.
pub fn type_attr(channel: u8) -> String {
    format!("scan_elements/in_voltage{channel}_type")
}

/// Scale shared by every voltage channel.
pub const SHARED_SCALE_ATTR: &str = "in_voltage_scale";
/// Offset shared by every voltage channel.
pub const SHARED_OFFSET_ATTR: &str = "in_voltage_offset";

/// An attribute whose text is not what the IIO ABI promises.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum IioError {
    #[error("expected a number in {attr}, found an empty file")]
    Empty { attr: &'static str },
    #[error("expected at most {MAX_ATTR_LEN} bytes in {attr}, found {len}")]
    TooLong { attr: &'static str, len: usize },
    #[error("expected {expected} in {attr}, found {found}")]
    BadNumber {
        attr: &'static str,
        expected: &'static str,
        found: Snippet,
    },
    #[error("expected a positive, finite {attr}, found {value}")]
    NotPositive { attr: &'static str, value: f64 },
}

/// The text without surrounding whitespace (the kernel ends values with LF).
fn trimmed<'a>(text: &'a [u8], attr: &'static str) -> Result<&'a [u8], IioError> {
    if text.len() > MAX_ATTR_LEN {
        return Err(IioError::TooLong {
            attr,
            len: text.len(),
        });
    }
    let t = text.trim_ascii();
    if t.is_empty() {
        return Err(IioError::Empty { attr });
    }
    Ok(t)
}

/// `[+-]digits` with at most 18 digits (so it fits an `i64`).
fn parse_integer(t: &[u8]) -> Option<i64> {
    let (neg, digits) = match t {
        [b'-', rest @ ..] => (true, rest),
        [b'+', rest @ ..] => (false, rest),
        _ => (false, t),
    };
    if digits.is_empty() || digits.len() > 18 || !digits.iter().all(u8::is_ascii_digit) {
        return None;
    }
    let v = digits
        .iter()
        .fold(0i64, |acc, d| acc * 10 + i64::from(d - b'0'));
    Some(if neg { -v } else { v })
}

/// `[+-]digits[.digits]` or `[+-].digits`; the grammar is checked by hand so
/// the standard parser never sees `inf`, `NaN` or exponents.
fn parse_decimal(t: &[u8]) -> Option<f64> {
    let unsigned = match t {
        [b'-' | b'+', rest @ ..] => rest,
        _ => t,
    };
    let (int, frac) = match unsigned.iter().position(|&b| b == b'.') {
        Some(dot) => (unsigned.get(..dot)?, unsigned.get(dot + 1..)?),
        None => (unsigned, &[][..]),
    };
    let ok = (!int.is_empty() || !frac.is_empty())
        && int.iter().all(u8::is_ascii_digit)
        && frac.iter().all(u8::is_ascii_digit);
    if !ok {
        return None;
    }
    std::str::from_utf8(t)
        .ok()?
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
}

/// `in_voltageY_raw`: a signed integer count.
pub fn parse_raw(text: &[u8]) -> Result<i64, IioError> {
    const ATTR: &str = "in_voltage_raw";
    let t = trimmed(text, ATTR)?;
    parse_integer(t).ok_or(IioError::BadNumber {
        attr: ATTR,
        expected: "an integer count",
        found: Snippet::new(t),
    })
}

/// `in_voltageY_scale`: millivolts per count, positive.
pub fn parse_scale(text: &[u8]) -> Result<f64, IioError> {
    const ATTR: &str = "in_voltage_scale";
    let t = trimmed(text, ATTR)?;
    let v = parse_decimal(t).ok_or(IioError::BadNumber {
        attr: ATTR,
        expected: "a decimal number of mV per count",
        found: Snippet::new(t),
    })?;
    if v <= 0.0 {
        return Err(IioError::NotPositive {
            attr: ATTR,
            value: v,
        });
    }
    Ok(v)
}

/// `in_voltageY_offset`: counts added to raw before scaling, may be negative.
pub fn parse_offset(text: &[u8]) -> Result<f64, IioError> {
    const ATTR: &str = "in_voltage_offset";
    let t = trimmed(text, ATTR)?;
    parse_decimal(t).ok_or(IioError::BadNumber {
        attr: ATTR,
        expected: "a decimal offset in counts",
        found: Snippet::new(t),
    })
}

/// `scan_elements/in_voltageY_type`: `[be|le]:[s|u]BITS/STORAGE[XREPEAT][>>SHIFT]`
/// (the kernel's IIO ABI); returns BITS, the converter's resolution.
pub fn parse_type(text: &[u8]) -> Result<u8, IioError> {
    const ATTR: &str = "in_voltage_type";
    let t = trimmed(text, ATTR)?;
    let bad = || IioError::BadNumber {
        attr: ATTR,
        expected: "le:u12/16>>0 (endianness:sign bits/storage bits)",
        found: Snippet::new(t),
    };
    let rest = match t {
        [b'l' | b'b', b'e', b':', rest @ ..] => rest,
        _ => return Err(bad()),
    };
    let rest = match rest {
        [b's' | b'u', rest @ ..] => rest,
        _ => return Err(bad()),
    };
    let slash = rest.iter().position(|&b| b == b'/').ok_or_else(bad)?;
    let (bits, storage) = (rest.get(..slash).ok_or_else(bad)?, rest.get(slash + 1..));
    let storage_digits = storage
        .map(|s| s.iter().take_while(|b| b.is_ascii_digit()).count())
        .unwrap_or(0);
    let bits = parse_integer(bits)
        .filter(|b| (1..=32).contains(b))
        .ok_or_else(bad)?;
    let storage = storage
        .and_then(|s| s.get(..storage_digits))
        .and_then(parse_integer)
        .ok_or_else(bad)?;
    if storage < bits {
        return Err(bad());
    }
    u8::try_from(bits).map_err(|_| bad())
}

/// What a raw value is checked against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum IioRange {
    /// The device stated its resolution (its `_type` attribute): counts
    /// above `2^bits − 1` cannot come from the converter.
    Counts { bits: u8 },
    /// The device states only its scale: the value in mV must lie below the
    /// profile's reference voltage (nothing on the board can exceed it).
    BelowReference { vref_mv: f64 },
}

impl IioRange {
    /// Largest count for a stated resolution.
    pub fn max_counts(bits: u8) -> u32 {
        u32::try_from((1u64 << bits.min(32)) - 1).unwrap_or(u32::MAX)
    }
}

/// How an IIO channel's raw value becomes millivolts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IioCalibration {
    /// mV per count.
    pub scale_mv: f64,
    /// Counts added before scaling.
    pub offset: f64,
}

impl IioCalibration {
    /// `raw` checked against what the device says it can produce (never
    /// against the profile's `adc_bits`: IIO states its own scale).
    pub fn measure(&self, raw: i64, range: IioRange) -> Result<Measurement, RangeError> {
        if raw < 0 {
            return Err(RangeError::NegativeCounts { counts: raw });
        }
        let above_max = |max: u32, bits: u8| RangeError::CountsAboveMax {
            counts: raw,
            max,
            bits,
        };
        let counts = match range {
            IioRange::Counts { bits } => {
                let max = IioRange::max_counts(bits);
                u32::try_from(raw)
                    .ok()
                    .filter(|c| *c <= max)
                    .ok_or_else(|| above_max(max, bits))?
            }
            IioRange::BelowReference { .. } => {
                u32::try_from(raw).map_err(|_| above_max(u32::MAX, 32))?
            }
        };
        let raw_mv = (raw as f64 + self.offset) * self.scale_mv;
        if let IioRange::BelowReference { vref_mv } = range
            && raw_mv >= vref_mv
        {
            return Err(RangeError::MillivoltsOutOfRange {
                mv: raw_mv,
                vref_mv,
            });
        }
        Ok(Measurement {
            raw_counts: counts,
            raw_mv,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_attribute_with_newline_parses() {
        assert_eq!(parse_raw(b"2048\n"), Ok(2048));
        assert_eq!(parse_raw(b"-12\n"), Ok(-12));
        assert!(matches!(
            parse_raw(b"12a\n"),
            Err(IioError::BadNumber { .. })
        ));
        assert_eq!(
            parse_raw(b"\n"),
            Err(IioError::Empty {
                attr: "in_voltage_raw"
            })
        );
        assert!(matches!(
            parse_raw(b"9999999999999999999"),
            Err(IioError::BadNumber { .. })
        ));
    }

    #[test]
    fn ads1015_scale_of_3_mv_and_ti_adc_scale_parse() {
        assert_eq!(parse_scale(b"3.000000000\n"), Ok(3.0));
        assert_eq!(parse_scale(b"1.220703125\n"), Ok(1.220703125));
        assert_eq!(parse_scale(b"2\n"), Ok(2.0));
    }

    #[test]
    fn scale_refuses_zero_negative_and_words() {
        assert!(matches!(
            parse_scale(b"0.0\n"),
            Err(IioError::NotPositive { .. })
        ));
        assert!(matches!(
            parse_scale(b"-1.5\n"),
            Err(IioError::NotPositive { .. })
        ));
        for bad in [&b"inf\n"[..], b"NaN", b"1e3", b".", b"1.2.3", b"1,5"] {
            assert!(
                matches!(parse_scale(bad), Err(IioError::BadNumber { .. })),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn offset_may_be_negative_or_fractional() {
        assert_eq!(parse_offset(b"-128\n"), Ok(-128.0));
        assert_eq!(parse_offset(b"0.5\n"), Ok(0.5));
    }

    #[test]
    fn oversized_attribute_is_refused_before_parsing() {
        let big = [b'1'; 100];
        assert_eq!(
            parse_raw(&big),
            Err(IioError::TooLong {
                attr: "in_voltage_raw",
                len: 100
            })
        );
    }

    #[test]
    fn calibration_applies_offset_then_scale_and_checks_range() {
        let cal = IioCalibration {
            scale_mv: 1.220703125,
            offset: 0.0,
        };
        let twelve = IioRange::Counts { bits: 12 };
        let m = cal.measure(2048, twelve).unwrap();
        assert_eq!(m.raw_counts, 2048);
        assert!((m.raw_mv - 2500.0).abs() < 1e-9);
        let cal = IioCalibration {
            scale_mv: 2.0,
            offset: -10.0,
        };
        assert!((cal.measure(110, twelve).unwrap().raw_mv - 200.0).abs() < 1e-9);
        assert_eq!(
            cal.measure(4096, twelve),
            Err(RangeError::CountsAboveMax {
                counts: 4096,
                max: 4095,
                bits: 12
            })
        );
        assert!(cal.measure(-1, twelve).is_err());
    }

    #[test]
    fn scan_type_states_the_resolution() {
        // ads1015 (12 bits, shifted), ti-ads8688 (16 of 16), a 10-bit MCP3008.
        assert_eq!(parse_type(b"be:s12/16>>4\n"), Ok(12));
        assert_eq!(parse_type(b"le:u16/16>>0\n"), Ok(16));
        assert_eq!(parse_type(b"le:u10/16\n"), Ok(10));
        assert_eq!(parse_type(b"le:s24/32X2>>8"), Ok(24));
        for bad in [
            &b"u12/16"[..],
            b"le:x12/16",
            b"le:u0/16",
            b"le:u17/16",
            b"le:u/16",
            b"le:u12",
        ] {
            assert!(
                matches!(parse_type(bad), Err(IioError::BadNumber { .. })),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn a_12_bit_reading_passes_whatever_a_profile_guessed() {
        // A 12-bit ADC against a 5 V reference: 3000 counts is 3662 mV.
        let cal = IioCalibration {
            scale_mv: 1.220703125,
            offset: 0.0,
        };
        let m = cal
            .measure(3000, IioRange::BelowReference { vref_mv: 5000.0 })
            .unwrap();
        assert!((m.raw_mv - 3662.109375).abs() < 1e-9);
        // Full scale and beyond cannot come from the converter.
        assert!(matches!(
            cal.measure(4096, IioRange::BelowReference { vref_mv: 5000.0 }),
            Err(RangeError::MillivoltsOutOfRange { .. })
        ));
        assert!(cal.measure(4095, IioRange::Counts { bits: 12 }).is_ok());
        assert_eq!(IioRange::max_counts(32), u32::MAX);
    }

    #[test]
    fn attribute_names_follow_the_iio_abi() {
        assert_eq!(raw_attr(3), "in_voltage3_raw");
        assert_eq!(scale_attr(0), "in_voltage0_scale");
        assert_eq!(offset_attr(1), "in_voltage1_offset");
        assert_eq!(type_attr(2), "scan_elements/in_voltage2_type");
    }
}
