//! `smokenav slam --carmen LOG [--particles N] [--backend rbpf] --out DIR`:
//! runs the SLAM pipeline over a CARMEN log as fast as the CPU allows and
//! writes the trajectory, the map and timing statistics.

use anyhow::Context;
use smokenav_algorithms_eval::{
    TrajectoryFormat, TrajectoryOptions, evaluate_trajectories, format_trajectory_as,
    load_trajectory,
};
use smokenav_algorithms_slam::graph::{GraphSlam, g2o};
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::{BackendOptions, Rbpf, SlamPipeline, StampedPose};
use smokenav_platform_config::{RobotConfig, SlamBackendKind, SlamSection, parse_toml};
use std::fmt::Write as _;
use std::io::{BufReader, IsTerminal};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct SlamArgs {
    /// CARMEN log (FLASER / ROBOTLASER1 + ODOM records).
    #[arg(long, value_name = "LOG")]
    carmen: PathBuf,
    /// Number of particles (overrides the configuration).
    #[arg(long)]
    particles: Option<usize>,
    /// Output folder: trajectory.txt, map.pgm/map.yaml/map.png, stats.txt.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Trajectory file layout: `plain` (trajectory.txt, `timestamp x y theta`) or
    /// `tum` (trajectory.tum, `timestamp x y z qx qy qz qw`, what `evo_ape tum` reads).
    #[arg(long, value_enum, default_value_t = TrajFormat::Plain)]
    format: TrajFormat,
    /// Robot profile whose `[slam]` section to use.
    #[arg(long, value_name = "PROFILE", conflicts_with = "slam_params")]
    profile: Option<PathBuf>,
    /// A TOML file holding only `[slam]` keys (e.g. `preset = "seed-table3"`).
    #[arg(long, value_name = "FILE")]
    slam_params: Option<PathBuf>,
    /// Random seed (overrides the configuration).
    #[arg(long)]
    seed: Option<u64>,
    /// SLAM back-end (overrides `[slam] backend`).
    #[arg(long, value_enum)]
    backend: Option<SlamBackendKind>,
    /// Reference poses (`timestamp x y theta`) at some of the log's stamps to
    /// compare the trajectory with (paired by stamp, not interpolated).
    #[arg(long, value_name = "FILE")]
    reference: Option<PathBuf>,
    /// Stop after this many scans.
    #[arg(long)]
    max_scans: Option<usize>,
    /// Write the pose graph (2D g2o) here at the end (graph back-end only).
    #[arg(long, value_name = "FILE.g2o")]
    save_graph: Option<PathBuf>,
}

/// `--format` of the trajectory writers.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrajFormat {
    /// `timestamp x y theta` (s, m, m, rad).
    Plain,
    /// TUM RGB-D `timestamp x y z qx qy qz qw` (evo, the TUM tools).
    Tum,
}

impl TrajFormat {
    pub fn layout(self) -> TrajectoryFormat {
        match self {
            TrajFormat::Plain => TrajectoryFormat::Plain,
            TrajFormat::Tum => TrajectoryFormat::Tum,
        }
    }

    /// The file extension: `.tum` files are what evo's users expect to pass.
    pub fn extension(self) -> &'static str {
        match self {
            TrajFormat::Plain => "txt",
            TrajFormat::Tum => "tum",
        }
    }
}

