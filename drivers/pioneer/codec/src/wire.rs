//! Packet layout, checksum, and the byte reader/writer every packet type uses.
//!
//! `FA FB <count> <payload…> <ck_hi> <ck_lo>` where `count = len(payload) + 2`.
//! Data integers are little-endian; the checksum is sent high byte first.

use thiserror::Error;

/// The two sync bytes every packet starts with.
pub const HEADER: [u8; 2] = [0xFA, 0xFB];
/// ARIA rejects a count above 200 (`ArRobotPacketReceiver.cpp`).
pub const MAX_COUNT: u8 = 200;
/// A packet carries at least its type byte plus the checksum.
pub const MIN_COUNT: u8 = 3;
/// Longest payload (type byte included).
pub const MAX_PAYLOAD: usize = MAX_COUNT as usize - 2;
/// Longest packet on the wire: header, count, payload, checksum.
pub const MAX_PACKET: usize = 3 + MAX_COUNT as usize;

/// The ARCOS checksum of a payload (type byte included): the payload summed as
/// big-endian 16-bit words mod 2^16, with a trailing odd byte XORed in
/// (`ArRobotPacket::calcCheckSum`).
pub fn checksum(payload: &[u8]) -> u16 {
    let mut sum: u16 = 0;
    let mut words = payload.chunks_exact(2);
    for w in &mut words {
        if let [hi, lo] = w {
            sum = sum.wrapping_add(u16::from_be_bytes([*hi, *lo]));
        }
    }
    if let [last] = words.remainder() {
        sum ^= u16::from(*last);
    }
    sum
}

/// Errors building a packet.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum EncodeError {
    #[error("payload would be {len} bytes, the protocol allows at most {MAX_PAYLOAD}")]
    TooLong { len: usize },
    #[error("{what}: {value} is outside {min}..={max}")]
    OutOfRange {
        what: &'static str,
        value: i64,
        min: i64,
        max: i64,
    },
    #[error("{what}: string contains a NUL byte")]
    NulInString { what: &'static str },
}

/// One framed packet in a fixed buffer (no allocation).
#[derive(Clone)]
pub struct PacketBuf {
    bytes: [u8; MAX_PACKET],
    len: usize,
}

impl Default for PacketBuf {
    fn default() -> Self {
        Self::new()
    }
}

impl std::fmt::Debug for PacketBuf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PacketBuf[{}]", crate::hex(self.as_bytes()))
    }
}

impl PartialEq for PacketBuf {
    fn eq(&self, other: &Self) -> bool {
        self.as_bytes() == other.as_bytes()
    }
}

impl PacketBuf {
    pub const fn new() -> Self {
        Self {
            bytes: [0; MAX_PACKET],
            len: 0,
        }
    }

    /// The whole packet as it goes on the wire.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..self.len).unwrap_or(&[])
    }

    /// The payload (type byte first), without header, count and checksum.
    pub fn payload(&self) -> &[u8] {
        if self.len < 5 {
            return &[];
        }
        self.bytes.get(3..self.len - 2).unwrap_or(&[])
    }

    /// Frames `payload` (type byte first) into this buffer.
    pub fn set_payload(&mut self, payload: &[u8]) -> Result<(), EncodeError> {
        let mut w = PacketWriter::new(self);
        w.bytes(payload)?;
        w.finish()
    }
}

/// Appends payload fields into a [`PacketBuf`], then frames it.
pub struct PacketWriter<'a> {
    buf: &'a mut PacketBuf,
    /// Payload bytes written so far.
    n: usize,
}

impl<'a> PacketWriter<'a> {
    pub fn new(buf: &'a mut PacketBuf) -> Self {
        buf.len = 0;
        Self { buf, n: 0 }
    }

    pub fn u8(&mut self, v: u8) -> Result<(), EncodeError> {
        self.bytes(&[v])
    }

    pub fn i8(&mut self, v: i8) -> Result<(), EncodeError> {
        self.bytes(&v.to_le_bytes())
    }

    pub fn u16(&mut self, v: u16) -> Result<(), EncodeError> {
        self.bytes(&v.to_le_bytes())
    }

    pub fn i16(&mut self, v: i16) -> Result<(), EncodeError> {
        self.bytes(&v.to_le_bytes())
    }

    pub fn u32(&mut self, v: u32) -> Result<(), EncodeError> {
        self.bytes(&v.to_le_bytes())
    }

    /// A NUL-terminated string, as SYNC2 and CONFIG carry them.
    pub fn cstr(&mut self, what: &'static str, s: &str) -> Result<(), EncodeError> {
        if s.as_bytes().contains(&0) {
            return Err(EncodeError::NulInString { what });
        }
        self.bytes(s.as_bytes())?;
        self.u8(0)
    }

