//! The live path end to end: from the last sensor input of a scan to its
//! `slam/pose`, through the real `smokenav-fusion` and `smokenav-slam`
//! processes on the bus, once per SLAM back-end (rbpf, then graph).
//!
//! The inputs are what the drivers publish on the bundled dense-smoke trial
//! (`r32-dense-crossing`: the simulator through the drivers' own cores, as
//! `smokenav-lab demo --fast` records it), replayed onto the bus in real
//! time with their stamps moved onto the bus clock. This process also
//! subscribes to `fusion/scan` (which names the sonar ring and smoke reading
//! each scan was fused with) and `slam/pose`: a scan's last input is the
//! latest-published of its laser scan, that sonar ring, that smoke reading
//! and the first odometry at or after its stamp (the SLAM pipeline pairs a
//! scan with odometry interpolated to its stamp) — of those published before
//! its pose arrived. Latency = pose received − that input's publish call.
//! A scan whose pose never arrives (within 1 s) is a miss.
//!
//! Run: `cargo bench -p smokenav-sim-lab --bench live_path` (builds the two
//! processes in the same profile first; `LIVE_BENCH_SECONDS` of the trial
//! per back-end, default 60; `LIVE_BENCH_BACKENDS`, default `rbpf/1,rbpf,graph`:
//! `NAME/N` runs that back-end with `[slam] threads = N`, so the particle
//! filter on one thread and on its default pool, one per core, are measured
//! side by side in one run; `graph+G` runs the graph back-end going on from
//! the graph `LIVE_BENCH_LOAD_GRAPH` names (`smokenav slam --save-graph`,
//! e.g. all of MIT CSAIL), so the trial's scans are mapped beside a large
//! map, which the SLAM process re-draws every second while they come).
//! Each run prints what the SLAM process's health said of its maps last:
//! how long one took to draw, the loop's own share, and how many were late.

mod support;

use smokenav_platform_bus::{Bus, BusOptions, Waiter, topics};
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_sim_link::DirectDrivers;
use smokenav_sim_link::DirectMessage;
use smokenav_sim_world::{Scenario, StepOutput, World};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

/// Stamp of sim time 0 in the generated stream (moved onto the bus clock when replayed).
const T0_NS: u64 = 1_000_000_000;
/// Scans at the start left out of the figures (the first map, page faults).
const WARMUP_SCANS: usize = 20;

/// Builds the two processes in this bench's profile, so it never runs stale ones.
fn build_processes() -> (PathBuf, PathBuf) {
    support::build(&["smokenav-nodes-fusion", "smokenav-nodes-slam"]);
    (
        support::profile_dir().join("smokenav-fusion"),
        support::profile_dir().join("smokenav-slam"),
    )
}

/// The drivers' messages of `seconds` of the trial, in publish order, with their publish times (ns from T0).
fn generate(scenario: &Scenario, profile: &RobotConfig, seconds: f64) -> Vec<(u64, DirectMessage)> {
    let mut drivers = DirectDrivers::new(profile, T0_NS).expect("drivers");
    let mut world = World::new(scenario.clone()).expect("world");
    let end = ((seconds.min(scenario.duration_s)) * 1e9) as u64;
    let mut out = StepOutput::default();
    let mut msgs = Vec::new();
    while world.time_ns() < end {
        out.clear();
        let step = Duration::from_nanos((end - world.time_ns()).min(100_000_000));
        world.step_into(step, &mut out);
        drivers.convert(&out, |t, m| msgs.push((t - T0_NS.min(t), m)));
    }
    msgs.sort_by_key(|(t, _)| *t);
    msgs
}

fn stamp_of(m: &DirectMessage) -> u64 {
    m.header().stamp_ns
}

fn shift(m: &mut DirectMessage, offset: u64) {
    let h = match m {
        DirectMessage::Laser(s) => &mut s.header,
        DirectMessage::Odometry(o) => &mut o.header,
        DirectMessage::Sonar(r) => &mut r.header,
        DirectMessage::Smoke(s) => &mut s.header,
    };
    h.stamp_ns = h.stamp_ns - T0_NS.min(h.stamp_ns) + offset;
}

struct Figures {
    latencies_us: Vec<u64>,
    scans: usize,
    misses: usize,
    fused: usize,
    slam_skipped: u64,
    /// The SLAM process's last health: `map_draw_ms`, `map_export_ms`, `map_exports_late`.
    maps: [f64; 3],
}

fn spawn(bin: &Path, args: &[&str], instance: &str) -> Child {
    smokenav_platform_runtime::launch::command(bin, instance)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {}: {e}", bin.display()))
}

