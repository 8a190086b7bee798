//! One-way latency of a full `LaserScan` between two processes, the
//! subscriber woken by an event (it sleeps in epoll; no spinning).
//!
//! `cargo bench -p smokenav-platform-bus --bench latency` prints p50/p99/max. The
//! subscriber is this binary re-executed with `SMOKENAV_BENCH_ROLE=subscriber`;
//! latency is CLOCK_MONOTONIC at receive minus the stamp written just before send.

use smokenav_platform_bus::{Bus, BusOptions, Topic, WaitOutcome, Waiter};
use smokenav_shared_types::LaserScan;
use smokenav_shared_types::clock::monotonic_now_ns;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

const TOPIC: Topic<LaserScan> = Topic::new("test/latency");
const SAMPLES: u64 = 20_000;
const WARMUP: u64 = 500;
/// 2 kHz: fast enough to finish in ~10 s, slow enough that every sample
/// finds the subscriber asleep, which is the case a 10 Hz robot lives in.
const PERIOD: Duration = Duration::from_micros(500);

fn subscriber(instance: &str) {
    let bus = Bus::open(&BusOptions::new(instance, "bench-sub")).expect("bus");
    let sub = bus.subscriber(TOPIC).expect("subscriber");
    let waiter = Waiter::new().expect("waiter");
    let _g = waiter.attach(&sub).expect("attach");
    let mut hist = hdrhistogram::Histogram::<u64>::new_with_bounds(1, 10_000_000_000, 3).unwrap();
    println!("ready");
    let mut seen = 0u64;
    while seen < SAMPLES + WARMUP {
        if waiter.wait(Some(Duration::from_secs(10))).expect("wait") == WaitOutcome::TimedOut {
            break;
        }
        while let Some(s) = sub.receive().expect("receive") {
            let now = monotonic_now_ns();
            if seen >= WARMUP {
                let _ = hist.record(now.saturating_sub(s.header.stamp_ns).max(1));
            }
            seen += 1;
        }
    }
    let us = |v: u64| v as f64 / 1000.0;
    println!(
        "one-way LaserScan ({} bytes), {} samples: p50 {:.1} µs  p90 {:.1} µs  p99 {:.1} µs  p99.9 {:.1} µs  max {:.1} µs  lost {}",
        std::mem::size_of::<LaserScan>(),
        hist.len(),
        us(hist.value_at_quantile(0.5)),
        us(hist.value_at_quantile(0.9)),
        us(hist.value_at_quantile(0.99)),
        us(hist.value_at_quantile(0.999)),
        us(hist.max()),
        sub.stats().lost,
    );
}

fn main() {
    if std::env::var("SMOKENAV_BENCH_ROLE").as_deref() == Ok("subscriber") {
        subscriber(&std::env::var("SMOKENAV_INSTANCE").expect("instance"));
        return;
    }
    let instance = format!("bench_latency_{}", std::process::id());
    let mut child = Command::new(std::env::current_exe().expect("exe"))
        .env("SMOKENAV_BENCH_ROLE", "subscriber")
        .env("SMOKENAV_INSTANCE", &instance)
        .stdout(Stdio::piped())
        .spawn()
        .expect("spawn subscriber");
    let mut lines = BufReader::new(child.stdout.take().expect("stdout")).lines();
    assert_eq!(lines.next().and_then(Result::ok).as_deref(), Some("ready"));

    let bus = Bus::open(&BusOptions::new(&instance, "bench-pub")).expect("bus");
    let mut publisher = bus.publisher(TOPIC).expect("publisher");
    publisher.update_connections().expect("connect");
    let mut scan = LaserScan {
        count: 1081,
        ..Default::default()
    };
    for i in 0..1081 {
        scan.ranges[i] = 1.0 + i as f32 * 1e-3;
    }
    for _ in 0..SAMPLES + WARMUP {
        scan.header.stamp_ns = monotonic_now_ns();
        publisher.publish(&scan).expect("publish");
        std::thread::sleep(PERIOD);
    }
    for line in lines.map_while(Result::ok) {
        println!("{line}");
    }
    let _ = child.wait();
}
