//! Codec throughput on the AMRISim capture: framing + SIP decoding, and
//! command encoding. Prints figures; no assertions (run with
//! `cargo bench -p smokenav-pioneer-codec`).

use smokenav_pioneer_codec::capture::parse_hex_line;
use smokenav_pioneer_codec::{
    Command, Framer, OdometryIntegrator, PacketBuf, RobotPacket, decode_robot_packet, params_for,
};
use std::hint::black_box;
use std::time::Instant;

fn main() {
    let text = include_str!("../fixtures/amrisim_capture.txt");
    let rx: Vec<u8> = text
        .lines()
        .filter(|l| l.starts_with("RX"))
        .flat_map(|l| parse_hex_line(l).1)
        .collect();
    let rounds = 20_000;
    let mut framer = Framer::new();
    let mut odo = OdometryIntegrator::new(*params_for("p3dx").unwrap());
    let mut sips = 0u64;
    let start = Instant::now();
    for _ in 0..rounds {
        framer.feed(black_box(&rx), |r| {
            if let Ok(p) = r
                && let Ok(RobotPacket::Sip(s)) = decode_robot_packet(p)
            {
                black_box(odo.update(&s));
                sips += 1;
            }
        });
    }
    let dt = start.elapsed();
    let bytes = rx.len() as f64 * f64::from(rounds);
    println!(
        "frame + decode + integrate: {sips} SIPs in {dt:?}: {:.0} ns/SIP, {:.1} MB/s",
        dt.as_nanos() as f64 / sips as f64,
        bytes / dt.as_secs_f64() / 1e6
    );

    let n = 1_000_000;
    let mut p = PacketBuf::new();
    let start = Instant::now();
    for i in 0..n {
        Command::Vel(black_box((i % 600) as i16 - 300))
            .encode(&mut p)
            .unwrap();
        black_box(p.as_bytes());
    }
    let dt = start.elapsed();
    println!(
        "encode VEL: {:.1} ns/command",
        dt.as_nanos() as f64 / f64::from(n)
    );
}
