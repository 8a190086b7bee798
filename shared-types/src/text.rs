//! A fixed-capacity UTF-8 string that can live inside a zero-copy message.

use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Up to `N` bytes of UTF-8 text stored inline. Longer input is truncated at
/// a character boundary rather than rejected: these hold names and last-error
/// messages, where a shortened text is more useful than none.
#[derive(Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
pub struct FixedStr<const N: usize> {
    len: u32,
    bytes: [u8; N],
}

impl<const N: usize> FixedStr<N> {
    /// The empty string.
    pub const fn new() -> Self {
        Self {
            len: 0,
            bytes: [0; N],
        }
    }

    /// Builds from `s`, truncating at the last character boundary that fits.
    pub fn from_str_truncate(s: &str) -> Self {
        let mut out = Self::new();
        out.set(s);
        out
    }

    /// Replaces the text with `s`, truncated at the last character boundary that fits.
    pub fn set(&mut self, s: &str) {
        let mut end = s.len().min(N);
        while !s.is_char_boundary(end) {
            end -= 1;
        }
        self.bytes[..end].copy_from_slice(&s.as_bytes()[..end]);
        self.bytes[end..].fill(0);
        self.len = end as u32;
    }

    /// The text (a peer's invalid UTF-8 is cut at the first bad byte).
    pub fn as_str(&self) -> &str {
        let len = (self.len as usize).min(N);
        // A peer process could in principle write any bytes here; never trust them.
        match core::str::from_utf8(&self.bytes[..len]) {
            Ok(s) => s,
            Err(e) => core::str::from_utf8(&self.bytes[..e.valid_up_to()]).unwrap_or(""),
        }
    }

    /// Whether the text is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

impl<const N: usize> Default for FixedStr<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> core::fmt::Debug for FixedStr<N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        core::fmt::Debug::fmt(self.as_str(), f)
    }
}

impl<const N: usize> core::fmt::Display for FixedStr<N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn truncates_at_char_boundary() {
        let s = FixedStr::<4>::from_str_truncate("abé€");
        assert_eq!(s.as_str(), "abé");
        let s = FixedStr::<8>::from_str_truncate("laser");
        assert_eq!(s.as_str(), "laser");
    }

    #[test]
    fn corrupt_length_never_panics() {
        let mut s = FixedStr::<4>::from_str_truncate("ab");
        s.len = 999;
        s.bytes = [b'a', 0xff, b'c', b'd'];
        assert_eq!(s.as_str(), "a");
    }
}
