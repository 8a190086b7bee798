//! Packet framing: `01 | len_lo len_hi | type | data… | chk | 5C`.
//!
//! `len` counts the type byte, the data and the checksum (so `len = data + 2`);
//! `chk` is the sum of every byte from the `01` to the last data byte, mod 256
//! (Nomadic's `Write_Pkg`/`Read_Pkg`).

use crate::PacketType;

/// First byte of every packet.
pub const START: u8 = 0x01;
/// Last byte of every packet (`\`).
pub const END: u8 = 0x5C;
/// Largest `len` we accept. Nomadic's `Write_Pkg` only looks at `len_lo`, and
/// no packet the Scout exchanges comes near 255, so a larger length is noise.
pub const MAX_LEN: usize = 255;
/// Largest data part of a packet.
pub const MAX_DATA: usize = MAX_LEN - 2;
/// Largest packet on the wire: start, two length bytes, `len` bytes, end.
pub const MAX_FRAME: usize = 3 + MAX_LEN + 1;
/// Bytes of framing around the data: start, len (2), type, chk, end.
pub const OVERHEAD: usize = 6;

/// One checked packet: its type byte and its data (without type and checksum).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    pub ptype: u8,
    pub data: &'a [u8],
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    #[error("packet data of {len} bytes exceeds the {max}-byte limit")]
    DataTooLong { len: usize, max: usize },
    #[error("output buffer of {have} bytes cannot hold the {need}-byte packet")]
    BufferTooSmall { need: usize, have: usize },
    #[error("{value} does not fit a sign-magnitude 16-bit integer (|n| <= 32767)")]
    OutOfRange { value: i32 },
}

/// Why bytes from the wire were not a packet. The splitter has already dropped
/// the offending bytes when it reports one of these.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("skipped {skipped} bytes that were not the 0x01 start of a packet")]
    Garbage { skipped: usize },
    #[error("packet length {len} is outside 2..={max}")]
    BadLength { len: usize, max: usize },
    #[error("packet type {ptype} is not a Nomadic packet type")]
    UnknownType { ptype: u8 },
    #[error("packet type {ptype} must have length {expected}, got {got}")]
    UnexpectedLength {
        ptype: u8,
        expected: usize,
        got: usize,
    },
    #[error("checksum mismatch: computed {expected:#04x}, packet says {got:#04x}")]
    BadChecksum { expected: u8, got: u8 },
    #[error("packet end byte should be 0x5c, got {got:#04x}")]
    BadEnd { got: u8 },
    #[error("packet incomplete: need {need} bytes, have {have}")]
    Incomplete { need: usize, have: usize },
}

/// Sum of `bytes` mod 256: the Nomadic checksum.
pub fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |acc, &b| acc.wrapping_add(b))
}

/// Writes a complete packet of type `ptype` carrying `data` into `out`;
/// returns its length.
pub fn encode_frame(ptype: u8, data: &[u8], out: &mut [u8]) -> Result<usize, EncodeError> {
    if data.len() > MAX_DATA {
        return Err(EncodeError::DataTooLong {
            len: data.len(),
            max: MAX_DATA,
        });
    }
    let total = data.len() + OVERHEAD;
    let have = out.len();
    let Some(out) = out.get_mut(..total) else {
        return Err(EncodeError::BufferTooSmall { need: total, have });
    };
    let len = (data.len() + 2) as u16;
    let [len_lo, len_hi] = len.to_le_bytes();
    out[0] = START;
    out[1] = len_lo;
    out[2] = len_hi;
    out[3] = ptype;
    out[4..4 + data.len()].copy_from_slice(data);
    let chk_at = 4 + data.len();
    out[chk_at] = checksum(&out[..chk_at]);
    out[chk_at + 1] = END;
    Ok(total)
}

/// Which side's packets a splitter reads. Lengths are fixed per type in each
/// direction, which lets the splitter reject a false start byte at once
/// instead of waiting for a length's worth of bytes that never come.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Replies from a Scout (fixed sensor mask: state packets of 44).
    ScoutReplies,
    /// Commands from a host.
    Commands,
}

