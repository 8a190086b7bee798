//! Runs the filter over the MIT CSAIL CARMEN log and prints accuracy against
//! the GMapping reference poses and per-scan timing (thread CPU time).
//!
//! `cargo bench -p smokenav-algorithms-slam --bench csail` (full log, 30 particles).
//! Environment: `CSAIL_DIR` (required: the folder holding `mit-csail.clf` and
//! `csail-reference-poses.txt`), `CSAIL_SCANS` (stop after N scans), `CSAIL_PARTICLES`,
//! `CSAIL_PARAMS` (extra `[slam]` TOML keys, `;`-separated), `CSAIL_THETA0`
//! (heading of the first pose in the map frame), `CSAIL_OUT` (folder for
//! map.png/.pgm/.yaml, trajectory.txt, trajectory_online.txt,
//! trajectory_frontend.txt, trajectory_odometry.txt and spread.txt).

use smokenav_algorithms_eval::{
    TrajectoryOptions, evaluate_trajectories, format_trajectory, load_trajectory,
};
use smokenav_algorithms_slam::carmen::format_stamp;
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::rbpf::Rbpf;
use smokenav_algorithms_slam::{BackendOptions, SlamPipeline, StampedPose};
use smokenav_platform_config::{SlamSection, parse_toml};

fn eval_poses(poses: &[StampedPose]) -> Vec<smokenav_algorithms_eval::StampedPose> {
    poses
        .iter()
        .map(|p| smokenav_algorithms_eval::StampedPose::from_ns(p.stamp_ns, &p.pose))
        .collect()
}

fn format_pose_file(poses: &[StampedPose]) -> String {
    format_trajectory(&eval_poses(poses))
}
use std::io::BufReader;
use std::path::{Path, PathBuf};

fn thread_cpu_ns() -> u64 {
    nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}

fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        })
        .unwrap_or(0.0)
        / 1024.0
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let Some(dir) = std::env::var_os("CSAIL_DIR").map(PathBuf::from) else {
        eprintln!(
            "csail: set CSAIL_DIR to the folder holding mit-csail.clf and csail-reference-poses.txt (the MIT CSAIL log, see REFERENCES.md); nothing measured"
        );
        std::process::exit(2);
    };
    let max_scans: usize = std::env::var("CSAIL_SCANS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(usize::MAX);
    let extra = std::env::var("CSAIL_PARAMS")
        .unwrap_or_default()
        .replace(';', "\n");
    let mut cfg: SlamSection = parse_toml(&extra, Path::new("CSAIL_PARAMS")).expect("CSAIL_PARAMS");
    // One core: per-scan figures are this thread's CPU (see `[slam] threads`).
    if cfg.threads == 0 {
        cfg.threads = 1;
    }
    if let Some(n) = std::env::var("CSAIL_PARTICLES")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        cfg.particles = n;
    }
    let log = std::fs::File::open(dir.join("mit-csail.clf")).expect("mit-csail.clf");
    let reference = load_trajectory(&dir.join("csail-reference-poses.txt")).unwrap();
    let mut scans = LogScans::new(BufReader::new(log));
    let mut slam = SlamPipeline::from_config(
        &cfg,
        &BackendOptions {
            keep_trajectory: true,
            ..BackendOptions::default()
        },
    );
    if let Some(t) = std::env::var("CSAIL_THETA0")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        slam.set_initial_pose(smokenav_algorithms_slam::Pose2::new(0.0, 0.0, t));
    }
    let mut online = Vec::new();
    let mut times = Vec::new();
    let mut spread = Vec::new();
    let mut frontend = Vec::new();
    let mut raw_odom = Vec::new();
    let start = thread_cpu_ns();
    while let Some((scan, odom)) = scans.next_scan() {
        let t0 = thread_cpu_ns();
        let u = slam.process(scan, &odom);
        times.push(thread_cpu_ns() - t0);
        online.push(StampedPose {
            stamp_ns: u.stamp_ns,
            pose: u.pose,
        });
        spread.push((
            u.stamp_ns,
            u.covariance[0].max(0.0).sqrt(),
            u.covariance[4].max(0.0).sqrt(),
            u.covariance[8].max(0.0).sqrt(),
            u.n_eff,
            u.resampled,
        ));
        if let Some(f) = slam.frontend_pose() {
            frontend.push(StampedPose {
                stamp_ns: u.stamp_ns,
                pose: f,
            });
        }
        raw_odom.push(StampedPose {
            stamp_ns: u.stamp_ns,
            pose: odom,
        });
        if online.len() >= max_scans {
            break;
        }
    }
    let total = (thread_cpu_ns() - start) as f64 / 1e9;
    times.sort_unstable();
    let pct = |q: f64| {
        times[((q * times.len() as f64).ceil() as usize).clamp(1, times.len()) - 1] as f64 / 1e6
    };
    let traj = slam.trajectory();
    let fallbacks = slam.stats().frontend_fallbacks;
    let rbpf: &Rbpf = slam
        .backend()
        .as_any()
        .downcast_ref()
        .expect("the bench runs the particle filter");
    let stats = rbpf.stats();
    let (tiles, bytes) = rbpf.map_memory();
    println!(
        "csail: {} scans, {} particles: per-scan CPU p50 {:.2} ms p99 {:.2} ms max {:.2} ms; total {:.1} CPU-s; peak RSS {:.1} MB; {} tiles ({:.1} MB); {} resamples, {} fallbacks, {:.1} evaluations per particle-scan",
        online.len(),
        cfg.particles,
        pct(0.5),
        pct(0.99),
        pct(1.0),
        total,
        peak_rss_mb(),
        tiles,
        bytes as f64 / 1e6,
        stats.resamples,
        fallbacks,
        stats.match_evaluations as f64 / (stats.updates.max(1) * cfg.particles as u64) as f64
    );
    for (name, est) in [("smoothed", &traj), ("online", &online)] {
        if let Ok(r) = evaluate_trajectories(
            &reference,
            &eval_poses(est),
            &TrajectoryOptions::same_stamp(),
        ) {
            println!(
                "csail: ATE {name}: RMS {:.4} m, max {:.3} m at {:.6}, mean {:.3} m over {} poses",
                r.ate_m.rmse, r.ate_m.max, r.ate_max_at_s, r.ate_m.mean, r.pairs
            );
        }
    }
    if let Ok(out) = std::env::var("CSAIL_OUT") {
        let out = PathBuf::from(out);
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("trajectory.txt"), format_pose_file(&traj)).unwrap();
        std::fs::write(out.join("trajectory_online.txt"), format_pose_file(&online)).unwrap();
        std::fs::write(
            out.join("trajectory_frontend.txt"),
            format_pose_file(&frontend),
        )
        .unwrap();
        std::fs::write(
            out.join("trajectory_odometry.txt"),
            format_pose_file(&raw_odom),
        )
        .unwrap();
        let text: String = spread
            .iter()
            .map(|(t, sx, sy, st, n, r)| {
                format!(
                    "{} {sx:.4} {sy:.4} {st:.5} {n:.1} {}\n",
                    format_stamp(*t),
                    u8::from(*r)
                )
            })
            .collect();
        std::fs::write(out.join("spread.txt"), text).unwrap();
        if let Some(map) = slam.map() {
            map.save_png(&out.join("map.png")).unwrap();
            smokenav_platform_map::save_map_server(&map, &out, "map").unwrap();
        }
    }
}
