//! Integers on the wire.
//!
//! Signed 16-bit values are sign-magnitude, little-endian: the low byte is
//! |n| mod 256, the high byte |n| / 256 with bit 7 as the sign (Nomadic's
//! `signed_int_to_two_bytes`). So -1 is `01 80`, not `FF FF`, and the range
//! is ±32767. Unsigned values are plain little-endian.

use crate::frame::EncodeError;

/// Largest magnitude a sign-magnitude 16-bit integer carries.
pub const SM16_MAX: i32 = 0x7FFF;

/// Encodes `n` as sign-magnitude; fails outside ±32767.
pub fn encode_sm16(n: i32) -> Result<[u8; 2], EncodeError> {
    let mag = n.unsigned_abs();
    if mag > SM16_MAX as u32 {
        return Err(EncodeError::OutOfRange { value: n });
    }
    let sign = if n < 0 { 0x80 } else { 0 };
    Ok([(mag & 0xFF) as u8, sign | (mag >> 8) as u8])
}

/// Decodes a sign-magnitude pair; `00 80` ("minus zero") is 0.
pub fn decode_sm16(bytes: [u8; 2]) -> i16 {
    let [lo, hi] = bytes;
    let mag = (((hi & 0x7F) as i16) << 8) | lo as i16;
    if hi & 0x80 != 0 { -mag } else { mag }
}

/// Clamps a value into the sign-magnitude range (for conversions from SI).
pub fn saturate_sm16(v: f64) -> i16 {
    if v.is_nan() {
        return 0;
    }
    v.round().clamp(-(SM16_MAX as f64), SM16_MAX as f64) as i16
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn minus_107_is_magnitude_with_sign_bit() {
        // vm(107, -107, 0) as Nomadic's host encodes it carries `6B 80` for -107.
        assert_eq!(encode_sm16(-107).unwrap(), [0x6B, 0x80]);
        assert_eq!(decode_sm16([0x6B, 0x80]), -107);
        assert_eq!(encode_sm16(107).unwrap(), [0x6B, 0x00]);
    }

    #[test]
    fn large_negative_uses_high_byte_magnitude() {
        // -3599 = -(14*256 + 15): low 0x0F, high 0x80 | 0x0E.
        assert_eq!(encode_sm16(-3599).unwrap(), [0x0F, 0x8E]);
        assert_eq!(decode_sm16([0x0F, 0x8E]), -3599);
        assert_eq!(encode_sm16(-32767).unwrap(), [0xFF, 0xFF]);
        assert_eq!(decode_sm16([0xFF, 0xFF]), -32767);
    }

    #[test]
    fn minus_zero_decodes_to_zero() {
        assert_eq!(decode_sm16([0x00, 0x80]), 0);
    }

    #[test]
    fn values_beyond_15_bits_are_rejected() {
        assert_eq!(
            encode_sm16(32768),
            Err(EncodeError::OutOfRange { value: 32768 })
        );
        assert_eq!(
            encode_sm16(-32768),
            Err(EncodeError::OutOfRange { value: -32768 })
        );
    }

    #[test]
    fn saturation_clamps_and_rounds() {
        assert_eq!(saturate_sm16(1e9), 32767);
        assert_eq!(saturate_sm16(-1e9), -32767);
        assert_eq!(saturate_sm16(-2.6), -3);
        assert_eq!(saturate_sm16(f64::NAN), 0);
    }

    proptest! {
        #[test]
        fn sm16_round_trips(n in -32767i32..=32767) {
            let b = encode_sm16(n).unwrap();
            prop_assert_eq!(decode_sm16(b) as i32, n);
        }
    }
}
