//! Printing offending input in error messages without trusting it.

use std::fmt;

/// What a parser found where it expected something else: a byte, or the end
/// of the input.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Found {
    Byte(u8),
    End,
}

impl Found {
    pub(crate) fn at(bytes: &[u8], i: usize) -> Self {
        bytes.get(i).map_or(Found::End, |&b| Found::Byte(b))
    }
}

impl fmt::Display for Found {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Found::End => f.write_str("end of line"),
            Found::Byte(b) if b.is_ascii_graphic() || b == b' ' => write!(f, "'{}'", b as char),
            Found::Byte(b) => write!(f, "byte 0x{b:02X}"),
        }
    }
}

/// Capacity of a [`Snippet`].
pub const SNIPPET_LEN: usize = 24;

/// The first bytes of a rejected value, kept inline (no allocation) and
/// printed escaped, so a binary blob in a sysfs file cannot garble a log line.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Snippet {
    bytes: [u8; SNIPPET_LEN],
    len: u8,
    truncated: bool,
}

impl Snippet {
    pub fn new(input: &[u8]) -> Self {
        let mut bytes = [0u8; SNIPPET_LEN];
        let n = input.len().min(SNIPPET_LEN);
        for (dst, src) in bytes.iter_mut().zip(input) {
            *dst = *src;
        }
        Self {
            bytes,
            len: n as u8,
            truncated: input.len() > SNIPPET_LEN,
        }
    }

    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

impl fmt::Display for Snippet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("\"")?;
        for &b in self.as_bytes() {
            for c in std::ascii::escape_default(b) {
                write!(f, "{}", c as char)?;
            }
        }
        if self.truncated {
            f.write_str("…")?;
        }
        f.write_str("\"")
    }
}

impl fmt::Debug for Snippet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn found_prints_printable_bytes_quoted_and_others_in_hex() {
        assert_eq!(Found::Byte(b'x').to_string(), "'x'");
        assert_eq!(Found::Byte(0xFF).to_string(), "byte 0xFF");
        assert_eq!(Found::End.to_string(), "end of line");
    }

    #[test]
    fn snippet_escapes_and_truncates_at_24_bytes() {
        let s = Snippet::new(b"12\n\x00");
        assert_eq!(s.to_string(), "\"12\\n\\x00\"");
        let long = Snippet::new(&[b'9'; 40]);
        assert_eq!(long.as_bytes().len(), 24);
        assert!(long.to_string().ends_with("…\""));
    }
}
