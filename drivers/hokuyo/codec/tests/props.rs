//! Property tests: arbitrary or damaged bytes never panic, memory stays bounded,
//! what a device writes decodes back exactly, and a changed data character is
//! always caught by its line checksum.

use proptest::prelude::*;
use smokenav_hokuyo_codec::{
    Command, DecodeError, FrameSplitter, ReplyWriter, decode_capture, parse_param_line,
    parse_reply, parse_request,
};

/// Exercises every decoding entry point on one frame.
fn poke(frame: &[u8]) {
    let mut ranges = [0u32; 1081];
    let mut intens = [0u32; 1081];
    if let Ok(r) = parse_reply(frame) {
        let _ = r.echo.scan();
        let _ = r.time();
        let _ = r.decode_scan(&mut ranges, &mut intens);
        let _ = r.decode_scan(&mut ranges[..10], &mut []);
        for p in r.params() {
            let _ = p;
        }
        let _ = smokenav_hokuyo_codec::VersionInfo::from_reply(&r);
        let _ = smokenav_hokuyo_codec::SensorSpec::from_reply(&r);
        let _ = smokenav_hokuyo_codec::SensorState::from_reply(&r);
        let _ = r.status.meaning(r.echo.command);
    }
}

fn md_reply(ranges: &[u32], tag: bool) -> Vec<u8> {
    let end = 44 + ranges.len() as u32 - 1;
    let echo = format!("MD0044{end:04}01000{}", if tag { ";t1" } else { "" });
    let mut out = Vec::new();
    ReplyWriter::new(&mut out)
        .echo(echo.as_bytes())
        .status(*b"99")
        .time(123_456)
        .data(3, ranges.iter().copied())
        .end();
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_in_arbitrary_chunks_never_panic_and_stay_bounded(
        bytes in proptest::collection::vec(any::<u8>(), 0..20_000),
        chunk in 1usize..700,
        cap in 16usize..4096,
    ) {
        let mut s = FrameSplitter::new(cap);
        for c in bytes.chunks(chunk) {
            s.feed(c, |f| {
                assert!(f.len() <= cap);
                poke(f);
            });
            prop_assert!(s.pending().len() <= cap);
        }
        prop_assert_eq!(s.capacity(), cap.max(16));
    }

    #[test]
    fn scip_alphabet_noise_never_panics(
        bytes in proptest::collection::vec(prop_oneof![Just(b'\n'), 0x30u8..0x70, Just(b';'), Just(b':')], 0..4000),
    ) {
        let mut s = FrameSplitter::new(8192);
        s.feed(&bytes, poke);
        poke(&bytes);
        let _ = decode_capture(&bytes, &Default::default());
        for line in bytes.split(|&b| b == b'\n') {
            let _ = parse_param_line(line, 1);
            let _ = parse_request(line);
        }
    }

    #[test]
    fn damaged_md_replies_never_panic(
        ranges in proptest::collection::vec(0u32..262_144, 1..1081),
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 1..8),
    ) {
        let mut frame = md_reply(&ranges, true);
        for (pos, byte, op) in edits {
            let i = usize::from(pos) % frame.len();
            match op {
                0 => frame[i] = byte,
                1 => frame.insert(i, byte),
                _ => { frame.remove(i); }
            }
            if frame.is_empty() { break; }
        }
        poke(&frame);
        let _ = decode_capture(&frame, &Default::default());
    }

    #[test]
    fn written_scans_decode_back_exactly(
        ranges in proptest::collection::vec(0u32..262_144, 1..1081),
        tag in any::<bool>(),
    ) {
        let frame = md_reply(&ranges, tag);
        let reply = parse_reply(&frame).unwrap();
        let mut out = [0u32; 1081];
        let h = reply.decode_scan(&mut out, &mut []).unwrap();
        prop_assert_eq!(h.timestamp, 123_456);
        prop_assert_eq!(&out[..h.count], &ranges[..]);
    }

    #[test]
    fn two_char_and_me_scans_round_trip(
        steps in proptest::collection::vec((0u32..5000, 0u32..262_144), 1..1081),
    ) {
        let end = steps.len() - 1;
        let mut ms = Vec::new();
        ReplyWriter::new(&mut ms).echo(format!("MS0000{end:04}00000").as_bytes()).status(*b"99").time(1)
            .data(2, steps.iter().map(|s| s.0)).end();
        let mut out = [0u32; 1081];
        let h = parse_reply(&ms).unwrap().decode_scan(&mut out, &mut []).unwrap();
        prop_assert_eq!(h.command, Command::Ms);
        for (got, want) in out[..h.count].iter().zip(&steps) {
            prop_assert_eq!(*got, want.0.min(4095));
        }
        let mut me = Vec::new();
        ReplyWriter::new(&mut me).echo(format!("ME0000{end:04}01000").as_bytes()).status(*b"99").time(2)
            .data(3, steps.iter().flat_map(|s| [s.0, s.1])).end();
        let mut r = [0u32; 1081];
        let mut i = [0u32; 1081];
        let h = parse_reply(&me).unwrap().decode_scan(&mut r, &mut i).unwrap();
        prop_assert_eq!(h.count, steps.len());
        for k in 0..steps.len() {
            prop_assert_eq!((r[k], i[k]), steps[k]);
        }
    }

    #[test]
    fn any_changed_data_character_fails_its_line_checksum(
        ranges in proptest::collection::vec(0u32..262_144, 1..700),
        which in any::<u16>(),
        replacement in 0x30u8..0x70,
    ) {
        let mut frame = md_reply(&ranges, false);
        // Data characters start after the echo, status and timestamp lines.
        let header = frame.iter().enumerate().filter(|&(_, &b)| b == b'\n').nth(2).unwrap().0 + 1;
        let data_positions: Vec<usize> = (header..frame.len())
            .filter(|&i| frame[i] != b'\n' && frame.get(i + 1) != Some(&b'\n'))
            .collect();
        let pos = data_positions[usize::from(which) % data_positions.len()];
        prop_assume!(frame[pos] != replacement);
        frame[pos] = replacement;
        let mut out = [0u32; 1081];
        let err = parse_reply(&frame).unwrap().decode_scan(&mut out, &mut []).unwrap_err();
        prop_assert!(matches!(err, DecodeError::Checksum { .. }), "{err:?}");
    }
}