    pub fn bytes(&mut self, b: &[u8]) -> Result<(), EncodeError> {
        let end = self.n + b.len();
        if end > MAX_PAYLOAD {
            return Err(EncodeError::TooLong { len: end });
        }
        if let Some(dst) = self.buf.bytes.get_mut(3 + self.n..3 + end) {
            dst.copy_from_slice(b);
        }
        self.n = end;
        Ok(())
    }

    /// Writes header, count and checksum.
    pub fn finish(self) -> Result<(), EncodeError> {
        if self.n == 0 {
            // A packet without a type byte is not a packet.
            return Err(EncodeError::TooLong { len: 0 });
        }
        let payload_end = 3 + self.n;
        let ck = checksum(self.buf.bytes.get(3..payload_end).unwrap_or(&[]));
        let b = &mut self.buf.bytes;
        b[0] = HEADER[0];
        b[1] = HEADER[1];
        // n <= MAX_PAYLOAD = 198, so the count fits a byte.
        b[2] = (self.n + 2) as u8;
        let [hi, lo] = ck.to_be_bytes();
        b[payload_end] = hi;
        b[payload_end + 1] = lo;
        self.buf.len = payload_end + 2;
        Ok(())
    }
}

/// Reads little-endian fields from a payload; every read checks the length.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    pub fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }

    pub fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.pos)
    }

    pub fn is_empty(&self) -> bool {
        self.remaining() == 0
    }

    /// Bytes read so far.
    pub fn position(&self) -> usize {
        self.pos
    }

    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let s = self.buf.get(self.pos..self.pos.checked_add(N)?)?;
        let mut out = [0u8; N];
        out.copy_from_slice(s);
        self.pos += N;
        Some(out)
    }

    pub fn u8(&mut self) -> Option<u8> {
        self.take::<1>().map(|[b]| b)
    }

    pub fn i8(&mut self) -> Option<i8> {
        self.take::<1>().map(i8::from_le_bytes)
    }

    pub fn u16(&mut self) -> Option<u16> {
        self.take::<2>().map(u16::from_le_bytes)
    }

    pub fn i16(&mut self) -> Option<i16> {
        self.take::<2>().map(i16::from_le_bytes)
    }

    pub fn u32(&mut self) -> Option<u32> {
        self.take::<4>().map(u32::from_le_bytes)
    }

    /// Bytes up to the next NUL (consumed, not returned). `None` when no NUL remains.
    pub fn cstr(&mut self) -> Option<&'a [u8]> {
        let rest = self.buf.get(self.pos..)?;
        let nul = rest.iter().position(|&b| b == 0)?;
        let s = rest.get(..nul)?;
        self.pos += nul + 1;
        Some(s)
    }

    /// Everything not read yet.
    pub fn rest(&mut self) -> &'a [u8] {
        let r = self.buf.get(self.pos..).unwrap_or(&[]);
        self.pos = self.buf.len();
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn odd_length_payload_xors_last_byte() {
        // NOTES §2: `FA FB 07 0F 2B 02 61 62 11 EE`:
        // 0x0F2B + 0x0261 = 0x118C, then ^ 0x62 = 0x11EE.
        assert_eq!(checksum(&[0x0F, 0x2B, 0x02, 0x61, 0x62]), 0x11EE);
    }

    #[test]
    fn even_length_payload_sums_big_endian_words() {
        // ENABLE 1: 04 3B 01 00 -> 0x043B + 0x0100 = 0x053B.
        assert_eq!(checksum(&[0x04, 0x3B, 0x01, 0x00]), 0x053B);
        // SYNC0: a single zero byte.
        assert_eq!(checksum(&[0x00]), 0x0000);
    }

    #[test]
    fn writer_frames_count_and_checksum() {
        let mut p = PacketBuf::new();
        p.set_payload(&[0x04, 0x3B, 0x01, 0x00]).unwrap();
        assert_eq!(
            p.as_bytes(),
            &[0xFA, 0xFB, 0x06, 0x04, 0x3B, 0x01, 0x00, 0x05, 0x3B]
        );
        assert_eq!(p.payload(), &[0x04, 0x3B, 0x01, 0x00]);
    }

    #[test]
    fn writer_rejects_payload_over_198_bytes() {
        let mut p = PacketBuf::new();
        assert!(p.set_payload(&[0u8; 198]).is_ok());
        assert_eq!(p.as_bytes().len(), 203);
        assert_eq!(
            p.set_payload(&[0u8; 199]),
            Err(EncodeError::TooLong { len: 199 })
        );
    }

    #[test]
    fn reader_never_reads_past_the_end() {
        let mut r = Reader::new(&[1, 2, 3]);
        assert_eq!(r.u16(), Some(0x0201));
        assert_eq!(r.u16(), None);
        assert_eq!(r.u8(), Some(3));
        assert_eq!(r.u8(), None);
        let mut r = Reader::new(b"ab\0cd");
        assert_eq!(r.cstr(), Some(&b"ab"[..]));
        assert_eq!(r.cstr(), None);
        assert_eq!(r.rest(), b"cd");
    }
}
