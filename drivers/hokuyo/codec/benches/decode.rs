//! Decode time of a full 682-step URG-04LX MD scan (target < 5 µs), plus the
//! frame splitter on the same bytes. Prints figures; `cargo bench -p smokenav-hokuyo-codec`.

use smokenav_hokuyo_codec::{FrameSplitter, ReplyWriter, parse_reply};
use std::hint::black_box;
use std::time::Instant;

fn main() {
    let ranges: Vec<u32> = (0..682u32).map(|i| 20 + (i * 37) % 5580).collect();
    let mut frame = Vec::new();
    ReplyWriter::new(&mut frame)
        .echo(b"MD0044072501000")
        .status(*b"99")
        .time(11_149_560)
        .data(3, ranges.iter().copied())
        .end();
    let mut out = [0u32; 1081];

    let iterations = 200_000;
    let mut samples = Vec::with_capacity(50);
    for _ in 0..50 {
        let t = Instant::now();
        for _ in 0..iterations / 50 {
            let reply = parse_reply(black_box(&frame)).expect("valid frame");
            let h = reply.decode_scan(&mut out, &mut []).expect("valid scan");
            black_box(h);
        }
        samples.push(t.elapsed().as_nanos() as f64 / (iterations / 50) as f64);
    }
    assert_eq!(&out[..682], &ranges[..]);
    samples.sort_by(f64::total_cmp);
    println!(
        "decode full 682-step MD scan ({} bytes): median {:.2} µs, best {:.2} µs, worst batch {:.2} µs (target < 5 µs)",
        frame.len(),
        samples[25] / 1000.0,
        samples[0] / 1000.0,
        samples[49] / 1000.0
    );

    let mut splitter = FrameSplitter::default();
    let stream: Vec<u8> = frame.repeat(64);
    let t = Instant::now();
    let mut frames = 0u64;
    for _ in 0..1000 {
        for chunk in stream.chunks(512) {
            splitter.feed(black_box(chunk), |f| {
                frames += 1;
                black_box(f);
            });
        }
    }
    let per_frame = t.elapsed().as_nanos() as f64 / frames as f64;
    println!(
        "split a 682-step MD frame from a stream read in 512-byte chunks: {:.2} µs per frame",
        per_frame / 1000.0
    );
}
