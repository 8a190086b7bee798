//! Decode and signal-chain throughput. Run:
//! `cargo bench -p smokenav-smoke-codec --bench throughput`
//!
//! The paper's sensor produces 10 samples per second; these figures show
//! how far below a microsecond budget per sample the chain stays.

use smokenav_smoke_codec::{
    AdcScale, ChecksumPolicy, Eol, Measurement, Sample, SampleValue, SerialDecoder, SignalConfig,
    SmokeProcessor, encode_sample,
};
use std::hint::black_box;
use std::time::Instant;

fn main() {
    const LINES: usize = 200_000;
    let mut stream = Vec::with_capacity(LINES * 12);
    for k in 0..LINES {
        let s = Sample {
            channel: 0,
            value: SampleValue::Counts(600 + (k % 30) as u32),
        };
        let line = encode_sample(&s, k % 2 == 0, Eol::CrLf).unwrap_or_else(|e| panic!("{e}"));
        stream.extend_from_slice(line.as_bytes());
    }

    let mut dec = SerialDecoder::<80>::new_synced(0, ChecksumPolicy::Optional);
    let adc = AdcScale::AVR_5V_10BIT;
    let mut sum = 0.0;
    let t = Instant::now();
    for chunk in stream.chunks(64) {
        dec.feed(chunk, |item| {
            if let Ok(s) = item
                && let Ok(m) = adc.measure(s.value)
            {
                sum += m.raw_mv;
            }
        });
    }
    let el = t.elapsed();
    black_box(sum);
    println!(
        "decode: {} lines ({} bytes) in {:.1} ms = {:.0} ns/line, {:.1} MB/s",
        dec.stats().samples,
        stream.len(),
        el.as_secs_f64() * 1e3,
        el.as_nanos() as f64 / LINES as f64,
        stream.len() as f64 / el.as_secs_f64() / 1e6
    );

    let cfg = SignalConfig {
        warmup_s: 0.0,
        ..SignalConfig::default()
    };
    let mut p = SmokeProcessor::new(cfg, 0).unwrap_or_else(|e| panic!("{e}"));
    const UPDATES: u64 = 1_000_000;
    let t = Instant::now();
    let mut acc = 0.0;
    for k in 0..UPDATES {
        let r = p.update(
            k * 100_000_000,
            Measurement {
                raw_counts: 600,
                raw_mv: 3000.0 - (k % 50) as f64,
            },
        );
        acc += r.level;
    }
    let el = t.elapsed();
    black_box(acc);
    println!(
        "signal chain: {UPDATES} updates in {:.1} ms = {:.0} ns/update (2 s trend window at 10 Hz = 21-point fit)",
        el.as_secs_f64() * 1e3,
        el.as_nanos() as f64 / UPDATES as f64
    );
}
