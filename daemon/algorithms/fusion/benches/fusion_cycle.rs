//! One fusion cycle: 16-sonar ring (Nomad Scout profile), 682-beam URG-04LX
//! scan, SmokeNav v2 (and v1 for comparison). Target: p99 < 100 µs for v2.
//!
//! Run: `cargo bench -p smokenav-algorithms-fusion --bench fusion_cycle`

use smokenav_algorithms_fusion::engine::FusionEngine;
use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_algorithms_fusion::testkit::{Room, smoke_reading, smoky_scan};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::{FusedScan, FusionMethod, SmokeTrend};
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

const WARMUP: usize = 2_000;
const RUNS: usize = 20_000;

fn profile() -> RobotConfig {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../config/nomad-scout.toml");
    RobotConfig::load(&p).expect("nomad-scout profile")
}

fn report(name: &str, mut d: Vec<Duration>) {
    d.sort_unstable();
    let pct = |p: f64| d[((d.len() as f64 * p) as usize).min(d.len() - 1)];
    println!(
        "{name:<44} n={:<6} p50={:>7.2} µs  p99={:>7.2} µs  max={:>8.2} µs",
        d.len(),
        pct(0.50).as_secs_f64() * 1e6,
        pct(0.99).as_secs_f64() * 1e6,
        d[d.len() - 1].as_secs_f64() * 1e6
    );
}

fn bench_step(name: &str, method: FusionMethod, dense: bool) {
    let cfg = profile();
    let mut engine = FusionEngine::from_config(&cfg, Some(method)).expect("engine");
    let room = Room::default();
    let ring = room.ring(engine.geometry(), 10.0, 3, 0);
    assert_eq!(ring.len(), 16);
    let (scan, level) = if dense {
        (smoky_scan(1, 0), 250.0)
    } else {
        (room.scan(1, 0), 0.0)
    };
    assert_eq!(scan.len(), 682);
    let smoke = smoke_reading(5, 0, level, SmokeTrend::Rising);
    let mut out: Box<FusedScan> = Box::default();
    let mut times = Vec::with_capacity(RUNS);
    for i in 0..WARMUP + RUNS {
        let t0 = Instant::now();
        let r = engine.step(
            Some(black_box(&scan)),
            Some(black_box(&ring)),
            Some(black_box(&smoke)),
            &mut out,
        );
        let dt = t0.elapsed();
        black_box(&r);
        if i >= WARMUP {
            times.push(dt);
        }
    }
    if dense && method != FusionMethod::LaserOnly {
        assert!(out.sonar_usage() > 0.9, "dense smoke must use the sonar");
    }
    report(name, times);
}

/// The whole cycle the process runs per scan: three pushes through the
/// synchroniser (the last one completes the set) plus the fusion step.
fn bench_pipeline(name: &str, method: FusionMethod) {
    let cfg = profile();
    let mut p = FusionPipeline::from_config(&cfg, Some(method)).expect("pipeline");
    let room = Room::default();
    let geometry = p.engine().geometry().clone();
    let mut times = Vec::with_capacity(RUNS);
    let mut outputs = 0u64;
    for k in 0..(WARMUP + RUNS) as u64 {
        let t = 1_000_000_000 + k * 100_000_000;
        let scan = smoky_scan(t, k);
        let ring = room.ring(&geometry, 10.0, t + 1_000_000, k);
        let smoke = smoke_reading(t + 2_000_000, k, 250.0, SmokeTrend::Rising);
        let mut emit = |f: &FusedScan, _: &_| {
            black_box(f);
            outputs += 1;
        };
        let t0 = Instant::now();
        p.push_laser(&scan, t, &mut emit);
        p.push_sonar(&ring, t + 1_000_000, &mut emit);
        p.push_smoke(&smoke, t + 2_000_000, &mut emit);
        let dt = t0.elapsed();
        if k as usize >= WARMUP {
            times.push(dt);
        }
    }
    assert_eq!(
        outputs,
        (WARMUP + RUNS) as u64,
        "every set must go out when its last member arrives"
    );
    report(name, times);
}

fn main() {
    println!("fusion cycle, 16 sonars (Scout), 682 beams (URG-04LX)");
    bench_step(
        "step v2, dense smoke (all sections sonar)",
        FusionMethod::V2,
        true,
    );
    bench_step(
        "step v2, clean air (laser untouched)",
        FusionMethod::V2,
        false,
    );
    bench_step("step v1, dense smoke", FusionMethod::V1, true);
    bench_step("step laser-only", FusionMethod::LaserOnly, true);
    bench_pipeline("sync (3 pushes) + step v2, dense smoke", FusionMethod::V2);
}
