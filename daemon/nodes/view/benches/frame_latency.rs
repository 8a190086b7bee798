//! Bus publish → WebSocket frame latency of the real `smokenav-view`.
//!
//! This process publishes laser scans (682 beams) at 50 Hz, each stamped
//! with CLOCK_MONOTONIC right before its publish call; a WebSocket client
//! here, subscribed to `/laser/scan`, takes the stamp from each frame's CDR
//! header and measures now − stamp when the frame is read. Two runs: the
//! client alone, then with a second client that subscribes to everything
//! and never reads (its queue overflows; the first must not notice).
//!
//! Run: `cargo bench -p smokenav-nodes-view --bench frame_latency`
//! (`VIEW_BENCH_SAMPLES` per run, default 1000).

use smokenav_platform_bus::{Bus, BusOptions, topics};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{BeamReading, LaserScan};
use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, mpsc};
use std::time::Duration;
use tungstenite::client::IntoClientRequest;
use tungstenite::http::HeaderValue;
use tungstenite::{Message, WebSocket};

const PERIOD: Duration = Duration::from_millis(20);
const WARMUP: usize = 50;

fn connect(addr: &str) -> WebSocket<TcpStream> {
    let mut req = format!("ws://{addr}").into_client_request().expect("url");
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_static("foxglove.websocket.v1"),
    );
    let tcp = TcpStream::connect(addr).expect("connect");
    tcp.set_nodelay(true).expect("nodelay");
    tungstenite::client(req, tcp).expect("handshake").0
}

/// Reads serverInfo and advertise; subscribes to `topics` (all if empty).
fn subscribe(ws: &mut WebSocket<TcpStream>, topics: &[&str]) {
    let mut adv = None;
    while adv.is_none() {
        if let Message::Text(t) = ws.read().expect("read") {
            let v: serde_json::Value = serde_json::from_str(t.as_str()).expect("json");
            if v["op"] == "advertise" {
                adv = Some(v);
            }
        }
    }
    let subs: Vec<String> = adv.expect("advertise")["channels"]
        .as_array()
        .expect("channels")
        .iter()
        .filter(|c| topics.is_empty() || topics.iter().any(|t| c["topic"] == *t))
        .enumerate()
        .map(|(i, c)| format!(r#"{{"id":{i},"channelId":{}}}"#, c["id"]))
        .collect();
    ws.send(Message::text(format!(
        r#"{{"op":"subscribe","subscriptions":[{}]}}"#,
        subs.join(",")
    )))
    .expect("subscribe");
}

fn pct(v: &mut [u64]) -> (f64, f64, f64) {
    v.sort_unstable();
    let at = |p: f64| v[((v.len() as f64 * p) as usize).min(v.len() - 1)] as f64 / 1e3;
    (at(0.5), at(0.99), v[v.len() - 1] as f64 / 1e3)
}

fn run(bus: &Bus, addr: &str, samples: usize, stalled: bool) -> Vec<u64> {
    let mut ws = connect(addr);
    subscribe(&mut ws, &["/laser/scan"]);
    // Never read: its queue (and the socket) fill up and stay full.
    let _stalled = stalled.then(|| {
        let mut s = connect(addr);
        subscribe(&mut s, &[]);
        s
    });
    let stop = Arc::new(AtomicBool::new(false));
    let (tx, rx) = mpsc::channel();
    let reader = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            ws.get_ref()
                .set_read_timeout(Some(Duration::from_millis(200)))
                .expect("timeout");
            while !stop.load(Ordering::Relaxed) {
                let Ok(Message::Binary(b)) = ws.read() else {
                    continue;
                };
                let now = monotonic_now_ns();
                // opcode, subscription, log time, then the CDR: encapsulation
                // header, builtin_interfaces/Time (int32 sec, uint32 nanosec).
                if b.len() < 13 + 12 || b[0] != 1 {
                    continue;
                }
                let cdr = &b[13..];
                let sec = i32::from_le_bytes(cdr[4..8].try_into().expect("4 bytes"));
                let nsec = u32::from_le_bytes(cdr[8..12].try_into().expect("4 bytes"));
                let stamp = sec as u64 * 1_000_000_000 + u64::from(nsec);
                let _ = tx.send(now.saturating_sub(stamp));
            }
        })
    };
    let mut publisher = bus.publisher(topics::LASER_SCAN).expect("publisher");
    let mut got = Vec::with_capacity(samples);
    for n in 0..samples + WARMUP {
        publisher
            .publish_with(|s: &mut LaserScan| {
                s.header.frame_id.set("laser");
                s.count = 682;
                s.angle_min = -2.0862;
                s.angle_increment = 0.0061359;
                s.range_max = 5.6;
                for i in 0..682 {
                    s.set_beam(i, BeamReading::Range(1.0 + (n % 10) as f32 * 0.1));
                }
                s.header.stamp_ns = monotonic_now_ns();
            })
            .expect("publish");
        std::thread::sleep(PERIOD);
        while let Ok(d) = rx.try_recv() {
            if n >= WARMUP {
                got.push(d);
            }
        }
    }
    std::thread::sleep(Duration::from_millis(300));
    got.extend(rx.try_iter());
    stop.store(true, Ordering::Relaxed);
    let _ = reader.join();
    got
}

