//! Incremental stream splitter: bytes from a serial port or socket in, whole
//! checked payloads out.
//!
//! It holds a fixed buffer and never allocates. After a bad count or a bad
//! checksum it skips only the first header byte and searches again, so a good
//! packet that followed (or hid inside) the corrupt one is still found — ARIA
//! drops the whole declared length instead, losing the next SIP as well.

use crate::wire::{HEADER, MAX_COUNT, MAX_PACKET, MIN_COUNT, checksum};
use serde::Serialize;
use thiserror::Error;

/// Room for two maximal packets plus slack, so a packet with a corrupted
/// (too large) count never blocks the good packets that follow it.
pub const FRAMER_CAPACITY: usize = 2 * MAX_PACKET + 106;

/// Why a candidate packet was dropped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub enum FrameError {
    #[error("count byte {count} is outside {MIN_COUNT}..={MAX_COUNT}")]
    BadCount { count: u8 },
    #[error(
        "bad checksum on packet type 0x{packet_type:02X}: computed 0x{computed:04X}, packet says 0x{received:04X}"
    )]
    BadChecksum {
        packet_type: u8,
        computed: u16,
        received: u16,
    },
}

/// Counters for everything the framer saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct FramerStats {
    /// Packets with a valid checksum.
    pub packets: u64,
    pub checksum_errors: u64,
    pub bad_counts: u64,
    /// Bytes skipped while looking for `FA FB` (noise, or remains of bad packets).
    pub discarded_bytes: u64,
}

/// See the module documentation.
pub struct Framer {
    buf: [u8; FRAMER_CAPACITY],
    start: usize,
    end: usize,
    stats: FramerStats,
}

impl Default for Framer {
    fn default() -> Self {
        Self::new()
    }
}

impl Framer {
    pub const fn new() -> Self {
        Self {
            buf: [0; FRAMER_CAPACITY],
            start: 0,
            end: 0,
            stats: FramerStats {
                packets: 0,
                checksum_errors: 0,
                bad_counts: 0,
                discarded_bytes: 0,
            },
        }
    }

    pub fn stats(&self) -> FramerStats {
        self.stats
    }

    /// Bytes waiting for the rest of their packet.
    pub fn buffered(&self) -> usize {
        self.end - self.start
    }

    /// Forgets buffered bytes (after a reconnect). Counters are kept.
    pub fn clear(&mut self) {
        self.start = 0;
        self.end = 0;
    }

    /// Copies as much of `data` as fits; returns how many bytes were taken.
    /// Drain [`Framer::next_frame`] before pushing the rest.
    pub fn push(&mut self, data: &[u8]) -> usize {
        if self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let n = data.len().min(FRAMER_CAPACITY - self.end);
        if let (Some(dst), Some(src)) = (self.buf.get_mut(self.end..self.end + n), data.get(..n)) {
            dst.copy_from_slice(src);
        }
        self.end += n;
        n
    }

    /// The next packet's payload (type byte first) or the reason a candidate
    /// was dropped; `None` when more bytes are needed.
    pub fn next_frame(&mut self) -> Option<Result<&[u8], FrameError>> {
        let avail = self.buf.get(self.start..self.end)?;
        let Some(at) = avail.windows(2).position(|w| w == HEADER) else {
            // Keep a trailing 0xFA: it may be the first half of a header.
            let keep = usize::from(avail.last() == Some(&HEADER[0]));
            let drop = avail.len() - keep;
            self.stats.discarded_bytes += drop as u64;
            self.start += drop;
            return None;
        };
        self.stats.discarded_bytes += at as u64;
        self.start += at;
        let avail = self.buf.get(self.start..self.end)?;
        let count = *avail.get(2)?;
        if !(MIN_COUNT..=MAX_COUNT).contains(&count) {
            self.stats.bad_counts += 1;
            self.start += 1;
            return Some(Err(FrameError::BadCount { count }));
        }
        let total = 3 + usize::from(count);
        let packet = avail.get(..total)?;
        let payload = packet.get(3..total - 2)?;
        let received = u16::from_be_bytes([*packet.get(total - 2)?, *packet.get(total - 1)?]);
        let computed = checksum(payload);
        if computed != received {
            self.stats.checksum_errors += 1;
            self.start += 1;
            return Some(Err(FrameError::BadChecksum {
                packet_type: payload.first().copied().unwrap_or(0),
                computed,
                received,
            }));
        }
        self.stats.packets += 1;
        let (s, e) = (self.start + 3, self.start + total - 2);
        self.start += total;
        self.buf.get(s..e).map(Ok)
    }