impl Direction {
    /// The `len` a packet of this type must have, or None when it varies.
    pub fn expected_len(self, ptype: PacketType) -> Option<usize> {
        match self {
            Direction::ScoutReplies => {
                if ptype.replies_with_state() {
                    Some(crate::STATE_LEN)
                } else {
                    None
                }
            }
            Direction::Commands => ptype.command_len(),
        }
    }
}

/// Parses one packet at the start of `bytes`; returns it and the bytes used.
/// For a byte stream use [`Splitter`].
pub fn parse_frame(bytes: &[u8], dir: Direction) -> Result<(Frame<'_>, usize), FrameError> {
    match bytes.first() {
        None => return Err(FrameError::Incomplete { need: 4, have: 0 }),
        Some(&START) => {}
        Some(_) => {
            let skipped = bytes
                .iter()
                .position(|&b| b == START)
                .unwrap_or(bytes.len());
            return Err(FrameError::Garbage { skipped });
        }
    }
    let (Some(&len_lo), Some(&len_hi), Some(&ptype)) = (bytes.get(1), bytes.get(2), bytes.get(3))
    else {
        return Err(FrameError::Incomplete {
            need: 4,
            have: bytes.len(),
        });
    };
    let len = u16::from_le_bytes([len_lo, len_hi]) as usize;
    if !(2..=MAX_LEN).contains(&len) {
        return Err(FrameError::BadLength { len, max: MAX_LEN });
    }
    let Some(known) = PacketType::from_u8(ptype) else {
        return Err(FrameError::UnknownType { ptype });
    };
    if let Some(expected) = dir.expected_len(known)
        && expected != len
    {
        return Err(FrameError::UnexpectedLength {
            ptype,
            expected,
            got: len,
        });
    }
    let total = 3 + len + 1;
    let Some(packet) = bytes.get(..total) else {
        return Err(FrameError::Incomplete {
            need: total,
            have: bytes.len(),
        });
    };
    let chk_at = 3 + len - 1;
    let expected = checksum(&packet[..chk_at]);
    if packet[chk_at] != expected {
        return Err(FrameError::BadChecksum {
            expected,
            got: packet[chk_at],
        });
    }
    if packet[total - 1] != END {
        return Err(FrameError::BadEnd {
            got: packet[total - 1],
        });
    }
    Ok((
        Frame {
            ptype,
            data: &packet[4..chk_at],
        },
        total,
    ))
}

/// Counters of what a [`Splitter`] found in the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SplitterStats {
    pub frames: u64,
    pub garbage_bytes: u64,
    pub checksum_errors: u64,
    pub end_errors: u64,
    pub length_errors: u64,
    pub unknown_types: u64,
}

impl SplitterStats {
    /// Packets rejected after a start byte (excludes plain garbage bytes).
    pub fn bad_frames(&self) -> u64 {
        self.checksum_errors + self.end_errors + self.length_errors + self.unknown_types
    }
}

/// Totals over several splitters (a driver opens a fresh one per link).
impl std::ops::AddAssign for SplitterStats {
    fn add_assign(&mut self, o: SplitterStats) {
        self.frames += o.frames;
        self.garbage_bytes += o.garbage_bytes;
        self.checksum_errors += o.checksum_errors;
        self.end_errors += o.end_errors;
        self.length_errors += o.length_errors;
        self.unknown_types += o.unknown_types;
    }
}

const CAPACITY: usize = 2 * MAX_FRAME;

/// Incremental packet splitter with a fixed buffer. Feed it bytes as they
/// arrive and drain [`Splitter::next_frame`] until it returns `None`. After a
/// bad packet it drops only the false start byte and searches again, so a
/// real packet hidden behind garbage is still found.
#[derive(Debug, Clone)]
pub struct Splitter {
    buf: [u8; CAPACITY],
    head: usize,
    len: usize,
    dir: Direction,
    stats: SplitterStats,
}