fn main() {
    let samples: usize = std::env::var("VIEW_BENCH_SAMPLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000);
    let dir = tempfile::tempdir().expect("temp dir");
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../config/nomad-scout.toml");
    let cfg = RobotConfig::load(&src).expect("profile");
    let cfg_path = dir.path().join("bench.toml");
    std::fs::write(&cfg_path, cfg.to_toml()).expect("write profile");
    let instance = format!("view_bench_{}", std::process::id());
    let mut child = Command::new(env!("CARGO_BIN_EXE_smokenav-view"))
        .args([
            "--config",
            cfg_path.to_str().unwrap_or_default(),
            "--instance",
            &instance,
            "--listen",
            "127.0.0.1:0",
        ])
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .expect("spawn smokenav-view");
    let mut lines = BufReader::new(child.stderr.take().expect("stderr")).lines();
    let addr = loop {
        let line = lines
            .next()
            .and_then(Result::ok)
            .expect("smokenav-view exited");
        if let Some(rest) = line.split("ws://").nth(1) {
            break rest
                .chars()
                .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == ':')
                .collect::<String>();
        }
    };
    // Keep draining its log so it never blocks on a full pipe.
    std::thread::spawn(move || for _ in lines.map_while(Result::ok) {});
    let bus = Bus::open(&BusOptions::new(&instance, "view-bench")).expect("bus");
    let health = bus
        .subscriber(topics::health("view"))
        .expect("health subscriber");
    println!(
        "bus publish → WebSocket frame read, /laser/scan (682 beams) at 50 Hz, {samples} samples:"
    );
    for (name, stalled) in [("one client", false), ("beside a stalled client", true)] {
        let mut d = run(&bus, &addr, samples, stalled);
        assert!(!d.is_empty(), "no frame arrived");
        let n = d.len();
        let (p50, p99, max) = pct(&mut d);
        println!("  {name:<24} n {n:>5}  p50 {p50:>7.0} µs  p99 {p99:>7.0} µs  max {max:>7.0} µs");
    }
    // The view's own count: the stalled client did overflow its queue.
    std::thread::sleep(Duration::from_millis(1500));
    let mut dropped = None;
    while let Ok(Some(h)) = health.receive() {
        dropped = h
            .metrics()
            .iter()
            .find(|m| m.name.as_str() == "dropped_total")
            .map(|m| m.value);
    }
    println!(
        "  health/view dropped_total {dropped:?} (over both runs: the stalled client did overflow its queue)"
    );
    let _ = child.kill();
    let _ = child.wait();
}