    /// Pushes all of `data`, calling `f` for every packet or framing error.
    pub fn feed(&mut self, mut data: &[u8], mut f: impl FnMut(Result<&[u8], FrameError>)) {
        loop {
            let n = self.push(data);
            data = data.get(n..).unwrap_or(&[]);
            while let Some(r) = self.next_frame() {
                f(r);
            }
            if data.is_empty() {
                break;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::PacketBuf;
    use proptest::prelude::*;

    const ENABLE_1: [u8; 9] = [0xFA, 0xFB, 0x06, 0x04, 0x3B, 0x01, 0x00, 0x05, 0x3B];
    const SYNC0: [u8; 6] = [0xFA, 0xFB, 0x03, 0x00, 0x00, 0x00];

    fn collect(f: &mut Framer, data: &[u8]) -> (Vec<Vec<u8>>, Vec<FrameError>) {
        let mut ok = Vec::new();
        let mut err = Vec::new();
        f.feed(data, |r| match r {
            Ok(p) => ok.push(p.to_vec()),
            Err(e) => err.push(e),
        });
        (ok, err)
    }

    #[test]
    fn packet_split_byte_by_byte_decodes_once() {
        let mut f = Framer::new();
        let mut got = Vec::new();
        for b in ENABLE_1 {
            f.feed(&[b], |r| got.push(r.map(<[u8]>::to_vec)));
        }
        assert_eq!(got, vec![Ok(vec![0x04, 0x3B, 0x01, 0x00])]);
        assert_eq!(f.buffered(), 0);
    }

    #[test]
    fn noise_before_header_is_counted_and_skipped() {
        let mut f = Framer::new();
        let mut data = vec![0x00, 0xFA, 0x13, 0xFB, 0xFA];
        data.extend_from_slice(&SYNC0);
        let (ok, err) = collect(&mut f, &data);
        assert_eq!(ok, vec![vec![0x00]]);
        assert!(err.is_empty());
        assert_eq!(f.stats().discarded_bytes, 5);
    }

    #[test]
    fn corrupt_checksum_is_reported_and_next_packet_survives() {
        let mut bad = ENABLE_1;
        bad[8] ^= 0x01;
        let mut data = bad.to_vec();
        data.extend_from_slice(&SYNC0);
        let mut f = Framer::new();
        let (ok, err) = collect(&mut f, &data);
        assert_eq!(ok, vec![vec![0x00]]);
        assert_eq!(
            err,
            vec![FrameError::BadChecksum {
                packet_type: 0x04,
                computed: 0x053B,
                received: 0x053A
            }]
        );
        assert_eq!(f.stats().checksum_errors, 1);
    }

    #[test]
    fn inflated_count_does_not_swallow_following_packets() {
        // The count of the first packet was hit by noise (0x06 -> 0xC8 = 200):
        // the framer waits for 203 bytes, fails the checksum, then finds the
        // SYNC0 packets that were buffered behind it.
        let mut bad = ENABLE_1;
        bad[2] = 0xC8;
        let mut data = bad.to_vec();
        for _ in 0..40 {
            data.extend_from_slice(&SYNC0);
        }
        let mut f = Framer::new();
        let (ok, err) = collect(&mut f, &data);
        assert_eq!(ok.len(), 40);
        assert_eq!(err.len(), 1);
    }

    #[test]
    fn count_below_three_or_above_200_is_rejected() {
        let mut f = Framer::new();
        let (_, err) = collect(&mut f, &[0xFA, 0xFB, 0x02, 0x00, 0x00]);
        assert_eq!(err, vec![FrameError::BadCount { count: 2 }]);
        let (_, err) = collect(&mut f, &[0xFA, 0xFB, 201]);
        assert_eq!(err, vec![FrameError::BadCount { count: 201 }]);
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic_and_stay_bounded(data in proptest::collection::vec(any::<u8>(), 0..4096)) {
            let mut f = Framer::new();
            let mut n = 0usize;
            f.feed(&data, |r| {
                if let Ok(p) = r {
                    assert!(!p.is_empty() && p.len() <= crate::wire::MAX_PAYLOAD);
                }
                n += 1;
            });
            prop_assert!(f.buffered() <= FRAMER_CAPACITY);
            prop_assert!(f.buffered() < MAX_PACKET);
        }

        #[test]
        fn framing_resynchronises_after_garbage(
            garbage in proptest::collection::vec(any::<u8>(), 0..600),
            payloads in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 1..60), 1..8),
            chunk in 1usize..50,
        ) {
            // Garbage, then a run of good packets: every good packet must come
            // out (possibly after some error reports caused by the garbage),
            // whatever the garbage was and however the stream is chunked.
            // A 0xFA 0xFB in the garbage may open a false packet that eats the
            // start of the good ones, so we put one maximal packet's worth of
            // filler zeros between them: false packets are at most 203 bytes.
            let mut stream = garbage.clone();
            stream.extend(std::iter::repeat_n(0u8, MAX_PACKET));
            for p in &payloads {
                let mut b = PacketBuf::new();
                b.set_payload(p).unwrap();
                stream.extend_from_slice(b.as_bytes());
            }
            let mut f = Framer::new();
            let mut got = Vec::new();
            for c in stream.chunks(chunk) {
                f.feed(c, |r| if let Ok(p) = r { got.push(p.to_vec()) });
            }
            // Garbage can itself contain a valid packet by chance; the good ones
            // are the last `payloads.len()` decoded.
            prop_assert!(got.len() >= payloads.len());
            prop_assert_eq!(&got[got.len() - payloads.len()..], &payloads[..]);
        }
    }
}
