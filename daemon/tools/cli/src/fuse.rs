//! `smokenav fuse`: SmokeNav over a recording, offline.
//!
//! Reads JSON lines exactly as `smokenav topic echo --json` prints them
//! (`laser/scan`, `base/sonar`, `smoke/level`; other topics are skipped) on
//! stdin, runs the fusion process's synchroniser and the chosen method, and
//! writes one `fusion/scan` record per fused scan on stdout. Bad lines are
//! reported on stderr with their line number and skipped.

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
}

pub fn run(args: FuseArgs) -> anyhow::Result<()> {
    let cfg = match &args.config {
        Some(path) => RobotConfig::load(path)
            .with_context(|| format!("invalid robot profile {}", path.display()))?,
        None => RobotConfig::builtin(DEFAULT_PROFILE).context("the built-in profile is invalid")?,
    };
    let mut pipeline = FusionPipeline::from_config(&cfg, Some(args.method))
        .context("the profile's sonar geometry is unusable")?;
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