impl Splitter {
    pub fn new(dir: Direction) -> Self {
        Self {
            buf: [0; CAPACITY],
            head: 0,
            len: 0,
            dir,
            stats: SplitterStats::default(),
        }
    }

    pub fn stats(&self) -> SplitterStats {
        self.stats
    }

    /// Bytes waiting for the rest of their packet.
    pub fn pending(&self) -> usize {
        self.len - self.head
    }

    /// Drops buffered bytes (e.g. before a new request, as Nomadic's host
    /// library flushes the line). Counters are kept.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    /// Copies as much of `input` as fits and returns how many bytes were
    /// taken. After [`Splitter::next_frame`] has returned `None` at least
    /// `MAX_FRAME` bytes always fit.
    pub fn feed(&mut self, input: &[u8]) -> usize {
        if self.head > 0 {
            self.buf.copy_within(self.head..self.len, 0);
            self.len -= self.head;
            self.head = 0;
        }
        let n = input.len().min(CAPACITY - self.len);
        self.buf[self.len..self.len + n].copy_from_slice(&input[..n]);
        self.len += n;
        n
    }

    /// The next packet or framing error, or `None` when more bytes are needed.
    pub fn next_frame(&mut self) -> Option<Result<Frame<'_>, FrameError>> {
        let start = self.head;
        let pending = &self.buf[start..self.len];
        if pending.is_empty() {
            return None;
        }
        match parse_frame(pending, self.dir) {
            Ok((_, used)) => {
                self.head += used;
                self.stats.frames += 1;
                // Re-borrow immutably: the frame lies in bytes already consumed.
                let packet = &self.buf[start..start + used];
                Some(Ok(Frame {
                    ptype: packet[3],
                    data: &packet[4..used - 2],
                }))
            }
            Err(FrameError::Incomplete { .. }) => None,
            Err(e) => {
                match e {
                    FrameError::Garbage { skipped } => {
                        self.head += skipped;
                        self.stats.garbage_bytes += skipped as u64;
                    }
                    _ => {
                        // Drop the false start byte only; the next 0x01 may be real.
                        self.head += 1;
                        match e {
                            FrameError::BadChecksum { .. } => self.stats.checksum_errors += 1,
                            FrameError::BadEnd { .. } => self.stats.end_errors += 1,
                            FrameError::UnknownType { .. } => self.stats.unknown_types += 1,
                            _ => self.stats.length_errors += 1,
                        }
                    }
                }
                Some(Err(e))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Command, Reply, StateReply};
    use proptest::prelude::*;

    const GS: [u8; 6] = [0x01, 0x02, 0x00, 0x07, 0x0A, 0x5C];
    const ST: [u8; 6] = [0x01, 0x02, 0x00, 0x09, 0x0C, 0x5C];

    fn state_packet(x: i16) -> Vec<u8> {
        let s = StateReply {
            x,
            sonar_in: [0x01; 16], // start bytes inside the data must not confuse the splitter
            ..Default::default()
        };
        let mut out = [0u8; MAX_FRAME];
        let n = s.encode(PacketType::Gs, &mut out).unwrap();
        out[..n].to_vec()
    }

    fn drain(s: &mut Splitter) -> (Vec<(u8, Vec<u8>)>, Vec<FrameError>) {
        let mut frames = Vec::new();
        let mut errors = Vec::new();
        while let Some(r) = s.next_frame() {
            match r {
                Ok(f) => frames.push((f.ptype, f.data.to_vec())),
                Err(e) => errors.push(e),
            }
        }
        (frames, errors)
    }

    #[test]
    fn gs_vector_parses_as_empty_get_state() {
        let (frame, used) = parse_frame(&GS, Direction::Commands).unwrap();
        assert_eq!(used, 6);
        assert_eq!(frame.ptype, 7);
        assert!(frame.data.is_empty());
    }

    #[test]
    fn packet_split_byte_by_byte_decodes() {
        let wire = state_packet(-321);
        let mut s = Splitter::new(Direction::ScoutReplies);
        let mut got = Vec::new();
        for b in &wire {
            assert_eq!(s.feed(std::slice::from_ref(b)), 1);
            let (f, e) = drain(&mut s);
            assert!(e.is_empty());
            got.extend(f);
        }
        assert_eq!(got.len(), 1);
        let frame = Frame {
            ptype: got[0].0,
            data: &got[0].1,
        };
        let Reply::State { state, .. } = Reply::decode(frame).unwrap() else {
            panic!("not a state reply");
        };
        assert_eq!(state.x, -321);
    }

    #[test]
    fn garbage_before_packet_is_skipped_and_counted() {
        let mut wire = vec![0xFF, 0x00, 0x5C, 0x42];
        wire.extend_from_slice(&GS);
        let mut s = Splitter::new(Direction::Commands);
        s.feed(&wire);
        let (frames, errors) = drain(&mut s);
        assert_eq!(frames, vec![(7, vec![])]);
        assert_eq!(errors, vec![FrameError::Garbage { skipped: 4 }]);
        assert_eq!(s.stats().garbage_bytes, 4);
        assert_eq!(s.stats().frames, 1);
    }

    #[test]
    fn false_start_byte_resynchronises_on_next_packet() {
        // A stray 0x01 whose "length" would swallow the real packet: the type
        // check rejects it at once, so the gs behind it is found.
        let mut wire = vec![0x01, 0x02, 0x00];
        wire.extend_from_slice(&GS);
        let mut s = Splitter::new(Direction::Commands);
        s.feed(&wire);
        let (frames, errors) = drain(&mut s);
        assert_eq!(frames, vec![(7, vec![])]);
        assert!(!errors.is_empty());
    }

    #[test]
    fn corrupted_checksum_drops_only_that_packet() {
        let mut bad = ST;
        bad[4] ^= 0x10;
        let mut wire = bad.to_vec();
        wire.extend_from_slice(&GS);
        let mut s = Splitter::new(Direction::Commands);
        s.feed(&wire);
        let (frames, errors) = drain(&mut s);
        assert_eq!(frames, vec![(7, vec![])]);
        assert_eq!(
            errors[0],
            FrameError::BadChecksum {
                expected: 0x0C,
                got: 0x1C
            }
        );
        assert_eq!(s.stats().checksum_errors, 1);
    }

    #[test]
    fn missing_end_byte_is_rejected() {
        let mut bad = GS;
        bad[5] = 0x00;
        assert_eq!(
            parse_frame(&bad, Direction::Commands),
            Err(FrameError::BadEnd { got: 0 })
        );
    }

    #[test]
    fn state_reply_with_wrong_length_is_rejected_at_the_header() {
        // A gs reply must be 44 long with the Scout's fixed mask.
        assert_eq!(
            parse_frame(&[0x01, 0x02, 0x00, 0x07], Direction::ScoutReplies),
            Err(FrameError::UnexpectedLength {
                ptype: 7,
                expected: 44,
                got: 2
            })
        );
        assert_eq!(
            parse_frame(&[0x01, 0x00, 0x01, 0x07], Direction::ScoutReplies),
            Err(FrameError::BadLength { len: 256, max: 255 })
        );
        assert_eq!(
            parse_frame(&[0x01, 0x02, 0x00, 0x63], Direction::ScoutReplies),
            Err(FrameError::UnknownType { ptype: 0x63 })
        );
    }

    #[test]
    fn back_to_back_packets_in_one_read_all_decode() {
        let mut wire = Vec::new();
        for x in [-5, 0, 5] {
            wire.extend(state_packet(x));
        }
        let mut s = Splitter::new(Direction::ScoutReplies);
        assert_eq!(s.feed(&wire), wire.len());
        let (frames, errors) = drain(&mut s);
        assert!(errors.is_empty());
        assert_eq!(frames.len(), 3);
    }

    #[test]
    fn clear_drops_a_partial_packet() {
        let wire = state_packet(1);
        let mut s = Splitter::new(Direction::ScoutReplies);
        s.feed(&wire[..10]);
        assert!(s.next_frame().is_none());
        assert_eq!(s.pending(), 10);
        s.clear();
        assert_eq!(s.pending(), 0);
        s.feed(&wire);
        assert!(matches!(s.next_frame(), Some(Ok(_))));
    }

    #[test]
    fn encode_rejects_oversized_data_and_small_buffers() {
        let mut out = [0u8; 8];
        assert_eq!(
            encode_frame(7, &[0; 3], &mut out),
            Err(EncodeError::BufferTooSmall { need: 9, have: 8 })
        );
        let mut big = [0u8; 400];
        assert_eq!(
            encode_frame(0x80, &[0; 254], &mut big),
            Err(EncodeError::DataTooLong { len: 254, max: 253 })
        );
        assert_eq!(encode_frame(0x80, &[7; 253], &mut big), Ok(259));
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic_the_splitter(
            chunks in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..300), 0..20),
            replies in any::<bool>(),
        ) {
            let dir = if replies { Direction::ScoutReplies } else { Direction::Commands };
            let mut s = Splitter::new(dir);
            for chunk in &chunks {
                let mut rest = &chunk[..];
                while !rest.is_empty() {
                    let n = s.feed(rest);
                    rest = &rest[n..];
                    while let Some(r) = s.next_frame() {
                        if let Ok(f) = r {
                            let _ = Reply::decode(f);
                            let _ = Command::decode(f);
                        }
                    }
                    // Bounded memory: never more than one packet waits.
                    prop_assert!(s.pending() < MAX_FRAME);
                }
            }
        }

