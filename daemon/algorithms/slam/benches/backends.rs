//! The SLAM back-ends over the MIT CSAIL log, side by side in one run, each
//! through the one SLAM pipeline (as the SLAM process and `smokenav slam` run
//! them): total thread CPU time, per-scan CPU p50/p99/max and ATE of the final
//! trajectory against GMapping's corrected poses (after the best rigid
//! alignment), plus the graph's loop-closure counters and the CPU time of
//! exporting the final map (what the SLAM process spends on its loop for each
//! map it publishes). Beside ATE, the consistency of the reference's scans
//! placed at each back-end's poses and at the reference's own (cells at 5 cm
//! holding an endpoint, and the distance of each endpoint to the nearest one
//! of another pass; see `smokenav_algorithms_eval::consistency`): the
//! reference is GMapping's estimate, and a trajectory farther from it can
//! still be the crisper one.
//!
//! `cargo bench -p smokenav-algorithms-slam --bench backends`
//! Environment: `CSAIL_DIR` (the folder of the log; required), `CSAIL_DRIFT=SEED` (run on the
//! corrected log's scans with seeded drifted odometry instead, see `drift`; `CSAIL_DRIFT_PARAMS`
//! overrides its parameters), `BACKENDS` (`rbpf,graph,frontend` by default; `fuzzy` too;
//! `frontend` is the graph with loop closure off, `closure_search_m = 0`: the front end's own
//! per-scan cost, which inline runs share a call with the closure search), `CSAIL_LOG` / `CSAIL_REFERENCE`
//! (other log and reference files in that folder), `SLAM_TOML` (`[slam]` keys), `CSAIL_OUT` (folder for
//! each back-end's map PNG and trajectory), `GRAPH_ONLINE=1` (the graph's loop closures on their
//! own thread, as the SLAM process runs them: the per-scan figures are then the scan path's alone,
//! the total adds the worker's CPU), `CSAIL_RATE=R` (feed the scans at R × the log's own pace
//! instead of as fast as they are processed: online, a faster feed leaves the worker fewer nodes).

use smokenav_algorithms_eval::{
    ConsistencyOptions, ScanConsistency, StampedPose as EvalPose, TrajectoryOptions,
    evaluate_trajectories, format_trajectory, load_trajectory, scan_consistency,
};
use smokenav_algorithms_slam::drift;
use smokenav_algorithms_slam::fuzzy::FuzzySlam;
use smokenav_algorithms_slam::graph::{GraphParams, GraphSlam, RobustKernel};
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::rbpf::RbpfParams;
use smokenav_algorithms_slam::{Rbpf, SlamBackend, SlamPipeline, StampedPose};
use smokenav_platform_config::SlamSection;
use smokenav_shared_types::Pose2;
use std::io::BufReader;
use std::path::PathBuf;

fn cpu_ns(clock: nix::time::ClockId) -> u64 {
    nix::time::clock_gettime(clock)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}

