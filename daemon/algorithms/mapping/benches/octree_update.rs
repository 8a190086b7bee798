//! One mapping update: a 682-beam URG-04LX scan plus a 16-sonar ring (Nomad
//! Scout profile) into the Bayes octree at 5 cm (and the fused 2D grid that
//! goes with it), the robot driving through an 8 × 6 m room. Target: p99 ≤ 2 ms.
//! The comparison set (per-sensor maps as well) is printed for reference.
//!
//! Run: `cargo bench -p smokenav-algorithms-mapping --bench octree_update`

use smokenav_algorithms_mapping::{Heights, MapParams, MapSet, Mapper, Rig};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::geometry::Pose2;
use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

const WARMUP: usize = 300;
const RUNS: usize = 3_000;
const ROOM: [f64; 2] = [8.0, 6.0];

fn profile() -> RobotConfig {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../config/nomad-scout.toml");
    RobotConfig::load(&p).expect("nomad-scout profile")
}

/// Distance from `(x, y)` along `theta` to the room's walls.
fn to_wall(x: f64, y: f64, theta: f64) -> f64 {
    let (s, c) = theta.sin_cos();
    let mut t = f64::INFINITY;
    for (p, d, hi) in [(x, c, ROOM[0]), (y, s, ROOM[1])] {
        if d > 1e-12 {
            t = t.min((hi - p) / d);
        } else if d < -1e-12 {
            t = t.min(-p / d);
        }
    }
    t
}

/// This thread's CPU time: on a loaded machine (the figures below were taken
/// on 2 cores shared by several builds) wall time also counts preemption.
fn cpu() -> Duration {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .expect("thread CPU clock");
    Duration::new(t.tv_sec() as u64, t.tv_nsec() as u32)
}

fn report(name: &str, mut d: Vec<Duration>) {
    d.sort_unstable();
    let pct = |p: f64| d[((d.len() as f64 * p) as usize).min(d.len() - 1)];
    println!(
        "{name:<60} n={:<5} p50={:>7.3} ms  p99={:>7.3} ms  max={:>7.3} ms",
        d.len(),
        pct(0.50).as_secs_f64() * 1e3,
        pct(0.99).as_secs_f64() * 1e3,
        d[d.len() - 1].as_secs_f64() * 1e3
    );
}

fn bench(name: &str, set: MapSet) {
    let cfg = profile();
    let rig = Rig::from_config(&cfg, &Heights::default());
    let params = MapParams {
        grid_origin: [-1.0, -1.0],
        grid_size_m: [10.0, 8.0],
        ..MapParams::default()
    };
    let mut m = Mapper::new(rig.clone(), params, set).expect("mapper");
    let beams: Vec<f64> = (44..=725)
        .map(|s| (s as f64 - 384.0) * std::f64::consts::TAU / 1024.0)
        .collect();
    assert_eq!(beams.len(), 682);
    let mut times = Vec::with_capacity(RUNS);
    let mut cpu_times = Vec::with_capacity(RUNS);
    let mut laser = Vec::with_capacity(RUNS);
    let mut sonar = Vec::with_capacity(RUNS);
    let mut scan = Vec::with_capacity(682);
    let mut ring = Vec::with_capacity(16);
    for i in 0..WARMUP + RUNS {
        // A slow loop around the room's middle, turning as it goes.
        let t = i as f64 * 0.01;
        let pose = Pose2::new(4.0 + 2.0 * t.cos(), 3.0 + 1.5 * t.sin(), t + 1.57);
        let lp = pose.compose(&rig.laser.pose);
        scan.clear();
        scan.extend(
            beams
                .iter()
                .map(|&a| (a, Some(to_wall(lp.x, lp.y, lp.theta + a).min(5.6)))),
        );
        ring.clear();
        ring.extend(rig.sonars.iter().map(|(idx, mnt)| {
            let sp = pose.compose(&mnt.pose);
            (*idx, to_wall(sp.x, sp.y, sp.theta))
        }));
        let (t0, c0) = (Instant::now(), cpu());
        m.insert_laser(black_box(&pose), scan.iter().copied());
        let c1 = cpu();
        m.insert_sonar(black_box(&pose), ring.iter().copied());
        let (t2, c2) = (Instant::now(), cpu());
        if i >= WARMUP {
            times.push(t2 - t0);
            cpu_times.push(c2 - c0);
            laser.push(c1 - c0);
            sonar.push(c2 - c1);
        }
    }
    report(&format!("{name}, wall"), times);
    report("  the same, thread CPU time", cpu_times);
    report("  of which the scan (CPU)", laser);
    report("  of which the ring (CPU)", sonar);
    println!(
        "  octree after {} updates: {} nodes, {:.1} KiB",
        WARMUP + RUNS,
        m.octree().node_count(),
        m.octree().memory_bytes() as f64 / 1024.0
    );
}

fn main() {
    bench(
        "scan + ring -> Bayes octree + fused grid (robot)",
        MapSet::Bayes,
    );
    bench(
        "scan + ring -> all maps (rule comparison)",
        MapSet::Comparison,
    );
}
