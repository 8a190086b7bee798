//! The graph back-end on every corrected CARMEN log of a folder, drifted:
//! for each `*-corrected.log[.gz]` (Radish's, or a team's own), the log's
//! motion corrupted as `smokenav-lab drift` does (`drift::DriftParams`'
//! defaults, seeds 1, 2, 3 unless `DRIFT_SEEDS` says otherwise) and once
//! undrifted (the log's own poses as odometry), each run through the one
//! SLAM pipeline; ATE RMS of the final trajectory against the log's poses
//! after the best rigid alignment, per seed and in a summary line (how
//! many runs reach `DRIFT_TARGET_M`, default 0.10 m, the aim). The
//! undrifted run tells drift left over from disagreement with the
//! reference (another SLAM system's estimate, not ground truth).
//!
//! `DRIFTED_LOGS_DIR=<folder> cargo bench -p smokenav-algorithms-slam --bench drifted_logs`
//! Environment: `DRIFTED_LOGS_DIR` (required), `DRIFT_SEEDS` (`1,2,3`),
//! `DRIFT_LOGS` (names to run, comma-separated, e.g. `intel,aces`; default
//! all), `BACKENDS` (`graph`; `rbpf` too), `DRIFT_TARGET_M`, `SLAM_TOML` (`[slam]` keys).

use smokenav_algorithms_eval::{
    StampedPose as EvalPose, TrajectoryOptions, evaluate_trajectories, parse_trajectory,
};
use smokenav_algorithms_slam::drift::{DriftParams, drift_log};
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::{BackendOptions, SlamPipeline};
use smokenav_platform_config::{SlamBackendKind, SlamSection};
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

fn thread_cpu_s() -> f64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(|t| t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9)
        .unwrap_or(0.0)
}

/// The log's text, decompressed if it is gzip.
fn read_log(path: &Path) -> Vec<u8> {
    let file = std::fs::File::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut text = Vec::new();
    smokenav_algorithms_slam::carmen::text(BufReader::new(file))
        .and_then(|mut r| r.read_to_end(&mut text))
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text
}

/// `[slam]` as `SLAM_TOML` writes it (e.g. `"[graph]\nclosure_rival_ratio = 0.95"`), else the defaults.
fn slam_section() -> SlamSection {
    match std::env::var("SLAM_TOML") {
        Ok(text) => {
            smokenav_platform_config::parse_toml::<SlamSection>(&text, "SLAM_TOML".as_ref())
                .unwrap_or_else(|e| panic!("{e}"))
        }
        Err(_) => SlamSection::default(),
    }
}

/// ATE RMS of `backend` over the log drifted by `p`, m, and the CPU seconds it took.
fn run(log: &[u8], p: &DriftParams, backend: SlamBackendKind) -> (f64, f64) {
    let (mut drifted, mut reference) = (Vec::new(), Vec::new());
    drift_log(log, &mut drifted, p, None, Some(&mut reference)).expect("drift the log");
    let reference = parse_trajectory(
        std::str::from_utf8(&reference).expect("the reference is text"),
        Path::new("reference"),
    )
    .expect("read back the reference");
    let cfg = SlamSection {
        backend,
        threads: 1,
        ..slam_section()
    };
    let mut slam = SlamPipeline::from_config(
        &cfg,
        &BackendOptions {
            keep_trajectory: true,
            ..BackendOptions::default()
        },
    );
    let mut scans = LogScans::new(drifted.as_slice());
    let start = thread_cpu_s();
    while let Some((scan, odom)) = scans.next_scan() {
        slam.process(scan, &odom);
    }
    let cpu = thread_cpu_s() - start;
    let est: Vec<EvalPose> = slam
        .trajectory()
        .iter()
        .map(|s| EvalPose::from_ns(s.stamp_ns, &s.pose))
        .collect();
    let ate = evaluate_trajectories(&reference, &est, &TrajectoryOptions::same_stamp())
        .map(|a| a.ate_m.rmse)
        .unwrap_or(f64::NAN);
    (ate, cpu)
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let Ok(dir) = std::env::var("DRIFTED_LOGS_DIR").map(PathBuf::from) else {
        eprintln!(
            "drifted_logs: set DRIFTED_LOGS_DIR to a folder of corrected CARMEN logs (NAME-corrected.log or .log.gz)"
        );
        std::process::exit(2);
    };
    let list = |var: &str, default: &str| -> Vec<String> {
        std::env::var(var)
            .unwrap_or_else(|_| default.into())
            .split(',')
            .map(|s| s.trim().to_string())
            .filter(|s| !s.is_empty())
            .collect()
    };
    let seeds: Vec<u64> = list("DRIFT_SEEDS", "1,2,3")
        .iter()
        .map(|s| s.parse().expect("DRIFT_SEEDS: seeds are numbers"))
        .collect();
    let only = list("DRIFT_LOGS", "");
    let target: f64 = std::env::var("DRIFT_TARGET_M")
        .ok()
        .map(|v| v.parse().expect("DRIFT_TARGET_M is a number"))
        .unwrap_or(0.10);
    let backends: Vec<SlamBackendKind> = list("BACKENDS", "graph")
        .iter()
        .map(|b| match b.as_str() {
            "graph" => SlamBackendKind::Graph,
            "rbpf" => SlamBackendKind::Rbpf,
            other => panic!("BACKENDS: {other} is not graph or rbpf"),
        })
        .collect();
    let mut logs: Vec<(String, PathBuf)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter_map(|p| {
            let name = p.file_name()?.to_str()?;
            let stem = name
                .strip_suffix("-corrected.log.gz")
                .or_else(|| name.strip_suffix("-corrected.log"))?;
            Some((stem.to_string(), p.clone()))
        })
        .filter(|(name, _)| only.is_empty() || only.contains(name))
        .collect();
    logs.sort();
    let undrifted = DriftParams::none();
    for backend in backends {
        let name = backend.as_str();
        let (mut runs, mut reached, mut sum) = (0usize, 0usize, 0.0);
        for (log, path) in &logs {
            let text = read_log(path);
            let (base, _) = run(&text, &undrifted, backend);
            let mut line = format!("drifted_logs {name:>5} {log:<20} undrifted {base:.3} m; seeds");
            let mut cpu_total = 0.0;
            for &seed in &seeds {
                let p = DriftParams {
                    seed,
                    ..DriftParams::default()
                };
                let (ate, cpu) = run(&text, &p, backend);
                cpu_total += cpu;
                runs += 1;
                reached += usize::from(ate <= target);
                sum += ate;
                line.push_str(&format!(" {seed}: {ate:.3} m"));
            }
            println!(
                "{line}; {:.2} CPU-s per drifted run",
                cpu_total / seeds.len().max(1) as f64
            );
        }
        println!(
            "drifted_logs {name:>5} {} logs × {} seeds: {reached} of {runs} runs within {target:.2} m, mean ATE {:.3} m",
            logs.len(),
            seeds.len(),
            sum / runs.max(1) as f64
        );
    }
}
