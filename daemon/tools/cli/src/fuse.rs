//! `smokenav fuse`: SmokeNav over a recording, offline.
//!
//! Reads JSON lines exactly as `smokenav topic echo --json` prints them
//! (`laser/scan`, `base/sonar`, `smoke/level`; other topics are skipped) on
//! stdin — or, with `--bag BAG`, a smokenav recording or a ROS 2 bag, fed in
//! receive order at its receive times as the process is — runs the fusion
//! process's synchroniser and the chosen method, and writes one
//! `fusion/scan` record per fused scan on stdout. Bad lines are reported on
//! stderr with their line number and skipped; a damaged bag message ends the
//! run with an error naming its file, topic and index.

use anyhow::Context;
use clap::Args;
use smokenav_algorithms_fusion::offline::{BadLine, fuse_jsonl};
use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_platform_config::RobotConfig;
use smokenav_shared_types::FusionMethod;
use std::io::{BufWriter, Write};
use std::path::PathBuf;

/// Used when no `--config` is given: the first platform of SmokeNav (Santos et al. 2015).
const DEFAULT_PROFILE: &str = "pioneer-3dx";

#[derive(Debug, Args)]
pub struct FuseArgs {
    /// Fusion method.
    #[arg(long, value_enum)]
    method: FusionMethod,
    /// Robot profile (sonar poses, laser mount, [fusion] parameters). Default:
    /// the shipped Pioneer 3-DX profile.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Read a `smokenav record` file or a ROS 2 bag (rosbag2 folder, .mcap,
    /// .db3) instead of stdin. A foreign bag gives the laser and, where it
    /// has one, the sonar (`--sonar`; mapped onto the profile's [sonar]); it
    /// has no smoke sensor, so the fusion treats the smoke as silent.
    #[arg(long, value_name = "BAG")]
    bag: Option<PathBuf>,
    #[command(flatten)]
    roles: crate::bag::RoleArgs,
}

pub fn run(args: FuseArgs) -> anyhow::Result<()> {
    let cfg = match &args.config {
        Some(path) => RobotConfig::load(path)
            .with_context(|| format!("invalid robot profile {}", path.display()))?,
        None => RobotConfig::builtin(DEFAULT_PROFILE).context("the built-in profile is invalid")?,
    };
    let mut pipeline = FusionPipeline::from_config(&cfg, Some(args.method))
        .context("the profile's sonar geometry is unusable")?;
    if let Some(bag) = &args.bag {
        return run_bag(&mut pipeline, bag, &args.roles, &cfg);
    }
    anyhow::ensure!(
        !args.roles.given(),
        "--laser, --odom and --sonar choose a bag's topics: give --bag BAG"
    );
    let stdin = std::io::stdin().lock();
    let stdout = BufWriter::new(std::io::stdout().lock());
    let mut stderr = std::io::stderr().lock();
    let report = fuse_jsonl(&mut pipeline, stdin, stdout, |b: &BadLine| {
        // Nothing sensible to do if stderr itself fails.
        let _ = writeln!(
            stderr,
            "smokenav fuse: line {}: {} (skipped)",
            b.line, b.error
        );
    })
    .context("smokenav fuse: I/O error")?;
    let sync = pipeline.sync_counters();
    eprintln!(
        "smokenav fuse: {} lines (laser {}, sonar {}, smoke {}, other topics {}, bad {}); {} fused scans, sonar usage {:.1}%, sync drops {}",
        report.lines,
        report.laser,
        report.sonar,
        report.smoke,
        report.ignored,
        report.bad,
        report.written,
        100.0 * pipeline.stats().sonar_usage(),
        sync.dropped_all(),
    );
    Ok(())
}

fn run_bag(
    pipeline: &mut FusionPipeline,
    path: &std::path::Path,
    roles: &crate::bag::RoleArgs,
    cfg: &RobotConfig,
) -> anyhow::Result<()> {
    use smokenav_platform_recording::AnyMessage;
    use smokenav_shared_types::catalog::topic_names;
    use smokenav_shared_types::record::{FusedScanRecord, Message, TopicRecord};
    let (bag, map) = crate::bag::open(path, roles, false)?;
    anyhow::ensure!(
        map.laser.is_some(),
        "{}: no sensor_msgs/msg/LaserScan topic to fuse",
        path.display()
    );
    let mut messages = bag.messages_with_sonar(&map, &cfg.sonar)?;
    let laser_topic = messages.laser_topic().to_owned();
    let mut out = BufWriter::new(std::io::stdout().lock());
    let mut written = 0u64;
    let mut failed: Option<std::io::Error> = None;
    let mut emit = |f: &smokenav_shared_types::FusedScan, _: &_| {
        if failed.is_some() {
            return;
        }
        let rec = TopicRecord {
            topic: topic_names::FUSION_SCAN.to_owned(),
            message: Message::FusedScan(FusedScanRecord::from(f)),
        };
        match serde_json::to_writer(&mut out, &rec)
            .map_err(std::io::Error::from)
            .and_then(|()| out.write_all(b"\n"))
        {
            Ok(()) => written += 1,
            Err(e) => failed = Some(e),
        }
    };
    let (mut laser, mut sonar, mut smoke, mut other) = (0u64, 0u64, 0u64, 0u64);
    while let Some(p) = messages.read_next()? {
        let now = p.log_time;
        match &p.message {
            AnyMessage::LaserScan(s) if p.topic == laser_topic => {
                laser += 1;
                pipeline.push_laser(s, now, &mut emit);
            }
            AnyMessage::SonarRing(r) => {
                sonar += 1;
                pipeline.push_sonar(r, now, &mut emit);
            }
            AnyMessage::SmokeReading(r) => {
                smoke += 1;
                pipeline.push_smoke(r, now, &mut emit);
            }
            _ => {
                other += 1;
                continue;
            }
        }
        pipeline.poll(now, &mut emit);
    }
    pipeline.flush(&mut emit);
    if let Some(e) = failed {
        return Err(e).context("smokenav fuse: cannot write stdout");
    }
    out.flush().context("smokenav fuse: cannot write stdout")?;
    drop(out);
    let sync = pipeline.sync_counters();
    let sonar_from = match (crate::bag::sonar_summary(&map), messages.sonar()) {
        (Some(what), Some(m)) => format!(" from {what}, {} cloud points dropped", m.dropped_points),
        _ => String::new(),
    };
    eprintln!(
        "smokenav fuse: {} (laser {laser} on {}, sonar {sonar}{sonar_from}, smoke {smoke}, other {other}); {written} fused scans, sonar usage {:.1}%, sync drops {}",
        path.display(),
        map.laser.as_deref().unwrap_or("?"),
        100.0 * pipeline.stats().sonar_usage(),
        sync.dropped_all(),
    );
    Ok(())
}
