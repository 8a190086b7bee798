//! SCIP character arithmetic: line checksums and the 6-bit character encoding.

use crate::error::CharError;

/// Lowest byte of the SCIP character encoding (value 0).
pub const CHAR_BASE: u8 = 0x30;
/// Highest byte of the SCIP character encoding (value 63).
pub const CHAR_MAX: u8 = 0x6F;

/// Checksum character of a line: sum of its payload bytes, low 6 bits, plus 0x30.
///
/// `00` → `P`, `99` → `b`, `Hokuyo` → `o`.
#[inline]
pub fn checksum(payload: &[u8]) -> u8 {
    let sum = payload
        .iter()
        .fold(0u32, |acc, &b| acc.wrapping_add(u32::from(b)));
    (sum & 0x3F) as u8 + CHAR_BASE
}

/// Value of one encoded character, `None` outside `0x30..=0x6F`.
#[inline]
pub fn char_value(c: u8) -> Option<u32> {
    let v = c.wrapping_sub(CHAR_BASE);
    (v < 64).then_some(u32::from(v))
}

/// Decodes 1..=5 SCIP characters, most significant first.
///
/// `CB` = 1234, `1Dh` = 5432, `m2@0` = 16 000 000.
pub fn decode(chars: &[u8]) -> Result<u32, CharError> {
    if chars.is_empty() || chars.len() > 5 {
        return Err(CharError::Width { width: chars.len() });
    }
    let mut v = 0u32;
    for (offset, &c) in chars.iter().enumerate() {
        let d = char_value(c).ok_or(CharError::OutOfRange { byte: c, offset })?;
        v = (v << 6) | d;
    }
    Ok(v)
}

/// Largest value `width` characters can carry.
pub const fn max_value(width: usize) -> u32 {
    if width >= 5 {
        (1 << 30) - 1
    } else {
        (1 << (6 * width)) - 1
    }
}

/// Encodes `value` into `out.len()` characters (1..=5), saturating at the largest
/// encodable value, as the sensor does for 2-character data (4095).
pub fn encode_into(value: u32, out: &mut [u8]) {
    let width = out.len().min(5);
    let v = value.min(max_value(width));
    for (i, slot) in out.iter_mut().take(width).enumerate() {
        let shift = 6 * (width - 1 - i);
        *slot = ((v >> shift) & 0x3F) as u8 + CHAR_BASE;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checksum_of_status_and_vendor_match_the_spec() {
        assert_eq!(checksum(b"00"), b'P');
        assert_eq!(checksum(b"99"), b'b');
        assert_eq!(checksum(b"Hokuyo"), b'o');
        assert_eq!(checksum(b"0E"), b'e');
        assert_eq!(checksum(b"02"), b'R');
        assert_eq!(checksum(b"10"), b'Q');
    }

    #[test]
    fn decode_2_3_4_chars_match_the_spec_examples() {
        assert_eq!(decode(b"CB"), Ok(1234));
        assert_eq!(decode(b"1Dh"), Ok(5432));
        assert_eq!(decode(b"m2@0"), Ok(16_000_000));
    }

    #[test]
    fn encode_round_trips_and_saturates_2_chars_at_4095() {
        let mut b = [0u8; 3];
        encode_into(5432, &mut b);
        assert_eq!(&b, b"1Dh");
        let mut two = [0u8; 2];
        encode_into(60_000, &mut two);
        assert_eq!(decode(&two), Ok(4095));
        let mut four = [0u8; 4];
        encode_into(16_000_000, &mut four);
        assert_eq!(&four, b"m2@0");
    }

    #[test]
    fn decode_rejects_bytes_outside_0x30_0x6f() {
        assert_eq!(
            decode(b"0p"),
            Err(CharError::OutOfRange {
                byte: b'p',
                offset: 1
            })
        );
        assert_eq!(
            decode(b"/0"),
            Err(CharError::OutOfRange {
                byte: b'/',
                offset: 0
            })
        );
        assert_eq!(decode(b""), Err(CharError::Width { width: 0 }));
    }
}
