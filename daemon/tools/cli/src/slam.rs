//! `smokenav slam --carmen LOG | --bag BAG [--particles N] [--backend rbpf] --out DIR`:
//! runs the SLAM pipeline over a CARMEN log or a ROS 2 bag as fast as the
//! CPU allows and writes the trajectory, the map and timing statistics.
//!
//! A bag's messages go through the pipeline in the order they were received,
//! polled at their receive times, exactly as the SLAM process handles them
//! live (`offline::replay`); the laser's mounting pose comes from the bag's
//! `/tf_static`, else from `--profile`.

use anyhow::Context;
use smokenav_algorithms_eval::{
    TrajectoryFormat, TrajectoryMetricError, TrajectoryOptions, TrajectoryReport,
    evaluate_relations, evaluate_trajectories, format_trajectory_as, load_relations,
    load_trajectory,
};
use smokenav_algorithms_fusion::pipeline::FusionPipeline;
use smokenav_algorithms_slam::backend::footprint_radius;
use smokenav_algorithms_slam::fuzzy::FuzzySlam;
use smokenav_algorithms_slam::graph::{GraphParams, GraphSlam, ResumedGraph, saved};
use smokenav_algorithms_slam::grid::{BeamEnd, LogOddsModel, TiledGrid};
use smokenav_algorithms_slam::offline::LogScans;
use smokenav_algorithms_slam::pipeline::vote_aware_footprint;
use smokenav_algorithms_slam::projected::SensorRig;
use smokenav_algorithms_slam::scan::{EndpointLimits, RangeScan};
use smokenav_algorithms_slam::vote::VoteSlam;
use smokenav_algorithms_slam::{BackendOptions, Rbpf, SlamPipeline, SlamUpdate, StampedPose};
use smokenav_platform_config::{
    ResumeAt, RobotConfig, SlamBackendKind, SlamMode, SlamSection, VoteRule, parse_toml,
};
use smokenav_platform_map::OccupancyGrid;
use smokenav_platform_recording::bag::{Bag, RoleMap};
use smokenav_shared_types::{AnyMessage, FusedScan, Pose2};
use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::{BufReader, IsTerminal};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

#[derive(clap::Args, Debug)]
pub struct SlamArgs {
    /// CARMEN log (FLASER / ROBOTLASER1 + ODOM records).
    #[arg(
        long,
        value_name = "LOG",
        required_unless_present = "bag",
        conflicts_with = "bag"
    )]
    carmen: Option<PathBuf>,
    /// ROS 2 bag: a rosbag2 folder (metadata.yaml + .mcap or .db3), an .mcap
    /// or .db3 file, or a `smokenav record` file; LaserScan + Odometry topics.
    #[arg(long, value_name = "BAG")]
    bag: Option<PathBuf>,
    #[command(flatten)]
    roles: crate::bag::RoleArgs,
    /// Run the bag's laser and sonar through SmokeNav first (as the fusion
    /// process does) and map from the fused scans; the sonar is mapped onto
    /// `--profile`'s [sonar] (default: the built-in Pioneer 3-DX).
    #[arg(long, value_enum, value_name = "METHOD", requires = "bag")]
    fuse: Option<smokenav_shared_types::FusionMethod>,
    /// Number of particles (overrides the configuration).
    #[arg(long)]
    particles: Option<usize>,
    /// Output folder: trajectory.txt, map.pgm/map.yaml/map.png, stats.txt; given a
    /// truth (`--truth-map`, or `--reference`'s scans), errors.png: where the map's error lies.
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Trajectory file layout: `plain` (trajectory.txt, `timestamp x y theta`) or
    /// `tum` (trajectory.tum, `timestamp x y z qx qy qz qw`, what `evo_ape tum` reads).
    #[arg(long, value_enum, default_value_t = TrajFormat::Plain)]
    format: TrajFormat,
    /// Robot profile whose `[slam]` section to use.
    #[arg(long, value_name = "PROFILE", conflicts_with = "slam_params")]
    profile: Option<PathBuf>,
    /// A TOML file holding only `[slam]` keys (e.g. `preset = "seed-table3"`), bare or under a `[slam]` header.
    #[arg(long, value_name = "FILE")]
    slam_params: Option<PathBuf>,
    /// Random seed (overrides the configuration).
    #[arg(long)]
    seed: Option<u64>,
    /// SLAM back-end (overrides `[slam] backend`).
    #[arg(long, value_enum)]
    backend: Option<SlamBackendKind>,
    /// Reference poses (`timestamp x y theta`) to compare the trajectory with:
    /// paired by stamp where they sit at the log's stamps (GMapping's
    /// corrected CARMEN poses), else interpolated at the estimate's stamps (a
    /// simulator's truth, sampled on its own clock; the report says which).
    #[arg(long, value_name = "FILE")]
    reference: Option<PathBuf>,
    /// A relations file of the SLAM benchmark of Kümmerle et al. 2009 (`t1 t2
    /// x y z roll pitch yaw` per line, as published for Intel, ACES, FR079,
    /// MIT CSAIL, …): the trajectory's relative motions scored against it.
    #[arg(long, value_name = "FILE")]
    relations: Option<PathBuf>,
    /// Stop after this many scans.
    #[arg(long)]
    max_scans: Option<usize>,
    /// Write the pose graph (2D g2o) here at the end, and the nodes' scans
    /// beside it as FILE.g2o.scans (the graph back-end's, or the vote's graph
    /// member's; `--load-graph` reads both).
    #[arg(long, value_name = "FILE.g2o")]
    save_graph: Option<PathBuf>,
    /// Go on from a run saved with `--save-graph` (G and G.scans): keep
    /// mapping from where it ended, or with `--localization` only track the
    /// robot on its map. Implies `--backend graph`.
    #[arg(long, value_name = "G.g2o")]
    load_graph: Option<PathBuf>,
    /// Localise on `--load-graph`'s map without changing it (no new nodes;
    /// the same as `[slam] mode = "localization"`).
    #[arg(long)]
    localization: bool,
    /// Where `--load-graph`'s run starts: `last`, where the saved run ended
    /// (carrying on), or `first`, where it began (a robot back at its dock).
    /// Overrides `[slam] resume_at`.
    #[arg(long, value_enum, value_name = "WHERE")]
    resume_at: Option<ResumeAt>,
    /// Ground-truth map (map_server YAML) to score the map with (with
    /// `--backend vote`: the vote's and every member's). Without it but with
    /// `--reference`, the log's scans drawn at the reference poses are the truth.
    #[arg(long, value_name = "GT.yaml")]
    truth_map: Option<PathBuf>,
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

