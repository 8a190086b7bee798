//! Reply encoding, as a device writes it (for emulators and tests).
//!
//! Appends to a caller-owned `Vec<u8>` that is cleared and reused, so a device
//! loop allocates nothing once the buffer has grown to a full scan.

use crate::chars::{checksum, encode_into};

/// Data characters per data line before its checksum.
pub const DATA_LINE_CHARS: usize = 64;

/// Writes reply frames into a reusable buffer.
#[derive(Debug)]
pub struct ReplyWriter<'a> {
    out: &'a mut Vec<u8>,
}

impl<'a> ReplyWriter<'a> {
    pub fn new(out: &'a mut Vec<u8>) -> Self {
        ReplyWriter { out }
    }

    /// The echo line: the request line as received (tag included).
    pub fn echo(&mut self, line: &[u8]) -> &mut Self {
        self.out.extend_from_slice(line);
        self.out.push(b'\n');
        self
    }

    /// A two-character status with its checksum.
    pub fn status(&mut self, code: [u8; 2]) -> &mut Self {
        self.out.extend_from_slice(&code);
        self.out.push(checksum(&code));
        self.out.push(b'\n');
        self
    }

    /// A bare SCIP 1.1 status line (no checksum).
    pub fn bare_status(&mut self, c: u8) -> &mut Self {
        self.out.push(c);
        self.out.push(b'\n');
        self
    }

    /// `KEY:VALUE;c` with the checksum over `KEY:VALUE`.
    pub fn param(&mut self, key: &str, value: &str) -> &mut Self {
        let start = self.out.len();
        self.out.extend_from_slice(key.as_bytes());
        self.out.push(b':');
        self.out.extend_from_slice(value.as_bytes());
        let sum = checksum(&self.out[start..]);
        self.out.push(b';');
        self.out.push(sum);
        self.out.push(b'\n');
        self
    }

    /// A 4-character time line (TM1 reply or scan timestamp), 24-bit.
    pub fn time(&mut self, ms: u32) -> &mut Self {
        let mut t = [0u8; 4];
        encode_into(ms & 0xFF_FFFF, &mut t);
        self.out.extend_from_slice(&t);
        self.out.push(checksum(&t));
        self.out.push(b'\n');
        self
    }

    /// Data lines: each value in `width` characters (ME: range then intensity per step),
    /// split into lines of 64 characters + checksum, values split across lines as the
    /// sensor does.
    pub fn data(&mut self, width: usize, values: impl IntoIterator<Item = u32>) -> &mut Self {
        let mut line_start = self.out.len();
        let mut enc = [0u8; 5];
        let width = width.clamp(1, 5);
        for v in values {
            encode_into(v, &mut enc[..width]);
            for &c in &enc[..width] {
                self.out.push(c);
                if self.out.len() - line_start == DATA_LINE_CHARS {
                    let sum = checksum(&self.out[line_start..]);
                    self.out.push(sum);
                    self.out.push(b'\n');
                    line_start = self.out.len();
                }
            }
        }
        if self.out.len() > line_start {
            let sum = checksum(&self.out[line_start..]);
            self.out.push(sum);
            self.out.push(b'\n');
        }
        self
    }

    /// The empty line that ends every reply.
    pub fn end(&mut self) {
        self.out.push(b'\n');
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reply::parse_reply;
    use crate::status::Status;

    #[test]
    fn written_gd_reply_round_trips_with_a_value_split_across_lines() {
        let ranges: Vec<u32> = (0..682).map(|i| 20 + i * 7).collect();
        let mut out = Vec::new();
        ReplyWriter::new(&mut out)
            .echo(b"GD0044072501")
            .status(*b"00")
            .time(11_149_560)
            .data(3, ranges.iter().copied())
            .end();
        // 682 · 3 = 2046 chars = 31 full lines + 62: values 21, 42, … straddle lines.
        let lines: Vec<&[u8]> = out.split(|&b| b == b'\n').collect();
        assert_eq!(lines[3].len(), 65);
        assert_eq!(lines[34].len(), 63);
        let reply = parse_reply(&out).unwrap();
        assert_eq!(reply.status, Status::OK);
        let mut buf = [0u32; 700];
        let h = reply.decode_scan(&mut buf, &mut []).unwrap();
        assert_eq!(h.timestamp, 11_149_560);
        assert_eq!(&buf[..h.count], &ranges[..]);
    }

    #[test]
    fn written_param_line_has_checksum_before_semicolon_like_the_04lx() {
        let mut out = Vec::new();
        ReplyWriter::new(&mut out).param("DMIN", "20");
        assert_eq!(out, b"DMIN:20;4\n");
    }
}
