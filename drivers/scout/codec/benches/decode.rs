//! Codec timing: splitting and decoding a Scout state reply, encoding a `vm`.
//! Run: `cargo bench -p smokenav-scout-codec` (prints ns per operation).

use smokenav_scout_codec::frame::MAX_FRAME;
use smokenav_scout_codec::{
    Command, DiffDrive, Direction, MotorStatus, PacketType, Reply, Splitter, StateReply, WheelOrder,
};
use std::hint::black_box;
use std::time::Instant;

fn main() {
    let state = StateReply {
        sonar_in: [37; 16],
        x: -1234,
        y: 5678,
        heading: 1800,
        velocity: [107, -107, 0],
        motor: MotorStatus(0b1011),
        time: 123_456,
        ..Default::default()
    };
    let mut wire = [0u8; MAX_FRAME];
    let n = state.encode(PacketType::Gs, &mut wire).unwrap();
    let wire = &wire[..n];
    let drive = DiffDrive::new(0.345, WheelOrder::RightLeft);
    let mut splitter = Splitter::new(Direction::ScoutReplies);

    const N: u32 = 1_000_000;
    // Warm-up, then measure.
    for round in 0..2 {
        let t = Instant::now();
        let mut sum = 0.0;
        for _ in 0..N {
            splitter.feed(black_box(wire));
            while let Some(Ok(f)) = splitter.next_frame() {
                if let Ok(Reply::State { state, .. }) = Reply::decode(f) {
                    sum += drive.state_si(&state).x_m;
                }
            }
        }
        let per = t.elapsed().as_nanos() as f64 / N as f64;
        if round == 1 {
            println!("split + decode + SI of a 48-byte state reply: {per:.0} ns ({sum:.0})");
        }
    }

    let mut out = [0u8; 32];
    let t = Instant::now();
    let mut total = 0usize;
    for i in 0..N {
        let v = (i % 200) as i16 - 100;
        total += Command::Velocity(black_box([v, -v, 0]))
            .encode(&mut out)
            .unwrap();
    }
    let per = t.elapsed().as_nanos() as f64 / N as f64;
    println!("encode vm: {per:.0} ns ({total} bytes)");
}