/// A `--slam-params` file whose keys sit under `[slam]`.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct SlamUnderHeader {
    slam: SlamSection,
}

fn load_config(args: &SlamArgs) -> anyhow::Result<SlamSection> {
    let mut cfg = if let Some(p) = &args.profile {
        RobotConfig::load(p)
            .with_context(|| format!("invalid robot profile {}", p.display()))?
            .slam
    } else if let Some(p) = &args.slam_params {
        let text =
            std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
        // The keys bare, or under the `[slam]` header they carry in a profile
        // (copied from one): the header alone used to be "unknown field `slam`".
        let under_header = text
            .parse::<toml::Table>()
            .is_ok_and(|t| t.len() == 1 && t.get("slam").is_some_and(toml::Value::is_table));
        if under_header {
            parse_toml::<SlamUnderHeader>(&text, p)?.slam
        } else {
            parse_toml::<SlamSection>(&text, p)?
        }
    } else {
        SlamSection::default()
    };
    if let Some(n) = args.particles {
        cfg.particles = n;
    }
    if let Some(s) = args.seed {
        cfg.seed = s;
    }
    // `--load-graph` or the profile's `[slam] load_graph` means the graph back-end.
    if let Some(b) = args.backend {
        cfg.backend = b;
    } else if args.load_graph.is_some() || cfg.load_graph.is_some() {
        cfg.backend = SlamBackendKind::Graph;
    }
    if args.localization {
        cfg.mode = SlamMode::Localization;
    }
    if let Some(at) = args.resume_at {
        cfg.resume_at = at;
    }
    // Offline the vote waits for every member at every scan: nothing dropped, reproducible.
    cfg.vote.lockstep = true;
    let mut v = smokenav_platform_config::Validator::default();
    smokenav_platform_config::Validate::validate(&cfg, "slam", &mut v);
    if let Some(issue) = v.issues.first() {
        anyhow::bail!("invalid SLAM parameters: {issue}");
    }
    // After the check: the profile's key must be absolute (a service runs in
    // /), a path given here is the user's, relative to where they are.
    if let Some(g) = &args.load_graph {
        cfg.load_graph = Some(g.clone());
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

enum Input {
    Carmen(PathBuf, std::fs::File),
    Bag(Box<Bag>, RoleMap),
}

/// Per scan handed to the pipeline: the pose it gave, and what it cost.
#[derive(Default)]
struct Run {
    online: Vec<StampedPose>,
    cpu_per_scan: Vec<u64>,
    wall_per_scan: Vec<u64>,
    processed: usize,
}

impl Run {
    /// Times `f` (one scan through the pipeline) and keeps its update.
    fn timed(&mut self, f: impl FnOnce() -> Option<SlamUpdate>) {
        // The process's clock, not this thread's: the particle filter's pool
        // and the vote's members work on the scan on threads of their own.
        let (c0, w0) = (
            cpu_ns(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID),
            Instant::now(),
        );
        let Some(update) = f() else {
            return;
        };
        let wall = w0.elapsed().as_nanos() as u64;
        let cpu = cpu_ns(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID).saturating_sub(c0);
        self.cpu_per_scan.push(cpu);
        self.wall_per_scan.push(wall);
        self.processed += usize::from(update.processed);
        self.online.push(StampedPose {
            stamp_ns: update.stamp_ns,
            pose: update.pose,
        });
    }
}

fn progress_bar(len: u64) -> indicatif::ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        indicatif::ProgressBar::new(len)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {percent:>3}% {msg} [{elapsed_precise} < {eta_precise}]",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

/// A CARMEN log: each scan with the odometry the logger attached.
fn run_carmen(
    args: &SlamArgs,
    log: &Path,
    file: std::fs::File,
    slam: &mut SlamPipeline,
    run: &mut Run,
    mut reference_map: Option<&mut ReferenceMap>,
) -> anyhow::Result<String> {
    let bar = progress_bar(file.metadata().map(|m| m.len()).unwrap_or(0));
    let input = smokenav_algorithms_slam::carmen::text(BufReader::new(bar.wrap_read(file)))
        .with_context(|| format!("cannot read {}", log.display()))?;
    let mut scans = LogScans::new(input);
    while let Some((scan, odom)) = scans.next_scan() {
        if let Some(rm) = reference_map.as_deref_mut() {
            rm.add(scan);
        }
        run.timed(|| Some(slam.process(scan, &odom)));
        if run.online.len().is_multiple_of(20) {
            bar.set_message(format!("{} scans", run.online.len()));
        }
        if args.max_scans.is_some_and(|m| run.online.len() >= m) {
            break;
        }
    }
    bar.finish_and_clear();
    let mut report = String::new();
    let _ = writeln!(report, "log                {}", log.display());
    let _ = writeln!(
        report,
        "log records        {} bad lines, {} ODOM records, {} odometry resets",
        scans.error_count,
        scans.odom_records,
        scans.odometry_resets()
    );
    if let Some((record, moved_m)) = scans.mount_moved() {
        let _ = writeln!(
            report,
            "laser poses        not the odometry plus a fixed mount from laser record {record} on (moved {moved_m:.2} m: a corrected log, as GMapping's .gfs.log?): those scans taken at their odometry pose, the laser at the robot's origin"
        );
    }
    if scans.unread_laser_records() > 0 {
        let _ = writeln!(
            report,
            "unread records     {} RAWLASER/RLASER (no pose of their own, or a rear laser): scans come from FLASER and ROBOTLASER1",
            scans.unread_laser_records()
        );
    }
    let resolution_s = scans.stamp_resolution_ns() as f64 / 1e9;
    if resolution_s >= 0.1 {
        // GMapping's corrected logs: `%g` stamps, a whole run under one or two values.
        let _ = writeln!(
            report,
            "stamps             written to {resolution_s} s only: odometry steps checked against that, and poses paired with a --reference by stamp are ambiguous"
        );
    }
    for e in &scans.errors {
        let _ = writeln!(report, "bad line           {e}");
    }
    Ok(report)
}

/// The laser's pose on the robot: the bag's `/tf_static`, else the profile's
/// `[laser] mount`, else the base origin; and where it came from.
fn laser_mount(
    bag: &Bag,
    roles: &RoleMap,
    profile: Option<&Path>,
) -> anyhow::Result<(Pose2, String)> {
    let frames = bag.frames(roles)?;
    if let Some((x, y, yaw)) = frames.laser_mount() {
        return Ok((
            Pose2::new(x, y, yaw),
            format!(
                "({x:.3}, {y:.3}, {:.2}°) from /tf_static ({} in {})",
                yaw.to_degrees(),
                frames.laser_frame.as_deref().unwrap_or("?"),
                frames.base_frame.as_deref().unwrap_or("base_link")
            ),
        ));
    }
    if let Some(p) = profile {
        let cfg = RobotConfig::load(p)
            .with_context(|| format!("invalid robot profile {}", p.display()))?;
        let m = cfg.laser.mount;
        return Ok((
            Pose2::new(m.x, m.y, m.yaw_rad()),
            format!(
                "({:.3}, {:.3}, {:.2}°) from {} [laser] mount",
                m.x,
                m.y,
                m.yaw_rad().to_degrees(),
                p.display()
            ),
        ));
    }
    Ok((
        Pose2::default(),
        "none: the bag's /tf_static does not place the laser; the base origin is used (--profile gives one)".into(),
    ))
}

/// A bag: its messages in receive order, polled at their receive times as the process does.
fn run_bag(
    args: &SlamArgs,
    bag: &Bag,
    roles: &RoleMap,
    slam: &mut SlamPipeline,
    run: &mut Run,
    mut fusion: Option<(FusionPipeline, RobotConfig)>,
    mut reference_map: Option<&mut ReferenceMap>,
) -> anyhow::Result<String> {
    // The reference's map draws each scan as the pipeline converted it.
    let mut draw = |slam: &SlamPipeline| {
        if let Some(rm) = reference_map.as_deref_mut() {
            rm.add(slam.scan());
        }
    };
    let total: u64 = bag
        .topics()
        .iter()
        .filter(|t| Some(&t.name) == roles.laser.as_ref() || Some(&t.name) == roles.odom.as_ref())
        .filter_map(|t| t.messages)
        .sum();
    let bar = progress_bar(total);
    let mut messages = match &fusion {
        Some((_, cfg)) => bag.messages_with_sonar(roles, &cfg.sonar)?,
        None => bag.messages(roles)?,
    };
    // Fused scans of one step (a few at most), handed on to SLAM; reused.
    let mut fused: Vec<FusedScan> = Vec::new();
    let (mut n_sonar, mut n_fused) = (0u64, 0u64);
    let (laser_topic, odom_topic) = (
        messages.laser_topic().to_owned(),
        messages.odom_topic().to_owned(),
    );
    let (mut n_laser, mut n_odom, mut read) = (0u64, 0u64, 0u64);
    while let Some(p) = messages.read_next()? {
        read += 1;
        if read.is_multiple_of(64) {
            bar.set_position(read);
        }
        match &p.message {
            AnyMessage::Odometry(o) if p.topic == odom_topic => {
                n_odom += 1;
                slam.push_odom(o);
            }
            AnyMessage::LaserScan(l) if p.topic == laser_topic => {
                n_laser += 1;
                match &mut fusion {
                    Some((f, _)) => f.push_laser(l, p.log_time, &mut |s, _| fused.push(*s)),
                    None => {
                        slam.push_laser(l);
                        draw(slam);
                    }
                }
            }
            AnyMessage::SonarRing(r) if fusion.is_some() => {
                n_sonar += 1;
                if let Some((f, _)) = &mut fusion {
                    f.push_sonar(r, p.log_time, &mut |s, _| fused.push(*s));
                }
            }
            // A smokenav recording's smoke sensor (a foreign bag has none).
            AnyMessage::SmokeReading(r) if fusion.is_some() => {
                if let Some((f, _)) = &mut fusion {
                    f.push_smoke(r, p.log_time, &mut |s, _| fused.push(*s));
                }
            }
            AnyMessage::FusedScan(f) if p.topic == laser_topic => {
                n_laser += 1;
                slam.push_fused(f);
                draw(slam);
            }
            _ => continue,
        }
        if let Some((f, _)) = &mut fusion {
            f.poll(p.log_time, &mut |s, _| fused.push(*s));
            for s in fused.drain(..) {
                n_fused += 1;
                slam.push_fused(&s);
                draw(slam);
            }
        }
        run.timed(|| slam.poll(p.log_time));
        if args.max_scans.is_some_and(|m| run.online.len() >= m) {
            break;
        }
    }
    if args.max_scans.is_none_or(|m| run.online.len() < m) {
        if let Some((f, _)) = &mut fusion {
            f.flush(&mut |s, _| fused.push(*s));
            for s in fused.drain(..) {
                n_fused += 1;
                slam.push_fused(&s);
                draw(slam);
                run.timed(|| slam.poll(s.scan.header.stamp_ns));
            }
        }
        run.timed(|| slam.flush());
    }
    bar.finish_and_clear();
    anyhow::ensure!(
        n_laser > 0 && n_odom > 0,
        "{}: {n_laser} scans on {} and {n_odom} odometry readings on {}: SLAM needs both",
        bag.path().display(),
        roles.laser.as_deref().unwrap_or("?"),
        roles.odom.as_deref().unwrap_or("?")
    );
    let mut report = String::new();
    let _ = writeln!(report, "bag                {}", bag.path().display());
    let _ = writeln!(
        report,
        "bag topics         {} scans on {}, {} odometry on {}",
        n_laser,
        roles.laser.as_deref().unwrap_or("?"),
        n_odom,
        roles.odom.as_deref().unwrap_or("?")
    );
    if let Some((f, _)) = &fusion {
        let _ = writeln!(
            report,
            "fusion             {n_fused} fused scans from {n_laser} scans and {n_sonar} sonar rings{}, sonar usage {:.1}%",
            crate::bag::sonar_summary(roles)
                .map(|w| format!(" on {w}"))
                .unwrap_or_default(),
            100.0 * f.stats().sonar_usage()
        );
    }
    let s = slam.stats();
    let _ = writeln!(
        report,
        "pairing            {} superseded, {} without odometry, {} odometry out of order, {} odometry resets, {} unflagged odometry jumps taken as resets",
        s.superseded, s.no_odometry, s.odom_out_of_order, s.odom_resets, s.odom_jumps
    );
    Ok(report)
}

pub fn run(args: SlamArgs) -> anyhow::Result<()> {
    let cfg = load_config(&args)?;
    let has_graph = cfg.backend == SlamBackendKind::Graph
        || (cfg.backend == SlamBackendKind::Vote
            && cfg.vote.members.contains(&SlamBackendKind::Graph));
    anyhow::ensure!(
        args.save_graph.is_none() || has_graph,
        "--save-graph needs --backend graph, or the vote with a graph member (only they keep a pose graph)"
    );
    anyhow::ensure!(
        cfg.load_graph.is_none() || cfg.backend == SlamBackendKind::Graph,
        "--load-graph needs the graph back-end, not --backend {}",
        cfg.backend.as_str()
    );
    anyhow::ensure!(
        cfg.mode == SlamMode::Mapping || cfg.load_graph.is_some(),
        "localization mode tracks the robot on a saved map: give --load-graph G or [slam] load_graph (saved with --save-graph)"
    );
    let reference = match &args.reference {
        Some(p) => Some(load_trajectory(p).context("bad reference file")?),
        None => None,
    };
    // Read before the run: a bad file should not cost the run.
    let relations = match &args.relations {
        Some(p) => Some(load_relations(p).context("bad relations file")?),
        None => None,
    };
    let input = match (&args.carmen, &args.bag) {
        (Some(log), _) => {
            anyhow::ensure!(
                !args.roles.given(),
                "--laser, --odom and --sonar choose a bag's topics; a CARMEN log has none"
            );
            let file = std::fs::File::open(log)
                .with_context(|| format!("cannot open {}", log.display()))?;
            Input::Carmen(log.clone(), file)
        }
        (None, Some(path)) => {
            // SLAM maps from the laser; a bag's sonar reaches it through fusion.
            anyhow::ensure!(
                args.roles.sonar.is_empty() || args.fuse.is_some(),
                "--sonar: the sonar reaches SLAM through the fusion; add --fuse v2 (or v1)"
            );
            let (bag, roles) = crate::bag::open(path, &args.roles, true)?;
            Input::Bag(Box::new(bag), roles)
        }
        (None, None) => anyhow::bail!("give --carmen LOG or --bag BAG"),
    };
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let robot = match &args.profile {
        Some(p) => Some(
            RobotConfig::load(p)
                .with_context(|| format!("invalid robot profile {}", p.display()))?,
        ),
        None => None,
    };
    // Without a profile the robot's size is unknown: nothing is cleared.
    let footprint_m = robot
        .as_ref()
        .map_or(0.0, |r| footprint_radius(&cfg, r.robot.radius_m));
    // What the pipeline clears itself (the vote's members clear their own).
    let own_footprint_m = vote_aware_footprint(&cfg, footprint_m);
    let mut slam = match &cfg.load_graph {
        Some(g) => {
            let run = saved::load(&cfg, GraphParams::from_config(&cfg), g)
                .with_context(|| format!("cannot load the saved graph {}", g.display()))?;
            SlamPipeline::new(
                &cfg,
                Box::new(ResumedGraph::new(
                    run,
                    cfg.mode == SlamMode::Localization,
                    true,
                )),
            )
        }
        None => {
            // The projected map needs the sensors in 3D: the profile's, if given.
            let sensors = robot.as_ref().map(|r| Arc::new(SensorRig::from_config(r)));
            SlamPipeline::from_config(
                &cfg,
                &BackendOptions {
                    keep_trajectory: true,
                    sensors,
                    footprint_m,
                    ..BackendOptions::default()
                },
            )
        }
    }
    .with_footprint(own_footprint_m);
    // Without a profile: no side transducers, v2's default margin.
    if let Some(r) = &robot {
        slam = slam.with_robot(r);
    }
    let truth_map = match &args.truth_map {
        Some(p) => Some(
            smokenav_platform_map::load_map_server(p)
                .with_context(|| format!("bad ground-truth map {}", p.display()))?,
        ),
        None => None,
    };
    let mut reference_map = reference
        .as_ref()
        .filter(|_| truth_map.is_none())
        .map(|r| ReferenceMap::new(r, &cfg));
    let mut run = Run::default();
    let process_cpu_start = cpu_ns(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID);
    let wall_start = Instant::now();
    let input_report = match input {
        Input::Carmen(log, file) => run_carmen(
            &args,
            &log,
            file,
            &mut slam,
            &mut run,
            reference_map.as_mut(),
        ),
        Input::Bag(bag, roles) => {
            let mount = laser_mount(&bag, &roles, args.profile.as_deref())?;
            slam = slam.with_sensor_pose(mount.0);
            let fusion = match args.fuse {
                Some(method) => {
                    let cfg = match &robot {
                        Some(r) => r.clone(),
                        None => RobotConfig::builtin("pioneer-3dx")
                            .context("the built-in profile is invalid")?,
                    };
                    let pipeline = FusionPipeline::from_config(&cfg, Some(method))
                        .context("the profile's sonar geometry is unusable")?;
                    Some((pipeline, cfg))
                }
                None => None,
            };
            let mut text = run_bag(
                &args,
                &bag,
                &roles,
                &mut slam,
                &mut run,
                fusion,
                reference_map.as_mut(),
            )?;
            let _ = writeln!(text, "laser mount        {}", mount.1);
            Ok(text)
        }
    }?;
    // A file that holds no scan (not a log, a compressed format we do not
    // read) is an error, not an empty result that looks like success.
    anyhow::ensure!(
        !run.online.is_empty(),
        "no laser scan could be read from the input\n{input_report}"
    );
    let total_cpu_ns =
        cpu_ns(nix::time::ClockId::CLOCK_PROCESS_CPUTIME_ID).saturating_sub(process_cpu_start);
    let wall_total = wall_start.elapsed();
    let Run {
        online,
        cpu_per_scan,
        wall_per_scan,
        processed,
    } = run;

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
    let (map, footprint_cleared) = slam.map_and_footprint().unzip();
    if let Some(map) = &map {
        smokenav_platform_map::save_map_server(map, &args.out, "map")?;
        map.save_png(&args.out.join("map.png"))?;
    }

    let mut cpu_sorted = cpu_per_scan.clone();
    cpu_sorted.sort_unstable();
    let mut wall_sorted = wall_per_scan.clone();
    wall_sorted.sort_unstable();
    let ms = |ns: u64| ns as f64 / 1e6;
    let stats = slam.stats();
    let mut report = String::new();
    let _ = writeln!(
        report,
        "scans              {} read, {} processed",
        online.len(),
        processed
    );
    report.push_str(&input_report);
    match cfg.backend {
        SlamBackendKind::Rbpf => writeln!(
            report,
            "back-end           rbpf ({} particles)",
            cfg.particles
        ),
        kind => writeln!(report, "back-end           {}", kind.as_str()),
    }
    .ok();
    if own_footprint_m > 0.0 {
        let _ = writeln!(
            report,
            "footprint          {} wall cells cleared where the robot drove (radius {footprint_m:.3} m)",
            footprint_cleared.unwrap_or(0)
        );
    } else if footprint_m > 0.0 {
        let _ = writeln!(
            report,
            "footprint          each member's map cleared under its own path (radius {footprint_m:.3} m)"
        );
    }
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
        let s = rbpf.stats();
        let _ = writeln!(
            report,
            "filter             {} resamples, {} put off while the laser was withheld; {} of {} updates weighed without refining, {} of them mostly withheld from the laser",
            s.resamples, s.held_resamples, s.unmatched_updates, s.updates, s.withheld_updates
        );
    }
    if let Some(f) = slam.backend().as_any().downcast_ref::<FuzzySlam>() {
        let s = f.stats();
        let _ = writeln!(
            report,
            "fuzzy              {} registered (mean overlap {:.3}, {} in some directions only); the prediction kept for {} refused and {} mostly withheld from the laser",
            s.registrations,
            s.mean_overlap(),
            s.degenerate,
            s.fallbacks,
            s.withheld
        );
    }
    let _ = writeln!(
        report,
        "pipeline           {} held back by the motion filter, {} front-end fallbacks to odometry, {} scans mostly withheld from the laser (heading matched, position by odometry), {} scans without ranges, {} sweeps deskewed by odometry, {} scans' sonar echoes moved to where the ring heard them",
        stats.held_back,
        stats.frontend_fallbacks,
        stats.frontend_withheld,
        stats.empty_scans,
        stats.deskewed,
        stats.sonar_compensated
    );
    let _ = writeln!(
        report,
        "heading            longest stretch on odometry alone (no laser match) {:.1} m; turned onto the square walls after a stretch: {} (last {:+.1}°); held by a side sonar along a wall: {} scans",
        stats.longest_blind_m,
        stats.headings_squared,
        stats.last_squared_turn.to_degrees(),
        stats.side_wall_headings
    );
    if let Some(g) = slam.backend().as_any().downcast_ref::<GraphSlam>() {
        let s = g.stats();
        let _ = writeln!(
            report,
            "graph              {} nodes, {} edges; loop closures: {} tried, {} accepted, {} below the score threshold, {} ambiguous, {} overlapping too little, {} inconsistent; {} optimisations ({} failed)",
            s.nodes,
            g.graph().edges().len(),
            s.closures_tried,
            s.closures_accepted,
            s.closures_low_score,
            s.closures_ambiguous,
            s.closures_low_overlap,
            s.closures_inconsistent,
            s.optimizations,
            s.optimization_failures
        );
        let _ = writeln!(
            report,
            "wide search        {} nodes uncertain and unclosed searched wider: {} matches held for a second, {} confirmed by one",
            s.closures_wide, s.closures_wide_held, s.closures_wide_confirmed
        );
        let _ = writeln!(
            report,
            "far closures       {} closures moved their node far and were reviewed: {} taken out again by a later match",
            s.closures_far, s.closures_retracted
        );
        if cfg.mode == SlamMode::Localization {
            let mut m = (0.0, 0.0);
            slam.backend().metrics(&mut |k, v| match k {
                "localization_matched" => m.0 = v,
                "localization_unmatched" => m.1 = v,
                _ => {}
            });
            let _ = writeln!(
                report,
                "localization       on {} (unchanged): {} scans matched to its map, {} followed the motion only",
                cfg.load_graph
                    .as_deref()
                    .unwrap_or(Path::new("?"))
                    .display(),
                m.0,
                m.1
            );
        }
    }
    if let Some(path) = &args.save_graph
        && let Some(written) = slam.backend().save_graph(path)
    {
        written?;
        let _ = writeln!(
            report,
            "pose graph         {} (nodes' scans: {})",
            path.display(),
            saved::scans_path(path).display()
        );
    }
    if let Some(reference) = &reference {
        for (name, est) in [("trajectory", &trajectory), ("online", &online)] {
            match evaluate_against_reference(reference, est) {
                Ok((r, pairing)) => {
                    let _ = writeln!(
                        report,
                        "ATE {name:<14} RMS {:.3} m, max {:.3} m (at {:.6}), {} poses {pairing}; RPE {:.3} m, {:.2}° per {} s; relations {:.4} ± {:.4} m, {:.3} ± {:.3}° ({})",
                        r.ate_m.rmse,
                        r.ate_m.max,
                        r.ate_max_at_s,
                        r.pairs,
                        r.rpe_translation_m.rmse,
                        r.rpe_rotation_deg.rmse,
                        r.rpe_delta_s,
                        r.relations_translation_m.mean,
                        r.relations_translation_m.std,
                        r.relations_rotation_deg.mean,
                        r.relations_rotation_deg.std,
                        r.relations
                    );
                }
                Err(e) => {
                    let _ = writeln!(report, "ATE {name:<14} {e}");
                }
            }
        }
    }
    if let (Some(relations), Some(path)) = (&relations, &args.relations) {
        for (name, est) in [("trajectory", &trajectory), ("online", &online)] {
            let line = match evaluate_relations(est, relations, RELATIONS_MAX_GAP_S) {
                Ok(r) => relations_line(&r),
                Err(e) => e.to_string(),
            };
            let label = if name == "online" {
                "relations online"
            } else {
                "relations"
            };
            let _ = writeln!(report, "{label:<19}{line} ({})", path.display());
        }
    }
    let truth = truth_map.or_else(|| reference_map.map(|r| r.grid()));
    if let Some(vote) = slam.backend().as_any().downcast_ref::<VoteSlam>() {
        vote_report(vote, truth.as_ref(), map.as_ref(), &args.out, &mut report)?;
    } else if let (Some(t), Some(m)) = (&truth, &map) {
        // Scored once: the text and the picture of where the error lies share the alignment.
        let opts = smokenav_algorithms_eval::MapOptions::default();
        let scored = smokenav_algorithms_eval::evaluate_maps(t, m, &opts);
        let _ = writeln!(report, "map error          {}", map_error_text(&scored));
        if let Ok(r) = &scored {
            // A picture that cannot be drawn is reported, not fatal: the run's
            // map, trajectory and stats are what it is for.
            let path = args.out.join("errors.png");
            let line = match crate::eval::error_image_png(t, m, r, opts.occupied_threshold, &path) {
                Ok(()) => format!(
                    "{} (where the map's walls lie against the truth's)",
                    path.display()
                ),
                Err(e) => format!("not drawn: {e:#}"),
            };
            let _ = writeln!(report, "error image        {line}");
        }
    }
    write(&args.out.join("stats.txt"), &report)?;
    print!("{report}");
    Ok(())
}

/// Longest gap between an estimate's poses a relation's stamp is
/// interpolated across, s: a laser's scans are 0.02–0.2 s apart, a log's
/// gap of seconds is not motion we know.
pub const RELATIONS_MAX_GAP_S: f64 = 0.5;

/// The relations metric as the benchmark's tables print it.
pub fn relations_line(r: &smokenav_algorithms_eval::RelationsReport) -> String {
    format!(
        "translation {:.4} ± {:.4} m (squared {:.5} ± {:.5} m²), rotation {:.3} ± {:.3}° (squared {:.3} ± {:.3}°²), {} relations{}",
        r.translation_m.mean,
        r.translation_m.std,
        r.translation_sq_m2.mean,
        r.translation_sq_m2.std,
        r.rotation_deg.mean,
        r.rotation_deg.std,
        r.rotation_sq_deg2.mean,
        r.rotation_sq_deg2.std,
        r.relations,
        if r.unmatched > 0 {
            format!(", {} outside the trajectory", r.unmatched)
        } else {
            String::new()
        }
    )
}

/// The trajectory against `--reference`: paired at equal stamps when the
/// reference lies at the log's stamps, else (no two poses within 1 ms of a
/// reference stamp) with the reference interpolated at the estimate's stamps.
/// Returns the report and how the poses were paired.
fn evaluate_against_reference(
    reference: &[smokenav_algorithms_eval::StampedPose],
    est: &[smokenav_algorithms_eval::StampedPose],
) -> Result<(TrajectoryReport, &'static str), TrajectoryMetricError> {
    match evaluate_trajectories(reference, est, &TrajectoryOptions::same_stamp()) {
        Ok(r) => Ok((r, "matched")),
        Err(TrajectoryMetricError::TooFewAtSameStamps { .. }) => {
            evaluate_trajectories(reference, est, &TrajectoryOptions::default())
                .map(|r| (r, "paired with the reference interpolated"))
        }
        Err(e) => Err(e),
    }
}

/// The log's scans drawn at the reference poses: the map a reference
/// trajectory implies, the truth a map is scored against when the log has no
/// ground-truth map. Drawn twice over: at the reference poses whose stamps
/// are the scans' (GMapping's corrected CARMEN poses), and at the reference
/// interpolated to every scan's stamp (a simulator's truth, sampled on its
/// own clock); the first is the map unless fewer than two scans had a pose
/// at their stamp, as [`evaluate_against_reference`] pairs poses.
struct ReferenceMap {
    poses: HashMap<u64, smokenav_shared_types::Pose2>,
    reference: Vec<smokenav_algorithms_eval::StampedPose>,
    limits: EndpointLimits,
    model: LogOddsModel,
    /// Scans drawn at a reference pose of their own stamp, and the grid.
    at_stamps: (usize, TiledGrid),
    /// Scans drawn at the interpolated reference, and the grid.
    interpolated: (usize, TiledGrid),
    ends: Vec<BeamEnd>,
    endpoints: Vec<smokenav_algorithms_slam::scan::Endpoint>,
}

impl ReferenceMap {
    fn new(reference: &[smokenav_algorithms_eval::StampedPose], cfg: &SlamSection) -> Self {
        Self {
            poses: reference
                .iter()
                .map(|p| {
                    (
                        (p.t * 1e6).round() as u64,
                        smokenav_shared_types::Pose2::new(p.x, p.y, p.theta),
                    )
                })
                .collect(),
            reference: reference.to_vec(),
            limits: EndpointLimits::from_config(cfg),
            model: LogOddsModel::new(cfg.hit_logodds, cfg.miss_logodds, cfg.max_logodds),
            at_stamps: (0, TiledGrid::new(cfg.resolution_m)),
            interpolated: (0, TiledGrid::new(cfg.resolution_m)),
            ends: Vec::new(),
            endpoints: Vec::new(),
        }
    }

    fn add(&mut self, scan: &RangeScan) {
        // Stamps are matched to the microsecond (the reference file's precision).
        let key = (scan.stamp_ns as f64 / 1e3).round() as u64;
        let exact = self.poses.get(&key).copied();
        // Once scans sit at reference stamps, the interpolated map is not the one.
        let interpolated = (self.at_stamps.0 < 2)
            .then(|| {
                smokenav_algorithms_eval::truth_at(
                    &self.reference,
                    scan.stamp_ns as f64 * 1e-9,
                    TrajectoryOptions::default().max_gap_s,
                )
            })
            .flatten()
            .map(|p| smokenav_shared_types::Pose2::new(p.x, p.y, p.theta));
        if exact.is_none() && interpolated.is_none() {
            return;
        }
        scan.endpoints(&self.limits, &mut self.endpoints);
        for (pose, (drawn, grid)) in [
            (exact, &mut self.at_stamps),
            (interpolated, &mut self.interpolated),
        ] {
            let Some(pose) = pose else { continue };
            let (s, c) = pose.theta.sin_cos();
            self.ends.clear();
            self.ends.extend(self.endpoints.iter().map(|e| BeamEnd {
                ex: pose.x + c * e.x - s * e.y,
                ey: pose.y + s * e.x + c * e.y,
                hit: e.range <= self.limits.max_urange,
            }));
            let sensor = pose.compose(&scan.sensor_pose);
            grid.integrate(&sensor, &self.ends, &self.model);
            *drawn += 1;
        }
    }

    /// The reference's map (see the type's docs).
    fn grid(&self) -> OccupancyGrid {
        if self.at_stamps.0 >= 2 {
            self.at_stamps.1.to_occupancy_grid()
        } else {
            self.interpolated.1.to_occupancy_grid()
        }
    }
}

fn map_error(truth: &OccupancyGrid, map: &OccupancyGrid) -> String {
    map_error_text(&smokenav_algorithms_eval::evaluate_maps(
        truth,
        map,
        &smokenav_algorithms_eval::MapOptions::default(),
    ))
}

fn map_error_text(
    scored: &Result<smokenav_algorithms_eval::MapReport, smokenav_algorithms_eval::MapMetricError>,
) -> String {
    match scored {
        Ok(r) => format!(
            "k-NN {:.3} m, pixel RMS {:.3}; of the k-NN, walls missing {:.4} m, phantom {:.4} m (`smokenav eval` says where)",
            r.knn_error_m,
            r.pixel_rms,
            r.truth_to_map_bands.far.knn_share_m,
            r.map_to_truth_bands.far.knn_share_m
        ),
        Err(e) => format!("not comparable: {e}"),
    }
}

/// The members beside the vote: health, drops, alignment, agreement, each
/// member's map (saved as `map_<member>`) and, given a truth, every map's error.
fn vote_report(
    vote: &VoteSlam,
    truth: Option<&OccupancyGrid>,
    fused: Option<&OccupancyGrid>,
    out: &Path,
    report: &mut String,
) -> anyhow::Result<()> {
    let st = vote.status();
    let _ = writeln!(
        report,
        "vote               {} rule, {} fused updates, last {:.1} ms; pose from {}; {} cells out of the laser plane",
        vote.params().section.rule.as_str(),
        st.fuses,
        st.last_fuse_ms,
        st.pose_member.unwrap_or("-"),
        st.out_of_plane_cells
    );
    for m in &st.members {
        let a = m
            .alignment
            .map(|a| {
                format!(
                    "aligned ({:+.3}, {:+.3}) m {:+.2}°, residual {:.3} m",
                    a.transform.x,
                    a.transform.y,
                    a.transform.theta.to_degrees(),
                    a.residual_m
                )
            })
            .unwrap_or_else(|| "not aligned".into());
        let mut line = format!(
            "  member {:<6}    {}, {} dropped, {a}, agreement {}",
            m.name,
            m.health,
            m.drops,
            m.agreement
                .map(|g| format!("{:.1} %", 100.0 * g))
                .unwrap_or_else(|| "-".into())
        );
        if m.local_blocks > 0 {
            let _ = write!(line, ", {} blocks re-aligned locally", m.local_blocks);
        }
        if let Some((map, _)) = &m.map {
            let name = format!("map_{}", m.name);
            smokenav_platform_map::save_map_server(map, out, &name)?;
            if let Some(t) = truth {
                let _ = write!(line, "; map error {}", map_error(t, map));
            }
        }
        let _ = writeln!(report, "{line}");
    }
    if let (Some(t), Some(f)) = (truth, fused) {
        let own = vote.params().section.rule;
        let _ = writeln!(
            report,
            "  vote map error    {} ({}, the configured rule)",
            map_error(t, f),
            own.as_str()
        );
        // The other rules over the same aligned member maps, for comparison.
        for rule in VoteRule::ALL.into_iter().filter(|&r| r != own) {
            if let Some(m) = vote.map_with_rule(rule) {
                let _ = writeln!(
                    report,
                    "  vote map error    {} ({})",
                    map_error(t, &m),
                    rule.as_str()
                );
            }
        }
        smokenav_platform_map::save_map_server(t, out, "truth")?;
    }
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
        /// Where smokenav-mapping saves its octree, to copy octree.bt from
        /// [default: the profile's `[mapping] map_dir`, else /var/lib/smokenav/octree].
        #[arg(long, value_name = "DIR")]
        octree_dir: Option<PathBuf>,
        #[command(flatten)]
        bus: crate::topic::BusArgs,
    },
    /// Vote over saved maps (SLAMfusion, as `[slam] backend = "vote"` does
    /// online): align each to the first, vote every cell, write DIR/map.yaml.
    Vote {
        /// map_server YAMLs, 2–8; the first is the frame and grid of the vote.
        #[arg(required = true, num_args = 2..)]
        maps: Vec<PathBuf>,
        /// `majority`, `weighted`, `consensus` or `majority-reference` [default: the profile's `[slam.vote] rule`].
        #[arg(long, value_parser = parse_rule)]
        rule: Option<VoteRule>,
        /// Robot profile whose `[slam.vote]` keys (windows, residual threshold, radius) apply.
        #[arg(long, value_name = "FILE")]
        config: Option<PathBuf>,
        /// Score every map and every rule against this ground truth (map_server YAML).
        #[arg(long, value_name = "GT.yaml")]
        truth_map: Option<PathBuf>,
        /// Output folder.
        #[arg(long, value_name = "DIR", default_value = "vote")]
        out: PathBuf,
    },
}

