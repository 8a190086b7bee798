//! Incremental line splitting over a fixed buffer.
//!
//! Bytes arrive from a serial port in arbitrary chunks; [`LineSplitter`]
//! reassembles lines in an inline `[u8; N]`, never allocating. LF, CR and
//! CR LF all end a line (empty lines are dropped, so CR LF is one line). A
//! line longer than `N` is dropped whole and reported at its terminator.
//!
//! A fresh or [`reset`](LineSplitter::reset) splitter starts *resyncing*: it
//! drops everything up to the first terminator, because a port opened (or
//! reopened after a replug) usually joins the board's output mid-line. The
//! cost is at most one good line per connect.

/// Default line capacity: several times the longest valid line (19 bytes),
/// so an honest line never hits it.
pub const DEFAULT_MAX_LINE: usize = 80;

/// What one byte completed.
#[derive(Debug, PartialEq, Eq)]
pub enum Split<'a> {
    /// A complete, non-empty line without its terminator.
    Line(&'a [u8]),
    /// The fragment dropped while resyncing after a (re)connect.
    SkippedPartial { bytes: usize },
    /// A line longer than the buffer, dropped.
    Overlong { bytes: usize },
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Collecting,
    Resyncing { dropped: usize },
    Overlong { dropped: usize },
}

#[derive(Debug, Clone)]
pub struct LineSplitter<const N: usize = DEFAULT_MAX_LINE> {
    buf: [u8; N],
    len: usize,
    mode: Mode,
}

impl<const N: usize> Default for LineSplitter<N> {
    fn default() -> Self {
        Self::new()
    }
}

fn is_eol(b: u8) -> bool {
    b == b'\n' || b == b'\r'
}

impl<const N: usize> LineSplitter<N> {
    /// A splitter that drops the first (probably partial) line.
    pub fn new() -> Self {
        Self {
            buf: [0; N],
            len: 0,
            mode: Mode::Resyncing { dropped: 0 },
        }
    }

    /// A splitter for input known to start at a line boundary (a capture
    /// file, a test vector).
    pub fn new_synced() -> Self {
        Self {
            mode: Mode::Collecting,
            ..Self::new()
        }
    }

    /// Forget any partial line and resync, e.g. after reopening the port.
    pub fn reset(&mut self) {
        self.len = 0;
        self.mode = Mode::Resyncing { dropped: 0 };
    }

    /// Longest line kept.
    pub const fn capacity(&self) -> usize {
        N
    }

    /// Bytes of the line being assembled.
    pub fn pending(&self) -> usize {
        self.len
    }

    /// Feeds one byte; returns what it completed, if anything.
    pub fn push_byte(&mut self, b: u8) -> Option<Split<'_>> {
        match self.mode {
            Mode::Collecting if is_eol(b) => {
                let n = std::mem::take(&mut self.len);
                (n > 0).then(|| Split::Line(self.buf.get(..n).unwrap_or(&[])))
            }
            Mode::Collecting => {
                if let Some(slot) = self.buf.get_mut(self.len) {
                    *slot = b;
                    self.len += 1;
                } else {
                    self.mode = Mode::Overlong {
                        dropped: self.len + 1,
                    };
                    self.len = 0;
                }
                None
            }
            Mode::Resyncing { dropped } if is_eol(b) => {
                self.mode = Mode::Collecting;
                (dropped > 0).then_some(Split::SkippedPartial { bytes: dropped })
            }
            Mode::Overlong { dropped } if is_eol(b) => {
                self.mode = Mode::Collecting;
                Some(Split::Overlong { bytes: dropped })
            }
            Mode::Resyncing { dropped } => {
                self.mode = Mode::Resyncing {
                    dropped: dropped.saturating_add(1),
                };
                None
            }
            Mode::Overlong { dropped } => {
                self.mode = Mode::Overlong {
                    dropped: dropped.saturating_add(1),
                };
                None
            }
        }
    }

    /// Feeds a chunk, calling `on_split` for everything it completes.
    pub fn feed(&mut self, input: &[u8], mut on_split: impl FnMut(Split<'_>)) {
        for &b in input {
            if let Some(s) = self.push_byte(b) {
                on_split(s);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn collect<const N: usize>(sp: &mut LineSplitter<N>, chunks: &[&[u8]]) -> Vec<String> {
        let mut out = Vec::new();
        for c in chunks {
            sp.feed(c, |s| {
                out.push(match s {
                    Split::Line(l) => String::from_utf8_lossy(l).into_owned(),
                    Split::SkippedPartial { bytes } => format!("<skipped {bytes}>"),
                    Split::Overlong { bytes } => format!("<overlong {bytes}>"),
                })
            });
        }
        out
    }

    #[test]
    fn line_split_across_chunks_is_reassembled() {
        let mut sp = LineSplitter::<80>::new_synced();
        let got = collect(&mut sp, &[b"A0:5", b"12\nA0:5", b"13\n"]);
        assert_eq!(got, ["A0:512", "A0:513"]);
    }

    #[test]
    fn lf_cr_and_crlf_each_end_one_line() {
        let mut sp = LineSplitter::<80>::new_synced();
        let got = collect(&mut sp, &[b"A0:1\nA0:2\rA0:3\r\nA0:4\r", b"\n"]);
        assert_eq!(got, ["A0:1", "A0:2", "A0:3", "A0:4"]);
    }

    #[test]
    fn first_fragment_after_connect_is_skipped() {
        let mut sp = LineSplitter::<80>::new();
        let got = collect(&mut sp, &[b":512\r\nA0:513\r\n"]);
        assert_eq!(got, ["<skipped 4>", "A0:513"]);
        // Opened exactly at a boundary: nothing to report, nothing lost after.
        let mut sp = LineSplitter::<80>::new();
        assert_eq!(collect(&mut sp, &[b"\nA0:1\n"]), ["A0:1"]);
    }

    #[test]
    fn overlong_line_is_dropped_whole_and_the_next_line_survives() {
        let mut sp = LineSplitter::<8>::new_synced();
        let got = collect(&mut sp, &[b"A0:123456789012\nA0:5\n"]);
        assert_eq!(got, ["<overlong 15>", "A0:5"]);
        assert_eq!(sp.pending(), 0);
    }

    #[test]
    fn line_of_exactly_capacity_is_kept() {
        let mut sp = LineSplitter::<6>::new_synced();
        assert_eq!(collect(&mut sp, &[b"A0:512\n"]), ["A0:512"]);
    }

    #[test]
    fn reset_drops_the_partial_line() {
        let mut sp = LineSplitter::<80>::new_synced();
        assert!(collect(&mut sp, &[b"A0:5"]).is_empty());
        sp.reset();
        assert_eq!(collect(&mut sp, &[b"12\nA0:6\n"]), ["<skipped 2>", "A0:6"]);
    }
}
