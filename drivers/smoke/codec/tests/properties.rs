//! Property tests: nothing from a wire or a file panics, memory stays
//! bounded, and framing does not depend on how the bytes were chunked.

use proptest::prelude::*;
use smokenav_smoke_codec::iio::{
    IioCalibration, IioRange, parse_offset, parse_raw, parse_scale, parse_type,
};
use smokenav_smoke_codec::line::xor_checksum;
use smokenav_smoke_codec::{
    AdcScale, BaselineMode, ChecksumPolicy, Eol, Line, Measurement, Sample, SampleValue,
    SerialDecoder, SignalConfig, SmokeProcessor, encode_sample, parse_line,
};

fn sample_strategy() -> impl Strategy<Value = Sample> {
    (
        0u8..=99,
        prop_oneof![
            (0u32..=99_999_999).prop_map(SampleValue::Counts),
            // One decimal, as the encoder writes.
            (0u32..=9_999_999).prop_map(|d| SampleValue::Millivolts(d as f32 / 10.0)),
        ],
    )
        .prop_map(|(channel, value)| Sample { channel, value })
}

fn decode_all(stream: &[u8], chunks: &[usize]) -> (Vec<Sample>, u64) {
    let mut dec = SerialDecoder::<80>::new_synced(3, ChecksumPolicy::Optional);
    let mut out = Vec::new();
    let mut rest = stream;
    let mut sizes = chunks.iter().cycle();
    while !rest.is_empty() {
        let n = (*sizes.next().unwrap_or(&1)).clamp(1, rest.len());
        let (chunk, tail) = rest.split_at(n);
        dec.feed(chunk, |item| {
            if let Ok(s) = item {
                out.push(s);
            }
        });
        rest = tail;
    }
    (out, dec.stats().parse_errors)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn arbitrary_bytes_never_panic_the_line_parser(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        let _ = parse_line(&bytes, ChecksumPolicy::Optional);
        let _ = parse_line(&bytes, ChecksumPolicy::Required);
    }

    #[test]
    fn arbitrary_stream_keeps_the_decoder_bounded_and_consistent(
        bytes in proptest::collection::vec(any::<u8>(), 0..4000),
    ) {
        let mut dec = SerialDecoder::<80>::new(0, ChecksumPolicy::Optional);
        let mut items = 0u64;
        dec.feed(&bytes, |_| items += 1);
        let st = *dec.stats();
        prop_assert!(st.samples + st.other_channel + st.comments + st.parse_errors <= st.lines);
        prop_assert_eq!(items, st.samples + st.parse_errors);
        prop_assert!(st.checksum_errors + st.overlong <= st.parse_errors);
        prop_assert!(st.lines <= bytes.len() as u64);
    }

    #[test]
    fn samples_do_not_depend_on_chunk_boundaries(
        samples in proptest::collection::vec(sample_strategy(), 1..40),
        checksum in any::<bool>(),
        crlf in any::<bool>(),
        chunks in proptest::collection::vec(1usize..23, 1..10),
    ) {
        let eol = if crlf { Eol::CrLf } else { Eol::Lf };
        let mut stream = Vec::new();
        for s in &samples {
            stream.extend_from_slice(encode_sample(&Sample { channel: 3, ..*s }, checksum, eol).unwrap().as_bytes());
        }
        let (whole, errors) = decode_all(&stream, &[stream.len()]);
        let (chunked, _) = decode_all(&stream, &chunks);
        prop_assert_eq!(errors, 0);
        prop_assert_eq!(whole.len(), samples.len());
        prop_assert_eq!(whole, chunked);
    }

    #[test]
    fn encoded_samples_parse_back(s in sample_strategy(), checksum in any::<bool>()) {
        let line = encode_sample(&s, checksum, Eol::CrLf).unwrap();
        prop_assert_eq!(parse_line(line.as_bytes(), ChecksumPolicy::Optional), Ok(Line::Sample(s)));
    }

    #[test]
    fn corrupted_checksummed_line_never_decodes_to_another_value(
        s in sample_strategy(),
        pos in any::<prop::sample::Index>(),
        byte in any::<u8>(),
    ) {
        let line = encode_sample(&s, true, Eol::Lf).unwrap();
        let mut bytes = line.as_bytes().to_vec();
        bytes.pop(); // the LF
        let i = pos.index(bytes.len());
        bytes[i] = byte;
        if let Ok(Line::Sample(got)) = parse_line(&bytes, ChecksumPolicy::Required) {
            // Only a change the checksum cannot see is possible: hex digit case.
            prop_assert_eq!(got, s);
        }
        // Sanity: the XOR of the body is what the line states.
        let text = line.as_bytes();
        let star = text.iter().position(|&b| b == b'*').unwrap();
        let stated = format!("{:02X}", xor_checksum(&text[..star]));
        prop_assert_eq!(stated.as_bytes(), &text[star + 1..star + 3]);
    }

    #[test]
    fn arbitrary_bytes_never_panic_the_iio_parsers(bytes in proptest::collection::vec(any::<u8>(), 0..100)) {
        let _ = parse_raw(&bytes);
        if let Ok(v) = parse_scale(&bytes) {
            prop_assert!(v.is_finite() && v > 0.0);
        }
        if let Ok(v) = parse_offset(&bytes) {
            prop_assert!(v.is_finite());
        }
        if let Ok(bits) = parse_type(&bytes) {
            prop_assert!((1..=32).contains(&bits));
        }
    }

    #[test]
    fn any_raw_value_either_measures_in_range_or_is_refused(raw in any::<i64>(), scale in 0.001f64..10.0) {
        let cal = IioCalibration { scale_mv: scale, offset: 0.0 };
        match cal.measure(raw, IioRange::Counts { bits: 12 }) {
            Ok(m) => prop_assert!(m.raw_counts <= 4095 && m.raw_mv >= 0.0),
            Err(_) => prop_assert!(!(0..=4095).contains(&raw)),
        }
        let vref_mv = 5000.0;
        match cal.measure(raw, IioRange::BelowReference { vref_mv }) {
            Ok(m) => prop_assert!(m.raw_mv >= 0.0 && m.raw_mv < vref_mv),
            Err(_) => prop_assert!(raw < 0 || (raw as f64) * scale >= vref_mv || raw > i64::from(u32::MAX)),
        }
        let adc = AdcScale::new(5000.0, 12).unwrap();
        prop_assert_eq!(adc.measure_counts(raw).is_ok(), (0..=4095).contains(&raw));
    }

    #[test]
    fn processor_output_is_finite_for_any_input(
        steps in proptest::collection::vec((0u64..2_000_000_000, -1e6f64..1e6, any::<bool>()), 1..300),
        inverse in any::<bool>(),
    ) {
        let cfg = SignalConfig {
            inverse,
            warmup_s: 0.5,
            baseline: BaselineMode::Calibrate { window_s: 0.3 },
            ..SignalConfig::default()
        };
        let mut p = SmokeProcessor::new(cfg, 0).unwrap();
        let mut now = 0u64;
        for (dt, mv, poll) in steps {
            now = now.saturating_add(dt);
            if poll {
                if let Some(r) = p.poll(now) {
                    prop_assert_eq!(r.level, 0.0);
                }
                continue;
            }
            let r = p.update(now, Measurement { raw_counts: 0, raw_mv: mv });
            prop_assert!(r.level.is_finite() && r.level >= 0.0);
            prop_assert!(r.filtered_mv.is_finite());
            if let Some(b) = r.baseline_mv {
                prop_assert!(b.is_finite());
            }
        }
    }
}
