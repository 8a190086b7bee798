//! Little-endian plain CDR (XCDR1), the serialization ROS 2 uses on the wire and in bags.
//!
//! A payload starts with the 4-byte encapsulation header `00 01 00 00`
//! (CDR_LE, no options). Every primitive is aligned to its own size (8 for
//! 64-bit values), counted from the first byte *after* that header. Strings
//! are a `u32` length that includes the terminating NUL, the bytes, and the
//! NUL. Sequences (`T[]`) are a `u32` element count and the elements; fixed
//! arrays (`T[N]`) are the elements alone.

use thiserror::Error;

/// Encapsulation header of a little-endian plain CDR payload.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Why a CDR payload could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum CdrError {
    #[error("payload of {len} bytes is shorter than the 4-byte encapsulation header")]
    NoHeader { len: usize },
    #[error("encapsulation header {found:02x?}: expected 00 01 (little-endian plain CDR)")]
    UnsupportedEncapsulation { found: [u8; 2] },
    #[error("{field}: needs {need} bytes at offset {at}, the payload has {len}")]
    Truncated {
        field: &'static str,
        need: usize,
        at: usize,
        len: usize,
    },
    #[error("{field}: string of length {len} has no terminating NUL")]
    UnterminatedString { field: &'static str, len: usize },
    #[error("{field}: string is not UTF-8")]
    NotUtf8 { field: &'static str },
    #[error("{field}: {len} elements exceed the limit of {max}")]
    TooLong {
        field: &'static str,
        len: usize,
        max: usize,
    },
    #[error("{field}: {got} elements, expected {expected}")]
    WrongLength {
        field: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("{field}: invalid value {value}")]
    InvalidValue { field: &'static str, value: u64 },
    #[error("{field}: {reason}")]
    Inconsistent { field: &'static str, reason: String },
}

/// Appends CDR to a reusable buffer. Writing cannot fail.
pub struct CdrWriter<'a> {
    buf: &'a mut Vec<u8>,
}

impl<'a> CdrWriter<'a> {
    /// Clears `buf` and writes the encapsulation header.
    pub fn new(buf: &'a mut Vec<u8>) -> Self {
        buf.clear();
        buf.extend_from_slice(&CDR_LE_HEADER);
        Self { buf }
    }

    fn align(&mut self, n: usize) {
        let pos = self.buf.len() - CDR_LE_HEADER.len();
        let pad = (n - pos % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    pub fn i8(&mut self, v: i8) {
        self.buf.push(v as u8);
    }

    pub fn bool(&mut self, v: bool) {
        self.buf.push(v as u8);
    }

    pub fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Bit pattern preserved, NaN payloads included.
    pub fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }

    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }

    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// The element count of a sequence that follows.
    pub fn seq_len(&mut self, n: usize) {
        self.u32(n as u32);
    }

    pub fn seq_u8(&mut self, v: &[u8]) {
        self.seq_len(v.len());
        self.buf.extend_from_slice(v);
    }

    pub fn seq_i8(&mut self, v: &[i8]) {
        self.seq_len(v.len());
        self.buf.extend(v.iter().map(|&c| c as u8));
    }

    pub fn seq_u16(&mut self, v: &[u16]) {
        self.seq_len(v.len());
        self.align(2);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }

    pub fn seq_f32(&mut self, v: impl ExactSizeIterator<Item = f32>) {
        self.seq_len(v.len());
        self.align(4);
        for x in v {
            self.buf.extend_from_slice(&x.to_bits().to_le_bytes());
        }
    }

    /// A fixed-size `float64[N]` array (no count).
    pub fn array_f64(&mut self, v: &[f64]) {
        for &x in v {
            self.f64(x);
        }
    }

    pub fn len(&self) -> usize {
        self.buf.len()
    }

    pub fn is_empty(&self) -> bool {
        self.buf.len() == CDR_LE_HEADER.len()
    }
}

/// Reads CDR from a borrowed payload; every read is bounds-checked.
pub struct CdrReader<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    /// Checks the encapsulation header. Only little-endian plain CDR is accepted
    /// (the options bytes are ignored, as the XCDR spec allows).
    pub fn new(data: &'a [u8]) -> Result<Self, CdrError> {
        let Some(head) = data.get(..4) else {
            return Err(CdrError::NoHeader { len: data.len() });
        };
        if head[0] != 0x00 || head[1] != 0x01 {
            return Err(CdrError::UnsupportedEncapsulation {
                found: [head[0], head[1]],
            });
        }
        Ok(Self { data, pos: 4 })
    }

    fn align(&mut self, n: usize) {
        let rel = self.pos - CDR_LE_HEADER.len();
        self.pos += (n - rel % n) % n;
    }

    fn take(&mut self, n: usize, field: &'static str) -> Result<&'a [u8], CdrError> {
        let end = self.pos.checked_add(n);
        match end.and_then(|end| self.data.get(self.pos..end)) {
            Some(s) => {
                self.pos += n;
                Ok(s)
            }
            None => Err(CdrError::Truncated {
                field,
                need: n,
                at: self.pos,
                len: self.data.len(),
            }),
        }
    }

    fn fixed<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], CdrError> {
        self.align(N);
        let s = self.take(N, field)?;
        let mut out = [0u8; N];
        out.copy_from_slice(s);
        Ok(out)
    }

    pub fn u8(&mut self, field: &'static str) -> Result<u8, CdrError> {
        Ok(self.fixed::<1>(field)?[0])
    }

    pub fn i8(&mut self, field: &'static str) -> Result<i8, CdrError> {
        Ok(self.u8(field)? as i8)
    }

    pub fn bool(&mut self, field: &'static str) -> Result<bool, CdrError> {
        match self.u8(field)? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(CdrError::InvalidValue {
                field,
                value: v.into(),
            }),
        }
    }

    pub fn u16(&mut self, field: &'static str) -> Result<u16, CdrError> {
        Ok(u16::from_le_bytes(self.fixed(field)?))
    }

    pub fn u32(&mut self, field: &'static str) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.fixed(field)?))
    }

    pub fn i32(&mut self, field: &'static str) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.fixed(field)?))
    }

    pub fn u64(&mut self, field: &'static str) -> Result<u64, CdrError> {
        Ok(u64::from_le_bytes(self.fixed(field)?))
    }

    pub fn f32(&mut self, field: &'static str) -> Result<f32, CdrError> {
        Ok(f32::from_bits(self.u32(field)?))
    }

    pub fn f64(&mut self, field: &'static str) -> Result<f64, CdrError> {
        Ok(f64::from_bits(self.u64(field)?))
    }

    /// A string of at most `max` bytes (NUL excluded).
    pub fn string(&mut self, field: &'static str, max: usize) -> Result<&'a str, CdrError> {
        let n = self.u32(field)? as usize;
        if n == 0 {
            // Some writers encode "" as length 0 with no NUL; accept it.
            return Ok("");
        }
        if n - 1 > max {
            return Err(CdrError::TooLong {
                field,
                len: n - 1,
                max,
            });
        }
        let bytes = self.take(n, field)?;
        let (text, nul) = bytes.split_at(n - 1);
        if nul != [0] {
            return Err(CdrError::UnterminatedString { field, len: n });
        }
        std::str::from_utf8(text).map_err(|_| CdrError::NotUtf8 { field })
    }

    /// A sequence's element count, checked against `max` and against the
    /// bytes left (`elem_size` each) so a crafted count cannot allocate.
    pub fn seq_len(
        &mut self,
        field: &'static str,
        max: usize,
        elem_size: usize,
    ) -> Result<usize, CdrError> {
        let n = self.u32(field)? as usize;
        if n > max {
            return Err(CdrError::TooLong { field, len: n, max });
        }
        let left = self.data.len().saturating_sub(self.pos);
        if n.saturating_mul(elem_size) > left {
            return Err(CdrError::Truncated {
                field,
                need: n.saturating_mul(elem_size),
                at: self.pos,
                len: self.data.len(),
            });
        }
        Ok(n)
    }

    /// A `uint8[]`/`int8[]` sequence as a borrowed slice.
    pub fn seq_bytes(&mut self, field: &'static str, max: usize) -> Result<&'a [u8], CdrError> {
        let n = self.seq_len(field, max, 1)?;
        self.take(n, field)
    }

    /// Reads a `float32[]` into `out`; returns the element count.
    pub fn seq_f32_into(
        &mut self,
        field: &'static str,
        out: &mut [f32],
    ) -> Result<usize, CdrError> {
        let n = self.seq_len(field, out.len(), 4)?;
        for slot in &mut out[..n] {
            *slot = self.f32(field)?;
        }
        Ok(n)
    }

    /// Reads a `uint16[]` into `out`; returns the element count.
    pub fn seq_u16_into(
        &mut self,
        field: &'static str,
        out: &mut [u16],
    ) -> Result<usize, CdrError> {
        let n = self.seq_len(field, out.len(), 2)?;
        for slot in &mut out[..n] {
            *slot = self.u16(field)?;
        }
        Ok(n)
    }

    pub fn array_f64(&mut self, field: &'static str, out: &mut [f64]) -> Result<(), CdrError> {
        for slot in out {
            *slot = self.f64(field)?;
        }
        Ok(())
    }

    /// Bytes not read yet (trailing padding or fields of a newer schema).
    pub fn remaining(&self) -> usize {
        self.data.len().saturating_sub(self.pos)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn u64_after_u8_is_aligned_from_after_the_header() {
        let mut buf = Vec::new();
        let mut w = CdrWriter::new(&mut buf);
        w.u8(7);
        w.u64(0x0102_0304_0506_0708);
        // 4 header bytes, 1 byte, 7 padding (alignment counted from byte 4), 8 bytes.
        assert_eq!(buf.len(), 4 + 1 + 7 + 8);
        assert_eq!(&buf[..4], &CDR_LE_HEADER);
        assert_eq!(buf[4], 7);
        assert_eq!(&buf[12..], &[8, 7, 6, 5, 4, 3, 2, 1]);
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.u64("b").unwrap(), 0x0102_0304_0506_0708);
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn string_carries_length_with_nul() {
        let mut buf = Vec::new();
        let mut w = CdrWriter::new(&mut buf);
        w.string("laser");
        assert_eq!(&buf[4..], &[6, 0, 0, 0, b'l', b'a', b's', b'e', b'r', 0]);
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(r.string("frame_id", 32).unwrap(), "laser");
    }

    #[test]
    fn nan_payload_survives() {
        let odd_nan = f32::from_bits(0x7fc0_1234);
        let mut buf = Vec::new();
        let mut w = CdrWriter::new(&mut buf);
        w.f32(odd_nan);
        let mut r = CdrReader::new(&buf).unwrap();
        assert_eq!(r.f32("x").unwrap().to_bits(), 0x7fc0_1234);
    }

    #[test]
    fn big_endian_payload_is_rejected() {
        assert_eq!(
            CdrReader::new(&[0, 0, 0, 0]).err(),
            Some(CdrError::UnsupportedEncapsulation { found: [0, 0] })
        );
        assert_eq!(
            CdrReader::new(&[0, 1]).err(),
            Some(CdrError::NoHeader { len: 2 })
        );
    }

    #[test]
    fn crafted_sequence_count_is_refused_before_allocating() {
        let mut buf = Vec::new();
        let mut w = CdrWriter::new(&mut buf);
        w.u32(1_000_000); // claims a million floats, provides none
        let mut r = CdrReader::new(&buf).unwrap();
        let mut out = vec![0f32; 2_000_000];
        assert!(matches!(
            r.seq_f32_into("ranges", &mut out),
            Err(CdrError::Truncated { .. })
        ));
        let mut r = CdrReader::new(&buf).unwrap();
        let mut small = [0f32; 10];
        assert!(matches!(
            r.seq_f32_into("ranges", &mut small),
            Err(CdrError::TooLong { len: 1_000_000, .. })
        ));
    }

    #[test]
    fn string_without_nul_is_an_error() {
        let mut buf = CDR_LE_HEADER.to_vec();
        buf.extend_from_slice(&3u32.to_le_bytes());
        buf.extend_from_slice(b"abc");
        let mut r = CdrReader::new(&buf).unwrap();
        assert!(matches!(
            r.string("s", 10),
            Err(CdrError::UnterminatedString { .. })
        ));
    }
}
