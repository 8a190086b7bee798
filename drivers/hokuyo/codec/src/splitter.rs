//! Incremental frame splitter: bytes from a stream in, complete `… LF LF` frames out.
//!
//! Memory is one fixed buffer allocated at construction. A frame that would not
//! fit (garbage with no LF LF, a runaway line) is dropped up to the next LF LF and
//! counted; nothing grows.

/// Default capacity: an ME reply of a 1081-step sweep is about 6.9 KiB.
pub const DEFAULT_CAPACITY: usize = 8 * 1024;

/// Counters of what the splitter did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SplitterStats {
    /// Frames handed out.
    pub frames: u64,
    /// Times the buffer filled without a frame end and was dropped.
    pub overflows: u64,
    /// Bytes dropped by overflows (up to and including the next LF LF).
    pub discarded_bytes: u64,
}

#[derive(Debug)]
pub struct FrameSplitter {
    buf: Box<[u8]>,
    /// First byte not yet handed out.
    start: usize,
    /// One past the last byte received.
    end: usize,
    /// Next position at which an LF LF may begin (earlier ones were searched).
    scan_from: usize,
    /// Dropping bytes until the next LF LF after an overflow.
    discarding: bool,
    stats: SplitterStats,
}

impl FrameSplitter {
    /// A splitter whose frames may be up to `capacity` bytes (at least 16).
    pub fn new(capacity: usize) -> Self {
        FrameSplitter {
            buf: vec![0; capacity.max(16)].into_boxed_slice(),
            start: 0,
            end: 0,
            scan_from: 0,
            discarding: false,
            stats: SplitterStats::default(),
        }
    }

    pub fn stats(&self) -> SplitterStats {
        self.stats
    }

    pub fn capacity(&self) -> usize {
        self.buf.len()
    }

    /// Bytes received but not yet part of a complete frame.
    pub fn pending(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    /// Forgets any partial frame (after a reconnect or a deliberate drain).
    pub fn reset(&mut self) {
        self.start = 0;
        self.end = 0;
        self.scan_from = 0;
        self.discarding = false;
    }

    /// Free space to read into; follow with [`commit`](Self::commit). Empty only when
    /// complete frames are waiting to be taken with [`next_frame`](Self::next_frame).
    pub fn spare(&mut self) -> &mut [u8] {
        self.make_room();
        &mut self.buf[self.end..]
    }

    /// Marks `n` bytes of [`spare`](Self::spare) as received.
    pub fn commit(&mut self, n: usize) {
        self.end = (self.end + n).min(self.buf.len());
    }

    /// Copies `bytes` in and calls `on_frame` for every complete frame.
    pub fn feed(&mut self, mut bytes: &[u8], mut on_frame: impl FnMut(&[u8])) {
        while !bytes.is_empty() {
            let room = self.spare();
            let n = room.len().min(bytes.len());
            room[..n].copy_from_slice(&bytes[..n]);
            self.commit(n);
            bytes = &bytes[n..];
            while let Some(frame) = self.next_frame() {
                on_frame(frame);
            }
        }
    }

    fn make_room(&mut self) {
        if self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.scan_from = self.scan_from.saturating_sub(self.start);
            self.start = 0;
        }
        if self.end == self.buf.len() && self.find_end().is_none() {
            // Full and no frame end: drop it all but a trailing LF, which may pair
            // with the next byte to end the oversized frame.
            let keep = usize::from(self.buf[self.end - 1] == b'\n');
            self.stats.overflows += 1;
            self.stats.discarded_bytes += (self.end - keep) as u64;
            if keep == 1 {
                self.buf[0] = b'\n';
            }
            self.end = keep;
            self.scan_from = 0;
            self.discarding = true;
        }
    }

    fn find_end(&self) -> Option<usize> {
        let from = self.scan_from.max(self.start);
        self.buf
            .get(from..self.end)?
            .windows(2)
            .position(|w| w == b"\n\n")
            .map(|i| from + i)
    }

    /// The next complete frame (leading LFs stripped, ending in LF LF), if any.
    pub fn next_frame(&mut self) -> Option<&[u8]> {
        loop {
            if !self.discarding {
                while self.start < self.end && self.buf[self.start] == b'\n' {
                    self.start += 1;
                }
            }
            let Some(i) = self.find_end() else {
                self.scan_from = self.end.saturating_sub(1).max(self.start);
                return None;
            };
            let frame_start = self.start;
            self.start = i + 2;
            self.scan_from = self.start;
            if self.discarding {
                self.discarding = false;
                self.stats.discarded_bytes += (self.start - frame_start) as u64;
                continue;
            }
            self.stats.frames += 1;
            return Some(&self.buf[frame_start..self.start]);
        }
    }
}

impl Default for FrameSplitter {
    fn default() -> Self {
        Self::new(DEFAULT_CAPACITY)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames_of(s: &mut FrameSplitter, bytes: &[u8]) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        s.feed(bytes, |f| out.push(f.to_vec()));
        out
    }

    #[test]
    fn frames_split_at_lf_lf_byte_by_byte() {
        let mut s = FrameSplitter::new(64);
        let stream = b"QT\n00P\n\nBM\n02R\n\n";
        let mut out = Vec::new();
        for b in stream {
            out.extend(frames_of(&mut s, &[*b]));
        }
        assert_eq!(out, vec![b"QT\n00P\n\n".to_vec(), b"BM\n02R\n\n".to_vec()]);
        assert_eq!(s.stats().frames, 2);
    }

    #[test]
    fn leading_lfs_are_skipped() {
        let mut s = FrameSplitter::new(64);
        assert_eq!(
            frames_of(&mut s, b"\n\n\nQT\n00P\n\n"),
            vec![b"QT\n00P\n\n".to_vec()]
        );
    }

    #[test]
    fn oversized_garbage_is_dropped_until_the_next_lf_lf() {
        let mut s = FrameSplitter::new(16);
        let mut input = vec![b'x'; 40];
        input.extend_from_slice(b"\n\nQT\n00P\n\n");
        assert_eq!(frames_of(&mut s, &input), vec![b"QT\n00P\n\n".to_vec()]);
        let st = s.stats();
        assert_eq!(st.frames, 1);
        assert!(st.overflows >= 1);
        assert_eq!(st.discarded_bytes, 42);
    }

    #[test]
    fn lf_lf_straddling_an_overflow_still_ends_the_dropped_frame() {
        let mut s = FrameSplitter::new(16);
        let mut input = vec![b'x'; 15];
        input.push(b'\n');
        input.extend_from_slice(b"\nBM\n00P\n\n");
        assert_eq!(frames_of(&mut s, &input), vec![b"BM\n00P\n\n".to_vec()]);
        assert_eq!(s.stats().discarded_bytes, 17);
    }
}
