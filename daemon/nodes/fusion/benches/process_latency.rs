//! End-to-end latency of the fusion process: the real `smokenav-fusion`
//! binary, inputs published from this process over the real bus.
//!
//! Per cycle (25 Hz, 16-sonar Scout profile, v2, dense and clean smoke
//! alternating every 50 cycles): laser, sonar and smoke are published; the
//! time from the smoke reading's publish call returning (the last input of
//! the set) to this process receiving the fused scan is measured. That bounds
//! from above the process's own "last input → FusedScan published" latency,
//! which it reports in its health (printed at the end). Target p99 < 1 ms.
//!
//! Run: `cargo bench -p smokenav-nodes-fusion --bench process_latency`
//! (`FUSION_BENCH_CYCLES` changes the number of cycles, default 1000).

use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_algorithms_fusion::testkit::{Room, smoke_reading, smoky_scan};
use smokenav_platform_bus::{Bus, BusOptions, Waiter, topics};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{
    FusedScan, FusionMethod, Health, LaserScan, SmokeReading, SmokeTrend, SonarRing,
};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const PERIOD: Duration = Duration::from_millis(40);
const MS: u64 = 1_000_000;

fn pct(d: &mut [Duration]) -> (f64, f64, f64) {
    d.sort_unstable();
    let at = |p: f64| d[((d.len() as f64 * p) as usize).min(d.len() - 1)].as_secs_f64() * 1e6;
    (at(0.5), at(0.99), d[d.len() - 1].as_secs_f64() * 1e6)
}

fn main() {
    let cycles: u64 = std::env::var("FUSION_BENCH_CYCLES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1000);
    let dir = tempfile::tempdir().expect("temp dir");
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../config/nomad-scout.toml");
    let mut cfg = RobotConfig::load(&src).expect("profile");
    cfg.fusion.method = FusionMethod::V2;
    // 25 Hz inputs: successive stamps 40 ms apart, so 20 ms bounds hold.
    cfg.fusion.sync.laser_min_period_s = 0.02;
    cfg.fusion.sync.sonar_min_period_s = 0.02;
    cfg.fusion.sync.smoke_min_period_s = 0.02;
    let cfg_path = dir.path().join("bench.toml");
    std::fs::write(&cfg_path, cfg.to_toml()).expect("write profile");
    let instance = format!("fusion_bench_{}", std::process::id());

    let mut child = Command::new(env!("CARGO_BIN_EXE_smokenav-fusion"))
        .args([
            "--config",
            cfg_path.to_str().unwrap_or_default(),
            "--instance",
            &instance,
        ])
        .env("RUST_LOG", "info")
        .env_remove("NOTIFY_SOCKET")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start smokenav-fusion");
    let stderr = child.stderr.take().expect("stderr");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let ready = Instant::now() + Duration::from_secs(20);
    loop {
        match rx.recv_timeout(ready.saturating_duration_since(Instant::now())) {
            Ok(l) if l.contains("fusing") => break,
            Ok(_) => {}
            Err(_) => {
                let _ = child.kill();
                panic!("smokenav-fusion did not start");
            }
        }
    }

    let bus = Bus::open(&BusOptions::new(&instance, "bench")).expect("bus");
    let fused = bus
        .subscriber::<FusedScan>(topics::FUSION_SCAN)
        .expect("sub");
    let health = bus
        .subscriber::<Health>(topics::health("fusion"))
        .expect("health");
    let mut laser = bus.publisher::<LaserScan>(topics::LASER_SCAN).expect("pub");
    let mut sonar = bus.publisher::<SonarRing>(topics::BASE_SONAR).expect("pub");
    let mut smoke = bus
        .publisher::<SmokeReading>(topics::SMOKE_LEVEL)
        .expect("pub");
    for p in [
        laser.update_connections(),
        sonar.update_connections(),
        smoke.update_connections(),
    ] {
        p.expect("connect");
    }
    let waiter = Waiter::new().expect("waiter");
    let _g = waiter.attach(&fused).expect("attach");
    let geometry = FusionPipeline::from_config(&cfg, None)
        .expect("pipeline")
        .engine()
        .geometry()
        .clone();
    let room = Room::default();

    let mut lat = Vec::with_capacity(cycles as usize);
    let mut missing = 0u64;
    let mut windows: Vec<(f32, f32, f32)> = Vec::new();
    let mut next = Instant::now();
    for k in 0..cycles {
        next += PERIOD;
        let dense = (k / 50) % 2 == 1;
        let t = monotonic_now_ns();
        let scan = if dense {
            smoky_scan(t - 2 * MS, k)
        } else {
            room.scan(t - 2 * MS, k)
        };
        let ring = room.ring(&geometry, cfg.sonar.cone_deg / 2.0, t - MS, k);
        let reading = smoke_reading(t, k, if dense { 250.0 } else { 0.0 }, SmokeTrend::Rising);
        laser.publish(&scan).expect("publish");
        sonar.publish(&ring).expect("publish");
        smoke.publish(&reading).expect("publish");
        let sent = Instant::now();
        let mut got = false;
        while !got && Instant::now() < next {
            while let Some(f) = fused.receive().expect("receive") {
                if f.scan.header.stamp_ns == t - 2 * MS {
                    lat.push(sent.elapsed());
                    got = true;
                }
            }
            if !got {
                let _ = waiter.wait(Some(next.saturating_duration_since(Instant::now())));
            }
        }
        missing += u64::from(!got);
        // The process's own view, per health window: completing input received → published.
        while let Some(h) = health.receive().expect("health") {
            if h.latency_p99_us > 0.0 {
                windows.push((h.latency_p50_us, h.latency_p99_us, h.latency_max_us));
            }
        }
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    let _ = child.kill();
    let _ = child.wait();

    println!("fusion process latency, {cycles} cycles at 25 Hz, Scout 16 sonars, 682 beams, v2");
    if lat.is_empty() {
        println!("no fused scan received: is smokenav-fusion running on instance {instance}?");
        return;
    }
    let (p50, p99, max) = pct(&mut lat);
    println!(
        "last input published → fused scan received (cross-process)  n={}  p50={p50:.1} µs  p99={p99:.1} µs  max={max:.1} µs  missing={missing}",
        lat.len()
    );
    if !windows.is_empty() {
        let worst_p99 = windows.iter().map(|w| w.1).fold(0.0f32, f32::max);
        let worst_max = windows.iter().map(|w| w.2).fold(0.0f32, f32::max);
        let mut p50s: Vec<f32> = windows.iter().map(|w| w.0).collect();
        p50s.sort_by(f32::total_cmp);
        println!(
            "in-process (health windows: {}): completing input received → published  median p50={:.0} µs  worst p99={worst_p99:.0} µs  worst max={worst_max:.0} µs",
            windows.len(),
            p50s[p50s.len() / 2]
        );
    }
}
