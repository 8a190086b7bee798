//! The one SLAM pipeline over a real robot log (CARMEN format: `ODOM` and
//! `FLASER`/`ROBOTLASER1` lines), with the back-end named on the command
//! line, exactly as `smokenav slam` and the SLAM process run it.
//!
//! ```text
//! slam_over_log LOG.clf [rbpf|graph]
//! ```

use anyhow::Context;
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::{BackendOptions, SlamPipeline};
use smokenav_platform_config::{SlamBackendKind, SlamSection};
use std::io::BufReader;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let log = args
        .next()
        .context("usage: slam_over_log LOG.clf [rbpf|graph|fuzzy]")?;
    let mut cfg = SlamSection {
        particles: 10,
        ..SlamSection::default()
    };
    cfg.backend = match args.next().as_deref() {
        None | Some("rbpf") => SlamBackendKind::Rbpf,
        Some("graph") => SlamBackendKind::Graph,
        Some("fuzzy") => SlamBackendKind::Fuzzy,
        Some(other) => anyhow::bail!("unknown back-end {other} (rbpf, graph or fuzzy)"),
    };
    let file = std::fs::File::open(&log).with_context(|| format!("cannot open {log}"))?;
    let mut scans = LogScans::new(BufReader::new(file));
    let mut slam = SlamPipeline::from_config(
        &cfg,
        &BackendOptions {
            keep_trajectory: true,
            ..BackendOptions::default()
        },
    );
    let mut n = 0;
    while let Some((scan, odom)) = scans.next_scan() {
        slam.process(scan, &odom);
        n += 1;
    }
    let pose = slam.pose().context("the log has no scan")?;
    let map = slam.map().context("no map")?;
    println!(
        "{} back-end: {n} scans, final pose x {:.2} m y {:.2} m θ {:.1}°, map {}×{} cells at {} m",
        slam.backend().name(),
        pose.x,
        pose.y,
        pose.theta.to_degrees(),
        map.width,
        map.height,
        map.resolution
    );
    Ok(())
}