fn thread_cpu_ns() -> u64 {
    cpu_ns(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
}

/// The whole process's CPU time (online, the closure worker's too).
fn process_cpu_ns() -> u64 {
    cpu_ns(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID)
}

/// The `key=value;…` pairs of the environment variable `var`.
fn overrides(var: &str) -> Vec<(String, f64)> {
    std::env::var(var)
        .unwrap_or_default()
        .split(';')
        .filter_map(|kv| kv.split_once('='))
        .map(|(k, v)| {
            let v = v
                .trim()
                .parse()
                .unwrap_or_else(|_| panic!("{var}: {k} = {v} is not a number"));
            (k.trim().to_string(), v)
        })
        .collect()
}

/// `CSAIL_DRIFT_PARAMS="heading_bias=0.012;scale=0.05"` overrides the drift's
/// defaults (all zero: the reference poses themselves as odometry).
fn drift_params(seed: u64) -> drift::DriftParams {
    let mut p = drift::DriftParams {
        seed,
        ..drift::DriftParams::default()
    };
    for (k, v) in overrides("CSAIL_DRIFT_PARAMS") {
        match k.as_str() {
            "scale" => p.scale = v,
            "turn_scale" => p.turn_scale = v,
            "heading_bias" => p.heading_bias = v,
            "sigma_t" => p.sigma_t = v,
            "sigma_r" => p.sigma_r = v,
            "sigma_r_per_m" => p.sigma_r_per_m = v,
            other => panic!("CSAIL_DRIFT_PARAMS: unknown key {other}"),
        }
    }
    p
}

/// `GRAPH_PARAMS="closure_search_m=6;closure_min_score=0.5"` overrides graph parameters.
fn graph_params() -> GraphParams {
    let mut p = GraphParams::default();
    for (k, v) in overrides("GRAPH_PARAMS") {
        match k.as_str() {
            "node_distance_m" => p.node_distance_m = v,
            "node_angle_rad" => p.node_angle_rad = v,
            "closure_search_m" => p.closure_search_m = v,
            "closure_min_separation" => p.closure_min_separation = v as usize,
            "closure_neighbours" => p.closure_neighbours = v as usize,
            "closure_candidates" => p.closure_candidates = v as usize,
            "share_frontend_match" => p.share_frontend_match = v != 0.0,
            "max_iterations" => p.optimize.max_iterations = v as u32,
            "closure_window_m" => p.closure_window_m = v,
            "closure_window_rad" => p.closure_window_rad = v,
            "closure_min_score" => p.closure_min_score = v,
            "closure_max_chi2" => p.closure_max_chi2 = v,
            "closure_every" => p.closure_every = v as usize,
            "closure_wide_sigmas" => p.closure_wide_sigmas = v,
            "closure_wide_max_m" => p.closure_wide_max.0 = v,
            "closure_wide_max_rad" => p.closure_wide_max.1 = v,
            "closure_wide_min_score" => p.closure_wide_min_score = v,
            "closure_min_overlap" => p.closure_min_overlap = v,
            "closure_map_covariance" => p.closure_map_covariance = v != 0.0,
            "edge_sigma_t0" => p.edge_sigma_t.0 = v,
            "edge_sigma_t1" => p.edge_sigma_t.1 = v,
            "edge_sigma_r0" => p.edge_sigma_r.0 = v,
            "edge_sigma_r1" => p.edge_sigma_r.1 = v,
            "closure_sigma_t" => p.closure_sigma.0 = v,
            "closure_sigma_r" => p.closure_sigma.1 = v,
            "closure_point_sigma_m" => p.closure_point_sigma_m = v,
            "closure_max_withheld" => p.closure_max_withheld = v,
            "closure_rival_m" => p.closure_rival_m = v,
            "closure_rival_ratio" => p.closure_rival_ratio = v,
            "tracker_window_m" => p.tracker_window_m = v,
            "tracker_window_rad" => p.tracker_window_rad = v,
            "sonar_edge_widening" => p.sonar_edge_widening = v,
            "cauchy" => p.optimize.kernel = RobustKernel::Cauchy(v),
            "relative_tolerance" => p.optimize.relative_tolerance = v,
            other => panic!("unknown graph parameter {other}"),
        }
    }
    p
}

/// Robot-frame endpoints of the log's scans at the reference's stamps (within 1 ms), by stamp.
type ReferenceScans = std::collections::BTreeMap<u64, Vec<(f64, f64)>>;

fn endpoints_of(scan: &smokenav_algorithms_slam::RangeScan, max_range: f64) -> Vec<(f64, f64)> {
    let s = scan.sensor_pose;
    let (sn, cs) = s.theta.sin_cos();
    scan.beams
        .iter()
        .filter_map(|b| {
            let r = b.range.filter(|&r| (r as f64) < max_range)? as f64;
            let (x, y) = (r * (b.angle as f64).cos(), r * (b.angle as f64).sin());
            Some((s.x + cs * x - sn * y, s.y + sn * x + cs * y))
        })
        .collect()
}

/// The reference scans placed at `poses` (looked up by stamp; a scan with no pose is left out).
fn consistency_at(scans: &ReferenceScans, poses: &[(u64, Pose2)]) -> ScanConsistency {
    let placed: Vec<Vec<(f64, f64)>> = scans
        .iter()
        .filter_map(|(stamp, points)| {
            let i = poses.partition_point(|(t, _)| *t < stamp.saturating_sub(1_000_000));
            let &(t, p) = poses.get(i)?;
            (t.abs_diff(*stamp) <= 1_000_000).then(|| {
                let (sn, cs) = p.theta.sin_cos();
                points
                    .iter()
                    .map(|&(x, y)| (p.x + cs * x - sn * y, p.y + sn * x + cs * y))
                    .collect()
            })
        })
        .collect();
    scan_consistency(&placed, &ConsistencyOptions::default())
}

fn consistency_line(c: &ScanConsistency) -> String {
    format!(
        "{} scans, {} cells at 5 cm, endpoint to another pass median {:.1} mm mean {:.1} mm ({:.0} % seen again)",
        c.scans,
        c.cells,
        c.nearest.median_m * 1e3,
        c.nearest.mean_m * 1e3,
        c.seen_again * 100.0
    )
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let Ok(dir) = std::env::var("CSAIL_DIR").map(PathBuf::from) else {
        eprintln!(
            "backends: set CSAIL_DIR to the folder holding mit-csail.clf and csail-reference-poses.txt"
        );
        std::process::exit(2);
    };
    let log = std::env::var("CSAIL_LOG").unwrap_or_else(|_| "mit-csail.clf".into());
    let reference =
        std::env::var("CSAIL_REFERENCE").unwrap_or_else(|_| "csail-reference-poses.txt".into());
    let reference = load_trajectory(&dir.join(&reference)).unwrap();
    // `CSAIL_DRIFT=SEED`: the corrected log's scans with its motion drifted
    // (`drift::DriftParams::default()` with that seed), against its own poses.
    let (dir, log) = match std::env::var("CSAIL_DRIFT") {
        Ok(seed) => {
            let p = drift_params(seed.parse().expect("CSAIL_DRIFT is a seed"));
            let text = std::process::Command::new("gzip")
                .arg("-dc")
                .arg(dir.join("csail-corrected.log.gz"))
                .output()
                .expect("gzip -dc csail-corrected.log.gz");
            let stamps: Vec<u64> = reference
                .iter()
                .map(|r| (r.t * 1e6).round() as u64 * 1000)
                .collect();
            let out = std::env::temp_dir().join(format!("csail-drifted-{}.log", p.seed));
            let file = std::io::BufWriter::new(std::fs::File::create(&out).unwrap());
            let r =
                drift::drift_log(text.stdout.as_slice(), file, &p, Some(&stamps), None).unwrap();
            let odom: Vec<EvalPose> = {
                let mut scans = LogScans::new(BufReader::new(std::fs::File::open(&out).unwrap()));
                let mut v = Vec::new();
                while let Some((scan, odom)) = scans.next_scan() {
                    v.push(EvalPose::from_ns(scan.stamp_ns, &odom));
                }
                v
            };
            let ate = evaluate_trajectories(&reference, &odom, &TrajectoryOptions::same_stamp())
                .map(|a| a.ate_m.rmse)
                .unwrap_or(f64::NAN);
            println!(
                "backends drifted CSAIL (seed {}): {} scans over {:.1} m, end {:.2} m off, odometry ATE RMS {ate:.3} m",
                p.seed, r.laser_records, r.path_m, r.end_offset_m
            );
            (
                out.parent().unwrap().to_path_buf(),
                out.file_name().unwrap().to_string_lossy().into_owned(),
            )
        }
        Err(_) => (dir, log),
    };
    let which = std::env::var("BACKENDS").unwrap_or_else(|_| "rbpf,graph,frontend".into());
    // `SLAM_TOML='frontend = false\n[fuzzy]\nsearch = "correlative"'` overrides `[slam]` keys.
    let mut cfg = match std::env::var("SLAM_TOML") {
        Ok(text) => {
            smokenav_platform_config::parse_toml::<SlamSection>(&text, "SLAM_TOML".as_ref())
                .unwrap_or_else(|e| panic!("{e}"))
        }
        Err(_) => SlamSection::default(),
    };
    // One core: the figures are this thread's CPU, which the particle
    // filter's pool (`threads`, default one per core) would hide work from.
    if cfg.threads == 0 {
        cfg.threads = 1;
    }
    let reference_stamps: Vec<u64> = reference
        .iter()
        .map(|r| (r.t * 1e6).round() as u64 * 1000)
        .collect();
    let reference_poses: Vec<(u64, Pose2)> = reference
        .iter()
        .zip(&reference_stamps)
        .map(|(r, &t)| (t, Pose2::new(r.x, r.y, r.theta)))
        .collect();
    let mut reference_scans = ReferenceScans::new();
    let online = std::env::var("GRAPH_ONLINE").is_ok_and(|v| v == "1");
    let rate: Option<f64> = std::env::var("CSAIL_RATE")
        .ok()
        .map(|v| v.parse().expect("CSAIL_RATE is a number"));
    for name in which.split(',') {
        let backend: Box<dyn SlamBackend> = match name {
            "rbpf" => Box::new(Rbpf::new(RbpfParams::from_config(&cfg), true)),
            "graph" => {
                let mut g = GraphSlam::new(&cfg, graph_params());
                g.set_online(online);
                Box::new(g)
            }
            "frontend" => Box::new(GraphSlam::new(
                &cfg,
                GraphParams {
                    closure_search_m: 0.0,
                    ..graph_params()
                },
            )),
            "fuzzy" => Box::new(FuzzySlam::new(&cfg, true)),
            other => panic!("unknown back-end {other}"),
        };
        let mut slam = SlamPipeline::new(&cfg, backend);
        let mut scans = LogScans::new(BufReader::new(std::fs::File::open(dir.join(&log)).unwrap()));
        let mut times = Vec::new();
        let start = thread_cpu_ns();
        let process_start = process_cpu_ns();
        let mut paced: Option<(std::time::Instant, u64)> = None;
        while let Some((scan, odom)) = scans.next_scan() {
            if let Some(r) = rate {
                let (t0, s0) = *paced.get_or_insert((std::time::Instant::now(), scan.stamp_ns));
                let due = t0
                    + std::time::Duration::from_secs_f64(
                        scan.stamp_ns.saturating_sub(s0) as f64 / 1e9 / r,
                    );
                std::thread::sleep(due.saturating_duration_since(std::time::Instant::now()));
            }
            let i =
                reference_stamps.partition_point(|&t| t < scan.stamp_ns.saturating_sub(1_000_000));
            if reference_stamps
                .get(i)
                .is_some_and(|&t| t.abs_diff(scan.stamp_ns) <= 1_000_000)
            {
                reference_scans
                    .entry(reference_stamps[i])
                    .or_insert_with(|| endpoints_of(scan, cfg.max_range_m));
            }
            let t0 = thread_cpu_ns();
            slam.process(scan, &odom);
            times.push(thread_cpu_ns() - t0);
        }
        let traj = slam.trajectory();
        let total = (thread_cpu_ns() - start) as f64 / 1e9;
        let process_total = (process_cpu_ns() - process_start) as f64 / 1e9;
        // What the SLAM process pays on its loop for each map it publishes.
        let t_map = thread_cpu_ns();
        let map = slam.map();
        let map_ms = (thread_cpu_ns() - t_map) as f64 / 1e6;
        if let Some(m) = &map {
            println!(
                "backends {log} {name:>5}: map export {map_ms:.1} CPU-ms ({} × {} cells)",
                m.width, m.height
            );
        }
        times.sort_unstable();
        let pct = |q: f64| {
            times[((q * times.len() as f64).ceil() as usize).clamp(1, times.len()) - 1] as f64 / 1e6
        };
        let est: Vec<EvalPose> = traj
            .iter()
            .map(|p: &StampedPose| EvalPose::from_ns(p.stamp_ns, &p.pose))
            .collect();
        let ate = evaluate_trajectories(&reference, &est, &TrajectoryOptions::same_stamp()).ok();
        println!(
            "backends {log} {name:>5}: {} scans, total {total:.2} CPU-s, per scan p50 {:.2} ms p99 {:.2} ms max {:.2} ms; ATE RMS {:.3} m, max {:.3} m over {} poses",
            times.len(),
            pct(0.5),
            pct(0.99),
            pct(1.0),
            ate.as_ref().map(|a| a.ate_m.rmse).unwrap_or(f64::NAN),
            ate.as_ref().map(|a| a.ate_m.max).unwrap_or(f64::NAN),
            ate.as_ref().map(|a| a.pairs).unwrap_or(0),
        );
        let poses: Vec<(u64, Pose2)> = traj.iter().map(|p| (p.stamp_ns, p.pose)).collect();
        println!(
            "backends {log} {name:>5} consistency: {}",
            consistency_line(&consistency_at(&reference_scans, &poses))
        );
        if let Some(g) = slam.backend().as_any().downcast_ref::<GraphSlam>() {
            println!("backends {log} {name}: {:?}", g.stats());
            if g.is_online() {
                let (max, p99) = g.closure_latency_ms();
                println!(
                    "backends {log} graph online: process total {process_total:.2} CPU-s (scan path and closure worker), closure job to applied p99 {p99:.0} ms max {max:.0} ms"
                );
            }
        }
        if let Some(f) = slam.backend().as_any().downcast_ref::<FuzzySlam>() {
            println!("backends {log} fuzzy: {:?}", f.stats());
        }
        if let Ok(out) = std::env::var("CSAIL_OUT") {
            let out = PathBuf::from(out).join(name);
            std::fs::create_dir_all(&out).unwrap();
            std::fs::write(out.join("trajectory.txt"), format_trajectory(&est)).unwrap();
            if let Some(map) = map {
                map.save_png(&out.join("map.png")).unwrap();
            }
        }
    }
    println!(
        "backends {log} reference poses consistency: {}",
        consistency_line(&consistency_at(&reference_scans, &reference_poses))
    );
}