fn run_backend(
    bins: &(PathBuf, PathBuf),
    profile_path: &Path,
    backend: &str,
    load_graph: Option<&str>,
    stream: &[(u64, DirectMessage)],
) -> Figures {
    // One bus per run: `rbpf/1` and `rbpf` differ only in their profile's file.
    let stem = profile_path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("robot");
    let loaded = if load_graph.is_some() { "_loaded" } else { "" };
    let instance = format!("live_bench_{}_{backend}{loaded}_{stem}", std::process::id());
    let bus = Bus::open(&BusOptions::new(&instance, "live-bench")).expect("bus");
    let mut laser = bus.publisher(topics::LASER_SCAN).expect("publisher");
    let mut sonar = bus.publisher(topics::BASE_SONAR).expect("publisher");
    let mut smoke = bus.publisher(topics::SMOKE_LEVEL).expect("publisher");
    let mut odom = bus.publisher(topics::BASE_ODOM).expect("publisher");
    let poses = bus.subscriber(topics::SLAM_POSE).expect("subscriber");
    let fused = bus.subscriber(topics::FUSION_SCAN).expect("subscriber");
    let health = [
        bus.subscriber(topics::health("fusion")).expect("health"),
        bus.subscriber(topics::health("slam")).expect("health"),
    ];
    let cfg = profile_path.to_str().expect("utf-8 path");
    let mut slam_args = vec!["--config", cfg, "--backend", backend];
    if let Some(g) = load_graph {
        slam_args.extend(["--load-graph", g]);
    }
    let mut children = vec![
        spawn(&bins.0, &["--config", cfg], &instance),
        spawn(&bins.1, &slam_args, &instance),
    ];
    // Ready: each process has published its health (its subscribers are up by then).
    let ready_by = Instant::now() + Duration::from_secs(60);
    let mut seen = [false; 2];
    while !seen.iter().all(|&s| s) {
        assert!(
            Instant::now() < ready_by,
            "fusion/slam not ready after 60 s"
        );
        for (i, h) in health.iter().enumerate() {
            while let Ok(Some(_)) = h.receive() {
                seen[i] = true;
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(500));
    for p in [
        laser.update_connections(),
        sonar.update_connections(),
        smoke.update_connections(),
        odom.update_connections(),
    ] {
        p.expect("connections");
    }

    let waiter = Waiter::new().expect("waiter");
    let _g1 = waiter.attach(&poses).expect("attach");
    let _g2 = waiter.attach(&fused).expect("attach");
    let start = monotonic_now_ns() + 200_000_000;
    // Publish time of each message, by (kind, stamp): the stamps are unique per kind.
    let mut sent: HashMap<(u8, u64), u64> = HashMap::with_capacity(stream.len());
    // Per scan stamp: (sonar stamp, smoke stamp) it was fused with.
    let mut fused_with: HashMap<u64, (u64, u64)> = HashMap::new();
    let mut received: HashMap<u64, u64> = HashMap::new();
    let mut odom_stamps: Vec<u64> = Vec::new();
    let mut scan_stamps: Vec<u64> = Vec::new();
    let mut slam_skipped = 0;
    let drain = |fused_with: &mut HashMap<u64, (u64, u64)>,
                 received: &mut HashMap<u64, u64>,
                 slam_skipped: &mut u64| {
        while let Ok(Some(p)) = poses.receive() {
            received
                .entry(p.header.stamp_ns)
                .or_insert_with(monotonic_now_ns);
            *slam_skipped = p.scans_skipped;
        }
        while let Ok(Some(f)) = fused.receive() {
            fused_with.insert(f.scan.header.stamp_ns, (f.sonar_stamp_ns, f.smoke_stamp_ns));
        }
    };
    for (t, m) in stream {
        let due = start + t;
        loop {
            let now = monotonic_now_ns();
            if now >= due {
                break;
            }
            // Woken by a pose or a fused scan; their receive time is the event.
            let _ = waiter.wait(Some(Duration::from_nanos(due - now)));
            drain(&mut fused_with, &mut received, &mut slam_skipped);
        }
        let mut m = m.clone();
        shift(&mut m, start);
        let stamp = stamp_of(&m);
        let (kind, r) = match &m {
            DirectMessage::Laser(s) => {
                scan_stamps.push(stamp);
                (0u8, laser.publish(s))
            }
            DirectMessage::Sonar(s) => (1, sonar.publish(s)),
            DirectMessage::Smoke(s) => (2, smoke.publish(s)),
            DirectMessage::Odometry(o) => {
                odom_stamps.push(stamp);
                (3, odom.publish(o))
            }
        };
        sent.insert((kind, stamp), monotonic_now_ns());
        r.expect("publish");
    }
    let end = Instant::now() + Duration::from_secs(1);
    while Instant::now() < end {
        let _ = waiter.wait(Some(Duration::from_millis(50)));
        drain(&mut fused_with, &mut received, &mut slam_skipped);
    }
    let mut maps = [f64::NAN; 3];
    while let Ok(Some(h)) = health[1].receive() {
        for (v, name) in maps
            .iter_mut()
            .zip(["map_draw_ms", "map_export_ms", "map_exports_late"])
        {
            *v = h.metric(name).unwrap_or(f64::NAN);
        }
    }
    for c in &mut children {
        let _ = smokenav_platform_runtime::launch::stop(c, Duration::from_secs(5));
    }

    let mut latencies_us = Vec::new();
    let mut misses = 0;
    for &s in scan_stamps.iter().skip(WARMUP_SCANS) {
        let Some(&got) = received.get(&s) else {
            misses += 1;
            continue;
        };
        let mut inputs = vec![sent.get(&(0, s)).copied()];
        if let Some(&(so, sm)) = fused_with.get(&s) {
            inputs.push(sent.get(&(1, so)).copied());
            inputs.push(sent.get(&(2, sm)).copied());
        }
        let i = odom_stamps.partition_point(|&o| o < s);
        if let Some(&o) = odom_stamps.get(i) {
            inputs.push(sent.get(&(3, o)).copied());
        }
        let last = inputs.into_iter().flatten().filter(|&t| t <= got).max();
        match last {
            Some(t) => latencies_us.push((got - t) / 1000),
            None => misses += 1,
        }
    }
    Figures {
        latencies_us,
        scans: scan_stamps.len().saturating_sub(WARMUP_SCANS),
        misses,
        fused: fused_with.len(),
        slam_skipped,
        maps,
    }
}

fn main() {
    let seconds: f64 = std::env::var("LIVE_BENCH_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(60.0);
    let backends =
        std::env::var("LIVE_BENCH_BACKENDS").unwrap_or_else(|_| "rbpf/1,rbpf,graph".into());
    let bins = build_processes();
    let scenario = Scenario::builtin("r32-dense-crossing").expect("scenario");
    let mut profile = scenario.profile.clone();
    if !scenario.smoke_sensor.cold_start {
        profile.smoke.warmup_s = 0.0;
    }
    let dir = std::env::temp_dir().join(format!("smokenav-live-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let profile_path = dir.join("robot.toml");
    std::fs::write(&profile_path, profile.to_toml()).expect("write profile");
    let stream = generate(&scenario, &profile, seconds);
    println!(
        "live path, last sensor input of a scan → its slam/pose in this process, real smokenav-fusion + smokenav-slam, {:.0} s of {} ({} messages):",
        seconds.min(scenario.duration_s),
        scenario.name,
        stream.len()
    );
    for label in backends.split(',').map(str::trim).filter(|b| !b.is_empty()) {
        let (label_backend, load_graph) = match label.split_once('+') {
            Some((b, _)) => {
                let g = std::env::var("LIVE_BENCH_LOAD_GRAPH").unwrap_or_else(|_| {
                    panic!("{label}: set LIVE_BENCH_LOAD_GRAPH to a graph saved with --save-graph")
                });
                (b, Some(g))
            }
            None => (label, None),
        };
        let (backend, path) = match label_backend.split_once('/') {
            Some((backend, threads)) => {
                let mut p = profile.clone();
                p.slam.threads = threads
                    .parse()
                    .unwrap_or_else(|_| panic!("{label}: threads must be a number"));
                let path = dir.join(format!("robot-{threads}.toml"));
                std::fs::write(&path, p.to_toml()).expect("write profile");
                (backend, path)
            }
            None => (label_backend, profile_path.clone()),
        };
        let f = run_backend(&bins, &path, backend, load_graph.as_deref(), &stream);
        let target_ms = match backend {
            "graph" => Some(15.0),
            "rbpf" => Some(30.0),
            _ => None,
        };
        let mut v = f.latencies_us.clone();
        v.sort_unstable();
        if v.is_empty() {
            println!(
                "  {label:<12} no pose arrived ({} scans, {} misses)",
                f.scans, f.misses
            );
            continue;
        }
        let at = |p: f64| v[((v.len() as f64 * p) as usize).min(v.len() - 1)] as f64 / 1e3;
        let over = target_ms.map_or(0, |t| v.iter().filter(|&&x| x as f64 / 1e3 > t).count());
        println!(
            "  {label:<12} scans {:>5}  p50 {:>6.2} ms  p99 {:>6.2} ms  max {:>7.2} ms  missed (no pose) {}  over {} ms {}  (fused {}, skipped by slam {})",
            f.scans,
            at(0.5),
            at(0.99),
            v[v.len() - 1] as f64 / 1e3,
            f.misses,
            target_ms.map_or("—".into(), |t| format!("{t:.0}")),
            over,
            f.fused,
            f.slam_skipped
        );
        println!(
            "  {:<12} maps (last health): drawn in {:.1} ms, the loop's share {:.1} ms, {} late",
            "", f.maps[0], f.maps[1], f.maps[2]
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