fn parse_rule(s: &str) -> Result<VoteRule, String> {
    VoteRule::from_name(s).ok_or_else(|| {
        let names: Vec<&str> = VoteRule::ALL.iter().map(|r| r.as_str()).collect();
        format!("unknown rule `{s}`; one of {}", names.join(", "))
    })
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
pub(crate) fn grid_from_wire(
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
    let (dir, mode, timeout_s, octree_dir, bus) = match cmd {
        MapCommand::Save {
            dir,
            mode,
            timeout_s,
            octree_dir,
            bus,
        } => (dir, mode, timeout_s, octree_dir, bus),
        MapCommand::Vote {
            maps,
            rule,
            config,
            truth_map,
            out,
        } => {
            return crate::mapvote::run(crate::mapvote::VoteArgs {
                maps,
                rule,
                config,
                truth_map,
                out,
            });
        }
    };
    let octree_dir = crate::mapsave::octree_dir(octree_dir, bus.config.as_deref())?;
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
    let wait = std::time::Duration::from_secs_f64(timeout_s);
    if let Some(f) = crate::mapsave::fuzzy_map(&bus, wait)? {
        smokenav_platform_map::save_fuzzy(&f, &dir)?;
        println!(
            "saved the fuzzy confidence map ({}×{}) to {} (fuzzy.pgm, fuzzy.yaml, fuzzy.png)",
            f.width,
            f.height,
            dir.display()
        );
    }
    match crate::mapsave::save_octree(&bus, &octree_dir, &dir, wait)? {
        Some(s) => println!(
            "saved the 3D map ({} occupied leaves, {} bytes) to {}",
            s.occupied_leaves,
            s.bytes,
            s.path.display()
        ),
        None => println!("no 3D map: smokenav-mapping is not running"),
    }
    Ok(())
}