/// CPU time of the process or of the calling thread, ns.
fn cpu_ns(clock: nix::time::ClockId) -> u64 {
    nix::time::clock_gettime(clock)
        .map(|t| t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
        .unwrap_or(0)
}

/// Peak resident set size, kB (`VmHWM` of /proc/self/status).
fn peak_rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

fn percentile(sorted: &[u64], q: f64) -> u64 {
    if sorted.is_empty() {
        return 0;
    }
    let idx = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1;
    sorted[idx]
}

fn load_config(args: &SlamArgs) -> anyhow::Result<SlamSection> {
    let mut cfg = if let Some(p) = &args.profile {
        RobotConfig::load(p)
            .with_context(|| format!("invalid robot profile {}", p.display()))?
            .slam
    } else if let Some(p) = &args.slam_params {
        let text =
            std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
        parse_toml::<SlamSection>(&text, p)?
    } else {
        SlamSection::default()
    };
    if let Some(n) = args.particles {
        cfg.particles = n;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    if let Some(b) = args.backend {
        cfg.backend = b;
    }
    let mut v = smokenav_platform_config::Validator::default();
    smokenav_platform_config::Validate::validate(&cfg, "slam", &mut v);
    if let Some(issue) = v.issues.first() {
        anyhow::bail!("invalid SLAM parameters: {issue}");
    }
    Ok(cfg)
}

fn eval_poses(poses: &[StampedPose]) -> Vec<smokenav_algorithms_eval::StampedPose> {
    poses
        .iter()
        .map(|p| smokenav_algorithms_eval::StampedPose::from_ns(p.stamp_ns, &p.pose))
        .collect()
}

fn write(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

pub fn run(args: SlamArgs) -> anyhow::Result<()> {
    let cfg = load_config(&args)?;
    anyhow::ensure!(
        args.save_graph.is_none() || cfg.backend == SlamBackendKind::Graph,
        "--save-graph needs --backend graph (the particle filter keeps no pose graph)"
    );
    let file = std::fs::File::open(&args.carmen)
        .with_context(|| format!("cannot open {}", args.carmen.display()))?;
    let size = file.metadata().map(|m| m.len()).unwrap_or(0);
    let reference = match &args.reference {
        Some(p) => Some(load_trajectory(p).context("bad reference file")?),
        None => None,
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;

    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(size)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {percent:>3}% {msg} [{elapsed_precise} < {eta_precise}]",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut scans = LogScans::new(BufReader::new(bar.wrap_read(file)));

    let process_cpu_start = cpu_ns(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID);
    let wall_start = Instant::now();
    let mut slam = SlamPipeline::from_config(
        &cfg,
        BackendOptions {
            keep_trajectory: true,
        },
    );
    let mut online: Vec<StampedPose> = Vec::new();
    let mut cpu_per_scan: Vec<u64> = Vec::new();
    let mut wall_per_scan: Vec<u64> = Vec::new();
    let mut processed = 0usize;
    while let Some((scan, odom)) = scans.next_scan() {
        let (c0, w0) = (
            cpu_ns(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID),
            Instant::now(),
        );
        let update = slam.process(scan, &odom);
        let wall = w0.elapsed().as_nanos() as u64;
        let cpu = cpu_ns(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID).saturating_sub(c0);
        cpu_per_scan.push(cpu);
        wall_per_scan.push(wall);
        processed += usize::from(update.processed);
        online.push(StampedPose {
            stamp_ns: update.stamp_ns,
            pose: update.pose,
        });
        if online.len().is_multiple_of(20) {
            bar.set_message(format!("{} scans", online.len()));
        }
        if args.max_scans.is_some_and(|m| online.len() >= m) {
            break;
        }
    }
    let total_cpu_ns =
        cpu_ns(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID).saturating_sub(process_cpu_start);
    let wall_total = wall_start.elapsed();
    bar.finish_and_clear();

    let trajectory = slam.trajectory();
    let trajectory = eval_poses(&trajectory);
    let online = eval_poses(&online);
    let ext = args.format.extension();
    write(
        &args.out.join(format!("trajectory.{ext}")),
        &format_trajectory_as(&trajectory, args.format.layout()),
    )?;
    write(
        &args.out.join(format!("trajectory_online.{ext}")),
        &format_trajectory_as(&online, args.format.layout()),
    )?;
    if let Some(map) = slam.map() {
        smokenav_platform_map::save_map_server(&map, &args.out, "map")?;
        map.save_png(&args.out.join("map.png"))?;
    }

    let mut cpu_sorted = cpu_per_scan.clone();
    cpu_sorted.sort_unstable();
    let mut wall_sorted = wall_per_scan.clone();
    wall_sorted.sort_unstable();
    let ms = |ns: u64| ns as f64 / 1e6;
    let stats = slam.stats();
    let mut report = String::new();
    let _ = writeln!(report, "log                {}", args.carmen.display());
    let _ = writeln!(
        report,
        "scans              {} read, {} processed, {} bad lines, {} ODOM records, {} odometry resets",
        online.len(),
        processed,
        scans.error_count,
        scans.odom_records,
        scans.odometry_resets()
    );
    match cfg.backend {
        SlamBackendKind::Rbpf => writeln!(
            report,
            "back-end           rbpf ({} particles)",
            cfg.particles
        ),
        kind => writeln!(report, "back-end           {}", kind.as_str()),
    }
    .ok();
    let _ = writeln!(
        report,
        "per-scan CPU ms    p50 {:.2}  p99 {:.2}  max {:.2}",
        ms(percentile(&cpu_sorted, 0.5)),
        ms(percentile(&cpu_sorted, 0.99)),
        ms(cpu_sorted.last().copied().unwrap_or(0))
    );
    let _ = writeln!(
        report,
        "per-scan wall ms   p50 {:.2}  p99 {:.2}  max {:.2}",
        ms(percentile(&wall_sorted, 0.5)),
        ms(percentile(&wall_sorted, 0.99)),
        ms(wall_sorted.last().copied().unwrap_or(0))
    );
    let _ = writeln!(
        report,
        "total CPU s        {:.2} (wall {:.2}); GMapping (30 particles): ~39 CPU-s for the 1988 CSAIL scans",
        total_cpu_ns as f64 / 1e9,
        wall_total.as_secs_f64()
    );
    let _ = writeln!(
        report,
        "peak RSS MB        {:.1}",
        peak_rss_kb().unwrap_or(0) as f64 / 1024.0
    );
    if let Some(rbpf) = slam.backend().as_any().downcast_ref::<Rbpf>() {
        let (tiles, tile_bytes) = rbpf.map_memory();
        let _ = writeln!(
            report,
            "maps               {} distinct tiles, {:.1} MB for {} particles",
            tiles,
            tile_bytes as f64 / 1e6,
            cfg.particles
        );
        let _ = writeln!(
            report,
            "filter             {} resamples",
            rbpf.stats().resamples
        );
    }
    let _ = writeln!(
        report,
        "pipeline           {} held back by the motion filter, {} front-end fallbacks, {} scans without ranges",
        stats.held_back, stats.frontend_fallbacks, stats.empty_scans
    );
    if let Some(g) = slam.backend().as_any().downcast_ref::<GraphSlam>() {
        let s = g.stats();
        let _ = writeln!(
            report,
            "graph              {} nodes, {} edges; loop closures: {} tried, {} accepted, {} below the score threshold, {} ambiguous, {} inconsistent; {} optimisations ({} failed)",
            s.nodes,
            g.graph().edges().len(),
            s.closures_tried,
            s.closures_accepted,
            s.closures_low_score,
            s.closures_ambiguous,
            s.closures_inconsistent,
            s.optimizations,
            s.optimization_failures
        );
        if let Some(path) = &args.save_graph {
            let mut text = Vec::new();
            g2o::write(g.graph(), &mut text)?;
            std::fs::write(path, text)
                .with_context(|| format!("cannot write {}", path.display()))?;
            let _ = writeln!(report, "pose graph         {}", path.display());
        }
    }
    if let Some(reference) = &reference {
        for (name, est) in [("trajectory", &trajectory), ("online", &online)] {
            match evaluate_trajectories(reference, est, &TrajectoryOptions::same_stamp()) {
                Ok(r) => {
                    let _ = writeln!(
                        report,
                        "ATE {name:<14} RMS {:.3} m, max {:.3} m (at {:.6}), {} poses matched; RPE {:.3} m, {:.2}° per {} s",
                        r.ate_m.rmse,
                        r.ate_m.max,
                        r.ate_max_at_s,
                        r.pairs,
                        r.rpe_translation_m.rmse,
                        r.rpe_rotation_deg.rmse,
                        r.rpe_delta_s
                    );
                }
                Err(e) => {
                    let _ = writeln!(report, "ATE {name:<14} {e}");
                }
            }
        }
    }
    for e in &scans.errors {
        let _ = writeln!(report, "bad line           {e}");
    }
    write(&args.out.join("stats.txt"), &report)?;
    print!("{report}");
    Ok(())
}

#[derive(clap::Subcommand, Debug)]
pub enum MapCommand {
    /// Save the map the SLAM process publishes as map.pgm|png + map.yaml (ROS map_server,
    /// as nav2's map_saver writes it) and map.png in DIR.
    Save {
        /// Output folder [default: $SMOKENAV_MAP_DIR, else ./maps].
        #[arg(env = "SMOKENAV_MAP_DIR")]
        dir: Option<PathBuf>,
        /// map_server mode: trinary (free/occupied/unknown, from `slam/map`), scale
        /// or raw (the occupancy probability, from `slam/map_probability`).
        #[arg(long, value_enum, default_value_t = SaveMode::Trinary)]
        mode: SaveMode,
        /// Give up if no map arrives within this many seconds.
        #[arg(long, default_value_t = 5.0)]
        timeout_s: f64,
        #[command(flatten)]
        bus: crate::topic::BusArgs,
    },
}

/// The map_server modes `map save` writes.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SaveMode {
    Trinary,
    Scale,
    Raw,
}

impl From<SaveMode> for smokenav_platform_map::MapMode {
    fn from(m: SaveMode) -> Self {
        match m {
            SaveMode::Trinary => Self::Trinary,
            SaveMode::Scale => Self::Scale,
            SaveMode::Raw => Self::Raw,
        }
    }
}

/// A map received from the bus as a grid, after checking its header against its payload.
fn grid_from_wire(
    info: &smokenav_shared_types::MapInfo,
    cells: &[i8],
) -> anyhow::Result<smokenav_platform_map::OccupancyGrid> {
    let (w, h) = (info.width as usize, info.height as usize);
    anyhow::ensure!(
        w.checked_mul(h)
            .is_some_and(|n| n == cells.len() && n <= smokenav_platform_map::MAX_CELLS),
        "map header says {w}×{h} cells but {} arrived",
        cells.len()
    );
    anyhow::ensure!(
        info.resolution.is_finite() && info.resolution > 0.0,
        "map resolution {} is not a positive number",
        info.resolution
    );
    anyhow::ensure!(
        [info.origin_x, info.origin_y, info.origin_theta]
            .iter()
            .all(|v| v.is_finite()),
        "map origin is not finite"
    );
    // MapInfo carries f32: take its shortest decimal form, so 0.05 stays 0.05 in the YAML.
    let resolution = info
        .resolution
        .to_string()
        .parse::<f64>()
        .unwrap_or(info.resolution as f64);
    Ok(smokenav_platform_map::OccupancyGrid {
        resolution,
        width: w,
        height: h,
        origin: [info.origin_x, info.origin_y, info.origin_theta],
        cells: cells.to_vec(),
    })
}

pub fn run_map(cmd: MapCommand) -> anyhow::Result<()> {
    let MapCommand::Save {
        dir,
        mode,
        timeout_s,
        bus,
    } = cmd;
    let dir = dir.unwrap_or_else(|| PathBuf::from("maps"));
    // Scale and raw keep the probabilities; the thresholded map would lose them.
    let topic = match mode {
        SaveMode::Trinary => smokenav_platform_bus::topics::SLAM_MAP,
        SaveMode::Scale | SaveMode::Raw => smokenav_platform_bus::topics::SLAM_MAP_PROBABILITY,
    };
    anyhow::ensure!(
        timeout_s.is_finite() && timeout_s > 0.0,
        "--timeout-s must be positive"
    );
    let bus = bus.open("map-save")?;
    let sub = bus.map_subscriber(topic.clone())?;
    let waiter = smokenav_platform_bus::Waiter::new()?;
    let _guard = waiter.attach(&sub)?;
    let deadline = Instant::now() + std::time::Duration::from_secs_f64(timeout_s);
    let grid = loop {
        let mut newest = None;
        while let Some(s) = sub.receive()? {
            newest = Some(grid_from_wire(s.user_header(), s.payload())?);
        }
        if let Some(g) = newest {
            break g;
        }
        let now = Instant::now();
        anyhow::ensure!(
            now < deadline,
            "no map on {} of instance `{}` within {timeout_s} s (is smokenav-slam running?)",
            topic.name(),
            bus.instance()
        );
        waiter.wait(Some(deadline - now))?;
    };
    smokenav_platform_map::save_map_server_mode(&grid, &dir, "map", mode.into())?;
    if mode != SaveMode::Scale {
        // Scale mode's image is map.png itself.
        grid.save_png(&dir.join("map.png"))?;
    }
    println!(
        "saved {}×{} {} map ({} m/cell) to {}",
        grid.width,
        grid.height,
        smokenav_platform_map::MapMode::from(mode).as_str(),
        grid.resolution,
        dir.display()
    );
    Ok(())
}
