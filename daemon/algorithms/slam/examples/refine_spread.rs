//! Diagnostic: how precisely does the particle scan matcher return to the same
//! pose from perturbed starts? Runs the filter over the first K scans of a
//! CARMEN log, then refines scan K+1 against the best particle's map from N
//! starts perturbed by (σxy, σθ) and prints the spread of the results.
//!
//! `refine_spread LOG K N SIGMA_XY SIGMA_THETA [key=value ...]`

use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::rbpf::Rbpf;
use smokenav_algorithms_slam::rbpf::matcher::{MatchParams, PreparedScan, refine};
use smokenav_algorithms_slam::{BackendOptions, Pose2, SlamPipeline};
use smokenav_platform_config::{SlamSection, parse_toml};
use smokenav_shared_types::Rng;
use std::io::BufReader;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() < 6 {
        return Err("usage: refine_spread LOG K N SIGMA_XY SIGMA_THETA [toml lines]".into());
    }
    let k: usize = a[2].parse()?;
    let n: usize = a[3].parse()?;
    let (sxy, sth): (f64, f64) = (a[4].parse()?, a[5].parse()?);
    let cfg: SlamSection = parse_toml(&a[6..].join("\n"), std::path::Path::new("args"))?;
    let mut scans = LogScans::new(BufReader::new(std::fs::File::open(&a[1])?));
    let mut slam = SlamPipeline::from_config(&cfg, &BackendOptions::default());
    for _ in 0..k {
        let (scan, odom) = scans.next_scan().ok_or("log too short")?;
        slam.process(scan, &odom);
    }
    let filter: &Rbpf = slam
        .backend()
        .as_any()
        .downcast_ref()
        .ok_or("refine_spread needs the particle filter")?;
    let best = filter.particles()[filter.best_index()].clone();
    let (scan, odom) = scans.next_scan().ok_or("log too short")?;
    let scan = scan.clone();
    // The filter's own answer for scan K+1 is the reference mode.
    let mode = slam.process(&scan, &odom).pose;
    let mp = MatchParams::from_config(&cfg);
    let mut prepared = PreparedScan::default();
    prepared.prepare(&scan, &mp);
    let center = refine(&best.grid, &prepared, &mode, &mp);
    println!(
        "mode {mode:?}\nrefined from mode {:?} (score {:.1})",
        center.pose, center.score
    );
    let mut rng = Rng::new(5, 0);
    let mut dth = Vec::new();
    let mut dxy = Vec::new();
    for _ in 0..n {
        let start = Pose2::new(
            center.pose.x + rng.gaussian(sxy),
            center.pose.y + rng.gaussian(sxy),
            center.pose.theta + rng.gaussian(sth),
        );
        let r = refine(&best.grid, &prepared, &start, &mp);
        dth.push(smokenav_shared_types::odom::normalize_angle(
            r.pose.theta - center.pose.theta,
        ));
        dxy.push((r.pose.x - center.pose.x).hypot(r.pose.y - center.pose.y));
    }
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    let mut sorted = dth.iter().map(|v| v.abs()).collect::<Vec<_>>();
    sorted.sort_by(f64::total_cmp);
    println!(
        "from {n} starts (σxy {sxy}, σθ {sth}): θ error mean {:+.4} RMS {:.4} rad, median {:.4}, p90 {:.4}; xy error RMS {:.3} m",
        dth.iter().sum::<f64>() / n as f64,
        rms(&dth),
        sorted[n / 2],
        sorted[n * 9 / 10],
        rms(&dxy)
    );
    Ok(())
}
