//! Recording overhead on a live bus.
//!
//! `cargo bench -p smokenav-platform-recording --bench live_record`
//!
//! Runs the real `smokenav record` (release build; built by this bench, or
//! `SMOKENAV_BIN`) on a private bus instance while four publisher threads
//! of this process — each its own bus node, as separate drivers would be —
//! publish `laser/scan` (682 beams), `base/odom`, `base/sonar` and
//! `smoke/level` at a rate per topic, for a few seconds per rate. Prints
//! per rate: messages offered and received per second, gaps the recorder
//! counted (sequence numbers it never saw), its CPU use, and the file size.

use smokenav_platform_bus::{Bus, BusOptions, topics};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{
    BeamReading, Header, LaserScan, Odometry, SmokeReading, SonarReading, SonarRing, SonarStatus,
};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

const RUN: Duration = Duration::from_secs(4);
const RATES_HZ: &[u64] = &[10, 100, 500, 1000, 2000];

fn smokenav_bin() -> PathBuf {
    if let Ok(p) = std::env::var("SMOKENAV_BIN") {
        return p.into();
    }
    // This bench runs from target/release/deps; the CLI lands in target/release.
    let exe = std::env::current_exe().unwrap();
    let dir = exe.parent().and_then(|d| d.parent()).unwrap().to_owned();
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(cargo)
        .args([
            "build",
            "--release",
            "--quiet",
            "-p",
            "smokenav-cli",
            "--bin",
            "smokenav",
        ])
        .status()
        .expect("run cargo");
    assert!(status.success(), "cannot build smokenav");
    dir.join("smokenav")
}

fn publish(instance: &str, topic: &'static str, rate: u64, start: u64, end: u64) -> u64 {
    let bus = Bus::open(&BusOptions::new(
        instance,
        &format!("bench-{}", topic.replace('/', "-")),
    ))
    .unwrap();
    let period = 1_000_000_000 / rate;
    let mut sent = 0u64;
    macro_rules! run {
        ($p:expr, $fill:expr) => {{
            let mut p = $p;
            p.update_connections().unwrap();
            loop {
                let t = start + sent * period;
                if t >= end {
                    break;
                }
                let now = monotonic_now_ns();
                if t > now {
                    std::thread::sleep(Duration::from_nanos(t - now));
                }
                p.publish_with(|m| $fill(m, t)).unwrap();
                sent += 1;
            }
        }};
    }
    match topic {
        "laser/scan" => run!(
            bus.publisher(topics::LASER_SCAN).unwrap(),
            |s: &mut LaserScan, t| {
                s.header = Header::new(t, 0, "laser");
                s.count = 682;
                s.range_max = 5.6;
                for i in 0..682 {
                    s.set_beam(
                        i,
                        BeamReading::Range(1.0 + ((t as usize + i * 7) % 4000) as f32 * 1e-3),
                    );
                }
            }
        ),
        "base/odom" => run!(
            bus.publisher(topics::BASE_ODOM).unwrap(),
            |o: &mut Odometry, t| {
                o.header = Header::new(t, 0, "odom");
                o.x = t as f64 * 1e-9;
            }
        ),
        "base/sonar" => run!(
            bus.publisher(topics::BASE_SONAR).unwrap(),
            |r: &mut SonarRing, t| {
                r.header = Header::new(t, 0, "base_link");
                for i in 0..8 {
                    r.push(SonarReading::new(i, 1.5, SonarStatus::Valid));
                }
            }
        ),
        _ => run!(
            bus.publisher(topics::SMOKE_LEVEL).unwrap(),
            |s: &mut SmokeReading, t| {
                s.header = Header::new(t, 0, "smoke");
                s.level = 10.0;
            }
        ),
    }
    sent
}

/// utime + stime of a process, s.
fn cpu_seconds(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks: f64 = f.get(11).and_then(|v| v.parse().ok()).unwrap_or(0.0)
        + f.get(12).and_then(|v| v.parse().ok()).unwrap_or(0.0);
    ticks / 100.0 // USER_HZ
}

fn main() {
    let bin = smokenav_bin();
    let dir = tempfile::tempdir().unwrap();
    let topics = ["laser/scan", "base/odom", "base/sonar", "smoke/level"];
    println!("rate/topic  offered msg/s  received msg/s  gaps  recorder CPU  file MB");
    for &rate in RATES_HZ {
        let instance = format!("tapsbench_{}_{rate}", std::process::id());
        let file = dir.path().join(format!("{rate}.mcap"));
        let mut rec = Command::new(&bin)
            .args([
                "record",
                "-o",
                file.to_str().unwrap(),
                "--instance",
                &instance,
            ])
            .args(topics)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(rec.stdout.take().unwrap()).lines();
        loop {
            let l = lines.next().expect("recorder output").unwrap();
            if l.starts_with("recording") {
                break;
            }
        }
        let start = monotonic_now_ns() + 200_000_000;
        let end = start + RUN.as_nanos() as u64;
        let threads: Vec<_> = topics
            .iter()
            .map(|&t| {
                let instance = instance.clone();
                std::thread::spawn(move || publish(&instance, t, rate, start, end))
            })
            .collect();
        let sent: u64 = threads.into_iter().map(|t| t.join().unwrap()).sum();
        std::thread::sleep(Duration::from_millis(300));
        let cpu = cpu_seconds(rec.id());
        nix::sys::signal::kill(
            nix::unistd::Pid::from_raw(rec.id() as i32),
            nix::sys::signal::Signal::SIGINT,
        )
        .unwrap();
        let (mut received, mut lost) = (0u64, 0u64);
        for l in lines.map_while(Result::ok) {
            let w: Vec<&str> = l.split_whitespace().collect();
            if w.len() >= 5 && w[1] == "received" && w[3] == "lost" {
                received += w[2].parse::<u64>().unwrap();
                lost += w[4].parse::<u64>().unwrap();
            }
        }
        assert!(rec.wait().unwrap().success());
        let secs = RUN.as_secs_f64();
        let size = std::fs::metadata(&file).map(|m| m.len()).unwrap_or(0);
        println!(
            "{rate:>7} Hz  {:>13.0}  {:>14.0}  {lost:>4}  {:>10.1} %  {:>7.1}",
            sent as f64 / secs,
            received as f64 / secs,
            100.0 * cpu / (secs + 0.5),
            size as f64 / 1e6
        );
    }
}