        #[test]
        fn arbitrary_frames_never_panic_the_decoders(ptype in any::<u8>(), data in proptest::collection::vec(any::<u8>(), 0..64)) {
            let f = Frame { ptype, data: &data };
            let _ = Reply::decode(f);
            let _ = Command::decode(f);
        }

        #[test]
        fn a_packet_after_garbage_is_always_found(
            garbage in proptest::collection::vec(any::<u8>(), 0..200),
            x in -32767i16..=32767,
        ) {
            let mut wire = garbage.clone();
            wire.extend(state_packet(x));
            let mut s = Splitter::new(Direction::ScoutReplies);
            let mut found = Vec::new();
            let mut rest = &wire[..];
            while !rest.is_empty() {
                let n = s.feed(rest);
                rest = &rest[n..];
                while let Some(r) = s.next_frame() {
                    if let Ok(f) = r && let Ok(Reply::State { state, .. }) = Reply::decode(f) {
                        found.push(state.x);
                    }
                }
            }
            // Garbage might itself contain a valid packet (vanishingly rare);
            // the real one must be the last thing decoded.
            prop_assert_eq!(found.last().copied(), Some(x));
        }

        #[test]
        fn every_state_reply_round_trips(
            sonar in proptest::array::uniform16(any::<u8>()),
            bumpers in 0u32..(1 << 24),
            words in proptest::array::uniform8(-32767i16..=32767),
            motor in any::<u8>(), time in any::<u32>(), cpu in any::<u8>(), mot in any::<u8>(),
        ) {
            let s = StateReply {
                sonar_in: sonar, bumpers, x: words[0], y: words[1], heading: words[2], turret: words[3],
                velocity: [words[4], words[5], words[6]], compass: words[7],
                motor: crate::MotorStatus(motor), time, cpu_voltage_raw: cpu, motor_voltage_raw: mot,
            };
            let mut out = [0u8; MAX_FRAME];
            let n = s.encode(PacketType::St, &mut out).unwrap();
            let (f, _) = parse_frame(&out[..n], Direction::ScoutReplies).unwrap();
            prop_assert_eq!(Reply::decode(f).unwrap(), Reply::State { to: PacketType::St, state: s });
        }
    }
}
