//! The filter on real robot data: the MIT CSAIL CARMEN log (Radish), against
//! GMapping's corrected poses for the same scans (a reference, not ground truth).
//!
//! The prefix test runs by default on the first 200 scans (a fixture in
//! `tests/data`). The full-log test needs a release build and the full log:
//! `CSAIL_DIR=<folder with mit-csail.clf and csail-reference-poses.txt>
//! cargo test --release -p smokenav-algorithms-slam --test csail -- --ignored`.

use smokenav_algorithms_eval::{
    TrajectoryOptions, TrajectoryReport, evaluate_trajectories, load_trajectory,
};
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::{BackendOptions, SlamPipeline, StampedPose};
use smokenav_platform_config::SlamSection;
use std::io::BufReader;
use std::path::{Path, PathBuf};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn reference(path: &Path) -> Vec<smokenav_algorithms_eval::StampedPose> {
    load_trajectory(path).unwrap()
}

struct Run {
    smoothed: Vec<StampedPose>,
    online: Vec<StampedPose>,
    scans: usize,
    bad_lines: usize,
}

fn run(log: &Path, cfg: &SlamSection) -> Run {
    let mut scans = LogScans::new(BufReader::new(std::fs::File::open(log).unwrap()));
    let mut slam = SlamPipeline::from_config(
        cfg,
        &BackendOptions {
            keep_trajectory: true,
            ..BackendOptions::default()
        },
    );
    let mut online = Vec::new();
    while let Some((scan, odom)) = scans.next_scan() {
        let u = slam.process(scan, &odom);
        online.push(StampedPose {
            stamp_ns: u.stamp_ns,
            pose: u.pose,
        });
    }
    Run {
        smoothed: slam.trajectory(),
        scans: online.len(),
        online,
        bad_lines: scans.error_count,
    }
}

/// ATE against the reference poses, which sit at some of the log's own
/// stamps: paired by stamp (to the microsecond), not interpolated.
fn ate(est: &[StampedPose], reference: &[smokenav_algorithms_eval::StampedPose]) -> Ate {
    let est: Vec<_> = est
        .iter()
        .map(|p| smokenav_algorithms_eval::StampedPose::from_ns(p.stamp_ns, &p.pose))
        .collect();
    let r = evaluate_trajectories(reference, &est, &TrajectoryOptions::same_stamp())
        .expect("poses in common with the reference");
    Ate {
        matched: r.pairs,
        rms_m: r.ate_m.rmse,
        max_m: r.ate_m.max,
        report: r,
    }
}

#[derive(Debug)]
#[allow(dead_code)] // `report` is for the failure messages
struct Ate {
    matched: usize,
    rms_m: f64,
    max_m: f64,
    report: TrajectoryReport,
}

#[test]
fn csail_prefix_tracks_the_gmapping_reference() {
    let cfg = SlamSection {
        particles: 10,
        ..SlamSection::default()
    };
    let r = run(&data("csail-prefix-200.clf"), &cfg);
    assert_eq!(r.scans, 200);
    assert_eq!(r.bad_lines, 0);
    assert_eq!(r.smoothed.len(), 200, "one pose per processed scan");
    let reference = reference(&data("csail-reference-poses.txt"));
    let smoothed = ate(&r.smoothed, &reference);
    // The first 200 scans (43 s, ~25 m of corridor) hold 30 reference poses.
    assert_eq!(smoothed.matched, 30);
    assert!(smoothed.rms_m < 0.10, "{smoothed:?}");
    assert!(smoothed.max_m < 0.25, "{smoothed:?}");
    // Raw odometry over the same stretch, for scale: it drifts by metres.
    let mut scans = LogScans::new(BufReader::new(
        std::fs::File::open(data("csail-prefix-200.clf")).unwrap(),
    ));
    let mut odom = Vec::new();
    while let Some((scan, pose)) = scans.next_scan() {
        odom.push(StampedPose {
            stamp_ns: scan.stamp_ns,
            pose,
        });
    }
    let raw = ate(&odom, &reference);
    assert!(
        raw.rms_m > 3.0 * smoothed.rms_m,
        "odometry {raw:?} vs slam {smoothed:?}"
    );
    // The online estimate has no hindsight but stays close on this stretch.
    assert!(ate(&r.online, &reference).rms_m < 0.15);
}

#[test]
fn same_seed_same_trajectory_other_seed_other_trajectory() {
    let mut lines: Vec<String> = std::fs::read_to_string(data("csail-prefix-200.clf"))
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    // Scans 60–100: the robot starts to move here.
    lines.truncate(103);
    lines.drain(3..63);
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("short.clf");
    std::fs::write(&log, lines.join("\n")).unwrap();
    let cfg = SlamSection {
        particles: 6,
        ..SlamSection::default()
    };
    let a = run(&log, &cfg).smoothed;
    let b = run(&log, &cfg).smoothed;
    assert_eq!(a, b);
    let c = run(&log, &SlamSection { seed: 7, ..cfg }).smoothed;
    assert_ne!(a, c);
}

#[test]
#[ignore = "full 1988-scan log: run with --release -- --ignored"]
fn csail_full_log_30_particles_within_0_3_m_rms() {
    let dir = std::env::var_os("CSAIL_DIR").map(PathBuf::from).expect(
        "set CSAIL_DIR to the folder holding mit-csail.clf and csail-reference-poses.txt (the MIT CSAIL log, see REFERENCES.md)",
    );
    let cfg = SlamSection::default();
    assert_eq!(cfg.particles, 30);
    let r = run(&dir.join("mit-csail.clf"), &cfg);
    assert_eq!(r.scans, 1988);
    assert_eq!(r.smoothed.len(), 1988);
    let reference = reference(&dir.join("csail-reference-poses.txt"));
    let a = ate(&r.smoothed, &reference);
    eprintln!("CSAIL full log: {a:?}");
    assert_eq!(a.matched, 406);
    assert!(a.rms_m < 0.3, "{a:?}");
    assert!(a.max_m < 0.6, "{a:?}");
}
